"""Studies: rules x topologies x schedules x seeds x bags against the centralized map
(``octofuse bench``).

A study is a grid of independent cells, one per (bags, topology, schedule, seed); every cell
is one pass over its bags that runs all the rules side by side. Cells run on an executor
(:mod:`octofuse.fusion.executors`: in this process, or as Ray tasks on a local Ray or a
cluster); a cell's numbers do not depend on where it ran. Each finished cell is written as
``cells/<key>.json`` inside the output folder, so an interrupted or partly failed study is
resumed by passing its folder as ``resume_from``: cells found there with the same key (the
same cell of the same configuration and bags) are carried over, not run again. A failed cell
is reported with its error and the rest go on; it is run again on resume.

The tables hold the mean over seeds and, with more than one seed, the standard deviation
(columns ``<metric>_sd``).
"""

from __future__ import annotations

import contextlib
import copy
import csv
import hashlib
import json
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..config import RunConfig, to_dict
from ..fusion.agent_frames import AgentFrames
from ..fusion.executors import Executor, SerialExecutor, make_executor
from ..fusion.graph import make_graph
from .libraries import pyplot
from .report import COLUMNS, mean_scores

#: per-cell results inside a study's output folder
CELLS_DIR = "cells"
#: version of the cell files: a change in how cells are computed makes old ones stale
CELL_FORMAT = 1


@dataclass(frozen=True)
class Cell:
    """One run of a study: the bags, topology, schedule and seed (the rules run together)."""

    bags: tuple[str, ...]
    topology: str
    schedule: str
    seed: int

    def label(self, axes: Sequence[str]) -> str:
        parts = {
            "bags": "+".join(Path(b).name for b in self.bags),
            "topology": self.topology,
            "schedule": self.schedule,
            "seed": f"seed {self.seed}",
        }
        return " ".join(parts[a] for a in axes) or self.topology


def study_cells(
    cfg: RunConfig,
    topologies: Sequence[str],
    schedules: Sequence[str] | None = None,
    seeds: Sequence[int] | None = None,
    bag_sets: Sequence[Sequence[str]] | None = None,
) -> list[Cell]:
    """The grid, bags outermost, then topology, schedule and seed."""
    schedules = list(schedules) if schedules else [cfg.fuse.schedule]
    seeds = [int(s) for s in seeds] if seeds is not None and len(seeds) else [cfg.fuse.seed]
    bag_sets = (
        [tuple(str(b) for b in bs) for bs in bag_sets] if bag_sets else [tuple(cfg.build.bags)]
    )
    return [
        Cell(b, t, s, seed)
        for b in bag_sets
        for t in topologies
        for s in schedules
        for seed in seeds
    ]


def cell_config(cfg: RunConfig, cell: Cell) -> RunConfig:
    c = copy.deepcopy(cfg)
    c.build.bags = list(cell.bags)
    c.fuse.topology, c.fuse.schedule, c.fuse.seed = cell.topology, cell.schedule, cell.seed
    return c


def cell_key(cfg: RunConfig, cell: Cell) -> str:
    """A name for the cell's result that changes with anything that changes its numbers: the
    configuration (less threads and outputs), the cell and the bags' names and sizes."""
    d = to_dict(cell_config(cfg, cell))
    d["build"].pop("threads", None)
    for k in ("out", "samples", "export_agents", "export", "formats"):
        d.pop(k, None)
    bags = []
    for b in cell.bags:
        try:
            bags.append([os.path.basename(b), os.path.getsize(b)])
        except OSError:
            bags.append([os.path.basename(b), None])
    blob = json.dumps(
        {"format": CELL_FORMAT, "config": d, "bags": bags}, sort_keys=True, default=str
    )
    digest = hashlib.sha256(blob.encode()).hexdigest()[:16]
    safe = "".join(
        ch if ch.isalnum() or ch in "-_." else "_"
        for ch in f"{cell.topology}_{cell.schedule}_s{cell.seed}"
    )[:60]
    return f"{safe}_{digest}"


