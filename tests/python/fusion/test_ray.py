"""Studies and swarms on Ray: one local Ray runtime with 2 CPUs shared by the whole module.

A study's cells run as Ray tasks give the numbers of the serial run; a swarm (agents in Ray
actors exchanging frames of bytes) gives the maps, scores and traffic of the in-process simulation.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

ray = pytest.importorskip("ray")

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bagfactory as bf  # noqa: E402
from octofuse.config import AgentFrame, FuseConfig, RobustConfig, RunConfig  # noqa: E402
from octofuse.fusion.executors import RayExecutor, make_executor  # noqa: E402
from octofuse.fusion.results import LOCAL  # noqa: E402
from octofuse.fusion.simulate import simulate  # noqa: E402
from octofuse.fusion.swarm import simulate_swarm  # noqa: E402
from octofuse.maps.build import make_build_config  # noqa: E402
from octofuse.outputs.study import load_cells, run_study  # noqa: E402

pytestmark = pytest.mark.slow

RULES = ["naive-bayes", "chernoff"]


@pytest.fixture(scope="module", autouse=True)
def ray_runtime():
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    robots = bf.team(4)
    rec = bf.robot_recording(robots, bf.team_times(robots, 4))
    return rec.write(tmp_path_factory.mktemp("team") / "team", "mcap")


def config(bag, threads=1) -> RunConfig:
    return RunConfig(
        build=make_build_config(bag, resolution=0.2, threads=threads),
        fuse=FuseConfig(rules=list(RULES), topology="ring", schedule="aperiodic:1"),
    )


def test_cells_on_ray_equal_the_serial_cells(bag, tmp_path):
    grid = dict(topologies=["ring"], seeds=[0, 5])
    run_study(config(bag, threads=2), out=tmp_path / "serial", executor="serial", **grid)
    lines: list[str] = []
    run_study(config(bag), out=tmp_path / "ray", executor="ray", log=lines.append, **grid)
    serial, on_ray = load_cells([tmp_path / "serial"]), load_cells([tmp_path / "ray"])
    assert len(serial) == 2 and serial.keys() == on_ray.keys()
    for k in serial:
        assert serial[k]["rows"] == on_ray[k]["rows"], k
    assert (tmp_path / "serial" / "bench.csv").read_text() == (
        tmp_path / "ray" / "bench.csv"
    ).read_text()
    assert sum("done in" in x for x in lines) == 2
    assert ray.is_initialized()  # a running Ray is used, not shut down


def test_a_failing_task_is_reported_and_the_others_go_on(bag, tmp_path):
    bad = tmp_path / "broken.bag"
    bad.write_bytes(b"not a bag at all")
    lines: list[str] = []
    run_study(
        config(bag),
        ["ring"],
        tmp_path / "out",
        bag_sets=[[str(bad)], [str(bag)]],
        executor=RayExecutor(),
        log=lines.append,
    )
    failed = [x for x in lines if "FAILED" in x]
    assert len(failed) == 1 and "broken.bag" in failed[0]
    assert "## Failed cells" in (tmp_path / "out" / "bench.md").read_text()


def test_the_executor_reports_a_crashed_worker():
    def crash_on_zero(x):  # defined here: shipped to the workers by value
        import os

        if x == 0:
            os._exit(1)  # the worker process dies, as when the kernel kills it for memory
        return 10 // x

    got = []
    make_executor("ray").run(crash_on_zero, [1, 0, 5], got.append)
    by = {o.index: o for o in got}
    assert [by[0].value, by[2].value] == [10, 2] and by[0].ok and by[2].ok
    assert not by[1].ok and "Worker" in by[1].error


@pytest.mark.parametrize(
    "delta, per_worker, framed, align, extra",
    [
        (False, 2, False, "off", {}),
        (True, 4, False, "off", {}),
        (False, 2, True, "off", {}),
        (True, 1, True, "off", {}),
        (False, 2, True, "planar", {}),
        (True, 2, True, "planar", {}),
        (True, 2, False, "off", {"rules": [*RULES, "channel-filter"], "loss": 0.3}),
        (False, 2, False, "off", {"rules": [*RULES, "source-layers"], "loss": 0.3}),
        (False, 2, True, "off", {"robust": RobustConfig(enabled=True, time=1.0)}),
    ],
)
def test_a_swarm_equals_the_in_process_simulation(bag, delta, per_worker, framed, align, extra):
    """Also with two agents mapping in frames of their own (their scans are taken as given in
    those frames): messages moved into the receiver's, the centralized map and the scores in
    the common frame, as in the simulation. And with alignment on first contact: each link
    registers (or fails to, and tries again) on the same maps and at the same times; with
    deltas, a link sends whole maps until it aligns. The KL timeline is the simulation's. The
    channel filter with deltas on links that lose messages, and robust fusion's vote with
    agent frames, run as in the simulation too; and source layers (their frames of several
    layers) on links that lose messages."""
    cfg = config(bag)
    frames = (
        [
            AgentFrame("a", [0.3, -0.2, 0.0, 0.0, 0.0, 0.09]),
            AgentFrame("c", [-0.1, 0.25, 0.0, 0.0, 0.0, -0.05]),
        ]
        if framed
        else []
    )
    # with alignment, messages often enough for a link's second registration to confirm it
    schedule = "periodic:0.2" if align != "off" else "periodic:0.33"
    fuse = FuseConfig(
        **{
            "rules": list(RULES),
            "topology": "ring",
            "schedule": schedule,
            "delta": delta,
            "agent_frames": frames,
            "align": align,
            **extra,
        }
    )
    fuse.validate("fuse")
    rules = fuse.rules
    ref = simulate(cfg.build, fuse, samples=3)
    if fuse.loss:
        assert 0 < ref.traffic["chernoff"].lost < ref.traffic["chernoff"].messages
    assert ref.frames.keys() == ({"a", "c"} if framed else set())
    if align != "off":  # links that align after a few tries, and links that never do
        assert {(d["aligned"], d["attempts"] > 1) for d in ref.alignment} == {
            (True, True),
            (False, True),
        }
    sw = simulate_swarm(cfg.build, fuse, samples=3, collect_maps=True, agents_per_worker=per_worker)

    def untimed(links):
        return [{k: v for k, v in d.items() if k != "seconds"} for d in links]

    assert untimed(sw.alignment) == untimed(ref.alignment)
    assert len(sw.timeline) == 3 * (len(rules) + 1) * 4 and sw.timeline == ref.timeline
    assert sw.excluded == ref.excluded and (sw.robust is None) == (ref.robust is None)
    assert sw.agents == ref.agents and sw.events == ref.events
    assert sw.messages == ref.traffic[rules[0]].messages  # the events robust fusion admits
    assert len(sw.workers) == -(-len(ref.agents) // per_worker) + 1
    assert sw.central == ref.central.to_bytes()
    for a in ref.agents:
        assert sw.maps[a][LOCAL] == ref.local[a].to_bytes(), a
        for r in rules:
            assert sw.maps[a][r] == ref.fused[r][a].to_bytes(), (r, a)
    for r in [LOCAL, *rules]:
        assert sw.scores[r] == ref.scores[r], r
    for r in rules:
        assert sw.traffic[r].messages == ref.traffic[r].messages
        assert sw.traffic[r].lost == ref.traffic[r].lost
        assert dict(sw.traffic[r].sent) == dict(ref.traffic[r].sent)
        assert dict(sw.traffic[r].received) == dict(ref.traffic[r].received)
        assert dict(sw.traffic[r].sent_32b) == dict(ref.traffic[r].sent_32b)
    assert sw.stream_bytes > 0 and all(w["peak_rss"] > 0 for w in sw.workers)
    # the driver's parts: wall time, named so (the workers' threads are not timed here)
    assert set(sw.timings) == {
        "start workers",
        "exchange calls (driver)",
        "run (wall)",
        "final scores (wall)",
        "total",
    }
