"""Ctrl-C that is never lost. Python raises ``KeyboardInterrupt`` wherever the main thread is
when the signal arrives; if that is inside the initialisation of a compiled module (numpy
imports ``numpy.random``, a Cython module, on first use), the module's code swallows it and the
command would run on to the end. The ``octofuse`` program therefore also remembers the signal,
and the places a command passes often (each batch of scans) and the moment its outputs would
replace the old ones ask again; the thread importing the output libraries ahead then begins no
other import. From the Ctrl-C on, what it left half-done (an object half-built when it landed,
a weak-reference callback it cut short) complains to no one as it is freed: the run is ending
with its one line."""

from __future__ import annotations

import signal
import sys

_interrupted = False


def _on_sigint(signum, frame) -> None:
    global _interrupted
    _interrupted = True
    sys.unraisablehook = _ignore_unraisable
    raise KeyboardInterrupt


def _ignore_unraisable(unraisable) -> None:
    """``sys.unraisablehook`` once interrupted: the errors of destructors and callbacks, which
    Python would print as "Exception ignored in", are dropped."""


def remember_interrupts() -> None:
    """Handle Ctrl-C as Python does and also remember it (the ``octofuse`` program; call on
    the main thread)."""
    signal.signal(signal.SIGINT, _on_sigint)


def interrupted() -> bool:
    """Whether a Ctrl-C arrived (as :func:`remember_interrupts` remembers it)."""
    return _interrupted


def raise_if_interrupted() -> None:
    """``KeyboardInterrupt`` if a Ctrl-C arrived (one that was swallowed on its way)."""
    if interrupted():
        raise KeyboardInterrupt
