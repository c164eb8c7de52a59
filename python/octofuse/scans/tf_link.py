"""Links of a transform tree: one parent -> child transform over time (static, or dynamic
samples interpolated linearly in translation and by shortest-arc slerp in rotation), and the
errors of looking transforms up. :class:`octofuse.scans.tf.TransformBuffer` chains them."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from .se3 import (
    normalize_quaternions,
    quaternion_to_matrix,
    rotate_vectors,
    slerp_arcs,
    slerp_at,
)

#: translations beyond this (metres) are refused: no map reaches that far and float64 poses
#: lose sub-millimetre precision there
MAX_TRANSLATION_M = 1e12


def sample_problem(t: Sequence[float], q: Sequence[float]) -> str | None:
    """Why a transform sample (translation, quaternion) cannot be used, or ``None`` (on
    Python floats: one sample of a message costs a few microseconds)."""
    if not all(math.isfinite(x) for x in t):
        return "non-finite translation"
    if not all(math.isfinite(x) for x in q):
        return "non-finite rotation quaternion"
    if math.sqrt(sum(x * x for x in q)) < 1e-12:
        return "zero rotation quaternion"
    if max(abs(x) for x in t) > MAX_TRANSLATION_M:
        return f"translation beyond {MAX_TRANSLATION_M:g} m"
    return None


class TransformError(Exception):
    """Base class of the errors raised by :class:`TransformBuffer`."""


class UnknownFrameError(TransformError):
    """A frame that no link of the buffer mentions (the message lists the known frames)."""


class ConnectivityError(TransformError):
    """Both frames are known but lie in different, unconnected trees."""


class ExtrapolationError(TransformError):
    """The stamp lies outside the sampled time range of a dynamic link on the chain.

    Attributes
    ----------
    parent, child : str
        The link that cannot be evaluated.
    stamp_ns : int
        The requested stamp.
    first_ns, last_ns : int
        Stamps of the first and last sample of the link.
    """

    def __init__(
        self, message: str, parent: str, child: str, stamp_ns: int, first_ns: int, last_ns: int
    ) -> None:
        super().__init__(message)
        self.parent = parent
        self.child = child
        self.stamp_ns = stamp_ns
        self.first_ns = first_ns
        self.last_ns = last_ns


#: multiplies a quaternion (x, y, z, w) into its conjugate (the inverse rotation)
_CONJUGATE = np.array([-1.0, -1.0, -1.0, 1.0])


def fmt_ns(ns: int) -> str:
    return f"{ns} ns ({ns / 1e9:.6f} s)"


# -- links ----------------------------------------------------------------------------------


class Link:
    """One parent -> child link; dynamic samples are kept sorted in numpy arrays."""

    def __init__(self, parent: str, child: str, static: bool) -> None:
        self.parent = parent
        self.child = child
        self.static = static
        self.static_matrix = np.eye(4)
        self._pending: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        #: single samples (stamp, translation, quaternion not yet normalized) added since,
        #: made into arrays at once when the link is read
        self._samples: list[tuple[int, Sequence[float], Sequence[float]]] = []
        self.stamps = np.empty(0, dtype=np.int64)
        self.trans = np.empty((0, 3), dtype=np.float64)
        self.quats = np.empty((0, 4), dtype=np.float64)
        self._arcs_cache: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def add(self, stamps: np.ndarray, trans: np.ndarray, quats: np.ndarray) -> None:
        self._take_samples()  # the order of adding decides between samples of one stamp
        self._pending.append((stamps, trans, quats))

    def add_sample(self, stamp_ns: int, t: Sequence[float], q: Sequence[float]) -> None:
        """One sample of finite values and a non-zero quaternion (normalized when read)."""
        self._samples.append((stamp_ns, t, q))

    def _take_samples(self) -> None:
        if self._samples:
            stamps, t, q = zip(*self._samples)
            self._samples.clear()
            quats = normalize_quaternions(np.array(q, dtype=np.float64).reshape(-1, 4))
            self._pending.append(
                (
                    np.array(stamps, dtype=np.int64),
                    np.array(t, dtype=np.float64).reshape(-1, 3),
                    quats,
                )
            )

    def _finalize(self) -> None:
        self._take_samples()
        if not self._pending:
            return
        stamps = np.concatenate([self.stamps] + [p[0] for p in self._pending])
        trans = np.concatenate([self.trans] + [p[1] for p in self._pending])
        quats = np.concatenate([self.quats] + [p[2] for p in self._pending])
        self._pending.clear()
        order = np.argsort(stamps, kind="stable")
        stamps = stamps[order]
        # Several samples at one stamp: the one added last wins.
        keep = np.ones(stamps.size, dtype=bool)
        keep[:-1] = stamps[1:] != stamps[:-1]
        order = order[keep]
        self.stamps = stamps[keep]
        self.trans = trans[order]
        self.quats = quats[order]
        self._arcs_cache = None

    def _arcs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:func:`slerp_arcs` of every pair of consecutive samples (computed once)."""
        if self._arcs_cache is None:
            self._arcs_cache = slerp_arcs(self.quats[:-1], self.quats[1:])
        return self._arcs_cache

    def _extrapolation(self, stamps: np.ndarray, bad: np.ndarray, what: str) -> ExtrapolationError:
        s = self.stamps
        first, last = int(s[0]), int(s[-1])
        t = int(stamps[np.argmax(bad)])
        side = (
            f"{(first - t) / 1e9:.6f} s before the first sample"
            if t < first
            else f"{(t - last) / 1e9:.6f} s after the last sample"
        )
        extra = (
            f" ({int(bad.sum())} of {stamps.size} stamps are outside)" if stamps.size > 1 else ""
        )
        return ExtrapolationError(
            f"{what} at {fmt_ns(t)}: link {self.parent!r} -> {self.child!r} has "
            f"{s.size} sample(s) from {fmt_ns(first)} to {fmt_ns(last)}; the stamp is "
            f"{side}{extra}",
            self.parent,
            self.child,
            t,
            first,
            last,
        )

    def matrix_at(self, stamp: int, tolerance_ns: int, what: str) -> np.ndarray:
        """T_parent_child at one stamp, shape (4, 4)."""
        if self.static:
            return self.static_matrix
        return self.matrices(np.array([stamp], dtype=np.int64), tolerance_ns, what)[0]

    def matrices(self, stamps: np.ndarray, tolerance_ns: int, what: str) -> np.ndarray:
        """Transforms T_parent_child at the stamps (K,), shape (K, 4, 4)."""
        if self.static:
            return np.broadcast_to(self.static_matrix, (stamps.size, 4, 4))
        trans, quats = self.interpolate(stamps, tolerance_ns, what)
        m = np.zeros((stamps.size, 4, 4), dtype=np.float64)
        m[:, :3, :3] = quaternion_to_matrix(quats)
        m[:, :3, 3] = trans
        m[:, 3, 3] = 1.0
        return m

    def to_parent(
        self, points: np.ndarray, stamps: np.ndarray, tolerance_ns: int, what: str
    ) -> np.ndarray:
        """Points (K, 3) of the child frame, each at its stamp (K,), in the parent frame."""
        if self.static:
            return points @ self.static_matrix[:3, :3].T + self.static_matrix[:3, 3]
        trans, quats = self.interpolate(stamps, tolerance_ns, what)
        return rotate_vectors(quats, points) + trans

    def to_child(
        self, points: np.ndarray, stamps: np.ndarray, tolerance_ns: int, what: str
    ) -> np.ndarray:
        """Points (K, 3) of the parent frame, each at its stamp (K,), in the child frame."""
        if self.static:
            return (points - self.static_matrix[:3, 3]) @ self.static_matrix[:3, :3]
        trans, quats = self.interpolate(stamps, tolerance_ns, what)
        return rotate_vectors(quats * _CONJUGATE, points - trans)

    def interpolate(
        self, stamps: np.ndarray, tolerance_ns: int, what: str
    ) -> tuple[np.ndarray, np.ndarray]:
        """Translations (K, 3) and unit quaternions (K, 4) of a dynamic link at the stamps (K,)."""
        self._finalize()
        s = self.stamps
        first, last = int(s[0]), int(s[-1])
        bad = (stamps < first - tolerance_ns) | (stamps > last + tolerance_ns)
        if bad.any():
            raise self._extrapolation(stamps, bad, what)
        t = np.clip(stamps, first, last)
        n = s.size
        if n == 1:
            trans = np.broadcast_to(self.trans[0], (t.size, 3))
            quats = np.broadcast_to(self.quats[0], (t.size, 4))
        else:
            i1 = np.clip(np.searchsorted(s, t, side="left"), 1, n - 1)
            i0 = i1 - 1
            s0, s1 = s[i0], s[i1]
            a = (t - s0).astype(np.float64) / (s1 - s0).astype(np.float64)
            q0, q1 = self.quats[i0], self.quats[i1]
            t0, t1 = self.trans[i0], self.trans[i1]
            trans = t0 + a[:, None] * (t1 - t0)
            q1_near, theta, sin_t = self._arcs()
            quats = slerp_at(q0, q1_near[i0], theta[i0], sin_t[i0], a)
            # Exact at the samples.
            at0, at1 = (a == 0.0)[:, None], (a == 1.0)[:, None]
            if at0.any() or at1.any():
                trans = np.where(at0, t0, np.where(at1, t1, trans))
                quats = np.where(at0, q0, np.where(at1, q1, quats))
        return trans, quats