def run_cell(payload: tuple) -> dict:
    """Run one cell (in this process or in a Ray worker): its rows per rule and its timings.
    ``payload`` is ``(cfg, cell, truth, threads)``; ``threads`` (if not None) replaces the
    build threads (the numbers do not depend on it)."""
    from ..fusion.results import merge_rule_results, without_maps
    from ..fusion.simulate import simulate_in_rule_groups

    cfg, cell, truth, threads, source = (*payload, None)[:5]
    c = cell_config(cfg, cell)
    if threads is not None:
        c.build.threads = int(threads)
    # a few rules at a time with fuse.rules_per_pass: each group's maps dropped as it comes
    res = merge_rule_results(
        [
            without_maps(part)
            for part in simulate_in_rule_groups(
                c.build, c.fuse, samples=0, truth=truth, source=source
            )
        ]
    )
    rows = []
    for rule, row in mean_scores(res.scores).items():
        messages = res.traffic[rule].messages if rule in res.traffic else 0  # local-only: none
        rows.append({"rule": rule, "messages": messages, **row})
    return {"rows": rows, "timings": {k: float(v) for k, v in res.timings.items()}}


def load_cells(folders: Sequence[str | os.PathLike]) -> dict[str, dict]:
    """Finished cells (status ok) found in ``cells/`` of the given study folders (or in the
    given journal folders), by key."""
    found: dict[str, dict] = {}
    for folder in folders:
        d = Path(folder) / CELLS_DIR
        if not d.is_dir():
            d = Path(folder)  # a journal: the cell files themselves
        if not d.is_dir():
            continue
        for f in sorted(d.glob("*.json")):
            try:
                rec = json.loads(f.read_text())
            except (OSError, ValueError):
                continue
            if rec.get("status") == "ok" and rec.get("key") == f.stem:
                found.setdefault(f.stem, rec)
    return found


def _write_json(path: Path, obj: Any) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(obj, indent=1, default=str) + "\n")
    os.replace(tmp, path)


def run_study(
    cfg: RunConfig,
    topologies: Sequence[str],
    out: str | Path,
    *,
    truth=None,
    progress: Callable | None = None,
    log: Callable[[str], None] | None = None,
    schedules: Sequence[str] | None = None,
    seeds: Sequence[int] | None = None,
    bag_sets: Sequence[Sequence[str]] | None = None,
    executor: str | Executor | None = "serial",
    ray_address: str | None = None,
    resume_from: Sequence[str | os.PathLike] = (),
    journal: str | os.PathLike | None = None,
    cpus_per_cell: int = 1,
    memory_per_cell: int | None = None,
) -> list[Path]:
    """Run the grid rules x topologies x ``schedules`` x ``seeds`` x ``bag_sets`` and write
    ``bench.csv``, ``bench.md``, ``bench_*.png`` and ``cells/*.json`` into ``out``; returns
    the paths of the tables and plots.

    ``schedules`` (default: ``cfg.fuse.schedule``), ``seeds`` (default: ``cfg.fuse.seed``) and
    ``bag_sets`` (lists of bags run as one recording; default: ``cfg.build.bags``) are the
    other axes. ``truth`` is the scene for all cells, or a callable giving it for a bag list.

    ``executor``: ``"serial"`` (in this process; the bags are opened once per bag set),
    ``"ray"`` (Ray tasks of ``cpus_per_cell`` CPUs and ``memory_per_cell`` bytes; a local Ray
    unless ``ray_address`` names a cluster; serial with a hint when Ray is not installed),
    ``"auto"`` (Ray if installed) or an :class:`~octofuse.fusion.executors.Executor`.

    ``resume_from``: earlier output folders (or journals) whose finished cells of the same
    key are carried over instead of run. ``journal``: a folder outside ``out`` where every
    cell is also written as soon as it finishes, so that a study killed before its outputs
    are put in place can be resumed from it.

    ``progress(description)`` makes a context manager called as ``bar(done, total)`` over the
    cells; ``log`` gets one line per finished or failed cell. Raises ``RuntimeError`` naming
    the failed cells if no cell succeeded; otherwise failed cells are listed in ``bench.md``
    (and ``cells/``) and left out of the tables.
    """
    out = Path(out)
    cells = study_cells(cfg, topologies, schedules, seeds, bag_sets)
    for cell in cells:  # fail early on a bad schedule or topology, before hours of work
        _check_cell(cfg, cell)
    stack = contextlib.ExitStack()
    with stack:
        return _run(
            cfg,
            cells,
            out,
            stack,
            truth=truth,
            progress=progress,
            log=log,
            executor=executor,
            ray_address=ray_address,
            resume_from=resume_from,
            journal=journal,
            cpus_per_cell=cpus_per_cell,
            memory_per_cell=memory_per_cell,
        )


