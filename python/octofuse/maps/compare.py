"""Scoring maps against the centralized map (and the ground truth, where there is one)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

from ..threads import thread_map
from .infoloss import InfoLossMap, voxels_per_leaf
from .occupancy import OccupancyMap, ReferenceMap


@dataclass
class Score:
    """How close one agent's map is to the centralized map."""

    kl_mean: float  #: mean KL(central || agent) over voxels the centralized map knows, nats
    agreement: float  #: fraction of those voxels with the same class (occupied/free/unknown)
    agreement_occupied: float  #: of the centralized map's occupied voxels, fraction occupied
    agreement_free: float  #: of its free voxels, fraction free
    overconfidence: float  #: of voxels both know, fraction where |l_agent| > |l_central| + tol
    coverage: float  #: fraction of the centralized map's voxels the agent knows
    mean_abs_logodds_error: float  #: mean |l_agent - l_central| over voxels both know
    loss_mean: float | None = None  #: mean accumulated information loss, nats per voxel
    loss_p95: float | None = None  #: its 95th percentile
    bytes_sent: int | None = None
    bytes_received: int | None = None
    bytes_sent_32b: int | None = None  #: the same messages at 32 bytes per voxel
    occupied_accuracy: float | None = None  #: occupied voxels on a true surface (ground truth)
    voxels: float | None = None  #: finest voxels the centralized map knows

    def to_dict(self) -> dict:
        return asdict(self)


#: values left when sorting them is cheaper than narrowing further (weighted_percentile)
SORT_BELOW = 1 << 15


def weighted_percentile(values: np.ndarray, weights: np.ndarray, q: float) -> float:
    """The first sorted value at which the cumulative weight reaches ``q`` % of the total: the
    smallest value whose weight at or below it does. Whole-number weights (voxel counts) are
    narrowed around ``np.partition`` pivots in O(n) instead of a sort; their partial sums are
    exact in any order, so the result is the sort's. Other weights, or NaN values, are sorted."""
    if len(values) == 0:
        return float("nan")
    total = float(weights.sum())
    if (
        not (np.array_equal(weights, np.floor(weights)) and total < 2.0**53)
        or np.isnan(values).any()
    ):
        return _sorted_percentile(values, weights, q)
    target = q / 100.0 * total
    if target <= 0.0:
        return float(values.min())
    # v: the values left, of weight `rest`; below: the weight of the values left out below v
    v, w, below, rest = values, weights, 0.0, total
    while len(v) > SORT_BELOW:
        if rest <= 0.0:  # the target lies beyond every weight: the last value, as sorted
            return float(v.max())
        rank = min(int((target - below) / rest * (len(v) - 1)), len(v) - 1)
        pivot = np.partition(v, rank)[rank]
        less = v < pivot
        w_less = float(w[less].sum())
        if below + w_less >= target:
            v, w, rest = v[less], w[less], w_less
            continue
        more = v > pivot
        w_more = float(w[more].sum())
        below += rest - w_more  # the values below the pivot and at it
        if below >= target or not more.any():
            return float(pivot)
        v, w, rest = v[more], w[more], w_more
    return _sorted_percentile(v, w, q, below, target)


def _sorted_percentile(
    v: np.ndarray, w: np.ndarray, q: float, below: float = 0.0, target: float | None = None
) -> float:
    """The same by a sort: ``v`` above values of weight ``below`` left out, ``target`` the
    weight to reach (default: ``q`` % of the cumulative weight). Equal values keep their
    order, so weights that are not whole numbers add up as the definition adds them."""
    order = np.argsort(v, kind="stable")
    cw = below + np.cumsum(w[order])
    if target is None:
        target = q / 100.0 * cw[-1]
    return float(v[order][min(np.searchsorted(cw, target), len(v) - 1)])


def loss_stats(values: np.ndarray, depths: np.ndarray) -> tuple[float, float]:
    """Mean and 95th percentile of a loss map over its finest voxels, from its leaves' values
    and depths (:meth:`InfoLossMap.values_depths`)."""
    if len(values) == 0:
        return 0.0, 0.0
    w = voxels_per_leaf(depths)
    mean = float(np.sum(w * values.astype(np.float64)) / np.sum(w))
    # sorted as stored (float32: the same order, in half the time)
    return mean, weighted_percentile(values, w, 95.0)


