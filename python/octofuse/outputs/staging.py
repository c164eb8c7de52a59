"""All-or-nothing output folders: a command writes into a fresh folder beside ``--out`` and
puts it in place only when everything is written.

A failed or interrupted command leaves the previous outputs exactly as they were. An existing
``--out`` folder is replaced whole (no stale files of an earlier run stay beside new ones) if
octofuse wrote it or it is empty; any other folder is refused, so a typo never deletes data.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import shutil
import tempfile
from pathlib import Path
from typing import Iterator

from ..interrupts import held, outputs_in_place, raise_if_interrupted

#: a file in every output folder octofuse writes, naming the command that wrote it
MARKER = ".octofuse-output"


def check_replaceable(out: str | os.PathLike) -> Path:
    """``out`` as a Path; ``ValueError`` if it exists and is not an output folder of octofuse."""
    p = Path(out)
    if p.exists() or p.is_symlink():
        if not p.is_dir() or p.is_symlink():
            raise ValueError(f"--out '{p}' exists and is not a folder; give a folder name")
        if any(p.iterdir()) and not (p / MARKER).is_file():
            raise ValueError(f"--out '{p}' is a folder that octofuse did not write; refusing to "
                             "replace it (give a new or empty folder)")
    return p


@contextlib.contextmanager
def staged_folder(out: str | os.PathLike, command: str) -> Iterator[Path]:
    """Yield a fresh folder to write into; on success it replaces ``out`` in one rename."""
    final = check_replaceable(out).absolute()
    final.parent.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=f".{final.name}.", suffix=".partial", dir=final.parent))
    try:
        yield stage
        with held():  # the old outputs or the new ones in place, never neither
            raise_if_interrupted()  # a Ctrl-C swallowed on its way keeps the old outputs too
            (stage / MARKER).write_text(f"written by octofuse {command}\n")
            _replace(stage, final)
            outputs_in_place()
    except BaseException as e:
        shutil.rmtree(stage, ignore_errors=True)
        _name_final_paths(e, stage, final)
        raise


def _name_final_paths(e: BaseException, stage: Path, final: Path) -> None:
    """Errors name the files as the user will find them (``--out``), not the staging folder."""
    def fix(x):
        return x.replace(str(stage), str(final)) if isinstance(x, str) else x

    if isinstance(e, OSError):  # its message is built from errno, strerror and the file names
        for name in ("filename", "filename2"):
            if isinstance(getattr(e, name), str):
                setattr(e, name, fix(getattr(e, name)))
    elif any(isinstance(a, str) and str(stage) in a for a in e.args):
        e.args = tuple(fix(a) for a in e.args)


def _replace(stage: Path, final: Path) -> None:
    old = None
    if final.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{final.name}.", suffix=".old", dir=final.parent))
        os.rename(final, old / final.name)
    try:
        os.rename(stage, final)
    except BaseException:
        if old is not None:  # put the previous outputs back
            os.rename(old / final.name, final)
        raise
    finally:
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)


@contextlib.contextmanager
def written_then_renamed(p: Path) -> Iterator[Path]:
    """A temporary name beside the file ``p`` to write it under: renamed to ``p`` when the block
    ends, removed if it fails, so ``p`` is never left half-written. It keeps ``p``'s suffix
    (writers pick the format from it) and is unique to the call (writers on several threads)."""
    tmp = p.with_name(f".{p.name}.{os.getpid()}-{secrets.token_hex(4)}.tmp{p.suffix}")
    try:
        yield tmp
        os.replace(tmp, p)
    finally:
        tmp.unlink(missing_ok=True)
