"""The live cloud's point buffers: a pool of fixed-size chunks, one batch each, rewritten in place.

Two regions share the arrays (core/renderable.PointBuffers):

- the **ring**: chunks of ``chunk`` (BATCH_SIZE) entries; a frame's Morton-ordered batches
  go into free chunks when it arrives and the chunks go back to the free list when the frame
  leaves the ring (``keep``, ``decay``). Frames of at most half a chunk share one, one after
  another (``pack_into``), and leave it from its front (``drop_first``): a chunk's points are
  the entries ``first``..``first + count`` of its span. A chunk holding no frame has count 0.
- the **mirror**: a copy of the snapshot octree's pool (lod.progressive.Pool, chunks of its
  own size), refreshed chunk by chunk from its ``batch_version`` so the renderer draws live
  frames and snapshots from one set of buffers in one pass.

Every write bumps ``version`` and records it in ``batch_version`` of the chunks written, as
the progressive octree's pool does, so render's RenderCache and the GPU's page cache redo only
what changed. Growing a region makes new arrays (caches drop the old ones by identity).
"""

from __future__ import annotations

import weakref
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from ..core.compact import point_words
from ..core.framelock import FrameLock
from ..core.layout import BATCH_DTYPE, COORD_BITS, WORD_BITS, WORD_MASK
from ..core.quantize import dequantize, make_batches, quantize
from ..core.renderable import check_point_index

_SCALE30 = float(1 << COORD_BITS)

#: attributes every live point has: ``normal``, its (3,) float32 unit normal (0 where unknown; one
#: (N, 3) array, which lighting reads without a copy: render/colors.normals_of) and ``frame_time``,
#: the seconds since the cloud's start at which its frame arrived (NaN: a snapshot point, never fades)
BASE_ATTRIBUTES = {"normal": np.dtype((np.float32, (3,))), "frame_time": np.dtype(np.float32)}
NORMAL_PARTS = ("nx", "ny", "nz")  # the normal as 1-D attributes (the snapshot octree's, LAS/PLY files')


def attribute_dtype(values: np.ndarray) -> np.dtype:
    """The dtype that ``np.zeros(n, dtype)`` makes (n, ...) arrays like ``values`` of."""
    return np.dtype((values.dtype, values.shape[1:])) if values.ndim > 1 else values.dtype


@njit(inline="always")
def _coordinate(lw, mw, hw, a, lo, cell):
    """Axis ``a`` of a point's 30-bit position (its low, medium and high words) as a float64
    world coordinate: core/quantize.dequantize at 30 bits, the cell centre lo + (X + 0.5) cell.
    Non-decreasing in X: the smallest X of a box's points gives their smallest coordinate."""
    s = WORD_BITS * a
    q = (((lw >> s) & WORD_MASK) << 20) | (((mw >> s) & WORD_MASK) << 10) | ((hw >> s) & WORD_MASK)
    return lo + (q + 0.5) * cell


@njit(parallel=True, cache=True)
def _dequantize_runs(low, med, high, firsts, counts, offsets, bbox_min, bbox_max, out):
    """float64 positions of runs of points (run j: ``counts[j]`` points from ``firsts[j]``, in the
    box of row j) into ``out`` from ``offsets[j]`` (``_coordinate``), compiled over many batches at once."""
    for j in prange(firsts.shape[0]):
        f = firsts[j]
        o = offsets[j]
        lo0, lo1, lo2 = bbox_min[j, 0], bbox_min[j, 1], bbox_min[j, 2]
        c0 = (bbox_max[j, 0] - lo0) / _SCALE30
        c1 = (bbox_max[j, 1] - lo1) / _SCALE30
        c2 = (bbox_max[j, 2] - lo2) / _SCALE30
        for k in range(counts[j]):  # a point's three coordinates together: out's rows are written in order
            lw, mw, hw = low[f + k], med[f + k], high[f + k]
            out[o + k, 0] = _coordinate(lw, mw, hw, 0, lo0, c0)
            out[o + k, 1] = _coordinate(lw, mw, hw, 1, lo1, c1)
            out[o + k, 2] = _coordinate(lw, mw, hw, 2, lo2, c2)


