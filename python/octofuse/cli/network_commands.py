"""Commands that fuse maps over a network: ``run`` (in time), ``demo``, ``fuse`` (finished
maps, in rounds) and ``bench`` (rules x topologies)."""

from __future__ import annotations

import contextlib
import shutil
from pathlib import Path

import click

from ..config import RunConfig
from ..threads import ThreadBudget
from .options import (
    _DEFAULT,
    THREADS,
    CliError,
    ListOption,
    NameList,
    Progress,
    RuleList,
    _options,
    bag_arguments,
    build_options,
    cli,
    config_options,
    console,
    dump_config,
    exchange_options,
    export_options,
    frame_options,
    layers_option,
    need_bags,
    need_out,
    out_option,
    passes_option,
    rule_option,
    run_config,
    say,
    topology_option,
)

export_bag_option = _options(
    click.option(
        "--export-bag",
        type=click.Path(dir_okay=False, path_type=Path),
        help="also write every exported agent's map after each fusion it received, per "
        "rule, as octomap_msgs/Octomap + PointCloud2 (.mcap, .bag or a ROS 2 bag "
        "folder) to replay the run in RViz or Foxglove",
    ),
    click.option(
        "--bag-every",
        type=click.IntRange(min=1),
        default=1,
        show_default=True,
        metavar="N",
        help="--export-bag: an agent's map at every N-th fusion it receives",
    ),
    click.option(
        "--bag-clouds-only",
        is_flag=True,
        help="--export-bag: occupied voxels only (PointCloud2, what a viewer such as "
        "Foxglove shows), not the whole octomaps",
    ),
)


def _run_and_report(
    cfg: RunConfig,
    title: str,
    command: str,
    export_bag: Path | None = None,
    bag_options: dict | None = None,
) -> None:
    from ..fusion.simulate import simulate, simulate_in_rule_groups
    from ..maps.truth import Scene
    from ..outputs.libraries import import_once_under_way
    from ..outputs.report import write_outputs
    from ..outputs.staging import check_replaceable
    from ..outputs.tables import scores_table

    out = check_replaceable(cfg.out)
    truth = Scene.find(cfg.truth, cfg.build.bags)
    bag = None
    if export_bag is not None:
        if cfg.export_agents == "none":
            raise CliError("--export-bag: no agent is exported (--export-agents none)")
        bag = _event_bag(
            export_bag,
            cfg,
            out,
            lambda agents: _export_agents(cfg.export_agents, agents),
            **(bag_options or {}),
        )
    with ThreadBudget(cfg.build.threads) as budget, _staged_with_bag(out, command, bag) as stage:
        with contextlib.ExitStack() as stack:
            bar = stack.enter_context(Progress(f"mapping + fusing ({len(cfg.fuse.rules)} rule(s))"))
            bar = import_once_under_way(bar)  # the inputs checked: an exit waits for imports
            # either way the final scores' loss leaves are kept, for the loss histogram
            if bag is not None:  # one pass in bag time: the bags' start is needed first
                from ..scans.source import ScanSource

                src = stack.enter_context(ScanSource(cfg.build))
                bag.start_ns = src.bags.start_ns or 0
                bag.expected = _bag_messages(cfg, src, bag.every)
                passes = _one_group(
                    lambda: simulate(
                        cfg.build,
                        cfg.fuse,
                        samples=cfg.samples,
                        truth=truth,
                        progress=bar,
                        source=src,
                        observer=bag,
                        keep_loss_leaves=True,
                        budget=budget,
                    )
                )
            else:
                passes = simulate_in_rule_groups(
                    cfg.build,
                    cfg.fuse,
                    samples=cfg.samples,
                    truth=truth,
                    progress=bar,
                    keep_loss_leaves=True,
                    budget=budget,
                )
            res, written = write_rule_groups(
                passes,
                stage,
                cfg,
                lambda agents: _export_agents(cfg.export_agents, agents),
                budget,
            )
        write_outputs(res, stage, cfg, title=title, event_bag=bag, maps=written)
    screen = console()
    screen.print(scores_table(res, title, width=screen.width))
    _say_alignment(res)
    if bag is not None:
        say(f"bag: {bag.path} ({bag.messages} map messages)")
    say(f"report: {out / 'report.md'}")


def _say_alignment(res) -> None:
    """Per link of a run with alignment: its estimate and confirmation, or why it was refused."""
    from ..fusion.agent_frames import alignment_lines

    for line in alignment_lines(getattr(res, "alignment", None) or []):
        say(line)


