"""What a target search run writes: report.md, summary.json and PNG figures."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..outputs.libraries import pyplot
from .search import BASELINES, DEFAULT_RULES, TargetSearchResult, simulate

EXTREME = 0.1  # omega within this of 0 or 1 counts as a 'winner takes all' choice
EARLY_STEP = 30  # the paper's 'initial stages' end near k = 30
PAPER_BAND = (0.4, 0.55)  # KLD of the WEP rules to the centralized belief in paper 000 (nats)


def _final(table: dict, scheme: str) -> np.ndarray:
    return table[scheme][-1]


def findings(res: TargetSearchResult) -> dict:
    """The paper's three findings (and the information dips), measured on this run."""
    wep = [s for s in res.schemes if s not in BASELINES and s != "naive-bayes"]
    central_gain = float(_final(res.info_gain, "centralized")[0])
    out: dict = {}
    if "naive-bayes" in res.schemes:
        nb_kl = _final(res.kl_to_central, "naive-bayes")
        wep_max = max((float(_final(res.kl_to_central, s).max()) for s in wep), default=math.nan)
        nb_gain = _final(res.info_gain, "naive-bayes")
        out["naive_bayes_inconsistent"] = {
            "kl_to_central_per_robot": nb_kl.tolist(),
            "largest_wep_kl_to_central": wep_max,
            "info_gain_per_robot": nb_gain.tolist(),
            "centralized_info_gain": central_gain,
            "overconfident_robots": int(np.sum(nb_gain > central_gain)),
            "holds": bool(np.all(nb_gain > central_gain) and nb_kl.min() > 2.0 * wep_max),
        }
    if wep:
        r1 = {s: float(_final(res.kl_to_central, s)[0]) for s in wep}
        allr = {s: _final(res.kl_to_central, s).tolist() for s in wep}
        lo, hi = min(r1.values()), max(r1.values())
        out["wep_band"] = {
            "robot1_kl_to_central": r1,
            "kl_to_central_per_robot": allr,
            "band": [lo, hi],
            "width": hi - lo,
            "no_sharing_robot1": float(_final(res.kl_to_central, "no-sharing")[0]),
            "paper_band": list(PAPER_BAND),
            "holds": bool(hi - lo <= PAPER_BAND[1] - PAPER_BAND[0] + 1e-12),
        }
    if wep:
        alone = float(_final(res.kl_to_central, "no-sharing").mean())
        mean_kl = {s: float(_final(res.kl_to_central, s).mean()) for s in wep}
        out["wep_closer_than_no_sharing"] = {
            "mean_kl_to_central": mean_kl,
            "no_sharing": alone,
            "rules_closer": [s for s, v in mean_kl.items() if v < alone],
        }
    extreme, dips = {}, {}
    for s in wep:
        recs = [f for f in res.fusions if f["scheme"] == s]
        early = [f["omega"] for f in recs if f["k"] <= EARLY_STEP]
        late = [f["omega"] for f in recs if f["k"] > EARLY_STEP]
        extreme[s] = {
            "early": _fraction_extreme(early),
            "late": _fraction_extreme(late),
            "early_distance": _distance_from_half(early),
            "late_distance": _distance_from_half(late),
            "n_early": len(early),
            "n_late": len(late),
        }
        drops = [f["gain_after"] < f["gain_before"] - 1e-3 for f in recs]
        dips[s] = float(np.mean(drops)) if drops else math.nan
    if "kld-weighted-chernoff" in extreme:
        kw = extreme["kld-weighted-chernoff"]
        plain = extreme.get("chernoff", {}).get("early_distance", -math.inf)
        out["kld_weighted_extreme_early"] = {
            "per_rule": extreme,
            "threshold": EXTREME,
            "early_steps": EARLY_STEP,
            "holds": bool(
                kw["early_distance"] > kw["late_distance"] and kw["early_distance"] > plain
            ),
        }
    out["information_dips"] = {"fraction_of_fusions_lowering_gain": dips}
    return out


def _fraction_extreme(ws: list[float]) -> float:
    return float(np.mean([min(w, 1.0 - w) <= EXTREME for w in ws])) if ws else math.nan


