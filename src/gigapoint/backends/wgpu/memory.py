"""Host arrays on the GPU: split into pages that fit one storage binding, uploaded once,
cached per array, evicted least-recently-used to stay within a byte budget.

Arrays are keyed by identity (``id`` checked through a weak reference), so a second frame
of the same cloud uploads nothing, and a cloud that is garbage-collected frees its copy.

Point buffers that rewrite their arrays in place (an LOD arena loading and evicting nodes
between frames) say so with the two attributes of the PointBuffers contract
(gigapoint.core.renderable), and the cache never serves a stale page of them:

- ``version``: an int bumped on every write (None: the arrays never change);
- ``batch_version`` (or None): per batch, the ``version`` of the write that last filled it.

Their arrays are registered with ``track``; each use of a page compares the cloud's version
with the page's, and rewrites in place only the batches written since (the whole page without
``batch_version``). Any other array changed in place must be dropped with ``forget``. A
compact cloud's ``ext`` is refreshed by its batches' streams (``packing``), not their points.
"""

from __future__ import annotations

import time
import weakref
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from ...core.compact import ext_bits_per_point, stream_words
from ...errors import GigapointError

#: Changed batches this close are sent in one write with the unchanged bytes between them: a
#: ``write_buffer`` call costs 10-40 us (lavapipe, measured: 41 us for 4 KiB, 22 us for 40 KiB),
#: about what sending 32 KiB more costs at 2 GB/s, and a filling progressive octree changes a
#: few thousand 2048-entry chunks between two frames, scattered over its pool.
MERGE_GAP_BYTES = 32 << 10


@dataclass
class _Entry:
    ref: weakref.ref
    buffer: object
    nbytes: int
    version: int = 0  # the tracked cloud's version the buffer's contents are from


@dataclass
class PagePlan:
    """Pages of whole batches: page p holds points starts[p] .. stops[p]."""

    ref: weakref.ref  # the batches array it was planned for
    starts: np.ndarray  # int64 first point of each page
    stops: np.ndarray  # int64 one past the last point
    page_of: np.ndarray  # int64 page of each batch
    ends: np.ndarray | None = None  # int64 end of each batch as planned (clouds whose batches refill: re-plan when it moves)
    ext_ranges: tuple[np.ndarray, np.ndarray] | None = None  # compact clouds: each page's u64 words of the extension streams
    ext_layout: tuple | None = None  # clouds refilled in place: (ext_first, code, len(ext)) the ranges were computed for

    @property
    def n_pages(self) -> int:
        return len(self.starts)


def batch_ends(batches: np.ndarray, max_points: int, capacity: int | None = None) -> np.ndarray:
    """int64 one past the last point of each batch, as pages are planned.

    ``capacity`` (the cloud's buffer length) for clouds whose batches are refilled in place
    (an LOD arena's slots): a batch then reaches up to the next batch's first point (at most
    a page), so the pages stay put while the counts change."""
    first = batches["first"].astype(np.int64)
    end = first + batches["count"].astype(np.int64)
    too_big = np.flatnonzero(end - first > max_points)
    if len(too_big):
        b = int(too_big[0])
        raise GigapointError(
            f"batch {b} holds {int(end[b] - first[b]):,} points, more than one GPU page ({max_points:,}); rebuild the cloud with smaller batches"
        )
    if capacity is not None and len(first):
        order = np.argsort(first, kind="stable")
        room = np.empty(len(first), np.int64)
        room[order] = np.append(first[order][1:], max(int(capacity), int(first.max()))) - first[order]
        end = np.maximum(end, first + np.minimum(room, max_points))
    return end