@njit(parallel=True, cache=True)
def _bounds_runs(low, med, high, firsts, counts, bbox_min, bbox_max, lo, hi):
    """Per run (as ``_dequantize_runs``'), the least and greatest float64 coordinate of its points
    on each axis into ``lo[j]``, ``hi[j]`` (inf, -inf for none), equal to those of the positions
    ``_dequantize_runs`` writes: X + 0.5 (exact) reduced, then scaled and moved as there
    (``_coordinate`` is monotonic in X). No positions written."""
    for j in prange(firsts.shape[0]):
        f = firsts[j]
        for a in range(3):
            x_lo, x_hi = np.inf, -np.inf
            for k in range(counts[j]):
                x = _coordinate(low[f + k], med[f + k], high[f + k], a, 0.0, 1.0)
                x_lo, x_hi = min(x_lo, x), max(x_hi, x)
            cell = (bbox_max[j, a] - bbox_min[j, a]) / _SCALE30
            lo[j, a] = bbox_min[j, a] + x_lo * cell if counts[j] else np.inf
            hi[j, a] = bbox_min[j, a] + x_hi * cell if counts[j] else -np.inf


@njit(parallel=True, cache=True)
def _copy_runs(src, firsts, counts, offsets, out):
    """out[offsets[j] : offsets[j] + counts[j]] = src[firsts[j] : ...], every run j, in parallel."""
    for j in prange(firsts.shape[0]):
        f, o = firsts[j], offsets[j]
        for k in range(counts[j]):
            out[o + k] = src[f + k]


class LiveLock(FrameLock):
    """The live cloud's lock: core/framelock.FrameLock (frames first, a writer between frames),
    plus ``released`` (a bound method, held
    weakly: no reference cycle) called after every frame and write: the live cloud then commits
    the frames that arrived while the lock was held (producers never wait for a frame)."""

    def __init__(self, released=None) -> None:
        super().__init__()
        self._released = weakref.WeakMethod(released) if released is not None else None

    def _after(self) -> None:
        fn = self._released() if self._released is not None else None
        if fn is not None:
            fn()

    @contextmanager
    def writing(self):
        try:
            with super().writing():
                yield
        finally:
            self._after()

    @contextmanager
    def reading(self):
        try:
            with super().reading():
                yield
        finally:
            self._after()


_UINT_OF_SIZE = {1: np.uint8, 2: np.uint16, 4: np.uint32, 8: np.uint64}


@dataclass(frozen=True)
class Runs:
    """The points of some ring chunks, in order: run j is ``counts[j]`` points from buffer entry
    ``firsts[j]``, in the box ``bbox_min[j]``..``bbox_max[j]``, the ``offsets[j]``-th on."""

    firsts: np.ndarray
    counts: np.ndarray
    offsets: np.ndarray
    bbox_min: np.ndarray
    bbox_max: np.ndarray

    @property
    def n_points(self) -> int:
        return int(self.counts.sum())

    def part(self, start: int = 0, stop: int | None = None):
        """(firsts, counts, offsets from ``start``, which runs) of the points [start, stop): the runs
        that hold any of them, cut to them."""
        stop = self.n_points if stop is None else stop
        lo = np.maximum(self.offsets, start)
        hi = np.minimum(self.offsets + self.counts, stop)
        keep = np.flatnonzero(hi > lo)
        lo, hi = lo[keep], hi[keep]
        return self.firsts[keep] + lo - self.offsets[keep], hi - lo, lo - start, keep


