"""Georeferenced top-down renders: `gigapoint render --gsd` (Camera.top_down) draws an orthophoto
on the gsd grid with a world file and a .prj beside it, and --depth-out a float32 surface model."""

from __future__ import annotations

import struct
import sys
from pathlib import Path

import laspy
import numpy as np
import pytest
from PIL import Image
from test_crs_units import geokeys_vlr  # tests/unit is on sys.path

import gigapoint as gp
from gigapoint.errors import CameraError, GigapointError
from gigapoint.io.las import read_las_header
from gigapoint.render.camera import MAX_IMAGE_SIDE

AUTZEN = str(Path(__file__).resolve().parents[2].parent / "shared" / "data" / "autzen_trim.laz")  # (../shared beside the clone)
AUTZEN_COPC = Path(__file__).parent / "data" / "pdal_ept" / "autzen_clip_native.copc.laz"  # PDAL's, in a compound CRS
GSD = 0.5
ORIGIN = np.array([637_000.0, 851_000.5, 100.0])  # a projected CRS's size of numbers, on the 0.5 grid


def grid_cloud(seed=0, n=300):
    """Points at the centres of random pixels of a 40 x 24 grid of GSD cells whose corner is
    ORIGIN (the box's min x and max y lie on cell edges), heights 100..110; also (columns, rows)
    of their cells counted from the left and from the top."""
    rng = np.random.default_rng(seed)
    cells = rng.choice(40 * 24, n, replace=False)
    cols, rows = cells % 40, cells // 40
    x = ORIGIN[0] + (cols + 0.5) * GSD
    y = ORIGIN[1] + 24 * GSD - (rows + 0.5) * GSD
    z = ORIGIN[2] + rng.uniform(0, 10, n)
    return np.column_stack([x, y, z]), cols, rows


def pixel_of(world_file, x, y):
    """(column, row) of world position (x, y) by the world file's inverse transform: the file
    gives the centre of pixel (0, 0) and the step to the next column and row."""
    a, _, _, e, c, f = world_file
    return np.floor((x - c) / a + 0.5).astype(int), np.floor((y - f) / e + 0.5).astype(int)


def read_world_file(path):
    return [float(line) for line in path.read_text().splitlines()]


def test_top_down_camera_lies_on_the_gsd_grid_and_covers_the_box():
    cam = gp.Camera.top_down(((0.3, 0.0, 0.0), (10.0, 6.2, 3.0)), GSD)
    # columns from floor(0.3 / 0.5) = 0 to floor(10 / 0.5) = 20 (x = 10 on the last column's left edge);
    # rows from ceil(6.2 / 0.5) = 13 (top y 6.5) down to ceil(0 / 0.5) = 0
    assert (cam.width, cam.height, cam.projection) == (21, 14, "orthographic")
    assert cam.world_file() == (0.5, 0.0, 0.0, -0.5, 0.25, 6.25)


def test_points_at_pixel_centres_land_in_the_pixels_the_world_file_names():
    """The rasterizer puts a point into pixel floor(px): the world file's pixel centres are where
    points land in the middle of their pixel, at UTM-sized coordinates."""
    xyz, cols, rows = grid_cloud()
    cam = gp.Camera.top_down((xyz.min(axis=0), xyz.max(axis=0)), GSD)
    assert (cam.width, cam.height) == (cols.max() - cols.min() + 1, rows.max() - rows.min() + 1)
    for adaptive in (True, False):  # 10-bit batches too: still within the pixel
        cloud = gp.from_arrays(xyz)
        frame = gp.render_frame(cloud, cam, size_mode="fixed", adaptive_precision=adaptive)
        col, row = pixel_of(cam.world_file(), xyz[:, 0], xyz[:, 1])
        np.testing.assert_array_equal(col, cols - cols.min())  # the inverse transform: the cells the points were put in
        np.testing.assert_array_equal(row, rows - rows.min())
        drawn = frame.index[row, col]
        assert (drawn >= 0).all() and (frame.index >= 0).sum() == len(xyz)  # each point in its own pixel, nothing else drawn
        np.testing.assert_allclose(cloud.positions(drawn), xyz, rtol=0, atol=1e-6)  # (30-bit positions)


def test_heights_are_the_points_z():
    xyz, _, _ = grid_cloud(seed=1)
    cam = gp.Camera.top_down((xyz.min(axis=0), xyz.max(axis=0)), GSD)
    cloud = gp.from_arrays(xyz)
    frame = gp.render_frame(cloud, cam, size_mode="fixed", adaptive_precision=False)
    heights = cam.heights(frame.depth)
    assert heights.dtype == np.float32
    col, row = pixel_of(cam.world_file(), xyz[:, 0], xyz[:, 1])
    np.testing.assert_allclose(heights[row, col], xyz[:, 2], rtol=0, atol=1e-5)  # float32 of heights 100..110: ~8e-6
    assert np.isnan(heights[frame.index < 0]).all()


def test_world_files_and_heights_need_a_top_down_camera():
    cam = gp.Camera.fit(((0, 0, 0), (1, 1, 1)), view=(0, 90), projection="orthographic")  # straight down, east up
    with pytest.raises(CameraError, match="needs an orthographic camera looking straight down, north up"):
        cam.world_file()
    with pytest.raises(CameraError, match="heights from depths needs"):
        cam.heights(np.zeros((2, 2)))


def test_a_gsd_too_fine_names_the_finest_that_fits():
    with pytest.raises(CameraError) as err:
        gp.Camera.top_down(((0, 0, 0), (10_000.0, 5.0, 1.0)), 0.5)
    assert str(err.value) == "gsd 0.5 makes a 20,002x12 image, over 16,384 pixels a side: a gsd of 0.611 or more fits"  # (a margin column and row: 0 and 5 lie on the grid)
    assert gp.Camera.top_down(((0, 0, 0), (10_000.0, 5.0, 1.0)), 0.611).width <= MAX_IMAGE_SIDE
    for bad in (0, -1, float("nan"), "1"):
        with pytest.raises(CameraError, match="gsd .ground sample distance. must be a number > 0"):
            gp.Camera.top_down(((0, 0, 0), (1, 1, 1)), bad)


