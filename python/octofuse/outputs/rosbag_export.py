"""Maps for RViz and Foxglove: ``octomap_msgs/msg/Octomap`` and ``sensor_msgs/msg/PointCloud2``
messages in a ROS 2 MCAP file or bag folder, or a ROS 1 bag (written with rosbags).

Every map becomes, on the topics of its name (``/NAME/octomap`` and ``/NAME/occupied_cells`` by
default):

- an ``octomap_msgs/msg/Octomap`` with ``binary = False``, ``id = "OcTree"``, the map's
  resolution, the header's ``frame_id`` and ``data`` = OctoMap's full tree stream, the node data
  of ``OcTree::writeData`` (log-odds and child mask of every node), exactly as octomap_msgs'
  ``fullMapToMsg`` fills it: RViz's octomap plugin (octomap_rviz_plugins) and
  ``octomap_msgs::msgToMap`` read it, log-odds included;
- a ``sensor_msgs/msg/PointCloud2`` of the centres of its occupied finest voxels with the fields
  ``x, y, z, log_odds, occupancy`` (float32): Foxglove shows no octomaps, but colours a cloud by
  any field.

The message definition of ``octomap_msgs/msg/Octomap`` is registered here (no ROS install is
needed). One call writes any number of messages: one per agent for a fused result, or one per
agent per fusion event (:class:`MapEvent`) so that a run can be replayed in time.

The output is written to a temporary name next to it and renamed when complete: an existing
file is never overwritten (``FileExistsError``) and a failed export leaves nothing behind.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .staging import clean_leftovers, partial_path

OCTOMAP = "octomap_msgs/msg/Octomap"
POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"

#: the message definition of octomap_msgs/msg/Octomap (octomap_msgs, ROS 1 and ROS 2)
OCTOMAP_MSG = """\
# A 3D map in binary format, as Octree
std_msgs/Header header

# Flag to denote a binary (only free/occupied) or full occupancy octree (.bt/.ot file)
bool binary

# Class id of the contained octree
string id

# Resolution (in m) of the smallest octree nodes
float64 resolution

# binary serialization of octree, use conversions.h to read and write octrees
int8[] data
"""

#: ``kind`` values of :func:`write_map_bag`
KINDS = ("mcap", "mcap-folder", "ros1")


@dataclass(frozen=True)
class MapEvent:
    """One map to publish: agent ``name``'s map at time ``stamp_ns`` (ns since the epoch)."""

    name: str
    stamp_ns: int
    map: object  #: an :class:`~octofuse.maps.occupancy.OccupancyMap`


def bag_kind(path: str | os.PathLike) -> str:
    """The kind a path asks for: ``.bag`` a ROS 1 bag, ``.mcap`` a bare ROS 2 MCAP file (what
    Foxglove opens), anything else a ROS 2 bag folder with MCAP storage (``ros2 bag play``)."""
    suffix = Path(path).suffix
    return "ros1" if suffix == ".bag" else "mcap" if suffix == ".mcap" else "mcap-folder"


