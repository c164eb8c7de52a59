"""Stage 2, scans to maps: OctoMap trees, their fusion, building from bags, scoring, ground truth.

``occupancy`` and ``infoloss`` are the only callers of the C++ map core.
"""
