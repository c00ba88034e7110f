"""The wgpu backend against the CPU backend (Mesa lavapipe counts as an adapter).

The CPU backend is the reference: the GPU must produce its visibility buffer, except
where float rounding on a GPU moves a point across a pixel edge (at most 0.1 % of pixels;
on lavapipe the buffers are identical).
"""

from __future__ import annotations

import gc

import numpy as np
import pytest
from wgpu_support import cpu, gpu, gpu32, wgpu_or_skip  # noqa: F401 - fixtures

import gigapoint
from gigapoint import Camera, RenderSettings
from gigapoint.backends.wgpu import WgpuBackend
from gigapoint.bench import comparison_cameras
from gigapoint.core.cloud import cloud_from_points
from gigapoint.core.layout import BATCH_SIZE, EMPTY_PIXEL
from gigapoint.core.selection import Selection, select
from gigapoint.errors import BackendUnavailableError, GigapointError
from gigapoint.render.reference import reference_visibility

pytestmark = pytest.mark.gpu

MAX_DIFF_FRACTION = 0.001
_LOW32 = np.uint64(0xFFFFFFFF)


@pytest.fixture(scope="module")
def scene():
    return gigapoint.demo(200_000, scale=None)


def _frame(cloud, cam, threshold_px=500.0, adaptive=True):
    near, far = cam.clip_range(cloud.bounds)
    sel = select(cloud.batches, cam.screen_rows(), cam.width, cam.height, near, far, threshold_px, adaptive)
    return sel, (cam.width, cam.height, near, far)


def _n_differ(a, b) -> int:
    assert a.shape == b.shape and a.dtype == b.dtype == np.uint64
    return int(np.count_nonzero(a != b))


def _assert_close(gpu_vis, cpu_vis):
    """Equal except a few pixels where rounding moved a point across a pixel edge."""
    n = _n_differ(gpu_vis, cpu_vis)
    assert n <= MAX_DIFF_FRACTION * cpu_vis.size, f"{n} of {cpu_vis.size} pixels differ"
    assert np.count_nonzero(cpu_vis != EMPTY_PIXEL) > 0


# --- the visibility buffer ------------------------------------------------------------------------
@pytest.mark.parametrize("view", ["iso", "top", "inside", "closeup", "ortho"])
def test_demo_scene_matches_cpu_from_each_camera(gpu, gpu32, cpu, scene, view):
    cam = comparison_cameras(scene)[view]
    sel, args = _frame(scene, cam)
    want = cpu.rasterize(scene, sel, *args)
    got = gpu.rasterize(scene, sel, *args)
    assert got.shape == (cam.width * cam.height,) and got.dtype == np.uint64
    _assert_close(got, want)
    # the two-pass 32-bit fallback gives exactly the 64-bit result
    assert _n_differ(gpu32.rasterize(scene, sel, *args), got) == 0


def test_cameras_cover_every_precision(scene):
    bits = set()
    for cam in comparison_cameras(scene).values():
        bits |= set(_frame(scene, cam)[0].bits.tolist())
    assert bits == {10, 20, 30}


@pytest.mark.parametrize("threshold_px, bits", [(1e9, 10), (1.0, 20), (1e-9, 30)])
def test_each_precision_on_every_batch(gpu, cpu, scene, threshold_px, bits):
    """A threshold forcing one precision on all batches exercises each decoder alone."""
    cam = comparison_cameras(scene)["iso"]
    sel, args = _frame(scene, cam, threshold_px)
    assert set(sel.bits.tolist()) == {bits}
    _assert_close(gpu.rasterize(scene, sel, *args), cpu.rasterize(scene, sel, *args))


def test_tiny_grid_matches_the_numpy_reference(gpu, gpu32, cpu):
    """A 4x4 grid seen from above: one point per pixel, at a known pixel."""
    xs, ys = np.meshgrid(np.arange(4.0), np.arange(4.0))
    xyz = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(16)])  # degenerate z axis
    cloud = gigapoint.from_arrays(xyz, np.full((16, 3), 200, np.uint8))
    cam = Camera.look_at((1.5, 1.5, 10.0), (1.5, 1.5, 0.0), up=(0, 1, 0), fov=30, width=16, height=16)
    sel, args = _frame(cloud, cam)
    ref = reference_visibility(cloud, cam, RenderSettings(size_mode="fixed")).reshape(-1)  # one-pixel points, as rasterize draws
    for backend in (cpu, gpu, gpu32):
        assert _n_differ(backend.rasterize(cloud, sel, *args), ref) == 0
    hit = ref != EMPTY_PIXEL
    assert hit.sum() == 16 and sorted((ref[hit] & _LOW32).tolist()) == list(range(16))


