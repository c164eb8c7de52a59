"""Exact fusion on any graph, under any fault: per-source map layers (``source-layers``).

A map in log-odds is the sum of what each robot's own scans contributed to it. Every agent
keeps, per source robot it has heard of (itself included), the latest contribution of that
source it knows (a *layer*: the source's own map, unclamped) with the source's version
number. The exact fused map is then the sum of those layers, and merging two agents' states
takes, per source, the newer version: a merge that is commutative, associative and idempotent
(a state-based CRDT). So the fused map is exact on any topology, loops included, and neither
lost, repeated or reordered messages nor partitions harm it: a message is a set of values,
applying one twice changes nothing, and an older one than held is ignored.

What an agent does:

* its own scans go into its own layer and into its fused map (with open clamping a scan's
  update is an addition, so the map stays the sum). That is cheaper than summing the layers
  where the map is read: on lab8 at every 4th scan, inserting every robot's scans into one
  more map takes 0.57 s over the whole run (rays traced again; a run traces them once for
  every map), while summing the layers once for every agent takes 0.42 s, and the demo scores
  its maps 9 times. The own layer gets a new version when it is sent after it changed (a copy
  of it then: what the neighbours hold of it);
* a message to a neighbour carries, per source, what the neighbour is not known to hold: the
  whole layer on first contact, afterwards the voxels changed since the version the neighbour
  is known to hold (its acknowledged one on a lossy link, as :class:`~.link.Link` does for
  whole maps), and the versions of every layer the sender holds (so that neither side sends
  the other what it has, also for layers that reached both over other paths). The changes
  are kept as the steps of the layer since the neighbour's version (each replacement of the
  layer: the voxels it changed, from the delta received or the difference of the two
  versions), each step's map shared by the links that need it: smaller than a copy of the
  version the neighbour holds. A message merges them into one map;
* on receiving a newer version of a source it replaces the layer and keeps the fused map equal
  to the sum of the layers incrementally: ``l += new - old`` (a whole layer is added and the
  one it replaces subtracted; a delta is applied voxel by voxel, on the old layer in place or
  on a copy of it where another agent may hold the same map, in process). A delta holds the
  new values of every voxel changed since its base version, gathered step by step, hence of
  every voxel changed since any later version too: it applies to any version held from the
  base on (on a loopy graph a receiver often holds a newer version than the sender knew);
* the fused map, like the layers, is kept unclamped and clamped for scoring and writing only
  (as the channel filter's, :mod:`.channel_filter`).

The price is memory and traffic: an agent holds every source's layer (sparse: a source's layer
holds only what it saw) besides the fused map, and keeps, per link and source, the voxels
changed since the version its neighbour is known to hold. A budget,
:attr:`~octofuse.config.FuseConfig.layers_max_bytes`, bounds the bytes of layers an agent
holds, the changes kept for deltas included. Beyond it the agent first lets go of the changes
(a neighbour then gets those sources' next layers whole: traffic for memory, still exact); if
the layers alone are over it, the layer heard of least recently (never the agent's own) is
folded into one *remainder* map by the Chernoff rule (a weighted exponential product
``w l_a + (1 - w) l_b`` in log-odds, its weight chosen by the C++ core's Chernoff criterion).
Chernoff is chosen because a WEP rule is conservative whatever the inputs share: its value
lies between theirs, so a later version of a folded source, which contains what the remainder
already holds of it, is folded in again without being counted twice; and Chernoff is the
least over-confident of the WEP rules on the demo. Exactness ends there: a folded source's
information is no longer summed (and the remainder is not sent on: only exact layers are), and
:attr:`Layers.folded` counts the folded sources in the scores.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..maps.occupancy import OccupancyMap
from ..maps.tree_fusion import fuse_into, subtract_into
from ..rules import Rule, UnknownPolicy
from .channel_filter import add_into, is_open, open_map, unclamped_copy
from .wire import LayerBlob, decode_layers, encode_layers

#: the WEP rule that folds layers into the remainder (see the module's docstring)
FOLD_RULE = Rule.CHERNOFF


@dataclass
class LayerPart:
    """One source in a message: version ``version`` of its layer, whole (``base`` 0) or the
    voxels changed since version ``base``; ``map`` None: the sender holds that version."""

    source: str
    version: int
    base: int = 0
    map: OccupancyMap | None = None


@dataclass
class LayeredPayload:
    """A source-layers message's payload: its layers, and the versions its sender holds."""

    parts: list[LayerPart]
    resolution: float

    @property
    def num_nodes(self) -> int:
        return sum(p.map.num_nodes for p in self.parts if p.map is not None)

    @property
    def num_leaves(self) -> int:
        return sum(p.map.num_leaves for p in self.parts if p.map is not None)

    def to_bytes(self) -> bytes:
        """The payload as :func:`~.wire.encode_layers` writes it."""
        return encode_layers(
            [
                LayerBlob(
                    p.source,
                    p.version,
                    p.base,
                    p.map.to_bytes() if p.map is not None else b"",
                    p.map is None,
                )
                for p in self.parts
            ]
        )

    @classmethod
    def from_bytes(cls, data: bytes, resolution: float = 0.0) -> LayeredPayload:
        """The payload of :meth:`to_bytes` (its maps unclamped, as layers are kept)."""
        parts = [
            LayerPart(
                b.source,
                b.version,
                b.base,
                None if b.held else open_map(OccupancyMap.from_bytes(b.data)),
            )
            for b in decode_layers(data)
        ]
        maps = [p.map for p in parts if p.map is not None]
        return cls(parts, maps[0].resolution if maps else resolution)


