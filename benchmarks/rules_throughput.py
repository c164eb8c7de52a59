"""Throughput of the per-voxel fusion rules on arrays (``octofuse.fuse_logodds``).

Fuses 10 million random log-odds pairs with every rule and reports pairs per second. The
array kernel is single-threaded (one core); numpy adding the same two arrays (the naive-Bayes
fusion, ``l_a + l_b``) is the baseline. Each figure is the median of ``--repeats`` runs.

The inputs: 80% of the values uniform in OctoMap's default clamping range [-2, 3.5] (where
the values of a stored map lie) and 20% uniform in [-8, 8] (unclamped values), fixed seed.

    .venv/bin/python benchmarks/rules_throughput.py [--pairs N] [--repeats R] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time

import numpy as np

import octofuse
from bench_common import machine  # noqa: E402

#: Closed-form rules (the target: at least 20 million pairs per second on one core).
CLOSED_FORM = ("bhattacharyya", "min-entropy", "chernoff", "min-info-loss")


def make_inputs(n: int, seed: int = 20240601) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)

    def one() -> np.ndarray:
        x = rng.uniform(-2.0, 3.5, n)
        wide = rng.random(n) < 0.2
        x[wide] = rng.uniform(-8.0, 8.0, int(wide.sum()))
        return x

    return one(), one()


def timed(fn, repeats: int) -> float:
    """Median wall time of ``fn()`` over ``repeats`` runs (after one warm-up run)."""
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def run(pairs: int, repeats: int) -> dict:
    la, lb = make_inputs(pairs)
    results = {"pairs": pairs, "repeats": repeats, "machine": machine(), "rules": {}}
    numpy_s = timed(lambda: np.add(la, lb), repeats)
    results["numpy_add_s"] = numpy_s
    results["numpy_add_pairs_per_s"] = pairs / numpy_s
    for rule in octofuse.RULES:
        s = timed(lambda rule=rule: octofuse.fuse_logodds(la, lb, rule=rule), repeats)
        results["rules"][rule] = {"median_s": s, "pairs_per_s": pairs / s}
    return results


def print_table(res: dict, out=sys.stdout) -> None:
    pairs = res["pairs"]
    nb = res["rules"]["naive-bayes"]["median_s"]
    print(
        "octofuse per-voxel rules on arrays (octofuse.fuse_logodds, single-threaded kernel)",
        file=out,
    )
    print(f"machine: {res['machine']}", file=out)
    print(
        f"{pairs:,} log-odds pairs; median of {res['repeats']} runs; each call returns the "
        "fused value, the weight and the information loss (3 arrays)",
        file=out,
    )
    print(
        f"{'method':34s} {'median s':>9s} {'pairs/s':>14s} {'time / numpy add':>17s} "
        f"{'time / NB':>10s}",
        file=out,
    )
    print(
        f"{'numpy l_a + l_b (baseline)':34s} {res['numpy_add_s']:9.3f} "
        f"{res['numpy_add_pairs_per_s']:14,.0f} {1.0:17.2f} {res['numpy_add_s'] / nb:10.2f}",
        file=out,
    )
    for rule, r in res["rules"].items():
        tag = " *" if rule in CLOSED_FORM else ""
        print(
            f"{'fuse_logodds ' + rule + tag:34s} {r['median_s']:9.3f} {r['pairs_per_s']:14,.0f} "
            f"{r['median_s'] / res['numpy_add_s']:17.2f} {r['median_s'] / nb:10.2f}",
            file=out,
        )
    print("* closed-form rule", file=out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=10_000_000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--json", help="also write the figures to this JSON file")
    args = ap.parse_args(argv)
    res = run(args.pairs, args.repeats)
    print_table(res)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(res, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
