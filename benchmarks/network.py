"""Where a fusion run's time goes, and how it grows with the number of agents.

1. The demo's setting (``octofuse demo``): data/lab8.bag, 8 robots, topology max-robust:3,
   schedule aperiodic:20, every rule, 8 samples of the KL over time, scores against the
   centralized map and the scene's ground truth, and the outputs (fused maps and heat maps of
   the first agent, plots, summary.json, report.md). The run is
   ``octofuse.fusion.simulate.simulate`` + ``octofuse.outputs.report.write_outputs``. Its
   wall time and CPU time are measured (CPU / wall: the cores kept busy). Inside ``simulate``
   each rule's maps are a lane of their own, and the lanes overlap on the threads, so the
   parts are thread-seconds (summed over the threads): insertion (tracing each batch's rays,
   then applying them to every rule's maps, the local-only maps and the centralized map),
   exchange + fusion (the messages of the communication events), scoring (KL samples during
   the run, and the final scores: each lane's last task), export (writing maps and heat maps) and
   the rest of ``write_outputs`` (plots, summary, report).

2. Growth with the number of agents: datasets of 4, 8, 16, 32 and 64 robots generated with
   ``data/generate_lab.py --robots N --duration D`` into build/bench-data/ (kept there and
   reused), each run with two rules (min-info-loss and naive-bayes) on max-robust:3 with the
   same schedule and samples, without writing outputs.

Every run is a fresh Python process, so its peak memory (VmHWM, the peak resident set; the
JSON also keeps ``resource.getrusage(RUSAGE_SELF).ru_maxrss``, which a process started by
fork + exec may inherit from its parent) is its own.

    .venv/bin/python benchmarks/network.py [--robots 4,8,16,32,64] [--duration 60] [--repeats R]
        [--demo-rules all|RULE,RULE] [--growth-only] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import resource
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

from bench_common import log, machine, peak_rss_mib  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
DATA = ROOT / "build" / "bench-data"
OUT = ROOT / "build" / "bench"
LAB8 = ROOT / "data" / "lab8.bag"

TOPOLOGY = "max-robust:3"
SCHEDULE = "aperiodic:20"
SAMPLES = 8
GROWTH_RULES = ("min-info-loss", "naive-bayes")

#: the parts of a run, in the order they are printed (thread-seconds inside simulate's lanes)
PARTS = (
    "insertion",
    "exchange + fusion",
    "scoring: KL samples during the run",
    "scoring: final scores",
    "export",
    "outputs (plots, summary, report)",
)


# -- one run (in its own process) --------------------------------------------------------------


def one_run(bag: str, rules: list[str], out: str | None, every: int = 1) -> dict:
    """simulate (+ write_outputs when ``out`` is given) with the demo's setting; figures as a dict."""
    from octofuse.config import RunConfig
    from octofuse.fusion.simulate import simulate
    from octofuse.maps.truth import Scene
    from octofuse.outputs.report import write_outputs

    cfg = RunConfig()
    cfg.build.bags = [bag]
    cfg.build.scan_stride = every
    cfg.fuse.topology = TOPOLOGY
    cfg.fuse.schedule = SCHEDULE
    cfg.fuse.rules = list(rules)
    scene = Scene.beside(bag)
    truth = Scene.load(scene) if scene is not None else None
    t0, c0 = time.perf_counter(), time.process_time()
    res = simulate(cfg.build, cfg.fuse, samples=SAMPLES, truth=truth)
    t_sim, cpu_sim = time.perf_counter() - t0, time.process_time() - c0
    t_out = 0.0
    if out is not None:
        cfg.out = out
        t1 = time.perf_counter()
        write_outputs(res, out, cfg, export_agents=res.agents[:1], title="octofuse benchmark run")
        t_out = time.perf_counter() - t1
    tm = dict(res.timings)
    messages = {r: res.traffic[r].messages for r in res.rules}
    scans = sum(s.scans_used for s in res.build_stats)
    points = sum(s.points for s in res.build_stats)
    sent = {r: sum(res.traffic[r].sent.values()) for r in res.rules}
    export = tm.get("export (wall)", 0.0)
    parts = {
        "insertion": tm.get("insertion", 0.0),
        "exchange + fusion": tm.get("exchange", 0.0) + tm.get("fusion", 0.0),
        "scoring: KL samples during the run": tm.get("scoring", 0.0),
        "scoring: final scores": tm.get("final scores", 0.0),
        "export": export,
        "outputs (plots, summary, report)": max(t_out - export, 0.0) if out is not None else 0.0,
    }
    return {
        "bag": bag,
        "rules": list(res.rules),
        "agents": len(res.agents),
        "scans": scans,
        "points": points,
        "events": len(res.events),
        "messages_per_rule": messages,
        "messages": sum(messages.values()),
        "bytes_sent_per_rule": sent,
        "links": len(res.graph.edges),
        "simulate_s": t_sim,
        "simulate_cpu_s": cpu_sim,
        "outputs_s": t_out,
        "wall_s": t_sim + t_out,
        "parts_s": parts,
        "timings_raw": tm,
        "fusion_summed_s": tm.get("fusion", 0.0),
        "exchange_summed_s": tm.get("exchange", 0.0),
        "central_leaves": res.central.num_leaves,
        "peak_rss_mib": peak_rss_mib(),
        "ru_maxrss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
    }


