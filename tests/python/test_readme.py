"""The README tells the truth: its Python code blocks (and those of the pages in docs/) run as
written on the bundled data, and its layout section names the folders the package has."""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from doc_figures import assert_as_printed, quoted

REPO = Path(__file__).resolve().parents[2]
README = (REPO / "README.md").read_text()


DOCS = sorted((REPO / "docs").glob("*.md"))


def python_blocks(text: str = README) -> list[str]:
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def every_python_block() -> list[str]:
    return python_blocks() + [b for page in DOCS for b in python_blocks(page.read_text())]


def test_the_readme_has_python_examples():
    assert len(python_blocks()) >= 2


@pytest.mark.slow
@pytest.mark.parametrize("index", range(len(every_python_block())))
def test_each_python_block_runs_as_written(tmp_path, index):
    (tmp_path / "data").symlink_to(REPO / "data")
    script = tmp_path / "example.py"
    script.write_text(every_python_block()[index])
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
