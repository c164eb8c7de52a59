"""Vectorised decoding of lidar messages into numpy point arrays.

Both decoders accept the message objects produced by :class:`octofuse.io.BagSet`
(``rosbags`` dataclasses, ROS 1 or ROS 2) or any object with the same fields.
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np

__all__ = ["POINTFIELD_DTYPES", "laserscan_to_xyz", "pointcloud2_to_xyz", "stamp_to_ns"]

#: ``sensor_msgs/PointField`` datatype constant -> numpy scalar type (native order).
POINTFIELD_DTYPES: dict[int, np.dtype[Any]] = {
    1: np.dtype(np.int8),
    2: np.dtype(np.uint8),
    3: np.dtype(np.int16),
    4: np.dtype(np.uint16),
    5: np.dtype(np.int32),
    6: np.dtype(np.uint32),
    7: np.dtype(np.float32),
    8: np.dtype(np.float64),
}


def stamp_to_ns(stamp: Any) -> int:
    """Nanoseconds since the epoch of a ``builtin_interfaces/Time`` (or a ``Header``).

    Parameters
    ----------
    stamp : object
        An object with ``sec`` and ``nanosec`` fields, or with a ``stamp``
        field holding one (a ``std_msgs/Header``).

    Returns
    -------
    int
    """
    if hasattr(stamp, "stamp"):
        stamp = stamp.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _as_bytes_array(data: Any) -> np.ndarray:
    if isinstance(data, np.ndarray):
        return data.view(np.uint8).reshape(-1) if data.dtype != np.uint8 else data.reshape(-1)
    if isinstance(data, (bytes, bytearray, memoryview)):
        return np.frombuffer(data, dtype=np.uint8)
    return np.asarray(data, dtype=np.uint8).reshape(-1)


def pointcloud2_to_xyz(msg: Any) -> np.ndarray:
    """Decode the x, y, z coordinates of a ``sensor_msgs/PointCloud2``.

    The fields ``x``, ``y`` and ``z`` may have any numeric ``PointField``
    datatype (normally FLOAT32 or FLOAT64) and lie at any offsets within the
    point; other fields and padding are skipped. ``point_step``/``row_step``
    padding and organized clouds (``height > 1``) are handled by a strided
    view of the buffer; ``is_bigendian`` selects the byte order. Points with a
    NaN or infinite coordinate are dropped (regardless of ``is_dense``), and
    the remaining points keep their row-major order.

    Parameters
    ----------
    msg : sensor_msgs/PointCloud2
        The message.

    Returns
    -------
    numpy.ndarray
        ``(N, 3)`` float64 array of finite points in the cloud's frame
        (``msg.header.frame_id``).

    Raises
    ------
    ValueError
        If a coordinate field is missing (the message names the fields that
        are present), has an unknown datatype, or the layout does not fit the
        data buffer.
    """
    fields = {}
    for f in msg.fields:
        fields.setdefault(f.name, f)
    missing = [n for n in ("x", "y", "z") if n not in fields]
    if missing:
        present = ", ".join(repr(f.name) for f in msg.fields) or "none"
        raise ValueError(
            f"PointCloud2 has no {'/'.join(missing)} field(s); fields present: {present}"
        )
    try:
        height, width = int(msg.height), int(msg.width)
        point_step, row_step = int(msg.point_step), int(msg.row_step)
    except (TypeError, ValueError, OverflowError) as e:
        raise ValueError(f"PointCloud2 layout is not a set of whole numbers ({e})") from None
    if min(height, width, point_step, row_step) < 0:
        raise ValueError(
            f"PointCloud2 layout has a negative size (height {height}, width {width},"
            f" point_step {point_step}, row_step {row_step})"
        )
    order = ">" if msg.is_bigendian else "<"
    formats, offsets = [], []
    for name in ("x", "y", "z"):
        f = fields[name]
        if int(f.datatype) not in POINTFIELD_DTYPES:
            raise ValueError(f"PointCloud2 field {name!r} has unknown datatype {f.datatype}")
        dt = POINTFIELD_DTYPES[int(f.datatype)].newbyteorder(order)
        if int(f.offset) < 0 or int(f.offset) + dt.itemsize > point_step:
            raise ValueError(
                f"PointCloud2 field {name!r} (offset {f.offset}, {dt.itemsize} bytes) does not fit"
                f" in point_step {point_step}"
            )
        formats.append(dt)
        offsets.append(int(f.offset))
    if height * width == 0:
        return np.empty((0, 3), dtype=np.float64)
    if height > 1 and row_step < width * point_step:
        raise ValueError(
            f"PointCloud2 row_step {row_step} is smaller than width * point_step"
            f" = {width} * {point_step}"
        )
    data = _as_bytes_array(msg.data)
    stride_row = row_step if height > 1 else width * point_step
    needed = (height - 1) * stride_row + width * point_step
    if data.size < needed:
        raise ValueError(
            f"PointCloud2 data has {data.size} bytes, its layout ({height} x {width} points,"
            f" point_step {point_step}, row_step {row_step}) needs {needed}"
        )
    dtype = np.dtype(
        {"names": ["x", "y", "z"], "formats": formats, "offsets": offsets, "itemsize": point_step}
    )
    points = np.ndarray(
        shape=(height, width), dtype=dtype, buffer=data, offset=0, strides=(stride_row, point_step)
    )
    xyz = np.empty((height * width, 3), dtype=np.float64)
    for col, name in enumerate(("x", "y", "z")):
        xyz[:, col] = points[name].reshape(-1)
    finite = np.isfinite(xyz).all(axis=1)
    return xyz if finite.all() else xyz[finite]


def laserscan_to_xyz(
    msg: Any, *, no_return: Literal["skip", "free"] = "skip"
) -> tuple[np.ndarray, np.ndarray]:
    """Decode a ``sensor_msgs/LaserScan`` into end points in the sensor frame.

    Beam ``i`` points at ``angle_min + i * angle_increment`` in the scan
    plane (``z = 0`` of the scan's frame). Ranges are classified as in REP 117:

    * hit: finite and ``range_min <= r <= range_max`` -> end point returned;
    * no return: ``+inf``, or finite but ``> range_max`` (some drivers, and
      the Intel data set, report "no echo" as a value just above
      ``range_max``) -> nothing was hit up to ``range_max``;
    * invalid: NaN, ``-inf`` or ``< range_min`` -> always dropped.

    With ``no_return="skip"`` (default) no-return beams are dropped, which is
    the conservative choice: nothing is cleared where the sensor saw nothing.
    With ``no_return="free"`` their unit directions are returned so the
    caller can mark the space along the beam free up to ``range_max``.

    Parameters
    ----------
    msg : sensor_msgs/LaserScan
        The message.
    no_return : {"skip", "free"}
        Handling of no-return beams, see above.

    Returns
    -------
    hits : numpy.ndarray
        ``(N, 3)`` float64 end points of the beams that hit something.
    free_dirs : numpy.ndarray
        ``(M, 3)`` float64 unit directions of the no-return beams (``M = 0``
        with ``no_return="skip"``).
    """
    if no_return not in ("skip", "free"):
        raise ValueError(f"no_return must be 'skip' or 'free', not {no_return!r}")
    ranges = np.asarray(msg.ranges, dtype=np.float64).reshape(-1)
    angles = float(msg.angle_min) + np.arange(ranges.size, dtype=np.float64) * float(
        msg.angle_increment
    )
    rmin, rmax = float(msg.range_min), float(msg.range_max)
    with np.errstate(invalid="ignore"):
        hit = np.isfinite(ranges) & (ranges >= rmin) & (ranges <= rmax)
        r = ranges[hit]
        a = angles[hit]
        hits = np.column_stack((r * np.cos(a), r * np.sin(a), np.zeros_like(r)))
        hits = hits[np.isfinite(hits).all(axis=1)]  # a non-finite angle maps nowhere
        if no_return == "skip":
            return hits, np.empty((0, 3), dtype=np.float64)
        none = (ranges == np.inf) | (np.isfinite(ranges) & (ranges > rmax))
        a = angles[none]
        free_dirs = np.column_stack((np.cos(a), np.sin(a), np.zeros_like(a)))
        free_dirs = free_dirs[np.isfinite(free_dirs).all(axis=1)]
    return hits, free_dirs
