"""The CPU software rasterizer: per-thread 64-bit visibility buffers merged by min.

Numba has no atomics on the CPU, so each thread rasterizes a contiguous run of batches
into its own buffer (thread 0 straight into the frame) and a merge takes the per-pixel
minimum. Within a thread points arrive in increasing index order, so a plain
``key < old`` test gives the contract's ties-to-lower-index rule, and the merge by min
makes the image independent of the thread count.

Each batch is drawn in two phases so the arithmetic vectorises: (1) decode + project all
its points into small scratch arrays (pixel id, depth bits), (2) the depth test and write.
``error_model="numpy"`` matters: Python's zero-division check on ``x / w`` alone stops
LLVM from vectorising phase 1 (6x slower).
"""

from __future__ import annotations

import functools

import numba
import numpy as np
from numba import njit, prange
from numba.extending import overload

from ...core.compact import expand_tails
from .simd import min_run8, resolve8_palette, resolve8_rgb565

EMPTY = np.uint64(0xFFFFFFFFFFFFFFFF)
TILE_SHIFT = 6  # merge bookkeeping: runs of 64 pixels
_TILE_SHIFT_U = np.uint32(TILE_SHIFT)
_TILE_SHIFT_U64 = np.uint64(TILE_SHIFT)
_MASK = np.uint32(1023)
_HALF = np.float32(0.5)
_INV1024 = np.float32(1.0 / 1024.0)
GENERAL, PERSPECTIVE, ORTHOGRAPHIC = 0, 1, 2  # batch matrix shapes (see project_point)
#: ``rasterize``'s layout code of a batch in three u32 words (others: core/compact.py's codes)
FULL_LAYOUT = np.uint32(0xFFFFFFFF)
NO_TABLE = np.zeros(0, np.uint32)  # resolve_colors: colors are u32 RGBA8


@njit
def _decode_word(w):
    """The three 10-bit components of a u32 word as float32.

    The int32 casts keep the vectorised decode in 32-bit lanes (numba widens u32 arithmetic
    to 64 bits otherwise): phase 1 gets 20 % faster."""
    return (
        np.float32(np.int32(w & _MASK)),
        np.float32(np.int32((w >> np.uint32(10)) & _MASK)),
        np.float32(np.int32((w >> np.uint32(20)) & _MASK)),
    )


@njit
def grid_coords(low, med, high, j, bits):
    """Point j's position in units of its batch's 10-bit grid (cell centres), float32."""
    x, y, z = _decode_word(low[j])
    if bits == 10:
        return x + _HALF, y + _HALF, z + _HALF
    fx, fy, fz = _decode_word(med[j])
    if bits == 20:
        return x + (fx + _HALF) * _INV1024, y + (fy + _HALF) * _INV1024, z + (fz + _HALF) * _INV1024
    gx, gy, gz = _decode_word(high[j])
    return (
        x + (fx + (gx + _HALF) * _INV1024) * _INV1024,
        y + (fy + (gy + _HALF) * _INV1024) * _INV1024,
        z + (fz + (gz + _HALF) * _INV1024) * _INV1024,
    )


@njit(error_model="numpy")
def project_point(m, x, y, z, wf, hf, wi, near, far, shape=0, clip=True):
    """(pixel id or -1, depth) of a grid-space point; m is the batch matrix as a 16-tuple.

    This operation order is the contract: the numpy reference and the WGSL shader follow
    it, so all three agree bit for bit. ``shape`` (a compile-time constant after inlining)
    skips work whose result is known exactly: PERSPECTIVE, the depth row equals the w row
    (so depth is w, bit for bit); ORTHOGRAPHIC, w is exactly 1 (x'/1 = x'). ``clip=False``
    for a batch that lies inside the frustum with a margin (``inside_frustum``): every
    point maps to a pixel, no test needed.
    """
    sx = m[0] * x + m[1] * y + m[2] * z + m[3]
    sy = m[4] * x + m[5] * y + m[6] * z + m[7]
    if shape == ORTHOGRAPHIC:
        sw = np.float32(1.0)
        px = sx
        py = sy
    else:
        sw = m[8] * x + m[9] * y + m[10] * z + m[11]
        px = sx / sw
        py = sy / sw
    if shape == PERSPECTIVE:
        sd = sw
    else:
        sd = m[12] * x + m[13] * y + m[14] * z + m[15]
    p = np.int32(py) * wi + np.int32(px)
    if not clip:
        return p, sd
    zero = np.float32(0.0)
    inside = (sd > near) & (sd < far) & (sw > zero) & (px >= zero) & (px < wf) & (py >= zero) & (py < hf)
    return (p if inside else np.int32(-1)), sd


