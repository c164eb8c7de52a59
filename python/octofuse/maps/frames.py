"""Map frames and resolutions: rigid transforms, ``NAME=x,y,z,roll,pitch,yaw`` frames, and
the preparation of maps from different frames and voxel sizes for fusion.

- :func:`pose_matrix` / :func:`matrix_pose`: a 4x4 rigid transform from / to ``x, y, z`` (metres)
  and ``roll, pitch, yaw`` (radians; R = Rz(yaw) Ry(pitch) Rx(roll), as ROS and tf use them).
- :func:`~octofuse.scans.se3.check_rigid` (from ``scans.se3``): the checks every transform passes.
- :func:`parse_frame`: ``"NAME=x,y,z,roll,pitch,yaw"`` (metres, radians).
- :func:`common_resolution`: the voxel size maps of different resolutions are fused at.
- :func:`prepare_maps`: maps moved into the common frame and resampled to one resolution.
- :func:`fuse_map_files`: any number of map files fused into one, with one loss convention.

Resolution rule. Maps of different voxel size are resampled to the COARSEST of their
resolutions unless a resolution is given: resampling a fine map to a coarse grid only
summarises what it measured (a coarse voxel is occupied if any part of it is, else it holds
the mean of its free parts), while resampling a coarse map to a fine grid would claim a
precision it never had (its blocks would be fused voxel by voxel with real fine detail). With
``strict=True`` maps of different resolutions are refused as before.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..scans.se3 import check_rigid


def pose_matrix(
    x: float = 0.0,
    y: float = 0.0,
    z: float = 0.0,
    roll: float = 0.0,
    pitch: float = 0.0,
    yaw: float = 0.0,
) -> np.ndarray:
    """The 4x4 homogeneous transform with translation (x, y, z) and rotation
    R = Rz(yaw) Ry(pitch) Rx(roll) (fixed axes: roll about x first, then pitch, then yaw)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    T = np.eye(4)
    T[:3, :3] = [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]
    T[:3, 3] = (x, y, z)
    # exact zeros and ones for multiples of 90 degrees (cos(pi/2) is 6e-17, not 0)
    R = T[:3, :3]
    R[np.abs(R) < 1e-15] = 0.0
    return T


def matrix_pose(T) -> dict[str, float]:
    """``x, y, z, roll, pitch, yaw`` of a rigid transform (inverse of :func:`pose_matrix`;
    pitch in [-pi/2, pi/2])."""
    T = check_rigid(T)
    R = T[:3, :3]
    pitch = math.asin(max(-1.0, min(1.0, -R[2, 0])))
    if abs(R[2, 0]) < 1 - 1e-12:
        roll = math.atan2(R[2, 1], R[2, 2])
        yaw = math.atan2(R[1, 0], R[0, 0])
    else:  # gimbal lock: only roll - yaw (or roll + yaw) is defined; put it all in yaw
        roll = 0.0
        yaw = math.atan2(-R[0, 1], R[1, 1])
    return {
        "x": float(T[0, 3]),
        "y": float(T[1, 3]),
        "z": float(T[2, 3]),
        "roll": roll,
        "pitch": pitch,
        "yaw": yaw,
    }


def invert(T) -> np.ndarray:
    """Inverse of a rigid transform."""
    T = check_rigid(T)
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


def parse_pose(text: str, what: str = "frame") -> np.ndarray:
    """``"x,y,z,roll,pitch,yaw"`` (metres, radians) as a 4x4 transform; ``ValueError`` naming
    ``what`` and the text otherwise (all six numbers are required: ``x,y,yaw`` and ``x,y,z``
    would be ambiguous)."""
    return pose_matrix(*parse_pose_values(text, what))


def parse_pose_values(text: str, what: str = "frame") -> list[float]:
    """The six numbers of ``"x,y,z,roll,pitch,yaw"``, checked as :func:`parse_pose` does."""
    parts = [p.strip() for p in str(text).split(",")]
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        raise ValueError(
            f"{what} '{text}': expected 6 numbers x,y,z,roll,pitch,yaw (metres, radians)"
        ) from None
    if len(vals) != 6:
        raise ValueError(
            f"{what} '{text}': expected 6 numbers x,y,z,roll,pitch,yaw (metres, "
            f"radians), got {len(vals)}"
        )
    if not all(math.isfinite(v) for v in vals):
        raise ValueError(f"{what} '{text}': values must be finite")
    return vals


