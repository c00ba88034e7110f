"""Height above ground (heights.py's ``height_above_ground``, ``classify_ground(heights=True)``,
``gigapoint classify --height-above-ground``): a sloped, curved terrain with buildings and poles
of known heights measured within the ground model's interpolation error, autzen's ground at 0
and its other points above it, the attribute read back by gigapoint and laspy."""

from __future__ import annotations

import laspy
import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import InputError

#: the terrain's curvature: z'' along x of 1.5 sin(x / 20) is at most 1.5 / 20²; along y none
CURVATURE = 1.5 / 20**2
#: the LAS z scale the test files are written at: each z rounded by up to half of it
SCALE = 0.001


def _terrain(x, y):
    return 0.3 * x - 0.2 * y + 1.5 * np.sin(x / 20.0)


def _write_las(path, xyz, classification):
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.scales, header.offsets = [SCALE] * 3, [0.0] * 3
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz.T
    las.classification = classification.astype(np.uint8)
    las.write(str(path))
    return path


def _slope_with_objects(rng):
    """(xyz, classification, known height above ground) of 100 x 80 m of sloped, curved ground
    on a 0.5 m lattice (class 2: four points a 1 m cell, around its centre), box buildings (roofs
    only, at 6 and 10 m over the ground beneath each roof point, no ground under them: class 1)
    and poles over the ground beside them (class 1, 0.5 to 15 m up). Two class-1 points at the corners
    (0, 0) and (100, 80) put the 1 m cells' edges on whole metres."""
    g = np.stack(np.meshgrid(np.arange(0.25, 100, 0.5), np.arange(0.25, 80, 0.5)), -1).reshape(-1, 2)
    boxes = [(20, 20, 20, 15, 6.0), (60, 40, 14, 24, 10.0)]  # (x0, y0, width, depth, height): whole metres
    under = np.zeros(len(g), bool)
    roofs, roof_heights = [], []
    for x0, y0, w, d, tall in boxes:
        under |= (g[:, 0] > x0) & (g[:, 0] < x0 + w) & (g[:, 1] > y0) & (g[:, 1] < y0 + d)
        r = rng.uniform((x0 + 0.1, y0 + 0.1), (x0 + w - 0.1, y0 + d - 0.1), (w * d, 2))
        roofs.append(np.column_stack([r, _terrain(r[:, 0], r[:, 1]) + tall]))
        roof_heights.append(np.full(len(r), tall))
    g = g[~under]
    ground = np.column_stack([g, _terrain(g[:, 0], g[:, 1])])
    poles = rng.uniform((5, 5), (95, 75), (3000, 2))
    poles = poles[~np.any([(poles[:, 0] > x0 - 1) & (poles[:, 0] < x0 + w + 1) & (poles[:, 1] > y0 - 1) & (poles[:, 1] < y0 + d + 1) for x0, y0, w, d, _ in boxes], axis=0)]
    pole_heights = rng.uniform(0.5, 15, len(poles))
    poles = np.column_stack([poles, _terrain(poles[:, 0], poles[:, 1]) + pole_heights])
    corners = np.array([[0.0, 0.0, _terrain(0, 0) + 1], [100.0, 80.0, _terrain(100, 80) + 1]])
    xyz = np.vstack([ground, *roofs, poles, corners])
    classes = np.r_[np.full(len(ground), 2), np.ones(len(xyz) - len(ground))]
    known = np.r_[np.zeros(len(ground)), *roof_heights, pole_heights, np.ones(2)]
    # how far the ground model may be off under each point: linear interpolation's error bound,
    # curvature x span² / 8, the span a building's width of missing cells + 1 within a cell of a
    # building (10 % on it: the fill's blend is near linear, not exactly), one cell elsewhere;
    # and the z's rounding
    bound = np.full(len(xyz), CURVATURE / 8 + 2 * SCALE)
    for x0, y0, w, d, _ in boxes:
        near = (xyz[:, 0] > x0 - 1) & (xyz[:, 0] < x0 + w + 1) & (xyz[:, 1] > y0 - 1) & (xyz[:, 1] < y0 + d + 1)
        bound[near] = 1.1 * CURVATURE * (w + 1) ** 2 / 8 + 2 * SCALE
    return xyz, classes, known, bound