def test_each_edge_of_the_box_lies_inside_the_image_by_a_margin():
    """A box whose corners lie on the gsd grid gets a column to the left and a row above (a point
    on the image's top or left edge was pushed out by the decoding's and float32's rounding); the
    pixel centres stay on the grid's half multiples."""
    cam = gp.Camera.top_down(((10.0, 20.0, 0.0), (13.0, 23.0, 1.0)), 1)
    # columns floor(10 - m) = 9 .. floor(13 + m) = 13; rows from ceil(23 + m) = 24 (top) down to ceil(20 - m) = 20
    assert (cam.width, cam.height) == (5, 5)
    assert cam.world_file() == (1.0, 0.0, 0.0, -1.0, 9.5, 23.5)
    # off the grid by more than the margin: the box's own columns and rows, as ever
    cam = gp.Camera.top_down(((10.1, 20.1, 0.0), (12.9, 22.9, 1.0)), 1)
    assert (cam.width, cam.height, cam.world_file()[4:]) == (3, 3, (10.5, 22.5))


def write_points_las(path, xyz):
    header = laspy.LasHeader(point_format=0, version="1.2")
    header.scales, header.offsets = np.array([0.01] * 3), np.zeros(3)
    las = laspy.LasData(header)
    las.x, las.y, las.z = np.asarray(xyz, float).T
    las.write(str(path))
    return path


@pytest.mark.parametrize("gsd", [1, 0.5])
@pytest.mark.parametrize(
    "xyz",
    [
        [[10, 20, 5]],  # a LAS point decodes ~5e-9 above its y: on the image's top edge it was dropped (a blank image)
        [[10, 20, 1], [13, 20, 2], [10, 23, 3], [13, 23, 4], [11, 22, 6]],  # the corners of the box and a point inside
    ],
)
def test_cli_draws_every_point_of_a_las_file_on_the_grid(cli, tmp_path, xyz, gsd):
    path = write_points_las(tmp_path / "grid.las", xyz)
    rc, out, err = cli("render", path, "-o", tmp_path / "o.png", "--gsd", gsd, "--depth-out", tmp_path / "dsm.tif", "--size-mode", "fixed")
    assert rc == 0 and "warning" not in err, err
    dsm = np.asarray(Image.open(tmp_path / "dsm.tif"))
    assert sorted(dsm[np.isfinite(dsm)].tolist()) == sorted(z for _, _, z in xyz)  # each point in a pixel of its own


def test_autzens_lowest_point_is_drawn():
    """autzen's lowest y (848,935.2) is a multiple of 0.3 that float64 puts a hair (5e-10) above the
    grid line: the image ended at that line, and float32 put the point on it, below the image
    (109,630 pixels were drawn)."""
    heights = gp.orthophoto(AUTZEN, 0.3, size_mode="fixed").heights
    assert heights.shape == (1877, 3926)
    assert np.isfinite(heights[-1]).any() and np.isfinite(heights).sum() == 109_631


@pytest.fixture
def grid_npy(tmp_path):
    xyz, cols, rows = grid_cloud()
    path = tmp_path / "grid.npy"
    np.save(path, xyz)
    return path, xyz


def test_cli_writes_the_orthophoto_its_world_file_and_the_dsm(cli, tmp_path, grid_npy):
    path, xyz = grid_npy
    rc, out, err = cli("render", path, "-o", tmp_path / "ortho.png", "--gsd", GSD, "--depth-out", tmp_path / "dsm.tif", "--size-mode", "fixed")
    assert rc == 0, err
    expected = "0.5\n0\n0\n-0.5\n637000.25\n851012.25\n"  # the centre of the top-left cell (grid_cloud)
    assert (tmp_path / "ortho.pgw").read_text() == expected
    assert (tmp_path / "dsm.tfw").read_text() == expected
    image = np.asarray(Image.open(tmp_path / "ortho.png"))
    dsm = np.asarray(Image.open(tmp_path / "dsm.tif"))
    assert dsm.dtype == np.float32 and dsm.shape == image.shape[:2] == (24, 40)
    col, row = pixel_of(read_world_file(tmp_path / "dsm.tfw"), xyz[:, 0], xyz[:, 1])
    np.testing.assert_allclose(dsm[row, col], xyz[:, 2], rtol=0, atol=1e-5)
    assert np.isnan(dsm).sum() == dsm.size - len(xyz)
    assert (image[row, col, :3] != 0).any(axis=1).all()  # drawn where the world file says (white points on black)
    assert "no .prj written: the inputs name no CRS" in out and not list(tmp_path.glob("*.prj"))


def test_cli_dsm_holds_each_pixels_highest_point_under_the_images_splats(cli, tmp_path, grid_npy):
    """With the default adaptive splats the DSM took the splats' depths: heights in pixels no point
    is in, and a neighbour's z where a splat covered a lower point. The image keeps its splats,
    the same with --depth-out as without."""
    path, xyz = grid_npy
    rc, _, err = cli("render", path, "-o", tmp_path / "ortho.png", "--gsd", GSD, "--depth-out", tmp_path / "dsm.tif")
    assert rc == 0, err
    dsm = np.asarray(Image.open(tmp_path / "dsm.tif"))
    col, row = pixel_of(read_world_file(tmp_path / "dsm.tfw"), xyz[:, 0], xyz[:, 1])
    np.testing.assert_allclose(dsm[row, col], xyz[:, 2], rtol=0, atol=1e-5)
    assert np.isnan(dsm).sum() == dsm.size - len(xyz)
    rc, _, err = cli("render", path, "-o", tmp_path / "alone.png", "--gsd", GSD)
    assert rc == 0, err
    image = np.asarray(Image.open(tmp_path / "ortho.png"))
    np.testing.assert_array_equal(image, np.asarray(Image.open(tmp_path / "alone.png")))
    assert (image[..., 3] > 0).sum() > 2 * len(xyz)  # splats


def test_pixels_no_point_reached_are_transparent_and_filled_ones_opaque(cli, tmp_path, grid_npy):
    """A map's empty pixels are no colour (alpha 0: GIS software and --colorize read an opaque
    background as black imagery); --fill-nodata's filled pixels take their neighbour's, opaque."""
    path, _ = grid_npy
    rc, _, err = cli("render", path, "-o", tmp_path / "ortho.png", "--gsd", GSD, "--depth-out", tmp_path / "dsm.tif", "--size-mode", "fixed")
    assert rc == 0, err
    alpha, dsm = np.asarray(Image.open(tmp_path / "ortho.png"))[..., 3], np.asarray(Image.open(tmp_path / "dsm.tif"))
    assert np.array_equal(alpha == 255, ~np.isnan(dsm)) and np.array_equal(alpha == 0, np.isnan(dsm)) and (alpha == 0).any()
    filled = gp.orthophoto(path, GSD, fill_nodata=1, size_mode="fixed")
    assert np.array_equal(filled.image[..., 3] == 255, ~np.isnan(filled.heights))  # (filled colours within 1 pixel, opaque)
    assert (filled.image[..., 3] == 255).sum() > (alpha == 255).sum()


