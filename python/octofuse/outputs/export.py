"""Point-cloud exports: information-loss heat maps and occupancy maps as PLY / PCD files.

Every voxel (tree leaf) becomes one point at its centre, with an RGB colour from a
matplotlib colour map and its scalars kept as named float32 per-point fields, so the files
open in Open3D, CloudCompare, MeshLab or PCL and read back into numpy
(:func:`.clouds.read_cloud`). A coarse (pruned) leaf is one point; its edge length is in the
``voxel_size`` field. The files are written and checked by :mod:`.clouds`.

A cloud with no points is refused with ``ValueError``: neither Open3D's PLY nor its PCD
writer stores one, and its PCD reader rejects ``POINTS 0``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..maps.infoloss import InfoLossMap, Leaves, read_info_loss
from ..maps.occupancy import OccupancyMap
from .clouds import CLOUD_SUFFIXES, check_field, cloud_path, write_cloud
from .libraries import pyplot
from .staging import written_then_renamed

MAP_SUFFIXES = (".ot", ".bt")
LOSS_SUFFIX = ".npz"


class ExportResult(NamedTuple):
    """What :func:`export_map` wrote."""

    path: Path  #: the file written
    count: int  #: points of a cloud, leaves of a map
    unit: str  #: "points" or "leaves"
    content: str  #: a short description of the file

    def __str__(self) -> str:
        return f"wrote {self.path}: {self.count:,} {self.unit} ({self.content})"


# -- writing -----------------------------------------------------------------------------
def write_heatmap(
    loss: InfoLossMap | Leaves,
    path: str | os.PathLike,
    *,
    cmap="inferno",
    vmin: float = 0.0,
    vmax: float | None = None,
    field: str = "info_loss",
    min_value: float | None = None,
    map: OccupancyMap | None = None,
    voxels: str | None = None,
    crop=None,
    z_range=None,
    colorbar: str | os.PathLike | None = None,
) -> Path:
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
    p = cloud_path(path)
    check_field(field)
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
        extra = {"log_odds": logodds, "occupancy": occupancy_of(logodds)}
    else:
        if kind != "all":
            raise ValueError(
                f"voxels={kind!r} needs the fused map (map=...) to tell occupied from free voxels"
            )
        values = np.asarray(lv.values, dtype=np.float32).reshape(-1)
        centers = np.asarray(lv.centers, dtype=np.float64).reshape(-1, 3)
        sizes = np.asarray(lv.sizes, dtype=np.float64).reshape(-1)
    keep = np.ones(len(values), bool)
    why = "the information-loss map is empty" if len(values) == 0 else ""
    if (map is not None or given) and len(values) == 0:
        why = (
            f"the map has no {kind} voxel the loss map covers"
            if kind != "all"
            else "the loss map covers no voxel of the map"
        )
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
        write_colorbar(
            colorbar, cmap, lo, hi, label=f"{field} (nats)" if field == "info_loss" else field
        )
    return write_cloud(p, centers, colors, {field: values, **extra, "voxel_size": sizes})


class MapVoxelLoss(NamedTuple):
    """Leaves of a fused map with the loss of the loss voxel at their centres."""

    centers: np.ndarray  #: (N, 3) float64, metres
    sizes: np.ndarray  #: (N,) float64 edge lengths, metres
    log_odds: np.ndarray  #: (N,) float32 of the map
    loss: np.ndarray  #: (N,) float32 information loss, nats


def map_voxel_loss(
    loss: InfoLossMap | Leaves, map: OccupancyMap, voxels: str = "occupied"
) -> MapVoxelLoss:
    """The leaves of ``map`` of the class ``voxels`` ("occupied": log-odds > 0, "free" or
    "all") with the loss at their centres; leaves the loss map does not cover are left out.
    What :func:`write_heatmap` writes with ``map=``."""
    if voxels not in ("occupied", "free", "all"):
        raise ValueError(f"voxels={voxels!r}: expected 'occupied', 'free' or 'all'")
    if isinstance(loss, InfoLossMap):  # one walk in the core, the same lookup as values_at
        ml, values = loss.on_leaves(map, voxels)
        return MapVoxelLoss(ml.centers, ml.sizes, ml.values, values)
    lv = _as_leaves(loss)
    ml = map.leaves(voxels)
    centers, sizes, logodds = ml.centers, ml.sizes, np.asarray(ml.values, dtype=np.float32)
    values = lv.values_at(centers, map.resolution)
    known = np.isfinite(values)
    return MapVoxelLoss(centers[known], sizes[known], logodds[known], values[known])


def shared_color_range(losses, vmin: float = 0.0, percentile: float = 99.0) -> tuple[float, float]:
    """One colour range for the heat maps of several rules: ``vmin`` and the ``percentile`` of
    all their loss values together (the maximum if that is not above ``vmin``). ``losses``:
    loss maps, leaves or :class:`MapVoxelLoss` (the voxels the heat maps show)."""
    vals = [
        np.asarray(
            x.loss if isinstance(x, MapVoxelLoss) else _as_leaves(x).values, dtype=np.float64
        ).reshape(-1)
        for x in losses
    ]
    v = np.concatenate(vals) if vals else np.empty(0)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return float(vmin), float(vmin)
    hi = float(np.percentile(v, percentile))
    if not hi > vmin:
        hi = float(v.max())
    return float(vmin), max(hi, float(vmin))


def write_colorbar(
    path: str | os.PathLike, cmap, vmin: float, vmax: float, label: str = "info_loss"
) -> Path:
    """A horizontal colour bar (PNG) of ``cmap`` over [vmin, vmax], labelled ``label``."""
    p = Path(path)
    if p.suffix.lower() != ".png":
        raise ValueError(f"cannot write colour bar '{p}': expected a .png file name")
    plt = pyplot()
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    fig, ax = plt.subplots(figsize=(5.0, 0.8), dpi=150)
    fig.subplots_adjust(left=0.05, right=0.95, bottom=0.55, top=0.9)
    norm = Normalize(vmin=vmin, vmax=vmax if vmax > vmin else vmin + 1e-12)
    fig.colorbar(
        ScalarMappable(norm=norm, cmap=_colormap(cmap)),
        cax=ax,
        orientation="horizontal",
        label=label,
    )
    try:
        with written_then_renamed(p) as tmp:
            fig.savefig(tmp)
    finally:
        plt.close(fig)
    return p


def _crop_box(crop) -> tuple[np.ndarray, np.ndarray]:
    try:
        lo, hi = (np.asarray(c, dtype=np.float64).reshape(3) for c in crop)
    except (TypeError, ValueError):
        raise ValueError(
            f"crop box {crop!r}: expected ((xmin, ymin, zmin), (xmax, ymax, zmax))"
        ) from None
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


def write_map_cloud(
    m: OccupancyMap,
    path: str | os.PathLike,
    *,
    occupied_only: bool = True,
    threshold: float = 0.0,
    cmap="viridis",
) -> Path:
    """Write an occupancy map as a point cloud coloured by height and return its path.

    One point per leaf with log-odds > ``threshold`` (``occupied_only=False``: every known
    leaf, free ones too), coloured by its z over the [min, max] z of the points written,
    with float32 fields ``log_odds``, ``occupancy`` (probability) and ``voxel_size``, named
    as in the heat maps.
    ``.ply`` or ``.pcd`` as for :func:`write_heatmap`; ``ValueError`` when there is
    nothing to write.
    """
    return _write_map_cloud(m, path, occupied_only, threshold, cmap)[0]


def _write_map_cloud(m, path, occupied_only, threshold, cmap) -> tuple[Path, int]:
    p = cloud_path(path)
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
        why = (
            "the map is empty"
            if m.num_leaves == 0 or not occupied_only
            else f"no voxel has log-odds > {threshold:g}"
        )
        raise ValueError(f"cannot write '{p}': no points to write ({why})")
    z = centers[:, 2]
    colors = colorize(z, cmap, float(z.min()), float(z.max()))
    path = write_cloud(
        p,
        centers,
        colors,
        {"log_odds": logodds, "occupancy": occupancy_of(logodds), "voxel_size": sizes},
    )
    return path, len(logodds)


def occupancy_of(log_odds) -> np.ndarray:
    """The probability of occupancy (float32) of log-odds values: the clouds' ``occupancy``."""
    return (1.0 / (1.0 + np.exp(-np.asarray(log_odds, dtype=np.float64)))).astype(np.float32)


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


