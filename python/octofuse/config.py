"""One typed configuration shared by the CLI, the Python API and saved runs.

Every value has one route: YAML files and command-line flags are merged as plain data and
turned into these dataclasses by :func:`from_dict`, which checks each value's type and range
once and names the file and key of a bad one. ``octofuse ... --dump-config`` writes the
merged result; feeding it back (``--config``, or :func:`load_yaml` to the API) gives the same run.
"""

from __future__ import annotations

import contextvars
import dataclasses
import functools
import math
import re
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from . import _core
from .rule_names import EXACT_RULES, FusionRule, parse_rules

#: the most threads a config may ask for (the core's limit; the machine's cores are the
#: useful number)
MAX_THREADS = _core.MAX_THREADS

#: exact fusion by channel filters on a tree of the graph (:mod:`octofuse.fusion.channel_filter`):
#: a fusion mode accepted in ``FuseConfig.rules`` beside the per-voxel rules (not part of "all")
CHANNEL_FILTER = FusionRule.CHANNEL_FILTER
#: exact fusion on any graph by per-source map layers (:mod:`octofuse.fusion.source_layers`):
#: a fusion mode beside the channel filter (not part of "all")
SOURCE_LAYERS = FusionRule.SOURCE_LAYERS
#: the fusion modes that keep unclamped maps, lose no information and need one frame
EXACT_MODES = EXACT_RULES

#: where the section being built sits in its file (set by :func:`from_dict` while it builds)
_WHERE: contextvars.ContextVar[str | None] = contextvars.ContextVar("where", default=None)


class Checked:
    """A section of the configuration, checked once when it is made: from a file or flags
    (:func:`from_dict`, errors naming the file and key) or in Python (errors naming the
    section). The layers that take a configuration trust it. Each section's ``validate``
    checks its own values; its subsections were checked when they were made."""

    #: the section's name in an error of a section made in Python
    SECTION = "config"

    def __post_init__(self) -> None:
        self.validate(_WHERE.get() or self.SECTION)


#: how the channel filter's tree is chosen on a graph with loops: a breadth-first tree from a
#: centre of the graph, or the topology itself (which must then be a tree); or a graph file
SPANNING_TREES = ("bfs", "given")
#: what a run writes per rule and exported agent (``RunConfig.export``), and heat-map formats
EXPORTS = ("all", "fused", "none")
HEATMAP_FORMATS = ("ply", "pcd")
#: how scans go into a map: OctoMap's insertPointCloud voxel for voxel, or the real-time mode
INSERT_MODES = ("exact", "fast")


@dataclass
class AgentSpec(Checked):
    """One robot: its scan topic and, optionally, a pose topic instead of tf."""

    SECTION = "agent"

    name: str
    topic: str
    #: topic giving the robot's pose in the fixed frame (``nav_msgs/Odometry``, or
    #: ``geometry_msgs/`` ``PoseStamped``, ``PoseWithCovarianceStamped`` or
    #: ``TransformStamped``); when set, tf is not used for this agent.
    pose_topic: str | None = None
    #: static sensor offset on the robot: x y z qx qy qz qw (with ``pose_topic``)
    sensor_offset: list[float] | None = None

    def validate(self, where: str) -> None:
        if not self.name or "/" in self.name or self.name == "centralized":
            raise ValueError(
                f"{where}.name = {self.name!r}: expected a name without '/' "
                "('centralized' is reserved)"
            )
        if not self.topic:
            raise ValueError(f"{where}.topic: expected the agent's scan topic")
        if self.sensor_offset is not None and len(self.sensor_offset) != 7:
            raise ValueError(f"{where}.sensor_offset: expected 7 numbers x y z qx qy qz qw")


