"""Live fleets: ``octofuse agent`` (one robot's process) and ``octofuse fleet`` (a fleet of them
on this machine, collected and scored as ``run`` scores its own)."""

from __future__ import annotations

import contextlib
from pathlib import Path

import click

from .network_commands import _export_agents, _staged_with_bag, write_rule_groups
from .options import (
    CliError,
    NameList,
    bag_arguments,
    build_options,
    cli,
    config_options,
    console,
    dump_config,
    exchange_options,
    export_options,
    need_bags,
    need_out,
    out_option,
    rule_option,
    run_config,
    say,
    topology_option,
)


def _faults(text: str | None) -> dict:
    """``loss=0.2,delay=0.3,...`` as the faults' section."""
    if not text:
        return {}
    out = {}
    for item in text.split(","):
        k, sep, v = item.partition("=")
        if not sep:
            raise click.BadParameter(
                f"{item!r}: expected NAME=VALUE (loss, duplicate, reorder, delay)",
                param_hint="--faults",
            )
        try:
            out[k.strip()] = float(v)
        except ValueError:
            raise click.BadParameter(
                f"{item!r}: expected a number", param_hint="--faults"
            ) from None
    return out


def _partitions(values) -> list[dict]:
    out = []
    for text in values:
        parts = text.split(":")
        try:
            if len(parts) != 3:
                raise ValueError(text)
            start, end, agents = float(parts[0]), float(parts[1]), parts[2].split(",")
        except ValueError:
            raise click.BadParameter(
                f"{text!r}: expected START:END:AGENT[,AGENT...] (seconds)", param_hint="--partition"
            ) from None
        out.append({"start": start, "end": end, "agents": agents})
    return out


@cli.command()
@bag_arguments
@rule_option
@topology_option
@exchange_options
@build_options
@click.option(
    "--lockstep",
    is_flag=True,
    default=None,
    help="hold the agents at each exchange time until its messages arrived: the maps "
    "of `octofuse run` with the same schedule",
)
@click.option(
    "--speed", type=click.FloatRange(min=0.001, max=1000), help="replay speed", show_default="1"
)
@click.option(
    "--link-budget",
    help="bytes per second each link carries, e.g. 2MB/s (needs --delta): the most "
    "informative voxels go first, the rest later",
    show_default="no limit",
)
@click.option("--faults", help="injected faults: loss=P,duplicate=P,reorder=P,delay=SECONDS")
@click.option(
    "--partition",
    multiple=True,
    help="START:END:AGENT[,AGENT...]: those agents cut off from the others (repeatable)",
)
@click.option(
    "--settle-rounds",
    type=click.IntRange(0, 1000),
    help="fault-free rounds of exchanges after the mission",
    show_default="0",
)
@click.option(
    "--view",
    is_flag=True,
    help="show the agents' maps in a web page while they "
    "grow (the address is printed; `octofuse view` is its own command)",
)
@click.option(
    "--base-port",
    type=click.IntRange(1, 65000),
    help="the first agent's port (the next free block is taken)",
    show_default="7447",
)
@click.option(
    "--export-agents",
    type=NameList(what="AGENT", metavar="A[,...]"),
    help="agents whose maps are written: all, first, none or names",
    show_default="all",
)
@export_options
@config_options
@out_option
def fleet(bags, **p):
    """A live fleet on this machine: one agent process per robot and rule over Zenoh."""
    from ..config import FleetConfig
    from ..live.fleet import FleetError, resolved, run_fleet
    from ..maps.truth import Scene
    from ..outputs.report import write_outputs
    from ..outputs.staging import check_replaceable
    from ..outputs.tables import scores_table

    live = {
        k: v
        for k, v in {
            "lockstep": p.get("lockstep"),
            "speed": p.get("speed"),
            "settle_rounds": p.get("settle_rounds"),
            "base_port": p.get("base_port"),
            "link_budget": p.get("link_budget"),
        }.items()
        if v is not None
    }
    faults = _faults(p.get("faults"))
    if p.get("partition"):
        faults["partitions"] = _partitions(p["partition"])
    if faults:
        live["faults"] = faults
    cfg = run_config(p, bags=bags, cls=FleetConfig, extra={"live": live, "samples": 0})
    if p["dump_config"]:
        return dump_config(cfg)
    need_bags(cfg, "octofuse fleet BAG... --rule R --topology T --out DIR")
    out = check_replaceable(need_out(cfg, p["out"]))
    cfg = resolved(cfg)
    truth = Scene.find(cfg.truth, cfg.build.bags)
    title = f"octofuse fleet: {len(cfg.build.agents)} agent processes per rule over Zenoh"
    with _staged_with_bag(out, "fleet", None) as stage, contextlib.ExitStack() as live_view:
        if p.get("view"):
            from ..view.fleet_source import FleetSource
            from .view_commands import serve

            source = FleetSource(cfg)
            live_view.callback(source.close)
            live_view.enter_context(
                serve(source, "127.0.0.1", 8080, 300_000, until="until the fleet ends")
            )
        try:
            res = run_fleet(cfg, stage, log=say, truth=truth)
        except FleetError as e:
            raise CliError(str(e)) from None
        res, written = write_rule_groups(
            iter([res]), stage, cfg, lambda agents: _export_agents(cfg.export_agents, agents)
        )
        write_outputs(res, stage, cfg, title=title, maps=written)
    console().print(scores_table(res, title))
    say(f"report: {out / 'report.md'}")


