"""The ``octofuse`` command line: flags -> one configuration -> one call -> a table.

Flags and ``--config`` files take one route: both become plain data, merged (flags win), and
:func:`octofuse.config.from_dict` validates the result once. Heavy modules load inside the
commands, so ``octofuse --help`` is quick.
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path
from typing import Optional

import click

from .config import RunConfig

_DEFAULT = RunConfig()
CONTEXT = {"help_option_names": ["-h", "--help"], "show_default": True, "max_content_width": 100}


class CliError(Exception):
    """An error the CLI reports as one line with a non-zero exit."""


def _console(stderr: bool = False):
    from rich.console import Console

    stream = sys.stderr if stderr else sys.stdout
    return Console(stderr=stderr, width=None if stream.isatty() else 120)


def say(text: str) -> None:
    _console().print(text, highlight=False, markup=False, soft_wrap=True)


# ---------------------------------------------------------------------------- shared options


def _options(*decorators):
    def apply(f):
        for d in reversed(decorators):
            f = d(f)
        return f
    return apply


bag_arguments = click.argument("bags", nargs=-1, type=click.Path(path_type=Path))
config_options = _options(
    click.option("--config", type=click.Path(dir_okay=False, path_type=Path),
                 help="YAML configuration (see --dump-config); flags given win"),
    click.option("--dump-config", is_flag=True,
                 help="print the configuration (defaults + config file + flags) and exit"),
)
build_options = _options(
    click.option("--agent", multiple=True, help="NAME=TOPIC (repeatable)  [default: one agent per "
                 "scan topic]"),
    click.option("--pose", multiple=True, help="NAME=POSE_TOPIC: Odometry/PoseStamped instead of tf"),
    click.option("--sensor-offset", multiple=True, help="NAME=x,y,z,qx,qy,qz,qw sensor pose on the robot"),
    click.option("--fixed-frame", help="fixed frame of the maps", show_default=_DEFAULT.build.fixed_frame),
    click.option("--resolution", type=float, help="voxel size in metres",
                 show_default=str(_DEFAULT.build.map.resolution)),
    click.option("--max-range", type=float, help="longer rays only clear free space; <= 0: no limit",
                 show_default="no limit"),
    click.option("--no-return", type=click.Choice(["skip", "free"]),
                 help="LaserScan beams without echo", show_default=_DEFAULT.build.no_return),
    click.option("--every", type=click.IntRange(min=1), help="use every N-th scan of each agent",
                 show_default="1"),
    click.option("--threads", type=click.IntRange(0, 256),
                 help="threads for ray casting, fusion and scoring; 0: one per core", show_default="0"),
)
rule_option = click.option("--rule", "--rules", "rule", multiple=True,
                           help="fusion rule(s), comma separated, or 'all'",
                           show_default=",".join(_DEFAULT.fuse.rules))
exchange_options = _options(
    click.option("--schedule", help="aperiodic:MEAN_S or periodic:PERIOD_S",
                 show_default=_DEFAULT.fuse.schedule),
    click.option("--directions", type=click.Choice(["both", "one"]), help="messages on a link",
                 show_default=_DEFAULT.fuse.directions),
    click.option("--delta/--whole-maps", default=None,
                 help="send only voxels changed since the last message on a link",
                 show_default="whole maps"),
    click.option("--unknown", type=click.Choice(["copy", "prior"]),
                 help="voxels known to one map only", show_default=_DEFAULT.fuse.unknown),
    click.option("--seed", type=int, help="seed of random topologies and schedules",
                 show_default=str(_DEFAULT.fuse.seed)),
    click.option("--truth", type=click.Path(dir_okay=False, path_type=Path),
                 help="scene ground truth JSON", show_default="NAME_scene.json beside the bag"),
    click.option("--spanning-tree", help="the tree the channel-filter rule runs on: bfs, given "
                 "(the topology is a tree) or a graph file", show_default=_DEFAULT.fuse.spanning_tree),
    click.option("--loss", type=click.FloatRange(0.0, 1.0, max_open=True),
                 help="probability that a message is lost (seeded, the same messages for every rule)",
                 show_default=str(_DEFAULT.fuse.loss)),
)
frame_options = _options(
    click.option("--agent-frame", multiple=True,
                 help="NAME=x,y,z,roll,pitch,yaw: the rigid transform from agent NAME's map frame "
                      "into the common frame (metres, radians; repeatable)",
                 show_default="every agent in the common frame"),
    click.option("--align", type=click.Choice(["off", "planar", "full"]), metavar="MODE",
                 help="estimate each link's transform on first contact: off, planar (x, y, z, "
                      "yaw) or full", show_default=_DEFAULT.fuse.align),
)
topology_option = click.option("--topology", help="ring, line, star, complete, grid, random:P, "
                                "max-robust:K or a graph file", show_default=_DEFAULT.fuse.topology)
out_option = click.option("--out", type=click.Path(file_okay=False, path_type=Path),
                          help="output folder (replaced whole when it holds an earlier octofuse "
                               "output)")
export_options = _options(
    click.option("--export", type=click.Choice(["all", "fused", "none"]), metavar="MODE",
                 help="per rule and exported agent: fused map and heat maps (all), the fused map "
                      "only (fused), or nothing (none: report, summary and plots)",
                 show_default=_DEFAULT.export),
    click.option("--formats", help="heat-map formats, comma separated: ply, pcd",
                 show_default=",".join(_DEFAULT.formats)),
)


def _pairs(values, what: str) -> dict[str, str]:
    out = {}
    for s in values:
        k, sep, v = s.partition("=")
        if not sep or not k or not v:
            raise click.BadParameter(f"{s!r}: expected {what}")
        out[k] = v
    return out


def _given(**values) -> dict:
    return {k: v for k, v in values.items() if v is not None and v != () and v != []}


def run_config(p: dict, *, bags=None, defaults: Optional[dict] = None) -> RunConfig:
    """The configuration of a command: the configuration's defaults, then the command's own
    ``defaults`` (e.g. bench's every rule), then ``--config``, then the flags in ``p``."""
    from .config import from_dict, merge, read_yaml

    data = read_yaml(p["config"]) if p.get("config") else {}
    if data:  # the file's own errors name the file and the key
        from_dict(RunConfig, data, where=str(p["config"]))
    data = merge(defaults or {}, data)
    build = _given(fixed_frame=p.get("fixed_frame"), max_range=p.get("max_range"),
                   no_return=p.get("no_return"), scan_stride=p.get("every"),
                   threads=p.get("threads"))
    if bags:
        build["bags"] = [str(b) for b in bags]
    if p.get("resolution") is not None:
        build["map"] = {"resolution": p["resolution"]}
    if p.get("agent"):
        build["agents"] = [dict(zip(("name", "topic"), kv))
                           for kv in _pairs(p["agent"], "NAME=TOPIC").items()]
    fuse = _given(rules=list(p.get("rule") or ()), topology=p.get("topology"),
                  schedule=p.get("schedule"), directions=p.get("directions"),
                  delta=p.get("delta"), unknown=p.get("unknown"), seed=p.get("seed"),
                  spanning_tree=p.get("spanning_tree"), loss=p.get("loss"))
    if p.get("robust") is not None:
        fuse["robust"] = {"enabled": p["robust"]}
    if p.get("agent_frame"):
        from .maps.frames import parse_frame_values

        fuse["agent_frames"] = [dict(zip(("name", "pose"), parse_frame_values(f)))
                                for f in p["agent_frame"]]
    if p.get("align") is not None:
        fuse["align"] = p["align"]
    run = _given(out=str(p["out"]) if p.get("out") else None,
                 truth=str(p["truth"]) if p.get("truth") else None,
                 samples=p.get("samples"), export_agents=p.get("export_agents"),
                 export=p.get("export"), formats=[p["formats"]] if p.get("formats") else None)
    data = merge(data, {"build": build, "fuse": fuse, **run})
    _agent_poses(data, p)
    return from_dict(RunConfig, data, where="options")


def _agent_poses(data: dict, p: dict) -> None:
    poses = _pairs(p.get("pose") or (), "NAME=POSE_TOPIC")
    offsets = _pairs(p.get("sensor_offset") or (), "NAME=x,y,z,qx,qy,qz,qw")
    agents = {a.get("name"): a for a in data.get("build", {}).get("agents", []) if isinstance(a, dict)}
    for name in [*poses, *offsets]:
        if name not in agents:
            raise click.BadParameter(f"--pose/--sensor-offset name '{name}' is not an agent given "
                                     f"with --agent (agents: {', '.join(map(str, agents)) or 'none'})")
    for name, topic in poses.items():
        agents[name]["pose_topic"] = topic
    for name, text in offsets.items():
        try:
            agents[name]["sensor_offset"] = [float(v) for v in text.split(",")]
        except ValueError:
            raise click.BadParameter(f"--sensor-offset {name}: expected 7 numbers "
                                     "x,y,z,qx,qy,qz,qw") from None


def _dump(cfg) -> None:
    from .config import dump_yaml

    click.echo(dump_yaml(cfg), nl=False)


def _need_bags(cfg: RunConfig, usage: str) -> None:
    if not cfg.build.bags:
        raise click.UsageError(f"no bag given: {usage}")
    for b in cfg.build.bags:
        if not Path(b).exists():
            raise CliError(f"bag '{b}' does not exist")


def _need_out(cfg: RunConfig, given: Optional[Path]) -> Path:
    if given is None and cfg.out == _DEFAULT.out:
        raise click.UsageError("--out DIR is required")
    return Path(cfg.out)


class Progress:
    """A progress bar on a terminal (nothing otherwise); called as ``bar(done, total)``."""

    def __init__(self, description: str):
        from rich.progress import BarColumn, MofNCompleteColumn, Progress as Bar, TextColumn
        from rich.progress import TimeRemainingColumn

        console = _console(stderr=True)
        self._bar = Bar(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                        TimeRemainingColumn(), console=console, transient=True,
                        disable=not console.is_terminal)
        self._task = self._bar.add_task(description, total=None)

    def __enter__(self) -> "Progress":
        self._bar.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        self._bar.__exit__(*exc)

    def __call__(self, done: int, total: int) -> None:
        self._bar.update(self._task, completed=done, total=total)


# ---------------------------------------------------------------------------------- commands


@click.group(context_settings=CONTEXT)
@click.version_option(package_name="octofuse", prog_name="octofuse")
def cli() -> None:
    """Conservative fusion of multi-robot beliefs: OctoMap maps fused with WEP rules."""


@cli.command()
@bag_arguments
@build_options
@config_options
@out_option
def build(bags, **p):
    """Build every agent's map and the centralized map from bags."""
    from .maps.build import build as build_maps_from, write_maps
    from .outputs.staging import check_replaceable, staged_folder
    from .outputs.tables import build_table, skip_notes

    cfg = run_config(p, bags=bags)
    if p["dump_config"]:
        return _dump(cfg)
    _need_bags(cfg, "octofuse build BAG... --out DIR")
    out = check_replaceable(_need_out(cfg, p["out"]))
    with Progress("inserting scans") as bar:
        result = build_maps_from(cfg.build, progress=bar)
    with staged_folder(out, "build") as stage:
        write_maps(result, stage)
    _console().print(build_table(result))
    for note in skip_notes(result):
        say(note)
    say(f"wrote {len(result.all_maps())} maps to {out}/")


def _run_and_report(cfg: RunConfig, title: str, command: str,
                    export_bag: Optional[Path] = None) -> None:
    from .fusion.simulate import simulate
    from .maps.truth import Scene
    from .outputs.report import write_outputs
    from .outputs.staging import check_replaceable, staged_folder
    from .outputs.tables import scores_table

    out = check_replaceable(cfg.out)
    truth = Scene.find(cfg.truth, cfg.build.bags)
    bag = _event_bag(export_bag, cfg, out) if export_bag is not None else None
    try:
        with Progress(f"mapping + fusing ({len(cfg.fuse.rules)} rule(s))") as bar:
            if bag is None:
                res = simulate(cfg.build, cfg.fuse, samples=cfg.samples, truth=truth, progress=bar)
            else:
                from .scans.source import ScanSource

                with ScanSource(cfg.build) as src:
                    bag.start_ns = src.bags.start_ns or 0
                    res = simulate(cfg.build, cfg.fuse, samples=cfg.samples, truth=truth,
                                   progress=bar, source=src, observer=bag)
        with staged_folder(out, command) as stage:
            write_outputs(res, stage, cfg, export_agents=_export_agents(cfg.export_agents, res.agents),
                          title=title, event_bag=bag)
            if bag is not None:
                bag.close()
    finally:
        if bag is not None:
            bag.abort()  # nothing once closed
    _console().print(scores_table(res, title))
    if bag is not None:
        say(f"bag: {bag.path} ({bag.messages} map messages)")
    say(f"report: {out / 'report.md'}")


def _event_bag(path: Path, cfg: RunConfig, out: Path):
    """The per-event bag of ``--export-bag``, checked and opened before the run."""
    from .outputs.event_bag import FusionEventBag

    if cfg.export_agents == "none":
        raise CliError("--export-bag: no agent is exported (--export-agents none)")
    if path.absolute() == out.absolute() or out.absolute() in path.absolute().parents:
        raise CliError(f"--export-bag '{path}' is inside --out '{out}', which is replaced "
                       "whole; give a path outside it")
    return FusionEventBag(path, frame_id=cfg.build.fixed_frame.strip("/"),
                          select=lambda agents: _export_agents(cfg.export_agents, agents))


def _export_agents(spec: str, agents: list[str]) -> list[str]:
    if spec in ("all", "none", "first"):
        return {"all": agents, "none": [], "first": agents[:1]}[spec]
    names = [x.strip() for x in spec.split(",") if x.strip()]
    bad = [n for n in names if n not in agents]
    if bad:
        raise CliError(f"--export-agents: unknown agent(s) {', '.join(bad)}; agents: {', '.join(agents)}")
    return names


@cli.command()
@bag_arguments
@rule_option
@topology_option
@exchange_options
@frame_options
@build_options
@click.option("--samples", type=click.IntRange(0, 10_000), help="points in time at which KL is recorded",
              show_default=str(_DEFAULT.samples))
@click.option("--export-agents", help="agents whose maps and heat maps are written: all, first, none "
              "or names", show_default=_DEFAULT.export_agents)
@export_options
@click.option("--export-bag", type=click.Path(dir_okay=False, path_type=Path),
              help="also write every exported agent's map after each fusion it received, per "
                   "rule, as octomap_msgs/Octomap + PointCloud2 (.mcap, .bag or a ROS 2 bag "
                   "folder) to replay the run in RViz or Foxglove")
@click.option("--robust/--no-robust", default=None, show_default="off",
              help="vote out a robot whose map disagrees with its neighbours' (dynamic voting; "
                   "its time and parameters: fuse.robust in --config)")
@config_options
@out_option
def run(bags, export_bag, **p):
    """The whole job in time order: build, exchange, fuse, score, export, report."""
    cfg = run_config(p, bags=bags)
    if p["dump_config"]:
        return _dump(cfg)
    _need_bags(cfg, "octofuse run BAG... --rule R --topology T --out DIR")
    _need_out(cfg, p["out"])
    _run_and_report(cfg, "octofuse run", "run", export_bag=export_bag)


def bundled_dataset() -> Path:
    """The bundled simulated dataset (installed with the package, or in the checkout)."""
    here = Path(__file__).resolve().parent
    for cand in (here / "data" / "lab8.bag", here.parents[1] / "data" / "lab8.bag"):
        if cand.is_file():
            return cand
    raise CliError("the bundled dataset lab8.bag was not found (reinstall octofuse, or run "
                   "`octofuse run data/lab8.bag ...` from the source checkout)")


@cli.command()
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=Path("octofuse-demo"),
              help="output folder")
