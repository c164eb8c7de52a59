"""Finished maps fused over a graph in synchronous rounds (``octofuse fuse``)."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterator

from ..config import CHANNEL_FILTER, FuseConfig
from ..maps.occupancy import OccupancyMap
from ..threads import ThreadBudget, budget_scope
from .agent_frames import AgentFrames
from .clock import RoundsClock
from .graph import make_graph
from .network import Network
from .results import SimResult, rule_groups, score_result
from .schedule import drop_messages, parse_schedule
from .schedule import rounds as make_rounds


def fuse_finished(
    maps: dict[str, OccupancyMap],
    central: OccupancyMap | None,
    fuse_cfg: FuseConfig,
    *,
    truth=None,
    threads: int | ThreadBudget = 0,
    score_local: bool = True,
    observer: Callable[[float, list, Network, dict], None] | None = None,
) -> SimResult:
    """Fuse finished maps over the graph for the rounds of ``fuse_cfg.schedule``
    (``rounds:N``): in a round every agent receives each neighbour's map as it was at the
    start of the round. ``threads``: a :class:`~octofuse.threads.ThreadBudget`, or its
    number of threads (0: one per core). ``fuse_cfg.loss`` drops messages
    (the same for every rule); the ``channel-filter`` runs on the links of
    ``fuse_cfg.spanning_tree`` and treats each finished map as its agent's own information.

    Each map is in its agent's frame (``fuse_cfg.agent_frames``; messages are moved into the
    receiver's, or the links aligned on first contact with ``fuse_cfg.align``) and ``central``
    in the common frame: the agents' maps are moved into it to be scored. ``score_local``:
    score the agents' own maps too (the floor). ``observer(t, round, network, {})``, if
    given, is called after every round, ``t`` its index (the rounds' ``time_s``), as
    :func:`~octofuse.fusion.simulate.simulate` calls it after a group of exchanges."""
    spec = parse_schedule(fuse_cfg.schedule)
    if spec.kind != "rounds":
        raise ValueError(
            f"schedule {fuse_cfg.schedule!r}: finished maps are fused in rounds "
            "(rounds:N); aperiodic and periodic schedules need the bags (`run`)"
        )
    with budget_scope(threads) as budget:
        return _fuse_rounds(maps, central, fuse_cfg, spec, truth, budget, score_local, observer)


def _fuse_rounds(maps, central, fuse_cfg, spec, truth, budget, score_local, observer):
    """:func:`fuse_finished` on ``budget``, its schedule ``spec`` parsed."""
    rules = list(fuse_cfg.rules)
    agents = list(maps)
    if len(agents) < 2:
        raise ValueError(f"fusion needs at least 2 agent maps, got {len(agents)}")
    frames = AgentFrames.from_config(agents, fuse_cfg)
    graph = make_graph(fuse_cfg.topology, len(agents), seed=fuse_cfg.seed, names=agents)
    rounds = make_rounds(graph, int(spec.value), directions=fuse_cfg.directions)
    if fuse_cfg.loss > 0:
        flat = drop_messages([e for rnd in rounds for e in rnd], fuse_cfg.loss, fuse_cfg.seed)
        sizes, rounds = [len(rnd) for rnd in rounds], []
        for n in sizes:
            rounds.append(flat[:n])
            flat = flat[n:]
    tree = None
    if CHANNEL_FILTER in rules:
        from .channel_filter import spanning_tree

        tree = spanning_tree(graph, fuse_cfg.spanning_tree)
    first = next(iter(maps.values()))
    net = Network(
        agents,
        rules,
        fuse_cfg,
        lambda: OccupancyMap(first.resolution),
        budget,
        tree=tree,
        frames=frames,
    )
    net.start_from(maps)  # fused in place
    t_all = time.perf_counter()
    for t, _, group in RoundsClock(rounds).steps():
        net.exchange(group)  # double-buffered: contents taken before fusing
        if observer is not None and group:
            observer(t, group, net, {})
    fused, unclamped = net.result_maps()
    res = SimResult(
        agents,
        rules,
        graph,
        [e for r in rounds for e in r],
        central,
        dict(maps),
        fused,
        {r: {a: net.loss_map(r, a) for a in agents} for r in rules},
        net.traffic,
        [],
        net.timings,
        memory=net.memory(),
        tree=tree,
        unclamped=unclamped,
        frames=frames.frames,
        alignment=frames.report(),
    )
    if central is not None:
        t0 = time.perf_counter()
        res.scores = score_result(
            res, fuse_cfg.overconfidence_tol, truth, budget, local=score_local
        )
        res.timings["scoring (wall)"] = time.perf_counter() - t0
    res.timings["total"] = time.perf_counter() - t_all
    return res


def fuse_finished_in_rule_groups(
    maps: dict[str, OccupancyMap],
    central: OccupancyMap | None,
    fuse_cfg: FuseConfig,
    *,
    truth=None,
    threads: int | ThreadBudget = 0,
) -> Iterator[SimResult]:
    """:func:`fuse_finished` a few rules at a time (one per thread, side by side), so that a
    caller can write those rules' maps and free them before the next ones run: the rules' maps
    never meet, so every rule's result is the one of the run with all rules. The agents' own
    maps are scored with the first rules. With alignment on first contact (``fuse_cfg.align``)
    every rule runs in one group (:func:`~octofuse.fusion.results.rule_groups`)."""
    with budget_scope(threads) as budget:
        for k, group in enumerate(rule_groups(fuse_cfg, budget.threads)):
            yield fuse_finished(
                maps,
                central,
                dataclasses.replace(fuse_cfg, rules=group),
                truth=truth,
                threads=budget,
                score_local=k == 0,
            )
