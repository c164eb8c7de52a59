"""Tests of octofuse.io.bags: reading ROS 1 / ROS 2 bags written with rosbags."""

from __future__ import annotations

import math
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

import octofuse.scans as oio
from conftest import SHARED_REAL

S = 1_000_000_000

TF = "tf2_msgs/msg/TFMessage"
PC2 = "sensor_msgs/msg/PointCloud2"
SCAN = "sensor_msgs/msg/LaserScan"
BLOB = "octofuse_test/msg/Blob"
BLOB_DEF = "float64 value\nstring label\nint32[] samples\n"


def typestore(ros1: bool):
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.LATEST)
    if TF not in ts.types:  # the builtin ROS 1 store has no tf2_msgs
        ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", TF))
    ts.register(get_types_from_msg(BLOB_DEF, BLOB))
    return ts


STORES = {True: typestore(True), False: typestore(False)}


# -- message builders (each takes the typestore the bag is written with) --------------------


def header(ts, stamp_ns, frame):
    stamp = ts.types["builtin_interfaces/msg/Time"](sec=stamp_ns // S, nanosec=stamp_ns % S)
    if "seq" in ts.fielddefs["std_msgs/msg/Header"][1][0]:
        return ts.types["std_msgs/msg/Header"](seq=7, stamp=stamp, frame_id=frame)
    return ts.types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)


def cloud(ts, stamp_ns, points, *, layout, point_step, bigendian=False, height=1, row_pad=0):
    """PointCloud2 with x/y/z at the given (offset, type) plus an 'intensity' u2 at offset 0."""
    points = np.asarray(points, dtype=np.float64)
    n = len(points)
    width = n // height
    order = ">" if bigendian else "<"
    names = ["intensity", *layout]
    formats = [order + "u2"] + [order + layout[a][1] for a in layout]
    offsets = [0] + [layout[a][0] for a in layout]
    dtype = np.dtype(
        {"names": names, "formats": formats, "offsets": offsets, "itemsize": point_step}
    )
    rec = np.zeros(n, dtype=dtype)
    rec["intensity"] = np.arange(n)
    for col, axis in enumerate("xyz"):
        rec[axis] = points[:, col]
    rows = rec.tobytes()
    data = b"".join(
        rows[r * width * point_step : (r + 1) * width * point_step] + b"\x55" * row_pad
        for r in range(height)
    )
    code = {"f4": 7, "f8": 8, "u2": 4}
    field = ts.types["sensor_msgs/msg/PointField"]
    fields = [field(name="intensity", offset=0, datatype=4, count=1)] + [
        field(name=a, offset=layout[a][0], datatype=code[layout[a][1]], count=1) for a in layout
    ]
    return ts.types[PC2](
        header=header(ts, stamp_ns, "lidar"),
        height=height,
        width=width,
        fields=fields,
        is_bigendian=bigendian,
        point_step=point_step,
        row_step=width * point_step + row_pad,
        data=np.frombuffer(data, dtype=np.uint8).copy(),
        is_dense=False,
    )


def scan(ts, stamp_ns, ranges, frame="laser"):
    return ts.types[SCAN](
        header=header(ts, stamp_ns, frame),
        angle_min=-math.pi / 2,
        angle_max=math.pi / 2,
        angle_increment=math.pi / (len(ranges) - 1),
        time_increment=0.0,
        scan_time=0.1,
        range_min=0.1,
        range_max=20.0,
        ranges=np.asarray(ranges, dtype=np.float32),
        intensities=np.zeros(len(ranges), dtype=np.float32),
    )


def tf_msg(ts, stamp_ns, links):
    T = ts.types
    return T[TF](
        transforms=[
            T["geometry_msgs/msg/TransformStamped"](
                header=header(ts, stamp_ns, parent),
                child_frame_id=child,
                transform=T["geometry_msgs/msg/Transform"](
                    translation=T["geometry_msgs/msg/Vector3"](*xyz),
                    rotation=T["geometry_msgs/msg/Quaternion"](
                        0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)
                    ),
                ),
            )
            for parent, child, xyz, yaw in links
        ]
    )


def blob(ts, value):
    return ts.types[BLOB](value=value, label=f"v{value}", samples=np.arange(3, dtype=np.int32))


# -- bag writers ----------------------------------------------------------------------------

KINDS = ["ros1", "sqlite3", "mcap", "bare_mcap", "bare_db3"]


