#!/usr/bin/env python3
"""Generate the simulated ``lab8`` dataset bundled with octofuse.

The scene stands for the laboratory experiment of Section IV-A of the
weighted-exponential-product fusion paper: a 15 m x 8 m room with outer walls,
a line of small skinny boxes on the left, larger boxes on the right (all boxes
10-25 cm tall) and eight robots that drive different paths for 120 s.  Each
robot carries a Hokuyo URG-04LX-like 2D lidar mounted at its front, pitched
45 degrees down so that the scan line sweeps the floor ahead of the robot.

Everything is simulated: the scene is a set of axis-aligned boxes (floor slab,
walls, obstacles) that is ray-cast exactly, and the result is written as a
ROS 1 bag (``sensor_msgs/LaserScan`` per robot, ``/tf`` and ``/tf_static``)
together with a JSON file that holds the scene ground truth, the sensor model,
the robot paths and the generator settings.

The output is deterministic: the same seed and flags give a byte-identical bag.

Only numpy and rosbags are needed::

    python data/generate_lab.py                      # data/lab8.bag + data/lab8_scene.json
    python data/generate_lab.py --robots 32 --out /tmp/lab32.bag
    python data/generate_lab.py --tiles 4 2 --duration 30 --out /tmp/lab64.bag   # 8 rooms, 64 robots
    python data/generate_lab.py --duration 600 --rate 10 --out /tmp/lab8_long.bag
    python data/generate_lab.py --bias-robot 3 --bias-offset 0.4 -0.2 --bias-yaw 3 --out /tmp/lab8_bias.bag
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.rosbag1 import Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

GENERATOR_VERSION = 1

# --------------------------------------------------------------------------- scene

ROOM_X = 15.0  # m, along x
ROOM_Y = 8.0  # m, along y
WALL_THICKNESS = 0.10
WALL_HEIGHT = 1.00
FLOOR_THICKNESS = 0.05

#: Diffuse reflectivity per surface kind (used by the return-detection model).
REFLECTIVITY = {"floor": 0.30, "wall": 0.70, "obstacle": 0.60}

# --------------------------------------------------------------------------- sensor

N_BEAMS = 667
ANGLE_MIN_DEG = -120.0
ANGLE_STEP_DEG = 0.36
RANGE_MIN = 0.02
RANGE_MAX = 5.6
#: Range noise: sigma = max(NOISE_NEAR_SIGMA, NOISE_FAR_FRACTION * r) (URG-04LX
#: datasheet accuracy: +-10 mm up to 1 m, 1 % of the measurement beyond).
NOISE_NEAR_SIGMA = 0.010
NOISE_FAR_FRACTION = 0.010
RANGE_QUANTUM = 0.001  # the sensor reports whole millimetres
#: Return detection: a Lambertian surface of reflectivity rho seen at incidence
#: angle i (from the surface normal) at range r returns with probability
#: p = 1 / (1 + (1/s)^k),  s = rho * cos(i) * (DETECT_R50 / r)^2.
#: DETECT_R50 is the range at which a perfect white target at normal incidence
#: would be detected half of the time (far beyond range_max); with the floor
#: reflectivity above, floor returns fade out beyond about 2.2 m range (grazing
#: incidence, i.e. about 2.1 m to the side of the robot), while walls and boxes
#: are seen up to range_max unless hit at a grazing angle.
DETECT_R50 = 9.4
DETECT_SHARPNESS = 8.0

MOUNT_X = 0.18  # m ahead of base_link (front of a Pioneer P3-DX)
MOUNT_Y = 0.0
MOUNT_Z = 0.40  # m above the floor
MOUNT_PITCH_DEG = 45.0  # pitched down (positive pitch about +y tilts +x towards -z)

# --------------------------------------------------------------------------- robots

ROBOT_RADIUS = 0.25
CLEARANCE = 0.35  # minimum distance between a path and any box footprint / wall
ACCEL = 0.30  # m/s^2, longitudinal acceleration / deceleration limit
OMEGA_MAX = 0.50  # rad/s, the robots slow down in tight turns
PATH_DS = 0.01  # m, arc-length sampling of the smoothed paths

# --------------------------------------------------------------------------- timing

BAG_START_NS = 1_700_000_000 * 1_000_000_000
TF_RATE_HZ = 10.0
TF_OFFSET_NS = 37_000_000  # /tf stamps: 0.037 s + k * 0.1 s after the bag start
SCAN_START_NS = 100_000_000  # first scan of robot 1, 0.1 s after the bag start
SCAN_PHASE_NS = 11_000_000  # robot k's scans are shifted by (k-1) * 11 ms

DEFAULT_OUT = Path(__file__).resolve().parent / "lab8.bag"


def box(name: str, kind: str, lo: tuple[float, float, float], hi: tuple[float, float, float]) -> dict[str, Any]:
    return {"name": name, "kind": kind, "min": [float(v) for v in lo], "max": [float(v) for v in hi]}


def obstacle(name: str, cx: float, cy: float, sx: float, sy: float, h: float) -> dict[str, Any]:
    return box(name, "obstacle", (cx - sx / 2, cy - sy / 2, 0.0), (cx + sx / 2, cy + sy / 2, h))


def build_scene() -> list[dict[str, Any]]:
    """Every surface of the lab as an axis-aligned box (map frame, floor top at z = 0)."""
    t, h = WALL_THICKNESS, WALL_HEIGHT
    boxes = [
        box("floor", "floor", (-t, -t, -FLOOR_THICKNESS), (ROOM_X + t, ROOM_Y + t, 0.0)),
        box("wall_west", "wall", (-t, -t, 0.0), (0.0, ROOM_Y + t, h)),
        box("wall_east", "wall", (ROOM_X, -t, 0.0), (ROOM_X + t, ROOM_Y + t, h)),
        box("wall_south", "wall", (0.0, -t, 0.0), (ROOM_X, 0.0, h)),
        box("wall_north", "wall", (0.0, ROOM_Y, 0.0), (ROOM_X, ROOM_Y + t, h)),
    ]
    # Left: a line of small skinny boxes along y = 4 m.
    skinny_h = [0.10, 0.25, 0.15, 0.20, 0.12, 0.25, 0.18]
    for i, hh in enumerate(skinny_h):
        boxes.append(obstacle(f"skinny_{i + 1}", 1.2 + 0.35 * i, 4.0, 0.24, 0.06, hh))
    # Right: larger boxes in three rows.
    big = [
        (11.6, 1.9, 0.60, 0.50, 0.20),
        (13.4, 1.9, 0.50, 0.70, 0.25),
        (11.5, 4.0, 0.50, 0.50, 0.15),
        (13.5, 4.0, 0.50, 0.60, 0.22),
        (11.6, 6.1, 0.50, 0.60, 0.18),
        (13.4, 6.1, 0.70, 0.50, 0.25),
    ]
    for i, (cx, cy, sx, sy, hh) in enumerate(big):
        boxes.append(obstacle(f"large_{i + 1}", cx, cy, sx, sy, hh))
    # Centre: two medium boxes seen from the corridors, one in the unexplored centre.
    boxes.append(obstacle("mid_south", 7.4, 2.4, 0.40, 0.30, 0.12))
    boxes.append(obstacle("mid_north", 7.8, 5.7, 0.30, 0.40, 0.16))
    boxes.append(obstacle("mid_centre", 7.6, 4.0, 0.40, 0.40, 0.20))
    return boxes


#: distance between the origins of neighbouring rooms of a tiled floor (their walls touch)
TILE_X = ROOM_X + 2 * WALL_THICKNESS
TILE_Y = ROOM_Y + 2 * WALL_THICKNESS


def tile_origins(tiles: tuple[int, int]) -> list[tuple[float, float]]:
    """Origins of the rooms of a floor of ``tiles = (nx, ny)`` copies of the lab, row by row."""
    nx, ny = tiles
    return [(ix * TILE_X, iy * TILE_Y) for iy in range(ny) for ix in range(nx)]


def tiled_scene(tiles: tuple[int, int]) -> list[dict[str, Any]]:
    """The boxes of a floor of ``nx x ny`` labs side by side; one room: the lab itself."""
    one = build_scene()
    if tuple(tiles) == (1, 1):
        return one
    out = []
    for t, (ox, oy) in enumerate(tile_origins(tiles)):
        for b in one:
            out.append({"name": f"room{t + 1}_{b['name']}", "kind": b["kind"],
                        "min": [b["min"][0] + ox, b["min"][1] + oy, b["min"][2]],
                        "max": [b["max"][0] + ox, b["max"][1] + oy, b["max"][2]]})
    return out


def shifted(spec: "PathSpec", ox: float, oy: float, room: int) -> "PathSpec":
    """``spec`` driven in the room whose origin is ``(ox, oy)``."""
    if (ox, oy) == (0.0, 0.0) and room == 0:
        return spec
    params = dict(spec.params)
    if "cx" in params:
        params["cx"] += ox
        params["cy"] += oy
    return PathSpec(f"room{room + 1}_{spec.name}", f"{spec.description} (room {room + 1})", spec.kind,
                    spec.speed, spec.closed, [(round(x + ox, 6), round(y + oy, 6)) for x, y in spec.waypoints],
                    spec.fillet, params, spec.reverse, spec.generated)


def robot_specs(robots: int, seed: int, tiles: tuple[int, int]) -> tuple[list["PathSpec"], list[int]]:
    """Paths of the robots and the room each one drives in. On one room: the hand-designed
    paths, then generated loops. On a tiled floor: the eight hand-designed paths in every
    room in turn (robot k in room k // 8), then generated loops spread over the rooms."""
    boxes = build_scene()
    if tuple(tiles) == (1, 1):
        specs = hand_paths()[:robots]
        specs += [generated_path(k, seed, boxes) for k in range(len(specs) + 1, robots + 1)]
        return specs, [0] * robots
    origins = tile_origins(tiles)
    hand = hand_paths()
    specs, rooms = [], []
    for k in range(robots):
        if k < len(hand) * len(origins):
            room, base = k // len(hand), hand[k % len(hand)]
        else:
            room, base = k % len(origins), generated_path(k + 1, seed, boxes)
        specs.append(shifted(base, *origins[room], room))
        rooms.append(room)
    return specs, rooms


# --------------------------------------------------------------------------- paths


@dataclass
class PathSpec:
    name: str
    description: str
    kind: str  # "polyline" (waypoints joined by circular fillets) or "lemniscate"
    speed: float  # nominal cruise speed, m/s
    closed: bool = True
    waypoints: list[tuple[float, float]] = field(default_factory=list)
    fillet: float = 0.5
    params: dict[str, float] = field(default_factory=dict)
    reverse: bool = False
    generated: bool = False


def mirror_y(pts: list[tuple[float, float]]) -> list[tuple[float, float]]:
    return [(x, ROOM_Y - y) for x, y in pts]


LOWER_LEFT_MOWER = [
    (0.6, 0.6), (4.0, 0.6), (4.0, 1.4), (1.4, 1.4), (1.4, 2.2), (4.0, 2.2), (4.0, 2.8), (0.6, 2.8),
]


def hand_paths() -> list[PathSpec]:
    """The eight hand-designed paths of the default dataset."""
    return [
        PathSpec("left_loop", "loop around the line of skinny boxes (left)", "polyline", 0.35,
                 waypoints=[(0.5, 3.3), (4.0, 3.3), (4.0, 4.7), (0.5, 4.7)], fillet=0.6),
        PathSpec("lower_left_mower", "lawn-mower lanes in the lower-left quadrant", "polyline", 0.35,
                 waypoints=LOWER_LEFT_MOWER, fillet=0.35),
        PathSpec("upper_left_mower", "lawn-mower lanes in the upper-left quadrant (reverse direction)",
                 "polyline", 0.30, waypoints=mirror_y(LOWER_LEFT_MOWER), fillet=0.35, reverse=True),
        PathSpec("south_corridor", "long narrow loop along the south wall", "polyline", 0.45,
                 waypoints=[(3.0, 0.45), (12.0, 0.45), (12.0, 0.85), (3.0, 0.85)], fillet=0.2),
        PathSpec("north_corridor", "long narrow loop along the north wall (clockwise)", "polyline", 0.40,
                 waypoints=[(3.5, 7.55), (12.0, 7.55), (12.0, 7.15), (3.5, 7.15)], fillet=0.2),
        PathSpec("right_mower", "lawn-mower lanes between the rows of large boxes", "polyline", 0.40,
                 waypoints=[(10.7, 0.8), (14.45, 0.8), (14.45, 3.0), (10.7, 3.0), (10.7, 5.05),
                            (14.45, 5.05), (14.45, 7.2), (10.7, 7.2)], fillet=0.5),
        PathSpec("right_perimeter", "clockwise loop around the right part of the room", "polyline", 0.45,
                 waypoints=[(10.5, 0.5), (10.5, 7.5), (14.5, 7.5), (14.5, 0.5)], fillet=0.8),
        PathSpec("right_figure_eight", "figure-eight around the two middle large boxes", "lemniscate", 0.35,
                 params={"cx": 12.5, "cy": 4.0, "a": 2.0, "b": 2.4}),
    ]


def generated_path(k: int, seed: int, boxes: list[dict[str, Any]]) -> PathSpec:
    """A random rounded-rectangle loop for the extra robots of scalability runs."""
    rng = np.random.default_rng([seed, 7919, k])
    for _ in range(10_000):
        hx, hy = rng.uniform(0.5, 3.0), rng.uniform(0.5, 2.5)
        cx = rng.uniform(CLEARANCE + hx, ROOM_X - CLEARANCE - hx)
        cy = rng.uniform(CLEARANCE + hy, ROOM_Y - CLEARANCE - hy)
        wp = [(cx - hx, cy - hy), (cx + hx, cy - hy), (cx + hx, cy + hy), (cx - hx, cy + hy)]
        wp = [(round(x, 3), round(y, 3)) for x, y in wp]
        spec = PathSpec(f"generated_{k}", "generated rounded-rectangle loop", "polyline",
                        round(float(rng.uniform(0.3, 0.5)), 3), waypoints=wp,
                        fillet=round(float(min(hx, hy, 0.6)), 3), reverse=bool(rng.integers(2)),
                        generated=True)
        xy = dense_path(spec)[0]
        if path_clearance(xy, boxes) >= CLEARANCE:
            return spec
    raise RuntimeError(f"could not place a path for robot {k}")


def fillet_polyline(pts: np.ndarray, closed: bool, radius: float) -> np.ndarray:
    """Densely sampled polyline whose corners are replaced by circular arcs."""
    n = len(pts)
    corners = range(n) if closed else range(1, n - 1)
    seg_len = [float(np.linalg.norm(pts[(i + 1) % n] - pts[i])) for i in range(n)]
    arcs: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # corner -> (entry, exit) points
    pieces: dict[int, np.ndarray] = {}
    for i in corners:
        p, a, b = pts[i], pts[i - 1], pts[(i + 1) % n]
        u_in = (p - a) / np.linalg.norm(p - a)
        u_out = (b - p) / np.linalg.norm(b - p)
        cross = u_in[0] * u_out[1] - u_in[1] * u_out[0]
        phi = math.atan2(cross, float(u_in @ u_out))  # signed turn angle
        if abs(phi) < 1e-9:
            continue
        r = radius
        # keep the tangent points within half of each adjacent segment
        d_max = 0.5 * min(seg_len[i - 1], seg_len[i])
        r = min(r, d_max / math.tan(abs(phi) / 2))
        d = r * math.tan(abs(phi) / 2)
        entry, exit_ = p - d * u_in, p + d * u_out
        normal = np.array([-u_in[1], u_in[0]]) * math.copysign(1.0, phi)
        centre = entry + r * normal
        a0 = math.atan2(entry[1] - centre[1], entry[0] - centre[0])
        m = max(2, int(math.ceil(r * abs(phi) / PATH_DS)) + 1)
        ang = a0 + np.linspace(0.0, phi, m)
        arc = centre + r * np.column_stack([np.cos(ang), np.sin(ang)])
        arc[0], arc[-1] = entry, exit_
        arcs[i] = (entry, exit_)
        pieces[i] = arc
    out: list[np.ndarray] = []
    order = list(range(n)) if closed else list(range(n - 1))
    for i in order:
        j = (i + 1) % n
        start = arcs[i][1] if i in arcs else pts[i]
        end = arcs[j][0] if j in arcs else pts[j]
        seg = end - start
        m = max(2, int(math.ceil(np.linalg.norm(seg) / PATH_DS)) + 1)
        line = start + np.linspace(0.0, 1.0, m)[:, None] * seg
        out.append(line[:-1])
        if j in pieces:
            out.append(pieces[j][:-1])
    if not closed:
        out.append(pts[-1][None, :])
    return np.concatenate(out)


def resample(xy: np.ndarray, closed: bool) -> np.ndarray:
    """Resample a dense curve at uniform arc-length steps of PATH_DS."""
    pts = np.vstack([xy, xy[:1]]) if closed else xy
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    total = s[-1]
    m = int(round(total / PATH_DS))
    s_new = np.linspace(0.0, total, m + 1)
    if closed:
        s_new = s_new[:-1]
    return np.column_stack([np.interp(s_new, s, pts[:, 0]), np.interp(s_new, s, pts[:, 1])])


def dense_path(spec: PathSpec) -> tuple[np.ndarray, bool]:
    """(N, 2) positions at ~PATH_DS spacing along the path, and whether it is closed."""
    if spec.kind == "lemniscate":
        p = spec.params
        u = np.linspace(0.0, 2 * math.pi, 20_000, endpoint=False)
        xy = np.column_stack([p["cx"] + p["a"] * np.cos(u), p["cy"] + p["b"] * np.sin(u) * np.cos(u)])
        closed = True
    else:
        closed = spec.closed
        xy = fillet_polyline(np.asarray(spec.waypoints, dtype=float), closed, spec.fillet)
    xy = resample(xy, closed)
    if spec.reverse:
        xy = xy[::-1].copy()
    return xy, closed


def path_clearance(xy: np.ndarray, boxes: list[dict[str, Any]]) -> float:
    """Smallest distance from the path to an obstacle footprint or to a wall."""
    d = np.min(np.column_stack([xy[:, 0], ROOM_X - xy[:, 0], xy[:, 1], ROOM_Y - xy[:, 1]]))
    for b in boxes:
        if b["kind"] != "obstacle":
            continue
        dx = np.maximum(np.maximum(b["min"][0] - xy[:, 0], xy[:, 0] - b["max"][0]), 0.0)
        dy = np.maximum(np.maximum(b["min"][1] - xy[:, 1], xy[:, 1] - b["max"][1]), 0.0)
        d = min(d, float(np.min(np.hypot(dx, dy))))
    return float(d)


class Trajectory:
    """Time-parametrised planar motion along a path.

    The robot starts at rest, accelerates with ACCEL, cruises at the path
    speed, slows down so that its turn rate stays below OMEGA_MAX and, on an
    open path, stops at the end.  Closed paths are driven lap after lap.
    """

    def __init__(self, spec: PathSpec, horizon: float):
        xy, closed = dense_path(spec)
        lap = len(xy) * PATH_DS if closed else (len(xy) - 1) * PATH_DS
        if closed:
            laps = int(math.ceil(spec.speed * horizon / lap)) + 1
            xy = np.vstack([xy] * laps + [xy[:1]])
        d = np.diff(xy, axis=0)
        heading = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
        yaw = np.concatenate([heading[:1], 0.5 * (heading[1:] + heading[:-1]), heading[-1:]])
        ds = np.linalg.norm(d, axis=1)
        s = np.concatenate([[0.0], np.cumsum(ds)])
        # curvature from the heading change over +-10 cm (the paths are smooth)
        w = 10
        dyaw = np.empty_like(yaw)
        dyaw[w:-w] = (yaw[2 * w:] - yaw[:-2 * w]) / (s[2 * w:] - s[:-2 * w])
        dyaw[:w], dyaw[-w:] = dyaw[w], dyaw[-w - 1]
        v = np.minimum(spec.speed, OMEGA_MAX / np.maximum(np.abs(dyaw), 1e-9))
        v[0] = 0.0
        if not closed:
            v[-1] = 0.0
        for i in range(1, len(v)):  # acceleration limit
            v[i] = min(v[i], math.sqrt(v[i - 1] ** 2 + 2 * ACCEL * ds[i - 1]))
        for i in range(len(v) - 2, -1, -1):  # deceleration limit
            v[i] = min(v[i], math.sqrt(v[i + 1] ** 2 + 2 * ACCEL * ds[i]))
        dt = 2 * ds / np.maximum(v[1:] + v[:-1], 1e-12)
        self.t = np.concatenate([[0.0], np.cumsum(dt)])
        self.s = s
        self.x, self.y, self.yaw = xy[:, 0], xy[:, 1], yaw
        self.length = float(s[-1])
        self.lap_length = lap
        self.closed = closed
        if closed and self.t[-1] < horizon:
            raise RuntimeError("trajectory shorter than the requested duration")

    def pose(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """x, y, yaw at the times t (seconds after the bag start); held after the end."""
        t = np.clip(t, 0.0, self.t[-1])
        return (np.interp(t, self.t, self.x), np.interp(t, self.t, self.y), np.interp(t, self.t, self.yaw))


# --------------------------------------------------------------------------- ray casting


def raycast(origins: np.ndarray, dirs: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, ...]:
    """Nearest intersection of rays with axis-aligned boxes (slab method, vectorised).

    Parameters: origins, dirs (B, 3) with unit directions; lo, hi (M, 3) box corners.
    Returns (t, box index, face axis), t = inf and index -1 where nothing is hit.
    """
    d = np.where(np.abs(dirs) < 1e-12, 1e-12, dirs)
    inv = 1.0 / d
    t1 = (lo[None, :, :] - origins[:, None, :]) * inv[:, None, :]
    t2 = (hi[None, :, :] - origins[:, None, :]) * inv[:, None, :]
    tmin = np.minimum(t1, t2)
    tnear = tmin.max(axis=2)
    tfar = np.maximum(t1, t2).min(axis=2)
    hit = (tnear <= tfar) & (tnear > 0.0)
    tn = np.where(hit, tnear, np.inf)
    idx = np.argmin(tn, axis=1)
    rows = np.arange(len(origins))
    t = tn[rows, idx]
    axis = np.argmax(tmin[rows, idx], axis=1)
    idx = np.where(np.isfinite(t), idx, -1)
    return t, idx, axis


# --------------------------------------------------------------------------- messages


def make_typestore() -> Any:
    store = get_typestore(Stores.ROS1_NOETIC)
    if "tf2_msgs/msg/TFMessage" not in store.types:
        store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"))
    return store


def yaw_quat(yaw: float) -> tuple[float, float, float, float]:
    return (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))


@dataclass
class PoseBias:
    """Error of what one robot's /tf reports: its poses are rotated by ``yaw + yaw_drift * t`` about
    its true start position, then shifted by ``offset + drift * t`` (t: seconds since the bag start).
    The scans are still taken at the true pose."""

    robot: int  # 1-based
    offset: tuple[float, float]
    yaw_deg: float
    drift: tuple[float, float]
    yaw_drift_deg: float
    pivot: tuple[float, float]

    def apply(self, t: float, x: float, y: float, yaw: float) -> tuple[float, float, float]:
        b = math.radians(self.yaw_deg + self.yaw_drift_deg * t)
        c, s = math.cos(b), math.sin(b)
        px, py = x - self.pivot[0], y - self.pivot[1]
        return (self.pivot[0] + c * px - s * py + self.offset[0] + self.drift[0] * t,
                self.pivot[1] + s * px + c * py + self.offset[1] + self.drift[1] * t, yaw + b)

    def to_json(self) -> dict[str, Any]:
        return {"robot": self.robot, "offset": list(self.offset), "yaw_deg": self.yaw_deg,
                "drift_per_s": list(self.drift), "yaw_drift_deg_per_s": self.yaw_drift_deg,
                "pivot": [r6(v) for v in self.pivot],
                "model": "reported = R(yaw_deg + yaw_drift * t) (true - pivot) + pivot + offset + drift * t, "
                         "yaw + yaw_deg + yaw_drift * t; t in s since the bag start; scans are cast at "
                         "the true pose"}


class Messages:
    def __init__(self, store: Any):
        self.store = store
        T = store.types
        self.Time, self.Header = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
        self.Vector3, self.Quaternion = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
        self.Transform, self.TransformStamped = T["geometry_msgs/msg/Transform"], T["geometry_msgs/msg/TransformStamped"]
        self.TFMessage, self.LaserScan = T["tf2_msgs/msg/TFMessage"], T["sensor_msgs/msg/LaserScan"]

    def header(self, seq: int, ns: int, frame: str) -> Any:
        return self.Header(seq=seq, stamp=self.Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000),
                           frame_id=frame)

    def transform(self, seq: int, ns: int, parent: str, child: str, xyz: tuple[float, float, float],
                  quat: tuple[float, float, float, float]) -> Any:
        return self.TransformStamped(
            header=self.header(seq, ns, parent), child_frame_id=child,
            transform=self.Transform(translation=self.Vector3(x=xyz[0], y=xyz[1], z=xyz[2]),
                                     rotation=self.Quaternion(x=quat[0], y=quat[1], z=quat[2], w=quat[3])))

    def tf(self, transforms: list[Any]) -> bytes:
        return bytes(self.store.serialize_ros1(self.TFMessage(transforms=transforms), "tf2_msgs/msg/TFMessage"))

    def scan(self, seq: int, ns: int, frame: str, f32: dict[str, np.float32], ranges: np.ndarray) -> bytes:
        msg = self.LaserScan(
            header=self.header(seq, ns, frame), angle_min=float(f32["angle_min"]),
            angle_max=float(f32["angle_max"]), angle_increment=float(f32["angle_increment"]),
            time_increment=float(f32["time_increment"]), scan_time=float(f32["scan_time"]),
            range_min=RANGE_MIN, range_max=RANGE_MAX, ranges=ranges.astype(np.float32),
            intensities=np.zeros(0, dtype=np.float32))
        return bytes(self.store.serialize_ros1(msg, "sensor_msgs/msg/LaserScan"))


