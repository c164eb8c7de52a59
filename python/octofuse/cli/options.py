"""Shared pieces of the ``octofuse`` commands: the command group, the option sets, and the
one route from flags and ``--config`` files to a configuration (:func:`run_config`).

Flags and ``--config`` files both become plain data, merged (flags win), and
:func:`octofuse.config.from_dict` validates the result once. Heavy modules load inside the
commands, so ``octofuse --help`` is quick.
"""

from __future__ import annotations

import sys
from pathlib import Path

import click

from ..config import INSERT_MODES, MAX_THREADS, RunConfig
from ..interrupts import raise_if_interrupted

_DEFAULT = RunConfig()
CONTEXT = {"help_option_names": ["-h", "--help"], "show_default": True, "max_content_width": 100}


class CliError(Exception):
    """An error the CLI reports as one line with a non-zero exit."""


def console(stderr: bool = False):
    from rich.console import Console

    stream = sys.stderr if stderr else sys.stdout
    return Console(stderr=stderr, width=None if stream.isatty() else 120)


def say(text: str) -> None:
    console().print(text, highlight=False, markup=False, soft_wrap=True)


# ---------------------------------------------------------------------------- shared options


def _options(*decorators):
    def apply(f):
        for d in reversed(decorators):
            f = d(f)
        return f

    return apply


class NameList(click.ParamType):
    """A comma-separated list, parsed once: no empty item, no item twice, each item one of
    ``choices()`` if given (a function, so that the names are looked up only when a list is
    parsed or the help is shown) and converted by ``item``. Gives a tuple."""

    name = "list"

    def __init__(self, choices=None, item=str, what: str = "NAME", metavar: str = ""):
        self.choices, self.item, self.what = choices, item, what
        self.metavar = metavar or f"{what}[,...]"

    def convert(self, value, param, ctx):
        if isinstance(value, tuple):
            return value
        items = [x.strip() for x in str(value).split(",")]
        if not all(items):
            self.fail(
                f"{value!r} has an empty item; expected {self.what}[,{self.what}...]", param, ctx
            )
        twice = next((x for i, x in enumerate(items) if x in items[:i]), None)
        if twice is not None:
            self.fail(f"{value!r} names {twice!r} twice", param, ctx)
        if self.choices is not None:
            valid = self.choices()
            bad = [x for x in items if x not in valid]
            if bad:
                self.fail(
                    f"unknown {bad[0]!r}; expected one or more of {', '.join(valid)}", param, ctx
                )
        try:
            return tuple(self.item(x) for x in items)
        except ValueError:
            self.fail(f"{value!r}: expected {self.what}[,{self.what}...]", param, ctx)

    def get_metavar(self, param, ctx=None):
        return self.metavar


class ListOption(click.Option):
    """An option of a :class:`NameList` whose help ends with the names it takes (looked up
    only when the help is shown)."""

    def get_help_record(self, ctx):
        record = super().get_help_record(ctx)
        if record is None or getattr(self.type, "choices", None) is None:
            return record
        first, text = record
        return first, f"{text}  [one or more of: {', '.join(self.type.choices())}]"


class RuleList(NameList):
    """``--rule`` of the map commands: fusion rules parsed into
    :class:`~octofuse.rule_names.FusionRule` members (every rule, 'all', the exact modes)."""

    def __init__(self):
        from ..rule_names import rule_choices

        super().__init__(rule_choices, what="RULE", metavar="R[,...]")

    def convert(self, value, param, ctx):
        from ..rule_names import parse_rules

        return parse_rules(super().convert(value, param, ctx))


#: ``--threads``: the core's range, 0 for one per core
THREADS = click.IntRange(0, MAX_THREADS)


def flat(lists) -> list:
    """The items of a repeated list option, in order (an item given twice is kept once)."""
    return list(dict.fromkeys(x for items in lists or () for x in items))


bag_arguments = click.argument("bags", nargs=-1, type=click.Path(path_type=Path))
config_options = _options(
    click.option(
        "--config",
        type=click.Path(dir_okay=False, path_type=Path),
        help="YAML configuration (see --dump-config); flags given win",
    ),
    click.option(
        "--dump-config",
        is_flag=True,
        help="print the configuration (defaults + config file + flags) and exit",
    ),
)
build_options = _options(
    click.option(
        "--agent",
        multiple=True,
        help="NAME=TOPIC (repeatable)  [default: one agent per scan topic]",
    ),
    click.option(
        "--pose",
        multiple=True,
        help="NAME=POSE_TOPIC instead of tf: Odometry, PoseStamped, "
        "PoseWithCovarianceStamped or TransformStamped",
    ),
    click.option(
        "--sensor-offset", multiple=True, help="NAME=x,y,z,qx,qy,qz,qw sensor pose on the robot"
    ),
    click.option(
        "--fixed-frame", help="fixed frame of the maps", show_default=_DEFAULT.build.fixed_frame
    ),
    click.option(
        "--resolution",
        type=float,
        help="voxel size in metres",
        show_default=str(_DEFAULT.build.map.resolution),
    ),
    click.option(
        "--max-range",
        type=float,
        help="longer rays only clear free space; <= 0: no limit",
        show_default="no limit",
    ),
    click.option(
        "--no-return",
        type=click.Choice(["skip", "free"]),
        help="LaserScan beams without echo",
        show_default=_DEFAULT.build.no_return,
    ),
    click.option(
        "--every",
        type=click.IntRange(min=1),
        help="use every N-th scan of each agent",
        show_default="1",
    ),
    click.option(
        "--threads",
        type=THREADS,
        help="threads for ray casting, fusion and scoring; 0: one per core",
        show_default="0",
    ),
    click.option(
        "--insert-mode",
        type=click.Choice(INSERT_MODES),
        metavar="MODE",
        help="exact: OctoMap's insertPointCloud; fast: real time for dense 3D lidar scans",
        show_default=_DEFAULT.build.insert_mode,
    ),
)
rule_option = click.option(
    "--rule",
    "--rules",
    "rule",
    multiple=True,
    cls=ListOption,
    type=RuleList(),
    help="fusion rule(s), comma separated, or 'all'",
    show_default=",".join(_DEFAULT.fuse.rules),
)


