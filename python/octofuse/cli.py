"""The ``octofuse`` command line."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import List, Optional

import typer
from rich.console import Console
from rich.table import Table

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="Fuse multi-robot OctoMap occupancy maps conservatively (WEP rules).")
console = Console()
err = Console(stderr=True)


class CliError(Exception):
    """An error the CLI reports as one line with a non-zero exit."""


@app.command()
def info(maps: List[Path] = typer.Argument(..., help="OctoMap files (.ot or .bt)")):
    """Print resolution, size and occupancy statistics of map files."""
    import numpy as np

    from .maps import OccupancyMap

    t = Table("map", "resolution", "leaves", "occupied", "free", "memory MB")
    for p in maps:
        m = OccupancyMap.load(p)
        v = m.leaves().values
        t.add_row(str(p), f"{m.resolution:g}", f"{m.num_leaves}", f"{int(np.sum(v > 0))}",
                  f"{int(np.sum(v <= 0))}", f"{m.memory_bytes / 1e6:.1f}")
    console.print(t)


@app.command("fuse-pair")
def fuse_pair(
    a: Path = typer.Argument(..., help="first map (.ot/.bt)"),
    b: Path = typer.Argument(..., help="second map (.ot/.bt)"),
    rule: str = typer.Option("min-info-loss", help="fusion rule"),
    unknown: str = typer.Option("copy", help="voxels known to one map only: copy or prior"),
    out: Path = typer.Option(..., help="fused map to write (.ot or .bt)"),
):
    """Fuse two map files into one."""
    from .maps import OccupancyMap, fuse_maps

    fused, loss = fuse_maps(OccupancyMap.load(a), OccupancyMap.load(b), rule=rule, unknown=unknown)
    fused.save(out)
    v = loss.leaves().values
    console.print(f"wrote {out}: {fused.num_leaves} leaves; information loss mean "
                  f"{float(v.mean()) if len(v) else 0.0:.4f} nats over {len(v)} leaves")


def main(argv: Optional[list[str]] = None) -> int:
    """Entry point: runs the CLI, turning expected errors into one line and exit code 1."""
    from .maps import MapFileError

    try:
        app(args=argv, standalone_mode=False)
    except (CliError, ValueError, OSError, MapFileError, KeyError) as e:
        msg = e.args[0] if isinstance(e, KeyError) and e.args else str(e)
        err.print(f"[bold red]error:[/] {msg}", highlight=False)
        return 1
    except KeyboardInterrupt:
        err.print("interrupted")
        return 130
    except Exception as e:  # click usage errors and the like
        import click

        if isinstance(e, click.exceptions.ClickException):
            e.show()
            return e.exit_code
        if isinstance(e, click.exceptions.Exit):
            return e.exit_code
        raise
    return 0


if __name__ == "__main__":
    sys.exit(main())
