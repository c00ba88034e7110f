"""Eye-dome lighting, hole filling and high-quality shading (issue #5) against numpy references."""

from __future__ import annotations

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.backends.numba_cpu.passes import eye_dome_lighting, fill_holes, hqs_colors
from gigapoint.core.layout import EMPTY_PIXEL
from gigapoint.core.selection import select
from gigapoint.render.passes.edl import edl_reference
from gigapoint.render.passes.holes import fill_holes_reference
from gigapoint.render.passes.hqs import hqs_reference

W, H = 48, 32


def top_camera(width=W, height=H, z=50.0):
    """Orthographic top view: world (x, y) in [0, width) x [0, height) maps 1:1 onto pixels."""
    c = (width / 2, height / 2)
    return gp.Camera.look_at(
        (c[0], c[1], z), (c[0], c[1], 0.0), up=(0, 1, 0), width=width, height=height, projection="orthographic", ortho_height=float(height)
    )


def plane(width=W, height=H, z=0.0, skip=(), rgb=None):
    """One point at the centre of every pixel (row 0 at the top), minus pixels in ``skip`` (x, row)."""
    pts, cols = [], []
    for row in range(height):
        for x in range(width):
            if (x, row) in skip:
                continue
            pts.append((x + 0.5, height - row - 0.5, z))
            cols.append(rgb if rgb is not None else (x * 5 % 256, row * 7 % 256, 100, 255))
    return np.array(pts, np.float64), np.array(cols, np.uint8)


def frame_of(xyz, rgba, cam, **settings):
    cloud = gp.from_arrays(xyz, rgba, name="scene")
    return cloud, gp.render_frame(cloud, cam, gp.RenderSettings(backend="cpu", **{"size_mode": "fixed", **settings}))  # one-pixel points


@pytest.fixture(scope="module")
def demo():
    cloud = gp.demo(150_000, seed=1, scale=None)
    cam = gp.Camera.fit(cloud.bounds, view=(-70.0, 30.0), width=200, height=120, fov=35.0)
    return cloud, cam, gp.render_frame(cloud, cam, gp.RenderSettings(backend="cpu", size_mode="fixed"))  # one-pixel points


# --- eye-dome lighting ---------------------------------------------------------------------------
def _u32(image):
    return np.ascontiguousarray(image).reshape(-1, 4).view(np.uint32).reshape(-1)


def test_edl_kernel_equals_reference(demo):
    _, cam, f = demo
    vis = f.visibility.reshape(-1)
    for strength, radius in ((1.0, 1.4), (0.4, 2.0), (2.5, 3.0)):
        a = eye_dome_lighting(vis, _u32(f.image), cam.width, cam.height, strength, radius)
        b = edl_reference(vis, _u32(f.image), cam.width, cam.height, strength, radius)
        d = np.abs(a.view(np.uint8).astype(int) - b.view(np.uint8).astype(int))
        assert d.max() <= 1 and (d > 0).mean() < 1e-3  # expf of numba vs numpy: at most one level, rarely


