"""Fusion across a communication graph: rumour propagation, exchange semantics, delta
messages, traffic and the order of scans and exchanges in time.

Agents are robots of :func:`bagfactory.team` in the box room. Finished maps come straight
from their shots (``bagfactory.reference_maps``); runs in time read a small bag written with
rosbags. Expected maps are computed here by replaying the same scans and messages with
:func:`octofuse.fuse_into` on copies, one event at a time.
"""

from __future__ import annotations

import sys
from collections import defaultdict
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bagfactory as bf  # noqa: E402
import octofuse  # noqa: E402
from bagfactory import T0, Robot, S, assert_same_map, voxel_keys  # noqa: E402
from octofuse import (  # noqa: E402
    InfoLossMap,
    OccupancyMap,
    _core,  # noqa: E402
    fuse_into,
    fuse_maps,
)
from octofuse.config import FuseConfig  # noqa: E402
from octofuse.fusion.graph import make_graph  # noqa: E402
from octofuse.fusion.results import LOCAL, rule_time_part
from octofuse.fusion.rounds import fuse_finished
from octofuse.fusion.schedule import Exchange, parse_schedule, periodic, rounds  # noqa: E402
from octofuse.fusion.simulate import simulate  # noqa: E402
from octofuse.maps.build import make_build_config  # noqa: E402
from octofuse.scans.source import ScanSource  # noqa: E402
from octofuse.threads import ThreadBudget  # noqa: E402

RES = 0.2
WEP = [r for r in octofuse.RULES if r != "naive-bayes"]
SOME_RULES = ["naive-bayes", "chernoff", "min-info-loss"]


# -- helpers ----------------------------------------------------------------------------------


def mean(scores: dict, key: str) -> float:
    return float(np.mean([getattr(s, key) for s in scores.values()]))


def finished_maps(n: int, n_scans: int = 4, resolution: float = RES):
    """Local maps of ``n`` team robots and the centralized map."""
    robots = bf.team(n)
    rec = bf.robot_recording(robots, bf.team_times(robots, n_scans))
    maps = bf.reference_maps(rec.shots, bf.team_agents(robots), resolution=resolution)
    central = maps.pop("centralized")
    return maps, central


def delta_message(current: OccupancyMap, previous: OccupancyMap) -> OccupancyMap:
    return OccupancyMap._wrap(_core._changed_voxels(current._m, previous._m))


class Replay:
    """Agents' maps for one rule, updated one event at a time: a message carries its sender's
    map as it was at the start of its group of simultaneous events (or, with ``delta``, the
    voxels of that map changed since the last message on the link)."""

    def __init__(self, maps: dict[str, OccupancyMap], rule: str, delta: bool = False):
        self.names = list(maps)
        self.maps = {a: m.copy() for a, m in maps.items()}
        self.rule, self.delta = rule, delta
        res = next(iter(maps.values())).resolution
        self.loss = {a: InfoLossMap(res) for a in self.names}
        self.sent: dict[str, int] = defaultdict(int)
        self.received: dict[str, int] = defaultdict(int)
        self.sent_32b: dict[str, int] = defaultdict(int)
        self.messages = 0
        self.snapshots: dict[tuple[str, str], OccupancyMap] = {}

    def group(self, events) -> None:
        before = {a: m.copy() for a, m in self.maps.items()}
        for e in events:
            s, d = self.names[e.sender], self.names[e.receiver]
            msg = before[s]
            if self.delta:
                prev = self.snapshots.get((s, d))
                self.snapshots[(s, d)] = before[s]
                if prev is not None:
                    msg = delta_message(before[s], prev)
            fuse_into(self.maps[d], msg, rule=self.rule, loss=self.loss[d])
            self.sent[s] += 5 * msg.num_nodes
            self.received[d] += 5 * msg.num_nodes
            self.sent_32b[s] += 32 * msg.num_leaves
            self.messages += 1


def groups_of(events):
    out: list[list[Exchange]] = []
    for e in events:
        if out and out[-1][0].time_s == e.time_s:
            out[-1].append(e)
        else:
            out.append([e])
    return out


def assert_same_traffic(traffic, replay: Replay) -> None:
    assert traffic.messages == replay.messages
    for a in replay.names:
        assert traffic.sent[a] == replay.sent[a], a
        assert traffic.received[a] == replay.received[a], a
        assert traffic.sent_32b[a] == replay.sent_32b[a], a