@pytest.fixture(scope="module")
def sloped(tmp_path_factory):
    xyz, classes, known, bound = _slope_with_objects(np.random.default_rng(5))
    return _write_las(tmp_path_factory.mktemp("hag") / "slope.las", xyz, classes), known, bound


def test_known_heights_are_measured_within_the_models_interpolation_error(sloped, tmp_path):
    path, known, bound = sloped
    result = gp.height_above_ground(path, tmp_path / "out.laz")
    las = laspy.read(str(tmp_path / "out.laz"))
    heights = np.asarray(las.HeightAboveGround)
    # the model is carried flat beyond the outermost cells' centres (the outer half metre)
    inside = (np.asarray(las.x) >= 0.5) & (np.asarray(las.x) <= 99.5) & (np.asarray(las.y) >= 0.5) & (np.asarray(las.y) <= 79.5)
    error, bound = np.abs(heights - known)[inside], bound[inside]
    assert (error <= bound).all(), f"worst {(error - bound).max():.4f} over its bound"
    near_buildings = bound > 0.01
    assert error[near_buildings].max() > 0.05 and error[~near_buildings].max() < 0.005  # (the bound is no blank cheque: measured 0.19 and 0.0012)
    assert result.ground == int((known == 0).sum()) and result.points == len(known)
    assert result.heights == pytest.approx((heights.min(), heights.max()), abs=1e-5)
    assert result.params == {"cell": 1.0, "units": "m (assumed)", "height_units": "m (assumed)"}


def test_normalize_writes_the_height_as_z_and_keeps_x_y(sloped, tmp_path):
    path, known, _ = sloped
    gp.height_above_ground(path, tmp_path / "chm.las", normalize=True)
    a, b = laspy.read(str(path)), laspy.read(str(tmp_path / "chm.las"))
    np.testing.assert_array_equal(np.asarray(a.x), np.asarray(b.x))
    np.testing.assert_allclose(np.asarray(b.z), np.asarray(b.HeightAboveGround), rtol=0, atol=SCALE)
    np.testing.assert_allclose(np.asarray(b.z), known, rtol=0, atol=0.25)


def test_autzens_ground_is_at_0_and_the_rest_above_it(autzen_path, tmp_path):
    """From autzen's own class 2 (no class 6 in it: its other points are 1), and from the ground
    SMRF finds in the same run; gigapoint reads the attribute back as laspy does."""
    gp.height_above_ground(autzen_path, tmp_path / "hag.laz")
    las = laspy.read(str(tmp_path / "hag.laz"))
    heights, classes = np.asarray(las.HeightAboveGround), np.asarray(las.classification)
    assert las.point_format.dimension_by_name("HeightAboveGround").dtype == np.float32
    ground = heights[classes == 2]
    assert abs(np.median(ground)) < 0.01 and (np.abs(ground) < 0.5).mean() > 0.98  # feet: measured median 0.0005, 99.7 %
    assert np.percentile(heights[classes == 1], 99) > 50  # autzen's trees and roofs: up to 108 ft
    cloud = gp.open(tmp_path / "hag.laz")
    np.testing.assert_array_equal(np.sort(cloud.attributes["HeightAboveGround"]), np.sort(heights))  # (gp.open orders the points its own way)

    result = gp.classify_ground(autzen_path, tmp_path / "both.laz", heights=True)
    las = laspy.read(str(tmp_path / "both.laz"))
    heights, classes = np.asarray(las.HeightAboveGround), np.asarray(las.classification)
    assert abs(np.median(heights[classes == 2])) < 0.2 and (heights[classes == 1] > 0).mean() > 0.99  # measured 0.07 ft, 99.9 %
    assert result.heights == pytest.approx((heights.min(), heights.max()), abs=1e-4)


