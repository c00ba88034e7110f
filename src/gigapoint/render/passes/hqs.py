"""High-quality shading (Schütz et al. 2021/2022, 3.6): blend all points near the closest depth.

After the depth pass (the normal rasterization), every point whose depth is within
``tolerance`` (relative) behind the closest point of its pixel adds its color and a count;
the resolve divides. Sums are integers (r | g << 32, b | a << 32 per u64, per thread,
merged in the resolve), exact for up to 2^24 points a pixel, and the mean is rounded
half up, so the image does not depend on the thread count.
"""

from __future__ import annotations

import numba
import numpy as np

from ...backends.numba_cpu import passes as kernels
from ...backends.numba_cpu.backend import split_by_points
from ...core.layout import EMPTY_PIXEL
from ..reference import grid_coordinates
from .splats import point_sizes

_buffers: dict = {}
_ONE = np.array([[0, 0, 1]], np.int32)


def _accumulators(n_threads: int, n_pixels: int):
    """Per-thread sums, zero on entry; ``hqs_resolve`` sets them back to zero as it reads them."""
    key = (n_threads, n_pixels)
    bufs = _buffers.get(key)
    if bufs is None:
        _buffers.clear()
        bufs = (
            np.zeros((n_threads, n_pixels), np.uint64),
            np.zeros((n_threads, n_pixels), np.uint64),
            np.zeros((n_threads, n_pixels), np.uint32),
        )
        _buffers[key] = bufs
    return bufs


def hqs_colors(
    cloud, sel, vis, width, height, near, far, point_colors, fallback, tolerance=0.01, threads=None, splat=None, softness=0.0
) -> np.ndarray:
    """(H*W,) u32 mean color of the points within ``tolerance`` of each pixel's closest depth.

    ``vis`` is the depth pass's (H*W,) visibility buffer; ``fallback`` the colors of pixels
    no point contributed to (empty, or filled by a later pass). ``splat``: (footprint, size,
    atten) of points larger than a pixel (passes/splats.py); each footprint pixel blends."""
    footprint, size, atten = splat if splat is not None else (_ONE, np.float32(1), np.float32(0))
    vis = np.ascontiguousarray(vis).reshape(-1)
    n_threads = max(1, min(threads or numba.get_num_threads(), numba.config.NUMBA_NUM_THREADS))
    batches = cloud.batches[sel.ids]
    counts = batches["count"].astype(np.int64)
    starts = split_by_points(counts, n_threads)
    rg, ba, cnt = _accumulators(n_threads, width * height)
    previous = numba.get_num_threads()
    numba.set_num_threads(n_threads)
    try:  # if the accumulation fails half-way the sums are dirty: drop them
        kernels.hqs_accumulate(
            batches["first"].astype(np.int64), counts, sel.bits, sel.matrices, cloud.low, cloud.med, cloud.high,
            width, height, near, far, starts, vis, vis.view(np.float32), np.float32(1.0 + tolerance), point_colors, rg, ba, cnt,
            footprint, np.float32(size), np.float32(atten), float(softness),
        )  # fmt: skip
        out = np.empty(width * height, np.uint32)
        kernels.hqs_resolve(rg, ba, cnt, np.ascontiguousarray(fallback).reshape(-1), out)
    except BaseException:
        _buffers.clear()
        raise
    finally:
        numba.set_num_threads(previous)
    return out


def hqs_reference(
    cloud, sel, vis, width, height, near, far, point_colors, fallback, tolerance=0.01, splat=None, softness=0.0
) -> np.ndarray:
    """Plain numpy: the same projection as the reference renderer, exact integer means."""
    vis = vis.reshape(-1)
    footprint, size, atten = splat if splat is not None else (_ONE, np.float32(1), np.float32(0))
    n = width * height
    sums = np.zeros((n, 4), np.int64)
    cnt = np.zeros(n, np.int64)
    depth0 = (vis >> np.uint64(32)).astype(np.uint32).view(np.float32)
    rgba = point_colors.view(np.uint8).reshape(-1, 4).astype(np.int64)
    for k, b in enumerate(sel.ids):
        first, count = int(cloud.batches["first"][b]), int(cloud.batches["count"][b])
        g = grid_coordinates(cloud, first, count, int(sel.bits[k]))
        m = sel.matrices[k]
        x, y, z = g[:, 0], g[:, 1], g[:, 2]
        sx, sy, sw, sd = (m[r, 0] * x + m[r, 1] * y + m[r, 2] * z + m[r, 3] for r in range(4))
        with np.errstate(divide="ignore", invalid="ignore"):
            px, py = sx / sw, sy / sw
        ok = (sd > np.float32(near)) & (sd < np.float32(far)) & (sw > 0) & (px >= 0) & (px < width) & (py >= 0) & (py < height)
        idx = np.flatnonzero(ok)
        x0, y0, d = px[ok].astype(np.int64), py[ok].astype(np.int64), sd[ok]
        sizes = point_sizes(d, size, atten)
        for dx, dy, need in footprint:
            m = (need <= sizes) & (x0 + dx >= 0) & (x0 + dx < width) & (y0 + dy >= 0) & (y0 + dy < height)
            pix = (y0[m] + dy) * width + x0[m] + dx
            keep = (vis[pix] != EMPTY_PIXEL) & (d[m] <= depth0[pix] * np.float32(1.0 + tolerance))
            if softness > 0:  # Kraft's eq. 3.1, quantised to 0..15
                o = 1.0 - (np.sqrt(float(dx * dx + dy * dy)) / (0.5 * sizes[m][keep].astype(np.float64))) ** softness
                w = np.maximum(0.0, 15.0 * o + 0.5).astype(np.int64)
            else:
                w = np.ones(int(keep.sum()), np.int64)
            np.add.at(sums, pix[keep], rgba[first + idx[m][keep]] * w[:, None])
            np.add.at(cnt, pix[keep], w)
    out = np.ascontiguousarray(fallback).reshape(-1).copy()
    hit = cnt > 0
    mean = (sums[hit] + cnt[hit, None] // 2) // cnt[hit, None]
    out[hit] = mean.astype(np.uint8).view(np.uint32).reshape(-1)
    return out
