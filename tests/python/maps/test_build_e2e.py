"""End to end: ``octofuse build`` on small bags of a known scene written with rosbags.

Every map is compared leaf by leaf with a map made by inserting the same scans, in log-time
order, at their true poses with ``OccupancyMap.insert_scan_from_sensor``, and checked against
the geometry of the scene (occupied voxels on faces, free voxels outside solids).
"""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bagfactory as bf  # noqa: E402
from bagfactory import KINDS, LAYOUTS, T0, Recording, Robot, S, run_cli  # noqa: E402
from conftest import REPO  # noqa: E402
from octofuse import OccupancyMap  # noqa: E402
from octofuse.config import AgentSpec, BuildConfig, MapConfig, RunConfig, load_yaml  # noqa: E402
from octofuse.maps.build import build, build_maps, make_build_config  # noqa: E402
from octofuse.scans.tf_bags import POSE_TYPES  # noqa: E402

pytestmark = pytest.mark.slow

RES = "0.1"


def lidar_robot(**kw) -> Robot:
    """Drives +x through the room's west half while turning left; map -> odom is not identity."""
    args = dict(
        start=(-1.9, 0.13, 0.1),
        velocity=(0.6, 0.05, 0.3),
        odom=(0.2, 0.1, 0.05),
        mount=(0.1, 0.05, 0.65, 0.1),
    )
    args.update(kw)
    return Robot("r1", **args)


def laser_robot(**kw) -> Robot:
    """A LaserScan robot in the east half, backing up while turning right."""
    args = dict(
        start=(1.9, -1.1, 2.0),
        velocity=(-0.3, 0.2, -0.2),
        odom=(-0.1, 0.05, -0.1),
        mount=(0.1, 0.0, 0.55, 0.2),
        sensor="laser",
    )
    args.update(kw)
    return Robot("r2", **args)


def times(offset: float, n: int = 4) -> list[int]:
    """n scan stamps, 0.5 s apart, starting ``offset`` s after T0 (between the 2 Hz tf samples)."""
    return [T0 + int(round((offset + 0.5 * k) * S)) for k in range(n)]


AGENTS2 = {"r1": "/r1/points", "r2": "/r2/scan"}


def two_robots(**scan_kw) -> Recording:
    return bf.robot_recording(
        [lidar_robot(), laser_robot()], {"r1": times(0.25), "r2": times(0.125)}, **scan_kw
    )


def build_cli(capsys, bags, out, *extra):
    bags = bags if isinstance(bags, (list, tuple)) else [bags]
    code, stdout, err = run_cli(
        capsys, "build", *bags, "--fixed-frame", "map", "--resolution", RES, "--out", out, *extra
    )
    assert code == 0, err
    assert "Traceback" not in err
    return stdout


def load_maps(out: Path) -> dict[str, OccupancyMap]:
    return {p.stem: OccupancyMap.load(p) for p in sorted(out.glob("*.ot"))}


def table_row(stdout: str, name: str, topic: str) -> tuple[int, int]:
    """(scans used, skipped) of one row of the summary table."""
    m = re.search(rf"{re.escape(name)}\W+{re.escape(topic)}\W+(\d+)\W+(\d+)\W", stdout)
    assert m, f"no row for {name} in:\n{stdout}"
    return int(m.group(1)), int(m.group(2))


# -- bag formats and several inputs -----------------------------------------------------------


