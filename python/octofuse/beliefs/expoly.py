"""Exponential-of-polynomial beliefs on the plane: ``p(x) = exp(-P(x)) / Z``.

``P`` is an elliptic polynomial (it grows to infinity in every direction) of degree 2 or 4. Its
coefficients are natural parameters, so the product of beliefs adds them, the quotient (channel
filter) subtracts them, and the WEP rule ``p_a^w p_b^(1-w)`` (covariance intersection extended
beyond Gaussians) is their convex combination, all exact. Degree 2 is exactly the Gaussian
family. Moments beyond degree 2 come from grid integration (:mod:`.expoly_grid`); diffusion by
process noise is the approximation of :meth:`ExPoly2D.diffuse`.
"""

from __future__ import annotations

import math
from math import comb

import numpy as np

from . import expoly_grid as grid
from .base import check_weight
from .gaussian import Gaussian, _as_matrix, check_covariance

DEGREES = (2, 4)
_FLOAT_BYTES = 8
_CANCELLATION = 1e-12  # a top-degree part this small relative to the rest is rounding noise


def _pad(c: np.ndarray, n: int) -> np.ndarray:
    out = np.zeros((n, n))
    out[: c.shape[0], : c.shape[1]] = c
    return out


class ExPoly2D:
    """A density ``exp(-P(x, y)) / Z`` with ``P = sum c[i, j] x^i y^j`` of degree 2 or 4.

    ``coefficients`` is a ``(d+1, d+1)`` array (``d`` in 2, 4) with zeros where ``i + j > d``.
    ``ValueError`` if a coefficient is not finite or ``P`` is not elliptic (``exp(-P)`` would
    not normalise). Ellipticity is checked on the top-degree form, which must be positive on the
    unit circle; a few normalisable polynomials with a semi-definite top form, such as
    ``x^4 + y^2``, are rejected.
    """

    __slots__ = ("_c", "_top", "_form_min", "_grid")

    def __init__(self, coefficients):
        c = np.array(coefficients, dtype=np.float64)
        if c.ndim != 2 or c.shape[0] != c.shape[1] or c.shape[0] - 1 not in DEGREES:
            raise ValueError(f"coefficients must be a 3x3 or 5x5 array, got shape {c.shape}")
        bad = np.argwhere(~np.isfinite(c))
        if bad.size:
            i, j = bad[0]
            raise ValueError(f"coefficient of x^{i} y^{j} is {c[i, j]}; all must be finite")
        n = c.shape[0]
        above = np.add.outer(np.arange(n), np.arange(n)) > n - 1
        if np.any(c[above] != 0.0):
            raise ValueError(f"coefficients of total degree above {n - 1} must be zero")
        top = grid.top_degree(c)
        while top > 0:
            scale = max(np.abs(c[1:, :]).max(), np.abs(c[0, 1:]).max())  # constant term excluded
            if np.abs(grid.total_degree_part(c, top)).max() > _CANCELLATION * scale:
                break
            for j in range(top + 1):
                c[top - j, j] = 0.0
            top = grid.top_degree(c)
        form_min, slack = grid.top_form_min(c, top) if top > 0 else (0.0, 0.0)
        if top <= 0 or top % 2 or form_min <= slack:
            raise ValueError(
                f"polynomial is not elliptic (top degree {top}, minimum of its top-degree form on "
                f"the unit circle {form_min:.3g}): exp(-P) does not normalise"
            )
        c.flags.writeable = False
        self._c, self._top, self._form_min, self._grid = c, top, form_min, None

    # -- construction -------------------------------------------------------------------------
    @classmethod
    def from_gaussian(cls, mean, cov) -> ExPoly2D:
        """The degree-2 polynomial of ``N(mean, cov)``, normaliser included (``Z = 1``)."""
        g = Gaussian.from_moments(mean, cov)
        if g.dim != 2:
            raise ValueError(f"ExPoly2D is 2-D; got a {g.dim}-D Gaussian")
        return cls._from_information(g.info_matrix, g.info_vector)

    @classmethod
    def _from_information(cls, Y: np.ndarray, y: np.ndarray) -> ExPoly2D:
        mean = np.linalg.solve(Y, y)
        c = np.zeros((3, 3))
        c[2, 0], c[0, 2], c[1, 1] = 0.5 * Y[0, 0], 0.5 * Y[1, 1], Y[0, 1]
        c[1, 0], c[0, 1] = -y[0], -y[1]
        c[0, 0] = 0.5 * mean @ y + np.log(2 * np.pi) - 0.5 * np.linalg.slogdet(Y)[1]
        return cls(c)

    @classmethod
    def range_likelihood(cls, sensor_xy, measured_range: float, a: float) -> ExPoly2D:
        """Range-only likelihood ``exp(-(a/z^2) (r^2 - z^2)^2)``, ``r = |x - sensor|``, ``z`` measured.

        Near the ring ``r = z`` this is ``exp(-4a (r - z)^2)``: a radial Gaussian of variance
        ``1/(8a)``. It is normalisable on its own (a ring).
        """
        s = np.asarray(sensor_xy, dtype=np.float64)
        z, a = float(measured_range), float(a)
        if s.shape != (2,) or not np.all(np.isfinite(s)):
            raise ValueError(f"sensor position must be 2 finite numbers, got {sensor_xy!r}")
        if not (np.isfinite(z) and z > 0.0):
            raise ValueError(f"measured range must be positive and finite, got {measured_range}")
        if not (np.isfinite(a) and a > 0.0):
            raise ValueError(f"sharpness a must be positive and finite, got {a}")
        k = a / (z * z) if z * z > 0.0 else math.inf
        if not (math.isfinite(k) and math.isfinite(a * z * z) and k > 0.0):
            raise ValueError(
                f"measured_range={measured_range!r} with a={a!r}: the "
                "coefficients a / range^2 and a range^2 must be finite and positive"
            )
        c = np.zeros((5, 5))  # k (u^2 + v^2)^2 - 2a (u^2 + v^2) + a z^2 around the sensor
        c[4, 0], c[0, 4], c[2, 2] = k, k, 2 * k
        c[2, 0], c[0, 2], c[0, 0] = -2 * a, -2 * a, a * z * z
        return cls(grid.compose_affine(c, np.eye(2), -s))

    # -- parameters ---------------------------------------------------------------------------
    @property
    def dim(self) -> int:
        return 2

    @property
    def coefficients(self) -> np.ndarray:
        """Read-only ``(d+1, d+1)`` coefficient array."""
        return self._c

    @property
    def degree(self) -> int:
        """Degree of the stored array (2 or 4)."""
        return self._c.shape[0] - 1

    @property
    def is_gaussian(self) -> bool:
        return self._top == 2

    @property
    def message_bytes(self) -> int:
        """Size of a message: the non-constant coefficients as float64 (the receiver normalises)."""
        d = self.degree
        return _FLOAT_BYTES * ((d + 1) * (d + 2) // 2 - 1)

    def __repr__(self) -> str:
        terms = [f"{v:+.4g} x^{i} y^{j}" for (i, j), v in np.ndenumerate(self._c) if v != 0.0]
        return f"ExPoly2D(P = {' '.join(terms)})"

    # -- exact algebra on coefficients --------------------------------------------------------
    def _combine(self, other, wa: float, wb: float) -> ExPoly2D:
        if not isinstance(other, ExPoly2D):
            raise ValueError(f"cannot combine an ExPoly2D with {type(other).__name__}")
        n = max(self._c.shape[0], other._c.shape[0])
        return ExPoly2D(wa * _pad(self._c, n) + wb * _pad(other._c, n))

    def multiply(self, other: ExPoly2D) -> ExPoly2D:
        """Naive-Bayes product ``p q``: coefficients add."""
        return self._combine(other, 1.0, 1.0)

    def divide(self, other: ExPoly2D) -> ExPoly2D:
        """Quotient ``p / q`` (channel filter); ``ValueError`` if it does not normalise."""
        return self._combine(other, 1.0, -1.0)

    def wep(self, other: ExPoly2D, w: float) -> ExPoly2D:
        """``p^w q^(1-w)``, normalised: covariance intersection on coefficients."""
        w = check_weight(w)
        return self._combine(other, w, 1.0 - w)

    def predict(self, F, Bu=None) -> ExPoly2D:
        """The density of ``x' = F x + Bu`` (no noise): ``P'(x') = P(F^-1 (x' - Bu)) + log|det F|``."""
        F = _as_matrix("F", F, 2)
        Bu = np.zeros(2) if Bu is None else np.asarray(Bu, dtype=np.float64)
        if Bu.shape != (2,) or not np.all(np.isfinite(Bu)):
            raise ValueError(f"Bu must be 2 finite numbers, got {Bu!r}")
        det = np.linalg.det(F)
        if not abs(det) > 1e-12 * max(np.abs(F).max(), 1e-300) ** 2:
            raise ValueError(f"F is singular (det {det:.3g}); the prediction has no density")
        A = np.linalg.inv(F)
        c = grid.compose_affine(self._c, A, -A @ Bu)
        c[0, 0] += np.log(abs(det))
        return ExPoly2D(c)

    def diffuse(self, Q, eta: float | None = None, match_moments: bool = True) -> ExPoly2D:
        """Approximate convolution with ``N(0, Q)`` (eq. 3 of Tonkes and Blair); exact at degree 2.

        Whitening ``x = mean + S^(1/2) V u`` (``V`` diagonalises ``S^(-1/2) Q S^(-1/2) = V L V^T``,
        ``S`` the covariance) splits ``P(u) = |u|^2 / 2 + R(u)``. The Gaussian part diffuses
        exactly to ``u^T (I + L)^-1 u / 2``; the residual is assumed to spread like it and to fade:
        ``R((I + L)^(-1/2) u) / (1 + max L)^eta`` with ``eta = 2 + degree / 2``. Mean and
        covariance are then only approximately ``mean`` and ``S + Q`` (the covariance grows too
        little); ``match_moments`` maps the result affinely, ``x -> m + A (x - m')`` with ``A``
        symmetric, onto the exact mean ``m`` and covariance ``S + Q`` of the convolution.
        """
        Q = check_covariance("process noise Q", Q, 2, allow_singular=True)
        if not Q.any():
            return self
        mean, cov = self.moments()
        if self.is_gaussian:
            return ExPoly2D.from_gaussian(mean, cov + Q)
        eta = 2.0 + self._top / 2.0 if eta is None else float(eta)
        s_half, s_ihalf = _sqrtm(cov), _sqrtm(cov, -0.5)
        lam, V = np.linalg.eigh(s_ihalf @ Q @ s_ihalf)
        lam = np.clip(lam, 0.0, None)
        M = s_half @ V
        residual = grid.compose_affine(self._c, M, mean)
        residual[2, 0] -= 0.5
        residual[0, 2] -= 0.5
        out = grid.compose_affine(residual, np.diag(1.0 / np.sqrt(1.0 + lam)), np.zeros(2))
        out *= (1.0 + lam.max()) ** (-eta)
        out[2, 0] += 0.5 / (1.0 + lam[0])
        out[0, 2] += 0.5 / (1.0 + lam[1])
        M_inv = np.linalg.inv(M)
        diffused = ExPoly2D(grid.compose_affine(out, M_inv, -M_inv @ mean))
        if not match_moments:
            return diffused
        got_mean, got_cov = diffused.moments()
        A = _symmetric_map(got_cov, cov + Q)
        return diffused.predict(A, mean - A @ got_mean)

    # -- integrals ----------------------------------------------------------------------------
    def _gaussian_form(self) -> tuple[np.ndarray, np.ndarray]:
        c = self._c
        Y = np.array([[2 * c[2, 0], c[1, 1]], [c[1, 1], 2 * c[0, 2]]])
        return Y, -np.array([c[1, 0], c[0, 1]])

    def grid(self) -> grid.GridDensity:
        """The density on a grid over its support (computed once)."""
        if self._grid is None:
            self._grid = grid.grid_density(self._c, self._top, self._form_min)
        return self._grid

    def log_normaliser(self) -> float:
        """``log Z``, ``Z`` the integral of ``exp(-P)``."""
        if self.is_gaussian:
            Y, y = self._gaussian_form()
            mean = np.linalg.solve(Y, y)
            p_min = grid.evaluate(self._c, mean[0], mean[1])
            return float(-p_min + np.log(2 * np.pi) - 0.5 * np.linalg.slogdet(Y)[1])
        return self.grid().log_norm

    def moments(self) -> tuple[np.ndarray, np.ndarray]:
        """Mean ``(2,)`` and covariance ``(2, 2)``; closed form at degree 2, else on the grid."""
        if self.is_gaussian:
            Y, y = self._gaussian_form()
            cov = np.linalg.inv(Y)
            return cov @ y, 0.5 * (cov + cov.T)
        return self.grid().moments()

    def raw_moments(self, monomials) -> np.ndarray:
        """``E[x^i y^j]`` for each ``(i, j)`` in ``monomials``, on the grid."""
        g = self.grid()
        X, Y = g.mesh
        return np.array([g.expect(X**i * Y**j) for i, j in monomials])

    def expect_polynomial(self, coefficients) -> float:
        """``E[Q(x)]`` for a polynomial given by its coefficient array."""
        g = self.grid()
        return g.expect(grid.evaluate(np.asarray(coefficients, dtype=np.float64), *g.mesh))

    def renyi2_entropy(self) -> float:
        """Renyi entropy of order 2, ``-log integral p^2`` (nats)."""
        if self.is_gaussian:
            return self.to_gaussian().renyi2_entropy()
        g = self.grid()
        return float(-np.log(np.sum(g.weights**2) / g.cell_area))

    def to_gaussian(self) -> Gaussian:
        """The Gaussian with the same mean and covariance (exact at degree 2)."""
        return Gaussian.from_moments(*self.moments())

    def pdf(self, x) -> np.ndarray:
        """Normalised density at points ``x`` of shape ``(..., 2)``."""
        x = np.asarray(x, dtype=np.float64)
        if x.shape[-1:] != (2,):
            raise ValueError(f"points must have shape (..., 2), got {x.shape}")
        return np.exp(-grid.evaluate(self._c, x[..., 0], x[..., 1]) - self.log_normaliser())


def _sqrtm(S: np.ndarray, power: float = 0.5) -> np.ndarray:
    val, vec = np.linalg.eigh(S)
    return vec @ np.diag(val**power) @ vec.T


def _symmetric_map(source_cov: np.ndarray, target_cov: np.ndarray) -> np.ndarray:
    """The symmetric positive-definite ``A`` with ``A source_cov A = target_cov``."""
    r, r_inv = _sqrtm(source_cov), _sqrtm(source_cov, -0.5)
    return r_inv @ _sqrtm(r @ target_cov @ r) @ r_inv


def predict_coefficients_1d(a, F: float, Bu: float) -> np.ndarray:
    """Univariate prediction ``P(F^-1 (x - Bu))``: ``a'_i = sum_{j>=i} a_j C(j,i) F^-j (-Bu)^(j-i)``."""
    a = np.asarray(a, dtype=np.float64)
    n = a.size
    return np.array(
        [
            sum(a[j] * comb(j, i) * F ** (-j) * (-Bu) ** (j - i) for j in range(i, n))
            for i in range(n)
        ]
    )
