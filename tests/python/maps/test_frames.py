"""Rigid transforms and resampling of maps (OccupancyMap.transformed), frames, resolutions, and
fusing map files (octofuse.maps.frames)."""

import math

import numpy as np
import pytest

from bagfactory import ROOM, SENSORS, room_map
from conftest import voxels
from octofuse import OccupancyMap
from octofuse.maps.frames import (
    check_rigid,
    common_resolution,
    fuse_map_files,
    invert,
    matrix_pose,
    parse_frame,
    pose_matrix,
    prepare_maps,
)
from octofuse.maps.tree_fusion import fuse_maps

RES = 0.1


@pytest.fixture(scope="module")
def room():
    return room_map()


def moved_keys(keys: np.ndarray, T: np.ndarray, res_from: float, res_to: float) -> np.ndarray:
    c = (keys + 0.5) * res_from
    return np.floor((c @ T[:3, :3].T + T[:3, 3]) / res_to).astype(np.int64)


def neighbourhood(keys: np.ndarray) -> np.ndarray:
    g = np.stack(np.meshgrid(*(np.arange(-1, 2),) * 3, indexing="ij"), -1).reshape(-1, 3)
    return keys[:, None, :] + g[None]


# -- exact cases -------------------------------------------------------------------------------


def test_identity_gives_the_same_map(room):
    out = room.transformed(np.eye(4))
    assert out is not room and out.resolution == room.resolution
    assert voxels(out) == voxels(room)
    assert out.num_leaves == room.num_leaves


@pytest.mark.parametrize("shift", [(3, 0, 0), (-2, 5, 1), (7, -4, -3)])
def test_translation_by_whole_voxels_is_exact(room, shift):
    T = pose_matrix(*(np.asarray(shift) * RES))
    want = {(a + shift[0], b + shift[1], c + shift[2]): v for (a, b, c), v in voxels(room).items()}
    assert voxels(room.transformed(T)) == want


@pytest.mark.parametrize("yaw_deg", [90, 180, -90, 270])
def test_yaw_by_right_angles_is_exact(room, yaw_deg):
    T = pose_matrix(0.4, -0.3, 0.0, 0, 0, math.radians(yaw_deg))
    src = voxels(room)
    keys = np.array(list(src))
    moved = moved_keys(keys, T, RES, RES)
    want = dict(zip(map(tuple, moved.tolist()), src.values()))
    assert len(want) == len(src)
    assert voxels(room.transformed(T)) == want


def test_roll_by_right_angle_is_exact(room):
    T = pose_matrix(0, 0, 1.0, math.pi / 2, 0, 0)
    src = voxels(room)
    moved = moved_keys(np.array(list(src)), T, RES, RES)
    assert voxels(room.transformed(T)) == dict(zip(map(tuple, moved.tolist()), src.values()))


def test_inverse_right_angle_round_trip_is_exact(room):
    T = pose_matrix(1.2, 0.5, 0.3, 0, 0, math.pi / 2)
    assert voxels(room.transformed(T).transformed(invert(T))) == voxels(room)


# -- general transforms ------------------------------------------------------------------------

GENERAL = [
    pose_matrix(0.37, -0.21, 0.04, 0, 0, 0.3),
    pose_matrix(-0.5, 0.13, 0.0, 0.05, -0.03, 2.0),
]


@pytest.mark.parametrize("T", GENERAL, ids=["yaw", "rpy"])
def test_occupied_stays_occupied(room, T):
    out = voxels(room.transformed(T))
    src = voxels(room)
    occ = np.array([k for k, v in src.items() if v > 0])
    assert len(occ) > 500
    # every occupied voxel leaves an occupied voxel where its centre lands (or next to it)
    near = neighbourhood(moved_keys(occ, T, RES, RES))
    has_occ = np.array([[out.get(tuple(k), -1.0) > 0 for k in row] for row in near.tolist()])
    assert has_occ.any(axis=1).all()
    # and the occupied voxels of the result lie on the moved surfaces of the room
    occ_out = np.array([k for k, v in out.items() if v > 0], dtype=float)
    centres = (occ_out + 0.5) * RES
    world = (centres - T[:3, 3]) @ T[:3, :3]
    assert np.percentile(ROOM.surface_distance(world), 99) < 1.5 * RES
    # occupied wins: a voxel rotated off the grid touches up to 8 target voxels, a surface
    # about 2 to 3 (measured 2.4 to 3.0 here); never more than the 8 its cells can reach
    assert len(occ) <= len(occ_out) < 4 * len(occ)


