"""The viewer's colours and their legends (HTML for the page's side panel)."""

from __future__ import annotations

import html

import numpy as np

from ..outputs.export import colorize, occupancy_of
from .difference import CLASSES, MEANINGS

OCCUPANCY_CMAP = "viridis"
LOSS_CMAP = "inferno"  # as the heat maps and top views of a run
#: over-confident, missed, agreeing
DIFFERENCE_COLORS = np.array([[220, 40, 40], [40, 110, 230], [170, 170, 170]], dtype=np.uint8)


def occupancy_colors(log_odds: np.ndarray) -> np.ndarray:
    """Occupancy probability 0.5 .. 1 over the colour map (occupied voxels only are drawn)."""
    return colorize(occupancy_of(log_odds), OCCUPANCY_CMAP, 0.5, 1.0)


def loss_colors(loss: np.ndarray, lo: float, hi: float) -> np.ndarray:
    return colorize(loss, LOSS_CMAP, lo, hi)


def difference_colors(classes: np.ndarray) -> np.ndarray:
    return DIFFERENCE_COLORS[np.asarray(classes, dtype=np.int64)]


def _gradient(cmap: str) -> str:
    stops = colorize(np.linspace(0, 1, 9), cmap, 0.0, 1.0)
    return ", ".join(f"rgb({r},{g},{b})" for r, g, b in stops)


def scale_legend(title: str, cmap: str, lo: float, hi: float, unit: str = "") -> str:
    """A colour bar with its ends and title."""
    return (
        f"<div style='font-size:0.8em'><b>{html.escape(title)}</b>"
        f"<div style='height:12px;border-radius:2px;background:linear-gradient(to right, "
        f"{_gradient(cmap)})'></div><div style='display:flex;justify-content:space-between'>"
        f"<span>{lo:.3g}</span><span>{hi:.3g}{(' ' + html.escape(unit)) if unit else ''}"
        "</span></div></div>"
    )


def occupancy_legend() -> str:
    return scale_legend("occupancy probability (occupied voxels)", OCCUPANCY_CMAP, 0.5, 1.0)


def loss_legend(lo: float, hi: float) -> str:
    return scale_legend(
        "accumulated information loss (one range for every rule)", LOSS_CMAP, lo, hi, "nats"
    )


def difference_legend(counts: dict[str, int]) -> str:
    """Three swatches, what each class means and how many voxels it holds."""
    rows = []
    for (r, g, b), name in zip(DIFFERENCE_COLORS.tolist(), CLASSES):
        rows.append(
            f"<div title='{html.escape(MEANINGS[name])}'><span style='display:inline-block;"
            f"width:10px;height:10px;background:rgb({r},{g},{b});margin-right:6px'></span>"
            f"{name}: {counts.get(name, 0):,}</div>"
        )
    return (
        "<div style='font-size:0.8em'><b>against the centralized map</b>" + "".join(rows) + "</div>"
    )
