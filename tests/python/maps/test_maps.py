"""Occupancy maps: OctoMap insertion, files, and tree fusion equal to the per-voxel rule."""

import shutil
import subprocess
import threading

import numpy as np
import pytest

import octofuse
from conftest import expand, map_with_values, random_map, scan_ring
from octofuse import OccupancyMap, fuse_logodds, fuse_maps


@pytest.fixture(scope="module")
def pair():
    # a: many scans, free space saturates and prunes to coarse leaves; b: fine leaves only
    return random_map(1, 25), random_map(2, 2, offset=(0.35, 0.1, 0.0))


def test_the_pair_covers_a_coarse_leaf_over_fine_leaves(pair):
    a, b = pair
    la, lb = a.leaves(), b.leaves()
    assert la.depths.min() < 16 and lb.depths.max() == 16
    coarse = la.depths < 16
    ka = expand(la._replace(values=la.depths.astype(np.float32)), a.resolution)
    kb = expand(lb._replace(values=lb.depths.astype(np.float32)), b.resolution)
    assert coarse.any()
    assert any(ka[k] < 16 and kb[k] == 16 for k in kb.keys() & ka.keys())


@pytest.mark.parametrize("unknown", ["copy", "prior"])
@pytest.mark.parametrize("rule", octofuse.RULES)
def test_tree_fusion_equals_the_rule_on_every_expanded_voxel(pair, rule, unknown):
    a, b = pair
    res = a.resolution
    fused, loss = fuse_maps(a, b, rule=rule, unknown=unknown)
    ea, eb = expand(a.leaves(), res), expand(b.leaves(), res)
    ef, el = expand(fused.leaves(), res), expand(loss.leaves(), res)
    keys = sorted(ea.keys() | eb.keys())
    assert set(ef) == set(keys)
    la = np.array([ea.get(k, np.nan) for k in keys], dtype=np.float64)
    lb = np.array([eb.get(k, np.nan) for k in keys], dtype=np.float64)
    both = ~np.isnan(la) & ~np.isnan(lb)
    if unknown == "copy":
        want = np.where(np.isnan(la), lb, la).astype(np.float32)
        want_loss = np.zeros(len(keys), dtype=np.float32)
        f = fuse_logodds(la[both], lb[both], rule=rule)
        cmin, cmax = a.clamping_logodds
        want[both] = np.clip(f.l, cmin, cmax).astype(np.float32)
        want_loss[both] = f.info_loss.astype(np.float32)
    else:
        f = fuse_logodds(np.nan_to_num(la, nan=0.0), np.nan_to_num(lb, nan=0.0), rule=rule)
        cmin, cmax = a.clamping_logodds
        want = np.clip(f.l, cmin, cmax).astype(np.float32)
        want_loss = f.info_loss.astype(np.float32)
    got = np.array([ef[k] for k in keys])
    got_loss = np.array([el[k] for k in keys])
    assert both.sum() > 1000 and (~both).sum() > 1000
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(got_loss, want_loss)


def test_fused_tree_is_pruned_and_inner_nodes_hold_the_max(pair, tmp_path):
    a, _ = pair
    fused, loss = fuse_maps(a, a, rule="bhattacharyya")
    # fusing a map with itself under a WEP rule gives the same map, as compact
    assert fused.num_leaves == a.num_leaves
    np.testing.assert_array_equal(fused.leaves().values, a.leaves().values)
    # the loss is what naive Bayes would have added: KL(p(2l) || p(l)) > 0 where l != 0
    lv = a.leaves().values.astype(np.float64)
    want = fuse_logodds(lv, lv, rule="bhattacharyya").info_loss.astype(np.float32)
    np.testing.assert_array_equal(loss.leaves().values, want)
    path = fused.save(tmp_path / "f.ot")
    assert OccupancyMap.load(path).num_nodes == a.num_nodes


