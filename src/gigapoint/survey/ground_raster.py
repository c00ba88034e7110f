"""The raster and the point passes that ground classification (ground.py), noise classification
(noise.py) and heights above ground (heights.py) share: ``point_files`` checks the output and
opens the inputs (io's PointFiles), ``files_grid`` lays a raster grid of ``cell``-sized cells over
the files' extent (raster_grid.py: its cells, its bilinear reads), ``write_through`` is every job's last pass
(each valid chunk, changed, written as ``convert -o`` writes it). ``ground_parameters``: SMRF's
lengths in the cloud's units, here because heights above ground take its cell (and its messages).

Lengths are in the cloud's units (io/crs.py): the defaults (cell 1 m, window 18 m, threshold
0.5 m, scalar 1.25 m per unit of slope) are converted for a cloud in feet; ``slope`` is rise over run.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError, check_switch, count_text, is_real, number_text
from .raster_grid import RasterGrid

#: PDAL's and the paper's defaults, in metres (``slope``: rise over run, no unit)
DEFAULTS_METRES = {"cell": 1.0, "window": 18.0, "threshold": 0.5, "scalar": 1.25}
DEFAULT_SLOPE = 0.15
#: the classes a ground classification keeps as they are: low and high noise
NOISE_CLASSES = (7, 18)
GROUND, NON_GROUND = 2, 1
#: the most cells the raster may have (several float64 arrays of it are held at once: ~1 GB each at this size)
MAX_CELLS = 120_000_000


def ground_parameters(files, cell=None, slope=None, window=None, threshold=None, scalar=None, where="classify_ground", lengths=("cell", "window")) -> dict:
    """The SMRF parameters in the units of ``files``' CRS: those given as they are, the others
    the defaults converted from metres (a cloud in feet: cell 3.28 ft...; units unknown: taken
    as metres). A value that is no number > 0 (threshold, scalar: >= 0), or coordinates in
    degrees without every one of ``lengths`` given (those the caller uses), is a one-line
    InputError; ``where``: the operation messages name."""
    from ..io.crs import files_length_units

    given = {"cell": cell, "slope": slope, "window": window, "threshold": threshold, "scalar": scalar}
    for name, value in given.items():
        least = "> 0" if name in ("cell", "slope", "window") else ">= 0"
        if value is not None and not (is_real(value) and (value > 0 if least == "> 0" else value >= 0)):
            raise InputError(f"{where}: {name} must be a number {least}, got {number_text(value)}")
    needs_lengths = defaults_needing_lengths({name: DEFAULTS_METRES[name] for name in lengths if given[name] is None})
    units = files_length_units(where, files, needs_lengths, f"give {'both' if len(lengths) > 1 else lengths[0]}, or ")
    across, up = units["horizontal"], units["vertical"]
    per_metre_across = 1.0 / across["metres"] if across is not None and across["metres"] else 1.0
    per_metre_up = 1.0 / up["metres"] if up is not None and up["metres"] else 1.0
    params = {
        "cell": DEFAULTS_METRES["cell"] * per_metre_across if cell is None else float(cell),
        "slope": DEFAULT_SLOPE if slope is None else float(slope),
        "window": DEFAULTS_METRES["window"] * per_metre_across if window is None else float(window),
        "threshold": DEFAULTS_METRES["threshold"] * per_metre_up if threshold is None else float(threshold),
        "scalar": DEFAULTS_METRES["scalar"] * per_metre_up if scalar is None else float(scalar),
    }
    return {**params, "units": unit_symbol(across), "height_units": unit_symbol(up)}


def defaults_needing_lengths(defaults: dict[str, float]) -> str | None:
    """What needs lengths, in io.crs.refuse_angles' words, of the ``defaults`` used ({name:
    metres}): 'a default cell (1 m) or window (18 m)'; None where none is."""
    return f"a default {' or '.join(f'{name} ({metres:g} m)' for name, metres in defaults.items())}" if defaults else None


def unit_symbol(unit: dict | None) -> str:
    """How a classification names a unit of io.crs_units (horizontal or vertical): its symbol;
    none known, 'm (assumed)', as its defaults take it."""
    return unit["symbol"] if unit is not None else "m (assumed)"


def point_files(source, out, chunk_size: int | None, where: str, **switches):
    """(``out`` as a Path, the PointFiles of ``source`` it is written from) for a classification
    that writes every point of its inputs again: ``out`` a .las, .laz or .ply file not there
    yet (or ``overwrite``), checked before a point is read (one-line errors starting ``where``).
    ``switches``: the classification's True/False parameters (``overwrite`` among them), each
    checked first: overwrite="no" replaced the file, heights="no" wrote heights."""
    from ..io import given_paths
    from ..io.write import check_point_file_output
    from ..lod.convert.to_file import PointFiles

    for name, value in switches.items():
        check_switch(name, value, where)
    out = Path(out)
    if out.suffix.lower() not in (".las", ".laz", ".ply"):
        raise InputError(f"{out}: {where} writes a .las, .laz or .ply file")
    check_point_file_output(out, switches["overwrite"])
    return out, PointFiles(given_paths(source, where, "source"), out, chunk_size, ply=out.suffix.lower() == ".ply", where=where)


def progress_bar(shown: bool):
    """The progress bar of a classification's passes (rich), or none."""
    from ..lod.progress import NullProgress, RichProgress

    return RichProgress() if shown else NullProgress()


def write_through(inputs, out: Path, phase: str, each, progress, tally: dict) -> int:
    """The last pass of a classification: every valid chunk of ``inputs`` as ``each`` gives it
    back, written to ``out`` on the inputs' LAS grid, with their CRS and colours (none where
    none of them has any); the points written."""
    from ..io.write import write_points

    def chunks():
        progress.phase(phase, None if None in inputs.counts else sum(inputs.counts))
        for _, chunk in inputs.valid_chunks(None, progress, tally):
            yield each(chunk)

    return write_points(out, chunks, None, grid=inputs.las_grid, crs_records=inputs.crs_records, color_bits=None, has_color=inputs.has_color)


def files_grid(inputs, cell: float, progress) -> RasterGrid:
    """The raster grid over the files' extent (``RasterGrid.over``: from its lowest corner, rows
    northwards): their headers' bounds, or a pass of its own where one tells none. More than
    MAX_CELLS cells is a one-line InputError."""
    bounds = inputs.headers_bounds()
    if bounds is None:
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        for _, chunk in inputs.valid_chunks(None, progress, {}):
            lo, hi = np.minimum(lo, chunk.xyz.min(axis=0)), np.maximum(hi, chunk.xyz.max(axis=0))
        bounds = (lo, hi)
    grid = RasterGrid.over(bounds[0], bounds[1], cell)
    if grid.cells > MAX_CELLS:
        raise InputError(
            f"{inputs.label}: cells of {number_text(cell)} make a {count_text(grid.shape[1])} x {count_text(grid.shape[0])} raster over the files' extent, more than "
            f"{MAX_CELLS:,} cells: give a larger cell, or classify tiles of it (gigapoint tile)"
        )
    return grid