@pytest.mark.parametrize("kind", KINDS)
def test_every_bag_format_gives_the_reference_maps(tmp_path, capsys, kind):
    rec = two_robots()
    bag = rec.write(tmp_path / "run", kind)
    out = tmp_path / "maps"
    stdout = build_cli(capsys, bag, out)
    assert sorted(p.name for p in out.iterdir()) == [
        ".octofuse-output",
        "centralized.ot",
        "r1.ot",
        "r2.ot",
    ]
    assert "wrote 3 maps" in stdout
    assert table_row(stdout, "r1", "/r1/points") == (4, 0)
    assert table_row(stdout, "r2", "/r2/scan") == (4, 0)
    got = load_maps(out)
    for name, want in bf.reference_maps(rec.shots, AGENTS2).items():
        bf.assert_same_map(got[name], want, name)
    check = bf.check_scene(got["centralized"])
    assert check.occupied > 500 and check.free > 5000
    # the laser agent's map is one slice at the laser's height
    centers, _ = bf.finest_voxels(got["r2"])
    np.testing.assert_allclose(centers[:, 2], 0.55, atol=1e-9)


def test_one_bag_per_robot_merged_in_time_order(tmp_path, capsys):
    r1, r2 = lidar_robot(), laser_robot()
    r3 = Robot("r3", start=(-0.2, -1.5, 0.3), velocity=(0.4, 0.1, 0.4), mount=(0.0, 0.0, 0.75, 0.0))
    recs = {
        "ros1": bf.robot_recording([r1], {"r1": times(0.25)}),
        "sqlite3": bf.robot_recording([r2], {"r2": times(0.125)}),
        "bare_mcap": bf.robot_recording([r3], {"r3": times(0.375)}, layout="float32"),
    }
    bags = [rec.write(tmp_path / f"robot_{kind}", kind) for kind, rec in recs.items()]
    assert [b.name for b in bags] == ["robot_ros1.bag", "robot_sqlite3", "robot_bare_mcap.mcap"]
    out = tmp_path / "maps"
    stdout = build_cli(capsys, bags, out)
    got = load_maps(out)
    assert sorted(got) == ["centralized", "r1", "r2", "r3"]
    shots = [s for rec in recs.values() for s in rec.shots]
    agents = {**AGENTS2, "r3": "/r3/points"}
    want = bf.reference_maps(shots, agents)
    for name in agents:
        bf.assert_same_map(got[name], want[name], name)
        assert table_row(stdout, name, agents[name]) == (4, 0)
    # the scans interleave across the bags; inserted robot by robot the result differs
    stamps = [s.stamp_ns for s in sorted(shots, key=lambda s: s.log_ns)]
    assert [next(s.topic for s in shots if s.stamp_ns == t) for t in stamps[:3]] == [
        "/r2/scan",
        "/r1/points",
        "/r3/points",
    ]
    bf.assert_same_map(got["centralized"], want["centralized"], "centralized")
    by_robot = OccupancyMap(0.1)
    for s in shots:  # r1's scans, then r2's, then r3's
        by_robot.insert_scan_from_sensor(s.points, s.pose)
    assert bf.maps_differ(by_robot, want["centralized"])
    bf.check_scene(got["centralized"])


# -- PointCloud2 layouts ----------------------------------------------------------------------


@pytest.mark.parametrize("layout", list(LAYOUTS))
def test_pointcloud2_layouts(tmp_path, layout):
    robot = lidar_robot()
    rec = bf.robot_recording([robot], {"r1": times(0.25, 2)}, layout=layout)
    kind = KINDS[list(LAYOUTS).index(layout) % len(KINDS)]
    bag = rec.write(tmp_path / "cloud", kind)
    cfg = make_build_config(bag, fixed_frame="map", resolution=0.1)
    result = build(cfg)
    (st,) = result.stats
    assert (st.name, st.scans_used, st.scans_skipped) == ("r1", 2, 0)
    assert st.points == sum(len(s.points) for s in rec.shots)
    grid = bf.lidar_directions().shape[0] * bf.lidar_directions().shape[1]
    assert all(len(s.points) < grid for s in rec.shots)  # beams past 4 m have no return
    bf.assert_same_map(result.maps["r1"], bf.reference_map(rec.shots), layout)
    bf.assert_same_map(result.centralized, result.maps["r1"], layout)
    bf.check_scene(result.centralized)


# -- LaserScan: NaN, inf and --no-return ------------------------------------------------------


