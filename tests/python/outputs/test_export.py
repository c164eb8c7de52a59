"""Point-cloud exports: heat maps and map clouds written, read back, and the export command."""

import os

import matplotlib
import numpy as np
import open3d as o3d
import pytest

import octofuse
from conftest import random_map
from octofuse.cli import main
from octofuse.outputs import export
from octofuse.outputs.clouds import read_cloud
from octofuse.outputs.export import write_heatmap, write_map_cloud

SUFFIXES = [".ply", ".pcd"]


@pytest.fixture(scope="module")
def maps():
    return random_map(1, 6), random_map(2, 2, offset=(0.35, 0.1, 0.0))


@pytest.fixture(scope="module")
def loss(maps):
    a, b = maps
    info = octofuse.fuse_maps(a, b, rule="chernoff", unknown="prior").info_loss
    assert info.num_leaves > 100
    return info


def header(path):
    with open(path, "rb") as fh:
        data = fh.read()
    end = data.find(b"end_header") if path.suffix == ".ply" else data.find(b"DATA")
    assert end > 0
    return data[:end].decode("ascii")


def lut_index(colors, cmap):
    """Position in the colour map's table of each (N, 3) colour in [0, 1]."""
    lut = matplotlib.colormaps[cmap](np.arange(256), bytes=True)[:, :3].astype(np.int32)
    rgb = np.rint(np.asarray(colors) * 255).astype(np.int32)
    d = np.abs(rgb[:, None, :] - lut[None, :, :]).sum(-1)
    assert np.all(d.min(axis=1) == 0), "every colour is an entry of the colour map"
    return d.argmin(axis=1)


def no_temporaries(folder):
    return [f for f in os.listdir(folder) if ".tmp" in f] == []


# -- heat maps ---------------------------------------------------------------------------
@pytest.mark.parametrize("suffix", SUFFIXES)
def test_heatmap_reads_back_exactly(loss, tmp_path, suffix):
    lv = loss.leaves()
    p = write_heatmap(loss, tmp_path / f"loss{suffix}")  # InfoLossMap.save writes only .npz
    c = read_cloud(p)
    assert set(c) == {"positions", "colors", "info_loss", "voxel_size"}
    n = loss.num_leaves
    assert c["positions"].shape == (n, 3) and c["colors"].shape == (n, 3)
    np.testing.assert_array_equal(c["positions"], lv.centers.astype(np.float32))
    np.testing.assert_allclose(c["positions"], lv.centers, atol=1e-5)
    assert c["info_loss"].dtype == np.float32
    np.testing.assert_array_equal(c["info_loss"], lv.values)
    np.testing.assert_array_equal(c["voxel_size"], lv.sizes.astype(np.float32))
    assert c["colors"].dtype == np.float32
    assert c["colors"].min() >= 0.0 and c["colors"].max() <= 1.0
    assert no_temporaries(tmp_path)


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_heatmap_opens_in_open3d_with_its_fields(loss, tmp_path, suffix):
    lv = loss.leaves()
    p = write_heatmap(loss, tmp_path / f"h{suffix}")
    text = header(p)
    if suffix == ".ply":
        assert "format binary_little_endian 1.0" in text
        assert "property float info_loss" in text and "property float voxel_size" in text
        assert "property uchar red" in text
    else:
        assert "VERSION 0.7" in text
        fields = next(line for line in text.splitlines() if line.startswith("FIELDS")).split()
        assert fields[:5] == ["FIELDS", "x", "y", "z", "rgb"]
        assert {"info_loss", "voxel_size"} <= set(fields)
        assert b"\nDATA binary\n" in p.read_bytes()[:4096]
    pcd = o3d.t.io.read_point_cloud(str(p))
    np.testing.assert_array_equal(pcd.point["positions"].numpy(), lv.centers.astype(np.float32))
    np.testing.assert_array_equal(pcd.point["info_loss"].numpy().ravel(), lv.values)
    np.testing.assert_array_equal(
        pcd.point["voxel_size"].numpy().ravel(), lv.sizes.astype(np.float32)
    )
    legacy = o3d.io.read_point_cloud(str(p))  # the classic reader: positions and colours
    assert len(legacy.points) == loss.num_leaves and legacy.has_colors()
    np.testing.assert_allclose(np.asarray(legacy.colors), read_cloud(p)["colors"], atol=1e-6)


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_heatmap_colours_rise_with_the_loss(loss, tmp_path, suffix):
    values = loss.leaves().values
    c = read_cloud(write_heatmap(loss, tmp_path / f"h{suffix}"))
    idx = lut_index(c["colors"], "inferno")
    order = np.argsort(c["info_loss"], kind="stable")
    assert np.all(np.diff(idx[order]) >= 0), "higher loss never gets a lower colour"
    # default range [0, 99th percentile]: the top 1 % saturate, the rest spread below
    p99 = np.percentile(values, 99)
    assert np.all(idx[values >= p99] == 255)
    assert idx[values < p99].max() < 255 and len(np.unique(idx)) > 50
    want = np.clip(np.floor(values.astype(np.float64) / p99 * 256), 0, 255)
    assert np.abs(idx - want).max() <= 1