def assert_same_loss(got: InfoLossMap, want: InfoLossMap, what: str) -> None:
    gk, gv = voxel_keys(got)
    wk, wv = voxel_keys(want)
    np.testing.assert_array_equal(gk, wk, err_msg=what)
    np.testing.assert_array_equal(gv, wv, err_msg=what)


def assert_loss_of_fused_voxels(
    got: InfoLossMap, want: InfoLossMap, a: OccupancyMap, b: OccupancyMap, what: str
) -> None:
    """``got`` (accumulated by in-place fusion) holds the voxels both maps know, with the loss
    of ``want`` (from :func:`fuse_maps`, which also lists the copied voxels, at zero loss)."""
    both = np.intersect1d(voxel_keys(a)[0], voxel_keys(b)[0])
    gk, gv = voxel_keys(got)
    wk, wv = voxel_keys(want)
    np.testing.assert_array_equal(gk, both, err_msg=what)
    fused = np.isin(wk, both)
    np.testing.assert_array_equal(gv, wv[fused], err_msg=what)
    assert np.all(wv[~fused] == 0), what


# -- fixtures ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def four():
    """Finished maps of 4 robots and their centralized map."""
    return finished_maps(4)


@pytest.fixture(scope="module")
def ring_result(four):
    """Every rule on a ring of 4 (a loop), 4 synchronous rounds of exchanges."""
    maps, central = four
    return fuse_finished(
        maps, central, FuseConfig(topology="ring", rules=list(octofuse.RULES), schedule="rounds:4")
    )


#: scans at 0.25 + 0.05 i + 0.5 k s (robot i, k = 0..3): none at a multiple of 0.33 s
PERIOD = "periodic:0.33"


@pytest.fixture(scope="module")
def team_bag(tmp_path_factory):
    return bf.team_bag(tmp_path_factory.mktemp("team"), 4, 4)


def run_config(bag, resolution=RES):
    return make_build_config(bag, resolution=resolution)


# -- rumour propagation on a loop -------------------------------------------------------------


def test_naive_bayes_rumours_make_maps_over_confident(ring_result):
    sc = ring_result.scores
    nb_oc, nb_kl = mean(sc["naive-bayes"], "overconfidence"), mean(sc["naive-bayes"], "kl_mean")
    worst_oc = max(mean(sc[r], "overconfidence") for r in WEP)
    worst_kl = max(mean(sc[r], "kl_mean") for r in WEP)
    assert nb_oc > 0.4 and nb_oc > 5 * worst_oc
    assert nb_kl > 2 * worst_kl
    for a in ring_result.agents:  # every naive-bayes agent, not only on average
        assert sc["naive-bayes"][a].overconfidence > 5 * max(sc[r][a].overconfidence for r in WEP)


def test_every_wep_rule_brings_every_agent_closer_to_the_centralized_map(ring_result):
    sc = ring_result.scores
    for r in WEP:
        for a in ring_result.agents:
            assert sc[r][a].kl_mean < 0.5 * sc[LOCAL][a].kl_mean, (r, a)
            assert sc[r][a].coverage > sc[LOCAL][a].coverage, (r, a)
            assert sc[r][a].agreement > sc[LOCAL][a].agreement, (r, a)


def test_wep_maps_stay_between_the_agents_maps(four, ring_result):
    """A WEP value is a convex combination of the values it fuses, so after any number of
    fusions every voxel lies within the range of the local maps' values there (a voxel only
    one map knows is copied). Naive-Bayes sums them and leaves that range."""
    maps, central = four
    keys, values = zip(*(voxel_keys(m) for m in maps.values()))
    k, v = np.concatenate(keys), np.concatenate(values)
    order = np.argsort(k, kind="stable")
    k, v = k[order], v[order]
    uniq, start = np.unique(k, return_index=True)
    lo, hi = np.minimum.reduceat(v, start), np.maximum.reduceat(v, start)
    ck, cv = voxel_keys(central)
    np.testing.assert_array_equal(ck, uniq)  # the agents know what the centralized map knows
    cmin, cmax = central.clamping_logodds
    outside_nb = 0
    for r in octofuse.RULES:
        for a in ring_result.agents:
            fk, fv = voxel_keys(ring_result.fused[r][a])
            np.testing.assert_array_equal(fk, uniq, err_msg=f"{r} {a}")  # 4 rounds reach all
            assert np.all((fv >= cmin - 1e-6) & (fv <= cmax + 1e-6)), (r, a)
            if r == "naive-bayes":
                outside_nb += int(np.sum((fv > hi + 1e-5) | (fv < lo - 1e-5)))
                continue
            assert np.all(fv >= lo - 1e-5) and np.all(fv <= hi + 1e-5), (r, a)
            # hence never more certain than the most certain local map or the centralized map
            assert np.all(
                np.abs(fv) <= np.maximum(np.maximum(np.abs(lo), np.abs(hi)), np.abs(cv)) + 1e-5
            ), (r, a)
    assert outside_nb > len(uniq)


