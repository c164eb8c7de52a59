"""The fast paths against the plain OctoMap operations they replace, bit for bit.

* ``OccupancyMap.insert_scan`` / ``insert_scans`` (depth-first batch update) against OctoMap's
  ``insertPointCloud`` scan by scan (the core's plain insertion);
* ``clamped_copy`` against a copy clamped and pruned.

``fuse_into`` on several threads against one thread, and losses carried in the map's nodes
against loss maps of their own, are checked node for node in tests/cpp
(test_parallel_fusion.cpp, test_carried_loss.cpp).

On random scans and maps and on scans of the generated warehouse (16-beam 3D lidar).
"""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bagfactory import assert_same_map
from conftest import REPO, random_map
from octofuse import _core
from octofuse.maps.occupancy import OccupancyMap
from octofuse.maps.tree_fusion import fuse_into


def plain_insert(m: OccupancyMap, points, origin, max_range=-1.0) -> None:
    """OctoMap's insertPointCloud through the core's plain path."""
    pts = np.ascontiguousarray(points)
    m._m.insert_scan(pts, np.asarray(origin, dtype=np.float64).reshape(-1), float(max_range), False)


def random_scans(
    seed: int, n_scans: int, dtype=np.float64, spread: float = 1.0, points: int = 300, ranges=None
):
    """Scans from origins within ``spread`` of the map origin, their points at random
    directions and at distances from ``ranges`` (default: uniform in 0.2-3 m)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n_scans):
        origin = rng.uniform(-spread, spread, 3)
        d = rng.normal(size=(points, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        r = (
            rng.uniform(0.2, 3.0, (points, 1))
            if ranges is None
            else rng.choice(ranges, (points, 1))
        )
        out.append(((origin + d * r).astype(dtype), origin))
    return out


def warehouse_scans(n_scans: int = 6, az_step: float = 2.0):
    """Map-frame scans of the generated warehouse (the generator's own ray casting)."""
    spec = importlib.util.spec_from_file_location(
        "generate_warehouse", REPO / "data" / "generate_warehouse.py"
    )
    gw = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gw)
    rng = np.random.default_rng(3)
    scene = gw.Scene(gw.build_scene(rng))
    n_az = int(round(360.0 / az_step))
    az = np.deg2rad(np.arange(n_az) * az_step)
    el = np.deg2rad(np.linspace(-15, 15, 16))
    d = np.stack(
        [
            np.outer(np.cos(el), np.cos(az)),
            np.outer(np.cos(el), np.sin(az)),
            np.outer(np.sin(el), np.ones_like(az)),
        ],
        axis=-1,
    ).reshape(-1, 3)
    out = []
    for k in range(n_scans):
        origin = np.array([3.0 + 1.3 * k, 6.0, 0.6])
        r = scene.raycast(origin, d)
        keep = np.isfinite(r) & (r < 12.0)
        out.append((origin + d[keep] * r[keep, None], origin))
    return out


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("max_range", [-1.0, 1.5])
def test_insert_scan_equals_insert_point_cloud(dtype, max_range):
    fast, plain = OccupancyMap(0.1), OccupancyMap(0.1)
    for pts, origin in random_scans(11, 12, dtype):
        fast.insert_scan(pts, origin, max_range)
        plain_insert(plain, pts, origin, max_range)
    assert_same_map(fast, plain)


def test_insert_scan_equals_insert_point_cloud_on_warehouse_scans():
    fast, together, plain = OccupancyMap(0.05), OccupancyMap(0.05), OccupancyMap(0.05)
    scans = warehouse_scans()
    together.insert_scans(scans, threads=2)  # the scans walked together
    for pts, origin in scans:
        fast.insert_scan(pts, origin)
        plain_insert(plain, pts, origin)
    assert_same_map(fast, plain)
    assert_same_map(together, plain)
    assert fast.num_leaves > 10_000


def test_insert_scans_equals_scan_by_scan():
    scans = random_scans(5, 10)
    rng = np.random.default_rng(9)
    mixed = []
    for k, (pts, origin) in enumerate(scans):
        if k % 2:  # sensor frame with a pose
            a = rng.uniform(-np.pi, np.pi)
            T = np.eye(4)
            T[:3, :3] = [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]
            T[:3, 3] = origin
            mixed.append(((pts - origin) @ T[:3, :3], T))
        else:
            mixed.append((pts, origin))
    for threads in (1, 2):
        batch, plain = OccupancyMap(0.1), OccupancyMap(0.1)
        batch.insert_scans(mixed, max_range=2.0, threads=threads)
        for pts, where in mixed:
            if np.shape(where) == (4, 4):
                plain._m.insert_scan(
                    np.ascontiguousarray(pts), np.ascontiguousarray(where), 2.0, True
                )
            else:
                plain_insert(plain, pts, where, 2.0)
        assert_same_map(batch, plain)


