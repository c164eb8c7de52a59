"""Scan insertion and the whole ``octofuse build`` on a bag (default: data/lab8.bag).

1. Insertion: every scan of the bag is decoded once into memory (points in the sensor frame
   and the pose, with :class:`octofuse.scans.source.ScanSource`, as a build reads them), then
   inserted, in the same run, by

   - OctoMap's own ``insertPointCloud`` (the baseline): ``OccupancyMap.insert_scan_from_sensor``
     once per scan and map, i.e. into the agent's map and into the centralized map (two
     insertions per scan, as a build needs);
   - octofuse: ``octofuse.maps.build.insert_scans`` in batches of the build's size (ray keys
     computed once per scan, scans in parallel, applied to both maps, maps in parallel), on 2
     threads and on 1;

   and the same again into the agent's map only; and the rays of each batch traced once and
   applied to the agents' maps on one thread (as a run's lanes apply them), a map's scans of
   a batch walked together against one walk per scan. Before the figures are reported the
   maps of all ways are compared leaf by leaf (centres, sizes and log-odds, bit for bit).

2. The whole build: ``octofuse.maps.build.build()`` end to end (read + decode + transforms +
   insertion, decoding overlapped with insertion) and ``write_maps()``, and each stage timed
   alone to show where the time goes: opening the bag and loading /tf, reading and
   deserializing the scan messages, decoding + transform look-ups, de-skewing, insertion
   (from the scans in memory) and writing the maps.

3. The build both ways (``--builds-only`` runs only this part, e.g. on the warehouse bag):
   ``build()`` as it runs (the poses and per-beam de-skew poses of up to 64 consecutive
   scans looked up together, one call per sensor frame) and with ``per_scan_transforms``
   (a look-up per scan and, for de-skew, one per scan over its beams: the previous path),
   taking turns in each round, with ``ScanSource.scans()`` alone both ways; every map of both
   builds is compared leaf by leaf.

Points are the points of the decoded scans (the build's defaults: beams with no return are
skipped, so on lab8 these are the returns); a scan's points count once however many maps it
goes into. Every figure is the median of ``--repeats`` runs, the
methods taking turns in each round.

    .venv/bin/python benchmarks/ingest.py [--bag BAG] [--repeats R] [--every N] [--json FILE]
        [--insertion-only | --builds-only]
"""

from __future__ import annotations

import argparse
import copy
import gc
import json
import shutil
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from bench_common import log, machine, peak_rss_mib  # noqa: E402
from octofuse.maps.build import build, insert_scans, make_build_config, trace_scans, write_maps
from octofuse.maps.occupancy import OccupancyMap
from octofuse.maps.ray_batches import apply_rays
from octofuse.scans.source import SCAN_TYPES, Scan, ScanSource

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
DEFAULT_BAG = ROOT / "data" / "lab8.bag"
OUT = ROOT / "build" / "bench"


# -- insertion methods: each returns (seconds, maps) -------------------------------------------


def baseline(scans: Sequence[Scan], cfg, n_agents: int, central: bool):
    """OctoMap's insertPointCloud, scan by scan, into the agent's map (and the centralized map)."""
    maps = [OccupancyMap.from_config(cfg.map) for _ in range(n_agents)]
    cmap = OccupancyMap.from_config(cfg.map)
    t0 = time.perf_counter()
    for s in scans:
        maps[s.agent].insert_scan_from_sensor(s.points, s.pose, s.max_range)
        if central:
            cmap.insert_scan_from_sensor(s.points, s.pose, s.max_range)
    return time.perf_counter() - t0, maps, cmap


def batched_insert(scans: Sequence[Scan], cfg, n_agents: int, central: bool, threads: int):
    """octofuse.maps.build.insert_scans in batches of cfg.batch_size, as build() calls it."""
    maps = [OccupancyMap.from_config(cfg.map) for _ in range(n_agents)]
    cmap = OccupancyMap.from_config(cfg.map)
    size = cfg.batch_size
    t0 = time.perf_counter()
    for i in range(0, len(scans), size):
        batch = scans[i : i + size]
        insert_scans(
            batch, [(maps[s.agent], cmap) if central else (maps[s.agent],) for s in batch], threads
        )
    return time.perf_counter() - t0, maps, cmap


