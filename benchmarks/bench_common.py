"""Helpers shared by the benchmark scripts: progress lines, the machine, peak memory."""

from __future__ import annotations

import os
import resource
import sys


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def machine() -> str:
    """Hardware threads and memory of this machine, e.g. '2 hardware threads, 23.5 GiB memory'."""
    mem = "unknown memory"
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemTotal:"):
                    mem = f"{int(line.split()[1]) / 2**20:.1f} GiB memory"
                    break
    except OSError:
        pass
    return f"{os.cpu_count()} hardware threads, {mem}"


def peak_rss_mib() -> float:
    """Peak resident memory of this process: VmHWM (reset by exec, unlike ru_maxrss, which a
    child started with fork + exec inherits from its parent), else ru_maxrss."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
