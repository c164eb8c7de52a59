"""Stage 2, scans to maps: OctoMap trees, their fusion, building from bags, scoring, ground truth.

``occupancy``, ``tree_fusion``, ``ray_batches``, ``infoloss`` and ``truth`` are the only callers
of the C++ map core.
"""
