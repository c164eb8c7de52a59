"""A swarm's worker (``SwarmWorker``): some agents' maps in one process, a Ray actor of
:func:`octofuse.fusion.swarm.simulate_swarm` (or used directly, in process).

It inserts its agents' scans, sends their maps as frames of bytes (a header and an OctoMap
``.ot`` stream, whole or a delta), fuses what it receives (moved into the receiver's frame, after aligning a link on first contact),
scores its agents against the centralized map and keeps its resident memory under a cap.
"""

from __future__ import annotations

import os
import time
from collections import defaultdict
from collections.abc import Iterable

from ..config import CHANNEL_FILTER, EXACT_MODES, MapConfig
from ..memory import resident_memory, return_freed_memory
from .agent import Agent, MapMessage
from .agent_frames import AgentFrames
from .channel_filter import clamped
from .network import message_bytes
from .results import LOCAL, timeline_point


class SwarmWorker:
    """Agents' maps in one process (a Ray actor; also usable directly, in process).

    Each agent runs one :class:`~.agent.Agent` per rule; their messages leave and arrive as
    frames of bytes (:meth:`~.agent.MapMessage.encode`). ``tree``: the channel filter's links
    (agent name pairs, both directions); ``reliable``: no message is lost (deltas against the
    last message sent, not the last acknowledged). ``memory_cap`` (bytes, optional): after
    every call the worker checks its private resident memory (not counting the shared object
    store) and raises ``MemoryError`` naming itself once it is over the cap. ``frames``: the
    run's agent frames (default: every agent in the common frame). ``layers_max_bytes``: source
    layers' memory budget per agent (0: unlimited)."""

    def __init__(
        self,
        index: int,
        names: list[str],
        map_cfg: MapConfig,
        rules: list[str],
        unknown: str,
        delta: bool,
        threads: int = 1,
        memory_cap: int | None = None,
        central: bool = False,
        frames: AgentFrames | None = None,
        tree: Iterable[tuple[str, str]] = (),
        reliable: bool = True,
        insert_mode: str = "exact",
        layers_max_bytes: int = 0,
    ):
        from ..maps.occupancy import OccupancyMap
        from ..rules import parse_unknown

        self.index, self.names, self.rules = index, list(names), list(rules)
        self.frames = frames or AgentFrames(self.names)
        self.unknown, self.delta, self.threads, self.cap = (
            parse_unknown(unknown),
            delta,
            max(1, threads),
            memory_cap,
        )
        self.tree, self.reliable, self.insert_mode = set(tree), reliable, insert_mode
        mk = lambda: OccupancyMap.from_config(map_cfg)  # noqa: E731
        self.resolution = map_cfg.resolution
        self.central = mk() if central else None
        self.nodes = {
            a: {r: Agent(a, r, mk(), layers_max_bytes) for r in rules} for a in self.names
        }
        self.local = {a: mk() for a in self.names}
        # with alignment and deltas: the links of this worker's senders known to have aligned,
        # and the whole maps last sent on the others ((rule, sender, receiver) -> map)
        self.aligned_out: set[tuple[str, str]] = set()
        self.unconfirmed: dict[tuple, object] = {}
        self.sent = {r: defaultdict(int) for r in rules}
        self.sent_32b = {r: defaultdict(int) for r in rules}
        self.received = {r: defaultdict(int) for r in rules}
        self.messages = {r: 0 for r in rules}
        self.dropped = 0  #: frames refused: malformed, or not for the agent that got them
        self.stream_bytes_sent = 0
        self.seconds: dict[str, float] = defaultdict(float)
        self.peak_private = 0

    # -- the calls the driver makes ----------------------------------------------------------
    def insert(self, scans: list) -> int:
        """Insert scans (``(agent_name, Scan)``; the central worker takes every scan) in order."""
        from ..maps.build import insert_scans

        t0 = time.perf_counter()
        if self.central is not None:
            insert_scans(
                [s for _, s in scans], [[self.central]] * len(scans), self.threads, self.insert_mode
            )
        else:
            targets = [
                [m for n in self.nodes[a].values() for m in n.scan_targets()] + [self.local[a]]
                for a, _ in scans
            ]
            insert_scans([s for _, s in scans], targets, self.threads, self.insert_mode)
        self.seconds["insertion"] += time.perf_counter() - t0
        self._check_memory()
        return len(scans)

    def uses(self, rule: str, sender: str, receiver: str) -> bool:
        """Whether ``rule`` sends on this link (the channel filter on its tree only)."""
        return rule != CHANNEL_FILTER or (sender, receiver) in self.tree

    def send(self, sender: str, receivers: list[str], *aligned: list):
        """The messages of ``sender`` at the start of a group, one per receiver (a tuple of
        them for two or more): per rule, a frame of its map (a delta since the last message
        the receiver is known to hold with ``delta``), or None where the rule does not use
        the link.

        With alignment, a link sends whole maps until it has aligned, as in the simulation, and
        its first delta is taken against the whole map that aligned it. ``aligned``: what the
        receivers' calls since this sender's last message returned (the links that aligned)."""
        t0 = time.perf_counter()
        for links in aligned:
            self._confirm(links)
        # a map sent to several receivers is written once (kept alive: its id stays its own)
        streams: dict[int, tuple] = {}
        per = []
        for d in receivers:
            whole = (
                self.delta and self.frames.align != "off" and (sender, d) not in self.aligned_out
            )
            frames = []
            for r, node in self.nodes[sender].items():
                if not self.uses(r, sender, d):
                    frames.append(None)
                    continue
                if whole:  # the base of the link's deltas if it aligns on this one
                    state = self.unconfirmed[(r, sender, d)] = node.map.copy()
                    msg = node.compose(d, state=state)
                else:
                    msg = node.compose(d, delta=self.delta, reliable=self.reliable)
                m = msg.payload
                if id(m) not in streams:
                    streams[id(m)] = (m, m.to_bytes())
                self._count(r, sender, m)
                frames.append(msg.encode(payload=streams[id(m)][1]))
            self.stream_bytes_sent += sum(len(f) for f in frames if f is not None)
            per.append(frames)
        self.seconds["serialise"] += time.perf_counter() - t0
        self._check_memory()
        return per[0] if len(per) == 1 else tuple(per)

    def receive(
        self, receiver: str, senders: list[str], time_s: float, *messages
    ) -> list[tuple[str, str]]:
        """Fuse the messages of the group at ``time_s`` (one list of per-rule frames per
        sender, in event order), each moved into the receiver's frame first. A frame that is
        malformed or not from that sender to this receiver under that rule is dropped and
        counted. With alignment, the links not aligned yet register first, all on the
        receiver's map as it was when the group started; a link that fails to is counted, not
        fused. Returns the links that aligned in this call (``(sender, receiver)``)."""
        t0 = time.perf_counter()
        decoded = [
            [self._read(f, s, receiver, r) for r, f in zip(self.rules, msg)]
            for s, msg in zip(senders, messages)
        ]
        first = self._align(receiver, senders, time_s, decoded)
        for sender, msgs in zip(senders, decoded):
            fused = self.frames.aligned(sender, receiver)
            for r, msg in zip(self.rules, msgs):
                if msg is None:
                    continue
                self.received[r][receiver] += message_bytes(msg.payload)
                if not fused:
                    continue
                moved = self.frames.to_receiver(sender, receiver, msg.payload, self.resolution)
                self.nodes[receiver][r].deliver(msg, unknown=self.unknown, moved=moved)
        self.seconds["fusion"] += time.perf_counter() - t0
        self._check_memory()
        return [(s, receiver) for s in first if self.frames.aligned(s, receiver)]

    def own_maps(self) -> dict[str, bytes]:
        """This worker's agents' own (local-only) maps as ``.ot`` streams."""
        return {a: self.local[a].to_bytes() for a in self.names}

    def alignment(self) -> list[dict]:
        """The alignment of the links into this worker's agents (:meth:`AgentFrames.report`)."""
        return self.frames.report()

    def central_bytes(self) -> bytes:
        return self.central.to_bytes()

    def sample(self, central: bytes, tol: float, t: float) -> list[dict]:
        """This worker's agents' maps against the centralized map now (time ``t``): their
        points of the KL timeline (:func:`~.results.timeline_point`)."""
        from ..maps.occupancy import OccupancyMap

        jobs, _, compared = self._compared(OccupancyMap.from_bytes(central), tol)
        self._check_memory()
        return [timeline_point(t, r, a, s) for (r, a), s in zip(jobs, compared)]

    def score(self, central: bytes, tol: float, truth=None) -> dict:
        """Scores of this worker's agents against the centralized map (as in
        :func:`octofuse.fusion.results.score_result`), with their traffic."""
        from ..maps.compare import score
        from ..maps.occupancy import OccupancyMap

        c = OccupancyMap.from_bytes(central)
        jobs, maps, compared = self._compared(c, tol)
        out: dict = {LOCAL: {}, **{r: {} for r in self.rules}}
        for (r, a), m, s in zip(jobs, maps, compared):
            if r == LOCAL:
                out[r][a] = score(m, c, tol=tol, truth=truth, compared=s)
                continue
            loss = None if r in EXACT_MODES else self.nodes[a][r].loss_map()
            out[r][a] = score(
                m,
                c,
                tol=tol,
                loss=loss,
                truth=truth,
                compared=s,
                bytes_sent=self.sent[r][a],
                bytes_received=self.received[r][a],
                bytes_sent_32b=self.sent_32b[r][a],
            )
        self._check_memory()
        return out

    def traffic(self) -> dict:
        return {
            r: {
                "sent": dict(self.sent[r]),
                "received": dict(self.received[r]),
                "sent_32b": dict(self.sent_32b[r]),
                "messages": self.messages[r],
            }
            for r in self.rules
        }

    def maps(self) -> dict:
        """Every map of this worker as scored, as ``.ot`` streams: agent -> rule|local-only ->
        bytes (the exact modes' clamped)."""
        return {
            a: {
                **{r: self._scored(r, a).to_bytes() for r in self.rules},
                LOCAL: self.local[a].to_bytes(),
            }
            for a in self.names
        }

    def stats(self) -> dict:
        private, cur, peak = resident_memory()
        self.peak_private = max(self.peak_private, private)
        held = {  # every map: fused, own, source layers and what the links keep
            id(m): m
            for a in self.names
            for n in self.nodes[a].values()
            for m in (n.map, *n.held_maps())
        }
        maps_bytes = sum(m.memory_bytes for m in held.values())
        maps_bytes += sum(self.local[a].memory_bytes for a in self.names)
        if self.central is not None:
            maps_bytes += self.central.memory_bytes
        return {
            "worker": self.index,
            "agents": len(self.names),
            "pid": os.getpid(),
            "rss": cur,
            "peak_rss": peak,
            "private": private,
            "peak_private": self.peak_private,
            "memory_cap": self.cap,
            "maps_bytes": maps_bytes,
            "stream_bytes_sent": self.stream_bytes_sent,
            "dropped": self.dropped,
            "seconds": dict(self.seconds),
        }

    # -- internals ------------------------------------------------------------------------------
    def _compared(self, central, tol: float) -> tuple[list, list, list]:
        """Every map of this worker (local-only first, then rule by rule; agents in order),
        moved into the common frame as scored, and its comparison with ``central``."""
        from ..maps.compare import compare_many

        jobs = [(LOCAL, a) for a in self.names] + [(r, a) for r in self.rules for a in self.names]
        maps = [self.frames.to_common(a, self._scored(r, a)) for r, a in jobs]
        return jobs, maps, compare_many(central, maps, tol, self.threads)

    def _scored(self, rule: str, agent: str):
        """``agent``'s map under ``rule`` as scored and written (the exact modes' clamped)."""
        if rule == LOCAL:
            return self.local[agent]
        m = self.nodes[agent][rule].map
        return clamped(m) if rule in EXACT_MODES else m

    def _read(self, frame: bytes | None, sender: str, receiver: str, rule: str):
        """The message of a frame, or None (counted as dropped) if it is not a well-formed
        message from ``sender`` to ``receiver`` under ``rule``."""
        if frame is None:
            return None
        try:
            msg = MapMessage.decode(frame)
        except ValueError:
            self.dropped += 1
            return None
        if (msg.sender, msg.receiver, msg.rule) != (sender, receiver, rule):
            self.dropped += 1
            return None
        return msg

    def _align(self, receiver: str, senders: list[str], time_s: float, decoded) -> dict:
        """Register the links of ``senders`` not aligned yet on the first rule's maps: the
        receiver's, and the sender's as its message carries it. Returns those senders' maps
        (none with alignment off)."""
        if self.frames.align == "off":
            return {}
        first = {
            s: msgs[0].payload
            for s, msgs in zip(senders, decoded)
            if msgs[0] is not None and not self.frames.aligned(s, receiver)
        }
        self.frames.align_links(
            [(s, receiver, False, time_s) for s in senders if s in first],
            {receiver: self.nodes[receiver][self.rules[0]].map, **first},
        )
        return first

    def _confirm(self, links: list) -> None:
        """The links of ``links`` from this worker's agents have aligned: their deltas start
        from the whole maps last sent on them."""
        for s, d in links:
            if s in self.names and (s, d) not in self.aligned_out:
                self.aligned_out.add((s, d))
                for r in self.rules:
                    self.nodes[s][r].link(d).baseline = self.unconfirmed.pop((r, s, d))

    def _count(self, r: str, sender: str, m) -> None:
        """A message of the map ``m`` sent."""
        self.sent[r][sender] += message_bytes(m)
        self.sent_32b[r][sender] += 32 * m.num_leaves
        self.messages[r] += 1

    def _check_memory(self) -> None:
        return_freed_memory(pools=False)
        cur = resident_memory()[0]
        self.peak_private = max(self.peak_private, cur)
        if self.cap:
            if cur > self.cap:
                raise MemoryError(
                    f"swarm worker {self.index} ({len(self.names)} agent(s)) uses "
                    f"{cur / 2**20:.0f} MiB, over its cap of {self.cap / 2**20:.0f} MiB"
                )