@njit(inline="always")
def matrix_tuple(m):
    """A batch matrix as 16 scalars: values, so the compiler keeps them in registers."""
    return (
        m[0, 0], m[0, 1], m[0, 2], m[0, 3],
        m[1, 0], m[1, 1], m[1, 2], m[1, 3],
        m[2, 0], m[2, 1], m[2, 2], m[2, 3],
        m[3, 0], m[3, 1], m[3, 2], m[3, 3],
    )  # fmt: skip


@njit(inline="always")
def matrix_shape(m):
    """PERSPECTIVE when the depth row is the w row, ORTHOGRAPHIC when w is the constant 1."""
    if m[2, 0] == m[3, 0] and m[2, 1] == m[3, 1] and m[2, 2] == m[3, 2] and m[2, 3] == m[3, 3]:
        return PERSPECTIVE
    if m[2, 0] == 0 and m[2, 1] == 0 and m[2, 2] == 0 and m[2, 3] == 1:
        return ORTHOGRAPHIC
    return GENERAL


@functools.cache
def _projection_loop(bits, shape, clip):
    """The phase-1 loop of one precision, matrix shape and clipping. The three are constants of
    the compiled function (closure variables), so its body is branch-free and vectorises; the
    helpers are small functions LLVM inlines, constants folded. Each variant is a function of
    its own, made and compiled only when a frame first needs it: numba's IR inlining of one nested
    helper chain per variant (``inline="always"``, 18 copies) took 11 s of a 14 s compile, and the
    variants of the other matrix shapes took 2-4 s of the first render (one camera, one shape).
    A GENERAL matrix (neither a perspective nor an orthographic camera's: only hand-made ones)
    always clips (``_project_impl``), which is exact for a batch inside the frustum too.

    Each variant gets a name of its own: numba names a compiled function by its qualified name,
    its argument types and a counter of the process that compiled it, and every variant has the
    same argument types. Cached kernels (``project_batch``, ``rasterize``, the passes') carry
    their variants' code under those names, so two kernels cached by different processes could
    hold different variants under one name, and a process loading both ran one variant's code
    for the other (an orthographic frame projected as a perspective one, writing out of bounds)."""

    def loop(low, med, high, mt, wf, hf, wi, near, far, pix, depth):
        for j in range(low.shape[0]):
            x, y, z = grid_coords(low, med, high, j, bits)
            pix[j], depth[j] = project_point(mt, x, y, z, wf, hf, wi, near, far, shape, clip)

    loop.__name__ = loop.__qualname__ = f"projection_loop_{bits}bit_shape{shape}_{'clipped' if clip else 'unclipped'}"
    return njit(error_model="numpy")(loop)


# The matrix shape of a frame's batch matrices, a compile-time type: an empty array whose dtype
# names it. Kernels that project (rasterize, the HQS and transparency passes) take it, so each is
# compiled (and cached) per shape with that shape's loops only (``_project``).
SHAPE_TOKENS = {PERSPECTIVE: np.zeros(0, np.int8), ORTHOGRAPHIC: np.zeros(0, np.int16), GENERAL: np.zeros(0, np.int32)}
_TOKEN_SHAPES = {numba.from_dtype(t.dtype): shape for shape, t in SHAPE_TOKENS.items()}


def shape_token(mats: np.ndarray) -> np.ndarray:
    """The ``SHAPE_TOKENS`` entry of float32 batch matrices (..., 4, 4): PERSPECTIVE when every
    depth row equals its w row, ORTHOGRAPHIC when every w row is (0, 0, 0, 1), else GENERAL
    (exact for both: the same operations, only none skipped). ``matrix_shape`` for one."""
    m = np.asarray(mats).reshape(-1, 4, 4)
    if np.array_equal(m[:, 2], m[:, 3]):
        return SHAPE_TOKENS[PERSPECTIVE]
    if (m[:, 2, :3] == 0).all() and (m[:, 2, 3] == 1).all():
        return SHAPE_TOKENS[ORTHOGRAPHIC]
    return SHAPE_TOKENS[GENERAL]


