"""The image-quality passes on the GPU (wgpu backend) against the CPU passes.

Splats (point size / shape) in both rasterize paths (64-bit atomicMin and the two-pass
fallback), HQS, hole filling, eye-dome lighting and Blinn-Phong lighting, each on the same
input as the CPU pass. Rules: the visibility buffer may differ where float rounding on a GPU
moves a point across a pixel edge (<= 0.1 % of pixels, as in test_wgpu_backend.py); the
integer passes (hole filling, HQS, resolve) must then be identical on the same input; the
float passes (EDL, lighting) may differ by one unit in a channel on <= 0.1 % of pixels
(GPUs may fuse multiply-adds or use their own pow). On Mesa lavapipe everything is exact.
"""

from __future__ import annotations

import numpy as np
import pytest
from wgpu_support import any_gpu, cpu, gpu, gpu32, wgpu_or_skip  # noqa: F401 - fixtures

import gigapoint
from gigapoint import Camera, RenderSettings
from gigapoint.backends.numba_cpu import NumbaCpuBackend
from gigapoint.backends.numba_cpu.passes import eye_dome_lighting, fill_holes, hqs_colors, shade
from gigapoint.backends.wgpu.context import DeviceArray, GpuContext
from gigapoint.core.layout import BATCH_SIZE, EMPTY_PIXEL
from gigapoint.core.selection import Selection, select
from gigapoint.errors import BackendUnavailableError
from gigapoint.render.passes.hqs import hqs_reference
from gigapoint.render.passes.lighting import point_normals
from gigapoint.render.splats import point_sizes, splat_params

pytestmark = pytest.mark.gpu

MAX_DIFF_FRACTION = 0.001
BG = (10, 20, 30, 255)


@pytest.fixture(scope="module")
def scene():
    cloud = gigapoint.demo(60_000, scale=None)
    from gigapoint.render.normals import estimate_normals

    estimate_normals(cloud, k=8)
    return cloud


def _cameras(cloud) -> dict[str, Camera]:
    lo, hi = cloud.bounds
    c = (lo + hi) / 2
    return {
        "iso": Camera.fit(cloud.bounds, width=200, height=150),
        # low over the middle: 10-, 20- and 30-bit batches, a wide range of depths
        "closeup": Camera.look_at((c[0] - 150, c[1] - 150, 60.0), (c[0], c[1], 0.0), fov=60, width=160, height=120),
        "ortho": Camera.fit(cloud.bounds, view="front", width=180, height=120, projection="orthographic"),
    }


def _frame(cloud, cam):
    near, far = cam.clip_range(cloud.bounds)
    sel = select(cloud.batches, cam.screen_rows(), cam.width, cam.height, near, far, 500.0, True)
    return sel, (cam.width, cam.height, near, far)


def _n_differ(a, b) -> int:
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.dtype == b.dtype
    return int(np.count_nonzero(a != b))


def _assert_vis_close(got, want):
    n = _n_differ(got, want)
    assert n <= MAX_DIFF_FRACTION * want.size, f"{n} of {want.size} pixels differ"
    assert np.count_nonzero(want != EMPTY_PIXEL) > 0


def _assert_colors_close(got, want, max_step: int = 1):
    """Equal except <= 0.1 % of pixels off by at most ``max_step`` in a channel."""
    got = np.asarray(got)
    assert got.dtype == np.uint32 and got.shape == want.shape
    d = np.abs(got.view(np.uint8).astype(int) - want.view(np.uint8).astype(int)).reshape(-1, 4)
    n = int(np.count_nonzero(d.max(axis=1)))
    assert n <= MAX_DIFF_FRACTION * len(want), f"{n} of {len(want)} pixels differ"
    assert d.max(initial=0) <= max_step


