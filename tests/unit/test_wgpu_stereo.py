"""Several views in one pass on the wgpu backend (2022 paper, 3.7): ``rasterize_views`` reads
each batch once and writes it into every view's buffer, on the 64-bit path and the two-pass
fallback, and equals the CPU backend's ``rasterize_views`` (<= 0.1 % of pixels, float
rounding at pixel edges; identical on lavapipe). Stereo frames (``render/passes/compose.py``)
take this path on wgpu and equal the CPU's stereo frames."""

from __future__ import annotations

import numpy as np
import pytest
from wgpu_support import any_gpu, cpu, gpu, gpu32, wgpu_or_skip  # noqa: F401 - fixtures

import gigapoint
from gigapoint import Camera, RenderSettings
from gigapoint.backends.wgpu.layout import MAX_VIEWS
from gigapoint.core.layout import EMPTY_PIXEL
from gigapoint.core.selection import select
from gigapoint.errors import BackendUnavailableError, GigapointError
from gigapoint.render.passes.compose import eye_cameras
from gigapoint.render.splats import splat_params

pytestmark = pytest.mark.gpu

MAX_DIFF_FRACTION = 0.001


@pytest.fixture(scope="module")
def scene():
    return gigapoint.demo(80_000)


def _views(cloud, cams, threshold_px=500.0):
    """(ids, bits (V, k), matrices (V, k, 4, 4), nears, fars) as compose.render_views builds them:
    the union of the views' batches, each view's own precision and matrix for every one."""
    w, h = cams[0].width, cams[0].height
    ranges = [cam.clip_range(cloud.bounds) for cam in cams]
    sels = [select(cloud.batches, c.screen_rows(), w, h, n, f, threshold_px, True) for c, (n, f) in zip(cams, ranges)]
    ids = sels[0].ids
    for s in sels[1:]:
        ids = np.union1d(ids, s.ids)
    full = [select(cloud.batches, c.screen_rows(), w, h, n, f, threshold_px, True, False) for c, (n, f) in zip(cams, ranges)]
    bits = np.stack([fs.bits[ids] for fs in full])
    mats = np.stack([fs.matrices[ids] for fs in full])
    return ids, bits, mats, [r[0] for r in ranges], [r[1] for r in ranges]


def _cams(cloud, n=2, width=200, height=150):
    """n views of one size: a stereo pair of a close-up (mixed 10/20/30-bit batches) first,
    then views from elsewhere (the same batches at other precisions)."""
    lo, hi = cloud.bounds
    c = (lo + hi) / 2
    near = Camera.look_at((c[0] - 150, c[1] - 150, 60.0), (c[0], c[1], 0.0), fov=60, width=width, height=height)
    cams = list(eye_cameras(near, 4.0))
    k = 0
    while len(cams) < n:
        a = 2 * np.pi * k / max(1, n - 2)
        cams.append(Camera.look_at((c[0] + 700 * np.cos(a), c[1] + 700 * np.sin(a), 300.0), tuple(c), width=width, height=height))
        k += 1
    return cams[:n]


def _n_differ(a, b) -> int:
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.dtype == b.dtype == np.uint64
    return int(np.count_nonzero(a != b))


def _assert_views_close(got, want):
    assert got.shape == want.shape
    for v in range(want.shape[0]):
        n = _n_differ(got[v], want[v])
        assert n <= MAX_DIFF_FRACTION * want[v].size, f"view {v}: {n} of {want[v].size} pixels differ"
        assert np.count_nonzero(want[v] != EMPTY_PIXEL) > 100


def test_stereo_pair_in_one_pass_equals_cpu(any_gpu, cpu, scene):
    cams = _cams(scene, 2)
    ids, bits, mats, nears, fars = args = _views(scene, cams)
    w, h = cams[0].width, cams[0].height
    assert len(np.unique(bits)) > 1  # the views mix precisions, so every word array is read
    want = cpu.rasterize_views(scene, ids, bits, mats, w, h, nears, fars)
    got = any_gpu.rasterize_views(scene, *args[:3], w, h, nears, fars)
    assert got.dtype == np.uint64 and got.shape == (2, w * h)
    _assert_views_close(got, want)
    # each view equals a mono render of the same batches with that view's matrices
    for v in range(2):
        mono = cpu.rasterize_views(scene, ids, bits[v : v + 1], mats[v : v + 1], w, h, nears[v : v + 1], fars[v : v + 1])[0]
        assert _n_differ(got[v], mono) <= MAX_DIFF_FRACTION * mono.size


def test_views_at_different_precisions_of_one_batch(any_gpu, cpu, scene):
    """A batch drawn at 10 bits in one view and 30 in another: each view decodes at its own."""
    cams = _cams(scene, 3)
    for order in (cams, cams[::-1]):  # the finest precision in the first view, then in the last
        ids, bits, mats, nears, fars = _views(scene, order)
        assert np.any((bits[0] == 30) & (bits[-1] == 10)) or np.any((bits[0] == 10) & (bits[-1] == 30))
        w, h = cams[0].width, cams[0].height
        want = cpu.rasterize_views(scene, ids, bits, mats, w, h, nears, fars)
        _assert_views_close(any_gpu.rasterize_views(scene, ids, bits, mats, w, h, nears, fars), want)


