"""Belief families for range-only target tracking: one adapter per family, one interface.

Each adapter starts a belief from the common prior, folds in a range measurement, predicts
under the motion model ``x' = x + v dt + noise(Q dt)``, fuses a received belief with the WEP rule
and reports its mean, Renyi-2 entropy and message size.
"""

from __future__ import annotations

import numpy as np
from scipy.special import logsumexp

from ..beliefs.expoly import ExPoly2D
from ..beliefs.gaussian import Gaussian
from ..beliefs.weight_search import choose_weight


class ExPolyFamily:
    """Exponential polynomials: exact products and WEP; approximate diffusion."""

    name = "expoly"

    def __init__(self, sensor_a: float, weight_cost: str = "trace"):
        self.sensor_a, self.weight_cost = sensor_a, weight_cost

    def prior(self, mean, cov):
        return ExPoly2D.from_gaussian(mean, cov)

    def update(self, belief, sensor, measured_range):
        return belief.multiply(ExPoly2D.range_likelihood(sensor, measured_range, self.sensor_a))

    def predict(self, belief, drift, Q):
        return belief.predict(np.eye(2), drift).diffuse(Q)

    def fuse(self, mine, received):
        choice = choose_weight(mine, received, self.weight_cost)
        return choice.fused, choice.w

    def mean(self, belief):
        return belief.moments()[0]

    def renyi2(self, belief):
        return belief.renyi2_entropy()

    def message_bytes(self, belief):
        return belief.message_bytes


class GaussianFamily(ExPolyFamily):
    """Gaussians fused by covariance intersection; a range update is the moment-matched
    projection of ``prior x ring likelihood`` (integrated on a grid)."""

    name = "gaussian"

    def prior(self, mean, cov):
        return Gaussian.from_moments(mean, cov)

    def update(self, belief, sensor, measured_range):
        ring = ExPoly2D.range_likelihood(sensor, measured_range, self.sensor_a)
        return ExPoly2D.from_gaussian(belief.mean, belief.cov).multiply(ring).to_gaussian()

    def predict(self, belief, drift, Q):
        return belief.predict(np.eye(2), drift).diffuse(Q)


def ring_mixture(sensor, measured_range: float, a: float, n_components: int = 16):
    """The range likelihood ``exp(-4a (r - z)^2)`` as Gaussians placed around the ring."""
    from ..beliefs.mixture import GaussianMixture

    angles = np.linspace(0.0, 2 * np.pi, n_components, endpoint=False)
    radial = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    tangent = np.stack([-radial[:, 1], radial[:, 0]], axis=1)
    var_r = 1.0 / (8.0 * a)
    var_t = (2 * np.pi * measured_range / n_components) ** 2 / 4.0 + var_r
    covs = (
        var_r * radial[:, :, None] * radial[:, None, :]
        + var_t * tangent[:, :, None] * tangent[:, None, :]
    )
    means = np.asarray(sensor, dtype=float) + measured_range * radial
    return GaussianMixture(np.full(n_components, 1.0 / n_components), means, covs)


class MixtureFamily:
    """Gaussian mixtures: the ring likelihood as a mixture, products reduced by Runnalls' method,
    fusion by :func:`~octofuse.beliefs.mixture_fusion.fuse_mixtures` (importance sampling)."""

    name = "mixture"

    def __init__(
        self, sensor_a: float, rule: str = "min-info-loss", max_components: int = 8, seed: int = 0
    ):
        self.sensor_a, self.rule, self.max_components = sensor_a, rule, max_components
        self.rng = np.random.default_rng(seed)

    def prior(self, mean, cov):
        from ..beliefs.mixture import GaussianMixture

        return GaussianMixture.gaussian(mean, cov)

    def update(self, belief, sensor, measured_range):
        return belief.multiply(ring_mixture(sensor, measured_range, self.sensor_a)).reduce(
            self.max_components
        )

    def predict(self, belief, drift, Q):
        from ..beliefs.mixture import GaussianMixture

        return GaussianMixture(belief.weights, belief.means + drift, belief.covariances + Q)

    def fuse(self, mine, received):
        from ..beliefs.mixture_fusion import fuse_mixtures

        out = fuse_mixtures(
            mine,
            received,
            rule=self.rule,
            n_samples=400,
            max_components=self.max_components,
            seed=self.rng,
        )
        return out.mixture, float(out.omega)

    def mean(self, belief):
        return belief.moments()[0]

    def renyi2(self, belief):
        """``-log integral p^2``, in closed form: ``sum w_q w_r N(m_q; m_r, S_q + S_r)``."""
        w, m, S = belief.weights, belief.means, belief.covariances
        diff = m[:, None, :] - m[None, :, :]
        cov = S[:, None] + S[None, :]
        quad = np.einsum("qri,qrij,qrj->qr", diff, np.linalg.inv(cov), diff)
        log_n = -0.5 * quad - np.log(2 * np.pi) - 0.5 * np.linalg.slogdet(cov)[1]
        return float(-logsumexp(log_n + np.log(w)[:, None] + np.log(w)[None, :]))

    def message_bytes(self, belief):
        d = belief.dim
        return 8 * belief.n_components * (1 + d + d * (d + 1) // 2)