def _run(
    cfg,
    cells,
    out,
    stack,
    *,
    truth,
    progress,
    log,
    executor,
    ray_address,
    resume_from,
    journal,
    cpus_per_cell,
    memory_per_cell,
) -> list[Path]:
    sources = _SharedSources(stack)
    n_agents = _agent_counts(cfg, cells, sources)
    for cell in cells:  # the graphs and agent frames on the bags' agents, before any cell
        if cell.bags in n_agents:
            make_graph(
                cell.topology, n_agents[cell.bags][0], seed=cell.seed, names=n_agents[cell.bags][1]
            )
            AgentFrames.from_config(n_agents[cell.bags][1], cfg.fuse)
    axes = [
        a
        for a, vals in (
            ("bags", {c.bags for c in cells}),
            ("topology", {c.topology for c in cells}),
            ("schedule", {c.schedule for c in cells}),
            ("seed", {c.seed for c in cells}),
        )
        if len(vals) > 1 or a == "topology"
    ]
    keys = [cell_key(cfg, c) for c in cells]
    cells_dir = out / CELLS_DIR
    cells_dir.mkdir(parents=True, exist_ok=True)
    jdir = Path(journal) if journal is not None else None
    if jdir is not None:
        jdir.mkdir(parents=True, exist_ok=True)
    earlier = load_cells([*resume_from, *([jdir] if jdir is not None else [])])
    records: dict[str, dict] = {}
    for k in keys:
        if k in earlier:
            records[k] = earlier[k]
            _write_json(cells_dir / f"{k}.json", earlier[k])
    todo = [i for i, k in enumerate(keys) if k not in records]
    say = log or (lambda _msg: None)
    if records:
        say(f"resuming: {len(records)} of {len(cells)} cell(s) already done")

    ex = (
        executor
        if not isinstance(executor, (str, type(None)))
        else make_executor(
            executor or "serial",
            address=ray_address,
            log=say,
            cpus=cpus_per_cell,
            memory=memory_per_cell,
        )
    )
    owned = isinstance(executor, (str, type(None)))
    tr = truth if callable(truth) else (lambda _bags, t=truth: t)
    truths = {c.bags: tr(list(c.bags)) for c in cells}
    bar_cm = progress(f"study: {len(cells)} cell(s)") if progress else contextlib.nullcontext()
    failed: list[dict] = []
    with bar_cm as bar:
        done = len(records)
        if bar is not None:
            bar(done, len(cells))

        def on_outcome(o) -> None:
            nonlocal done
            i = todo[o.index]
            cell, key = cells[i], keys[i]
            rec = {
                "key": key,
                "format": CELL_FORMAT,
                "cell": _cell_dict(cell),
                "status": "ok" if o.ok else "failed",
                "seconds": o.seconds,
            }
            if o.ok:
                rec.update(o.value)
                say(
                    f"{cell.label(axes)}: done in {o.value['timings'].get('total', o.seconds):.1f} s"
                )
            else:
                rec.update(error=o.error, details=o.details)
                failed.append(rec)
                say(f"{cell.label(axes)}: FAILED: {o.error}")
            records[key] = rec
            _write_json(cells_dir / f"{key}.json", rec)
            if jdir is not None:
                _write_json(jdir / f"{key}.json", rec)
            done += 1
            if bar is not None:
                bar(done, len(cells))

        if todo:
            if isinstance(ex, SerialExecutor):
                fn, payloads = (
                    _serial_cell,
                    [(cfg, cells[i], truths[cells[i].bags], None, sources) for i in todo],
                )
            else:
                fn = run_cell
                payloads = [(cfg, cells[i], truths[cells[i].bags], cpus_per_cell) for i in todo]
            try:
                ex.run(fn, payloads, on_outcome)
            finally:
                if owned:
                    ex.close()
    ok = [(c, records[k]) for c, k in zip(cells, keys) if records.get(k, {}).get("status") == "ok"]
    if not ok:
        raise RuntimeError(
            "every cell of the study failed: "
            + "; ".join(
                f"{Cell(**{**f['cell'], 'bags': tuple(f['cell']['bags'])}).label(axes)}: {f['error']}"
                for f in failed
            )
        )
    rows = _aggregate(ok)
    paths = _write_tables(cfg, rows, ok, failed, axes, out)
    paths += _plots(
        rows, [r for r in dict.fromkeys(_group_label(r, axes) for r in rows)], axes, out
    )
    return paths


