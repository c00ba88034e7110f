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

``height_above_ground`` (at the end) measures each point against such a model: see its notes.

Lengths are in the cloud's units (io/crs.py): the defaults (cell 1 m, window 18 m, threshold
0.5 m, scalar 1.25 m per unit of slope) are converted for a cloud in feet; ``slope`` is rise over run.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit

from ..errors import InputError, is_real
from ..render.raster_fill import fill_everywhere

#: PDAL's and the paper's defaults, in metres (``slope``: rise over run, no unit)
DEFAULTS_METRES = {"cell": 1.0, "window": 18.0, "threshold": 0.5, "scalar": 1.25}
DEFAULT_SLOPE = 0.15
#: the classes a ground classification keeps as they are: low and high noise
NOISE_CLASSES = (7, 18)
GROUND, NON_GROUND = 2, 1
#: the most cells the raster may have (several float64 arrays of it are held at once: ~1 GB each at this size)
MAX_CELLS = 120_000_000
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


def ground_parameters(files, cell=None, slope=None, window=None, threshold=None, scalar=None) -> dict:
    """The SMRF parameters in the units of ``files``' CRS: those given as they are, the others
    the defaults converted from metres (a cloud in feet: cell 3.28 ft...; units unknown: taken
    as metres). A value that is no number > 0 (threshold, scalar: >= 0), or coordinates in
    degrees without every length given, is a one-line InputError."""
    from ..io.crs import files_units

    given = {"cell": cell, "slope": slope, "window": window, "threshold": threshold, "scalar": scalar}
    for name, value in given.items():
        least = "> 0" if name in ("cell", "slope", "window") else ">= 0"
        if value is not None and not (is_real(value) and (value > 0 if least == "> 0" else value >= 0)):
            raise InputError(f"classify_ground: {name} must be a number {least}, got {value!r}")
    units = files_units(files)
    across, up = units["horizontal"], units["vertical"]
    if across is not None and across["metres"] is None and any(given[n] is None for n in ("cell", "window")):
        raise InputError(f"classify_ground: the coordinates are in {across['name']}s, not lengths: give cell and window in them, or reproject the cloud")
    per_metre_across = 1.0 / across["metres"] if across is not None and across["metres"] else 1.0
    per_metre_up = 1.0 / up["metres"] if up is not None and up["metres"] else 1.0
    params = {
        "cell": DEFAULTS_METRES["cell"] * per_metre_across if cell is None else float(cell),
        "slope": DEFAULT_SLOPE if slope is None else float(slope),
        "window": DEFAULTS_METRES["window"] * per_metre_across if window is None else float(window),
        "threshold": DEFAULTS_METRES["threshold"] * per_metre_up if threshold is None else float(threshold),
        "scalar": DEFAULTS_METRES["scalar"] * per_metre_up if scalar is None else float(scalar),
    }
    params["units"] = across["symbol"] if across is not None else "m (assumed)"
    return params


@njit(cache=True)
def _lowest_into(raster, rows, cols, z):  # pragma: no cover - compiled
    for i in range(z.size):
        raster[rows[i], cols[i]] = min(raster[rows[i], cols[i]], z[i])