@dataclass
class MapConfig(Checked):
    """Map parameters (OctoMap's sensor model)."""

    SECTION = "map"

    resolution: float = _core.DEFAULT_MAP["resolution"]  # the core's defaults: one source
    prob_hit: float = _core.DEFAULT_MAP["prob_hit"]
    prob_miss: float = _core.DEFAULT_MAP["prob_miss"]
    clamping: tuple[float, float] = (_core.DEFAULT_MAP["clamp_min"], _core.DEFAULT_MAP["clamp_max"])

    def validate(self, where: str) -> None:
        if not _core.MIN_RESOLUTION <= self.resolution <= _core.MAX_RESOLUTION:
            raise ValueError(
                f"{where}.resolution = {self.resolution}: expected a voxel size "
                f"from {_core.MIN_RESOLUTION:g} to {_core.MAX_RESOLUTION:g} metres"
            )
        if not 0.5 < self.prob_hit < 1.0:
            raise ValueError(f"{where}.prob_hit = {self.prob_hit}: expected 0.5 < p < 1")
        if not 0.0 < self.prob_miss < 0.5:
            raise ValueError(f"{where}.prob_miss = {self.prob_miss}: expected 0 < p < 0.5")
        lo, hi = self.clamping
        if not 0.0 < lo < 0.5 < hi < 1.0:
            raise ValueError(
                f"{where}.clamping = {list(self.clamping)}: expected two "
                "probabilities min < 0.5 < max"
            )


@dataclass
class BuildConfig(Checked):
    """How scans are read from bags and turned into maps (``octofuse build``)."""

    SECTION = "build"

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
    #: threads for ray casting and fusion; 0: one per core of the machine
    threads: int = 0
    #: "exact" (OctoMap's insertPointCloud) or "fast" (real time for dense 3D lidar scans)
    insert_mode: str = "exact"

    def validate(self, where: str) -> None:
        if self.no_return not in ("skip", "free"):
            raise ValueError(f"{where}.no_return = {self.no_return!r}: expected 'skip' or 'free'")
        if not self.fixed_frame.strip("/"):
            raise ValueError(f"{where}.fixed_frame: expected a frame name")
        if not math.isfinite(self.max_range):
            raise ValueError(f"{where}.max_range = {self.max_range}: expected a finite number")
        if self.scan_stride < 1:
            raise ValueError(f"{where}.scan_stride = {self.scan_stride}: expected 1 or more")
        if not 1 <= self.batch_size <= 4096:
            raise ValueError(f"{where}.batch_size = {self.batch_size}: expected 1 to 4096")
        if self.insert_mode not in INSERT_MODES:
            raise ValueError(
                f"{where}.insert_mode = {self.insert_mode!r}: expected 'exact' or 'fast'"
            )
        if not 0 <= self.threads <= MAX_THREADS:
            raise ValueError(
                f"{where}.threads = {self.threads}: expected 0 (one per core) to {MAX_THREADS}"
            )

    @property
    def workers(self) -> int:
        """The number of threads to use (0: the core's count of the machine's threads)."""
        return self.threads or _core.default_threads()


@dataclass
class RobustConfig(Checked):
    """Robust fusion: the robots measure their maps' offsets to their neighbours' maps and
    vote out a robot whose map is wrong (:mod:`octofuse.fusion.robust`)."""

    SECTION = "robust"

    enabled: bool = False
    #: when the vote takes place, seconds after the start of the bags
    time: float = 60.0
    #: exchange no maps before the vote (nothing of a wrong map is fused before it is found)
    hold: bool = True
    #: expected fraction of correctly localised robots and wanted success probability (these
    #: set the number of hypotheses), consensus iterations, confidence of the chi-square test
    p_in: float = 0.8
    success: float = 0.99
    iterations: int = 100
    confidence: float = 0.95

    def validate(self, where: str) -> None:
        if not (math.isfinite(self.time) and self.time >= 0):
            raise ValueError(f"{where}.time = {self.time}: expected seconds >= 0")
        for name in ("p_in", "success", "confidence"):
            if not 0.0 < getattr(self, name) < 1.0:
                raise ValueError(
                    f"{where}.{name} = {getattr(self, name)}: expected a "
                    "probability strictly between 0 and 1"
                )
        if not 1 <= self.iterations <= 100_000:
            raise ValueError(f"{where}.iterations = {self.iterations}: expected 1 to 100000")


