"""Occupied cells of a grid of boxes over a stream of points, held as 64-bit keys in an
open-addressing hash table (numba): the set of cells met by thinning (io/thin.py) and the
points counted in each cell by noise classification (survey/noise.py).

The cells are [i·edge, (i+1)·edge) on each axis (an edge an axis: x, y, z): a grid anchored at
coordinate 0, not at a file's bounds or offset, so tiles processed separately line up. A key
packs the three cell indices, each counted from a corner cell, in bits shared out by the extent
in cells of the data (the headers' bounds where they tell, else the first point's cell); the
bits left over widen every axis (a point beyond stale header bounds still fits). Cells too small
for the extent to fit 63 bits are a one-line InputError, before anything is read where the
bounds are known. Each point is one probe (linear probing, Fibonacci hashing).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..errors import InputError

#: bits of a cell key (a uint64; the top bit never set, so the empty slot's all-ones is never a key)
KEY_BITS = 63
#: cell indices (coordinate / edge, floored) are exact float64 integers below this, and a
#: cell less the keys' corner cell too: an axis's key bits are at most _AXIS_BITS
_EXACT = 2.0**52
_AXIS_BITS = 52
EMPTY = np.uint64(0xFFFFFFFFFFFFFFFF)
_HASH_MUL = np.uint64(0x9E3779B97F4A7C15)  # Fibonacci hashing: neighbouring cells scattered over the table
#: a cell count's top bit: the cell marked (``mark_sparse``); its count is the bits below
_MARK = np.uint32(0x80000000)
_COUNT_MAX = np.uint32(0x7FFFFFFF)


class CellKeys:
    """How the cells of ``edges`` (x, y, z) are keyed: ``corner`` (the cell whose key is 0, as
    float64 indices) and ``bits`` (key bits of x, y, z), sized by ``size_for`` for the points
    within given bounds. ``label`` (the option as given) and the files name a refusal."""

    def __init__(self, edges, label: str):
        self.edges, self.label = np.asarray(edges, np.float64), label
        self.corner = self.bits = None

    def size_for(self, lo, hi, where: str) -> None:
        """Key bits and corner cell for points within ``lo``..``hi`` (read from ``where``): each
        axis as many bits as its extent in cells needs, the bits left shared out to widen every axis both ways."""
        with np.errstate(over="ignore"):  # (a subnormal cell's division: inf, refused just below)
            lo_cell, hi_cell = np.floor(np.asarray(lo, np.float64) / self.edges), np.floor(np.asarray(hi, np.float64) / self.edges)
        if not np.all(np.abs(np.concatenate([lo_cell, hi_cell])) < _EXACT):
            self.too_small(f"{where}: cells {lo_cell.min():.3g} to {hi_cell.max():.3g} from the origin")
        lo_cell, cells = lo_cell.astype(np.int64), (hi_cell - lo_cell + 1).astype(np.int64)
        need = np.array([int(n - 1).bit_length() for n in cells], np.int64)
        if need.sum() > KEY_BITS or need.max() > _AXIS_BITS:
            extent = " x ".join(f"{n:.3g}" for n in cells.astype(np.float64))
            self.too_small(f"{where}: {extent} cells, over 2^{KEY_BITS}")
        self.bits = np.minimum(need + (KEY_BITS - need.sum()) // 3, _AXIS_BITS)
        # the data centred in the keys' reach; (integers: the corner and a cell less it stay exact floats)
        self.corner = (lo_cell - ((1 << self.bits) - cells) // 2).astype(np.float64)

    def sized_for(self, xyz: np.ndarray, path) -> None:
        """Keys sized around the first point of ``xyz`` where no bounds were told."""
        if self.bits is None:
            self.size_for(xyz[0], xyz[0], path)

    def too_small(self, why: str):
        raise InputError(f"{self.label}: cells too small for the data's extent ({why})")

    def beyond_reach(self, xyz: np.ndarray, failed: int, path):
        """The refusal of a kernel that returned ``failed`` (-1 - i: point i of ``xyz`` beyond the keys' reach)."""
        far = ", ".join(f"{v:.15g}" for v in xyz[-1 - failed])
        self.too_small(f"{path}: a point at {far} is beyond the reach of {KEY_BITS}-bit cell keys")


@njit(cache=True)
def cell_key(xyz, i, edges, corner, bits):  # pragma: no cover - compiled
    """The key of point i's cell, or EMPTY where it lies beyond the keys' reach."""
    key = np.uint64(0)
    for a in range(3):
        cell = math.floor(xyz[i, a] / edges[a]) - corner[a]
        if not (0.0 <= cell < 2.0 ** bits[a]):
            return EMPTY
        key = (key << np.uint64(bits[a])) | np.uint64(cell)
    return key


@njit(cache=True)
def slot_of(table, key, shift):  # pragma: no cover - compiled
    """The slot of ``table`` holding ``key``, or the empty one where it would go."""
    h = (key * _HASH_MUL) >> shift
    mask = np.uint64(table.shape[0] - 1)
    while table[h] != key and table[h] != EMPTY:
        h = (h + np.uint64(1)) & mask
    return h


@njit(cache=True)
def _rehash(old, old_counts, table, counts, shift):  # pragma: no cover - compiled
    """Enter every key of the table ``old`` (and its count, where counts are kept) into the empty, larger ``table``."""
    for s in range(old.shape[0]):
        if old[s] != EMPTY:
            h = slot_of(table, old[s], shift)
            table[h] = old[s]
            if counts.shape[0]:
                counts[h] = old_counts[s]


def table_shift(table: np.ndarray) -> np.uint64:
    """How far a key times _HASH_MUL is shifted right to leave a slot of ``table`` (2^k slots: its top k bits)."""
    return np.uint64(65 - int(table.size).bit_length())


def grown(table: np.ndarray, counts: np.ndarray, slots_needed: int, counted: bool) -> tuple[np.ndarray, np.ndarray]:
    """``table`` (and its ``counts`` where ``counted``; else an empty array) moved into a power
    of two of slots, at least ``slots_needed``; as they are where they have that many."""
    if slots_needed <= table.size:
        return table, counts
    bigger = np.full(1 << (slots_needed - 1).bit_length(), EMPTY)
    more = np.zeros(bigger.size if counted else 0, np.uint32)
    _rehash(table, counts, bigger, more, table_shift(bigger))
    return bigger, more


@njit(cache=True)
def _count_into(xyz, start, edges, corner, bits, table, counts, shift, room):  # pragma: no cover - compiled
    """Add the points of ``xyz`` from ``start`` on to their cells' counts (saturating), entering
    at most ``room`` new cells. Returns (the next point to count: xyz's length when all are,
    cells entered), or (-1 - i, 0) where point i lies beyond the keys' reach."""
    entered = 0
    last_key, last_slot = EMPTY, np.uint64(0)
    for i in range(start, xyz.shape[0]):
        key = cell_key(xyz, i, edges, corner, bits)
        if key == EMPTY:
            return -1 - i, 0
        if key != last_key:  # (a scan's points come a cell at a time: no probe for the next point of the same cell)
            slot = slot_of(table, key, shift)
            if table[slot] == EMPTY:
                if entered == room:  # (full enough: the table grows, then counting goes on from here)
                    return i, entered
                table[slot] = key
                entered += 1
            last_key, last_slot = key, slot
        if counts[last_slot] < _COUNT_MAX:
            counts[last_slot] += np.uint32(1)
    return xyz.shape[0], entered


@njit(cache=True)
def _block_total(table, counts, shift, cx, cy, cz, bits, most):  # pragma: no cover - compiled
    """The points in the 3 x 3 x 3 cells around cell (cx, cy, cz), counted up to ``most`` + 1."""
    total = 0
    for x in range(cx - 1, cx + 2):
        for y in range(cy - 1, cy + 2):
            for z in range(cz - 1, cz + 2):
                if x < 0 or y < 0 or z < 0 or x >= (1 << bits[0]) or y >= (1 << bits[1]) or z >= (1 << bits[2]):
                    continue  # (beyond the keys' reach: no point there)
                near = (np.uint64(x) << np.uint64(bits[1] + bits[2])) | (np.uint64(y) << np.uint64(bits[2])) | np.uint64(z)
                h = slot_of(table, near, shift)
                if table[h] == near:
                    total += counts[h] & _COUNT_MAX
                    if total > most:
                        return total
    return total


@njit(cache=True)
def _mark_sparse(table, counts, shift, bits, most):  # pragma: no cover - compiled
    """Set the mark bit of every cell whose 3 x 3 x 3 block of cells (itself in the middle) holds
    at most ``most`` points. Returns the number of points in the marked cells."""
    bz, by = np.uint64(bits[2]), np.uint64(bits[1])
    marked = 0
    for s in range(table.shape[0]):
        key = table[s]
        if key == EMPTY:
            continue
        cx = np.int64(key >> (by + bz))
        cy = np.int64((key >> bz) & ((np.uint64(1) << by) - np.uint64(1)))
        cz = np.int64(key & ((np.uint64(1) << bz) - np.uint64(1)))
        if _block_total(table, counts, shift, cx, cy, cz, bits, most) <= most:
            counts[s] |= _MARK
            marked += counts[s] & _COUNT_MAX
    return marked


@njit(cache=True)
def _marked_points(xyz, edges, corner, bits, table, counts, shift, out):  # pragma: no cover - compiled
    """``out[i]``: whether point i lies in a marked cell (a cell never counted: not marked)."""
    last_key, marked = EMPTY, False
    for i in range(xyz.shape[0]):
        key = cell_key(xyz, i, edges, corner, bits)
        if key != last_key:
            last_key = key
            h = slot_of(table, key, shift) if key != EMPTY else np.uint64(0)
            marked = key != EMPTY and table[h] == key and (counts[h] & _MARK) != 0
        out[i] = marked


class CellCounts:
    """The number of points in each occupied cell of ``edges`` (x, y, z) over a stream of
    chunks (``add``), then which cells are sparse (``mark_sparse``) and which points lie in them
    (``in_sparse_cells``). ``bounds``: (lo, hi) of every point to come, from headers (None:
    unknown, the first point's cell stands for them). A uint64 key and a uint32 count a slot,
    the table between 3/8 and 3/4 full (doubled when a point's new cell would fill it more): 16 to
    32 bytes an occupied cell (past the first MIN_SLOTS), 1.5 times that while it grows."""

    MAX_LOAD = 0.75
    MIN_SLOTS = 1024

    def __init__(self, edges, label: str, bounds, where: str):
        self.keys = CellKeys(edges, label)
        if bounds is not None:
            self.keys.size_for(*bounds, where)
        self.cells = 0
        self.table, self.counts = np.full(0, EMPTY), np.zeros(0, np.uint32)

    @property
    def nbytes(self) -> int:
        return self.table.nbytes + self.counts.nbytes

    def add(self, xyz: np.ndarray, path) -> None:
        """Count the points of ``xyz`` (read from ``path``; finite) in their cells."""
        if not len(xyz):
            return
        self.keys.sized_for(xyz, path)
        xyz = np.ascontiguousarray(xyz, np.float64)
        i = 0
        while i < len(xyz):
            room = int(self.table.size * self.MAX_LOAD) - self.cells
            if room <= 0:  # (doubled: 3/8 full after, 3/4 at most before)
                self.table, self.counts = grown(self.table, self.counts, max(2 * self.table.size, self.MIN_SLOTS), counted=True)
                continue
            i, entered = _count_into(xyz, i, self.keys.edges, self.keys.corner, self.keys.bits, self.table, self.counts, table_shift(self.table), room)
            if i < 0:
                self.keys.beyond_reach(xyz, i, path)
            self.cells += entered

    def mark_sparse(self, most: int) -> int:
        """Mark the cells whose 3 x 3 x 3 block holds at most ``most`` points; returns how many points they hold."""
        return int(_mark_sparse(self.table, self.counts, table_shift(self.table), self.keys.bits, most)) if self.table.size else 0

    def in_sparse_cells(self, xyz: np.ndarray) -> np.ndarray:
        """Whether each point of ``xyz`` lies in a marked cell."""
        out = np.zeros(len(xyz), np.bool_)
        if self.table.size and len(xyz):
            xyz = np.ascontiguousarray(xyz, np.float64)
            _marked_points(xyz, self.keys.edges, self.keys.corner, self.keys.bits, self.table, self.counts, table_shift(self.table), out)
        return out
