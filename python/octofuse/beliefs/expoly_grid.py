"""Bivariate polynomials as coefficient arrays, and grid integration of ``exp(-P)``.

A polynomial of degree ``d`` is a ``(d+1, d+1)`` array ``c`` with ``P(x, y) = sum c[i, j] x^i y^j``
and ``c[i, j] = 0`` for ``i + j > d``. Densities ``exp(-P)`` have no closed-form moments beyond
degree 2, so they are integrated on a grid over the support: the region where
``P - min P < LOG_CUTOFF`` (outside it the density is below ``exp(-LOG_CUTOFF)`` of its peak).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np
from numpy.polynomial import polynomial as npoly
from scipy.signal import convolve2d

LOG_CUTOFF = 46.0  # exp(-46) ~ 1e-20 of the peak
GRID_POINTS = 161
_COARSE_POINTS = 96
_ANGLES = np.linspace(0.0, 2.0 * np.pi, 1440, endpoint=False)


def evaluate(c: np.ndarray, x, y) -> np.ndarray:
    """``P(x, y)`` for arrays ``x`` and ``y`` of one shape."""
    powers = np.arange(c.shape[0])
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    return np.einsum("...i,ij,...j->...", x[..., None] ** powers, c, y[..., None] ** powers)


def evaluate_mesh(c: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """``P`` on the mesh ``xs x ys`` (indexing "ij"), as Vandermonde products."""
    n = c.shape[0]
    return np.vander(xs, n, increasing=True) @ c @ np.vander(ys, n, increasing=True).T


def total_degree_part(c: np.ndarray, k: int) -> np.ndarray:
    """Coefficients ``c[k-j, j]`` (j = 0..k) of the homogeneous part of degree ``k``."""
    return np.array([c[k - j, j] for j in range(k + 1)])


def top_degree(c: np.ndarray) -> int:
    """The highest total degree with a non-zero coefficient (-1 for the zero polynomial)."""
    n = c.shape[0] - 1
    for k in range(n, -1, -1):
        if np.any(total_degree_part(c, k) != 0.0):
            return k
    return -1


def top_form_min(c: np.ndarray, k: int) -> tuple[float, float]:
    """Minimum of the degree-``k`` form on the unit circle, and the sampling bound on its error.

    The form is sampled at 1440 angles; between samples it can dip by at most
    ``k^2 * sum|c| * (pi/1440)^2 / 2``, which is returned as the second value.
    """
    part = total_degree_part(c, k)
    values = part @ _circle_monomials(k)
    slack = 0.5 * k * k * np.abs(part).sum() * (np.pi / _ANGLES.size) ** 2
    return float(values.min()), float(slack)


@lru_cache(maxsize=8)
def _circle_monomials(k: int) -> np.ndarray:
    """``cos^(k-j) sin^j`` at the sample angles, one row per ``j``."""
    cos, sin = np.cos(_ANGLES), np.sin(_ANGLES)
    return np.stack([cos ** (k - j) * sin**j for j in range(k + 1)])


def multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Coefficients of the product of two polynomials."""
    return convolve2d(a, b)