def plan_pages(batches: np.ndarray, max_points: int, end: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Greedy split of batches (in point order) into pages of at most ``max_points`` points.

    A page is a contiguous range of point indices holding whole batches, so a workgroup
    never needs two bindings. ``end``: each batch's end (default from ``batch_ends``).
    """
    first = batches["first"].astype(np.int64)
    end = batch_ends(batches, max_points) if end is None else end
    order = np.argsort(first, kind="stable")
    page_of = np.empty(len(batches), np.int64)
    starts, stops = [], []
    start = stop = None
    for b in order.tolist():  # once per cloud; a few 10^5 batches at most
        if start is None or end[b] - start > max_points:
            if start is not None:
                stops.append(stop)
            start, stop = int(first[b]), int(end[b])
            starts.append(start)
        stop = max(stop, int(end[b]))
        page_of[b] = len(starts) - 1
    stops.append(stop)
    return np.array(starts, np.int64), np.array(stops, np.int64), page_of


class BufferCache:
    """GPU storage buffers holding slices of host arrays, within ``budget`` bytes."""

    def __init__(self, device, budget: int) -> None:
        self.device = device
        self.budget = int(budget)
        self._entries: OrderedDict[tuple, _Entry] = OrderedDict()
        self.bytes_resident = 0
        self.bytes_uploaded = 0
        self.uploads = 0
        self.evictions = 0
        self.refreshes = 0  # pages of tracked arrays rewritten in place after their cloud changed
        self.refresh_writes = 0  # the write_buffer calls those rewrites took
        self.refresh_seconds = 0.0  # and the time they took (Python and queueing the writes)
        self.merge_gap_bytes = MERGE_GAP_BYTES  # changed batches this close go in one write (0: each run on its own)
        # id(array) -> (weak array, weak cloud): arrays their cloud rewrites in place (see track)
        self._sources: dict[int, tuple[weakref.ref, weakref.ref]] = {}

    def _drop(self, key) -> None:
        entry = self._entries.pop(key)
        self.bytes_resident -= entry.nbytes
        # Safe while submitted work still reads it: freeing waits for that work (WebGPU rule).
        entry.buffer.destroy()

    def purge_dead(self) -> None:
        """Free the copies of arrays that no longer exist."""
        for key in [k for k, e in self._entries.items() if e.ref() is None]:
            self._drop(key)
        for key in [k for k, (a, c) in self._sources.items() if a() is None or c() is None]:
            del self._sources[key]

    def track(self, cloud, arrays) -> None:
        """Register ``arrays`` as ``cloud``'s, if the cloud has a ``version`` (it rewrites them
        in place): their pages are checked against it at every ``get``."""
        if cloud.version is None:
            return
        for a in arrays:
            if a is not None:
                self._sources[id(a)] = (weakref.ref(a), weakref.ref(cloud))

    def _owner(self, array):
        """The tracked cloud ``array`` belongs to, or None."""
        source = self._sources.get(id(array))
        if source is None:
            return None
        if source[0]() is not array:  # the tracked array is gone and its id reused
            del self._sources[id(array)]
            return None
        return source[1]()

    def forget(self, array) -> None:
        """Drop every page of ``array`` (call after changing it in place)."""
        for key in [k for k, e in self._entries.items() if e.ref() is array]:
            self._drop(key)

    def clear(self) -> None:
        for key in list(self._entries):
            self._drop(key)

    def get(self, array: np.ndarray, start: int, stop: int, pinned: set) -> object:
        """The buffer holding ``array[start:stop]``; uploads it if absent. Adds its key to ``pinned``.

        Pinned keys (the buffers the dispatch being recorded needs) are never evicted.
        """
        import wgpu  # optional dependency, present once a backend exists

        key = (id(array), int(start), int(stop))
        pinned.add(key)
        entry = self._entries.get(key)
        owner = self._owner(array) if self._sources else None
        version = int(owner.version) if owner is not None else 0
        if entry is not None and entry.ref() is array:
            self._entries.move_to_end(key)
            if entry.version != version:
                self._refresh(entry, array, int(start), int(stop), owner, version)
            return entry.buffer
        if entry is not None:  # an id reused by a new array
            self._drop(key)
        data = np.ascontiguousarray(array[start:stop])
        if data.nbytes % 16:  # whole 16-byte rows, so the vec4 view (vertex prefetch) covers every word
            data = np.concatenate([data.view(np.uint8).reshape(-1), np.zeros(16 - data.nbytes % 16, np.uint8)])
        nbytes = data.nbytes
        for old in [k for k in self._entries if k not in pinned]:
            if self.bytes_resident + nbytes <= self.budget:
                break
            self._drop(old)
            self.evictions += 1
        if self.bytes_resident + nbytes > self.budget:
            raise GigapointError(
                f"wgpu backend: memory_budget of {self.budget:,} bytes cannot hold the {nbytes:,} bytes one dispatch needs; raise it"
            )
        if data.nbytes == 0:
            data = np.zeros(16, np.uint8)
            nbytes = 16
        buffer = self.device.create_buffer_with_data(data=data, usage=wgpu.BufferUsage.STORAGE | wgpu.BufferUsage.COPY_DST)
        self._entries[key] = _Entry(weakref.ref(array), buffer, nbytes, version)
        self.bytes_resident += nbytes
        self.bytes_uploaded += nbytes
        self.uploads += 1
        return buffer

    def _refresh(self, entry: _Entry, array: np.ndarray, start: int, stop: int, owner, version: int) -> None:
        """Rewrite the points of ``array[start:stop]`` that ``owner`` wrote since the entry's version.

        Queued writes run after the work already submitted and before the work submitted
        next, so earlier dispatches still see the old contents and later ones the new."""
        t0 = time.perf_counter()
        row_bytes = array.itemsize * int(np.prod(array.shape[1:], dtype=np.int64))
        for s, e in stale_ranges(owner, entry.version, start, stop, array, gap=self.merge_gap_bytes // row_bytes):
            # whole 4-byte words (a copy's rule): 16-bit colours of an odd count widen by one
            b0, b1 = (s - start) * row_bytes // 4 * 4, -(-(e - start) * row_bytes // 4) * 4
            data = np.ascontiguousarray(array[start + b0 // row_bytes : start + -(-b1 // row_bytes)]).view(np.uint8).reshape(-1)
            lead = b0 % row_bytes
            data = data[lead : lead + b1 - b0]
            if len(data) < b1 - b0:  # the page's end: its buffer is padded
                data = np.concatenate([data, np.zeros(b1 - b0 - len(data), np.uint8)])
            self.device.queue.write_buffer(entry.buffer, b0, data)
            self.bytes_uploaded += data.nbytes
            self.refresh_writes += 1
        entry.version = version
        self.refreshes += 1
        self.refresh_seconds += time.perf_counter() - t0


def stale_ranges(cloud, since: int, start: int, stop: int, array=None, gap: int = 0) -> list[tuple[int, int]]:
    """Point ranges within start..stop that ``cloud`` wrote after its version ``since``:
    the batches whose ``batch_version`` is newer, merged where they touch or lie at most ``gap``
    rows apart (all of start..stop when the cloud has no per-batch versions). ``array`` the
    compact layout's ``ext``: ranges of its u64 words, the batches' streams, instead."""
    versions = cloud.batch_version
    if versions is None:
        return [(start, stop)]
    batches = cloud.batches
    counts = batches["count"].astype(np.int64)
    if array is not None and cloud.med is None and array is cloud.ext:
        first = cloud.packing["ext_first"].astype(np.int64)
        end = first + stream_words(ext_bits_per_point(cloud.packing, counts), counts)
    else:
        first = batches["first"].astype(np.int64)
        end = first + counts
    hit = np.flatnonzero((np.asarray(versions) > since) & (first < stop) & (end > start) & (end > first))  # an emptied batch: nothing to send
    if not len(hit):
        return []
    lo = np.maximum(first[hit], start)
    hi = np.minimum(end[hit], stop)
    order = np.argsort(lo, kind="stable")
    lo, hi = lo[order], hi[order]
    reach = np.maximum.accumulate(hi)
    new_run = np.concatenate([[True], lo[1:] > reach[:-1] + gap])
    run_of = np.cumsum(new_run) - 1
    run_hi = np.zeros(int(run_of[-1]) + 1, np.int64)
    np.maximum.at(run_hi, run_of, hi)
    return list(zip(lo[new_run].tolist(), run_hi.tolist()))
