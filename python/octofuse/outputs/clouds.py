"""Point-cloud files (PLY, PCD): written through Open3D, checked, and read back into numpy.

Both formats are written by Open3D's tensor I/O (``open3d.t.io.write_point_cloud``), binary:

* ``.ply``: ``binary_little_endian 1.0``, vertex properties ``float x y z``,
  ``uchar red green blue`` and one ``property float NAME`` per field;
* ``.pcd``: PCD v0.7, ``DATA binary``, ``FIELDS x y z rgb NAME...`` with ``x y z`` and the
  fields as ``F 4`` and ``rgb`` packed as PCL does (``U 4``: 0x00RRGGBB).

Positions are float32 (what viewers and PCL's point types use): exact to well under a
millimetre within OctoMap's key range at the usual resolutions.

Files are written to a temporary name in the target folder, checked for their full length and
renamed, so an existing file is never left half-written.
"""

from __future__ import annotations

import contextlib
import os
import re
import sys
import threading
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from .libraries import open3d
from .staging import written_then_renamed

CLOUD_SUFFIXES = (".ply", ".pcd")

#: per-point names a scalar field may not take: coordinates, colours, normals, the voxel
#: size, and the attributes that make Open3D treat a cloud as Gaussian splats
_RESERVED = frozenset(
    {
        "x",
        "y",
        "z",
        "positions",
        "colors",
        "normals",
        "nx",
        "ny",
        "nz",
        "rgb",
        "rgba",
        "red",
        "green",
        "blue",
        "alpha",
        "voxel_size",
        "scale",
        "rot",
        "opacity",
        "f_dc",
        "f_rest",
    }
)
_FIELD_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")


