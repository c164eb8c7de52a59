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
