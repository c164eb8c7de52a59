"""Choosing the WEP weight ``w`` for beliefs whose WEP rule is exact (Gaussians, ExPoly2D).

Costs of the fused belief ``p_w ~ p_a^w p_b^(1-w)``:

``trace`` / ``det``  trace or determinant of its covariance (covariance intersection)
``chernoff``         ``log integral p_a^w p_b^(1-w)``: minimal where KL(p_w||p_a) = KL(p_w||p_b)
``info-loss``        ``KL(p_NB || p_w)`` with ``p_NB ~ p_a p_b`` the naive-Bayes product

For exponential polynomials the covariance cost is unimodal in ``w`` but not convex (a ring and
a ring fuse to a belief smaller than either), so the search brackets the minimum on a coarse
scan and then narrows it by golden sections, instead of trusting a convex solver.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from .expoly import ExPoly2D
from .gaussian import Gaussian

COSTS = ("trace", "det", "chernoff", "info-loss")
_GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0


class WeightChoice(NamedTuple):
    fused: object  #: the fused belief p_w
    w: float  #: weight on the first belief
    cost: float  #: the cost at w


def bracket_minimise(
    f: Callable[[float], float], scan: int = 11, tol: float = 1e-3
) -> tuple[float, float]:
    """Minimise ``f`` on [0, 1]: the best of ``scan`` even points, then golden sections
    between its neighbours down to width ``tol``. Returns ``(w, f(w))``."""
    ws = np.linspace(0.0, 1.0, scan)
    fs = np.array([f(w) for w in ws])
    k = int(np.nanargmin(fs))
    best_w, best_f = ws[k], fs[k]
    lo, hi = ws[max(k - 1, 0)], ws[min(k + 1, scan - 1)]
    x1, x2 = hi - _GOLDEN * (hi - lo), lo + _GOLDEN * (hi - lo)
    f1, f2 = f(x1), f(x2)
    while hi - lo > tol:
        if f1 < f2:
            hi, x2, f2 = x2, x1, f1
            x1 = hi - _GOLDEN * (hi - lo)
            f1 = f(x1)
        else:
            lo, x1, f1 = x1, x2, f2
            x2 = lo + _GOLDEN * (hi - lo)
            f2 = f(x2)
    for w, fw in ((x1, f1), (x2, f2)):
        if fw < best_f:
            best_w, best_f = w, fw
    return float(best_w), float(best_f)


def _as_expoly(b) -> ExPoly2D:
    if isinstance(b, ExPoly2D):
        return b
    if isinstance(b, Gaussian):
        return ExPoly2D.from_gaussian(b.mean, b.cov)
    raise ValueError(f"{type(b).__name__} has no exact WEP rule for the integral costs")


def cost_function(a, b, cost: str) -> Callable[[float], float]:
    """The cost of ``a.wep(b, w)`` as a function of ``w``."""
    if cost == "trace":
        return lambda w: float(np.trace(a.wep(b, w).moments()[1]))
    if cost == "det":
        return lambda w: float(np.linalg.det(a.wep(b, w).moments()[1]))
    if cost in ("chernoff", "info-loss"):
        pa, pb = _as_expoly(a), _as_expoly(b)
        za, zb = pa.log_normaliser(), pb.log_normaliser()
        if cost == "chernoff":
            return lambda w: pa.wep(pb, w).log_normaliser() - w * za - (1.0 - w) * zb
        nb = pa.multiply(pb)
        e_pa, e_pb = nb.expect_polynomial(pa.coefficients), nb.expect_polynomial(pb.coefficients)
        entropy_nb = nb.expect_polynomial(nb.coefficients) + nb.log_normaliser()
        return lambda w: w * e_pa + (1.0 - w) * e_pb + pa.wep(pb, w).log_normaliser() - entropy_nb
    raise ValueError(f"unknown weight cost {cost!r}; choose one of {', '.join(COSTS)}")


def choose_weight(a, b, cost: str = "trace", tol: float = 1e-3) -> WeightChoice:
    """The WEP fusion of ``a`` and ``b`` with ``w`` minimising ``cost`` (see :data:`COSTS`)."""
    f = cost_function(a, b, cost)
    w, value = bracket_minimise(f, tol=tol)
    return WeightChoice(a.wep(b, w), w, value)
