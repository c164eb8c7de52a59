"""Live fleets measured: `octofuse fleet` in time against `octofuse run`, on the same bag.

For each loss level, a fleet replays the bag at ``--speed`` times its rate (one process per
robot and rule over Zenoh on loopback, the loss injected where messages leave an agent) and
`run` simulates the same schedule with the same share of messages lost. Printed per level and
rule: the agents' CPU seconds (mean) and peak resident memory (the largest), each agent's
own as it wrote them when it ended; the bytes each link carried per second of mission; the
final KL to the centralized map of the fleet beside `run`'s; and the scan-to-neighbour latency
(median, p95): from a robot's scan going into its map to a neighbour applying the first
message composed after it (wall clock, shared by the processes on this machine).

``--restart``: then a fleet of the first rule in which one agent is killed (SIGKILL) once it
has written a checkpoint, started again after ``--downtime`` seconds, and resumes from it.
Printed: its catch-up time, from being started again to being back on the mission's clock with
a message of every neighbour applied in its new epoch.

    .venv/bin/python benchmarks/fleet.py [--bag data/lab8.bag] [--every 4] [--speed 2]
        [--rules min-info-loss,channel-filter] [--losses 0,0.2,0.5] [--restart]
        [--downtime 3] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bag", default=str(REPO / "data" / "lab8.bag"))
    ap.add_argument("--every", type=int, default=4)
    ap.add_argument("--speed", type=float, default=2.0)
    ap.add_argument("--rules", default="min-info-loss,channel-filter")
    ap.add_argument("--topology", default="max-robust:3")
    ap.add_argument("--schedule", default="aperiodic:20")
    ap.add_argument("--losses", default="0,0.2,0.5")
    ap.add_argument("--restart", action="store_true")
    ap.add_argument("--downtime", type=float, default=3.0)
    ap.add_argument("--json", type=Path)
    a = ap.parse_args()

    from octofuse.config import FleetConfig, RunConfig, from_dict
    from octofuse.fusion.simulate import simulate
    from octofuse.live.fleet import agent_counts, resolved, run_fleet

    rows = []
    for loss in (float(x) for x in a.losses.split(",")):
        base = {
            "build": {"bags": [a.bag], "scan_stride": a.every},
            "fuse": {"rules": a.rules.split(","), "topology": a.topology, "schedule": a.schedule},
        }
        run_cfg = from_dict(RunConfig, {**base, "fuse": {**base["fuse"], "loss": loss}})
        t0 = time.perf_counter()
        sim = simulate(run_cfg.build, run_cfg.fuse, samples=0)
        sim_s = time.perf_counter() - t0
        fleet_cfg = resolved(
            from_dict(
                FleetConfig,
                {
                    **base,
                    "live": {
                        "speed": a.speed,
                        "faults": {"loss": loss, "seed": 1},
                        "base_port": 21447,
                    },
                },
            )
        )
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            res = run_fleet(fleet_cfg, Path(tmp), log=lambda m: print(m, file=sys.stderr))
            wall = time.perf_counter() - t0
            counts = {
                r: [agent_counts(Path(tmp) / "agents", r, n) for n in res.agents] for r in res.rules
            }
            waits = {r: latencies(Path(tmp) / "agents", r, res.agents) for r in res.rules}
        mission = max(e.time_s for e in res.events) / a.speed if res.events else wall
        links = len(res.graph.edges) * 2
        for r in res.rules:
            rows.append(
                {
                    "loss": loss,
                    "rule": r,
                    "agents": len(res.agents),
                    "cpu_s_per_agent": round(
                        sum(c["cpu_s"] for c in counts[r]) / len(res.agents), 2
                    ),
                    "peak_rss_mib": round(max(c["peak_rss"] for c in counts[r]) / 2**20, 1),
                    "bytes_per_link_s": round(sum(res.traffic[r].sent.values()) / links / mission),
                    "kl_fleet": round(_mean(res.scores[r], "kl_mean"), 4),
                    "kl_run": round(_mean(sim.scores[r], "kl_mean"), 4),
                    "latency_median_s": round(_quantile(waits[r], 0.5), 2),
                    "latency_p95_s": round(_quantile(waits[r], 0.95), 2),
                    "fleet_wall_s": round(wall, 1),
                    "run_wall_s": round(sim_s, 1),
                }
            )
            print(json.dumps(rows[-1]))
    print(
        "\n| loss | rule | CPU s/agent | peak MiB | B/link/s | KL fleet | KL run "
        "| latency median, p95 (s) |\n|---:|---|---:|---:|---:|---:|---:|---:|"
    )
    for x in rows:
        print(
            f"| {x['loss']:.0%} | {x['rule']} | {x['cpu_s_per_agent']} | {x['peak_rss_mib']} | "
            f"{x['bytes_per_link_s']:,} | {x['kl_fleet']} | {x['kl_run']} | "
            f"{x['latency_median_s']}, {x['latency_p95_s']} |"
        )
    out = {"rows": rows}
    if a.restart:
        out["restart"] = restart(a)
        print(json.dumps(out["restart"]))
    if a.json:
        a.json.write_text(json.dumps(out, indent=1))


def latencies(agents_dir: Path, rule: str, names: list[str]) -> list[float]:
    """Seconds from each scan of a robot going into its map to each neighbour applying the
    first message of the robot composed after it (a scan that no later message carried to a
    neighbour counts not)."""
    traces = {n: json.loads((agents_dir / rule / n / "trace.json").read_text()) for n in names}
    out = []
    for sender, tr in traces.items():
        for receiver, other in traces.items():
            applied = {seq: t for s, seq, t in other["applied"] if s == sender}
            # messages to the receiver that it applied: (scans in them, when applied)
            arrived = sorted(
                (scans, applied[seq])
                for r, seq, _, scans in tr["sent"]
                if r == receiver and seq in applied
            )
            if not arrived:
                continue
            k = 0
            for t_scan, count in tr["scans"]:
                while k < len(arrived) and arrived[k][0] < count:
                    k += 1
                if k == len(arrived):
                    break
                first = min(t for c, t in arrived[k:] if c >= count)
                out.append(first - t_scan)
    return out


def restart(a) -> dict:
    """A fleet of the first rule in which the second agent is killed after its first
    checkpoint and started again ``a.downtime`` seconds later; its catch-up time."""
    import signal
    import subprocess

    from octofuse.config import FleetConfig, dump_yaml, from_dict
    from octofuse.live.fleet import resolved

    cfg = resolved(
        from_dict(
            FleetConfig,
            {
                "build": {"bags": [a.bag], "scan_stride": a.every},
                "fuse": {
                    "rules": [a.rules.split(",")[0]],
                    "topology": a.topology,
                    "schedule": a.schedule,
                },
                "live": {"speed": a.speed, "base_port": 23447, "checkpoint_period": 5.0},
            },
        )
    )
    names = [x.name for x in cfg.build.agents]
    victim, rule = names[1], cfg.fuse.rules[0]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "fleet.yaml"
        path.write_text(dump_yaml(cfg))
        out = Path(tmp) / "agents"

        def start(name: str, fresh: bool) -> subprocess.Popen:
            cmd = [sys.executable, "-m", "octofuse", "agent", name, "--fleet", str(path)]
            cmd += ["--out", str(out)] + (["--fresh"] if fresh else [])
            return subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

        procs = {n: start(n, True) for n in names}
        ckpt = out / rule / victim / "checkpoint.pkl"
        while not ckpt.is_file():
            time.sleep(0.05)
        time.sleep(1.0)
        procs[victim].send_signal(signal.SIGKILL)
        procs[victim].wait()
        killed = time.time()
        time.sleep(a.downtime)
        started = time.time()
        procs[victim] = start(victim, False)
        for n, p in procs.items():
            if p.wait() != 0:
                raise SystemExit(f"agent {n} failed")
        counts = json.loads((out / rule / victim / "counts.json").read_text())
    caught = counts["caught_up_at"]
    return {
        "rule": rule,
        "agent": victim,
        "downtime_s": round(started - killed, 2),
        "catch_up_s": round(caught - started, 2) if caught else None,
        "restarts": counts["restarts"],
        "scans_behind": counts["behind"],
    }


def _quantile(values: list[float], q: float) -> float:
    import numpy as np

    return float(np.quantile(values, q)) if values else float("nan")


def _mean(scores: dict, key: str) -> float:
    values = [getattr(s, key) for s in scores.values()]
    return sum(values) / len(values)


if __name__ == "__main__":
    main()
