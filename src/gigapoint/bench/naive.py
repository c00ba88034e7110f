"""The naive baseline: the first numba loop one writes (no batches, culling or quantization),
with gigapoint's merge and colour resolve after it, so only the raster differs."""

from __future__ import annotations

import time

import numpy as np
from numba import njit, prange

from ..backends.numba_cpu import NumbaCpuBackend
from ..backends.numba_cpu.raster import NO_TABLE, TILE_SHIFT, fill_empty, merge, resolve_colors
from ..core.threads import numba_threads
from ..render import Camera


@njit(parallel=True, cache=True, error_model="numpy")  # numpy's model: no zero-division branch on x'/w
def naive_raster(xyz, m, width, height, near, far, bufs):
    """The first loop one writes: point i of ``xyz`` (float32 (N, 3)) through ``m`` (float32
    4x4, rows x', y', w, depth), depth-tested into thread t's buffer ``bufs[t]`` (EMPTY on
    entry) with the key (depth bits << 32 | i). Thread t takes the t-th contiguous share of
    the points; no batches, no culling, no quantization, no vectorised phases."""
    n = xyz.shape[0]
    n_threads = bufs.shape[0]
    for t in prange(n_threads):
        buf = bufs[t]
        depth = np.empty(1, np.float32)
        depth_bits = depth.view(np.uint32)
        for i in range(t * n // n_threads, (t + 1) * n // n_threads):
            x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
            sx = m[0, 0] * x + m[0, 1] * y + m[0, 2] * z + m[0, 3]
            sy = m[1, 0] * x + m[1, 1] * y + m[1, 2] * z + m[1, 3]
            sw = m[2, 0] * x + m[2, 1] * y + m[2, 2] * z + m[2, 3]
            sd = m[3, 0] * x + m[3, 1] * y + m[3, 2] * z + m[3, 3]
            if sw <= 0 or sd <= near or sd >= far:
                continue
            px = sx / sw
            py = sy / sw
            if px < 0 or px >= width or py < 0 or py >= height:
                continue
            p = np.int64(py) * width + np.int64(px)
            depth[0] = sd
            key = (np.uint64(depth_bits[0]) << np.uint64(32)) | np.uint64(i)
            buf[p] = min(buf[p], key)


def naive_matrix(camera: Camera, center) -> np.ndarray:
    """float32 rows (x', y', w, depth) of ``camera`` for points given relative to ``center``."""
    to_world = np.eye(4)
    to_world[:3, 3] = center
    return (camera.screen_rows() @ to_world).astype(np.float32)


def naive_frame(xyz, color, camera: Camera, near: float, far: float, n_threads: int, background=(0, 0, 0, 255), center=(0.0, 0.0, 0.0)):
    """(visibility (H*W,) u64, colors (H*W,) u32, seconds in ``naive_raster``) of one naive frame:
    clear the per-thread buffers, the loop, the merge, and gigapoint's own colour resolve."""
    n_pixels = camera.width * camera.height
    with NumbaCpuBackend.lock, numba_threads(n_threads):  # numba's parallel kernels: one caller at a time
        bufs = np.empty((n_threads, n_pixels), np.uint64)
        for b in bufs:
            fill_empty(b)
        t0 = time.perf_counter()
        naive_raster(xyz, naive_matrix(camera, center), camera.width, camera.height, np.float32(near), np.float32(far), bufs)
        t1 = time.perf_counter()
        frame = bufs[0]
        if n_threads > 1:  # gigapoint's merge with every tile flagged: the naive loop keeps no flags
            merge(frame, bufs[1:], np.ones((n_threads, (n_pixels >> TILE_SHIFT) + 1), np.uint8))
        colors = np.empty(n_pixels, np.uint32)
        resolve_colors(frame, color, np.array(background, np.uint8).view(np.uint32)[0], colors, NO_TABLE, NO_TABLE, 0)
    return frame, colors, t1 - t0
