"""Noise classification (``gigapoint classify --noise``, ``gp.classify_noise``): isolated points
(birds, multipath returns, sensor spikes far above or below the surface) classified 7, low
noise, as LAStools' lasnoise does (PDAL's filters.outlier, radius method, by cells instead of a
radius). Pass 1 counts the points of each occupied cell of step x step x step_z (io/cells.py's
hash table: 16-32 bytes an occupied cell, never the points); a cell whose 3 x 3 x 3 block of
cells (itself in the middle) holds at most isolated + 1 points is sparse. Pass 2 writes every
point, class 7 where it lies in a sparse cell (at most `isolated` other points in its 27
cells). The cells are anchored at 0, as thinning's are, so tiles classified separately line up
(a point near a tile's edge has neighbours in the next tile: classify buffered tiles).
With classify_ground(noise=...) (ground.py), the noise is found first (``sparse_cells``, a pass
of its own) and marked in its passes' chunks (``noise_classified``), so that it is kept out of
the ground raster as the noise classes always are.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError, is_real, number_text
from .ground_raster import NOISE_CLASSES, defaults_needing_lengths, point_files, progress_bar, unit_symbol, write_through

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


#: noise_parameters' keywords: what classify_ground's ``noise`` dict may give
NOISE_KEYS = ("step", "step_z", "isolated")


def noise_option(noise, where: str) -> dict | None:
    """classify_ground's ``noise`` as noise_parameters' keywords: None where it is None, False or
    empty, {} (the defaults) where True, the dict where its keys are NOISE_KEYS; anything else a
    one-line InputError naming them (noise={"stepp": 3} was a TypeError, noise="yes" another)."""
    from collections.abc import Mapping

    if noise is None or isinstance(noise, (bool, np.bool_)):
        return {} if noise else None
    if isinstance(noise, Mapping) and set(noise) <= set(NOISE_KEYS):
        return dict(noise) or None
    raise InputError(f"{where}: noise must be True, False or a dict of {', '.join(NOISE_KEYS)}, got {noise!r}")


def noise_parameters(files, step=None, step_z=None, isolated=None) -> dict:
    """The noise parameters in the units of ``files``' CRS: ``step`` (the cells' horizontal
    edge) as given, else 4 m converted; ``step_z`` (their height) as given, else as long as
    ``step`` in the vertical units; ``isolated`` (the most other points an isolated point has in
    its 27 cells) as given, else 5. A step that is no number > 0, an isolated that is no whole
    number >= 0, or coordinates in degrees without both steps given, is a one-line InputError."""
    import numbers

    from ..io.crs import files_length_units

    for name, value in (("step", step), ("step_z", step_z)):
        if value is not None and not (is_real(value) and value > 0):
            raise InputError(f"classify_noise: {name} must be a number > 0, got {number_text(value)}")
    if isolated is not None and not (isinstance(isolated, numbers.Integral) and not isinstance(isolated, bool) and isolated >= 0):
        raise InputError(f"classify_noise: isolated must be a whole number >= 0, got {isolated!r}")
    needs_lengths = defaults_needing_lengths({name: NOISE_STEP_METRES for name, value in (("step", step), ("step_z", step_z)) if value is None})
    units = files_length_units("classify_noise", files, needs_lengths, "give both, or ")
    across, up = units["horizontal"], units["vertical"]
    metres_across = across["metres"] if across is not None and across["metres"] else 1.0
    metres_up = up["metres"] if up is not None and up["metres"] else 1.0
    step = NOISE_STEP_METRES / metres_across if step is None else float(step)
    return {
        "step": step,
        "step_z": step * metres_across / metres_up if step_z is None else float(step_z),
        "isolated": DEFAULT_ISOLATED if isolated is None else int(isolated),
        "units": unit_symbol(across),
        "height_units": unit_symbol(up),
    }


def classify_noise(source, out, *, step=None, step_z=None, isolated=None, overwrite: bool = False,
                   chunk_size: int | None = None, progress: bool = False) -> NoiseResult:  # fmt: skip
    """Classify the isolated points of ``source`` (files, folders or patterns, as ``gp.open``
    takes them) as noise (7), as lasnoise does, and write them all to ``out`` (.las, .laz or
    .ply), every other point's class and every attribute as read. Two passes over the files,
    memory bounded by the occupied cells (see the module's notes). Parameters in the cloud's units,
    None: the defaults (``noise_parameters``). ``out`` appears only once whole; an existing one
    is replaced only with ``overwrite``."""
    t0 = time.perf_counter()
    out, inputs = point_files(source, out, chunk_size, "classify_noise", overwrite=overwrite, progress=progress)
    params = noise_parameters(inputs.files, step, step_z, isolated)
    shown = progress_bar(progress)
    try:
        cells = sparse_cells(inputs, params, shown)
        counts = {"noise": 0, "kept": 0}
        tally: dict = {}
        written = write_through(inputs, out, "classify", lambda chunk: noise_classified(chunk, cells, counts), shown, tally)
    finally:
        shown.close()
    return NoiseResult(out, written, counts["noise"], counts["kept"], tally["skipped"], cells.cells, cells.nbytes, params, time.perf_counter() - t0)


def sparse_cells(inputs, params: dict, progress):
    """Pass 1: every valid point counted in its cell, the cells with at most ``isolated`` + 1
    points in their 3 x 3 x 3 block marked (io/cells.py's CellCounts)."""
    from ..io.cells import CellCounts

    edges = (params["step"], params["step"], params["step_z"])
    cells = CellCounts(edges, f"classify_noise: step {params['step']:g}", inputs.headers_bounds(), inputs.label)
    progress.phase("count", None if None in inputs.counts else sum(inputs.counts))
    for f, chunk in inputs.valid_chunks(None, progress, {}):
        cells.add(chunk.xyz, f)
    cells.mark_sparse(min(params["isolated"], 2**62) + 1)  # (no block holds 2**62 points; 1e20 overflowed the kernel's int64: a numba traceback)
    return cells


def noise_classified(chunk, cells, counts: dict):
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
