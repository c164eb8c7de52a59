"""``octofuse build`` on bad inputs: one clear line on stderr, exit 1, maps already written kept.

A good build writes maps into a folder first; every failing build then targets the same
folder, and the maps in it must be byte-identical afterwards.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bagfactory as bf  # noqa: E402
from bagfactory import PC2, T0, Recording, Robot, S, run_cli  # noqa: E402


def scene_recording(bad_message: bool = False) -> Recording:
    robot = Robot("r1", start=(-1.5, 0.13, 0.2), velocity=(0.4, 0.0, 0.2))
    rec = bf.robot_recording([robot], {"r1": [T0 + S // 4 + k * S // 2 for k in range(4)]})
    if bad_message:  # a message that cannot be deserialized, after two good scans
        rec.records.append((robot.topic, PC2, T0 + S, lambda ts: b"\x01\x00\x00\x00\x05"))
    return rec


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    """A bag, and the maps a good build wrote from it into ``out``."""
    from octofuse.cli import main

    root = tmp_path_factory.mktemp("good")
    rec = scene_recording()
    bags = {kind: rec.write(root / f"run_{kind}", kind) for kind in ("ros1", "mcap")}
    out = root / "maps"
    assert main(["build", str(bags["ros1"]), "--resolution", "0.1", "--out", str(out)]) == 0
    files = {p.name: p.read_bytes() for p in out.iterdir()}
    assert sorted(files) == [".octofuse-output", "centralized.ot", "r1.ot"]
    return {"root": root, "bags": bags, "out": out, "files": files}


def truncated(good, tmp_path, kind):
    src = good["bags"][kind]
    if src.is_dir():
        dst = tmp_path / "cut_folder"
        shutil.copytree(src, dst)
        storage = next(dst.glob("*.mcap"))
    else:
        dst = storage = tmp_path / "cut.bag"
        shutil.copy(src, dst)
    data = storage.read_bytes()
    storage.write_bytes(data[: int(len(data) * 0.6)])
    return dst


def case_missing_file(good, tmp):
    return [tmp / "nothere.bag"], ["nothere.bag", "does not exist"]


def case_not_a_bag(good, tmp):
    p = tmp / "notes.bag"
    p.write_text("these are notes, not a bag\n" * 50)
    return [p], ["notes.bag", "not a bag"]


def case_truncated_ros1(good, tmp):
    return [truncated(good, tmp, "ros1")], ["cut.bag", "truncated"]


def case_truncated_mcap(good, tmp):
    return [truncated(good, tmp, "mcap")], ["cut_folder", "truncated"]


def case_undecodable_message(good, tmp):
    # found only while the scans are inserted: the build fails half-way
    bag = scene_recording(bad_message=True).write(tmp / "garbage", "ros1")
    return [bag], [
        "garbage.bag",
        "cannot deserialize a sensor_msgs/msg/PointCloud2 message on '/r1/points'",
    ]


def case_unknown_agent_topic(good, tmp):
    return (
        [good["bags"]["ros1"], "--agent", "a=/r9/points"],
        [
            "'/r9/points' not found in",
            "run_ros1.bag",
            "the bags contain:",
            "/r1/points (sensor_msgs/msg/PointCloud2, 4 msgs)",
            "/tf (tf2_msgs/msg/TFMessage",
        ],
    )


def case_unknown_pose_topic(good, tmp):
    return (
        [good["bags"]["ros1"], "--agent", "a=/r1/points", "--pose", "a=/r1/odom"],
        ["'/r1/odom' not found in", "the bags contain:", "/r1/points"],
    )


def case_agent_topic_of_wrong_type(good, tmp):
    return (
        [good["bags"]["mcap"], "--agent", "a=/tf"],
        ["'/tf'", "tf2_msgs/msg/TFMessage", "expected", "sensor_msgs/msg/LaserScan"],
    )


def case_missing_fixed_frame(good, tmp):
    return (
        [good["bags"]["mcap"], "--fixed-frame", "world"],
        [
            "fixed frame 'world' is not in the bags' transforms; "
            "frames present: map, r1/base_link, r1/lidar, r1/odom"
        ],
    )


def case_no_transforms_at_all(good, tmp):
    rec = Recording()
    rec.cloud("/lidar/points", "lidar", T0, bf.pose_matrix(0.23, 0.17, 1.05, 0.0))
    bag = rec.write(tmp / "no_tf", "mcap")
    return [bag], [
        "fixed frame 'map' is not in the bags' transforms; frames present: none "
        "(no /tf, /tf_static or pose topic)"
    ]


def case_no_scan_topic(good, tmp):
    rec = Recording()
    rec.robot_tf(Robot("r1"), [T0])
    bag = rec.write(tmp / "only_tf", "sqlite3")
    return [bag], ["no LaserScan or PointCloud2 topic in the bags; they contain: /tf (tf2_msgs"]


def case_topic_given_to_two_agents(good, tmp):
    return (
        [good["bags"]["ros1"], "--agent", "a=/r1/points", "--agent", "b=/r1/points"],
        ["topic(s) given to more than one agent: /r1/points"],
    )


def case_cloud_without_xyz_fields(good, tmp):
    robot = Robot("r1", start=(-1.5, 0.13, 0.2))
    rec = Recording()
    rec.robot_tf(robot, [T0, T0 + S])
    broken = bf.Layout((("a", 0, "f4"), ("b", 4, "f4"), ("c", 8, "f4")), 12)
    rec.robot_scan(robot, T0 + S // 2, layout=broken)
    bag = rec.write(tmp / "abc", "mcap")
    return [bag], [
        "cannot decode the message on '/r1/points' stamped 100500000000 ns",
        "no x/y/z field(s); fields present: 'a', 'b', 'c'",
    ]


def case_config_bags_not_a_list(good, tmp):
    p = tmp / "bags.yaml"
    p.write_text("build:\n  bags: {a: 1}\n")
    return ["--config", p], ["bags.yaml.build.bags: expected a list, got dict"]


def case_missing_config_file(good, tmp):
    return ["--config", tmp / "nothere.yaml"], ["nothere.yaml", "does not exist"]


def case_config_with_unknown_key(good, tmp):
    p = tmp / "typo.yaml"
    p.write_text(f"build:\n  bags: [{good['bags']['ros1']}]\n  resolutoin: 0.1\n")
    return ["--config", p], ["typo.yaml", "unknown key(s) resolutoin"]


def case_config_scan_stride_zero(good, tmp):
    # ``--every 0`` is a usage error (exit 2, test_cli_usage.py); from a file it is bad input
    p = tmp / "stride.yaml"
    p.write_text(f"build:\n  bags: [{good['bags']['ros1']}]\n  scan_stride: 0\n")
    return ["--config", p], ["stride.yaml.build.scan_stride = 0"]


CASES = {name[5:]: f for name, f in list(globals().items()) if name.startswith("case_")}


@pytest.mark.parametrize("case", list(CASES))
def test_bad_input_is_one_clear_line(good, tmp_path, capsys, case):
    args, expected = CASES[case](good, tmp_path)
    out = good["out"]
    code, stdout, err = run_cli(capsys, "build", *args, "--out", out)
    assert code == 1
    assert "Traceback" not in err and "Traceback" not in stdout
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("error: ")
    for text in expected:
        assert text in lines[0]
    assert "wrote" not in stdout
    # the maps of the earlier build are untouched, and nothing was added
    assert {p.name: p.read_bytes() for p in out.iterdir()} == good["files"]


def test_failed_build_creates_no_output_folder(good, tmp_path, capsys):
    out = tmp_path / "new" / "maps"
    code, _, err = run_cli(
        capsys, "build", good["bags"]["mcap"], "--fixed-frame", "world", "--out", out
    )
    assert code == 1 and "frames present" in err
    assert not out.parent.exists()
