"""A forward-looking camera with a binary 'detection' / 'no detection' output."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def _sigmoid(z: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.tanh(0.5 * z))


@dataclass(frozen=True)
class CameraDetector:
    """Detection probability model of a forward camera with an object detector.

    ``P(detection | target at x) = p_false_alarm + (p_detect - p_false_alarm) * s_r * s_b``:
    ``s_r`` and ``s_b`` are logistic steps that are 1 inside the view cone (range up to
    ``max_range``, bearing within half of ``fov_deg`` of the heading) and fall to 0 across its edges
    with widths ``edge_m`` (metres) and ``edge_deg`` (degrees). Defaults: 42.5 degree field of view,
    1 m range, 0.9 detection probability inside the cone, no false alarms.
    """

    fov_deg: float = 42.5
    max_range: float = 1.0
    p_detect: float = 0.9
    p_false_alarm: float = 0.0
    edge_m: float = 0.05
    edge_deg: float = 2.0

    def __post_init__(self) -> None:
        if not (0.0 <= self.p_false_alarm <= self.p_detect <= 1.0):
            raise ValueError("need 0 <= p_false_alarm <= p_detect <= 1")
        if self.max_range <= 0 or not (0 < self.fov_deg < 360):
            raise ValueError("need max_range > 0 and 0 < fov_deg < 360")

    def p_detection(self, pose, points) -> np.ndarray:
        """``P(detection | x)`` for a pose ``(x, y, heading rad)`` and points ``(..., 2)``."""
        pts = np.asarray(points, dtype=float)
        rel = pts - np.asarray(pose[:2], dtype=float)
        dist = np.hypot(rel[..., 0], rel[..., 1])
        bearing = np.arctan2(rel[..., 1], rel[..., 0]) - pose[2]
        bearing = np.abs((bearing + np.pi) % (2.0 * np.pi) - np.pi)
        s_r = _sigmoid((self.max_range - dist) / (self.edge_m / 4.0))
        s_b = _sigmoid(
            (math.radians(self.fov_deg / 2.0) - bearing) / (math.radians(self.edge_deg) / 4.0)
        )
        return self.p_false_alarm + (self.p_detect - self.p_false_alarm) * s_r * s_b

    def likelihood(self, detected: bool, pose, points) -> np.ndarray:
        """``P(y | x)`` for the observation ``y`` (detection or not)."""
        p = self.p_detection(pose, points)
        return p if detected else 1.0 - p

    def observe(self, pose, target, rng: np.random.Generator) -> bool:
        """One simulated detector output for a target at ``target``."""
        return bool(rng.random() < float(self.p_detection(pose, np.asarray(target, dtype=float))))
