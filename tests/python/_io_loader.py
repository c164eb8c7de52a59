"""Import ``octofuse.io`` for the io tests.

``octofuse.io`` only needs numpy and rosbags. When the ``octofuse`` package
itself cannot be imported (its compiled core is not built in this checkout),
the io package is loaded on its own from its source folder, so the io tests
run either way.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
from pathlib import Path
from types import ModuleType

IO_DIR = Path(__file__).resolve().parents[2] / "python" / "octofuse" / "io"
_STANDALONE = "octofuse_io_standalone"


def load_io() -> ModuleType:
    """Return ``octofuse.io``, or the same package loaded from ``python/octofuse/io``."""
    try:
        return importlib.import_module("octofuse.io")
    except ImportError:
        pass
    if _STANDALONE in sys.modules:
        return sys.modules[_STANDALONE]
    spec = importlib.util.spec_from_file_location(
        _STANDALONE, IO_DIR / "__init__.py", submodule_search_locations=[str(IO_DIR)]
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[_STANDALONE] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[_STANDALONE]
        raise
    return module


oio = load_io()
