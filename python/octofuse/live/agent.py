"""One robot's ``octofuse agent``: its scans, its links to its neighbours over Zenoh, its map.

The agent replays its own scans at the bags' rate (``live.speed``) and exchanges with its
neighbours at the times of the fleet's schedule, which every agent computes alike from the
configuration (graph, schedule, seed). It sends as an :class:`~octofuse.fusion.agent.Agent`
composes (the link protocol: sequence numbers, acknowledgements, deltas) and applies what
arrives from its configured neighbours only; frames that are malformed, oversized, foreign or
from others are dropped and counted.

Two ways to run:

* **in time** (default): scans are inserted at their time, messages sent at theirs through the
  fault layer and applied as they arrive; a checkpoint is written every
  ``live.checkpoint_period`` seconds of mission time, and an agent started again resumes from
  it (a new epoch of its links). After the mission, ``live.settle_rounds`` rounds of
  fault-free exchanges let the fleet settle.
* **lockstep**: at each exchange time an agent sends its messages, then waits for those the
  schedule sends it and applies them in the schedule's order, as ``octofuse run`` does: the
  fleet's maps are then ``run``'s, bit for bit.

At the end the agent writes its fused map, its own map, its loss leaves and its counts into
``out/<agent>/`` (each file renamed into place when complete) and publishes its fused map.
"""

from __future__ import annotations

import json
import os
import queue
import time
from collections import defaultdict, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..config import CHANNEL_FILTER, FleetConfig
from ..fusion.agent import Agent, MapMessage
from ..fusion.graph import make_graph
from ..fusion.network import message_bytes
from ..fusion.schedule import EXCHANGE, mission_events, moments, parse_schedule
from ..fusion.wire import Encoding, Kind, Message
from ..maps.build import insert_scans
from ..maps.occupancy import OccupancyMap
from ..memory import resident_memory
from ..rules import parse_unknown
from ..scans.source import ScanSource, prefetch
from . import checkpoint, keys
from .budget import MIN_NODES, LinkBudget
from .chunks import wire_bytes
from .faults import FaultyLinks
from .transport import ZenohTransport, endpoint


@dataclass
class AgentCounts:
    """What an agent did, published as its status and written at the end."""

    scans: int = 0
    sent: int = 0  #: messages sent (through the fault layer)
    applied: int = 0  #: messages applied
    refused: dict = field(default_factory=lambda: defaultdict(int))  #: dropped, by reason
    bytes_sent: int = 0  #: OctoMap stream bytes (5 per node), as ``run`` counts them
    bytes_received: int = 0
    sent_32b: int = 0
    behind: int = 0  #: scans inserted later than their time plus a second
    queued_max: int = 0  #: most scans waiting at once to be inserted (a live feed)
    held_back: int = 0  #: messages not sent: the link's budget had no room
    #: after a restart: when (wall clock) the agent was back on time with every neighbour
    #: heard from in its new epoch
    caught_up_at: float | None = None
    restarts: int = 0


