"""A drawing made in a process of its own beside the caller: Matplotlib holds Python's lock
while it draws, so two figures drawn on two threads take as long as one after the other,
while a forked child draws on the other core."""

from __future__ import annotations

import contextlib
import os
from typing import Callable, Iterator

from .libraries import pyplot


@contextlib.contextmanager
def drawn_aside(draw: Callable[[], object], what: str, cores: int = 2) -> Iterator[None]:
    """``draw()`` run in a forked child while the body runs (before it, in the caller's
    process, with fewer than 2 ``cores`` or where there is no ``fork``); on leaving, the child
    is waited for and, if it failed, an :class:`OSError` names ``what`` and says why (after an
    error of the body, the body's error is the one raised). The child shares nothing written
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
            os.write(write, f"{type(e).__name__}: {e}".encode(errors="replace")[:2000])
        finally:
            os._exit(code)
    os.close(write)
    failed = True
    try:
        yield
        failed = False
    finally:
        with os.fdopen(read, "rb") as pipe:
            why = pipe.read().decode(errors="replace")
        code = os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])
    if code != 0 and not failed:
        raise OSError(f"cannot write {what}: "
                      + (why or f"its drawing process ended with {code}"))