def _attenuated(cloud, cam, size=6, shape="round"):
    """Attenuated settings whose sizes span 1..size over the scene (so the clamp and the
    per-point size both matter); orthographic cameras get one size, ~3 px."""
    if cam.projection != "perspective":
        return RenderSettings(
            point_size=size, point_shape=shape, size_mode="attenuated", point_world_size=3.0 * cam.ortho_height / cam.height
        )
    depth = np.linalg.norm(cloud.positions() - np.asarray(cam.eye), axis=1).astype(np.float32)
    unit = RenderSettings(point_size=size, size_mode="attenuated", point_world_size=1.0)
    world = 3.0 * float(np.median(depth)) / float(splat_params(unit, cam)[2])  # ~3 px at the median depth
    s = RenderSettings(point_size=size, point_shape=shape, size_mode="attenuated", point_world_size=world)
    _, smax, atten = splat_params(s, cam)
    sizes = point_sizes(depth, smax, atten)
    assert sizes.min() < size - 1 and sizes.max() > 2  # neither end clamps everything
    return s


# --- splats in the rasterizer -----------------------------------------------------------------------
SPLATS = {
    "square3": {"point_size": 3},
    "square4": {"point_size": 4},
    "round5": {"point_size": 5, "point_shape": "round"},
    "square2": {"point_size": 2},
}


@pytest.mark.parametrize("view", ["iso", "closeup", "ortho"])
@pytest.mark.parametrize("splat", list(SPLATS) + ["attenuated"])
def test_splats_match_cpu(gpu, gpu32, cpu, scene, view, splat):
    cam = _cameras(scene)[view]
    settings = _attenuated(scene, cam) if splat == "attenuated" else RenderSettings(**SPLATS[splat])
    sp = splat_params(settings, cam)
    sel, args = _frame(scene, cam)
    want = cpu.rasterize(scene, sel, *args, splat=sp)
    got = gpu.rasterize(scene, sel, *args, splat=sp)
    _assert_vis_close(got, want)
    assert _n_differ(gpu32.rasterize(scene, sel, *args, splat=sp), got) == 0  # the fallback equals the 64-bit path
    # splats cover more than one-pixel points do
    assert np.count_nonzero(want != EMPTY_PIXEL) > np.count_nonzero(cpu.rasterize(scene, sel, *args) != EMPTY_PIXEL)


def test_a_near_small_point_beats_a_far_large_one_pixel_by_pixel(any_gpu, cpu):
    """Hand-built: a far point's 5x5 square and a near one's; each footprint pixel takes the nearer key."""
    xyz = np.array([[10.5, 10.5, 0.0], [12.5, 10.5, 5.0], [3.5, 3.5, 1.0]])  # the middle one is nearest the camera
    cloud = gigapoint.from_arrays(xyz, np.full((3, 3), 200, np.uint8))
    cam = Camera.look_at((8.0, 8.0, 50.0), (8.0, 8.0, 0.0), up=(0, 1, 0), width=16, height=16, projection="orthographic", ortho_height=16.0)
    sel, args = _frame(cloud, cam)
    sp = splat_params(RenderSettings(point_size=5), cam)
    want = cpu.rasterize(cloud, sel, *args, splat=sp)
    got = any_gpu.rasterize(cloud, sel, *args, splat=sp)
    assert _n_differ(got, want) == 0
    idx = np.where(got == EMPTY_PIXEL, -1, (got & np.uint64(0xFFFFFFFF)).astype(np.int64))
    pos = cloud.positions()
    near_i, far_i, third = (int(np.argmin(np.abs(pos[:, 2] - z))) for z in (5.0, 0.0, 1.0))
    assert np.count_nonzero(idx == near_i) == 25  # the whole near square
    assert np.count_nonzero(idx == far_i) == 10  # two columns of the far one stick out
    assert np.count_nonzero(idx == third) == 25 and np.count_nonzero(idx >= 0) == 60


def test_render_frame_with_splats_stays_on_wgpu(scene):
    cam = _cameras(scene)["iso"]
    settings = {"point_size": 4, "point_shape": "round"}
    try:
        frame = gigapoint.render_frame(scene, cam, RenderSettings(backend="wgpu", **settings))
    except BackendUnavailableError as exc:
        pytest.skip(str(exc))
    ref = gigapoint.render_frame(scene, cam, RenderSettings(backend="cpu", **settings))
    assert frame.stats.backend == "wgpu"
    _assert_vis_close(frame.visibility.reshape(-1), ref.visibility.reshape(-1))