def test_finished_maps_are_not_modified(four, ring_result):
    maps, _ = four
    for a, m in maps.items():
        assert ring_result.local[a] is m
        assert bf.maps_differ(ring_result.fused["chernoff"][a], m)
    fresh, _ = finished_maps(4)
    for a in maps:
        assert_same_map(maps[a], fresh[a], a)


@pytest.mark.slow
@pytest.mark.parametrize("threads", [1, 2, 3])
def test_rules_a_few_at_a_time_give_the_run_with_every_rule(four, ring_result, threads):
    """fuse_finished_in_rule_groups (what `octofuse fuse` runs, a thread's worth of rules at a time)
    gives every rule the maps, losses, traffic and scores of the run with all rules at once."""
    from octofuse.fusion.results import merge_rule_results
    from octofuse.fusion.rounds import fuse_finished_in_rule_groups

    maps, central = four
    cfg = FuseConfig(topology="ring", rules=list(octofuse.RULES), schedule="rounds:4")
    parts = list(fuse_finished_in_rule_groups(maps, central, cfg, threads=threads))
    assert [r for p in parts for r in p.rules] == list(octofuse.RULES)
    assert all(len(p.rules) <= threads for p in parts) and len(parts[0].rules) == threads
    for p in parts:
        for r in p.rules:
            for a in maps:
                assert_same_map(p.fused[r][a], ring_result.fused[r][a], (r, a))
                assert p.loss[r][a].loss_sum == ring_result.loss[r][a].loss_sum
            assert p.traffic[r] == ring_result.traffic[r]
    merged = merge_rule_results(parts)
    assert merged.rules == ring_result.rules and merged.fused == {}
    assert merged.scores.keys() == ring_result.scores.keys()
    for r, per in ring_result.scores.items():
        for a, sc in per.items():
            assert merged.scores[r][a].to_dict() == sc.to_dict(), (r, a)
    aligned = list(
        fuse_finished_in_rule_groups(
            maps,
            central,
            FuseConfig(
                topology="ring", align="planar", schedule="rounds:1", rules=list(octofuse.RULES)
            ),
            threads=threads,
        )
    )
    assert [p.rules for p in aligned] == [list(octofuse.RULES)]  # one group: links align once


# -- exchange semantics -----------------------------------------------------------------------


@pytest.mark.parametrize("delta", [False, True], ids=["whole", "delta"])
@pytest.mark.parametrize("rule", SOME_RULES)
def test_a_two_way_exchange_fuses_both_maps_from_before(rule, delta):
    maps, central = finished_maps(2)
    a, b = maps["a"].copy(), maps["b"].copy()
    res = fuse_finished(
        maps,
        central,
        FuseConfig(topology="complete", delta=delta, rules=[rule], schedule="rounds:1"),
    )
    assert res.events == [Exchange(0.0, 0, 1), Exchange(0.0, 1, 0)]
    want_a, loss_a = fuse_maps(a, b, rule=rule)
    want_b, loss_b = fuse_maps(b, a, rule=rule)
    assert_same_map(res.fused[rule]["a"], want_a, "a")
    assert_same_map(res.fused[rule]["b"], want_b, "b")
    assert_loss_of_fused_voxels(res.loss[rule]["a"], loss_a, a, b, "loss a")
    assert_loss_of_fused_voxels(res.loss[rule]["b"], loss_b, a, b, "loss b")
    assert res.loss[rule]["a"].voxels_fused == res.loss[rule]["b"].voxels_fused > 0