class _SharedSources:
    """Serial cells share one open ScanSource per bag set (transforms read once)."""

    def __init__(self, stack: contextlib.ExitStack):
        self.stack, self.open = stack, {}

    def get(self, build_cfg):
        from ..scans.source import ScanSource

        key = tuple(build_cfg.bags)
        if key not in self.open:
            self.open[key] = self.stack.enter_context(ScanSource(build_cfg))
        return self.open[key]


def _serial_cell(payload) -> dict:
    cfg, cell, truth, threads, sources = payload
    src = sources.get(cell_config(cfg, cell).build)
    return run_cell((cfg, cell, truth, threads, src))


def _check_cell(cfg: RunConfig, cell: Cell) -> None:
    from ..fusion.schedule import parse_schedule

    spec = parse_schedule(cell.schedule)
    if spec.kind == "rounds":
        raise ValueError(
            f"schedule {cell.schedule!r} fuses finished maps; a study takes "
            "aperiodic:MEAN_S or periodic:PERIOD_S"
        )
    if cell.seed < 0:
        raise ValueError(f"seed {cell.seed}: expected a non-negative integer")


def _agent_counts(cfg: RunConfig, cells: Sequence[Cell], sources: _SharedSources) -> dict:
    """Agents of every bag set (to check the topologies before running anything); a bag set
    that cannot be read is left out: its cells fail and are reported."""
    out = {}
    for bags in dict.fromkeys(c.bags for c in cells):
        c = copy.deepcopy(cfg.build)
        c.bags = list(bags)
        try:
            names = [a.name for a in sources.get(c).agents]
        except Exception:  # noqa: BLE001 - the cells of this bag set report it
            continue
        out[bags] = (len(names), names)
    return out


def _cell_dict(cell: Cell) -> dict:
    return {
        "bags": list(cell.bags),
        "topology": cell.topology,
        "schedule": cell.schedule,
        "seed": cell.seed,
    }


def _aggregate(ok: list) -> list[dict]:
    """One row per (bags, topology, schedule, rule): mean and sd over seeds."""
    groups: dict[tuple, list] = {}
    for cell, rec in ok:
        for r in rec["rows"]:
            groups.setdefault((cell.bags, cell.topology, cell.schedule, r["rule"]), []).append(r)
    rows = []
    for (bags, topo, sched, rule), rs in groups.items():
        row: dict = {
            "bags": "+".join(bags),
            "topology": topo,
            "schedule": sched,
            "rule": rule,
            "seeds": len(rs),
        }
        for k in ["messages"] + [k for k, _, _ in COLUMNS]:
            vals = [r.get(k) for r in rs]
            vals = [
                float(v)
                for v in vals
                if v is not None and not (isinstance(v, float) and math.isnan(v))
            ]
            mean = sum(vals) / len(vals) if vals else None
            if k == "messages" and mean is not None and mean == int(mean):
                mean = int(mean)
            row[k] = mean
            row[f"{k}_sd"] = (
                math.sqrt(sum((v - mean) ** 2 for v in vals) / (len(vals) - 1))
                if len(vals) > 1
                else None
            )
        rows.append(row)
    return rows


def _group_label(row: dict, axes: Sequence[str]) -> str:
    parts = {"bags": row["bags"], "topology": row["topology"], "schedule": row["schedule"]}
    return " ".join(parts[a] for a in axes if a in parts)


