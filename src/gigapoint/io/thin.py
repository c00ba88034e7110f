"""Thinning: one point kept per occupied cube cell of edge ``spacing`` (PDAL's
filters.voxelcenternearestneighbor / filters.sample, LAStools' lasthin, CloudCompare's spatial
subsampling), the first point of each cell in the order the points come.

The cells are [i·spacing, (i+1)·spacing) on each axis: a grid anchored at coordinate 0, not at
a file's bounds or offset, so tiles thinned separately line up. ``Thinning`` holds the cells met
so far over a whole stream of chunks (a cell met in the first chunk and again in the seventh
keeps the first one's point) as 64-bit keys in an open-addressing set (numba): each point is one
probe. The set is kept at most half full (should a whole chunk be new), a power of two of slots:
16 to 32 bytes a kept point, 1.5 times that while it grows. Measured (10^8 points at random, all
kept, 2 M-point chunks, on a shared 2-core host): the set 45 s and 21.5 bytes a kept point (a
2 GiB table); a numpy sorted array merged a chunk at a time 136 s and 8 bytes, as it copies the
whole array each chunk (time quadratic in the points kept).

A key packs the three cell indices, each counted from a corner cell, in bits shared out by the
extent in cells of the data (the headers' bounds where they tell, else the first point's cell);
the bits left over widen every axis (a point beyond stale header bounds still fits). Bad
spacings (not a number above 0; cells too small for the extent to fit 63 bits) are one-line
InputErrors, before anything is read where the bounds are known.
"""

from __future__ import annotations

import math
import numbers

import numpy as np
from numba import njit

from ..core.chunk import PointChunk
from ..errors import InputError

#: bits of a cell key (a uint64; the top bit never set, so the empty slot's all-ones is never a key)
KEY_BITS = 63
#: cell indices (coordinate / spacing, floored) are exact float64 integers below this, and a
#: cell less the keys' corner cell too: an axis's key bits are at most _AXIS_BITS
_EXACT = 2.0**52
_AXIS_BITS = 52
_EMPTY = np.uint64(0xFFFFFFFFFFFFFFFF)
_HASH_MUL = np.uint64(0x9E3779B97F4A7C15)  # Fibonacci hashing: neighbouring cells scattered over the table


def thin_spacing(value, label: str) -> float | None:
    """``value`` (None: no thinning) as the cells' edge, a finite number above 0; else a one-line
    InputError starting with ``label`` (the option and its value as given: "convert: --thin 0")."""
    if value is None:
        return None
    if not (isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value) and value > 0):
        raise InputError(f"{label}: the cells' edge is a number above 0, in the cloud's units")
    return float(value)


@njit(cache=True)
def _first_in_cells(xyz, spacing, corner, bits, table, shift, keep):
    """Mark in ``keep`` the points of ``xyz`` whose cell is not in ``table`` yet, entering it
    (the first point of a cell wins). ``corner``: the cell whose key is 0 (float64 indices);
    ``bits``: key bits of x, y, z. Returns the number kept, or -1 - i where point i's cell lies
    beyond the keys' reach (the table then holds the cells before it)."""
    kept = 0
    for i in range(xyz.shape[0]):
        key = np.uint64(0)
        for a in range(3):
            cell = math.floor(xyz[i, a] / spacing) - corner[a]
            if not (0.0 <= cell < 2.0 ** bits[a]):
                return -1 - i
            key = (key << np.uint64(bits[a])) | np.uint64(cell)
        h = (key * _HASH_MUL) >> shift
        mask = np.uint64(table.shape[0] - 1)
        while True:
            held = table[h]
            if held == key:
                keep[i] = False
                break
            if held == _EMPTY:
                table[h] = key
                keep[i] = True
                kept += 1
                break
            h = (h + np.uint64(1)) & mask
    return kept


