"""End to end: ``octofuse run``, ``fuse``, ``bench`` and ``demo`` on a small bag of four robots
in the box room (written with rosbags), their output files and their error messages."""

from __future__ import annotations

import csv
import json
import math
import re
import shutil
import sys
from pathlib import Path

import pytest
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bagfactory as bf  # noqa: E402
from bagfactory import T0, S, assert_same_map, run_cli, run_keeping_result  # noqa: E402
from conftest import REPO  # noqa: E402
from octofuse import OccupancyMap  # noqa: E402
from octofuse.config import FuseConfig  # noqa: E402
from octofuse.fusion.results import LOCAL, rule_time_part
from octofuse.fusion.rounds import fuse_finished  # noqa: E402

pytestmark = pytest.mark.slow

RES = "0.2"
AGENTS = ["a", "b", "c", "d"]
PNG = b"\x89PNG\r\n\x1a\n"


def is_png(p: Path) -> bool:
    return p.is_file() and p.read_bytes()[:8] == PNG


def fraction(v) -> bool:
    return v is not None and 0.0 <= v <= 1.0


@pytest.fixture(scope="module")
def team_recording():
    robots = bf.team(4)
    return bf.robot_recording(robots, bf.team_times(robots, 4))


@pytest.fixture(scope="module")
def bag(team_recording, tmp_path_factory):
    return team_recording.write(tmp_path_factory.mktemp("bag") / "team", "mcap")


RUN_ARGS = [
    "--rule",
    "chernoff",
    "--topology",
    "ring",
    "--schedule",
    "periodic:1",
    "--resolution",
    RES,
    "--samples",
    "4",
]


@pytest.fixture(scope="module")
def run_out(bag, tmp_path_factory):
    """``octofuse run`` once; the SimResult it wrote is kept to check the files against."""
    out = tmp_path_factory.mktemp("run") / "out"
    code, res = run_keeping_result("run", bag, *RUN_ARGS, "--out", out)
    assert code == 0
    return out, res


# -- run ----------------------------------------------------------------------------------------


def test_run_writes_every_output(run_out, team_recording):
    out, res = run_out
    for name in ("report.md", "summary.json", "centralized.ot"):
        assert (out / name).is_file(), name
    assert is_png(out / "kl_over_time.png") and is_png(out / "info_loss_histogram.png")
    assert sorted(p.name for p in (out / "chernoff").iterdir()) == sorted(
        f"{a}{suffix}" for a in AGENTS for suffix in (".ot", "_info_loss.ply")
    )
    assert sorted(p.name for p in out.iterdir() if p.is_dir()) == ["chernoff"]
    # the maps written are the run's maps; the centralized one is every scan of the bag
    want = bf.reference_maps(team_recording.shots, bf.team_agents(bf.team(4)), resolution=0.2)
    assert_same_map(OccupancyMap.load(out / "centralized.ot"), want["centralized"], "centralized")
    for a in AGENTS:
        assert_same_map(
            OccupancyMap.load(out / "chernoff" / f"{a}.ot"), res.fused["chernoff"][a], a
        )
        assert_same_map(res.local[a], want[a], f"local {a}")


