"""The clocks of a run: bag time puts every scan and every moment of the schedule in one
order, a moment after the scans stamped up to its time and before the later ones."""

from __future__ import annotations

from dataclasses import dataclass

from hypothesis import given
from hypothesis import strategies as st

from octofuse.fusion.clock import SCANS, BagClock, RoundsClock
from octofuse.fusion.schedule import EXCHANGE, SAMPLE


@dataclass
class Scan:
    stamp_ns: int


@given(
    stamps=st.lists(st.integers(0, 50), max_size=40),
    times=st.lists(st.integers(0, 55), max_size=12),
    batch=st.integers(1, 6),
)
def test_bag_time_orders_scans_and_moments(stamps, times, batch):
    start = 1_000_000_000
    scans = [Scan(start + s * 100_000_000) for s in sorted(stamps)]  # s / 10 seconds
    moments = sorted((t / 10, EXCHANGE if t % 2 else SAMPLE, [t]) for t in times)
    steps = list(BagClock(moments, start, batch).steps(scans))

    # every scan once, in order, in batches of at most `batch`; every moment once, in order
    batches = [w for _, kind, w in steps if kind == SCANS]
    assert [s for b in batches for s in b] == scans
    assert all(1 <= len(b) <= batch for b in batches)
    assert [x for x in steps if x[1] != SCANS] == moments
    # a moment comes after the scans stamped up to its time (one stamped at its time is
    # inserted before it) and before the later ones
    seen = 0
    for t, kind, what in steps:
        if kind == SCANS:
            seen += len(what)
            assert t == (what[-1].stamp_ns - start) / 1e9
        else:
            assert seen == sum((s.stamp_ns - start) / 1e9 <= t for s in scans)


def test_rounds_are_one_group_each_at_their_index():
    rounds = [["a"], [], ["b", "c"]]
    assert list(RoundsClock(rounds).steps()) == [
        (0.0, EXCHANGE, ["a"]),
        (1.0, EXCHANGE, []),
        (2.0, EXCHANGE, ["b", "c"]),
    ]