def traced_batches(scans: Sequence[Scan], cfg) -> list:
    """Each batch of cfg.batch_size scans with its rays traced once (as a run traces them)."""
    grid = OccupancyMap.from_config(cfg.map)
    size = cfg.batch_size
    return [
        (b, trace_scans(b, grid, 2))
        for b in (scans[i : i + size] for i in range(0, len(scans), size))
    ]


def apply_traced(traced: list, cfg, n_agents: int, together: bool):
    """Traced batches applied to the agents' maps on one thread, as a run's lanes apply them:
    each batch in one call (a map's scans walked together, up to 8 per walk) or scan by scan
    (one walk per scan: the baseline)."""
    maps = [OccupancyMap.from_config(cfg.map) for _ in range(n_agents)]
    calls = []  # (rays, each scan's targets), the target lists built before the clock starts
    for batch, rays in traced:
        targets = [[maps[s.agent]] for s in batch]
        if together:
            calls.append((rays, targets))
        else:
            calls += [
                (rays, [t if i == k else [] for i, t in enumerate(targets)])
                for k in range(len(batch))
            ]
    t0 = time.perf_counter()
    for rays, targets in calls:
        apply_rays(rays, targets, 1)
    return time.perf_counter() - t0, maps, None


def to_map_frame(scans: Sequence[Scan]) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Each scan's points in the map frame with its sensor origin (for the one-map public API)."""
    return [
        (
            np.ascontiguousarray(s.points @ s.pose[:3, :3].T + s.pose[:3, 3]),
            s.pose[:3, 3].copy(),
            s.max_range,
        )
        for s in scans
    ]


def public_plain(scans: Sequence[Scan], world, cfg, n_agents: int):
    """OctoMap's insertPointCloud on map-frame points (the core's plain path), scan by scan."""
    maps = [OccupancyMap.from_config(cfg.map) for _ in range(n_agents)]
    t0 = time.perf_counter()
    for s, (pts, o, r) in zip(scans, world):
        maps[s.agent]._m.insert_scan(pts, o, float(r), False)
    return time.perf_counter() - t0, maps, None


def public_insert_scan(scans: Sequence[Scan], world, cfg, n_agents: int):
    """OccupancyMap.insert_scan (the public one-map API), scan by scan."""
    maps = [OccupancyMap.from_config(cfg.map) for _ in range(n_agents)]
    t0 = time.perf_counter()
    for s, (pts, o, r) in zip(scans, world):
        maps[s.agent].insert_scan(pts, o, r)
    return time.perf_counter() - t0, maps, None


def public_insert_scans(scans: Sequence[Scan], world, cfg, n_agents: int, threads: int):
    """OccupancyMap.insert_scans: each agent's scans in lists of cfg.batch_size (same max_range)."""
    maps = [OccupancyMap.from_config(cfg.map) for _ in range(n_agents)]
    per_agent: dict[int, list] = {}
    for s, w in zip(scans, world):
        per_agent.setdefault(s.agent, []).append(w)
    t0 = time.perf_counter()
    for a, items in per_agent.items():
        for i in range(0, len(items), cfg.batch_size):
            chunk = items[i : i + cfg.batch_size]
            for r in sorted({w[2] for w in chunk}):
                maps[a].insert_scans(
                    [(p, o) for p, o, rr in chunk if rr == r], max_range=r, threads=threads
                )
    return time.perf_counter() - t0, maps, None


def sorted_leaves(m) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    lv = m.leaves()
    order = np.lexsort((lv.centers[:, 2], lv.centers[:, 1], lv.centers[:, 0], lv.sizes))
    return lv.centers[order], lv.sizes[order], lv.values[order]


def same_map(a, b) -> bool:
    ca, sa, va = sorted_leaves(a)
    cb, sb, vb = sorted_leaves(b)
    return (
        len(ca) == len(cb)
        and np.array_equal(ca, cb)
        and np.array_equal(sa, sb)
        and np.array_equal(va, vb)
    )


def same_maps(x, y, central: bool) -> bool:
    ok = all(same_map(a, b) for a, b in zip(x[1], y[1]))
    return ok and (not central or same_map(x[2], y[2]))


def median_of(times: list[float]) -> float:
    return statistics.median(times)


# -- stages of a build -------------------------------------------------------------------------


