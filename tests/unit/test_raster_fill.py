"""Gap filling of top-down rasters (render/raster_fill, `render --gsd --fill-nodata`): a DSM/DTM's
NaN holes interpolated linearly inside the data's footprint, the orthophoto's speckle closed
with the nearest colour."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from gigapoint.errors import GigapointError
from gigapoint.render.raster_fill import fill_colors, fill_everywhere, fill_heights

AUTZEN = str(Path(__file__).resolve().parents[2].parent / "shared" / "data" / "autzen_trim.laz")  # (../shared beside the clone)
ROWS, COLS = np.mgrid[0:60, 0:80]
PLANE = (0.3 * COLS - 0.7 * ROWS + 112.5).astype(np.float32)  # z = a x + b y + c on the pixel grid


def test_a_square_hole_in_a_plane_is_filled_with_the_plane():
    heights = PLANE.copy()
    heights[20:35, 30:50] = np.nan
    filled = fill_heights(heights)
    assert not np.isnan(filled).any() and np.isnan(heights[20:35, 30:50]).all()  # a copy: the input kept
    np.testing.assert_allclose(filled, PLANE, rtol=0, atol=1e-4)


def test_max_distance_fills_speckle_and_only_a_big_holes_rim():
    rng = np.random.default_rng(0)
    heights = PLANE.copy()
    speckle = rng.random(PLANE.shape) < 0.1
    heights[speckle] = np.nan
    heights[20:40, 30:50] = np.nan  # 20 x 20: its middle lies more than 2 pixels from data
    filled = fill_heights(heights, max_distance=2)
    kept = np.isnan(filled)
    # the big hole's middle stays: its pixels 3 or more from the nearest drawn one (it has speckle on its rim)
    assert kept[23:37, 33:47].all() and kept.sum() < 20 * 20
    assert not kept[:18].any() and not kept[42:].any()  # speckle elsewhere closed
    np.testing.assert_allclose(filled[~kept], PLANE[~kept], rtol=0, atol=1e-4)
    assert np.isnan(fill_heights(heights, max_distance=1)).sum() > kept.sum()


def test_pixels_outside_the_footprint_stay_nan():
    heights = np.where(ROWS > COLS / 2 + 5, PLANE, np.nan).astype(np.float32)  # data below a slanted edge
    heights[40:45, 40:45] = np.nan
    for distance in (None, 3):
        filled = fill_heights(heights, max_distance=distance)
        np.testing.assert_array_equal(np.isnan(filled), np.isnan(heights) & ~((ROWS >= 40) & (ROWS < 45) & (COLS >= 40) & (COLS < 45)))
        np.testing.assert_allclose(filled[40:45, 40:45], PLANE[40:45, 40:45], rtol=0, atol=1e-4)
    only_a_line = np.full((5, 5), np.nan, np.float32)
    only_a_line[2] = 1.0  # a footprint of no area: nothing to fill, no Qhull error
    np.testing.assert_array_equal(np.isnan(fill_heights(only_a_line)), np.isnan(only_a_line))


def test_fill_everywhere_keeps_a_plane_in_holes_beyond_the_data_and_between_sparse_cells():
    """The fast fill (classify's DEMs): first-order pull-push keeps a plane exactly, in a hole,
    in a corner outside the data's hull, and with 90 % of the cells empty (plain pull-push sagged
    1.97 in the 15 x 20 hole); the known cells keep their values to the bit."""
    plane = 0.3 * COLS - 0.7 * ROWS + 112.5  # (float64: PLANE's float32 rounding is no fill's error)
    heights = plane.copy()
    heights[20:35, 30:50] = np.nan
    heights[:10, :10] = np.nan
    sparse = np.where(np.random.default_rng(0).random(PLANE.shape) < 0.9, np.nan, plane)
    for raster in (heights, sparse):
        kept = raster.copy()
        filled = fill_everywhere(raster)
        np.testing.assert_array_equal(raster, kept)  # a copy: the input kept
        np.testing.assert_allclose(filled, plane, rtol=0, atol=1e-9)
        known = ~np.isnan(raster)
        np.testing.assert_array_equal(filled[known], raster[known])


def test_fill_everywhere_bends_like_linear_interpolation_over_a_curved_hole():
    """A 20 x 20 hole in a surface curved along x (z'' at most 1.5 / 20²): off by little more than
    linear interpolation's bound, curvature x span² / 8 (measured 0.1884 against 0.1875)."""
    rows, cols = np.mgrid[0:80, 0:100].astype(np.float64)
    surface = 0.3 * cols - 0.2 * rows + 1.5 * np.sin(cols / 20)
    holed = surface.copy()
    holed[30:50, 40:60] = np.nan
    error = np.abs(fill_everywhere(holed) - surface)
    assert 0.1 < error.max() <= 1.1 * (1.5 / 20**2) * 21**2 / 8  # (21: the span between the known cells either side)


