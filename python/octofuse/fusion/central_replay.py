"""The centralized map mapped once: runs that map the same scans several times (one pass per
group of rules) map the centralized map in the first pass only, and score the later passes
against its snapshots as the first pass took them."""

from __future__ import annotations

from concurrent.futures import Future

from ..maps.occupancy import OccupancyMap


class CentralReplay:
    """The centralized map of a run of ``passes`` passes over the same scans and its
    snapshots (:class:`~octofuse.maps.occupancy.ReferenceMap`), in the order the first pass
    took them (at every sample time, then at the end). Later passes take them back in turn;
    the last one lets each go once given."""

    def __init__(self, passes: int):
        self.passes = passes
        self.map: OccupancyMap | None = None  # the first pass's map, once it is mapped
        self._snapshots: list[Future | None] = []
        self._pass = 0
        self._next = 0

    @property
    def replaying(self) -> bool:
        """Whether this pass takes the map and its snapshots from the first pass."""
        return self._pass > 0

    def keep(self, snapshot: Future) -> Future:
        """The first pass's next snapshot (a future of its ReferenceMap), kept for the others."""
        if self.passes > 1:
            self._snapshots.append(snapshot)
        return snapshot

    def take(self) -> Future:
        """The next snapshot as the first pass took it."""
        k = self._next
        if k >= len(self._snapshots) or self._snapshots[k] is None:
            raise RuntimeError(
                f"central replay: pass {self._pass + 1} takes snapshot {k + 1}, "
                f"the first pass took {len(self._snapshots)}"
            )
        snapshot = self._snapshots[k]
        if self._pass == self.passes - 1:
            self._snapshots[k] = None
        self._next += 1
        return snapshot

    def end_pass(self, central: OccupancyMap) -> None:
        """A pass is over: the first keeps its map; each other has taken every snapshot."""
        if self._pass == 0:
            self.map = central
        elif self._next != len(self._snapshots):
            raise RuntimeError(
                f"central replay: pass {self._pass + 1} took {self._next} of "
                f"the first pass's {len(self._snapshots)} snapshots"
            )
        self._pass += 1
        self._next = 0
