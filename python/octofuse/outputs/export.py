"""Point-cloud exports: information-loss heat maps and occupancy maps as PLY / PCD files.

Every voxel (tree leaf) becomes one point at its centre, with an RGB colour from a
matplotlib colour map and its scalars kept as named float32 per-point fields, so the files
open in Open3D, CloudCompare, MeshLab or PCL and read back into numpy (:func:`read_cloud`).
A coarse (pruned) leaf is one point; its edge length is in the ``voxel_size`` field.

Both formats are written by Open3D's tensor I/O (``open3d.t.io.write_point_cloud``), binary:

* ``.ply``: ``binary_little_endian 1.0``, vertex properties ``float x y z``,
  ``uchar red green blue`` and one ``property float NAME`` per field;
* ``.pcd``: PCD v0.7, ``DATA binary``, ``FIELDS x y z rgb NAME...`` with ``x y z`` and the
  fields as ``F 4`` and ``rgb`` packed as PCL does (``U 4``: 0x00RRGGBB).

Positions are float32 (what viewers and PCL's point types use): exact to well under a
millimetre within OctoMap's key range at the usual resolutions.

Files are written to a temporary name in the target folder and renamed, so an existing
file is never left half-written. A cloud with no points is refused with ``ValueError``:
neither Open3D's PLY nor its PCD writer stores one, and its PCD reader rejects ``POINTS 0``.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
import sys
import threading
from pathlib import Path
from typing import Mapping, NamedTuple

import numpy as np

from ..maps.infoloss import InfoLossMap, Leaves, read_info_loss
from ..maps.occupancy import OccupancyMap

CLOUD_SUFFIXES = (".ply", ".pcd")
MAP_SUFFIXES = (".ot", ".bt")
LOSS_SUFFIX = ".npz"

#: per-point names a scalar field may not take: coordinates, colours, normals, the voxel
#: size, and the attributes that make Open3D treat a cloud as Gaussian splats
_RESERVED = frozenset({
    "x", "y", "z", "positions", "colors", "normals", "nx", "ny", "nz", "rgb", "rgba", "red",
    "green", "blue", "alpha", "voxel_size", "scale", "rot", "opacity", "f_dc", "f_rest",
})
_FIELD_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")


class ExportResult(NamedTuple):
    """What :func:`export_map` wrote."""

    path: Path  #: the file written
    count: int  #: points of a cloud, leaves of a map
    unit: str  #: "points" or "leaves"
    content: str  #: a short description of the file

    def __str__(self) -> str:
        return f"wrote {self.path}: {self.count:,} {self.unit} ({self.content})"


# -- writing -----------------------------------------------------------------------------
def write_heatmap(loss: InfoLossMap | Leaves, path: str | os.PathLike, *, cmap="inferno",
                  vmin: float = 0.0, vmax: float | None = None, field: str = "info_loss",
                  min_value: float | None = None, map: OccupancyMap | None = None,
                  voxels: str | None = None, crop=None, z_range=None,
                  colorbar: str | os.PathLike | None = None) -> Path:
    """Write per-voxel information loss as a coloured point cloud and return its path.

    Parameters
    ----------
    loss : InfoLossMap, Leaves or MapVoxelLoss
        The loss map (or any leaves: their ``values`` are the scalar written), or voxels of a
        fused map with their loss (:func:`map_voxel_loss`; ``map`` is then not needed).
    path : path ending in ``.ply`` or ``.pcd``
        Both binary, written by Open3D (see the module notes for the exact layout).
    cmap : str or matplotlib Colormap
        Colour map over [vmin, vmax]; values outside are clipped to its ends.
    vmin, vmax : float
        Colour range. Pass the same range for every rule of a run (:func:`shared_color_range`)
        so that their heat maps compare. ``vmax`` defaults to the 99th percentile of the values
        written, so a few outliers don't squeeze every other voxel into the bottom colours; if
        that percentile is not above ``vmin`` (more than 99 % of the voxels lose nothing, as
        min-info-loss fusion often gives), the maximum is used instead.
    field : str
        Name of the per-point float32 field holding the values (``info_loss``). A
        ``voxel_size`` field (leaf edge length, metres) is always written too.
    min_value : float, optional
        Write only voxels whose value is >= ``min_value`` (e.g. ``1e-9`` to drop the
        voxels that lost nothing). The default colour range is taken over these.
    map : OccupancyMap, optional
        The fused map the loss belongs to. With it, the points are the map's leaves of the
        class ``voxels`` asks for, each with the loss of the loss voxel at its centre (leaves
        the loss map does not cover are left out), and ``log_odds`` and ``occupancy`` fields.
    voxels : "occupied", "free" or "all"
        Which leaves of ``map`` to write: occupied (log-odds > 0: the walls and objects) by
        default when a map is given; without a map only ``"all"`` (every loss voxel) applies.
    crop : ((xmin, ymin, zmin), (xmax, ymax, zmax)), optional
        Keep only voxels whose centre lies in this box (metres).
    z_range : (zmin, zmax), optional
        A height slice: keep only voxels whose centre z lies in [zmin, zmax].
    colorbar : path ending in ``.png``, optional
        Also write a colour bar of the colour map over the range used, labelled with ``field``.

    Raises ``ValueError`` for another suffix, an unknown colour map, ``vmax < vmin``, a
    reserved or malformed field name, a bad ``voxels``, crop box or slice, or when no voxel is
    left to write (the message says which filter emptied it).
    """
    p = _cloud_path(path)
    _check_field(field)
    _colormap(cmap)
    given = isinstance(loss, MapVoxelLoss)  # voxels of a fused map already picked
    lv = None if given else _as_leaves(loss)
    kind = voxels if voxels is not None else ("occupied" if map is not None or given else "all")
    if kind not in ("occupied", "free", "all"):
        raise ValueError(f"voxels={kind!r}: expected 'occupied', 'free' or 'all'")
    extra: dict[str, np.ndarray] = {}
    if given or map is not None:
        mv = loss if given else map_voxel_loss(lv, map, kind)
        centers, sizes, logodds, values = mv.centers, mv.sizes, mv.log_odds, mv.loss
        extra = {"log_odds": logodds,
                 "occupancy": (1.0 / (1.0 + np.exp(-logodds.astype(np.float64)))).astype(np.float32)}
    else:
        if kind != "all":
            raise ValueError(f"voxels={kind!r} needs the fused map (map=...) to tell occupied "
                             "from free voxels")
        values = np.asarray(lv.values, dtype=np.float32).reshape(-1)
        centers = np.asarray(lv.centers, dtype=np.float64).reshape(-1, 3)
        sizes = np.asarray(lv.sizes, dtype=np.float64).reshape(-1)
    keep = np.ones(len(values), bool)
    why = "the information-loss map is empty" if len(values) == 0 else ""
    if (map is not None or given) and len(values) == 0:
        why = f"the map has no {kind} voxel the loss map covers" if kind != "all" else \
            "the loss map covers no voxel of the map"
    if crop is not None:
        lo, hi = _crop_box(crop)
        keep &= np.all((centers >= lo) & (centers <= hi), axis=1)
        if len(values) and not keep.any():
            why = f"the crop box {lo.tolist()}..{hi.tolist()} holds no voxel"
    if z_range is not None:
        z0, z1 = _z_range(z_range)
        before = keep.any()
        keep &= (centers[:, 2] >= z0) & (centers[:, 2] <= z1)
        if before and not keep.any():
            why = f"the height slice z in [{z0:g}, {z1:g}] holds no voxel"
    if min_value is not None:
        before = keep.any()
        keep &= values >= np.float32(min_value)
        if before and not keep.any():
            why = f"no voxel has {field} >= {min_value:g}"
    if not keep.any():
        raise ValueError(f"cannot write '{p}': no points to write ({why})")
    values, centers, sizes = values[keep], centers[keep], sizes[keep]
    extra = {k: v[keep] for k, v in extra.items()}
    lo, hi = _color_range(values, vmin, vmax)
    colors = colorize(values, cmap, lo, hi)
    if colorbar is not None:
        write_colorbar(colorbar, cmap, lo, hi, label=f"{field} (nats)" if field == "info_loss"
                       else field)
    return _write_cloud(p, centers, colors, {field: values, **extra, "voxel_size": sizes})


class MapVoxelLoss(NamedTuple):
    """Leaves of a fused map with the loss of the loss voxel at their centres."""

    centers: np.ndarray  #: (N, 3) float64, metres
    sizes: np.ndarray  #: (N,) float64 edge lengths, metres
    log_odds: np.ndarray  #: (N,) float32 of the map
    loss: np.ndarray  #: (N,) float32 information loss, nats


def map_voxel_loss(loss: InfoLossMap | Leaves, map: OccupancyMap,
                   voxels: str = "occupied") -> MapVoxelLoss:
    """The leaves of ``map`` of the class ``voxels`` ("occupied": log-odds > 0, "free" or
    "all") with the loss at their centres; leaves the loss map does not cover are left out.
    What :func:`write_heatmap` writes with ``map=``."""
    if voxels not in ("occupied", "free", "all"):
        raise ValueError(f"voxels={voxels!r}: expected 'occupied', 'free' or 'all'")
    if isinstance(loss, InfoLossMap):  # one walk in the core, the same lookup as values_at
        ml, values = loss.on_leaves(map, voxels)
        return MapVoxelLoss(ml.centers, ml.sizes, ml.values, values)
    lv = _as_leaves(loss)
    ml = map.leaves()
    logodds = np.asarray(ml.values, dtype=np.float32)
    sel = (logodds > 0 if voxels == "occupied" else logodds <= 0 if voxels == "free"
           else np.ones(len(logodds), bool))
    centers, sizes, logodds = ml.centers[sel], ml.sizes[sel], logodds[sel]
    values = lv.values_at(centers, map.resolution)
    known = np.isfinite(values)
    return MapVoxelLoss(centers[known], sizes[known], logodds[known], values[known])


def shared_color_range(losses, vmin: float = 0.0, percentile: float = 99.0) -> tuple[float, float]:
    """One colour range for the heat maps of several rules: ``vmin`` and the ``percentile`` of
    all their loss values together (the maximum if that is not above ``vmin``). ``losses``:
    loss maps, leaves or :class:`MapVoxelLoss` (the voxels the heat maps show)."""
    vals = [np.asarray(x.loss if isinstance(x, MapVoxelLoss) else _as_leaves(x).values,
                       dtype=np.float64).reshape(-1) for x in losses]
    v = np.concatenate(vals) if vals else np.empty(0)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return float(vmin), float(vmin)
    hi = float(np.percentile(v, percentile))
    if not hi > vmin:
        hi = float(v.max())
    return float(vmin), max(hi, float(vmin))


def write_colorbar(path: str | os.PathLike, cmap, vmin: float, vmax: float,
                   label: str = "info_loss") -> Path:
    """A horizontal colour bar (PNG) of ``cmap`` over [vmin, vmax], labelled ``label``."""
    p = Path(path)
    if p.suffix.lower() != ".png":
        raise ValueError(f"cannot write colour bar '{p}': expected a .png file name")
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.colors import Normalize

    fig, ax = plt.subplots(figsize=(5.0, 0.8), dpi=150)
    fig.subplots_adjust(left=0.05, right=0.95, bottom=0.55, top=0.9)
    norm = Normalize(vmin=vmin, vmax=vmax if vmax > vmin else vmin + 1e-12)
    fig.colorbar(matplotlib.cm.ScalarMappable(norm=norm, cmap=_colormap(cmap)), cax=ax,
                 orientation="horizontal", label=label)
    tmp = p.with_name(f".{p.name}.{os.getpid()}-{secrets.token_hex(4)}.tmp.png")
    try:
        fig.savefig(tmp)
        os.replace(tmp, p)
    finally:
        plt.close(fig)
        tmp.unlink(missing_ok=True)
    return p


def _crop_box(crop) -> tuple[np.ndarray, np.ndarray]:
    try:
        lo, hi = (np.asarray(c, dtype=np.float64).reshape(3) for c in crop)
    except (TypeError, ValueError):
        raise ValueError(f"crop box {crop!r}: expected ((xmin, ymin, zmin), (xmax, ymax, zmax))") \
            from None
    if not (np.isfinite(lo).all() and np.isfinite(hi).all()) or (lo > hi).any():
        raise ValueError(f"crop box {lo.tolist()}..{hi.tolist()} is empty or not finite")
    return lo, hi


def _z_range(z_range) -> tuple[float, float]:
    try:
        z0, z1 = (float(z) for z in z_range)
    except (TypeError, ValueError):
        raise ValueError(f"height slice {z_range!r}: expected (zmin, zmax)") from None
    if not (np.isfinite(z0) and np.isfinite(z1)) or z0 > z1:
        raise ValueError(f"height slice [{z0:g}, {z1:g}] is empty or not finite")
    return z0, z1


def write_map_cloud(m: OccupancyMap, path: str | os.PathLike, *, occupied_only: bool = True,
                    threshold: float = 0.0, cmap="viridis") -> Path:
    """Write an occupancy map as a point cloud coloured by height and return its path.

    One point per leaf with log-odds > ``threshold`` (``occupied_only=False``: every known
    leaf, free ones too), coloured by its z over the [min, max] z of the points written,
    with float32 fields ``log_odds``, ``probability`` (of occupancy) and ``voxel_size``.
    ``.ply`` or ``.pcd`` as for :func:`write_heatmap`; ``ValueError`` when there is
    nothing to write.
    """
    return _write_map_cloud(m, path, occupied_only, threshold, cmap)[0]


def _write_map_cloud(m, path, occupied_only, threshold, cmap) -> tuple[Path, int]:
    p = _cloud_path(path)
    if not isinstance(m, OccupancyMap):
        raise TypeError(f"write_map_cloud expects an OccupancyMap, got {type(m).__name__}")
    _colormap(cmap)
    lv = m.leaves()
    logodds = np.asarray(lv.values, dtype=np.float32)
    centers, sizes = lv.centers, lv.sizes
    if occupied_only:
        keep = logodds > np.float32(threshold)
        logodds, centers, sizes = logodds[keep], centers[keep], sizes[keep]
    if logodds.size == 0:
        why = ("the map is empty" if m.num_leaves == 0 or not occupied_only
               else f"no voxel has log-odds > {threshold:g}")
        raise ValueError(f"cannot write '{p}': no points to write ({why})")
    prob = 1.0 / (1.0 + np.exp(-logodds.astype(np.float64)))
    z = centers[:, 2]
    colors = colorize(z, cmap, float(z.min()), float(z.max()))
    path = _write_cloud(p, centers, colors,
                        {"log_odds": logodds, "probability": prob, "voxel_size": sizes})
    return path, len(logodds)


def colorize(values, cmap, vmin: float, vmax: float) -> np.ndarray:
    """RGB colours (N, 3) uint8 of ``values`` through a colour map over [vmin, vmax].

    Values are clipped to the range; if ``vmax == vmin`` every value above it takes the top
    colour and the rest the bottom one. NaN takes the map's "bad" colour.
    """
    cm = _colormap(cmap)
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    if vmax > vmin:
        t = np.clip((v - vmin) / (vmax - vmin), 0.0, 1.0)
    else:
        t = np.where(np.isnan(v), np.nan, (v > vmin).astype(np.float64))
    return np.ascontiguousarray(cm(t, bytes=True)[:, :3])


# -- reading -----------------------------------------------------------------------------
def read_cloud(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read a ``.ply`` or ``.pcd`` point cloud into numpy arrays.

    Returns ``positions`` (N, 3), ``colors`` (N, 3) as floats in [0, 1] (when the file has
    colours) and every other per-point field by name, one-column fields as 1-D arrays, in
    the file's own dtypes (float32 for the files this module writes). Raises
    ``FileNotFoundError`` for a missing file and ``OSError`` for one Open3D cannot read.
    """
    p = _cloud_path(path, verb="read")
    if not p.exists():
        raise FileNotFoundError(f"point cloud '{p}' does not exist")
    if p.is_dir():
        raise IsADirectoryError(f"point cloud '{p}' is a directory")
    _check_ply_length(p)
    o3d = _open3d()
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


