"""Ground classification (``gigapoint classify --ground``, ``gp.classify_ground``): the Simple
Morphological Filter (SMRF, Pingel, Clarke & McBride 2013), as PDAL's filters.smrf and LAStools'
lasground classify unclassified deliveries so that a DTM (``render --gsd --classes 2``) and
sections can be made of them.

It runs in bounded memory however many points there are: what it holds is a raster of the
files' extent (a float64 a cell), never the points.

1. Pass 1 streams the points (``PointFiles.valid_chunks``, as ``convert -o x.laz`` reads them)
   into the lowest z of each ``cell``-sized cell. Noise (classes 7 and 18) is left out, and so
   are the first and intermediate returns of a pulse that has several: only a pulse's last
   return can reach the ground (PDAL's ``returns="last,only"``).
2. On the raster: empty cells filled (render/raster_fill.py's ``fill_everywhere``); low
   outliers (a cell more than 5 x cell below an opening of the inverted surface, SMRF's first
   step) removed; then openings by diamonds of radius 1, 2, ... window /
   cell cells, each of the last: a cell that the opening lowers by more than slope x radius x
   cell is an object (a building, a tree). The cells neither empty, low nor object make the
   provisional DEM, filled over the others (``fill_everywhere``: a first-order pull-push, linear
   over a hole in a slope; the TIN of render's ``--fill-nodata`` took 50 s of a million cells).
3. Pass 2 streams the points again and writes them (io/write.py's ``write_points``, as
   ``convert -o`` does): class 2 where |z - DEM(x, y)| <= threshold + scalar x the DEM's slope
   (bilinear DEM, the slope of the point's cell), else 1. Noise keeps its class (7, 18: a
   user who cleaned a cloud expects it kept), first and intermediate returns become 1; every
   other attribute is written as read.

``height_above_ground`` (heights.py) measures each point against such a model: see its notes.

Lengths are in the cloud's units (io/crs.py): the defaults (cell 1 m, window 18 m, threshold
0.5 m, scalar 1.25 m per unit of slope) are converted for a cloud in feet; ``slope`` is rise over run.
The raster's grid, these parameters (``ground_parameters``) and the point passes are
ground_raster.py's, shared with noise.py and heights.py.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit

from ..errors import InputError
from ..render.raster_fill import fill_everywhere
from .ground_raster import GROUND, NOISE_CLASSES, NON_GROUND, files_grid, ground_parameters, point_files, progress_bar, write_through
from .heights import HeightSpan, heights_over
from .noise import noise_classified, noise_option, noise_parameters, sparse_cells
from .raster_grid import RasterGrid

#: SMRF's low-outlier step: an opening of the inverted surface with this slope, radius 1 cell
LOW_OUTLIER_SLOPE = 5.0


@dataclass(frozen=True)
class GroundResult:
    """What ``classify_ground`` wrote: ``points`` in ``out``, of which ``ground`` class 2,
    ``non_ground`` class 1 and ``noise`` kept as 7 or 18; ``skipped`` invalid points (NaN, inf)
    not written; ``params`` the parameters used, in the cloud's units; ``seconds`` taken."""

    out: Path
    points: int
    ground: int
    non_ground: int
    noise: int
    skipped: int
    params: dict
    seconds: float
    #: of ``noise``, the points found isolated and classified 7 (``noise=...``)
    isolated: int = 0
    #: (lowest, highest) height above ground written (``heights``), else None
    heights: tuple[float, float] | None = None

    @property
    def points_per_second(self) -> float:
        return self.points / self.seconds if self.seconds > 0 else 0.0



@njit(cache=True)
def _lowest_into(raster, rows, cols, z):  # pragma: no cover - compiled
    for i in range(z.size):
        raster[rows[i], cols[i]] = min(raster[rows[i], cols[i]], z[i])



def _ground_candidates(chunk) -> np.ndarray:
    """Which points may be ground: not noise, and a pulse's last (or only) return where the
    points tell their returns (a return number 0 or above the count: taken as a last one)."""
    attrs = chunk.attributes
    keep = np.ones(len(chunk), bool)
    if "classification" in attrs:
        keep &= ~np.isin(attrs["classification"], NOISE_CLASSES)
    if "return_number" in attrs and "number_of_returns" in attrs:
        keep &= attrs["return_number"] >= attrs["number_of_returns"]
    return keep