def write_rule_groups(
    results, stage: Path, cfg: RunConfig, export_agents, budget: ThreadBudget | None = None
):
    """The results of a run's groups of rules merged into one, each group's maps written into
    ``stage`` as it arrives and then freed (only what comes after is kept: heat maps' voxels,
    histogram values); the merged result and the :class:`MapExports` that wrote them.
    ``export_agents(agents)``: the agents whose maps are written; ``budget``: the run's
    :class:`~octofuse.threads.ThreadBudget` (default: the configuration's threads)."""
    from ..fusion.results import merge_rule_results, without_maps
    from ..memory import return_freed_memory
    from ..outputs.map_exports import MapExports
    from ..threads import thread_map

    threads = budget or cfg.build.threads

    written, parts = None, []
    for part in results:
        if written is None:
            written = MapExports(
                stage, cfg, cfg.fuse.rules, export_agents(part.agents), threads=threads
            )
        written.add(part)
        # the rules' maps freed on every thread: the next rules' maps reuse their memory; the
        # losses a map carries go with it, its loss map is freed next
        rule_maps = [m for per in (*part.fused.values(), part.unclamped) for m in per.values()]
        thread_map(lambda m: m.clear(keep_loss=False), rule_maps, threads)
        loss_maps = [m for per in part.loss.values() for m in per.values()]
        thread_map(lambda m: m.clear(), loss_maps, threads)
        parts.append(without_maps(part))
        del part, rule_maps, loss_maps
        return_freed_memory()
    return merge_rule_results(parts), written


def _one_group(run):
    """Every rule in one group for :func:`write_rule_groups`: ``run()``'s result, computed
    when the writer asks for it and not held afterwards."""
    yield run()


def _event_bag(
    path: Path, cfg: RunConfig, out: Path, select, bag_every: int = 1, bag_clouds_only: bool = False
):
    """The per-event bag of ``--export-bag`` with the maps of the agents ``select(agents)``,
    checked and opened before the run."""
    from ..outputs.event_bag import FusionEventBag

    if path.absolute() == out.absolute() or out.absolute() in path.absolute().parents:
        raise CliError(
            f"--export-bag '{path}' is inside --out '{out}', which is replaced "
            "whole; give a path outside it"
        )
    return FusionEventBag(
        path,
        frame_id=cfg.build.fixed_frame.strip("/"),
        select=select,
        every=bag_every,
        clouds_only=bag_clouds_only,
        say=say,
    )


