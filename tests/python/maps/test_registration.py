"""Registration of two maps from their occupied voxels (octofuse.maps.registration)."""

import math

import numpy as np
import pytest

from bagfactory import ROOM, SENSORS, Box, Scene, lidar_directions, room_map
from octofuse import OccupancyMap
from octofuse.maps.frames import pose_matrix
from octofuse.maps.registration import MAX_CONFLICT, free_space_conflict, register

RES = 0.1

#: (x, y, z metres, yaw degrees) of B's frame in A's frame
OFFSETS = [
    (0.5, -0.3, 0.0, 0.0),
    (1.2, 0.4, 0.1, 30.0),
    (-0.8, 0.9, 0.0, -120.0),
    (0.3, 0.2, 0.0, 180.0),
    (2.0, -1.0, 0.0, 75.0),
]


@pytest.fixture(scope="module")
def a_map():
    return room_map()


def errors(T_est, T_true):
    E = np.linalg.inv(T_true) @ T_est
    ang = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(E[:3, :3]) - 1) / 2))))
    return float(np.linalg.norm(T_est[:3, 3] - T_true[:3, 3])), ang


@pytest.mark.parametrize("planar", [False, True], ids=["full", "planar"])
@pytest.mark.parametrize(
    "off", OFFSETS, ids=[f"{x},{y},{z},{yaw:g}deg" for x, y, z, yaw in OFFSETS]
)
def test_known_offsets_are_recovered(a_map, off, planar):
    x, y, z, yaw = off
    T = pose_matrix(x, y, z, 0, 0, math.radians(yaw))
    b = room_map(T=T)  # the same scans, mapped in a frame offset by T
    r = register(a_map, b, planar=planar)
    t_err, r_err = errors(r.matrix, T)
    assert t_err < RES and r_err < 1.0, (t_err, r_err)
    assert r.fitness > 0.9
    d = r.as_dict()
    assert set(d) >= {"x", "y", "z", "roll", "pitch", "yaw", "fitness"}
    assert abs(d["x"] - x) < RES and abs(d["y"] - y) < RES and abs(d["z"] - z) < RES
    assert abs(math.remainder(d["yaw"] - math.radians(yaw), 2 * math.pi)) < math.radians(1)
    if planar:
        assert d["roll"] == 0.0 and d["pitch"] == 0.0


@pytest.mark.parametrize("planar", [False, True], ids=["full", "planar"])
def test_partial_overlap_is_recovered(planar):
    T = pose_matrix(0.7, -0.4, 0.0, 0, 0, math.radians(20))
    r = register(room_map(SENSORS[:3]), room_map(SENSORS[1:], T=T), planar=planar)
    t_err, r_err = errors(r.matrix, T)
    assert t_err < RES and r_err < 1.0


def test_small_rotation_about_x_is_recovered(a_map):
    T = pose_matrix(0.3, -0.2, 0.1, math.radians(4), math.radians(-3), math.radians(25))
    r = register(a_map, room_map(T=T))
    t_err, r_err = errors(r.matrix, T)
    assert t_err < RES and r_err < 1.0


def _scene_map(scene, sensors):
    m = OccupancyMap(RES)
    dirs = lidar_directions(90, 15, 0.9).reshape(-1, 3)
    for o in sensors:
        m.insert_scan(np.asarray(o) + dirs * scene.raycast(o, dirs)[:, None], o)
    return m


def test_single_wall_is_refused(a_map):
    wall = OccupancyMap(RES)
    ys, zs = np.meshgrid(np.arange(-1.5, 1.5, 0.05), np.arange(0.2, 1.8, 0.05))
    wall.insert_scan(np.stack([np.full(ys.size, 1.5), ys.ravel(), zs.ravel()], 1), [0, 0, 1.0])
    for planar in (False, True):
        with pytest.raises(ValueError, match="cannot register.*too small|too little"):
            register(a_map, wall, planar=planar)


def test_other_place_is_refused(a_map):
    corridor = Scene(Box((-4.95, -0.95, -0.05), (4.95, 0.95, 2.45)))
    with pytest.raises(
        ValueError, match="cannot register: the best transform matches .*too little"
    ):
        register(a_map, _scene_map(corridor, [(-3, 0, 0.6), (3, 0, 0.6)]))


def test_too_few_voxels_is_refused(a_map):
    tiny = OccupancyMap(RES)
    tiny.insert_scan(np.array([[1.0, 0.0, 0.5], [1.0, 0.3, 0.5]]), [0, 0, 0.5])
    with pytest.raises(ValueError, match="map B has 2 occupied points.*at least 60"):
        register(a_map, tiny)


def test_bad_options(a_map):
    with pytest.raises(ValueError, match="voxel"):
        register(a_map, a_map, voxel=-1)
    with pytest.raises(ValueError, match="min_fitness"):
        register(a_map, a_map, min_fitness=2)


def test_free_space_conflict_tells_the_place_from_a_similar_one(a_map):
    T = pose_matrix(0.5, -0.3, 0.0, 0, 0, math.radians(30))
    b = room_map(T=T)
    assert free_space_conflict(a_map, b, T) < MAX_CONFLICT
    assert register(a_map, b).conflict < MAX_CONFLICT
    # B's walls half a metre off: they stand in A's empty room
    assert free_space_conflict(a_map, b, pose_matrix(0.5) @ T) > 3 * MAX_CONFLICT


def test_a_similar_place_is_refused(a_map):
    """The same room with a large cabinet A saw as free space: the walls match, the cabinet
    stands where A saw nothing."""
    cabinet = Scene(ROOM.room, (*ROOM.obstacles, Box((-0.6, -1.9, -0.05), (0.4, -0.6, 2.0))))
    b = _scene_map(cabinet, SENSORS)
    with pytest.raises(ValueError, match="cannot register: .* in space A saw free"):
        register(a_map, b)
    assert register(a_map, b, max_conflict=1.0).fitness > 0.5  # geometry alone accepts it


@pytest.mark.parametrize("planar", [False, True], ids=["full", "planar"])
def test_the_same_maps_give_the_same_transform_bit_for_bit(a_map, planar):
    """The coarse search is seeded and runs on one thread: call after call, the same maps
    give the same transform."""
    T = pose_matrix(0.7, -0.4, 0.0, 0, 0, math.radians(20))
    b = room_map(SENSORS[1:], T=T)
    first = register(room_map(SENSORS[:3]), b, planar=planar).matrix
    for _ in range(4):
        assert register(room_map(SENSORS[:3]), b, planar=planar).matrix.tobytes() == first.tobytes()
