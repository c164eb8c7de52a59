"""Freed memory given back to the system, so that resident memory measures what the process
holds and what comes next adds to that, not to its peak."""

from __future__ import annotations

import ctypes
import functools
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Callable, Iterable, Optional


def return_freed_memory(pools: bool = True) -> None:
    """Give back the pages glibc's heap holds free (``malloc_trim``) and, with ``pools``, the
    tree pools' empty slabs (which the next maps would otherwise reuse)."""
    if pools:
        from . import _core

        _core._trim_node_pools()
    trim = _malloc_trim()
    if trim is not None:
        trim(0)


@functools.cache
def _malloc_trim() -> Optional[Callable[[int], int]]:
    """glibc's ``malloc_trim``, or None where the C library has none."""
    try:
        return ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError):
        return None


class MapFreeing:
    """Frees maps (``clear()``, then :func:`return_freed_memory`) on a thread of its own, batch
    after batch, so that the caller can go on (writing a run's outputs); a batch the caller
    waits for is cleared on ``threads`` threads. The ``with`` block's end waits for every
    batch, and raises what a batch raised (unless the block itself raised)."""

    def __init__(self, threads: int = 1):
        self.threads = threads
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="octofuse-free")
        self._batches: list[Future] = []

    def free(self, maps: Iterable, wait: bool = False) -> None:
        """Clear ``maps`` (objects with ``clear()``), after the batches given before; with
        ``wait``, return once they are freed (on ``threads`` threads, else on one: the caller
        keeps the others)."""
        self._batches.append(self._pool.submit(self._free, list(maps),
                                               self.threads if wait else 1))
        if wait:
            self._batches[-1].result()

    @staticmethod
    def _free(maps: list, threads: int) -> None:
        from .threads import thread_map

        thread_map(lambda m: m.clear(), maps, threads)
        return_freed_memory()

    def __enter__(self) -> "MapFreeing":
        return self

    def __exit__(self, kind, *_) -> None:
        self._pool.shutdown(wait=True)
        if kind is None:
            for batch in self._batches:
                batch.result()
