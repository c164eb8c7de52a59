"""Tests of octofuse.io.decode: PointCloud2 and LaserScan decoding."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import octofuse.scans as oio

FLOAT32, FLOAT64, UINT16, UINT8, INT32 = 7, 8, 4, 2, 5
CODE = {np.dtype(v).str[1:]: k for k, v in oio.POINTFIELD_DTYPES.items()}


def make_cloud(points, *, layout, point_step, height=1, row_pad=0, bigendian=False, extra=None):
    """Pack ``points`` (height*width, 3) into a PointCloud2-like message.

    ``layout`` maps field name -> (offset, numpy type char such as 'f4').
    ``extra`` maps extra field name -> values (height*width,).
    """
    points = np.asarray(points, dtype=np.float64)
    n = points.shape[0]
    width = n // height
    order = ">" if bigendian else "<"
    names, formats, offsets = [], [], []
    for name, (offset, typ) in layout.items():
        names.append(name)
        formats.append(order + typ)
        offsets.append(offset)
    dtype = np.dtype(
        {"names": names, "formats": formats, "offsets": offsets, "itemsize": point_step}
    )
    rec = np.zeros(n, dtype=dtype)
    for col, axis in enumerate("xyz"):
        if axis in layout:
            rec[axis] = points[:, col]
    for name, values in (extra or {}).items():
        rec[name] = values
    raw = rec.tobytes()
    row_step = width * point_step + row_pad
    data = bytearray()
    for r in range(height):
        data += raw[r * width * point_step : (r + 1) * width * point_step] + b"\xab" * row_pad
    fields = [
        SimpleNamespace(name=name, offset=off, datatype=CODE[np.dtype(typ).str[1:]], count=1)
        for name, (off, typ) in layout.items()
    ]
    return SimpleNamespace(
        header=SimpleNamespace(stamp=SimpleNamespace(sec=1, nanosec=2), frame_id="lidar"),
        height=height,
        width=width,
        fields=fields,
        is_bigendian=bigendian,
        point_step=point_step,
        row_step=row_step,
        data=np.frombuffer(bytes(data), dtype=np.uint8),
        is_dense=False,
    )


PTS = np.array(
    [[1.5, -2.25, 3.0], [0.0, 0.0, 0.0], [-100.125, 7.5, 0.25], [1e3, -1e3, 12.0]], dtype=np.float64
)


def test_packed_float32():
    msg = make_cloud(PTS, layout={"x": (0, "f4"), "y": (4, "f4"), "z": (8, "f4")}, point_step=12)
    xyz = oio.pointcloud2_to_xyz(msg)
    assert xyz.dtype == np.float64 and xyz.shape == (4, 3)
    np.testing.assert_array_equal(xyz, PTS)


def test_float64_shuffled_offsets_padding_and_extra_fields():
    layout = {
        "intensity": (0, "f4"),
        "z": (4, "f8"),
        "ring": (12, "u2"),
        "x": (16, "f8"),
        "y": (24, "f8"),
    }
    pts = PTS + np.array([1e-9, 0, 0])  # not representable in float32
    msg = make_cloud(
        pts, layout=layout, point_step=40, extra={"intensity": np.arange(4), "ring": np.arange(4)}
    )
    np.testing.assert_array_equal(oio.pointcloud2_to_xyz(msg), pts)


def test_mixed_float_types_and_bigendian():
    layout = {"x": (8, "f8"), "y": (0, "f4"), "z": (4, "f4")}
    msg = make_cloud(PTS, layout=layout, point_step=20, bigendian=True)
    np.testing.assert_array_equal(oio.pointcloud2_to_xyz(msg), PTS)
    # Reading the same bytes as little endian must give different numbers.
    msg.is_bigendian = False
    assert not np.array_equal(oio.pointcloud2_to_xyz(msg), PTS)


def test_organized_cloud_with_row_padding_and_nan():
    pts = np.arange(3 * 4 * 3, dtype=np.float64).reshape(12, 3) / 4.0
    pts[1] = [np.nan, np.nan, np.nan]
    pts[6] = [1.0, np.inf, 2.0]
    pts[11] = [-np.inf, 0.0, 0.0]
    layout = {"x": (0, "f4"), "y": (4, "f4"), "z": (8, "f4"), "rgb": (12, "u4")}
    msg = make_cloud(pts, layout=layout, point_step=16, height=3, row_pad=5)
    assert msg.row_step == 4 * 16 + 5
    xyz = oio.pointcloud2_to_xyz(msg)
    keep = np.isfinite(pts).all(axis=1)
    np.testing.assert_array_equal(xyz, pts[keep])
    assert xyz.shape == (9, 3)


def test_organized_cloud_without_row_padding():
    pts = np.arange(2 * 5 * 3, dtype=np.float64).reshape(10, 3)
    msg = make_cloud(
        pts, layout={"x": (0, "f8"), "y": (8, "f8"), "z": (16, "f8")}, point_step=24, height=2
    )
    np.testing.assert_array_equal(oio.pointcloud2_to_xyz(msg), pts)


def test_trailing_bytes_and_bytes_data_are_accepted():
    msg = make_cloud(PTS, layout={"x": (0, "f4"), "y": (4, "f4"), "z": (8, "f4")}, point_step=12)
    msg.data = bytes(msg.data) + b"\x00" * 7
    np.testing.assert_array_equal(oio.pointcloud2_to_xyz(msg), PTS)


def test_empty_cloud():
    msg = make_cloud(
        np.empty((0, 3)), layout={"x": (0, "f4"), "y": (4, "f4"), "z": (8, "f4")}, point_step=12
    )
    out = oio.pointcloud2_to_xyz(msg)
    assert out.shape == (0, 3) and out.dtype == np.float64


def test_missing_field_names_present_fields():
    msg = make_cloud(
        PTS, layout={"x": (0, "f4"), "y": (4, "f4"), "intensity": (8, "f4")}, point_step=12
    )
    with pytest.raises(ValueError, match=r"no z field.*'x', 'y', 'intensity'"):
        oio.pointcloud2_to_xyz(msg)


def test_inconsistent_layouts_raise():
    msg = make_cloud(PTS, layout={"x": (0, "f4"), "y": (4, "f4"), "z": (8, "f4")}, point_step=12)
    msg.data = msg.data[:-1]
    with pytest.raises(ValueError, match="needs 48"):
        oio.pointcloud2_to_xyz(msg)
    msg = make_cloud(PTS, layout={"x": (0, "f4"), "y": (4, "f4"), "z": (8, "f8")}, point_step=16)
    msg.point_step = 12
    with pytest.raises(ValueError, match="does not fit in point_step 12"):
        oio.pointcloud2_to_xyz(msg)
    msg = make_cloud(PTS, layout={"x": (0, "f4"), "y": (4, "f4"), "z": (8, "f4")}, point_step=12)
    msg.fields[2].datatype = 42
    with pytest.raises(ValueError, match="unknown datatype 42"):
        oio.pointcloud2_to_xyz(msg)


@st.composite
def cloud_layouts(draw):
    types = [draw(st.sampled_from(["f4", "f8"])) for _ in range(3)]
    extra = draw(st.integers(0, 2))  # number of extra u2 fields
    slots = [(axis, t) for axis, t in zip("xyz", types, strict=True)] + [
        (f"e{i}", "u2") for i in range(extra)
    ]
    order = draw(st.permutations(slots))
    layout, offset = {}, 0
    for name, typ in order:
        offset += draw(st.integers(0, 3))  # unaligned gaps are allowed
        layout[name] = (offset, typ)
        offset += np.dtype(typ).itemsize
    point_step = offset + draw(st.integers(0, 6))
    height = draw(st.integers(1, 3))
    width = draw(st.integers(0, 5))
    row_pad = draw(st.integers(0, 9)) if height > 1 else 0
    bigendian = draw(st.booleans())
    return layout, point_step, height, width, row_pad, bigendian


@settings(max_examples=150, deadline=None)
@given(cloud_layouts(), st.randoms(use_true_random=False))
def test_random_layouts_roundtrip(params, rnd):
    layout, point_step, height, width, row_pad, bigendian = params
    n = height * width
    pts = np.array([[rnd.uniform(-1e3, 1e3) for _ in range(3)] for _ in range(n)]).reshape(n, 3)
    for col, axis in enumerate("xyz"):
        if layout[axis][1] == "f4":
            pts[:, col] = pts[:, col].astype(np.float32)
    if n:
        pts[rnd.randrange(n), rnd.randrange(3)] = rnd.choice([np.nan, np.inf, -np.inf])
    extra = {name: np.arange(n) % 7 for name in layout if name.startswith("e")}
    msg = make_cloud(
        pts,
        layout=layout,
        point_step=point_step,
        height=height,
        row_pad=row_pad,
        bigendian=bigendian,
        extra=extra,
    )
    np.testing.assert_array_equal(oio.pointcloud2_to_xyz(msg), pts[np.isfinite(pts).all(axis=1)])


def make_scan(ranges, *, angle_min=-math.pi / 2, inc=math.pi / 4, rmin=0.1, rmax=10.0):
    return SimpleNamespace(
        header=SimpleNamespace(stamp=SimpleNamespace(sec=0, nanosec=0), frame_id="laser"),
        angle_min=angle_min,
        angle_max=angle_min + inc * (len(ranges) - 1),
        angle_increment=inc,
        time_increment=0.0,
        scan_time=0.0,
        range_min=rmin,
        range_max=rmax,
        ranges=np.asarray(ranges, dtype=np.float32),
        intensities=np.zeros(0, dtype=np.float32),
    )


def test_laserscan_hits_and_invalid_beams():
    # beams at -90, -45, 0, 45, 90, 135, 180, 225 degrees
    ranges = [2.0, np.nan, 10.0, np.inf, 0.05, 12.5, -np.inf, 0.1]
    hits, free = oio.laserscan_to_xyz(make_scan(ranges))
    expected = np.array(
        [
            [0.0, -2.0, 0.0],
            [10.0, 0.0, 0.0],
            [0.1 * math.cos(math.radians(225)), 0.1 * math.sin(math.radians(225)), 0.0],
        ]
    )
    np.testing.assert_allclose(hits, expected, atol=1e-6)
    assert hits.dtype == np.float64 and np.all(hits[:, 2] == 0.0)
    assert free.shape == (0, 3)


def test_laserscan_no_return_free_directions():
    ranges = [2.0, np.nan, 10.0, np.inf, 0.05, 12.5, -np.inf, 0.1]
    hits, free = oio.laserscan_to_xyz(make_scan(ranges), no_return="free")
    assert hits.shape == (3, 3)
    angles = np.radians([45.0, 135.0])  # +inf and 12.5 > range_max
    np.testing.assert_allclose(
        free, np.column_stack([np.cos(angles), np.sin(angles), [0, 0]]), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.norm(free, axis=1), 1.0)


def test_laserscan_angles_follow_increment_exactly():
    n = 181
    scan = make_scan(np.full(n, 3.0), angle_min=-1.0, inc=0.01, rmax=5.0)
    hits, _ = oio.laserscan_to_xyz(scan)
    angles = -1.0 + np.arange(n) * 0.01
    np.testing.assert_allclose(hits[:, 0], 3.0 * np.cos(angles), rtol=0, atol=1e-12)
    np.testing.assert_allclose(hits[:, 1], 3.0 * np.sin(angles), rtol=0, atol=1e-12)


def test_laserscan_bad_mode():
    with pytest.raises(ValueError, match="no_return"):
        oio.laserscan_to_xyz(make_scan([1.0]), no_return="clear")


def test_stamp_to_ns():
    stamp = SimpleNamespace(sec=1_600_000_000, nanosec=123_456_789)
    assert oio.stamp_to_ns(stamp) == 1_600_000_000_123_456_789
    assert oio.stamp_to_ns(SimpleNamespace(stamp=stamp, frame_id="a")) == 1_600_000_000_123_456_789
