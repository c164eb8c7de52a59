"""Agents mapping in frames of their own (``fuse.agent_frames``) and links aligned on first
contact (``fuse.align``), in ``run`` (the lab with one robot's poses biased) and ``fuse``."""

from __future__ import annotations

import dataclasses
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bagfactory as bf  # noqa: E402
from bagfactory import SENSORS, assert_same_map, room_map, run_cli  # noqa: E402
from conftest import REPO, expand, random_map  # noqa: E402
from doc_figures import assert_as_printed, quoted  # noqa: E402
from octofuse import OccupancyMap  # noqa: E402
from octofuse.config import AgentFrame, FuseConfig, RobustConfig, RunConfig, from_dict  # noqa: E402
from octofuse.fusion.agent_frames import AgentFrames, moved, transform_error  # noqa: E402
from octofuse.fusion.results import LOCAL  # noqa: E402
from octofuse.fusion.rounds import fuse_finished  # noqa: E402
from octofuse.fusion.simulate import simulate  # noqa: E402
from octofuse.maps.build import make_build_config  # noqa: E402
from octofuse.maps.compare import compare  # noqa: E402
from octofuse.maps.frames import invert, pose_matrix  # noqa: E402

GENERATOR = REPO / "data" / "generate_lab.py"
LAB = ["--duration", "30", "--rate", "1", "--robots", "4"]  # about 2 s per run
RULE = "min-info-loss"
#: robot3's reported poses: a whole-voxel shift (0.05 m voxels), or the shift and a 3 degree turn
SHIFT = ["--bias-robot", "3", "--bias-offset", "0.4", "-0.2"]
TURN = SHIFT + ["--bias-yaw", "3"]


def lab_bag(folder: Path, name: str, bias=()) -> Path:
    out = folder / f"{name}.bag"
    subprocess.run(
        [sys.executable, str(GENERATOR), *LAB, *bias, "--out", str(out)],
        check=True,
        stdout=subprocess.DEVNULL,
    )
    return out


def bias_frame(bag: Path) -> list[float]:
    """robot3's map frame into the true (common) frame: the inverse of the generator's bias
    ``p -> R(yaw) (p - pivot) + pivot + offset``, as x, y, z, roll, pitch, yaw."""
    b = json.loads(bag.with_name(bag.stem + "_scene.json").read_text())["generator"]["pose_bias"]
    yaw = math.radians(b["yaw_deg"])
    pivot, offset = np.array(b["pivot"]), np.array(b["offset"])
    bias = pose_matrix(*(pivot + offset), 0, 0, 0, yaw) @ pose_matrix(*-pivot, 0, 0, 0, 0)
    T = invert(bias)
    return [float(T[0, 3]), float(T[1, 3]), 0.0, 0.0, 0.0, -yaw]


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    d = tmp_path_factory.mktemp("lab")
    return {
        "true": lab_bag(d, "lab"),
        "shift": lab_bag(d, "shift", SHIFT),
        "turn": lab_bag(d, "turn", TURN),
    }


def run_lab(bag: Path, **fuse) -> object:
    fcfg = FuseConfig(rules=[RULE], topology="ring", schedule="periodic:10", **fuse)
    return simulate(make_build_config(bag, threads=2), fcfg, samples=2)


@pytest.fixture(scope="module")
def unbiased(lab):
    return run_lab(lab["true"])


@pytest.fixture(scope="module")
def biased_runs(lab):
    """Runs of the shifted and of the turned lab, without and with robot3's frame."""
    frame = {b: [AgentFrame("robot3", bias_frame(lab[b]))] for b in ("shift", "turn")}
    return {
        "shift": run_lab(lab["shift"]),
        "shift framed": run_lab(lab["shift"], agent_frames=frame["shift"]),
        "turn": run_lab(lab["turn"]),
        "turn framed": run_lab(lab["turn"], agent_frames=frame["turn"]),
    }


