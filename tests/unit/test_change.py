"""Change between two surveys (`gigapoint change`, gp.change: survey/change.py): both surfaces on
one grid, AFTER - BEFORE as a GeoTIFF, cut and fill volumes, a diverging preview."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import laspy
import numpy as np
import pytest
from laspy.vlrs.known import WktCoordinateSystemVlr
from PIL import Image
from test_geo_coords import UTM10_NAVD88_WKT1, UTM11_NAVD88_WKT1, without_pyproj  # (tests/unit is on sys.path)

import gigapoint as gp
from gigapoint.errors import GigapointError, InputError

AUTZEN = str(Path(__file__).resolve().parents[2].parent / "shared" / "data" / "autzen_trim.laz")  # (../shared beside the clone)
ORIGIN = (500_000.0, 4_000_000.0)  # a UTM-sized corner, on every grid below
SPACING = 0.2  # of the synthetic surveys' points, at cell centres: 0.1, 0.3, ...
BOX = (10.0, 5.0, 10.0, 20.0, 3.0)  # x, y (from ORIGIN), width, length, height: 600 units³ of fill
PIT = (28.0, 28.0, 5.0, 5.0, -2.0)  # 50 units³ of cut


def plane(size_x=40.0, size_y=40.0):
    """Points every SPACING over a size_x x size_y square at z 0, coordinates from (0, 0)."""
    x, y = np.meshgrid(np.arange(SPACING / 2, size_x, SPACING), np.arange(SPACING / 2, size_y, SPACING))
    return np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])


def with_blocks(xyz, offset=0.0):
    """``xyz`` with BOX's top raised and PIT's floor sunk, both moved ``offset`` in x and y."""
    xyz = xyz.copy()
    for x0, y0, w, length, h in (BOX, PIT):
        inside = (xyz[:, 0] >= x0 + offset) & (xyz[:, 0] < x0 + offset + w) & (xyz[:, 1] >= y0 + offset) & (xyz[:, 1] < y0 + offset + length)
        xyz[inside, 2] = h
    return xyz


def volume_error_bound(width, length, height, gsd):
    """How far a width x length block drawn on a gsd grid can be from its volume: the pixels its
    outline crosses count whole or not at all, so the footprint drawn lies between the outline
    grown and shrunk by one pixel on every side."""
    grown = (width + 2 * gsd) * (length + 2 * gsd) - width * length
    shrunk = width * length - max(width - 2 * gsd, 0) * max(length - 2 * gsd, 0)
    return abs(height) * max(grown, shrunk)


@pytest.mark.parametrize("offset", [0.0, 0.3])
def test_a_box_is_fill_and_a_pit_is_cut(offset):
    """On pixel edges (offset 0) the volumes are exact; moved off them (0.3) they are within the
    grid's discretisation error, which is not zero there."""
    gsd = 0.5
    before = gp.from_arrays(plane())
    after = gp.from_arrays(with_blocks(plane(), offset))
    c = gp.change(before, after, gsd)
    fill_error = volume_error_bound(*BOX[2:], gsd)
    cut_error = volume_error_bound(*PIT[2:], gsd)
    assert (fill_error, cut_error) == (93.0, 22.0)
    if offset == 0:
        assert (c.fill, c.cut, c.net) == (600.0, 50.0, 550.0)
    else:
        assert 0 < abs(c.fill - 600) <= fill_error and 0 < abs(c.cut - 50) <= cut_error
        assert (c.fill, c.cut) == (3 * 10.5 * 20.5, 2 * 4.5 * 4.5)  # the box's 21 x 41 pixels touched, the pit's 9 x 9 wholly inside
    assert c.area_compared == 40 * 40 and c.dz.shape == (80, 80)
    assert set(np.unique(c.dz)) == {-2.0, 0.0, 3.0}
    assert c.area_changed == (c.fill / 3 + c.cut / 2)
    assert c.summary()["units"] == {"length": "units", "area": "square units", "volume": "cubic units"}  # arrays name no CRS


def test_min_change_leaves_small_changes_out():
    c = gp.change(gp.from_arrays(plane()), gp.from_arrays(with_blocks(plane())), 0.5, min_change=2.5)
    assert (c.fill, c.cut, c.area_changed, c.area_compared) == (600.0, 0.0, 200.0, 1600.0)  # the pit's 2 is no change beyond 2.5
    c = gp.change(gp.from_arrays(plane()), gp.from_arrays(with_blocks(plane())), 0.5, min_change=3.0)
    assert (c.fill, c.cut, c.area_changed) == (0.0, 0.0, 0.0)  # 'by more than'


def test_a_move_of_exactly_min_change_is_left_out_whatever_the_float32_rounding():
    """Heights of 400-520 (a LAS grid of 0.01) moved exactly -2 and +3: float32 gives |dz| an ulp
    either side (2.0000305 in 22 of the 800 pixels moved 2); min_change 2 leaves all of those out."""
    x, y = (a.ravel() for a in np.meshgrid(np.arange(0.5, 40), np.arange(0.5, 40)))  # one point a pixel, at its centre
    z = np.round(np.random.default_rng(0).uniform(400, 520, x.size), 2)
    before = np.column_stack([x + ORIGIN[0], y + ORIGIN[1], z])
    after = before.copy()
    after[:, 2] += np.where(x < 20, -2.0, 3.0)
    c = gp.change(gp.from_arrays(before), gp.from_arrays(after), 1, min_change=2)
    assert ((np.abs(c.dz[:, :20]) > 2).sum(), c.resolution) == (22, 2**-13)  # the rounding that bit
    assert (c.cut, c.area_changed) == (0.0, 800.0) and c.fill == pytest.approx(2400, abs=0.01)
    c = gp.change(gp.from_arrays(before), gp.from_arrays(after), 1)  # min_change 0: every pixel moved
    assert c.area_changed == 1600.0 and c.cut == pytest.approx(1600, abs=0.01)