# -- the `octofuse export` command -------------------------------------------------------
def export_map(src_path: str | os.PathLike, out_path: str | os.PathLike, *,
               occupied_only: bool = True, threshold: float = 0.0,
               cmap: str | None = None) -> ExportResult:
    """Convert a map or an information-loss file; what ``octofuse export`` runs.

    ``src_path``: an OctoMap file (``.ot``/``.bt``) or an information-loss ``.npz``.
    ``out_path``: ``.ply``/``.pcd`` writes a map cloud (:func:`write_map_cloud`, with
    ``occupied_only`` and ``threshold``) or, for a loss file, a heat map
    (:func:`write_heatmap`; ``occupied_only`` and ``threshold`` don't apply); ``.ot``/``.bt``
    converts a map (``.bt`` keeps only free/occupied, see :meth:`OccupancyMap.save`).
    ``cmap`` defaults to viridis for maps and inferno for heat maps.

    Raises ``ValueError`` for unknown suffixes or a loss file to ``.ot``/``.bt``, and
    ``OSError`` (``FileNotFoundError``, ``MapFileError``) for missing or unreadable input.
    """
    src, out = Path(src_path), Path(out_path)
    out_suffix, src_suffix = out.suffix, src.suffix
    if out_suffix not in CLOUD_SUFFIXES + MAP_SUFFIXES:
        raise ValueError(f"cannot export to '{out}': expected a point cloud "
                         f"({', '.join(CLOUD_SUFFIXES)}) or a map ({', '.join(MAP_SUFFIXES)})")
    if src_suffix == LOSS_SUFFIX:
        if out_suffix in MAP_SUFFIXES:
            raise ValueError(f"cannot convert the information-loss file '{src}' to '{out}': "
                             f"it is not an occupancy map; write a .ply or .pcd heat map")
        lv = read_info_loss(src)
        path = write_heatmap(lv, out, cmap=cmap or "inferno")
        return ExportResult(path, len(lv.values), "points", "information-loss heat map")
    if src_suffix not in MAP_SUFFIXES:
        raise ValueError(f"cannot export '{src}': expected a map ({', '.join(MAP_SUFFIXES)}) "
                         f"or an information-loss file ({LOSS_SUFFIX})")
    m = OccupancyMap.load(src)
    if out_suffix in MAP_SUFFIXES:
        path = m.save(out)
        kind = ("OctoMap .bt: free/occupied only" if out_suffix == ".bt"
                else "OctoMap .ot: full log-odds")
        return ExportResult(path, m.num_leaves, "leaves", kind)
    path, n = _write_map_cloud(m, out, occupied_only, threshold, cmap or "viridis")
    what = "occupied voxels" if occupied_only else "all known voxels"
    return ExportResult(path, n, "points", f"{what} coloured by height")