def parse_frame(spec: str) -> tuple[str, np.ndarray]:
    """``"NAME=x,y,z,roll,pitch,yaw"`` as ``(NAME, 4x4 transform)`` (NAME's frame into the
    common frame)."""
    name, vals = parse_frame_values(spec)
    return name, pose_matrix(*vals)


def parse_frame_values(spec: str) -> tuple[str, list[float]]:
    """``"NAME=x,y,z,roll,pitch,yaw"`` as ``(NAME, [x, y, z, roll, pitch, yaw])``."""
    name, sep, rest = str(spec).partition("=")
    if not sep or not name.strip():
        raise ValueError(f"frame '{spec}': expected NAME=x,y,z,roll,pitch,yaw")
    return name.strip(), parse_pose_values(rest, f"frame '{name.strip()}'")


def common_resolution(
    resolutions: Sequence[float], resolution: float | None = None, strict: bool = False
) -> float:
    """The voxel size maps of ``resolutions`` are fused at: ``resolution`` if given, else the
    coarsest (largest) of them. With ``strict=True`` different resolutions (or a given
    resolution that differs from theirs) raise the fusion's ``ValueError``."""
    rs = [float(r) for r in resolutions]
    if not rs:
        raise ValueError("no maps given")
    differ = max(rs) - min(rs) > 1e-9 * max(rs)
    if strict and (
        differ or (resolution is not None and abs(float(resolution) - rs[0]) > 1e-9 * rs[0])
    ):
        listed = " m, ".join(f"{r:g}" for r in sorted(set(rs)))
        raise ValueError(
            f"maps have different resolutions ({listed} m"
            + (f", requested {float(resolution):g} m" if resolution is not None else "")
            + "); fuse maps built at the same resolution, or leave strict off to "
            "resample them"
        )
    if resolution is not None:
        from .occupancy import _resolution

        return _resolution(resolution)
    return max(rs)


def prepare_maps(
    maps: Sequence,
    frames: Sequence | None = None,
    resolution: float | None = None,
    strict: bool = False,
) -> list:
    """The maps moved into the common frame and resampled to one resolution, ready to fuse.

    ``frames[i]`` is the 4x4 rigid transform of map i's frame into the common frame (``None``:
    the map is already in it). The resolution is :func:`common_resolution`. A map that needs
    neither a move nor a resampling is passed through unchanged (not copied).
    """
    maps = list(maps)
    frames = [None] * len(maps) if frames is None else list(frames)
    if len(frames) != len(maps):
        raise ValueError(f"{len(frames)} frames given for {len(maps)} maps")
    res = common_resolution([m.resolution for m in maps], resolution, strict)
    out = []
    for i, (m, T) in enumerate(zip(maps, frames)):
        T = None if T is None else check_rigid(T, f"frame of map {i + 1}")
        same_res = abs(m.resolution - res) <= 1e-9 * res
        if (T is None or np.array_equal(T, np.eye(4))) and same_res:
            out.append(m)
        else:
            out.append(m.transformed(np.eye(4) if T is None else T, res))
    return out


@dataclass
class FuseStats:
    """What :func:`fuse_map_files` did.

    ``loss_mean`` is the information loss (nats) averaged over the voxels actually fused (known
    to two or more maps, counted once per pairwise fusion); voxels known to one map only are
    copied (or fused with the prior, ``unknown="prior"``) and counted in ``voxels_copied``: the
    same convention as ``run`` and ``fuse``.
    """

    inputs: list[str]
    resolution: float
    voxels_fused: int = 0
    voxels_copied: int = 0
    loss_mean: float = 0.0
    loss_p95: float = 0.0
    loss_total: float = 0.0
    leaves: int = 0
    resampled: list[str] = field(default_factory=list)

    def as_dict(self) -> dict:
        return {
            "inputs": self.inputs,
            "resolution": self.resolution,
            "voxels_fused": self.voxels_fused,
            "voxels_copied": self.voxels_copied,
            "loss_mean": self.loss_mean,
            "loss_p95": self.loss_p95,
            "loss_total": self.loss_total,
            "leaves": self.leaves,
            "resampled": self.resampled,
        }


