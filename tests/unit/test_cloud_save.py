"""PointCloud.save: a cloud read, built or recoloured written to LAS, LAZ or PLY (io/write.py),
faithful to its LAS source (integers, grid, CRS, 8-bit colours as stored), chunk by chunk."""

from __future__ import annotations

import re
import struct
import subprocess
import sys
from pathlib import Path

import laspy
import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import GigapointWarning, InputError
from gigapoint.io.las import read_las_header, wkt_of
from gigapoint.io.write import save_cloud

LAS_FIELDS = ("X", "Y", "Z", "classification", "intensity", "return_number", "number_of_returns", "gps_time", "point_source_id",
              "user_data", "red", "green", "blue")  # fmt: skip


def by_position(las) -> dict[str, np.ndarray]:
    """The fields of a laspy file in one order (X, Y, Z, then gps_time: unique in autzen_trim)."""
    order = np.lexsort((np.asarray(las.gps_time), np.asarray(las.Z), np.asarray(las.Y), np.asarray(las.X)))
    return {f: np.asarray(las[f])[order] for f in LAS_FIELDS}


@pytest.mark.parametrize("chunked", [False, True])
def test_autzen_round_trip_gives_back_the_files_integers_attributes_colours_and_crs(tmp_path, autzen_path, chunked):
    """Every field gigapoint keeps comes back as the file had it: X, Y, Z on its grid (scale
    0.01, offset 0), colours as its 8-bit values in 16-bit fields (not x 257), its WKT CRS;
    built in memory or in bounded memory (core/chunked.py) alike."""
    out = tmp_path / "x.laz"
    assert gp.open(autzen_path, colors="rgba", chunked=chunked).save(out) == 110_000
    src, got = laspy.read(autzen_path), laspy.read(out)
    assert list(got.header.scales) == [0.01] * 3 and list(got.header.offsets) == [0.0] * 3
    want, have = by_position(src), by_position(got)
    for field in LAS_FIELDS:
        np.testing.assert_array_equal(have[field], want[field], err_msg=field)
    assert int(have["red"].max()) == 236  # (8-bit values: written back as they were)
    source = read_las_header(autzen_path)
    written = read_las_header(out)
    assert wkt_of(written.vlrs) == wkt_of(source.vlrs) and "NAD83" in wkt_of(written.vlrs)
    assert got.header.global_encoding.wkt


def _las_with_offset_and_geotiff_crs(path: Path) -> laspy.LasData:
    """A LAS 1.2 file of 5 000 points on a grid off zero (offset 100.005, scale 0.01) with 16-bit
    colours and a GeoTIFF-only CRS (EPSG:32610), as many older files are."""
    rng = np.random.default_rng(5)
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = np.full(3, 0.01), np.array([100.005, 200.005, 0.005])
    keys = struct.pack("<8H", 1, 1, 0, 1, 3072, 0, 1, 32610)  # one key: ProjectedCSTypeGeoKey = 32610
    header.vlrs.append(laspy.VLR("LASF_Projection", 34735, "GeoTIFF keys", keys))
    las = laspy.LasData(header)
    n = 5000
    las.X, las.Y, las.Z = (rng.integers(-50_000, 50_000, n, dtype=np.int32) for _ in range(3))
    las.red, las.green, las.blue = (rng.integers(0, 65536, n).astype(np.uint16) for _ in range(3))
    las.intensity = rng.integers(0, 65536, n).astype(np.uint16)
    las.gps_time = np.arange(n, dtype=np.float64)
    las.write(str(path))
    return las


def test_a_files_offset_grid_and_geotiff_crs_are_kept_and_16_bit_colours_keep_their_high_byte(tmp_path):
    """The source's grid is kept (its integers, its offset off zero), its GeoTIFF keys copied
    (LAS 1.4 wants WKT; making it needs pyproj), and 16-bit colours lose their low byte only:
    gigapoint holds 8 bits a channel (written back x 257)."""
    src_path = tmp_path / "old.las"
    src = _las_with_offset_and_geotiff_crs(src_path)
    out = tmp_path / "new.las"
    cloud = gp.open(src_path, colors="rgba")
    assert cloud.source_color_bits == 16
    assert cloud.save(out) == 5000
    got = laspy.read(out)
    np.testing.assert_array_equal(got.header.offsets, [100.005, 200.005, 0.005])
    order_src, order_got = np.argsort(np.asarray(src.gps_time)), np.argsort(np.asarray(got.gps_time))
    for field in ("X", "Y", "Z", "intensity"):
        np.testing.assert_array_equal(np.asarray(got[field])[order_got], np.asarray(src[field])[order_src], err_msg=field)
    np.testing.assert_array_equal(np.asarray(got.red)[order_got], (np.asarray(src.red)[order_src] >> 8) * 257)
    assert read_las_header(out).crs() == "EPSG:32610"
    src_path.unlink()  # a source gone since: its CRS and grid are lost, not the save
    assert cloud.save(tmp_path / "later.las") == 5000 and read_las_header(tmp_path / "later.las").crs() is None


