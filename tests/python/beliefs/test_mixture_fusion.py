"""Gaussian-mixture WEP fusion: defining properties checked by integration on a 2-D grid."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.special import logsumexp
from scipy.stats import multivariate_normal

from doc_figures import assert_as_printed, benchmark, quoted
from octofuse.beliefs.base import Belief
from octofuse.beliefs.gaussian import Gaussian
from octofuse.beliefs.mixture import GaussianMixture
from octofuse.beliefs.mixture_algebra import foci, product
from octofuse.beliefs.mixture_fusion import fuse_mixtures, search_omega
from octofuse.beliefs.mixture_grid import Grid2D, grid_fuse
from octofuse.beliefs.mixture_omega import WepCosts
from octofuse.beliefs.mixture_reduction import runnalls_reduce

W_GRID = np.linspace(0.0, 1.0, 101)


def random_mixture(seed, m=3, offset=(0.0, 0.0), spread=3.0):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(m, 2, 2)) * 0.7
    cov = a @ np.swapaxes(a, 1, 2) + 0.2 * np.eye(2)
    return GaussianMixture(
        rng.uniform(0.2, 1.0, m), rng.uniform(-spread, spread, (m, 2)) + offset, cov
    )


class GridTruth:
    """Densities on a grid from scipy's Gaussians, independent of the library's evaluation."""

    def __init__(self, *mixtures, n=200):
        self.grid = Grid2D.covering(*mixtures, n=n)
        self.pts = self.grid.points
        self.dA = self.grid.cell_area

    def log_pdf(self, mix):
        comps = [
            np.log(w) + multivariate_normal(m, c).logpdf(self.pts)
            for w, m, c in zip(mix.weights, mix.means, mix.covariances)
        ]
        return logsumexp(comps, axis=0)

    def normalise(self, log_p):
        return log_p - logsumexp(log_p) - np.log(self.dA)

    def kl(self, log_p, log_q):
        log_p, log_q = self.normalise(log_p), self.normalise(log_q)
        return float(np.sum(np.exp(log_p) * (log_p - log_q)) * self.dA)

    def wep(self, la, lb, w):
        return self.normalise(w * la + (1 - w) * lb)


# -- the mixture type ------------------------------------------------------------------------


def test_pdf_matches_independent_evaluation_and_integrates_to_one():
    mix = random_mixture(1)
    truth = GridTruth(mix)
    np.testing.assert_allclose(mix.logpdf(truth.pts), truth.log_pdf(mix), rtol=1e-9, atol=1e-9)
    assert np.sum(mix.pdf(truth.pts)) * truth.dA == pytest.approx(1.0, abs=2e-3)
    assert isinstance(mix, Belief)


def test_sample_moments_match_moments():
    mix = random_mixture(2)
    x = mix.sample(200_000, seed=0)
    mean, cov = mix.moments()
    np.testing.assert_allclose(x.mean(0), mean, atol=0.03)
    np.testing.assert_allclose(np.cov(x.T), cov, atol=0.08)


@pytest.mark.parametrize(
    "weights, means, covs, match",
    [
        ([1.0], [[0.0, 0.0]], [[[1.0, 1.0], [1.0, 1.0]]], "positive definite"),
        ([1.0], [[0.0, 0.0]], [[[1.0, 0.5], [0.0, 1.0]]], "symmetric"),
        ([-1.0, 2.0], [[0, 0], [1, 1]], [np.eye(2), np.eye(2)], "non-negative"),
        ([1.0], [[0.0, np.nan]], [np.eye(2)], "finite"),
        ([1.0, 1.0], [[0.0, 0.0]], [np.eye(2)], "shape"),
        ([], np.zeros((0, 2)), np.zeros((0, 2, 2)), "at least one"),
    ],
)
def test_invalid_mixtures_raise_clear_errors(weights, means, covs, match):
    with pytest.raises(ValueError, match=match):
        GaussianMixture(weights, means, covs)


def test_product_is_the_normalised_naive_bayes_density():
    a, b = random_mixture(3), random_mixture(4, offset=(1.0, 0.5))
    truth = GridTruth(a, b)
    la, lb = truth.log_pdf(a), truth.log_pdf(b)
    nb, log_z, _ = product(a, b)
    np.testing.assert_allclose(nb.logpdf(truth.pts), truth.normalise(la + lb), atol=1e-3)
    assert log_z == pytest.approx(float(logsumexp(la + lb) + np.log(truth.dA)), abs=1e-3)


def test_runnalls_preserves_moments_and_bounds_the_size():
    mix = product(random_mixture(5, m=6), random_mixture(6, m=5))[0]
    small = runnalls_reduce(mix, 4)
    assert small.n_components == 4
    for got, want in zip(small.moments(), mix.moments()):
        np.testing.assert_allclose(got, want, atol=1e-9)
    assert runnalls_reduce(small, 10) is small


# -- the rules' defining properties --------------------------------------------------------


def test_single_gaussians_reduce_to_covariance_intersection():
    a = GaussianMixture.gaussian([0.0, 0.0], [[2.0, 0.3], [0.3, 0.5]])
    b = GaussianMixture.gaussian([1.5, -1.0], [[0.4, -0.1], [-0.1, 1.5]])
    res = fuse_mixtures(a, b, rule="chernoff", n_samples=2000, seed=0, pair_samples=20_000)
    w = res.omega
    info = w * np.linalg.inv(a.covariances[0]) + (1 - w) * np.linalg.inv(b.covariances[0])
    ci_cov = np.linalg.inv(info)
    ci_mean = ci_cov @ (
        w * np.linalg.solve(a.covariances[0], a.means[0])
        + (1 - w) * np.linalg.solve(b.covariances[0], b.means[0])
    )
    mean, cov = res.mixture.moments()
    np.testing.assert_allclose(mean, ci_mean, atol=0.02)
    np.testing.assert_allclose(cov, ci_cov, atol=0.02)
    exact = foci(a, b, w)
    np.testing.assert_allclose(exact.covariances[0], ci_cov, rtol=1e-10)
    np.testing.assert_allclose(exact.means[0], ci_mean, rtol=1e-10, atol=1e-12)


def test_chernoff_equalises_the_two_klds():
    a, b = random_mixture(7), random_mixture(8, offset=(1.0, 0.0))
    truth = GridTruth(a, b)
    la, lb = truth.log_pdf(a), truth.log_pdf(b)
    w = fuse_mixtures(a, b, rule="chernoff", n_samples=4000, seed=1, method="foci").omega
    lw = truth.wep(la, lb, w)
    kl_a, kl_b = truth.kl(lw, la), truth.kl(lw, lb)
    assert abs(kl_a - kl_b) < 0.1 * (kl_a + kl_b)
    weps = [truth.wep(la, lb, v) for v in W_GRID]
    gap = [abs(truth.kl(lv, la) - truth.kl(lv, lb)) for lv in weps]
    assert abs(w - W_GRID[int(np.argmin(gap))]) < 0.04


def test_min_info_loss_minimises_kl_from_naive_bayes():
    a, b = random_mixture(9), random_mixture(10, offset=(0.5, 1.0))
    truth = GridTruth(a, b)
    la, lb = truth.log_pdf(a), truth.log_pdf(b)
    loss = np.array([truth.kl(la + lb, w * la + (1 - w) * lb) for w in W_GRID])
    w = fuse_mixtures(a, b, rule="min-info-loss", n_samples=4000, seed=2, method="foci").omega
    best = W_GRID[int(np.argmin(loss))]
    assert 0.0 < best < 1.0  # an interior minimum, so the check is not trivial
    assert abs(w - best) < 0.04
    assert truth.kl(la + lb, w * la + (1 - w) * lb) < loss.min() + 0.01 * (loss.max() - loss.min())


def test_kld_weighted_chernoff_balances_weighted_klds():
    prior = random_mixture(11, m=2, spread=1.0)
    a, b = random_mixture(12), random_mixture(13, offset=(1.0, 1.0))
    truth = GridTruth(a, b, prior)
    la, lb, l0 = truth.log_pdf(a), truth.log_pdf(b), truth.log_pdf(prior)
    ca, cb = truth.kl(la, l0), truth.kl(lb, l0)
    w = fuse_mixtures(
        a, b, rule="kld-weighted-chernoff", prior=prior, n_samples=4000, seed=3, method="foci"
    ).omega
    grid_gap = [
        abs(ca * truth.kl(truth.wep(la, lb, v), la) - cb * truth.kl(truth.wep(la, lb, v), lb))
        for v in W_GRID
    ]
    assert abs(w - W_GRID[int(np.argmin(grid_gap))]) < 0.05


def test_importance_sampling_estimates_converge_to_grid_values():
    a, b = random_mixture(14), random_mixture(15, offset=(1.5, 0.0))
    truth = GridTruth(a, b, n=320)
    la, lb = truth.log_pdf(a), truth.log_pdf(b)
    w = 0.3
    log_c_grid = float(logsumexp(w * la + (1 - w) * lb) + np.log(truth.dA))
    w_grid = grid_fuse(a, b, "chernoff", truth.grid).omega
    errors = {}
    for n in (100, 10_000):
        err_c, err_w = [], []
        for seed in range(6):
            rng = np.random.default_rng(seed)
            w_is, _, costs, _ = search_omega(a, b, "chernoff", n, rng)
            err_c.append(costs.log_c(w) - log_c_grid)
            err_w.append(w_is - w_grid)
        errors[n] = (np.sqrt(np.mean(np.square(err_c))), np.sqrt(np.mean(np.square(err_w))))
    assert errors[10_000][0] < 0.5 * errors[100][0] and errors[10_000][0] < 0.02
    assert errors[10_000][1] < 0.5 * errors[100][1] and errors[10_000][1] < 0.02


def test_moment_matching_is_closer_to_the_true_wep_than_foci():
    a, b = random_mixture(16, m=4), random_mixture(17, m=4, offset=(1.0, -1.0))
    truth = GridTruth(a, b)
    la, lb = truth.log_pdf(a), truth.log_pdf(b)
    kls = {}
    for method in ("moment-match", "em", "foci"):
        res = fuse_mixtures(a, b, rule="bhattacharyya", method=method, seed=4, max_components=16)
        kls[method] = truth.kl(truth.wep(la, lb, 0.5), res.mixture.logpdf(truth.pts))
    assert kls["moment-match"] < kls["foci"]
    assert kls["moment-match"] < 0.05


def test_belief_wep_matches_the_grid_wep_at_a_fixed_weight():
    a, b = random_mixture(23), random_mixture(24, offset=(1.0, 0.0))
    truth = GridTruth(a, b)
    fused = a.wep(b, 0.3, seed=0)
    exact = truth.wep(truth.log_pdf(a), truth.log_pdf(b), 0.3)
    assert truth.kl(exact, fused.logpdf(truth.pts)) < 0.03
    assert truth.kl(exact, a.foci(b, 0.3).logpdf(truth.pts)) > truth.kl(
        exact, fused.logpdf(truth.pts)
    )


@settings(max_examples=12, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    m_a=st.integers(1, 3),
    m_b=st.integers(1, 3),
    rule=st.sampled_from(
        ["naive-bayes", "bhattacharyya", "chernoff", "min-info-loss", "min-entropy"]
    ),
    method=st.sampled_from(["moment-match", "em", "foci"]),
)
def test_fused_mixtures_are_valid(seed, m_a, m_b, rule, method):
    a, b = random_mixture(seed, m=m_a), random_mixture(seed + 1, m=m_b, offset=(2.0, 0.0))
    res = fuse_mixtures(a, b, rule=rule, method=method, n_samples=300, max_components=4, seed=seed)
    mix = res.mixture
    assert mix.n_components <= 4
    assert mix.weights.sum() == pytest.approx(1.0, abs=1e-12)
    assert np.all(np.linalg.eigvalsh(mix.covariances) > 0)
    assert np.isnan(res.omega) if rule == "naive-bayes" else 0.0 <= res.omega <= 1.0
    assert np.all(np.isfinite(mix.logpdf(a.means)))


# -- degenerate inputs ---------------------------------------------------------------------


def test_identical_mixtures_fuse_to_themselves():
    a = random_mixture(18)
    truth = GridTruth(a)
    for rule in ("chernoff", "min-info-loss", "bhattacharyya"):
        res = fuse_mixtures(a, a, rule=rule, seed=0)
        assert res.omega == 0.5
        assert truth.kl(truth.log_pdf(a), res.mixture.logpdf(truth.pts)) < 1e-6


def test_disjoint_supports_with_underflowing_densities_give_finite_results():
    a = GaussianMixture([0.5, 0.5], [[0.0, 0.0], [0.0, 1.0]], [np.eye(2) * 0.1] * 2)
    b = GaussianMixture.gaussian([400.0, 0.0], np.eye(2) * 0.1)
    assert a.pdf(b.means[0]) == 0.0 and b.pdf(a.means[0]) == 0.0  # they underflow
    for rule in ("naive-bayes", "chernoff", "min-info-loss", "kld-weighted-chernoff"):
        res = fuse_mixtures(
            a,
            b,
            rule=rule,
            prior=GaussianMixture.gaussian([200.0, 0.0], np.eye(2) * 1e4),
            n_samples=500,
            seed=0,
        )
        mean, cov = res.mixture.moments()
        assert np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))
        # x is independent of y in both inputs, with variance 0.1: the x-part of a^w b^(1-w) is
        # N((1-w) 400, 0.1) exactly, and of the product a b N(200, 0.05)
        if rule == "naive-bayes":
            assert mean[0] == pytest.approx(200.0, abs=1e-9) and cov[0, 0] == pytest.approx(0.05)
            # a's components at y = 0 and 1 weighted by N(0; 0, 0.2) and N(1; 0, 0.2), each
            # product component at half its y
            odds = np.exp(-1.0 / 0.4)
            assert mean[1] == pytest.approx(0.5 * odds / (1.0 + odds), rel=1e-6)
        else:
            assert 0.0 <= res.omega <= 1.0
            assert mean[0] == pytest.approx(400.0 * (1.0 - res.omega), abs=0.05)


def test_weights_at_the_end_points_return_one_side():
    a, b = random_mixture(19), random_mixture(20)
    assert (
        fuse_mixtures(a, b, omega=1.0, rule="chernoff").mixture.means.tolist() == a.means.tolist()
    )
    assert (
        fuse_mixtures(a, b, omega=0.0, rule="chernoff").mixture.means.tolist() == b.means.tolist()
    )


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"rule": "entropy-weighted-chernoff"}, "negative"),
        ({"rule": "kld-weighted-chernoff"}, "prior"),
        ({"rule": "nope"}, "valid rules"),
        ({"method": "nope"}, "valid methods"),
        ({"n_samples": 3}, "n_samples"),
    ],
)
def test_bad_arguments_raise_clear_errors(kwargs, match):
    a, b = random_mixture(21), random_mixture(22)
    with pytest.raises(ValueError, match=match):
        fuse_mixtures(a, b, **kwargs)


def test_dimension_mismatch_raises():
    with pytest.raises(ValueError, match="dimension"):
        fuse_mixtures(random_mixture(1), GaussianMixture.gaussian([0.0], [[1.0]]))


def test_operations_keep_the_class_of_their_input_and_refuse_other_beliefs():
    class Tagged(GaussianMixture):  # a user's subclass: every result must stay one
        __slots__ = ()

    a, b = (
        Tagged(m.weights, m.means, m.covariances) for m in (random_mixture(5), random_mixture(6))
    )
    results = [
        product(a, b)[0],
        foci(a, b, 0.3),
        runnalls_reduce(product(a, b)[0], 2),
        a.reduce(1),
        a.multiply(b),
        a.wep(b, 0.4, seed=0),
    ]
    results += [
        fuse_mixtures(a, b, rule=r, method=m, seed=1).mixture
        for r in ("naive-bayes", "chernoff")
        for m in ("moment-match", "em", "foci")
    ]
    assert all(type(m) is Tagged for m in results)
    gaussian = Gaussian.from_moments([0.0, 0.0], np.eye(2))
    for call in (
        lambda: product(a, gaussian),
        lambda: foci(gaussian, a, 0.5),
        lambda: fuse_mixtures(a, gaussian),
    ):
        with pytest.raises(TypeError, match="GaussianMixture"):
            call()


def test_wep_costs_reject_non_finite_log_densities():
    with pytest.raises(ValueError, match="finite"):
        WepCosts(np.array([0.0, -np.inf]), np.zeros(2), np.zeros(2))


# -- accuracy against closed forms, bounds, argument contracts ---------------------------------
from scipy.optimize import minimize_scalar  # noqa: E402

from octofuse.beliefs.mixture_fusion import MAX_PAIRS  # noqa: E402


def _wep_1d(w, ma=0.0, va=1.0, mb=2.0, vb=4.0):
    """Mean, variance and log normaliser of N(ma, va)^w N(mb, vb)^(1-w), exactly."""
    lam = w / va + (1 - w) / vb
    eta = w * ma / va + (1 - w) * mb / vb
    log_c = (
        -0.5 * (w * ma * ma / va + (1 - w) * mb * mb / vb - eta * eta / lam)
        + 0.5 * np.log(2 * np.pi / lam)
        - 0.5 * w * np.log(2 * np.pi * va)
        - 0.5 * (1 - w) * np.log(2 * np.pi * vb)
    )
    return eta / lam, 1 / lam, log_c


def _closed_form(rule):
    if rule == "chernoff":
        cost = lambda w: _wep_1d(w)[2]  # noqa: E731
    else:  # KL(p_NB || p_w), p_NB = N(0.4, 0.8)

        def cost(w):
            m, v, _ = _wep_1d(w)
            return 0.5 * np.log(v / 0.8) + (0.8 + (0.4 - m) ** 2) / (2 * v) - 0.5

    w = minimize_scalar(cost, bounds=(0, 1), method="bounded", options={"xatol": 1e-10}).x
    return w, _wep_1d(w)[1]


def reliability_figures() -> dict[str, tuple[str, int]]:
    """docs/reliability.md's variance errors (percent, as printed) and seed counts, per rule."""
    chernoff, mil, n_chernoff, n_mil = quoted(
        "docs/reliability.md",
        r"fused variance within #% for Chernoff, #% for min-info-loss, 1 sd over # and # seeds",
    )
    return {"chernoff": (chernoff, int(n_chernoff)), "min-info-loss": (mil, int(n_mil))}


