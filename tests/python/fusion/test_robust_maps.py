"""Robust fusion on maps: 2-D registration of occupied voxels, the neighbour-offset measurement,
and a run in which the robots vote out the one whose poses are biased."""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import REPO
from doc_figures import assert_as_printed, benchmark, quoted
from octofuse.config import FuseConfig, RobustConfig, RunConfig, from_dict
from octofuse.maps.alignment import (
    ABSTAIN_VARIANCE,
    map_points,
    neighbour_offset,
    occupied_points,
    register,
)
from octofuse.maps.build import insert_scans, make_build_config
from octofuse.maps.occupancy import OccupancyMap
from octofuse.scans.source import ScanSource

GENERATOR = REPO / "data" / "generate_lab.py"
BIAS = [
    "--bias-robot",
    "3",
    "--bias-offset",
    "0.4",
    "-0.2",
    "--bias-yaw",
    "3",
    "--bias-drift",
    "0.002",
    "0.001",
    "--bias-yaw-drift",
    "0.01",
]


@pytest.fixture(scope="module")
def lab_bag(tmp_path_factory) -> Path:
    """60 s of the simulated lab at 1 scan/s, robot 3's poses biased."""
    out = tmp_path_factory.mktemp("lab") / "lab_bias.bag"
    subprocess.run(
        [
            sys.executable,
            str(GENERATOR),
            "--duration",
            "60",
            "--rate",
            "1",
            "--out",
            str(out),
            *BIAS,
        ],
        check=True,
        stdout=subprocess.DEVNULL,
    )
    return out