def test_a_cloud_with_no_ground_is_a_one_line_error(tmp_path, cli):
    path = _write_las(tmp_path / "raw.las", np.random.default_rng(0).uniform(0, 10, (100, 3)), np.ones(100))
    with pytest.raises(InputError, match=r"raw.las: no ground point \(class 2\) to measure heights from: classify the ground in the same run"):
        gp.height_above_ground(path, tmp_path / "out.laz")
    rc, _, err = cli("classify", path, "-o", tmp_path / "out.laz", "--height-above-ground")
    assert rc != 0 and err.strip().endswith("raw.las: no ground point (class 2) to measure heights from: classify the ground in the same run (--ground)")
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "out.laz").exists()
    rc, out, err = cli("classify", path, "-o", tmp_path / "out.laz", "--height-above-ground", "--ground", "--cell", "2", "-q")
    assert rc == 0, err
    assert " heights above ground " in out and " in HeightAboveGround; cell 2 m (assumed)" in out


def test_the_cli_writes_heights_that_info_lists_and_render_colours_by(cli, sloped, tmp_path):
    path, _, _ = sloped
    rc, out, err = cli("classify", path, "-o", tmp_path / "hag.laz", "--height-above-ground", "-q")
    assert rc == 0, err
    assert " in HeightAboveGround; ground model of " in out and " class-2 points, cell 1 m (assumed)" in out
    rc, _, err = cli("classify", path, "-o", tmp_path / "hag.laz", "--height-above-ground")
    assert rc != 0 and err == f"error: {tmp_path / 'hag.laz'}: already exists; pass --overwrite to replace it\n"  # (said as the option)
    rc, out, err = cli("info", tmp_path / "hag.laz")
    assert rc == 0 and "HeightAboveGround" in out.split("attributes:")[1].splitlines()[0]
    rc, _, err = cli("render", tmp_path / "hag.laz", "-o", tmp_path / "hag.png", "--color-mode", "attribute", "--color-attribute", "HeightAboveGround", "--width", "64", "--height", "48")
    assert rc == 0, err
    rc, _, err = cli("classify", path, "-o", tmp_path / "b.laz", "--height-above-ground", "--slope", "0.2")
    assert rc != 0 and "classify: --slope is for the ground classification: give --ground too" in err


@pytest.mark.parametrize("normalize", [False, True])
def test_classify_grounds_heights_are_its_models_bilinear_read_once_a_point(sloped, tmp_path, monkeypatch, normalize):
    """``classify_ground(heights=True)`` measures each point against the DEM it classified it
    by, read once: bit for bit z minus ``RasterGrid.bilinear`` of that DEM, with no second read."""
    from gigapoint.survey import ground as smrf
    from gigapoint.survey.raster_grid import RasterGrid

    path, _, _ = sloped
    made = {}
    real_model, real_raster = smrf.ground_model, smrf._lowest_raster
    monkeypatch.setattr(smrf, "ground_model", lambda *args: made.setdefault("dem", real_model(*args)))
    monkeypatch.setattr(smrf, "_lowest_raster", lambda *args: made.setdefault("grid and lowest", real_raster(*args)))
    read = {"bilinear": [], "with cell values": []}  # the points of each read of the DEM
    bilinear, with_cell_values = RasterGrid.bilinear, RasterGrid.bilinear_and_cell_values
    monkeypatch.setattr(RasterGrid, "bilinear", lambda self, raster, xy: read["bilinear"].append(len(xy)) or bilinear(self, raster, xy))
    monkeypatch.setattr(RasterGrid, "bilinear_and_cell_values",
                        lambda self, raster, values, xy: read["with cell values"].append(len(xy)) or with_cell_values(self, raster, values, xy))  # fmt: skip

    result = gp.classify_ground(path, tmp_path / "out.las", heights=True, normalize=normalize, chunk_size=10_000)
    chunks = read["with cell values"]
    assert read["bilinear"] == [] and len(chunks) > 1 and sum(chunks) == result.points  # one read a point, in several chunks

    a, b = laspy.read(str(path)), laspy.read(str(tmp_path / "out.las"))
    xyz = np.column_stack([np.asarray(a.x), np.asarray(a.y), np.asarray(a.z)])
    grid, _ = made["grid and lowest"]
    expected = xyz[:, 2] - bilinear(grid, made["dem"], xyz)
    np.testing.assert_array_equal(np.asarray(b.HeightAboveGround), expected.astype(np.float32))
    assert result.heights == (expected.min(), expected.max())