def write_bag(path: Path, kind: str, records) -> Path:
    """Write ``records`` as a bag of ``kind``.

    ``records`` = [(topic, msgtype, log_ns, build(ts) -> msg or raw bytes)].

    Returns the path to open: a .bag file, a ROS 2 bag folder, or a bare storage file.
    """
    ros1 = kind == "ros1"
    ts = STORES[ros1]
    if ros1:
        out = path.with_suffix(".bag")
        writer = Writer1(out)
    else:
        out = path
        plugin = StoragePlugin.SQLITE3 if kind in ("sqlite3", "bare_db3") else StoragePlugin.MCAP
        writer = Writer2(out, version=9, storage_plugin=plugin)
    conns = {}
    with writer:
        for topic, msgtype, log_ns, build in records:
            if (topic, msgtype) not in conns:
                conns[(topic, msgtype)] = writer.add_connection(topic, msgtype, typestore=ts)
            msg = build(ts)
            if isinstance(msg, bytes):
                raw = msg
            else:
                raw = ts.serialize_ros1(msg, msgtype) if ros1 else ts.serialize_cdr(msg, msgtype)
            writer.write(conns[(topic, msgtype)], log_ns, raw)
    if kind.startswith("bare_"):
        storage = next(p for p in out.iterdir() if p.suffix in (".mcap", ".db3"))
        bare = out.parent / f"{out.name}_bare{storage.suffix}"
        storage.rename(bare)
        shutil.rmtree(out)
        return bare
    return out


CLOUD_PTS = np.array(
    [[1.25, -2.5, 0.125], [10.0, 20.0, -30.0], [np.nan, 1.0, 1.0], [-0.5, 0.25, 8.0]]
)
CLOUD_LAYOUT = {"z": (4, "f8"), "x": (16, "f8"), "y": (12, "f4")}
SCAN_RANGES = [1.0, np.nan, 2.0, np.inf, 0.05, 25.0, 4.0]


def sample_records():
    return [
        (
            "/tf_static",
            TF,
            1 * S,
            lambda ts: tf_msg(ts, 0, [("base_link", "lidar", (0.5, 0, 1.0), 0.0)]),
        ),
        ("/tf", TF, 2 * S, lambda ts: tf_msg(ts, 2 * S, [("map", "base_link", (0, 0, 0), 0.0)])),
        (
            "/cloud",
            PC2,
            3 * S,
            lambda ts: cloud(
                ts, 3 * S, CLOUD_PTS, layout=CLOUD_LAYOUT, point_step=28, bigendian=True
            ),
        ),
        ("/scan", SCAN, 4 * S, lambda ts: scan(ts, 4 * S, SCAN_RANGES)),
        (
            "/tf",
            TF,
            6 * S,
            lambda ts: tf_msg(ts, 6 * S, [("map", "base_link", (4, 0, 0), math.pi / 2)]),
        ),
        (
            "/cloud",
            PC2,
            5 * S,
            lambda ts: cloud(
                ts,
                5 * S,
                np.arange(18.0).reshape(6, 3),
                layout=CLOUD_LAYOUT,
                point_step=32,
                height=2,
                row_pad=3,
            ),
        ),
        ("/blob", BLOB, 7 * S, lambda ts: blob(ts, 2.5)),
    ]