def kl_in_common(res, truth: OccupancyMap, maps: dict) -> dict[str, float]:
    """KL of each agent's map, moved into the common frame, to ``truth``."""
    out = {}
    for a, m in maps.items():
        out[a] = compare(truth, moved(m, res.frames.get(a)), 0.1).kl_mean
    return out


# -- frames of a run ------------------------------------------------------------------------------


def test_identity_frames_give_the_same_run_bit_for_bit(tmp_path):
    bag = bf.team_bag(tmp_path, 3, 4)
    bcfg = make_build_config(bag, resolution=0.1, threads=1)
    plain = simulate(
        bcfg, FuseConfig(rules=[RULE], topology="line", schedule="periodic:0.5"), samples=3
    )
    same = simulate(
        bcfg,
        FuseConfig(
            rules=[RULE],
            topology="line",
            schedule="periodic:0.5",
            agent_frames=[AgentFrame("b", [0.0] * 6)],
        ),
        samples=3,
    )
    assert same.frames == {} and same.alignment == []
    assert_same_map(same.central, plain.central, "centralized")
    for a in plain.agents:
        assert_same_map(same.fused[RULE][a], plain.fused[RULE][a], a)
        assert same.scores[RULE][a] == plain.scores[RULE][a]
    assert same.timeline == plain.timeline
    assert plain.traffic[RULE].messages > 0


def test_a_frame_pair_moves_a_message_by_whole_voxels_exactly():
    res = 0.1
    m = random_map(3, 4, res)
    frames = AgentFrames(
        ["a", "b", "c"],
        {"a": pose_matrix(3 * res, -2 * res, res), "b": pose_matrix(-res, res, 0.0)},
    )
    moved = frames.to_receiver("a", "b", m, res)  # T_b^-1 T_a: (4, -3, 1) voxels
    want = {(k[0] + 4, k[1] - 3, k[2] + 1): v for k, v in expand(m.leaves(), res).items()}
    assert expand(moved.leaves(), res) == want and len(want) > 1000
    back = frames.to_receiver("b", "a", moved, res)
    assert expand(back.leaves(), res) == expand(m.leaves(), res)
    assert frames.to_receiver("c", "c", m, res) is m
    assert frames.plain("c", "c") and not frames.plain("a", "c") and not frames.plain("c", "b")
    np.testing.assert_allclose(frames.reference("c", "b"), invert(pose_matrix(-res, res, 0.0)))


@pytest.mark.slow
def test_a_known_frame_undoes_a_biased_robot(unbiased, biased_runs):
    """robot3's poses shifted by whole voxels: with its frame the run is the unbiased run (its
    scans reach the centralized map moved back; its messages are moved exactly)."""
    truth = unbiased.central
    biased, framed = biased_runs["shift"], biased_runs["shift framed"]
    assert set(framed.frames) == {"robot3"}
    assert compare(truth, framed.central, 0.1).kl_mean < 1e-6
    want = kl_in_common(unbiased, truth, unbiased.fused[RULE])
    got = kl_in_common(framed, truth, framed.fused[RULE])
    worse = kl_in_common(biased, truth, biased.fused[RULE])
    for a in ("robot2", "robot3", "robot4"):  # robot3 and its neighbours on the ring
        assert got[a] == pytest.approx(want[a], rel=0.02, abs=1e-4), a
        assert worse[a] > 1.3 * got[a], (a, worse[a], got[a])
    # the scores are taken in the common frame: they equal the unbiased run's
    for a in framed.agents:
        assert framed.scores[RULE][a].kl_mean == pytest.approx(
            unbiased.scores[RULE][a].kl_mean, rel=0.02, abs=1e-4
        )


