"""Image-quality options of `gigapoint render` (issue #5): generated from RenderSettings by cli/settings_opts.py."""

from __future__ import annotations

import dataclasses

from ..core.cloud import PointCloud
from ..render.settings import RenderSettings
from .settings_opts import option_of


def _quality_fields() -> list[str]:
    names = [f.name for f in dataclasses.fields(RenderSettings)]
    return names[names.index("color_mode") :]  # the image-quality block of RenderSettings


# every image-quality field of RenderSettings -> the `gigapoint render` option that sets it
_OPTIONS = option_of(RenderSettings)
OPTION_OF = {name: _OPTIONS[name] for name in _quality_fields()}


def prepare_cloud(cloud, settings) -> None:
    """Estimate normals when lighting or the normal color mode needs them and the cloud has none
    (a plain cloud: an octree's points are not all in memory)."""
    if not (settings.lighting or settings.color_mode == "normal") or not isinstance(cloud, PointCloud):
        return
    from ..render.colors import normals_of

    if normals_of(cloud) is None:
        from ..render.normals import estimate_normals

        estimate_normals(cloud)