@click.option("--rule", "--rules", "rule", multiple=True, help="rules, comma separated",
              show_default="all,channel-filter")
@click.option("--every", type=click.IntRange(min=1), help="use every N-th scan", show_default="1")
@click.option("--threads", type=click.IntRange(0, 256), help="0: one per core", show_default="0")
@export_options
def demo(**p):
    """The paper's setting on the bundled dataset: 8 robots, max-robust:3, every rule."""
    bag = bundled_dataset()
    cfg = run_config(p, bags=[bag], defaults={
        "fuse": {"rules": ["all", "channel-filter"], "topology": "max-robust:3",
                 "schedule": "aperiodic:20"},
        "samples": 8, "export_agents": "first"})
    say(f"octofuse demo: {bag.name} (simulated 15 x 8 m lab, 8 robots, 120 s), max-robust:3, "
        "aperiodic exchanges, every rule")
    _run_and_report(cfg, "octofuse demo: 8 robots, max-robust:3", "demo")


@cli.command("fuse")
@click.argument("maps_dir", type=click.Path(path_type=Path))
@rule_option
@topology_option
@click.option("--rounds", type=click.IntRange(1, 10_000), help="synchronous rounds of exchanges",
              show_default="3")
@click.option("--directions", type=click.Choice(["both", "one"]), help="messages on a link",
              show_default="both")
