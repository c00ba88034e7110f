"""Thinning: one point kept per occupied cube cell of edge ``spacing`` (PDAL's
filters.voxelcenternearestneighbor / filters.sample, LAStools' lasthin, CloudCompare's spatial
subsampling), the first point of each cell in the order the points come.

The cells are those of io/cells.py (anchored at coordinate 0, so tiles thinned separately line
up). ``Thinning`` holds the cells met so far over a whole stream of chunks (a cell met in the
first chunk and again in the seventh keeps the first one's point) as 64-bit keys in its
open-addressing set (numba): each point is one probe. The set is kept at most half full (should
a whole chunk be new), a power of two of slots: 16 to 32 bytes a kept point, 1.5 times that
while it grows. Measured (10^8 points at random, all kept, 2 M-point chunks, on a shared 2-core
host): the set 45 s and 21.5 bytes a kept point (a 2 GiB table); a numpy sorted array merged a
chunk at a time 136 s and 8 bytes, as it copies the whole array each chunk (time quadratic in
the points kept).

Bad spacings (not a number above 0; cells too small for the extent to fit 63 bits) are one-line
InputErrors, before anything is read where the bounds are known.
"""

from __future__ import annotations

import math
import numbers

import numpy as np
from numba import njit

from ..core.chunk import PointChunk
from ..errors import InputError
from .cells import EMPTY, CellKeys, cell_key, grown, slot_of, table_shift


def thin_spacing(value, label: str) -> float | None:
    """``value`` (None: no thinning) as the cells' edge, a finite number above 0; else a one-line
    InputError starting with ``label`` (the option and its value as given: "convert: --thin 0")."""
    if value is None:
        return None
    if not (isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value) and value > 0):
        raise InputError(f"{label}: the cells' edge is a number above 0, in the cloud's units")
    return float(value)


@njit(cache=True)
def _first_in_cells(xyz, edges, corner, bits, table, shift, keep):  # pragma: no cover - compiled
    """Mark in ``keep`` the points of ``xyz`` whose cell is not in ``table`` yet, entering it
    (the first point of a cell wins). Returns the number kept, or -1 - i where point i's cell
    lies beyond the keys' reach (the table then holds the cells before it)."""
    kept = 0
    for i in range(xyz.shape[0]):
        key = cell_key(xyz, i, edges, corner, bits)
        if key == EMPTY:
            return -1 - i
        h = slot_of(table, key, shift)
        keep[i] = table[h] == EMPTY
        if keep[i]:
            table[h] = key
            kept += 1
    return kept


class Thinning:
    """The first point of each occupied cell of edge ``spacing`` over a stream of chunks
    (``kept``, chunk after chunk). ``bounds``: (lo, hi) of every point to come, from headers
    (None: unknown, the first point's cell stands for them); cells too small to key them are
    refused here, naming ``label`` (the option as given) and ``where`` (the files)."""

    def __init__(self, spacing: float, label: str, bounds, where: str):
        self.spacing, self.label = spacing, label
        self.kept_points = 0
        self.table, self._no_counts = np.full(0, EMPTY), np.zeros(0, np.uint32)
        self.keys = CellKeys(np.full(3, spacing), label)
        if bounds is not None:
            self.keys.size_for(*bounds, where)

    def kept(self, chunk: PointChunk, path) -> PointChunk:
        """The points of ``chunk`` (read from ``path``; finite positions) in cells no earlier point
        was in."""
        if not len(chunk):
            return chunk
        self.keys.sized_for(chunk.xyz, path)
        # (at most half full should all the chunk's points be kept)
        self.table, _ = grown(self.table, self._no_counts, 2 * (self.kept_points + len(chunk)), counted=False)
        keep = np.empty(len(chunk), np.bool_)
        xyz = np.ascontiguousarray(chunk.xyz, np.float64)
        n = _first_in_cells(xyz, self.keys.edges, self.keys.corner, self.keys.bits, self.table, table_shift(self.table), keep)
        if n < 0:
            self.keys.beyond_reach(xyz, n, path)
        self.kept_points += n
        if n == len(chunk):
            return chunk
        return chunk.subset(keep)


__all__ = ["Thinning", "thin_spacing"]
