"""Studies as grids of independent cells on the serial executor (no Ray needed): the seeds
axis, resuming from an earlier output folder, a failing cell reported while the others go on."""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bagfactory as bf  # noqa: E402
from octofuse.config import FuseConfig, RunConfig  # noqa: E402
from octofuse.fusion import executors  # noqa: E402
from octofuse.fusion.executors import SerialExecutor, make_executor  # noqa: E402
from octofuse.fusion.results import LOCAL  # noqa: E402
from octofuse.maps.build import make_build_config  # noqa: E402
from octofuse.outputs.study import CELLS_DIR, load_cells, run_study, study_cells  # noqa: E402

RULES = ["naive-bayes", "chernoff"]
SCHEDULE = "aperiodic:1"


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    return bf.team_bag(tmp_path_factory.mktemp("team"), 4, 4)


def config(bag) -> RunConfig:
    return RunConfig(
        build=make_build_config(bag, resolution=0.2, threads=1),
        fuse=FuseConfig(rules=list(RULES), topology="ring", schedule=SCHEDULE),
    )


def read_csv(path: Path) -> list[dict]:
    with path.open() as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def seeded(bag, tmp_path_factory):
    """Two topologies x two seeds, serially."""
    out = tmp_path_factory.mktemp("study") / "seeded"
    lines: list[str] = []
    run_study(
        config(bag), ["ring", "random:0.8"], out, seeds=[0, 1], executor="serial", log=lines.append
    )
    return out, lines


def test_seeds_are_an_axis_with_mean_and_spread(seeded):
    out, lines = seeded
    assert sorted(p.name for p in out.iterdir() if p.is_file()) == [
        "bench.csv",
        "bench.md",
        "bench_kl_mean.png",
        "bench_loss_mean.png",
        "bench_overconfidence.png",
    ]
    assert len(list((out / CELLS_DIR).glob("*.json"))) == 4
    rows = read_csv(out / "bench.csv")
    assert [(r["topology"], r["rule"]) for r in rows] == [
        (t, r) for t in ("ring", "random:0.8") for r in (LOCAL, *RULES)
    ]
    cells = {(c["cell"]["topology"], c["cell"]["seed"]): c for c in load_cells([out]).values()}
    for r in rows:
        assert r["seeds"] == "2" and r["schedule"] == SCHEDULE
        per_seed = [
            next(x for x in cells[(r["topology"], s)]["rows"] if x["rule"] == r["rule"])
            for s in (0, 1)
        ]
        kl = [x["kl_mean"] for x in per_seed]
        assert float(r["kl_mean"]) == pytest.approx(sum(kl) / 2, rel=1e-12)
        assert float(r["kl_mean_sd"]) == pytest.approx(abs(kl[0] - kl[1]) / 2**0.5, rel=1e-9)
    # the aperiodic schedule depends on the seed: the two seeds are different runs
    ring = [cells[("ring", s)]["rows"] for s in (0, 1)]
    assert ring[0] != ring[1]
    md = (out / "bench.md").read_text()
    assert "± " in md and "| topology | seed | seconds |" in md
    assert sum("done in" in x for x in lines) == 4


def test_a_cell_equals_a_run_of_its_own(bag, seeded, tmp_path):
    """The cell (ring, seed 1) of the grid has the numbers of a study of that cell alone."""
    out = tmp_path / "one"
    cfg = config(bag)
    cfg.fuse.seed = 1
    run_study(cfg, ["ring"], out, executor=SerialExecutor())
    one = next(iter(load_cells([out]).values()))
    grid = {c["key"]: c for c in load_cells([seeded[0]]).values()}
    assert one["key"] in grid and one["rows"] == grid[one["key"]]["rows"]
    row = read_csv(out / "bench.csv")[0]
    assert "kl_mean_sd" not in row and row["seeds"] == "1"


def test_a_cell_in_passes_has_the_rows_of_one_pass(bag, seeded, tmp_path, monkeypatch):
    """With fuse.rules_per_pass a cell replays its bag per rule and keeps only the scores:
    the same rows as the cell of the grid that ran both rules at once."""
    import octofuse.fusion.simulate as sim

    passes, real = [], sim.simulate
    monkeypatch.setattr(
        sim, "simulate", lambda *a, **kw: passes.append(a[1].rules) or real(*a, **kw)
    )
    out = tmp_path / "passes"
    cfg = config(bag)
    cfg.fuse.seed, cfg.fuse.rules_per_pass = 1, 1
    run_study(cfg, ["ring"], out, executor=SerialExecutor())
    assert passes == [(r,) for r in RULES]
    one = next(iter(load_cells([out]).values()))
    want = next(
        c
        for c in load_cells([seeded[0]]).values()
        if (c["cell"]["topology"], c["cell"]["seed"]) == ("ring", 1)
    )
    assert one["rows"] == want["rows"]
    assert [r["rule"] for r in one["rows"]] == [LOCAL, *RULES]