def test_the_preview_is_symmetric_around_zero():
    """Red where cut, white where unchanged, blue where filled, transparent where not compared;
    by default spanning the 98th percentile of the changed pixels' |dz| (the box's 3 here: 800 of their 900)."""
    before = gp.from_arrays(plane())
    after = gp.from_arrays(with_blocks(plane(40.0, 44.0)))  # 4 more units north: not compared
    c = gp.change(before, after, 0.5)
    assert c.preview_range() == 3.0 and c.dz.shape == (88, 80)
    image = c.preview()
    box, pit, flat, north = image[88 - 20, 25], image[88 - 60, 60], image[88 - 2, 2], image[2, 2]  # (row 0 is the top)
    assert tuple(box) == (0x05, 0x30, 0x61, 255)  # +3: RdBu's end
    assert tuple(flat) == (0xF7, 0xF7, 0xF7, 255) or abs(int(flat[0]) - 0xF7) <= 2  # 0: its white middle
    assert pit[0] > 200 and pit[2] < pit[0] and pit[3] == 255  # -2 of 3: on the red side
    assert tuple(north) == (0, 0, 0, 0)
    assert tuple(c.preview(2.0)[88 - 60, 60]) == (0x67, 0x00, 0x1F, 255)  # a range of 2: the pit at RdBu's red end
    with pytest.raises(InputError, match="the preview's range must be a number > 0"):
        c.preview(0)


def test_surveys_that_share_no_pixel_are_refused():
    far = plane() + (100.0, 0.0, 0.0)
    with pytest.raises(InputError, match=r"^arrays and arrays: the surveys do not overlap \(arrays x 0.1..39.9, y 0.1..39.9; arrays x 100.1..139.9, y 0.1..39.9\): nothing to compare$"):
        gp.change(gp.from_arrays(plane()), gp.from_arrays(far), 0.5)
    corners = np.concatenate([plane(10, 10), plane(10, 10) + (30.0, 30.0, 0.0)])  # boxes that meet, points that do not
    with pytest.raises(InputError, match="arrays and arrays: no 0.5-unit pixel holds points of both: the surveys do not overlap"):
        gp.change(gp.from_arrays(corners), gp.from_arrays(plane(10, 10) + (15.0, 15.0, 0.0)), 0.5)
    for bad, message in (({"gsd": 0}, "gsd must be a number > 0"), ({"min_change": -1}, "min_change must be a number >= 0"), ({"fill_nodata": 0}, "fill_nodata")):
        with pytest.raises(InputError, match=message):
            gp.change(gp.from_arrays(plane()), gp.from_arrays(plane()), **{"gsd": 0.5, **bad})


# --- the command: LAS files in a CRS ---------------------------------------------------------------

EPSG_32610_KEYS = [(1024, 0, 1, 1), (3072, 0, 1, 32610)]  # LAS 1.2 GeoTIFF keys: projected, UTM 10N
EPSG_4326_KEYS = [(1024, 0, 1, 2), (2048, 0, 1, 4326)]  # geographic, WGS 84: x and y in degrees
EPSG_4326_METRES_UP_KEYS = [*EPSG_4326_KEYS, (4099, 0, 1, 9001)]  # and heights in metres (VerticalUnitsGeoKey)
DEGREES_SCALE = (1e-7, 1e-7, 0.01)  # x and y to ~1 cm in degrees
DEGREES_ORIGIN = (-123.0, 44.0)  # Oregon, in longitude and latitude


def write_las(path, xyz, keys=EPSG_32610_KEYS, wkt=None, scale=(0.01, 0.01, 0.01), origin=ORIGIN):
    """A LAS 1.2 file of ``xyz`` (from ``origin``, stored at ``scale``) naming its CRS by GeoTIFF
    ``keys``, or by ``wkt`` (a WKT VLR) where given."""
    header = laspy.LasHeader(point_format=0, version="1.2")
    header.scales, header.offsets = np.array(scale), np.array([*origin, 0.0])
    data = struct.pack("<4H", 1, 1, 0, len(keys)) + b"".join(struct.pack("<4H", *k) for k in keys)
    header.vlrs.append(WktCoordinateSystemVlr(wkt) if wkt else laspy.VLR("LASF_Projection", 34735, "GeoKeyDirectoryTag", data))
    las = laspy.LasData(header)
    las.x, las.y, las.z = (xyz + (*origin, 0.0)).T
    las.write(str(path))
    return path


def write_degrees_grid(path, n, height=lambda x, y: np.full(x.size, 2.0), origin=DEGREES_ORIGIN, keys=EPSG_4326_KEYS):
    """A LAS file in WGS 84 (EPSG:4326 keys, x and y at DEGREES_SCALE): n x n points 0.00002
    degrees apart from ``origin`` (n = 40: 0.0008 degrees square), at ``height(x, y)`` of their
    offsets in degrees (2 by default); ``keys``: its GeoTIFF keys (EPSG_4326_METRES_UP_KEYS: heights in metres)."""
    g = np.arange(n) * 0.00002
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    return write_las(path, np.column_stack([x, y, height(x, y)]), keys=keys, scale=DEGREES_SCALE, origin=origin)


