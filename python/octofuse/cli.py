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
                  every, config):
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


def _rules(rule: Optional[List[str]]) -> list[str]:
    from .rules import RULES, rule_index

    out: list[str] = []
    for r in rule or []:
        for x in r.split(","):
            x = x.strip()
            if x == "all":
                out.extend(RULES)
            elif x:
                rule_index(x)
                out.append(x)
    return list(dict.fromkeys(out))


def _truth(truth: Optional[Path], bags):
    from .scene import Scene

    if truth is not None:
        return Scene.load(truth)
    for b in bags:
        p = Scene.beside(b)
        if p is not None:
            return Scene.load(p)
    return None


def _export_agents(spec: str, agents: list[str]) -> list[str]:
    if spec == "all":
        return agents
    if spec == "none":
        return []
    if spec == "first":
        return agents[:1]
    names = [x.strip() for x in spec.split(",") if x.strip()]
    bad = [n for n in names if n not in agents]
    if bad:
        raise CliError(f"--export-agents: unknown agent(s) {', '.join(bad)}; agents: {', '.join(agents)}")
    return names


def _fuse_config(cfg, rule, topology, schedule, directions, delta, unknown, seed):
    f = cfg.fuse
    if rule:
        f.rule = ",".join(rule)
    if topology is not None:
        f.topology = topology
    if schedule is not None:
        f.schedule = schedule
    if directions is not None:
        f.directions = directions
    if delta is not None:
        f.delta = delta
    if unknown is not None:
        f.unknown = unknown
    if seed is not None:
        f.seed = seed
    return cfg


RuleOpt = typer.Option(None, "--rule", "--rules", help="fusion rule(s), comma separated, or 'all'")
TopoOpt = typer.Option(None, "--topology", help="ring, line, star, complete, grid, random:P, max-robust:K or a file")
SchedOpt = typer.Option(None, "--schedule", help="aperiodic:MEAN_S or periodic:PERIOD_S")
DirOpt = typer.Option(None, "--directions", help="both (default) or one")
DeltaOpt = typer.Option(None, "--delta/--whole-maps", help="send only voxels changed since the last message")
UnknownOpt = typer.Option(None, "--unknown", help="voxels known to one map only: copy (default) or prior")
SeedOpt = typer.Option(None, "--seed", help="seed of random topologies and schedules")
TruthOpt = typer.Option(None, "--truth", help="scene ground truth JSON (default: NAME_scene.json beside the bag)")


def _run_job(cfg, rules, out: Path, *, samples: int, truth_path, export_agents: str, title: str):
    from .report import mean_scores, write_outputs
    from .network import simulate

    _check_bags(cfg.build.bags)
    if not rules:
        rules = _rules([cfg.fuse.rule])
    from .build import ScanSource

    with ScanSource(cfg.build) as src:
        total = src.total_scans
        agents = [a.name for a in src.agents]
    truth = _truth(truth_path, cfg.build.bags)
    cfg.fuse.rule = ",".join(rules)
    with _progress() as prog:
        task = prog.add_task(f"mapping + fusing ({len(rules)} rule(s))", total=total)
        res = simulate(cfg.build, cfg.fuse, rules, samples=samples, truth=truth,
                       progress=lambda n: prog.advance(task, n))
    paths = write_outputs(res, out, cfg, export_agents=_export_agents(export_agents, agents),
                          title=title)
    means = mean_scores(res.scores)
    t = Table("rule", "KL(central‖agent)", "over-confident", "agreement", "coverage",
              "loss mean", "loss p95", title=title)
    for r, row in means.items():
        def f(k, fmt):
            return "–" if row.get(k) is None else fmt.format(row[k])
        t.add_row(r, f("kl_mean", "{:.4f}"), f("overconfidence", "{:.1%}"), f("agreement", "{:.1%}"),
                  f("coverage", "{:.1%}"), f("loss_mean", "{:.3f}"), f("loss_p95", "{:.3f}"))
    console.print(t)
    console.print(f"report: {paths['report']}", highlight=False, soft_wrap=True)
    return res, paths