@pytest.mark.parametrize("rule", ["chernoff", "min-info-loss"])
def test_default_samples_fuse_single_gaussians_to_the_closed_form_within_one_percent(rule):
    percent, seeds = reliability_figures()[rule]
    w_true, var_true = _closed_form(rule)
    if rule == "chernoff":
        assert w_true == pytest.approx(0.3522, abs=1e-4) and var_true == pytest.approx(
            1.9449, abs=1e-4
        )
    a, b = GaussianMixture.gaussian([0.0], [[1.0]]), GaussianMixture.gaussian([2.0], [[4.0]])
    res = [fuse_mixtures(a, b, rule=rule, seed=s) for s in range(seeds)]
    omega = np.array([r.omega for r in res])
    var = np.array([r.mixture.moments()[1][0, 0] for r in res])
    err = np.array([r.std_error for r in res])
    rel_sd = np.sqrt(np.mean((var / var_true - 1) ** 2))  # 1 sd, bias included
    assert rel_sd < 0.01
    assert_as_printed({"variance": 100 * rel_sd}, {"variance": percent}, "docs/reliability.md")
    assert np.sqrt(np.mean((omega - w_true) ** 2)) < 0.008
    assert np.all(
        (err > 0) & (err <= 0.005 + 1e-12) | (np.array([r.n_samples for r in res]) >= 1 << 15)
    )
    assert np.sqrt(np.mean((omega - w_true) ** 2)) < 3 * np.mean(err)  # the error it reports