class LiveBuffers:
    """Ring chunks [0, n_ring) then mirror chunks [n_ring, n_ring + n_mirror), in the batch layout."""

    def __init__(self, name: str, n_ring: int, chunk: int, n_mirror: int, mirror_chunk: int, attribute_dtypes: dict):
        self.name = name
        self.chunk = chunk
        self.mirror_chunk = mirror_chunk
        self.n_ring = n_ring
        self.n_mirror = n_mirror
        self.ring_points = n_ring * chunk
        n = self.ring_points + n_mirror * mirror_chunk
        self.batches = np.zeros(n_ring + n_mirror, BATCH_DTYPE)
        self.batches["first"][:n_ring] = np.arange(n_ring, dtype=np.uint64) * chunk
        self.batches["first"][n_ring:] = self.ring_points + np.arange(n_mirror, dtype=np.uint64) * mirror_chunk
        self.low = np.zeros(n, np.uint32)
        self.med = np.zeros(n, np.uint32)
        self.high = np.zeros(n, np.uint32)
        self.color = np.zeros(n, np.uint32)
        self.attributes = {a: np.zeros(n, dt) for a, dt in attribute_dtypes.items()}
        if "frame_time" in self.attributes:
            self.attributes["frame_time"][self.ring_points :] = np.nan
        self.batch_version = np.zeros(n_ring + n_mirror, np.int64)
        self.version = 0
        self.bounds = (np.zeros(3), np.zeros(3))

    @property
    def n_points(self) -> int:
        return len(self.low)

    def grown(self, n_ring: int, n_mirror: int) -> LiveBuffers:
        """Buffers with room for ``n_ring`` ring and ``n_mirror`` mirror chunks holding this one's
        contents (new arrays, a new version)."""
        new = LiveBuffers(self.name, n_ring, self.chunk, n_mirror, self.mirror_chunk, {a: attribute_dtype(v) for a, v in self.attributes.items()})
        r, m = min(self.n_ring, n_ring), min(self.n_mirror, n_mirror)
        rp, mp = r * self.chunk, m * self.mirror_chunk
        for a in ("low", "med", "high", "color"):
            src, dst = getattr(self, a), getattr(new, a)
            dst[:rp] = src[:rp]
            dst[new.ring_points : new.ring_points + mp] = src[self.ring_points : self.ring_points + mp]
        for a, v in self.attributes.items():
            new.attributes[a][:rp] = v[:rp]
            new.attributes[a][new.ring_points : new.ring_points + mp] = v[self.ring_points : self.ring_points + mp]
        for field in ("count", "level", "bbox_min", "bbox_max"):
            new.batches[field][:r] = self.batches[field][:r]
            new.batches[field][n_ring : n_ring + m] = self.batches[field][self.n_ring : self.n_ring + m]
        new.batches["first"][:r] = self.batches["first"][:r]  # where a ring chunk's live points start (packed: past its oldest frames')
        new.batch_version[:] = self.version + 1
        new.version = self.version + 1
        new.bounds = self.bounds
        return new

    def write_chunk(self, slot: int, record, low, med, high, color, attributes: dict) -> None:
        """Ring chunk ``slot`` := one batch (its record's count and box) and its point arrays."""
        n = len(low)
        f = slot * self.chunk
        b = self.batches[slot]
        b["first"], b["count"], b["level"], b["bbox_min"], b["bbox_max"] = f, n, 0, record["bbox_min"], record["bbox_max"]
        self.low[f : f + n] = low
        self.med[f : f + n] = med
        self.high[f : f + n] = high
        self.color[f : f + n] = color
        for a, v in self.attributes.items():
            v[f : f + n] = attributes[a]
        self.batch_version[slot] = self.version

    def start_chunk(self, slot: int) -> None:
        """Ring chunk ``slot`` is empty, to be packed from its start (``pack_into``)."""
        self.batches["first"][slot] = slot * self.chunk
        self.batches["count"][slot] = 0

    def pack_into(self, slot: int, xyz: np.ndarray, m: int, color: np.ndarray, attributes: dict) -> None:
        """Ring chunk ``slot``'s span holds the world positions ``xyz`` from its start, the last
        ``m`` of them (with ``color`` and ``attributes``) new: those ``m`` are written and every
        position quantized afresh (30 bits) in their box, the chunk's box from now on; its live
        points run from its first on to the new ones' end."""
        n = len(xyz)
        f = slot * self.chunk
        one = make_batches(n, n)
        self.low[f : f + n], self.med[f : f + n], self.high[f : f + n] = quantize(xyz, np.arange(n), one)
        self.color[f + n - m : f + n] = color
        for a, v in self.attributes.items():
            v[f + n - m : f + n] = attributes.get(a, 0)
        b = self.batches[slot]
        b["count"], b["level"], b["bbox_min"], b["bbox_max"] = f + n - int(b["first"]), 0, one[0]["bbox_min"], one[0]["bbox_max"]
        self.batch_version[slot] = self.version

    def drop_first(self, slot: int, n: int) -> int:
        """The first ``n`` live points of ring chunk ``slot`` leave it (their frame left the ring;
        frames leave in arrival order, so they are its oldest): the points it has left. Their
        words stay (as an emptied chunk's do until it is refilled, the write ``batch_version``
        records): what is drawn is the rest, unchanged."""
        b = self.batches[slot]
        left = int(b["count"]) - n
        b["first"], b["count"] = int(b["first"]) + n, left
        return left

    def mirror_from(self, pool, chunks: np.ndarray) -> None:
        """Copy chunks ``chunks`` of the snapshot octree's pool into the mirror region."""
        if not len(chunks):
            return
        mc = self.mirror_chunk
        ids = self.n_ring + chunks
        for field in ("count", "level", "bbox_min", "bbox_max"):
            self.batches[field][ids] = pool.batches[field][chunks]
        # runs of consecutive chunks copied as slices: a new pool is one run (fancy indexing of
        # its ~18 M entries took 1-3 s of the first frame after a snapshot)
        for run in np.split(chunks, np.flatnonzero(np.diff(chunks) != 1) + 1):
            s0, s1 = int(run[0]) * mc, (int(run[-1]) + 1) * mc
            d0, d1 = s0 + self.ring_points, s1 + self.ring_points
            self.low[d0:d1] = pool.low[s0:s1]
            self.color[d0:d1] = pool.color[s0:s1]
            if pool.med is not None:
                self.med[d0:d1] = pool.med[s0:s1]
                self.high[d0:d1] = pool.high[s0:s1]
            for a, v in self.attributes.items():
                if a in pool.attributes:
                    v[d0:d1] = pool.attributes.at(a, slice(s0, s1))
                elif a == "normal" and all(p in pool.attributes for p in NORMAL_PARTS):
                    for k, part in enumerate(NORMAL_PARTS):
                        v[d0:d1, k] = pool.attributes.at(part, slice(s0, s1))
        if pool.med is None:  # the octree's compact pool (core/compact.py): each chunk's medium and high words decoded from its stream
            for c, n in zip(chunks.tolist(), pool.batches["count"][chunks].tolist()):
                f, o = c * mc, self.ring_points + c * mc
                _, self.med[o : o + n], self.high[o : o + n] = point_words(pool, c, f, f + n)
        self.batch_version[ids] = self.version

    def positions(self, slot: int) -> np.ndarray:
        """float64 world positions (30-bit cell centres) of the points of chunk ``slot``."""
        rec = self.batches[slot]
        f, n = int(rec["first"]), int(rec["count"])
        return dequantize(self.low[f : f + n], self.med[f : f + n], self.high[f : f + n], rec["bbox_min"], rec["bbox_max"], 30)

    def runs(self, slots: list[int], firsts: list[int], counts: list[int]) -> Runs:
        """Runs of ``counts[j]`` points from buffer entry ``firsts[j]`` in ring chunk ``slots[j]``,
        in order (frames' parts: FrameInfo; the chunks' boxes copied: they may be refilled after)."""
        rec = self.batches[np.asarray(slots, np.int64)]
        counts = np.asarray(counts, np.int64)
        return Runs(np.asarray(firsts, np.int64), counts, np.cumsum(counts) - counts, rec["bbox_min"].copy(), rec["bbox_max"].copy())

    def bounds_of(self, runs: Runs) -> tuple[np.ndarray, np.ndarray]:
        """(min, max) of the world positions ``gather`` gives the points of ``runs``, without them."""
        lo, hi = np.empty((len(runs.firsts), 3)), np.empty((len(runs.firsts), 3))
        _bounds_runs(self.low, self.med, self.high, runs.firsts, runs.counts, runs.bbox_min, runs.bbox_max, lo, hi)
        return lo.min(axis=0, initial=np.inf), hi.max(axis=0, initial=-np.inf)

    def sample(self, runs: Runs, step: int) -> np.ndarray:
        """float64 world positions of every ``step``-th point of ``runs`` (as ``gather`` gives
        them): runs of one point each, through the same kernel."""
        at = np.arange(0, runs.n_points, max(int(step), 1), dtype=np.int64)
        run = np.searchsorted(runs.offsets, at, side="right") - 1
        out = np.empty((len(at), 3))
        ones = np.ones(len(at), np.int64)
        _dequantize_runs(self.low, self.med, self.high, runs.firsts[run] + at - runs.offsets[run], ones, np.arange(len(at), dtype=np.int64),
                         runs.bbox_min[run], runs.bbox_max[run], out)  # fmt: skip
        return out

    def gather(self, runs: Runs, skip=(), start: int = 0, stop: int | None = None, out: dict | None = None):
        """(xyz float64 (N, 3) world, rgba uint8 (N, 4), attributes: the normal as nx, ny, nz) of the
        points of ``runs``, in order; of points [start, stop) of them only, when given. ``out``: a
        dict the arrays are taken from and kept in (first rows of arrays made for the largest
        range so far: one set of pages for many ranges)."""
        firsts, counts, offsets, keep = runs.part(start, stop)
        n = int(counts.sum())
        out = {} if out is None else out

        def array(name, dtype, shape=()):
            a = out.get(name)
            if a is None or len(a) < n or a.dtype != dtype or a.shape[1:] != shape:
                a = out[name] = np.empty((n, *shape), dtype)
            return a[:n]

        xyz = array("xyz", np.float64, (3,))
        _dequantize_runs(self.low, self.med, self.high, firsts, counts, offsets, runs.bbox_min[keep], runs.bbox_max[keep], xyz)

        def take(name, values):
            dst = array(name, values.dtype)
            u = _UINT_OF_SIZE.get(values.dtype.itemsize)
            if u is not None and values.ndim == 1:  # moved as same-width integers: one compiled copy a width
                _copy_runs(values.view(u), firsts, counts, offsets, dst.view(u))
            else:
                for f, c, o in zip(firsts.tolist(), counts.tolist(), offsets.tolist()):
                    dst[o : o + c] = values[f : f + c]
            return dst

        rgba = take("color", self.color).view(np.uint8).reshape(-1, 4)
        attrs = {}
        for a, v in self.attributes.items():
            if a in skip:
                continue
            if a == "normal":  # 1-D parts, as the octree and the file writers take attributes: gathered straight into them
                attrs.update({part: take(part, v[:, k]) for k, part in enumerate(NORMAL_PARTS)})
            else:
                attrs[a] = take(a, v)
        return xyz, rgba, attrs

    def point_info(self, index: int) -> dict | None:
        """Position, colour and attributes of the entry at ``index`` (a live frame's point or a
        snapshot's); None for -1 (no point)."""
        check_point_index(index, self.n_points, self.name)
        if index == -1:
            return None
        if index < self.ring_points:
            slot = index // self.chunk
        else:
            slot = self.n_ring + (index - self.ring_points) // self.mirror_chunk
        rec = self.batches[slot]
        i = np.array([index])
        pos = dequantize(self.low[i], self.med[i], self.high[i], rec["bbox_min"], rec["bbox_max"], 30)[0]
        info = {"index": int(index), "position": pos.tolist(), "rgba": self.color[i].view(np.uint8).tolist(),
                "source": "live frame" if index < self.ring_points else "snapshot"}  # fmt: skip
        for a, v in self.attributes.items():
            info[a] = v[index].tolist()
        return info
