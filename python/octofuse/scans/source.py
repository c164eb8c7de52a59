"""Scans from bags: agents, decoding and poses, in time order."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
import queue
import threading
from typing import Iterable, Iterator

import numpy as np

from ..config import AgentSpec, BuildConfig
from .bags import BagSet
from .decode import laserscan_to_xyz, pointcloud2_to_xyz, stamp_to_ns
from .se3 import transform_matrix
from .tf import (
    ConnectivityError,
    ExtrapolationError,
    PoseSource,
    TransformError,
    UnknownFrameError,
    load_transforms,
)

LASERSCAN = "sensor_msgs/msg/LaserScan"
POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
SCAN_TYPES = (LASERSCAN, POINTCLOUD2)
POSE_TYPES = ("nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseStamped")
RESERVED_NAMES = ("centralized",)
#: OctoMap's keys reach 32768 voxels from the origin; a voxel less, for float rounding
EXTENT_VOXELS = 32767.0
#: longest ray, in voxels crossed (OctoMap traces a ray into a buffer of 100,000 keys)
MAX_RAY_VOXELS = 90_000


@dataclass
class Scan:
    """One scan ready for insertion."""

    agent: int  #: index of the agent
    stamp_ns: int  #: header stamp
    points: np.ndarray  #: (N, 3) float64 in the sensor frame
    pose: np.ndarray  #: (4, 4) sensor-to-fixed-frame transform at the stamp
    max_range: float  #: rays longer than this only clear free space (-1: none)


@dataclass
class AgentStats:
    """What ingest did for one agent."""

    name: str
    topic: str
    scans_used: int = 0
    skipped: Counter = field(default_factory=Counter)  #: reason -> count
    points: int = 0
    dropped: Counter = field(default_factory=Counter)  #: reason -> points dropped
    seconds: float = 0.0  #: decode + transform + insertion time attributed to the agent

    @property
    def scans_skipped(self) -> int:
        return sum(self.skipped.values())


def agent_name_for(topic: str) -> str:
    """``/robot1/scan`` -> ``robot1``; ``/scan`` -> ``scan``."""
    parts = [p for p in topic.split("/") if p]
    return parts[0] if len(parts) > 1 else (parts[0] if parts else "scan")


def default_agents(topics: dict) -> list[AgentSpec]:
    """One agent per scan topic, named after the topic's namespace."""
    scan_topics = sorted(t for t, info in topics.items() if info.msgtype in SCAN_TYPES)
    names = [agent_name_for(t) for t in scan_topics]
    if len(set(names)) < len(names):
        names = ["_".join(p for p in t.split("/") if p) for t in scan_topics]
    return [AgentSpec(n, t) for n, t in zip(names, scan_topics)]


def _offset_matrix(offset) -> np.ndarray | None:
    if offset is None:
        return None
    v = np.asarray(offset, dtype=float)
    if v.shape != (7,):
        raise ValueError(f"sensor_offset must be 7 numbers x y z qx qy qz qw, got {list(v)}")
    return transform_matrix(v[:3], v[3:])