def test_crs_records_of_geotiff_keys_make_no_wkt(tmp_path, autzen_path, monkeypatch):
    """source_crs_records of a LAS file naming its CRS by GeoTIFF keys alone made a WKT of them by
    pyproj (and its units), both thrown away: the keys are copied as they are. A LAS WKT is
    copied as it is; a PLY's 'EPSG:n' is made WKT (by pyproj)."""
    import pyproj

    from gigapoint.io.write import source_crs_records

    src_path = tmp_path / "old.las"
    _las_with_offset_and_geotiff_crs(src_path)
    gp.open(src_path, colors="rgba").save(tmp_path / "old.ply")
    made = []
    for name in ("from_user_input", "from_epsg"):
        real = getattr(pyproj.CRS, name).__func__
        monkeypatch.setattr(pyproj.CRS, name, classmethod(lambda cls, *a, real=real, **k: made.append(a) or real(cls, *a, **k)))
    keys = [(b"LASF_Projection", 34735, struct.pack("<8H", 1, 1, 0, 1, 3072, 0, 1, 32610))]  # (_las_with_offset_and_geotiff_crs's)
    assert source_crs_records([src_path]) == keys and made == []
    wkt = wkt_of(read_las_header(autzen_path).vlrs)
    assert source_crs_records([autzen_path]) == [(b"LASF_Projection", 2112, wkt.encode() + b"\0")] and made == []
    (_, record, data), = source_crs_records([tmp_path / "old.ply"])
    assert record == 2112 and pyproj.CRS.from_wkt(data.rstrip(b"\0").decode()).to_epsg() == 32610 and made


def test_from_arrays_with_attributes_saves_to_las_laz_and_ply_and_reads_back_equal(tmp_path):
    rng = np.random.default_rng(3)
    n = 4000
    xyz = np.round(rng.random((n, 3)) * [500, 300, 40] + [4.5e5, 5.2e6, 10], 3)  # on a millimetre grid
    rgb = rng.integers(0, 256, (n, 3), dtype=np.uint8)
    attrs = {"intensity": rng.integers(0, 65536, n).astype(np.uint16), "classification": rng.integers(0, 20, n).astype(np.uint8),
             "label": np.arange(n, dtype=np.int32), "height": rng.random(n).astype(np.float32)}  # fmt: skip
    cloud = gp.from_arrays(xyz, rgb, scale=0.001, colors="rgba", **attrs)
    for suffix in (".las", ".laz", ".ply"):
        out = tmp_path / f"a{suffix}"
        assert cloud.save(out) == n
        back = gp.open(out, colors="rgba")
        order = np.argsort(back.attributes["label"])
        assert back.n_points == n, suffix
        np.testing.assert_allclose(back.positions()[order], xyz, atol=1e-6, rtol=0, err_msg=suffix)
        np.testing.assert_array_equal(back.rgba[order, :3], rgb, err_msg=suffix)
        for name, values in attrs.items():
            np.testing.assert_array_equal(back.attributes[name][order], values, err_msg=f"{suffix} {name}")
    assert laspy.read(tmp_path / "a.las").header.scales.tolist() == [0.001] * 3  # from_arrays' scale is the file's


@pytest.mark.parametrize("copies", [1, 2])
def test_one_point_or_equal_points_save_on_a_millimetre_grid(tmp_path, copies):
    """A cloud of one point (or of equal points) has no extent: its LAS scale was the 1 nm / float64
    floor (8.6e-9 at UTM coordinates), which other tools show as absurd scales and offsets; such
    points are saved on the millimetre grid, and read back within half a millimetre."""
    xyz = np.array([[654321.1234567, 4321987.4567891, 123.7891234]] * copies)
    gp.from_arrays(xyz).save(tmp_path / "one.las")
    las = laspy.read(tmp_path / "one.las")
    assert las.header.scales.tolist() == [0.001] * 3
    np.testing.assert_allclose(np.column_stack([las.x, las.y, las.z]), xyz, atol=0.0005, rtol=0)


def test_a_plain_save_to_a_copc_name_is_refused_and_points_to_convert(tmp_path, autzen_path):
    """save("x.copc.laz") wrote a plain LAZ (no COPC info VLR) under a COPC's name, as did
    classify_noise and height_above_ground; refused now, nothing written, naming gigapoint.convert,
    which writes the COPC."""
    from gigapoint.errors import InputError

    cloud = gp.from_arrays(np.c_[np.arange(5.0), np.zeros(5), np.zeros(5)])
    out = tmp_path / "x.COPC.laz"
    with pytest.raises(InputError) as err:
        cloud.save(out)
    refused = f"{out}: a COPC file is an octree, not a plain LAZ file: name it .laz, or write the COPC with gigapoint.convert(..., {str(out)!r})"
    assert str(err.value) == refused
    assert not out.exists()
    for classify in (gp.classify_noise, gp.height_above_ground):  # (their plain LAZ under a COPC's name too)
        with pytest.raises(InputError) as err:
            classify(autzen_path, out)
        assert str(err.value) == refused and not out.exists()
    gp.convert(cloud, out, progress=False)
    assert "copc" in [v.user_id for v in laspy.read(out).header.vlrs]


