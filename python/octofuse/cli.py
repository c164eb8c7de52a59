"""The ``octofuse`` command line."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import List, Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="Fuse multi-robot OctoMap occupancy maps conservatively (WEP rules).")
console = Console(width=None if sys.stdout.isatty() else 120)
err = Console(stderr=True, width=None if sys.stderr.isatty() else 120)


class CliError(Exception):
    """An error the CLI reports as one line with a non-zero exit."""


def _print_config(cfg) -> None:
    from .config import dump_yaml

    console.print(dump_yaml(cfg), end="", highlight=False, markup=False, soft_wrap=True)


def _build_config(bags, agent, pose, sensor_offset, fixed_frame, resolution, max_range, no_return,
                  every, config, section="build"):
    """Merge a YAML config (if any) with command-line flags (flags win when given)."""
    from .build import parse_agent
    from .config import BuildConfig, RunConfig, load_yaml

    cfg = load_yaml(config, RunConfig).build if config else BuildConfig()
    if bags:
        cfg.bags = [str(b) for b in bags]
    if agent:
        cfg.agents = [parse_agent(a) for a in agent]
    poses = dict(_kv(p, "--pose NAME=TOPIC") for p in (pose or []))
    offsets = dict(_kv(o, "--sensor-offset NAME=x,y,z,qx,qy,qz,qw") for o in (sensor_offset or []))
    names = {a.name for a in cfg.agents}
    for name in list(poses) + list(offsets):
        if name not in names:
            raise CliError(f"--pose/--sensor-offset name '{name}' is not an agent given with "
                           f"--agent (agents: {', '.join(sorted(names)) or 'none'})")
    for a in cfg.agents:
        if a.name in poses:
            a.pose_topic = poses[a.name]
        if a.name in offsets:
            try:
                a.sensor_offset = [float(v) for v in offsets[a.name].split(",")]
            except ValueError:
                raise CliError(f"--sensor-offset {a.name}: expected 7 numbers x,y,z,qx,qy,qz,qw") from None
    if fixed_frame is not None:
        cfg.fixed_frame = fixed_frame
    if resolution is not None:
        cfg.map.resolution = resolution
    if max_range is not None:
        cfg.max_range = max_range
    if no_return is not None:
        cfg.no_return = no_return
    if every is not None:
        cfg.scan_stride = every
    return cfg


def _kv(s: str, what: str) -> tuple[str, str]:
    k, sep, v = s.partition("=")
    if not sep or not k or not v:
        raise CliError(f"{s!r}: expected {what}")
    return k, v


def _check_bags(bags) -> None:
    for b in bags:
        if not Path(b).exists():
            raise CliError(f"bag '{b}' does not exist")


def _progress():
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                    TimeRemainingColumn(), console=err, transient=True, disable=not err.is_terminal)


def _build_table(result) -> Table:
    t = Table("agent", "topic", "scans used", "skipped", "points", "leaves", "seconds",
              title="octofuse build")
    for s in result.stats:
        t.add_row(s.name, s.topic, str(s.scans_used), str(s.scans_skipped), f"{s.points:,}",
                  f"{result.maps[s.name].num_leaves:,}", f"{s.seconds:.2f}")
    t.add_row("centralized", "(all)", str(sum(s.scans_used for s in result.stats)),
              str(sum(s.scans_skipped for s in result.stats)),
              f"{sum(s.points for s in result.stats):,}", f"{result.centralized.num_leaves:,}",
              f"{result.seconds:.2f}")
    return t


def _skip_notes(result) -> list[str]:
    notes = []
    for s in result.stats:
        for reason, n in sorted(s.skipped.items()):
            notes.append(f"{s.name}: skipped {n} scan(s): {reason}")
    return notes


BagsArg = typer.Argument(None, help="ROS 1 .bag files, ROS 2 bag folders or .mcap files")
AgentOpt = typer.Option(None, "--agent", help="NAME=TOPIC (repeatable); default: one agent per scan topic")
PoseOpt = typer.Option(None, "--pose", help="NAME=POSE_TOPIC: Odometry/PoseStamped instead of tf")
OffsetOpt = typer.Option(None, "--sensor-offset", help="NAME=x,y,z,qx,qy,qz,qw sensor pose on the robot")
FrameOpt = typer.Option(None, "--fixed-frame", help="fixed frame of the maps [default: map]")
ResOpt = typer.Option(None, "--resolution", help="voxel size in metres [default: 0.05]")
RangeOpt = typer.Option(None, "--max-range", help="longer rays only clear free space [default: none]")
NoRetOpt = typer.Option(None, "--no-return", help="LaserScan beams without echo: skip (default) or free")
EveryOpt = typer.Option(None, "--every", help="use every N-th scan of each agent [default: 1]")
ConfigOpt = typer.Option(None, "--config", help="YAML config file (see --dump-config)")
DumpOpt = typer.Option(False, "--dump-config", help="print the configuration (defaults + given) and exit")


@app.command()
def build(
    bags: Optional[List[Path]] = BagsArg,
    agent: Optional[List[str]] = AgentOpt,
    pose: Optional[List[str]] = PoseOpt,
    sensor_offset: Optional[List[str]] = OffsetOpt,
    fixed_frame: Optional[str] = FrameOpt,
    resolution: Optional[float] = ResOpt,
    max_range: Optional[float] = RangeOpt,
    no_return: Optional[str] = NoRetOpt,
    every: Optional[int] = EveryOpt,
    config: Optional[Path] = ConfigOpt,
    dump_config: bool = DumpOpt,
    out: Optional[Path] = typer.Option(None, "--out", help="output folder for NAME.ot and centralized.ot"),
):
    """Build every agent's map and the centralized map from bags."""
    from .config import RunConfig

    cfg = _build_config(bags, agent, pose, sensor_offset, fixed_frame, resolution, max_range,
                        no_return, every, config)
    if dump_config:
        _print_config(RunConfig(build=cfg, out=str(out or "octofuse-out")))
        return
    if not cfg.bags:
        raise CliError("no bag given: octofuse build BAG... --out DIR")
    if out is None:
        raise CliError("--out DIR is required")
    _check_bags(cfg.bags)
    from .build import ScanSource, build as run_build, write_maps

    with ScanSource(cfg) as src:
        total = src.total_scans
    with _progress() as prog:
        task = prog.add_task("inserting scans", total=total)
        result = run_build(cfg, progress=lambda n: prog.advance(task, n))
    paths = write_maps(result, out)
    console.print(_build_table(result))
    for note in _skip_notes(result):
        console.print(f"[yellow]{escape(note)}[/]", highlight=False, soft_wrap=True)
    console.print(f"wrote {len(paths)} maps to {escape(str(out))}/", highlight=False, soft_wrap=True)


@app.command()
def export(
    src: Path = typer.Argument(..., help="map (.ot/.bt) or information-loss file (.npz)"),
    out: Path = typer.Option(..., "--out", help="file to write: .ply/.pcd cloud, or .ot/.bt map"),
    all_voxels: bool = typer.Option(False, "--all-voxels",
                                    help="map clouds: every known voxel, not only occupied ones"),
    cmap: Optional[str] = typer.Option(None, "--cmap", help="matplotlib colour map "
                                       "(default: viridis for maps, inferno for heat maps)"),
):
    """Write a map or an information-loss file as a PLY/PCD point cloud, or convert .ot/.bt."""
    from .export import export_map

    result = export_map(src, out, occupied_only=not all_voxels, cmap=cmap)
    console.print(str(result), highlight=False, markup=False, soft_wrap=True)


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
    from .io import BagError, TransformError
    from .maps import MapFileError

    try:
        app(args=argv, standalone_mode=False)
    except (CliError, ValueError, OSError, MapFileError, KeyError, BagError, TransformError) as e:
        msg = e.args[0] if isinstance(e, KeyError) and e.args else str(e)
        err.print(f"[bold red]error:[/] {escape(msg)}", highlight=False, soft_wrap=True)
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
