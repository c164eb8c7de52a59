"""Exact fusion by channel filters (``channel-filter``): on a tree every agent's map is the map
of exactly the scans that have reached it, message by message; deltas are values (repeating
or reordering one changes nothing); lost messages cost time, never consistency.

Runs in time read a small bag of :func:`bagfactory.team`; the expected maps are built here
from the same scans (``ScanSource``), inserted into maps with open clamping, and summed per
agent over the scans its knowledge covers, tracked from the schedule's delivered messages.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bagfactory as bf  # noqa: E402
import octofuse  # noqa: E402
from bagfactory import voxel_keys  # noqa: E402
from octofuse import OccupancyMap, fuse_into  # noqa: E402
from octofuse.config import CHANNEL_FILTER as CF  # noqa: E402
from octofuse.config import FuseConfig
from octofuse.fusion.agent import Agent, MapMessage  # noqa: E402
from octofuse.fusion.channel_filter import (  # noqa: E402
    add_into,
    clamped,
    negated,
    open_map,
    spanning_tree,
    subtract_into,
    unclamped_copy,
)
from octofuse.fusion.graph import make_graph  # noqa: E402
from octofuse.fusion.rounds import fuse_finished  # noqa: E402
from octofuse.fusion.schedule import drop_messages, periodic  # noqa: E402
from octofuse.fusion.simulate import simulate  # noqa: E402
from octofuse.maps.build import insert_scans, make_build_config  # noqa: E402
from octofuse.outputs.report import findings, mean_scores  # noqa: E402
from octofuse.scans.source import ScanSource  # noqa: E402

RES = 0.2
PERIOD = "periodic:0.33"  # scans at 0.25 + 0.05 i + 0.5 k s: none at a multiple of 0.33 s
TOL = 2e-4  # float32 log-odds summed in another order


def assert_values(got: OccupancyMap, want: OccupancyMap, what: str) -> None:
    """Same finest voxels with the same log-odds to float precision (a voxel held at exactly 0
    by one map and unknown to the other counts as equal: l = 0 is the prior)."""
    kg, vg = voxel_keys(got)
    kw, vw = voxel_keys(want)
    keys = np.union1d(kg, kw)
    a, b = np.zeros(len(keys)), np.zeros(len(keys))
    a[np.searchsorted(keys, kg)] = vg
    b[np.searchsorted(keys, kw)] = vw
    extra = (np.isin(keys, kg) != np.isin(keys, kw)) & ((a != 0) | (b != 0))
    assert not extra.any(), f"{what}: {int(extra.sum())} voxels known to one map only"
    err = np.abs(a - b)
    assert err.max(initial=0.0) <= TOL * max(1.0, np.abs(b).max(initial=0.0)), (
        f"{what}: max |difference| {err.max():.3g}"
    )


def empty_open(res: float = RES) -> OccupancyMap:
    return open_map(OccupancyMap(res))


# -- fixtures ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def team_bag(tmp_path_factory):
    return bf.team_bag(tmp_path_factory.mktemp("team"), 4, 5)


@pytest.fixture(scope="module")
def team_scans(team_bag):
    """agent -> its scans, in order (as the run reads them)."""
    cfg = make_build_config(team_bag, resolution=RES)
    with ScanSource(cfg) as src:
        agents = [a.name for a in src.agents]
        scans = {a: [] for a in agents}
        for s in src.scans():
            scans[agents[s.agent]].append(s)
    return scans


@pytest.fixture(scope="module")
def prefixes(team_scans):
    """agent -> [unclamped map of its first n scans for n = 0, 1, ...] (as the run inserts them)."""
    scans, out = team_scans, {}
    for a in scans:
        m, maps = empty_open(), [empty_open()]
        for s in scans[a]:
            insert_scans([s], [[m]], 1)
            maps.append(unclamped_copy(m))
        out[a] = maps
    return out


class Knowledge:
    """Which scans each agent's map holds (a prefix of every agent's scans), updated by the
    delivered messages of each group on the links ``tree`` (both directions) under the exact
    ``rule``; and the check against the run."""

    def __init__(self, agents, tree, prefixes, rule=CF):
        self.agents, self.prefixes, self.rule = list(agents), prefixes, rule
        self.tree = {(a, b) for a, b in tree} | {(b, a) for a, b in tree}
        self.know = {a: {b: 0 for b in agents} for a in agents}
        self.checked = 0

    def __call__(self, t, group, net, inserted):
        for a in self.agents:  # own scans up to the group (also before it: the sender's state)
            self.know[a][a] = inserted[a]
        start = {a: dict(k) for a, k in self.know.items()}
        for e in group:
            if (e.sender, e.receiver) in self.tree and not e.lost:
                s, d = self.agents[e.sender], self.agents[e.receiver]
                for b in self.agents:
                    self.know[d][b] = max(self.know[d][b], start[s][b])
        for a in self.agents:
            want = empty_open()
            for b, n in self.know[a].items():
                if n:
                    add_into(want, self.prefixes[b][n])
            assert_values(net.fused[self.rule][a], want, f"t={t:.2f} agent {a}")
        self.checked += 1


def run_checked(bag, prefixes, fcfg: FuseConfig, rules=(CF, "min-info-loss")):
    cfg = make_build_config(bag, resolution=RES)
    fcfg.rules = list(rules)
    fcfg.validate("fuse")
    with ScanSource(cfg) as src:
        agents = [a.name for a in src.agents]
    graph = make_graph(fcfg.topology, len(agents), names=agents)
    check = Knowledge(agents, spanning_tree(graph, fcfg.spanning_tree), prefixes)
    res = simulate(cfg, fcfg, samples=2, observer=check)
    assert check.checked > 5
    return res, check


# -- arithmetic -------------------------------------------------------------------------------


def test_open_maps_add_and_subtract_exactly(prefixes):
    a, b = prefixes["a"][-1], prefixes["b"][-1]
    lo, hi = a.clamping_logodds
    assert (lo, hi) == (-np.inf, np.inf)
    assert unclamped_copy(a).clamping_logodds == (-np.inf, np.inf)
    s = unclamped_copy(a)
    add_into(s, b)
    subtract_into(s, b)
    assert_values(s, a, "a + b - b")
    n = negated(a)
    kn, vn = voxel_keys(n)
    ka, va = voxel_keys(a)
    np.testing.assert_array_equal(kn, ka)
    np.testing.assert_array_equal(vn, -va)
    c = clamped(a)
    assert c.clamping_logodds == OccupancyMap(RES).clamping_logodds
    _, vc = voxel_keys(c)
    clo, chi = c.clamping_logodds
    assert clo <= vc.min() and vc.max() <= chi
    # unclamped values exceed OctoMap's thresholds where the scans say so
    assert va.max() > chi or va.min() < clo


def test_subtracting_is_adding_a_negated_copy_bit_for_bit(prefixes):
    """subtract_into walks the map it subtracts with its values negated as read: the same
    tree, node for node, as adding a negated copy (on coarse and fine leaves both ways)."""
    from conftest import random_map

    maps = [prefixes["a"][-1], prefixes["b"][-1], prefixes["a"][0], empty_open()]
    pruned = [random_map(1, 25), random_map(2, 2, offset=(0.35, 0.1, 0.0))]  # 0.1 m
    assert (pruned[0].leaves().depths < 16).any()
    pairs = [(x, y, unclamped_copy) for x in maps for y in maps]  # open clamping
    pairs += [(x, y, OccupancyMap.copy) for x in pruned for y in pruned]  # OctoMap's, clamped
    for x, y, copy in pairs:
        got, want = copy(x), copy(x)
        subtract_into(got, y)
        fuse_into(want, copy(y).negate_values(), rule="naive-bayes", unknown="copy")
        assert got.to_bytes() == want.to_bytes()  # every node and value
        assert got.num_nodes == want.num_nodes
    with pytest.raises(ValueError, match="itself"):
        subtract_into(maps[0], maps[0])


# -- exactness on trees, message by message ---------------------------------------------------


@pytest.mark.parametrize("topology,delta", [("line", False), ("star", True)])
def test_tree_agents_hold_exactly_the_scans_that_reached_them(team_bag, prefixes, topology, delta):
    res, check = run_checked(
        team_bag, prefixes, FuseConfig(topology=topology, schedule=PERIOD, delta=delta)
    )
    full = 0
    for a in res.agents:  # at the end: own scans since the last exchange too
        know = {**check.know[a], a: len(prefixes[a]) - 1}
        want = empty_open()
        for b, n in know.items():
            add_into(want, prefixes[b][n])
        assert_values(res.unclamped[a], want, f"final {a}")
        if all(n == len(prefixes[b]) - 1 for b, n in know.items()):
            full += 1  # heard everything: the centralized map without clamping
            assert_values(res.unclamped[a], res.central_unclamped, f"final {a}")
        # scored and written clamped: compatible with the centralized map
        assert res.fused[CF][a].clamping == res.central.clamping
    assert res.scores[CF]["a"].loss_mean is None
    assert res.memory[CF]["a"]["links"] > 0
    assert (res.memory["min-info-loss"]["a"]["links"] > 0) == delta
    for a in res.agents:  # the maps as they were measured: the filter's unclamped
        assert res.memory[CF][a]["map"] == res.unclamped[a].memory_bytes
        assert res.memory["min-info-loss"][a]["map"] == res.fused["min-info-loss"][a].memory_bytes


def test_a_spanning_tree_file(team_bag, prefixes, tmp_path):
    tree = tmp_path / "tree.txt"
    tree.write_text("a b\nb c\nb d\n")
    run_checked(
        team_bag,
        prefixes,
        FuseConfig(topology="complete", schedule=PERIOD, spanning_tree=str(tree)),
    )
    bad = tmp_path / "bad.txt"
    bad.write_text("a b\nb c\nc a\nc d\n")
    g = make_graph("complete", 4, names=list("abcd"))
    with pytest.raises(ValueError, match="a tree has 3"):
        spanning_tree(g, str(bad))
    line = make_graph("line", 4, names=list("abcd"))
    off = tmp_path / "off.txt"
    off.write_text("a b\nb c\na d\n")
    with pytest.raises(ValueError, match="not a link of the topology"):
        spanning_tree(line, str(off))


def test_loops_run_the_filter_on_a_spanning_tree(team_bag, prefixes):
    g = make_graph("ring", 4, names=list("abcd"))
    tree = spanning_tree(g, "bfs")
    assert len(tree) == 3 and set(tree) <= set(g.edges)
    with pytest.raises(ValueError, match="needs a graph without loops"):
        spanning_tree(g, "given")
    assert spanning_tree(make_graph("line", 4), "given") == make_graph("line", 4).edges
    res, _ = run_checked(team_bag, prefixes, FuseConfig(topology="ring", schedule=PERIOD))
    assert res.tree == tree
    # the WEP rule used every link, the filter only the tree's
    assert res.traffic["min-info-loss"].messages > res.traffic[CF].messages
    text = " ".join(
        findings(mean_scores(res.scores), {"tree_links": 3, "graph_links": 4, "floor_kl": 0.0})
    )
    assert "channel filter on a spanning tree (3 of 4 links)" in text
    assert "`min-info-loss` KL" in text


# -- deltas are values ------------------------------------------------------------------------


def test_repeated_and_reordered_deltas_do_not_double_count(prefixes):
    pa, pb = prefixes["a"], prefixes["b"]
    a, b = Agent("a", CF, unclamped_copy(pa[2])), Agent("b", CF, unclamped_copy(pb[-1]))
    lossy = dict(delta=True, reliable=False)
    m1 = a.compose("b", **lossy)  # the whole contribution (nothing acknowledged yet)
    assert b.deliver(m1)
    assert a.deliver(MapMessage("b", "a", CF, 1, 1, empty_open(), True))  # b acknowledges m1
    a.map = unclamped_copy(pa[3])
    m2 = a.compose("b", **lossy)  # the voxels scan 3 changed since m1
    a.map = unclamped_copy(pa[5])
    m3 = a.compose("b", **lossy)  # m2 is not acknowledged: every voxel changed since m1
    k2, _ = voxel_keys(m2.payload)
    k3, _ = voxel_keys(m3.payload)
    assert 0 < len(k2) < len(k3) and np.isin(k2, k3).all()
    exact = unclamped_copy(pb[-1])
    add_into(exact, pa[5])
    # reordered: the newer delta first (as bytes, through the frame); the older one is
    # dropped (m3 holds its voxels, newer)
    assert b.deliver(MapMessage.decode(m3.encode("lab")))
    assert not b.deliver(m2)
    assert not b.deliver(m3)  # repeated: dropped by its sequence number ...
    for _ in range(2):  # ... and harmless even without it: a delta is a value
        b.apply_contribution("a", m3.payload, True)
    assert_values(b.map, exact, "after reordered and repeated deltas")

    # in order, each delta applied three times: still exact; naive Bayes counts every repeat
    a, b = Agent("a", CF, unclamped_copy(pa[2])), Agent("b", CF, unclamped_copy(pb[-1]))
    d1 = a.compose("b", delta=True)
    a.map = unclamped_copy(pa[3])
    d2 = a.compose("b", delta=True)
    nb = unclamped_copy(pb[-1])
    for d in (d1, d2):
        for _ in range(3):
            b.apply_contribution("a", d.payload, True)
            fuse_into(nb, d.payload, rule="naive-bayes")
    exact2 = unclamped_copy(pb[-1])
    add_into(exact2, pa[3])
    assert_values(b.map, exact2, "deltas applied three times")
    _, v_nb = voxel_keys(nb)
    _, v_ex = voxel_keys(exact2)
    assert np.abs(v_nb).sum() > 1.5 * np.abs(v_ex).sum()


def test_whole_messages_are_values_too(prefixes):
    pa, pb = prefixes["a"], prefixes["b"]
    a, b = Agent("a", CF, unclamped_copy(pa[-1])), Agent("b", CF, unclamped_copy(pb[-1]))
    m = a.compose("b")
    for _ in range(3):
        b.apply_contribution("a", m.payload, False)
    exact = unclamped_copy(pb[-1])
    add_into(exact, pa[-1])
    assert_values(b.map, exact, "whole message three times")
    # the reply carries b's own side only: a ends with the same map
    assert a.deliver(MapMessage.decode(b.compose("a").encode("lab")))
    assert_values(a.map, exact, "two-way exchange")


# -- lost messages ----------------------------------------------------------------------------


def test_lost_messages_are_the_same_for_every_rule():
    g = make_graph("ring", 4)
    ev = periodic(g, period_s=1.0, duration_s=20.0)
    a, b = drop_messages(ev, 0.3, seed=1), drop_messages(ev, 0.3, seed=1)
    assert a == b and 0.15 < np.mean([e.lost for e in a]) < 0.45
    assert drop_messages(ev, 0.0, seed=1) == ev
    with pytest.raises(ValueError):
        drop_messages(ev, 1.0, seed=1)


@pytest.mark.parametrize("delta", [False, True])
def test_lossy_links_stay_exact(team_bag, prefixes, delta):
    res, check = run_checked(
        team_bag,
        prefixes,
        FuseConfig(topology="line", schedule="periodic:0.2", delta=delta, loss=0.35, seed=3),
        rules=(CF, "min-info-loss", "naive-bayes"),
    )
    lost = {r: res.traffic[r].lost for r in res.rules}
    assert lost[CF] > 0 and len(set(lost.values())) == 1  # every rule lost the same messages
    for r in res.rules:
        tr = res.traffic[r]
        assert sum(tr.sent.values()) > sum(tr.received.values())


def test_finished_maps_in_rounds_sum_exactly(prefixes):
    maps = {a: clamped(p[-1]) for a, p in prefixes.items()}
    central = clamped(prefixes["a"][-1])
    res = fuse_finished(
        maps,
        central,
        FuseConfig(topology="star", schedule="rounds:2", rules=[CF, "chernoff"]),
        threads=1,
    )
    want = empty_open()
    for m in maps.values():
        add_into(want, unclamped_copy(m))
    for a in res.agents:
        assert_values(res.unclamped[a], want, f"rounds {a}")


def test_config_accepts_the_filter_beside_the_rules():
    f = FuseConfig(rules=["all", CF])
    assert f.rules == (*octofuse.RULES, CF)
    f = FuseConfig(rules="all")
    assert CF not in f.rules
    for bad in (dict(loss=1.0), dict(loss=-0.1), dict(spanning_tree="dfs")):
        with pytest.raises(ValueError):
            FuseConfig(**bad)
