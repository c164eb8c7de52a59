"""Hostile inputs through the installed ``octofuse`` command: never a crash, hang or lie.

Every case runs the command in a child process under a time and memory limit and checks the
outcome: a clean error is a non-zero exit (no signal) with exactly one line on stderr and no
traceback; an earlier output folder given as ``--out`` is byte-identical afterwards. The
generators below are shared with ``benchmarks/fuzz_campaign.py``, which draws many more
seeded cases from them.
"""

from __future__ import annotations

import hashlib
import math
import os
import resource
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bagfactory as bf  # noqa: E402
from bagfactory import PC2, SCAN, T0, TF, Recording, Robot, S  # noqa: E402
from conftest import REPO, map_with_values  # noqa: E402,F401  (also for the campaign)

pytestmark = pytest.mark.slow

OCTOFUSE = Path(sys.executable).parent / "octofuse"
MEMORY_LIMIT = 3 << 30  #: address space of a child, bytes
TIME_LIMIT = 60.0  #: seconds per child

# -- running one case ---------------------------------------------------------------------


@dataclass
class Case:
    """One hostile input: the command line and what a correct octofuse does with it."""

    name: str
    argv: list[str]
    expect: str = "error"  #: "error": a clean error; "any": success or a clean error
    out: Path | None = None  #: an earlier output folder that must stay unchanged
    fsize: int | None = None  #: file size limit (bytes): a full disk
    sigint_after: float | None = None  #: SIGINT this many seconds after the command started
    stop_signal: int = signal.SIGINT  #: the signal sigint_after sends (SIGINT or SIGTERM)
    exit_code: int | None = None  #: the exit code a clean error must have (any non-zero if None)
    python: bool = False  #: argv is a Python script run by the interpreter (API cases)
    timeout: float = TIME_LIMIT


@dataclass
class Outcome:
    #: ok, clean (one line, non-zero exit), usage (exit 2, click's usage block ending in one
    #: "Error:" line), traceback, signal, hang, messy (not one line), changed (earlier outputs),
    #: wrong-exit, internal (exit 70)
    kind: str
    returncode: int | None
    stderr: str
    seconds: float
    notes: list[str] = field(default_factory=list)


def tree_hash(folder: Path | None) -> str | None:
    """Hash of every file name and content under ``folder`` (None if it does not exist)."""
    if folder is None or not folder.exists():
        return None
    h = hashlib.sha256()
    for p in sorted(folder.rglob("*")):
        if p.is_file():
            h.update(str(p.relative_to(folder)).encode() + b"\0" + p.read_bytes())
    return h.hexdigest()


def _limits(fsize: int | None) -> Callable[[], None]:
    def apply() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))
        resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
        os.setsid()
        # as a user's shell would start it: a suite started in the background inherits an
        # ignored SIGINT, and Python then installs no KeyboardInterrupt for it
        signal.signal(signal.SIGINT, signal.SIG_DFL)

    return apply


def _started(pid: int, marker: str) -> bool:
    """Whether the child has opened a file whose path contains ``marker`` (it is past imports)."""
    try:
        return any(
            marker in os.readlink(f"/proc/{pid}/fd/{fd}") for fd in os.listdir(f"/proc/{pid}/fd")
        )
    except OSError:
        return False


