"""Small ROS bags of a known scene, written with rosbags, and the truth to check maps against.

The scene is an axis-aligned box room with box obstacles standing on its floor. Every face
lies on a plane through voxel centres of a 0.1 m grid, so the points a sensor returns from a
face fall into one layer of voxels and no rounding decides which.

A :class:`Robot` moves with constant velocity and yaw rate and publishes the tf chain
``map -> NAME/odom`` (static) ``-> NAME/base_link`` (dynamic, sampled) ``-> NAME/lidar`` or
``NAME/laser`` (static). tf interpolates linearly in translation and by slerp in rotation,
so between two samples the sensor pose is exactly :meth:`Robot.sensor_pose`.

A :class:`Recording` collects messages (tf, poses, PointCloud2 in many layouts, LaserScan)
and, for every scan, a :class:`Shot`: the sensor-frame points exactly as a decoder must
return them from the message, and the true sensor pose. :func:`reference_maps` inserts the
shots with :meth:`octofuse.OccupancyMap.insert_scan_from_sensor`, which is what a map built
from the bag must equal. :meth:`Recording.write` writes a ROS 1 ``.bag``, a ROS 2 sqlite3 or
MCAP folder, or a bare ``.mcap`` file.
"""

from __future__ import annotations

import math
import re
import shutil
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from functools import cache, lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

import octofuse
from octofuse.maps.frames import invert

S = 1_000_000_000  #: one second in ns
T0 = 100 * S  #: start of every recording

TF = "tf2_msgs/msg/TFMessage"
PC2 = "sensor_msgs/msg/PointCloud2"
SCAN = "sensor_msgs/msg/LaserScan"
ODOM = "nav_msgs/msg/Odometry"
POSE = "geometry_msgs/msg/PoseStamped"
POSE_COV = "geometry_msgs/msg/PoseWithCovarianceStamped"
TRANSFORM = "geometry_msgs/msg/TransformStamped"

KINDS = ("ros1", "sqlite3", "mcap", "bare_mcap")


# -- geometry ---------------------------------------------------------------------------------


def yaw_quaternion(yaw: float) -> tuple[float, float, float, float]:
    return (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))


def pose_matrix(x: float, y: float, z: float, yaw: float) -> np.ndarray:
    """4x4 transform: translation (x, y, z), rotation yaw about z."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0, x], [s, c, 0.0, y], [0.0, 0.0, 1.0, z], [0.0, 0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class Box:
    """An axis-aligned box ``lo <= p <= hi``."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]

    def _arrays(self) -> tuple[np.ndarray, np.ndarray]:
        return np.asarray(self.lo, dtype=float), np.asarray(self.hi, dtype=float)

    def distance_outside(self, p: np.ndarray) -> np.ndarray:
        """Euclidean distance from points (N, 3) to the box (0 inside)."""
        lo, hi = self._arrays()
        d = np.maximum(np.maximum(lo - p, p - hi), 0.0)
        return np.linalg.norm(d, axis=1)

    def depth_inside(self, p: np.ndarray) -> np.ndarray:
        """Distance from points inside the box to its nearest face (0 outside)."""
        lo, hi = self._arrays()
        return np.maximum(np.minimum(p - lo, hi - p).min(axis=1), 0.0)

    def surface_distance(self, p: np.ndarray) -> np.ndarray:
        return np.maximum(self.distance_outside(p), self.depth_inside(p))


@dataclass(frozen=True)
class Scene:
    """The inside of ``room`` is free except for the solid ``obstacles``."""

    room: Box
    obstacles: tuple[Box, ...] = ()

    def raycast(self, origin: Sequence[float], dirs: np.ndarray) -> np.ndarray:
        """Distance along unit directions (N, 3) from ``origin`` (inside the room) to a face."""
        o = np.asarray(origin, dtype=float)
        d = np.asarray(dirs, dtype=float)
        lo, hi = self.room._arrays()
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d
            t_room = np.where(d > 0, (hi - o) * inv, np.where(d < 0, (lo - o) * inv, np.inf))
            best = t_room.min(axis=1)
            for box in self.obstacles:
                blo, bhi = box._arrays()
                t1, t2 = (blo - o) * inv, (bhi - o) * inv
                near = np.where(
                    d == 0, np.where((o >= blo) & (o <= bhi), -np.inf, np.inf), np.minimum(t1, t2)
                ).max(axis=1)
                far = np.where(
                    d == 0, np.where((o >= blo) & (o <= bhi), np.inf, -np.inf), np.maximum(t1, t2)
                ).min(axis=1)
                hit = (near <= far) & (near > 0)
                best = np.where(hit & (near < best), near, best)
        return best

    def surface_distance(self, p: np.ndarray) -> np.ndarray:
        """Distance from points (N, 3) to the nearest face of the room or an obstacle."""
        p = np.asarray(p, dtype=float).reshape(-1, 3)
        d = self.room.surface_distance(p)
        for box in self.obstacles:
            d = np.minimum(d, box.surface_distance(p))
        return d

    def solid_depth(self, p: np.ndarray) -> np.ndarray:
        """How far points lie inside solid matter (outside the room or in an obstacle), else 0."""
        p = np.asarray(p, dtype=float).reshape(-1, 3)
        d = self.room.distance_outside(p)
        for box in self.obstacles:
            d = np.maximum(d, box.depth_inside(p))
        return d


