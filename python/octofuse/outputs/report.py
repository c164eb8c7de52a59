"""Outputs of a fusion run: maps, heat maps, summary.json, report.md and plots."""

from __future__ import annotations

import contextlib
import json
import math
import os
from collections.abc import Sequence
from functools import partial
from pathlib import Path

import numpy as np

from ..config import CHANNEL_FILTER, EXACT_MODES, SOURCE_LAYERS, RunConfig, to_dict
from ..fusion.agent_frames import frames_section
from ..fusion.results import LOCAL, SimResult, ordered_timings
from ..maps.frames import matrix_pose
from .aside import drawn_aside
from .libraries import pyplot
from .loss_histogram import count_loss_histograms, plot_loss_histograms
from .map_exports import MapExports

#: columns of the results tables: (key, header, format)
COLUMNS = [
    ("kl_mean", "KL(central ‖ agent)", "{:.4f}"),
    ("overconfidence", "over-confident", "{:.1%}"),
    ("agreement", "class agreement", "{:.1%}"),
    ("coverage", "coverage", "{:.1%}"),
    ("loss_mean", "info loss mean", "{:.3f}"),
    ("loss_p95", "info loss p95", "{:.3f}"),
    ("occupied_accuracy", "occupied on surface", "{:.1%}"),
    ("bytes_sent", "MB sent", "{:.1f}"),
    ("bytes_sent_32b", "MB sent at 32 B/voxel", "{:.1f}"),
]


def mean_scores(scores: dict) -> dict[str, dict[str, float | None]]:
    """Per rule (and local-only), the mean of every metric over the agents."""
    out = {}
    for rule, per_agent in scores.items():
        row = {}
        for key, _, _ in COLUMNS:
            vals = [getattr(s, key) for s in per_agent.values()]
            vals = [
                v for v in vals if v is not None and not (isinstance(v, float) and math.isnan(v))
            ]
            row[key] = float(np.mean(vals)) if vals else None
        out[rule] = row
    return out


def _fmt(key: str, fmt: str, v) -> str:
    if v is None:
        return "–"
    if key.startswith("bytes"):
        v = v / 1e6
    return fmt.format(v)


def markdown_table(rows: dict[str, dict], first: str = "rule") -> str:
    head = [first] + [h for _, h, _ in COLUMNS]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, row in rows.items():
        lines.append(
            "| "
            + " | ".join([f"`{name}`"] + [_fmt(k, f, row.get(k)) for k, _, f in COLUMNS])
            + " |"
        )
    return "\n".join(lines)


