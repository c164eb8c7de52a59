"""Information-loss maps: per-voxel KL(p_NB || p_fused) trees and their ``.npz`` file format."""

from __future__ import annotations

import os
import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np

from .. import _core

_LOSS_KEYS = ("centers", "sizes", "values", "depths")


class Leaves(NamedTuple):
    """Leaves of a tree as arrays (one row per leaf)."""

    centers: np.ndarray  #: (N, 3) float64 voxel centres, metres
    sizes: np.ndarray  #: (N,) float64 edge lengths, metres
    values: np.ndarray  #: (N,) float32 stored value (log-odds for occupancy maps)
    depths: np.ndarray  #: (N,) uint8 tree depth (16 = finest voxel)

    def values_at(self, points: np.ndarray, resolution: float) -> np.ndarray:
        """Value of the leaf containing each point (N, 3) (NaN where no leaf does), for leaves
        of a tree of finest voxel size ``resolution``: looked up depth by depth through the
        leaves' integer keys."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        out = np.full(len(points), np.nan, dtype=np.float32)
        depths = np.asarray(self.depths)
        for d in np.unique(depths):
            sel = depths == d
            size = resolution * 2.0 ** (16 - int(d))
            keys = _pack_keys(np.floor(np.asarray(self.centers)[sel] / size))
            order = np.argsort(keys)
            keys, vals = keys[order], np.asarray(self.values)[sel][order]
            q = _pack_keys(np.floor(points / size))
            i = np.clip(np.searchsorted(keys, q), 0, len(keys) - 1)
            hit = keys[i] == q
            out[hit] = vals[i[hit]]
        return out


#: finest voxels under a leaf at depth d (index d, 0 to 16): 8^(16-d), exact in float64
_VOXELS_AT_DEPTH = np.ldexp(1.0, 3 * (16 - np.arange(17)))


def voxels_per_leaf(depths: np.ndarray) -> np.ndarray:
    """Finest voxels each leaf stands for (a leaf at depth d: 8^(16-d)), as float64."""
    return _VOXELS_AT_DEPTH[np.asarray(depths)]


def voxels_in_bins(
    leaves: Sequence[tuple[np.ndarray, np.ndarray]], nbins: int, top: float, block: int = 1 << 18
) -> tuple[np.ndarray, float]:
    """The finest voxels of ``leaves`` (pairs of value and depth arrays, as
    :meth:`InfoLossMap.values_depths` gives them for several maps) in each of ``nbins`` equal
    bins of [0, ``top``] (``top`` in the last bin, values outside left out), as float64, and
    the finest voxels of all the leaves. The leaves are counted per bin and depth, ``block``
    at a time (no temporary array of every leaf), then weighed: each sum is of integers, so
    it equals the sum of :func:`voxels_per_leaf` exactly while below 2^53 (a tree holds at
    most 8^16 = 2^48)."""
    nd = len(_VOXELS_AT_DEPTH)
    counts, per_depth = np.zeros(nbins * nd, np.int64), np.zeros(nd, np.int64)
    for values, depths in leaves:
        for start in range(0, len(values), block):
            v, d = values[start : start + block], depths[start : start + block]
            inside = (v >= 0) & (v <= top)
            k = np.minimum((v[inside] * (nbins / top)).astype(np.int64), nbins - 1)
            counts += np.bincount(k * nd + d[inside], minlength=nbins * nd)
            per_depth += np.bincount(d, minlength=nd)
    per_bin = (counts.reshape(nbins, nd) * _VOXELS_AT_DEPTH).sum(axis=1)
    return per_bin, float((per_depth * _VOXELS_AT_DEPTH).sum())


def _pack_keys(k: np.ndarray) -> np.ndarray:
    k = k.astype(np.int64) + (1 << 20)
    return (k[:, 0] << 42) | (k[:, 1] << 21) | k[:, 2]


def leaves_from_core(raw: dict) -> Leaves:
    return Leaves(raw["centers"], raw["sizes"], raw["values"], raw["depths"])


class InfoLossMap:
    """Per-voxel information loss KL(p_NB || p_fused) (nats) of one or more fusions.

    A tree over the same voxel keys as the maps. :meth:`accumulate` adds another loss map
    voxel by voxel, which is how an agent's loss over all its fusions is kept.

    A loss map made by :meth:`carried_by` is carried by the map its fusions go into: the map's
    nodes keep the losses of the voxels it keeps as leaves (in bytes the nodes have spare),
    this map's tree the rest, and every read of this map gathers them first. The values are
    those of a loss map that is not carried, bit for bit; the fusions and insertions into the
    map walk one tree instead of two.

    ``voxels_fused`` and ``voxels_copied`` count finest voxels (a coarse leaf counts for every
    voxel below it) over the fusions recorded here; ``loss_sum`` is the loss (nats) summed over
    the fused voxels, so ``loss_sum / voxels_fused`` is the mean loss of a fused voxel.
    """

    __slots__ = ("_t", "_carrier", "voxels_fused", "voxels_copied", "loss_sum")

    def __init__(self, resolution: float):
        self._t = _core._ScalarTree(float(resolution))
        self._carrier = None  # the OccupancyMap that carries this map's losses, if any
        self.voxels_fused = 0
        self.voxels_copied = 0
        self.loss_sum = 0.0

    @classmethod
    def carried_by(cls, map) -> InfoLossMap:
        """An empty loss map whose losses the occupancy map ``map`` carries (its fusions that
        add into this loss map keep them in ``map``'s nodes). A map carries one loss map."""
        if not isinstance(getattr(map, "_m", None), _core._OccupancyMap):  # an OccupancyMap
            raise TypeError(
                f"InfoLossMap.carried_by expects an OccupancyMap, not {type(map).__name__}"
            )
        if map._m.carries_loss:
            raise ValueError(f"{map!r} carries a loss map already")
        obj = cls(map.resolution)
        map._m.carry_loss(obj._t)
        obj._carrier = map
        return obj

    @classmethod
    def _wrap(cls, raw, fused: int = 0, copied: int = 0, loss_sum: float = 0.0) -> InfoLossMap:
        obj = cls.__new__(cls)
        obj._t, obj._carrier = raw, None
        obj.voxels_fused, obj.voxels_copied, obj.loss_sum = fused, copied, loss_sum
        return obj

    def _tree_for(self, dst=None):
        """The core's tree, for a fusion into the occupancy map ``dst`` (None: to read it):
        the losses its carrier holds are gathered into it first, unless ``dst`` carries them."""
        if self._carrier is not None and self._carrier is not dst:
            self._carrier._m.settle_loss()
        return self._t

    def _record(self, counts) -> None:
        """Adds the counts of one fusion: (voxels fused, voxels copied, loss sum), as the
        core's counts begin."""
        fused, copied, loss_sum = counts[:3]
        self.voxels_fused += int(fused)
        self.voxels_copied += int(copied)
        self.loss_sum += float(loss_sum)

    def leaves(self) -> Leaves:
        """Leaf centres, sizes, loss values (nats) and depths."""
        return leaves_from_core(self._tree_for().leaves())

    def values_depths(self) -> tuple[np.ndarray, np.ndarray]:
        """The loss values (float32, nats) and depths (uint8) of the leaves, in the order of
        :meth:`leaves`, without their geometry."""
        if self._carrier is not None:  # read as settled, without building the tree
            raw = self._t.settled_values_depths(self._carrier._m)
        else:
            raw = self._t.values_depths()
        return raw["values"], raw["depths"]

    def on_leaves(self, map, voxels: str = "occupied") -> tuple[Leaves, np.ndarray]:
        """The leaves of the occupancy map ``map`` of the class ``voxels`` ("occupied":
        log-odds > 0, "free" or "all") that a leaf of this map contains the centre of, and that
        leaf's loss (float32): what :meth:`Leaves.values_at` finds at their centres, in one walk
        of the core. Leaves whose loss is not finite are left out."""
        raw = map._m.leaves_with(self._tree_for(), voxels)
        return leaves_from_core(raw), raw["scalar"]

    def accumulate(self, other: InfoLossMap) -> None:
        """Add ``other`` into this map voxel by voxel (in place)."""
        self._tree_for().accumulate(other._tree_for())
        self._record((other.voxels_fused, other.voxels_copied, other.loss_sum))

    def copy(self) -> InfoLossMap:
        return InfoLossMap._wrap(
            self._tree_for().copy(), self.voxels_fused, self.voxels_copied, self.loss_sum
        )

    def clear(self) -> None:
        """Remove every value and count, freeing the nodes (without the GIL); a carried
        map's losses are dropped from its map's nodes too."""
        if self._carrier is not None:
            self._carrier._m.drop_loss()
        else:
            self._t.clear()
        self.voxels_fused = self.voxels_copied = 0
        self.loss_sum = 0.0

    def save(self, path: str | os.PathLike) -> Path:
        """Write the leaves as ``.npz`` arrays (read back by :func:`read_info_loss`)."""
        p = Path(path)
        if p.suffix != ".npz":
            raise ValueError(
                f"cannot save information loss to '{p}': expected a .npz file "
                "(heat-map clouds: octofuse.outputs.export.write_heatmap)"
            )
        lv = self.leaves()
        tmp = p.with_name(p.name + ".tmp.npz")
        np.savez_compressed(
            tmp,
            centers=lv.centers,
            sizes=lv.sizes,
            values=lv.values,
            depths=lv.depths,
            resolution=self.resolution,
        )
        os.replace(tmp, p)
        return p

    @property
    def num_leaves(self) -> int:
        return self._tree_for().num_leaves

    @property
    def resolution(self) -> float:
        return self._t.resolution

    @property
    def memory_bytes(self) -> int:
        return self._tree_for().memory_bytes

    def __repr__(self) -> str:
        return f"InfoLossMap(resolution={self.resolution}, leaves={self.num_leaves})"


def read_info_loss(path: str | os.PathLike) -> Leaves:
    """Read an information-loss ``.npz`` as written by :meth:`InfoLossMap.save`.

    Raises ``FileNotFoundError`` for a missing file and ``OSError`` naming the file for one
    that is not such an archive (not a zip, missing arrays, mismatched lengths).
    """
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"information-loss file '{p}' does not exist")
    if p.is_dir():
        raise IsADirectoryError(f"information-loss file '{p}' is a directory")
    try:
        with np.load(p, allow_pickle=False) as z:
            if not hasattr(z, "files"):
                raise ValueError("a single array, not an .npz archive")
            missing = [k for k in _LOSS_KEYS if k not in z.files]
            if missing:
                raise ValueError(f"missing arrays {', '.join(missing)}")
            raw = {k: np.asarray(z[k]) for k in _LOSS_KEYS}
        with np.errstate(over="ignore", invalid="ignore"):  # out-of-range values: checked below
            lv = Leaves(
                raw["centers"].astype(np.float64),
                raw["sizes"].astype(np.float64),
                raw["values"].astype(np.float32),
                raw["depths"].astype(np.uint8),
            )
    except (ValueError, TypeError, OSError, EOFError, zipfile.BadZipFile) as e:
        raise OSError(f"cannot read information-loss file '{p}': {e}") from None
    n = len(lv.values)
    if (
        lv.centers.shape != (n, 3)
        or lv.sizes.shape != (n,)
        or lv.values.shape != (n,)
        or lv.depths.shape != (n,)
    ):
        raise OSError(
            f"cannot read information-loss file '{p}': arrays of mismatched shapes "
            f"(centers {lv.centers.shape}, sizes {lv.sizes.shape}, "
            f"values {lv.values.shape}, depths {lv.depths.shape})"
        )
    _check_loss_arrays(p, raw)
    return lv


