"""Choosing the WEP weight omega for two densities from weighted sample sets.

Every cost of paper 000 (section II, III-B) is a function of the weighted integrals of
``p_w = p_a^w p_b^(1-w) / c(w)``. Given log densities ``log p_a``, ``log p_b`` at points ``x_s``
drawn from an importance density ``g`` (or grid nodes with ``g`` = 1 / cell area), with
``theta_s(w) = p_a^w p_b^(1-w) / g`` (eq. 20) and ``D = log p_a - log p_b``:

    log c(w)        = log mean_s theta_s(w)
    m(w)            = E_w[D]                 (= d/dw log c, non-decreasing in w)
    KL(p_w || p_a)  = -(1 - w) m(w) - log c(w)
    KL(p_w || p_b)  =        w m(w) - log c(w)
    KL(p_NB || p_w) = const + w kappa + log c(w),  kappa = -E_NB[D]   (eq. 18)

The same sample set is reused for every w (Algorithm 1). ``p_a`` and ``p_b`` are rescaled by
their own sample estimates ``c(1)`` and ``c(0)`` so that the estimated KLDs vanish exactly at the
end points; the estimates stay consistent and the rules' sign conditions hold for any sample.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import brentq, minimize_scalar
from scipy.special import logsumexp, softmax

from ..rule_names import FusionRule

#: Rules that choose a weight; ``naive-bayes`` is the un-weighted product and has none.
OMEGA_RULES = (
    FusionRule.BHATTACHARYYA,
    FusionRule.CHERNOFF,
    FusionRule.KLD_WEIGHTED_CHERNOFF,
    FusionRule.MIN_INFO_LOSS,
    FusionRule.MIN_ENTROPY,
)

_FLAT = 1e-10  # |D| spread below which both densities are equal and every w gives the same p_w


class WepCosts:
    """The WEP costs of paper 000 as functions of w, from one weighted sample set."""

    def __init__(self, log_a: np.ndarray, log_b: np.ndarray, log_g: np.ndarray) -> None:
        log_a, log_b, log_g = (np.asarray(v, dtype=float) for v in (log_a, log_b, log_g))
        if not (
            np.all(np.isfinite(log_a)) and np.all(np.isfinite(log_b)) and np.all(np.isfinite(log_g))
        ):
            raise ValueError("log densities at the importance samples must be finite")
        self.n = log_a.shape[0]
        self._raw = (log_a, log_b, log_g)
        self.log_a_scale = float(logsumexp(log_a - log_g) - np.log(self.n))
        self.log_b_scale = float(logsumexp(log_b - log_g) - np.log(self.n))
        self.a = log_a - self.log_a_scale
        self.b = log_b - self.log_b_scale
        self.log_g = log_g
        self.diff = self.a - self.b

    def subset(self, index) -> WepCosts:
        """The costs of the samples ``index`` alone (batch estimates of the standard error)."""
        return WepCosts(*(v[index] for v in self._raw))

    @property
    def flat(self) -> bool:
        """True when ``p_a`` and ``p_b`` agree at every sample (then p_w does not depend on w)."""
        return float(np.ptp(self.diff)) <= _FLAT * max(1.0, float(np.max(np.abs(self.diff))))

    def log_theta(self, w: float) -> np.ndarray:
        return w * self.diff + self.b - self.log_g

    def log_c(self, w: float) -> float:
        return float(logsumexp(self.log_theta(w)) - np.log(self.n))

    def weights(self, w: float) -> np.ndarray:
        """Normalised importance weights of ``p_w`` at the samples."""
        return softmax(self.log_theta(w))

    def mean_diff(self, w: float) -> float:
        return float(self.weights(w) @ self.diff)

    def kl_to_a(self, w: float) -> float:
        return max(0.0, -(1.0 - w) * self.mean_diff(w) - self.log_c(w))

    def kl_to_b(self, w: float) -> float:
        return max(0.0, w * self.mean_diff(w) - self.log_c(w))

    def entropy(self, w: float) -> float:
        """Differential entropy ``H(p_w) = log c(w) - E_w[w log p_a + (1 - w) log p_b]``."""
        t = self.weights(w)
        return self.log_c(w) - float(t @ (w * self.a + (1.0 - w) * self.b))

    def ess(self, w: float) -> float:
        """Effective sample size ``(sum theta)^2 / sum theta^2`` of the weights at w."""
        t = self.weights(w)
        return float(1.0 / np.sum(t * t))

    def info_loss(self, w: float, nb_mean_a: float, nb_mean_b: float, log_z_nb: float) -> float:
        """``KL(p_NB || p_w)`` (eq. 9), given ``E_NB[log p_a]``, ``E_NB[log p_b]`` and ``log Z_NB``.

        The expectations are of the exact (unscaled) log densities.
        """
        ea, eb = nb_mean_a - self.log_a_scale, nb_mean_b - self.log_b_scale
        shift = self.log_a_scale + self.log_b_scale  # log p_a + log p_b in the scaled units
        return max(0.0, (1.0 - w) * ea + w * eb + shift - log_z_nb + self.log_c(w))


def _root_of_increasing(f, lo: float = 0.0, hi: float = 1.0) -> float:
    """Root of a non-decreasing function on [lo, hi], clipped to the end points."""
    f_lo, f_hi = f(lo), f(hi)
    if f_lo >= 0.0:
        return lo
    if f_hi <= 0.0:
        return hi
    return float(brentq(f, lo, hi, xtol=1e-7, rtol=1e-9))


def choose_omega(
    costs: WepCosts,
    rule: str,
    nb_mean_diff: float | None = None,
    info_a: float | None = None,
    info_b: float | None = None,
) -> float:
    """The weight on ``p_a`` that ``rule`` chooses.

    ``nb_mean_diff`` is ``E_NB[log p_a - log p_b]`` under the normalised naive-Bayes product, for
    ``min-info-loss``; ``info_a``, ``info_b`` are the information gains ``KL(p || p_0)`` over the
    common prior, for ``kld-weighted-chernoff``. Equal densities give w = 1/2 for every rule.
    """
    if rule not in OMEGA_RULES:
        raise ValueError(
            f"rule {rule!r} does not choose a weight; choose one of {', '.join(OMEGA_RULES)}"
        )
    if rule == "bhattacharyya" or costs.flat:
        return 0.5
    if rule == "chernoff":  # argmin log c(w): the w with E_w[D] = 0, i.e. equal KLDs
        return _root_of_increasing(costs.mean_diff)
    if rule == "min-info-loss":  # argmin w kappa + log c(w): E_w[D] = E_NB[D]
        if nb_mean_diff is None:
            raise ValueError("min-info-loss needs E_NB[log p_a - log p_b]")
        target = nb_mean_diff - costs.log_a_scale + costs.log_b_scale
        return _root_of_increasing(lambda w: costs.mean_diff(w) - target)
    if rule == "kld-weighted-chernoff":  # c_a KL(p_w||p_a) = c_b KL(p_w||p_b), decreasing in w
        if info_a is None or info_b is None:
            raise ValueError("kld-weighted-chernoff needs the information gains of both sides")
        ca, cb = max(float(info_a), 0.0), max(float(info_b), 0.0)
        if ca + cb <= 0.0:  # neither side learnt anything since the prior: plain Chernoff
            return _root_of_increasing(costs.mean_diff)
        return _root_of_increasing(lambda w: cb * costs.kl_to_b(w) - ca * costs.kl_to_a(w))
    # min-entropy: H(p_w) need not be convex for mixtures; scan, then refine around the best node
    grid = np.linspace(0.0, 1.0, 41)
    values = np.array([costs.entropy(w) for w in grid])
    k = int(np.argmin(values))
    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    res = minimize_scalar(costs.entropy, bounds=(lo, hi), method="bounded", options={"xatol": 1e-6})
    return float(res.x) if res.fun <= values[k] else float(grid[k])
