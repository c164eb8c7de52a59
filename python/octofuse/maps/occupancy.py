"""Occupancy maps: OctoMap trees held by the C++ core, built from scans, read and written as
`.ot`/`.bt` files, and the flattened centralized map that agents are scored against."""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from .. import _core
from ..config import INSERT_MODES, MapConfig
from .infoloss import Leaves, leaves_from_core

MapFileError = _core.MapFileError


class MapValueWarning(UserWarning):
    """A map read held values its clamping cannot produce; they were clamped into its range."""


def _checked_values(m: OccupancyMap, name: str) -> OccupancyMap:
    """``m`` as read from ``name``, its stored log-odds (every node) checked against what
    OctoMap's clamping produces: values outside the clamping range are clamped into it with a
    :class:`MapValueWarning`; subnormal values (no OctoMap writes them) are refused with a
    :class:`MapFileError`."""
    values = np.frombuffer(m.tree_data(), dtype=np.dtype([("v", "<f4"), ("mask", "u1")]))["v"]
    if values.size == 0:
        return m
    tiny = np.finfo(np.float32).tiny
    subnormal = np.flatnonzero((values != 0) & (np.abs(values) < tiny))
    if subnormal.size:
        raise MapFileError(
            f"map '{name}' holds {subnormal.size} subnormal log-odds values (first "
            f"{float(values[subnormal[0]]):.3g}), which OctoMap never writes: the "
            "file is corrupt"
        )
    lo, hi = m.clamping_logodds
    outside = (values < lo - 1e-5) | (values > hi + 1e-5)
    if outside.any():
        warnings.warn(
            MapValueWarning(
                f"map '{name}': {int(outside.sum())} log-odds values outside its clamping range "
                f"[{lo:.4g}, {hi:.4g}] (from {float(values.min()):.3g} to {float(values.max()):.3g}) "
                "clamped into it"
            ),
            stacklevel=3,
        )
        m.clamp_values()
    return m


def _existing_file(path: str | os.PathLike) -> str:
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"map file '{p}' does not exist")
    if p.is_dir():
        raise IsADirectoryError(f"map file '{p}' is a directory, expected a .ot or .bt file")
    if not p.is_file():  # a FIFO would block, a device never ends
        raise MapFileError(f"map file '{p}' is not a regular file (a device, FIFO or socket)")
    return str(p)