def test_duplicate_points_go_to_the_lowest_index(gpu, gpu32):
    rng = np.random.default_rng(3)
    base = rng.uniform(0, 10, (50, 3))
    xyz = np.concatenate([base, base, base])  # every position three times
    cloud = gigapoint.from_arrays(xyz)
    cam = Camera.fit(cloud.bounds, width=64, height=48)
    sel, args = _frame(cloud, cam)
    pos = cloud.positions()
    for backend in (gpu, gpu32):
        vis = backend.rasterize(cloud, sel, *args)
        winners = (vis[vis != EMPTY_PIXEL] & _LOW32).astype(np.int64)
        assert len(winners) > 10
        for w in winners.tolist():
            same = np.flatnonzero(np.all(pos == pos[w], axis=1))
            assert len(same) >= 3 and w == same.min()


def test_points_behind_and_beside_the_camera_are_dropped(gpu, cpu):
    xyz = np.array([[0, 0, 5], [0, 0, -5], [100, 0, 5], [0.5, 0.2, 3], [0, 0, 1e-7]], float)
    cloud = gigapoint.from_arrays(xyz)
    cam = Camera.look_at((0, 0, 0), (0, 0, 10), up=(0, 1, 0), fov=40, width=32, height=32, near=0.01, far=50)
    sel, args = _frame(cloud, cam)
    want = cpu.rasterize(cloud, sel, *args)
    assert _n_differ(gpu.rasterize(cloud, sel, *args), want) == 0
    assert 1 <= np.count_nonzero(want != EMPTY_PIXEL) <= 2


def test_more_batches_than_one_dispatch_dimension(gpu, cpu):
    """70 000 one-point batches: the dispatch goes 2D past 65 535 workgroups."""
    rng = np.random.default_rng(7)
    n = 70_000
    xyz = rng.uniform(0, 100, (n, 3))
    cloud = cloud_from_points(xyz, np.full((n, 4), 255, np.uint8), batch_size=1)
    cam = Camera.fit(cloud.bounds, width=200, height=150)
    sel, args = _frame(cloud, cam)
    assert len(sel.ids) > 65_535
    _assert_close(gpu.rasterize(cloud, sel, *args), cpu.rasterize(cloud, sel, *args))


def test_empty_selection_gives_an_empty_buffer(gpu, scene):
    sel, args = _frame(scene, comparison_cameras(scene)["iso"])
    none = Selection(sel.ids[:0], sel.bits[:0], sel.matrices[:0], sel.projected_px[:0], len(scene.batches))
    vis = gpu.rasterize(scene, none, *args)
    assert np.all(vis == EMPTY_PIXEL)


def test_frame_beyond_one_binding_is_refused(gpu, scene):
    sel, (_, _, near, far) = _frame(scene, comparison_cameras(scene)["iso"])
    side = int(np.sqrt(gpu.max_binding / 8)) + 2
    with pytest.raises(GigapointError, match="visibility buffer"):
        gpu.rasterize(scene, sel, side, side, near, far)


# --- pages and memory ---------------------------------------------------------------------------
def test_a_big_frames_buffers_are_freed_by_the_small_frames_after_it(gpu, cpu, scene):
    """A 3000 x 3000 frame's 72 MB visibility buffer was held through every small frame after it;
    its result, still on the GPU, reads back whole after they free it."""
    sel, (_, _, near, far) = _frame(scene, comparison_cameras(scene)["iso"])
    big = gpu.rasterize(scene, sel, 3000, 3000, near, far, keep_on_device=True)
    held = gpu.memory["frame_buffers"]  # (and what earlier tests left)
    assert held > 70e6
    small_sel, small = _frame(scene, comparison_cameras(scene)["top"])
    _assert_close(gpu.rasterize(scene, small_sel, *small), cpu.rasterize(scene, small_sel, *small))
    assert gpu.memory["frame_buffers"] < held - 70e6
    _assert_close(np.asarray(big), cpu.rasterize(scene, sel, 3000, 3000, near, far))


def test_paging_gives_the_same_buffer(gpu, scene):
    """Pages of 3 batches and a budget of 4 page-words: 7 pages, evictions every frame."""
    page = 3 * BATCH_SIZE * 4
    paged = wgpu_or_skip(page_bytes=page, memory_budget=4 * page)
    assert paged.page_points == 3 * BATCH_SIZE
    for view in ("iso", "inside"):
        cam = comparison_cameras(scene)[view]
        sel, args = _frame(scene, cam, threshold_px=1e-9 if view == "iso" else 500.0)
        assert _n_differ(paged.rasterize(scene, sel, *args), gpu.rasterize(scene, sel, *args)) == 0
    mem = paged.memory
    assert mem["evictions"] > 0
    assert mem["points_resident"] <= mem["budget"]
    assert paged.ctx.plan(scene).n_pages == 7


