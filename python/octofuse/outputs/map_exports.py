"""The map files of a run, written rule by rule: each rule's fused maps as they are finished,
keeping only what comes after (the heat maps' voxels, the loss histogram's values), then the
heat maps, colour bar and top views with one colour range for every rule."""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..config import EXACT_MODES, RunConfig
from ..fusion.results import SimResult
from ..rule_names import FusionRule
from ..threads import ThreadBudget, thread_map

#: rules drawn in the report's top views, in this order of preference (naive Bayes loses nothing)
TOPVIEW_RULES = (
    FusionRule.CHERNOFF,
    FusionRule.KLD_WEIGHTED_CHERNOFF,
    FusionRule.MIN_INFO_LOSS,
    FusionRule.ENTROPY_WEIGHTED_CHERNOFF,
    FusionRule.BHATTACHARYYA,
    FusionRule.MIN_ENTROPY,
)
COLORBAR = "info_loss_colorbar.png"


def topview_rules(rules: Sequence[str], n: int = 3) -> list[str]:
    """Up to ``n`` WEP rules of the run for the top views, in the run's order."""
    picked = [r for r in TOPVIEW_RULES if r in rules][:n]
    return [r for r in rules if r in picked]


class MapExports:
    """Writes the maps of ``rules`` into ``out`` as results arrive (:meth:`add`), so that a
    rule's maps can be freed once written; :meth:`finish` writes what needs every rule."""

    def __init__(
        self,
        out: Path,
        cfg: RunConfig,
        rules: Sequence[str],
        agents: Sequence[str],
        heatmaps: bool = True,
        threads: int | ThreadBudget = 1,
    ):
        self.out, self.cfg, self.agents = Path(out), cfg, list(agents)
        self.threads = threads  #: files written side by side: a budget, or a thread count
        self.views = topview_rules(rules)
        self.heatmaps = heatmaps and cfg.export == "all"
        #: (rule, agent) -> the occupied voxels with their loss, and the map's resolution
        self.voxels: dict = {}
        self.resolution: dict = {}
        #: rule -> the loss values (float32) and depths (uint8) of each agent's loss leaves:
        #: 5 bytes a leaf, for the loss histogram
        self.histogram: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
        self.seconds = 0.0  #: time spent writing
        self._central_written = False

    def add(self, res: SimResult) -> None:
        """Write the fused maps of every rule of ``res`` (and the centralized map once) and
        keep the heat maps' voxels and the histogram's values."""
        from .export import map_voxel_loss

        t0 = time.perf_counter()
        if self.cfg.export != "none":
            if res.central is not None and not self._central_written:
                res.central.save(self.out / "centralized.ot")
                self._central_written = True
            for r in res.rules:
                (self.out / r).mkdir(exist_ok=True)

        def one(job):  # a map written, its heat map's voxels taken
            r, a = job
            if self.cfg.export != "none":
                res.fused[r][a].save(self.out / r / f"{a}.ot")
            wanted = self.heatmaps or (r in self.views and a == self.agents[0])
            if wanted and res.loss[r][a].num_leaves > 0:
                return map_voxel_loss(res.loss[r][a], res.fused[r][a])
            return None

        jobs = [(r, a) for r in res.rules for a in self.agents]
        for (r, a), v in zip(jobs, thread_map(one, jobs, self.threads)):
            if v is not None and len(v.loss):
                self.voxels[(r, a)] = v
                self.resolution[(r, a)] = res.fused[r][a].resolution
        for r in res.rules:
            if r not in (FusionRule.NAIVE_BAYES, *EXACT_MODES):
                self.histogram[r] = thread_map(
                    lambda a: res.loss_leaves_of(r, a), res.agents, self.threads
                )
        self.seconds += time.perf_counter() - t0

    def finish(self) -> dict:
        """Heat maps (occupied voxels of each fused map, one colour range for the run), the
        colour bar and the report's top views; what was written, for the summary."""
        from .export import shared_color_range, write_colorbar, write_heatmap
        from .topview import write_topview

        t0 = time.perf_counter()
        cfg, out = self.cfg, self.out
        info: dict = {
            "export": cfg.export,
            "formats": list(cfg.formats),
            "heatmaps": [],
            "topviews": [],
            "range": None,
        }
        if not self.agents or not self.voxels:
            self.seconds += time.perf_counter() - t0
            return info
        lo, hi = shared_color_range(self.voxels.values())
        info["range"] = [lo, hi]
        if self.heatmaps:
            jobs = [
                (v, out / r / f"{a}_info_loss.{ext}")
                for (r, a), v in self.voxels.items()
                for ext in cfg.formats
            ]
            info["heatmaps"] = [
                p.name
                for p in thread_map(
                    lambda job: write_heatmap(job[0], job[1], vmin=lo, vmax=hi), jobs, self.threads
                )
            ]
            write_colorbar(out / COLORBAR, "inferno", lo, hi, label="information loss [nats]")
            info["colorbar"] = COLORBAR
        first = self.agents[0]
        for r in self.views:
            v = self.voxels.get((r, first))
            if v is not None:
                name = f"topview_{r}.png"
                write_topview(
                    v,
                    self.resolution[(r, first)],
                    out / name,
                    vmin=lo,
                    vmax=hi,
                    title=f"{first}, {r}: accumulated information loss of the "
                    "occupied voxels (max over height)",
                )
                info["topviews"].append({"rule": r, "agent": first, "file": name})
        self.seconds += time.perf_counter() - t0
        return info
