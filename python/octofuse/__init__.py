"""octofuse: conservative fusion of multi-robot beliefs (OctoMap occupancy maps first).

The per-voxel weighted exponential product (WEP) rules (Chernoff, entropy- and
KLD-weighted Chernoff, minimum information loss) and the naive-Bayes and Bhattacharyya
baselines, applied to whole OctoMap trees by a compiled C++ core.

The package follows the data flow: ``scans`` (bags to posed scans) -> ``maps`` (scans to
maps, map fusion, scores) -> ``fusion`` (maps exchanged over a graph) -> ``outputs``
(reports, exports, studies); ``beliefs`` and ``targets`` hold the same rules on target
beliefs. ``import octofuse`` loads nothing else: every public name below is imported on its
first use (so that the ``octofuse`` program can catch an interruption while it imports).
"""

from __future__ import annotations

import importlib

#: public name -> module that defines it (imported on first access)
_LAZY = {
    "InfoLossMap": "maps.infoloss",
    "Leaves": "maps.infoloss",
    "MapFileError": "maps.occupancy",
    "OccupancyMap": "maps.occupancy",
    "MapFusion": "maps.tree_fusion",
    "exchange_maps": "maps.tree_fusion",
    "fuse_into": "maps.tree_fusion",
    "fuse_maps": "maps.tree_fusion",
    "RULES": "rules",
    "WEP_RULES": "rules",
    "BernoulliFusion": "rules",
    "LogOddsFusion": "rules",
    "fuse_bernoulli": "rules",
    "fuse_logodds": "rules",
    "AgentSpec": "config",
    "BuildConfig": "config",
    "FuseConfig": "config",
    "MapConfig": "config",
    "RunConfig": "config",
    "load_yaml": "config",
    "build_maps": "maps.build",
    "BuildResult": "maps.build",
    "Score": "maps.compare",
    "compare": "maps.compare",
    "score": "maps.compare",
    "make_graph": "fusion.graph",
    "SimResult": "fusion.results",
    "simulate": "fusion.simulate",
    "fuse_finished": "fusion.rounds",
    "dynamic_vote": "fusion.voting",
    "static_vote": "fusion.voting_baselines",
    "maximum_likelihood": "fusion.voting_baselines",
    "ExPoly2D": "beliefs.expoly",
    "Gaussian": "beliefs.gaussian",
    "GaussianMixture": "beliefs.mixture",
    "fuse_mixtures": "beliefs.mixture_fusion",
    "run_target_search": "targets.search_report",
    "run_tracking": "targets.tracking_report",
}


def __getattr__(name: str):
    if name == "__version__":
        value = _version()
    else:
        module = _LAZY.get(name)
        if module is None:
            raise AttributeError(f"module 'octofuse' has no attribute {name!r}")
        value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def _version() -> str:
    import importlib.metadata

    try:
        return importlib.metadata.version("octofuse")
    except importlib.metadata.PackageNotFoundError:  # a source tree that was never installed
        return "0+unknown"


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


__all__ = [*_LAZY]