def typestore(ros1: bool):
    """A rosbags type store with ``octomap_msgs/msg/Octomap`` registered."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.LATEST)
    if OCTOMAP not in ts.types:
        ts.register(get_types_from_msg(OCTOMAP_MSG, OCTOMAP))
    return ts


def write_map_bag(
    path: str | os.PathLike,
    maps: Mapping[str, object] | Iterable[MapEvent],
    *,
    kind: str | None = None,
    frame_id: str = "map",
    stamp_ns: int = 0,
    topic: str = "/{name}/octomap",
    cloud_topic: str | None = "/{name}/occupied_cells",
    occupied: float = 0.0,
) -> Path:
    """Write maps as ``octomap_msgs/msg/Octomap`` (and occupied voxels as PointCloud2) messages.

    ``maps`` is ``{name: map}`` (all stamped ``stamp_ns``) or :class:`MapEvent` items in any
    order (written in time order). ``kind`` defaults to :func:`bag_kind` of ``path``;
    ``topic``/``cloud_topic`` are formatted with ``name`` (``cloud_topic=None``: no clouds);
    voxels with log-odds above ``occupied`` go into the cloud. Returns the path written.
    """
    if isinstance(maps, Mapping):
        events = [MapEvent(str(k), int(stamp_ns), m) for k, m in maps.items()]
    else:
        events = list(maps)
    if not events:
        raise ValueError("no maps to write")
    for e in events:
        if not isinstance(e, MapEvent):
            raise TypeError(
                f"expected MapEvent items or a {{name: map}} mapping, got {type(e).__name__}"
            )
        _check_stamp(e)
    events.sort(key=lambda e: e.stamp_ns)
    with MapBagWriter(
        path, kind=kind, frame_id=frame_id, topic=topic, cloud_topic=cloud_topic, occupied=occupied
    ) as writer:
        for e in events:
            writer.write(e)
    return writer.path


class MapBagWriter:
    """Map messages streamed into a bag: :meth:`write` one :class:`MapEvent` at a time (nothing
    is kept in memory), :meth:`close` puts the finished bag at ``path``.

    Arguments as for :func:`write_map_bag`. The path is checked when the writer is made (an
    existing path, a bad ``kind`` or frame raise then), the messages go to a temporary folder
    beside it, and only :meth:`close` (:meth:`finish`, then :meth:`put_in_place`) renames the
    complete bag into place; :meth:`abort` (or
    leaving the ``with`` block by an exception) removes everything written.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        kind: str | None = None,
        frame_id: str = "map",
        topic: str | None = "/{name}/octomap",
        cloud_topic: str | None = "/{name}/occupied_cells",
        occupied: float = 0.0,
    ):
        from rosbags.rosbag1 import Writer as Writer1
        from rosbags.rosbag2 import StoragePlugin
        from rosbags.rosbag2 import Writer as Writer2

        out = Path(path)
        kind = bag_kind(out) if kind is None else kind
        if kind not in KINDS:
            raise ValueError(f"kind {kind!r}: expected one of {', '.join(KINDS)}")
        if kind == "ros1" and out.suffix != ".bag":
            raise ValueError(f"'{out}': a ROS 1 bag needs a .bag file name")
        if out.exists() or out.is_symlink():
            raise FileExistsError(f"'{out}' exists; not overwriting it")
        if not frame_id:
            raise ValueError("frame_id must not be empty")
        self.path, self.kind, self.count = out, kind, 0
        self.bytes = 0  #: message bytes written so far
        self._frame, self._topic, self._cloud_topic = frame_id, topic, cloud_topic
        self._occupied = occupied
        self._ros1 = kind == "ros1"
        self._ts = typestore(self._ros1)
        out.parent.mkdir(parents=True, exist_ok=True)
        clean_leftovers(out)
        self._tmp = partial_path(out.absolute())
        self._tmp.mkdir()
        self._done: Path | None = None
        try:
            if self._ros1:
                self._staged = self._tmp / out.name
                self._writer = Writer1(self._staged)
            else:
                self._staged = self._tmp / "bag"
                self._writer = Writer2(self._staged, version=9, storage_plugin=StoragePlugin.MCAP)
            self._writer.open()
        except BaseException:
            shutil.rmtree(self._tmp, ignore_errors=True)
            raise
        self._conns: dict[tuple[str, str], object] = {}
        self._open = True

    def write(self, e: MapEvent) -> None:
        """Write one map (and its occupied voxels) stamped ``e.stamp_ns``."""
        if not self._open:
            raise ValueError(f"'{self.path}': the bag is closed")
        _check_stamp(e)
        hdr = _header(self._ts, e.stamp_ns, self._frame)
        if self._topic is not None:
            self._put(
                self._topic.format(name=e.name),
                OCTOMAP,
                octomap_message(self._ts, e.map, hdr),
                e.stamp_ns,
            )
        if self._cloud_topic is not None:
            self._put(
                self._cloud_topic.format(name=e.name),
                POINTCLOUD2,
                occupied_cloud(self._ts, e.map, hdr, self._occupied),
                e.stamp_ns,
            )
        self.count += 1

    def finish(self) -> None:
        """Finish the bag beside ``path``, not in place yet (:meth:`put_in_place`)."""
        if not self._open:
            return
        self._open = False
        try:
            self._writer.close()
            staged = self._staged
            if self.kind == "mcap":
                staged = next(p for p in staged.iterdir() if p.suffix == ".mcap")
            self._done = staged
        except BaseException:
            shutil.rmtree(self._tmp, ignore_errors=True)
            raise

    def put_in_place(self) -> Path:
        """Finish the bag and rename it to ``path``; returns ``path``."""
        self.finish()
        if self._done is None:
            return self.path
        try:
            if self.path.exists() or self.path.is_symlink():
                raise FileExistsError(f"'{self.path}' appeared while writing; not overwriting it")
            os.rename(self._done, self.path)
        finally:
            self._done = None
            shutil.rmtree(self._tmp, ignore_errors=True)
        return self.path

    close = put_in_place

    def abort(self) -> None:
        """Drop everything written; ``path`` is left as it was."""
        if self._open:
            self._open = False
            try:
                self._writer.close()
            except Exception:  # noqa: BLE001 - the partial bag is deleted anyway
                pass
        self._done = None
        shutil.rmtree(self._tmp, ignore_errors=True)

    def __enter__(self) -> MapBagWriter:
        return self

    def __exit__(self, exc_type, *exc) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def _put(self, topic: str, msgtype: str, msg, log_ns: int) -> None:
        key = (topic, msgtype)
        if key not in self._conns:
            self._conns[key] = self._writer.add_connection(topic, msgtype, typestore=self._ts)
        ts = self._ts
        raw = ts.serialize_ros1(msg, msgtype) if self._ros1 else ts.serialize_cdr(msg, msgtype)
        self._writer.write(self._conns[key], log_ns, raw)
        self.bytes += len(raw)