# --------------------------------------------------------------------------- main


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT,
                    help="output bag; the scene JSON is written beside it as <stem>_scene.json")
    ap.add_argument("--seed", type=int, default=8, help="seed of the noise / dropout / extra-path generator")
    ap.add_argument("--rate", type=float, default=5.0, help="scan rate per robot, Hz (the real URG-04LX runs at 10)")
    ap.add_argument("--duration", type=float, default=120.0, help="length of the run, s")
    ap.add_argument("--robots", type=int, default=None,
                    help="number of robots (default: 8 per room); on one room 1-8 use the hand-designed "
                         "paths, more add generated loops")
    ap.add_argument("--tiles", type=int, nargs=2, default=(1, 1), metavar=("NX", "NY"),
                    help="a larger floor: NX x NY copies of the lab side by side (walls touching), "
                         "the eight hand-designed paths driven in every room, the same sensors")
    ap.add_argument("--noise-scale", type=float, default=1.0, help="multiplies the range noise sigma (0: exact)")
    ap.add_argument("--no-dropout", action="store_true",
                    help="every surface within range_max returns (no reflectivity / incidence model)")
    ap.add_argument("--snapshot", action="store_true",
                    help="all beams of a scan at the header stamp (time_increment = 0) instead of a sweep")
    bias = ap.add_argument_group("pose bias", "make one robot's /tf wrong (its scans stay true)")
    bias.add_argument("--bias-robot", type=int, default=None, metavar="K",
                      help="robot whose reported poses are biased (1-based); none by default")
    bias.add_argument("--bias-offset", type=float, nargs=2, default=(0.0, 0.0), metavar=("DX", "DY"),
                      help="constant offset of the reported position, m")
    bias.add_argument("--bias-yaw", type=float, default=0.0, metavar="DEG",
                      help="constant rotation of the reported poses about the robot's start, degrees")
    bias.add_argument("--bias-drift", type=float, nargs=2, default=(0.0, 0.0), metavar=("VX", "VY"),
                      help="offset growing with time, m/s")
    bias.add_argument("--bias-yaw-drift", type=float, default=0.0, metavar="DEG_PER_S",
                      help="rotation growing with time, degrees/s")
    args = ap.parse_args(argv)
    if not all(1 <= v <= 64 for v in args.tiles):
        ap.error("--tiles NX NY must be in 1..64")
    rooms = args.tiles[0] * args.tiles[1]
    if args.robots is None:
        args.robots = 8 * rooms
    if not 1 <= args.robots <= 256 * rooms:
        ap.error(f"--robots must be in 1..{256 * rooms}")
    biased = (tuple(args.bias_offset) != (0.0, 0.0) or args.bias_yaw != 0.0
              or tuple(args.bias_drift) != (0.0, 0.0) or args.bias_yaw_drift != 0.0)
    if args.bias_robot is None and biased:
        ap.error("--bias-offset, --bias-yaw, --bias-drift and --bias-yaw-drift need --bias-robot")
    if args.bias_robot is not None and not 1 <= args.bias_robot <= args.robots:
        ap.error(f"--bias-robot must be in 1..{args.robots}")
    if args.rate <= 0 or args.duration <= 0 or args.noise_scale < 0:
        ap.error("--rate and --duration must be positive, --noise-scale non-negative")
    return args