def test_fixed_sample_counts_report_their_standard_error():
    a, b = GaussianMixture.gaussian([0.0], [[1.0]]), GaussianMixture.gaussian([2.0], [[4.0]])
    small, large = (fuse_mixtures(a, b, rule="chernoff", n_samples=n, seed=1) for n in (500, 8000))
    assert small.n_samples == 500 and large.n_samples == 8000
    assert small.std_error > large.std_error > 0
    assert fuse_mixtures(a, b, omega=0.3, seed=1).std_error == 0.0


def test_too_many_component_pairs_are_refused_before_any_work():
    k = int(np.sqrt(MAX_PAIRS)) + 1
    big = GaussianMixture(np.ones(k), np.arange(k, dtype=float)[:, None], np.ones((k, 1, 1)))
    with pytest.raises(ValueError, match=r"a has \d+ components and b \d+.*reduce") as info:
        fuse_mixtures(big, big, seed=0)
    assert str(k * k) in str(info.value)
    huge = GaussianMixture(np.ones(3000), np.arange(3000.0)[:, None], np.ones((3000, 1, 1)))
    with pytest.raises(ValueError, match="component pairs"):
        fuse_mixtures(huge, huge, seed=0)


def test_sample_counts_beyond_memory_are_refused_naming_the_argument():
    a = random_mixture(0, m=10)
    with pytest.raises(ValueError, match="n_samples=.*GB.*lower n_samples"):
        fuse_mixtures(a, a, n_samples=10**12, seed=0)
    with pytest.raises(ValueError, match="lower pair_samples"):
        fuse_mixtures(a, random_mixture(1, m=10), pair_samples=10**11, n_samples=100, seed=0)


