"""The report's loss histogram: every rule's accumulated information loss per fused voxel,
counted from its agents' loss leaves (numpy on large arrays, the rules on threads), then
drawn (Matplotlib)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..maps.infoloss import voxels_in_bins
from ..threads import thread_map
from .libraries import pyplot

#: bins over [0, the largest 99.5th percentile of the rules]
NBINS = 59
LINE_STYLES = ("-", "--", ":", "-.", (0, (5, 1, 1, 1, 1, 1)))


@dataclass(frozen=True)
class LossHistograms:
    """Bin edges (nats) and, per rule, the fraction of its fused voxels in each bin."""

    bins: np.ndarray
    fractions: dict[str, np.ndarray]


def count_loss_histograms(
    data: dict[str, Sequence[tuple[np.ndarray, np.ndarray]]], threads: int = 1
) -> LossHistograms | None:
    """The histograms of ``data``, which maps a rule to the loss values and depths of each of
    its agents' loss leaves (:attr:`.map_exports.MapExports.histogram`; a leaf weighs the
    voxels it covers), counted on ``threads`` threads; None without rules. The values are
    left as they were."""
    if not data:
        return None
    rules = [r for r, leaves in data.items() if any(len(v) for v, _ in leaves)]
    # the values of all agents, copied into one array, partitioned in place by the percentile
    tops = thread_map(
        lambda r: float(
            np.percentile(np.concatenate([v for v, _ in data[r]]), 99.5, overwrite_input=True)
        ),
        rules,
        threads,
    )
    top = max([0.0, *tops]) or 1.0

    def fractions(r):
        per_bin, total = voxels_in_bins(data[r], NBINS, top)
        return per_bin / total

    return LossHistograms(
        np.linspace(0, top, NBINS + 1), dict(zip(rules, thread_map(fractions, rules, threads)))
    )


def plot_loss_histograms(hist: LossHistograms | None, path: Path) -> Path | None:
    """The histograms drawn into the PNG ``path`` (log scale); None, and nothing written,
    for None."""
    if hist is None:
        return None
    fig = loss_histogram_figure(hist)
    fig.savefig(path, dpi=110)
    pyplot().close(fig)
    return path


def loss_histogram_figure(hist: LossHistograms):
    """The Matplotlib figure of :func:`plot_loss_histograms`."""
    fig, ax = pyplot().subplots(figsize=(8, 4), layout="constrained")
    # rules with equal histograms draw on top of each other: each its own dash, the later
    # ones thinner, so that every line shows
    for i, (r, h) in enumerate(hist.fractions.items()):
        ax.stairs(
            h,
            hist.bins,
            lw=2.4 - 1.2 * i / max(1, len(hist.fractions) - 1),
            ls=LINE_STYLES[i % len(LINE_STYLES)],
            label=r,
        )
    ax.set_xlabel("accumulated information loss per voxel [nats]")
    ax.set_ylabel("fraction of fused voxels")
    ax.set_yscale("log")
    if ax.get_legend_handles_labels()[0]:
        fig.legend(fontsize=8, loc="outside right upper")  # beside the curves, not over them
    ax.grid(alpha=0.3)
    ax.set_title("Information loss over all fusions, all agents")
    return fig