def test_edl_darkens_the_far_side_of_a_step_only():
    xyz, rgba = plane(rgb=(200, 200, 200, 255))
    xyz[xyz[:, 0] < W / 2, 2] = 10.0  # left half is 10 m nearer the camera
    cam = top_camera(z=50.0)
    _, plain = frame_of(xyz, rgba, cam)
    _, lit = frame_of(xyz, rgba, cam, edl=True)
    p, e = plain.image[..., 0].astype(int), lit.image[..., 0].astype(int)
    inner = slice(2, H - 2)
    assert np.all(e[inner, W // 2] < p[inner, W // 2])  # first far column next to the step: shaded
    assert np.array_equal(e[inner, W // 2 - 1], p[inner, W // 2 - 1])  # near side of the step: untouched
    assert np.array_equal(e[inner, 3 : W // 2 - 2], p[inner, 3 : W // 2 - 2])  # flat parts: untouched
    assert np.array_equal(e[inner, W // 2 + 3 : W - 3], p[inner, W // 2 + 3 : W - 3])
    expected = round(200 * np.exp(-300 * (np.log2(50.0) - np.log2(40.0)) * 3 / 8))  # 3 of 8 neighbours are nearer
    assert abs(e[H // 2, W // 2] - expected) <= 1


def test_edl_outlines_silhouettes_on_the_background():
    xyz, rgba = plane(width=10, height=10, rgb=(200, 200, 200, 255))
    xyz[:, :2] += 19.0
    cam = top_camera()
    _, f = frame_of(xyz, rgba, cam, edl=True, background="white")
    img = f.image[..., 0].astype(int)
    assert img[0, 0] == 255  # far from the object: background untouched
    assert img[8, 18] < 255 and img[8, 19] == 200  # background pixel next to the object: dark outline


# --- hole filling --------------------------------------------------------------------------------
def test_fill_closes_a_one_pixel_gap_and_keeps_silhouettes():
    xyz, rgba = plane(width=20, height=12, skip={(9, 6)})  # 20 x 12 patch with one hole
    xyz[:, 0] += 10.0
    xyz[:, 1] += 10.0
    cam = top_camera()
    for level in (1, 2, 3):
        _, plain = frame_of(xyz, rgba, cam)
        _, filled = frame_of(xyz, rgba, cam, fill_holes=level)
        hole = (H - 10 - 12 + 6, 10 + 9)
        assert plain.index[hole] == -1
        assert filled.index[hole] >= 0  # the gap is filled...
        assert filled.depth[hole] == plain.depth[hole[0], hole[1] + 1]  # ...with a point of the same plane
        changed = filled.visibility != plain.visibility
        assert changed.sum() == 1 and changed[hole]  # and nothing else moved: the silhouette stays


def test_fill_replaces_a_far_point_seen_through_a_hole():
    near, cols = plane(z=5.0, skip={(20, 10)})
    far = np.array([[20.5, H - 10.5, -20.0]])
    xyz = np.concatenate([near, far])
    rgba = np.concatenate([cols, [[255, 0, 0, 255]]]).astype(np.uint8)
    _, plain = frame_of(xyz, rgba, top_camera())
    _, filled = frame_of(xyz, rgba, top_camera(), fill_holes=1)
    assert tuple(plain.image[10, 20]) == (255, 0, 0, 255)  # the far red point shows through the gap
    assert tuple(filled.image[10, 20]) != (255, 0, 0, 255)
    assert filled.depth[10, 20] == plain.depth[10, 21]


def test_fill_leaves_a_line_end_and_corners_alone():
    # an L-shaped object on empty background: no pixel outside it is surrounded
    skip = {(x, r) for x in range(W) for r in range(H) if not ((10 <= x < 30 and 10 <= r < 14) or (10 <= x < 14 and 10 <= r < 28))}
    xyz, rgba = plane(skip=skip)
    _, plain = frame_of(xyz, rgba, top_camera())
    for level in (1, 2, 3):
        _, filled = frame_of(xyz, rgba, top_camera(), fill_holes=level)
        changed = np.argwhere(filled.visibility != plain.visibility)
        # only the concave inner corner may round off; nothing beyond the convex outline
        assert all(14 <= x < 14 + level and 14 <= r < 14 + level for r, x in changed), (level, changed)


@pytest.mark.parametrize("level", [1, 2, 3])
@pytest.mark.parametrize("foveated", [False, True])
def test_fill_kernel_equals_reference(demo, level, foveated):
    _, cam, f = demo
    vis = f.visibility.reshape(-1)
    a = fill_holes(vis, cam.width, cam.height, level, foveated)
    b = fill_holes_reference(vis, cam.width, cam.height, level, foveated)
    np.testing.assert_array_equal(a, b)
    assert (a != vis).sum() > 0
    assert np.all(a <= vis)  # filling only ever brings nearer points forward


def test_foveated_fill_uses_small_windows_in_the_centre():
    # a 2-pixel-wide crack across the whole image: 3x3 cannot close it, 5x5 can
    skip = {(x, r) for x in range(W) for r in (15, 16)}
    xyz, rgba = plane(skip=skip)
    _, full = frame_of(xyz, rgba, top_camera(), fill_holes=2)
    _, fov = frame_of(xyz, rgba, top_camera(), fill_holes=2, fill_holes_foveated=True)
    assert np.all(full.index[15:17, :] >= 0)
    assert np.all(fov.index[15:17, W // 2 - 1 : W // 2 + 1] == -1)  # the centre keeps a 3x3 window
    assert np.all(fov.index[15:17, 0] >= 0)  # the border gets the 5x5 one


# --- high-quality shading ------------------------------------------------------------------------
def test_hqs_mean_is_exact():
    # 7 points in one pixel within 1% of the closest depth, 1 far behind, 1 in the next pixel
    xyz = np.array([[10.5, 10.5, 0.0 - 0.001 * k] for k in range(7)] + [[10.5, 10.5, -30.0], [11.5, 10.5, 0.0]])
    rgba = np.array([[10 * k + 1, 255 - 3 * k, 17 * k, 255] for k in range(7)] + [[0, 0, 0, 255], [9, 9, 9, 255]], np.uint8)
    cam = top_camera(z=50.0)
    _, f = frame_of(xyz, rgba, cam, hqs=True)
    px = f.image[H - 11, 10].astype(int)
    exact = rgba[:7].astype(np.int64).sum(0)
    np.testing.assert_array_equal(px, (exact + 3) // 7)  # rounded mean of the 7 near points, not the far one
    assert tuple(f.image[H - 11, 11]) == (9, 9, 9, 255)
    _, plain = frame_of(xyz, rgba, cam)
    assert np.array_equal(plain.visibility, f.visibility)


def test_hqs_kernel_equals_reference_and_thread_count(demo):
    cloud, cam, f = demo
    near, far = cam.clip_range(cloud.bounds)
    sel = select(cloud.batches, cam.screen_rows(), cam.width, cam.height, near, far)
    vis = f.visibility.reshape(-1)
    fallback = _u32(f.image)
    for tol in (0.0, 0.01, 0.1):
        ref = hqs_reference(cloud, sel, vis, cam.width, cam.height, near, far, cloud.color, fallback, tol)
        for threads in (1, 2):
            got = hqs_colors(cloud, sel, vis, cam.width, cam.height, near, far, cloud.color, fallback, tol, threads)
            np.testing.assert_array_equal(got, ref)
    from gigapoint.render.splats import splat_params

    for kw in (
        {"point_size": 3},
        {"point_size": 4, "point_shape": "round"},
        {"point_size": 5, "size_mode": "attenuated", "point_world_size": 30.0},
    ):
        splat = splat_params(gp.RenderSettings(**kw), cam)
        ref = hqs_reference(cloud, sel, vis, cam.width, cam.height, near, far, cloud.color, fallback, 0.01, splat)
        got = hqs_colors(cloud, sel, vis, cam.width, cam.height, near, far, cloud.color, fallback, 0.01, 2, splat)
        np.testing.assert_array_equal(got, ref)
    # Kraft's soft splats: weighted means, the same in kernel and reference, and not the hard ones
    splat = splat_params(gp.RenderSettings(point_size=5, point_shape="round"), cam)
    hard = hqs_colors(cloud, sel, vis, cam.width, cam.height, near, far, cloud.color, fallback, 0.01, 2, splat)
    for softness in (1.0, 3.0):
        ref = hqs_reference(cloud, sel, vis, cam.width, cam.height, near, far, cloud.color, fallback, 0.01, splat, softness)
        got = hqs_colors(cloud, sel, vis, cam.width, cam.height, near, far, cloud.color, fallback, 0.01, 2, splat, softness)
        np.testing.assert_array_equal(got, ref)
        assert not np.array_equal(got, hard)
    img = gp.render(cloud, cam, backend="cpu", hqs=True)
    assert np.array_equal(_u32(img), hqs_reference(cloud, sel, vis, cam.width, cam.height, near, far, cloud.color, fallback, 0.01))
    assert not np.array_equal(img, f.image)


def test_hqs_under_a_point_cap_blends_only_the_points_drawn(demo):
    """max_points draws every step-th point; HQS blended the skipped ones in too (and paid for them)."""
    xyz, _ = plane()
    two_layers = gp.from_arrays(np.r_[xyz, xyz + (0.0, 0.0, 0.001)], name="scene")  # two points a pixel, within HQS's tolerance
    rgb = np.zeros((two_layers.n_points, 3), np.uint8)
    rgb[0::2, 0] = 255  # even points (those a step of 2 draws) red, odd green
    rgb[1::2, 1] = 255
    two_layers.set_colors(rgb)
    settings = gp.RenderSettings(backend="cpu", size_mode="fixed", max_points=two_layers.n_points // 2, hqs=True)
    f = gp.render_frame(two_layers, top_camera(), settings)
    assert f.stats.points_processed == W * H
    assert np.all(f.index % 2 == 0)
    assert np.unique(f.image.reshape(-1, 4), axis=0).tolist() == [[255, 0, 0, 255]]  # was (128, 128, 0): red and green blended
    # the kernel and its reference agree on a step
    cloud, cam, f = demo
    near, far = cam.clip_range(cloud.bounds)
    sel = select(cloud.batches, cam.screen_rows(), cam.width, cam.height, near, far)
    vis = gp.render_frame(cloud, cam, gp.RenderSettings(backend="cpu", size_mode="fixed", max_points=cloud.n_points // 3)).visibility.reshape(-1)
    fallback = _u32(f.image)
    ref = hqs_reference(cloud, sel, vis, cam.width, cam.height, near, far, cloud.color, fallback, 0.05, step=3)
    np.testing.assert_array_equal(hqs_colors(cloud, sel, vis, cam.width, cam.height, near, far, cloud.color, fallback, 0.05, 2, step=3), ref)
    assert not np.array_equal(ref, hqs_reference(cloud, sel, vis, cam.width, cam.height, near, far, cloud.color, fallback, 0.05))


@pytest.mark.parametrize("step", [2, 5, 8])
def test_hqs_under_a_point_cap_equals_the_reference_at_every_step(demo, step):
    """A point cap's subsample is gathered before it is projected (the points skipped are not
    read): the image stays the reference's, which projects every point and blends every step-th,
    one-pixel and splats, overview and close-up (10- to 30-bit batches)."""
    from gigapoint.render.passes import splat_for

    cloud, overview, _ = demo
    lo, hi = cloud.bounds
    c = (lo + hi) / 2
    closeup = gp.Camera.look_at((c[0] - 120, c[1] - 120, c[2] + 40.0), tuple(c), fov=60, width=200, height=120)
    bits = set()
    for cam in (overview, closeup):
        view = cam.view(cloud.bounds)
        for kw in ({"size_mode": "fixed"}, {"size_mode": "adaptive"}, {"size_mode": "fixed", "point_size": 3, "point_shape": "round", "splat_softness": 2.0}):
            s = gp.RenderSettings(backend="cpu", max_points=-(-cloud.n_points // step), hqs=True, threads=2, **kw)
            draw = cloud.prepare(view, s)
            assert draw.step == step
            bits |= set(np.unique(draw.selection.bits).tolist())
            plain = gp.render_frame(cloud, cam, s.replace(hqs=False, splat_softness=0.0))
            ref = hqs_reference(cloud, draw.selection, plain.visibility.reshape(-1), cam.width, cam.height, view.near, view.far, cloud.color,
                                _u32(plain.image), s.hqs_depth_tolerance, splat_for(s, cam, draw, view.near), s.splat_softness, step=step)  # fmt: skip
            np.testing.assert_array_equal(_u32(gp.render(cloud, cam, s)), ref)
    assert {10, 20, 30} <= bits  # the gather of the medium and high words at each precision


def test_hqs_mean_is_exact_past_the_packed_sums():
    """5000 points in one pixel, far more than the 32 a packed u64 sums: the spill sums keep the
    mean exact, hard and with soft-splat weights, whatever the threads and bands."""
    rng = np.random.default_rng(5)
    n = 5000
    xyz = np.concatenate([np.column_stack([np.full(n, 20.5), np.full(n, 10.5), -0.001 * rng.random(n)]), [[10.5, 20.5, 0.0]]])
    rgba = rng.integers(0, 256, (n + 1, 4)).astype(np.uint8)
    cam = top_camera(z=50.0)
    _, f = frame_of(xyz, rgba, cam, hqs=True)
    np.testing.assert_array_equal(f.image[H - 11, 20], (rgba[:n].astype(np.int64).sum(0) + n // 2) // n)
    assert tuple(f.image[H - 21, 10]) == tuple(rgba[n])
    cloud = gp.from_arrays(xyz, rgba, name="pile")
    from gigapoint.render.splats import splat_params

    near, far = cam.clip_range(cloud.bounds)
    sel = select(cloud.batches, cam.screen_rows(), W, H, near, far)
    vis = f.visibility.reshape(-1)
    for softness in (0.0, 2.0):
        s = gp.RenderSettings(point_size=7, point_shape="round", hqs=True, splat_softness=softness)
        splat = splat_params(s, cam)
        big = gp.render_frame(cloud, cam, s.replace(backend="cpu")).visibility.reshape(-1)
        ref = hqs_reference(cloud, sel, big, W, H, near, far, cloud.color, _u32(f.image), 0.01, splat, softness)
        for threads, bands in ((1, None), (2, None), (2, 9)):
            got = hqs_colors(cloud, sel, big, W, H, near, far, cloud.color, _u32(f.image), 0.01, threads, splat, softness, bands=bands)
            np.testing.assert_array_equal(got, ref)
    assert not np.array_equal(got, hqs_colors(cloud, sel, vis, W, H, near, far, cloud.color, _u32(f.image), 0.01, 2))


def test_hqs_bands_and_cameras_inside_the_cloud(demo):
    """The screen bands (many, and batches reaching behind the eye) change nothing."""
    from gigapoint.render.splats import splat_params

    cloud, _, _ = demo
    lo, hi = np.asarray(cloud.bounds[0]), np.asarray(cloud.bounds[1])
    centre = (lo + hi) / 2
    cam = gp.Camera.look_at(centre + [0, 0, 5], centre + [300, 200, -5], up=(0, 0, 1), width=90, height=70, fov=70.0)
    f = gp.render_frame(cloud, cam, gp.RenderSettings(backend="cpu", point_size=3))
    near, far = cam.clip_range(cloud.bounds)
    sel = select(cloud.batches, cam.screen_rows(), cam.width, cam.height, near, far)
    vis = f.visibility.reshape(-1)
    splat = splat_params(gp.RenderSettings(point_size=3), cam)
    ref = hqs_reference(cloud, sel, vis, cam.width, cam.height, near, far, cloud.color, _u32(f.image), 0.05, splat)
    assert not np.array_equal(ref, _u32(f.image))
    for bands in (1, 2, 7, 70):
        got = hqs_colors(cloud, sel, vis, cam.width, cam.height, near, far, cloud.color, _u32(f.image), 0.05, 2, splat, 0.0, bands=bands)
        np.testing.assert_array_equal(got, ref)


def test_hqs_packed_mean_is_exact_for_every_lane_sum():
    """The resolve's float32 reciprocal gives round-half-up(s / n) for every lane sum s <= 255 n, n <= 32."""
    from numba import njit

    from gigapoint.backends.numba_cpu.pass_kernels import _lane_mean

    @njit
    def all_means(out):
        for n in range(1, 33):
            rcp = np.float32(1.0) / np.float32(n)
            for s in range(255 * n + 1):
                out[n, s] = _lane_mean(np.uint64(s), np.uint32(n >> 1), rcp)

    got = np.zeros((33, 255 * 32 + 1), np.int64)
    all_means(got)
    for n in range(1, 33):
        s = np.arange(255 * n + 1)
        np.testing.assert_array_equal(got[n, : len(s)], (s + n // 2) // n)


def test_hqs_bands_share_the_points_evenly():
    from gigapoint.backends.numba_cpu.passes import split_rows

    # 90 000 points over rows 0..99, 10 000 over rows 100..999 of a 100 px wide screen
    lo, hi, span, counts = np.array([0, 100]), np.array([99, 999]), np.array([100.0, 900.0]), np.array([90_000, 10_000])
    two = split_rows(lo, hi, span, counts, 100, 1000, 2)
    assert two[0] == 0 and two[2] == 1000 and 50 < two[1] < 80  # the dense rows are split, not the screen
    four = split_rows(lo, hi, span, counts, 100, 1000, 4)
    assert np.all(np.diff(four) > 0) and four[3] < 100
    assert list(split_rows(lo, hi, span, counts, 100, 1000, 1)) == [0, 1000]


def test_passes_compose_like_their_references(demo):
    """fill holes -> color mode -> HQS -> EDL, each step by its numpy reference."""
    from gigapoint.render.colors import point_colors

    cloud, cam, f = demo
    s = gp.RenderSettings(backend="cpu", hqs=True, fill_holes=1, color_mode="classification", edl=True)
    img = gp.render(cloud, cam, s)
    near, far = cam.clip_range(cloud.bounds)
    sel = select(cloud.batches, cam.screen_rows(), cam.width, cam.height, near, far)
    vis = fill_holes_reference(f.visibility.reshape(-1), cam.width, cam.height, 1)
    pc = point_colors(cloud, s)
    base = np.where(
        vis == EMPTY_PIXEL,
        np.array(s.background, np.uint8).view(np.uint32)[0],
        pc[(vis & np.uint64(0xFFFFFFFF)).astype(np.int64) % cloud.n_points],
    )
    blended = hqs_reference(cloud, sel, vis, cam.width, cam.height, near, far, pc, base, s.hqs_depth_tolerance)
    expected = edl_reference(vis, blended, cam.width, cam.height)
    d = np.abs(img.reshape(-1, 4).astype(int) - expected.view(np.uint8).reshape(-1, 4).astype(int))
    assert d.max() <= 1 and (d > 0).mean() < 1e-3