@app.command()
def run(
    bags: Optional[List[Path]] = BagsArg,
    rule: Optional[List[str]] = RuleOpt,
    topology: Optional[str] = TopoOpt,
    schedule: Optional[str] = SchedOpt,
    directions: Optional[str] = DirOpt,
    delta: Optional[bool] = DeltaOpt,
    unknown: Optional[str] = UnknownOpt,
    seed: Optional[int] = SeedOpt,
    agent: Optional[List[str]] = AgentOpt,
    pose: Optional[List[str]] = PoseOpt,
    sensor_offset: Optional[List[str]] = OffsetOpt,
    fixed_frame: Optional[str] = FrameOpt,
    resolution: Optional[float] = ResOpt,
    max_range: Optional[float] = RangeOpt,
    no_return: Optional[str] = NoRetOpt,
    every: Optional[int] = EveryOpt,
    truth: Optional[Path] = TruthOpt,
    samples: int = typer.Option(12, "--samples", help="points in time at which KL is recorded"),
    export_agents: str = typer.Option("all", "--export-agents", help="agents whose maps and heat maps are written: all, first, none or names"),
    config: Optional[Path] = ConfigOpt,
    dump_config: bool = DumpOpt,
    out: Optional[Path] = typer.Option(None, "--out", help="output folder"),
):
    """The whole job in time order: build, exchange, fuse, score, export, report."""
    from .config import RunConfig, load_yaml

    cfg = load_yaml(config, RunConfig) if config else RunConfig()
    cfg.build = _build_config(bags, agent, pose, sensor_offset, fixed_frame, resolution, max_range,
                              no_return, every, config)
    _fuse_config(cfg, rule, topology, schedule, directions, delta, unknown, seed)
    if out is not None:
        cfg.out = str(out)
    if dump_config:
        _print_config(cfg)
        return
    if not cfg.build.bags:
        raise CliError("no bag given: octofuse run BAG... --rule R --topology T --out DIR")
    _run_job(cfg, _rules([cfg.fuse.rule]), Path(cfg.out), samples=samples, truth_path=truth,
             export_agents=export_agents, title="octofuse run")


def bundled_dataset() -> Path:
    """The bundled simulated dataset (installed with the package, or in the checkout)."""
    here = Path(__file__).resolve().parent
    for cand in (here / "data" / "lab8.bag", here.parents[1] / "data" / "lab8.bag"):
        if cand.is_file():
            return cand
    raise CliError("the bundled dataset lab8.bag was not found (reinstall octofuse, or run "
                   "`octofuse run data/lab8.bag ...` from the source checkout)")


@app.command()
def demo(
    out: Path = typer.Option(Path("octofuse-demo"), "--out", help="output folder"),
    rule: Optional[List[str]] = typer.Option(None, "--rule", "--rules", help="rules [default: all]"),
    every: Optional[int] = EveryOpt,
):
    """The paper's setting on the bundled dataset: 8 robots, max-robust:3, every rule."""
    from .config import RunConfig

    bag = bundled_dataset()
    cfg = RunConfig()
    cfg.build.bags = [str(bag)]
    cfg.fuse.topology = "max-robust:3"
    cfg.fuse.schedule = "aperiodic:20"
    if every is not None:
        cfg.build.scan_stride = every
    cfg.out = str(out)
    console.print(f"octofuse demo: {bag.name} (simulated 15 x 8 m lab, 8 robots, 120 s), "
                  f"max-robust:3, aperiodic exchanges, every rule", highlight=False)
    _run_job(cfg, _rules(rule or ["all"]), out, samples=8, truth_path=None,
             export_agents="first", title="octofuse demo: 8 robots, max-robust:3")