@click.option("--unknown", type=click.Choice(["copy", "prior"]), help="voxels known to one map only",
              show_default="copy")
@click.option("--seed", type=int, help="seed of random topologies", show_default="0")
@click.option("--truth", type=click.Path(dir_okay=False, path_type=Path), help="scene ground truth JSON")
@click.option("--threads", type=click.IntRange(0, 256), help="0: one per core", show_default="0")
@frame_options
@export_options
@config_options
@out_option
def fuse_cmd(maps_dir, rounds, **p):
    """Fuse finished maps (a folder written by `octofuse build`) over a graph for R rounds."""
    from .fusion.rounds import fuse_finished
    from .maps.occupancy import OccupancyMap
    from .maps.truth import Scene
    from .outputs.report import write_outputs
    from .outputs.staging import check_replaceable, staged_folder

    cfg = run_config({**p, "schedule": None if rounds is None else f"rounds:{rounds}"},
                     bags=[maps_dir], defaults={"fuse": {"schedule": "rounds:3"}})
    if p["dump_config"]:
        return _dump(cfg)
    out = check_replaceable(_need_out(cfg, p["out"]))
    if not maps_dir.is_dir():
        raise CliError(f"maps folder '{maps_dir}' does not exist")
    files = sorted(f for f in maps_dir.glob("*.ot") if f.stem != "centralized")
    if len(files) < 2:
        raise CliError(f"'{maps_dir}' holds {len(files)} agent map(s) (*.ot besides centralized.ot); "
                       "fusion needs at least 2")
    maps = {f.stem: OccupancyMap.load(f) for f in files}
    central_path = maps_dir / "centralized.ot"
    central = OccupancyMap.load(central_path) if central_path.is_file() else None
    res = fuse_finished(maps, central, cfg.fuse, truth=Scene.find(cfg.truth, []),
                        threads=cfg.build.threads)
    title = f"octofuse fuse: {cfg.fuse.schedule.partition(':')[2]} rounds over {cfg.fuse.topology}"
    with staged_folder(out, "fuse") as stage:
        write_outputs(res, stage, cfg, title=title)
    say(f"fused {len(maps)} maps with {', '.join(cfg.fuse.rules)} over {cfg.fuse.topology} "
        f"({len(res.events)} messages); report: {out / 'report.md'}")


