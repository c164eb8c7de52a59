"""Print the published checks of dynamic voting beside octofuse's results.

    .venv/bin/python benchmarks/voting_paper_checks.py [--trials 1000] [--seed 0] [--json FILE]

The checks themselves are ``octofuse.fusion.voting_checks.paper_checks``; this script only prints
them (under a minute for 1000 trials on one core).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from octofuse.fusion.voting_checks import PAPER_TABLE, paper_checks


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trials", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", type=Path, help="also write the results here")
    args = ap.parse_args()
    res = paper_checks(args.trials, args.seed)
    print_checks(res)
    if args.json:
        args.json.write_text(json.dumps(res, indent=1) + "\n")


def print_checks(res: dict) -> None:
    print("1. Number of hypotheses K (P = 0.99, c = 1)")
    for key, v in res["hypothesis_counts"].items():
        verdict = "matches" if v["K"] == v["paper"] else "DIFFERS"
        print(f"   {key}: K = {v['K']} (paper {v['paper']}) {verdict}")

    f = res["fig3"]
    print(f"\n2. Fig. 3: 10 robots, 7 inliers, fixed graph, K = {f['hypotheses']}")
    votes = f["winner_votes"]
    print(
        f"   winner's votes at the robots: {min(votes):.6f} .. {max(votes):.6f} "
        f"(paper: 0.7 = inlier fraction {f['inlier_fraction']})"
    )
    print(
        f"   inliers found exactly: {f['inliers_found']}; "
        f"winner seeded by an inlier: {f['winner_seeded_by_inlier']}"
    )
    print(
        f"   estimate vs ML of the inliers: max difference {f['max_estimate_error_to_ml_inliers']:.2e} "
        f"(ML of the inliers {_xy(f['ml_inliers'])}, ML of all {_xy(f['ml_all'])})"
    )
    print(
        f"   last round in which a robot changed its vote: {f['last_round_with_a_vote_change']} "
        "(paper: fewer than 10)"
    )
    print(f"   traffic: {f['bytes'] / 1e3:.0f} kB in total")

    for key, title in (
        ("table1", "3. Table I under the paper's covariances"),
        ("table1_consistent", "3b. The same with covariances that state the noise (4 I)"),
    ):
        t = res[key]
        print(
            f"\n{title}: {t['trials']} trials of 20 robots, {t['outliers']} outliers, "
            f"{t['inliers']} inliers"
        )
        head = (
            f"   {'method':<18}{'false pos':>10}{'false neg':>10}{'err to ML_in':>13}{'std':>7}"
            f"{'err to truth':>13}{'rounds':>7}{'kB/trial':>9}"
        )
        print(head)
        for name, paper_key in _rows(t):
            r = t[name]
            print(
                f"   {name:<18}{r['false_positives']:>10}{r['false_negatives']:>10}"
                + (
                    f"{r['mean_error']:>13.3f}{r['std_error']:>7.3f}{r['mean_error_to_truth']:>13.3f}"
                    f"{r['rounds']:>7}{r['kilobytes_per_trial']:>9.0f}"
                    if "mean_error" in r
                    else "   (the gate alone, at the exact ML of the true inliers)"
                )
            )
            if paper_key and key == "table1":
                p = PAPER_TABLE[paper_key]
                print(
                    f"   {'  paper':<18}{p['false_positives']:>10}{p['false_negatives']:>10}"
                    f"{p['mean_error']:>13.3f}{p['std_error']:>7.3f}{'':>13}{p['rounds']:>7}"
                )
    print("\nAssumptions (the text leaves them open):")
    for k, v in res["table1"]["assumptions"].items():
        print(f"   {k}: {v}")
    print(VERDICT)


def _rows(t: dict):
    for name in t:
        if isinstance(t[name], dict) and "false_positives" in t[name]:
            base = name.split("[")[0]
            yield (
                name,
                (
                    base
                    if base in PAPER_TABLE and (base == "ml" or name.endswith("[paper]"))
                    else None
                ),
            )


def _xy(v) -> str:
    return "(" + ", ".join(f"{c:.2f}" for c in v) + ")"


VERDICT = """
What matches: K = 6 and K = 3; Fig. 3 (the winner's votes reach 0.7 at every robot, its estimate
the ML of the inliers, votes settle within a few rounds); ML's false positives (every outlier,
about 4000) and false negatives (0) and, roughly, its error (about 2 m); dynamic voting's false
positives (about 360 against 355) with the paper's test form.

What does not: the false negatives and the errors of both voting methods. With the stated noise
(inliers 2 m, outliers 10 m, both about the true value) and covariances whose eigenvalues are
about 0.5 m^2, an inlier's covariance understates its error about threefold in standard
deviation, so even the oracle row (each robot testing against the exact ML of the true inliers)
rejects thousands of inliers. Nor can a gate that does not know who is an inlier give both of
the paper's rates: for round gates of radius R about the true value, with u = exp(-R^2 / 200),
outliers pass with probability 1 - E[u] and inliers fail with probability E[u^25] >= E[u]^25
(Jensen), so accepting 9 % of the outliers means rejecting at least 9.7 % of the inliers, not the
paper's 1.2 %. Dimension 3, confidence 0.99, exponential eigenvalues or eigenvalues read as
standard deviations do not close the gap either (the oracle still rejects 1600 or more).
The inliers dropped are the confident ones (small covariance, tight gate), so the voting
estimates move away from the ML of all inliers. Static voting tests against Λ_i + Λ_ML, a wider
gate than dynamic voting's Λ_i: hence its fewer false negatives and more false positives here
(the paper reports the opposite order). With covariances that state the noise (second table)
the algorithms behave as designed: false negatives near the gate's 5 %, the false positives are
outliers that fall among the inliers, and the errors are small.
"""


if __name__ == "__main__":
    main()
