"""The README tells the truth: its Python code blocks (and those of the pages in docs/) run as
written on the bundled data, and its layout section names the folders the package has."""

import json
import os
import re
import subprocess
import sys

import numpy as np
import pytest

from doc_figures import REPO, assert_as_printed, quoted

README = (REPO / "README.md").read_text()


DOCS = sorted((REPO / "docs").glob("*.md"))


def python_blocks(text: str = README) -> list[str]:
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def every_python_block() -> list[str]:
    return python_blocks() + [b for page in DOCS for b in python_blocks(page.read_text())]


def test_the_readme_has_python_examples():
    assert len(python_blocks()) >= 2


#: prepended to an example: each print call's output ends with a separator line, so that the
#: output of the N-th print statement can be found
SEPARATED_PRINTS = (
    "import builtins\n"
    "def print(*args, **kwargs):\n"
    "    builtins.print(*args, **kwargs)\n"
    "    builtins.print('\\x1e')\n"
)


def promised_prints(block: str) -> list[tuple[int, str]]:
    """(index among the block's top-level print statements, its comment) of each commented one;
    comment lines below it continue the comment."""
    lines, found, index = block.splitlines(), [], -1
    for n, line in enumerate(lines):
        if not line.startswith("print("):
            continue
        index += 1
        if "#" in line:
            comment = [line.split("#", 1)[1].strip()]
            for more in lines[n + 1 :]:
                if not more.strip().startswith("#"):
                    break
                comment.append(more.strip()[1:].strip())
            found.append((index, " ".join(comment)))
    return found


def check_promise(printed: str, comment: str) -> None:
    """A comment "about 2.6" promises the printed number to its digits; a comment listing names
    ("a, b, c") promises those names, in that order."""
    about = re.fullmatch(r"about (\d+(?:\.\d+)?)\b.*", comment)
    if about:
        decimals = len(about[1].partition(".")[2])
        assert f"{float(printed):.{decimals}f}" == about[1], (printed, comment)
    elif re.fullmatch(r"[a-z-]+(, [a-z-]+)+", comment):
        assert re.findall(r"[a-z][a-z-]*", printed) == comment.split(", "), (printed, comment)