def write_las(path, crs_vlr):
    header = laspy.LasHeader(point_format=0, version="1.2")
    header.scales, header.offsets = np.array([0.01] * 3), ORIGIN
    header.vlrs.append(crs_vlr)
    las = laspy.LasData(header)
    las.x, las.y, las.z = grid_cloud()[0].T
    las.write(str(path))


def test_cli_prj_holds_the_files_wkt(cli, tmp_path):
    """autzen's WKT (its LAS VLR) is the .prj beside both the image and the DSM, which share it."""
    out, dsm = tmp_path / "autzen.jpg", tmp_path / "autzen.tif"
    rc, stdout, err = cli("render", AUTZEN, "-o", out, "--gsd", 8, "--depth-out", dsm, "--size-mode", "fixed")
    assert rc == 0, err
    wkt = read_las_header(AUTZEN).crs()
    assert wkt.startswith('PROJCS["NAD_1983_HARN_Lambert_Conformal_Conic"')
    assert (tmp_path / "autzen.prj").read_text() == wkt
    assert sorted(p.name for p in tmp_path.iterdir()) == ["autzen.jgw", "autzen.jpg", "autzen.prj", "autzen.tfw", "autzen.tif"]
    assert "no .prj" not in stdout
    # the DSM's heights lie where the world file puts them: each drawn pixel's height is that of
    # autzen's highest point in it (read from the file: its exact values)
    las = laspy.read(AUTZEN)
    x, y, z = np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)
    heights = np.asarray(Image.open(dsm))
    a, _, _, e, c, f = read_world_file(tmp_path / "autzen.tfw")
    fc, fr = (x - c) / a + 0.5, (y - f) / e + 0.5  # pixel coordinates: column floor(fc), row floor(fr)
    highest = np.full(heights.shape, -np.inf)
    np.maximum.at(highest, (np.floor(fr).astype(int), np.floor(fc).astype(int)), z)
    # a point on a pixel edge (autzen's 0.01 grid meets the gsd's multiples) belongs to either pixel
    # as float32 rounds it: those pixels are left out
    unsure = np.zeros(heights.shape, bool)
    edge = (np.abs(fc - np.round(fc)) < 1e-3) | (np.abs(fr - np.round(fr)) < 1e-3)
    for eps in (-1e-3, 1e-3):
        unsure[np.floor(fr[edge] + eps).astype(int), np.floor(fc[edge] + eps).astype(int)] = True
    drawn = ~np.isnan(heights)
    assert drawn.mean() > 0.6 and (drawn & unsure).mean() < 0.1  # (autzen_trim is no rectangle)
    assert (drawn == np.isfinite(highest)).all()
    np.testing.assert_allclose(heights[drawn & ~unsure], highest[drawn & ~unsure], rtol=0, atol=1e-3)


def test_cli_an_epsg_only_crs_writes_no_prj_and_says_so(cli, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "pyproj", None)  # (import pyproj raises ImportError: an optional dependency)
    keys = [(1024, 0, 1, 1), (3072, 0, 1, 32610)]  # model type projected; ProjectedCSTypeGeoKey (LAS 1.2's GeoTIFF keys)
    data = struct.pack("<4H", 1, 1, 0, len(keys)) + b"".join(struct.pack("<4H", *k) for k in keys)
    write_las(tmp_path / "utm.las", laspy.VLR("LASF_Projection", 34735, "GeoKeyDirectoryTag", data))
    rc, stdout, err = cli("render", tmp_path / "utm.las", "-o", tmp_path / "o.png", "--gsd", GSD)
    assert rc == 0, err
    assert "no .prj written: the inputs name their CRS only as EPSG:32610, and its WKT needs pyproj" in stdout
    assert (tmp_path / "o.pgw").exists() and not (tmp_path / "o.prj").exists()


@pytest.mark.parametrize(
    "args, message",
    [
        (["--gsd", "0"], "--gsd must be a number > 0 and at most 2e+12 (cloud units per pixel), got 0"),
        (["--gsd", "nan"], "--gsd must be a number > 0 and at most 2e+12 (cloud units per pixel), got nan"),
        (["--gsd", "-2"], "--gsd must be a number > 0"),
        (["--gsd", "1", "--view", "iso"], "--view and --gsd: give one (--gsd draws one image straight down, orthographic, north up"),
        (["--gsd", "1", "--camera", "yaw=0 pitch=90"], "--camera and --gsd: give one"),
        (["--gsd", "1", "--width", "100"], "--width and --gsd: give one"),
        (["--gsd", "1", "-W", "100", "-H", "100"], "--width, --height and --gsd: give one"),
        (["--gsd", "1", "--projection", "perspective"], "--projection and --gsd: give one"),
        (["--gsd", "1", "--stereo", "anaglyph"], "--stereo and --gsd: give one"),
        (["--gsd", "1", "--depth-out", "d.npy"], "d.npy: unsupported output type '.npy'; use one of .tif, .tiff"),
        (["--gsd", "1", "--turntable", "3"], "--gsd: options of a still image, not of --turntable"),
        (["--gsd", "0.001"], "grid.npy: --gsd 0.001 makes a 19,502x11,502 image, over 16,384 pixels a side: a gsd of 0.0012 or more fits"),
    ],
)
def test_cli_gsd_errors_are_one_line(cli, tmp_path, grid_npy, args, message):
    path, _ = grid_npy
    out = tmp_path / ("o.mp4" if "--turntable" in args else "o.png")
    rc, _, err = cli("render", path, "-o", out, *[str(tmp_path / a) if a.endswith(".npy") else a for a in args])
    assert rc == 1 and err.count("\n") == 1 and message in err, err
    assert not out.exists() and not list(tmp_path.glob("o.*"))


def test_views_that_agree_with_gsd_are_taken(cli, tmp_path, grid_npy):
    path, _ = grid_npy
    rc, _, err = cli("render", path, "-o", tmp_path / "o.png", "--gsd", GSD, "--view", "top", "--projection", "orthographic")
    assert rc == 0, err
    assert Image.open(tmp_path / "o.png").size == (40, 24)