def test_run_summary_numbers(run_out):
    out, res = run_out
    s = json.loads((out / "summary.json").read_text())
    assert s["agents"] == AGENTS and s["rules"] == ["chernoff"]
    assert s["graph"] == {"spec": "ring", "edges": [[0, 1], [0, 3], [1, 2], [2, 3]]}
    # periodic:1 over the 2.01 s of the bag: rounds at 1 s and 2 s, 4 links, both directions
    assert s["events"] == 16 and s["messages"] == {"chernoff": 16}
    assert s["config"]["fuse"]["rules"] == ["chernoff"]
    assert s["config"]["fuse"]["schedule"] == "periodic:1"
    assert s["config"]["build"]["map"]["resolution"] == 0.2
    assert set(s["mean"]) == {LOCAL, "chernoff"}
    for rule, row in s["mean"].items():
        assert row["kl_mean"] > 0
        for key in ("overconfidence", "agreement", "coverage"):
            assert fraction(row[key]), (rule, key)
    local, fused = s["mean"][LOCAL], s["mean"]["chernoff"]
    assert fused["kl_mean"] < local["kl_mean"] and fused["coverage"] > local["coverage"]
    assert local["loss_mean"] is None and local["bytes_sent"] is None
    assert 0 < fused["loss_mean"] <= fused["loss_p95"] < 5
    assert fused["bytes_sent"] > 0 and fused["bytes_sent_32b"] > 0
    for a in AGENTS:
        sa = s["scores"]["chernoff"][a]
        tr = res.traffic["chernoff"]
        assert (sa["bytes_sent"], sa["bytes_received"], sa["bytes_sent_32b"]) == (
            tr.sent[a],
            tr.received[a],
            tr.sent_32b[a],
        )
        assert sa["bytes_sent"] % 5 == 0 and sa["bytes_sent_32b"] % 32 == 0
        assert sa["kl_mean"] == res.scores["chernoff"][a].kl_mean
        assert sa["voxels"] == s["scores"][LOCAL][a]["voxels"] > 1000
    assert len(s["timeline"]) == 4 * 2 * 4  # samples x (rule + local-only) x agents
    assert all(fraction(x["coverage"]) and x["kl"] >= 0 for x in s["timeline"])
    assert s["timings_s"]["total"] > 0 and s["timings_s"]["export (wall)"] > 0
    assert any(
        f.startswith("Every WEP rule closer") and "1 of 1 rules." in f for f in s["findings"]
    )


def test_run_report(run_out):
    out, _ = run_out
    md = (out / "report.md").read_text()
    assert md.startswith("# octofuse run\n")
    assert "- topology: `ring` (4 links), schedule `periodic:1`" in md
    assert "| `chernoff` |" in md and f"| `{LOCAL}` |" in md
    assert "![timeline](kl_over_time.png)" in md and "![loss_hist](info_loss_histogram.png)" in md
    assert "### chernoff" in md and "| `a` |" in md


def test_run_prints_the_table(bag, tmp_path, capsys):
    code, out, err = run_cli(
        capsys,
        "run",
        bag,
        "--rules",
        "naive-bayes,min-info-loss",
        "--topology",
        "complete",
        "--schedule",
        "aperiodic:0.5",
        "--resolution",
        RES,
        "--samples",
        "0",
        "--export-agents",
        "b",
        "--out",
        tmp_path / "o",
    )
    assert code == 0, err
    assert "Traceback" not in err
    for rule in (LOCAL, "naive-bayes", "min-info-loss"):
        assert rule in out
    assert f"report: {tmp_path / 'o' / 'report.md'}" in out
    for rule in ("naive-bayes", "min-info-loss"):
        assert sorted(p.name for p in (tmp_path / "o" / rule).iterdir()) == [
            "b.ot",
            "b_info_loss.ply",
        ]
    assert not (tmp_path / "o" / "kl_over_time.png").exists()  # no samples, no timeline
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert s["events"] > 0 and s["timeline"] == []
    assert s["mean"]["naive-bayes"]["overconfidence"] > s["mean"]["min-info-loss"]["overconfidence"]


@pytest.mark.parametrize("command", ["run", "fleet"])
def test_layers_max_bytes_is_a_size_given_once_on_the_command_line(bag, tmp_path, capsys, command):
    args = [command, bag, "--rule", "source-layers", "--dump-config"]
    code, text, err = run_cli(capsys, *args, "--layers-max-bytes", "512MB")
    assert code == 0, err
    assert yaml.safe_load(text)["fuse"]["layers_max_bytes"] == 512_000_000
    code, _, err = run_cli(capsys, *args, "--layers-max-bytes", "lots")
    assert code != 0 and "--layers-max-bytes" in err and "'lots' is not a byte size" in err