def _check_stamp(e: MapEvent) -> None:
    if int(e.stamp_ns) < 0:
        raise ValueError(f"map '{e.name}': negative time stamp {e.stamp_ns}")


def octomap_message(ts, m, header):
    """An ``octomap_msgs/msg/Octomap`` of map ``m`` (full tree, log-odds kept)."""
    data = np.frombuffer(m.tree_data(), dtype=np.int8)
    return ts.types[OCTOMAP](
        header=header, binary=False, id="OcTree", resolution=float(m.resolution), data=data
    )


def occupied_cloud(ts, m, header, occupied: float = 0.0):
    """A ``sensor_msgs/msg/PointCloud2`` of the centres of the occupied finest voxels of ``m``
    (fields x, y, z, log_odds, occupancy; float32, little-endian)."""
    from ..maps.registration import occupied_centers

    lv = m.leaves()
    sel = lv.values > occupied
    # log-odds per finest voxel: expand like occupied_centers (a coarse leaf gives its voxels)
    span = np.rint(lv.sizes[sel] / m.resolution).astype(np.int64)
    vals = [lv.values[sel][span == 1]] + [
        np.repeat(lv.values[sel][span == n], n**3) for n in np.unique(span[span > 1])
    ]
    xyz = occupied_centers(m, occupied)
    lo = np.concatenate(vals).astype(np.float32) if vals else np.empty(0, np.float32)
    rec = np.zeros(
        len(xyz),
        dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("log_odds", "<f4"), ("occupancy", "<f4")],
    )
    rec["x"], rec["y"], rec["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    rec["log_odds"] = lo
    rec["occupancy"] = 1.0 / (1.0 + np.exp(-lo.astype(np.float64)))
    pf = ts.types["sensor_msgs/msg/PointField"]
    fields = [
        pf(name=n, offset=4 * i, datatype=7, count=1)  # 7 = FLOAT32
        for i, n in enumerate(rec.dtype.names)
    ]
    step = rec.dtype.itemsize
    return ts.types[POINTCLOUD2](
        header=header,
        height=1,
        width=len(rec),
        fields=fields,
        is_bigendian=False,
        point_step=step,
        row_step=step * len(rec),
        data=np.frombuffer(rec.tobytes(), dtype=np.uint8),
        is_dense=True,
    )


def read_map_bag(path: str | os.PathLike) -> list[tuple[str, int, object]]:
    """The ``octomap_msgs/msg/Octomap`` messages of a bag (any kind :class:`~octofuse.scans.bags.
    BagSet` opens) as ``(topic, stamp_ns, map)``, in log-time order, each decoded with the map
    core's OctoMap reader (full ``OcTree`` maps only; ``ValueError`` for others)."""
    from ..maps.occupancy import OccupancyMap
    from ..scans.bags import BagSet

    p = Path(path)
    out = []
    with BagSet([p]) as bags:
        topics = [t for t, info in bags.topics().items() if info.msgtype == OCTOMAP]
        if not topics:
            return out
        for topic, _log, msg in bags.messages(topics):
            if msg.binary or msg.id != "OcTree":
                raise ValueError(
                    f"'{p}': {topic} holds a {'binary ' if msg.binary else ''}"
                    f"'{msg.id}' octomap; only full OcTree maps are read"
                )
            m = OccupancyMap.from_tree_data(np.asarray(msg.data).tobytes(), msg.resolution)
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            out.append((topic, int(stamp), m))
    return out


def _header(ts, stamp_ns: int, frame: str):
    stamp = ts.types["builtin_interfaces/msg/Time"](
        sec=int(stamp_ns) // 1_000_000_000, nanosec=int(stamp_ns) % 1_000_000_000
    )
    if "seq" in [f[0] for f in ts.fielddefs["std_msgs/msg/Header"][1]]:
        return ts.types["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame)
    return ts.types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)
