"""One robot's map under one rule, its links, and the messages it sends and applies.

An :class:`Agent` is what runs on a robot: it composes a message for a neighbour
(:meth:`Agent.compose`) and applies what a neighbour sent (:meth:`Agent.deliver`), keeping the
link protocol's state per neighbour (:class:`~.link.Link`). Whoever drives the agents (the
simulation in bag time, rounds on finished maps, a swarm's actors) decides when they talk and
how a message travels: as a :class:`MapMessage` within a process, or as the bytes of
:meth:`MapMessage.encode` between processes.

Rules: every per-voxel rule fuses what arrives into the agent's map (its loss map carried by
the map); the channel filter (:mod:`.channel_filter`) sends its map minus what it got from the
receiver and replaces the sender's previous contribution, on unclamped maps.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from ..config import CHANNEL_FILTER
from ..maps.infoloss import InfoLossMap
from ..maps.occupancy import OccupancyMap
from ..maps.tree_fusion import exchange_maps, fuse_into, subtract_into
from .channel_filter import add_into, is_open, open_map, unclamped_copy
from .link import Link
from .wire import DEFAULT_MAX_PAYLOAD, Kind, Message, decode


@dataclass
class MapMessage:
    """A message within a process: the header's values and the payload as a map."""

    sender: str
    receiver: str
    rule: str
    seq: int  #: 1, 2, ... per link and direction
    ack: int  #: the newest seq the sender has applied from the receiver (0: none)
    payload: OccupancyMap  #: the sender's map (or contribution), whole or its changed voxels
    delta: bool  #: applied voxel by voxel (the payload holds changed voxels only)

    def encode(self, fleet: str = "", payload: Optional[bytes] = None) -> bytes:
        """The message as one frame (:mod:`.wire`); ``payload``: the payload's ``.ot`` stream,
        if it was written already."""
        return Message(fleet, self.rule, self.sender, self.receiver, self.seq, self.ack,
                       Kind.DELTA if self.delta else Kind.WHOLE,
                       payload if payload is not None else self.payload.to_bytes()).encode()

    @classmethod
    def decode(cls, frame: bytes, max_payload: int = DEFAULT_MAX_PAYLOAD) -> "MapMessage":
        """The message of a frame; ``WireError`` if the frame is not one, and the map
        stream's error if its payload is not a map."""
        msg = decode(frame, max_payload)
        payload = OccupancyMap.from_bytes(msg.payload)
        if msg.rule == CHANNEL_FILTER:
            open_map(payload)  # contributions are unclamped (a stream keeps no clamping)
        return cls(msg.sender, msg.receiver, msg.rule, msg.seq, msg.ack, payload,
                   msg.kind == Kind.DELTA)


class Agent:
    """Agent ``name``'s map under ``rule``, fused in place, and its links by neighbour."""

    def __init__(self, name: str, rule: str, map: OccupancyMap):
        self.name, self.rule, self.map = name, rule, map
        self.exact = rule == CHANNEL_FILTER
        if self.exact:
            open_map(map)  # clamping breaks the additivity exact fusion needs
        self.links: dict[str, Link] = {}
        self._loss: Optional[InfoLossMap] = None

    def link(self, neighbour: str) -> Link:
        """The state of the link to ``neighbour`` (made on first use)."""
        link = self.links.get(neighbour)
        if link is None:
            link = self.links[neighbour] = Link(neighbour)
        return link

    @property
    def loss(self) -> Optional[InfoLossMap]:
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

    # -- sending -----------------------------------------------------------------------------
    def compose(self, to: str, *, delta: bool = False, reliable: bool = True,
                state: Optional[OccupancyMap] = None) -> MapMessage:
        """The message for neighbour ``to`` now: the map (``state`` if given: the map as it was
        at an earlier moment), or the channel filter's contribution; with ``delta``, only what
        changed since the snapshot the neighbour is known to hold."""
        link = self.link(to)
        if self.exact:
            snapshot = unclamped_copy(self.map)
            if link.received is not None:
                subtract_into(snapshot, link.received)
        else:
            snapshot = state if state is not None else self.map
            if delta:  # kept as the next baseline: a copy of the map as sent
                snapshot = snapshot.copy()
        whole = link.sends_whole()
        seq, payload = link.outgoing(snapshot, delta=delta, reliable=reliable)
        if self.exact and payload is not snapshot:
            open_map(payload)
        return MapMessage(self.name, to, self.rule, seq, link.applied, payload,
                          delta and not whole)

    # -- receiving ---------------------------------------------------------------------------
    def deliver(self, msg: MapMessage, *, unknown: str = "copy", threads: int = 1,
                moved: Optional[OccupancyMap] = None) -> bool:
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
        if self.exact:
            self.apply_contribution(msg.sender, payload, msg.delta)
        else:
            fuse_into(self.map, payload, rule=self.rule, unknown=unknown, loss=self.loss,
                      threads=threads)
        return True

    def apply_contribution(self, sender: str, payload: OccupancyMap, delta: bool) -> None:
        """The channel filter's fusion, without sequence numbers: ``l += m - c``, ``c = m`` on
        the payload's voxels for a delta, everywhere for a whole contribution."""
        link = self.link(sender)
        if delta:
            if link.received is None:
                m = self.map
                link.received = open_map(OccupancyMap(m.resolution, m.prob_hit, m.prob_miss,
                                                      m.clamping))
            self.map.assign_delta(link.received, payload)
            return
        add_into(self.map, payload)
        if link.received is not None:
            subtract_into(self.map, link.received)
        # kept as it came: a whole contribution is never modified (copied if not unclamped)
        link.received = payload if is_open(payload) else unclamped_copy(payload)

    def exchange_with(self, other: "Agent", *, unknown: str = "copy") -> tuple[int, int]:
        """A two-way exchange of whole maps, both fused in one walk (a per-voxel rule, both
        agents in one frame). Returns the leaves of this agent's and ``other``'s map as sent
        (the two messages' voxels)."""
        for a, b in ((self, other), (other, self)):
            seq, _ = a.link(b.name).outgoing(a.map, delta=False, reliable=True)
            b.link(a.name).accept(seq)
        return exchange_maps(self.map, other.map, rule=self.rule, unknown=unknown,
                             loss_a=self.loss, loss_b=other.loss)

    def held_maps(self) -> list[OccupancyMap]:
        """The maps the links hold (for memory accounting)."""
        return [m for link in self.links.values() for m in link.maps()]
