"""Filling a ProgressiveOctree in the background: ``gigapoint.open(..., progressive=True)``.

A loader thread reads point chunks from the sources (any reader, several files, the demo
generator), decoding the next chunk in a second thread while it inserts this one (LAS/LAZ
decoding releases the GIL), and inserts them in slices. Frames go first (SimLOD's schedule,
ProgressiveOctree.builder_turn): while a frame draws, or waits to, neither thread starts a
slice or a chunk, unless a frame has been drawn since its last one (frames and slices then
alternate), and while frames are being drawn the slices are small, so drawing stays
interactive while the octree grows and loading runs at full speed when nothing draws. Where the sources tell their bounds up front (LAS
headers) the octree's root cube is set from them, so it never has to grow. When every point is
in, it orders the leaves' points, a grid sample first (ProgressiveOctree.order_leaves), in
slices between frames too, before the load counts as done.

A source that fails part-way (a truncated or corrupt file) stops the loader: what was
inserted stays drawable, ``error`` holds the one-line error naming the file, and ``wait``
raises it. The loader's warnings (a file's EVLRs cut, invalid points skipped, attributes not in
every file) are kept, not issued on its threads (errors.warn), in ``warnings``; ``wait`` and
``close`` issue each once, in order, in the caller's thread. ``close`` stops the loader and waits for it.
"""

from __future__ import annotations

import contextvars
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

import numba
import numpy as np

from ...core.chunk import PointChunk, join_chunks
from ...core.chunked import physical_memory
from ...core.cloud import check_valid_count
from ...core.threads import SMALL_BATCH
from ...errors import (
    GigapointError,
    InputError,
    KeptWarnings,
    MemoryLimitError,
    keep_warnings,
)
from ...io import human_bytes
from ...io._base import headers_once
from ...io.filters import PointFilter, filtered
from ...io.las import header_slack
from ..convert.prefetch import prefetch

# points inserted under one hold of the octree while no frames are drawn (~70-140 ms; a frame asked for
# meanwhile waits for it once, then slices are SLICE_WHILE_DRAWING): decoded chunks are joined up to it
# while no frames are drawn, as an insertion of 1 M points costs less a point than four of 250 k (a 20 M
# LAS load 3.2 -> 2.5 s, Zen 4); while frames are drawn, up to JOIN_WHILE_DRAWING (points show as they come).
# 2 M and 4 M were no faster and raised a 20 M load's peak by 137 / 483 MiB (docs/benchmarks.md, bench_slices.py)
SLICE_POINTS = 1_000_000
JOIN_WHILE_DRAWING = SMALL_BATCH
SLICE_WHILE_DRAWING = 50_000  # ... and while frames are drawn: a waiting frame waits ~5-10 ms at most
ORDER_POINTS = 2_000_000  # points of leaves ordered (octree.order_leaves: ~10 ns a point) under one hold while no frames are drawn
ORDER_WHILE_DRAWING = 400_000  # ... and while frames are drawn (~4 ms)
DECODE_CHUNK = 250_000  # points decoded at a time: decoding pauses between chunks while frames draw
_PRESIZED_BYTES_PER_POINT = 80  # what presizing for one expected point allocates, about (pool room, voxels, table)
MEMORY_SHARE = 0.5  # the default memory limit: this share of the machine's physical memory


def default_memory_limit() -> int:
    """Bytes a progressive octree may hold by default: half the machine's physical memory."""
    return int(MEMORY_SHARE * physical_memory())


def memory_limit_bytes(value) -> int:
    """``memory_limit=`` as bytes: None, half the machine's memory (``default_memory_limit``);
    else bytes or a size as ``gigapoint convert --memory-limit`` reads it ('8G', '512M'), at
    least 16M (an empty octree's arrays take a few); anything else a one-line InputError
    before anything is read."""
    if value is None:
        return default_memory_limit()
    from ..convert.options import parse_memory

    try:
        return parse_memory(value, "memory_limit", minimum=16 << 20)
    except GigapointError as exc:
        raise InputError(str(exc)) from None


