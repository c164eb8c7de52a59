"""``octofuse fleet``: one ``octofuse agent`` process per robot and rule on this machine, Zenoh
peers on explicit loopback endpoints, each replaying its robot's scans; then the final maps
collected and scored as ``octofuse run`` scores its own.

The launcher writes the fleet's configuration (``fleet.yaml``: the run's options, the agents
resolved from the bags, the ports) where every agent reads it, builds the centralized map and
the robots' own maps from the bags while the agents run, shows each agent's progress from the
status it publishes, and fails with one line naming the agent (and its log) whose process
failed.
"""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..config import FleetConfig, dump_yaml
from ..fusion.results import SimResult, Traffic, score_result
from ..fusion.schedule import run_schedule
from ..maps.build import build
from ..maps.infoloss import InfoLossMap
from ..maps.occupancy import OccupancyMap
from ..scans.source import ScanSource
from . import keys
from .transport import endpoint


class FleetError(RuntimeError):
    """An agent of the fleet failed (its name and log in the message)."""


def free_base_port(start: int, count: int, host: str = "127.0.0.1") -> int:
    """The first port from ``start`` on with ``count`` free ports after it."""
    port = start
    while port + count < 65000:
        taken = next((p for p in range(port, port + count) if not _free(host, p)), None)
        if taken is None:
            return port
        port = taken + 1
    raise OSError(f"no {count} free ports from {start} on {host}")


def _free(host: str, port: int) -> bool:
    with socket.socket() as s:
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


def resolved(cfg: FleetConfig) -> FleetConfig:
    """``cfg`` with the agents named from the bags (every agent reads the same list) and a
    block of free ports."""
    with ScanSource(cfg.build) as src:
        agents = list(src.agents)
    names = {a.name for a in agents}
    for p in cfg.live.faults.partitions:
        unknown = [a for a in p.agents if a not in names]
        if unknown:
            raise ValueError(
                f"faults.partitions: no agent {unknown[0]!r} in the fleet; its agents are "
                f"{', '.join(sorted(names))}"
            )
    n = len(agents) * len(cfg.fuse.rules)
    # the agents' ports, then the launcher's and a live viewer's
    live = replace(cfg.live, base_port=free_base_port(cfg.live.base_port, n + 2, cfg.live.host))
    return replace(cfg, build=replace(cfg.build, agents=agents), live=live)


def run_fleet(
    cfg: FleetConfig,
    stage: Path,
    *,
    log: Callable[[str], None] = print,
    truth=None,
    status_every: float = 5.0,
) -> SimResult:
    """Launch the fleet of ``cfg`` (agents resolved: :func:`resolved`), wait for it, and return
    its result with the scores of ``octofuse run``. Logs and maps go below ``stage``."""
    names = [a.name for a in cfg.build.agents]
    rules = list(cfg.fuse.rules)
    fleet_file = stage / "fleet.yaml"
    fleet_file.write_text(dump_yaml(cfg))
    agents_dir, logs = stage / "agents", stage / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    procs: dict[tuple[str, str], subprocess.Popen] = {}
    t0 = time.perf_counter()
    status: dict[tuple[str, str], dict] = {}
    watcher = _watch_status(cfg, names, status)
    try:
        for rule in rules:
            for name in names:
                with open(logs / f"{rule}-{name}.log", "wb") as out:
                    procs[rule, name] = subprocess.Popen(
                        [
                            sys.executable,
                            "-m",
                            "octofuse",
                            "agent",
                            name,
                            "--fleet",
                            str(fleet_file),
                            "--rule",
                            rule,
                            "--out",
                            str(agents_dir),
                            "--fresh",
                        ],
                        stdout=out,
                        stderr=subprocess.STDOUT,
                        stdin=subprocess.DEVNULL,
                    )
        log(
            f"fleet {cfg.live.fleet}: {len(procs)} agent process(es), {len(names)} robots x "
            f"{len(rules)} rule(s), Zenoh on {endpoint(cfg.live, 0)} and up"
        )
        built = build(cfg.build)  # the centralized map and the robots' own maps, meanwhile
        _wait(procs, logs, log, status, status_every)
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait()
        watcher.close()
    wall = time.perf_counter() - t0
    return _collect(cfg, names, rules, agents_dir, built, truth, wall)


