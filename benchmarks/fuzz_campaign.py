"""A long, seeded fuzz campaign against the installed ``octofuse`` command.

Draws cases from the generators of ``tests/python/cli/test_fuzz.py`` (mutated map files, map values
no clamping produces, impossible loss files, mutated and hostile bags, numbers through the API
(maps, mixtures, exponential polynomials), command lines, configs, SIGINT and SIGTERM during a
run or an export over an earlier file, full disks), runs
each in a child process with a time and memory limit, and prints the counts per generator:
clean errors, accepted inputs, tracebacks, signals, hangs, messy stderr, changed outputs.
Exit status 1 if any case crashed, hung, printed a traceback, changed earlier outputs or
accepted an input that must be refused.

    python benchmarks/fuzz_campaign.py --cases 2000 --minutes 5 --seed 1
"""

from __future__ import annotations

import argparse
import shutil
import signal
import sys
import tempfile
import threading
import time
from collections import Counter, defaultdict
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests" / "python" / "cli"), str(ROOT / "tests" / "python")]
import test_fuzz as tf  # noqa: E402
from test_fuzz import Case  # noqa: E402

BAD = ("traceback", "signal", "hang", "messy", "changed", "wrong-exit", "internal", "lie")


class Inputs:
    """The files every case starts from, made once."""

    def __init__(self, root: Path):
        self.root = root
        self.bags = {"ros1": tf.good_bag(root), "mcap": tf.good_bag(root, "bare_mcap")}
        self.team = tf.team_bag(root)
        self.maps = tf.small_maps(root)
        self.built = root / "built"
        self._cli(
            ["build", str(self.bags["ros1"]), "--resolution", "0.1", "--out", str(self.built)]
        )
        self.maps["built.ot"] = self.built / "r1.ot"
        self.ran = root / "ran"
        self._cli(
            [
                "run",
                str(self.team),
                "--resolution",
                "0.1",
                "--topology",
                "ring",
                "--samples",
                "2",
                "--out",
                str(self.ran),
            ]
        )
        self.hostile = {
            w: tf.bag_lying_definition(root, w)
            for w in ("pc2_no_header", "pc2_float_height", "tf_string_transform")
        }
        self.hostile["renamed_field"] = tf.bag_renamed_field(root)
        for w in ("nan_quaternion", "nan_angle", "huge_points", "huge_tf", "huge_ray"):
            self.hostile[w] = tf.bag_hostile_numbers(root, w)
        self.big = root / "big.ot"  # an export of about a second, for signals while it writes
        import octofuse

        big = octofuse.OccupancyMap(0.05)
        pts = np.random.default_rng(3).uniform(-5, 5, (4, 20000, 3))
        for p in pts:
            big.insert_scan(p, [0.0, 0.0, 0.0])
        big.save(self.big)
        self.fifo = root / "fifo"
        import os

        os.mkfifo(self.fifo)
        self._n = 0
        self._lock = threading.Lock()

    def _cli(self, argv: list[str]) -> None:
        out = tf.run_case(Case("setup", argv, expect="any"), self.root)
        if out.kind != "ok":
            raise SystemExit(f"setup failed: {' '.join(argv)}: {out.stderr}")

    def fresh(self, stem: str) -> Path:
        with self._lock:
            self._n += 1
            return self.root / "cases" / f"{self._n:05d}_{stem}"

    def copy_of(self, folder: Path) -> Path:
        dst = self.fresh(folder.name)
        shutil.copytree(folder, dst)
        return dst


# -- generators: (rng, inputs) -> Case ------------------------------------------------------


def gen_map_truncate(rng, x: Inputs) -> Case:
    src = x.maps[rng.choice(sorted(x.maps))]
    keep = int(rng.integers(0, src.stat().st_size))
    dst = tf.truncated(src, x.fresh("cut" + src.suffix).with_suffix(src.suffix), keep)
    return Case(f"map truncated at {keep}", ["info", str(dst)])


def gen_map_flip(rng, x: Inputs) -> Case:
    src = x.maps[rng.choice(sorted(x.maps))]
    dst = tf.flipped(src, x.fresh("flip").with_suffix(src.suffix), rng, int(rng.integers(1, 9)))
    return Case("map byte flips", ["info", str(dst)], expect="any")


HEADER_VALUES = {
    b"size": [b"0", b"-1", b"1e30", b"inf", b"nan", b"18446744073709551616", b"9" * 40, b"x", b""],
    b"res": [b"0", b"-0.1", b"1e-30", b"1e30", b"inf", b"nan", b"5e-324", b"x", b""],
    b"id": [b"OcTr\xffe", b"ColorOcTree", b"", b"\x00" * 8],
}