def test_cli_side_files_are_never_replaced_without_overwrite(cli, tmp_path):
    out = tmp_path / "o.png"
    for side in ("o.pgw", "o.prj", "d.tfw"):
        (tmp_path / side).write_text("precious")
        rc, _, err = cli("render", AUTZEN, "-o", out, "--gsd", 8, "--depth-out", tmp_path / "d.tif")
        assert rc == 1 and err.strip() == f"error: {tmp_path / side}: already exists; pass --overwrite to replace it", err
        assert (tmp_path / side).read_text() == "precious" and not out.exists() and not (tmp_path / "d.tif").exists()
        (tmp_path / side).unlink()
    (tmp_path / "o.prj").write_text("precious")
    rc, _, err = cli("render", AUTZEN, "-o", out, "--gsd", 8, "--overwrite")
    assert rc == 0, err
    assert (tmp_path / "o.prj").read_text() == read_las_header(AUTZEN).crs()
    assert read_world_file(tmp_path / "o.pgw")[0] == 8.0


def test_cli_a_prj_holding_the_same_crs_is_kept(cli, tmp_path):
    """x.webp then x.jpg of one map share x.prj: the second keeps it (as gigapoint.orthophoto
    does), where it said 'x.prj: already exists'; a .prj of another CRS is still refused."""
    rc, _, err = cli("render", AUTZEN, "-o", tmp_path / "x.webp", "--gsd", 10)
    assert rc == 0, err
    rc, stdout, err = cli("render", AUTZEN, "-o", tmp_path / "x.jpg", "--gsd", 10)
    assert rc == 0, err
    assert (tmp_path / "x.prj").read_text() == read_las_header(AUTZEN).crs()
    assert stdout.splitlines()[-1] == f"wrote {tmp_path / 'x.jgw'}"
    (tmp_path / "x.prj").write_text("precious")
    rc, _, err = cli("render", AUTZEN, "-o", tmp_path / "x.png", "--gsd", 10)
    assert rc == 1 and err.strip() == f"error: {tmp_path / 'x.prj'}: already exists; pass --overwrite to replace it", err
    assert (tmp_path / "x.prj").read_text() == "precious" and not (tmp_path / "x.png").exists()


def test_a_prj_beside_a_map_of_no_crs_is_refused(cli, tmp_path, grid_npy):
    """A cloud naming no CRS writes no .prj: an x.prj already there (another map's) would be left
    describing this one, so it is refused without --overwrite (it was written beside it, rc 0),
    by the CLI and by gigapoint.orthophoto alike."""
    path, _ = grid_npy
    (tmp_path / "x.prj").write_text('PROJCS["some other map"]')
    rc, _, err = cli("render", path, "-o", tmp_path / "x.png", "--gsd", GSD)
    assert rc == 1 and err.strip() == f"error: {tmp_path / 'x.prj'}: already exists; pass --overwrite to replace it", err
    with pytest.raises(GigapointError, match="x.prj: already exists"):
        gp.orthophoto(path, GSD, out=tmp_path / "y.png", dsm=tmp_path / "x.tif")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["grid.npy", "x.prj"]
    rc, _, err = cli("render", path, "-o", tmp_path / "x.png", "--gsd", GSD, "--overwrite")
    assert rc == 0 and (tmp_path / "x.pgw").exists(), err


def test_overwriting_a_map_with_one_of_no_crs_removes_the_earlier_prj(cli, tmp_path):
    """autzen's map (its CRS in x.prj), then --overwrite from the same points in a .npy (no CRS):
    x.prj was left, describing the new map in a CRS its inputs do not name. It is removed, and
    said so; gigapoint.orthophoto's overwrite=True alike, by a warning."""
    points = tmp_path / "points.npy"
    np.save(points, gp.open(AUTZEN).positions())
    for name in ("x.png", "y.tif"):
        rc, _, err = cli("render", AUTZEN, "-o", tmp_path / name, "--gsd", 10)
        assert rc == 0, err
    assert (tmp_path / "x.prj").read_text() == read_las_header(AUTZEN).crs() == (tmp_path / "y.prj").read_text()
    rc, stdout, err = cli("render", points, "-o", tmp_path / "x.png", "--gsd", 10, "--overwrite")
    assert rc == 0, err
    assert stdout.splitlines()[-1] == f"removed {tmp_path / 'x.prj'}: an earlier map's CRS, which these inputs do not name"
    assert not (tmp_path / "x.prj").exists() and read_world_file(tmp_path / "x.pgw")[0] == 10.0
    with pytest.warns(gp.GigapointWarning, match=r"^removed \S*y\.prj: an earlier map's CRS, which these inputs do not name$"):
        gp.orthophoto(points, 10, out=tmp_path / "y.tif", overwrite=True)
    assert sorted(p.name for p in tmp_path.glob("*.prj")) == []


def test_overwriting_a_map_with_a_plain_image_removes_its_world_file_and_prj(cli, tmp_path):
    """autzen's map x.png (x.pgw, x.prj), then x.png --overwrite without --gsd: x.pgw and x.prj
    were left, placing the plain image on the old map's grid. They go once it is written, said in
    one line; without --overwrite, beside an image not there yet, they are refused and left as
    they were (the image was written beside them, rc 0)."""
    rc, _, err = cli("render", AUTZEN, "-o", tmp_path / "x.png", "--gsd", 10)
    assert rc == 0, err
    rc, stdout, err = cli("render", AUTZEN, "-o", tmp_path / "x.png", "-W", 64, "-H", 36, "--overwrite")
    assert rc == 0, err
    removed = f"removed {tmp_path / 'x.pgw'}, {tmp_path / 'x.prj'}: an earlier map's georeferencing; this image is no map (no --gsd)"
    assert stdout.splitlines()[-1] == removed
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.png"] and Image.open(tmp_path / "x.png").size == (64, 36)
    (tmp_path / "y.pgw").write_text("precious")
    rc, stdout, err = cli("render", AUTZEN, "-o", tmp_path / "y.png", "-W", 64, "-H", 36)
    refused = f"error: {tmp_path / 'y.pgw'}: an earlier map's georeferencing, which would place y.png (no map: no --gsd) on its grid; remove it, or pass --overwrite to remove it once the image is written"
    assert rc == 1 and "removed" not in stdout and err.strip() == refused, err
    assert (tmp_path / "y.pgw").read_text() == "precious" and not (tmp_path / "y.png").exists()