@dataclass
class AgentFrame(Checked):
    """An agent's map frame: the rigid transform taking a point of agent ``name``'s map frame
    into the common frame, as ``x, y, z`` (metres) and ``roll, pitch, yaw`` (radians)."""

    SECTION = "agent_frame"

    name: str
    pose: list[float]

    def validate(self, where: str) -> None:
        if not self.name:
            raise ValueError(f"{where}.name: expected an agent's name")
        if len(self.pose) != 6 or not all(math.isfinite(v) for v in self.pose):
            raise ValueError(
                f"{where}.pose = {self.pose}: expected 6 finite numbers x, y, z, "
                "roll, pitch, yaw (metres, radians)"
            )


#: alignment of a link on first contact (``FuseConfig.align``): none, x y z + yaw, or 6-DoF
ALIGN_MODES = ("off", "planar", "full")


@dataclass
class FuseConfig(Checked):
    """How maps are exchanged and fused (``octofuse fuse`` / ``run``)."""

    SECTION = "fuse"

    #: fusion rules run side by side (each on its own copy of every agent's map); made from
    #: names (a comma-separated text or a list; "all": every per-voxel rule)
    rules: tuple[FusionRule, ...] = (FusionRule.MIN_INFO_LOSS,)
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
    #: robust fusion by dynamic voting (``run``)
    robust: RobustConfig = field(default_factory=RobustConfig)
    #: the tree the channel filter runs on: "bfs", "given" (the topology is a tree) or a file
    #: with the tree's links (a subgraph of the topology); the other rules use every link
    spanning_tree: str = "bfs"
    #: probability that a message is lost (drawn once per message from ``seed``, the same
    #: messages for every rule)
    loss: float = 0.0
    #: the agents' own map frames (agents not listed are in the common frame)
    agent_frames: list[AgentFrame] = field(default_factory=list)
    #: estimate each link's transform on first contact: off, planar (x, y, z, yaw) or full
    align: str = "off"
    #: ``run``: the rules whose maps are held at once; more rules map the scans once per
    #: group of this many (memory for time). 0: all in one
    rules_per_pass: int = 0
    #: ``source-layers``: bytes of layers an agent holds before it folds the oldest into one
    #: conservative remainder (exact no more); 0: unlimited
    layers_max_bytes: int = 0

    def validate(self, where: str) -> None:
        self.rules = parse_rules(self.rules, f"{where}.rules")
        policies = _core.UNKNOWN_POLICY_NAMES
        if self.unknown not in policies:
            raise ValueError(
                f"{where}.unknown = {self.unknown!r}: expected one of {', '.join(policies)}"
            )
        if self.directions not in ("both", "one"):
            raise ValueError(f"{where}.directions = {self.directions!r}: expected both or one")
        if not (math.isfinite(self.overconfidence_tol) and self.overconfidence_tol >= 0):
            raise ValueError(
                f"{where}.overconfidence_tol = {self.overconfidence_tol}: expected a number >= 0"
            )
        if self.rules_per_pass < 0:
            raise ValueError(
                f"{where}.rules_per_pass = {self.rules_per_pass}: expected 0 or more "
                "rules (0: every rule in one pass)"
            )
        if self.layers_max_bytes < 0:
            raise ValueError(
                f"{where}.layers_max_bytes = {self.layers_max_bytes}: expected 0 "
                "(unlimited) or more bytes"
            )
        if not (math.isfinite(self.loss) and 0.0 <= self.loss < 1.0):
            raise ValueError(
                f"{where}.loss = {self.loss}: expected a probability from 0 to below 1"
            )
        tree = str(self.spanning_tree).strip()
        if not tree or (tree not in SPANNING_TREES and not Path(tree).suffix):
            raise ValueError(
                f"{where}.spanning_tree = {self.spanning_tree!r}: expected "
                f"{' or '.join(SPANNING_TREES)}, or a graph file with the tree's links"
            )
        self.spanning_tree = tree
        self._validate_frames(where)

    @property
    def own_frames(self) -> list[str]:
        """Agents whose map frame is not the common frame (a pose other than all zeros)."""
        return [f.name for f in self.agent_frames if any(v != 0 for v in f.pose)]

    def _validate_frames(self, where: str) -> None:
        seen: set[str] = set()
        for f in self.agent_frames:
            if f.name in seen:
                raise ValueError(f"{where}.agent_frames: agent '{f.name}' is given twice")
            seen.add(f.name)
        if self.align not in ALIGN_MODES:
            raise ValueError(
                f"{where}.align = {self.align!r}: expected one of {', '.join(ALIGN_MODES)}"
            )
        moved = self.own_frames
        if not moved and self.align == "off":
            return
        why = f"agent '{moved[0]}' has a frame of its own" if moved else f"align = {self.align}"
        for exact in EXACT_MODES:
            if exact in self.rules:
                raise ValueError(
                    f"{where}: the {exact} rule needs every agent in one frame "
                    f"(its arithmetic on resampled maps is not exact), but {why}"
                )
        if self.robust.enabled and self.align != "off":
            raise ValueError(
                f"{where}: robust fusion measures the maps' offsets itself (in "
                f"the common frame, each map moved by its agent's frame), but "
                f"align = {self.align}"
            )


