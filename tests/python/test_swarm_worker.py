"""A swarm worker in this process (no Ray): messages as .ot streams, its memory cap."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from conftest import random_map  # noqa: E402

from octofuse import InfoLossMap, fuse_into  # noqa: E402
from octofuse.config import BuildConfig, FuseConfig, MapConfig  # noqa: E402
from octofuse.fusion.network import message_bytes  # noqa: E402
from octofuse.fusion.swarm import simulate_swarm  # noqa: E402
from octofuse.fusion.swarm_worker import SwarmWorker  # noqa: E402


def worker(names, delta=False, cap=None):
    return SwarmWorker(0, names, MapConfig(resolution=0.1), ["chernoff"], "copy", delta, 1, cap)


def test_a_message_is_the_senders_map_and_is_fused_as_in_process():
    a, b = random_map(1, 4), random_map(2, 4, offset=(0.5, 0, 0))
    w = worker(["a", "b"])
    w.fused["a"]["chernoff"], w.fused["b"]["chernoff"] = a.copy(), b.copy()
    msg = w.send("a", ["b"])
    assert msg == [a.to_bytes()]
    w.receive("b", ["a"], 0.0, msg)
    want, loss = b.copy(), InfoLossMap(0.1)
    fuse_into(want, a, rule="chernoff", loss=loss)
    assert w.fused["b"]["chernoff"].to_bytes() == want.to_bytes()
    assert w.sent["chernoff"]["a"] == w.received["chernoff"]["b"] == message_bytes(a)
    assert w.messages["chernoff"] == 1 and w.stats()["peak_rss"] > 0


def test_deltas_send_only_what_changed_on_the_link():
    w = worker(["a", "b", "c"], delta=True)
    w.fused["a"]["chernoff"] = random_map(3, 3)
    first = w.send("a", ["b", "c"])
    assert isinstance(first, tuple) and len(first) == 2  # one message per receiver
    again = w.send("a", ["b"])
    assert len(again[0]) < len(first[0][0])  # nothing changed: an empty delta


def test_a_worker_over_its_memory_cap_says_so():
    w = worker(["a"], cap=2**20)
    with pytest.raises(MemoryError, match="over its cap of 1 MiB"):
        w.insert([])


@pytest.mark.parametrize("fuse", [
    FuseConfig(rules=["chernoff", "channel-filter"], schedule="periodic:1"),
    FuseConfig(rules=["chernoff"], schedule="periodic:1", loss=0.2),
])
def test_a_swarm_refuses_what_it_cannot_run_before_starting(fuse):
    # checked before Ray starts or a bag opens (the bag does not exist)
    with pytest.raises(ValueError, match="not available in a swarm"):
        simulate_swarm(BuildConfig(bags=["no-such.bag"]), fuse)


def test_a_swarm_refuses_a_bad_number_of_samples_before_starting():
    with pytest.raises(ValueError, match="samples = -1: expected 0 to 10000"):
        simulate_swarm(BuildConfig(bags=["no-such.bag"]),
                       FuseConfig(rules=["chernoff"], schedule="periodic:1"), samples=-1)