def time_open(cfg) -> float:
    t0 = time.perf_counter()
    with ScanSource(cfg):
        pass
    return time.perf_counter() - t0


def time_read(cfg) -> tuple[float, int]:
    """Reading and deserializing the scan messages alone (no transforms, no decoding)."""
    with ScanSource(cfg) as src:
        topics = {a.topic: list(SCAN_TYPES) for a in src.agents}
        n = 0
        t0 = time.perf_counter()
        for _ in src.bags.messages(topics):
            n += 1
        return time.perf_counter() - t0, n


def time_scans(cfg, per_scan_transforms: bool = False) -> tuple[float, int, int]:
    """ScanSource.scans() alone: read + deserialize + transform look-ups + decode (+ de-skew)."""
    with ScanSource(cfg, per_scan_transforms=per_scan_transforms) as src:
        t0 = time.perf_counter()
        n = pts = 0
        for s in src.scans():
            n += 1
            pts += len(s.points)
        return time.perf_counter() - t0, n, pts


def time_build(cfg, out_dir: Path):
    t0 = time.perf_counter()
    res = build(cfg)
    t_build = time.perf_counter() - t0
    t1 = time.perf_counter()
    paths = write_maps(res, out_dir)
    t_write = time.perf_counter() - t1
    size = sum(p.stat().st_size for p in paths)
    return t_build, t_write, res, size


def compare_builds(cfg, repeats: int) -> dict:
    """``build()`` with the scans' poses and beam poses looked up many scans at once (the
    build's way) and scan by scan (``per_scan_transforms``, the previous way), taking turns in
    each round; ``scans()`` alone both ways; the maps of both compared leaf by leaf."""
    paths = {"batched": False, "per_scan": True}
    build_s: dict[str, list[float]] = {k: [] for k in paths}
    scans_s: dict[str, list[float]] = {k: [] for k in paths}
    insert_s: dict[str, list[float]] = {k: [] for k in paths}
    maps: dict[str, dict] = {}
    points = 0
    for r in range(repeats):
        log(f"build, batched and per-scan transform look-ups, round {r + 1} of {repeats}")
        for name, per_scan in paths.items():
            gc.collect()
            scans_s[name].append(time_scans(cfg, per_scan)[0])
            gc.collect()
            t0 = time.perf_counter()
            bres = build(cfg, per_scan_transforms=per_scan)
            build_s[name].append(time.perf_counter() - t0)
            insert_s[name].append(bres.timings.get("insert (C++, GIL released)", float("nan")))
            points = sum(st.points for st in bres.stats)
            if r == repeats - 1:
                maps[name] = bres.all_maps()
            del bres
    same = all(same_map(maps["batched"][k], maps["per_scan"][k]) for k in maps["per_scan"])
    out = {
        name: {
            "build_s": median_of(build_s[name]),
            "build_runs_s": build_s[name],
            "build_points_per_s": points / median_of(build_s[name]),
            "insert_calls_s": median_of(insert_s[name]),
            "scans_s": median_of(scans_s[name]),
            "scans_runs_s": scans_s[name],
        }
        for name in paths
    }
    out["points"] = points
    out["speedup"] = out["per_scan"]["build_s"] / out["batched"]["build_s"]
    out["same_maps"] = same
    return out