def findings(
    means: dict[str, dict],
    exact: dict | None = None,
    memory: dict[str, float] | None = None,
    folded: dict[str, int] | None = None,
) -> list[str]:
    """What the numbers say about the paper's three claims (computed, not assumed), how close
    each WEP rule comes to the exact channel filter when it ran (``exact``: its links and the
    floor it can reach, from :func:`exact_summary`), and what source layers cost beside the
    others (``memory``: bytes per agent by rule, from :func:`memory_per_agent`; ``folded``:
    the layers each agent folded)."""
    out = []
    wep = [r for r in means if r not in (LOCAL, "naive-bayes", *EXACT_MODES)]
    nb = means.get("naive-bayes")
    if nb and wep:
        worst_oc = max(means[r]["overconfidence"] for r in wep)
        worst_kl = max(means[r]["kl_mean"] for r in wep)
        holds = nb["overconfidence"] > worst_oc and nb["kl_mean"] > worst_kl
        out.append(
            f"Rumour propagation: naive-bayes is over-confident on {nb['overconfidence']:.1%} of the "
            f"voxels (WEP rules: at most {worst_oc:.1%}) and its KL to the centralized map is "
            f"{nb['kl_mean']:.4f} (WEP rules: at most {worst_kl:.4f}): "
            + ("holds." if holds else "does not fully hold on this run (see the table).")
        )
    if LOCAL in means and wep:
        loc = means[LOCAL]["kl_mean"]
        better = [r for r in wep if means[r]["kl_mean"] < loc]
        out.append(
            f"Every WEP rule closer to the centralized map than the local-only maps "
            f"(KL {loc:.4f}): {len(better)} of {len(wep)} rules"
            + (
                "."
                if len(better) == len(wep)
                else f"; not: {', '.join(r for r in wep if r not in better)}."
            )
        )
    if "min-info-loss" in means and len(wep) > 1:

        def rank(key):
            return sorted(wep, key=lambda r: means[r][key] if means[r][key] is not None else np.inf)

        by_mean, by_p95 = rank("loss_mean"), rank("loss_p95")
        out.append(
            f"Lowest accumulated information loss among the WEP rules: by mean `{by_mean[0]}`, by "
            f"95th percentile `{by_p95[0]}` (min-info-loss ranks {by_mean.index('min-info-loss') + 1} "
            f"and {by_p95.index('min-info-loss') + 1} of {len(wep)}). Per fusion, min-info-loss "
            f"has the least loss by construction; accumulated over a run the maps differ "
            f"(min-info-loss keeps more of each map and becomes more certain, so later fusions of "
            f"agreeing certain voxels each lose a little), so the ranking of accumulated loss is an "
            f"empirical result."
        )
    cf = means.get(CHANNEL_FILTER)
    if cf and cf.get("kl_mean") is not None:
        ex = exact or {}
        links = (
            f" on a spanning tree ({ex['tree_links']} of {ex['graph_links']} links)"
            if ex.get("tree_links") is not None and ex["tree_links"] < ex["graph_links"]
            else ""
        )
        floor, floor_over = ex.get("floor_kl"), ex.get("floor_overconfidence")
        text = (
            f"Exact fusion (channel filter{links}): KL {cf['kl_mean']:.4f}, over-confident "
            f"on {cf['overconfidence']:.1%}, class agreement {cf['agreement']:.1%}"
            + (
                f" (a map of all scans, clamped once, has KL {floor:.4f}"
                + (f" and is over-confident on {floor_over:.1%}" if floor_over is not None else "")
                + ": clamping the sum is not OctoMap's step-by-step clamping)"
                if floor is not None
                else ""
            )
            + "."
        )
        if wep:
            parts = []
            for r in sorted(wep, key=lambda r: means[r]["kl_mean"]):
                kl, agr = means[r]["kl_mean"], means[r]["agreement"]
                parts.append(
                    f"`{r}` KL {kl:.4f} ({kl / cf['kl_mean']:.2f}x), agreement "
                    f"{agr - cf['agreement']:+.1%}"
                )
            best = min(wep, key=lambda r: means[r]["kl_mean"])
            where = "on every link" if links else "on the same links"
            text += (
                f" WEP rules {where} against it: "
                + "; ".join(parts)
                + f". Closest: `{best}`"
                + (
                    " (better than the exact filter on the tree alone: the loop links carry "
                    "information the tree does not)"
                    if means[best]["kl_mean"] < cf["kl_mean"]
                    else ""
                )
                + "."
            )
        out.append(text)
    if means.get(SOURCE_LAYERS, {}).get("kl_mean") is not None:
        out.append(layers_finding(means, memory or {}, folded or {}))
    return out


