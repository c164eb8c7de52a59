"""Live fleets measured: `octofuse fleet` in time against `octofuse run`, on the same bag.

For each loss level, a fleet replays the bag at ``--speed`` times its rate (one process per
robot and rule over Zenoh on loopback, the loss injected where messages leave an agent) and
`run` simulates the same schedule with the same share of messages lost. Printed per level and
rule: the agents' CPU seconds (mean) and peak resident memory (the largest), each agent's
own as it wrote them when it ended; the bytes each link carried per second of mission; and
the final KL to the centralized map of the fleet beside `run`'s.

    .venv/bin/python benchmarks/fleet.py [--bag data/lab8.bag] [--every 4] [--speed 2]
        [--rules min-info-loss,channel-filter] [--losses 0,0.2,0.5] [--json FILE]
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
                    "fleet_wall_s": round(wall, 1),
                    "run_wall_s": round(sim_s, 1),
                }
            )
            print(json.dumps(rows[-1]))
    print(
        "\n| loss | rule | CPU s/agent | peak MiB | B/link/s | KL fleet | KL run |\n"
        "|---:|---|---:|---:|---:|---:|---:|"
    )
    for x in rows:
        print(
            f"| {x['loss']:.0%} | {x['rule']} | {x['cpu_s_per_agent']} | {x['peak_rss_mib']} | "
            f"{x['bytes_per_link_s']:,} | {x['kl_fleet']} | {x['kl_run']} |"
        )
    if a.json:
        a.json.write_text(json.dumps(rows, indent=1))


def _mean(scores: dict, key: str) -> float:
    values = [getattr(s, key) for s in scores.values()]
    return sum(values) / len(values)


if __name__ == "__main__":
    main()