def _project(token, bits, clip, args):
    """Phase 1 of one batch with the loop of its precision and clipping (numba only: ``_project_impl``)."""
    raise NotImplementedError("compiled code only")


@overload(_project)
def _project_impl(token, bits, clip, args):
    """Picks the matrix shape's loops when the caller compiles: only those are compiled."""
    shape = _TOKEN_SHAPES[token.dtype]
    unclipped = shape != GENERAL
    c10, n10 = _projection_loop(10, shape, True), _projection_loop(10, shape, not unclipped)
    c20, n20 = _projection_loop(20, shape, True), _projection_loop(20, shape, not unclipped)
    c30, n30 = _projection_loop(30, shape, True), _projection_loop(30, shape, not unclipped)

    def impl(token, bits, clip, args):
        if bits == 10:
            c10(*args) if clip else n10(*args)
        elif bits == 20:
            c20(*args) if clip else n20(*args)
        else:
            c30(*args) if clip else n30(*args)

    return impl


@njit
def _grid_corner(m, c):
    """(x', y', w, depth) in float64 of corner c (0..7) of a batch's grid cube [0, 1024]^3."""
    x = 1024.0 * ((c >> 2) & 1)
    y = 1024.0 * ((c >> 1) & 1)
    z = 1024.0 * (c & 1)
    sx = np.float64(m[0, 0]) * x + np.float64(m[0, 1]) * y + np.float64(m[0, 2]) * z + np.float64(m[0, 3])
    sy = np.float64(m[1, 0]) * x + np.float64(m[1, 1]) * y + np.float64(m[1, 2]) * z + np.float64(m[1, 3])
    sw = np.float64(m[2, 0]) * x + np.float64(m[2, 1]) * y + np.float64(m[2, 2]) * z + np.float64(m[2, 3])
    sd = np.float64(m[3, 0]) * x + np.float64(m[3, 1]) * y + np.float64(m[3, 2]) * z + np.float64(m[3, 3])
    return sx, sy, sw, sd


@njit
def inside_frustum(m, width, height, near, far):
    """True when the batch's whole grid cube [0, 1024]^3 projects inside the image and the
    depth range with a margin (1 pixel, 0.1 % of the depth): every point then has a pixel and
    phase 1 needs no clipping tests. Corners in float64 from the float32 matrix; the float32
    projection of a point differs from it by far less than the margin."""
    for c in range(8):
        sx, sy, sw, sd = _grid_corner(m, c)
        if not (sw > 0.0 and sd > near + 1e-3 * abs(near) + 1e-6 and sd < far - 1e-3 * abs(far)):
            return False
        if not (1.0 <= sx / sw <= width - 1.0 and 1.0 <= sy / sw <= height - 1.0):
            return False
    return True


@njit
def mark_footprint(m, width, height, dirty, n):
    """For a batch ``inside_frustum``: flag the tiles its projected grid cube covers (one pixel
    of margin) in ``dirty``, instead of one flag store per point (~4 % of a 2-thread overview).
    The cube's projection is the hull of its corners', so every point's pixel is inside.
    Returns False, flagging nothing, when the box has more tile rows than n / 4 (a large, sparse
    batch of a close-up: its points then flag their own tiles, and the merge visits fewer)."""
    x0 = np.inf
    x1 = -np.inf
    y0 = np.inf
    y1 = -np.inf
    for c in range(8):
        sx, sy, sw, _ = _grid_corner(m, c)
        x0 = min(x0, sx / sw)
        x1 = max(x1, sx / sw)
        y0 = min(y0, sy / sw)
        y1 = max(y1, sy / sw)
    xa = max(0, int(x0) - 1)
    xb = min(width - 1, int(x1) + 1)
    ya = max(0, int(y0) - 1)
    yb = min(height - 1, int(y1) + 1)
    if (yb - ya + 1) * (((xb - xa) >> TILE_SHIFT) + 2) > n >> 2:
        return False
    for y in range(ya, yb + 1):
        row = y * width
        for tile in range((row + xa) >> TILE_SHIFT, ((row + xb) >> TILE_SHIFT) + 1):
            dirty[tile] = 1
    return True


