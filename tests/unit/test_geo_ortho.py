"""Georeferenced top-down renders: `gigapoint render --gsd` (Camera.top_down) draws an orthophoto
on the gsd grid with a world file and a .prj beside it, and --depth-out a float32 surface model."""

from __future__ import annotations

import struct

import laspy
import numpy as np
import pytest
from PIL import Image

import gigapoint as gp
from gigapoint.errors import CameraError
from gigapoint.io.las import read_las_header
from gigapoint.render.camera import MAX_IMAGE_SIDE

AUTZEN = "/work/shared/data/autzen_trim.laz"
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
    assert str(err.value) == "gsd 0.5 makes a 20,001x11 image, over 16,384 pixels a side: a gsd of 0.611 or more fits"
    assert gp.Camera.top_down(((0, 0, 0), (10_000.0, 5.0, 1.0)), 0.611).width <= MAX_IMAGE_SIDE
    for bad in (0, -1, float("nan"), "1"):
        with pytest.raises(CameraError, match="gsd .ground sample distance. must be a number > 0"):
            gp.Camera.top_down(((0, 0, 0), (1, 1, 1)), bad)


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


def test_cli_an_epsg_only_crs_writes_no_prj_and_says_so(cli, tmp_path):
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
        (["--gsd", "0"], "--gsd must be a number > 0 (cloud units per pixel), got 0"),
        (["--gsd", "nan"], "--gsd must be a number > 0 (cloud units per pixel), got nan"),
        (["--gsd", "-2"], "--gsd must be a number > 0"),
        (["--gsd", "1", "--view", "iso"], "--view and --gsd: give one (--gsd draws one image straight down, orthographic, north up"),
        (["--gsd", "1", "--camera", "yaw=0 pitch=90"], "--camera and --gsd: give one"),
        (["--gsd", "1", "--width", "100"], "--width and --gsd: give one"),
        (["--gsd", "1", "-W", "100", "-H", "100"], "--width, --height and --gsd: give one"),
        (["--gsd", "1", "--projection", "perspective"], "--projection and --gsd: give one"),
        (["--gsd", "1", "--stereo", "anaglyph"], "--stereo and --gsd: give one"),
        (["--gsd", "1", "--depth-out", "d.npy"], "d.npy: unsupported output type '.npy'; use one of .tif, .tiff"),
        (["--gsd", "1", "--turntable", "3"], "--gsd: options of a still image, not of --turntable"),
        (["--gsd", "0.001"], "--gsd: gsd 0.001 makes a 19,501x11,501 image, over 16,384 pixels a side: a gsd of 0.0012 or more fits"),
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


def test_a_failed_side_write_takes_the_image_back(cli, tmp_path, grid_npy, monkeypatch):
    """The world file's write failing (a full disk) removes the image written before it: no
    orthophoto is left without its georeference."""
    from gigapoint.cli import render_cmd

    def full_disk(camera, path):
        raise OSError(28, "No space left on device", str(path))

    monkeypatch.setattr(render_cmd, "write_world_file", full_disk)
    rc, _, err = cli("render", grid_npy[0], "-o", tmp_path / "o.png", "--gsd", GSD)
    assert rc == 1 and f"{tmp_path / 'o.pgw'}" in err and "No space left on device" in err, err
    assert not list(tmp_path.glob("o.*"))