@pytest.mark.parametrize("delta", [False, True], ids=["whole", "delta"])
def test_messages_of_a_round_carry_the_maps_from_its_start(delta):
    """Complete graph of 3: each agent fuses the other two maps as they were before the
    round, in the order of the schedule (first in, first out)."""
    maps, central = finished_maps(3)
    rule = "naive-bayes"  # sums: any map sent after its sender fused would show
    res = fuse_finished(
        maps,
        central,
        FuseConfig(topology="complete", delta=delta, rules=[rule], schedule="rounds:1"),
    )
    m = {a: x.copy() for a, x in maps.items()}
    want = {
        "a": fuse_maps(fuse_maps(m["a"], m["b"], rule).map, m["c"], rule).map,  # b then c
        "b": fuse_maps(fuse_maps(m["b"], m["a"], rule).map, m["c"], rule).map,
        "c": fuse_maps(fuse_maps(m["c"], m["a"], rule).map, m["b"], rule).map,
    }
    for a in want:
        assert_same_map(res.fused[rule][a], want[a], a)


@pytest.mark.parametrize("directions", ["both", "one"])
@pytest.mark.parametrize("delta", [False, True], ids=["whole", "delta"])
def test_rounds_on_a_line_equal_a_replay(delta, directions):
    maps, central = finished_maps(4)
    fcfg = FuseConfig(
        topology="line", delta=delta, directions=directions, rules=SOME_RULES, schedule="rounds:3"
    )
    res = fuse_finished(maps, central, fcfg)
    graph = make_graph("line", 4)
    for rule in SOME_RULES:
        rep = Replay(maps, rule, delta)
        for rnd in rounds(graph, 3, directions):
            rep.group(rnd)
        for a in rep.names:
            assert_same_map(res.fused[rule][a], rep.maps[a], f"{rule} {a}")
            assert_same_loss(res.loss[rule][a], rep.loss[a], f"{rule} {a} loss")
        assert_same_traffic(res.traffic[rule], rep)


def test_information_travels_one_hop_per_round():
    maps, central = finished_maps(4)
    known = {a: set(voxel_keys(m)[0].tolist()) for a, m in maps.items()}
    only_d = known["d"] - known["a"] - known["b"] - known["c"]
    assert len(only_d) > 100
    for n_rounds, reached in [(1, {"c", "d"}), (2, {"b", "c", "d"}), (3, {"a", "b", "c", "d"})]:
        res = fuse_finished(
            maps,
            central,
            FuseConfig(topology="line", rules=["chernoff"], schedule=f"rounds:{n_rounds}"),
        )
        for a in maps:
            has = set(voxel_keys(res.fused["chernoff"][a])[0].tolist())
            assert (only_d <= has) == (a in reached), (n_rounds, a)
            assert not (only_d & has) or a in reached


# -- traffic ----------------------------------------------------------------------------------


def test_traffic_of_one_round_is_five_bytes_per_node(four):
    maps, central = four
    res = fuse_finished(
        maps,
        central,
        FuseConfig(topology="ring", rules=["chernoff", "naive-bayes"], schedule="rounds:1"),
    )
    graph = make_graph("ring", 4)
    names = list(maps)
    assert len(res.events) == 2 * len(graph.edges) == 8
    for rule in ("chernoff", "naive-bayes"):
        tr = res.traffic[rule]
        assert tr.messages == len(res.events)
        for i, a in enumerate(names):
            nbrs = graph.neighbors(i)
            assert tr.sent[a] == len(nbrs) * 5 * maps[a].num_nodes
            assert tr.sent_32b[a] == len(nbrs) * 32 * maps[a].num_leaves
            assert tr.received[a] == sum(5 * maps[names[j]].num_nodes for j in nbrs)
            s = res.scores[rule][a]
            assert (s.bytes_sent, s.bytes_received, s.bytes_sent_32b) == (
                tr.sent[a],
                tr.received[a],
                tr.sent_32b[a],
            )
    assert res.scores[LOCAL]["a"].bytes_sent is None


