"""Scans from bags: agents, decoding and poses, in time order."""

from __future__ import annotations

import queue
import threading
import time
from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

import numpy as np

from ..config import AgentSpec, BuildConfig
from .bags import BagSet
from .decode import laserscan_to_xyz, pointcloud2_to_xyz, stamp_to_ns
from .deskew import deskew_scan, deskew_scans
from .se3 import transform_matrix
from .tf import ConnectivityError, ExtrapolationError, TransformError, UnknownFrameError
from .tf_bags import POSE_TYPES, PoseSource, load_transforms

LASERSCAN = "sensor_msgs/msg/LaserScan"
POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
SCAN_TYPES = (LASERSCAN, POINTCLOUD2)
RESERVED_NAMES = ("centralized",)
#: OctoMap's keys reach 32768 voxels from the origin; a voxel less, for float rounding
EXTENT_VOXELS = 32767.0
#: longest ray, in voxels crossed (OctoMap traces a ray into a buffer of 100,000 keys)
MAX_RAY_VOXELS = 90_000
#: scan messages placed together: their poses and beam poses in one look-up per frame
PLACE_CHUNK = 64


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
    laserscans: int = 0  #: LaserScans placed (de-skew applies to them only)
    deskewed: int = 0  #: of them, de-skewed (beam times from a time_increment > 0)
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

    def __init__(self, cfg: BuildConfig, *, per_scan_transforms: bool = False):
        self.cfg = cfg
        #: look poses and beam poses up scan by scan (the reference the batched look-ups of
        #: :data:`PLACE_CHUNK` scans are checked and timed against)
        self.per_scan_transforms = per_scan_transforms
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
                + self.bags.describe_topics()
            )
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
            raise ValueError(
                f"invalid agent name(s) {', '.join(map(repr, bad))}: "
                f"'centralized' is reserved and names may not contain '/'"
            )
        self.bags.check_topics({a.topic: list(SCAN_TYPES) for a in self.agents})
        pose_sources = []
        self._pose_frames: dict[int, str] = {}
        for i, a in enumerate(self.agents):
            if a.pose_topic:
                self.bags.check_topics({a.pose_topic: list(POSE_TYPES)})
                frame = f"octofuse/{a.name}/sensor"
                pose_sources.append(
                    PoseSource(
                        a.pose_topic, frame, cfg.fixed_frame, _offset_matrix(a.sensor_offset)
                    )
                )
                self._pose_frames[i] = frame
            elif a.sensor_offset is not None:
                raise ValueError(f"agent {a.name}: sensor_offset needs a pose_topic")
        self.tf = load_transforms(self.bags, pose_sources=pose_sources)
        frames = self.tf.frames
        if cfg.fixed_frame.lstrip("/") not in frames:
            known = ", ".join(sorted(frames)) or "none (no /tf, /tf_static or pose topic)"
            raise ValueError(
                f"fixed frame '{cfg.fixed_frame}' is not in the bags' transforms; "
                f"frames present: {known}"
            )
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
        out += [
            f"{s.name}: dropped {n} point(s): {why}"
            for s in self.stats
            for why, n in sorted(s.dropped.items())
        ]
        return out

    def close(self) -> None:
        self.bags.close()

    def __enter__(self) -> ScanSource:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def check_placed(self) -> None:
        """After :meth:`scans`: raise ``ValueError`` saying why if no scan could be placed."""
        if any(s.scans_used for s in self.stats):
            return
        reasons = "; ".join(
            f"{s.name}: {n} {why}" for s in self.stats for why, n in s.skipped.items()
        )
        raise ValueError(
            f"no scan of {', '.join(self.cfg.bags)} could be placed in the fixed "
            f"frame '{self.cfg.fixed_frame}' ({reasons or 'the scan topics are empty'})"
        )

    def scans(self) -> Iterator[Scan]:
        """Scans of all agents in log-time order (skipped scans are counted, not yielded)."""
        cfg = self.cfg
        self.stats = [AgentStats(a.name, a.topic) for a in self.agents]  # per pass
        seen = [0] * len(self.agents)
        fixed = cfg.fixed_frame.lstrip("/")
        chunk = 1 if self.per_scan_transforms else PLACE_CHUNK
        pending: list[_Pending] = []
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
                raise ValueError(
                    f"the message on '{m.topic}' logged at {m.log_time_ns} ns has no "
                    f"usable header ({type(e).__name__}: {e})"
                ) from None
            bad = _laserscan_problem(msg) if hasattr(msg, "ranges") else None
            if bad:
                st.skipped[bad] += 1
                continue
            if not frame.strip("/"):
                st.skipped["empty header.frame_id"] += 1
                continue
            pending.append(_Pending(i, m.topic, msg, stamp, frame))
            st.seconds += time.perf_counter() - t0
            if len(pending) >= chunk:
                yield from self._place(pending, fixed)
                pending = []
        yield from self._place(pending, fixed)

    def _place(self, pending: list[_Pending], fixed: str) -> list[Scan]:
        """Poses, decoding, de-skew and range checks of consecutive scans; the scans placed.

        Poses and per-beam poses are looked up for all the scans of one frame at once (one
        call per frame), unless :attr:`per_scan_transforms` asks for a call per scan.
        """
        if not pending:
            return []
        t0 = time.perf_counter()
        poses = self._poses(pending, fixed)
        placed: list[tuple[_Pending, np.ndarray, np.ndarray, float]] = []
        for p, pose in zip(pending, poses):
            if pose is None:
                continue
            if not self._in_extent(pose[:3, 3]):
                self.stats[p.agent].skipped[
                    "sensor pose outside the map's extent "
                    f"(±{self._extent():g} m at resolution {self.cfg.map.resolution:g} m)"
                ] += 1
                continue
            try:
                points, max_range = self._decode(p.msg)
            except (ValueError, AttributeError, TypeError, OverflowError) as e:
                raise ValueError(
                    f"cannot decode the message on '{p.topic}' stamped {p.stamp} ns: {e}"
                ) from None
            placed.append((p, points, pose, max_range))
        skewed = [
            k
            for k, (p, points, _, _) in enumerate(placed)
            if self.cfg.deskew
            and hasattr(p.msg, "ranges")
            and p.msg.time_increment > 0
            and len(points)
        ]
        for p, _, _, _ in placed:
            self.stats[p.agent].laserscans += hasattr(p.msg, "ranges")
        for k in skewed:
            self.stats[placed[k][0].agent].deskewed += 1
        if skewed:
            rows = [placed[k] for k in skewed]
            if self.per_scan_transforms:
                moved = [
                    deskew_scan(
                        self.tf, self._time_range, fixed, p.msg, points, p.frame, p.stamp, pose
                    )
                    for p, points, pose, _ in rows
                ]
            else:
                moved = deskew_scans(
                    self.tf,
                    self._time_range,
                    fixed,
                    [r[0].msg for r in rows],
                    [r[1] for r in rows],
                    [r[0].frame for r in rows],
                    [r[0].stamp for r in rows],
                    [r[2] for r in rows],
                )
            for k, points in zip(skewed, moved):
                p, _, pose, max_range = placed[k]
                placed[k] = (p, points, pose, max_range)
        out = []
        for (p, _, pose, max_range), points in zip(placed, self._keep_traceable(placed)):
            st = self.stats[p.agent]
            if len(points) == 0:
                st.skipped["no valid points"] += 1
                continue
            st.scans_used += 1
            st.points += len(points)
            out.append(Scan(p.agent, p.stamp, points, pose, max_range))
        dt = (time.perf_counter() - t0) / len(pending)
        for p in pending:
            self.stats[p.agent].seconds += dt
        return out

    def _poses(self, pending: list[_Pending], fixed: str) -> list[np.ndarray | None]:
        """The sensor pose of each scan at its stamp, or ``None`` (the skip counted)."""
        poses: list[np.ndarray | None] = [None] * len(pending)
        if self.per_scan_transforms:
            for k, p in enumerate(pending):
                poses[k] = self._pose_or_skip(p, fixed)
            return poses
        by_frame: dict[str, list[int]] = {}
        for k, p in enumerate(pending):
            by_frame.setdefault(p.frame, []).append(k)
        for frame, ks in by_frame.items():
            rng = self._time_range(fixed, frame)
            if rng is None:  # the chain cannot be evaluated: each scan says why
                inside = []
            else:
                lo, hi = rng
                inside = [k for k in ks if lo is None or lo <= pending[k].stamp <= hi]
            if inside:
                stamps = np.array([pending[k].stamp for k in inside], dtype=np.int64)
                for k, pose in zip(inside, self.tf.lookup_many(fixed, frame, stamps)):
                    poses[k] = pose
            for k in set(ks).difference(inside):
                poses[k] = self._pose_or_skip(pending[k], fixed)
        return poses

    def _time_range(self, fixed: str, frame: str) -> tuple | None:
        """Stamps ``(lo, hi)`` at which ``frame`` can be placed in ``fixed`` (``(None, None)``:
        always, an all-static chain); ``None`` if the chain is broken or the frame unknown."""
        if frame not in self._time_ranges:
            try:
                self._time_ranges[frame] = self.tf.time_range(fixed, frame) or (None, None)
            except TransformError:
                self._time_ranges[frame] = None
        return self._time_ranges[frame]

    def _pose_or_skip(self, p: _Pending, fixed: str) -> np.ndarray | None:
        """One scan's pose, or ``None`` with the reason counted in its agent's skips."""
        st = self.stats[p.agent]
        try:
            return self.tf.lookup(fixed, p.frame, p.stamp)
        except ExtrapolationError as e:
            st.skipped[
                "before the first transform" if p.stamp < e.first_ns else "after the last transform"
            ] += 1
        except ConnectivityError:
            st.skipped[f"no transform chain from '{p.frame}' to '{fixed}'"] += 1
        except UnknownFrameError:
            st.skipped[f"unknown frame '{p.frame}'"] += 1
        except TransformError as e:
            st.skipped[f"transform error: {e}"] += 1
        return None

    def _extent(self) -> float:
        return EXTENT_VOXELS * self.cfg.map.resolution

    def _in_extent(self, xyz: np.ndarray) -> bool:
        return bool(np.all(np.isfinite(xyz)) and np.all(np.abs(xyz) < self._extent()))

    def _keep_traceable(self, placed: list) -> list[np.ndarray]:
        """Each placed scan's points without (and counting) those outside the map's extent
        or whose ray is too long to trace; all the scans' points checked at once."""
        sizes = np.array([len(points) for _, points, _, _ in placed])
        if not sizes.sum():
            return [points for _, points, _, _ in placed]
        d = np.concatenate([points @ pose[:3, :3].T for _, points, pose, _ in placed])
        origin = np.repeat(np.array([pose[:3, 3] for _, _, pose, _ in placed]), sizes, axis=0)
        max_range = np.repeat(np.array([r for _, _, _, r in placed], dtype=np.float64), sizes)
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            near = np.abs(d + origin) < self._extent()  # False for NaN and inf
            inside = near[:, 0] & near[:, 1] & near[:, 2]
            x, y, z = d[:, 0], d[:, 1], d[:, 2]
            dist = np.sqrt(x * x + y * y + z * z)
            scale = np.where(
                max_range > 0, np.minimum(1.0, max_range / np.maximum(dist, 1e-300)), 1.0
            )
            voxels = scale * (np.abs(x) + np.abs(y) + np.abs(z)) / self.cfg.map.resolution
            short = voxels < MAX_RAY_VOXELS
        keep = inside & short
        if keep.all():
            return [points for _, points, _, _ in placed]
        scan_of = np.repeat(np.arange(len(placed)), sizes)
        n_out = np.bincount(scan_of, weights=~inside, minlength=len(placed))
        n_long = np.bincount(scan_of, weights=inside & ~short, minlength=len(placed))
        ends = np.cumsum(sizes)
        out = []
        for k, (p, points, _, _) in enumerate(placed):
            dropped = self.stats[p.agent].dropped
            if n_out[k]:
                dropped[
                    "outside the map's extent "
                    f"(±{self._extent():g} m at resolution {self.cfg.map.resolution:g} m)"
                ] += int(n_out[k])
            if n_long[k]:
                dropped[
                    f"ray crosses more than {MAX_RAY_VOXELS:,} voxels (set max_range to shorten it)"
                ] += int(n_long[k])
            out.append(points[keep[ends[k] - sizes[k] : ends[k]]])
        return out

    def _decode(self, msg) -> tuple[np.ndarray, float]:
        return decode_scan(msg, self.cfg)


