"""The fast insert mode (``insert_scan(..., mode="fast")``) against the exact mode (OctoMap's
insertPointCloud, voxel for voxel).

Its defining properties: OctoMap's update rules (one hit per end point voxel, duplicates
merged; end points win over free; clamping); where no cell is crossed by enough rays (a single
ray, a few rays) it is the exact map; a scan into a map changes the occupied voxels as the
exact mode does and frees a superset of the exact mode's free voxels. Its stated bound, on the
real Luminar clouds and on the generated warehouse (0.1 m, 40 m): at least 95% of the exact
map's occupied voxels stay occupied and at most 5% more appear.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bagfactory import assert_same_map
from octofuse.config import BuildConfig
from octofuse.maps.occupancy import OccupancyMap
from octofuse.maps.tree_fusion import fuse_maps
from octofuse.scans.bags import BagSet
from octofuse.scans.decode import pointcloud2_to_xyz
from test_fast_paths import random_scans, warehouse_scans  # noqa: E402

#: the bound the fast mode is held to against the exact mode
MIN_KEPT, MAX_EXTRA = 0.95, 0.05


def agreement(m: OccupancyMap, exact: OccupancyMap) -> tuple[float, float, np.ndarray]:
    """Occupied voxels of `exact` kept by `m`, and extra ones (fractions), and the confusion
    (rows: exact's class, columns: m's; occupied, free, unknown)."""
    q = np.array(m.class_counts(exact, 0.0)["confusion"])
    occ = q[0].sum()
    return q[0, 0] / occ, (q[1, 0] + q[2, 0]) / occ, q


def both_modes(scans, max_range=-1.0, **fast):
    exact, fast_map = OccupancyMap(0.1), OccupancyMap(0.1)
    for pts, origin in scans:
        exact.insert_scan(pts, origin, max_range)
        fast_map.insert_scan(pts, origin, max_range, mode="fast", **fast)
    return exact, fast_map


@pytest.mark.parametrize("max_range", [-1.0, 2.0])
def test_single_rays_give_the_exact_map(max_range):
    rng = np.random.default_rng(4)
    scans = [
        (origin + rng.normal(size=(1, 3)) * 3.0, origin) for origin in rng.uniform(-1, 1, (40, 3))
    ]
    exact, fast = both_modes(scans, max_range)
    assert_same_map(fast, exact)


def test_scans_of_few_rays_give_the_exact_map():
    # 7 rays: no cell is crossed by the 8 that clearing it whole takes
    exact, fast = both_modes(random_scans(2, 20, points=7, ranges=[2.0, 4.0, 6.0]))
    assert_same_map(fast, exact)


def test_one_scan_same_occupied_and_more_free():
    pts, origin = warehouse_scans(1, az_step=0.4)[0]
    exact, fast = both_modes([(pts, origin)], 40.0)
    kept, extra, q = agreement(fast, exact)
    assert kept == 1.0 and extra == 0.0
    assert q[1, 1] == q[1].sum()  # every free voxel of the exact map is free
    assert q[2, 1] > 0.2 * q[1, 1]  # and the cells between the rays too
    assert fast.num_leaves < exact.num_leaves


def test_end_points_occupied_once_and_duplicates_merged():
    pts, origin = warehouse_scans(1, az_step=0.4)[0]
    once = OccupancyMap(0.1)
    once.insert_scan(pts, origin, mode="fast")
    rng = np.random.default_rng(1)
    doubled = np.concatenate([pts, pts, pts[rng.integers(0, len(pts), 5000)]])
    twice = OccupancyMap(0.1)
    twice.insert_scan(doubled[rng.permutation(len(doubled))], origin, mode="fast")
    assert_same_map(twice, once)
    occ = once.leaves("occupied")
    hit = np.log(0.7 / 0.3)
    np.testing.assert_allclose(occ.values, hit, rtol=1e-6)  # one hit each, in a fresh map
    exact = OccupancyMap(0.1)
    exact.insert_scan(pts, origin)
    np.testing.assert_array_equal(
        np.unique(occ.centers, axis=0), np.unique(exact.leaves("occupied").centers, axis=0)
    )


def test_values_stay_clamped_and_free_space_saturates():
    pts, origin = warehouse_scans(1, az_step=0.4)[0]
    m = OccupancyMap(0.1)
    for _ in range(12):
        m.insert_scan(pts, origin, mode="fast")
    lo, hi = m.clamping_logodds
    v = m.leaves().values
    assert v.min() >= lo and v.max() <= hi
    assert (v == lo).sum() > 0.9 * (v <= 0).sum() and (v == hi).sum() > 0.9 * (v > 0).sum()


def test_threads_give_the_same_map_and_batches_agree_with_scan_by_scan():
    scans = warehouse_scans(4, az_step=0.4)
    maps = {}
    for threads in (1, 2):
        batch = OccupancyMap(0.1)
        batch.insert_scans(scans, 40.0, threads=threads, mode="fast")
        each = OccupancyMap(0.1)
        for pts, origin in scans:
            each.insert_scan(pts, origin, 40.0, mode="fast", threads=threads)
        maps[threads] = batch, each
    assert_same_map(maps[1][0], maps[2][0])
    assert_same_map(maps[1][1], maps[2][1])
    # a batch's scans are traced before any is applied: a cell where an earlier scan of the
    # batch left an occupied voxel is traced again when applied, its voxel walk restarted at
    # its border, which may move a voxel there
    batch, each = maps[1]
    q = np.array(batch.class_counts(each, 0.0)["confusion"])
    assert np.trace(q) >= 0.9999 * q.sum()


def test_threads_give_the_same_map_in_a_fused_map():
    # a large fused map keeps its nodes in an arena of its own, which the threads' walks
    # prune and expand the arena's way
    scans = warehouse_scans(8, az_step=0.4)
    base = OccupancyMap(0.1)
    for pts, origin in scans[:6]:
        base.insert_scan(pts, origin, 40.0, mode="fast")
    assert 2 * base.num_nodes >= 2**18  # fuse_maps gives such results an arena
    maps = []
    for threads in (1, 2):
        fused = fuse_maps(base, base).map
        for pts, origin in scans[6:]:
            fused.insert_scan(pts, origin, 40.0, mode="fast", threads=threads)
        maps.append(fused)
    assert_same_map(maps[0], maps[1])


def test_bound_on_warehouse_scans():
    exact, fast = both_modes(warehouse_scans(8, az_step=0.4), 40.0)
    kept, extra, _ = agreement(fast, exact)
    assert kept >= MIN_KEPT and extra <= MAX_EXTRA, (kept, extra)


def test_bound_on_real_luminar_clouds(shared_real: Path):
    bag = shared_real / "luminar_pointcloud2.bag"
    if not bag.is_file():
        pytest.skip(f"{bag.name} not present in {shared_real}")
    with BagSet(bag) as b:
        clouds = [pointcloud2_to_xyz(m.msg) for m in b.messages("/luminar_pointcloud")]
    scans = [(np.ascontiguousarray(c[np.isfinite(c).all(axis=1)]), np.zeros(3)) for c in clouds]
    assert len(scans) == 5 and min(len(p) for p, _ in scans) > 30_000
    exact, fast = both_modes(scans, 40.0)
    kept, extra, q = agreement(fast, exact)
    assert kept >= MIN_KEPT and extra <= MAX_EXTRA, (kept, extra)
    assert fast.memory_bytes < exact.memory_bytes
    # a real cloud's update is applied on both threads (its subtrees split between them):
    # the same map, node for node
    two = OccupancyMap(0.1)
    for pts, origin in scans:
        two.insert_scan(pts, origin, 40.0, mode="fast", threads=2)
    assert_same_map(two, fast)


def test_mode_is_checked():
    m = OccupancyMap(0.1)
    with pytest.raises(ValueError, match="insert mode"):
        m.insert_scan(np.ones((3, 3)), np.zeros(3), mode="quick")
    with pytest.raises(ValueError, match="insert_mode"):
        BuildConfig(insert_mode="quick")
