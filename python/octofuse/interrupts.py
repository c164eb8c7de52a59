"""Ctrl-C that is never lost. Python raises ``KeyboardInterrupt`` wherever the main thread is
when the signal arrives; if that is inside the initialisation of a compiled module (numpy
imports ``numpy.random``, a Cython module, on first use), the module's code swallows it and the
command would run on to the end. The ``octofuse`` program therefore also remembers the signal,
and the places a command passes often (each batch of scans) and the moment its outputs would
replace the old ones ask again; the thread importing the output libraries ahead then begins no
other import."""

from __future__ import annotations

import signal

_interrupted = False


def _on_sigint(signum, frame) -> None:
    global _interrupted
    _interrupted = True
    raise KeyboardInterrupt


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