@cli.command()
@bag_arguments
@rule_option
@click.option("--topologies", default="ring,max-robust:3", help="comma separated topologies")
@click.option("--schedules", help="comma separated schedules, a study axis", show_default="--schedule")
@click.option("--seeds", help="comma separated seeds, a study axis (mean and spread in the tables)",
              show_default="--seed")
@click.option("--executor", type=click.Choice(["auto", "serial", "ray"]), default="auto",
              help="where the cells run (auto: a local Ray when Ray is installed)")
@click.option("--ray-address", help="join this Ray cluster instead of starting a local Ray")
@click.option("--resume", is_flag=True, help="reuse the finished cells of --out and of an "
              "interrupted run")
@exchange_options
@build_options
@config_options
@out_option
def bench(bags, topologies, schedules, seeds, executor, ray_address, resume, **p):
    """Compare rules x topologies against the centralized map: CSV, markdown and plots."""
    from .maps.truth import Scene
    from .outputs.staging import check_replaceable, staged_folder
    from .outputs.study import run_study

    cfg = run_config(p, bags=bags, defaults={"fuse": {"rules": ["all"]}})
    if p["dump_config"]:
        return _dump(cfg)
    _need_bags(cfg, "octofuse bench BAG... --out DIR")
    out = check_replaceable(_need_out(cfg, p["out"]))
    topo = [t.strip() for t in topologies.split(",") if t.strip()]
    if not topo:
        raise click.BadParameter("give at least one topology", param_hint="--topologies")
    try:
        seed_list = [int(x) for x in seeds.split(",") if x.strip()] if seeds else None
    except ValueError:
        raise click.BadParameter(f"{seeds!r}: expected whole numbers", param_hint="--seeds") from None
    # cells finished so far, kept beside --out so that an interrupted study can be resumed
    journal = out.parent / f".{out.name}.cells"
    if not resume:
        shutil.rmtree(journal, ignore_errors=True)
    with staged_folder(out, "bench") as stage:
        run_study(cfg, topo, stage, truth=Scene.find(cfg.truth, cfg.build.bags),
                  progress=Progress, log=say, seeds=seed_list,
                  schedules=[x.strip() for x in schedules.split(",") if x.strip()] if schedules else None,
                  executor=executor, ray_address=ray_address,
                  resume_from=[out, journal] if resume else [], journal=journal)
    shutil.rmtree(journal, ignore_errors=True)
    say(f"wrote {out / 'bench.csv'}, {out / 'bench.md'} and plots")