def test_one_point_far_out_saves_on_the_grid_float64_tells_apart(tmp_path):
    """A point at 1e12 m has no extent: it got the millimetre, though float64 tells no finer steps
    than 2e-15 of its coordinates apart there (0.002): that floor, as for a cloud with an extent."""
    from gigapoint.io.las_fields import default_step

    far = 2e-15 * 1e12
    assert default_step([1e12, -1e12, 5.0], [1e12, -1e12, 5.0]) == far
    assert default_step([0, 0, 0], [0, 0, 0]) == 0.001  # (near 0: the millimetre)
    xyz = np.array([[1e12, -1e12, 5.0]])
    gp.from_arrays(xyz).save(tmp_path / "far.las")
    las = laspy.read(tmp_path / "far.las")
    assert las.header.scales.tolist() == [far] * 3
    np.testing.assert_allclose(np.column_stack([las.x, las.y, las.z]), xyz, atol=far / 2, rtol=0)


@pytest.mark.parametrize(
    ("suffix", "left_out"),
    [(".las", ["x", "red", "bit_fields", "café"]), (".laz", ["x", "red", "bit_fields", "café"]), (".ply", ["x", "red", "Red", "my attr", "café"])],
)
def test_attributes_a_file_cannot_hold_under_their_name_are_left_out_with_a_warning(tmp_path, suffix, left_out):
    """A name the file's own fields use (x, red; LAS's packed bit_fields; 'Red' in PLY, read in
    lower case) was a ValueError or IndexError traceback; one a PLY header cannot hold ('my
    attr', 'café') a file no reader opened: now they are left out, said, and the rest written."""
    n = 500
    xyz = np.random.default_rng(5).random((n, 3)) * 100
    rgb = np.full((n, 3), 90, np.uint8)
    names = ["x", "red", "Red", "bit_fields", "my attr", "café", "label"]
    cloud = gp.from_arrays(xyz, rgb, colors="rgba", **{a: np.arange(n, dtype=np.int32) + k for k, a in enumerate(names)})
    out = tmp_path / f"odd{suffix}"
    with pytest.warns(gp.GigapointWarning) as caught:
        assert cloud.save(out) == n
    said = [re.match(rf"^{re.escape(str(out))}: attribute '(.+)' is not written: ", str(w.message)) for w in caught]
    assert [m[1] for m in said if m] == left_out
    back = gp.open(out, colors="rgba")
    order = np.argsort(back.attributes["label"])
    np.testing.assert_allclose(back.positions()[order], xyz, atol=1e-3, rtol=0)
    np.testing.assert_array_equal(back.rgba[order, :3], rgb)
    for k, a in enumerate(names):
        assert (a in back.attributes) == (a not in left_out), a
        if a in back.attributes:
            np.testing.assert_array_equal(back.attributes[a][order], np.arange(n) + k, err_msg=a)


@pytest.mark.parametrize("suffix", [".las", ".laz", ".ply"])
def test_attributes_of_several_values_a_point_are_written_a_column_each(tmp_path, suffix):
    """An NPZ's (N, 3) normals (or a structured NPY's subarray field) made save and convert -o
    numpy's "could not broadcast input array from shape (500,3) into shape (500,)" traceback:
    normals are written as nx, ny, nz (read back as the renderer's normals), others as name_0 ..."""
    n = 500
    rng = np.random.default_rng(6)
    xyz, normals, pair = rng.random((n, 3)) * 50, rng.normal(size=(n, 3)), rng.integers(0, 1000, (n, 2)).astype(np.uint16)
    src = tmp_path / "n.npz"
    np.savez(src, xyz=xyz, normals=normals, pair=pair, label=np.arange(n, dtype=np.int32))
    saved, converted = tmp_path / f"saved{suffix}", tmp_path / f"converted{suffix}"
    assert gp.open(src).save(saved) == n
    assert gp.convert(src, converted).points == n
    for out in (saved, converted):
        back = gp.open(out)
        order = np.argsort(back.attributes["label"])
        for name, want in {"nx": normals[:, 0], "ny": normals[:, 1], "nz": normals[:, 2], "pair_0": pair[:, 0], "pair_1": pair[:, 1]}.items():
            np.testing.assert_array_equal(back.attributes[name][order], want, err_msg=f"{out.name} {name}")
        assert back.attributes["pair_0"].dtype == np.uint16 and "normals" not in back.attributes


def test_set_colors_then_save_writes_the_new_colours(tmp_path):
    xyz = np.random.default_rng(1).random((3000, 3)) * 10
    cloud = gp.from_arrays(xyz, np.full((3000, 3), 200, np.uint8), colors="rgba")
    cloud.set_colors([10, 20, 30], np.arange(0, 3000, 2))
    cloud.save(tmp_path / "a.ply")
    cloud.save(tmp_path / "a.las")
    ply = gp.open(tmp_path / "a.ply", colors="rgba")
    assert sorted(map(tuple, np.unique(ply.rgba[:, :3], axis=0).tolist())) == [(10, 20, 30), (200, 200, 200)]
    assert np.count_nonzero(ply.rgba[:, 0] == 10) == 1500
    las = laspy.read(tmp_path / "a.las")  # built from points: LAS's 16-bit colours, x 257
    assert sorted(set(np.asarray(las.red).tolist())) == [10 * 257, 200 * 257] and np.count_nonzero(np.asarray(las.green) == 20 * 257) == 1500