@pytest.mark.parametrize("kind", KINDS)
def test_read_every_format(tmp_path, kind):
    path = write_bag(tmp_path / "run", kind, sample_records())
    with oio.BagSet(path) as bags:
        topics = bags.topics()
        assert {t: (i.msgtype, i.count) for t, i in topics.items()} == {
            "/blob": (BLOB, 1),
            "/cloud": (PC2, 2),
            "/scan": (SCAN, 1),
            "/tf": (TF, 2),
            "/tf_static": (TF, 1),
        }
        assert topics["/cloud"].paths == (path,)
        assert (bags.start_ns, bags.end_ns) == (1 * S, 7 * S)
        msgs = list(bags.messages())
        # Log time order, although /tf at 6 s was written before /cloud at 5 s.
        assert [(m.topic, m.log_time_ns) for m in msgs] == [
            ("/tf_static", 1 * S),
            ("/tf", 2 * S),
            ("/cloud", 3 * S),
            ("/scan", 4 * S),
            ("/cloud", 5 * S),
            ("/tf", 6 * S),
            ("/blob", 7 * S),
        ]
        clouds = [m.msg for m in msgs if m.topic == "/cloud"]
        assert oio.stamp_to_ns(clouds[0].header) == 3 * S
        np.testing.assert_array_equal(oio.pointcloud2_to_xyz(clouds[0]), CLOUD_PTS[[0, 1, 3]])
        np.testing.assert_array_equal(
            oio.pointcloud2_to_xyz(clouds[1]), np.arange(18.0).reshape(6, 3)
        )
        hits, free = oio.laserscan_to_xyz(
            next(m.msg for m in msgs if m.topic == "/scan"), no_return="free"
        )
        # Beams every 30 degrees from -90: hits at -90 (1 m), -30 (2 m), 90 (4 m); no return
        # at 0 (+inf) and 60 (25 m > range_max); NaN and 0.05 m < range_min are dropped.
        c30 = math.cos(math.pi / 6)
        np.testing.assert_allclose(hits, [[0, -1, 0], [2 * c30, -1, 0], [0, 4, 0]], atol=1e-6)
        np.testing.assert_allclose(free, [[1, 0, 0], [0.5, c30, 0]], atol=1e-6)
        # A type known only from the definition stored in the bag.
        b = next(m.msg for m in msgs if m.topic == "/blob")
        assert (b.value, b.label, list(b.samples)) == (2.5, "v2.5", [0, 1, 2])

        tf = oio.load_transforms(bags)
        # Halfway between the /tf samples: base_link at (2, 0, 0) with yaw 45 degrees; the
        # point 1 m ahead of the lidar is 1.5 m ahead of base_link and 1 m up.
        h = 1.5 * math.sqrt(0.5)
        np.testing.assert_allclose(
            tf.lookup("map", "lidar", 4 * S) @ [1, 0, 0, 1], [2 + h, h, 1, 1], atol=1e-12
        )
        # Only the requested topics, with type checks (ROS 1 style names are accepted).
        only = list(bags.messages({"/scan": "sensor_msgs/LaserScan", "/tf_static": None}))
        assert [m.topic for m in only] == ["/tf_static", "/scan"]
        assert [m.log_time_ns for m in bags.messages("/cloud", start_ns=4 * S, stop_ns=6 * S)] == [
            5 * S
        ]


def test_metadata_yaml_path_is_accepted(tmp_path):
    path = write_bag(tmp_path / "run", "mcap", sample_records()[:2])
    with oio.BagSet(path / "metadata.yaml") as bags:
        assert bags.paths == (path,)
        assert len(list(bags.messages())) == 2