@pytest.mark.parametrize("step", [1, 3])
def test_views_with_splats_and_point_budget(any_gpu, cpu, scene, step):
    cams = _cams(scene, 2)
    ids, bits, mats, nears, fars = _views(scene, cams)
    w, h = cams[0].width, cams[0].height
    for settings in (
        RenderSettings(point_size=3, point_shape="round"),
        RenderSettings(point_size=4, size_mode="attenuated", point_world_size=0.5),
    ):
        sp = splat_params(settings, cams[0])
        want = cpu.rasterize_views(scene, ids, bits, mats, w, h, nears, fars, splat=sp, step=step)
        got = any_gpu.rasterize_views(scene, ids, bits, mats, w, h, nears, fars, splat=sp, step=step)
        _assert_views_close(got, want)


def test_one_dispatch_per_page_whatever_the_number_of_views(gpu, scene, monkeypatch):
    """The batches are read once for all views: a stereo pair costs as many draw dispatches as one view."""
    cams = _cams(scene, 2)
    ids, bits, mats, nears, fars = _views(scene, cams)
    w, h = cams[0].width, cams[0].height
    calls: list[str] = []
    original = gpu.ctx.dispatch
    monkeypatch.setattr(gpu.ctx, "dispatch", lambda name, *a: (calls.append(name), original(name, *a))[1])
    gpu.rasterize_views(scene, ids, bits[:1], mats[:1], w, h, nears[:1], fars[:1])
    mono = [c for c in calls if c.startswith("raster")]
    calls.clear()
    gpu.rasterize_views(scene, ids, bits, mats, w, h, nears, fars)
    stereo = [c for c in calls if c.startswith("raster")]
    assert len(mono) >= 1 and stereo == mono


def test_more_views_than_one_dispatch_draws_in_groups(gpu, cpu, scene, monkeypatch):
    n = MAX_VIEWS + 2
    cams = _cams(scene, n, width=96, height=72)
    ids, bits, mats, nears, fars = _views(scene, cams)
    w, h = cams[0].width, cams[0].height
    want = cpu.rasterize_views(scene, ids, bits, mats, w, h, nears, fars)
    _assert_views_close(gpu.rasterize_views(scene, ids, bits, mats, w, h, nears, fars), want)
    # views that do not fit one buffer binding together: groups of 3
    monkeypatch.setattr(gpu.ctx, "max_binding", 3 * w * h * 8 + 8)
    _assert_views_close(gpu.rasterize_views(scene, ids, bits, mats, w, h, nears, fars), want)


def test_views_of_an_empty_selection_are_empty(gpu, scene):
    cams = _cams(scene, 2)
    out = gpu.rasterize_views(
        scene, np.empty(0, np.int64), np.empty((2, 0), np.int32), np.empty((2, 0, 4, 4), np.float32), 32, 24, [1.0, 1.0], [9.0, 9.0]
    )
    assert out.shape == (2, 32 * 24) and np.all(out == EMPTY_PIXEL)
    assert cams  # the fixture scene is untouched


def test_mismatched_view_arrays_are_refused(gpu, scene):
    ids, bits, mats, nears, fars = _views(scene, _cams(scene, 2))
    with pytest.raises(GigapointError, match="views need"):
        gpu.rasterize_views(scene, ids, bits[:1], mats, 200, 150, nears, fars)
    with pytest.raises(GigapointError, match="views need"):
        gpu.rasterize_views(scene, ids, bits, mats, 200, 150, nears, fars[:1])


@pytest.mark.parametrize(
    "settings",
    [
        {"stereo": "side-by-side"},
        {"stereo": "anaglyph", "edl": True, "fill_holes": 1},
        {"stereo": "side-by-side", "point_size": 3, "hqs": True},
    ],
)
def test_stereo_frames_on_wgpu_equal_cpu(scene, settings, monkeypatch):
    from gigapoint.backends import get_backend

    try:
        backend = get_backend("wgpu")
    except BackendUnavailableError as exc:
        pytest.skip(str(exc))
    calls = []
    original = backend.rasterize_views
    monkeypatch.setattr(backend, "rasterize_views", lambda *a, **k: (calls.append(1), original(*a, **k))[1])
    lo, hi = scene.bounds
    c = (lo + hi) / 2
    cam = Camera.look_at((c[0] - 150, c[1] - 150, 60.0), (c[0], c[1], 0.0), fov=60, width=160, height=120)
    frame = gigapoint.render_frame(scene, cam, RenderSettings(backend="wgpu", ipd=3.0, **{"size_mode": "fixed", **settings}))  # the exact one-pixel render
    ref = gigapoint.render_frame(scene, cam, RenderSettings(backend="cpu", ipd=3.0, **{"size_mode": "fixed", **settings}))
    assert calls == [1]  # both eyes in one pass
    assert frame.stats.backend == "wgpu" and frame.image.shape == ref.image.shape
    n_vis = _n_differ(frame.visibility, ref.visibility)
    assert n_vis <= MAX_DIFF_FRACTION * ref.visibility.size
    n_img = int(np.count_nonzero(np.any(frame.image != ref.image, axis=-1)))
    assert n_img <= MAX_DIFF_FRACTION * ref.image.shape[0] * ref.image.shape[1] + 25 * n_vis
    assert np.count_nonzero(ref.visibility != EMPTY_PIXEL) > 1000
