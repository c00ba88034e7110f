"""Hole filling: depth-aware dilation of the visibility buffer (Schütz et al. 2022, 3.7).

A pixel that is empty, or lies more than ``depth_gap`` (relative) behind neighbours in
its window (a far point seen through a gap in a nearer surface), takes the closest key of
its window — but only when those closer neighbours *surround* it: their directions,
binned into 16 sectors, leave no half-plane free. A one-pixel gap in a surface is
surrounded and closes; a pixel just outside a silhouette sees neighbours on one side
only and stays, so objects do not grow. ``level`` 1, 2, 3 = 3x3, 5x5, 7x7 windows;
``foveated`` uses 3x3 at the image centre growing to the full window at the corners.
The result is a new visibility buffer, so picking, depth and later passes see the fill.
"""

from __future__ import annotations

import functools
import math

import numba
import numpy as np

from ...backends.numba_cpu import passes as kernels
from ...core.layout import EMPTY_PIXEL

N_SECTORS = 16
DEPTH_GAP = 0.1


def window(level: int):
    """offsets (k, 2) int32 (dx, dy), sector bit (k,) u32, Chebyshev ring (k,) int8 of a (2L+1)^2 window."""
    r = int(level)
    offs = sorted(
        ((dx, dy) for dy in range(-r, r + 1) for dx in range(-r, r + 1) if (dx, dy) != (0, 0)), key=lambda o: max(abs(o[0]), abs(o[1]))
    )
    offsets = np.array(offs, np.int32).reshape(-1, 2)
    ang = np.arctan2(offsets[:, 1].astype(np.float64), offsets[:, 0].astype(np.float64))
    sector = np.floor((ang + math.pi) / (2 * math.pi) * N_SECTORS).astype(np.int64) % N_SECTORS
    bits = (np.uint32(1) << sector.astype(np.uint32)).astype(np.uint32)
    ring = np.maximum(np.abs(offsets[:, 0]), np.abs(offsets[:, 1])).astype(np.int8)
    return offsets, bits, ring


@functools.lru_cache(maxsize=8)
def radius_map(width: int, height: int, level: int, foveated: bool) -> np.ndarray:
    """(height, width) int8 window radius per pixel."""
    if not foveated or level <= 1:
        return np.full((height, width), level, np.int8)
    y, x = np.mgrid[0:height, 0:width]
    d = np.hypot((x + 0.5 - width / 2) / (width / 2), (y + 0.5 - height / 2) / (height / 2)) / math.sqrt(2.0)
    return np.minimum(level, 1 + np.floor(d * level)).astype(np.int8)


def fill_holes(vis: np.ndarray, width: int, height: int, level: int, foveated: bool = False, depth_gap: float = DEPTH_GAP) -> np.ndarray:
    """Filled copy of the (H*W,) u64 visibility buffer."""
    vis = np.ascontiguousarray(vis).reshape(-1)
    if level <= 0:
        return vis
    offsets, bits, ring = window(level)
    sectors = np.log2(bits).astype(np.int64)
    radii = radius_map(width, height, level, foveated)
    runs, run_start = radius_runs(width, height, level, foveated)
    masks = ring_masks(width, height, level, foveated)
    n_bands = min(height, 8 * numba.get_num_threads())  # bands of rows, each gone down once
    out = np.empty_like(vis)
    gap = np.float32(1.0 / (1.0 + depth_gap))
    kernels.fill_holes(vis, vis.view(np.float32), width, height, radii, runs, run_start, masks, offsets, bits, sectors, ring, gap, n_bands, out)
    return out


@functools.lru_cache(maxsize=8)
def radius_runs(width: int, height: int, level: int, foveated: bool):
    """(runs (k, 3) int64, start (H+1,) int64): the runs (xa, xb, r) of one window radius r in
    each row of ``radius_map``, row y's are runs[start[y] : start[y + 1]]."""
    radii = radius_map(width, height, level, foveated)
    brk = np.ones((height, width), bool)
    brk[:, 1:] = radii[:, 1:] != radii[:, :-1]
    ys, xa = np.nonzero(brk)
    nxt = np.append(xa[1:], width)
    xb = np.where(np.append(ys[1:], height) == ys, nxt, width)
    runs = np.stack([xa, xb, radii[ys, xa]], axis=1).astype(np.int64)
    start = np.searchsorted(ys, np.arange(height + 1)).astype(np.int64)
    return runs, start


@functools.lru_cache(maxsize=8)
def ring_masks(width: int, height: int, level: int, foveated: bool) -> np.ndarray:
    """(H, level+1, nw) u64 bit rows: bit x of [y, m] set where pixel (x, y)'s window radius >= m."""
    radii = radius_map(width, height, level, foveated)
    nw = (width + 63) // 64
    bits = np.zeros((height, level + 1, nw * 64), bool)
    for m in range(level + 1):
        bits[:, m, :width] = radii >= m
    return np.packbits(bits, axis=-1, bitorder="little").view(np.uint64)


def _no_free_half(occ: np.ndarray) -> np.ndarray:
    """True where the 16-bit sector mask has no run of 8 (cyclically) free sectors."""
    free = np.stack([(occ >> np.uint32(s)) & np.uint32(1) for s in range(N_SECTORS)], axis=-1) == 0
    run = np.ones(occ.shape, bool)
    any_run = np.zeros(occ.shape, bool)
    for start in range(N_SECTORS):
        run = np.ones(occ.shape, bool)
        for k in range(N_SECTORS // 2):
            run &= free[..., (start + k) % N_SECTORS]
        any_run |= run
    return ~any_run


def fill_holes_reference(
    vis: np.ndarray, width: int, height: int, level: int, foveated: bool = False, depth_gap: float = DEPTH_GAP
) -> np.ndarray:
    """Plain-numpy version of :func:`fill_holes` (same float32 threshold)."""
    v = vis.reshape(height, width)
    if level <= 0:
        return v.reshape(-1).copy()
    empty = v == EMPTY_PIXEL
    depth = (v >> np.uint64(32)).astype(np.uint32).view(np.float32)
    thr_f = np.where(empty, np.float32(np.inf), depth * np.float32(1.0 / (1.0 + depth_gap))).astype(np.float32)
    thr = thr_f.view(np.uint32).astype(np.uint64) << np.uint64(32)
    rad = radius_map(width, height, level, foveated)
    best = np.full((height, width), EMPTY_PIXEL, np.uint64)
    occ = np.zeros((height, width), np.uint32)
    padded = np.full((height + 2 * level, width + 2 * level), EMPTY_PIXEL, np.uint64)
    padded[level : level + height, level : level + width] = v
    offsets, bits, rings = window(level)
    for (dx, dy), bit, ring in zip(offsets, bits, rings):
        n = padded[level + dy : level + dy + height, level + dx : level + dx + width]
        use = ring <= rad
        best = np.minimum(best, np.where(use, n, EMPTY_PIXEL))
        occ |= np.where(use & (n < thr), bit, np.uint32(0)).astype(np.uint32)
    take = _no_free_half(occ) & (best < thr)
    return np.where(take, best, v).reshape(-1)