def test_incompatible_maps_are_rejected():
    a = OccupancyMap(0.1)
    with pytest.raises(ValueError, match="different resolutions"):
        fuse_maps(a, OccupancyMap(0.05))
    with pytest.raises(ValueError, match="different clamping"):
        fuse_maps(a, OccupancyMap(0.1, clamping=(0.12, 0.97)))
    with pytest.raises(ValueError, match="valid rules are"):
        fuse_maps(a, a, rule="chernov")
    with pytest.raises(ValueError, match="'zero'; valid policies are: copy, prior"):
        fuse_maps(a, a, unknown="zero")


def test_map_parameters_are_validated():
    with pytest.raises(ValueError, match="resolution"):
        OccupancyMap(0.0)
    with pytest.raises(ValueError, match="prob_hit"):
        OccupancyMap(0.1, prob_hit=0.3)
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        OccupancyMap(0.1).insert_scan(np.zeros((4, 2)), (0, 0, 0))
    with pytest.raises(ValueError, match="non-finite coordinate at row 1"):
        OccupancyMap(0.1).insert_scan(np.array([[1.0, 0, 0], [np.nan, 0, 0]]), (0, 0, 0))


def test_insertion_matches_octomap_ray_casting():
    m = OccupancyMap(0.1)
    m.insert_scan(np.array([[1.05, 0.05, 0.05]], dtype=np.float32), (0.05, 0.05, 0.05))
    lv = m.leaves()
    occ = lv.centers[lv.values > 0]
    np.testing.assert_allclose(occ, [[1.05, 0.05, 0.05]], atol=1e-6)
    free = lv.centers[lv.values < 0]
    assert len(free) == 10 and np.all(free[:, 0] < 1.0)
    # one hit with prob_hit 0.7: log-odds 0.847; one miss with 0.4: -0.405
    assert lv.values[lv.values > 0][0] == pytest.approx(np.log(0.7 / 0.3), rel=1e-6)
    assert np.all(np.isclose(lv.values[lv.values < 0], np.log(0.4 / 0.6), rtol=1e-6))


def test_sensor_frame_insertion_equals_map_frame_insertion():
    rng = np.random.default_rng(5)
    pts = rng.uniform(-1, 1, (200, 3))
    T = np.eye(4)
    c, s = np.cos(0.7), np.sin(0.7)
    T[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    T[:3, 3] = [0.3, -0.2, 0.1]
    a, b = OccupancyMap(0.1), OccupancyMap(0.1)
    a.insert_scan_from_sensor(pts, T)
    b.insert_scan(pts @ T[:3, :3].T + T[:3, 3], T[:3, 3])
    np.testing.assert_array_equal(a.leaves().values, b.leaves().values)


def test_ot_round_trip_keeps_every_log_odds(pair, tmp_path):
    a, _ = pair
    b = OccupancyMap.load(a.save(tmp_path / "a.ot"))
    la, lb = a.leaves(), b.leaves()
    np.testing.assert_array_equal(la.values, lb.values)
    np.testing.assert_array_equal(la.centers, lb.centers)
    assert (b.resolution, b.prob_hit, b.prob_miss, b.clamping) == (0.1, 0.7, 0.4, (0.1192, 0.971))


def test_bt_keeps_only_maximum_likelihood(pair, tmp_path):
    a, _ = pair
    b = OccupancyMap.load(a.save(tmp_path / "a.bt"))
    ea, eb = expand(a.leaves(), 0.1), expand(b.leaves(), 0.1)
    assert ea.keys() == eb.keys()
    cmin, cmax = b.clamping_logodds
    assert set(np.unique(list(eb.values()))) <= {np.float32(cmin), np.float32(cmax)}
    assert all((ea[k] > 0) == (eb[k] > 0) for k in ea)


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("compare_octrees") is None, reason="octomap-tools not installed")
def test_octomaps_own_tools_open_our_files(pair, tmp_path):
    a, _ = pair
    p = a.save(tmp_path / "a.ot")
    out = subprocess.run(
        ["compare_octrees", str(p), str(p)], capture_output=True, text=True, check=True
    )
    assert "KLD: 0" in out.stdout
    bt = a.save(tmp_path / "a.bt")
    subprocess.run(
        ["convert_octree", str(bt), str(tmp_path / "c.ot")], check=True, capture_output=True
    )
    c = OccupancyMap.load(tmp_path / "c.ot")
    assert c.num_leaves == OccupancyMap.load(bt).num_leaves


