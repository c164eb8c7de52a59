"""The libraries the outputs draw and write with (Matplotlib, Open3D), imported on a thread of
their own while a run computes: together they take a second or more, which would otherwise
come after the run, on the main thread."""

from __future__ import annotations

import threading


def import_output_libraries() -> threading.Thread:
    """Start importing Matplotlib (with its Agg backend, as the outputs use it) and Open3D;
    whoever needs them first waits for the import to finish, as Python's imports do."""

    def load() -> None:
        try:
            import matplotlib

            matplotlib.use("Agg", force=False)
            import matplotlib.pyplot  # noqa: F401

            from .clouds import _open3d

            _open3d()
        except Exception:  # the outputs import them again, and say what is wrong
            pass

    thread = threading.Thread(target=load, name="octofuse-imports", daemon=True)
    thread.start()
    return thread
