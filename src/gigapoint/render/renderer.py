"""The renderer facade: camera + settings -> selection -> backend -> Frame."""

from __future__ import annotations

import time
import warnings

import numpy as np

from ..backends import get_backend
from ..backends.numba_cpu.raster import count_covered
from ..errors import GigapointError, GigapointWarning
from .camera import Camera
from .frame import Frame, RenderStats
from .passes import finish_frame, raster_options, wants_composite
from .selection import select
from .settings import RenderSettings

_MAX_INDEX = 0xFFFFFFFF  # point indices live in the low 32 bits of the visibility buffer


def subsample_step(counts: np.ndarray, max_points: int) -> int:
    """Smallest k such that every k-th point of each batch stays within ``max_points`` (0: no cap;
    never fewer than one point per batch)."""
    total = int(counts.sum())
    if max_points <= 0 or total <= max_points:
        return 1
    step = -(-total // max_points)
    largest = int(counts.max())
    while step < largest and int(((counts + step - 1) // step).sum()) > max_points:  # each batch rounds up
        step += 1
    return min(step, largest)  # one point per batch is the floor


def render_frame(cloud, camera: Camera, settings: RenderSettings | None = None) -> Frame:
    """Render ``cloud`` into a Frame (visibility buffer, image, stats)."""
    settings = settings or RenderSettings()
    if not isinstance(camera, Camera):
        raise GigapointError(f"camera must be a gigapoint.Camera, got {type(camera).__name__}")
    lod_select = getattr(cloud, "select", None)  # octree clouds (gigapoint.lod) pick nodes into an arena
    if lod_select is None and cloud.n_points > _MAX_INDEX:
        raise GigapointError(f"{cloud.name}: {cloud.n_points:,} points exceed the 2^32 a brute-force frame can index; convert it to an octree")
    if wants_composite(settings):  # supersampling / stereo: whole renders combined (passes/compose.py)
        from .passes.compose import composite_frame

        return composite_frame(cloud, camera, settings)
    t0 = time.perf_counter()
    backend = get_backend(settings.backend)
    width, height = camera.width, camera.height
    near, far = camera.clip_range(cloud.bounds)
    rows = camera.screen_rows()
    lod_cloud = cloud
    if lod_select is not None:
        cloud, sel = lod_select(camera, settings)  # the arena quacks like a PointCloud for everything below
    else:
        sel = select(cloud.batches, rows, width, height, near, far, settings.precision_threshold_px, settings.adaptive_precision, settings.frustum_culling)
    counts = cloud.batches["count"][sel.ids].astype(np.int64)
    t1 = time.perf_counter()
    backend, extra = raster_options(backend, settings, camera)  # point size / shape (passes/splats.py)
    step = subsample_step(counts, settings.max_points) if lod_select is None else 1
    if step > 1:
        extra["step"] = step
        counts = (counts + step - 1) // step
    visibility = backend.rasterize(cloud, sel, width, height, near, far, settings.threads, **extra)
    t2 = time.perf_counter()
    covered: list = []
    visibility, colors = finish_frame(backend, cloud, camera, sel, visibility, settings, near, far, covered)
    image = colors.view(np.uint8).reshape(height, width, 4)
    visibility = visibility.reshape(height, width)
    stats = RenderStats(
        points_total=lod_cloud.n_points,
        batches_total=len(lod_cloud.batches),
        batches_culled=sel.n_culled,
        batches_rendered=len(sel.ids),
        points_processed=int(counts.sum()),
        precision_histogram={b: int(counts[sel.bits == b].sum()) for b in (10, 20, 30)},
        time_ms=(time.perf_counter() - t0) * 1000.0,
        raster_ms=(t2 - t1) * 1000.0,
        backend=backend.name,
    )
    frame = Frame(visibility, image, stats)
    stats.visible_pixels = covered[0] if covered else int(count_covered(frame.visibility.reshape(-1)))
    if stats.visible_pixels == 0:
        warnings.warn(f"{cloud.name}: no point is in view of the camera; the image shows only the background", GigapointWarning, stacklevel=2)
    return frame


def render(cloud, camera: Camera, settings: RenderSettings | None = None, return_stats: bool = False, **setting_overrides):
    """(H, W, 4) uint8 RGBA image of ``cloud`` seen by ``camera`` (and RenderStats if asked)."""
    if setting_overrides:
        settings = (settings or RenderSettings()).replace(**setting_overrides)
    frame = render_frame(cloud, camera, settings)
    return (frame.image, frame.stats) if return_stats else frame.image
