"""Maps as octomap_msgs/Octomap and PointCloud2 messages in ROS 2 MCAP and ROS 1 bags, read back
with rosbags and decoded with the map core's OctoMap reader."""

import numpy as np
import pytest

from bagfactory import SENSORS, room_map
from conftest import voxels
from octofuse import OccupancyMap
from octofuse.maps.registration import occupied_centers
from octofuse.outputs.rosbag_export import (
    OCTOMAP,
    POINTCLOUD2,
    MapEvent,
    read_map_bag,
    typestore,
    write_map_bag,
)
from octofuse.scans.bags import BagSet

S = 1_000_000_000


@pytest.fixture(scope="module")
def maps():
    return {"robot1": room_map(SENSORS[:2]), "robot2": room_map(SENSORS[2:])}


def test_tree_data_is_the_node_stream_of_the_ot_file(maps, tmp_path):
    m = maps["robot1"]
    path = m.save(tmp_path / "m.ot")
    data = m.tree_data()
    assert path.read_bytes().endswith(b"\ndata\n" + data)  # what fullMapToMsg puts in `data`
    assert m.to_bytes() == path.read_bytes()
    assert voxels(OccupancyMap.from_bytes(path.read_bytes())) == voxels(m)
    assert OccupancyMap.from_tree_data(b"", 0.1).num_leaves == 0


def test_truncated_tree_data_is_refused(maps):
    data = maps["robot1"].tree_data()
    with pytest.raises(OSError, match="octomap message.*truncated"):
        OccupancyMap.from_tree_data(data[:-7], 0.1)
    with pytest.raises(OSError, match="not an OctoMap stream"):
        OccupancyMap.from_bytes(b"hello\n")


@pytest.mark.parametrize("name", ["fused.mcap", "fused_bag", "fused.bag"])
def test_maps_round_trip_voxel_by_voxel(maps, tmp_path, name):
    paths = {}
    for agent, m in maps.items():
        paths[agent] = m.save(tmp_path / f"{agent}.ot")
    out = write_map_bag(tmp_path / name, maps, frame_id="world", stamp_ns=5 * S)
    assert out.exists() and [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []
    got = read_map_bag(out)
    assert [(t, s) for t, s, _ in got] == [("/robot1/octomap", 5 * S), ("/robot2/octomap", 5 * S)]
    for (_, _, m), agent in zip(got, maps):
        ref = OccupancyMap.load(paths[agent])  # the .ot file written by the map core
        assert m.resolution == ref.resolution
        assert voxels(m) == voxels(ref)  # log-odds kept, voxel by voxel
    with BagSet([out]) as bags:
        topics = bags.topics()
        assert topics["/robot1/octomap"].msgtype == OCTOMAP
        assert topics["/robot1/occupied_cells"].msgtype == POINTCLOUD2
        for topic, _, msg in bags.messages():
            assert msg.header.frame_id == "world"
            if msg.__class__.__name__.endswith("Octomap") or topic.endswith("octomap"):
                assert msg.binary is False and msg.id == "OcTree" and msg.resolution == 0.1
                continue
            agent = topic.split("/")[1]
            names = [f.name for f in msg.fields]
            assert names == ["x", "y", "z", "log_odds", "occupancy"]
            rec = np.frombuffer(np.asarray(msg.data).tobytes(), dtype=[(n, "<f4") for n in names])
            assert msg.width == len(rec) == len(occupied_centers(maps[agent])) > 100
            np.testing.assert_allclose(
                np.stack([rec["x"], rec["y"], rec["z"]], 1),
                occupied_centers(maps[agent]),
                atol=1e-6,
            )
            assert (rec["log_odds"] > 0).all() and (rec["occupancy"] > 0.5).all()


def test_one_message_per_agent_per_event_in_time_order(maps, tmp_path):
    events = [
        MapEvent("robot2", 3 * S, maps["robot2"]),
        MapEvent("robot1", 1 * S, maps["robot1"]),
        MapEvent("robot1", 2 * S, maps["robot2"]),
    ]
    out = write_map_bag(tmp_path / "run.mcap", events, cloud_topic=None)
    got = read_map_bag(out)
    assert [(t, s) for t, s, _ in got] == [
        ("/robot1/octomap", S),
        ("/robot1/octomap", 2 * S),
        ("/robot2/octomap", 3 * S),
    ]
    assert voxels(got[1][2]) == voxels(maps["robot2"])
    with BagSet([out]) as bags:
        assert set(bags.topics()) == {"/robot1/octomap", "/robot2/octomap"}


def test_registered_definition_matches_octomap_msgs():
    # the ROS 1 md5sum of octomap_msgs/Octomap as published by octomap_msgs
    assert typestore(True).generate_msgdef(OCTOMAP)[1] == "9a45536b45c5e409cd49f04bb2d9999f"


def test_existing_output_is_kept_and_bad_input_refused(maps, tmp_path):
    out = tmp_path / "a.mcap"
    out.write_bytes(b"precious")
    with pytest.raises(FileExistsError):
        write_map_bag(out, maps)
    assert out.read_bytes() == b"precious"
    with pytest.raises(ValueError, match="no maps"):
        write_map_bag(tmp_path / "b.mcap", {})
    with pytest.raises(ValueError, match="kind"):
        write_map_bag(tmp_path / "c.mcap", maps, kind="zip")
    with pytest.raises(ValueError, match="negative"):
        write_map_bag(tmp_path / "d.mcap", [MapEvent("r", -1, maps["robot1"])])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.mcap"]
