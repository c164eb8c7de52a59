"""Tests of the simulated lab dataset generator (data/generate_lab.py).

The generator is run as a separate process (it is standalone: numpy + rosbags)
on a short, small configuration; the bags are read back with rosbags.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from conftest import REPO

pytestmark = pytest.mark.slow

rosbag1 = pytest.importorskip("rosbags.rosbag1")
typesys = pytest.importorskip("rosbags.typesys")

GENERATOR = REPO / "data" / "generate_lab.py"
ROBOTS = 3
DURATION = 4.0
RATE = 5.0


def run_generator(out: Path, *extra: str) -> dict[str, Any]:
    cmd = [
        sys.executable,
        str(GENERATOR),
        "--out",
        str(out),
        "--robots",
        str(ROBOTS),
        "--duration",
        str(DURATION),
        "--rate",
        str(RATE),
        *extra,
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=60, check=False)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == "", proc.stderr  # no warnings either
    return json.loads(out.with_name(out.stem + "_scene.json").read_text())


def read_bag(path: Path) -> dict[str, Any]:
    """All messages of a bag, deserialised, grouped by topic: [(bag time, msgtype, msg)]."""
    store = typesys.get_typestore(typesys.Stores.EMPTY)
    out: dict[str, Any] = {"topics": {}, "messages": {}}
    with rosbag1.Reader(path) as reader:
        types: dict[str, Any] = {}
        for conn in reader.connections:
            types.update(typesys.get_types_from_msg(conn.msgdef.data, conn.msgtype))
            out["topics"][conn.topic] = conn.msgtype
        store.register(types)
        for conn, stamp, raw in reader.messages():
            msg = store.deserialize_ros1(raw, conn.msgtype)
            out["messages"].setdefault(conn.topic, []).append((stamp, msg))
    return out


def stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions x, y, z, w -> (..., 3, 3) rotation matrices."""
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def slerp(q0: np.ndarray, q1: np.ndarray, a: np.ndarray) -> np.ndarray:
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    small = theta < 1e-9
    st = np.where(small, 1.0, np.sin(theta))
    w0 = np.where(small, 1 - a, np.sin((1 - a) * theta) / st)
    w1 = np.where(small, a, np.sin(a * theta) / st)
    return w0 * q0 + w1 * q1


