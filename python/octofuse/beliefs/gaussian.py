"""Gaussian beliefs in information form; their WEP rule is covariance intersection."""

from __future__ import annotations

import numpy as np

from .base import check_weight

_FLOAT_BYTES = 8


def _as_matrix(name: str, value, dim: int) -> np.ndarray:
    m = np.asarray(value, dtype=np.float64)
    if m.shape != (dim, dim):
        raise ValueError(f"{name} must have shape ({dim}, {dim}), got {m.shape}")
    if not np.all(np.isfinite(m)):
        raise ValueError(f"{name} has non-finite entries: {m.tolist()}")
    return m


def check_covariance(name: str, cov, dim: int, allow_singular: bool = False) -> np.ndarray:
    """``cov`` as a symmetric positive-definite (or semi-definite) matrix; ``ValueError`` if not."""
    m = _as_matrix(name, cov, dim)
    if not np.allclose(m, m.T, rtol=1e-10, atol=1e-12):
        raise ValueError(f"{name} is not symmetric: {m.tolist()}")
    m = 0.5 * (m + m.T)
    low = np.linalg.eigvalsh(m).min()
    if low < 0.0 or (low == 0.0 and not allow_singular):
        kind = "semi-definite" if allow_singular else "definite"
        raise ValueError(f"{name} is not positive {kind} (smallest eigenvalue {low:.3g})")
    return m


class Gaussian:
    """``N(mean, cov)`` stored as information matrix ``Y = cov^-1`` and vector ``y = Y mean``.

    ``multiply`` adds information, ``divide`` subtracts it (channel filters), and
    ``wep(other, w)`` is covariance intersection: ``Y = w Y_a + (1-w) Y_b``, ``y`` likewise.
    """

    __slots__ = ("info_matrix", "info_vector")

    def __init__(self, info_matrix, info_vector):
        y = np.asarray(info_vector, dtype=np.float64)
        if y.ndim != 1 or not np.all(np.isfinite(y)):
            raise ValueError(f"information vector must be a finite 1-D array, got {y!r}")
        Y = check_covariance("information matrix", info_matrix, y.size)
        self.info_matrix, self.info_vector = Y, y
        Y.flags.writeable = False
        y.flags.writeable = False

    @classmethod
    def from_moments(cls, mean, cov) -> Gaussian:
        mean = np.asarray(mean, dtype=np.float64)
        if mean.ndim != 1 or not np.all(np.isfinite(mean)):
            raise ValueError(f"mean must be a finite 1-D array, got {mean!r}")
        Y = np.linalg.inv(check_covariance("covariance", cov, mean.size))
        Y = 0.5 * (Y + Y.T)
        return cls(Y, Y @ mean)

    @property
    def dim(self) -> int:
        return self.info_vector.size

    @property
    def mean(self) -> np.ndarray:
        return np.linalg.solve(self.info_matrix, self.info_vector)

    @property
    def cov(self) -> np.ndarray:
        c = np.linalg.inv(self.info_matrix)
        return 0.5 * (c + c.T)

    def moments(self) -> tuple[np.ndarray, np.ndarray]:
        return self.mean, self.cov

    def _check_other(self, other) -> None:
        if not isinstance(other, Gaussian) or other.dim != self.dim:
            raise ValueError(f"cannot combine a {self.dim}-D Gaussian with {other!r}")

    def multiply(self, other: Gaussian) -> Gaussian:
        self._check_other(other)
        return Gaussian(self.info_matrix + other.info_matrix, self.info_vector + other.info_vector)

    def divide(self, other: Gaussian) -> Gaussian:
        """Remove ``other``'s information; ``ValueError`` if the quotient is not a density."""
        self._check_other(other)
        return Gaussian(self.info_matrix - other.info_matrix, self.info_vector - other.info_vector)

    def wep(self, other: Gaussian, w: float) -> Gaussian:
        w = check_weight(w)
        self._check_other(other)
        return Gaussian(
            w * self.info_matrix + (1.0 - w) * other.info_matrix,
            w * self.info_vector + (1.0 - w) * other.info_vector,
        )

    def predict(self, F, Bu=None) -> Gaussian:
        """The density of ``F x + Bu`` (no process noise; see :meth:`diffuse`)."""
        F = _as_matrix("F", F, self.dim)
        Bu = np.zeros(self.dim) if Bu is None else np.asarray(Bu, dtype=np.float64)
        return Gaussian.from_moments(F @ self.mean + Bu, F @ self.cov @ F.T)

    def diffuse(self, Q) -> Gaussian:
        """Convolve with ``N(0, Q)``: exact for Gaussians."""
        Q = check_covariance("process noise Q", Q, self.dim, allow_singular=True)
        return Gaussian.from_moments(self.mean, self.cov + Q)

    def pdf(self, x) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        d = x - self.mean
        quad = np.einsum("...i,ij,...j->...", d, self.info_matrix, d)
        log_norm = 0.5 * (self.dim * np.log(2 * np.pi) - np.linalg.slogdet(self.info_matrix)[1])
        return np.exp(-0.5 * quad - log_norm)

    def renyi2_entropy(self) -> float:
        """``-log integral p^2 = (d/2) log(4 pi) + (1/2) log det cov`` (nats)."""
        return float(
            0.5 * self.dim * np.log(4 * np.pi) - 0.5 * np.linalg.slogdet(self.info_matrix)[1]
        )

    @property
    def message_bytes(self) -> int:
        """Size of a message: mean and the upper triangle of the covariance as float64."""
        d = self.dim
        return _FLOAT_BYTES * (d + d * (d + 1) // 2)

    def __repr__(self) -> str:
        return f"Gaussian(mean={self.mean.round(4).tolist()}, cov={self.cov.round(4).tolist()})"