@pytest.mark.parametrize("suffix", [".las", ".laz", ".ply"])
def test_writing_in_small_chunks_gives_the_same_file_as_one_chunk(tmp_path, suffix, autzen_path):
    """points_per_chunk=1: each of autzen_trim's 11 batches a chunk of its own, written one by one."""
    cloud = gp.open(autzen_path, colors="rgba")  # (exact colours: no warning)
    assert len(cloud.batches) > 1
    one, many = tmp_path / f"one{suffix}", tmp_path / f"many{suffix}"
    assert save_cloud(cloud, one, points_per_chunk=10**9) == save_cloud(cloud, many, points_per_chunk=1) == 110_000
    if suffix == ".laz":  # (LAZ chunks follow the writes: the points compared)
        a, b = laspy.read(one), laspy.read(many)
        for field in LAS_FIELDS:
            np.testing.assert_array_equal(np.asarray(a[field]), np.asarray(b[field]), err_msg=field)
    else:
        assert one.read_bytes() == many.read_bytes()


@pytest.mark.timeout(600)  # a deadlock guard: the progressive load's kernels compile in its thread, minutes on a cold cache under load
@pytest.mark.parametrize("how", ["convert", "save", "progressive"])
def test_a_ply_keeps_the_crs_in_a_header_comment_and_reads_it_back(tmp_path, autzen_path, cli, how):
    """``convert autzen.laz -o a.ply`` (a cloud's save, a progressive cloud's) lost the CRS without a word: PLY has no
    field for one. It is written in a ``comment crs`` line, which PLY readers skip and gigapoint reads."""
    import plyfile

    from gigapoint.io import file_info
    from gigapoint.lod.reader import cloud_crs

    out = tmp_path / "a.ply"
    if how == "convert":
        rc, _, err = cli("convert", autzen_path, "-o", out)
        assert rc == 0, err
    elif how == "progressive":
        loading = gp.open(autzen_path, progressive=True)
        assert loading.wait()  # (until the load ends: wait(120) failed one still compiling, twice in fresh worktrees at load 4)
        loading.save(out)
    else:
        gp.open(autzen_path, colors="rgba").save(out)
    wkt = read_las_header(autzen_path).crs()
    assert wkt.startswith('PROJCS["NAD_1983_HARN_Lambert_Conformal_Conic"')
    assert cloud_crs(gp.open(out)) == wkt and file_info(out)["crs"] == wkt
    ply = plyfile.PlyData.read(out)  # (a standard PLY reader: the comment is skipped, the points all there)
    assert ply.comments == [f"crs {wkt}"] and ply["vertex"].count == 110_000


def test_save_refuses_in_one_line_naming_the_file_and_leaves_nothing(tmp_path, monkeypatch):
    cloud = gp.from_arrays(np.random.default_rng(2).random((100, 3)), big=np.full(100, -(2**63)))
    (tmp_path / "taken.las").write_bytes(b"mine")
    (tmp_path / "dir.laz").mkdir()
    monkeypatch.chdir(tmp_path)
    for path, problem in (
        ("taken.las", "taken.las: already exists; pass overwrite=True to replace it"),
        ("dir.laz", "dir.laz: is a directory, not a LAZ file; not replaced"),
        ("taken.las/a.ply", "taken.las/a.ply: taken.las is a file, not a folder"),
        ("a.xyz", "a.xyz: save writes .las, .laz or .ply files, not .xyz"),
        ("a", "a: save writes .las, .laz or .ply files, not a name without a suffix"),
        (5, "arrays: save: the output must be a path of a .las, .laz or .ply file, got 5"),
        ("b.ply", "b.ply: attribute 'big' holds int64 values PLY cannot hold (it has no 64-bit integers), e.g. -9223372036854775808; save as .las or .laz"),
    ):  # fmt: skip
        with pytest.raises(InputError, match=f"^{re.escape(problem)}$"):
            cloud.save(path, overwrite=path == "dir.laz")
    with pytest.raises(InputError, match="overwrite"):
        cloud.save("taken.las", overwrite="no")
    assert (tmp_path / "taken.las").read_bytes() == b"mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dir.laz", "taken.las"]  # nothing else, no temporary file
    assert cloud.save("taken.las", overwrite=True) == 100 and laspy.read("taken.las").header.point_count == 100


def test_convert_of_a_cloud_into_a_point_file_points_to_its_save(tmp_path):
    """gp.convert(cloud, "a.laz") said "a gigapoint octree is a folder": the cloud's own save writes that file."""
    from gigapoint.lod.octree_dir import ConvertError

    cloud = gp.from_arrays(np.random.default_rng(2).random((100, 3)))
    out = tmp_path / "a.laz"
    said = f"{out}: convert writes a cloud as an octree folder or a .copc.laz file; cloud.save({str(out)!r}) writes its points as that file"
    with pytest.raises(ConvertError, match=f"^{re.escape(said)}$"):
        gp.convert(cloud, out)
    assert not out.exists()
    assert cloud.save(out) == 100  # (as it says)