@njit(cache=True)
def _cross_extreme(surface: np.ndarray, lowest: bool) -> np.ndarray:  # pragma: no cover - compiled
    """One erosion (``lowest``: each cell the least of itself and its 4 neighbours) or dilation
    (the most) by a 3 x 3 cross, the raster's edge cells seeing only the neighbours they have
    (scipy.ndimage's mode="nearest"): 4 x faster than scipy's general footprint filter, which
    the 342 passes of a default opening on a million cells spent 4 s in."""
    rows, cols = surface.shape
    out = np.empty_like(surface)
    for r in range(rows):
        up, down = surface[max(r - 1, 0)], surface[min(r + 1, rows - 1)]  # (an edge's missing neighbour: the cell itself)
        row = surface[r]
        for c in range(cols):
            left, right = row[max(c - 1, 0)], row[min(c + 1, cols - 1)]
            if lowest:
                out[r, c] = min(row[c], up[c], down[c], left, right)
            else:
                out[r, c] = max(row[c], up[c], down[c], left, right)
    return out


def _opened(surface: np.ndarray, radius: int) -> np.ndarray:
    """The morphological opening of ``surface`` by a diamond of ``radius`` cells (``radius``
    erosions by a cross, then as many dilations: PDAL's structuring element)."""
    out = surface
    for _ in range(radius):
        out = _cross_extreme(out, True)
    for _ in range(radius):
        out = _cross_extreme(out, False)
    return out


def _objects(surface: np.ndarray, cell: float, slope: float, window: float) -> np.ndarray:
    """SMRF's progressive filter: the cells that an opening by a growing diamond (radius 1 to
    window / cell cells) lowers by more than slope x radius x cell below the previous opening."""
    objects = np.zeros(surface.shape, bool)
    last = surface
    # a diamond of rows + cols cells covers the raster from any cell: larger ones open it alike
    # (a window of 1e12 ran 3e11 openings: a hang)
    radii = min(max(1, math.ceil(window / cell)), sum(surface.shape))
    for radius in range(1, radii + 1):
        opened = _opened(last, radius)
        objects |= last - opened > slope * radius * cell
        last = opened
    return objects


def ground_model(lowest: np.ndarray, cell: float, slope: float, window: float) -> np.ndarray:
    """The provisional DEM of a raster of lowest z (NaN: no point): low outliers and objects
    left out, then every cell filled from the rest (render/raster_fill.py's ``fill_everywhere``,
    as are the surfaces the openings run on: 0.4 s a fill of a million cells, where the TIN
    took 12-50 s)."""
    surface = fill_everywhere(lowest)
    low = _objects(-surface, cell, LOW_OUTLIER_SLOPE, 1.0)  # (a cell pitted below its neighbours: a multipath return)
    surface = fill_everywhere(np.where(low | np.isnan(lowest), np.nan, lowest))
    objects = _objects(surface, cell, slope, window)
    dem = np.where(objects | low | np.isnan(lowest), np.nan, lowest)
    if np.isnan(dem).all():  # (every cell an object: nothing to interpolate from; the lowest surface stands)
        return surface
    return fill_everywhere(dem)


