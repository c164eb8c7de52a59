"""Exact fusion by per-source map layers (``source-layers``) on any graph: every agent's map is
the sum of the newest layer of every source it has heard of, on loopy graphs, in time, under
message loss, repeated and reordered messages; a memory budget folds layers conservatively.

The expected maps are sums of unclamped scan prefixes, as in :mod:`test_channel_filter`.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bagfactory import voxel_keys  # noqa: E402
from conftest import random_map  # noqa: E402
from octofuse import fuse_into  # noqa: E402
from octofuse.config import SOURCE_LAYERS as SL  # noqa: E402
from octofuse.config import FuseConfig
from octofuse.fusion.agent import Agent, MapMessage  # noqa: E402
from octofuse.fusion.channel_filter import add_into, clamped, unclamped_copy  # noqa: E402
from octofuse.fusion.graph import make_graph  # noqa: E402
from octofuse.fusion.rounds import fuse_finished  # noqa: E402
from octofuse.fusion.simulate import simulate  # noqa: E402
from octofuse.maps.build import insert_scans, make_build_config  # noqa: E402
from octofuse.outputs.report import (  # noqa: E402
    exact_summary,
    findings,
    layers_folded,
    mean_scores,
    memory_per_agent,
    memory_table,
)

# the fixtures (prefixes, team_bag, team_scans) are used by name
from test_channel_filter import (  # noqa: E402,F401
    PERIOD,
    RES,
    Knowledge,
    assert_values,
    empty_open,
    prefixes,
    team_bag,
    team_scans,
)


def total(maps):
    """The unclamped sum of ``maps``."""
    maps = list(maps)
    want = empty_open(maps[0].resolution)
    for m in maps:
        add_into(want, unclamped_copy(m))
    return want


@pytest.fixture(scope="module")
def finished():
    """Six robots' finished maps, overlapping in part."""
    return {f"r{k}": random_map(k, 3, offset=(0.3 * k, 0.2 * (k % 2), 0.0)) for k in range(6)}


class Last:
    """An observer keeping the network of the last round."""

    def __call__(self, t, group, net, inserted):
        self.net = net


# -- finished maps on loopy graphs -------------------------------------------------------------


@pytest.mark.parametrize(
    "topology,loss", [("ring", 0.0), ("complete", 0.0), ("max-robust:3", 0.0), ("ring", 0.3)]
)
def test_finished_maps_on_loopy_graphs_sum_exactly(finished, topology, loss):
    last = Last()
    rounds = 12 if loss else 4
    res = fuse_finished(
        finished,
        finished["r0"],
        FuseConfig(
            topology=topology,
            schedule=f"rounds:{rounds}",
            rules=[SL, "naive-bayes"],
            loss=loss,
            seed=2,
        ),
        threads=1,
        observer=last,
    )
    want = total(finished.values())
    if loss:
        assert res.traffic[SL].lost > 0
    for a in res.agents:
        assert_values(last.net.fused[SL][a], want, f"{topology} {a}")
        # scored and written clamped
        assert res.fused[SL][a].to_bytes() == clamped(last.net.fused[SL][a]).to_bytes()
        assert res.memory[SL][a]["layers"] == 6 and res.memory[SL][a]["folded"] == 0
    assert res.scores[SL]["r0"].loss_mean is None
    # naive Bayes counts what arrives over two paths twice: far from the sum on loops
    _, v_nb = voxel_keys(res.fused["naive-bayes"]["r0"])
    _, v_sl = voxel_keys(res.fused[SL]["r0"])
    assert np.abs(v_nb).sum() > np.abs(v_sl).sum()


def test_layers_sent_once_then_versions_only(finished):
    """Finished maps do not change: once every agent knows what the others hold, messages
    carry versions and no map."""

    def sent(rounds):
        res = fuse_finished(
            finished,
            None,
            FuseConfig(topology="complete", schedule=f"rounds:{rounds}", rules=[SL]),
            threads=1,
        )
        return sum(res.traffic[SL].sent.values())

    # the second round still sends what the first delivered at the same time over other links
    assert 0 < sent(1) < sent(2) == sent(5)