def test_save_makes_the_folders_missing_on_its_way(tmp_path):
    """As an octree folder and a COPC file are made (convert, a progressive cloud's save): "the
    folder nowhere does not exist" was the one output refused for it."""
    cloud = gp.from_arrays(np.random.default_rng(2).random((100, 3)))
    assert cloud.save(tmp_path / "nowhere" / "deeper" / "a.ply") == 100
    assert gp.open(tmp_path / "nowhere" / "deeper" / "a.ply").n_points == 100


def test_save_where_nothing_can_be_created_names_the_file(tmp_path):
    cloud = gp.from_arrays(np.random.default_rng(2).random((100, 3)))
    with pytest.raises(InputError, match=r"^/proc/gigapoint_save\.las: not written \(.+\); nothing was left there$"):
        cloud.save("/proc/gigapoint_save.las")


_SAVE_ON_A_FULL_DISK = """
import resource, signal, sys
from pathlib import Path
import numpy as np
import gigapoint as gp
from gigapoint.errors import GigapointWarning, InputError

out = Path(sys.argv[1])
cloud = gp.from_arrays(np.random.default_rng(3).random((20000, 3)) * 100, np.full((20000, 3), 9, np.uint8))
for suffix in (".las", ".laz", ".ply"):
    cloud.save(out / f"warm{suffix}")  # every kernel compiled (and cached) before the limit
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit: EFBIG, as a full disk's ENOSPC
resource.setrlimit(resource.RLIMIT_FSIZE, (4000, resource.RLIM_INFINITY))
for suffix in (".las", ".laz", ".ply"):
    try:
        cloud.save(out / f"scan{suffix}")
    except InputError as exc:
        print(exc)
"""


