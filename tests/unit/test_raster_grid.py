"""The raster grid the survey commands share (survey/raster_grid.py): ground/heights rasters laid
over the data (``RasterGrid.over``) and change/volume images (``RasterGrid.of_camera``), one rule
for which cell a position is in, where cells' centres lie and how values are read between them."""

from __future__ import annotations

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.core.chunk import PointChunk
from gigapoint.io.polygon import clip_polygon_of
from gigapoint.render import Camera
from gigapoint.survey import ground as smrf
from gigapoint.survey.change import surface
from gigapoint.survey.raster_grid import RasterGrid


def test_a_grid_over_data_counts_rows_north_and_puts_an_edge_point_in_the_cell_after_it():
    grid = RasterGrid.over((10.0, 20.0, 0.0), (14.0, 23.0, 5.0), 1.0)
    assert grid.shape == (4, 5)  # floor(extent / cell) + 1: the highest x and y inside the last cells
    assert grid.bounds == (10.0, 20.0, 15.0, 24.0)
    xy = np.array([[10.0, 20.0], [11.0, 21.0], [14.0, 23.0], [13.5, 20.5], [9.0, 25.0]])
    rows, cols = grid.cells_of(xy)
    # (11, 21) lies on two edges: the cell to its north-east; (9, 25) beyond the grid: its edge cell
    assert rows.tolist() == [0, 1, 3, 0, 3]
    assert cols.tolist() == [0, 1, 4, 3, 0]
    assert grid.centres(np.array([0, 3]), np.array([3, 4])).tolist() == [[13.5, 20.5], [14.5, 23.5]]


def test_a_cameras_grid_is_its_image_rows_south_as_the_rasterizer_fills_it():
    camera = Camera.top_down(((0.0, 0.0, 0.0), (10.0, 6.0, 1.0)), 1.0)
    assert camera.world_file() == (1.0, 0.0, 0.0, -1.0, -0.5, 6.5)  # its edges a pixel beyond the box: x -1..11, y -1..7
    grid = RasterGrid.of_camera(camera)
    assert grid.shape == (camera.height, camera.width) == (8, 12)
    assert grid.bounds == (-1.0, -1.0, 11.0, 7.0)
    assert grid.centres(np.array([0, 7]), np.array([0, 11])).tolist() == [[-0.5, 6.5], [10.5, -0.5]]
    # points on pixel edges (x 3, y 2, y 4): in the column east of it, the row south of it (row r: y in (6 - r, 7 - r])
    xyz = np.array([[3.0, 2.0, 0.25], [5.5, 4.0, 0.5], [0.25, 5.75, 0.75]])
    rows, cols = grid.cells_of(xyz)
    assert rows.tolist() == [5, 3, 1]
    assert cols.tolist() == [4, 6, 1]
    heights = surface(gp.from_arrays(xyz), camera)  # the rasterizer's pixels: the same
    assert np.argwhere(~np.isnan(heights)).tolist() == [[1, 1], [3, 6], [5, 4]]
    assert heights[rows, cols].tolist() == [0.25, 0.5, 0.75]


def test_a_cameras_grid_measures_from_its_first_centre_as_volume_always_has():
    """A toe vertex on a column edge of a 0.3 grid: measured from the world file's centre
    (volume's toe heights since it was written) it lies in column 464; measured from the corner
    half a pixel off it (a rounded sum), in 465: the grid keeps the number it was given."""
    centre = RasterGrid((619199.25, 5000100.15), 0.3, (335, 670), rows_north=False, measured_from="centre")
    corner = RasterGrid((619199.1, 5000100.3), 0.3, (335, 670), rows_north=False, measured_from="corner")
    vertex = np.array([[619338.6, 5000050.0]])
    assert centre.cells_of(vertex)[1].tolist() == [464]
    assert corner.cells_of(vertex)[1].tolist() == [465]


