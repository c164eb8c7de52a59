"""Swarms on Ray: wall time, messages per second and peak memory per worker as the number of
agents grows (``octofuse.fusion.swarm.simulate_swarm``).

Floors of 8, 16, 32, 64 and 128 robots (``data/generate_lab.py --tiles NX NY``: NX x NY copies
of the lab, eight robots in each room, the same sensors) are generated into
build/bench-data/swarm/ the first time and reused. Each swarm runs in one local Ray runtime
(``--num-cpus``, 2 here) with ``--per-worker`` agents per Ray actor and a memory cap per
worker (``--memory-cap-mib``: reserved from Ray's memory resource for each worker and checked
by the worker on its resident memory after every call). The centralized map lives in one
more worker. ``--check-inprocess N`` also runs the in-process simulation on the N-robot floor
and checks that the swarm's scores are the same; the other floors are not scored (every
agent's map is compared with the whole floor's centralized map: quadratic in the floor).

    .venv/bin/python benchmarks/swarm_scaling.py [--agents 8,16,32,64,128] [--duration 20]
        [--per-worker 8] [--memory-cap-mib 768] [--rules min-info-loss] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
DATA = ROOT / "build" / "bench-data" / "swarm"
MIB = 2**20


def tiles_for(n: int) -> tuple[int, int]:
    """Rooms for n robots (8 per room), as square as possible, wider than tall."""
    rooms = max(1, math.ceil(n / 8))
    ny = int(math.sqrt(rooms))
    while rooms % ny:
        ny -= 1
    return rooms // ny, ny


def floor_bag(n: int, duration: float) -> Path:
    bag = DATA / f"floor{n}_{duration:g}s.bag"
    if not bag.is_file():
        DATA.mkdir(parents=True, exist_ok=True)
        nx, ny = tiles_for(n)
        cmd = [
            sys.executable,
            str(ROOT / "data" / "generate_lab.py"),
            "--tiles",
            str(nx),
            str(ny),
            "--robots",
            str(n),
            "--duration",
            f"{duration:g}",
            "--out",
            str(bag),
        ]
        print("generating:", " ".join(cmd[1:]), flush=True)
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return bag


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--agents", default="8,16,32,64,128")
    ap.add_argument(
        "--duration", type=float, default=20.0, help="seconds of every floor's recording"
    )
    ap.add_argument("--per-worker", type=int, default=8, help="agents per Ray actor")
    ap.add_argument("--memory-cap-mib", type=int, default=768, help="memory cap per worker, MiB")
    ap.add_argument("--rules", default="min-info-loss")
    ap.add_argument("--topology", default="max-robust:3")
    ap.add_argument("--schedule", default="aperiodic:5")
    ap.add_argument("--resolution", type=float, default=0.05)
    ap.add_argument("--num-cpus", type=int, default=2)
    ap.add_argument(
        "--check-inprocess",
        type=int,
        default=8,
        help="also run the in-process simulation on this floor and compare (0: none)",
    )
    ap.add_argument("--json", type=Path, default=ROOT / "build" / "bench" / "swarm_scaling.json")
    args = ap.parse_args(argv)

    import ray

    from octofuse.config import FuseConfig
    from octofuse.fusion.results import LOCAL
    from octofuse.fusion.simulate import simulate
    from octofuse.fusion.swarm import simulate_swarm
    from octofuse.maps.build import make_build_config
    from octofuse.maps.truth import Scene

    sizes = [int(x) for x in args.agents.split(",") if x.strip()]
    bags = {n: floor_bag(n, args.duration) for n in sizes}
    fuse = FuseConfig(rules=args.rules.split(","), topology=args.topology, schedule=args.schedule)
    ray.init(num_cpus=args.num_cpus, include_dashboard=False, log_to_driver=False)
    rows = []
    try:
        print(
            f"Ray {ray.__version__}: {ray.cluster_resources().get('CPU')} CPUs, "
            f"{ray.cluster_resources().get('memory', 0) / 2**30:.1f} GiB of memory resource",
            flush=True,
        )
        for n in sizes:
            build = make_build_config(bags[n], resolution=args.resolution, threads=1)
            truth = Scene.find(None, [bags[n]])
            t0 = time.perf_counter()
            check = n == args.check_inprocess
            res = simulate_swarm(
                build,
                fuse,
                truth=truth,
                agents_per_worker=args.per_worker,
                memory_per_worker=args.memory_cap_mib * MIB,
                score=check,
            )
            wall = time.perf_counter() - t0
            agents_w = [w for w in res.workers if w["agents"] > 0]
            central_w = [w for w in res.workers if w["agents"] == 0][0]
            row = {
                "agents": n,
                "workers": len(agents_w),
                "agents_per_worker": args.per_worker,
                "events": len(res.events),
                "messages": res.messages,
                "wall_s": round(wall, 2),
                "start_workers_s": round(res.timings["start workers"], 2),
                "run_s": round(res.timings["run (wall)"], 2),
                "final_scores_s": round(res.timings.get("final scores (wall)", 0.0), 2),
                "messages_per_s": round(res.messages_per_second, 1),
                "stream_mb": round(res.stream_bytes / 1e6, 1),
                "peak_private_worker_max_mib": round(
                    max(w["peak_private"] for w in agents_w) / MIB
                ),
                "peak_private_worker_mean_mib": round(
                    sum(w["peak_private"] for w in agents_w) / len(agents_w) / MIB
                ),
                "peak_rss_worker_max_mib": round(max(w["peak_rss"] for w in agents_w) / MIB),
                "maps_mib_per_worker_max": round(max(w["maps_bytes"] for w in agents_w) / MIB, 1),
                "maps_mib_per_agent": round(sum(w["maps_bytes"] for w in agents_w) / n / MIB, 2),
                "peak_private_central_mib": round(central_w["peak_private"] / MIB),
                "timings": {k: round(v, 2) for k, v in res.timings.items()},
            }
            if check:
                row["kl_mean"] = {
                    r: sum(s.kl_mean for s in res.scores[r].values()) / n
                    for r in [LOCAL, *fuse.rules]
                }
                t1 = time.perf_counter()
                ref = simulate(build, fuse, samples=0, truth=truth)
                row["inprocess_wall_s"] = round(time.perf_counter() - t1, 2)
                row["equal_to_inprocess"] = all(res.scores[r] == ref.scores[r] for r in ref.scores)
            rows.append(row)
            print(json.dumps(row), flush=True)
    finally:
        ray.shutdown()
    driver_peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print()
    print(
        "| agents | workers | messages | wall s | run s | messages/s | stream MB | "
        "peak private MiB/worker (max, mean) | peak RSS incl. shared, max | maps MiB/agent | "
        "central worker MiB |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['agents']} | {r['workers']} | {r['messages']} | {r['wall_s']} | {r['run_s']} | "
            f"{r['messages_per_s']} | {r['stream_mb']} | {r['peak_private_worker_max_mib']}, "
            f"{r['peak_private_worker_mean_mib']} | {r['peak_rss_worker_max_mib']} | "
            f"{r['maps_mib_per_agent']} | {r['peak_private_central_mib']} |"
        )
    print(f"driver peak RSS: {driver_peak:.0f} MiB")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(
        json.dumps(
            {
                "args": {k: str(v) for k, v in vars(args).items()},
                "rows": rows,
                "driver_peak_rss_mib": round(driver_peak),
            },
            indent=1,
        )
        + "\n"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
