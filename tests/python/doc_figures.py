"""Figures quoted in README.md and docs/*.md, read from the text itself, so that a test compares
what it measures with what the docs say, to the digits they print, and the two cannot drift."""

from __future__ import annotations

import importlib.util
import re
import sys
from functools import cache
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


@cache
def page(name: str) -> str:
    """A page (``README.md``, ``docs/beliefs.md``, ...) with its line breaks and indentation
    collapsed to single spaces, so a pattern can span the wrapped lines of a paragraph."""
    return re.sub(r"\s+", " ", (REPO / name).read_text())


NUMBER = r"(-?\d{1,3}(?:,\d{3})+(?:\.\d+)?|-?\d+(?:\.\d+)?)"


def quoted(name: str, pattern: str) -> tuple[str, ...]:
    """The groups of the one place where ``pattern`` matches the page (an error if none or more);
    each ``#`` in the pattern stands for a number, captured as printed (``0.437``, ``4,047``)."""
    found = list(re.finditer(pattern.replace("#", NUMBER), page(name)))
    assert len(found) == 1, f"{name}: expected one match of {pattern!r}, found {len(found)}"
    return found[0].groups()


def printed(value: float, figure: str) -> str:
    """``value`` printed with as many decimals as ``figure`` has (``"0.437"`` -> 3)."""
    decimals = len(figure.split(".")[1]) if "." in figure else 0
    return f"{value:,.{decimals}f}" if "," in figure else f"{value:.{decimals}f}"


def assert_as_printed(measured: dict[str, float], figures: dict[str, str], where: str) -> None:
    """Every measured value, printed as its figure in the docs is, equals that figure."""
    got = {k: printed(measured[k], figures[k]) for k in figures}
    assert got == figures, f"{where}: the docs say {figures}, measured {got}"


def benchmark(name: str):
    """The module ``benchmarks/NAME.py``, whose functions print the figures the docs quote."""
    folder = str(REPO / "benchmarks")
    if folder not in sys.path:  # the scripts import their shared helpers (bench_common)
        sys.path.insert(0, folder)
    spec = importlib.util.spec_from_file_location(name, REPO / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
