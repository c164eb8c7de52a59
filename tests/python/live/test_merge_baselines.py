"""The table of docs/fleets.md: today's live systems' merges beside octofuse's rules, as
benchmarks/merge_baselines.py measures it on the bundled lab."""

import pytest

from doc_figures import REPO, assert_as_printed, benchmark, quoted

ROWS = {
    "newest diff per source (marble_mapping)": r"newest diff per source \(marble_mapping\)",
    "replace by latest (RACER)": r"replace by latest \(RACER\)",
    "min-info-loss": "min-info-loss",
    "chernoff": "chernoff",
    "channel-filter": "channel-filter",
    "own map only": "own map only",
}


@pytest.mark.slow
def test_the_merges_table_is_what_the_benchmark_measures():
    rows, _ = benchmark("merge_baselines").measure(
        str(REPO / "data" / "lab8.bag"),
        4,
        ["min-info-loss", "chernoff", "channel-filter"],
        "max-robust:3",
        "aperiodic:20",
    )
    by = {r["merge"]: r for r in rows}
    assert by.keys() == ROWS.keys()
    for merge, label in ROWS.items():
        kl, over = quoted("docs/fleets.md", rf"\| {label} \| # \| #% \|")
        assert_as_printed(
            {"kl": by[merge]["kl_mean"], "over": 100 * by[merge]["overconfidence"]},
            {"kl": kl, "over": over},
            merge,
        )
    # the exact channel filter and the conservative rules beat replacing by the latest
    assert by["channel-filter"]["kl_mean"] < by["replace by latest (RACER)"]["kl_mean"]
    assert by["min-info-loss"]["kl_mean"] < by["newest diff per source (marble_mapping)"]["kl_mean"]
