"""Numba kernels of the image-quality passes (render/passes/ drives them).

Screen-space passes (eye-dome lighting, hole filling) run row-parallel; their inner loops
go over one row for one neighbour offset at a time, branch-free, so LLVM vectorises
them. High-quality shading re-projects the selected batches with raster.py's own ``project_batch``
(decode + project, the contract's operation order) so a point lands on exactly the
pixel the depth pass gave it.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .raster import project_batch

EMPTY = np.uint64(0xFFFFFFFFFFFFFFFF)
_LOW32 = np.uint64(0xFFFFFFFF)


# --- eye-dome lighting -------------------------------------------------------------------------
@njit(parallel=True, cache=True)
def log_depth(vis, vis_f32, logd, empty):
    """logd = log2(depth) (0 where empty), empty = 1 where no point.

    vis_f32 is ``vis.view(np.float32)``: element 2p+1 is pixel p's depth (little-endian)."""
    for p in prange(vis.shape[0]):
        e = vis[p] == EMPTY
        logd[p] = np.float32(0.0) if e else np.float32(math.log2(vis_f32[2 * p + 1]))
        empty[p] = np.float32(1.0) if e else np.float32(0.0)


@njit(parallel=True, cache=True)
def edl(logd, empty, colors, width, height, offsets, strength, out):
    """Potree's eye-dome lighting: shade = exp(-300 * strength * mean response), where each of
    the neighbours at ``offsets`` adds max(0, logd - logd_n) (100 if this pixel is empty)."""
    n_off = offsets.shape[0]
    scale = np.float32(-300.0 * strength / n_off)
    for y in prange(height):
        acc = np.zeros(width, np.float32)
        base = y * width
        for o in range(n_off):
            dx = offsets[o, 0]
            dy = offsets[o, 1]
            yy = y + dy
            if yy < 0 or yy >= height:
                continue
            nb = yy * width + dx
            x0 = max(0, -dx)
            x1 = min(width, width - dx)
            for x in range(x0, x1):
                c = logd[base + x]
                ec = empty[base + x]
                valid = np.float32(1.0) - empty[nb + x]
                r = ec * np.float32(100.0) + (np.float32(1.0) - ec) * max(np.float32(0.0), c - logd[nb + x])
                acc[x] += valid * r
        for x in range(width):
            shade = np.float32(math.exp(acc[x] * scale))
            c = colors[base + x]
            r = np.uint32(np.float32(c & np.uint32(255)) * shade + np.float32(0.5))
            g = np.uint32(np.float32((c >> np.uint32(8)) & np.uint32(255)) * shade + np.float32(0.5))
            b = np.uint32(np.float32((c >> np.uint32(16)) & np.uint32(255)) * shade + np.float32(0.5))
            out[base + x] = (c & np.uint32(0xFF000000)) | r | (g << np.uint32(8)) | (b << np.uint32(16))


# --- hole filling ------------------------------------------------------------------------------
@njit(parallel=True, cache=True)
def fill_holes(vis, vis_f32, width, height, offsets, sector_bits, ring, radius_map, inv_gap, out):
    """Depth-aware dilation. A pixel that is empty, or whose depth is more than ``1/inv_gap``
    times that of closer neighbours, takes the closest key in its window, but only when those
    closer neighbours surround it (no half of the 16 direction sectors is free of them), so
    holes close and silhouettes do not grow.

    offsets (k, 2) dx, dy; sector_bits (k,) u32 one bit per direction sector; ring (k,) the
    Chebyshev distance of each offset; radius_map (height, width) int8 window radius per pixel.
    """
    n_off = offsets.shape[0]
    for y in prange(height):
        best = np.empty(width, np.uint64)
        thr = np.empty(width, np.uint64)
        thr_f = np.empty(width, np.float32)
        thr_b = thr_f.view(np.uint32)
        occ = np.zeros(width, np.uint32)
        base = y * width
        for x in range(width):
            best[x] = EMPTY
            thr_f[x] = np.float32(np.inf) if vis[base + x] == EMPTY else vis_f32[2 * (base + x) + 1] * inv_gap
        for x in range(width):
            thr[x] = np.uint64(thr_b[x]) << np.uint64(32)
        rrow = radius_map[y]
        for o in range(n_off):
            dx = offsets[o, 0]
            dy = offsets[o, 1]
            yy = y + dy
            if yy < 0 or yy >= height:
                continue
            m = ring[o]
            bit = sector_bits[o]
            nb = yy * width + dx
            x0 = max(0, -dx)
            x1 = min(width, width - dx)
            for x in range(x0, x1):
                k = vis[nb + x]
                use = m <= rrow[x]
                kk = k if use else EMPTY
                best[x] = min(best[x], kk)
                occ[x] |= bit if (use and k < thr[x]) else np.uint32(0)
        for x in range(width):
            m32 = np.uint64(occ[x]) | (np.uint64(occ[x]) << np.uint64(16))
            z = (~m32) & _LOW32
            z = z & (z >> np.uint64(1))
            z = z & (z >> np.uint64(2))
            z = z & (z >> np.uint64(4))  # a run of 8 free sectors survives
            out[base + x] = best[x] if (z == 0 and best[x] < thr[x]) else vis[base + x]


