"""A drawing made in a process of its own beside the caller: Matplotlib holds Python's lock
while it draws, so two figures drawn on two threads take as long as one after the other,
while a forked child draws on the other core."""

from __future__ import annotations

import contextlib
import os
import pickle
import traceback
from collections.abc import Callable, Iterator

from .libraries import pyplot


@contextlib.contextmanager
def drawn_aside(draw: Callable[[], object], what: str, cores: int = 2) -> Iterator[None]:
    """``draw()`` run in a forked child while the body runs (before it, in the caller's
    process, with fewer than 2 ``cores`` or where there is no ``fork``); on leaving, the child
    is waited for and its error, if it failed, raised in the caller as drawing in the caller's
    process would have raised it (the child's traceback in a note; after an error of the body,
    the body's error is the one raised). A child ended by a signal, or that handed over no
    whole error, is an :class:`OSError` naming ``what``. The child shares nothing written
    after the fork: ``draw`` writes files only."""
    if cores < 2 or not hasattr(os, "fork"):
        draw()
        yield
        return
    pyplot()  # imported before the fork: a child never inherits an import under way
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: no atexit handlers, no buffers of the parent flushed twice
        code = 1
        try:
            os.close(read)
            draw()
            code = 0
        except BaseException as e:  # noqa: BLE001  (handed to the parent)
            _hand_over(write, e)
        finally:
            os._exit(code)
    os.close(write)
    failed = True
    try:
        yield
        failed = False
    finally:
        with os.fdopen(read, "rb") as pipe:
            handed = pipe.read()
        code = os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])
    if code != 0 and not failed:
        handed_over = _handed_error(handed) if code > 0 else None  # not after a signal
        if handed_over is None:
            raise OSError(f"cannot write {what}: its drawing process ended with {code}")
        error, child_traceback = handed_over
        error.add_note(f"raised while drawing {what} in a child process:\n{child_traceback}")
        raise error


def _hand_over(fd: int, e: BaseException) -> None:
    """The child's error ``e`` and its traceback written to the pipe ``fd``, pickled; an error
    that does not pickle goes as a RuntimeError naming its kind and text."""
    told = traceback.format_exc()[-8000:]
    try:
        data = pickle.dumps((e, told))
        pickle.loads(data)  # an error whose arguments do not rebuild it fails here, not later
    except Exception:  # noqa: BLE001
        data = pickle.dumps((RuntimeError(f"{type(e).__name__}: {e}"), told))
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]


def _handed_error(data: bytes):
    """The (error, traceback) a child handed over, or None if it handed over nothing whole."""
    try:
        return pickle.loads(data) if data else None
    except Exception:  # noqa: BLE001  (a child cut short while writing)
        return None
