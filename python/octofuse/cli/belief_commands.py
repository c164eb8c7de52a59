"""Commands on target beliefs: ``search`` (Gaussian mixtures, paper 000) and ``track``
(range-only tracking, paper 004)."""

from __future__ import annotations

from pathlib import Path

import click

from .options import cli, say


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
    from ..targets.search import DEFAULT_RULES
    from ..targets.search_report import run_target_search

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
    from ..targets.tracking_report import run_tracking

    names = tuple(f.strip() for f in families.split(",") if f.strip())
    run_tracking(out, duration=duration, seed=seed, families=names)
    say(f"report: {out / 'report.md'}")
