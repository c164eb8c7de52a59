"""Agents' maps on a network: message delivery, fusion in place and traffic, per rule."""

from __future__ import annotations

import threading
import time
from collections import defaultdict
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Optional, Sequence

from ..config import CHANNEL_FILTER, FuseConfig
from ..maps.infoloss import InfoLossMap
from ..maps.occupancy import OccupancyMap
from ..maps.tree_fusion import exchange_maps, fuse_into
from ..threads import thread_map
from .agent_frames import AgentFrames
from .results import FusionEvent, Traffic, rule_time_part
from .schedule import Exchange


def message_bytes(m: OccupancyMap) -> int:
    """Size of a map message: OctoMap's full stream, 4-byte log-odds + 1 child byte per node."""
    return 5 * m.num_nodes



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
        #: seconds per part (summed over threads; wall time for `total` and the `(wall)`
        #: parts), added to through :meth:`add_time` while the run goes
        self.timings: dict[str, float] = defaultdict(float)
        self._clock = threading.Lock()
        self.threads = threads
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
        """The agents' maps per rule as scored and written (:meth:`scored_maps`), and the
        channel filter's unclamped maps."""
        return {r: self.scored_maps(r, self.threads) for r in self.rules}, self.unclamped_maps()

    def unclamped_maps(self) -> dict[str, OccupancyMap]:
        """The channel filter's maps as fused (unclamped), or none without it."""
        return dict(self.fused[CHANNEL_FILTER]) if self.cf is not None else {}

    def scored_maps(self, rule: str, threads: int = 1) -> dict[str, OccupancyMap]:
        """The agents' maps of ``rule`` as scored and written: the maps themselves, or the
        channel filter's clamped copies (made on ``threads`` threads)."""
        if rule != CHANNEL_FILTER:
            return self.fused[rule]
        from .channel_filter import clamped

        exact = self.fused[CHANNEL_FILTER]
        return dict(zip(exact, thread_map(clamped, exact.values(), threads)))

    def memory(self) -> dict[str, dict[str, dict[str, int]]]:
        """Per rule and agent: bytes of the map and of the per-link state (each map measured
        once, on the network's threads)."""
        held = {}  # (rule, agent) -> the map, the per-link maps
        for r in self.rules:
            for a in self.agents:
                if r == CHANNEL_FILTER:
                    links = self.cf.link_maps(a)
                else:
                    links = [m for (rr, s, _), m in self.sent_snapshot.items()
                             if rr == r and s == a]
                    links += [m for (rr, s, _), pend in self._pending.items()
                              if rr == r and s == a for m in pend.values()]
                held[r, a] = (self.fused[r][a], links)
        maps = list({id(m): m for own, links in held.values() for m in (own, *links)}.values())
        size = dict(zip(map(id, maps), thread_map(lambda m: m.memory_bytes, maps, self.threads)))
        return {r: {a: {"map": size[id(held[r, a][0])],
                        "links": sum(size[id(m)] for m in held[r, a][1])}
                    for a in self.agents} for r in self.rules}

    def exchange(self, group: Sequence[Exchange]) -> None:
        """Deliver simultaneous messages, first in, first out; the rules run in parallel."""
        t0 = time.perf_counter()
        self.align(group)
        if self.pool is None or len(self.rules) == 1:
            for r in self.rules:
                self.exchange_rule(r, group)
        else:
            # the slowest rules first (as they were in the last group): the threads finish
            # the group together
            order = sorted(self.rules, key=lambda r: -self._rule_seconds[r])
            list(self.pool.map(lambda r: self.exchange_rule(r, group), order))
        self.add_time("exchange + fusion (wall)", t0)

    def align(self, group: Sequence[Exchange]) -> None:
        """Align the links of a group's messages that have not aligned yet (with
        ``fuse.align``), on the first rule's maps; before any rule exchanges the group."""
        self.frames.align_links([(self.agents[e.sender], self.agents[e.receiver], e.lost, e.time_s)
                                 for e in group], self.fused[self.rules[0]])

    def exchange_rule(self, r: str, group: Sequence[Exchange]) -> None:
        """One rule's messages of a group (after :meth:`align`); rules may run in parallel."""
        t0 = time.perf_counter()
        self._exchange_rule(r, group)
        self._rule_seconds[r] = self.add_time(rule_time_part(r), t0)

    def add_time(self, part: str, since: float) -> float:
        """Adds the seconds from ``since`` (``time.perf_counter()``) to now to ``part`` of
        :attr:`timings` and returns them; safe on any thread (the rules' exchanges run in
        parallel)."""
        seconds = time.perf_counter() - since
        with self._clock:
            self.timings[part] += seconds
        return seconds

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown()
            self.pool = None

    def _loss(self, r: str, agent: str) -> InfoLossMap:
        """The loss map of ``agent``'s fusions by rule ``r``, carried by its fused map."""
        loss = self.loss[r].get(agent)
        if loss is None:
            loss = self.loss[r][agent] = InfoLossMap.carried_by(self.fused[r][agent])
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
        self.add_time("exchange", t0)
        t1 = time.perf_counter()
        for e, msg in msgs:
            self._count(r, msg.sender, msg.receiver, msg.payload, lost=e.lost)
            if not e.lost:
                cf.deliver(msg)
                self.traffic[r].fusions.append(
                    FusionEvent(e.time_s, r, msg.sender, msg.receiver, None, None))
        self.add_time("fusion", t1)

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
                loss_d = self._loss(r, d)
                loss_s = self._loss(r, s)
                before = _loss_totals(loss_d), _loss_totals(loss_s)
                # the walk counts the leaves each map had: the two messages' voxels
                n_d, n_s = exchange_maps(maps[d], maps[s], rule=r, unknown=cfg.unknown,
                                         loss_a=loss_d, loss_b=loss_s)
                self.add_time("fusion", t1)
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
                self.add_time("exchange", t0)
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
                self.add_time("exchange", t0)
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
            self.add_time("exchange", t0)
            t1 = time.perf_counter()
            loss_d = self._loss(r, d)
            before = _loss_totals(loss_d)
            fuse_into(maps[d], m, rule=r, unknown=cfg.unknown, loss=loss_d,
                      threads=self.fuse_threads)
            self.add_time("fusion", t1)
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
