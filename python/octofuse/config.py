"""One typed configuration shared by the CLI, the Python API and saved runs."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import yaml


@dataclass
class AgentSpec:
    """One robot: its scan topic and, optionally, a pose topic instead of tf."""

    name: str
    topic: str
    #: ``nav_msgs/Odometry`` or ``geometry_msgs/PoseStamped`` topic giving the robot's pose
    #: in the fixed frame; when set, tf is not used for this agent.
    pose_topic: Optional[str] = None
    #: static sensor offset on the robot: x y z qx qy qz qw (with ``pose_topic``)
    sensor_offset: Optional[list[float]] = None


@dataclass
class MapConfig:
    """Map parameters (OctoMap's sensor model)."""

    resolution: float = 0.05
    prob_hit: float = 0.7
    prob_miss: float = 0.4
    clamping: tuple[float, float] = (0.1192, 0.971)


@dataclass
class BuildConfig:
    """How scans are read from bags and turned into maps (``octofuse build``)."""

    bags: list[str] = field(default_factory=list)
    #: empty: one agent per scan topic (LaserScan or PointCloud2), named after the topic
    agents: list[AgentSpec] = field(default_factory=list)
    fixed_frame: str = "map"
    map: MapConfig = field(default_factory=MapConfig)
    #: rays longer than this (metres) only clear free space; <= 0: no limit
    max_range: float = -1.0
    #: LaserScan beams with no return: "skip" (default) or "free" (clear up to range_max)
    no_return: str = "skip"
    #: LaserScan with time_increment > 0: place every beam with the pose at its own time
    #: (the robot moves during a sweep); False: the whole scan at header.stamp
    deskew: bool = True
    #: use every N-th scan of each agent (1 = all)
    scan_stride: int = 1
    #: scans inserted per call into the C++ core
    batch_size: int = 32
    #: threads for ray casting (the machine has 2 cores)
    threads: int = 2


@dataclass
class FuseConfig:
    """How maps are exchanged and fused (``octofuse fuse`` / ``run``)."""

    rule: str = "min-info-loss"
    topology: str = "max-robust:3"
    #: "aperiodic:MEAN_S", "periodic:PERIOD_S" (``run``) or "rounds:N" (``fuse``)
    schedule: str = "aperiodic:10"
    directions: str = "both"
    #: send only the voxels changed since the last message on a link
    delta: bool = False
    unknown: str = "copy"
    seed: int = 0
    #: voxels where an agent is more certain than the centralized map by more than this
    #: (in log-odds) count as over-confident
    overconfidence_tol: float = 0.1


@dataclass
class RunConfig:
    """The whole job: build, exchange, fuse, score, export."""

    build: BuildConfig = field(default_factory=BuildConfig)
    fuse: FuseConfig = field(default_factory=FuseConfig)
    out: str = "octofuse-out"


def to_dict(cfg: Any) -> dict:
    """A plain dict (YAML/JSON-ready) of a config dataclass."""
    d = dataclasses.asdict(cfg)
    return _plain(d)


def _plain(x):
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, Path):
        return str(x)
    return x


def from_dict(cls, data: dict, where: str = "config"):
    """Build a config dataclass from a dict, rejecting unknown keys with a clear message."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ValueError(f"{where}: expected a mapping, got {type(data).__name__}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {', '.join(unknown)}; "
                         f"valid keys are {', '.join(fields)}")
    kwargs = {}
    for name, value in data.items():
        f = fields[name]
        sub = _SUBCONFIGS.get((cls, name))
        if sub is not None:
            if name == "agents":
                if not isinstance(value, list):
                    raise ValueError(f"{where}.agents: expected a list of {{name, topic}}")
                value = [from_dict(AgentSpec, v, f"{where}.agents[{i}]") for i, v in enumerate(value)]
            else:
                value = from_dict(sub, value, f"{where}.{name}")
        elif name == "clamping":
            value = tuple(value)
        elif name == "bags":
            if isinstance(value, str):  # one bag
                value = [value]
            if not isinstance(value, list) or not all(isinstance(b, str) for b in value):
                raise ValueError(f"{where}.bags: expected a list of bag paths")
        kwargs[f.name] = value
    return cls(**kwargs)


_SUBCONFIGS = {
    (BuildConfig, "agents"): AgentSpec,
    (BuildConfig, "map"): MapConfig,
    (RunConfig, "build"): BuildConfig,
    (RunConfig, "fuse"): FuseConfig,
}


def load_yaml(path: str | Path, cls=RunConfig):
    """Read a YAML config file into ``cls``; errors name the file and the key."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"config file '{p}' does not exist")
    try:
        data = yaml.safe_load(p.read_text())
    except yaml.YAMLError as e:
        raise ValueError(f"config file '{p}' is not valid YAML: {e}") from None
    return from_dict(cls, data, where=str(p))


def dump_yaml(cfg: Any) -> str:
    return yaml.safe_dump(to_dict(cfg), sort_keys=False)