class OccupancyMap:
    """A 3D occupancy map: an ``octomap::OcTree`` with its sensor model and clamping.

    Parameters
    ----------
    resolution : float
        Edge length of the finest voxel, metres.
    prob_hit, prob_miss : float
        Sensor model: P(occupied) of an endpoint and of a voxel a ray passes through.
    clamping : (float, float)
        Clamping thresholds (probabilities) of the stored values.
    """

    __slots__ = ("_m",)

    def __init__(
        self,
        resolution: float,
        prob_hit: float = MapConfig.prob_hit,
        prob_miss: float = MapConfig.prob_miss,
        clamping: tuple[float, float] = MapConfig.clamping,
    ):
        cmin, cmax = clamping
        self._m = _core._OccupancyMap(
            float(resolution), float(prob_hit), float(prob_miss), float(cmin), float(cmax)
        )

    @classmethod
    def from_config(cls, cfg: MapConfig) -> OccupancyMap:
        """An empty map with the resolution, sensor model and clamping of ``cfg``."""
        return cls(cfg.resolution, cfg.prob_hit, cfg.prob_miss, tuple(cfg.clamping))

    @classmethod
    def _wrap(cls, raw) -> OccupancyMap:
        obj = cls.__new__(cls)
        obj._m = raw
        return obj

    # -- insertion ---------------------------------------------------------------------
    def insert_scan(
        self, points, origin, max_range: float = -1.0, mode: str = "exact", threads: int = 1
    ) -> None:
        """Insert one scan with OctoMap's ray casting update (the map is the one
        ``insertPointCloud`` gives: the rays traced with OctoMap's steps and arithmetic, the
        voxels updated by octofuse's depth-first batch update).

        ``mode="fast"``: the real-time mode for dense 3D lidar scans (OctoMap's update rules,
        free space cleared a cell of 8^3 voxels at a time where 8 or more of the scan's rays
        cross it and the map holds no occupied voxel; see ``cpp/octofuse/insert_fast.hpp``),
        its rays traced on ``threads`` threads.

        ``points`` is an (N, 3) float32 or float64 array in the map frame (passed to C++
        without a copy when C-contiguous), ``origin`` the sensor position. Rays longer than
        ``max_range`` (if > 0) only clear free space up to ``max_range``. The GIL is
        released while the core works.
        """
        pts = _points(points)
        o = np.asarray(origin, dtype=np.float64).reshape(-1)
        _core._insert_scan_batched(
            self._m, pts, o, float(max_range), mode=insert_mode(mode), threads=thread_count(threads)
        )

    def insert_scans(
        self, scans, max_range: float = -1.0, threads: int | None = None, mode: str = "exact"
    ) -> None:
        """Insert several scans in order, as :meth:`insert_scan` (or
        :meth:`insert_scan_from_sensor`) one after the other would.

        ``scans`` is a sequence of ``(points, origin_or_pose)``: with a 3-vector origin the
        points are in the map frame, with a 4x4 sensor-to-map pose in the sensor frame. The
        scans' ray keys are computed on ``threads`` threads (default: one per core), then
        applied to the map in order, several scans per walk of the tree; the GIL is released.
        Every scan is checked before the map changes (``ValueError`` naming the scan and point
        row). ``mode``: as in :meth:`insert_scan`.
        """
        pts_list, poses, map_frame = [], [], []
        for k, item in enumerate(scans):
            try:
                points, where = item
            except (TypeError, ValueError):
                raise ValueError(f"scan {k}: expected a (points, origin_or_pose) pair") from None
            pts_list.append(_points(points))
            w = np.asarray(where, dtype=np.float64)
            if w.shape == (4, 4):
                poses.append(w)
                map_frame.append(False)
            elif w.size == 3:
                T = np.eye(4)
                T[:3, 3] = w.reshape(-1)
                poses.append(T)
                map_frame.append(True)
            else:
                raise ValueError(
                    f"scan {k}: expected an origin (3 values) or a 4x4 pose, got shape {w.shape}"
                )
            if not np.all(np.isfinite(poses[-1])):
                raise ValueError(f"scan {k}: {'origin' if map_frame[-1] else 'pose'} is not finite")
        if not pts_list:
            return
        n = len(pts_list)
        kw = {"mode": insert_mode(mode)}
        if threads is not None:
            kw["threads"] = thread_count(threads)
        _core._insert_batch(
            [[self._m]] * n,
            pts_list,
            np.ascontiguousarray(np.stack(poses)),
            np.full(n, float(max_range)),
            map_frame=map_frame,
            **kw,
        )

    def insert_scan_from_sensor(self, points, pose, max_range: float = -1.0) -> None:
        """Insert a scan given in the sensor frame; ``pose`` is the 4x4 sensor-to-map transform."""
        pts = _points(points)
        T = np.asarray(pose, dtype=np.float64)
        if T.shape != (4, 4):
            raise ValueError(f"pose must be a 4x4 matrix, got shape {T.shape}")
        self._m.insert_scan(pts, np.ascontiguousarray(T), float(max_range), True)

    # -- files -------------------------------------------------------------------------
    def save(self, path: str | os.PathLike) -> Path:
        """Write the map and return its path.

        ``.ot`` (the default for other suffixes is an error) keeps the full log-odds of
        every node; ``.bt`` is OctoMap's compact maximum-likelihood binary format, which
        keeps only free/occupied per leaf and DROPS the probabilities (a reloaded ``.bt``
        holds the clamping thresholds as values). Both open in OctoMap's own tools
        (octovis, compare_octrees). The file is written to a temporary name and renamed,
        so an existing file is never left half-written.
        """
        p = Path(path)
        if p.suffix not in (".ot", ".bt"):
            raise ValueError(f"cannot save map to '{p}': expected a .ot or .bt file name")
        self._m.save(str(p))
        return p

    @classmethod
    def load(cls, path: str | os.PathLike) -> OccupancyMap:
        """Read a ``.ot`` or ``.bt`` OctoMap file (validated before any node is built).

        Raises ``FileNotFoundError`` for a missing file and :class:`MapFileError` (an
        ``OSError``) naming the file for a truncated, corrupt or foreign one. Values outside the
        clamping range are clamped into it with a :class:`MapValueWarning`.
        """
        path = _existing_file(path)
        return _checked_values(cls._wrap(_core._OccupancyMap.load(path)), path)

    def to_bytes(self, fmt: str = "ot") -> bytes:
        """The map as an OctoMap stream, built in memory: exactly the bytes :meth:`save` writes
        to a ``.ot`` file (full log-odds; ``fmt="bt"``: the maximum-likelihood binary stream).
        This is what a robot sends; :meth:`from_bytes` reads it back."""
        if fmt not in ("ot", "bt"):
            raise ValueError(f"fmt must be 'ot' or 'bt', got {fmt!r}")
        return _core._map_to_stream(self._m, fmt == "bt")

    @classmethod
    def from_bytes(cls, data: bytes | bytearray | memoryview, name: str = "stream") -> OccupancyMap:
        """A map from an OctoMap ``.ot`` or ``.bt`` stream held in memory, checked like
        :meth:`load` (:class:`MapFileError` naming ``name`` for a truncated or corrupt one)."""
        return cls._wrap(_core._map_from_stream(bytes(data), str(name)))

    def tree_data(self) -> bytes:
        """OctoMap's node data alone (``OcTree::writeData``: log-odds and child mask of every
        node, depth first): the ``data`` of an ``octomap_msgs/Octomap`` message with
        ``binary=False`` and ``id="OcTree"``, as octomap_msgs' ``fullMapToMsg`` fills it."""
        return _core._tree_data(self._m)

    @classmethod
    def from_tree_data(
        cls,
        data: bytes | bytearray | memoryview,
        resolution: float,
        prob_hit: float = MapConfig.prob_hit,
        prob_miss: float = MapConfig.prob_miss,
        clamping: tuple[float, float] = MapConfig.clamping,
    ) -> OccupancyMap:
        """A map from the node data of :meth:`tree_data` (an ``octomap_msgs/Octomap``
        message's ``data``) and its resolution; checked like :meth:`load`."""
        cmin, cmax = clamping
        m = cls._wrap(
            _core._map_from_tree_data(
                bytes(data),
                float(resolution),
                float(prob_hit),
                float(prob_miss),
                float(cmin),
                float(cmax),
            )
        )
        return _checked_values(m, "octomap message")

    # -- frames --------------------------------------------------------------------------
    def transformed(
        self, T, resolution: float | None = None, resampling: str = "vote"
    ) -> OccupancyMap:
        """A new map: this map moved by the rigid transform ``T`` and resampled onto a grid of
        voxel size ``resolution`` (default: this map's), with this map's sensor model and
        clamping. ``T`` is a 4x4 homogeneous matrix taking a point of this map's frame into the
        new frame (rotation with det +1, last row 0 0 0 1).

        Rule ("occupied wins, then mean", forward splatting): every leaf is cut into cubic cells
        of edge ``min(own resolution, resolution) / 2`` (one cell per voxel where ``T`` maps the
        grid onto itself); the centre of each cell is moved by ``T`` and votes with the leaf's
        log-odds in the target voxel it lands in. A target voxel with votes gets the largest
        vote if any vote is occupied (log-odds > 0), else the mean of its votes (cells have
        equal volume: the volume-weighted mean of the free space it overlaps). Unknown space
        casts no votes, so no voxel appears away from known space, and a target voxel that lies
        inside the moved known space always gets votes (cells of at most half a target voxel).
        The identity, translations by whole voxels and rotations by multiples of 90 degrees
        about the axes are exact; a target voxel that touches an occupied voxel is occupied.
        Resampling to a coarser grid gives each coarse voxel the maximum of its occupied parts
        (OctoMap's own rule for inner nodes) or the mean of its free parts.

        ``resampling="nearest"`` gives a target voxel instead the vote cast closest to its
        centre (about the value at the pre-image of its centre): surfaces keep their thickness,
        so a map moved back and forth between frames (messages between agents) does not grow
        thicker at every move. The exact cases above stay exact.

        Raises ``ValueError`` naming the value for a ``T`` that is not a finite rigid 4x4
        matrix, a bad resolution, or a result outside the octree's key range. The GIL is
        released while the C++ core works.
        """
        from ..scans.se3 import check_rigid

        T = check_rigid(T)
        res = self.resolution if resolution is None else _resolution(resolution)
        if resampling not in ("vote", "nearest"):
            raise ValueError(f"resampling {resampling!r}: expected 'vote' or 'nearest'")
        raw, _stats = _core._transform_map(self._m, T, res, resampling)
        return OccupancyMap._wrap(raw)

    # -- contents ----------------------------------------------------------------------
    def leaves(self, voxels: str = "all") -> Leaves:
        """Leaf centres (N, 3), sizes (N,), log-odds (N,) and depths (N,) of the leaves of
        class ``voxels``: "all", "occupied" (log-odds > 0) or "free"."""
        return leaves_from_core(self._m.leaves(voxels))

    def copy(self) -> OccupancyMap:
        """A deep copy of the map."""
        return OccupancyMap._wrap(self._m.copy())

    def clear(self, keep_loss: bool = True) -> None:
        """Remove every voxel, freeing the nodes (without the GIL: maps no longer needed can
        be freed on several threads). The losses the map carries for its loss map
        (:meth:`InfoLossMap.carried_by`) are moved there first, or with ``keep_loss=False``
        go with the nodes (to free the map and its loss map together)."""
        self._m.clear(keep_loss)

    # -- log-odds arithmetic (exact fusion by channel filters) ---------------------------
    def open_clamping(self) -> OccupancyMap:
        """Open the clamping (thresholds -inf/+inf log-odds) in place, so sums stay exact."""
        _core._open_clamping(self._m)
        return self

    def clamp_values(self) -> OccupancyMap:
        """Clamp every stored value to the configured thresholds, in place."""
        _core._clamp_values(self._m)
        return self

    def clamped_copy(self) -> OccupancyMap:
        """A copy clamped to the configured thresholds: ``copy().clamp_values()``, node for
        node, in one walk."""
        return OccupancyMap._wrap(_core._clamped_copy(self._m))

    def negate_values(self) -> OccupancyMap:
        """Negate every stored log-odds, in place."""
        _core._negate_values(self._m)
        return self

    def assign_delta(self, channel: OccupancyMap, delta: OccupancyMap) -> int:
        """Exact fusion of a delta, on its voxels: ``l += m - c`` then ``c = m``, with ``c`` this
        map's copy of the sender's contribution (``channel``, updated in place)."""
        return _core._assign_values(self._m, channel._m, delta._m)

    def changed_since(self, previous: OccupancyMap) -> OccupancyMap:
        """The voxels whose value differs from ``previous`` (a delta message), with this map's
        clamping."""
        return self._same_clamping(OccupancyMap._wrap(_core._changed_voxels(self._m, previous._m)))

    def most_informative(self, held: OccupancyMap, max_nodes: int) -> tuple[OccupancyMap, int]:
        """The voxels of this map (a delta) that change ``held`` (the receiver's copy) most,
        as many as fit in ``max_nodes`` nodes of a stream: ranked by the size of the log-odds
        change, ``|l - l_held|`` (``l_held`` = 0 where ``held`` has no voxel), largest first.
        Returns them and how many voxels (leaves) they are."""
        raw, taken = _core._most_informative_voxels(self._m, held._m, int(max_nodes))
        return self._same_clamping(OccupancyMap._wrap(raw)), taken

    def overlaid(self, delta: OccupancyMap) -> OccupancyMap:
        """A new map: this one with the voxels of ``delta`` written over it (a receiver's
        copy after the delta)."""
        return self._same_clamping(OccupancyMap._wrap(_core._overlaid(self._m, delta._m)))

    def _same_clamping(self, made: OccupancyMap) -> OccupancyMap:
        """``made`` (of this map's parameters) with this map's clamping, open if it is."""
        return made.open_clamping() if self.clamping_logodds != made.clamping_logodds else made

    def class_counts(self, reference: OccupancyMap | ReferenceMap, tol: float) -> dict:
        """Voxel counts of this map against ``reference`` over finest voxels: the class
        confusion (occupied/free/unknown), KL(reference || self) and |l| differences summed,
        and voxels where this map is more certain than the reference by more than ``tol``.
        A map scored against often is read once into a :class:`ReferenceMap`."""
        if not isinstance(reference, ReferenceMap):
            reference = ReferenceMap(reference)
        return _core._compare_maps(reference._r, self._m, float(tol), 0.0)

    @property
    def num_leaves(self) -> int:
        return self._m.num_leaves

    @property
    def known_voxels(self) -> int:
        """Finest voxels the map knows (a coarse leaf counts for every voxel below it)."""
        return self._m.known_voxels

    @property
    def num_nodes(self) -> int:
        return self._m.num_nodes

    @property
    def resolution(self) -> float:
        return self._m.resolution

    @property
    def memory_bytes(self) -> int:
        """Memory used by the tree's nodes, bytes (OctoMap's ``memoryUsage()``)."""
        return self._m.memory_bytes

    @property
    def prob_hit(self) -> float:
        return self._m.prob_hit

    @property
    def prob_miss(self) -> float:
        return self._m.prob_miss

    @property
    def clamping(self) -> tuple[float, float]:
        return self._m.clamping

    @property
    def clamping_logodds(self) -> tuple[float, float]:
        """Clamping thresholds as the float log-odds OctoMap stores."""
        return self._m.clamping_logodds

    def __repr__(self) -> str:
        return (
            f"OccupancyMap(resolution={self.resolution}, leaves={self.num_leaves}, "
            f"memory={self.memory_bytes / 1e6:.1f} MB)"
        )