class ByteSize(click.ParamType):
    """A byte size such as 512MB or 2GiB (:func:`~octofuse.config.parse_bytes`), as bytes."""

    name = "SIZE"

    def convert(self, value, param, ctx):
        from ..config import parse_bytes

        if isinstance(value, int):
            return value
        try:
            return parse_bytes(value)
        except ValueError as e:
            self.fail(str(e), param, ctx)


layers_option = click.option(
    "--layers-max-bytes",
    type=ByteSize(),
    help="source-layers: bytes of layers an agent holds before it folds the oldest into one "
    "conservative remainder (exact no more), e.g. 512MB; 0: unlimited",
    show_default=str(_DEFAULT.fuse.layers_max_bytes),
)
exchange_options = _options(
    click.option(
        "--schedule",
        help="aperiodic:MEAN_S or periodic:PERIOD_S",
        show_default=_DEFAULT.fuse.schedule,
    ),
    click.option(
        "--directions",
        type=click.Choice(["both", "one"]),
        help="messages on a link",
        show_default=_DEFAULT.fuse.directions,
    ),
    click.option(
        "--delta/--whole-maps",
        default=None,
        help="send only voxels changed since the last message on a link",
        show_default="whole maps",
    ),
    click.option(
        "--unknown",
        type=click.Choice(["copy", "prior"]),
        help="voxels known to one map only",
        show_default=_DEFAULT.fuse.unknown,
    ),
    click.option(
        "--seed",
        type=int,
        help="seed of random topologies and schedules",
        show_default=str(_DEFAULT.fuse.seed),
    ),
    click.option(
        "--truth",
        type=click.Path(dir_okay=False, path_type=Path),
        help="scene ground truth JSON",
        show_default="NAME_scene.json beside the bag",
    ),
    click.option(
        "--spanning-tree",
        help="the tree the channel-filter rule runs on: bfs, given "
        "(the topology is a tree) or a graph file",
        show_default=_DEFAULT.fuse.spanning_tree,
    ),
    click.option(
        "--loss",
        type=click.FloatRange(0.0, 1.0, max_open=True),
        help="probability that a message is lost (seeded, the same messages for every rule)",
        show_default=str(_DEFAULT.fuse.loss),
    ),
    layers_option,
)
frame_options = _options(
    click.option(
        "--agent-frame",
        multiple=True,
        help="NAME=x,y,z,roll,pitch,yaw: the rigid transform from agent NAME's map frame "
        "into the common frame (metres, radians; repeatable)",
        show_default="every agent in the common frame",
    ),
    click.option(
        "--align",
        type=click.Choice(["off", "planar", "full"]),
        metavar="MODE",
        help="estimate each link's transform on first contact: off, planar (x, y, z, yaw) or full",
        show_default=_DEFAULT.fuse.align,
    ),
)


def passes_option(default: int):
    return click.option(
        "--rules-per-pass",
        type=click.IntRange(min=0),
        metavar="N",
        show_default=str(default),
        help="rules whose maps are held at once; more rules map the scans once per group of "
        "this many (less memory, more time); 0: all in one pass",
    )