def decode_scan(msg, cfg: BuildConfig) -> tuple[np.ndarray, float]:
    """A ``LaserScan`` or ``PointCloud2`` as end points in the sensor frame and the range past
    which rays only clear (-1: none), as ``cfg`` asks (range limit, beams without a return)."""
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


@dataclass
class _Pending:
    """A scan message that passed the header checks, waiting for its pose."""

    agent: int
    topic: str
    msg: object
    stamp: int
    frame: str


#: longest sweep of one LaserScan (time_increment x beams) taken for a real scan, seconds
MAX_SWEEP_S = 1.0


def _laserscan_problem(msg) -> str | None:
    """Why a LaserScan's geometry cannot be mapped (a skip reason), or ``None``."""
    try:
        values = {
            k: float(getattr(msg, k))
            for k in ("angle_min", "angle_increment", "range_min", "time_increment")
        }
        rmax = float(msg.range_max)
    except (AttributeError, TypeError, ValueError) as e:
        return f"LaserScan fields unusable ({e})"
    bad = [k for k, v in values.items() if not np.isfinite(v)]
    if bad:
        return f"LaserScan with non-finite {', '.join(bad)}"
    if np.isnan(rmax) or rmax <= 0:
        return "LaserScan with range_max not > 0"
    if values["time_increment"] < 0:
        return "LaserScan with negative time_increment"
    try:
        beams = len(msg.ranges)
    except TypeError:
        beams = 0
    if values["time_increment"] * max(beams - 1, 0) > MAX_SWEEP_S:
        return (
            f"LaserScan whose beams span more than {MAX_SWEEP_S:g} s "
            "(time_increment x beams): no real scanner sweeps that slowly"
        )
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
