"""The numba kernel against the plain-numpy reference, pixel-exact."""

import numpy as np
import pytest

import gigapoint as gp
from gigapoint import Camera, RenderSettings
from gigapoint.core.layout import EMPTY_PIXEL
from gigapoint.render.reference import reference_image, reference_visibility


def _check_exact(cloud, cam, settings=None):
    frame = gp.render_frame(cloud, cam, settings)
    ref = reference_visibility(cloud, cam, settings)
    np.testing.assert_array_equal(frame.visibility, ref)
    np.testing.assert_array_equal(frame.image, reference_image(cloud, cam, settings))
    return frame


def test_hand_built_4x4_scene():
    # 4x4 image, orthographic from above: one point per pixel centre, plus an occluded one
    xy = [(x + 0.5, y + 0.5) for y in range(4) for x in range(4)]
    pts = [(x, y, 0.0) for x, y in xy] + [(1.5, 1.5, -1.0)]  # below pixel (1, 2): hidden
    rgb = [(16 * i, 0, 0) for i in range(16)] + [(0, 255, 0)]
    cloud = gp.from_arrays(np.array(pts), np.array(rgb, np.uint8))
    cam = Camera.look_at((2, 2, 10), (2, 2, 0), up=(0, 1, 0), width=4, height=4, projection="orthographic", ortho_height=4)
    frame = _check_exact(cloud, cam)
    assert (frame.index >= 0).all()
    red = frame.image[..., 0].astype(int)
    # image row 0 is the top (largest y); pixel (col x, row 3 - y) holds point y * 4 + x
    expected = np.array([[16 * (y * 4 + x) for x in range(4)] for y in range(4)])[::-1]
    np.testing.assert_array_equal(red, expected)
    assert not (frame.image[..., 1] == 255).any()
    depth = frame.depth
    # 10-bit quantization of the batch (z range 1 m) moves depths by < 1 mm
    np.testing.assert_allclose(depth, 10.0, atol=1e-3)


def test_nearest_point_wins_and_ties_go_to_the_lower_index():
    pts = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [1.0, 1.0, 0.0]])
    cloud = gp.from_arrays(pts, np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [9, 9, 9]], np.uint8))
    cam = Camera.look_at((0, 0, 10), (0, 0, 0), up=(0, 1, 0), width=9, height=9, projection="orthographic", ortho_height=4)
    frame = _check_exact(cloud, cam)
    centre = frame.index[4, 4]
    pos = cloud.positions([centre])[0]
    assert pos[2] == pytest.approx(1.0, abs=1e-6)  # the z = 1 points are nearer the camera
    twins = [i for i in range(4) if abs(cloud.positions([i])[0][2] - 1.0) < 1e-6 and abs(cloud.positions([i])[0][0]) < 1e-6]
    assert centre == min(twins)


CAMERAS = {
    "iso": lambda b: Camera.fit(b, view="iso", width=320, height=180),
    "top-ortho": lambda b: Camera.fit(b, view="top", width=257, height=131, projection="orthographic"),
    "front": lambda b: Camera.fit(b, view="front", width=200, height=200, fov=30),
    "inside": lambda b: Camera.look_at((500, 480, 8), (560, 520, 5), width=240, height=160, fov=90),
    "close-up": lambda b: Camera.look_at((430, 420, 25), (450, 450, 10), width=2000, height=1200, fov=20),
    "away": lambda b: Camera.look_at((-100, -100, 10), (-200, -200, 10), width=64, height=64),
}


@pytest.mark.parametrize("view", list(CAMERAS))
def test_kernel_equals_reference_on_demo_scene(demo_small, view):
    cam = CAMERAS[view](demo_small.bounds)
    if view == "away":
        with pytest.warns(gp.GigapointWarning, match="no point is in view"):
            frame = _check_exact(demo_small, cam)
        assert (frame.visibility == EMPTY_PIXEL).all()
        assert frame.stats.batches_rendered == 0
        return
    frame = _check_exact(demo_small, cam)
    assert frame.stats.visible_pixels == int((frame.visibility != EMPTY_PIXEL).sum()) > 0  # counted by the resolve
    if view == "close-up":
        assert frame.stats.precision_histogram[20] > 0  # large projected batches use more bits
    if view == "inside":
        assert frame.stats.batches_culled > 0


