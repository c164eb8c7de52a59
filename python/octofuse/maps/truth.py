"""Ground truth of a simulated scene (axis-aligned boxes) for scoring map accuracy."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import _core


@dataclass
class Scene:
    """Boxes (B, 2, 3): min and max corners, with their names and kinds."""

    boxes: np.ndarray
    names: list[str]
    kinds: list[str]

    @classmethod
    def load(cls, path: str | Path) -> Scene:
        p = Path(path)
        try:
            data = json.loads(p.read_text())
            corners = [_corners(b, k) for k, b in enumerate(data["boxes"])]
            boxes = np.array(corners, dtype=float).reshape(-1, 2, 3)  # (0, 2, 3) without boxes
            return cls(
                boxes,
                [b.get("name", "") for b in data["boxes"]],
                [b.get("kind", "") for b in data["boxes"]],
            )
        except FileNotFoundError:
            raise FileNotFoundError(f"scene file '{p}' does not exist") from None
        except (KeyError, TypeError, ValueError) as e:
            raise ValueError(
                f"scene file '{p}' is not a scene description "
                f"(expected boxes with min/max corners): {e}"
            ) from None

    @classmethod
    def find(cls, path: str | Path | None, bags) -> Scene | None:
        """The scene at ``path``, or else the one shipped beside the first bag that has one."""
        if path is not None:
            return cls.load(path)
        for b in bags:
            beside = cls.beside(b)
            if beside is not None:
                return cls.load(beside)
        return None

    @staticmethod
    def beside(bag: str | Path) -> Path | None:
        """The ground-truth file shipped beside a bag (``NAME_scene.json``), if any."""
        p = Path(bag)
        cand = p.with_name(p.stem + "_scene.json")
        return cand if cand.is_file() else None

    def signed_distance(self, points: np.ndarray, chunk: int = 200_000) -> np.ndarray:
        """Distance to the nearest box surface; negative inside a box."""
        pts = np.asarray(points, dtype=float).reshape(-1, 3)
        out = np.empty(len(pts))
        lo, hi = self.boxes[:, 0], self.boxes[:, 1]
        for s in range(0, len(pts), chunk):
            p = pts[s : s + chunk, None, :]
            d_out = np.maximum(np.maximum(lo - p, p - hi), 0.0)
            outside = np.linalg.norm(d_out, axis=2)
            inside = -np.min(np.minimum(p - lo, hi - p), axis=2)
            d = np.where(outside > 0, outside, inside)
            # inside one box but near another's surface: the smallest magnitude wins
            out[s : s + chunk] = d[np.arange(len(d)), np.argmin(np.abs(d), axis=1)]
        return out

    def near_surface(self, points: np.ndarray, tol: float) -> np.ndarray:
        """Whether each point lies within ``tol`` of a box surface (``|signed_distance| <=
        tol``), by the core: each point against the boxes of its cell in a grid over the
        boxes, with the arithmetic of :meth:`signed_distance`."""
        pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        return _core._near_box_surfaces(pts, self.boxes, float(tol))

    def occupied_accuracy(
        self, centers: np.ndarray, voxel_size: float, noise: float = 0.03
    ) -> float:
        """Fraction of occupied voxel centres within a voxel half-diagonal (+ range noise)
        of a true surface."""
        if len(centers) == 0:
            return float("nan")
        tol = voxel_size * np.sqrt(3) / 2 + noise
        return float(np.mean(self.near_surface(centers, tol)))


def _corners(box: dict, k: int) -> np.ndarray:
    """A scene box's min and max corners (2 x 3), checked."""
    lo, hi = (np.asarray(box[key], dtype=float) for key in ("min", "max"))
    if lo.shape != (3,) or hi.shape != (3,) or not np.isfinite([lo, hi]).all():
        raise ValueError(
            f"box {box.get('name') or k + 1}: min and max must be 3 finite numbers each"
        )
    return np.stack([lo, hi])
