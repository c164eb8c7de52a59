"""The network in time (``octofuse run``): mapping and fusion interleaved as the bags were recorded."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator
from dataclasses import replace

from ..config import CHANNEL_FILTER, EXACT_MODES, BuildConfig, FuseConfig
from ..lanes import Lanes
from ..maps.build import trace_scans
from ..maps.compare import compare, compare_many
from ..maps.occupancy import OccupancyMap, ReferenceMap
from ..maps.ray_batches import apply_rays
from ..maps.ray_replay import RayReplay
from ..memory import return_freed_memory
from ..scans.replay import ScanReplay
from ..scans.source import ScanSource, prefetch
from ..threads import ThreadBudget, budget_scope
from .agent_frames import AgentFrames
from .central_replay import CentralReplay
from .clock import SCANS, BagClock
from .network import Network
from .results import LOCAL, SimResult, rule_groups, score_agent, timeline_point, with_traffic
from .robust import admitted, vote_for_run
from .schedule import EXCHANGE, VOTE, check_samples, moments, parse_schedule, run_schedule

#: the lane of the maps in the common frame (centralized) and the agents' own maps
COMMON = "common frame"


def _scored_as(lane: str) -> str:
    """What a lane's maps are scored as: its rule, or the local-only maps (the common lane)."""
    return LOCAL if lane == COMMON else lane


