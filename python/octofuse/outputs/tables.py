"""The tables the commands print (rich), built from results."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from rich.table import Table


def build_table(result) -> Table:
    """Scans, points and leaves per agent of a :class:`~octofuse.maps.build.BuildResult`."""
    t = Table("agent", "topic", "scans used", "skipped", "points", "leaves", "seconds",
              title="octofuse build")
    for s in result.stats:
        t.add_row(s.name, s.topic, str(s.scans_used), str(s.scans_skipped), f"{s.points:,}",
                  f"{result.maps[s.name].num_leaves:,}", f"{s.seconds:.2f}")
    t.add_row("centralized", "(all)", str(sum(s.scans_used for s in result.stats)),
              str(sum(s.scans_skipped for s in result.stats)),
              f"{sum(s.points for s in result.stats):,}", f"{result.centralized.num_leaves:,}",
              f"{result.seconds:.2f}")
    return t


def skip_notes(result) -> list[str]:
    """One line per agent and reason for scans a build skipped, and per agent of LaserScans
    whether they were de-skewed."""
    return [f"{s.name}: skipped {n} scan(s): {reason}"
            for s in result.stats for reason, n in sorted(s.skipped.items())] + [
        deskew_note(s) for s in result.stats if getattr(s, "laserscans", 0)] + list(result.notes)


def deskew_note(s) -> str:
    """Whether an agent's LaserScans were de-skewed (:class:`~octofuse.scans.source.AgentStats`)."""
    if s.deskewed == s.laserscans:
        return f"{s.name}: de-skewed all {s.laserscans} LaserScan(s) (beam times from time_increment)"
    if s.deskewed:
        return (f"{s.name}: de-skewed {s.deskewed} of {s.laserscans} LaserScan(s); the others have "
                "time_increment 0 (or no points)")
    return f"{s.name}: LaserScans not de-skewed (time_increment 0, or de-skew off)"


def scores_table(res, title: str) -> Table:
    """Mean scores per rule of a :class:`~octofuse.fusion.results.SimResult`."""
    from .report import mean_scores

    t = Table("rule", "KL(central‖agent)", "over-confident", "agreement", "coverage",
              "loss mean", "loss p95", title=title)
    for rule, row in mean_scores(res.scores).items():
        def cell(key, fmt):
            return "–" if row.get(key) is None else fmt.format(row[key])
        t.add_row(rule, cell("kl_mean", "{:.4f}"), cell("overconfidence", "{:.1%}"),
                  cell("agreement", "{:.1%}"), cell("coverage", "{:.1%}"),
                  cell("loss_mean", "{:.3f}"), cell("loss_p95", "{:.3f}"))
    return t


def map_info_table(paths: Sequence[Path]) -> Table:
    """Resolution, leaves, occupied/free leaves and memory of map files."""
    import numpy as np

    from ..maps.occupancy import OccupancyMap

    t = Table("map", "resolution", "leaves", "occupied", "free", "memory MB")
    for p in paths:
        m = OccupancyMap.load(p)
        v = m.leaves().values
        t.add_row(str(p), f"{m.resolution:g}", f"{m.num_leaves}", f"{int(np.sum(v > 0))}",
                  f"{int(np.sum(v <= 0))}", f"{m.memory_bytes / 1e6:.1f}")
    return t
