"""Image-quality passes applied after rasterization (issue #5): their order and references.

``finish_frame`` turns a depth pass's visibility buffer into the final colors, in this
order: hole filling (on the visibility buffer) -> color resolve (color mode; HQS blends
instead of taking the winner; transparent points, transparency.py, are composited instead)
-> Blinn-Phong lighting -> eye-dome lighting. The backend's
``Passes`` (gigapoint.render.backend) run each step on its own buffers; supersampling and
stereo wrap whole renders (``compose.py``). Every pass has a plain-numpy reference in
this package, which the tests compare the backends against.
"""

from __future__ import annotations

import numpy as np

from ..cache import render_cache
from ..colors import point_colors, rgba_point_colors
from ..splats import largest_size, point_spacing, splat_params
from .lighting import point_normals
from .transparency import frame_alphas, wants_transparency


def wants_composite(settings) -> bool:
    return settings.supersample > 1 or settings.stereo != "none"


def splat_for(settings, camera, draw=None, near: float = 0.0):
    """The ``splat`` argument of rasterization for points larger than a pixel (None: one pixel).

    Adaptive sizes (``RenderSettings.point_sizing``: 'adaptive') come from the point spacing of ``draw``'s buffers
    (every ``draw.step``-th point drawn); where no point of its selection can reach two pixels
    (a dense cloud, a far view) the one-pixel loop draws the same image, faster."""
    if settings.point_sizing != "adaptive":
        return splat_params(settings, camera) if settings.point_size > 1 else None
    if draw is None or len(draw.selection.ids) == 0:
        return None
    spacing = draw.spacing if draw.spacing is not None else _spacing(draw.points, draw.step)
    splat = splat_params(settings, camera, spacing)
    return splat if largest_size(splat, nearest_depth(draw.selection.matrices, near)) >= 2.0 else None


def _spacing(points, step: int) -> float:
    """``point_spacing`` of point buffers, kept in the RenderCache: a pass over every batch's box
    (30 ms a frame at 100 000 batches) paid once, not in every frame."""
    cache = render_cache.arrays(points)
    key = f"__spacing_{step}__"
    spacing = cache.get(key)
    if spacing is None:
        spacing = cache[key] = point_spacing(points, step)
    return spacing


def nearest_depth(matrices: np.ndarray, near: float) -> float:
    """The smallest depth (not below ``near``) of the grid cubes [0, 1024]^3 that batch
    ``matrices`` (k, 4, 4: row 3 is the depth) place."""
    m = matrices[:, 3, :].astype(np.float64)
    d = m[:, 3] + np.minimum(m[:, :3] * 1024.0, 0.0).sum(axis=1)
    return max(float(d.min()), near)


def finish_frame(backend, draw, camera, vis, settings, near, far) -> tuple[np.ndarray, np.ndarray, int | None]:
    """(visibility, u32 colors, covered pixels or None) of a frame of DrawList ``draw`` after
    the passes ``settings`` asks for. The backend's lock is held throughout: its passes share
    scratch buffers. Results become numpy arrays (read back from a GPU) only at the end."""
    width, height = camera.width, camera.height
    points = draw.points
    passes = backend.passes
    with backend.lock:
        if settings.fill_holes:
            vis = passes.fill_holes(vis, width, height, settings.fill_holes, settings.fill_holes_foveated)
        colors_per_point = point_colors(points, settings)  # RGBA8, or RGB565 (a compact cloud's): the blending passes get RGBA8
        colors, covered = passes.resolve(vis, colors_per_point, settings.background)  # after hole filling: later passes keep the pixels
        if wants_transparency(settings, draw):  # transparent points (instead of HQS): blended behind the depth pass's front
            colors = passes.transparent_colors(
                points, draw.selection, vis, width, height, near, far, rgba_point_colors(points, settings), frame_alphas(settings, draw), colors,
                settings.background, settings.threads, splat_for(settings, camera, draw, near), draw.step,
            )  # fmt: skip
        elif settings.hqs:
            colors = passes.hqs_colors(
                points, draw.selection, vis, width, height, near, far, rgba_point_colors(points, settings), colors,
                settings.hqs_depth_tolerance, settings.threads, splat_for(settings, camera, draw, near), settings.splat_softness,
                step=draw.step,
            )  # fmt: skip
        if settings.lighting:
            colors = passes.shade(vis, colors, point_normals(points), camera, settings.shininess)
        if settings.edl:
            colors = passes.eye_dome_lighting(vis, colors, width, height, settings.edl_strength, settings.edl_radius)
        return np.ascontiguousarray(vis), np.ascontiguousarray(colors), covered
