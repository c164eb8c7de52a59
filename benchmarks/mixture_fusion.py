"""Speed of Gaussian-mixture WEP fusion (``octofuse.beliefs.mixture_fusion.fuse_mixtures``).

One fusion of two 15-component 2-D mixtures with N_s = 1000 importance samples: the omega search
(paper 000 Algorithm 1), the fused mixture (each method) and the reduction to 15 components,
in milliseconds on one core. Beside it, in the same run, the same fusion by integration on a
regular grid (``mixture_grid.grid_fuse``: omega from the grid costs and the fused density at the
grid nodes), and the ratio of the two. The fused mixtures' accuracy is reported as the KLD from
the grid density (nats). Each figure is the median of ``--repeats`` runs (seeds vary), timed as
the process's CPU time: the work is single-threaded (BLAS limited to one thread), so this is the
time on one core, and it stays steady when other processes share the machine.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/mixture_fusion.py [--repeats R] [--grid N] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from bench_common import machine  # noqa: E402
from octofuse.beliefs.mixture import GaussianMixture  # noqa: E402
from octofuse.beliefs.mixture_fusion import fuse_mixtures  # noqa: E402
from octofuse.beliefs.mixture_grid import Grid2D, grid_fuse, grid_kl  # noqa: E402

RULES = ("chernoff", "min-info-loss", "kld-weighted-chernoff")
METHODS = ("moment-match", "em", "foci")


def random_mixture(seed: int, m: int = 15, offset=(0.0, 0.0)) -> GaussianMixture:
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(m, 2, 2)) * 0.6
    cov = a @ np.swapaxes(a, 1, 2) + 0.3 * np.eye(2)
    return GaussianMixture(rng.uniform(0.2, 1.0, m), rng.uniform(-4, 4, (m, 2)) + offset, cov)


def timed(fn, repeats: int) -> tuple[float, object]:
    times, out = [], None
    for k in range(repeats):
        t0 = time.process_time()
        out = fn(k)
        times.append(time.process_time() - t0)
    return statistics.median(times) * 1e3, out


def measure(repeats: int, grid_n: int) -> list[dict]:
    """Every rule and method, timed against the grid; accuracy of the last run (seed repeats-1)."""
    a, b = random_mixture(1), random_mixture(2, offset=(1.0, 0.5))
    prior = random_mixture(3, m=4)
    grid = Grid2D.covering(a, b, prior, n=grid_n)
    pts = grid.points
    rows = []
    for rule in RULES:
        grid_ms, truth = timed(lambda k: grid_fuse(a, b, rule, grid, prior=prior), repeats)
        for method in METHODS:
            ms, res = timed(
                lambda k: fuse_mixtures(
                    a,
                    b,
                    rule=rule,
                    n_samples=1000,
                    method=method,
                    max_components=15,
                    prior=prior,
                    seed=k,
                ),
                repeats,
            )
            rows.append(
                {
                    "rule": rule,
                    "method": method,
                    "ms": ms,
                    "grid_ms": grid_ms,
                    "grid_over_sampling": grid_ms / ms,
                    "omega": res.omega,
                    "grid_omega": truth.omega,
                    "kl_from_grid": grid_kl(truth.log_density, res.mixture.logpdf(pts)),
                }
            )
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--grid", type=int, default=400, help="grid nodes per axis")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    rows = measure(args.repeats, args.grid)
    print(
        f"Mixture fusion, 2 x 15 components in 2-D, N_s = 1000, reduction to 15 ({machine()}, one core;"
        f" CPU time; grid {args.grid} x {args.grid}, median of {args.repeats})"
    )
    print(
        f"{'rule':24s} {'method':13s} {'ms':>8s} {'grid ms':>8s} {'grid/IS':>8s} {'omega':>7s}"
        f" {'grid w':>7s} {'KL grid||fused':>15s}"
    )
    for r in rows:
        print(
            f"{r['rule']:24s} {r['method']:13s} {r['ms']:8.1f} {r['grid_ms']:8.1f} "
            f"{r['grid_over_sampling']:8.2f} {r['omega']:7.3f} {r['grid_omega']:7.3f} {r['kl_from_grid']:15.4f}"
        )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(
                {"machine": machine(), "grid": args.grid, "repeats": args.repeats, "rows": rows},
                f,
                indent=1,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
