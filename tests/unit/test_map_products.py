"""gigapoint.orthophoto: the orthophoto and surface model of `render --gsd` from Python, the same
files byte for byte (orthophoto.py, render/georef.py); the survey functions' errors spelling the
numbers given as errors.number_text does."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

import gigapoint as gp
from gigapoint.errors import GigapointError, GigapointWarning, InputError
from gigapoint.survey.ground_raster import ground_parameters
from gigapoint.survey.noise import noise_parameters

GSD = 4.0  # autzen in feet: 295x142 pixels


def test_orthophoto_writes_the_bytes_the_cli_writes(cli, tmp_path, autzen_path):
    (tmp_path / "cli").mkdir()
    rc, _, err = cli("render", autzen_path, "--gsd", GSD, "-o", tmp_path / "cli/ortho.tif", "--depth-out", tmp_path / "cli/dsm.tif", "--fill-nodata", 2)
    assert rc == 0, err
    result = gp.orthophoto(autzen_path, GSD, out=tmp_path / "ortho.tif", dsm=tmp_path / "dsm.tif", fill_nodata=2)
    for name in ("ortho.tif", "ortho.tfw", "ortho.prj", "dsm.tif", "dsm.tfw", "dsm.prj"):
        assert (tmp_path / name).read_bytes() == (tmp_path / "cli" / name).read_bytes(), name
    assert result.image.shape == (142, 295, 4) and result.heights.shape == (142, 295)
    np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / "dsm.tif")), result.heights)


def test_orthophoto_geotiffs_are_placed_in_the_files_crs(tmp_path, autzen_path):
    rasterio = pytest.importorskip("rasterio")
    result = gp.orthophoto(autzen_path, GSD, out=tmp_path / "ortho.tif", dsm=tmp_path / "dsm.tif")
    size, _, _, _, x, y = result.camera.world_file()
    for name in ("ortho.tif", "dsm.tif"):
        with rasterio.open(tmp_path / name) as ds:
            assert tuple(ds.transform)[:6] == (GSD, 0.0, x - size / 2, 0.0, -GSD, y + size / 2)  # the upper-left corner: half a pixel out
            assert ds.crs.linear_units == "foot" and "Lambert_Conformal_Conic" in ds.crs.to_wkt()
            assert (ds.width, ds.height) == (295, 142)
    with rasterio.open(tmp_path / "dsm.tif") as ds:
        assert np.isnan(ds.nodata)
        np.testing.assert_array_equal(ds.read(1), result.heights)


def test_write_is_refused_over_an_existing_file_and_writes_nothing(tmp_path, autzen_path):
    result = gp.orthophoto(autzen_path, GSD)
    (tmp_path / "ortho.prj").write_text("mine")
    with pytest.raises(GigapointError, match=r"^\S*ortho\.prj: already exists; pass overwrite=True to replace it$"):
        result.write(tmp_path / "ortho.png", tmp_path / "dsm.tif")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ortho.prj"] and (tmp_path / "ortho.prj").read_text() == "mine"
    written = result.write(tmp_path / "ortho.png", tmp_path / "dsm.tif", overwrite=True)
    assert [p.name for p in written] == ["ortho.png", "dsm.tif", "ortho.pgw", "dsm.tfw", "ortho.prj", "dsm.prj"]
    assert (tmp_path / "ortho.prj").read_text().startswith("PROJCS[")


def test_an_existing_output_is_refused_before_anything_is_read(tmp_path):
    (tmp_path / "ortho.png").write_bytes(b"mine")
    with pytest.raises(GigapointError, match=r"ortho\.png: already exists; pass overwrite=True"):
        gp.orthophoto(tmp_path / "missing.laz", 1.0, out=tmp_path / "ortho.png")  # (not: missing.laz does not exist)


def test_a_failed_side_write_takes_the_image_back(tmp_path, autzen_path, monkeypatch):
    from gigapoint.render import georef

    def full_disk(*args):
        raise OSError(28, "No space left on device")

    result = gp.orthophoto(autzen_path, GSD)
    monkeypatch.setattr(georef, "write_world_file", full_disk)
    with pytest.raises(GigapointError) as err:  # (was the OSError raw: "[Errno 28] No space left on device", naming no file)
        result.write(tmp_path / "ortho.tif", tmp_path / "dsm.tif")
    assert str(err.value) == f"{tmp_path / 'ortho.tfw'}: not written (No space left on device); none of the map's files was left"
    assert list(tmp_path.iterdir()) == []


def test_a_cloud_without_a_crs_is_placed_by_its_world_file_and_warned_of(tmp_path):
    xyz = np.array([[0.5, 0.5, 1.0], [3.5, 1.5, 2.0], [1.5, 2.5, 3.0]])
    with pytest.warns(GigapointWarning, match="no .prj written: the inputs name no CRS"):
        result = gp.orthophoto(gp.from_arrays(xyz), 1.0, dsm=tmp_path / "dsm.tif", size_mode="fixed", point_size=1)
    assert (tmp_path / "dsm.tfw").read_text() == "1\n0\n0\n-1\n0.5\n2.5\n" and not list(tmp_path.glob("*.prj"))
    assert result.heights[0, 1] == 3.0 and result.heights[2, 0] == 1.0 and np.isnan(result.heights[0, 0])


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ({"gsd": 0}, r"^orthophoto: gsd must be a number > 0 \(cloud units per pixel\), got 0$"),
        ({"gsd": 1, "fill_nodata": 0}, r"^orthophoto: fill_nodata: max_distance must be an integer >= 1 pixels, got 0$"),
        ({"gsd": 1, "classes": [2]}, r"^orthophoto: classes filter the files read; a cloud is drawn as it is"),
        ({"gsd": 1, "dsm": "dsm.png"}, r"^dsm\.png: unsupported output type '\.png'; use one of \.tif, \.tiff$"),
        ({"gsd": 1, "overwrite": "no"}, r"^orthophoto: overwrite must be True or False, got 'no'$"),
    ],
)
def test_errors_are_one_line(args, message):
    with pytest.raises(InputError if "dsm" not in args else GigapointError, match=message):
        gp.orthophoto(gp.from_arrays(np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])), **args)


SECTION_CLOUD = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 1.0]])


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: gp.orthophoto(gp.from_arrays(SECTION_CLOUD), -1e13), "orthophoto: gsd must be a number > 0 (cloud units per pixel), got -1e+13"),
        (lambda: gp.change("m.laz", "m.laz", 0.0), "change: gsd must be a number > 0 (cloud units per pixel), got 0"),
        (lambda: gp.change("m.laz", "m.laz", 1, min_change=-1e13), "change: min_change must be a number >= 0 (a height difference), got -1e+13"),
        (lambda: gp.volume("m.laz", "toe.geojson", 0.0), "volume: gsd must be a number > 0 (cloud units per pixel), got 0"),
        (lambda: gp.volume("m.laz", "toe.geojson", 1, base=np.float64("nan")), "volume: base must be 'plane', 'lowest' or an elevation (a number), got nan"),
        (lambda: gp.section("m.laz", (0, 0, 1, 1), 0.0), "section: width=0: the corridor's width must be a finite number above 0"),
        (lambda: gp.section(gp.from_arrays(SECTION_CLOUD), (0, 0, 10, 0), 2).camera(scale=0.0), "section: scale (pixels per unit) must be a number > 0, got 0"),
        (lambda: gp.section(gp.from_arrays(SECTION_CLOUD), (0, 0, 10, 0), 2).camera(vertical_exaggeration=-1e13),
         "section: vertical_exaggeration must be a number > 0 (1: heights at the scale of distances), got -1e+13"),
        (lambda: gp.section(gp.from_arrays(SECTION_CLOUD), (0, 0, 10, 0), 2).camera(scale=1e300),  # (not in 300 digits: errors.count_text)
         "section: scale 1e+300 makes a 1e+301x1e+300 image, over 16,384 pixels a side: a scale of 1.64e+03 or less fits"),
        # (pixels of 1e-308 overflowed the division: an OverflowError)
        (lambda: gp.section(gp.from_arrays(SECTION_CLOUD), (0, 0, 10, 0), 2).camera(scale=1e308),
         "section: scale 1e+308 makes a infx1e+308 image, over 16,384 pixels a side: a scale of 1.64e+03 or less fits"),
        (lambda: gp.orthophoto(gp.from_arrays(SECTION_CLOUD), 5e-324),
         "orthophoto: gsd: gsd 4.94066e-324 makes a infx2 image, over 16,384 pixels a side: a gsd of 0.000611 or more fits"),
        # (the filters checked under orthophoto's name, as section's: gp.open's said "open: classes='x'")
        (lambda: gp.orthophoto("m.laz", 1.0, classes="x"), "orthophoto: classes='x': class numbers are integers from 0 to 255 (LAS classes)"),
        (lambda: gp.orthophoto("m.laz", 1.0, clip=(1, 0, 0, 1)), "orthophoto: clip=(1, 0, 0, 1): xmin 1 is above xmax 0"),
        (lambda: noise_parameters([], step=0.0), "classify_noise: step must be a number > 0, got 0"),
        (lambda: ground_parameters([], threshold=-1e13), "classify_ground: threshold must be a number >= 0, got -1e+13"),
    ],
)  # fmt: skip
def test_survey_errors_spell_the_numbers_given_compactly(call, message):
    """The survey functions' errors say a number as ``errors.number_text`` does: 'got 0' and
    'got -1e+13', not 'got 0.0' and 'got -10000000000000.0' (nor numpy's 'np.float64(nan)')."""
    with pytest.raises(GigapointError) as err:
        call()
    assert str(err.value) == message


def test_a_count_whose_division_overflows_is_infinite_and_said_so():
    """``errors.count_or_inf``: the count of a size that overflows its division (5e-324) is more
    than any limit, not an OverflowError; ``count_text`` says it 'inf', a huge one in 3 digits."""
    import math

    from gigapoint.errors import count_or_inf, count_text

    assert count_or_inf(lambda: math.floor(100.0 / 0.5) + 1) == 201
    assert count_or_inf(lambda: math.floor(np.float64(100.0) / 5e-324) + 1) == math.inf  # (numpy's overflow warning too: pytest's -W error finds it)
    assert count_or_inf(lambda: math.floor(1e308 * 10 - 1e308 * 10)) == math.inf  # (inf - inf: nan)
    assert [count_text(n) for n in (2000, 1.18e303, math.inf)] == ["2,000", "1.18e+303", "inf"]


def binned_max(camera, xyz):
    """(H, W) the highest z of ``xyz`` floor-binned into ``camera``'s pixels by its world file, NaN
    where none; and the pixels (with the one across the edge) of points within 1e-3 pixel of an
    inner pixel edge, which float32 may put on either side (guide section 5)."""
    size, _, _, _, x0, y0 = camera.world_file()
    px, py = (xyz[:, 0] - (x0 - size / 2)) / size, ((y0 + size / 2) - xyz[:, 1]) / size
    col, row = np.floor(px).astype(int), np.floor(py).astype(int)
    highest = np.full((camera.height, camera.width), -np.inf)
    np.maximum.at(highest, (row, col), xyz[:, 2])
    on_edge = np.zeros(highest.shape, bool)
    near = (np.abs(px - np.round(px)) < 1e-3) | (np.abs(py - np.round(py)) < 1e-3)
    for dr, dc in ((0, 0), (-1, 0), (0, -1), (-1, -1)):
        on_edge[np.maximum(row[near] + dr, 0), np.maximum(col[near] + dc, 0)] = True
    return np.where(np.isfinite(highest), highest, np.nan), on_edge


def sparse_cloud(seed=4):
    """A few hundred points scattered over a 60 x 40 field of 1-unit pixels at a projected CRS's
    size of numbers, several to some pixels, most pixels empty, none within 0.05 of a pixel edge;
    heights 0..100 apart."""
    rng = np.random.default_rng(seed)
    xy = np.array([636_100.0, 849_200.0]) + rng.integers(0, [60, 40], (400, 2)) + rng.uniform(0.05, 0.95, (400, 2))
    return np.column_stack([xy, rng.uniform(300, 400, 400)])


def test_heights_are_each_pixels_highest_point_whatever_the_images_point_size():
    """The default settings draw adaptive splats: their depths gave the DSM heights in 3x the
    pixels points fall in, and a neighbour's z in pixels holding points (autzen: 358,509 pixels
    of heights for 103,939 holding a point, some 108 ft off). The image keeps its splats."""
    xyz = sparse_cloud()
    for settings in ({}, {"point_size": 4}, {"size_mode": "fixed", "point_size": 1}):
        result = gp.orthophoto(gp.from_arrays(xyz), 1.0, **settings)
        expected, on_edge = binned_max(result.camera, xyz)
        assert not on_edge.any()
        np.testing.assert_allclose(result.heights, expected, rtol=0, atol=1e-4, err_msg=str(settings))  # float32 of 400: 3e-5
        drawn = (result.image[..., 3] > 0).sum()
        assert drawn == np.isfinite(expected).sum() if settings.get("size_mode") == "fixed" else drawn > 2 * np.isfinite(expected).sum()


def test_an_image_of_one_pixel_points_in_a_colour_of_its_own_is_its_surface_too(monkeypatch):
    """Any setting apart from the surface's (an elevation colour mode, a background) drew the
    cloud a second time for the heights: only those that move a point's pixel or depth do."""
    from gigapoint.render import renderer, surface
    from gigapoint.survey import orthophoto

    drawn = []

    def counted(*args, **kw):
        drawn.append(1)
        return renderer.render_frame(*args, **kw)

    monkeypatch.setattr(orthophoto, "render_frame", counted)
    monkeypatch.setattr(surface, "render_frame", counted)
    xyz = sparse_cloud()
    expected, _ = binned_max(gp.Camera.top_down((xyz.min(axis=0), xyz.max(axis=0)), 1.0), xyz)
    for settings, draws in (({"color_mode": "elevation", "background": "white"}, 1), ({"point_size": 3}, 2), ({"hqs": True}, 2)):
        drawn.clear()
        result = gp.orthophoto(gp.from_arrays(xyz), 1.0, size_mode="fixed", **settings)
        assert len(drawn) == draws, settings
        np.testing.assert_allclose(result.heights, expected, rtol=0, atol=1e-4, err_msg=str(settings))


def test_autzens_dsm_is_each_pixels_highest_point(autzen_path):
    import laspy

    las = laspy.read(autzen_path)
    xyz = np.column_stack([las.x, las.y, las.z])
    heights = gp.orthophoto(autzen_path, 1.0).heights
    expected, on_edge = binned_max(gp.Camera.top_down((xyz.min(axis=0), xyz.max(axis=0)), 1.0), xyz)
    assert heights.shape == expected.shape == (563, 1179)
    np.testing.assert_allclose(heights[~on_edge], expected[~on_edge], rtol=0, atol=1e-3)  # float32 of ~500 ft: 3e-5
    assert np.isfinite(heights).sum() == 103_939 and on_edge.sum() < 10_000  # (points on whole feet: 1 in 100 a side)


def test_the_documented_surface_recipe_gives_each_pixels_highest_point():
    """README and the guide's `cam.heights(gp.render_frame(cloud, cam, ...).depth)` for a
    top_down camera: as first written (the default settings: adaptive splats, 10- and 20-bit
    positions) heights were a neighbour's and up to 0.0024 off."""
    xyz = sparse_cloud(seed=5)
    cloud = gp.from_arrays(xyz)
    cam = gp.Camera.top_down(cloud.bounds, gsd=0.5)
    heights = cam.heights(gp.render_frame(cloud, cam, size_mode="fixed", adaptive_precision=False).depth)
    expected, on_edge = binned_max(cam, xyz)
    assert not on_edge.any()
    np.testing.assert_allclose(heights, expected, rtol=0, atol=1e-4)
    np.testing.assert_allclose(heights, gp.orthophoto(cloud, 0.5).heights, rtol=0, atol=0)
    assert not np.allclose(cam.heights(gp.render_frame(cloud, cam).depth), expected, rtol=0, atol=1e-4, equal_nan=True)  # (the old recipe)
