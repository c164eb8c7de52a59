"""Fusion of two occupancy maps voxel by voxel, by walks of both trees in the C++ core: into a
new map, into one of them in place, or both into each other."""

from __future__ import annotations

from typing import NamedTuple

from .. import _core
from ..rules import parse_rule, parse_unknown
from .infoloss import InfoLossMap
from .occupancy import OccupancyMap, thread_count


class MapFusion(NamedTuple):
    """Result of :func:`fuse_maps`."""

    map: OccupancyMap
    info_loss: InfoLossMap


def fuse_maps(
    a: OccupancyMap, b: OccupancyMap, rule: str = "min-info-loss", unknown: str = "copy"
) -> MapFusion:
    """Fuse two occupancy maps voxel by voxel.

    Both trees are walked once, together; a coarse (pruned) leaf stands for all voxels
    below it. A voxel both maps know gets :func:`octofuse.fuse_logodds` of the two values,
    clamped to the maps' clamping thresholds. A voxel known to only one map keeps its value
    (``unknown="copy"``: it carries no common information, so that is the exact fusion) or
    is fused with the prior p = 0.5 (``unknown="prior"``). The GIL is released while fusing.

    The two new trees of large inputs (2^18 nodes or more together) keep their nodes in
    slabs of their own, given back at once when the result is freed (unless nodes were
    added to it since: then it is freed node by node).

    Raises ``ValueError`` if the maps differ in resolution or clamping, or for an unknown
    rule or policy.
    """
    _check_maps("fuse_maps", a, b)
    rule, unknown = parse_rule(rule), parse_unknown(unknown)
    raw_map, raw_loss, counts = _core._fuse_maps(a._m, b._m, rule, unknown)
    return MapFusion(OccupancyMap._wrap(raw_map), InfoLossMap._wrap(raw_loss, *counts[:3]))


def fuse_into(
    dst: OccupancyMap,
    msg: OccupancyMap,
    rule: str = "min-info-loss",
    unknown: str = "copy",
    loss: InfoLossMap | None = None,
    threads: int = 1,
) -> InfoLossMap | None:
    """Fuse ``msg`` into ``dst`` in place (the result equals ``fuse_maps(dst, msg)``).

    With ``unknown="copy"`` the work is proportional to the message, not to ``dst``: this is
    how an agent fuses each received map (or delta) into its own. The information loss of
    the fused voxels is added into ``loss`` (in place) if given, with the counts of finest
    voxels fused and copied (voxels only the message knows); returns ``loss``. With
    ``threads`` > 1, disjoint subtrees are fused on that many threads (same result).
    """
    _check_maps("fuse_into", dst, msg)
    rule, unknown = parse_rule(rule), parse_unknown(unknown)
    counts = _core._fuse_into(
        dst._m, msg._m, rule, unknown, _loss_tree(loss, dst), threads=thread_count(threads)
    )
    if loss is not None:
        loss._record(counts)
    return loss


def subtract_into(dst: OccupancyMap, msg: OccupancyMap) -> None:
    """``dst -= msg`` voxel by voxel in log-odds, in place (a voxel only ``msg`` knows gets
    its negated value): the naive-Bayes fusion of a negated copy of ``msg``, bit for bit,
    without the copy."""
    _check_maps("subtract_into", dst, msg)
    _core._subtract_into(dst._m, msg._m)


def exchange_maps(
    a: OccupancyMap,
    b: OccupancyMap,
    rule: str = "min-info-loss",
    unknown: str = "copy",
    loss_a: InfoLossMap | None = None,
    loss_b: InfoLossMap | None = None,
) -> tuple[int, int]:
    """A simultaneous two-way exchange, in place: ``a`` fuses ``b`` and ``b`` fuses ``a``
    (each as it was before), in one walk and without copying either map. Equal to
    ``fuse_into(a, b0)`` and ``fuse_into(b, a0)``. Losses are added into ``loss_a``/``loss_b``.
    Returns the leaves ``a`` and ``b`` had, i.e. the sizes of the two messages in voxels
    (counted by the walk: ``a0.num_leaves`` and ``b0.num_leaves``).
    """
    _check_maps("exchange_maps", a, b)
    rule, unknown = parse_rule(rule), parse_unknown(unknown)
    counts_a, counts_b = _core._fuse_mutual(
        a._m, b._m, rule, unknown, _loss_tree(loss_a, a), _loss_tree(loss_b, b)
    )
    for loss, counts in ((loss_a, counts_a), (loss_b, counts_b)):
        if loss is not None:
            loss._record(counts)
    return int(counts_b[3]), int(counts_a[3])  # what a received is b's


def _check_maps(function: str, a, b) -> None:
    if not isinstance(a, OccupancyMap) or not isinstance(b, OccupancyMap):
        raise TypeError(f"{function} expects two OccupancyMap objects")


def _loss_tree(loss: InfoLossMap | None, dst: OccupancyMap):
    """The core's tree of ``loss`` for a fusion into ``dst``, or None."""
    return None if loss is None else loss._tree_for(dst)
