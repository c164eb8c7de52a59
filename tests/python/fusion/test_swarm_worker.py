"""A swarm worker in this process (no Ray): messages as frames of bytes, its memory cap."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
import numpy as np  # noqa: E402

from bagfactory import voxel_keys  # noqa: E402
from conftest import random_map  # noqa: E402
from octofuse import InfoLossMap, OccupancyMap, fuse_into  # noqa: E402
from octofuse.config import BuildConfig, FuseConfig, MapConfig  # noqa: E402
from octofuse.fusion.agent import MapMessage  # noqa: E402
from octofuse.fusion.channel_filter import add_into, clamped, unclamped_copy  # noqa: E402
from octofuse.fusion.network import message_bytes  # noqa: E402
from octofuse.fusion.swarm import simulate_swarm  # noqa: E402
from octofuse.fusion.swarm_worker import SwarmWorker  # noqa: E402
from octofuse.fusion.wire import Kind, Message  # noqa: E402


def worker(names, delta=False, cap=None, rules=("chernoff",), tree=()):
    return SwarmWorker(
        0, names, MapConfig(resolution=0.1), list(rules), "copy", delta, 1, cap, tree=tree
    )


def test_a_message_is_the_senders_map_and_is_fused_as_in_process():
    a, b = random_map(1, 4), random_map(2, 4, offset=(0.5, 0, 0))
    w = worker(["a", "b"])
    w.nodes["a"]["chernoff"].map = a.copy()
    w.nodes["b"]["chernoff"].map = b.copy()
    msg = w.send("a", ["b"])
    got = MapMessage.decode(msg[0])
    assert (got.sender, got.receiver, got.rule, got.seq) == ("a", "b", "chernoff", 1)
    assert got.payload.to_bytes() == a.to_bytes()
    w.receive("b", ["a"], 0.0, msg)
    want, loss = b.copy(), InfoLossMap(0.1)
    fuse_into(want, a, rule="chernoff", loss=loss)
    assert w.nodes["b"]["chernoff"].map.to_bytes() == want.to_bytes()
    assert w.sent["chernoff"]["a"] == w.received["chernoff"]["b"] == message_bytes(a)
    assert w.messages["chernoff"] == 1 and w.stats()["peak_rss"] > 0


def test_deltas_send_only_what_changed_on_the_link():
    w = worker(["a", "b", "c"], delta=True)
    w.nodes["a"]["chernoff"].map = random_map(3, 3)
    first = w.send("a", ["b", "c"])
    assert isinstance(first, tuple) and len(first) == 2  # one message per receiver
    again = w.send("a", ["b"])
    assert len(again[0]) < len(first[0][0])  # nothing changed: an empty delta


def test_a_worker_over_its_memory_cap_says_so():
    w = worker(["a"], cap=2**20)
    with pytest.raises(MemoryError, match="over its cap of 1 MiB"):
        w.insert([])


def test_the_channel_filter_runs_on_its_tree_only_and_stays_exact():
    a, b = random_map(4, 3), random_map(5, 3, offset=(0.5, 0, 0))
    w = worker(["a", "b", "c"], rules=["channel-filter"], tree=[("a", "b"), ("b", "a")])
    w.nodes["a"]["channel-filter"].map = unclamped_copy(a)
    w.nodes["b"]["channel-filter"].map = unclamped_copy(b)
    assert w.send("a", ["c"]) == [None]  # not a link of the tree
    for _ in range(2):  # the same exchange twice: nothing counted twice
        w.receive("b", ["a"], 0.0, w.send("a", ["b"]))
        w.receive("a", ["b"], 0.0, w.send("b", ["a"]))
    exact = unclamped_copy(a)
    add_into(exact, unclamped_copy(b))
    want_keys, want = voxel_keys(exact)
    for x in "ab":  # the sum of both maps, to float precision (added in another order)
        keys, values = voxel_keys(w.nodes[x]["channel-filter"].map)
        assert np.array_equal(keys, want_keys) and np.allclose(values, want, atol=1e-5), x
    _, scored = voxel_keys(OccupancyMap.from_bytes(w.maps()["a"]["channel-filter"]))
    assert np.allclose(scored, np.clip(want, *clamped(exact).clamping_logodds), atol=1e-5)


def test_frames_that_are_damaged_or_not_for_the_receiver_are_dropped_and_counted():
    w = worker(["a", "b"])
    w.nodes["a"]["chernoff"].map = random_map(6, 2)
    before = w.nodes["b"]["chernoff"].map.to_bytes()
    good = w.send("a", ["b"])[0]
    foreign = Message("f", "chernoff", "x", "b", 1, 0, Kind.WHOLE, random_map(7, 1).to_bytes())
    for frame in (good[:-1], good[:40] + b"\0" + good[41:], foreign.encode(), b"junk"):
        w.receive("b", ["a"], 0.0, [frame])
    assert w.dropped == 4
    assert w.nodes["b"]["chernoff"].map.to_bytes() == before


def test_a_swarm_refuses_a_bad_number_of_samples_before_starting():
    with pytest.raises(ValueError, match="samples = -1: expected 0 to 10000"):
        simulate_swarm(
            BuildConfig(bags=["no-such.bag"]),
            FuseConfig(rules=["chernoff"], schedule="periodic:1"),
            samples=-1,
        )


def test_maps_bytes_counts_source_layers_and_what_links_keep():
    w = worker(["a", "b"], rules=("source-layers",))
    for n, seed in (("a", 5), ("b", 6)):
        w.nodes[n]["source-layers"].map.insert_scan(
            np.random.default_rng(seed).uniform(-2, 2, (300, 3)), [0.0, 0.0, 0.0]
        )
        w.nodes[n]["source-layers"].layers.own.insert_scan(
            np.random.default_rng(seed).uniform(-2, 2, (300, 3)), [0.0, 0.0, 0.0]
        )
    w.receive("b", ["a"], 0.0, w.send("a", ["b"]))
    b = w.nodes["b"]["source-layers"]
    held = {
        id(m): m
        for n in w.nodes.values()
        for m in (n["source-layers"].map, *n["source-layers"].held_maps())
    }
    want = sum(m.memory_bytes for m in held.values()) + sum(
        m.memory_bytes for m in w.local.values()
    )
    assert len(b.layers.maps()) >= 2  # b's own layer and a's
    assert w.stats()["maps_bytes"] == want
    assert want > sum(n["source-layers"].map.memory_bytes for n in w.nodes.values())