def test_bilinear_reads_centres_exactly_between_them_linearly_and_carries_the_edges_on():
    over_data = RasterGrid.over((0.0, 0.0), (2.5, 1.5), 1.0)
    raster = np.array([[0.0, 1.0, 2.0], [10.0, 11.0, 12.0]])  # row 0 the southern
    xy = np.array([[0.5, 0.5], [1.0, 0.5], [0.5, 1.0], [2.5, 1.5], [-5.0, -5.0], [9.0, 9.0], [1.75, 1.25]])
    expected = [0.0, 0.5, 5.0, 12.0, 0.0, 12.0, 8.75]  # (1.75, 1.25): 1.25 + 0.75 x 10
    assert over_data.bilinear(raster, xy).tolist() == expected
    # the same cells as an image (rows southwards, measured from the first centre): its raster upside down
    image = RasterGrid((0.5, 1.5), 1.0, (2, 3), rows_north=False, measured_from="centre")
    assert image.bounds == over_data.bounds
    assert image.bilinear(raster[::-1], xy).tolist() == expected


def test_the_cells_whose_centre_lies_inside_a_polygon():
    square = clip_polygon_of("POLYGON((2 2, 5 2, 5 4, 2 4, 2 2))", "test")
    over_data = RasterGrid.over((0.0, 0.0), (9.5, 9.5), 1.0)
    rows, cols = np.nonzero(over_data.centres_inside(square))
    assert sorted(set(rows.tolist())) == [2, 3] and sorted(set(cols.tolist())) == [2, 3, 4]
    image = RasterGrid((0.5, 9.5), 1.0, (10, 10), rows_north=False, measured_from="centre")
    assert (image.centres_inside(square) == over_data.centres_inside(square)[::-1]).all()


# A numpy reference of the module's rules (cell coordinates, the cell holding a position, the
# bilinear read), op for op as the grid computed them before its kernels took them over: the
# kernels must agree with it bit for bit, on cell edges and beyond the grid too.


def _reference_cell_coordinates(grid: RasterGrid, xy: np.ndarray):
    x0, y0 = grid.origin
    cols = (xy[:, 0] - x0) / grid.cell
    rows = (xy[:, 1] - y0) / grid.cell if grid.rows_north else (y0 - xy[:, 1]) / grid.cell
    return (cols + 0.5, rows + 0.5) if grid.measured_from == "centre" else (cols, rows)


def _reference_cells(grid: RasterGrid, xy: np.ndarray):
    cols, rows = _reference_cell_coordinates(grid, xy)
    return np.clip(np.floor(rows), 0, grid.shape[0] - 1).astype(np.intp), np.clip(np.floor(cols), 0, grid.shape[1] - 1).astype(np.intp)


def _reference_bilinear(grid: RasterGrid, raster: np.ndarray, xy: np.ndarray) -> np.ndarray:
    cols, rows = _reference_cell_coordinates(grid, xy)
    x = np.clip(cols - 0.5, 0.0, grid.shape[1] - 1.0)  # from the first centre, the edges carried on
    y = np.clip(rows - 0.5, 0.0, grid.shape[0] - 1.0)
    c0, r0 = np.minimum(x.astype(np.intp), grid.shape[1] - 1), np.minimum(y.astype(np.intp), grid.shape[0] - 1)
    c1, r1 = np.minimum(c0 + 1, grid.shape[1] - 1), np.minimum(r0 + 1, grid.shape[0] - 1)
    tx, ty = x - c0, y - r0
    top = raster[r0, c0] * (1 - tx) + raster[r0, c1] * tx
    bottom = raster[r1, c0] * (1 - tx) + raster[r1, c1] * tx
    return top * (1 - ty) + bottom * ty


#: a 0.3 grid (its edges round: x0 + k x 0.3 falls either side of k) laid both ways
_GRIDS = {
    "over data": RasterGrid.over((619199.1, 5000000.2), (619199.1 + 0.3 * 23.5, 5000000.2 + 0.3 * 17.5), 0.3),
    "camera": RasterGrid((619199.25, 5000100.15), 0.3, (18, 24), rows_north=False, measured_from="centre"),
}