#: A 5.9 x 3.9 x 2.5 m room with a low box and a tall pillar; faces on 0.1 m voxel centres.
ROOM = Scene(
    Box((-2.95, -1.95, -0.05), (2.95, 1.95, 2.45)),
    (
        Box((0.75, 0.45, -0.05), (1.35, 1.05, 0.95)),
        Box((-1.65, -1.35, -0.05), (-1.05, -0.75, 1.85)),
    ),
)


# -- robots -----------------------------------------------------------------------------------


@dataclass
class Robot:
    """A robot moving with constant velocity; its sensor's pose is known at any time.

    ``start``/``velocity`` are (x, y, yaw) of ``base_link`` in ``odom`` at :data:`T0` and their
    rates per second; ``odom`` is (x, y, yaw) of ``odom`` in ``map``; ``mount`` is
    (x, y, z, yaw) of the sensor on ``base_link``.
    """

    name: str
    start: tuple[float, float, float] = (0.0, 0.0, 0.0)
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    odom: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mount: tuple[float, float, float, float] = (0.1, 0.0, 0.65, 0.0)
    sensor: str = (
        "lidar"  #: "lidar" (PointCloud2 on /NAME/points) or "laser" (LaserScan on /NAME/scan)
    )

    @property
    def odom_frame(self) -> str:
        return f"{self.name}/odom"

    @property
    def base_frame(self) -> str:
        return f"{self.name}/base_link"

    @property
    def sensor_frame(self) -> str:
        return f"{self.name}/{self.sensor}"

    @property
    def topic(self) -> str:
        return f"/{self.name}/points" if self.sensor == "lidar" else f"/{self.name}/scan"

    def base_in_odom(self, t_ns: int) -> tuple[float, float, float]:
        dt = (t_ns - T0) / S
        return tuple(s + v * dt for s, v in zip(self.start, self.velocity))  # type: ignore[return-value]

    def odom_matrix(self) -> np.ndarray:
        return pose_matrix(self.odom[0], self.odom[1], 0.0, self.odom[2])

    def mount_matrix(self) -> np.ndarray:
        return pose_matrix(*self.mount)

    def base_pose(self, t_ns: int) -> np.ndarray:
        """T_map_base at ``t_ns``."""
        x, y, yaw = self.base_in_odom(t_ns)
        return self.odom_matrix() @ pose_matrix(x, y, 0.0, yaw)

    def sensor_pose(self, t_ns: int) -> np.ndarray:
        """T_map_sensor at ``t_ns``."""
        return self.base_pose(t_ns) @ self.mount_matrix()


# -- point cloud layouts ----------------------------------------------------------------------

_DATATYPES = {"i1": 1, "u1": 2, "i2": 3, "u2": 4, "i4": 5, "u4": 6, "f4": 7, "f8": 8}


@dataclass(frozen=True)
class Layout:
    """How a PointCloud2 stores its points: fields (name, offset, numpy type), in field order."""

    fields: tuple[tuple[str, int, str], ...]
    point_step: int
    bigendian: bool = False
    organized: bool = False  #: one row per elevation, NaN where there is no return
    row_pad: int = 0  #: bytes after each row (organized clouds)


