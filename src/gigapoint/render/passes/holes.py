"""Hole filling: depth-aware dilation of the visibility buffer (Schütz et al. 2022, 3.7).

A pixel that is empty, or lies more than ``depth_gap`` (relative) behind neighbours in
its window (a far point seen through a gap in a nearer surface), takes the closest key of
its window — but only when those closer neighbours *surround* it: their directions,
binned into 16 sectors, leave no half-plane free. A one-pixel gap in a surface is
surrounded and closes; a pixel just outside a silhouette sees neighbours on one side
only and stays, so objects do not grow. ``level`` 1, 2, 3 = 3x3, 5x5, 7x7 windows;
``foveated`` uses 3x3 at the image centre growing to the full window at the corners.
The result is a new visibility buffer, so picking, depth and later passes see the fill.

The backends run it (their Passes.fill_holes); this is its plain-numpy reference, and the
window, radius map and depth gap all of them use are in render/params.py.
"""

from __future__ import annotations

import numpy as np

from ...core.layout import EMPTY_PIXEL
from ..params import DEPTH_GAP, N_SECTORS, radius_map, window


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