@pytest.mark.slow
def test_a_known_turned_frame_moves_the_robots_own_map_into_place(unbiased, biased_runs):
    """robot3's poses turned by 3 degrees: its own map, moved by its frame, lies on the truth,
    and the fused maps of robot3 and its neighbours with it."""
    truth = unbiased.central
    biased, framed = biased_runs["turn"], biased_runs["turn framed"]
    want = compare(truth, unbiased.local["robot3"], 0.1).kl_mean
    got = kl_in_common(framed, truth, {"robot3": framed.local["robot3"]})["robot3"]
    worse = compare(truth, biased.local["robot3"], 0.1).kl_mean
    assert got < want + 0.25 * (worse - want), (want, got, worse)
    assert framed.scores[LOCAL]["robot3"].kl_mean == pytest.approx(got, rel=0.05)
    assert (
        compare(truth, framed.central, 0.1).kl_mean
        < 0.5 * compare(truth, biased.central, 0.1).kl_mean
    )
    # messages moved between the frames by point sampling: the fused maps come close to the
    # unbiased run's and are far better than without the frame
    want = kl_in_common(unbiased, truth, unbiased.fused[RULE])
    got = kl_in_common(framed, truth, framed.fused[RULE])
    worse = kl_in_common(biased, truth, biased.fused[RULE])
    for a in ("robot2", "robot3", "robot4"):
        assert got[a] - want[a] < 0.5 * (worse[a] - want[a]), (a, want[a], got[a], worse[a])


#: the rows of docs/frames.md's table: robot3's poses and whether its frame is given
FRAME_TABLE = {
    "unbiased": r"unbiased \| –",
    "shift": r"shifted 0\.4, -0\.2 m \| no",
    "shift framed": r"shifted 0\.4, -0\.2 m \| yes",
    "turn": r"shifted and turned 3 degrees \| no",
    "turn framed": r"shifted and turned 3 degrees \| yes",
}


@pytest.mark.slow
def test_the_frames_table_of_the_docs_is_what_the_runs_give(unbiased, biased_runs):
    """docs/frames.md's table: each robot's fused map, moved into the common frame, against the
    unbiased centralized map, in the runs the tests above make."""
    runs = {"unbiased": unbiased, **biased_runs}
    figures, measured = {}, {}
    for name, row in FRAME_TABLE.items():
        kl = kl_in_common(runs[name], unbiased.central, runs[name].fused[RULE])
        cells = quoted("docs/frames.md", rf"\| {row} \| # / # / # / # \|")
        for agent, cell in zip(sorted(kl), cells, strict=True):
            figures[f"{name} {agent}"], measured[f"{name} {agent}"] = cell, kl[agent]
    assert_as_printed(measured, figures, "docs/frames.md")


# -- alignment on first contact (finished maps: `fuse`) -------------------------------------------


RES = 0.1
TRUE_B = pose_matrix(0.7, -0.4, 0.0, 0, 0, math.radians(20))  # b's frame into the common frame


@pytest.fixture(scope="module")
def room_maps():
    """a and b see overlapping parts of the test room; b maps in its own frame."""
    return {"a": room_map(SENSORS[:3]), "b": room_map(SENSORS[1:], T=TRUE_B)}, room_map(SENSORS)


def fuse_room(room_maps, **fuse):
    maps, central = room_maps
    # two rounds: an alignment is confirmed by the link's second registration
    cfg = FuseConfig(rules=[RULE], topology="line", schedule="rounds:2", **fuse)
    return fuse_finished(maps, central, cfg, threads=1)


def test_alignment_recovers_the_frames_and_the_scores(room_maps):
    frame = [AgentFrame("b", [0.7, -0.4, 0.0, 0.0, 0.0, math.radians(20)])]
    aligned = fuse_room(room_maps, align="planar", agent_frames=frame)
    assert [(d["sender"], d["receiver"], d["aligned"]) for d in aligned.alignment] == [
        ("a", "b", True),
        ("b", "a", True),
    ]
    for d in aligned.alignment:
        assert d["error_m"] < RES and d["error_deg"] < 1.0, d
        assert d["attempts"] == 2 and d["fitness"] > 0.5  # an estimate and its check
    est = {(d["sender"], d["receiver"]): d["estimate"] for d in aligned.alignment}
    assert math.degrees(est[("b", "a")]["yaw"]) == pytest.approx(20, abs=1)
    known = fuse_room(room_maps, agent_frames=frame)
    blind = fuse_room(room_maps)  # b's map fused as if it were in a's frame
    kl = {
        k: r.scores[RULE]["a"].kl_mean
        for k, r in (("aligned", aligned), ("known", known), ("blind", blind))
    }
    assert kl["aligned"] < 0.75 * kl["blind"] and kl["aligned"] < 1.05 * kl["known"], kl