LAYOUTS = {
    "float32": Layout((("x", 0, "f4"), ("y", 4, "f4"), ("z", 8, "f4")), 16),
    "float64": Layout((("x", 0, "f8"), ("y", 8, "f8"), ("z", 16, "f8")), 24),
    # fields listed out of offset order, coordinates in reverse order in memory
    "shuffled": Layout(
        (("y", 8, "f4"), ("intensity", 0, "f4"), ("z", 4, "f4"), ("x", 12, "f4")), 16
    ),
    # a gap before x, padding after each point and each row
    "padded": Layout(
        (("x", 4, "f4"), ("y", 8, "f4"), ("z", 12, "f4")), 32, organized=True, row_pad=12
    ),
    "extra_fields": Layout(
        (
            ("x", 0, "f4"),
            ("y", 4, "f4"),
            ("z", 8, "f4"),
            ("intensity", 12, "f4"),
            ("ring", 16, "u2"),
            ("time", 20, "f8"),
        ),
        28,
    ),
    "organized_nan": Layout((("x", 0, "f4"), ("y", 4, "f4"), ("z", 8, "f4")), 16, organized=True),
    "bigendian": Layout(
        (("x", 0, "f8"), ("y", 8, "f8"), ("z", 16, "f8"), ("ring", 24, "u2")), 28, bigendian=True
    ),
    "mixed_types": Layout(
        (("ring", 0, "u2"), ("x", 2, "f8"), ("y", 10, "f4"), ("z", 14, "f8")),
        22,
        bigendian=True,
        organized=True,
        row_pad=2,
    ),
}


def lidar_directions(n_az: int = 40, n_el: int = 7, elevation: float = 0.6) -> np.ndarray:
    """Unit directions (n_el, n_az, 3) of a spinning lidar in its own frame (rows = rings)."""
    az = np.linspace(-math.pi, math.pi, n_az, endpoint=False) + 0.0123
    el = np.linspace(-elevation, elevation, n_el) + 0.0071
    a, e = np.meshgrid(az, el)
    return np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=-1)


#: sensor positions in ROOM from which :func:`room_map` scans it
SENSORS = [(-2.0, 0.9, 0.6), (0.0, -0.2, 0.6), (2.2, -1.0, 0.6), (-0.4, 1.3, 1.2)]


def room_map(sensors=SENSORS, res=0.1, T=None) -> octofuse.OccupancyMap:
    """The test room scanned from ``sensors`` (world frame), built in the frame of T^-1 (a world
    point p is inserted at T^-1 p; None: the world frame)."""
    m = octofuse.OccupancyMap(res)
    dirs = lidar_directions(90, 15, 0.9).reshape(-1, 3)
    Ti = np.eye(4) if T is None else invert(T)
    for o in sensors:
        r = ROOM.raycast(o, dirs)
        pts = np.asarray(o) + dirs * r[:, None]
        pts = pts @ Ti[:3, :3].T + Ti[:3, 3]
        m.insert_scan(pts, Ti[:3, :3] @ np.asarray(o) + Ti[:3, 3])
    return m


def _encode_cloud(grid: np.ndarray, layout: Layout) -> tuple[bytes, int, int, np.ndarray]:
    """Bytes, height, width and decoded points (finite rows, row-major) of a cloud."""
    if not layout.organized:
        grid = grid.reshape(1, -1, 3)
        grid = grid[:, np.isfinite(grid[0]).all(axis=1)]
    height, width = grid.shape[:2]
    order = ">" if layout.bigendian else "<"
    dtype = np.dtype(
        {
            "names": [f[0] for f in layout.fields],
            "formats": [order + f[2] for f in layout.fields],
            "offsets": [f[1] for f in layout.fields],
            "itemsize": layout.point_step,
        }
    )
    rec = np.zeros((height, width), dtype=dtype)
    flat = grid.reshape(height, width, 3)
    for name, _off, fmt in layout.fields:
        if name in "xyz" and len(name) == 1:
            rec[name] = flat[..., "xyz".index(name)]
        elif fmt.startswith("f"):
            rec[name] = 0.25
        else:
            rec[name] = np.arange(width)[None, :] % 16
    raw = rec.tobytes()
    row = width * layout.point_step
    data = b"".join(raw[r * row : (r + 1) * row] + b"\xa5" * layout.row_pad for r in range(height))
    if not all(axis in dtype.names for axis in "xyz"):  # a broken cloud
        return data, height, width, np.empty((0, 3))
    stored = np.empty((height * width, 3))
    for col, axis in enumerate("xyz"):
        stored[:, col] = rec[axis].reshape(-1).astype(np.float64)
    stored = stored[np.isfinite(stored).all(axis=1)]
    return data, height, width, stored


# -- messages ---------------------------------------------------------------------------------