def pack(keys: np.ndarray) -> np.ndarray:
    k = np.asarray(keys, dtype=np.int64) + (1 << 20)
    return (k[..., 0] << 42) | (k[..., 1] << 21) | k[..., 2]


@pytest.mark.parametrize("T", GENERAL, ids=["yaw", "rpy"])
def test_unknown_stays_unknown_and_known_space_has_no_holes(room, T):
    out = voxels(room.transformed(T))
    keys = np.array(list(voxels(room)))
    known = np.sort(pack(keys))
    tgt = np.array(list(out))
    # every target voxel's centre is within one voxel of the source's known space
    back = np.floor(((tgt + 0.5) * RES - T[:3, 3]) @ T[:3, :3] / RES).astype(np.int64)
    assert np.isin(pack(neighbourhood(back)), known).any(axis=1).all()
    # every target voxel whose centre lands deep in known space (all neighbours known) has a value
    lo, hi = keys.min(axis=0) - 2, keys.max(axis=0) + 3
    grid = np.stack(
        np.meshgrid(*[np.arange(a, b) for a, b in zip(lo, hi)], indexing="ij"), -1
    ).reshape(-1, 3)
    cand = np.unique(moved_keys(grid, T, RES, RES), axis=0)
    back = np.floor(((cand + 0.5) * RES - T[:3, 3]) @ T[:3, :3] / RES).astype(np.int64)
    inside = np.isin(pack(neighbourhood(back)), known).all(axis=1)
    assert inside.sum() > 1000
    assert np.isin(pack(cand[inside]), pack(tgt)).all()


def test_rule_on_a_two_voxel_map():
    """Occupied wins (largest vote), else the mean of the free votes."""
    m = OccupancyMap(RES)
    m.insert_scan(np.array([[0.55, 0.05, 0.05]]), [0.05, 0.05, 0.05])  # free 0..4, occupied 5
    out = voxels(m.transformed(np.eye(4), resolution=2 * RES))
    src = voxels(m)
    assert out[(2, 0, 0)] == pytest.approx(src[(5, 0, 0)])  # occupied wins over the free (4, 0, 0)
    assert out[(0, 0, 0)] == pytest.approx(np.mean([src[(0, 0, 0)], src[(1, 0, 0)]]))
    assert set(out) == {(0, 0, 0), (1, 0, 0), (2, 0, 0)}


def test_coarser_resolution_is_max_of_occupied_else_mean_of_free(room):
    out = voxels(room.transformed(np.eye(4), resolution=2 * RES))
    groups: dict = {}
    for k, v in voxels(room).items():
        groups.setdefault(tuple(np.floor_divide(k, 2)), []).append(v)
    want = {
        k: (max(vs) if max(vs) > 0 else float(np.float32(np.mean(vs)))) for k, vs in groups.items()
    }
    assert set(out) == set(want)
    assert all(out[k] == pytest.approx(want[k], abs=1e-6) for k in want)


def test_finer_resolution_is_exact(room):
    out = room.transformed(np.eye(4), resolution=RES / 2)
    assert out.resolution == RES / 2
    back = out.transformed(np.eye(4), resolution=RES)
    assert voxels(back) == voxels(room)
    assert out.num_leaves == room.num_leaves  # every voxel splits into 8 equal ones: pruned


def test_empty_map_and_parameters_kept():
    m = OccupancyMap(0.2, prob_hit=0.8, prob_miss=0.3, clamping=(0.2, 0.9))
    out = m.transformed(pose_matrix(1, 2, 3, 0.1, 0.2, 0.3), resolution=0.25)
    assert out.num_leaves == 0 and out.resolution == 0.25
    assert out.prob_hit == 0.8 and out.prob_miss == 0.3 and out.clamping == (0.2, 0.9)


