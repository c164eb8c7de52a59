"""What a run writes: export modes and heat-map formats, heat maps of the occupied voxels of the
fused maps over one colour range, top views, the loss of every fusion event, and a bag of the
maps after every fusion for replay."""

from __future__ import annotations

import json
import struct
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bagfactory as bf  # noqa: E402
from bagfactory import run_cli, run_keeping_result  # noqa: E402
from conftest import finest_voxels  # noqa: E402
from octofuse import OccupancyMap  # noqa: E402
from octofuse.fusion.results import FusionEvent  # noqa: E402
from octofuse.outputs.clouds import read_cloud  # noqa: E402
from octofuse.outputs.event_loss import (  # noqa: E402
    MIN_EXPLAINED,
    counts_messages,
    event_loss_summary,
    messages_sentence,
)
from octofuse.outputs.export import MapVoxelLoss, colorize  # noqa: E402
from octofuse.outputs.rosbag_export import read_map_bag  # noqa: E402
from octofuse.outputs.topview import (  # noqa: E402
    MARGIN_PX,
    MAX_SIDE_PX,
    MIN_CELL_PX,
    MIN_SIDE_PX,
    above_floor,
    frame_for,
    pooled_max,
    topview_grid,
)

RES = "0.2"
AGENTS = ["a", "b", "c", "d"]
RULES = ["naive-bayes", "chernoff", "kld-weighted-chernoff", "min-info-loss"]
BASE = [
    "--topology",
    "ring",
    "--schedule",
    "aperiodic:0.4",
    "--resolution",
    RES,
    "--samples",
    "0",
    "--seed",
    "3",
]


def png_size(p: Path) -> tuple[int, int]:
    head = p.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n", p
    return struct.unpack(">II", head[16:24])


def files(out: Path, *suffixes: str) -> list[str]:
    return sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.suffix in suffixes)


def voxels(m) -> dict:
    k, v = finest_voxels(m.leaves(), m.resolution)
    return dict(zip(map(tuple, k.tolist()), v.tolist()))


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    robots = bf.team(4)
    return bf.robot_recording(robots, bf.team_times(robots, 4)).write(
        tmp_path_factory.mktemp("bag") / "team", "mcap"
    )


@pytest.fixture(scope="module")
def run_all(bag, tmp_path_factory):
    """One run of four rules with heat maps in both formats and the per-event bag."""
    tmp = tmp_path_factory.mktemp("run")
    out, replay = tmp / "out", tmp / "replay.mcap"
    # rounds at 1 s and 2 s: the last one after every scan, so the maps written are the maps
    # of each agent's last fusion
    args = [*BASE[:2], "--schedule", "periodic:1", *BASE[4:]]
    code, res = run_keeping_result(
        "run",
        bag,
        "--rules",
        ",".join(RULES),
        *args,
        "--formats",
        "ply,pcd",
        "--export-bag",
        replay,
        "--out",
        out,
    )
    assert code == 0
    return out, replay, res


# -- what is written --------------------------------------------------------------------------


@pytest.mark.parametrize("mode", ["none", "fused", "all"])
def test_export_modes_and_formats(bag, tmp_path, capsys, mode):
    out = tmp_path / "o"
    code, _, err = run_cli(
        capsys, "run", bag, "--rules", "chernoff", *BASE, "--export", mode, "--out", out
    )
    assert code == 0, err
    assert (out / "report.md").is_file() and (out / "summary.json").is_file()
    maps = [f"chernoff/{a}.ot" for a in AGENTS] + ["centralized.ot"]
    clouds = [f"chernoff/{a}_info_loss.ply" for a in AGENTS]
    want = {"none": [], "fused": maps, "all": maps + clouds}[mode]
    assert files(out, ".ot", ".bt", ".ply", ".pcd") == sorted(want)  # default formats: ply only
    assert (out / "info_loss_colorbar.png").is_file() == (mode == "all")
    assert (out / "topview_chernoff.png").is_file()  # a plot of the report, in every mode


