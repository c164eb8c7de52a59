"""Map fusion across a communication graph, in time (``run``) or in rounds (``fuse``)."""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from collections import defaultdict
from dataclasses import dataclass, field
from itertools import groupby
from typing import Callable, Optional, Sequence

from . import _core
from .build import insert_scans, new_map, prefetch
from .config import BuildConfig, FuseConfig
from .graph import Graph, make_graph
from .ingest import ScanSource
from .maps import InfoLossMap, OccupancyMap, exchange_maps, fuse_into
from .metrics import Score, compare, score
from .rules import rule_index
from .schedule import Exchange, parse_schedule

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


class _Network:
    """Per-rule agent maps, message exchange and fusion."""

    def __init__(self, agents, rules, fcfg: FuseConfig, make_map: Callable[[], OccupancyMap],
                 threads: int = 2):
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
                    m = OccupancyMap._wrap(_core._changed_voxels(snapshot._m, prev._m))
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


def _check_rules(rules: Sequence[str]) -> list[str]:
    for r in rules:
        rule_index(r)
    if not rules:
        raise ValueError("no fusion rule given")
    return list(dict.fromkeys(rules))


def simulate(build_cfg: BuildConfig, fuse_cfg: FuseConfig, rules: Sequence[str] | None = None, *,
             samples: int = 12, truth=None,
             progress: Optional[Callable[[int], None]] = None) -> SimResult:
    """Run the network in time: every agent maps its own scans in time order and, at each
    communication event, fuses the received map into its own (first in, first out), then
    keeps mapping on the fused map. All rules (and the local-only and centralized maps) run
    in one pass over the scans: each scan's rays are cast once and applied to every map.

    ``fuse_cfg.schedule`` is ``aperiodic:MEAN_S`` or ``periodic:PERIOD_S`` over the bags'
    duration. The result holds the final maps, accumulated losses, traffic, a timeline of
    KL to the centralized map (``samples`` points in time) and the scores.
    """
    rules = _check_rules(rules or [fuse_cfg.rule])
    spec = parse_schedule(fuse_cfg.schedule)
    if spec.kind == "rounds":
        raise ValueError("schedule 'rounds:N' fuses finished maps: use `octofuse fuse`; "
                         "`run` takes aperiodic:MEAN_S or periodic:PERIOD_S")
    t_all = time.perf_counter()
    with ScanSource(build_cfg) as src:
        agents = [a.name for a in src.agents]
        graph = make_graph(fuse_cfg.topology, len(agents), seed=fuse_cfg.seed, names=agents)
        start, end = src.bags.start_ns, src.bags.end_ns
        duration = max((end - start) / 1e9, 1e-3) if start is not None else 1e-3
        events = spec.build(graph, duration_s=duration, seed=fuse_cfg.seed,
                            directions=fuse_cfg.directions)
        mk = lambda: new_map(build_cfg.map)  # noqa: E731
        net = _Network(agents, rules, fuse_cfg, mk, build_cfg.threads)
        local = {a: mk() for a in agents}
        central = mk()
        sample_times = [duration * (k + 1) / samples for k in range(samples)] if samples else []
        timeline: list[dict] = []
        timings = net.timings

        def sample(t):
            t0 = time.perf_counter()
            jobs = [(r, a, maps[a]) for r, maps in [(LOCAL, local)] + [(r, net.fused[r]) for r in rules]
                    for a in agents]
            run = net.pool.map if net.pool else map
            tol = fuse_cfg.overconfidence_tol
            for (r, a, _), s in zip(jobs, run(lambda j: compare(central, j[2], tol), jobs)):
                timeline.append({"t": t, "rule": r, "agent": a, "kl": s.kl_mean,
                                 "overconfidence": s.overconfidence, "coverage": s.coverage})
            timings["scoring"] += time.perf_counter() - t0

        # exchange groups and KL samples, merged in time order: (time, kind, payload)
        timed = [(g[0].time_s, 0, g) for g in (list(g) for _, g in groupby(events, key=lambda e: e.time_s))]
        timed += [(t, 1, None) for t in sample_times]
        timed.sort(key=lambda x: (x[0], x[1]))
        next_i = 0

        def flush(batch):
            if not batch:
                return
            t0 = time.perf_counter()
            targets = [[net.fused[r][agents[s.agent]] for r in rules]
                       + [local[agents[s.agent]], central] for s in batch]
            insert_scans(batch, targets, build_cfg.threads)
            timings["insertion"] += time.perf_counter() - t0
            if progress:
                progress(len(batch))

        def advance(until: float) -> None:
            """Exchanges and samples before ``until`` (a scan stamped exactly at an exchange
            time is inserted before it)."""
            nonlocal next_i
            while next_i < len(timed) and timed[next_i][0] < until:
                t, kind, group = timed[next_i]
                if kind == 0:
                    net.exchange(group)
                else:
                    sample(t)
                next_i += 1

        batch: list = []
        for scan in prefetch(src.scans()):
            t = (scan.stamp_ns - start) / 1e9
            if next_i < len(timed) and timed[next_i][0] < t:
                flush(batch)
                batch = []
                advance(t)
            batch.append(scan)
            if len(batch) >= build_cfg.batch_size:
                flush(batch)
                batch = []
        flush(batch)
        advance(float("inf"))
        net.close()
        src.check_placed()
        stats = src.stats
    res = SimResult(agents, rules, graph, events, central, local, net.fused,
                    {r: {a: net.loss_map(r, a, build_cfg.map.resolution) for a in agents}
                     for r in rules}, net.traffic, timeline, timings, build_stats=stats)
    t0 = time.perf_counter()
    res.scores = score_result(res, fuse_cfg.overconfidence_tol, truth)
    timings["scoring"] += time.perf_counter() - t0
    timings["total"] = time.perf_counter() - t_all
    return res


