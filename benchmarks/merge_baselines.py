"""The merges of today's live mapping systems beside octofuse's, on the same bag and schedule.

Two baselines, written here from their described semantics (benchmark code, not octofuse
rules):

* **newest diff per source, own cells kept** (as marble_mapping merges): every agent keeps,
  per source robot, the newest version of that robot's own map it has heard of (sent by the
  robot or relayed by a neighbour); its merged map is those versions laid over one another,
  older first, with its own map's cells on top.
* **replace by the latest received** (as RACER's map manager merges): an agent's map takes,
  on every cell a received map holds, the received value; its own scans go on into it.

Both run on the exchanges of the run's schedule, messages whole and never lost. `simulate`
runs octofuse's rules on the same bag and schedule in the same process. Printed per merge:
the mean KL to the centralized map and the share of over-confident voxels (more certain than
the centralized map by more than the tolerance), averaged over the agents.

    .venv/bin/python benchmarks/merge_baselines.py [--bag data/lab8.bag] [--every 4]
        [--rules min-info-loss,chernoff,channel-filter] [--topology max-robust:3]
        [--schedule aperiodic:20] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


class NewestPerSource:
    """An agent of the newest-diff-per-source merge: its own map, and per source the newest
    version it knows (version: the mission time it was taken)."""

    def __init__(self, name: str, own):
        self.name, self.own = name, own
        self.versions: dict[str, tuple[float, object]] = {}

    def message(self, t: float) -> dict:
        """What it sends at ``t``: its own map now and every newer version it holds."""
        return {**self.versions, self.name: (t, self.own.copy())}

    def receive(self, msg: dict) -> None:
        for source, (t, m) in msg.items():
            if source != self.name and t > self.versions.get(source, (-1.0, None))[0]:
                self.versions[source] = (t, m)

    def merged(self):
        from octofuse.fusion.link import empty_like

        out = empty_like(self.own)
        for _, m in sorted(self.versions.values(), key=lambda x: x[0]):
            out = out.overlaid(m)
        return out.overlaid(self.own)


def replace_by_latest(receiver, received) -> object:
    """The latest-received merge: ``received``'s cells over ``receiver``'s."""
    return receiver.overlaid(received)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bag", default=str(REPO / "data" / "lab8.bag"))
    ap.add_argument("--every", type=int, default=4)
    ap.add_argument("--rules", default="min-info-loss,chernoff,channel-filter")
    ap.add_argument("--topology", default="max-robust:3")
    ap.add_argument("--schedule", default="aperiodic:20")
    ap.add_argument("--json", type=Path)
    a = ap.parse_args()
    rows, header = measure(a.bag, a.every, a.rules.split(","), a.topology, a.schedule)
    print(
        f"\n{header}\n"
        "\n| merge | | KL to centralized (nats/voxel) | over-confident voxels |\n|---|---|---:|---:|"
    )
    for x in rows:
        print(f"| {x['merge']} | {x['kind']} | {x['kl_mean']:.4f} | {x['overconfidence']:.2%} |")
    if a.json:
        a.json.write_text(json.dumps(rows, indent=1))


def measure(
    bag: str, every: int, rules: list[str], topology: str, schedule: str
) -> tuple[list[dict], str]:
    """One row per merge (the baselines, octofuse's rules, the own map alone) with its mean KL
    to the centralized map and share of over-confident voxels; and a line on the run."""
    from octofuse.config import RunConfig, from_dict
    from octofuse.fusion.results import LOCAL, score_agent
    from octofuse.fusion.schedule import run_schedule
    from octofuse.fusion.simulate import simulate
    from octofuse.maps.build import insert_scans
    from octofuse.maps.occupancy import OccupancyMap
    from octofuse.scans.source import ScanSource

    cfg = from_dict(
        RunConfig,
        {
            "build": {"bags": [bag], "scan_stride": every},
            "fuse": {"rules": rules, "topology": topology, "schedule": schedule},
        },
    )
    t0 = time.perf_counter()
    sim = simulate(cfg.build, cfg.fuse, samples=0)
    sim_s = time.perf_counter() - t0

    t0 = time.perf_counter()
    with ScanSource(cfg.build) as src:
        names = [x.name for x in src.agents]
        start = src.bags.start_ns
        _, _, events = run_schedule(cfg.fuse, names, start, src.bags.end_ns)
        mk = lambda: OccupancyMap.from_config(cfg.build.map)  # noqa: E731
        newest = [NewestPerSource(n, mk()) for n in names]
        latest = [mk() for _ in names]
        pending = iter(sorted(events, key=lambda e: e.time_s))
        event = next(pending, None)

        def exchange_until(t: float):
            nonlocal event
            while event is not None and event.time_s <= t:
                s, r = event.sender, event.receiver
                newest[r].receive(newest[s].message(event.time_s))
                latest[r] = replace_by_latest(latest[r], latest[s])
                event = next(pending, None)

        for scan in src.scans():
            exchange_until((scan.stamp_ns - start) / 1e9)
            k = scan.agent
            insert_scans([scan], [[newest[k].own, latest[k]]], cfg.build.threads or 1)
        exchange_until(float("inf"))
    base_s = time.perf_counter() - t0

    tol = cfg.fuse.overconfidence_tol
    maps = {
        "newest diff per source (marble_mapping)": [x.merged() for x in newest],
        "replace by latest (RACER)": latest,
    }
    rows = []
    for merge, per_agent in maps.items():
        scores = [score_agent(m, sim.central, tol) for m in per_agent]
        rows.append(_row(merge, "baseline", scores))
    for r in sim.rules:
        rows.append(_row(r, "octofuse", list(sim.scores[r].values())))
    rows.append(_row("own map only", "floor", list(sim.scores[LOCAL].values())))
    header = (
        f"{len(names)} agents, {len(events)} exchanges ({topology}, {schedule}); "
        f"octofuse rules {sim_s:.1f} s, baselines {base_s:.1f} s"
    )
    return rows, header


def _row(merge: str, kind: str, scores: list) -> dict:
    n = len(scores)
    return {
        "merge": merge,
        "kind": kind,
        "kl_mean": sum(s.kl_mean for s in scores) / n,
        "overconfidence": sum(s.overconfidence for s in scores) / n,
    }


if __name__ == "__main__":
    main()
