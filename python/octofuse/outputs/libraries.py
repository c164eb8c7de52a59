"""The libraries octofuse draws and writes files with, Matplotlib (on its Agg backend: files, no
screen) and Open3D, imported where they are first needed; a run imports them ahead on a thread
of their own while it computes, since together they take a second or more."""

from __future__ import annotations

import threading


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

    def load() -> None:
        try:
            pyplot()
            open3d()
        except Exception:  # imported again where needed, which says what is wrong
            pass

    # not a daemon: an interpreter that exits early (an interrupted run) waits for the
    # imports instead of tearing down a half-initialised extension module
    thread = threading.Thread(target=load, name="octofuse-imports")
    thread.start()
    return thread