class Loader:
    """The thread that fills ``octree`` from ``sources``: (name, make_chunks) pairs."""

    def __init__(
        self,
        octree,
        sources: list[tuple[str, Callable[[], Iterable[PointChunk]]]],
        total: int | None,
        memory_limit: int | None = None,
        point_filter: PointFilter | None = None,
    ):
        self.octree = octree
        self.memory_limit = memory_limit_bytes(memory_limit)
        self.sources = sources
        self.total = total  # input points, when the sources tell it up front (with a filter: at most that many kept)
        self.inserted = 0  # points inserted so far (valid or not)
        self.point_filter = point_filter  # the one the sources' chunks went through (file_sources): it counts the points read
        self.error: GigapointError | None = None
        self.warnings = KeptWarnings()  # (message, category) of the warnings of the load, in order
        self.complete = False  # every source read (not stopped by close, an error or the memory limit)
        self.started = time.perf_counter()
        self.finished_at: float | None = None
        self._stop = threading.Event()
        self._done = threading.Event()
        self._first_in = threading.Event()  # the first slice is inserted (the decoder then goes on)
        # run in the caller's context: the headers file_sources read (io headers_once) are not read again
        self._thread = threading.Thread(target=contextvars.copy_context().run, args=(self._run,), name=f"gigapoint-load-{octree.name}", daemon=True)

    def start(self) -> Loader:
        # numba's threads started by this thread, not by the loader's first kernel: TBB shuts them down
        # before a fork only from the thread that started them (numba's atfork handler), and each later fork
        # of this one (ffmpeg for a video, multiprocessing) printed "Numba: Attempted to fork from a non-main thread"
        numba.get_num_threads()
        self._thread.start()
        return self

    @property
    def done(self) -> bool:
        return self._done.is_set()

    @property
    def read(self) -> int:
        """Input points read so far: inserted, and with a filter those it left out too (``total`` counts them)."""
        if self.point_filter is None:
            return self.inserted
        return self.point_filter.read  # (the decoder's count: at most a chunk ahead of the insertion)

    @property
    def progress(self) -> float:
        """0..1: points read of the total (0 until done where no total is known; short of 1 after an error
        or a close part-way)."""
        if self._done.is_set() and self.complete and self.error is None:
            return 1.0
        if self.total:
            return min(1.0, self.read / self.total)
        return 0.0

    @property
    def points_per_second(self) -> float:
        end = self.finished_at or time.perf_counter()
        return self.read / max(end - self.started, 1e-9)

    def _chunks(self) -> Iterator[tuple[str, PointChunk]]:
        turn, made = -1, 0
        for name, make in self.sources:
            chunks = iter(make())
            while True:
                if made == 1:
                    # the second chunk waits for the first to be in: decoding holds the GIL (lazrs, the
                    # demo's kernels), which the first insertion, so the first image, would wait for
                    self._first_in.wait()
                turn, _ = self.octree.builder_turn(turn)  # decoding, too, waits while a frame draws
                chunk = next(chunks, None)
                if chunk is None:
                    break
                if not len(chunk):  # no slice to insert: the next chunk would wait for a first slice for good
                    continue
                made += 1
                yield name, chunk

    def _run(self) -> None:
        name = self.octree.name
        turn = -1
        keep_warnings(self.warnings)  # this thread's context, which the decoder's copies (prefetch)
        chunks = prefetch(self._chunks(), name="gigapoint-decode")  # held here: closed below, after the decoder is let go
        try:
            for name, chunk in _joined(chunks, self._join_points):
                s = 0
                # the attributes every source has so far: a file without one drops it, one with more brings none
                self.octree.keep_attributes(chunk.attributes)
                while s < len(chunk):
                    if self._stop.is_set():
                        return
                    turn, drawing = self.octree.builder_turn(turn)
                    sl = slice(s, min(s + (SLICE_WHILE_DRAWING if drawing else SLICE_POINTS), len(chunk)))
                    attrs = self.octree.held_of(chunk.attributes)
                    try:
                        self.octree.add_read(chunk.xyz[sl], chunk.rgba[sl], {a: v[sl] for a, v in attrs.items()}, chunk.color_bits)
                    except InputError as exc:
                        raise _of_source(exc, self.octree.name, name) from None
                    self._first_in.set()
                    s = sl.stop
                    self.inserted += sl.stop - sl.start
                    if self.octree.nbytes > self.memory_limit:
                        self._stop_for_memory(name)
                        return
            # every source read: no valid point is the plain cloud's error, invalid points skipped its warning
            from ...io import files_label

            if self.point_filter is not None:  # not "no valid points": the filter left none
                self.point_filter.check_passed(files_label(source for source, _ in self.sources))
            check_valid_count(files_label(source for source, _ in self.sources), self.octree.points, self.octree.skipped)
            self.complete = True
            while not self._stop.is_set():  # the leaves' draw order (a grid sample first), between frames
                turn, drawing = self.octree.builder_turn(turn)
                if not self.octree.order_leaves(ORDER_WHILE_DRAWING if drawing else ORDER_POINTS):
                    break
        except GigapointError as exc:
            self.error = exc
        except MemoryError:
            self.error = GigapointError(f"{name}: out of memory while loading")
        except Exception as exc:  # noqa: BLE001 - any failure of a source ends the load with a one-line error
            self.error = InputError(f"{name}: loading stopped: {' '.join(str(exc).split()) or type(exc).__name__}")
        finally:
            # the decoder may wait for the first slice: let it go before closing the prefetch, which
            # waits for it (an error inserting the first slice hung the load here for good)
            self._first_in.set()
            try:
                chunks.close()
                if not self._stop.is_set():
                    self.octree.trim()  # the room kept for growth, back
            except Exception as exc:  # noqa: BLE001 - (a library's warning made an error by the caller's filter: wait() waited for good)
                self.error = self.error or InputError(f"{name}: loading stopped: {' '.join(str(exc).split()) or type(exc).__name__}")
            finally:
                self.finished_at = time.perf_counter()
                self._done.set()

    def _join_points(self) -> int:
        """The points decoded chunks are joined up to before they go in (``_joined``)."""
        return JOIN_WHILE_DRAWING if self.octree.lock.frames_recent() else SLICE_POINTS

    def _stop_for_memory(self, name: str) -> None:
        of = f" of {self.total:,}" if self.total else ""
        self.error = MemoryLimitError(  # sizes in a unit that fits them: in GiB, a 40M limit read "0.0 GiB"
            f"{name}: loading stopped at {self.read:,}{of} points: the octree holds {human_bytes(self.octree.nbytes)}, its memory "
            f"limit ({human_bytes(self.memory_limit)}; pass memory_limit=, or convert the input with `gigapoint convert` to view all of it)"
        )

    def wait(self, timeout: float | None = None) -> bool:
        """Until the load ends: True once every source is read; False when ``timeout`` seconds pass
        first, or when ``close`` stopped the load part-way (it said True, as though complete);
        raises the load's error, after issuing its warnings (``issue_warnings``)."""
        finished = self._done.wait(timeout)
        self.issue_warnings()
        if self.error is not None:
            raise self.error
        return finished and self.complete

    def wait_first_points(self) -> None:
        """Until the sources' first points are in, or the load has ended (for any thread but the
        loader's own): those points fix the octree's attributes, where a program's ``add`` before
        them fixed its own set (none), and every attribute of the files was dropped."""
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._first_in.wait()

    def close(self) -> None:
        """Stop loading (after the slice in hand) and wait for the thread."""
        self._stop.set()
        self._first_in.set()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join()
        self.issue_warnings()

    def issue_warnings(self) -> None:
        """Issue the load's warnings not issued yet, each once and in order, in this (the caller's)
        thread, where its filters and catches apply, at the caller's line (errors.outside_stacklevel)."""
        self.warnings.issue()