@pytest.mark.slow
@pytest.mark.parametrize("index", range(len(every_python_block())))
def test_each_python_block_runs_as_written(tmp_path, index):
    """Each example exits 0 in a folder of its own and prints what its comments say."""
    (tmp_path / "data").symlink_to(REPO / "data")
    script = tmp_path / "example.py"
    block = every_python_block()[index]
    script.write_text(SEPARATED_PRINTS + block)
    env = {**os.environ, "MPLBACKEND": "Agg"}
    done = subprocess.run(
        [sys.executable, str(script)],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    outputs = done.stdout.split("\x1e\n")
    for n, comment in promised_prints(block):
        check_promise(outputs[n].strip(), comment)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data", "example.py"]  # nothing left


def test_promises_are_read_from_the_examples():
    promises = [p for b in every_python_block() for p in promised_prints(b)]
    assert (1, RULES_COMMENT) in promises
    assert any(comment.startswith("about 2.6") for _, comment in promises)
    check_promise("2.5686", "about 2.6: smaller than either source")
    with pytest.raises(AssertionError):
        check_promise("2.66", "about 2.6")
    with pytest.raises(AssertionError):
        check_promise("('chernoff', 'naive-bayes')", "naive-bayes, chernoff")


RULES_COMMENT = (
    "naive-bayes, bhattacharyya, min-entropy, chernoff, entropy-weighted-chernoff, "
    "kld-weighted-chernoff, min-info-loss"
)


def test_the_layout_section_matches_the_package():
    layout = README.split("## Layout", 1)[1].split("\n## ", 1)[0]
    package = REPO / "python" / "octofuse"
    folders = sorted(p.name for p in package.iterdir() if p.is_dir() and p.name != "__pycache__")
    for name in folders:
        assert f"{name}/" in layout, f"the README's layout does not mention {name}/"
    for name in re.findall(r"python/octofuse/(\w+)/", layout):
        assert (package / name).is_dir(), f"the README names python/octofuse/{name}/, which is gone"


@pytest.mark.slow
def test_the_quicker_demo_gives_the_figures_the_docs_quote(tmp_path):
    """docs/demo.md's quicker demo (every 4th scan, three rules), run as the page writes it."""
    from octofuse.cli import main

    page = "docs/demo.md"
    (command,) = quoted(page, r"`octofuse demo (--every 4 --rules [a-z,-]+ --export none)`")
    assert main(["demo", *command.split(), "--out", str(tmp_path / "demo")]) == 0
    mean = json.loads((tmp_path / "demo" / "summary.json").read_text())["mean"]
    names = ["chernoff", "min-info-loss", "channel-filter", "local-only"]
    figures = dict(
        zip(
            names,
            quoted(
                page,
                r"KL\(central ‖ agent\) # for Chernoff, # for min-info-loss and # for the channel "
                r"filter, against # for the local-only maps",
            ),
        )
    )
    assert_as_printed({n: mean[n]["kl_mean"] for n in names}, figures, page)


#: the README's demo table: its columns and the summary's keys of the same scores
DEMO_COLUMNS = {
    "KL(central ‖ agent)": ("kl_mean", 1),
    "over-confident": ("overconfidence", 100),
    "class agreement": ("agreement", 100),
    "coverage": ("coverage", 100),
    "info loss mean": ("loss_mean", 1),
    "info loss p95": ("loss_p95", 1),
    "occupied on a true surface": ("occupied_accuracy", 100),
}


def readme_demo_table() -> dict[str, dict[str, str]]:
    """The README's demo table: cells by rule (the first word of the first cell) and column."""
    section = README.split("## What the demo shows")[1].splitlines()
    first = next(n for n, line in enumerate(section) if line.startswith("|"))
    lines = []
    for line in section[first:]:
        if not line.startswith("|"):
            break
        lines.append(line)
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    rows = {}
    for line in lines[2:]:
        cells = [c.strip() for c in line.strip("|").split("|")]
        rows[cells[0].split()[0]] = dict(zip(header[1:], cells[1:]))
    return rows


@pytest.mark.slow
def test_the_demo_gives_the_readme_table(tmp_path):
    """Four rows of the README's demo table, from a demo of three rules alone: a rule's maps are
    its own, so its scores are those of the whole demo (local-only comes with every run); and
    docs/demo.md's memory and traffic figures of those rules."""
    from octofuse.cli import main

    rules = ["naive-bayes", "min-info-loss", "source-layers"]
    args = ["demo", "--rules", ",".join(rules), "--export", "none", "--out", str(tmp_path / "d")]
    assert main(args) == 0
    summary = json.loads((tmp_path / "d" / "summary.json").read_text())
    mean = summary["mean"]
    table = readme_demo_table()
    assert list(table) == ["local-only", *octofuse_rules(), "channel-filter", "source-layers"]
    figures, measured = {}, {}
    for rule in ["local-only", *rules]:
        for column, (key, scale) in DEMO_COLUMNS.items():
            cell = table[rule][column].rstrip("%")
            if cell != "–":
                figures[f"{rule} {column}"] = cell
                measured[f"{rule} {column}"] = scale * mean[rule][key]
    assert len(figures) == 4 * 7 - 4  # local-only and source-layers have no loss columns
    assert_as_printed(measured, figures, "README.md")

    def megabytes(rule, part):
        return (
            np.mean([sum(m[p] for p in part) for m in summary["memory_bytes"][rule].values()]) / 1e6
        )

    page = "docs/demo.md"
    names = ["total", "map", "layers", "others low", "sent", "others sent low"]
    figures = dict(
        zip(
            names,
            quoted(
                page,
                r"The price is memory: # MB per robot \(# MB map, # MB of layers and of the changes "
                r"kept for deltas\) against \d+ MB for the channel filter and #-\d+ MB for naive "
                r"Bayes and the WEP rules; a robot sends # MB \(the others #-\d",
            ),
        )
    )
    figures["floor over"] = quoted(page, r"all scans summed and clamped once give #%")[0]
    figures["nb sent"] = quoted(page, r"a robot sends # MB \(naive-bayes")[0]
    layers = "source-layers"
    sent = {r: mean[r]["bytes_sent"] / 1e6 for r in rules}
    measured = {
        "total": megabytes(layers, ("map", "links")),
        "map": megabytes(layers, ("map",)),
        "layers": megabytes(layers, ("links",)),
        "others low": megabytes("naive-bayes", ("map",)),
        "sent": sent[layers],
        "others sent low": sent["naive-bayes"],
        "floor over": 100 * summary["exact"]["floor_overconfidence"],
        "nb sent": sent["naive-bayes"],
    }
    assert_as_printed(measured, figures, page)
    # docs/commands.md: the share of the accumulated loss the count of messages explains
    low, high = quoted("docs/commands.md", r"In the demo it explains #-#% for every WEP rule")
    share = re.search(r"`min-info-loss` (\d+)%", summary["loss_per_event_finding"]).group(1)
    assert int(low) <= int(share) <= int(high), (share, low, high)


def octofuse_rules() -> list[str]:
    import octofuse

    return list(octofuse.RULES)


@pytest.mark.slow
def test_message_loss_gives_the_figures_the_docs_quote(tmp_path):
    """docs/demo.md's run with 30% of the messages lost, run as the page writes it."""
    from octofuse.cli import main

    page = "docs/demo.md"
    (command,) = quoted(page, r"With 30% of the messages lost \(`octofuse (run [^`]+)`")
    assert main([*command.split(), "--out", str(tmp_path / "loss")]) == 0
    mean = json.loads((tmp_path / "loss" / "summary.json").read_text())["mean"]
    names = ["channel-filter", "min-info-loss", "chernoff", "naive-bayes over-confident"]
    figures = dict(
        zip(
            names,
            quoted(
                page,
                r"# for the channel filter \(its tree has no second path around a lost message\), "
                r"# for min-info-loss and # for Chernoff; naive Bayes stays over-confident on #% ",
            ),
        )
    )
    measured = {n: mean[n]["kl_mean"] for n in names[:3]}
    measured[names[3]] = 100 * mean["naive-bayes"]["overconfidence"]
    assert_as_printed(measured, figures, page)


def test_the_demo_findings_are_the_readme_table():
    """docs/demo.md's findings quote the demo's table in the README (which a test runs):
    each figure there is the table's cell, or a range, extreme or ratio of its cells."""
    table = readme_demo_table()

    def cell(rule, column):
        return float(table[rule][column].rstrip("%"))

    def over(rules, column):
        return [cell(r, column) for r in rules]

    wep = [r for r in octofuse_rules() if r != "naive-bayes"]
    chernoffs = [r for r in wep if "chernoff" in r or r == "bhattacharyya"]
    kl, p95, mean = "KL(central ‖ agent)", "info loss p95", "info loss mean"
    page = "docs/demo.md"
    figures, measured = {}, {}

    def check(names, pattern, values):
        figures.update(zip(names, quoted(page, pattern)))
        measured.update(zip(names, values))

    oc = over(wep, "over-confident")
    check(
        ["nb over", "wep over min", "wep over max"],
        r"Naive Bayes leaves #% of the voxels more certain than the centralized map \(by more "
        r"than 0\.1 in log-odds\), against # to #% for the WEP rules",
        [cell("naive-bayes", "over-confident"), min(oc), max(oc)],
    )
    check(
        ["nb kl", "wep kl min", "wep kl max"],
        r"over-confidence gap \(# against # to #\)",
        [cell("naive-bayes", kl), min(over(wep, kl)), max(over(wep, kl))],
    )
    check(
        ["wep kl low", "wep kl high", "local kl", "wep coverage", "local coverage"],
        r"\(KL # to # against #; coverage #% against #%\)",
        [
            min(over(wep, kl)),
            max(over(wep, kl)),
            cell("local-only", kl),
            min(over(wep, "coverage")),
            cell("local-only", "coverage"),
        ],
    )
    assert len({f"{c:.0f}" for c in over(wep, "coverage")}) == 1
    check(
        ["mil p95", "me p95"],
        r"min-info-loss is the lowest of the WEP rules \(#, min-entropy #\)",
        [cell("min-info-loss", p95), cell("min-entropy", p95)],
    )
    assert min(wep, key=lambda r: cell(r, p95)) == "min-info-loss"
    lower = ["bhattacharyya", "chernoff", "entropy-weighted-chernoff"]
    check(
        ["lower min", "lower max", "mil mean"],
        r"entropy-weighted Chernoff are lower \(# to # against #\)",
        [min(over(lower, mean)), max(over(lower, mean)), cell("min-info-loss", mean)],
    )
    assert max(over(lower, mean)) < cell("min-info-loss", mean)
    assert sorted(wep, key=lambda r: cell(r, kl))[1] == "min-info-loss"
    check(
        ["me kl", "mil kl", "cf kl", "family low", "family high"],
        r"min-entropy \(KL #\) and min-info-loss \(#\) do better than the exact filter on the "
        r"tree alone \(#\), because the 5 loop links carry information the tree does not; the "
        r"Chernoff family \(#-#\) does not",
        [
            cell("min-entropy", kl),
            cell("min-info-loss", kl),
            cell("channel-filter", kl),
            min(over(chernoffs, kl)),
            max(over(chernoffs, kl)),
        ],
    )
    links = quoted(page, r"spanning tree \(`--spanning-tree bfs\|given\|FILE`; # of the # links\)")
    assert links == quoted("README.md", r"on a spanning tree: # of # links")
    sl, me_times, me, cf_times, sl_over = quoted(
        page,
        r"KL #, # times below min-entropy \(#\) and # times below the channel filter \(its #% "
        r"over-confidence",
    )
    figures.update({"sl kl": sl, "me kl again": me, "sl over": sl_over})
    measured.update(
        {
            "sl kl": cell("source-layers", kl),
            "me kl again": cell("min-entropy", kl),
            "sl over": cell("source-layers", "over-confident"),
        }
    )
    assert_as_printed(measured, figures, page)
    for times, other in ((me_times, "min-entropy"), (cf_times, "channel-filter")):
        # the ratio of the unrounded values, within what the table's rounding allows
        a, b = table[other][kl], table["source-layers"][kl]
        half = 0.5 * 10 ** -len(a.split(".")[1])
        low, high = (float(a) - half) / (float(b) + half), (float(a) + half) / (float(b) - half)
        step = 0.5 * 10 ** -len(times.split(".")[1])
        assert float(times) + step >= low and float(times) - step <= high, (times, other)