def layers_finding(
    means: dict[str, dict], memory: dict[str, float], folded: dict[str, int] | None = None
) -> str:
    """Source layers against every other row: KL, over-confidence, bytes sent and memory; and
    where exactness ended (layers folded under the memory budget)."""
    sl = means[SOURCE_LAYERS]
    others = {
        r: m
        for r, m in means.items()
        if r not in (LOCAL, SOURCE_LAYERS) and m.get("kl_mean") is not None
    }
    text = (
        f"Exact fusion on every link (source-layers): KL {sl['kl_mean']:.4f}, over-confident "
        f"on {sl['overconfidence']:.1%}"
    )
    if others:
        best = min(others, key=lambda r: others[r]["kl_mean"])
        kl = others[best]["kl_mean"]
        closest = (
            "closer to the centralized map than every other rule"
            if sl["kl_mean"] < kl
            else "not the closest"
        )
        ratio = f", {kl / sl['kl_mean']:.2f}x" if sl["kl_mean"] > 0 else ""
        text += f"; {closest} (next: `{best}` KL {kl:.4f}{ratio})"
    mb = lambda v: f"{v / 1e6:.1f} MB"  # noqa: E731
    if sl.get("bytes_sent") is not None:
        sent = {r: m["bytes_sent"] for r, m in others.items() if m.get("bytes_sent") is not None}
        text += f". A robot sends {mb(sl['bytes_sent'])}" + (
            f" (others {mb(min(sent.values()))} to {mb(max(sent.values()))})" if sent else ""
        )
    if SOURCE_LAYERS in memory:
        rest = {r: v for r, v in memory.items() if r != SOURCE_LAYERS}
        text += f" and holds {mb(memory[SOURCE_LAYERS])} of map and layers" + (
            f" (others {mb(min(rest.values()))} to {mb(max(rest.values()))} of map and "
            "per-link state)"
            if rest
            else ""
        )
    text += "."
    if folded and any(folded.values()):
        text += (
            f" Over the memory budget {sum(v > 0 for v in folded.values())} of "
            f"{len(folded)} agents folded layers ({np.mean(list(folded.values())):.1f} "
            "per agent on average) into a conservative remainder: not exact."
        )
    return text


def layers_folded(res: SimResult) -> dict[str, int]:
    """Per agent, the source layers it folded under the memory budget (none without them)."""
    return {a: v["folded"] for a, v in res.memory.get(SOURCE_LAYERS, {}).items()}


def memory_per_agent(res: SimResult) -> dict[str, float]:
    """Per rule, the mean over agents of the bytes of the map and the per-link state (source
    layers: the layers)."""
    return {
        r: float(np.mean([v["map"] + v["links"] for v in per.values()]))
        for r, per in res.memory.items()
        if per
    }


def exact_summary(res: SimResult, tol: float) -> dict | None:
    """The channel filter's links and the floor the exact modes can reach (the centralized map
    without clamping, clamped once, against the centralized map); None without them."""
    if not any(r in EXACT_MODES for r in res.rules):
        return None
    out: dict = {
        "tree_links": len(res.tree) if res.tree is not None else None,
        "graph_links": len(res.graph.edges),
        "tree": [list(e) for e in res.tree] if res.tree is not None else None,
        "floor_kl": None,
        "floor_agreement": None,
        "floor_overconfidence": None,
    }
    if res.central_unclamped is not None and res.central is not None:
        from ..fusion.channel_filter import clamped
        from ..maps.compare import compare

        s = compare(res.central, clamped(res.central_unclamped), tol)
        out["floor_kl"], out["floor_agreement"] = s.kl_mean, s.agreement
        out["floor_overconfidence"] = s.overconfidence
    return out


def memory_table(res: SimResult) -> list[str]:
    """Markdown rows: per rule, mean over agents of the map's and the per-link state's
    memory, and of the bytes sent; messages and lost messages."""
    if not res.memory:
        return []
    layered = any("folded" in v for per in res.memory.values() for v in per.values())
    lines = [
        "| rule | map MB | per-link state MB | MB sent | messages | lost |"
        + (" layers held (folded) |" if layered else ""),
        "|---|---|---|---|---|---|" + ("---|" if layered else ""),
    ]
    for r in res.rules:
        per = res.memory.get(r, {})
        if not per:
            continue
        tr = res.traffic[r]
        mb = lambda xs: float(np.mean(xs)) / 1e6  # noqa: E731
        lines.append(
            f"| `{r}` | {mb([v['map'] for v in per.values()]):.2f} | "
            f"{mb([v['links'] for v in per.values()]):.2f} | "
            f"{mb([tr.sent[a] for a in res.agents]):.2f} | {tr.messages} | {tr.lost} |"
            + (_layers_cell(per) if layered else "")
        )
    return lines