def test_run_writes_both_formats_and_a_shared_colour_range(run_all):
    out, _, res = run_all
    s = json.loads((out / "summary.json").read_text())
    lo, hi = s["exports"]["range"]
    assert 0.0 == lo < hi
    values = []
    for r in RULES:
        for a in AGENTS:
            ply, pcd = (read_cloud(out / r / f"{a}_info_loss{ext}") for ext in (".ply", ".pcd"))
            for name in ("positions", "info_loss", "log_odds"):
                np.testing.assert_array_equal(ply[name], pcd[name])
            # every heat map is coloured over the run's one range
            want = colorize(ply["info_loss"], "inferno", lo, hi) / 255.0
            np.testing.assert_allclose(ply["colors"], want, atol=1 / 255 + 1e-6)
            values.append(ply["info_loss"])
    v = np.concatenate(values)
    assert hi == pytest.approx(np.percentile(v.astype(np.float64), 99), rel=1e-5)
    assert png_size(out / "info_loss_colorbar.png") == (750, 120)
    assert (out / "chernoff" / "a_info_loss.ply").stat().st_size > 0


def test_heat_maps_hold_the_occupied_voxels_of_the_fused_maps(run_all):
    out, _, res = run_all
    for r in ("chernoff", "min-info-loss"):
        for a in AGENTS:
            cloud = read_cloud(out / r / f"{a}_info_loss.ply")
            lv = res.fused[r][a].leaves()
            occ = lv.values > 0
            # brute force: every occupied leaf of the fused map, with its loss voxel's value
            loss = {tuple(k): v for k, v in zip(*finest_voxels(res.loss[r][a].leaves(), 0.2))}
            keys = np.floor(lv.centers[occ] / 0.2).astype(np.int64)
            covered = np.array([tuple(k) in loss for k in keys.tolist()])
            want_pos = lv.centers[occ][covered]
            order = np.lexsort(cloud["positions"].T)
            want_order = np.lexsort(want_pos.T)
            np.testing.assert_allclose(cloud["positions"][order], want_pos[want_order], atol=1e-5)
            want_loss = np.array([loss[tuple(k)] for k in keys[covered].tolist()], np.float32)
            np.testing.assert_array_equal(cloud["info_loss"][order], want_loss[want_order])
            assert (cloud["log_odds"] > 0).all() and (cloud["occupancy"] > 0.5).all()
            assert len(cloud["positions"]) == covered.sum() > 50  # never fused: no loss voxel


def test_report_embeds_three_top_views_of_the_first_agent(run_all):
    out, _, _ = run_all
    md = (out / "report.md").read_text()
    s = json.loads((out / "summary.json").read_text())
    views = s["exports"]["topviews"]
    assert [v["rule"] for v in views] == ["chernoff", "kld-weighted-chernoff", "min-info-loss"]
    for v in views:
        width, height = png_size(out / v["file"])  # sized to the map: a small one here
        assert v["agent"] == "a" and width == MIN_SIDE_PX + MARGIN_PX[0]
        assert f"![{v['rule']}]({v['file']})" in md
    assert not (out / "topview_naive-bayes.png").exists()
    lo, hi = s["exports"]["range"]
    assert f"{lo:.4g} to {hi:.4g} nats" in md and "occupied voxels" in md


def test_topview_grid_against_brute_force():
    rng = np.random.default_rng(4)
    res = 0.1
    keys = rng.integers(-20, 20, size=(300, 3))
    centers = (keys + 0.5) * res
    sizes = np.full(len(keys), res)
    centers = np.vstack([centers, [[0.4, 0.4, 0.4]]])  # one coarse leaf: 8 x 8 x 8 voxels
    sizes = np.append(sizes, 0.8)
    loss = rng.uniform(0, 2, len(sizes)).astype(np.float32)
    v = MapVoxelLoss(centers, sizes, np.ones(len(sizes), np.float32), loss)
    grid, (x0, x1, y0, y1) = topview_grid(v, res)
    want: dict = {}
    for c, s, l in zip(centers, sizes, loss):
        n = int(round(s / res))
        ix0, iy0 = (
            int(np.floor((c[0] - s / 2) / res + 0.5)),
            int(np.floor((c[1] - s / 2) / res + 0.5)),
        )
        for i in range(ix0, ix0 + n):
            for j in range(iy0, iy0 + n):
                want[(i, j)] = max(want.get((i, j), -1.0), float(l))
    assert (x0, y0) == (-20 * res, -20 * res) and grid.shape == (
        round((y1 - y0) / res),
        round((x1 - x0) / res),
    )
    for (i, j), w in want.items():
        assert grid[j + 20, i + 20] == pytest.approx(w)
    assert np.isnan(grid).sum() == grid.size - len(want)


