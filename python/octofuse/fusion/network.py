"""The agents of one process, every rule's, exchanging groups of simultaneous messages."""

from __future__ import annotations

import threading
import time
from collections import defaultdict
from collections.abc import Callable, Sequence

from ..config import CHANNEL_FILTER, EXACT_MODES, FuseConfig
from ..maps.infoloss import InfoLossMap
from ..maps.occupancy import OccupancyMap
from ..rules import parse_unknown
from ..threads import ThreadBudget, budget_of
from .agent import Agent
from .agent_frames import AgentFrames
from .results import FusionEvent, Traffic, rule_time_part
from .schedule import Exchange


def message_bytes(m: OccupancyMap) -> int:
    """Size of a map message: OctoMap's full stream, 4-byte log-odds + 1 child byte per node."""
    return 5 * m.num_nodes


class Network:
    """Per rule, every robot's :class:`~.agent.Agent`, driven through groups of simultaneous
    messages on the threads of a :class:`~octofuse.threads.ThreadBudget` (or a budget of
    ``threads``), with their traffic and timings."""

    def __init__(
        self,
        agents,
        rules,
        fcfg: FuseConfig,
        make_map: Callable[[], OccupancyMap],
        threads: int | ThreadBudget,
        tree: Sequence[tuple[int, int]] | None = None,
        frames: AgentFrames | None = None,
    ):
        self.agents, self.rules, self.cfg = agents, rules, fcfg
        self.unknown = parse_unknown(fcfg.unknown)  # the core's policy, parsed once
        self.frames = frames or AgentFrames(agents)
        if CHANNEL_FILTER in rules and tree is None:
            raise ValueError("the channel filter needs the links of a tree")
        #: the channel filter's links, both directions (agent indices)
        self._tree_links = {(a, b) for a, b in tree or ()} | {(b, a) for a, b in tree or ()}
        self._start({r: {a: make_map() for a in agents} for r in rules})
        self.traffic = {r: Traffic() for r in rules}
        #: seconds per part (summed over threads; wall time for `total` and the `(wall)`
        #: parts), added to through :meth:`add_time` while the run goes
        self.timings: dict[str, float] = defaultdict(float)
        self._clock = threading.Lock()
        self.budget = budget_of(threads)
        self._owns_budget = self.budget is not threads
        # the threads of one fusion: a share of the budget, so that the rules run side by side
        self.fuse_threads = max(1, self.budget.threads // max(1, len(rules)))
        self._rule_seconds: dict[str, float] = defaultdict(float)  # each rule's last exchange

    def _start(self, maps: dict[str, dict[str, OccupancyMap]]) -> None:
        """Every rule's agents on ``maps`` (rule -> agent -> map, fused in place)."""
        self.nodes = {
            r: {a: Agent(a, r, m, self.cfg.layers_max_bytes) for a, m in per.items()}
            for r, per in maps.items()
        }
        #: rule -> agent -> the agent's map (the channel filter's unclamped)
        self.fused = {r: {a: n.map for a, n in per.items()} for r, per in self.nodes.items()}

    def start_from(self, maps: dict[str, OccupancyMap]) -> None:
        """Every rule's agents start from copies of ``maps`` (finished maps)."""
        self._start({r: {a: m.copy() for a, m in maps.items()} for r in self.rules})

    def result_maps(self) -> tuple[dict[str, dict[str, OccupancyMap]], dict[str, OccupancyMap]]:
        """The agents' maps per rule as scored and written (:meth:`scored_maps`), and the
        channel filter's unclamped maps."""
        return {r: self.scored_maps(r) for r in self.rules}, self.unclamped_maps()

    def unclamped_maps(self) -> dict[str, OccupancyMap]:
        """The channel filter's maps as fused (unclamped), or none without it."""
        return dict(self.fused.get(CHANNEL_FILTER, {}))

    def scored_maps(self, rule: str) -> dict[str, OccupancyMap]:
        """The agents' maps of ``rule`` as scored and written: the maps themselves, or the
        exact modes' clamped copies (made on the budget's threads)."""
        if rule not in EXACT_MODES:
            return self.fused[rule]
        from .channel_filter import clamped

        exact = self.fused[rule]
        return dict(zip(exact, self.budget.map(clamped, exact.values())))

    def memory(self) -> dict[str, dict[str, dict[str, int]]]:
        """Per rule and agent: bytes of the map and of the per-link state (each map measured
        once, on the network's threads); with source layers, the per-link state holds the
        layers, and ``layers`` and ``folded`` count the layers held and folded."""
        held = {
            (r, a): (n.map, n.held_maps()) for r, per in self.nodes.items() for a, n in per.items()
        }
        maps = list({id(m): m for own, links in held.values() for m in (own, *links)}.values())
        size = dict(zip(map(id, maps), self.budget.map(lambda m: m.memory_bytes, maps)))
        out = {
            r: {
                a: {
                    "map": size[id(held[r, a][0])],
                    "links": sum(size[id(m)] for m in held[r, a][1]),
                }
                for a in self.agents
            }
            for r in self.rules
        }
        for r, per in self.nodes.items():
            for a, n in per.items():
                if n.layers is not None:
                    out[r][a].update(layers=len(n.layers.layers), folded=len(n.layers.folded))
        return out

    def exchange(self, group: Sequence[Exchange]) -> None:
        """Deliver simultaneous messages, first in, first out; the rules run in parallel."""
        t0 = time.perf_counter()
        self.align(group)
        # the slowest rules first (as they were in the last group): the threads finish the
        # group together
        order = sorted(self.rules, key=lambda r: -self._rule_seconds[r])
        self.budget.map(lambda r: self.exchange_rule(r, group), order)
        self.add_time("exchange + fusion (wall)", t0)

    def align(self, group: Sequence[Exchange]) -> None:
        """Align the links of a group's messages that have not aligned yet (with
        ``fuse.align``), on the first rule's maps; before any rule exchanges the group."""
        self.frames.align_links(
            [(self.agents[e.sender], self.agents[e.receiver], e.lost, e.time_s) for e in group],
            self.fused[self.rules[0]],
        )

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
        if self._owns_budget:
            self.budget.close()

    def _count(
        self,
        r: str,
        s: str,
        d: str,
        m: OccupancyMap,
        lost: bool = False,
        leaves: dict | None = None,
    ) -> None:
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

    def _count_sizes(
        self, r: str, s: str, d: str, nbytes: int, n_leaves: int, lost: bool = False
    ) -> None:
        """Counts a message of ``nbytes`` (OctoMap's stream) and ``n_leaves`` voxels."""
        tr = self.traffic[r]
        tr.sent[s] += nbytes
        if lost:
            tr.lost += 1
        else:
            tr.received[d] += nbytes
        tr.sent_32b[s] += 32 * n_leaves
        tr.messages += 1

    def _exchange_composed(self, r: str, group: Sequence[Exchange]) -> None:
        """Every message of the group composed from its sender's state at the start of the
        group (its map and its links alike), then delivered in order; lost ones are counted
        as sent and dropped. The exact modes' messages (the channel filter's on its tree's
        links only), and deltas."""
        nodes, cfg, exact = self.nodes[r], self.cfg, r in EXACT_MODES
        t0 = time.perf_counter()
        msgs = []
        for e in group:
            s, d = self.agents[e.sender], self.agents[e.receiver]
            if r == CHANNEL_FILTER and (e.sender, e.receiver) not in self._tree_links:
                continue
            if not self.frames.aligned(s, d):  # sent whole, no transform to fuse it with yet
                self._count(r, s, d, self.fused[r][s], lost=e.lost)
                continue
            msgs.append((e, nodes[s].compose(d, delta=cfg.delta, reliable=cfg.loss == 0)))
        self.add_time("exchange", t0)
        for e, msg in msgs:
            t1 = time.perf_counter()
            self._count(r, msg.sender, msg.receiver, msg.payload, lost=e.lost)
            if e.lost:
                continue
            d = nodes[msg.receiver]
            moved = self.frames.to_receiver(msg.sender, d.name, msg.payload, d.map.resolution)
            before = None if exact else _loss_totals(d.loss)
            with self.budget.core(self.fuse_threads) as threads:
                d.deliver(msg, unknown=self.unknown, threads=threads, moved=moved)
            self.add_time("fusion", t1)
            self._record(r, e, d, before)

    def _exchange_rule(self, r: str, group: Sequence[Exchange]) -> None:
        """One rule's messages of a group. Whole maps of a per-voxel rule: a message carries
        its sender's map as it was when the group started; fusion is in place, so an agent
        that still has to send after it received is copied first, and a two-way exchange of
        agents not yet touched in the group is one walk (:meth:`Agent.exchange_with`),
        without copies. Otherwise :meth:`_exchange_composed`."""
        if r in EXACT_MODES or self.cfg.delta:
            self._exchange_composed(r, group)
            return
        nodes, maps = self.nodes[r], self.fused[r]
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
            two_way = (
                k + 1 < len(ev_names)
                and ev_names[k + 1] == (d, s)
                and s not in modified
                and d not in modified
                and self.frames.plain(s, d)
                and self.frames.plain(d, s)
                and not group[k].lost
                and not group[k + 1].lost
            )
            if two_way:
                sends_left[s] -= 1
                sends_left[d] -= 1
                sizes = message_bytes(maps[s]), message_bytes(maps[d])
                before_modifying(s)
                before_modifying(d)
                t1 = time.perf_counter()
                before = _loss_totals(nodes[d].loss), _loss_totals(nodes[s].loss)
                # the walk counts the leaves each map had: the two messages' voxels
                n_d, n_s = nodes[d].exchange_with(nodes[s], unknown=self.unknown)
                self.add_time("fusion", t1)
                self._count_sizes(r, s, d, sizes[0], n_s)
                self._count_sizes(r, d, s, sizes[1], n_d)
                for x, n in ((s, n_s), (d, n_d)):  # a later message of x sends its copy
                    if x in start:
                        leaves[id(start[x])] = (start[x], n)
                self._record(r, group[k], nodes[d], before[0])
                self._record(r, group[k + 1], nodes[s], before[1])
                modified |= {s, d}
                k += 2
                continue
            t0 = time.perf_counter()
            state = start.get(s) if s in modified else None
            sends_left[s] -= 1
            if not self.frames.aligned(s, d):  # sent, but no transform to fuse it with yet
                self._count(
                    r,
                    s,
                    d,
                    state if state is not None else maps[s],
                    lost=group[k].lost,
                    leaves=leaves,
                )
                self.add_time("exchange", t0)
                k += 1
                continue
            msg = nodes[s].compose(d, state=state)
            if group[k].lost:
                self._count(r, s, d, msg.payload, lost=True, leaves=leaves)
                self.add_time("exchange", t0)
                k += 1
                continue
            before_modifying(d)
            self._count(r, s, d, msg.payload, leaves=leaves)
            moved = self.frames.to_receiver(s, d, msg.payload, maps[d].resolution)
            self.add_time("exchange", t0)
            t1 = time.perf_counter()
            before = _loss_totals(nodes[d].loss)
            with self.budget.core(self.fuse_threads) as threads:
                nodes[d].deliver(msg, unknown=self.unknown, threads=threads, moved=moved)
            self.add_time("fusion", t1)
            self._record(r, group[k], nodes[d], before)
            modified.add(d)
            k += 1

    def _record(self, r: str, e: Exchange, receiver: Agent, before: tuple | None) -> None:
        """Append the fusion of message ``e`` (its loss: the receiver's loss map less its
        totals ``before``; none for the channel filter)."""
        loss = None
        if before is not None:
            voxels, total = _loss_totals(receiver.loss)
            loss = voxels - before[0], max(0.0, total - before[1])
        self.traffic[r].fusions.append(
            FusionEvent(
                e.time_s, r, self.agents[e.sender], self.agents[e.receiver], *(loss or (None, None))
            )
        )

    def loss_map(self, rule: str, agent: str) -> InfoLossMap:
        """The information lost by ``agent``'s fusions under ``rule`` (empty if none)."""
        return self.nodes[rule][agent].loss_map()


def _loss_totals(loss: InfoLossMap) -> tuple[int, float]:
    """Voxels fused and information loss summed over them (nats)."""
    return loss.voxels_fused, float(loss.loss_sum)
