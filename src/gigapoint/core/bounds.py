"""A cloud's valid points and their bounds in one parallel pass (numba: the readers' rule of
core/coords, ``valid_mask``, with the box of what passes), for the octree builders and the
reprojection, which both need the two."""

from __future__ import annotations

import numba
import numpy as np
from numba import njit, prange


@njit(parallel=True, cache=True)
def _valid_bounds(xyz, limit, valid, lo, hi):
    """valid[i] = finite and within ±limit; per-thread-slice min/max of the valid points into lo/hi (T, 3)."""
    n = xyz.shape[0]
    n_threads = lo.shape[0]
    step = (n + n_threads - 1) // n_threads
    for t in prange(n_threads):
        # running bounds in locals: stored into lo/hi per point they would not stay in registers
        lx, ly, lz = lo[t, 0], lo[t, 1], lo[t, 2]
        hx, hy, hz = hi[t, 0], hi[t, 1], hi[t, 2]
        for i in range(t * step, min(n, (t + 1) * step)):
            x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
            ok = abs(x) <= limit and abs(y) <= limit and abs(z) <= limit  # False for NaN too
            valid[i] = ok
            if ok:
                lx, ly, lz = min(lx, x), min(ly, y), min(lz, z)
                hx, hy, hz = max(hx, x), max(hy, y), max(hz, z)
        lo[t, 0], lo[t, 1], lo[t, 2] = lx, ly, lz
        hi[t, 0], hi[t, 1], hi[t, 2] = hx, hy, hz


def valid_bounds(xyz: np.ndarray, limit: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(valid mask, min, max of the valid points) in one parallel pass."""
    n_threads = max(1, numba.get_num_threads())
    valid = np.empty(len(xyz), np.bool_)
    lo = np.full((n_threads, 3), np.inf)
    hi = np.full((n_threads, 3), -np.inf)
    _valid_bounds(np.ascontiguousarray(xyz, np.float64), float(limit), valid, lo, hi)
    return valid, lo.min(axis=0), hi.max(axis=0)
