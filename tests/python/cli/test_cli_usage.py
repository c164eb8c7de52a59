"""The installed ``octofuse`` command: usage errors exit 2 with click's message, ``--version``
and ``--help``; output folders written all-or-nothing; a light ``import octofuse``."""

from __future__ import annotations

import importlib.metadata
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bagfactory as bf  # noqa: E402
from bagfactory import run_cli  # noqa: E402
from conftest import REPO  # noqa: E402
from octofuse.cli import cli  # noqa: E402
from octofuse.outputs.staging import MARKER  # noqa: E402

OCTOFUSE = Path(sys.executable).parent / "octofuse"
RES = "0.2"
ENV = {k: v for k, v in os.environ.items() if k not in ("FORCE_COLOR", "COLUMNS", "OCTOFUSE_DEBUG")}


def python_c(script: str, timeout: float = 120) -> subprocess.CompletedProcess:
    """``script`` run by a fresh Python (as a user's shell would start it), its output as text."""
    return subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=timeout, env=ENV
    )


def assert_interrupted(p: subprocess.CompletedProcess) -> None:
    """How an interrupted command ends: one line, exit code 130, no traceback."""
    assert (p.returncode, p.stderr) == (130, "error: interrupted\n")


def octofuse(*args, cwd=None) -> subprocess.CompletedProcess:
    """The installed console script, as a user runs it."""
    assert OCTOFUSE.is_file(), f"the octofuse command is not installed at {OCTOFUSE}"
    return subprocess.run(
        [str(OCTOFUSE), *map(str, args)],
        capture_output=True,
        text=True,
        timeout=120,
        env=ENV,
        cwd=cwd,
    )


# -- usage errors ---------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize(
    "args, usage, needle",
    [
        (["build", "--foo"], "octofuse build", "No such option '--foo'"),
        (["launch"], "octofuse", "No such command 'launch'"),
        (["fuse"], "octofuse fuse", "Missing argument 'MAPS_DIR'"),
        (["run", "--every", "two"], "octofuse run", "Invalid value for '--every': 'two'"),
        (["build", "x.bag", "--every", "0"], "octofuse build", "Invalid value for '--every': 0"),
        (["fuse", "x", "--rounds", "-1"], "octofuse fuse", "Invalid value for '--rounds': -1"),
        (
            ["run", "x.bag", "--directions", "sideways"],
            "octofuse run",
            "Invalid value for '--directions': 'sideways'",
        ),
        ([], "octofuse", "Commands:"),
    ],
    ids=[
        "unknown_option",
        "unknown_command",
        "missing_argument",
        "every_not_a_number",
        "every_zero",
        "negative_rounds",
        "bad_choice",
        "bare",
    ],
)
def test_usage_errors_exit_2_with_clicks_message(tmp_path, args, usage, needle):
    p = octofuse(*args, cwd=tmp_path)
    assert p.returncode == 2, (p.stdout, p.stderr)
    assert "Traceback" not in p.stderr and "Traceback" not in p.stdout
    assert p.stderr.startswith(f"Usage: {usage} [OPTIONS]"), p.stderr
    assert needle in p.stderr, p.stderr
    if args:  # an error, not the help: one "Error:" line and a pointer to --help
        assert f"Try '{usage} --help' for help." in p.stderr
        assert [line for line in p.stderr.splitlines() if line.startswith("Error: ")] != []
    assert p.stdout == ""
    assert list(tmp_path.iterdir()) == []  # nothing written


@pytest.mark.slow
def test_version():
    p = octofuse("--version")
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == f"octofuse, version {importlib.metadata.version('octofuse')}"
    assert p.stderr == ""
    p = octofuse("run", "--help")
    assert p.returncode == 0 and p.stderr == "" and p.stdout.startswith("Usage: octofuse run ")
    assert "[default: (max-robust:3)]" in p.stdout


@pytest.mark.slow
def test_bad_input_exits_1_with_one_line(tmp_path):
    p = octofuse("build", tmp_path / "nothere.bag", "--out", tmp_path / "o")
    assert p.returncode == 1
    assert p.stderr.strip() == f"error: bag '{tmp_path / 'nothere.bag'}' does not exist"
    assert not (tmp_path / "o").exists()