def test_resume_carries_finished_cells_over(bag, seeded, tmp_path, monkeypatch):
    old, _ = seeded
    ran: list = []
    import octofuse.outputs.study as study

    real = study.run_cell
    monkeypatch.setattr(study, "run_cell", lambda p: ran.append(p[1]) or real(p))
    out = tmp_path / "more"
    lines: list[str] = []
    run_study(
        config(bag),
        ["ring", "random:0.8"],
        out,
        seeds=[0, 1, 2],
        executor="serial",
        resume_from=[old],
        log=lines.append,
    )
    assert [(c.topology, c.seed) for c in ran] == [("ring", 2), ("random:0.8", 2)]
    assert "resuming: 4 of 6 cell(s) already done" in lines
    assert len(list((out / CELLS_DIR).glob("*.json"))) == 6
    assert all(r["seeds"] == "3" for r in read_csv(out / "bench.csv"))
    # a changed configuration is a different cell: nothing is carried over
    ran.clear()
    cfg = config(bag)
    cfg.fuse.unknown = "prior"
    run_study(cfg, ["ring"], tmp_path / "other", executor="serial", resume_from=[old])
    assert len(ran) == 1


class Killed(BaseException):
    """Stands for the study being stopped (Ctrl-C, a killed process)."""


def test_a_journal_keeps_cells_of_an_interrupted_study(bag, tmp_path, monkeypatch):
    import octofuse.outputs.study as study

    real, calls = study.run_cell, []

    def interrupted(p):
        calls.append(p[1])
        if len(calls) == 2:
            raise Killed
        return real(p)

    monkeypatch.setattr(study, "run_cell", interrupted)
    journal = tmp_path / "journal"
    with pytest.raises(Killed):
        run_study(
            config(bag), ["ring", "line"], tmp_path / "stage1", executor="serial", journal=journal
        )
    assert len(list(journal.glob("*.json"))) == 1
    calls.clear()
    run_study(
        config(bag), ["ring", "line"], tmp_path / "stage2", executor="serial", journal=journal
    )
    assert [c.topology for c in calls] == ["line"]


def test_a_failing_cell_is_reported_and_the_others_go_on(bag, tmp_path):
    bad = tmp_path / "broken.bag"
    bad.write_bytes(b"#ROSBAG V2.0\n" + b"\0" * 64)
    out = tmp_path / "out"
    lines: list[str] = []
    cfg = config(bag)
    run_study(
        cfg, ["ring"], out, bag_sets=[[str(bag)], [str(bad)]], executor="serial", log=lines.append
    )
    rows = read_csv(out / "bench.csv")
    assert {r["bags"] for r in rows} == {str(bag)}
    failed = [x for x in lines if "FAILED" in x]
    assert len(failed) == 1 and "broken.bag" in failed[0]
    md = (out / "bench.md").read_text()
    assert "## Failed cells" in md and "broken.bag" in md
    recs = [json.loads(p.read_text()) for p in (out / CELLS_DIR).glob("*.json")]
    assert sorted(r["status"] for r in recs) == ["failed", "ok"]
    assert all(r["error"] for r in recs if r["status"] == "failed")
    # every cell failing is an error naming them
    with pytest.raises(RuntimeError, match="every cell of the study failed"):
        run_study(cfg, ["ring"], tmp_path / "none", bag_sets=[[str(bad)]], executor="serial")


def test_grid_and_bad_axes(bag):
    cfg = config(bag)
    cells = study_cells(cfg, ["ring", "line"], ["periodic:1", "aperiodic:2"], [3, 4])
    assert len(cells) == 8 and cells[0].topology == "ring" and cells[0].seed == 3
    assert [c.seed for c in study_cells(cfg, ["ring"])] == [cfg.fuse.seed]
    with pytest.raises(ValueError, match="rounds"):
        run_study(cfg, ["ring"], "/nonexistent/never", schedules=["rounds:2"], executor="serial")
    with pytest.raises(ValueError):
        run_study(cfg, ["ring"], "/nonexistent/never", schedules=["sometimes"], executor="serial")


def test_asking_for_ray_by_name_without_it_is_refused(monkeypatch):
    monkeypatch.setattr(executors, "ray_available", lambda: False)
    said: list[str] = []
    with pytest.raises(ValueError, match="Ray is not installed"):
        make_executor("ray", log=said.append)
    with pytest.raises(ValueError, match="Ray is not installed"):
        make_executor("auto", address="ray://head:10001")
    said.clear()
    assert isinstance(make_executor("auto", log=said.append), SerialExecutor) and not said
    with pytest.raises(ValueError, match="unknown executor"):
        make_executor("dask")


def test_the_serial_executor_reports_errors_per_item():
    got = []
    SerialExecutor().run(lambda x: 10 // x, [1, 0, 5], got.append)
    assert [(o.index, o.ok, o.value) for o in got] == [
        (0, True, 10),
        (1, False, None),
        (2, True, 2),
    ]
    assert got[1].error.startswith("ZeroDivisionError")