def test_run_dump_config_then_run_it(bag, tmp_path, capsys):
    out = tmp_path / "o"
    code, text, err = run_cli(
        capsys,
        "run",
        bag,
        "--rule",
        "chernoff,naive-bayes",
        "--topology",
        "star",
        "--schedule",
        "periodic:0.7",
        "--delta",
        "--resolution",
        RES,
        "--out",
        out,
        "--dump-config",
    )
    assert code == 0, err
    cfg = yaml.safe_load(text)
    assert cfg["fuse"]["rules"] == ["chernoff", "naive-bayes"]
    assert cfg["fuse"]["topology"] == "star" and cfg["fuse"]["schedule"] == "periodic:0.7"
    assert cfg["fuse"]["delta"] is True
    assert cfg["build"]["bags"] == [str(bag)] and cfg["build"]["map"]["resolution"] == 0.2
    assert cfg["out"] == str(out)
    assert not out.exists()
    conf = tmp_path / "run.yaml"
    conf.write_text(text)
    code, _, err = run_cli(
        capsys, "run", "--config", conf, "--samples", "0", "--export-agents", "none"
    )
    assert code == 0, err
    s = json.loads((out / "summary.json").read_text())
    assert s["rules"] == ["chernoff", "naive-bayes"] and s["config"]["fuse"]["delta"] is True
    assert s["graph"]["edges"] == [[0, 1], [0, 2], [0, 3]]
    assert s["events"] == 2 * 3 * 2  # rounds at 0.7 and 1.4 s
    assert "delta messages" in (out / "report.md").read_text()


# -- build, then fuse finished maps --------------------------------------------------------------


@pytest.fixture(scope="module")
def built(bag, tmp_path_factory):
    from octofuse.cli import main

    out = tmp_path_factory.mktemp("maps") / "maps"
    assert main(["build", str(bag), "--resolution", RES, "--out", str(out)]) == 0
    return out


def test_build_then_fuse(built, tmp_path, capsys):
    out = tmp_path / "fused"
    code, text, err = run_cli(
        capsys,
        "fuse",
        built,
        "--topology",
        "complete",
        "--rule",
        "min-info-loss",
        "--rounds",
        "2",
        "--out",
        out,
    )
    assert code == 0, err
    assert "fused 4 maps with min-info-loss over complete (24 messages)" in text
    maps = {a: OccupancyMap.load(built / f"{a}.ot") for a in AGENTS}
    central = OccupancyMap.load(built / "centralized.ot")
    want = fuse_finished(
        maps, central, FuseConfig(topology="complete", rules=["min-info-loss"], schedule="rounds:2")
    )
    for a in AGENTS:
        assert_same_map(
            OccupancyMap.load(out / "min-info-loss" / f"{a}.ot"), want.fused["min-info-loss"][a], a
        )
        assert (out / "min-info-loss" / f"{a}_info_loss.ply").is_file()
    assert_same_map(OccupancyMap.load(out / "centralized.ot"), central, "centralized")
    s = json.loads((out / "summary.json").read_text())
    assert s["events"] == 24 and s["messages"] == {"min-info-loss": 24}
    assert s["config"]["fuse"]["schedule"] == "rounds:2"
    fused, local = s["mean"]["min-info-loss"], s["mean"][LOCAL]
    assert fused["kl_mean"] < local["kl_mean"] and fused["coverage"] == pytest.approx(1.0)
    assert fraction(fused["overconfidence"])
    assert is_png(out / "info_loss_histogram.png")
    assert not (out / "kl_over_time.png").exists()
    assert "# octofuse fuse: 2 rounds over complete" in (out / "report.md").read_text()
    # the parts measured on the calling thread are named as wall time
    assert all(s["timings_s"][p] > 0 for p in ("scoring (wall)", "export (wall)", "total"))


def test_fuse_with_nothing_to_plot_forks_no_drawing_process(built, tmp_path, capsys, monkeypatch):
    """Naive Bayes loses nothing (no loss histogram) and `fuse` samples no timeline: no plot,
    so no process is forked to draw one."""
    import os

    def fork():
        raise AssertionError("a drawing process forked with nothing to draw")

    monkeypatch.setattr(os, "fork", fork)
    out = tmp_path / "fused"
    code, _, err = run_cli(
        capsys, "fuse", built, "--rule", "naive-bayes", "--rounds", "1", "--out", out
    )
    assert code == 0, err
    assert not (out / "kl_over_time.png").exists()
    assert not (out / "info_loss_histogram.png").exists()
    report = (out / "report.md").read_text()
    assert "![timeline]" not in report and "![loss_hist]" not in report


