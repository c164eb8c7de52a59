"""Live fleets: every robot an ``octofuse agent`` process exchanging over Zenoh.

5\\. The last stage: agents of :mod:`octofuse.fusion` (their maps, links and messages as bytes)
driven by a robot's own clock and a real network. ``keys`` names what goes where, ``transport``
is one Zenoh session, ``faults`` injects loss, duplicates, delay, reordering and partitions
where messages leave an agent, ``checkpoint`` keeps an agent's state across a restart,
``agent`` is the agent's process, ``fleet`` launches a fleet on one machine and collects it.
"""
