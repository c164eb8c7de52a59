#!/usr/bin/env python3
"""Generate a simulated warehouse with 3D-lidar robots as a ROS 2 MCAP bag.

A 30 m x 20 m hall (6 m walls, pillars on a grid), four rows of pallet racks
(uprights, three levels of shelves, cartons on the shelves) and loose pallets on
the floor. Several robots (4 by default) drive loops through the aisles, each
carrying a 16-beam spinning lidar: 360 degrees in 0.4 degree steps, elevations
-15 to +15 degrees, 12 m range, Gaussian range noise, a NaN point for every beam
without a return. Every scan is an organized ``sensor_msgs/PointCloud2``
(height 16 rings, width one column per azimuth step, float32 x/y/z) in the lidar
frame at its header stamp. ``/tf`` holds map -> robotK/base_link at 20 Hz,
``/tf_static`` robotK/base_link -> robotK/lidar.

The scene is a set of axis-aligned boxes that is ray-cast exactly (numpy, two
levels: racks and hall parts first, then the parts of the racks a ray meets); the
boxes are written to ``NAME_scene.json`` beside the bag in the format of
``lab8_scene.json``, so maps of the bag can be scored against the ground truth.

The output is deterministic for a given seed and set of flags. Only numpy and
rosbags are needed::

    python data/generate_warehouse.py --out build/bench-data/warehouse4
    python data/generate_warehouse.py --robots 2 --duration 20 --out /tmp/wh2
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

GENERATOR_VERSION = 1

HALL_X, HALL_Y, HALL_Z = 30.0, 20.0, 6.0
WALL = 0.2
FLOOR_THICKNESS = 0.1

RACK_ROWS_Y = (4.0, 8.0, 12.0, 16.0)  # centre lines of the rack rows
RACK_DEPTH = 1.1
RACK_SPANS_X = ((4.0, 13.6), (16.4, 26.0))  # two racks per row, a cross aisle between
RACK_BAY = 2.4  # m between uprights
SHELF_Z = (0.15, 1.0, 1.85)  # shelf tops
SHELF_THICKNESS = 0.06
RACK_HEIGHT = 2.6
UPRIGHT = 0.08

N_RINGS = 16
ELEV_MIN_DEG, ELEV_MAX_DEG = -15.0, 15.0
AZ_STEP_DEG = 0.4
RANGE_MAX = 12.0
RANGE_MIN = 0.3
NOISE_SIGMA = 0.01
DROPOUT = 0.01  # beams lost at random (NaN)
MOUNT_Z = 0.6
SCAN_HZ = 10.0
TF_HZ = 20.0
SPEED = 1.0  # m/s

BAG_START_NS = 1_700_000_000 * 1_000_000_000


def box(name: str, kind: str, lo, hi) -> dict[str, Any]:
    return {"name": name, "kind": kind, "min": [round(float(v), 6) for v in lo],
            "max": [round(float(v), 6) for v in hi]}


def build_scene(rng: np.random.Generator) -> list[list[dict[str, Any]]]:
    """Groups of boxes: each rack is one group (its bounding box is tested first), every other
    part of the hall is a group of its own."""
    t = WALL
    groups = [[box("floor", "floor", (-t, -t, -FLOOR_THICKNESS), (HALL_X + t, HALL_Y + t, 0.0))],
              [box("wall_west", "wall", (-t, -t, 0.0), (0.0, HALL_Y + t, HALL_Z))],
              [box("wall_east", "wall", (HALL_X, -t, 0.0), (HALL_X + t, HALL_Y + t, HALL_Z))],
              [box("wall_south", "wall", (0.0, -t, 0.0), (HALL_X, 0.0, HALL_Z))],
              [box("wall_north", "wall", (0.0, HALL_Y, 0.0), (HALL_X, HALL_Y + t, HALL_Z))]]
    for i, px in enumerate((7.5, 15.0, 22.5)):
        for j, py in enumerate((2.0, 10.0, 18.0)):
            groups.append([box(f"pillar_{i}{j}", "pillar", (px - 0.2, py - 0.2, 0.0), (px + 0.2, py + 0.2, HALL_Z))])
    for r, yc in enumerate(RACK_ROWS_Y):
        y0, y1 = yc - RACK_DEPTH / 2, yc + RACK_DEPTH / 2
        for s, (x0, x1) in enumerate(RACK_SPANS_X):
            parts = []
            n_bays = int(round((x1 - x0) / RACK_BAY))
            xs = np.linspace(x0, x1, n_bays + 1)
            for u, x in enumerate(xs):
                for side, (ya, yb) in enumerate(((y0, y0 + UPRIGHT), (y1 - UPRIGHT, y1))):
                    parts.append(box(f"rack_{r}{s}_upright_{u}{side}", "rack",
                                     (x - UPRIGHT / 2, ya, 0.0), (x + UPRIGHT / 2, yb, RACK_HEIGHT)))
            for lv, z in enumerate(SHELF_Z):
                parts.append(box(f"rack_{r}{s}_shelf_{lv}", "rack", (x0, y0, z - SHELF_THICKNESS), (x1, y1, z)))
                for b in range(n_bays):  # cartons on the shelf, one or two per bay, some bays empty
                    for c in range(int(rng.integers(0, 3))):
                        w = rng.uniform(0.4, 0.9)
                        cx = xs[b] + (c + 0.5) * (RACK_BAY / 2) + rng.uniform(-0.1, 0.1)
                        d = rng.uniform(0.5, RACK_DEPTH - 0.2)
                        h = rng.uniform(0.25, 0.7)
                        cy = yc + rng.uniform(-(RACK_DEPTH - d) / 2, (RACK_DEPTH - d) / 2)
                        parts.append(box(f"rack_{r}{s}_carton_{lv}{b}{c}", "carton",
                                         (cx - w / 2, cy - d / 2, z), (cx + w / 2, cy + d / 2, z + h)))
            groups.append(parts)
    # loose pallets with loads in the end zones
    for k in range(10):
        x = rng.uniform(0.8, 2.4) if k % 2 else rng.uniform(27.6, 29.2)
        y = 2.0 + 1.7 * k
        groups.append([box(f"pallet_{k}", "pallet", (x - 0.6, y - 0.4, 0.0), (x + 0.6, y + 0.4, rng.uniform(0.3, 1.5)))])
    return groups


def robot_loop(k: int) -> np.ndarray:
    """A closed loop (dense polyline) around rack row k % 4, through the aisles either side."""
    yc = RACK_ROWS_Y[k % len(RACK_ROWS_Y)]
    ya, yb = yc - 2.0, yc + 2.0
    if k % 2:  # every other robot drives the loop the other way round
        ya, yb = yb, ya
    corners = np.array([(2.0, ya), (28.0, ya), (28.0, yb), (2.0, yb)])
    pts = np.vstack([corners, corners[:1]])
    for _ in range(4):  # Chaikin corner cutting: rounded corners
        q = 0.75 * pts[:-1] + 0.25 * pts[1:]
        r = 0.25 * pts[:-1] + 0.75 * pts[1:]
        pts = np.empty((2 * len(q), 2))
        pts[0::2], pts[1::2] = q, r
        pts = np.vstack([pts, pts[:1]])
    return pts


class Trajectory:
    def __init__(self, k: int, n_robots: int):
        pts = robot_loop(k)
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        self.s = np.concatenate([[0.0], np.cumsum(seg)])
        self.pts = pts
        self.length = self.s[-1]
        self.start = self.length * ((k // len(RACK_ROWS_Y)) / max(1, -(-n_robots // len(RACK_ROWS_Y))))
        d = np.diff(pts, axis=0)
        self.yaw = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))

    def pose(self, t: np.ndarray):
        s = np.mod(self.start + SPEED * t, self.length)
        x = np.interp(s, self.s, self.pts[:, 0])
        y = np.interp(s, self.s, self.pts[:, 1])
        mid = 0.5 * (self.s[:-1] + self.s[1:])
        yaw = np.interp(s, mid, self.yaw)
        return x, y, yaw


def slab(origins, dirs_inv, lo, hi):
    """Entry distance of rays (R, 3) into boxes (M, 3): (R, M), inf where missed."""
    tnear = tfar = None
    for ax in range(3):  # axis by axis: reductions over a length-3 axis are slow in numpy
        o, inv = origins[:, ax, None], dirs_inv[:, ax, None]
        t1 = (lo[None, :, ax] - o) * inv
        t2 = (hi[None, :, ax] - o) * inv
        lo_t, hi_t = np.minimum(t1, t2), np.maximum(t1, t2)
        tnear = lo_t if tnear is None else np.maximum(tnear, lo_t, out=tnear)
        tfar = hi_t if tfar is None else np.minimum(tfar, hi_t, out=tfar)
    return np.where((tnear <= tfar) & (tfar > 0.0), np.maximum(tnear, 0.0), np.inf)


class Scene:
    def __init__(self, groups: list[list[dict[str, Any]]]):
        self.groups = [(np.array([b["min"] for b in g], np.float32), np.array([b["max"] for b in g], np.float32))
                       for g in groups]
        self.glo = np.array([g[0].min(axis=0) for g in self.groups])
        self.ghi = np.array([g[1].max(axis=0) for g in self.groups])

    def raycast(self, origin: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        """Distance to the first box along each unit direction from one origin (inf: none)."""
        d = np.where(np.abs(dirs) < 1e-9, 1e-9, dirs)
        inv = (1.0 / d).astype(np.float32)
        org = np.broadcast_to(origin.astype(np.float32), dirs.shape)
        # groups within range of the origin only, nearest first (rays they stop skip the others)
        gap = np.maximum(np.maximum(self.glo - origin, origin - self.ghi), 0.0)
        dist = np.linalg.norm(gap, axis=1)
        gidx = np.argsort(dist, kind="stable")
        gidx = gidx[dist[gidx] < RANGE_MAX]
        tg = slab(org, inv, self.glo[gidx], self.ghi[gidx])  # (R, G)
        best = np.full(len(dirs), np.inf, np.float32)
        for j, g in enumerate(gidx):
            rays = np.nonzero(tg[:, j] < np.minimum(best, RANGE_MAX))[0]
            if len(rays) == 0:
                continue
            lo, hi = self.groups[g]
            if len(lo) == 1:
                best[rays] = np.minimum(best[rays], tg[rays, j])
            else:
                best[rays] = np.minimum(best[rays], slab(org[rays], inv[rays], lo, hi).min(axis=1))
        return best.astype(np.float64)


def make_typestore():
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_HUMBLE)


def parse_args(argv):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--out", type=Path, required=True, help="bag folder to write (replaced if present)")
    ap.add_argument("--robots", type=int, default=4)
    ap.add_argument("--duration", type=float, default=20.0, help="seconds of driving")
    ap.add_argument("--az-step", type=float, default=AZ_STEP_DEG, help="azimuth step in degrees")
    ap.add_argument("--seed", type=int, default=7)
    args = ap.parse_args(argv)
    if args.robots < 1 or args.duration <= 0 or not 0.05 <= args.az_step <= 5.0:
        ap.error("--robots >= 1, --duration > 0 and --az-step in [0.05, 5] expected")
    return args


def generate(args) -> dict[str, Any]:
    from rosbags.rosbag2 import StoragePlugin, Writer

    t_wall = time.perf_counter()
    rng = np.random.default_rng(args.seed)
    groups = build_scene(rng)
    scene = Scene(groups)
    trajs = [Trajectory(k, args.robots) for k in range(args.robots)]

    n_az = int(round(360.0 / args.az_step))
    az = np.deg2rad(np.arange(n_az) * (360.0 / n_az) - 180.0)
    el = np.deg2rad(np.linspace(ELEV_MIN_DEG, ELEV_MAX_DEG, N_RINGS))
    ce, se = np.cos(el)[:, None], np.sin(el)[:, None]
    dirs_s = np.stack([np.broadcast_to(ce * np.cos(az), (N_RINGS, n_az)),
                       np.broadcast_to(ce * np.sin(az), (N_RINGS, n_az)),
                       np.broadcast_to(se, (N_RINGS, n_az))], axis=-1).reshape(-1, 3)  # lidar frame

    store = make_typestore()
    T = store.types
    Time, Header = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
    PointField, PointCloud2 = T["sensor_msgs/msg/PointField"], T["sensor_msgs/msg/PointCloud2"]
    Vector3, Quaternion = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    Transform, TransformStamped = T["geometry_msgs/msg/Transform"], T["geometry_msgs/msg/TransformStamped"]
    TFMessage = T["tf2_msgs/msg/TFMessage"]

    def header(ns: int, frame: str):
        return Header(stamp=Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000), frame_id=frame)

    def tfs(ns: int, parent: str, child: str, x: float, y: float, z: float, yaw: float):
        return TransformStamped(header=header(ns, parent), child_frame_id=child, transform=Transform(
            translation=Vector3(x=x, y=y, z=z),
            rotation=Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))))

    fields = [PointField(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate("xyz")]
    names = [f"robot{k + 1}" for k in range(args.robots)]
    records: list[tuple[int, int, int, bytes]] = []  # (time, order, connection, data)
    n_scans = int(args.duration * SCAN_HZ)
    returns = 0
    for k, tr in enumerate(trajs):
        phase = int(k * 1e9 / SCAN_HZ / args.robots)
        for j in range(n_scans):
            ns = BAG_START_NS + int(1e8) + phase + int(j * 1e9 / SCAN_HZ)
            x, y, yaw = (float(v[0]) for v in tr.pose(np.array([(ns - BAG_START_NS) * 1e-9])))
            c, s = math.cos(yaw), math.sin(yaw)
            R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
            dirs_w = dirs_s @ R.T
            r = scene.raycast(np.array([x, y, MOUNT_Z]), dirs_w)
            r = r + rng.normal(0.0, NOISE_SIGMA, r.shape)
            lost = (r > RANGE_MAX) | (r < RANGE_MIN) | ~np.isfinite(r) | (rng.random(r.shape) < DROPOUT)
            returns += int((~lost).sum())
            pts = (dirs_s * np.where(lost, np.nan, r)[:, None]).astype(np.float32)
            msg = PointCloud2(header=header(ns, f"{names[k]}/lidar"), height=N_RINGS, width=n_az, fields=fields,
                              is_bigendian=False, point_step=12, row_step=12 * n_az,
                              data=pts.reshape(-1).view(np.uint8), is_dense=False)
            records.append((ns, 1, 2 + k, bytes(store.serialize_cdr(msg, "sensor_msgs/msg/PointCloud2"))))
    n_tf = int((args.duration + 0.3) * TF_HZ) + 1
    for i in range(n_tf):
        ns = BAG_START_NS + int(i * 1e9 / TF_HZ)
        tlist = []
        for k, tr in enumerate(trajs):
            x, y, yaw = (float(v[0]) for v in tr.pose(np.array([(ns - BAG_START_NS) * 1e-9])))
            tlist.append(tfs(ns, "map", f"{names[k]}/base_link", x, y, 0.0, yaw))
        records.append((ns, 0, 1, bytes(store.serialize_cdr(TFMessage(transforms=tlist), "tf2_msgs/msg/TFMessage"))))
    static = TFMessage(transforms=[tfs(BAG_START_NS, f"{n}/base_link", f"{n}/lidar", 0.0, 0.0, MOUNT_Z, 0.0)
                                   for n in names])
    records.append((BAG_START_NS, -1, 0, bytes(store.serialize_cdr(static, "tf2_msgs/msg/TFMessage"))))
    records.sort(key=lambda rec: (rec[0], rec[1]))

    out: Path = args.out
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".partial")
    if tmp.exists():
        shutil.rmtree(tmp)
    with Writer(tmp, version=8, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = [writer.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=store),
                 writer.add_connection("/tf", "tf2_msgs/msg/TFMessage", typestore=store)]
        for n in names:
            conns.append(writer.add_connection(f"/{n}/points", "sensor_msgs/msg/PointCloud2", typestore=store))
        for stamp_ns, _, ci, data in records:
            writer.write(conns[ci], stamp_ns, data)
    # the bag folder keeps its name: rename the storage file inside it as well
    if out.exists():
        shutil.rmtree(out)
    tmp.rename(out)
    meta = out / "metadata.yaml"
    text = meta.read_text()
    for f in out.glob(f"{tmp.name}*.mcap"):
        f.rename(out / f.name.replace(tmp.name, out.name))
        text = text.replace(f.name, f.name.replace(tmp.name, out.name))
    meta.write_text(text)

    boxes = [b for g in groups for b in g]
    stats = {"scans": n_scans * args.robots, "points_per_scan": N_RINGS * n_az, "returns": returns,
             "tf_messages": n_tf, "bag_bytes": sum(f.stat().st_size for f in out.iterdir())}
    scene_doc = {
        "name": out.name,
        "description": f"Simulated {HALL_X:g} m x {HALL_Y:g} m warehouse (pallet racks, cartons, pillars) with "
                       f"{args.robots} robots carrying 16-beam 3D lidars.",
        "simulated": True, "frame": "map",
        "axes": "x along the 30 m side, y along the 20 m side, z up; floor top surface at z = 0",
        "room": {"size": [HALL_X, HALL_Y], "wall_height": HALL_Z, "wall_thickness": WALL,
                 "floor_thickness": FLOOR_THICKNESS},
        "boxes": boxes,
        "sensor": {"model": "16-beam spinning lidar", "rings": N_RINGS, "elevation_deg": [ELEV_MIN_DEG, ELEV_MAX_DEG],
                   "azimuth_step_deg": 360.0 / n_az, "range_min": RANGE_MIN, "range_max": RANGE_MAX,
                   "range_noise_sigma": NOISE_SIGMA, "dropout": DROPOUT, "rate_hz": SCAN_HZ,
                   "no_return": "NaN point (organized cloud)",
                   "timing": "every point of a scan is measured from the pose at header.stamp (no sweep motion)"},
        "robots": [{"name": n, "topic": f"/{n}/points", "lidar_frame": f"{n}/lidar", "base_frame": f"{n}/base_link",
                    "mount_z": MOUNT_Z, "speed": SPEED} for n in names],
        "bag": {"format": "ROS 2 (mcap)", "start_ns": BAG_START_NS, "duration_s": args.duration,
                "topics": {"/tf": "map -> robotK/base_link for every robot at 20 Hz",
                           "/tf_static": "robotK/base_link -> robotK/lidar",
                           "/robotK/points": "sensor_msgs/msg/PointCloud2, organized 16 x width, frame robotK/lidar"}},
        "generator": {"script": "data/generate_warehouse.py", "version": GENERATOR_VERSION, "seed": args.seed,
                      "robots": args.robots, "duration": args.duration, "az_step_deg": args.az_step},
        "stats": stats,
    }
    scene_path = out.with_name(out.name + "_scene.json")
    scene_path.write_text(json.dumps(scene_doc, indent=1) + "\n")
    stats["seconds"] = time.perf_counter() - t_wall
    stats["scene_path"] = str(scene_path)
    return stats


def main(argv=None) -> int:
    args = parse_args(argv)
    stats = generate(args)
    print(f"wrote {args.out} ({stats['scans']} scans, {stats['returns']:,} returns, "
          f"{stats['bag_bytes'] / 1e6:.1f} MB) and {stats['scene_path']} in {stats['seconds']:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