# --- HQS ----------------------------------------------------------------------------------------
HQS_CASES = {
    "one-pixel": ({}, 0.01),
    "wide-tolerance": ({}, 0.2),
    "square3": ({"point_size": 3}, 0.01),
    "round5-soft": ({"point_size": 5, "point_shape": "round", "splat_softness": 2.0}, 0.05),
    "attenuated": ("attenuated", 0.01),
    "attenuated-soft": ("attenuated-soft", 0.05),
}


@pytest.mark.parametrize("case", list(HQS_CASES))
def test_hqs_matches_cpu(any_gpu, scene, case):
    """On the GPU's own depth pass (64-bit or fallback), the GPU HQS equals the CPU HQS."""
    cam = _cameras(scene)["closeup"]
    kw, tol = HQS_CASES[case]
    if isinstance(kw, str):
        s = _attenuated(scene, cam, 6)
        kw = {"point_size": 6, "point_shape": "round", "size_mode": "attenuated", "point_world_size": s.point_world_size}
        if case.endswith("soft"):
            kw["splat_softness"] = 1.5
    settings = RenderSettings(hqs=True, **kw)
    sp = splat_params(settings, cam) if settings.point_size > 1 else None
    sel, (w, h, near, far) = _frame(scene, cam)
    vis = np.asarray(any_gpu.rasterize(scene, sel, w, h, near, far, splat=sp))
    fallback = NumbaCpuBackend().resolve(vis, scene.color, BG)
    want = hqs_colors(scene, sel, vis, w, h, near, far, scene.color, fallback, tol, None, sp, settings.splat_softness)
    got = any_gpu.passes.hqs_colors(scene, sel, vis, w, h, near, far, scene.color, fallback, tol, None, sp, settings.splat_softness)
    assert isinstance(got, DeviceArray)
    if case == "attenuated-soft":  # per-point soft weights in float32 on the GPU (float64 on the CPU)
        _assert_colors_close(got, want, max_step=255)  # a weight off by one moves a mean by any amount, on rare pixels
    else:
        assert _n_differ(got, want) == 0
    assert np.count_nonzero(want != fallback) > 0.05 * np.count_nonzero(vis != EMPTY_PIXEL)  # blending happened


def test_hqs_under_a_point_cap_blends_only_the_points_drawn_like_the_cpu(any_gpu, scene):
    """step=3 (max_points): the GPU's HQS blends every third point, as its depth pass drew them."""
    cam = _cameras(scene)["closeup"]
    sel, (w, h, near, far) = _frame(scene, cam)
    vis = np.asarray(any_gpu.rasterize(scene, sel, w, h, near, far, step=3))
    fallback = NumbaCpuBackend().resolve(vis, scene.color, BG)
    want = hqs_colors(scene, sel, vis, w, h, near, far, scene.color, fallback, 0.05, step=3)
    assert _n_differ(np.asarray(any_gpu.passes.hqs_colors(scene, sel, vis, w, h, near, far, scene.color, fallback, 0.05, step=3)), want) == 0
    assert _n_differ(hqs_colors(scene, sel, vis, w, h, near, far, scene.color, fallback, 0.05), want) > 100  # all points blend otherwise