class TfBuffer:
    """Minimal tf lookup: dynamic map -> base frames interpolated in time, static base -> laser."""

    def __init__(self, bag: dict[str, Any]):
        dyn: dict[str, list[tuple[int, list[float], list[float]]]] = {}
        self.parent: dict[str, str] = {}
        for _, msg in bag["messages"]["/tf"]:
            for tf in msg.transforms:
                t, r = tf.transform.translation, tf.transform.rotation
                dyn.setdefault(tf.child_frame_id, []).append(
                    (stamp_ns(tf.header), [t.x, t.y, t.z], [r.x, r.y, r.z, r.w])
                )
                self.parent[tf.child_frame_id] = tf.header.frame_id
        self.dyn = {
            k: (
                np.array([v[0] for v in vs]),
                np.array([v[1] for v in vs]),
                np.array([v[2] for v in vs]),
            )
            for k, vs in dyn.items()
        }
        self.static: dict[str, tuple[str, np.ndarray, np.ndarray]] = {}
        for _, msg in bag["messages"]["/tf_static"]:
            for tf in msg.transforms:
                t, r = tf.transform.translation, tf.transform.rotation
                self.static[tf.child_frame_id] = (
                    tf.header.frame_id,
                    np.array([t.x, t.y, t.z]),
                    np.array([r.x, r.y, r.z, r.w]),
                )

    def laser_in_map(self, laser: str, times_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rotation (N, 3, 3) and origin (N, 3) of a laser frame in map at the given times."""
        base, t_bl, q_bl = self.static[laser]
        assert self.parent[base] == "map"
        ts, trans, quats = self.dyn[base]
        assert np.all(np.diff(ts) > 0)
        assert times_ns.min() >= ts[0] and times_ns.max() <= ts[-1], "scan outside the tf coverage"
        i = np.clip(np.searchsorted(ts, times_ns, side="right") - 1, 0, len(ts) - 2)
        a = ((times_ns - ts[i]) / (ts[i + 1] - ts[i]))[:, None]
        pos = trans[i] * (1 - a) + trans[i + 1] * a
        rot = quat_to_matrix(slerp(quats[i], quats[i + 1], a))
        r_bl = quat_to_matrix(q_bl)
        return rot @ r_bl, pos + rot @ t_bl


def scan_points(msg: Any, tfbuf: TfBuffer) -> tuple[np.ndarray, np.ndarray]:
    """Map-frame points and ranges of the finite beams of a scan (per-beam time)."""
    ranges = np.asarray(msg.ranges, dtype=np.float64)
    n = len(ranges)
    ang = msg.angle_min + np.arange(n) * msg.angle_increment
    times = stamp_ns(msg.header) + np.round(np.arange(n) * msg.time_increment * 1e9)
    ok = np.isfinite(ranges)
    rot, org = tfbuf.laser_in_map(msg.header.frame_id, times[ok])
    local = (
        np.column_stack([np.cos(ang[ok]), np.sin(ang[ok]), np.zeros(ok.sum())]) * ranges[ok, None]
    )
    return org + np.einsum("nij,nj->ni", rot, local), ranges[ok]


def surface_distance(points: np.ndarray, scene: dict[str, Any]) -> np.ndarray:
    """Distance from each point to the nearest box surface of the scene."""
    lo = np.array([b["min"] for b in scene["boxes"]])[None]
    hi = np.array([b["max"] for b in scene["boxes"]])[None]
    p = points[:, None, :]
    outside = np.linalg.norm(np.maximum(np.maximum(lo - p, p - hi), 0.0), axis=2)
    inside = np.minimum(p - lo, hi - p).min(axis=2)
    return np.where(outside > 0, outside, inside).min(axis=1)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    root = tmp_path_factory.mktemp("lab")
    runs = {
        "a": ("a/lab.bag", ("--seed", "3")),
        "b": ("b/lab.bag", ("--seed", "3")),
        "other_seed": ("c/lab.bag", ("--seed", "4")),
        "exact": ("d/lab.bag", ("--seed", "3", "--noise-scale", "0")),
    }
    out: dict[str, Any] = {}
    for key, (rel, extra) in runs.items():
        path = root / rel
        path.parent.mkdir()
        out[key] = {"path": path, "scene": run_generator(path, *extra)}
    for key in ("a", "exact"):
        out[key]["bag"] = read_bag(out[key]["path"])
    return out


def test_topics_types_and_frames(dataset: dict[str, Any]) -> None:
    bag = dataset["a"]["bag"]
    expected = {"/tf": "tf2_msgs/msg/TFMessage", "/tf_static": "tf2_msgs/msg/TFMessage"}
    expected.update({f"/robot{k}/scan": "sensor_msgs/msg/LaserScan" for k in range(1, ROBOTS + 1)})
    assert bag["topics"] == expected

    (static,) = bag["messages"]["/tf_static"]
    pairs = {(tf.header.frame_id, tf.child_frame_id) for tf in static[1].transforms}
    assert pairs == {(f"robot{k}/base_link", f"robot{k}/laser") for k in range(1, ROBOTS + 1)}
    for tf in static[1].transforms:  # laser at the front, 0.35-0.45 m up, pitched 45 degrees down
        t, q = tf.transform.translation, tf.transform.rotation
        assert t.x > 0 and 0.35 <= t.z <= 0.45
        x_axis = quat_to_matrix(np.array([q.x, q.y, q.z, q.w]))[:, 0]
        assert math.degrees(math.asin(-x_axis[2])) == pytest.approx(45.0, abs=1e-6)

    children = set()
    for _, msg in bag["messages"]["/tf"]:
        for tf in msg.transforms:
            assert tf.header.frame_id == "map"
            children.add(tf.child_frame_id)
    assert children == {f"robot{k}/base_link" for k in range(1, ROBOTS + 1)}

    for k in range(1, ROBOTS + 1):
        scans = bag["messages"][f"/robot{k}/scan"]
        assert len(scans) == pytest.approx(DURATION * RATE, abs=1)
        assert {m.header.frame_id for _, m in scans} == {f"robot{k}/laser"}


def test_laserscan_fields(dataset: dict[str, Any]) -> None:
    bag = dataset["a"]["bag"]
    finite = total = 0
    for k in range(1, ROBOTS + 1):
        for bag_time, m in bag["messages"][f"/robot{k}/scan"]:
            assert bag_time == stamp_ns(m.header)
            assert len(m.ranges) == 667
            assert len(m.intensities) == 0
            assert m.angle_min == pytest.approx(math.radians(-120.0), abs=1e-6)
            assert m.angle_increment == pytest.approx(math.radians(0.36), abs=1e-7)
            assert m.angle_max == pytest.approx(m.angle_min + 666 * m.angle_increment, abs=1e-5)
            assert m.range_min == pytest.approx(0.02) and m.range_max == pytest.approx(5.6)
            assert m.scan_time == pytest.approx(1.0 / RATE)
            assert m.time_increment == pytest.approx(m.scan_time * 0.36 / 360.0)
            assert 666 * m.time_increment < m.scan_time
            r = np.asarray(m.ranges)
            assert r.dtype == np.float32
            ok = np.isfinite(r)
            assert np.all(r[~ok] == np.inf)  # no return: +inf (REP 117), never NaN
            assert np.all((r[ok] >= m.range_min) & (r[ok] <= m.range_max))
            finite += int(ok.sum())
            total += r.size
    assert 0.5 < finite / total < 0.98


def test_tf_timing(dataset: dict[str, Any]) -> None:
    bag = dataset["a"]["bag"]
    tf_times = np.array([stamp_ns(msg.transforms[0].header) for _, msg in bag["messages"]["/tf"]])
    assert np.all(np.diff(tf_times) == 100_000_000)  # 10 Hz
    static_time = bag["messages"]["/tf_static"][0][0]
    assert static_time <= tf_times[0]
    for k in range(1, ROBOTS + 1):
        scans = [m for _, m in bag["messages"][f"/robot{k}/scan"]]
        stamps = np.array([stamp_ns(m.header) for m in scans])
        assert tf_times[0] <= stamps[0]
        last_beam = stamps[-1] + 666 * scans[-1].time_increment * 1e9
        assert tf_times[-1] >= last_beam
        assert not np.isin(stamps, tf_times).any()  # a reader has to interpolate


def test_beams_land_on_box_surfaces(dataset: dict[str, Any]) -> None:
    bag, scene = dataset["exact"]["bag"], dataset["exact"]["scene"]
    tfbuf = TfBuffer(bag)
    dists = []
    for k in range(1, ROBOTS + 1):
        for _, m in bag["messages"][f"/robot{k}/scan"][::4]:
            pts, _ = scan_points(m, tfbuf)
            dists.append(surface_distance(pts, scene))
    d = np.concatenate(dists)
    assert d.size > 1000
    # noise-free ranges are only rounded to whole millimetres
    assert d.max() < 0.005, np.sort(d)[-10:]

    bag, scene = dataset["a"]["bag"], dataset["a"]["scene"]
    tfbuf = TfBuffer(bag)
    near, all_d = [], []
    for k in range(1, ROBOTS + 1):
        for _, m in bag["messages"][f"/robot{k}/scan"][::4]:
            pts, r = scan_points(m, tfbuf)
            dd = surface_distance(pts, scene)
            near.append(dd[r < 1.0])
            all_d.append(dd)
    near_d, all_dd = np.concatenate(near), np.concatenate(all_d)
    assert near_d.size > 100
    assert near_d.max() < 0.05  # sigma 1 cm below 1 m
    assert np.median(all_dd) < 0.02


def test_robots_stay_in_the_room_and_off_the_boxes(dataset: dict[str, Any]) -> None:
    bag, scene = dataset["a"]["bag"], dataset["a"]["scene"]
    sx, sy = scene["room"]["size"]
    assert (sx, sy) == (15.0, 8.0)
    xy = np.array(
        [
            [tf.transform.translation.x, tf.transform.translation.y]
            for _, msg in bag["messages"]["/tf"]
            for tf in msg.transforms
        ]
    )
    assert np.all((xy > 0.3) & (xy < [sx - 0.3, sy - 0.3]))
    for b in scene["boxes"]:
        if b["kind"] == "obstacle":
            inside = (
                (xy[:, 0] > b["min"][0] - 0.25)
                & (xy[:, 0] < b["max"][0] + 0.25)
                & (xy[:, 1] > b["min"][1] - 0.25)
                & (xy[:, 1] < b["max"][1] + 0.25)
            )
            assert not inside.any(), b["name"]


def test_scene_json(dataset: dict[str, Any]) -> None:
    scene = dataset["a"]["scene"]
    kinds = {b["kind"] for b in scene["boxes"]}
    assert kinds == {"floor", "wall", "obstacle"}
    floor = [b for b in scene["boxes"] if b["kind"] == "floor"]
    assert len(floor) == 1 and floor[0]["max"][2] == 0.0
    heights = [b["max"][2] - b["min"][2] for b in scene["boxes"] if b["kind"] == "obstacle"]
    assert min(heights) >= 0.10 - 1e-9 and max(heights) <= 0.25 + 1e-9
    assert scene["sensor"]["beams"] == 667 and scene["sensor"]["range_max"] == 5.6
    assert len(scene["robots"]) == ROBOTS and all(r["waypoints"] for r in scene["robots"])
    assert scene["generator"]["seed"] == 3


def test_deterministic(dataset: dict[str, Any]) -> None:
    a = dataset["a"]["path"].read_bytes()
    assert a == dataset["b"]["path"].read_bytes()
    assert a != dataset["other_seed"]["path"].read_bytes()
