"""The agents' own map frames in a run, and the alignment of a link on first contact.

Every agent maps in its own frame: ``frames[NAME]`` is the rigid transform taking a point of
NAME's map frame into the common frame (agents not listed are in the common frame). A message
from ``s`` to ``d`` is moved by ``T_d^-1 @ T_s`` into the receiver's frame and resampled to the
receiver's resolution before it is fused (:func:`moved`: point sampling, so that maps moved
back and forth at every exchange do not thicken); between agents of one frame it is fused as
it is.

With ``align`` (``planar`` or ``full``) a link's transform is estimated instead: at the first
message on a link the receiver registers the message map against its own map
(:func:`octofuse.maps.registration.register`). A registration alone is not trusted (in
repetitive rooms one matches a similar place metres away): it must be confirmed by a second,
independent one that agrees within :data:`AGREE_M` and :data:`AGREE_DEG`: the link's own at a
later message, on grown maps, with a new RANSAC seed (two seeds on the same maps agree on a
wrong match of repetitive rooms too). Only the receiver's own estimates count
(what a robot knows without further messages), so agents in different processes align alike.
Until then, or when registration refuses (too little overlap yet), the message is not fused
(it still counts as sent) and the link tries again later (at its 2nd, 4th, 8th, ... message);
once confirmed, the link keeps the transform. A link registers at most :data:`MAX_ATTEMPTS` times and is then refused
for the run, which bounds the cost; the time spent is kept per link. A link aligns once for all
rules (on the first rule's maps), so every rule fuses the same messages. The known frames, if
any, then serve as the reference the estimate's error is measured against.

The centralized map and the scores are in the common frame: an agent's scans reach the
centralized map moved by its frame, and its maps are moved into the common frame to be scored.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..config import ALIGN_MODES
from ..maps.frames import invert, matrix_pose, pose_matrix

#: registrations a link tries before it is refused for the run (bounds the cost of alignment);
#: they are spread over the run: at the link's 1st, 2nd, 4th, 8th, ... delivered message
MAX_ATTEMPTS = 5
#: two estimates of a link confirm each other when they differ by at most this translation...
AGREE_M = 0.3
#: ... and this rotation angle (degrees)
AGREE_DEG = 3.0


@dataclass
class LinkAlignment:
    """The alignment of one directed link (messages from ``sender`` fused by ``receiver``)."""

    sender: str
    receiver: str
    matrix: np.ndarray | None = None  #: sender's frame -> receiver's frame; None: not aligned
    time_s: float | None = None  #: time of the message it aligned on
    attempts: int = 0  #: registrations tried (the last one succeeded if aligned)
    messages: int = 0  #: delivered messages while not aligned
    fitness: float = 0.0
    refusal: str = ""  #: why the last refused registration refused
    reference: np.ndarray | None = None  #: the transform the agent frames give, if any
    conflict: float = 0.0
    confirmed_by: str = ""  #: what confirmed the estimate
    seconds: float = 0.0  #: wall time of the link's registrations
    #: estimates not confirmed yet: (matrix, fitness, conflict, time_s)
    candidates: list = field(default_factory=list)

    @property
    def exhausted(self) -> bool:
        return self.matrix is None and self.attempts >= MAX_ATTEMPTS

    def as_dict(self) -> dict:
        d = {
            "sender": self.sender,
            "receiver": self.receiver,
            "aligned": self.matrix is not None,
            "time_s": self.time_s,
            "attempts": self.attempts,
            "fitness": self.fitness,
            "seconds": self.seconds,
        }
        if self.matrix is None:
            d["refusal"] = self.refusal
            if self.candidates:
                d["unconfirmed"] = [matrix_pose(c[0]) for c in self.candidates]
            return d
        d["estimate"] = matrix_pose(self.matrix)
        d["conflict"], d["confirmed_by"] = self.conflict, self.confirmed_by
        if self.reference is not None:
            d["error_m"], d["error_deg"] = transform_error(self.matrix, self.reference)
        return d


def moved(m, T: np.ndarray | None, resolution: float | None = None):
    """``m`` moved by ``T`` (None: not moved) onto a grid of ``resolution`` (default: its own);
    ``m`` itself when nothing changes. Point sampling (``resampling="nearest"``): maps moved
    between frames at every exchange keep their surfaces' thickness and known extent."""
    res = m.resolution if resolution is None else resolution
    if T is None and abs(m.resolution - res) <= 1e-9 * res:
        return m
    return m.transformed(np.eye(4) if T is None else T, res, resampling="nearest")


def transform_error(estimate: np.ndarray, reference: np.ndarray) -> tuple[float, float]:
    """Translation (metres) and rotation angle (degrees) of ``reference^-1 @ estimate``."""
    E = invert(reference) @ estimate
    cos = max(-1.0, min(1.0, (float(np.trace(E[:3, :3])) - 1.0) / 2.0))
    return float(np.linalg.norm(E[:3, 3])), math.degrees(math.acos(cos))


