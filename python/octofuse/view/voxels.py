"""Voxels as arrays, and their level of detail: a map of millions of leaves drawn within a
voxel budget by merging its finest voxels into coarser octree cells, finer near the middle
of the map than far from it."""

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

    def subset(self, keep: np.ndarray) -> Voxels:
        return Voxels(self.centers[keep], self.sizes[keep], self.values[keep])

    def moved(self, T) -> Voxels:
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
    return Voxels(
        np.asarray(leaves.centers, dtype=np.float64)[keep],
        np.asarray(leaves.sizes, dtype=np.float64)[keep],
        values[keep],
    )


@dataclass(frozen=True)
class Detail:
    """Voxels within a budget and the largest cell they were merged into (the finest voxel
    size when nothing was merged)."""

    voxels: Voxels
    cell: float
    merged: bool


def within_budget(
    v: Voxels, budget: int, resolution: float, combine=np.maximum, focus: np.ndarray | None = None
) -> Detail:
    """``v`` with at most ``budget`` voxels where it can: finer voxels merged into the cells
    of the octree level above, level by level (at most :data:`MAX_COARSENING`), until they
    fit; then the cells nearest ``focus`` (default: the middle of ``v``) split again into
    the voxels of the level below while the budget allows: fine near, coarse far. A merged
    cell takes the ``combine`` of its voxels' values (the largest by default: a wall's
    occupancy, a region's worst loss)."""
    if len(v) <= budget:
        return Detail(v, resolution, False)
    lo, hi = v.bounds
    focus = (lo + hi) / 2 if focus is None else np.asarray(focus, dtype=np.float64)
    fine, cell = v, resolution
    for _ in range(MAX_COARSENING):
        coarse, parent = merged_with_parents(fine, cell * 2, combine)
        if len(coarse) <= budget:
            return Detail(refined_near(fine, coarse, parent, budget, focus), cell * 2, True)
        fine, cell = coarse, cell * 2
    return Detail(fine, cell, True)


def refined_near(
    fine: Voxels, coarse: Voxels, parent: np.ndarray, budget: int, focus: np.ndarray
) -> Voxels:
    """``coarse`` with its cells nearest ``focus`` replaced by their voxels of ``fine``
    (``parent``: the cell of each), as many as ``budget`` allows."""
    children = np.bincount(parent, minlength=len(coarse))
    order = np.argsort(np.linalg.norm(coarse.centers - focus, axis=1), kind="stable")
    fits = np.cumsum(children[order] - 1) <= budget - len(coarse)
    split = np.zeros(len(coarse), dtype=bool)
    split[order[fits]] = True
    kept, finer = coarse.subset(~split), fine.subset(split[parent])
    return Voxels(
        np.concatenate([kept.centers, finer.centers]),
        np.concatenate([kept.sizes, finer.sizes]),
        np.concatenate([kept.values, finer.values]),
    )


def merged_into_cells(v: Voxels, cell: float, combine=np.maximum) -> Voxels:
    """The voxels smaller than ``cell`` merged into the cells of that size that hold their
    centres; larger voxels as they are."""
    return merged_with_parents(v, cell, combine)[0]


def merged_with_parents(v: Voxels, cell: float, combine=np.maximum) -> tuple[Voxels, np.ndarray]:
    """:func:`merged_into_cells`, and for each voxel of ``v`` the index of the merged voxel
    that holds it."""
    small = v.sizes < cell * (1 - 1e-9)
    parent = np.empty(len(v), dtype=np.int64)
    big = v.subset(~small)
    parent[~small] = np.arange(len(big))
    if not small.any():
        return v.subset(~small), parent
    keys = np.floor(v.centers[small] / cell).astype(np.int64)
    _, first, index = np.unique(packed_keys(keys), return_index=True, return_inverse=True)
    cells, index = keys[first], index.reshape(-1)
    values = v.values[small][first]  # then every voxel of the cell combined into it
    combine.at(values, index, v.values[small])
    parent[small] = len(big) + index
    return Voxels(
        np.concatenate([big.centers, (cells + 0.5) * cell]),
        np.concatenate([big.sizes, np.full(len(cells), cell)]),
        np.concatenate([big.values, values]),
    ), parent


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
