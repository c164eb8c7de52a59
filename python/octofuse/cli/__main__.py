"""``python -m octofuse.cli``: the ``octofuse`` command."""

from ..interrupts import remember_interrupts
from . import entry

remember_interrupts()
entry()