@njit(inline="always")
def gather_every(words, first, n, step, out):
    """out[:n] = words[first], words[first + step], ...: a subsample (every step-th point of a
    batch) made contiguous, so the one compiled projection of contiguous slices serves it."""
    for j in range(n):
        out[j] = words[first + j * step]


@njit(cache=True, error_model="numpy")
def project_batch(low, med, high, bits, m, width, height, near, far, pix, depth, clip, token):
    """Phase 1: pixel id (or -1) and float32 depth of each point of one batch.

    ``low/med/high`` are the batch's slices, ``m`` its float32 matrix from 10-bit grid
    units to (x', y', w, depth), ``token`` the matrix shape's (``shape_token``). One loop per
    precision, matrix shape and clipping (same body, constants folded) so each loop is
    branch-free and vectorises. ``clip=False`` only for a batch ``inside_frustum`` (most of
    them in an overview): no clipping tests.
    """
    args = (low, med, high, matrix_tuple(m), np.float32(width), np.float32(height), np.int32(width), near, far, pix, depth)
    _project(token, bits, clip, args)


@njit(inline="always")
def _write_pixels(first, step, pix, depth_bits, buf, dirty, clipped, mark):
    """The one-pixel phase 2. Two interleaved streams, the batch's halves, with a branch-free
    min: Morton order puts ~60 % of consecutive points on the pixel just written, so one
    stream waits on its own store (store-to-load forwarding) every other point; the far
    half's pixels are others, and its chain runs alongside. (A ``key < old`` branch
    mispredicts on the ~10 % of points that win.) ``clipped``: some pix are -1; ``mark``:
    flag the tiles written (constants at the call sites). The loop body is written out:
    an inline helper taking the arrays would keep reference counting calls in the loop."""
    n = pix.shape[0]
    h = n >> 1
    for j in range(h):
        p = pix[j]
        if not clipped or p >= 0:
            u = np.uint32(p)  # unsigned: numba then skips its negative-index wraparound
            buf[u] = min(buf[u], (np.uint64(depth_bits[j]) << np.uint64(32)) | np.uint64(first + j * step))
            if mark:
                dirty[u >> _TILE_SHIFT_U] = 1
        q = pix[j + h]
        if not clipped or q >= 0:
            u = np.uint32(q)
            buf[u] = min(buf[u], (np.uint64(depth_bits[j + h]) << np.uint64(32)) | np.uint64(first + (j + h) * step))
            if mark:
                dirty[u >> _TILE_SHIFT_U] = 1
    for j in range(2 * h, n):  # the last point of an odd count
        p = pix[j]
        if not clipped or p >= 0:
            u = np.uint32(p)
            buf[u] = min(buf[u], (np.uint64(depth_bits[j]) << np.uint64(32)) | np.uint64(first + j * step))
            if mark:
                dirty[u >> _TILE_SHIFT_U] = 1


@njit(cache=True)
def footprint_spans(footprint):
    """The footprint table as row spans: for a point of size k (the rows with need <= k),
    ``spans[k, dy + r]`` = (dx_lo, dx_hi), dx_lo > dx_hi where row dy has none, and
    ``rows[k]`` = (dy_lo, dy_hi); r is the table's largest |dy|. A size's offsets are one run of
    columns per row (squares and discs alike), so a point writes runs instead of testing
    every offset (the adaptive size's default frame)."""
    k_max = 1
    r = 0
    for o in range(footprint.shape[0]):
        k_max = max(k_max, footprint[o, 2])
        r = max(r, abs(footprint[o, 1]))
    spans = np.empty((k_max + 1, 2 * r + 1, 2), np.int32)
    spans[:, :, 0] = 1 << 30
    spans[:, :, 1] = -(1 << 30)
    rows = np.empty((k_max + 1, 2), np.int32)
    rows[:, 0] = 1 << 30
    rows[:, 1] = -(1 << 30)
    for o in range(footprint.shape[0]):
        dx, dy = footprint[o, 0], footprint[o, 1]
        for k in range(max(footprint[o, 2], 1), k_max + 1):
            spans[k, dy + r, 0] = min(spans[k, dy + r, 0], dx)
            spans[k, dy + r, 1] = max(spans[k, dy + r, 1], dx)
            rows[k, 0] = min(rows[k, 0], dy)
            rows[k, 1] = max(rows[k, 1], dy)
    return spans, rows


