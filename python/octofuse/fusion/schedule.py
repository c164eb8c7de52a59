"""Communication schedules: when each link of a graph carries a map, and in which direction.

A schedule is a time-ordered list of :class:`Exchange` events; an event carries the sender's
map to the receiver, which fuses it into its own. Events that share a time are simultaneous:
every one of them carries its sender's map as it was before any of them was delivered, and
the receivers fuse them in list order (first in, first out). A round of :func:`rounds` (time =
round index) and a round of :func:`periodic` are such groups, i.e. double-buffered.

``directions``:

* ``"both"``: every time a link fires it carries two events at the same time, ``a -> b`` then
  ``b -> a`` for the link ``(a, b)`` with ``a < b``;
* ``"one"``: every firing carries one event, alternating ``a -> b``, ``b -> a``, ``a -> b``, ...
  over the firings of that link.

Graphs are used through ``graph.n`` and ``graph.edges`` (sorted ``(a, b)`` pairs with
``a < b``), as provided by :class:`octofuse.graph.Graph`. Links are always visited in that
sorted order, so a schedule is fully determined by its arguments.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from itertools import groupby

import numpy as np

from .graph import Graph, make_graph

DIRECTIONS = ("both", "one")
SCHEDULE_KINDS = ("periodic:SECONDS", "aperiodic:SECONDS", "rounds:R")
#: most exchange events one schedule may hold (each one is a map fusion)
MAX_EXCHANGES = 100_000


def _check_count(what: str, count: float) -> None:
    if not count <= MAX_EXCHANGES:
        raise ValueError(
            f"{what} would create {count:.3g} exchanges, more than the "
            f"{MAX_EXCHANGES:,} a run can use; choose a longer interval or fewer rounds"
        )


@dataclass(frozen=True, slots=True)
class Exchange:
    """At ``time_s``, agent ``sender`` sends its map to agent ``receiver``; a ``lost`` message
    is sent (and counted as sent) but never arrives (:func:`drop_messages`)."""

    time_s: float
    sender: int
    receiver: int
    lost: bool = False


def drop_messages(events, loss: float, seed: int) -> list[Exchange]:
    """``events`` with each message lost with probability ``loss``, independently.

    The draws come from ``numpy.random.default_rng([seed, 1055])``, one per event in list
    order, so a schedule and a seed give the same lost messages for every fusion rule. With
    ``loss == 0`` the events are returned unchanged.
    """
    loss = float(loss)
    if not (math.isfinite(loss) and 0.0 <= loss < 1.0):
        raise ValueError(f"loss must be a probability from 0 to below 1, got {loss}")
    events = list(events)
    if loss == 0.0 or not events:
        return events
    draws = np.random.default_rng([int(seed), 1055]).random(len(events))
    return [
        Exchange(e.time_s, e.sender, e.receiver, True) if u < loss else e
        for e, u in zip(events, draws.tolist())
    ]


#: what happens at an instant of a run in time, in the order it happens there: the robust vote
#: (before the exchanges of its instant), the exchange groups, the KL samples
VOTE, EXCHANGE, SAMPLE = -1, 0, 1


def check_samples(samples: int) -> None:
    """``ValueError`` unless ``samples`` (points of a KL timeline) lies in 0..10000."""
    if not 0 <= samples <= 10_000:
        raise ValueError(f"samples = {samples}: expected 0 to 10000 points in time")


def moments(
    events: list, duration: float, samples: int, vote_time: float | None = None
) -> list[tuple[float, int, list | None]]:
    """A run's moments in time order, ``(time, kind, exchange group or None)``: its groups of
    simultaneous exchanges, ``samples`` KL samples evenly over ``duration`` (the last at its
    end) and the robust vote at ``vote_time`` (if given); at one instant in the order of
    :data:`VOTE`, :data:`EXCHANGE`, :data:`SAMPLE`."""
    out = [
        (g[0].time_s, EXCHANGE, g)
        for g in (list(g) for _, g in groupby(events, key=lambda e: e.time_s))
    ]
    out += [(duration * (k + 1) / samples, SAMPLE, None) for k in range(samples)]
    if vote_time is not None:
        out.append((vote_time, VOTE, None))
    return sorted(out, key=lambda x: (x[0], x[1]))


def mission_events(
    spec: ScheduleSpec, graph, fuse_cfg, start_ns: int | None, end_ns: int | None
) -> tuple[float, list[Exchange]]:
    """The mission's length (seconds, from the bags' first to last message) and the exchanges of
    a run in time on ``graph``, with ``fuse_cfg.loss`` applied (:func:`drop_messages`)."""
    duration = max((end_ns - start_ns) / 1e9, 1e-3) if start_ns is not None else 1e-3
    events = spec.build(
        graph, duration_s=duration, seed=fuse_cfg.seed, directions=fuse_cfg.directions
    )
    return duration, drop_messages(events, fuse_cfg.loss, fuse_cfg.seed)


def run_schedule(
    fuse_cfg, agents: list[str], start_ns: int | None, end_ns: int | None
) -> tuple[Graph, float, list[Exchange]]:
    """The graph of a run in time on ``agents`` (names), the mission's length and its
    exchanges (:func:`mission_events`), all from ``fuse_cfg`` and the bags' first and last
    message."""
    graph = make_graph(fuse_cfg.topology, len(agents), seed=fuse_cfg.seed, names=agents)
    duration, events = mission_events(
        parse_schedule(fuse_cfg.schedule), graph, fuse_cfg, start_ns, end_ns
    )
    return graph, duration, events


def periodic(
    graph,
    *,
    period_s: float,
    duration_s: float,
    start_s: float | None = None,
    directions: str = "both",
) -> list[Exchange]:
    """Every link fires every ``period_s`` seconds.

    Rounds happen at ``start_s + k * period_s`` for every k >= 0 with a time <= ``duration_s``;
    ``start_s`` defaults to ``period_s`` (no exchange of empty maps at t = 0), which gives
    ``floor(duration_s / period_s)`` rounds. Within a round the links fire in sorted edge order.
    """
    period_s = _positive("period_s", period_s)
    duration_s = _non_negative("duration_s", duration_s)
    start_s = period_s if start_s is None else _non_negative("start_s", start_s)
    _check_directions(directions)
    if start_s > duration_s:
        return []
    per_round = len(graph.edges) * (2 if directions == "both" else 1)
    _check_count(
        f"periodic:{period_s:g} over {duration_s:g} s on {len(graph.edges)} link(s)",
        ((duration_s - start_s) / period_s + 1) * per_round,
    )
    events = []
    for k in range(math.floor((duration_s - start_s) / period_s + 1e-9) + 1):
        events.extend(_fire(graph.edges, start_s + k * period_s, k, directions))
    return events


def aperiodic(
    graph,
    *,
    mean_interval_s: float,
    duration_s: float,
    seed: int,
    directions: str = "both",
) -> list[Exchange]:
    """Every link fires at the times of its own Poisson process on ``(0, duration_s]``.

    The gaps between firings of a link are exponential with mean ``mean_interval_s``. The
    process of link ``(a, b)`` is seeded by ``(seed, a, b)`` only, so it does not change when
    other links are added or removed, and a shorter ``duration_s`` gives a prefix of a longer
    one. Events are sorted by time; ties go by sorted link order, then ``a -> b`` first.
    """
    mean_interval_s = _positive("mean_interval_s", mean_interval_s)
    duration_s = _non_negative("duration_s", duration_s)
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    _check_directions(directions)
    per_firing = 2 if directions == "both" else 1
    _check_count(
        f"aperiodic:{mean_interval_s:g} over {duration_s:g} s on {len(graph.edges)} link(s)",
        duration_s / mean_interval_s * len(graph.edges) * per_firing,
    )
    keyed = []
    for link, (a, b) in enumerate(graph.edges):
        times = _poisson_times(
            np.random.default_rng([int(seed), a, b]), mean_interval_s, duration_s
        )
        for k, t in enumerate(times):
            for order, ex in enumerate(_fire([(a, b)], t, k, directions)):
                keyed.append(((t, link, order), ex))
    keyed.sort(key=lambda item: item[0])
    return [ex for _, ex in keyed]


def rounds(graph, n_rounds: int, directions: str = "both") -> list[list[Exchange]]:
    """``n_rounds`` synchronous rounds for fusing finished maps (``time_s`` = round index 0, 1, ...).

    Double buffering: in a round every agent receives each neighbour's map as it was at the
    START of that round, so the order of events inside a round does not matter, and after R
    rounds information has travelled at most R hops. Apply a round by fusing copies of the maps
    taken before the round, not the maps being updated.
    """
    if isinstance(n_rounds, bool) or not isinstance(n_rounds, (int, np.integer)) or n_rounds < 0:
        raise ValueError(f"n_rounds must be a non-negative integer, got {n_rounds!r}")
    _check_directions(directions)
    _check_count(
        f"rounds:{int(n_rounds)} on {len(graph.edges)} link(s)",
        int(n_rounds) * len(graph.edges) * (2 if directions == "both" else 1),
    )
    return [_fire(graph.edges, float(r), r, directions) for r in range(int(n_rounds))]


@dataclass(frozen=True)
class ScheduleSpec:
    """A parsed ``--schedule`` string: ``kind`` is periodic, aperiodic or rounds; ``value`` the
    period (s), the mean interval (s) or the number of rounds."""

    kind: str
    value: float

    def build(
        self, graph, *, duration_s: float | None = None, seed: int = 0, directions: str = "both"
    ) -> list[Exchange]:
        """The events for ``graph``; ``rounds`` come flattened (``time_s`` = round index) and
        ignore ``duration_s``, which the other kinds need."""
        if self.kind != "rounds" and duration_s is None:
            raise ValueError(f"a {self.kind} schedule needs duration_s (the mission length)")
        if self.kind == "periodic":
            return periodic(
                graph, period_s=self.value, duration_s=duration_s, directions=directions
            )
        if self.kind == "aperiodic":
            return aperiodic(
                graph,
                mean_interval_s=self.value,
                duration_s=duration_s,
                seed=seed,
                directions=directions,
            )
        return [ex for rnd in rounds(graph, int(self.value), directions) for ex in rnd]


def parse_schedule(spec: str) -> ScheduleSpec:
    """Parse ``periodic:10`` (every 10 s), ``aperiodic:15`` (15 s mean gap) or ``rounds:3``."""
    text = str(spec).strip()
    kind, sep, param = (s.strip() for s in text.partition(":"))
    kind = kind.lower()
    valid = f"valid: {', '.join(SCHEDULE_KINDS)} (e.g. periodic:10)"
    if kind not in ("periodic", "aperiodic", "rounds"):
        raise ValueError(f"unknown schedule {text!r}; {valid}")
    if not sep or not param:
        raise ValueError(
            f"schedule {kind!r} needs a value, e.g. {kind}:{3 if kind == 'rounds' else 10}"
        )
    if kind == "rounds":
        if not re.fullmatch(r"\d+", param) or int(param) < 1:
            raise ValueError(f"rounds:R needs a whole number of rounds >= 1, got {text!r}")
        return ScheduleSpec(kind, float(int(param)))
    try:
        value = float(param)
    except ValueError:
        raise ValueError(f"{kind}:SECONDS needs a number of seconds, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{kind}:SECONDS needs a positive, finite number of seconds, got {text!r}")
    return ScheduleSpec(kind, value)


def _fire(edges, time_s: float, k: int, directions: str) -> list[Exchange]:
    """Events of the k-th firing (0-based) of each link in ``edges`` at ``time_s``."""
    t = float(time_s)
    out = []
    for a, b in edges:
        if directions == "both":
            out += [Exchange(t, a, b), Exchange(t, b, a)]
        else:
            out.append(Exchange(t, a, b) if k % 2 == 0 else Exchange(t, b, a))
    return out


def _poisson_times(rng: np.random.Generator, mean_s: float, duration_s: float) -> list[float]:
    times: list[float] = []
    t = 0.0
    batch = max(16, int(1.2 * duration_s / mean_s) + 16)
    while True:
        for gap in rng.exponential(mean_s, batch).tolist():
            t += gap
            if t > duration_s:
                return times
            times.append(t)


def _check_directions(directions: str) -> None:
    if directions not in DIRECTIONS:
        raise ValueError(f"directions must be one of {', '.join(DIRECTIONS)}, got {directions!r}")


def _positive(what: str, value: float) -> float:
    value = _number(what, value)
    if value <= 0:
        raise ValueError(f"{what} must be > 0, got {value}")
    return value


def _non_negative(what: str, value: float) -> float:
    value = _number(what, value)
    if value < 0:
        raise ValueError(f"{what} must be >= 0, got {value}")
    return value


def _number(what: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{what} must be a number of seconds, got {value!r}")
    if not math.isfinite(value):
        raise ValueError(f"{what} must be finite, got {value}")
    return float(value)
