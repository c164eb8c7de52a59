"""Live fleets: real ``octofuse agent`` processes over real Zenoh on loopback.

A lockstep fleet's maps, scores and traffic are those of ``octofuse run`` with the same
options, bit for bit (the live protocol is the simulated one); a fleet in time with injected
loss, duplicates, reordering and delay, and an agent killed and started again, end with every
channel-filter agent holding exactly the sum of every robot's scans. Every test of a fleet is
marked slow; faults, checkpoints and chunks are tested without one.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

pytest.importorskip("zenoh")

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bagfactory as bf  # noqa: E402
from bagfactory import run_cli, voxel_keys  # noqa: E402
from octofuse import OccupancyMap  # noqa: E402
from octofuse.config import FleetConfig, dump_yaml, from_dict  # noqa: E402
from octofuse.fusion.channel_filter import add_into, clamped, open_map  # noqa: E402
from octofuse.maps.build import insert_scans  # noqa: E402
from octofuse.scans.source import ScanSource  # noqa: E402

RES = "0.2"
SCHEDULE = ["--topology", "ring", "--schedule", "periodic:0.33", "--resolution", RES]


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    robots = bf.team(3)
    rec = bf.robot_recording(robots, bf.team_times(robots, 4))
    return rec.write(tmp_path_factory.mktemp("team") / "team", "mcap")


@pytest.mark.slow
def test_a_lockstep_fleet_equals_run(bag, tmp_path, capsys):
    options = [
        *SCHEDULE,
        "--rule",
        "chernoff,channel-filter,source-layers",
        "--delta",
        "--loss",
        "0.25",
    ]
    code, _, err = run_cli(
        capsys, "run", bag, *options, "--samples", "0", "--out", tmp_path / "run"
    )
    assert code == 0, err
    code, text, err = run_cli(
        capsys,
        "fleet",
        bag,
        *options,
        "--lockstep",
        "--base-port",
        "17447",
        "--out",
        tmp_path / "fleet",
    )
    assert code == 0, err
    run = json.loads((tmp_path / "run" / "summary.json").read_text())
    fleet = json.loads((tmp_path / "fleet" / "summary.json").read_text())
    for rule in ("chernoff", "channel-filter", "source-layers"):
        for a in ("a", "b", "c"):
            got = (tmp_path / "fleet" / rule / f"{a}.ot").read_bytes()
            assert got == (tmp_path / "run" / rule / f"{a}.ot").read_bytes(), (rule, a)
        for key in (
            "kl_mean",
            "overconfidence",
            "agreement",
            "coverage",
            "loss_mean",
            "bytes_sent",
        ):
            assert fleet["mean"][rule][key] == run["mean"][rule][key], (rule, key)
    assert "octofuse fleet" in text


# -- in time, with faults and restarts ------------------------------------------------------


def exact_sum(bag) -> OccupancyMap:
    """Every robot's scans summed without clamping, then clamped: what each channel-filter
    agent of a tree holds once every contribution has reached it."""
    from octofuse.maps.build import make_build_config

    cfg = make_build_config(bag, resolution=float(RES))
    with ScanSource(cfg) as src:
        own = {a.name: open_map(OccupancyMap(float(RES))) for a in src.agents}
        names = [a.name for a in src.agents]
        for scan in src.scans():
            insert_scans([scan], [[own[names[scan.agent]]]], 1)
    total = open_map(OccupancyMap(float(RES)))
    for m in own.values():
        add_into(total, m)
    return clamped(total)


def assert_same_values(got: OccupancyMap, want: OccupancyMap, what: str) -> None:
    kg, vg = voxel_keys(got)
    kw, vw = voxel_keys(want)
    assert np.array_equal(kg, kw), what
    assert np.abs(vg - vw).max(initial=0.0) <= 2e-4, what


def fleet_config(bag, tmp_path, **live) -> tuple[FleetConfig, Path]:
    from octofuse.live.fleet import resolved

    cfg = from_dict(
        FleetConfig,
        {
            "build": {"bags": [str(bag)], "map": {"resolution": float(RES)}},
            "fuse": {
                "rules": ["channel-filter"],
                "topology": "line",
                "schedule": "periodic:0.2",
                "delta": True,
            },
            "live": {
                "speed": 2.0,
                "checkpoint_period": 0.4,
                "settle_rounds": 3,
                "base_port": 18447,
                "timeout": 60,
                **live,
            },
        },
        where="test",
    )
    cfg = resolved(cfg)
    path = tmp_path / "fleet.yaml"
    path.write_text(dump_yaml(cfg))
    return cfg, path


def start_agent(path: Path, name: str, out: Path, fresh: bool = True) -> subprocess.Popen:
    cmd = [
        sys.executable,
        "-m",
        "octofuse",
        "agent",
        name,
        "--fleet",
        str(path),
        "--out",
        str(out),
    ] + (["--fresh"] if fresh else [])
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)


def finish(procs: dict) -> None:
    for name, p in procs.items():
        out, _ = p.communicate(timeout=180)
        assert p.returncode == 0, (name, out.decode())


@pytest.mark.slow
def test_through_loss_duplicates_reordering_and_delay_the_channel_filter_stays_exact(bag, tmp_path):
    # small chunks: a message is several, each lost, repeated, held back or late on its own
    cfg, path = fleet_config(
        bag,
        tmp_path,
        max_chunk_bytes=2048,
        faults={"loss": 0.3, "duplicate": 0.2, "reorder": 0.2, "delay": 0.2, "seed": 4},
    )
    out = tmp_path / "agents"
    finish({a.name: start_agent(path, a.name, out) for a in cfg.build.agents})
    want = exact_sum(bag)
    faults = {"lost": 0, "duplicated": 0, "reordered": 0, "delayed": 0}
    for a in cfg.build.agents:
        assert_same_values(
            OccupancyMap.load(out / "channel-filter" / a.name / "fused.ot"), want, a.name
        )
        counts = json.loads((out / "channel-filter" / a.name / "counts.json").read_text())
        assert counts["chunks_refused"] == 0
        for k in faults:
            faults[k] += counts["faults"].get(k, 0)
    assert all(n > 0 for n in faults.values()), faults  # every fault happened, to chunks


@pytest.mark.slow
@pytest.mark.parametrize("rule", ["channel-filter", "source-layers"])
def test_an_agent_killed_and_started_again_resumes_and_the_fleet_ends_exact(bag, tmp_path, rule):
    cfg, path = fleet_config(bag, tmp_path, speed=1.0)
    cfg = replace(cfg, fuse=replace(cfg.fuse, rules=[rule]))
    path.write_text(dump_yaml(cfg))
    out = tmp_path / "agents"
    procs = {a.name: start_agent(path, a.name, out) for a in cfg.build.agents}
    victim = cfg.build.agents[1].name  # the middle of the line
    ckpt = out / rule / victim / "checkpoint.pkl"
    deadline = time.monotonic() + 60
    while not ckpt.is_file() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert ckpt.is_file(), "no checkpoint written"
    time.sleep(0.3)
    procs[victim].send_signal(signal.SIGKILL)
    procs[victim].communicate()
    procs[victim] = start_agent(path, victim, out, fresh=False)
    finish(procs)
    counts = json.loads((out / rule / victim / "counts.json").read_text())
    assert counts["restarts"] == 1
    want = exact_sum(bag)
    for a in cfg.build.agents:
        assert_same_values(OccupancyMap.load(out / rule / a.name / "fused.ot"), want, a.name)


# -- a byte budget per link ------------------------------------------------------------------


def test_a_link_budget_sends_the_most_informative_voxels_first_and_the_rest_later(bag, tmp_path):
    """Agents of a line compose frames under a 4 kB/s budget every quarter second, a third of
    them lost: no link carries more than 4 kB in any second (bytes counted on the frames),
    the first message carries the largest log-odds of its sender's map, and once the budget
    has let everything through every channel-filter map is exactly the sum of every robot's
    scans."""
    from octofuse.fusion.agent import MapMessage
    from octofuse.live.agent import LiveAgent
    from octofuse.live.chunks import wire_bytes

    rate = 4000
    cfg, _ = fleet_config(bag, tmp_path, link_budget="4kB/s", faults={"loss": 0.3})
    names = [a.name for a in cfg.build.agents]
    agents = {n: LiveAgent(cfg, n, "channel-filter", tmp_path / "out") for n in names}
    with ScanSource(cfg.build) as src:
        scans = list(src.scans())
    want = exact_sum(bag)
    rng = np.random.default_rng(3)
    sent: dict[tuple[str, str], list] = {}
    first = None
    for step in range(400):
        t = step / 4
        if scans and step % 3 == 1:  # a scan now and then, the first after a message
            scan = scans.pop(0)
            agents[names[scan.agent]]._insert([scan], {"scans": 0})
        for x in agents.values():
            for y in x.neighbours:
                frame = x.compose(y, t)
                if frame is None:
                    continue
                sent.setdefault((x.name, y), []).append((t, wire_bytes(len(frame), 2**16)))
                if first is None and x.scans_in_map:  # and the map it was taken from
                    first = (x.agent.map.copy(), MapMessage.decode(frame).payload)
                if step > 200 or rng.random() > 0.3:  # lost, until the last rounds
                    agents[y].apply(x.name, frame)
        if step > 200 and all(_same(clamped(x.agent.map), want) for x in agents.values()):
            break
    else:
        raise AssertionError("the fleet did not settle under its budget")
    for a in agents.values():
        assert_same_values(clamped(a.agent.map), want, a.name)
    for link, sends in sent.items():  # the bytes of every second that ends at a send
        for t, _ in sends:
            assert sum(n for s, n in sends if t - 1 < s <= t) <= rate, link
        assert agents[link[0]].budget.peak[link[1]] <= rate
    assert max(len(s) for s in sent.values()) > 10  # the budget held messages back
    # an acknowledgement alone (what an agent that sends no more gives) moves the baseline on
    from octofuse.fusion.wire import Encoding, Kind, Message

    a, b = agents[names[0]], names[1]
    a.agent.map.insert_scan(np.array([[9.0, 9.0, 1.0]]), [8.0, 9.0, 1.0])
    msg = MapMessage.decode(a.compose(b, t + 2))
    assert msg.payload.num_leaves > 0
    ack = Message(
        cfg.live.fleet, "channel-filter", b, a.name, 1, msg.seq, Kind.ACK, b"", Encoding.NONE
    )
    before = a.agent.map.to_bytes()
    assert not a.apply(b, ack.encode()) and not a.counts.refused
    assert a.agent.map.to_bytes() == before
    assert MapMessage.decode(a.compose(b, t + 4)).payload.num_leaves == 0  # nothing new
    sender_map, payload = first
    ks, vs = voxel_keys(payload)
    km, vm = voxel_keys(sender_map)
    unsent = ~np.isin(km, ks)
    assert 0 < len(ks) and unsent.any()
    assert np.abs(vs).min() >= np.abs(vm[unsent]).max()


def _same(got: OccupancyMap, want: OccupancyMap) -> bool:
    kg, vg = voxel_keys(got)
    kw, vw = voxel_keys(want)
    return np.array_equal(kg, kw) and np.abs(vg - vw).max(initial=0.0) <= 2e-4


@pytest.mark.parametrize(
    "value, why",
    [
        ("2MB", "expected a size per second"),
        ("2Mb/s", "is not a byte size"),
        ("fast/s", "is not a byte size"),
        ("100B/s", "expected at least 1024"),
    ],
)
def test_a_bad_link_budget_is_one_line_naming_it(value, why):
    with pytest.raises(ValueError, match=f"fleet.yaml.live.link_budget = '{value}': .*{why}"):
        from_dict(
            FleetConfig, {"fuse": {"delta": True}, "live": {"link_budget": value}}, "fleet.yaml"
        )
    assert (
        from_dict(
            FleetConfig, {"fuse": {"delta": True}, "live": {"link_budget": "2MB/s"}}
        ).live.budget_bytes_per_s
        == 2_000_000
    )
    with pytest.raises(ValueError, match="set fuse.delta"):
        from_dict(FleetConfig, {"live": {"link_budget": "2MB/s"}})


@pytest.mark.slow
def test_through_loss_under_a_link_budget_a_fleet_ends_exact_and_within_it(bag, tmp_path):
    cfg, path = fleet_config(
        bag, tmp_path, link_budget="8kB/s", settle_rounds=25, faults={"loss": 0.2, "seed": 2}
    )
    out = tmp_path / "agents"
    finish({a.name: start_agent(path, a.name, out) for a in cfg.build.agents})
    want = exact_sum(bag)
    for a in cfg.build.agents:
        assert_same_values(
            OccupancyMap.load(out / "channel-filter" / a.name / "fused.ot"), want, a.name
        )
        counts = json.loads((out / "channel-filter" / a.name / "counts.json").read_text())
        assert counts["budget_peak"] and max(counts["budget_peak"].values()) <= 8000


# -- what an agent lets in ------------------------------------------------------------------


@pytest.mark.slow
def test_an_agent_fuses_only_well_formed_messages_of_its_neighbours(bag, tmp_path):
    from octofuse.fusion.agent import Agent
    from octofuse.fusion.wire import Kind, Message
    from octofuse.live.agent import LiveAgent

    cfg, _ = fleet_config(bag, tmp_path)
    cfg = replace(cfg, fuse=replace(cfg.fuse, rules=["chernoff"]))
    live = LiveAgent(cfg, "a", "chernoff", tmp_path / "out")
    before = live.agent.map.to_bytes()
    sender = Agent("b", "chernoff", OccupancyMap(float(RES)))
    sender.map.insert_scan(np.array([[1.0, 0.0, 0.0]]), [0.0, 0.0, 0.0])
    good = sender.compose("a").encode(cfg.live.fleet)
    foreign = Message("f", "chernoff", "b", "a", 1, 0, Kind.WHOLE, b"not a map").encode()
    stranger = Agent("c", "chernoff", sender.map.copy()).compose("a").encode()
    assert not live.apply("b", good[:-3])  # truncated
    assert not live.apply("b", b"\0" * 64)  # not a frame
    assert not live.apply("b", foreign)  # a frame whose payload is no map
    assert not live.apply("z", good)  # not a neighbour
    assert not live.apply("b", stranger)  # says it is c's
    assert live.agent.map.to_bytes() == before
    assert live.apply("b", good) and not live.apply("b", good)  # a repeat changes nothing
    assert live.agent.map.to_bytes() != before
    assert sum(live.counts.refused.values()) == 6


# -- only the fleet gets in -------------------------------------------------------------------


def self_signed(folder: Path) -> dict:
    """A certificate authority and a certificate for localhost signed by it (openssl)."""

    def run(*args):
        subprocess.run(["openssl", *args], cwd=folder, check=True, capture_output=True)

    run(
        "req",
        "-x509",
        "-newkey",
        "rsa:2048",
        "-nodes",
        "-keyout",
        "ca.key",
        "-out",
        "ca.pem",
        "-days",
        "2",
        "-subj",
        "/CN=octofuse test authority",
    )
    run(
        "req",
        "-newkey",
        "rsa:2048",
        "-nodes",
        "-keyout",
        "key.pem",
        "-out",
        "req.csr",
        "-subj",
        "/CN=localhost",
    )
    (folder / "ext.cnf").write_text("subjectAltName=DNS:localhost,IP:127.0.0.1\n")
    run(
        "x509",
        "-req",
        "-in",
        "req.csr",
        "-CA",
        "ca.pem",
        "-CAkey",
        "ca.key",
        "-CAcreateserial",
        "-out",
        "cert.pem",
        "-days",
        "2",
        "-extfile",
        "ext.cnf",
    )
    return {
        "tls_root_ca": str(folder / "ca.pem"),
        "tls_certificate": str(folder / "cert.pem"),
        "tls_private_key": str(folder / "key.pem"),
    }


@pytest.mark.slow
def test_agents_meet_over_tls_and_a_peer_without_it_does_not_get_in(tmp_path):
    import shutil

    from octofuse.config import LiveConfig
    from octofuse.live.fleet import free_base_port
    from octofuse.live.transport import ZenohTransport, endpoint

    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed (make test installs it)")
    port = free_base_port(19447, 3)
    live = from_dict(
        LiveConfig,
        {
            "fleet": "tls",
            "host": "localhost",
            "base_port": port,
            "timeout": 20,
            **self_signed(tmp_path),
        },
        where="test",
    )
    a = ZenohTransport(live, "chernoff", "a", endpoint(live, 0), [])
    b = ZenohTransport(live, "chernoff", "b", endpoint(live, 1), [endpoint(live, 0)])
    plain = replace(live, tls_root_ca="", tls_certificate="", tls_private_key="")
    c = ZenohTransport(plain, "chernoff", "c", endpoint(plain, 2), [f"tcp/localhost:{port}"])
    try:
        assert endpoint(live, 0).startswith("tls/localhost:")
        a.wait_for(["b"], 20)
        b.wait_for(["a"], 20)
        b.send("a", b"over tls")
        assert a.inbox.get(timeout=20) == ("b", b"over tls")
        c.send("a", b"let me in")
        with pytest.raises(TimeoutError, match="no word from a"):
            c.wait_for(["a"], 2)
        time.sleep(0.5)
        assert a.inbox.empty()
    finally:
        for t in (a, b, c):
            t.close()


# -- the fault layer and the checkpoints, in process -------------------------------------------


def test_faults_lose_duplicate_reorder_and_cut_off_as_configured():
    from octofuse.config import FaultConfig, PartitionConfig
    from octofuse.live.faults import FaultyLinks

    sent = []
    faults = FaultConfig(
        loss=0.2, duplicate=0.1, reorder=0.1, seed=1, partitions=[PartitionConfig(1.0, 2.0, ["a"])]
    )
    clock = [0.0]
    links = FaultyLinks(faults, "a", 0, lambda to, f: sent.append((to, f)), lambda: clock[0])
    frames = [bytes([k % 256, k // 256]) for k in range(2000)]
    for f in frames:
        links.send("b", f)
    links.flush()
    c = links.counts
    assert len(sent) == len(frames) - c["lost"] + c["duplicated"]
    assert 0.15 < c["lost"] / len(frames) < 0.25 and c["duplicated"] > 100 and c["reordered"] > 100
    order = [frames.index(f) for _, f in sent]
    assert order != sorted(order) and set(order) == set(range(2000)) - {
        k for k in range(2000) if frames[k] not in {f for _, f in sent}
    }
    clock[0] = 1.5  # a's partition: nothing leaves a, b's side is cut off
    sent.clear()
    links.send("b", b"x")
    assert sent == [] and links.counts["partitioned"] == 1 and links.cut_off("b", 1.5)
    assert not links.cut_off("b", 2.0)


def test_a_checkpoint_restores_the_maps_and_links_in_a_new_epoch(tmp_path):
    from octofuse.fusion.agent import Agent
    from octofuse.live import checkpoint

    rng = np.random.default_rng(0)
    a, b = (Agent(n, "channel-filter", OccupancyMap(0.2)) for n in "ab")
    for x in (a, b):
        x.map.insert_scan(rng.uniform(-2, 2, (200, 3)), [0.0, 0.0, 0.0])
    assert b.deliver(a.compose("b", delta=True)) and a.deliver(b.compose("a", delta=True))
    local = OccupancyMap(0.2)
    checkpoint.save(tmp_path / "ckpt", a, local, {"t": 1.5, "scans": 3})
    assert [p.name for p in tmp_path.iterdir()] == ["ckpt"]
    restored = Agent("a", "channel-filter", OccupancyMap(0.2))
    epoch = checkpoint.next_epoch(tmp_path / "epoch")
    assert epoch == 1 and checkpoint.next_epoch(tmp_path / "epoch") == 2
    _, progress = checkpoint.restore(tmp_path / "ckpt", restored, 2)
    assert progress == {"t": 1.5, "scans": 3}
    assert restored.map.to_bytes() == a.map.to_bytes()
    assert restored.links["b"].received.to_bytes() == a.links["b"].received.to_bytes()
    stale = b.compose("a", delta=True)  # b has not heard of the restart
    assert stale.delta and not restored.deliver(stale)  # no delta before a whole map
    msg = restored.compose("b", delta=True)
    assert msg.seq > a.links["b"].seq and not msg.delta  # a new epoch; a whole map first
    assert b.deliver(msg)
    reply = b.compose("a", delta=True)  # b saw the new epoch: it resynchronises too
    assert not reply.delta and restored.deliver(reply)
    with pytest.raises(ValueError, match="is agent a's under channel-filter, not b's"):
        checkpoint.restore(tmp_path / "ckpt", Agent("b", "channel-filter", OccupancyMap(0.2)), 3)


# -- a ROS 2 robot behind zenoh-bridge-ros2dds ------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["exact", None])
def test_agents_map_what_a_ros2_bridge_publishes_as_the_bag_would_give_it(bag, tmp_path, mode):
    """Each message of the bag put on the key of its topic without the leading slash, as CDR
    (what zenoh-bridge-ros2dds does with ROS 2 topics): each agent's own map equals the one
    built from the bag, and the agents exchange. By default (no --insert-mode) an agent maps
    the 3D clouds of a live robot in the fast mode: its map then agrees with the exact one
    within the fast mode's bound, and its counts say which mode and how far it fell behind."""
    from rosbags.highlevel import AnyReader

    from octofuse.live.transport import ZenohTransport, endpoint
    from octofuse.maps.build import build, make_build_config

    cfg, path = fleet_config(bag, tmp_path, base_port=20447)
    cfg = replace(cfg, fuse=replace(cfg.fuse, rules=["chernoff"], schedule="periodic:0.5"))
    path.write_text(dump_yaml(cfg))
    out = tmp_path / "agents"
    names = [a.name for a in cfg.build.agents]
    procs = {
        n: subprocess.Popen(
            [
                sys.executable,
                "-m",
                "octofuse",
                "agent",
                n,
                "--fleet",
                str(path),
                "--out",
                str(out),
                "--from-zenoh",
                "pointcloud2",
                *(["--insert-mode", mode] if mode else []),
                "--duration",
                "5",
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
        )
        for n in names
    }
    bridge = ZenohTransport(
        cfg.live,
        "chernoff",
        "bridge",
        endpoint(cfg.live, 9),
        [endpoint(cfg.live, k) for k in range(len(names))],
    )
    try:
        bridge.wait_for(names, 60)
        with AnyReader([Path(bag)]) as reader:
            for conn, _, raw in sorted(reader.messages(), key=lambda m: m[1]):
                bridge.publish(conn.topic.lstrip("/"), bytes(raw))
    finally:
        bridge.close()
    finish(procs)
    own = build(make_build_config(bag, resolution=float(RES))).maps
    for n in names:
        d = out / "chernoff" / n
        counts = json.loads((d / "counts.json").read_text())
        assert counts["scans"] == 4 and counts["applied"] > 0, (n, counts)
        assert counts["insert_mode"] == (mode or "fast") and counts["queued_max"] >= 0
        local = OccupancyMap.load(d / "local.ot")
        if mode == "exact":
            assert local.to_bytes() == own[n].to_bytes(), n
        else:
            q = np.array(local.class_counts(own[n], 0.0)["confusion"])
            occupied = q[0].sum()
            assert q[0, 0] >= 0.95 * occupied and q[1:, 0].sum() <= 0.05 * occupied, (n, q)
            assert q[2, 1] > 0, n  # free between the rays, where the exact map knows nothing
        assert OccupancyMap.load(d / "fused.ot").num_leaves > own[n].num_leaves, n


# -- a fleet seen live --------------------------------------------------------------------------


@pytest.mark.slow
def test_a_viewer_sees_the_agents_maps_grow_and_their_links_deliver(bag, tmp_path):
    from octofuse.view.fleet_source import FleetSource

    cfg, path = fleet_config(bag, tmp_path, speed=1.0, map_period=0.2, base_port=25447)
    cfg = replace(cfg, fuse=replace(cfg.fuse, rules=["chernoff"]))
    path.write_text(dump_yaml(cfg))
    source = FleetSource(cfg)
    seen: dict = {}
    redraws = []
    source.on_change = lambda: redraws.append(source.maps_received())
    try:
        out = tmp_path / "agents"
        procs = {a.name: start_agent(path, a.name, out) for a in cfg.build.agents}
        finish(procs)
        time.sleep(1.5)  # the last maps on their way, the last redraw
        for got in redraws:
            for key, n in got.items():
                seen.setdefault(key, set()).add(n)
        assert {a for _, a in seen} == {a.name for a in cfg.build.agents}
        for a in cfg.build.agents:
            final = OccupancyMap.load(out / "chernoff" / a.name / "fused.ot").num_leaves
            assert source.maps_received()["chernoff", a.name] == final
            assert len(seen["chernoff", a.name]) > 1 and min(seen["chernoff", a.name]) < final
        linked = {(e["sender"], e["receiver"]) for e in source.events}
        assert linked and linked <= {(x, y) for a, b in source.links for x, y in ((a, b), (b, a))}
        assert source.agents_of("chernoff") == [a.name for a in cfg.build.agents]
        assert len(source.occupancy("chernoff", "a").values) > 0
    finally:
        source.close()


@settings(max_examples=60, deadline=None)
@given(st.binary(min_size=0, max_size=3000), st.integers(24, 700), st.randoms())
def test_chunks_put_a_message_together_in_any_order_and_only_whole(frame, size, rnd):
    from octofuse.live.chunks import Reassembler, split

    chunks = split(frame, 7, size)
    assert all(len(c) <= size for c in chunks)
    got = Reassembler(4096)
    order = chunks + chunks[:1]  # a repeat
    rnd.shuffle(order)
    out = [f for c in order if (f := got.add("b", c)) is not None]
    # whole once; a repeated one-chunk message is whole again (the link protocol drops it)
    assert out == [frame] * (2 if len(chunks) == 1 else 1)
    if len(chunks) > 1:  # one chunk missing: never whole
        late = Reassembler(4096)
        assert [late.add("b", c) for c in chunks[1:]] == [None] * (len(chunks) - 1)
    if frame:  # a message over the receiver's bound is refused at its first chunk
        small = Reassembler(len(frame) - 1)
        assert small.add("b", chunks[0]) is None and small.dropped == 1


@pytest.mark.parametrize(
    "partition, said",
    [
        ("1:2:robot1:robot2", "expected START:END:AGENT[,AGENT...]"),
        ("1:2:nobody", "no agent 'nobody' in the fleet"),
    ],
)
def test_a_partition_naming_no_agent_of_the_fleet_is_refused(
    bag, tmp_path, capsys, partition, said
):
    code, _, err = run_cli(
        capsys, "fleet", bag, "--partition", partition, "--out", tmp_path / "fleet"
    )
    assert code != 0 and said in err.strip().splitlines()[-1], err
    assert not (tmp_path / "fleet").exists()