@dataclass
class Layer:
    """One source's layer as held: its version, its unclamped map and when it was last replaced
    (the agent's message count). ``shared``: the map went into a message or came in one whole,
    so that others may hold it too (a delta then goes into a copy, otherwise in place)."""

    version: int
    map: OccupancyMap
    heard: int = 0
    shared: bool = False


@dataclass
class Change:
    """A layer replaced: ``source``'s version ``old`` (0: none) by ``new``; ``delta``: the new
    values of the voxels that changed, or None (then :meth:`diff` takes them from the maps)."""

    source: str
    old: int
    new: int
    old_map: OccupancyMap | None
    new_map: OccupancyMap
    delta: OccupancyMap | None = None

    def diff(self) -> OccupancyMap:
        """The voxels that changed, with their new values (computed once)."""
        if self.delta is None:
            self.delta = (
                self.new_map
                if self.old_map is None
                else open_map(self.new_map.changed_since(self.old_map))
            )
        return self.delta


def empty_like(m: OccupancyMap) -> OccupancyMap:
    """An empty unclamped map with ``m``'s resolution and sensor model."""
    return open_map(OccupancyMap(m.resolution, m.prob_hit, m.prob_miss, m.clamping))


def overwritten(changes: OccupancyMap, delta: OccupancyMap) -> OccupancyMap:
    """A copy of ``changes`` with ``delta``'s voxels set to its values: the changes of two
    steps in one."""
    out = unclamped_copy(changes)
    empty_like(out).assign_delta(out, delta)
    return out


