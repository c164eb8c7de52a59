"""The libraries octofuse draws and writes files with, Matplotlib (on its Agg backend: files, no
screen) and Open3D, imported where they are first needed; a run imports them ahead on a thread
of their own while it computes, since together they take a second or more of CPU."""

from __future__ import annotations

import threading
from collections.abc import Callable

from ..interrupts import interrupted

#: the share of a run's scans after which the imports ahead begin: at the start the imports
#: would hold Python's lock while the first scans are decoded and the maps' threads wait for
#: them (the demo's first rays applied about a second later)
IMPORT_AFTER = 0.1


def pyplot():
    """``matplotlib.pyplot``, drawing on the Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def open3d():
    """The ``open3d`` module (about a second to import, so imported only when needed)."""
    import open3d as o3d

    return o3d


def import_output_libraries() -> threading.Thread:
    """Start importing both on a thread of their own; whoever needs them first waits for the
    import to finish, as Python's imports do."""

    # not a daemon: an interpreter that exits early (an interrupted run) waits for the
    # import under way instead of tearing down a half-initialised extension module
    thread = threading.Thread(target=_load_output_libraries, name="octofuse-imports")
    thread.start()
    return thread


def import_once_under_way(
    progress: Callable[[int, int], None], share: float = IMPORT_AFTER
) -> Callable[[int, int], None]:
    """``progress(done, total)`` that also starts :func:`import_output_libraries` once
    ``share`` of the total is done (a run that ends sooner imports them where they are
    needed)."""
    started = False

    def step(done: int, total: int) -> None:
        nonlocal started
        progress(done, total)
        if not started and done >= share * total:
            started = True
            import_output_libraries()

    return step


def _load_output_libraries() -> None:
    """Both libraries imported; the second not begun once a Ctrl-C has arrived (the exit
    would wait for it)."""
    try:
        for load in (pyplot, open3d):
            if interrupted():
                return
            load()
    except Exception:  # imported again where needed, which says what is wrong
        pass
