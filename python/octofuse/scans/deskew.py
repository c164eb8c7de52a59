"""De-skew: a LaserScan's beams are measured one after another while the sensor moves, so each
point is moved by the sensor's motion between the scan's stamp and its beam's time."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from .tf import TransformBuffer

#: ``time_range(fixed, frame)``: the first and last stamp (ns) at which ``frame`` is known in
#: ``fixed``, or ``(None, None)`` where it is known at all times
TimeRange = Callable[[str, str], tuple]


def beam_times(
    points: np.ndarray, angle_min, angle_increment, time_increment_ns, stamp
) -> np.ndarray:
    """Stamps (float ns) of the beams that gave the points of a LaserScan: the beam index
    from each point's bearing, ``stamp + index * time_increment`` (scalars or per point)."""
    ang = np.arctan2(points[:, 1], points[:, 0])
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        idx = np.rint(np.mod(ang - angle_min, 2 * np.pi) / angle_increment)
        return stamp + idx * time_increment_ns


def deskew_scan(
    tf: TransformBuffer,
    time_range: TimeRange,
    fixed: str,
    msg,
    points: np.ndarray,
    frame: str,
    stamp: int,
    pose: np.ndarray,
) -> np.ndarray:
    """One scan's points, each moved by the sensor motion between the scan's stamp and its
    beam's time (a 4x4 transform per beam).

    Points come back in the sensor frame at ``stamp``: p = T(stamp)^-1 T(t_i) p_i, with
    t_i = stamp + i * time_increment (beam times clipped to the transforms' time range).
    """
    t = beam_times(
        points, msg.angle_min, msg.angle_increment, float(msg.time_increment) * 1e9, stamp
    )
    if not np.all(np.isfinite(t)):  # degenerate beam timing: no motion correction
        return points
    lo, hi = time_range(fixed, frame)
    if lo is not None:
        t = np.clip(t, lo, hi)
    T = tf.lookup_many(fixed, frame, t.astype(np.int64))
    world = np.einsum("kij,kj->ki", T[:, :3, :3], points) + T[:, :3, 3]
    return _into_sensor_frame(world, pose)


def deskew_scans(
    tf: TransformBuffer,
    time_range: TimeRange,
    fixed: str,
    msgs: Sequence,
    points: Sequence[np.ndarray],
    frames: Sequence[str],
    stamps: Sequence[int],
    poses: Sequence[np.ndarray],
) -> list[np.ndarray]:
    """:func:`deskew_scan` of several scans: the beam times of all of them at once, and one
    :meth:`TransformBuffer.transform_points` per frame over all their beams (no 4x4 matrix per
    beam)."""
    sizes = np.array([len(p) for p in points])
    starts = np.concatenate(([0], np.cumsum(sizes)[:-1]))
    per_beam = lambda values: np.repeat(np.array(values, dtype=np.float64), sizes)  # noqa: E731
    t = beam_times(
        np.concatenate(points),
        per_beam([m.angle_min for m in msgs]),
        per_beam([m.angle_increment for m in msgs]),
        per_beam([float(m.time_increment) * 1e9 for m in msgs]),
        per_beam(stamps),
    )
    timed = np.logical_and.reduceat(np.isfinite(t), starts)  # else no motion correction
    by_frame: dict[str, list[int]] = {}
    for j, frame in enumerate(frames):
        if timed[j]:
            by_frame.setdefault(frame, []).append(j)
    out = list(points)
    for frame, js in by_frame.items():
        beams = np.concatenate([np.arange(starts[j], starts[j] + sizes[j]) for j in js])
        tf_ns = t[beams]
        lo, hi = time_range(fixed, frame)
        if lo is not None:
            tf_ns = np.clip(tf_ns, lo, hi)
        world = tf.transform_points(
            fixed, frame, tf_ns.astype(np.int64), np.concatenate([points[j] for j in js])
        )
        at = 0
        for j in js:
            mine = world[at : at + sizes[j]]
            at += sizes[j]
            out[j] = _into_sensor_frame(mine, poses[j])
    return out


def _into_sensor_frame(world: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Points of the fixed frame back in the sensor frame at the scan's stamp (``pose``, a
    rigid transform): R^T (x - t)."""
    return (world - pose[:3, 3]) @ pose[:3, :3]