@njit(cache=True)
def _rehash(old, table, shift):
    """Enter every key of the table ``old`` into the empty, larger ``table``."""
    mask = np.uint64(table.shape[0] - 1)
    for key in old:
        if key == _EMPTY:
            continue
        h = (key * _HASH_MUL) >> shift
        while table[h] != _EMPTY:
            h = (h + np.uint64(1)) & mask
        table[h] = key


class Thinning:
    """The first point of each occupied cell of edge ``spacing`` over a stream of chunks
    (``kept``, chunk after chunk). ``bounds``: (lo, hi) of every point to come, from headers
    (None: unknown, the first point's cell stands for them); cells too small to key them are
    refused here, naming ``label`` (the option as given) and ``where`` (the files)."""

    def __init__(self, spacing: float, label: str, bounds, where: str):
        self.spacing, self.label = spacing, label
        self.kept_points = 0
        self.table = np.full(0, _EMPTY)
        self.corner = self.bits = None
        if bounds is not None:
            self._size_keys(*bounds, where)

    def _size_keys(self, lo, hi, where: str) -> None:
        """Key bits and corner cell for points within ``lo``..``hi``: each axis as many bits as
        its extent in cells needs, the bits left shared out to widen every axis both ways."""
        lo_cell, hi_cell = np.floor(np.asarray(lo, np.float64) / self.spacing), np.floor(np.asarray(hi, np.float64) / self.spacing)
        if not np.all(np.abs(np.concatenate([lo_cell, hi_cell])) < _EXACT):
            self._too_small(f"{where}: cells {lo_cell.min():.3g} to {hi_cell.max():.3g} from the origin")
        lo_cell, cells = lo_cell.astype(np.int64), (hi_cell - lo_cell + 1).astype(np.int64)
        need = np.array([int(n - 1).bit_length() for n in cells], np.int64)
        if need.sum() > KEY_BITS or need.max() > _AXIS_BITS:
            extent = " x ".join(f"{n:.3g}" for n in cells.astype(np.float64))
            self._too_small(f"{where}: {extent} cells, over 2^{KEY_BITS}")
        self.bits = np.minimum(need + (KEY_BITS - need.sum()) // 3, _AXIS_BITS)
        # the data centred in the keys' reach; (integers: the corner and a cell less it stay exact floats)
        self.corner = (lo_cell - ((1 << self.bits) - cells) // 2).astype(np.float64)

    def _too_small(self, why: str):
        raise InputError(f"{self.label}: cells too small for the data's extent ({why})")

    def kept(self, chunk: PointChunk, path) -> PointChunk:
        """The points of ``chunk`` (read from ``path``; finite positions) in cells no earlier point
        was in."""
        if not len(chunk):
            return chunk
        if self.bits is None:  # no bounds told: keys sized around the first point
            self._size_keys(chunk.xyz[0], chunk.xyz[0], path)
        self._make_room(len(chunk))
        keep = np.empty(len(chunk), np.bool_)
        xyz = np.ascontiguousarray(chunk.xyz, np.float64)
        n = _first_in_cells(xyz, self.spacing, self.corner, self.bits, self.table, _shift(self.table), keep)
        if n < 0:
            far = ", ".join(f"{v:.15g}" for v in xyz[-1 - n])
            self._too_small(f"{path}: a point at {far} is beyond the reach of {KEY_BITS}-bit cell keys")
        self.kept_points += n
        if n == len(chunk):
            return chunk
        return chunk.subset(keep)

    def _make_room(self, coming: int) -> None:
        """Grow the table (a power of two of slots) to stay at most half full should all ``coming`` points be kept."""
        need = 2 * (self.kept_points + coming)
        if need <= self.table.size:
            return
        old, self.table = self.table, np.full(1 << (need - 1).bit_length(), _EMPTY)
        _rehash(old, self.table, _shift(self.table))


def _shift(table: np.ndarray) -> np.uint64:
    """How far a key times _HASH_MUL is shifted right to leave a slot of ``table`` (2^k slots: its top k bits)."""
    return np.uint64(65 - int(table.size).bit_length())


__all__ = ["Thinning", "thin_spacing"]