def test_a_plain_image_where_a_removed_map_was_is_refused_or_cleared(cli, tmp_path):
    """x.png a map (x.pgw, x.prj), x.png removed, then a plain x.png: it was written beside the
    old map's x.pgw and x.prj without a word (a GIS placed it on that grid). Refused before
    anything is read, nothing removed; with --overwrite they go once it is written, as where
    x.png was still there. A plain --depth-out is a .npy, which no GIS places: the d.tfw and d.prj
    of an earlier map's d.tif, not replaced, are kept."""
    rc, _, err = cli("render", AUTZEN, "-o", tmp_path / "x.png", "--gsd", 10, "--depth-out", tmp_path / "d.tif")
    assert rc == 0, err
    (tmp_path / "x.png").unlink()
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    assert sorted(before) == ["d.prj", "d.tfw", "d.tif", "x.pgw", "x.prj"]
    rc, stdout, err = cli("render", AUTZEN, "-o", tmp_path / "x.png", "-W", 64, "-H", 36, "--depth-out", tmp_path / "d.npy")
    refused = f"error: {tmp_path / 'x.pgw'}, {tmp_path / 'x.prj'}: an earlier map's georeferencing, which would place x.png (no map: no --gsd) on its grid; remove them, or pass --overwrite to remove them once the image is written"
    assert rc == 1 and stdout == "" and err.strip() == refused, err
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
    rc, stdout, err = cli("render", AUTZEN, "-o", tmp_path / "x.png", "-W", 64, "-H", 36, "--depth-out", tmp_path / "d.npy", "--overwrite")
    assert rc == 0, err
    removed = f"removed {tmp_path / 'x.pgw'}, {tmp_path / 'x.prj'}: an earlier map's georeferencing; this image is no map (no --gsd)"
    assert stdout.splitlines()[-1] == removed
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.npy", "d.prj", "d.tfw", "d.tif", "x.png"]
    assert all((tmp_path / name).read_bytes() == before[name] for name in ("d.prj", "d.tfw", "d.tif"))
    rc, _, err = cli("render", AUTZEN, "-o", tmp_path / "y.png", "--depth-out", tmp_path / "d.tif", "--overwrite")  # (a plain depth is no map)
    assert rc == 1 and err.strip() == f"error: {tmp_path / 'd.tif'}: unsupported output type '.tif'; use one of .npy", err


def test_a_lone_prj_beside_a_plain_image_is_left_alone(cli, tmp_path):
    """s.prj beside s.shp (a shapefile's, no world file): a plain s.png is no map for it to
    misplace; neither refused nor, with --overwrite, removed."""
    (tmp_path / "s.shp").write_bytes(b"shape")
    (tmp_path / "s.prj").write_text("PROJCS shapefile's")
    for extra in ((), ("--overwrite",)):
        rc, stdout, err = cli("render", AUTZEN, "-o", tmp_path / "s.png", "-W", 64, "-H", 36, *extra)
        assert rc == 0 and "removed" not in stdout, err
        assert (tmp_path / "s.prj").read_text() == "PROJCS shapefile's"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.png", "s.prj", "s.shp"]


def test_overwrite_keeps_the_prj_another_map_of_the_stem_uses(cli, tmp_path):
    """x.tif is a map (x.tfw, x.prj); a plain x.png --overwrite (x.png not there before) removed
    x.prj, which x.tif's map still needs. Kept now, and x.tfw with it; a map of no CRS named x.png
    is refused (x.prj is x.tif's and would describe it), even with --overwrite: nothing removed."""
    rc, _, err = cli("render", AUTZEN, "-o", tmp_path / "x.tif", "--gsd", 10)
    assert rc == 0, err
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    assert sorted(before) == ["x.prj", "x.tfw", "x.tif"]
    rc, stdout, err = cli("render", AUTZEN, "-o", tmp_path / "x.png", "-W", 64, "-H", 36, "--overwrite")
    assert rc == 0 and "removed" not in stdout, err
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.name != "x.png"} == before
    points = tmp_path / "points.npy"
    np.save(points, gp.open(AUTZEN).positions())
    (tmp_path / "x.png").unlink()
    for extra in ((), ("--overwrite",)):
        rc, _, err = cli("render", points, "-o", tmp_path / "x.png", "--gsd", 10, *extra)
        assert rc == 1 and err.strip() == f"error: {tmp_path / 'x.prj'}: holds the CRS of the map beside it (x.tfw), which these inputs do not name: write this map under another name", err
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.name != "points.npy"} == before  # (no x.png, no x.pgw)


def test_an_image_and_a_dsm_sharing_one_world_file_are_refused(cli, tmp_path, grid_npy):
    """m.tif and --depth-out m.tiff both need m.tfw: render wrote it twice (the second over the
    first), where gigapoint.orthophoto refused the pair; refused before anything is read or written."""
    path, _ = grid_npy
    rc, _, err = cli("render", path, "-o", tmp_path / "m.tif", "--gsd", GSD, "--depth-out", tmp_path / "m.tiff")
    assert rc == 1 and err.strip() == f"error: {tmp_path / 'm.tfw'}: named for two outputs", err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["grid.npy"]


def test_a_failed_side_write_takes_the_image_back(cli, tmp_path, grid_npy, monkeypatch):
    """The world file's write failing (a full disk) removes the image written before it: no
    orthophoto is left without its georeference."""
    from gigapoint.render import georef

    def full_disk(camera, path):
        raise OSError(28, "No space left on device", str(path))

    monkeypatch.setattr(georef, "write_world_file", full_disk)
    rc, _, err = cli("render", grid_npy[0], "-o", tmp_path / "o.png", "--gsd", GSD)
    assert rc == 1 and f"{tmp_path / 'o.pgw'}" in err and "No space left on device" in err, err
    assert not list(tmp_path.glob("o.*"))


# --- GeoTIFF: a .tif output carries its grid and CRS in its own tags --------------------------


@pytest.fixture
def gdal():
    """rasterio (GDAL) reading only what a file holds itself: GDAL reads a .tfw beside a plain
    TIFF too, and that must not stand in for the GeoTIFF's own tags."""
    rasterio = pytest.importorskip("rasterio")
    with rasterio.Env(GDAL_GEOREF_SOURCES="INTERNAL"):
        yield rasterio


def world_grid(world_file_path):
    """The affine transform (GDAL's a, b, c, d, e, f) of a world file's grid: the world file names
    the centre of pixel (0, 0), the transform its upper-left corner, half a pixel left and up."""
    a, d, b, e, c, f = read_world_file(world_file_path)
    return (a, b, c - a / 2 - b / 2, d, e, f - d / 2 - e / 2)