def run_case(case: Case, cwd: Path) -> Outcome:
    if case.python:
        cmd = [sys.executable, "-c", case.argv[0]]
    else:
        cmd = [str(OCTOFUSE), *case.argv]
    if case.fsize is not None:
        cmd = ["prlimit", f"--fsize={case.fsize}", *cmd]
    before = tree_hash(case.out)
    env = {**os.environ, "COLUMNS": "200", "OMP_NUM_THREADS": "1", "PYTHONWARNINGS": "ignore"}
    env.pop("OCTOFUSE_DEBUG", None)
    t0 = time.monotonic()
    p = subprocess.Popen(
        cmd,
        cwd=cwd,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        env=env,
        preexec_fn=_limits(case.fsize),
    )
    if case.sigint_after is not None:
        marker = case.argv[1] if len(case.argv) > 1 else ""
        while (
            time.monotonic() - t0 < case.timeout
            and p.poll() is None
            and not _started(p.pid, marker)
        ):
            time.sleep(0.02)
        time.sleep(case.sigint_after)
        if p.poll() is None:
            p.send_signal(case.stop_signal)
    try:
        _, err_b = p.communicate(timeout=max(case.timeout - (time.monotonic() - t0), 1.0))
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        _, err_b = p.communicate()
        return Outcome("hang", None, err_b.decode(errors="replace"), time.monotonic() - t0)
    seconds = time.monotonic() - t0
    err = err_b.decode(errors="replace")
    rc = p.returncode
    changed = case.out is not None and tree_hash(case.out) != before
    if rc < 0:
        kind = "signal"
    elif "Traceback" in err:
        kind = "traceback"
    elif changed and rc != 0:
        kind = "changed"
    elif rc == 0:
        kind = "ok"
    elif (
        rc == 2
        and err.rstrip().splitlines()[-1:]
        and err.rstrip().splitlines()[-1].startswith("Error: ")
    ):
        kind = "usage"  # click's usage block, its last line naming the bad argument
    elif len(err.splitlines()) != 1:
        kind = "messy"
    elif case.exit_code is not None and rc != case.exit_code:
        kind = "wrong-exit"
    elif rc == 70:
        kind = "internal"
    else:
        kind = "clean"
    return Outcome(kind, rc, err, seconds)


def check(case: Case, outcome: Outcome) -> None:
    """Assert that ``outcome`` is what ``case`` expects."""
    what = (
        f"{case.name}: {outcome.kind} (exit {outcome.returncode}) stderr={outcome.stderr[-600:]!r}"
    )
    allowed = {"clean", "usage"} if case.expect == "error" else {"clean", "usage", "ok"}
    assert outcome.kind in allowed, what


# -- inputs -------------------------------------------------------------------------------

