"""ProgressiveOctree: an LOD octree that grows while points are added, drawn at any moment.

The structure of SimLOD (Schütz, Herzberger, Wimmer 2024, sections 3-5; Wand et al. 2008):

- **leaves** hold the original points (30-bit positions in the cube of the leaf a point first
  landed in, at worst the root's: a micrometre for a kilometre, a millimetre for a thousand
  kilometres), up to ``max_leaf`` (50 000) each; a leaf that would
  overflow is split: it becomes an inner node, its points are *spilled* and inserted again,
  together with the batch that made it overflow, until every leaf holds at most
  ``max_leaf`` points. Every point added lives in exactly one leaf.
- **inner nodes** hold voxels: one per occupied cell of a 128³ grid inscribed in the node,
  at the cell's centre, with the rounded mean colour of all the points that passed through the
  cell (the paper draws the first point's colour and leaves the mean to post-processing; the
  first point gives the voxel its attributes). Voxels are extra representatives, not the points themselves.
  Occupancy is an open-addressing table keyed by (node, cell), not a 128³ bit grid per node:
  256 KB a node is more than the voxels of most nodes (a surface fills ~16 k of 2 M cells).
- **storage**: a pool of fixed-size chunks (``CHUNK`` entries) in gigapoint's compact batch
  layout (core/compact.py: a low word, u32 RGBA and the attributes an entry, positions relative
  to the node's cube): a point chunk keeps the bits under the low word in a stream of its
  own: where the points lie on the source's grid (a LAS file's offset and scale), the bits
  its cube needs at the grid's step, each point written as its grid cell as it comes (15-18
  bits a point at 1 mm: ``_level_bits``), else 20 an axis (a wide batch, 7.5 bytes a point;
  ``trim`` packs the chunks of those that lie on a grid all the same, ``_pack``); a voxel chunk
  needs nothing more (a voxel sits at its cell's centre on the node's 128³ grid, which the low
  word holds). Attributes are held, while points come, in the form their values so far need
  (core/attributes.py: a constant as one value, an integer range in a narrow dtype; a batch
  that does not fit widens it: ``_stored_form``), and in their real range once loaded. A node's entries are a linked list of chunks, so nodes grow without copies, and a split
  leaf's chunks go back to a free list. Each chunk is a batch: the renderer draws the pool
  directly (one batch per chunk), with the octree's node selection (largest projected
  first, within the point budget) and per-node precision, and the GPU re-uploads only the
  chunks written since it last drew them (``version`` / ``batch_version``). With hidden classes
  it draws each chunk's entries of the other classes, kept apart (``KeptChunks``).
- **the root** is the bounding cube of the points seen so far (or of bounds given up front,
  e.g. from LAS headers); a point outside it makes the tree grow upwards: a new root twice
  the size takes the old one as a child, and samples every point into its own voxels.

An insertion runs SimLOD's passes on the CPU: sort the batch by point code (packed (code
prefix, index) keys, by numpy's sort or a radix sort, whichever is faster here), route it down the tree in one pass over the sorted codes
(``kernels.distribute``: a node's points are one contiguous run), split overflowing leaves
(their points one more set, sorted and routed from their leaves) and route again, then find the voxel
cells of every inner node the runs pass, bottom-up and shared (``kernels.sample_runs``), look
them up in the voxel table, allocate chunks, and write points and voxels in parallel. ``add`` is thread-safe; ``reading()`` keeps a frame's view consistent.
"""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
from typing import NamedTuple, Self

import numba
import numpy as np
from numba.typed import List

from ...core import pages
from ...core.attributes import Attributes, encode, fits, holder_for, repacked, resized, widened, zeroed_like
from ...core.attributes import stored as stored_array
from ...core.bounds import valid_bounds
from ...core.chunk import PointChunk, attribute_dtype_problem, attribute_name_problem, colors_for, points_for, warn_dropped_attributes
from ...core.cloud import MAX_ABS_COORDINATE, at_scale, byte_views, check_valid_count, source_color_bits, take
from ...core.compact import GRID_TOLERANCE, centre_half, ext_bits_per_point, point_words, stream_words, streams_into
from ...core.framelock import FrameLock
from ...core.layout import BATCH_DTYPE, EXT_FULL_BITS, PACK_DTYPE, WORD_BITS
from ...core.morton import fastest
from ...core.quantize import dequantize
from ...core.renderable import DrawList, MultiViewDrawList, check_classified, check_point_index
from ...core.selection import Selection, View, batch_matrices, precision_for, visible_and_size
from ...core.threads import threads_for
from ...errors import GigapointError, InputError, check_timeout, check_whole
from ...render.splats import weighted_median
from ..class_counts import class_histogram
from ..keys import CODE_BITS, morton_position, point_codes
from ..store import KEPT_ROUNDS, kept_shares, list_chunks, select_octants
from . import kernels as K

CHUNK = 2048  # entries a chunk holds (the paper: 1 000)
MAX_LEAF = 50_000  # points a leaf holds before it splits (the paper's)
_INITIAL_NODES = 1024
_INITIAL_CHUNKS = 64
_ROOM_PER_POINT = 2.0  # pool entries an expected point takes: itself, 0.3-0.5 voxels, half-filled chunks (room unwritten: address space)
_STREAMS_PER_POINT = 1.1  # point chunks' streams (CHUNK points each) an expected point takes: itself, half-filled chunks
_VOXELS_PER_POINT = 0.5  # voxels a point brings, at most about (the demo town: 0.34 in 1 M batches, 0.49 in the loader's 250 k slices)
_PARALLEL_CELLS = 100_000  # points of a set from which sample_runs spreads each level's nodes over the threads
_PRESIZE_MAX = 32_000_000  # points the pool is presized for at most (1.5-2.5 GB of address space, written as it fills)
_PRESIZE_TABLE_MAX = 16_000_000  # ... and the voxel table (filled up front: ~0.2 GB)
_NO_BITS = np.zeros(CODE_BITS + 2, np.int64)  # voxel chunks' (no stream)
_GROWTH_MAX_CHUNKS = 16_384  # the pool grows by at most this many chunks (32 M entries, ~0.6 GB) beyond doubling small pools


def _voxel_table(size: int) -> tuple[np.ndarray, np.ndarray]:
    """An empty voxel table of ``size`` slots: (keys u64, ids u32), views of one buffer of
    12-byte slots, a slot's id next to its key (kernels.voxel_lookup: one cache miss a look-up, not
    two; 1.3x faster than two arrays)."""
    raw = pages.full(12 * size, 0xFF, np.uint8)  # keys EMPTY_KEY
    return np.ndarray((size,), np.uint64, raw, 0, (12,)), np.ndarray((size,), np.uint32, raw, 8, (12,))


def _stored_attributes(pool) -> dict[str, np.ndarray]:
    """The arrays the pool's attributes are stored in, by name (a constant one has none)."""
    held = {a: stored_array(pool.attributes.held(a)) for a in pool.attributes}
    return {a: v for a, v in held.items() if v is not None}


def _pool_views(pool) -> tuple[List, np.ndarray]:
    """(the pool's stored attributes as bytes, their widths in bytes): what kernels move attributes with."""
    arrays = _stored_attributes(pool).values()
    return byte_views(arrays), np.array([v.dtype.itemsize for v in arrays], np.int64)


def _attribute_views(st, pool) -> tuple[List, List, np.ndarray]:
    """(a set's attributes, the pool's, their widths in bytes): what kernels scatter attributes
    with (a set's attributes are as the pool stores them: ProgressiveOctree._stored_form)."""
    src = byte_views(np.ascontiguousarray(st.attrs[a]) for a in _stored_attributes(pool))
    return src, *_pool_views(pool)