@cli.command()
@click.argument("name")
@click.option(
    "--fleet",
    "fleet_file",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="the fleet's configuration (fleet.yaml, as `fleet` writes it)",
)
@click.option("--rule", help="the rule this process runs", show_default="the fleet's only rule")
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="folder of the agents' states and final maps",
)
@click.option(
    "--replay",
    multiple=True,
    type=click.Path(path_type=Path),
    help="bag(s) to replay instead of the fleet's",
)
@click.option("--speed", type=click.FloatRange(min=0.001, max=1000), help="replay speed")
@click.option("--fresh", is_flag=True, help="start over instead of resuming from a checkpoint")
@click.option(
    "--from-zenoh",
    "scan_type",
    type=click.Choice(["pointcloud2", "laserscan"]),
    help="map the scans a ROS 2 robot publishes through zenoh-bridge-ros2dds (its "
    "scan topic, tf, tf_static as CDR) instead of replaying bags",
)
@click.option(
    "--duration",
    type=click.FloatRange(min=0.1),
    default=60.0,
    help="seconds to run with --from-zenoh",
)
@click.option(
    "--insert-mode",
    type=click.Choice(["exact", "fast"]),
    help="scan insertion",
    show_default="fast for --from-zenoh pointcloud2, else the fleet's",
)
def agent(name, fleet_file, rule, out, replay, speed, fresh, scan_type, duration, insert_mode):
    """One robot's agent: maps its scans, exchanges with its neighbours over Zenoh."""
    from dataclasses import replace

    from ..config import FleetConfig, load_yaml
    from ..live.agent import LiveAgent

    cfg = load_yaml(fleet_file, FleetConfig)
    if replay:
        cfg = replace(cfg, build=replace(cfg.build, bags=[str(b) for b in replay]))
    if speed is not None:
        cfg = replace(cfg, live=replace(cfg.live, speed=speed))
    if rule is None:
        if len(cfg.fuse.rules) != 1:
            raise CliError(
                f"fleet '{fleet_file}' runs {len(cfg.fuse.rules)} rules: give --rule "
                f"(one of {', '.join(cfg.fuse.rules)})"
            )
        rule = cfg.fuse.rules[0]
    try:
        live = LiveAgent(cfg, name, rule, out, log=say, insert_mode=insert_mode)
        counts = live.run_bridged(scan_type, duration) if scan_type else live.run(resume=not fresh)
    except TimeoutError as e:
        raise CliError(str(e)) from None
    say(
        f"agent {name} ({rule}): {counts.scans} scans, {counts.sent} messages sent, "
        f"{counts.applied} applied, {sum(counts.refused.values())} refused"
    )
