"""Robust fusion: the robots find and exclude one whose map is wrong, by dynamic voting.

When ``FuseConfig.robust.enabled`` is on, :func:`octofuse.fusion.simulate.simulate` calls
:func:`vote_on_maps` once, at ``robust.time`` seconds after the start of the bags (before the
exchanges of that instant):

1. every robot takes the occupied voxels above the floor of its own map (its own scans only,
   not the fused map, which may already hold others' errors) as 2-D points and sends them to
   its neighbours on the communication graph (8 bytes per point: two float32);
2. every robot measures its offset ``(dx, dy, yaw)`` to the majority of its neighbours' maps
   with its covariance (:func:`octofuse.maps.alignment.neighbour_offset`): about zero for a
   correctly localised robot, its pose error for a wrong one;
3. the robots vote with :func:`octofuse.fusion.voting.dynamic_vote` over the same graph
   (neighbour messages only); a robot whose own measurement fails the test against the
   winning estimate is voted out.

From then on the messages of a voted-out robot are not fused by anyone (they are not sent);
its own map keeps fusing the others'. With ``robust.hold`` (the default) no map is exchanged
before the vote, so nothing of a wrong map is fused before it is found; whole-map messages
carry everything mapped before the vote at the next exchange.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..maps.alignment import map_points, neighbour_offset
from .voting import ChiSquareGate, dynamic_vote

#: bytes of one 2-D point sent to a neighbour (two float32)
POINT_BYTES = 8


@dataclass
class RobustOutcome:
    """The vote on the robots' maps.

    ``measurements`` (N, 3) each robot's ``(dx, dy, yaw)`` offset to its neighbours (yaw in
    radians), ``covariances`` (N, 3, 3), ``abstained`` (N,) robots without a majority of
    agreeing neighbours, ``inliers`` (N,) the vote's verdict, ``votes`` (N,) each robot's share
    of votes for the hypothesis it chose, ``excluded`` the names of the robots voted out.
    ``alignment_bytes`` the point sets sent to neighbours, ``voting_bytes`` the consensus messages.
    """

    time_s: float
    agents: list[str]
    measurements: np.ndarray
    covariances: np.ndarray
    abstained: np.ndarray
    inliers: np.ndarray
    votes: np.ndarray
    excluded: list[str]
    hypotheses: int
    rounds: int
    alignment_bytes: int
    voting_bytes: int
    points: list[int] = field(default_factory=list)

    @property
    def total_bytes(self) -> int:
        return self.alignment_bytes + self.voting_bytes

    def to_dict(self) -> dict:
        return {
            "time_s": self.time_s,
            "excluded": list(self.excluded),
            "hypotheses": self.hypotheses,
            "rounds": self.rounds,
            "alignment_bytes": self.alignment_bytes,
            "voting_bytes": self.voting_bytes,
            "robots": {
                a: {
                    "dx": float(m[0]),
                    "dy": float(m[1]),
                    "yaw_deg": float(np.degrees(m[2])),
                    "abstained": bool(ab),
                    "inlier": bool(ok),
                    "votes": float(v),
                    "points": int(p),
                }
                for a, m, ab, ok, v, p in zip(
                    self.agents,
                    self.measurements,
                    self.abstained,
                    self.inliers,
                    self.votes,
                    self.points,
                )
            },
        }


def measure(
    points: list[np.ndarray], edges, **options
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every robot's :func:`neighbour_offset` from the point sets of its neighbours on ``edges``:
    measurements (N, 3), covariances (N, 3, 3) and abstentions (N,)."""
    n = len(points)
    nbrs: list[list[int]] = [[] for _ in range(n)]
    for i, j in edges:
        nbrs[i].append(j)
        nbrs[j].append(i)
    out = [
        neighbour_offset(points[i], [points[j] for j in sorted(nbrs[i])], **options)
        for i in range(n)
    ]
    x = np.array([o[0] for o in out]).reshape(n, 3)
    cov = np.array([o[1] for o in out]).reshape(n, 3, 3)
    return x, cov, np.array([not o[2] for o in out], dtype=bool)