def test_heatmap_colour_range_and_filter(loss, tmp_path):
    lv = loss.leaves()
    vmax = float(np.median(lv.values))
    c = read_cloud(write_heatmap(loss, tmp_path / "h.ply", cmap="viridis", vmax=vmax))
    idx = lut_index(c["colors"], "viridis")
    assert np.all(idx[lv.values >= vmax] == 255)
    assert np.all(idx[lv.values < vmax * 255 / 256] < 255)  # the top entry covers [255/256, 1]
    cut = float(np.quantile(lv.values, 0.75))
    c = read_cloud(write_heatmap(lv, tmp_path / "top.pcd", field="kl", min_value=cut))
    keep = lv.values >= np.float32(cut)
    assert set(c) == {"positions", "colors", "kl", "voxel_size"}
    np.testing.assert_array_equal(c["kl"], lv.values[keep])
    np.testing.assert_array_equal(c["positions"], lv.centers[keep].astype(np.float32))


def test_heatmap_all_zero_loss_takes_the_bottom_colour(tmp_path):
    n = 5
    lv = octofuse.Leaves(
        np.arange(3 * n, dtype=float).reshape(n, 3),
        np.full(n, 0.1),
        np.zeros(n, np.float32),
        np.full(n, 16, np.uint8),
    )
    c = read_cloud(write_heatmap(lv, tmp_path / "z.ply"))
    assert np.all(lut_index(c["colors"], "inferno") == 0)


def test_heatmap_refuses_bad_input(loss, tmp_path):
    with pytest.raises(ValueError, match=r"'.*h\.xyz'.*\.ply or \.pcd"):
        write_heatmap(loss, tmp_path / "h.xyz")
    with pytest.raises(ValueError, match="empty"):
        write_heatmap(octofuse.InfoLossMap(0.1), tmp_path / "h.ply")
    with pytest.raises(ValueError, match="no voxel has info_loss >= 1e"):
        write_heatmap(loss, tmp_path / "h.ply", min_value=1e9)
    with pytest.raises(ValueError, match="unknown colour map 'nope'"):
        write_heatmap(loss, tmp_path / "h.ply", cmap="nope")
    with pytest.raises(ValueError, match="vmin=1 > vmax=0"):
        write_heatmap(loss, tmp_path / "h.ply", vmin=1, vmax=0)
    for bad in ("rgb", "voxel_size", "x", "a b", ""):
        with pytest.raises(ValueError, match="field name"):
            write_heatmap(loss, tmp_path / "h.ply", field=bad)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        write_heatmap(loss, tmp_path / "no" / "h.ply")
    with pytest.raises(TypeError):
        write_heatmap(np.zeros(3), tmp_path / "h.ply")
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("suffix", SUFFIXES)
@pytest.mark.parametrize("how", ["fails", "raises"])
def test_a_failed_write_leaves_the_existing_file_untouched(
    loss, tmp_path, monkeypatch, suffix, how
):
    p = write_heatmap(loss, tmp_path / f"h{suffix}")
    before = p.read_bytes()

    def broken_writer(filename, pcd, **kw):
        with open(filename, "wb") as fh:  # a partial file, then the failure
            fh.write(b"ply\nformat binary_little_endian 1.0\n")
        if how == "raises":
            raise RuntimeError("disk full")
        return False

    monkeypatch.setattr(o3d.t.io, "write_point_cloud", broken_writer)
    err = RuntimeError if how == "raises" else OSError
    with pytest.raises(err):
        write_heatmap(loss, p, cmap="viridis")
    assert p.read_bytes() == before
    assert os.listdir(tmp_path) == [p.name]


