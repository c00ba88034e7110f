"""High-quality shading (Schütz et al. 2021/2022, 3.6): blend all points near the closest depth.

After the depth pass (the normal rasterization), every point whose depth is within
``tolerance`` (relative) behind the closest point of its pixel adds its color and a count;
the resolve divides. The screen is cut into one band of rows per thread; a thread re-projects
only the batches that reach its band, sums into one packed u64 per pixel (exact integer sums,
spilled into wider ones past 32 points a pixel: exact for up to 2^24) and resolves its own
rows right away. The mean is rounded half up and every pixel is summed by one thread, so the
image does not depend on the thread count.
"""

from __future__ import annotations

import numba
import numpy as np

from ...backends.numba_cpu import passes as kernels
from ...core.layout import EMPTY_PIXEL
from ..reference import footprint_pixels, projected_batches
from .splats import point_sizes

_buffers: dict = {}
_ONE = np.array([[0, 0, 1]], np.int32)
# corners of a batch's 10-bit grid (every point decodes inside it), homogeneous
_GRID_CORNERS = np.array([[x, y, z, 1.0] for x in (0, 1024) for y in (0, 1024) for z in (0, 1024)])
_ROW_MARGIN = 4  # rows added around a batch's projected corners (float32 rounding of the points)
_RESOLVE_POINTS_PER_ROW = 0.15  # cost of resolving one pixel, in points accumulated (for balancing)


def _accumulators(n_pixels: int):
    """Packed sums and spill sums, zero on entry; ``hqs_shade`` sets them back to zero.
    The spill arrays are calloc'ed: pages no pixel spills into never take memory."""
    bufs = _buffers.get(n_pixels)
    if bufs is None:
        _buffers.clear()
        bufs = tuple(np.zeros(n_pixels, t) for t in (np.uint64, np.uint64, np.uint64, np.uint32))
        _buffers[n_pixels] = bufs
    return bufs


def batch_rows(matrices: np.ndarray, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(first row, last row, rows spanned) each batch's points can land on: its grid cube's 8
    corners projected (float64) with a margin; the whole screen where the cube reaches behind
    the eye. The span (unclipped, >= 1) spreads a batch's points over rows for balancing."""
    p = np.einsum("cj,kij->kci", _GRID_CORNERS, matrices.astype(np.float64))  # (k, 8, 4): x', y', w, depth
    w = p[..., 2]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        y = p[..., 1] / w
        lo = np.floor(y.min(axis=1)) - _ROW_MARGIN
        hi = np.floor(y.max(axis=1)) + _ROW_MARGIN
    whole = ~(np.all(w > 0, axis=1) & np.isfinite(lo) & np.isfinite(hi))
    lo[whole], hi[whole] = 0, height - 1
    span = np.maximum(hi - lo + 1, 1.0)
    return np.clip(lo, -1, height).astype(np.int64), np.clip(hi, -1, height).astype(np.int64), span


def split_rows(row_lo, row_hi, span, counts, width: int, height: int, n_bands: int) -> np.ndarray:
    """bands[0..n_bands]: row bounds giving each band about the same work, counting each batch's
    points spread evenly over the rows it spans plus the resolve of every row."""
    if n_bands == 1:
        return np.array([0, height], np.int64)
    lo = np.clip(row_lo, 0, height)
    hi = np.clip(row_hi + 1, 0, height)
    on = hi > lo
    per_row = counts[on] / span[on]
    density = np.bincount(lo[on], per_row, height + 1) - np.bincount(hi[on], per_row, height + 1)
    cost = np.cumsum(np.cumsum(density)[:height] + width * _RESOLVE_POINTS_PER_ROW)
    inner = np.searchsorted(cost, cost[-1] * np.arange(1, n_bands) / n_bands) + 1
    return np.concatenate([[0], np.minimum(inner, height), [height]]).astype(np.int64)


def hqs_colors(
    cloud, sel, vis, width, height, near, far, point_colors, fallback, tolerance=0.01, threads=None, splat=None, softness=0.0, bands=None
) -> np.ndarray:
    """(H*W,) u32 mean color of the points within ``tolerance`` of each pixel's closest depth.

    ``vis`` is the depth pass's (H*W,) visibility buffer; ``fallback`` the colors of pixels
    no point contributed to (empty, or filled by a later pass). ``splat``: (footprint, size,
    atten) of points larger than a pixel (passes/splats.py); each footprint pixel blends.
    ``bands``: how many bands of rows the screen is cut into (default: one per thread)."""
    footprint, size, atten = splat if splat is not None else (_ONE, np.float32(1), np.float32(0))
    vis = np.ascontiguousarray(vis).reshape(-1)
    n_threads = max(1, min(threads or numba.get_num_threads(), numba.config.NUMBA_NUM_THREADS, height))
    batches = cloud.batches[sel.ids]
    counts = batches["count"].astype(np.int64)
    matrices = np.ascontiguousarray(sel.matrices, np.float32)
    row_lo, row_hi, span = batch_rows(matrices, height)
    bands = split_rows(row_lo, row_hi, span, counts, width, height, max(1, min(int(bands or n_threads), height)))
    acc, spill_rg, spill_ba, spill_n = _accumulators(width * height)
    out = np.empty(width * height, np.uint32)
    previous = numba.get_num_threads()
    numba.set_num_threads(n_threads)
    try:  # if the pass fails half-way the sums are dirty: drop them
        kernels.hqs_shade(
            batches["first"].astype(np.int64), counts, np.ascontiguousarray(sel.bits, np.int32), matrices, row_lo, row_hi,
            cloud.low, cloud.med, cloud.high, width, height, near, far, bands, vis.view(np.float32), np.float32(1.0 + tolerance),
            point_colors, np.ascontiguousarray(footprint, np.int32), np.float32(size), np.float32(atten), float(softness),
            acc, spill_rg, spill_ba, spill_n, np.ascontiguousarray(fallback).reshape(-1), out,
        )  # fmt: skip
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
    for first, idx, x0, y0, d in projected_batches(cloud, sel, width, height, near, far):
        sizes = point_sizes(d, size, atten)
        for dx, dy, m, pix in footprint_pixels(x0, y0, sizes, footprint, width, height):
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