@njit
def largest_size(m, size, atten, near):
    """An upper bound of the size of a batch's points: ``size``, or with ``atten`` > 0 atten over
    the nearest depth of the batch's grid cube (its matrix's depth row, float64; the float32
    depth of a point differs from it far less than the 0.1 % margin)."""
    if atten == 0:
        return np.float64(size)
    d = np.inf
    for c in range(8):
        d = min(d, _grid_corner(m, c)[3])
    d = max(d * (1.0 - 1e-3) - 1e-6 * abs(d), np.float64(near) * (1.0 - 1e-3))
    return min(np.float64(size), max(1.0, np.float64(atten) / d)) if d > 0 else np.float64(size)


@njit(inline="always")
def _min_run(buf, first, n, key):
    """buf[first..first + n - 1] = min(buf, key): 8 pixels a vector operation (simd.min_run8);
    the default frame's splat writes take 0.75x the time of a scalar loop's (Intel Xeon)."""
    if n <= 8:  # (apart from the loop below: a loop around every run costs what the vectors save)
        min_run8(buf, first, n, key)
        return
    o = np.int64(0)
    while o < n:
        min_run8(buf, first + o, min(n - o, np.int64(8)), key)
        o += 8


@njit
def _write_run(buf, dirty, lo, hi, key, mark):
    """buf[lo..hi] = min(buf, key), flagging the run's tiles in ``dirty`` if ``mark``. A run is
    at most 65 pixels (point_size <= 64), so its first and last tiles are all it touches."""
    n = np.int64(hi - lo + 1)
    _min_run(buf, np.int64(lo), n, key)
    if mark and n > 0:
        dirty[np.uint64(lo) >> _TILE_SHIFT_U64] = 1
        dirty[np.uint64(hi) >> _TILE_SHIFT_U64] = 1


@njit
def uniform_runs(spans, rows, width):
    """Per point size k of ``footprint_spans`` whose rows are all the same run of columns
    (squares): (offset of the first pixel from the point's, run length, rows); rows 0 for
    the other sizes. ``write_batch`` then moves one run down the rows, its start and length
    looked up once a point (23 % faster than reading each row's span on the default frame)."""
    r = spans.shape[1] // 2
    out = np.zeros((spans.shape[0], 3), np.int64)
    for k in range(spans.shape[0]):
        r0, r1 = np.int64(rows[k, 0]), np.int64(rows[k, 1])
        if r0 > r1:
            continue
        lo, hi = np.int64(spans[k, r0 + r, 0]), np.int64(spans[k, r0 + r, 1])
        same = True
        for dy in range(r0, r1 + 1):
            same &= spans[k, dy + r, 0] == lo and spans[k, dy + r, 1] == hi
        if same:
            out[k, 0] = r0 * width + lo
            out[k, 1] = hi - lo + 1
            out[k, 2] = r1 - r0 + 1
    return out


