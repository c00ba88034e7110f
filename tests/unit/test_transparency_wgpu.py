"""Transparent points on the GPU (wgpu; Mesa lavapipe in CI) against the CPU pass and the numpy
reference: the composite is integer work, so it must be identical on the same input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from wgpu_support import cpu, gpu, gpu32, wgpu_or_skip  # noqa: F401 - fixtures

import gigapoint as gp
from gigapoint.backends.numba_cpu.passes import transparent_colors
from gigapoint.core.layout import BATCH_SIZE
from gigapoint.render.colors import rgba_point_colors
from gigapoint.render.params import batch_alphas
from gigapoint.render.passes import splat_for
from gigapoint.render.passes.transparency import hybrid_reference

pytestmark = pytest.mark.gpu

BG = (10, 20, 30, 255)


@pytest.fixture(scope="module")
def scene():
    cloud = gp.demo(60_000, seed=2, scale=None)
    cam = gp.Camera.fit(cloud.bounds, view=(-60.0, 35.0), width=120, height=80, fov=40.0)
    return cloud, cam


def _inputs(cloud, cam, settings, fade=None):
    view = cam.view(cloud.bounds)
    draw = cloud.prepare(view, settings)
    sel = draw.selection
    alphas = batch_alphas(fade(sel.ids) if fade else None, settings.opacity, len(sel.ids))
    fallback = (
        np.asarray(gp.render_frame(cloud, cam, settings.replace(opacity=1.0, backend="cpu")).image)
        .reshape(-1, 4)
        .view(np.uint32)
        .reshape(-1)
    )
    splat = splat_for(settings, cam, draw, view.near)
    return sel, view, alphas, fallback.copy(), splat, draw.step


@pytest.mark.parametrize(
    ("options", "fade"),
    [({"size_mode": "fixed"}, None), ({"size_mode": "adaptive"}, None), ({"point_size": 3, "point_shape": "round"}, lambda ids: (ids % 5) / 4.0),
     ({"size_mode": "fixed", "max_points": 20_000}, lambda ids: (ids % 2) * 0.5 + 0.25)],
)  # fmt: skip
def test_gpu_equals_cpu_and_reference(gpu, scene, options, fade):
    if not gpu.ctx.transparency_on_gpu:
        pytest.skip("adapter without 64-bit atomics that return a value: the GPU runs the CPU pass")
    cloud, cam = scene
    s = gp.RenderSettings(opacity=0.55, background=BG, **options)
    sel, view, alphas, fallback, splat, step = _inputs(cloud, cam, s, fade)
    args = (cloud, sel, None, cam.width, cam.height, view.near, view.far, cloud.color, alphas, fallback, BG)
    on_gpu = np.asarray(gpu.passes.transparent_colors(*args, None, splat, step))
    on_cpu = transparent_colors(*args, None, splat, step)
    assert np.array_equal(on_gpu, on_cpu)
    ref = hybrid_reference(cloud, sel, cam.width, cam.height, view.near, view.far, cloud.color, alphas, fallback, BG, splat, step)
    assert np.array_equal(on_cpu, ref)


def test_gpu_pages(scene):
    """Point words and colors over several pages: the gather pass and the alpha lookup per page."""
    paged = wgpu_or_skip(page_bytes=BATCH_SIZE * 4 * 2)
    if not paged.ctx.transparency_on_gpu:
        pytest.skip("adapter without 64-bit atomics that return a value")
    cloud, cam = scene
    s = gp.RenderSettings(opacity=0.4, background=BG, size_mode="adaptive")
    sel, view, alphas, fallback, splat, step = _inputs(cloud, cam, s, lambda ids: 1.0 - (ids % 3) / 3.0)
    args = (cloud, sel, None, cam.width, cam.height, view.near, view.far, cloud.color, alphas, fallback, BG, None, splat, step)
    assert np.array_equal(np.asarray(paged.passes.transparent_colors(*args)), transparent_colors(*args))


def test_two_pass_adapter_falls_back_to_cpu(gpu32, scene):
    cloud, cam = scene
    s = gp.RenderSettings(opacity=0.5, background=BG, size_mode="fixed")
    sel, view, alphas, fallback, splat, step = _inputs(cloud, cam, s)
    args = (cloud, sel, None, cam.width, cam.height, view.near, view.far, cloud.color, alphas, fallback, BG, None, splat, step)
    assert not gpu32.ctx.transparency_on_gpu
    assert np.array_equal(np.asarray(gpu32.passes.transparent_colors(*args)), transparent_colors(*args))


def test_render_on_wgpu(gpu, scene):
    """The whole frame through the renderer with backend 'wgpu' equals the CPU's (lavapipe: exact)."""
    cloud, cam = scene
    s = gp.RenderSettings(opacity=0.5, background=BG, size_mode="fixed")
    a = gp.render(cloud, cam, s.replace(backend="cpu"))
    b = gp.render(cloud, cam, s.replace(backend="wgpu"))
    if "llvmpipe" not in str(gpu.info.get("device", "")):
        assert (a != b).any(axis=2).mean() <= 0.001  # a GPU may move a point across a pixel edge
    else:
        assert np.array_equal(a, b)


def test_gpu_compact_layout(gpu):
    """A compact cloud's words decode in the accumulate pass (common.wgsl) as in the CPU's."""
    if not gpu.ctx.transparency_on_gpu:
        pytest.skip("adapter without 64-bit atomics that return a value")
    path = Path(__file__).parents[2] / ".." / "shared" / "data" / "autzen_trim.laz"
    if not path.exists():
        pytest.skip("shared sample autzen_trim.laz is not here")
    cloud = gp.open(path)
    cam = gp.Camera.fit(cloud.bounds, view=(-60.0, 40.0), width=120, height=80)
    s = gp.RenderSettings(opacity=0.45, background=BG, size_mode="adaptive")
    view = cam.view(cloud.bounds)
    draw = cloud.prepare(view, s)
    colors = rgba_point_colors(cloud, s)
    fallback = np.zeros(cam.width * cam.height, np.uint32)
    alphas = batch_alphas(None, 0.45, len(draw.selection.ids))
    args = (cloud, draw.selection, None, cam.width, cam.height, view.near, view.far, colors, alphas, fallback, BG, None,
            splat_for(s, cam, draw, view.near), draw.step)  # fmt: skip
    assert np.array_equal(np.asarray(gpu.passes.transparent_colors(*args)), transparent_colors(*args))
