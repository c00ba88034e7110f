"""The raster grid the survey commands share: square cells over the ground, a ground sample
distance a side. The ground and heights rasters (ground_raster.py: ``RasterGrid.over``) and
the top-down images of change and volume (``RasterGrid.of_camera``) lay theirs by its rules:

* A position's *cell coordinates* are how many cells it lies from the outer corner of cell
  (0, 0), along the columns (east) and along the rows (north, or south: ``rows_north``). Its
  cell is their floor: a point on an edge belongs to the cell after it (to the east; to the
  north or the south as the rows run). A position beyond the grid is in its edge cell.
* A cell's centre lies half a cell on from its corner; a value of a cell is its centre's
  (``bilinear`` reads between them).
* Positions are measured from ``origin``, the point the grid was given by: the corner of cell
  (0, 0) for a grid laid over data (``measured_from="corner"``: its lowest x and y), its centre
  for a camera's image (``"centre"``: a world file's numbers). Never from a point made from it by
  adding or taking half a cell: that rounds, and a point on an edge then falls on its other side
  (a toe's vertex at x 619338.6 on a 0.3 grid whose first centre is at 619199.25: column 464
  measured from that centre, 465 from the corner 619199.1), as it does at many edges of a cell
  that is no power of two (0.1, 0.3); measured otherwise, results would change.

The two grids differ in essentials kept as named parameters: ``rows_north`` (a raster over data
counts its rows northwards, as numpy's y does; an image southwards, its top row first, as the
rasterizer and a GeoTIFF do) and ``measured_from``; and in where their edges lie: ``over`` starts
at the data's lowest x and y (its edges on no common grid), ``Camera.top_down`` at whole
multiples of the gsd beyond the data (tiles line up)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numba import njit

from ..errors import count_or_inf


@dataclass(frozen=True)
class RasterGrid:
    """``shape`` (rows, columns) cells ``cell`` a side; ``origin`` (x, y) the corner or the centre
    (``measured_from``) of cell (0, 0), which lies at the south-west of the grid where
    ``rows_north``, at its north-west otherwise. The rules: this module's notes."""

    origin: tuple[float, float]
    cell: float
    shape: tuple[int, int]
    rows_north: bool
    measured_from: Literal["corner", "centre"]

    @classmethod
    def over(cls, lo, hi, cell: float) -> RasterGrid:
        """The grid over the box ``lo``..``hi`` (x, y, ...) from its lowest corner, rows northwards:
        floor(extent / cell) + 1 cells each way, so that its highest x and y lie inside the last
        (math.inf where a tiny cell overflows the division: the caller refuses it as too many)."""
        shape = tuple(count_or_inf(lambda low=low, h=h: math.floor((h - low) / cell) + 1) for low, h in zip(lo[1::-1], hi[1::-1]))  # (rows: y, columns: x)
        return cls((lo[0], lo[1]), cell, shape, rows_north=True, measured_from="corner")

    @classmethod
    def of_camera(cls, camera) -> RasterGrid:
        """The pixels of a ``Camera.top_down`` image: rows southwards (its top row first),
        measured from its world file's centre of the upper-left pixel."""
        size, _, _, _, x0, y0 = camera.world_file()
        return cls((x0, y0), size, (camera.height, camera.width), rows_north=False, measured_from="centre")

    @property
    def cells(self) -> int:
        return self.shape[0] * self.shape[1]

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(left, bottom, right, top): the outer edges of the edge cells."""
        half = 0.5 * self.cell if self.measured_from == "centre" else 0.0  # from the origin out to cell (0, 0)'s corner
        rows, cols = self.shape
        left = self.origin[0] - half
        if self.rows_north:
            bottom = self.origin[1] - half
            return left, bottom, left + cols * self.cell, bottom + rows * self.cell
        top = self.origin[1] + half
        return left, top - rows * self.cell, left + cols * self.cell, top

    def cells_of(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(rows, columns) of the cells holding the (n, 2+) positions ``xy`` (an edge's points in
        the cell after it; positions beyond the grid in its edge cells)."""
        return _cells(np.asarray(xy, np.float64), self.shape[0], self.shape[1], *self._kernel_grid())

    def centres(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(n, 2) x, y of the centres of the cells (``rows``, ``cols``)."""
        on = 0.0 if self.measured_from == "centre" else 0.5  # cells from the origin to the first centre
        x0, y0 = self.origin
        along = (rows + on) * self.cell
        return np.column_stack([x0 + (cols + on) * self.cell, y0 + along if self.rows_north else y0 - along])

    def bilinear(self, raster: np.ndarray, xy: np.ndarray) -> np.ndarray:
        """``raster`` (this grid's shape; values at the cells' centres) at the (n, 2+) positions
        ``xy``, bilinearly; the edge cells' values carried half a cell beyond them."""
        return _bilinear(raster, np.asarray(xy, np.float64), *self._kernel_grid())

    def bilinear_and_cell_values(self, raster: np.ndarray, cell_values: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(``bilinear(raster, xy)``, ``cell_values`` (this grid's shape) of the cells holding
        ``xy``, as ``cells_of`` finds them): each position's cell coordinates computed once."""
        return _bilinear_and_cell_values(raster, cell_values, np.asarray(xy, np.float64), *self._kernel_grid())

    def _kernel_grid(self) -> tuple:
        """The grid as the kernels take it after their arrays: ``_cell_coordinates``' numbers."""
        row_sign = 1.0 if self.rows_north else -1.0
        from_origin = 0.5 if self.measured_from == "centre" else 0.0
        return float(self.origin[0]), float(self.origin[1]), float(self.cell), row_sign, from_origin

    def centres_inside(self, polygon) -> np.ndarray:
        """(rows, columns) bool: the cells whose centre lies inside ``polygon`` (an io ClipPolygon;
        only the cells of its box are tested)."""
        corner_rows, corner_cols = self.cells_of(np.array([polygon.lo, polygon.hi]))
        rows, cols = np.mgrid[corner_rows.min() : corner_rows.max() + 1, corner_cols.min() : corner_cols.max() + 1]
        mask = np.zeros(self.shape, bool)
        mask[rows, cols] = polygon.inside(self.centres(rows.ravel(), cols.ravel())).reshape(rows.shape)
        return mask


# The kernels take the grid as ``RasterGrid._kernel_grid`` gives it, and find a position's cell
# coordinates by ``_cell_coordinates`` alone (computed in numpy beforehand, four temporary arrays
# took 2 M points' bilinear read in scan order from ~35 ms to ~48 ms: bench_raster_grid.py).


@njit(inline="always")
def _cell_coordinates(x, y, x0, y0, cell, row_sign, from_origin):  # pragma: no cover - compiled
    """(columns, rows): how many cells (``x``, ``y``) lies from the outer corner of cell (0, 0),
    along the columns and the rows (the module's one convention), for the grid that
    ``RasterGrid._kernel_grid`` gives: ``row_sign`` -1 where the rows run south ((y - y0) / cell
    negated is (y0 - y) / cell exactly), ``from_origin`` the cells from that corner to the origin
    (0.5 from a centre, 0 from the corner: adding 0 changes nothing). Numbers, not flags: a
    branch on flags here made the bilinear read 1.5-2 x slower."""
    return (x - x0) / cell + from_origin, (y - y0) / cell * row_sign + from_origin


@njit(inline="always")
def _cell_of(col, row, rows, cols):  # pragma: no cover - compiled
    """(row, column) of the cell at cell coordinates (``col``, ``row``) in a grid of ``rows`` x
    ``cols``: their floor (an edge in the cell after it), beyond the grid its edge cell."""
    return int(min(max(np.floor(row), 0.0), rows - 1.0)), int(min(max(np.floor(col), 0.0), cols - 1.0))


@njit(inline="always")
def _bilinear_at(raster, col, row):  # pragma: no cover - compiled
    """``raster`` (values at the cells' centres) read bilinearly at cell coordinates (``col``,
    ``row``), the edge cells' values carried on beyond them (numpy's version padded the raster
    and gathered four arrays of corners per chunk: 3 s of 10 M points)."""
    rows, cols = raster.shape
    x = min(max(col - 0.5, 0.0), cols - 1.0)  # in cells from the first centre, clamped: the edges carried on
    y = min(max(row - 0.5, 0.0), rows - 1.0)
    c0, r0 = min(int(x), cols - 1), min(int(y), rows - 1)
    c1, r1 = min(c0 + 1, cols - 1), min(r0 + 1, rows - 1)
    tx, ty = x - c0, y - r0
    top = raster[r0, c0] * (1 - tx) + raster[r0, c1] * tx
    bottom = raster[r1, c0] * (1 - tx) + raster[r1, c1] * tx
    return top * (1 - ty) + bottom * ty


@njit(cache=True)
def _cells(xy, rows, cols, x0, y0, cell, row_sign, from_origin):  # pragma: no cover - compiled
    """``RasterGrid.cells_of`` a point at a time."""
    n = xy.shape[0]
    found_rows, found_cols = np.empty(n, np.intp), np.empty(n, np.intp)
    for i in range(n):
        col, row = _cell_coordinates(xy[i, 0], xy[i, 1], x0, y0, cell, row_sign, from_origin)
        found_rows[i], found_cols[i] = _cell_of(col, row, rows, cols)
    return found_rows, found_cols


@njit(cache=True)
def _bilinear(raster, xy, x0, y0, cell, row_sign, from_origin):  # pragma: no cover - compiled
    """``RasterGrid.bilinear`` a point at a time."""
    out = np.empty(xy.shape[0])
    for i in range(xy.shape[0]):
        col, row = _cell_coordinates(xy[i, 0], xy[i, 1], x0, y0, cell, row_sign, from_origin)
        out[i] = _bilinear_at(raster, col, row)
    return out


@njit(cache=True)
def _bilinear_and_cell_values(raster, cell_values, xy, x0, y0, cell, row_sign, from_origin):  # pragma: no cover - compiled
    """``RasterGrid.bilinear_and_cell_values`` a point at a time."""
    rows, cols = cell_values.shape
    read, of_cell = np.empty(xy.shape[0]), np.empty(xy.shape[0], cell_values.dtype)
    for i in range(xy.shape[0]):
        col, row = _cell_coordinates(xy[i, 0], xy[i, 1], x0, y0, cell, row_sign, from_origin)
        read[i] = _bilinear_at(raster, col, row)
        of_cell[i] = cell_values[_cell_of(col, row, rows, cols)]
    return read, of_cell