def refused_writing_nothing(classify, path, out, **options) -> str:
    """The one-line InputError of ``classify(path, out, **options)`` (a classification refused in
    degrees), checking it left no ``out``."""
    with pytest.raises(InputError) as caught:
        classify(path, out, **options)
    assert not out.exists()
    return str(caught.value)


@pytest.fixture
def surveys(tmp_path):
    """before.las (the plane) and after.las (the box and the pit, its plane 4 units longer north), EPSG:32610."""
    return write_las(tmp_path / "before.las", plane()), write_las(tmp_path / "after.las", with_blocks(plane(40.0, 44.0)))


def test_cli_writes_the_differences_as_a_geotiff_in_the_inputs_crs(cli, tmp_path, surveys):
    rasterio = pytest.importorskip("rasterio")
    out = tmp_path / "change.tif"
    rc, stdout, err = cli("change", *surveys, "--gsd", 0.5, "-o", out, "--preview", tmp_path / "change.png")
    assert rc == 0, err
    assert stdout.splitlines()[:2] == [f"wrote {out} (80x88, after - before, NaN where either survey has no point)", f"wrote {tmp_path / 'change.png'}, {tmp_path / 'change.tfw'}, {tmp_path / 'change.pgw'}, {tmp_path / 'change.prj'}"]
    assert "compared 1,600.00 m² (6,400 pixels of 0.5 m)" in stdout and "changed by more than 0 m: 225.00 m²" in stdout
    assert "cut  50.000 m³\nfill 600.000 m³\nnet  +550.000 m³\n" in stdout
    with rasterio.Env(GDAL_GEOREF_SOURCES="INTERNAL"), rasterio.open(out) as ds:  # its own tags, not the .tfw beside it
        assert ds.crs.to_epsg() == 32610 and ds.dtypes == ("float32",) and np.isnan(ds.nodata)
        assert ds.transform[:6] == pytest.approx((0.5, 0, ORIGIN[0], 0, -0.5, ORIGIN[1] + 44), rel=0, abs=1e-9)
        dz = ds.read(1)
        # the box's cell centre (x 15, y 15) and the pit's (30.5, 30.5), through GDAL's own transform
        assert dz[ds.index(ORIGIN[0] + 15, ORIGIN[1] + 15)] == 3.0 and dz[ds.index(ORIGIN[0] + 30.5, ORIGIN[1] + 30.5)] == -2.0
        assert np.isnan(dz[ds.index(ORIGIN[0] + 15, ORIGIN[1] + 42)])  # only the after survey reaches there
    assert np.isnan(dz[:8]).all() and not np.isnan(dz[8:]).any() and (dz[8:] == 0).sum() == 6400 - 225 * 4
    preview = np.asarray(Image.open(tmp_path / "change.png"))
    assert preview.shape == (88, 80, 4) and (preview[:8, :, 3] == 0).all() and (preview[8:, :, 3] == 255).all()


def test_write_geotiff_and_write_preview_write_the_bytes_the_cli_writes(cli, tmp_path, surveys):
    """Change.write_geotiff / write_preview: the CLI's files from Python; the preview keeps the
    .prj the GeoTIFF wrote beside it (the same CRS), as the CLI writes one for both."""
    rasterio = pytest.importorskip("rasterio")
    (tmp_path / "cli").mkdir()
    rc, _, err = cli("change", *surveys, "--gsd", 0.5, "-o", tmp_path / "cli/change.tif", "--preview", tmp_path / "cli/change.png", "--range", 2)
    assert rc == 0, err
    result = gp.change(*surveys, 0.5)
    assert [p.name for p in result.write_geotiff(tmp_path / "change.tif")] == ["change.tif", "change.tfw", "change.prj"]
    assert [p.name for p in result.write_preview(tmp_path / "change.png", limit=2)] == ["change.png", "change.pgw"]
    for name in ("change.tif", "change.tfw", "change.png", "change.pgw", "change.prj"):
        assert (tmp_path / name).read_bytes() == (tmp_path / "cli" / name).read_bytes(), name
    with rasterio.Env(GDAL_GEOREF_SOURCES="INTERNAL"), rasterio.open(tmp_path / "change.tif") as ds:
        assert ds.crs.to_epsg() == 32610 and np.isnan(ds.nodata)
        assert ds.transform[:6] == pytest.approx((0.5, 0, ORIGIN[0], 0, -0.5, ORIGIN[1] + 44), rel=0, abs=1e-9)
        np.testing.assert_array_equal(ds.read(1), result.dz)


def test_write_geotiff_refuses_an_existing_file_and_other_types(tmp_path, surveys):
    result = gp.change(*surveys, 0.5)
    with pytest.raises(GigapointError, match=r"c\.png: unsupported output type '\.png'; use one of \.tif, \.tiff$"):
        result.write_geotiff(tmp_path / "c.png")
    (tmp_path / "c.tfw").write_text("precious")
    with pytest.raises(GigapointError, match=r"c\.tfw: already exists; pass overwrite=True to replace it$"):
        result.write_geotiff(tmp_path / "c.tif")
    assert not (tmp_path / "c.tif").exists() and (tmp_path / "c.tfw").read_text() == "precious"
    assert [p.name for p in result.write_geotiff(tmp_path / "c.tif", overwrite=True)] == ["c.tif", "c.tfw", "c.prj"]


