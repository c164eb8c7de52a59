"""Exact fusion of occupancy maps by channel filters on a tree (``channel-filter``).

The exact fusion of two beliefs is p_f ∝ p_i p_j / p_c, with p_c the information both share;
in log-odds, voxel by voxel, l_f = l_i + l_j - l_c. On a graph without loops the common
information of a link can be tracked exactly: every piece of information crosses a tree link
at most once, so what agent i knows from j's side of the link is exactly what j told it.

What each side stores and does, per link (i, j) and direction:

* **receiver** ``i`` keeps one map per neighbour ``j``, ``c_ji``: the last contribution ``j``
  sent it (the log-odds of the scans on ``j``'s side of the link that ``i`` knows). The
  common map of the link is ``c_ji + c_ij`` (what each side told the other).
* **sender** ``j`` sends ``m = l_j - c_ij``: its map minus what it got from ``i`` over this
  link, i.e. everything it knows from its own side (its scans and its other neighbours').
* on receiving, ``i`` replaces ``j``'s previous contribution by the new one:
  ``l_i <- l_i + m - c_ji``, then ``c_ji <- m``. This is ``l_i + l_j - l_ij`` with the common
  map ``l_ij = c_ji + c_ij`` (``m + c_ij = l_j``), and after a two-way exchange both agents
  hold ``l_i + l_j - l_ij``, which is then the new common map of the link.
* the sender stores nothing about a whole-map message: the next one supersedes it. (Setting
  the common map to the receiver's new map after a one-way message would put the receiver's
  own information into it, and the next message from the sender would cancel it.)

A message is a *value*, not an increment: applying it twice changes nothing (``m - c_ji = 0``
the second time), and a message lost on the way costs only time, because the next one carries
everything it carried. Messages carry a sequence number per link and direction; one older than
the newest applied (a reordered message) is dropped, since the newer one contains it.

Delta messages carry ``m`` only on the voxels that changed since the last message the sender
knows was received (on a lossless link: the last one sent). The receiver applies it voxel by
voxel (``l_i += m - c_ji`` and ``c_ji = m`` on those voxels only): repeated deltas change
nothing. On a link that loses messages the sender cannot know whether a delta arrived; every
message therefore carries an acknowledgement, the newest sequence number its sender has
applied from the receiver, and a sender computes deltas against the last acknowledged message
(so unacknowledged voxels are sent again until acknowledged).

OctoMap clamps stored log-odds (default [-2, 3.5]), which breaks the additivity the exact rule
needs: the agents' maps, the messages and the per-link maps are kept with the clamping opened
to +-inf (:meth:`OccupancyMap.open_clamping`; subtraction is naive-Bayes fusion of a negated copy), and
the maps are clamped to the configured thresholds only for scoring and writing
(:func:`clamped`). Clamping ``sum of scans`` once is not OctoMap's clamped step-by-step
insertion, so a fully informed agent differs from the (clamped) centralized map by that much.

On a graph with loops the same information would reach an agent over two paths and be counted
twice: the filter then runs on a spanning tree of the graph (:func:`spanning_tree`) and the
messages on the other links are not used by it.

The per-link state (contributions received, sequence numbers, delta baselines) is the link
protocol's (:class:`~.link.Link`), and the sending and applying are the agent's
(:class:`~.agent.Agent`): this module holds the arithmetic and the tree.
"""

from __future__ import annotations

import math
from collections import deque

from ..config import CHANNEL_FILTER
from ..maps.occupancy import OccupancyMap
from ..maps.tree_fusion import fuse_into, subtract_into
from ..rules import Rule, UnknownPolicy
from .graph import Graph, make_graph

__all__ = [
    "CHANNEL_FILTER",
    "add_into",
    "clamped",
    "negated",
    "open_map",
    "spanning_tree",
    "subtract_into",
    "unclamped_copy",
]


# -- log-odds arithmetic on maps ------------------------------------------------------------


