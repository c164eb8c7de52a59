"""``python -m octofuse.cli``: the ``octofuse`` command."""

from . import entry

entry()