@dataclass
class RunConfig(Checked):
    """The whole job: build, exchange, fuse, score, export."""

    build: BuildConfig = field(default_factory=BuildConfig)
    fuse: FuseConfig = field(default_factory=FuseConfig)
    out: str = "octofuse-out"
    #: points in time at which KL to the centralized map is recorded
    samples: int = 12
    #: agents whose fused maps and heat maps are written: all, first, none or names
    export_agents: str = "all"
    #: what is written per rule and exported agent: all (fused map and heat maps), fused
    #: (fused map only) or none (report, summary and plots only)
    export: str = "all"
    #: file formats of the heat maps: ply, pcd
    formats: list[str] = field(default_factory=lambda: ["ply"])
    #: scene ground truth JSON (default: NAME_scene.json beside the first bag)
    truth: str | None = None

    def validate(self, where: str) -> None:
        if not 0 <= self.samples <= 10_000:
            raise ValueError(f"{where}.samples = {self.samples}: expected 0 to 10000")
        if self.export not in EXPORTS:
            raise ValueError(
                f"{where}.export = {self.export!r}: expected one of {', '.join(EXPORTS)}"
            )
        names = [x.strip() for f in self.formats for x in str(f).split(",") if x.strip()]
        bad = [x for x in names if x not in HEATMAP_FORMATS]
        if bad or not names:
            raise ValueError(
                f"{where}.formats = {self.formats!r}: expected one or more of "
                f"{', '.join(HEATMAP_FORMATS)}"
            )
        self.formats = list(dict.fromkeys(names))


@dataclass
class PartitionConfig(Checked):
    """A partition of a live fleet: from ``start`` to ``end`` (seconds of mission time) the
    agents ``agents`` hear nothing from the others and the others nothing from them."""

    SECTION = "partition"

    start: float
    end: float
    agents: list[str] = field(default_factory=list)

    def validate(self, where: str) -> None:
        if not 0 <= self.start < self.end:
            raise ValueError(
                f"{where}: start {self.start} and end {self.end}: expected "
                "0 <= start < end (seconds)"
            )
        if not self.agents:
            raise ValueError(f"{where}.agents: name the agents cut off from the others")


@dataclass
class FaultConfig(Checked):
    """Faults a live fleet's links inject where messages leave an agent (seeded per agent):
    each message is lost, duplicated or held back (reordered behind the next) with these
    probabilities, and delayed by a uniform 0 to ``delay`` seconds."""

    SECTION = "faults"

    loss: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    delay: float = 0.0
    partitions: list[PartitionConfig] = field(default_factory=list)
    seed: int = 0

    def validate(self, where: str) -> None:
        for name in ("loss", "duplicate", "reorder"):
            if not 0.0 <= getattr(self, name) < 1.0:
                raise ValueError(
                    f"{where}.{name} = {getattr(self, name)}: expected a "
                    "probability from 0 to below 1"
                )
        if not 0.0 <= self.delay <= 60.0:
            raise ValueError(f"{where}.delay = {self.delay}: expected 0 to 60 seconds")

    @property
    def any(self) -> bool:
        return bool(self.loss or self.duplicate or self.reorder or self.delay or self.partitions)