def test_cli_json_of_autzen_against_itself_is_no_change(cli, tmp_path, autzen_path):
    rc, stdout, err = cli("change", autzen_path, autzen_path, "--gsd", 4, "-o", tmp_path / "c.tif", "--json")
    assert rc == 0, err
    summary = json.loads(stdout)
    assert (summary["cut"], summary["fill"], summary["net"], summary["area_changed"]) == (0.0, 0.0, 0.0, 0.0)
    assert summary["area_compared"] == summary["pixels_compared"] * 16 > 300_000
    assert summary["units"] == {"length": "ft", "area": "ft²", "volume": "ft³"}  # autzen is in (international) feet
    assert summary["outputs"] == [str(tmp_path / p) for p in ("c.tif", "c.tfw", "c.prj")]
    dz = np.asarray(Image.open(tmp_path / "c.tif"))
    assert (dz[~np.isnan(dz)] == 0).all() and (~np.isnan(dz)).sum() == summary["pixels_compared"]


def test_autzen_raised_one_foot_is_its_area_in_cubic_feet(tmp_path, autzen_path):
    las = laspy.read(autzen_path)
    las.z = las.z + 1.0
    las.write(str(tmp_path / "raised.laz"))
    c = gp.change(autzen_path, tmp_path / "raised.laz", 4)
    moved = c.dz[c.compared]
    # float32 heights (eye - depth) near autzen's 406..521 ft: each a few ulps of the highest off
    ulps = 4 * float(np.spacing(np.float32(521.0)))
    assert np.abs(moved - 1.0).max() <= ulps
    assert c.cut == 0.0 and abs(c.net - c.area_compared) <= c.area_compared * ulps and c.area_compared > 300_000
    assert c.area_changed == c.area_compared


def test_float32_rounding_is_no_change(tmp_path, autzen_path):
    """A stockpile raised 8 ft and a pit dug 5 ft below autzen's lowest point: the after cloud's
    box, so its batches, differ, and points that did not move come out an ulp (3e-5 ft) apart in
    ~1 % of the pixels. They are neither changed area nor volume nor the preview's range."""
    las = laspy.read(autzen_path)
    x, y = np.asarray(las.x), np.asarray(las.y)
    blocks = {(636_500, 849_100, 636_600, 849_160): 8.0, (636_900, 849_300, 636_940, 849_340): -5.0}
    z = np.asarray(las.z).copy()
    for (x0, y0, x1, y1), dz in blocks.items():
        z[(x > x0) & (x < x1) & (y > y0) & (y < y1)] += dz
    las.z = z
    las.write(str(tmp_path / "dug.laz"))
    c = gp.change(autzen_path, tmp_path / "dug.laz", 2)
    a, _, _, e, left, top = c.camera.world_file()
    px, py = np.meshgrid(left + a * np.arange(c.dz.shape[1]), top + e * np.arange(c.dz.shape[0]))  # pixel centres
    near = {dz: (px > x0 - 2) & (px < x1 + 2) & (py > y0 - 2) & (py < y1 + 2) for (x0, y0, x1, y1), dz in blocks.items()}  # within a pixel
    elsewhere = c.compared & ~near[8.0] & ~near[-5.0]
    assert c.resolution == 2 * float(np.spacing(np.float32(520.51)))  # (autzen's highest point: 1.2e-4 ft)
    assert (c.dz[elsewhere] != 0).sum() > 500 and np.abs(c.dz[elsewhere]).max() <= c.resolution
    assert not (c.changed & elsewhere).any()
    for dz, there in near.items():
        assert np.abs(c.dz[c.changed & there] - dz).max() <= c.resolution
    assert c.area_changed == 4 * int((c.changed & (near[8.0] | near[-5.0])).sum())
    assert c.preview_range() == pytest.approx(8.0, abs=c.resolution)


def test_cli_refuses_surveys_in_different_crss(cli, tmp_path, surveys, autzen_path):
    rc, _, err = cli("change", autzen_path, surveys[1], "--gsd", 4, "-o", tmp_path / "c.tif")
    assert rc == 1 and err.count("\n") == 1, err
    assert err.startswith(f"error: {autzen_path} is in NAD_1983_HARN_Lambert_Conformal_Conic (WKT), lengths in ft; {surveys[1]} in EPSG:32610, lengths in m: change compares two surveys in one CRS")
    assert not list(tmp_path.glob("c.*"))


@pytest.mark.parametrize("pyproj_installed", [True, False])
def test_one_compound_crs_as_geotiff_keys_and_as_wkt_is_compared_another_zone_refused(tmp_path, pyproj_installed, monkeypatch):
    """EPSG:26910+5703 as GeoTIFF keys with a vertical code in one survey, as GDAL's COMPD_CS in
    the other: one CRS (it was refused as two, "change compares two surveys in one CRS"), with
    pyproj or without; the next zone's COMPD_CS is still refused."""
    without_pyproj(pyproj_installed, monkeypatch)
    keys = [(1024, 0, 1, 1), (3072, 0, 1, 26910), (4096, 0, 1, 5703)]  # projected, UTM 10N (NAD83), NAVD88 heights
    before = write_las(tmp_path / "before.las", plane(), keys)
    after = write_las(tmp_path / "after.las", with_blocks(plane()), wkt=UTM10_NAVD88_WKT1)
    c = gp.change(before, after, 0.5)
    assert c.crs == "EPSG:26910+5703" and c.summary()["fill"] == pytest.approx(600, abs=volume_error_bound(*BOX[2:], 0.5))
    other = write_las(tmp_path / "other.las", with_blocks(plane()), wkt=UTM11_NAVD88_WKT1)
    with pytest.raises(InputError, match=rf"^{before} is in EPSG:26910\+5703, .*; {other} in NAD83 / UTM zone 11N \+ NAVD88 height \(WKT\), .*: change compares two surveys in one CRS"):
        gp.change(before, other, 0.5)


