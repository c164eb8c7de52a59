"""The clocks that drive a run's agents: when scans arrive and when the schedule's moments
(exchanges, samples, the vote) come. Bag time for ``run``: the scans in time order, the
moments between them; rounds for ``fuse``: one group of exchanges per round. A clock says
when; the mission loop that reads it says what happens then."""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence

from .schedule import EXCHANGE

#: a step of a batch of scans (beside the schedule's VOTE, EXCHANGE and SAMPLE moments)
SCANS = 2


class BagClock:
    """Bag time: the scans in batches of at most ``batch_size``, and the run's ``moments``
    (``(time, kind, group)`` in time order, :func:`~.schedule.moments`) between them, each
    after the scans stamped before it, before a scan stamped at or after its time. Times are
    seconds from ``start_ns``."""

    def __init__(self, moments: Sequence[tuple], start_ns: int, batch_size: int):
        self.moments, self.start_ns, self.batch_size = moments, start_ns, batch_size

    def steps(self, scans: Iterable) -> Iterator[tuple[float, int, object]]:
        """``(time, kind, what)``: ``(t, SCANS, batch)`` (``t``: the batch's last scan), or
        a moment ``(t, kind, group)``; the moments left after the last scan come at the end."""
        batch: list = []
        k, last = 0, 0.0
        for scan in scans:
            t = (scan.stamp_ns - self.start_ns) / 1e9
            if k < len(self.moments) and self.moments[k][0] < t:
                if batch:
                    yield last, SCANS, batch
                    batch = []
                while k < len(self.moments) and self.moments[k][0] < t:
                    yield self.moments[k]
                    k += 1
            batch.append(scan)
            last = t
            if len(batch) >= self.batch_size:
                yield last, SCANS, batch
                batch = []
        if batch:
            yield last, SCANS, batch
        yield from self.moments[k:]


class RoundsClock:
    """Rounds on finished maps: round ``k`` at time ``k``, its group of exchanges."""

    def __init__(self, rounds: Sequence[list]):
        self.rounds = rounds

    def steps(self) -> Iterator[tuple[float, int, list]]:
        for k, group in enumerate(self.rounds):
            yield float(k), EXCHANGE, group