@dataclass
class LiveConfig(Checked):
    """A live fleet: one ``octofuse agent`` process per robot and rule, exchanging over Zenoh
    (:mod:`octofuse.live`)."""

    SECTION = "live"

    #: the fleet's name: its Zenoh keys are under ``octofuse/<fleet>/``
    fleet: str = "octofuse"
    #: agent k (in the agents' order) listens on ``tcp/<host>:<base_port + k>`` (``tls/`` with
    #: TLS); one port per agent and rule
    host: str = "127.0.0.1"
    base_port: int = 7447
    #: replay speed of the bags (1: their recorded rate)
    speed: float = 1.0
    #: hold every agent at each exchange time until its messages of that time have arrived:
    #: the fleet's maps are then those of ``octofuse run`` with the same schedule
    lockstep: bool = False
    #: seconds of mission time between checkpoints of an agent's state (0: none)
    checkpoint_period: float = 5.0
    #: the largest message an agent takes (bytes); larger ones are dropped and counted
    max_message_bytes: int = 256 * 2**20
    #: messages go over the links in chunks of at most this many bytes
    max_chunk_bytes: int = 64 * 2**10
    #: bytes a link may carry per second, each direction (e.g. ``2MB/s``; empty: no limit): a
    #: delta that does not fit sends its most informative voxels and keeps the rest for later
    link_budget: str = ""
    #: seconds an agent waits for a neighbour (to appear, or in lockstep for its message)
    timeout: float = 120.0
    #: after the mission, rounds of fault-free exchanges in which the fleet settles
    settle_rounds: int = 0
    #: seconds between an agent's publications of its fused map (0: only at the end)
    map_period: float = 2.0
    faults: FaultConfig = field(default_factory=FaultConfig)
    #: TLS (PEM files): the certificate authority, this machine's certificate and key
    tls_root_ca: str = ""
    tls_certificate: str = ""
    tls_private_key: str = ""
    #: Zenoh user/password authentication: this agent's user and password, and the file of
    #: accepted ``user:password`` lines
    user: str = ""
    password: str = ""
    users_file: str = ""

    def validate(self, where: str) -> None:
        if not self.fleet or "/" in self.fleet or any(c in self.fleet for c in "*$?#"):
            raise ValueError(
                f"{where}.fleet = {self.fleet!r}: expected a name without '/', '*', '$', '?' or '#'"
            )
        if not 1 <= self.base_port <= 65000:
            raise ValueError(f"{where}.base_port = {self.base_port}: expected 1 to 65000")
        if not (math.isfinite(self.speed) and 0 < self.speed <= 1000):
            raise ValueError(f"{where}.speed = {self.speed}: expected above 0, up to 1000")
        if not 0 <= self.checkpoint_period <= 86400:
            raise ValueError(
                f"{where}.checkpoint_period = {self.checkpoint_period}: expected 0 "
                "(none) to 86400 seconds"
            )
        if not 1024 <= self.max_message_bytes <= 2**32 - 1:
            raise ValueError(
                f"{where}.max_message_bytes = {self.max_message_bytes}: expected 1024 to 4 GiB"
            )
        if not 256 <= self.max_chunk_bytes <= self.max_message_bytes:
            raise ValueError(
                f"{where}.max_chunk_bytes = {self.max_chunk_bytes}: expected 256 "
                f"to max_message_bytes ({self.max_message_bytes})"
            )
        try:
            self.budget_bytes_per_s  # noqa: B018 - parsed here, once, to name a bad value
        except ValueError as e:
            raise ValueError(f"{where}.link_budget = {self.link_budget!r}: {e}") from None
        if not 0 < self.timeout <= 3600:
            raise ValueError(f"{where}.timeout = {self.timeout}: expected above 0, up to 3600 s")
        if not 0 <= self.map_period <= 3600:
            raise ValueError(
                f"{where}.map_period = {self.map_period}: expected 0 (only at the "
                "end) to 3600 seconds"
            )
        if not 0 <= self.settle_rounds <= 1000:
            raise ValueError(f"{where}.settle_rounds = {self.settle_rounds}: expected 0 to 1000")
        if self.lockstep and self.faults.any:
            raise ValueError(
                f"{where}: lockstep waits for every message of the schedule, which "
                "injected faults would lose; use fuse.loss for lost messages"
            )
        if self.lockstep and self.budget_bytes_per_s:
            raise ValueError(
                f"{where}: lockstep waits for every message of the schedule, which "
                "link_budget may hold back"
            )
        tls = [self.tls_root_ca, self.tls_certificate, self.tls_private_key]
        if any(tls) and not all(tls):
            raise ValueError(
                f"{where}: TLS needs tls_root_ca, tls_certificate and tls_private_key together"
            )
        for name in ("tls_root_ca", "tls_certificate", "tls_private_key", "users_file"):
            path = getattr(self, name)
            if path and not Path(path).is_file():
                raise ValueError(f"{where}.{name}: file '{path}' does not exist")
        if bool(self.user) != bool(self.password):
            raise ValueError(f"{where}: authentication needs both user and password")

    @property
    def scheme(self) -> str:
        return "tls" if self.tls_root_ca else "tcp"

    @functools.cached_property
    def budget_bytes_per_s(self) -> int:
        """:attr:`link_budget` in bytes per second (0: no limit)."""
        text = self.link_budget.strip()
        if not text:
            return 0
        size, sep, per = text.rpartition("/")
        if not sep or per.strip() != "s":
            raise ValueError("expected a size per second such as 2MB/s or 500kB/s")
        rate = parse_bytes(size)
        if rate < 1024:  # a message's header and map stream alone take a few hundred bytes
            raise ValueError(f"{rate} bytes per second: expected at least 1024 (1KiB/s)")
        return rate


