"""Landmarks from leaf arrays of a known scene: extraction, association and the map offset."""

import numpy as np
import pytest

from octofuse.maps.landmarks import (
    Landmarks,
    associate,
    extract_landmarks,
    map_offset,
    offsets_to_reference,
)

RES = 0.05
#: (centre x, centre y, size x, size y, height) of boxes standing on the floor
BOXES = [
    (1.0, 1.0, 0.30, 0.20, 0.20),
    (2.5, 1.5, 0.60, 0.50, 0.25),
    (1.5, 3.0, 0.24, 0.06, 0.15),
    (3.2, 3.4, 0.40, 0.40, 0.10),
]


def box_surface(cx, cy, sx, sy, h, step=0.01):
    """Points on the sides and top of a box standing on the floor."""
    xs, ys, zs = (
        np.arange(lo, hi + 1e-9, step)
        for lo, hi in ((cx - sx / 2, cx + sx / 2), (cy - sy / 2, cy + sy / 2), (0.0, h))
    )
    pts = []
    for x in (xs[0], xs[-1]):
        pts.append(np.stack(np.meshgrid([x], ys, zs, indexing="ij"), -1).reshape(-1, 3))
    for y in (ys[0], ys[-1]):
        pts.append(np.stack(np.meshgrid(xs, [y], zs, indexing="ij"), -1).reshape(-1, 3))
    pts.append(np.stack(np.meshgrid(xs, ys, [h], indexing="ij"), -1).reshape(-1, 3))
    return np.concatenate(pts)


def scene_points(dx=0.0, dy=0.0, yaw=0.0):
    """Floor, a long wall and the boxes, as a robot with map error (dx, dy, yaw) about the origin
    would map them."""
    floor = np.stack(
        np.meshgrid(np.arange(0, 4, 0.04), np.arange(0, 4, 0.04), [-0.01], indexing="ij"), -1
    ).reshape(-1, 3)
    wall = np.stack(
        np.meshgrid(np.arange(0, 4, 0.02), [4.0], np.arange(0, 0.6, 0.02), indexing="ij"), -1
    ).reshape(-1, 3)
    pts = np.concatenate([floor, wall] + [box_surface(*b) for b in BOXES])
    c, s = np.cos(yaw), np.sin(yaw)
    xy = pts[:, :2] @ np.array([[c, -s], [s, c]]).T + [dx, dy]
    return np.column_stack([xy, pts[:, 2]])


def leaves_of(points, coarse_free=True):
    """Leaf arrays of a map holding ``points`` as occupied finest voxels, plus free leaves."""
    keys = np.unique(np.floor(points / RES).astype(np.int64), axis=0)
    centers = (keys + 0.5) * RES
    sizes = np.full(len(keys), RES)
    values = np.full(len(keys), 2.0)
    if coarse_free:  # free space above everything, coarse leaves
        free = np.stack(
            np.meshgrid(
                np.arange(0, 4, 0.4) + 0.2, np.arange(0, 4, 0.4) + 0.2, [1.0], indexing="ij"
            ),
            -1,
        ).reshape(-1, 3)
        centers = np.vstack([centers, free])
        sizes = np.concatenate([sizes, np.full(len(free), 0.4)])
        values = np.concatenate([values, np.full(len(free), -2.0)])
    return centers, sizes, values


def test_boxes_are_found_with_their_centres():
    lm = extract_landmarks(*leaves_of(scene_points()), resolution=RES)
    assert len(lm) == len(BOXES)  # floor below, wall too long
    truth = np.array(sorted((b[0], b[1]) for b in BOXES))
    np.testing.assert_allclose(lm.centroids[:, :2], truth, atol=RES)
    assert np.all(lm.lower[:, 2] >= RES - 1e-9)
    for cov in lm.covariances:
        assert np.all(np.linalg.eigvalsh(cov) > 0)
        np.testing.assert_allclose(cov, cov.T)