def run(
    bag: str | Path = DEFAULT_BAG, repeats: int = 3, every: int = 1, insertion_only: bool = False
) -> dict:
    cfg = make_build_config(str(bag), scan_stride=every)
    with ScanSource(cfg) as src:
        agents = [a.name for a in src.agents]
        log(f"decoding the scans of {Path(bag).name} into memory")
        scans = list(src.scans())
    n_agents = len(agents)
    points = sum(len(s.points) for s in scans)
    res: dict = {
        "bag": str(Path(bag).resolve().relative_to(ROOT))
        if Path(bag).resolve().is_relative_to(ROOT)
        else str(bag),
        "machine": machine(),
        "repeats": repeats,
        "every": every,
        "agents": n_agents,
        "scans": len(scans),
        "points": points,
        "batch_size": cfg.batch_size,
        "resolution": cfg.map.resolution,
    }

    # 1. insertion, scans in memory
    world = to_map_frame(scans)
    traced = traced_batches(scans, cfg)
    methods: dict[str, Callable] = {
        "public-octomap": lambda: public_plain(scans, world, cfg, n_agents),
        "public-insert_scan": lambda: public_insert_scan(scans, world, cfg, n_agents),
        "public-insert_scans-t1": lambda: public_insert_scans(scans, world, cfg, n_agents, 1),
        "public-insert_scans-t2": lambda: public_insert_scans(scans, world, cfg, n_agents, 2),
        "octomap-2": lambda: baseline(scans, cfg, n_agents, True),
        "octofuse-2-t2": lambda: batched_insert(scans, cfg, n_agents, True, 2),
        "octofuse-2-t1": lambda: batched_insert(scans, cfg, n_agents, True, 1),
        "octomap-1": lambda: baseline(scans, cfg, n_agents, False),
        "octofuse-1-t2": lambda: batched_insert(scans, cfg, n_agents, False, 2),
        "octofuse-1-t1": lambda: batched_insert(scans, cfg, n_agents, False, 1),
        "apply-scan-by-scan": lambda: apply_traced(traced, cfg, n_agents, False),
        "apply-together": lambda: apply_traced(traced, cfg, n_agents, True),
    }
    times: dict[str, list[float]] = {k: [] for k in methods}
    last: dict[str, tuple] = {}
    for r in range(repeats):
        log(f"insertion, round {r + 1} of {repeats}")
        for name, fn in methods.items():
            gc.collect()
            t, maps, cmap = fn()
            times[name].append(t)
            if r == repeats - 1:
                last[name] = (t, maps, cmap)
            else:
                del maps, cmap
    same = {
        "two_maps": all(
            same_maps(last["octomap-2"], last[k], True) for k in ("octofuse-2-t2", "octofuse-2-t1")
        ),
        "one_map": all(
            same_maps(last["octomap-1"], last[k], False) for k in ("octofuse-1-t2", "octofuse-1-t1")
        ),
        "public_api": all(
            same_maps(last["public-octomap"], last[k], False)
            for k in ("public-insert_scan", "public-insert_scans-t1", "public-insert_scans-t2")
        ),
        "walks": same_maps(last["apply-scan-by-scan"], last["apply-together"], False)
        and same_maps(last["octomap-1"], last["apply-together"], False),
    }
    del traced
    central_leaves = last["octomap-2"][2].num_leaves
    central_ref = last["octomap-2"][2]
    del last
    res["insertion"] = {
        k: {"median_s": median_of(v), "runs_s": v, "points_per_s": points / median_of(v)}
        for k, v in times.items()
    }
    res["same_maps"] = same
    res["central_leaves"] = central_leaves
    if insertion_only:
        res["process_peak_rss_mib"] = peak_rss_mib()
        return res

    # 2. the whole build and its stages
    out_dir = OUT / "ingest-maps"
    nodeskew = copy.deepcopy(cfg)
    nodeskew.deskew = False
    stages: dict[str, list[float]] = {
        k: [] for k in ("open", "read", "scans_nodeskew", "scans", "build", "write")
    }
    build_insert: list[float] = []
    build_same = None
    for r in range(repeats):
        log(f"build stages, round {r + 1} of {repeats}")
        gc.collect()
        stages["open"].append(time_open(cfg))
        t, n_msgs = time_read(cfg)
        stages["read"].append(t)
        stages["scans_nodeskew"].append(time_scans(nodeskew)[0])
        stages["scans"].append(time_scans(cfg)[0])
        gc.collect()
        t_build, t_write, bres, size = time_build(cfg, out_dir)
        stages["build"].append(t_build)
        stages["write"].append(t_write)
        build_insert.append(bres.timings.get("insert (C++, GIL released)", float("nan")))
        if build_same is None:
            build_same = same_map(bres.centralized, central_ref)
        del bres
    shutil.rmtree(out_dir, ignore_errors=True)
    med = {k: median_of(v) for k, v in stages.items()}
    ins2 = res["insertion"]["octofuse-2-t2"]["median_s"]
    base2 = res["insertion"]["octomap-2"]["median_s"]
    res["build"] = {
        "messages": n_msgs,
        "stages_s": {
            "open bag + load /tf": med["open"],
            "read + deserialize scan messages": med["read"],
            "decode + transform look-ups": med["scans_nodeskew"] - med["read"],
            "de-skew": med["scans"] - med["scans_nodeskew"],
            "insertion (octofuse, 2 maps, 2 threads)": ins2,
            "write maps (.ot)": med["write"],
        },
        "stage_runs_s": stages,
        "build_s": med["build"],
        "build_insert_calls_s": median_of(build_insert),
        "write_s": med["write"],
        "end_to_end_s": med["build"] + med["write"],
        "maps_bytes": size,
        "build_points_per_s": points / med["build"],
        "same_central_as_octomap": build_same,
        # the same stages with OctoMap's insertion, one after the other (not measured end to end)
        "octomap_sequential_s": med["open"] + med["scans"] + base2 + med["write"],
    }
    res["build_paths"] = compare_builds(cfg, repeats)
    res["process_peak_rss_mib"] = peak_rss_mib()
    return res


