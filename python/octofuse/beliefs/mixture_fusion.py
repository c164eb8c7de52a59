"""WEP fusion of two Gaussian mixtures: choose omega by importance sampling, then build the mixture.

Rules (names as for the occupancy rules):

``naive-bayes``            the exact product ``p_a p_b / Z`` (pairwise Gaussian products, paper 002
                           eqs. 20-23); not conservative, no omega (``omega`` is NaN).
``bhattacharyya``          w = 1/2.
``chernoff``               argmin_w ``int p_a^w p_b^(1-w)``: KL(p_w||p_a) = KL(p_w||p_b).
``kld-weighted-chernoff``  ``c_a KL(p_w||p_a) = c_b KL(p_w||p_b)`` with ``c = KL(p || prior)``, the
                           information each side gained over the common ``prior`` (paper 000 eq. 6).
``min-info-loss``          argmin_w KL(p_NB || p_w) (eqs. 9-10), p_NB the normalised product.
``min-entropy``            argmin_w of the differential entropy H(p_w) (Shannon fusion). The
                           minimisation is well defined for densities even where H < 0.

``entropy-weighted-chernoff`` is rejected with a ``ValueError``: its weights c = 1/H are meaningless
for densities, whose differential entropy can be zero or negative; use ``kld-weighted-chernoff``.

Omega search (paper 000 Algorithm 1): ``n_samples`` draws from the importance density ``g(x; w_bar)``
(w_bar = 1/2) are taken once; ``g`` is the component-wise covariance intersection (FOCI) made
defensive, ``0.8 FOCI + 0.1 p_a + 0.1 p_b``, which bounds every importance weight
``p_a^w p_b^(1-w) / g <= 10`` for all w (FOCI alone has lighter tails than the wider side, and
the estimates of the KLDs near w = 0 or 1 then have unbounded variance); every cost is evaluated
at any w from the stored log densities. If the effective sample size at the chosen w is below
``ess_fraction * n_samples``, the search restarts from ``w_bar = w`` (at most ``max_restarts`` times;
the draw with the largest ESS is kept).

Fused mixture at the chosen w (``method``):

``moment-match``  paper 002 section IV: ``p_w = sum_qr w_q N_q w_r N_r / u`` with
                  ``u = p_a^(1-w) p_b^w``; each pair term is moment matched (weight, mean,
                  covariance) by importance sampling from the pair's FOCI component with its
                  covariance doubled. Since ``u >= (w_q N_q)^(1-w) (w_r N_r)^w``, each pair term is
                  bounded by its FOCI component, so the importance weights are bounded (paper
                  002's proposal, centred at the product mean with the larger of Sigma_q, Sigma_r,
                  misses the mass when w is far from 1/2 and the supports are far apart). Exact
                  up to sampling noise when both sides are single Gaussians.
``em``            paper 000: weighted EM on the omega-search samples, started from FOCI reduced to
                  ``max_components`` (Runnalls).
``foci``          the component-wise covariance intersection itself.

``naive-bayes`` ignores ``method`` (its product is exact). All results are reduced to
``max_components`` by Runnalls' method.

Sample counts: by default (``n_samples=None``) the omega search starts with ``ADAPTIVE_START``
draws and redraws with more (as many as the standard error asks for, at least twice as many) until the standard error of omega (batch means over ``BATCHES``
batches, reported as ``std_error``) is at most ``omega_tol``, or the count reaches
``ADAPTIVE_MAX`` or the memory bound. Sizes are checked before any work: more than ``MAX_PAIRS``
component pairs (``a``'s components times ``b``'s), or arrays needing more than half of the
machine's memory, are refused with a ``ValueError`` naming the argument to lower.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp

from ..rule_names import FusionRule
from .base import check_weight
from .mixture_algebra import (
    M,
    Mixture,
    as_rng,
    check_pair,
    foci,
    kl_divergence,
    logsumexp0,
    product,
)
from .mixture_omega import OMEGA_RULES, WepCosts, choose_omega
from .mixture_reduction import runnalls_reduce, weighted_em

MIXTURE_RULES = (FusionRule.NAIVE_BAYES, *OMEGA_RULES)
MIXTURE_METHODS = ("moment-match", "em", "foci")
DEFENSIVE_SHARE = 0.1  # weight of each side's own mixture in the omega-search density
PROPOSAL_INFLATION = 2.0  # moment matching samples each pair from its FOCI term, covariance x 2
ADAPTIVE_START = 4000  # first omega-search draw of the adaptive count
ADAPTIVE_MAX = 1 << 16  # largest adaptive count
OMEGA_TOL = 0.005  # standard error of omega the adaptive count aims at
BATCHES = 8  # batches of the standard error's batch means
MAX_PAIRS = 2500  # component pairs: Runnalls' reduction of them costs O(pairs^3) time


@dataclass(frozen=True)
class MixtureFusion:
    """Result of :func:`fuse_mixtures`. Divergences are sample estimates in nats."""

    mixture: Mixture  #: the fused mixture, at most ``max_components`` components
    omega: float  #: weight on ``a`` (NaN for naive-bayes)
    rule: str
    method: str
    ess: float  #: effective sample size of the omega-search weights at ``omega``
    n_samples: int
    restarts: (
        int  #: which draw of the omega search was kept (0: the first; more after low-ESS restarts)
    )
    kl_to_a: float  #: KL(p_w || p_a)
    kl_to_b: float  #: KL(p_w || p_b)
    info_loss: float  #: KL(p_NB || p_w), the approximate information loss of paper 000 eq. 9
    info_a: float  #: KL(p_a || prior) (NaN without a prior)
    info_b: float  #: KL(p_b || prior)
    #: standard error of ``omega`` (batch means; 0 when omega is fixed, NaN for naive-bayes)
    std_error: float = math.nan

    def summary(self) -> dict:
        out = {
            k: getattr(self, k)
            for k in (
                "omega",
                "rule",
                "method",
                "ess",
                "n_samples",
                "restarts",
                "kl_to_a",
                "kl_to_b",
                "info_loss",
                "info_a",
                "info_b",
                "std_error",
            )
        }
        out["n_components"] = self.mixture.n_components
        return out


def check_rule(rule: str) -> str:
    if rule == "entropy-weighted-chernoff":
        raise ValueError(
            "entropy-weighted-chernoff is not defined for densities: its weights 1/H need a positive "
            "entropy, and differential entropy can be zero or negative; use kld-weighted-chernoff"
        )
    if rule not in MIXTURE_RULES:
        raise ValueError(
            f"unknown mixture fusion rule {rule!r}; valid rules are: {', '.join(MIXTURE_RULES)}"
        )
    return rule


def importance_density(a: M, b: M, w_bar: float) -> M:
    """``(1 - 2 eps) FOCI(w_bar) + eps p_a + eps p_b``: the defensive omega-search density."""
    f = foci(a, b, w_bar)
    parts = [(1.0 - 2.0 * DEFENSIVE_SHARE, f), (DEFENSIVE_SHARE, a), (DEFENSIVE_SHARE, b)]
    return type(a)(
        np.concatenate([s * m.weights for s, m in parts]),
        np.concatenate([m.means for _, m in parts]),
        np.concatenate([m.covariances for _, m in parts]),
    )


def _draw(a, b, w_bar, n, rng):
    g = importance_density(a, b, w_bar)
    x = g.sample(n, rng)
    return x, WepCosts(a.logpdf(x), b.logpdf(x), g.logpdf(x))


def search_omega(
    a,
    b,
    rule,
    n_samples,
    rng,
    *,
    nb_mean_diff=None,
    info_a=None,
    info_b=None,
    omega=None,
    ess_fraction=0.2,
    max_restarts=3,
):
    """Algorithm 1 of paper 000: returns ``(omega, samples, costs, restarts)``."""
    w_bar = 0.5 if omega is None else omega
    best = None
    for attempt in range(max_restarts + 1):
        x, costs = _draw(a, b, w_bar, n_samples, rng)
        w = omega if omega is not None else choose_omega(costs, rule, nb_mean_diff, info_a, info_b)
        ess = costs.ess(w)
        if best is None or ess > best[3]:
            best = (w, x, costs, ess, attempt)
        if ess >= ess_fraction * n_samples or abs(w - w_bar) < 1e-9:
            break
        w_bar = w
    w, x, costs, _, attempt = best
    return w, x, costs, attempt


def moment_match(a: M, b: M, w: float, n_per_pair: int, rng) -> M:
    """Paper 002 section IV: one moment-matched Gaussian per component pair of ``p_a^w p_b^(1-w)``."""
    w = check_weight(w)
    if w in (0.0, 1.0):
        return b if w == 0.0 else a
    f = foci(a, b, w)
    if f.n_components != a.n_components * b.n_components:
        raise ValueError("moment matching needs mixtures without zero-weight components")
    if f.n_components == 1:  # p_a^w p_b^(1-w) of two Gaussians is their FOCI Gaussian, exactly
        return f
    d = a.dim
    n_pairs = f.n_components
    q = np.repeat(np.arange(a.n_components), b.n_components)
    r = np.tile(np.arange(b.n_components), a.n_components)
    prop_chol = np.linalg.cholesky(PROPOSAL_INFLATION * f.covariances)
    z = rng.standard_normal(((n_per_pair + 1) // 2, d))
    z = np.concatenate([z, -z])  # antithetic pairs, the same for every component pair
    n_per_pair = len(z)
    x = f.means[:, None, :] + np.matmul(z[None, :, :], np.swapaxes(prop_chol, 1, 2))  # (P, n, d)
    pts = x.reshape(-1, d)
    comp_a = a.component_logpdf(pts) + np.log(a.weights)[:, None]  # (Ma, P n)
    comp_b = b.component_logpdf(pts) + np.log(b.weights)[:, None]
    log_pa = logsumexp0(comp_a).reshape(n_pairs, n_per_pair)
    log_pb = logsumexp0(comp_b).reshape(n_pairs, n_per_pair)
    cols = np.arange(n_pairs * n_per_pair).reshape(n_pairs, n_per_pair)
    log_pair = comp_a[q[:, None], cols] + comp_b[r[:, None], cols]  # log w_q N_q + log w_r N_r
    log_target = log_pair - (1.0 - w) * log_pa - w * log_pb
    half_log_det = np.log(np.diagonal(prop_chol, axis1=1, axis2=2)).sum(1)
    log_prop = -0.5 * np.einsum("ni,ni->n", z, z)[None, :] - half_log_det[:, None]
    log_theta = log_target - log_prop  # the common (2 pi)^(d/2) cancels on normalising
    log_mass = logsumexp0(log_theta.T)
    theta = np.exp(log_theta - log_mass[:, None])
    mean = np.matmul(theta[:, None, :], x)[:, 0, :]
    diff = x - mean[:, None, :]
    cov = np.matmul(np.swapaxes(diff * theta[:, :, None], 1, 2), diff)
    cov = 0.5 * (cov + np.swapaxes(cov, 1, 2))
    ess = 1.0 / np.sum(theta * theta, axis=1)
    eig_min = np.linalg.eigvalsh(cov)[:, 0]
    scale = np.linalg.eigvalsh(f.covariances)[:, -1]
    bad = (ess < d + 2) | ~(eig_min > 1e-9 * scale) | ~np.all(np.isfinite(mean), axis=1)
    mean[bad], cov[bad] = f.means[bad], f.covariances[bad]  # too few effective samples: FOCI term
    weights = np.exp(log_mass - logsumexp(log_mass))
    keep = weights > 0
    return type(a)(weights[keep], mean[keep], cov[keep])


def _without_zero_weights(m: M) -> M:
    keep = m.weights > 0
    return m if keep.all() else type(m)(m.weights[keep], m.means[keep], m.covariances[keep])


def _estimate_info(p: Mixture, prior: Mixture, n: int, rng) -> float:
    return max(0.0, kl_divergence(p, prior, n, rng))


def fuse_mixtures(
    a: Mixture,
    b: Mixture,
    rule: str = "min-info-loss",
    n_samples: int | None = None,
    method: str = "moment-match",
    max_components: int = 15,
    prior: Mixture | None = None,
    seed=None,
    *,
    omega: float | None = None,
    pair_samples: int | None = None,
    ess_fraction: float = 0.2,
    max_restarts: int = 3,
    omega_tol: float = OMEGA_TOL,
) -> MixtureFusion:
    """Fuse mixture ``b`` into mixture ``a`` with a WEP ``rule`` (``omega`` is the weight on ``a``).

    ``prior`` (the common prior mixture) is required by ``kld-weighted-chernoff`` and, when given,
    the information gains ``KL(a || prior)``, ``KL(b || prior)`` (Monte Carlo, ``4 n_samples`` draws
    each) are reported for every rule.
    ``omega`` fixes the weight and skips the search. ``n_samples`` fixes the omega search's draws
    (default: adaptive until omega's standard error is at most ``omega_tol``, see the module
    docstring). ``pair_samples`` is the number of importance samples per component pair for
    ``moment-match`` (default ``max(64, n_samples // 4)``).
    ``seed`` is an int or a numpy Generator. See the module docstring for rules and methods.
    """
    check_pair(a, b)
    a, b = _without_zero_weights(a), _without_zero_weights(b)
    rule = check_rule(rule)
    if method not in MIXTURE_METHODS:
        raise ValueError(
            f"unknown mixture fusion method {method!r}; valid methods are: {', '.join(MIXTURE_METHODS)}"
        )
    adaptive = n_samples is None
    n_samples = ADAPTIVE_START if adaptive else _count("n_samples", n_samples, 10)
    if pair_samples is not None:
        pair_samples = _count("pair_samples", pair_samples, 2)
    omega_tol = float(omega_tol)
    if not omega_tol > 0.0:
        raise ValueError(f"omega_tol must be positive; got {omega_tol}")
    if rule == "kld-weighted-chernoff" and prior is None and omega is None:
        raise ValueError("kld-weighted-chernoff needs the common prior mixture (prior=...)")
    if prior is not None:
        check_pair(a, prior)
    if omega is not None:
        omega = check_weight(omega)
    n_max = check_size(
        a, b, n_samples, pair_samples, method, ADAPTIVE_MAX if adaptive else n_samples
    )
    rng = as_rng(seed)
    info_a = info_b = math.nan
    if prior is not None:
        info_a = _estimate_info(a, prior, 4 * n_samples, rng)
        info_b = _estimate_info(b, prior, 4 * n_samples, rng)
    nb, log_z_nb, _ = product(a, b)

    if rule == "naive-bayes" and omega is None:
        fused = _finite(runnalls_reduce(nb, max_components))
        return MixtureFusion(
            fused,
            math.nan,
            rule,
            method,
            math.nan,
            n_samples,
            0,
            math.nan,
            math.nan,
            0.0,
            info_a,
            info_b,
        )

    while True:
        x_nb = nb.sample(n_samples, rng)
        nb_a, nb_b = a.logpdf(x_nb), b.logpdf(x_nb)
        nb_diff, nb_log_a, nb_log_b = nb_a - nb_b, float(np.mean(nb_a)), float(np.mean(nb_b))
        w, x, costs, restarts = search_omega(
            a,
            b,
            rule,
            n_samples,
            rng,
            nb_mean_diff=nb_log_a - nb_log_b,
            info_a=info_a,
            info_b=info_b,
            omega=omega,
            ess_fraction=ess_fraction,
            max_restarts=max_restarts,
        )
        std_error = (
            0.0 if omega is not None else _omega_std_error(costs, rule, nb_diff, info_a, info_b)
        )
        if not adaptive or std_error <= omega_tol or n_samples >= n_max:
            break
        # the count the standard error asks for (it falls as 1 / sqrt(n)), at least doubled
        wanted = (
            n_samples * (std_error / omega_tol) ** 2 * 1.2 if math.isfinite(std_error) else n_max
        )
        n_samples = int(min(max(wanted, 2 * n_samples), n_max))
    if costs.flat or w == 1.0:  # equal densities (p_w is either of them for every w), or w = 1
        fused = a
    elif w == 0.0:
        fused = b
    elif method == "foci":
        fused = foci(a, b, w)
    elif method == "em":
        init = runnalls_reduce(foci(a, b, w), max_components)
        fused = weighted_em(x, costs.weights(w), init)
    else:
        n_pair = pair_samples if pair_samples is not None else max(64, n_samples // 4)
        fused = moment_match(a, b, w, n_pair, rng)
    fused = _finite(runnalls_reduce(fused, max_components))
    return MixtureFusion(
        fused,
        float(w),
        rule,
        method,
        costs.ess(w),
        n_samples,
        restarts,
        costs.kl_to_a(w),
        costs.kl_to_b(w),
        costs.info_loss(w, nb_log_a, nb_log_b, log_z_nb),
        info_a,
        info_b,
        std_error,
    )


def _count(name: str, value, least: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer, float, np.floating)):
        raise TypeError(f"{name} must be an integer; got {type(value).__name__}")
    if not (math.isfinite(float(value)) and float(value) == int(value)):
        raise ValueError(f"{name} must be a whole number; got {value!r}")
    if int(value) < least:
        raise ValueError(f"{name} must be at least {least}; got {int(value)}")
    return int(value)


def _memory() -> float:
    try:
        return float(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError):
        return float("inf")


def check_size(
    a: M, b: M, n_samples: int, pair_samples: int | None, method: str, n_max: int
) -> int:
    """Refuse, before any work, a fusion of ``a`` and ``b`` too large to finish: more than
    ``MAX_PAIRS`` component pairs, or arrays of more than half of the machine's memory with
    ``n_samples`` draws (``ValueError`` naming the argument). Returns the largest draw count
    (at most ``n_max``) that fits."""
    ma, mb, d = a.n_components, b.n_components, a.dim
    pairs = ma * mb
    if pairs > MAX_PAIRS:
        raise ValueError(
            f"a has {ma} components and b {mb}: fusing them needs {pairs} component pairs, more than "
            f"{MAX_PAIRS}; reduce them first (GaussianMixture.reduce(k), k * k <= {MAX_PAIRS})"
        )
    budget = 0.5 * _memory()

    def need(n: int) -> float:  # the largest arrays alive at once, float64, with temporaries
        search = 8.0 * n * (pairs + ma + mb) * (d + 2)
        n_pair = pair_samples if pair_samples is not None else max(64, n // 4)
        match = 8.0 * pairs * n_pair * (ma + mb) * (d + 2) if method == "moment-match" else 0.0
        return max(search, match, 8.0 * pairs * pairs)

    if need(n_samples) > budget:
        what = (
            "pair_samples"
            if pair_samples is not None
            and method == "moment-match"
            and need(n_samples) > 8.0 * n_samples * (pairs + ma + mb) * (d + 2)
            else "n_samples"
        )
        raise ValueError(
            f"fusing a ({ma} components) and b ({mb}) with n_samples={n_samples} needs about "
            f"{need(n_samples) / 1e9:.3g} GB, more than half of this machine's {2 * budget / 1e9:.3g} GB; "
            f"lower {what} or reduce the mixtures first"
        )
    while n_max > n_samples and need(n_max) > budget:
        n_max //= 2
    return max(n_max, n_samples)


def _omega_std_error(costs, rule, nb_diff, info_a, info_b) -> float:
    """Standard error of the chosen omega: the spread of the omegas of ``BATCHES`` disjoint
    batches of the samples (each with its batch of the naive-Bayes draws) over sqrt(BATCHES)."""
    if rule == "bhattacharyya" or costs.flat:
        return 0.0
    n = min(costs.n, len(nb_diff)) // BATCHES * BATCHES
    omegas = []
    for k in range(BATCHES):
        idx = np.arange(k, n, BATCHES)
        try:
            omegas.append(
                choose_omega(costs.subset(idx), rule, float(np.mean(nb_diff[idx])), info_a, info_b)
            )
        except ValueError:  # a batch without finite costs
            return math.inf
    return float(np.std(omegas, ddof=1) / math.sqrt(BATCHES))


def _finite(m: M) -> M:
    if not (
        np.all(np.isfinite(m.weights))
        and np.all(np.isfinite(m.means))
        and np.all(np.isfinite(m.covariances))
    ):
        raise ValueError("the fused mixture is not finite (the inputs' scales overflow float64)")
    return m