class LiveAgent:
    """Agent ``name`` of the fleet ``cfg`` under ``rule`` (one of ``cfg.fuse.rules``; each
    rule's agents are a fleet of their own, on ports of their own). ``insert_mode``: how
    its scans go into its maps; by default the fleet's, but the fast mode for the 3D clouds
    of a live robot (:meth:`run_bridged`), which must keep up with its sensor."""

    def __init__(
        self,
        cfg: FleetConfig,
        name: str,
        rule: str,
        out: Path,
        log: Callable[[str], None] = lambda _m: None,
        insert_mode: str | None = None,
    ):
        if rule not in cfg.fuse.rules:
            raise ValueError(
                f"rule '{rule}' is not one of the fleet's: {', '.join(cfg.fuse.rules)}"
            )
        self.cfg, self.name, self.live, self.log = cfg, name, cfg.live, log
        self.unknown = parse_unknown(cfg.fuse.unknown)  # the core's policy, parsed once
        self.rule, self.rule_index = rule, cfg.fuse.rules.index(rule)
        names = [a.name for a in cfg.build.agents]
        if name not in names:
            raise ValueError(
                f"agent '{name}' is not in the fleet: its agents are "
                f"{', '.join(names) or 'none (build.agents is empty)'}"
            )
        self.names, self.index = names, names.index(name)
        graph = make_graph(cfg.fuse.topology, len(names), seed=cfg.fuse.seed, names=names)
        self.graph = graph
        self.neighbours = [names[j] for j in graph.neighbors(self.index)]
        self.tree: set[tuple[str, str]] = set()
        if self.rule == CHANNEL_FILTER:
            from ..fusion.channel_filter import spanning_tree

            for a, b in spanning_tree(graph, cfg.fuse.spanning_tree):
                self.tree |= {(names[a], names[b]), (names[b], names[a])}
        self.out = Path(out) / rule / name
        self.out.mkdir(parents=True, exist_ok=True)
        mk = lambda: OccupancyMap.from_config(cfg.build.map)  # noqa: E731
        self.agent = Agent(name, self.rule, mk(), cfg.fuse.layers_max_bytes)
        self.local = mk()
        self.counts = AgentCounts()
        self._insert_mode = insert_mode  #: as given (None: the default)
        self.insert_mode = insert_mode or cfg.build.insert_mode
        self.queued = 0  #: scans arrived and not inserted yet (the agent falls behind)
        self._published = 0.0  #: when the fused map was last published (monotonic)
        self.faults: dict = {}  #: what the fault layer did to this agent's chunks
        self.pending: dict[str, deque] = defaultdict(deque)  # lockstep: frames by sender
        #: wall-clock times for latency: own scans inserted (time, count), messages sent
        #: (receiver, seq, time, own scans in them) and applied (sender, seq, time)
        self.trace: dict[str, list] = {"scans": [], "sent": [], "applied": []}
        self.heard: set[str] = set()  #: neighbours applied from since this process started
        self.scans_in_map = 0  #: own scans in the map (those before a restart too)
        #: the mission time now (set when the mission starts: the budget counts in it)
        self.clock: Callable[[], float] = time.monotonic
        rate = self.live.budget_bytes_per_s
        self.budget = LinkBudget(rate, self.live.max_chunk_bytes) if rate else None

    # -- the link protocol on frames ---------------------------------------------------------
    def uses(self, other: str) -> bool:
        """Whether this agent's rule exchanges with ``other`` (the channel filter on its tree)."""
        if self.rule != CHANNEL_FILTER:
            return other in self.neighbours
        return (self.name, other) in self.tree

    def compose(self, receiver: str, t: float) -> bytes | None:
        """The frame for ``receiver`` at mission time ``t``; None if the link's budget leaves
        no room for a finest voxel now."""
        f = self.cfg.fuse
        max_nodes = None
        if self.budget is not None:
            max_nodes = self.budget.max_nodes(receiver, t, self._empty_frame(receiver))
            if max_nodes < MIN_NODES:
                self.counts.held_back += 1
                return None
        msg = self.agent.compose(
            receiver,
            delta=f.delta,
            reliable=f.loss == 0 and not self.live.faults.any,
            max_nodes=max_nodes,
        )
        self.counts.sent += 1
        self.counts.bytes_sent += message_bytes(msg.payload)
        self.counts.sent_32b += 32 * msg.payload.num_leaves
        frame = msg.encode(self.live.fleet)
        self.trace["sent"].append((receiver, msg.seq, time.time(), self.scans_in_map))
        if self.budget is not None:
            self.budget.spend(receiver, t, frame)
        return frame

    def acknowledge(self, transport, sender: str) -> None:
        """Tell ``sender`` what this agent has applied of its messages, without a map (when
        this agent sends no more, or has no message for it yet): the sender's deltas move on,
        under a budget to the voxels that did not fit."""
        link = self.agent.link(sender)
        frame = Message(
            self.live.fleet,
            self.rule,
            self.name,
            sender,
            link.seq,
            link.applied,
            Kind.ACK,
            encoding=Encoding.NONE,
        ).encode()
        if self.budget is not None:
            t = self.clock()
            if self.budget.allowance(sender, t) < wire_bytes(len(frame), self.live.max_chunk_bytes):
                return
            self.budget.spend(sender, t, frame)
        transport.send(sender, frame)

    def _empty_frame(self, receiver: str) -> int:
        """Bytes of a frame to ``receiver`` whose map has no node."""
        m = self.agent.map
        empty = OccupancyMap(m.resolution, m.prob_hit, m.prob_miss, m.clamping)
        return len(
            MapMessage(self.name, receiver, self.rule, 1, 1, empty, True).encode(self.live.fleet)
        )

    def apply(self, sender: str, frame: bytes) -> bool:
        """Apply a frame that arrived from ``sender``; False (counted) if it is refused."""
        if sender not in self.neighbours or not self.uses(sender):
            self.counts.refused["not a neighbour"] += 1
            return False
        try:
            msg = MapMessage.decode(frame, self.live.max_message_bytes)
        except (ValueError, OSError) as e:  # a bad frame, or a payload that is no map
            self.counts.refused[f"malformed: {type(e).__name__}"] += 1
            return False
        if (msg.sender, msg.receiver, msg.rule) != (sender, self.name, self.rule):
            self.counts.refused["not for this link"] += 1
            return False
        if msg.payload is None:  # an acknowledgement: what the neighbour holds of ours
            self.agent.link(sender).acknowledged(msg.ack)
            return False
        self.counts.bytes_received += message_bytes(msg.payload)
        # a fleet's maps share one frame (FleetConfig refuses agent frames and alignment)
        if not self.agent.deliver(msg, unknown=self.unknown):
            self.counts.refused["old or repeated"] += 1
            return False
        self.counts.applied += 1
        self.heard.add(sender)
        self.trace["applied"].append((sender, msg.seq, time.time()))
        return True

    # -- the mission ---------------------------------------------------------------------------
    def run(self, resume: bool = True) -> AgentCounts:
        cfg, live = self.cfg, self.live
        build = _own_build(cfg, self.index)
        with ScanSource(build) as src:
            start = src.bags.start_ns
            timed = self._exchange_times(start, src.bags.end_ns)
            progress = {"t": -1.0, "scans": 0}
            ckpt = self.out / "checkpoint.pkl"
            epoch = checkpoint.next_epoch(self.out / "epoch")
            if resume and ckpt.is_file():
                self.local, progress = checkpoint.restore(ckpt, self.agent, epoch)
                self.scans_in_map = progress["scans"]
                self.counts.restarts = epoch - 1
                self.log(
                    f"{self.name}: resumed from {ckpt} at t = {progress['t']:.2f} s (start {epoch})"
                )
            transport = self._open()
            try:
                transport.wait_for([n for n in self.neighbours if self.uses(n)], live.timeout)
                scans = (s for i, s in enumerate(prefetch(src.scans())) if i >= progress["scans"])
                timed = [(t, g) for t, g in timed if t > progress["t"]]
                if live.lockstep:
                    self._lockstep(transport, scans, timed, start, progress)
                else:
                    self._in_time(transport, scans, timed, start, progress, ckpt)
                self._end(transport)
            finally:
                transport.close()
        return self.counts

    def run_bridged(self, scan_type: str, duration: float) -> AgentCounts:
        """Map the scans a ROS 2 robot publishes through zenoh-bridge-ros2dds (its agent's
        scan topic, ``tf``, ``tf_static``: :mod:`.bridged`) for ``duration`` seconds, exchanging
        at the schedule's times from now. Its status says how many scans wait (it falls
        behind when they grow)."""
        from .bridged import BridgedScans

        cfg, live = self.cfg, self.live
        if self._insert_mode is None and scan_type == "pointcloud2":
            self.insert_mode = "fast"  # a 3D lidar in real time
        timed = self._exchange_times(0, int(duration * 1e9))
        progress = {"t": -1.0, "scans": 0}
        transport = self._open(announce=False)
        feed = BridgedScans(
            transport.session, cfg.build.agents[self.index].topic, scan_type, cfg.build
        )
        transport.announce()  # listening for scans too: a bridge may start
        try:
            transport.wait_for([n for n in self.neighbours if self.uses(n)], live.timeout)
            t0 = time.monotonic()
            self.clock = lambda: time.monotonic() - t0
            links = FaultyLinks(live.faults, self.name, self.index, transport.put, self.clock)
            self.faults = links.counts
            for t, group in [*timed, (duration, [])]:
                while time.monotonic() - t0 < t:
                    self._insert(
                        feed.take(min(0.05, max(0.0, t0 + t - time.monotonic()))), progress
                    )
                    self.queued = feed.backlog()
                    self.counts.queued_max = max(self.counts.queued_max, self.queued)
                    self._drain(transport, until=time.monotonic())
                self._exchange(group, _through(transport, links), transport, t, progress)
            links.flush()
            for reason, n in feed.skipped.items():
                self.counts.refused[f"scan: {reason}"] += n
            self._end(transport)
        finally:
            feed.close()
            transport.close()
        return self.counts

    def _exchange_times(self, start_ns: int, end_ns: int) -> list:
        """The schedule's groups of simultaneous exchanges, ``(mission time, group)``, of a
        mission from ``start_ns`` to ``end_ns``."""
        duration, events = mission_events(
            parse_schedule(self.cfg.fuse.schedule), self.graph, self.cfg.fuse, start_ns, end_ns
        )
        return [(t, g) for t, kind, g in moments(events, duration, 0) if kind == EXCHANGE]

    def _exchange(self, group, send, transport, t: float, progress: dict) -> None:
        """Send this agent's messages of ``group`` (mission time ``t``) through ``send``."""
        for e in group:
            s, d = self.names[e.sender], self.names[e.receiver]
            if s == self.name and self.uses(d):
                frame = self.compose(d, self.clock())  # the budget's clock: when it leaves
                if frame is not None:
                    send(d, frame)
        progress["t"] = t
        self._status(transport, t)

    def _end(self, transport) -> None:
        """Say this agent has sent all it will, apply what its neighbours still send until
        they have too (so nothing is sent to an agent gone), and write the result."""
        transport.declare_done()
        self._drain(transport, until=None, done=[n for n in self.neighbours if self.uses(n)])
        self._finish(transport)

    def _open(self, announce: bool = True) -> ZenohTransport:
        """This agent's Zenoh session, listening on its endpoint, connected to its neighbours'."""
        live = self.live
        connect = [endpoint(live, self._port_index(n)) for n in self.neighbours]
        return ZenohTransport(
            live,
            self.rule,
            self.name,
            endpoint(live, self._port_index(self.name)),
            connect,
            announce,
        )

    def _port_index(self, name: str) -> int:
        """Agent ``name``'s port offset: one port per agent and rule."""
        return self.rule_index * len(self.names) + self.names.index(name)

    def _insert(self, batch: list, progress: dict) -> None:
        if batch:
            insert_scans(
                batch, [[*self.agent.scan_targets(), self.local]] * len(batch), 1, self.insert_mode
            )
            self.counts.scans += len(batch)
            progress["scans"] += len(batch)
            self.scans_in_map = progress["scans"]
            self.trace["scans"].append((time.time(), self.scans_in_map))
            batch.clear()

    def _scans_until(self, scans, t: float, start: int, progress: dict, carry: list) -> None:
        """Insert the scans stamped at or before mission time ``t`` (``carry``: a scan read
        ahead, at most one)."""
        batch: list = []
        while True:
            scan = carry.pop() if carry else next(scans, None)
            if scan is None:
                break
            if (scan.stamp_ns - start) / 1e9 > t:
                carry.append(scan)
                break
            batch.append(scan)
            if len(batch) >= self.cfg.build.batch_size:
                self._insert(batch, progress)
        self._insert(batch, progress)

    def _lockstep(self, transport, scans, timed, start, progress) -> None:
        carry: list = []
        for t, group in timed:
            self._scans_until(scans, t, start, progress, carry)
            for e in group:  # every message of the group composed before any is applied
                s, d = self.names[e.sender], self.names[e.receiver]
                if s == self.name and self.uses(d):
                    frame = self.compose(d, t)
                    if not e.lost:
                        transport.send(d, frame)
            for e in group:
                s, d = self.names[e.sender], self.names[e.receiver]
                if d == self.name and self.uses(s) and not e.lost:
                    self.apply(s, self._wait_from(transport, s))
            progress["t"] = t
            self._status(transport, t)
        self._scans_until(scans, float("inf"), start, progress, carry)

    def _wait_from(self, transport, sender: str) -> bytes:
        """The next frame from ``sender`` (frames of others kept for later)."""
        deadline = time.monotonic() + self.live.timeout
        while not self.pending[sender]:
            left = deadline - time.monotonic()
            item = None
            if left > 0:
                try:
                    item = transport.inbox.get(timeout=left)
                except queue.Empty:
                    pass
            if item is None:
                raise TimeoutError(
                    f"agent {self.name}: no message from {sender} within "
                    f"{self.live.timeout:g} s (lockstep)"
                )
            self.pending[item[0]].append(item[1])
        return self.pending[sender].popleft()

    def _in_time(self, transport, scans, timed, start, progress, ckpt) -> None:
        live = self.live
        # the mission's clock starts once, with the fleet: an agent started again catches up
        # with it (the scans and exchanges it missed go at once) rather than lag behind
        started = progress.setdefault("start_wall", time.time())
        t0 = time.monotonic() - (time.time() - started)
        now = self.clock = lambda: (time.monotonic() - t0) * live.speed  # mission time
        tree = [n for n in self.neighbours if self.uses(n)]
        links = FaultyLinks(live.faults, self.name, self.index, transport.put, now)
        self.faults = links.counts
        next_ckpt = progress["t"] + live.checkpoint_period if live.checkpoint_period else None
        carry: list = []
        for t, group in [*timed, (float("inf"), [])]:
            # scans and arrivals until the exchange at t
            while True:
                scan = carry.pop() if carry else next(scans, None)
                if scan is None:  # after the last exchange, what has arrived (the settle
                    # rounds and the end take the rest: waiting for quiet here would hold this
                    # agent's own rounds back while its neighbours settle)
                    last = time.monotonic() if t == float("inf") else t0 + t / live.speed
                    self._drain(transport, until=last)
                    break
                at = (scan.stamp_ns - start) / 1e9
                if at > t:
                    carry.append(scan)
                    self._drain(transport, until=t0 + t / live.speed)
                    break
                self._drain(transport, until=t0 + at / live.speed)
                if now() > at + 1.0:
                    self.counts.behind += 1
                elif self.counts.restarts and self.counts.caught_up_at is None:
                    if self.heard.issuperset(tree):
                        self.counts.caught_up_at = time.time()
                self._insert([scan], progress)
            if t == float("inf"):
                break
            self._exchange(group, _through(transport, links), transport, t, progress)
            if next_ckpt is not None and t >= next_ckpt:
                checkpoint.save(ckpt, self.agent, self.local, progress)
                next_ckpt = t + live.checkpoint_period
        links.flush()
        for _ in range(live.settle_rounds):  # fault-free rounds: the fleet settles
            for n in self.neighbours:
                frame = self.compose(n, now()) if self.uses(n) else None
                if frame is not None:
                    transport.send(n, frame)
            self._drain(transport, until=time.monotonic() + 0.5)

    def _drain(self, transport, until: float | None, done: list | None = None) -> None:
        """Apply what arrives until the monotonic time ``until``; with None, until every agent
        of ``done`` has finished and nothing has arrived for a second."""
        deadline = time.monotonic() + self.live.timeout
        while True:
            wait = 1.0 if until is None else until - time.monotonic()
            if wait <= 0 and until is not None:
                return
            if until is None and time.monotonic() > deadline:
                late = ", ".join(transport.running(done or []))
                raise TimeoutError(
                    f"agent {self.name}: neighbours still running after "
                    f"{self.live.timeout:g} s: {late}"
                )
            try:
                sender, frame = transport.inbox.get(timeout=max(wait, 0.0))
            except queue.Empty:
                if until is None and not transport.running(done or []):
                    return
                continue
            # under a budget a sender's rest waits for acknowledgements: give them at once
            if self.apply(sender, frame) and (done or self.budget is not None):
                self.acknowledge(transport, sender)

    def _scored(self) -> OccupancyMap:
        """The fused map as scored and written (the exact modes' clamped)."""
        from ..fusion.channel_filter import clamped

        return clamped(self.agent.map) if self.agent.exact else self.agent.map

    def _publish_map(self, transport, scored: OccupancyMap | None = None) -> None:
        """The fused map (as scored) as ROS 2 sees it behind a bridge, and as a viewer does."""
        from ..outputs.rosbag_export import _header, occupied_cloud, octomap_message, typestore

        scored = scored if scored is not None else self._scored()
        ts = typestore(ros1=False)
        header = _header(ts, time.time_ns(), self.cfg.build.fixed_frame)
        rule = self.rule if len(self.cfg.fuse.rules) > 1 else None
        transport.publish(
            keys.fused_map(self.name, rule),
            bytes(
                ts.serialize_cdr(octomap_message(ts, scored, header), "octomap_msgs/msg/Octomap")
            ),
        )
        transport.publish(
            keys.occupied_cloud(self.name, rule),
            bytes(
                ts.serialize_cdr(occupied_cloud(ts, scored, header), "sensor_msgs/msg/PointCloud2")
            ),
        )
        self._published = time.monotonic()

    def _status(self, transport, t: float) -> None:
        if self.live.map_period and time.monotonic() - self._published >= self.live.map_period:
            self._publish_map(transport)
        transport.publish_status(
            {
                "agent": self.name,
                "rule": self.rule,
                "t": round(t, 3),
                "scans": self.counts.scans,
                "sent": self.counts.sent,
                "applied": self.counts.applied,
                "refused": sum(self.counts.refused.values()),
                "insert_mode": self.insert_mode,
                "behind": self.counts.behind,
                "queued": self.queued,
                "queued_max": self.counts.queued_max,
                "links": {
                    n: {"seq": l.seq & 0xFFFFFFFF, "applied": l.applied & 0xFFFFFFFF}
                    for n, l in self.agent.links.items()
                },
            }
        )

    def _finish(self, transport) -> None:
        """Write the final state and publish the fused map."""
        scored = self._scored()
        with checkpoint.written(self.out / "fused.ot") as f:
            f.write(scored.to_bytes())
        with checkpoint.written(self.out / "local.ot") as f:
            f.write(self.local.to_bytes())
        values, depths = self.agent.loss_map().values_depths()
        with checkpoint.written(self.out / "loss.npz") as f:
            np.savez(f, values=values, depths=depths)
        c = self.counts
        with checkpoint.written(self.out / "trace.json") as f:
            f.write(json.dumps(self.trace).encode())
        with checkpoint.written(self.out / "counts.json") as f:
            f.write(
                json.dumps(
                    {
                        "scans": c.scans,
                        "sent": c.sent,
                        "applied": c.applied,
                        "refused": dict(c.refused),
                        "bytes_sent": c.bytes_sent,
                        "bytes_received": c.bytes_received,
                        "sent_32b": c.sent_32b,
                        "insert_mode": self.insert_mode,
                        "behind": c.behind,
                        "queued_max": c.queued_max,
                        "held_back": c.held_back,
                        "budget_peak": dict(self.budget.peak) if self.budget else {},
                        "restarts": c.restarts,
                        "caught_up_at": c.caught_up_at,
                        "chunks_over_bound": transport.dropped,
                        "chunks_refused": transport.chunks_refused,
                        "faults": dict(self.faults),
                        "peak_rss": resident_memory()[2],
                        "cpu_s": sum(os.times()[:2]),
                    }
                ).encode()
            )
        self._publish_map(transport, scored)


def _through(transport: ZenohTransport, links: FaultyLinks):
    """``send(receiver, frame)``: the frame in chunks, each through the fault layer."""
    return lambda receiver, frame: transport.send(receiver, frame, put=links.send)


def _own_build(cfg: FleetConfig, index: int):
    """The build configuration of agent ``index``'s own scans alone."""
    from dataclasses import replace

    return replace(cfg.build, agents=[cfg.build.agents[index]])