def simulate(
    build_cfg: BuildConfig,
    fuse_cfg: FuseConfig,
    *,
    samples: int = 12,
    truth=None,
    progress: Callable[[int, int], None] | None = None,
    source: ScanSource | ScanReplay | None = None,
    observer: Callable[[float, list, Network, dict], None] | None = None,
    local: bool = True,
    rays: RayReplay | None = None,
    central_replay: CentralReplay | None = None,
    keep_loss_leaves: bool = False,
    budget: ThreadBudget | None = None,
) -> SimResult:
    """Run the network in time: every agent maps its own scans in time order and, at each
    communication event, fuses the received map into its own (first in, first out), then
    keeps mapping on the fused map. All rules (and the local-only and centralized maps) run
    in one pass over the scans: each scan's rays are cast once and applied to every map.
    Each rule's maps are a lane of their own (:mod:`octofuse.lanes`), so that no rule waits
    for the others at every exchange; lanes, ray tracing and fusion share ``budget`` (by
    default one of ``build_cfg.threads``); the result is that of one thread.

    ``fuse_cfg.schedule`` is ``aperiodic:MEAN_S`` or ``periodic:PERIOD_S`` over the bags'
    duration. The result holds the final maps, accumulated losses, traffic, a timeline of
    KL to the centralized map (``samples`` points in time) and the scores.

    ``fuse_cfg.loss`` drops messages (the same ones for every rule); the ``channel-filter``
    runs on the links of ``fuse_cfg.spanning_tree`` only. An agent of ``fuse_cfg.agent_frames``
    maps its scans in its own frame (they reach the centralized map moved by its frame, its maps
    are moved into the common frame to be scored; :mod:`.agent_frames`).
    ``observer(t, group, network, scans)``, if given, is called after every group of exchanges
    with the number of scans inserted so far per agent. ``local``: map, sample and score the
    agents' own maps too (the floor; robust fusion votes on them). ``rays``: the batches'
    rays as traced in an earlier pass over the same scans, or kept for later passes;
    ``central_replay``: the centralized map and its snapshots as mapped and taken in an
    earlier pass, or kept for later passes. ``keep_loss_leaves``: keep the loss maps' leaves
    as the final scores read them (:meth:`SimResult.loss_leaves_of`, for a loss histogram; 5
    bytes a leaf), instead of letting them go once scored.
    """
    check_samples(samples)
    rules = list(fuse_cfg.rules)
    spec = parse_schedule(fuse_cfg.schedule)
    if fuse_cfg.robust.enabled and not local:
        raise ValueError("robust fusion votes on the agents' own maps: simulate them (local=True)")
    if spec.kind == "rounds":
        raise ValueError(
            "schedule 'rounds:N' fuses finished maps: use `octofuse fuse`; "
            "`run` takes aperiodic:MEAN_S or periodic:PERIOD_S"
        )
    t_all = time.perf_counter()
    trace = rays.next_pass() if rays is not None else trace_scans
    with (
        _opened(source, build_cfg) as src,
        budget_scope(budget or build_cfg.threads) as budget,
        Lanes(budget) as lanes,
    ):
        done = [0]
        agents = [a.name for a in src.agents]
        start = src.bags.start_ns
        graph, duration, events = run_schedule(fuse_cfg, agents, start, src.bags.end_ns)
        mk = lambda: OccupancyMap.from_config(build_cfg.map)  # noqa: E731
        tree = exact = None
        if CHANNEL_FILTER in rules:
            from .channel_filter import spanning_tree

            tree = spanning_tree(graph, fuse_cfg.spanning_tree)
        if any(r in EXACT_MODES for r in rules):
            from .channel_filter import open_map

            exact = open_map(mk())  # the centralized map without clamping
        frames = AgentFrames.from_config(agents, fuse_cfg)
        net = Network(agents, rules, fuse_cfg, mk, budget, tree=tree, frames=frames)
        own = {a: mk() for a in agents} if local else {}
        replayed = central_replay is not None and central_replay.replaying
        central = central_replay.map if replayed else mk()
        # the maps of the common frame mapped in this pass
        common = ([] if replayed else [central]) + ([exact] if exact is not None else [])
        inserted: dict[str, int] = {a: 0 for a in agents}

        # Each rule's maps are a lane of their own (inserted into, fused, scored, in order),
        # and so are the maps of the common frame with the agents' own maps: the lanes meet
        # only where a score needs the centralized map as it was at that time (a snapshot the
        # common lane reads, and goes on inserting).
        lane_maps = {
            r: {id(m) for n in net.nodes[r].values() for m in n.scan_targets()} for r in rules
        }
        lane_maps[COMMON] = {id(m) for m in [*common, *own.values()]}
        sampled: dict = {}  # lane -> its last scores, while its maps are unchanged since
        taken: list = []  # (time, the scores of every lane)

        def submit(lane, fn, after=(), key: str | None = None):
            def run():
                t0 = time.perf_counter()
                try:
                    return fn()
                finally:
                    if key is not None:
                        net.add_time(key, t0)

            return lanes.submit(lane, run, after)

        tol = fuse_cfg.overconfidence_tol

        def scores_of(r: str, maps: dict, ref: ReferenceMap) -> list:
            """The agents' maps ``maps`` of rule ``r`` scored against the centralized map
            ``ref``."""
            as_is = [a for a in agents if r not in EXACT_MODES and frames.frames.get(a) is None]
            scores = dict(zip(as_is, compare_many(ref, [maps[a] for a in as_is], tol)))
            for a in agents:
                if a not in scores:  # a copy scored: moved into the common frame, or clamped
                    m = frames.to_common(a, maps[a])
                    if r in EXACT_MODES:
                        from .channel_filter import clamped

                        m = clamped(m)
                    scores[a] = compare(ref, m, tol)
            return [scores[a] for a in agents]

        def final_scores(lane, ref: ReferenceMap, last) -> tuple[dict, dict, dict]:
            """The lane's final maps as scored and written, their scores (without traffic)
            and, if kept, their loss leaves as read for the scores. ``last``: the lane's last
            sample, if its maps did not change since."""
            r = _scored_as(lane)
            maps = own if lane == COMMON else net.scored_maps(lane)
            compared = dict(zip(agents, last.result())) if last is not None else {}
            has_loss = r not in (LOCAL, *EXACT_MODES)

            def read(a):  # the values and depths of a's loss map's leaves
                return net.loss_map(r, a).values_depths()

            # kept leaves are read first, all of them; others one by one, each let go once
            # its agent is scored
            leaves = {a: read(a) for a in agents} if has_loss and keep_loss_leaves else {}
            return (
                maps,
                {
                    a: score_agent(
                        maps[a],
                        ref,
                        tol,
                        frame=frames.frames.get(a),
                        truth=truth,
                        loss=(leaves[a] if a in leaves else read(a)) if has_loss else None,
                        compared=None if frames.frames.get(a) is not None else compared.get(a),
                    )
                    for a in agents
                },
                leaves,
            )

        def snapshot(key: str):
            """The centralized map as it is now, as scored against (a future)."""
            if replayed:
                return central_replay.take()
            ref = submit(COMMON, lambda: ReferenceMap(central), key=key)
            return central_replay.keep(ref) if central_replay is not None else ref

        def sample(t):
            ref = snapshot("scoring")
            scored = []
            for lane, maps in ([(COMMON, own)] if local else []) + [
                (r, net.fused[r]) for r in rules
            ]:
                r = _scored_as(lane)
                sampled[lane] = submit(
                    lane,
                    lambda r=r, maps=maps: scores_of(r, maps, ref.result()),
                    after=() if lane == COMMON else [ref],
                    key="scoring",
                )
                scored.append((r, sampled[lane]))
            taken.append((t, scored))

        vote: list = []  # robust fusion: the vote, once taken
        timed = moments(
            events,
            duration,
            samples,
            vote_time=min(fuse_cfg.robust.time, duration) if fuse_cfg.robust.enabled else None,
        )
        trimmed: list = []  # the replayed rays' memory given back, once

        def scans_in(batch):
            t0 = time.perf_counter()
            # every map a scan goes into, its rays traced once (the exact modes' with open
            # clamping); the centralized maps in the common frame: scans of agents with a
            # frame moved there
            targets = [
                [m for r in rules for m in net.nodes[r][agents[s.agent]].scan_targets()]
                + ([own[agents[s.agent]]] if local else [])
                for s in batch
            ]
            scans, per_scan = frames.scan_targets(batch, targets, common)
            # its grid only, not its nodes
            with budget.core() as threads:
                traced = trace(scans, central, threads, build_cfg.insert_mode)
            net.add_time("insertion", t0)
            applied = []
            for lane, ids in lane_maps.items():
                if not ids:  # the common lane of a pass that replays the centralized map
                    continue
                into = [[m for m in t if id(m) in ids] for t in per_scan]
                sampled.pop(lane, None)
                applied.append(
                    submit(lane, lambda into=into: apply_rays(traced, into, 1), key="insertion")
                )
            if rays is not None and rays.given_back and not trimmed:
                # the replayed rays, once applied, leave the heap's pages free: given back
                # before the maps grow to their peak
                trimmed.append(True)
                submit(COMMON, lambda: return_freed_memory(pools=False), after=applied)
            for s in batch:
                inserted[agents[s.agent]] += 1
            done[0] += len(batch)
            if progress:
                progress(done[0], src.total_scans)

        def exchanges_out(t, group):
            group = admitted(group, vote[0] if vote else None, fuse_cfg, agents)
            if not group:
                return
            if frames.align != "off":  # on the maps as they are at this time
                lanes.wait()
                net.align(group)
            for r in rules:
                sampled.pop(r, None)
                submit(r, lambda r=r, group=group: net.exchange_rule(r, group))
            if observer is not None:
                lanes.wait()
                observer(t, group, net, dict(inserted))

        def vote_now(t):
            def on_own_maps():  # in the common frame, once the common lane inserted its scans
                own_maps = {a: frames.to_common(a, m) for a, m in own.items()}
                return vote_for_run(own_maps, graph, fuse_cfg, t)

            vote.append(submit(COMMON, on_own_maps).result())

        # the mission: scans in, exchanges out, samples and the vote at their times
        t_run = time.perf_counter()
        clock = BagClock(timed, start, build_cfg.batch_size)
        for t, kind, what in clock.steps(prefetch(src.scans())):
            if kind == SCANS:
                scans_in(what)
            elif kind == EXCHANGE:
                exchanges_out(t, what)
            elif kind == VOTE:
                vote_now(t)
            else:
                sample(t)
        # each lane scores its final maps as soon as it is done (a lane that ends first
        # scores while the others still fuse), against the final centralized map
        ref = snapshot("final scores")
        finals = {
            lane: submit(
                lane,
                lambda lane=lane, last=sampled.get(lane): final_scores(lane, ref.result(), last),
                after=() if lane == COMMON else [ref],
                key="final scores",
            )
            for lane in lane_maps
            if lane != COMMON or local
        }
        lanes.wait()
        net.add_time("mapping + fusion (wall)", t_run)
        if central_replay is not None:
            central_replay.end_pass(central)
        src.check_placed()
        stats, notes = src.stats, src.notes()
    timeline = [
        timeline_point(t, r, a, s)
        for t, scored in taken
        for r, fut in scored
        for a, s in zip(agents, fut.result())
    ]
    final = {_scored_as(lane): fut.result() for lane, fut in finals.items()}
    final = {r: final[r] for r in ([LOCAL] if local else []) + rules}  # the scores' order
    fused = {r: final[r][0] for r in rules}
    res = SimResult(
        agents,
        rules,
        graph,
        events,
        central,
        own,
        fused,
        {r: {a: net.loss_map(r, a) for a in agents} for r in rules},
        net.traffic,
        timeline,
        net.timings,
        build_stats=stats,
        build_notes=notes,
        memory=net.memory(),
        tree=tree,
        unclamped=net.unclamped_maps(),
        central_unclamped=exact,
        frames=frames.frames,
        alignment=frames.report(),
        loss_leaves={r: final[r][2] for r in rules},
    )
    if vote:
        res.robust, res.excluded = vote[0], list(vote[0].excluded)
    res.scores = with_traffic({r: scores for r, (_, scores, _) in final.items()}, net.traffic)
    res.timings["total"] = time.perf_counter() - t_all
    return res