def test_pooled_max_keeps_the_largest_value_of_each_block():
    rng = np.random.default_rng(5)
    grid = rng.uniform(0, 1, (7, 11))
    grid[rng.uniform(size=grid.shape) < 0.5] = np.nan
    grid[:3, :3] = np.nan  # a block with no voxel
    pooled = pooled_max(grid, 3)
    assert pooled.shape == (3, 4)
    for i in range(3):
        for j in range(4):
            block = grid[3 * i : 3 * i + 3, 3 * j : 3 * j + 3]
            if np.isnan(block).all():
                assert np.isnan(pooled[i, j])
            else:
                assert pooled[i, j] == np.nanmax(block)


@pytest.mark.parametrize("cells", [(10, 12), (300, 200), (400, 5000), (6000, 90)])
def test_top_views_draw_every_cell_on_a_few_pixels(cells):
    pool, (width, height) = frame_for(cells)
    rows, cols = -(-cells[0] // pool), -(-cells[1] // pool)
    axes = (width - MARGIN_PX[0], height - MARGIN_PX[1])
    assert min(axes) >= MIN_SIDE_PX / 2 and max(axes) <= MAX_SIDE_PX
    px = min(axes[0] / cols, axes[1] / rows)  # pixels a drawn cell, at the least
    assert px >= MIN_CELL_PX
    assert pool == 1 or px < MIN_CELL_PX * 2  # cells are pooled only when they must be


def test_floor_is_left_out_of_top_views():
    res = 0.1
    floor = [((i + 0.5) * res, (j + 0.5) * res, -0.05) for i in range(10) for j in range(10)]
    wall = [(0.05, (j + 0.5) * res, 0.05 + 0.1 * k) for j in range(10) for k in range(1, 4)]
    c = np.array(floor + wall)
    v = MapVoxelLoss(
        c, np.full(len(c), res), np.ones(len(c), np.float32), np.zeros(len(c), np.float32)
    )
    assert above_floor(v, res) == pytest.approx((0.0, np.inf))
    grid, _ = topview_grid(v, res, above_floor(v, res))
    assert grid.shape == (10, 1)  # only the wall's column is left
    wall_only = MapVoxelLoss(c[100:], v.sizes[100:], v.log_odds[100:], v.loss[100:])
    assert above_floor(wall_only, res) is None  # no scanned floor: every voxel kept


# -- loss per fusion event ------------------------------------------------------------------


def test_every_fusion_is_recorded_with_its_loss(run_all):
    out, _, res = run_all
    s = json.loads((out / "summary.json").read_text())
    records = s["fusion_events"]
    for r in RULES:
        mine = [e for e in records if e["rule"] == r]
        tr = res.traffic[r]
        assert len(mine) == tr.messages - tr.lost > 0
        for a in AGENTS:
            got = [e for e in mine if e["receiver"] == a]
            loss = res.loss[r][a]
            assert sum(e["voxels"] for e in got) == loss.voxels_fused
            assert sum(e["loss"] for e in got) == pytest.approx(loss.loss_sum, rel=1e-9, abs=1e-9)
            # the loss map holds the same loss, voxel by voxel (coarse fusions over voxels
            # fused before at a finer level included)
            lv = loss.leaves()
            in_map = float(np.sum(np.power(8.0, 16 - lv.depths.astype(float)) * lv.values))
            assert in_map == pytest.approx(loss.loss_sum, rel=1e-6)
        if r == "naive-bayes":
            assert all(e["loss"] == 0 for e in mine)
        else:
            assert any(e["loss"] > 0 for e in mine)
    times = [e["t"] for e in records]
    assert times == sorted(times)
    row = s["loss_per_event"]["chernoff"]
    assert row["events"] == len([e for e in records if e["rule"] == "chernoff"])
    md = (out / "report.md").read_text()
    assert "## Information loss per fusion event" in md and s["loss_per_event_finding"] in md


def _events(per_agent: dict[str, list[float]], rule: str = "r") -> list[FusionEvent]:
    return [
        FusionEvent(float(i), rule, "x", a, 100, loss)
        for a, losses in per_agent.items()
        for i, loss in enumerate(losses)
    ]


def test_accumulated_loss_that_counts_messages_is_said_so():
    # constant loss per event, agents fusing 1 to 4 messages: accumulated = messages x 2 nats
    s = event_loss_summary(
        _events({"a": [2.0], "b": [2.0] * 2, "c": [2.0] * 3, "d": [2.0] * 4}), ["a", "b", "c", "d"]
    )
    row = s["r"]
    assert row["correlation"] == pytest.approx(1.0) and row["event_loss_cv"] == 0.0
    assert row["accumulated"] == {"a": 2.0, "b": 4.0, "c": 6.0, "d": 8.0}
    assert row["mean_loss_per_event"] == 2.0 and row["loss_per_voxel"] == pytest.approx(0.02)
    assert counts_messages(row) is True
    assert messages_sentence(s).startswith(
        "The accumulated loss mostly reflects the number of messages an agent fused"
    )
    assert "`r` 100%" in messages_sentence(s)


def test_accumulated_loss_driven_by_per_event_loss_is_not():
    # the agent with most messages loses least: the ranking is not the message count
    s = event_loss_summary(
        _events({"a": [9.0], "b": [0.1] * 4, "c": [3.0, 3.0], "d": [1.0] * 3}), ["a", "b", "c", "d"]
    )
    row = s["r"]
    assert row["correlation"] < 0 and row["event_loss_cv"] > 1
    assert counts_messages(row) is False
    assert "does not mostly reflect" in messages_sentence(s)
    # per-event losses that vary at random: the message count explains little
    weak = event_loss_summary(
        _events({"a": [5.0], "b": [1.0, 2.0], "c": [0.5, 6.0, 0.2], "d": [1.0, 0.5, 1.0, 1.0]}),
        ["a", "b", "c", "d"],
    )
    assert 0 < weak["r"]["correlation"] ** 2 < MIN_EXPLAINED
    assert counts_messages(weak["r"]) is False and "`r` " in messages_sentence(weak)
    # equal message counts: no correlation to compute, and the sentence says so
    same = event_loss_summary(
        _events({"a": [1.0, 2.0], "b": [1.0, 1.0], "c": [3.0, 1.0]}), ["a", "b", "c"]
    )
    assert same["r"]["correlation"] is None and counts_messages(same["r"]) is None
    assert "cannot be told" in messages_sentence(same)
    assert (
        event_loss_summary([FusionEvent(0.0, "channel-filter", "a", "b", None, None)], ["a", "b"])
        == {}
    )


# -- the per-event bag ----------------------------------------------------------------------


def test_bag_replays_every_fusion_and_ends_at_the_written_maps(run_all):
    out, replay, res = run_all
    s = json.loads((out / "summary.json").read_text())
    got = read_map_bag(replay)
    start = bf.T0
    # one message per rule, receiver and instant it fused at least one message
    want = sorted(
        {(e["rule"], e["receiver"], start + round(e["t"] * 1e9)) for e in s["fusion_events"]},
        key=lambda x: x[2],
    )
    assert len(got) == len(want) == s["event_bag"]["messages"]
    assert sorted((t, st) for t, st, _ in got) == sorted(
        (f"/octofuse/{r}/{a}/octomap", st) for r, a, st in want
    )
    stamps = [st for _, st, _ in got]
    assert stamps == sorted(stamps)
    for r in RULES:
        for a in AGENTS:
            mine = [m for t, _, m in got if t == f"/octofuse/{r}/{a}/octomap"]
            assert mine, (r, a)
            assert voxels(mine[-1]) == voxels(OccupancyMap.load(out / r / f"{a}.ot")), (r, a)
    assert [p.name for p in replay.parent.iterdir() if p.name.startswith(".")] == []


def test_bag_path_is_checked_before_the_run(bag, tmp_path, capsys):
    taken = tmp_path / "taken.mcap"
    taken.write_bytes(b"keep")
    out = tmp_path / "o"
    code, _, err = run_cli(
        capsys, "run", bag, "--rules", "chernoff", *BASE, "--export-bag", taken, "--out", out
    )
    assert code == 1 and err.startswith("error: ") and "exists" in err
    assert taken.read_bytes() == b"keep" and not out.exists()
    code, _, err = run_cli(
        capsys,
        "run",
        bag,
        "--rules",
        "chernoff",
        *BASE,
        "--export-bag",
        out / "r.mcap",
        "--out",
        out,
    )
    assert code == 1 and "inside --out" in err and not out.exists()
    code, _, err = run_cli(
        capsys,
        "run",
        bag,
        "--rules",
        "chernoff",
        *BASE,
        "--export-agents",
        "none",
        "--export-bag",
        tmp_path / "r.mcap",
        "--out",
        out,
    )
    assert code == 1 and "no agent is exported" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["taken.mcap"]


def test_bag_of_the_exported_agents_only_as_ros1(bag, tmp_path, capsys):
    replay = tmp_path / "replay.bag"
    code, text, err = run_cli(
        capsys,
        "run",
        bag,
        "--rules",
        "min-info-loss",
        *BASE,
        "--export-agents",
        "b",
        "--export",
        "none",
        "--export-bag",
        replay,
        "--out",
        tmp_path / "o",
    )
    assert code == 0, err
    got = read_map_bag(replay)
    assert got and {t for t, _, _ in got} == {"/octofuse/min-info-loss/b/octomap"}
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    fused_by_b = {e["t"] for e in s["fusion_events"] if e["receiver"] == "b"}
    assert [st for _, st, _ in got] == [bf.T0 + round(t * 1e9) for t in sorted(fused_by_b)]
    assert f"bag: {replay} ({len(got)} map messages)" in text


# -- configuration ----------------------------------------------------------------------------


def test_export_flags_round_trip_through_the_config(bag, tmp_path, capsys):
    code, text, err = run_cli(
        capsys,
        "run",
        bag,
        "--rules",
        "chernoff",
        *BASE,
        "--export",
        "fused",
        "--formats",
        "pcd,ply",
        "--out",
        tmp_path / "o",
        "--dump-config",
    )
    assert code == 0, err
    cfg = yaml.safe_load(text)
    assert cfg["export"] == "fused" and cfg["formats"] == ["pcd", "ply"]
    conf = tmp_path / "run.yaml"
    conf.write_text(text)
    code, again, err = run_cli(capsys, "run", "--config", conf, "--dump-config")
    assert code == 0 and again == text


@pytest.mark.parametrize(
    "flags, message",
    [
        (["--formats", "ply,obj"], "formats = ['ply,obj']: expected one or more of ply, pcd"),
        (["--export", "some"], "Invalid value for '--export'"),
    ],
)
def test_bad_export_flags_are_one_line(bag, tmp_path, capsys, flags, message):
    code, _, err = run_cli(capsys, "run", bag, *flags, "--out", tmp_path / "o")
    assert code in (1, 2) and message in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_loss_histograms_counted_on_threads_draw_the_same_image(tmp_path):
    from octofuse.outputs.loss_histogram import count_loss_histograms, plot_loss_histograms

    def plot(data, path, threads):
        return plot_loss_histograms(count_loss_histograms(data, threads), path)

    rng = np.random.default_rng(3)

    def agents(scale, n=3):  # each agent's loss leaves
        return [
            (
                rng.gamma(2.0, scale, 2000).astype(np.float32),
                rng.integers(13, 17, 2000).astype(np.uint8),
            )
            for _ in range(n)
        ]

    data = {
        "chernoff": agents(0.3),
        "min-info-loss": agents(0.5),
        "empty": [(np.zeros(0, np.float32), np.zeros(0, np.uint8))],
    }
    kept = {r: [(v.copy(), d.copy()) for v, d in leaves] for r, leaves in data.items()}
    one = plot(data, tmp_path / "one.png", 1)
    two = plot(data, tmp_path / "two.png", 2)
    assert one.read_bytes() == two.read_bytes()
    for r, leaves in data.items():  # the agents' values are left as they were
        assert all(
            np.array_equal(v, kv) and np.array_equal(d, kd)
            for (v, d), (kv, kd) in zip(leaves, kept[r])
        )
    # the agents' leaves in one array draw the same image
    whole = {r: [tuple(np.concatenate(x) for x in zip(*leaves))] for r, leaves in data.items()}
    assert plot(whole, tmp_path / "whole.png", 2).read_bytes() == one.read_bytes()
    # a rule with other values draws another image
    data["chernoff"] = [(v * 2, d) for v, d in data["chernoff"]]
    assert plot(data, tmp_path / "other.png", 2).read_bytes() != one.read_bytes()


def test_every_rule_of_the_loss_histogram_shows_beside_its_legend():
    from octofuse.outputs.libraries import pyplot
    from octofuse.outputs.loss_histogram import LossHistograms, loss_histogram_figure

    same = np.geomspace(1e-3, 0.1, 10)  # Bhattacharyya and Chernoff are often this close
    hist = LossHistograms(
        np.linspace(0, 2, 11),
        {"chernoff": same, "bhattacharyya": same.copy(), "min-info-loss": same[::-1].copy()},
    )
    fig = loss_histogram_figure(hist)
    try:
        fig.canvas.draw()
        ax = fig.axes[0]
        lines = ax.patches
        assert len({(p.get_linestyle(), p.get_linewidth()) for p in lines}) == len(lines) == 3
        legend, plot = fig.legends[0].get_window_extent(), ax.get_window_extent()
        assert not legend.overlaps(plot)
    finally:
        pyplot().close(fig)