def test_fuse_finished_errors(four):
    maps, central = four
    with pytest.raises(ValueError, match="at least 2 agent maps"):
        fuse_finished({"a": maps["a"]}, central, FuseConfig(topology="ring", schedule="rounds:3"))
    with pytest.raises(ValueError, match="valid rules are: naive-bayes"):
        fuse_finished(
            maps, central, FuseConfig(topology="ring", rules=["bayes"], schedule="rounds:3")
        )
    with pytest.raises(ValueError, match="max-robust"):
        fuse_finished(maps, central, FuseConfig(topology="max-robust:4", schedule="rounds:3"))
    with pytest.raises(ValueError, match="finished maps are fused in rounds"):
        fuse_finished(maps, central, FuseConfig(topology="ring", schedule="periodic:1"))
    res = fuse_finished(
        maps, None, FuseConfig(topology="ring", rules=["chernoff"], schedule="rounds:1")
    )
    assert res.central is None and res.scores == {}


# -- delta messages ---------------------------------------------------------------------------


def test_a_delta_holds_the_new_and_changed_voxels():
    robots = bf.team(1)
    rec = bf.robot_recording(robots, bf.team_times(robots, 4))
    early = bf.reference_map(rec.shots[:2], resolution=RES)
    late = bf.reference_map(rec.shots, resolution=RES)
    d = delta_message(late, early)
    ek, ev = voxel_keys(early)
    lk, lv = voxel_keys(late)
    dk, dv = voxel_keys(d)
    pos = np.searchsorted(ek, lk).clip(max=len(ek) - 1)
    new_or_changed = (ek[pos] != lk) | (ev[pos] != lv)
    assert 0 < new_or_changed.sum() < len(lk)
    np.testing.assert_array_equal(dk, lk[new_or_changed])
    np.testing.assert_array_equal(dv, lv[new_or_changed])
    assert d.num_nodes < late.num_nodes
    assert delta_message(late, late).num_nodes == 0
    assert_same_map(delta_message(late, OccupancyMap(RES)), late)


@pytest.fixture(scope="module")
def whole_and_delta(team_bag):
    cfg = run_config(team_bag)
    out = {}
    for delta in (False, True):
        out[delta] = simulate(
            cfg,
            FuseConfig(topology="ring", schedule=PERIOD, delta=delta, rules=SOME_RULES),
            samples=0,
        )
    return out


class WatchedBudget(ThreadBudget):
    """A thread budget that keeps the most slots ever held at once."""

    most = 0

    def take(self, n: int) -> int:
        k = super().take(n)
        self._seen()
        return k

    @contextmanager
    def working(self):
        with super().working():
            self._seen()
            yield

    def _seen(self) -> None:
        with self._cond:
            self.most = max(self.most, self.threads - self._free)


def test_a_run_on_threads_gives_the_run_on_one_thread(team_bag):
    """simulate on 2 and 3 threads (each rule's maps a lane of their own, the common frame's
    maps another, meeting where a score needs the centralized map of its time) gives the
    maps, losses, traffic, timeline and scores of the run on one thread."""
    from dataclasses import replace

    rules = [*SOME_RULES, "channel-filter"]
    cfg = FuseConfig(topology="ring", schedule=PERIOD, rules=rules)
    one = simulate(replace(run_config(team_bag), threads=1), cfg, samples=4)
    assert len(one.timeline) == 4 * (len(rules) + 1) * len(one.agents)
    # each lane scores its own final maps: the scores score_result takes anew from the result
    from octofuse.fusion.results import score_result

    anew = score_result(one, cfg.overconfidence_tol, threads=2)
    assert {r: {a: s.to_dict() for a, s in per.items()} for r, per in anew.items()} == {
        r: {a: s.to_dict() for a, s in per.items()} for r, per in one.scores.items()
    }
    for threads in (2, 3):
        budget = WatchedBudget(threads)
        with budget:
            got = simulate(run_config(team_bag), cfg, samples=4, budget=budget)
        # the run used its whole budget, and never more
        assert budget.most == threads
        assert_same_map(got.central, one.central, "central")
        for a in one.agents:
            assert_same_map(got.local[a], one.local[a], a)
            for r in rules:
                assert_same_map(got.fused[r][a], one.fused[r][a], (r, a))
                assert got.loss[r][a].loss_sum == one.loss[r][a].loss_sum
        assert got.traffic == one.traffic
        assert got.timeline == one.timeline
        assert {r: {a: s.to_dict() for a, s in per.items()} for r, per in got.scores.items()} == {
            r: {a: s.to_dict() for a, s in per.items()} for r, per in one.scores.items()
        }
        # each rule's time, added to from the lanes' threads, holds its exchanges and fusions
        per_rule = [got.timings[rule_time_part(r)] for r in rules]
        assert min(per_rule) > 0
        assert sum(per_rule) >= got.timings["fusion"] + got.timings["exchange"] > 0


