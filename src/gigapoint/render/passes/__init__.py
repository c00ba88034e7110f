"""Image-quality passes applied after rasterization (issue #5).

``finish_frame`` turns a depth pass's visibility buffer into the final colors, in this
order: hole filling (on the visibility buffer) -> color resolve (color mode; HQS blends
instead of taking the winner) -> Blinn-Phong lighting -> eye-dome lighting. Supersampling
and stereo wrap whole renders (``compose.py``). Every pass has a plain-numpy reference
next to it, which the tests compare against.
"""

from __future__ import annotations

import numpy as np

from ..colors import point_colors


def wants_composite(settings) -> bool:
    return settings.supersample > 1 or settings.stereo != "none"


def raster_options(backend, settings, camera):
    """(backend, keyword arguments for backend.rasterize): point size and shape, and, for
    backends with GPU ``passes``, keeping the visibility buffer on the device for them.
    Both backends (cpu, wgpu) draw every point size, so the backend is returned as given."""
    extra = {"keep_on_device": True} if getattr(backend, "passes", None) is not None else {}
    if settings.point_size > 1:
        from .splats import splat_params

        extra["splat"] = splat_params(settings, camera)
    return backend, extra


def finish_frame(backend, cloud, camera, sel, vis, settings, near, far, covered: list | None = None):
    """(visibility, u32 colors) of a frame after the passes ``settings`` asks for. ``covered``:
    gets the covered-pixel count appended when the resolve counts them on the way (CPU)."""
    from ...backends.numba_cpu.backend import _KERNEL_LOCK  # numba's parallel kernels: one frame at a time

    with _KERNEL_LOCK:
        return _finish(backend, cloud, camera, sel, vis, settings, near, far, covered)


def _finish(backend, cloud, camera, sel, vis, settings, near, far, covered=None):
    width, height = camera.width, camera.height
    # Backends with ``passes`` (wgpu) run each pass themselves, on buffers kept on the device;
    # their results turn into numpy arrays (read back) only at the end.
    gpu = getattr(backend, "passes", None)
    if settings.fill_holes:
        from .holes import fill_holes

        if gpu is not None:
            fill_holes = gpu.fill_holes
        vis = fill_holes(vis, width, height, settings.fill_holes, settings.fill_holes_foveated)
    colors_per_point = point_colors(cloud, settings)
    if getattr(backend, "counts_covered", False) and covered is not None:  # after hole filling: later passes keep the pixels
        colors = backend.resolve(vis, colors_per_point, settings.background, covered)
    else:
        colors = (backend if gpu is None else gpu).resolve(vis, colors_per_point, settings.background)
    if settings.hqs:
        from .hqs import hqs_colors

        if gpu is not None:
            hqs_colors = gpu.hqs_colors

        splat = None
        if settings.point_size > 1:
            from .splats import splat_params

            splat = splat_params(settings, camera)
        colors = hqs_colors(
            cloud,
            sel,
            vis,
            width,
            height,
            near,
            far,
            colors_per_point,
            colors,
            settings.hqs_depth_tolerance,
            settings.threads,
            splat,
            settings.splat_softness,
        )
    if settings.lighting:
        from .lighting import shade

        if gpu is not None:
            shade = gpu.shade
        colors = shade(cloud, camera, vis, colors, settings.shininess)
    if settings.edl:
        from .edl import eye_dome_lighting

        if gpu is not None:
            eye_dome_lighting = gpu.eye_dome_lighting
        colors = eye_dome_lighting(vis, colors, width, height, settings.edl_strength, settings.edl_radius)
    return np.ascontiguousarray(vis), np.ascontiguousarray(colors)
