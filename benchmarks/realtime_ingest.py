"""Real-time insertion of 3D lidar scans: octofuse's exact and fast insert modes against
OctoMap's ``insertPointCloud`` and an ``insertRay`` loop, side by side in one run.

Scans (0.1 m voxels, 40 m maximum range, every scan of a set into one map, in order):

- ``luminar``: the five real Luminar clouds of ``luminar_pointcloud2.bag`` (topic
  ``/luminar_pointcloud``, ~36,000 points each, ranges to 250 m), read with octofuse's bag
  reading; the bag has no pose, so the sensor is at each cloud's origin;
- ``warehouse``: scans of the generated warehouse (``data/generate_warehouse.py``'s scene and
  its robot 1's loop at 10 Hz, its 16-beam lidar: 14,400 beams, 12 m range, 1 cm noise).

Methods (one core unless said): OctoMap's ``insertPointCloud`` (the baseline) and an
``insertRay`` loop (a point at a time), octofuse ``insert_scan`` exact and fast, fast with
the rays of each scan traced on 2 threads, and ``insert_scans`` fast on 2 threads (scans
traced in parallel). Per method: time per scan (wall, and the process's CPU time: the
machine may be shared), points/s, real-time factor at 10 Hz (0.1 s over the wall time per
scan, and over the CPU time), speed-up against the baseline in the same run (wall and CPU), the map's memory (``memoryUsage()``), and the
map against the baseline's over finest voxels: occupied voxels kept, extra occupied voxels
(both as fractions of the baseline's occupied voxels), free voxels (as a fraction of the
baseline's) and KL(baseline || map) summed. Times are medians of ``--repeats`` rounds, the
methods taking turns in each round.

    .venv/bin/python benchmarks/realtime_ingest.py [--repeats R] [--sets luminar,warehouse]
        [--warehouse-scans N] [--json FILE]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from bench_common import log, machine  # noqa: E402
from octofuse import _core
from octofuse.maps.occupancy import OccupancyMap
from octofuse.scans.bags import BagSet
from octofuse.scans.decode import pointcloud2_to_xyz

ROOT = Path(__file__).resolve().parent.parent
#: the shared data beside the repository (or beside a directory above it, for a checkout
#: placed deeper)
SHARED_REAL = next(
    (p / "shared" / "data" / "real" for p in ROOT.parents if (p / "shared" / "data").is_dir()),
    ROOT.parent / "shared" / "data" / "real",
)
LUMINAR = SHARED_REAL / "luminar_pointcloud2.bag"
RESOLUTION, MAX_RANGE, HZ = 0.1, 40.0, 10.0


def luminar_scans(bag: Path) -> list[tuple[np.ndarray, np.ndarray]]:
    """The bag's clouds (finite points, float32) with the sensor at their origin."""
    with BagSet(bag) as b:
        clouds = [pointcloud2_to_xyz(m.msg) for m in b.messages("/luminar_pointcloud")]
    return [
        (np.ascontiguousarray(c[np.isfinite(c).all(axis=1)], dtype=np.float32), np.zeros(3))
        for c in clouds
    ]


def warehouse_scans(n_scans: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Map-frame scans of the generated warehouse along robot 1's loop, 10 per second."""
    spec = importlib.util.spec_from_file_location(
        "generate_warehouse", ROOT / "data" / "generate_warehouse.py"
    )
    gw = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gw)
    rng = np.random.default_rng(7)
    scene, traj = gw.Scene(gw.build_scene(rng)), gw.Trajectory(0, 1)
    n_az = int(round(360.0 / gw.AZ_STEP_DEG))
    az = np.deg2rad(np.arange(n_az) * (360.0 / n_az))
    el = np.deg2rad(np.linspace(gw.ELEV_MIN_DEG, gw.ELEV_MAX_DEG, gw.N_RINGS))
    out = []
    for k in range(n_scans):
        x, y, yaw = (float(v) for v in traj.pose(np.array(k / gw.SCAN_HZ)))
        d = np.stack(
            [
                np.outer(np.cos(el), np.cos(az + yaw)),
                np.outer(np.cos(el), np.sin(az + yaw)),
                np.outer(np.sin(el), np.ones_like(az)),
            ],
            axis=-1,
        ).reshape(-1, 3)
        origin = np.array([x, y, gw.MOUNT_Z])
        r = scene.raycast(origin, d)
        keep = np.isfinite(r) & (r < gw.RANGE_MAX) & (r > gw.RANGE_MIN)
        r = r[keep] + rng.normal(0.0, gw.NOISE_SIGMA, keep.sum())
        out.append((np.ascontiguousarray(origin + d[keep] * r[:, None], dtype=np.float32), origin))
    return out


def _scan_by_scan(insert):
    def run(scans):
        m = OccupancyMap(RESOLUTION)
        for pts, origin in scans:
            insert(m, pts, origin)
        return m

    return run


def _insert_scans_fast(scans):
    m = OccupancyMap(RESOLUTION)
    m.insert_scans(scans, MAX_RANGE, threads=2, mode="fast")
    return m


