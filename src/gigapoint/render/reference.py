"""Plain-numpy reference renderer: the same contract as the kernels, written for clarity.

It uses the same batch selection and float32 arithmetic in the same order as the CPU
kernel, so on small scenes the visibility buffers must be identical bit for bit.
"""

from __future__ import annotations

import numpy as np

from ..core.compact import colors_at, point_words
from ..core.layout import EMPTY_PIXEL
from ..core.quantize import unpack_words
from ..core.selection import select
from .camera import Camera
from .settings import RenderSettings
from .splats import point_sizes, point_spacing, splat_params


def grid_coordinates(cloud, first: int, count: int, bits: int, batch: int | None = None) -> np.ndarray:
    """(count, 3) float32 positions of a batch's points in its 10-bit grid units (cell centres).
    ``batch``: its number, needed for the compact layout (whose words decode per batch)."""
    if cloud.med is None:  # the compact layout
        low, med, high = point_words(cloud, int(batch), first, first + count)
    else:
        s = slice(first, first + count)
        low, med, high = cloud.low[s], cloud.med[s], cloud.high[s]
    half, inv = np.float32(0.5), np.float32(1.0 / 1024.0)
    q = unpack_words(low).astype(np.float32)
    if bits == 10:
        return q + half
    m = unpack_words(med).astype(np.float32)
    if bits == 20:
        return q + (m + half) * inv
    h = unpack_words(high).astype(np.float32)
    return q + (m + (h + half) * inv) * inv


def projected_batches(cloud, sel, width: int, height: int, near: float, far: float):
    """Per selected batch: (first, idx, x, y, depth) of its points in view, decoded and projected
    in the kernels' float32 operation order; idx are batch-relative, x, y int64 pixel columns/rows."""
    for k, b in enumerate(sel.ids):
        first, count = int(cloud.batches["first"][b]), int(cloud.batches["count"][b])
        g = grid_coordinates(cloud, first, count, int(sel.bits[k]), int(b))
        m = sel.matrices[k]
        x, y, z = g[:, 0], g[:, 1], g[:, 2]
        sx, sy, sw, sd = (m[r, 0] * x + m[r, 1] * y + m[r, 2] * z + m[r, 3] for r in range(4))
        with np.errstate(divide="ignore", invalid="ignore"):
            px, py = sx / sw, sy / sw
        ok = (sd > np.float32(near)) & (sd < np.float32(far)) & (sw > 0) & (px >= 0) & (px < width) & (py >= 0) & (py < height)
        yield first, np.flatnonzero(ok), px[ok].astype(np.int64), py[ok].astype(np.int64), sd[ok]


def footprint_pixels(x0, y0, sizes, footprint, width: int, height: int):
    """Per footprint row (dx, dy, need): (dx, dy, mask of the points that cover it, their pixel ids)."""
    for dx, dy, need in footprint:
        m = (need <= sizes) & (x0 + dx >= 0) & (x0 + dx < width) & (y0 + dy >= 0) & (y0 + dy < height)
        yield dx, dy, m, (y0[m] + dy) * width + x0[m] + dx


def reference_visibility(cloud, camera: Camera, settings: RenderSettings | None = None) -> np.ndarray:
    settings = RenderSettings.of(settings)
    w, h = camera.width, camera.height
    near, far = camera.clip_range(cloud.bounds)
    sel = select(
        cloud.batches,
        camera.screen_rows(),
        w,
        h,
        near,
        far,
        settings.precision_threshold_px,
        settings.adaptive_precision,
        settings.frustum_culling,
    )
    vis = np.full(w * h, EMPTY_PIXEL, np.uint64)
    footprint, size, atten = splat_params(settings, camera, point_spacing(cloud))
    for first, idx, x0, y0, d in projected_batches(cloud, sel, w, h, near, far):
        keys = (d.view(np.uint32).astype(np.uint64) << np.uint64(32)) | (first + idx).astype(np.uint64)
        sizes = point_sizes(d, size, atten)
        for _, _, m, pix in footprint_pixels(x0, y0, sizes, footprint, w, h):  # every covered pixel gets the point's own key
            np.minimum.at(vis, pix, keys[m])
    return vis.reshape(h, w)


def reference_image(cloud, camera: Camera, settings: RenderSettings | None = None) -> np.ndarray:
    settings = RenderSettings.of(settings)
    vis = reference_visibility(cloud, camera, settings).reshape(-1)
    out = np.empty(len(vis), np.uint32)
    out[:] = np.array(settings.background, np.uint8).view(np.uint32)[0]
    hit = vis != EMPTY_PIXEL
    out[hit] = colors_at(cloud.color, (vis[hit] & np.uint64(0xFFFFFFFF)).astype(np.int64))
    return out.view(np.uint8).reshape(camera.height, camera.width, 4)
