"""Defining properties of the per-voxel fusion rules (MATH.md), as property tests."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import octofuse
from octofuse import RULES, WEP_RULES, fuse_bernoulli, fuse_logodds

logodds = st.floats(min_value=-8.0, max_value=8.0, allow_nan=False)
probs = st.floats(min_value=1e-6, max_value=1 - 1e-6)
SYMMETRIC = [r for r in RULES if r != "min-entropy"]


def kl(lq, lp):
    """KL(q || p) of Bernoullis from log-odds, straight from the definition."""
    q, p = 1 / (1 + np.exp(-lq)), 1 / (1 + np.exp(-lp))
    return q * np.log(q / p) + (1 - q) * np.log((1 - q) / (1 - p))


def entropy(l):
    p = 1 / (1 + np.exp(-l))
    return -p * np.log(p) - (1 - p) * np.log(1 - p)


def distinct(a, b):
    return abs(a - b) > 1e-3


@given(logodds, logodds)
def test_chernoff_equalises_the_two_klds(la, lb):
    f = fuse_logodds(la, lb, rule="chernoff")
    assert kl(f.l, la) == pytest.approx(kl(f.l, lb), rel=1e-6, abs=1e-12)


@given(logodds, logodds)
def test_entropy_weighted_chernoff_equalises_the_weighted_klds(la, lb):
    f = fuse_logodds(la, lb, rule="entropy-weighted-chernoff")
    assert kl(f.l, la) / entropy(la) == pytest.approx(
        kl(f.l, lb) / entropy(lb), rel=1e-6, abs=1e-11
    )


@given(logodds.filter(lambda x: abs(x) > 1e-3))
def test_entropy_weighted_reduces_to_chernoff_at_equal_entropies(la):
    # l and -l have the same entropy
    e = fuse_logodds(la, -la, rule="entropy-weighted-chernoff")
    c = fuse_logodds(la, -la, rule="chernoff")
    assert e.omega == pytest.approx(c.omega, abs=1e-12)
    assert e.l == pytest.approx(c.l, abs=1e-12)


@given(logodds.filter(lambda x: abs(x) > 1e-2), logodds.filter(lambda x: abs(x) > 1e-2))
def test_kld_weighted_chernoff_equalises_information_weighted_klds(la, lb):
    f = fuse_logodds(la, lb, rule="kld-weighted-chernoff")
    ca, cb = kl(la, 0.0), kl(lb, 0.0)
    assert ca * kl(f.l, la) == pytest.approx(cb * kl(f.l, lb), rel=1e-6, abs=1e-12)


def test_kld_weighted_chernoff_takes_the_informed_map_when_the_other_learnt_nothing():
    f = fuse_logodds(0.0, 2.5, rule="kld-weighted-chernoff")
    assert f.omega == 0.0 and f.l == 2.5


@given(logodds, logodds)
def test_min_info_loss_has_no_smaller_loss_on_a_fine_grid(la, lb):
    f = fuse_logodds(la, lb, rule="min-info-loss")
    w = np.linspace(0.0, 1.0, 2001)
    losses = kl(la + lb, w * la + (1 - w) * lb)
    assert f.info_loss <= losses.min() + 1e-12
    assert f.info_loss == pytest.approx(kl(la + lb, f.l), abs=1e-12)


@given(logodds, logodds)
def test_min_info_loss_is_zero_exactly_when_the_log_odds_disagree_in_sign(la, lb):
    f = fuse_logodds(la, lb, rule="min-info-loss")
    if la * lb <= 0.0:
        assert f.info_loss == 0.0
    elif la + lb not in (la, lb) and min(abs(la), abs(lb)) > 1e-100:
        # l_NB distinguishable from both inputs, and the loss (~ l^2 / 8) not below the
        # smallest double
        assert f.info_loss > 0.0


@given(logodds, logodds)
def test_min_entropy_picks_the_lower_entropy_endpoint(la, lb):
    f = fuse_logodds(la, lb, rule="min-entropy")
    assert entropy(f.l) <= min(entropy(la), entropy(lb)) + 1e-12


@pytest.mark.parametrize("rule", WEP_RULES)
@given(la=logodds, lb=logodds)
def test_every_wep_result_lies_between_the_inputs(rule, la, lb):
    f = fuse_logodds(la, lb, rule=rule)
    assert min(la, lb) <= f.l <= max(la, lb)
    assert 0.0 <= f.omega <= 1.0
    assert f.info_loss >= 0.0


@pytest.mark.parametrize("rule", SYMMETRIC)
@given(la=logodds, lb=logodds)
def test_symmetric_rules_are_symmetric(rule, la, lb):
    """Bit for bit: both robots of a two-way exchange get the same value from one fusion."""
    f, g = fuse_logodds(la, lb, rule=rule), fuse_logodds(lb, la, rule=rule)
    assert f.l == g.l
    assert f.info_loss == g.info_loss
    if rule != "naive-bayes" and distinct(la, lb):
        assert f.omega == pytest.approx(1 - g.omega, abs=1e-6)


@pytest.mark.parametrize("rule", RULES)
def test_arrays_give_each_pair_what_it_gets_alone(rule):
    """The array kernels (Chernoff's packs of pairs) and the single-pair path give the same bits,
    in either order of the pair."""
    rng = np.random.default_rng(3)
    a, b = rng.uniform(-6, 6, 203), rng.uniform(-6, 6, 203)
    a[::17] = b[::17]  # equal pairs too
    for x, y in ((a, b), (b, a)):
        arr = fuse_logodds(x, y, rule=rule)
        for i in range(len(x)):
            one = fuse_logodds(float(x[i]), float(y[i]), rule=rule)
            assert (arr.l[i], arr.info_loss[i]) == (one.l, one.info_loss), i
            assert arr.omega[i] == one.omega or (np.isnan(arr.omega[i]) and np.isnan(one.omega))


@given(la=logodds, lb=logodds)
def test_naive_bayes_adds_log_odds_and_loses_nothing(la, lb):
    f = fuse_logodds(la, lb, rule="naive-bayes")
    assert f.l == la + lb and f.info_loss == 0.0 and np.isnan(f.omega)


@given(probs, probs)
@settings(max_examples=50)
def test_bernoulli_form_matches_log_odds_form(pa, pb):
    for rule in RULES:
        fb = fuse_bernoulli(pa, pb, rule=rule)
        fl = fuse_logodds(np.log(pa / (1 - pa)), np.log(pb / (1 - pb)), rule=rule)
        assert fb.p == pytest.approx(1 / (1 + np.exp(-fl.l)), rel=1e-9)


def test_chernoff_matches_the_papers_closed_form():
    pa, pb = 0.8, 0.3  # eq. (13) of the paper, with the signs restored
    A, B = np.log(pa / pb), np.log((1 - pa) / (1 - pb))
    p_star = B / (B - A)
    w = (np.log(p_star / (1 - p_star)) - np.log(pb / (1 - pb))) / (
        np.log(pa / (1 - pa)) - np.log(pb / (1 - pb))
    )
    assert fuse_bernoulli(pa, pb, rule="chernoff").omega == pytest.approx(w, rel=1e-12)


def test_prior_enters_naive_bayes():
    f = fuse_bernoulli(0.7, 0.7, rule="naive-bayes", prior=0.7)
    assert f.p == pytest.approx(0.7)


def test_arrays_broadcast_like_numpy():
    pa = np.linspace(0.05, 0.95, 12).reshape(3, 4)
    f = fuse_bernoulli(pa, 0.6, rule="chernoff")
    assert f.p.shape == f.omega.shape == f.info_loss.shape == (3, 4)
    g = fuse_bernoulli(pa[:, :1], np.full((1, 4), 0.6), rule="chernoff")
    np.testing.assert_allclose(g.p, fuse_bernoulli(np.repeat(pa[:, :1], 4, 1), 0.6, "chernoff").p)
    with pytest.raises(ValueError, match="cannot be broadcast"):
        fuse_bernoulli(np.zeros(3) + 0.5, np.zeros(4) + 0.5)


def test_certain_inputs_dominate():
    for rule in RULES:
        f = fuse_bernoulli([1.0, 0.0, 0.3], [0.4, 0.6, 1.0], rule=rule)
        np.testing.assert_array_equal(f.p, [1.0, 0.0, 1.0])
        np.testing.assert_array_equal(f.info_loss, [0.0, 0.0, 0.0])


def test_bad_inputs_are_clear_errors():
    with pytest.raises(ValueError, match=r"valid rules are: naive-bayes, .*min-info-loss"):
        fuse_bernoulli(0.5, 0.5, rule="chernof")
    with pytest.raises(ValueError, match=r"p_b is NaN at flat index 1"):
        fuse_bernoulli([0.5, 0.5], [0.5, np.nan])
    with pytest.raises(ValueError, match=r"p_a = 1.5.* not a probability"):
        fuse_bernoulli(1.5, 0.5)
    with pytest.raises(ValueError, match="contradictory certainties at flat index 0"):
        fuse_bernoulli(0.0, 1.0, rule="chernoff")
    with pytest.raises(ValueError, match="l_a is NaN"):
        fuse_logodds(np.nan, 1.0)
    with pytest.raises(ValueError, match="prior"):
        fuse_bernoulli(0.5, 0.5, prior=1.0)


def test_rules_list_is_complete():
    assert octofuse.RULES == (
        "naive-bayes",
        "bhattacharyya",
        "min-entropy",
        "chernoff",
        "entropy-weighted-chernoff",
        "kld-weighted-chernoff",
        "min-info-loss",
    )
