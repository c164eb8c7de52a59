"""Shared fixtures: small real OctoMap trees built by ray casting."""

from pathlib import Path

import numpy as np
import pytest

import octofuse

REPO = Path(__file__).resolve().parents[2]
SHARED_REAL = REPO.parent / "shared" / "data" / "real"


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


@pytest.fixture
def shared_real():
    if not SHARED_REAL.is_dir():
        pytest.skip(f"real recorded data not present at {SHARED_REAL}")
    return SHARED_REAL
