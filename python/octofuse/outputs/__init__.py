"""Stage 4, what a run writes: reports, point-cloud exports, rules x topologies studies."""
