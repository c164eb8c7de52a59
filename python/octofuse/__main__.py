"""``python -m octofuse``: the ``octofuse`` program (:func:`octofuse.program.run`)."""

from .program import run

run()