class AgentFrames:
    """The frames of a run's agents and the per-link alignment state."""

    def __init__(
        self,
        agents: Sequence[str],
        frames: Mapping[str, np.ndarray] | None = None,
        align: str = "off",
    ):
        self.agents = list(agents)
        frames = dict(frames or {})
        unknown = [n for n in frames if n not in self.agents]
        if unknown:
            raise ValueError(
                f"fuse.agent_frames: unknown agent '{unknown[0]}' (agents: "
                f"{', '.join(self.agents)})"
            )
        if align not in ALIGN_MODES:
            raise ValueError(f"fuse.align = {align!r}: expected one of {', '.join(ALIGN_MODES)}")
        #: agent -> its frame into the common frame; identity frames are left out
        self.frames = {
            a: np.asarray(T, dtype=float)
            for a, T in frames.items()
            if not np.array_equal(T, np.eye(4))
        }
        self.align = align
        self.links: dict[tuple[str, str], LinkAlignment] = {}

    @classmethod
    def from_config(cls, agents: Sequence[str], fuse_cfg) -> AgentFrames:
        return cls(
            agents, {f.name: pose_matrix(*f.pose) for f in fuse_cfg.agent_frames}, fuse_cfg.align
        )

    @property
    def active(self) -> bool:
        """Whether any message or score needs a transform."""
        return bool(self.frames) or self.align != "off"

    def plain(self, s: str, d: str) -> bool:
        """A message from ``s`` is fused by ``d`` as it is (no transform, no alignment)."""
        return self.align == "off" and self.reference(s, d) is None

    def reference(self, s: str, d: str) -> np.ndarray | None:
        """``T_d^-1 @ T_s`` from the agent frames; None when the two share a frame."""
        Ts, Td = self.frames.get(s), self.frames.get(d)
        if (
            Ts is None
            and Td is None
            or (Ts is not None and Td is not None and np.array_equal(Ts, Td))
        ):
            return None
        eye = np.eye(4)
        return invert(eye if Td is None else Td) @ (eye if Ts is None else Ts)

    def aligned(self, s: str, d: str) -> bool:
        """Messages on the link may be fused (alignment off, or the link has aligned)."""
        if self.align == "off":
            return True
        link = self.links.get((s, d))
        return link is not None and link.matrix is not None

    def to_receiver(self, s: str, d: str, m, resolution: float):
        """The message map ``m`` of ``s`` in ``d``'s frame at ``d``'s ``resolution`` (``m``
        itself when nothing changes)."""
        if self.align == "off":
            T = self.reference(s, d)
        else:
            T = self.links[(s, d)].matrix
        return moved(m, T, resolution)

    def to_common(self, agent: str, m):
        """``agent``'s map ``m`` moved into the common frame (``m`` itself in that frame)."""
        return moved(m, self.frames.get(agent))

    def align_links(self, events: Sequence[tuple[str, str, bool, float]], maps: Mapping) -> None:
        """Register the links of ``events`` ``(sender, receiver, lost, time_s)`` that carry
        a delivered message and have not aligned yet: the receiver's map in ``maps`` against
        the sender's (both as they are when the messages are sent)."""
        if self.align == "off":
            return
        from ..maps.registration import register

        for s, d, lost, t in events:
            link = self._link(s, d)
            if lost or link.matrix is not None or link.exhausted:
                continue
            link.messages += 1
            if link.messages & (link.messages - 1):  # not a power of two: wait
                continue
            link.attempts += 1
            t0 = time.perf_counter()
            try:
                # a new RANSAC seed at each attempt, on grown maps: a second estimate
                reg = register(
                    maps[d], maps[s], planar=self.align == "planar", seed=link.attempts - 1
                )
            except ValueError as e:
                link.refusal = str(e)
                continue
            finally:
                link.seconds += time.perf_counter() - t0
            self._confirm(link, (reg.matrix, reg.fitness, reg.conflict, t))

    def _link(self, s: str, d: str) -> LinkAlignment:
        link = self.links.get((s, d))
        if link is None:
            ref = self.reference(s, d)
            link = self.links[(s, d)] = LinkAlignment(
                s, d, reference=(np.eye(4) if ref is None else ref) if self.frames else None
            )
        return link

    @staticmethod
    def _confirm(link: LinkAlignment, estimate: tuple) -> None:
        """Keep ``estimate`` of ``link`` if an earlier one of the link agrees with it; else
        hold it as a candidate."""
        T = estimate[0]
        others = [(c[0], f"a second registration (t = {c[3]:g} s)") for c in link.candidates]
        for U, what in others:
            dm, ddeg = transform_error(T, U)
            if dm <= AGREE_M and ddeg <= AGREE_DEG:
                link.matrix, link.fitness, link.conflict, link.time_s = estimate
                link.confirmed_by, link.refusal, link.candidates = what, "", []
                return
        link.candidates.append(estimate)
        link.refusal = "not confirmed: " + (
            "no second estimate yet"
            if not others
            else "the estimates disagree by "
            + ", ".join("{:.2f} m / {:.1f} deg".format(*transform_error(T, U)) for U, _ in others)
        )

    def report(self) -> list[dict]:
        """Per link (sorted): whether and when it aligned, its estimate and error."""
        return [self.links[k].as_dict() for k in sorted(self.links)]

    def scan_targets(
        self, scans: Sequence, targets: Sequence[list], common: Sequence
    ) -> tuple[list, list]:
        """Scans and their target maps with the maps of the common frame (``common``: the
        centralized map, and its unclamped twin) added: a scan of an agent in the common
        frame also goes into them; one of an agent with its own frame is followed by a copy
        moved by that frame (points and origin) for them."""
        out_scans, out_targets = [], []
        for scan, tgt in zip(scans, targets):
            moved_scan = self.scan_in_common(scan)
            if moved_scan is scan:
                out_scans.append(scan)
                out_targets.append([*tgt, *common])
            else:
                out_scans += [scan, moved_scan]
                out_targets += [list(tgt), list(common)]
        return out_scans, out_targets

    def scan_in_common(self, scan):
        """``scan`` of its agent's frame in the common frame (its pose moved by that frame;
        ``scan`` itself for an agent in the common frame)."""
        T = self.frames.get(self.agents[scan.agent])
        return scan if T is None else dataclasses.replace(scan, pose=T @ scan.pose)


