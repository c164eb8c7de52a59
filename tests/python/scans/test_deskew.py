"""De-skew and pose look-ups of many scans at once against the scan-by-scan path and the truth.

``ScanSource`` looks the poses and per-beam poses of consecutive scans up together
(``TransformBuffer.transform_points``: a rotation by the interpolated quaternion per beam, no
4x4 matrix); ``per_scan_transforms=True`` keeps a look-up per scan. Poses agree bit for bit,
de-skewed points within 1e-9 m, and both within 1e-9 m of the robot's true motion.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import bagfactory as bf
from conftest import REPO
from octofuse.maps.build import build, make_build_config
from octofuse.scans import source as source_module
from octofuse.scans.decode import laserscan_to_xyz
from octofuse.scans.se3 import quaternion_to_matrix, rotate_vectors
from octofuse.scans.source import ScanSource
from octofuse.scans.tf import ExtrapolationError, TransformBuffer
from test_io_tf import S, chain_buffer

LAB8 = REPO / "data" / "lab8.bag"
BEAMS = 72
TIME_INCREMENT = 0.1 / BEAMS  #: a 0.1 s sweep
POINT_TOL = 1e-9  #: metres


def test_rotate_vectors_matches_rotation_matrices():
    rng = np.random.default_rng(1)
    q = rng.normal(size=(500, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    v = rng.normal(size=(500, 3)) * 20
    want = np.einsum("kij,kj->ki", quaternion_to_matrix(q), v)
    np.testing.assert_allclose(rotate_vectors(q, v), want, rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    "target,source",
    [("map", "laser"), ("laser", "map"), ("cam", "laser"), ("odom", "cam"), ("laser", "laser")],
)
def test_transform_points_matches_lookup_many(target, source):
    """Up the chain, down the chain, across it: each point as its own 4x4 transform moves it."""
    buf = chain_buffer()
    rng = np.random.default_rng(2)
    stamps = np.concatenate([[10 * S, 12 * S, 20 * S], rng.integers(10 * S, 20 * S, 400)])
    pts = rng.normal(size=(stamps.size, 3)) * 10
    T = buf.lookup_many(target, source, stamps)
    want = np.einsum("kij,kj->ki", T[:, :3, :3], pts) + T[:, :3, 3]
    np.testing.assert_allclose(
        buf.transform_points(target, source, stamps, pts), want, rtol=0, atol=1e-12
    )


def test_transform_points_refuses_stamps_outside_the_samples():
    buf = chain_buffer()
    with pytest.raises(ExtrapolationError, match="1 of 2 stamps are outside"):
        buf.transform_points("map", "laser", [15 * S, 25 * S], np.zeros((2, 3)))
    with pytest.raises(ValueError, match="2 stamps for 1 points"):
        buf.transform_points("map", "laser", [15 * S, 16 * S], np.zeros((1, 3)))


def test_interpolation_between_samples_is_the_slerp_of_the_pair():
    """The per-pair arcs cached on a link give the slerp of the two samples around each stamp."""
    from octofuse.scans.se3 import slerp

    buf = TransformBuffer()
    rng = np.random.default_rng(3)
    q = rng.normal(size=(6, 4))
    q[3] = -q[2]  # the same rotation with the opposite sign: the short arc is taken
    buf.add_transforms("map", "base", np.arange(6) * S, rng.normal(size=(6, 3)), q)
    stamps = rng.integers(0, 5 * S, 200)
    got = buf.lookup_many("map", "base", stamps)
    qn = q / np.linalg.norm(q, axis=1, keepdims=True)
    i0 = stamps // S
    a = (stamps - i0 * S) / S
    want = quaternion_to_matrix(slerp(qn[i0], qn[i0 + 1], a))
    np.testing.assert_array_equal(got[:, :3, :3], want)


# -- sweeping LaserScans in a bag ---------------------------------------------------------------


def sweeping(rec: bf.Recording) -> None:
    """Give the LaserScan just recorded a sweep: beam i at stamp + i * TIME_INCREMENT."""
    topic, msgtype, log_ns, make = rec.records[-1]
    rec.records[-1] = (
        topic,
        msgtype,
        log_ns,
        lambda ts: dataclasses.replace(make(ts), time_increment=TIME_INCREMENT),
    )


def sweep_bag(tmp_path):
    """Two turning, driving robots with LaserScans sweeping over 0.1 s; tf at 10 Hz from
    T0 + 0.1 s to T0 + 1.5 s. Scans before the first sample, sweeping past the last one, of
    an unknown frame, and a robot whose tf is a static chain only."""
    fast = bf.Robot(
        "r1",
        start=(0.5, 0.2, 0.3),
        velocity=(0.8, -0.3, 1.5),
        sensor="laser",
        mount=(0.1, 0.05, 0.3, 0.4),
    )
    still = bf.Robot("r2", start=(-1.0, 0.5, 2.0), sensor="laser")
    rec = bf.Recording()
    rec.robot_tf(fast, [bf.T0 + k * S // 10 for k in range(1, 16)])
    rec.tf(
        bf.T0,
        [
            ("map", still.odom_frame, still.odom_matrix()),
            (
                still.odom_frame,
                still.base_frame,
                bf.pose_matrix(*still.start[:2], 0.0, still.start[2]),
            ),
            (still.base_frame, still.sensor_frame, still.mount_matrix()),
        ],
        static=True,
        log_ns=bf.T0,
    )
    placed = []
    for k in range(26):
        t = bf.T0 + 50_000_000 + k * 57_000_000  # 0.05 s ... 1.475 s: first one too early
        shot = rec.robot_scan(fast, t, beams=BEAMS)
        sweeping(rec)
        if bf.T0 + S // 10 <= t and t + BEAMS * TIME_INCREMENT * S <= bf.T0 + 15 * S // 10:
            placed.append(shot)
        rec.robot_scan(still, t + 1000, beams=BEAMS)
        sweeping(rec)
    rec.scan(
        "/r1/scan", "ghost/laser", bf.T0 + S // 2, fast.sensor_pose(bf.T0 + S // 2), beams=BEAMS
    )
    return rec.write(tmp_path / "sweep", "mcap"), fast, placed


def scans_both_ways(cfg):
    out = {}
    for per_scan in (True, False):
        with ScanSource(cfg, per_scan_transforms=per_scan) as src:
            out[per_scan] = (list(src.scans()), src.stats)
    return out[True], out[False]


def assert_same_scans(per_scan, batched):
    (ref, ref_stats), (got, got_stats) = per_scan, batched
    assert [(s.agent, s.stamp_ns, len(s.points)) for s in got] == [
        (s.agent, s.stamp_ns, len(s.points)) for s in ref
    ]
    for a, b in zip(ref, got):
        np.testing.assert_array_equal(b.pose, a.pose)
        np.testing.assert_allclose(b.points, a.points, rtol=0, atol=POINT_TOL)
        assert b.max_range == a.max_range
    assert [(s.scans_used, dict(s.skipped), s.points, dict(s.dropped)) for s in got_stats] == [
        (s.scans_used, dict(s.skipped), s.points, dict(s.dropped)) for s in ref_stats
    ]


def test_batched_lookups_match_the_per_scan_path_and_the_true_motion(tmp_path, monkeypatch):
    monkeypatch.setattr(source_module, "PLACE_CHUNK", 5)  # chunks end mid-stream
    bag, robot, inside = sweep_bag(tmp_path)
    cfg = make_build_config(bag, resolution=0.1)
    per_scan, batched = scans_both_ways(cfg)
    assert_same_scans(per_scan, batched)
    stats = {s.name: s for s in batched[1]}
    assert stats["r1"].skipped == {
        "before the first transform": 1,
        "unknown frame 'ghost/laser'": 1,
    }
    assert stats["r1"].scans_used == 25 and stats["r2"].scans_used == 26

    # every beam moved by the robot's true motion between the scan's stamp and the beam's
    by_stamp = {s.stamp_ns: s for s in batched[0] if s.agent == 0}
    assert len(inside) >= 20
    with ScanSource(cfg) as src:
        msgs = {
            m.msg.header.stamp.sec * S + m.msg.header.stamp.nanosec: m.msg
            for m in src.bags.messages({"/r1/scan": ["sensor_msgs/msg/LaserScan"]})
        }
    for shot in inside:
        scan = by_stamp[shot.stamp_ns]
        msg = msgs[shot.stamp_ns]
        hits, _ = laserscan_to_xyz(msg)
        ranges = np.asarray(msg.ranges, dtype=np.float64)
        beam = np.flatnonzero(
            np.isfinite(ranges) & (ranges >= msg.range_min) & (ranges <= msg.range_max)
        )
        at_stamp = np.linalg.inv(robot.sensor_pose(shot.stamp_ns))
        step_ns = float(msg.time_increment) * 1e9  # float32 in the message
        want = np.array(
            [
                (
                    at_stamp
                    @ robot.sensor_pose(int(shot.stamp_ns + i * step_ns))
                    @ np.append(p, 1.0)
                )[:3]
                for i, p in zip(beam, hits)
            ]
        )
        np.testing.assert_allclose(scan.points, want, rtol=0, atol=POINT_TOL)
        # and the sweep mattered: the beams were moved by more than a centimetre
        assert np.abs(scan.points - hits).max() > 0.01


def test_build_maps_are_the_same_both_ways(tmp_path):
    bag, _, _ = sweep_bag(tmp_path)
    cfg = make_build_config(bag, resolution=0.1)
    ref = build(cfg, per_scan_transforms=True).all_maps()
    got = build(cfg).all_maps()
    for name in ref:
        bf.assert_same_map(got[name], ref[name], name)


def test_lab8_batched_lookups_match_the_per_scan_path():
    """The bundled bag (8 robots, 667-beam sweeps): every 40th scan of each robot."""
    per_scan, batched = scans_both_ways(make_build_config(str(LAB8), scan_stride=40))
    assert len(batched[0]) == 8 * 15
    assert_same_scans(per_scan, batched)


@pytest.mark.parametrize(
    "increment,reason",
    [(-1.0, "negative time_increment"), (1e30, "span more than"), (0.5, "span more than")],
)
def test_scans_that_cannot_sweep_so_are_skipped_and_deskew_is_reported(tmp_path, increment, reason):
    from octofuse.outputs.tables import skip_notes

    robot = bf.Robot("r1", start=(0.5, 0.2, 0.3), sensor="laser")
    rec = bf.Recording()
    rec.robot_tf(robot, [bf.T0 + k * S // 10 for k in range(0, 30)])
    for k in range(6):
        rec.robot_scan(robot, bf.T0 + S // 5 + k * S // 4, beams=BEAMS)
        topic, msgtype, log_ns, make = rec.records[-1]
        inc = increment if k % 2 else TIME_INCREMENT
        rec.records[-1] = (
            topic,
            msgtype,
            log_ns,
            lambda ts, make=make, inc=inc: dataclasses.replace(make(ts), time_increment=inc),
        )
    result = build(make_build_config(rec.write(tmp_path / "odd", "mcap"), resolution=0.1))
    (stats,) = result.stats
    assert stats.scans_used == 3 and sum(stats.skipped.values()) == 3
    assert reason in next(iter(stats.skipped))
    notes = skip_notes(result)
    assert any("skipped 3 scan(s)" in n and reason in n for n in notes)
    assert "r1: de-skewed all 3 LaserScan(s) (beam times from time_increment)" in notes