def _distance_from_half(ws: list[float]) -> float:
    """Mean ``|w - 1/2|``: 0 for Bhattacharyya, 1/2 for 'winner takes all'."""
    return float(np.mean(np.abs(np.asarray(ws) - 0.5))) if ws else math.nan


def _verdict(f: dict) -> str:
    return "**holds**" if f.get("holds") else "**does not hold**"


def _report_md(res: TargetSearchResult, found: dict, figures: list[str]) -> str:
    p = res.params
    lines = [
        f"# octofuse target search: {res.setting}",
        "",
        f"Static target at ({res.target[0]:.2f}, {res.target[1]:.2f}) m in the 15 x 8 m lab; "
        f"{res.poses.shape[0]} robots, {p['duration']} s at 1 Hz, exchanges every {p['comm_period']} s; "
        f"{p['particles']} particles per mixand, at most {p['max_components']} mixands, "
        f"N_s = {p['n_samples']}, fused mixtures by {p['method']}; seed {res.seed}; "
        f"{res.detections} detections.",
        "",
        "Information gain is KL(robot || common prior); distance to the centralized belief is "
        "KL(centralized || robot); both in nats, by integration on the lab grid.",
        "",
        "| scheme | gain robot 1 | mean gain | KL to centralized, robot 1 | mean KL to centralized |",
        "|---|---|---|---|---|",
    ]
    for s in res.schemes:
        g, k = _final(res.info_gain, s), _final(res.kl_to_central, s)
        lines.append(f"| {s} | {g[0]:.3f} | {g.mean():.3f} | {k[0]:.3f} | {k.mean():.3f} |")
    lines += ["", "## What the data says about the paper's findings", ""]
    if "naive_bayes_inconsistent" in found:
        f = found["naive_bayes_inconsistent"]
        lines.append(
            f"- Naive Bayes severely inconsistent: {_verdict(f)}. Its final information gain exceeds the "
            f"centralized belief's ({f['centralized_info_gain']:.3f} nats, all the data) for "
            f"{f['overconfident_robots']} of {len(f['info_gain_per_robot'])} robots (gains "
            f"{', '.join(f'{v:.2f}' for v in f['info_gain_per_robot'])}); its KL to the centralized belief "
            f"is {min(f['kl_to_central_per_robot']):.2f}-{max(f['kl_to_central_per_robot']):.2f} nats against at "
            f"most {f['largest_wep_kl_to_central']:.3f} for any WEP rule."
        )
    if "wep_band" in found:
        f = found["wep_band"]
        vals = ", ".join(f"{s} {v:.3f}" for s, v in f["robot1_kl_to_central"].items())
        lines.append(
            f"- WEP rules within a band of the centralized belief: {_verdict(f)} (band width at most "
            f"{PAPER_BAND[1] - PAPER_BAND[0]:.2f} nats as in the paper). Robot 1's KL to centralized: {vals}; "
            f"band {f['band'][0]:.3f}-{f['band'][1]:.3f} (paper: {PAPER_BAND[0]}-{PAPER_BAND[1]}); "
            f"without sharing {f['no_sharing_robot1']:.3f}."
        )
    if "wep_closer_than_no_sharing" in found:
        f = found["wep_closer_than_no_sharing"]
        vals = ", ".join(f"{s} {v:.3f}" for s, v in f["mean_kl_to_central"].items())
        lines.append(
            f"- Not a finding of the paper, measured alongside: mean KL to the centralized belief over the robots "
            f"without sharing {f['no_sharing']:.3f} nats; with WEP fusion {vals}. WEP rules closer than no sharing: "
            f"{', '.join(f['rules_closer']) or 'none'}."
        )
    if "kld_weighted_extreme_early" in found:
        f = found["kld_weighted_extreme_early"]
        vals = "; ".join(
            f"{s} {v['early_distance']:.2f} / {v['late_distance']:.2f}"
            f" ({v['early']:.0%} / {v['late']:.0%})"
            for s, v in f["per_rule"].items()
        )
        lines.append(
            f"- KLD-weighted Chernoff chooses extreme w early: {_verdict(f)} (its mean |w - 1/2| is larger for "
            f"k <= {EARLY_STEP} than later and larger than Chernoff's early). Mean |w - 1/2|, k <= {EARLY_STEP} / "
            f"later (share of fusions with w within {EXTREME} of 0 or 1): {vals}."
        )
    dips = found["information_dips"]["fraction_of_fusions_lowering_gain"]
    if dips:
        lines.append(
            "- Fusions that lowered the receiver's information gain: "
            + ", ".join(f"{s} {v:.0%}" for s, v in dips.items())
            + "."
        )
    lines += ["", "## Figures", ""] + [f"![{f}]({f})" for f in figures] + [""]
    return "\n".join(lines)