def gdal_crs_of(gdal, wkt, tmp_path):
    """The CRS GDAL reads back from a GeoTIFF it writes itself in ``wkt`` (GDAL renames a datum by
    its EPSG code: autzen's 'Regional' network is EPSG's 'Reference' one, in any GeoTIFF)."""
    crs = gdal.crs.CRS.from_wkt(wkt)
    with gdal.open(tmp_path / "gdal_own.tif", "w", driver="GTiff", width=1, height=1, count=1, dtype="uint8", crs=crs, transform=gdal.transform.from_origin(0, 1, 1, 1)) as ds:
        ds.write(np.zeros((1, 1, 1), np.uint8))
    with gdal.open(tmp_path / "gdal_own.tif") as ds:
        return ds.crs


def test_cli_tif_outputs_are_geotiffs_in_the_files_crs(cli, tmp_path, gdal):
    """autzen (a WKT in US feet that names no EPSG code for its map grid): GDAL places the image
    and the DSM by their own tags where the world files put them, in the .prj's CRS; the DSM's
    empty pixels are its nodata, its heights those Pillow reads."""
    out, dsm = tmp_path / "autzen.tif", tmp_path / "dsm.tiff"
    rc, stdout, err = cli("render", AUTZEN, "-o", out, "--gsd", 8, "--depth-out", dsm, "--size-mode", "fixed")
    assert rc == 0, err
    prj = (tmp_path / "autzen.prj").read_text()
    assert prj == read_las_header(AUTZEN).crs() == (tmp_path / "dsm.prj").read_text()  # the .prj and world files as before
    expected_crs = gdal_crs_of(gdal, prj, tmp_path)
    for path, world in ((out, "autzen.tfw"), (dsm, "dsm.tfw")):
        with gdal.open(path) as ds:
            assert ds.transform[:6] == pytest.approx(world_grid(tmp_path / world), rel=0, abs=1e-6)
            assert ds.transform[:6] == pytest.approx((8, 0, 636_000, 0, -8, 849_504), rel=0, abs=1e-6)  # corners on multiples of 8 ft
            assert ds.crs == expected_crs
            assert ds.crs.linear_units == "foot" and ds.crs.to_proj4() == gdal.crs.CRS.from_wkt(prj).to_proj4()
            pixels = ds.read()
    with gdal.open(out) as ds:
        assert ds.count == 4 and ds.dtypes == ("uint8",) * 4
        np.testing.assert_array_equal(np.moveaxis(ds.read(), 0, -1), np.asarray(Image.open(out)))  # RGBA as Pillow reads it
    heights = np.asarray(Image.open(dsm))
    assert np.isnan(heights).mean() > 0.1  # (autzen_trim is no rectangle)
    with gdal.open(dsm) as ds:
        assert ds.count == 1 and ds.dtypes == ("float32",) and np.isnan(ds.nodata)
        np.testing.assert_array_equal(pixels[0], heights)  # NaN where Pillow's are, the same heights elsewhere
        assert ds.read_masks(1).astype(bool).tolist() == (~np.isnan(heights)).tolist()  # empty pixels are nodata
    assert "no .prj" not in stdout and "GeoTIFF keys" not in stdout


def test_cli_an_epsg_only_crs_writes_pyprojs_wkt_as_prj(cli, tmp_path):
    """With pyproj (the gis extra), the .prj of a CRS named only as EPSG:32610 holds its WKT."""
    pyproj = pytest.importorskip("pyproj")
    keys = [(1024, 0, 1, 1), (3072, 0, 1, 32610)]
    data = struct.pack("<4H", 1, 1, 0, len(keys)) + b"".join(struct.pack("<4H", *k) for k in keys)
    write_las(tmp_path / "utm.las", laspy.VLR("LASF_Projection", 34735, "GeoKeyDirectoryTag", data))
    rc, stdout, err = cli("render", tmp_path / "utm.las", "-o", tmp_path / "o.png", "--gsd", GSD)
    assert rc == 0, err
    assert "no .prj written" not in stdout
    assert pyproj.CRS.from_wkt((tmp_path / "o.prj").read_text()).to_epsg() == 32610


def test_cli_geotiff_of_an_epsg_only_crs_names_the_code(cli, tmp_path, gdal, monkeypatch):
    """LAS 1.2 GeoTIFF keys naming EPSG:32610 alone (no WKT: no .prj without pyproj): the GeoTIFF
    names the code and GDAL knows its metres; a PNG is placed by its world file alone, as before."""
    monkeypatch.setitem(sys.modules, "pyproj", None)
    keys = [(1024, 0, 1, 1), (3072, 0, 1, 32610)]
    data = struct.pack("<4H", 1, 1, 0, len(keys)) + b"".join(struct.pack("<4H", *k) for k in keys)
    write_las(tmp_path / "utm.las", laspy.VLR("LASF_Projection", 34735, "GeoKeyDirectoryTag", data))
    rc, stdout, err = cli("render", tmp_path / "utm.las", "-o", tmp_path / "o.tif", "--gsd", GSD, "--depth-out", tmp_path / "d.tif")
    assert rc == 0, err
    for name in ("o", "d"):
        with gdal.open(tmp_path / f"{name}.tif") as ds:
            assert ds.crs.to_epsg() == 32610 and ds.crs.linear_units == "metre"
            assert ds.transform[:6] == pytest.approx(world_grid(tmp_path / f"{name}.tfw"), rel=0, abs=1e-9)
            assert ds.transform[:6] == pytest.approx((0.5, 0, 637_000, 0, -0.5, 851_012.5), rel=0, abs=1e-9)  # grid_cloud's corner
    rc, _, err = cli("render", tmp_path / "utm.las", "-o", tmp_path / "o.png", "--gsd", GSD)
    assert rc == 0, err
    with gdal.open(tmp_path / "o.png") as ds:
        assert ds.driver == "PNG" and ds.crs is None  # as before: its world file places it (GDAL's PNG driver reads it)
        assert ds.transform[:6] == pytest.approx(world_grid(tmp_path / "o.pgw"), rel=0, abs=1e-9)