def test_hqs_means_round_half_up_like_the_reference(any_gpu):
    """Stacks of points on one pixel: means of 0.5 and 0.75 round up; alpha too."""
    xyz = np.array([[1.5, 1.5, 0.0]] * 2 + [[5.5, 2.5, 0.0]] * 4 + [[2.5, 5.5, 0.0]])
    rgba = np.array([[0, 0, 0, 255], [1, 3, 5, 254], [0, 0, 0, 0], [1, 1, 1, 1], [1, 1, 1, 1], [1, 2, 1, 1], [9, 9, 9, 9]], np.uint8)
    cloud = gigapoint.from_arrays(xyz, rgba)
    cam = Camera.look_at((4.0, 4.0, 30.0), (4.0, 4.0, 0.0), up=(0, 1, 0), width=8, height=8, projection="orthographic", ortho_height=8.0)
    sel, (w, h, near, far) = _frame(cloud, cam)
    vis = np.asarray(any_gpu.rasterize(cloud, sel, w, h, near, far))
    fallback = np.full(w * h, 7, np.uint32)
    want = hqs_reference(cloud, sel, vis, w, h, near, far, cloud.color, fallback)
    got = np.asarray(any_gpu.passes.hqs_colors(cloud, sel, vis, w, h, near, far, cloud.color, fallback))
    assert _n_differ(got, want) == 0
    means = sorted(tuple(c) for c in got[got != 7].view(np.uint8).reshape(-1, 4).tolist())
    # (0+1)/2 -> 1, (0+3)/2 -> 2, (255+254)/2 -> 255; (0+1+1+1)/4 -> 1, (0+1+1+2)/4 -> 1
    assert means == sorted([(1, 2, 3, 255), (1, 1, 1, 1), (9, 9, 9, 9)])


def test_hqs_with_paged_colors(cpu, scene):
    """Point words and colors in pages of 2 batches: the accumulate reads each page's colors."""
    paged = wgpu_or_skip(page_bytes=BATCH_SIZE * 4 * 2)
    cam = _cameras(scene)["iso"]
    sel, (w, h, near, far) = _frame(scene, cam)
    assert paged.ctx.plan(scene).n_pages > 2
    vis = cpu.rasterize(scene, sel, w, h, near, far)
    fallback = cpu.resolve(vis, scene.color, BG)
    want = hqs_colors(scene, sel, vis, w, h, near, far, scene.color, fallback, 0.05)
    assert (
        _n_differ(paged.passes.hqs_colors(scene, sel, vis, w, h, near, far, scene.color, fallback, 0.05), want) <= MAX_DIFF_FRACTION * w * h
    )


def test_hqs_of_an_empty_selection_is_the_fallback(gpu, scene):
    sel, (w, h, near, far) = _frame(scene, _cameras(scene)["iso"])
    none = Selection(sel.ids[:0], sel.bits[:0], sel.matrices[:0], sel.projected_px[:0], len(scene.batches))
    vis = np.full(w * h, EMPTY_PIXEL)
    fallback = np.arange(w * h, dtype=np.uint32)
    assert _n_differ(gpu.passes.hqs_colors(scene, none, vis, w, h, near, far, scene.color, fallback), fallback) == 0


# --- hole filling -------------------------------------------------------------------------------
@pytest.mark.parametrize("level", [1, 2, 3])
@pytest.mark.parametrize("foveated", [False, True])
def test_fill_holes_matches_cpu(any_gpu, scene, level, foveated):
    """On the GPU's own sparse depth pass: the same filled buffer, bit for bit."""
    cam = Camera.fit(scene.bounds, width=320, height=240)  # sparse: many holes
    sel, (w, h, near, far) = _frame(scene, cam)
    vis = np.asarray(any_gpu.rasterize(scene, sel, w, h, near, far))
    want = fill_holes(vis, w, h, level, foveated)
    got = any_gpu.passes.fill_holes(vis, w, h, level, foveated)
    assert isinstance(got, DeviceArray) and got.dtype == np.uint64
    assert _n_differ(got, want) == 0
    assert np.count_nonzero(want != vis) > 100  # it filled something


def test_fill_holes_level_0_is_the_input(gpu):
    vis = np.full(12, EMPTY_PIXEL)
    assert gpu.passes.fill_holes(vis, 4, 3, 0) is vis


# --- eye-dome lighting --------------------------------------------------------------------------
@pytest.mark.parametrize("strength, radius", [(1.0, 1.4), (0.3, 2.0), (2.0, 4.0)])
def test_edl_matches_cpu(any_gpu, cpu, scene, strength, radius):
    cam = _cameras(scene)["closeup"]
    sel, (w, h, near, far) = _frame(scene, cam)
    vis = np.asarray(any_gpu.rasterize(scene, sel, w, h, near, far))
    colors = cpu.resolve(vis, scene.color, BG)
    want = eye_dome_lighting(vis, colors, w, h, strength, radius)
    got = any_gpu.passes.eye_dome_lighting(vis, colors, w, h, strength, radius)
    _assert_colors_close(got, want)
    assert np.count_nonzero(want != colors) > 0.1 * w * h  # it shaded


