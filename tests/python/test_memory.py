"""Freeing a run's maps off the caller's thread (octofuse.memory.MapFreeing)."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from octofuse import OccupancyMap
from octofuse.memory import MapFreeing


def a_map(seed: int) -> OccupancyMap:
    m = OccupancyMap(0.1)
    pts = np.random.default_rng(seed).uniform(-2, 2, (300, 3)).astype(np.float32)
    m.insert_scan(pts, (0.0, 0.0, 0.0), max_range=-1.0)
    assert m.num_leaves > 0
    return m


class Gated:
    """A map whose clear() waits for the test to open the gate."""

    def __init__(self, gate: threading.Event):
        self.gate, self.cleared = gate, False

    def clear(self):
        assert self.gate.wait(10)
        self.cleared = True


@pytest.mark.parametrize("threads", [1, 2])
def test_every_map_given_is_freed_by_the_end_of_the_block(threads):
    maps = [a_map(s) for s in range(5)]
    with MapFreeing(threads) as freeing:
        freeing.free(maps[:2])
        freeing.free(m for m in maps[2:])  # any iterable
    assert [m.num_leaves for m in maps] == [0] * 5


def test_free_returns_at_once_and_with_wait_once_freed():
    gate = threading.Event()
    first, second = Gated(gate), Gated(gate)
    with MapFreeing() as freeing:
        freeing.free([first])
        assert not first.cleared  # the caller goes on while the batch waits
        gate.set()
        freeing.free([second], wait=True)
        assert first.cleared and second.cleared  # in order: the earlier batch first


def test_an_error_while_freeing_reaches_the_caller_at_the_end():
    class Broken:
        def clear(self):
            raise RuntimeError("cannot free")

    with pytest.raises(RuntimeError, match="cannot free"):
        with MapFreeing() as freeing:
            freeing.free([Broken()])
    # the block's own error wins over a batch's
    with pytest.raises(KeyError):
        with MapFreeing() as freeing:
            freeing.free([Broken()])
            raise KeyError("the block's")
