"""NumbaCpuBackend: drives the kernels in raster.py, owns the per-thread buffers."""

from __future__ import annotations

import threading

import numba
import numpy as np

from . import raster

# Numba's parallel kernels are not re-entrant from several Python threads (the workqueue
# layer aborts) and the scratch buffers are shared: one frame at a time per process.
_KERNEL_LOCK = threading.RLock()


def split_by_points(counts: np.ndarray, n_parts: int) -> np.ndarray:
    """starts[0..n_parts]: contiguous runs of batches holding about equal point counts."""
    if len(counts) == 0:
        return np.zeros(n_parts + 1, np.int64)
    cum = np.cumsum(counts, dtype=np.int64)
    targets = cum[-1] * np.arange(1, n_parts) / n_parts
    inner = np.searchsorted(cum, targets, side="left") + 1
    return np.concatenate([[0], np.minimum(inner, len(counts)), [len(counts)]]).astype(np.int64)


class NumbaCpuBackend:
    name = "cpu"

    def __init__(self) -> None:
        self._scratch: np.ndarray | None = None

    def describe(self) -> str:
        return f"cpu (numba {numba.__version__}, {numba.get_num_threads()} threads)"

    def _scratch_for(self, n_threads: int, n_pixels: int) -> np.ndarray:
        need = (max(n_threads - 1, 0), n_pixels)
        if self._scratch is None or self._scratch.shape != need:
            self._scratch = None
            self._scratch = np.empty(need, np.uint64)
            for row in self._scratch:
                raster.fill_empty(row)
        return self._scratch

    def rasterize(self, cloud, selection, width: int, height: int, near: float, far: float, threads: int | None = None) -> np.ndarray:
        """The (height * width,) u64 visibility buffer of the selected batches."""
        n_threads = threads or numba.get_num_threads()
        n_threads = max(1, min(n_threads, numba.config.NUMBA_NUM_THREADS))
        batches = cloud.batches[selection.ids]
        counts = batches["count"].astype(np.int64)
        starts = split_by_points(counts, n_threads)
        with _KERNEL_LOCK:
            return self._rasterize_locked(cloud, width, height, near, far, n_threads, batches, counts, starts, selection)

    def _rasterize_locked(self, cloud, width, height, near, far, n_threads, batches, counts, starts, selection):
        frame = np.empty(width * height, np.uint64)
        raster.fill_empty(frame)
        scratch = self._scratch_for(n_threads, width * height)
        rows_touched = np.empty((n_threads, 2), np.int64)
        previous = numba.get_num_threads()
        numba.set_num_threads(n_threads)
        try:
            raster.rasterize(
                batches["first"].astype(np.int64),
                counts,
                selection.bits,
                selection.matrices,
                cloud.low,
                cloud.med,
                cloud.high,
                width,
                height,
                near,
                far,
                starts,
                frame,
                scratch,
                rows_touched,
            )
            if n_threads > 1:
                raster.merge(frame, scratch, rows_touched, width)
        finally:
            numba.set_num_threads(previous)
        return frame

    def resolve(self, visibility: np.ndarray, color: np.ndarray, background_rgba) -> np.ndarray:
        """u32 RGBA per pixel: the winning point's color or the background."""
        bg = np.array(background_rgba, np.uint8).view(np.uint32)[0]
        out = np.empty(visibility.shape[0], np.uint32)
        with _KERNEL_LOCK:
            raster.resolve_colors(visibility, color, bg, out)
        return out
