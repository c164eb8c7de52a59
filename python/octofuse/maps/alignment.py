"""2-D registration of occupancy maps: how far one robot's map is from its neighbours' maps.

- :func:`occupied_points`: the horizontal positions (M, 2) of a map's occupied voxels above the
  floor (walls and objects: what every robot sees of the same room).
- :func:`register`: point-to-line ICP of one such point set onto another, giving the rigid
  transform ``(dx, dy, yaw)`` with ``R(yaw) (p - pivot) + pivot + (dx, dy) ≈ q`` and its covariance.
- :func:`neighbour_offset`: a robot's offset to the majority of its neighbours' maps, the
  measurement robust voting works on (:mod:`octofuse.fusion.robust`).

Measurement design. Robot ``i`` registers its own map onto the map of every neighbour ``j``
(rotation about the centroid of its own points, so all of ``i``'s offsets share one pivot).
Correctly localised robots are offset by about zero from each other; a robot whose poses are
wrong is offset by its error from every neighbour, and an inlier next to it sees that error in
one offset among several. Each robot therefore keeps the largest group of its neighbour offsets
that agree with each other (pairwise chi-square test) and measures their information-weighted
mean, ``x_i``: about zero for an inlier whose neighbours are mostly correct, the inverse of its
own error for a wrongly localised robot. A robot that cannot form a majority (fewer than two
agreeing offsets, or two groups of equal size) abstains: its measurement is zero with a very
large covariance, so it passes every test and adds almost nothing to any estimate (it cannot
be voted out, nor can it accuse anybody).

Covariance. Point-to-line ICP minimises ``sum (n_k . (T p_k - q_k))^2``; with the Gauss-Newton
matrix ``H = J^T J`` and the residual variance ``s^2``, the covariance is ``s^2 H^-1``. Along
a wall ``H`` is weak and the covariance large, as it should be. Neighbouring voxels do not
give independent residuals (quantisation, smearing), so ``s^2 H^-1`` is optimistic: it is
multiplied by ``inflation`` and a floor ``diag(floor_xy^2, floor_xy^2, floor_yaw^2)`` is added
to the measurement (what two correct maps may disagree by: about a voxel and a fraction of a
degree).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .landmarks import _occupied_keys

#: the covariance of an abstaining robot (metres^2, metres^2, rad^2 on the diagonal)
ABSTAIN_VARIANCE = 1e6


def occupied_points(
    centers,
    sizes,
    values,
    resolution: float,
    *,
    floor_height: float = 0.0,
    clearance: float = 0.1,
    occupied: float = 0.0,
) -> np.ndarray:
    """Distinct horizontal centres (M, 2) of the occupied finest voxels (log-odds above
    ``occupied``) whose centres lie more than ``clearance`` above ``floor_height``."""
    centers = np.asarray(centers, dtype=float).reshape(-1, 3)
    sizes, values = np.asarray(sizes, dtype=float), np.asarray(values, dtype=float)
    occ = values > occupied
    keys = _occupied_keys(centers[occ], sizes[occ], resolution)
    keys = keys[(keys[:, 2] + 0.5) * resolution > floor_height + clearance]
    return (np.unique(keys[:, :2], axis=0) + 0.5) * resolution


def map_points(m, **options) -> np.ndarray:
    """:func:`occupied_points` of an :class:`~octofuse.maps.occupancy.OccupancyMap`."""
    lv = m.leaves()
    return occupied_points(lv.centers, lv.sizes, lv.values, m.resolution, **options)


@dataclass(frozen=True)
class Registration:
    """A rigid 2-D transform ``params = (dx, dy, yaw)`` about ``pivot``, its covariance (3, 3),
    the number of matched points and their RMS point-to-line residual (m)."""

    params: np.ndarray
    covariance: np.ndarray
    pairs: int
    rms: float

    def apply(self, points: np.ndarray, pivot) -> np.ndarray:
        return (points - pivot) @ _rot(self.params[2]).T + np.asarray(pivot) + self.params[:2]


def _normals(target: np.ndarray, tree, k: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (M, 2) of the target points from the PCA of their ``k`` nearest
    neighbours, and whether the neighbourhood is line-like (M,)."""
    k = min(k, len(target))
    _, idx = tree.query(target, k=k)
    nb = target[idx] - target[idx].mean(axis=1, keepdims=True)
    cov = np.einsum("mki,mkj->mij", nb, nb) / k
    w, v = np.linalg.eigh(cov)
    return v[:, :, 0], w[:, 0] <= 0.25 * np.maximum(w[:, 1], 1e-12)


