"""One robot's map under one rule, its links, and the messages it sends and applies.

An :class:`Agent` is what runs on a robot: it composes a message for a neighbour
(:meth:`Agent.compose`) and applies what a neighbour sent (:meth:`Agent.deliver`), keeping the
link protocol's state per neighbour (:class:`~.link.Link`). Whoever drives the agents (the
simulation in bag time, rounds on finished maps, a swarm's actors) decides when they talk and
how a message travels: as a :class:`MapMessage` within a process, or as the bytes of
:meth:`MapMessage.encode` between processes.

Rules: every per-voxel rule fuses what arrives into the agent's map (its loss map carried by
the map); the channel filter (:mod:`.channel_filter`) sends its map minus what it got from the
receiver and replaces the sender's previous contribution, on unclamped maps; source layers
(:mod:`.source_layers`) send per source what the receiver lacks and keep the map the sum of
the newest layer of every source.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..config import CHANNEL_FILTER, SOURCE_LAYERS
from ..maps.infoloss import InfoLossMap
from ..maps.occupancy import OccupancyMap
from ..maps.tree_fusion import exchange_maps, fuse_into, subtract_into
from ..rule_names import FusionRule
from ..rules import UnknownPolicy
from .channel_filter import add_into, is_open, open_map, unclamped_copy
from .link import Link
from .source_layers import Change, LayeredPayload, Layers, empty_like
from .wire import DEFAULT_MAX_PAYLOAD, Encoding, Kind, Message, decode


@dataclass
class MapMessage:
    """A message within a process: the header's values and the payload as a map."""

    sender: str
    receiver: str
    rule: str
    seq: int  #: 1, 2, ... per link and direction
    ack: int  #: the newest seq the sender has applied from the receiver (0: none)
    #: the sender's map (or contribution), whole or its changed voxels; source layers': its
    #: layers (:class:`~.source_layers.LayeredPayload`); None: an acknowledgement alone
    payload: OccupancyMap | LayeredPayload | None
    delta: bool  #: applied voxel by voxel (the payload holds changed voxels only)

    def encode(self, fleet: str = "", payload: bytes | None = None) -> bytes:
        """The message as one frame (:mod:`.wire`); ``payload``: the payload's bytes (an
        ``.ot`` stream, or source layers), if they were written already."""
        encoding = (
            Encoding.LAYERS if isinstance(self.payload, LayeredPayload) else Encoding.OCTOMAP_OT
        )
        return Message(
            fleet,
            self.rule,
            self.sender,
            self.receiver,
            self.seq,
            self.ack,
            Kind.DELTA if self.delta else Kind.WHOLE,
            payload if payload is not None else self.payload.to_bytes(),
            encoding,
        ).encode()

    @classmethod
    def decode(cls, frame: bytes, max_payload: int = DEFAULT_MAX_PAYLOAD) -> MapMessage:
        """The message of a frame; ``WireError`` if the frame is not one, and the map
        stream's error if its payload is not a map."""
        msg = decode(frame, max_payload)
        if msg.kind == Kind.ACK:  # no map: the sender's acknowledgement alone
            return cls(msg.sender, msg.receiver, msg.rule, msg.seq, msg.ack, None, False)
        if msg.encoding == Encoding.LAYERS:
            return cls(
                msg.sender,
                msg.receiver,
                msg.rule,
                msg.seq,
                msg.ack,
                LayeredPayload.from_bytes(msg.payload),
                msg.kind == Kind.DELTA,
            )
        payload = OccupancyMap.from_bytes(msg.payload)
        if msg.rule == CHANNEL_FILTER:
            open_map(payload)  # contributions are unclamped (a stream keeps no clamping)
        return cls(
            msg.sender, msg.receiver, msg.rule, msg.seq, msg.ack, payload, msg.kind == Kind.DELTA
        )