def dump_json(obj: Any) -> str:
    """Indented JSON with short lists of numbers kept on one line."""
    text = json.dumps(obj, indent=1)
    text = re.sub(r"\[\s*([-+0-9.eE]+(?:,\s*[-+0-9.eE]+)*)\s*\]",
                  lambda m: "[" + ", ".join(v.strip() for v in m.group(1).split(",")) + "]", text)
    return text + "\n"


def r6(v: float) -> float:
    return float(round(float(v), 6))


def generate(args: argparse.Namespace) -> dict[str, Any]:
    t_wall = time.perf_counter()
    tiles = tuple(args.tiles)
    boxes = tiled_scene(tiles)
    lo = np.array([b["min"] for b in boxes])
    hi = np.array([b["max"] for b in boxes])
    kinds = [b["kind"] for b in boxes]
    rho = np.array([REFLECTIVITY[k] for k in kinds])

    specs, rooms = robot_specs(args.robots, args.seed, tiles)
    room_origins = tile_origins(tiles)
    room_boxes = build_scene()
    # boxes a robot's rays can reach within range_max (all of them on one room): exact, as
    # a return from farther away is dropped anyway
    near = []
    for ox, oy in room_origins:
        m = RANGE_MAX + 1.0
        sel = ((lo[:, 0] <= ox + TILE_X + m) & (hi[:, 0] >= ox - m)
               & (lo[:, 1] <= oy + TILE_Y + m) & (hi[:, 1] >= oy - m))
        ids = np.flatnonzero(sel)
        near.append((ids, lo[ids], hi[ids]) if len(ids) < len(boxes) else (None, lo, hi))

    duration_ns = int(round(args.duration * 1e9))
    period_ns = int(round(1e9 / args.rate))
    tf_period_ns = int(round(1e9 / TF_RATE_HZ))

    # LaserScan constants, kept as float32 (as they are stored) and used as such.
    f32 = {
        "angle_min": np.float32(math.radians(ANGLE_MIN_DEG)),
        "angle_increment": np.float32(math.radians(ANGLE_STEP_DEG)),
        "scan_time": np.float32(period_ns / 1e9),
    }
    f32["angle_max"] = np.float32(np.float64(f32["angle_min"]) + (N_BEAMS - 1) * np.float64(f32["angle_increment"]))
    # The mirror turns 360 degrees per scan_time; one beam every angle_increment.
    f32["time_increment"] = np.float32(
        0.0 if args.snapshot else float(f32["scan_time"]) * math.radians(ANGLE_STEP_DEG) / (2 * math.pi))
    angles = np.float64(f32["angle_min"]) + np.arange(N_BEAMS) * np.float64(f32["angle_increment"])
    beam_dt = np.arange(N_BEAMS) * np.float64(f32["time_increment"])  # seconds after the stamp
    sweep = float(beam_dt[-1])

    pitch = math.radians(MOUNT_PITCH_DEG)
    # beam directions in base_link (before yaw): R_y(pitch) @ (cos a, sin a, 0)
    dir_b = np.column_stack([np.cos(angles) * math.cos(pitch), np.sin(angles), -np.cos(angles) * math.sin(pitch)])

    horizon = args.duration + 2.0
    trajs = [Trajectory(s, horizon) for s in specs]
    for s, tr, room in zip(specs, trajs, rooms):
        ox, oy = room_origins[room]
        c = path_clearance(np.column_stack([tr.x - ox, tr.y - oy]), room_boxes)
        if c < CLEARANCE - 1e-6:
            raise RuntimeError(f"path {s.name} passes {c:.2f} m from a box or wall")

    bias = None
    if args.bias_robot is not None:
        x0, y0, _ = (float(a[0]) for a in trajs[args.bias_robot - 1].pose(np.array([0.0])))
        bias = PoseBias(args.bias_robot, tuple(args.bias_offset), args.bias_yaw, tuple(args.bias_drift),
                        args.bias_yaw_drift, (x0, y0))

    store = make_typestore()
    msgs = Messages(store)
    n = len(specs)
    robot_ns = [f"robot{k}" for k in range(1, n + 1)]

    records: list[tuple[int, int, int, bytes]] = []  # (time, order, connection, data)
    hits_by_box = np.zeros(len(boxes), dtype=np.int64)
    counts = {"floor": 0, "obstacle": 0, "wall": 0, "dropout": 0, "nothing": 0}
    skew_err: list[np.ndarray] = []
    n_scans = [0] * n
    last_scan_end_ns = 0

    for r in range(n):
        rng = np.random.default_rng([args.seed, r + 1])
        tr = trajs[r]
        frame = f"{robot_ns[r]}/laser"
        first = SCAN_START_NS + r * SCAN_PHASE_NS
        j = 0
        while True:
            stamp = first + j * period_ns
            if stamp + sweep * 1e9 > duration_ns:
                break
            tb = stamp / 1e9 + beam_dt
            x, y, yaw = tr.pose(tb)
            cy, sy = np.cos(yaw), np.sin(yaw)
            origins = np.column_stack([x + MOUNT_X * cy - MOUNT_Y * sy, y + MOUNT_X * sy + MOUNT_Y * cy,
                                       np.full(N_BEAMS, MOUNT_Z)])
            dirs = np.column_stack([cy * dir_b[:, 0] - sy * dir_b[:, 1], sy * dir_b[:, 0] + cy * dir_b[:, 1],
                                    dir_b[:, 2]])
            ids, lo_r, hi_r = near[rooms[r]]
            t, idx, axis = raycast(origins, dirs, lo_r, hi_r)
            if ids is not None:
                idx = np.where(idx >= 0, ids[np.maximum(idx, 0)], -1)
            noise = rng.standard_normal(N_BEAMS)
            u = rng.random(N_BEAMS)
            hit = idx >= 0
            cos_inc = np.abs(dirs[np.arange(N_BEAMS), axis])
            with np.errstate(divide="ignore", invalid="ignore"):
                s = np.where(hit, rho[np.maximum(idx, 0)] * cos_inc * (DETECT_R50 / t) ** 2, 0.0)
                p = np.where(hit, 1.0 / (1.0 + (1.0 / np.maximum(s, 1e-12)) ** DETECT_SHARPNESS), 0.0)
            detected = hit & (u < p) if not args.no_dropout else hit
            sigma = np.maximum(NOISE_NEAR_SIGMA, NOISE_FAR_FRACTION * np.where(hit, t, 0.0))
            meas = np.where(hit, t + args.noise_scale * sigma * noise, np.inf)
            meas = np.round(meas / RANGE_QUANTUM) * RANGE_QUANTUM
            in_range = hit & (t <= RANGE_MAX) & (meas <= RANGE_MAX) & (meas >= RANGE_MIN)
            valid = in_range & detected
            ranges = np.where(valid, meas, np.inf)

            # bookkeeping
            np.add.at(hits_by_box, idx[valid], 1)
            reachable = hit & (t <= RANGE_MAX)
            counts["dropout"] += int(np.count_nonzero(reachable & ~valid))
            counts["nothing"] += int(np.count_nonzero(~reachable))
            if not args.snapshot and np.any(valid):
                # error made by a reader that projects the whole scan from the stamp pose
                x0, y0, yaw0 = (float(a[0]) for a in tr.pose(np.array([stamp / 1e9])))
                c0, s0 = math.cos(yaw0), math.sin(yaw0)
                o0 = np.array([x0 + MOUNT_X * c0 - MOUNT_Y * s0, y0 + MOUNT_X * s0 + MOUNT_Y * c0, MOUNT_Z])
                d0 = np.column_stack([c0 * dir_b[:, 0] - s0 * dir_b[:, 1], s0 * dir_b[:, 0] + c0 * dir_b[:, 1],
                                      dir_b[:, 2]])
                tv = t[valid, None]
                true_pt = origins[valid] + dirs[valid] * tv
                approx_pt = o0 + d0[valid] * tv
                skew_err.append(np.linalg.norm(true_pt - approx_pt, axis=1))

            data = msgs.scan(j, BAG_START_NS + stamp, frame, f32, ranges)
            records.append((BAG_START_NS + stamp, 2 + r, 2 + r, data))
            last_scan_end_ns = max(last_scan_end_ns, stamp + int(round(sweep * 1e9)))
            n_scans[r] += 1
            j += 1

    # /tf: every robot's map -> base_link at 10 Hz, one message per tick
    n_tf = 0
    k = 0
    while True:
        ts_ns = TF_OFFSET_NS + k * tf_period_ns
        if k > 0 and ts_ns - tf_period_ns >= max(last_scan_end_ns, duration_ns):  # previous tick covers all
            break
        tsec = np.array([ts_ns / 1e9])
        tfs = []
        for r in range(n):
            x, y, yaw = (float(a[0]) for a in trajs[r].pose(tsec))
            if bias is not None and r == bias.robot - 1:
                x, y, yaw = bias.apply(ts_ns / 1e9, x, y, yaw)
            tfs.append(msgs.transform(k, ts_ns + BAG_START_NS, "map", f"{robot_ns[r]}/base_link",
                                      (x, y, 0.0), yaw_quat(yaw)))
        records.append((BAG_START_NS + ts_ns, 1, 1, msgs.tf(tfs)))
        n_tf += 1
        k += 1

    static_q = (0.0, math.sin(pitch / 2), 0.0, math.cos(pitch / 2))
    static = msgs.tf([msgs.transform(0, BAG_START_NS, f"{ns}/base_link", f"{ns}/laser",
                                     (MOUNT_X, MOUNT_Y, MOUNT_Z), static_q) for ns in robot_ns])
    records.append((BAG_START_NS, 0, 0, static))
    records.sort(key=lambda rec: (rec[0], rec[1]))

    out: Path = args.out
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".partial")
    if tmp.exists():
        tmp.unlink()
    with Writer(tmp) as writer:
        conns = [writer.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=store, latching=1),
                 writer.add_connection("/tf", "tf2_msgs/msg/TFMessage", typestore=store)]
        for ns in robot_ns:
            conns.append(writer.add_connection(f"/{ns}/scan", "sensor_msgs/msg/LaserScan", typestore=store))
        for stamp_ns, _, ci, data in records:
            writer.write(conns[ci], stamp_ns, data)
    os.replace(tmp, out)

    for b, h in zip(boxes, hits_by_box):
        counts[b["kind"]] += int(h)
    total = sum(counts.values())
    skew = np.concatenate(skew_err) if skew_err else np.zeros(1)
    stats = {
        "scans": int(sum(n_scans)),
        "scans_per_robot": n_scans,
        "tf_messages": n_tf,
        "tf_static_messages": 1,
        "beams": int(total),
        "beam_fractions": {k: r6(v / total) for k, v in counts.items()},
        "returns_per_box": {b["name"]: int(h) for b, h in zip(boxes, hits_by_box)},
        "sweep_skew_error_m": {
            "note": "distance between the true hit point and the point obtained when a whole scan is "
                    "projected from the pose at its header stamp (ignoring time_increment)",
            "median": r6(np.median(skew)), "p95": r6(np.percentile(skew, 95)), "max": r6(skew.max()),
        },
        "bag_bytes": out.stat().st_size,
    }
    scene = scene_json(args, boxes, specs, trajs, f32, stats)
    if tiles != (1, 1):
        scene["name"] = f"lab{n}"
        scene["description"] = (f"Simulated floor of {tiles[0]} x {tiles[1]} copies of the 15 m x 8 m laboratory "
                                f"(walls touching) with {n} robots carrying 45-degree pitched URG-04LX-like "
                                "2D lidars; robot K drives in room room_of_robot[K-1].")
        scene["room"]["tiles"] = list(tiles)
        scene["room"]["tile_pitch"] = [r6(TILE_X), r6(TILE_Y)]
        scene["room"]["room_origins"] = [[r6(x), r6(y)] for x, y in room_origins]
        scene["room_of_robot"] = [room + 1 for room in rooms]
        scene["generator"]["tiles"] = list(tiles)
    if bias is not None:
        scene["generator"]["pose_bias"] = bias.to_json()
        scene["bag"]["topics"]["/tf"] += f"; robot{bias.robot}'s poses are biased (generator.pose_bias)"
    scene_path = out.with_name(out.stem + "_scene.json")
    scene_path.write_text(dump_json(scene))
    stats["seconds"] = time.perf_counter() - t_wall
    stats["scene_path"] = str(scene_path)
    return stats


