"""``python -m octofuse.cli``: the ``octofuse`` program (:func:`octofuse.program.run`). Python
imports the command line before this module runs, so a Ctrl-C in those first moments is a
traceback; ``python -m octofuse`` imports nothing first."""

from ..program import run

run()
