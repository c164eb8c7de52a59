"""Run every octofuse benchmark and print one table (``make bench``).

1. Builds the C++ benchmark (CMake, Release) into build/bench if it is missing or out of date.
2. Runs it twice: maps with sensor-model values (as built from scans) and maps with continuous
   values (as after earlier fusions, no repeated pairs of values).
3. Runs benchmarks/rules_throughput.py (the per-voxel rules on numpy arrays).
4. Prints the figures with the targets.
4b. Runs the C++ benchmark on maps built from bags ("maps"): robot2 + robot3 of a generated
   3D-lidar warehouse (data/generate_warehouse.py, generated and built once into
   build/bench-data) and robot1 + robot2 of lab8, side by side with the updateNode merge.
5. Runs benchmarks/ingest.py (scan insertion against OctoMap's insertPointCloud, and where the
   time of `octofuse build` goes) and benchmarks/network.py (a fusion run's time split in the
   demo's setting, and its growth with 4 to 32 agents on generated bags in build/bench-data).
6. Writes every figure to build/bench/results.json and the table of current figures in
   benchmarks/README.md (the rows of the parts run, dated today; not with --quick).

    .venv/bin/python benchmarks/run_all.py [--repeats N] [--pairs N] [--quick]
        [--parts fusion,maps,ingest,network,beliefs,realtime] [--ingest-repeats N] [--network-repeats N]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
BUILD = ROOT / "build" / "bench"
EXE = BUILD / "benchmarks" / "octofuse_bench_fuse_trees"

sys.path.insert(0, str(HERE))
import figures_table  # noqa: E402
import ingest  # noqa: E402
import network  # noqa: E402
import rules_throughput  # noqa: E402
from bench_common import machine  # noqa: E402

PARTS = ("fusion", "maps", "ingest", "network", "beliefs", "realtime")
DATA = ROOT / "build" / "bench-data"
#: (name, bag or generator, maps fused: a, b) for the benchmark on maps built from bags
MAP_SETS = (("warehouse", "warehouse4", "robot2", "robot3"), ("lab8", "lab8", "robot1", "robot2"))

CLOSED_FORM = ("bhattacharyya", "min-entropy", "chernoff", "min-info-loss")
WEIGHTED = ("entropy-weighted-chernoff", "kld-weighted-chernoff")


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def build() -> None:
    jobs = str(os.cpu_count() or 2)
    if not (BUILD / "CMakeCache.txt").exists():
        log(f"configuring the C++ benchmark in {BUILD.relative_to(ROOT)} (Release)")
        subprocess.run(
            [
                "cmake",
                "-S",
                str(ROOT),
                "-B",
                str(BUILD),
                "-DOCTOFUSE_BUILD_BENCHMARKS=ON",
                "-DCMAKE_BUILD_TYPE=Release",
            ],
            check=True,
            stdout=subprocess.DEVNULL,
        )
    log("building the C++ benchmark (if out of date)")
    subprocess.run(
        ["cmake", "--build", str(BUILD), "-j", jobs, "--target", "octofuse_bench_fuse_trees"],
        check=True,
        stdout=subprocess.DEVNULL,
    )


def run_trees(values: str, repeats: int, scale: float) -> dict:
    out = BUILD / f"fuse_trees_{values}.json"
    log(f"running the tree benchmark ({values} values, {repeats} runs per method)")
    t0 = time.perf_counter()
    proc = subprocess.run(
        [
            str(EXE),
            "--repeats",
            str(repeats),
            "--scale",
            str(scale),
            "--values",
            values,
            "--json",
            str(out),
        ],
        text=True,
        capture_output=True,
    )
    if proc.returncode not in (0, 1) or not out.exists():
        sys.stderr.write(proc.stdout + proc.stderr)
        raise SystemExit(f"the tree benchmark failed (exit code {proc.returncode})")
    log(f"  done in {time.perf_counter() - t0:.0f} s")
    res = json.loads(out.read_text())
    res["stdout"] = proc.stdout
    return res


def run_mixture_fusion(repeats: int, grid: int) -> dict:
    """benchmarks/mixture_fusion.py in a process of its own: its BLAS limited to one thread
    before numpy loads, as its CPU times assume."""
    out = BUILD / "mixture_fusion.json"
    BUILD.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    subprocess.run(
        [sys.executable, str(HERE / "mixture_fusion.py"), "--repeats", str(repeats)]
        + ["--grid", str(grid), "--json", str(out)],
        check=True,
        env=env,
        stdout=subprocess.DEVNULL,
    )
    return json.loads(out.read_text())


def run_realtime(repeats: int) -> list[dict] | None:
    """benchmarks/realtime_ingest.py in a process of its own, when the real Luminar bag is
    there (it is not part of the repository)."""
    import realtime_ingest

    if not realtime_ingest.LUMINAR.exists():
        log(f"realtime: skipped, {realtime_ingest.LUMINAR} not found")
        return None
    out = BUILD / "realtime_ingest.json"
    BUILD.mkdir(parents=True, exist_ok=True)
    subprocess.run(
        [sys.executable, str(HERE / "realtime_ingest.py"), "--repeats", str(repeats)]
        + ["--json", str(out)],
        check=True,
        stdout=subprocess.DEVNULL,
    )
    return json.loads(out.read_text())


def bag_path(name: str, quick: bool) -> Path:
    """lab8, or the warehouse bag, generated once into build/bench-data (data/generate_warehouse.py:
    4 robots, 16-beam 3D lidars, 20 s; 4 s with --quick)."""
    if name == "lab8":
        return ROOT / "data" / "lab8.bag"
    bag = DATA / name
    if not (bag / "metadata.yaml").exists():
        log(f"generating {bag.relative_to(ROOT)} (data/generate_warehouse.py)")
        extra = ["--duration", "4"] if quick else []
        subprocess.run(
            [sys.executable, str(ROOT / "data" / "generate_warehouse.py"), "--out", str(bag)]
            + extra,
            check=True,
        )
    return bag


def bag_maps(name: str, quick: bool) -> Path:
    """The maps of a bag, built once with `octofuse build` into build/bench-data."""
    bag = bag_path(name, quick)
    maps = DATA / f"{name}_maps"
    if not (maps / "robot1.ot").exists():
        log(
            f"building the maps of {bag.name} into {maps.relative_to(ROOT)} (once; minutes for the warehouse)"
        )
        subprocess.run(
            [str(Path(sys.executable).parent / "octofuse"), "build", str(bag), "--out", str(maps)],
            check=True,
            stdout=subprocess.DEVNULL,
        )
    return maps


def run_map_files(name: str, a: Path, b: Path, repeats: int) -> dict:
    out = BUILD / f"fuse_maps_{name}.json"
    log(
        f"running the tree benchmark on the {name} maps {a.name} + {b.name} ({repeats} runs per method)"
    )
    t0 = time.perf_counter()
    proc = subprocess.run(
        [
            str(EXE),
            "--repeats",
            str(repeats),
            "--map-a",
            str(a),
            "--map-b",
            str(b),
            "--threads",
            "2",
            "--json",
            str(out),
        ],
        text=True,
        capture_output=True,
    )
    if proc.returncode not in (0, 1) or not out.exists():
        sys.stderr.write(proc.stdout + proc.stderr)
        raise SystemExit(f"the tree benchmark failed on {name} (exit code {proc.returncode})")
    log(f"  done in {time.perf_counter() - t0:.0f} s")
    res = json.loads(out.read_text())
    res["stdout"] = proc.stdout
    res["ok"] = proc.returncode == 0
    res["maps"] = [str(a.relative_to(ROOT)), str(b.relative_to(ROOT))]
    return res


def report_maps(sets: dict[str, dict]) -> str:
    """Maps built from bags, side by side: in place and new tree (with freeing) against the merge."""
    lines: list[str] = []
    p = lines.append
    names = list(sets)
    p(
        "Tree fusion on maps built from bags (0.05 m), against OctoMap's updateNode merge in the same run"
    )
    for n, r in sets.items():
        p(
            f"   {n}: {r['maps'][0]} ({r['leaves_a']:,} leaves) + {r['maps'][1]} ({r['leaves_b']:,} leaves); "
            f"{r['voxels']:,} leaf pairs; median of {r['repeats']} runs; same results as the merges and as "
            f"fuse_maps: {'yes' if r['ok'] else 'NO'}"
        )
    p(f"   {'method':58s}" + "".join(f" {n + ' s':>12s} {'ratio':>7s}" for n in names))
    p(
        f"   {'OctoMap merge in place (expand b + updateNode)':58s}"
        + "".join(f" {sets[n]['merge_in_place_s']:12.3f} {1.0:7.2f}" for n in names)
    )
    for i, row in enumerate(sets[names[0]]["in_place"]):
        label = f"octofuse {row['rule']} fuse_into, {row['threads']} thread(s)"
        cells = ""
        for n in names:
            rr = sets[n]["in_place"][i]
            cells += f" {rr['median_s']:12.3f} {sets[n]['merge_in_place_s'] / rr['median_s']:7.2f}"
        p(f"   {label:58s}{cells}")
    merge = {
        n: next(
            r["median_s"]
            for r in sets[n]["rows"]
            if r["name"].startswith("OctoMap updateNode merge (lazy_eval=false")
        )
        for n in names
    }
    p(
        f"   {'OctoMap merge (copy a + expand b + updateNode)':58s}"
        + "".join(f" {merge[n]:12.3f} {1.0:7.2f}" for n in names)
    )
    for i, row in enumerate(sets[names[0]]["whole_cost"]):
        cells = ""
        for n in names:
            rr = sets[n]["whole_cost"][i]
            tot = rr["fuse_s"] + rr["free_s"]
            cells += f" {rr['fuse_s']:5.2f}+{rr['free_s']:.2f} {merge[n] / tot:7.2f}"
        p(f"   {'octofuse ' + row['rule'] + ' fuse_maps + freeing the result':58s}{cells}")
    return "\n".join(lines)


def fmt_rate(x: float) -> str:
    return f"{x / 1e6:,.1f} M"


def verdict(ok: bool) -> str:
    return "met" if ok else "MISSED"


def report(trees: dict[str, dict], rules: dict) -> tuple[str, dict]:
    lines: list[str] = []
    p = lines.append
    s = trees["sensor"]
    p("octofuse benchmarks")
    p(
        f"machine: {s['hardware_threads']} hardware threads, {s['memory']} memory; every benchmarked "
        "code path is single-threaded (one core)"
    )
    p("")
    p(
        "1. Tree fusion: two overlapping maps, every rule (unknown = copy) beside OctoMap's updateNode merge"
    )
    p(
        f"   map a: {s['leaves_a']:,} leaves, map b: {s['leaves_b']:,} leaves "
        f"({100 * s['finest_leaves_a'] / s['leaves_a']:.1f}% / {100 * s['finest_leaves_b'] / s['leaves_b']:.1f}% "
        "at the finest level); node layout as read from a map file"
    )
    p(
        f"   voxels = leaf pairs walked = {s['voxels']:,} ({s['voxels_both']:,} known to both maps); "
        f"median of {s['repeats']} runs"
    )
    same = all(t["same_result_eager"] and t["same_result_lazy"] for t in trees.values())
    p(
        f"   octofuse naive-bayes gives the same map as the updateNode merges (all finest-level voxels "
        f"compared): {'yes' if same else 'NO'}"
    )
    p("")
    head = f"   {'method':44s} {'sensor-model values':>27s} {'continuous values':>27s}"
    p(head)
    p(f"   {'':44s} {'voxels/s':>13s} {'time / NB':>13s} {'voxels/s':>13s} {'time / NB':>13s}")
    cont = trees["continuous"]
    for rs, rc in zip(s["rows"], cont["rows"]):
        p(
            f"   {rs['name']:44s} {fmt_rate(rs['voxels_per_s']):>13s} {rs['vs_naive_bayes']:13.2f} "
            f"{fmt_rate(rc['voxels_per_s']):>13s} {rc['vs_naive_bayes']:13.2f}"
        )
    p("")
    nb_s = next(r["median_s"] for r in s["rows"] if r["name"] == "octofuse naive-bayes")
    merge_s = next(
        r["median_s"]
        for r in s["rows"]
        if r["name"].startswith("OctoMap updateNode merge (lazy_eval=false")
    )
    p(
        f"   allocation floor: OctoMap's own deep copy of the naive-bayes result ({s['result_nodes']:,} nodes, "
        f"one heap allocation each) takes {s['copy_result_s'] * 1e3:.0f} ms, octofuse naive-bayes "
        f"{nb_s * 1e3:.0f} ms, the updateNode merge {merge_s * 1e3:.0f} ms "
        f"({merge_s / s['copy_result_s']:.1f}x the copy)"
    )
    p("")
    rows = {r["name"]: r for r in s["rows"]}
    rows_c = {r["name"]: r for r in cont["rows"]}
    merge = "OctoMap updateNode merge (lazy_eval=false)"
    nb_ratio = rows[merge]["vs_naive_bayes"]
    nb_ratio_c = rows_c[merge]["vs_naive_bayes"]
    checks = {}  # name -> (met on the main trees, figure, met with continuous values or None)
    checks["naive-bayes >= 10x the updateNode merge"] = (
        nb_ratio >= 10.0,
        f"{nb_ratio:.1f}x / {nb_ratio_c:.1f}x",
        nb_ratio_c >= 10.0,
    )
    for rule in CLOSED_FORM:
        r1, r2 = (
            rows[f"octofuse {rule}"]["vs_naive_bayes"],
            rows_c[f"octofuse {rule}"]["vs_naive_bayes"],
        )
        checks[f"{rule} within 1.5x of naive-bayes"] = (
            r1 <= 1.5,
            f"{r1:.2f}x / {r2:.2f}x",
            r2 <= 1.5,
        )
    for rule in WEIGHTED:
        r1, r2 = (
            rows[f"octofuse {rule}"]["vs_naive_bayes"],
            rows_c[f"octofuse {rule}"]["vs_naive_bayes"],
        )
        checks[f"{rule} within 4x of naive-bayes"] = (
            r1 <= 4.0,
            f"{r1:.2f}x / {r2:.2f}x",
            r2 <= 4.0,
        )

    p(
        f"2. Per-voxel rules on arrays: octofuse.fuse_logodds on {rules['pairs']:,} random log-odds pairs "
        f"(single-threaded kernel), median of {rules['repeats']} runs"
    )
    nb_s = rules["rules"]["naive-bayes"]["median_s"]
    p(f"   {'method':40s} {'pairs/s':>12s} {'time / numpy add':>17s} {'time / NB':>10s}")
    p(
        f"   {'numpy l_a + l_b':40s} {fmt_rate(rules['numpy_add_pairs_per_s']):>12s} {1.0:17.2f} "
        f"{rules['numpy_add_s'] / nb_s:10.2f}"
    )
    for rule, r in rules["rules"].items():
        p(
            f"   {'fuse_logodds ' + rule:40s} {fmt_rate(r['pairs_per_s']):>12s} "
            f"{r['median_s'] / rules['numpy_add_s']:17.2f} {r['median_s'] / nb_s:10.2f}"
        )
        if rule in CLOSED_FORM:
            checks[f"array {rule} >= 20 M pairs/s"] = (
                r["pairs_per_s"] >= 20e6,
                fmt_rate(r["pairs_per_s"]),
                None,
            )
    p("")
    p("3. Targets: verdict on the main trees (sensor-model values) [and with continuous values];")
    p("   figures: sensor-model values / continuous values")
    for name, (ok, fig, ok_c) in checks.items():
        extra = "" if ok_c is None else f"[{verdict(ok_c)}]"
        p(f"   {verdict(ok):7s} {extra:9s} {name:52s} {fig}")
    summary = {
        "trees": {k: {kk: vv for kk, vv in v.items() if kk != "stdout"} for k, v in trees.items()},
        "rules": rules,
        "targets": {
            k: {"met": ok, "met_continuous_values": ok_c, "figure": fig}
            for k, (ok, fig, ok_c) in checks.items()
        },
    }
    return "\n".join(lines), summary


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--repeats", type=int, default=5, help="timed runs per method (median reported)"
    )
    ap.add_argument("--pairs", type=int, default=10_000_000, help="pairs for the array benchmark")
    ap.add_argument(
        "--quick", action="store_true", help="small inputs, for a smoke test of the scripts"
    )
    ap.add_argument(
        "--parts",
        default=",".join(PARTS),
        help="what to run: fusion (trees + arrays), maps (trees of bags), ingest, network, "
        "beliefs (mixture fusion), realtime (3-D lidar insertion; needs the real Luminar bag) "
        "(comma separated)",
    )
    ap.add_argument("--ingest-repeats", type=int, default=3, help="timed runs per insertion method")
    ap.add_argument("--network-repeats", type=int, default=1, help="runs per fusion-run setting")
    ap.add_argument(
        "--network-duration",
        type=float,
        default=60.0,
        help="length of the generated 4-32 robot bags, s",
    )
    args = ap.parse_args(argv)
    parts = [x.strip() for x in args.parts.split(",") if x.strip()]
    bad = [x for x in parts if x not in PARTS]
    if bad:
        ap.error(f"--parts: unknown part(s) {', '.join(bad)}; parts: {', '.join(PARTS)}")
    scale = 1.0
    ingest_every, robots, demo_every, demo_rules = 1, (4, 8, 16, 32, 64), 1, None
    if args.quick:
        args.repeats, args.pairs, scale = 1, 200_000, 0.25
        args.ingest_repeats, args.network_repeats, args.network_duration = 1, 1, 10.0
        ingest_every, robots, demo_every, demo_rules = 20, (4, 8), 20, list(network.GROWTH_RULES)
    summary: dict = {}
    ok = True
    if "fusion" in parts:
        build()
        trees = {v: run_trees(v, args.repeats, scale) for v in ("sensor", "continuous")}
        log(f"running the array benchmark ({args.pairs:,} pairs, {args.repeats} runs per rule)")
        rules = rules_throughput.run(args.pairs, args.repeats)
        text, summary = report(trees, rules)
        print(text)
    if "maps" in parts:
        build()
        sets = {}
        for name, bag, ma, mb in MAP_SETS:
            d = bag_maps(bag, args.quick)
            sets[name] = run_map_files(name, d / f"{ma}.ot", d / f"{mb}.ot", args.repeats)
        print()
        print(report_maps(sets))
        summary["maps"] = {
            k: {kk: vv for kk, vv in v.items() if kk != "stdout"} for k, v in sets.items()
        }
        ok = ok and all(v["ok"] for v in sets.values())
    if "ingest" in parts:
        log(
            "running the insertion benchmark on the warehouse bag (every 40th scan, insertion only)"
        )
        bag = bag_path("warehouse4", args.quick)
        wres = ingest.run(
            bag, args.ingest_repeats, 40 if not args.quick else 100, insertion_only=True
        )
        print()
        print("4a. Scan insertion on the warehouse (16-beam 3D lidar, 12 m)")
        ingest.print_tables(wres)
        summary["ingest_warehouse"] = wres
        ok = ok and all(wres["same_maps"].values())
        log("running the insertion and build benchmark (benchmarks/ingest.py)")
        res = ingest.run(ingest.DEFAULT_BAG, args.ingest_repeats, ingest_every)
        print()
        print("4. Scan insertion and the whole build")
        ingest.print_tables(res)
        summary["ingest"] = res
        ok = ok and all(res["same_maps"].values())
    if "network" in parts:
        log("running the fusion-run benchmark (benchmarks/network.py)")
        res = network.run(
            robots, args.network_duration, args.network_repeats, demo_rules, demo_every
        )
        print()
        print("5. Fusion runs: where the time goes, and growth with the number of agents")
        network.print_tables(res)
        summary["network"] = res
    if "beliefs" in parts:
        log("running the mixture-fusion benchmark (benchmarks/mixture_fusion.py)")
        summary["mixture_fusion"] = run_mixture_fusion(args.repeats, 100 if args.quick else 400)
    if "realtime" in parts and not args.quick:
        log("running the real-time insertion benchmark (benchmarks/realtime_ingest.py)")
        rows = run_realtime(args.repeats)
        if rows:
            summary["realtime"] = rows
    BUILD.mkdir(parents=True, exist_ok=True)
    if not args.quick:
        figures_table.update(HERE / "README.md", summary, machine())
        log("table of current figures updated in benchmarks/README.md")
    if set(parts) != set(PARTS) and (BUILD / "results.json").exists():
        try:  # keep the figures of the parts not run this time
            summary = {**json.loads((BUILD / "results.json").read_text()), **summary}
        except ValueError:
            pass
    (BUILD / "results.json").write_text(json.dumps(summary, indent=2))
    log(f"figures written to {(BUILD / 'results.json').relative_to(ROOT)}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