def _of_source(exc: InputError, label: str, source: str) -> InputError:
    """An insertion's error naming ``source``, the file its points came from: the octree's names
    the octree (``label``), which for several files said only "2 files"."""
    return type(exc)(f"{source}: {str(exc).removeprefix(f'{label}: ')}")


def _joined(chunks: Iterator[tuple[str, PointChunk]], least: int | Callable[[], int]) -> Iterator[tuple[str, PointChunk]]:
    """``chunks`` with runs of small ones (fewer than ``least`` points, or ``least()``, asked as each chunk comes:
    many small files, decoded chunks) joined into chunks of that many points or more, where their
    attributes are the same: an insertion costs ~0.1 ms whatever its size (2 000 files of 50 points
    loaded in 1.7 s, one by one), and a large one less a point than several small ones
    (SLICE_POINTS). The first chunk goes in as it is (the first image; the decoder waits for it), and a source's
    error comes after the points read before it are given (they stay drawable)."""
    held: list[PointChunk] = []
    held_points, name, first = 0, "", True

    def kind(chunk: PointChunk) -> list:
        return [(a, v.dtype) for a, v in chunk.attributes.items()]

    while True:
        try:
            item = next(chunks, None)
        except BaseException:
            if held:
                yield name, join_chunks(held)
            raise
        if item is not None and first:
            first = False
            yield item
            continue
        target = least() if callable(least) else least
        if held and (item is None or kind(item[1]) != kind(held[0]) or len(item[1]) >= target):
            yield name, join_chunks(held)
            held, held_points = [], 0
        if item is None:
            return
        if len(item[1]) >= target:
            yield item
            continue
        name = item[0]  # (the last file of a join: an error inserting it names one of them)
        held.append(item[1])
        held_points += len(item[1])
        if held_points >= target:
            yield name, join_chunks(held)
            held, held_points = [], 0