def test_scans_walked_together_equal_scan_by_scan_at_the_clamping_thresholds():
    """insert_scans walks several scans at once (a voxel's updates in scan order): equal, bit
    for bit, to insertPointCloud scan by scan where voxels reach the clamping thresholds, are
    pruned, and are expanded again by a later scan (walls that appear and vanish)."""
    rng = np.random.default_rng(21)
    scans = []
    for k in range(30):
        origin = np.array([0.05, 0.05, 0.05]) + rng.normal(scale=0.02, size=3)
        a = rng.uniform(-np.pi, np.pi, 400)
        e = rng.uniform(-0.3, 0.3, 400)
        d = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=1)
        r = np.where(k % 3 == 2, 0.8, 1.6)  # a wall at 1.6 m, every third scan one at 0.8 m
        scans.append((origin + d * r, origin))
    for clamping in ((0.1192, 0.971), (0.3, 0.7)):
        batch, plain = OccupancyMap(0.1, clamping=clamping), OccupancyMap(0.1, clamping=clamping)
        batch.insert_scans(scans, threads=1)
        for pts, origin in scans:
            plain_insert(plain, pts, origin)
        assert_same_map(batch, plain)
        lv = plain.leaves()
        cmin, cmax = (float(np.float32(np.log(p / (1 - p)))) for p in clamping)
        assert np.any(lv.values == np.float32(cmin)) and np.any(lv.values == np.float32(cmax))
        assert np.any(lv.depths < 16)  # pruned leaves


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n_scans=st.integers(2, 12),
    clamping=st.sampled_from([(0.1192, 0.971), (0.3, 0.7), (0.45, 0.55)]),
    hit=st.floats(0.55, 0.95),
    miss=st.floats(0.1, 0.45),
)
def test_scans_walked_together_equal_scan_by_scan_for_any_sensor_model(
    seed, n_scans, clamping, hit, miss
):
    """Random scans from nearby origins into maps of any sensor model and clamping: the scans
    walked together (insert_scans) give insertPointCloud's tree scan by scan, bit for bit."""
    scans = random_scans(seed, n_scans, spread=0.2, points=60, ranges=[0.5, 0.9, 1.3])
    made = [OccupancyMap(0.1, prob_hit=hit, prob_miss=miss, clamping=clamping) for _ in range(2)]
    made[0].insert_scans(scans, threads=1)
    for pts, origin in scans:
        plain_insert(made[1], pts, origin)
    assert_same_map(*made)


def test_one_batch_feeds_maps_of_every_clamping_and_sensor_model():
    """The rays of a scan are cast once for all its targets, whatever their clamping or
    sensor model (those act per map): each map ends as if filled on its own."""
    from octofuse.maps.ray_batches import insert_batch

    scans = random_scans(6, 12)
    kinds = [
        lambda: OccupancyMap(0.1),
        lambda: OccupancyMap(0.1).open_clamping(),
        lambda: OccupancyMap(0.1, prob_hit=0.9, prob_miss=0.3, clamping=(0.05, 0.99)),
    ]
    poses = np.stack([np.eye(4)] * len(scans))
    poses[:, :3, 3] = [origin for _, origin in scans]
    points = [np.ascontiguousarray(pts - origin) for pts, origin in scans]
    together = [k() for k in kinds]
    insert_batch(points, poses, np.full(len(scans), -1.0), [together] * len(scans), 2)
    for k, got in zip(kinds, together):
        alone = k()
        insert_batch(points, poses, np.full(len(scans), -1.0), [[alone]] * len(scans), 2)
        assert got.to_bytes() == alone.to_bytes()
    assert together[0].to_bytes() != together[1].to_bytes() != together[2].to_bytes()
    with pytest.raises(ValueError, match="different resolutions"):
        insert_batch(
            points[:1], poses[:1], np.full(1, -1.0), [[OccupancyMap(0.1), OccupancyMap(0.2)]], 1
        )


