"""Consensus primitives for robust fusion, vectorised over a batch of independent networks.

Every array carries a leading batch axis ``B`` (independent trials on the same number of robots
``N``); a single network is ``B = 1``. A topology is an adjacency matrix ``(B, N, N)`` of booleans
(symmetric, empty diagonal), one per communication round.

- :func:`metropolis_weights`: the doubly stochastic averaging matrix of a round,
  ``a_ij = 1 / (1 + max(deg_i, deg_j))`` on the edges and ``a_ii = 1 - sum_j a_ij``.
- :func:`select_seeds`: which robots seed each hypothesis, by max consensus on random numbers.
- :func:`average`: one averaging round of per-robot states ``(B, K, N, ...)``.
- :func:`information_consensus`: distributed maximum likelihood (average consensus on the
  information form ``P = Λ^-1``, ``q = Λ^-1 x``), the estimate read as ``θ_i = P_i^-1 q_i``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

import numpy as np

Topology = Callable[[int], np.ndarray]  # round t -> adjacency (B, N, N)


def adjacency_from_edges(edges: Iterable, n: int) -> np.ndarray:
    """Symmetric boolean ``(N, N)`` adjacency of undirected ``(i, j)`` pairs (or of an object with
    an ``edges`` attribute, such as :class:`octofuse.graph.Graph`)."""
    pairs = list(getattr(edges, "edges", edges))
    adj = np.zeros((n, n), dtype=bool)
    for pair in pairs:
        try:
            i, j = (int(v) for v in pair)
        except (TypeError, ValueError):
            raise ValueError(f"edge {pair!r} is not a pair of robot indices") from None
        if not (0 <= i < n and 0 <= j < n):
            raise ValueError(f"edge ({i}, {j}) names a robot outside 0..{n - 1}")
        if i == j:
            raise ValueError(f"edge ({i}, {j}) is a self-loop")
        adj[i, j] = adj[j, i] = True
    return adj


def metropolis_weights(adjacency: np.ndarray) -> np.ndarray:
    """Metropolis averaging matrices ``(B, N, N)`` of adjacency matrices ``(B, N, N)``."""
    adj = np.asarray(adjacency, dtype=bool)
    deg = adj.sum(axis=-1)
    larger = np.maximum(deg[..., :, None], deg[..., None, :])
    w = np.where(adj, 1.0 / (1.0 + larger), 0.0)
    idx = np.arange(adj.shape[-1])
    w[..., idx, idx] = 1.0 - w.sum(axis=-1)
    return w


def diameter(adjacency: np.ndarray) -> int:
    """Hop diameter of one connected graph ``(N, N)``; ValueError if it is disconnected."""
    adj = np.asarray(adjacency, dtype=bool)
    n = adj.shape[0]
    reach = np.eye(n, dtype=bool)
    hops = 0
    while not reach.all():
        grown = reach | (reach.astype(np.int64) @ adj.astype(np.int64) > 0)
        if (grown == reach).all():
            cut = np.flatnonzero(~reach[0]).tolist()
            raise ValueError(
                f"the communication graph is disconnected: robots {cut} cannot reach robot 0"
            )
        reach = grown
        hops += 1
    return hops


def select_seeds(
    numbers: np.ndarray, c: int, topology: Topology, rounds: int | None, max_rounds: int
) -> tuple[np.ndarray, int, int]:
    """Seed robots of every hypothesis by max consensus on random numbers.

    ``numbers`` (B, K, N) holds each robot's random number per hypothesis. Every robot keeps the
    ``c`` largest numbers it has heard of and, each round, merges its neighbours' lists (eq. 6).
    With ``rounds`` given (the diameter of a fixed graph) exactly that many rounds run; otherwise
    rounds run until every robot holds the network's ``c`` largest numbers (a changing topology).
    Returns the seed masks (B, K, N), the rounds used and the messages sent per network (B,), one
    per robot and neighbour per round.
    """
    b, k, n = numbers.shape
    known = np.full((b, k, n, c), -np.inf)
    known[..., 0] = numbers
    target = -np.sort(-numbers, axis=-1)[..., :c]  # (B, K, c)
    t, messages = 0, np.zeros(b, dtype=np.int64)
    while t < rounds if rounds is not None else not np.all(known == target[:, :, None, :]):
        if t >= max_rounds:
            raise ValueError(
                f"seed selection did not agree within {max_rounds} rounds: "
                "the changing topology is not jointly connected often enough"
            )
        adj = np.asarray(topology(t), dtype=bool)
        heard = adj | np.eye(n, dtype=bool)  # (B, N, N): robot i hears j
        messages += adj.sum(axis=(-2, -1))
        pool = np.where(heard[:, None, :, :, None], known[:, :, None, :, :], -np.inf)  # (B,K,N,N,c)
        pool = -np.sort(-pool.reshape(b, k, n, n * c), axis=-1)
        pool[..., 1:][pool[..., 1:] == pool[..., :-1]] = -np.inf  # a number heard twice counts once
        known = -np.sort(-pool, axis=-1)[..., :c]
        t += 1
    seeds = numbers >= known[..., -1]  # own number among the c largest it knows
    return seeds, t, messages


def average(weights: np.ndarray, state: np.ndarray) -> np.ndarray:
    """One averaging round: ``state_i <- sum_j a_ij state_j`` for states ``(B, K, N, ...)``."""
    flat = state.reshape(state.shape[:3] + (-1,))
    return np.einsum("bij,bkjf->bkif", weights, flat).reshape(state.shape)


def information_terms(x: np.ndarray, covariances: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each robot's information matrix ``Λ_i^-1`` (B, N, d, d) and vector ``Λ_i^-1 x_i`` (B, N, d)."""
    info = np.linalg.inv(covariances)
    info = 0.5 * (info + np.swapaxes(info, -1, -2))
    return info, np.einsum("bnij,bnj->bni", info, x)