#: command -> defaults its --help must show
HELP_DEFAULTS = {
    "build": ["map", "0.05", "skip", "no limit"],
    "run": ["min-info-loss", "max-robust:3", "aperiodic:10", "both", "copy", "12"],
    "bench": ["ring,max-robust:3", "aperiodic:10", "0.05"],
    "fuse": ["3", "both", "copy", "max-robust:3"],
    "demo": ["octofuse-demo", "all,channel-filter,source-layers"],
    "search": ["3-robots", "0", "65"],
    "track": ["10.0", "0", "expoly,gaussian,mixture"],
    "export": ["viridis for maps, inferno for heat maps"],
    "fuse-maps": ["min-info-loss", "copy", "the coarsest input's"],
    "align": ["0.5"],
    "info": [],
    "fleet": ["min-info-loss", "aperiodic:10", "1", "7447", "all"],
    "agent": ["60.0"],
    "view": ["127.0.0.1", "8080", "300000"],
}


def test_every_command_has_help_defaults():
    assert sorted(cli.commands) == sorted(HELP_DEFAULTS)


@pytest.mark.parametrize("command", list(HELP_DEFAULTS))
def test_help_of_each_command_shows_its_defaults(capsys, command):
    code, out, err = run_cli(capsys, command, "--help")
    assert code == 0, err
    assert out.startswith(f"Usage: octofuse {command} ")
    text = " ".join(re.sub(r"-\n\s+", "-", out).split())  # help is wrapped to the terminal
    shown = re.findall(r"\[default: \(?([^)\];]*)\)?[;\]]", text)
    for value in HELP_DEFAULTS[command]:
        assert value in shown, (value, shown)
    code, short, _ = run_cli(capsys, command, "-h")
    assert code == 0 and short == out


# -- --out: all or nothing ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    robots = bf.team(2)
    rec = bf.robot_recording(robots, bf.team_times(robots, 4))
    return rec.write(tmp_path_factory.mktemp("bag") / "pair", "mcap")


def snapshot(folder: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }


def no_leftovers(parent: Path, keep: set[str]) -> bool:
    """Only ``keep`` in ``parent``: no staging or old folders of octofuse stayed behind."""
    return {p.name for p in parent.iterdir()} == keep


def build(capsys, bag, out, *extra):
    return run_cli(capsys, "build", bag, "--resolution", RES, *extra, "--out", out)


def test_a_rerun_replaces_its_own_folder_whole(bag, tmp_path, capsys):
    out = tmp_path / "maps"
    code, _, err = build(capsys, bag, out)
    assert code == 0, err
    assert sorted(snapshot(out)) == [MARKER, "a.ot", "b.ot", "centralized.ot"]
    assert (out / MARKER).read_text() == "written by octofuse build\n"
    (out / "stale.txt").write_text("from an earlier run")
    (out / "old").mkdir()
    (out / "old" / "x.ot").write_bytes(b"x")
    first = (out / "a.ot").read_bytes()
    code, _, err = build(capsys, bag, out, "--every", "2")
    assert code == 0, err
    assert sorted(snapshot(out)) == [MARKER, "a.ot", "b.ot", "centralized.ot"]
    assert (out / "a.ot").read_bytes() != first  # half the scans: the new maps
    assert no_leftovers(tmp_path, {"maps"})


def test_an_empty_folder_is_used(bag, tmp_path, capsys):
    out = tmp_path / "empty"
    out.mkdir()
    code, _, err = build(capsys, bag, out)
    assert code == 0, err
    assert sorted(snapshot(out)) == [MARKER, "a.ot", "b.ot", "centralized.ot"]


@pytest.mark.parametrize("command", ["build", "run", "bench", "fuse"])
def test_a_folder_octofuse_did_not_write_is_refused(bag, tmp_path, capsys, command):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "thesis.tex").write_text("months of work")
    (out / "data").mkdir()
    (out / "data" / "a.ot").write_bytes(b"not octofuse's")
    before = snapshot(out)
    if command == "fuse":  # a folder of maps to fuse
        assert build(capsys, bag, tmp_path / "maps")[0] == 0
    args = {
        "build": [bag, "--resolution", RES],
        "run": [bag, "--resolution", RES, "--topology", "line", "--schedule", "periodic:1"],
        "bench": [
            bag,
            "--resolution",
            RES,
            "--topologies",
            "line",
            "--schedule",
            "periodic:1",
            "--executor",
            "serial",
        ],
        "fuse": [tmp_path / "maps", "--topology", "line"],
    }[command]
    code, text, err = run_cli(capsys, command, *args, "--out", out)
    assert code == 1, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err
    assert lines[0] == (
        f"error: --out '{out}' is a folder that octofuse did not write; refusing "
        "to replace it (give a new or empty folder)"
    )
    assert snapshot(out) == before
    assert "wrote" not in text and "done in" not in text