# -- the `octofuse export` command -------------------------------------------------------
def export_map(
    src_path: str | os.PathLike,
    out_path: str | os.PathLike,
    *,
    occupied_only: bool = True,
    threshold: float = 0.0,
    cmap: str | None = None,
) -> ExportResult:
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
        raise ValueError(
            f"cannot export to '{out}': expected a point cloud "
            f"({', '.join(CLOUD_SUFFIXES)}) or a map ({', '.join(MAP_SUFFIXES)})"
        )
    if src_suffix == LOSS_SUFFIX:
        if out_suffix in MAP_SUFFIXES:
            raise ValueError(
                f"cannot convert the information-loss file '{src}' to '{out}': "
                f"it is not an occupancy map; write a .ply or .pcd heat map"
            )
        lv = read_info_loss(src)
        path = write_heatmap(lv, out, cmap=cmap or "inferno")
        return ExportResult(path, len(lv.values), "points", "information-loss heat map")
    if src_suffix not in MAP_SUFFIXES:
        raise ValueError(
            f"cannot export '{src}': expected a map ({', '.join(MAP_SUFFIXES)}) "
            f"or an information-loss file ({LOSS_SUFFIX})"
        )
    m = OccupancyMap.load(src)
    if out_suffix in MAP_SUFFIXES:
        path = m.save(out)
        kind = (
            "OctoMap .bt: free/occupied only"
            if out_suffix == ".bt"
            else "OctoMap .ot: full log-odds"
        )
        return ExportResult(path, m.num_leaves, "leaves", kind)
    path, n = _write_map_cloud(m, out, occupied_only, threshold, cmap or "viridis")
    what = "occupied voxels" if occupied_only else "all known voxels"
    return ExportResult(path, n, "points", f"{what} coloured by height")


# -- helpers -----------------------------------------------------------------------------
def _colormap(cmap):
    import matplotlib

    if not isinstance(cmap, str):
        if callable(cmap) and hasattr(cmap, "N"):
            return cmap
        raise TypeError(f"cmap must be a colour map name or a matplotlib Colormap, got {cmap!r}")
    try:
        return matplotlib.colormaps[cmap]
    except KeyError:
        raise ValueError(
            f"unknown colour map {cmap!r}: expected a matplotlib colour map name "
            f"such as viridis, inferno, magma, plasma, cividis or turbo"
        ) from None


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


def _as_leaves(loss) -> Leaves:
    if isinstance(loss, InfoLossMap):
        return loss.leaves()
    if isinstance(loss, Leaves):
        return loss
    raise TypeError(f"expected an InfoLossMap or Leaves, got {type(loss).__name__}")
