"""Agents' maps on a network: message delivery, fusion in place and traffic, per rule."""

from __future__ import annotations

import time
from collections import defaultdict
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import Callable, Optional, Sequence

from ..config import CHANNEL_FILTER, FuseConfig
from ..maps.compare import Score, compare_many, score
from ..maps.infoloss import InfoLossMap
from ..maps.occupancy import OccupancyMap, exchange_maps, fuse_into
from ..threads import thread_map
from .agent_frames import AgentFrames, moved
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
    lost: int = 0  #: messages sent that never arrived (counted in ``sent``, not ``received``)
    fusions: list["FusionEvent"] = field(default_factory=list)  #: messages fused, in order


@dataclass(frozen=True)
class FusionEvent:
    """One message fused: when, by which rule, from whom into whom, the voxels fused and the
    information loss summed over them (nats; None where the loss is not kept)."""

    time_s: float
    rule: str
    sender: str
    receiver: str
    voxels: Optional[int]
    loss: Optional[float]

    @property
    def mean_loss(self) -> Optional[float]:
        """Loss per fused voxel (None without loss or voxels)."""
        return self.loss / self.voxels if self.loss is not None and self.voxels else None

    def to_dict(self) -> dict:
        return {"t": self.time_s, "rule": self.rule, "sender": self.sender,
                "receiver": self.receiver, "voxels": self.voxels, "loss": self.loss,
                "mean_loss": self.mean_loss}


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
    #: rule -> agent -> {"map": bytes of the agent's map, "links": bytes of its per-link state
    #: (channel-filter: the neighbours' contributions; deltas: the maps they are taken against)}
    memory: dict[str, dict[str, dict[str, int]]] = field(default_factory=dict)
    #: the channel filter's links (agent index pairs) and its unclamped agent maps (``fused``
    #: holds them clamped, as scored and written)
    tree: Optional[tuple] = None
    unclamped: dict[str, OccupancyMap] = field(default_factory=dict)
    #: the centralized map without clamping (runs with the channel filter): the exact target
    central_unclamped: Optional[OccupancyMap] = None
    #: agent -> its map frame into the common frame (agents in the common frame left out),
    #: and per link the alignment on first contact (:mod:`octofuse.fusion.agent_frames`)
    frames: dict = field(default_factory=dict)
    alignment: list[dict] = field(default_factory=list)