def test_a_file_as_out_is_refused(bag, tmp_path, capsys):
    out = tmp_path / "notes.txt"
    out.write_text("keep")
    code, _, err = build(capsys, bag, out)
    assert code == 2 and "Invalid value for '--out'" in err and "is a file" in err
    assert out.read_text() == "keep"


@pytest.fixture
def previous(bag, tmp_path, capsys):
    """A run's outputs and a build's maps, written by octofuse: what failures must keep."""
    run_out, maps = tmp_path / "run", tmp_path / "maps"
    code, _, err = run_cli(
        capsys,
        "run",
        bag,
        "--rules",
        "chernoff",
        "--topology",
        "line",
        "--schedule",
        "periodic:1",
        "--resolution",
        RES,
        "--samples",
        "0",
        "--out",
        run_out,
    )
    assert code == 0, err
    assert build(capsys, bag, maps)[0] == 0
    return {
        "run": run_out,
        "maps": maps,
        "before": {"run": snapshot(run_out), "maps": snapshot(maps)},
    }


def failing_commands(bag, tmp, previous):
    """(args, exit code, error text) of commands that fail after --out is known."""
    run, maps = previous["run"], previous["maps"]
    line = ["--schedule", "periodic:1", "--resolution", RES]
    return [
        (["build", tmp / "nothere.bag", "--out", maps], 1, "does not exist"),
        (["build", bag, "--fixed-frame", "world", "--out", maps], 1, "fixed frame 'world'"),
        (["run", bag, "--topology", "hexagon", *line, "--out", run], 1, "unknown topology"),
        (["run", bag, "--topology", "max-robust:3", *line, "--out", run], 1, "K=3 with n=2"),
        (
            ["run", bag, "--topology", "line", "--export-agents", "z", *line, "--out", run],
            1,
            "unknown agent(s) z",
        ),
        (
            ["bench", bag, "--topologies", "line,hexagon", *line, "--out", run],
            1,
            "unknown topology",
        ),
        (["fuse", maps, "--topology", "max-robust:3", "--out", run], 1, "K=3 with n=2"),
        (["run", bag, "--every", "0", "--out", run], 2, "Invalid value for '--every'"),
    ]


def test_a_failing_command_leaves_the_previous_outputs_byte_identical(
    bag, tmp_path, capsys, previous
):
    for args, want, needle in failing_commands(bag, tmp_path, previous):
        code, text, err = run_cli(capsys, *args)
        assert code == want, (args, err)
        assert needle in err and "Traceback" not in err, (args, err)
        for name in ("run", "maps"):
            assert snapshot(previous[name]) == previous["before"][name], (args, name)
        assert no_leftovers(tmp_path, {"run", "maps"}), (args, sorted(os.listdir(tmp_path)))


def test_an_interrupted_write_leaves_the_previous_outputs(
    bag, tmp_path, capsys, previous, monkeypatch
):
    import octofuse.outputs.report

    def interrupted(res, out, *args, **kw):
        (Path(out) / "report.md").write_text("half")
        raise KeyboardInterrupt

    monkeypatch.setattr(octofuse.outputs.report, "write_outputs", interrupted)
    code, _, err = run_cli(
        capsys,
        "run",
        bag,
        "--rules",
        "chernoff",
        "--topology",
        "line",
        "--schedule",
        "periodic:1",
        "--resolution",
        RES,
        "--samples",
        "0",
        "--out",
        previous["run"],
    )
    assert code == 130 and err.strip() == "error: interrupted"
    assert snapshot(previous["run"]) == previous["before"]["run"]
    assert no_leftovers(tmp_path, {"run", "maps"})


