"""Stage 3, beliefs exchanged over a communication graph: graphs, schedules, the network in
time (``simulate``) and in rounds (``rounds``), robust voting."""