def test_fill_everywhere_leaves_what_it_cannot_fill():
    nothing = np.full((4, 5), np.nan)
    assert np.isnan(fill_everywhere(nothing)).all()
    np.testing.assert_array_equal(fill_everywhere(PLANE), PLANE)
    one = np.full((3, 4), np.nan)
    one[1, 2] = 7.0  # one known cell: every cell takes it (no slope to carry)
    np.testing.assert_array_equal(fill_everywhere(one), np.full((3, 4), 7.0))
    row = np.array([[1.0, 2.0, np.nan, np.nan, 5.0, 6.0, np.nan]])  # one row, its slope told by neighbouring cells: the line along it
    np.testing.assert_allclose(fill_everywhere(row), [np.arange(1.0, 8.0)], rtol=0, atol=1e-12)
    np.testing.assert_allclose(fill_everywhere(row.T), np.arange(1.0, 8.0)[:, None], rtol=0, atol=1e-12)
    with pytest.raises(GigapointError, match=r"fill_everywhere takes an \(H, W\) raster, got shape \(3,\)"):
        fill_everywhere(np.zeros(3))


def test_fill_colors_gives_speckle_the_nearest_colour_within_the_distance():
    image = np.zeros((9, 9, 4), np.uint8)
    image[:, :5] = (200, 10, 10, 255)
    image[:, 5:] = (10, 10, 200, 255)
    empty = np.zeros((9, 9), bool)
    empty[4, 1] = empty[4, 7] = True  # speckle
    empty[:, 0] = True  # a whole edge column: outside the drawn pixels' hull
    image[empty] = (0, 0, 0, 255)  # the background
    filled = fill_colors(image, empty, 1)
    assert tuple(filled[4, 1]) == (200, 10, 10, 255) and tuple(filled[4, 7]) == (10, 10, 200, 255)
    assert (filled[:, 0] == (0, 0, 0, 255)).all()
    with pytest.raises(GigapointError, match="fill_colors needs a max_distance in pixels"):
        fill_colors(image, empty, None)


def test_bad_max_distances_and_a_missing_scipy_are_one_line_errors(monkeypatch):
    for bad in (0, -1, 1.5, "2", True):
        with pytest.raises(GigapointError, match="fill_heights: max_distance must be an integer >= 1 pixels"):
            fill_heights(PLANE, max_distance=bad)
    monkeypatch.setitem(sys.modules, "scipy.spatial", None)  # import scipy.spatial: ImportError
    with pytest.raises(GigapointError, match=r"^fill_heights needs scipy \(pip install 'gigapoint\[quality\]'\)$"):
        fill_heights(PLANE)