@pytest.fixture
def ctrl_c(monkeypatch):
    """``ctrl_c()`` does what the ``octofuse`` program's handler does on a Ctrl-C (the state
    of octofuse.interrupts is restored afterwards)."""
    import signal

    from octofuse import interrupts

    monkeypatch.setattr(interrupts, "_interrupted", False)
    monkeypatch.setattr(interrupts, "_outputs_in_place", False)
    monkeypatch.setattr(sys, "unraisablehook", sys.unraisablehook)
    return lambda frame=None: interrupts._on_sigint(signal.SIGINT, frame)


def test_an_error_after_a_ctrl_c_is_the_interruption(
    bag, tmp_path, capsys, previous, monkeypatch, ctrl_c
):
    """A library that turns the KeyboardInterrupt into an error of its own (Matplotlib's
    compiled code: "Invalid bounding box") ends the command as interrupted."""
    import octofuse.outputs.report

    def interrupted_in_a_library(res, out, *args, **kw):
        (Path(out) / "report.md").write_text("half")
        try:
            ctrl_c()
        except KeyboardInterrupt:
            raise ValueError("Invalid bounding box") from None

    monkeypatch.setattr(octofuse.outputs.report, "write_outputs", interrupted_in_a_library)
    code, _, err = run_cli(
        capsys,
        "run",
        bag,
        "--rules",
        "chernoff",
        "--topology",
        "line",
        "--schedule",
        "periodic:1",
        "--resolution",
        RES,
        "--samples",
        "0",
        "--out",
        previous["run"],
    )
    assert (code, err.strip()) == (130, "error: interrupted")
    assert snapshot(previous["run"]) == previous["before"]["run"]
    assert no_leftovers(tmp_path, {"run", "maps"})


def test_a_ctrl_c_once_the_outputs_are_in_place_ends_nothing(
    bag, tmp_path, capsys, previous, monkeypatch, ctrl_c
):
    """The command is done once its outputs replaced the old ones: a Ctrl-C as it prints its
    table neither ends it with 130 (which says the old outputs were kept) nor cuts it short."""
    import octofuse.outputs.tables

    table = octofuse.outputs.tables.scores_table

    def interrupted_table(*args, **kw):
        ctrl_c()
        return table(*args, **kw)

    monkeypatch.setattr(octofuse.outputs.tables, "scores_table", interrupted_table)
    code, text, err = run_cli(
        capsys,
        "run",
        bag,
        "--rules",
        "naive-bayes",
        "--topology",
        "line",
        "--schedule",
        "periodic:1",
        "--resolution",
        RES,
        "--samples",
        "0",
        "--out",
        previous["run"],
    )
    assert code == 0 and err == "", err
    assert "naive-bayes" in text and "report:" in text
    assert snapshot(previous["run"]) != previous["before"]["run"]
    assert (previous["run"] / MARKER).read_text() == "written by octofuse run\n"


def test_a_ctrl_c_in_the_import_systems_bookkeeping_is_only_remembered(ctrl_c):
    """Raised in importlib's own code (a module lock's callback between taking and releasing
    the import lock), a KeyboardInterrupt could leave the import lock held and the exit
    waiting forever for the imports thread: there it is remembered, and raised at the next
    check."""
    from octofuse import interrupts

    frames = []

    class Spy:  # a finder: importlib's own frame calls it
        def find_spec(self, name, path=None, target=None):
            if name == "octofuse_no_such_module":
                frames.append(sys._getframe(1))

    sys.meta_path.insert(0, Spy())
    try:
        with pytest.raises(ModuleNotFoundError):
            __import__("octofuse_no_such_module")
    finally:
        sys.meta_path.pop(0)
    assert frames[0].f_code.co_filename.startswith("<frozen importlib")

    def only_remembered(frame):
        try:
            ctrl_c(frame)
        except KeyboardInterrupt:
            pytest.fail("raised")

    only_remembered(frames[0])
    assert interrupts.cut_short()
    with pytest.raises(KeyboardInterrupt):
        interrupts.raise_if_interrupted()
    with pytest.raises(KeyboardInterrupt):
        ctrl_c(sys._getframe())  # anywhere else: raised at once
    with interrupts.held():
        only_remembered(sys._getframe())


