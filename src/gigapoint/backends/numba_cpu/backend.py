"""NumbaCpuBackend: drives the kernels in raster.py, owns the per-thread buffers, its passes
(passes.py) and the lock every numba kernel of a frame runs under."""

from __future__ import annotations

import itertools
import threading

import numba
import numpy as np

from ...core.threads import numba_threads
from ...render.splats import ONE_PIXEL
from . import raster
from .passes import CpuPasses

_NO_WORDS = np.zeros(0, np.uint32)
_NO_EXT = np.zeros(0, np.uint64)
_NO_BANDS = np.zeros(0, np.int64)  # rasterize without bands: threads split the batches
BAND_SAMPLES = 16  # points of each batch that ``band_plan`` places to balance the bands
BAND_POINT_COST = 4.0  # a splat point's own work, in pixel writes (projection, size, the row division)


def layout_words(points, ids) -> tuple:
    """``raster.rasterize``'s (med, high, ext, ext_firsts, codes) for the batches ``ids``: the
    medium/high word arrays, or the compact layout's streams and codes (core/compact.py)."""
    if points.med is not None:  # three words a point (else the compact layout: core/compact.py)
        return points.med, points.high, _NO_EXT, np.zeros(len(ids), np.int64), np.full(len(ids), raster.FULL_LAYOUT, np.uint32)
    chosen = points.packing[ids]
    return _NO_WORDS, _NO_WORDS, points.ext, chosen["ext_first"].astype(np.int64), chosen["code"].astype(np.uint32)


def split_by_points(counts: np.ndarray, n_parts: int) -> np.ndarray:
    """starts[0..n_parts]: contiguous runs of batches holding about equal point counts."""
    if len(counts) == 0:
        return np.zeros(n_parts + 1, np.int64)
    cum = np.cumsum(counts, dtype=np.int64)
    targets = cum[-1] * np.arange(1, n_parts) / n_parts
    inner = np.searchsorted(cum, targets, side="left") + 1
    return np.concatenate([[0], np.minimum(inner, len(counts)), [len(counts)]]).astype(np.int64)


def band_plan(matrices, firsts, counts, low, width: int, height: int, splat, n_parts: int):
    """(starts, entries, bands) of ``raster.rasterize``'s banded mode: the image cut into
    ``n_parts`` bands of rows holding about equal shares of the work, and per band the
    batches whose points may write its rows.

    The work is estimated from ``BAND_SAMPLES`` points of each batch (evenly spaced in its
    Morton order: spread over it), placed by their low words (10-bit cells) and projected with
    the batch's matrix (``matrices``, (k, 4, 4)): per point ``BAND_POINT_COST`` plus the pixels
    of its ``splat`` (footprint, size, atten; render/splats.py) at its depth. A batch's rows: the
    projection of its grid cube [0, 1024]^3, the largest splat's reach more each way and one for
    float32 rounding; all rows where a corner is behind the eye."""
    footprint, size, atten = splat
    reach = int(np.abs(footprint[:, 1]).max())
    top, bottom, work = _band_rows_and_work(
        np.ascontiguousarray(matrices, np.float64), firsts, counts, low, height, reach, float(size), float(atten), BAND_SAMPLES, BAND_POINT_COST
    )  # fmt: skip
    above = np.concatenate([[0.0], np.cumsum(work)])
    cuts = np.searchsorted(above, above[-1] * np.arange(1, n_parts) / n_parts)
    bands = np.concatenate([[0], cuts, [height]]).astype(np.int64)
    parts = [np.nonzero((bottom >= lo) & (top < hi))[0] for lo, hi in itertools.pairwise(bands)]
    starts = np.concatenate([[0], np.cumsum([len(p) for p in parts])]).astype(np.int64)
    return starts, np.concatenate(parts).astype(np.int64), bands


