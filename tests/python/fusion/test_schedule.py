import math

import numpy as np
import pytest

from octofuse.fusion import (
    graph,  # noqa: E402
    schedule,  # noqa: E402
)

Exchange = schedule.Exchange

RING8 = graph.make_graph("ring", 8)
H38 = graph.make_graph("max-robust:3", 8)


def times(events):
    return [e.time_s for e in events]


def assert_time_ordered(events):
    assert times(events) == sorted(times(events))


# ------------------------------------------------------------------------------------ periodic


def test_periodic_both_counts_order_and_times():
    events = schedule.periodic(H38, period_s=10, duration_s=100)
    assert len(events) == H38.n_edges * 10 * 2  # links x rounds x 2
    assert sorted(set(times(events))) == [10.0 * k for k in range(1, 11)]
    assert_time_ordered(events)
    first_round = [(e.sender, e.receiver) for e in events if e.time_s == 10.0]
    assert first_round == [p for a, b in H38.edges for p in ((a, b), (b, a))]
    assert events[0] == Exchange(10.0, 0, 1) and events[1] == Exchange(10.0, 1, 0)


def test_periodic_one_direction_alternates_per_round():
    events = schedule.periodic(RING8, period_s=5, duration_s=20, directions="one")
    assert len(events) == RING8.n_edges * 4
    for k, t in enumerate([5.0, 10.0, 15.0, 20.0]):
        pairs = [(e.sender, e.receiver) for e in events if e.time_s == t]
        assert pairs == [(a, b) if k % 2 == 0 else (b, a) for a, b in RING8.edges]


def test_periodic_start_and_boundaries():
    assert times(schedule.periodic(RING8, period_s=10, duration_s=30, start_s=0))[::16] == [
        0,
        10,
        20,
        30,
    ]
    assert times(schedule.periodic(RING8, period_s=10, duration_s=35, start_s=2.5))[::16] == [
        2.5,
        12.5,
        22.5,
        32.5,
    ]
    assert schedule.periodic(RING8, period_s=10, duration_s=9) == []
    assert set(times(schedule.periodic(RING8, period_s=10, duration_s=0, start_s=0))) == {0.0}
    # rounding must not drop the last round: 3 x 0.1 is not exactly 0.3
    assert len(set(times(schedule.periodic(RING8, period_s=0.1, duration_s=0.3)))) == 3


# ----------------------------------------------------------------------------------- aperiodic


def test_aperiodic_seeded_sorted_and_within_horizon():
    a = schedule.aperiodic(H38, mean_interval_s=15, duration_s=600, seed=4)
    assert a == schedule.aperiodic(H38, mean_interval_s=15, duration_s=600, seed=4)
    assert a != schedule.aperiodic(H38, mean_interval_s=15, duration_s=600, seed=5)
    assert_time_ordered(a)
    assert all(0 < t <= 600 for t in times(a))
    assert all(isinstance(e.time_s, float) for e in a)
    # "both": each firing is a -> b immediately followed by b -> a at the same time
    for x, y in zip(a[::2], a[1::2]):
        assert x.time_s == y.time_s and (x.sender, x.receiver) == (y.receiver, y.sender)
        assert x.sender < x.receiver


def test_aperiodic_link_times_depend_only_on_seed_and_link():
    short = schedule.aperiodic(H38, mean_interval_s=10, duration_s=200, seed=1)
    long = schedule.aperiodic(H38, mean_interval_s=10, duration_s=400, seed=1)
    assert short == [e for e in long if e.time_s <= 200]  # a shorter horizon is a prefix

    def link_01(g):
        return [
            e
            for e in schedule.aperiodic(g, mean_interval_s=10, duration_s=400, seed=1)
            if {e.sender, e.receiver} == {0, 1}
        ]

    assert link_01(H38) == link_01(graph.make_graph("complete", 8))


def test_aperiodic_one_direction_alternates_per_link():
    events = schedule.aperiodic(RING8, mean_interval_s=5, duration_s=300, seed=2, directions="one")
    assert_time_ordered(events)
    for a, b in RING8.edges:
        dirs = [(e.sender, e.receiver) for e in events if {e.sender, e.receiver} == {a, b}]
        assert len(dirs) > 10
        assert dirs == [(a, b) if k % 2 == 0 else (b, a) for k in range(len(dirs))]


def test_aperiodic_mean_gap_matches_request():
    line = graph.make_graph("line", 3)
    mean, horizon = 15.0, 300_000.0  # simulated seconds
    expected_firings = horizon / mean
    events = schedule.aperiodic(
        line, mean_interval_s=mean, duration_s=horizon, seed=11, directions="one"
    )
    for a, b in line.edges:
        t = np.array([e.time_s for e in events if {e.sender, e.receiver} == {a, b}])
        gaps = np.diff(np.concatenate([[0.0], t]))
        # ~20000 gaps: the standard error of the mean is ~0.7 %; allow 5 %
        assert abs(gaps.mean() - mean) < 0.05 * mean
        assert abs(len(t) - expected_firings) < 0.05 * expected_firings
        # exponential gaps: the standard deviation equals the mean
        assert abs(gaps.std() - mean) < 0.1 * mean


# -------------------------------------------------------------------------------------- rounds