@pytest.mark.parametrize("per_pass", [1, 2])
def test_a_run_in_passes_of_a_few_rules_gives_the_run_with_every_rule(
    team_bag, whole_and_delta, per_pass
):
    """simulate_in_rule_groups (the bags replayed once per group of rules, as `demo` runs)
    gives every rule the maps, losses, traffic, scores and timeline of one pass with all rules;
    the agents' own maps are mapped, sampled and scored in the first pass only."""
    from octofuse.fusion.results import merge_rule_results
    from octofuse.fusion.simulate import simulate_in_rule_groups

    one = simulate(
        run_config(team_bag),
        FuseConfig(topology="ring", schedule=PERIOD, rules=SOME_RULES),
        samples=3,
    )
    cfg = FuseConfig(topology="ring", schedule=PERIOD, rules=SOME_RULES, rules_per_pass=per_pass)
    parts = list(simulate_in_rule_groups(run_config(team_bag), cfg, samples=3))
    assert [p.rules for p in parts] == [
        SOME_RULES[k : k + per_pass] for k in range(0, len(SOME_RULES), per_pass)
    ]
    assert parts[0].local and not any(p.local for p in parts[1:])
    for p in parts:
        assert_same_map(p.central, one.central, "central")
        for r in p.rules:
            for a in one.agents:
                assert_same_map(p.fused[r][a], one.fused[r][a], (r, a))
                assert p.loss[r][a].loss_sum == one.loss[r][a].loss_sum
            assert p.traffic[r] == one.traffic[r]
    merged = merge_rule_results(parts)
    assert merged.timeline == one.timeline  # in time order, each time's samples in rule order
    assert merged.scores.keys() == one.scores.keys()
    for r, per in one.scores.items():
        for a, sc in per.items():
            assert merged.scores[r][a].to_dict() == sc.to_dict(), (r, a)
    # the pass of the whole-map fixture is the same run without samples: the same maps, and
    # the same final scores (here taken anew, there from the last sample, after every change)
    for a in one.agents:
        assert_same_map(whole_and_delta[False].fused["chernoff"][a], one.fused["chernoff"][a], a)
    for r, per in whole_and_delta[False].scores.items():
        for a, sc in per.items():
            assert one.scores[r][a].to_dict() == sc.to_dict(), (r, a)
    # the loss leaves the final scores read are kept only when asked (for a loss histogram);
    # otherwise they are read again from the loss maps: the same arrays
    assert not any(per for p in (one, *parts) for per in p.loss_leaves.values())
    kept = list(
        simulate_in_rule_groups(run_config(team_bag), cfg, samples=0, keep_loss_leaves=True)
    )
    wep = [r for r in SOME_RULES if r != "naive-bayes"]
    for p in kept:
        for r in p.rules:
            assert p.loss_leaves[r].keys() == set(one.agents)
            for a in one.agents:
                for x, y in zip(p.loss_leaves[r][a], one.loss_leaves_of(r, a)):
                    np.testing.assert_array_equal(x, y)
            assert r not in wep or any(len(p.loss_leaves[r][a][0]) for a in one.agents)
    robust = FuseConfig(topology="ring", schedule=PERIOD, rules=SOME_RULES, rules_per_pass=1)
    robust.robust.enabled = True
    groups = simulate_in_rule_groups(run_config(team_bag), robust, samples=0)
    assert next(groups).rules == SOME_RULES  # robust fusion votes once, on the own maps
    with pytest.raises(ValueError, match="rules_per_pass = -1"):
        FuseConfig(rules_per_pass=-1)


