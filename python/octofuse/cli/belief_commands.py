"""Commands on target beliefs: ``search`` (Gaussian mixtures, paper 000) and ``track``
(range-only tracking, paper 004)."""

from __future__ import annotations

from pathlib import Path

import click

from .options import ListOption, NameList, cli, console, flat, say

#: the belief types ``track`` compares
FAMILIES = ("expoly", "gaussian", "mixture")


def _mixture_rules() -> tuple[str, ...]:
    from ..beliefs.mixture_fusion import MIXTURE_RULES

    return MIXTURE_RULES


@cli.command()
@click.option(
    "--setting",
    type=click.Choice(["3-robots", "8-robots"]),
    default="3-robots",
    help="the paper's cyclic 3-robot pattern, or 8 robots on max-robust:3",
)
@click.option(
    "--rule",
    "--rules",
    "rule",
    multiple=True,
    cls=ListOption,
    type=NameList(_mixture_rules, what="RULE"),
    help="mixture fusion rules, comma separated",
    show_default="naive-bayes,bhattacharyya,chernoff,kld-weighted-chernoff,min-info-loss",
)
@click.option(
    "--seed", type=int, default=0, help="seed of the target, the detections and the sampling"
)
@click.option("--duration", type=click.IntRange(1, 3600), default=65, help="seconds of search")
@click.option(
    "--out", type=click.Path(file_okay=False, path_type=Path), required=True, help="output folder"
)
def search(setting, rule, seed, duration, out):
    """Multi-robot target search with Gaussian-mixture beliefs (paper 000): report and figures."""
    from ..outputs.tables import search_table
    from ..targets.search import DEFAULT_RULES
    from ..targets.search_report import run_target_search

    rules = flat(rule) or list(DEFAULT_RULES)
    res = run_target_search(
        out, setting=setting, rules=rules, seed=seed, duration=duration, progress=say
    )
    console().print(search_table(res))
    say(f"report: {out / 'report.md'}")


@cli.command()
@click.option("--duration", type=click.FloatRange(0.2, 600), default=10.0, help="seconds tracked")
@click.option("--seed", type=int, default=0, help="seed of the range noise")
@click.option(
    "--families",
    cls=ListOption,
    type=NameList(lambda: FAMILIES, what="FAMILY"),
    default=",".join(FAMILIES),
    help="belief types, comma separated",
)
@click.option(
    "--out", type=click.Path(file_okay=False, path_type=Path), required=True, help="output folder"
)
def track(duration, seed, families, out):
    """Range-only tracking over a directed ring of four nodes (paper 004): report and figures."""
    from ..outputs.tables import tracking_table
    from ..targets.tracking_report import run_tracking

    result = run_tracking(out, duration=duration, seed=seed, families=families)
    console().print(tracking_table(result.summary))
    say(f"report: {out / 'report.md'}")
