"""The checks of Tonkes and Blair (exponentials of polynomials), measured beside the paper's numbers.

1. Two rings (sensors at (2, 2) and (1, -1), target at (-1, -2), a = 2): each source's covariance
   trace (paper: about 25 and 5), the fused minimum of the trace over w (about 2.6 near w = 0.49),
   the other weight costs, and covariance intersection of the moment-matched Gaussians, which
   cannot go below the smaller source.
2. Degree 2 is Gaussian covariance intersection exactly (largest difference over random pairs).
3. The approximate diffusion (eq. 3) against the exact convolution on a grid: total variation
   distance and covariance trace, with and without the final moment correction.
4. The moments-to-coefficients Newton step: a - G^-1 dM reduces the moment error, the printed
   a + G^-1 dM increases it; whole fits of a mild and of a ring-like target.

    .venv/bin/python benchmarks/expoly_paper_checks.py [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
from scipy.signal import fftconvolve

from octofuse.beliefs.expoly import ExPoly2D
from octofuse.beliefs.expoly_fit import _with, fit_moments, monomials
from octofuse.beliefs.gaussian import Gaussian
from octofuse.beliefs.weight_search import COSTS, choose_weight

SENSORS = np.array([[2.0, 2.0], [1.0, -1.0]])
TARGET = np.array([-1.0, -2.0])


def two_rings(a: float = 2.0) -> dict:
    rings = [ExPoly2D.range_likelihood(s, np.linalg.norm(TARGET - s), a) for s in SENSORS]
    out = {"source_traces": [float(np.trace(r.moments()[1])) for r in rings]}
    out["trace_curve"] = {
        f"{w:.1f}": float(np.trace(rings[0].wep(rings[1], w).moments()[1]))
        for w in np.linspace(0, 1, 11)
    }
    for cost in COSTS:
        t0 = time.perf_counter()
        choice = choose_weight(rings[0], rings[1], cost)
        mean, cov = choice.fused.moments()
        out[cost] = {
            "w": choice.w,
            "cost": choice.cost,
            "trace": float(np.trace(cov)),
            "mean": mean.tolist(),
            "seconds": time.perf_counter() - t0,
        }
    gauss = choose_weight(rings[0].to_gaussian(), rings[1].to_gaussian(), "trace")
    out["gaussian_ci"] = {"w": gauss.w, "trace": gauss.cost}
    return out


def degree_two_vs_gaussian_ci(pairs: int = 200, seed: int = 0) -> float:
    rng = np.random.default_rng(seed)
    worst = 0.0
    for _ in range(pairs):
        beliefs = []
        for _ in range(2):
            L = rng.normal(size=(2, 2))
            beliefs.append((rng.normal(scale=3, size=2), L @ L.T + 0.1 * np.eye(2)))
        w = rng.uniform()
        mean, cov = (
            ExPoly2D.from_gaussian(*beliefs[0])
            .wep(ExPoly2D.from_gaussian(*beliefs[1]), w)
            .moments()
        )
        ci = Gaussian.from_moments(*beliefs[0]).wep(Gaussian.from_moments(*beliefs[1]), w)
        worst = max(worst, np.abs(mean - ci.mean).max(), np.abs(cov - ci.cov).max())
    return float(worst)


def diffusion_error(h: float = 0.04) -> list[dict]:
    cases = {
        "ring x Gaussian": ExPoly2D.range_likelihood([0, 0], 2.0, 2.0).multiply(
            ExPoly2D.from_gaussian([1, 1], [[2, 0], [0, 2]])
        ),
        "two rings fused (w = 0.49)": ExPoly2D.range_likelihood(SENSORS[0], 5.0, 2.0).wep(
            ExPoly2D.range_likelihood(SENSORS[1], np.sqrt(5.0), 2.0), 0.49
        ),
    }
    rows = []
    for name, belief in cases.items():
        m = belief.moments()[0]
        xs, ys = np.arange(-9, 9 + h / 2, h) + m[0], np.arange(-9, 9 + h / 2, h) + m[1]
        X, Y = np.meshgrid(xs, ys, indexing="ij")
        pts = np.stack([X, Y], axis=-1)
        p = belief.pdf(pts)
        k = np.arange(-4, 4 + h / 2, h)
        KX, KY = np.meshgrid(k, k, indexing="ij")
        for q in (0.01, 0.05, 0.25):
            kernel = np.exp(-0.5 * (KX**2 + KY**2) / q)
            exact = fftconvolve(p, kernel / kernel.sum(), mode="same")
            row = {
                "belief": name,
                "q": q,
                "exact_trace": float(np.trace(belief.moments()[1]) + 2 * q),
            }
            for label, match in (("eq3", False), ("eq3+moments", True)):
                out = belief.diffuse(q * np.eye(2), match_moments=match)
                row[f"tv_{label}"] = float(0.5 * np.abs(out.pdf(pts) - exact).sum() * h * h)
                row[f"trace_{label}"] = float(np.trace(out.moments()[1]))
            rows.append(row)
    return rows


def newton_checks() -> dict:
    terms = monomials(4)
    mild = ExPoly2D.from_gaussian([1, 0], [[2, 0.5], [0.5, 1]]).multiply(
        ExPoly2D.range_likelihood([0, 0], 2, 0.3)
    )
    target = mild.raw_moments(terms)
    start = mild.wep(ExPoly2D.from_gaussian(*mild.moments()), 0.7)  # a nearby degree-4 belief
    c = start.coefficients
    a = np.array([c[i, j] for i, j in terms])
    g = start.grid()
    X, Y = g.mesh
    phi = np.stack([(X**i * Y**j).ravel() for i, j in terms])
    w = g.weights.ravel()
    m = phi @ w
    G = ((phi - m[:, None]) * w) @ (phi - m[:, None]).T
    dm = target - m
    step = np.linalg.solve(G, dm)
    out = {"start_error": float(np.abs(dm).max())}
    for label, sign in (("a - G^-1 dM", -1.0), ("a + G^-1 dM", 1.0)):
        try:
            moved = _with(a + sign * step, terms, 4).raw_moments(terms)
            out[label] = float(np.abs(target - moved).max())
        except ValueError as err:
            out[label] = f"not elliptic ({err})"
    for name, belief in (
        ("mild", mild),
        (
            "ring-like",
            ExPoly2D.range_likelihood([2, 2], 5, 2.0).wep(
                ExPoly2D.from_gaussian([0, 0], [[2, 0], [0, 2]]), 0.2
            ),
        ),
    ):
        fit = fit_moments(belief.raw_moments(terms))
        out[f"fit {name}"] = {
            "converged": fit.converged,
            "iterations": fit.iterations,
            "residual": fit.residual,
        }
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", help="also write the numbers to this file")
    args = parser.parse_args()
    rings = two_rings()
    print("Two rings, a = 2                          measured     paper")
    print(f"  trace of source 1 (sensor (2, 2))      {rings['source_traces'][0]:8.3f}      ~25")
    print(f"  trace of source 2 (sensor (1, -1))     {rings['source_traces'][1]:8.3f}      ~5")
    tr = rings["trace"]
    print(f"  fused minimum trace                    {tr['trace']:8.3f}      ~2.6")
    print(f"  at w                                   {tr['w']:8.3f}      ~0.49")
    print(
        f"  Gaussian CI of the moments: min trace  {rings['gaussian_ci']['trace']:8.3f}      >= 5 (the smaller source)"
    )
    print("  trace over w: " + ", ".join(f"{k}: {v:.2f}" for k, v in rings["trace_curve"].items()))
    for cost in COSTS:
        r = rings[cost]
        print(
            f"  cost {cost:9s}: w = {r['w']:.3f}, fused trace {r['trace']:.3f}, mean {np.round(r['mean'], 2).tolist()}"
            f" ({r['seconds']:.2f} s)"
        )
    worst = degree_two_vs_gaussian_ci()
    print(
        f"\nDegree 2 vs Gaussian CI: largest difference in mean/covariance over 200 pairs {worst:.2e}"
    )
    print("\nDiffusion, eq. 3 (eta = 4) vs exact convolution with q I on a grid")
    diff = diffusion_error()
    for r in diff:
        print(
            f"  {r['belief']:28s} q = {r['q']:.2f}: TV {r['tv_eq3']:.3f} (moment-corrected {r['tv_eq3+moments']:.3f}),"
            f" trace {r['trace_eq3']:.3f} vs exact {r['exact_trace']:.3f}"
        )
    newton = newton_checks()
    print("\nMoments to coefficients (largest moment error)")
    for k, v in newton.items():
        print(f"  {k}: {v}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(
                {
                    "two_rings": rings,
                    "degree_two_max_diff": worst,
                    "diffusion": diff,
                    "newton": newton,
                },
                f,
                indent=1,
            )


if __name__ == "__main__":
    main()
