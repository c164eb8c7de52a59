"""What a tracking run writes: report.md, summary.json and PNG plots, put in place together."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..outputs.libraries import pyplot
from .tracking import SENSORS, TrackingConfig, TrackingResult, simulate_tracking

BURN_IN_S = 1.0  #: errors are summarised after this time (the prior dominates before)


def summarise(result: TrackingResult) -> dict:
    """Per family: tracking error, entropy rises at fusion events, bytes per message."""
    out = {"config": {k: v for k, v in vars(result.config).items()}, "families": {}}
    late = [c["error"] for c in result.central if c["time"] >= BURN_IN_S]
    early = [c["error"] for c in result.central if c["time"] < BURN_IN_S]
    out["central"] = {
        "rms_error": float(np.sqrt(np.mean(np.square(late)))) if late else None,
        "rms_error_before_burn_in": float(np.sqrt(np.mean(np.square(early)))) if early else None,
        "final_error": result.central[-1]["error"],
        "final_renyi2": result.central[-1]["renyi2"],
    }
    for name in dict.fromkeys(r["family"] for r in result.records):
        rows = [r for r in result.records if r["family"] == name]
        fusions = [r for r in rows if r["event"] == "send"]
        rises = [r for r in fusions if r["renyi2"] > r["renyi2_before"] + 1e-9]
        per_node = {}
        for node in range(1, len(SENSORS) + 1):
            errs = [r["error"] for r in rows if r["node"] == node and r["time"] >= BURN_IN_S]
            last = [r for r in rows if r["node"] == node][-1]
            per_node[str(node)] = {
                "rms_error": float(np.sqrt(np.mean(np.square(errs)))) if errs else None,
                "final_error": last["error"],
                "final_renyi2": last["renyi2"],
            }
        all_late = [r["error"] for r in rows if r["time"] >= BURN_IN_S]
        early = [r["error"] for r in rows if r["time"] < BURN_IN_S]
        out["families"][name] = {
            "rms_error": float(np.sqrt(np.mean(np.square(all_late)))) if all_late else None,
            "rms_error_before_burn_in": float(np.sqrt(np.mean(np.square(early))))
            if early
            else None,
            "per_node": per_node,
            "fusions": len(fusions),
            "entropy_rises": len(rises),
            "largest_rise": max((r["renyi2"] - r["renyi2_before"] for r in rises), default=0.0),
            "mean_w": float(np.mean([r["w"] for r in fusions])) if fusions else None,
            "bytes_per_message": {
                "mean": float(np.mean([r["bytes"] for r in fusions])) if fusions else None,
                "max": int(max((r["bytes"] for r in fusions), default=0)),
            },
        }
    return out


def _fmt(value, spec: str = ".3f") -> str:
    return "n/a" if value is None else format(value, spec)


def _markdown(summary: dict) -> str:
    cfg = summary["config"]
    lines = [
        "# Range-only tracking over a directed ring of four nodes",
        "",
        f"{cfg['duration']} s, seed {cfg['seed']}, sensor a = {cfg['sensor_a']}, WEP weight by "
        f"minimum {cfg['weight_cost']} of the fused covariance (mixtures: their own rule, min-info-loss). "
        f"Errors are RMS distances of each node's mean to the target after {BURN_IN_S} s "
        f"(and, in the column 'before', during the first {BURN_IN_S} s, while ranges are still ambiguous).",
        "",
        "| belief | RMS error | node 1 | node 2 | node 3 | node 4 | RMS error before | fusions "
        "| Renyi-2 rises at fusion | bytes/message |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, fam in summary["families"].items():
        nodes = " | ".join(_fmt(fam["per_node"][k]["rms_error"]) for k in sorted(fam["per_node"]))
        lines.append(
            f"| {name} | {_fmt(fam['rms_error'])} | {nodes} | {_fmt(fam['rms_error_before_burn_in'])} | "
            f"{fam['fusions']} | {fam['entropy_rises']} "
            f"(largest {fam['largest_rise']:.3f} nats) | {_fmt(fam['bytes_per_message']['mean'], '.0f')} |"
        )
    c = summary["central"]
    lines.append(
        f"| centralized grid | {_fmt(c['rms_error'])} | | | | | {_fmt(c['rms_error_before_burn_in'])} | | | |"
    )
    lines += [
        "",
        "A Renyi-2 entropy rise at a fusion event means the fused belief is less concentrated than the",
        "receiver's own; the weight minimises the covariance trace, not this entropy, so rises can occur.",
        "",
        "![error](error.png)",
        "",
        "![entropy](entropy.png)",
        "",
        "![beliefs](beliefs.png)",
        "",
    ]
    return "\n".join(lines)


def _plots(result: TrackingResult, out: Path) -> None:
    plt = pyplot()

    families = list(dict.fromkeys(r["family"] for r in result.records))
    fig, ax = plt.subplots(figsize=(8, 4))
    for name in families:
        rows = [r for r in result.records if r["family"] == name]
        ax.plot([r["time"] for r in rows], [r["error"] for r in rows], ".", ms=3, label=name)
    ax.plot(
        [c["time"] for c in result.central],
        [c["error"] for c in result.central],
        "k-",
        label="centralized",
    )
    ax.set(
        xlabel="time [s]",
        ylabel="|mean - target| [m]",
        yscale="log",
        title="tracking error (all nodes)",
    )
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "error.png", dpi=110)
    plt.close(fig)

    fig, axes = plt.subplots(
        1, len(families), figsize=(5 * len(families), 4), sharey=True, squeeze=False
    )
    for ax, name in zip(axes[0], families):
        for node in range(1, len(SENSORS) + 1):
            rows = [r for r in result.records if r["family"] == name and r["node"] == node]
            (line,) = ax.plot(
                [r["time"] for r in rows],
                [r["renyi2"] for r in rows],
                "-",
                lw=1,
                label=f"node {node}",
            )
            fus = [r for r in rows if r["event"] == "send"]
            ax.plot(
                [r["time"] for r in fus],
                [r["renyi2"] for r in fus],
                "o",
                ms=3,
                color=line.get_color(),
            )
        ax.plot(
            [c["time"] for c in result.central],
            [c["renyi2"] for c in result.central],
            "k--",
            lw=1,
            label="centralized",
        )
        ax.set(xlabel="time [s]", title=f"{name}: Renyi-2 entropy (dots: after fusion)")
    axes[0][0].set_ylabel("nats")
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "entropy.png", dpi=110)
    plt.close(fig)

    beliefs = result.final_beliefs.get("expoly")
    if beliefs:
        target = result.truth[-1]
        xs = np.linspace(target[0] - 4, target[0] + 4, 160)
        ys = np.linspace(target[1] - 4, target[1] + 4, 160)
        X, Y = np.meshgrid(xs, ys, indexing="ij")
        fig, axes = plt.subplots(
            1, len(beliefs), figsize=(4 * len(beliefs), 4.6), squeeze=False, layout="constrained"
        )
        pdfs = [b.pdf(np.stack([X, Y], axis=-1)) for b in beliefs]
        from matplotlib.ticker import MaxNLocator

        top = max(float(p.max()) for p in pdfs) or 1.0
        levels = MaxNLocator(20).tick_values(0, top)  # one scale for every node, one colour bar
        for k, (ax, pdf) in enumerate(zip(axes[0], pdfs)):
            filled = ax.contourf(X, Y, pdf, levels=levels, cmap="viridis")
            ax.plot(*SENSORS.T, "w^", ms=6, mec="k", label="sensors")
            ax.plot(*SENSORS[k], "r^", ms=8, label="this node's sensor")
            ax.plot(*target, "rs", mfc="none", ms=9, label="target")
            ax.set(
                title=f"node {k + 1}",
                aspect="equal",
                xlim=(xs[0], xs[-1]),
                ylim=(ys[0], ys[-1]),
                xlabel="x [m]",
            )
        axes[0][0].set_ylabel("y [m]")
        fig.colorbar(filled, ax=axes[0].tolist(), shrink=0.8, label="density [1/m²]")
        fig.suptitle(f"ExPoly beliefs at {result.times[-1]:.2f} s")
        fig.legend(
            *axes[0][0].get_legend_handles_labels(), loc="outside lower center", ncol=3, fontsize=8
        )
        fig.savefig(out / "beliefs.png", dpi=110)
        plt.close(fig)


def write_report(result: TrackingResult, out_dir) -> dict:
    """Write report.md, summary.json and the plots into ``out_dir``, all or nothing
    (:func:`octofuse.outputs.staging.staged_folder`)."""
    from ..outputs.staging import staged_folder

    summary = summarise(result)
    summary["records"] = result.records
    summary["central_series"] = result.central
    summary["truth"] = {"times": result.times.tolist(), "xy": result.truth.tolist()}
    with staged_folder(out_dir, "track") as stage:
        (stage / "summary.json").write_text(json.dumps(summary, indent=1, default=float))
        (stage / "report.md").write_text(_markdown(summary))
        _plots(result, stage)
    return summary


def run_tracking(out_dir, duration: float = 10.0, seed: int = 0, **options) -> TrackingResult:
    """Simulate (``options`` are further :class:`TrackingConfig` fields) and write report.md,
    summary.json and plots to ``out_dir`` (replaced as a whole). Returns the result; its
    ``summary`` attribute holds what summary.json holds."""
    result = simulate_tracking(TrackingConfig(duration=duration, seed=seed, **options))
    result.summary = write_report(result, out_dir)
    return result