def _write_tables(
    cfg: RunConfig, rows: list[dict], ok: list, failed: list[dict], axes: Sequence[str], out: Path
) -> list[Path]:
    metrics = ["messages"] + [k for k, _, _ in COLUMNS]
    multi_seed = any(r["seeds"] > 1 for r in rows)
    keys = (
        ["topology", "rule", "messages"]
        + [k for k, _, _ in COLUMNS]
        + ["schedule", "bags", "seeds"]
    )
    if multi_seed:
        keys += [f"{k}_sd" for k in metrics]
    tmp = out / "bench.csv.tmp"
    with tmp.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in keys})
    os.replace(tmp, out / "bench.csv")

    group_axes = [a for a in axes if a != "seed"]
    seeds = sorted({c.seed for c, _ in ok})
    schedules = list(dict.fromkeys(c.schedule for c, _ in ok))
    bags = list(dict.fromkeys("+".join(c.bags) for c, _ in ok))
    md = [
        "# octofuse bench",
        "",
        f"bags: {', '.join(bags)}; schedule{'s' if len(schedules) > 1 else ''} "
        + ", ".join(f"`{s}`" for s in schedules)
        + "; means over agents against the centralized map"
        + (f"; mean ± sd over seeds {', '.join(map(str, seeds))}" if multi_seed else ""),
        "",
    ]
    head = group_axes + ["rule"] + [h for _, h, _ in COLUMNS]
    md += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [f"`{r[a] if a != 'bags' else r['bags']}`" for a in group_axes] + [f"`{r['rule']}`"]
        for k, _, fmt in COLUMNS:
            v, sd = r.get(k), r.get(f"{k}_sd")
            scale = 1e6 if k.startswith("bytes") else 1
            text = "–" if v is None else fmt.format(v / scale)
            if sd is not None and v is not None:
                text += " ± " + fmt.format(sd / scale)
            cells.append(text)
        md.append("| " + " | ".join(cells) + " |")
    time_axes = list(axes)
    md += ["", "| " + " | ".join(time_axes) + " | seconds |", "|" + "---|" * (len(time_axes) + 1)]
    for c, rec in ok:
        vals = {
            "bags": "+".join(c.bags),
            "topology": c.topology,
            "schedule": c.schedule,
            "seed": str(c.seed),
        }
        total = rec.get("timings", {}).get("total", rec.get("seconds", 0.0))
        md.append("| " + " | ".join(f"`{vals[a]}`" for a in time_axes) + f" | {total:.1f} |")
    if failed:
        md += ["", "## Failed cells", "", "| cell | error |", "|---|---|"]
        for f in failed:
            c = f["cell"]
            md.append(
                f"| `{'+'.join(c['bags'])}` `{c['topology']}` `{c['schedule']}` seed {c['seed']} "
                f"| {f['error'].replace('|', '/')} |"
            )
    (out / "bench.md").write_text("\n".join(md) + "\n")
    return [out / "bench.csv", out / "bench.md"]


def _plots(rows: list[dict], groups: list[str], axes: Sequence[str], out: Path) -> list[Path]:
    plt = pyplot()
    import numpy as np

    rules = list(dict.fromkeys(r["rule"] for r in rows))
    paths = []
    for key, label in [
        ("kl_mean", "KL(central ‖ agent)"),
        ("overconfidence", "over-confident fraction"),
        ("loss_mean", "mean accumulated information loss [nats]"),
    ]:
        fig, ax = plt.subplots(figsize=(max(6, 1.2 * len(rules)), 4))
        width = 0.8 / max(len(groups), 1)
        x = np.arange(len(rules))
        for i, g in enumerate(groups):
            sel = [
                next((r for r in rows if _group_label(r, axes) == g and r["rule"] == ru), None)
                for ru in rules
            ]
            vals = [np.nan if r is None or r.get(key) is None else r[key] for r in sel]
            err = [0.0 if r is None or r.get(f"{key}_sd") is None else r[f"{key}_sd"] for r in sel]
            ax.bar(
                x + i * width,
                vals,
                width,
                label=g,
                yerr=err if any(e > 0 for e in err) else None,
                capsize=2,
            )
        ax.set_xticks(x + width * (len(groups) - 1) / 2)
        ax.set_xticklabels(rules, rotation=30, ha="right", fontsize=8)
        ax.set_ylabel(
            label + (" (mean ± sd over seeds)" if any(r["seeds"] > 1 for r in rows) else "")
        )
        ax.legend(fontsize=8)
        ax.grid(axis="y", alpha=0.3)
        fig.tight_layout()
        p = out / f"bench_{key}.png"
        fig.savefig(p, dpi=110)
        plt.close(fig)
        paths.append(p)
    return paths