def test_each_command_marks_its_folder(bag, tmp_path, capsys, previous):
    assert (previous["run"] / MARKER).read_text() == "written by octofuse run\n"
    out = tmp_path / "fused"
    code, _, err = run_cli(
        capsys, "fuse", previous["maps"], "--topology", "line", "--rounds", "1", "--out", out
    )
    assert code == 0, err
    assert (out / MARKER).read_text() == "written by octofuse fuse\n"
    # a run's folder may be replaced by another command's outputs: octofuse wrote it
    code, _, err = run_cli(
        capsys,
        "bench",
        bag,
        "--rules",
        "chernoff",
        "--topologies",
        "line",
        "--schedule",
        "periodic:1",
        "--resolution",
        RES,
        "--every",
        "2",
        "--executor",
        "serial",
        "--out",
        previous["run"],
    )
    assert code == 0, err
    assert (previous["run"] / MARKER).read_text() == "written by octofuse bench\n"
    assert not (previous["run"] / "report.md").exists()
    assert (previous["run"] / "bench.csv").is_file()


# -- a light import -------------------------------------------------------------------------------


@pytest.mark.slow
def test_import_octofuse_loads_no_heavy_module():
    heavy = ["rosbags", "open3d", "matplotlib", "click"]
    code = (
        "import sys, octofuse, octofuse.config\n"
        "assert octofuse.OccupancyMap and octofuse.RULES\n"
        f"print(sorted(m for m in {heavy!r} if m in sys.modules))\n"
        "octofuse.simulate\n"  # a lazy name: loads the pipeline
        f"print(sorted(m for m in {heavy!r} if m in sys.modules))\n"
    )
    p = python_c(code)
    assert p.returncode == 0, p.stderr
    light, after = p.stdout.splitlines()
    assert light == "[]"
    assert after == "['rosbags']"  # the check above can see a module that was imported
    # nothing but the package itself: the program can catch an interruption while it imports
    p = python_c(
        "import sys, octofuse.program\n"
        "print(sorted(m for m in sys.modules if m.startswith(('octofuse.', 'numpy'))))"
    )
    assert p.stdout.strip() == "['octofuse.program']", p.stdout + p.stderr


@pytest.mark.slow
def test_a_ctrl_c_while_the_command_line_is_imported_is_one_line():
    """An interruption while the program imports the command line (a quarter of a second)
    ends as one while the command runs: one line, exit code 130, no traceback."""
    script = (
        "import sys, octofuse.program\n"
        "class Interrupt:  # Ctrl-C as the command line is imported\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name == 'octofuse.cli':\n"
        "            raise KeyboardInterrupt\n"
        "sys.meta_path.insert(0, Interrupt())\n"
        "octofuse.program.run()\n"
    )
    assert_interrupted(python_c(script))


@pytest.mark.slow
def test_python_m_octofuse_is_the_program():
    """``python -m octofuse`` runs the program: its usage, and a Ctrl-C while it imports the
    command line ends as the program's does."""
    p = subprocess.run(
        [sys.executable, "-m", "octofuse", "--help"],
        capture_output=True,
        text=True,
        timeout=120,
        env=ENV,
    )
    assert p.returncode == 0 and "Usage: octofuse" in p.stdout, p.stdout + p.stderr
    script = (
        "import runpy, sys\n"
        "class Interrupt:  # Ctrl-C as the command line is imported\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name == 'octofuse.cli':\n"
        "            raise KeyboardInterrupt\n"
        "sys.meta_path.insert(0, Interrupt())\n"
        "runpy.run_module('octofuse', run_name='__main__')\n"
    )
    assert_interrupted(python_c(script))


@pytest.mark.slow
def test_a_ctrl_c_swallowed_on_its_way_still_interrupts(tmp_path):
    """A Ctrl-C whose KeyboardInterrupt is swallowed where it lands (numpy's compiled modules,
    imported on first use, do so in their initialisation) still ends the command: one line,
    exit code 130, the previous outputs as they were."""
    lab8 = REPO / "data" / "lab8.bag"
    out = tmp_path / "out"
    out.mkdir()
    (out / MARKER).write_text("written by octofuse run\n")  # an earlier run's outputs
    (out / "previous.txt").write_text("kept")
    script = (
        "import os, signal, sys, time, octofuse.program\n"
        "class Swallow:  # Ctrl-C while a module is imported, swallowed there\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name == 'octofuse.fusion.simulate':\n"
        "            try:\n"
        "                os.kill(os.getpid(), signal.SIGINT)\n"
        "                time.sleep(5)\n"
        "            except KeyboardInterrupt:\n"
        "                pass\n"
        "sys.meta_path.insert(0, Swallow())\n"
        f"sys.argv = ['octofuse', 'run', {str(lab8)!r}, '--rule', 'naive-bayes', "
        f"'--topology', 'ring', '--every', '50', '--samples', '2', '--out', {str(out)!r}]\n"
        "octofuse.program.run()\n"
    )
    assert_interrupted(python_c(script, timeout=300))
    assert sorted(p.name for p in out.iterdir()) == sorted([MARKER, "previous.txt"])


