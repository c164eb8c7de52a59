"""Bayes updates of a Gaussian-mixture belief by a Gaussian-sum particle filter.

Each mixand is sampled with ``n_particles`` particles, which are weighted by the observation
likelihood; the mixand's new weight is its old weight times the particles' mean likelihood
(Kotecha and Djuric's Gaussian-sum particle filter). A mixand whose particle weights stay nearly
even is replaced by one moment-matched Gaussian; one the sensor footprint cuts (relative
effective sample size below ``split_below``) is refitted with ``split_into`` Gaussians by weighted
EM, so the hole the footprint leaves survives in part. The result is reduced to ``max_components`` by Runnalls' method.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..beliefs.mixture import GaussianMixture
from ..beliefs.mixture_reduction import runnalls_reduce, weighted_em

Likelihood = Callable[[np.ndarray], np.ndarray]


def _refit(x: np.ndarray, theta: np.ndarray, cov: np.ndarray, k: int, rng) -> GaussianMixture:
    """Weighted EM with ``k`` components started at ``k`` particles drawn by weight."""
    start = rng.choice(len(x), size=k, replace=False, p=theta)
    init = GaussianMixture(np.ones(k), x[start], np.repeat(cov[None] / k, k, axis=0))
    return weighted_em(x, theta, init, n_iter=40, tol=1e-5)


def gaussian_sum_update(
    belief: GaussianMixture,
    likelihood: Likelihood,
    rng: np.random.Generator,
    n_particles: int = 1000,
    max_components: int = 15,
    split_below: float = 0.99,
    split_into: int = 4,
) -> GaussianMixture:
    """The posterior ``belief(x) likelihood(x) / Z`` as a mixture of at most ``max_components``.

    ``likelihood`` maps points ``(N, d)`` to values ``(N,)`` in [0, inf). If every particle has zero
    likelihood (an observation the belief gives no support), the belief is returned unchanged.
    """
    m, d = belief.n_components, belief.dim
    half = max(1, n_particles // 2)
    chol = np.linalg.cholesky(belief.covariances)
    z = rng.standard_normal((m, half, d))
    z = np.concatenate(
        [z, -z], axis=1
    )  # antithetic pairs: each mixand's particles have its exact mean
    x = belief.means[:, None, :] + np.matmul(z, np.swapaxes(chol, 1, 2))  # (M, N, d)
    lik = np.asarray(likelihood(x.reshape(-1, d)), dtype=float).reshape(m, 2 * half)
    mass = belief.weights * lik.mean(axis=1)
    if not np.any(mass > 0):
        return belief
    weights, means, covs = [], [], []
    for k in np.flatnonzero(mass > 0):
        if np.ptp(lik[k]) <= 1e-12 * lik[k].max():  # the sensor says nothing about this mixand
            fit = GaussianMixture([1.0], belief.means[k][None], belief.covariances[k][None])
        else:
            theta = lik[k] / lik[k].sum()
            mean, cov = _moments(x[k], theta, belief.means[k], belief.covariances[k])
            if 1.0 / np.sum(theta * theta) >= split_below * len(theta):
                fit = GaussianMixture([1.0], mean[None], cov[None])
            else:
                fit = _refit(x[k], theta, cov, split_into, rng)
        weights.append(mass[k] * fit.weights)
        means.append(fit.means)
        covs.append(fit.covariances)
    post = GaussianMixture(np.concatenate(weights), np.concatenate(means), np.concatenate(covs))
    return runnalls_reduce(post, max_components)


def _moments(x, theta, prior_mean, prior_cov):
    """Weighted mean and covariance with the prior's exact covariance as a control variate.

    ``cov = prior_cov + (weighted sample covariance - unweighted sample covariance)``, so a nearly
    flat likelihood changes the mixand by nearly nothing instead of by the particles' sampling
    noise (which would otherwise accumulate over many updates); the plain weighted estimate is
    used if the corrected one is not positive definite.
    """
    mean = theta @ x
    diff = x - mean
    weighted = (diff * theta[:, None]).T @ diff
    dev = x - prior_mean
    cov = prior_cov + weighted - dev.T @ dev / len(x)
    cov = 0.5 * (cov + cov.T)
    if np.linalg.eigvalsh(cov)[0] <= 1e-12 * np.trace(prior_cov):
        cov = weighted + 1e-9 * np.eye(len(mean))
    return mean, cov