def fmt_rate(x: float) -> str:
    return f"{x / 1e6:.2f} M"


def print_tables(res: dict, out=sys.stdout) -> None:
    p = lambda s="": print(s, file=out)  # noqa: E731
    ins = res["insertion"]
    p(
        f"Scan insertion: {res['bag']}"
        + (f" (every {res['every']}th scan)" if res["every"] > 1 else "")
        + f", {res['agents']} agents, {res['scans']:,} scans, {res['points']:,} points, "
        f"{res['resolution']} m voxels; batches of {res['batch_size']} scans; median of {res['repeats']} runs"
    )
    p(f"machine: {res['machine']}")
    p(
        f"same maps as OctoMap's insertPointCloud (every leaf: centre, size, log-odds): "
        f"agent + centralized maps {'yes' if res['same_maps']['two_maps'] else 'NO'}, "
        f"agent maps only {'yes' if res['same_maps']['one_map'] else 'NO'}"
    )
    p()
    p(
        f"   one map, public API (map-frame points, each scan into its agent's map); same maps: "
        f"{'yes' if res['same_maps'].get('public_api') else 'NO'}"
    )
    for name, label in (
        ("public-octomap", "OctoMap insertPointCloud, scan by scan (baseline)"),
        ("public-insert_scan", "OccupancyMap.insert_scan, scan by scan"),
        ("public-insert_scans-t1", "OccupancyMap.insert_scans, lists of 32, 1 thread"),
        ("public-insert_scans-t2", "OccupancyMap.insert_scans, lists of 32, 2 threads"),
    ):
        r = ins[name]
        p(
            f"     {label:58s} {r['median_s']:7.2f} {fmt_rate(r['points_per_s']):>10s} "
            f"{ins['public-octomap']['median_s'] / r['median_s']:8.2f}x"
        )
    rows = [
        (
            "agent + centralized map (2 insertions per scan)",
            "octomap-2",
            "octofuse-2-t2",
            "octofuse-2-t1",
        ),
        ("agent map only (1 insertion per scan)", "octomap-1", "octofuse-1-t2", "octofuse-1-t1"),
    ]
    p(f"   {'method':60s} {'s':>7s} {'points/s':>10s} {'speed-up':>9s}")
    for title, b, o2, o1 in rows:
        p(f"   {title}")
        for name, label in (
            (b, "OctoMap insertPointCloud, scan by scan (baseline)"),
            (o2, "octofuse insert_scans, 2 threads"),
            (o1, "octofuse insert_scans, 1 thread"),
        ):
            r = ins[name]
            p(
                f"     {label:58s} {r['median_s']:7.2f} {fmt_rate(r['points_per_s']):>10s} "
                f"{ins[b]['median_s'] / r['median_s']:8.2f}x"
            )
    if "apply-together" in ins:
        p(
            f"   traced rays applied to the agents' maps, 1 thread (a run's lanes); same maps: "
            f"{'yes' if res['same_maps'].get('walks') else 'NO'}"
        )
        for name, label in (
            ("apply-scan-by-scan", "one walk per scan (baseline)"),
            ("apply-together", "a map's scans of a batch walked together"),
        ):
            r = ins[name]
            p(
                f"     {label:58s} {r['median_s']:7.2f} {fmt_rate(r['points_per_s']):>10s} "
                f"{ins['apply-scan-by-scan']['median_s'] / r['median_s']:8.2f}x"
            )
    p()
    if "build" not in res:
        return
    b = res["build"]
    total = sum(b["stages_s"].values())
    p(
        f"Whole build (octofuse.maps.build.build + write_maps) of {res['bag']}: {b['end_to_end_s']:.2f} s end to end "
        f"({b['build_s']:.2f} s build + {b['write_s']:.2f} s writing {b['maps_bytes'] / 1e6:.1f} MB of maps), "
        f"{fmt_rate(b['build_points_per_s'])} points/s for the build"
    )
    p(
        f"   centralized map of the build = OctoMap's: {'yes' if b['same_central_as_octomap'] else 'NO'}"
    )
    p(f"   {'stage, timed alone':48s} {'s':>7s} {'share':>7s}")
    for k, v in b["stages_s"].items():
        p(f"   {k:48s} {v:7.2f} {100 * v / total:6.1f}%")
    p(f"   {'sum of the stages':48s} {total:7.2f}")
    p(
        f"   in build(), decoding runs in a second thread while the C++ insertion works: "
        f"{b['build_insert_calls_s']:.2f} s in insertion calls, the rest waiting for scans"
    )
    p(
        f"   the same stages with OctoMap's insertion, one after the other: {b['octomap_sequential_s']:.2f} s "
        f"({b['octomap_sequential_s'] / b['end_to_end_s']:.2f}x the octofuse build)"
    )
    if "build_paths" in res:
        p()
        print_build_paths(res["build_paths"], res["bag"], res["repeats"], out)