def _reachable(bounds: tuple, offset, scale) -> bool:
    """Whether a LAS header's bounds are ones its points can have: finite, low <= high, within
    what its 32-bit integer coordinates reach. A header's 1e12 drew a quarter of the image wrong (a
    root cube past the octree's levels); such bounds are left out, and the points make the root."""
    lo, hi = (np.asarray(b, np.float64) for b in bounds)
    if offset is None or scale is None:
        return bool(np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(lo <= hi))
    reach = np.abs(np.asarray(scale, np.float64)) * 2.0**31 * (1 + 1e-9)
    low, high = np.asarray(offset, np.float64) - reach, np.asarray(offset, np.float64) + reach
    with np.errstate(invalid="ignore"):  # NaN fails every comparison
        return bool(np.all(lo <= hi) and np.all(lo >= low) and np.all(hi <= high))


def file_sources(paths, cut_off: list | None = None, point_filter: PointFilter | None = None) -> tuple[list, int | None, tuple[np.ndarray, np.ndarray] | None, str, tuple | None]:
    """(sources, total points, header bounds of all files, name, grid) of files and directories:
    every file through its reader (io registry), in bounded chunks; a file cut off gives the
    points before the cut, then its error (``read_salvaged``; its name appended to ``cut_off``). Totals, bounds and the grid
    are known when every file's header tells them (LAS/LAZ); the grid (ProgressiveOctree's) is
    the first file's offset and the finest scale (points of files on other grids stay wide).
    ``point_filter``: each chunk goes through it as it is read (the total, then, counts points
    read, not kept; the bounds are cut to its clip box)."""
    from ...core.cloud import finest_scale
    from ...io import cloud_name, point_files_of, reader_for, scan_angles_differ, warn_mixed_crs
    from ...io._base import DEFAULT_CHUNK_SIZE
    from ...io.las import with_scan_angle

    files = point_files_of(paths)  # (an empty file among several: skipped, as gp.open and convert skip it)
    warn_mixed_crs(files)
    read = with_scan_angle if scan_angles_differ(files) else iter
    sources, total, lo, hi = [], 0, np.full(3, np.inf), np.full(3, -np.inf)
    bounds_known, offsets, scales = True, [], []
    for f in files:
        reader = reader_for(f)
        head = reader.header(f, salvage=True)  # not info(): an NPY file's info read all its points before the loader began
        n = head["point_count"]
        if n == 0:  # the reader's one-line error now, as gp.open's: not a cloud that loads nothing and says so at wait()
            next(iter(reader.read_chunks(f)), None)
        if head.get("truncated") and cut_off is not None:
            cut_off.append(str(f))
        total = None if total is None or n is None else total + n
        b = head.get("bounds")
        if b is not None and _reachable(b, head.get("offset"), head.get("scale")):
            lo, hi = np.minimum(lo, b[0]), np.maximum(hi, b[1])
        else:
            bounds_known = False
        offsets.append(head.get("offset"))
        scales.append(head.get("scale"))
        sources.append((str(f), lambda f=f, reader=reader: filtered(read(reader.read_salvaged(f, min(DEFAULT_CHUNK_SIZE, DECODE_CHUNK))), f, point_filter)))
    if point_filter is not None:  # the root cube of the points kept: a clip box of a corner of the survey is not drawn tiny
        lo, hi = point_filter.clipped_bounds(lo, hi)
    name = cloud_name(files)
    grid, scale = None, finest_scale(scales)
    if scale is not None and all(o is not None for o in offsets):
        step = float(np.min(scale))  # one step for every axis: the finer axes' grid holds the coarser ones' points
        if np.isfinite(step) and step > 0 and np.all(np.isfinite(offsets[0])):  # a header's nonsense: no grid, points kept wide
            grid = (np.asarray(offsets[0], np.float64), step)
    return sources, total, ((lo, hi) if bounds_known and np.all(lo <= hi) else None), name, grid


