"""Voxels as arrays, and their level of detail: a map of millions of leaves drawn within a
voxel budget by merging its finest voxels into coarser octree cells."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: the coarsest cell the level of detail merges into, as octree levels above the finest voxel
MAX_COARSENING = 10


@dataclass(frozen=True)
class Voxels:
    """Cubes with one value each (log-odds, loss or a class number)."""

    centers: np.ndarray  #: (N, 3) float64, metres
    sizes: np.ndarray  #: (N,) float64 edge lengths, metres
    values: np.ndarray  #: (N,) float32

    def __len__(self) -> int:
        return len(self.values)

    def subset(self, keep: np.ndarray) -> "Voxels":
        return Voxels(self.centers[keep], self.sizes[keep], self.values[keep])

    def moved(self, T) -> "Voxels":
        """The voxels with their centres moved by the rigid transform ``T`` (4x4; None: as
        they are)."""
        if T is None:
            return self
        T = np.asarray(T, dtype=np.float64)
        return Voxels(self.centers @ T[:3, :3].T + T[:3, 3], self.sizes, self.values)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The lowest and highest corner of the box around the voxels."""
        half = self.sizes[:, None] / 2
        return (self.centers - half).min(axis=0), (self.centers + half).max(axis=0)


def occupied_voxels(leaves) -> Voxels:
    """The occupied leaves (log-odds > 0) of a map's :class:`~octofuse.maps.infoloss.Leaves`,
    valued by their log-odds."""
    values = np.asarray(leaves.values, dtype=np.float32)
    keep = values > 0
    return Voxels(np.asarray(leaves.centers, dtype=np.float64)[keep],
                  np.asarray(leaves.sizes, dtype=np.float64)[keep], values[keep])


@dataclass(frozen=True)
class Detail:
    """Voxels within a budget and the cell size they were merged into (the finest voxel
    size when nothing was merged)."""

    voxels: Voxels
    cell: float
    merged: bool


def within_budget(v: Voxels, budget: int, resolution: float,
                  combine=np.maximum) -> Detail:
    """``v`` with at most ``budget`` voxels where it can: voxels finer than a cell of the
    octree level above are merged into that cell, level by level, until they fit (or
    :data:`MAX_COARSENING` levels up). A merged cell takes the ``combine`` of its voxels'
    values (the largest by default: a wall's occupancy, a region's worst loss)."""
    cell, merged = resolution, False
    for _ in range(MAX_COARSENING):
        if len(v) <= budget:
            break
        cell *= 2
        v = merged_into_cells(v, cell, combine)
        merged = True
    return Detail(v, cell, merged)


def merged_into_cells(v: Voxels, cell: float, combine=np.maximum) -> Voxels:
    """The voxels smaller than ``cell`` merged into the cells of that size that hold their
    centres; larger voxels as they are."""
    small = v.sizes < cell * (1 - 1e-9)
    if not small.any():
        return v
    keys = np.floor(v.centers[small] / cell).astype(np.int64)
    _, first, index = np.unique(packed_keys(keys), return_index=True, return_inverse=True)
    cells, index = keys[first], index.reshape(-1)
    values = np.full(len(cells), -np.inf, dtype=np.float32)
    combine.at(values, index, v.values[small])
    big = v.subset(~small)
    return Voxels(np.concatenate([big.centers, (cells + 0.5) * cell]),
                  np.concatenate([big.sizes, np.full(len(cells), cell)]),
                  np.concatenate([big.values, values]))


def packed_keys(keys: np.ndarray) -> np.ndarray:
    """One int64 per row of integer cell coordinates (N, 3), equal where the rows are."""
    if len(keys) == 0:
        return np.empty(0, dtype=np.int64)
    low = keys.min(axis=0)
    span = keys.max(axis=0) - low + 1
    k = keys - low
    return (k[:, 0] * span[1] + k[:, 1]) * span[2] + k[:, 2]


def by_size(v: Voxels) -> dict[float, np.ndarray]:
    """Voxel size -> the indices of the voxels of that size (one draw call each)."""
    sizes = np.round(v.sizes, 9)
    return {float(s): np.flatnonzero(sizes == s) for s in np.unique(sizes)}
