"""Heat maps of the information loss on the fused map's voxels (outputs.export.write_heatmap)."""

import numpy as np
import pytest

from bagfactory import SENSORS, room_map
from octofuse.maps.tree_fusion import fuse_maps
from octofuse.outputs.clouds import read_cloud
from octofuse.outputs.export import shared_color_range, write_heatmap


@pytest.fixture(scope="module")
def fused():
    a, b = room_map(SENSORS[:2]), room_map(SENSORS[1:])
    return {
        rule: fuse_maps(a, b, rule=rule)
        for rule in ("min-info-loss", "naive-bayes", "bhattacharyya")
    }


def test_occupied_voxels_by_default_with_occupancy_fields(fused, tmp_path):
    m, loss = fused["bhattacharyya"]
    out = write_heatmap(loss, tmp_path / "h.ply", map=m)
    c = read_cloud(out)
    lv = m.leaves()
    assert len(c["positions"]) == int((lv.values > 0).sum()) > 100
    assert (c["log_odds"] > 0).all() and (c["occupancy"] > 0.5).all()
    assert {"info_loss", "voxel_size"} <= set(c)
    free = read_cloud(write_heatmap(loss, tmp_path / "f.pcd", map=m, voxels="free"))
    assert (free["log_odds"] <= 0).all() and len(free["positions"]) > len(c["positions"])
    every = read_cloud(write_heatmap(loss, tmp_path / "a.ply", map=m, voxels="all"))
    assert len(every["positions"]) == len(c["positions"]) + len(free["positions"])


def test_loss_values_are_those_of_the_loss_map(fused, tmp_path):
    m, loss = fused["bhattacharyya"]
    c = read_cloud(write_heatmap(loss, tmp_path / "h.ply", map=m, voxels="all"))
    ll = loss.leaves()
    # every loss leaf's value appears at its own centre
    pos = np.round(c["positions"] / 0.05).astype(np.int64)
    want = dict(zip(map(tuple, np.round(ll.centers / 0.05).astype(np.int64).tolist()), ll.values))
    got = dict(zip(map(tuple, pos.tolist()), c["info_loss"]))
    common = set(want) & set(got)
    assert len(common) > 100
    assert all(got[k] == pytest.approx(want[k]) for k in common)


def test_shared_range_crop_slice_and_colour_bar(fused, tmp_path):
    lo, hi = shared_color_range([loss for _, loss in fused.values()])
    assert lo == 0.0 and hi > 0
    for rule, (m, loss) in fused.items():
        write_heatmap(
            loss,
            tmp_path / f"{rule}.ply",
            map=m,
            vmin=lo,
            vmax=hi,
            colorbar=tmp_path / "bar.png",
            crop=((-3, -2, -0.2), (0, 2, 2.5)),
            z_range=(0.0, 1.0),
        )
        c = read_cloud(tmp_path / f"{rule}.ply")
        assert (c["positions"][:, 0] <= 0).all() and (c["positions"][:, 2] <= 1.0).all()
    assert (tmp_path / "bar.png").read_bytes()[:4] == b"\x89PNG"


def test_bad_filters_are_refused(fused, tmp_path):
    m, loss = fused["bhattacharyya"]
    with pytest.raises(ValueError, match="crop box .* holds no voxel"):
        write_heatmap(loss, tmp_path / "x.ply", map=m, crop=((10, 10, 10), (11, 11, 11)))
    with pytest.raises(ValueError, match="empty"):
        write_heatmap(loss, tmp_path / "x.ply", map=m, crop=((1, 1, 1), (0, 0, 0)))
    with pytest.raises(ValueError, match="height slice"):
        write_heatmap(loss, tmp_path / "x.ply", map=m, z_range=(5, 6))
    with pytest.raises(ValueError, match="needs the fused map"):
        write_heatmap(loss, tmp_path / "x.ply", voxels="occupied")
    with pytest.raises(ValueError, match="voxels="):
        write_heatmap(loss, tmp_path / "x.ply", map=m, voxels="walls")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("voxels", ["occupied", "free", "all"])
def test_core_lookup_equals_the_leaf_lookup(fused, voxels):
    """The heat map's voxels from the loss map (one walk in the core) equal those found by
    looking the map's leaf centres up in the loss map's leaves (Leaves.values_at), value for
    value: every rule, every class, and a loss map coarser and finer than the map in places."""
    from octofuse.outputs.export import map_voxel_loss

    for rule, (m, loss) in fused.items():
        fast = map_voxel_loss(loss, m, voxels)
        slow = map_voxel_loss(loss.leaves(), m, voxels)
        assert len(fast.loss) > 0 or rule == "naive-bayes"
        for field in fast._fields:
            x, y = getattr(fast, field), getattr(slow, field)
            assert x.dtype == y.dtype and np.array_equal(x, y), (rule, field)
    # the other way round: the map of one rule against the loss of another (other pruning)
    m, _ = fused["naive-bayes"]
    _, loss = fused["min-info-loss"]
    fast, slow = map_voxel_loss(loss, m, voxels), map_voxel_loss(loss.leaves(), m, voxels)
    assert all(np.array_equal(getattr(fast, f), getattr(slow, f)) for f in fast._fields)
    values, depths = loss.values_depths()
    lv = loss.leaves()
    assert np.array_equal(values, lv.values) and np.array_equal(depths, lv.depths)