def test_reads_octomaps_own_binary_file(shared_real):
    m = OccupancyMap.load(shared_real / "geb079.bt")
    assert m.resolution == pytest.approx(0.08) and m.num_leaves > 10000


def test_bad_map_files_are_clear_errors(pair, tmp_path):
    a, _ = pair
    with pytest.raises(FileNotFoundError, match="missing.ot"):
        OccupancyMap.load(tmp_path / "missing.ot")
    (tmp_path / "foreign.ot").write_text("ply\nformat ascii 1.0\n")
    with pytest.raises(octofuse.MapFileError, match=r"foreign.ot' is not an OctoMap file"):
        OccupancyMap.load(tmp_path / "foreign.ot")
    for ext in ("ot", "bt"):
        data = a.save(tmp_path / f"full.{ext}").read_bytes()
        (tmp_path / f"cut.{ext}").write_bytes(data[: len(data) // 2])
        with pytest.raises(octofuse.MapFileError, match=f"cut.{ext}' is truncated"):
            OccupancyMap.load(tmp_path / f"cut.{ext}")
    with pytest.raises(ValueError, match="expected a .ot or .bt"):
        a.save(tmp_path / "a.pcd")
    with pytest.raises(octofuse.MapFileError, match="no-such-dir"):
        a.save(tmp_path / "no-such-dir" / "a.ot")


def test_a_failed_save_keeps_the_existing_file(pair, tmp_path):
    a, _ = pair
    p = a.save(tmp_path / "keep.ot")
    before = p.read_bytes()
    (tmp_path / "keep.ot.octofuse-tmp").mkdir()  # the temporary name is taken: write fails
    with pytest.raises(octofuse.MapFileError):
        OccupancyMap(0.1).save(p)
    assert p.read_bytes() == before


def test_fusion_releases_the_gil(pair):
    a, b = pair
    ticks = []
    stop = threading.Event()

    def tick():
        while not stop.is_set():
            ticks.append(1)

    t = threading.Thread(target=tick)
    t.start()
    for _ in range(5):
        fuse_maps(a, b, rule="kld-weighted-chernoff")
    stop.set()
    t.join()
    assert len(ticks) > 0


def test_info_loss_accumulates_and_saves(pair, tmp_path):
    a, b = pair
    _, l1 = fuse_maps(a, b, rule="chernoff", unknown="prior")
    _, l2 = fuse_maps(b, a, rule="bhattacharyya", unknown="prior")
    acc = l1.copy()
    acc.accumulate(l2)
    e1, e2, ea = (expand(x.leaves(), 0.1) for x in (l1, l2, acc))
    assert ea.keys() == e1.keys() | e2.keys()
    for k, v in ea.items():
        assert v == pytest.approx(e1.get(k, 0) + e2.get(k, 0), rel=1e-6, abs=1e-7)
    p = acc.save(tmp_path / "loss.npz")
    with np.load(p) as z:
        np.testing.assert_array_equal(z["values"], acc.leaves().values)


@pytest.mark.parametrize("unknown", ["copy", "prior"])
@pytest.mark.parametrize(
    "rule", ["naive-bayes", "chernoff", "min-info-loss", "kld-weighted-chernoff"]
)
def test_in_place_fusion_equals_tree_fusion(pair, rule, unknown):
    a, b = pair
    for dst, msg in [(a.copy(), b), (b.copy(), a)]:
        ref, ref_loss = fuse_maps(dst, msg, rule=rule, unknown=unknown)
        known_both = expand(dst.leaves(), 0.1).keys() & expand(msg.leaves(), 0.1).keys()
        loss = octofuse.InfoLossMap(dst.resolution)
        octofuse.fuse_into(dst, msg, rule=rule, unknown=unknown, loss=loss)
        assert expand(dst.leaves(), 0.1) == expand(ref.leaves(), 0.1)
        want_loss = expand(ref_loss.leaves(), 0.1)
        if unknown == "copy":  # copied voxels were not fused: they have no loss entry
            want_loss = {k: v for k, v in want_loss.items() if k in known_both}
        assert expand(loss.leaves(), 0.1) == want_loss


def test_in_place_fusion_accumulates_loss_over_messages(pair):
    a, b = pair
    dst, loss = a.copy(), octofuse.InfoLossMap(a.resolution)
    octofuse.fuse_into(dst, b, rule="chernoff", loss=loss)
    first = expand(loss.leaves(), 0.1)
    octofuse.fuse_into(dst, b, rule="chernoff", loss=loss)
    second = expand(loss.leaves(), 0.1)
    # the voxels b alone knew were copied by the first fusion and are fused by the second
    assert first.keys() < second.keys()
    assert all(second[k] >= first[k] for k in first)
    assert sum(second.values()) > sum(first.values())
    with pytest.raises(ValueError, match="into itself"):
        octofuse.fuse_into(dst, dst)


@pytest.mark.parametrize("unknown", ["copy", "prior"])
@pytest.mark.parametrize(
    "rule",
    [
        "chernoff",
        "min-entropy",
        "naive-bayes",
        "kld-weighted-chernoff",
        "entropy-weighted-chernoff",
        "bhattacharyya",
        "min-info-loss",
    ],
)
def test_two_way_exchange_equals_two_fusions_of_the_maps_before(pair, rule, unknown):
    a, b = pair
    ra, rb = a.copy(), b.copy()
    la_ref, lb_ref = octofuse.InfoLossMap(0.1), octofuse.InfoLossMap(0.1)
    octofuse.fuse_into(ra, b, rule, unknown, la_ref)
    octofuse.fuse_into(rb, a, rule, unknown, lb_ref)
    xa, xb = a.copy(), b.copy()
    la, lb = octofuse.InfoLossMap(0.1), octofuse.InfoLossMap(0.1)
    octofuse.exchange_maps(xa, xb, rule, unknown, la, lb)
    assert expand(xa.leaves(), 0.1) == expand(ra.leaves(), 0.1)
    assert expand(xb.leaves(), 0.1) == expand(rb.leaves(), 0.1)
    assert expand(la.leaves(), 0.1) == expand(la_ref.leaves(), 0.1)
    assert expand(lb.leaves(), 0.1) == expand(lb_ref.leaves(), 0.1)


@pytest.mark.parametrize("unknown", ["copy", "prior"])
def test_in_place_fusions_count_the_leaves_of_what_they_fuse_in(pair, unknown):
    """The walks count each message's own leaves (coarse leaves the walk expands count once):
    the voxels of the messages of a run, without a walk of their own."""
    from octofuse import _core
    from octofuse.rules import parse_rule, parse_unknown

    empty = OccupancyMap(0.1)
    pairs = [
        pair,
        pair[::-1],
        _random_tree_pair(5),
        _random_tree_pair(6),
        (pair[0], empty),
        (empty, pair[1]),
        (empty, OccupancyMap(0.1)),
    ]
    for a, b in pairs:
        want = a.num_leaves, b.num_leaves
        assert octofuse.exchange_maps(a.copy(), b.copy(), "chernoff", unknown) == want
        for threads in (1, 2, 3):
            counts = _core._fuse_into(
                a.copy()._m,
                b._m,
                parse_rule("min-info-loss"),
                parse_unknown(unknown),
                None,
                threads=threads,
            )
            assert counts[3] == b.num_leaves
    assert min(pairs[2][0].leaves().depths) < 16 and max(pairs[2][1].leaves().depths) == 16


def _random_tree_data(rng, top_depth=11, leaf_prob=(0.25, 0.3, 0.35, 0.45, 1.0)):
    """OctoMap node data (``OcTree::writeData``: each node's float log-odds and its child mask,
    depth first) of a random tree: one path from the root down to ``top_depth``, then random
    subtrees whose leaves lie at every depth from top_depth + 1 to 16 (a leaf at depth d stands
    for 8^(16-d) finest voxels). Values are a few sensor-model sums and some continuous ones."""
    out = bytearray()
    steps = np.array([-2.0, -1.23, -0.41, 0.0, 0.85, 1.7, 3.5], dtype=np.float32)

    def node(value, mask):
        out.extend(np.float32(value).tobytes())
        out.append(mask)

    def subtree(depth):
        v = rng.choice(steps) if rng.random() < 0.7 else rng.uniform(-2.0, 3.5)
        if depth == 16 or rng.random() < leaf_prob[depth - top_depth - 1]:
            node(v, 0)
            return
        mask = int(rng.integers(1, 256))
        node(v, mask)
        for i in range(8):
            if mask >> i & 1:
                subtree(depth + 1)

    for depth in range(top_depth):  # the path: child 7 at the root, then child 0 (near 0, 0, 0)
        node(0.0, 1 << (7 if depth == 0 else 0))
    mask = int(rng.integers(1, 256)) | 1
    node(0.0, mask)
    for i in range(8):
        if mask >> i & 1:
            subtree(top_depth + 1)
    return bytes(out)


def _random_tree_pair(seed):
    rng = np.random.default_rng(seed)
    a, b = (OccupancyMap.from_tree_data(_random_tree_data(rng), 0.1) for _ in range(2))
    return a, b


def _brute_force_counts(a, b, rule, unknown):
    """Finest voxels fused and copied by fusing ``a`` and ``b`` and the summed loss, from the
    expanded maps: (fused, only in a, only in b, loss sum)."""
    ea, eb = expand(a.leaves(), 0.1), expand(b.leaves(), 0.1)
    keys = sorted(ea.keys() | eb.keys())
    la = np.array([ea.get(k, np.nan) for k in keys], dtype=np.float64)
    lb = np.array([eb.get(k, np.nan) for k in keys], dtype=np.float64)
    both = ~np.isnan(la) & ~np.isnan(lb)
    only_a, only_b = (
        int((~np.isnan(la) & np.isnan(lb)).sum()),
        int((np.isnan(la) & ~np.isnan(lb)).sum()),
    )
    if unknown == "copy":
        loss = fuse_logodds(la[both], lb[both], rule=rule).info_loss
        return (
            int(both.sum()),
            only_a,
            only_b,
            float(loss.astype(np.float32).astype(np.float64).sum()),
        )
    loss = fuse_logodds(np.nan_to_num(la, nan=0.0), np.nan_to_num(lb, nan=0.0), rule=rule).info_loss
    return len(keys), only_a, only_b, float(loss.astype(np.float32).astype(np.float64).sum())


@pytest.mark.parametrize("unknown", ["copy", "prior"])
@pytest.mark.parametrize("rule", ["naive-bayes", "min-info-loss", "chernoff"])
@pytest.mark.parametrize("seed", [3, 4, 5])
def test_counts_are_finest_voxels_and_the_loss_sum_is_the_voxels_loss(seed, rule, unknown):
    a, b = _random_tree_pair(seed)
    assert len(np.unique(np.concatenate([a.leaves().depths, b.leaves().depths]))) >= 4
    fused, only_a, only_b, loss_sum = _brute_force_counts(a, b, rule, unknown)
    assert fused > 0 and only_a > 0 and only_b > 0
    assert a.known_voxels == len(expand(a.leaves(), 0.1))
    prior = unknown == "prior"

    _, loss = fuse_maps(a, b, rule=rule, unknown=unknown)
    assert (loss.voxels_fused, loss.voxels_copied) == (fused, 0 if prior else only_a + only_b)
    assert loss.loss_sum == pytest.approx(loss_sum, rel=1e-9, abs=1e-9)

    for threads in (1, 2, 3):  # in place: voxels only dst knows are not visited
        for dst, msg, only_msg in ((a, b, only_b), (b, a, only_a)):
            loss = octofuse.InfoLossMap(0.1)
            octofuse.fuse_into(dst.copy(), msg, rule, unknown, loss, threads=threads)
            assert (loss.voxels_fused, loss.voxels_copied) == (fused, 0 if prior else only_msg)
            assert loss.loss_sum == pytest.approx(loss_sum, rel=1e-9, abs=1e-9)

    la, lb = octofuse.InfoLossMap(0.1), octofuse.InfoLossMap(0.1)
    octofuse.exchange_maps(a.copy(), b.copy(), rule, unknown, la, lb)
    assert (la.voxels_fused, la.voxels_copied) == (fused, 0 if prior else only_b)
    assert (lb.voxels_fused, lb.voxels_copied) == (fused, 0 if prior else only_a)
    assert la.loss_sum == pytest.approx(loss_sum, rel=1e-9, abs=1e-9)
    # the counts follow the loss map through copy and accumulate
    acc = la.copy()
    acc.accumulate(lb)
    assert (acc.voxels_fused, acc.loss_sum) == (2 * fused, pytest.approx(la.loss_sum + lb.loss_sum))


def test_clear_frees_every_voxel_and_leaves_a_usable_map():
    from octofuse.threads import thread_map

    maps = [random_map(s, 3) for s in range(4)]
    fused = [fuse_maps(maps[0], m, "chernoff") for m in maps[1:]]
    assert all(m.num_leaves > 0 for m in maps) and all(f.info_loss.num_leaves > 0 for f in fused)
    thread_map(lambda m: m.clear(), [*maps, *(f.info_loss for f in fused)], 2)
    assert [m.num_leaves for m in maps] == [0] * 4
    assert all(f.info_loss.num_leaves == 0 and f.info_loss.loss_sum == 0 for f in fused)
    maps[0].insert_scan(np.array([[1.0, 0.5, 0.2]]), (0.0, 0.0, 0.2))  # maps again as a new map
    fresh = OccupancyMap(0.1)
    fresh.insert_scan(np.array([[1.0, 0.5, 0.2]]), (0.0, 0.0, 0.2))
    assert expand(maps[0].leaves(), 0.1) == expand(fresh.leaves(), 0.1) != {}


def _dense_map(seed, offset):
    """A map of about 170,000 nodes: 0.02 m voxels, three scans of 3000 points."""
    rng = np.random.default_rng(seed)
    m = OccupancyMap(0.02)
    for _ in range(3):
        m.insert_scan(scan_ring(rng, np.asarray(offset), n_points=3000), rng.uniform(-0.2, 0.2, 3))
    return m


def _same_leaves(x, y):
    lx, ly = x.leaves(), y.leaves()
    np.testing.assert_array_equal(lx.centers, ly.centers)
    np.testing.assert_array_equal(lx.depths, ly.depths)
    np.testing.assert_array_equal(lx.values, ly.values)


@pytest.mark.parametrize("rule", ["naive-bayes", "entropy-weighted-chernoff", "min-info-loss"])
def test_large_results_are_the_same_maps_before_and_after_changes(rule):
    # inputs this large give fuse_maps' results slabs of their own, freed at once while
    # nothing else was added to them: the same maps as fusing in place, and they stay
    # maps like any other when changed
    a, b, c = _dense_map(1, (0, 0, 0)), _dense_map(2, (0.3, 0.1, 0)), _dense_map(3, (-0.2, 0, 0))
    assert a.num_nodes + b.num_nodes >= 2**18
    fused, loss = fuse_maps(a, b, rule=rule, unknown="prior")
    ref = a.copy()
    ref_loss = octofuse.InfoLossMap(a.resolution)
    octofuse.fuse_into(ref, b, rule=rule, unknown="prior", loss=ref_loss)
    _same_leaves(fused, ref)
    np.testing.assert_array_equal(loss.leaves().values, ref_loss.leaves().values)
    for m, m_loss in [(fused, loss), (ref, ref_loss)]:
        octofuse.fuse_into(m, c, rule="naive-bayes", loss=m_loss)
        m.insert_scan(scan_ring(np.random.default_rng(4), np.zeros(3), n_points=500), np.zeros(3))
    _same_leaves(fused, ref)
    np.testing.assert_array_equal(loss.leaves().values, ref_loss.leaves().values)
    copy = fused.copy()
    del fused, loss
    _same_leaves(copy, ref)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_leaves_of_a_class_are_those_leaves_of_all(seed):
    m = random_map(seed, 20)
    every = m.leaves()
    occupied = every.values > 0
    assert 0 < occupied.sum() < len(every.values) and (every.depths < 16).any()  # coarse leaves too
    for voxels, sel in (
        ("occupied", occupied),
        ("free", ~occupied),
        ("all", np.ones(len(occupied), bool)),
    ):
        got = m.leaves(voxels)
        for name in ("centers", "sizes", "values", "depths"):
            assert np.array_equal(getattr(got, name), getattr(every, name)[sel]), (voxels, name)
    with pytest.raises(ValueError, match="voxels = 'walls': expected 'occupied', 'free' or 'all'"):
        m.leaves("walls")


# -- values no OctoMap clamping produces ---------------------------------------------------
import warnings  # noqa: E402

from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from octofuse.maps.occupancy import MapFileError, MapValueWarning  # noqa: E402

_F32_MAX = float(np.finfo(np.float32).max)


def _f32(x):
    return float(np.float32(x))


def _with_values(tmp_path, values):
    """A small .ot file whose first len(values) nodes hold ``values`` (depth-first order)."""
    m = octofuse.OccupancyMap(0.1)
    m.insert_scan(np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [-1.0, 0, 0]]), [0, 0, 0])
    return map_with_values(m.save(tmp_path / "src.ot"), tmp_path / "m.ot", values)


