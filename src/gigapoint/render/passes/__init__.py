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


def finish_frame(backend, cloud, camera, sel, vis, settings, near, far):
    """(visibility, u32 colors) of a frame after the passes ``settings`` asks for."""
    width, height = camera.width, camera.height
    if settings.fill_holes:
        from .holes import fill_holes

        vis = fill_holes(vis, width, height, settings.fill_holes, settings.fill_holes_foveated)
    colors_per_point = point_colors(cloud, settings)
    colors = backend.resolve(vis, colors_per_point, settings.background)
    if settings.hqs:
        from .hqs import hqs_colors

        colors = hqs_colors(cloud, sel, vis, width, height, near, far, colors_per_point, colors, settings.hqs_depth_tolerance, settings.threads)
    if settings.lighting:
        from .lighting import shade

        colors = shade(cloud, camera, vis, colors, settings.shininess)
    if settings.edl:
        from .edl import eye_dome_lighting

        colors = eye_dome_lighting(vis, colors, width, height, settings.edl_strength, settings.edl_radius)
    return vis, np.ascontiguousarray(colors)
