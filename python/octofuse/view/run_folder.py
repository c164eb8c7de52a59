"""A run's output folder (``octofuse run``/``demo``/``fuse --out``) as the viewer's source:
its agents, rules, links, fusion events and scores from ``summary.json``, its maps from
``centralized.ot`` and ``RULE/AGENT.ot``, its losses from the heat maps
``RULE/AGENT_info_loss.ply`` (or ``.pcd``). Maps are read when first shown, then kept.
A :class:`.source.MapSource`.
"""

from __future__ import annotations

import json
import threading
from pathlib import Path

import numpy as np

from ..config import MapConfig
from ..maps.frames import pose_matrix
from ..maps.occupancy import OccupancyMap
from ..outputs.clouds import CLOUD_SUFFIXES, read_cloud
from .difference import difference_voxels
from .voxels import Voxels, occupied_voxels

CENTRALIZED = "centralized"


class RunFolder:
    """The maps, events and scores of one run's output folder."""

    def __init__(self, folder: str | Path):
        self.folder = Path(folder)
        path = self.folder / "summary.json"
        if not path.is_file():
            raise FileNotFoundError(
                f"'{self.folder}' is not the output folder of a run "
                "(no summary.json): give the --out folder of octofuse "
                "run, demo or fuse"
            )
        s = json.loads(path.read_text())
        self.title = str(self.folder)
        self.agents: list[str] = list(s["agents"])
        self.rules: list[str] = list(s["rules"])
        #: links as (agent, agent) names
        self.links = [(self.agents[a], self.agents[b]) for a, b in s["graph"]["edges"]]
        self.events: list[dict] = list(s.get("fusion_events", []))
        self.means: dict[str, dict] = dict(s.get("mean", {}))
        rng = (s.get("exports") or {}).get("range")
        self.loss_range: tuple[float, float] | None = tuple(rng) if rng else None
        cfg = s.get("config", {})
        self.resolution = float(
            cfg.get("build", {}).get("map", {}).get("resolution", MapConfig.resolution)
        )
        self.tol = float(cfg.get("fuse", {}).get("overconfidence_tol", 0.1))
        self.frames = {a: pose_matrix(**p) for a, p in (s.get("agent_frames") or {}).items()}
        self.on_change = lambda: None  # a finished run's maps do not change
        self._leaves: dict = {}
        self._lock = threading.Lock()  # the page's callbacks run on threads

    # -- what there is ---------------------------------------------------------------
    def agents_of(self, rule: str) -> list[str]:
        """The agents whose fused map of ``rule`` the folder holds."""
        return [a for a in self.agents if (self.folder / rule / f"{a}.ot").is_file()]

    def has_central(self) -> bool:
        return (self.folder / "centralized.ot").is_file()

    # -- maps --------------------------------------------------------------------------
    def leaves(self, rule: str, agent: str):
        """The leaves of a map in the common frame: ``rule`` :data:`CENTRALIZED` for the
        centralized map (``agent`` then ignored), else the agent's fused map of ``rule``."""
        key = (CENTRALIZED, "") if rule == CENTRALIZED else (rule, agent)
        with self._lock:
            if key not in self._leaves:
                self._leaves[key] = self._load(*key)
            return self._leaves[key]

    def _load(self, rule: str, agent: str):
        if rule == CENTRALIZED:
            return OccupancyMap.load(self.folder / "centralized.ot").leaves()
        m = OccupancyMap.load(self.folder / rule / f"{agent}.ot")
        T = self.frames.get(agent)
        if T is not None:
            from ..fusion.agent_frames import moved

            m = moved(m, T)
        return m.leaves()

    def occupancy(self, rule: str, agent: str) -> Voxels:
        """The occupied voxels of a map (:meth:`leaves`), valued by their log-odds."""
        return occupied_voxels(self.leaves(rule, agent))

    def loss(self, rule: str, agent: str) -> Voxels | None:
        """The occupied voxels of an agent's fused map with their accumulated information loss
        (its heat map), None where the run wrote none (naive Bayes, ``--export fused``)."""
        for suffix in CLOUD_SUFFIXES:
            path = self.folder / rule / f"{agent}_info_loss{suffix}"
            if path.is_file():
                c = read_cloud(path)
                v = Voxels(
                    np.asarray(c["positions"], dtype=np.float64),
                    np.asarray(c["voxel_size"], dtype=np.float64),
                    np.asarray(c["info_loss"], dtype=np.float32),
                )
                return v.moved(self.frames.get(agent))
        return None

    def difference(self, rule: str, agent: str) -> Voxels:
        """The agent's fused map against the centralized map (:mod:`.difference`)."""
        return difference_voxels(
            self.leaves(rule, agent), self.leaves(CENTRALIZED, ""), self.resolution, self.tol
        )