def _plot(res: TargetSearchResult, out: Path) -> list[str]:
    plt = pyplot()

    ext = res.params["grid_extent"]
    xs, ys = np.linspace(ext[0], ext[1], 241), np.linspace(ext[2], ext[3], 141)
    pts = np.column_stack([c.ravel() for c in np.meshgrid(xs, ys, indexing="xy")])
    panels = [("common prior", res.prior)] + [(s, res.final[s][0]) for s in res.schemes]
    cols = 3
    rows = math.ceil(len(panels) / cols)
    fig, axes = plt.subplots(
        rows, cols, figsize=(4.6 * cols, 2.8 * rows + 0.6), squeeze=False, layout="constrained"
    )
    for ax, (name, mix) in zip(axes.ravel(), panels):
        im = ax.imshow(
            mix.pdf(pts).reshape(len(ys), len(xs)), origin="lower", extent=ext, cmap="viridis"
        )
        fig.colorbar(im, ax=ax, shrink=0.9, label="density [1/m²]")
        for i, path in enumerate(res.poses):
            ax.plot(path[:, 0], path[:, 1], "w-", lw=0.8, label="robot paths" if i == 0 else None)
            ax.plot(
                *path[-1, :2],
                "o",
                color="red" if i == 0 else "white",
                ms=3,
                label={0: "robot 1", 1: "other robots"}.get(i),
            )
        ax.plot(*res.target, "*", color="orange", ms=9, label="target")
        ax.set_title(name if name == "common prior" else f"robot 1, {name}", fontsize=9)
        ax.set_xlim(0, 15), ax.set_ylim(0, 8)
    for ax in axes.ravel()[len(panels) :]:
        ax.axis("off")
    fig.legend(
        *axes[0, 0].get_legend_handles_labels(),
        loc="outside lower center",
        ncol=4,
        fontsize=8,
        facecolor="lightgrey",
    )
    names = ["final_beliefs_robot1.png"]
    fig.savefig(out / names[-1], dpi=110)
    plt.close(fig)

    steps = np.arange(res.info_gain[res.schemes[0]].shape[0])
    exch = [k for k in steps[1:] if k % res.params["comm_period"] == 0]
    for key, table, label in (
        ("info_gain", res.info_gain, "KL(robot || prior), nats"),
        ("kl_to_central", res.kl_to_central, "KL(centralized || robot), nats"),
    ):
        schemes = [s for s in res.schemes if not (key == "kl_to_central" and s == "centralized")]
        fig, axes = plt.subplots(
            math.ceil(len(schemes) / 3),
            3,
            figsize=(13, 3.0 * math.ceil(len(schemes) / 3)),
            squeeze=False,
        )
        for ax, s in zip(axes.ravel(), schemes):
            for i in range(table[s].shape[1]):
                ax.plot(steps, table[s][:, i], lw=1, label=f"robot {i + 1}")
            for k in exch:
                ax.axvline(k, color="0.8", lw=0.6)
            ax.set_title(s, fontsize=9), ax.set_xlabel("k (s)"), ax.set_ylabel(label, fontsize=8)
            if s == "naive-bayes":
                ax.set_yscale("symlog", linthresh=0.1)
                ax.set_ylim(bottom=0.0)
        axes.ravel()[0].legend(fontsize=6, ncol=2)
        for ax in axes.ravel()[len(schemes) :]:
            ax.axis("off")
        fig.tight_layout()
        names.append(f"{key}.png")
        fig.savefig(out / names[-1], dpi=110)
        plt.close(fig)

    wep = [s for s in res.schemes if s not in BASELINES and s != "naive-bayes"]
    if wep:
        fig, axes = plt.subplots(
            1, len(wep), figsize=(3.3 * len(wep), 2.8), squeeze=False, sharey=True
        )
        for ax, s in zip(axes[0], wep):
            recs = [f for f in res.fusions if f["scheme"] == s]
            jitter = np.array([(f["receiver"] - 1) * 0.6 for f in recs])
            ax.scatter(
                [f["k"] for f in recs] + jitter,
                [f["omega"] for f in recs],
                c=[f["receiver"] for f in recs],
                cmap="tab10",
                vmin=1,
                vmax=10,
                s=14,
            )
            ax.set_title(s, fontsize=9), ax.set_xlabel("k (s)"), ax.set_ylim(-0.05, 1.05)
        axes[0][0].set_ylabel("w on the receiver's belief")
        fig.suptitle(
            "chosen w per fusion; colour: receiving robot (1 blue, 2 orange, 3 green, 4 red, ...)",
            fontsize=9,
        )
        fig.tight_layout()
        names.append("omega.png")
        fig.savefig(out / names[-1], dpi=110)
        plt.close(fig)
    return names