def test_deltas_send_fewer_bytes_and_reach_the_same_voxels(whole_and_delta):
    whole, delta = whole_and_delta[False], whole_and_delta[True]
    assert [e for e in delta.events] == whole.events
    for rule in SOME_RULES:
        tw, td = whole.traffic[rule], delta.traffic[rule]
        assert td.messages == tw.messages == len(whole.events)
        for a in whole.agents:
            assert td.sent[a] < tw.sent[a], (rule, a)
            assert td.sent_32b[a] < tw.sent_32b[a], (rule, a)
            # a receiver already holds what a link carried before: the same voxels get known
            np.testing.assert_array_equal(
                voxel_keys(delta.fused[rule][a])[0],
                voxel_keys(whole.fused[rule][a])[0],
                err_msg=f"{rule} {a}",
            )
            assert delta.scores[rule][a].coverage == whole.scores[rule][a].coverage
    # re-fusing voxels that did not change is what whole maps add: naive-bayes counts them again
    assert mean(delta.scores["naive-bayes"], "overconfidence") < mean(
        whole.scores["naive-bayes"], "overconfidence"
    )


def test_a_first_message_on_a_link_is_the_whole_map(team_bag):
    cfg = run_config(team_bag)
    # one round of exchanges, after the last scan: deltas and whole maps are the same messages
    runs = [
        simulate(
            cfg,
            FuseConfig(topology="ring", schedule="periodic:2", delta=d, rules=["min-info-loss"]),
            samples=0,
        )
        for d in (False, True)
    ]
    assert len(runs[0].events) == 8
    for a in runs[0].agents:
        assert_same_map(runs[1].fused["min-info-loss"][a], runs[0].fused["min-info-loss"][a], a)
    assert runs[1].traffic["min-info-loss"].sent == runs[0].traffic["min-info-loss"].sent


# -- in time ----------------------------------------------------------------------------------


def replay_run(bag, topology: str, schedule: str, rules, delta: bool = False):
    """Every agent's maps from the bag's scans and the schedule's exchange groups, applied in
    time order (a group before any later scan), with :meth:`OccupancyMap.insert_scan_from_sensor`
    and :class:`Replay`."""
    cfg = run_config(bag)
    with ScanSource(cfg) as src:
        names = [a.name for a in src.agents]
        start, end = src.bags.start_ns, src.bags.end_ns
        scans = list(src.scans())
    duration = (end - start) / 1e9
    graph = make_graph(topology, len(names), names=names)
    events = parse_schedule(schedule).build(graph, duration_s=duration)
    empty = {a: OccupancyMap(RES) for a in names}
    replays = {r: Replay(empty, r, delta) for r in rules}
    local = {a: OccupancyMap(RES) for a in names}
    central = OccupancyMap(RES)
    steps = [((s.stamp_ns - start) / 1e9, 0, s) for s in scans]
    steps += [(g[0].time_s, 1, g) for g in groups_of(events)]
    for _, kind, item in sorted(steps, key=lambda x: (x[0], x[1])):
        if kind == 1:
            for rep in replays.values():
                rep.group(item)
            continue
        a = names[item.agent]
        for m in [rep.maps[a] for rep in replays.values()] + [local[a], central]:
            m.insert_scan_from_sensor(item.points, item.pose, item.max_range)
    return events, replays, local, central, scans, start


@pytest.mark.parametrize("delta", [False, True], ids=["whole", "delta"])
def test_a_run_interleaves_scans_and_exchanges_in_time_order(team_bag, whole_and_delta, delta):
    res = whole_and_delta[delta]
    events, replays, local, central, scans, start = replay_run(
        team_bag, "ring", PERIOD, SOME_RULES, delta
    )
    times = sorted({e.time_s for e in events})
    stamps = [(s.stamp_ns - start) / 1e9 for s in scans]
    assert len(times) == 6 and len(scans) == 16
    # scans before the first exchange, between every two, and the last exchange after them
    between = np.histogram(stamps, bins=[-1.0] + times + [99.0])[0]
    assert list(between) == [2, 2, 4, 2, 2, 4, 0]
    assert res.events == events
    assert_same_map(res.central, central, "centralized")
    for a in res.agents:
        assert_same_map(res.local[a], local[a], f"local {a}")
    for rule, rep in replays.items():
        for a in res.agents:
            assert_same_map(res.fused[rule][a], rep.maps[a], f"{rule} {a}")
            assert_same_loss(res.loss[rule][a], rep.loss[a], f"{rule} {a} loss")
        assert_same_traffic(res.traffic[rule], rep)