@njit(error_model="numpy")  # a clipped point at depth 0 (in the eye's plane) sized atten / 0 = inf, not a ZeroDivisionError
def _write_splats(first, step, pix, depth, depth_bits, buf, dirty, width, height, spans, rows, uniform, size, atten, mark, row_lo, row_hi):
    """``write_batch`` of points larger than a pixel (its arguments): only rows row_lo..row_hi - 1."""
    r = spans.shape[1] // 2
    k_max = spans.shape[0] - 1
    # the sizes first, in a loop of their own that vectorises: the writes then do not wait on a
    # division per point (13-15 % of the default frame's splat writes)
    ks = np.empty(pix.shape[0], np.int32)
    for j in range(pix.shape[0]):
        s = size if atten == 0 else min(size, max(np.float32(1.0), atten / depth[j]))
        ks[j] = min(np.int32(s), k_max)
    for j in range(pix.shape[0]):
        p = pix[j]
        if p < 0:
            continue
        key = (np.uint64(depth_bits[j]) << np.uint64(32)) | np.uint64(first + j * step)
        k = np.int64(ks[j])
        yu = np.uint32(p) // np.uint32(width)  # unsigned 32-bit: one cheap division, no sign fix-ups
        x = np.int64(np.uint32(p) - yu * np.uint32(width))
        y = np.int64(yu)
        if r <= x < width - r and row_lo + r <= y < row_hi - r:  # away from the border (and the band's): no clamping
            nr = uniform[k, 2]
            if nr > 0:  # every row the same run (squares): one run, moved down a row at a time
                c = p + uniform[k, 0]
                n = uniform[k, 1]
                for _ in range(nr):
                    _min_run(buf, c, n, key)
                    c += width
                if mark:  # the tiles of the first and last pixel of each row
                    c = p + uniform[k, 0]
                    for _ in range(nr):
                        dirty[np.uint64(c) >> _TILE_SHIFT_U64] = 1
                        dirty[np.uint64(c + n - 1) >> _TILE_SHIFT_U64] = 1
                        c += width
                continue
            for dy in range(np.int64(rows[k, 0]), np.int64(rows[k, 1]) + 1):
                c = p + dy * width
                _write_run(buf, dirty, c + np.int64(spans[k, dy + r, 0]), c + np.int64(spans[k, dy + r, 1]), key, mark)
            continue
        for dy in range(max(np.int64(rows[k, 0]), row_lo - y), min(np.int64(rows[k, 1]), row_hi - 1 - y) + 1):
            row = (y + dy) * width
            _write_run(buf, dirty, row + max(x + spans[k, dy + r, 0], 0), row + min(x + spans[k, dy + r, 1], width - 1), key, mark)


@njit(cache=True)
def write_batch(first, step, pix, depth, depth_bits, buf, dirty, width, height, one_pixel, spans, rows, uniform, size, atten, clipped, mark, row_lo, row_hi):
    """Phase 2: depth test and write; marks the TILE-pixel tiles written in ``dirty`` (if ``mark``).

    Entry j is point ``first + j * step`` (step > 1: a subsample, see ``rasterize``);
    ``clipped=False``: no entry is -1 (a batch ``inside_frustum``).

    Point sizes: a footprint (render/splats.py, rows (dx, dy, need) sorted by need): a point of
    size s covers the offsets with need <= s, every one with the point's own key (so nearer
    points win pixel by pixel). ``one_pixel``: every point of the batch is one pixel (the
    plain loop; see ``largest_size``). The size is ``size``, or
    with ``atten`` > 0 (attenuated splats) atten / depth clamped to 1..size. ``spans`` and
    ``rows`` (``footprint_spans``) are the same offsets as runs of columns: needs are
    integers, so size s covers those of size floor(s); ``uniform`` (``uniform_runs``): sizes
    whose rows are all one run. Tiles are flagged per run written (a superset of the pixels
    changed: the merge takes the minimum anyway), if ``mark``. Splats write only rows
    row_lo..row_hi - 1 (a thread's band, see ``rasterize``); one-pixel points come restricted
    to them (``in_band``).
    """
    if one_pixel:
        if clipped:
            if mark:
                _write_pixels(first, step, pix, depth_bits, buf, dirty, True, True)
            else:
                _write_pixels(first, step, pix, depth_bits, buf, dirty, True, False)
        elif mark:
            _write_pixels(first, step, pix, depth_bits, buf, dirty, False, True)
        else:
            _write_pixels(first, step, pix, depth_bits, buf, dirty, False, False)
        return
    _write_splats(first, step, pix, depth, depth_bits, buf, dirty, width, height, spans, rows, uniform, size, atten, mark, row_lo, row_hi)


@njit
def in_band(pix, lo, hi):
    """pix outside lo..hi - 1 (a band's pixels) to -1, the one-pixel loop's "no pixel"."""
    for j in range(pix.shape[0]):
        p = pix[j]
        pix[j] = p if lo <= p < hi else np.int32(-1)


