"""Top views (x-y) of information-loss heat maps as PNG images for reports.

Each cell of the map's finest x-y grid shows the largest loss of the occupied voxels above it
(a coarse leaf covers all the cells under its footprint); cells with no voxel stay blank. The
floor, when it was scanned, is an occupied layer under everything: ``z_range`` cuts it away so
that walls and objects stand out.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from .export import MapVoxelLoss, _colormap
from .libraries import pyplot
from .staging import written_then_renamed

#: a drawn cell takes at least MIN_CELL_PX and at most MAX_CELL_PX pixels a side; the axes at
#: most MAX_SIDE_PX and at least MIN_SIDE_PX wide; the margins hold the labels and colour bar
MIN_CELL_PX, MAX_CELL_PX = 3, 12
MAX_SIDE_PX, MIN_SIDE_PX = 1800, 480
MARGIN_PX = (240, 110)


def topview_grid(
    v: MapVoxelLoss, resolution: float, z_range=None
) -> tuple[np.ndarray, tuple[float, float, float, float]]:
    """The max-over-z loss of every x-y cell (NaN where no voxel is) as an array indexed
    ``[iy, ix]``, and its extent ``(xmin, xmax, ymin, ymax)`` in metres."""
    centers, sizes, loss = v.centers, v.sizes, np.asarray(v.loss, dtype=np.float64)
    if z_range is not None:
        keep = (centers[:, 2] >= z_range[0]) & (centers[:, 2] <= z_range[1])
        centers, sizes, loss = centers[keep], sizes[keep], loss[keep]
    if len(loss) == 0:
        raise ValueError(
            "no occupied voxel to draw"
            + (f" with z in [{z_range[0]:g}, {z_range[1]:g}]" if z_range is not None else "")
        )
    lo = np.floor((centers[:, :2] - sizes[:, None] / 2) / resolution + 0.5).astype(np.int64)
    span = np.maximum(np.rint(sizes / resolution).astype(np.int64), 1)
    xs, ys, vals = [], [], []
    for n in np.unique(span):
        sel = span == n
        off = np.stack(np.meshgrid(np.arange(n), np.arange(n), indexing="ij"), -1).reshape(-1, 2)
        cells = (lo[sel][:, None, :] + off[None]).reshape(-1, 2)
        xs.append(cells[:, 0])
        ys.append(cells[:, 1])
        vals.append(np.repeat(loss[sel], len(off)))
    ix, iy, val = np.concatenate(xs), np.concatenate(ys), np.concatenate(vals)
    x0, y0 = ix.min(), iy.min()
    grid = np.full((iy.max() - y0 + 1, ix.max() - x0 + 1), -np.inf)
    np.maximum.at(grid, (iy - y0, ix - x0), val)
    grid[np.isneginf(grid)] = np.nan
    extent = (
        x0 * resolution,
        (ix.max() + 1) * resolution,
        y0 * resolution,
        (iy.max() + 1) * resolution,
    )
    return grid, extent


def above_floor(
    v: MapVoxelLoss, resolution: float, ratio: float = 3.0, max_layers: int = 3
) -> tuple | None:
    """A height slice without the floor, or None (keep every voxel). Starting from the
    lowest, a layer of occupied voxels is floor when it holds more than ``ratio`` times the
    voxels of the median layer (a scanned floor spans the whole area, a wall's layer only its
    outline); a floor on a voxel boundary fills two layers, so up to ``max_layers`` are cut."""
    if len(v.centers) == 0:
        return None
    layer = np.floor(v.centers[:, 2] / resolution + 1e-6).astype(np.int64)
    levels, counts = np.unique(layer, return_counts=True)
    typical = np.median(counts)
    cut = None
    for low, n in list(zip(levels, counts))[: min(max_layers, len(levels) - 1)]:
        if n <= ratio * typical:
            break
        cut = low + 1
    return None if cut is None else (cut * resolution, np.inf)


def pooled_max(grid: np.ndarray, factor: int) -> np.ndarray:
    """``grid`` with every ``factor`` x ``factor`` block of cells as one: the largest value
    of the block (NaN where the whole block is)."""
    if factor <= 1:
        return grid
    ny, nx = -(-grid.shape[0] // factor) * factor, -(-grid.shape[1] // factor) * factor
    padded = np.full((ny, nx), np.nan)
    padded[: grid.shape[0], : grid.shape[1]] = grid
    blocks = padded.reshape(ny // factor, factor, nx // factor, factor)
    return np.fmax.reduce(np.fmax.reduce(blocks, axis=3), axis=1)


def frame_for(cells: tuple[int, int]) -> tuple[int, tuple[int, int]]:
    """For a grid of ``cells`` (rows, columns): the block of cells one drawn cell shows (1
    unless the map is too large for :data:`MIN_CELL_PX` pixels a cell within
    :data:`MAX_SIDE_PX`) and the image size in pixels, its axes sized to the map's shape."""
    rows, cols = cells
    pool = max(1, math.ceil(max(rows, cols) * MIN_CELL_PX / MAX_SIDE_PX))
    rows, cols = math.ceil(rows / pool), math.ceil(cols / pool)
    px = min(MAX_CELL_PX, MAX_SIDE_PX / max(rows, cols))  # pixels a drawn cell
    width, height = max(cols * px, MIN_SIDE_PX), max(rows * px, MIN_SIDE_PX / 2)
    return pool, (int(width) + MARGIN_PX[0], int(height) + MARGIN_PX[1])


def write_topview(
    v: MapVoxelLoss,
    resolution: float,
    path: str | os.PathLike,
    *,
    vmin: float,
    vmax: float,
    cmap="inferno",
    title: str = "",
    size_px: tuple[int, int] | None = None,
    dpi: int = 100,
    label: str = "information loss [nats]",
) -> Path:
    """A PNG: the top view of ``v`` (:func:`topview_grid`, the floor left out by
    :func:`above_floor`) over the colour range [vmin, vmax], axes in metres and a colour bar.
    The image is sized to the map (:func:`frame_for`: every drawn cell at least a few pixels,
    blocks of cells as one in a map too large for that) unless ``size_px`` is given. Pass the
    same range for every rule so that the images compare."""
    plt = pyplot()
    from matplotlib.colors import Normalize

    p = Path(path)
    if p.suffix.lower() != ".png":
        raise ValueError(f"cannot write top view '{p}': expected a .png file name")
    grid, extent = topview_grid(v, resolution, above_floor(v, resolution))
    pool, fitted = frame_for(grid.shape)
    grid, size_px = pooled_max(grid, pool), size_px or fitted
    x0, _, y0, _ = extent  # a pooled grid's last blocks reach past the map
    extent = (
        x0,
        x0 + grid.shape[1] * pool * resolution,
        y0,
        y0 + grid.shape[0] * pool * resolution,
    )
    cm = _colormap(cmap).with_extremes(bad="white")
    norm = Normalize(vmin=vmin, vmax=vmax if vmax > vmin else vmin + 1e-12)
    fig, ax = plt.subplots(
        figsize=(size_px[0] / dpi, size_px[1] / dpi), dpi=dpi, layout="constrained"
    )
    im = ax.imshow(grid, origin="lower", extent=extent, cmap=cm, norm=norm, interpolation="nearest")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal")
    ax.grid(alpha=0.2)
    if title:
        ax.set_title(title, fontsize=10)
    fig.colorbar(im, ax=ax, label=label, shrink=0.9)
    try:
        with written_then_renamed(p) as tmp:
            fig.savefig(tmp, dpi=dpi)
    finally:
        plt.close(fig)
    return p
