"""The target search simulation: detector, Gaussian-sum particle filter, exchanges, outputs."""

import json
import math

import numpy as np
import pytest

from doc_figures import assert_as_printed, quoted
from octofuse.beliefs.mixture import GaussianMixture
from octofuse.targets.detector import CameraDetector
from octofuse.targets.particle_filter import gaussian_sum_update
from octofuse.targets.search import exchanges, robot_paths, simulate
from octofuse.targets.search_report import run_target_search

POSE = (0.0, 0.0, 0.0)  # at the origin, facing +x


def test_detector_sees_only_its_view_cone():
    det = CameraDetector()
    pts = np.array([[0.5, 0.0], [0.9, 0.1], [1.3, 0.0], [-0.5, 0.0], [0.5, 0.5], [0.5, -0.5]])
    p = det.p_detection(POSE, pts)
    np.testing.assert_allclose(p[:2], 0.9, atol=1e-3)
    np.testing.assert_allclose(p[2:], 0.0, atol=1e-3)  # too far, behind, outside 21.25 degrees
    rotated = det.p_detection((0.0, 0.0, math.pi / 2), [[0.0, 0.5]])
    assert rotated[0] == pytest.approx(0.9, abs=1e-3)
    np.testing.assert_allclose(
        det.likelihood(False, POSE, pts) + det.likelihood(True, POSE, pts), 1.0
    )


def test_particle_filter_matches_grid_bayes_for_a_no_detection():
    prior = GaussianMixture.gaussian([0.6, 0.0], [[0.3, 0.0], [0.0, 0.2]])
    det = CameraDetector()
    post = gaussian_sum_update(
        prior,
        lambda x: det.likelihood(False, POSE, x),
        np.random.default_rng(0),
        n_particles=4000,
        max_components=6,
    )
    xs, ys = np.linspace(-2.5, 3.5, 241), np.linspace(-2.5, 2.5, 201)
    pts = np.column_stack([c.ravel() for c in np.meshgrid(xs, ys)])
    exact = prior.pdf(pts) * det.likelihood(False, POSE, pts)
    exact /= exact.sum()
    approx = post.pdf(pts)
    approx /= approx.sum()
    kl = float(np.sum(exact * np.log(np.maximum(exact, 1e-300) / approx)))
    kl_prior = float(
        np.sum(exact * np.log(np.maximum(exact, 1e-300) / (prior.pdf(pts) / prior.pdf(pts).sum())))
    )
    assert kl < 0.6 * kl_prior  # much closer to the exact posterior than the prior is
    assert post.pdf([0.6, 0.0]) < 0.5 * prior.pdf([0.6, 0.0])  # mass left the view cone
    assert 1 < post.n_components <= 6


def test_three_robot_exchanges_follow_the_paper_cycles():
    assert exchanges("3-robots", 3, 13) == [[(0, 2)], [(2, 1)], [(1, 0)]]  # 1 -> 3 -> 2 -> 1
    assert exchanges("3-robots", 3, 26) == [[(0, 1)], [(1, 2)], [(2, 0)]]  # 1 -> 2 -> 3 -> 1


def test_eight_robot_exchanges_use_the_max_robust_network():
    (round_,) = exchanges("8-robots", 8, 13)
    assert len(round_) == 24
    for i in range(8):
        senders = [s for s, r in round_ if r == i]
        assert len(senders) == 3 and i not in senders


def test_paths_stay_in_the_lab_and_robot_one_stands_still():
    for setting, n in (("3-robots", 3), ("8-robots", 8)):
        poses = robot_paths(setting, 65)
        assert poses.shape == (n, 66, 3)
        assert np.all(
            (poses[..., 0] >= 0)
            & (poses[..., 0] <= 15)
            & (poses[..., 1] >= 0)
            & (poses[..., 1] <= 8)
        )
        assert np.ptp(poses[0], axis=0).max() == 0.0


@pytest.fixture(scope="module")
def short_run():
    return simulate(
        "3-robots",
        rules=("naive-bayes", "chernoff"),
        duration=8,
        comm_period=4,
        n_samples=200,
        particles=150,
        max_components=6,
        grid_step=0.25,
    )