def test_merge_across_bags_of_different_formats(tmp_path):
    def rec(topic, t):
        return (topic, SCAN, t, lambda ts: scan(ts, t, [1.0, 2.0, 3.0], frame=topic.strip("/")))

    a = write_bag(
        tmp_path / "a",
        "ros1",
        [rec("/r1/scan", t * S) for t in (1, 3, 5, 7)] + [rec("/both", 4 * S)],
    )
    b = write_bag(
        tmp_path / "b", "mcap", [rec("/r2/scan", t * S) for t in (2, 4, 6)] + [rec("/both", 4 * S)]
    )
    c = write_bag(tmp_path / "c", "bare_db3", [rec("/both", t * S) for t in (0, 4, 8)])
    with oio.BagSet([a, b, c]) as bags:
        assert bags.topics()["/both"].count == 5
        assert bags.topics()["/both"].paths == (a, b, c)
        assert bags.topics()["/r2/scan"].paths == (b,)
        assert (bags.start_ns, bags.end_ns) == (0, 8 * S)
        got = [(m.topic, m.log_time_ns // S, m.msg.header.frame_id) for m in bags.messages()]
    assert [t for _, t, _ in got] == sorted(t for _, t, _ in got)
    assert got[:3] == [("/both", 0, "both"), ("/r1/scan", 1, "r1/scan"), ("/r2/scan", 2, "r2/scan")]
    # Equal log times: the order of the inputs, then the order within the file.
    at4 = [(topic) for topic, t, _ in got if t == 4]
    assert at4 == ["/both", "/r2/scan", "/both", "/both"]
    # ROS 1 messages keep ROS 1 fields; ROS 2 messages have none.
    with oio.BagSet([a, b]) as bags:
        first = {m.topic: m.msg for m in bags.messages(["/r1/scan", "/r2/scan"])}
    assert first["/r1/scan"].header.seq == 7
    assert not hasattr(first["/r2/scan"].header, "seq")


def test_topic_errors_name_topics_and_types(tmp_path):
    path = write_bag(tmp_path / "run", "ros1", sample_records())
    with oio.BagSet(path) as bags:
        with pytest.raises(
            oio.BagError,
            match=r"'/points' not found in .*run\.bag; the bags contain: "
            r".*/cloud \(sensor_msgs/msg/PointCloud2, 2 msgs\)"
            r".*/scan \(sensor_msgs/msg/LaserScan, 1 msgs\)",
        ):
            bags.messages(["/scan", "/points"])
        with pytest.raises(
            oio.BagError,
            match=r"'/scan' in .*run\.bag has type 'sensor_msgs/msg/LaserScan', "
            r"expected 'sensor_msgs/msg/PointCloud2'",
        ):
            bags.messages({"/scan": "sensor_msgs/PointCloud2"})
        with pytest.raises(
            oio.BagError, match="expected 'nav_msgs/msg/Odometry' or 'tf2_msgs/msg/TFMessage'"
        ):
            bags.check_topics({"/cloud": ["tf2_msgs/TFMessage", "nav_msgs/msg/Odometry"]})
        with pytest.raises(oio.BagError, match="'/odom' not found"):
            oio.load_transforms(bags, pose_sources={"/odom": "base_link"})
        assert bags.check_topics("/scan")["/scan"].msgtype == SCAN


def test_conflicting_types_across_inputs(tmp_path):
    a = write_bag(tmp_path / "a", "ros1", [("/x", SCAN, S, lambda ts: scan(ts, S, [1.0, 2.0]))])
    b = write_bag(tmp_path / "b", "mcap", [("/x", BLOB, S, lambda ts: blob(ts, 1.0))])
    with oio.BagSet([a, b]) as bags:
        info = bags.topics()["/x"]
        assert info.msgtype is None and set(info.types) == {SCAN, BLOB}
        with pytest.raises(
            oio.BagError,
            match=r"'/x' has different types in the inputs: "
            r".*a\.bag: sensor_msgs/msg/LaserScan; .*b: octofuse_test/msg/Blob",
        ):
            bags.messages("/x")


def test_missing_and_non_bag_inputs(tmp_path):
    good = write_bag(tmp_path / "good", "ros1", sample_records()[:1])
    with pytest.raises(oio.BagError, match=r"nothere\.bag: no such file or directory"):
        oio.BagSet([good, tmp_path / "nothere.bag"])
    text = tmp_path / "notes.bag"
    text.write_text("these are my notes, not a bag\n" * 20)
    with pytest.raises(oio.BagError, match=r"notes\.bag: not a bag"):
        oio.BagSet(text)
    fake_mcap = tmp_path / "fake.mcap"
    fake_mcap.write_bytes(b"\x00" * 100)
    with pytest.raises(oio.BagError, match=r"fake\.mcap: not a bag"):
        oio.BagSet(fake_mcap)
    empty = tmp_path / "empty.bag"
    empty.touch()
    with pytest.raises(oio.BagError, match=r"empty\.bag: file is empty"):
        oio.BagSet(empty)
    folder = tmp_path / "folder"
    folder.mkdir()
    with pytest.raises(
        oio.BagError, match=r"folder: directory is not a ROS 2 bag \(it has no metadata\.yaml\)"
    ):
        oio.BagSet(folder)
    with pytest.raises(oio.BagError, match="no input bag"):
        oio.BagSet([])
    mcap = write_bag(tmp_path / "m", "bare_mcap", sample_records()[:1])
    renamed = mcap.rename(tmp_path / "m.bag")
    with pytest.raises(
        oio.BagError, match=r"m\.bag: file is a MCAP file but is named '\.bag'; rename it"
    ):
        oio.BagSet(renamed)
    sqlite = tmp_path / "other.db3"
    import sqlite3

    con = sqlite3.connect(sqlite)
    con.execute("create table t (a integer)")
    con.commit()
    con.close()
    with pytest.raises(oio.BagError, match=r"other\.db3: cannot open sqlite3 ROS 2 storage file"):
        oio.BagSet(sqlite).open()
    bags = oio.BagSet(good)
    with pytest.raises(oio.BagError, match="not open"):
        bags.topics()


def many_scans(n):
    return [
        ("/scan", SCAN, k * S // 10, lambda ts, k=k: scan(ts, k * S // 10, np.full(50, 1.0 + k)))
        for k in range(n)
    ]


@pytest.mark.parametrize("kind", KINDS)
def test_truncated_bags_raise_bag_error(tmp_path, kind):
    path = write_bag(tmp_path / "cut", kind, many_scans(300))
    storage = (
        path if path.is_file() else next(p for p in path.iterdir() if p.suffix in (".mcap", ".db3"))
    )
    data = storage.read_bytes()
    for frac in (0.5, 0.98):
        storage.write_bytes(data[: int(len(data) * frac)])
        # Depending on the format the damage is found when opening or while reading.
        name = re.escape(storage.name if path.is_file() else path.name)
        with pytest.raises(oio.BagError, match=name) as err, oio.BagSet(path) as bags:
            for _ in bags.messages():
                pass
        assert "damaged" in str(err.value) or "truncated" in str(err.value)


def test_damage_found_while_reading_is_wrapped(tmp_path):
    """A ROS 1 bag whose index is intact but whose message data is overwritten."""
    path = write_bag(tmp_path / "damaged", "ros1", many_scans(300))
    data = bytearray(path.read_bytes())
    mid = len(data) // 2
    data[mid - 2000 : mid + 2000] = b"\xff" * 4000
    path.write_bytes(bytes(data))
    with oio.BagSet(path) as bags:
        stream = bags.messages("/scan")
        with pytest.raises(oio.BagError, match=r"damaged\.bag: .*damaged") as err:
            for _ in stream:
                pass
    assert err.value.__cause__ is not None


@pytest.mark.parametrize("kind", ["ros1", "mcap"])
def test_undecodable_message_is_wrapped(tmp_path, kind):
    records = [
        ("/scan", SCAN, S, lambda ts: scan(ts, S, [1.0, 2.0])),
        ("/scan", SCAN, 2 * S, lambda ts: b"\x01\x00\x00\x00\x05"),
    ]
    path = write_bag(tmp_path / "garbage", kind, records)
    with oio.BagSet(path) as bags:
        stream = bags.messages("/scan")
        assert next(stream).log_time_ns == S
        with pytest.raises(
            oio.BagError,
            match=r"garbage.*cannot deserialize a sensor_msgs/msg/LaserScan message on '/scan' "
            r"logged at 2000000000 ns",
        ):
            next(stream)


# -- real recorded data (kept outside the repository) ----------------------------------------

needs_real = pytest.mark.skipif(
    not (SHARED_REAL / "intel_4agents.bag").is_file()
    or not (SHARED_REAL / "luminar_pointcloud2.bag").is_file(),
    reason=f"real recorded data not found in {SHARED_REAL}",
)


@needs_real
def test_real_intel_four_agents():
    with oio.BagSet(SHARED_REAL / "intel_4agents.bag") as bags:
        scans = {f"/robot{k}/scan": SCAN for k in range(1, 5)}
        info = bags.check_topics(scans)
        assert sum(i.count for i in info.values()) == 910
        tf = oio.load_transforms(bags)
        assert {"map", "robot1/base_link", "robot4/laser"} <= set(tf.frames)
        n_hits = n_free = 0
        for topic, _t, msg in bags.messages(scans):
            hits, free = oio.laserscan_to_xyz(msg, no_return="free")
            assert np.isfinite(hits).all() and hits.shape[1] == 3
            assert len(hits) + len(free) <= len(msg.ranges) == 180
            # Range 81.83 means no return and lies just above range_max.
            assert len(free) == int(np.sum(np.asarray(msg.ranges) > msg.range_max))
            n_hits += len(hits)
            n_free += len(free)
            pose = tf.lookup("map", msg.header.frame_id, oio.stamp_to_ns(msg.header))
            assert msg.header.frame_id == topic.split("/")[1] + "/laser"
            assert pose[2, 3] == pytest.approx(0.3)  # the laser is mounted 0.3 m up
        assert n_hits > 100_000 and n_free > 0


@needs_real
def test_real_luminar_pointcloud():
    with oio.BagSet(SHARED_REAL / "luminar_pointcloud2.bag") as bags:
        clouds = [m.msg for m in bags.messages({"/luminar_pointcloud": PC2})]
    assert len(clouds) == 5
    for msg in clouds:
        xyz = oio.pointcloud2_to_xyz(msg)
        assert 30_000 < len(xyz) <= msg.width * msg.height
        assert np.isfinite(xyz).all()
        r = np.linalg.norm(xyz, axis=1)
        assert r.min() > 5.0 and r.max() < 260.0
