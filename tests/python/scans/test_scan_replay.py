"""Scans read once and replayed for later passes over the same bags (scans/replay.py)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
import bagfactory as bf  # noqa: E402
from octofuse.maps.build import make_build_config  # noqa: E402
from octofuse.scans.replay import ScanReplay  # noqa: E402
from octofuse.scans.source import ScanSource  # noqa: E402


@pytest.fixture(scope="module")
def team_bag(tmp_path_factory):
    return bf.team_bag(tmp_path_factory.mktemp("replay"), 3, 4)


class CountingSource(ScanSource):
    """A real source that counts how often the bags are read."""

    reads = 0

    def scans(self):
        self.reads += 1
        yield from super().scans()


def as_tuples(scans):
    return [(s.agent, s.stamp_ns, s.points.tobytes(), s.pose.tobytes(), s.max_range) for s in scans]


def test_later_passes_replay_the_first_passes_scans(team_bag):
    cfg = make_build_config(team_bag, resolution=0.1)
    with ScanSource(cfg) as plain:
        want = as_tuples(plain.scans())
    with CountingSource(cfg) as src:
        replay = ScanReplay(src, passes=3)
        passes = [as_tuples(replay.scans()) for _ in range(3)]
        assert src.reads == 1  # decoded and placed once
        assert passes == [want] * 3
        assert replay._kept is None  # the last pass let every scan go
        assert [s.scans_used for s in replay.stats] == [s.scans_used for s in src.stats]
        assert replay.agents is src.agents


def test_scans_over_the_budget_are_read_again(team_bag):
    cfg = make_build_config(team_bag, resolution=0.1)
    with CountingSource(cfg) as src:
        first = list(src.scans())
        one_scan = max(s.points.nbytes for s in first)
        replay = ScanReplay(src, passes=2, max_bytes=one_scan)
        passes = [as_tuples(replay.scans()) for _ in range(2)]
        assert src.reads == 3  # once above, then once per pass: nothing was kept
        assert passes[0] == passes[1] == as_tuples(first)


def test_one_pass_keeps_nothing(team_bag):
    cfg = make_build_config(team_bag, resolution=0.1)
    with ScanSource(cfg) as src:
        replay = ScanReplay(src, passes=1)
        assert sum(1 for _ in replay.scans()) > 0
        assert replay._kept is None