@numba.njit(cache=True)
def _band_rows_and_work(m, firsts, counts, low, height, reach, size, atten, n_samples, point_cost):
    """``band_plan``'s per-batch part, one loop (numpy's stacked products and temporaries took
    4-9 ms a frame for a progressive octree's 2 500 batches): each batch's rows (top, bottom)
    and the estimated work a row, summed over the batches' sample points."""
    k = firsts.shape[0]
    top = np.zeros(k, np.int64)
    bottom = np.full(k, height - 1, np.int64)
    work = np.zeros(height)
    for b in range(k):
        lo_y, hi_y, seen = np.inf, -np.inf, True
        for c in range(8):  # the grid cube's corners [0, 1024]^3
            x, y, z = 1024.0 * (c >> 2), 1024.0 * ((c >> 1) & 1), 1024.0 * (c & 1)
            w = m[b, 2, 0] * x + m[b, 2, 1] * y + m[b, 2, 2] * z + m[b, 2, 3]
            if w <= 0:
                seen = False
                break
            ys = (m[b, 1, 0] * x + m[b, 1, 1] * y + m[b, 1, 2] * z + m[b, 1, 3]) / w
            lo_y, hi_y = min(lo_y, ys), max(hi_y, ys)
        if seen:  # else every row: a corner behind the eye
            top[b] = min(max(np.int64(np.floor(lo_y)) - reach - 1, 0), height - 1)
            bottom[b] = min(max(np.int64(np.floor(hi_y)) + reach + 1, 0), height - 1)
        n_low = low.shape[0]
        for s in range(n_samples):  # evenly spaced in the batch's Morton order: spread over it
            word = np.int64(low[min(firsts[b] + np.int64(counts[b] * (s + 0.5) / n_samples), n_low - 1)])
            x, y, z = (word & 1023) + 0.5, ((word >> 10) & 1023) + 0.5, ((word >> 20) & 1023) + 0.5
            w = m[b, 2, 0] * x + m[b, 2, 1] * y + m[b, 2, 2] * z + m[b, 2, 3]
            if w <= 0:
                continue
            row = (m[b, 1, 0] * x + m[b, 1, 1] * y + m[b, 1, 2] * z + m[b, 1, 3]) / w
            if not 0 <= row < height:
                continue
            depth = max(m[b, 3, 0] * x + m[b, 3, 1] * y + m[b, 3, 2] * z + m[b, 3, 3], 1e-9)
            px = np.floor(min(size, max(1.0, atten / depth))) if atten > 0 else np.floor(size)
            work[np.int64(row)] += counts[b] / n_samples * (point_cost + px * px)
    return top, bottom, work