def test_cli_geotiff_of_a_compound_wkt_names_its_horizontal_code(cli, tmp_path, gdal):
    """A WKT of UTM 10N (EPSG:26910) with NAVD88 heights: the GeoKeys name the map grid's code (and
    the heights' vertical CRS: GDAL reads the compound CRS back)."""
    horizontal = gdal.crs.CRS.from_epsg(26910).to_wkt()
    wkt = f'COMPD_CS["NAD83 / UTM zone 10N + NAVD88 height",{horizontal},VERT_CS["NAVD88 height",VERT_DATUM["North American Vertical Datum 1988",2005],UNIT["metre",1],AUTHORITY["EPSG","5703"]]]'
    write_las(tmp_path / "c.las", laspy.VLR("LASF_Projection", 2112, "OGC WKT", wkt.encode() + b"\0"))
    rc, _, err = cli("render", tmp_path / "c.las", "-o", tmp_path / "o.tif", "--gsd", GSD)
    assert rc == 0, err
    assert (tmp_path / "o.prj").read_text() == wkt
    with gdal.open(tmp_path / "o.tif") as ds:
        assert 'AUTHORITY["EPSG","26910"]],VERT_CS["NAVD88 height"' in ds.crs.to_wkt() and ds.crs.linear_units == "metre"


def geo_key_directory(path):
    """A GeoTIFF's key directory as Pillow reads it: (its revision (KeyRevision, MinorRevision),
    {key: value}), a value held in place as its number, one in GeoAsciiParams as its text."""
    tags = Image.open(path).tag_v2
    directory, text = tags[34735], tags.get(34737, "")
    keys = {}
    for at in range(4, 4 + 4 * directory[3], 4):
        key, location, count, offset = directory[at : at + 4]
        keys[key] = offset if location == 0 else text[offset : offset + count - 1]  # (ASCII: without its '|')
    return tuple(directory[1:3]), keys


@pytest.mark.parametrize("pyproj_installed", [True, False])
@pytest.mark.parametrize(
    ("code", "wkt_version", "keys", "height_unit"),
    [
        ("EPSG:26910+5703", "WKT1_GDAL", {3072: 26910, 3076: 9001, 4096: 5703, 4099: 9001}, "metre"),  # NAD83 / UTM 10N + NAVD88 height
        ("EPSG:2994+6360", "WKT2_2019", {3072: 2994, 3076: 9002, 4096: 6360, 4099: 9003}, "US survey foot"),  # Oregon GIC (ft) + NAVD88 (ftUS)
    ],
)
def test_cli_dsm_of_a_compound_crs_names_its_vertical_crs(cli, tmp_path, gdal, monkeypatch, code, wkt_version, keys, height_unit, pyproj_installed):
    """A LAS file's compound WKT: the DSM's GeoTIFF 1.1 keys name the heights' vertical CRS and unit
    as well as the map grid (with pyproj or without: the WKT's own codes), and GDAL reads them
    back as the CRS it reads from a GeoTIFF it writes itself in that WKT."""
    wkt = gdal.crs.CRS.from_user_input(code).to_wkt(version=wkt_version)
    if not pyproj_installed:
        monkeypatch.setitem(sys.modules, "pyproj", None)
    write_las(tmp_path / "c.las", laspy.VLR("LASF_Projection", 2112, "OGC WKT", wkt.encode() + b"\0"))
    rc, _, err = cli("render", tmp_path / "c.las", "-o", tmp_path / "o.png", "--gsd", GSD, "--depth-out", tmp_path / "d.tif")
    assert rc == 0, err
    assert geo_key_directory(tmp_path / "d.tif") == ((1, 1), {1024: 1, 1025: 1, **keys})
    with gdal.open(tmp_path / "d.tif") as ds:
        assert ds.crs == gdal_crs_of(gdal, wkt, tmp_path)
        assert ds.crs.to_wkt().endswith(f'AUTHORITY["EPSG","{keys[4096]}"]]]')  # (the compound's last part: its vertical one)
        assert ds.units == (height_unit,)  # the heights' unit, GDAL's band unit


def test_cli_dsm_of_autzens_copc_names_its_heights_navd88_in_us_feet(cli, tmp_path, gdal):
    """PDAL's COPC of autzen: Oregon Lambert in metres (EPSG:2991), heights NAVD88 in US survey feet."""
    rc, _, err = cli("render", AUTZEN_COPC, "-o", tmp_path / "o.png", "--gsd", 4, "--depth-out", tmp_path / "d.tif")
    assert rc == 0, err
    assert geo_key_directory(tmp_path / "d.tif") == ((1, 1), {1024: 1, 1025: 1, 3072: 2991, 3076: 9001, 4096: 6360, 4099: 9003})
    with gdal.open(tmp_path / "d.tif") as ds:
        assert ds.crs.linear_units == "metre" and ds.units == ("US survey foot",)
        assert 'VERT_CS["NAVD88 height (ftUS)"' in ds.crs.to_wkt()


def test_cli_dsm_of_a_vertical_crs_without_a_code_names_it_by_citation(cli, tmp_path, gdal):
    """A vertical CRS no EPSG code names: user-defined, its name the VerticalCitationGeoKey."""
    wkt = gdal.crs.CRS.from_user_input("EPSG:26910+6360").to_wkt()
    wkt = wkt.replace('AUTHORITY["EPSG","6360"]]]', "]]").replace("NAVD88 height (ftUS)", "site height")
    write_las(tmp_path / "c.las", laspy.VLR("LASF_Projection", 2112, "OGC WKT", wkt.encode() + b"\0"))
    rc, _, err = cli("render", tmp_path / "c.las", "-o", tmp_path / "o.png", "--gsd", GSD, "--depth-out", tmp_path / "d.tif")
    assert rc == 0, err
    assert geo_key_directory(tmp_path / "d.tif") == ((1, 1), {1024: 1, 1025: 1, 3072: 26910, 3076: 9001, 4096: 32767, 4097: "site height", 4099: 9003})
    with gdal.open(tmp_path / "d.tif") as ds:
        assert 'VERT_CS["site height"' in ds.crs.to_wkt() and ds.units == ("US survey foot",)


def test_cli_geotiff_of_a_2d_crs_has_no_vertical_keys(cli, tmp_path, gdal):
    """A CRS without a vertical part (UTM 10N alone): GeoTIFF 1.0's key directory, as before."""
    write_las(tmp_path / "c.las", laspy.VLR("LASF_Projection", 2112, "OGC WKT", gdal.crs.CRS.from_epsg(26910).to_wkt().encode() + b"\0"))
    rc, _, err = cli("render", tmp_path / "c.las", "-o", tmp_path / "o.png", "--gsd", GSD, "--depth-out", tmp_path / "d.tif")
    assert rc == 0, err
    assert Image.open(tmp_path / "d.tif").tag_v2[34735] == (1, 1, 0, 4, 1024, 0, 1, 1, 1025, 0, 1, 1, 3072, 0, 1, 26910, 3076, 0, 1, 9001)


