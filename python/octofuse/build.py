"""Per-agent and centralized maps from bags (``octofuse build``)."""

from __future__ import annotations

import queue
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Iterator, Optional, Sequence

import numpy as np

from . import _core
from .config import AgentSpec, BuildConfig, MapConfig
from .ingest import AgentStats, Scan, ScanSource
from .maps import OccupancyMap


def new_map(cfg: MapConfig) -> OccupancyMap:
    return OccupancyMap(cfg.resolution, cfg.prob_hit, cfg.prob_miss, tuple(cfg.clamping))


def insert_scans(scans: Sequence[Scan], targets: Sequence[Sequence[OccupancyMap]],
                 threads: int = 2) -> None:
    """Insert scans (sensor frame + pose) into their target maps in one C++ call.

    Each scan's ray keys are computed once (scans in parallel) and applied to each of its
    targets, different maps in parallel; the result equals OctoMap's insertPointCloud of
    every scan into every target, in order. The GIL is released.
    """
    if not scans:
        return
    _core._insert_batch([[m._m for m in t] for t in targets],
                        [np.ascontiguousarray(s.points) for s in scans],
                        np.stack([s.pose for s in scans]),
                        np.array([s.max_range for s in scans], dtype=np.float64),
                        int(threads))


def batched(source: Iterable[Scan], size: int) -> Iterator[list[Scan]]:
    batch: list[Scan] = []
    for s in source:
        batch.append(s)
        if len(batch) >= size:
            yield batch
            batch = []
    if batch:
        yield batch


def prefetch(it: Iterator, depth: int = 4) -> Iterator:
    """Run an iterator in a background thread (decoding overlaps C++ insertion)."""
    q: queue.Queue = queue.Queue(maxsize=depth)
    done = object()
    stop = threading.Event()

    def run():
        try:
            for item in it:
                if stop.is_set():
                    return
                q.put(item)
            q.put(done)
        except BaseException as e:  # handed to the consumer
            q.put(e)

    t = threading.Thread(target=run, daemon=True, name="octofuse-prefetch")
    t.start()
    try:
        while True:
            item = q.get()
            if item is done:
                return
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        while t.is_alive():  # unblock the producer
            try:
                q.get_nowait()
            except queue.Empty:
                t.join(0.05)


@dataclass
class BuildResult:
    """Maps and statistics of a build."""

    maps: dict[str, OccupancyMap]
    centralized: OccupancyMap
    stats: list[AgentStats]
    seconds: float = 0.0
    timings: dict[str, float] = field(default_factory=dict)  #: where the time went

    def all_maps(self) -> dict[str, OccupancyMap]:
        return {**self.maps, "centralized": self.centralized}


def build(cfg: BuildConfig, progress: Optional[Callable[[int], None]] = None) -> BuildResult:
    """Read the bags and build every agent's map and the centralized map (all scans)."""
    t_start = time.perf_counter()
    with ScanSource(cfg) as src:
        maps = {a.name: new_map(cfg.map) for a in src.agents}
        agent_maps = [maps[a.name] for a in src.agents]
        central = new_map(cfg.map)
        t_insert = 0.0
        for batch in prefetch(batched(src.scans(), cfg.batch_size)):
            t0 = time.perf_counter()
            insert_scans(batch, [(agent_maps[s.agent], central) for s in batch], cfg.threads)
            dt = time.perf_counter() - t0
            t_insert += dt
            n_pts = sum(len(s.points) for s in batch)
            for s in batch:  # attribute insertion time by points
                src.stats[s.agent].seconds += dt * len(s.points) / max(n_pts, 1)
            if progress:
                progress(len(batch))
        src.check_placed()
        stats = src.stats
    total = time.perf_counter() - t_start
    timings = {"insert (C++, GIL released)": t_insert,
               "read + decode + transforms (overlapped)": sum(s.seconds for s in stats) - t_insert}
    return BuildResult(maps, central, stats, total, timings)


def build_maps(bags, agents: Optional[Sequence[AgentSpec | str]] = None, fixed_frame: str = "map",
               resolution: float = 0.05, **options) -> dict[str, OccupancyMap]:
    """Build one map per agent and the centralized map from bag files.

    Parameters
    ----------
    bags : path or list of paths
        ROS 1 ``.bag`` files, ROS 2 bag folders or ``.mcap``/``.db3`` files.
    agents : list of AgentSpec or "NAME=TOPIC" strings, optional
        Default: one agent per LaserScan/PointCloud2 topic, named after its namespace.
    fixed_frame : str
        The frame the maps are built in (looked up through /tf and /tf_static).
    resolution : float
        Voxel size, metres.
    **options
        Further :class:`~octofuse.config.BuildConfig` fields (``max_range``,
        ``no_return``, ``scan_stride``, ...).

    Returns
    -------
    dict of str to OccupancyMap
        Every agent's map, and the centralized map under ``"centralized"``.
    """
    cfg = make_build_config(bags, agents, fixed_frame, resolution, **options)
    return build(cfg).all_maps()


def parse_agent(spec: str) -> AgentSpec:
    name, sep, topic = spec.partition("=")
    if not sep or not name or not topic:
        raise ValueError(f"agent {spec!r}: expected NAME=TOPIC, e.g. robot1=/robot1/scan")
    return AgentSpec(name.strip(), topic.strip())


def make_build_config(bags, agents=None, fixed_frame="map", resolution=0.05, **options) -> BuildConfig:
    if isinstance(bags, (str, Path)):
        bags = [bags]
    specs = [parse_agent(a) if isinstance(a, str) else a for a in (agents or [])]
    map_keys = {"prob_hit", "prob_miss", "clamping"}
    mcfg = MapConfig(resolution=resolution, **{k: options.pop(k) for k in list(options) if k in map_keys})
    return BuildConfig(bags=[str(b) for b in bags], agents=specs, fixed_frame=fixed_frame,
                       map=mcfg, **options)


def write_maps(result: BuildResult, out_dir: str | Path) -> list[Path]:
    """Write ``NAME.ot`` for every agent and ``centralized.ot``; returns the paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    return [m.save(out / f"{name}.ot") for name, m in result.all_maps().items()]