#: units of byte sizes (SI and binary); case matters only between b and B ("kB" = "KB")
_BYTE_UNITS = {
    "B": 1,
    "KB": 10**3,
    "MB": 10**6,
    "GB": 10**9,
    "KIB": 2**10,
    "MIB": 2**20,
    "GIB": 2**30,
}


def parse_bytes(text: str) -> int:
    """A byte size such as ``2MB``, ``64KiB``, ``500kB`` or ``1200`` (bytes), as bytes;
    ``ValueError`` saying what was expected otherwise."""
    m = re.fullmatch(r"\s*(\d+(?:\.\d*)?|\.\d+)\s*([A-Za-z]*)\s*", str(text))
    unit = m and (m.group(2).upper() or "B")
    if not m or unit not in _BYTE_UNITS or m.group(2).endswith("b"):
        raise ValueError(
            f"{text!r} is not a byte size: expected a number and a unit "
            "(B, kB, MB, GB, KiB, MiB, GiB), e.g. 2MB"
        )
    return int(float(m.group(1)) * _BYTE_UNITS[unit])


@dataclass
class FleetConfig(RunConfig):
    """A run as a live fleet: the run's configuration and how its agents meet."""

    live: LiveConfig = field(default_factory=LiveConfig)

    def validate(self, where: str) -> None:
        super().validate(where)
        if self.fuse.robust.enabled:
            raise ValueError(
                f"{where}.fuse.robust: a live fleet has no place where every "
                "robot's map meets to vote; run robust fusion with `run`"
            )
        if self.fuse.align != "off" or self.fuse.own_frames:
            raise ValueError(
                f"{where}.fuse: a live fleet maps every robot in the common frame "
                "for now; agent frames and alignment run in `run` and the swarm"
            )
        if self.live.budget_bytes_per_s:
            if not self.fuse.delta:
                raise ValueError(
                    f"{where}.live.link_budget: a budget sends what does not fit in a later "
                    "message, as deltas do; set fuse.delta (--delta)"
                )
            if SOURCE_LAYERS in self.fuse.rules:
                raise ValueError(
                    f"{where}.live.link_budget: source layers send versions of whole layers, "
                    "which a budget cannot cut; run them without link_budget"
                )


# ------------------------------------------------------------------------------ plain data


def to_dict(cfg: Any) -> dict:
    """A plain dict (YAML/JSON-ready) of a config dataclass."""
    return _plain(dataclasses.asdict(cfg))


