"""Every public name of the package resolves to what its module defines."""

import importlib
import pkgutil

import pytest

import octofuse


@pytest.mark.parametrize("name", octofuse.__all__)
def test_every_top_level_name_resolves(name):
    value = getattr(octofuse, name)
    assert value is not None
    assert name in dir(octofuse)


def _modules_with_all():
    for info in pkgutil.walk_packages(octofuse.__path__, "octofuse."):
        if info.name.endswith("__main__"):
            continue
        module = importlib.import_module(info.name)
        if hasattr(module, "__all__"):
            yield module


def test_every_module_all_resolves():
    missing = [
        f"{m.__name__}.{n}" for m in _modules_with_all() for n in m.__all__ if not hasattr(m, n)
    ]
    assert missing == []


def test_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'NoSuchThing'"):
        octofuse.NoSuchThing  # noqa: B018
