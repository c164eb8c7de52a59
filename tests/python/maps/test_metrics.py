"""Scoring maps against the centralized map, on small maps whose answers are known.

Maps are made by OctoMap's own ray casting: one ray along +x from the centre of a voxel marks
the voxels it passes free (log-odds of prob_miss) and its end voxel occupied (prob_hit), and
eight endpoints filling a 2 x 2 x 2 block give one pruned (coarse) leaf. Expected values are
worked out from the leaves' log-odds: KL of two Bernoullis, with an unknown voxel at p = 0.5.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

import octofuse
from conftest import expand, random_map
from octofuse import OccupancyMap, fuse_into, fuse_maps
from octofuse.maps.compare import (
    compare,
    compare_many,
    finest_centers,
    loss_stats,
    score,
    weighted_percentile,
)
from octofuse.maps.infoloss import voxels_in_bins, voxels_per_leaf
from octofuse.maps.occupancy import ReferenceMap
from octofuse.maps.truth import Scene

RES = 0.1
L_MISS = float(np.float32(math.log(0.4 / 0.6)))  #: a voxel a ray passed through once
L_HIT = float(np.float32(math.log(0.7 / 0.3)))  #: an endpoint seen once
ORIGIN = (0.05, 0.05, 0.05)  #: centre of the voxel at the origin


def sigmoid(l):
    return 1.0 / (1.0 + np.exp(-np.asarray(l, dtype=np.float64)))


def kl(lq, lp):
    """KL(q || p) of Bernoullis given by log-odds, nats."""
    q, p = sigmoid(lq), sigmoid(lp)
    return q * np.log(q / p) + (1 - q) * np.log((1 - q) / (1 - p))


def ray_map(end_x: float, times: int = 1, **kw) -> OccupancyMap:
    """One ray from :data:`ORIGIN` along +x to ``end_x``, inserted ``times`` times."""
    m = OccupancyMap(RES, **kw)
    for _ in range(times):
        m.insert_scan(np.array([[end_x, 0.05, 0.05]]), ORIGIN)
    return m


def block_map(k: int = 2, origin=(-0.95, -0.95, -0.95)) -> OccupancyMap:
    """Endpoints filling the k x k x k voxels of [0, k * RES)^3 (one octree node): one scan,
    so all of them hold the same value and prune into a single coarse leaf."""
    g = (np.arange(k) + 0.5) * RES
    pts = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    m = OccupancyMap(RES)
    m.insert_scan(pts, origin)
    return m


def values_by_x(m: OccupancyMap) -> dict[float, float]:
    lv = m.leaves()
    assert np.all(lv.depths == 16)
    np.testing.assert_allclose(lv.centers[:, 1:], 0.05)
    return {round(float(c[0]), 2): float(v) for c, v in zip(lv.centers, lv.values)}


def finest(m: OccupancyMap) -> dict[tuple, float]:
    """Every finest voxel (integer key) with its value; a coarse leaf gives all voxels below it."""
    return {k: float(v) for k, v in expand(m.leaves(), m.resolution).items()}


def reference_score(central: OccupancyMap, agent: OccupancyMap, tol: float) -> dict:
    """The metrics of :func:`compare`, voxel by voxel in Python."""
    c, a = finest(central), finest(agent)
    keys = list(c)
    lc = np.array([c[k] for k in keys])
    la = np.array([a.get(k, np.nan) for k in keys])
    known = ~np.isnan(la)
    occ_c, occ_a = lc > 0, la > 0
    same = known & (occ_c == occ_a)
    return {
        "kl_mean": float(np.mean(kl(lc, np.where(known, la, 0.0)))),
        "agreement": float(np.mean(same)),
        "agreement_occupied": float(np.mean(same[occ_c])) if occ_c.any() else math.nan,
        "agreement_free": float(np.mean(same[~occ_c])) if (~occ_c).any() else math.nan,
        "overconfidence": float(np.mean(np.abs(la[known]) > np.abs(lc[known]) + tol)),
        "coverage": float(np.mean(known)),
        "mean_abs_logodds_error": float(np.mean(np.abs(la[known] - lc[known]))),
        "voxels": float(len(keys)),
    }


def assert_score(s, want: dict) -> None:
    for key, value in want.items():
        got = getattr(s, key)
        if isinstance(value, float) and math.isnan(value):
            assert math.isnan(got), key
        else:
            assert got == pytest.approx(value, rel=1e-9, abs=1e-12), key


# -- hand-made maps ---------------------------------------------------------------------------


def test_the_single_ray_maps_hold_the_expected_voxels():
    once, twice = ray_map(0.55), ray_map(0.55, times=2)
    assert values_by_x(once) == pytest.approx(
        {0.05: L_MISS, 0.15: L_MISS, 0.25: L_MISS, 0.35: L_MISS, 0.45: L_MISS, 0.55: L_HIT}
    )
    assert values_by_x(twice) == pytest.approx(
        {x: 2 * v for x, v in values_by_x(once).items()}, rel=1e-6
    )


def test_a_map_against_itself_scores_perfectly():
    m = ray_map(0.55)
    s = compare(m, m.copy())
    assert_score(
        s,
        {
            "kl_mean": 0.0,
            "agreement": 1.0,
            "agreement_occupied": 1.0,
            "agreement_free": 1.0,
            "overconfidence": 0.0,
            "coverage": 1.0,
            "mean_abs_logodds_error": 0.0,
            "voxels": 6.0,
        },
    )


def test_kl_of_a_less_certain_agent_by_hand():
    central, agent = ray_map(0.55, times=2), ray_map(0.55)
    c, a = values_by_x(central), values_by_x(agent)
    want_kl = sum(kl(c[x], a[x]) for x in c) / 6
    by_hand = (5 * kl(2 * L_MISS, L_MISS) + kl(2 * L_HIT, L_HIT)) / 6
    assert want_kl == pytest.approx(by_hand, rel=1e-6)
    s = compare(central, agent)
    assert_score(
        s,
        {
            "kl_mean": want_kl,
            "agreement": 1.0,
            "coverage": 1.0,
            "overconfidence": 0.0,
            "mean_abs_logodds_error": sum(abs(c[x] - a[x]) for x in c) / 6,
            "voxels": 6.0,
        },
    )


def test_over_confidence_is_certainty_beyond_the_tolerance():
    central, agent = ray_map(0.55), ray_map(0.55, times=2)
    assert compare(central, agent).overconfidence == 1.0  # every voxel, by >= 0.405 > 0.1
    # with tol 0.5 only the occupied voxel (more certain by 0.847) counts
    assert compare(central, agent, tol=0.5).overconfidence == pytest.approx(1 / 6)
    assert compare(central, agent, tol=0.9).overconfidence == 0.0
    s = compare(central, agent)
    c, a = values_by_x(central), values_by_x(agent)
    assert s.kl_mean == pytest.approx(sum(kl(c[x], a[x]) for x in c) / 6, rel=1e-9)


def test_unknown_agent_voxels_count_as_even_odds():
    central = ray_map(0.55)  # free 0.05 .. 0.45, occupied 0.55
    agent = ray_map(0.25)  # free 0.05, 0.15, occupied 0.25; the rest unknown
    want_kl = (
        kl(L_MISS, L_HIT)  # 0.25: free against occupied
        + 2 * kl(L_MISS, 0.0)
        + kl(L_HIT, 0.0)
    ) / 6  # 0.35, 0.45, 0.55 unknown
    s = compare(central, agent)
    assert_score(
        s,
        {
            "kl_mean": want_kl,
            "agreement": 2 / 6,  # 0.05 and 0.15
            "agreement_free": 2 / 5,
            "agreement_occupied": 0.0,
            "coverage": 3 / 6,
            "overconfidence": 1 / 3,  # of the 3 voxels both know: 0.25 (|0.847| > |-0.405| + 0.1)
            "mean_abs_logodds_error": (L_HIT - L_MISS) / 3,
            "voxels": 6.0,
        },
    )


def test_voxels_only_the_agent_knows_do_not_count():
    central, agent = ray_map(0.25), ray_map(0.55)
    s = compare(central, agent)
    assert s.voxels == 3.0 and s.coverage == 1.0
    assert s.kl_mean == pytest.approx(kl(L_HIT, L_MISS) / 3, rel=1e-9)
    assert s.agreement == pytest.approx(2 / 3)


def test_an_empty_agent_knows_nothing():
    central = ray_map(0.55)
    s = compare(central, OccupancyMap(RES))
    assert s.coverage == 0.0 and s.agreement == 0.0
    assert s.kl_mean == pytest.approx((5 * kl(L_MISS, 0.0) + kl(L_HIT, 0.0)) / 6, rel=1e-9)
    assert math.isnan(s.overconfidence) and math.isnan(s.mean_abs_logodds_error)
    empty = compare(OccupancyMap(RES), OccupancyMap(RES))
    assert empty.voxels == 0.0 and math.isnan(empty.kl_mean) and math.isnan(empty.coverage)


def test_maps_of_other_resolutions_are_refused():
    with pytest.raises(ValueError, match="different resolutions"):
        compare(ray_map(0.55), OccupancyMap(0.2))


# -- coarse leaves ----------------------------------------------------------------------------


def test_a_coarse_leaf_counts_for_its_eight_voxels():
    central = block_map()
    lv = central.leaves()
    block = lv.values > 0
    assert block.sum() == 1 and lv.depths[block][0] == 15  # the 8 endpoints, pruned
    np.testing.assert_allclose(lv.centers[block][0], [0.1, 0.1, 0.1])
    weights = np.power(8.0, 16 - lv.depths.astype(float))
    s = compare(central, OccupancyMap(RES))
    assert s.voxels == weights.sum()
    want_kl = np.sum(weights * kl(lv.values, 0.0)) / weights.sum()
    assert s.kl_mean == pytest.approx(want_kl, rel=1e-9)
    # an agent knowing one of the eight voxels (a ray ending there) covers 1/8 of the leaf
    agent = OccupancyMap(RES)
    agent.insert_scan(np.array([[0.15, 0.15, 0.15]]), (0.55, 0.55, 0.55))
    s = compare(central, agent)
    want = reference_score(central, agent, 0.1)
    assert want["agreement_occupied"] == pytest.approx(1 / 8)
    assert_score(s, want)


def test_a_coarse_agent_leaf_over_fine_central_voxels():
    central = OccupancyMap(RES)
    central.insert_scan(np.array([[0.15, 0.15, 0.15]]), (0.55, 0.55, 0.55))
    agent = block_map()
    s = compare(central, agent)
    assert_score(s, reference_score(central, agent, 0.1))
    assert s.agreement_occupied == 1.0  # the central endpoint lies in the agent's occupied block


@pytest.mark.parametrize("tol", [0.1, 0.6])
@pytest.mark.parametrize("which", ["pruned-central", "pruned-agent"])
def test_compare_equals_a_voxel_by_voxel_reference(which, tol):
    pruned, fine = random_map(1, 25), random_map(2, 2, offset=(0.35, 0.1, 0.0))
    assert (pruned.leaves().depths < 16).sum() > 10
    central, agent = (pruned, fine) if which == "pruned-central" else (fine, pruned)
    s = compare(central, agent, tol)
    want = reference_score(central, agent, tol)
    assert 0 < want["coverage"] < 1 and 0 < want["overconfidence"] < 1
    assert_score(s, want)


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_compare_many_gives_each_map_its_own_comparison(threads):
    """One walk of the reference for several maps (pruned and fine, disjoint, empty, the
    reference itself) gives every map exactly the score it gets alone."""
    central = random_map(1, 25)
    maps = [
        random_map(2, 2, offset=(0.35, 0.1, 0.0)),
        OccupancyMap(RES),
        central.copy(),
        random_map(3, 25, offset=(-0.2, 0.3, 0.1)),
        random_map(4, 3, offset=(9.0, 9.0, 9.0)),
        block_map(),
    ]
    many = compare_many(central, maps, 0.1, threads=threads)
    assert [s.kl_mean for s in many][2] == 0.0
    # different maps, different scores (the empty and the disjoint map score alike)
    assert len({s.kl_mean for s in many}) == len(maps) - 1
    for m, s in zip(maps, many):
        np.testing.assert_equal(s.to_dict(), compare(central, m, 0.1).to_dict())  # exactly
    assert compare_many(OccupancyMap(RES), maps[:2], 0.1, threads)[1].voxels == 0.0
    assert compare_many(central, [], 0.1, threads) == []


def test_a_reference_map_is_a_snapshot_of_its_map():
    """Read once, a reference scores as its map did then, whatever the map does afterwards."""
    central, agent = random_map(1, 25), random_map(2, 2, offset=(0.35, 0.1, 0.0))
    before = central.copy()
    ref = ReferenceMap(central)
    assert ref.num_nodes == central.num_nodes and ref.memory_bytes >= 12 * ref.num_nodes
    fuse_into(central, random_map(3, 25, offset=(-0.2, 0.3, 0.1)), rule="naive-bayes")
    central.insert_scan(np.array([[2.0, 0.05, 0.05]]), ORIGIN)
    assert compare(central, agent).to_dict() != compare(before, agent).to_dict()
    np.testing.assert_equal(compare(ref, agent).to_dict(), compare(before, agent).to_dict())
    want = reference_score(before, agent, 0.1)
    assert_score(compare_many(ref, [agent], 0.1)[0], want)
    del central, before  # the reference holds its own copy of the nodes
    assert_score(compare(ref, agent), want)
    assert ReferenceMap(OccupancyMap(RES)).num_nodes == 0


def test_a_reference_map_is_checked_like_its_map():
    with pytest.raises(ValueError, match="resolution"):
        compare(ReferenceMap(ray_map(0.55)), OccupancyMap(0.2))
    with pytest.raises(TypeError, match="OccupancyMap"):
        ReferenceMap(ray_map(0.55).leaves())


# -- loss statistics and percentiles ----------------------------------------------------------


def test_loss_stats_weight_coarse_leaves_by_their_voxels():
    m = block_map()
    fused, loss = fuse_maps(m, m, rule="chernoff")
    # chernoff of two equal values keeps the value: the loss is KL(p(2 l) || p(l))
    lv = loss.leaves()
    occupied = fused.leaves().values > 0
    np.testing.assert_allclose(lv.centers, fused.leaves().centers)
    np.testing.assert_allclose(lv.values[occupied], kl(2 * L_HIT, L_HIT), rtol=1e-6)
    np.testing.assert_allclose(lv.values[~occupied], kl(2 * L_MISS, L_MISS), rtol=1e-6)
    weights = np.power(8.0, 16 - lv.depths.astype(float))
    n_occ, n_free = weights[occupied].sum(), weights[~occupied].sum()
    assert n_occ == 8
    mean, p95 = loss_stats(*loss.values_depths())
    want_mean = (n_occ * kl(2 * L_HIT, L_HIT) + n_free * kl(2 * L_MISS, L_MISS)) / (n_occ + n_free)
    assert mean == pytest.approx(want_mean, rel=1e-6)
    # 8 of the voxels (> 5 %) lost the most, although they are a single leaf (< 5 % of leaves)
    assert n_occ / (n_occ + n_free) > 0.05 and occupied.sum() / len(lv.values) < 0.05
    assert p95 == pytest.approx(kl(2 * L_HIT, L_HIT), rel=1e-6)
    assert float(np.percentile(lv.values, 95)) < p95


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 40), st.floats(0.5, 4.0), st.integers(1, 64), st.data())
def test_voxels_in_bins_are_the_weights_summed_per_bin(nbins, top, block, data):
    # leaves counted per bin and depth, a block at a time, then weighed: the sums are exact
    # (the leaves of a few trees: at most 300 x 8^14 voxels, below 2^53)
    n = data.draw(st.integers(0, 300))
    values = np.array(
        data.draw(
            st.lists(
                st.sampled_from([-0.5, 0.0, top, top + 0.1, np.nan]) | st.floats(0.0, top),
                min_size=n,
                max_size=n,
            )
        ),
        dtype=np.float32,
    )
    depths = np.array(
        data.draw(st.lists(st.integers(2, 16), min_size=n, max_size=n)), dtype=np.uint8
    )
    w = voxels_per_leaf(depths)
    inside = (values >= 0) & (values <= top)
    bins = np.minimum((values[inside] * (nbins / top)).astype(np.int64), nbins - 1)
    cut = data.draw(st.integers(0, n))  # the leaves of two maps
    per_bin, total = voxels_in_bins(
        [(values[:cut], depths[:cut]), (values[cut:], depths[cut:])], nbins, top, block
    )
    assert per_bin.shape == (nbins,)
    assert np.array_equal(per_bin, np.bincount(bins, weights=w[inside], minlength=nbins))
    assert total == w.sum()


def test_loss_stats_of_an_empty_loss_map():
    assert loss_stats(*octofuse.InfoLossMap(RES).values_depths()) == (0.0, 0.0)


def test_weighted_percentile():
    v = np.array([3.0, 1.0, 4.0, 2.0])
    ones = np.ones(4)
    assert weighted_percentile(v, ones, 50) == 2.0  # first value with half the weight below it
    assert weighted_percentile(v, ones, 95) == 4.0
    assert weighted_percentile(v, ones, 0) == 1.0
    assert weighted_percentile(v, ones, 100) == 4.0
    heavy = np.array([0.0, 10.0])
    assert weighted_percentile(heavy, np.array([99.0, 1.0]), 95) == 0.0
    assert weighted_percentile(heavy, np.array([99.0, 1.0]), 99.5) == 10.0
    assert weighted_percentile(heavy, np.array([1.0, 19.0]), 5) == 0.0
    assert weighted_percentile(heavy, np.array([1.0, 19.0]), 6) == 10.0
    assert math.isnan(weighted_percentile(np.array([]), np.array([]), 50))


# -- score: every metric of one agent ---------------------------------------------------------


def test_score_adds_loss_traffic_and_accuracy():
    central, agent = ray_map(0.55, times=2), ray_map(0.55)
    _, loss = fuse_maps(agent, agent, rule="bhattacharyya")
    truth = Scene(np.array([[[0.5, -1.0, -1.0], [2.0, 1.0, 1.0]]]), ["wall"], ["wall"])
    s = score(
        agent, central, loss=loss, truth=truth, bytes_sent=10, bytes_received=20, bytes_sent_32b=30
    )
    # the loss map's leaves as read already give the same statistics
    read = score(agent, central, loss=loss.values_depths())
    assert (read.loss_mean, read.loss_p95) == (s.loss_mean, s.loss_p95)
    base = compare(central, agent)
    for key in ("kl_mean", "agreement", "coverage", "overconfidence", "voxels"):
        assert getattr(s, key) == getattr(base, key)
    assert (s.loss_mean, s.loss_p95) == loss_stats(*loss.values_depths())
    assert (s.bytes_sent, s.bytes_received, s.bytes_sent_32b) == (10, 20, 30)
    assert s.occupied_accuracy == 1.0  # the endpoint 0.55 lies 0.05 m inside the wall at x = 0.5
    plain = score(agent, central)
    assert plain.loss_mean is None and plain.occupied_accuracy is None and plain.bytes_sent is None
    d = s.to_dict()
    assert d["bytes_sent"] == 10 and d["kl_mean"] == s.kl_mean


def test_occupied_accuracy_counts_a_coarse_leaf_as_its_voxels():
    m = block_map(k=4)  # 64 occupied voxels in [0, 0.4)^3, pruned into one leaf
    lv = m.leaves()
    occ = lv.values > 0
    assert occ.sum() == 1 and lv.depths[occ][0] == 14
    # a floor whose top face passes through the lowest layer of voxel centres (z = 0.05):
    # the layers z = 0.05 and 0.15 lie within the tolerance (0.1 * sqrt(3) / 2 + 0.03), the
    # layers 0.25 and 0.35 do not; the leaf centre (z = 0.2) alone would count as off
    floor = Scene(np.array([[[-5.0, -5.0, -1.0], [5.0, 5.0, 0.05]]]), ["floor"], ["floor"])
    assert floor.occupied_accuracy(lv.centers[occ], RES) == 0.0
    assert score(m, m, truth=floor).occupied_accuracy == pytest.approx(0.5)


def test_finest_centers_expands_coarse_leaves():
    c = finest_centers(np.array([[0.1, 0.1, 0.1], [1.05, 0.05, 0.05]]), np.array([0.2, 0.1]), RES)
    assert len(c) == 9
    g = [0.05, 0.15]
    want = sorted([(x, y, z) for x in g for y in g for z in g] + [(1.05, 0.05, 0.05)])
    np.testing.assert_allclose(sorted(map(tuple, c)), want)
    assert finest_centers(np.empty((0, 3)), np.empty(0), RES).shape == (0, 3)


# -- ground truth -----------------------------------------------------------------------------


UNIT = Scene(np.array([[[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]]), ["box"], ["obstacle"])


def test_signed_distance_to_a_box():
    pts = np.array(
        [
            [0.5, 0.5, 0.5],  # centre: 0.5 inside
            [0.5, 0.5, 0.9],  # near the top face
            [1.0, 0.5, 0.5],  # on a face
            [2.0, 0.5, 0.5],  # beside a face
            [2.0, 2.0, 0.5],  # beside an edge
            [2.0, 2.0, 3.0],  # beside a corner
            [-0.3, -0.4, 0.5],
        ]
    )
    want = [-0.5, -0.1, 0.0, 1.0, math.sqrt(2), math.sqrt(6), 0.5]
    np.testing.assert_allclose(UNIT.signed_distance(pts), want, atol=1e-12)
    np.testing.assert_allclose(UNIT.signed_distance(pts, chunk=2), want, atol=1e-12)
    np.testing.assert_allclose(UNIT.signed_distance([2.0, 0.5, 0.5]), [1.0])


def test_signed_distance_takes_the_nearest_box():
    two = Scene(
        np.array([[[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]], [[1.2, 0.0, 0.0], [2.0, 1.0, 1.0]]]),
        ["a", "b"],
        ["", ""],
    )
    pts = np.array([[0.9, 0.5, 0.5], [1.1, 0.5, 0.5], [1.5, 0.5, 0.5], [3.0, 0.5, 0.5]])
    np.testing.assert_allclose(two.signed_distance(pts), [-0.1, 0.1, -0.3, 1.0], atol=1e-12)


def test_occupied_accuracy_within_half_a_voxel_diagonal_and_noise():
    tol = RES * math.sqrt(3) / 2 + 0.03
    centers = np.array(
        [
            [1.0, 0.5, 0.5],  # on the surface
            [1.0 + tol - 1e-6, 0.5, 0.5],  # just within, outside
            [1.0 - tol + 1e-6, 0.5, 0.5],  # just within, inside
            [1.0 + tol + 1e-3, 0.5, 0.5],  # just beyond
            [0.5, 0.5, 0.5],  # deep inside
        ]
    )
    assert UNIT.occupied_accuracy(centers, RES) == pytest.approx(3 / 5)
    assert UNIT.occupied_accuracy(centers, RES, noise=0.0) == pytest.approx(1 / 5)
    assert math.isnan(UNIT.occupied_accuracy(np.empty((0, 3)), RES))


def test_near_surface_is_the_signed_distance_test():
    """The core's test (each point against the boxes of its grid cell) equals |signed
    distance| <= tol on random points around overlapping and separate boxes (corners, edges,
    faces, inside and far away), and on voxel centres with the accuracy's tolerance."""
    rng = np.random.default_rng(5)
    lo = rng.uniform(-2, 2, (6, 3))
    boxes = np.stack([lo, lo + rng.uniform(0.05, 1.5, (6, 3))], axis=1)
    scene = Scene(boxes, [""] * 6, [""] * 6)
    on_faces = boxes[:, 0] + rng.uniform(0, 1, (6, 3)) * (boxes[:, 1] - boxes[:, 0])
    on_faces[:, 0] = boxes[:, 1, 0]  # on each box's +x face
    pts = np.concatenate([rng.uniform(-3, 4, (20_000, 3)), on_faces, boxes[:, 0], boxes[:, 1]])
    for tol in (0.0, 0.05, 0.3):
        want = np.abs(scene.signed_distance(pts)) <= tol
        np.testing.assert_array_equal(scene.near_surface(pts, tol), want)
        assert 0 < want.sum() < len(pts)
    res = 0.05
    centres = (np.floor(rng.uniform(-3, 4, (50_000, 3)) / res) + 0.5) * res
    tol = res * np.sqrt(3) / 2 + 0.03
    want = np.abs(scene.signed_distance(centres)) <= tol
    np.testing.assert_array_equal(scene.near_surface(centres, tol), want)
    one_box = Scene(boxes[:1], [""], [""])  # a grid of one cell
    np.testing.assert_array_equal(
        one_box.near_surface(pts, 0.05), np.abs(one_box.signed_distance(pts)) <= 0.05
    )
    assert not scene.near_surface(np.array([[np.nan, 0.0, 0.0]]), 0.3).any()
    assert len(scene.near_surface(np.empty((0, 3)), 0.3)) == 0
    with pytest.raises(ValueError, match="a box corner is not finite"):
        Scene(np.full((1, 2, 3), np.nan), [""], [""]).near_surface(pts, 0.05)


