"""Numba kernels of the image-quality passes (passes.py drives them; their parameters and
numpy references: gigapoint.render.params and gigapoint.render.passes).

Screen-space passes run in parallel over rows (eye-dome lighting) or bands of rows (hole
filling); their inner loops go over one row for one neighbour offset at a time, branch-free,
so LLVM vectorises them. High-quality shading re-projects the selected batches with raster.py's own ``project_batch``
(decode + project, the contract's operation order) so a point lands on exactly the
pixel the depth pass gave it.
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import njit, prange
from numba.core import cgutils, types
from numba.cpython.unsafe.numbers import trailing_zeros as _ctz
from numba.extending import intrinsic

from ...render.params import (
    EDL_EMPTY_RESPONSE,
    EXP2_C,
    LOG2_C1,
    LOG2_C3,
    LOG2_C5,
    LOG2_C7,
    TR_COUNT_BITS,
    TR_REVEAL_BITS,
    soft_weight,
)
from .raster import footprint_spans, gather_every, inside_frustum, project_batch

EMPTY = np.uint64(0xFFFFFFFFFFFFFFFF)
_LOW32 = np.uint64(0xFFFFFFFF)
_F0 = np.float32(0.0)
_F1 = np.float32(1.0)
_TWO_M23 = np.float32(2.0**-23)


@njit(parallel=True, cache=True)
def log_depth(vis, logd, empty):
    """logd = log2(depth) (0 where empty), empty = 1 where no point.

    log2 = exponent + atanh series of the mantissa m in [1, 2): t = (m-1)/(m+1). The depth
    bits are taken from the u64 keys (contiguous loads: the loop vectorises)."""
    n = vis.shape[0]
    rows = (n + 4095) // 4096
    for r in prange(rows):
        p0 = r * 4096
        p1 = min(n, p0 + 4096)
        keys = vis[p0:p1]
        lrow = logd[p0:p1]
        erow = empty[p0:p1]
        for i in range(p1 - p0):
            k = keys[i]
            b = np.uint32(k >> np.uint64(32))
            ex = np.float32(np.int32(b >> np.uint32(23)) - np.int32(127))
            # the mantissa as a float in [1, 2), exactly (23 fraction bits): no bit cast needed
            m = _F1 + np.float32(np.int32(b & np.uint32(0x007FFFFF))) * _TWO_M23
            t = (m - _F1) / (m + _F1)
            t2 = t * t
            lg = ex + t * (LOG2_C1 + t2 * (LOG2_C3 + t2 * (LOG2_C5 + t2 * LOG2_C7)))
            e = k == EMPTY
            lrow[i] = _F0 if e else lg
            erow[i] = _F1 if e else _F0


@njit(parallel=True, cache=True)
def edl(logd, empty, colors, width, height, offsets, scale, out):
    """Potree's eye-dome lighting: shade = exp(-300 * strength * mean response), where each of
    the neighbours at ``offsets`` adds max(0, logd - logd_n) (100 if this pixel is empty).
    exp is 2^y with y = response * scale (params.edl_scale), split into 2^floor(y) (bits)
    and a degree-6 Taylor polynomial of 2^frac."""
    n_off = offsets.shape[0]
    c1, c2, c3, c4, c5, c6 = EXP2_C
    for y in prange(height):
        acc = np.zeros(width, np.float32)
        base = y * width
        crow = logd[base : base + width]
        erow = empty[base : base + width]
        for o in range(n_off):
            dx = offsets[o, 0]
            dy = offsets[o, 1]
            yy = y + dy
            if yy < 0 or yy >= height:
                continue
            x0 = max(0, -dx)
            x1 = min(width, width - dx)
            c_ = crow[x0:x1]
            e_ = erow[x0:x1]
            n_ = logd[yy * width + x0 + dx : yy * width + x1 + dx]
            ne_ = empty[yy * width + x0 + dx : yy * width + x1 + dx]
            a_ = acc[x0:x1]
            for i in range(x1 - x0):
                ec = e_[i]
                r = ec * EDL_EMPTY_RESPONSE + (_F1 - ec) * max(_F0, c_[i] - n_[i])
                a_[i] += (_F1 - ne_[i]) * r
        pw = np.empty(width, np.float32)
        pwb = pw.view(np.int32)
        poly = np.empty(width, np.float32)
        for x in range(width):
            yv = max(acc[x] * scale, np.float32(-126.0))
            fl = np.float32(math.floor(yv))
            f = yv - fl
            poly[x] = _F1 + f * (c1 + f * (c2 + f * (c3 + f * (c4 + f * (c5 + f * c6)))))
            pwb[x] = (np.int32(fl) + np.int32(127)) << np.int32(23)
        orow = out[base : base + width]
        colrow = colors[base : base + width]
        for x in range(width):
            shade = poly[x] * pw[x]
            c = colrow[x]
            r = np.uint32(np.float32(c & np.uint32(255)) * shade + np.float32(0.5))
            g = np.uint32(np.float32((c >> np.uint32(8)) & np.uint32(255)) * shade + np.float32(0.5))
            b = np.uint32(np.float32((c >> np.uint32(16)) & np.uint32(255)) * shade + np.float32(0.5))
            orow[x] = (c & np.uint32(0xFF000000)) | r | (g << np.uint32(8)) | (b << np.uint32(16))


# --- hole filling ------------------------------------------------------------------------------
@njit(inline="always")
def _pack_row(vrow, nw, dst):
    """dst[1 + w] bit i = pixel 64 w + i of the row is not empty; dst[0], dst[nw + 1] = 0 (padding)."""
    width = vrow.shape[0]
    dst[0] = np.uint64(0)
    dst[nw + 1] = np.uint64(0)
    for w in range(nw):
        word = np.uint64(0)
        row = vrow[64 * w : min(width, 64 * w + 64)]
        for i in range(row.shape[0]):
            word |= np.uint64(row[i] != EMPTY) << np.uint64(i)
        dst[w + 1] = word


@njit(inline="always")
def _or_shifted(plane, src, dx, mask):
    """plane |= mask & the padded bit row ``src`` (``_pack_row``) moved so that bit x holds
    bit x + dx (|dx| < 64; zeros beyond the row), word by word."""
    nw = plane.shape[0]
    a = src[1 : nw + 1]
    if dx == 0:
        for w in range(nw):
            plane[w] |= a[w] & mask[w]
    elif dx > 0:
        b = src[2 : nw + 2]
        sr, sl = np.uint64(dx), np.uint64(64 - dx)
        for w in range(nw):
            plane[w] |= ((a[w] >> sr) | (b[w] << sl)) & mask[w]
    else:
        b = src[0:nw]
        sl, sr = np.uint64(-dx), np.uint64(64 + dx)
        for w in range(nw):
            plane[w] |= ((a[w] << sl) | (b[w] >> sr)) & mask[w]


@njit(inline="always")
def _surrounded_words(occ, tmp, surr):
    """surr[w] bit x: the 16 sector planes occ[:, w] leave no run of 8 (cyclically) sectors
    clear at x, i.e. every run of 8 has a set bit: OR over runs of 2, 4, 8, then AND."""
    nw = surr.shape[0]
    for s in range(16):
        p, q, d = occ[s], occ[(s + 1) & 15], tmp[0, s]
        for w in range(nw):
            d[w] = p[w] | q[w]
    for s in range(16):
        p, q, d = tmp[0, s], tmp[0, (s + 2) & 15], tmp[1, s]
        for w in range(nw):
            d[w] = p[w] | q[w]
    surr[:] = ~np.uint64(0)
    for s in range(16):
        p, q = tmp[1, s], tmp[1, (s + 4) & 15]
        for w in range(nw):
            surr[w] &= p[w] | q[w]


@njit(inline="always")
def _surrounded(occ):
    m32 = np.uint64(occ) | (np.uint64(occ) << np.uint64(16))
    z = (~m32) & _LOW32
    z = z & (z >> np.uint64(1))
    z = z & (z >> np.uint64(2))
    z = z & (z >> np.uint64(4))  # a run of 8 free sectors survives
    return z == 0


@njit(inline="always")
def _window_min(vis, width, height, y, runs, r_hi, x_lo, x_hi, empty_row, cm, t, best):
    """best[x] = min of vis over pixel (x, y)'s window (EMPTY where its radius is 0), the centre
    included, for x_lo <= x < x_hi; runs (k, 3): the row's runs of pixels [xa, xb) of one radius
    r, r_hi their largest r. cm (>= r_hi, width + 2 pad) gets the column minima of radius
    1..r_hi, t (2, width + 2 pad) is scratch; both keep EMPTY in their pad columns."""
    pad = (cm.shape[1] - width) // 2
    c_lo, c_hi = max(x_lo - r_hi, 0), min(x_hi + r_hi, width)  # the columns the windows reach
    for m in range(1, r_hi + 1):  # column minima, nested: radius m = radius m - 1 and rows y -+ m
        c = cm[m - 1, pad + c_lo : pad + c_hi]
        row = y * width
        prev = vis[row + c_lo : row + c_hi] if m == 1 else cm[m - 2, pad + c_lo : pad + c_hi]
        row = (y - m) * width
        up = vis[row + c_lo : row + c_hi] if y - m >= 0 else empty_row[c_lo:c_hi]
        row = (y + m) * width
        down = vis[row + c_lo : row + c_hi] if y + m < height else empty_row[c_lo:c_hi]
        for x in range(c_hi - c_lo):
            c[x] = min(prev[x], min(up[x], down[x]))
    for j in range(runs.shape[0]):  # runs of equal radius (the whole row unless foveated)
        xa, xb, r = max(runs[j, 0], x_lo), min(runs[j, 1], x_hi), runs[j, 2]
        if xa >= xb:
            continue
        if r == 0:
            best[xa:xb] = EMPTY
        else:
            # row minima by doubling: t[i] = min of c[i .. i + k - 1], k the largest power of 2
            # <= 2r + 1; the window [x - r, x + r] is [x - r, x - r + k) and (x + r - k, x + r]
            c = cm[r - 1]
            k = 1
            while 2 * k <= 2 * r + 1:
                k *= 2
            lo = pad + xa - r
            hi = pad + xb + r - k + 1  # t needed on [lo, hi)
            src = c
            par = 0
            k_now = 1
            while k_now < k:  # ping-pong between t[0] and t[1] (LLVM does not vectorise in place)
                end = hi + k - 2 * k_now
                d = t[par, lo:end]  # (slices: loops from 0 let LLVM drop numba's negative-index wrap)
                s0 = src[lo:end]
                s1 = src[lo + k_now : end + k_now]
                for i in range(end - lo):
                    d[i] = min(s0[i], s1[i])
                src = t[par]
                par ^= 1
                k_now *= 2
            a = src[pad + xa - r : pad + xb - r]
            b = src[pad + xa + r - k + 1 : pad + xb + r - k + 1]
            seg = best[xa:xb]
            for x in range(xb - xa):
                seg[x] = min(a[x], b[x])


@njit(inline="always")
def _select_bits(dst, a, b, bits):
    """dst[i] = a[i] where bit i of ``bits`` is set, else b[i] (i < 64)."""
    for i in range(dst.shape[0]):
        dst[i] = a[i] if (bits >> np.uint64(i)) & np.uint64(1) else b[i]


@njit(inline="always")
def _flag_word(vrow, vf, best, bf, inv_gap, x0, x1):
    """Bit i: pixel x0 + i holds a point and its window minimum is nearer by more than the gap."""
    word = np.uint64(0)
    v = vrow[x0:x1]
    b = best[x0:x1]
    vd = vf[2 * x0 : 2 * x1]
    bd = bf[2 * x0 : 2 * x1]
    for i in range(x1 - x0):
        k = v[i]
        hit = (k != EMPTY) & (b[i] < k) & (bd[2 * i + 1] < vd[2 * i + 1] * inv_gap)
        word |= np.uint64(hit) << np.uint64(i)
    return word


@njit(cache=True, nogil=True)
def fill_holes(vis, vis_f32, width, height, radius_map, runs, run_start, ring_masks, offsets, sector_bits, sectors, ring, inv_gap, n_bands, out, band_lo, band_hi):
    """Depth-aware dilation into out. A pixel that is empty, or whose depth is more than
    ``1/inv_gap`` times that of the closest pixel of its window, takes that closest key, but
    only when the closer neighbours surround it (no run of 8 of the 16 direction sectors is
    free of them), so holes close and silhouettes do not grow.

    radius_map (H, W) int8 window radius per pixel, runs (k, 3) int64 its runs (xa, xb, r) of
    one radius in a row, row y's are runs[run_start[y] : run_start[y + 1]]; ring_masks
    (H, R+1, nw) u64: bit set where the pixel's radius >= ring; offsets (k, 2) dx, dy ordered
    by ring; sector_bits (k,) u32, sectors (k,) their index; ring (k,) int8.
    The rows are split into ``n_bands`` bands; each goes down its rows once, so the window's
    rows stay in cache. This call fills bands ``band_lo`` .. ``band_hi`` - 1: threads share the
    bands out (``passes._in_bands``; the GIL is released). As a parallel kernel (a prange over
    the bands) it compiled 3.5x longer: numba's parfor passes and gufunc lowering went over the
    whole band loop again (18.5 s CPU on an AMD EPYC, 5.2 s now; HQS's kernel, tried the same
    way, compiled 3x faster but drew 1.2-2x slower, so it stays a prange). Per row: (2) the
    sectors holding a point, 64 pixels a word as bit planes, the free-half test bit-sliced;
    (1) where that finds pixels surrounded, the window minimum,
    from column minima and row minima by doubling (vectorised); empty pixels so surrounded take
    it (a vectorised select writes the row); (3) pixels with a point, only where the window minimum is nearer
    (a flag word of 64 pixels, vectorised) and their points surround them: a scalar sector
    scan of the nearer points, ring by ring, stopping once surrounded."""
    n_off = offsets.shape[0]
    nw = (width + 63) // 64
    n_rings = np.int64(ring[n_off - 1])
    ring_start = np.zeros(n_rings + 2, np.int64)
    for o in range(n_off):
        ring_start[ring[o] + 1] = o + 1
    empty_row = np.full(width, EMPTY, np.uint64)
    step2 = 2 * (offsets[:, 1].astype(np.int64) * width + offsets[:, 0])  # offsets in vis_f32
    for b in range(band_lo, band_hi):
        y0 = b * height // n_bands
        y1 = (b + 1) * height // n_bands
        # bit rows of the band and n_rings rows above and below it (zeros outside the image),
        # each packed just before its first use (while it is in cache anyway)
        present = np.zeros((y1 - y0 + 2 * n_rings, nw + 2), np.uint64)
        for yy in range(max(y0 - n_rings, 0), min(y0 + n_rings, height)):
            _pack_row(vis[yy * width : yy * width + width], nw, present[yy - y0 + n_rings])
        cm = np.full((n_rings, width + 2 * n_rings), EMPTY, np.uint64)
        t = np.full((2, width + 2 * n_rings), EMPTY, np.uint64)
        best = np.empty(width, np.uint64)
        best_f = best.view(np.float32)
        occ = np.empty((16, nw), np.uint64)
        tmp = np.empty((2, 16, nw), np.uint64)
        surr = np.empty(nw, np.uint64)
        for y in range(y0, y1):
            base = y * width
            rrow = radius_map[y]
            row_runs = runs[run_start[y] : run_start[y + 1]]
            r_hi = np.int64(0)
            for j in range(row_runs.shape[0]):
                r_hi = max(r_hi, row_runs[j, 2])
            vrow = vis[base : base + width]
            vrow_f = vis_f32[2 * base : 2 * base + 2 * width]
            yy = y + n_rings
            if yy < height:
                _pack_row(vis[yy * width : yy * width + width], nw, present[yy - y0 + n_rings])
            # step 2: sector planes of the points around each pixel
            occ[:] = 0
            for o in range(ring_start[r_hi + 1]):
                dy = offsets[o, 1]
                if not 0 <= y + dy < height:
                    continue
                _or_shifted(occ[sectors[o]], present[y - y0 + n_rings + dy], offsets[o, 0], ring_masks[y, ring[o]])
            _surrounded_words(occ, tmp, surr)
            # step 1: the window minimum, needed only where the points around surround a pixel
            w_lo, w_hi = nw, 0
            for w in range(nw):
                if surr[w]:
                    w_lo, w_hi = min(w_lo, w), w + 1
            if w_lo < w_hi:
                _window_min(vis, width, height, y, row_runs, r_hi, 64 * w_lo, min(width, 64 * w_hi), empty_row, cm, t, best)
            me = present[y - y0 + n_rings]
            for w in range(nw):
                # empty pixels surrounded by points (so their window minimum is a point) take it
                take = surr[w] & ~me[w + 1]
                x0 = 64 * w
                x1 = min(width, x0 + 64)
                _select_bits(out[base + x0 : base + x1], best[x0:x1], vrow[x0:x1], take)  # vectorised
                # step 3 (a few % of the pixels): a point far behind nearer neighbours; only
                # where its neighbours with a point surround it can the nearer ones
                cand = surr[w] & me[w + 1]
                if cand:
                    cand &= _flag_word(vrow, vrow_f, best, best_f, inv_gap, x0, x1)
                while cand:
                    x = x0 + np.int64(_ctz(cand))
                    cand &= cand - np.uint64(1)
                    # the sectors of the nearer points, ring by ring until surrounded (an empty
                    # key's depth bits are a NaN: never nearer)
                    p2 = 2 * (base + x) + 1
                    thr_f = vis_f32[p2] * inv_gap
                    occ1 = np.uint32(0)
                    done = False
                    interior = (x >= n_rings) & (x < width - n_rings) & (y >= n_rings) & (y < height - n_rings)
                    for m in range(1, np.int64(rrow[x]) + 1):
                        for o in range(ring_start[m], ring_start[m + 1]):
                            q2 = p2 + step2[o]
                            ok = True
                            if not interior:
                                xx = x + offsets[o, 0]
                                yy = y + offsets[o, 1]
                                ok = (xx >= 0) & (xx < width) & (yy >= 0) & (yy < height)
                                q2 = q2 if ok else p2
                            occ1 |= sector_bits[o] * np.uint32(ok & (vis_f32[q2] < thr_f))
                        if _surrounded(occ1):
                            done = True
                            break
                    if not done:
                        continue
                    out[base + x] = best[x]


# --- high-quality shading ----------------------------------------------------------------------
# One u64 a pixel holds the running sums (Schütz et al.'s HQS, exact integer means): 13-bit
# lanes for r, g, b, a (bits 0-51), an 11-bit weight count (bits 52-62) and a flag (bit 63)
# saying that wider sums in the spill arrays belong to the pixel too. Before a lane could pass
# 2^13 (more than 32 weights) the packed sums move to the spill arrays (r | g << 32, b | a << 32,
# count: exact for up to 2^24 weights a pixel). 8 bytes a pixel instead of 20 is what makes the
# scattered accumulation fast: it is memory-bound.
_LANE = np.uint64(8191)
_N_SHIFT = np.uint64(52)
_N_MASK = np.uint64(2047)
_SPILLED = np.uint64(1) << np.uint64(63)
_LANE_WEIGHTS = np.uint64(32)  # 32 x 255 < 2^13
_ONE_COUNT = np.uint64(1) << _N_SHIFT
_PREFETCH_AHEAD = 64  # points: the scattered sums wait on memory, so their lines are asked for early


@intrinsic
def prefetch(typingctx, arr, idx):
    """Hint that arr[idx] will be written soon (LLVM's prefetch; no effect on results, never faults)."""
    sig = types.void(arr, idx)

    def codegen(context, builder, signature, args):
        aryty = signature.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary, [args[1]], wraparound=False, boundscheck=False)
        i8p = ir.IntType(8).as_pointer()
        name = "llvm.prefetch.p0" if getattr(i8p, "is_opaque", False) else "llvm.prefetch.p0i8"
        i32 = ir.IntType(32)
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]), name)
        builder.call(fn, [builder.bitcast(ptr, i8p), ir.Constant(i32, 1), ir.Constant(i32, 3), ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return sig, codegen


@njit(inline="always")
def _packed_color(col):
    """RGBA u32 -> the four 13-bit lanes plus a count of one."""
    c = np.uint64(col)
    return (
        (c & np.uint64(0xFF))
        | ((c & np.uint64(0xFF00)) << np.uint64(5))
        | ((c & np.uint64(0xFF0000)) << np.uint64(10))
        | ((c & np.uint64(0xFF000000)) << np.uint64(15))
        | _ONE_COUNT
    )


@njit(inline="always")
def _hqs_add(p, depth, col, w, vis_f32, t1, acc, spill_rg, spill_ba, spill_n):
    """Add w x color and w to pixel p if ``depth`` is within the tolerance of its closest depth
    (an empty pixel's depth bits are a NaN: the test fails). Branch-free: a point that fails
    adds zero (every point's pixel is covered, so its line is written anyway)."""
    p = np.uint64(p)  # unsigned (p >= 0 here): numba then skips its negative-index wraparound
    w = w * np.uint64(depth <= vis_f32[np.uint64(2) * p + np.uint64(1)] * t1)
    v = acc[p]
    if ((v >> _N_SHIFT) & _N_MASK) + w > _LANE_WEIGHTS:
        spill_rg[p] += (v & _LANE) | (((v >> np.uint64(13)) & _LANE) << np.uint64(32))
        spill_ba[p] += ((v >> np.uint64(26)) & _LANE) | (((v >> np.uint64(39)) & _LANE) << np.uint64(32))
        spill_n[p] += np.uint32((v >> _N_SHIFT) & _N_MASK)
        v = _SPILLED
    acc[p] = v + w * _packed_color(col)


@njit(inline="always")
def _mean(s, n, nf):
    """round-half-up(s / n) for s <= 255 n < 2^32: a float64 quotient is exact enough (a
    non-integer quotient is >= 1/n from the next integer, far above the rounding error)."""
    return np.uint32(np.float64(s + (n >> np.uint64(1))) / nf)


@njit(inline="always")
def _lane_mean(s, h, rcp):
    """round-half-up(s / n) of a 13-bit lane (n <= 32), h = n // 2, rcp = float32(1 / n):
    (s + h + 0.5) / n lies >= 0.5 / n >= 1/64 away from the integers, and float32 is off by
    less than 2^-15 here, so truncating is exact."""
    return np.uint32((np.float32(np.uint32(s) + h) + np.float32(0.5)) * rcp)


@njit(inline="always")
def _rgba(r, g, b, a):
    return r | (g << np.uint32(8)) | (b << np.uint32(16)) | (a << np.uint32(24))


@njit(inline="always")
def _hqs_resolve_rows(r0, r1, width, acc, spill_rg, spill_ba, spill_n, fallback, out):
    """out = the rounded mean color of rows r0..r1 (fallback where nothing was added); the sums
    are set back to zero. Rows without a spilled pixel take a branch-free (vectorised) loop."""
    for y in range(r0, r1):
        base = y * width
        a_ = acc[base : base + width]
        o_ = out[base : base + width]
        f_ = fallback[base : base + width]
        used = np.uint64(0)
        for x in range(width):
            used |= a_[x]
        if used == 0:  # nothing added in this row
            for x in range(width):
                o_[x] = f_[x]
            continue
        if used & _SPILLED:
            for x in range(width):
                v = a_[x]
                p = base + x
                rg = (v & _LANE) | (((v >> np.uint64(13)) & _LANE) << np.uint64(32))
                ba = ((v >> np.uint64(26)) & _LANE) | (((v >> np.uint64(39)) & _LANE) << np.uint64(32))
                n = (v >> _N_SHIFT) & _N_MASK
                if v & _SPILLED:
                    rg += spill_rg[p]
                    ba += spill_ba[p]
                    n += np.uint64(spill_n[p])
                    spill_rg[p] = 0
                    spill_ba[p] = 0
                    spill_n[p] = 0
                a_[x] = 0
                if n == 0:
                    o_[x] = f_[x]
                else:
                    nf = np.float64(n)
                    o_[x] = _rgba(
                        _mean(rg & _LOW32, n, nf),
                        _mean(rg >> np.uint64(32), n, nf),
                        _mean(ba & _LOW32, n, nf),
                        _mean(ba >> np.uint64(32), n, nf),
                    )
            continue
        for x in range(width):
            v = a_[x]
            n = np.uint32((v >> _N_SHIFT) & _N_MASK)
            h = n >> np.uint32(1)
            rcp = np.float32(1.0) / np.float32(max(n, np.uint32(1)))
            c = _rgba(
                _lane_mean(v & _LANE, h, rcp),
                _lane_mean((v >> np.uint64(13)) & _LANE, h, rcp),
                _lane_mean((v >> np.uint64(26)) & _LANE, h, rcp),
                _lane_mean((v >> np.uint64(39)) & _LANE, h, rcp),
            )
            o_[x] = c if n != 0 else f_[x]
            if v != 0:  # lines of empty pixels stay clean
                a_[x] = 0



@njit(inline="always")
def _band_reach(footprint, counts):
    """(rows a footprint reaches above or below its point, the largest batch count): what a
    band pass needs to find the batches that reach its rows and size its scratch."""
    reach = 0
    for o in range(footprint.shape[0]):
        reach = max(reach, abs(footprint[o, 1]))
    max_count = 0
    for k in range(counts.shape[0]):
        max_count = max(max_count, counts[k])
    return reach, max_count

@njit(inline="always")
def _project_every(low, med, high, first, c, step, bits, m, width, height, near, far, pix, depth, clip, token, sub_low, sub_med, sub_high):
    """Pixel ids and depths of every step-th point of the batch at words first..first+c into
    pix[:n], depth[:n]; returns n. step > 1 gathers those points' words into the scratch sub_*
    first, as ``raster.rasterize`` does: the points a point cap skips are neither read nor
    projected (the same projection per point: the same pixels and depths as the depth pass)."""
    if step == 1:
        project_batch(low[first : first + c], med[first : first + c], high[first : first + c], bits, m,
                      width, height, near, far, pix[:c], depth[:c], clip, token)  # fmt: skip
        return c
    n = (c + step - 1) // step
    gather_every(low, first, n, step, sub_low)
    if bits > 10:  # a 10-bit projection reads the low word alone
        gather_every(med, first, n, step, sub_med)
    if bits > 20:
        gather_every(high, first, n, step, sub_high)
    project_batch(sub_low[:n], sub_med[:n], sub_high[:n], bits, m, width, height, near, far, pix[:n], depth[:n], clip, token)
    return n


@njit(inline="always")
def _every_scratch(max_count, step):
    """A thread's (pix, depth, sub_low, sub_med, sub_high) for ``_project_every`` of batches of
    up to ``max_count`` points (the sub_* words only where step > 1 gathers into them)."""
    sub = max_count if step > 1 else 0
    pix = np.empty(max_count, np.int32)
    depth = np.empty(max_count, np.float32)
    return pix, depth, np.empty(sub, np.uint32), np.empty(sub, np.uint32), np.empty(sub, np.uint32)


@njit(parallel=True, cache=True)
def hqs_shade(
    firsts,
    counts,
    bits,
    mats,
    row_lo,
    row_hi,
    low,
    med,
    high,
    width,
    height,
    near,
    far,
    step,
    bands,
    vis_f32,
    tol1,
    color,
    footprint,
    size,
    atten,
    softness,
    acc,
    spill_rg,
    spill_ba,
    spill_n,
    fallback,
    out,
    token,
):
    """High-quality shading, accumulation and resolve in one parallel pass over screen bands.

    Band t (rows bands[t]..bands[t+1]) belongs to one thread, which re-projects (raster.py's
    ``project_batch``) the batches whose rows row_lo[k]..row_hi[k] reach its band, adds every
    step-th point (as the depth pass drew them) whose depth is <= tol1 x the closest depth at its pixel (``vis_f32`` = the depth pass's
    visibility buffer viewed as float32) at every pixel of its footprint inside the band (same
    footprint rule as raster.write_batch; with ``softness`` > 0 weights 0..15 from
    ``soft_weight``), then writes its rows' rounded means to ``out`` (``fallback`` where nothing
    was added). Each pixel is summed by one thread in index order, so the image does not depend
    on the thread count. acc and the spill arrays must be zero on entry; they are on exit.
    ``token``: the matrices' shape (``raster.shape_token``)."""
    n_bands = bands.shape[0] - 1
    n_fp = footprint.shape[0]
    reach, max_count = _band_reach(footprint, counts)
    near32 = np.float32(near)
    far32 = np.float32(far)
    t1 = np.float32(tol1)
    for t in prange(n_bands):
        r0 = bands[t]
        r1 = bands[t + 1]
        p0 = np.int32(r0 * width)
        p1 = np.int32(r1 * width)
        pix, depth, sub_low, sub_med, sub_high = _every_scratch(max_count, step)
        for k in range(counts.shape[0]):
            if r0 == r1 or row_hi[k] + reach < r0 or row_lo[k] - reach >= r1:
                continue
            first = firsts[k]
            clip = not inside_frustum(mats[k], width, height, near32, far32)
            n = _project_every(low, med, high, first, counts[k], step, bits[k], mats[k], width, height, near32, far32,
                               pix, depth, clip, token, sub_low, sub_med, sub_high)  # fmt: skip
            # entry j is point first + j * step
            if n_fp == 1:
                for j in range(n):
                    if j + _PREFETCH_AHEAD < n:
                        q = pix[j + _PREFETCH_AHEAD]
                        if p0 <= q < p1:
                            prefetch(acc, q)
                            prefetch(vis_f32, 2 * q + 1)
                    p = pix[j]
                    if p0 <= p < p1:
                        _hqs_add(p, depth[j], color[first + j * step], np.uint64(1), vis_f32, t1, acc, spill_rg, spill_ba, spill_n)
                continue
            for j in range(n):
                if j + _PREFETCH_AHEAD < n and pix[j + _PREFETCH_AHEAD] >= 0:
                    q = pix[j + _PREFETCH_AHEAD]
                    prefetch(acc, q)
                    prefetch(vis_f32, 2 * q + 1)
                p = pix[j]
                if p < 0:
                    continue
                x = p % width
                y = p // width
                if y + reach < r0 or y - reach >= r1:
                    continue
                s = size if atten == 0 else min(size, max(np.float32(1.0), atten / depth[j]))
                for o in range(n_fp):
                    if footprint[o, 2] > s:
                        break
                    xx = x + footprint[o, 0]
                    yy = y + footprint[o, 1]
                    if 0 <= xx < width and r0 <= yy < r1:
                        w = soft_weight(footprint[o, 0], footprint[o, 1], s, softness)
                        if w > 0:
                            _hqs_add(
                                np.int64(yy) * width + xx, depth[j], color[first + j * step], w, vis_f32, t1, acc, spill_rg, spill_ba, spill_n
                            )
        _hqs_resolve_rows(r0, r1, width, acc, spill_rg, spill_ba, spill_n, fallback, out)


# --- transparency (render/passes/transparency.py: the rule and its numpy reference) ------------
_TR_COUNT_SHIFT = np.uint64(TR_COUNT_BITS)
_FULL = np.int64(65536)  # transmittance 1, 16-bit fixed point


@njit(inline="always")
def _tr_add(p, key, col, a8, reveal, kbuf, kalpha, sums):
    """One fragment into pixel p: its key into the k-buffer kbuf[p] (ascending, EMPTY-padded: the
    largest drops out) and its alpha into kalpha[p] beside it; a8, a8 x color and the revealage
    term into sums[p]."""
    p = np.uint64(p)  # unsigned (p >= 0 here): no negative-index wraparound
    layers = kbuf.shape[1]
    if key < kbuf[p, layers - 1]:
        i = layers - 1
        while i > 0 and kbuf[p, i - 1] > key:
            kbuf[p, i] = kbuf[p, i - 1]
            kalpha[p, i] = kalpha[p, i - 1]
            i -= 1
        kbuf[p, i] = key
        kalpha[p, i] = np.uint8(a8)
    c = np.uint64(col)
    sums[p, 0] += a8
    sums[p, 1] += a8 * (c & np.uint64(255))
    sums[p, 2] += a8 * ((c >> np.uint64(8)) & np.uint64(255))
    sums[p, 3] += a8 * ((c >> np.uint64(16)) & np.uint64(255))
    sums[p, 4] += reveal


@njit(inline="always")
def _tr_resolve_rows(r0, r1, width, kbuf, kalpha, sums, color, table, background, fallback, out):
    """out = the composite of rows r0..r1 (fallback where no fragment landed); k-buffer and sums
    back to EMPTY and zero."""
    layers = kbuf.shape[1]
    for p in range(r0 * width, r1 * width):
        reveal = sums[p, 4]
        if reveal == 0:
            out[p] = fallback[p]
            continue
        t = _FULL
        acc0 = np.int64(0)
        acc1 = np.int64(0)
        acc2 = np.int64(0)
        kept_a = np.uint64(0)
        kept0 = np.uint64(0)
        kept1 = np.uint64(0)
        kept2 = np.uint64(0)
        for i in range(layers):  # the nearest fragments, front to back
            key = kbuf[p, i]
            if key == EMPTY:
                break
            kbuf[p, i] = EMPTY
            index = np.int64(key & _LOW32)
            a = np.int64(kalpha[p, i])
            c = color[index]
            c0 = np.int64(c & np.uint32(255))
            c1 = np.int64((c >> np.uint32(8)) & np.uint32(255))
            c2 = np.int64((c >> np.uint32(16)) & np.uint32(255))
            w = (a * t + 127) // 255
            acc0 += w * c0
            acc1 += w * c1
            acc2 += w * c2
            t -= w
            kept_a += np.uint64(a)
            kept0 += np.uint64(a * c0)
            kept1 += np.uint64(a * c1)
            kept2 += np.uint64(a * c2)
        tail_a = sums[p, 0] - kept_a
        if tail_a > 0:  # fragments left out: their mean color gets the light the kept ones leave
            lg = reveal >> _TR_COUNT_SHIFT
            e = lg >> np.uint64(TR_REVEAL_BITS)
            t_all = np.int64(0) if e >= np.uint64(16) else np.int64(table[(lg >> np.uint64(TR_REVEAL_BITS - 8)) & np.uint64(255)] >> np.uint32(e))
            t_all = min(t_all, t)
            s = np.uint64(0)
            while (tail_a >> s) >= np.uint64(65536):
                s += np.uint64(1)
            w16 = tail_a >> s
            h = w16 >> np.uint64(1)
            tw = t - t_all
            acc0 += tw * np.int64((((sums[p, 1] - kept0) >> s) + h) // w16)
            acc1 += tw * np.int64((((sums[p, 2] - kept1) >> s) + h) // w16)
            acc2 += tw * np.int64((((sums[p, 3] - kept2) >> s) + h) // w16)
            t = t_all
        r = np.uint32((acc0 + np.int64(background[0]) * t + 32768) >> 16)
        g = np.uint32((acc1 + np.int64(background[1]) * t + 32768) >> 16)
        b = np.uint32((acc2 + np.int64(background[2]) * t + 32768) >> 16)
        a_out = np.uint32((255 * (_FULL - t) + np.int64(background[3]) * t + 32768) >> 16)
        out[p] = r | (g << np.uint32(8)) | (b << np.uint32(16)) | (a_out << np.uint32(24))
        for q in range(5):
            sums[p, q] = 0


@njit(parallel=True, cache=True)
def transparency_shade(
    firsts, counts, bits, mats, row_lo, row_hi, low, med, high, width, height, near, far, step, bands,
    alphas, color, footprint, size, atten, kbuf, kalpha, sums, table, background, fallback, out, token,
):  # fmt: skip
    """Hybrid transparency, accumulation and resolve in one parallel pass over screen bands (the
    layout of ``hqs_shade``): band t's thread re-projects (raster.py's ``project_batch``) the
    batches reaching its rows and puts every fragment (each footprint pixel of every step-th
    point, as the depth pass drew them) into its pixel's k-buffer ``kbuf`` (pixels, layers) u64,
    with the kept fragments' alphas in ``kalpha`` (pixels, layers) u8, and sums ``sums``
    (pixels, 5) u64 (``_tr_add``; ``alphas[k]`` = the batch's 8-bit alpha and revealage term),
    then composites its rows over ``background`` (4 ints) with the transmittance ``table``
    (``fallback`` where nothing landed). The k-buffer keeps the
    smallest keys and the sums are integers: the image does not depend on the order or the
    thread count. kbuf must be EMPTY and sums zero on entry; they are on exit. ``token``: the
    matrices' shape (``raster.shape_token``)."""
    n_bands = bands.shape[0] - 1
    n_fp = footprint.shape[0]
    reach, max_count = _band_reach(footprint, counts)
    near32 = np.float32(near)
    far32 = np.float32(far)
    spans, rows = footprint_spans(footprint)
    rr = spans.shape[1] // 2
    k_max = spans.shape[0] - 1
    one_centre = rows[1, 0] == 0 and rows[1, 1] == 0 and spans[1, rr, 0] == 0 and spans[1, rr, 1] == 0
    for t in prange(n_bands):
        r0 = bands[t]
        r1 = bands[t + 1]
        p0 = np.int32(r0 * width)
        p1 = np.int32(r1 * width)
        pix, depth, sub_low, sub_med, sub_high = _every_scratch(max_count, step)
        dbits = depth.view(np.uint32)
        for k in range(counts.shape[0]):
            if r0 == r1 or row_hi[k] + reach < r0 or row_lo[k] - reach >= r1:
                continue
            first = firsts[k]
            clip = not inside_frustum(mats[k], width, height, near32, far32)
            n = _project_every(low, med, high, first, counts[k], step, bits[k], mats[k], width, height, near32, far32,
                               pix, depth, clip, token, sub_low, sub_med, sub_high)  # fmt: skip
            a8 = np.uint64(alphas[k, 0])
            reveal = (np.uint64(alphas[k, 1]) << _TR_COUNT_SHIFT) + np.uint64(1)
            for j in range(n):  # entry j is point first + j * step
                p = pix[j]
                if p < 0:
                    continue
                index = first + j * step
                key = (np.uint64(dbits[j]) << np.uint64(32)) | np.uint64(index)
                if n_fp == 1:
                    if p0 <= p < p1:
                        _tr_add(p, key, color[index], a8, reveal, kbuf, kalpha, sums)
                    continue
                x = np.int64(p % width)
                y = np.int64(p // width)
                if y + reach < r0 or y - reach >= r1:
                    continue
                s = size if atten == 0 else min(size, max(np.float32(1.0), atten / depth[j]))
                kk = min(np.int64(s), k_max)  # needs are integers: size s covers those of floor(s)
                col = color[index]
                if kk == 1 and one_centre:  # most points of an adaptive overview: their own pixel
                    if r0 <= y < r1:
                        _tr_add(p, key, col, a8, reveal, kbuf, kalpha, sums)
                    continue
                # row by row (the footprint as runs of columns, raster.footprint_spans): neighbouring
                # pixels one after the other, 7-18 % faster than the table's order by need
                for dy in range(max(np.int64(rows[kk, 0]), r0 - y), min(np.int64(rows[kk, 1]), r1 - 1 - y) + 1):
                    row = (y + dy) * width
                    for xx in range(max(x + spans[kk, dy + rr, 0], 0), min(x + spans[kk, dy + rr, 1], width - 1) + 1):
                        _tr_add(row + xx, key, col, a8, reveal, kbuf, kalpha, sums)
        _tr_resolve_rows(r0, r1, width, kbuf, kalpha, sums, color, table, background, fallback, out)


@njit(parallel=True, cache=True)
def downsample(vis, image, width, height, s, vis_out, image_out):
    """s x s blocks of a (height*s, width*s) render -> the closest key and the rounded mean RGBA."""
    big_w = width * s
    half = (s * s) // 2
    for y in prange(height):
        for x in range(width):
            k = EMPTY
            acc0 = 0
            acc1 = 0
            acc2 = 0
            acc3 = 0
            for dy in range(s):
                row = (y * s + dy) * big_w + x * s
                for dx in range(s):
                    k = min(k, vis[row + dx])
                    c = image[row + dx]
                    acc0 += c & np.uint32(255)
                    acc1 += (c >> np.uint32(8)) & np.uint32(255)
                    acc2 += (c >> np.uint32(16)) & np.uint32(255)
                    acc3 += c >> np.uint32(24)
            vis_out[y * width + x] = k
            n = s * s
            image_out[y * width + x] = (
                np.uint32((acc0 + half) // n)
                | (np.uint32((acc1 + half) // n) << np.uint32(8))
                | (np.uint32((acc2 + half) // n) << np.uint32(16))
                | (np.uint32((acc3 + half) // n) << np.uint32(24))
            )


# --- lighting ----------------------------------------------------------------------------------
@njit(parallel=True, cache=True)
def blinn_phong(vis, normals, colors, view_dirs, ambient, diffuse, specular, shininess, out):
    """Headlight Blinn-Phong (light = eye direction, so the half vector is the view vector).
    Normals are unoriented: the side facing the camera is lit. view_dirs (n_pix or 1, 3)."""
    one_dir = view_dirs.shape[0] == 1
    for p in prange(vis.shape[0]):
        k = vis[p]
        c = colors[p]
        if k == EMPTY:
            out[p] = c
            continue
        i = np.int64(k & _LOW32)
        q = np.int64(0) if one_dir else np.int64(p)
        ndv = abs(normals[i, 0] * view_dirs[q, 0] + normals[i, 1] * view_dirs[q, 1] + normals[i, 2] * view_dirs[q, 2])
        ndv = min(ndv, np.float32(1.0))
        lit = ambient + diffuse * ndv
        spec = specular * ndv**shininess * np.float32(255.0)
        res = c & np.uint32(0xFF000000)
        for s in range(3):
            v = np.float32((c >> np.uint32(8 * s)) & np.uint32(255)) * lit + spec + np.float32(0.5)
            res |= np.uint32(min(max(v, np.float32(0.0)), np.float32(255.0))) << np.uint32(8 * s)
        out[p] = res