def scene_json(args: argparse.Namespace, boxes: list[dict[str, Any]], specs: list[PathSpec],
               trajs: list[Trajectory], f32: dict[str, np.float32], stats: dict[str, Any]) -> dict[str, Any]:
    robots = []
    for k, (s, tr) in enumerate(zip(specs, trajs), start=1):
        entry: dict[str, Any] = {
            "id": k, "namespace": f"robot{k}", "scan_topic": f"/robot{k}/scan",
            "base_frame": f"robot{k}/base_link", "laser_frame": f"robot{k}/laser",
            "name": s.name, "description": s.description, "generated": s.generated,
            "path_type": s.kind, "closed": s.closed if s.kind == "polyline" else True,
            "reverse": s.reverse, "cruise_speed": s.speed, "path_length_per_lap": r6(tr.lap_length),
            "distance_driven": r6(float(np.interp(args.duration, tr.t, tr.s))),
            "scan_time_offset_s": r6((SCAN_START_NS + (k - 1) * SCAN_PHASE_NS) / 1e9),
        }
        if s.kind == "polyline":
            entry["waypoints"] = [[r6(x), r6(y)] for x, y in s.waypoints]
            entry["fillet_radius"] = s.fillet
        else:
            entry["parametric"] = {"curve": "lemniscate of Gerono",
                                   "x": "cx + a cos(u)", "y": "cy + b sin(u) cos(u)", **s.params}
            xy, _ = dense_path(s)
            step = max(1, len(xy) // 48)
            entry["waypoints"] = [[r6(x), r6(y)] for x, y in xy[::step]]
        robots.append(entry)

    q = (0.0, math.sin(math.radians(MOUNT_PITCH_DEG) / 2), 0.0, math.cos(math.radians(MOUNT_PITCH_DEG) / 2))
    return {
        "name": "lab8",
        "description": "Simulated 15 m x 8 m laboratory with eight robots carrying 45-degree pitched "
                       "URG-04LX-like 2D lidars (after Section IV-A of the WEP fusion paper).",
        "simulated": True,
        "frame": "map",
        "axes": "x along the 15 m side, y along the 8 m side, z up; floor top surface at z = 0",
        "room": {"size": [ROOM_X, ROOM_Y], "wall_height": WALL_HEIGHT, "wall_thickness": WALL_THICKNESS,
                 "floor_thickness": FLOOR_THICKNESS},
        "boxes": [{**b, "min": [r6(v) for v in b["min"]], "max": [r6(v) for v in b["max"]],
                   "reflectivity": REFLECTIVITY[b["kind"]]} for b in boxes],
        "sensor": {
            "model": "Hokuyo URG-04LX-like 2D lidar (simulated)",
            "message": "sensor_msgs/LaserScan, ranges as float32, intensities left empty",
            "fov_deg": 240.0, "step_deg": ANGLE_STEP_DEG, "beams": N_BEAMS,
            "angle_min": float(f32["angle_min"]), "angle_max": float(f32["angle_max"]),
            "angle_increment": float(f32["angle_increment"]),
            "scan_time": float(f32["scan_time"]), "time_increment": float(f32["time_increment"]),
            "beam_timing": "snapshot: every beam at the header stamp" if args.snapshot else
                           "sweep: beam i is measured at header.stamp + i * time_increment "
                           "(counter-clockwise from angle_min, the mirror turns once per scan_time)",
            "range_min": RANGE_MIN, "range_max": RANGE_MAX,
            "no_return": "+inf (REP 117); beams pointing up/backwards see nothing (no ceiling)",
            "noise": {"model": "gaussian, sigma = noise_scale * max(near_sigma, far_fraction * range), "
                               "then rounded to range_quantum",
                      "near_sigma": NOISE_NEAR_SIGMA, "far_fraction": NOISE_FAR_FRACTION,
                      "range_quantum": RANGE_QUANTUM, "noise_scale": args.noise_scale},
            "detection": {"enabled": not args.no_dropout,
                          "model": "p = 1 / (1 + s^-k), s = reflectivity * cos(incidence) * (r50 / range)^2",
                          "r50": DETECT_R50, "k": DETECT_SHARPNESS, "reflectivity": REFLECTIVITY},
            "mount": {"parent": "robotK/base_link", "child": "robotK/laser",
                      "translation": [MOUNT_X, MOUNT_Y, MOUNT_Z], "pitch_deg_down": MOUNT_PITCH_DEG,
                      "quaternion_xyzw": [r6(v) for v in q]},
        },
        "robot_model": {"footprint_radius": ROBOT_RADIUS, "path_clearance": CLEARANCE,
                        "accel": ACCEL, "omega_max": OMEGA_MAX,
                        "base_link": "on the floor (z = 0), x forward; map -> base_link is the true pose",
                        "mutual_visibility": "robots do not see each other (the original runs were "
                                             "sequential)"},
        "robots": robots,
        "bag": {"topics": {"/tf": "tf2_msgs/msg/TFMessage (map -> robotK/base_link for every robot, "
                                  "one message per tick)",
                           "/tf_static": "tf2_msgs/msg/TFMessage (robotK/base_link -> robotK/laser, latched)",
                           "/robotK/scan": "sensor_msgs/msg/LaserScan, frame robotK/laser"},
                "start_time_ns": BAG_START_NS, "tf_rate_hz": TF_RATE_HZ,
                "tf_stamps": f"start + {TF_OFFSET_NS / 1e9:g} s + i / {TF_RATE_HZ:g} Hz",
                "scan_stamps": f"start + {SCAN_START_NS / 1e9:g} s + (K-1) * {SCAN_PHASE_NS / 1e9:g} s "
                               f"+ j / rate"},
        "generator": {"script": "data/generate_lab.py", "version": GENERATOR_VERSION, "seed": args.seed,
                      "rate": args.rate, "duration": args.duration, "robots": args.robots,
                      "noise_scale": args.noise_scale, "no_dropout": bool(args.no_dropout),
                      "snapshot": bool(args.snapshot), "bag_file": args.out.name},
        "stats": stats,
    }


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    stats = generate(args)
    f = stats["beam_fractions"]
    print(f"wrote {args.out} ({stats['bag_bytes'] / 1e6:.2f} MB) and {stats['scene_path']} "
          f"in {stats['seconds']:.1f} s")
    print(f"scans {stats['scans']}, tf messages {stats['tf_messages']}; beams: "
          + ", ".join(f"{k} {100 * v:.1f}%" for k, v in f.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