topology_option = click.option(
    "--topology",
    help="ring, line, star, complete, grid, random:P, max-robust:K or a graph file",
    show_default=_DEFAULT.fuse.topology,
)
out_option = click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    help="output folder (replaced whole when it holds an earlier octofuse output)",
)
export_options = _options(
    click.option(
        "--export",
        type=click.Choice(["all", "fused", "none"]),
        metavar="MODE",
        help="per rule and exported agent: fused map and heat maps (all), the fused map "
        "only (fused), or nothing (none: report, summary and plots)",
        show_default=_DEFAULT.export,
    ),
    click.option(
        "--formats",
        help="heat-map formats, comma separated: ply, pcd",
        show_default=",".join(_DEFAULT.formats),
    ),
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


def run_config(
    p: dict, *, bags=None, defaults: dict | None = None, cls=RunConfig, extra: dict | None = None
) -> RunConfig:
    """The configuration of a command: the configuration's defaults, then the command's own
    ``defaults`` (e.g. bench's every rule), then ``--config``, then the flags in ``p`` (and
    the sections ``extra`` of a configuration ``cls`` beyond a run's, from its own flags)."""
    from ..config import from_dict, merge, read_yaml

    data = read_yaml(p["config"]) if p.get("config") else {}
    if data:  # the file's own errors name the file and the key
        from_dict(cls, data, where=str(p["config"]))
    data = merge(defaults or {}, data)
    build = _given(
        fixed_frame=p.get("fixed_frame"),
        max_range=p.get("max_range"),
        no_return=p.get("no_return"),
        scan_stride=p.get("every"),
        threads=p.get("threads"),
        insert_mode=p.get("insert_mode"),
    )
    if bags:
        build["bags"] = [str(b) for b in bags]
    if p.get("resolution") is not None:
        build["map"] = {"resolution": p["resolution"]}
    if p.get("agent"):
        build["agents"] = [
            dict(zip(("name", "topic"), kv)) for kv in _pairs(p["agent"], "NAME=TOPIC").items()
        ]
    fuse = _given(
        rules=flat(p.get("rule")),
        topology=p.get("topology"),
        schedule=p.get("schedule"),
        directions=p.get("directions"),
        delta=p.get("delta"),
        unknown=p.get("unknown"),
        seed=p.get("seed"),
        spanning_tree=p.get("spanning_tree"),
        loss=p.get("loss"),
        rules_per_pass=p.get("rules_per_pass"),
        layers_max_bytes=p.get("layers_max_bytes"),
    )
    if p.get("robust") is not None:
        fuse["robust"] = {"enabled": p["robust"]}
    if p.get("agent_frame"):
        from ..maps.frames import parse_frame_values

        fuse["agent_frames"] = [
            dict(zip(("name", "pose"), parse_frame_values(f))) for f in p["agent_frame"]
        ]
    if p.get("align") is not None:
        fuse["align"] = p["align"]
    run = _given(
        out=str(p["out"]) if p.get("out") else None,
        truth=str(p["truth"]) if p.get("truth") else None,
        samples=p.get("samples"),
        export_agents=",".join(p["export_agents"]) if p.get("export_agents") else None,
        export=p.get("export"),
        formats=[p["formats"]] if p.get("formats") else None,
    )
    data = merge(data, {"build": build, "fuse": fuse, **run, **(extra or {})})
    _agent_poses(data, p)
    return from_dict(cls, data, where="options")


def _agent_poses(data: dict, p: dict) -> None:
    poses = _pairs(p.get("pose") or (), "NAME=POSE_TOPIC")
    offsets = _pairs(p.get("sensor_offset") or (), "NAME=x,y,z,qx,qy,qz,qw")
    agents = {
        a.get("name"): a for a in data.get("build", {}).get("agents", []) if isinstance(a, dict)
    }
    for name in [*poses, *offsets]:
        if name not in agents:
            raise click.BadParameter(
                f"--pose/--sensor-offset name '{name}' is not an agent given "
                f"with --agent (agents: {', '.join(map(str, agents)) or 'none'})"
            )
    for name, topic in poses.items():
        agents[name]["pose_topic"] = topic
    for name, text in offsets.items():
        try:
            agents[name]["sensor_offset"] = [float(v) for v in text.split(",")]
        except ValueError:
            raise click.BadParameter(
                f"--sensor-offset {name}: expected 7 numbers x,y,z,qx,qy,qz,qw"
            ) from None


def dump_config(cfg) -> None:
    from ..config import dump_yaml

    click.echo(dump_yaml(cfg), nl=False)


def need_bags(cfg: RunConfig, usage: str) -> None:
    if not cfg.build.bags:
        raise click.UsageError(f"no bag given: {usage}")
    for b in cfg.build.bags:
        if not Path(b).exists():
            raise CliError(f"bag '{b}' does not exist")


def need_out(cfg: RunConfig, given: Path | None) -> Path:
    if given is None and cfg.out == _DEFAULT.out:
        raise click.UsageError("--out DIR is required")
    return Path(cfg.out)


class Progress:
    """A progress bar on a terminal (nothing otherwise); called as ``bar(done, total)``."""

    def __init__(self, description: str):
        from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeRemainingColumn
        from rich.progress import Progress as Bar

        err = console(stderr=True)
        self._bar = Bar(
            TextColumn("{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeRemainingColumn(),
            console=err,
            transient=True,
            disable=not err.is_terminal,
        )
        self._task = self._bar.add_task(description, total=None)

    def __enter__(self) -> Progress:
        self._bar.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        self._bar.__exit__(*exc)

    def __call__(self, done: int, total: int) -> None:
        raise_if_interrupted()
        self._bar.update(self._task, completed=done, total=total)


@click.group(context_settings=CONTEXT)
@click.version_option(package_name="octofuse", prog_name="octofuse")
def cli() -> None:
    """Conservative fusion of multi-robot beliefs: OctoMap maps fused with WEP rules."""
