"""What a run of the network gives: the maps, losses, traffic and scores per rule and agent,
how its rules are grouped into passes and how the groups' results merge, and its scoring."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

from ..config import EXACT_MODES, FuseConfig
from ..maps.compare import Score, compare_many, score
from ..maps.infoloss import InfoLossMap
from ..maps.occupancy import OccupancyMap
from ..threads import thread_map
from .agent_frames import moved
from .graph import Graph
from .schedule import Exchange

LOCAL = "local-only"


@dataclass
class Traffic:
    sent: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    received: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    sent_32b: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    messages: int = 0
    lost: int = 0  #: messages sent that never arrived (counted in ``sent``, not ``received``)
    fusions: list[FusionEvent] = field(default_factory=list)  #: messages fused, in order


@dataclass(frozen=True)
class FusionEvent:
    """One message fused: when, by which rule, from whom into whom, the voxels fused and the
    information loss summed over them (nats; None where the loss is not kept)."""

    time_s: float
    rule: str
    sender: str
    receiver: str
    voxels: int | None
    loss: float | None

    @property
    def mean_loss(self) -> float | None:
        """Loss per fused voxel (None without loss or voxels)."""
        return self.loss / self.voxels if self.loss is not None and self.voxels else None

    def to_dict(self) -> dict:
        return {
            "t": self.time_s,
            "rule": self.rule,
            "sender": self.sender,
            "receiver": self.receiver,
            "voxels": self.voxels,
            "loss": self.loss,
            "mean_loss": self.mean_loss,
        }


@dataclass
class SimResult:
    """Everything a fusion run produced."""

    agents: list[str]
    rules: list[str]
    graph: Graph
    events: list[Exchange]
    central: OccupancyMap | None  #: None when fusing finished maps without one
    local: dict[str, OccupancyMap]
    fused: dict[str, dict[str, OccupancyMap]]  #: rule -> agent -> map
    loss: dict[str, dict[str, InfoLossMap]]  #: rule -> agent -> accumulated loss
    traffic: dict[str, Traffic]  #: rule -> traffic
    timeline: list[dict] = field(
        default_factory=list
    )  #: samples {t, rule, agent, kl, overconfidence}
    timings: dict[str, float] = field(default_factory=lambda: defaultdict(float))
    scores: dict[str, dict[str, Score]] = field(default_factory=dict)  #: rule|local-only -> agent
    build_stats: list = field(default_factory=list)
    build_notes: list[str] = field(default_factory=list)  #: skipped transforms, dropped points
    #: robust fusion: the robots voted out (their messages were not fused) and the vote
    #: (:class:`octofuse.fusion.robust.RobustOutcome`, None without robust fusion)
    excluded: list[str] = field(default_factory=list)
    robust: object | None = None
    #: rule -> agent -> {"map": bytes of the agent's map, "links": bytes of its per-link state
    #: (channel-filter: the neighbours' contributions; deltas: the maps they are taken against)}
    memory: dict[str, dict[str, dict[str, int]]] = field(default_factory=dict)
    #: the channel filter's links (agent index pairs) and its unclamped agent maps (``fused``
    #: holds them clamped, as scored and written)
    tree: tuple | None = None
    unclamped: dict[str, OccupancyMap] = field(default_factory=dict)
    #: the centralized map without clamping (runs with the channel filter): the exact target
    central_unclamped: OccupancyMap | None = None
    #: agent -> its map frame into the common frame (agents in the common frame left out),
    #: and per link the alignment on first contact (:mod:`octofuse.fusion.agent_frames`)
    frames: dict = field(default_factory=dict)
    alignment: list[dict] = field(default_factory=list)
    #: rule -> agent -> the values and depths of its loss map's leaves, once read
    #: (:meth:`loss_leaves_of`)
    loss_leaves: dict[str, dict[str, tuple]] = field(default_factory=dict)

    def loss_leaves_of(self, rule: str, agent: str) -> tuple:
        """The values and depths of the leaves of ``agent``'s loss map under ``rule``
        (:meth:`~octofuse.maps.infoloss.InfoLossMap.values_depths`), read once for the scores
        and the loss histogram."""
        per = self.loss_leaves.setdefault(rule, {})
        if agent not in per:
            per[agent] = self.loss[rule][agent].values_depths()
        return per[agent]


def rule_time_part(rule: str) -> str:
    """The part of a run's timings that holds one rule's exchanges and fusions (the time of
    the thread that ran them, summed over the run)."""
    return f"exchange + fusion: {rule}"


def ordered_timings(res: SimResult) -> dict[str, float]:
    """``res.timings`` with each rule's own part after the others, in the order of its rules."""
    own = [rule_time_part(r) for r in res.rules]
    out = {k: v for k, v in res.timings.items() if k not in own}
    out.update((k, res.timings[k]) for k in own if k in res.timings)
    return out


