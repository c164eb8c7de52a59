"""Robust distributed fusion by dynamic voting (Montijano, Martínez, Sagüés), with baselines.

Every robot ``i`` holds a measurement ``x_i`` (d,) of the same quantity with covariance ``Λ_i``.
Some robots are outliers. RANSAC over a network: ``K`` hypotheses, each seeded by ``c`` random
robots (max consensus on random numbers), are built and voted on by average consensus with
Metropolis weights, using only messages between neighbours.

- :func:`dynamic_vote`: one consensus step. Each robot tests its own measurement against its
  current estimate ``θ_i = P_i^-1 q_i`` of each hypothesis and adds its term ``[Λ_i^-1, Λ_i^-1 x_i, 1]``
  to ``[P_i, q_i, v_i]`` when the test switches from fail to pass, subtracts it when it switches
  back. The hypothesis with the most votes wins; its estimate tends to the ML of its voters.
- Baselines in :mod:`octofuse.fusion.voting_baselines`: ``static_vote`` (three consensus steps:
  hypotheses, votes, ML of the inliers) and ``maximum_likelihood`` (all robots, no rejection).

The chi-square test (:class:`ChiSquareGate`) compares the squared Mahalanobis distance with the
chi-square quantile (``form="squared"``, the statistically consistent test). The paper compares
the Mahalanobis distance itself, ``sqrt(r^T Λ^-1 r)``, with the same quantile; ``form="paper"``
reproduces that looser test (for d = 2 at 95 %: 5.99 sigma instead of 2.45 sigma).

Each function has a ``*_batch`` form over independent networks ``(B, N, ...)`` with a topology
callable ``t -> (B, N, N)`` adjacency, used for Monte Carlo studies.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from .consensus import (
    adjacency_from_edges,
    average,
    diameter,
    estimates,
    information_floor,
    information_terms,
    metropolis_weights,
    select_seeds,
)

FLOAT_BYTES = 8  # floats travel as float64


def _check_probability(name: str, value: float) -> None:
    if not (isinstance(value, (int, float, np.floating)) and 0.0 < float(value) < 1.0):
        raise ValueError(f"{name} must be a probability strictly between 0 and 1, got {value!r}")


def _check_int(name: str, value: int, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def hypothesis_count(p_in: float, success: float = 0.99, c: int = 1) -> int:
    """RANSAC's number of hypotheses ``K = ceil(log(1 - P) / log(1 - p_in^c))`` so that at least one
    is seeded by inliers only with probability ``P = success``."""
    _check_probability("p_in", p_in)
    _check_probability("success", success)
    c = _check_int("c", c, 1)
    return max(1, math.ceil(math.log(1.0 - success) / math.log(1.0 - p_in**c)))


@dataclass(frozen=True)
class ChiSquareGate:
    """Chi-square test of a residual ``r`` with covariance ``S``: passes when
    ``r^T S^-1 r <= chi2_d(confidence)`` (``form="squared"``) or, as the paper writes it,
    ``sqrt(r^T S^-1 r) <= chi2_d(confidence)`` (``form="paper"``)."""

    confidence: float = 0.95
    form: Literal["squared", "paper"] = "squared"

    def __post_init__(self) -> None:
        _check_probability("confidence", self.confidence)
        if self.form not in ("squared", "paper"):
            raise ValueError(f"gate form must be 'squared' or 'paper', not {self.form!r}")

    def threshold(self, d: int) -> float:
        from scipy.stats import chi2

        return float(chi2.ppf(self.confidence, d))

    def passes(self, mahalanobis2: np.ndarray, d: int) -> np.ndarray:
        stat = mahalanobis2 if self.form == "squared" else np.sqrt(np.maximum(mahalanobis2, 0.0))
        return stat <= self.threshold(d)


@dataclass(frozen=True)
class VoteResult:
    """Outcome of a vote; arrays of a ``*_batch`` call carry a leading trial axis.

    inliers (N,) each robot's verdict on its own measurement for the hypothesis it chose;
    estimate (N, d) each robot's final estimate (NaN where it has none); votes (K, N) each
    robot's share of votes per hypothesis (the fraction of robots voting, once converged);
    seeds (K, N) the seed robots of each hypothesis; winner the hypothesis with the most votes
    on average over the robots; robot_winner (N,) the one each robot picks from its own votes;
    rounds of communication (seed selection included), messages sent (one per robot and
    neighbour per round) and floats sent in them.
    """

    inliers: np.ndarray
    estimate: np.ndarray
    votes: np.ndarray
    seeds: np.ndarray
    winner: np.ndarray | int
    robot_winner: np.ndarray
    hypotheses: int
    rounds: int
    messages: np.ndarray | int
    floats: np.ndarray | int
    history: dict | None = None

    @property
    def bytes(self) -> np.ndarray | int:
        return self.floats * FLOAT_BYTES

    def trial(self, b: int) -> VoteResult:
        """The result of trial ``b`` of a batch."""

        def pick(a):
            return a[b] if isinstance(a, np.ndarray) else a

        hist = None if self.history is None else {k: v[:, b] for k, v in self.history.items()}
        out = {
            f: pick(getattr(self, f))
            for f in ("inliers", "estimate", "votes", "seeds", "robot_winner")
        }
        return replace(
            self,
            **out,
            winner=int(self.winner[b]),
            messages=int(self.messages[b]),
            floats=int(self.floats[b]),
            history=hist,
        )


# ---------------------------------------------------------------- single network


def dynamic_vote(
    x,
    covariances,
    edges,
    p_in: float = 0.8,
    success: float = 0.99,
    c: int = 1,
    iterations: int = 100,
    seed=None,
    gate: ChiSquareGate = ChiSquareGate(),
    seed_sets: Iterable[Iterable[int]] | None = None,
    record: bool = False,
) -> VoteResult:
    """Dynamic voting over a network of robots.

    ``x`` (N, d) measurements, ``covariances`` (N, d, d) symmetric positive definite, ``edges`` a
    list of undirected ``(i, j)`` pairs (or a graph with ``.edges``) or a callable ``t -> edges``
    for a topology that changes every round ``t`` (seed selection runs first, from ``t = 0``).
    ``K = hypothesis_count(p_in, success, c)`` hypotheses unless ``seed_sets`` names the seed
    robots of each. As in the paper, a robot tests ``x_i - θ_i`` with ``Λ_i`` alone (early ``P_i``
    are unreliable), and fails while ``P_i`` is not positive definite: singular before any
    information reaches it, possibly indefinite just after a robot subtracted its term.
    ``record`` keeps every round's votes (T+1, K, N), estimates (T+1, K, N, d) and test outcomes
    (T+1, K, N) in ``history``.
    """
    x, cov, topology, fixed_rounds, rng = _prepare(x, covariances, edges, seed)
    seeds, k = _seed_masks(seed_sets, x.shape[1], p_in, success, c)
    return dynamic_vote_batch(
        x,
        cov,
        topology,
        k=k,
        c=c,
        iterations=iterations,
        rng=rng,
        gate=gate,
        seeds=seeds,
        seed_rounds=fixed_rounds,
        record=record,
    ).trial(0)


# ---------------------------------------------------------------- batches of networks


def dynamic_vote_batch(
    x: np.ndarray,
    covariances: np.ndarray,
    topology: Callable[[int], np.ndarray],
    *,
    k: int,
    c: int = 1,
    iterations: int = 100,
    rng: np.random.Generator,
    gate: ChiSquareGate = ChiSquareGate(),
    seeds: np.ndarray | None = None,
    seed_rounds: int | None = None,
    record: bool = False,
) -> VoteResult:
    """:func:`dynamic_vote` on ``B`` networks at once: ``x`` (B, N, d), ``covariances`` (B, N, d, d),
    ``topology(t)`` (B, N, N) adjacency. ``seeds`` (K, N) fixes the seed robots; otherwise they are
    drawn with ``rng``, over ``seed_rounds`` rounds (a fixed graph's diameter) or until agreement."""
    b, n, d = x.shape
    iterations = _check_int("iterations", iterations, 0)
    info, vec = information_terms(x, covariances)
    floor = information_floor(info)
    seeds, rounds, msgs = _draw_seeds(seeds, b, k, n, c, rng, topology, seed_rounds, iterations)
    floats = msgs * k * c
    per_message = k * (d * (d + 1) // 2 + d + 1)  # symmetric P, q and v per hypothesis

    passing = seeds.copy()  # (B, K, N): whose term is in the state
    weight = passing.astype(float)
    p = weight[..., None, None] * info[:, None]
    q = weight[..., None] * vec[:, None]
    v = weight.copy()
    hist: dict[str, list] = {"votes": [], "estimates": [], "passing": []}
    for t in range(iterations):
        theta, now = _gate_test(p, q, x, info, floor, gate)
        if record:
            hist["votes"].append(v.copy())
            hist["estimates"].append(theta)
            hist["passing"].append(now)
        change = now.astype(float) - passing.astype(float)  # +1 fail -> pass, -1 pass -> fail
        passing = now
        adj = np.asarray(topology(rounds + t), dtype=bool)
        w = metropolis_weights(adj)
        sent = adj.sum(axis=(-2, -1))
        msgs, floats = msgs + sent, floats + sent * per_message
        p = average(w, p) + change[..., None, None] * info[:, None]
        q = average(w, q) + change[..., None] * vec[:, None]
        v = average(w, v) + change
    theta, final = _gate_test(p, q, x, info, floor, gate)
    if record:
        hist["votes"].append(v.copy())
        hist["estimates"].append(theta)
        hist["passing"].append(final)
    history = {key: np.stack(val) for key, val in hist.items()} if record else None
    return _result(final, theta, v, seeds, k, rounds + iterations, msgs, floats, history)


# ---------------------------------------------------------------- internals


def _gate_test(p, q, x, info, floor, gate):
    """Each robot's estimate of each hypothesis (B, K, N, d) and whether its own measurement passes
    (a robot without an invertible ``P_i`` fails)."""
    theta, valid = estimates(p, q, floor)
    r = np.where(valid[..., None], x[:, None] - theta, 0.0)
    m2 = np.einsum("bkni,bnij,bknj->bkn", r, info, r)
    return theta, valid & gate.passes(m2, x.shape[-1])


def _result(final, theta, v, seeds, k, rounds, msgs, floats, history) -> VoteResult:
    choice = np.argmax(v, axis=1)  # (B, N): each robot's pick from its own votes
    inliers = np.take_along_axis(final, choice[:, None], axis=1)[:, 0]
    est = np.take_along_axis(theta, choice[:, None, :, None], axis=1)[:, 0]
    return VoteResult(
        inliers=inliers,
        estimate=est,
        votes=v,
        seeds=seeds,
        winner=np.argmax(v.mean(axis=-1), axis=-1),
        robot_winner=choice,
        hypotheses=k,
        rounds=rounds,
        messages=msgs,
        floats=floats,
        history=history,
    )


def _draw_seeds(seeds, b, k, n, c, rng, topology, seed_rounds, iterations):
    if seeds is not None:
        seeds = np.broadcast_to(np.asarray(seeds, dtype=bool), (b, k, n)).copy()
        return seeds, 0, np.zeros(b, dtype=np.int64)
    c = _check_int("c", c, 1)
    if c > n:
        raise ValueError(f"c = {c} seeds per hypothesis but only {n} robots")
    numbers = rng.random((b, k, n))
    return select_seeds(numbers, c, topology, seed_rounds, max_rounds=max(10 * n, iterations))


def _seed_masks(seed_sets, n, p_in, success, c):
    k = hypothesis_count(p_in, success, c)
    if seed_sets is None:
        return None, k
    sets = [list(s) for s in seed_sets]
    if not sets or any(not s for s in sets):
        raise ValueError("seed_sets needs at least one hypothesis, each with at least one robot")
    masks = np.zeros((len(sets), n), dtype=bool)
    for h, members in enumerate(sets):
        for i in members:
            if not (isinstance(i, (int, np.integer)) and 0 <= i < n):
                raise ValueError(f"seed_sets[{h}] names robot {i!r}, outside 0..{n - 1}")
            masks[h, i] = True
    return masks, len(sets)


def _prepare(x, covariances, edges, seed):
    """Validated single-network inputs as a batch of one, the topology and the seed-round count."""
    x = np.asarray(x, dtype=float)
    if x.ndim != 2 or x.shape[0] < 1 or x.shape[1] < 1:
        raise ValueError(f"x must have shape (N, d) with N, d >= 1, got {x.shape}")
    n, d = x.shape
    cov = np.asarray(covariances, dtype=float)
    if cov.shape != (n, d, d):
        raise ValueError(f"covariances must have shape ({n}, {d}, {d}) to match x, got {cov.shape}")
    if not np.all(np.isfinite(x)):
        bad = np.flatnonzero(~np.isfinite(x).all(axis=1)).tolist()
        raise ValueError(f"x has non-finite values at robots {bad}")
    if not np.all(np.isfinite(cov)):
        raise ValueError("covariances have non-finite values")
    asym = np.abs(cov - np.swapaxes(cov, 1, 2)).max(axis=(1, 2)) > 1e-9 * np.abs(cov).max(
        axis=(1, 2)
    )
    if asym.any():
        raise ValueError(f"covariances of robots {np.flatnonzero(asym).tolist()} are not symmetric")
    not_pd = np.linalg.eigvalsh(cov)[:, 0] <= 0
    if not_pd.any():
        raise ValueError(
            f"covariances of robots {np.flatnonzero(not_pd).tolist()} are not positive definite"
        )
    rng = np.random.default_rng(seed)
    if callable(edges):

        def topology(t: int) -> np.ndarray:
            return adjacency_from_edges(edges(t), n)[None]

        return x[None], cov[None], topology, None, rng
    adj = adjacency_from_edges(edges, n)
    rounds = diameter(adj)
    return x[None], cov[None], lambda t: adj[None], rounds, rng