# -- in time -----------------------------------------------------------------------------------


@pytest.mark.parametrize("topology,loss", [("ring", 0.0), ("complete", 0.0), ("ring", 0.35)])
def test_in_time_agents_hold_exactly_the_scans_they_heard_of(team_bag, prefixes, topology, loss):
    cfg = make_build_config(team_bag, resolution=RES)
    fcfg = FuseConfig(
        topology=topology,
        schedule=PERIOD if not loss else "periodic:0.2",
        rules=[SL, "min-info-loss"],
        loss=loss,
        seed=3,
    )
    fcfg.validate("fuse")
    agents = list(prefixes)
    graph = make_graph(topology, len(agents), names=agents)
    check = Knowledge(agents, graph.edges, prefixes, rule=SL)
    res = simulate(cfg, fcfg, samples=2, observer=check)
    assert check.checked > 5
    if loss:
        assert res.traffic[SL].lost > 0
    for a in res.agents:  # at the end: own scans since the last exchange too (scored clamped)
        know = {**check.know[a], a: len(prefixes[a]) - 1}
        want = empty_open()
        for b, n in know.items():
            add_into(want, prefixes[b][n])
        assert_values(res.fused[SL][a], clamped(want), f"final {a}")
        if all(n == len(prefixes[b]) - 1 for b, n in know.items()):
            # heard everything: the centralized map without clamping, clamped once
            assert_values(res.fused[SL][a], clamped(res.central_unclamped), f"final {a}")


# -- repeated, reordered and lost messages -----------------------------------------------------


def test_repeated_reordered_and_relayed_layers_count_once(team_scans, prefixes):
    pa, pb, pc = prefixes["a"], prefixes["b"], prefixes["c"]
    a, b, c = (Agent(x, SL, empty_open()) for x in "abc")
    lossy = dict(reliable=False)

    def scans(agent, lo, hi):
        insert_scans(team_scans[agent.name][lo:hi], [agent.scan_targets()] * (hi - lo), 1)

    scans(a, 0, 2)
    m1 = a.compose("b", **lossy)
    scans(a, 2, 4)
    m2 = a.compose("b", **lossy)  # m1 not acknowledged: whole again, a newer version
    assert not m1.delta and not m2.delta
    scans(b, 0, len(team_scans["b"]))
    # reordered and repeated, through the frame: the older is dropped, repeats change nothing
    assert b.deliver(MapMessage.decode(m2.encode("lab")))
    assert not b.deliver(m1) and not b.deliver(m2)
    for m in (m1, m2, m2):  # and harmless even without sequence numbers: layers are values
        b.apply_layers("a", m.payload)
    assert_values(b.map, total([pb[-1], pa[4]]), "b after repeats")

    # b acknowledges: a's next message is a delta, applied thrice; naive Bayes counts it thrice
    assert a.deliver(b.compose("a", **lossy))
    assert_values(a.map, total([pa[4], pb[-1]]), "a")
    scans(a, 4, 5)
    m3 = a.compose("b", **lossy)
    assert m3.delta and [p.source for p in m3.payload.parts if p.map is not None] == ["a"]
    nb = unclamped_copy(b.map)
    for _ in range(3):
        b.apply_layers("a", m3.payload)
        fuse_into(nb, m3.payload.parts[0].map, rule="naive-bayes")
    exact = total([pb[-1], pa[5]])
    assert_values(b.map, exact, "b after a delta thrice")
    _, v_nb = voxel_keys(nb)
    _, v_ex = voxel_keys(exact)
    assert np.abs(v_nb).sum() > 1.2 * np.abs(v_ex).sum()

    # relayed over a loop: c hears a through b and directly; each source counts once
    scans(c, 0, 3)
    assert c.deliver(b.compose("c"))
    assert c.deliver(a.compose("c"))
    assert b.deliver(c.compose("b"))
    assert a.deliver(b.compose("a"))  # b relays c's layer to a; a's own comes back not at all
    for x in (a, b, c):
        assert_values(x.map, total([pa[5], pb[-1], pc[3]]), f"{x.name} after the loop")
    # nothing new: messages carry versions only
    assert b.compose("c").payload.num_nodes == 0