def test_laserscan_no_return_free_clears_up_to_range_max(tmp_path, capsys):
    robot = laser_robot(start=(0.3, -0.6, 0.4), velocity=(0.0, 0.0, 0.0), odom=(0.0, 0.0, 0.0))
    rec = bf.Recording()
    rec.robot_tf(robot, [T0, T0 + S])
    range_max = 2.0
    shot = rec.robot_scan(robot, T0 + S // 4, beams=12, range_max=range_max, nan_beams=(1,))
    bag = rec.write(tmp_path / "laser", "mcap")
    assert 2 <= len(shot.free_dirs) and len(shot.points) + len(shot.free_dirs) == 11
    maps = {}
    for mode in ("skip", "free"):
        build_cli(capsys, bag, tmp_path / mode, "--no-return", mode)
        maps[mode] = OccupancyMap.load(tmp_path / mode / "r2.ot")
    # skip (the default) ignores the no-return beams: just the hits
    bf.assert_same_map(maps["skip"], bf.reference_map([shot]), "skip")
    default = tmp_path / "default"
    build_cli(capsys, bag, default)
    bf.assert_same_map(OccupancyMap.load(default / "r2.ot"), maps["skip"], "default")
    # the no-return beam whose wall is farthest away
    origin, rot = shot.pose[:3, 3], shot.pose[:3, :3]
    dirs = shot.free_dirs @ rot.T
    walls = rec.scene.raycast(origin, dirs)
    d = dirs[np.argmax(walls)]
    assert walls.max() > range_max + 0.6
    inside = origin + np.arange(0.8, range_max - 0.1, 0.05)[:, None] * d
    beyond = origin + np.arange(range_max + 0.15, range_max + 0.6, 0.05)[:, None] * d
    assert np.isnan(bf.values_at(maps["skip"], inside)).all()
    assert (bf.values_at(maps["free"], inside) < 0).all()
    assert np.isnan(bf.values_at(maps["free"], beyond)).all()
    assert np.isnan(bf.values_at(maps["skip"], beyond)).all()
    # the hits are the same; free space only grew
    occ = {m: bf.finest_voxels(maps[m]) for m in maps}
    np.testing.assert_array_equal(*(np.sort(c[v > 0], axis=0) for c, v in occ.values()))
    assert (occ["free"][1] < 0).sum() > (occ["skip"][1] < 0).sum() + 30
    bf.check_scene(maps["free"])
    # nothing is known farther than range_max from the laser
    c, _ = occ["free"]
    assert np.linalg.norm(c - origin, axis=1).max() < range_max + 0.1


# -- tf chains and poses ----------------------------------------------------------------------


def test_tf_chain_is_interpolated_between_samples(tmp_path, capsys):
    """map -> odom (static) -> base_link (2 Hz) -> lidar (static); scans between the samples."""
    robot = lidar_robot()
    stamps = times(0.25)
    rec = bf.robot_recording([robot], {"r1": stamps})
    tf_stamps = [T0 + k * S // 2 for k in range(5)]
    assert all(t not in tf_stamps for t in stamps)
    bag = rec.write(tmp_path / "moving", "ros1")
    out = tmp_path / "maps"
    build_cli(capsys, bag, out)
    got = OccupancyMap.load(out / "r1.ot")
    bf.assert_same_map(got, bf.reference_map(rec.shots), "interpolated")
    bf.check_scene(got)

    # the pose of the nearest tf sample is 0.15 m and 4 degrees off: a clearly different map
    def nearest(shot):
        return robot.sensor_pose(min(tf_stamps, key=lambda t: abs(t - shot.stamp_ns)))

    wrong = bf.reference_map(rec.shots, poses=nearest)
    assert bf.maps_differ(got, wrong)
    assert bf.check_scene(wrong, strict=False).worst_occupied > 0.1


def test_scans_outside_the_tf_time_range_are_skipped_and_counted(tmp_path, capsys):
    robot = lidar_robot()
    rec = Recording()
    rec.robot_tf(robot, [T0 + k * S // 2 for k in range(1, 5)])  # 100.5 s ... 102 s
    shots = [rec.robot_scan(robot, T0 + int(t * S)) for t in (0.25, 0.75, 1.25, 2.25)]
    bag = rec.write(tmp_path / "late_tf", "mcap")
    out = tmp_path / "maps"
    stdout = build_cli(capsys, bag, out)
    assert table_row(stdout, "r1", "/r1/points") == (2, 2)
    lines = stdout.splitlines()
    assert "r1: skipped 1 scan(s): before the first transform" in lines
    assert "r1: skipped 1 scan(s): after the last transform" in lines
    bf.assert_same_map(OccupancyMap.load(out / "r1.ot"), bf.reference_map(shots[1:3]), "r1")


def test_scan_with_empty_frame_id_is_skipped_and_counted(tmp_path, capsys):
    robot = lidar_robot()
    rec = bf.robot_recording([robot], {"r1": times(0.25, 3)})
    t = T0 + S
    rec.cloud(robot.topic, "", t, robot.sensor_pose(t))
    bag = rec.write(tmp_path / "no_frame", "sqlite3")
    out = tmp_path / "maps"
    stdout = build_cli(capsys, bag, out)
    assert table_row(stdout, "r1", "/r1/points") == (3, 1)
    assert "r1: skipped 1 scan(s): empty header.frame_id" in stdout.splitlines()
    bf.assert_same_map(OccupancyMap.load(out / "r1.ot"), bf.reference_map(rec.shots[:3]), "r1")


POSE_WRITERS = {  # each pose message type --pose reads, and how a recording writes it
    "nav_msgs/msg/Odometry": lambda rec, t, pose: rec.odometry(
        "/r1/pose", t, pose, frame="map", child="r1/base_link"
    ),
    "geometry_msgs/msg/PoseStamped": lambda rec, t, pose: rec.pose_stamped("/r1/pose", t, pose),
    "geometry_msgs/msg/PoseWithCovarianceStamped": lambda rec, t, pose: rec.pose_with_covariance(
        "/r1/pose", t, pose
    ),
    "geometry_msgs/msg/TransformStamped": lambda rec, t, pose: rec.transform(
        "/r1/pose", t, pose, child="r1/base_link"
    ),
}


def test_pose_writers_cover_every_pose_type():
    assert sorted(POSE_WRITERS) == sorted(POSE_TYPES)


@pytest.mark.parametrize("msgtype", sorted(POSE_WRITERS))
def test_pose_topic_instead_of_tf(tmp_path, capsys, msgtype):
    # a constant heading: the sensor offset then moves rigidly with the pose samples
    robot = lidar_robot(velocity=(0.5, 0.1, 0.0), start=(-1.9, 0.13, 0.3), odom=(0.0, 0.0, 0.0))
    rec = Recording()
    for k in range(5):
        POSE_WRITERS[msgtype](rec, T0 + k * S // 2, robot.base_pose(T0 + k * S // 2))
    for t in times(0.25):
        rec.robot_scan(robot, t)
    bag = rec.write(tmp_path / "poses", "ros1")
    topic = "/r1/pose"
    x, y, z, yaw = robot.mount
    offset = ",".join(f"{v:.17g}" for v in (x, y, z, *bf.yaw_quaternion(yaw)))
    out = tmp_path / "maps"
    stdout = build_cli(
        capsys,
        bag,
        out,
        "--agent",
        "front=/r1/points",
        "--pose",
        f"front={topic}",
        "--sensor-offset",
        f"front={offset}",
    )
    assert table_row(stdout, "front", "/r1/points") == (4, 0)
    got = load_maps(out)
    assert sorted(got) == ["centralized", "front"]
    bf.assert_same_map(got["front"], bf.reference_map(rec.shots), "front")
    bf.check_scene(got["front"])
    # without the offset the lidar would sit on the floor at the robot's origin
    bare = tmp_path / "bare"
    build_cli(capsys, bag, bare, "--agent", "front=/r1/points", "--pose", f"front={topic}")
    assert bf.check_scene(OccupancyMap.load(bare / "front.ot"), strict=False).worst_occupied > 0.1


# -- options ----------------------------------------------------------------------------------


def test_every_nth_scan(tmp_path, capsys):
    rec = two_robots()
    bag = rec.write(tmp_path / "run", "mcap")
    out = tmp_path / "maps"
    stdout = build_cli(capsys, bag, out, "--every", "2")
    assert table_row(stdout, "r1", "/r1/points") == (2, 0)
    assert table_row(stdout, "r2", "/r2/scan") == (2, 0)
    kept = [
        s for topic in AGENTS2.values() for s in [x for x in rec.shots if x.topic == topic][::2]
    ]
    got = load_maps(out)
    for name, want in bf.reference_maps(kept, AGENTS2).items():
        bf.assert_same_map(got[name], want, name)


def test_max_range(tmp_path, capsys):
    rec = two_robots()
    bag = rec.write(tmp_path / "run", "sqlite3")
    full = tmp_path / "full"
    build_cli(capsys, bag, full)
    out = tmp_path / "maps"
    build_cli(capsys, bag, out, "--max-range", "1.5")
    got = load_maps(out)
    for name, want in bf.reference_maps(rec.shots, AGENTS2, max_range=1.5).items():
        bf.assert_same_map(got[name], want, name)
    c, v = bf.finest_voxels(got["centralized"])
    origins = np.array([s.pose[:3, 3] for s in rec.shots])
    reach = np.linalg.norm(c[:, None, :] - origins[None], axis=2).min(axis=1)
    assert reach.max() < 1.5 + 0.1 * math.sqrt(3)
    n_occ = (v > 0).sum()
    _, v_full = bf.finest_voxels(OccupancyMap.load(full / "centralized.ot"))
    assert 50 < n_occ < (v_full > 0).sum() / 2
    bf.check_scene(got["centralized"])


def test_config_file_and_dump_config(tmp_path, capsys):
    rec = two_robots()
    # a long path: the dumped YAML must keep it on one line
    deep = tmp_path / ("d" * 80) / ("e" * 60)
    deep.mkdir(parents=True)
    bag = rec.write(deep / "run", "ros1")
    cfg_file = tmp_path / "octofuse.yaml"
    cfg_file.write_text(
        yaml.safe_dump(
            {
                "build": {
                    "bags": str(bag),  # one bag needs no list
                    "agents": [
                        {"name": "cloud", "topic": "/r1/points"},
                        {"name": "laser", "topic": "/r2/scan"},
                    ],
                    "fixed_frame": "map",
                    "map": {"resolution": 0.1},
                    "max_range": 3.0,
                    "scan_stride": 2,
                }
            }
        )
    )
    out = tmp_path / "maps"
    code, stdout, err = run_cli(capsys, "build", "--config", cfg_file, "--out", out)
    assert code == 0, err
    assert table_row(stdout, "cloud", "/r1/points") == (2, 0)
    kept = [s for t in AGENTS2.values() for s in [x for x in rec.shots if x.topic == t][::2]]
    want = bf.reference_maps(kept, {"cloud": "/r1/points", "laser": "/r2/scan"}, max_range=3.0)
    got = load_maps(out)
    for name in want:
        bf.assert_same_map(got[name], want[name], name)

    # --dump-config: defaults + file + flags (flags win); it loads back to the same config
    code, dumped, err = run_cli(
        capsys,
        "build",
        "--config",
        cfg_file,
        "--every",
        "1",
        "--no-return",
        "free",
        "--dump-config",
    )
    assert code == 0 and err == ""
    expected = RunConfig(
        build=BuildConfig(
            bags=[str(bag)],
            agents=[AgentSpec("cloud", "/r1/points"), AgentSpec("laser", "/r2/scan")],
            fixed_frame="map",
            map=MapConfig(resolution=0.1),
            max_range=3.0,
            no_return="free",
            scan_stride=1,
        )
    )
    dump_file = tmp_path / "dumped.yaml"
    dump_file.write_text(dumped)
    assert load_yaml(dump_file) == expected
    code, again, _ = run_cli(capsys, "build", "--config", dump_file, "--dump-config")
    assert code == 0 and again == dumped
    # the dumped file builds the same maps as the flags it stands for
    out2 = tmp_path / "maps2"
    code, _, err = run_cli(capsys, "build", "--config", dump_file, "--out", out2)
    assert code == 0, err
    flags = tmp_path / "maps3"
    build_cli(
        capsys,
        bag,
        flags,
        "--agent",
        "cloud=/r1/points",
        "--agent",
        "laser=/r2/scan",
        "--max-range",
        "3",
        "--no-return",
        "free",
    )
    for name in ("cloud", "laser", "centralized"):
        assert (out2 / f"{name}.ot").read_bytes() == (flags / f"{name}.ot").read_bytes()


def test_build_maps_api(tmp_path):
    rec = two_robots()
    bag = rec.write(tmp_path / "run", "mcap")
    maps = build_maps(
        bag,
        agents=["cloud=/r1/points", AgentSpec("laser", "/r2/scan")],
        fixed_frame="map",
        resolution=0.1,
    )
    assert sorted(maps) == ["centralized", "cloud", "laser"]
    assert all(isinstance(m, OccupancyMap) and m.resolution == 0.1 for m in maps.values())
    want = bf.reference_maps(rec.shots, {"cloud": "/r1/points", "laser": "/r2/scan"})
    for name in want:
        bf.assert_same_map(maps[name], want[name], name)
    # default agents: one per scan topic, named after its namespace; options pass through
    maps = build_maps([str(bag)], fixed_frame="map", resolution=0.1, max_range=2.0, scan_stride=2)
    assert sorted(maps) == ["centralized", "r1", "r2"]
    kept = [s for t in AGENTS2.values() for s in [x for x in rec.shots if x.topic == t][::2]]
    bf.assert_same_map(
        maps["centralized"],
        bf.reference_maps(kept, AGENTS2, max_range=2.0)["centralized"],
        "options",
    )


# -- a real process ---------------------------------------------------------------------------


def octofuse_command() -> list[str]:
    for exe in (REPO / ".venv" / "bin" / "octofuse", Path(sys.executable).parent / "octofuse"):
        if exe.is_file():
            return [str(exe)]
    return [sys.executable, "-m", "octofuse"]


def test_command_line_process(tmp_path):
    rec = two_robots()
    bag = rec.write(tmp_path / "run", "ros1")
    out = tmp_path / "maps"
    env = {k: v for k, v in os.environ.items() if k not in ("FORCE_COLOR", "COLUMNS")}
    ok = subprocess.run(
        [
            *octofuse_command(),
            "build",
            str(bag),
            "--fixed-frame",
            "map",
            "--resolution",
            RES,
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )
    assert ok.returncode == 0, ok.stderr
    assert "Traceback" not in ok.stderr and ok.stderr.strip() == ""
    assert "wrote 3 maps" in ok.stdout
    bf.assert_same_map(
        OccupancyMap.load(out / "centralized.ot"),
        bf.reference_maps(rec.shots, AGENTS2)["centralized"],
        "centralized",
    )
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    bad = subprocess.run(
        [*octofuse_command(), "build", str(bag), "--fixed-frame", "world", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )
    assert bad.returncode == 1
    assert "Traceback" not in bad.stderr
    lines = bf.strip_ansi(bad.stderr).strip().splitlines()
    assert len(lines) == 1, bad.stderr
    assert lines[0].startswith("error: fixed frame 'world' is not in the bags' transforms")
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