# -- reading -----------------------------------------------------------------------------
def read_cloud(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read a ``.ply`` or ``.pcd`` point cloud into numpy arrays.

    Returns ``positions`` (N, 3), ``colors`` (N, 3) as floats in [0, 1] (when the file has
    colours) and every other per-point field by name, one-column fields as 1-D arrays, in
    the file's own dtypes (float32 for the files this module writes). Raises
    ``FileNotFoundError`` for a missing file and ``OSError`` for one Open3D cannot read.
    """
    p = cloud_path(path, verb="read")
    if not p.exists():
        raise FileNotFoundError(f"point cloud '{p}' does not exist")
    if p.is_dir():
        raise IsADirectoryError(f"point cloud '{p}' is a directory")
    _check_ply_length(p)
    o3d = open3d()
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        pcd = o3d.t.io.read_point_cloud(str(p))
    names = set(pcd.point)
    if "positions" not in names:
        raise OSError(f"cannot read point cloud '{p}': not a valid {p.suffix} file")
    out = {"positions": pcd.point["positions"].numpy()}
    if "colors" in names:
        c = pcd.point["colors"].numpy()
        if np.issubdtype(c.dtype, np.integer):
            c = c.astype(np.float32) / np.float32(np.iinfo(c.dtype).max)
        out["colors"] = c
    for name in sorted(names - {"positions", "colors"}):
        a = pcd.point[name].numpy()
        out[name] = a.reshape(-1) if a.ndim == 2 and a.shape[1] == 1 else a
    return out


def check_field(name: str) -> None:
    """Raise ``ValueError`` unless ``name`` can be a per-point field of a cloud."""
    if not isinstance(name, str) or not _FIELD_NAME.match(name):
        raise ValueError(f"field name {name!r}: expected letters, digits and underscores")
    if name in _RESERVED:
        raise ValueError(
            f"field name {name!r} is reserved (coordinates, colours, voxel_size "
            f"and Open3D's Gaussian-splat attributes)"
        )


def cloud_path(path, verb: str = "write") -> Path:
    """``path`` as a Path, if it names a cloud file (``ValueError`` otherwise)."""
    p = Path(path)
    if p.suffix not in CLOUD_SUFFIXES:
        raise ValueError(
            f"cannot {verb} point cloud '{p}': expected a file name ending in "
            f"{' or '.join(CLOUD_SUFFIXES)}"
        )
    return p


_PLY_SIZES = {
    "char": 1,
    "int8": 1,
    "uchar": 1,
    "uint8": 1,
    "short": 2,
    "int16": 2,
    "ushort": 2,
    "uint16": 2,
    "int": 4,
    "int32": 4,
    "uint": 4,
    "uint32": 4,
    "float": 4,
    "float32": 4,
    "double": 8,
    "float64": 8,
}


def _ply_layout(head: bytes, end: int) -> tuple[int, int] | None:
    """(points, data bytes) a binary PLY header declares, ``None`` if not fixed-size binary."""
    body = head[:end].decode("ascii", "replace").splitlines()
    if not any(line.startswith("format binary") for line in body):
        return None
    need, count, points = 0, 0, 0
    for line in body:
        w = line.split()
        if w and w[0] == "element" and len(w) == 3:
            count = int(w[2]) if w[2].isdigit() else 0
            if w[1] == "vertex":
                points = count
        elif w and w[0] == "property":
            if len(w) != 3 or w[1] not in _PLY_SIZES:
                return None  # list properties: no fixed record size
            need += count * _PLY_SIZES[w[1]]
    return points, need


def _pcd_layout(head: bytes, end: int) -> tuple[int, int] | None:
    """(points, data bytes) a binary PCD header declares, ``None`` if not uncompressed binary."""
    fields: dict[str, list[str]] = {}
    for line in head[:end].decode("ascii", "replace").splitlines():
        w = line.split()
        if w and not w[0].startswith("#"):
            fields[w[0].upper()] = w[1:]
    if fields.get("DATA", [""])[0] != "binary":
        return None
    try:
        sizes = [int(x) for x in fields["SIZE"]]
        counts = [int(x) for x in fields.get("COUNT", ["1"] * len(sizes))]
        points = int(fields["POINTS"][0])
    except (KeyError, IndexError, ValueError):
        return None
    return points, points * sum(a * b for a, b in zip(sizes, counts))


def _cloud_data(p: Path) -> tuple[int, int, int] | None:
    """(points declared, data bytes present, data bytes needed) of a binary PLY/PCD file."""
    with open(p, "rb") as fh:
        head = fh.read(65536)
    if head.startswith(b"ply"):
        end = head.find(b"end_header")
        layout = _ply_layout(head, end) if end >= 0 else None
    else:
        end = head.find(b"\nDATA ")
        layout = _pcd_layout(head, head.find(b"\n", end + 1)) if end >= 0 else None
    if layout is None:
        return None  # Open3D's reader reports it
    nl = head.find(b"\n", end + 1)
    data_start = (nl + 1) if nl >= 0 else len(head)
    return layout[0], p.stat().st_size - data_start, layout[1]


def _check_ply_length(p: Path) -> None:
    """Refuse a truncated binary PLY or PCD (Open3D's reader fills missing points silently)."""
    found = _cloud_data(p)
    if found is not None and found[1] < found[2]:
        raise OSError(
            f"cannot read point cloud '{p}': truncated ({found[1]:,} of {found[2]:,} data bytes)"
        )


def _check_written(tmp: Path, p: Path, n: int) -> None:
    """Verify a file Open3D says it wrote (its writers report success on write errors)."""
    try:
        found = _cloud_data(tmp)
    except OSError as err:
        raise OSError(f"could not write point cloud '{p}': {err.strerror or err}") from None
    if found is None:
        raise OSError(f"could not write point cloud '{p}': the written file has no valid header")
    points, have, need = found
    if points != n or have != need:
        raise OSError(
            f"could not write point cloud '{p}': the file holds {have:,} of {need:,} "
            f"data bytes for {points:,} of {n:,} points (disk full or write error?)"
        )


class _QuietStderr:
    """Silences the C writers' own messages on fd 2 (RPly prints one per failed write); the
    result is checked and reported by the caller. fd 2 belongs to the process, so writers on
    several threads share one silence: the first to enter redirects it, the last to leave
    restores it."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._users = 0
        self._saved = None

    @contextlib.contextmanager
    def __call__(self):
        with self._lock:
            if self._users == 0:
                self._saved = self._redirect()
            self._users += 1
        try:
            yield
        finally:
            with self._lock:
                self._users -= 1
                if self._users == 0 and self._saved is not None:
                    os.dup2(self._saved, 2)
                    os.close(self._saved)
                    self._saved = None

    @staticmethod
    def _redirect():
        """fd 2 pointed at the null device; the saved fd 2 (None if fd 2 cannot be saved)."""
        try:
            sys.stderr.flush()
            saved = os.dup(2)
        except (OSError, ValueError):
            return None
        try:
            null = os.open(os.devnull, os.O_WRONLY)
        except OSError:
            os.close(saved)
            return None
        os.dup2(null, 2)
        os.close(null)
        return saved


_quiet_stderr = _QuietStderr()


def write_cloud(
    p: Path, centers: np.ndarray, colors: np.ndarray, fields: Mapping[str, np.ndarray]
) -> Path:
    """Write one binary cloud through a temporary file in the same folder."""
    folder = p.parent
    if not folder.is_dir():
        raise FileNotFoundError(f"cannot write '{p}': folder '{folder}' does not exist")
    if p.is_dir():
        raise IsADirectoryError(f"cannot write '{p}': it is a directory")
    n = len(centers)
    pos32 = np.asarray(centers, dtype=np.float64).reshape(n, 3)
    with np.errstate(over="ignore"):
        pos32 = pos32.astype(np.float32)
    if not np.isfinite(pos32).all():
        raise ValueError(
            f"cannot write '{p}': voxel coordinates beyond the float32 range of "
            f"point clouds (largest {np.abs(np.asarray(centers)).max():.3g} m)"
        )
    o3d = open3d()
    o3c = o3d.core
    pcd = o3d.t.geometry.PointCloud()
    pcd.point["positions"] = o3c.Tensor.from_numpy(np.ascontiguousarray(pos32))
    pcd.point["colors"] = o3c.Tensor.from_numpy(np.ascontiguousarray(colors, dtype=np.uint8))
    for name, values in fields.items():
        pcd.point[name] = o3c.Tensor.from_numpy(
            np.ascontiguousarray(values, dtype=np.float32).reshape(n, 1)
        )
    with written_then_renamed(p) as tmp:
        with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error), _quiet_stderr():
            ok = o3d.t.io.write_point_cloud(
                str(tmp), pcd, write_ascii=False, compressed=False, print_progress=False
            )
        if not ok:
            raise OSError(f"could not write point cloud '{p}' (disk full or folder not writable?)")
        _check_written(tmp, p, n)
    return p