def open_map(m: OccupancyMap) -> OccupancyMap:
    """Open ``m``'s clamping (thresholds -inf/+inf log-odds) in place; returns ``m``."""
    return m.open_clamping()


def is_open(m: OccupancyMap) -> bool:
    """Whether ``m``'s clamping is open (-inf/+inf log-odds)."""
    return m.clamping_logodds == (-math.inf, math.inf)


def unclamped_copy(m: OccupancyMap) -> OccupancyMap:
    """A copy of ``m`` with open clamping (a plain copy gets its parameters' thresholds)."""
    return open_map(m.copy())


def clamped(m: OccupancyMap) -> OccupancyMap:
    """A copy of ``m`` clamped to its configured thresholds: what scoring and files see."""
    return m.clamped_copy()


def negated(m: OccupancyMap) -> OccupancyMap:
    """An unclamped copy of ``m`` with every log-odds negated."""
    return unclamped_copy(m).negate_values()


def add_into(dst: OccupancyMap, src: OccupancyMap) -> None:
    """``dst += src`` voxel by voxel (naive-Bayes fusion: l_dst + l_src - l_0 with l_0 = 0;
    a voxel ``dst`` does not know gets ``src``'s value). ``dst`` must have open clamping."""
    fuse_into(dst, src, rule=Rule.NAIVE_BAYES, unknown=UnknownPolicy.COPY)


# -- the tree -------------------------------------------------------------------------------


def spanning_tree(graph: Graph, how: str = "bfs") -> tuple[tuple[int, int], ...]:
    """The links (sorted ``(a, b)``, ``a < b``) the channel filter uses on ``graph``.

    ``"bfs"``: the graph itself if it is a tree, else a breadth-first tree from its centre
    (the node of least eccentricity, lowest index first; neighbours in index order), which
    keeps every agent as few hops from the others as the graph allows. ``"given"``: the
    graph, which must be a tree. Anything else is a graph file (see
    :func:`octofuse.fusion.graph.make_graph`) whose links must be a tree on every agent and
    links of ``graph``.
    """
    n, edges = graph.n, tuple(graph.edges)
    if len(edges) == n - 1:
        if how in ("bfs", "given"):
            return edges
    if how == "given":
        raise ValueError(
            f"the channel filter needs a graph without loops: topology {graph.spec or 'given'!r} "
            f"has {len(edges)} links on {n} agents (a tree has {n - 1}); use spanning_tree: bfs, "
            "or a file with the tree's links"
        )
    if how == "bfs":
        ecc = [max(_hops(graph, s)) for s in range(n)]
        root = min(range(n), key=lambda s: (ecc[s], s))
        seen, tree, queue = {root}, [], deque([root])
        while queue:
            a = queue.popleft()
            for b in graph.neighbors(a):
                if b not in seen:
                    seen.add(b)
                    tree.append((min(a, b), max(a, b)))
                    queue.append(b)
        return tuple(sorted(tree))
    given = make_graph(str(how), n, names=graph.names)
    if len(given.edges) != n - 1:
        raise ValueError(
            f"spanning tree file '{how}' has {len(given.edges)} links on {n} agents: "
            f"a tree has {n - 1}"
        )
    extra = [e for e in given.edges if e not in set(edges)]
    if extra:
        a, b = extra[0]
        name = (lambda k: graph.names[k]) if graph.names else str
        raise ValueError(
            f"spanning tree file '{how}': link {name(a)} - {name(b)} is not a link "
            f"of the topology {graph.spec!r}"
        )
    return tuple(given.edges)


def _hops(graph: Graph, s: int) -> list[int]:
    dist = [-1] * graph.n
    dist[s] = 0
    queue = deque([s])
    while queue:
        a = queue.popleft()
        for b in graph.neighbors(a):
            if dist[b] < 0:
                dist[b] = dist[a] + 1
                queue.append(b)
    return [d if d >= 0 else graph.n for d in dist]