class _Grid:
    """The raster's cells: ``cell`` units a side from ``lo`` (x, y), ``shape`` (rows, columns)."""

    def __init__(self, lo, hi, cell: float, label: str):
        self.lo, self.cell = np.asarray(lo[:2], np.float64), cell
        self.shape = tuple(math.floor((h - low) / cell) + 1 for low, h in zip(lo[1::-1], hi[1::-1]))  # (rows: y, columns: x)
        if self.shape[0] * self.shape[1] > MAX_CELLS:
            raise InputError(
                f"{label}: cells of {cell:g} make a {self.shape[1]:,} x {self.shape[0]:,} raster over the files' extent, more than "
                f"{MAX_CELLS:,} cells: give a larger cell, or classify tiles of it (gigapoint tile)"
            )

    def cells_of(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(row, column) of each point's cell; points beyond the extent (a stale header's) in the edge cells."""
        cols = np.clip(np.floor((xyz[:, 0] - self.lo[0]) / self.cell), 0, self.shape[1] - 1).astype(np.intp)
        rows = np.clip(np.floor((xyz[:, 1] - self.lo[1]) / self.cell), 0, self.shape[0] - 1).astype(np.intp)
        return rows, cols

    def bilinear(self, raster: np.ndarray, xyz: np.ndarray) -> np.ndarray:
        """``raster`` (values at the cells' centres) at the points' (x, y), bilinearly; the edge
        cells' values carried half a cell beyond them."""
        return _bilinear(raster, np.ascontiguousarray(xyz[:, 0]), np.ascontiguousarray(xyz[:, 1]), self.lo[0], self.lo[1], self.cell)


@njit(cache=True)
def _bilinear(raster, x, y, x0, y0, cell):  # pragma: no cover - compiled
    """``Grid.bilinear`` a point at a time (numpy's version padded the raster and gathered four
    arrays of corners per chunk: 3 s of 10 M points)."""
    rows, cols = raster.shape
    out = np.empty(x.size)
    for i in range(x.size):
        fx = min(max((x[i] - x0) / cell - 0.5, 0.0), cols - 1.0)  # in cells from the first centre, clamped: the edges carried on
        fy = min(max((y[i] - y0) / cell - 0.5, 0.0), rows - 1.0)
        c0, r0 = min(int(fx), cols - 1), min(int(fy), rows - 1)
        c1, r1 = min(c0 + 1, cols - 1), min(r0 + 1, rows - 1)
        tx, ty = fx - c0, fy - r0
        top = raster[r0, c0] * (1 - tx) + raster[r0, c1] * tx
        bottom = raster[r1, c0] * (1 - tx) + raster[r1, c1] * tx
        out[i] = top * (1 - ty) + bottom * ty
    return out


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
    for radius in range(1, max(1, math.ceil(window / cell)) + 1):
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


def _point_files(source, out, overwrite: bool, chunk_size: int | None, where: str):
    """(``out`` as a Path, the PointFiles of ``source`` it is written from) for a classification
    that writes every point of its inputs again: ``out`` a .las, .laz or .ply file not there
    yet (or ``overwrite``), checked before a point is read (one-line errors starting ``where``)."""
    from ..io.write import check_point_file_output
    from ..lod.convert.to_file import PointFiles

    out = Path(out)
    if out.suffix.lower() not in (".las", ".laz", ".ply"):
        raise InputError(f"{out}: {where} writes a .las, .laz or .ply file")
    check_point_file_output(out, overwrite)
    return out, PointFiles(source, out, chunk_size, ply=out.suffix.lower() == ".ply")


def _progress(shown: bool):
    """The progress bar of a classification's passes (rich), or none."""
    from ..lod.progress import NullProgress, RichProgress

    return RichProgress() if shown else NullProgress()


def _write_through(inputs, out: Path, phase: str, each, progress, tally: dict) -> int:
    """The last pass of a classification: every valid chunk of ``inputs`` as ``each`` gives it
    back, written to ``out`` on the inputs' LAS grid, with their CRS and colours (none where
    none of them has any); the points written."""
    from ..io.write import write_points

    def chunks():
        progress.phase(phase, None if None in inputs.counts else sum(inputs.counts))
        for _, chunk in inputs.valid_chunks(None, progress, tally):
            yield each(chunk)

    return write_points(out, chunks, None, grid=inputs.las_grid, crs_records=inputs.crs_records, color_bits=None, has_color=inputs.has_color)


def classify_ground(source, out, *, cell=None, slope=None, window=None, threshold=None, scalar=None, overwrite: bool = False,
                    chunk_size: int | None = None, progress: bool = False, noise: dict | bool | None = None, heights: bool = False, normalize: bool = False) -> GroundResult:  # fmt: skip
    """Classify the points of ``source`` (files, folders or patterns, as ``gp.open`` takes them)
    as ground (2) or not (1) by SMRF, and write them all to ``out`` (.las, .laz or .ply), every
    other attribute as read; noise (7, 18) keeps its class. Two passes over the files, memory
    bounded by the raster (see the module's notes). Parameters in the cloud's units, None: the
    defaults converted from metres (``ground_parameters``). ``out`` appears only once whole; an
    existing one is replaced only with ``overwrite``. ``noise``: classify_noise's parameters
    (a dict; True: its defaults) to classify isolated points 7 first, in a pass of its own, and
    keep them out of the ground. ``heights``: each point's height above
    the ground model just made written too (``height_above_ground``'s attribute; ``normalize``:
    as its z as well)."""
    t0 = time.perf_counter()
    out, inputs = _point_files(source, out, overwrite, chunk_size, "classify_ground")
    params = ground_parameters(inputs.files, cell, slope, window, threshold, scalar)
    noise_params = noise_parameters(inputs.files, **({} if noise is True else noise)) if noise else None
    shown = _progress(progress)
    try:
        if noise_params is not None:
            inputs = _NoiseFound(inputs, _sparse_cells(inputs, noise_params, shown))
        grid, lowest = _lowest_raster(inputs, params["cell"], shown)
        dem = ground_model(lowest, params["cell"], params["slope"], params["window"])
        rise_y, rise_x = np.gradient(np.pad(dem, 1, mode="edge"), params["cell"])
        tolerance = params["threshold"] + params["scalar"] * np.hypot(rise_x, rise_y)[1:-1, 1:-1]
        counts = {GROUND: 0, NON_GROUND: 0, "noise": 0}
        tally: dict = {}
        span = _HeightSpan()

        def classified(chunk):
            chunk = _classified(chunk, grid, dem, tolerance, counts)
            return _with_heights(chunk, grid, dem, normalize, span) if heights or normalize else chunk

        written = _write_through(inputs, out, "classify", classified, shown, tally)
    finally:
        shown.close()
    if noise_params is not None:
        params = {**params, **{k: v for k, v in noise_params.items() if k != "units"}}
    isolated = inputs.counts_found["noise"] if noise_params is not None else 0
    return GroundResult(out, written, counts[GROUND], counts[NON_GROUND], counts["noise"], tally["skipped"], params, time.perf_counter() - t0, isolated, span.range())


def _files_grid(inputs, cell: float, progress) -> _Grid:
    """The grid over the files' extent: their headers' bounds, or a pass of its own where one tells none."""
    bounds = inputs.headers_bounds()
    if bounds is None:
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        for _, chunk in inputs.valid_chunks(None, progress, {}):
            lo, hi = np.minimum(lo, chunk.xyz.min(axis=0)), np.maximum(hi, chunk.xyz.max(axis=0))
        bounds = (lo, hi)
    return _Grid(bounds[0], bounds[1], cell, inputs.label)


def _lowest_raster(inputs, cell: float, progress) -> tuple[_Grid, np.ndarray]:
    """Pass 1: the grid over the files' extent (their headers' bounds; a pass of its own where
    one tells none) and the lowest z of the ground candidates in each of its cells (NaN: none).
    Fewer than 3 cells with points is a one-line InputError: no surface to make."""
    grid = _files_grid(inputs, cell, progress)
    tally: dict = {}
    lowest = np.full(grid.shape, np.inf)
    progress.phase("raster", None if None in inputs.counts else sum(inputs.counts))
    for _, chunk in inputs.valid_chunks(None, progress, tally):
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


def _classified(chunk, grid: _Grid, dem: np.ndarray, tolerance: np.ndarray, counts: dict):
    """``chunk`` with its classification set: 2 where a ground candidate lies within its cell's
    ``tolerance`` of the ``dem``, 1 for every other point but noise, which keeps its class."""
    from ..core.chunk import PointChunk

    old = chunk.attributes.get("classification")
    noise = np.isin(old, NOISE_CLASSES) if old is not None else np.zeros(len(chunk), bool)
    rows, cols = grid.cells_of(chunk.xyz)
    near = np.abs(chunk.xyz[:, 2] - grid.bilinear(dem, chunk.xyz)) <= tolerance[rows, cols]
    ground = near & _ground_candidates(chunk)
    classes = np.where(noise, old if old is not None else 0, np.where(ground, GROUND, NON_GROUND))
    counts[GROUND] += int(ground.sum())
    counts["noise"] += int(noise.sum())
    counts[NON_GROUND] += len(chunk) - int(ground.sum()) - int(noise.sum())
    attributes = dict(chunk.attributes)
    attributes["classification"] = classes.astype(old.dtype if old is not None else np.uint8)
    return PointChunk(chunk.xyz, chunk.rgba, attributes, scale=chunk.scale, color_bits=chunk.color_bits)


# Noise classification (``gigapoint classify --noise``, ``gp.classify_noise``): isolated points
# (birds, multipath returns, sensor spikes far above or below the surface) classified 7, low
# noise, as LAStools' lasnoise does (PDAL's filters.outlier, radius method, by cells instead of a
# radius). Pass 1 counts the points of each occupied cell of step x step x step_z (io/cells.py's
# hash table: 16-32 bytes an occupied cell, never the points); a cell whose 3 x 3 x 3 block of
# cells (itself in the middle) holds at most isolated + 1 points is sparse. Pass 2 writes every
# point, class 7 where it lies in a sparse cell (at most `isolated` other points in its 27
# cells). The cells are anchored at 0, as thinning's are, so tiles classified separately line up
# (a point near a tile's edge has neighbours in the next tile: classify buffered tiles).
# With classify_ground(noise=...), the noise is found first (a pass of its own) and kept out of
# the ground raster as the noise classes always are.

#: lasnoise's defaults: cells of 4 m each way; a point with at most 5 others in its 27 cells is noise
NOISE_STEP_METRES = 4.0
DEFAULT_ISOLATED = 5
LOW_NOISE = 7


@dataclass(frozen=True)
class NoiseResult:
    """What ``classify_noise`` wrote: ``points`` in ``out``, of which ``noise`` found isolated
    and classified 7, ``kept_noise`` classified 7 or 18 already (kept); every other point's class
    as read. ``skipped`` invalid points not written; ``cells`` the occupied cells counted, in a
    table of ``table_bytes``; ``params`` the parameters used, in the cloud's units; ``seconds`` taken."""

    out: Path
    points: int
    noise: int
    kept_noise: int
    skipped: int
    cells: int
    table_bytes: int
    params: dict
    seconds: float

    @property
    def points_per_second(self) -> float:
        return self.points / self.seconds if self.seconds > 0 else 0.0


def noise_parameters(files, step=None, step_z=None, isolated=None) -> dict:
    """The noise parameters in the units of ``files``' CRS: ``step`` (the cells' horizontal
    edge) as given, else 4 m converted; ``step_z`` (their height) as given, else as long as
    ``step`` in the vertical units; ``isolated`` (the most other points an isolated point has in
    its 27 cells) as given, else 5. A step that is no number > 0, an isolated that is no whole
    number >= 0, or coordinates in degrees without both steps given, is a one-line InputError."""
    import numbers

    from ..io.crs import files_units

    for name, value in (("step", step), ("step_z", step_z)):
        if value is not None and not (is_real(value) and value > 0):
            raise InputError(f"classify_noise: {name} must be a number > 0, got {value!r}")
    if isolated is not None and not (isinstance(isolated, numbers.Integral) and not isinstance(isolated, bool) and isolated >= 0):
        raise InputError(f"classify_noise: isolated must be a whole number >= 0, got {isolated!r}")
    units = files_units(files)
    across, up = units["horizontal"], units["vertical"]
    if across is not None and across["metres"] is None and (step is None or step_z is None):
        raise InputError(f"classify_noise: the coordinates are in {across['name']}s, not lengths: give step and step_z, or reproject the cloud")
    metres_across = across["metres"] if across is not None and across["metres"] else 1.0
    metres_up = up["metres"] if up is not None and up["metres"] else 1.0
    step = NOISE_STEP_METRES / metres_across if step is None else float(step)
    return {
        "step": step,
        "step_z": step * metres_across / metres_up if step_z is None else float(step_z),
        "isolated": DEFAULT_ISOLATED if isolated is None else int(isolated),
        "units": across["symbol"] if across is not None else "m (assumed)",
    }


def classify_noise(source, out, *, step=None, step_z=None, isolated=None, overwrite: bool = False,
                   chunk_size: int | None = None, progress: bool = False) -> NoiseResult:  # fmt: skip
    """Classify the isolated points of ``source`` (files, folders or patterns, as ``gp.open``
    takes them) as noise (7), as lasnoise does, and write them all to ``out`` (.las, .laz or
    .ply), every other point's class and every attribute as read. Two passes over the files,
    memory bounded by the occupied cells (see the notes above). Parameters in the cloud's units,
    None: the defaults (``noise_parameters``). ``out`` appears only once whole; an existing one
    is replaced only with ``overwrite``."""
    t0 = time.perf_counter()
    out, inputs = _point_files(source, out, overwrite, chunk_size, "classify_noise")
    params = noise_parameters(inputs.files, step, step_z, isolated)
    shown = _progress(progress)
    try:
        cells = _sparse_cells(inputs, params, shown)
        counts = {"noise": 0, "kept": 0}
        tally: dict = {}
        written = _write_through(inputs, out, "classify", lambda chunk: _noise_classified(chunk, cells, counts), shown, tally)
    finally:
        shown.close()
    return NoiseResult(out, written, counts["noise"], counts["kept"], tally["skipped"], cells.cells, cells.nbytes, params, time.perf_counter() - t0)


def _sparse_cells(inputs, params: dict, progress):
    """Pass 1: every valid point counted in its cell, the cells with at most ``isolated`` + 1
    points in their 3 x 3 x 3 block marked (io/cells.py's CellCounts)."""
    from ..io.cells import CellCounts

    edges = (params["step"], params["step"], params["step_z"])
    cells = CellCounts(edges, f"classify_noise: step {params['step']:g}", inputs.headers_bounds(), inputs.label)
    progress.phase("count", None if None in inputs.counts else sum(inputs.counts))
    for f, chunk in inputs.valid_chunks(None, progress, {}):
        cells.add(chunk.xyz, f)
    cells.mark_sparse(params["isolated"] + 1)
    return cells


def _noise_classified(chunk, cells, counts: dict):
    """``chunk`` with its points in sparse cells classified 7, but those classified noise (7,
    18) already, which keep their class, as every other point does."""
    from ..core.chunk import PointChunk

    old = chunk.attributes.get("classification")
    was_noise = np.isin(old, NOISE_CLASSES) if old is not None else np.zeros(len(chunk), bool)
    found = cells.in_sparse_cells(chunk.xyz) & ~was_noise
    counts["noise"] += int(found.sum())
    counts["kept"] += int(was_noise.sum())
    attributes = dict(chunk.attributes)
    attributes["classification"] = np.where(found, LOW_NOISE, old if old is not None else 0).astype(old.dtype if old is not None else np.uint8)
    return PointChunk(chunk.xyz, chunk.rgba, attributes, scale=chunk.scale, color_bits=chunk.color_bits)


class _NoiseFound:
    """``inputs`` (a PointFiles) read with the points of the sparse ``cells`` classified 7
    (``_noise_classified``): what classify_ground's passes read when it finds noise first, so
    that the ground raster leaves them out and the output keeps them 7. ``counts_found``: of
    the last pass read."""

    def __init__(self, inputs, cells):
        self.inputs, self.cells = inputs, cells
        self.files, self.label, self.counts = inputs.files, inputs.label, inputs.counts
        self.las_grid, self.crs_records, self.has_color = inputs.las_grid, inputs.crs_records, inputs.has_color
        self.counts_found = {"noise": 0, "kept": 0}

    def headers_bounds(self):
        return self.inputs.headers_bounds()

    def valid_chunks(self, keep, progress, tally: dict):
        self.counts_found = {"noise": 0, "kept": 0}
        for f, chunk in self.inputs.valid_chunks(keep, progress, tally):
            yield f, _noise_classified(chunk, self.cells, self.counts_found)


# --- Height above ground (``gigapoint classify --height-above-ground``, ``gp.height_above_ground``):
# PDAL's filters.hag_dem, LAStools' lasheight. The ground model is a raster of the files' extent,
# as SMRF's: the mean z of the class-2 points in each cell (pass 1), its empty cells (buildings,
# water) filled by ``fill_everywhere``; pass 2 writes each point's z minus the model read
# bilinearly at its (x, y). With ``classify_ground(heights=True)`` the model is SMRF's, just made.

#: the extra-bytes dimension the heights are written to (PDAL's name for them)
HEIGHT_ATTRIBUTE = "HeightAboveGround"


@dataclass(frozen=True)
class HeightResult:
    """What ``height_above_ground`` wrote: ``points`` in ``out`` with their heights above the
    ground model, the ``heights`` (lowest, highest) among them; ``ground`` the class-2 points the
    model was made of; ``skipped`` invalid points not written; ``params`` the cell and units;
    ``seconds`` taken."""

    out: Path
    points: int
    ground: int
    heights: tuple[float, float]
    skipped: int
    params: dict
    seconds: float

    @property
    def points_per_second(self) -> float:
        return self.points / self.seconds if self.seconds > 0 else 0.0


class _HeightSpan:
    """The lowest and highest height above ground written so far."""

    def __init__(self):
        self.lowest, self.highest = math.inf, -math.inf

    def add(self, heights: np.ndarray) -> None:
        if heights.size:
            self.lowest, self.highest = min(self.lowest, float(heights.min())), max(self.highest, float(heights.max()))

    def range(self) -> tuple[float, float] | None:
        return (self.lowest, self.highest) if self.lowest <= self.highest else None


def _with_heights(chunk, grid: _Grid, dem: np.ndarray, normalize: bool, span: _HeightSpan):
    """``chunk`` with its heights above ``dem`` as the float32 ``HeightAboveGround`` attribute
    (``normalize``: as its z too, the z it had dropped)."""
    from ..core.chunk import PointChunk

    heights = chunk.xyz[:, 2] - grid.bilinear(dem, chunk.xyz)
    span.add(heights)
    attributes = dict(chunk.attributes)
    attributes[HEIGHT_ATTRIBUTE] = heights.astype(np.float32)
    xyz = np.column_stack([chunk.xyz[:, :2], heights]) if normalize else chunk.xyz
    return PointChunk(xyz, chunk.rgba, attributes, scale=chunk.scale, color_bits=chunk.color_bits)


@njit(cache=True)
def _sum_into(sums, counts, rows, cols, z):  # pragma: no cover - compiled
    for i in range(z.size):
        sums[rows[i], cols[i]] += z[i]
        counts[rows[i], cols[i]] += 1


def _mean_ground_raster(inputs, grid: _Grid, progress) -> tuple[np.ndarray, int]:
    """Pass 1 of ``height_above_ground``: (the mean z of the class-2 points in each cell, NaN
    where none; how many there were). None at all is a one-line InputError."""
    sums, counts = np.zeros(grid.shape), np.zeros(grid.shape, np.int64)
    progress.phase("ground", None if None in inputs.counts else sum(inputs.counts))
    for _, chunk in inputs.valid_chunks(None, progress, {}):
        classes = chunk.attributes.get("classification")
        if classes is None:
            continue
        xyz = chunk.xyz[classes == GROUND]
        rows, cols = grid.cells_of(xyz)
        _sum_into(sums, counts, rows, cols, np.ascontiguousarray(xyz[:, 2]))
    ground = int(counts.sum())
    if not ground:
        raise InputError(f"{inputs.label}: no ground point (class 2) to measure heights from: classify the ground in the same run (--ground, heights=True)")
    with np.errstate(invalid="ignore", divide="ignore"):
        return sums / counts, ground


def height_above_ground(source, out, *, cell=None, normalize: bool = False, overwrite: bool = False, chunk_size: int | None = None,
                        progress: bool = False) -> HeightResult:  # fmt: skip
    """Write the points of ``source`` (files, folders or patterns) to ``out`` (.las, .laz or
    .ply) with each one's height above the ground as the float32 attribute ``HeightAboveGround``
    (``normalize``: as its z too, for a canopy height model), every other attribute as read. The
    ground model is made of the files' class-2 points, ``cell`` a side (None: 1 m in the
    cloud's units, as ``classify_ground``'s); a cloud with no class 2 is a one-line InputError
    (``classify_ground(..., heights=True)`` classifies and measures in one run). Two passes,
    memory bounded by the raster."""
    t0 = time.perf_counter()
    out, inputs = _point_files(source, out, overwrite, chunk_size, "height_above_ground")
    params = {k: v for k, v in ground_parameters(inputs.files, cell=cell).items() if k in ("cell", "units")}
    shown = _progress(progress)
    span, tally = _HeightSpan(), {}
    try:
        grid = _files_grid(inputs, params["cell"], shown)
        mean, ground = _mean_ground_raster(inputs, grid, shown)
        dem = fill_everywhere(mean)
        written = _write_through(inputs, out, "heights", lambda chunk: _with_heights(chunk, grid, dem, normalize, span), shown, tally)
    finally:
        shown.close()
    return HeightResult(out, written, ground, span.range(), tally["skipped"], params, time.perf_counter() - t0)
