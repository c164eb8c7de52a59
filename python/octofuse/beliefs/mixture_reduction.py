"""Keeping mixtures small: Runnalls' greedy merge and weighted EM on weighted samples."""

from __future__ import annotations

import numpy as np

from .mixture_algebra import M, gaussian_logpdf, log_det_spd, logsumexp0


def _merge(w, mu, cov, i, j):
    """Moment-preserving merge of components i and j (weights need not be normalised)."""
    wij = w[i] + w[j]
    a, b = w[i] / wij, w[j] / wij
    m = a * mu[i] + b * mu[j]
    diff = mu[i] - mu[j]
    c = a * cov[i] + b * cov[j] + a * b * np.outer(diff, diff)
    return wij, m, 0.5 * (c + c.T)


def _merge_costs(w, mu, cov, logdet, i, others):
    """Runnalls' upper bound on KL(before || after) for merging i with each of ``others``."""
    wi, wo = w[i], w[others]
    wij = wi + wo
    a, b = (wi / wij)[:, None, None], (wo / wij)[:, None, None]
    diff = mu[i] - mu[others]
    c = a * cov[i] + b * cov[others] + a * b * np.einsum("ni,nj->nij", diff, diff)
    logdet_ij = log_det_spd(c)
    return 0.5 * (wij * logdet_ij - wi * logdet[i] - wo * logdet[others])


def runnalls_reduce(mix: M, max_components: int) -> M:
    """Merge pairs greedily by Runnalls' KL bound until at most ``max_components`` remain.

    Merges preserve the mixture's weight, mean and covariance; zero-weight components are dropped
    first. ``max_components >= 1``.
    """
    max_components = int(max_components)
    if max_components < 1:
        raise ValueError(f"max_components must be >= 1; got {max_components}")
    keep = mix.weights > 0
    w, mu, cov = mix.weights[keep].copy(), mix.means[keep].copy(), mix.covariances[keep].copy()
    n = w.shape[0]
    if n <= max_components:
        return mix if keep.all() else type(mix)(w, mu, cov)
    logdet = log_det_spd(cov)
    costs = np.full((n, n), np.inf)
    for i in range(n - 1):
        others = np.arange(i + 1, n)
        costs[i, others] = _merge_costs(w, mu, cov, logdet, i, others)
    active = np.ones(n, dtype=bool)
    for _ in range(n - max_components):
        flat = int(np.argmin(costs))
        i, j = divmod(flat, n)
        w[i], mu[i], cov[i] = _merge(w, mu, cov, i, j)
        logdet[i] = log_det_spd(cov[i])
        active[j] = False
        w[j] = 0.0
        costs[j, :] = np.inf
        costs[:, j] = np.inf
        others = np.flatnonzero(active)
        others = others[others != i]
        new = _merge_costs(w, mu, cov, logdet, i, others)
        lo, hi = others < i, others > i
        costs[others[lo], i] = new[lo]
        costs[i, others[hi]] = new[hi]
    return type(mix)(w[active], mu[active], cov[active])


def weighted_em(
    x: np.ndarray,
    weights: np.ndarray,
    init: M,
    n_iter: int = 50,
    tol: float = 1e-6,
) -> M:
    """Weighted EM: the mixture maximising ``sum_s weights_s log p(x_s)``, started from ``init``.

    ``weights`` are non-negative importance weights (normalised here). Covariances get a small
    ridge (1e-6 of the samples' mean variance) so they stay positive definite; components that
    lose all responsibility are dropped.
    """
    x = np.asarray(x, dtype=float)
    theta = np.asarray(weights, dtype=float)
    theta = theta / theta.sum()
    d = x.shape[1]
    mean_all = theta @ x
    spread = float(theta @ ((x - mean_all) ** 2).sum(1)) / d
    ridge = max(spread, 1e-12) * 1e-6 * np.eye(d)
    w, mu, cov = init.weights.copy(), init.means.copy(), init.covariances.copy()
    prev = -np.inf
    for _ in range(int(n_iter)):
        log_joint = gaussian_logpdf(x, mu, cov) + np.log(w)[:, None]  # (M, N)
        log_px = logsumexp0(log_joint)
        loglik = float(theta @ log_px)
        resp = np.exp(log_joint - log_px[None, :]) * theta[None, :]  # weighted responsibilities
        nk = resp.sum(1)
        alive = nk > 1e-10
        resp, nk = resp[alive], nk[alive]
        w = nk / nk.sum()
        mu = (resp @ x) / nk[:, None]
        diff = x[None, :, :] - mu[:, None, :]
        cov = np.einsum("mn,mni,mnj->mij", resp, diff, diff) / nk[:, None, None] + ridge
        cov = 0.5 * (cov + np.swapaxes(cov, 1, 2))
        if abs(loglik - prev) < tol * max(1.0, abs(loglik)):
            break
        prev = loglik
    return type(init)(w, mu, cov)