def gen_map_header(rng, x: Inputs) -> Case:
    key = [b"size", b"res", b"id"][int(rng.integers(3))]
    value = HEADER_VALUES[key][int(rng.integers(len(HEADER_VALUES[key])))]
    src = x.maps[rng.choice([".ot", ".bt", "built.ot"])]
    dst = tf.map_with_header(src, x.fresh("hdr").with_suffix(src.suffix), key, value)
    return Case(f"map header {key.decode()} {value[:20]!r}", ["info", str(dst)])


def gen_map_special(rng, x: Inputs) -> Case:
    if rng.random() < 0.5:
        dst = tf.bt_all_inner(x.fresh("inner").with_suffix(".bt"), int(rng.integers(1, 8_000_000)))
        return Case("bt all inner", ["info", str(dst)], timeout=60)
    path = [x.fifo, Path("/dev/zero"), Path("/dev/null")][int(rng.integers(3))]
    return Case(
        f"{path} as a map",
        [["info"], ["export"]][int(rng.integers(2))]
        + [str(path)]
        + ([] if rng.random() < 0.5 else ["--out", str(x.fresh("x")) + ".ply"]),
        timeout=20,
    )


def _build(x: Inputs, bag: Path, expect: str = "error", **kw) -> Case:
    out = x.copy_of(x.built)
    return Case(
        f"build {bag.name}",
        ["build", str(bag), "--resolution", "0.1", "--out", str(out)],
        expect=expect,
        out=out,
        **kw,
    )


def gen_bag_truncate(rng, x: Inputs) -> Case:
    src = x.bags[rng.choice(sorted(x.bags))]
    keep = int(rng.integers(0, src.stat().st_size))
    return _build(x, tf.truncated(src, x.fresh("cut").with_suffix(src.suffix), keep))


def gen_bag_flip(rng, x: Inputs) -> Case:
    src = x.bags[rng.choice(sorted(x.bags))]
    dst = tf.flipped(src, x.fresh("flip").with_suffix(src.suffix), rng, int(rng.integers(1, 12)))
    return _build(x, dst, expect="any")


def gen_bag_hostile(rng, x: Inputs) -> Case:
    which = rng.choice(sorted(x.hostile) + ["fifo", "/dev/zero"])
    bag = {"fifo": x.fifo, "/dev/zero": Path("/dev/zero")}.get(which) or x.hostile[which]
    return _build(x, bag, expect="any" if which == "nan_quaternion" else "error", timeout=30)


NUMBERS = [
    "float('nan')",
    "float('inf')",
    "-float('inf')",
    "1e30",
    "-1e30",
    "1e10",
    "5e-324",
    "0.0",
    "-1.0",
    "1e-30",
    "1e308",
]


def gen_api(rng, x: Inputs) -> Case:
    if rng.random() < 0.3:
        name = rng.choice(sorted(tf.API_CASES))
        return Case(f"api {name}", [tf.api_script(tf.API_CASES[name])], python=True)
    pick = lambda: NUMBERS[int(rng.integers(len(NUMBERS)))]  # noqa: E731
    res = pick() if rng.random() < 0.5 else "0.1"
    pts = f"np.array([[{pick()}, {pick()}, {pick()}], [1.0, 0.0, 0.0]])"
    origin = f"[{pick()}, 0.0, 0.0]" if rng.random() < 0.5 else "[0.0, 0.0, 0.0]"
    body = f"m = octofuse.OccupancyMap({res})\nm.insert_scan({pts}, {origin}, {pick()})\nm.leaves()"
    return Case("api numbers", [tf.api_script(body)], python=True, expect="any")


def gen_cli(rng, x: Inputs) -> Case:
    if rng.random() < 0.4:
        kind = rng.choice(["periodic", "aperiodic"])
        value = 10 ** rng.uniform(-12, -4.5)
        out = x.copy_of(x.ran)
        return Case(
            f"schedule {kind}:{value:.3g}",
            [
                "run",
                str(x.team),
                "--topology",
                "ring",
                "--schedule",
                f"{kind}:{value:.3g}",
                "--out",
                str(out),
            ],
            out=out,
            timeout=30,
        )
    argv = tf.HOSTILE_ARGUMENTS[int(rng.integers(len(tf.HOSTILE_ARGUMENTS)))]
    built = x.copy_of(x.built)
    argv = [a.format(built=built, bag=x.bags["ros1"], root=x.root) for a in argv]
    return Case(
        " ".join(argv[:4]), argv, out=built, expect="any" if "--max-range" in argv else "error"
    )