@pytest.mark.parametrize(
    "error, code, says",
    [
        (TypeError, 70, "internal error (TypeError: drawn wrong)"),
        (PermissionError, 1, "error: drawn wrong"),
    ],
)
def test_a_drawing_error_keeps_its_kind_across_the_drawing_process(
    built, tmp_path, capsys, monkeypatch, error, code, says
):
    """The loss histogram drawn in a process of its own fails: a bug is an internal error, a
    file's error bad input, as if drawn in the command's own process."""
    from octofuse.outputs import report

    def plot(hist, path):
        raise error("drawn wrong")

    monkeypatch.setattr(report, "plot_loss_histograms", plot)
    got, _, err = run_cli(
        capsys,
        "fuse",
        built,
        "--rule",
        "min-info-loss",
        "--rounds",
        "1",
        "--out",
        tmp_path / "fused",
    )
    assert got == code and says in err and "Traceback" not in err


@pytest.mark.parametrize("fmt", ["mcap", "bag"])
def test_fuse_writes_every_round_to_a_bag(built, tmp_path, capsys, fmt):
    """--export-bag: one message per rule, receiver and round it fused in, stamped with the
    round (s); each agent's last one is its written map."""
    from octofuse.outputs.rosbag_export import read_map_bag

    out, replay = tmp_path / "fused", tmp_path / f"rounds.{fmt}"
    rules = ["min-info-loss", "channel-filter"]
    code, text, err = run_cli(
        capsys,
        "fuse",
        built,
        "--topology",
        "line",
        "--rounds",
        "3",
        "--rules",
        ",".join(rules),
        "--export-bag",
        replay,
        "--out",
        out,
    )
    assert code == 0, err
    s = json.loads((out / "summary.json").read_text())
    want = {(e["rule"], e["receiver"], round(e["t"] * 1e9)) for e in s["fusion_events"]}
    got = read_map_bag(replay)
    assert len(got) == len(want) == s["event_bag"]["messages"] > 0
    assert f"bag: {replay} ({len(got)} map messages)" in text
    assert sorted((t, st) for t, st, _ in got) == sorted(
        (f"/octofuse/{r}/{a}/octomap", st) for r, a, st in want
    )
    assert {st for _, st, _ in got} == {0, S, 2 * S}
    for r in rules:
        for a in AGENTS:
            last = [m for t, _, m in got if t == f"/octofuse/{r}/{a}/octomap"][-1]
            assert_same_map(last, OccupancyMap.load(out / r / f"{a}.ot"), (r, a))
    # the same maps as without the bag (there, the rules run in groups)
    plain = tmp_path / "plain"
    assert (
        run_cli(
            capsys,
            "fuse",
            built,
            "--topology",
            "line",
            "--rounds",
            "3",
            "--rules",
            ",".join(rules),
            "--out",
            plain,
        )[0]
        == 0
    )
    for r in rules:
        for a in AGENTS:
            assert_same_map(
                OccupancyMap.load(plain / r / f"{a}.ot"),
                OccupancyMap.load(out / r / f"{a}.ot"),
                (r, a),
            )


def test_fuse_without_a_centralized_map_scores_nothing(built, tmp_path, capsys):
    maps = tmp_path / "maps"
    maps.mkdir()
    for a in ("a", "b"):
        shutil.copy(built / f"{a}.ot", maps)
    out = tmp_path / "fused"
    code, _, err = run_cli(
        capsys, "fuse", maps, "--topology", "line", "--rounds", "1", "--out", out
    )
    assert code == 0, err
    assert not (out / "centralized.ot").exists()  # not an agent's map under that name
    assert sorted(p.name for p in (out / "min-info-loss").glob("*.ot")) == ["a.ot", "b.ot"]
    s = json.loads((out / "summary.json").read_text())
    assert s["scores"] == {} and s["mean"] == {} and s["events"] == 2
    assert "(no centralized map: nothing scored)" in (out / "report.md").read_text()