def print_build_paths(c: dict, bag: str, repeats: int, out=sys.stdout) -> None:
    p = lambda s="": print(s, file=out)  # noqa: E731
    p(
        f"build() of {bag}: transform look-ups many scans at once vs scan by scan, same run, "
        f"median of {repeats}; {c['points']:,} points; same maps (every leaf of every map): "
        f"{'yes' if c['same_maps'] else 'NO'}"
    )
    p(
        f"   {'path':44s} {'build s':>8s} {'points/s':>10s} {'insert calls s':>15s} {'scans() alone s':>16s}"
    )
    for name, label in (
        ("per_scan", "scan by scan (previous path, baseline)"),
        ("batched", "many scans at once (the build's path)"),
    ):
        r = c[name]
        p(
            f"   {label:44s} {r['build_s']:8.2f} {fmt_rate(r['build_points_per_s']):>10s} "
            f"{r['insert_calls_s']:15.2f} {r['scans_s']:16.2f}"
        )
    p(
        f"   speed-up of the build: {c['speedup']:.2f}x; scans() alone: "
        f"{c['per_scan']['scans_s'] / c['batched']['scans_s']:.2f}x"
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bag", default=str(DEFAULT_BAG))
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument(
        "--every", type=int, default=1, help="use every N-th scan of each agent (1: all)"
    )
    ap.add_argument(
        "--quick", action="store_true", help="every 20th scan, 1 run (checks that it runs)"
    )
    ap.add_argument("--json", help="also write the figures to this JSON file")
    ap.add_argument("--insertion-only", action="store_true", help="skip the build and its stages")
    ap.add_argument(
        "--builds-only",
        action="store_true",
        help="only build() with batched vs per-scan transform look-ups",
    )
    args = ap.parse_args(argv)
    if args.quick:
        args.every, args.repeats = 20, 1
    if args.builds_only:
        c = compare_builds(make_build_config(str(args.bag), scan_stride=args.every), args.repeats)
        bag = Path(args.bag).name + (f" (every {args.every}th scan)" if args.every > 1 else "")
        print(f"machine: {machine()}")
        print_build_paths(c, bag, args.repeats)
        if args.json:
            Path(args.json).parent.mkdir(parents=True, exist_ok=True)
            Path(args.json).write_text(
                json.dumps(
                    {
                        "bag": str(args.bag),
                        "every": args.every,
                        "machine": machine(),
                        "build_paths": c,
                    },
                    indent=2,
                )
            )
        return 0 if c["same_maps"] else 1
    res = run(args.bag, args.repeats, args.every, args.insertion_only)
    print_tables(res)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(res, indent=2))
    return (
        0
        if all(res["same_maps"].values()) and res.get("build_paths", {}).get("same_maps", True)
        else 1
    )


if __name__ == "__main__":
    sys.exit(main())