def test_events_follow_the_schedule_and_the_timeline_ends_at_the_final_scores(team_bag):
    res = simulate(
        run_config(team_bag),
        FuseConfig(topology="star", schedule=PERIOD, rules=["chernoff", "naive-bayes"]),
        samples=5,
    )
    duration = (T0 + int(2.0 * S) + bf.LATENCY_NS - T0) / 1e9  # the last tf message
    graph = make_graph("star", 4)
    want = periodic(graph, period_s=0.33, duration_s=duration)
    assert res.events == want
    assert res.graph.edges == graph.edges
    for rule in res.rules:
        assert res.traffic[rule].messages == len(want) == 6 * 2 * 3
    assert len(res.timeline) == 5 * 3 * 4  # samples x (rules + local-only) x agents
    ts = sorted({s["t"] for s in res.timeline})
    np.testing.assert_allclose(ts, [duration * (k + 1) / 5 for k in range(5)])
    assert [s["t"] for s in res.timeline] == sorted(s["t"] for s in res.timeline)
    for s in res.timeline:
        assert s["kl"] >= 0 and 0 <= s["coverage"] <= 1
        if s["t"] == ts[-1]:
            final = res.scores[s["rule"]][s["agent"]]
            assert s["kl"] == final.kl_mean and s["coverage"] == final.coverage
            assert s["overconfidence"] == final.overconfidence


def test_a_region_seen_late_reaches_no_one_before_it_is_seen(tmp_path):
    """The only exchanges happen at 2.1 s; robot c scans a region far east at 3.0 and 3.5 s:
    the others never get it, while what c saw early reaches everyone."""
    a, b = bf.team(3)[0], bf.team(3)[2]
    b = Robot("b", start=b.start, velocity=b.velocity)
    c = Robot("c", start=(-2.4, -1.6, 0.0), velocity=(1.4, 0.0, 0.5))
    scan_times = {
        "a": [T0 + S // 4, T0 + 3 * S // 4],
        "b": [T0 + 3 * S // 10, T0 + 8 * S // 10],
        "c": [T0 + 7 * S // 20, T0 + 3 * S, T0 + 7 * S // 2],
    }
    rec = bf.robot_recording([a, b, c], scan_times, sensor_range=2.0)
    bag = rec.write(tmp_path / "late", "mcap")
    cfg = run_config(bag)
    with ScanSource(cfg) as src:
        scans = list(src.scans())
    early, late = OccupancyMap(RES), OccupancyMap(RES)
    for s in scans:
        if s.stamp_ns < T0 + 2 * S:
            early.insert_scan_from_sensor(s.points, s.pose, s.max_range)
        elif s.agent == 2:
            late.insert_scan_from_sensor(s.points, s.pose, s.max_range)
    ek, lk = voxel_keys(early)[0], voxel_keys(late)[0]
    late_only = np.setdiff1d(lk, ek)
    assert len(late_only) > 100
    res = simulate(
        cfg, FuseConfig(topology="complete", schedule="periodic:2.1", rules=SOME_RULES), samples=4
    )
    assert {e.time_s for e in res.events} == {2.1}
    c_early = np.setdiff1d(voxel_keys(res.local["c"])[0], late_only)
    for rule in SOME_RULES:
        for name in ("a", "b"):
            known = voxel_keys(res.fused[rule][name])[0]
            assert not np.isin(late_only, known).any(), (rule, name)
            assert np.isin(c_early, known).all(), (rule, name)
        assert np.isin(late_only, voxel_keys(res.fused[rule]["c"])[0]).all()
    assert np.isin(late_only, voxel_keys(res.central)[0]).all()
    # before the exchange nobody covers more than its own scans; after it a and b jump
    for name in ("a", "b"):
        cov = {
            s["t"]: s["coverage"]
            for s in res.timeline
            if s["rule"] == "chernoff" and s["agent"] == name
        }
        local = {
            s["t"]: s["coverage"] for s in res.timeline if s["rule"] == LOCAL and s["agent"] == name
        }
        t_before, t_after = sorted(cov)[1], sorted(cov)[2]  # samples at ~2.0 s and ~3.0 s
        assert t_before < 2.1 < t_after
        assert cov[t_before] == local[t_before]
        assert cov[t_after] > local[t_after]
