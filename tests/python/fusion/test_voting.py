"""Robust fusion by voting: hand-made networks with known inliers, baselines, hypothesis count,
the static-voting residual covariance, consensus primitives and input errors."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from doc_figures import assert_as_printed, quoted
from octofuse.fusion.consensus import estimates, metropolis_weights, select_seeds
from octofuse.fusion.voting import ChiSquareGate, dynamic_vote, hypothesis_count
from octofuse.fusion.voting_baselines import maximum_likelihood, residual_covariance, static_vote
from octofuse.fusion.voting_checks import paper_checks

N_IN = 6
RING = [(i, (i + 1) % 8) for i in range(8)]
EVEN = [(0, 1), (2, 3), (4, 5), (6, 7)]  # alternate with ODD: jointly a ring, never connected alone
ODD = [(1, 2), (3, 4), (5, 6), (7, 0)]


def network(seed=0):
    """Six inliers near (1, 2) and two outliers far away, with random covariances."""
    rng = np.random.default_rng(seed)
    x = np.vstack([rng.normal([1.0, 2.0], 0.2, (N_IN, 2)), [[9.0, 9.0], [-8.0, 4.0]]])
    cov = np.array([np.diag(rng.uniform(0.05, 0.2, 2)) for _ in range(8)])
    return x, cov


def ml(x, cov):
    info = np.linalg.inv(cov)
    return np.linalg.solve(info.sum(0), np.einsum("nij,nj->i", info, x))


TRUE_INLIERS = np.arange(8) < N_IN


def test_hypothesis_count_matches_the_paper():
    assert hypothesis_count(0.6, 0.99, 1) == 6
    assert hypothesis_count(0.8, 0.99, 1) == 3
    assert hypothesis_count(0.5, 0.99, 2) == math.ceil(math.log(0.01) / math.log(0.75))


@given(st.floats(0.05, 0.95), st.floats(0.5, 0.999), st.integers(1, 4))
def test_hypothesis_count_is_the_smallest_that_succeeds(p_in, success, c):
    k = hypothesis_count(p_in, success, c)
    assert 1 - (1 - p_in**c) ** k >= success - 1e-12
    if k > 1:
        assert 1 - (1 - p_in**c) ** (k - 1) < success + 1e-12


@pytest.mark.parametrize(
    "edges, iterations",
    [(RING, 150), (lambda t: EVEN if t % 2 else ODD, 400)],
    ids=["fixed", "switching"],
)
def test_dynamic_vote_finds_the_inliers(edges, iterations):
    x, cov = network()
    res = dynamic_vote(x, cov, edges, seed_sets=[[6], [2], [7]], iterations=iterations)
    assert res.winner == 1 and np.all(res.robot_winner == 1)
    np.testing.assert_array_equal(res.inliers, TRUE_INLIERS)
    np.testing.assert_allclose(
        res.estimate, np.broadcast_to(ml(x[:N_IN], cov[:N_IN]), (8, 2)), atol=1e-6
    )
    np.testing.assert_allclose(res.votes[1], N_IN / 8, atol=1e-6)
    assert res.votes[0].max() < 0.5 and res.votes[2].max() < 0.5  # outlier-seeded hypotheses lose


def test_dynamic_vote_with_random_seeds_is_reproducible():
    x, cov = network(1)
    a = dynamic_vote(x, cov, RING, p_in=0.6, seed=5)
    b = dynamic_vote(x, cov, RING, p_in=0.6, seed=5)
    assert a.hypotheses == 6 and a.seeds.shape == (6, 8) and np.all(a.seeds.sum(axis=1) == 1)
    np.testing.assert_array_equal(a.inliers, b.inliers)
    np.testing.assert_array_equal(a.estimate, b.estimate)
    np.testing.assert_array_equal(a.inliers, TRUE_INLIERS)


def test_dynamic_vote_history_and_traffic():
    x, cov = network()
    res = dynamic_vote(x, cov, RING, seed_sets=[[0], [7]], iterations=20, record=True)
    assert res.history["votes"].shape == (21, 2, 8)
    assert res.history["estimates"].shape == (21, 2, 8, 2)
    assert res.rounds == 20 and res.messages == 20 * 2 * len(RING)
    assert res.floats == res.messages * 2 * (3 + 2 + 1)  # per hypothesis: symmetric P, q, v
    assert res.bytes == 8 * res.floats
    np.testing.assert_array_equal(res.history["votes"][0], res.seeds.astype(float))


def test_seed_selection_costs_diameter_rounds():
    x, cov = network()
    res = dynamic_vote(x, cov, RING, p_in=0.8, c=2, iterations=5, seed=3)
    assert res.rounds == 4 + 5  # diam(C8) = 4
    assert np.all(res.seeds.sum(axis=1) == 2)


def test_static_vote_and_maximum_likelihood_baselines():
    x, cov = network()
    st_res = static_vote(x, cov, RING, seed_sets=[[6], [3]], iterations=150)
    np.testing.assert_array_equal(st_res.inliers, TRUE_INLIERS)
    assert st_res.rounds == 450
    np.testing.assert_allclose(st_res.estimate[0], ml(x[:N_IN], cov[:N_IN]), atol=1e-6)
    full = maximum_likelihood(x, cov, RING, iterations=200)
    assert full.inliers.all()
    np.testing.assert_allclose(full.estimate, np.broadcast_to(ml(x, cov), (8, 2)), atol=1e-6)


def test_residual_covariance_by_monte_carlo():
    rng = np.random.default_rng(0)
    d, n, samples = 2, 5, 200_000
    a = rng.normal(size=(n, d, d))
    cov = a @ np.swapaxes(a, 1, 2) + 0.3 * np.eye(d)
    info = np.linalg.inv(cov)
    members = np.array([True, True, True, False, False])
    cov_ml = np.linalg.inv(info[members].sum(0))
    e = np.einsum("nij,snj->sni", np.linalg.cholesky(cov), rng.normal(size=(samples, n, d)))
    theta = np.einsum(
        "ij,sj->si", cov_ml, np.einsum("nij,snj->sni", info[members], e[:, members]).sum(1)
    )
    for i in (0, 4):
        emp = np.cov((e[:, i] - theta).T)
        expected = residual_covariance(cov[i], cov_ml, members[i])
        np.testing.assert_allclose(emp, expected, atol=0.02 * np.abs(expected).max())
    paper_eq9 = cov_ml + cov[0] - 2 * cov_ml @ info[0] @ cov_ml
    assert np.abs(paper_eq9 - np.cov((e[:, 0] - theta).T)).max() > 0.1 * np.abs(paper_eq9).max()


def test_gate_forms():
    m2 = np.array([9.0])  # Mahalanobis distance 3 in 2-D
    assert not ChiSquareGate(0.95, "squared").passes(m2, 2)[0]  # 9 > 5.99
    assert ChiSquareGate(0.95, "paper").passes(m2, 2)[0]  # 3 <= 5.99
    assert ChiSquareGate(0.95).threshold(2) == pytest.approx(5.991, abs=1e-3)


def test_singular_information_has_no_estimate():
    p = np.zeros((1, 2, 2, 2))
    p[0, 1] = np.eye(2)
    theta, valid = estimates(p, np.ones((1, 2, 2)), np.array([1e-9]))
    assert valid.tolist() == [[False, True]]
    assert np.isnan(theta[0, 0]).all() and np.allclose(theta[0, 1], 1.0)


@settings(max_examples=30, deadline=None)
@given(st.integers(2, 9), st.floats(0.1, 0.9), st.integers(0, 2**16))
def test_metropolis_weights_are_doubly_stochastic(n, p, seed):
    rng = np.random.default_rng(seed)
    upper = np.triu(rng.random((n, n)) < p, 1)
    w = metropolis_weights((upper | upper.T)[None])[0]
    np.testing.assert_allclose(w.sum(0), 1.0)
    np.testing.assert_allclose(w, w.T)
    assert np.all(w >= 0)


def test_max_consensus_picks_the_largest_numbers():
    rng = np.random.default_rng(2)
    adj = np.zeros((8, 8), dtype=bool)
    for i, j in RING:
        adj[i, j] = adj[j, i] = True
    numbers = rng.random((1, 3, 8))
    seeds, rounds, messages = select_seeds(numbers, 2, lambda t: adj[None], None, 100)
    top2 = np.argsort(-numbers, axis=-1)[..., :2]
    for h in range(3):
        assert set(np.flatnonzero(seeds[0, h])) == set(top2[0, h])
    assert rounds <= 4 and messages[0] == rounds * 16


@pytest.mark.parametrize(
    "change, match",
    [
        (dict(x=np.zeros((8, 2, 1))), "x must have shape"),
        (dict(covariances=np.ones((8, 3, 3))), "covariances must have shape"),
        (dict(covariances=np.tile(np.diag([1.0, -1.0]), (8, 1, 1))), "not positive definite"),
        (dict(covariances=np.tile([[1.0, 0.5], [0.0, 1.0]], (8, 1, 1))), "not symmetric"),
        (dict(x=np.full((8, 2), np.nan)), "non-finite"),
        (dict(p_in=1.5), "p_in"),
        (dict(success=1.0), "success"),
        (dict(c=0), "c must be"),
        (dict(c=9), "c = 9"),
        (dict(iterations=-1), "iterations"),
        (dict(edges=[(0, 8)]), "outside 0..7"),
        (dict(edges=[(3, 3)]), "self-loop"),
        (dict(edges=[(0, 1)]), "disconnected"),
        (dict(seed_sets=[[0], [12]]), "seed_sets"),
    ],
)
def test_bad_input_raises_a_clear_error(change, match):
    x, cov = network()
    kwargs = dict(x=x, covariances=cov, edges=RING, seed=0) | change
    with pytest.raises(ValueError, match=match):
        dynamic_vote(**kwargs)


def test_bad_gate_raises():
    with pytest.raises(ValueError, match="gate form"):
        ChiSquareGate(0.95, "sqrt")
    with pytest.raises(ValueError, match="confidence"):
        ChiSquareGate(1.2)


@pytest.mark.slow
def test_paper_checks_give_the_figures_the_docs_quote():
    """`benchmarks/voting_paper_checks.py` (1000 trials, seed 0): the figures of docs/robust.md."""
    res = paper_checks(1000, 0)
    page = "docs/robust.md"
    fig3, table, fair = res["fig3"], res["table1"], res["table1_consistent"]
    figures, measured = {}, {}

    def expect(names, pattern, values):
        figures.update(zip(names, quoted(page, pattern)))
        measured.update(zip(names, values))

    counts = res["hypothesis_counts"]
    expect(
        ["K 0.6", "K 0.8"],
        r"K = # for p_in = 0\.6 and K = # for p_in = 0\.8",
        [counts["p_in=0.6"]["K"], counts["p_in=0.8"]["K"]],
    )
    expect(
        ["votes", "to ML"],
        r"votes converge to # for 7 of 10 inliers, the estimate to the maximum likelihood of the "
        r"inliers to (\d)e-14",
        [min(fig3["winner_votes"]), fig3["max_estimate_error_to_ml_inliers"] * 1e14],
    )
    assert max(fig3["winner_votes"]) == pytest.approx(min(fig3["winner_votes"]), abs=1e-12)
    assert fig3["inliers_found"]
    ml, static, dynamic = table["ml"], table["static[paper]"], table["dynamic[paper]"]
    paper = table["paper"]
    expect(
        ["ml error", "paper ml error", "ml fp", "paper ml fp"],
        r"error # against #, false positives # against #",
        [ml["mean_error"], paper["ml"]["mean_error"], ml["false_positives"]]
        + [paper["ml"]["false_positives"]],
    )
    expect(
        ["dyn fp", "paper dyn fp", "dyn fn", "paper dyn fn", "static fn", "paper static fn"],
        r"dynamic voting's false positives match \(# against #\), but its false negatives do "
        r"not \(# against #\), nor static voting's \(# against #\)",
        [dynamic["false_positives"], paper["dynamic"]["false_positives"]]
        + [dynamic["false_negatives"], paper["dynamic"]["false_negatives"]]
        + [static["false_negatives"], paper["static"]["false_negatives"]],
    )
    expect(
        ["oracle fn"],
        r"maximum likelihood of the true inliers rejects #\.",
        [table["oracle[paper]"]["false_negatives"]],
    )
    expect(
        ["fair static", "fair dynamic"],
        r"errors of # \(static\) and # \(dynamic\)",
        [fair["static[squared]"]["mean_error"], fair["dynamic[squared]"]["mean_error"]],
    )
    assert_as_printed(measured, figures, page)