def test_cli_geotiff_without_a_crs_holds_its_grid(cli, tmp_path, grid_npy, gdal):
    """No CRS (a .npy): the GeoTIFF DSM has its grid and nodata, no CRS (as no .prj is written)."""
    rc, out, err = cli("render", grid_npy[0], "-o", tmp_path / "o.png", "--gsd", GSD, "--depth-out", tmp_path / "d.tif")
    assert rc == 0, err
    with gdal.open(tmp_path / "d.tif") as ds:
        assert ds.crs is None and np.isnan(ds.nodata)
        assert ds.transform[:6] == pytest.approx((0.5, 0, 637_000, 0, -0.5, 851_012.5), rel=0, abs=1e-9)
    assert "no .prj written: the inputs name no CRS" in out and "GeoTIFF keys" not in out


def test_a_wkt_too_long_for_gdals_citation_is_left_to_the_prj(tmp_path):
    """GDAL reads a user-defined CRS's WKT from its GeoKeys into 2 400 characters: a longer one is
    not written there (it would be cut), and the command says the .prj has it."""
    from gigapoint.render.georef import PCS_CITATION, geo_keys, geotiff_notes

    wkt = read_las_header(AUTZEN).crs()
    units = {"horizontal": {"name": "foot", "symbol": "ft", "metres": 0.3048}}
    assert geo_keys(wkt, wkt, units) == {1024: 32767, 1025: 1, PCS_CITATION: f"ESRI PE String = {wkt}", 3076: 9002}
    long = wkt[:-1] + ',EXTENSION["note","' + "x" * 2400 + '"]]'
    assert geo_keys(long, long, units) == {}
    assert geotiff_notes([tmp_path / "o.png", tmp_path / "d.tif", None], long, long, units) == [
        f"{tmp_path / 'd.tif'}: its GeoTIFF keys name no CRS (its WKT is longer than GDAL reads from them); the .prj beside it has it"
    ]
    assert geotiff_notes([tmp_path / "d.tif"], wkt, wkt, units) == []


@pytest.mark.parametrize("pyproj_installed", [True, False])
def test_cli_geokeys_naming_a_vertical_crs_reach_info_and_the_dsm(cli, tmp_path, gdal, monkeypatch, pyproj_installed):
    """A LAS 1.2 file naming Oregon GIC Lambert (ft) and NAVD88 height (ftUS) by GeoTIFF keys alone
    (VerticalCSTypeGeoKey 6360): info names the compound CRS, and the DSM's keys the heights'
    vertical CRS and unit as the file's own (with pyproj or without: the codes are text)."""
    pyproj = pytest.importorskip("pyproj") if pyproj_installed else monkeypatch.setitem(sys.modules, "pyproj", None)
    keys = {1024: 1, 3072: 2994, 3076: 9002, 4096: 6360, 4099: 9003}  # projected, ft; heights NAVD88 in US ft
    write_las(tmp_path / "c.las", geokeys_vlr(keys))
    rc, stdout, err = cli("info", tmp_path / "c.las")
    assert rc == 0, err
    assert "  crs:         EPSG:2994+6360\n" in stdout
    rc, stdout, err = cli("render", tmp_path / "c.las", "-o", tmp_path / "o.png", "--gsd", GSD, "--depth-out", tmp_path / "d.tif")
    assert rc == 0, err
    assert geo_key_directory(tmp_path / "d.tif") == ((1, 1), {1025: 1, **keys})
    with gdal.open(tmp_path / "d.tif") as ds:
        assert ds.crs.linear_units == "foot" and ds.units == ("US survey foot",)
        assert 'PROJCS["NAD83(HARN) / Oregon GIC Lambert (ft)"' in ds.crs.to_wkt()
        assert 'VERT_CS["NAVD88 height (ftUS)"' in ds.crs.to_wkt() and ds.crs.to_wkt().endswith('AUTHORITY["EPSG","6360"]]]')
    if pyproj_installed:  # the .prj: pyproj's WKT of the compound CRS
        prj = pyproj.CRS.from_wkt((tmp_path / "o.prj").read_text())
        assert [part.to_epsg() for part in prj.sub_crs_list] == [2994, 6360]
    else:
        assert "no .prj written: the inputs name their CRS only as EPSG:2994+6360, and its WKT needs pyproj" in stdout


@pytest.mark.parametrize(
    "vertical_code",
    [32767, 5103],  # user-defined; GeoTIFF 1.0's own code of NAVD88 (EPSG's code of its datum, no CRS)
)
def test_cli_geokeys_naming_the_heights_unit_alone_reach_the_dsm(cli, tmp_path, gdal, vertical_code):
    """VerticalUnitsGeoKey beside a vertical CRS no EPSG code names: the CRS is the map grid's code
    alone, and the DSM's keys keep the heights' unit (a user-defined vertical CRS, as GDAL reads it)."""
    write_las(tmp_path / "c.las", geokeys_vlr({1024: 1, 3072: 26910, 3076: 9001, 4096: vertical_code, 4099: 9003}))
    rc, stdout, err = cli("info", tmp_path / "c.las")
    assert rc == 0, err
    assert "  crs:         EPSG:26910\n" in stdout
    rc, _, err = cli("render", tmp_path / "c.las", "-o", tmp_path / "o.png", "--gsd", GSD, "--depth-out", tmp_path / "d.tif")
    assert rc == 0, err
    assert geo_key_directory(tmp_path / "d.tif") == ((1, 1), {1024: 1, 1025: 1, 3072: 26910, 3076: 9001, 4096: 32767, 4099: 9003})
    with gdal.open(tmp_path / "d.tif") as ds:
        assert ds.crs.linear_units == "metre" and ds.units == ("US survey foot",)


def test_dsm_heights_unit_is_the_files_own_unit_key():
    """NAVD88 height (EPSG:5703, in metres) with VerticalUnitsGeoKey US survey foot, as many US
    LAS files name their heights: the DSM's keys keep the file's unit, the one its heights are in."""
    pytest.importorskip("pyproj")
    from gigapoint.io import crs_units
    from gigapoint.render.georef import geo_keys

    keys = {1024: 1, 3072: 26910, 3076: 9001, 4096: 5703, 4099: 9003}
    units = crs_units("EPSG:26910+5703", keys)
    assert geo_keys("EPSG:26910+5703", None, units) == {1024: 1, 1025: 1, 3072: 26910, 3076: 9001, 4096: 5703, 4099: 9003}
    assert geo_keys("EPSG:26910+5703", None, crs_units("EPSG:26910+5703"))[4099] == 9001  # no unit key: NAVD88's metres