@cli.command()
@click.argument("src", type=click.Path(path_type=Path))
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="file to write: .ply/.pcd cloud, or .ot/.bt map")
@click.option("--all-voxels", is_flag=True, help="map clouds: every known voxel, not only occupied ones")
@click.option("--cmap", help="matplotlib colour map", show_default="viridis for maps, inferno for heat maps")
def export(src, out, all_voxels, cmap):
    """Write a map or an information-loss file as a PLY/PCD point cloud, or convert .ot/.bt."""
    from .outputs.export import export_map

    say(str(export_map(src, out, occupied_only=not all_voxels, cmap=cmap)))


@cli.command()
@click.argument("maps", nargs=-1, required=True, type=click.Path(path_type=Path))
def info(maps):
    """Print resolution, size and occupancy statistics of map files."""
    from .outputs.tables import map_info_table

    _console().print(map_info_table(maps))


@cli.command("fuse-maps")
@click.argument("maps", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--rule", default="min-info-loss", help="fusion rule")
@click.option("--unknown", type=click.Choice(["copy", "prior"]), default="copy",
              help="voxels known to one map only")
@click.option("--frame", multiple=True, help="NAME=x,y,z,roll,pitch,yaw: the rigid transform from "
              "map NAME's frame (its file name without suffix) into the common frame; metres, radians")
@click.option("--resolution", type=float, help="voxel size of the fused map",
              show_default="the coarsest input's")
@click.option("--strict", is_flag=True, help="refuse maps of different resolutions instead of resampling")
@click.option("--export-bag", type=click.Path(dir_okay=False, path_type=Path),
              help="also write the fused map as octomap_msgs/Octomap + PointCloud2 (.mcap, .bag or "
                   "a ROS 2 bag folder) for RViz and Foxglove")
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="fused map to write (.ot or .bt)")
def fuse_maps_cmd(maps, rule, unknown, frame, resolution, strict, export_bag, out):
    """Fuse map files (A.ot B.ot ... -> OUT.ot), each in its own frame and resolution."""
    from .maps.frames import fuse_map_files, parse_frame
    from .rules import parse_rule

    parse_rule(rule)
    if out.suffix not in (".ot", ".bt"):
        raise click.BadParameter(f"'{out}': expected a .ot or .bt file name", param_hint="--out")
    if len(maps) < 2:
        raise click.UsageError("give at least two map files")
    frames = dict(parse_frame(f) for f in frame)
    fused, _, stats = fuse_map_files(list(maps), rule=rule, unknown=unknown, frames=frames or None,
                                     resolution=resolution, strict=strict)
    fused.save(out)
    if export_bag is not None:
        from .outputs.rosbag_export import write_map_bag

        write_map_bag(export_bag, {out.stem: fused})
    d = stats.as_dict()
    say(f"wrote {out}: {fused.num_leaves} leaves at {fused.resolution:g} m; " +
        ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in d.items()))


