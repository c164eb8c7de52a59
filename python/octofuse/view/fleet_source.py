"""A live fleet as the viewer's source: every agent's fused map as it publishes it
(``octomap_msgs/Octomap`` CDR on its map key, :mod:`octofuse.live.keys`) and its links' state
from its status (the messages each link delivered, as fusion events), read from the fleet's
Zenoh peers. The page is redrawn when a map arrives.
A :class:`.source.MapSource` without a centralized map or scores (those come when the fleet
has ended, in its output folder).
"""

from __future__ import annotations

import json
import threading
from collections.abc import Callable

import numpy as np

from ..config import FleetConfig
from ..maps.occupancy import OccupancyMap
from .voxels import Voxels, occupied_voxels


class FleetSource:
    """The maps and link states of the running fleet ``cfg`` (agents resolved)."""

    def __init__(self, cfg: FleetConfig):
        from ..fusion.graph import make_graph
        from ..live import keys
        from ..live.transport import endpoint, open_session
        from ..outputs.rosbag_export import typestore

        self.cfg = cfg
        self.agents = [a.name for a in cfg.build.agents]
        self.rules = list(cfg.fuse.rules)
        graph = make_graph(
            cfg.fuse.topology, len(self.agents), seed=cfg.fuse.seed, names=self.agents
        )
        self.links = [(self.agents[a], self.agents[b]) for a, b in graph.edges]
        self.title = f"live fleet {cfg.live.fleet}"
        self.events: list[dict] = []
        self.means: dict[str, dict] = {}
        self.loss_range: tuple[float, float] | None = None
        self.resolution = cfg.build.map.resolution
        self.status: dict[tuple[str, str], dict] = {}
        self.on_change: Callable[[], None] = lambda: None
        self._maps: dict[tuple[str, str], OccupancyMap] = {}
        self._lock = threading.Lock()
        self._ts = typestore(ros1=False)
        self._changed, self._closed = threading.Event(), threading.Event()
        threading.Thread(target=self._redraw, name="fleet-view", daemon=True).start()
        n = len(self.agents) * len(self.rules)
        self.session = open_session(
            cfg.live,
            endpoint(cfg.live, n + 1),
            [endpoint(cfg.live, k) for k in range(n)],
            "the viewer",
        )
        self._subs = [
            self.session.declare_subscriber(keys.statuses(cfg.live.fleet), self._on_status)
        ]
        for rule in self.rules:
            for agent in self.agents:
                self._subs.append(
                    self.session.declare_subscriber(
                        keys.fused_map(agent, rule if len(self.rules) > 1 else None),
                        lambda s, key=(rule, agent): self._on_map(key, s),
                    )
                )

    def _on_map(self, key: tuple[str, str], sample) -> None:
        try:
            msg = self._ts.deserialize_cdr(sample.payload.to_bytes(), "octomap_msgs/msg/Octomap")
            m = OccupancyMap.from_tree_data(np.asarray(msg.data).tobytes(), msg.resolution)
        except (ValueError, OSError, KeyError):
            return  # not a map: nothing to show
        with self._lock:
            self._maps[key] = m
        self._changed.set()

    def _redraw(self) -> None:
        """Call :attr:`on_change` once a second at most while maps arrive (a redraw reads
        them all)."""
        while not self._closed.is_set():
            if self._changed.wait(0.5) and not self._closed.is_set():
                self._changed.clear()
                self.on_change()
                self._closed.wait(1.0)

    def _on_status(self, sample) -> None:
        """An agent's status: each message it applied since its last one becomes a fusion
        event of its link (so the page's slider and link traffic follow the fleet)."""
        try:
            s = json.loads(sample.payload.to_bytes())
            rule, agent, links = s["rule"], s["agent"], s["links"]
            with self._lock:
                before = self.status.get((rule, agent), {}).get("links", {})
                self.status[rule, agent] = s
                for sender, state in sorted(links.items()):
                    new = state["applied"] - before.get(sender, {}).get("applied", 0)
                    self.events += [
                        {
                            "t": float(s["t"]),
                            "rule": rule,
                            "sender": sender,
                            "receiver": agent,
                            "voxels": None,
                            "loss": None,
                        }
                    ] * max(0, new)
        except (ValueError, KeyError, TypeError):
            pass

    # -- the page's questions --------------------------------------------------------------
    def has_central(self) -> bool:
        return False

    def agents_of(self, rule: str) -> list[str]:
        with self._lock:
            return [a for a in self.agents if (rule, a) in self._maps]

    def occupancy(self, rule: str, agent: str) -> Voxels:
        with self._lock:
            m = self._maps[rule, agent]
        return occupied_voxels(m.leaves())

    def loss(self, rule: str, agent: str) -> Voxels | None:
        return None  # a live agent publishes its map, not its loss

    def difference(self, rule: str, agent: str) -> Voxels:
        raise ValueError("a live fleet has no centralized map to compare with")

    def maps_received(self) -> dict[tuple[str, str], int]:
        """(rule, agent) -> leaves of the last map received."""
        with self._lock:
            return {k: m.num_leaves for k, m in self._maps.items()}

    def close(self) -> None:
        self._closed.set()
        for s in self._subs:
            s.undeclare()
        self.session.close()