def test_a_link_that_cannot_register_fuses_nothing_and_tries_again():
    maps = {}
    for name, y in (("a", 0.0), ("b", 1.0)):  # a few voxels each: too few to register
        maps[name] = OccupancyMap(0.1)
        maps[name].insert_scan(np.array([[2.0, y + 0.1 * k, 0.5] for k in range(8)]), (0, y, 0.5))
    cfg = FuseConfig(rules=[RULE], topology="line", schedule="rounds:3", align="full")
    res = fuse_finished(maps, None, cfg, threads=1)
    assert [d["aligned"] for d in res.alignment] == [False, False]
    # at the 1st and 2nd messages (the 3rd waits for the 4th)
    assert all(d["attempts"] == 2 and "cannot register" in d["refusal"] for d in res.alignment)
    for a, m in maps.items():  # sent, counted, not fused
        assert_same_map(res.fused[RULE][a], m, a)
    tr = res.traffic[RULE]
    assert tr.messages == 6 and tr.sent["a"] > 0 and tr.received["b"] > 0


@pytest.mark.slow
def test_a_run_records_the_alignment_in_the_summary_and_report(tmp_path, capsys):
    bag = bf.team_bag(tmp_path, 2, 4)
    out = tmp_path / "o"
    code, said, err = run_cli(
        capsys,
        "run",
        bag,
        "--resolution",
        "0.1",
        "--topology",
        "line",
        "--schedule",
        "periodic:0.5",
        "--align",
        "planar",
        "--agent-frame",
        "b=0.2,0,0,0,0,0.1",
        "--samples",
        "0",
        "--export-agents",
        "none",
        "--out",
        out,
    )
    assert code == 0, err
    lines = [x for x in said.splitlines() if x.startswith("align")]  # every link on the terminal
    assert {x.split(":")[0] for x in lines} == {"align a -> b", "align b -> a", "alignment"}
    assert all("confirmed by" in x or "refused, not fused" in x for x in lines[:-1])
    assert (
        "registration(s)" in lines[-1]
        and "alignment registrations (wall)" in (out / "report.md").read_text()
    )
    summary = json.loads((out / "summary.json").read_text())
    assert summary["config"]["fuse"]["align"] == "planar"
    assert summary["agent_frames"]["b"]["x"] == pytest.approx(0.2)
    assert {(d["sender"], d["receiver"]) for d in summary["alignment"]} == {("a", "b"), ("b", "a")}
    assert "## Agent frames" in (out / "report.md").read_text()


def test_transform_error_is_the_relative_motion():
    a = pose_matrix(1.0, 2.0, 0.0, 0, 0, 0.3)
    b = a @ pose_matrix(0.03, -0.04, 0.0, 0, 0, math.radians(2))
    t, deg = transform_error(b, a)
    assert t == pytest.approx(0.05) and deg == pytest.approx(2.0)