# -- helpers -----------------------------------------------------------------------------
def _open3d():
    import open3d  # slow (about a second): imported only when a cloud is written or read

    return open3d


def _colormap(cmap):
    import matplotlib

    if not isinstance(cmap, str):
        if callable(cmap) and hasattr(cmap, "N"):
            return cmap
        raise TypeError(f"cmap must be a colour map name or a matplotlib Colormap, got {cmap!r}")
    try:
        return matplotlib.colormaps[cmap]
    except KeyError:
        raise ValueError(f"unknown colour map {cmap!r}: expected a matplotlib colour map name "
                         f"such as viridis, inferno, magma, plasma, cividis or turbo") from None


def _color_range(values: np.ndarray, vmin: float, vmax: float | None) -> tuple[float, float]:
    vmin = float(vmin)
    if vmax is None:
        finite = values[np.isfinite(values)]
        if finite.size == 0:
            return vmin, vmin
        vmax = float(np.percentile(finite, 99))
        if not vmax > vmin:
            vmax = float(finite.max())
        return vmin, max(vmax, vmin)
    vmax = float(vmax)
    if vmax < vmin:
        raise ValueError(f"colour range vmin={vmin:g} > vmax={vmax:g}")
    return vmin, vmax


def _check_field(name: str) -> None:
    if not isinstance(name, str) or not _FIELD_NAME.match(name):
        raise ValueError(f"field name {name!r}: expected letters, digits and underscores")
    if name in _RESERVED:
        raise ValueError(f"field name {name!r} is reserved (coordinates, colours, voxel_size "
                         f"and Open3D's Gaussian-splat attributes)")


