"""The ``octofuse`` command line: flags -> one configuration -> one call -> a table.

- :mod:`.options`: the command group, shared option sets, flags + ``--config`` -> configuration;
- :mod:`.map_commands`: build, fuse-maps, align, export, info;
- :mod:`.network_commands`: run, demo, fuse, bench;
- :mod:`.belief_commands`: search, track;
- :mod:`.fleet_commands`: agent, fleet (live fleets over Zenoh);
- :mod:`.view_commands`: view.

:func:`main` runs it: usage errors exit 2, bad input 1 with one line, an interruption 130.
"""

from __future__ import annotations

import gc
import os
import signal
import sys
import warnings

import click

from ..interrupts import begin_command, cut_short, exit_code, interruption, raise_if_interrupted
from . import belief_commands, fleet_commands, map_commands, network_commands, view_commands  # noqa: F401  (register commands)
from .options import CliError, cli, run_config

__all__ = ["cli", "entry", "main", "run_config", "CliError"]

_python_showwarning = warnings.showwarning


def entry() -> None:
    """What the ``octofuse`` program (:mod:`octofuse.program`) runs once it has imported the
    command line: :func:`main`, then the interpreter's exit, which a late Ctrl-C
    (the command is over, its outputs written or left as they were) no longer interrupts with
    a traceback or a death by signal. The objects left are frozen out of the exit's last
    garbage collection (half a second after a demo): every file is written and closed."""
    code = main()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    gc.freeze()
    sys.exit(code)


def main(argv: list[str] | None = None) -> int:
    """Run the CLI: usage errors exit 2 with click's message, bad input 1 with one line,
    an interruption 130; never a traceback (``OCTOFUSE_DEBUG=1`` shows one for a bug). An
    error after a Ctrl-C is the Ctrl-C's (a library turned it into an error of its own)."""
    begin_command()
    warnings.showwarning = _show_warning
    warnings.filterwarnings("always", module=r"octofuse\.")  # about the input: always said
    try:
        args = sys.argv[1:] if argv is None else list(argv)
        with cli.make_context("octofuse", args) as ctx:  # interruptions reach the handler below
            cli.invoke(ctx)
        raise_if_interrupted()  # one swallowed on its way (octofuse.interrupts)
    except click.exceptions.Exit as e:
        return e.exit_code
    except click.ClickException as e:
        e.show()
        return e.exit_code
    except (click.Abort, KeyboardInterrupt):
        return _interrupted()
    except Exception as e:
        if cut_short():
            return _interrupted()
        if _bad_input(e):
            _error(_message(e))
            return 1
        # a bug in octofuse, not bad input
        if os.environ.get("OCTOFUSE_DEBUG"):
            raise
        _error(
            f"internal error ({type(e).__name__}: {_message(e)}); rerun with OCTOFUSE_DEBUG=1 "
            "for the traceback"
        )
        return 70
    return 0


def _bad_input(e: BaseException) -> bool:
    """An error bad input gives: one of the kinds below, or a bag's or transform's error (their
    modules are imported only if they ran)."""
    if isinstance(e, (CliError, ValueError, OSError, KeyError, MemoryError, RecursionError)):
        return True
    for module, name in (
        ("octofuse.scans.bags", "BagError"),
        ("octofuse.scans.tf", "TransformError"),
    ):
        cls = getattr(sys.modules.get(module), name, None)
        if cls is not None and isinstance(e, cls):
            return True
    return False


def _message(e: BaseException) -> str:
    if isinstance(e, MemoryError):
        return "out of memory: " + (str(e) or "the input asks for more memory than the machine has")
    text = e.args[0] if isinstance(e, KeyError) and e.args else str(e)
    return " ".join(str(text).split()) or type(e).__name__


def _error(text: str) -> None:
    click.echo(f"error: {text}", err=True)


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning about the input (a category defined by octofuse) as one ``warning:`` line;
    other warnings as Python shows them."""
    if category.__module__.startswith("octofuse."):
        click.echo(f"warning: {' '.join(str(message).split())}", err=True)
    else:
        _python_showwarning(message, category, filename, lineno, file, line)


def _interrupted() -> int:
    _error(interruption())
    return exit_code()