def demo_sources(n_points: int, seed: int = 0) -> tuple[list, int, tuple[np.ndarray, np.ndarray] | None, str]:
    """The procedural demo town as a source, generated DECODE_CHUNK points at a time."""
    from ...io.demo import demo_chunks

    return [(f"demo({n_points:,})", lambda: demo_chunks(n_points, seed, chunk_size=DECODE_CHUNK))], n_points, None, f"demo({n_points:,})"


def open_progressive(sources, total, bounds, name, grid=None, max_leaf=None, memory_limit=None, point_filter=None):
    """A ProgressiveOctree filled by a started Loader (bounds: the root cube, when known; grid:
    the sources' grid, when they have one: ProgressiveOctree's ``grid``; loading stops with a
    MemoryLimitError once the octree holds ``memory_limit`` bytes, by default half the
    machine's memory; ``point_filter``: the one ``file_sources`` was given, which counts the
    points read and says where it left none)."""
    from .octree import MAX_LEAF, ProgressiveOctree

    cube = None
    if bounds is not None:
        lo, hi = (np.asarray(b, np.float64) for b in bounds)
        pad = header_slack(lo, hi)  # headers round their bounds
        cube = (lo - pad, float(np.max(hi - lo)) + 2 * pad)
    memory_limit = memory_limit_bytes(memory_limit)
    capacity = min(total or 0, memory_limit // _PRESIZED_BYTES_PER_POINT)  # presized no larger than the limit allows
    octree = ProgressiveOctree(name, cube=cube, max_leaf=max_leaf or MAX_LEAF, capacity=capacity, grid=grid)
    octree.source_files = [Path(label) for label, _ in sources if Path(label).is_file()]  # save() takes their CRS
    octree.attach(Loader(octree, sources, total, memory_limit, point_filter).start())
    return octree


@headers_once()  # the headers file_sources reads, read once: its loader thread takes them along
def open_sized(paths, point_budget: int, progressive: bool | None = None, progress: bool = False, point_filter=None):
    """What ``gigapoint view`` and ``render`` open: an octree (a converted folder, COPC, EPT) as
    itself; other inputs as a ProgressiveOctree (drawable while it loads) when asked, or when
    their headers count more points than ``point_budget``, or when one is cut off (what it
    holds drawn, its error said); else as one PointCloud. ``point_filter`` (io/filters.py):
    only the points it keeps are read, or of an octree drawn (``reader.open_filtered``: level
    of detail, the nodes meeting it read as frames need them)."""
    from ...io import expand_paths, lone_match, open_cloud
    from ..reader import is_lod_source, open_filtered, open_octree, refuse_octrees

    paths = lone_match(paths)  # (a pattern matching one octree opens it)
    if len(paths) == 1 and is_lod_source(paths[0]) and not progressive:
        return open_octree(paths[0]) if point_filter is None else open_filtered(paths[0], point_filter, "filter the point files, or wait for the octree")
    # (--progressive of a converted folder drew it as stored, without a word; a local COPC file is read as LAZ)
    refuse_octrees(paths, "it cannot join other files" if len(paths) > 1 else "--progressive builds an octree from point files")
    paths = expand_paths(paths)  # once: a file named twice was warned about twice (headers, then the points)
    if progressive is not False:
        cut_off = []
        sources, total, bounds, name, grid = file_sources(paths, cut_off, point_filter)
        # (a file cut off, too: what it holds is drawn, with its error, where the plain cloud only refuses it)
        if progressive or cut_off or (total is not None and total > point_budget):
            return open_progressive(sources, total, bounds, name, grid, point_filter=point_filter)
    return open_cloud(*paths, progress=progress, point_filter=point_filter)
