"""``octofuse view``: a run's output folder in a local web page."""

from __future__ import annotations

import contextlib
import io
import sys
import time
from pathlib import Path

import click

from .options import CliError, cli, say


@cli.command()
@click.argument("folder", type=click.Path(file_okay=False, path_type=Path), required=False)
@click.option(
    "--fleet",
    "fleet_file",
    type=click.Path(dir_okay=False, path_type=Path),
    help="show a running fleet instead (its fleet.yaml): the agents' maps as they grow",
)
@click.option(
    "--host",
    default="127.0.0.1",
    show_default=True,
    help="address to listen on (0.0.0.0: every network interface)",
)
@click.option(
    "--port",
    type=click.IntRange(1, 65535),
    default=8080,
    show_default=True,
    help="port (the next free one if taken)",
)
@click.option(
    "--budget",
    type=click.IntRange(1000),
    default=300_000,
    show_default=True,
    help="voxels drawn at most: finer voxels merge into coarser octree cells",
)
def view(folder, fleet_file, host, port, budget):
    """Show the maps, events and scores of a run's output folder (or a running fleet's maps)
    in a web page."""
    if (folder is None) == (fleet_file is None):
        raise click.UsageError("give a run's output folder or --fleet FLEET.yaml")
    if fleet_file is not None:
        from ..config import FleetConfig, load_yaml
        from ..view.fleet_source import FleetSource

        source = FleetSource(load_yaml(fleet_file, FleetConfig))
    else:
        from ..view.run_folder import RunFolder

        source = RunFolder(folder)  # checked before the server starts
    try:
        with serve(source, host, port, budget):
            while True:
                time.sleep(3600)
    finally:
        if fleet_file is not None:
            source.close()


@contextlib.contextmanager
def serve(source, host: str, port: int, budget: int, until: str = "Ctrl-C to stop"):
    """A viewer page of ``source`` served while the context lasts; its address is printed
    with ``until`` (how long it stays)."""
    from ..view.page import RunPage

    try:
        import viser
    except ImportError:
        raise CliError("octofuse view needs viser: pip install 'octofuse[view]'") from None
    with contextlib.redirect_stdout(io.StringIO()):  # viser's own banner: the line below says it
        server = viser.ViserServer(host=host, port=port, verbose=False)
    try:
        page = RunPage(source, server, budget=budget)
        source.on_change = page.refresh
        shown = "localhost" if host in ("0.0.0.0", "127.0.0.1") else host
        say(f"viewer: http://{shown}:{server.get_port()}/ ({until})")
        sys.stdout.flush()  # the address now, also into a pipe, not when the server stops
        yield page
    finally:
        with contextlib.redirect_stdout(io.StringIO()):  # and its farewell
            server.stop()
