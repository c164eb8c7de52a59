"""All-or-nothing outputs: a command writes into a fresh folder or file beside ``--out`` (named
``.NAME.PID-XXXX.partial``) and puts it in place only when everything is written.

A failed or interrupted command leaves the previous outputs exactly as they were. An existing
``--out`` folder is replaced whole (no stale files of an earlier run stay beside new ones) if
octofuse wrote it or it is empty; any other folder is refused, so a typo never deletes data.
What a killed run left beside an output (its ``.partial`` names, or the earlier output moved
aside for the rename) is removed, or put back, by the next command writing that output.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
import shutil
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

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
            raise ValueError(
                f"--out '{p}' is a folder that octofuse did not write; refusing to "
                "replace it (give a new or empty folder)"
            )
    return p


def _prefix(final: Path) -> str:
    return f".{final.name}.{os.getpid()}-"


def partial_path(final: Path, suffix: str = "") -> Path:
    """A new name beside ``final`` to write it under, ``suffix`` kept (writers pick the format
    from it); :func:`clean_leftovers` knows it."""
    return final.with_name(f"{_prefix(final)}{secrets.token_hex(4)}.partial{suffix}")


def clean_leftovers(final: str | os.PathLike) -> list[Path]:
    """Remove what killed octofuse processes left beside ``final``: names ``.NAME.PID-*.partial*``
    (and those of files written under such a name) of processes no longer running; the
    earlier output a killed rename had moved aside (``.NAME.*.old``) is put back if ``final`` is
    missing, else removed. Returns the paths removed."""
    final = Path(final).absolute()
    # NAME, then the writer's pid and a random part without dots: '.demo.PID-x.partial' is
    # demo's, '.demo.mcap.PID-x.partial' is demo.mcap's
    pattern = re.compile(r"\.+" + re.escape(final.name) + r"\.(?:(\d+)-)?\w+\.(partial|old)")
    removed = []
    try:
        entries = list(final.parent.iterdir())
    except OSError:
        return removed
    for p in entries:
        m = pattern.match(p.name)
        if m is None or (m.group(1) and _running(int(m.group(1)))):
            continue
        if (
            m.group(2) == "old"
            and (p / final.name).exists()
            and not (final.exists() or final.is_symlink())
        ):
            os.rename(p / final.name, final)
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)
        removed.append(p)
    return removed


def _running(pid: int) -> bool:
    if pid == os.getpid():
        return True  # this process may still be writing it
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's process
        return True
    return True


def put_in_place(*moves: Callable[[], None]) -> None:
    """Run ``moves`` (the renames that put a command's outputs in place) as one step an
    interruption does not cut: a Ctrl-C or SIGTERM before it keeps every earlier output, one
    during or after it is ignored (the command is done)."""
    with held():  # the old outputs or the new ones in place, never neither
        raise_if_interrupted()  # a Ctrl-C swallowed on its way keeps the old outputs too
        for move in moves:
            move()
        outputs_in_place()


@contextlib.contextmanager
def staged_folder(
    out: str | os.PathLike, command: str, also: tuple[Callable[[], None], ...] = ()
) -> Iterator[Path]:
    """Yield a fresh folder to write into; on success it replaces ``out`` in one rename, and the
    renames ``also`` (other outputs of the command, such as a bag) run first in the same step."""
    final = check_replaceable(out).absolute()
    final.parent.mkdir(parents=True, exist_ok=True)
    clean_leftovers(final)
    stage = Path(tempfile.mkdtemp(prefix=_prefix(final), suffix=".partial", dir=final.parent))
    try:
        yield stage
        (stage / MARKER).write_text(f"written by octofuse {command}\n")
        put_in_place(*also, lambda: _replace(stage, final))
    except BaseException as e:
        shutil.rmtree(stage, ignore_errors=True)
        _name_final_paths(e, stage, final)
        raise


@contextlib.contextmanager
def staged_file(
    out: str | os.PathLike, also: tuple[Callable[[], None], ...] = ()
) -> Iterator[Path]:
    """Yield a new name beside the file ``out`` (its suffix kept) to write it under; on success
    it replaces ``out`` in one rename (:func:`put_in_place`, after the renames ``also``), on
    failure or interruption it is removed and ``out`` is left as it was."""
    final = Path(out).absolute()
    final.parent.mkdir(parents=True, exist_ok=True)
    clean_leftovers(final)
    tmp = partial_path(final, final.suffix)
    try:
        yield tmp
        put_in_place(*also, lambda: os.replace(tmp, final))
    except BaseException as e:
        _name_final_paths(e, tmp, final)
        raise
    finally:
        tmp.unlink(missing_ok=True)


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
        old = Path(tempfile.mkdtemp(prefix=_prefix(final), suffix=".old", dir=final.parent))
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
    tmp = partial_path(p, p.suffix)
    try:
        yield tmp
        os.replace(tmp, p)
    finally:
        tmp.unlink(missing_ok=True)
