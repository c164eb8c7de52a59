"""Transforms read from bags: the tf topics and pose topics of a bag set into a
:class:`~.tf.TransformBuffer`."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from .tf import TransformBuffer
from .tf_link import TransformError

if TYPE_CHECKING:
    from .bags import BagSet

__all__ = ["POSE_TYPES", "PoseSource", "load_transforms"]

#: the message types a pose topic may have (each gives a pose with its stamp)
POSE_TYPES = (
    "nav_msgs/msg/Odometry",
    "geometry_msgs/msg/PoseStamped",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
    "geometry_msgs/msg/TransformStamped",
)
_TF_TYPE = "tf2_msgs/msg/TFMessage"


@dataclass(frozen=True)
class PoseSource:
    """A pose topic used as a dynamic link, for :func:`load_transforms`.

    Attributes
    ----------
    topic : str
        ``nav_msgs/Odometry``, ``geometry_msgs/PoseStamped``,
        ``geometry_msgs/PoseWithCovarianceStamped`` or
        ``geometry_msgs/TransformStamped`` topic.
    child_frame : str or None
        The frame whose pose the topic gives (with ``offset`` applied). ``None``
        uses the message's ``child_frame_id`` (Odometry, TransformStamped).
    parent_frame : str or None
        The fixed frame; ``None`` uses ``header.frame_id``.
    offset : array_like or None
        Static 4x4 transform ``T_body_child`` from the body whose pose the
        topic reports to ``child_frame`` (e.g. the lidar mounting), or ``None``.
    """

    topic: str
    child_frame: str | None = None
    parent_frame: str | None = None
    offset: Any = None


def load_transforms(
    bags: BagSet,
    *,
    tf_topics: Sequence[str] | None = None,
    static_tf_topics: Sequence[str] | None = None,
    pose_sources: Iterable[PoseSource] | Mapping[str, str] = (),
    tolerance_ns: int = 0,
) -> TransformBuffer:
    """Fill a :class:`TransformBuffer` from the tf and pose topics of a bag set.

    Parameters
    ----------
    bags : BagSet
        An open bag set.
    tf_topics, static_tf_topics : sequence of str, optional
        ``tf2_msgs/TFMessage`` topics with dynamic and static transforms.
        When not given, ``/tf`` and ``/tf_static`` are read if the bags have
        them; topics given explicitly must exist.
    pose_sources : iterable of PoseSource, or mapping of topic to child frame
        Pose topics to add as dynamic links.
    tolerance_ns : int
        Passed to :class:`TransformBuffer`.

    Returns
    -------
    TransformBuffer

    Raises
    ------
    octofuse.io.BagError
        A requested topic is missing or has the wrong type.
    """
    present = bags.topics()
    if tf_topics is None:
        tf_topics = [t for t in ("/tf",) if t in present]
    if static_tf_topics is None:
        static_tf_topics = [t for t in ("/tf_static",) if t in present]
    if isinstance(pose_sources, Mapping):
        pose_sources = [PoseSource(topic, child) for topic, child in pose_sources.items()]
    poses = {p.topic: p for p in pose_sources}
    spec: dict[str, Any] = {t: _TF_TYPE for t in (*tf_topics, *static_tf_topics)}
    spec.update({t: POSE_TYPES for t in poses})
    buf = TransformBuffer(tolerance_ns=tolerance_ns)
    if not spec:
        return buf
    static_set = set(static_tf_topics)
    for topic, log_ns, msg in bags.messages(spec):
        try:
            if topic in poses:
                p = poses[topic]
                buf.add_pose_message(
                    msg, p.child_frame, parent_frame=p.parent_frame, offset=p.offset, topic=topic
                )
            else:
                buf.add_tf_message(msg, static=topic in static_set, topic=topic)
        except TransformError as err:
            raise TransformError(f"{topic} (message logged at {log_ns} ns): {err}") from None
        except (AttributeError, TypeError, ValueError, OverflowError) as err:
            raise TransformError(
                f"{topic}: the message logged at {log_ns} ns is not a usable "
                f"transform ({type(err).__name__}: {err})"
            ) from None
    return buf
