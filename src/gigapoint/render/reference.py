"""Plain-numpy reference renderer: the same contract as the kernels, written for clarity.

It uses the same batch selection and float32 arithmetic in the same order as the CPU
kernel, so on small scenes the visibility buffers must be identical bit for bit.
"""

from __future__ import annotations

import numpy as np

from ..core.layout import EMPTY_PIXEL
from ..core.quantize import unpack_words
from .camera import Camera
from .passes.splats import point_sizes, splat_params
from .selection import select
from .settings import RenderSettings


def grid_coordinates(cloud, first: int, count: int, bits: int) -> np.ndarray:
    """(count, 3) float32 positions of a batch's points in its 10-bit grid units (cell centres)."""
    s = slice(first, first + count)
    half, inv = np.float32(0.5), np.float32(1.0 / 1024.0)
    q = unpack_words(cloud.low[s]).astype(np.float32)
    if bits == 10:
        return q + half
    m = unpack_words(cloud.med[s]).astype(np.float32)
    if bits == 20:
        return q + (m + half) * inv
    h = unpack_words(cloud.high[s]).astype(np.float32)
    return q + (m + (h + half) * inv) * inv


def reference_visibility(cloud, camera: Camera, settings: RenderSettings | None = None) -> np.ndarray:
    settings = settings or RenderSettings()
    w, h = camera.width, camera.height
    near, far = camera.clip_range(cloud.bounds)
    sel = select(cloud.batches, camera.screen_rows(), w, h, near, far, settings.precision_threshold_px, settings.adaptive_precision, settings.frustum_culling)
    vis = np.full(w * h, EMPTY_PIXEL, np.uint64)
    footprint, size, atten = splat_params(settings, camera)
    for k, b in enumerate(sel.ids):
        first, count = int(cloud.batches["first"][b]), int(cloud.batches["count"][b])
        g = grid_coordinates(cloud, first, count, int(sel.bits[k]))
        m = sel.matrices[k]
        x, y, z = g[:, 0], g[:, 1], g[:, 2]
        sx, sy, sw, sd = (m[r, 0] * x + m[r, 1] * y + m[r, 2] * z + m[r, 3] for r in range(4))
        with np.errstate(divide="ignore", invalid="ignore"):
            px, py = sx / sw, sy / sw
        ok = (sd > np.float32(near)) & (sd < np.float32(far)) & (sw > 0) & (px >= 0) & (px < w) & (py >= 0) & (py < h)
        keys = (sd[ok].view(np.uint32).astype(np.uint64) << np.uint64(32)) | (first + np.flatnonzero(ok)).astype(np.uint64)
        x0, y0 = px[ok].astype(np.int64), py[ok].astype(np.int64)
        sizes = point_sizes(sd[ok], size, atten)
        for dx, dy, need in footprint:  # point size: every covered pixel gets the point's own key
            m = (need <= sizes) & (x0 + dx >= 0) & (x0 + dx < w) & (y0 + dy >= 0) & (y0 + dy < h)
            np.minimum.at(vis, (y0[m] + dy) * w + x0[m] + dx, keys[m])
    return vis.reshape(h, w)


def reference_image(cloud, camera: Camera, settings: RenderSettings | None = None) -> np.ndarray:
    settings = settings or RenderSettings()
    vis = reference_visibility(cloud, camera, settings).reshape(-1)
    out = np.empty(len(vis), np.uint32)
    out[:] = np.array(settings.background, np.uint8).view(np.uint32)[0]
    hit = vis != EMPTY_PIXEL
    out[hit] = cloud.color[(vis[hit] & np.uint64(0xFFFFFFFF)).astype(np.int64)]
    return out.view(np.uint8).reshape(camera.height, camera.width, 4)