def _as_leaves(loss) -> Leaves:
    if isinstance(loss, InfoLossMap):
        return loss.leaves()
    if isinstance(loss, Leaves):
        return loss
    raise TypeError(f"expected an InfoLossMap or Leaves, got {type(loss).__name__}")


def _cloud_path(path, verb: str = "write") -> Path:
    p = Path(path)
    if p.suffix not in CLOUD_SUFFIXES:
        raise ValueError(f"cannot {verb} point cloud '{p}': expected a file name ending in "
                         f"{' or '.join(CLOUD_SUFFIXES)}")
    return p


_PLY_SIZES = {"char": 1, "int8": 1, "uchar": 1, "uint8": 1, "short": 2, "int16": 2,
              "ushort": 2, "uint16": 2, "int": 4, "int32": 4, "uint": 4, "uint32": 4,
              "float": 4, "float32": 4, "double": 8, "float64": 8}


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
        raise OSError(f"cannot read point cloud '{p}': truncated ({found[1]:,} of {found[2]:,} "
                      f"data bytes)")


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
        raise OSError(f"could not write point cloud '{p}': the file holds {have:,} of {need:,} "
                      f"data bytes for {points:,} of {n:,} points (disk full or write error?)")


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


def _write_cloud(p: Path, centers: np.ndarray, colors: np.ndarray,
                 fields: Mapping[str, np.ndarray]) -> Path:
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
        raise ValueError(f"cannot write '{p}': voxel coordinates beyond the float32 range of "
                         f"point clouds (largest {np.abs(np.asarray(centers)).max():.3g} m)")
    o3d = _open3d()
    o3c = o3d.core
    pcd = o3d.t.geometry.PointCloud()
    pcd.point["positions"] = o3c.Tensor.from_numpy(
        np.ascontiguousarray(pos32))
    pcd.point["colors"] = o3c.Tensor.from_numpy(np.ascontiguousarray(colors, dtype=np.uint8))
    for name, values in fields.items():
        pcd.point[name] = o3c.Tensor.from_numpy(
            np.ascontiguousarray(values, dtype=np.float32).reshape(n, 1))
    # the writer picks the format from the suffix, so the temporary name keeps it
    tmp = folder / f".{p.name}.{os.getpid()}-{secrets.token_hex(4)}.tmp{p.suffix}"
    try:
        with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error), \
                _quiet_stderr():
            ok = o3d.t.io.write_point_cloud(str(tmp), pcd, write_ascii=False, compressed=False,
                                            print_progress=False)
        if not ok:
            raise OSError(f"could not write point cloud '{p}' (disk full or folder not writable?)")
        _check_written(tmp, p, n)
        os.replace(tmp, p)
    finally:
        tmp.unlink(missing_ok=True)
    return p
