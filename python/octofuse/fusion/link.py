"""One agent's state of its link to one neighbour: the link protocol.

Both directions of a link run the same protocol, whatever the rule:

* every message carries a sequence number (1, 2, ... per direction) and an acknowledgement,
  the newest sequence number its sender has applied from the receiver;
* a receiver applies a message only if it is newer than the newest it applied on the link, so
  a repeated or overtaken message changes nothing (it is contained in the newer one);
* with deltas, a sender sends the voxels changed since the last snapshot the receiver is known
  to hold: on a lossless link the last one sent, otherwise the last one acknowledged (what was
  not acknowledged is sent again until it is).

The channel filter also keeps, per link, the neighbour's last contribution (:attr:`received`);
source layers keep, per source, the version the neighbour is known to hold (:attr:`known`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..maps.occupancy import OccupancyMap


@dataclass
class Link:
    """What an agent keeps of its link to ``neighbour``."""

    neighbour: str
    #: the sequence number of the last message sent to the neighbour
    seq: int = 0
    #: the newest sequence number applied from the neighbour (0: none)
    applied: int = 0
    #: with deltas: the snapshot the next delta is taken against (known to be held there)
    baseline: OccupancyMap | None = None
    #: with deltas on a lossy link: the snapshots sent and not acknowledged yet (seq -> map)
    pending: dict[int, OccupancyMap] = field(default_factory=dict)
    #: the channel filter's common information: the neighbour's last applied contribution
    received: OccupancyMap | None = None
    #: after a restart (this agent's or the neighbour's): send whole maps until the first of
    #: them (its sequence number here) is acknowledged
    resync: int = 0
    #: after this agent's restart: apply no delta of the neighbour before a whole map
    needs_whole: bool = False
    #: source layers: per source, the newest version the neighbour is known to hold (sent on
    #: a lossless link, acknowledged, or named by the neighbour) and the steps of this agent's
    #: layer since (from version, to version, the voxels that changed; None: not known, the
    #: next goes whole). A step's map is shared by every link that needs it
    known: dict[str, tuple[int, list[tuple[int, int, OccupancyMap]] | None]] = field(
        default_factory=dict
    )
    #: source layers on a lossy link: the versions sent and not acknowledged yet (seq -> them)
    pending_layers: dict[int, list[tuple[str, int]]] = field(default_factory=dict)

    def outgoing(
        self,
        snapshot: OccupancyMap,
        *,
        delta: bool,
        reliable: bool,
        max_nodes: int | None = None,
    ) -> tuple[int, OccupancyMap]:
        """The next message's sequence number and payload for ``snapshot`` (what the agent
        sends now, a map of its own): the snapshot itself, or with ``delta`` its voxels changed
        since :attr:`baseline`. With ``max_nodes`` (deltas only) a payload of more nodes keeps
        its most informative voxels (:meth:`~OccupancyMap.most_informative`); the others stay
        changed against the next baseline and go in later messages. What the neighbour then
        holds becomes the baseline (``reliable``) or waits for its acknowledgement."""
        self.seq += 1
        if self.resync < 0:
            self.resync = self.seq
        if not delta:
            return self.seq, snapshot
        whole = self.sends_whole() or self.baseline is None
        payload = snapshot if whole else snapshot.changed_since(self.baseline)
        held = snapshot
        if max_nodes is not None and payload.num_nodes > max_nodes:
            # a whole map replaces what the neighbour had: it then holds the part sent alone
            base = empty_like(snapshot) if whole else self.baseline
            payload, _ = payload.most_informative(base, max_nodes)
            held = base.overlaid(payload)
        if reliable:
            self.baseline = held
        else:
            self.pending[self.seq] = held
        return self.seq, payload

    def acknowledged(self, ack: int) -> None:
        """The neighbour has applied this agent's messages up to ``ack``: the snapshot of
        ``ack`` becomes the baseline and older ones are let go."""
        if self.resync > 0 and ack >= self.resync:
            self.resync = 0
        if ack in self.pending:
            self.baseline = self.pending[ack]
            for k in [k for k in self.pending if k <= ack]:
                del self.pending[k]
        for k in [k for k in self.pending_layers if k <= ack]:
            for source, version in self.pending_layers.pop(k):
                self.learn(source, version)

    def sent_layers(self, layers: list[tuple[str, int]], *, reliable: bool) -> int:
        """The next message's sequence number, for one carrying ``layers`` (source, version):
        known to be held at once (``reliable``) or once acknowledged."""
        self.seq += 1
        if reliable:
            for source, version in layers:
                self.learn(source, version)
        elif layers:
            self.pending_layers[self.seq] = layers
        return self.seq

    def learn(self, source: str, version: int) -> None:
        """The neighbour holds ``version`` of ``source``'s layer (or a newer one): the steps
        that end by it are not needed."""
        held, steps = self.known.get(source, (0, None))
        if version > held:
            self.known[source] = (
                version,
                None if steps is None else [x for x in steps if x[1] > version],
            )

    def advanced(self, source: str, old: int, new: int, delta) -> None:
        """This agent's layer of ``source`` went from version ``old`` to ``new``; ``delta()``
        gives the voxels that changed (called only if needed). A neighbour that held ``old``
        or newer lacks that step; one further behind, its earlier steps too; one whose steps
        are not known, the whole layer."""
        held, steps = self.known.get(source, (0, None))
        if held >= new or held == 0:
            return
        if old and held >= old:
            self.known[source] = (held, [(old, new, delta())])
        elif steps is not None:
            self.known[source] = (held, [*steps, (old, new, delta())])

    def caught_up(self, source: str) -> None:
        """The neighbour holds this agent's layer of ``source``: no steps to keep."""
        held, _ = self.known.get(source, (0, None))
        self.known[source] = (held, None)

    def forget_changes(self) -> None:
        """Let go of the changes kept for deltas: the layers go whole next (traffic for
        memory, still exact)."""
        self.known = {s: (v, None) for s, (v, _) in self.known.items()}

    def restart(self) -> None:
        """What either side held of the other may be gone: deltas start again from whole maps."""
        self.baseline = None
        self.pending.clear()
        self.resync = -1  # set to the first whole map's number when it is sent
        self.known.clear()  # source layers: what the neighbour holds is not known any more
        self.pending_layers.clear()

    def sends_whole(self) -> bool:
        return self.resync != 0

    def accept(self, seq: int) -> bool:
        """Whether a message numbered ``seq`` from the neighbour is newer than every one
        applied; if so it counts as applied."""
        if seq <= self.applied:
            return False
        self.applied = seq
        return True

    def maps(self) -> list[OccupancyMap]:
        """The maps this link holds (for memory accounting)."""
        held = [
            self.baseline,
            self.received,
            *self.pending.values(),
            *(m for _, steps in self.known.values() for _, _, m in steps or ()),
        ]
        return [m for m in held if m is not None]


def empty_like(m: OccupancyMap) -> OccupancyMap:
    """An empty map of ``m``'s parameters (its clamping too: open stays open)."""
    out = OccupancyMap(m.resolution, m.prob_hit, m.prob_miss, m.clamping)
    return out.open_clamping() if m.clamping_logodds == (-math.inf, math.inf) else out