def test_short_search_measures_every_scheme(short_run):
    res = short_run
    assert res.schemes == ("centralized", "no-sharing", "naive-bayes", "chernoff")
    for s in res.schemes:
        assert res.info_gain[s].shape == (9, 3)
        assert np.all(res.info_gain[s][0] == 0.0)
        assert all(m.n_components <= 6 for m in res.final[s])
    np.testing.assert_allclose(res.kl_to_central["centralized"], 0.0, atol=1e-12)
    assert len([f for f in res.fusions if f["scheme"] == "chernoff"]) == 6  # 2 exchanges x 3 hops
    assert all(0.0 <= f["omega"] <= 1.0 for f in res.fusions if f["scheme"] == "chernoff")
    # double counting: naive Bayes claims more information than all the data hold
    assert res.info_gain["naive-bayes"][-1].min() > res.info_gain["centralized"][-1][0]
    assert res.info_gain["chernoff"][-1].max() < res.info_gain["naive-bayes"][-1].min()


def test_run_writes_outputs_in_place(tmp_path):
    out = tmp_path / "search"
    res = run_target_search(
        out,
        setting="3-robots",
        rules=("chernoff",),
        duration=2,
        comm_period=2,
        n_samples=100,
        particles=100,
        max_components=4,
        grid_step=0.5,
        figures=True,
    )
    assert res.out_dir == out
    names = {p.name for p in out.iterdir()}
    assert {
        "report.md",
        "summary.json",
        "final_beliefs_robot1.png",
        "info_gain.png",
        "kl_to_central.png",
        "omega.png",
    } <= names
    summary = json.loads((out / "summary.json").read_text())
    assert summary["schemes"] == ["centralized", "no-sharing", "chernoff"]
    # what is written is what was measured: robot 1's final KL to the centralized belief
    final = {s: float(res.kl_to_central[s][-1][0]) for s in res.schemes}
    assert summary["final_kl_to_central"]["chernoff"][0] == pytest.approx(final["chernoff"])
    band = summary["findings"]["wep_band"]
    assert band["band"] == pytest.approx([final["chernoff"]] * 2) and band["width"] == 0.0
    assert band["no_sharing_robot1"] == pytest.approx(final["no-sharing"])
    report = (out / "report.md").read_text()
    assert "What the data says" in report
    gain = float(res.info_gain["chernoff"][-1][0])
    assert f"| chernoff | {gain:.3f} |" in report
    assert [p.name for p in tmp_path.iterdir()] == ["search"]  # no staging folder left behind


@pytest.mark.parametrize(
    "kwargs, match",
    [({"setting": "5-robots"}, "setting"), ({"rules": ("entropy-weighted-chernoff",)}, "negative")],
)
def test_bad_arguments_raise(tmp_path, kwargs, match):
    with pytest.raises(ValueError, match=match):
        run_target_search(tmp_path / "x", **kwargs)


@pytest.mark.slow
def test_short_search_gives_the_figures_the_docs_quote():
    """The shorter run of docs/beliefs.md (3 robots, 26 s, three rules), to its printed digits."""
    page = "docs/beliefs.md"
    duration, rules = quoted(
        page, r"`octofuse search --setting 3-robots --duration # --rules ([a-z,-]+)`"
    )
    assert rules == "naive-bayes,chernoff,min-info-loss"
    res = simulate("3-robots", rules=tuple(rules.split(",")), duration=int(duration))
    gain = {s: res.info_gain[s][-1] for s in res.schemes}
    kl1 = {s: float(res.kl_to_central[s][-1][0]) for s in res.schemes}
    names = ["central", "nb low", "nb high", "chernoff", "min-info-loss", "alone"]
    figures = dict(
        zip(
            names,
            quoted(
                page,
                r"centralized information gain of #, naive-Bayes gains of #-#, and robot 1's KL "
                r"to the centralized belief # \(Chernoff\) and # \(min-info-loss\) against # "
                r"without sharing",
            ),
        )
    )
    measured = {"central": gain["centralized"][0], "nb low": gain["naive-bayes"].min()}
    measured |= {"nb high": gain["naive-bayes"].max(), "alone": kl1["no-sharing"]}
    measured |= {"chernoff": kl1["chernoff"], "min-info-loss": kl1["min-info-loss"]}
    assert_as_printed(measured, figures, page)
    np.testing.assert_allclose(gain["centralized"], gain["centralized"][0])  # one shared belief