def test_full_precision_setting_matches_reference(demo_small):
    cam = CAMERAS["iso"](demo_small.bounds)
    settings = RenderSettings(adaptive_precision=False)
    frame = _check_exact(demo_small, cam, settings)
    assert frame.stats.precision_histogram == {10: 0, 20: 0, 30: demo_small.n_points}


@pytest.mark.parametrize("view", ["iso", "inside", "close-up"])
def test_image_identical_with_one_and_two_threads(demo_small, view):
    cam = CAMERAS[view](demo_small.bounds)
    one = gp.render_frame(demo_small, cam, RenderSettings(threads=1, backend="cpu"))
    two = gp.render_frame(demo_small, cam, RenderSettings(threads=2, backend="cpu"))
    np.testing.assert_array_equal(one.visibility, two.visibility)
    # and again, so leftovers in the per-thread buffers would show
    again = gp.render_frame(demo_small, CAMERAS["iso"](demo_small.bounds), RenderSettings(threads=2, backend="cpu"))
    ref = reference_visibility(demo_small, CAMERAS["iso"](demo_small.bounds))
    np.testing.assert_array_equal(again.visibility, ref)


def test_adaptive_precision_stays_close_to_full_precision(demo_small):
    cam = CAMERAS["iso"](demo_small.bounds)
    adaptive = gp.render_frame(demo_small, cam)
    full = gp.render_frame(demo_small, cam, RenderSettings(adaptive_precision=False))
    assert adaptive.stats.precision_histogram[10] == demo_small.n_points
    # 10-bit positions move points by less than a pixel: nearly the same coverage
    a, f = ~adaptive.empty, ~full.empty
    assert abs(int(a.sum()) - int(f.sum())) < 0.02 * f.sum()


def test_frustum_culling_never_drops_a_visible_point(demo_small):
    cam = CAMERAS["inside"](demo_small.bounds)
    culled = gp.render_frame(demo_small, cam)
    everything = gp.render_frame(demo_small, cam, RenderSettings(frustum_culling=False))
    assert culled.stats.batches_culled > 0 and everything.stats.batches_culled == 0
    np.testing.assert_array_equal(culled.visibility, everything.visibility)


def test_background_and_render_api(demo_small):
    cam = Camera.fit(demo_small.bounds, width=64, height=48)
    image, stats = gp.render(demo_small, cam, background="#102030", return_stats=True)
    assert image.shape == (48, 64, 4) and image.dtype == np.uint8
    corner = image[0, 0]
    assert corner.tolist() == [16, 32, 48, 255]
    assert stats.points_processed == demo_small.n_points
    assert sum(stats.precision_histogram.values()) == stats.points_processed


def test_degenerate_clouds_render(rng):
    cam_for = lambda c: Camera.fit(c.bounds, view="iso", width=50, height=40)
    single = gp.from_arrays(np.array([[637_000.5, 851_000.25, 120.0]]))
    f = gp.render_frame(single, cam_for(single))
    assert f.stats.visible_pixels == 1  # adaptive size: no spacing, one pixel
    rows, cols = np.nonzero(f.index == 0)  # the single point is in the middle
    assert abs(rows[0] - 20) <= 1 and abs(cols[0] - 25) <= 1
    same = gp.from_arrays(np.tile([[1.0, 2.0, 3.0]], (1000, 1)))
    f = gp.render_frame(same, cam_for(same))
    assert f.stats.visible_pixels == 1 and f.index[f.index >= 0][0] == 0
    flat = gp.from_arrays(np.column_stack([rng.random((5000, 2)), np.zeros(5000)]))
    for view in ("top", "iso", "front"):
        cam = Camera.fit(flat.bounds, view=view, width=60, height=60)
        exact = gp.RenderSettings(size_mode="fixed")  # one-pixel points
        np.testing.assert_array_equal(gp.render_frame(flat, cam, exact).visibility, reference_visibility(flat, cam, exact))


