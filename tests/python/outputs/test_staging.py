"""All-or-nothing output folders: failures keep the earlier outputs and name the final paths."""

import errno
import os

import pytest

from octofuse.outputs.staging import MARKER, staged_folder


def test_success_replaces_earlier_output_whole(tmp_path):
    out = tmp_path / "out"
    with staged_folder(out, "run") as stage:
        (stage / "old.txt").write_text("old")
    with staged_folder(out, "run") as stage:
        (stage / "new.txt").write_text("new")
    assert sorted(p.name for p in out.iterdir()) == sorted([MARKER, "new.txt"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_failure_keeps_earlier_output_and_names_the_final_path(tmp_path):
    out = tmp_path / "out"
    with staged_folder(out, "run") as stage:
        (stage / "kept.txt").write_text("kept")
    with pytest.raises(OSError) as info:
        with staged_folder(out, "run") as stage:
            (stage / "half.ot").write_text("x")
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(stage / "half.ot"))
    assert info.value.filename == str((out / "half.ot").absolute())
    assert ".partial" not in str(info.value)
    assert (out / "kept.txt").read_text() == "kept"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_messages_of_other_errors_name_the_final_path(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(ValueError, match="cannot write") as info:
        with staged_folder(out, "run") as stage:
            raise ValueError(f"cannot write '{stage / 'a.ply'}'")
    assert str((out / "a.ply").absolute()) in str(info.value)
    assert not out.exists()


def test_plain_os_errors_keep_their_message(tmp_path):
    with pytest.raises(OSError) as info:
        with staged_folder(tmp_path / "out", "run"):
            raise OSError("no space left on the device")
    assert str(info.value) == "no space left on the device"


# -- interruptions and killed runs -----------------------------------------------------------
import signal  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from octofuse import interrupts  # noqa: E402
from octofuse.outputs.staging import clean_leftovers, partial_path, staged_file  # noqa: E402

OCTOFUSE = Path(sys.executable).parent / "octofuse"


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def _leftovers(folder: Path) -> list[str]:
    return sorted(
        p.name for p in folder.iterdir() if ".partial" in p.name or p.name.endswith(".old")
    )


def test_leftovers_of_dead_processes_are_removed_and_moved_aside_output_restored(tmp_path):
    out, dead = tmp_path / "out", _dead_pid()
    (tmp_path / f".out.{dead}-abcd1234.partial").mkdir()
    (tmp_path / f".a.ply.{dead}-0a0b0c0d.partial.ply").write_text("half")
    (tmp_path / f"..a.ply.{dead}-01.partial.ply.{dead}-02.partial.ply").write_text("half")
    (tmp_path / ".out.q8_x1.partial").mkdir()  # an older name without a process id
    mine = partial_path(tmp_path / "out")
    mine.mkdir()  # this process may still write it
    aside = tmp_path / f".out.{dead}-ffff0000.old"
    (aside / "out").mkdir(parents=True)
    (aside / "out" / "kept.txt").write_text("earlier output")
    clean_leftovers(tmp_path / "a.ply")
    clean_leftovers(out)
    sibling = partial_path(tmp_path / "out.mcap")  # a name that begins like out's
    sibling.mkdir()
    (tmp_path / f".out.mcap.{dead}-0a0b0c0d.partial").mkdir()  # out.mcap's, not out's
    clean_leftovers(out)
    assert (out / "kept.txt").read_text() == "earlier output"
    assert _leftovers(tmp_path) == sorted(
        [mine.name, sibling.name, f".out.mcap.{dead}-0a0b0c0d.partial"]
    )


def test_interruption_as_outputs_go_in_place_keeps_the_earlier_bag_and_folder(
    tmp_path, monkeypatch
):
    from octofuse import OccupancyMap
    from octofuse.outputs.rosbag_export import MapBagWriter, MapEvent

    m = OccupancyMap(0.1)
    m.insert_scan([[1.0, 0.0, 0.0]], [0.0, 0.0, 0.0])
    out, bag_path = tmp_path / "out", tmp_path / "r.mcap"
    with staged_folder(out, "run") as stage:
        (stage / "kept.txt").write_text("kept")
    monkeypatch.setattr(interrupts, "_outputs_in_place", False)
    bag = MapBagWriter(bag_path)
    with pytest.raises(KeyboardInterrupt):
        with staged_folder(out, "run", also=(bag.put_in_place,)) as stage:
            bag.write(MapEvent("a", 0, m))
            bag.finish()
            monkeypatch.setattr(interrupts, "_interrupted", True)  # a Ctrl-C swallowed on its way
    bag.abort()
    assert not bag_path.exists()
    assert (out / "kept.txt").read_text() == "kept"
    assert _leftovers(tmp_path) == []


def test_staged_file_failure_keeps_the_file_and_names_it(tmp_path):
    out = tmp_path / "a.ply"
    out.write_bytes(b"old")
    with pytest.raises(ValueError) as info:
        with staged_file(out) as tmp:
            tmp.write_bytes(b"ne")
            raise ValueError(f"cannot write '{tmp}'")
    assert str(out) in str(info.value) and ".partial" not in str(info.value)
    assert out.read_bytes() == b"old" and _leftovers(tmp_path) == []


@pytest.fixture(scope="module")
def big_map(tmp_path_factory):
    import numpy as np

    from conftest import scan_ring
    from octofuse import OccupancyMap

    rng = np.random.default_rng(3)
    m = OccupancyMap(0.05)
    for _ in range(6):
        m.insert_scan(rng.uniform(-6, 6, (20000, 3)), [0.0, 0.0, 0.0])
        m.insert_scan(scan_ring(rng, np.zeros(3), 2000, 3.0), [0.0, 0.0, 0.0])
    p = tmp_path_factory.mktemp("big") / "big.ot"
    m.save(p)
    return p


def _export(src: Path, out: Path, sig=None, after: float = 0.0):
    p = subprocess.Popen(
        [str(OCTOFUSE), "export", str(src), "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    if sig is not None:
        time.sleep(after)
        p.send_signal(sig)
    so, se = p.communicate(timeout=120)
    return p.returncode, so.decode(), se.decode()


@pytest.mark.slow
@pytest.mark.parametrize("suffix", [".ply", ".ot"])
def test_export_interrupted_at_any_moment_keeps_the_old_file(big_map, tmp_path, suffix):
    out = tmp_path / f"existing{suffix}"
    out.write_bytes(b"earlier output\n")
    rc, _, err = _export(big_map, tmp_path / f"reference{suffix}")
    assert rc == 0, err
    new = (tmp_path / f"reference{suffix}").read_bytes()
    seen = set()
    delays = [0.05, 0.3, 0.6, 0.9, 1.2, 1.6, 2.0, 2.6]
    for k, after in enumerate(delays):
        sig = (signal.SIGINT, signal.SIGTERM)[k % 2]
        rc, so, err = _export(big_map, out, sig, after)
        assert _leftovers(tmp_path) == [], (after, sig)
        if rc == 0:  # done before the signal, or the signal came as the file went in place
            assert out.read_bytes() == new
            out.write_bytes(b"earlier output\n")
        elif rc == -sig:  # the signal came before the interpreter had loaded octofuse
            assert out.read_bytes() == b"earlier output\n"
        else:
            assert rc == 128 + sig, (after, sig, err)
            word = "terminated" if sig == signal.SIGTERM else "interrupted"
            assert err.strip().splitlines() == [f"error: {word}"], (after, err)
            assert "wrote" not in so
            assert out.read_bytes() == b"earlier output\n"
        seen.add(rc)
    assert seen - {0}, "no signal landed while the command ran"


@pytest.mark.slow
def test_a_killed_export_leaves_what_the_next_one_removes(big_map, tmp_path):
    out = tmp_path / "existing.ply"
    out.write_bytes(b"earlier output\n")
    for after in (0.8, 1.4):
        rc, _, _ = _export(big_map, out, signal.SIGKILL, after)
        assert out.read_bytes() == b"earlier output\n" or rc == 0
    rc, _, err = _export(big_map, out)
    assert rc == 0, err
    assert _leftovers(tmp_path) == []