@pytest.mark.parametrize(
    "kwargs,error,match",
    [
        ({"n_samples": 12.5}, ValueError, "n_samples"),
        ({"n_samples": "many"}, TypeError, "n_samples"),
        ({"n_samples": float("nan")}, ValueError, "n_samples"),
        ({"pair_samples": 1}, ValueError, "pair_samples"),
        ({"omega_tol": 0.0}, ValueError, "omega_tol"),
    ],
)
def test_bad_counts_name_the_argument(kwargs, error, match):
    with pytest.raises(error, match=match):
        fuse_mixtures(random_mixture(0), random_mixture(1), seed=0, **kwargs)


def test_from_dict_and_moments_refuse_with_value_errors():
    with pytest.raises(ValueError, match="covariances"):
        GaussianMixture.from_dict({"weights": [1.0], "means": [[0.0]]})
    with pytest.raises(TypeError, match="mapping"):
        GaussianMixture.from_dict([1.0])
    m = GaussianMixture([0.5, 0.5], [[1e308, 0.0], [-1e308, 0.0]], [np.eye(2)] * 2)
    with pytest.raises(ValueError, match="overflows"):
        m.moments()


def test_range_likelihood_refuses_ranges_whose_coefficients_overflow():
    from octofuse.beliefs.expoly import ExPoly2D

    for z, a in ((1e-200, 1.0), (1e200, 1.0), (1e-160, 1e300)):
        with pytest.raises(ValueError, match="measured_range"):
            ExPoly2D.range_likelihood([0.0, 0.0], z, a=a)


@pytest.mark.slow
def test_benchmark_accuracy_is_what_the_docs_quote():
    """`benchmarks/mixture_fusion.py`: each method's largest KL from the grid density over the
    rules, as docs/beliefs.md prints it (the times it prints are measured, not tested)."""
    rows = benchmark("mixture_fusion").measure(repeats=5, grid_n=400)
    worst = {
        m: max(r["kl_from_grid"] for r in rows if r["method"] == m)
        for m in ("moment-match", "em", "foci")
    }
    page = "docs/beliefs.md"
    figures = dict(
        zip(
            ["moment-match", "em", "foci"],
            quoted(
                page,
                r"is within # nats of the same fusion by grid integration \(400 x 400\).*?"
                r"by weighted EM within # \(in about the same time\), by FOCI alone within #",
            ),
        )
    )
    assert_as_printed(worst, figures, page)
