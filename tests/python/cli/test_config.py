"""One configuration for the CLI and the API: ``--dump-config`` round trips, the API runs a
dumped config to the same scores as the CLI, and a bad value in a config file is one line
naming the file and the key."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bagfactory as bf  # noqa: E402
from bagfactory import run_cli  # noqa: E402
from octofuse.config import BuildConfig, FuseConfig, RunConfig, dump_yaml, load_yaml  # noqa: E402
from octofuse.fusion.results import LOCAL  # noqa: E402
from octofuse.fusion.simulate import simulate  # noqa: E402

RES = "0.2"


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    """Two robots, four scans each (a few seconds of work at most)."""
    return bf.team_bag(tmp_path_factory.mktemp("bag"), 2, 4, name="pair")


@pytest.fixture(scope="module")
def maps_dir(bag, tmp_path_factory):
    from octofuse.cli import main

    out = tmp_path_factory.mktemp("maps") / "maps"
    assert main(["build", str(bag), "--resolution", RES, "--out", str(out)]) == 0
    return out


def dump(capsys, *args) -> str:
    code, text, err = run_cli(capsys, *args, "--dump-config")
    assert code == 0, err
    assert err == ""
    return text


# -- --dump-config, then --config ---------------------------------------------------------------


def command_args(command: str, bag: Path, maps_dir: Path, out: Path) -> list:
    """Non-default flags for every command with a configuration."""
    build = [
        "--resolution",
        RES,
        "--every",
        "2",
        "--max-range",
        "3.5",
        "--threads",
        "2",
        "--agent",
        "a=/a/points",
        "--agent",
        "b=/b/points",
    ]
    exchange = ["--schedule", "periodic:0.7", "--delta", "--unknown", "prior", "--seed", "7"]
    return {
        "build": ["build", bag, *build, "--no-return", "free", "--out", out],
        "run": [
            "run",
            bag,
            *build,
            *exchange,
            "--rules",
            "chernoff,naive-bayes",
            "--topology",
            "line",
            "--samples",
            "3",
            "--export-agents",
            "first",
            "--agent-frame",
            "b=0.2,-0.1,0,0,0,0.5",
            "--align",
            "planar",
            "--out",
            out,
        ],
        "bench": [
            "bench",
            bag,
            *build,
            *exchange,
            "--rules",
            "chernoff",
            "--executor",
            "serial",
            "--out",
            out,
        ],
        "fuse": [
            "fuse",
            maps_dir,
            "--rules",
            "chernoff",
            "--topology",
            "complete",
            "--rounds",
            "2",
            "--directions",
            "one",
            "--threads",
            "1",
            "--agent-frame",
            "a=1,2,0.5,0,0.1,-3",
            "--out",
            out,
        ],
    }[command]


@pytest.mark.parametrize("command", ["build", "run", "bench", "fuse"])
def test_a_dumped_config_fed_back_dumps_the_same(bag, maps_dir, tmp_path, capsys, command):
    out = tmp_path / "o"
    args = command_args(command, bag, maps_dir, out)
    text = dump(capsys, *args)
    cfg = yaml.safe_load(text)
    assert cfg["out"] == str(out)
    # every flag given is in the dump, so the round trip below carries something
    if command == "fuse":
        assert cfg["fuse"]["schedule"] == "rounds:2" and cfg["fuse"]["rules"] == ["chernoff"]
        assert cfg["fuse"]["directions"] == "one" and cfg["build"]["threads"] == 1
        assert cfg["fuse"]["agent_frames"] == [{"name": "a", "pose": [1, 2, 0.5, 0, 0.1, -3]}]
    else:
        assert cfg["build"]["bags"] == [str(bag)] and cfg["build"]["scan_stride"] == 2
        assert cfg["build"]["map"]["resolution"] == 0.2
        assert cfg["build"]["max_range"] == 3.5 and cfg["build"]["threads"] == 2
        assert [a["topic"] for a in cfg["build"]["agents"]] == ["/a/points", "/b/points"]
    if command in ("run", "bench"):
        assert cfg["fuse"]["schedule"] == "periodic:0.7" and cfg["fuse"]["delta"] is True
        assert cfg["fuse"]["unknown"] == "prior" and cfg["fuse"]["seed"] == 7
    if command == "run":
        assert cfg["fuse"]["rules"] == ["chernoff", "naive-bayes"]
        assert cfg["samples"] == 3 and cfg["export_agents"] == "first"
        assert cfg["fuse"]["agent_frames"] == [{"name": "b", "pose": [0.2, -0.1, 0, 0, 0, 0.5]}]
        assert cfg["fuse"]["align"] == "planar"
    if command == "bench":  # the config's rules, not bench's default of every rule
        assert cfg["fuse"]["rules"] == ["chernoff"]
    conf = tmp_path / f"{command}.yaml"
    conf.write_text(text)
    head = [command, maps_dir] if command == "fuse" else [command]
    assert dump(capsys, *head, "--config", conf) == text
    # the file is a valid configuration for the API as it stands
    assert dump_yaml(load_yaml(conf)) == text
    assert not out.exists()


def test_flags_given_win_over_the_config_file(bag, tmp_path, capsys):
    conf = tmp_path / "run.yaml"
    conf.write_text(dump(capsys, *command_args("run", bag, bag, tmp_path / "o")))
    cfg = yaml.safe_load(
        dump(
            capsys,
            "run",
            "--config",
            conf,
            "--rules",
            "min-entropy",
            "--every",
            "3",
            "--out",
            tmp_path / "p",
        )
    )
    assert cfg["fuse"]["rules"] == ["min-entropy"] and cfg["build"]["scan_stride"] == 3
    assert cfg["out"] == str(tmp_path / "p")
    assert cfg["fuse"]["schedule"] == "periodic:0.7"  # from the file


def test_the_api_runs_a_dumped_config_to_the_cli_scores(bag, tmp_path, capsys):
    out = tmp_path / "o"
    text = dump(
        capsys,
        "run",
        bag,
        "--rules",
        "chernoff,naive-bayes",
        "--topology",
        "line",
        "--schedule",
        "periodic:1",
        "--resolution",
        RES,
        "--every",
        "2",
        "--samples",
        "2",
        "--export-agents",
        "none",
        "--out",
        out,
    )
    conf = tmp_path / "run.yaml"
    conf.write_text(text)
    code, _, err = run_cli(capsys, "run", "--config", conf)
    assert code == 0, err
    summary = json.loads((out / "summary.json").read_text())

    cfg = load_yaml(conf)
    assert isinstance(cfg, RunConfig)
    assert isinstance(cfg.build, BuildConfig) and isinstance(cfg.fuse, FuseConfig)
    assert cfg.fuse.rules == ("chernoff", "naive-bayes") and cfg.build.scan_stride == 2
    res = simulate(cfg.build, cfg.fuse, samples=cfg.samples)
    assert res.rules == summary["rules"] == ["chernoff", "naive-bayes"]
    assert res.agents == summary["agents"] == ["a", "b"]
    assert summary["events"] == len(res.events) > 0
    assert set(summary["scores"]) == set(res.scores) == {LOCAL, "chernoff", "naive-bayes"}
    for rule, per_agent in res.scores.items():
        for agent, score in per_agent.items():
            assert summary["scores"][rule][agent] == json.loads(json.dumps(score.to_dict())), (
                rule,
                agent,
            )
    # the two rules differ, so equal scores above are not a coincidence of identical maps
    assert (
        summary["scores"]["chernoff"]["a"]["kl_mean"]
        != summary["scores"]["naive-bayes"]["a"]["kl_mean"]
    )
    assert [(s["t"], s["rule"], s["agent"], s["kl"]) for s in summary["timeline"]] == [
        (s["t"], s["rule"], s["agent"], s["kl"]) for s in res.timeline
    ]


# -- a bad value in a config file ---------------------------------------------------------------


CASES = {  # name: (YAML text, what the error line holds besides the file name)
    "stride_as_text": (
        "build:\n  scan_stride: '2'\n",
        ["build.scan_stride", "expected a whole number", "'2'"],
    ),
    "range_as_word": (
        "build:\n  max_range: far\n",
        ["build.max_range", "expected a number", "far"],
    ),
    "clamping_as_number": (
        "build:\n  map:\n    clamping: 5\n",
        ["build.map.clamping", "expected a list of 2 numbers"],
    ),
    "frame_as_number": ("build:\n  fixed_frame: 5\n", ["build.fixed_frame", "expected text"]),
    "rules_as_number": ("fuse:\n  rules: 5\n", ["fuse.rules", "expected a list"]),
    "threads_as_word": ("build:\n  threads: two\n", ["build.threads", "expected a whole number"]),
    "threads_negative": ("build:\n  threads: -1\n", ["build.threads = -1", "expected 0"]),
    "resolution_as_list": (
        "build:\n  map:\n    resolution: [1, 2]\n",
        ["build.map.resolution", "expected a number", "[1, 2]"],
    ),
    "agent_without_topic": ("build:\n  agents:\n  - name: a\n", ["build.agents[0]", "topic"]),
    "invalid_yaml": ("build:\n  bags: [a.bag\n  every: 2\n", ["not valid YAML", "at line 3"]),
    "not_a_mapping": ("- build\n- run\n", ["expected a mapping", "list"]),
    "unknown_key": ("fuse:\n  rule: chernoff\n", ["fuse", "unknown key(s) rule", "rules"]),
}


@pytest.mark.parametrize("command", ["build", "run", "bench", "fuse"])
@pytest.mark.parametrize("case", list(CASES))
def test_a_bad_config_value_is_one_line_naming_file_and_key(tmp_path, capsys, command, case):
    text, needles = CASES[case]
    conf = tmp_path / "bad.yaml"
    conf.write_text(text)
    out = tmp_path / "o"
    head = [command, tmp_path] if command == "fuse" else [command]
    code, stdout, err = run_cli(capsys, *head, "--config", conf, "--out", out)
    assert code == 1, err
    assert "Traceback" not in err and "Traceback" not in stdout
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("error: ") and str(conf) in lines[0], lines[0]
    for n in needles:
        assert n in lines[0], (n, lines[0])
    assert not out.exists()


@pytest.mark.parametrize("case", [c for c in CASES if c != "not_a_mapping"])
def test_the_api_reports_the_same_file_and_key(tmp_path, case):
    text, needles = CASES[case]
    conf = tmp_path / "bad.yaml"
    conf.write_text(text)
    with pytest.raises(ValueError) as e:
        load_yaml(conf)
    assert str(conf) in str(e.value)
    for n in needles:
        assert n in str(e.value), (n, str(e.value))


def test_build_maps_validates_through_the_config(bag):
    from octofuse.maps.build import build_maps, make_build_config

    with pytest.raises(ValueError, match=r"scan_stride: expected a whole number, got str '2'"):
        make_build_config([bag], scan_stride="2")
    with pytest.raises(ValueError, match=r"threads = -1"):
        build_maps([bag], threads=-1)


def test_rules_are_parsed_once_into_typed_members():
    import octofuse
    from octofuse.config import from_dict
    from octofuse.rule_names import FusionRule

    f = FuseConfig(rules=["chernoff, naive-bayes", "chernoff"])
    assert f.rules == (FusionRule.CHERNOFF, FusionRule.NAIVE_BAYES)
    assert all(type(r) is FusionRule for r in f.rules)
    assert FuseConfig(rules="all").rules == octofuse.RULES
    # the members print, join and serialise as their names
    assert ",".join(f.rules) == "chernoff,naive-bayes" and f"{f.rules[0]}" == "chernoff"
    assert json.dumps(f.rules) == '["chernoff", "naive-bayes"]'
    assert yaml.safe_load(dump_yaml(f))["rules"] == ["chernoff", "naive-bayes"]
    # the core's rule where there is one, none for the exact modes
    assert f.rules[0].core == octofuse._core.Rule.CHERNOFF
    assert FusionRule.CHANNEL_FILTER.core is None and FusionRule.SOURCE_LAYERS.exact
    with pytest.raises(ValueError, match="at least one fusion rule"):
        FuseConfig(rules=[" , "])
    # the flags of a command and a config file's data give the same typed tuple
    from octofuse.cli import cli
    from octofuse.cli.options import run_config

    flags = ["--rule", "min-info-loss,all", "--rule", "source-layers"]
    ctx = cli.commands["run"].make_context("run", flags)
    by_flags = run_config(ctx.params).fuse.rules
    by_data = from_dict(FuseConfig, {"rules": ["min-info-loss,all", "source-layers"]}).rules
    assert by_flags == by_data and all(type(r) is FusionRule for r in by_flags)
    assert by_flags[0] == FusionRule.MIN_INFO_LOSS and by_flags[-1] == FusionRule.SOURCE_LAYERS
    assert len(by_flags) == len(octofuse.RULES) + 1


@pytest.mark.parametrize("route", ["flag", "file", "api"])
def test_a_bad_rule_is_refused_naming_it_and_the_choices(tmp_path, capsys, route):
    from octofuse.rule_names import rule_choices

    if route == "api":
        with pytest.raises(ValueError) as e:
            FuseConfig(rules=["chernoff", "chernof"])
        text = str(e.value)
    else:
        args = ["--rule", "chernoff,chernof"]
        if route == "file":
            conf = tmp_path / "bad.yaml"
            conf.write_text("fuse:\n  rules: [chernoff, chernof]\n")
            args = ["--config", str(conf)]
        code, _, text = run_cli(capsys, "run", *args, "--out", tmp_path / "o")
        assert code != 0 and "Traceback" not in text
    assert "'chernof'" in text
    for name in rule_choices():
        assert name in text, (name, text)


def test_a_maps_defaults_are_the_cores():
    from octofuse import OccupancyMap, _core
    from octofuse.config import MapConfig

    d, cfg = _core.DEFAULT_MAP, MapConfig()
    assert (cfg.resolution, cfg.prob_hit, cfg.prob_miss) == (
        d["resolution"],
        d["prob_hit"],
        d["prob_miss"],
    )
    assert cfg.clamping == (d["clamp_min"], d["clamp_max"])
    m = OccupancyMap(cfg.resolution)
    assert (m.prob_hit, m.prob_miss, m.clamping) == (cfg.prob_hit, cfg.prob_miss, cfg.clamping)


def test_the_voxel_sizes_a_config_takes_are_the_cores():
    from octofuse import OccupancyMap, _core
    from octofuse.config import MapConfig, from_dict

    for ok in (_core.MIN_RESOLUTION, 5e-4, _core.MAX_RESOLUTION):
        assert from_dict(MapConfig, {"resolution": ok}).resolution == ok
        OccupancyMap(ok)  # and the core builds the map
    for bad in (_core.MIN_RESOLUTION / 2, _core.MAX_RESOLUTION * 2):
        with pytest.raises(
            ValueError,
            match=r"map.resolution = .*: expected a voxel size from "
            r"0.0001 to 1000 metres",
        ):
            from_dict(MapConfig, {"resolution": bad}, where="map")
        with pytest.raises(ValueError):
            OccupancyMap(bad)
