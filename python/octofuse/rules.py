"""Per-voxel fusion rules on numpy arrays (computed in the C++ core)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from . import _core
from .rule_names import CORE_RULES, FusionRule

#: The per-voxel fusion rules, in the order of the C++ core's ``Rule`` enum (the one source).
RULES: tuple[FusionRule, ...] = CORE_RULES

#: The weighted exponential product (WEP) rules, i.e. every rule but naive Bayes.
WEP_RULES: tuple[FusionRule, ...] = tuple(r for r in RULES if r != FusionRule.NAIVE_BAYES)


class BernoulliFusion(NamedTuple):
    """Result of :func:`fuse_bernoulli`: arrays of the broadcast input shape."""

    p: np.ndarray  #: fused occupancy probability
    omega: np.ndarray  #: WEP weight on ``p_a`` (NaN for naive-bayes)
    info_loss: np.ndarray  #: KL(p_NB || p_fused) in nats


class LogOddsFusion(NamedTuple):
    """Result of :func:`fuse_logodds`: arrays of the broadcast input shape."""

    l: np.ndarray  #: fused log-odds  # noqa: E741
    omega: np.ndarray  #: WEP weight on ``l_a`` (NaN for naive-bayes)
    info_loss: np.ndarray  #: KL(p_NB || p_fused) in nats


#: Policies for voxels only one map knows: keep its value, or fuse it with the prior.
UNKNOWN_POLICIES: tuple[str, ...] = tuple(_core.UNKNOWN_POLICY_NAMES)

Rule = _core.Rule
UnknownPolicy = _core.UnknownPolicy


def parse_rule(rule: str | FusionRule | Rule) -> Rule:
    """The core's :class:`Rule` for a rule name (a per-voxel :class:`FusionRule` hands its
    own); ``ValueError`` listing the valid names."""
    if isinstance(rule, Rule):
        return rule
    core = rule.core if isinstance(rule, FusionRule) else None
    return core if core is not None else _core.rule_from_name(str(rule))


def parse_unknown(policy: str | UnknownPolicy) -> UnknownPolicy:
    """The core's policy for voxels one map knows, from ``"copy"`` or ``"prior"``."""
    return (
        policy if isinstance(policy, UnknownPolicy) else _core.unknown_policy_from_name(str(policy))
    )


def _pair(a, b) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape:
        try:
            a, b = np.broadcast_arrays(a, b)
        except ValueError:
            raise ValueError(
                f"input shapes {a.shape} and {b.shape} cannot be broadcast together"
            ) from None
    # contiguous float64 inputs pass to C++ without a copy; broadcast views are copied once
    shape = a.shape
    return np.ascontiguousarray(a).reshape(shape), np.ascontiguousarray(b).reshape(shape)


def fuse_bernoulli(p_a, p_b, rule: str = "min-info-loss", prior: float = 0.5) -> BernoulliFusion:
    """Fuse occupancy probabilities element-wise with a fusion rule.

    Parameters
    ----------
    p_a, p_b : array_like
        Occupancy probabilities in [0, 1]; shapes broadcast like numpy.
    rule : str
        One of :data:`RULES`.
    prior : float
        The common prior probability p_0 (0.5 for OctoMap); used by naive-bayes
        (``l = l_a + l_b - l_0``), min-info-loss and kld-weighted-chernoff.

    Returns
    -------
    BernoulliFusion
        ``p`` (fused probability), ``omega`` (the chosen weight on ``p_a``, NaN for
        naive-bayes) and ``info_loss`` (KL(p_NB || p_fused), nats).

    Notes
    -----
    A certain input (p exactly 0 or 1) dominates: the fused p is that certainty with
    ``omega`` 1 (or 0 if it is ``p_b``) and zero loss. Certainties of opposite outcomes
    (0 with 1), NaN inputs and values outside [0, 1] raise ``ValueError`` naming the index.
    """
    rule = parse_rule(rule)
    if not 0.0 < prior < 1.0:
        raise ValueError(f"prior = {prior!r}: expected a probability strictly between 0 and 1")
    a, b = _pair(p_a, p_b)
    l0 = float(np.log(prior) - np.log1p(-prior))
    p, w, loss = _core._fuse(rule, a, b, True, l0, "p_a", "p_b")
    return BernoulliFusion(p, w, loss)


def fuse_logodds(
    l_a, l_b, rule: str = "min-info-loss", prior_logodds: float = 0.0
) -> LogOddsFusion:
    """Fuse log-odds element-wise with a fusion rule (see :func:`fuse_bernoulli`).

    ``l_a``, ``l_b`` may be +-inf (certain); NaN and contradictory infinities raise
    ``ValueError``. ``prior_logodds`` is the common prior's log-odds (0 for OctoMap).
    """
    rule = parse_rule(rule)
    if not np.isfinite(prior_logodds):
        raise ValueError(f"prior_logodds = {prior_logodds!r}: expected a finite number")
    a, b = _pair(l_a, l_b)
    l, w, loss = _core._fuse(rule, a, b, False, float(prior_logodds), "l_a", "l_b")
    return LogOddsFusion(l, w, loss)