@pytest.mark.slow
@pytest.mark.parametrize("where", ["half-built", "callback"])
def test_what_a_ctrl_c_leaves_half_done_prints_nothing(where):
    """A Ctrl-C landing in an object's construction (Matplotlib's parser grammar as the output
    libraries are imported) or in a weak-reference callback leaves the object to complain as
    it is freed ("Exception ignored in ..."): once interrupted, the run ends with its one
    line."""
    script = (
        "import os, signal, sys, time, weakref\n"
        "from octofuse.interrupts import interrupted, remember_interrupts\n"
        "remember_interrupts()\n"
        "def ctrl_c():\n"
        "    os.kill(os.getpid(), signal.SIGINT)\n"
        "    time.sleep(5)\n"
        "class Half:\n"
        "    def __init__(self):\n"
        "        ctrl_c()\n"
        "        self.expr = None\n"
        "    def __del__(self):\n"
        "        self.expr  # AttributeError: never set\n"
        "class Target:\n"
        "    pass\n"
        "try:\n"
        f"    if {where!r} == 'half-built':\n"
        "        Half()\n"
        "    else:\n"
        "        t = Target()\n"
        "        r = weakref.ref(t, lambda _: ctrl_c())\n"
        "        del t  # the KeyboardInterrupt is raised in the callback, and swallowed\n"
        "except KeyboardInterrupt:\n"
        "    pass\n"
        "if interrupted():\n"
        "    sys.stderr.write('error: interrupted\\n')\n"
        "    sys.exit(130)\n"
    )
    assert_interrupted(python_c(script))


@pytest.mark.slow
@pytest.mark.parametrize("code", [0, 130])
def test_a_ctrl_c_during_the_exit_leaves_the_exit_code(code):
    """Once the command is over (done, or interrupted and reported), a Ctrl-C while the
    interpreter exits is ignored: no traceback, no death by signal, the command's code."""
    script = (
        "import atexit, os, signal\n"
        "import octofuse.cli as c\n"
        f"c.main = lambda: {code}\n"
        "atexit.register(lambda: os.kill(os.getpid(), signal.SIGINT))\n"
        "c.entry()\n"
    )
    out = python_c(script)
    assert (out.returncode, out.stderr) == (code, "")
    installed = OCTOFUSE.read_text()
    assert "from octofuse.program import run" in installed, installed


@pytest.mark.parametrize(
    "args, message",
    [
        (["run", "x.bag", "--rule", "chernoff,,min-info-loss"], "has an empty item"),
        (["run", "x.bag", "--rule", "chernoff,bogus"], "unknown 'bogus'; expected one or more of"),
        (["run", "x.bag", "--export-agents", ","], "',' has an empty item"),
        (["bench", "x.bag", "--topologies", "ring,ring"], "names 'ring' twice"),
        (["bench", "x.bag", "--seeds", ","], "has an empty item"),
        (["bench", "x.bag", "--seeds", "1,x"], "expected SEED[,SEED...]"),
        (["bench", "x.bag", "--schedules", ""], "'' has an empty item"),
        (["search", "--rules", "", "--out", "o"], "'' has an empty item"),
        (["track", "--families", "expoly,foo", "--out", "o"], "unknown 'foo'"),
    ],
)
def test_list_values_are_refused_with_an_empty_item_a_repeat_or_a_stranger(
    capsys, tmp_path, monkeypatch, args, message
):
    monkeypatch.chdir(tmp_path)
    code, _, err = run_cli(capsys, *args)
    assert code == 2 and message in err
    assert list(tmp_path.iterdir()) == []  # nothing written


def test_rule_help_lists_the_rules():
    from click.testing import CliRunner

    text = CliRunner().invoke(cli, ["run", "--help"], terminal_width=200).output
    assert (
        "one or more of: naive-bayes, bhattacharyya" in text
        and "channel-filter, source-layers]" in text
    )
