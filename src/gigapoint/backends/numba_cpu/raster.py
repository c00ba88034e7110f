"""The CPU software rasterizer: per-thread 64-bit visibility buffers merged by min.

Numba has no atomics on the CPU, so each thread rasterizes a contiguous run of batches
into its own buffer (thread 0 straight into the frame) and a merge takes the per-pixel
minimum. Within a thread points arrive in increasing index order, so a plain
``key < old`` test gives the contract's ties-to-lower-index rule, and the merge by min
makes the image independent of the thread count.

Each batch is drawn in two phases so the arithmetic vectorises: (1) decode + project all
its points into small scratch arrays (pixel id, depth bits), (2) the depth test and write.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

EMPTY = np.uint64(0xFFFFFFFFFFFFFFFF)
_MASK = np.uint32(1023)
_HALF = np.float32(0.5)
_INV1024 = np.float32(1.0 / 1024.0)


@njit(inline="always")
def _grid_coords(low, med, high, i, bits):
    """A point's position in units of its batch's 10-bit grid (cell centres), float32."""
    w = low[i]
    x = np.float32(w & _MASK)
    y = np.float32((w >> np.uint32(10)) & _MASK)
    z = np.float32((w >> np.uint32(20)) & _MASK)
    if bits == 10:
        return x + _HALF, y + _HALF, z + _HALF
    m = med[i]
    fx = np.float32(m & _MASK)
    fy = np.float32((m >> np.uint32(10)) & _MASK)
    fz = np.float32((m >> np.uint32(20)) & _MASK)
    if bits == 20:
        return x + (fx + _HALF) * _INV1024, y + (fy + _HALF) * _INV1024, z + (fz + _HALF) * _INV1024
    h = high[i]
    gx = np.float32(h & _MASK)
    gy = np.float32((h >> np.uint32(10)) & _MASK)
    gz = np.float32((h >> np.uint32(20)) & _MASK)
    return (
        x + (fx + (gx + _HALF) * _INV1024) * _INV1024,
        y + (fy + (gy + _HALF) * _INV1024) * _INV1024,
        z + (fz + (gz + _HALF) * _INV1024) * _INV1024,
    )


@njit(inline="always")
def _project(m, x, y, z, width, height, near, far):
    """(pixel id or -1, depth) of a grid-space point under batch matrix m (float32 math)."""
    sx = m[0, 0] * x + m[0, 1] * y + m[0, 2] * z + m[0, 3]
    sy = m[1, 0] * x + m[1, 1] * y + m[1, 2] * z + m[1, 3]
    sw = m[2, 0] * x + m[2, 1] * y + m[2, 2] * z + m[2, 3]
    sd = m[3, 0] * x + m[3, 1] * y + m[3, 2] * z + m[3, 3]
    px = sx / sw
    py = sy / sw
    inside = (sd > near) & (sd < far) & (sw > 0) & (px >= 0) & (px < width) & (py >= 0) & (py < height)
    pix = np.int32(-1)
    if inside:
        pix = np.int32(py) * np.int32(width) + np.int32(px)
    return pix, sd


@njit(inline="always")
def _draw_batch(m, first, count, bits, low, med, high, width, height, near, far, pix, depth, depth_bits, buf):
    """Project one batch into scratch, then depth-test into buf. Returns the min/max row touched."""
    for j in range(count):
        x, y, z = _grid_coords(low, med, high, first + j, bits)
        pix[j], depth[j] = _project(m, x, y, z, width, height, near, far)
    row_lo = height
    row_hi = -1
    for j in range(count):
        p = pix[j]
        if p >= 0:
            key = (np.uint64(depth_bits[j]) << np.uint64(32)) | np.uint64(first + j)
            if key < buf[p]:
                buf[p] = key
                r = p // width
                row_lo = min(row_lo, r)
                row_hi = max(row_hi, r)
    return row_lo, row_hi


@njit(parallel=True, cache=True)
def fill_empty(buf):
    for i in prange(buf.shape[0]):
        buf[i] = EMPTY


@njit(parallel=True, cache=True)
def rasterize(firsts, counts, bits, mats, low, med, high, width, height, near, far, starts, frame, scratch, rows_touched):
    """Draw the selected batches into ``frame`` (pre-filled with EMPTY).

    starts[t]..starts[t+1] are the selection entries thread t draws; scratch[t-1] is
    thread t's buffer (EMPTY on entry, restored to EMPTY by ``merge``).
    rows_touched[t] receives the row range thread t wrote.
    """
    n_threads = starts.shape[0] - 1
    max_count = 0
    for k in range(counts.shape[0]):
        max_count = max(max_count, counts[k])
    near32 = np.float32(near)
    far32 = np.float32(far)
    for t in prange(n_threads):
        buf = frame if t == 0 else scratch[t - 1]
        pix = np.empty(max_count, np.int32)
        depth = np.empty(max_count, np.float32)
        depth_bits = depth.view(np.uint32)
        lo = height
        hi = -1
        for k in range(starts[t], starts[t + 1]):
            r0, r1 = _draw_batch(mats[k], firsts[k], counts[k], bits[k], low, med, high, width, height, near32, far32, pix, depth, depth_bits, buf)
            lo = min(lo, r0)
            hi = max(hi, r1)
        rows_touched[t, 0] = lo
        rows_touched[t, 1] = hi


@njit(parallel=True, cache=True)
def merge(frame, scratch, rows_touched, width):
    """frame = min(frame, scratch[t]) over the rows each thread touched; scratch back to EMPTY."""
    lo = rows_touched[:, 0].min()
    hi = rows_touched[:, 1].max()
    for r in prange(lo, hi + 1):
        for t in range(1, rows_touched.shape[0]):
            if rows_touched[t, 0] <= r <= rows_touched[t, 1]:
                sb = scratch[t - 1]
                for p in range(r * width, (r + 1) * width):
                    v = sb[p]
                    if v != EMPTY:
                        if v < frame[p]:
                            frame[p] = v
                        sb[p] = EMPTY


@njit(parallel=True, cache=True)
def resolve_colors(frame, color, background, out):
    """out[p] = color of the winning point, or the background (u32 RGBA)."""
    for p in prange(frame.shape[0]):
        key = frame[p]
        if key == EMPTY:
            out[p] = background
        else:
            out[p] = color[key & np.uint64(0xFFFFFFFF)]