def test_rays_traced_once_feed_maps_apart_as_one_batch():
    """Rays traced once and applied to groups of maps in separate calls (as a run's lanes
    do) leave every map as one batch into all of them; a wrong call changes no map."""
    from octofuse.maps.ray_batches import apply_rays, insert_batch, trace_rays

    scans = random_scans(7, 10)
    poses = np.stack([np.eye(4)] * len(scans))
    poses[:, :3, 3] = [origin for _, origin in scans]
    points = [np.ascontiguousarray(pts - origin) for pts, origin in scans]
    ranges = np.full(len(scans), 2.5)
    # scan k goes into map k % 3 and into the last map
    together = [OccupancyMap(0.1) for _ in range(4)]
    insert_batch(
        points, poses, ranges, [[together[k % 3], together[3]] for k in range(len(scans))], 2
    )
    apart = [OccupancyMap(0.1) for _ in range(4)]
    rays = trace_rays(apart[0], points, poses, ranges, 2)
    assert rays.scans == len(scans) and rays.nbytes > 0
    for group in ([0, 1], [2, 3]):
        apply_rays(
            rays, [[apart[i] for i in group if i in (k % 3, 3)] for k in range(len(scans))], 1
        )
    for got, want in zip(apart, together):
        assert got.to_bytes() == want.to_bytes()
    before = apart[0].to_bytes()
    with pytest.raises(ValueError, match="3 target lists for 10 scans"):
        apply_rays(rays, [[apart[0]]] * 3, 1)
    with pytest.raises(ValueError, match="for rays traced at 0.1"):
        apply_rays(rays, [[OccupancyMap(0.2)]] + [[]] * 9, 1)
    with pytest.raises(ValueError, match="threads = 0"):
        apply_rays(rays, [[apart[0]]] * 10, 0)
    assert apart[0].to_bytes() == before
    with pytest.raises(ValueError, match="scan 1.*non-finite"):
        bad = [points[0], np.array([[np.nan, 0.0, 0.0]])]
        trace_rays(apart[0], bad, poses[:2], ranges[:2], 1)


def test_insert_errors_name_the_row_and_leave_the_map():
    m = OccupancyMap(0.1)
    with pytest.raises(ValueError, match="non-finite coordinate at row 1"):
        m.insert_scan(np.array([[1.0, 0, 0], [np.nan, 0, 0]]), (0, 0, 0))
    with pytest.raises(ValueError, match="scan 1"):
        m.insert_scans([(np.ones((2, 3)), (0, 0, 0)), (np.array([[np.inf, 0, 0]]), (0, 0, 0))])
    with pytest.raises(ValueError, match="origin"):
        m.insert_scans([(np.ones((2, 3)), (0, 0))])
    assert m.num_leaves == 0
    m.insert_scans([])
    assert m.num_leaves == 0
    for bad in (0, -1, 2.5, "2", True):  # as fuse_into's: only whole numbers in range
        with pytest.raises(ValueError, match="threads"):
            m.insert_scans([(np.ones((2, 3)), (0, 0, 0))], threads=bad)
    assert m.num_leaves == 0


def _rule(name):
    from octofuse.rules import parse_rule

    return parse_rule(name)


def _unknown(name):
    from octofuse.rules import parse_unknown

    return parse_unknown(name)


def test_fuse_into_rejects_bad_thread_counts():
    a, b = random_map(1, 8), random_map(2, 8)
    with pytest.raises(ValueError, match="threads"):
        _core._fuse_into(a._m, b._m, _rule("naive-bayes"), _unknown("copy"), None, threads=0)
    for bad in (0, -1, 2.5, "2", True):
        with pytest.raises(ValueError, match="threads"):
            fuse_into(a, b, "naive-bayes", threads=bad)
    assert_same_map(a, random_map(1, 8))  # nothing fused by the refused calls
    fuse_into(a, b, "naive-bayes")  # the public call is unchanged


# -- clamped copies ------------------------------------------------------------------------


def _holding(data: bytes) -> OccupancyMap:
    """A map of 0.1 m voxels at the default clamping holding exactly the node data ``data``,
    values past the clamping included (reading node data clamps those, an .ot stream keeps
    what it holds): as a map whose values were fused unclamped."""
    wide = OccupancyMap.from_tree_data(data, 0.1, clamping=(1e-6, 1 - 1e-6)).to_bytes()
    default = wide.replace(
        b"clamping_thres_min 1e-06 clamping_thres_max 0.999999",
        b"clamping_thres_min 0.1192 clamping_thres_max 0.971",
    )
    assert default != wide
    return OccupancyMap.from_bytes(default)