@app.command("fuse")
def fuse_cmd(
    maps_dir: Path = typer.Argument(..., help="folder written by `octofuse build` (NAME.ot, centralized.ot)"),
    rule: Optional[List[str]] = RuleOpt,
    topology: str = typer.Option("max-robust:3", "--topology"),
    rounds: int = typer.Option(3, "--rounds", help="synchronous rounds of exchanges"),
    seed: int = typer.Option(0, "--seed"),
    unknown: str = typer.Option("copy", "--unknown"),
    directions: str = typer.Option("both", "--directions"),
    truth: Optional[Path] = TruthOpt,
    out: Path = typer.Option(..., "--out", help="output folder"),
):
    """Fuse finished maps over a communication graph for R rounds."""
    from .config import FuseConfig, RunConfig
    from .maps import OccupancyMap
    from .report import write_outputs
    from .network import fuse_finished

    if not maps_dir.is_dir():
        raise CliError(f"maps folder '{maps_dir}' does not exist")
    files = sorted(p for p in maps_dir.glob("*.ot") if p.stem != "centralized")
    if len(files) < 2:
        raise CliError(f"'{maps_dir}' holds {len(files)} agent map(s) (*.ot besides centralized.ot); "
                       f"fusion needs at least 2")
    if rounds < 1:
        raise CliError(f"--rounds {rounds}: expected 1 or more")
    maps = {p.stem: OccupancyMap.load(p) for p in files}
    cpath = maps_dir / "centralized.ot"
    central = OccupancyMap.load(cpath) if cpath.is_file() else None
    rules = _rules(rule) or ["min-info-loss"]
    fcfg = FuseConfig(rule=",".join(rules), topology=topology, schedule=f"rounds:{rounds}",
                      directions=directions, unknown=unknown, seed=seed)
    from .scene import Scene

    res = fuse_finished(maps, central, fcfg, rules, n_rounds=rounds,
                        truth=Scene.load(truth) if truth else None)
    cfg = RunConfig(fuse=fcfg, out=str(out))
    cfg.build.bags = [str(maps_dir)]
    paths = write_outputs(res, out, cfg, title=f"octofuse fuse: {rounds} rounds over {topology}")
    console.print(f"fused {len(maps)} maps with {', '.join(rules)} over {topology} "
                  f"({len(res.events)} messages); report: {paths['report']}", highlight=False,
                  soft_wrap=True)


@app.command()
def bench(
    bags: List[Path] = typer.Argument(..., help="bags (as for run)"),
    rules: str = typer.Option("all", "--rules", help="comma separated rules or 'all'"),
    topologies: str = typer.Option("ring,max-robust:3", "--topologies", help="comma separated topologies"),
    schedule: Optional[str] = SchedOpt,
    seed: Optional[int] = SeedOpt,
    delta: Optional[bool] = DeltaOpt,
    fixed_frame: Optional[str] = FrameOpt,
    resolution: Optional[float] = ResOpt,
    every: Optional[int] = EveryOpt,
    truth: Optional[Path] = TruthOpt,
    out: Path = typer.Option(..., "--out", help="output folder"),
):
    """Compare rules x topologies against the centralized map: CSV, markdown and plots."""
    from .bench import run_bench
    from .config import RunConfig

    cfg = RunConfig()
    cfg.build = _build_config(bags, None, None, None, fixed_frame, resolution, None, None, every, None)
    _fuse_config(cfg, None, None, schedule, None, delta, None, seed)
    _check_bags(cfg.build.bags)
    topo = [t.strip() for t in topologies.split(",") if t.strip()]
    if not topo:
        raise CliError("--topologies: give at least one topology")
    paths = run_bench(cfg, _rules([rules]), topo, out, truth=_truth(truth, cfg.build.bags),
                      console=console, progress=_progress)
    console.print(f"wrote {', '.join(str(p) for p in paths)}", highlight=False, soft_wrap=True)


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
