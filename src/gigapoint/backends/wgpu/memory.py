"""Host arrays on the GPU: split into pages that fit one storage binding, uploaded once,
cached per array, evicted least-recently-used to stay within a byte budget.

Arrays are keyed by identity (``id`` checked through a weak reference), so a second frame
of the same cloud uploads nothing, and a cloud that is garbage-collected frees its copy.
An array changed in place must be dropped with ``forget`` (the cache cannot see writes).
"""

from __future__ import annotations

import weakref
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from ...errors import GigapointError


@dataclass
class _Entry:
    ref: weakref.ref
    buffer: object
    nbytes: int


@dataclass
class PagePlan:
    """Pages of whole batches: page p holds points starts[p] .. stops[p]."""

    ref: weakref.ref  # the batches array it was planned for
    starts: np.ndarray  # int64 first point of each page
    stops: np.ndarray  # int64 one past the last point
    page_of: np.ndarray  # int64 page of each batch

    @property
    def n_pages(self) -> int:
        return len(self.starts)


def plan_pages(batches: np.ndarray, max_points: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Greedy split of batches (in point order) into pages of at most ``max_points`` points.

    A page is a contiguous range of point indices holding whole batches, so a workgroup
    never needs two bindings.
    """
    first = batches["first"].astype(np.int64)
    end = first + batches["count"].astype(np.int64)
    too_big = np.flatnonzero(end - first > max_points)
    if len(too_big):
        b = int(too_big[0])
        raise GigapointError(
            f"batch {b} holds {int(end[b] - first[b]):,} points, more than one GPU page ({max_points:,}); rebuild the cloud with smaller batches"
        )
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

    def _drop(self, key) -> None:
        entry = self._entries.pop(key)
        self.bytes_resident -= entry.nbytes
        # Safe while submitted work still reads it: freeing waits for that work (WebGPU rule).
        entry.buffer.destroy()

    def purge_dead(self) -> None:
        """Free the copies of arrays that no longer exist."""
        for key in [k for k, e in self._entries.items() if e.ref() is None]:
            self._drop(key)

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
        if entry is not None and entry.ref() is array:
            self._entries.move_to_end(key)
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
        buffer = self.device.create_buffer_with_data(data=data, usage=wgpu.BufferUsage.STORAGE)
        self._entries[key] = _Entry(weakref.ref(array), buffer, nbytes)
        self.bytes_resident += nbytes
        self.bytes_uploaded += nbytes
        self.uploads += 1
        return buffer
