"""The table of current figures in benchmarks/README.md, written by run_all.py.

Each row is keyed by its first two cells (benchmark, what); a run replaces the rows of the parts
it ran, dated today, and keeps the others with the date they were measured.
"""

from __future__ import annotations

import datetime
import re
from pathlib import Path

BEGIN = "<!-- figures: begin (written by benchmarks/run_all.py) -->"
END = "<!-- figures: end -->"
HEADER = ("benchmark", "what", "octofuse", "baseline", "ratio", "measured")


def _s(x: float) -> str:
    return f"{x:.3f} s" if x < 10 else f"{x:.1f} s"


def _m(x: float) -> str:
    return f"{x / 1e6:.2f} M" if x < 10e6 else f"{x / 1e6:.1f} M"


def _x(x: float) -> str:
    return f"{x:.1f}x"


def rows_from(summary: dict) -> dict[tuple[str, str], list[str]]:
    """The table's rows for the parts in ``summary`` (run_all.py's results), undated."""
    rows: dict[tuple[str, str], list[str]] = {}
    trees = summary.get("trees", {}).get("sensor")
    if trees:
        by = {r["name"]: r for r in trees["rows"]}
        merge = next(
            r for n, r in by.items() if n.startswith("OctoMap updateNode merge (lazy_eval=f")
        )
        for rule in ("naive-bayes", "min-info-loss"):
            r = by[f"octofuse {rule}"]
            rows[("fuse_trees.cpp", f"new fused tree, {rule}, generated maps")] = [
                f"{_m(r['voxels_per_s'])} voxels/s",
                f"updateNode merge: {_m(merge['voxels_per_s'])} voxels/s",
                _x(merge["median_s"] / r["median_s"]),
            ]
    rules = summary.get("rules")
    if rules:
        for rule in ("chernoff", "min-info-loss"):
            r = rules["rules"][rule]
            rows[("rules_throughput.py", f"{rule} on arrays, one core")] = [
                f"{_m(r['pairs_per_s'])} pairs/s",
                f"numpy add: {_m(rules['numpy_add_pairs_per_s'])} pairs/s",
                "",
            ]
    for name, res in summary.get("maps", {}).items():
        ones = {(r["rule"], r["threads"]): r["median_s"] for r in res["in_place"]}
        for rule in ("naive-bayes", "min-info-loss"):
            t = [ones[(rule, n)] for n in (1, 2) if (rule, n) in ones]
            rows[
                (
                    "fuse_trees.cpp --map-a/--map-b",
                    f"in place (`fuse_into`), {rule}, 1 / 2 threads, {name}",
                )
            ] = [
                " / ".join(_s(x) for x in t),
                f"expand + updateNode in place: {_s(res['merge_in_place_s'])}",
                " / ".join(_x(res["merge_in_place_s"] / x) for x in t),
            ]
        merge = next(
            r["median_s"]
            for r in res["rows"]
            if r["name"].startswith("OctoMap updateNode merge (lazy_eval=f")
        )
        nb = next(r for r in res["whole_cost"] if r["rule"] == "naive-bayes")
        total = nb["fuse_s"] + nb["free_s"]
        rows[
            (
                "fuse_trees.cpp --map-a/--map-b",
                f"new tree (`fuse_maps`) + freeing, naive-bayes, {name}",
            )
        ] = [
            _s(total),
            f"copy + merge: {_s(merge)}",
            _x(merge / total),
        ]
    for key, bag in (("ingest", "lab8"), ("ingest_warehouse", "warehouse")):
        res = summary.get(key)
        if not res:
            continue
        ins = res["insertion"]
        base = ins["public-octomap"]
        for name, what in (
            ("public-insert_scan", "`insert_scan`, one map"),
            ("public-insert_scans-t2", "`insert_scans`, one map, 2 threads"),
        ):
            ours = ins[name]
            rows[("ingest.py", f"{what}, {bag}")] = [
                f"{_m(ours['points_per_s'])} points/s",
                f"insertPointCloud: {_m(base['points_per_s'])} points/s",
                _x(base["median_s"] / ours["median_s"]),
            ]
    for r in summary.get("network", {}).get("growth", []):
        rows[("network.py --growth-only", f"{r['agents']} agents, 2 rules, 60 s bags")] = [
            f"{r['simulate_s']:.1f} s wall, {r['peak_rss_mib'] / 1024:.2f} GiB peak",
            "",
            "",
        ]
    mix = summary.get("mixture_fusion")
    if mix:
        mm = [r for r in mix["rows"] if r["method"] == "moment-match"]
        ms, grid = [r["ms"] for r in mm], [r["grid_ms"] for r in mm]
        ratio = [r["grid_over_sampling"] for r in mm]
        rows[("mixture_fusion.py", "2 x 15-component mixtures, N_s = 1000, moment matching")] = [
            f"{min(ms):.0f}-{max(ms):.0f} ms CPU",
            f"grid {mix['grid']} x {mix['grid']}: {min(grid):.0f}-{max(grid):.0f} ms",
            f"{min(ratio):.1f}-{max(ratio):.1f}x",
        ]
    realtime = summary.get("realtime")
    if realtime:
        by = {(r["set"], r["method"]): r for r in realtime}
        base = by[("luminar", "OctoMap insertPointCloud")]
        # threads pay off in wall time only (their CPU time is the same or more)
        for method, key, clock in (
            ("octofuse exact", "cpu_ms_per_scan", "CPU"),
            ("octofuse fast", "cpu_ms_per_scan", "CPU"),
            ("octofuse fast, 2 threads", "ms_per_scan", "wall"),
        ):
            r, ms = by[("luminar", method)], by[("luminar", method)][key]
            rows[("realtime_ingest.py", f"{method}, 5 real Luminar clouds, 0.1 m, 40 m")] = [
                f"{ms:.0f} ms {clock}/scan ({100.0 / ms:.2f}x real time), "
                f"{100 * r['occupied_kept']:.1f}% kept, {100 * r['extra_occupied']:.1f}% extra",
                f"insertPointCloud: {base[key]:.0f} ms {clock}/scan",
                _x(base[key] / ms),
            ]
    return rows


def parse_rows(block: str) -> dict[tuple[str, str], list[str]]:
    rows = {}
    for line in block.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if (
            line.startswith("|")
            and len(cells) == len(HEADER)
            and cells[0] not in (HEADER[0], "---")
        ):
            rows[(cells[0], cells[1])] = cells[2:]
    return rows


def update(readme: Path, summary: dict, machine: str, today: str | None = None) -> None:
    """Rewrite the table between the markers of ``readme``: the rows of ``summary`` dated
    ``today``, the rows of the parts not run as they were."""
    text = readme.read_text()
    head, rest = text.split(BEGIN, 1)
    block, tail = rest.split(END, 1)
    rows = parse_rows(block)
    today = today or datetime.date.today().isoformat()
    fresh = rows_from(summary)
    for key, cells in fresh.items():
        rows[key] = cells + [today]
    old_machine = re.search(r"^Machine: (.*)$", block, flags=re.M)
    machine_line = machine if fresh or not old_machine else old_machine.group(1)
    lines = [
        "",
        "",
        f"Machine: {machine_line}",
        "",
        "| " + " | ".join(HEADER) + " |",
        "|" + "---|" * len(HEADER),
    ]
    lines += ["| " + " | ".join([*key, *cells]) + " |" for key, cells in rows.items()]
    readme.write_text(head + BEGIN + "\n".join(lines) + "\n" + END + tail)