def _check_loss_arrays(p: Path, raw: dict) -> None:
    """``ValueError`` naming the file, the array and its first bad entry unless the losses are
    finite, non-negative float32 numbers and the voxels finite, with positive sizes."""
    checks = (
        (
            "values",
            lambda v: np.isfinite(v) & (v >= 0) & (np.abs(v) <= np.finfo(np.float32).max),
            "finite losses >= 0 (nats, float32)",
        ),
        ("centers", lambda v: np.isfinite(v).all(axis=-1), "finite voxel centres"),
        ("sizes", lambda v: np.isfinite(v) & (v > 0), "positive finite voxel sizes"),
    )
    for key, ok, expected in checks:
        v = raw[key]
        if v.dtype.kind not in "fiu":
            raise ValueError(
                f"information-loss file '{p}': {key} holds {v.dtype} data; expected {expected}"
            )
        with np.errstate(invalid="ignore"):
            bad = np.flatnonzero(~ok(v.astype(np.float64)))
        if bad.size:
            i = int(bad[0])
            raise ValueError(
                f"information-loss file '{p}': {key} holds {bad.size} bad entr"
                f"{'y' if bad.size == 1 else 'ies'} (first at index {i}: "
                f"{np.asarray(v[i]).tolist()}); expected {expected}"
            )
