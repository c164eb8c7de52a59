"""A robot's scans as zenoh-bridge-ros2dds carries its ROS 2 topics: on the key of the topic
without its leading slash, the CDR bytes of each message (``sensor_msgs/msg/PointCloud2`` or
``LaserScan``; ``tf`` and ``tf_static`` as ``tf2_msgs/msg/TFMessage``). A ROS 2 robot behind
the bridge needs nothing else.

Scans are placed with the transforms that have arrived (the scan's frame to the fixed frame at
its stamp, interpolated); a scan whose pose is not known yet waits for later transforms, up to
``wait_s`` seconds, and is then skipped and counted. Undecodable messages are counted too.
"""

from __future__ import annotations

import queue
import time
from collections import Counter, deque

import numpy as np

from ..config import BuildConfig
from ..scans.decode import stamp_to_ns
from ..scans.source import Scan, decode_scan
from ..scans.tf import TransformBuffer, TransformError
from . import keys

#: the message types a scan topic may carry, by the name ``--scan-type`` gives them
SCAN_TYPES = {
    "pointcloud2": "sensor_msgs/msg/PointCloud2",
    "laserscan": "sensor_msgs/msg/LaserScan",
}
TF = "tf2_msgs/msg/TFMessage"


class BridgedScans:
    """Scans of ``topic`` (of type ``scan_type``) and the transforms of ``tf``/``tf_static``
    from a Zenoh session, placed in ``cfg.fixed_frame``."""

    def __init__(self, session, topic: str, scan_type: str, cfg: BuildConfig, wait_s: float = 2.0):
        from rosbags.typesys import Stores, get_typestore

        if scan_type not in SCAN_TYPES:
            raise ValueError(f"scan type {scan_type!r}: expected one of {', '.join(SCAN_TYPES)}")
        self.cfg, self.msgtype, self.wait_s = cfg, SCAN_TYPES[scan_type], wait_s
        self.ts = get_typestore(Stores.LATEST)
        self.tf = TransformBuffer()
        self.skipped: Counter = Counter()
        self._arrivals: queue.Queue[tuple[str, bytes]] = queue.Queue()
        self._waiting: deque = deque()  # (arrival time, message) of scans without a pose yet
        self._subs = [
            session.declare_subscriber(
                key, lambda s, kind=kind: self._arrivals.put((kind, s.payload.to_bytes()))
            )
            for kind, key in (
                ("scan", keys.ros_topic_key(topic)),
                ("tf", "tf"),
                ("tf_static", "tf_static"),
            )
        ]

    def take(self, timeout: float) -> list[Scan]:
        """The scans placed within ``timeout`` seconds (waiting for the first arrival)."""
        deadline = time.monotonic() + timeout
        while True:
            try:
                kind, data = self._arrivals.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                break
            self._read(kind, data)
            if self._arrivals.empty():
                break
        return self._placed()

    def backlog(self) -> int:
        """Messages arrived and scans waiting, not placed yet."""
        return self._arrivals.qsize() + len(self._waiting)

    def _read(self, kind: str, data: bytes) -> None:
        try:
            msg = self.ts.deserialize_cdr(data, TF if kind != "scan" else self.msgtype)
        except Exception:  # noqa: BLE001 - any malformed CDR is one counted message
            self.skipped[f"undecodable {kind} message"] += 1
            return
        if kind == "scan":
            self._waiting.append((time.monotonic(), msg))
        else:
            self.tf.add_tf_message(msg, static=kind == "tf_static", topic=kind)

    def _placed(self) -> list[Scan]:
        out, fixed = [], self.cfg.fixed_frame.lstrip("/")
        while self._waiting:
            arrived, msg = self._waiting[0]
            stamp, frame = stamp_to_ns(msg.header), str(msg.header.frame_id)
            try:
                pose = self.tf.lookup(fixed, frame, stamp)
            except TransformError:
                if time.monotonic() - arrived < self.wait_s:
                    break  # later transforms may place it; later scans wait behind it
                self._waiting.popleft()
                self.skipped["no transform to the fixed frame"] += 1
                continue
            self._waiting.popleft()
            points, max_range = decode_scan(msg, self.cfg)
            out.append(
                Scan(0, stamp, np.ascontiguousarray(points, dtype=np.float64), pose, max_range)
            )
        return out

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()
