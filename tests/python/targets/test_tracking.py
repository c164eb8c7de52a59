"""Range-only tracking over the four-node ring: a short run of every belief family."""

import json

import numpy as np
import pytest

from doc_figures import assert_as_printed, quoted
from octofuse.targets.tracking import SENSORS, TrackingConfig, schedule, simulate_tracking
from octofuse.targets.tracking_report import run_tracking, summarise


def test_schedule_orders_measurements_before_messages():
    events = schedule(TrackingConfig(duration=1.4))
    at_14 = [(e.kind, e.node) for e in events if e.time == pytest.approx(1.4)]
    assert at_14 == [
        ("measure", 0),
        ("measure", 1),
        ("measure", 2),
        ("measure", 3),
        ("send", 0),
        ("send", 2),
    ]
    assert [e.time for e in events] == sorted(e.time for e in events)
    sends = [e for e in events if e.kind == "send" and e.node == 1]
    assert [e.time for e in sends] == pytest.approx([0.45, 0.9, 1.35])


def test_short_run_writes_its_report(tmp_path):
    out = tmp_path / "tracking"
    result = run_tracking(out, duration=0.8, seed=3)
    names = sorted(p.name for p in out.iterdir())
    assert names == [
        ".octofuse-output",
        "beliefs.png",
        "entropy.png",
        "error.png",
        "report.md",
        "summary.json",
    ]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["families"].keys() == result.summary["families"].keys()
    assert {"expoly", "gaussian"} <= summary["families"].keys()
    for name, fam in summary["families"].items():
        assert fam["fusions"] == 6  # nodes 1, 3 send at 0.35 and 0.7 s; nodes 2, 4 at 0.45 s
        assert fam["rms_error"] is None  # the run ends within the burn-in second
        errors = [r["error"] for r in result.records if r["family"] == name]
        assert fam["rms_error_before_burn_in"] == pytest.approx(np.sqrt(np.mean(np.square(errors))))
        for k, node in fam["per_node"].items():  # each node's mean against the true target
            belief = result.final_beliefs[name][int(k) - 1]
            mean = belief.moments()[0]
            assert node["final_error"] == pytest.approx(np.linalg.norm(mean - result.truth[-1]))
            assert np.isfinite(node["final_renyi2"])
    assert summary["families"]["expoly"]["bytes_per_message"]["max"] == 112
    assert summary["families"]["gaussian"]["bytes_per_message"]["max"] == 40
    assert "| expoly |" in (out / "report.md").read_text()
    # a second run replaces the directory as a whole
    run_tracking(out, duration=0.4, seed=3, families=("gaussian",))
    assert json.loads((out / "summary.json").read_text())["families"].keys() == {"gaussian"}
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_unknown_family_is_rejected(tmp_path):
    with pytest.raises(ValueError, match="unknown belief family 'particles'"):
        run_tracking(tmp_path / "x", duration=0.4, families=("particles",))


def test_track_prints_its_key_figures(tmp_path, capsys):
    from bagfactory import run_cli

    code, out, err = run_cli(
        capsys, "track", "--duration", "1.5", "--families", "gaussian", "--out", tmp_path / "t"
    )
    assert code == 0, err
    fam = json.loads((tmp_path / "t" / "summary.json").read_text())["families"]["gaussian"]
    row = next(line for line in out.splitlines() if line.startswith("│ gaussian"))
    assert [c.strip() for c in row.split("│")[1:-1]] == [
        "gaussian",
        f"{fam['rms_error']:.3f}",
        str(fam["fusions"]),
        "40",
    ]
    assert out.rstrip().endswith(f"report: {tmp_path / 't' / 'report.md'}")


@pytest.mark.slow
def test_ten_second_run_gives_the_figures_the_docs_quote():
    """`octofuse track` (10 s, seed 0): the figures of docs/beliefs.md, to their printed digits."""
    summary = summarise(simulate_tracking(TrackingConfig(duration=10.0, seed=0)))
    fams, central = summary["families"], summary["central"]
    names = ("expoly", "gaussian", "mixture")
    page = "docs/beliefs.md"
    after = quoted(
        page,
        r"RMS error after the first second # \(exponential polynomial\), # "
        r"\(Gaussian\), # \(mixture\), # \(centralized grid\)",
    )
    before = quoted(page, r"while ranges are ambiguous, #, #, # and #")
    rises = quoted(
        page,
        r"\(# of # fusions for exponential polynomials, # for Gaussians, # for mixtures\)",
    )
    sizes = quoted(page, r"Bytes per message: #, # and #")
    measured = {f"after {n}": fams[n]["rms_error"] for n in names}
    measured["after central"] = central["rms_error"]
    measured |= {f"before {n}": fams[n]["rms_error_before_burn_in"] for n in names}
    measured["before central"] = central["rms_error_before_burn_in"]
    measured |= {f"rises {n}": fams[n]["entropy_rises"] for n in names}
    measured["fusions"] = fams["expoly"]["fusions"]
    measured |= {f"bytes {n}": fams[n]["bytes_per_message"]["max"] for n in names}
    figures = dict(zip([f"after {n}" for n in names] + ["after central"], after))
    figures |= dict(zip([f"before {n}" for n in names] + ["before central"], before))
    figures |= dict(zip(["rises expoly", "fusions", "rises gaussian", "rises mixture"], rises))
    figures |= dict(zip([f"bytes {n}" for n in names], sizes))
    assert_as_printed(measured, figures, page)
    assert len(SENSORS) == 4 and all(f["fusions"] == measured["fusions"] for f in fams.values())