@pytest.mark.parametrize(
    "args, message",
    [
        (["--gsd", "0"], "--gsd must be a number > 0 and at most 2e+12 (cloud units per pixel), got 0"),
        (["--gsd", "1", "--min-change", "-1"], "--min-change must be a number >= 0"),
        (["--gsd", "1", "--range", "2"], "--range: an option of --preview"),
        (["--gsd", "1", "--fill-nodata", "x"], "--fill-nodata must be 'all' or a whole number of pixels >= 1, got 'x'"),
        (["--gsd", "1", "--classes", "300"], "change: --classes 300"),
    ],
)
def test_cli_option_errors_are_one_line(cli, tmp_path, surveys, args, message):
    rc, _, err = cli("change", *surveys, "-o", tmp_path / "c.tif", *args)
    assert rc == 1 and err.count("\n") == 1 and message in err, err
    assert not list(tmp_path.glob("c.*"))


def test_cli_outputs_are_never_replaced_without_overwrite(cli, tmp_path, surveys):
    rc, _, err = cli("change", *surveys, "--gsd", 0.5, "-o", tmp_path / "c.png")
    assert rc == 1 and "c.png: unsupported output type '.png'; use one of .tif, .tiff" in err
    for existing in ("c.tif", "c.tfw", "p.png", "p.pgw"):
        (tmp_path / existing).write_text("precious")
        rc, _, err = cli("change", *surveys, "--gsd", 0.5, "-o", tmp_path / "c.tif", "--preview", tmp_path / "p.png")
        assert rc == 1 and err.strip() == f"error: {tmp_path / existing}: already exists; pass --overwrite to replace it", err
        assert sorted(p.name for p in tmp_path.iterdir()) == ["after.las", "before.las", existing]
        (tmp_path / existing).unlink()
    (tmp_path / "c.tif").write_text("precious")
    rc, _, err = cli("change", *surveys, "--gsd", 0.5, "-o", tmp_path / "c.tif", "--overwrite")
    assert rc == 0, err
    assert np.asarray(Image.open(tmp_path / "c.tif")).shape == (88, 80)


def test_cli_keeps_the_prj_of_the_same_map_and_refuses_another_maps(cli, tmp_path, surveys):
    """d.png's d.prj holds the surveys' CRS: d.tif beside it keeps it (it was refused, 'already
    exists', though Change.write_geotiff keeps it); a .prj of another CRS, or any .prj beside a
    map of no CRS (it would describe another map), is refused without --overwrite; one another
    map beside it uses (d.pgw), whatever is passed."""
    rc, _, err = cli("change", *surveys, "--gsd", 1, "-o", tmp_path / "d1.tif", "--preview", tmp_path / "d.png")
    assert rc == 0, err
    prj = (tmp_path / "d.prj").read_bytes()
    rc, out, err = cli("change", *surveys, "--gsd", 1, "-o", tmp_path / "d.tif", "--json")
    assert rc == 0, err
    assert json.loads(out)["outputs"] == [str(tmp_path / "d.tif"), str(tmp_path / "d.tfw")]
    assert (tmp_path / "d.prj").read_bytes() == prj == (tmp_path / "d1.prj").read_bytes()
    (tmp_path / "e.prj").write_text('PROJCS["some other map"]')
    no_crs = [write_las(tmp_path / f"{name}_no_crs.las", plane(), keys=[]) for name in ("before", "after")]
    # (d.prj is d.png's map's too, d.pgw beside it: refused even with --overwrite, which would remove it)
    shared = "holds the CRS of the map beside it (d.pgw), which these inputs do not name: write this map under another name"
    for inputs, existing, why in ((surveys, "e.prj", "already exists; pass --overwrite to replace it"), (no_crs, "d.prj", shared)):
        rc, _, err = cli("change", *inputs, "--gsd", 1, "-o", tmp_path / f"{existing[0]}2.tif", "--preview", tmp_path / f"{existing[0]}.jpg")
        assert rc == 1 and err.strip() == f"error: {tmp_path / existing}: {why}", err
        assert not list(tmp_path.glob(f"{existing[0]}2.*")) and not list(tmp_path.glob(f"{existing[0]}.j*"))
    assert (tmp_path / "e.prj").read_text() == 'PROJCS["some other map"]' and (tmp_path / "d.prj").read_bytes() == prj


def test_cli_leaves_nothing_half_written(cli, tmp_path, surveys, monkeypatch):
    """A failed write (a full disk at the world file) takes back the GeoTIFF and preview written
    before it; a failure before any write (no overlap) writes nothing."""
    from gigapoint.render import georef

    def full_disk(camera, path):
        raise OSError(28, "No space left on device", str(path))

    monkeypatch.setattr(georef, "write_world_file", full_disk)
    rc, _, err = cli("change", *surveys, "--gsd", 0.5, "-o", tmp_path / "c.tif", "--preview", tmp_path / "p.png")
    assert rc == 1 and f"{tmp_path / 'c.tfw'}: No space left on device" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["after.las", "before.las"]  # no temporary file either
    monkeypatch.undo()
    far = write_las(tmp_path / "far.las", plane() + (100.0, 0.0, 0.0))
    rc, _, err = cli("change", surveys[0], far, "--gsd", 0.5, "-o", tmp_path / "c.tif")
    assert rc == 1 and "the surveys do not overlap" in err
    assert not list(tmp_path.glob("c.*"))


