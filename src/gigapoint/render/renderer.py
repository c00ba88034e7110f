"""The renderer facade: camera + settings -> the cloud's DrawList -> backend -> Frame.

It orchestrates and knows neither the kind of cloud (any Renderable: core/renderable.py)
nor the backend (any Backend: backend.py).
"""

from __future__ import annotations

import time

import numpy as np

from ..core.layout import EMPTY_PIXEL
from ..core.renderable import Renderable
from ..errors import GigapointError, GigapointWarning, check_switch, type_text, warn
from .backend import get_backend
from .camera import Camera, image_size
from .frame import Frame, RenderStats, check_indexable
from .passes import finish_frame, splat_for, wants_composite
from .passes.compose import composite_frame
from .settings import RenderSettings

_RENDERABLE_TYPES: set[type] = set()  # classes already checked (isinstance of a Protocol costs ~50 µs)


def check_renderable(cloud) -> None:
    """A clear error for what is not a cloud (an array, a path) instead of an AttributeError later."""
    if type(cloud) in _RENDERABLE_TYPES:
        return
    if not isinstance(cloud, Renderable):
        raise GigapointError(f"render: cannot draw {type_text(cloud)}; give a cloud (gigapoint.open, from_arrays, demo)")
    _RENDERABLE_TYPES.add(type(cloud))


def render_frame(cloud, camera: Camera | None = None, settings: RenderSettings | None = None,
                 width: int | None = None, height: int | None = None, **setting_overrides) -> Frame:  # fmt: skip
    """Render ``cloud`` (any Renderable) into a Frame (visibility buffer, image, stats). Without a
    camera: ``Camera.fit_cloud(cloud)`` (1920x1080, the CLI's default view) of what it holds now.
    ``width`` / ``height``: the image's size instead of the camera's; one side alone: the other
    follows the camera's aspect (the fitted one's 16:9: width=800 is 800x450; ``image_size``).
    Settings as ``render`` takes them: ``settings`` and/or keywords (``point_size=3``)."""
    settings = RenderSettings.of(settings)
    if setting_overrides:  # (size_mode=... was a TypeError here, a setting in render)
        settings = settings.given(**setting_overrides)
    check_renderable(cloud)
    if camera is None:
        fit_width, fit_height = image_size(width, height)
        camera = Camera.fit_cloud(cloud, width=fit_width, height=fit_height)
    elif isinstance(camera, Camera) and (width is not None or height is not None):  # (width=... was "unknown render setting(s)" here)
        camera = camera.with_size(*image_size(width, height, (camera.width, camera.height)))
    if not isinstance(camera, Camera):
        raise GigapointError(f"camera must be a gigapoint.Camera, got {type(camera).__name__}")
    if wants_composite(settings):  # supersampling / stereo: whole renders combined (passes/compose.py)
        return composite_frame(cloud, camera, settings, render_frame)
    t0 = time.perf_counter()
    backend = get_backend(settings.backend)
    view = camera.view(cloud.bounds)
    with cloud.reading():  # a cloud that fills while drawn waits with its next insertion
        draw = cloud.prepare(view, settings)
        check_indexable(draw.points)
        counts = draw.points.batches["count"][draw.selection.ids].astype(np.int64)
        if draw.step > 1:
            counts = (counts + draw.step - 1) // draw.step
        t1 = time.perf_counter()
        visibility = backend.rasterize(
            draw.points, draw.selection, view.width, view.height, view.near, view.far, settings.threads,
            splat=splat_for(settings, camera, draw, view.near), step=draw.step, keep_on_device=True,
        )  # fmt: skip
        t2 = time.perf_counter()
        visibility, colors, covered = finish_frame(backend, draw, camera, visibility, settings, view.near, view.far)
    image = colors.view(np.uint8).reshape(view.height, view.width, 4)
    visibility = visibility.reshape(view.height, view.width)
    stats = RenderStats.of(draw, counts, cloud.n_points, (time.perf_counter() - t0) * 1000.0, (t2 - t1) * 1000.0, backend.name)
    stats.visible_pixels = covered if covered is not None else int(np.count_nonzero(visibility != EMPTY_PIXEL))
    if stats.visible_pixels == 0:
        why = " (it holds none: nothing loaded yet, or closed)" if cloud.n_points == 0 else ""
        warn(f"{cloud.name}: no point is in view of the camera{why}; the image shows only the background", GigapointWarning)
    return Frame(visibility, image, stats, draw.points, draw.generation)


def render(cloud, camera: Camera | None = None, settings: RenderSettings | None = None, return_stats: bool = False,
           width: int | None = None, height: int | None = None, **setting_overrides):  # fmt: skip
    """(H, W, 4) uint8 RGBA image of ``cloud`` seen by ``camera`` (and RenderStats if asked), an
    ``Image``: the array, shown as the picture in a notebook (frame.py); without a camera, ``Camera.fit_cloud(cloud)`` of what it holds now (1920x1080). ``width`` /
    ``height``: the image's size instead of the camera's; one side alone: the other follows the
    camera's aspect (the fitted one's 16:9: width=800 is 800x450), as in ``render_frame``."""
    check_switch("return_stats", return_stats, "render")  # "no" gave the stats too
    frame = render_frame(cloud, camera, settings, width, height, **setting_overrides)
    return (frame.image, frame.stats) if return_stats else frame.image
