"""An agent's map against the centralized map, voxel by voxel: where the agent is
over-confident, where it misses the centralized map's class, where the two agree."""

from __future__ import annotations

import numpy as np

from .voxels import Voxels, packed_keys

#: the classes, in the order of their numbers (the values of the voxels returned)
OVER_CONFIDENT, MISSED, AGREEING = 0, 1, 2
CLASSES = ("over-confident", "missed", "agreeing")
MEANINGS = {
    "over-confident": "the agent's |log-odds| exceeds the centralized map's by more than the "
    "run's tolerance",
    "missed": "the agent's class (occupied, free or unknown) differs from the centralized map's",
    "agreeing": "both maps hold the voxel occupied",
}


def difference_voxels(agent, central, resolution: float, tol: float) -> Voxels:
    """The voxels either map holds occupied (``agent``, ``central``: their
    :class:`~octofuse.maps.infoloss.Leaves`, in one frame), each valued by its class:
    :data:`OVER_CONFIDENT` first, then :data:`MISSED`, else :data:`AGREEING`. A voxel one map
    does not know counts as log-odds 0 there (unknown)."""
    parts = [_occupied(agent), _occupied(central)]
    centers = np.concatenate([p[0] for p in parts])
    sizes = np.concatenate([p[1] for p in parts])
    # a voxel both hold occupied at the same place is drawn once
    _, first = np.unique(
        packed_keys(np.floor(centers / (resolution / 2)).astype(np.int64)), return_index=True
    )
    centers, sizes = centers[first], sizes[first]
    a = _known_or_zero(agent.values_at(centers, resolution))
    c = _known_or_zero(central.values_at(centers, resolution))
    cls = np.full(len(centers), AGREEING, dtype=np.float32)
    cls[np.sign(a) != np.sign(c)] = MISSED
    cls[np.abs(a) > np.abs(c) + tol] = OVER_CONFIDENT
    return Voxels(centers, sizes, cls)


def _occupied(leaves) -> tuple[np.ndarray, np.ndarray]:
    occ = np.asarray(leaves.values) > 0
    return (
        np.asarray(leaves.centers, dtype=np.float64)[occ],
        np.asarray(leaves.sizes, dtype=np.float64)[occ],
    )


def _known_or_zero(values: np.ndarray) -> np.ndarray:
    return np.where(np.isfinite(values), values, 0.0)


def class_counts(v: Voxels) -> dict[str, int]:
    """How many voxels of each class ``v`` holds."""
    return {name: int(np.sum(v.values == i)) for i, name in enumerate(CLASSES)}
