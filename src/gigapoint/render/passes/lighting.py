"""Blinn-Phong headlight shading (Todoran 2019, ch. 4) from per-point normals.

The light sits at the eye, so light, view and half vectors coincide: the lit color is
c * (ambient + diffuse * |n.v|) + specular * |n.v|^shininess * 255. Point normals carry no
reliable sign, so the side facing the camera is the lit one.
"""

from __future__ import annotations

import functools

import numpy as np

from ...backends.numba_cpu import passes as kernels
from ...core.layout import EMPTY_PIXEL
from ...errors import SettingsError
from ..colors import _cache, normals_of

AMBIENT, DIFFUSE, SPECULAR = 0.3, 0.7, 0.25


@functools.lru_cache(maxsize=4)
def view_directions(camera) -> np.ndarray:
    """(H*W, 3) float32 unit vectors from each pixel's centre towards the eye ((1, 3) if orthographic)."""
    right, up, back = camera.basis()
    if camera.projection != "perspective":
        return back.astype(np.float32)[None, :]
    t = np.tan(np.radians(camera.fov) / 2)
    nx = ((np.arange(camera.width) + 0.5) / camera.width * 2 - 1) * t * camera.aspect
    ny = (1 - (np.arange(camera.height) + 0.5) / camera.height * 2) * t
    d = back[None, None, :] - nx[None, :, None] * right[None, None, :] - ny[:, None, None] * up[None, None, :]
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return d.reshape(-1, 3).astype(np.float32)


def _normals(cloud) -> np.ndarray:
    cache = _cache(cloud)
    n = cache.get("__normals__")
    if n is None:
        n = normals_of(cloud)
        if n is None:
            raise SettingsError(
                f"lighting: {cloud.name} has no normals (attributes nx, ny, nz); estimate them with gigapoint.render.normals.estimate_normals(cloud)"
            )
        n = np.ascontiguousarray(n, np.float32)
        cache["__normals__"] = n
    return n


def shade(cloud, camera, vis, colors, shininess=32.0) -> np.ndarray:
    out = np.empty_like(colors)
    kernels.blinn_phong(np.ascontiguousarray(vis).reshape(-1), _normals(cloud), np.ascontiguousarray(colors).reshape(-1), view_directions(camera),
                        np.float32(AMBIENT), np.float32(DIFFUSE), np.float32(SPECULAR), np.float32(shininess), out)  # fmt: skip
    return out


def shade_reference(cloud, camera, vis, colors, shininess=32.0) -> np.ndarray:
    vis = vis.reshape(-1)
    hit = vis != EMPTY_PIXEL
    n = _normals(cloud)[(vis[hit] & np.uint64(0xFFFFFFFF)).astype(np.int64)]
    v = view_directions(camera)
    v = v if len(v) == 1 else v[hit]
    ndv = np.minimum(np.abs(n[:, 0] * v[:, 0] + n[:, 1] * v[:, 1] + n[:, 2] * v[:, 2]), np.float32(1))
    lit = np.float32(AMBIENT) + np.float32(DIFFUSE) * ndv
    spec = np.float32(SPECULAR) * ndv ** np.float32(shininess) * np.float32(255)
    rgba = colors.reshape(-1).view(np.uint8).reshape(-1, 4).copy()
    c = rgba[hit, :3].astype(np.float32) * lit[:, None] + spec[:, None] + np.float32(0.5)
    rgba[hit, :3] = np.clip(c, 0, 255).astype(np.uint8)
    return rgba.view(np.uint32).reshape(-1)