def _layers_cell(per: dict) -> str:
    """Mean layers held per agent and the folded ones (source layers), or a dash."""
    if not all("folded" in v for v in per.values()):
        return " – |"
    held = np.mean([v["layers"] for v in per.values()])
    return f" {held:.1f} ({np.mean([v['folded'] for v in per.values()]):.1f}) |"


def plot_timeline(res: SimResult, path: Path) -> Path | None:
    if not res.timeline:
        return None
    plt = pyplot()

    rules = [LOCAL] + res.rules
    ncol = min(4, len(rules))
    nrow = math.ceil(len(rules) / ncol)
    fig, axes = plt.subplots(
        nrow, ncol, figsize=(4 * ncol, 3 * nrow), sharex=True, sharey=True, squeeze=False
    )
    for ax, rule in zip(axes.flat, rules):
        for agent in res.agents:
            pts = [
                (s["t"], s["kl"]) for s in res.timeline if s["rule"] == rule and s["agent"] == agent
            ]
            if pts:
                t, kl = zip(*pts)
                ax.plot(t, kl, marker=".", lw=1, label=agent)
        ax.set_title(rule, fontsize=9)
        ax.grid(alpha=0.3)
    for ax in axes.flat[len(rules) :]:
        ax.axis("off")
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    for ax in axes[:, 0]:
        ax.set_ylabel("KL(central ‖ agent)")
    axes.flat[0].legend(fontsize=6, ncol=2)
    fig.suptitle("Per-agent KL divergence to the centralized map over time")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_outputs(
    res: SimResult,
    out: str | Path,
    cfg: RunConfig,
    *,
    export_agents: Sequence[str] | None = None,
    heatmaps: bool = True,
    title: str = "octofuse run",
    event_bag=None,
    maps: MapExports | None = None,
) -> dict[str, Path]:
    """Write fused maps and heat maps (as ``cfg.export`` and ``cfg.formats`` ask),
    summary.json, plots, top views and report.md. ``event_bag``: the run's per-event bag
    (:class:`~octofuse.outputs.event_bag.FusionEventBag`), named in the report. ``maps``: the
    map files already written rule by rule (then ``res`` need not hold the maps)."""
    from .event_loss import event_loss_summary, messages_sentence
    from .event_loss import markdown_section as loss_section

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if maps is None:
        agents = list(export_agents) if export_agents is not None else res.agents
        maps = MapExports(out, cfg, res.rules, agents, heatmaps)
        maps.add(res)
    hist = count_loss_histograms(maps.histogram, maps.threads)
    plots = {}  # by their name in the report: the plots with data to draw, and how
    if res.timeline:
        plots["timeline"] = (out / "kl_over_time.png", partial(plot_timeline, res))
    if hist is not None:
        plots["loss_hist"] = (out / "info_loss_histogram.png", partial(plot_loss_histograms, hist))

    def draw_plots():
        for path, draw in plots.values():
            draw(path)

    # the plots drawn on another core while the heat maps and top views are written
    with (
        drawn_aside(
            draw_plots, " and ".join(p.name for p, _ in plots.values()), cores=cfg.build.workers
        )
        if plots
        else contextlib.nullcontext()
    ):
        exported = maps.finish()
    paths = {name: path for name, (path, _) in plots.items()}
    res.timings["export (wall)"] = maps.seconds  # the maps written group by group, the heat maps
    if res.alignment:  # registrations run between the exchanges, outside the parts above
        res.timings["alignment registrations (wall)"] = sum(
            d.get("seconds", 0.0) for d in res.alignment
        )
    timings = ordered_timings(res)  # every part timed by now
    fusions = sorted((e for r in res.rules for e in res.traffic[r].fusions), key=lambda e: e.time_s)
    per_event = event_loss_summary(fusions, res.agents)
    means = mean_scores(res.scores) if res.scores else {}
    exact = exact_summary(res, cfg.fuse.overconfidence_tol)
    summary = {
        "config": to_dict(cfg),
        "agents": res.agents,
        "rules": res.rules,
        "graph": {"spec": cfg.fuse.topology, "edges": [list(e) for e in res.graph.edges]},
        "events": len(res.events),
        "messages": {r: res.traffic[r].messages for r in res.rules},
        "mean": means,
        "scores": {r: {a: s.to_dict() for a, s in per.items()} for r, per in res.scores.items()},
        "timeline": res.timeline,
        "timings_s": timings,
        "findings": findings(means, exact, memory_per_agent(res), layers_folded(res))
        if means
        else [],
        "machine": f"{os.cpu_count()} cores",
        "robust": res.robust.to_dict() if res.robust is not None else None,
        "exports": exported,
        "loss_per_event": per_event,
        "loss_per_event_finding": messages_sentence(per_event),
        "fusion_events": [e.to_dict() for e in fusions],
    }
    if event_bag is not None:
        summary["event_bag"] = {"path": str(event_bag.path), "messages": event_bag.messages}
    if exact is not None:
        summary["exact"] = exact
    if res.memory:
        summary["memory_bytes"] = res.memory
        if SOURCE_LAYERS in res.memory:  # where exactness ends: layers folded per agent
            summary["layers_folded"] = layers_folded(res)
        summary["lost_messages"] = {r: res.traffic[r].lost for r in res.rules}
    if res.frames or res.alignment:
        summary["agent_frames"] = {a: matrix_pose(T) for a, T in res.frames.items()}
        summary["alignment"] = res.alignment
    tmp = out / "summary.json.tmp"
    tmp.write_text(json.dumps(summary, indent=1, default=float))
    os.replace(tmp, out / "summary.json")
    lines = [
        f"# {title}",
        "",
        f"- bags: {', '.join(cfg.build.bags)}",
        f"- agents: {', '.join(res.agents)}",
        f"- topology: `{cfg.fuse.topology}` ({len(res.graph.edges)} links), schedule "
        f"`{cfg.fuse.schedule}` ({cfg.fuse.directions} directions, "
        f"{'delta' if cfg.fuse.delta else 'whole-map'} messages), unknown voxels: "
        f"`{cfg.fuse.unknown}`, seed {cfg.fuse.seed}",
        f"- exchanges: {len(res.events)}; resolution {cfg.build.map.resolution} m",
        "",
        "## Mean over agents, against the centralized map",
        "",
        markdown_table(means) if means else "(no centralized map: nothing scored)",
        "",
        "KL and class agreement are over the voxels the centralized map knows (an unknown "
        "agent voxel counts as p = 0.5); over-confident: the agent's |log-odds| exceeds the "
        f"centralized map's by more than {cfg.fuse.overconfidence_tol}; information loss: "
        "KL(p_NB ‖ p_fused) accumulated over all of an agent's fusions, per fused voxel; "
        "MB sent: OctoMap's stream (5 bytes per node) beside the 32 bytes per voxel of "
        "sending centre + log-odds in doubles.",
        "",
    ]
    if res.memory and (exact is not None or cfg.fuse.loss > 0):
        lines += [
            "## Memory and traffic",
            "",
            *memory_table(res),
            "",
            "Mean over agents. Per-link state: the channel filter's copies of its "
            "neighbours' contributions (one map per link end) and, with delta messages, "
            "the maps deltas are taken against; the WEP rules keep per-link state only for "
            "deltas; source layers' per-link state is their layers (every source's, its own "
            "and the values neighbours are known to hold, each map once; folded: layers "
            "merged into one conservative remainder under `fuse.layers_max_bytes`, exact no "
            "more). The exact modes' maps are unclamped (less pruning than clamped maps); "
            f"message loss {cfg.fuse.loss:g}.",
            "",
        ]
    if res.robust is not None:
        from ..fusion.robust import markdown_section

        lines += markdown_section(res.robust)
    if summary["findings"]:
        lines += ["## Findings", ""] + [f"- {f}" for f in summary["findings"]] + [""]
    lines += loss_section(per_event)
    for name, p in paths.items():
        lines += [f"![{name}]({p.name})", ""]
    lines += exports_section(exported, event_bag)
    if res.scores:
        lines += ["## Per agent", ""]
        for r, per in res.scores.items():
            rows = {a: s.to_dict() for a, s in per.items()}
            lines += [f"### {r}", "", markdown_table(rows, first="agent"), ""]
    lines += ["## Time", "", "| part | seconds |", "|---|---|"]
    lines += [f"| {k} | {v:.2f} |" for k, v in timings.items()]
    lines += [
        "",
        "The parts that run on several threads are summed over them (so they can add up "
        "to more than the wall time); `(wall)` and `total` are wall time.",
        "",
    ]
    lines += [files_note(cfg), ""]
    if res.frames or res.alignment:
        lines += frames_section(res.frames, res.alignment)
    (out / "report.md").write_text("\n".join(lines))
    paths["report"] = out / "report.md"
    paths["summary"] = out / "summary.json"
    return paths