def test_cli_filters_read_the_same_classes_of_both(cli, tmp_path, autzen_path):
    """--classes 2: ground against ground (autzen's classes 1 and 2): the pixels compared are
    those `render --classes 2 --gsd 4 --depth-out` draws, fewer than of every point."""
    rc, stdout, err = cli("change", autzen_path, autzen_path, "--gsd", 4, "-o", tmp_path / "all.tif", "--json")
    every = json.loads(stdout)["pixels_compared"]
    rc, stdout, err = cli("change", autzen_path, autzen_path, "--gsd", 4, "-o", tmp_path / "ground.tif", "--json", "--classes", "2")
    assert rc == 0, err
    rc, _, err = cli("render", autzen_path, "--classes", "2", "--gsd", 4, "-o", tmp_path / "o.png", "--depth-out", tmp_path / "dtm.tif", "--size-mode", "fixed")
    assert rc == 0, err
    dtm = np.asarray(Image.open(tmp_path / "dtm.tif"))
    assert json.loads(stdout)["pixels_compared"] == (~np.isnan(dtm)).sum() < every
    dz = np.asarray(Image.open(tmp_path / "ground.tif"))
    assert (np.isnan(dz) == np.isnan(dtm)).all()  # the same grid, pixel for pixel


def test_a_gsd_too_fine_for_the_surveys_grid_names_both_surveys(cli, tmp_path, surveys):
    """The grid spans both surveys: its size error names them (it named no file), in one line."""
    far = write_las(tmp_path / "far.las", np.vstack([plane(), [20_000.0, 0.0, 0.0]]))  # one point 20 km east
    rc, _, err = cli("change", surveys[0], far, "--gsd", 1, "-o", tmp_path / "c.tif")
    assert rc == 1 and not list(tmp_path.glob("c.*"))
    assert err.strip().splitlines() == [
        f"error: {surveys[0]} and {far}: gsd 1 makes a 20,001x41 image, over 16,384 pixels a side: a gsd of 1.23 or more fits"
    ]


# --- octree inputs: a converted folder, a COPC file -------------------------------------------------


@pytest.fixture(scope="module")
def autzen_octrees(tmp_path_factory):
    """autzen_trim converted to a gigapoint octree folder and a COPC file (each point in one node)."""
    if not Path(AUTZEN).exists():
        pytest.skip(f"shared sample {AUTZEN} not present")
    out = tmp_path_factory.mktemp("octrees")
    gp.convert([AUTZEN], out / "autzen_octree")
    gp.convert([AUTZEN], out / "autzen.copc.laz", format="copc")
    return {"gigapoint": out / "autzen_octree", "copc": out / "autzen.copc.laz"}


@pytest.mark.parametrize("kind", ["gigapoint", "copc"])
@pytest.mark.parametrize("octree_first", [True, False])
def test_an_octree_against_its_point_file_is_no_change(autzen_octrees, kind, octree_first):
    """Every point of the octree's nodes, at its LAS coordinates (the nodes' 30-bit positions put
    back on the 0.01 ft grid: off it, points on a pixel edge fell into the next pixel, 9.2 ft of
    change in 20 pixels), gives the LAZ file's surface exactly."""
    pair = (autzen_octrees[kind], AUTZEN) if octree_first else (AUTZEN, autzen_octrees[kind])
    c = gp.change(*pair, 4)
    itself = gp.change(AUTZEN, AUTZEN, 4)
    assert (c.dz[c.compared] == 0).all() and (c.cut, c.fill, c.area_changed) == (0.0, 0.0, 0.0)
    assert (c.compared == itself.compared).all() and c.compared.sum() == 23_613
    assert c.summary()["units"] == {"length": "ft", "area": "ft²", "volume": "ft³"} and c.crs == itself.crs  # the octree's CRS, from its metadata
    ground = gp.change(*pair, 4, classes=[2])  # the filter read through the nodes meeting it
    assert (ground.compared == gp.change(AUTZEN, AUTZEN, 4, classes=[2]).compared).all() and ground.area_changed == 0.0


def test_an_octree_drawn_a_few_nodes_at_a_time_is_the_same_surface(autzen_octrees, monkeypatch):
    """At most 20,000 points a draw (6+ draws of autzen's 110,000), each pixel the highest of
    the draws': the surface of one draw, but where a point lies exactly on a pixel edge (autzen's
    0.01 ft grid meets the 4 ft one): each draw's batches have their own float32 transforms, which
    put it on either side (~0.1 % of the pixels)."""
    from gigapoint.survey import change as change_module

    whole = gp.change(autzen_octrees["copc"], AUTZEN, 4)
    monkeypatch.setattr(change_module, "STREAM_POINTS", 20_000)
    drawn = gp.change(autzen_octrees["copc"], AUTZEN, 4)
    both = whole.compared & drawn.compared
    apart = np.abs(drawn.before - whole.before)[both] > drawn.resolution
    assert both.sum() >= 23_613 - 30 and 0 < apart.sum() <= 30
    assert drawn.area_changed == 16 * apart.sum()  # (the same pixels: the after survey is the LAZ file, drawn whole)


def test_an_octree_against_a_copy_raised_one_foot_is_one_foot_of_fill(tmp_path, autzen_octrees):
    las = laspy.read(AUTZEN)
    las.z = las.z + 1.0
    las.write(str(tmp_path / "raised.las"))
    c = gp.change(autzen_octrees["copc"], tmp_path / "raised.las", 4)
    assert c.compared.sum() == 23_613 and np.abs(c.dz[c.compared] - 1.0).max() <= c.resolution  # (each height rounded to float32 once)
    assert c.cut == 0.0 and abs(c.fill - c.area_compared) <= c.area_compared * c.resolution and c.area_changed == c.area_compared