class Agent:
    """Agent ``name``'s map under ``rule``, fused in place, and its links by neighbour.
    ``layers_max_bytes``: source layers' memory budget (0: unlimited)."""

    def __init__(
        self, name: str, rule: FusionRule | str, map: OccupancyMap, layers_max_bytes: int = 0
    ):
        self.name, self.rule, self.map = name, FusionRule(rule), map
        #: the core's per-voxel rule the agent fuses with (None for the exact modes)
        self.core_rule = self.rule.core
        self.exact = self.rule.exact
        if self.exact:
            open_map(map)  # clamping breaks the additivity exact fusion needs
        #: source layers: the layers (the own one: the map given), ``map`` their sum
        self.layers: Layers | None = None
        if self.rule == SOURCE_LAYERS:
            self.map = unclamped_copy(map)
            self.layers = Layers(name, map, self.map, layers_max_bytes)
        self.links: dict[str, Link] = {}
        self._loss: InfoLossMap | None = None

    def link(self, neighbour: str) -> Link:
        """The state of the link to ``neighbour`` (made on first use)."""
        link = self.links.get(neighbour)
        if link is None:
            link = self.links[neighbour] = Link(neighbour)
        return link

    @property
    def loss(self) -> InfoLossMap | None:
        """The information lost by this agent's fusions, carried by its map (none for the
        channel filter, which loses nothing); made on first use."""
        if self.exact:
            return None
        if self._loss is None:
            self._loss = InfoLossMap.carried_by(self.map)
        return self._loss

    def reset_loss(self) -> None:
        """Forget the loss counted so far (the map was replaced)."""
        self._loss = None

    def loss_map(self) -> InfoLossMap:
        """:attr:`loss`, or an empty loss map where there is none."""
        return self._loss if self._loss is not None else InfoLossMap(self.map.resolution)

    def scan_targets(self) -> list[OccupancyMap]:
        """The maps this agent's next scans go into: its map, and with source layers its own
        layer too (with open clamping a scan adds to both alike: the map stays the sum)."""
        return [self.map] if self.layers is None else [self.map, self.layers.own]

    # -- sending -----------------------------------------------------------------------------
    def compose(
        self,
        to: str,
        *,
        delta: bool = False,
        reliable: bool = True,
        state: OccupancyMap | None = None,
        max_nodes: int | None = None,
    ) -> MapMessage:
        """The message for neighbour ``to`` now: the map (``state`` if given: the map as it was
        at an earlier moment), or the channel filter's contribution; with ``delta``, only what
        changed since the snapshot the neighbour is known to hold, and with ``max_nodes`` only
        its most informative voxels that fit (:meth:`~.link.Link.outgoing`). Source layers
        send the layers ``to`` lacks, whole on first contact and as deltas after, whatever
        ``delta``."""
        link = self.link(to)
        if self.layers is not None:  # per source what ``to`` lacks: whole, or a delta
            self._advanced([c for c in [self.layers.publish()] if c is not None])
            parts = self.layers.parts_for(link.known)
            seq = link.sent_layers(
                [(p.source, p.version) for p in parts if p.map is not None], reliable=reliable
            )
            self._forget_caught_up()
            self.fit_budget()
            return MapMessage(
                self.name,
                to,
                self.rule,
                seq,
                link.applied,
                LayeredPayload(parts, self.map.resolution),
                any(p.base for p in parts),
            )
        if self.exact:
            snapshot = unclamped_copy(self.map)
            if link.received is not None:
                subtract_into(snapshot, link.received)
        else:
            snapshot = state if state is not None else self.map
            if delta:  # kept as the next baseline: a copy of the map as sent
                snapshot = snapshot.copy()
        whole = link.sends_whole()
        seq, payload = link.outgoing(snapshot, delta=delta, reliable=reliable, max_nodes=max_nodes)
        if self.exact and payload is not snapshot:
            open_map(payload)
        return MapMessage(self.name, to, self.rule, seq, link.applied, payload, delta and not whole)

    # -- receiving ---------------------------------------------------------------------------
    def deliver(
        self,
        msg: MapMessage,
        *,
        unknown: UnknownPolicy = UnknownPolicy.COPY,
        threads: int = 1,
        moved: OccupancyMap | None = None,
    ) -> bool:
        """Apply ``msg`` (``moved``: its payload moved into this agent's frame, if the sender
        maps in another). False if it was not newer than the last applied on its link, which
        then changes nothing."""
        link = self.link(msg.sender)
        if msg.seq >> 32 > link.applied >> 32 and link.applied:
            link.restart()  # the neighbour restarted: it may have lost what it had of us
        link.acknowledged(msg.ack)
        if link.needs_whole and msg.delta:
            return False  # a delta on what this agent held before its restart
        if not link.accept(msg.seq):
            return False
        link.needs_whole = False
        payload = moved if moved is not None else msg.payload
        if self.layers is not None:
            self.apply_layers(msg.sender, payload)
        elif self.exact:
            self.apply_contribution(msg.sender, payload, msg.delta)
        else:
            fuse_into(
                self.map,
                payload,
                rule=self.core_rule,
                unknown=unknown,
                loss=self.loss,
                threads=threads,
            )
        return True

    def apply_contribution(self, sender: str, payload: OccupancyMap, delta: bool) -> None:
        """The channel filter's fusion, without sequence numbers: ``l += m - c``, ``c = m`` on
        the payload's voxels for a delta, everywhere for a whole contribution."""
        link = self.link(sender)
        if delta:
            if link.received is None:
                link.received = empty_like(self.map)
            self.map.assign_delta(link.received, payload)
            return
        add_into(self.map, payload)
        if link.received is not None:
            subtract_into(self.map, link.received)
        # kept as it came: a whole contribution is never modified (copied if not unclamped)
        link.received = payload if is_open(payload) else unclamped_copy(payload)

    def apply_layers(self, sender: str, payload: LayeredPayload) -> None:
        """Source layers' merge, without sequence numbers: per source the newer version; what
        ``sender`` holds is learnt (no layer it holds is sent back to it)."""
        link = self.link(sender)
        for p in payload.parts:
            if p.map is None:  # a version the sender holds
                link.learn(p.source, p.version)
        changes = self.layers.merge(payload.parts)
        for c in changes:
            link.learn(c.source, c.new)
        self._advanced(changes)
        self._forget_caught_up()
        self.fit_budget()

    def _advanced(self, changes: list[Change]) -> None:
        """Layers replaced: every link keeps what its neighbour now lacks."""
        for c in changes:
            for link in self.links.values():
                link.advanced(c.source, c.old, c.new, c.diff)

    def _forget_caught_up(self) -> None:
        """No changes kept for neighbours that hold a layer's version held here."""
        held = self.layers.versions()
        for link in self.links.values():
            for s, (v, changes) in list(link.known.items()):
                if changes is not None and v >= held.get(s, 0):
                    link.caught_up(s)

    def fit_budget(self) -> None:
        """Source layers over their memory budget (the layers and the changes the links keep
        for deltas) let go of the changes (those layers go whole next: still exact), then
        fold layers (exact no more, :meth:`~.source_layers.Layers.fold_to_budget`)."""
        budget = self.layers.max_bytes
        if budget and sum(m.memory_bytes for m in self.held_maps()) > budget:
            for link in self.links.values():
                link.forget_changes()
            self.layers.fold_to_budget()

    def exchange_with(
        self, other: Agent, *, unknown: UnknownPolicy = UnknownPolicy.COPY
    ) -> tuple[int, int]:
        """A two-way exchange of whole maps, both fused in one walk (a per-voxel rule, both
        agents in one frame). Returns the leaves of this agent's and ``other``'s map as sent
        (the two messages' voxels)."""
        for a, b in ((self, other), (other, self)):
            seq, _ = a.link(b.name).outgoing(a.map, delta=False, reliable=True)
            b.link(a.name).accept(seq)
        return exchange_maps(
            self.map,
            other.map,
            rule=self.core_rule,
            unknown=unknown,
            loss_a=self.loss,
            loss_b=other.loss,
        )

    def held_maps(self) -> list[OccupancyMap]:
        """The maps the links hold, and source layers' layers (for memory accounting)."""
        held = [m for link in self.links.values() for m in link.maps()]
        if self.layers is not None:
            held += self.layers.maps()
        return list({id(m): m for m in held}.values())
