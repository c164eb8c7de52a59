"""The closed-form algebra of Gaussian mixtures: log densities, pairwise products, FOCI.

A mixture ``sum_m w_m N(x; mu_m, Sigma_m)`` has weights ``(M,)``, means ``(M, d)`` and covariances
``(M, d, d)``. Densities are evaluated in the log domain throughout, so mixtures whose supports are
far apart (densities that underflow to 0.0 in floating point) still fuse to finite results.

The operations here, the reduction and the fusion take any :class:`Mixture` and build their
results with its class (:class:`~octofuse.beliefs.mixture.GaussianMixture`, which offers them as
methods, sits above them).
"""

from __future__ import annotations

from typing import Protocol, TypeVar, runtime_checkable

import numpy as np
from scipy.special import logsumexp

from .base import check_weight

LOG_2PI = float(np.log(2.0 * np.pi))


@runtime_checkable
class Mixture(Protocol):
    """What the mixture operations read of a mixture; its class builds their results as
    ``type(m)(weights, means, covariances)``."""

    weights: np.ndarray
    means: np.ndarray
    covariances: np.ndarray

    @property
    def dim(self) -> int: ...

    @property
    def n_components(self) -> int: ...

    def component_logpdf(self, x) -> np.ndarray: ...

    def logpdf(self, x) -> np.ndarray: ...

    def sample(self, n: int, seed=None) -> np.ndarray: ...


M = TypeVar("M", bound=Mixture)


def as_rng(seed) -> np.random.Generator:
    """``seed`` (an int, None or a numpy Generator) as a Generator."""
    return seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)


def gaussian_logpdf(x: np.ndarray, means: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """``log N(x_n; mu_m, Sigma_m)`` for points ``(N, d)`` and components ``(M, d)``: shape ``(M, N)``."""
    chol = np.linalg.cholesky(covariances)
    return logpdf_cholesky(np.atleast_2d(x), means, np.linalg.inv(chol), log_det_cholesky(chol))


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


def log_det_cholesky(chol: np.ndarray) -> np.ndarray:
    """``log det Sigma`` from stacked Cholesky factors ``L`` of ``Sigma = L L^T``."""
    return 2.0 * np.log(np.diagonal(chol, axis1=-2, axis2=-1)).sum(-1)


def logpdf_cholesky(
    x: np.ndarray, means: np.ndarray, inv_chol: np.ndarray, log_det: np.ndarray
) -> np.ndarray:
    """Component log densities ``(M, N)`` from the inverse Cholesky factors ``L^-1`` ``(M, d, d)``."""
    d = x.shape[1]
    z = np.matmul(x[None, :, :], np.swapaxes(inv_chol, 1, 2))  # L^-1 x, shape (M, N, d)
    z -= np.einsum("mij,mj->mi", inv_chol, means)[:, None, :]
    z *= z
    return -0.5 * (z.sum(-1) + log_det[:, None] + d * LOG_2PI)


def check_pair(a, b) -> None:
    """``TypeError`` unless both are mixtures, ``ValueError`` unless of one dimension."""
    if not isinstance(a, Mixture) or not isinstance(b, Mixture):
        raise TypeError("both beliefs must be GaussianMixture instances")
    if a.dim != b.dim:
        raise ValueError(f"cannot fuse mixtures of dimension {a.dim} and {b.dim}")


def _pair_index(a: Mixture, b: Mixture) -> tuple[np.ndarray, np.ndarray]:
    q, r = np.meshgrid(np.arange(a.n_components), np.arange(b.n_components), indexing="ij")
    return q.ravel(), r.ravel()


def _combine(prec_a, prec_b, mean_a, mean_b, wa: float, wb: float):
    """Information-form sum ``wa P_a + wb P_b``: covariances and means of all pairs."""
    info = wa * prec_a + wb * prec_b
    cov = np.linalg.inv(info)
    cov = 0.5 * (cov + np.swapaxes(cov, 1, 2))
    vec = wa * np.einsum("pij,pj->pi", prec_a, mean_a) + wb * np.einsum(
        "pij,pj->pi", prec_b, mean_b
    )
    return np.einsum("pij,pj->pi", cov, vec), cov


def product(a: M, b: M) -> tuple[M, float, np.ndarray]:
    """Pairwise Gaussian products of two mixtures (paper 002, eqs. 20-23).

    Returns the normalised product mixture, ``log Z`` with ``Z = int p_a p_b dx``, and the log
    weights ``log(w_q w_r zbar_qr)`` of all pairs (row-major over ``(q, r)``).
    """
    check_pair(a, b)
    q, r = _pair_index(a, b)
    prec_a, prec_b = np.linalg.inv(a.covariances)[q], np.linalg.inv(b.covariances)[r]
    mean, cov = _combine(prec_a, prec_b, a.means[q], b.means[r], 1.0, 1.0)
    # zbar_qr = N(mu_q; mu_r, Sigma_q + Sigma_r)
    s = a.covariances[q] + b.covariances[r]
    chol = np.linalg.cholesky(s)
    diff = (a.means[q] - b.means[r])[:, None, :]
    log_z = logpdf_cholesky(
        np.zeros((1, a.dim)), diff[:, 0, :], np.linalg.inv(chol), log_det_cholesky(chol)
    )[:, 0]
    with np.errstate(divide="ignore"):
        log_w = np.log(a.weights[q]) + np.log(b.weights[r]) + log_z
    log_norm = float(logsumexp(log_w))
    weights = np.exp(log_w - log_norm)
    keep = weights > 0
    return type(a)(weights[keep], mean[keep], cov[keep]), log_norm, log_w


def foci(a: M, b: M, w: float) -> M:
    """Component-wise covariance intersection (paper 000 eqs. 21-24, 'FOCI' in paper 002).

    ``Sigma_qr = [w Sigma_q^-1 + (1-w) Sigma_r^-1]^-1``, ``mu_qr = Sigma_qr [w Sigma_q^-1 mu_q +
    (1-w) Sigma_r^-1 mu_r]``, weights ``w_q^w w_r^(1-w)`` normalised: ``M_a * M_b`` components.
    """
    check_pair(a, b)
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
    return type(a)(weights[keep], mean[keep], cov[keep])


def kl_divergence(p: Mixture, q: Mixture, n_samples: int = 2000, seed=None) -> float:
    """Monte Carlo estimate of ``KL(p || q)`` in nats (``n_samples`` draws from ``p``)."""
    x = p.sample(n_samples, seed)
    return float(np.mean(p.logpdf(x) - q.logpdf(x)))