def test_cli_compares_an_octree_folder_with_a_point_file(cli, tmp_path, autzen_octrees):
    rc, stdout, err = cli("change", autzen_octrees["gigapoint"], AUTZEN, "--gsd", 4, "-o", tmp_path / "c.tif", "--json")
    assert rc == 0, err
    summary = json.loads(stdout)
    assert (summary["cut"], summary["fill"], summary["area_changed"], summary["units"]["volume"]) == (0.0, 0.0, 0.0, "ft³")
    assert summary["pixels_compared"] == 23_613  # autzen against itself's


def test_an_opened_octree_takes_no_other_filter(autzen_octrees):
    octree = gp.open(autzen_octrees["gigapoint"])
    c = gp.change(octree, AUTZEN, 4)
    assert c.compared.sum() == 23_613 and (c.dz[c.compared] == 0).all()
    with pytest.raises(InputError, match=r"^autzen_trim: an opened LOD octree reads no other filter; give its path"):
        gp.change(octree, AUTZEN, 4, classes=[2])


# --- a coarse gsd reads an octree's upper levels only ------------------------------------------------

COARSE_GSD = 16.0  # a quarter of it, 4 ft: autzen_layered's levels 0-2 (9.2, 4.6, 2.3 ft), not 3-4


def nodes_read(monkeypatch, octree) -> list:
    """A list that gathers the indices of the nodes ``octree`` reads (its ``node_points``)."""
    read: list = []
    node_points = octree.node_points

    def counted(index):
        read.append(index)
        return node_points(index)

    monkeypatch.setattr(octree, "node_points", counted)
    return read


@pytest.mark.parametrize("kind", ["gigapoint", "copc"])
def test_points_meeting_stops_at_the_first_level_as_dense_as_asked(autzen_layered, kind):
    from gigapoint.io.filters import PointFilter
    from gigapoint.lod.query import deepest_level, points_meeting

    octree = gp.open(autzen_layered[kind])
    everywhere = PointFilter().meets
    assert [deepest_level(octree, s) for s in (100.0, 9.2, 4.0, 2.3, 0.6, None)] == [0, 0, 2, 2, 4, None]
    down_to_2 = sum(map(len, points_meeting(octree, everywhere, max_spacing=4.0)))
    assert down_to_2 == 8_993 + 20_546 + 49_437  # levels 0, 1, 2 of the 110,000 points
    assert sum(map(len, points_meeting(octree, everywhere, max_spacing=100.0))) == 8_993  # the root only
    assert sum(map(len, points_meeting(octree, everywhere))) == 110_000


@pytest.mark.parametrize("kind", ["gigapoint", "copc"])
def test_a_coarse_gsd_reads_the_upper_levels_and_full_reads_every_point(autzen_layered, kind, monkeypatch):
    """At 16 ft the levels down to 2.3 ft (a quarter pixel) are read: 78,976 of autzen's 110,000
    points. Each pixel is then the highest of a sample of its points: never higher than every
    point's surface (but for the float32 heights' rounding), and in 98 % of the pixels within 0.5 ft
    of it, in 99 % within the spacing read (measured: 98.2 %, 99.5 %).
    ``full=True`` reads every node: the LAZ file's surface exactly, as before."""
    octree = gp.open(autzen_layered[kind])
    read = nodes_read(monkeypatch, octree)
    coarse = gp.change(octree, AUTZEN, COARSE_GSD)
    assert set(octree.levels[read]) == {0, 1, 2} and int(octree.counts[read].sum()) == 78_976
    read.clear()
    full = gp.change(octree, AUTZEN, COARSE_GSD, full=True)
    assert set(octree.levels[read]) == {0, 1, 2, 3, 4} and int(octree.counts[read].sum()) == 110_000
    assert (full.dz[full.compared] == 0).all() and full.compared.sum() == gp.change(AUTZEN, AUTZEN, COARSE_GSD).compared.sum() == 1_989
    both = coarse.compared & full.compared
    below = full.before[both] - coarse.before[both]  # how far the sample's surface lies below every point's
    assert both.sum() == 1_989 and (below >= -coarse.resolution).all()
    assert (np.abs(below) <= 0.5).mean() >= 0.98 and (np.abs(below) <= 2.3).mean() >= 0.99
    assert coarse.fill > 0 and coarse.cut == pytest.approx(0, abs=0.01 * coarse.fill)  # the LAZ file (after) a little higher


def test_cli_all_points_reads_every_node_of_an_octree(cli, autzen_layered, tmp_path):
    args = ("change", autzen_layered["gigapoint"], AUTZEN, "--gsd", COARSE_GSD, "--json", "-o")
    rc, coarse, err = cli(*args, tmp_path / "coarse.tif")
    assert rc == 0, err
    rc, every, err = cli(*args, tmp_path / "every.tif", "--all-points")
    assert rc == 0, err
    assert json.loads(coarse)["fill"] > 0 and (json.loads(every)["fill"], json.loads(every)["cut"]) == (0.0, 0.0)
    with pytest.raises(InputError, match=r"^change: full must be True or False, got 'yes'$"):
        gp.change(autzen_layered["gigapoint"], AUTZEN, COARSE_GSD, full="yes")


