"""Blinn-Phong headlight shading (Todoran 2019, ch. 4) from per-point normals.

The light sits at the eye, so light, view and half vectors coincide: the lit color is
c * (ambient + diffuse * |n.v|) + specular * |n.v|^shininess * 255. Point normals carry no
reliable sign, so the side facing the camera is the lit one. The backends run it (their
Passes.shade); this module gives them the normals and is its plain-numpy reference. The
constants and view directions all of them use are in render/params.py.
"""

from __future__ import annotations

import numpy as np

from ...core.layout import EMPTY_PIXEL
from ...errors import SettingsError
from ..cache import render_cache
from ..colors import normals_of
from ..params import AMBIENT, DIFFUSE, SPECULAR, view_directions


def point_normals(points) -> np.ndarray:
    """float32 (N, 3) normals of point buffers, converted once (RenderCache)."""
    cache = render_cache.arrays(points)
    n = cache.get("__normals__")
    if n is None:
        n = normals_of(points)
        if n is None:
            raise SettingsError(
                f"lighting: {points.name} has no normals (attributes nx, ny, nz); estimate them with gigapoint.estimate_normals(cloud) "
                f"on a cloud held in memory (gigapoint.open(path))"
            )
        n = np.ascontiguousarray(n, np.float32)
        cache["__normals__"] = n
    return n


def shade_reference(cloud, camera, vis, colors, shininess=32.0) -> np.ndarray:
    vis = vis.reshape(-1)
    hit = vis != EMPTY_PIXEL
    n = point_normals(cloud)[(vis[hit] & np.uint64(0xFFFFFFFF)).astype(np.int64)]
    v = view_directions(camera)
    v = v if len(v) == 1 else v[hit]
    ndv = np.minimum(np.abs(n[:, 0] * v[:, 0] + n[:, 1] * v[:, 1] + n[:, 2] * v[:, 2]), np.float32(1))
    lit = np.float32(AMBIENT) + np.float32(DIFFUSE) * ndv
    spec = np.float32(SPECULAR) * ndv ** np.float32(shininess) * np.float32(255)
    rgba = colors.reshape(-1).view(np.uint8).reshape(-1, 4).copy()
    c = rgba[hit, :3].astype(np.float32) * lit[:, None] + spec[:, None] + np.float32(0.5)
    rgba[hit, :3] = np.clip(c, 0, 255).astype(np.uint8)
    return rgba.view(np.uint32).reshape(-1)