def run_in_process(bag: Path, rules: list[str], out: Path | None, every: int = 1) -> dict:
    cmd = [
        sys.executable,
        str(Path(__file__).resolve()),
        "--one",
        str(bag),
        "--rules",
        ",".join(rules),
        "--every",
        str(every),
    ]
    if out is not None:
        cmd += ["--out", str(out)]
    proc = subprocess.run(cmd, text=True, capture_output=True)
    if proc.returncode != 0:
        sys.stderr.write(proc.stdout + proc.stderr)
        raise SystemExit(f"the run on {bag} failed (exit code {proc.returncode})")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def median_run(runs: list[dict]) -> dict:
    """The run with the median wall time, with every part's median over the runs."""
    runs = sorted(runs, key=lambda r: r["wall_s"])
    mid = dict(runs[len(runs) // 2])
    mid["parts_s"] = {k: statistics.median(r["parts_s"][k] for r in runs) for k in PARTS}
    for k in (
        "simulate_s",
        "simulate_cpu_s",
        "outputs_s",
        "wall_s",
        "fusion_summed_s",
        "exchange_summed_s",
    ):
        mid[k] = statistics.median(r[k] for r in runs)
    mid["peak_rss_mib"] = max(r["peak_rss_mib"] for r in runs)
    mid["ru_maxrss_mib"] = max(r.get("ru_maxrss_mib", 0.0) for r in runs)
    mid["runs_wall_s"] = [r["wall_s"] for r in runs]
    return mid


# -- datasets ----------------------------------------------------------------------------------


def dataset(robots: int, duration: float, rate: float | None = None) -> Path:
    """build/bench-data/labN_Ds.bag, generated if missing."""
    name = f"lab{robots}_{duration:g}s" + (f"_{rate:g}hz" if rate else "") + ".bag"
    bag = DATA / name
    if not bag.exists():
        DATA.mkdir(parents=True, exist_ok=True)
        log(f"generating {bag.relative_to(ROOT)} ({robots} robots, {duration:g} s)")
        cmd = [
            sys.executable,
            str(ROOT / "data" / "generate_lab.py"),
            "--robots",
            str(robots),
            "--duration",
            str(duration),
            "--out",
            str(bag),
        ]
        if rate:
            cmd += ["--rate", str(rate)]
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return bag


# -- the benchmark -----------------------------------------------------------------------------


def run(
    robots=(4, 8, 16, 32, 64),
    duration: float = 60.0,
    repeats: int = 1,
    demo_rules=None,
    demo_every: int = 1,
    rate: float | None = None,
    demo: bool = True,
) -> dict:
    from octofuse.rules import RULES

    demo_rules = list(demo_rules or RULES)
    res: dict = {
        "machine": machine(),
        "topology": TOPOLOGY,
        "schedule": SCHEDULE,
        "samples": SAMPLES,
        "repeats": repeats,
    }
    out = OUT / "network-demo-out"
    runs = []
    for r in range(repeats if demo else 0):
        log(
            f"demo setting on {LAB8.name} with {len(demo_rules)} rules"
            + (f" (every {demo_every}th scan)" if demo_every > 1 else "")
            + f", run {r + 1} of {repeats}"
        )
        runs.append(run_in_process(LAB8, demo_rules, out, demo_every))
    shutil.rmtree(out, ignore_errors=True)
    if runs:
        res["demo"] = median_run(runs)
        res["demo"]["every"] = demo_every
    res["growth"] = []
    res["growth_duration_s"] = duration
    res["growth_rules"] = list(GROWTH_RULES)
    for n in robots:
        bag = dataset(n, duration, rate)
        runs = []
        for r in range(repeats):
            log(f"{n} agents ({bag.name}), 2 rules, run {r + 1} of {repeats}")
            runs.append(run_in_process(bag, list(GROWTH_RULES), None))
        row = median_run(runs)
        row["bag_mb"] = bag.stat().st_size / 1e6
        res["growth"].append(row)
    return res


def fmt_s(x: float) -> str:
    return f"{x:.1f}" if x >= 10 else f"{x:.2f}"


def print_tables(res: dict, out=sys.stdout) -> None:
    if "demo" in res:
        print_demo(res, out)
    print_growth(res, out)


def print_demo(res: dict, out=sys.stdout) -> None:
    p = lambda s="": print(s, file=out)  # noqa: E731
    d = res["demo"]
    p(
        f"Fusion run in the demo's setting: {Path(d['bag']).name}"
        + (f" (every {d['every']}th scan)" if d.get("every", 1) > 1 else "")
        + f", {d['agents']} agents, {res['topology']} ({d['links']} links), {res['schedule']}, "
        f"{len(d['rules'])} rules, {res['samples']} samples; median of {res['repeats']} runs"
    )
    p(f"machine: {res['machine']}")
    p(
        f"   {d['scans']:,} scans, {d['points']:,} points, {d['events']} messages per rule ({d['messages']:,} "
        f"over {len(d['rules'])} rules); wall {fmt_s(d['wall_s'])} s "
        f"(simulate {fmt_s(d['simulate_s'])} s on {cores(d):.2f} cores + write_outputs "
        f"{fmt_s(d['outputs_s'])} s), peak memory {d['peak_rss_mib']:.0f} MiB"
    )
    p(f"   {'part':42s} {'thread-s':>8s}")
    for k in PARTS:
        p(f"   {k:42s} {fmt_s(d['parts_s'][k]):>8s}")
    p(
        f"   exchange + fusion per message: {1e3 * d['parts_s']['exchange + fusion'] / max(d['messages'], 1):.1f} "
        "thread-ms (each rule's maps a lane of their own, the lanes on 2 threads)"
    )
    p()


def cores(run: dict) -> float:
    """Cores kept busy by simulate: its CPU time over its wall time."""
    return run.get("simulate_cpu_s", 0.0) / max(run["simulate_s"], 1e-9)


def print_growth(res: dict, out=sys.stdout) -> None:
    p = lambda s="": print(s, file=out)  # noqa: E731
    g = res["growth"]
    if not g:
        return
    p(f"machine: {res['machine']}")
    p(
        f"Growth with the number of agents: generated labN bags of {res['growth_duration_s']:g} s, rules "
        f"{' + '.join(res['growth_rules'])}, {res['topology']}, {res['schedule']}, {res['samples']} samples, "
        f"no outputs; median of {res['repeats']} runs"
    )
    head = (
        f"   {'agents':>6s} {'scans':>7s} {'points':>10s} {'msgs':>6s} {'wall s':>7s} {'cores':>5s} "
        f"{'insert':>7s} {'exch+fus':>8s} {'KL samp':>7s} {'scores':>7s} {'ms/msg':>7s} "
        f"{'us/point':>8s} {'peak MiB':>8s}"
    )
    p(head)
    for r in g:
        pt = r["parts_s"]
        p(
            f"   {r['agents']:6d} {r['scans']:7,d} {r['points']:10,d} {r['messages']:6,d} "
            f"{fmt_s(r['simulate_s']):>7s} {cores(r):5.2f} {fmt_s(pt['insertion']):>7s} "
            f"{fmt_s(pt['exchange + fusion']):>8s} {fmt_s(pt['scoring: KL samples during the run']):>7s} "
            f"{fmt_s(pt['scoring: final scores']):>7s} "
            f"{1e3 * pt['exchange + fusion'] / max(r['messages'], 1):7.1f} "
            f"{1e6 * pt['insertion'] / max(r['points'], 1):8.2f} {r['peak_rss_mib']:8.0f}"
        )
    p(
        "   msgs: messages over both rules; insert, exch+fus, KL samp: thread-seconds in the lanes; "
        "scores: the final scores (thread-s in the lanes);"
    )
    p(
        "   ms/msg: exchange + fusion thread-ms per message; us/point: insertion thread-us per scan "
        "point (each point goes into 4 maps: 2 rules, local-only, centralized)"
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", default="4,8,16,32,64", help="agent counts of the growth table")
    ap.add_argument("--growth-only", action="store_true", help="skip the demo-setting run")
    ap.add_argument("--duration", type=float, default=60.0, help="length of the generated bags, s")
    ap.add_argument(
        "--rate", type=float, default=None, help="scan rate of the generated bags (default 5 Hz)"
    )
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument(
        "--demo-rules", default="all", help="rules of the demo-setting run: all or a list"
    )
    ap.add_argument(
        "--quick",
        action="store_true",
        help="tiny settings: demo setting on every 20th scan with 2 rules, 4 and 8 agents for 10 s",
    )
    ap.add_argument("--json", help="also write the figures to this JSON file")
    # one run in this process (used by the benchmark itself)
    ap.add_argument("--one", help=argparse.SUPPRESS)
    ap.add_argument("--rules", help=argparse.SUPPRESS)
    ap.add_argument("--out", help=argparse.SUPPRESS)
    ap.add_argument("--every", type=int, default=1, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one:
        print(json.dumps(one_run(args.one, args.rules.split(","), args.out, args.every)))
        return 0
    from octofuse.rules import RULES

    demo_rules = list(RULES) if args.demo_rules == "all" else args.demo_rules.split(",")
    robots = tuple(int(x) for x in args.robots.split(","))
    demo_every = 1
    if args.quick:
        robots, args.duration, args.repeats, demo_every = (4, 8), 10.0, 1, 20
        demo_rules = list(GROWTH_RULES)
    res = run(
        robots,
        args.duration,
        args.repeats,
        demo_rules,
        demo_every,
        args.rate,
        demo=not args.growth_only,
    )
    print_tables(res)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(res, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
