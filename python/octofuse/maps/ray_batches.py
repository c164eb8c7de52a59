"""Scans inserted into maps in batches by the C++ core: rays traced once per scan and applied to
every map that receives it."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .. import _core
from .occupancy import OccupancyMap, insert_mode


def insert_batch(
    points: Sequence[np.ndarray],
    poses: np.ndarray,
    max_ranges: np.ndarray,
    targets: Sequence[Sequence[OccupancyMap]],
    threads: int,
    mode: str = "exact",
) -> None:
    """Insert scans (sensor frame, 4x4 poses) into their target maps in one C++ call.

    Each scan's ray keys are computed once (scans in parallel) and applied to each of its
    targets, different maps in parallel; the result equals OctoMap's insertPointCloud of
    every scan into every target, in order (``mode="fast"``: the real-time mode of
    :meth:`OccupancyMap.insert_scan`). The GIL is released.
    """
    _core._insert_batch(
        _core_targets(targets),
        *_batch_arrays(points, poses, max_ranges),
        int(threads),
        mode=insert_mode(mode),
    )


def trace_rays(
    grid: OccupancyMap,
    points: Sequence[np.ndarray],
    poses: np.ndarray,
    max_ranges: np.ndarray,
    threads: int,
    mode: str = "exact",
):
    """Trace scans' rays once on ``grid``'s grid (as :func:`insert_batch`, no map changes):
    the updates, to apply to any maps of that grid with :func:`apply_rays`. The GIL is
    released."""
    return _core._trace_rays(
        grid._m, *_batch_arrays(points, poses, max_ranges), int(threads), mode=insert_mode(mode)
    )


def apply_rays(rays, targets: Sequence[Sequence[OccupancyMap]], threads: int) -> None:
    """Apply traced rays (:func:`trace_rays`) to maps: ``targets[k]`` receive scan ``k``; each
    map its scans in order, maps in parallel. The GIL is released."""
    _core._apply_rays(rays, _core_targets(targets), int(threads))


def _batch_arrays(points, poses, max_ranges) -> tuple[list, np.ndarray, np.ndarray]:
    """A batch's points, poses and maximum ranges as the core reads them (C-contiguous)."""
    return (
        [np.ascontiguousarray(p) for p in points],
        np.ascontiguousarray(poses, dtype=np.float64),
        np.ascontiguousarray(max_ranges, dtype=np.float64),
    )


def _core_targets(targets: Sequence[Sequence[OccupancyMap]]) -> list[list]:
    """Each scan's target maps as the core's objects."""
    return [[m._m for m in t] for t in targets]
