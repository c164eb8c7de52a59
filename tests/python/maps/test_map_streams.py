"""Maps as OctoMap streams (what a robot sends): to_bytes / from_bytes."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from conftest import random_map  # noqa: E402
from octofuse import OccupancyMap  # noqa: E402
from octofuse.maps.occupancy import MapFileError  # noqa: E402


def test_a_stream_is_the_ot_file_and_reads_back_exactly(tmp_path):
    m = random_map(3, 6)
    data = m.to_bytes()
    assert data == m.save(tmp_path / "m.ot").read_bytes()
    back = OccupancyMap.from_bytes(data)
    assert back.to_bytes() == data and back.num_nodes == m.num_nodes
    bt = m.to_bytes("bt")
    assert bt == m.save(tmp_path / "m.bt").read_bytes()
    assert OccupancyMap.from_bytes(bt).num_leaves == OccupancyMap.load(tmp_path / "m.bt").num_leaves
    assert OccupancyMap.from_bytes(OccupancyMap(0.1).to_bytes()).num_nodes == 0


def test_a_broken_stream_is_an_error():
    data = random_map(1, 2).to_bytes()
    for bad in (data[: len(data) // 2], b"", b"hello"):
        with pytest.raises(MapFileError):
            OccupancyMap.from_bytes(bad)
    with pytest.raises(ValueError):
        random_map(1, 1).to_bytes("ply")