def _summary(res: TargetSearchResult, found: dict) -> dict:
    return {
        "setting": res.setting,
        "seed": res.seed,
        "params": res.params,
        "target": res.target.tolist(),
        "schemes": list(res.schemes),
        "detections": res.detections,
        "final_info_gain": {s: _final(res.info_gain, s).tolist() for s in res.schemes},
        "final_kl_to_central": {s: _final(res.kl_to_central, s).tolist() for s in res.schemes},
        "final_target_logpdf": {s: _final(res.target_logpdf, s).tolist() for s in res.schemes},
        "info_gain": {s: res.info_gain[s].tolist() for s in res.schemes},
        "kl_to_central": {s: res.kl_to_central[s].tolist() for s in res.schemes},
        "fusions": res.fusions,
        "findings": found,
        "final_beliefs_robot1": {s: res.final[s][0].to_dict() for s in res.schemes},
    }


def _clean(v):
    """JSON-ready copy: numpy scalars and arrays as Python values, NaN and inf as null."""
    if isinstance(v, dict):
        return {k: _clean(x) for k, x in v.items()}
    if isinstance(v, (list, tuple, np.ndarray)):
        return [_clean(x) for x in v]
    if isinstance(v, (np.floating, np.integer, np.bool_)):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def write_report(res: TargetSearchResult, out: Path, figures: bool = True) -> Path:
    """Write the outputs into a staged folder that replaces ``out`` when complete."""
    from ..outputs.staging import staged_folder

    found = findings(res)
    with staged_folder(out, "search") as stage:
        names = _plot(res, stage) if figures else []
        (stage / "summary.json").write_text(
            json.dumps(_clean(_summary(res, found)), indent=1, allow_nan=False)
        )
        (stage / "report.md").write_text(_report_md(res, found, names))
    return Path(out)


def run_target_search(
    out_dir,
    setting: str = "3-robots",
    rules=DEFAULT_RULES,
    seed: int = 0,
    *,
    duration: int = 65,
    comm_period: int = 13,
    n_samples: int = 1000,
    particles: int = 1000,
    max_components: int = 15,
    method: str = "moment-match",
    pair_samples: int = 1000,
    grid_step: float = 0.1,
    figures: bool = True,
    progress=None,
) -> TargetSearchResult:
    """Simulate the search and write ``report.md``, ``summary.json`` and figures into ``out_dir``.

    ``n_samples`` is N_s of the omega search, ``pair_samples`` the importance samples per component
    pair when ``method`` is ``moment-match``, ``particles`` the particles per mixand of the filter.
    The outputs are written into a temporary directory beside ``out_dir`` and renamed into place
    (an existing ``out_dir`` written by octofuse is replaced; any other folder is refused).
    ``progress`` is an optional callable taking one line.
    """
    res = simulate(
        setting,
        rules,
        seed,
        duration=duration,
        comm_period=comm_period,
        n_samples=n_samples,
        particles=particles,
        max_components=max_components,
        method=method,
        pair_samples=pair_samples,
        grid_step=grid_step,
        progress=progress,
    )
    res.out_dir = write_report(res, Path(out_dir), figures=figures)
    return res