# -- map clouds --------------------------------------------------------------------------
@pytest.mark.parametrize("suffix", SUFFIXES)
def test_map_cloud_has_the_occupied_voxels_coloured_by_height(maps, tmp_path, suffix):
    a = maps[0]
    lv = a.leaves()
    occ = lv.values > 0
    assert 0 < occ.sum() < a.num_leaves
    c = read_cloud(write_map_cloud(a, tmp_path / f"m{suffix}"))
    assert set(c) == {"positions", "colors", "log_odds", "occupancy", "voxel_size"}
    np.testing.assert_array_equal(c["positions"], lv.centers[occ].astype(np.float32))
    np.testing.assert_array_equal(c["log_odds"], lv.values[occ])
    assert np.all(c["log_odds"] > 0) and np.all(c["occupancy"] > 0.5)
    np.testing.assert_allclose(
        c["occupancy"], 1 / (1 + np.exp(-lv.values[occ].astype(float))), rtol=1e-6
    )
    np.testing.assert_array_equal(c["voxel_size"], lv.sizes[occ].astype(np.float32))
    z = lv.centers[occ, 2]
    idx = lut_index(c["colors"], "viridis")
    assert np.all(np.diff(idx[np.argsort(z, kind="stable")]) >= 0)
    assert idx[z.argmin()] == 0 and idx[z.argmax()] == 255


def test_map_cloud_of_all_voxels_and_threshold(maps, tmp_path):
    a = maps[0]
    lv = a.leaves()
    c = read_cloud(write_map_cloud(a, tmp_path / "all.ply", occupied_only=False, cmap="turbo"))
    np.testing.assert_array_equal(c["log_odds"], lv.values)
    assert (c["log_odds"] <= 0).any()
    lut_index(c["colors"], "turbo")
    c = read_cloud(write_map_cloud(a, tmp_path / "sure.pcd", threshold=1.0))
    np.testing.assert_array_equal(c["log_odds"], lv.values[lv.values > 1.0])
    with pytest.raises(ValueError, match="the map is empty"):
        write_map_cloud(octofuse.OccupancyMap(0.1), tmp_path / "e.ply")
    with pytest.raises(ValueError, match="no voxel has log-odds > 100"):
        write_map_cloud(a, tmp_path / "e.ply", threshold=100)