def _plain_clamped(m: OccupancyMap) -> OccupancyMap:
    """OctoMap's way: a copy, its leaves clamped, inner nodes recomputed, prune()."""
    return m.copy().clamp_values()


def assert_same_stream(a: OccupancyMap, b: OccupancyMap) -> None:
    """Node for node: every node's value and child mask (the .ot stream), and the node count."""
    assert a.to_bytes() == b.to_bytes()
    assert a.num_nodes == b.num_nodes
    assert a.clamping_logodds == b.clamping_logodds


def test_clamped_copy_equals_copy_and_clamp_on_open_maps():
    maps = [OccupancyMap(0.1).open_clamping(), OccupancyMap(0.05).open_clamping()]
    for pts_origin in random_scans(7, 12) + warehouse_scans(3):
        pts, origin = pts_origin
        for m in maps:  # every scan 3 times: values well past the thresholds
            for _ in range(3):
                m.insert_scan(pts, origin)
    empty = OccupancyMap(0.1)
    for m in [*maps, maps[0].copy().negate_values(), empty]:
        want = _plain_clamped(m)
        assert_same_stream(m.clamped_copy(), want)
        assert m.clamped_copy().clamping_logodds == OccupancyMap(m.resolution).clamping_logodds
    assert maps[0].clamped_copy().num_nodes < maps[0].num_nodes  # clamping made leaves equal


LO, HI = OccupancyMap(0.1).clamping_logodds  # the default thresholds, about -2 and 3.5
VALUES = [-9.0, LO - 0.5, LO, -1.0, 0.0, 0.4, HI, HI + 0.5, 7.0, 12.0]


def _stream(value: float, children) -> bytes:
    """OctoMap's node data of one node and its subtree: value, child mask, children."""
    mask = sum(1 << i for i, c in enumerate(children) if c is not None)
    return (
        np.float32(value).tobytes() + bytes([mask]) + b"".join(c for c in children if c is not None)
    )


def _chain(depth: int, below: bytes) -> bytes:
    """The node data of a tree whose root leads down child 0 to ``below`` at ``depth``."""
    for _ in range(depth):
        below = _stream(0.0, [below] + [None] * 7)
    return below


def test_clamped_copy_keeps_prune_stopping_at_a_level_that_prunes_nothing():
    # 8 coarse leaves at depth 15, all past the upper threshold: clamped, they are equal, but
    # OctoMap's prune() starts at the finest level, prunes nothing there and stops
    leaves = [_stream(v, [None] * 8) for v in (4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0)]
    m = _holding(_chain(14, _stream(0.0, leaves)))
    want = _plain_clamped(m)
    assert want.num_nodes == m.num_nodes  # not collapsed
    assert_same_stream(m.clamped_copy(), want)
    # with one finest node that collapses as well, prune() goes on and collapses both levels
    finest = _stream(
        0.0, [_stream(v, [None] * 8) for v in (5.0, 6.0, 7.0, 8.0, 4.0, 4.0, 4.0, 4.0)]
    )
    leaves[1] = finest
    m = _holding(_chain(14, _stream(0.0, leaves)))
    want = _plain_clamped(m)
    assert want.num_nodes == 15  # the chain to depth 14, whose node is now a leaf
    assert_same_stream(m.clamped_copy(), want)


def _subtrees(height: int):
    """Random subtrees at most ``height`` levels deep, often with all 8 children (so that
    clamping makes them collapse), leaves from VALUES."""
    from hypothesis import strategies as st

    leaf = st.sampled_from(VALUES).map(lambda v: _stream(v, [None] * 8))
    if height == 0:
        return leaf
    child = _subtrees(height - 1)
    masks = st.one_of(st.just(0xFF), st.integers(1, 0xFF))
    inner = masks.flatmap(
        lambda mask: st.tuples(*[child if mask >> i & 1 else st.none() for i in range(8)])
    ).map(lambda kids: _stream(0.0, list(kids)))
    return st.one_of(leaf, inner, inner)


def test_clamped_copy_equals_copy_and_clamp_on_random_trees():
    from hypothesis import given, settings
    from hypothesis import strategies as st

    @settings(max_examples=150, deadline=None)
    @given(st.integers(12, 16).flatmap(lambda d: st.tuples(st.just(d), _subtrees(min(16 - d, 3)))))
    def check(case):
        depth, below = case
        m = _holding(_chain(depth, below))
        assert_same_stream(m.clamped_copy(), _plain_clamped(m))

    check()
