"""Gaussian-mixture beliefs: the mixture itself (evaluation, sampling, moments) and its
operations as a :class:`~octofuse.beliefs.base.Belief`.

The operations live below this class and take any mixture: the closed-form products in
:mod:`~octofuse.beliefs.mixture_algebra`, the reduction in
:mod:`~octofuse.beliefs.mixture_reduction`, the WEP fusion in
:mod:`~octofuse.beliefs.mixture_fusion`.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from .base import check_weight
from .mixture_algebra import as_rng, foci, log_det_cholesky, logpdf_cholesky, logsumexp0, product
from .mixture_fusion import fuse_mixtures
from .mixture_reduction import runnalls_reduce


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
        self._log_det = log_det_cholesky(chol)

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
        return {
            "weights": self.weights.tolist(),
            "means": self.means.tolist(),
            "covariances": self.covariances.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict) -> GaussianMixture:
        """The mixture of :meth:`to_dict`: a mapping with ``weights``, ``means`` and ``covariances``."""
        if not isinstance(d, Mapping):
            raise TypeError(f"from_dict expects a mapping, got {type(d).__name__}")
        missing = [k for k in ("weights", "means", "covariances") if k not in d]
        if missing:
            raise ValueError(
                f"mixture dict lacks {', '.join(missing)}: expected the keys weights, "
                "means and covariances"
            )
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
        return logpdf_cholesky(pts, self.means, self._inv_chol, self._log_det)

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
        rng = as_rng(seed)
        counts = rng.multinomial(int(n), self.weights)
        comp = np.repeat(np.arange(self.n_components), counts)
        z = rng.standard_normal((int(n), self.dim))
        x = self.means[comp] + np.einsum("nij,nj->ni", self._chol[comp], z)
        return x[rng.permutation(int(n))]

    def moments(self) -> tuple[np.ndarray, np.ndarray]:
        """Mean ``(d,)`` and covariance ``(d, d)`` of the whole mixture."""
        mean = self.weights @ self.means
        diff = self.means - mean
        with np.errstate(over="ignore", invalid="ignore"):
            cov = np.einsum("m,mij->ij", self.weights, self.covariances)
            cov += np.einsum("m,mi,mj->ij", self.weights, diff, diff)
        if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))):
            raise ValueError(
                "the mixture's mean or covariance overflows float64 (components "
                "too far apart or too wide); rescale its units"
            )
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
        return fuse_mixtures(self, other, omega=check_weight(w), **kwargs).mixture

    def reduce(self, max_components: int) -> GaussianMixture:
        """Runnalls' greedy merge down to at most ``max_components`` components."""
        return runnalls_reduce(self, max_components)