def _wait(procs, logs: Path, log, status: dict, every: float) -> None:
    next_report = time.monotonic() + every
    while True:
        running = [k for k, p in procs.items() if p.poll() is None]
        failed = [k for k, p in procs.items() if p.poll() not in (None, 0)]
        if failed:
            rule, name = failed[0]
            tail = (logs / f"{rule}-{name}.log").read_text(errors="replace").strip().splitlines()
            raise FleetError(
                f"agent {name} ({rule}) exited with code "
                f"{procs[failed[0]].returncode}: {tail[-1] if tail else 'no output'} "
                f"(log: {logs / f'{rule}-{name}.log'})"
            )
        if not running:
            return
        if time.monotonic() >= next_report:
            next_report = time.monotonic() + every
            log(progress_line(status))
        time.sleep(0.2)


def progress_line(status: dict) -> str:
    """One line of the agents' published states: mission time, scans, messages, links."""
    if not status:
        return "fleet: waiting for the agents' first status"
    parts = []
    for (rule, name), s in sorted(status.items()):
        links = " ".join(f"{n}:{v['seq']}/{v['applied']}" for n, v in sorted(s["links"].items()))
        parts.append(
            f"{name}[{rule}] t={s['t']:.1f} scans={s['scans']} sent={s['sent']} "
            f"applied={s['applied']} refused={s['refused']} links(sent/applied) {links}"
        )
    return "fleet: " + "; ".join(parts)


def _watch_status(cfg: FleetConfig, names: list[str], status: dict):
    """A Zenoh session of the launcher's own, connected to every agent, that keeps the last
    status of each."""
    from .transport import open_session

    n = len(names) * len(cfg.fuse.rules)
    session = open_session(
        cfg.live, endpoint(cfg.live, n), [endpoint(cfg.live, k) for k in range(n)], "the launcher"
    )
    lock = threading.Lock()

    def on_status(sample) -> None:
        try:
            s = json.loads(sample.payload.to_bytes())
            with lock:
                status[s["rule"], s["agent"]] = s
        except (ValueError, KeyError):
            pass

    sub = session.declare_subscriber(keys.statuses(cfg.live.fleet), on_status)

    class Watcher:
        def close(self) -> None:
            sub.undeclare()
            session.close()

    return Watcher()


def _collect(
    cfg: FleetConfig, names, rules, agents_dir: Path, built, truth, wall: float
) -> SimResult:
    """The fleet's result: every agent's final map, loss leaves and traffic, scored."""
    graph, _, events = run_schedule(cfg.fuse, names, built.start_ns, built.end_ns)
    fused, leaves, traffic = {}, {}, {}
    for r in rules:
        fused[r], leaves[r], traffic[r] = {}, {}, Traffic()
        for a in names:
            d = agents_dir / r / a
            fused[r][a] = OccupancyMap.load(d / "fused.ot")
            with np.load(d / "loss.npz") as z:
                leaves[r][a] = (z["values"], z["depths"])
            counts = json.loads((d / "counts.json").read_text())
            tr = traffic[r]
            tr.sent[a] += counts["bytes_sent"]
            tr.received[a] += counts["bytes_received"]
            tr.sent_32b[a] += counts["sent_32b"]
            tr.messages += counts["sent"]
    res = SimResult(
        names,
        rules,
        graph,
        events,
        built.centralized,
        built.maps,
        fused,
        {r: {a: InfoLossMap(cfg.build.map.resolution) for a in names} for r in rules},
        traffic,
        build_stats=built.stats,
        build_notes=built.notes,
        loss_leaves=leaves,
    )
    res.timings["fleet (wall)"] = wall
    res.scores = score_result(res, cfg.fuse.overconfidence_tol, truth, cfg.build.workers)
    return res


def agent_counts(agents_dir: Path, rule: str, name: str) -> dict | None:
    """What agent ``name`` of ``rule`` wrote of its counts, if it finished."""
    p = Path(agents_dir) / rule / name / "counts.json"
    return json.loads(p.read_text()) if p.is_file() else None
