"""An agent's state kept across a restart: its maps, its links and how far its mission got.

Written whole to a temporary name beside the checkpoint and renamed over it (after an fsync),
so a kill at any moment leaves the previous checkpoint or the new one, never a mix. Maps are
OctoMap streams; the rest is plain data (source layers included). The information-loss maps
are not kept: after a restart an agent counts its loss from there.

A restarted agent starts a new *epoch*: its sequence numbers continue above every number it
used before (``epoch << 32``), so its neighbours take its messages as new, and it resynchronises
every link: it sends whole maps until one is acknowledged and applies no delta of a neighbour
before that neighbour's next whole map (what either side held of the other may be older than
the checkpoint).
"""

from __future__ import annotations

import contextlib
import os
import pickle
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

from ..fusion.agent import Agent
from ..fusion.channel_filter import open_map
from ..maps.occupancy import OccupancyMap
from ..outputs.staging import written_then_renamed

VERSION = 1


def _stream(m: OccupancyMap | None) -> bytes | None:
    return None if m is None else m.to_bytes()


def _map(data: bytes | None, exact: bool) -> OccupancyMap | None:
    if data is None:
        return None
    m = OccupancyMap.from_bytes(data, "checkpoint")
    return open_map(m) if exact else m


@contextlib.contextmanager
def written(path: Path, fsync: bool = False) -> Iterator[BinaryIO]:
    """A file to write the new content of ``path`` into: written under a temporary name beside
    it and renamed over it once complete (after an fsync with ``fsync``), so ``path`` holds its
    old content or the new one, never a part."""
    with written_then_renamed(Path(path)) as tmp, open(tmp, "wb") as f:
        yield f
        if fsync:
            f.flush()
            os.fsync(f.fileno())


def save(path: Path, agent: Agent, local: OccupancyMap, progress: dict) -> None:
    """Write ``agent``'s state, its own map ``local`` and ``progress`` (plain data) to
    ``path`` atomically."""
    state = {
        "version": VERSION,
        "name": agent.name,
        "rule": agent.rule,
        "progress": progress,
        "map": agent.map.to_bytes(),
        "local": local.to_bytes(),
        "links": {
            n: {"seq": link.seq, "applied": link.applied, "received": _stream(link.received)}
            for n, link in agent.links.items()
        },
        "layers": _layers_state(agent.layers) if agent.layers is not None else None,
    }
    with written(path, fsync=True) as f:
        pickle.dump(state, f, protocol=pickle.HIGHEST_PROTOCOL)


def restore(path: Path, agent: Agent, epoch: int) -> tuple[OccupancyMap, dict]:
    """Load the checkpoint at ``path`` into ``agent`` (its map and links, numbering its
    messages in ``epoch``: above every epoch it started before) and return its own map and
    the progress saved with it. ``ValueError`` naming the file if it is not a checkpoint of
    this agent."""
    try:
        with open(path, "rb") as f:
            state = pickle.load(f)
    except (OSError, pickle.UnpicklingError, EOFError) as e:
        raise ValueError(f"checkpoint '{path}' cannot be read: {e}") from None
    if not isinstance(state, dict) or state.get("version") != VERSION:
        raise ValueError(f"checkpoint '{path}': not an octofuse checkpoint of version {VERSION}")
    if (state["name"], state["rule"]) != (agent.name, agent.rule):
        raise ValueError(
            f"checkpoint '{path}' is agent {state['name']}'s under {state['rule']}, "
            f"not {agent.name}'s under {agent.rule}"
        )
    exact = agent.exact
    agent.map = _map(state["map"], exact)
    agent.reset_loss()
    if agent.layers is not None:
        _restore_layers(agent, state["layers"], epoch)
    agent.links.clear()
    for n, saved in state["links"].items():
        link = agent.link(n)
        link.seq = epoch << 32
        link.applied = saved["applied"]
        link.received = _map(saved["received"], exact)
        link.restart()
        link.needs_whole = True
    return _map(state["local"], False), state["progress"]


def _layers_state(layers) -> dict:
    """Source layers as plain data: every layer's version and map, the own layer, the
    remainder of folded layers."""
    return {
        "own": layers.own.to_bytes(),
        "own_version": layers.own_version,
        "heard": layers.heard,
        "folded": dict(layers.folded),
        "remainder": _stream(layers.remainder),
        "layers": {src: (x.version, x.map.to_bytes(), x.heard) for src, x in layers.layers.items()},
    }


def _restore_layers(agent: Agent, saved: dict, epoch: int) -> None:
    """The layers of a checkpoint, the own layer's versions numbered in ``epoch``: above every
    version a neighbour may hold of it, so they take the restarted one as newer."""
    from ..fusion.source_layers import Layer

    layers = agent.layers
    layers.own = _map(saved["own"], True)
    layers.fused = agent.map
    layers.heard, layers.folded = saved["heard"], dict(saved["folded"])
    layers.remainder = _map(saved["remainder"], True)
    layers.layers = {
        src: Layer(version, _map(data, True), heard)
        for src, (version, data, heard) in saved["layers"].items()
    }
    layers.own_version = max(saved["own_version"], epoch << 32)


def next_epoch(path: Path) -> int:
    """The number of this start of an agent (1, 2, ...), counted in the file ``path``."""
    path = Path(path)
    try:
        epoch = int(path.read_text()) + 1
    except (OSError, ValueError):
        epoch = 1
    with written(path) as f:
        f.write(str(epoch).encode())
    return epoch