def _positions_on_edges_centres_and_beyond(grid: RasterGrid, rng) -> np.ndarray:
    """(n, 3) random positions over the grid and 3 cells beyond it, and positions whose x or y
    lies on a cell's edge or centre (the grid's outer edges among them)."""
    left, bottom, right, top = grid.bounds
    margin = 3 * grid.cell
    spread = rng.uniform((left - margin, bottom - margin), (right + margin, top + margin), (4000, 2))
    # x and y on edges and centres: the corner of cell (0, 0) plus k half cells, k from 2 cells before the grid to 2 after
    half_steps = np.arange(-4, 2 * max(grid.shape) + 5) * 0.5 * grid.cell
    x_lines, y_lines = left + half_steps, bottom + half_steps
    on_x = np.column_stack([rng.choice(x_lines, 2000), rng.uniform(bottom - margin, top + margin, 2000)])
    on_y = np.column_stack([rng.uniform(left - margin, right + margin, 2000), rng.choice(y_lines, 2000)])
    on_both = np.column_stack([rng.choice(x_lines, 2000), rng.choice(y_lines, 2000)])
    xy = np.vstack([spread, on_x, on_y, on_both])
    return np.column_stack([xy, rng.uniform(-1.0, 1.0, len(xy))])


@pytest.mark.parametrize("kind", list(_GRIDS))
def test_the_kernels_cells_and_bilinear_reads_are_the_numpy_rules_bit_for_bit(kind):
    grid = _GRIDS[kind]
    rng = np.random.default_rng(7)
    xyz = _positions_on_edges_centres_and_beyond(grid, rng)
    raster = rng.normal(100.0, 10.0, grid.shape)
    rows, cols = grid.cells_of(xyz)
    expected_rows, expected_cols = _reference_cells(grid, xyz)
    assert np.array_equal(rows, expected_rows) and np.array_equal(cols, expected_cols)
    assert {0, grid.shape[0] - 1} <= set(rows.tolist()) and {0, grid.shape[1] - 1} <= set(cols.tolist())
    assert np.array_equal(grid.bilinear(raster, xyz), _reference_bilinear(grid, raster, xyz))
    tolerance = rng.uniform(0.0, 2.0, grid.shape)
    read, of_cell = grid.bilinear_and_cell_values(raster, tolerance, xyz)
    assert np.array_equal(read, _reference_bilinear(grid, raster, xyz))
    assert np.array_equal(of_cell, tolerance[expected_rows, expected_cols])


def test_ground_classification_reads_the_model_and_the_tolerance_of_each_points_cell_as_the_numpy_rules():
    """``_classified`` on points on cell edges and beyond the grid, each within a random
    tolerance of a cell's: 2 exactly where |z - the bilinear model| is within its own cell's."""
    grid = _GRIDS["over data"]
    rng = np.random.default_rng(11)
    xyz = _positions_on_edges_centres_and_beyond(grid, rng)
    dem = rng.normal(100.0, 10.0, grid.shape)
    tolerance = rng.uniform(0.0, 2.0, grid.shape)
    xyz[:, 2] = _reference_bilinear(grid, dem, xyz) + rng.uniform(-2.0, 2.0, len(xyz))  # near some cells' tolerance, beyond others'
    classification = np.where(rng.random(len(xyz)) < 0.05, 7, 0).astype(np.uint8)  # a little noise, kept as it is
    counts = {smrf.GROUND: 0, smrf.NON_GROUND: 0, "noise": 0}
    classes = smrf._classified(PointChunk(xyz, attributes={"classification": classification}), grid, dem, tolerance, counts)[0].attributes["classification"]
    rows, cols = _reference_cells(grid, xyz)
    near = np.abs(xyz[:, 2] - _reference_bilinear(grid, dem, xyz)) <= tolerance[rows, cols]
    expected = np.where(classification == 7, 7, np.where(near, 2, 1))
    assert np.array_equal(classes, expected)
    assert counts == {2: int((expected == 2).sum()), 1: int((expected == 1).sum()), "noise": int((expected == 7).sum())}
    assert 0.3 < counts[2] / len(xyz) < 0.7  # both classes well represented: a wrong cell shows