def register(
    source: np.ndarray,
    target: np.ndarray,
    *,
    pivot=None,
    initial=(0.0, 0.0, 0.0),
    gates=(1.0, 0.6, 0.4, 0.25, 0.15),
    iterations: int = 8,
    min_pairs: int = 100,
    inflation: float = 4.0,
) -> Registration | None:
    """Point-to-line ICP of ``source`` (M, 2) onto ``target`` (L, 2), starting at ``initial``.

    Pairs are nearest neighbours closer than the current gate; the gate shrinks through
    ``gates`` (``iterations`` Gauss-Newton steps each). ``pivot`` defaults to the centroid of
    ``source``. Returns ``None`` when fewer than ``min_pairs`` pairs remain or the overlap does
    not constrain all three parameters (for example a single straight wall)."""
    from scipy.spatial import cKDTree

    source, target = (
        np.asarray(source, float).reshape(-1, 2),
        np.asarray(target, float).reshape(-1, 2),
    )
    if len(source) < min_pairs or len(target) < max(min_pairs, 3):
        return None
    pivot = source.mean(axis=0) if pivot is None else np.asarray(pivot, float)
    tree = cKDTree(target)
    normals, linear = _normals(target, tree)
    x = np.array(initial, dtype=float)
    rel = source - pivot
    for gate in gates:
        for _ in range(iterations):
            moved = rel @ _rot(x[2]).T + pivot + x[:2]
            dist, idx = tree.query(moved, distance_upper_bound=gate)
            ok = np.isfinite(dist)
            ok[ok] &= linear[idx[ok]]
            if ok.sum() < min_pairs:
                return None
            n, q = normals[idx[ok]], target[idx[ok]]
            r = np.einsum("mi,mi->m", n, moved[ok] - q)
            jac = np.column_stack([n, np.einsum("mi,mi->m", n, rel[ok] @ _drot(x[2]).T)])
            h = jac.T @ jac
            if np.linalg.cond(h) > 1e8:
                return None
            step = -np.linalg.solve(h, jac.T @ r)
            x += step
            if np.abs(step[:2]).max() < 1e-5 and abs(step[2]) < 1e-6:
                break
    dof = max(len(r) - 3, 1)
    s2 = max(float(r @ r) / dof, 1e-8)
    cov = inflation * s2 * np.linalg.inv(h)
    return Registration(x, 0.5 * (cov + cov.T), int(len(r)), float(np.sqrt(np.mean(r**2))))


def neighbour_offset(
    own: np.ndarray,
    neighbours,
    *,
    floor_xy: float = 0.05,
    floor_yaw_deg: float = 1.0,
    agree: float = 0.999,
    **register_options,
) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """A robot's offset ``(dx, dy, yaw)`` to the majority of its neighbours' maps.

    ``own`` (M, 2) is the robot's :func:`occupied_points`, ``neighbours`` a sequence of its
    neighbours' point sets. Every neighbour is registered with :func:`register` (pivot: the
    centroid of ``own``); offsets whose difference passes the chi-square test at ``agree`` (3
    degrees of freedom, the two covariances plus twice the floor) agree. The largest group of
    mutually agreeing offsets, if it has at least two members and no other group is as large,
    gives the information-weighted mean and its covariance plus the floor. Returns the
    measurement (3,), its covariance (3, 3) and the indices of the neighbours used (empty:
    the robot abstains, see the module docstring)."""
    from itertools import combinations

    from scipy.stats import chi2

    own = np.asarray(own, float).reshape(-1, 2)
    floor = np.diag([floor_xy**2, floor_xy**2, np.radians(floor_yaw_deg) ** 2])
    abstain = (np.zeros(3), np.eye(3) * ABSTAIN_VARIANCE, [])
    if len(own) == 0:
        return abstain
    pivot = own.mean(axis=0)
    regs = {
        j: register(own, pts, pivot=pivot, **register_options) for j, pts in enumerate(neighbours)
    }
    regs = {j: r for j, r in regs.items() if r is not None}
    limit = chi2.ppf(agree, 3)

    def agrees(a: Registration, b: Registration) -> bool:
        d = a.params - b.params
        return float(d @ np.linalg.solve(a.covariance + b.covariance + 2 * floor, d)) <= limit

    best: list[tuple[int, ...]] = []
    keys = sorted(regs)
    for size in range(len(keys), 1, -1):
        best = [
            g
            for g in combinations(keys, size)
            if all(agrees(regs[a], regs[b]) for a, b in combinations(g, 2))
        ]
        if best:
            break
    if len(best) != 1:
        return abstain
    info = sum(np.linalg.inv(regs[j].covariance) for j in best[0])
    vec = sum(np.linalg.solve(regs[j].covariance, regs[j].params) for j in best[0])
    cov = np.linalg.inv(info)
    return np.linalg.solve(info, vec), 0.5 * (cov + cov.T) + floor, list(best[0])


def _rot(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s], [s, c]])


def _drot(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[-s, -c], [c, -s]])