@njit(parallel=True, cache=True)
def fill_empty(buf):
    for i in prange(buf.shape[0]):
        buf[i] = EMPTY


@njit(parallel=True, cache=True)
def rasterize(firsts, counts, bits, mats, low, med, high, ext, ext_firsts, codes, width, height, nears, fars, starts, entries, bands, frames, scratch, dirty, footprint, size, atten, step, token):
    """Draw the selected batches into ``frames`` (pre-filled with EMPTY), one per view.

    Point words: ``low`` always; per selected batch ``codes[k]`` is FULL_LAYOUT (its medium and
    high words are in ``med`` / ``high``) or a compact layout code (core/compact.py: they decode
    from the stream ``ext`` at u64 word ``ext_firsts[k]``, only when a view draws it at 20 or 30
    bits; ``med`` / ``high`` may then be empty).

    V views (1; 2 for stereo, section 3.7 of the 2022 paper) are drawn in the same pass:
    each batch is read once and projected and written into every view's buffer.
    bits (V, k) and mats (V, k, 4, 4) per view and batch, nears/fars (V,), frames (V, n_pix).
    entries[starts[t]:starts[t+1]] are the selection entries thread t draws. Without ``bands``
    (empty), threads draw disjoint entries: scratch[v, t-1] is thread t's buffer of view v
    (EMPTY on entry, restored to EMPTY by ``merge``), and dirty[v, t] flags its tiles written
    (zero on entry; thread 0's, the frame's, go unread). With ``bands`` (n_threads + 1 rows,
    one view): thread t writes only rows bands[t]..bands[t+1] - 1, straight into the frame
    (no scratch, no merge), and draws every entry whose points may reach them: an entry near
    a band's edge is drawn by both threads, each writing its own rows (``band_plan``).
    footprint / size / atten: point size and shape (see ``write_batch``); token: the matrices'
    shape (``shape_token``).
    step > 1 draws every step-th point of each batch (a point budget for plain clouds:
    Morton order makes that an even spatial subsample).
    """
    n_threads = starts.shape[0] - 1
    n_views = frames.shape[0]
    spans, rows = footprint_spans(footprint)
    uniform = uniform_runs(spans, rows, width)
    splats = footprint.shape[0] > 1
    max_count = 0
    any_packed = False
    for k in range(counts.shape[0]):
        max_count = max(max_count, counts[k])
        any_packed |= codes[k] != FULL_LAYOUT
    banded = bands.shape[0] == n_threads + 1
    for t in prange(n_threads):
        row_lo = np.int64(bands[t]) if banded else np.int64(0)
        row_hi = np.int64(bands[t + 1]) if banded else np.int64(height)
        pix = np.empty(max_count, np.int32)
        depth = np.empty(max_count, np.float32)
        depth_bits = depth.view(np.uint32)
        # a subsample (step > 1) is gathered into contiguous words first: one compiled phase 1
        # (contiguous slices) serves both, instead of a second one for strided slices (14 s)
        # (a compact batch's medium and high words are decoded into the same scratch)
        sub = max_count if step > 1 or any_packed else 0
        sub_low = np.empty(sub, np.uint32)
        sub_med = np.empty(sub, np.uint32)
        sub_high = np.empty(sub, np.uint32)
        sub_bits = np.empty(max_count if any_packed else 0, np.uint64)
        for e in range(starts[t], starts[t + 1]):
            k = entries[e]
            f = firsts[k]
            c = counts[k]
            n = (c + step - 1) // step
            packed = codes[k] != FULL_LAYOUT
            fine = 0
            for v in range(n_views):
                fine = max(fine, bits[v, k])
            if step > 1:
                gather_every(low, f, n, step, sub_low)
                if not packed and fine > 10:  # a 10-bit draw reads the low word alone, a 20-bit one not the high
                    gather_every(med, f, n, step, sub_med)
                if not packed and fine > 20:
                    gather_every(high, f, n, step, sub_high)
            if packed and fine > 10:
                expand_tails(ext, ext_firsts[k], codes[k], np.int64(0), n, step, sub_med, sub_high, sub_bits)  # np.int64: a literal 0 compiles it again
            for v in range(n_views):
                buf = frames[v] if t == 0 or banded else scratch[v, t - 1]
                near = np.float32(nears[v])
                far = np.float32(fars[v])
                clip = not inside_frustum(mats[v, k], width, height, near, far)
                # points that stay one pixel (all of a batch whose nearest corner is too far for two
                # pixels: most of a dense cloud's) take the one-pixel loop, the same pixels faster
                one = not splats or largest_size(mats[v, k], size, atten, near) < 2.0
                # thread 0 draws into the frame itself: its tiles need no merge, so no flags
                mark = t > 0 and not banded
                if mark and not clip and one:
                    mark = not mark_footprint(mats[v, k], width, height, dirty[v, t], n)
                if step == 1 and not packed:  # contiguous slices: the vectorised loop
                    project_batch(low[f : f + c], med[f : f + c], high[f : f + c], bits[v, k], mats[v, k], width, height, near, far, pix[:n], depth[:n], clip, token)
                elif step == 1:
                    project_batch(low[f : f + c], sub_med[:n], sub_high[:n], bits[v, k], mats[v, k], width, height, near, far, pix[:n], depth[:n], clip, token)
                else:
                    project_batch(sub_low[:n], sub_med[:n], sub_high[:n], bits[v, k], mats[v, k], width, height, near, far, pix[:n], depth[:n], clip, token)
                if banded and one:
                    in_band(pix[:n], row_lo * width, row_hi * width)
                write_batch(
                    f, step, pix[:n], depth[:n], depth_bits[:n], buf, dirty[v, t], width, height, one, spans, rows, uniform, size, atten,
                    clip or banded, mark, row_lo, row_hi,
                )  # fmt: skip


