"""Filling a ProgressiveOctree in the background: ``gigapoint.open(..., progressive=True)``.

A loader thread reads point chunks from the sources (any reader, several files, the demo
generator), decoding the next chunk in a second thread while it inserts this one (LAS/LAZ
decoding releases the GIL), and inserts them in slices of ``SLICE_POINTS``: between slices
a frame that waits for the octree goes first (ProgressiveOctree.reading), so drawing stays
interactive while the octree grows. Where the sources tell their bounds up front (LAS
headers) the octree's root cube is set from them, so it never has to grow.

A source that fails part-way (a truncated or corrupt file) stops the loader: what was
inserted stays drawable, ``error`` holds the one-line error naming the file, and ``wait``
raises it. ``close`` stops the loader and waits for it.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable, Iterator

import numpy as np

from ...core.chunk import PointChunk
from ...errors import GigapointError, InputError
from ..convert.prefetch import prefetch

SLICE_POINTS = 250_000  # points inserted under one hold of the octree (~10-30 ms): a waiting frame waits at most that


class Loader:
    """The thread that fills ``octree`` from ``sources``: (name, make_chunks) pairs."""

    def __init__(self, octree, sources: list[tuple[str, Callable[[], Iterable[PointChunk]]]], total: int | None):
        self.octree = octree
        self.sources = sources
        self.total = total  # input points, when the sources tell it up front
        self.read = 0  # input points read so far (valid or not)
        self.error: GigapointError | None = None
        self.started = time.perf_counter()
        self.finished_at: float | None = None
        self._stop = threading.Event()
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"gigapoint-load-{octree.name}", daemon=True)

    def start(self) -> Loader:
        self._thread.start()
        return self

    @property
    def done(self) -> bool:
        return self._done.is_set()

    @property
    def progress(self) -> float:
        """0..1: points read of the total (0 until done where no total is known; short of 1 after an error)."""
        if self._done.is_set() and self.error is None:
            return 1.0
        if self.total:
            return min(1.0, self.read / self.total)
        return 0.0

    @property
    def points_per_second(self) -> float:
        end = self.finished_at or time.perf_counter()
        return self.read / max(end - self.started, 1e-9)

    def _chunks(self) -> Iterator[tuple[str, PointChunk]]:
        for name, make in self.sources:
            for chunk in make():
                yield name, chunk

    def _run(self) -> None:
        name = self.octree.name
        try:
            for name, chunk in prefetch(self._chunks(), name="gigapoint-decode"):
                for s in range(0, len(chunk), SLICE_POINTS):
                    if self._stop.is_set():
                        return
                    sl = slice(s, s + SLICE_POINTS)
                    self.octree.add(chunk.xyz[sl], chunk.rgba[sl], **{a: v[sl] for a, v in chunk.attributes.items()})
                    self.read += len(chunk.xyz[sl])
        except GigapointError as exc:
            self.error = exc
        except MemoryError:
            self.error = GigapointError(f"{name}: out of memory while loading")
        except Exception as exc:  # noqa: BLE001 - any failure of a source ends the load with a one-line error
            self.error = InputError(f"{name}: loading stopped: {' '.join(str(exc).split()) or type(exc).__name__}")
        finally:
            self.finished_at = time.perf_counter()
            self._done.set()

    def wait(self, timeout: float | None = None) -> bool:
        """Until the load ends (True) or ``timeout`` seconds pass (False); raises the load's error."""
        finished = self._done.wait(timeout)
        if self.error is not None:
            raise self.error
        return finished

    def close(self) -> None:
        """Stop loading (after the slice in hand) and wait for the thread."""
        self._stop.set()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join()


def file_sources(paths) -> tuple[list, int | None, tuple[np.ndarray, np.ndarray] | None, str]:
    """(sources, total points, header bounds of all files, name) of files and directories: every
    file through its reader (io registry), in bounded chunks. Totals and bounds are known when
    every file's header tells them (LAS/LAZ)."""
    from ...io import expand_paths, reader_for
    from ...io._base import DEFAULT_CHUNK_SIZE

    files = expand_paths(paths)
    sources, total, lo, hi = [], 0, np.full(3, np.inf), np.full(3, -np.inf)
    bounds_known = True
    for f in files:
        reader = reader_for(f)
        n = reader.point_count(f)
        total = None if total is None or n is None else total + n
        info = reader.info(f) if bounds_known and n is not None else {}  # a header read, not a scan
        b = info.get("bounds") or {}
        if info.get("bounds_source") == "header" and b.get("min") is not None:
            lo, hi = np.minimum(lo, b["min"]), np.maximum(hi, b["max"])
        else:
            bounds_known = False
        sources.append((str(f), lambda f=f, reader=reader: reader.read_chunks(f, min(DEFAULT_CHUNK_SIZE, 1_000_000))))
    name = files[0].name if len(files) == 1 else f"{len(files)} files"
    return sources, total, ((lo, hi) if bounds_known and np.all(lo <= hi) else None), name


def demo_sources(n_points: int, seed: int = 0) -> tuple[list, int, tuple[np.ndarray, np.ndarray] | None, str]:
    """The procedural demo town as a source, generated a million points at a time."""
    from ...io.demo import demo_chunks

    return [(f"demo({n_points:,})", lambda: demo_chunks(n_points, seed, chunk_size=1_000_000))], n_points, None, f"demo({n_points:,})"


def open_progressive(sources, total, bounds, name, max_leaf=None):
    """A ProgressiveOctree filled by a started Loader (bounds: the root cube, when known)."""
    from .octree import MAX_LEAF, ProgressiveOctree

    cube = None
    if bounds is not None:
        lo, hi = (np.asarray(b, np.float64) for b in bounds)
        pad = 0.001 * max(float(np.max(hi - lo)), 1e-9)  # headers round their bounds
        cube = (lo - pad, float(np.max(hi - lo)) + 2 * pad)
    octree = ProgressiveOctree(name, cube=cube, max_leaf=max_leaf or MAX_LEAF, capacity=total or 0)
    octree.attach(Loader(octree, sources, total).start())
    return octree
