"""Point size and shape: each point covers a footprint of pixels, all at the point's own depth.

The footprint is a list of pixel offsets (dx, dy) with the smallest point size that covers
each (``need``), sorted by it, so one table serves every size up to ``point_size``:
a point of size s writes the offsets with need <= s. Squares of even size extend one
pixel more to the right/bottom; round points are discs of diameter s around the pixel.
Every footprint pixel goes through the normal depth test with the point's own key, so a
nearer small point is never hidden by a farther large one.

``size_mode='attenuated'``: the size is ``point_world_size`` metres projected at the
point's depth (perspective: scale / depth, with scale = world size x focal length in
pixels), clamped to 1 .. point_size.
"""

from __future__ import annotations

import functools
import math

import numpy as np


@functools.lru_cache(maxsize=16)
def footprint(size: int, shape: str = "square") -> np.ndarray:
    """(k, 3) int32 rows (dx, dy, need), sorted by need, for point sizes up to ``size``."""
    r = size // 2
    rows = []
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            if shape == "round":
                need = max(1, math.ceil(2.0 * math.sqrt(dx * dx + dy * dy) - 1e-9))
            else:
                nx = 2 * dx if dx > 0 else 2 * -dx + 1
                ny = 2 * dy if dy > 0 else 2 * -dy + 1
                need = max(nx, ny, 1)
            if need <= size:
                rows.append((dx, dy, need))
    rows.sort(key=lambda t: (t[2], t[1], t[0]))
    return np.array(rows, np.int32).reshape(-1, 3)


def splat_params(settings, camera):
    """(footprint, size, atten) for the rasterizer: float32 size is the fixed size in pixels
    (or the clamp for attenuated points), atten the perspective scale (0: fixed size)."""
    size = np.float32(settings.point_size)
    atten = np.float32(0.0)
    if settings.size_mode == "attenuated":
        if camera.projection == "perspective":
            atten = np.float32(settings.point_world_size * (camera.height / 2.0) / math.tan(math.radians(camera.fov) / 2.0))
        else:
            size = np.float32(min(settings.point_size, max(1.0, settings.point_world_size * camera.height / camera.ortho_height)))
    return footprint(settings.point_size, settings.point_shape), size, atten


def point_sizes(depth: np.ndarray, size: np.float32, atten: np.float32) -> np.ndarray:
    """float32 per-point size in pixels (the same float32 arithmetic as the kernel)."""
    if atten == 0:
        return np.full(depth.shape, size, np.float32)
    return np.minimum(size, np.maximum(np.float32(1.0), atten / depth.astype(np.float32)))
