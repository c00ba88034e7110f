"""High-quality shading (Schütz et al. 2021/2022, 3.6): blend all points near the closest depth.

After the depth pass (the normal rasterization), every point whose depth is within
``tolerance`` (relative) behind the closest point of its pixel adds its color and a count;
the resolve divides, rounding half up, with exact integer sums, so the image does not
depend on the order the points come in. Soft splats (Kraft 2019) weigh each footprint
pixel 0..15 (render/params.soft_weight).

The backends run it (their Passes.hqs_colors); this is its plain-numpy reference.
"""

from __future__ import annotations

import numpy as np

from ...core.layout import EMPTY_PIXEL
from ..reference import footprint_pixels, projected_batches
from ..splats import ONE_PIXEL, point_sizes


def hqs_reference(
    cloud, sel, vis, width, height, near, far, point_colors, fallback, tolerance=0.01, splat=None, softness=0.0, step: int = 1
) -> np.ndarray:
    """Plain numpy: the same projection as the reference renderer, exact integer means; ``step``:
    every step-th point of each batch (a point cap's depth pass drew no other)."""
    vis = vis.reshape(-1)
    footprint, size, atten = splat if splat is not None else ONE_PIXEL
    n = width * height
    sums = np.zeros((n, 4), np.int64)
    cnt = np.zeros(n, np.int64)
    depth0 = (vis >> np.uint64(32)).astype(np.uint32).view(np.float32)
    rgba = point_colors.view(np.uint8).reshape(-1, 4).astype(np.int64)
    for first, idx, x0, y0, d in projected_batches(cloud, sel, width, height, near, far):
        drawn = idx % step == 0
        idx, x0, y0, d = idx[drawn], x0[drawn], y0[drawn], d[drawn]
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
