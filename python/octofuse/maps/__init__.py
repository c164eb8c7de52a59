"""Stage 2, scans to maps: OctoMap trees, their fusion, building from bags, scoring, ground truth.

``occupancy``, ``tree_fusion``, ``ray_batches``, ``infoloss`` and ``truth`` call the C++ map
core; outside ``maps``, only ``octofuse.memory`` does (it gives the core's node pools back).
"""