def classify_ground(source, out, *, cell=None, slope=None, window=None, threshold=None, scalar=None, overwrite: bool = False,
                    chunk_size: int | None = None, progress: bool = False, noise: dict | bool | None = None, heights: bool = False, normalize: bool = False) -> GroundResult:  # fmt: skip
    """Classify the points of ``source`` (files, folders or patterns, as ``gp.open`` takes them)
    as ground (2) or not (1) by SMRF, and write them all to ``out`` (.las, .laz or .ply), every
    other attribute as read; noise (7, 18) keeps its class. Two passes over the files, memory
    bounded by the raster (see the module's notes). Parameters in the cloud's units, None: the
    defaults converted from metres (``ground_parameters``). ``out`` appears only once whole; an
    existing one is replaced only with ``overwrite``. ``noise``: classify_noise's parameters
    (a dict of step, step_z, isolated; True: its defaults) to classify isolated points 7 first, in a pass of its own, and
    keep them out of the ground. ``heights``: each point's height above
    the ground model just made written too (``height_above_ground``'s attribute; ``normalize``:
    as its z as well)."""
    t0 = time.perf_counter()
    noise = noise_option(noise, "classify_ground")
    out, inputs = point_files(source, out, chunk_size, "classify_ground", overwrite=overwrite, progress=progress, heights=heights, normalize=normalize)
    params = ground_parameters(inputs.files, cell, slope, window, threshold, scalar)
    noise_params = noise_parameters(inputs.files, **noise) if noise is not None else None
    shown = progress_bar(progress)
    try:
        # Noise found first (a pass of its own) is marked 7 in each chunk both later passes read,
        # so that the ground raster leaves it out and the output keeps it 7.
        cells = sparse_cells(inputs, noise_params, shown) if noise_params is not None else None
        found = {"noise": 0, "kept": 0}  # counted in the points written
        found_again = {"noise": 0, "kept": 0}  # the same points, read for the raster: not counted

        def noise_marked(chunk, counts):
            return chunk if cells is None else noise_classified(chunk, cells, counts)

        grid, lowest = _lowest_raster(inputs, params["cell"], shown, lambda chunk: noise_marked(chunk, found_again))
        dem = ground_model(lowest, params["cell"], params["slope"], params["window"])
        rise_y, rise_x = np.gradient(np.pad(dem, 1, mode="edge"), params["cell"])
        tolerance = params["threshold"] + params["scalar"] * np.hypot(rise_x, rise_y)[1:-1, 1:-1]
        counts = {GROUND: 0, NON_GROUND: 0, "noise": 0}
        tally: dict = {}
        span = HeightSpan()

        def classified(chunk):
            chunk, model = _classified(noise_marked(chunk, found), grid, dem, tolerance, counts)
            return heights_over(chunk, model, normalize, span) if heights or normalize else chunk  # (the dem read once a point)

        written = write_through(inputs, out, "classify", classified, shown, tally)
    finally:
        shown.close()
    if noise_params is not None:
        params = {**params, **{k: v for k, v in noise_params.items() if k not in ("units", "height_units")}}
    return GroundResult(out, written, counts[GROUND], counts[NON_GROUND], counts["noise"], tally["skipped"], params, time.perf_counter() - t0,
                        found["noise"], span.range())


def _lowest_raster(inputs, cell: float, progress, noise_marked) -> tuple[RasterGrid, np.ndarray]:
    """Pass 1: the grid over the files' extent (their headers' bounds; a pass of its own where
    one tells none) and the lowest z of the ground candidates in each of its cells (NaN: none),
    each chunk read as ``noise_marked`` gives it back (the noise found first classified 7).
    Fewer than 3 cells with points is a one-line InputError: no surface to make."""
    grid = files_grid(inputs, cell, progress)
    tally: dict = {}
    lowest = np.full(grid.shape, np.inf)
    progress.phase("raster", None if None in inputs.counts else sum(inputs.counts))
    for _, chunk in inputs.valid_chunks(None, progress, tally):
        chunk = noise_marked(chunk)
        keep = _ground_candidates(chunk)
        xyz = chunk.xyz[keep]
        rows, cols = grid.cells_of(xyz)
        _lowest_into(lowest, rows, cols, np.ascontiguousarray(xyz[:, 2]))
    occupied = int(np.isfinite(lowest).sum())
    if occupied < 3:
        raise InputError(
            f"{inputs.label}: {tally['points']:,} point{'s' if tally['points'] != 1 else ''} in {occupied} cell{'s' if occupied != 1 else ''} of {cell:g}: "
            "a ground surface needs points (last returns, not noise) in 3 cells at least"
        )
    return grid, np.where(np.isfinite(lowest), lowest, np.nan)


def _classified(chunk, grid: RasterGrid, dem: np.ndarray, tolerance: np.ndarray, counts: dict):
    """(``chunk`` with its classification set: 2 where a ground candidate lies within its cell's
    ``tolerance`` of the ``dem``, 1 for every other point but noise, which keeps its class; the
    ``dem`` read at its points, for their heights above ground)."""
    from ..core.chunk import PointChunk

    old = chunk.attributes.get("classification")
    noise = np.isin(old, NOISE_CLASSES) if old is not None else np.zeros(len(chunk), bool)
    model, allowed = grid.bilinear_and_cell_values(dem, tolerance, chunk.xyz)
    near = np.abs(chunk.xyz[:, 2] - model) <= allowed
    ground = near & _ground_candidates(chunk)
    classes = np.where(noise, old if old is not None else 0, np.where(ground, GROUND, NON_GROUND))
    counts[GROUND] += int(ground.sum())
    counts["noise"] += int(noise.sum())
    counts[NON_GROUND] += len(chunk) - int(ground.sum()) - int(noise.sum())
    attributes = dict(chunk.attributes)
    attributes["classification"] = classes.astype(old.dtype if old is not None else np.uint8)
    return PointChunk(chunk.xyz, chunk.rgba, attributes, scale=chunk.scale, color_bits=chunk.color_bits), model
