"""Landmarks from occupancy-map leaves, their association across robots, and each robot's map
offset measured on them (the measurement robust voting works on).

- :func:`extract_landmarks`: objects standing on the floor, as connected occupied voxels above it,
  each with its centroid and covariance.
- :func:`associate`: one-to-one matching of two landmark sets (Hungarian, distance-gated).
- :func:`map_offset`: the rigid 2-D transform ``(dx, dy, yaw)`` that carries a robot's landmarks
  onto a reference set, with its covariance.
- :func:`offsets_to_reference`: that measurement for every robot, ready for
  :func:`octofuse.fusion.voting.dynamic_vote`.

All functions take plain arrays (leaf centres, sizes, log-odds), not map objects.

Measurement design. Every robot measures the transform between its own map frame and one shared
reference landmark set (for example the landmarks of one robot's map, or of a prior map), with the
rotation about a fixed pivot (the reference's mean centroid). A correctly localised robot measures
about zero, a robot whose poses were offset or rotated measures that error. If the reference
itself is wrong, every robot's measurement moves by the same transform, so the robots that agree
with each other still agree: the vote is on agreement, not on the reference. The measurements of
different robots share the reference's errors, so they are not independent as the voting theory
assumes; with landmark covariances far below the errors sought this matters little.

A landmark's covariance is the covariance of its voxel centres plus the voxel quantisation
(``resolution^2 / 12`` per axis): one standard deviation of the object's own extent. That is
meant to be conservative for the centroid, but a robot that saw only one face of a box has a thin
component with a small spread across that face, while its centroid lies up to half a box from the
truth: on the simulated lab the centroids of the 0.5-0.7 m boxes differ by up to 0.3 m between
robots that saw different faces. ``centroid_sigma`` adds a floor for that.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Landmarks:
    """Objects found in one map: centroids (M, 3), covariances (M, 3, 3), voxel counts (M,),
    bounding boxes ``lower`` / ``upper`` (M, 3) of their voxels (outer faces)."""

    centroids: np.ndarray
    covariances: np.ndarray
    voxels: np.ndarray
    lower: np.ndarray
    upper: np.ndarray

    def __len__(self) -> int:
        return len(self.centroids)


def extract_landmarks(
    centers,
    sizes,
    values,
    *,
    resolution: float | None = None,
    floor_height: float = 0.0,
    clearance: float | None = None,
    occupied: float = 0.0,
    max_footprint: float = 2.0,
    max_height: float | None = None,
    within=None,
    min_voxels: int = 2,
    centroid_sigma: float = 0.0,
) -> Landmarks:
    """Objects standing on the floor in a map given by its leaves.

    ``centers`` (N, 3), ``sizes`` (N,) and ``values`` (N,) log-odds are a map's leaves (coarse
    leaves are split into finest voxels of ``resolution``, by default the smallest leaf size).
    Voxels with log-odds above ``occupied`` whose centres lie more than ``clearance`` (default
    one voxel) above ``floor_height`` are grouped into 26-connected components; components of at
    least ``min_voxels`` voxels whose horizontal extent is at most ``max_footprint`` (walls and
    long clutter are longer) are the landmarks, sorted by centroid x then y. ``max_height`` drops
    components reaching higher above the floor, ``within`` = ``((x0, y0), (x1, y1))`` keeps only
    components whose voxels all lie in that rectangle (for example a room's inside, so that the
    pieces in which a wall is seen are not taken for objects). ``centroid_sigma`` (m) is added
    to every axis of each covariance, for objects seen from one side only.
    """
    from scipy import ndimage

    centers, sizes, values = _check_leaves(centers, sizes, values)
    if resolution is None:
        resolution = float(sizes.min()) if len(sizes) else 1.0
    if not resolution > 0:
        raise ValueError(f"resolution must be positive, got {resolution!r}")
    clearance = resolution if clearance is None else float(clearance)
    if within is not None:
        area = np.asarray(within, dtype=float)
        if area.shape != (2, 2) or np.any(area[1] <= area[0]):
            raise ValueError(
                f"within must be ((x0, y0), (x1, y1)) with x0 < x1 and y0 < y1, got {within!r}"
            )

    keys = _occupied_keys(centers[values > occupied], sizes[values > occupied], resolution)
    pts = (keys + 0.5) * resolution
    keys = keys[pts[:, 2] > floor_height + clearance]
    if len(keys) == 0:
        return _empty()
    lo = keys.min(axis=0)
    grid = np.zeros(tuple(keys.max(axis=0) - lo + 1), dtype=bool)
    grid[tuple((keys - lo).T)] = True
    labels, count = ndimage.label(grid, structure=np.ones((3, 3, 3), dtype=bool))
    which = labels[tuple((keys - lo).T)] - 1  # component of every voxel

    order = np.argsort(which, kind="stable")
    bounds = np.searchsorted(which[order], np.arange(count + 1))
    found = []
    for c in range(count):
        members = keys[order[bounds[c] : bounds[c + 1]]]
        low, high = members.min(axis=0) * resolution, (members.max(axis=0) + 1) * resolution
        if len(members) < min_voxels or np.max(high[:2] - low[:2]) > max_footprint:
            continue
        if max_height is not None and high[2] > floor_height + max_height:
            continue
        if within is not None and not (np.all(low[:2] >= area[0]) and np.all(high[:2] <= area[1])):
            continue
        p = (members + 0.5) * resolution
        cov = np.cov(p.T, bias=True) + np.eye(3) * (resolution**2 / 12.0 + centroid_sigma**2)
        found.append((p.mean(axis=0), cov, len(members), low, high))
    if not found:
        return _empty()
    found.sort(key=lambda f: (round(f[0][0], 6), round(f[0][1], 6)))
    cen, cov, n, low, high = (np.array(v) for v in zip(*found))
    return Landmarks(cen, cov, n.astype(np.int64), low, high)


def associate(reference: Landmarks, landmarks: Landmarks, max_distance: float = 0.5) -> np.ndarray:
    """One-to-one pairs ``(reference index, landmark index)`` (P, 2) minimising the total
    horizontal distance between centroids (Hungarian), pairs farther than ``max_distance`` dropped."""
    from scipy.optimize import linear_sum_assignment

    if not max_distance > 0:
        raise ValueError(f"max_distance must be positive, got {max_distance!r}")
    if len(reference) == 0 or len(landmarks) == 0:
        return np.empty((0, 2), dtype=np.int64)
    dist = np.linalg.norm(
        reference.centroids[:, None, :2] - landmarks.centroids[None, :, :2], axis=-1
    )
    big = 1e6 + dist.max()
    rows, cols = linear_sum_assignment(np.where(dist <= max_distance, dist, big))
    keep = dist[rows, cols] <= max_distance
    return np.column_stack([rows[keep], cols[keep]]).astype(np.int64)


def map_offset(
    reference: Landmarks,
    landmarks: Landmarks,
    pairs: np.ndarray | None = None,
    *,
    pivot=None,
    max_distance: float = 0.5,
) -> tuple[np.ndarray, np.ndarray]:
    """The transform ``(dx, dy, yaw)`` with ``R(yaw) (p - pivot) + pivot + (dx, dy) ≈ p_ref`` that
    carries ``landmarks`` onto ``reference`` over associated ``pairs`` (found with
    :func:`associate` when not given), and its covariance (3, 3) by weighted least squares
    (weights: the inverse of the sum of the pair's horizontal covariances). ``pivot`` defaults to
    the mean of the reference centroids. At least two pairs are needed (yaw)."""
    if pairs is None:
        pairs = associate(reference, landmarks, max_distance)
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if len(pairs) < 2:
        raise ValueError(f"map_offset needs at least 2 associated landmarks, got {len(pairs)}")
    pivot = (
        reference.centroids[:, :2].mean(axis=0) if pivot is None else np.asarray(pivot, float)[:2]
    )
    ref = reference.centroids[pairs[:, 0], :2] - pivot
    own = landmarks.centroids[pairs[:, 1], :2] - pivot
    cov_sum = (
        reference.covariances[pairs[:, 0], :2, :2] + landmarks.covariances[pairs[:, 1], :2, :2]
    )

    # closed-form start (unweighted Procrustes), then Gauss-Newton on the weighted residuals
    a, b = own - own.mean(0), ref - ref.mean(0)
    yaw = np.arctan2(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]), np.sum(a * b))
    t = ref.mean(0) - _rot(yaw) @ own.mean(0)
    weight = np.linalg.inv(cov_sum)
    jac = np.zeros((len(pairs), 2, 3))
    jac[:, :, :2] = np.eye(2)
    for _ in range(5):
        resid = own @ _rot(yaw).T + t - ref
        jac[:, :, 2] = own @ _rot_derivative(yaw).T
        normal = np.einsum("pia,pij,pjb->ab", jac, weight, jac)
        grad = np.einsum("pia,pij,pj->a", jac, weight, resid)
        step = np.linalg.solve(normal, -grad)
        t, yaw = t + step[:2], yaw + step[2]
        if np.abs(step).max() < 1e-12:
            break
    jac[:, :, 2] = own @ _rot_derivative(yaw).T
    normal = np.einsum("pia,pij,pjb->ab", jac, weight, jac)
    cov = np.linalg.inv(normal)
    return np.array([t[0], t[1], (yaw + np.pi) % (2 * np.pi) - np.pi]), 0.5 * (cov + cov.T)


def offsets_to_reference(
    landmark_sets: list[Landmarks], reference: Landmarks | int, *, max_distance: float = 0.5
) -> tuple[np.ndarray, np.ndarray]:
    """Every robot's :func:`map_offset` to one shared reference (a landmark set, or the index of
    the robot whose landmarks serve as reference) with the rotation about the same pivot:
    measurements ``x`` (N, 3) and covariances (N, 3, 3) for voting."""
    ref = landmark_sets[reference] if isinstance(reference, (int, np.integer)) else reference
    pivot = ref.centroids[:, :2].mean(axis=0)
    out = [map_offset(ref, lm, pivot=pivot, max_distance=max_distance) for lm in landmark_sets]
    return np.array([o[0] for o in out]), np.array([o[1] for o in out])


def _rot(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s], [s, c]])


def _rot_derivative(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[-s, -c], [c, -s]])


def _occupied_keys(centers: np.ndarray, sizes: np.ndarray, resolution: float) -> np.ndarray:
    """Integer keys (M, 3) of the finest voxels of the given leaves; voxel k spans
    ``[k, k + 1) * resolution``."""
    lower = np.rint((centers - sizes[:, None] / 2) / resolution).astype(np.int64)
    span = np.maximum(np.rint(sizes / resolution).astype(np.int64), 1)
    keys = [np.empty((0, 3), np.int64)]
    for s in np.unique(span):
        sel = span == s
        offsets = np.stack(np.meshgrid(*(np.arange(s),) * 3, indexing="ij"), -1).reshape(-1, 3)
        keys.append((lower[sel][:, None, :] + offsets[None]).reshape(-1, 3))
    return np.unique(np.concatenate(keys), axis=0)


def _check_leaves(centers, sizes, values) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    centers = np.asarray(centers, dtype=float)
    sizes = np.asarray(sizes, dtype=float)
    values = np.asarray(values, dtype=float)
    if centers.ndim != 2 or centers.shape[1] != 3:
        raise ValueError(f"centers must have shape (N, 3), got {centers.shape}")
    if sizes.shape != (len(centers),) or values.shape != (len(centers),):
        raise ValueError(
            f"sizes {sizes.shape} and values {values.shape} must have shape ({len(centers)},)"
        )
    if not (np.all(np.isfinite(centers)) and np.all(sizes > 0)):
        raise ValueError("centers must be finite and sizes positive")
    return centers, sizes, values


def _empty() -> Landmarks:
    z = np.empty((0, 3))
    return Landmarks(z, np.empty((0, 3, 3)), np.empty(0, np.int64), z, z.copy())