def vote_on_maps(
    maps: dict,
    graph,
    *,
    p_in: float = 0.8,
    success: float = 0.99,
    iterations: int = 100,
    confidence: float = 0.95,
    seed: int = 0,
    time_s: float = 0.0,
    floor_height: float = 0.0,
) -> RobustOutcome:
    """Measure every robot's offset to its neighbours on its own map and vote.

    ``maps`` name -> map in the graph's robot order, ``graph`` a :class:`~octofuse.fusion.graph.Graph`
    (or anything with ``.edges`` of index pairs)."""
    agents = list(maps)
    edges = [tuple(e) for e in graph.edges]
    points = [map_points(maps[a], floor_height=floor_height) for a in agents]
    x, cov, abstained = measure(points, edges)
    res = dynamic_vote(
        x,
        cov,
        edges,
        p_in=p_in,
        success=success,
        iterations=iterations,
        seed=seed,
        gate=ChiSquareGate(confidence),
    )
    # a robot without a measurement cannot be voted out (its test passes by construction
    # unless the estimate is undefined at it)
    inliers = np.asarray(res.inliers, dtype=bool) | abstained
    votes = res.votes[res.robot_winner, np.arange(len(agents))]
    sent = sum(len(points[i]) + len(points[j]) for i, j in edges) * POINT_BYTES
    return RobustOutcome(
        time_s,
        agents,
        x,
        cov,
        abstained,
        inliers,
        votes,
        [a for a, ok in zip(agents, inliers) if not ok],
        res.hypotheses,
        res.rounds,
        int(sent),
        int(res.bytes),
        [len(p) for p in points],
    )


def vote_for_run(own_maps: dict, graph, fuse_cfg, time_s: float) -> RobustOutcome:
    """The vote of a run (``fuse_cfg.robust``) on the robots' own maps in the common frame."""
    r = fuse_cfg.robust
    return vote_on_maps(
        own_maps,
        graph,
        p_in=r.p_in,
        success=r.success,
        iterations=r.iterations,
        confidence=r.confidence,
        seed=fuse_cfg.seed,
        time_s=time_s,
    )


def admitted(group: list, outcome: RobustOutcome | None, fuse_cfg, agents: list) -> list:
    """The exchanges of ``group`` that robust fusion lets through: none before the vote if
    the run holds them, none from a voted-out sender after it."""
    if not fuse_cfg.robust.enabled:
        return group
    if outcome is None:
        return [] if fuse_cfg.robust.hold else group
    out = set(outcome.excluded)
    return [e for e in group if agents[e.sender] not in out]


def markdown_section(outcome: RobustOutcome) -> list[str]:
    """The report's section on the vote (lines of Markdown)."""
    excl = ", ".join(f"`{a}`" for a in outcome.excluded) or "none"
    lines = [
        "## Robust fusion (dynamic voting)",
        "",
        f"- vote at t = {outcome.time_s:.1f} s: {outcome.hypotheses} hypotheses, "
        f"{outcome.rounds} consensus rounds; excluded robots: {excl}",
        f"- bytes: {outcome.alignment_bytes / 1e3:.1f} kB of map points to neighbours, "
        f"{outcome.voting_bytes / 1e3:.1f} kB of voting messages "
        f"({outcome.total_bytes / 1e3:.1f} kB in all)",
        "",
        "| robot | dx [m] | dy [m] | yaw [deg] | measured | votes | verdict |",
        "|---|---|---|---|---|---|---|",
    ]
    for a, m, ab, ok, v in zip(
        outcome.agents, outcome.measurements, outcome.abstained, outcome.inliers, outcome.votes
    ):
        meas = "abstained" if ab else "yes"
        lines.append(
            f"| `{a}` | {m[0]:+.3f} | {m[1]:+.3f} | {np.degrees(m[2]):+.2f} | {meas} | "
            f"{v:.2f} | {'kept' if ok else '**excluded**'} |"
        )
    lines += [
        "",
        "Each robot's measurement is its map's offset to the majority of its neighbours' "
        "maps (2-D ICP of occupied voxels above the floor); `votes` is the robot's share "
        "of votes for the hypothesis it chose; an excluded robot's messages are not fused, "
        "its own map keeps fusing the others'.",
        "",
    ]
    return lines