def _plain(x):
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, (Path, str)):  # a rule's name as plain text
        return str(x)
    return x


def from_dict(cls, data: Any, where: str = "config"):
    """Build a config dataclass from plain data, each section checked as it is made.

    Unknown keys, values of the wrong type and values out of range raise ``ValueError``
    naming ``where`` and the key.
    """
    return _build(cls, data, where)


def _build(cls, data: Any, where: str):
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ValueError(f"{where}: expected a mapping of keys to values, got {_kind(data)}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(str(k) for k in set(data) - set(fields))
    if unknown:
        raise ValueError(
            f"{where}: unknown key(s) {', '.join(unknown)}; valid keys are {', '.join(fields)}"
        )
    missing = [
        f.name
        for f in fields.values()
        if f.name not in data
        and f.default is dataclasses.MISSING
        and f.default_factory is dataclasses.MISSING
    ]
    if missing:
        raise ValueError(f"{where}: missing key(s) {', '.join(missing)}")
    hints = typing.get_type_hints(cls)
    values = {name: _convert(hints[name], value, f"{where}.{name}") for name, value in data.items()}
    token = _WHERE.set(where)
    try:
        return cls(**values)
    finally:
        _WHERE.reset(token)


def _convert(tp, value: Any, where: str):
    """``value`` as type ``tp`` (no lossy coercion: '2' is not an int)."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):  # X | None
        if value is None:
            return None
        return _convert(next(a for a in args if a is not type(None)), value, where)
    if dataclasses.is_dataclass(tp):
        return _build(tp, value, where)
    if tp == tuple[FusionRule, ...]:
        return parse_rules(value, where)
    if origin is list:
        if tp == list[str] and isinstance(value, str):  # one item
            value = [value]
        if not isinstance(value, list):
            raise ValueError(f"{where}: expected a list, got {_kind(value)}")
        return [_convert(args[0], v, f"{where}[{i}]") for i, v in enumerate(value)]
    if origin is tuple:
        if not isinstance(value, (list, tuple)) or len(value) != len(args):
            raise ValueError(f"{where}: expected a list of {len(args)} numbers, got {_kind(value)}")
        return tuple(_convert(a, v, f"{where}[{i}]") for i, (a, v) in enumerate(zip(args, value)))
    if tp is bool:
        if not isinstance(value, bool):
            raise ValueError(f"{where}: expected true or false, got {_kind(value)}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{where}: expected a whole number, got {_kind(value)}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"{where}: expected a number, got {_kind(value)}")
        if not math.isfinite(value):
            raise ValueError(f"{where}: expected a finite number, got {value}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ValueError(f"{where}: expected text, got {_kind(value)}")
        return value
    raise TypeError(f"{where}: unsupported config type {tp}")  # a bug, not bad input


def _kind(value: Any) -> str:
    text = repr(value)
    return f"{type(value).__name__} {text if len(text) <= 40 else text[:37] + '...'}"


def load_yaml(path: str | Path, cls=RunConfig):
    """Read and validate a YAML config file; errors name the file and the key."""
    return from_dict(cls, read_yaml(path), where=str(path))


def read_yaml(path: str | Path) -> dict:
    """The plain data of a YAML config file (a mapping); errors name the file."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"config file '{p}' does not exist or is not a regular file")
    try:
        data = yaml.safe_load(p.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise ValueError(f"config file '{p}' is not UTF-8 text") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        at = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        raise ValueError(
            f"config file '{p}' is not valid YAML{at}: "
            f"{getattr(e, 'problem', None) or 'syntax error'}"
        ) from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ValueError(
            f"config file '{p}': expected a mapping of keys to values, got {_kind(data)}"
        )
    return data


def merge(base: dict, overrides: dict) -> dict:
    """``base`` with ``overrides`` laid over it, nested mappings merged key by key."""
    out = dict(base)
    for k, v in overrides.items():
        out[k] = merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def dump_yaml(cfg: Any) -> str:
    return yaml.safe_dump(to_dict(cfg), sort_keys=False)