@pytest.mark.parametrize("octree_first", [True, False])
def test_one_survey_sampled_against_one_read_whole_is_warned_of(autzen_layered, octree_first, recwarn):
    """The sampled surface lies low: as BEFORE its fill comes out high (the same points: 9,922 ft³
    of fill and no cut), as AFTER its cut; one warning naming it and what to give."""
    octree = autzen_layered["copc"]
    c = gp.change(octree, AUTZEN, COARSE_GSD) if octree_first else gp.change(AUTZEN, octree, COARSE_GSD)
    bias = "fill comes out high and cut low" if octree_first else "cut comes out high and fill low"
    message = (
        f"change: {octree} is read down to the octree levels the gsd needs (a sample of its points), {AUTZEN} whole: "
        f"the sample's surface lies low where the ground is rough, so {bias}; --all-points (full=True) reads every point"
    )
    assert [str(w.message) for w in recwarn] == [message]
    assert (c.fill > 9_000 and c.cut == 0) if octree_first else (c.cut > 9_000 and c.fill == 0)


@pytest.mark.parametrize(
    "pair, full",
    [(("copc", "copc"), False), ((AUTZEN, AUTZEN), False), (("copc", AUTZEN), True)],
    ids=["both-sampled", "both-files", "all-points"],
)
def test_no_sampling_warning_where_both_surveys_are_read_alike(autzen_layered, pair, full, recwarn):
    gp.change(*(autzen_layered.get(p, p) for p in pair), COARSE_GSD, full=full)
    assert [str(w.message) for w in recwarn] == []


def test_cli_warns_of_one_sampled_survey_but_not_with_all_points(cli, autzen_layered, tmp_path):
    args = ("change", autzen_layered["gigapoint"], AUTZEN, "--gsd", COARSE_GSD, "--overwrite", "-o", tmp_path / "c.tif")
    rc, _, err = cli(*args)
    assert rc == 0 and err.count("warning: change: ") == 1 and f"{autzen_layered['gigapoint']} is read down to the octree levels" in err
    rc, _, err = cli(*args, "--all-points")
    assert rc == 0 and "warning" not in err


# --- surveys in different units ----------------------------------------------------------------------

FOOT, METRE = 'UNIT["foot",0.3048,AUTHORITY["EPSG","9002"]]', 'UNIT["metre",1,AUTHORITY["EPSG","9001"]]'


def test_a_survey_in_metres_against_one_in_feet_names_both_units(tmp_path, autzen_path):
    """autzen (its WKT in international feet) and a copy in metres: the same projection (its
    false easting 1,312,335.958 ft = 400,000 m), the same CRS name; the message tells them apart."""
    las = laspy.read(autzen_path)
    wkt = las.header.vlrs.get("WktCoordinateSystemVlr")[0].string.strip("\0")
    assert FOOT in wkt
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = np.array([0.001] * 3), np.zeros(3)
    header.vlrs.append(WktCoordinateSystemVlr(wkt.replace(FOOT, METRE).replace("1312335.958005249", "400000")))
    metres = laspy.LasData(header)
    metres.x, metres.y, metres.z = (np.asarray(las.x) * 0.3048, np.asarray(las.y) * 0.3048, np.asarray(las.z) * 0.3048)
    metres.write(str(tmp_path / "metres.las"))
    name = "NAD_1983_HARN_Lambert_Conformal_Conic (WKT)"
    with pytest.raises(InputError) as caught:
        gp.change(autzen_path, tmp_path / "metres.las", 4)
    assert str(caught.value) == (
        f"{autzen_path} is in {name}, lengths in ft; {tmp_path / 'metres.las'} in {name}, lengths in m: "
        "change compares two surveys in one CRS and unit; reproject one first (gigapoint convert --to-crs)"
    )


def test_one_crs_with_heights_in_another_unit_is_refused(tmp_path):
    """Both EPSG:32610 (metres), one with VerticalUnitsGeoKey foot: one CRS by its code, but its
    heights in feet would have been subtracted from heights in metres."""
    before = write_las(tmp_path / "before.las", plane())
    after = write_las(tmp_path / "after.las", plane(), keys=[*EPSG_32610_KEYS, (4099, 0, 1, 9002)])
    with pytest.raises(InputError, match=rf"^{before} is in EPSG:32610, lengths in m; {after} in EPSG:32610, lengths in m, heights in ft: change compares"):
        gp.change(before, after, 0.5)


def test_surveys_in_degrees_are_refused_not_measured_in_square_degrees(tmp_path):
    """Both in WGS 84 (GeoTIFF keys: geographic, EPSG:4326), the ground risen by 2 over a corner:
    the areas and volumes came out in square degrees, labelled as units (fill 3.2e-7: the
    command printed 'fill 0.000 cubic units', 'compared 0.00 square units'), though it rose."""
    paths = []
    for name, rise in (("before.las", 0.0), ("after.las", 2.0)):
        xyz = plane() * (0.00002, 0.00002, 1.0)  # 0.0008 x 0.0008 degrees from DEGREES_ORIGIN
        xyz[(xyz[:, 0] < 0.0004) & (xyz[:, 1] < 0.0004), 2] += rise
        paths.append(write_las(tmp_path / name, xyz, keys=EPSG_4326_KEYS, scale=DEGREES_SCALE, origin=DEGREES_ORIGIN))
    with pytest.raises(InputError) as caught:
        gp.change(*paths, 0.00002)
    assert str(caught.value) == (
        f"change: {paths[0]} has coordinates in degrees (EPSG:4326); measuring areas and volumes needs metres or feet: "
        "reproject first (gigapoint convert --to-crs EPSG:32610, WGS 84 / UTM zone 10N, where the data lie)"
    )