class Network:
    """Per-rule agent maps, message exchange and fusion."""

    def __init__(self, agents, rules, fcfg: FuseConfig, make_map: Callable[[], OccupancyMap],
                 threads: int, tree: Optional[Sequence[tuple[int, int]]] = None,
                 frames: Optional[AgentFrames] = None):
        self.agents, self.rules, self.cfg = agents, rules, fcfg
        self.frames = frames or AgentFrames(agents)
        self.fused = {r: {a: make_map() for a in agents} for r in rules}
        self.loss: dict[str, dict[str, InfoLossMap]] = {r: {} for r in rules}
        self.traffic = {r: Traffic() for r in rules}
        self.sent_snapshot: dict[tuple, OccupancyMap] = {}  # (rule, sender, receiver) -> map
        self.timings: dict[str, float] = defaultdict(float)
        self.pool = ThreadPoolExecutor(max_workers=threads) if threads > 1 else None
        self.fuse_threads = max(1, threads // max(1, len(rules)))  # threads of one fuse_into
        self._rule_seconds: dict[str, float] = defaultdict(float)  # each rule's last exchange
        #: lossy links, deltas: (rule, sender, receiver) -> last seq sent / applied, and the
        #: snapshots sent but not yet acknowledged (a delta goes against the last acknowledged)
        self._seq: dict[tuple, int] = defaultdict(int)
        self._applied: dict[tuple, int] = defaultdict(int)
        self._pending: dict[tuple, dict[int, OccupancyMap]] = defaultdict(dict)
        self.tree = tuple(tree) if tree is not None else None
        self.cf = None
        if CHANNEL_FILTER in rules:
            from .channel_filter import ChannelFilter

            if tree is None:
                raise ValueError("the channel filter needs the links of a tree")
            self.cf = ChannelFilter(agents, self.fused[CHANNEL_FILTER], tree, delta=fcfg.delta,
                                    reliable=fcfg.loss == 0)

    def start_from(self, maps: dict[str, OccupancyMap]) -> None:
        """Every rule's agents start from copies of ``maps`` (finished maps)."""
        for r in self.rules:
            self.fused[r] = {a: m.copy() for a, m in maps.items()}  # fused in place
        if self.cf is not None:
            from .channel_filter import open_map

            self.cf.maps = self.fused[CHANNEL_FILTER]
            for m in self.cf.maps.values():
                open_map(m)

    def result_maps(self) -> tuple[dict[str, dict[str, OccupancyMap]], dict[str, OccupancyMap]]:
        """The agents' maps per rule as scored and written (the channel filter's clamped), and
        the channel filter's unclamped maps."""
        if self.cf is None:
            return self.fused, {}
        from .channel_filter import clamped

        exact = self.fused[CHANNEL_FILTER]
        return ({**self.fused, CHANNEL_FILTER: {a: clamped(m) for a, m in exact.items()}},
                dict(exact))

    def memory(self) -> dict[str, dict[str, dict[str, int]]]:
        """Per rule and agent: bytes of the map and of the per-link state."""
        out: dict[str, dict[str, dict[str, int]]] = {}
        for r in self.rules:
            out[r] = {}
            for a in self.agents:
                if r == CHANNEL_FILTER:
                    links = self.cf.link_memory(a)
                else:
                    links = sum(m.memory_bytes for (rr, s, _), m in self.sent_snapshot.items()
                                if rr == r and s == a)
                    links += sum(m.memory_bytes for (rr, s, _), pend in self._pending.items()
                                 if rr == r and s == a for m in pend.values())
                out[r][a] = {"map": self.fused[r][a].memory_bytes, "links": links}
        return out

    def exchange(self, group: Sequence[Exchange]) -> None:
        """Deliver simultaneous messages, first in, first out; the rules run in parallel."""
        t0 = time.perf_counter()
        self.frames.align_links([(self.agents[e.sender], self.agents[e.receiver], e.lost, e.time_s)
                                 for e in group], self.fused[self.rules[0]])
        if self.pool is None or len(self.rules) == 1:
            for r in self.rules:
                self._exchange_rule(r, group)
        else:
            # the slowest rules first (as they were in the last group): the threads finish
            # the group together
            order = sorted(self.rules, key=lambda r: -self._rule_seconds[r])
            list(self.pool.map(lambda r: self._timed_exchange(r, group), order))
        self.timings["exchange + fusion (wall)"] += time.perf_counter() - t0

    def _timed_exchange(self, r: str, group: Sequence[Exchange]) -> None:
        t0 = time.perf_counter()
        self._exchange_rule(r, group)
        self._rule_seconds[r] = time.perf_counter() - t0

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown()
            self.pool = None

    def _loss(self, r: str, agent: str, resolution: float) -> InfoLossMap:
        loss = self.loss[r].get(agent)
        if loss is None:
            loss = self.loss[r][agent] = InfoLossMap(resolution)
        return loss

    def _count(self, r: str, s: str, d: str, m: OccupancyMap, lost: bool = False,
               leaves: Optional[dict] = None) -> None:
        """Counts a message ``m`` from ``s`` to ``d``. ``leaves``: leaf counts of the maps
        sent so far in the group (a sender's unchanged map sent again is not counted again)."""
        if leaves is None:
            n = m.num_leaves
        else:  # keyed by identity, the map kept alive so that its id is not reused
            n = leaves.get(id(m), (None, None))[1]
            if n is None:
                n = m.num_leaves
                leaves[id(m)] = (m, n)
        self._count_sizes(r, s, d, message_bytes(m), n, lost)

    def _count_sizes(self, r: str, s: str, d: str, nbytes: int, n_leaves: int,
                     lost: bool = False) -> None:
        """Counts a message of ``nbytes`` (OctoMap's stream) and ``n_leaves`` voxels."""
        tr = self.traffic[r]
        tr.sent[s] += nbytes
        if lost:
            tr.lost += 1
        else:
            tr.received[d] += nbytes
        tr.sent_32b[s] += 32 * n_leaves
        tr.messages += 1

    def _exchange_cf(self, group: Sequence[Exchange]) -> None:
        """The channel filter's messages of a group, on its tree's links only: every message
        is composed from its sender's state at the start of the group, then delivered in
        order (lost ones are counted as sent and dropped)."""
        cf, r = self.cf, CHANNEL_FILTER
        t0 = time.perf_counter()
        msgs = [(e, cf.compose(self.agents[e.sender], self.agents[e.receiver]))
                for e in group if cf.uses(e.sender, e.receiver)]
        t1 = time.perf_counter()
        self.timings["exchange"] += t1 - t0
        for e, msg in msgs:
            self._count(r, msg.sender, msg.receiver, msg.payload, lost=e.lost)
            if not e.lost:
                cf.deliver(msg)
                self.traffic[r].fusions.append(
                    FusionEvent(e.time_s, r, msg.sender, msg.receiver, None, None))
        self.timings["fusion"] += time.perf_counter() - t1

    def _exchange_rule(self, r: str, group: Sequence[Exchange]) -> None:
        """One rule's maps. A message carries its sender's map as it was when the group
        started: fusion is in place, so an agent that still has to send after it received is
        copied first. A two-way exchange of agents not yet touched in the group is one walk
        (:func:`octofuse.maps.exchange_maps`), without copies."""
        if r == CHANNEL_FILTER:
            self._exchange_cf(group)
            return
        maps, cfg = self.fused[r], self.cfg
        reliable = cfg.loss == 0
        ev_names = [(self.agents[e.sender], self.agents[e.receiver]) for e in group]
        sends_left: dict[str, int] = defaultdict(int)
        for s, _ in ev_names:
            sends_left[s] += 1
        start: dict[str, OccupancyMap] = {}  # start-of-group copies of modified senders
        modified: set[str] = set()
        leaves: dict = {}  # leaf counts of the maps sent, while they are unchanged

        def before_modifying(x: str) -> None:
            if sends_left[x] > 0 and x not in start and x not in modified:
                start[x] = maps[x].copy()

        k = 0
        while k < len(ev_names):
            s, d = ev_names[k]
            two_way = (not cfg.delta and k + 1 < len(ev_names) and ev_names[k + 1] == (d, s)
                       and s not in modified and d not in modified
                       and self.frames.plain(s, d) and self.frames.plain(d, s)
                       and not group[k].lost and not group[k + 1].lost)
            if two_way:
                sends_left[s] -= 1
                sends_left[d] -= 1
                sizes = message_bytes(maps[s]), message_bytes(maps[d])
                before_modifying(s)
                before_modifying(d)
                t1 = time.perf_counter()
                loss_d = self._loss(r, d, maps[d].resolution)
                loss_s = self._loss(r, s, maps[s].resolution)
                before = _loss_totals(loss_d), _loss_totals(loss_s)
                # the walk counts the leaves each map had: the two messages' voxels
                n_d, n_s = exchange_maps(maps[d], maps[s], rule=r, unknown=cfg.unknown,
                                         loss_a=loss_d, loss_b=loss_s)
                self.timings["fusion"] += time.perf_counter() - t1
                self._count_sizes(r, s, d, sizes[0], n_s)
                self._count_sizes(r, d, s, sizes[1], n_d)
                for x, n in ((s, n_s), (d, n_d)):  # a later message of x sends its copy
                    if x in start:
                        leaves[id(start[x])] = (start[x], n)
                self._record(r, group[k], loss_d, before[0])
                self._record(r, group[k + 1], loss_s, before[1])
                modified |= {s, d}
                k += 2
                continue
            t0 = time.perf_counter()
            state = start.get(s, maps[s]) if s in modified else maps[s]
            m = state
            if not self.frames.aligned(s, d):  # sent, but no transform to fuse it with yet
                sends_left[s] -= 1
                self._count(r, s, d, m, lost=group[k].lost, leaves=leaves)
                self.timings["exchange"] += time.perf_counter() - t0
                k += 1
                continue
            seq = ack = 0
            if cfg.delta:
                prev = self.sent_snapshot.get((r, s, d))
                snapshot = state.copy()
                if prev is not None:
                    m = snapshot.changed_since(prev)
                else:
                    m = snapshot
                if reliable:
                    self.sent_snapshot[(r, s, d)] = snapshot
                else:  # against the last acknowledged snapshot until this one is
                    seq = self._seq[(r, s, d)] = self._seq[(r, s, d)] + 1
                    self._pending[(r, s, d)][seq] = snapshot
                    ack = self._applied[(r, d, s)]
            sends_left[s] -= 1
            if group[k].lost:
                self._count(r, s, d, m, lost=True, leaves=None if cfg.delta else leaves)
                self.timings["exchange"] += time.perf_counter() - t0
                k += 1
                continue
            if seq:
                self._applied[(r, s, d)] = seq
                pend = self._pending.get((r, d, s))
                if pend and ack in pend:
                    self.sent_snapshot[(r, d, s)] = pend[ack]
                    for q in [q for q in pend if q <= ack]:
                        del pend[q]
            before_modifying(d)
            self._count(r, s, d, m, leaves=None if cfg.delta else leaves)
            m = self.frames.to_receiver(s, d, m, maps[d].resolution)
            t1 = time.perf_counter()
            self.timings["exchange"] += t1 - t0
            loss_d = self._loss(r, d, m.resolution)
            before = _loss_totals(loss_d)
            fuse_into(maps[d], m, rule=r, unknown=cfg.unknown, loss=loss_d,
                      threads=self.fuse_threads)
            self.timings["fusion"] += time.perf_counter() - t1
            self._record(r, group[k], loss_d, before)
            modified.add(d)
            k += 1

    def _record(self, r: str, e: Exchange, loss: InfoLossMap, before: tuple) -> None:
        """Append the fusion of message ``e`` (its loss: ``loss`` less its totals ``before``)."""
        voxels, total = _loss_totals(loss)
        self.traffic[r].fusions.append(FusionEvent(
            e.time_s, r, self.agents[e.sender], self.agents[e.receiver], voxels - before[0],
            max(0.0, total - before[1])))

    def loss_map(self, rule: str, agent: str, resolution: float) -> InfoLossMap:
        return self.loss[rule].get(agent) or InfoLossMap(resolution)


def _loss_totals(loss: InfoLossMap) -> tuple[int, float]:
    """Voxels fused and information loss summed over them (nats)."""
    return loss.voxels_fused, float(loss.loss_sum)


def score_result(res: SimResult, tol: float, truth=None, threads: int = 1,
                 local: bool = True, compared: Optional[dict] = None
                 ) -> dict[str, dict[str, Score]]:
    """Scores of every agent for every rule, and (``local``) of the local-only maps (the
    floor). ``compared``: (rule, agent) -> the comparison of those final maps with the
    centralized map, where it was taken already."""
    jobs = ([(LOCAL, a) for a in res.agents] if local else []) + \
        [(r, a) for r in res.rules for a in res.agents]
    agent_map = lambda r, a: res.local[a] if r == LOCAL else res.fused[r][a]  # noqa: E731
    # maps in the common frame: compared in one walk of the centralized map
    compared = dict(compared or {})
    as_is = [j for j in jobs if res.frames.get(j[1]) is None and j not in compared]
    compared.update(zip(as_is, compare_many(res.central, [agent_map(*j) for j in as_is], tol,
                                            threads)))

    def one(job):
        r, a = job
        m = moved(agent_map(r, a), res.frames.get(a))  # other frames: scored in the common one
        c = compared.get(job)
        if r == LOCAL:
            return score(m, res.central, tol=tol, truth=truth, compared=c)
        tr = res.traffic[r]
        loss = None if r == CHANNEL_FILTER else res.loss[r][a]  # exact: no WEP loss
        return score(m, res.central, tol=tol, loss=loss, truth=truth, compared=c,
                     bytes_sent=tr.sent[a], bytes_received=tr.received[a],
                     bytes_sent_32b=tr.sent_32b[a])

    out: dict[str, dict[str, Score]] = {}
    for (r, a), s in zip(jobs, thread_map(one, jobs, threads)):
        out.setdefault(r, {})[a] = s
    return out


def rule_groups(fuse_cfg: FuseConfig, size: int) -> list[list[str]]:
    """``fuse_cfg.rules`` in groups of at most ``size`` (0: one group), to run one group after
    the other: the rules' maps never meet, so each rule's result is that of the run with every
    rule. Robust fusion (its vote is taken once, before the rules' exchanges) and alignment on
    first contact (on the first rule's maps) put every rule in one group."""
    rules = list(fuse_cfg.rules)
    if size <= 0 or fuse_cfg.robust.enabled or fuse_cfg.align != "off":
        size = len(rules)
    return [rules[k:k + size] for k in range(0, len(rules), size)]


def merge_rule_results(parts: Sequence[SimResult]) -> SimResult:
    """One result from the results of the same run with different rules (e.g.
    :func:`octofuse.fusion.rounds.fuse_finished_in_rule_groups`), without the rules' maps (``fused``,
    ``loss`` and ``unclamped`` are left empty: written and freed by the caller). Times add up."""
    first = parts[0]
    timings: dict[str, float] = defaultdict(float)
    for p in parts:
        for k, v in p.timings.items():
            timings[k] += v
    scores: dict[str, dict[str, Score]] = {}
    for p in parts:
        scores.update(p.scores)
    tree = next((p.tree for p in parts if p.tree is not None), None)
    exact = next((p.central_unclamped for p in parts if p.central_unclamped is not None), None)
    return replace(
        first, rules=[r for p in parts for r in p.rules], fused={}, loss={},
        traffic={r: p.traffic[r] for p in parts for r in p.rules},
        # in time order, each time's samples in rule order: as in the run with every rule
        timeline=sorted((s for p in parts for s in p.timeline), key=lambda s: s["t"]),
        timings=timings, scores=scores,
        memory={r: m for p in parts for r, m in p.memory.items()}, tree=tree, unclamped={},
        central_unclamped=exact)