# -- bench ----------------------------------------------------------------------------------------


def test_bench_rules_by_topologies(bag, run_out, tmp_path, capsys):
    graph = tmp_path / "square.txt"
    graph.write_text("# the ring, by agent name\na b\nb c\nc d\nd a\n")
    out = tmp_path / "bench"
    code, text, err = run_cli(
        capsys,
        "bench",
        bag,
        "--rules",
        "naive-bayes,chernoff",
        "--topologies",
        f"ring,complete,{graph}",
        "--schedule",
        "periodic:1",
        "--resolution",
        RES,
        "--executor",
        "serial",
        "--out",
        out,
    )
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == [
        ".octofuse-output",
        "bench.csv",
        "bench.md",
        "bench_kl_mean.png",
        "bench_loss_mean.png",
        "bench_overconfidence.png",
        "cells",
    ]
    assert all(is_png(p) for p in out.glob("*.png"))
    with (out / "bench.csv").open() as f:
        rows = list(csv.DictReader(f))
    topologies = ["ring", "complete", str(graph)]
    assert [(r["topology"], r["rule"]) for r in rows] == [
        (t, r) for t in topologies for r in (LOCAL, "naive-bayes", "chernoff")
    ]
    messages = {"ring": 16, "complete": 24, str(graph): 16}
    for r in rows:
        assert int(r["messages"]) == (0 if r["rule"] == LOCAL else messages[r["topology"]])
        assert float(r["kl_mean"]) > 0 and fraction(float(r["coverage"]))
        assert (r["loss_mean"] == "") == (r["rule"] == LOCAL)
    by = {(r["topology"], r["rule"]): r for r in rows}
    for t in topologies:
        assert float(by[(t, "chernoff")]["kl_mean"]) < float(by[(t, LOCAL)]["kl_mean"])
        assert float(by[(t, "naive-bayes")]["overconfidence"]) > float(
            by[(t, "chernoff")]["overconfidence"]
        )
    # the named file is the ring; each rule's maps do not depend on the others run beside it
    for rule in ("naive-bayes", "chernoff", LOCAL):
        assert by[(str(graph), rule)]["kl_mean"] == by[("ring", rule)]["kl_mean"]
    run_summary = json.loads((run_out[0] / "summary.json").read_text())
    assert float(by[("ring", "chernoff")]["kl_mean"]) == run_summary["mean"]["chernoff"]["kl_mean"]
    md = (out / "bench.md").read_text()
    assert md.startswith("# octofuse bench")
    assert "| `complete` | `naive-bayes` |" in md
    assert md.count("| `ring` | `") == 3 and "| `ring` | " in md.split("| topology | seconds |")[1]
    for t in ("ring", "complete"):
        assert f"{t}: done in" in text


# -- demo -----------------------------------------------------------------------------------------


def test_demo_help(capsys):
    code, out, err = run_cli(capsys, "demo", "--help")
    assert code == 0, err
    for opt in ("--out", "--rules", "--every"):
        assert opt in out
    assert "max-robust:3" in out


