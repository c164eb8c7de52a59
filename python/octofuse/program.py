"""The ``octofuse`` program: the command line (:mod:`octofuse.cli`) imported, then run. Importing
it takes a quarter of a second; an interruption (Ctrl-C) in that time ends as one while the
command runs does, with one line and exit code 130, not a traceback."""

from __future__ import annotations

import sys


def run() -> None:
    """Import the command line and run it (:func:`octofuse.cli.entry`)."""
    from .interrupts import exit_code, interruption, remember_interrupts

    remember_interrupts()
    try:
        from .cli import entry
    except KeyboardInterrupt:
        sys.stderr.write(f"error: {interruption()}\n")
        sys.exit(exit_code())
    entry()
