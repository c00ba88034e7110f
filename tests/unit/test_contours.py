"""Contour lines of a heights raster (render/contours.py) and `render --gsd --contours INTERVAL
[--contours-base B] [--contours-out lines.geojson] [--contours-on-image]`: polylines in world
coordinates at every level, none across a hole, every 5th an index contour, written as GeoJSON in
the cloud's CRS and/or drawn onto the orthophoto where the GeoJSON's lines run."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from gigapoint.errors import GigapointError
from gigapoint.render.contours import LINE_RGB, contour_lines, contours_geojson, draw_contours, write_contours

AUTZEN = str(Path(__file__).resolve().parents[2].parent / "shared" / "data" / "autzen_trim.laz")  # (../shared beside the clone)
SIZE = 2.0  # the grid's pixel size
WORLD_FILE = (SIZE, 0.0, 0.0, -SIZE, 1001.0, 2079.0)  # pixel (row, col)'s centre: x = 1001 + 2 col, y = 2079 - 2 row
ROWS, COLS = np.mgrid[0:60, 0:80]
X, Y = WORLD_FILE[4] + SIZE * COLS, WORLD_FILE[5] - SIZE * ROWS
A, B, C = 0.3, -0.2, 150.0
PLANE = A * X + B * Y + C  # 34.5 .. 105.5


def test_a_planes_contours_are_straight_lines_at_each_level():
    lines = contour_lines(PLANE.astype(np.float32), WORLD_FILE, 10)
    assert [line.elevation for line in lines] == [40.0, 50.0, 60.0, 70.0, 80.0, 90.0, 100.0]  # one line a level
    assert [line.index for line in lines] == [False, True, False, False, False, False, True]  # 50, 100: every 5th
    for line in lines:
        residual = (A * line.xy[:, 0] + B * line.xy[:, 1] + C - line.elevation) / np.hypot(A, B)  # distance off the true line
        assert np.abs(residual).max() < 1e-4 * SIZE  # float32 heights: far inside half a pixel
        assert not line.closed and len(line.xy) > 10
        # from edge to edge of the grid of pixel centres
        ends = line.xy[[0, -1]]
        on_edge = np.isclose(ends[:, 0], X.min()) | np.isclose(ends[:, 0], X.max()) | np.isclose(ends[:, 1], Y.min()) | np.isclose(ends[:, 1], Y.max())
        assert on_edge.all()
    with_base = contour_lines(PLANE, WORLD_FILE, 10, base=3)
    assert [line.elevation for line in with_base] == [43.0, 53.0, 63.0, 73.0, 83.0, 93.0, 103.0]
    assert [line.elevation for line in with_base if line.index] == [53.0, 103.0]  # base + 5k intervals
    assert [line.elevation for line in contour_lines(PLANE, WORLD_FILE, 0.1)][1:4] == [34.6, 34.7, 34.8]  # not 34.800000000000004


def test_a_cones_contours_are_closed_rings_of_the_right_radii():
    centre = (X.mean(), Y.mean())
    radius = np.hypot(X - centre[0], Y - centre[1])
    cone = 200.0 - radius  # level L: a ring of radius 200 - L
    lines = contour_lines(cone, WORLD_FILE, 10)
    rings = [line for line in lines if line.closed]
    assert [line.elevation for line in rings] == [150.0, 160.0, 170.0, 180.0, 190.0]  # radii 50 .. 10 fit in the 158 x 118 grid
    for ring in rings:
        r = np.hypot(ring.xy[:, 0] - centre[0], ring.xy[:, 1] - centre[1])
        assert np.abs(r - (200.0 - ring.elevation)).max() < SIZE / 2  # within half a pixel
        assert len(ring.xy) > 20
    assert all(not line.closed for line in lines if line.elevation < 150)  # larger rings are cut by the grid's edges


def test_a_nan_hole_splits_the_lines_and_no_vertex_lies_in_it():
    heights = PLANE.copy()
    heights[:, 30:40] = np.nan  # a band across the whole grid
    lines = contour_lines(heights, WORLD_FILE, 10)
    whole = contour_lines(PLANE, WORLD_FILE, 10)
    assert len(lines) > len(whole)
    hole_x = (X[0, 29], X[0, 40])  # the last drawn pixel centres either side
    for line in lines:
        x = line.xy[:, 0]
        assert ((x <= hole_x[0]) | (x >= hole_x[1])).all()  # no vertex, hence no segment, inside the band
        assert (x <= hole_x[0]).all() or (x >= hole_x[1]).all()  # each line on one side
    all_nan = np.full((5, 5), np.nan)
    assert contour_lines(all_nan, WORLD_FILE, 1) == []


def test_geojson_holds_the_lines_and_names_the_crs(tmp_path):
    lines = contour_lines(PLANE, WORLD_FILE, 25)
    collection = contours_geojson(lines, "EPSG:2992", None)
    assert collection["crs"] == {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::2992"}}
    assert [f["properties"] for f in collection["features"]] == [
        {"elevation": 50.0, "index": False}, {"elevation": 75.0, "index": False}, {"elevation": 100.0, "index": False},
    ]  # fmt: skip
    feature = collection["features"][1]
    assert feature["geometry"]["type"] == "LineString"
    np.testing.assert_allclose(feature["geometry"]["coordinates"], lines[1].xy, atol=5e-4)
    wkt = 'PROJCS["local feet",GEOGCS["x",DATUM["d",SPHEROID["s",6378137,298.257]],PRIMEM["G",0],UNIT["degree",0.0174532925199433]],UNIT["foot",0.3048]]'
    assert contours_geojson(lines, wkt, wkt)["crs"]["properties"]["name"] == wkt  # no EPSG code: the WKT itself
    assert "crs" not in contours_geojson(lines, None, None)
    path = write_contours(tmp_path / "c.geojson", lines, "EPSG:2992", None, pixel_size=SIZE)
    written = json.loads(path.read_text())
    assert written["crs"] == collection["crs"] and len(written["features"]) == 3
    assert [name.name for name in tmp_path.iterdir()] == ["c.geojson"]  # no temporary file left


@pytest.mark.parametrize("interval", [0, -5, float("nan"), float("inf"), "5", True, None])
def test_bad_intervals_are_one_line_errors(interval):
    with pytest.raises(GigapointError, match=r"^contour_lines: the contour interval must be a number > 0, got "):
        contour_lines(PLANE, WORLD_FILE, interval)


def test_too_many_levels_is_a_one_line_error():
    with pytest.raises(GigapointError, match=r"^contour_lines: interval 0.01 gives 7,100 levels over 71; give a larger one \(at most 1,000 levels\)$"):
        contour_lines(PLANE, WORLD_FILE, 0.01)
    assert len(contour_lines(PLANE, WORLD_FILE, 0.1)) == 710  # 34.5 .. 105.4: under the limit
    with pytest.raises(GigapointError, match=r"^contour_lines: interval 1e-300 gives 7.1e\+301 levels over 71; "):  # (not in 302 digits)
        contour_lines(PLANE, WORLD_FILE, 1e-300)
    with pytest.raises(GigapointError, match=r"^contour_lines: interval 4.94066e-324 gives inf levels over 71; "):  # (overflowed: an OverflowError)
        contour_lines(PLANE, WORLD_FILE, 5e-324)


def test_drawn_lines_cover_the_pixels_they_run_through_and_index_lines_are_twice_as_wide():
    heights = 99.0 - 2.0 * ROWS[:40, :30]  # level L runs along row (99 - L) / 2: 90 between rows 4 and 5, 50 between 24 and 25
    lines = contour_lines(heights, WORLD_FILE, 10)
    assert [(line.elevation, line.index) for line in lines if line.elevation in (50, 90)] == [(50.0, True), (90.0, False)]
    grey = np.full((40, 30, 4), 200, np.uint8)
    drawn = draw_contours(grey, lines, WORLD_FILE)
    assert (grey == 200).all()  # a copy
    half_line = np.rint(200 + (np.array(LINE_RGB) - 200) * 0.5)
    column = drawn[:, 10]  # inside the grid's columns (a line ends at the pixel centres of the edge columns)
    np.testing.assert_array_equal(column[[4, 5], :3], [half_line, half_line])  # a 1-pixel line half over each row
    np.testing.assert_array_equal(column[[24, 25], :3], [LINE_RGB, LINE_RGB])  # the index line, 2 pixels over both
    lined_rows = {4, 5, 14, 15, 24, 25, 34, 35}  # levels 90, 70, 50, 30 (80, 60, 40 between rows 9|10, 19|20, 29|30)
    lined_rows |= {9, 10, 19, 20, 29, 30}
    untouched = [r for r in range(40) if r not in lined_rows]
    assert (drawn[untouched, 1:-1] == 200).all() and (drawn[sorted(lined_rows), 1:-1, :3] < 200).all()
    empty = draw_contours(np.zeros((40, 30, 4), np.uint8), lines, WORLD_FILE)
    assert empty[25, 10].tolist() == [*LINE_RGB, 255] and empty[4, 10, 3] == 128  # empty pixels become opaque by the share covered


def dtm_args(tmp_path, *extra):
    return ["render", AUTZEN, "--classes", "2", "--gsd", "10", "-o", tmp_path / "o.png", "--fill-nodata", "all", *extra]


def test_cli_writes_contours_of_the_dtm(cli, tmp_path):
    from rasterio.crs import CRS

    rc, out, err = cli(*dtm_args(tmp_path, "--depth-out", tmp_path / "dtm.tif", "--contours", 5, "--contours-out", tmp_path / "c.geojson"))
    assert rc == 0, err
    assert "c.geojson" in out
    dtm = np.asarray(Image.open(tmp_path / "dtm.tif"), np.float64)
    size, _, _, minus_size, x0, y0 = (float(v) for v in (tmp_path / "dtm.tfw").read_text().split())
    collection = json.loads((tmp_path / "c.geojson").read_text())
    elevations = np.array([f["properties"]["elevation"] for f in collection["features"]])
    assert len(elevations) > 10 and len(set(elevations)) >= 4
    np.testing.assert_array_equal(elevations % 5, 0)
    assert np.nanmin(dtm) <= elevations.min() and elevations.max() <= np.nanmax(dtm)
    assert [f["properties"]["index"] for f in collection["features"]] == list(elevations % 25 == 0)
    vertices = np.concatenate([f["geometry"]["coordinates"] for f in collection["features"]])
    cols, rows = (vertices[:, 0] - x0) / size, (vertices[:, 1] - y0) / minus_size
    assert cols.min() >= 0 and cols.max() <= dtm.shape[1] - 1 and rows.min() >= 0 and rows.max() <= dtm.shape[0] - 1  # inside the raster
    # a vertex on a row of pixel centres lies where the heights between its two pixels reach its level
    elevation_of = np.concatenate([[f["properties"]["elevation"]] * len(f["geometry"]["coordinates"]) for f in collection["features"]])
    on_row = np.isclose(rows, np.round(rows), atol=1e-3) & ~np.isclose(cols, np.round(cols), atol=1e-3)
    r, c0 = np.round(rows[on_row]).astype(int), np.floor(cols[on_row]).astype(int)
    t = cols[on_row] - c0
    between = dtm[r, c0] * (1 - t) + dtm[r, c0 + 1] * t
    assert on_row.sum() > 50
    np.testing.assert_allclose(between, elevation_of[on_row], atol=0.02)  # coordinates rounded to 0.01 ft
    # the CRS: the .prj's, which GDAL reads from the crs member's name
    name = collection["crs"]["properties"]["name"]
    assert CRS.from_user_input(name) == CRS.from_wkt((tmp_path / "dtm.prj").read_text())


def test_cli_contours_without_depth_out_are_those_of_the_same_heights(cli, tmp_path):
    rc, _, err = cli(*dtm_args(tmp_path, "--depth-out", tmp_path / "dtm.tif", "--contours", 5, "--contours-out", tmp_path / "a.geojson"))
    assert rc == 0, err
    rc, _, err = cli(*dtm_args(tmp_path, "--contours", 5, "--contours-out", tmp_path / "b.geojson", "--overwrite"))
    assert rc == 0, err
    assert (tmp_path / "a.geojson").read_text() == (tmp_path / "b.geojson").read_text()


def test_cli_draws_the_lines_onto_the_orthophoto_where_the_geojson_runs(cli, tmp_path):
    from scipy.spatial import cKDTree

    rc, _, err = cli(*dtm_args(tmp_path, "--depth-out", tmp_path / "dtm.tif", "--contours", 5, "--contours-out", tmp_path / "c.geojson"))
    assert rc == 0, err
    plain = np.asarray(Image.open(tmp_path / "o.png"))  # with --contours-out alone the image is left as rendered
    rc, _, err = cli(*dtm_args(tmp_path, "--depth-out", tmp_path / "dtm.tif", "--contours", 5, "-o", tmp_path / "d.png", "--overwrite"))
    assert rc == 0, err
    drawn = np.asarray(Image.open(tmp_path / "d.png"))  # without --contours-out: drawn onto the image
    rc, _, err = cli(*dtm_args(tmp_path, "--contours", 5, "-o", tmp_path / "both.png", "--contours-out", tmp_path / "c.geojson", "--contours-on-image", "--overwrite"))
    assert rc == 0, err
    np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / "both.png")), drawn)
    size, _, _, minus_size, x0, y0 = (float(v) for v in (tmp_path / "d.pgw").read_text().split())
    features = json.loads((tmp_path / "c.geojson").read_text())["features"]
    vertices = np.concatenate([f["geometry"]["coordinates"] for f in features])
    pixels = np.column_stack(((vertices[:, 0] - x0) / size, (vertices[:, 1] - y0) / minus_size))  # (col, row), pixel centres whole
    changed = (drawn != plain).any(axis=2)
    cols, rows = np.rint(pixels).astype(int).T
    assert changed[rows, cols].all()  # every pixel a line runs through is drawn on
    # and nothing else: a drawn pixel's centre lies within the widest line's half width (1 pixel) and
    # half a pixel's diagonal of a line, so within 1 + 0.71 + 0.71 (vertices on a line are at most a diagonal apart)
    distance, _ = cKDTree(pixels).query(np.argwhere(changed)[:, ::-1])
    assert distance.max() <= 2.5
    assert 0.02 < changed.mean() < 0.5  # lines, not the whole image


def test_cli_contours_base_shifts_the_levels_and_the_index_contours(cli, tmp_path):
    rc, _, err = cli(*dtm_args(tmp_path, "--contours", 5, "--contours-base", 2.5, "--contours-out", tmp_path / "c.geojson"))
    assert rc == 0, err
    properties = [f["properties"] for f in json.loads((tmp_path / "c.geojson").read_text())["features"]]
    elevations = np.array([p["elevation"] for p in properties])
    assert len(set(elevations)) >= 4
    np.testing.assert_array_equal(elevations % 5, 2.5)  # 2.5 + 5k
    assert [p["index"] for p in properties] == list((elevations - 2.5) % 25 == 0)  # 2.5 + 25k: every 5th counted from the base


@pytest.mark.parametrize(
    "args, message",
    [
        (["--gsd", "10", "--contours", "0", "--contours-out", "c.geojson"], "error: --contours: the contour interval must be a number > 0, got 0.0"),
        (["--gsd", "10", "--contours", "nan", "--contours-out", "c.geojson"], "error: --contours: the contour interval must be a number > 0, got nan"),
        (["--gsd", "10", "--contours", "5", "--contours-base", "nan"], "error: --contours-base: the contour base must be a finite number, got nan"),
        (["--gsd", "10", "--contours", "5", "--contours-base", "-inf"], "error: --contours-base: the contour base must be a finite number, got -inf"),
        (["--gsd", "10", "--contours-out", "c.geojson"], "error: --contours-out: an option of --contours INTERVAL"),
        (["--gsd", "10", "--contours-base", "2", "--contours-on-image"], "error: --contours-base and --contours-on-image: options of --contours INTERVAL"),
        (["--contours", "5", "--contours-out", "c.geojson"], "error: --contours: an option of --gsd (contour lines of a top-down render's surface model)"),
        (["--gsd", "10", "--contours", "5", "--contours-out", "c.shp"], "unsupported output type '.shp'; use one of .geojson, .json"),
        (["--gsd", "10", "--contours", "0.001", "--contours-out", "c.geojson"], "error: --contours: interval 0.001 ft gives 113,780 levels over 113.78 ft; give a larger one (at most 1,000 levels)"),
    ],
)
def test_cli_bad_contour_options_are_one_line_errors(cli, tmp_path, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    rc, _, err = cli("render", AUTZEN, "-o", "o.png", *args)
    assert rc == 1 and err.count("\n") == 1 and message in err, err
    assert not list(tmp_path.iterdir())  # nothing written, the image neither


def test_cli_refuses_an_existing_contours_file(cli, tmp_path):
    (tmp_path / "c.geojson").write_text("mine")
    rc, _, err = cli("render", AUTZEN, "-o", tmp_path / "o.png", "--gsd", "10", "--contours", "5", "--contours-out", tmp_path / "c.geojson")
    assert rc == 1 and err.strip() == f"error: {tmp_path / 'c.geojson'}: already exists; pass --overwrite to replace it", err
    assert (tmp_path / "c.geojson").read_text() == "mine" and sorted(p.name for p in tmp_path.iterdir()) == ["c.geojson"]