def test_demo_on_every_400th_scan(tmp_path, capsys):
    if not (REPO / "data" / "lab8.bag").is_file():
        pytest.skip("the bundled dataset data/lab8.bag is not present")
    out = tmp_path / "demo"
    replay = tmp_path / "demo.mcap"
    code, text, err = run_cli(
        capsys,
        "demo",
        "--every",
        "400",
        "--rules",
        "naive-bayes,min-info-loss",
        "--export-bag",
        replay,
        "--out",
        out,
    )
    assert code == 0, err
    assert "octofuse demo: lab8.bag" in text
    from octofuse.outputs.rosbag_export import read_map_bag

    topics = {topic for topic, _, _ in read_map_bag(replay)}  # only the exported robot1
    assert topics == {f"/octofuse/{r}/robot1/octomap" for r in ("naive-bayes", "min-info-loss")}
    s = json.loads((out / "summary.json").read_text())
    assert s["agents"] == [f"robot{i}" for i in range(1, 9)]
    assert s["config"]["fuse"]["topology"] == "max-robust:3" and len(s["graph"]["edges"]) == 12
    assert s["rules"] == ["naive-bayes", "min-info-loss"]
    for rule in s["rules"]:  # only the first agent's maps are exported
        assert sorted(p.name for p in (out / rule).iterdir()) == [
            "robot1.ot",
            "robot1_info_loss.ply",
        ]
    nb, mil = s["mean"]["naive-bayes"], s["mean"]["min-info-loss"]
    assert nb["overconfidence"] > 0.5 > 0.05 > mil["overconfidence"]
    assert fraction(mil["occupied_accuracy"]) and mil["occupied_accuracy"] > 0.9  # ground truth
    assert s["findings"][0].startswith("Rumour propagation") and s["findings"][0].endswith("holds.")


def test_demo_in_passes_writes_what_one_pass_writes(tmp_path, capsys):
    """The demo's rules two at a time (the bag replayed per pair) write the files of one pass
    with every rule: the same maps and heat maps byte for byte, the same summary but for the
    timings, the setting itself and the folder."""
    if not (REPO / "data" / "lab8.bag").is_file():
        pytest.skip("the bundled dataset data/lab8.bag is not present")
    rules = "naive-bayes,chernoff,min-info-loss,channel-filter"
    outs = {}
    for per_pass in ("0", "2"):
        outs[per_pass] = tmp_path / f"demo{per_pass}"
        code, _, err = run_cli(
            capsys,
            "demo",
            "--every",
            "400",
            "--rules",
            rules,
            "--rules-per-pass",
            per_pass,
            "--out",
            outs[per_pass],
        )
        assert code == 0, err
    files = sorted(p.relative_to(outs["0"]) for p in outs["0"].rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(outs["2"]) for p in outs["2"].rglob("*") if p.is_file())
    assert Path("channel-filter/robot1.ot") in files
    for f in files:
        if f.suffix not in (".json", ".md", ".png"):
            assert (outs["0"] / f).read_bytes() == (outs["2"] / f).read_bytes(), f
    one, two = (json.loads((outs[k] / "summary.json").read_text()) for k in ("0", "2"))
    assert (one["config"]["fuse"]["rules_per_pass"], two["config"]["fuse"]["rules_per_pass"]) == (
        0,
        2,
    )
    # each rule's own time after the other parts, in the order of the rules, in both runs
    for s in (one, two):
        parts = list(s["timings_s"])
        assert parts[-4:] == [rule_time_part(r) for r in rules.split(",")], parts
        assert all(s["timings_s"][p] > 0 for p in parts[-4:])
    for s in (one, two):
        del s["timings_s"], s["config"]["fuse"]["rules_per_pass"], s["config"]["out"]
    assert one == two


# -- bad input ------------------------------------------------------------------------------------


def assert_one_error(code: int, err: str, *needles: str) -> None:
    assert code == 1, err
    assert "Traceback" not in err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("error: "), err
    for n in needles:
        assert n in lines[0], (n, lines[0])


@pytest.fixture(scope="module")
def split_graph(tmp_path_factory):
    p = tmp_path_factory.mktemp("graphs") / "split.txt"
    p.write_text("a b\nc d\n")
    return p


@pytest.mark.parametrize(
    "args, needles",
    [
        (["--topology", "hexagon"], ["unknown topology 'hexagon'", "ring", "max-robust:K"]),
        (["--topology", "SPLIT"], ["is disconnected", "nodes {c, d} are cut off from node a"]),
        (
            ["--topology", "max-robust:4"],
            ["max-robust:K needs K < n, got K=4 with n=4", "max-robust:3"],
        ),
        (["--topology", "max-robust:7"], ["K=7 with n=4"]),
        (["--schedule", "rounds:2"], ["rounds:N", "octofuse fuse", "periodic:PERIOD_S"]),
        (["--schedule", "weekly"], ["unknown schedule 'weekly'"]),
        (["--schedule", "periodic:-1"], ["positive"]),
        (["--topology", "missing.yaml"], ["graph file not found: missing.yaml"]),
    ],
)
def test_run_bad_input_is_one_error_line(bag, split_graph, tmp_path, capsys, args, needles):
    args = [str(split_graph) if a == "SPLIT" else a for a in args]
    base = ["--rule", "chernoff", "--topology", "ring", "--schedule", "periodic:1"]
    out = tmp_path / "o"
    code, _, err = run_cli(capsys, "run", bag, *base, "--resolution", RES, *args, "--out", out)
    assert_one_error(code, err, *needles)
    assert not out.exists()