def compare(central: OccupancyMap | ReferenceMap, agent: OccupancyMap, tol: float = 0.1) -> Score:
    """Score ``agent`` against ``central`` over finest-level voxels."""
    return compare_many(central, [agent], tol)[0]


def compare_many(
    central: OccupancyMap | ReferenceMap,
    agents: Sequence[OccupancyMap],
    tol: float = 0.1,
    threads: int = 1,
) -> list[Score]:
    """:func:`compare` of each of ``agents``, on up to ``threads`` threads (a map at a time, to
    whichever thread is free); ``central`` is read once."""
    ref = central if isinstance(central, ReferenceMap) else ReferenceMap(central)
    counts = thread_map(lambda m: m.class_counts(ref, tol), agents, threads)
    return [_score_of_counts(d) for d in counts]


def _score_of_counts(d: dict) -> Score:
    c = np.array(d["confusion"])  # [central class][agent class]; 0 occ, 1 free, 2 unknown
    known = c[0].sum() + c[1].sum()
    both = d["both_known"]

    def ratio(a, b):
        return float(a / b) if b > 0 else float("nan")

    return Score(
        kl_mean=ratio(d["kl_sum"], known),
        agreement=ratio(c[0, 0] + c[1, 1], known),
        agreement_occupied=ratio(c[0, 0], c[0].sum()),
        agreement_free=ratio(c[1, 1], c[1].sum()),
        overconfidence=ratio(d["overconfident"], both),
        coverage=ratio(c[0, 0] + c[0, 1] + c[1, 0] + c[1, 1], known),
        mean_abs_logodds_error=ratio(d["abs_diff_sum"], both),
        voxels=float(known),
    )


def score(
    agent: OccupancyMap,
    central: OccupancyMap,
    *,
    tol: float = 0.1,
    loss: InfoLossMap | tuple[np.ndarray, np.ndarray] | None = None,
    truth=None,
    bytes_sent: int | None = None,
    bytes_received: int | None = None,
    bytes_sent_32b: int | None = None,
    compared: Score | None = None,
) -> Score:
    """Every metric of one agent: :func:`compare` (or ``compared``, its result for these maps
    from :func:`compare_many`), the statistics of its accumulated ``loss`` (the loss map, or
    its leaves' values and depths as read already: :meth:`InfoLossMap.values_depths`),
    traffic and the occupied-voxel accuracy against a :class:`~octofuse.scene.Scene`."""
    s = compared if compared is not None else compare(central, agent, tol)
    if loss is not None:
        s.loss_mean, s.loss_p95 = loss_stats(
            *(loss.values_depths() if isinstance(loss, InfoLossMap) else loss)
        )
    s.bytes_sent, s.bytes_received, s.bytes_sent_32b = bytes_sent, bytes_received, bytes_sent_32b
    if truth is not None:
        lv = agent.leaves("occupied")
        centers = finest_centers(lv.centers, lv.sizes, agent.resolution)
        s.occupied_accuracy = truth.occupied_accuracy(centers, agent.resolution)
    return s


def finest_centers(centers: np.ndarray, sizes: np.ndarray, resolution: float) -> np.ndarray:
    """Centres of the finest voxels that leaves (centres, edge lengths) stand for: a coarse
    (pruned) leaf counts as all the voxels below it, as in :func:`compare`."""
    centers = np.asarray(centers, dtype=np.float64).reshape(-1, 3)
    span = np.rint(np.asarray(sizes, dtype=np.float64) / resolution).astype(np.int64)
    out = [centers[span <= 1]]
    for k in np.unique(span[span > 1]):
        g = (np.arange(k) + 0.5) * resolution - k * resolution / 2
        offsets = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
        out.append((centers[span == k][:, None, :] + offsets[None]).reshape(-1, 3))
    return np.concatenate(out)