#: (name, threads, build the map of a set of scans)
METHODS = [
    (
        "OctoMap insertPointCloud",
        1,
        _scan_by_scan(lambda m, p, o: m._m.insert_scan(p, o, MAX_RANGE, False)),
    ),
    (
        "OctoMap insertRay loop",
        1,
        _scan_by_scan(lambda m, p, o: _core._insert_ray_loop(m._m, p, o, MAX_RANGE)),
    ),
    ("octofuse exact", 1, _scan_by_scan(lambda m, p, o: m.insert_scan(p, o, MAX_RANGE))),
    (
        "octofuse fast",
        1,
        _scan_by_scan(lambda m, p, o: m.insert_scan(p, o, MAX_RANGE, mode="fast")),
    ),
    (
        "octofuse fast, 2 threads",
        2,
        _scan_by_scan(lambda m, p, o: m.insert_scan(p, o, MAX_RANGE, mode="fast", threads=2)),
    ),
    ("octofuse fast, insert_scans 2 threads", 2, _insert_scans_fast),
]


def agreement(m: OccupancyMap, ref: OccupancyMap) -> dict:
    """The map against the baseline's, over finest voxels (classes: occupied, free, unknown)."""
    c = m.class_counts(ref, 0.0)
    q = np.array(c["confusion"])
    occ, free = q[0].sum(), q[1].sum()
    return {
        "occupied_kept": q[0, 0] / occ,
        "extra_occupied": (q[1, 0] + q[2, 0]) / occ,
        "free_voxels": q[:, 1].sum() / free,
        "kl_sum": c["kl_sum"],
    }


def bench_set(name: str, scans, repeats: int) -> list[dict]:
    n_pts = sum(len(p) for p, _ in scans)
    log(f"{name}: {len(scans)} scans, {n_pts / len(scans):,.0f} points per scan")
    wall = {k: [] for k, _, _ in METHODS}
    cpu = {k: [] for k, _, _ in METHODS}
    maps = {}
    for r in range(repeats):
        for label, _, run in METHODS:
            c0, t0 = time.process_time(), time.perf_counter()
            maps[label] = run(scans)
            wall[label].append(time.perf_counter() - t0)
            cpu[label].append(time.process_time() - c0)
            log(f"  round {r + 1}: {label}: {wall[label][-1]:.3f} s (CPU {cpu[label][-1]:.3f} s)")
    ref = maps[METHODS[0][0]]
    base = statistics.median(wall[METHODS[0][0]])
    rows = []
    for label, threads, _ in METHODS:
        w, c = statistics.median(wall[label]), statistics.median(cpu[label])
        per_scan = w / len(scans)
        rows.append(
            {
                "set": name,
                "method": label,
                "threads": threads,
                "scans": len(scans),
                "points_per_scan": n_pts / len(scans),
                "ms_per_scan": 1e3 * per_scan,
                "cpu_ms_per_scan": 1e3 * c / len(scans),
                "points_per_s": n_pts / w,
                "realtime_factor": (1.0 / HZ) / per_scan,
                "speedup": base / w,
                "cpu_speedup": statistics.median(cpu[METHODS[0][0]]) / c,
                "memory_mb": maps[label].memory_bytes / 1e6,
                **agreement(maps[label], ref),
            }
        )
    return rows


def table(rows: list[dict]) -> str:
    """Markdown: wall times, and CPU times (what the process used: on a shared machine the
    wall times grow with the other load; ``real time (CPU)`` is 0.1 s over the CPU time per
    scan, the rate of a core of its own)."""
    head = (
        "| scans | method | ms/scan | CPU ms/scan | M points/s | real time | real time (CPU) | "
        "vs insertPointCloud (CPU) | memory | occupied kept | extra occupied | "
        "free voxels | KL |"
    )
    lines = [head, "|" + "---|" * 13]
    base = {r["set"]: r["cpu_ms_per_scan"] for r in rows if r["method"] == METHODS[0][0]}
    for r in rows:
        lines.append(
            f"| {r['set']} | {r['method']} | {r['ms_per_scan']:.0f} | {r['cpu_ms_per_scan']:.0f} | "
            f"{r['points_per_s'] / 1e6:.3f} | {r['realtime_factor']:.2f}x | {100.0 / r['cpu_ms_per_scan']:.2f}x | "
            f"{base[r['set']] / r['cpu_ms_per_scan']:.1f}x | {r['memory_mb']:.1f} MB | "
            f"{100 * r['occupied_kept']:.1f}% | {100 * r['extra_occupied']:.1f}% | "
            f"{100 * r['free_voxels']:.0f}% | {r['kl_sum']:.0f} |"
        )
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=3, help="rounds (methods taking turns)")
    ap.add_argument("--sets", default="luminar,warehouse", help="luminar, warehouse or both")
    ap.add_argument("--luminar-bag", type=Path, default=LUMINAR)
    ap.add_argument(
        "--warehouse-scans", type=int, default=20, help="scans of the warehouse (10 Hz)"
    )
    ap.add_argument("--json", type=Path, help="write the rows here")
    args = ap.parse_args(argv)
    log(machine())
    rows = []
    for name in args.sets.split(","):
        if name == "luminar":
            scans = luminar_scans(args.luminar_bag)
        elif name == "warehouse":
            scans = warehouse_scans(args.warehouse_scans)
        else:
            ap.error(f"unknown set {name!r}")
        rows += bench_set(name, scans, args.repeats)
    print(table(rows))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