def test_run_without_a_placeable_scan_is_an_error(tmp_path, capsys):
    robots = bf.team(2)
    late_tf = {r.name: [T0 + 5 * S, T0 + 6 * S] for r in robots}
    rec = bf.robot_recording(robots, bf.team_times(robots, 2), tf_times=late_tf)
    bag = rec.write(tmp_path / "early", "mcap")
    out = tmp_path / "o"
    code, _, err = run_cli(
        capsys,
        "run",
        bag,
        "--rules",
        "naive-bayes,chernoff",
        "--topology",
        "ring",
        "--schedule",
        "periodic:1",
        "--resolution",
        RES,
        "--out",
        out,
    )
    assert_one_error(
        code,
        err,
        "no scan of",
        "could be placed in the fixed frame 'map'",
        "a: 2 before the first transform",
    )
    assert not out.exists()


@pytest.mark.parametrize(
    "args, needles",
    [
        (["--topology", "max-robust:4"], ["K=4 with n=4"]),
        (["--topology", "SPLIT"], ["is disconnected"]),
        # flags are checked by click (usage errors, below); the same values from a config file
        # are bad input, and a config's schedule is not overridden by the default of --rounds
        (
            ["--config", "fuse:\n  schedule: rounds:0\n"],
            ["rounds:R needs a whole number of rounds >= 1"],
        ),
        (["--config", "fuse:\n  schedule: periodic:1\n"], ["finished maps are fused in rounds"]),
        (
            ["--config", "fuse:\n  directions: sideways\n"],
            ["fuse.directions = 'sideways'", "expected both or one"],
        ),
    ],
)
def test_fuse_bad_input_is_one_error_line(built, split_graph, tmp_path, capsys, args, needles):
    args = [str(split_graph) if a == "SPLIT" else a for a in args]
    if args[0] == "--config":
        (tmp_path / "fuse.yaml").write_text(args[1])
        args = ["--config", tmp_path / "fuse.yaml"]
    code, _, err = run_cli(
        capsys, "fuse", built, "--topology", "ring", *args, "--out", tmp_path / "o"
    )
    assert_one_error(code, err, *needles)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    "command, args, needles",
    [
        ("fuse", ["--rounds", "0"], ["--rounds", "0 is not in the range 1<=x<=10000"]),
        (
            "fuse",
            ["--directions", "sideways"],
            ["--directions", "'sideways' is not one of 'both', 'one'"],
        ),
        ("bench", ["--topologies", " , "], ["--topologies", "' , ' has an empty item"]),
        (
            "run",
            ["--rule", "bayes"],
            [
                "--rule",
                "unknown 'bayes'; expected one or more of "
                "naive-bayes, bhattacharyya, min-entropy, chernoff",
            ],
        ),
        ("run", ["--rule", "chernoff,bayes"], ["unknown 'bayes'"]),
        ("fuse", ["--rule", "bayes"], ["unknown 'bayes'"]),
        ("bench", ["--rules", "chernoff,bayes"], ["unknown 'bayes'"]),
    ],
)
def test_bad_flag_values_are_usage_errors(bag, built, tmp_path, capsys, command, args, needles):
    out = tmp_path / "o"
    code, text, err = run_cli(
        capsys, command, built if command == "fuse" else bag, *args, "--out", out
    )
    assert code == 2, err
    assert "Traceback" not in err and err.startswith(f"Usage: octofuse {command} ")
    for n in needles:
        assert n in err, (n, err)
    assert "done in" not in text and not out.exists()