def fuse_finished(maps: dict[str, OccupancyMap], central: Optional[OccupancyMap],
                  fuse_cfg: FuseConfig, rules: Sequence[str] | None = None, *,
                  n_rounds: int = 3, truth=None) -> SimResult:
    """Fuse finished maps for ``n_rounds`` synchronous rounds over the graph: in a round
    every agent receives each neighbour's map as it was at the start of the round."""
    from .schedule import rounds as make_rounds

    rules = _check_rules(rules or [fuse_cfg.rule])
    agents = list(maps)
    if len(agents) < 2:
        raise ValueError(f"fusion needs at least 2 agent maps, got {len(agents)}")
    graph = make_graph(fuse_cfg.topology, len(agents), seed=fuse_cfg.seed, names=agents)
    rounds = make_rounds(graph, n_rounds, directions=fuse_cfg.directions)
    first = next(iter(maps.values()))
    net = _Network(agents, rules, fuse_cfg, lambda: OccupancyMap(first.resolution))
    for r in rules:
        net.fused[r] = {a: m.copy() for a, m in maps.items()}  # fused in place
    t_all = time.perf_counter()
    for rnd in rounds:
        net.exchange(rnd)  # double-buffered: contents taken before fusing
    net.close()
    res = SimResult(agents, rules, graph, [e for r in rounds for e in r],
                    central, dict(maps), net.fused,
                    {r: {a: net.loss_map(r, a, first.resolution) for a in agents} for r in rules},
                    net.traffic, [], net.timings)
    if central is not None:
        t0 = time.perf_counter()
        res.scores = score_result(res, fuse_cfg.overconfidence_tol, truth)
        res.timings["scoring"] += time.perf_counter() - t0
    res.timings["total"] = time.perf_counter() - t_all
    return res


def score_result(res: SimResult, tol: float, truth=None, threads: int = 2) -> dict[str, dict[str, Score]]:
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