def test_cli_dtm_has_no_nan_inside_the_grounds_footprint(cli, tmp_path):
    from scipy import ndimage
    from scipy.spatial import Delaunay

    args = ["render", AUTZEN, "--classes", "2", "--gsd", "10"]
    rc, _, err = cli(*args, "-o", tmp_path / "raw.png", "--depth-out", tmp_path / "raw.tif")
    assert rc == 0, err
    rc, _, err = cli(*args, "-o", tmp_path / "dtm.png", "--depth-out", tmp_path / "dtm.tif", "--fill-nodata", "all")
    assert rc == 0, err
    raw, dtm = np.asarray(Image.open(tmp_path / "raw.tif")), np.asarray(Image.open(tmp_path / "dtm.tif"))
    drawn = ~np.isnan(raw)
    pixels = np.argwhere(np.ones(raw.shape, bool))
    footprint = (Delaunay(np.argwhere(drawn)).find_simplex(pixels) >= 0).reshape(raw.shape)  # the ground's convex hull
    holes = ~drawn & footprint
    assert holes.sum() > 1000  # buildings and trees left holes in the ground
    assert not np.isnan(dtm[footprint]).any()
    np.testing.assert_array_equal(np.isnan(dtm), ~drawn & ~footprint)  # outside it: still NaN
    np.testing.assert_array_equal(dtm[drawn], raw[drawn])
    # each hole's values lie between the drawn heights around it: those within the hole's box
    # widened by its own size (a hole on the footprint's edge is spanned by triangles reaching past its rim)
    labels, n = ndimage.label(holes, np.ones((3, 3)))
    for box in ndimage.find_objects(labels):
        pad = max(box[0].stop - box[0].start, box[1].stop - box[1].start) + 2
        around = tuple(slice(max(s.start - pad, 0), s.stop + pad) for s in box)
        near, hole = raw[around][drawn[around]], dtm[box][holes[box]]
        assert near.min() <= hole.min() and hole.max() <= near.max()
    assert n > 50


def test_cli_fill_nodata_n_closes_the_orthophotos_speckle_too(cli, tmp_path):
    rc, _, err = cli("render", AUTZEN, "-o", tmp_path / "raw.png", "--gsd", "4", "--depth-out", tmp_path / "raw.tif")
    assert rc == 0, err
    rc, _, err = cli("render", AUTZEN, "-o", tmp_path / "o.png", "--gsd", "4", "--depth-out", tmp_path / "o.tif", "--fill-nodata", "1")
    assert rc == 0, err
    raw, dsm = np.asarray(Image.open(tmp_path / "raw.tif")), np.asarray(Image.open(tmp_path / "o.tif"))
    raw_image, image = np.asarray(Image.open(tmp_path / "raw.png")), np.asarray(Image.open(tmp_path / "o.png"))
    filled = np.isnan(raw) & ~np.isnan(dsm)
    assert filled.sum() > 100
    # only speckle: every filled pixel has a drawn 4-neighbour (within 1 pixel)
    padded = np.pad(~np.isnan(raw), 1)
    next_to_data = padded[:-2, 1:-1] | padded[2:, 1:-1] | padded[1:-1, :-2] | padded[1:-1, 2:]
    assert next_to_data[filled].all()
    background = (raw_image[..., :3] == 0).all(axis=-1)
    assert background[filled].all() and not (image[filled][:, :3] == 0).all(axis=-1).any()  # coloured now
    np.testing.assert_array_equal(image[~filled], raw_image[~filled])


@pytest.mark.parametrize(
    "args, message",
    [
        (["--fill-nodata", "all"], "--fill-nodata: an option of --gsd"),
        (["--gsd", "8", "--fill-nodata", "0"], "--fill-nodata must be 'all' or a whole number of pixels >= 1, got '0'"),
        (["--gsd", "8", "--fill-nodata", "some"], "--fill-nodata must be 'all' or a whole number of pixels >= 1, got 'some'"),
        (["--gsd", "8", "--fill-nodata", "all"], "--fill-nodata all fills the surface model: give --depth-out too"),
    ],
)
def test_cli_fill_nodata_errors_are_one_line(cli, tmp_path, args, message):
    rc, _, err = cli("render", AUTZEN, "-o", tmp_path / "o.png", *args)
    assert rc == 1 and err.count("\n") == 1 and message in err, err
    assert not list(tmp_path.iterdir())


def test_cli_without_scipy_says_what_to_install(cli, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "scipy.ndimage", None)
    rc, _, err = cli("render", AUTZEN, "-o", tmp_path / "o.png", "--gsd", "8", "--fill-nodata", "2")
    assert rc == 1 and err.strip() == "error: --fill-nodata needs scipy (pip install 'gigapoint[quality]')", err
    assert not list(tmp_path.iterdir())