# -- what is refused ------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("bias", ["shift", "turn"])
def test_robust_fusion_votes_on_the_maps_in_the_common_frame(lab, bias):
    """robot3's biased poses: without its frame its map is off by the bias and voted out; with
    it, its map moved into the common frame agrees with its neighbours' and it is kept."""

    def vote(**fuse):
        fcfg = FuseConfig(
            rules=[RULE],
            topology="max-robust:3",
            schedule="periodic:10",
            robust=RobustConfig(enabled=True, time=20.0),
            **fuse,
        )
        res = simulate(make_build_config(lab[bias], threads=2), fcfg, samples=0)
        return res, res.robust.measurements[res.agents.index("robot3")]

    res, offset = vote()
    assert res.excluded == ["robot3"] and np.hypot(*offset[:2]) > 0.35
    res, framed = vote(agent_frames=[AgentFrame("robot3", bias_frame(lab[bias]))])
    assert res.excluded == [] and np.hypot(*framed[:2]) < 0.05 and abs(framed[2]) < 0.01
    assert not res.robust.abstained[res.agents.index("robot3")]
    # the offsets docs/frames.md quotes: shifted / turned, without and with the frame
    off_shift, off_turn, on_shift, on_turn = quoted(
        "docs/frames.md",
        r"without its frame \(measured offset # / # m\) and kept with it \(# / # m\)",
    )
    figures = {"shift": (off_shift, on_shift), "turn": (off_turn, on_turn)}[bias]
    assert_as_printed(
        {"without": np.hypot(*offset[:2]), "with": np.hypot(*framed[:2])},
        dict(zip(["without", "with"], figures)),
        f"docs/frames.md ({bias})",
    )


@pytest.fixture(scope="module")
def small_bag(tmp_path_factory):
    return bf.team_bag(tmp_path_factory.mktemp("bag"), 2, 2)


@pytest.mark.parametrize(
    "flags, needle",
    [
        (["--agent-frame", "zz=1,0,0,0,0,0"], "unknown agent 'zz' (agents: a, b)"),
        (["--agent-frame", "a=1,nan,0,0,0,0"], "frame 'a' '1,nan,0,0,0,0': values must be finite"),
        (
            ["--agent-frame", "a=1,0,0"],
            "expected 6 numbers x,y,z,roll,pitch,yaw (metres, radians), got 3",
        ),
        (
            ["--agent-frame", "a=1,0,0,0,0,0", "--agent-frame", "a=2,0,0,0,0,0"],
            "agent 'a' is given twice",
        ),
        (
            ["--agent-frame", "a=1,0,0,0,0,0", "--rules", "channel-filter"],
            "the channel-filter rule needs every agent in one frame",
        ),
        (["--align", "planar", "--rules", "channel-filter"], "but align = planar"),
        (["--align", "planar", "--robust"], "robust fusion measures the maps' offsets itself"),
    ],
)
def test_bad_frames_are_one_line_and_exit_1(small_bag, tmp_path, capsys, flags, needle):
    out = tmp_path / "o"
    code, text, err = run_cli(
        capsys, "run", small_bag, "--resolution", "0.2", "--topology", "line", *flags, "--out", out
    )
    assert code == 1, (text, err)
    assert err.startswith("error: ") and needle in err and len(err.strip().splitlines()) == 1, err
    assert not out.exists()


def test_fuse_refuses_a_frame_for_an_unknown_map(small_bag, tmp_path, capsys):
    maps = tmp_path / "maps"
    assert run_cli(capsys, "build", small_bag, "--resolution", "0.2", "--out", maps)[0] == 0
    code, _, err = run_cli(
        capsys, "fuse", maps, "--agent-frame", "c=0,0,0,0,0,1", "--out", tmp_path / "o"
    )
    assert code == 1 and "unknown agent 'c' (agents: a, b)" in err, err


def test_a_config_file_pose_of_the_wrong_length_names_the_key():
    with pytest.raises(ValueError, match=r"cfg.fuse.agent_frames\[0\].pose = \[1.0, 2.0\]"):
        from_dict(
            RunConfig, {"fuse": {"agent_frames": [{"name": "a", "pose": [1.0, 2.0]}]}}, where="cfg"
        )
    with pytest.raises(ValueError, match="cfg.fuse.align = 'yes'"):
        from_dict(FuseConfig, {"align": "yes"}, where="cfg.fuse")


# -- confirmation of registrations, bounded attempts ------------------------------------------