def exports_section(exported: dict, event_bag=None) -> list[str]:
    """The report's paragraph on the heat maps (what they hold, the colour range), the top
    views and the per-event bag."""
    lines: list[str] = []
    rng = exported.get("range")
    if exported.get("topviews") or exported.get("heatmaps"):
        lines += ["## Information-loss heat maps", ""]
        if exported.get("heatmaps"):
            lines += [
                f"Heat maps ({', '.join('.' + f for f in exported['formats'])}, one per rule and "
                "exported agent): the occupied voxels (log-odds > 0) of the agent's fused map, "
                "each with its accumulated information loss (field `info_loss`, nats) and its "
                "`log_odds`, `occupancy` and `voxel_size`, coloured (inferno) over one range for "
                f"every rule of the run: {rng[0]:.4g} to {rng[1]:.4g} nats (the 99th percentile "
                "of the losses written; higher losses take the top colour). Colour bar: "
                f"`{exported['colorbar']}`.",
                "",
                f"![colour bar]({exported['colorbar']})",
                "",
            ]
        if exported.get("topviews"):
            first = exported["topviews"][0]["agent"]
            lines += [
                f"Top views of {first}'s heat maps: every x-y cell shows the largest loss "
                "of the occupied voxels above it (floor left out), over the same range "
                f"({rng[0]:.4g} to {rng[1]:.4g} nats).",
                "",
            ]
            lines += [f"![{v['rule']}]({v['file']})" for v in exported["topviews"]] + [""]
    if event_bag is not None:
        lines += [
            f"Replay: `{event_bag.path}` holds {event_bag.messages} map messages "
            "(`/octofuse/RULE/AGENT/octomap` and `.../occupied_cells`), one per exported "
            "agent and rule at every instant it fused a message.",
            "",
        ]
    return lines


def files_note(cfg: RunConfig) -> str:
    """What the output folder holds, for the export mode of ``cfg``."""
    ext = cfg.formats[0] if len(cfg.formats) == 1 else "{" + ",".join(cfg.formats) + "}"
    what = {
        "all": "with every exported agent's fused map (`AGENT.ot`) and its information-loss "
        f"heat map (`AGENT_info_loss.{ext}`)",
        "fused": "with every exported agent's fused map (`AGENT.ot`)",
        "none": None,
    }[cfg.export]
    maps = (
        f"`centralized.ot`; per rule a folder {what}; " if what else "no maps (`--export none`); "
    )
    return (
        f"Files: {maps}`summary.json` holds every number, with every fusion event "
        "(`fusion_events`); plots and top views as PNG."
    )
