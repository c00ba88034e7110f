"""The raster grid the survey commands share (survey/raster_grid.py): ground/heights rasters laid
over the data (``RasterGrid.over``) and change/volume images (``RasterGrid.of_camera``), one rule
for which cell a position is in, where cells' centres lie and how values are read between them."""

from __future__ import annotations

import numpy as np

import gigapoint as gp
from gigapoint.io.polygon import clip_polygon_of
from gigapoint.render import Camera
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
