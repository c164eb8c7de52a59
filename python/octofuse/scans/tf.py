"""A time-aware transform buffer for recorded tf trees and pose topics.

Frames form a forest: every link goes from a parent frame to a child frame
and maps points in the child frame into the parent frame (the ``tf``
convention: ``T_parent_child``). A child has exactly one parent. Links are

* static (``/tf_static``): one transform, valid at all times;
* dynamic (``/tf``, odometry and pose topics): samples sorted by stamp,
  interpolated at lookup time (linear in translation, shortest-arc slerp in
  rotation). A lookup exactly at a sample returns that sample; a lookup
  before the first or after the last sample of a needed link fails with
  :class:`ExtrapolationError` (up to ``tolerance_ns``).

:meth:`TransformBuffer.lookup` walks from both frames up to their common
ancestor, so a chain may be of any length and links may be traversed against
their direction.

Frame names are normalized by stripping a leading ``/`` (ROS 1 bags often
write ``/base_link``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from .decode import stamp_to_ns
from .se3 import (
    invert_transform,
    matrix_to_quaternion,
    normalize_quaternions,
    transform_matrix,
)
from .tf_link import (
    ConnectivityError,
    ExtrapolationError,
    Link,
    TransformError,
    UnknownFrameError,
    fmt_ns,
    sample_problem,
)

__all__ = [
    "ConnectivityError",
    "ExtrapolationError",
    "TransformBuffer",
    "TransformError",
    "UnknownFrameError",
]


def _norm_frame(frame: str) -> str:
    frame = str(frame).lstrip("/")
    if not frame:
        raise ValueError("frame names must not be empty")
    return frame


class TransformBuffer:
    """Transforms between frames over time, built from tf and pose messages.

    Parameters
    ----------
    tolerance_ns : int, optional
        A stamp up to this far outside the sampled range of a dynamic link is
        answered with the nearest sample instead of raising
        :class:`ExtrapolationError`. Default 0: only stamps within
        ``[first, last]`` (inclusive) of each link.
    """

    def __init__(self, *, tolerance_ns: int = 0) -> None:
        if tolerance_ns < 0:
            raise ValueError("tolerance_ns must be >= 0")
        self.tolerance_ns = int(tolerance_ns)
        self._links: dict[str, Link] = {}  # child -> link to its parent
        self._frames: set[str] = set()
        self._paths: dict[tuple[str, str], tuple[list[Link], list[Link]]] = {}
        #: samples skipped while loading: (topic, parent, child, reason) -> (count, first stamp)
        self.skipped: dict[tuple[str, str, str, str], tuple[int, int]] = {}

    def _skip(self, topic: str, parent: str, child: str, stamp_ns: int, reason: str) -> None:
        key = (topic, str(parent), str(child), reason)
        n, first = self.skipped.get(key, (0, stamp_ns))
        self.skipped[key] = (n + 1, min(first, stamp_ns))

    def skipped_notes(self) -> list[str]:
        """One line per topic, link and reason for the transform samples that were skipped."""
        return [
            f"{topic}: skipped {n} transform sample(s) {parent!r} -> {child!r} "
            f"(first stamped {fmt_ns(first)}): {reason}"
            for (topic, parent, child, reason), (n, first) in sorted(self.skipped.items())
        ]

    # -- building ---------------------------------------------------------------------------
    def _link(self, parent: str, child: str, static: bool) -> Link:
        parent, child = _norm_frame(parent), _norm_frame(child)
        if parent == child:
            raise TransformError(f"link {parent!r} -> {child!r} connects a frame to itself")
        link = self._links.get(child)
        if link is not None:
            if link.parent != parent:
                raise TransformError(
                    f"frame {child!r} already has parent {link.parent!r}; cannot add a second "
                    f"parent {parent!r} (a frame has one parent in a tf tree)"
                )
            if link.static != static:
                kinds = ("static", "dynamic") if link.static else ("dynamic", "static")
                raise TransformError(
                    f"link {parent!r} -> {child!r} is {kinds[0]};"
                    f" cannot add {kinds[1]} samples to it"
                )
            return link
        frame = parent
        while frame in self._links:
            frame = self._links[frame].parent
            if frame == child:
                raise TransformError(f"link {parent!r} -> {child!r} would close a loop in the tree")
        if frame == child:
            raise TransformError(f"link {parent!r} -> {child!r} would close a loop in the tree")
        link = Link(parent, child, static)
        self._links[child] = link
        self._frames.update((parent, child))
        self._paths.clear()
        return link

    def add_static_transform(
        self, parent: str, child: str, translation: Any, rotation: Any
    ) -> None:
        """Add (or replace) a static link ``parent -> child``.

        Parameters
        ----------
        parent, child : str
            Frame names; the transform maps child coordinates into the parent.
        translation : array_like, shape (3,)
        rotation : array_like, shape (4,)
            Quaternion ``(x, y, z, w)``, normalized here.
        """
        link = self._link(parent, child, static=True)
        link.static_matrix = transform_matrix(
            np.asarray(translation, dtype=np.float64).reshape(3),
            np.asarray(rotation, dtype=np.float64).reshape(4),
        )

    def add_transform(
        self, parent: str, child: str, stamp_ns: int, translation: Any, rotation: Any
    ) -> None:
        """Add one sample of the dynamic link ``parent -> child``.

        A sample with the same stamp as an earlier one replaces it.

        Parameters
        ----------
        parent, child : str
        stamp_ns : int
            Nanoseconds since the epoch.
        translation : array_like, shape (3,)
        rotation : array_like, shape (4,)
            Quaternion ``(x, y, z, w)``, normalized here.
        """
        self._add_sample(
            parent,
            child,
            int(stamp_ns),
            [float(x) for x in np.asarray(translation, dtype=np.float64).reshape(3)],
            [float(x) for x in np.asarray(rotation, dtype=np.float64).reshape(4)],
        )

    def _add_sample(
        self, parent: str, child: str, stamp_ns: int, t: Sequence[float], q: Sequence[float]
    ) -> None:
        """:meth:`add_transform` of Python floats (checked here, made into arrays when the
        link is read: a sample costs microseconds, not a few numpy calls)."""
        why = sample_problem(t, q)
        if why is not None:
            raise ValueError(f"transform {parent} -> {child} at {stamp_ns} ns: {why}")
        self._link(parent, child, static=False).add_sample(stamp_ns, t, q)

    def add_transforms(
        self, parent: str, child: str, stamps_ns: Any, translations: Any, rotations: Any
    ) -> None:
        """Add many samples of the dynamic link ``parent -> child`` at once.

        Parameters
        ----------
        parent, child : str
        stamps_ns : array_like of int, shape (K,)
        translations : array_like, shape (K, 3)
        rotations : array_like, shape (K, 4)
            Quaternions ``(x, y, z, w)``, normalized here.
        """
        stamps = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
        trans = np.asarray(translations, dtype=np.float64).reshape(-1, 3)
        quats = np.asarray(rotations, dtype=np.float64).reshape(-1, 4)
        if not stamps.size == trans.shape[0] == quats.shape[0]:
            raise ValueError("stamps, translations and rotations must have the same length")
        if not np.all(np.isfinite(trans)):
            raise ValueError("translations must be finite")
        quats = normalize_quaternions(quats)
        if stamps.size:
            self._link(parent, child, static=False).add(stamps, trans, quats)

    def add_tf_message(self, msg: Any, *, static: bool = False, topic: str | None = None) -> None:
        """Add every transform of a ``tf2_msgs/TFMessage``.

        Parameters
        ----------
        msg : tf2_msgs/TFMessage
        static : bool
            ``True`` for messages of ``/tf_static``: their stamps are ignored.
        topic : str, optional
            With a topic, a sample that cannot be used (non-finite or huge translation,
            non-finite or zero quaternion, empty frame name) is skipped and counted in
            :attr:`skipped`; without one it raises ``ValueError``.
        """
        for ts in msg.transforms:
            tr, rot = ts.transform.translation, ts.transform.rotation
            t = (float(tr.x), float(tr.y), float(tr.z))
            q = (float(rot.x), float(rot.y), float(rot.z), float(rot.w))
            if topic is not None:
                parent, child = str(ts.header.frame_id), str(ts.child_frame_id)
                why = sample_problem(t, q)
                if why is None and not (parent.lstrip("/") and child.lstrip("/")):
                    why = "empty frame name"
                if why is not None:
                    self._skip(topic, parent, child, stamp_to_ns(ts.header), why)
                    continue
            if static:
                self.add_static_transform(ts.header.frame_id, ts.child_frame_id, t, q)
            elif topic is not None:  # checked above
                self._link(parent, child, static=False).add_sample(stamp_to_ns(ts.header), t, q)
            else:
                self._add_sample(
                    ts.header.frame_id, ts.child_frame_id, stamp_to_ns(ts.header), t, q
                )

    def add_pose_message(
        self,
        msg: Any,
        child_frame: str | None = None,
        *,
        parent_frame: str | None = None,
        offset: Any = None,
        topic: str | None = None,
    ) -> None:
        """Add a pose message as a sample of the dynamic link ``parent -> child``.

        Supports ``nav_msgs/Odometry``, ``geometry_msgs/PoseStamped``,
        ``geometry_msgs/PoseWithCovarianceStamped`` and
        ``geometry_msgs/TransformStamped``. The stored transform is
        ``T_parent_child = T_pose @ offset``.

        Parameters
        ----------
        msg : pose message
        child_frame : str, optional
            Default: the message's ``child_frame_id``.
        parent_frame : str, optional
            The fixed frame. Default: ``msg.header.frame_id``.
        offset : array_like (4, 4), optional
            Static transform from the body whose pose the message reports to
            ``child_frame``.
        """
        if hasattr(msg, "transform"):
            tr, rot = msg.transform.translation, msg.transform.rotation
        else:
            pose = msg.pose
            if hasattr(pose, "pose"):
                pose = pose.pose
            tr, rot = pose.position, pose.orientation
        child = child_frame or getattr(msg, "child_frame_id", "")
        parent = parent_frame or msg.header.frame_id
        if not child:
            raise ValueError("child_frame is required for messages without child_frame_id")
        if not parent:
            raise ValueError("parent_frame is required: the message has an empty header.frame_id")
        t = np.array([tr.x, tr.y, tr.z], dtype=np.float64)
        q = np.array([rot.x, rot.y, rot.z, rot.w], dtype=np.float64)
        why = sample_problem(t, q) if topic is not None else None
        if why is not None:  # skipped and counted (see add_tf_message)
            self._skip(topic, parent, child, stamp_to_ns(msg.header), why)
            return
        if offset is not None:
            m = transform_matrix(t, q) @ np.asarray(offset, dtype=np.float64).reshape(4, 4)
            t, q = m[:3, 3], matrix_to_quaternion(m)
        self.add_transform(parent, child, stamp_to_ns(msg.header), t, q)

    # -- queries ----------------------------------------------------------------------------
    @property
    def frames(self) -> list[str]:
        """Sorted names of all frames mentioned by a link."""
        return sorted(self._frames)

    def links(self) -> list[tuple[str, str, bool, int, int | None, int | None]]:
        """``(parent, child, static, n_samples, first_ns, last_ns)`` of every link."""
        out = []
        for child in sorted(self._links):
            link = self._links[child]
            if link.static:
                out.append((link.parent, child, True, 1, None, None))
            else:
                link._finalize()
                out.append(
                    (
                        link.parent,
                        child,
                        False,
                        link.stamps.size,
                        int(link.stamps[0]),
                        int(link.stamps[-1]),
                    )
                )
        return out

    def _check_frame(self, frame: str) -> str:
        name = _norm_frame(frame)
        if name not in self._frames:
            known = ", ".join(map(repr, self.frames)) or "none (the buffer is empty)"
            raise UnknownFrameError(f"unknown frame {frame!r}; known frames: {known}")
        return name

    def _path(self, target: str, source: str) -> tuple[list[Link], list[Link]]:
        key = (target, source)
        path = self._paths.get(key)
        if path is not None:
            return path
        up_s: list[Link] = []
        chain_s = [source]
        frame = source
        while frame in self._links:
            link = self._links[frame]
            up_s.append(link)
            frame = link.parent
            chain_s.append(frame)
        index_s = {f: i for i, f in enumerate(chain_s)}
        up_t: list[Link] = []
        frame = target
        while frame not in index_s:
            link = self._links.get(frame)
            if link is None:
                raise ConnectivityError(
                    f"no transform chain between {target!r} and {source!r}: {target!r} belongs"
                    f" to the tree rooted at {frame!r}, {source!r} to the tree rooted at"
                    f" {chain_s[-1]!r}"
                )
            up_t.append(link)
            frame = link.parent
        path = (up_s[: index_s[frame]], up_t)
        self._paths[key] = path
        return path

    def lookup_many(self, target: str, source: str, stamps_ns: Any) -> np.ndarray:
        """Transforms from ``source`` into ``target`` at many stamps.

        Parameters
        ----------
        target, source : str
            Frame names.
        stamps_ns : array_like of int, shape (K,)

        Returns
        -------
        numpy.ndarray, shape (K, 4, 4)
            ``T_target_source``: ``p_target = T @ p_source`` (homogeneous).

        Raises
        ------
        UnknownFrameError, ConnectivityError, ExtrapolationError
        """
        stamps = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
        tgt, src = self._check_frame(target), self._check_frame(source)
        up_s, up_t = self._path(tgt, src)
        what = f"cannot transform from {src!r} into {tgt!r}"
        result = np.broadcast_to(np.eye(4), (stamps.size, 4, 4))
        # T_anc_source = L_k @ ... @ L_1 with L_1 the link of the source.
        t_anc_src = None
        for link in up_s:
            m = link.matrices(stamps, self.tolerance_ns, what)
            t_anc_src = m if t_anc_src is None else m @ t_anc_src
        t_anc_tgt = None
        for link in up_t:
            m = link.matrices(stamps, self.tolerance_ns, what)
            t_anc_tgt = m if t_anc_tgt is None else m @ t_anc_tgt
        if t_anc_tgt is None:
            result = t_anc_src if t_anc_src is not None else result
        elif t_anc_src is None:
            result = invert_transform(t_anc_tgt)
        else:
            result = invert_transform(t_anc_tgt) @ t_anc_src
        return np.array(result, dtype=np.float64)

    def transform_points(self, target: str, source: str, stamps_ns: Any, points: Any) -> np.ndarray:
        """Points of ``source``, each at its own stamp, in ``target``.

        ``out[k] = T_target_source(stamps_ns[k]) @ points[k]``, as :meth:`lookup_many` would
        give, without building a 4x4 matrix per point: each link of the chain moves the
        points one frame along (a rotation by the interpolated quaternion and a translation,
        or the static link's rotation and translation).

        Parameters
        ----------
        target, source : str
        stamps_ns : array_like of int, shape (K,)
        points : array_like, shape (K, 3)

        Returns
        -------
        numpy.ndarray, shape (K, 3)

        Raises
        ------
        UnknownFrameError, ConnectivityError, ExtrapolationError
        """
        stamps = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if pts.shape[0] != stamps.size:
            raise ValueError(f"transform_points: {stamps.size} stamps for {pts.shape[0]} points")
        tgt, src = self._check_frame(target), self._check_frame(source)
        up_s, up_t = self._path(tgt, src)
        what = f"cannot transform from {src!r} into {tgt!r}"
        for link in up_s:  # up from the source to the common ancestor
            pts = link.to_parent(pts, stamps, self.tolerance_ns, what)
        for link in reversed(up_t):  # down from the common ancestor to the target
            pts = link.to_child(pts, stamps, self.tolerance_ns, what)
        return pts

    def lookup(self, target: str, source: str, stamp_ns: int) -> np.ndarray:
        """Transform from ``source`` into ``target`` at one stamp.

        Parameters
        ----------
        target, source : str
            Frame names.
        stamp_ns : int
            Nanoseconds since the epoch; ignored if the chain is all static.

        Returns
        -------
        numpy.ndarray, shape (4, 4)
            ``T_target_source``: ``p_target = T @ p_source`` (homogeneous).

        Raises
        ------
        UnknownFrameError
            A frame no link mentions; the message lists the known frames.
        ConnectivityError
            The frames are in different trees.
        ExtrapolationError
            The stamp is outside the samples of a dynamic link on the chain.
        """
        tgt, src = self._check_frame(target), self._check_frame(source)
        up_s, up_t = self._path(tgt, src)
        what = f"cannot transform from {src!r} into {tgt!r}"
        stamp = int(stamp_ns)
        tol = self.tolerance_ns
        t_anc_src = np.eye(4)
        for link in up_s:
            t_anc_src = link.matrix_at(stamp, tol, what) @ t_anc_src
        if not up_t:
            return t_anc_src
        t_anc_tgt = np.eye(4)
        for link in up_t:
            t_anc_tgt = link.matrix_at(stamp, tol, what) @ t_anc_tgt
        return invert_transform(t_anc_tgt) @ t_anc_src

    def can_transform(self, target: str, source: str, stamp_ns: int) -> bool:
        """Whether :meth:`lookup` would succeed."""
        try:
            self.lookup(target, source, stamp_ns)
        except TransformError:
            return False
        return True

    def time_range(self, target: str, source: str) -> tuple[int, int] | None:
        """Stamps ``(first, last)`` at which ``target <- source`` can be looked up.

        The intersection of the sampled ranges of the dynamic links on the
        chain (widened by ``tolerance_ns``); ``None`` if the chain is all
        static (valid at any time).

        Raises
        ------
        UnknownFrameError, ConnectivityError
            As :meth:`lookup`. An empty intersection raises
            :class:`ExtrapolationError`.
        """
        tgt, src = self._check_frame(target), self._check_frame(source)
        up_s, up_t = self._path(tgt, src)
        lo, hi = None, None
        for link in up_s + up_t:
            if link.static:
                continue
            link._finalize()
            first = int(link.stamps[0]) - self.tolerance_ns
            last = int(link.stamps[-1]) + self.tolerance_ns
            lo = first if lo is None else max(lo, first)
            hi = last if hi is None else min(hi, last)
        if lo is None or hi is None:
            return None
        if lo > hi:
            raise ExtrapolationError(
                f"the dynamic links between {src!r} and {tgt!r} have no common time range",
                tgt,
                src,
                lo,
                lo,
                hi,
            )
        return lo, hi
