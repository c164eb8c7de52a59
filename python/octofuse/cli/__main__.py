"""``python -m octofuse.cli``: the ``octofuse`` command (Python imports the command line before
this runs; ``python -m octofuse`` installs the Ctrl-C handler first)."""

from ..interrupts import remember_interrupts
from . import entry

remember_interrupts()
entry()