@cli.command()
@click.argument("a", type=click.Path(path_type=Path))
@click.argument("b", type=click.Path(path_type=Path))
@click.option("--planar", is_flag=True, help="ground robots: estimate x, y, z and yaw only")
@click.option("--min-fitness", type=click.FloatRange(0.0, 1.0), default=0.5,
              help="refuse an alignment with fewer matching voxels than this fraction")
@click.option("--max-conflict", type=click.FloatRange(0.0, 1.0), default=0.03,
              help="refuse an alignment that puts more of B's occupied voxels than this fraction "
                   "where A saw free space")
@click.option("--json", "as_json", is_flag=True, help="print one JSON object")
def align(a, b, planar, min_fitness, max_conflict, as_json):
    """Estimate the rigid transform that takes map B's frame into map A's (occupied voxels)."""
    import json

    from .maps.occupancy import OccupancyMap
    from .maps.registration import register

    r = register(OccupancyMap.load(a), OccupancyMap.load(b), planar=planar, min_fitness=min_fitness,
                 max_conflict=max_conflict)
    d = r.as_dict()
    if as_json:
        click.echo(json.dumps(d))
    else:
        say(f"B -> A: x {d['x']:.4f} m, y {d['y']:.4f} m, z {d['z']:.4f} m, roll {d['roll']:.5f}, "
            f"pitch {d['pitch']:.5f}, yaw {d['yaw']:.5f} rad; fitness {d['fitness']:.3f}, "
            f"conflict {d['conflict']:.3f}")


