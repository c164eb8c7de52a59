"""``octofuse build`` on the real recorded bags in ``../shared/data/real`` (skipped if absent).

* ``intel_4agents.bag``: 910 real 2D scans cut into 4 agents, tf ``map -> robotK/base_link
  -> robotK/laser`` (laser 0.3 m up): 4 agent maps and the centralized map.
* ``luminar_pointcloud2.bag``: 5 real Luminar clouds in frame ``luminar_lidar`` with no pose
  for the lidar: no /tf or /tf_static at all, so asking for any fixed frame is a clear error
  saying so. The bag's only pose topic (``/base_pose_ground_truth``, a simulator's Odometry on
  a 60 s clock) places the simulator's own ``/base_scan``, but not the clouds, whose stamps
  (2020) lie after its last sample: every cloud is skipped and counted with that reason.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bagfactory as bf  # noqa: E402
from bagfactory import run_cli  # noqa: E402
from octofuse import OccupancyMap  # noqa: E402


def real_bag(shared_real: Path, name: str) -> Path:
    p = shared_real / name
    if not p.is_file():
        pytest.skip(f"{name} not present in {shared_real}")
    return p


def test_intel_four_agents(shared_real, tmp_path, capsys):
    bag = real_bag(shared_real, "intel_4agents.bag")
    out = tmp_path / "maps"
    code, stdout, err = run_cli(
        capsys, "build", bag, "--fixed-frame", "map", "--resolution", "0.1", "--out", out
    )
    assert code == 0, err
    names = [f"robot{k}" for k in range(1, 5)]
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [".octofuse-output", *(f"{n}.ot" for n in [*names, "centralized"])]
    )
    used = {n: int(re.search(rf"{n}\W+/{n}/scan\W+(\d+)\W+0\W", stdout).group(1)) for n in names}
    assert sum(used.values()) == 910 and min(used.values()) >= 220
    assert re.search(r"centralized\W+\(all\)\W+910\W+0\W", stdout)
    maps = {p.stem: OccupancyMap.load(p) for p in out.glob("*.ot")}
    leaves = {n: m.num_leaves for n, m in maps.items()}
    for n in names:
        assert 10_000 < leaves[n] < 200_000, leaves
        v = maps[n].leaves().values
        assert (v > 0).sum() > 1_000 and (v < 0).sum() > 5_000
    # the agents overlap: the union is larger than each part and smaller than their sum
    assert max(leaves[n] for n in names) < leaves["centralized"] < sum(leaves[n] for n in names)
    # planar data: one slice of voxels around the laser height, 0.3 m
    centers, _ = bf.finest_voxels(maps["centralized"])
    assert np.abs(centers[:, 2] - 0.3).max() <= 0.1
    # the building is about 30 m across
    extent = centers[:, :2].max(axis=0) - centers[:, :2].min(axis=0)
    assert ((extent > 15) & (extent < 80)).all(), extent


def test_luminar_cloud_has_no_pose(shared_real, tmp_path, capsys):
    bag = real_bag(shared_real, "luminar_pointcloud2.bag")
    out = tmp_path / "maps"
    code, stdout, err = run_cli(
        capsys, "build", bag, "--fixed-frame", "luminar_lidar", "--out", out
    )
    assert code == 1
    assert err.strip().splitlines() == [
        "error: fixed frame 'luminar_lidar' is not in the bags' transforms; frames present: "
        "none (no /tf, /tf_static or pose topic)"
    ]
    assert not out.exists()

    # the ground-truth Odometry places the simulator's LaserScan ...
    code, stdout, err = run_cli(
        capsys,
        "build",
        bag,
        "--agent",
        "base=/base_scan",
        "--pose",
        "base=/base_pose_ground_truth",
        "--fixed-frame",
        "odom",
        "--resolution",
        "0.1",
        "--out",
        tmp_path / "base",
    )
    assert code == 0, err
    assert re.search(r"base\W+/base_scan\W+5\W+0\W", stdout)
    assert OccupancyMap.load(tmp_path / "base" / "base.ot").num_leaves > 500

    # ... but its clock is not the lidar's: each cloud is after its last sample, and a
    # build that places no scan at all is an error that says why (and writes nothing)
    code, stdout, err = run_cli(
        capsys,
        "build",
        bag,
        "--agent",
        "lidar=/luminar_pointcloud",
        "--pose",
        "lidar=/base_pose_ground_truth",
        "--fixed-frame",
        "odom",
        "--resolution",
        "0.1",
        "--out",
        tmp_path / "lidar",
    )
    assert code == 1
    assert len(err.strip().splitlines()) == 1
    assert "no scan" in err and "lidar: 5 after the last transform" in err
    assert not (tmp_path / "lidar").exists()
