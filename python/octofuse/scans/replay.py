"""The scans of a source read once and replayed: runs that go over the same bags several times
(one pass per group of rules) decode and place every scan once."""

from __future__ import annotations

from collections.abc import Iterator

from .source import Scan, ScanSource

#: scans (their points) kept for replay at most; beyond, later passes read the bags again
REPLAY_BYTES = 256 << 20


class ScanReplay:
    """A :class:`ScanSource` read for ``passes`` passes: the first reads the bags and keeps the
    scans (up to ``max_bytes`` of points), the others replay them, the last one letting each
    go once given. Everything else (agents, bags, stats, notes) is the source's; the stats are
    those of the first pass, which later passes repeat."""

    def __init__(self, source: ScanSource, passes: int, max_bytes: int = REPLAY_BYTES):
        self.source, self.passes, self.max_bytes = source, passes, max_bytes
        self._kept: list[Scan] | None = None  # the first pass's scans, if they fitted
        self._pass = 0

    def __getattr__(self, name):
        return getattr(self.source, name)

    def scans(self) -> Iterator[Scan]:
        k = self._pass
        self._pass += 1
        if k > 0 and self._kept is not None:
            yield from self._replay(last=k == self.passes - 1)
            return
        keep = k == 0 and self.passes > 1
        kept: list[Scan] = []
        size = 0
        for scan in self.source.scans():
            if keep:
                size += scan.points.nbytes
                if size <= self.max_bytes:
                    kept.append(scan)
                else:
                    keep, kept = False, []
            yield scan
        if keep:
            self._kept = kept

    def _replay(self, last: bool) -> Iterator[Scan]:
        kept = self._kept
        if last:
            self._kept = None
            kept.reverse()  # popped from the end: each scan let go once given
            while kept:
                yield kept.pop()
        else:
            yield from kept