@dataclass
class Layers:
    """An agent's layers and the fused map kept equal to their sum (plus the remainder)."""

    name: str
    own: OccupancyMap  #: the agent's own layer, into which its scans go
    fused: OccupancyMap
    max_bytes: int = 0
    layers: dict[str, Layer] = field(default_factory=dict)  #: the others' and own as sent
    remainder: OccupancyMap | None = None
    folded: dict[str, int] = field(default_factory=dict)  #: source -> newest version folded
    own_version: int = 0
    heard: int = 0

    def publish(self) -> Change | None:
        """A new version of the own layer if it changed since the last one (a copy). Whether
        it did is read from the maps (what changed is needed anyway), not told by whoever
        inserts the scans: inserting may be under way on another thread until the agent's
        next step."""
        old = self.layers.get(self.name)
        delta = None
        if old is not None:
            delta = open_map(self.own.changed_since(old.map))
            if delta.num_leaves == 0:
                return None
        self.own_version += 1
        self.layers[self.name] = Layer(self.own_version, unclamped_copy(self.own), self.heard)
        return Change(
            self.name,
            old.version if old else 0,
            self.own_version,
            old.map if old else None,
            self.layers[self.name].map,
            delta,
        )

    def versions(self) -> dict[str, int]:
        return {s: x.version for s, x in self.layers.items()}

    def parts_for(self, known: dict[str, tuple[int, list | None]]) -> list[LayerPart]:
        """What a neighbour lacks that holds ``known`` (source -> version, and the steps of
        the layer held here since, if known: :attr:`~.link.Link.known`): newer layers, as the
        voxels those steps changed or whole; then every version held."""
        parts = []
        for s, x in self.layers.items():
            v, steps = known.get(s, (0, None))
            if x.version <= v:
                continue
            if steps and v > 0:
                changes = steps[0][2]
                for _, _, later in steps[1:]:
                    changes = overwritten(changes, later)
                parts.append(LayerPart(s, x.version, v, changes))
            else:
                x.shared = True
                parts.append(LayerPart(s, x.version, 0, x.map))
        return parts + [LayerPart(s, v) for s, v in self.versions().items()]

    def merge(self, parts: list[LayerPart]) -> list[Change]:
        """Take, per source, the newer version (the CRDT merge); returns the layers replaced. A
        delta applies to a held version from its base on (see the module's docstring); one
        against a newer version than held is ignored (its sender learns the version held from
        this agent's next message and sends the whole layer)."""
        self.heard += 1
        taken = []
        for p in parts:
            if p.map is None or p.source == self.name:
                continue
            if p.source in self.folded:
                if p.version > self.folded[p.source] and p.base == 0:
                    self._fold(p.source, p.version, p.map)
                continue
            cur = self.layers.get(p.source)
            held = cur.version if cur is not None else 0
            if p.version <= held or p.base > held:  # older, or a delta of voxels it lacks
                continue
            if p.base:
                # what changed from the version held (the delta may hold more: changes since
                # an older one), kept for the neighbours
                changed = open_map(p.map.changed_since(cur.map))
                # in place unless others may hold the map (then into a copy, kept unshared)
                new = unclamped_copy(cur.map) if cur.shared else cur.map
                # new - old on the delta's voxels, then added: work in the delta's size, not
                # in the fused map's (assigning into the fused map prunes all of it)
                diff = empty_like(new)
                diff.assign_delta(new, p.map)
                add_into(self.fused, diff)
                self.layers[p.source] = Layer(p.version, new, self.heard)
                taken.append(Change(p.source, held, p.version, None, new, changed))
                continue
            new = p.map if is_open(p.map) else unclamped_copy(p.map)
            add_into(self.fused, new)
            if cur is not None:
                subtract_into(self.fused, cur.map)
            self.layers[p.source] = Layer(p.version, new, self.heard, shared=True)
            taken.append(Change(p.source, held, p.version, cur.map if cur else None, new))
        return taken

    # -- the memory budget -------------------------------------------------------------------
    def bytes_held(self) -> int:
        """Bytes of the layers held: the own layer, the others' and the remainder."""
        maps = {
            id(m): m
            for m in (self.own, self.remainder, *(x.map for x in self.layers.values()))
            if m is not None
        }
        return sum(m.memory_bytes for m in maps.values())

    def fold_to_budget(self) -> None:
        """Fold the layers heard of least recently (never the own) into the remainder until the
        layers held fit :attr:`max_bytes` (0: never)."""
        while self.max_bytes and self.bytes_held() > self.max_bytes:
            others = [s for s in self.layers if s != self.name]
            if not others:
                return
            s = min(others, key=lambda s: (self.layers[s].heard, s))
            x = self.layers.pop(s)
            subtract_into(self.fused, x.map)
            self._fold(s, x.version, x.map)

    def _fold(self, source: str, version: int, m: OccupancyMap) -> None:
        old = self.remainder
        new = unclamped_copy(m)
        if old is not None:
            new = unclamped_copy(old)
            fuse_into(new, m, rule=FOLD_RULE, unknown=UnknownPolicy.COPY)
        add_into(self.fused, new)
        if old is not None:
            subtract_into(self.fused, old)
        self.remainder = new
        self.folded[source] = max(version, self.folded.get(source, 0))

    def maps(self) -> list[OccupancyMap]:
        """The maps held besides the fused one (for memory accounting)."""
        return [
            m
            for m in (self.own, self.remainder, *(x.map for x in self.layers.values()))
            if m is not None
        ]
