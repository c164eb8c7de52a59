"""Agents' maps on a network: message delivery, fusion in place and traffic, per rule."""

from __future__ import annotations

import time
from collections import defaultdict
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Callable, Optional, Sequence

from ..config import FuseConfig
from ..maps.compare import Score, score
from ..maps.infoloss import InfoLossMap
from ..maps.occupancy import OccupancyMap, exchange_maps, fuse_into
from .graph import Graph
from .schedule import Exchange

LOCAL = "local-only"


def message_bytes(m: OccupancyMap) -> int:
    """Size of a map message: OctoMap's full stream, 4-byte log-odds + 1 child byte per node."""
    return 5 * m.num_nodes


@dataclass
class Traffic:
    sent: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    received: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    sent_32b: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    messages: int = 0


@dataclass
class SimResult:
    """Everything a fusion run produced."""

    agents: list[str]
    rules: list[str]
    graph: Graph
    events: list[Exchange]
    central: Optional[OccupancyMap]  #: None when fusing finished maps without one
    local: dict[str, OccupancyMap]
    fused: dict[str, dict[str, OccupancyMap]]  #: rule -> agent -> map
    loss: dict[str, dict[str, InfoLossMap]]  #: rule -> agent -> accumulated loss
    traffic: dict[str, Traffic]  #: rule -> traffic
    timeline: list[dict] = field(default_factory=list)  #: samples {t, rule, agent, kl, overconfidence}
    timings: dict[str, float] = field(default_factory=lambda: defaultdict(float))
    scores: dict[str, dict[str, Score]] = field(default_factory=dict)  #: rule|local-only -> agent
    build_stats: list = field(default_factory=list)
    build_notes: list[str] = field(default_factory=list)  #: skipped transforms, dropped points
    #: robust fusion: the robots voted out (their messages were not fused) and the vote
    #: (:class:`octofuse.fusion.robust.RobustOutcome`, None without robust fusion)
    excluded: list[str] = field(default_factory=list)
    robust: Optional[object] = None


class Network:
    """Per-rule agent maps, message exchange and fusion."""

    def __init__(self, agents, rules, fcfg: FuseConfig, make_map: Callable[[], OccupancyMap],
                 threads: int):
        self.agents, self.rules, self.cfg = agents, rules, fcfg
        self.fused = {r: {a: make_map() for a in agents} for r in rules}
        self.loss: dict[str, dict[str, InfoLossMap]] = {r: {} for r in rules}
        self.traffic = {r: Traffic() for r in rules}
        self.sent_snapshot: dict[tuple, OccupancyMap] = {}  # (rule, sender, receiver) -> map
        self.timings: dict[str, float] = defaultdict(float)
        self.pool = ThreadPoolExecutor(max_workers=threads) if threads > 1 else None

    def exchange(self, group: Sequence[Exchange]) -> None:
        """Deliver simultaneous messages, first in, first out; the rules run in parallel."""
        t0 = time.perf_counter()
        if self.pool is None or len(self.rules) == 1:
            for r in self.rules:
                self._exchange_rule(r, group)
        else:
            list(self.pool.map(lambda r: self._exchange_rule(r, group), self.rules))
        self.timings["exchange + fusion (wall)"] += time.perf_counter() - t0

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown()
            self.pool = None

    def _loss(self, r: str, agent: str, resolution: float) -> InfoLossMap:
        loss = self.loss[r].get(agent)
        if loss is None:
            loss = self.loss[r][agent] = InfoLossMap(resolution)
        return loss

    def _count(self, r: str, s: str, d: str, m: OccupancyMap) -> None:
        tr = self.traffic[r]
        nbytes = message_bytes(m)
        tr.sent[s] += nbytes
        tr.received[d] += nbytes
        tr.sent_32b[s] += 32 * m.num_leaves
        tr.messages += 1

    def _exchange_rule(self, r: str, group: Sequence[Exchange]) -> None:
        """One rule's maps. A message carries its sender's map as it was when the group
        started: fusion is in place, so an agent that still has to send after it received is
        copied first. A two-way exchange of agents not yet touched in the group is one walk
        (:func:`octofuse.maps.exchange_maps`), without copies."""
        maps, cfg = self.fused[r], self.cfg
        ev_names = [(self.agents[e.sender], self.agents[e.receiver]) for e in group]
        sends_left: dict[str, int] = defaultdict(int)
        for s, _ in ev_names:
            sends_left[s] += 1
        start: dict[str, OccupancyMap] = {}  # start-of-group copies of modified senders
        modified: set[str] = set()

        def before_modifying(x: str) -> None:
            if sends_left[x] > 0 and x not in start and x not in modified:
                start[x] = maps[x].copy()

        k = 0
        while k < len(ev_names):
            s, d = ev_names[k]
            two_way = (not cfg.delta and k + 1 < len(ev_names) and ev_names[k + 1] == (d, s)
                       and s not in modified and d not in modified)
            if two_way:
                sends_left[s] -= 1
                sends_left[d] -= 1
                self._count(r, s, d, maps[s])
                self._count(r, d, s, maps[d])
                before_modifying(s)
                before_modifying(d)
                t1 = time.perf_counter()
                exchange_maps(maps[d], maps[s], rule=r, unknown=cfg.unknown,
                              loss_a=self._loss(r, d, maps[d].resolution),
                              loss_b=self._loss(r, s, maps[s].resolution))
                self.timings["fusion"] += time.perf_counter() - t1
                modified |= {s, d}
                k += 2
                continue
            t0 = time.perf_counter()
            state = start.get(s, maps[s]) if s in modified else maps[s]
            m = state
            if cfg.delta:
                prev = self.sent_snapshot.get((r, s, d))
                snapshot = state.copy()
                if prev is not None:
                    m = snapshot.changed_since(prev)
                else:
                    m = snapshot
                self.sent_snapshot[(r, s, d)] = snapshot
            sends_left[s] -= 1
            before_modifying(d)
            self._count(r, s, d, m)
            t1 = time.perf_counter()
            self.timings["exchange"] += t1 - t0
            fuse_into(maps[d], m, rule=r, unknown=cfg.unknown,
                      loss=self._loss(r, d, m.resolution))
            self.timings["fusion"] += time.perf_counter() - t1
            modified.add(d)
            k += 1

    def loss_map(self, rule: str, agent: str, resolution: float) -> InfoLossMap:
        return self.loss[rule].get(agent) or InfoLossMap(resolution)


def score_result(res: SimResult, tol: float, truth=None, threads: int = 1) -> dict[str, dict[str, Score]]:
    """Scores of every agent for every rule, and of the local-only maps (the floor)."""
    jobs = [(LOCAL, a) for a in res.agents] + [(r, a) for r in res.rules for a in res.agents]

    def one(job):
        r, a = job
        if r == LOCAL:
            return score(res.local[a], res.central, tol=tol, truth=truth)
        tr = res.traffic[r]
        return score(res.fused[r][a], res.central, tol=tol, loss=res.loss[r][a], truth=truth,
                     bytes_sent=tr.sent[a], bytes_received=tr.received[a],
                     bytes_sent_32b=tr.sent_32b[a])

    if threads > 1:
        with ThreadPoolExecutor(max_workers=threads) as pool:
            results = list(pool.map(one, jobs))
    else:
        results = [one(j) for j in jobs]
    out: dict[str, dict[str, Score]] = {}
    for (r, a), s in zip(jobs, results):
        out.setdefault(r, {})[a] = s
    return out
