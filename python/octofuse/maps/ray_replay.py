"""Rays traced once and replayed: runs that map the same batches of scans several times (one
pass per group of rules) trace each batch's rays once, in the first pass."""

from __future__ import annotations

from collections.abc import Callable, Sequence

from ..scans.source import Scan
from .build import trace_scans
from .occupancy import OccupancyMap

#: traced rays kept for replay at most; beyond, later passes trace the rest of the batches
REPLAY_RAY_BYTES = 256 << 20


class RayReplay:
    """The rays of a run's batches for ``passes`` passes that map the same batches in the same
    order: the first pass traces every batch and keeps the rays of its first batches (up to
    ``max_bytes``), the others take them back in turn and trace the batches beyond; the last
    one lets each batch's rays go once given."""

    def __init__(self, passes: int, max_bytes: int = REPLAY_RAY_BYTES):
        self.passes, self.max_bytes = passes, max_bytes
        self._kept: list[tuple[list, object] | None] = []  # (scans' (agent, stamp), rays)
        self._size = 0
        self._full = passes < 2  # nothing to keep for
        self._pass = -1

    def next_pass(self) -> Callable[[Sequence[Scan], OccupancyMap, int], object]:
        """The tracing of the next pass, batch by batch: it takes and gives what
        :func:`~octofuse.maps.build.trace_scans` does."""
        self._pass += 1
        k, last = self._pass, self._pass == self.passes - 1
        if k >= self.passes:
            raise RuntimeError(f"ray replay: pass {k + 1} of a replay of {self.passes}")
        batch = iter(range(len(self._kept))) if k > 0 else iter(())

        def trace(scans: Sequence[Scan], grid: OccupancyMap, threads: int, mode: str = "exact"):
            i = next(batch, None)
            if i is not None:
                ids, rays = self._kept[i]
                if ids != _ids(scans):
                    raise RuntimeError(
                        f"ray replay: batch {i + 1} of pass {k + 1} holds other "
                        "scans than in the first pass"
                    )
                if last:
                    self._kept[i] = None
                return rays
            rays = trace_scans(scans, grid, threads, mode)
            if k == 0 and not self._full:
                self._size += rays.nbytes
                if self._size <= self.max_bytes:
                    self._kept.append((_ids(scans), rays))
                else:
                    self._full = True
            return rays

        return trace

    @property
    def given_back(self) -> bool:
        """Whether the last pass has given out every batch it kept (their rays freed once
        applied)."""
        return self._pass == self.passes - 1 and bool(self._kept) and self._kept[-1] is None


def _ids(scans: Sequence[Scan]) -> list[tuple[int, int]]:
    """What tells a batch's scans apart: their agent and stamp each."""
    return [(s.agent, s.stamp_ns) for s in scans]
