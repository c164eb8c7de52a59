"""The tables the commands print: whole rule names on an 80-column terminal."""

import io
from types import SimpleNamespace

import pytest
from rich.console import Console

from octofuse.outputs.tables import broken_at_hyphens, scores_table

RULES = [
    "local-only",
    "naive-bayes",
    "bhattacharyya",
    "min-info-loss",
    "kld-weighted-chernoff",
    "entropy-weighted-chernoff",
    "channel-filter",
]


def result(rules):
    """A result with every score of every rule (one agent), as ``scores_table`` reads it."""
    score = SimpleNamespace(
        kl_mean=0.0377,
        overconfidence=0.018,
        agreement=1.0,
        coverage=0.916,
        loss_mean=0.371,
        loss_p95=0.915,
        occupied_accuracy=None,
        bytes_sent=None,
        bytes_sent_32b=None,
    )
    return SimpleNamespace(scores={r: {"robot1": score} for r in rules})


def printed(table, width: int) -> str:
    console = Console(width=width, record=True, file=io.StringIO())
    console.print(table)
    return console.export_text()


@pytest.mark.parametrize("width", [80, 120])
def test_scores_table_shows_every_rule_name_whole(width):
    text = printed(scores_table(result(RULES), "octofuse run", width=width), width)
    assert "…" not in text
    assert max(len(line) for line in text.splitlines()) <= width
    cells = [line.split("│")[1].strip() for line in text.splitlines() if line.startswith("│")]
    names, current = [], ""
    for cell in cells:  # a name broken at its hyphens continues on the next lines
        if cell and current and not current.endswith("-"):
            names.append(current)
            current = ""
        current += cell
    names.append(current)
    assert names == RULES
    assert text.count("100.0%") == len(RULES)


def test_a_wide_terminal_keeps_names_and_headers_on_one_line():
    text = printed(scores_table(result(RULES), "octofuse run", width=200), 200)
    assert "entropy-weighted-chernoff" in text and "KL(central‖agent)" in text


@pytest.mark.parametrize(
    "name, lines",
    [
        ("naive-bayes", ["naive-bayes"]),
        ("min-info-loss", ["min-info-loss"]),
        ("kld-weighted-chernoff", ["kld-weighted-", "chernoff"]),
        ("entropy-weighted-chernoff", ["entropy-", "weighted-", "chernoff"]),
        ("bhattacharyya", ["bhattacharyya"]),
    ],
)
def test_names_break_after_hyphens(name, lines):
    assert broken_at_hyphens(name).split("\n") == lines


def test_search_table_prints_each_schemes_figures_at_the_end():
    import numpy as np

    from octofuse.outputs.tables import search_table

    steps = {
        "chernoff": ([[9.0, 9.0, 9.0], [0.02, 0.04, 0.03]], [[0, 0, 0], [0.5, 0.1, 0.1]]),
        "naive-bayes": ([[9.0, 9.0, 9.0], [0.7, 1.1, 0.2]], [[0, 0, 0], [0.62, 0.9, 0.9]]),
    }
    res = SimpleNamespace(
        schemes=list(steps),
        kl_to_central={s: np.array(kl) for s, (kl, _) in steps.items()},
        info_gain={s: np.array(g) for s, (_, g) in steps.items()},
    )
    text = printed(search_table(res), 80)
    assert "robot 1 gain [nats]" in text
    rows = [line.split("│")[1:-1] for line in text.splitlines() if line.startswith("│")]
    assert [[c.strip() for c in r] for r in rows] == [
        ["chernoff", "0.030", "0.040", "0.500"],
        ["naive-bayes", "0.667", "1.100", "0.620"],
    ]


def test_tracking_table_prints_errors_fusions_and_message_sizes():
    from octofuse.outputs.tables import tracking_table

    summary = {
        "families": {
            "expoly": {"rms_error": 0.4812, "fusions": 28, "bytes_per_message": {"mean": 112.0}},
            "gaussian": {"rms_error": None, "fusions": 6, "bytes_per_message": {"mean": 40.0}},
        },
        "central": {"rms_error": 0.2861},
    }
    text = printed(tracking_table(summary), 80)
    assert "RMS error [m]" in text
    rows = [
        [c.strip() for c in line.split("│")[1:-1]]
        for line in text.splitlines()
        if line.startswith("│")
    ]
    assert rows == [
        ["expoly", "0.481", "28", "112"],
        ["gaussian", "–", "6", "40"],
        ["centralized grid", "0.286", "", ""],
    ]