@njit(parallel=True, cache=True)
def merge(frame, scratch, dirty):
    """frame = min(frame, scratch[t]) over the tiles thread t + 1 wrote; those tiles back to EMPTY.

    Only written tiles are visited: an overview covers a fraction of the image, and the
    merge used to read (and reset) whole rows."""
    n = frame.shape[0]
    for tile in prange(dirty.shape[1]):
        for t in range(scratch.shape[0]):
            if dirty[t + 1, tile]:
                dirty[t + 1, tile] = 0
                sb = scratch[t]
                for p in range(tile << TILE_SHIFT, min((tile + 1) << TILE_SHIFT, n)):  # branch-free: vectorises
                    frame[p] = min(frame[p], sb[p])
                    sb[p] = EMPTY


@njit(parallel=True, cache=True)
def resolve_colors(frame, color, background, out, rgb565, palette, shift):
    """out[p] = color of the winning point, or the background (u32 RGBA); returns the number of
    covered pixels (what ``count_covered`` says, without reading the frame again).

    ``rgb565`` empty: ``color`` is u32 RGBA8 per point. Else 16-bit colors (a compact cloud's,
    core/compact.py): ``color`` is their u32 words (``rgb565_words``: two a word) and ``rgb565``
    the RGBA8 of each 16-bit value (``rgb565_table``). ``palette`` not empty: per-block palettes
    (core/palette.py), ``color`` their u8 indices as u32 words (four a word), a block 2^``shift``
    points, decoded as ``palette.palette_rgba`` does."""
    n = frame.shape[0]
    half = rgb565.shape[0] > 0
    indexed = palette.shape[0] > 0
    covered = 0
    if not (half or indexed):  # one gather a pixel: the loop vectorises and is bound by memory
        for p in prange(n):
            key = frame[p]
            if key == EMPTY:
                out[p] = background
            else:
                out[p] = color[key & np.uint64(0xFFFFFFFF)]
                covered += 1
        return covered
    for g in prange((n + 7) >> 3):  # two dependent gathers a pixel: an empty group of 8 skips them (simd.py)
        p = g << 3
        if indexed:
            covered += resolve8_palette(frame, p, n - p, out, background, color, palette, shift)
        else:
            covered += resolve8_rgb565(frame, p, n - p, out, background, color, rgb565, 0)
    return covered


@njit(parallel=True, cache=True)
def count_covered(frame):
    """Number of pixels some point was drawn to."""
    covered = 0
    for p in prange(frame.shape[0]):
        if frame[p] != EMPTY:
            covered += 1
    return covered