# -- reading -----------------------------------------------------------------------------
def test_read_cloud_refuses_missing_foreign_and_truncated_files(loss, tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        read_cloud(tmp_path / "none.ply")
    with pytest.raises(ValueError, match=r"\.ply or \.pcd"):
        read_cloud(tmp_path / "x.txt")
    for suffix in SUFFIXES:
        (tmp_path / f"junk{suffix}").write_bytes(b"hello\n")
        with pytest.raises(OSError, match="not a valid"):
            read_cloud(tmp_path / f"junk{suffix}")
    data = write_heatmap(loss, tmp_path / "h.ply").read_bytes()
    (tmp_path / "cut.ply").write_bytes(data[:-7])
    with pytest.raises(OSError, match="truncated"):
        read_cloud(tmp_path / "cut.ply")


# -- export_map and the command ----------------------------------------------------------
@pytest.fixture(scope="module")
def files(maps, loss, tmp_path_factory):
    d = tmp_path_factory.mktemp("export")
    maps[0].save(d / "a.ot")
    loss.save(d / "loss.npz")
    return d


def test_export_map_writes_clouds_heat_maps_and_converts_maps(maps, loss, files, tmp_path):
    a = maps[0]
    r = export.export_map(files / "a.ot", tmp_path / "a.pcd")
    assert r.unit == "points" and r.count == int((a.leaves().values > 0).sum())
    assert len(read_cloud(r.path)["positions"]) == r.count
    r = export.export_map(files / "a.ot", tmp_path / "all.ply", occupied_only=False)
    assert r.count == a.num_leaves
    r = export.export_map(files / "loss.npz", tmp_path / "loss.ply", cmap="magma")
    assert "heat map" in r.content and r.count == loss.num_leaves
    c = read_cloud(r.path)
    np.testing.assert_array_equal(c["info_loss"], loss.leaves().values)
    lut_index(c["colors"], "magma")
    r = export.export_map(files / "a.ot", tmp_path / "a.bt")
    assert r.unit == "leaves"
    assert octofuse.OccupancyMap.load(tmp_path / "a.bt").resolution == a.resolution


def test_export_map_errors(files, tmp_path):
    with pytest.raises(ValueError, match=r"'.*a\.txt'.*\.ply, \.pcd.*\.ot, \.bt"):
        export.export_map(files / "a.ot", tmp_path / "a.txt")
    with pytest.raises(ValueError, match="not an occupancy map"):
        export.export_map(files / "loss.npz", tmp_path / "loss.ot")
    with pytest.raises(ValueError, match=r"cannot export '.*a\.pcd'"):
        export.export_map(tmp_path / "a.pcd", tmp_path / "b.ply")
    with pytest.raises(FileNotFoundError):
        export.export_map(tmp_path / "none.npz", tmp_path / "b.ply")
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(OSError, match=r"cannot read information-loss file '.*bad\.npz'"):
        export.export_map(tmp_path / "bad.npz", tmp_path / "b.ply")
    np.savez(tmp_path / "other.npz", centers=np.zeros((2, 3)))
    with pytest.raises(OSError, match="missing arrays sizes, values, depths"):
        export.export_map(tmp_path / "other.npz", tmp_path / "b.ply")
    assert sorted(os.listdir(tmp_path)) == ["bad.npz", "other.npz"]


def test_export_command(maps, files, tmp_path, capsys):
    out = tmp_path / "a.ply"
    assert main(["export", str(files / "a.ot"), "--out", str(out)]) == 0
    n = int((maps[0].leaves().values > 0).sum())
    line = capsys.readouterr().out.strip()
    assert line == f"wrote {out}: {n:,} points (occupied voxels coloured by height)"
    assert len(read_cloud(out)["positions"]) == n
    out = tmp_path / "all.pcd"
    assert (
        main(["export", str(files / "a.ot"), "--out", str(out), "--all-voxels", "--cmap", "plasma"])
        == 0
    )
    assert f"{maps[0].num_leaves:,} points" in capsys.readouterr().out
    lut_index(read_cloud(out)["colors"], "plasma")
    assert main(["export", str(files / "loss.npz"), "--out", str(tmp_path / "l.pcd")]) == 0
    assert "information-loss heat map" in capsys.readouterr().out


@pytest.mark.parametrize(
    "args, message",
    [
        (["a.ot", "--out", "OUT/a.xyz"], "cannot export to"),
        (["missing.ot", "--out", "OUT/a.ply"], "does not exist"),
        (["loss.npz", "--out", "OUT/a.bt"], "not an occupancy map"),
        (["a.ot", "--out", "OUT/a.ply", "--cmap", "nope"], "unknown colour map"),
    ],
)
def test_export_command_errors(files, tmp_path, capsys, args, message):
    argv = [
        a.replace("OUT", str(tmp_path))
        if "OUT" in a
        else (str(files / a) if a.endswith((".ot", ".npz")) else a)
        for a in args
    ]
    assert main(["export", *argv]) == 1
    cap = capsys.readouterr()
    lines = cap.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0]
    assert cap.out == "" and os.listdir(tmp_path) == []


