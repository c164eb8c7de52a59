"""Per-agent and centralized maps from bags (``octofuse build``)."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..config import AgentSpec, BuildConfig, MapConfig
from ..scans.source import AgentStats, Scan, ScanSource, batched, prefetch
from .occupancy import OccupancyMap
from .ray_batches import insert_batch, trace_rays


def insert_scans(
    scans: Sequence[Scan],
    targets: Sequence[Sequence[OccupancyMap]],
    threads: int,
    mode: str = "exact",
) -> None:
    """Insert posed scans into their target maps (``targets[k]`` for ``scans[k]``)."""
    if scans:
        insert_batch(*_scan_arrays(scans), targets, threads, mode)


def trace_scans(scans: Sequence[Scan], grid: OccupancyMap, threads: int, mode: str = "exact"):
    """The posed scans' rays traced once on ``grid``'s grid, to apply to maps with
    :func:`~octofuse.maps.ray_batches.apply_rays`."""
    return trace_rays(grid, *_scan_arrays(scans), threads, mode)


def _scan_arrays(scans: Sequence[Scan]) -> tuple[list, np.ndarray, np.ndarray]:
    """Points, poses and maximum ranges of posed scans, as the core takes them."""
    return (
        [s.points for s in scans],
        np.stack([s.pose for s in scans]),
        np.array([s.max_range for s in scans]),
    )


@dataclass
class BuildResult:
    """Maps and statistics of a build."""

    maps: dict[str, OccupancyMap]
    centralized: OccupancyMap
    stats: list[AgentStats]
    seconds: float = 0.0
    timings: dict[str, float] = field(default_factory=dict)  #: where the time went
    notes: list[str] = field(default_factory=list)  #: skipped transforms and dropped points
    start_ns: int | None = None  #: the bags' first message (None: no messages)
    end_ns: int | None = None  #: and their last

    def all_maps(self) -> dict[str, OccupancyMap]:
        return {**self.maps, "centralized": self.centralized}


def build(
    cfg: BuildConfig,
    progress: Callable[[int, int], None] | None = None,
    *,
    per_scan_transforms: bool = False,
) -> BuildResult:
    """Read the bags and build every agent's map and the centralized map (all scans).

    ``progress(done, total)`` is called with the scans inserted so far.
    ``per_scan_transforms`` looks poses up scan by scan instead of many scans at once (see
    :class:`~octofuse.scans.source.ScanSource`; the maps agree).
    """
    t_start = time.perf_counter()
    with ScanSource(cfg, per_scan_transforms=per_scan_transforms) as src:
        maps = {a.name: OccupancyMap.from_config(cfg.map) for a in src.agents}
        agent_maps = [maps[a.name] for a in src.agents]
        central = OccupancyMap.from_config(cfg.map)
        t_insert = 0.0
        done = 0
        for batch in prefetch(batched(src.scans(), cfg.batch_size)):
            t0 = time.perf_counter()
            insert_scans(
                batch, [(agent_maps[s.agent], central) for s in batch], cfg.workers, cfg.insert_mode
            )
            dt = time.perf_counter() - t0
            t_insert += dt
            n_pts = sum(len(s.points) for s in batch)
            for s in batch:  # attribute insertion time by points
                src.stats[s.agent].seconds += dt * len(s.points) / max(n_pts, 1)
            done += len(batch)
            if progress:
                progress(done, src.total_scans)
        src.check_placed()
        stats, notes = src.stats, src.notes()
        start_ns, end_ns = src.bags.start_ns, src.bags.end_ns
    total = time.perf_counter() - t_start
    timings = {
        "insert (C++, GIL released)": t_insert,
        "read + decode + transforms (overlapped)": sum(s.seconds for s in stats) - t_insert,
    }
    return BuildResult(maps, central, stats, total, timings, notes, start_ns, end_ns)


def build_maps(
    bags,
    agents: Sequence[AgentSpec | str] | None = None,
    fixed_frame: str = "map",
    resolution: float = MapConfig.resolution,
    **options,
) -> dict[str, OccupancyMap]:
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


def make_build_config(
    bags, agents=None, fixed_frame="map", resolution=MapConfig.resolution, **options
) -> BuildConfig:
    """A validated :class:`BuildConfig` from API arguments (what :func:`build_maps` takes)."""
    from ..config import from_dict

    if isinstance(bags, (str, Path)):
        bags = [bags]
    specs = [parse_agent(a) if isinstance(a, str) else a for a in (agents or [])]
    map_keys = {"prob_hit", "prob_miss", "clamping"}
    map_cfg = {
        "resolution": resolution,
        **{k: options.pop(k) for k in list(options) if k in map_keys},
    }
    data = {
        "bags": [str(b) for b in bags],
        "fixed_frame": fixed_frame,
        "map": map_cfg,
        "agents": [{k: v for k, v in vars(s).items() if v is not None} for s in specs],
        **options,
    }
    return from_dict(BuildConfig, data, where="build_maps")


def write_maps(result: BuildResult, out_dir: str | Path) -> list[Path]:
    """Write ``NAME.ot`` for every agent and ``centralized.ot``; returns the paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    return [m.save(out / f"{name}.ot") for name, m in result.all_maps().items()]