# --- high-quality shading ----------------------------------------------------------------------
@njit(parallel=True, cache=True)
def hqs_accumulate(firsts, counts, bits, mats, low, med, high, width, height, near, far, starts, vis, vis_f32, tol1, color, acc_rg, acc_ba, acc_n):
    """Every point whose depth is <= (1 + tolerance) x the closest depth at its pixel adds its
    RGBA to thread t's sums (r | g << 32 and b | a << 32: exact for up to 2^24 points a pixel)
    and 1 to its count. acc_*[t] must be zero on entry."""
    n_threads = starts.shape[0] - 1
    max_count = 0
    for k in range(counts.shape[0]):
        max_count = max(max_count, counts[k])
    near32 = np.float32(near)
    far32 = np.float32(far)
    t1 = np.float32(tol1)
    for t in prange(n_threads):
        rg = acc_rg[t]
        ba = acc_ba[t]
        cnt = acc_n[t]
        pix = np.empty(max_count, np.int32)
        depth = np.empty(max_count, np.float32)
        for k in range(starts[t], starts[t + 1]):
            first = firsts[k]
            c = counts[k]
            project_batch(low[first : first + c], med[first : first + c], high[first : first + c], bits[k], mats[k], width, height, near32, far32, pix[:c], depth[:c])
            for j in range(c):
                p = pix[j]
                if p >= 0:
                    if vis[p] != EMPTY:
                        if depth[j] <= vis_f32[2 * p + 1] * t1:
                            col = color[first + j]
                            rg[p] += np.uint64(col & np.uint32(255)) | (np.uint64((col >> np.uint32(8)) & np.uint32(255)) << np.uint64(32))
                            ba[p] += np.uint64((col >> np.uint32(16)) & np.uint32(255)) | (np.uint64(col >> np.uint32(24)) << np.uint64(32))
                            cnt[p] += np.uint32(1)


@njit(parallel=True, cache=True)
def hqs_resolve(acc_rg, acc_ba, acc_n, fallback, out):
    """out[p] = the rounded mean color over all threads' sums (fallback where nothing added)."""
    n_threads = acc_rg.shape[0]
    for p in prange(out.shape[0]):
        rg = np.uint64(0)
        ba = np.uint64(0)
        n = np.uint64(0)
        for t in range(n_threads):
            rg += acc_rg[t, p]
            ba += acc_ba[t, p]
            n += np.uint64(acc_n[t, p])
        if n == 0:
            out[p] = fallback[p]
        else:
            h = n >> np.uint64(1)
            r = ((rg & _LOW32) + h) // n
            g = ((rg >> np.uint64(32)) + h) // n
            b = ((ba & _LOW32) + h) // n
            a = ((ba >> np.uint64(32)) + h) // n
            out[p] = np.uint32(r | (g << np.uint64(8)) | (b << np.uint64(16)) | (a << np.uint64(24)))


@njit(parallel=True, cache=True)
def zero_u64(a):
    flat = a.reshape(-1)
    for i in prange(flat.shape[0]):
        flat[i] = 0


@njit(parallel=True, cache=True)
def zero_u32(a):
    flat = a.reshape(-1)
    for i in prange(flat.shape[0]):
        flat[i] = 0


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
        q = 0 if one_dir else p
        ndv = abs(normals[i, 0] * view_dirs[q, 0] + normals[i, 1] * view_dirs[q, 1] + normals[i, 2] * view_dirs[q, 2])
        ndv = min(ndv, np.float32(1.0))
        lit = ambient + diffuse * ndv
        spec = specular * ndv**shininess * np.float32(255.0)
        res = c & np.uint32(0xFF000000)
        for s in range(3):
            v = np.float32((c >> np.uint32(8 * s)) & np.uint32(255)) * lit + spec + np.float32(0.5)
            res |= np.uint32(min(max(v, np.float32(0.0)), np.float32(255.0))) << np.uint32(8 * s)
        out[p] = res