def alignment_lines(alignment: Sequence[dict]) -> list[str]:
    """One line per link for the terminal: the estimate, its fitness, conflict and what
    confirmed it, or why the link was refused; then the registrations' count and time."""
    out = []
    for d in alignment:
        link = f"align {d['sender']} -> {d['receiver']}"
        if d["aligned"]:
            e = d["estimate"]
            line = (
                f"{link}: x {e['x']:.2f} m, y {e['y']:.2f} m, z {e['z']:.2f} m, yaw "
                f"{math.degrees(e['yaw']):.1f} deg at t = {d['time_s']:g} s; fitness "
                f"{d['fitness']:.2f}, conflict {d.get('conflict', 0.0):.1%}, confirmed by "
                f"{d.get('confirmed_by') or 'its registration'}"
            )
            if "error_m" in d:
                line += f"; error {d['error_m']:.2f} m, {d['error_deg']:.1f} deg"
        elif d["attempts"]:
            line = (
                f"{link}: refused, not fused ({d['attempts']} registration(s)): "
                f"{' '.join(str(d.get('refusal', '')).split())}"
            )
        else:
            line = f"{link}: no message delivered, not aligned"
        out.append(line)
    if alignment:
        tries = sum(d["attempts"] for d in alignment)
        secs = sum(d.get("seconds", 0.0) for d in alignment)
        out.append(
            f"alignment: {sum(d['aligned'] for d in alignment)} of {len(alignment)} links "
            f"aligned; {tries} registration(s) (at most {MAX_ATTEMPTS} per link) took "
            f"{secs:.1f} s"
        )
    return out


def frames_section(frames: Mapping[str, np.ndarray], alignment: Sequence[dict]) -> list[str]:
    """The report's lines on the agents' frames and the links' alignment."""
    lines = ["## Agent frames", ""]
    for a, T in frames.items():
        p = matrix_pose(T)
        lines.append(
            f"- `{a}` -> common frame: x {p['x']:.3f} m, y {p['y']:.3f} m, z "
            f"{p['z']:.3f} m, roll {math.degrees(p['roll']):.2f}, pitch "
            f"{math.degrees(p['pitch']):.2f}, yaw {math.degrees(p['yaw']):.2f} deg"
        )
    if frames:
        lines += [
            "",
            "Every other agent maps in the common frame; messages are moved into the "
            "receiver's frame, scores are taken in the common frame.",
            "",
        ]
    if alignment:
        with_error = any("error_m" in d for d in alignment)
        head = "| link | aligned at | tries | fitness | x m | y m | z m | yaw deg |"
        lines += [
            "Alignment on first contact (messages on a link are fused once it aligned):",
            "",
            head + (" error m | error deg |" if with_error else ""),
            "|" + "---|" * (8 + 2 * with_error),
        ]
        for d in alignment:
            link = f"`{d['sender']}` -> `{d['receiver']}`"
            if not d["aligned"]:
                lines.append(f"| {link} | never | {d['attempts']} |" + " |" * (5 + 2 * with_error))
                continue
            e = d["estimate"]
            row = (
                f"| {link} | {d['time_s']:g} | {d['attempts']} | {d['fitness']:.2f} | "
                f"{e['x']:.3f} | {e['y']:.3f} | {e['z']:.3f} | {math.degrees(e['yaw']):.2f} |"
            )
            if with_error:
                row += f" {d['error_m']:.3f} | {d['error_deg']:.2f} |"
            lines.append(row)
        lines += [
            "",
            "Per link, on the terminal as in this list:",
            "",
            *(f"- {x}" for x in alignment_lines(alignment)),
            "",
        ]
    return lines