CONFIG_KEYS = [
    "build.scan_stride",
    "build.max_range",
    "build.map.clamping",
    "build.fixed_frame",
    "fuse.rules",
    "build.threads",
    "build.map.resolution",
    "build.agents",
    "build.bags",
    "build.map.prob_hit",
    "build.batch_size",
    "build.no_return",
    "build.deskew",
]
CONFIG_VALUES = [
    "'2'",
    "far",
    "5",
    "-1",
    "100000",
    "two",
    "[1, 2]",
    "{a: 1}",
    "null",
    ".nan",
    "1e-30",
    "1e30",
    "-.inf",
    "[{name: a}]",
    "\xff",
    "''",
    "[",
    "!!binary AAAA",
]


def gen_config(rng, x: Inputs) -> Case:
    path = x.fresh("cfg").with_suffix(".yaml")
    if rng.random() < 0.15:
        path.write_bytes(bytes(rng.integers(0, 256, int(rng.integers(1, 64)), dtype=np.uint8)))
    else:
        key = CONFIG_KEYS[int(rng.integers(len(CONFIG_KEYS)))].split(".")
        value = CONFIG_VALUES[int(rng.integers(len(CONFIG_VALUES)))]
        text = "".join(f"{'  ' * i}{k}:\n" for i, k in enumerate(key[:-1]))
        path.write_bytes(
            (text + f"{'  ' * (len(key) - 1)}{key[-1]}: {value}\n").encode(
                "utf-8", "surrogateescape"
            )
        )
    out = x.copy_of(x.built)
    return Case(
        f"config {path.name}",
        ["build", str(x.bags["ros1"]), "--config", str(path), "--out", str(out)],
        out=out,
        expect="any",
    )


def gen_sigint(rng, x: Inputs) -> Case:
    out = x.copy_of(x.ran)
    return Case(
        "SIGINT in run",
        [
            "run",
            str(x.team),
            "--topology",
            "ring",
            "--samples",
            "2",
            "--resolution",
            "0.1",
            "--out",
            str(out),
        ],
        out=out,
        sigint_after=float(rng.uniform(0.0, 2.5)),
        exit_code=130,
        expect="any",
    )


def gen_interrupt_export(rng, x: Inputs) -> Case:
    """SIGINT or SIGTERM while ``export`` replaces an earlier file: it must stay byte-identical
    unless the command succeeds, and no partial file may stay beside it."""
    out = x.fresh("export")
    out.mkdir(parents=True)
    target = out / f"cloud{rng.choice(['.ply', '.pcd', '.ot'])}"
    target.write_bytes(b"earlier output\n")
    sig = (signal.SIGINT, signal.SIGTERM)[int(rng.integers(2))]
    return Case(
        f"{sig.name} in export",
        ["export", str(x.big), "--out", str(target)],
        out=out,
        sigint_after=float(rng.uniform(0.0, 1.5)),
        stop_signal=sig,
        exit_code=128 + sig,
        expect="any",
    )


MAP_VALUES = [-1e38, -100.0, 100.0, 1e-40, -1e-42, 3.0e38, 0.5, -1.0]


def gen_map_values(rng, x: Inputs) -> Case:
    values = [
        MAP_VALUES[int(rng.integers(len(MAP_VALUES)))] for _ in range(int(rng.integers(1, 6)))
    ]
    src = tf.map_with_values(x.maps[".ot"], x.fresh("values").with_suffix(".ot"), values)
    out = x.copy_of(x.built)
    if rng.random() < 0.5:
        argv = ["export", str(src), "--out", str(out / "cloud.ply")]
    else:
        argv = ["fuse-maps", str(src), str(x.maps["built.ot"]), "--out", str(out / "fused.ot")]
    return Case(f"map values {values}", argv, out=out, expect="any")


def gen_loss_values(rng, x: Inputs) -> Case:
    value = [np.inf, -np.inf, 1e300, 3.5e38, np.nan, -1.0, -1e-30][int(rng.integers(7))]
    src = tf.loss_file(x.fresh("loss").with_suffix(".npz"), value)
    return Case(f"loss value {value}", ["export", str(src), "--out", str(src.with_suffix(".ply"))])


