"""Registration of two occupancy maps from their occupied voxels (open3d).

:func:`register` estimates the rigid transform that takes a point of map B's frame into map A's
frame, so that ``B.transformed(result.matrix)`` lies on ``A``:

1. the centres of the occupied finest voxels of each map, thinned to one point per
   ``voxel`` metres (default: two map voxels), with normals;
2. FPFH features (open3d) on the same points thinned further to about
   :data:`FEATURE_POINTS` points for large maps, and a RANSAC search over mutual feature
   matches for a coarse transform (a fixed seed, on one thread: the same maps always give the
   same transform; open3d's own RANSAC runs on several threads and does not);
3. ICP refinement on the step-1 points: point-to-plane ICP in the full mode; in the
   planar mode (ground robots: ``roll = pitch = 0``) only ``x, y, z`` and ``yaw`` are
   estimated: the coarse transform reduced to its yaw, and a yaw-only 2-point RANSAC over
   mutual feature matches, each refined by point-to-point ICP solved in closed form for a
   rotation about z; the one with the higher fitness is kept.

``fitness`` is the fraction of B's points that have a point of A within ``max(voxel, 1.5 map
resolutions)`` after alignment (as open3d counts it). Every step after the features (open3d's)
runs in numpy and scipy on one thread. ``conflict`` is what geometry alone does
not see: the fraction of B's occupied voxels, moved into A and landing in space A knows, that
land where A saw free space with no occupied voxel beside it (a wall of B in A's empty room).
The result is refused with ``ValueError`` (one line saying why) when either map has too few
occupied voxels, when too few correspondences support the transform, when the fitness is below
``min_fitness``, when the matched surfaces all face about one way (one wall or a floor: the
maps could slide along it), or when the conflict exceeds ``max_conflict``: the overlap is then
too small, or too ambiguous, to trust. (In repetitive rooms registration finds transforms
metres off that match 50-75% of the points; their conflict was 4.5-20%, that of correct
transforms 1.3-1.8%.)
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from .frames import matrix_pose, pose_matrix

#: samples the coarse RANSAC draws
RANSAC_TRIES = 20000
#: fewest occupied points (after thinning) either map must have
MIN_POINTS = 60
#: fewest correspondences within the ICP distance that must support the transform
MIN_INLIERS = 40
#: points (about) the feature search runs on; larger maps are thinned further for it
FEATURE_POINTS = 15000
#: smallest ratio of the least to the largest eigenvalue of the matched surfaces' normal matrix
#: (sum n n^T): below it the overlap is one wall or floor, and slides along it
MIN_SPREAD = 0.1
#: fewest of B's occupied points that must have a point of A nearby after alignment
MIN_FITNESS = 0.5
#: most of B's occupied voxels, moved into A, that may land deep in A's free space
MAX_CONFLICT = 0.03


@dataclass(frozen=True)
class Registration:
    """A transform taking points of map B's frame into map A's frame, and how well it fits."""

    matrix: np.ndarray  #: 4x4 homogeneous transform (B's frame -> A's frame)
    fitness: float  #: fraction of B's occupied points with a point of A nearby after alignment
    rmse: float  #: RMS distance of those point pairs, metres
    inliers: int  #: number of those point pairs
    points_a: int  #: occupied points of A used (after thinning)
    points_b: int  #: occupied points of B used
    planar: bool  #: yaw-only mode (roll = pitch = 0)
    conflict: float = 0.0  #: fraction of B's occupied voxels landing deep in A's free space

    @property
    def pose(self) -> dict[str, float]:
        """``x, y, z`` (metres) and ``roll, pitch, yaw`` (radians) of :attr:`matrix`."""
        return matrix_pose(self.matrix)

    def as_dict(self) -> dict:
        """``x, y, z, roll, pitch, yaw, fitness`` (what ``octofuse align --json`` prints), with
        ``rmse``, ``inliers`` and ``planar``."""
        d = self.pose
        d.update(
            fitness=self.fitness,
            rmse=self.rmse,
            inliers=self.inliers,
            planar=self.planar,
            conflict=self.conflict,
        )
        return d


def occupied_centers(m, occupied: float = 0.0) -> np.ndarray:
    """Centres (N, 3) of the occupied finest voxels (log-odds above ``occupied``) of a map; a
    coarse occupied leaf gives every voxel below it."""
    lv = m.leaves()
    sel = lv.values > occupied
    c, s = lv.centers[sel], lv.sizes[sel]
    res = m.resolution
    span = np.rint(s / res).astype(np.int64)
    out = [c[span == 1]]
    for n in np.unique(span[span > 1]):
        g = (np.arange(n) + 0.5) * res
        sub = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
        blk = c[span == n] - n * res / 2
        out.append((blk[:, None, :] + sub[None]).reshape(-1, 3))
    return np.concatenate(out) if out else np.empty((0, 3))


def free_space_conflict(a, b, T: np.ndarray) -> float:
    """Of ``b``'s occupied finest voxels moved by ``T`` into ``a`` that land in space ``a``
    knows, the fraction that land in a free voxel of ``a`` none of whose six face neighbours
    is occupied (0 when none lands in known space)."""
    pts = _moved(occupied_centers(b), T)
    lv, res = a.leaves(), a.resolution
    here = lv.values_at(pts, res)
    known = ~np.isnan(here)
    deep = known & (here <= 0)
    for step in np.vstack([np.eye(3), -np.eye(3)]) * res:
        deep &= ~(lv.values_at(pts + step, res) > 0)
    return float(deep.sum() / known.sum()) if known.any() else 0.0


def register(
    a,
    b,
    planar: bool = False,
    voxel: float | None = None,
    min_fitness: float = MIN_FITNESS,
    seed: int = 0,
    max_conflict: float = MAX_CONFLICT,
) -> Registration:
    """The transform that takes a point of ``b``'s frame into ``a``'s frame (see the module
    documentation); ``ValueError`` if the maps overlap too little to trust it."""
    res = max(a.resolution, b.resolution)
    v = 2.0 * res if voxel is None else float(voxel)
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"voxel must be a positive number of metres, got {voxel!r}")
    for name, value in (("min_fitness", min_fitness), ("max_conflict", max_conflict)):
        if not (0.0 <= value <= 1.0):
            raise ValueError(f"{name} must lie in [0, 1], got {value!r}")
    from scipy.spatial import cKDTree

    ca, cb = occupied_centers(a), occupied_centers(b)
    pa, pb = _cloud(ca, v), _cloud(cb, v)
    na, nb = len(pa.points), len(pb.points)
    if min(na, nb) < MIN_POINTS:
        which = "A" if na < nb else "B"
        raise ValueError(
            f"cannot register: map {which} has {min(na, nb)} occupied points after "
            f"thinning to {v:g} m (at least {MIN_POINTS} needed); the maps overlap "
            "too little to trust a transform"
        )
    _normals(pa, v)
    _normals(pb, v)
    # features on clouds of at most about FEATURE_POINTS points (surfaces: count ~ 1 / voxel^2)
    vc = v * max(1.0, math.sqrt(max(na, nb) / FEATURE_POINTS))
    ga, gb = (pa, pb) if vc == v else (_cloud(ca, vc), _cloud(cb, vc))
    fa, fb = _features(ga, vc), _features(gb, vc)
    dist = max(2.0 * vc, 3.0 * res)
    src, dst = np.asarray(pb.points), np.asarray(pa.points)
    pairs = _mutual_matches(fb, fa)  # B's and A's feature points matched, for both searches
    ps, pt = np.asarray(gb.points)[pairs[:, 0]], np.asarray(ga.points)[pairs[:, 1]]
    coarse = _rigid_ransac(ps, pt, 1.5 * vc, seed)
    tree = cKDTree(dst)
    fit = max(v, 1.5 * res)  # aligned voxel centres of the same surface lie this close
    if planar:
        # the 6-DoF estimate projected to a yaw, and a yaw-only search; the better one wins
        R = coarse[:3, :3]
        starts = [pose_matrix(*coarse[:3, 3], yaw=math.atan2(R[1, 0], R[0, 0]))]
        try:
            starts.append(_planar_ransac(ps, pt, dist, seed))
        except ValueError:
            pass
        T = max(
            (_planar_icp(src, tree, S, dist, res) for S in starts),
            key=lambda X: _evaluate(src, tree, X, fit)[0],
        )
    else:
        T = _plane_icp(src, tree, np.asarray(pa.normals), coarse, dist, res)
    T = _orthonormal(T)
    fitness, rmse, pairs = _evaluate(src, tree, T, fit)
    inliers = len(pairs)
    out = Registration(T, fitness, rmse, inliers, na, nb, planar)
    if inliers < MIN_INLIERS or out.fitness < min_fitness:
        raise ValueError(
            f"cannot register: the best transform matches {out.fitness:.0%} of B's "
            f"occupied points ({inliers} points within {fit:g} m; at least "
            f"{min_fitness:.0%} and {MIN_INLIERS} needed): the maps overlap too "
            "little to trust it"
        )
    # the matched surfaces must face enough directions to fix the translation
    n = np.asarray(pa.normals)[pairs[:, 1]]
    n = n[:, :2] if planar else n
    ev_ = np.linalg.eigvalsh(n.T @ n / len(n))
    if ev_[0] < MIN_SPREAD * ev_[-1]:
        axis = "horizontal direction" if planar else "direction"
        raise ValueError(
            f"cannot register: the overlapping surfaces leave a {axis} unconstrained "
            f"(normal spread {ev_[0] / ev_[-1]:.3f}, at least {MIN_SPREAD} needed; "
            "a single wall or floor?): the overlap is too small to trust a transform"
        )
    conflict = free_space_conflict(a, b, T)
    if conflict > max_conflict:
        raise ValueError(
            f"cannot register: the best transform ({out.fitness:.0%} of B's occupied "
            f"points matched) puts {conflict:.1%} of B's occupied voxels in space A "
            f"saw free (at most {max_conflict:.1%}): it matches a similar place, not "
            "the same one"
        )
    return dataclasses.replace(out, conflict=conflict)


# -- internals ------------------------------------------------------------------------------------


def _cloud(points: np.ndarray, voxel: float):
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))
    return pc.voxel_down_sample(voxel) if len(points) else pc


def _normals(pc, voxel: float) -> None:
    import open3d as o3d

    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2.5 * voxel, max_nn=30))


def _features(pc, voxel: float):
    import open3d as o3d

    if not pc.has_normals():
        _normals(pc, voxel)
    return o3d.pipelines.registration.compute_fpfh_feature(
        pc, o3d.geometry.KDTreeSearchParamHybrid(radius=5.0 * voxel, max_nn=100)
    )


def _orthonormal(T: np.ndarray) -> np.ndarray:
    """T with its rotation part projected onto SO(3) (removes float drift)."""
    T = np.array(T, dtype=np.float64)
    U, _, Vt = np.linalg.svd(T[:3, :3])
    R = U @ Vt
    if np.linalg.det(R) < 0:
        U[:, -1] *= -1
        R = U @ Vt
    T[:3, :3] = R
    T[3] = (0, 0, 0, 1)
    return T


def _mutual_matches(fs, ft) -> np.ndarray:
    """Pairs (i, j) of source and target points whose FPFH features are mutual nearest
    neighbours."""
    from scipy.spatial import cKDTree

    xs, xt = np.asarray(fs.data).T, np.asarray(ft.data).T
    _, st = cKDTree(xt).query(xs)
    _, ts = cKDTree(xs).query(xt)
    i = np.arange(len(xs))
    keep = ts[st] == i
    return np.stack([i[keep], st[keep]], axis=1)


def _fit_planar(src: np.ndarray, dst: np.ndarray, w=None) -> np.ndarray:
    """Least-squares yaw about z and translation (x, y, z) taking src onto dst."""
    w = np.ones(len(src)) if w is None else w
    cs, cd = np.average(src, axis=0, weights=w), np.average(dst, axis=0, weights=w)
    s, d = src[:, :2] - cs[:2], dst[:, :2] - cd[:2]
    yaw = math.atan2(
        np.sum(w * (s[:, 0] * d[:, 1] - s[:, 1] * d[:, 0])),
        np.sum(w * (s[:, 0] * d[:, 0] + s[:, 1] * d[:, 1])),
    )
    T = pose_matrix(yaw=yaw)
    T[:3, 3] = cd - T[:3, :3] @ cs
    return T


def _kabsch(ps: np.ndarray, pt: np.ndarray) -> np.ndarray:
    """Rigid transforms (k, 4, 4) taking the point sets ``ps`` (k, n, 3) onto ``pt``, least
    squares."""
    cs, ct = ps.mean(axis=1), pt.mean(axis=1)
    H = np.einsum("kni,knj->kij", ps - cs[:, None], pt - ct[:, None])
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.einsum("kij,kjl->kil", U, Vt)))
    D = np.tile(np.eye(3), (len(ps), 1, 1))
    D[:, 2, 2] = d
    R = np.einsum("kji,kjl,kml->kim", Vt, D, U)  # V D U^T
    T = np.tile(np.eye(4), (len(ps), 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = ct - np.einsum("kij,kj->ki", R, cs)
    return T


def _rigid_ransac(ps, pt, dist, seed, tries: int = RANSAC_TRIES) -> np.ndarray:
    """A coarse rigid transform taking the matched points ``ps`` onto ``pt``: 3-point RANSAC
    over the matches, the samples drawn from ``seed`` and every step on one thread, so that
    the same maps always give the same transform. A sample is kept if its edges have about
    the same lengths in both clouds (within 10%) and its own points land within ``dist``; the
    transform that carries the most matches within ``dist`` wins (the first drawn, on a tie).
    The search stops once, at the best inlier ratio so far, a sample of inliers only would
    have been drawn with 99.9% confidence. The identity if no sample passes."""
    if len(ps) < 3:
        return np.eye(4)
    idx = np.random.default_rng(seed).integers(0, len(ps), size=(tries, 3))
    drawn = np.arange(tries)  # when each sample was drawn
    a, b = ps[idx], pt[idx]  # (tries, 3, 3)
    edges = [(0, 1), (1, 2), (2, 0)]
    la = np.stack([np.linalg.norm(a[:, i] - a[:, j], axis=1) for i, j in edges], axis=1)
    lb = np.stack([np.linalg.norm(b[:, i] - b[:, j], axis=1) for i, j in edges], axis=1)
    ok = np.all((la >= 0.9 * lb) & (lb >= 0.9 * la) & (la > 0), axis=1)
    drawn, a, b = drawn[ok], a[ok], b[ok]
    if not len(drawn):
        return np.eye(4)
    T = _kabsch(a, b)
    ok = np.all(np.linalg.norm(_moved_by_each(T, a) - b, axis=2) < dist, axis=1)
    drawn, T = drawn[ok], T[ok]
    best, best_n = None, 0
    for k0 in range(0, len(T), 256):  # matches within dist, a chunk of transforms at a time
        Tc = T[k0 : k0 + 256]
        err = np.linalg.norm(_moved_by_each(Tc, ps) - pt, axis=2)
        n = np.sum(err < dist, axis=1)
        k = int(np.argmax(n))
        if n[k] > best_n:
            best, best_n = Tc[k], int(n[k])
        w = best_n / len(ps)
        needed = math.log(1e-3) / math.log1p(-(w**3)) if 0 < w < 1 else 0.0
        if drawn[min(k0 + 256, len(T)) - 1] + 1 >= needed:
            break
    return np.eye(4) if best is None else best


def _planar_ransac(ps, pt, dist, seed) -> np.ndarray:
    """Yaw + translation taking the matched points ``ps`` onto ``pt``: 2-point RANSAC in the
    plane."""
    if len(ps) < 3:
        raise ValueError(
            "cannot register: the maps share no distinctive structure (fewer than "
            "3 feature matches); the maps overlap too little to trust a transform"
        )
    rng = np.random.default_rng(seed)
    best, best_n = np.eye(4), -1
    for _ in range(5000):
        i, j = rng.choice(len(ps), 2, replace=False)
        ds, dt = ps[j, :2] - ps[i, :2], pt[j, :2] - pt[i, :2]
        ls, lt = np.hypot(*ds), np.hypot(*dt)
        if ls < 2 * dist or abs(ls - lt) > dist:
            continue
        T = _fit_planar(ps[[i, j]], pt[[i, j]])
        err = np.linalg.norm(_moved(ps, T) - pt, axis=1)
        n = int(np.sum(err < dist))
        if n > best_n:
            best, best_n = T, n
    inl = np.linalg.norm(_moved(ps, best) - pt, axis=1) < dist
    return _fit_planar(ps[inl], pt[inl]) if inl.sum() >= 3 else best


def _moved(points: np.ndarray, T: np.ndarray) -> np.ndarray:
    """``points`` (n, 3) moved by the transform ``T``."""
    return points @ T[:3, :3].T + T[:3, 3]


def _moved_by_each(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points moved by each of the transforms ``T`` (k, 4, 4): the same points (n, 3) by
    every one, or each transform's own (k, n, 3); (k, n, 3)."""
    return points @ T[:, :3, :3].transpose(0, 2, 1) + T[:, None, :3, 3]