SCAN_TIMES = [T0 + S // 4 + k * S // 2 for k in range(4)]


def _robot(sensor: str = "lidar") -> Robot:
    return Robot("r1", start=(-1.5, 0.13, 0.2), velocity=(0.4, 0.0, 0.2), sensor=sensor)


def good_bag(root: Path, kind: str = "ros1") -> Path:
    rec = bf.robot_recording([_robot()], {"r1": SCAN_TIMES})
    return rec.write(root / f"good_{kind}", kind)


def team_bag(root: Path) -> Path:
    robots = bf.team(3)
    return bf.robot_recording(robots, bf.team_times(robots, n_scans=4)).write(root / "team", "ros1")


def small_maps(root: Path) -> dict[str, Path]:
    """Small real maps written by octofuse (one .ot and one .bt)."""
    import octofuse

    m = octofuse.OccupancyMap(0.1)
    rng = np.random.default_rng(0)
    for _ in range(3):
        m.insert_scan(rng.uniform(-2, 2, (60, 3)), rng.uniform(-0.5, 0.5, 3))
    return {s: m.save(root / f"small{s}") for s in (".ot", ".bt")}


def _custom_store(overrides: dict[str, str]):
    """A ROS 2 typestore whose definitions of some standard types are replaced."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    defs = dict(bf.typestore(False).fielddefs)
    for name, text in overrides.items():
        defs.update(get_types_from_msg(text, name))
    ts = get_typestore(Stores.EMPTY)
    ts.register(defs)
    return ts


def _write_mcap(path: Path, records, ts) -> Path:
    from rosbags.rosbag2 import StoragePlugin, Writer

    if path.exists():
        shutil.rmtree(path)
    conns: dict[str, object] = {}
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        for topic, msgtype, log_ns, build in records:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, msgtype, typestore=ts)
            w.write(conns[topic], log_ns, ts.serialize_cdr(build(ts), msgtype))
    storage = next(p for p in path.iterdir() if p.suffix == ".mcap")
    bare = path.parent / f"{path.name}.mcap"
    storage.replace(bare)
    shutil.rmtree(path)
    return bare


_PC2_FIELDS = (
    "uint32 width\nsensor_msgs/PointField[] fields\nbool is_bigendian\nuint32 point_step\n"
    "uint32 row_step\nuint8[] data\nbool is_dense"
)


def _one_point_cloud(ts, **fields):
    pf = ts.types["sensor_msgs/msg/PointField"]
    data = np.frombuffer(np.array([1, 0, 0], np.float32).tobytes(), np.uint8).copy()
    return ts.types[PC2](
        width=1,
        fields=[pf(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate("xyz")],
        is_bigendian=False,
        point_step=12,
        row_step=12,
        data=data,
        is_dense=True,
        **fields,
    )


def _tf_records(robot: Robot):
    rec = Recording()
    rec.robot_tf(robot, range(T0, T0 + 3 * S, S // 2))
    return rec.records


def bag_lying_definition(root: Path, which: str) -> Path:
    """A bag whose message definitions lie about the messages' fields."""
    robot = _robot()
    if which == "pc2_no_header":
        ts = _custom_store({PC2: "uint32 height\n" + _PC2_FIELDS})
        recs = _tf_records(robot) + [
            (robot.topic, PC2, T0 + S, lambda ts: _one_point_cloud(ts, height=1))
        ]
    elif which == "pc2_float_height":
        ts = _custom_store({PC2: "std_msgs/Header header\nfloat64 height\n" + _PC2_FIELDS})
        recs = _tf_records(robot) + [
            (
                robot.topic,
                PC2,
                T0 + S,
                lambda ts: _one_point_cloud(
                    ts, header=bf.header(ts, T0 + S, robot.sensor_frame), height=math.inf
                ),
            )
        ]
    elif which == "tf_string_transform":
        ts = _custom_store(
            {
                "geometry_msgs/msg/TransformStamped": "std_msgs/Header header\nstring child_frame_id\nstring transform"
            }
        )

        def tf_str(ts):
            T = ts.types
            return T[TF](
                transforms=[
                    T["geometry_msgs/msg/TransformStamped"](
                        header=bf.header(ts, T0, "map"), child_frame_id="r1/odom", transform="x"
                    )
                ]
            )

        scans = bf.robot_recording([robot], {"r1": SCAN_TIMES}).records
        recs = [r for r in scans if not r[0].startswith("/tf")] + [("/tf_static", TF, T0, tf_str)]
    else:
        raise ValueError(which)
    return _write_mcap(root / f"lying_{which}", recs, ts)


def bag_renamed_field(root: Path) -> Path:
    """An MCAP file whose schemas have a flipped byte in every ``frame_id``."""
    src = good_bag(root, "bare_mcap")
    data = bytearray(src.read_bytes())
    at = data.find(b"frame_id")
    while at >= 0:
        data[at + 3] ^= 0x01
        at = data.find(b"frame_id", at + 1)
    dst = root / "renamed_field.mcap"
    dst.write_bytes(bytes(data))
    return dst


def bag_hostile_numbers(root: Path, which: str, name: str | None = None) -> Path:
    """A ROS 1 bag with hostile numbers in its transforms or scans."""
    robot = _robot("laser" if which == "nan_angle" else "lidar")
    rec = bf.robot_recording([robot], {"r1": SCAN_TIMES})
    if which == "nan_quaternion":  # one bad tf sample among good ones
        rec.tf(T0 + S, [(robot.odom_frame, robot.base_frame, np.full((4, 4), np.nan))])
    elif which == "nan_angle":
        rec.records = [r for r in rec.records if r[1] != SCAN]
        for t in SCAN_TIMES:

            def build(ts, t=t):
                return ts.types[SCAN](
                    header=bf.header(ts, t, robot.sensor_frame),
                    angle_min=0.0,
                    angle_max=1.0,
                    angle_increment=math.nan,
                    time_increment=0.001,
                    scan_time=0.1,
                    range_min=0.1,
                    range_max=10.0,
                    ranges=np.full(20, 2.0, np.float32),
                    intensities=np.zeros(20, np.float32),
                )

            rec.add(robot.topic, SCAN, t + 1000, build)
    elif which in ("huge_points", "huge_ray"):
        rec.records = [r for r in rec.records if r[1] != PC2]
        value = 1e30 if which == "huge_points" else 3600.0
        for t in SCAN_TIMES:

            def build(ts, t=t):
                pf = ts.types["sensor_msgs/msg/PointField"]
                data = np.full((4, 3), value, np.float32).tobytes()
                return ts.types[PC2](
                    header=bf.header(ts, t, robot.sensor_frame),
                    height=1,
                    width=4,
                    fields=[
                        pf(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate("xyz")
                    ],
                    is_bigendian=False,
                    point_step=12,
                    row_step=48,
                    data=np.frombuffer(data, np.uint8).copy(),
                    is_dense=True,
                )

            rec.add(robot.topic, PC2, t + 1000, build)
        if which == "huge_ray":  # the sensor far out at (-1000, -1000, -1000)
            rec.tf(
                T0,
                [("map", robot.odom_frame, bf.pose_matrix(-1000, -1000, -1000, 0))],
                static=True,
                log_ns=T0 + 1,
            )
    elif which == "huge_tf":
        rec.records = [r for r in rec.records if not (r[0] == "/tf")]
        for t in range(T0, T0 + 3 * S, S // 2):
            rec.tf(t, [(robot.odom_frame, robot.base_frame, bf.pose_matrix(1e30, 0, 0, 0))])
    else:
        raise ValueError(which)
    return rec.write(root / (name or f"hostile_{which}"), "ros1")


def flipped(src: Path, dst: Path, rng: np.random.Generator, flips: int, skip: int = 0) -> Path:
    data = bytearray(src.read_bytes())
    for at in rng.integers(min(skip, len(data) - 1), len(data), flips):
        data[at] ^= 1 << int(rng.integers(8))
    dst.write_bytes(bytes(data))
    return dst


def truncated(src: Path, dst: Path, keep: int) -> Path:
    dst.write_bytes(src.read_bytes()[:keep])
    return dst


def map_with_header(src: Path, dst: Path, key: bytes, value: bytes) -> Path:
    """A copy of a map file with one header line (``size``, ``res``, ``id``) replaced."""
    data = src.read_bytes()
    start = data.index(b"\n" + key + b" ") + 1
    end = data.index(b"\n", start)
    dst.write_bytes(data[:start] + key + b" " + value + data[end:])
    return dst


def bt_all_inner(dst: Path, records: int) -> Path:
    """A ``.bt`` file whose every record says "8 inner children" (the tree never ends)."""
    head = b"# Octomap OcTree binary file\nid OcTree\nsize 1\nres 0.1\ndata\n"
    dst.write_bytes(head + b"\xff" * (2 * records))
    return dst


def loss_file(dst: Path, value: float) -> Path:
    """An information-loss .npz of two voxels, the second with loss ``value``."""
    np.savez(
        dst,
        centers=np.zeros((2, 3)),
        sizes=np.full(2, 0.1),
        values=np.array([0.5, value]),
        depths=np.full(2, 16, np.uint8),
    )
    return dst


def api_script(body: str) -> str:
    """A child script: a clean error prints one line and exits 1, as the command does."""
    return textwrap.dedent("""
        import sys, numpy as np, octofuse
        try:
        {body}
        except (ValueError, OSError, MemoryError, TypeError, OverflowError) as e:
            print(f"error: {{type(e).__name__}}: {{e}}".replace("\\n", " "), file=sys.stderr)
            sys.exit(1)
        """).format(body=textwrap.indent(textwrap.dedent(body), "    "))


# -- fixtures -----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    """Inputs, and earlier outputs (a build folder and a run folder) that must survive."""
    root = tmp_path_factory.mktemp("fuzz")
    w = {"root": root, "bag": good_bag(root), "team": team_bag(root), "maps": small_maps(root)}
    w["built"] = root / "built"
    r = subprocess.run(
        [str(OCTOFUSE), "build", str(w["bag"]), "--resolution", "0.1", "--out", str(w["built"])],
        capture_output=True,
        text=True,
        cwd=root,
    )
    assert r.returncode == 0, r.stderr
    return w


@pytest.fixture(scope="module")
def ran(work):
    """A finished ``run`` folder."""
    out = work["root"] / "ran"
    r = subprocess.run(
        [
            str(OCTOFUSE),
            "run",
            str(work["team"]),
            "--resolution",
            "0.1",
            "--topology",
            "ring",
            "--samples",
            "2",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        cwd=work["root"],
    )
    assert r.returncode == 0, r.stderr
    return out


def _go(case: Case, work) -> Outcome:
    outcome = run_case(case, work["root"])
    check(case, outcome)
    return outcome


def _go_all(cases: list[Case], work) -> list[Outcome]:
    """Run cases two at a time; assert them all."""
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(2) as pool:
        outcomes = list(pool.map(lambda c: run_case(c, work["root"]), cases))
    failures = []
    for case, outcome in zip(cases, outcomes):
        try:
            check(case, outcome)
        except AssertionError as err:
            failures.append(str(err).splitlines()[0])
    assert not failures, "\n".join(failures)
    return outcomes


# -- map files ----------------------------------------------------------------------------


@pytest.mark.parametrize("suffix", [".ot", ".bt"])
def test_truncated_maps(work, suffix):
    src = work["maps"][suffix]
    size = src.stat().st_size
    cases = []
    for frac in (0.0, 0.05, 0.3, 0.7, 0.999):
        keep = int(size * frac)
        dst = truncated(src, work["root"] / f"cut{keep}{suffix}", keep)
        cases.append(Case(f"truncated {suffix} at {keep}", ["info", str(dst)]))
    _go_all(cases, work)


@pytest.mark.parametrize("suffix", [".ot", ".bt"])
def test_flipped_maps(work, suffix):
    rng = np.random.default_rng(7 if suffix == ".ot" else 8)
    src = work["maps"][suffix]
    cases = []
    for k in range(3):
        dst = flipped(src, work["root"] / f"flip{k}{suffix}", rng, flips=1 + k)
        cases.append(Case(f"flipped {suffix} #{k}", ["info", str(dst)], expect="any"))
    _go_all(cases, work)


@pytest.mark.parametrize(
    "key,value",
    [
        (b"size", b"0"),
        (b"size", b"1e30"),
        (b"size", b"inf"),
        (b"size", b"18446744073709551616"),
        (b"res", b"1e-30"),
        (b"res", b"1e30"),
        (b"id", b"OcTr\xffe"),
        (b"res", b"nan"),
        (b"size", b"-5"),
    ],
)
def test_map_header_values(work, key, value):
    dst = map_with_header(work["maps"][".ot"], work["root"] / "header.ot", key, value)
    outcome = _go(Case(f"header {key!r} {value!r}", ["info", str(dst)]), work)
    assert "header.ot" in outcome.stderr


def test_special_files_as_maps(work):
    fifo = work["root"] / "fifo.ot"
    if not fifo.exists():
        os.mkfifo(fifo)
    for path in (fifo, Path("/dev/zero")):
        outcome = _go(Case(f"{path} as a map", ["info", str(path)], timeout=20), work)
        assert str(path) in outcome.stderr


def test_bt_every_node_inner(work):
    dst = bt_all_inner(work["root"] / "inner.bt", 4_000_000)
    _go(Case("bt all inner", ["info", str(dst)], timeout=30), work)


# -- bags -----------------------------------------------------------------------------------


def _build(bag: Path, work, expect: str = "error", **kw) -> Outcome:
    case = Case(
        f"build {bag.name}",
        ["build", str(bag), "--resolution", "0.1", "--out", str(work["built"])],
        expect=expect,
        out=work["built"],
        **kw,
    )
    return _go(case, work)


@pytest.mark.parametrize("which", ["pc2_no_header", "pc2_float_height", "tf_string_transform"])
def test_lying_definitions(work, which):
    bag = bag_lying_definition(work["root"], which)
    outcome = _build(bag, work)
    assert bag.name in outcome.stderr and "definition" in outcome.stderr


def test_renamed_field_in_schema(work):
    bag = bag_renamed_field(work["root"])
    outcome = _build(bag, work)
    assert "frame_id" in outcome.stderr and bag.name in outcome.stderr


def test_nan_quaternion_sample_is_skipped(work, tmp_path):
    from octofuse.config import BuildConfig, MapConfig
    from octofuse.scans.source import ScanSource

    bag = bag_hostile_numbers(work["root"], "nan_quaternion")
    with ScanSource(BuildConfig(bags=[str(bag)], map=MapConfig(resolution=0.1))) as src:
        used = sum(1 for _ in src.scans())
        notes = src.tf_skipped
    assert used >= 3
    assert len(notes) == 1 and "/tf" in notes[0] and "r1/base_link" in notes[0]
    assert "non-finite" in notes[0] and str(T0 + S) in notes[0]
    _go(
        Case(
            "nan quaternion",
            ["build", str(bag), "--resolution", "0.1", "--out", str(tmp_path / "maps")],
            expect="any",
        ),
        work,
    )
    assert (tmp_path / "maps" / "r1.ot").is_file()


@pytest.mark.parametrize(
    "which,reason",
    [
        ("nan_angle", "angle_increment"),
        ("huge_points", "no valid points"),
        ("huge_tf", "no scan"),
        ("huge_ray", "no valid points"),
    ],
)
def test_unmappable_geometry(work, which, reason):
    bag = bag_hostile_numbers(work["root"], which)
    outcome = _build(bag, work)
    assert reason in outcome.stderr


def test_damaged_bags(work):
    rng = np.random.default_rng(3)
    bag = work["bag"]
    size = bag.stat().st_size
    paths = [truncated(bag, work["root"] / f"cut{keep}.bag", keep) for keep in (0, 13, size // 3)]
    paths += [flipped(bag, work["root"] / f"flip{k}.bag", rng, 4, skip=64) for k in range(2)]
    _go_all(
        [
            Case(
                f"build {p.name}",
                ["build", str(p), "--resolution", "0.1", "--out", str(work["built"])],
                expect="any" if "flip" in p.name else "error",
                out=work["built"],
            )
            for p in paths
        ],
        work,
    )


def test_special_files_as_bags(work):
    fifo = work["root"] / "fifo.bag"
    if not fifo.exists():
        os.mkfifo(fifo)
    for path in (fifo, Path("/dev/zero")):
        outcome = _build(path, work, timeout=20)
        assert str(path) in outcome.stderr


# -- numbers through the API ----------------------------------------------------------------

API_CASES = {
    "nan points": "octofuse.OccupancyMap(0.1).insert_scan(np.array([[np.nan, 0, 0]]), [0, 0, 0])",
    "inf points": "octofuse.OccupancyMap(0.1).insert_scan(np.array([[np.inf, 0, 0]]), [0, 0, 0])",
    "huge points": "octofuse.OccupancyMap(0.1).insert_scan(np.array([[1e30, 0, 0]]), [0, 0, 0])",
    "nan origin": "octofuse.OccupancyMap(0.1).insert_scan(np.ones((2, 3)), [np.nan, 0, 0])",
    "huge origin": "octofuse.OccupancyMap(0.1).insert_scan(np.ones((2, 3)), [1e30, 0, 0])",
    "zero resolution": "octofuse.OccupancyMap(0.0)",
    "negative resolution": "octofuse.OccupancyMap(-1.0)",
    "nan resolution": "octofuse.OccupancyMap(float('nan'))",
    "tiny resolution": "octofuse.OccupancyMap(1e-30)",
    "huge resolution": "octofuse.OccupancyMap(1e30)",
    "long ray": (
        "octofuse.OccupancyMap(0.05).insert_scan(np.array([[1600., 1600, 1600]]), "
        "[-1600, -1600, -1600])"
    ),
    "long fine ray": (
        "octofuse.OccupancyMap(0.005).insert_scan(np.array([[100., 100, 100]]), [-100, -100, -100])"
    ),
    # rays whose float length is 0 but which end across a voxel face from the origin
    "tiny max_range": (
        "octofuse.OccupancyMap(0.1).insert_scan(np.array([[-1.0, -1.0, 0.0]]), [0, 0, 0], 1e-30)"
    ),
    "tiny max_range, OctoMap's path": (
        "octofuse.OccupancyMap(0.1).insert_scan_from_sensor("
        "np.array([[-1.0, -1.0, 0.0]]), np.eye(4), 1e-30)"
    ),
    "point beside the origin": (
        "octofuse.OccupancyMap(0.1).insert_scan(np.array([[-1e-30, -1e-30, 0.0]]), [0, 0, 0])"
    ),
    # beliefs: sizes beyond any machine, numbers that overflow, contracts of the arguments
    "huge mixtures": (
        "from octofuse.beliefs.mixture import GaussianMixture as G\n"
        "g = G(np.ones(3000), np.arange(3000.0)[:, None], np.ones((3000, 1, 1)))\n"
        "octofuse.fuse_mixtures(g, g)"
    ),
    "huge sample count": (
        "from octofuse.beliefs.mixture import GaussianMixture as G\n"
        "g = G.gaussian([0.0], [[1.0]])\n"
        "octofuse.fuse_mixtures(g, g, n_samples=10**13)"
    ),
    "tiny measured range": (
        "from octofuse.beliefs.expoly import ExPoly2D\n"
        "ExPoly2D.range_likelihood([0, 0], 1e-200, a=1.0)"
    ),
    "mixture dict without covariances": (
        "from octofuse.beliefs.mixture import GaussianMixture\n"
        "GaussianMixture.from_dict({'weights': [1], 'means': [[0]]})"
    ),
    "overflowing moments": (
        "from octofuse.beliefs.mixture import GaussianMixture\n"
        "GaussianMixture([.5, .5], [[1e308, 0], [-1e308, 0]], "
        "[np.eye(2)] * 2).moments()"
    ),
}


@pytest.mark.parametrize("name", list(API_CASES))
def test_api_numbers(work, name):
    _go(Case(f"api {name}", [api_script(API_CASES[name])], python=True), work)


# -- command lines and configs --------------------------------------------------------------


def test_runaway_schedules(work, ran):
    for spec in ("aperiodic:1e-9", "periodic:1e-6"):
        outcome = _go(
            Case(
                f"schedule {spec}",
                [
                    "run",
                    str(work["team"]),
                    "--topology",
                    "ring",
                    "--schedule",
                    spec,
                    "--out",
                    str(ran),
                ],
                out=ran,
                timeout=30,
            ),
            work,
        )
        assert "exchanges" in outcome.stderr


HOSTILE_ARGUMENTS = [
    ["fuse", "{built}", "--rounds", "1000000000", "--out", "{root}/f"],
    ["run", "{bag}", "--samples", "1000000", "--out", "{root}/r"],
    ["build", "{bag}", "--threads", "100000", "--out", "{built}"],
    ["build", "{bag}", "--every", "0", "--out", "{built}"],
    ["build", "{bag}", "--resolution", "nan", "--out", "{built}"],
    ["build", "{bag}", "--resolution", "-1", "--out", "{built}"],
    ["build", "{bag}", "--max-range", "inf", "--resolution", "0.1", "--out", "{root}/mr"],
    ["export", "{root}/small.ot", "--out", "{root}/x.txt"],
    ["nosuchcommand"],
]


def test_hostile_arguments(work):
    cases = []
    for argv in HOSTILE_ARGUMENTS:
        argv = [a.format(built=work["built"], bag=work["bag"], root=work["root"]) for a in argv]
        cases.append(
            Case(
                " ".join(argv[:4]),
                argv,
                expect="any" if "--max-range" in argv else "error",
                out=work["built"],
            )
        )
    _go_all(cases, work)


HOSTILE_CONFIGS = [
    b"build:\n  scan_stride: '2'\n",
    b"build:\n  max_range: far\n",
    b"build:\n  map:\n    clamping: 5\n",
    b"build:\n  fixed_frame: 5\n",
    b"fuse:\n  rules: 5\n",
    b"build:\n  threads: two\n",
    b"build:\n  threads: -1\n",
    b"build:\n  map:\n    resolution: [1, 2]\n",
    b"build:\n  agents:\n    - name: a\n",
    b"build:\n  threads: 100000\n",
    b"build: [\n",
    b"build:\n  scan_stride: \xff\n",
    b"\x00\x01\x02",
    b"- 1\n- 2\n",
    b"build:\n  map:\n    resolution: 1e-30\n",
    b"build:\n  bags: 5\n",
]


def test_hostile_configs(work):
    cases = []
    for k, text in enumerate(HOSTILE_CONFIGS):
        cfg = work["root"] / f"hostile{k}.yaml"
        cfg.write_bytes(text)
        cases.append(
            Case(
                f"config {text[:30]!r}",
                ["build", str(work["bag"]), "--config", str(cfg), "--out", str(work["built"])],
                out=work["built"],
            )
        )
    for k, outcome in enumerate(_go_all(cases, work)):
        assert f"hostile{k}.yaml" in outcome.stderr or "options" in outcome.stderr, outcome


# -- kills and full disks -------------------------------------------------------------------


def test_sigint_keeps_outputs(work, ran):
    # the bundled lab: a run of many seconds, so that the interruption lands inside it
    lab8 = REPO / "data" / "lab8.bag"
    case = Case(
        "SIGINT in run",
        [
            "run",
            str(lab8),
            "--topology",
            "ring",
            "--samples",
            "2",
            "--resolution",
            "0.1",
            "--out",
            str(ran),
        ],
        out=ran,
        sigint_after=0.3,
        exit_code=130,
    )
    outcome = run_case(case, work["root"])
    # click writes an empty line before its Abort, hence strip()
    assert outcome.returncode == 130 and outcome.kind in ("clean", "messy"), outcome
    assert outcome.stderr.strip() == "error: interrupted"


@pytest.mark.parametrize(
    "value,expect",
    [(-1e38, "warning"), (100.0, "warning"), (-100.0, "warning"), (1e-40, "subnormal")],
)
def test_map_values_no_clamping_produces(work, tmp_path, value, expect):
    src = map_with_values(work["maps"][".ot"], tmp_path / "odd.ot", [value, value])
    out = tmp_path / "kept"
    out.mkdir()
    (out / "cloud.ply").write_bytes(b"earlier")
    outcome = run_case(
        Case(
            "map values",
            ["export", str(src), "--out", str(out / "cloud.ply")],
            out=out,
            expect="any",
        ),
        work["root"],
    )
    assert str(src) in outcome.stderr and expect in outcome.stderr, outcome
    assert outcome.kind == ("ok" if expect == "warning" else "clean"), outcome


@pytest.mark.parametrize("value", [np.inf, 1e300, np.nan, -1.0])
def test_loss_files_with_impossible_losses(work, tmp_path, value):
    src = loss_file(tmp_path / "loss.npz", value)
    outcome = _go(Case("loss values", ["export", str(src), "--out", str(tmp_path / "h.ply")]), work)
    assert str(src) in outcome.stderr and "values" in outcome.stderr


def test_sigterm_keeps_outputs(work, ran):
    lab8 = REPO / "data" / "lab8.bag"
    case = Case(
        "SIGTERM in run",
        [
            "run",
            str(lab8),
            "--topology",
            "ring",
            "--samples",
            "2",
            "--resolution",
            "0.1",
            "--out",
            str(ran),
        ],
        out=ran,
        sigint_after=0.3,
        stop_signal=signal.SIGTERM,
        exit_code=143,
    )
    outcome = run_case(case, work["root"])
    assert outcome.returncode == 143 and outcome.kind in ("clean", "messy"), outcome
    assert outcome.stderr.strip() == "error: terminated"
    assert not [p for p in ran.parent.iterdir() if ".partial" in p.name]


def test_sigint_while_importing_is_one_line(work, tmp_path):
    """Ctrl-C once the interpreter is up, while the program still imports (numpy loaded, the
    command line not yet): one line, exit code 130, nothing written."""
    out = tmp_path / "never"
    p = subprocess.Popen(
        [str(OCTOFUSE), "run", str(work["team"]), "--out", str(out)],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        preexec_fn=_limits(None),
        env={**os.environ, "PYTHONWARNINGS": "ignore"},
    )
    t0 = time.monotonic()
    while p.poll() is None and time.monotonic() - t0 < TIME_LIMIT:
        try:
            if "numpy" in Path(f"/proc/{p.pid}/maps").read_text():
                break
        except OSError:
            pass
        time.sleep(0.002)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=TIME_LIMIT)
    assert (p.returncode, err.decode().strip()) == (130, "error: interrupted")
    assert not out.exists()


def test_full_disk(work, ran):
    fsize = 30000
    _go(
        Case(
            "build with fsize 1000",
            ["build", str(work["bag"]), "--resolution", "0.1", "--out", str(work["built"])],
            out=work["built"],
            fsize=1000,
        ),
        work,
    )
    for argv, out in (
        (
            [
                "run",
                str(work["team"]),
                "--topology",
                "ring",
                "--samples",
                "2",
                "--resolution",
                "0.1",
                "--out",
                str(ran),
            ],
            ran,
        ),
        (
            ["build", str(work["bag"]), "--resolution", "0.1", "--out", str(work["built"])],
            work["built"],
        ),
        (["export", str(ran / "centralized.ot"), "--out", str(ran / "cloud.pcd")], ran),
    ):
        outcome = _go(Case(f"{argv[0]} with fsize {fsize}", argv, out=out, fsize=fsize), work)
        assert "disk full" in outcome.stderr or "write" in outcome.stderr