def compose_affine(c: np.ndarray, A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Coefficients of ``x -> P(A x + b)`` (same degree, same array shape)."""
    n = c.shape[0]
    # (A x + b)_0 and (A x + b)_1 as degree-1 polynomials
    u = np.array([[b[0], A[0, 1]], [A[0, 0], 0.0]])
    v = np.array([[b[1], A[1, 1]], [A[1, 0], 0.0]])
    u_pow, v_pow = [np.ones((1, 1))], [np.ones((1, 1))]
    for _ in range(n - 1):
        u_pow.append(multiply(u_pow[-1], u))
        v_pow.append(multiply(v_pow[-1], v))
    out = np.zeros((2 * n, 2 * n))
    for i in range(n):
        for j in range(n - i):
            if c[i, j] != 0.0:
                term = c[i, j] * multiply(u_pow[i], v_pow[j])
                out[: term.shape[0], : term.shape[1]] += term
    return out[:n, :n].copy()


def derivatives(c: np.ndarray) -> tuple[np.ndarray, ...]:
    """Coefficients of ``P_x, P_y, P_xx, P_xy, P_yy`` (padded to the shape of ``c``)."""
    n = c.shape[0]
    cx, cy = npoly.polyder(c, axis=0), npoly.polyder(c, axis=1)
    parts = (
        cx,
        cy,
        npoly.polyder(cx, axis=0),
        npoly.polyder(cx, axis=1),
        npoly.polyder(cy, axis=1),
    )
    out = []
    for p in parts:
        padded = np.zeros((n, n))
        padded[: p.shape[0], : p.shape[1]] = p
        out.append(padded)
    return tuple(out)


def gradient_hessian(c: np.ndarray, x, y, derivs=None):
    """Gradient ``(gx, gy)`` and Hessian ``(hxx, hxy, hyy)`` of ``P`` at points."""
    cx, cy, cxx, cxy, cyy = derivatives(c) if derivs is None else derivs
    return (evaluate(cx, x, y), evaluate(cy, x, y)), (
        evaluate(cxx, x, y),
        evaluate(cxy, x, y),
        evaluate(cyy, x, y),
    )


def support_radius(c: np.ndarray, k: int, form_min: float) -> float:
    """A radius ``R`` around the origin outside which ``P > P(0) + LOG_CUTOFF``.

    On ``|x| = r``, ``P >= m r^k - sum_{0<l<k} n_l r^l + P(0)`` with ``m`` the minimum of the top
    form on the unit circle and ``n_l`` the sum of absolute coefficients of degree ``l``.
    """
    bound = np.zeros(k + 1)
    bound[k] = form_min
    for deg in range(1, k):
        bound[deg] = -np.abs(total_degree_part(c, deg)).sum()
    bound[0] = -LOG_CUTOFF
    roots = np.roots(bound[::-1])
    real = roots[np.abs(roots.imag) <= 1e-9 * (1.0 + np.abs(roots))].real
    return float(max(real.max(initial=0.0), 1e-9))


def _polish_minima(c: np.ndarray, x: np.ndarray, y: np.ndarray, steps: int = 12):
    """Damped Newton descent from starting points; returns points, values and Hessians."""
    value = evaluate(c, x, y)
    derivs = derivatives(c)
    for _ in range(steps):
        (gx, gy), (hxx, hxy, hyy) = gradient_hessian(c, x, y, derivs)
        det = hxx * hyy - hxy * hxy
        newton_ok = (hxx > 0) & (det > 0)
        safe_det = np.where(newton_ok, det, 1.0)
        dx = np.where(newton_ok, -(hyy * gx - hxy * gy) / safe_det, -1e-3 * gx)
        dy = np.where(newton_ok, -(hxx * gy - hxy * gx) / safe_det, -1e-3 * gy)
        new = evaluate(c, x + dx, y + dy)
        better = new < value
        x, y = np.where(better, x + dx, x), np.where(better, y + dy, y)
        value = np.where(better, new, value)
    return x, y, value, gradient_hessian(c, x, y, derivs)[1]


def locate_support(c: np.ndarray, k: int, form_min: float, rounds: int = 5):
    """Box ``(x0, x1, y0, y1)`` holding the region where ``P - min P < LOG_CUTOFF``.

    Starts from the guaranteed disk of :func:`support_radius`, polishes the coarse grid's lowest
    local minima with Newton steps (so a mode narrower than a grid cell is not missed), then
    shrinks the box to the thresholded region until it stops changing.
    """
    r = support_radius(c, k, form_min)
    box = np.array([-r, r, -r, r])
    for round_index in range(rounds):
        xs = np.linspace(box[0], box[1], _COARSE_POINTS)
        ys = np.linspace(box[2], box[3], _COARSE_POINTS)
        V = evaluate_mesh(c, xs, ys)
        v_min = V.min()
        keep_x, keep_y = [], []
        if round_index == 0:
            inner = V[1:-1, 1:-1]
            is_min = np.ones_like(inner, dtype=bool)
            for di in (-1, 0, 1):
                for dj in (-1, 0, 1):
                    if di or dj:
                        is_min &= (
                            inner <= V[1 + di : V.shape[0] - 1 + di, 1 + dj : V.shape[1] - 1 + dj]
                        )
            idx = np.argwhere(is_min)
            idx = idx[np.argsort(inner[is_min])][:6] + 1
            if idx.size:
                px, py, pv, (hxx, hxy, hyy) = _polish_minima(c, xs[idx[:, 0]], ys[idx[:, 1]])
                v_min = min(v_min, float(pv.min()))
                for x0, y0, val, a, b, d in zip(px, py, pv, hxx, hxy, hyy):
                    if val - v_min < LOG_CUTOFF and a > 0 and a * d - b * b > 0:
                        # half-widths of the quadratic model's cut-off ellipse; a flat direction
                        # (a ring's tangent) is covered by the thresholded cells instead
                        det = a * d - b * b
                        sx = min(np.sqrt(2 * LOG_CUTOFF * d / det), 2 * (xs[1] - xs[0]))
                        sy = min(np.sqrt(2 * LOG_CUTOFF * a / det), 2 * (ys[1] - ys[0]))
                        keep_x += [x0 - sx, x0 + sx]
                        keep_y += [y0 - sy, y0 + sy]
        inside = V - v_min < LOG_CUTOFF
        # dilate by one cell so that the threshold's edge lies inside the box
        grown = inside.copy()
        grown[1:, :] |= inside[:-1, :]
        grown[:-1, :] |= inside[1:, :]
        grown[:, 1:] |= inside[:, :-1]
        grown[:, :-1] |= inside[:, 1:]
        ii, jj = np.nonzero(grown)
        hx, hy = xs[1] - xs[0], ys[1] - ys[0]
        cand_x = np.concatenate([xs[ii] - hx, xs[ii] + hx, keep_x])
        cand_y = np.concatenate([ys[jj] - hy, ys[jj] + hy, keep_y])
        new = np.array([cand_x.min(), cand_x.max(), cand_y.min(), cand_y.max()])
        new[[0, 2]] = np.maximum(new[[0, 2]], box[[0, 2]])
        new[[1, 3]] = np.minimum(new[[1, 3]], box[[1, 3]])
        shrink = (new[1] - new[0]) * (new[3] - new[2]) / ((box[1] - box[0]) * (box[3] - box[2]))
        box = new
        if shrink > 0.7:
            break
    return tuple(float(v) for v in box)


@dataclass(frozen=True)
class GridDensity:
    """``p = exp(-P) / Z`` sampled on a regular grid covering its support."""

    x: np.ndarray  #: (n,) grid abscissae
    y: np.ndarray  #: (n,) grid ordinates
    weights: np.ndarray  #: (n, n) probability of each cell, summing to 1 (indexing "ij")
    p_values: np.ndarray  #: (n, n) the polynomial P on the grid
    log_norm: float  #: log Z = log of the integral of exp(-P)
    cell_area: float

    @cached_property
    def mesh(self) -> tuple[np.ndarray, np.ndarray]:
        return np.meshgrid(self.x, self.y, indexing="ij")

    def expect(self, values: np.ndarray) -> float:
        """Expectation of a function given by its values on the grid."""
        return float(np.sum(self.weights * values))

    def moments(self) -> tuple[np.ndarray, np.ndarray]:
        X, Y = self.mesh
        mean = np.array([self.expect(X), self.expect(Y)])
        dx, dy = X - mean[0], Y - mean[1]
        sxy = self.expect(dx * dy)
        cov = np.array([[self.expect(dx * dx), sxy], [sxy, self.expect(dy * dy)]])
        return mean, cov


def grid_density(
    c: np.ndarray, k: int, form_min: float, n: int = GRID_POINTS, box=None
) -> GridDensity:
    """Sample ``exp(-P)`` on an ``n x n`` grid over its located support (or over ``box``)."""
    x0, x1, y0, y1 = locate_support(c, k, form_min) if box is None else box
    x, y = np.linspace(x0, x1, n), np.linspace(y0, y1, n)
    V = evaluate_mesh(c, x, y)
    v_min = V.min()
    e = np.exp(-(V - v_min))
    cell = (x[1] - x[0]) * (y[1] - y[0])
    total = e.sum()
    return GridDensity(x, y, e / total, V, float(np.log(total * cell) - v_min), float(cell))