# --- lighting -----------------------------------------------------------------------------------
@pytest.mark.parametrize("view", ["iso", "ortho"])
@pytest.mark.parametrize("shininess", [32.0, 0.0, 5.5])
def test_lighting_matches_cpu(any_gpu, cpu, scene, view, shininess):
    cam = _cameras(scene)[view]
    sel, (w, h, near, far) = _frame(scene, cam)
    vis = np.asarray(any_gpu.rasterize(scene, sel, w, h, near, far))
    colors = cpu.resolve(vis, scene.color, BG)
    want = shade(vis, colors, point_normals(scene), cam, shininess)
    got = any_gpu.passes.shade(vis, colors, point_normals(scene), cam, shininess)
    _assert_colors_close(got, want)
    assert np.count_nonzero(want != colors) > 0.5 * np.count_nonzero(vis != EMPTY_PIXEL)


def test_lighting_with_paged_normals(cpu, scene):
    paged = wgpu_or_skip(page_bytes=BATCH_SIZE * 4 * 2)
    cam = _cameras(scene)["iso"]
    sel, (w, h, near, far) = _frame(scene, cam)
    vis = cpu.rasterize(scene, sel, w, h, near, far)
    colors = cpu.resolve(vis, scene.color, BG)
    normals = point_normals(scene)
    _assert_colors_close(paged.passes.shade(vis, colors, normals, cam), shade(vis, colors, normals, cam))


# --- the frame pipeline -------------------------------------------------------------------------
PIPELINES = {
    "all": {"fill_holes": 2, "hqs": True, "lighting": True, "edl": True},
    "splats": {
        "point_size": 4,
        "point_shape": "round",
        "hqs": True,
        "splat_softness": 1.5,
        "fill_holes": 1,
        "fill_holes_foveated": True,
        "edl": True,
    },
    "attenuated": {"point_size": 5, "size_mode": "attenuated", "point_world_size": 0.4, "hqs": True, "edl": True},
    "supersampled": {"supersample": 2, "edl": True, "fill_holes": 1},
}


@pytest.mark.parametrize("case", list(PIPELINES))
def test_render_frame_on_wgpu_equals_cpu(gpu, scene, case):
    cam = _cameras(scene)["iso"]
    try:
        frame = gigapoint.render_frame(scene, cam, RenderSettings(backend="wgpu", **{"size_mode": "fixed", **PIPELINES[case]}))  # the exact one-pixel render
    except BackendUnavailableError as exc:
        pytest.skip(str(exc))
    ref = gigapoint.render_frame(scene, cam, RenderSettings(backend="cpu", **{"size_mode": "fixed", **PIPELINES[case]}))
    assert frame.stats.backend == "wgpu"
    assert isinstance(frame.visibility, np.ndarray) and frame.visibility.dtype == np.uint64
    _assert_vis_close(frame.visibility.reshape(-1), ref.visibility.reshape(-1))
    n_vis = _n_differ(frame.visibility, ref.visibility)
    n_img = int(np.count_nonzero(np.any(frame.image != ref.image, axis=-1)))
    assert n_img <= MAX_DIFF_FRACTION * frame.image.shape[0] * frame.image.shape[1] + 25 * n_vis