@cache
def typestore(ros1: bool):
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.LATEST)
    if TF not in ts.types:  # the builtin ROS 1 store has no tf2_msgs
        ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", TF))
    return ts


def header(ts, stamp_ns: int, frame: str):
    stamp = ts.types["builtin_interfaces/msg/Time"](sec=stamp_ns // S, nanosec=stamp_ns % S)
    if "seq" in [f[0] for f in ts.fielddefs["std_msgs/msg/Header"][1]]:
        return ts.types["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame)
    return ts.types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)


def _pose_msg(ts, m: np.ndarray):
    T = ts.types
    from octofuse.scans import matrix_to_quaternion

    q = matrix_to_quaternion(m)
    return T["geometry_msgs/msg/Pose"](
        position=T["geometry_msgs/msg/Point"](*map(float, m[:3, 3])),
        orientation=T["geometry_msgs/msg/Quaternion"](*map(float, q)),
    )


def tf_message(ts, stamp_ns: int, links: Iterable[tuple[str, str, np.ndarray]]):
    """TFMessage of (parent, child, 4x4 T_parent_child) links."""
    return ts.types[TF](
        transforms=[transform_stamped(ts, stamp_ns, parent, child, m) for parent, child, m in links]
    )


def transform_stamped(ts, stamp_ns: int, parent: str, child: str, m: np.ndarray):
    """TransformStamped of the link parent -> child, 4x4 T_parent_child."""
    T = ts.types
    from octofuse.scans import matrix_to_quaternion

    q = matrix_to_quaternion(m)
    return T[TRANSFORM](
        header=header(ts, stamp_ns, parent),
        child_frame_id=child,
        transform=T["geometry_msgs/msg/Transform"](
            translation=T["geometry_msgs/msg/Vector3"](*map(float, m[:3, 3])),
            rotation=T["geometry_msgs/msg/Quaternion"](*map(float, q)),
        ),
    )


@dataclass
class Shot:
    """One scan as a map builder must see it."""

    topic: str
    stamp_ns: int
    log_ns: int
    pose: np.ndarray  #: true T_map_sensor at the stamp
    points: np.ndarray  #: (N, 3) sensor-frame points as decoded from the message
    free_dirs: np.ndarray = field(default_factory=lambda: np.empty((0, 3)))  #: no-return beams
    range_max: float = -1.0  #: LaserScan range_max


LATENCY_NS = 10_000_000  #: log time = stamp + 10 ms


@dataclass
class Recording:
    """Messages of one bag plus the truth about its scans."""

    scene: Scene = ROOM
    records: list[tuple[str, str, int, Callable[[Any], Any]]] = field(default_factory=list)
    shots: list[Shot] = field(default_factory=list)

    def add(self, topic: str, msgtype: str, log_ns: int, build: Callable[[Any], Any]) -> None:
        self.records.append((topic, msgtype, log_ns, build))

    # tf
    def tf(self, stamp_ns: int, links, *, static: bool = False, log_ns: int | None = None) -> None:
        links = list(links)
        self.add(
            "/tf_static" if static else "/tf",
            TF,
            stamp_ns + LATENCY_NS if log_ns is None else log_ns,
            lambda ts: tf_message(ts, stamp_ns, links),
        )

    def robot_tf(self, robot: Robot, times_ns: Iterable[int], *, static_log_ns: int = T0) -> None:
        """The static links of ``robot`` once and its odom -> base_link samples at ``times_ns``."""
        self.tf(
            static_log_ns,
            [
                ("map", robot.odom_frame, robot.odom_matrix()),
                (robot.base_frame, robot.sensor_frame, robot.mount_matrix()),
            ],
            static=True,
            log_ns=static_log_ns,
        )
        for t in times_ns:
            x, y, yaw = robot.base_in_odom(t)
            self.tf(t, [(robot.odom_frame, robot.base_frame, pose_matrix(x, y, 0.0, yaw))])

    # poses
    def odometry(
        self,
        topic: str,
        stamp_ns: int,
        pose: np.ndarray,
        frame: str = "odom",
        child: str = "base_link",
    ) -> None:
        def build(ts):
            T = ts.types
            z3 = T["geometry_msgs/msg/Vector3"](0.0, 0.0, 0.0)
            return T[ODOM](
                header=header(ts, stamp_ns, frame),
                child_frame_id=child,
                pose=T["geometry_msgs/msg/PoseWithCovariance"](
                    pose=_pose_msg(ts, pose), covariance=np.zeros(36)
                ),
                twist=T["geometry_msgs/msg/TwistWithCovariance"](
                    twist=T["geometry_msgs/msg/Twist"](linear=z3, angular=z3),
                    covariance=np.zeros(36),
                ),
            )

        self.add(topic, ODOM, stamp_ns + LATENCY_NS, build)

    def pose_stamped(self, topic: str, stamp_ns: int, pose: np.ndarray, frame: str = "map") -> None:
        self.add(
            topic,
            POSE,
            stamp_ns + LATENCY_NS,
            lambda ts: ts.types[POSE](header=header(ts, stamp_ns, frame), pose=_pose_msg(ts, pose)),
        )

    def pose_with_covariance(
        self, topic: str, stamp_ns: int, pose: np.ndarray, frame: str = "map"
    ) -> None:
        def build(ts):
            T = ts.types
            return T[POSE_COV](
                header=header(ts, stamp_ns, frame),
                pose=T["geometry_msgs/msg/PoseWithCovariance"](
                    pose=_pose_msg(ts, pose), covariance=np.zeros(36)
                ),
            )

        self.add(topic, POSE_COV, stamp_ns + LATENCY_NS, build)

    def transform(
        self,
        topic: str,
        stamp_ns: int,
        pose: np.ndarray,
        frame: str = "map",
        child: str = "base_link",
    ) -> None:
        self.add(
            topic,
            TRANSFORM,
            stamp_ns + LATENCY_NS,
            lambda ts: transform_stamped(ts, stamp_ns, frame, child, pose),
        )

    # scans
    def cloud(
        self,
        topic: str,
        frame: str,
        stamp_ns: int,
        pose: np.ndarray,
        *,
        layout: str | Layout = "float64",
        sensor_range: float = 4.0,
        directions: np.ndarray | None = None,
    ) -> Shot:
        """A PointCloud2 of the scene seen from ``pose``; beams longer than ``sensor_range`` are NaN."""
        lay = LAYOUTS[layout] if isinstance(layout, str) else layout
        dirs = lidar_directions() if directions is None else directions
        flat = dirs.reshape(-1, 3)
        r = self.scene.raycast(pose[:3, 3], flat @ pose[:3, :3].T)
        pts = flat * r[:, None]
        pts[r > sensor_range] = np.nan
        data, height, width, stored = _encode_cloud(pts.reshape(dirs.shape), lay)

        def build(ts):
            pf = ts.types["sensor_msgs/msg/PointField"]
            return ts.types[PC2](
                header=header(ts, stamp_ns, frame),
                height=height,
                width=width,
                fields=[
                    pf(name=n, offset=o, datatype=_DATATYPES[t], count=1) for n, o, t in lay.fields
                ],
                is_bigendian=lay.bigendian,
                point_step=lay.point_step,
                row_step=width * lay.point_step + lay.row_pad,
                data=np.frombuffer(data, dtype=np.uint8).copy(),
                is_dense=False,
            )

        shot = Shot(topic, stamp_ns, stamp_ns + LATENCY_NS, pose, stored)
        self.add(topic, PC2, shot.log_ns, build)
        self.shots.append(shot)
        return shot

    def scan(
        self,
        topic: str,
        frame: str,
        stamp_ns: int,
        pose: np.ndarray,
        *,
        beams: int = 72,
        range_max: float = 10.0,
        range_min: float = 0.1,
        nan_beams: Sequence[int] = (),
        angle_min: float = -math.pi + 0.01,
    ) -> Shot:
        """A LaserScan of the scene in the sensor's xy plane; beams past ``range_max`` are +inf."""
        inc32 = np.float32(2 * math.pi / beams)
        amin32 = np.float32(angle_min)
        angles = float(amin32) + np.arange(beams) * float(inc32)
        local = np.column_stack([np.cos(angles), np.sin(angles), np.zeros(beams)])
        r = self.scene.raycast(pose[:3, 3], local @ pose[:3, :3].T)
        ranges = r.astype(np.float32)
        ranges[r > range_max] = np.inf
        ranges[list(nan_beams)] = np.nan
        r64 = ranges.astype(np.float64)
        with np.errstate(invalid="ignore"):
            hit = np.isfinite(r64) & (r64 >= np.float32(range_min)) & (r64 <= np.float32(range_max))
        pts = np.column_stack(
            [
                r64[hit] * np.cos(angles[hit]),
                r64[hit] * np.sin(angles[hit]),
                np.zeros(int(hit.sum())),
            ]
        )
        none = np.isposinf(r64)

        def build(ts):
            return ts.types[SCAN](
                header=header(ts, stamp_ns, frame),
                angle_min=float(amin32),
                angle_max=float(amin32) + (beams - 1) * float(inc32),
                angle_increment=float(inc32),
                time_increment=0.0,
                scan_time=0.1,
                range_min=range_min,
                range_max=range_max,
                ranges=ranges,
                intensities=np.zeros(beams, dtype=np.float32),
            )

        shot = Shot(
            topic,
            stamp_ns,
            stamp_ns + LATENCY_NS,
            pose,
            pts,
            local[none],
            float(np.float32(range_max)),
        )
        self.add(topic, SCAN, shot.log_ns, build)
        self.shots.append(shot)
        return shot

    def robot_scan(self, robot: Robot, stamp_ns: int, **kw) -> Shot:
        """A scan of ``robot``'s sensor (cloud or LaserScan) at its true pose."""
        pose = robot.sensor_pose(stamp_ns)
        if robot.sensor == "lidar":
            return self.cloud(robot.topic, robot.sensor_frame, stamp_ns, pose, **kw)
        return self.scan(robot.topic, robot.sensor_frame, stamp_ns, pose, **kw)

    def write(self, path: Path, kind: str = "mcap") -> Path:
        """Write the bag; returns what to open (``.bag`` file, bag folder or bare ``.mcap``)."""
        return write_bag(Path(path), kind, self.records)


def write_bag(path: Path, kind: str, records) -> Path:
    """Write ``records`` [(topic, msgtype, log_ns, build(ts) -> msg or raw bytes)] as a bag."""
    if kind not in KINDS:
        raise ValueError(f"kind {kind!r}: expected one of {KINDS}")
    ros1 = kind == "ros1"
    ts = typestore(ros1)
    if ros1:
        out = path.with_suffix(".bag")
        writer: Any = Writer1(out)
    else:
        out = path
        plugin = StoragePlugin.SQLITE3 if kind == "sqlite3" else StoragePlugin.MCAP
        writer = Writer2(out, version=9, storage_plugin=plugin)
    conns: dict[tuple[str, str], Any] = {}
    with writer:
        for topic, msgtype, log_ns, build in records:
            if (topic, msgtype) not in conns:
                conns[(topic, msgtype)] = writer.add_connection(topic, msgtype, typestore=ts)
            msg = build(ts)
            if isinstance(msg, bytes):  # a deliberately broken message
                raw = msg
            else:
                raw = ts.serialize_ros1(msg, msgtype) if ros1 else ts.serialize_cdr(msg, msgtype)
            writer.write(conns[(topic, msgtype)], log_ns, raw)
    if kind == "bare_mcap":
        storage = next(p for p in out.iterdir() if p.suffix == ".mcap")
        bare = out.parent / f"{out.name}.mcap"
        storage.rename(bare)
        shutil.rmtree(out)
        return bare
    return out


def robot_recording(
    robots: Sequence[Robot],
    scan_times: dict[str, Sequence[int]],
    tf_times: dict[str, Sequence[int]] | None = None,
    rec: Recording | None = None,
    **scan_kw,
) -> Recording:
    """tf of every robot (2 Hz from T0 to the last scan, unless given) and its scans."""
    rec = rec or Recording()
    for robot in robots:
        times = scan_times[robot.name]
        if tf_times and robot.name in tf_times:
            tft = tf_times[robot.name]
        else:
            tft = range(T0, max(times) + S // 2 + 1, S // 2)
        rec.robot_tf(robot, tft)
        for t in times:
            rec.robot_scan(robot, t, **scan_kw)
    return rec


# -- reference maps and checks ----------------------------------------------------------------


def reference_map(
    shots: Iterable[Shot],
    resolution: float = 0.1,
    max_range: float = -1.0,
    poses: Callable[[Shot], np.ndarray] | None = None,
) -> octofuse.OccupancyMap:
    """Insert ``shots`` in log-time order with ``insert_scan_from_sensor`` (no-return beams skipped)."""
    m = octofuse.OccupancyMap(resolution)
    for s in sorted(shots, key=lambda s: s.log_ns):
        if len(s.points):
            m.insert_scan_from_sensor(s.points, s.pose if poses is None else poses(s), max_range)
    return m


def reference_maps(
    shots: Sequence[Shot], agents: dict[str, str], resolution: float = 0.1, max_range: float = -1.0
) -> dict[str, octofuse.OccupancyMap]:
    """``agents`` = {name: topic}: one map per agent and ``"centralized"`` (all their shots)."""
    out = {
        name: reference_map([s for s in shots if s.topic == topic], resolution, max_range)
        for name, topic in agents.items()
    }
    topics = set(agents.values())
    out["centralized"] = reference_map(
        [s for s in shots if s.topic in topics], resolution, max_range
    )
    return out


def sorted_leaves(m: octofuse.OccupancyMap):
    lv = m.leaves()
    order = np.lexsort((lv.centers[:, 2], lv.centers[:, 1], lv.centers[:, 0], lv.sizes))
    return lv.centers[order], lv.sizes[order], lv.values[order]


def assert_same_map(
    got: octofuse.OccupancyMap, want: octofuse.OccupancyMap, what: str = "map"
) -> None:
    """Leaf by leaf: same voxels, sizes and log-odds (bit for bit), and the same node count."""
    assert got.resolution == want.resolution, what
    gc, gs, gv = sorted_leaves(got)
    wc, ws, wv = sorted_leaves(want)
    assert len(gc) == len(wc), f"{what}: {len(gc)} leaves, expected {len(wc)}"
    assert len(gc) > 0, f"{what}: empty"
    np.testing.assert_array_equal(gs, ws, err_msg=what)
    np.testing.assert_array_equal(gc, wc, err_msg=what)
    np.testing.assert_array_equal(gv.view(np.uint32), wv.view(np.uint32), err_msg=what)
    assert got.num_nodes == want.num_nodes, (
        f"{what}: {got.num_nodes} nodes, expected {want.num_nodes}"
    )


def maps_differ(a: octofuse.OccupancyMap, b: octofuse.OccupancyMap) -> bool:
    ac, as_, av = sorted_leaves(a)
    bc, bs, bv = sorted_leaves(b)
    return not (
        len(ac) == len(bc)
        and np.array_equal(ac, bc)
        and np.array_equal(as_, bs)
        and np.array_equal(av, bv)
    )


def finest_voxels(m: octofuse.OccupancyMap) -> tuple[np.ndarray, np.ndarray]:
    """Centres (N, 3) and log-odds (N,) of all finest voxels (pruned leaves expanded)."""
    lv = m.leaves()
    res = m.resolution
    centers, values = [lv.centers[lv.depths == 16]], [lv.values[lv.depths == 16]]
    for c, size, v in zip(
        lv.centers[lv.depths < 16], lv.sizes[lv.depths < 16], lv.values[lv.depths < 16]
    ):
        n = int(round(size / res))
        g = (np.arange(n) + 0.5) * res - size / 2
        sub = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3) + c
        centers.append(sub)
        values.append(np.full(len(sub), v, dtype=lv.values.dtype))
    return np.concatenate(centers), np.concatenate(values)


def values_at(m: octofuse.OccupancyMap, points: np.ndarray) -> np.ndarray:
    """Log-odds of the leaf containing each point, NaN where the map knows nothing."""
    lv = m.leaves()
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    out = np.full(len(p), np.nan)
    for i, q in enumerate(p):
        inside = np.all(np.abs(lv.centers - q) <= lv.sizes[:, None] / 2, axis=1)
        if inside.any():
            out[i] = lv.values[np.argmax(inside)]
    return out


@dataclass
class SceneCheck:
    occupied: int
    free: int
    worst_occupied: float  #: largest distance of an occupied voxel centre from a face
    worst_free: float  #: largest depth of a free voxel centre inside solid matter


def check_scene(m: octofuse.OccupancyMap, scene: Scene = ROOM, strict: bool = True) -> SceneCheck:
    """Occupied voxels lie on faces and free ones outside solids, each within one voxel.

    With ``strict=False`` the distances are only measured, not asserted.
    """
    res = m.resolution
    centers, values = finest_voxels(m)
    occ, free = centers[values > 0], centers[values <= 0]
    worst_occ = float(scene.surface_distance(occ).max()) if len(occ) else 0.0
    worst_free = float(scene.solid_depth(free).max()) if len(free) else 0.0
    if strict:
        assert worst_occ <= res, f"an occupied voxel lies {worst_occ:.3f} m from every face"
        assert worst_free <= res, f"a free voxel lies {worst_free:.3f} m deep inside solid matter"
    return SceneCheck(len(occ), len(free), worst_occ, worst_free)


# -- running the command line -----------------------------------------------------------------

_ANSI = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")


def strip_ansi(text: str) -> str:
    return _ANSI.sub("", text)


def run_cli(capsys, *args) -> tuple[int, str, str]:
    """Run ``octofuse ARGS`` in-process: (exit code, stdout, stderr)."""
    from octofuse.cli import main

    capsys.readouterr()
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, strip_ansi(out), strip_ansi(err)


def run_keeping_result(*args):
    """Run ``octofuse ARGS`` in-process: (exit code, the SimResult its outputs were written
    from, or None), to check the files against. The rules' maps, written group by group and
    freed before the outputs, are put back into it (copies taken as they were written)."""
    import dataclasses

    import pytest

    import octofuse.outputs.report as report
    from octofuse.cli import main
    from octofuse.outputs.map_exports import MapExports

    kept, write, add = {}, report.write_outputs, MapExports.add
    maps: dict = {"fused": {}, "loss": {}, "unclamped": {}}

    def keep_maps(self, res):
        for k, per in maps.items():
            for key, m in getattr(res, k).items():  # rule -> agent -> map, or agent -> map
                per[key] = {a: x.copy() for a, x in m.items()} if isinstance(m, dict) else m.copy()
        return add(self, res)

    def keep(res, *a, **kw):
        kept["res"] = dataclasses.replace(
            res, **{k: getattr(res, k) or per for k, per in maps.items()}
        )
        return write(res, *a, **kw)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(report, "write_outputs", keep)
        mp.setattr(MapExports, "add", keep_maps)
        code = main([str(a) for a in args])
    return code, kept.get("res")


# -- robot teams ------------------------------------------------------------------------------

#: (start, velocity) of up to 4 lidar robots, one per quarter of :data:`ROOM`; each drives
#: slowly while turning and stays clear of the obstacles for the first 5 s.
TEAM = (
    ((-2.3, 1.0, 0.0), (0.25, 0.0, 0.3)),
    ((2.3, -1.0, 3.0), (-0.25, 0.0, 0.3)),
    ((-0.4, -1.5, 1.5), (0.1, 0.12, -0.3)),
    ((0.3, 1.5, -1.5), (-0.1, -0.1, 0.3)),
)


def team(n: int = 4, names: Sequence[str] = ("a", "b", "c", "d")) -> list[Robot]:
    """``n`` (<= 4) lidar robots of :data:`TEAM`, named ``a``, ``b``, ... (topics ``/a/points``, ...)."""
    if not 1 <= n <= len(TEAM):
        raise ValueError(f"a team has 1 to {len(TEAM)} robots, got {n}")
    return [Robot(names[i], start=TEAM[i][0], velocity=TEAM[i][1]) for i in range(n)]


def team_times(
    robots: Sequence[Robot], n_scans: int = 4, step_s: float = 0.5, first_s: float = 0.25
) -> dict[str, list[int]]:
    """``n_scans`` stamps per robot, ``step_s`` apart; robot i starts at ``first_s + 0.05 i`` s
    after :data:`T0`, so no two scans share a stamp and none falls on a 2 Hz tf sample."""
    return {
        r.name: [T0 + int(round((first_s + 0.05 * i + step_s * k) * S)) for k in range(n_scans)]
        for i, r in enumerate(robots)
    }


def team_agents(robots: Sequence[Robot]) -> dict[str, str]:
    """{name: scan topic} of robots, as :func:`reference_maps` takes it."""
    return {r.name: r.topic for r in robots}


def voxel_keys(m) -> tuple[np.ndarray, np.ndarray]:
    """Finest voxels of a map (or loss map) as sorted int64 keys and their float64 values; a
    coarse leaf gives every voxel below it. Keys of maps of one resolution compare directly."""
    from conftest import finest_voxels

    k, v = finest_voxels(m.leaves(), m.resolution)
    k = k + (1 << 20)
    packed = (k[:, 0] << 42) | (k[:, 1] << 21) | k[:, 2]
    order = np.argsort(packed)
    return packed[order], v.astype(np.float64)[order]


def team_bag(folder, n_robots: int, scans_per_robot: int, name: str = "team"):
    """An MCAP bag of ``n_robots`` robots of :func:`team` with ``scans_per_robot`` scans each."""
    robots = team(n_robots)
    return robot_recording(robots, team_times(robots, scans_per_robot)).write(folder / name, "mcap")