@settings(
    max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(st.data())
def test_any_order_of_messages_gives_the_sum_of_the_newest_layers(team_scans, prefixes, data):
    """Scans, messages composed on lossy links, and messages delivered in any order, repeated
    or never (by sequence number, or applied as values without it): every agent's map is its
    own scans and, per other source, the scans of the version it holds."""
    names = "abc"
    agents = {x: Agent(x, SL, empty_open()) for x in names}
    done = {x: 0 for x in names}
    scans_of = {x: {} for x in names}  # version -> the scans in it
    sent = []
    for _ in range(data.draw(st.integers(5, 30))):
        op = data.draw(st.sampled_from(["scan", "send", "deliver"]))
        if op == "scan":
            x = data.draw(st.sampled_from(names))
            if done[x] < len(team_scans[x]):
                insert_scans(team_scans[x][done[x] : done[x] + 1], [agents[x].scan_targets()], 1)
                done[x] += 1
        elif op == "send":
            x, y = data.draw(st.permutations(names))[:2]
            sent.append(agents[x].compose(y, reliable=False))
            scans_of[x][agents[x].layers.own_version] = done[x]
        elif sent:
            msg = sent[data.draw(st.integers(0, len(sent) - 1))]
            if data.draw(st.booleans()):
                agents[msg.receiver].deliver(msg)
            else:
                agents[msg.receiver].apply_layers(msg.sender, msg.payload)
    for x, agent in agents.items():
        want = [prefixes[x][done[x]]] + [
            prefixes[s][scans_of[s][layer.version]]
            for s, layer in agent.layers.layers.items()
            if s != x
        ]
        assert_values(agent.map, total(want), x)


def test_scans_inserted_after_a_message_go_into_the_next(team_scans, prefixes):
    """A run takes the maps a scan goes into before the agent's lane inserts it, maybe while
    the agent still sends: the own layer is published when its contents changed."""
    a, b = Agent("a", SL, empty_open()), Agent("b", SL, empty_open())
    targets = a.scan_targets()
    b.deliver(a.compose("b"))
    insert_scans(team_scans["a"][:2], [targets] * 2, 1)
    b.deliver(a.compose("b"))
    assert_values(b.map, prefixes["a"][2], "b")
    assert a.layers.own_version == 2
    assert a.compose("b").payload.num_nodes == 0  # nothing new: no new version
    assert a.layers.own_version == 2


def test_a_delta_applies_to_a_version_newer_than_its_base(team_scans, prefixes):
    """On a loop a receiver may hold a newer version than the sender knew: the delta still
    gives the newest version exactly."""
    a, b, c = (Agent(x, SL, empty_open()) for x in "abc")
    insert_scans(team_scans["a"][:1], [a.scan_targets()], 1)
    b.deliver(a.compose("b"))  # b holds a@1, a knows it
    insert_scans(team_scans["a"][1:3], [a.scan_targets()] * 2, 1)
    c.deliver(a.compose("c"))  # a@2
    b.deliver(c.compose("b"))  # b holds a@2 from c; a does not know
    insert_scans(team_scans["a"][3:5], [a.scan_targets()] * 2, 1)
    m = a.compose("b")
    assert m.delta and m.payload.parts[0].base == 1
    b.deliver(m)
    assert b.layers.layers["a"].version == 3
    assert_values(b.map, prefixes["a"][5], "b")


# -- the memory budget -------------------------------------------------------------------------


def test_a_budget_lets_go_of_the_changes_kept_before_exactness(team_bag, prefixes):
    """A budget above the layers but below the layers and the changes kept for deltas to the
    neighbours: the changes go (more traffic, less memory), no layer is folded, every map
    exact."""
    cfg = make_build_config(team_bag, resolution=RES)
    agents = list(prefixes)
    graph = make_graph("complete", len(agents), names=agents)

    def run(budget):
        check = Knowledge(agents, graph.edges, prefixes, rule=SL)
        nets = []

        def observe(t, group, net, inserted):
            check(t, group, net, inserted)
            nets[:] = [net]

        res = simulate(
            cfg,
            FuseConfig(topology="complete", schedule=PERIOD, rules=[SL], layers_max_bytes=budget),
            samples=0,
            observer=observe,
        )
        nodes = nets[0].nodes[SL].values()
        return res, max(n.layers.bytes_held() for n in nodes)

    free, layers = run(0)
    links = {a: free.memory[SL][a]["links"] for a in agents}
    budget = int(1.05 * layers)
    assert max(links.values()) > budget  # the changes kept are over it
    bound, _ = run(budget)
    for a in agents:
        assert bound.memory[SL][a]["folded"] == 0
        assert bound.memory[SL][a]["links"] <= budget
    assert sum(bound.memory[SL][a]["links"] for a in agents) < sum(links.values())
    assert sum(bound.traffic[SL].sent.values()) > sum(free.traffic[SL].sent.values())


def test_a_budget_folds_the_oldest_layers_conservatively(finished):
    layer = max(unclamped_copy(m).memory_bytes for m in finished.values())
    last = Last()
    res = fuse_finished(
        finished,
        finished["r0"],
        FuseConfig(
            topology="complete", schedule="rounds:3", rules=[SL], layers_max_bytes=3 * layer
        ),
        threads=1,
        observer=last,
    )
    for a in res.agents:
        n = last.net.nodes[SL][a].layers
        assert res.memory[SL][a]["folded"] == len(n.folded) > 0
        assert res.memory[SL][a]["layers"] + len(n.folded) == 6 and a in n.layers
        # the map: the exact layers' sum and the remainder
        assert_values(n.fused, total([*(x.map for x in n.layers.values()), n.remainder]), a)
        # the remainder lies between the folded maps' values (a WEP rule: never more certain)
        kr, vr = voxel_keys(n.remainder)
        lo, hi = np.full(len(kr), np.inf), np.full(len(kr), -np.inf)
        for s in n.folded:
            k, v = voxel_keys(unclamped_copy(finished[s]))
            assert np.isin(k, kr).all()
            at = np.searchsorted(kr, k)
            lo[at], hi[at] = np.minimum(lo[at], v), np.maximum(hi[at], v)
        assert (vr >= lo - 1e-4).all() and (vr <= hi + 1e-4).all()
    means = mean_scores(res.scores)
    text = findings(means, None, memory_per_agent(res), layers_folded(res))[-1]
    assert "Over the memory budget 6 of 6 agents folded layers" in text and "not exact" in text


def test_the_report_sets_the_layers_beside_the_other_rules(finished):
    central = clamped(total(finished.values()))
    res = fuse_finished(
        finished,
        central,
        FuseConfig(topology="ring", schedule="rounds:4", rules=["naive-bayes", "chernoff", SL]),
        threads=1,
    )
    means = mean_scores(res.scores)
    assert means[SL]["kl_mean"] < means["chernoff"]["kl_mean"]
    memory = memory_per_agent(res)
    assert memory[SL] > memory["chernoff"]  # the price: every source's layer
    text = findings(means, exact_summary(res, 0.1), memory)[-1]
    assert text.startswith("Exact fusion on every link (source-layers): KL ")
    assert "closer to the centralized map than every other rule" in text
    assert "A robot sends" in text and "of map and layers (others" in text
    rows = memory_table(res)
    assert rows[0].endswith("layers held (folded) |")
    assert rows[-1].startswith(f"| `{SL}` |") and rows[-1].endswith(" 6.0 (0.0) |")
    assert rows[-2].endswith(" – |")


def test_config_takes_the_mode_beside_the_rules():
    f = FuseConfig(rules=["all", SL, "channel-filter"])
    assert f.rules[-2:] == (SL, "channel-filter")
    f = FuseConfig(rules="all")
    assert SL not in f.rules
    with pytest.raises(ValueError, match="layers_max_bytes"):
        FuseConfig(rules=[SL], layers_max_bytes=-1)