def _sorted_weighted_percentile(v, w, q):
    """The definition: sort, accumulate the weights, take the first value that reaches q %."""
    order = np.argsort(v, kind="stable")
    cw = np.cumsum(w[order])
    return float(v[order][min(np.searchsorted(cw, q / 100.0 * cw[-1]), len(v) - 1)])


@settings(max_examples=300, deadline=None)
@given(
    st.lists(st.tuples(st.integers(0, 12), st.integers(0, 4)), min_size=1, max_size=200),
    st.one_of(st.sampled_from([0.0, 25.0, 50.0, 95.0, 100.0]), st.floats(0.0, 100.0)),
    st.sampled_from([np.float32, np.float64]),
)
# the target exactly at the weight of the smallest value: with weights / 3, the tied values'
# weights must add up in their order, as in the definition
@example(
    [
        (0, 0),
        (0, 1),
        (0, 1),
        (0, 2),
        (0, 3),
        (0, 3),
        (1, 1),
        (1, 2),
        (1, 2),
        (0, 1),
        (0, 3),
        (1, 2),
        (1, 3),
        (1, 4),
        (1, 2),
    ],
    25.0,
    np.float32,
)
def test_weighted_percentile_narrowing_is_the_sort(pairs, q, dtype):
    """Narrowing around partition pivots (forced down to a few values) picks the value the
    sort picks, with ties, zero weights and voxel-count weights."""
    import octofuse.maps.compare as cmp

    v = np.array([p[0] / 4.0 for p in pairs], dtype=dtype)
    w = np.array([0.0 if p[1] == 0 else 8.0 ** (p[1] - 1) for p in pairs])
    if w.sum() == 0:
        w[0] = 1.0
    want = _sorted_weighted_percentile(v, w, q)
    for below in (1, 8, cmp.SORT_BELOW):
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(cmp, "SORT_BELOW", below)
            assert weighted_percentile(v, w, q) == want
    # weights that are not whole numbers are sorted, as the definition does
    assert weighted_percentile(v, w / 3.0, q) == _sorted_weighted_percentile(v, w / 3.0, q)


@pytest.mark.parametrize("corner", [[0.0, 1.0], [0.0, float("nan"), 1.0], [0.0, float("inf"), 1.0]])
def test_a_scene_file_with_a_bad_corner_is_refused_by_name(tmp_path, corner):
    path = tmp_path / "bad_scene.json"
    path.write_text(json.dumps({"boxes": [{"min": corner, "max": [1.0, 2.0, 3.0]}]}))
    with pytest.raises(
        ValueError, match="bad_scene.json.*box 1: min and max must be 3 finite numbers"
    ):
        Scene.load(path)
