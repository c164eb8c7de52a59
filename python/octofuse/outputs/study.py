"""Studies: rules x topologies against the centralized map (``octofuse bench``)."""

from __future__ import annotations

import contextlib
import copy
import csv
import os
from pathlib import Path
from typing import Callable, Optional, Sequence

from ..config import RunConfig
from ..fusion.graph import make_graph
from ..fusion.network import LOCAL
from ..fusion.simulate import simulate
from ..scans.source import ScanSource
from .report import COLUMNS, mean_scores


def run_study(cfg: RunConfig, topologies: Sequence[str], out: str | Path, *, truth=None,
              progress: Optional[Callable] = None, log: Optional[Callable[[str], None]] = None
              ) -> list[Path]:
    """Run every rule of ``cfg.fuse.rules`` on every topology and write ``bench.csv``,
    ``bench.md`` and ``bench_*.png`` into ``out``; returns the paths.

    The bags are opened and their transforms read once; each topology is one pass over the
    scans. ``progress(description)`` makes a context manager called as ``bar(done, total)``.
    """
    cfg.validate("config")
    out = Path(out)
    rows = []
    timings = {}
    with ScanSource(cfg.build) as src:
        names = [a.name for a in src.agents]
        for t in topologies:  # fail early on a bad topology, before hours of work
            make_graph(t, len(names), seed=cfg.fuse.seed, names=names)
        for topo in topologies:
            fcfg = copy.deepcopy(cfg.fuse)
            fcfg.topology = topo
            bar = progress(f"{topo}: {len(fcfg.rules)} rule(s)") if progress else contextlib.nullcontext()
            with bar:
                res = simulate(cfg.build, fcfg, samples=0, truth=truth, source=src,
                               progress=bar if progress else None)
            timings[topo] = dict(res.timings)
            for rule, row in mean_scores(res.scores).items():
                rows.append({"topology": topo, "rule": rule,
                             "messages": res.traffic[rule].messages if rule != LOCAL else 0, **row})
            if log is not None:
                log(f"{topo}: done in {res.timings['total']:.1f} s")
    out.mkdir(parents=True, exist_ok=True)
    keys = ["topology", "rule", "messages"] + [k for k, _, _ in COLUMNS]
    tmp = out / "bench.csv.tmp"
    with tmp.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in keys})
    os.replace(tmp, out / "bench.csv")
    md = ["# octofuse bench", "", f"bags: {', '.join(cfg.build.bags)}; schedule "
          f"`{cfg.fuse.schedule}`; means over agents against the centralized map", ""]
    head = ["topology", "rule"] + [h for _, h, _ in COLUMNS]
    md += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [f"`{r['topology']}`", f"`{r['rule']}`"]
        for k, _, fmt in COLUMNS:
            v = r.get(k)
            cells.append("–" if v is None else fmt.format(v / 1e6 if k.startswith("bytes") else v))
        md.append("| " + " | ".join(cells) + " |")
    md += ["", "| topology | seconds |", "|---|---|"]
    md += [f"| `{t}` | {v['total']:.1f} |" for t, v in timings.items()]
    (out / "bench.md").write_text("\n".join(md) + "\n")
    paths = [out / "bench.csv", out / "bench.md"]
    paths += _plots(rows, topologies, out)
    return paths


def _plots(rows, topologies, out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    rules = list(dict.fromkeys(r["rule"] for r in rows))
    paths = []
    for key, label in [("kl_mean", "KL(central ‖ agent)"), ("overconfidence", "over-confident fraction"),
                       ("loss_mean", "mean accumulated information loss [nats]")]:
        fig, ax = plt.subplots(figsize=(max(6, 1.2 * len(rules)), 4))
        width = 0.8 / max(len(topologies), 1)
        x = np.arange(len(rules))
        for i, t in enumerate(topologies):
            vals = [next((r[key] for r in rows if r["topology"] == t and r["rule"] == ru), None)
                    for ru in rules]
            ax.bar(x + i * width, [np.nan if v is None else v for v in vals], width, label=t)
        ax.set_xticks(x + width * (len(topologies) - 1) / 2)
        ax.set_xticklabels(rules, rotation=30, ha="right", fontsize=8)
        ax.set_ylabel(label)
        ax.legend(fontsize=8)
        ax.grid(axis="y", alpha=0.3)
        fig.tight_layout()
        p = out / f"bench_{key}.png"
        fig.savefig(p, dpi=110)
        plt.close(fig)
        paths.append(p)
    return paths