def test_coarse_occupied_leaves_are_split_into_voxels():
    centers = np.array([[1.0, 1.0, 0.2], [1.0 + 1.5 * RES, 1.0 + RES / 2, 0.2 - RES / 2]])
    sizes = np.array([2 * RES, RES])  # a coarse leaf of 8 voxels and one voxel touching it
    lm = extract_landmarks(centers, sizes, np.array([1.0, 1.0]), resolution=RES)
    assert len(lm) == 1 and lm.voxels[0] == 9


def test_free_and_floor_voxels_are_not_landmarks():
    centers, sizes, values = leaves_of(scene_points())
    lm = extract_landmarks(centers, sizes, -np.abs(values), resolution=RES)
    assert len(lm) == 0
    lm = extract_landmarks(centers, sizes, values, resolution=RES, floor_height=1.0)
    assert len(lm) == 0


def test_walls_stay_with_a_larger_footprint():
    lm = extract_landmarks(*leaves_of(scene_points()), resolution=RES, max_footprint=10.0)
    assert len(lm) == len(BOXES) + 1


def test_association_is_one_to_one_and_gated():
    a = extract_landmarks(*leaves_of(scene_points()), resolution=RES)
    b = extract_landmarks(*leaves_of(scene_points(dx=0.1)), resolution=RES)
    pairs = associate(a, b, max_distance=0.3)
    assert pairs.tolist() == [[i, i] for i in range(len(BOXES))]
    assert len(associate(a, b, max_distance=0.01)) == 0


@pytest.mark.parametrize(
    "dx, dy, yaw", [(0.0, 0.0, 0.0), (0.2, -0.15, 0.0), (0.1, 0.05, np.radians(3))]
)
def test_map_offset_recovers_the_error(dx, dy, yaw):
    ref = extract_landmarks(*leaves_of(scene_points()), resolution=RES)
    own = extract_landmarks(*leaves_of(scene_points(dx, dy, yaw)), resolution=RES)
    pivot = np.zeros(2)
    x, cov = map_offset(ref, own, pivot=pivot)
    # own = R p + d  ->  the offset carrying own back is R^-1, -R^-1 d
    c, s = np.cos(yaw), np.sin(yaw)
    back = -np.array([[c, s], [-s, c]]) @ [dx, dy]
    np.testing.assert_allclose(x[:2], back, atol=1.5 * RES)
    assert abs(x[2] + yaw) < np.radians(1.5)
    assert np.all(np.linalg.eigvalsh(cov) > 0)


def test_offsets_to_reference_feed_voting():
    sets = [
        extract_landmarks(*leaves_of(scene_points(*e)), resolution=RES)
        for e in [(0, 0, 0), (0, 0, 0), (0.3, 0.0, 0.0), (0, 0, 0)]
    ]
    x, cov = offsets_to_reference(sets, 0)
    assert x.shape == (4, 3) and cov.shape == (4, 3, 3)
    assert np.abs(x[[0, 1, 3]]).max() < 1e-9
    assert x[2, 0] == pytest.approx(-0.3, abs=RES)


def test_bad_leaves_and_too_few_landmarks_raise():
    with pytest.raises(ValueError, match="centers"):
        extract_landmarks(np.zeros((3, 2)), np.ones(3), np.ones(3))
    with pytest.raises(ValueError, match="sizes"):
        extract_landmarks(np.zeros((3, 3)), np.ones(2), np.ones(3))
    one = Landmarks(
        np.zeros((1, 3)), np.eye(3)[None], np.ones(1, np.int64), np.zeros((1, 3)), np.ones((1, 3))
    )
    with pytest.raises(ValueError, match="at least 2"):
        map_offset(one, one)


def test_height_and_area_filters():
    leaves = leaves_of(scene_points())
    low = extract_landmarks(
        *leaves, resolution=RES, max_height=0.26
    )  # voxel tops: 0.25, 0.3, 0.2, 0.15
    assert sorted(np.round(low.centroids[:, :2], 1).tolist()) == [
        [1.0, 1.0],
        [1.5, 3.0],
        [3.2, 3.4],
    ]
    left = extract_landmarks(*leaves, resolution=RES, within=((0.0, 0.0), (2.0, 4.0)))
    assert len(left) == 2
    with pytest.raises(ValueError, match="within"):
        extract_landmarks(*leaves, within=((1.0, 0.0), (0.0, 4.0)))
