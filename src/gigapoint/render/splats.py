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

``size_mode='adaptive'`` (Potree's default, and ours: ``size_mode='auto'`` without a
point_size or point_world_size): the same, with the world size the cloud's own point
spacing (``point_spacing``: each batch's points over the area of its box, the median over
the points) times ``ADAPTIVE_FILL`` times ``point_size``, clamped to 1 .. ``ADAPTIVE_MAX_PX``:
neighbouring points touch on screen, so sparse real data looks solid at every distance.
``size_mode='fixed'`` with ``point_size=1`` is the exact one-pixel render.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from ..errors import GigapointError


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


#: the ``splat`` of one-pixel points, what None stands for: footprint (dx, dy, need) of the
#: point's own pixel, size 1, no attenuation
ONE_PIXEL = (np.array([[0, 0, 1]], np.int32), np.float32(1.0), np.float32(0.0))

#: adaptive points cover this many times the point spacing: at 1 they would touch on a regular
#: grid, real scans are not one (lines of a scanner, overlapping strips), so holes stay open below ~1.5
ADAPTIVE_FILL = 1.25
ADAPTIVE_MAX_PX = 16  # the largest adaptive point, in pixels


def point_spacing(points, step: int = 1) -> float:
    """World distance between neighbouring points of a cloud's buffers (``points.batches``),
    drawing every ``step``-th point: per batch, the area of its box's two largest sides (points
    on a surface) over its points, the median over points. 0 for a cloud without extent."""
    rec = points.batches
    counts = rec["count"].astype(np.float64)
    keep = counts > 0
    if not keep.any():
        return 0.0
    counts = np.ceil(counts[keep] / max(1, step))
    ext = np.sort(rec["bbox_max"][keep] - rec["bbox_min"][keep], axis=1)
    return weighted_median(np.sqrt(ext[:, 2] * ext[:, 1] / counts), counts)


def weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """The median of ``values`` with each counted ``weights`` times (the median over points of a
    per-batch figure). ``weights`` > 0, not empty."""
    order = np.argsort(values, kind="stable")
    cum = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cum, cum[-1] / 2.0)])


def splat_params(settings, camera, spacing: float | None = None):
    """(footprint, size, atten) for the rasterizer: float32 size is the fixed size in pixels
    (or the clamp for attenuated points), atten the perspective scale (0: fixed size).
    ``spacing``: the cloud's ``point_spacing`` (needed by ``size_mode='adaptive'``)."""
    size = np.float32(settings.point_size)
    atten = np.float32(0.0)
    mode, largest, world = settings.point_sizing, settings.point_size, settings.point_world_size
    if mode == "adaptive":
        if spacing is None:
            raise GigapointError("size_mode 'adaptive' needs the cloud's point spacing (splats.point_spacing)")
        largest, world = ADAPTIVE_MAX_PX, spacing * ADAPTIVE_FILL * settings.point_size
        size = np.float32(largest)
    if mode != "fixed":  # (this float64 operation order is the attenuated mode's since #5)
        if camera.projection == "perspective":
            atten = np.float32(world * (camera.height / 2.0) / math.tan(math.radians(camera.fov) / 2.0))
            if mode == "adaptive" and atten == 0:  # no spacing (a single point, a line): one pixel
                size = np.float32(1.0)
        else:
            size = np.float32(min(largest, max(1.0, world * camera.height / camera.ortho_height)))
    return footprint(largest, settings.point_shape), size, atten


def largest_size(splat, nearest_depth: float) -> float:
    """The largest size in pixels a point of ``splat`` gets at depths >= ``nearest_depth``."""
    _, size, atten = splat
    if atten == 0:
        return float(size)
    return float(min(size, max(np.float32(1.0), atten / np.float32(max(nearest_depth, 1e-30)))))


def point_sizes(depth: np.ndarray, size: np.float32, atten: np.float32) -> np.ndarray:
    """float32 per-point size in pixels (the same float32 arithmetic as the kernel)."""
    if atten == 0:
        return np.full(depth.shape, size, np.float32)
    return np.minimum(size, np.maximum(np.float32(1.0), atten / depth.astype(np.float32)))
