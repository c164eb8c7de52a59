"""The Python tests sit in tiers that mirror the package: tests/python/<part>/ holds the tests
of python/octofuse/<part>/, and tests/python itself only the fixtures and helpers they share."""

from conftest import REPO

TESTS = REPO / "tests" / "python"
PACKAGE = REPO / "python" / "octofuse"


def parts() -> set[str]:
    return {p.parent.name for p in PACKAGE.glob("*/__init__.py")}


def test_every_test_file_sits_in_a_tier():
    outside = sorted(
        str(p.relative_to(TESTS))
        for p in TESTS.rglob("*.py")
        if p.name.startswith("test_") and p.parent.parent != TESTS
    )
    tiers = "|".join(sorted(parts()))
    assert outside == [], f"test files outside tests/python/<{tiers}>/: {outside}"


def test_every_tier_is_a_part_of_the_package():
    tiers = {p.name for p in TESTS.iterdir() if p.is_dir() and any(p.glob("test_*.py"))}
    assert tiers <= parts(), f"tiers naming no part of python/octofuse: {sorted(tiers - parts())}"