class Pool:
    """The octree's point buffers (core/renderable.PointBuffers) in the compact layout: chunks of
    ``CHUNK`` entries, one batch and one PACK_DTYPE record each; ``n_streams`` point chunks'
    streams (``stream`` u64 words each) in ``ext``. Rewritten in place, so every write bumps
    ``version``."""

    med = high = None  # the compact layout: positions are the low word and the streams

    def __init__(self, name: str, n_chunks: int, chunk: int, attribute_forms: dict, n_streams: int):
        self.name = name
        self.chunk = chunk
        self.stream = int(stream_words(np.int64(K.WIDE_BITS), np.int64(chunk)))
        self.batches = np.zeros(n_chunks, BATCH_DTYPE)
        self.batches["first"] = np.arange(n_chunks, dtype=np.uint64) * chunk
        self.packing = np.zeros(n_chunks, PACK_DTYPE)
        self.ext = pages.zeros(n_streams * self.stream, np.uint64)
        self.packing["ext_first"] = len(self.ext)  # chunks not in use yet: empty streams at the end (streams follow chunk order)
        n = n_chunks * chunk
        self.low = pages.zeros(n, np.uint32)
        self.color = pages.zeros(n, np.uint32)
        self.attributes = Attributes()  # each held in the form of ``attribute_forms`` (core/attributes.holder_for), zeroed
        for a, form in attribute_forms.items():
            self.attributes.hold(a, zeroed_like(form, n))
        self.chunk_next = np.full(n_chunks, -1, np.int64)
        self.chunk_node = np.full(n_chunks, -1, np.int64)
        self.batch_version = np.zeros(n_chunks, np.int64)
        self.version = 0
        self.bounds = (np.zeros(3), np.zeros(3))
        self.source_scale = None  # set by the octree each frame: its grid's step while every point is on it
        self.node_is_leaf = None  # set by the octree each frame (its leaf flags): point_info tells voxels from points

    @property
    def n_points(self) -> int:
        return len(self.low)

    @property
    def n_chunks(self) -> int:
        return len(self.batches)

    @property
    def n_streams(self) -> int:
        return len(self.ext) // self.stream

    def memory(self) -> dict[str, int]:
        """Bytes per component: positions (low words and streams), colours, attributes and batch records."""
        def size(*arrays) -> int:
            return int(sum(a.nbytes for a in arrays))

        return {
            "positions": size(self.low, self.ext), "color": size(self.color), "attributes": self.attributes.nbytes,
            "batches": size(self.batches, self.packing, self.chunk_next, self.chunk_node, self.batch_version),
        }  # fmt: skip

    def grown(self, n_chunks: int, n_streams: int) -> Pool:
        """A pool of ``n_chunks`` chunks and ``n_streams`` streams holding this one's contents, or
        its first ones when smaller (new arrays: caches of the old ones are dropped by identity)."""
        new = Pool(self.name, n_chunks, self.chunk, {a: self.attributes.held(a) for a in self.attributes}, n_streams)
        k = min(self.n_chunks, n_chunks)
        n = k * self.chunk
        new.batches[:k] = self.batches[:k]
        new.packing[:k] = self.packing[:k]
        w = min(len(self.ext), len(new.ext))
        new.ext[:w] = self.ext[:w]
        new.low[:n] = self.low[:n]
        new.color[:n] = self.color[:n]
        for a, v in _stored_attributes(self).items():
            stored_array(new.attributes.held(a))[:n] = v[:n]
        new.chunk_next[:k] = self.chunk_next[:k]
        new.chunk_node[:k] = self.chunk_node[:k]
        new.batch_version[:k] = self.batch_version[:k]
        new.version = self.version + 1
        new.bounds = self.bounds
        return new

    def prefix(self, n_chunks: int, n_streams: int) -> Pool:
        """A pool of this one's first ``n_chunks`` chunks and ``n_streams`` streams, as views: no
        copy (the room cut off was never written, so it holds address space, not memory)."""
        new = object.__new__(Pool)
        new.__dict__.update(self.__dict__)
        n = n_chunks * self.chunk
        for name in ("batches", "packing", "chunk_next", "chunk_node", "batch_version"):
            setattr(new, name, getattr(self, name)[:n_chunks])
        new.low, new.color = self.low[:n], self.color[:n]
        new.attributes = self.attributes.copy()
        for a in new.attributes:
            new.attributes.hold(a, resized(self.attributes.held(a), n))
        new.ext = self.ext[: n_streams * self.stream]
        new.version = self.version + 1
        return new

    def repacked(self, ext: np.ndarray, packing: np.ndarray, attributes) -> Pool:
        """This pool with the streams ``ext`` laid out by ``packing`` and ``attributes`` (the same
        entries, held otherwise: ProgressiveOctree._pack; new arrays for the streams and their
        records, so caches of the old ones are dropped by identity)."""
        new = object.__new__(Pool)
        new.__dict__.update(self.__dict__)
        new.ext, new.packing, new.batches, new.attributes = ext, packing, self.batches[:], attributes
        new.version = self.version + 1
        return new

    def attribute_rows(self, slots: np.ndarray) -> dict:
        """The attributes of the entries at pool ``slots`` (an array or a slice), decoded."""
        return {a: self.attributes.at(a, slots) for a in self.attributes}

    def point_info(self, index: int) -> dict | None:
        """Position (rounded to ``source_scale``, the octree's grid while every point is on it),
        color, level and attributes of the entry at pool slot ``index``; None for -1 (no point)."""
        check_point_index(index, self.n_points, self.name)
        if index == -1:
            return None
        rec = self.batches[index // self.chunk]
        c = index // self.chunk
        pos = dequantize(*point_words(self, c, index, index + 1), rec["bbox_min"], rec["bbox_max"], 30, centre_half(self.packing["code"][c]))[0]
        info = {
            "position": at_scale(pos, self.source_scale),
            "rgba": self.color[index : index + 1].view(np.uint8).tolist(),
            "level": int(rec["level"]),
            "source": "progressive octree",
        }
        if self.node_is_leaf is not None:  # a voxel: an inner node's cell centre, its cell's mean colour, one of its points' attributes
            info["voxel"] = not bool(self.node_is_leaf[self.chunk_node[index // self.chunk]])
        for a, v in self.attribute_rows(np.array([index])).items():
            info[a] = v[0].item()
        return info


def _within_runs(counts: np.ndarray) -> np.ndarray:
    """0, 1, .. counts[0] - 1, 0, 1, .. counts[1] - 1, ...: each entry's place in its run."""
    return np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)


def _extended(values: np.ndarray, n: int, fill: int) -> np.ndarray:
    """``values`` with ``fill`` up to ``n`` entries (itself where it has as many)."""
    return values if len(values) >= n else np.concatenate([values, np.full(n - len(values), fill, values.dtype)])


class KeptChunks:
    """What a progressive octree draws while classes are hidden (the settings' ``hidden_classes``):
    the entries of the frame's chunks whose ``classification`` is not hidden, each chunk's a
    batch of its own in the chunk's box, in a Pool of their own (``pool``, whose slots keep
    their streams in fixed rooms, as store.Arena's do), entries as the octree's pool stores
    them (low word, stream bits, colour, attributes: they draw where they drew). A voxel stands
    for the points of its cell and has its first point's attributes, so it is hidden by that
    point's class (as Potree hides its sampled points). A chunk is filtered when a frame first
    draws it, again once it was rewritten (its ``batch_version``: entries written into it, its
    leaf reordered, a voxel's colour), and every chunk once the hidden set or the attributes'
    forms change; chunks no longer drawn give their slots back, least recently drawn first.
    Slots filtered are stamped (``version``/``batch_version``): the GPU re-uploads those alone.
    Written by ``prepare`` alone, under the octree's frame lock (no insertion meanwhile)."""

    def __init__(self, name: str, chunk: int) -> None:
        self.name, self.chunk = name, chunk
        self.pool: Pool | None = None
        self.hidden: tuple[int, ...] = ()
        self.forms: tuple = ()  # the octree's attribute forms (held_dtype) the kept entries are held in
        self.slot_of = np.empty(0, np.int64)  # per octree chunk: the slot of its kept entries (-1: none, or none kept)
        self.filtered_at = np.empty(0, np.int64)  # per octree chunk: its batch_version when filtered (-1: not filtered)
        # per octree chunk: the entries it kept and its batch_version then (-1: never filtered), known
        # after its slot is taken back (``kept_counts``: what the selection weighs it by)
        self.kept_entries = np.empty(0, np.int64)
        self.counted_at = np.empty(0, np.int64)
        self.chunk_in = np.empty(0, np.int64)  # per slot: the octree chunk whose entries it holds (-1: free)
        self.drawn_at = np.empty(0, np.int64)  # per slot: the frame that last drew it
        self.frames = 0
        self.filtered = 0  # octree chunks filtered since creation (a frame's selection knows more once it grows)

    @property
    def nbytes(self) -> int:
        """Bytes it holds: its pool and its records of chunks and slots (kept while nothing is
        hidden, so that hiding the same classes again filters nothing)."""
        records = self.slot_of, self.filtered_at, self.kept_entries, self.counted_at, self.chunk_in, self.drawn_at
        return sum(a.nbytes for a in records) + (sum(self.pool.memory().values()) if self.pool is not None else 0)

    def slots(self, source: Pool, chunks: np.ndarray, hidden: tuple[int, ...]) -> np.ndarray:
        """The slot holding each of the octree's ``chunks`` (of its pool ``source``) without its
        entries of ``hidden`` classes, filtered where it is not yet; -1 where none is kept."""
        forms = self._forms_of(source)
        if hidden != self.hidden or forms != self.forms:  # everything filtered again
            self.slot_of[:], self.filtered_at[:], self.counted_at[:], self.chunk_in[:] = -1, -1, -1, -1
            self.hidden = hidden
            if forms != self.forms:  # held otherwise (widened, packed once loaded): a pool in the new forms
                self.pool, self.forms = None, forms
                self.chunk_in = self.drawn_at = np.empty(0, np.int64)
        self.slot_of = _extended(self.slot_of, source.n_chunks, -1)
        self.filtered_at = _extended(self.filtered_at, source.n_chunks, -1)
        self.kept_entries = _extended(self.kept_entries, source.n_chunks, 0)
        self.counted_at = _extended(self.counted_at, source.n_chunks, -1)
        stale = chunks[self.filtered_at[chunks] != source.batch_version[chunks]]
        if len(stale) or self.pool is None:
            self._filter(source, stale, chunks)
        out = self.slot_of[chunks]
        self.drawn_at[out[out >= 0]] = self.frames
        self.frames += 1
        return out

    def kept_counts(self, source: Pool, hidden: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
        """(the entries of each of the octree's chunks (of its pool ``source``) as a selection
        hiding ``hidden`` knows them, which chunks it knows): a chunk filtered since it was last
        written counts the entries it kept (its slot taken back since or not), the others all
        theirs (what they keep is known once filtered)."""
        counts = source.batches["count"].astype(np.int64)
        known = np.zeros(len(counts), bool)
        if hidden != self.hidden or self._forms_of(source) != self.forms:  # (the next ``slots`` filters every chunk again)
            return counts, known
        n = min(len(self.counted_at), source.n_chunks)
        known[:n] = self.counted_at[:n] == source.batch_version[:n]
        counts[:n][known[:n]] = self.kept_entries[:n][known[:n]]
        return counts, known

    @staticmethod
    def _forms_of(source: Pool) -> tuple:
        """The forms (held_dtype) the octree's attributes are held in."""
        return tuple((a, source.attributes.held_dtype(a)) for a in source.attributes)

    def _filter(self, source: Pool, stale: np.ndarray, drawn: np.ndarray) -> None:
        """The kept entries of octree chunks ``stale`` into slots (``drawn``: the frame's chunks,
        whose slots stay)."""
        held = self.slot_of[stale]
        self.chunk_in[held[held >= 0]] = -1
        self.slot_of[stale] = -1
        counts = source.batches["count"][stale].astype(np.int64)
        position = _within_runs(counts)  # an entry's in its chunk
        entries = np.repeat(stale * self.chunk, counts) + position
        keep = ~np.isin(source.attributes.at("classification", entries), self.hidden)
        kept = np.bincount(np.repeat(np.arange(len(stale)), counts)[keep], minlength=len(stale))
        self.filtered += len(stale)
        self.kept_entries[stale], self.counted_at[stale] = kept, source.batch_version[stale]
        filled, n_kept = stale[kept > 0], kept[kept > 0]
        slots = self._room(len(filled), drawn, source)
        self.filtered_at[stale] = source.batch_version[stale]
        if not len(filled):
            return
        pool, src = self.pool, entries[keep]
        dst = np.repeat(slots * self.chunk, n_kept) + _within_runs(n_kept)
        pool.low[dst], pool.color[dst] = source.low[src], source.color[src]
        for a, values in _stored_attributes(source).items():
            stored_array(pool.attributes.held(a))[dst] = values[src]
        streams_into(source, filled, n_kept, position[keep], pool.ext, pool.packing["ext_first"][slots])
        pool.packing["code"][slots] = source.packing["code"][filled]
        records = source.batches[filled]
        records["first"], records["count"] = pool.batches["first"][slots], n_kept
        pool.batches[slots] = records
        pool.chunk_node[slots] = source.chunk_node[filled]  # (point_info: a voxel's or a point's)
        pool.version += 1
        pool.batch_version[slots] = pool.version
        self.slot_of[filled], self.chunk_in[slots] = slots, filled

    def _room(self, n: int, drawn: np.ndarray, source: Pool) -> np.ndarray:
        """``n`` free slots: those of chunks the frame does not draw taken back where too few are
        free (least recently drawn first), the pool grown where that is still too few."""
        free = np.flatnonzero(self.chunk_in < 0)
        if len(free) < n:
            held = np.flatnonzero(self.chunk_in >= 0)
            idle = held[~np.isin(self.chunk_in[held], drawn)]
            idle = idle[np.argsort(self.drawn_at[idle], kind="stable")[: n - len(free)]]
            self.slot_of[self.chunk_in[idle]] = self.filtered_at[self.chunk_in[idle]] = -1
            self.chunk_in[idle] = -1
            free = np.flatnonzero(self.chunk_in < 0)
        if self.pool is None or len(free) < n:
            size = (len(self.chunk_in) - len(free) + n) * 5 // 4 + 16  # room for the frame's chunks and a few more
            if self.pool is None:
                self.pool = Pool(self.name, size, self.chunk, {a: source.attributes.held(a) for a in source.attributes}, size)
            else:
                self.pool = self.pool.grown(size, size)
            self.pool.packing["ext_first"] = np.arange(size, dtype=np.uint64) * np.uint64(self.pool.stream)  # a slot's room
            self.chunk_in = _extended(self.chunk_in, size, -1)
            self.drawn_at = _extended(self.drawn_at, size, 0)
            free = np.flatnonzero(self.chunk_in < 0)
        return free[:n]


def _checked_grid(name: str, grid) -> tuple[np.ndarray, float] | None:
    """(anchor (3,), step) of a ``grid`` argument: a point of the grid and its step."""
    if grid is None:
        return None
    anchor, step = np.asarray(grid[0], np.float64).reshape(3), float(grid[1])
    if not (np.all(np.isfinite(anchor)) and np.isfinite(step) and step > 0):
        raise InputError(f"{name}: grid must be (a point, a positive step), got {grid!r}")
    return anchor, step


#: grid steps from the grid's point to the data beyond which float64 no longer places a cube on the grid
_GRID_REACH = 2.0**50


def _checked_cube(name: str, cube) -> tuple[np.ndarray, float] | None:
    """``cube`` as (origin float64 (3,), edge), or a one-line InputError: three finite numbers and
    a positive finite edge (5 was a TypeError; an edge of -1 or NaN was taken)."""
    if cube is None:
        return None
    try:
        origin, edge = cube
        origin, edge = np.asarray(origin, np.float64).reshape(3), float(edge)
    except (TypeError, ValueError):
        raise InputError(f"{name}: cube must be (origin x, y, z; edge), got {cube!r:.80}") from None
    if not (np.isfinite(origin).all() and np.isfinite(edge) and edge > 0):
        raise InputError(f"{name}: cube must have a finite origin and a positive finite edge, got {cube!r:.80}")
    return origin, edge


def _grid_cube(origin, edge: float, anchor, step: float) -> tuple[np.ndarray, float] | None:
    """The smallest cube holding (origin, edge) that is 2^B grid steps wide, its corner half a
    step below a grid point: each of its nodes' cubes is then 2^b steps with cell centres on the
    grid (the compact layout's boxes, core/compact.py). None where float64 cannot place it (the
    grid's point too far from the data, in steps: a header's absurd offset or scale)."""
    index = np.floor((np.asarray(origin, np.float64) - anchor) / step)
    if not np.all(np.abs(index) < _GRID_REACH) or edge / step >= _GRID_REACH:
        return None
    corner = anchor + (index - 0.5) * step
    steps = float(np.max(np.asarray(origin) + edge - corner)) / step
    return corner, 2.0 ** max(1, int(np.ceil(np.log2(steps)))) * step


def _grown_cube(origin, edge: float, lo) -> tuple[np.ndarray, float]:
    """The root cube twice the size, towards the axes where ``lo`` lies below it (what ``_grow``
    makes and ``_check_reach`` counts ahead)."""
    return origin - edge * (lo < origin), edge * 2.0


class _PackState(NamedTuple):
    """ProgressiveOctree._pack_state: the pool as trim left it, and copies of what packing reads."""

    pool: Pool
    version: int
    bits: int | None
    fill: np.ndarray
    packing: np.ndarray
    chunk_node: np.ndarray
    level: np.ndarray


def _chunk_of(parts) -> PointChunk:
    xyz = np.concatenate([p[0] for p in parts])
    rgba = np.concatenate([p[1] for p in parts]).view(np.uint8).reshape(-1, 4)
    return PointChunk(xyz, rgba, {a: np.concatenate([p[2][a] for p in parts]) for a in parts[0][2]})


def _runs(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(value, length) of each run of equal consecutive values."""
    if not len(values):
        return np.empty(0, values.dtype), np.empty(0, np.int64)
    starts = np.flatnonzero(np.concatenate([[True], values[1:] != values[:-1]]))
    return values[starts], np.diff(np.append(starts, len(values)))


_KEEP_WORK_BYTES = 256 << 20  # work arrays an octree keeps from one insertion to the next (batches up to ~3 M points)


class _Work:
    """An insertion's work arrays (sort keys, sorted codes, voxel cell entries, split leaves'
    points...): ``get(name, n, dtype)`` gives the first ``n`` rows of the array kept under
    ``name``, made anew only when a batch needs more, and kept while all kept arrays stay within
    ``keep_bytes`` (ProgressiveOctree.keep_work_bytes; None: any size, holding_work; 0: none). A large array is an mmap of
    its own that goes back to the kernel when freed, and on these VMs (the guest hands freed
    memory back to its host) touching it again costs what fresh memory does (1-2.5 ms a MB):
    made anew for each 10^6-point batch, they cost a 20 M-point insertion 1-2 s of system time
    (docs/benchmarks.md, "Ninth session"). ``trim`` and ``close`` let them go."""

    def __init__(self, keep_bytes: int | None = 0) -> None:
        self.keep_bytes = keep_bytes
        self.arrays: dict[str, np.ndarray] = {}

    def get(self, name: str, n: int, dtype, width: int = 0, room: int = 0) -> np.ndarray:
        """``room``: the rows later batches are expected to need, made at once where they fit
        within ``keep_bytes`` (an array made again as it grows has its pages faulted in again)."""
        a = self.arrays.get(name)
        if a is None or len(a) < n or a.dtype != dtype:
            rows = max(n, len(a) * 3 // 2 if a is not None else 0)
            others = self.nbytes - (a.nbytes if a is not None else 0)
            if room > rows and self.keep_bytes is not None and others + room * max(width, 1) * np.dtype(dtype).itemsize <= self.keep_bytes:
                rows = room
            new = pages.empty((rows, width) if width else rows, dtype)
            kept = others + new.nbytes
            if self.keep_bytes is None or kept <= self.keep_bytes:
                self.arrays[name] = new
            else:  # too large to keep: neither is the smaller one kept for it (no batch would use it)
                self.arrays.pop(name, None)
            a = new
        return a[:n]

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in self.arrays.values())


_U32_SUMS_BELOW = 1 << 24  # points of a set whose voxel cells' colour sums fit u32 (255 x 2^24 < 2^32)
_ENTRIES_PER_POINT = 1.5  # voxel cell entries a set's point makes, made room for at once (the town's: 0.2-1.3 at 8 M, 1.9 at 20 M)


def _entry_room(st: _Set) -> int:
    """Rows the voxel cell entries' work arrays are made with (``_Work.get``'s room): a batch in
    no spatial order makes more entries a point as the tree deepens (8 M town points in 10^6
    batches: 0.50, 0.54, 0.89, 1.23 M over the first four), and arrays grown to each made them
    again, faulting their pages in again (docs/benchmarks.md, "Voxel cell entries made room for")."""
    return int(_ENTRIES_PER_POINT * len(st.codes))


_KEY_SORT: list = []  # "numpy" or "radix": the faster here, timed once a process on a real set's keys
_TIME_SORT_FROM = 1 << 18  # keys of the first set timed (the loader's slices: 250 000 points)


def _faster_key_sort(keys: np.ndarray | None = None, index_bits: int = 0, scratch: np.ndarray | None = None) -> str:
    """numpy's sort or ``kernels.radix_sort``, whichever sorts a set's keys faster on this CPU:
    timed once, on the first set of at least _TIME_SORT_FROM keys (``keys``: sorted by the
    faster meanwhile); numpy's until then (small sets: the first image does not wait for it).
    On real keys, not random ones: the radix sort skips the digits a bucket's keys share, which
    random keys never do (AMD EPYC Zen 2, 10^6 keys: random numpy 15.0 / radix 15.2 ms, the
    town's 14.2 / 9.7 ms; the Intel Xeon's numpy 5-7 ms)."""
    if not _KEY_SORT and keys is not None and len(keys) >= _TIME_SORT_FROM:
        given, parts = keys.copy(), max(1, numba.get_num_threads())

        def numpy_sort():
            keys[:] = given
            keys.sort()

        def radix_sort():
            keys[:] = given
            K.radix_sort(keys, scratch, index_bits, parts)

        _KEY_SORT.append(fastest({"numpy": numpy_sort, "radix": radix_sort}, repeats=2))  # (keys: sorted by the last)
    return _KEY_SORT[0] if _KEY_SORT else "numpy"


def sort_keys_in_place(keys: np.ndarray, index_bits: int, scratch: np.ndarray) -> None:
    """``kernels.sort_keys``' keys sorted ascending, by the faster sort here (the same result: the
    keys are unique, and the radix sort leaves ties of their top bits in index order)."""
    if not _KEY_SORT and len(keys) >= _TIME_SORT_FROM:
        _faster_key_sort(keys, index_bits, scratch)  # (they come sorted)
    elif _faster_key_sort() == "numpy":
        keys.sort()
    else:
        K.radix_sort(keys, scratch, index_bits, max(1, numba.get_num_threads()))


class _Set:
    """Points to be routed from the nodes ``starts`` (a batch from the root; the points of the
    leaves split by a batch, each from its leaf: disjoint subtrees, so one sort and one pass of
    each kernel serve them all): their codes and colours sorted, and ``order``, where sorted
    point k is in the arrays as given (the kernels read positions and attributes through it: no
    sorted copy of them is made)."""

    __slots__ = ("attrs", "codes", "order", "rgba", "starts", "xyz")

    def __init__(self, starts, codes, order, xyz, rgba, attrs):
        self.starts, self.codes, self.order, self.xyz, self.rgba, self.attrs = starts, codes, order, xyz, rgba, attrs

    @classmethod
    def of(cls, starts, xyz, rgba, attrs: dict, origin, edge: float, work: _Work | None = None, tag: str = "") -> _Set:
        """``work``: where its arrays come from, named with ``tag`` (one per set alive at once)."""
        work = work or _Work()
        codes = point_codes(xyz, origin, edge)
        n = len(codes)
        keys = work.get("keys" + tag, n, np.uint64)
        index_bits = max(1, (n - 1).bit_length())
        K.sort_keys(codes, index_bits, keys)
        sort_keys_in_place(keys, index_bits, work.get("sort_scratch" + tag, n, np.uint64))
        order, sorted_codes = work.get("order" + tag, n, np.int64), work.get("codes" + tag, n, np.uint64)
        sorted_rgba = work.get("rgba" + tag, n, np.uint32)
        K.code_order(keys, codes, rgba, index_bits, order, sorted_codes, sorted_rgba)
        return cls(np.atleast_1d(np.asarray(starts, np.int64)), sorted_codes, order, xyz, sorted_rgba, attrs)


class ProgressiveOctree:
    """An LOD octree filled by ``add`` (or a background loader: gigapoint.open(..., progressive=True))
    and drawable at any moment (a Renderable: core/renderable.py)."""

    #: bytes of work arrays kept from one insertion to the next (_Work)
    keep_work_bytes = _KEEP_WORK_BYTES
    #: frames select and cull nodes by the box of the points below them (kept at insertion),
    #: else by their cubes (bench_progressive.py --parts select compares the two)
    select_by_points = True

    def __init__(
        self, name: str = "progressive", cube=None, max_leaf: int = MAX_LEAF, chunk: int = CHUNK, attributes: dict | None = None,
        capacity: int = 0, grid=None,
    ):  # fmt: skip
        """``cube``: (origin, edge) of the root, when the bounds are known up front (else the first
        batch's, grown as needed); ``capacity``: the points expected (the pool is sized for them,
        their voxels and some room, so it need not grow and be copied while it fills); ``grid``:
        (a point of the source's grid, its step), where the points lie on one (a LAS file's
        offset and scale): the root cube is aligned to it, and ``trim`` keeps each leaf's points
        in the bits the grid needs (core/compact.py), not 30 an axis."""
        if not (isinstance(max_leaf, int) and max_leaf >= 1):
            raise InputError(f"{name}: max_leaf must be a positive integer, got {max_leaf!r}")
        # (chunk 0 was a ZeroDivisionError, -5 an OverflowError, 10**9 a 447 GiB allocation; capacity "a" a ValueError)
        chunk = check_whole(name, "chunk", chunk, 16, 1 << 20, " points")
        capacity = check_whole(name, "capacity", capacity, 0, None, " points")
        if attributes is not None and not isinstance(attributes, dict):
            raise InputError(f"{name}: attributes must be a dict of names and dtypes, got {type(attributes).__name__}")
        cube = _checked_cube(name, cube)
        self.name = name
        self.max_leaf = max_leaf
        self.source_files: list[Path] = []  # the files a loader reads (open_progressive): save() takes their CRS
        self.colors_exact = True  # PointSource: leaves hold the points' own 32-bit colours
        self.chunk = chunk
        self.capacity = min(int(capacity), _PRESIZE_MAX)
        self.lock = FrameLock()
        self._attribute_dtypes = dict(attributes) if attributes is not None else None
        self._dropped_said: set[str] = set()  # attributes said to be left out (keep_attributes)
        self._color_bits: set[int | None] = set()  # the colours' bits of the points added (add_read): a point file's save keeps 8-bit values
        self.pool: Pool | None = None
        self.origin: np.ndarray | None = None
        self.edge = 0.0
        self.root = 0
        self.n_nodes = 0
        self.n_voxels = 0
        self.points = 0  # points added (valid ones)
        self.shown_points = 0  # ``points`` as of the last finished insertion: what n_points says (its insertion takes a split leaf's points out, then back in)
        self.skipped = 0  # invalid points left out (NaN, inf, beyond ±1e12)
        self.points_per_class = np.zeros(256, np.int64)  # of the points added, by LAS class (``class_facts``)
        self._added_colors: dict = {}  # add()'s colour range (colors_for's scalers): decided on its first colours, as a file's and a live push's
        self._colors_added = False  # whether an add() brought colours (rgb=): a save then writes colours, whatever the source files hold
        self.closed = False  # close() frees everything; add() then refuses (it would start a new tree)
        self.spilled = 0  # points taken out of split leaves to be inserted again, in all
        self.lo = np.full(3, np.inf)
        self.hi = np.full(3, -np.inf)
        self.loader = None  # the background Loader filling it (gigapoint.open(..., progressive=True))
        self._kept = KeptChunks(name, chunk)  # what frames with hidden classes draw
        self._last_kept_costs: tuple = (None, None, None)  # (what ``_kept_costs`` last answered for, its sample, its answer)
        self._nodes(_INITIAL_NODES)
        self._vox(1 << 16)
        self._hkeys, self._hvals = _voxel_table(1 << 17)
        self._run_lo = self._run_hi = self._ent_start = self._ent_count = np.empty(0, np.int64)  # sample_runs' scratch
        self._work = _Work(self.keep_work_bytes)  # insertions' work arrays, kept from one to the next
        self._holding = 0
        self._free = np.zeros(_INITIAL_CHUNKS, np.int64)
        self._n_free = 0
        self._n_chunks = 0
        self._n_words = 0  # of the pool's streams in use (``stream`` words a wide chunk, fewer a narrow one)
        self._voxel_state = True  # the voxels' build state is there (trim drops it: _rebuild_voxel_state)
        self.grid = _checked_grid(name, grid)
        self._narrow = self.grid is not None  # point chunks written on the grid (_level_bits) until a point is off it
        self._packed = False  # held as trim leaves it (_pack): unpacked before a write
        if cube is not None:
            self._start(*cube)

    # ------------------------------------------------------------------ storage
    def _nodes(self, cap: int) -> None:
        """(Re)allocate the node arrays for ``cap`` nodes, keeping the first n_nodes."""
        n = self.n_nodes
        old = getattr(self, "key", None) if n else None
        arrays = {
            "key": np.zeros(cap, np.uint64), "level": np.zeros(cap, np.int32), "parent": np.full(cap, -1, np.int64),
            "children": np.full((cap, 8), -1, np.int64), "leaf": np.zeros(cap, np.uint8), "count": np.zeros(cap, np.int64),
            "first_chunk": np.full(cap * K.LISTS, -1, np.int64), "last_chunk": np.full(cap * K.LISTS, -1, np.int64),
            "list_count": np.zeros(cap * K.LISTS, np.int64),
            "cmin": np.zeros((cap, 3)), "cedge": np.zeros(cap),
            "point_min": np.full((cap, 3), np.inf), "point_max": np.full((cap, 3), -np.inf),  # the box of the points below (none: empty)
            "grid_sample": np.zeros(cap, np.int64),  # points of a leaf's grid sample, at the head of its list (kernels.order_leaves; 0: none)
        }  # fmt: skip
        for name, arr in arrays.items():
            if old is not None:
                k = n * K.LISTS if name in ("first_chunk", "last_chunk", "list_count") else n
                arr[:k] = getattr(self, name)[:k]
            setattr(self, name, arr)

    def _vox(self, cap: int) -> None:
        n = self.n_voxels
        arrays = {"vox_slot": pages.zeros(cap, np.uint32), "vox_sum": pages.zeros((cap, 5), np.uint32)}  # keys: in the table
        for name, arr in arrays.items():
            if n:
                arr[:n] = getattr(self, name)[:n]
            setattr(self, name, arr)

    def _ensure_chunks(self, extra: int, streams: int) -> None:
        """Room for ``extra`` more chunks and ``streams`` more streams than are in use (the pool
        doubles when it grows)."""
        pool = self.pool

        def grown(have: int, need: int) -> int:
            # doubling, but by bounded steps: a memory limit is checked between inserts, so overshoot it little
            return have if need <= have else max(need, have + max(1, min(have, _GROWTH_MAX_CHUNKS)))

        chunks, n_streams = grown(pool.n_chunks, self._n_chunks + extra), grown(pool.n_streams, self._streams_in_use() + streams)
        if (chunks, n_streams) != (pool.n_chunks, pool.n_streams):
            # both by the same factor: the other runs out soon after, and each growth copies the whole pool
            f = max(chunks / pool.n_chunks, n_streams / max(pool.n_streams, 1))
            chunks, n_streams = max(chunks, int(pool.n_chunks * f)), max(n_streams, int(pool.n_streams * f))
            self.pool = pool.grown(chunks, n_streams)
        if len(self._free) < self.pool.n_chunks:
            free = np.zeros(self.pool.n_chunks, np.int64)
            free[: self._n_free] = self._free[: self._n_free]
            self._free = free

    def _streams_in_use(self) -> int:
        """Wide streams' worth of the pool's stream words in use, rounded up."""
        return -(-self._n_words // self.pool.stream)

    def _level_bits(self) -> np.ndarray:
        """Stream bits an axis of a leaf's point chunk, by the leaf's level: the bits of its cube's
        grid under the low word's (e = B - level - 10, where that is 1..10) while every point lies
        on the source's grid (``_narrow``: 15-18 bits a point at 1 mm, written as grid cells by
        kernels.write_points, not 60 to be packed later), else EXT_FULL_BITS (wide). B - level
        does not change as the root grows, so a leaf's chunks keep one code."""
        bits = np.full(CODE_BITS + 2, EXT_FULL_BITS, np.int64)
        root_bits = self._grid_bits() if self._narrow else None
        if root_bits is not None:
            e = root_bits - np.arange(len(bits)) - WORD_BITS
            narrow = (e >= 1) & (e <= EXT_FULL_BITS - WORD_BITS)
            bits[narrow] = e[narrow]
        return bits

    def _go_wide(self) -> None:
        """A point off the source's grid came: every point chunk wide from now on (its stream
        rewritten where it was written on the grid)."""
        self._narrow = False
        if self.pool is not None:
            self._restream(wide=True)

    def _restream(self, wide: bool) -> None:
        """Every point chunk's stream with room for a whole chunk, in chunk order (as insertions
        write them: ``_pack`` leaves a stream as long as its points), ``wide`` (60 bits a point)
        or in its code. Nothing to do to wide streams that were never packed."""
        pool = self.pool
        fill, pack = pool.batches["count"], pool.packing
        if wide and not np.any((pack["code"] != 0) & (pack["code"] != K.WIDE_CODE)):
            return
        packing = pack.copy()
        if wide:
            packing["code"] = np.where(pack["code"] != 0, K.WIDE_CODE, 0)
        words = stream_words(ext_bits_per_point(packing, fill), pool.chunk)
        packing["ext_first"] = np.cumsum(words) - words
        ext = pages.zeros(int(words.sum()), np.uint64)
        K.restream(fill, pack["code"], wide, pool.ext, pack["ext_first"], ext, packing["ext_first"])
        self._n_words = len(ext)
        self.pool = pool.repacked(ext, packing, pool.attributes)

    def _ensure_hash(self, extra: int, table: tuple | None = None) -> None:
        """The voxel table at most two thirds full after ``extra`` more entries (rebuilt when it
        grows; into ``table``, an empty one made beforehand, where it is large enough). Not half:
        a look-up in its 12-byte slots still reads one cache line nearly always, and a 20 M-point
        load then fits the presized table (rebuilding it took 0.4 s of 3.3)."""
        size = self._table_size(extra)
        if size is None:
            return
        old = self._hkeys, self._hvals
        self._hkeys, self._hvals = table if table is not None and len(table[0]) >= size else _voxel_table(size)
        K.rehash(*old, self._hkeys, self._hvals)

    def _table_size(self, extra: int) -> int | None:
        """The slots the voxel table grows to for ``extra`` more entries (doubling); None: it has room."""
        need = 3 * (self.n_voxels + extra) // 2
        size = len(self._hkeys)
        if need <= size:
            return None
        while size < need:
            size *= 2
        return size

    def _presize_extra(self) -> int:
        """Entries the voxel table is presized for beyond its voxels: those of the expected points.
        From the second batch on: filling it takes 0.13 s for 16 M points, which the first image
        would wait for; the first batch's few voxels are entered again in ~1 ms."""
        if not (self.capacity and self.points and self._voxel_state):
            return 0
        return max(0, int(min(self.capacity, _PRESIZE_TABLE_MAX) * _VOXELS_PER_POINT) - self.n_voxels)

    def _presized_table(self) -> tuple | None:
        """The presized voxel table, empty, where the next insertion will want it (``_presize_extra``):
        made by ``add`` before it takes the write lock, so that a frame does not wait for its fill
        either (it held up the first image of the 10^9 demo by ~0.15 s). None: not wanted."""
        extra = self._presize_extra()
        size = self._table_size(extra) if extra else None
        return None if size is None else _voxel_table(size)

    def trim(self) -> None:
        """Release the room kept for growth (the loader calls it when loading ends): the pool
        down to the chunks and streams in use, and the voxels' build state (their colour sums,
        keys, slots and table: the next ``add`` rebuilds it from the points); and pack what is
        kept (``_pack``: streams on the source's grid, attributes in their range; worked out
        outside the lock, so frames go on meanwhile: 0.3 s for 20 M points)."""
        with self.lock:
            if self.pool is None:
                return
            if self._n_chunks < self.pool.n_chunks or self._streams_in_use() < self.pool.n_streams:
                self.pool = self.pool.prefix(max(self._n_chunks, 1), self._streams_in_use())
                self._free = self._free[: self.pool.n_chunks].copy()
            self._drop_voxel_state()
            self._order_leaves()
            state = self._pack_state()
        if state is not None:
            self._pack(state)

    def order_leaves(self, max_points: int | None = None) -> bool:
        """Order leaves whose points changed since they were last ordered (all of them, or about
        ``max_points`` points' worth) so that they begin with a sample of one point a cell of
        the leaf's own 128³ grid (kernels.order_leaves): frames draw the sample alone where a
        leaf is too small on screen for all its points (store.select_octants), as a converted
        octree draws an inner node of that size and not its children. The loader does it when
        its points are in, between frames; ``trim`` does the rest. Returns whether leaves are
        left to order."""
        with self.lock.writing():
            return self._order_leaves(max_points)

    def _order_leaves(self, max_points: int | None = None) -> bool:
        self._unpack()  # (it moves 60-bit stream entries and attribute arrays)
        n = self.n_nodes
        leaves = np.flatnonzero((self.leaf[:n] == 1) & (self.grid_sample[:n] == 0) & (self.count[:n] > self.chunk))
        if not len(leaves):
            return False
        left = False
        if max_points is not None:
            take = max(1, int(np.searchsorted(np.cumsum(self.count[leaves]), max_points, side="right")))
            leaves, left = leaves[:take], take < len(leaves)
        pool = self.pool
        pool.version += 1
        K.order_leaves(leaves, self.first_chunk, pool.chunk_next, pool.batches["count"], self.list_count, pool.chunk, pool.low, pool.ext,
                       pool.packing["ext_first"], pool.packing["code"], pool.color, *_pool_views(pool), pool.batch_version, pool.version,
                       max(1, numba.get_num_threads()), self.grid_sample)  # fmt: skip
        return left

    def _grid_bits(self) -> int | None:
        """B where the root cube is 2^B steps of the source's grid (``_start`` aligned it, growing
        keeps it; a cube off the grid would only leave chunks wide: kernels.grid_widths checks
        every point); None without a grid."""
        if self.grid is None or self.origin is None:
            return None
        return round(np.log2(self.edge / self.grid[1]))

    def _pack_state(self) -> _PackState | None:
        """What ``_pack`` works from, taken under the lock: the pool, its version, and copies of
        the small arrays it reads (a concurrent ``add`` may change them). The chunks' room in
        the attributes takes a used entry's values first (their zeros would widen the range;
        no frame reads them). None: nothing to pack."""
        pool = self.pool
        if self._packed or self._n_chunks == 0:
            return None
        count = pool.batches["count"].astype(np.int64)
        if pool.attributes and count.any():
            room = pool.chunk - count
            has = np.flatnonzero(room)
            n_room = room[has]
            ends = np.cumsum(n_room)
            unused = np.repeat(has * pool.chunk + count[has] - (ends - n_room), n_room) + np.arange(int(ends[-1]) if len(ends) else 0)
            used = int(np.flatnonzero(count)[0]) * pool.chunk
            for v in _stored_attributes(pool).values():
                v[unused] = v[used]
        return _PackState(pool, pool.version, self._grid_bits(), count, pool.packing.copy(), pool.chunk_node.copy(), self.level.copy())

    def _pack(self, state: _PackState) -> None:
        """The loaded octree held as the plain cloud's layout holds points (``trim``): point chunks
        on the source's grid in the bits it needs (``_streams_on_grid``), attributes in their real
        range (core/attributes.py: a constant none, an intensity of a few hundred values a byte).
        Worked out without the lock from ``state``, and taken only if nothing was written since;
        ``_unpack`` undoes it before anything is written."""
        streams = self._streams_on_grid(state)
        attributes = None
        if state.pool.attributes and state.fill.any():
            attributes = state.pool.attributes.copy()
            for a in attributes:
                attributes.hold(a, repacked(attributes.held(a)))
        if streams is None and attributes is None:
            return
        with self.lock:
            pool = self.pool
            if pool is not state.pool or pool.version != state.version:  # an add came first: it stays as it is
                return
            ext, packing = streams or (pool.ext, pool.packing)
            self.pool = pool.repacked(ext, packing, attributes or pool.attributes)
            if streams is not None:
                self._n_words = len(ext)
            self._packed = True

    def _streams_on_grid(self, state: _PackState) -> tuple[np.ndarray, np.ndarray] | None:
        """(streams, their records) with each point chunk whose points all sit on the source's
        grid in the bits it needs (kernels.grid_widths, pack_streams: a town at 1 mm keeps 15-18
        bits a point, not 60), the others wide; None where none is. The positions drawn stay the
        same (to the last of 30 bits: the cell centre, not where truncation put a point)."""
        if state.bits is None:
            return None
        pool, fill, pack = state.pool, state.fill, state.packing
        widths = np.empty(len(fill), np.int64)
        K.grid_widths(fill, pack["code"], state.chunk_node, state.level, state.bits, pool.ext, pack["ext_first"], widths)
        if not np.any((widths > 0) & (widths < EXT_FULL_BITS)):
            return None
        words = stream_words(3 * widths, fill)
        first = np.cumsum(words) - words  # streams follow chunk order; a voxel chunk's is empty, where the next starts
        ext = pages.zeros(int(words.sum()), np.uint64)
        K.pack_streams(fill, pack["code"], widths, pool.ext, pack["ext_first"], ext, first)
        packing = pack.copy()
        packing["ext_first"], packing["code"] = first, widths | widths << 8 | widths << 16
        return ext, packing

    def _unpack(self) -> None:
        """``_pack`` undone where insertions would not write as it left them: each point chunk's
        stream room for a whole chunk again, wide unless chunks are written on the grid
        (``_narrow``: packing kept each leaf's chunks at its level's bits, as ``_level_bits``
        gives them); attributes stay as they are held (a batch they do not fit widens them,
        ``_stored_form``)."""
        if not self._packed:
            return
        self._restream(wide=not self._narrow)
        self._packed = False

    def _drop_voxel_state(self) -> None:
        """Drop the voxels' build state, and the insertions' work arrays with it."""
        self._voxel_state = False
        self._work = _Work(self._work.keep_bytes)
        self.vox_slot, self.vox_sum = np.zeros(0, np.uint32), np.zeros((0, 5), np.uint32)
        self._hkeys, self._hvals = np.zeros(0, np.uint64), np.zeros(0, np.uint32)

    def _rebuild_voxel_state(self) -> None:
        """The voxels' keys, slots and table from their lists (a voxel's cell is in its low word),
        and their colour sums from the points: every point that passed a voxel's cell is in a
        leaf below it, so sampling all of them again gives the sums the inserts had made."""
        lists = (self.inner_nodes()[:, None] * K.LISTS + np.arange(K.LISTS)).reshape(-1)
        n = self.n_voxels
        size = 1 << 17
        while size < 2 * n:
            size *= 2
        self._hkeys, self._hvals = _voxel_table(size)
        cap = max(n, 1)
        self.vox_slot, self.vox_sum = np.zeros(cap, np.uint32), np.zeros((cap, 5), np.uint32)
        pool = self.pool
        got = K.voxel_table(lists, self.first_chunk, pool.chunk_next, pool.batches["count"], pool.chunk, self.level, pool.low, self._hkeys,
                            self._hvals, self.vox_slot)  # fmt: skip
        assert got == n, (got, n)
        self._voxel_state = True
        if n:
            st = _Set.of(self.root, *self._all_points(), self.origin, self.edge)
            _, node, cell, _, sums = self._voxel_cells(st, *self._distribute(st))
            vid = np.empty(len(node), np.int64)
            is_new = np.empty(len(node), np.uint8)
            assert K.voxel_ids(self._hkeys, self._hvals, node, cell, n, vid, is_new, 1) == n  # every cell is a voxel already
            K.set_voxel_sums(self.vox_sum, vid, sums)

    def _start(self, origin: np.ndarray, edge: float) -> None:
        """The root cube (aligned to the source's grid where there is one), and the root: an empty leaf."""
        edge = edge if edge > 0 else 1.0
        cube = _grid_cube(origin, edge, *self.grid) if self.grid is not None else None
        if cube is None:
            self.grid = None  # (none, or one float64 cannot place this cube on): points stay wide
        else:
            origin, edge = cube
        self.origin, self.edge = origin, edge
        self.key[0], self.level[0], self.leaf[0], self.count[0] = 1, 0, 1, 0
        self.children[0] = -1
        self._clear_lists(0)
        self.cmin[0], self.cedge[0] = self.origin, self.edge
        self.root, self.n_nodes = 0, 1

    def _clear_lists(self, node: int) -> None:
        lists = slice(node * K.LISTS, (node + 1) * K.LISTS)
        self.first_chunk[lists] = self.last_chunk[lists] = -1
        self.list_count[lists] = 0

    def _list_slots(self, lst: int) -> np.ndarray:
        """Pool slots of the entries of list ``lst`` (node lst // LISTS), in order."""
        pool = self.pool
        slots = np.empty(int(self.list_count[lst]), np.int64)
        k = K.list_slots(self.first_chunk, pool.chunk_next, pool.batches["count"], pool.chunk, lst, slots)
        return slots[:k]

    # ------------------------------------------------------------------ loading
    def attach(self, loader) -> None:
        self.loader = loader

    @property
    def load_progress(self) -> float:
        """0..1: how much of its sources is read (1 without a loader)."""
        return 1.0 if self.loader is None else self.loader.progress

    progress = load_progress

    @property
    def loading(self) -> bool:
        return self.loader is not None and not self.loader.done

    @property
    def points_per_second(self) -> float:
        """Input points read per second since loading started (0 without a loader)."""
        return 0.0 if self.loader is None else self.loader.points_per_second

    @property
    def error(self):
        """The error that stopped loading (one line, naming the file), or None."""
        return None if self.loader is None else self.loader.error

    @property
    def warnings(self) -> tuple[str, ...]:
        """The load's warnings so far (one line each, naming the file), in order; ``wait`` and
        ``close`` issue them in the caller's thread, each once."""
        return () if self.loader is None else tuple(message for message, _ in self.loader.warnings)

    def wait(self, timeout: float | None = None) -> bool:
        """Until the loader has read everything (True) or ``timeout`` passes, or ``close`` stopped
        it part-way (False); raises the error that stopped it, if any. What was inserted before an
        error stays drawable."""
        timeout = check_timeout(f"{self.name}: wait", timeout)
        return True if self.loader is None else self.loader.wait(timeout)

    def close(self) -> None:
        """Stop loading and free the octree's memory (it draws nothing afterwards)."""
        if self.loader is not None:
            self.loader.close()
        with self.lock:
            self.closed = True
            self.pool, self._packed = None, False
            self._kept = KeptChunks(self.name, self.chunk)
            self._n_chunks = self._n_free = self._n_words = 0
            self._narrow = self.grid is not None
            self.origin = None
            self.points = self.shown_points = self.n_nodes = self.n_voxels = 0
            self.points_per_class = np.zeros(256, np.int64)
            self._nodes(1)
            self._drop_voxel_state()

    @property
    def nbytes(self) -> int:
        """Bytes the octree holds (the sum of ``memory()``)."""
        return sum(self.memory().values())

    layout = "progressive octree"  # what `--stats` and `gigapoint info` call its memory layout

    def memory(self) -> dict[str, int]:
        """Bytes per component: the pool's positions (low words and streams), colours, attributes
        and batch records (points and voxels, with the room kept for growth), the voxels' colour
        sums and lookup table (build state, none once trimmed), the nodes, and the copies of
        chunks without hidden classes that frames drew (``kept``: KeptChunks, until closed)."""
        def size(*arrays) -> int:
            return int(sum(a.nbytes for a in arrays))

        pool = self.pool
        m = pool.memory() if pool is not None else {"positions": 0, "color": 0, "attributes": 0, "batches": 0}
        m["voxels"] = size(self.vox_slot, self.vox_sum, self._hkeys, self._hvals)
        m["work"] = self._work.nbytes  # insertions' work arrays kept (address space: the rows touched are the largest batch's)
        m["nodes"] = size(self.key, self.level, self.parent, self.children, self.leaf, self.count, self.first_chunk, self.last_chunk,
                          self.list_count, self.cmin, self.cedge, self.grid_sample, self._free)  # fmt: skip
        m["kept"] = self._kept.nbytes
        return m

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ facts (Renderable)
    @property
    def n_points(self) -> int:
        """Points added so far (read without the lock: never the count of an insertion under way)."""
        return self.shown_points

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        if self.points == 0:
            return np.zeros(3), np.zeros(3)
        return self.lo.copy(), self.hi.copy()

    @property
    def attributes(self) -> dict:
        return self.pool.attributes if self.pool is not None else {}

    @property
    def attribute_names(self) -> tuple[str, ...]:
        """The attributes the points hold (fixed by the first ``add``; none before it)."""
        return () if self._attribute_dtypes is None else tuple(self._attribute_dtypes)

    def held_of(self, attributes: dict) -> dict:
        """Those of a batch's ``attributes`` the octree holds (all of them before the first
        ``add``): what a source whose batches may bring others passes to ``add``."""
        held = self._attribute_dtypes
        return dict(attributes) if held is None else {a: v for a, v in attributes.items() if a in held}

    def class_facts(self) -> dict:
        """The LAS classes its points hold, counted as they were added (``points_per_class``):
        the viewer's Classes panel lists them, more as a loader brings points of others (as
        ``OctreeCloud.class_facts``); {} without classification."""
        if "classification" not in self.attribute_names:
            return {}
        return {"classes": np.flatnonzero(self.points_per_class).tolist()}

    @property
    def batches(self) -> np.ndarray:
        """One record per node (stats: ``batches_total`` counts nodes, as for a converted octree)."""
        return self.key[: self.n_nodes]

    def __len__(self) -> int:
        return self.shown_points

    def __repr__(self) -> str:
        state = ""
        if self.closed:
            state = ", closed"
        elif self.error is not None:
            state = ", loading stopped: " + str(self.error)
        elif self.loading:
            state = f", loading: {self.progress:.0%} read" if self.loader.total else ", loading"
        return f"ProgressiveOctree({self.name!r}, {self.points:,} points, {self.n_nodes:,} node{'' if self.n_nodes == 1 else 's'}, {self.n_voxels:,} voxels{state})"

    # ------------------------------------------------------------------ adding points
    def wait_first_points(self) -> None:
        """Until the loading sources' first points are in, or their load has ended: those points fix
        the attributes (``attribute_names``: none before them)."""
        if self.loader is not None:
            self.loader.wait_first_points()

    def add(self, xyz, rgb=None, **attributes) -> int:
        """Insert points (float64 (N, 3); colors (N, 3|4) uint8/uint16/float; 1-D attributes of
        length N). Invalid points (NaN, inf, beyond ±1e12) are skipped and counted. Returns the
        number inserted. Attributes are those of the first call with a valid point; later calls fill missing ones with 0
        and may not bring others (InputError); an attribute whose dtype cannot hold a batch's
        widens to numpy's dtype for both (uint16 and float32: float32), as ``gp.open`` of
        several files does. While a loader fills the octree, an add waits for the files' first
        points, whose attributes are the set."""
        added = self.add_read(xyz, rgb, attributes, None)
        self._colors_added = self._colors_added or (rgb is not None and added > 0)
        return added

    def add_read(self, xyz, rgb, attributes: dict, color_bits: int | None) -> int:
        """``add`` of points read from a file whose colours were ``color_bits``-bit values
        (PointChunk.color_bits; None: not a file's, as ``add``'s): a LAS file of 8-bit values in
        16-bit fields is saved into a point file as it was, not x 257 (as a plain cloud's save)."""
        xyz = np.ascontiguousarray(points_for(xyz, self.name), np.float64)
        n = len(xyz)
        if n == 0:
            return 0
        self.wait_first_points()
        with threads_for(n, when_awake=False):  # a small batch on this thread alone: waking the others costs more (core/threads.py)
            added = self._add(xyz, rgb, attributes)
        if added:  # (a batch refused adds no colours: its bits do not count)
            self._color_bits.add(color_bits)
        return added

    def _add(self, xyz, rgb, attributes: dict) -> int:
        n = len(xyz)
        if rgb is None:
            rgba = np.full(n, np.array([200, 200, 200, 255], np.uint8).view(np.uint32)[0], np.uint32)
        else:
            rgba = colors_for(rgb, n, self.name, self._added_colors).view(np.uint32).reshape(-1)
        attrs = {}
        for a, v in attributes.items():
            v = np.asarray(v)
            if v.ndim != 1 or len(v) != n:
                raise InputError(f"{self.name}: attribute {a!r} must be 1-D of length {n}, got shape {v.shape}")
            problem = attribute_name_problem(a) or attribute_dtype_problem(a, v)
            if problem:
                raise InputError(f"{self.name}: {problem}")
            attrs[a] = v
        valid, lo, hi = valid_bounds(xyz, MAX_ABS_COORDINATE)
        n_valid = int(np.count_nonzero(valid))
        table = self._presized_table()  # filled before the lock is taken: frames meanwhile draw
        classes = class_histogram(np.asarray(attrs["classification"])[valid]) if "classification" in attrs else None  # (likewise)
        with self.lock.writing():
            if self.closed:
                raise InputError(f"{self.name}: the octree is closed; open it again to add points")
            if n_valid == 0 and self._attribute_dtypes is None:  # an all-NaN first batch fixed no attributes
                self.skipped += n
                return 0
            if n_valid:
                self._check_reach(lo, hi)  # before the root grows as far as it can: a batch refused changes nothing
            attrs = self._attribute_set(attrs, n)  # before anything counts: a batch it refuses changes nothing
            self.skipped += n - n_valid
            if n_valid == 0:
                return 0
            if n_valid < n:
                xyz, rgba = xyz[valid], rgba[valid]
                attrs = {a: v[valid] for a, v in attrs.items()}
            self._insert(xyz, rgba, attrs, lo, hi, table)
            if classes is not None and "classification" in attrs:  # (kept by the attribute set; a new array, not added in place: read without the lock)
                self.points_per_class = self.points_per_class + classes
        return n_valid

    def expect(self, sample, weight: float) -> int:
        """Shape the tree for points to come, of which ``sample`` (float64 (N, 3)) is a sample,
        each of its points standing for ``weight`` of them: the leaves they would overflow are
        split now, level by level, so that those points go straight to the leaves they end in
        instead of filling a leaf, spilling out of it and being inserted again (a snapshot of
        18 M points spilled 61 % of them; a second snapshot into the same tree 65 %). A leaf that
        holds points has them moved once, to the leaves they end in under the new shape; a leaf
        the sample underestimates splits as usual later. The root cube must be set (given, or by
        an earlier ``add``); sample points outside it are left out. Returns the leaves split."""
        sample = np.ascontiguousarray(sample, np.float64)
        if sample.ndim != 2 or sample.shape[1:] != (3,):
            raise InputError(f"{self.name}: expect: the sample must have shape (N, 3), got {sample.shape}")
        if not (isinstance(weight, (int, float, np.integer, np.floating)) and np.isfinite(weight) and weight > 0):
            raise InputError(f"{self.name}: expect: weight must be a positive finite number of points, got {weight!r}")
        if self.origin is None or not len(sample):
            return 0
        inside = np.all((sample >= self.origin) & (sample <= self.origin + self.edge), axis=1)
        sample = sample[inside]
        if not len(sample):
            return 0
        with self.lock.writing():
            self._unpack()  # split leaves' points are written again
            if self.pool is not None and not self._voxel_state:
                self._rebuild_voxel_state()  # spilled points are sampled into voxels again
            inner_before = int(np.count_nonzero(self.leaf[: self.n_nodes] == 0))
            sets = [_Set.of(self.root, sample, np.zeros(len(sample), np.uint32), {}, self.origin, self.edge, _Work(), "s")]
            routes = self._route(sets, [float(weight)])
            if len(sets) > 1:  # leaves that held points, split: their points go to the leaves they end in now
                self._write_sets(sets[1:], routes[1:])
            return int(np.count_nonzero(self.leaf[: self.n_nodes] == 0)) - inner_before

    @contextmanager
    def holding_work(self):
        """Keep the insertions' work arrays from one ``add`` to the next, whatever their size (not
        only up to _KEEP_WORK_BYTES), until the block ends: many large batches in a row
        (LiveCloud.snapshot's). ``memory()`` counts them as ``work``."""
        with self.lock:
            self._holding += 1
            if self._holding == 1:
                self._work = _Work(None)
        try:
            yield self
        finally:
            with self.lock:
                self._holding -= 1
                if self._holding == 0:
                    self._work = _Work(self.keep_work_bytes)

    def reading(self):
        """Held while a frame reads what ``prepare`` returned: no insertion moves it meanwhile
        (core/framelock.py: frames first, insertions between them)."""
        return self.lock.reading()

    def builder_turn(self, seen: int) -> tuple[int, bool]:
        """The loader's turn (SimLOD's schedule): FrameLock.builder_turn."""
        return self.lock.builder_turn(seen)

    def _attribute_set(self, attrs: dict, n: int) -> dict:
        """The batch's attributes in the octree's set (fixed by the first batch), in its dtypes:
        missing ones 0; one outside the set is an InputError; a dtype that cannot hold the
        batch's widens (``_stored_form`` then widens the pool's holder)."""
        if self._attribute_dtypes is None:
            self._attribute_dtypes = {a: v.dtype for a, v in attrs.items()}
        unknown = sorted(set(attrs) - set(self._attribute_dtypes))
        if unknown:
            held = ", ".join(self._attribute_dtypes) or "none"
            raise InputError(f"{self.name}: attribute {unknown[0]!r} is not one of this cloud's ({held}): the first add() fixes them")
        for a, v in attrs.items():
            dt = self._attribute_dtypes[a]
            if v.dtype != dt and not np.can_cast(v.dtype, dt, "safe"):
                self._attribute_dtypes[a] = np.result_type(dt, v.dtype)
        return {a: (attrs[a].astype(dt, copy=False) if a in attrs else np.zeros(n, dt)) for a, dt in self._attribute_dtypes.items()}

    def keep_attributes(self, names) -> None:
        """Hold only the attributes among ``names``; points already in lose the others (a loader
        of several files keeps those every file has, as ``gigapoint.open`` of them does). Those
        left out, either way, are said once (``warn_dropped_attributes``)."""
        held = self._attribute_dtypes
        extra = {a for a in names if held is not None and a not in held} - self._dropped_said
        self._dropped_said |= extra
        warn_dropped_attributes(self.name, extra)
        if not any(a not in names for a in held or {}):
            return
        with self.lock.writing():
            gone = [a for a in self._attribute_dtypes if a not in names]
            for a in gone:
                del self._attribute_dtypes[a]
                if self.pool is not None and a in self.pool.attributes:
                    del self.pool.attributes[a]
            if gone and self.pool is not None:
                self.pool.version += 1  # a packing worked out meanwhile held them: it is dropped (_pack)
            if "classification" in gone:
                self.points_per_class = np.zeros(256, np.int64)
        self._dropped_said |= set(gone)
        warn_dropped_attributes(self.name, gone)

    def _insert(self, xyz, rgba, attrs, lo, hi, table: tuple | None = None) -> None:
        """Valid points with their attributes in the octree's set (``_attribute_set``) in."""
        n = len(xyz)
        self._unpack()
        if self.pool is None:
            expected = int(self.capacity * _ROOM_PER_POINT) // self.chunk
            streams = int(self.capacity * _STREAMS_PER_POINT * (0.5 if self._narrow else 1.0)) // self.chunk  # (narrow: 30 bits a point at most)
            forms = {a: holder_for(v, 0) for a, v in attrs.items()}
            self.pool = Pool(self.name, max(_INITIAL_CHUNKS, expected), self.chunk, forms, max(_INITIAL_CHUNKS, streams))
            if self.capacity:  # room for the expected voxels too: growing their arrays and table copies them
                self._vox(max(len(self.vox_slot), int(self.capacity * _VOXELS_PER_POINT)))
        attrs = self._stored_form(attrs, n)
        if not self._voxel_state:
            self._rebuild_voxel_state()
        else:
            self._ensure_hash(self._presize_extra(), table)
        outside = self.origin is not None and (np.any(lo < self.origin) or np.any(hi > self.origin + self.edge))
        if self.origin is None or outside and self.n_nodes == 1:
            # the root is one leaf still: a cube around its points and these (a header's zeros: the cube given misses
            # the points; a first batch of one point: a cube 2e-11 wide, still 4e-5 wide once grown its CODE_BITS
            # levels, so a point a metre away was refused)
            if self.points:
                held_xyz, held_rgba, held_attrs = self._split(np.array([self.root]), "r")
                xyz, rgba = np.concatenate([held_xyz, xyz]), np.concatenate([held_rgba, rgba])
                attrs = {a: np.concatenate([held_attrs[a], v]) for a, v in attrs.items()}
                lo, hi = np.minimum(lo, self.lo), np.maximum(hi, self.hi)
            pad = 0.01 * max(float(np.max(hi - lo)), 1e-9)  # a little room: growing the root costs a pass over every point
            self._start(lo - pad, float(np.max(hi - lo)) + 2 * pad)
        while np.any(lo < self.origin) or np.any(hi > self.origin + self.edge):
            self._grow(lo, hi)
        if self._narrow and (self.grid is None or not K.on_grid(xyz, self.grid[0], self.grid[1], GRID_TOLERANCE)):
            self._go_wide()
        sets = [_Set.of(self.root, xyz, rgba, attrs, self.origin, self.edge, self._work, "0")]
        self._write_sets(sets, self._route(sets, [1.0]))
        self.lo, self.hi = np.minimum(self.lo, lo), np.maximum(self.hi, hi)
        self.pool.bounds = self.bounds

    def _stored_form(self, attrs: dict, n: int) -> dict:
        """A batch's attributes as the pool stores them (core/attributes.py: a holder the batch
        does not fit is widened first, its entries so far copied once), constant ones left out:
        what kernels move as bytes."""
        pool, out = self.pool, {}
        for a, v in attrs.items():
            held = pool.attributes.held(a)
            if held.dtype != v.dtype or not fits(held, v):  # (another dtype: _attribute_set widened the set's)
                held = widened(held, v, self._n_chunks * self.chunk)
                pool.attributes.hold(a, held)
            s = stored_array(held)
            if s is not None:
                out[a] = encode(held, v, self._work.get("attr." + a, n, s.dtype))
        return out

    def _route(self, sets: list, weights: list) -> list:
        """Route ``sets`` (each of its points standing for ``weights[i]`` points) until no leaf
        would overflow: a leaf that would is split, and its stored points are spilled, one more
        set (weight 1, appended to ``sets``) routed from that leaf down; a leaf created on the
        way holds nothing to spill. Returns every set's (leaf runs, inner runs)."""
        while True:
            routes = [self._distribute(st) for st in sets]
            incoming = np.zeros(self.n_nodes)
            for (leaf_runs, _), w in zip(routes, weights):
                np.add.at(incoming, leaf_runs[:, 0], (leaf_runs[:, 2] - leaf_runs[:, 1]) * w)
            hit = np.flatnonzero(incoming)
            over = hit[(self.count[hit] + incoming[hit] > self.max_leaf) & (self.level[hit] < CODE_BITS)]
            if not len(over):
                return routes
            stored = over[self.count[over] > 0]
            self.leaf[over[self.count[over] == 0]] = 0  # created by these sets: nothing stored to spill
            if len(stored):
                tag = str(len(sets))
                sets.append(_Set.of(stored, *self._split(stored, tag), self.origin, self.edge, self._work, tag))
                weights.append(1.0)

    def _write_sets(self, sets: list, routes: list) -> None:
        """The routed sets' points into their leaves and voxels."""
        self.pool.version += 1
        for st, (leaf_runs, inner_runs) in zip(sets, routes):
            self._sample(st, leaf_runs, inner_runs)
            self._write_points(st, leaf_runs)
            self.points += len(st.codes)  # a batch, or the points spilled from split leaves
        self.shown_points = self.points

    def _distribute(self, st: _Set) -> tuple[np.ndarray, np.ndarray]:
        """(leaf runs, inner runs) of a set's sorted codes routed from its start nodes, growing
        the node arrays as needed."""
        codes, starts = st.codes, st.starts
        roots = np.empty((len(starts), 3), np.int64)
        roots[:, 0] = starts
        if len(starts) == 1:
            roots[0, 1:] = 0, len(codes)
        else:  # each start's codes: one run, the runs in code order and covering every code
            by_code = np.argsort(morton_position(self.key[starts], self.level[starts]))
            roots = roots[by_code]
            lev = self.level[roots[:, 0]].astype(np.uint64)
            prefix = self.key[roots[:, 0]] ^ (np.uint64(1) << (np.uint64(3) * lev))
            first = prefix << (np.uint64(3) * (np.uint64(CODE_BITS) - lev))
            roots[:, 1] = np.searchsorted(codes, first)
            roots[0, 1] = 0
            roots[:-1, 2] = roots[1:, 1]
            roots[-1, 2] = len(codes)
        while True:
            cap = len(self.key)
            leaf_runs = np.empty((cap, 3), np.int64)
            inner_runs = np.empty((cap, 3), np.int64)
            nl, ni, n_nodes = K.distribute(codes, roots, self.key, self.level, self.parent, self.children, self.leaf, self.count,
                                           self.first_chunk, self.last_chunk, self.cmin, self.cedge, self.n_nodes, leaf_runs, inner_runs)  # fmt: skip
            self.n_nodes = n_nodes
            if nl >= 0:
                return leaf_runs[:nl], inner_runs[:ni]
            self._nodes(2 * cap)

    def _split(self, nodes: np.ndarray, tag: str):
        """Turn the leaves ``nodes`` into (empty) inner nodes; their points come back, to be
        inserted again (in work arrays named with ``tag``)."""
        pool = self.pool
        w = self._work
        slots = np.concatenate([self._list_slots(node * K.LISTS) for node in nodes.tolist()])
        n = len(slots)
        xyz = self._decode(slots, w.get("xyz" + tag, n, np.float64, 3))
        # numpy's gathers: a few 10^5 points, not worth a parallel region each ("clip": not buffered)
        rgba = np.take(pool.color, slots, out=w.get("split_rgba" + tag, n, np.uint32), mode="clip")
        attrs = {a: np.take(v, slots, out=w.get(f"{a}_{tag}", n, v.dtype), mode="clip") for a, v in _stored_attributes(pool).items()}
        for node in nodes.tolist():
            self._n_free = K.free_chunks(
                self.first_chunk, self.last_chunk, pool.chunk_next, pool.batches["count"], node * K.LISTS, self._free, self._n_free
            )
        self.list_count[nodes * K.LISTS] = 0
        self.leaf[nodes] = 0
        self.count[nodes] = 0
        self.grid_sample[nodes] = 0
        self.points -= len(slots)  # they are counted again when inserted again
        self.spilled += len(slots)
        return xyz, rgba, attrs

    def _allocate(self, lists: np.ndarray, counts: np.ndarray, points: bool) -> np.ndarray:
        """Pool slots for counts[j] new entries of list lists[j], in order (leaves' points, or
        inner nodes' voxels); the counts go up."""
        pool = self.pool
        extra = K.chunks_needed(lists, counts, pool.chunk, self.last_chunk, pool.batches["count"])
        self._ensure_chunks(extra, extra if points else 0)
        pool = self.pool
        slots = np.empty(int(counts.sum()), np.int64)
        b, pk = pool.batches, pool.packing
        self._n_free, self._n_chunks, self._n_words = K.allocate(
            lists, counts, pool.chunk, self.first_chunk, self.last_chunk, self.level, self.leaf, self.cmin, self.cedge, b["count"],
            pool.chunk_next, pool.chunk_node, b["bbox_min"], b["bbox_max"], b["level"], pk["ext_first"], pk["code"], pool.ext,
            self._level_bits() if points else _NO_BITS, self._free, self._n_free, self._n_chunks, self._n_words, pool.version,
            pool.batch_version, slots,
        )  # fmt: skip
        np.add.at(self.list_count, lists, counts)
        np.add.at(self.count, lists // K.LISTS, counts)
        return slots

    def _write_points(self, st: _Set, leaf_runs) -> None:
        """The routed points into their leaves (leaf runs are in code order: slots follow)."""
        counts = leaf_runs[:, 2] - leaf_runs[:, 1]
        self.grid_sample[leaf_runs[:, 0]] = 0  # new points: the leaf's sample no longer covers them all
        slots = self._allocate(leaf_runs[:, 0] * K.LISTS, counts, points=True)  # a leaf's points: its list 0
        offsets = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
        pool = self.pool
        src, dst, width = _attribute_views(st, pool)
        run_min, run_max = np.empty((len(leaf_runs), 3)), np.empty((len(leaf_runs), 3))
        K.write_points(st.xyz, st.rgba, src, dst, width, st.order, leaf_runs, offsets, slots, self.cmin, self.cedge, pool.low, pool.ext,
                       pool.packing["ext_first"], pool.packing["code"], pool.chunk, pool.color, run_min, run_max)  # fmt: skip
        K.grow_bounds(leaf_runs, run_min, run_max, self.parent, self.point_min, self.point_max)

    def _voxel_cells(self, st: _Set, leaf_runs, inner_runs, only: int | None = None):
        """(count, list, cell, first point, colour sums) of each voxel cell of the inner nodes
        (of node ``only``) the routed points pass (kernels.sample_runs: each level's nodes spread
        over the threads, their entries' places counted first, kernels.cell_counts)."""
        if len(self._run_lo) < len(self.key):
            self._run_lo = np.full(len(self.key), -1, np.int64)
            self._run_hi = np.full(len(self.key), -1, np.int64)
            self._ent_start = np.zeros(len(self.key), np.int64)
            self._ent_count = np.zeros(len(self.key), np.int64)
        w = self._work
        ni = len(inner_runs)
        counts = np.empty(ni, np.int64)
        K.cell_counts(st.codes, inner_runs, self.level, counts)
        ends = np.cumsum(counts[::-1])[::-1]  # children before parents: a run's entries follow those of the runs after it
        m = int(ends[0]) if ni else 0
        self._ent_start[inner_runs[:, 0]], self._ent_count[inner_runs[:, 0]] = ends - counts, counts
        bins = max(1, numba.get_num_threads()) if len(st.codes) >= _PARALLEL_CELLS else 1
        tasks, group_start = np.empty(ni, np.int64), np.empty(ni * bins + 1, np.int64)
        groups = K.plan_levels(inner_runs, self.level, bins, tasks, group_start)
        room = _entry_room(st)
        e_cell, e_local = w.get("e_cell", m, np.uint64, room=room), w.get("e_local", m, np.uint64, room=room)
        e_first, e_node = w.get("e_first", m, np.int64, room=room), w.get("e_node", m, np.int64, room=room)
        # colour sums: 255 times a set's points fits u32 under 2^24 points (20 bytes an entry, not 40); else u64
        e_sum = w.get("e_sum", m, np.uint32 if len(st.codes) < _U32_SUMS_BELOW else np.uint64, 5, room=room)
        K.sample_runs(st.codes, st.rgba, st.order, inner_runs, leaf_runs, self._ent_start, self._ent_count, tasks, group_start, groups, bins,
                      self.level, self.leaf, self.children, self._run_lo, self._run_hi, e_cell, e_first, e_sum, e_node, e_local)  # fmt: skip
        if only is not None:
            s0, c0 = int(self._ent_start[only]), int(self._ent_count[only])
            entries = slice(s0, s0 + c0)
        else:
            entries = slice(0, m)
        node = e_node[entries]
        return len(node), node, e_local[entries], e_first[entries], e_sum[entries]

    def _sample(self, st: _Set, leaf_runs, inner_runs, only: int | None = None) -> None:
        """Voxels of the inner nodes the routed points pass (of node ``only``): new cells become
        voxels, every touched voxel's colour the mean of all the points that fell into it."""
        if not len(inner_runs):
            return
        m, node, cell, first, sums = self._voxel_cells(st, leaf_runs, inner_runs, only)
        if m == 0:
            return
        room = _entry_room(st)
        vid, is_new = self._work.get("vid", m, np.int64, room=room), self._work.get("is_new", m, np.uint8, room=room)
        n_new = K.voxel_lookup(self._hkeys, self._hvals, node, cell, vid, is_new)
        self._ensure_hash(n_new)  # room for the new voxels (a rebuilt table keeps every id found)
        next_vid = K.voxel_enter(self._hkeys, self._hvals, node, cell, self.n_voxels, vid, is_new, max(1, numba.get_num_threads()))
        if next_vid > len(self.vox_slot):
            cap = max(len(self.vox_slot), 1)
            while cap < next_vid:
                cap *= 2
            self._vox(cap)
        # entries come list by list (node by node, octant by octant): so do the new ones, and their slots
        new = np.flatnonzero(is_new)
        new_lists, new_counts = _runs(node[new])
        slots = self._allocate(new_lists, new_counts, points=False) if len(new) else np.empty(0, np.int64)
        first_new = self.n_voxels
        self.n_voxels = next_vid
        pool = self.pool
        K.write_voxels(vid, is_new, node, cell, sums, self.level, slots, first_new, self.vox_sum, self.vox_slot, pool.low,
                       pool.color, pool.batch_version, pool.chunk, pool.version)  # fmt: skip
        if len(new) and pool.attributes:  # a new voxel's attributes: its cell's first point's
            K.scatter_rows(*_attribute_views(st, pool), first[new], slots)

    def _check_reach(self, lo, hi) -> None:
        """A one-line InputError unless the root can grow (``_grow``, as often as its deepest node
        allows) to take ``lo..hi``."""
        if self.origin is None or self.n_nodes == 1:  # a root that is one leaf is made again around the points (_insert)
            return
        origin, edge, grows = self.origin, self.edge, 0
        while np.any(lo < origin) or np.any(hi > origin + edge):
            origin, edge = _grown_cube(origin, edge, lo)
            grows += 1
        if grows and int(self.level[: self.n_nodes].max()) + grows > CODE_BITS:
            raise InputError(f"{self.name}: points span more than the octree's {CODE_BITS} levels resolve; give the bounds up front")

    def _grow(self, lo, hi) -> None:
        """A root twice the size with the old one as a child, towards the points outside."""
        below = lo < self.origin
        d = int(below[0]) << 2 | int(below[1]) << 1 | int(below[2])
        n = self.n_nodes
        lev = self.level[:n].astype(np.uint64)
        prefix = self.key[:n] ^ (np.uint64(1) << (np.uint64(3) * lev))
        self.key[:n] = (np.uint64(1) << (np.uint64(3) * (lev + np.uint64(1)))) | (np.uint64(d) << (np.uint64(3) * lev)) | prefix
        self.level[:n] += 1
        if self.pool is not None:
            used = self.pool.batches["count"] > 0
            self.pool.batches["level"][used] += 1
        if n >= len(self.key):
            self._nodes(2 * len(self.key))
        old = self.root
        self.origin, self.edge = _grown_cube(self.origin, self.edge, lo)
        self.key[n], self.level[n], self.leaf[n], self.count[n], self.parent[n] = 1, 0, 0, 0, -1
        self.children[n] = -1
        self.children[n, d] = old
        self._clear_lists(n)
        self.cmin[n], self.cedge[n] = self.origin, self.edge
        self.point_min[n], self.point_max[n] = self.point_min[old], self.point_max[old]
        self.parent[old] = n
        self.root, self.n_nodes = n, n + 1
        if self.pool is not None and self.points:  # the new root's voxels: every point seen so far passed it
            st = _Set.of(n, *self._all_points(), self.origin, self.edge)
            self.pool.version += 1
            self._sample(st, *self._distribute(st), only=n)

    def _all_points(self):
        """(xyz, rgba, attributes as stored) of every point in the leaves."""
        pool = self.pool
        slots = np.concatenate([self._list_slots(node * K.LISTS) for node in self.leaves().tolist()])
        return self._decode(slots), take(pool.color, slots), {a: take(v, slots) for a, v in _stored_attributes(pool).items()}

    # ------------------------------------------------------------------ saving
    def chunks(self, points_per_chunk: int = 1_000_000, leaves_of=None):
        """The points of the leaves as PointChunks (positions, colours, attributes), leaf by leaf,
        once loading has finished; one line of error if the octree changes meanwhile (``_check_unchanged``).
        ``leaves_of``: those of the leaves it picks (given the leaves and their cubes' corners and
        edges, it returns which: a tool reading a region, lod/query.py), not all."""
        self.check_loaded("read its points")
        with self.lock:
            leaves = self.leaves()
            if leaves_of is not None:
                leaves = leaves[leaves_of(leaves, self.cmin[leaves], self.cedge[leaves])]
            leaves = leaves.tolist()
            stamp = self._stamp()
        parts, held = [], 0
        for node in leaves:
            with self.lock:
                self._check_unchanged(stamp)
                slots = self._list_slots(node * K.LISTS)
                part = (self._decode(slots), self.pool.color[slots], self.pool.attribute_rows(slots))
            parts.append(part)
            held += len(slots)
            if held >= points_per_chunk:
                yield _chunk_of(parts)
                parts, held = [], 0
        if parts:
            yield _chunk_of(parts)

    def save(self, out, format: str | None = None, overwrite: bool = False, **options):
        """Write the octree as a converted octree folder (gigapoint, potree) or a COPC file
        through ``gigapoint.convert`` (``format`` None: copc for a .copc.laz ``out``, else
        gigapoint); waits for loading to finish first. Returns the ConvertResult.

        The converted octree has this one's nodes: its leaves, with their points, are the
        conversion's partitions as they stand (``grown``; lod/convert/seeded.py), and the
        converter samples the inner nodes from them. With another ``max_leaf`` or a Dask
        ``client`` the points are converted again from scratch."""
        import inspect

        from ..convert import convert
        from ..convert.to_file import is_point_file_name

        if format is None and out is not None and str(out) != "" and is_point_file_name(out):  # save("merged.laz"): the points, no octree
            return self._save_points(Path(out), overwrite, options)
        # (not the point filter's classes, drop_classes, clip: they filter points read from files, not an octree's)
        taken = set(inspect.signature(convert).parameters) - {"inputs", "out", "format", "overwrite", "classes", "drop_classes", "clip"}
        unknown = sorted(set(options) - taken)
        if unknown:  # banana=1 was a TypeError inside
            raise InputError(f"{self.name}: save: unknown option(s) {', '.join(unknown)}; it takes {', '.join(sorted(taken))}")
        self._check_savable()
        options.setdefault("source_files", [p for p in self.source_files if p.is_file()])  # the files' CRS and LAS grid (those still there)
        options.setdefault("max_leaf", self.max_leaf)
        options.setdefault("name", self.name)  # name= another was "multiple values for keyword argument"
        options.setdefault("has_color", self._saves_colors())
        grown = options["max_leaf"] == self.max_leaf and options.get("client") is None and self.points > 0
        inputs = self.grown() if grown else self.chunks()
        return convert(inputs, out, format=format, overwrite=overwrite, **options)

    def _save_points(self, out: Path, overwrite: bool, options: dict):
        """``save`` into one plain point file (.las, .laz, .ply): the leaves' points (not the
        voxels), on the source files' grid where the octree kept one (``grid``), with the first
        LAS file's CRS (io/write.py). Options of an octree are refused."""
        import time

        from ...io.las_fields import las_grid
        from ...io.write import check_point_file_output, las_color_bits, source_crs_records, write_points
        from ..convert.converter import ConvertResult

        if options:  # (sampler=, max_leaf=, ...: each meant something of an octree only)
            raise InputError(f"{out}: {', '.join(sorted(options))}: options of an octree, not of a plain {out.suffix[1:].upper()} file")
        check_point_file_output(out, overwrite)
        self._check_savable()
        t0 = time.perf_counter()
        ply = out.suffix.lower() == ".ply"
        grid = None if ply or self.grid is None else las_grid(self.lo, self.hi, np.full(3, self.grid[1]), self.grid[0], out)
        crs = source_crs_records(self.source_files)
        color_bits = las_color_bits(source_color_bits(self._color_bits))
        n = write_points(out, self.chunks, self.points, grid=grid, crs_records=crs, color_bits=color_bits, has_color=self._saves_colors())
        return ConvertResult(out, out.suffix[1:].lower(), None, n, 0, self.skipped, time.perf_counter() - t0, False)

    def _saves_colors(self) -> bool:
        """Whether a save writes colours: where an ``add`` brought some, or the source files have
        them (io/write.py's ``sources_have_color``: colourless files' grey is no colour of theirs)."""
        from ...io.write import sources_have_color

        return self._colors_added or sources_have_color(self.source_files)

    def check_loaded(self, to: str) -> None:
        """Wait for loading to finish; a one-line InputError where the octree is closed, or a
        close stopped its load part-way (its points were then saved as though the whole input)."""
        if not self.wait() or self.closed:
            raise InputError(f"{self.name}: the octree is closed (its points were freed); open it again to {to}")

    def _check_savable(self) -> None:
        """``check_loaded``; then, where it holds no point, the plain cloud's one-line EmptyCloudError
        (with the invalid points skipped): saved into a point file, it was a file of no points,
        as though a cloud were saved; into a folder, the converter's error without them."""
        self.check_loaded("save it")
        if self.points == 0:
            check_valid_count(self.name, 0, self.skipped)

    def grown(self):
        """The octree as a conversion's input (convert.seeded.GrownTree): its cube, its leaves and
        a way to read their points."""
        from ..convert.seeded import GrownTree

        with self.lock:
            leaves = self.leaves()
            node_of = dict(zip(self.key[leaves].tolist(), leaves.tolist()))
            stamp = self._stamp()
            return GrownTree(self.origin.copy(), float(self.edge), self.lo.copy(), self.hi.copy(), self.skipped,
                             dict(self._attribute_dtypes or {}), self.key[leaves].copy(), self.count[leaves].copy(),
                             lambda keys: self._leaf_points([node_of[k] for k in np.asarray(keys).tolist()], stamp))  # fmt: skip

    def _stamp(self) -> tuple:
        return (self.points, self.n_nodes, self.spilled)

    def _check_unchanged(self, stamp: tuple) -> None:
        """Raise unless the octree is as it was when ``stamp`` was taken: a point added since may
        have split a leaf, whose list 0 would then hold voxels (call with the lock held)."""
        if self._stamp() != stamp:
            raise GigapointError(f"{self.name}: the octree changed while it was being saved (points added, or closed); save it again")

    def _leaf_points(self, nodes: list, stamp: tuple) -> dict:
        """The points of leaves ``nodes``, leaf by leaf: {"xyz", "rgba" (u32), "attr.<name>"}, as
        long as the octree is unchanged since ``stamp``."""
        with self.lock:
            self._check_unchanged(stamp)
            slots = np.concatenate([self._list_slots(node * K.LISTS) for node in nodes]) if nodes else np.empty(0, np.int64)
            pool = self.pool
            return {"xyz": self._decode(slots), "rgba": take(pool.color, slots),
                    **{f"attr.{a}": v for a, v in pool.attribute_rows(slots).items()}}  # fmt: skip

    # ------------------------------------------------------------------ reading
    def node_entries(self, node: int) -> np.ndarray:
        """Pool slots of a node's points (a leaf) or voxels (an inner node, octant by octant)."""
        return np.concatenate([self._list_slots(node * K.LISTS + o) for o in range(K.LISTS)])

    def leaves(self) -> np.ndarray:
        """Indices of the leaves that hold points."""
        n = self.n_nodes
        return np.flatnonzero((self.leaf[:n] == 1) & (self.count[:n] > 0))

    def inner_nodes(self) -> np.ndarray:
        n = self.n_nodes
        return np.flatnonzero(self.leaf[:n] == 0)

    def positions(self, slots) -> np.ndarray:
        """float64 positions (30-bit cell centres) of entries at pool ``slots``."""
        return self._decode(np.asarray(slots, np.int64))

    def _box_min(self, nodes) -> np.ndarray:
        """The corner of the box of each node's chunks: its cube's, moved by VOXEL_SHIFT for an inner node's voxels."""
        return self.cmin[nodes] - np.where(self.leaf[nodes] == 1, 0.0, K.VOXEL_SHIFT * self.cedge[nodes])[..., None]

    def _decode(self, slots: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """float64 positions of the entries at pool ``slots`` (each in its chunk's node's box), into ``out`` when given."""
        pool = self.pool
        out = np.empty((len(slots), 3)) if out is None else out
        n = self.n_nodes
        K.dequantize_slots(pool.low, pool.ext, pool.packing["ext_first"], pool.packing["code"], pool.chunk, slots, pool.chunk_node,
                           self._box_min(np.arange(n)), self.cedge[:n], out)  # fmt: skip
        return out

    # ------------------------------------------------------------------ drawing (Renderable)
    def prepare(self, view: View, settings) -> DrawList:
        """What a view draws (store.select_octants: largest projected child first within the point
        budget, each drawn child replacing its parent's voxels of its octant), one batch per chunk;
        with ``hidden_classes``, each chunk's entries of the other classes (KeptChunks), the
        budget spent on those: a chunk filtered counts the entries it kept (``_kept_costs``)."""
        n = self.n_nodes
        pool = self.pool
        if pool is None or self.points == 0:
            empty = Selection(np.empty(0, np.int64), np.empty(0, np.int32), np.empty((0, 4, 4), np.float32), np.empty(0), 0)
            # before the first points no buffers: empty ones (no point, so no color mode asks for an attribute not known yet)
            return DrawList(pool or Pool(self.name, 0, self.chunk, {}, 0), empty, max(n, 1), nodes=np.empty(0, np.int64))
        hidden = settings.hidden_classes
        if hidden:
            check_classified(self.name, self.attribute_names, hidden)
        pool.source_scale = (self.grid[1],) * 3 if self.grid is not None and self._narrow else None  # point_info's rounding
        pool.node_is_leaf = self.leaf  # ... and its voxels
        lo, hi = self.bounds
        cmin, cedge = self.cmin[:n], self.cedge[:n]
        cube_min = np.clip(cmin, lo, hi)
        cube_max = np.clip(cmin + cedge[:, None], lo, hi)
        box_min, box_size = cube_min, cube_max - cube_min
        if self.select_by_points:
            # nodes selected and culled by the box of their points (and half a voxel cell more,
            # where their voxels sit), not their cube: a node of a flat town is a thin slab of it
            pad = (cedge / (2 << K.GRID_BITS))[:, None]
            has = (self.point_min[:n, 0] <= self.point_max[:n, 0])[:, None]
            box_min = np.where(has, np.maximum(self.point_min[:n] - pad, cube_min), cube_min)
            box_size = np.where(has, np.minimum(self.point_max[:n] + pad, cube_max), cube_max) - box_min
        sample = self.grid_sample[:n]
        sample = np.where(sample > 0, np.minimum(self.count[:n], -(-sample // pool.chunk) * pool.chunk), 0)  # whole chunks are drawn
        rounds = 1 + (KEPT_ROUNDS if hidden else 0)
        for r in range(rounds):
            # the last round weighs the chunks not filtered whole: what it filters fits whatever they keep
            costs = self._kept_costs(hidden, sample, estimated=r < rounds - 1) if hidden else (self.count[:n], self.list_count, sample)
            lists, sampled = self._drawn_lists(view, settings, box_min, box_size, sample, costs)
            node = lists // K.LISTS
            entries = np.where(sampled[node], sample[node], self.list_count[lists])  # a leaf drawn as its sample: its first chunks
            chunks, chunk_list = self._list_chunks(lists, entries)
            if not hidden:
                break
            # the chunks filtered now count their kept entries from now on, not their estimates:
            # an estimate too low drops the octants past the budget, one too high leaves budget
            # to deeper octants, until a selection filters no chunk (every entry it draws weighed
            # as kept: within the budget)
            filtered = self._kept.filtered
            slots = self._kept.slots(pool, chunks, hidden)
            if self._kept.filtered == filtered:
                break
        ids, list_node = np.unique(node, return_inverse=True)
        corner = self._box_min(ids)  # the chunks' boxes (the voxels' moved: kernels.VOXEL_SHIFT)
        # the precision a batch needs follows the projection of its quantization box: its whole
        # cube, not clipped to the data (a single point's clipped box is a point: 10 bits of a
        # cube far larger than the close-up that frames it put the point off the image)
        _, size = visible_and_size(view.rows, cmin[ids], cmin[ids] + cedge[ids, None], view.width, view.height, view.near, view.far)
        bits = precision_for(size, settings.precision_threshold_px) if settings.adaptive_precision else np.full(len(ids), 30, np.int32)
        mats = batch_matrices(view.rows, corner, corner + cedge[ids, None])
        owner = list_node[chunk_list]
        drawn_from = pool
        if hidden:
            chunks, owner = slots[slots >= 0], owner[slots >= 0]  # (a chunk of hidden entries alone: nothing to draw)
            drawn_from = self._kept.pool
            drawn_from.source_scale, drawn_from.node_is_leaf, drawn_from.bounds = pool.source_scale, pool.node_is_leaf, pool.bounds
        sel = Selection(chunks, bits[owner].astype(np.int32), mats[owner], size[owner], int(n - len(ids)))
        return DrawList(drawn_from, sel, n, nodes=ids, spacing=self._drawn_spacing(lists, box_size, entries, sampled[node]))

    def _drawn_lists(self, view: View, settings, box_min: np.ndarray, box_size: np.ndarray, sample: np.ndarray, costs: tuple):
        """(the lists a view draws, in Morton order of their nodes' cubes; which leaves draw their
        grid ``sample`` alone) as store.select_octants selects them within the point budget,
        ``costs`` its (costs, list_costs, sample_costs)."""
        n = self.n_nodes
        drawn = np.zeros((n, K.LISTS), np.bool_)
        size_of = np.zeros(n)
        sampled = np.zeros(n, np.bool_)
        node_costs, list_costs, sample_costs = costs
        select_octants(
            view.rows, box_min, box_size, node_costs, self.list_count, list_costs, self.parent, self.children[:n], float(view.width),
            float(view.height), float(view.near), float(view.far), float(settings.lod_threshold_px), int(settings.point_budget), drawn,
            size_of, float(settings.lod_foveation), self.root, sample, sample_costs, sampled,
        )  # fmt: skip
        lists = np.flatnonzero(drawn.reshape(-1))
        # drawn node by node in Morton order of their cubes, not in the pool's order: the pool
        # interleaves chunks of nodes all over the cloud (as batches arrived), and frames drawn in
        # that order scatter their writes over the whole image
        node = lists // K.LISTS
        return lists[np.argsort(morton_position(self.key[node], self.level[node]), kind="stable")], sampled

    def _list_chunks(self, lists: np.ndarray, entries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(the chunks holding the first ``entries`` of each of ``lists``, list by list; the index
        in ``lists`` of each one's list)."""
        max_chunks = -(-entries // self.pool.chunk)
        chunks = np.empty(int(max_chunks.sum()), np.int64)
        owner = np.empty(len(chunks), np.int64)
        k = list_chunks(self.first_chunk, self.pool.chunk_next, lists, chunks, owner, max_chunks)
        return chunks[:k], owner[:k]

    def _kept_costs(self, hidden: tuple[int, ...], sample: np.ndarray, estimated: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(costs, list_costs, sample_costs) of store.select_octants while ``hidden`` classes are
        left out: the entries of each node, list and grid ``sample`` (its first chunks), less
        those hidden in the chunks KeptChunks has filtered (KeptChunks.kept_counts); the others
        (``estimated``) less the share of theirs their node's filtered chunks, or its nearest
        ancestor's, left out (store.kept_shares), or (not ``estimated``) none. The same arrays
        while no chunk was written or filtered since: each selection asks (two or more a frame)
        and the answer walks every chunk the estimates leave entries out of, all of them."""
        n, pool, kept_chunks = self.n_nodes, self.pool, self._kept
        asked = (pool, pool.version, n, hidden, estimated, kept_chunks, kept_chunks.filtered, kept_chunks.hidden, kept_chunks.forms)
        last, last_sample, answer = self._last_kept_costs
        if last == asked and np.array_equal(last_sample, sample):
            return answer
        counts = pool.batches["count"].astype(np.int64)
        kept, known = kept_chunks.kept_counts(pool, hidden)
        if estimated:
            chunk_node = pool.chunk_node
            ours = (chunk_node >= 0) & (chunk_node < n)  # (a chunk never written has none)
            filtered = known & ours
            shares = kept_shares(np.bincount(chunk_node[filtered], kept[filtered], n), np.bincount(chunk_node[filtered], counts[filtered], n), self.parent[:n])
            guess = ours & ~known
            kept[guess] = np.ceil(counts[guess] * shares[chunk_node[guess]])
        left_out = counts - kept
        costs, list_costs, sample_costs = self.count[:n].copy(), self.list_count.copy(), sample.copy()
        nodes = np.unique(pool.chunk_node[left_out > 0])
        nodes = nodes[(nodes >= 0) & (nodes < n)]  # (a chunk given back keeps its last node: its lists are walked for nothing)
        lists = (nodes[:, None] * K.LISTS + np.arange(K.LISTS)).ravel()
        lists = lists[self.list_count[lists] > 0]
        chunks, chunk_list = self._list_chunks(lists, self.list_count[lists])
        per_list = np.bincount(chunk_list, left_out[chunks], minlength=len(lists)).astype(np.int64)
        list_costs[lists] -= per_list
        np.subtract.at(costs, lists // K.LISTS, per_list)
        node = lists[chunk_list] // K.LISTS
        in_sample = _within_runs(np.bincount(chunk_list, minlength=len(lists))) < -(-sample[node] // pool.chunk)
        np.subtract.at(sample_costs, node[in_sample], left_out[chunks[in_sample]])
        self._last_kept_costs = (asked, sample.copy(), (costs, list_costs, sample_costs))
        return costs, list_costs, sample_costs

    def _drawn_spacing(self, lists: np.ndarray, box_size: np.ndarray, entries: np.ndarray, sampled: np.ndarray) -> float:
        """Spacing of the drawn entries (adaptive point sizes), from the voxel grids rather than
        the chunks' boxes (each is its node's whole cube): an octant's voxels sit one cell apart,
        as a leaf's grid sample (``sampled``) does in its own grid; a leaf's points cover the
        area its parent's voxels of its octant do (cells x cell area), so their spacing is
        sqrt(area / points). The median over the drawn ``entries`` of each list."""
        node = lists // K.LISTS
        counts = entries.astype(np.float64)
        keep = counts > 0
        if not keep.any():
            return 0.0
        node, counts, sampled = node[keep], counts[keep], sampled[keep]
        cell = self.cedge[: self.n_nodes] / (1 << K.GRID_BITS)
        spacing = cell[node].copy()  # voxels
        leaf = (self.leaf[node] == 1) & ~sampled
        parent = self.parent[node]
        has = leaf & (parent >= 0)
        if has.any():
            p = parent[has]
            octant = np.argmax(self.children[p] == node[has][:, None], axis=1)
            voxels = self.list_count[p * K.LISTS + octant].astype(np.float64)
            spacing[has] = cell[p] * np.sqrt(np.maximum(voxels, 1.0) / counts[has])
        alone = leaf & (parent < 0)  # the root, still a leaf: its box within the bounds
        if alone.any():
            ext = np.sort(box_size[node[alone]], axis=1)
            spacing[alone] = np.sqrt(ext[:, 2] * ext[:, 1] / counts[alone])
        return weighted_median(spacing, counts)

    def prepare_views(self, views, settings) -> MultiViewDrawList | None:
        """None: each eye selects its own nodes, as for a converted octree."""
        return None