class NumbaCpuBackend:
    """The ``Backend`` on the CPU (gigapoint.render.backend): always available."""

    name = "cpu"
    # Numba's parallel kernels are not re-entrant from several Python threads (the workqueue
    # layer aborts) and the passes' scratch buffers are shared: one frame at a time per
    # process, whichever instance draws it.
    lock = threading.RLock()

    def __init__(self) -> None:
        self._scratch: dict | None = None  # (views, threads - 1, pixels) -> buffers
        self.passes = CpuPasses()

    @classmethod
    def is_available(cls) -> bool:
        return True

    def describe(self) -> str:
        return f"cpu (numba {numba.__version__}, {numba.get_num_threads()} threads)"

    def _scratch_for(self, n_views: int, n_threads: int, n_pixels: int) -> tuple[np.ndarray, np.ndarray]:
        """Per-thread buffers (EMPTY between frames) and their written-tile flags (zero between
        frames), kept per shape: mono and stereo frames that alternate (a viewer, a benchmark)
        do not reallocate every time."""
        need = (n_views, n_threads, n_pixels)
        cache = self._scratch if isinstance(self._scratch, dict) else {}
        if need not in cache:
            if len(cache) >= 2:
                cache.pop(next(iter(cache)))
            buf = np.empty((n_views, n_threads - 1, n_pixels), np.uint64)
            for view in buf:
                for row in view:
                    raster.fill_empty(row)
            n_tiles = (n_pixels >> raster.TILE_SHIFT) + 1
            cache[need] = (buf, np.zeros((n_views, n_threads, n_tiles), np.uint8))
        self._scratch = cache
        return cache[need]

    def rasterize(
        self, points, selection, width: int, height: int, near: float, far: float, threads: int | None = None, splat=None, step: int = 1,
        keep_on_device: bool = False,
    ) -> np.ndarray:  # fmt: skip
        """The (height * width,) u64 visibility buffer of the selected batches.

        ``splat``: (footprint, size, atten) for points larger than a pixel (render/splats.py).
        ``step`` > 1: only every step-th point of each batch (a point cap). ``keep_on_device``:
        no difference here (host and device are one)."""
        return self.rasterize_views(
            points, selection.ids, selection.bits[None], selection.matrices[None], width, height, [near], [far], threads, splat, step
        )[0]

    def rasterize_views(self, points, ids, bits, matrices, width, height, nears, fars, threads=None, splat=None, step=1) -> np.ndarray:
        """(V, height * width) visibility buffers of V views drawn in one pass over batches ``ids``
        (bits (V, k), matrices (V, k, 4, 4), nears/fars (V,): each view's own)."""
        n_threads = threads or numba.get_num_threads()
        n_threads = max(1, min(n_threads, numba.config.NUMBA_NUM_THREADS))
        firsts = points.batches["first"][ids].astype(np.int64)  # two fields, not whole records: 0.1 ms less a frame
        counts = points.batches["count"][ids].astype(np.int64)
        if splat is None:
            splat = ONE_PIXEL
        if n_threads > 1 and len(nears) == 1 and len(splat[0]) > 1 and len(ids) > 0:
            # splats: each thread its own band of rows, straight into the frame. Split by batches,
            # the second thread's splats covered much of the image, and merging them back took
            # as long as drawing them
            starts, entries, bands = band_plan(matrices[0], firsts, counts, points.low, width, height, splat, n_threads)
        else:
            starts, entries, bands = split_by_points(counts, n_threads), np.arange(len(ids), dtype=np.int64), _NO_BANDS
        words = layout_words(points, ids)
        with self.lock:
            return self._rasterize_locked(points, width, height, np.asarray(nears, np.float64), np.asarray(fars, np.float64), n_threads, firsts, counts, starts,
                                          entries, bands, np.ascontiguousarray(bits, np.int32), np.ascontiguousarray(matrices, np.float32), splat, max(1, int(step)), words)  # fmt: skip

    def _rasterize_locked(self, points, width, height, nears, fars, n_threads, firsts, counts, starts, entries, bands, bits, matrices, splat, step, words):
        n_views = len(nears)
        frames = np.empty((n_views, width * height), np.uint64)
        for frame in frames:
            raster.fill_empty(frame)
        scratch, dirty = self._scratch_for(n_views, n_threads, width * height)
        with numba_threads(n_threads):
            raster.rasterize(
                firsts,
                counts,
                bits,
                matrices,
                points.low,
                *words,
                width,
                height,
                nears,
                fars,
                starts,
                entries,
                bands,
                frames,
                scratch,
                dirty,
                splat[0],
                np.float32(splat[1]),
                np.float32(splat[2]),
                np.int64(step),
                raster.shape_token(matrices),
            )
            if n_threads > 1 and len(bands) == 0:  # (bands: every thread drew into the frame)
                for v in range(n_views):
                    raster.merge(frames[v], scratch[v], dirty[v])
        return frames

    def resolve(self, visibility: np.ndarray, color: np.ndarray, background_rgba) -> np.ndarray:
        """u32 RGBA per pixel: the winning point's color or the background."""
        with self.lock:
            return self.passes.resolve(visibility, color, background_rgba)[0]