def test_writers_on_threads_leave_stderr_as_it_was():
    """fd 2 is the process's: writers silencing it on overlapping threads restore it when the
    last one leaves (a writer restoring what another had silenced would lose stderr for good)."""
    import threading

    from octofuse.outputs.clouds import _quiet_stderr

    def target_of_fd2():
        st = os.fstat(2)
        return st.st_dev, st.st_ino

    null = os.stat(os.devnull)
    before = target_of_fd2()
    assert before != (null.st_dev, null.st_ino)
    first_in, second_in, first_out = threading.Event(), threading.Event(), threading.Event()
    seen = {}

    def first():
        with _quiet_stderr():
            first_in.set()
            second_in.wait(5)
        first_out.set()

    def second():
        first_in.wait(5)
        with _quiet_stderr():
            second_in.set()
            first_out.wait(5)
            seen["while the other left"] = target_of_fd2()

    threads = [threading.Thread(target=first), threading.Thread(target=second)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert seen["while the other left"] == (null.st_dev, null.st_ino)
    assert target_of_fd2() == before


@pytest.mark.slow
def test_the_output_libraries_are_imported_ahead_on_a_thread_of_their_own():
    import subprocess
    import sys

    code = (
        "import sys; from octofuse.outputs.libraries import import_output_libraries\n"
        "t = import_output_libraries(); assert t.name == 'octofuse-imports'\n"
        "t.join(120)\n"
        "import matplotlib\n"
        "print('open3d' in sys.modules, 'matplotlib.pyplot' in sys.modules, "
        "matplotlib.get_backend().lower())"
    )
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=180,
        env={**os.environ, "MPLBACKEND": ""},
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["True", "True", "agg"]


def test_a_run_begins_the_imports_once_under_way_and_only_once(monkeypatch):
    """The imports ahead wait for the given share of the scans (at the start they would slow
    the decoding the maps wait for), then begin once; the progress is passed on unchanged."""
    from octofuse.outputs import libraries

    started, seen = [], []
    monkeypatch.setattr(libraries, "import_output_libraries", lambda: started.append(1))
    step = libraries.import_once_under_way(lambda d, t: seen.append((d, t)), share=0.1)
    for done in (0, 5, 9):
        step(done, 100)
    assert started == []
    for done in (10, 11, 50, 100):
        step(done, 100)
    assert started == [1]
    assert seen == [(d, 100) for d in (0, 5, 9, 10, 11, 50, 100)]


@pytest.mark.slow
def test_an_interpreter_leaving_while_the_libraries_import_exits_as_asked():
    """A command that ends while the imports ahead run (an interrupted run, bad input found
    early) waits for them: an interpreter torn down in the middle of Open3D's import can end
    in a segmentation fault instead of its exit code."""
    import subprocess
    import sys

    for delay in (0.1, 0.2, 0.3, 0.4):
        code = (
            "import time; from octofuse.outputs.libraries import import_output_libraries\n"
            f"import_output_libraries(); time.sleep({delay}); raise SystemExit(3)"
        )
        out = subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, timeout=180
        )
        assert out.returncode == 3, (delay, out.returncode, out.stderr[-500:])


def test_the_imports_ahead_begin_no_library_once_interrupted(monkeypatch):
    """After a Ctrl-C the thread finishes the import under way and begins no other: the exit
    waits for it."""
    from octofuse.outputs import libraries

    for flags, expected in (
        ([False, False], ["pyplot", "open3d"]),
        ([False, True], ["pyplot"]),
        ([True], []),
    ):
        calls, asked = [], iter(flags)
        monkeypatch.setattr(libraries, "pyplot", lambda: calls.append("pyplot"))
        monkeypatch.setattr(libraries, "open3d", lambda: calls.append("open3d"))
        monkeypatch.setattr(libraries, "interrupted", lambda: next(asked))
        libraries._load_output_libraries()
        assert calls == expected


@pytest.mark.parametrize(
    "key,value",
    [
        ("values", np.inf),
        ("values", 1e300),
        ("values", np.nan),
        ("values", -1.0),
        ("sizes", 0.0),
        ("centers", np.nan),
    ],
)
def test_loss_files_with_impossible_values_are_refused_naming_the_array(tmp_path, key, value):
    from octofuse.maps.infoloss import read_info_loss

    arrays = {
        "centers": np.zeros((2, 3)),
        "sizes": np.full(2, 0.1),
        "values": np.array([0.5, 0.2]),
        "depths": np.full(2, 16, np.uint8),
    }
    arrays[key] = arrays[key].astype(np.float64)
    arrays[key][1] = value
    p = tmp_path / "loss.npz"
    np.savez(p, **arrays)
    with pytest.raises(ValueError, match=rf"'{p}': {key} holds 1 bad entry \(first at index 1"):
        read_info_loss(p)