@cli.command()
@click.option("--setting", type=click.Choice(["3-robots", "8-robots"]), default="3-robots",
              help="the paper's cyclic 3-robot pattern, or 8 robots on max-robust:3")
@click.option("--rule", "--rules", "rule", multiple=True, help="mixture fusion rules, comma separated",
              show_default="naive-bayes,bhattacharyya,chernoff,kld-weighted-chernoff,min-info-loss")
@click.option("--seed", type=int, default=0, help="seed of the target, the detections and the sampling")
@click.option("--duration", type=click.IntRange(1, 3600), default=65, help="seconds of search")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="output folder")
def search(setting, rule, seed, duration, out):
    """Multi-robot target search with Gaussian-mixture beliefs (paper 000): report and figures."""
    from .targets.search import DEFAULT_RULES
    from .targets.search_report import run_target_search

    rules = [r.strip() for x in rule for r in x.split(",") if r.strip()] or list(DEFAULT_RULES)
    run_target_search(out, setting=setting, rules=rules, seed=seed, duration=duration, progress=say)
    say(f"report: {out / 'report.md'}")


@cli.command()
@click.option("--duration", type=click.FloatRange(0.2, 600), default=10.0, help="seconds tracked")
@click.option("--seed", type=int, default=0, help="seed of the range noise")
@click.option("--families", default="expoly,gaussian,mixture",
              help="belief types, comma separated: expoly, gaussian, mixture")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="output folder")
def track(duration, seed, families, out):
    """Range-only tracking over a directed ring of four nodes (paper 004): report and figures."""
    from .targets.tracking_report import run_tracking

    names = tuple(f.strip() for f in families.split(",") if f.strip())
    run_tracking(out, duration=duration, seed=seed, families=names)
    say(f"report: {out / 'report.md'}")


# ------------------------------------------------------------------------------ entry point


def main(argv: Optional[list[str]] = None) -> int:
    """Run the CLI: usage errors exit 2 with click's message, bad input 1 with one line,
    an interruption 130; never a traceback (``OCTOFUSE_DEBUG=1`` shows one for a bug)."""
    try:
        args = sys.argv[1:] if argv is None else list(argv)
        with cli.make_context("octofuse", args) as ctx:  # interruptions reach the handler below
            cli.invoke(ctx)
    except click.exceptions.Exit as e:
        return e.exit_code
    except click.ClickException as e:
        e.show()
        return e.exit_code
    except click.Abort:
        _error("interrupted")
        return 130
    except KeyboardInterrupt:
        _error("interrupted")
        return 130
    except (CliError, ValueError, OSError, KeyError, MemoryError, RecursionError) as e:
        _error(_message(e))
        return 1
    except Exception as e:  # a bug in octofuse, not bad input
        if _bad_input(e):
            _error(_message(e))
            return 1
        if os.environ.get("OCTOFUSE_DEBUG"):
            raise
        _error(f"internal error ({type(e).__name__}: {_message(e)}); rerun with OCTOFUSE_DEBUG=1 "
               "for the traceback")
        return 70
    return 0


def _bad_input(e: BaseException) -> bool:
    """A bag or transform error (bad input); their modules are imported only if they ran."""
    for module, name in (("octofuse.scans.bags", "BagError"), ("octofuse.scans.tf", "TransformError")):
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


if __name__ == "__main__":
    sys.exit(main())