def test_save_on_a_full_disk_is_one_line_naming_the_file_and_leaves_nothing(tmp_path):
    pytest.importorskip("resource")
    run = subprocess.run([sys.executable, "-c", _SAVE_ON_A_FULL_DISK, str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    lines = run.stdout.splitlines()
    assert [line.split(" (")[0] for line in lines] == [f"{tmp_path / f'scan{s}'}: not written" for s in (".las", ".laz", ".ply")]
    assert all(line.endswith("); nothing was left there") for line in lines)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["warm.las", "warm.laz", "warm.ply"]


def test_saving_approximated_colours_says_so(tmp_path, autzen_path):
    """gp.open's default colors="auto" holds RGB565 or palettes: save writes those, off the
    file's by up to 12/255, which it said nowhere (convert says it); exact colours say nothing."""
    import warnings

    from gigapoint.errors import GigapointWarning

    out = tmp_path / "approx.laz"
    with pytest.warns(GigapointWarning) as caught:
        gp.open(autzen_path).save(out)
    said = f"{out}: the cloud holds its colours approximated (RGB565 or a palette), so the file gets those; "
    assert [str(w.message) for w in caught] == [said + f"open its files ({autzen_path}) with colors='rgba' for exact colours"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        gp.open(autzen_path, colors="rgba").save(tmp_path / "exact.laz")


def test_a_progressive_octree_saves_its_points_into_one_point_file(tmp_path, autzen_path):
    """save("merged.laz") of a progressive octree was "a gigapoint octree is a folder": its leaves'
    points (not its voxels) into one file, on the source's grid (the same X, Y, Z integers, as
    sets: the leaves' order is not the file's) with its CRS; the octree's options refused."""
    from gigapoint.errors import InputError

    cloud = gp.open(autzen_path, progressive=True)
    result = cloud.save(tmp_path / "merged.laz")
    assert result.points == 110_000 and result.out == tmp_path / "merged.laz" and result.nodes == 0
    src, out = laspy.read(autzen_path), laspy.read(tmp_path / "merged.laz")
    fields = ("X", "Y", "Z", "classification", "intensity", "return_number", "gps_time")

    def rows(las):
        return np.sort(np.rec.fromarrays([np.asarray(las[f]) for f in fields], names=fields))

    src_rows, out_rows = rows(src), rows(out)
    np.testing.assert_array_equal(out.header.scales, src.header.scales)
    np.testing.assert_array_equal(out.header.offsets, src.header.offsets)
    assert (src_rows == out_rows).all()
    from gigapoint.io.las import read_las_header

    assert read_las_header(tmp_path / "merged.laz").crs() == read_las_header(autzen_path).crs() and "Lambert" in read_las_header(autzen_path).crs()
    ply = cloud.save(tmp_path / "merged.ply")
    assert ply.points == 110_000 and gp.open(tmp_path / "merged.ply").n_points == 110_000
    with pytest.raises(InputError, match=r"^.*again\.laz: max_leaf: options of an octree, not of a plain LAZ file$"):
        cloud.save(tmp_path / "again.laz", max_leaf=1000)
    with pytest.raises(InputError, match=r"merged\.laz: already exists"):
        cloud.save(tmp_path / "merged.laz")
    cloud.close()



def test_a_cloud_of_a_colourless_file_saves_without_colours_until_it_is_given_some(tmp_path):
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.scales, header.offsets = np.full(3, 0.01), np.zeros(3)
    las = laspy.LasData(header)
    las.X, las.Y, las.Z = (np.arange(3000, dtype=np.int32) * k for k in (1, 2, 3))
    las.intensity = np.arange(3000, dtype=np.uint16)
    las.write(str(tmp_path / "norgb.las"))
    cloud = gp.open(tmp_path / "norgb.las", colors="rgba")
    cloud.save(tmp_path / "plain.las")
    cloud.save(tmp_path / "plain.ply")
    plain = laspy.read(str(tmp_path / "plain.las"))
    assert plain.header.point_format.id == 6 and "red" not in plain.point_format.dimension_names  # (was 7: grey 51400 made up)
    assert sorted(np.asarray(plain.intensity).tolist()) == list(range(3000))
    assert b"property uchar red" not in (tmp_path / "plain.ply").read_bytes().split(b"end_header")[0]
    cloud.set_colors([10, 20, 30])  # colours given: they are the cloud's, and written
    cloud.save(tmp_path / "coloured.las")
    coloured = laspy.read(str(tmp_path / "coloured.las"))
    assert coloured.header.point_format.id == 7 and set(np.asarray(coloured.green).tolist()) == {20 * 257}


def test_a_progressive_octree_saves_8_bit_colours_as_its_files_stored_them(tmp_path, autzen_path):
    """autzen_trim stores 8-bit values in its 16-bit fields: a progressive cloud's save("x.laz")
    wrote them x 257 (red up to 60652), where a plain cloud's save and convert -o x.laz keep them
    (red up to 236); points added of its own make LAS's 16-bit colours again."""
    cloud = gp.open(autzen_path, progressive=True)
    cloud.save(tmp_path / "as_stored.laz")
    red = np.asarray(laspy.read(tmp_path / "as_stored.laz").red)
    np.testing.assert_array_equal(np.sort(red), np.sort(np.asarray(laspy.read(autzen_path).red)))
    cloud.add(np.array([[636500.0, 849200.0, 450.0]]), rgb=np.array([[255, 0, 0]], np.uint8))
    cloud.save(tmp_path / "own.laz")
    red = np.asarray(laspy.read(tmp_path / "own.laz").red)
    assert int(red.max()) == 65535 and int(np.sort(red)[-2]) == 236 * 257
    cloud.close()


def test_a_progressive_octree_keeps_8_bit_colours_after_an_add_it_refused(tmp_path, autzen_path):
    """add() noted its points' colours as LAS's 16-bit ones before checking the batch: an add
    refused (an attribute the cloud has not) made the save write autzen's 8-bit values x 257."""
    cloud = gp.open(autzen_path, progressive=True)
    with pytest.raises(InputError, match="bogus"):
        cloud.add(np.array([[636500.0, 849200.0, 450.0]]), rgb=np.array([[1, 2, 3]], np.uint8), bogus=np.array([1.0]))
    cloud.save(tmp_path / "after.laz")
    red = np.asarray(laspy.read(tmp_path / "after.laz").red)
    np.testing.assert_array_equal(np.sort(red), np.sort(np.asarray(laspy.read(autzen_path).red)))
    cloud.close()


def test_a_ply_cloud_saved_keeps_its_crs(tmp_path):
    """A cloud opened from a PLY file naming its CRS saved it to no file: the CRS records were
    read from LAS headers only."""
    import plyfile

    pyproj = pytest.importorskip("pyproj")
    v = np.zeros(10, [("x", "<f8"), ("y", "<f8"), ("z", "<f8")])
    v["x"] = 500_000 + np.arange(10.0)
    plyfile.PlyData([plyfile.PlyElement.describe(v, "vertex")], comments=["crs EPSG:32610"]).write(str(tmp_path / "utm.ply"))
    cloud = gp.open(tmp_path / "utm.ply")
    cloud.save(tmp_path / "out.ply")
    cloud.save(tmp_path / "out.las")
    assert plyfile.PlyData.read(str(tmp_path / "out.ply")).comments == ["crs EPSG:32610"]
    assert pyproj.CRS.from_user_input(read_las_header(tmp_path / "out.las").crs()).to_epsg() == 32610


#: a WKT naming no EPSG code of its own, not in ASCII
ZONE_WKT = (
    'PROJCS["Zoné 10",GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563]],PRIMEM["Greenwich",0],'
    'UNIT["degree",0.0174532925199433]],PROJECTION["Transverse_Mercator"],PARAMETER["latitude_of_origin",0],'
    'PARAMETER["central_meridian",-123],PARAMETER["scale_factor",0.9996],PARAMETER["false_easting",500000],'
    'PARAMETER["false_northing",0],UNIT["metre",1]]'
)


def test_a_crs_a_ply_header_cannot_hold_is_left_out_with_a_warning(tmp_path):
    """A PLY header is ASCII: a WKT in another script was written into it, and the file could not
    be read back, by gigapoint either ('ascii' codec can't decode). It is left out, said once."""
    import plyfile
    from test_change import write_las  # (tests/unit is on sys.path)

    source = write_las(tmp_path / "zone.las", np.random.default_rng(0).random((50, 3)), wkt=ZONE_WKT)
    out = tmp_path / "zone.ply"
    with pytest.warns(GigapointWarning) as caught:
        gp.open(source).save(out)
    said = [str(w.message) for w in caught if "CRS" in str(w.message)]
    assert said == [f"{out}: its CRS (Zoné 10 (WKT)) is not written: its WKT is not ASCII, and a PLY header line must be ASCII and under 1024 bytes; save as .las or .laz to keep it"]
    assert plyfile.PlyData.read(str(out)).comments == [] and gp.open(out).n_points == 50


def test_convert_of_an_opened_octree_is_refused_as_its_folder_is(tmp_path):
    """gp.convert(gp.open(octree folder), ...) said "got a CompactOctree": the folder's own refusal, with what to convert instead."""
    folder = tmp_path / "oct"
    gp.convert(gp.from_arrays(np.random.default_rng(3).random((100, 3))), folder, progress=False)
    octree = gp.open(folder)
    said = f"{folder}: is a converted octree (opened), not an input point cloud; convert the point files it was made from"
    for out in (tmp_path / "again", tmp_path / "a.laz"):
        with pytest.raises(InputError, match=f"^{re.escape(said)}$"):
            gp.convert(octree, out)
        assert not out.exists()


def test_a_progressive_octree_of_a_colourless_file_saves_the_colours_an_add_gave(tmp_path, autzen_path):
    """Colours given to add(rgb=) were dropped by a save where the source file had none (point
    format 6, a PLY without red, octree.json's has_color false): the files alone decided, where a
    plain cloud keeps colours of its own. Without an add's colours the save stays colourless."""
    import json

    src = laspy.read(autzen_path)
    las = laspy.LasData(laspy.LasHeader(point_format=1, version="1.2"))
    las.header.scales, las.header.offsets = src.header.scales, src.header.offsets
    las.X, las.Y, las.Z = src.X[:5000], src.Y[:5000], src.Z[:5000]
    las.write(str(tmp_path / "norgb.laz"))
    cloud = gp.open(tmp_path / "norgb.laz", progressive=True)
    cloud.wait()
    cloud.save(tmp_path / "plain.laz")
    assert laspy.read(tmp_path / "plain.laz").header.point_format.id == 6
    cloud.add(np.c_[np.full(10, 636500.0), np.full(10, 849000.0), np.linspace(410, 420, 10)], rgb=np.tile(np.array([10, 20, 30], np.uint8), (10, 1)))
    cloud.wait()
    cloud.save(tmp_path / "p.laz")
    cloud.save(tmp_path / "p.ply")
    cloud.save(tmp_path / "p_oct")
    out = laspy.read(tmp_path / "p.laz")
    assert out.header.point_format.id == 7 and np.count_nonzero(np.asarray(out.green) == 20 * 257) == 10
    assert b"property uchar red" in (tmp_path / "p.ply").read_bytes().split(b"end_header")[0]
    assert json.loads((tmp_path / "p_oct" / "octree.json").read_text())["has_color"] is True
    cloud.close()


def _far_las(path: Path, x0: float) -> None:
    """Two points at x ~ ``x0`` on a 0.01 grid from offset ``x0`` (autzen's y and z)."""
    las = laspy.LasData(laspy.LasHeader(point_format=3, version="1.2"))
    las.header.scales, las.header.offsets = np.full(3, 0.01), np.array([x0, 0.0, 0.0])
    las.x, las.y, las.z = np.array([x0 + 0.5, x0 + 1.25]), np.array([849000.0, 849001.0]), np.array([400.0, 401.0])
    las.write(str(path))


def test_a_merge_spanning_more_than_2_30_steps_keeps_its_scale_and_one_beyond_int32_says_it_coarsens(tmp_path, autzen_path):
    """autzen and points at x 30 000 000 (2.9e9 steps of 0.01 apart) were merged at scale 0.0273
    without a word (2**30 steps counted from the lowest point): centred, 32-bit integers hold
    them at 0.01, every value as read; at x 60 000 000 they do not, and the coarser scale is said."""
    import warnings

    _far_las(tmp_path / "far.las", 30_000_000.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", GigapointWarning)
        warnings.filterwarnings("ignore", "far.las names no CRS", GigapointWarning)
        gp.convert([autzen_path, tmp_path / "far.las"], tmp_path / "farm.laz")
    src, far, out = laspy.read(autzen_path), laspy.read(tmp_path / "far.las"), laspy.read(tmp_path / "farm.laz")
    np.testing.assert_array_equal(out.header.scales, [0.01, 0.01, 0.01])
    np.testing.assert_array_equal(out.header.offsets[1:], [0.0, 0.0])  # (y, z: the first file's offset still holds them)
    for axis in "xyz":
        want = np.concatenate([np.asarray(src[axis]), np.asarray(far[axis])])
        assert np.abs(np.asarray(out[axis]) - want).max() < 1e-6
    _far_las(tmp_path / "farther.las", 60_000_000.0)
    with pytest.warns(GigapointWarning) as said:
        gp.convert([autzen_path, tmp_path / "farther.las"], tmp_path / "farm2.laz")
    coarse = [str(w.message) for w in said if "32-bit" in str(w.message)]
    want = f"{tmp_path / 'farm2.laz'}: the points span more than 32-bit integers hold at scale 0.01, 0.01, 0.01: written at scale 0.0138218, 0.01, 0.01"
    assert coarse == [f"{want}, positions moved by up to 0.00691"]
    assert laspy.read(tmp_path / "farm2.laz").header.scales[0] == pytest.approx(0.0138218, rel=1e-5)


def test_a_progressive_save_of_points_added_beyond_int32_on_its_grid_says_it_coarsens(tmp_path, autzen_path):
    """A progressive octree's save("x.laz") after add() of a point at x 60 000 000 coarsened its grid without a word."""
    cloud = gp.open(autzen_path, progressive=True)
    cloud.wait()
    cloud.add(np.array([[60_000_000.5, 849000.0, 400.0]]))
    with pytest.warns(GigapointWarning, match=r"p\.laz: the points span more than 32-bit integers hold at scale 0\.01, 0\.01, 0\.01: written at scale 0\.0138218, 0\.01, 0\.01, positions moved by up to 0\.00691$"):
        cloud.save(tmp_path / "p.laz")
    cloud.close()


def test_attribute_values_beyond_their_las_field_are_said_once_a_field_on_save(tmp_path):
    """intensity -5 or 70 000 and class 300 were written 0, 65 535 and 255 without a word; values
    the field holds are written without one."""
    import warnings

    xyz = np.c_[np.arange(4.0), np.zeros(4), np.zeros(4)]
    cloud = gp.from_arrays(xyz, intensity=np.array([-5, 70000, 70001, 7]), classification=np.array([2, 300, 2, 2]))
    with pytest.warns(GigapointWarning) as said:
        save_cloud(cloud, tmp_path / "x.laz", points_per_chunk=2)  # (two chunks: said once a field, counted over both)
    out = tmp_path / "x.laz"
    assert [str(w.message) for w in said] == [
        f"{out}: 3 intensity values beyond 0..65535, what its LAS field holds: written as 0 or 65535",
        f"{out}: 1 classification value beyond 0..255, what its LAS field holds: written as 0 or 255",
    ]
    las = laspy.read(out)
    assert np.asarray(las.intensity).tolist() == [0, 65535, 65535, 7] and np.asarray(las.classification).tolist() == [2, 255, 2, 2]
    with warnings.catch_warnings():
        warnings.simplefilter("error", GigapointWarning)
        gp.from_arrays(xyz, intensity=np.array([0, 65535, 3, 7])).save(tmp_path / "fits.laz")


def test_attribute_values_beyond_their_las_field_are_said_once_a_field_in_copc(tmp_path):
    """A cloud converted to COPC clipped intensity 70 000 to 65 535 without a word (the LAS save says it)."""
    xyz = np.c_[np.arange(4.0), np.zeros(4), np.zeros(4)]
    cloud = gp.from_arrays(xyz, intensity=np.array([-5, 70000, 70001, 7]))
    out = tmp_path / "x.copc.laz"
    with pytest.warns(GigapointWarning) as said:
        gp.convert(cloud, out, progress=False)
    assert [str(w.message) for w in said if "intensity" in str(w.message)] == [
        f"{out}: 3 intensity values beyond 0..65535, what its LAS field holds: written as 0 or 65535"
    ]
    assert sorted(np.asarray(laspy.read(out).intensity).tolist()) == [0, 7, 65535, 65535]


def test_a_potree_output_that_must_coarsen_the_inputs_scale_says_it_once(tmp_path):
    """Potree counts positions from the lowest point in 31 bits: points 30 000 km apart at scale
    0.01 (3e9 steps, which centred 32-bit integers hold: a LAS output keeps 0.01) were written at
    scale 0.0279 without a word."""
    import json

    _far_las(tmp_path / "near.las", 0.0)
    _far_las(tmp_path / "far.las", 30_000_000.0)
    out = tmp_path / "pot"
    with pytest.warns(GigapointWarning) as said:
        gp.convert([tmp_path / "near.las", tmp_path / "far.las"], out, format="potree", progress=False)
    scale = json.loads((out / "metadata.json").read_text())["scale"]
    assert scale[0] == pytest.approx((30_000_001.25 - 0.5) / 2**30) and scale[1:] == [0.01, 0.01]
    coarse = [str(w.message) for w in said if "32-bit" in str(w.message)]
    want = f"{out}: the points span more than 32-bit integers hold at scale 0.01, 0.01, 0.01: written at scale {scale[0]:.6g}, 0.01, 0.01"
    assert coarse == [f"{want}, positions moved by up to {scale[0] / 2:.3g}"]


def test_decimal_values_of_a_text_file_read_back_as_they_were(tmp_path, monkeypatch):
    """Points without a grid of their own got 3/65 536 m steps from an offset off the decimal
    values: a text file's 1.0 came back 0.99998. The step is now a power of ten (1e-5 here) from
    a whole-number offset."""
    from gigapoint.cli import main

    (tmp_path / "clean.xyz").write_text("x y z\n1 2 3\n4 5 6\n")
    monkeypatch.chdir(tmp_path)
    assert main(["tile", "clean.xyz", "--size", "500", "-o", "t"]) == 0
    gp.convert(tmp_path / "clean.xyz", tmp_path / "x.laz", progress=False)
    for path in (tmp_path / "t" / "clean_0_0.laz", tmp_path / "x.laz"):
        las = laspy.read(path)
        assert las.header.scales.tolist() == [1e-5] * 3
        assert np.column_stack([las.x, las.y, las.z]).tolist() == [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]