def test_coordinates_in_degrees_are_measured_with_a_cell_given(tmp_path):
    """A WGS 84 cloud was refused even with its cell given, by classify_ground's words (\"give
    cell and window\": height_above_ground takes no window), as was a cell of 0: now only the
    default cell (1 m, no length in degrees) is refused, under its own name; given, it runs."""
    from test_change import write_degrees_grid  # (tests/unit is on sys.path)

    first = np.arange(400) == 0
    path = write_degrees_grid(tmp_path / "wgs84.las", 20, lambda x, y: np.where(first, 7.0, 2.0))  # the first point 5 above the others' plane
    las = laspy.read(str(path))
    las.classification = np.where(first, 1, 2).astype(np.uint8)
    las.write(str(path))
    with pytest.raises(InputError) as caught:
        gp.height_above_ground(path, tmp_path / "out.las")
    assert str(caught.value) == (
        f"height_above_ground: {path} has coordinates in degrees (EPSG:4326); a default cell (1 m) needs metres or feet: "
        "give cell, or reproject first (gigapoint convert --to-crs EPSG:32610, WGS 84 / UTM zone 10N, where the data lie)"
    )
    with pytest.raises(InputError, match=r"^height_above_ground: cell must be a number > 0, got 0$"):
        gp.height_above_ground(path, tmp_path / "out.las", cell=0)
    result = gp.height_above_ground(path, tmp_path / "out.las", cell=0.00004)
    heights = np.asarray(laspy.read(str(tmp_path / "out.las"))["HeightAboveGround"])
    assert result.params["cell"] == 0.00004 and heights[0] == pytest.approx(5.0, abs=0.01) and np.abs(heights[1:]).max() < 0.01


def test_the_cli_says_heights_in_the_vertical_unit_of_a_cloud_in_degrees(tmp_path, cli):
    """A cloud in WGS 84 with heights in metres: its heights above ground were said in degrees
    ('0 to 5 °', the horizontal unit); now in metres, its cell still in degrees."""
    from test_change import EPSG_4326_METRES_UP_KEYS, write_degrees_grid  # (tests/unit is on sys.path)

    first = np.arange(400) == 0
    path = write_degrees_grid(tmp_path / "wgs84.las", 20, lambda x, y: np.where(first, 7.0, 2.0), keys=EPSG_4326_METRES_UP_KEYS)
    las = laspy.read(str(path))
    las.classification = np.where(first, 1, 2).astype(np.uint8)
    las.write(str(path))
    rc, out, err = cli("classify", path, "-o", tmp_path / "hag.las", "--height-above-ground", "--cell", "0.00004", "-q")
    assert rc == 0, err
    assert ": 400 points, heights above ground 0 to 5 m in HeightAboveGround; ground model of 399 class-2 points, cell 4e-05 °; " in out
    rc, out, err = cli("classify", path, "-o", tmp_path / "both.las", "--ground", "--height-above-ground", "--cell", "0.00004", "--window", "0.0002", "-q")
    assert rc == 0, err
    assert ", heights above ground 0 to 5 m in HeightAboveGround; cell 4e-05 °, " in out


def test_a_ply_in_degrees_is_refused_its_default_cell(tmp_path):
    """As a LAS file in degrees is (above): the PLY file's ``comment crs`` line was not read."""
    from test_change import write_degrees_grid  # (tests/unit is on sys.path)

    ply = tmp_path / "wgs84.ply"
    gp.convert(write_degrees_grid(tmp_path / "wgs84.las", 20), ply)
    with pytest.raises(InputError) as caught:
        gp.height_above_ground(ply, tmp_path / "out.las")
    assert str(caught.value) == (
        f"height_above_ground: {ply} has coordinates in degrees (EPSG:4326); a default cell (1 m) needs metres or feet: "
        "give cell, or reproject first (gigapoint convert --to-crs EPSG:n of a projected CRS)"
    )