def _nearest(src, tree, T, d):
    """B's points ``src`` moved by ``T``, the distance to and index of each one's nearest
    point of A (``tree``) within ``d``, and which have one."""
    moved = _moved(src, T)
    e, j = tree.query(moved, distance_upper_bound=d)
    return moved, e, j, np.isfinite(e)


def _shrinking(dist: float, res: float) -> tuple[float, float, float]:
    """The match distances of ICP, coarse to fine."""
    return dist, 0.5 * dist + 0.5 * res, res


def _evaluate(src, tree, T, fit) -> tuple[float, float, np.ndarray]:
    """B's points ``src`` moved by ``T`` against A's (``tree``): the fraction with a point of
    A within ``fit`` (fitness), their RMS distance and the pairs (B's index, A's index)."""
    _, e, j, ok = _nearest(src, tree, T, fit)
    rmse = float(np.sqrt(np.mean(e[ok] ** 2))) if ok.any() else 0.0
    return float(ok.sum() / len(src)), rmse, np.stack([np.flatnonzero(ok), j[ok]], axis=1)


def _plane_icp(src, tree, normals, T, dist, res) -> np.ndarray:
    """Point-to-plane ICP (A's normals), linearised about the current transform, with a
    shrinking match distance; up to 60 steps per distance, until the fitness and RMS change by
    less than 1e-6."""
    dst = tree.data
    for d in _shrinking(dist, res):
        last = None
        for _ in range(60):
            moved, e, j, ok = _nearest(src, tree, T, d)
            if ok.sum() < 6:
                break
            p, q, n = moved[ok], dst[j[ok]], normals[j[ok]]
            J = np.hstack([np.cross(p, n), n])
            x = np.linalg.lstsq(J.T @ J, -J.T @ np.einsum("ij,ij->i", p - q, n), rcond=None)[0]
            T = pose_matrix(*x[3:], *x[:3]) @ T  # the small step: rotations x[:3], shift x[3:]
            now = (ok.mean(), float(np.sqrt(np.mean(e[ok] ** 2))))
            if last is not None and abs(now[0] - last[0]) < 1e-6 and abs(now[1] - last[1]) < 1e-6:
                break
            last = now
    return T


def _planar_icp(src, tree, T, dist, res) -> np.ndarray:
    """Point-to-point ICP restricted to yaw + translation, with a shrinking match distance."""
    dst = tree.data
    for d in _shrinking(dist, res):
        for _ in range(40):
            moved, _, j, ok = _nearest(src, tree, T, d)
            if ok.sum() < 3:
                break
            step = _fit_planar(moved[ok], dst[j[ok]])
            T = step @ T
            if np.abs(step[:3, 3]).max() < 1e-5 and abs(step[1, 0]) < 1e-6:
                break
    return T
