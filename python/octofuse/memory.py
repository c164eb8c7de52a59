"""Freed memory given back to the system, so that resident memory measures what the process
holds and what comes next adds to that, not to its peak."""

from __future__ import annotations

import ctypes
import functools
from collections.abc import Callable


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
def _malloc_trim() -> Callable[[int], int] | None:
    """glibc's ``malloc_trim``, or None where the C library has none."""
    try:
        return ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError):
        return None


def resident_memory() -> tuple[int, int, int]:
    """(private, total, peak total) resident memory of this process, bytes (Linux /proc; 0
    elsewhere). Private memory leaves out shared memory (Ray's object store is mapped into
    every worker that reads an object from it, and counts in the total)."""
    vals: dict[str, int] = {}
    try:
        with open("/proc/self/status") as f:
            for line in f:
                key, _, rest = line.partition(":")
                if key in ("VmRSS", "VmHWM", "RssAnon", "RssFile"):
                    vals[key] = int(rest.split()[0]) * 1024
    except OSError:
        pass
    return (
        vals.get("RssAnon", 0) + vals.get("RssFile", 0),
        vals.get("VmRSS", 0),
        vals.get("VmHWM", 0),
    )
