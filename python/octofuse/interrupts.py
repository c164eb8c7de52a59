"""Ctrl-C that is never lost, and never leaves half-done what it must not. Python raises
``KeyboardInterrupt`` wherever the main thread is when the signal arrives; if that is inside the
initialisation of a compiled module (numpy imports ``numpy.random``, a Cython module, on first
use), the module's code swallows it and the command would run on to the end. The ``octofuse``
program therefore also remembers the signal, and the places a command passes often (each batch
of scans) and the moment its outputs would replace the old ones ask again; the thread importing
the output libraries ahead then begins no other import.

The signal is remembered but not raised where raising would break more than the command:

- in the import system's own bookkeeping (a module lock's callback raising between taking and
  releasing the import lock leaves it held, and the exit then waits forever for the imports
  thread);
- while the outputs are put in place (the old ones or the new ones, never neither), and after:
  the command is then done.

From the Ctrl-C on, what it left half-done (an object half-built when it landed, a weak-reference
callback it cut short) complains to no one as it is freed: the run is ending with its one line.
"""

from __future__ import annotations

import contextlib
import signal
import sys
from collections.abc import Iterator

_interrupted = False
_signal = signal.SIGINT  # the signal that interrupted
_held = 0  # depth of held() blocks
_outputs_in_place = False


def _on_sigint(signum, frame) -> None:
    global _interrupted, _signal
    if not _interrupted:
        _signal = signal.Signals(signum)
    _interrupted = True
    sys.unraisablehook = _ignore_unraisable
    if _held or _outputs_in_place or _in_import_system(frame):
        return  # asked again at the next check, or the command is done
    raise KeyboardInterrupt


def _in_import_system(frame) -> bool:
    return frame is not None and frame.f_code.co_filename.startswith("<frozen importlib")


def _ignore_unraisable(unraisable) -> None:
    """``sys.unraisablehook`` once interrupted: the errors of destructors and callbacks, which
    Python would print as "Exception ignored in", are dropped."""


def remember_interrupts() -> None:
    """Handle Ctrl-C as Python does and also remember it, and SIGTERM (``kill``, a job
    scheduler's stop) as Ctrl-C (the ``octofuse`` program; call on the main thread)."""
    signal.signal(signal.SIGINT, _on_sigint)
    signal.signal(signal.SIGTERM, _on_sigint)


def exit_code() -> int:
    """The exit code of an interrupted command: 128 + the signal's number (130 for Ctrl-C,
    143 for SIGTERM), as a shell reports a death by that signal."""
    return 128 + int(_signal)


def interruption() -> str:
    """How the command was interrupted, for its one line: "interrupted" or "terminated"."""
    return "terminated" if _signal == signal.SIGTERM else "interrupted"


def begin_command() -> None:
    """A command starts: its outputs are not in place yet."""
    global _outputs_in_place
    _outputs_in_place = False


def interrupted() -> bool:
    """Whether a Ctrl-C arrived (as :func:`remember_interrupts` remembers it)."""
    return _interrupted


def cut_short() -> bool:
    """Whether a Ctrl-C arrived before the command's outputs were in place: the command ends
    as interrupted, its old outputs kept."""
    return _interrupted and not _outputs_in_place


def raise_if_interrupted() -> None:
    """``KeyboardInterrupt`` if :func:`cut_short` (a Ctrl-C swallowed on its way, or held)."""
    if cut_short():
        raise KeyboardInterrupt


@contextlib.contextmanager
def held() -> Iterator[None]:
    """A block a Ctrl-C does not cut in two: one arriving in it is only remembered."""
    global _held
    _held += 1
    try:
        yield
    finally:
        _held -= 1


def outputs_in_place() -> None:
    """The command's outputs replaced the old ones: a Ctrl-C from now on is ignored."""
    global _outputs_in_place
    _outputs_in_place = True