# -- bad transforms ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    "T, match",
    [
        (np.diag([2.0, 1, 1, 1]), "not a rigid transform.*orthonormal"),
        (np.diag([1.0, 1, -1, 1]), "reflection"),
        (np.eye(3), "4x4"),
        ([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0.5, 0, 1]], "last row"),
        ([[1, 0.2, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "orthonormal"),
        ("identity", "4x4"),
    ],
)
def test_bad_transform_is_refused(room, T, match):
    with pytest.raises(ValueError, match=match):
        room.transformed(T)


def test_nan_is_named(room):
    T = np.eye(4)
    T[1, 3] = np.nan
    with pytest.raises(ValueError, match=r"T\[1, 3\] is nan"):
        room.transformed(T)
    T = np.eye(4)
    T[0, 0] = np.inf
    with pytest.raises(ValueError, match=r"T\[0, 0\] is inf"):
        room.transformed(T)


@pytest.mark.parametrize("res", [0, -0.1, float("nan"), "fine"])
def test_bad_resolution_is_refused(room, res):
    with pytest.raises(ValueError, match="resolution"):
        room.transformed(np.eye(4), resolution=res)


def test_outside_the_key_range_is_refused(room):
    with pytest.raises(ValueError, match="outside the octree's range"):
        room.transformed(pose_matrix(1e4, 0, 0))


# -- poses and frames --------------------------------------------------------------------------


def test_pose_round_trip():
    rng = np.random.default_rng(3)
    for _ in range(50):
        x, y, z = rng.uniform(-5, 5, 3)
        r, p, yw = rng.uniform(-3, 3), rng.uniform(-1.5, 1.5), rng.uniform(-3, 3)
        T = pose_matrix(x, y, z, r, p, yw)
        check_rigid(T)
        back = pose_matrix(**matrix_pose(T))
        np.testing.assert_allclose(back, T, atol=1e-12)
    np.testing.assert_allclose(invert(T) @ T, np.eye(4), atol=1e-12)


def test_parse_frame():
    name, T = parse_frame("robot2=1,2,0,0,0,1.5707963267948966")
    assert name == "robot2"
    np.testing.assert_allclose(T[:3, 3], [1, 2, 0])
    assert T[0, 1] == -1.0 and T[0, 0] == 0.0
    for bad, match in [
        ("robot2", "NAME="),
        ("r=1,2", "6 numbers"),
        ("r=1,a,2,0,0,0", "6 numbers"),
        ("r=1,2,3", "got 3"),
        ("r=1,nan,2,0,0,0", "finite"),
    ]:
        with pytest.raises(ValueError, match=match):
            parse_frame(bad)


# -- resolutions and fusing map files ----------------------------------------------------------


def test_common_resolution_default_is_the_coarsest():
    assert common_resolution([0.05, 0.1, 0.08]) == 0.1
    assert common_resolution([0.05, 0.1], 0.05) == 0.05
    assert common_resolution([0.1, 0.1], strict=True) == 0.1
    with pytest.raises(ValueError, match="different resolutions"):
        common_resolution([0.05, 0.1], strict=True)


def test_maps_of_different_resolutions_fuse_after_resampling(room):
    fine = room_map(SENSORS[:2], res=RES / 2)
    with pytest.raises(ValueError, match="different resolutions"):
        fuse_maps(room, fine)  # the low-level fusion stays strict
    with pytest.raises(ValueError, match="different resolutions"):
        prepare_maps([room, fine], strict=True)
    a, b = prepare_maps([room, fine])
    assert a is room and b.resolution == RES
    fused, loss = fuse_maps(a, b)
    assert fused.resolution == RES and loss.voxels_fused > 0


def test_fuse_map_files_with_frames_and_one_loss_convention(tmp_path, room):
    b = room_map(SENSORS[2:])
    c = room_map(SENSORS[1:3], res=RES / 2)
    shift = pose_matrix(3 * RES, -2 * RES, 0, 0, 0, math.pi / 2)  # B stored in its own frame
    room.save(tmp_path / "a.ot")
    b.transformed(invert(shift)).save(tmp_path / "b.ot")
    c.save(tmp_path / "c.ot")
    fused, loss, stats = fuse_map_files(
        [tmp_path / "a.ot", tmp_path / "b.ot", tmp_path / "c.ot"], frames={"b": shift}
    )
    want, _ = fuse_maps(fuse_maps(room, b).map, c.transformed(np.eye(4), RES))
    assert voxels(fused) == voxels(want)
    assert stats.resolution == RES and stats.resampled == [
        str(tmp_path / "b.ot"),
        str(tmp_path / "c.ot"),
    ]
    # fused voxels: known to both sides of each fusion; copied: known to one side only
    ab = np.asarray(b.class_counts(room, 0.0)["confusion"])
    both_ab = int(ab[:2, :2].sum())
    assert stats.voxels_fused > both_ab > 0 and stats.voxels_copied > 0
    assert stats.loss_mean == pytest.approx(stats.loss_total / stats.voxels_fused)
    assert loss.voxels_fused == stats.voxels_fused
    # one pair: the same numbers as fuse_maps' own counts where every voxel is a finest one
    _, _, pair = fuse_map_files([tmp_path / "a.ot", tmp_path / "c.ot"], resolution=RES)
    assert pair.voxels_fused + pair.voxels_copied > 0