def test_fuse_needs_a_folder_of_maps(built, tmp_path, capsys):
    code, _, err = run_cli(capsys, "fuse", tmp_path / "nowhere", "--out", tmp_path / "o")
    assert_one_error(code, err, "does not exist")
    one = tmp_path / "one"
    one.mkdir()
    shutil.copy(built / "a.ot", one)
    shutil.copy(built / "centralized.ot", one)
    code, _, err = run_cli(capsys, "fuse", one, "--out", tmp_path / "o")
    assert_one_error(code, err, "holds 1 agent map(s)", "at least 2")


def test_bench_with_an_agent_in_its_own_frame_scores_as_run_does(bag, tmp_path, capsys):
    args = [
        "--rules",
        "chernoff",
        "--schedule",
        "periodic:1",
        "--resolution",
        RES,
        "--agent-frame",
        "b=0.2,0,0,0,0,0.1",
    ]
    code, _, err = run_cli(
        capsys,
        "bench",
        bag,
        *args,
        "--topologies",
        "ring",
        "--executor",
        "serial",
        "--out",
        tmp_path / "bench",
    )
    assert code == 0, err
    with (tmp_path / "bench" / "bench.csv").open() as f:
        rows = {r["rule"]: r for r in csv.DictReader(f)}
    code, _, err = run_cli(
        capsys, "run", bag, *args, "--topology", "ring", "--samples", "0", "--out", tmp_path / "run"
    )
    assert code == 0, err
    run = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert run["agent_frames"]["b"]["x"] == pytest.approx(0.2)
    for rule in ("chernoff", LOCAL):
        for key in ("kl_mean", "overconfidence", "coverage"):
            assert float(rows[rule][key]) == pytest.approx(run["mean"][rule][key], rel=1e-12), (
                rule,
                key,
            )


@pytest.mark.parametrize(
    "args, needles",
    [
        (["--topologies", "ring,hexagon"], ["unknown topology 'hexagon'"]),
        (["--topologies", "ring,SPLIT"], ["is disconnected"]),
        (["--rules", "chernoff", "--agent-frame", "zz=1,0,0,0,0,0"], ["unknown agent 'zz'"]),
    ],
)
def test_bench_bad_input_fails_before_any_run(bag, split_graph, tmp_path, capsys, args, needles):
    args = [a.replace("SPLIT", str(split_graph)) for a in args]
    out = tmp_path / "o"
    code, text, err = run_cli(
        capsys, "bench", bag, "--resolution", RES, "--schedule", "periodic:1", *args, "--out", out
    )
    assert_one_error(code, err, *needles)
    assert "done in" not in text and not out.exists()


def test_score_numbers_are_finite(run_out):
    _, res = run_out
    for per in res.scores.values():
        for s in per.values():
            for key in ("kl_mean", "agreement", "coverage", "overconfidence"):
                assert math.isfinite(getattr(s, key))


def test_a_run_bag_of_every_nth_map_as_clouds_says_its_size_first(bag, tmp_path, capsys):
    from rosbags.highlevel import AnyReader

    from octofuse.outputs.rosbag_export import POINTCLOUD2

    replay = tmp_path / "replay.mcap"
    code, text, err = run_cli(
        capsys,
        "run",
        bag,
        *RUN_ARGS,
        "--schedule",
        "periodic:0.33",
        "--export-bag",
        replay,
        "--bag-every",
        "2",
        "--bag-clouds-only",
        "--out",
        tmp_path / "out",
    )
    assert code == 0, err
    said = re.search(
        r"--export-bag: (\d+) of about (\d+) map messages written, about [\d.,]+ "
        r"MB expected",
        text,
    )
    assert said, text
    with AnyReader([replay]) as reader:
        assert {c.msgtype for c in reader.connections} == {POINTCLOUD2}
        written = sum(c.msgcount for c in reader.connections)
    assert written == int(said.group(2))  # the projection counted the messages right
    assert f"bag: {replay} ({written} map messages)" in text
