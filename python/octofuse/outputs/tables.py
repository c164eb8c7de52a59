"""The tables the commands print (rich), built from results."""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

from rich.markup import escape
from rich.table import Table


def build_table(result) -> Table:
    """Scans, points and leaves per agent of a :class:`~octofuse.maps.build.BuildResult`."""
    t = Table(
        "agent",
        "topic",
        "scans used",
        "skipped",
        "points",
        "leaves",
        "seconds",
        title="octofuse build",
    )
    for s in result.stats:
        t.add_row(
            s.name,
            s.topic,
            str(s.scans_used),
            str(s.scans_skipped),
            f"{s.points:,}",
            f"{result.maps[s.name].num_leaves:,}",
            f"{s.seconds:.2f}",
        )
    t.add_row(
        "centralized",
        "(all)",
        str(sum(s.scans_used for s in result.stats)),
        str(sum(s.scans_skipped for s in result.stats)),
        f"{sum(s.points for s in result.stats):,}",
        f"{result.centralized.num_leaves:,}",
        f"{result.seconds:.2f}",
    )
    return t


def skip_notes(result) -> list[str]:
    """One line per agent and reason for scans a build skipped, and per agent of LaserScans
    whether they were de-skewed."""
    return (
        [
            f"{s.name}: skipped {n} scan(s): {reason}"
            for s in result.stats
            for reason, n in sorted(s.skipped.items())
        ]
        + [deskew_note(s) for s in result.stats if getattr(s, "laserscans", 0)]
        + list(result.notes)
    )


def deskew_note(s) -> str:
    """Whether an agent's LaserScans were de-skewed (:class:`~octofuse.scans.source.AgentStats`)."""
    if s.deskewed == s.laserscans:
        return (
            f"{s.name}: de-skewed all {s.laserscans} LaserScan(s) (beam times from time_increment)"
        )
    if s.deskewed:
        return (
            f"{s.name}: de-skewed {s.deskewed} of {s.laserscans} LaserScan(s); the others have "
            "time_increment 0 (or no points)"
        )
    return f"{s.name}: LaserScans not de-skewed (time_increment 0, or de-skew off)"


#: the scores table's columns: (key, header, header on two lines for a narrow terminal, format)
SCORE_COLUMNS = (
    ("kl_mean", "KL(central‖agent)", "KL(central\n‖agent)", "{:.4f}"),
    ("overconfidence", "over-confident", "over-\nconfident", "{:.1%}"),
    ("agreement", "agreement", "agree-\nment", "{:.1%}"),
    ("coverage", "coverage", "cover-\nage", "{:.1%}"),
    ("loss_mean", "loss mean", "loss\nmean", "{:.3f}"),
    ("loss_p95", "loss p95", "loss\np95", "{:.3f}"),
)


def scores_table(res, title: str, width: int | None = None) -> Table:
    """Mean scores per rule of a :class:`~octofuse.fusion.results.SimResult`; headers on two
    lines and rule names broken at their hyphens when the table would not fit ``width``
    columns otherwise."""
    from .report import mean_scores

    rows = mean_scores(res.scores)
    t = _scores_table(rows, title, narrow=False)
    if width is not None and _width(t) > width:
        t = _scores_table(rows, title, narrow=True)
    return t


def _scores_table(rows: dict, title: str, narrow: bool) -> Table:
    names = {rule: broken_at_hyphens(rule) if narrow else rule for rule in rows}
    t = Table(title=title)
    t.add_column(
        "rule",
        no_wrap=True,
        min_width=max((len(line) for n in names.values() for line in n.split("\n")), default=4),
    )
    for _, header, two_lines, _ in SCORE_COLUMNS:
        t.add_column(two_lines if narrow else header, no_wrap=True)
    for rule, row in rows.items():
        t.add_row(
            names[rule],
            *(
                "–" if row.get(key) is None else fmt.format(row[key])
                for key, _, _, fmt in SCORE_COLUMNS
            ),
        )
    return t


def broken_at_hyphens(name: str, width: int = 13) -> str:
    """``name`` on lines of at most ``width`` characters (or one part), broken after hyphens:
    ``kld-weighted-chernoff`` -> ``kld-weighted-`` / ``chernoff``."""
    lines = [""]
    for part in re.findall(r"[^-]+-?|-", name):
        if lines[-1] and len(lines[-1]) + len(part) > width:
            lines.append("")
        lines[-1] += part
    return "\n".join(lines)


def _width(table: Table) -> int:
    """The columns ``table`` takes when nothing is wrapped."""
    from rich.console import Console

    return Console(width=10_000).measure(table).maximum


def map_info_table(paths: Sequence[Path]) -> Table:
    """Resolution, leaves, occupied/free leaves and memory of map files."""
    import numpy as np

    from ..maps.occupancy import OccupancyMap

    t = Table("map", "resolution", "leaves", "occupied", "free", "memory MB")
    for p in paths:
        m = OccupancyMap.load(p)
        v = m.leaves().values
        t.add_row(
            str(p),
            f"{m.resolution:g}",
            f"{m.num_leaves}",
            f"{int(np.sum(v > 0))}",
            f"{int(np.sum(v <= 0))}",
            f"{m.memory_bytes / 1e6:.1f}",
        )
    return t


def search_table(res) -> Table:
    """Per scheme of a target search (:class:`~octofuse.targets.search.TargetSearchResult`),
    at its end: the KL divergence of the robots' beliefs to the centralized one and robot 1's
    information gain over the prior."""
    t = Table(
        "scheme",
        "KL(central‖robot) mean",
        "max",
        escape("robot 1 gain [nats]"),
        title="octofuse search: at the end",
    )
    for s in res.schemes:
        kl, gain = res.kl_to_central[s][-1], res.info_gain[s][-1]
        t.add_row(s, f"{kl.mean():.3f}", f"{kl.max():.3f}", f"{gain[0]:.3f}")
    return t


def tracking_table(summary: dict) -> Table:
    """Per belief type of a tracking run (``run_tracking``'s summary): the RMS error after the
    burn-in, the fusions and the bytes per message, and the centralized grid's error."""
    t = Table("belief", escape("RMS error [m]"), "fusions", "bytes/message", title="octofuse track")
    num = lambda v, f: "–" if v is None else format(v, f)  # noqa: E731
    for name, fam in summary["families"].items():
        t.add_row(
            name,
            num(fam["rms_error"], ".3f"),
            str(fam["fusions"]),
            num(fam["bytes_per_message"]["mean"], ".0f"),
        )
    t.add_row("centralized grid", num(summary["central"]["rms_error"], ".3f"), "", "")
    return t