def timeline_point(t: float, rule: str, agent: str, compared) -> dict:
    """One point of a run's KL timeline: ``agent``'s map of ``rule`` compared with the
    centralized map at time ``t`` (a :class:`~octofuse.maps.compare.Comparison`)."""
    return {
        "t": t,
        "rule": rule,
        "agent": agent,
        "kl": compared.kl_mean,
        "overconfidence": compared.overconfidence,
        "coverage": compared.coverage,
    }


def score_result(
    res: SimResult, tol: float, truth=None, threads: int = 1, local: bool = True
) -> dict[str, dict[str, Score]]:
    """Scores of every agent for every rule, and (``local``) of the local-only maps (the
    floor), with their traffic."""
    jobs = ([(LOCAL, a) for a in res.agents] if local else []) + [
        (r, a) for r in res.rules for a in res.agents
    ]
    agent_map = lambda r, a: res.local[a] if r == LOCAL else res.fused[r][a]  # noqa: E731
    # maps in the common frame: compared as they are, on both threads
    as_is = [j for j in jobs if res.frames.get(j[1]) is None]
    compared = dict(
        zip(as_is, compare_many(res.central, [agent_map(*j) for j in as_is], tol, threads))
    )

    def one(job):
        r, a = job
        return score_agent(
            agent_map(r, a),
            res.central,
            tol,
            frame=res.frames.get(a),
            loss=None if r in (LOCAL, *EXACT_MODES) else res.loss_leaves_of(r, a),
            truth=truth,
            compared=compared.get(job),
        )

    out: dict[str, dict[str, Score]] = {}
    for (r, a), s in zip(jobs, thread_map(one, jobs, threads)):
        out.setdefault(r, {})[a] = s
    return with_traffic(out, res.traffic)


def score_agent(
    m: OccupancyMap,
    central,
    tol: float,
    *,
    frame=None,
    loss: InfoLossMap | tuple | None = None,
    truth=None,
    compared: Score | None = None,
) -> Score:
    """One agent's map of a rule (or its own map) scored against the centralized map (an
    :class:`OccupancyMap` or a ``ReferenceMap``), in the common frame (``frame``: the agent's
    map frame there, None if it maps in it), without its traffic. ``loss``: its accumulated
    loss, as :func:`~octofuse.maps.compare.score` takes it (None for the local-only maps and
    the exact filter). ``compared``: the comparison of ``m`` with the centralized map, where
    it was taken already."""
    return score(moved(m, frame), central, tol=tol, loss=loss, truth=truth, compared=compared)


def with_traffic(
    scores: dict[str, dict[str, Score]], traffic: dict[str, Traffic]
) -> dict[str, dict[str, Score]]:
    """``scores`` (rule -> agent -> score) with each rule's bytes sent and received."""
    for r, per in scores.items():
        if r in traffic:
            tr = traffic[r]
            for a, s in per.items():
                s.bytes_sent, s.bytes_received = tr.sent[a], tr.received[a]
                s.bytes_sent_32b = tr.sent_32b[a]
    return scores


def rule_groups(fuse_cfg: FuseConfig, size: int) -> list[list[str]]:
    """``fuse_cfg.rules`` in groups of at most ``size`` (0: one group), to run one group after
    the other: the rules' maps never meet, so each rule's result is that of the run with every
    rule. Robust fusion (its vote is taken once, before the rules' exchanges) and alignment on
    first contact (on the first rule's maps) put every rule in one group."""
    rules = list(fuse_cfg.rules)
    if size <= 0 or fuse_cfg.robust.enabled or fuse_cfg.align != "off":
        size = len(rules)
    return [rules[k : k + size] for k in range(0, len(rules), size)]


def without_maps(res: SimResult) -> SimResult:
    """``res`` without its rules' maps (``fused``, ``loss``, ``unclamped``) and the loss
    leaves read from them: what a caller keeps of a group of rules once its maps are written,
    so that they can be freed."""
    return replace(res, fused={}, loss={}, unclamped={}, loss_leaves={})


def merge_rule_results(parts: Sequence[SimResult]) -> SimResult:
    """One result from the results of the same run with different rules (e.g.
    :func:`octofuse.fusion.rounds.fuse_finished_in_rule_groups`), without the rules' maps (``fused``,
    ``loss`` and ``unclamped`` are left empty: written and freed by the caller). Times add up."""
    first = parts[0]
    timings: dict[str, float] = defaultdict(float)
    for p in parts:
        for k, v in p.timings.items():
            timings[k] += v
    scores: dict[str, dict[str, Score]] = {}
    for p in parts:
        scores.update(p.scores)
    tree = next((p.tree for p in parts if p.tree is not None), None)
    exact = next((p.central_unclamped for p in parts if p.central_unclamped is not None), None)
    return replace(
        without_maps(first),
        rules=[r for p in parts for r in p.rules],
        traffic={r: p.traffic[r] for p in parts for r in p.rules},
        # in time order, each time's samples in rule order: as in the run with every rule
        timeline=sorted((s for p in parts for s in p.timeline), key=lambda s: s["t"]),
        timings=timings,
        scores=scores,
        memory={r: m for p in parts for r, m in p.memory.items()},
        tree=tree,
        central_unclamped=exact,
    )
