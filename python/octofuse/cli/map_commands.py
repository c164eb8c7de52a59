"""Commands on maps: ``build`` (bags -> maps), ``fuse-maps``, ``align``, ``export``, ``info``."""

from __future__ import annotations

from pathlib import Path

import click

from ..config import FuseConfig
from ..maps.registration import MAX_CONFLICT, MIN_FITNESS
from ..rule_names import CORE_RULES, FusionRule
from .options import (
    Progress,
    bag_arguments,
    build_options,
    cli,
    config_options,
    console,
    dump_config,
    need_bags,
    need_out,
    out_option,
    run_config,
    say,
)

#: what ``fuse-maps --rule`` takes: a per-voxel rule of the core
RULE_NAMES = tuple(str(r) for r in CORE_RULES)


@cli.command()
@bag_arguments
@build_options
@config_options
@out_option
def build(bags, **p):
    """Build every agent's map and the centralized map from bags."""
    from ..maps.build import build as build_maps_from
    from ..maps.build import write_maps
    from ..outputs.staging import check_replaceable, staged_folder
    from ..outputs.tables import build_table, skip_notes

    cfg = run_config(p, bags=bags)
    if p["dump_config"]:
        return dump_config(cfg)
    need_bags(cfg, "octofuse build BAG... --out DIR")
    out = check_replaceable(need_out(cfg, p["out"]))
    with Progress("inserting scans") as bar:
        result = build_maps_from(cfg.build, progress=bar)
    with staged_folder(out, "build") as stage:
        write_maps(result, stage)
    console().print(build_table(result))
    for note in skip_notes(result):
        say(note)
    say(f"wrote {len(result.all_maps())} maps to {out}/")


@cli.command()
@click.argument("src", type=click.Path(path_type=Path))
@click.option(
    "--out",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="file to write: .ply/.pcd cloud, or .ot/.bt map",
)
@click.option(
    "--all-voxels", is_flag=True, help="map clouds: every known voxel, not only occupied ones"
)
@click.option(
    "--cmap", help="matplotlib colour map", show_default="viridis for maps, inferno for heat maps"
)
def export(src, out, all_voxels, cmap):
    """Write a map or an information-loss file as a PLY/PCD point cloud, or convert .ot/.bt."""
    from ..outputs.export import export_map
    from ..outputs.staging import staged_file

    with staged_file(out) as tmp:  # in place only when complete; an interruption keeps the old
        result = export_map(src, tmp, occupied_only=not all_voxels, cmap=cmap)
    say(str(result._replace(path=out)))


@cli.command()
@click.argument("maps", nargs=-1, required=True, type=click.Path(path_type=Path))
def info(maps):
    """Print resolution, size and occupancy statistics of map files."""
    from ..outputs.tables import map_info_table

    console().print(map_info_table(maps))


@cli.command("fuse-maps")
@click.argument("maps", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option(
    "--rule",
    type=click.Choice(RULE_NAMES),
    default=str(FuseConfig.rules[0]),
    metavar="RULE",
    help=f"per-voxel fusion rule: {', '.join(RULE_NAMES)}",
)
@click.option(
    "--unknown",
    type=click.Choice(["copy", "prior"]),
    default="copy",
    help="voxels known to one map only",
)
@click.option(
    "--frame",
    multiple=True,
    help="NAME=x,y,z,roll,pitch,yaw: the rigid transform from "
    "map NAME's frame (its file name without suffix) into the common frame; metres, radians",
)
@click.option(
    "--resolution",
    type=float,
    help="voxel size of the fused map",
    show_default="the coarsest input's",
)
@click.option(
    "--strict", is_flag=True, help="refuse maps of different resolutions instead of resampling"
)
@click.option(
    "--export-bag",
    type=click.Path(dir_okay=False, path_type=Path),
    help="also write the fused map as octomap_msgs/Octomap + PointCloud2 (.mcap, .bag or "
    "a ROS 2 bag folder) for RViz and Foxglove",
)
@click.option(
    "--out",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="fused map to write (.ot or .bt)",
)
def fuse_maps_cmd(maps, rule, unknown, frame, resolution, strict, export_bag, out):
    """Fuse map files (A.ot B.ot ... -> OUT.ot), each in its own frame and resolution."""
    from ..maps.frames import fuse_map_files, parse_frame
    from ..outputs.staging import staged_file

    if out.suffix not in (".ot", ".bt"):
        raise click.BadParameter(f"'{out}': expected a .ot or .bt file name", param_hint="--out")
    if len(maps) < 2:
        raise click.UsageError("give at least two map files")
    frames = dict(parse_frame(f) for f in frame)
    bag = None
    if export_bag is not None:  # checked before the work
        from ..outputs.rosbag_export import MapBagWriter

        bag = MapBagWriter(export_bag)
    try:
        fused, _, stats = fuse_map_files(
            list(maps),
            rule=FusionRule(rule),
            unknown=unknown,
            frames=frames or None,
            resolution=resolution,
            strict=strict,
        )
        with staged_file(out, also=() if bag is None else (bag.put_in_place,)) as tmp:
            fused.save(tmp)
            if bag is not None:
                from ..outputs.rosbag_export import MapEvent

                bag.write(MapEvent(out.stem, 0, fused))
                bag.finish()
    finally:
        if bag is not None:
            bag.abort()  # nothing once in place
    d = stats.as_dict()
    say(
        f"wrote {out}: {fused.num_leaves} leaves at {fused.resolution:g} m; "
        + ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in d.items())
    )


@cli.command()
@click.argument("a", type=click.Path(path_type=Path))
@click.argument("b", type=click.Path(path_type=Path))
@click.option("--planar", is_flag=True, help="ground robots: estimate x, y, z and yaw only")
@click.option(
    "--min-fitness",
    type=click.FloatRange(0.0, 1.0),
    default=MIN_FITNESS,
    help="refuse an alignment with fewer matching voxels than this fraction",
)
@click.option(
    "--max-conflict",
    type=click.FloatRange(0.0, 1.0),
    default=MAX_CONFLICT,
    help="refuse an alignment that puts more of B's occupied voxels than this fraction "
    "where A saw free space",
)
@click.option("--json", "as_json", is_flag=True, help="print one JSON object")
def align(a, b, planar, min_fitness, max_conflict, as_json):
    """Estimate the rigid transform that takes map B's frame into map A's (occupied voxels)."""
    import json

    from ..maps.occupancy import OccupancyMap
    from ..maps.registration import register

    r = register(
        OccupancyMap.load(a),
        OccupancyMap.load(b),
        planar=planar,
        min_fitness=min_fitness,
        max_conflict=max_conflict,
    )
    d = r.as_dict()
    if as_json:
        click.echo(json.dumps(d))
    else:
        say(
            f"B -> A: x {d['x']:.4f} m, y {d['y']:.4f} m, z {d['z']:.4f} m, roll {d['roll']:.5f}, "
            f"pitch {d['pitch']:.5f}, yaw {d['yaw']:.5f} rad; fitness {d['fitness']:.3f}, "
            f"conflict {d['conflict']:.3f}"
        )
