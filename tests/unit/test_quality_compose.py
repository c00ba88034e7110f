"""Supersampling, stereo, normals and lighting (issue #5)."""

from __future__ import annotations

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import GigapointError, SettingsError
from gigapoint.render.normals import decode_octahedral, encode_octahedral, estimate_normals, octahedral_error
from gigapoint.render.passes.compose import convergence_shift, eye_cameras
from gigapoint.render.passes.lighting import shade_reference


@pytest.fixture(scope="module")
def scene():
    cloud = gp.demo(80_000, seed=2)
    cam = gp.Camera.fit(cloud.bounds, view=(-50.0, 40.0), width=120, height=80, fov=40.0, margin=0.7)
    return cloud, cam


@pytest.mark.parametrize("s", [2, 4])
def test_supersample_is_the_box_filtered_big_render(scene, s):
    cloud, cam = scene
    f = gp.render_frame(cloud, cam, gp.RenderSettings(backend="cpu", supersample=s))
    # points keep their size in output pixels: s x s in the big render
    big = gp.render_frame(cloud, cam.with_size(cam.width * s, cam.height * s), gp.RenderSettings(backend="cpu", point_size=s))
    blocks = big.image.reshape(cam.height, s, cam.width, s, 4).astype(np.int64).sum(axis=(1, 3))
    np.testing.assert_array_equal(f.image, ((blocks + s * s // 2) // (s * s)).astype(np.uint8))
    assert f.visibility.shape == (cam.height, cam.width)
    np.testing.assert_array_equal(f.visibility, big.visibility.reshape(cam.height, s, cam.width, s).min(axis=(1, 3)))
    # anti-aliasing: more distinct in-between colors than the plain render
    plain = gp.render(cloud, cam, backend="cpu")
    assert len(np.unique(f.image.reshape(-1, 4), axis=0)) > len(np.unique(plain.reshape(-1, 4), axis=0))


def test_supersample_lanczos_is_pillows_resize(scene):
    from PIL import Image

    cloud, cam = scene
    f = gp.render_frame(cloud, cam, gp.RenderSettings(backend="cpu", supersample=2, supersample_filter="lanczos"))
    big = gp.render(cloud, cam.with_size(cam.width * 2, cam.height * 2), backend="cpu", point_size=2)
    np.testing.assert_array_equal(f.image, np.asarray(Image.fromarray(big).resize((cam.width, cam.height), Image.Resampling.LANCZOS)))
    box = gp.render(cloud, cam, backend="cpu", supersample=2)
    assert not np.array_equal(f.image, box)


def test_supersample_too_big_is_a_settings_error(scene):
    cloud, _ = scene
    cam = gp.Camera.fit(cloud.bounds, width=8000, height=100)
    with pytest.raises(SettingsError, match="supersample 4"):
        gp.render(cloud, cam, supersample=4)


def test_stereo_equals_two_renders_with_shifted_cameras(scene):
    cloud, cam = scene
    ipd, conv = 40.0, 900.0
    s = gp.RenderSettings(backend="cpu", stereo="side-by-side", ipd=ipd, convergence=conv)
    f = gp.render_frame(cloud, cam, s)
    left_cam, right_cam = eye_cameras(cam, ipd)
    np.testing.assert_allclose(np.subtract(right_cam.eye, left_cam.eye), cam.basis()[0] * ipd)
    left = gp.render(cloud, left_cam, backend="cpu")
    right = gp.render(cloud, right_cam, backend="cpu")
    h = convergence_shift(cam, ipd, conv)
    assert h > 0
    bg = np.array([0, 0, 0, 255], np.uint8)
    w = cam.width
    np.testing.assert_array_equal(f.image[:, : w - h], left[:, h:])  # left eye moved left by h
    assert np.all(f.image[:, w - h : w] == bg)
    np.testing.assert_array_equal(f.image[:, w + h :], right[:, : w - h])  # right eye moved right by h
    assert not np.array_equal(left, right)
    ana = gp.render(cloud, cam, s.replace(stereo="anaglyph"))
    np.testing.assert_array_equal(ana[..., 0], f.image[:, :w, 0])
    np.testing.assert_array_equal(ana[..., 1:3], f.image[:, w:, 1:3])


@pytest.mark.parametrize("kw", [{}, {"supersample": 2}])
def test_a_stereo_frame_picks_the_points_it_shows(scene, kw):
    """frame.point_info of a stereo frame was None for every pixel (its Frame named no buffers);
    now each pixel's point, in either eye, is the cloud's point there."""
    cloud, cam = scene
    for stereo in ("side-by-side", "anaglyph"):
        f = gp.render_frame(cloud, cam, gp.RenderSettings(backend="cpu", stereo=stereo, ipd=40.0, **kw))
        picked = f.index[f.index >= 0]
        assert len(picked) > 1000
        for i in picked[:: len(picked) // 5].tolist():
            assert f.point_info(i) == cloud.point_info(i)
            assert f.point_info(i)["index"] == i


def test_an_empty_stereo_frame_warns_like_a_plain_one():
    """A stereo frame that shows no point (a camera looking away; eyes an ipd apart that is wide
    for a 1 cm scene, each image moved off the frame) was the background without a word."""
    cloud = gp.from_arrays(np.random.default_rng(0).random((1000, 3)) * 0.01, name="pebble")
    cam = gp.Camera.fit_cloud(cloud, width=64, height=48)
    with pytest.warns(gp.GigapointWarning, match=r"^pebble: no point is in view of the stereo camera \(each eye's image moves 101 px of 64: ipd 0.065 world units is wide"):
        f = gp.render_frame(cloud, cam, stereo="anaglyph", ipd=0.065)
    assert f.stats.visible_pixels == 0
    away = gp.Camera.look_at((5, 5, 5), (6, 6, 6), width=64, height=48)
    with pytest.warns(gp.GigapointWarning, match=r"^pebble: no point is in view of the stereo camera; the image shows only the background$"):
        gp.render_frame(cloud, away, stereo="side-by-side")
    assert gp.render_frame(cloud, cam, stereo="anaglyph", ipd=0.0005).stats.visible_pixels > 100  # an ipd for its size
    # eyes beside the pebble, their images hardly moved (a convergence far away): that said too
    beside = r"^pebble: no point is in view of the stereo camera \(%s puts each eye beside the cloud, 0.00999 across: give %s\); the image"
    with pytest.warns(gp.GigapointWarning, match=beside % ("ipd 1 world units", "a smaller ipd")):
        gp.render_frame(cloud, cam, stereo="anaglyph", ipd=1.0, convergence=1e6)
    with pytest.warns(gp.GigapointWarning, match=beside % (r"the automatic ipd, 3.3e\+04 world units from convergence 1e\+06,", "a convergence near the cloud's distance, or an ipd")):
        gp.render_frame(cloud, cam, stereo="side-by-side", convergence=1e6)


def test_the_default_stereo_pair_of_a_pebble_shows_it():
    """The default ipd was a fixed 0.065 world units: a 1 cm pebble's stereo frame was blank (each
    eye's image moved 101 px off a 64 px frame). The automatic ipd scales with the scene."""
    cloud = gp.from_arrays(np.random.default_rng(0).random((1000, 3)) * 0.01, name="pebble")
    cam = gp.Camera.fit_cloud(cloud, width=64, height=48)
    plain = gp.render_frame(cloud, cam).stats.visible_pixels
    f = gp.render_frame(cloud, cam, stereo="anaglyph")
    assert f.stats.visible_pixels > 0.8 * plain > 100


def _near_and_far(scale):
    """A red cube at 0.6 and a green one at 1.5 times the target distance 2 * scale, seen along +y."""
    rng = np.random.default_rng(7)
    cube = (rng.random((4000, 3)) - 0.5) * 0.1
    xyz = np.concatenate([cube + (-0.3, -0.8, 0.0), cube + (0.5, 1.0, 0.0)]) * scale
    rgb = np.repeat(np.array([[255, 0, 0], [0, 255, 0]], np.uint8), 4000, axis=0)
    cam = gp.Camera.look_at((0.0, -2.0 * scale, 0.0), (0.0, 0.0, 0.0), fov=60.0, width=160, height=120)
    return gp.from_arrays(xyz, rgb, name="pair"), cam


def _disparity(frame, channel):
    """Centroid x of the pixels of one color in the left eye minus that in the right eye (side-by-side)."""
    w = frame.image.shape[1] // 2
    xs = [np.nonzero(frame.image[:, k * w : (k + 1) * w, channel] > 200)[1] for k in (0, 1)]
    assert all(len(x) > 20 for x in xs)
    return xs[0].mean() - xs[1].mean()


@pytest.mark.parametrize("scale", [0.15, 1500.0])  # a 30 cm object, a 3 km scene
def test_the_default_ipd_gives_any_scene_the_same_depth(scale):
    """The default ipd was a fixed 0.065 world units: the disparity between the near and the far
    cube (the depth the viewer sees) was 14 % of the image width for a 30 cm object, and 0 px for a
    3 km scene. Auto ipd, convergence / 30 (the stereographers' 1/30 rule): fx / 30 (2.2 % of
    the width here) whatever the units."""
    cloud, cam = _near_and_far(scale)
    s = gp.RenderSettings(backend="cpu", stereo="side-by-side", size_mode="fixed", point_size=2)
    f = gp.render_frame(cloud, cam, s)
    depth = _disparity(f, 0) - _disparity(f, 1)  # near (red) minus far (green)
    fx = 60.0 / np.tan(np.radians(30.0))
    assert depth / cam.width == pytest.approx(fx / 30.0 / cam.width, abs=0.002)  # 0.0217
    assert _disparity(f, 0) > 0.5 > -0.5 > _disparity(f, 1)  # near pops out, far recedes: zero parallax at the target
    assert f.stats.visible_pixels > 0.9 * 2 * gp.render_frame(cloud, cam, s.replace(stereo="none")).stats.visible_pixels
    # the rule, as an explicit ipd: the same pixels; an explicit convergence sets the auto ipd too
    np.testing.assert_array_equal(f.image, gp.render(cloud, cam, s.replace(ipd=2.0 * scale / 30.0)))
    conv = s.replace(convergence=1.5 * scale)
    np.testing.assert_array_equal(gp.render(cloud, cam, conv), gp.render(cloud, cam, conv.replace(ipd=1.5 * scale / 30.0)))


@pytest.mark.parametrize("fov", [60.0, 20.0, 5.0, 0.5, 0.05])
def test_the_default_ipd_of_a_narrow_fov_keeps_the_eyes_images_in_the_picture(fov):
    """The auto ipd, convergence / 30, moved each eye's image fx / 60 px: a 5 degree pair's 21 %
    of the width apart, a 0.5 degree pair's out of the picture (blank, both eyes). Made smaller by
    tan(fov / 2) / tan(30°) under 60 degrees, it moves them H / (120 tan 30°) px, 2 px here, at any fov."""
    from gigapoint.render.passes.compose import stereo_ipd

    cloud = gp.from_arrays(np.random.default_rng(0).random((20_000, 3)) * 100.0, name="box")
    cam = gp.Camera.fit_cloud(cloud, width=160, height=120, fov=fov)
    s = gp.RenderSettings(backend="cpu", stereo="side-by-side")
    assert convergence_shift(cam, stereo_ipd(cam, s), None) == round(120 / (120 * np.tan(np.radians(30.0)))) == 2
    plain = gp.render_frame(cloud, cam, s.replace(stereo="none")).stats.visible_pixels
    assert gp.render_frame(cloud, cam, s).stats.visible_pixels > 0.9 * 2 * plain > 1000


def test_the_default_ipd_of_an_orthographic_camera_is_0():
    """Parallel rays see no parallax: eyes moved apart only doubled a small object's image (red
    and cyan copies 0.065 world units apart). The automatic ipd of an orthographic camera is 0."""
    cloud, _ = _near_and_far(0.15)
    cam = gp.Camera.fit(cloud.bounds, view="front", width=160, height=120, projection="orthographic")
    plain = gp.render(cloud, cam, backend="cpu")
    np.testing.assert_array_equal(gp.render(cloud, cam, backend="cpu", stereo="anaglyph"), plain)
    assert not np.array_equal(gp.render(cloud, cam, backend="cpu", stereo="anaglyph", ipd=0.065), plain)


def test_an_explicit_ipd_is_drawn_as_given(scene):
    cloud, cam = scene
    s = gp.RenderSettings(backend="cpu", stereo="anaglyph", ipd=0.1)
    np.testing.assert_array_equal(gp.render(cloud, cam, backend="cpu", stereo="anaglyph", ipd=0.1), gp.render(cloud, cam, s))
    left, right = eye_cameras(cam, 0.1)
    plain = [gp.render(cloud, c, backend="cpu") for c in (left, right)]  # h is 0 px at this distance
    assert convergence_shift(cam, 0.1, None) == 0
    np.testing.assert_array_equal(gp.render(cloud, cam, s)[..., 0], plain[0][..., 0])
    np.testing.assert_array_equal(gp.render(cloud, cam, s)[..., 1:3], plain[1][..., 1:3])
    assert not np.array_equal(gp.render(cloud, cam, s), gp.render(cloud, cam, s.replace(ipd=None)))


@pytest.mark.parametrize("kw", [{"threads": 1}, {"threads": 2, "point_size": 3}, {"edl": True, "fill_holes": 1, "hqs": True}])
def test_one_pass_stereo_equals_separate_renders(scene, kw):
    from gigapoint.render.passes import compose

    cloud, cam = scene
    s = gp.RenderSettings(backend="cpu", **kw)
    cams = eye_cameras(cam, 60.0)
    calls = []
    real = compose.render_views
    compose.render_views = lambda *a: calls.append(1) or real(*a)
    try:
        f = gp.render_frame(cloud, cam, s.replace(stereo="side-by-side", ipd=60.0, convergence=1e9))
    finally:
        compose.render_views = real
    assert calls, "the one-pass path was not taken"
    for k, c in enumerate(cams):
        sep = gp.render_frame(cloud, c, s)
        np.testing.assert_array_equal(f.visibility[:, k * cam.width : (k + 1) * cam.width], sep.visibility)
        np.testing.assert_array_equal(f.image[:, k * cam.width : (k + 1) * cam.width], sep.image)


def test_octahedral_normals_round_trip():
    rng = np.random.default_rng(5)
    n = rng.normal(size=(50_000, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    code = encode_octahedral(n)
    assert code.dtype == np.uint16
    d = decode_octahedral(code)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1, atol=1e-5)
    err = octahedral_error(n)
    assert err["max_deg"] < 1.2 and err["mean_deg"] < 0.5
    axes = np.eye(3)
    np.testing.assert_allclose(
        decode_octahedral(encode_octahedral(np.concatenate([axes, -axes]))), np.concatenate([axes, -axes]), atol=1e-6
    )


def test_estimated_normals_of_planes():
    rng = np.random.default_rng(1)
    xy = rng.random((4000, 2)) * 10
    floor = np.c_[xy, np.zeros(4000)]
    wall = np.c_[xy[:, 0] + 20, np.full(4000, 5.0), xy[:, 1]]  # the plane y = 5
    cloud = gp.from_arrays(np.concatenate([floor, wall]) + [500000.0, 4000000.0, 100.0], name="planes")
    normals, radii = estimate_normals(cloud, k=12)
    z = cloud.positions()[:, 2] - 100.0
    x = cloud.positions()[:, 0] - 500000.0
    on_floor = (z < 1e-6) & (x < 10)
    on_wall = x > 21
    assert np.all(np.abs(normals[on_floor, 2]) > 0.999)
    assert np.all(np.abs(normals[on_wall, 1]) > 0.999)
    assert np.all(normals[:, 2] >= 0)
    assert 0.05 < np.median(radii) < 0.5  # ~0.16 m spacing at 40 points / m^2
    assert {"nx", "ny", "nz", "radius"} <= set(cloud.attributes)
    with pytest.raises(GigapointError):
        estimate_normals(gp.from_arrays(np.zeros((2, 3)) + [[0, 0, 0], [1, 1, 1]]))
    for bad in ({"k": -1}, {"k": 2}, {"k": 12.5}, {"chunk": 0}):  # k=-1 was taken as 3 silently, chunk=0 a ValueError
        with pytest.raises(GigapointError, match=r"^estimate_normals: (k|chunk) must be an integer >= (3|1), got "):
            estimate_normals(cloud, **bad)
    with pytest.raises(GigapointError, match=r"^estimate_normals: store must be True or False, got 'no'$"):
        estimate_normals(small_cloud := gp.from_arrays(rng.random((50, 3))), store="no")  # "no" stored them
    assert "nx" not in small_cloud.attributes
    with pytest.raises(GigapointError, match=r"^estimate_normals takes a cloud held in memory \(gigapoint.open\(path\)\), not a NoneType$"):
        estimate_normals(None)  # an AttributeError on None.name
    small = gp.from_arrays(rng.random((5, 3)))  # k above the cloud's points: every point is a neighbour
    assert np.array_equal(estimate_normals(small, k=16, store=False)[0], estimate_normals(small, k=5, store=False)[0])


def test_lighting_matches_reference_and_needs_normals(scene):
    cloud, cam = scene
    with pytest.raises(SettingsError, match="no normals"):
        gp.render(cloud, cam, lighting=True)
    estimate_normals(cloud, k=10)
    for c in (cam, gp.Camera.fit(cloud.bounds, view="top", width=64, height=48, projection="orthographic")):
        plain = gp.render_frame(cloud, c, gp.RenderSettings(backend="cpu"))
        lit = gp.render(cloud, c, backend="cpu", lighting=True, shininess=16.0)
        ref = shade_reference(cloud, c, plain.visibility, np.ascontiguousarray(plain.image).view(np.uint32).reshape(-1), 16.0)
        d = np.abs(lit.reshape(-1, 4).astype(int) - ref.view(np.uint8).reshape(-1, 4).astype(int))
        assert d.max() <= 1
        assert not np.array_equal(lit, plain.image)
