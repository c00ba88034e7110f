"""The numba kernels of raster_fill.py's ``fill_everywhere`` (pull-push), in a module of their
own so that importing raster_fill (the CLI's render and change commands do) loads no numba."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def pulled(values: np.ndarray, weights: np.ndarray):  # pragma: no cover - compiled
    """The next level up the pyramid: each coarse cell the weighted mean of its (up to) 2 x 2
    cells, its weight their weights' sum capped at 1 (a cell with one known child is known)."""
    rows, cols = values.shape
    coarse = np.zeros(((rows + 1) // 2, (cols + 1) // 2))
    weight = np.zeros(coarse.shape)
    for r in range(rows):
        for c in range(cols):
            if weights[r, c] > 0:
                coarse[r // 2, c // 2] += weights[r, c] * values[r, c]
                weight[r // 2, c // 2] += weights[r, c]
    for r in range(coarse.shape[0]):
        for c in range(coarse.shape[1]):
            if weight[r, c] > 0:
                coarse[r, c] /= weight[r, c]
                weight[r, c] = min(weight[r, c], 1.0)
    return coarse, weight


@njit(cache=True)
def pushed(values: np.ndarray, weights: np.ndarray, coarse: np.ndarray) -> None:  # pragma: no cover - compiled
    """A level back down the pyramid, in place: each cell blended with the (filled) ``coarse``
    level read bilinearly at its centre, by its weight (a known cell, weight 1, kept as it is)."""
    rows, cols = values.shape
    top_r, top_c = coarse.shape[0] - 1, coarse.shape[1] - 1
    for r in range(rows):
        fy = min(max(r / 2.0 - 0.25, 0.0), float(top_r))  # the centre of fine cell r is at r / 2 - 0.25 in coarse cells
        r0 = min(int(fy), max(top_r - 1, 0))
        r1, ty = min(r0 + 1, top_r), fy - r0
        for c in range(cols):
            w = weights[r, c]
            if w >= 1.0:
                continue
            fx = min(max(c / 2.0 - 0.25, 0.0), float(top_c))
            c0 = min(int(fx), max(top_c - 1, 0))
            c1, tx = min(c0 + 1, top_c), fx - c0
            up = coarse[r0, c0] * (1 - tx) + coarse[r0, c1] * tx
            down = coarse[r1, c0] * (1 - tx) + coarse[r1, c1] * tx
            values[r, c] = w * values[r, c] + (1 - w) * (up * (1 - ty) + down * ty)