def simulate_in_rule_groups(
    build_cfg: BuildConfig,
    fuse_cfg: FuseConfig,
    *,
    samples: int = 12,
    truth=None,
    progress: Callable[[int, int], None] | None = None,
    source: ScanSource | None = None,
    keep_loss_leaves: bool = False,
    budget: ThreadBudget | None = None,
) -> Iterator[SimResult]:
    """:func:`simulate` with at most ``fuse_cfg.rules_per_pass`` rules at a time (0: all),
    replaying the bags once per group, so that a caller can write a group's maps and free them
    before the next group runs. The rules' maps never meet, so every rule's result is the one
    of the run with all rules. The agents' own maps are mapped and scored in the first pass
    only. Robust fusion and alignment on first contact run every rule in one pass
    (:func:`~octofuse.fusion.results.rule_groups`). ``progress`` counts the scans of every
    pass. The bags (or ``source``) are read in the first pass; later passes replay its scans
    (:class:`~octofuse.scans.replay.ScanReplay`), their rays
    (:class:`~octofuse.maps.ray_replay.RayReplay`) and the centralized map with its snapshots
    (:class:`~.central_replay.CentralReplay`)."""
    groups = rule_groups(fuse_cfg, fuse_cfg.rules_per_pass)
    with _opened(source, build_cfg) as src, budget_scope(budget or build_cfg.threads) as budget:
        scans = ScanReplay(src, len(groups))  # decoded and placed once for every pass
        rays = RayReplay(len(groups))  # and traced once
        central = CentralReplay(len(groups))  # and the centralized map mapped once
        for k, group in enumerate(groups):
            step = (
                None
                if progress is None
                else (lambda done, total, k=k: progress(k * total + done, len(groups) * total))
            )
            yield simulate(
                build_cfg,
                replace(fuse_cfg, rules=group),
                samples=samples,
                truth=truth,
                progress=step,
                source=scans,
                local=k == 0,
                rays=rays,
                central_replay=central,
                keep_loss_leaves=keep_loss_leaves,
                budget=budget,
            )


def _opened(source, build_cfg: BuildConfig):
    """``source`` as a context that leaves it open, or a :class:`ScanSource` of the bags."""
    return contextlib.nullcontext(source) if source is not None else ScanSource(build_cfg)