def test_rounds_structure():
    r = schedule.rounds(H38, 3)
    assert len(r) == 3
    for k, rnd in enumerate(r):
        assert len(rnd) == 2 * H38.n_edges
        assert set(times(rnd)) == {float(k)}
    assert schedule.rounds(H38, 0) == []
    one = schedule.rounds(RING8, 2, directions="one")
    assert [(e.sender, e.receiver) for e in one[0]] == list(RING8.edges)
    assert [(e.receiver, e.sender) for e in one[1]] == list(RING8.edges)


def _spread(n, events_by_round, double_buffered):
    """Which agents' scans each agent holds, after fusing the given rounds."""
    held = [{i} for i in range(n)]
    for rnd in events_by_round:
        before = [set(h) for h in held] if double_buffered else held
        for e in rnd:
            held[e.receiver] |= before[e.sender]
    return held


def test_rounds_are_double_buffered():
    assert "START" in schedule.rounds.__doc__ and "double" in schedule.rounds.__doc__.lower()
    line = graph.make_graph("line", 6)
    for n_rounds in range(1, 6):
        held = _spread(6, schedule.rounds(line, n_rounds), double_buffered=True)
        # information travels exactly one hop per round
        assert held[5] == set(range(5 - n_rounds, 6))
        assert held[0] == set(range(0, n_rounds + 1))
    # applied one by one instead, a single round would carry agent 0's map down the whole line
    assert _spread(6, schedule.rounds(line, 1), double_buffered=False)[5] == set(range(6))


# ------------------------------------------------------------------------------ parse_schedule


@pytest.mark.parametrize(
    "spec, kind, value",
    [
        ("periodic:10", "periodic", 10.0),
        ("aperiodic:15", "aperiodic", 15.0),
        (" Periodic : 2.5 ", "periodic", 2.5),
        ("rounds:3", "rounds", 3.0),
    ],
)
def test_parse_schedule(spec, kind, value):
    s = schedule.parse_schedule(spec)
    assert (s.kind, s.value) == (kind, value)


def test_schedule_spec_build():
    assert schedule.parse_schedule("periodic:10").build(H38, duration_s=50) == schedule.periodic(
        H38, period_s=10, duration_s=50
    )
    assert schedule.parse_schedule("aperiodic:15").build(H38, duration_s=90, seed=3) == (
        schedule.aperiodic(H38, mean_interval_s=15, duration_s=90, seed=3)
    )
    flat = schedule.parse_schedule("rounds:2").build(H38, directions="one")
    assert flat == [e for r in schedule.rounds(H38, 2, directions="one") for e in r]
    with pytest.raises(ValueError, match="periodic schedule needs duration_s"):
        schedule.parse_schedule("periodic:10").build(H38)


@pytest.mark.parametrize(
    "spec, expected",
    [
        (
            "sometimes:3",
            "unknown schedule 'sometimes:3'; valid: periodic:SECONDS, aperiodic:SECONDS, rounds:R",
        ),
        ("periodic", "needs a value, e.g. periodic:10"),
        ("aperiodic:", "needs a value, e.g. aperiodic:10"),
        ("periodic:soon", "needs a number of seconds, got 'periodic:soon'"),
        ("periodic:0", "positive, finite"),
        ("aperiodic:-5", "positive, finite"),
        ("aperiodic:nan", "positive, finite"),
        ("periodic:inf", "positive, finite"),
        ("rounds:0", "whole number of rounds >= 1"),
        ("rounds:2.5", "whole number of rounds >= 1"),
    ],
)
def test_parse_schedule_errors(spec, expected):
    with pytest.raises(ValueError) as err:
        schedule.parse_schedule(spec)
    assert expected in str(err.value)


@pytest.mark.parametrize(
    "call, expected",
    [
        (lambda: schedule.periodic(RING8, period_s=0, duration_s=10), "period_s must be > 0"),
        (lambda: schedule.periodic(RING8, period_s=1, duration_s=-1), "duration_s must be >= 0"),
        (
            lambda: schedule.periodic(RING8, period_s=1, duration_s=10, start_s=-1),
            "start_s must be >= 0",
        ),
        (
            lambda: schedule.periodic(RING8, period_s=math.inf, duration_s=10),
            "period_s must be finite",
        ),
        (
            lambda: schedule.periodic(RING8, period_s="10", duration_s=10),
            "period_s must be a number",
        ),
        (
            lambda: schedule.periodic(RING8, period_s=1, duration_s=10, directions="two"),
            "directions must be one of both, one, got 'two'",
        ),
        (
            lambda: schedule.aperiodic(RING8, mean_interval_s=0, duration_s=10, seed=0),
            "mean_interval_s must be > 0",
        ),
        (
            lambda: schedule.aperiodic(RING8, mean_interval_s=1, duration_s=10, seed=-1),
            "non-negative integer",
        ),
        (
            lambda: schedule.aperiodic(RING8, mean_interval_s=1, duration_s=10, seed=1.5),
            "non-negative integer",
        ),
        (lambda: schedule.rounds(RING8, -1), "n_rounds must be a non-negative integer"),
        (lambda: schedule.rounds(RING8, True), "n_rounds must be a non-negative integer"),
    ],
)
def test_argument_errors(call, expected):
    with pytest.raises(ValueError) as err:
        call()
    assert expected in str(err.value)