def test_fuse_map_files_errors(tmp_path, room):
    room.save(tmp_path / "a.ot")
    room.save(tmp_path / "b.ot")
    with pytest.raises(ValueError, match="unknown map 'c'"):
        fuse_map_files([tmp_path / "a.ot", tmp_path / "b.ot"], frames={"c": np.eye(4)})
    with pytest.raises(ValueError, match="frame of .*b.ot.*not a rigid"):
        fuse_map_files(
            [tmp_path / "a.ot", tmp_path / "b.ot"], frames=[None, np.diag([1, 1, 2, 1.0])]
        )
    with pytest.raises(ValueError, match="1 frames given for 2"):
        fuse_map_files([tmp_path / "a.ot", tmp_path / "b.ot"], frames=[None])
    with pytest.raises(FileNotFoundError):
        fuse_map_files([tmp_path / "a.ot", tmp_path / "nope.ot"])


# ------------------------------------------------------------------ point sampling ("nearest")

ODD_MOVES = [
    pose_matrix(0.03, 0.02, 0.0, 0.0, 0.0, math.radians(3)),
    pose_matrix(0.37, -0.21, 0.05, 0.02, -0.01, math.radians(-17)),
]


@pytest.mark.slow
@pytest.mark.parametrize("T", ODD_MOVES)
def test_nearest_takes_the_value_at_the_pre_image_of_each_centre(room, T):
    moved = room.transformed(T, resampling="nearest")
    lv = moved.leaves()
    back = (invert(T) @ np.c_[lv.centers, np.ones(len(lv.values))].T).T[:, :3]
    src = room.leaves()
    for centre, value in zip(back[::7], lv.values[::7]):  # brute force over the source leaves
        inside = np.all(np.abs(src.centers - centre) <= src.sizes[:, None] / 2 + 1e-9, axis=1)
        assert inside.any(), "a voxel appeared whose centre came from unknown space"
        assert value == pytest.approx(float(src.values[inside][0]), abs=1e-6)


@pytest.mark.parametrize("T", ODD_MOVES)
def test_nearest_keeps_surfaces_thin_when_moved_back_and_forth(room, T):
    def counts(m):
        lv = m.leaves()
        w = np.power(8.0, 16 - lv.depths.astype(float))
        return w[lv.values > 0].sum(), w.sum()

    occ0, known0 = counts(room)
    vote = nearest = room
    for _ in range(4):
        vote = vote.transformed(T).transformed(invert(T))
        nearest = nearest.transformed(T, resampling="nearest").transformed(
            invert(T), resampling="nearest"
        )
    occ_v, known_v = counts(vote)
    occ_n, known_n = counts(nearest)
    assert occ_v > 1.5 * occ0  # occupied wins: surfaces thicken at every move
    assert abs(occ_n - occ0) <= 0.1 * occ0 and abs(known_n - known0) <= 0.05 * known0


@pytest.mark.parametrize("T", [pose_matrix(0.4, -0.2, 0.1), pose_matrix(yaw=math.pi / 2)])
def test_nearest_is_exact_where_the_grid_maps_onto_itself(room, T):
    a = room.transformed(T).leaves()
    b = room.transformed(T, resampling="nearest").leaves()
    assert np.array_equal(a.centers, b.centers) and np.array_equal(a.values, b.values)


def test_unknown_resampling_is_refused(room):
    with pytest.raises(ValueError, match="resampling 'cubic'"):
        room.transformed(np.eye(4), resampling="cubic")