def information_floor(info: np.ndarray, rtol: float = 1e-9) -> np.ndarray:
    """Per network (B,): the smallest eigenvalue an information matrix needs to count as
    invertible, ``rtol`` times the largest eigenvalue of the robots' ``Λ_i^-1``."""
    return rtol * np.linalg.eigvalsh(info)[..., -1].max(axis=-1)


def estimates(p: np.ndarray, q: np.ndarray, floor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``θ = P^-1 q`` for information pairs ``(B, ..., d, d)``, ``(B, ..., d)``. ``valid`` is False
    (and θ NaN) where ``P`` is not positive definite, its smallest eigenvalue at most the network's
    ``floor`` (B,): no information has arrived yet, or more was subtracted than averaged in."""
    eig = np.linalg.eigvalsh(p)
    valid = eig[..., 0] > floor.reshape(floor.shape + (1,) * (eig.ndim - 2))
    safe = np.where(valid[..., None, None], p, np.eye(p.shape[-1]))
    theta = np.linalg.solve(safe, q[..., None])[..., 0]
    theta[~valid] = np.nan
    return theta, valid


def information_consensus(
    info: np.ndarray,
    vec: np.ndarray,
    members: np.ndarray,
    topology: Topology,
    iterations: int,
    t0: int = 0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Distributed ML of the ``members`` (B, K, N) of each set: states start at
    ``[Λ_i^-1, Λ_i^-1 x_i]`` for members and zero otherwise (eq. 5) and are averaged ``iterations``
    rounds (eq. 2). Returns every robot's estimate (B, K, N, d), whether it is defined (B, K, N),
    the final information matrices (B, K, N, d, d) and the messages sent per network (B,)."""
    m = members.astype(float)
    p = m[..., None, None] * info[:, None]
    q = m[..., None] * vec[:, None]
    messages = np.zeros(info.shape[0], dtype=np.int64)
    for t in range(iterations):
        adj = np.asarray(topology(t0 + t), dtype=bool)
        messages += adj.sum(axis=(-2, -1))
        w = metropolis_weights(adj)
        p, q = average(w, p), average(w, q)
    theta, valid = estimates(p, q, information_floor(info))
    return theta, valid, p, messages
