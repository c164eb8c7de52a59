"""Tests of octofuse.io.tf: the transform buffer."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

import octofuse.scans as oio

S = 1_000_000_000  # ns per second


def yaw_quat(yaw):
    return np.array([0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)])


def yaw_matrix(yaw, t):
    c, s = math.cos(yaw), math.sin(yaw)
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    m[:3, 3] = t
    return m


def chain_buffer():
    """map -> odom (dynamic) -> base_link (dynamic) -> laser (static), plus base_link -> cam."""
    buf = oio.TransformBuffer()
    buf.add_transform("map", "odom", 10 * S, [1.0, 0.0, 0.0], yaw_quat(0.0))
    buf.add_transform("map", "odom", 20 * S, [3.0, 0.0, 0.0], yaw_quat(0.0))
    buf.add_transform("odom", "base_link", 10 * S, [0.0, 0.0, 0.0], yaw_quat(0.0))
    buf.add_transform("odom", "base_link", 12 * S, [2.0, 4.0, 0.0], yaw_quat(math.pi / 2))
    buf.add_transform("odom", "base_link", 20 * S, [2.0, 4.0, 0.0], yaw_quat(math.pi / 2))
    buf.add_static_transform("base_link", "laser", [0.5, 0.0, 0.3], yaw_quat(math.pi))
    buf.add_static_transform("/base_link", "/cam", [0.0, 0.1, 0.0], yaw_quat(-math.pi / 2))
    return buf


def test_exact_at_samples():
    buf = chain_buffer()
    np.testing.assert_array_equal(buf.lookup("odom", "base_link", 10 * S), np.eye(4))
    t = buf.lookup("odom", "base_link", 12 * S)
    np.testing.assert_allclose(t, yaw_matrix(math.pi / 2, [2, 4, 0]), atol=1e-15)
    expected = (
        yaw_matrix(0.0, [3, 0, 0])
        @ yaw_matrix(math.pi / 2, [2, 4, 0])
        @ yaw_matrix(math.pi, [0.5, 0, 0.3])
    )
    np.testing.assert_allclose(buf.lookup("map", "laser", 20 * S), expected, atol=1e-12)


def test_interpolation_midway():
    buf = chain_buffer()
    # 11 s: odom -> base_link is halfway: translation (1, 2, 0), yaw 45 degrees;
    # map -> odom at 1/10: translation (1.2, 0, 0).
    t = buf.lookup("odom", "base_link", 11 * S)
    np.testing.assert_allclose(t, yaw_matrix(math.pi / 4, [1, 2, 0]), atol=1e-12)
    expected = (
        yaw_matrix(0.0, [1.2, 0, 0])
        @ yaw_matrix(math.pi / 4, [1, 2, 0])
        @ yaw_matrix(math.pi, [0.5, 0, 0.3])
    )
    np.testing.assert_allclose(buf.lookup("map", "laser", 11 * S), expected, atol=1e-12)
    # A point 1 m ahead of the laser, seen from the map.
    p = buf.lookup("map", "laser", 11 * S) @ [1.0, 0, 0, 1]
    np.testing.assert_allclose(p, expected @ [1.0, 0, 0, 1])


def test_slerp_takes_shortest_arc():
    buf = oio.TransformBuffer()
    # yaw 170 deg -> yaw -170 deg (second one given with the negated quaternion): the short
    # way passes through 180 deg, not through 0.
    buf.add_transform("a", "b", 0, [0, 0, 0], yaw_quat(math.radians(170)))
    buf.add_transform("a", "b", 2 * S, [0, 0, 0], -yaw_quat(math.radians(-170)))
    mid = buf.lookup("a", "b", S)
    np.testing.assert_allclose(mid, yaw_matrix(math.pi, [0, 0, 0]), atol=1e-12)
    buf2 = oio.TransformBuffer()
    buf2.add_transform("a", "b", 0, [0, 0, 0], yaw_quat(math.radians(170)))
    buf2.add_transform("a", "b", 2 * S, [0, 0, 0], yaw_quat(math.radians(-170)))
    np.testing.assert_allclose(buf2.lookup("a", "b", S), mid, atol=1e-12)


def test_reverse_and_sibling_lookups():
    buf = chain_buffer()
    fwd = buf.lookup("map", "laser", 15 * S)
    np.testing.assert_allclose(buf.lookup("laser", "map", 15 * S), np.linalg.inv(fwd), atol=1e-12)
    # laser and cam are siblings under base_link: no dynamic link is involved.
    t = buf.lookup("cam", "laser", 0)
    expected = np.linalg.inv(yaw_matrix(-math.pi / 2, [0, 0.1, 0])) @ yaw_matrix(
        math.pi, [0.5, 0, 0.3]
    )
    np.testing.assert_allclose(t, expected, atol=1e-12)
    np.testing.assert_array_equal(buf.lookup("laser", "laser", 5), np.eye(4))


def test_lookup_many_matches_lookup():
    buf = chain_buffer()
    stamps = np.linspace(10 * S, 20 * S, 37).astype(np.int64)
    many = buf.lookup_many("laser", "map", stamps)
    assert many.shape == (37, 4, 4)
    for k, stamp in enumerate(stamps):
        np.testing.assert_allclose(many[k], buf.lookup("laser", "map", int(stamp)), atol=1e-12)


def test_extrapolation_errors():
    buf = chain_buffer()
    with pytest.raises(
        oio.ExtrapolationError, match=r"'map' -> 'odom'.*before the first sample"
    ) as err:
        buf.lookup("map", "odom", 9 * S)
    assert (err.value.parent, err.value.child, err.value.first_ns, err.value.last_ns) == (
        "map",
        "odom",
        10 * S,
        20 * S,
    )
    with pytest.raises(oio.ExtrapolationError, match=r"1\.000000 s after the last sample"):
        buf.lookup("laser", "map", 21 * S)
    with pytest.raises(oio.ExtrapolationError, match="3 of 4 stamps are outside"):
        buf.lookup_many("laser", "map", [15 * S, 0, 1, 2])
    # Frames below the dynamic links need no time.
    buf.lookup("laser", "base_link", 0)
    assert isinstance(oio.ExtrapolationError("m", "a", "b", 0, 0, 0), oio.TransformError)
    assert not buf.can_transform("map", "laser", 25 * S)
    assert buf.can_transform("map", "laser", 20 * S)
    assert buf.time_range("map", "laser") == (10 * S, 20 * S)
    assert buf.time_range("laser", "cam") is None


def test_tolerance_clamps_to_the_nearest_sample():
    buf = oio.TransformBuffer(tolerance_ns=1000)
    buf.add_transform("a", "b", 5 * S, [1, 2, 3], [0, 0, 0, 1])
    np.testing.assert_array_equal(buf.lookup("a", "b", 5 * S - 1000)[:3, 3], [1, 2, 3])
    np.testing.assert_array_equal(buf.lookup("a", "b", 5 * S + 999)[:3, 3], [1, 2, 3])
    with pytest.raises(oio.ExtrapolationError):
        buf.lookup("a", "b", 5 * S + 1001)
    exact = oio.TransformBuffer()
    exact.add_transform("a", "b", 5 * S, [1, 2, 3], [0, 0, 0, 1])
    exact.lookup("a", "b", 5 * S)
    with pytest.raises(oio.ExtrapolationError):
        exact.lookup("a", "b", 5 * S + 1)


def test_connectivity_and_unknown_frames():
    buf = chain_buffer()
    buf.add_static_transform("world", "other_robot", [0, 0, 0], [0, 0, 0, 1])
    with pytest.raises(oio.ConnectivityError, match="rooted at 'world'.*rooted at 'map'"):
        buf.lookup("other_robot", "laser", 15 * S)
    with pytest.raises(oio.UnknownFrameError, match=r"'nowhere'; known frames: 'base_link', 'cam'"):
        buf.lookup("map", "nowhere", 15 * S)
    assert issubclass(oio.ConnectivityError, oio.TransformError)
    assert issubclass(oio.UnknownFrameError, oio.TransformError)
    with pytest.raises(oio.UnknownFrameError, match="buffer is empty"):
        oio.TransformBuffer().lookup("a", "b", 0)


def test_tree_consistency_is_enforced():
    buf = chain_buffer()
    with pytest.raises(oio.TransformError, match="already has parent 'odom'"):
        buf.add_transform("map", "base_link", 10 * S, [0, 0, 0], [0, 0, 0, 1])
    with pytest.raises(oio.TransformError, match="loop"):
        buf.add_static_transform("laser", "map", [0, 0, 0], [0, 0, 0, 1])
    with pytest.raises(oio.TransformError, match="is static"):
        buf.add_transform("base_link", "laser", 10 * S, [0, 0, 0], [0, 0, 0, 1])
    with pytest.raises(ValueError, match="map -> odom at 10000000000 ns: zero rotation quaternion"):
        buf.add_transform("map", "odom", 10 * S, [0, 0, 0], [0, 0, 0, 0])
    with pytest.raises(ValueError, match="non-finite translation"):
        buf.add_transform("map", "odom", 10 * S, [0, math.nan, 0], [0, 0, 0, 1])
    with pytest.raises(ValueError, match="translation beyond"):
        buf.add_transform("map", "odom", 10 * S, [2e12, 0, 0], [0, 0, 0, 1])


def test_samples_out_of_order_and_duplicates():
    buf = oio.TransformBuffer()
    buf.add_transforms(
        "a",
        "b",
        [3 * S, 1 * S, 2 * S],
        [[3, 0, 0], [1, 0, 0], [9, 9, 9]],
        np.tile([0, 0, 0, 1.0], (3, 1)),
    )
    buf.add_transform("a", "b", 2 * S, [2, 0, 0], [0, 0, 0, 1])  # replaces the 2 s sample
    np.testing.assert_array_equal(buf.lookup("a", "b", 2 * S)[:3, 3], [2, 0, 0])
    np.testing.assert_allclose(buf.lookup("a", "b", 2 * S + S // 2)[:3, 3], [2.5, 0, 0])
    assert buf.links() == [("a", "b", False, 3, 1 * S, 3 * S)]
    # Adding later samples after lookups keeps the storage sorted.
    buf.add_transform("a", "b", 0, [0, 0, 0], [0, 0, 0, 1])
    np.testing.assert_allclose(buf.lookup("a", "b", S // 2)[:3, 3], [0.5, 0, 0])
    # A single sample, then an array holding the same stamp: the array, added last, wins;
    # single samples are normalized as arrays are.
    buf.add_transform("a", "b", 4 * S, [7, 0, 0], [0, 0, 0, 2.0])
    buf.add_transforms("a", "b", [4 * S], [[4, 0, 0]], [[0, 0, 0, 1.0]])
    buf.add_transform("a", "b", 5 * S, [5, 0, 0], [0, 0, 0, 3.0])
    np.testing.assert_array_equal(buf.lookup("a", "b", 4 * S)[:3, 3], [4, 0, 0])
    np.testing.assert_array_equal(
        buf.lookup("a", "b", 5 * S), [[1, 0, 0, 5], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
    )


@pytest.mark.parametrize("store", [Stores.ROS1_NOETIC, Stores.LATEST], ids=["ros1", "ros2"])
def test_messages_from_rosbags_types(store):
    ts = get_typestore(store)
    if "tf2_msgs/msg/TFMessage" not in ts.types:  # not in the builtin ROS 1 store
        ts.register(
            get_types_from_msg(
                "geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"
            )
        )
    T = ts.types
    is_ros1 = store == Stores.ROS1_NOETIC

    def header(stamp_ns, frame):
        stamp = T["builtin_interfaces/msg/Time"](sec=stamp_ns // S, nanosec=stamp_ns % S)
        if is_ros1:
            return T["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame)
        return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

    def tstamped(stamp_ns, parent, child, xyz, q):
        return T["geometry_msgs/msg/TransformStamped"](
            header=header(stamp_ns, parent),
            child_frame_id=child,
            transform=T["geometry_msgs/msg/Transform"](
                translation=T["geometry_msgs/msg/Vector3"](*xyz),
                rotation=T["geometry_msgs/msg/Quaternion"](*q),
            ),
        )

    def pose(xyz, q):
        return T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](*xyz),
            orientation=T["geometry_msgs/msg/Quaternion"](*q),
        )

    def vec0():
        return T["geometry_msgs/msg/Vector3"](0, 0, 0)

    tfm = T["tf2_msgs/msg/TFMessage"]
    buf = oio.TransformBuffer()
    buf.add_tf_message(tfm(transforms=[tstamped(S, "map", "odom", (1, 0, 0), (0, 0, 0, 1))]))
    buf.add_tf_message(tfm(transforms=[tstamped(3 * S, "map", "odom", (3, 0, 0), (0, 0, 0, 1))]))
    static = tfm(transforms=[tstamped(0, "/base_link", "/laser", (0, 0, 0.3), (0, 0, 0, 1))])
    buf.add_tf_message(static, static=True)
    odom = T["nav_msgs/msg/Odometry"](
        header=header(2 * S, "odom"),
        child_frame_id="base_link",
        pose=T["geometry_msgs/msg/PoseWithCovariance"](
            pose=pose((0, 1, 0), yaw_quat(math.pi / 2)), covariance=np.zeros(36)
        ),
        twist=T["geometry_msgs/msg/TwistWithCovariance"](
            twist=T["geometry_msgs/msg/Twist"](linear=vec0(), angular=vec0()),
            covariance=np.zeros(36),
        ),
    )
    buf.add_pose_message(odom)
    expected = (
        yaw_matrix(0, [2, 0, 0]) @ yaw_matrix(math.pi / 2, [0, 1, 0]) @ yaw_matrix(0, [0, 0, 0.3])
    )
    np.testing.assert_allclose(buf.lookup("map", "laser", 2 * S), expected, atol=1e-12)

    # PoseStamped of a robot body with a mounting offset to its lidar.
    ps = T["geometry_msgs/msg/PoseStamped"](
        header=header(5 * S, "world"), pose=pose((1, 2, 0), yaw_quat(math.pi / 2))
    )
    offset = yaw_matrix(math.pi, [0.2, 0, 0.5])
    buf.add_pose_message(ps, "lidar", offset=offset)
    np.testing.assert_allclose(
        buf.lookup("world", "lidar", 5 * S), yaw_matrix(math.pi / 2, [1, 2, 0]) @ offset, atol=1e-12
    )
    with pytest.raises(ValueError, match="child_frame"):
        buf.add_pose_message(ps)


# -- properties -------------------------------------------------------------------------


@st.composite
def random_trees(draw):
    """A random tree of 2..7 frames with dynamic and static links, sampled between 0 and 10 s."""
    n = draw(st.integers(2, 7))
    buf = oio.TransformBuffer()
    unit = st.floats(-1.0, 1.0, allow_nan=False)
    for child in range(1, n):
        parent = draw(st.integers(0, child - 1))
        q = np.array([draw(unit) for _ in range(4)])
        if np.linalg.norm(q) < 0.1:
            q = np.array([0.0, 0.0, 0.0, 1.0])
        if draw(st.booleans()):
            buf.add_static_transform(
                f"f{parent}", f"f{child}", [draw(unit) * 5 for _ in range(3)], q
            )
        else:
            k = draw(st.integers(2, 4))
            stamps = np.array(
                [0, 10 * S] + [draw(st.integers(1, 10 * S - 1)) for _ in range(k - 2)]
            )
            trans = np.array([[draw(unit) * 5 for _ in range(3)] for _ in range(k)])
            quats = np.array([[draw(unit) for _ in range(4)] for _ in range(k)])
            quats[np.linalg.norm(quats, axis=1) < 0.1] = [0.0, 0.0, 0.0, 1.0]
            buf.add_transforms(f"f{parent}", f"f{child}", stamps, trans, quats)
    return buf, n


@settings(max_examples=120, deadline=None)
@given(random_trees(), st.data())
def test_lookups_invert_and_compose(tree, data):
    buf, n = tree
    frame = st.integers(0, n - 1).map(lambda i: f"f{i}")
    a, b, c = data.draw(frame), data.draw(frame), data.draw(frame)
    t = data.draw(st.integers(0, 10 * S))
    ab, ba = buf.lookup(a, b, t), buf.lookup(b, a, t)
    np.testing.assert_allclose(buf.lookup_many(a, b, [t, t])[1], ab, atol=1e-12)
    np.testing.assert_allclose(ab @ ba, np.eye(4), atol=1e-9)
    np.testing.assert_allclose(buf.lookup(a, c, t), ab @ buf.lookup(b, c, t), atol=1e-9)
    # Every result is a proper rigid transform.
    r = ab[:3, :3]
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-9)
    assert np.linalg.det(r) == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_array_equal(ab[3], [0, 0, 0, 1])


def test_quaternion_matrix_roundtrip():
    rng = np.random.default_rng(1)
    for q in rng.normal(size=(200, 4)):
        q /= np.linalg.norm(q)
        back = oio.matrix_to_quaternion(oio.quaternion_to_matrix(q))
        assert np.allclose(back, q, atol=1e-12) or np.allclose(back, -q, atol=1e-12)
    m = oio.transform_matrix([1, 2, 3], yaw_quat(0.3))
    np.testing.assert_allclose(oio.invert_transform(m) @ m, np.eye(4), atol=1e-15)


def test_many_lookups_are_fast():
    buf = oio.TransformBuffer()
    stamps = np.arange(10_000, dtype=np.int64) * (S // 100)
    yaw = np.linspace(0, 20, stamps.size)
    quats = np.column_stack(
        [np.zeros_like(yaw), np.zeros_like(yaw), np.sin(yaw / 2), np.cos(yaw / 2)]
    )
    buf.add_transforms("map", "base_link", stamps, np.column_stack([yaw, yaw, yaw]), quats)
    buf.add_static_transform("base_link", "laser", [0.1, 0, 0.2], [0, 0, 0, 1])
    queries = np.random.default_rng(0).integers(0, stamps[-1], 100_000)
    out = buf.lookup_many("map", "laser", queries)
    assert out.shape == (100_000, 4, 4)
    for k in range(0, 2000):
        buf.lookup("map", "laser", int(queries[k]))
    np.testing.assert_allclose(buf.lookup("map", "laser", int(queries[5])), out[5], atol=1e-12)