def test_a_frame_reads_each_buffer_back_once(monkeypatch, scene):
    """Raster, fill, HQS, lighting, EDL: the visibility buffer and the image come back once each."""
    try:
        from gigapoint.backends import get_backend

        backend = get_backend("wgpu")
    except BackendUnavailableError as exc:
        pytest.skip(str(exc))
    cam = _cameras(scene)["iso"]
    n_pixels = cam.width * cam.height
    reads = []
    real = GpuContext.read_back

    def counting(self, buffer, dtype, n):
        reads.append((np.dtype(dtype), n))
        return real(self, buffer, dtype, n)

    uploads = []
    real_write = backend.device.queue.write_buffer

    def counting_write(buffer, offset, data, *args):
        uploads.append(np.asarray(data).nbytes)
        return real_write(buffer, offset, data, *args)

    monkeypatch.setattr(GpuContext, "read_back", counting)
    monkeypatch.setattr(backend.device.queue, "write_buffer", counting_write)
    gigapoint.render_frame(scene, cam, RenderSettings(backend="wgpu", **PIPELINES["all"]))
    big = [r for r in reads if r[1] >= n_pixels]
    assert sorted(big) == sorted([(np.dtype(np.uint64), n_pixels), (np.dtype(np.uint32), n_pixels)])
    assert max(uploads) < 4 * n_pixels  # no frame-sized upload between passes


def test_results_survive_the_reuse_of_their_buffer(gpu, cpu, scene):
    """A pass result still held when its buffer is written again is read back first."""
    cam = _cameras(scene)["closeup"]
    sel, (w, h, near, far) = _frame(scene, cam)
    vis = gpu.rasterize(scene, sel, w, h, near, far)
    first, _ = gpu.passes.resolve(vis, scene.color, BG)
    lit = gpu.passes.eye_dome_lighting(vis, first, w, h)  # into the other image buffer
    again = gpu.passes.eye_dome_lighting(vis, lit, w, h)  # back into first's buffer
    want = cpu.resolve(vis, scene.color, BG)
    assert _n_differ(first, want) == 0
    want_lit = eye_dome_lighting(vis, want, w, h)
    # EDL's logarithm divides: a GPU's float32 division need not round as the CPU's (Vulkan
    # allows 2.5 ulps), so a rare channel is one off, as in the EDL tests; a result overwritten
    # before it was read back would be another image
    _assert_colors_close(lit, want_lit)
    _assert_colors_close(again, eye_dome_lighting(vis, want_lit, w, h))
    assert _n_differ(first, again) > 0.5 * np.count_nonzero(vis != EMPTY_PIXEL)
    # and a DeviceArray from rasterize is a visibility buffer like any other
    dev = gpu.rasterize(scene, sel, w, h, near, far, keep_on_device=True)
    assert isinstance(dev, DeviceArray) and _n_differ(dev, vis) == 0


# --- point budget ---------------------------------------------------------------------------------
@pytest.mark.parametrize("step", [2, 7])
def test_every_step_th_point_like_the_cpu(any_gpu, cpu, scene, step):
    """rasterize(step=k) draws points first, first + k, ... of each batch, as the CPU backend does."""
    cam = _cameras(scene)["iso"]
    sel, args = _frame(scene, cam)
    sp = splat_params(RenderSettings(point_size=3), cam)
    for splat in (None, sp):
        want = cpu.rasterize(scene, sel, *args, splat=splat, step=step)
        got = any_gpu.rasterize(scene, sel, *args, splat=splat, step=step)
        _assert_vis_close(got, want)
        idx = (got[got != EMPTY_PIXEL] & np.uint64(0xFFFFFFFF)).astype(np.int64)
        firsts = scene.batches["first"].astype(np.int64)
        batch = np.searchsorted(firsts, idx, side="right") - 1
        assert np.all((idx - firsts[batch]) % step == 0)


def test_hqs_falls_back_to_the_cpu_pass_on_adapters_binding_8_storage_buffers(cpu, scene):
    """WebGPU guarantees 8 storage buffers a stage; HQS needs 9 and otherwise runs on the CPU."""
    small = wgpu_or_skip()
    small.ctx.hqs_on_gpu = False
    cam = _cameras(scene)["iso"]
    sel, (w, h, near, far) = _frame(scene, cam)
    vis = small.rasterize(scene, sel, w, h, near, far, keep_on_device=True)
    fallback, _ = small.passes.resolve(vis, scene.color, BG)
    got = small.passes.hqs_colors(scene, sel, vis, w, h, near, far, scene.color, fallback, 0.05)
    assert isinstance(got, np.ndarray)
    host_vis = np.asarray(vis)
    want = hqs_colors(scene, sel, host_vis, w, h, near, far, scene.color, cpu.resolve(host_vis, scene.color, BG), 0.05)
    assert _n_differ(got, want) == 0