def _bag_messages(cfg: RunConfig, src, every: int) -> int:
    """About how many map messages the run's ``--export-bag`` will hold: per rule and
    exported agent, every ``every``-th of the exchange times at which it receives."""
    from ..fusion.schedule import run_schedule

    agents = [a.name for a in src.agents]
    _, _, events = run_schedule(cfg.fuse, agents, src.bags.start_ns, src.bags.end_ns)
    exported = set(_export_agents(cfg.export_agents, agents))
    times: dict[str, set] = {a: set() for a in exported}
    for e in events:
        if not e.lost and agents[e.receiver] in exported:
            times[agents[e.receiver]].add(e.time_s)
    return len(cfg.fuse.rules) * sum(-(-len(t) // every) for t in times.values())


@contextlib.contextmanager
def _staged_with_bag(out: Path, command: str, bag):
    """:func:`~octofuse.outputs.staging.staged_folder` of ``out``, with the per-event bag (or
    None) finished before the folder is put in place, and dropped if anything fails."""
    from ..outputs.staging import staged_folder

    try:  # the bag put in place in the step that puts the folder in place
        with staged_folder(out, command, also=() if bag is None else (bag.put_in_place,)) as stage:
            yield stage
            if bag is not None:
                bag.finish()
    finally:
        if bag is not None:
            bag.abort()  # nothing once closed


def _export_agents(spec: str, agents: list[str]) -> list[str]:
    if spec in ("all", "none", "first"):
        return {"all": agents, "none": [], "first": agents[:1]}[spec]
    names = [n.strip() for n in spec.split(",") if n.strip()]  # the CLI's or a config file's
    bad = [n for n in names if n not in agents]
    if bad:
        raise CliError(
            f"--export-agents: unknown agent(s) {', '.join(bad)}; agents: {', '.join(agents)}"
        )
    return names


@cli.command()
@bag_arguments
@rule_option
@topology_option
@exchange_options
@frame_options
@build_options
@click.option(
    "--samples",
    type=click.IntRange(0, 10_000),
    help="points in time at which KL is recorded",
    show_default=str(_DEFAULT.samples),
)
@click.option(
    "--export-agents",
    type=NameList(what="AGENT", metavar="A[,...]"),
    help="agents whose maps and heat maps are written: all, first, none or names",
    show_default=_DEFAULT.export_agents,
)
@export_options
@export_bag_option
@passes_option(_DEFAULT.fuse.rules_per_pass)
@click.option(
    "--robust/--no-robust",
    default=None,
    show_default="off",
    help="vote out a robot whose map disagrees with its neighbours' (dynamic voting; "
    "its time and parameters: fuse.robust in --config)",
)
@config_options
@out_option
def run(bags, export_bag, **p):
    """The whole job in time order: build, exchange, fuse, score, export, report."""
    cfg = run_config(p, bags=bags)
    if p["dump_config"]:
        return dump_config(cfg)
    need_bags(cfg, "octofuse run BAG... --rule R --topology T --out DIR")
    need_out(cfg, p["out"])
    _run_and_report(
        cfg,
        "octofuse run",
        "run",
        export_bag=export_bag,
        bag_options={k: p[k] for k in ("bag_every", "bag_clouds_only")},
    )


#: the demo's 9 rules in 3 passes over the bag: at most 4 rules' maps held at once (with 8
#: rules, 2 passes held 1.1 GB less than one), for the time of mapping the scans again
DEMO_RULES_PER_PASS = 4


def bundled_dataset() -> Path:
    """The bundled simulated dataset (installed with the package, or in the checkout)."""
    here = Path(__file__).resolve().parents[1]  # the package
    for cand in (here / "data" / "lab8.bag", here.parents[1] / "data" / "lab8.bag"):
        if cand.is_file():
            return cand
    raise CliError(
        "the bundled dataset lab8.bag was not found (reinstall octofuse, or run "
        "`octofuse run data/lab8.bag ...` from the source checkout)"
    )


@cli.command()
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("octofuse-demo"),
    help="output folder",
)
@click.option(
    "--rule",
    "--rules",
    "rule",
    multiple=True,
    cls=ListOption,
    type=RuleList(),
    help="rules, comma separated",
    show_default="all,channel-filter,source-layers",
)
@click.option("--every", type=click.IntRange(min=1), help="use every N-th scan", show_default="1")
@click.option("--threads", type=THREADS, help="0: one per core", show_default="0")
@export_options
@export_bag_option
@passes_option(DEMO_RULES_PER_PASS)
def demo(export_bag, **p):
    """The paper's setting on the bundled dataset: 8 robots, max-robust:3, every rule."""
    bag = bundled_dataset()
    cfg = run_config(
        p,
        bags=[bag],
        defaults={
            "fuse": {
                "rules": ["all", "channel-filter", "source-layers"],
                "topology": "max-robust:3",
                "schedule": "aperiodic:20",
                "rules_per_pass": DEMO_RULES_PER_PASS,
            },
            "samples": 8,
            "export_agents": "first",
        },
    )
    say(
        f"octofuse demo: {bag.name} (simulated 15 x 8 m lab, 8 robots, 120 s), max-robust:3, "
        "aperiodic exchanges, every rule"
    )
    _run_and_report(
        cfg,
        "octofuse demo: 8 robots, max-robust:3",
        "demo",
        export_bag=export_bag,
        bag_options={k: p[k] for k in ("bag_every", "bag_clouds_only")},
    )


@cli.command("fuse")
@click.argument("maps_dir", type=click.Path(path_type=Path))
@rule_option
@topology_option
@click.option(
    "--rounds",
    type=click.IntRange(1, 10_000),
    help="synchronous rounds of exchanges",
    show_default="3",
)
@click.option(
    "--directions",
    type=click.Choice(["both", "one"]),
    help="messages on a link",
    show_default="both",
)
@click.option(
    "--unknown",
    type=click.Choice(["copy", "prior"]),
    help="voxels known to one map only",
    show_default="copy",
)
@click.option("--seed", type=int, help="seed of random topologies", show_default="0")
@click.option(
    "--truth", type=click.Path(dir_okay=False, path_type=Path), help="scene ground truth JSON"
)
@click.option("--threads", type=THREADS, help="0: one per core", show_default="0")
@layers_option
@frame_options
@export_options
@export_bag_option
@config_options
@out_option
def fuse_cmd(maps_dir, rounds, export_bag, **p):
    """Fuse finished maps (a folder written by `octofuse build`) over a graph for R rounds."""
    from ..fusion.rounds import fuse_finished, fuse_finished_in_rule_groups
    from ..maps.occupancy import OccupancyMap
    from ..maps.truth import Scene
    from ..outputs.report import write_outputs
    from ..outputs.staging import check_replaceable

    cfg = run_config(
        {**p, "schedule": None if rounds is None else f"rounds:{rounds}"},
        bags=[maps_dir],
        defaults={"fuse": {"schedule": "rounds:3"}},
    )
    if p["dump_config"]:
        return dump_config(cfg)
    out = check_replaceable(need_out(cfg, p["out"]))
    if not maps_dir.is_dir():
        raise CliError(f"maps folder '{maps_dir}' does not exist")
    files = sorted(f for f in maps_dir.glob("*.ot") if f.stem != "centralized")
    if len(files) < 2:
        raise CliError(
            f"'{maps_dir}' holds {len(files)} agent map(s) (*.ot besides centralized.ot); "
            "fusion needs at least 2"
        )
    maps = {f.stem: OccupancyMap.load(f) for f in files}
    central_path = maps_dir / "centralized.ot"
    central = OccupancyMap.load(central_path) if central_path.is_file() else None
    truth = Scene.find(cfg.truth, [])
    title = f"octofuse fuse: {cfg.fuse.schedule.partition(':')[2]} rounds over {cfg.fuse.topology}"
    every = lambda agents: agents  # noqa: E731  (every agent's maps are written)
    bag = (
        _event_bag(export_bag, cfg, out, every, p["bag_every"], p["bag_clouds_only"])
        if export_bag is not None
        else None
    )
    with ThreadBudget(cfg.build.threads) as budget, _staged_with_bag(out, "fuse", bag) as stage:
        if bag is not None:  # every rule in one group, the bag written round by round
            groups = _one_group(
                lambda: fuse_finished(
                    maps, central, cfg.fuse, truth=truth, threads=budget, observer=bag
                )
            )
        else:  # a few rules at a time: their maps written, then freed before the next
            groups = fuse_finished_in_rule_groups(
                maps, central, cfg.fuse, truth=truth, threads=budget
            )
        res, written = write_rule_groups(groups, stage, cfg, every, budget)
        write_outputs(res, stage, cfg, title=title, event_bag=bag, maps=written)
    _say_alignment(res)
    say(
        f"fused {len(maps)} maps with {', '.join(cfg.fuse.rules)} over {cfg.fuse.topology} "
        f"({len(res.events)} messages); report: {out / 'report.md'}"
    )
    if bag is not None:
        say(f"bag: {bag.path} ({bag.messages} map messages)")


@cli.command()
@bag_arguments
@rule_option
@click.option(
    "--topologies",
    type=NameList(what="TOPOLOGY"),
    default="ring,max-robust:3",
    help="comma separated topologies",
)
@click.option(
    "--schedules",
    type=NameList(what="SCHEDULE"),
    help="comma separated schedules, a study axis",
    show_default="--schedule",
)
@click.option(
    "--seeds",
    type=NameList(item=int, what="SEED"),
    help="comma separated seeds, a study axis (mean and spread in the tables)",
    show_default="--seed",
)
@click.option(
    "--executor",
    type=click.Choice(["auto", "serial", "ray"]),
    default="auto",
    help="where the cells run (auto: a local Ray when Ray is installed)",
)
@click.option("--ray-address", help="join this Ray cluster instead of starting a local Ray")
@click.option(
    "--resume", is_flag=True, help="reuse the finished cells of --out and of an interrupted run"
)
@exchange_options
@frame_options
@passes_option(_DEFAULT.fuse.rules_per_pass)
@build_options
@config_options
@out_option
def bench(bags, topologies, schedules, seeds, executor, ray_address, resume, **p):
    """Compare rules x topologies against the centralized map: CSV, markdown and plots."""
    from ..maps.truth import Scene
    from ..outputs.staging import check_replaceable, staged_folder
    from ..outputs.study import run_study

    cfg = run_config(p, bags=bags, defaults={"fuse": {"rules": ["all"]}})
    if p["dump_config"]:
        return dump_config(cfg)
    need_bags(cfg, "octofuse bench BAG... --out DIR")
    out = check_replaceable(need_out(cfg, p["out"]))
    topo = list(topologies)
    seed_list = list(seeds) if seeds else None
    # cells finished so far, kept beside --out so that an interrupted study can be resumed
    journal = out.parent / f".{out.name}.cells"
    if not resume:
        shutil.rmtree(journal, ignore_errors=True)
    with staged_folder(out, "bench") as stage:
        run_study(
            cfg,
            topo,
            stage,
            truth=Scene.find(cfg.truth, cfg.build.bags),
            progress=Progress,
            log=say,
            seeds=seed_list,
            schedules=list(schedules) if schedules else None,
            executor=executor,
            ray_address=ray_address,
            resume_from=[out, journal] if resume else [],
            journal=journal,
        )
    shutil.rmtree(journal, ignore_errors=True)
    say(f"wrote {out / 'bench.csv'}, {out / 'bench.md'} and plots")
