"""Rays traced once and replayed for later passes over the same batches (maps/ray_replay.py)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
import bagfactory as bf  # noqa: E402
from bagfactory import assert_same_map  # noqa: E402
from octofuse.maps import ray_replay  # noqa: E402
from octofuse.maps.build import make_build_config  # noqa: E402
from octofuse.maps.occupancy import OccupancyMap  # noqa: E402
from octofuse.maps.ray_batches import apply_rays  # noqa: E402
from octofuse.maps.ray_replay import RayReplay  # noqa: E402
from octofuse.scans.source import ScanSource, batched  # noqa: E402

RES = 0.1


@pytest.fixture(scope="module")
def batches(tmp_path_factory):
    """The scans of a small team bag, in batches of two."""
    bag = bf.team_bag(tmp_path_factory.mktemp("rays"), 3, 4)
    with ScanSource(make_build_config(bag, resolution=RES)) as src:
        return list(batched(src.scans(), 2))


def mapped(trace, batches) -> OccupancyMap:
    """One map of every batch, its rays from ``trace``."""
    m = OccupancyMap(RES)
    for b in batches:
        apply_rays(trace(b, m, 2), [[m]] * len(b), 1)
    return m


class CountingTrace:
    """The real tracing, counted (patched into the replay's module)."""

    def __init__(self):
        self.calls = 0
        self.plain = ray_replay.trace_scans

    def __call__(self, *args):
        self.calls += 1
        return self.plain(*args)


def test_later_passes_map_what_tracing_anew_maps(batches, monkeypatch):
    want = mapped(CountingTrace().plain, batches)
    counted = CountingTrace()
    monkeypatch.setattr(ray_replay, "trace_scans", counted)
    replay = RayReplay(passes=3)
    for _ in range(3):
        assert not replay.given_back
        assert_same_map(mapped(replay.next_pass(), batches), want)
    assert replay.given_back
    assert counted.calls == len(batches)  # traced in the first pass only
    assert replay._kept == [None] * len(batches)  # the last pass let every batch's rays go
    with pytest.raises(RuntimeError, match="pass 4 of a replay of 3"):
        replay.next_pass()


def test_batches_over_the_budget_are_traced_again(batches, monkeypatch):
    counted = CountingTrace()
    monkeypatch.setattr(ray_replay, "trace_scans", counted)
    first = counted.plain(batches[0], OccupancyMap(RES), 1).nbytes
    replay = RayReplay(passes=2, max_bytes=first)
    want = mapped(replay.next_pass(), batches)
    assert_same_map(mapped(replay.next_pass(), batches), want)
    assert counted.calls == 2 * len(batches) - 1  # only the first batch was kept
    one = RayReplay(passes=1)
    mapped(one.next_pass(), batches)
    assert one._kept == []  # nothing to keep for


def test_a_pass_of_other_batches_is_refused(batches):
    replay = RayReplay(passes=2)
    mapped(replay.next_pass(), batches)
    with pytest.raises(RuntimeError, match="batch 1 of pass 2 holds other scans"):
        mapped(replay.next_pass(), batches[1:])
