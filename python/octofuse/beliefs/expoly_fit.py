"""Coefficients of an exponential polynomial from its moments, by guarded Newton steps.

For ``p ~ exp(-sum a_k phi_k)`` (``phi_k`` the monomials ``x^i y^j``, ``0 < i + j <= d``) the
moments ``M = E[phi]`` fall as ``a`` grows: ``dM/da = -G`` with ``G = Cov(phi)`` the Fisher
information. Reaching target moments ``M*`` is Newton's method on the convex function
``f(a) = log Z(a) + a . M*`` (gradient ``M* - M(a) = dM``, Hessian ``G``):

    a  <-  a - G^-1 dM

(the sign matters: ``a + G^-1 dM`` moves away from the target). Full steps easily leave the
elliptic polynomials (the family's boundary is near for ring-like targets), so steps are damped
until the polynomial is elliptic and ``f`` decreases; strongly non-Gaussian targets may still
stall, which ``MomentFit.converged`` reports.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from . import expoly_grid as grid
from .expoly import ExPoly2D

_SEED_QUARTIC = 1e-3


class MomentFit(NamedTuple):
    belief: ExPoly2D
    iterations: int
    residual: float  #: largest |M* - M| relative to the moment's scale
    converged: bool


def monomials(degree: int) -> list[tuple[int, int]]:
    """``(i, j)`` with ``0 < i + j <= degree``, by total degree then by power of ``y``."""
    return [(k - j, j) for k in range(1, degree + 1) for j in range(k + 1)]


def _with(coeffs: np.ndarray, terms, degree: int) -> ExPoly2D:
    c = np.zeros((degree + 1, degree + 1))
    for (i, j), v in zip(terms, coeffs):
        c[i, j] = v
    return ExPoly2D(c)


def _objective(belief: ExPoly2D, coeffs: np.ndarray, target: np.ndarray) -> float:
    return belief.log_normaliser() + float(coeffs @ target)


def _moments_under_affine(
    target: np.ndarray, terms, degree: int, A: np.ndarray, b: np.ndarray
) -> np.ndarray:
    """Raw moments of ``u = A x + b`` from the raw moments ``target`` of ``x``."""
    lookup = dict(zip(terms, target))
    lookup[(0, 0)] = 1.0
    out = []
    for i, j in terms:
        unit = np.zeros((degree + 1, degree + 1))
        unit[i, j] = 1.0
        expanded = grid.compose_affine(unit, A, b)
        out.append(sum(v * lookup[(k, l)] for (k, l), v in np.ndenumerate(expanded) if v != 0.0))
    return np.array(out)


def fit_moments(target, degree: int = 4, max_iter: int = 40, tol: float = 1e-6) -> MomentFit:
    """An ExPoly2D whose raw moments ``E[x^i y^j]`` are ``target`` (ordered as :func:`monomials`).

    Works in whitened coordinates ``u = L^-1 (x - mean)`` (``L L^T`` the target covariance),
    starting from the standard Gaussian plus a small quartic; stops when every whitened moment is
    within ``tol``, or after ``max_iter`` steps (``converged`` is then False).
    """
    terms = monomials(degree)
    target = np.asarray(target, dtype=np.float64)
    if target.shape != (len(terms),) or not np.all(np.isfinite(target)):
        raise ValueError(f"target must hold {len(terms)} finite moments, got shape {target.shape}")
    mean = target[:2]
    cov = np.array([[target[2], target[3]], [target[3], target[4]]]) - np.outer(mean, mean)
    L = np.linalg.cholesky(cov)
    L_inv = np.linalg.inv(L)
    target_u = _moments_under_affine(target, terms, degree, L_inv, -L_inv @ mean)
    coeffs = np.zeros(len(terms))
    for k, (i, j) in enumerate(terms):
        coeffs[k] = 0.5 if (i, j) in ((2, 0), (0, 2)) else 0.0
        if degree > 2 and i + j == 4:  # eps (u^T u)^2 seeds a positive top-degree form
            coeffs[k] = _SEED_QUARTIC * (2.0 if (i, j) == (2, 2) else 1.0 if 4 in (i, j) else 0.0)
    coeffs, belief, residual, used = _newton(coeffs, target_u, terms, degree, max_iter, tol)
    c_x = grid.compose_affine(belief.coefficients, L_inv, -L_inv @ mean)
    c_x[0, 0] = 0.0
    return MomentFit(ExPoly2D(c_x), used, residual, residual < tol)


def _newton(coeffs, goal, terms, degree, max_iter, tol):
    """Guarded Newton steps ``a <- a - (G + mu I)^-1 dM`` towards moments ``goal``.

    ``mu`` (Levenberg-Marquardt damping) grows tenfold whenever a step leaves the elliptic
    polynomials or fails to decrease the convex objective, and shrinks after a success.
    """
    belief = _with(coeffs, terms, degree)
    f = _objective(belief, coeffs, goal)
    residual, it, mu = np.inf, 0, None
    best = (np.inf, coeffs, belief)
    for it in range(1, max_iter + 1):  # noqa: B007 (the count is returned)
        g = belief.grid()
        X, Y = g.mesh
        phi = np.stack([(X**i * Y**j).ravel() for i, j in terms])
        w = g.weights.ravel()
        moments = phi @ w
        delta_m = goal - moments
        residual = float(np.max(np.abs(delta_m)))
        if residual < best[0]:
            best = (residual, coeffs, belief)
        if residual < tol:
            break
        centred = phi - moments[:, None]
        G = (centred * w) @ centred.T
        scale = np.trace(G) / len(terms)
        mu = 1e-6 * scale if mu is None else mu
        while mu < 1e8 * scale:
            trial = coeffs - np.linalg.solve(G + mu * np.eye(len(terms)), delta_m)
            try:
                candidate = _with(trial, terms, degree)
                f_new = _objective(candidate, trial, goal)
            except ValueError:  # left the elliptic polynomials
                f_new = np.inf
            if f_new < f:
                mu *= 0.1
                break
            mu *= 10.0
        else:
            break
        coeffs, belief, f = trial, candidate, f_new
    residual, coeffs, belief = best  # a grid-integration slip can make a late step worse
    return coeffs, belief, residual, it