def fuse_map_files(
    paths: Sequence[str | os.PathLike],
    rule: str = "min-info-loss",
    unknown: str = "copy",
    frames: Sequence | Mapping | None = None,
    resolution: float | None = None,
    strict: bool = False,
):
    """Fuse any number of ``.ot``/``.bt`` map files into one: ``(fused, loss, stats)``.

    ``frames``: one rigid 4x4 transform (or ``None``) per path, in order, or a mapping from a
    file's stem or path to its transform (map frame into the common frame); files without one
    are in the common frame. Maps are resampled to :func:`common_resolution` (``strict=True``:
    different resolutions are an error). The maps are fused left to right
    (``((m1 + m2) + m3) + ...``; every rule of octofuse is commutative, and for
    ``min-info-loss`` and ``naive-bayes`` also associative). ``loss`` is the
    :class:`~octofuse.maps.infoloss.InfoLossMap` accumulated over the fusions; ``stats`` is a
    :class:`FuseStats` (mean loss over fused voxels only; copied voxels counted separately).
    """
    from ..rules import parse_rule, parse_unknown
    from .infoloss import InfoLossMap, voxels_per_leaf
    from .occupancy import OccupancyMap
    from .tree_fusion import fuse_into

    paths = [Path(p) for p in paths]
    if not paths:
        raise ValueError("no map files given")
    rule, unknown = parse_rule(rule), parse_unknown(unknown)
    if isinstance(frames, Mapping):
        keys = {str(p) for p in paths} | {p.stem for p in paths} | {p.name for p in paths}
        extra = sorted(k for k in frames if str(k) not in keys)
        if extra:
            raise ValueError(
                f"frame given for unknown map '{extra[0]}' (maps: "
                f"{', '.join(p.stem for p in paths)})"
            )
        by = {str(k): v for k, v in frames.items()}
        frames = [by.get(str(p), by.get(p.name, by.get(p.stem))) for p in paths]
    elif frames is not None:
        frames = list(frames)
        if len(frames) != len(paths):
            raise ValueError(f"{len(frames)} frames given for {len(paths)} map files")
    frames = [
        None if T is None else check_rigid(T, f"frame of '{p}'")
        for p, T in zip(paths, frames or [None] * len(paths))
    ]
    maps = [OccupancyMap.load(p) for p in paths]
    res = common_resolution([m.resolution for m in maps], resolution, strict)
    ready = prepare_maps(maps, frames, res, strict)
    stats = FuseStats(
        [str(p) for p in paths],
        res,
        resampled=[str(p) for p, a, b in zip(paths, maps, ready) if a is not b],
    )
    fused = ready[0]  # loaded or resampled here, so ours to change in place
    loss = InfoLossMap(res)
    prior = unknown == parse_unknown("prior")
    known = fused.known_voxels  # finest voxels the fused map knows so far
    for m in ready[1:]:
        fused_before, copied_before = loss.voxels_fused, loss.voxels_copied
        fuse_into(fused, m, rule=rule, unknown=unknown, loss=loss)
        fused_now = loss.voxels_fused - fused_before
        only_m = loss.voxels_copied - copied_before
        if not prior:  # the voxels only the fused map knew are not visited: copied as well
            loss.voxels_copied += known - fused_now
        known = fused_now if prior else known + only_m
    # one convention: counts in finest voxels, loss averaged over fused voxels only
    stats.voxels_fused, stats.voxels_copied = loss.voxels_fused, loss.voxels_copied
    stats.loss_total = loss.loss_sum
    lv = loss.leaves()
    if len(lv.values):
        w = voxels_per_leaf(lv.depths)
        v = lv.values.astype(np.float64)
        if stats.voxels_fused:
            stats.loss_mean = stats.loss_total / stats.voxels_fused
            stats.loss_p95 = _fused_percentile(v, w, stats.voxels_fused, 95.0)
    stats.leaves = fused.num_leaves
    return fused, loss, stats


def _fused_percentile(v: np.ndarray, w: np.ndarray, n_fused: int, q: float) -> float:
    """The q-th percentile of the loss over the ``n_fused`` fused voxels: the loss tree also
    holds the copied voxels at zero loss, so that many zeros are taken out first."""
    from .compare import weighted_percentile

    extra = float(w.sum()) - n_fused  # copied voxels (zero loss) among the leaves
    if extra > 0:  # taken from the lowest values (<= 0) up, in sorted order
        low = np.flatnonzero(v <= 0.0)
        low = low[np.argsort(v[low])]
        before = np.cumsum(w[low]) - w[low]
        w = w.copy()
        w[low] -= np.clip(extra - before, 0.0, w[low])
    return weighted_percentile(v, w, q) if w.sum() > 0 else 0.0
