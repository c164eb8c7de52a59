"""Target beliefs over a robot network: the multi-robot search of paper 000 (section IV-B) and
range-only tracking of paper 004 (:mod:`.tracking`, :func:`.tracking_report.run_tracking`).

Search robots with forward binary detectors update a common Gaussian-mixture prior over a static
target's position by a Gaussian-sum particle filter and share beliefs over a network with the
WEP rules of :mod:`octofuse.beliefs.mixture_fusion`. :func:`run_target_search` runs the
simulation and writes a report.
"""

from .detector import CameraDetector
from .particle_filter import gaussian_sum_update
from .search import SETTINGS, TargetSearchResult
from .search_report import run_target_search

__all__ = [
    "CameraDetector",
    "SETTINGS",
    "TargetSearchResult",
    "gaussian_sum_update",
    "run_target_search",
]
