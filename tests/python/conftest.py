"""Shared fixtures: small real OctoMap trees built by ray casting."""

import struct
from pathlib import Path

import numpy as np
import pytest

import octofuse

REPO = Path(__file__).resolve().parents[2]
# the shared data beside the repository (or beside a directory above it, for a checkout
# placed deeper)
SHARED_REAL = next(
    (p / "shared" / "data" / "real" for p in REPO.parents if (p / "shared" / "data").is_dir()),
    REPO.parent / "shared" / "data" / "real",
)


def scan_ring(rng, center, n_points=400, radius=1.0, z=(-0.3, 0.3)):
    """Points on a noisy sphere-ish shell around ``center`` (a room-like blob)."""
    d = rng.normal(size=(n_points, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pts = center + d * radius * rng.uniform(0.8, 1.0, size=(n_points, 1))
    pts[:, 2] = np.clip(pts[:, 2], center[2] + z[0], center[2] + z[1])
    return pts


def random_map(seed, n_scans, resolution=0.1, offset=(0.0, 0.0, 0.0)):
    """An OctoMap tree from a few random scans; many scans saturate and prune free space."""
    rng = np.random.default_rng(seed)
    m = octofuse.OccupancyMap(resolution)
    c = np.asarray(offset, dtype=float)
    for _ in range(n_scans):
        origin = c + rng.uniform(-0.2, 0.2, 3)
        m.insert_scan(scan_ring(rng, c), origin)
    return m


def finest_voxels(leaves, resolution):
    """Every finest voxel of a tree as integer keys (N, 3) and its leaf's value (N,); a coarse
    leaf gives all the voxels below it."""
    lo = np.rint((leaves.centers - leaves.sizes[:, None] / 2) / resolution).astype(np.int64)
    span = np.rint(leaves.sizes / resolution).astype(np.int64)
    keys, values = [np.empty((0, 3), np.int64)], [leaves.values[:0]]
    for s in np.unique(span):
        sel = span == s
        g = np.stack(np.meshgrid(*(np.arange(s),) * 3, indexing="ij"), -1).reshape(-1, 3)
        keys.append((lo[sel][:, None, :] + g[None]).reshape(-1, 3))
        values.append(np.repeat(leaves.values[sel], len(g)))
    return np.concatenate(keys), np.concatenate(values)


def expand(leaves, resolution):
    """Every finest voxel (integer key tuple) of a tree with its value, as a dict."""
    keys, values = finest_voxels(leaves, resolution)
    return dict(zip(map(tuple, keys.tolist()), values))


def voxels(m) -> dict:
    """{integer key: log-odds} of every finest voxel of a map."""
    k, v = finest_voxels(m.leaves(), m.resolution)
    return dict(zip(map(tuple, k.tolist()), v.tolist()))


def map_with_values(src: Path, dst: Path, values) -> Path:
    """``src`` (a .ot) with its first nodes' log-odds set to ``values`` (depth-first order)."""
    raw = bytearray(src.read_bytes())
    start = raw.index(b"data\n") + 5
    n = (len(raw) - start) // 5
    for k, v in enumerate(values):
        i = start + 5 * (k % n)
        raw[i : i + 4] = struct.pack("<f", v)
    dst.write_bytes(bytes(raw))
    return dst


@pytest.fixture
def shared_real():
    if not SHARED_REAL.is_dir():
        pytest.skip(f"real recorded data not present at {SHARED_REAL}")
    return SHARED_REAL