def test_resolve_takes_a_2d_buffer(gpu, cpu):
    vis = np.full((3, 5), EMPTY_PIXEL)
    vis[1, 2] = np.uint64(7 << 32 | 1)
    color = np.array([11, 22], np.uint32)
    assert _n_differ(gpu.resolve(vis, color, BG), cpu.resolve(vis.reshape(-1), color, BG)) == 0


def test_shader_constants_are_the_cpu_kernels_float32_bits():
    """EDL's log2 / exp2 series: the generated WGSL literals parse back to the CPU's float32 values."""
    import re

    from gigapoint.backends.wgpu.shaders import shader_source
    from gigapoint.render import params as cpu_kernels  # the constants the CPU kernels use

    found = dict(re.findall(r"^const (\w+): f32 = (\S+);$", shader_source("log_depth"), re.MULTILINE))
    want = {f"LOG2_C{k}": getattr(cpu_kernels, f"LOG2_C{k}") for k in (1, 3, 5, 7)}
    want.update({f"EXP2_C{k + 1}": c for k, c in enumerate(cpu_kernels.EXP2_C)})
    want["EDL_EMPTY_RESPONSE"] = cpu_kernels.EDL_EMPTY_RESPONSE
    assert set(found) == set(want)
    for name, value in want.items():
        assert np.float32(float(found[name])).view(np.uint32) == np.float32(value).view(np.uint32), name


def test_a_buffer_of_the_wrong_size_is_refused(gpu):
    from gigapoint.errors import GigapointError

    with pytest.raises(GigapointError, match="needs 12 values"):
        gpu.passes.eye_dome_lighting(np.full(10, EMPTY_PIXEL), np.zeros(12, np.uint32), 4, 3)
    vis = gpu.passes.fill_holes(np.full(12, EMPTY_PIXEL), 4, 3, 1)
    with pytest.raises(GigapointError, match="needs 20 values of uint64"):
        gpu.passes.fill_holes(vis, 5, 4, 1)


def test_hqs_of_a_frame_whose_sums_exceed_one_binding_is_the_cpus(gpu, cpu):
    """HQS sums 20 bytes a pixel: past one binding (lavapipe's 128 MiB: 2592 x 2592) the CPU pass
    draws it, not a GPUValidationError."""
    side = int(np.sqrt(gpu.max_binding / 20)) + 2
    if side * side * 8 > gpu.max_binding:
        pytest.skip("the visibility buffer does not fit one binding either")
    cloud = gigapoint.demo(5_000, scale=None)
    cam = Camera.fit(cloud.bounds, width=side, height=side)
    frames = {b.name: gigapoint.render_frame(cloud, cam, RenderSettings(hqs=True, point_size=2), backend=b.name) for b in (gpu, cpu)}
    assert np.count_nonzero(frames["cpu"].visibility != EMPTY_PIXEL) > 5_000
    assert np.array_equal(frames["wgpu"].image, frames["cpu"].image)


def test_passes_draw_the_visibility_buffer_as_its_holder_changed_it(gpu, cpu, scene):
    """rasterize's numpy buffer, changed in place, is what the passes read (they used the GPU's
    copy of the unchanged buffer: cleared pixels still showed their points)."""
    cam = _cameras(scene)["iso"]
    sel, (w, h, near, far) = _frame(scene, cam)
    vis = gpu.rasterize(scene, sel, w, h, near, far)
    vis[: len(vis) // 2] = EMPTY_PIXEL  # the top half cleared
    assert np.count_nonzero(vis != EMPTY_PIXEL) > 1000
    want = cpu.resolve(vis, scene.color, BG)
    assert _n_differ(gpu.resolve(vis, scene.color, BG), want) == 0
    _assert_colors_close(gpu.passes.eye_dome_lighting(vis, want, w, h), eye_dome_lighting(vis, want, w, h))
