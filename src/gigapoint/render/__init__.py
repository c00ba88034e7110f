"""The renderer: cameras, settings, the Backend contract, passes and their references, the facade.

The names below are imported on first use (PEP 562): the renderer's modules define numba
kernels, which ``import gigapoint`` and the CLI's ``--help`` and ``info`` need none of."""

from __future__ import annotations

_LAZY = {
    "VIEWS": "camera",
    "Camera": "camera",
    "Frame": "frame",
    "Image": "frame",
    "RenderStats": "frame",
    "render": "renderer",
    "render_frame": "renderer",
    "RenderSettings": "settings",
    "parse_color": "settings",
}


from ..core.hooks import lazy_names

__getattr__ = lazy_names(__name__, _LAZY)


__all__ = ["VIEWS", "Camera", "Frame", "Image", "RenderSettings", "RenderStats", "parse_color", "render", "render_frame"]
