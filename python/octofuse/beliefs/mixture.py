"""Gaussian-mixture beliefs: evaluation, sampling, moments and the closed-form products.

A mixture ``sum_m w_m N(x; mu_m, Sigma_m)`` has weights ``(M,)``, means ``(M, d)`` and covariances
``(M, d, d)``. Densities are evaluated in the log domain throughout, so mixtures whose supports are
far apart (densities that underflow to 0.0 in floating point) still fuse to finite results.
"""

from __future__ import annotations

import numpy as np
from scipy.special import logsumexp

from .base import check_weight

LOG_2PI = float(np.log(2.0 * np.pi))


def _as_rng(seed) -> np.random.Generator:
    return seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)


def gaussian_logpdf(x: np.ndarray, means: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """``log N(x_n; mu_m, Sigma_m)`` for points ``(N, d)`` and components ``(M, d)``: shape ``(M, N)``."""
    chol = np.linalg.cholesky(covariances)
    return _logpdf_chol(np.atleast_2d(x), means, np.linalg.inv(chol), _log_det(chol))


def logsumexp0(a: np.ndarray) -> np.ndarray:
    """``log sum exp`` over the first axis (scipy's is several times slower on small arrays)."""
    top = np.max(a, axis=0)
    safe = np.where(np.isfinite(top), top, 0.0)
    with np.errstate(divide="ignore"):
        return np.log(np.sum(np.exp(a - safe), axis=0)) + safe


def log_det_spd(cov: np.ndarray) -> np.ndarray:
    """``log det`` of stacked symmetric positive definite matrices (closed form in 2-D)."""
    if cov.shape[-1] == 2:
        return np.log(cov[..., 0, 0] * cov[..., 1, 1] - cov[..., 0, 1] * cov[..., 1, 0])
    return np.linalg.slogdet(cov)[1]


def _log_det(chol: np.ndarray) -> np.ndarray:
    return 2.0 * np.log(np.diagonal(chol, axis1=-2, axis2=-1)).sum(-1)


def _logpdf_chol(x: np.ndarray, means: np.ndarray, inv_chol: np.ndarray, log_det: np.ndarray) -> np.ndarray:
    """Component log densities ``(M, N)`` from the inverse Cholesky factors ``L^-1`` ``(M, d, d)``."""
    d = x.shape[1]
    z = np.matmul(x[None, :, :], np.swapaxes(inv_chol, 1, 2))  # L^-1 x, shape (M, N, d)
    z -= np.einsum("mij,mj->mi", inv_chol, means)[:, None, :]
    z *= z
    return -0.5 * (z.sum(-1) + log_det[:, None] + d * LOG_2PI)


class GaussianMixture:
    """A finite Gaussian mixture over R^d (a :class:`~octofuse.beliefs.base.Belief`).

    Weights must be finite and non-negative with a positive sum (they are normalised); every
    covariance must be symmetric positive definite. A ``ValueError`` names the offending component.
    """

    __slots__ = ("weights", "means", "covariances", "_chol", "_inv_chol", "_log_det")

    def __init__(self, weights, means, covariances) -> None:
        w = np.asarray(weights, dtype=float).reshape(-1)
        mu = np.asarray(means, dtype=float)
        cov = np.asarray(covariances, dtype=float)
        m = w.shape[0]
        if m == 0:
            raise ValueError("a Gaussian mixture needs at least one component")
        if mu.ndim != 2 or mu.shape[0] != m:
            raise ValueError(f"means must have shape (M, d) with M = {m}; got {mu.shape}")
        d = mu.shape[1]
        if cov.shape != (m, d, d):
            raise ValueError(f"covariances must have shape {(m, d, d)}; got {cov.shape}")
        if not (np.all(np.isfinite(w)) and np.all(np.isfinite(mu)) and np.all(np.isfinite(cov))):
            raise ValueError("mixture weights, means and covariances must be finite")
        if np.any(w < 0) or w.sum() <= 0:
            raise ValueError(f"mixture weights must be non-negative with a positive sum; got {w}")
        if not np.allclose(cov, np.swapaxes(cov, 1, 2), rtol=1e-8, atol=1e-12):
            raise ValueError("mixture covariances must be symmetric")
        cov = 0.5 * (cov + np.swapaxes(cov, 1, 2))
        try:
            chol = np.linalg.cholesky(cov)
        except np.linalg.LinAlgError:
            bad = [k for k in range(m) if np.any(np.linalg.eigvalsh(cov[k]) <= 0)] or [0]
            raise ValueError(
                f"covariance of component {bad[0]} is not positive definite (singular?): {cov[bad[0]].tolist()}"
            ) from None
        diag = np.diagonal(chol, axis1=1, axis2=2)
        if np.any(diag <= 1e-150):
            raise ValueError("a mixture covariance is numerically singular")
        self.weights = w / w.sum()
        self.means = mu
        self.covariances = cov
        self._chol = chol
        self._inv_chol = np.linalg.inv(chol)
        self._log_det = _log_det(chol)

    @classmethod
    def gaussian(cls, mean, covariance) -> GaussianMixture:
        """A single Gaussian as a one-component mixture."""
        mean = np.asarray(mean, dtype=float)
        return cls([1.0], mean[None, :], np.asarray(covariance, dtype=float)[None, :, :])

    # -- basic properties --------------------------------------------------------------------
    @property
    def dim(self) -> int:
        return int(self.means.shape[1])

    @property
    def n_components(self) -> int:
        return int(self.weights.shape[0])

    def __len__(self) -> int:
        return self.n_components

    def __repr__(self) -> str:
        return f"GaussianMixture(n_components={self.n_components}, dim={self.dim})"

    def to_dict(self) -> dict:
        return {"weights": self.weights.tolist(), "means": self.means.tolist(),
                "covariances": self.covariances.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> GaussianMixture:
        return cls(d["weights"], d["means"], d["covariances"])

    # -- evaluation -----------------------------------------------------------------------
    def _points(self, x) -> tuple[np.ndarray, bool]:
        x = np.asarray(x, dtype=float)
        single = x.ndim == 1
        x = np.atleast_2d(x)
        if x.shape[-1] != self.dim:
            raise ValueError(f"points must have last dimension {self.dim}; got shape {x.shape}")
        return x.reshape(-1, self.dim), single

    def component_logpdf(self, x) -> np.ndarray:
        """``log N(x; mu_m, Sigma_m)`` for each component and point: shape ``(M, N)``."""
        pts, _ = self._points(x)
        return _logpdf_chol(pts, self.means, self._inv_chol, self._log_det)

    def logpdf(self, x) -> np.ndarray:
        """Log density at points ``(N, d)`` (or one point ``(d,)``), never ``-inf`` for finite x."""
        x_arr = np.asarray(x, dtype=float)
        pts, single = self._points(x_arr)
        with np.errstate(divide="ignore"):
            log_w = np.log(self.weights)
        out = logsumexp0(self.component_logpdf(pts) + log_w[:, None])
        return out[0] if single else out.reshape(x_arr.shape[:-1])

    def pdf(self, x) -> np.ndarray:
        return np.exp(self.logpdf(x))

    def sample(self, n: int, seed=None) -> np.ndarray:
        """``n`` independent draws, shape ``(n, d)``; ``seed`` is an int or a numpy Generator."""
        rng = _as_rng(seed)
        counts = rng.multinomial(int(n), self.weights)
        comp = np.repeat(np.arange(self.n_components), counts)
        z = rng.standard_normal((int(n), self.dim))
        x = self.means[comp] + np.einsum("nij,nj->ni", self._chol[comp], z)
        return x[rng.permutation(int(n))]

    def moments(self) -> tuple[np.ndarray, np.ndarray]:
        """Mean ``(d,)`` and covariance ``(d, d)`` of the whole mixture."""
        mean = self.weights @ self.means
        diff = self.means - mean
        cov = np.einsum("m,mij->ij", self.weights, self.covariances)
        cov += np.einsum("m,mi,mj->ij", self.weights, diff, diff)
        return mean, cov

    # -- closed-form products ---------------------------------------------------------------
    def multiply(self, other: GaussianMixture) -> GaussianMixture:
        """The normalised naive-Bayes product ``p q / Z`` (exact, ``M_p * M_q`` components)."""
        return product(self, other)[0]

    def foci(self, other: GaussianMixture, w: float) -> GaussianMixture:
        """First-order covariance intersection at weight ``w`` on ``self`` (component-wise CI)."""
        return foci(self, other, w)

    def wep(self, other: GaussianMixture, w: float, **kwargs) -> GaussianMixture:
        """The WEP ``p^w q^(1-w)`` at a fixed ``w``, approximated as in :func:`fuse_mixtures`."""
        from .mixture_fusion import fuse_mixtures

        return fuse_mixtures(self, other, omega=check_weight(w), **kwargs).mixture

    def reduce(self, max_components: int) -> GaussianMixture:
        """Runnalls' greedy merge down to at most ``max_components`` components."""
        from .mixture_reduction import runnalls_reduce

        return runnalls_reduce(self, max_components)


def _check_pair(a: GaussianMixture, b: GaussianMixture) -> None:
    if not isinstance(a, GaussianMixture) or not isinstance(b, GaussianMixture):
        raise TypeError("both beliefs must be GaussianMixture instances")
    if a.dim != b.dim:
        raise ValueError(f"cannot fuse mixtures of dimension {a.dim} and {b.dim}")


def _pair_index(a: GaussianMixture, b: GaussianMixture) -> tuple[np.ndarray, np.ndarray]:
    q, r = np.meshgrid(np.arange(a.n_components), np.arange(b.n_components), indexing="ij")
    return q.ravel(), r.ravel()


def _combine(prec_a, prec_b, mean_a, mean_b, wa: float, wb: float):
    """Information-form sum ``wa P_a + wb P_b``: covariances and means of all pairs."""
    info = wa * prec_a + wb * prec_b
    cov = np.linalg.inv(info)
    cov = 0.5 * (cov + np.swapaxes(cov, 1, 2))
    vec = wa * np.einsum("pij,pj->pi", prec_a, mean_a) + wb * np.einsum("pij,pj->pi", prec_b, mean_b)
    return np.einsum("pij,pj->pi", cov, vec), cov


def product(a: GaussianMixture, b: GaussianMixture) -> tuple[GaussianMixture, float, np.ndarray]:
    """Pairwise Gaussian products of two mixtures (paper 002, eqs. 20-23).

    Returns the normalised product mixture, ``log Z`` with ``Z = int p_a p_b dx``, and the log
    weights ``log(w_q w_r zbar_qr)`` of all pairs (row-major over ``(q, r)``).
    """
    _check_pair(a, b)
    q, r = _pair_index(a, b)
    prec_a, prec_b = np.linalg.inv(a.covariances)[q], np.linalg.inv(b.covariances)[r]
    mean, cov = _combine(prec_a, prec_b, a.means[q], b.means[r], 1.0, 1.0)
    # zbar_qr = N(mu_q; mu_r, Sigma_q + Sigma_r)
    s = a.covariances[q] + b.covariances[r]
    chol = np.linalg.cholesky(s)
    diff = (a.means[q] - b.means[r])[:, None, :]
    log_z = _logpdf_chol(np.zeros((1, a.dim)), diff[:, 0, :], np.linalg.inv(chol), _log_det(chol))[:, 0]
    with np.errstate(divide="ignore"):
        log_w = np.log(a.weights[q]) + np.log(b.weights[r]) + log_z
    log_norm = float(logsumexp(log_w))
    weights = np.exp(log_w - log_norm)
    keep = weights > 0
    return GaussianMixture(weights[keep], mean[keep], cov[keep]), log_norm, log_w


def foci(a: GaussianMixture, b: GaussianMixture, w: float) -> GaussianMixture:
    """Component-wise covariance intersection (paper 000 eqs. 21-24, 'FOCI' in paper 002).

    ``Sigma_qr = [w Sigma_q^-1 + (1-w) Sigma_r^-1]^-1``, ``mu_qr = Sigma_qr [w Sigma_q^-1 mu_q +
    (1-w) Sigma_r^-1 mu_r]``, weights ``w_q^w w_r^(1-w)`` normalised: ``M_a * M_b`` components.
    """
    _check_pair(a, b)
    w = check_weight(w)
    q, r = _pair_index(a, b)
    prec_a, prec_b = np.linalg.inv(a.covariances)[q], np.linalg.inv(b.covariances)[r]
    mean, cov = _combine(prec_a, prec_b, a.means[q], b.means[r], w, 1.0 - w)
    with np.errstate(divide="ignore"):
        la, lb = np.log(a.weights[q]), np.log(b.weights[r])
    if w in (0.0, 1.0):  # 0 * log 0: the absent side's weights do not matter
        log_w = la if w == 1.0 else lb
    else:
        log_w = w * la + (1.0 - w) * lb
    weights = np.exp(log_w - logsumexp(log_w))
    keep = weights > 0
    return GaussianMixture(weights[keep], mean[keep], cov[keep])


def kl_divergence(p: GaussianMixture, q: GaussianMixture, n_samples: int = 2000, seed=None) -> float:
    """Monte Carlo estimate of ``KL(p || q)`` in nats (``n_samples`` draws from ``p``)."""
    x = p.sample(n_samples, seed)
    return float(np.mean(p.logpdf(x) - q.logpdf(x)))