class ReferenceMap:
    """A map read once to score maps against (:meth:`OccupancyMap.class_counts`): its nodes in
    one array, read faster than the tree. A snapshot: what happens to the map afterwards does
    not change it."""

    __slots__ = ("_r",)

    def __init__(self, m: OccupancyMap):
        if not isinstance(m, OccupancyMap):
            raise TypeError(f"ReferenceMap reads an OccupancyMap, got {type(m).__name__}")
        self._r = _core._ReferenceMap(m._m)

    @property
    def num_nodes(self) -> int:
        return self._r.num_nodes

    @property
    def memory_bytes(self) -> int:
        return self._r.nbytes


def _resolution(resolution) -> float:
    try:
        r = float(resolution)
    except (TypeError, ValueError):
        raise ValueError(f"resolution must be a number of metres, got {resolution!r}") from None
    if not np.isfinite(r) or r <= 0:
        raise ValueError(f"resolution must be a positive number of metres, got {resolution!r}")
    return r


def thread_count(threads) -> int:
    """``threads`` as an int, or a ValueError naming it unless it is a whole number (the core
    then checks its range)."""
    if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)):
        raise ValueError(f"threads must be a whole number, got {threads!r}")
    return int(threads)


def insert_mode(mode) -> str:
    """``mode`` if it is one of :data:`INSERT_MODES`, else a ValueError naming it."""
    if mode not in INSERT_MODES:
        raise ValueError(f"insert mode {mode!r}: expected 'exact' or 'fast'")
    return mode


def _points(points) -> np.ndarray:
    pts = np.asarray(points)
    if pts.dtype not in (np.float32, np.float64):
        pts = pts.astype(np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must be an (N, 3) array, got shape {pts.shape}")
    return np.ascontiguousarray(pts)
