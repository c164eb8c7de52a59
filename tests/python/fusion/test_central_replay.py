"""The centralized map mapped once for every pass over the same scans
(fusion/central_replay.py)."""

from __future__ import annotations

import sys
from concurrent.futures import Future
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
import bagfactory as bf  # noqa: E402
from bagfactory import assert_same_map  # noqa: E402
from octofuse.config import AgentFrame, FuseConfig  # noqa: E402
from octofuse.fusion.central_replay import CentralReplay  # noqa: E402
from octofuse.fusion.results import merge_rule_results  # noqa: E402
from octofuse.fusion.simulate import simulate, simulate_in_rule_groups  # noqa: E402
from octofuse.maps.build import make_build_config  # noqa: E402
from octofuse.maps.occupancy import OccupancyMap  # noqa: E402


def done(value) -> Future:
    f: Future = Future()
    f.set_result(value)
    return f


def test_later_passes_take_the_first_passes_snapshots_in_order():
    replay = CentralReplay(passes=3)
    central = OccupancyMap(0.1)
    assert not replay.replaying
    taken = [replay.keep(done(k)) for k in range(3)]
    replay.end_pass(central)
    for _ in range(2):
        assert replay.replaying and replay.map is central
        assert [replay.take() for _ in range(3)] == taken
        replay.end_pass(central)
    assert replay._snapshots == [None] * 3  # the last pass let every snapshot go


def test_a_pass_that_takes_other_snapshots_is_refused():
    replay = CentralReplay(passes=3)
    replay.keep(done(0))
    replay.end_pass(OccupancyMap(0.1))
    replay.take()
    with pytest.raises(RuntimeError, match="pass 2 takes snapshot 2, the first pass took 1"):
        replay.take()
    replay = CentralReplay(passes=2)
    replay.keep(done(0))
    replay.keep(done(1))
    replay.end_pass(OccupancyMap(0.1))
    replay.take()
    with pytest.raises(RuntimeError, match="pass 2 took 1 of the first pass's 2 snapshots"):
        replay.end_pass(replay.map)
    one = CentralReplay(passes=1)
    one.keep(done(0))
    assert one._snapshots == []  # nothing to keep for


def test_passes_with_an_agent_in_its_own_frame_give_the_run_in_one_pass(tmp_path):
    """Only the first pass maps the centralized map (the framed agent's scans moved into it);
    later passes score against its snapshots: every rule gets the maps, scores and timeline
    of the run with all rules in one pass."""
    bag = bf.team_bag(tmp_path, 3, 4)
    bcfg = make_build_config(bag, resolution=0.1, threads=1)
    rules = ["naive-bayes", "min-info-loss"]
    cfg = dict(
        rules=rules,
        topology="line",
        schedule="periodic:0.5",
        agent_frames=[AgentFrame("b", [0.2, 0.0, 0.0, 0.0, 0.0, 0.0])],
    )
    one = simulate(bcfg, FuseConfig(**cfg), samples=3)
    parts = list(simulate_in_rule_groups(bcfg, FuseConfig(**cfg, rules_per_pass=1), samples=3))
    assert all(p.central is parts[0].central for p in parts)  # mapped once
    assert_same_map(parts[0].central, one.central, "centralized")
    assert merge_rule_results(parts).timeline == one.timeline
    for p, r in zip(parts, rules):
        assert p.rules == [r]
        for a in one.agents:
            assert p.scores[r][a] == one.scores[r][a], (r, a)
            assert_same_map(p.fused[r][a], one.fused[r][a], (r, a))
