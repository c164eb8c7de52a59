"""octofuse: conservative fusion of multi-robot OctoMap occupancy maps.

The per-voxel weighted exponential product (WEP) rules (Chernoff, entropy- and
KLD-weighted Chernoff, minimum information loss) and the naive-Bayes and Bhattacharyya
baselines, applied to whole OctoMap trees by a compiled C++ core.
"""

from __future__ import annotations

from .maps import InfoLossMap, Leaves, MapFileError, MapFusion, OccupancyMap, fuse_into, fuse_maps
from .rules import RULES, WEP_RULES, BernoulliFusion, LogOddsFusion, fuse_bernoulli, fuse_logodds

# the workflow: bags -> maps -> network fusion -> scores (``octofuse.simulate`` is the
# function; its module stays importable as ``from octofuse.network import ...``)
from .build import build_maps  # noqa: E402
from .metrics import Score, compare, score  # noqa: E402
from .network import SimResult, fuse_finished, simulate  # noqa: E402

__version__ = "0.1.0"

__all__ = [
    "RULES",
    "WEP_RULES",
    "BernoulliFusion",
    "InfoLossMap",
    "Leaves",
    "LogOddsFusion",
    "MapFileError",
    "MapFusion",
    "OccupancyMap",
    "fuse_bernoulli",
    "fuse_logodds",
    "Score",
    "SimResult",
    "build_maps",
    "compare",
    "fuse_finished",
    "fuse_into",
    "fuse_maps",
    "score",
    "simulate",
]
