"""Surface models: the z of the highest point in each pixel of a top-down camera (``Camera.top_down``),
drawn so that each point lands in its own pixel and keeps its height (``render --gsd --depth-out``,
``gigapoint.orthophoto``, survey/change.py)."""

from __future__ import annotations

import numpy as np

from .camera import Camera
from .frame import Frame
from .renderer import render_frame
from .settings import RenderSettings

#: a surface model's drawing: each point in its exact pixel (no splat reaches a neighbour), 30-bit positions
SURFACE_SETTINGS = {"size_mode": "fixed", "point_size": 1, "adaptive_precision": False}
#: the settings that choose which points are drawn, and on what: a surface keeps the image's (the rest only shade them)
POINTS_DRAWN = ("backend", "threads", "hidden_classes", "point_budget", "max_points", "lod_threshold_px", "lod_foveation")
#: the settings that move a point's pixel or its depth: an image drawn with a surface's values of
#: these (and its POINTS_DRAWN, copied) holds the surface (the others only colour the points)
POINTS_PLACED = ("size_mode", "point_size", "point_shape", "adaptive_precision", "fill_holes", "supersample", "stereo", "opacity", "hqs")


def surface_settings(settings: RenderSettings | None = None) -> RenderSettings:
    """The settings that draw ``settings``' points as a surface model (SURFACE_SETTINGS, nothing
    that spreads a point or fills a hole: splats, supersampling, hole filling)."""
    settings = RenderSettings.of(settings)
    return RenderSettings(**{name: getattr(settings, name) for name in POINTS_DRAWN}, **SURFACE_SETTINGS)


def surface_heights(cloud, camera: Camera, settings: RenderSettings | None = None, frame: Frame | None = None) -> np.ndarray:
    """(H, W) float32 z of ``cloud``'s highest point in each of the top-down ``camera``'s pixels,
    NaN where none (``Camera.heights``), of the points ``settings`` draws. ``frame``: the image
    already drawn with ``settings``, reused where they draw the surface too (else a second draw:
    an adaptive splat held a neighbour's height)."""
    settings = RenderSettings.of(settings)
    surface = surface_settings(settings)
    # (a colour mode or background of its own drew the surface a second time)
    if frame is None or any(getattr(settings, name) != getattr(surface, name) for name in POINTS_PLACED):
        frame = render_frame(cloud, camera, surface)
    return camera.heights(frame.depth)