class ScanSource:
    """Opens bags, resolves agents and transforms, and yields scans in time order.

    Use as a context manager. Scans whose pose cannot be found (before the first transform,
    after the last, a broken chain) are skipped and counted per reason in :attr:`stats`;
    a missing topic or fixed frame raises an error listing what the bags contain.
    """

    def __init__(self, cfg: BuildConfig):
        cfg.validate("build")
        self.cfg = cfg
        if not cfg.bags:
            raise ValueError("no bag files given")
        self.bags = BagSet(cfg.bags).open()
        try:
            self._setup()
        except BaseException:
            self.bags.close()
            raise

    def _setup(self) -> None:
        cfg = self.cfg
        topics = self.bags.topics()
        self.agents = list(cfg.agents) or default_agents(topics)
        if not self.agents:
            raise ValueError(
                "no LaserScan or PointCloud2 topic in the bags; they contain: "
                + self.bags.describe_topics())
        names = [a.name for a in self.agents]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"agent name(s) used twice: {', '.join(dup)}")
        topics_used = [a.topic for a in self.agents]
        dup = sorted({t for t in topics_used if topics_used.count(t) > 1})
        if dup:
            raise ValueError(f"topic(s) given to more than one agent: {', '.join(dup)}")
        bad = [n for n in names if n in RESERVED_NAMES or not n or "/" in n]
        if bad:
            raise ValueError(f"invalid agent name(s) {', '.join(map(repr, bad))}: "
                             f"'centralized' is reserved and names may not contain '/'")
        self.bags.check_topics({a.topic: list(SCAN_TYPES) for a in self.agents})
        pose_sources = []
        self._pose_frames: dict[int, str] = {}
        for i, a in enumerate(self.agents):
            if a.pose_topic:
                self.bags.check_topics({a.pose_topic: list(POSE_TYPES)})
                frame = f"octofuse/{a.name}/sensor"
                pose_sources.append(PoseSource(a.pose_topic, frame, cfg.fixed_frame,
                                               _offset_matrix(a.sensor_offset)))
                self._pose_frames[i] = frame
            elif a.sensor_offset is not None:
                raise ValueError(f"agent {a.name}: sensor_offset needs a pose_topic")
        self.tf = load_transforms(self.bags, pose_sources=pose_sources)
        frames = self.tf.frames
        if cfg.fixed_frame.lstrip("/") not in frames:
            known = ", ".join(sorted(frames)) or "none (no /tf, /tf_static or pose topic)"
            raise ValueError(f"fixed frame '{cfg.fixed_frame}' is not in the bags' transforms; "
                             f"frames present: {known}")
        self.topic_agent = {a.topic: i for i, a in enumerate(self.agents)}
        self._time_ranges: dict[str, tuple] = {}
        self.stats = [AgentStats(a.name, a.topic) for a in self.agents]
        info = self.bags.topics()
        self.total_scans = sum(-(-info[a.topic].count // cfg.scan_stride) for a in self.agents)

    @property
    def tf_skipped(self) -> list[str]:
        """One line per topic, link and reason for transform samples skipped while loading."""
        return self.tf.skipped_notes()

    def notes(self) -> list[str]:
        """Transform samples skipped and points dropped, one line each (scans skipped are in
        :attr:`stats`)."""
        out = list(self.tf_skipped)
        out += [f"{s.name}: dropped {n} point(s): {why}"
                for s in self.stats for why, n in sorted(s.dropped.items())]
        return out

    def close(self) -> None:
        self.bags.close()

    def __enter__(self) -> "ScanSource":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def check_placed(self) -> None:
        """After :meth:`scans`: raise ``ValueError`` saying why if no scan could be placed."""
        if any(s.scans_used for s in self.stats):
            return
        reasons = "; ".join(f"{s.name}: {n} {why}" for s in self.stats for why, n in s.skipped.items())
        raise ValueError(f"no scan of {', '.join(self.cfg.bags)} could be placed in the fixed "
                         f"frame '{self.cfg.fixed_frame}' ({reasons or 'the scan topics are empty'})")

    def scans(self) -> Iterator[Scan]:
        """Scans of all agents in log-time order (skipped scans are counted, not yielded)."""
        import time

        cfg = self.cfg
        self.stats = [AgentStats(a.name, a.topic) for a in self.agents]  # per pass
        seen = [0] * len(self.agents)
        fixed = cfg.fixed_frame.lstrip("/")
        for m in self.bags.messages({a.topic: list(SCAN_TYPES) for a in self.agents}):
            i = self.topic_agent[m.topic]
            seen[i] += 1
            if (seen[i] - 1) % cfg.scan_stride:
                continue
            t0 = time.perf_counter()
            st = self.stats[i]
            msg = m.msg
            try:
                stamp = stamp_to_ns(msg.header)
                frame = self._pose_frames.get(i, str(msg.header.frame_id))
            except (AttributeError, TypeError, ValueError, OverflowError) as e:
                raise ValueError(f"the message on '{m.topic}' logged at {m.log_time_ns} ns has no "
                                 f"usable header ({type(e).__name__}: {e})") from None
            bad = _laserscan_problem(msg) if hasattr(msg, "ranges") else None
            if bad:
                st.skipped[bad] += 1
                continue
            if not frame.strip("/"):
                st.skipped["empty header.frame_id"] += 1
                continue
            try:
                pose = self.tf.lookup(fixed, frame, stamp)
            except ExtrapolationError as e:
                st.skipped["before the first transform" if stamp < e.first_ns
                           else "after the last transform"] += 1
                continue
            except ConnectivityError:
                st.skipped[f"no transform chain from '{frame}' to '{fixed}'"] += 1
                continue
            except UnknownFrameError:
                st.skipped[f"unknown frame '{frame}'"] += 1
                continue
            except TransformError as e:
                st.skipped[f"transform error: {e}"] += 1
                continue
            if not self._in_extent(pose[:3, 3]):
                st.skipped["sensor pose outside the map's extent "
                           f"(±{self._extent():g} m at resolution {cfg.map.resolution:g} m)"] += 1
                continue
            try:
                points, max_range = self._decode(msg)
            except (ValueError, AttributeError, TypeError, OverflowError) as e:
                raise ValueError(f"cannot decode the message on '{m.topic}' stamped {stamp} ns: "
                                 f"{e}") from None
            if self.cfg.deskew and hasattr(msg, "ranges") and msg.time_increment > 0 and len(points):
                points = self._deskew(msg, points, fixed, frame, stamp, pose)
            points = self._keep_traceable(points, pose, max_range, st)
            if len(points) == 0:
                st.skipped["no valid points"] += 1
                continue
            st.scans_used += 1
            st.points += len(points)
            st.seconds += time.perf_counter() - t0
            yield Scan(i, stamp, points, pose, max_range)

    def _extent(self) -> float:
        return EXTENT_VOXELS * self.cfg.map.resolution

    def _in_extent(self, xyz: np.ndarray) -> bool:
        return bool(np.all(np.isfinite(xyz)) and np.all(np.abs(xyz) < self._extent()))

    def _keep_traceable(self, points: np.ndarray, pose: np.ndarray, max_range: float,
                        st: AgentStats) -> np.ndarray:
        """Drop (and count) points outside the map's extent or whose ray is too long to trace."""
        if len(points) == 0:
            return points
        origin = pose[:3, 3]
        with np.errstate(over="ignore", invalid="ignore"):
            d = points @ pose[:3, :3].T
            world = d + origin
            inside = np.isfinite(world).all(axis=1) & (np.abs(world) < self._extent()).all(axis=1)
            dist = np.linalg.norm(d, axis=1)
            scale = np.ones_like(dist)
            if max_range > 0:
                scale = np.minimum(1.0, max_range / np.maximum(dist, 1e-300))
            voxels = scale * np.abs(d).sum(axis=1) / self.cfg.map.resolution
            short = voxels < MAX_RAY_VOXELS
        keep = inside & short
        if keep.all():
            return points
        n_out = int((~inside).sum())
        n_long = int((inside & ~short).sum())
        if n_out:
            st.dropped["outside the map's extent "
                       f"(±{self._extent():g} m at resolution {self.cfg.map.resolution:g} m)"] += n_out
        if n_long:
            st.dropped[f"ray crosses more than {MAX_RAY_VOXELS:,} voxels "
                       "(set max_range to shorten it)"] += n_long
        return points[keep]

    def _deskew(self, msg, points, fixed, frame, stamp, pose) -> np.ndarray:
        """Move each beam's point by the sensor motion between the scan stamp and its beam time.

        Points come back in the sensor frame at ``stamp``: p = T(stamp)^-1 T(t_i) p_i, with
        t_i = stamp + i * time_increment (beam times clipped to the transforms' time range).
        """
        ang = np.arctan2(points[:, 1], points[:, 0])
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            idx = np.rint(np.mod(ang - msg.angle_min, 2 * np.pi) / msg.angle_increment)
            t = stamp + idx * (float(msg.time_increment) * 1e9)
        if not np.all(np.isfinite(t)):  # degenerate beam timing: no motion correction
            return points
        rng = self._time_ranges.get(frame)
        if rng is None:
            rng = self.tf.time_range(fixed, frame) or (None, None)
            self._time_ranges[frame] = rng
        lo, hi = rng
        if lo is not None:
            t = np.clip(t, lo, hi)
        T = self.tf.lookup_many(fixed, frame, t.astype(np.int64))
        world = np.einsum("kij,kj->ki", T[:, :3, :3], points) + T[:, :3, 3]
        inv = np.linalg.inv(pose)
        return world @ inv[:3, :3].T + inv[:3, 3]

    def _decode(self, msg) -> tuple[np.ndarray, float]:
        cfg = self.cfg
        if hasattr(msg, "ranges"):
            hits, free_dirs = laserscan_to_xyz(msg, no_return=cfg.no_return)
            rmax = float(msg.range_max)
            if cfg.max_range > 0:
                rmax = min(rmax, cfg.max_range)
            if len(free_dirs):
                # past the range limit: OctoMap clears the ray up to max_range only
                far = free_dirs * (rmax + 2.0 * cfg.map.resolution + 1.0)
                return np.concatenate([hits, far]), rmax
            return hits, (cfg.max_range if cfg.max_range > 0 else -1.0)
        pts = pointcloud2_to_xyz(msg)
        return pts, (cfg.max_range if cfg.max_range > 0 else -1.0)


def _laserscan_problem(msg) -> str | None:
    """Why a LaserScan's geometry cannot be mapped (a skip reason), or ``None``."""
    try:
        values = {k: float(getattr(msg, k)) for k in
                  ("angle_min", "angle_increment", "range_min", "time_increment")}
        rmax = float(msg.range_max)
    except (AttributeError, TypeError, ValueError) as e:
        return f"LaserScan fields unusable ({e})"
    bad = [k for k, v in values.items() if not np.isfinite(v)]
    if bad:
        return f"LaserScan with non-finite {', '.join(bad)}"
    if np.isnan(rmax) or rmax <= 0:
        return "LaserScan with range_max not > 0"
    return None


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