def test_nan_and_absurd_points_are_skipped_with_a_warning(rng):
    xyz = rng.random((100, 3))
    xyz[3] = np.nan
    xyz[7, 1] = np.inf
    xyz[9, 2] = 1e300
    with pytest.warns(gp.GigapointWarning, match="skipped 3 invalid points"):
        cloud = gp.from_arrays(xyz)
    assert cloud.n_points == 97 and cloud.skipped == 3


def test_all_invalid_points_is_an_error():
    with pytest.raises(gp.GigapointError, match="no valid points"):
        gp.from_arrays(np.full((5, 3), np.nan))
    with pytest.raises(gp.GigapointError, match="no valid points"):
        gp.from_arrays(np.empty((0, 3)))


def _batch_views(cloud, cam):
    """Per selected batch: (inside_frustum as the kernel decides, matrix shape)."""
    from gigapoint.backends.numba_cpu.raster import inside_frustum, matrix_shape
    from gigapoint.core.selection import select

    near, far = cam.clip_range(cloud.bounds)
    sel = select(cloud.batches, cam.screen_rows(), cam.width, cam.height, near, far)
    return sel, near, far, [(bool(inside_frustum(m, cam.width, cam.height, near, far)), int(matrix_shape(m))) for m in sel.matrices]


@pytest.mark.parametrize("view", ["iso", "top-ortho", "front", "inside"])
def test_batches_inside_the_frustum_skip_clipping_and_stay_exact(demo_small, view):
    """Phase 1 skips the clipping tests for batches whose grid cube projects inside the image:
    every reference point of such a batch must have a pixel, and the image stays exact."""
    from gigapoint.backends.numba_cpu import raster
    from gigapoint.render.reference import projected_batches

    cam = CAMERAS[view](demo_small.bounds)
    sel, near, far, flags = _batch_views(demo_small, cam)
    n_inside = sum(ok for ok, _ in flags)
    assert n_inside > 0 and (n_inside < len(flags) or view == "iso")
    want_shape = raster.ORTHOGRAPHIC if view == "top-ortho" else raster.PERSPECTIVE
    assert {s for _, s in flags} == {want_shape}
    counts = demo_small.batches["count"][sel.ids]
    for (ok, _), count, (_, idx, _, _, _) in zip(flags, counts, projected_batches(demo_small, sel, cam.width, cam.height, near, far)):
        if ok:
            assert len(idx) == count  # no point of an inside batch is clipped
    _check_exact(demo_small, cam)


