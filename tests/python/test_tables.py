"""The tables the commands print: whole rule names on an 80-column terminal."""

import io
from types import SimpleNamespace

import pytest
from rich.console import Console

from octofuse.outputs.tables import broken_at_hyphens, scores_table

RULES = ["local-only", "naive-bayes", "bhattacharyya", "min-info-loss", "kld-weighted-chernoff",
         "entropy-weighted-chernoff", "channel-filter"]


def result(rules):
    """A result with every score of every rule (one agent), as ``scores_table`` reads it."""
    score = SimpleNamespace(kl_mean=0.0377, overconfidence=0.018, agreement=1.0, coverage=0.916,
                            loss_mean=0.371, loss_p95=0.915, occupied_accuracy=None,
                            bytes_sent=None, bytes_sent_32b=None)
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


@pytest.mark.parametrize("name, lines", [
    ("naive-bayes", ["naive-bayes"]),
    ("min-info-loss", ["min-info-loss"]),
    ("kld-weighted-chernoff", ["kld-weighted-", "chernoff"]),
    ("entropy-weighted-chernoff", ["entropy-", "weighted-", "chernoff"]),
    ("bhattacharyya", ["bhattacharyya"]),
])
def test_names_break_after_hyphens(name, lines):
    assert broken_at_hyphens(name).split("\n") == lines