def test_paging_with_ragged_batches(cpu):
    """Batches of 1001 points: page starts and batch starts not multiples of 4 (no prefetch)."""
    xyz, rgba, _ = gigapoint.demo_arrays(30_000)
    cloud = cloud_from_points(xyz, rgba, batch_size=1001)
    paged = wgpu_or_skip(page_bytes=5 * 1001 * 4 + 16, atomics64=False)
    cam = Camera.fit(cloud.bounds, width=160, height=120)
    sel, args = _frame(cloud, cam)
    assert paged.ctx.plan(cloud).n_pages == 6
    assert _n_differ(paged.rasterize(cloud, sel, *args), cpu.rasterize(cloud, sel, *args)) <= MAX_DIFF_FRACTION * 160 * 120


def test_a_batch_larger_than_a_page_is_refused(scene):
    small = wgpu_or_skip(page_bytes=BATCH_SIZE * 2)  # 5120 points
    sel, args = _frame(scene, comparison_cameras(scene)["iso"])
    with pytest.raises(GigapointError, match="more than one GPU page"):
        small.rasterize(scene, sel, *args)


def test_second_frame_uploads_nothing_and_dead_clouds_are_freed():
    backend = wgpu_or_skip()
    cloud = gigapoint.demo(30_000, scale=None)
    cam = Camera.fit(cloud.bounds, width=64, height=64)
    sel, args = _frame(cloud, cam, threshold_px=1e-9)  # 30 bits: low, med and high uploaded
    backend.rasterize(cloud, sel, *args)
    uploaded = backend.memory["uploaded"]
    assert uploaded >= 3 * 4 * cloud.n_points
    backend.rasterize(cloud, sel, *args)
    assert backend.memory["uploaded"] == uploaded
    backend.resolve(np.full(16, EMPTY_PIXEL), cloud.color, (0, 0, 0, 255))
    assert backend.memory["points_resident"] >= 4 * 4 * cloud.n_points  # colors too
    other = gigapoint.demo(20_000, scale=None)
    del cloud
    gc.collect()
    sel2, args2 = _frame(other, cam)
    backend.rasterize(other, sel2, *args2)
    assert backend.memory["points_resident"] < 2 * 4 * other.n_points + 64


def test_only_needed_words_are_uploaded(scene):
    backend = wgpu_or_skip()
    sel, args = _frame(scene, comparison_cameras(scene)["iso"], threshold_px=1e9)  # 10 bits everywhere
    backend.rasterize(scene, sel, *args)
    assert backend.memory["uploaded"] == 4 * scene.n_points  # low words only


# --- resolve --------------------------------------------------------------------------------------
def test_resolve_matches_cpu_on_the_same_buffer(gpu, cpu, scene):
    sel, args = _frame(scene, comparison_cameras(scene)["top"])
    vis = cpu.rasterize(scene, sel, *args)
    bg = (10, 20, 30, 255)
    want = cpu.resolve(vis, scene.color, bg)
    assert np.array_equal(gpu.resolve(vis, scene.color, bg), want)
    assert np.count_nonzero(want == np.array(bg, np.uint8).view(np.uint32)[0]) > 0


def test_resolve_with_paged_colors(cpu, scene):
    paged = wgpu_or_skip(page_bytes=BATCH_SIZE * 4 * 2)  # 10 color pages
    sel, args = _frame(scene, comparison_cameras(scene)["top"])
    vis = cpu.rasterize(scene, sel, *args)
    assert np.array_equal(paged.resolve(vis, scene.color, (0, 0, 0, 255)), cpu.resolve(vis, scene.color, (0, 0, 0, 255)))


# --- the facade and the registry ------------------------------------------------------------------
def test_render_frame_with_backend_wgpu(gpu, scene):
    cam = comparison_cameras(scene)["iso"]
    try:
        frame = gigapoint.render_frame(scene, cam, RenderSettings(backend="wgpu", size_mode="fixed"))  # the exact one-pixel render
    except BackendUnavailableError as exc:
        pytest.skip(str(exc))
    ref = gigapoint.render_frame(scene, cam, RenderSettings(backend="cpu", size_mode="fixed"))
    assert frame.stats.backend == "wgpu"
    n = int(np.count_nonzero(frame.visibility != ref.visibility))
    assert n <= MAX_DIFF_FRACTION * ref.visibility.size
    assert np.count_nonzero(np.any(frame.image != ref.image, axis=-1)) <= n


def test_require_hardware_refuses_cpu_adapters(gpu):
    if gpu.info.get("adapter_type") != "CPU":
        pytest.skip("a hardware adapter is present")
    try:
        hw = WgpuBackend(require_hardware=True)
    except BackendUnavailableError as exc:
        assert "no hardware GPU" in str(exc)
    else:  # a hardware adapter exists beside the CPU one we were given
        assert hw.info.get("adapter_type") != "CPU"


def test_describe_names_device_and_path(gpu, gpu32):
    assert "wgpu (" in gpu.describe() and gpu.name == "wgpu"
    assert "two-pass" in gpu32.describe()
