"""``octofuse view``: a local web page (viser) of a run's maps, events and scores.

- :mod:`.voxels`: voxels as arrays and their level of detail (a voxel budget);
- :mod:`.difference`: an agent's map against the centralized map, voxel by voxel;
- :mod:`.events`: the fusion events up to an instant: traffic per link, loss per agent;
- :mod:`.palette`: colours and legends;
- :mod:`.source`: what the page reads (maps, events, scores), whoever provides it;
- :mod:`.run_folder`: a run's output folder as such a source;
- :mod:`.page`: the page itself, drawn from any source (a finished run now; a live fleet
  can provide the same).
"""