class _Stub:
    """``register`` answering each (receiver, sender) with the next transform of a list."""

    def __init__(self, answers):
        self.answers = {k: list(v) for k, v in answers.items()}
        self.calls = []

    def __call__(self, a, b, planar=False, seed=0):
        from octofuse.maps.registration import Registration

        key = (b, a)  # (sender, receiver): the maps are named by themselves below
        self.calls.append((*key, seed))
        T = self.answers[key].pop(0) if self.answers[key] else None
        if T is None:
            raise ValueError("cannot register: stub refuses")
        return Registration(T, 0.7, 0.05, 100, 200, 200, planar, conflict=0.01)


def _frames_with(monkeypatch, answers):
    from octofuse.fusion.agent_frames import AgentFrames
    from octofuse.maps import registration

    stub = _Stub(answers)
    monkeypatch.setattr(registration, "register", stub)
    return AgentFrames(["a", "b"], align="planar"), stub


def test_a_registration_alone_is_not_fused_until_a_second_one_agrees(monkeypatch):
    good = pose_matrix(1.0, 2.0, 0.0, 0, 0, 0.3)
    wrong = pose_matrix(-8.0, 5.0, 0.0, 0, 0, 2.5)
    frames, stub = _frames_with(monkeypatch, {("b", "a"): [wrong, good, good], ("a", "b"): []})
    maps = {"a": "a", "b": "b"}
    frames.align_links([("b", "a", False, 1.0)], maps)
    assert not frames.aligned("b", "a")  # one estimate: unconfirmed
    frames.align_links([("b", "a", False, 2.0)], maps)
    assert not frames.aligned("b", "a")  # a second one that disagrees
    assert "disagree" in frames.links[("b", "a")].refusal
    frames.align_links([("b", "a", False, 3.0)], maps)  # the 3rd message: no registration
    assert not frames.aligned("b", "a") and len(stub.calls) == 2
    frames.align_links([("b", "a", False, 3.5)], maps)  # the 4th
    assert frames.aligned("b", "a") and len(stub.calls) == 3
    np.testing.assert_allclose(frames.links[("b", "a")].matrix, good)
    assert "second registration" in frames.links[("b", "a")].confirmed_by
    frames.align_links([("a", "b", False, 4.0)], maps)  # the reverse registers on its own
    assert not frames.aligned("a", "b") and "stub refuses" in frames.links[("a", "b")].refusal


def test_only_the_links_own_estimates_confirm_and_wrong_pairs_are_never_fused(monkeypatch):
    # the reverse link's agreeing estimate lives with the other robot: it confirms nothing
    T = pose_matrix(1.0, 2.0, 0.0, 0, 0, 0.3)
    frames, _ = _frames_with(monkeypatch, {("b", "a"): [T], ("a", "b"): [invert(T)]})
    frames.align_links([("b", "a", False, 1.0), ("a", "b", False, 1.0)], {"a": "a", "b": "b"})
    assert not frames.aligned("a", "b") and not frames.aligned("b", "a")

    # every estimate half a metre or more from every other
    frames, stub = _frames_with(
        monkeypatch,
        {
            ("b", "a"): [pose_matrix(1.0 + k, 2.0, 0.0, 0, 0, 0.3) for k in range(9)],
            ("a", "b"): [invert(pose_matrix(1.5 + k, 2.0, 0.0, 0, 0, 0.3)) for k in range(9)],
        },
    )
    for k in range(40):  # attempts are bounded: the link is refused for the run
        frames.align_links([("b", "a", False, k), ("a", "b", False, k)], {"a": "a", "b": "b"})
    from octofuse.fusion.agent_frames import MAX_ATTEMPTS, alignment_lines

    assert not frames.aligned("a", "b") and not frames.aligned("b", "a")
    assert len(stub.calls) == 2 * MAX_ATTEMPTS
    assert sorted({c[2] for c in stub.calls}) == list(range(MAX_ATTEMPTS))  # a new seed each time
    lines = alignment_lines(frames.report())
    assert lines[0].startswith("align a -> b: refused, not fused") and "disagree" in lines[0]
    assert lines[-1].startswith(
        f"alignment: 0 of 2 links aligned; {2 * MAX_ATTEMPTS} registration(s)"
    )
