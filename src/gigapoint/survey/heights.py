"""Height above ground (``gigapoint classify --height-above-ground``, ``gp.height_above_ground``):
PDAL's filters.hag_dem, LAStools' lasheight. The ground model is a raster of the files' extent,
as SMRF's (ground_raster.py's ``files_grid``): the mean z of the class-2 points in each cell (pass 1),
its empty cells (buildings, water) filled by ``fill_everywhere``; pass 2 writes each point's z
minus the model read bilinearly at its (x, y). With ``classify_ground(heights=True)`` (ground.py)
the model is SMRF's, just made, and its points are measured by ``heights_over`` against the
model values that classifying them read.
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
from .ground_raster import GROUND, files_grid, ground_parameters, point_files, progress_bar, write_through
from .raster_grid import RasterGrid

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


class HeightSpan:
    """The lowest and highest height above ground written so far."""

    def __init__(self):
        self.lowest, self.highest = math.inf, -math.inf

    def add(self, heights: np.ndarray) -> None:
        if heights.size:
            self.lowest, self.highest = min(self.lowest, float(heights.min())), max(self.highest, float(heights.max()))

    def range(self) -> tuple[float, float] | None:
        return (self.lowest, self.highest) if self.lowest <= self.highest else None


def heights_over(chunk, model: np.ndarray, normalize: bool, span: HeightSpan):
    """``chunk`` with its heights above ``model`` (the ground model's z read at its points:
    ``classify_ground`` has it from classifying them, and reads it only once) as the float32
    ``HeightAboveGround`` attribute (``normalize``: as its z too, the z it had dropped)."""
    from ..core.chunk import PointChunk

    heights = chunk.xyz[:, 2] - model
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


def _mean_ground_raster(inputs, grid: RasterGrid, progress) -> tuple[np.ndarray, int]:
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
    out, inputs = point_files(source, out, chunk_size, "height_above_ground", overwrite=overwrite, progress=progress, normalize=normalize)
    params = {k: v for k, v in ground_parameters(inputs.files, cell=cell, where="height_above_ground", lengths=("cell",)).items() if k in ("cell", "units", "height_units")}
    shown = progress_bar(progress)
    span, tally = HeightSpan(), {}
    try:
        grid = files_grid(inputs, params["cell"], shown)
        mean, ground = _mean_ground_raster(inputs, grid, shown)
        dem = fill_everywhere(mean)
        written = write_through(inputs, out, "heights", lambda chunk: heights_over(chunk, grid.bilinear(dem, chunk.xyz), normalize, span), shown, tally)
    finally:
        shown.close()
    return HeightResult(out, written, ground, span.range(), tally["skipped"], params, time.perf_counter() - t0)