def test_odd_and_tiny_batches_write_every_point():
    """Phase 2 interleaves a batch's two halves: odd counts (the last point has no partner)
    and one- to three-point clouds draw every point."""
    for n in (1, 2, 3, 7, 10241):
        cols = min(n, 128)
        rows = -(-n // cols)
        i = np.arange(n)
        xyz = np.column_stack([i % cols + 0.5, i // cols + 0.5, np.zeros(n)])  # one point per pixel centre
        cloud = gp.from_arrays(np.vstack([xyz, [[0.0, 0.0, 0.0], [cols, rows, 0.0]]]))  # two corners fix the bounds
        cam = Camera.look_at((cols / 2, rows / 2, 10), (cols / 2, rows / 2, 0), up=(0, 1, 0), width=cols, height=rows, projection="orthographic", ortho_height=rows)
        frame = _check_exact(cloud, cam)
        covered = ~frame.empty[::-1]  # image row 0 is the top (largest y)
        assert covered.reshape(-1)[:n].all()


def test_visible_pixels_count_the_frame_after_hole_filling(demo_small):
    cam = Camera.fit(demo_small.bounds, view="top", width=300, height=200)
    plain = gp.render_frame(demo_small, cam, gp.RenderSettings(threads=2))
    filled = gp.render_frame(demo_small, cam, gp.RenderSettings(threads=2, fill_holes=2))
    for f in (plain, filled):
        assert f.stats.visible_pixels == int((f.visibility != EMPTY_PIXEL).sum())
    assert filled.stats.visible_pixels > plain.stats.visible_pixels


def test_batch_footprint_flags_every_tile_its_points_write(demo_small):
    """Thread 1's merge visits only flagged tiles; for a batch inside the frustum the flags come
    from its projected grid cube (raster.mark_footprint), not from its points: they must cover
    every pixel the points land on."""
    from gigapoint.backends.numba_cpu import raster
    from gigapoint.core.selection import select

    cam = CAMERAS["iso"](demo_small.bounds)
    w, h = cam.width, cam.height
    near, far = cam.clip_range(demo_small.bounds)
    sel = select(demo_small.batches, cam.screen_rows(), w, h, near, far)
    inside = 0
    for k, bid in enumerate(sel.ids):
        m = np.ascontiguousarray(sel.matrices[k], np.float32)
        if not raster.inside_frustum(m, w, h, np.float32(near), np.float32(far)):
            continue
        inside += 1
        b = demo_small.batches[bid]
        f, c = int(b["first"]), int(b["count"])
        pix = np.empty(c, np.int32)
        depth = np.empty(c, np.float32)
        raster.project_batch(demo_small.low[f : f + c], demo_small.med[f : f + c], demo_small.high[f : f + c], sel.bits[k], m, w, h, np.float32(near), np.float32(far), pix, depth, False, raster.shape_token(m))
        dirty = np.zeros((w * h >> raster.TILE_SHIFT) + 1, np.uint8)
        assert raster.mark_footprint(m, w, h, dirty, 1 << 40)
        assert (pix >= 0).all() and dirty[pix >> raster.TILE_SHIFT].all()
        untouched = np.zeros_like(dirty)
        assert not raster.mark_footprint(m, w, h, untouched, 0) and not untouched.any()  # too sparse: the points flag their own tiles
    assert inside > 0


@pytest.mark.parametrize("view", ["iso", "top-ortho"])
def test_every_matrix_shape_draws_the_same_image(demo_small, view):
    """``shape_token`` names the batch matrices' shape (the kernels are compiled per shape, with
    that shape's loops only); the GENERAL loops, which skip nothing and always clip, give the
    same visibility buffer bit for bit as the camera's own shape."""
    from gigapoint.backends.numba_cpu import raster
    from gigapoint.backends.numba_cpu.backend import NumbaCpuBackend

    cam = CAMERAS[view](demo_small.bounds)
    sel, near, far, _ = _batch_views(demo_small, cam)
    mats = np.ascontiguousarray(sel.matrices, np.float32)
    own = raster.shape_token(mats)
    assert own is raster.SHAPE_TOKENS[raster.ORTHOGRAPHIC if view == "top-ortho" else raster.PERSPECTIVE]
    skewed = mats.copy()
    skewed[0, 2, 0] += 1e-3  # one batch's w row: no longer its depth row, nor (0, 0, 0, 1)
    assert raster.shape_token(skewed) is raster.SHAPE_TOKENS[raster.GENERAL]
    assert raster.shape_token(mats[:0]) is raster.SHAPE_TOKENS[raster.PERSPECTIVE]  # nothing drawn: the common shape

    backend = NumbaCpuBackend()
    drawn = {}
    for name, token in (("own", own), ("general", raster.SHAPE_TOKENS[raster.GENERAL])):
        real = raster.shape_token
        raster.shape_token = lambda m, token=token: token  # the driver asks this one
        try:
            drawn[name] = backend.rasterize(demo_small, sel, cam.width, cam.height, near, far, threads=2)
        finally:
            raster.shape_token = real
    np.testing.assert_array_equal(drawn["general"], drawn["own"])
    np.testing.assert_array_equal(drawn["own"], reference_visibility(demo_small, cam).reshape(-1))


def test_first_render_compiles_each_kernel_once(tmp_path, autzen_path):
    """A first render on an empty numba cache compiles each helper for one signature (a prange
    index typed unsigned in the parallel loop's own compile, or a constant argument typed as a
    literal, compiled helpers twice: 3 s of a 20 s first render) and only the camera's matrix
    shape's projection loops."""
    import os
    import subprocess
    import sys

    script = f"""
import gc
import gigapoint as gp
from numba.core.registry import CPUDispatcher
from gigapoint.backends.numba_cpu import raster
cloud = gp.open({str(autzen_path)!r})
gp.render_frame(cloud, gp.Camera.fit_cloud(cloud, width=320, height=180))
# by design: grid_coords per precision (10/20/30), project_point clipped or not
allowed = {{"grid_coords": 3, "project_point": 2}}
for o in gc.get_objects():
    if isinstance(o, CPUDispatcher) and o.py_func.__module__.startswith("gigapoint"):
        n = len(o.signatures)
        if n > allowed.get(o.py_func.__name__, 1):
            print("MANY", o.py_func.__module__, o.py_func.__qualname__, n)
loops = [raster._projection_loop(b, s, c) for b in (10, 20, 30) for s in (raster.ORTHOGRAPHIC, raster.GENERAL) for c in (True, False)]
print("OTHER SHAPES", sum(len(f.signatures) for f in loops))
"""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "MANY" not in out.stdout, out.stdout
    assert "OTHER SHAPES 0" in out.stdout, out.stdout


def test_kernels_cached_by_different_processes_keep_each_shapes_projection(tmp_path):
    """Two processes compile project_batch for a perspective and for an orthographic matrix in
    one numba cache, each the same way (so numba numbers their functions alike); a third loads
    both from the cache. Each shape's projection loops must stay its own: when every variant had
    the same name, the third process ran the perspective loops for the orthographic matrix (in
    the renderer: wrong pixels, writes out of bounds, a segfault)."""
    import os
    import subprocess
    import sys

    script = """
import hashlib, sys
import numpy as np
from gigapoint.backends.numba_cpu import raster
rng = np.random.default_rng(1)
low, med, high = (rng.integers(0, 1 << 30, 4096, dtype=np.uint32) for _ in range(3))
rows = [[0.1, 0.0, 0.05, 20.0], [0.0, 0.1, 0.02, 30.0]]
mats = {"perspective": np.array(rows + [[0.0, 0.0, 0.01, 5.0], [0.0, 0.0, 0.01, 5.0]], np.float32),
        "orthographic": np.array(rows + [[0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.01, 5.0]], np.float32)}
for name in sys.argv[1:]:
    m, pix, depth = mats[name], np.empty(4096, np.int32), np.empty(4096, np.float32)
    raster.project_batch(low, med, high, 10, m, 200, 150, 1.0, 100.0, pix, depth, True, raster.shape_token(m))
    print(name, hashlib.sha1(pix.tobytes() + depth.tobytes()).hexdigest(), flush=True)
"""

    def run(cache, *shapes):
        env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / cache))
        out = subprocess.run([sys.executable, "-c", script, *shapes], env=env, capture_output=True, text=True, timeout=600)
        assert out.returncode == 0, out.stderr[-2000:]
        return dict(line.split() for line in out.stdout.splitlines())

    alone = {**run("perspective", "perspective"), **run("orthographic", "orthographic")}
    assert alone["perspective"] != alone["orthographic"]
    run("shared", "perspective")
    run("shared", "orthographic")
    assert run("shared", "perspective", "orthographic") == alone


def test_vector_runs_write_exactly_their_pixels():
    """simd.min_run8 (the splats' rows): min with the key on lanes < n only; pixels past the run,
    here past the end of a view into a larger array, stay untouched."""
    from numba import njit

    from gigapoint.backends.numba_cpu.simd import min_run8

    @njit
    def run(buf, first, n, key):
        min_run8(buf, first, n, key)

    rng = np.random.default_rng(3)
    for n in range(-2, 9):  # n <= 0: nothing
        for first in (0, 5, 17 - max(n, 0)):
            big = rng.integers(0, 1000, 32).astype(np.uint64)
            want = big.copy()
            want[first : first + max(n, 0)] = np.minimum(want[first : first + max(n, 0)], np.uint64(500))
            run(big[:17], first, n, np.uint64(500))  # lanes past first + n would reach big[17:]
            np.testing.assert_array_equal(big, want)
