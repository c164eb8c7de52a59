"""Baselines for robust voting: static voting (three consensus steps) and the plain distributed
maximum likelihood of all robots, with the covariance the static test needs.

Arguments and results as :func:`octofuse.fusion.voting.dynamic_vote`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

import numpy as np

from .consensus import average, information_consensus, information_terms, metropolis_weights
from .voting import ChiSquareGate, VoteResult, _check_int, _draw_seeds, _prepare, _seed_masks


def static_vote(
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
) -> VoteResult:
    """Static voting: ``iterations`` rounds each to build the hypotheses, to average the votes and
    to compute the ML of the winner's inliers. Arguments as :func:`dynamic_vote`."""
    x, cov, topology, fixed_rounds, rng = _prepare(x, covariances, edges, seed)
    seeds, k = _seed_masks(seed_sets, x.shape[1], p_in, success, c)
    return static_vote_batch(
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
    ).trial(0)


def maximum_likelihood(x, covariances, edges, iterations: int = 100) -> VoteResult:
    """Distributed ML of all robots (no outlier rejection): every robot counts as an inlier."""
    x, cov, topology, _, _ = _prepare(x, covariances, edges, None)
    return maximum_likelihood_batch(x, cov, topology, iterations=iterations).trial(0)


def static_vote_batch(
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
) -> VoteResult:
    """:func:`static_vote` on ``B`` networks at once (arguments as :func:`dynamic_vote_batch`).

    A robot tests ``r = x_i - θ^h`` with the covariance of that difference,
    :func:`residual_covariance`, where ``Λ_ML^h`` is its own estimate ``(N P_i)^-1``.
    """
    b, n, d = x.shape
    iterations = _check_int("iterations", iterations, 1)
    info, vec = information_terms(x, covariances)
    seeds, rounds, msgs = _draw_seeds(seeds, b, k, n, c, rng, topology, seed_rounds, iterations)
    floats = msgs * k * c
    theta, valid, p, sent = information_consensus(info, vec, seeds, topology, iterations, rounds)
    msgs, floats = msgs + sent, floats + sent * k * (d * (d + 1) // 2 + d)

    cov_ml = np.linalg.inv(np.where(valid[..., None, None], n * p, np.eye(d)))
    s = residual_covariance(covariances[:, None], cov_ml, seeds)
    r = np.where(valid[..., None], x[:, None] - theta, 0.0)
    passes = valid & gate.passes(_mahalanobis2(r, s), d)

    v = passes.astype(float)
    for t in range(iterations):
        adj = np.asarray(topology(rounds + iterations + t), dtype=bool)
        sent = adj.sum(axis=(-2, -1))
        msgs, floats = msgs + sent, floats + sent * k
        v = average(metropolis_weights(adj), v)

    choice = np.argmax(v, axis=1)  # (B, N)
    inliers = np.take_along_axis(passes, choice[:, None], axis=1)[:, 0]
    est, _, _, sent = information_consensus(
        info, vec, inliers[:, None], topology, iterations, rounds + 2 * iterations
    )
    msgs, floats = msgs + sent, floats + sent * (d * (d + 1) // 2 + d)
    return VoteResult(
        inliers=inliers,
        estimate=est[:, 0],
        votes=v,
        seeds=seeds,
        winner=np.argmax(v.mean(axis=-1), axis=-1),
        robot_winner=choice,
        hypotheses=k,
        rounds=rounds + 3 * iterations,
        messages=msgs,
        floats=floats,
    )


def maximum_likelihood_batch(
    x: np.ndarray,
    covariances: np.ndarray,
    topology: Callable[[int], np.ndarray],
    *,
    iterations: int = 100,
) -> VoteResult:
    """:func:`maximum_likelihood` on ``B`` networks at once."""
    b, n, d = x.shape
    iterations = _check_int("iterations", iterations, 1)
    info, vec = information_terms(x, covariances)
    everyone = np.ones((b, 1, n), dtype=bool)
    est, _, _, msgs = information_consensus(info, vec, everyone, topology, iterations)
    return VoteResult(
        inliers=everyone[:, 0],
        estimate=est[:, 0],
        votes=np.ones((b, 1, n)),
        seeds=everyone,
        winner=np.zeros(b, dtype=np.int64),
        robot_winner=np.zeros((b, n), dtype=np.int64),
        hypotheses=1,
        rounds=iterations,
        messages=msgs,
        floats=msgs * (d * (d + 1) // 2 + d),
    )


def residual_covariance(cov_i: np.ndarray, cov_ml: np.ndarray, member: np.ndarray) -> np.ndarray:
    """Covariance of ``x_i - θ`` where ``θ = Λ_ML Σ_{j∈V} Λ_j^-1 x_j``,
    ``Λ_ML = (Σ_{j∈V} Λ_j^-1)^-1`` and the ``x_j = θ* + e_j`` are independent with covariances ``Λ_j``.

    Not a member (``i ∉ V``): ``x_i`` and ``θ`` are independent, ``Λ_i + Λ_ML``.

    A member (``i ∈ V``): ``x_i - θ = e_i - Λ_ML Σ_j Λ_j^-1 e_j``, so
    ``Cov = Λ_i - Cov(e_i, θ) - Cov(θ, e_i) + Cov(θ)``, with
    ``Cov(e_i, θ) = Λ_i Λ_i^-1 Λ_ML = Λ_ML`` and
    ``Cov(θ) = Λ_ML (Σ_j Λ_j^-1 Λ_j Λ_j^-1) Λ_ML = Λ_ML``:
    ``Λ_i - 2 Λ_ML + Λ_ML = Λ_i - Λ_ML``. (The paper's eq. 9, ``Λ_ML + Λ_i - 2 Λ_ML Λ_i^-1 Λ_ML``,
    differs; with one seed, ``V = {i}``, the residual is exactly zero and so is ``Λ_i - Λ_ML``.)
    """
    sign = np.where(member, -1.0, 1.0)[..., None, None]
    return cov_i + sign * cov_ml


def _mahalanobis2(r: np.ndarray, s: np.ndarray, rtol: float = 1e-9) -> np.ndarray:
    """``r^T S^+ r`` with directions of (near) zero variance left out: a member's residual with
    one seed is zero and so is its covariance."""
    eig, vecs = np.linalg.eigh(s)
    along = np.einsum("...ij,...i->...j", vecs, r)
    keep = eig > rtol * np.abs(eig).max(axis=-1, keepdims=True)
    return np.sum(np.where(keep, along**2 / np.where(keep, eig, 1.0), 0.0), axis=-1)