def _pose_shift(dx: float, dy: float, yaw_deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    return np.array([[c, -s, 0, dx], [s, c, 0, dy], [0, 0, 1, 0], [0, 0, 0, 1.0]])


@pytest.fixture(scope="module")
def maps(lab_bag):
    """Maps of robots 7 and 8 (correctly localised, they overlap): robot 8 from its even and
    from its odd scans, robot 7 from all, and robot 8's even scans with every pose moved by a
    known rigid transform (a shifted copy of the map)."""
    cfg = make_build_config(
        lab_bag, agents=["robot7=/robot7/scan", "robot8=/robot8/scan"], threads=1
    )
    out = {k: OccupancyMap.from_config(cfg.map) for k in ("even", "odd", "other", "shifted")}
    shift = _pose_shift(0.3, -0.2, 4.0)
    with ScanSource(cfg) as src:
        count = 0
        for scan in src.scans():
            if scan.agent == 0:
                insert_scans([scan], [[out["other"]]], 1)
                continue
            key = "even" if count % 2 == 0 else "odd"
            insert_scans([scan], [[out[key]]], 1)
            if key == "even":
                moved = dataclasses.replace(scan, pose=shift @ scan.pose)
                insert_scans([moved], [[out["shifted"]]], 1)
            count += 1
    return out


def _expected_inverse(dx, dy, yaw_deg):
    """The registration ``(dx, dy, yaw)`` that undoes a shift ``p -> R(yaw) (p - c) + c + (dx, dy)``
    (about the same pivot ``c``)."""
    a = math.radians(yaw_deg)
    c, s = math.cos(a), math.sin(a)
    back = -np.array([[c, s], [-s, c]]) @ np.array([dx, dy])
    return np.array([back[0], back[1], -a])


def test_occupied_points_keep_walls_and_drop_floor_and_free_space():
    m = OccupancyMap(0.1)
    wall = np.array([[2.05, y, z] for y in np.arange(-0.95, 1.0, 0.1) for z in (0.25, 0.55)])
    floor = np.array([[x, 0.05, -0.05] for x in np.arange(0.25, 1.9, 0.1)])
    for _ in range(3):
        m.insert_scan(np.vstack([wall, floor]), (0.05, 0.05, 0.45))
    pts = map_points(m)
    assert len(pts) == 20  # one column per wall cell; no floor, no free voxel
    np.testing.assert_allclose(pts[:, 0], 2.05)
    lv = m.leaves()
    assert len(occupied_points(lv.centers, lv.sizes, lv.values, 0.1, clearance=0.6)) == 0


@pytest.mark.slow
@pytest.mark.parametrize("shift", [(0.0, 0.0, 0.0), (0.25, -0.15, 2.0), (-0.4, 0.3, -5.0)])
def test_register_recovers_a_known_transform(maps, shift):
    target = map_points(maps["even"])
    dx, dy, yaw = shift
    c, s = math.cos(math.radians(yaw)), math.sin(math.radians(yaw))
    pivot = target.mean(axis=0)
    source = (target - pivot) @ np.array([[c, -s], [s, c]]).T + pivot + [dx, dy]
    reg = register(source, target, pivot=pivot)
    assert reg is not None and reg.pairs > 0.3 * len(target)  # line-like neighbourhoods only
    np.testing.assert_allclose(reg.params, _expected_inverse(dx, dy, yaw), atol=1e-4)
    np.testing.assert_allclose(reg.apply(source, pivot), target, atol=1e-3)
    sd = np.sqrt(np.diag(reg.covariance))
    assert np.all(sd > 0) and sd[0] < 0.05 and sd[2] < math.radians(1)


def test_register_gives_up_on_a_single_wall_and_on_too_few_points():
    line = np.column_stack([np.arange(0, 5, 0.05), np.zeros(100)])
    assert register(line + [0.0, 0.1], line) is None
    assert register(line[:10], line) is None


@pytest.mark.slow
def test_shifted_copy_of_a_map_measures_the_shift(maps):
    shifted, even, odd, other = (map_points(maps[k]) for k in ("shifted", "even", "odd", "other"))
    x, cov, used = neighbour_offset(shifted, [odd, other])
    assert used == [0, 1]
    # the registration undoes the pose shift, written about the centroid of the shifted points
    a = -math.radians(4.0)
    c_ = shifted.mean(axis=0)
    inv = _expected_inverse(0.3, -0.2, 4.0)
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    want_t = rot @ c_ + inv[:2] - c_  # the same transform written about the centroid
    assert x[2] == pytest.approx(a, abs=math.radians(0.5))
    np.testing.assert_allclose(x[:2], want_t, atol=0.05)
    # the unshifted map agrees with its neighbours
    x0, cov0, used0 = neighbour_offset(even, [odd, other])
    assert used0 == [0, 1]
    assert np.hypot(*x0[:2]) < 0.05 and abs(x0[2]) < math.radians(0.5)
    d = x - x0
    assert d @ np.linalg.solve(cov + cov0, d) > 100  # far outside each other's uncertainty


@pytest.mark.slow
def test_no_majority_means_abstaining(maps):
    even, odd, shifted = (map_points(maps[k]) for k in ("even", "odd", "shifted"))
    x, cov, used = neighbour_offset(even, [odd, shifted])  # one says 0, one says the shift
    assert used == [] and np.all(x == 0) and cov[0, 0] == ABSTAIN_VARIANCE
    x, cov, used = neighbour_offset(even, [odd])  # a single neighbour is no majority
    assert used == []


def test_robust_fields_are_validated():
    cfg = from_dict(RunConfig, {"fuse": {"robust": {"enabled": True, "time": 30, "p_in": 0.7}}})
    r = cfg.fuse.robust
    assert r.enabled and r.time == 30.0 and r.hold and r.p_in == 0.7
    for key, bad in [
        ("p_in", 1.0),
        ("confidence", 0.0),
        ("time", -1.0),
        ("iterations", 0),
        ("success", 1.5),
    ]:
        with pytest.raises(ValueError, match=key):
            from_dict(RunConfig, {"fuse": {"robust": {key: bad}}})
    with pytest.raises(ValueError, match="robust"):
        from_dict(RunConfig, {"fuse": {"robust": {"enabled": "yes"}}})


@pytest.mark.slow
def test_the_biased_robot_is_voted_out_and_not_fused(lab_bag, tmp_path):
    from octofuse.fusion.simulate import simulate
    from octofuse.outputs.report import write_outputs

    bcfg = make_build_config(lab_bag, threads=1)
    fcfg = FuseConfig(
        rules=["min-info-loss"],
        topology="max-robust:3",
        schedule="periodic:10",
        robust=RobustConfig(enabled=True, time=50.0),
    )
    res = simulate(bcfg, fcfg, samples=0)
    out = res.robust
    assert res.excluded == ["robot3"] and out.excluded == ["robot3"]
    i = res.agents.index("robot3")
    assert not out.abstained[i] and not out.inliers[i]
    assert np.hypot(*out.measurements[i, :2]) > 0.3 and abs(np.degrees(out.measurements[i, 2])) > 2
    assert out.alignment_bytes > 0 and out.voting_bytes > 0
    tr = res.traffic["min-info-loss"]
    assert tr.sent["robot3"] == 0 and tr.received["robot3"] > 0  # it keeps fusing the others
    assert all(tr.sent[a] > 0 for a in res.agents if a != "robot3")

    cfg = RunConfig(build=bcfg, fuse=fcfg)
    paths = write_outputs(res, tmp_path, cfg, export_agents=[], heatmaps=False)
    report = paths["report"].read_text()
    assert "## Robust fusion" in report and "excluded robots: `robot3`" in report
    assert report.count("**excluded**") == 1

    plain = simulate(bcfg, dataclasses.replace(fcfg, robust=RobustConfig()), samples=0)
    assert plain.robust is None and plain.excluded == []
    assert plain.traffic["min-info-loss"].sent["robot3"] > 0


@pytest.mark.slow
def test_the_lab_figures_of_the_docs_are_what_the_benchmark_measures(tmp_path):
    """docs/robust.md's measured paragraph, from one run of benchmarks/robust_lab.py."""
    lab = benchmark("robust_lab")
    bias, run = lab.BIAS, lab.RUN
    bag = lab.generate(tmp_path / "biased.bag", **bias)
    biased = f"robot{bias['robot']}"
    rows, runs = lab.measure(bag, biased, **run, threads=2)
    row = {(r["rule"], r["mode"]): r for r in rows}
    vote = runs["on"].robust
    assert vote.excluded == [biased] and runs["on, no hold"].excluded == [biased]
    m = vote.measurements[vote.agents.index(biased)]

    page = "docs/robust.md"
    figures, measured = {}, {}

    def check(names, pattern, values):
        figures.update(zip(names, quoted(page, pattern)))
        measured.update(zip(names, values))

    check(
        ["dx", "dy", "yaw"],
        r"robot 3 measured \(# m, \+# m, # degrees\) and was voted out, nobody else was",
        [m[0], m[1], np.degrees(m[2])],
    )
    mil, mil_on = row["min-info-loss", "off"], row["min-info-loss", "on"]
    ch, ch_on = row["chernoff", "off"], row["chernoff", "on"]
    check(
        ["kl", "kl on", "occ", "occ on", "surface", "surface on", "ch kl", "ch kl on"],
        r"min-info-loss: KL # -> #, occupied-voxel agreement #% -> #%, occupied voxels on a "
        r"true surface #% -> #%; chernoff: KL # -> #\.",
        [
            mil["kl"],
            mil_on["kl"],
            100 * mil["occupied_agreement"],
            100 * mil_on["occupied_agreement"],
            100 * mil["on_surface"],
            100 * mil_on["on_surface"],
            ch["kl"],
            ch_on["kl"],
        ],
    )
    check(
        ["total", "points", "voting", "maps"],
        r"The vote cost # MB in all \(map points # MB, voting messages # MB\) against # MB of "
        r"min-info-loss's map messages",
        [
            vote.total_bytes / 1e6,
            vote.alignment_bytes / 1e6,
            vote.voting_bytes / 1e6,
            mil_on["mb_sent"],
        ],
    )
    check(["no hold"], r"the gain is small \(KL #\)", [row["min-info-loss", "on, no hold"]["kl"]])
    assert_as_printed(measured, figures, page)