@settings(max_examples=25, deadline=None)
@given(
    st.lists(
        st.one_of(
            st.floats(-_F32_MAX, _f32(-2.01), width=32), st.floats(_f32(3.52), _F32_MAX, width=32)
        ),
        min_size=1,
        max_size=6,
    )
)
def test_values_outside_the_clamping_range_are_clamped_with_one_warning(tmp_path_factory, values):
    p = _with_values(tmp_path_factory.mktemp("v"), values)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        m = octofuse.OccupancyMap.load(p)
    assert [type(w.message) for w in seen] == [MapValueWarning]
    assert str(p) in str(seen[0].message) and "clamped" in str(seen[0].message)
    lo, hi = m.clamping_logodds
    v = m.leaves().values
    assert v.min() >= lo - 1e-5 and v.max() <= hi + 1e-5


@pytest.mark.parametrize("value", [1e-40, -1e-42])
def test_subnormal_values_are_refused_naming_the_file(tmp_path, value):
    p = _with_values(tmp_path, [0.5, value])
    with pytest.raises(MapFileError, match=r"m\.ot.*subnormal"):
        octofuse.OccupancyMap.load(p)


def test_maps_octomap_writes_load_without_warnings(tmp_path):
    p = _with_values(tmp_path, [])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        octofuse.OccupancyMap.load(p)