def gen_full_disk(rng, x: Inputs) -> Case:
    fsize = int(10 ** rng.uniform(2, 5.7))
    which = int(rng.integers(3))
    if which == 0:
        out = x.copy_of(x.ran)
        argv = [
            "run",
            str(x.team),
            "--topology",
            "ring",
            "--samples",
            "2",
            "--resolution",
            "0.1",
            "--out",
            str(out),
        ]
    elif which == 1:
        out = x.copy_of(x.built)
        argv = ["build", str(x.bags["ros1"]), "--resolution", "0.1", "--out", str(out)]
    else:
        out = x.copy_of(x.built)
        argv = [
            "export",
            str(out / "r1.ot"),
            "--out",
            str(out / f"cloud{rng.choice(['.ply', '.pcd'])}"),
        ]
    return Case(f"{argv[0]} with fsize {fsize}", argv, out=out, fsize=fsize, expect="any")


GENERATORS = {
    "map truncated": (gen_map_truncate, 6),
    "map flipped": (gen_map_flip, 6),
    "map header": (gen_map_header, 3),
    "map special": (gen_map_special, 1),
    "bag truncated": (gen_bag_truncate, 3),
    "bag flipped": (gen_bag_flip, 4),
    "bag hostile": (gen_bag_hostile, 2),
    "api numbers": (gen_api, 4),
    "cli args": (gen_cli, 2),
    "config": (gen_config, 3),
    "sigint": (gen_sigint, 1),
    "full disk": (gen_full_disk, 1),
    "signal export": (gen_interrupt_export, 2),
    "map values": (gen_map_values, 2),
    "loss values": (gen_loss_values, 1),
}


def classify(case: Case, outcome: tf.Outcome) -> str:
    said = {130: "error: interrupted", 143: "error: terminated"}.get(outcome.returncode)
    if (
        case.sigint_after is not None
        and said is not None
        and outcome.stderr.strip() == said
        and outcome.kind in ("clean", "messy")
    ):
        return "interrupted"
    if outcome.kind == "ok" and case.expect == "error":
        return "lie"
    return outcome.kind


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=1000)
    ap.add_argument("--minutes", type=float, default=5.0, help="stop drawing cases after this")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--keep", action="store_true", help="keep the working folder")
    args = ap.parse_args()
    root = Path(tempfile.mkdtemp(prefix="octofuse-fuzz-"))
    (root / "cases").mkdir()
    t0 = time.monotonic()
    x = Inputs(root)
    names = list(GENERATORS)
    weights = np.array([GENERATORS[n][1] for n in names], dtype=float)
    rng = np.random.default_rng(args.seed)
    counts: dict[str, Counter] = defaultdict(Counter)
    failures: list[str] = []
    deadline = t0 + args.minutes * 60

    def one(k: int, gen: str, seed: int) -> tuple[str, str, Case, tf.Outcome]:
        case = GENERATORS[gen][0](np.random.default_rng([args.seed, k]), x)
        return gen, classify(case, out := tf.run_case(case, root)), case, out

    with ThreadPoolExecutor(args.workers) as pool:
        pending = set()
        k = 0
        while pending or (k < args.cases and time.monotonic() < deadline):
            while (
                k < args.cases and len(pending) < 2 * args.workers and time.monotonic() < deadline
            ):
                pending.add(
                    pool.submit(one, k, names[rng.choice(len(names), p=weights / weights.sum())], k)
                )
                k += 1
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for fut in done:
                gen, kind, case, out = fut.result()
                counts[gen][kind] += 1
                if kind in BAD:
                    failures.append(
                        f"[{kind}] {gen}: {case.name}: exit {out.returncode}: "
                        f"{' | '.join(out.stderr.strip().splitlines()[-3:])[:300]}"
                    )
    total = Counter()
    for c in counts.values():
        total.update(c)
    cols = ["clean", "usage", "interrupted", "ok", *BAD]
    print(
        f"octofuse fuzz campaign: seed {args.seed}, {sum(total.values())} cases in "
        f"{time.monotonic() - t0:.0f} s"
    )
    print(f"{'generator':16s}" + "".join(f"{c:>12s}" for c in ["cases", *cols]))
    for gen in names + ["TOTAL"]:
        c = total if gen == "TOTAL" else counts.get(gen, Counter())
        print(f"{gen:16s}" + "".join(f"{v:>12d}" for v in [sum(c.values()), *(c[k] for k in cols)]))
    print(
        f"clean errors {total['clean'] + total['usage'] + total['interrupted']}, accepted "
        f"{total['ok']}, tracebacks {total['traceback']}, signals {total['signal']}, hangs "
        f"{total['hang']}, outputs changed {total['changed']}, messy stderr {total['messy']}, "
        f"accepted but must be refused {total['lie']}, internal errors {total['internal']}"
    )
    for line in failures[:40]:
        print(line)
    if args.keep:
        print(f"working folder: {root}")
    else:
        shutil.rmtree(root, ignore_errors=True)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
