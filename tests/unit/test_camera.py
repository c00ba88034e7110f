import math

import numpy as np
import pytest

from gigapoint import Camera
from gigapoint.errors import CameraError
from gigapoint.render.camera import VIEWS


def project(cam, p):
    rows = cam.screen_rows()
    x, y, w, d = rows @ np.append(np.asarray(p, float), 1.0)
    return x / w, y / w, d


def test_target_projects_to_the_image_centre():
    cam = Camera.look_at((10, -20, 30), (1, 2, 3), width=640, height=480)
    px, py, d = project(cam, (1, 2, 3))
    assert px == pytest.approx(320) and py == pytest.approx(240)
    assert d == pytest.approx(math.dist((10, -20, 30), (1, 2, 3)))


def test_perspective_edges_and_orientation():
    cam = Camera.look_at((0, -10, 0), (0, 0, 0), up=(0, 0, 1), fov=90, width=200, height=100)
    # fov 90: at distance 10 the top edge of the image is z = 10, the right edge x = 20 (aspect 2)
    assert project(cam, (0, 0, 10))[1] == pytest.approx(0)
    assert project(cam, (20, 0, 0))[0] == pytest.approx(200)
    assert project(cam, (-20, 0, -10))[:2] == pytest.approx((0, 100))


def test_orthographic_scale_and_depth():
    cam = Camera.look_at((0, 0, 50), (0, 0, 0), up=(0, 1, 0), width=100, height=100, projection="orthographic", ortho_height=10)
    assert project(cam, (5, 5, 0))[:2] == pytest.approx((100, 0))
    assert project(cam, (5, 5, -20))[:2] == pytest.approx((100, 0))  # no perspective shrink
    assert project(cam, (0, 0, -20))[2] == pytest.approx(70)


def test_orbit_places_the_eye():
    cam = Camera.orbit((1, 1, 1), yaw=90, pitch=0, distance=5)
    np.testing.assert_allclose(cam.eye, (1, 6, 1), atol=1e-12)
    top = Camera.orbit((0, 0, 0), yaw=-90, pitch=90, distance=5)
    np.testing.assert_allclose(top.eye, (0, 0, 5), atol=1e-12)
    # straight down: north (+y) is up in the image
    assert project(top, (0, 1, 0))[1] < project(top, (0, -1, 0))[1]


@pytest.mark.parametrize("view", list(VIEWS))
@pytest.mark.parametrize("projection", ["perspective", "orthographic"])
def test_fit_keeps_every_corner_in_the_image(view, projection):
    lo, hi = np.array([637_000.0, 851_000.0, 100.0]), np.array([638_000.0, 851_500.0, 180.0])
    cam = Camera.fit((lo, hi), view=view, width=320, height=200, projection=projection)
    for x in (lo[0], hi[0]):
        for y in (lo[1], hi[1]):
            for z in (lo[2], hi[2]):
                px, py, d = project(cam, (x, y, z))
                assert 0 <= px <= 320 and 0 <= py <= 200 and d > 0


def test_clip_range_encloses_bounds_and_handles_camera_inside():
    bounds = (np.zeros(3), np.ones(3) * 10)
    outside = Camera.look_at((30, 30, 30), (5, 5, 5))
    near, far = outside.clip_range(bounds)
    assert 0 < near < far and far >= math.dist((30, 30, 30), (0, 0, 0)) * 0.99
    inside = Camera.look_at((5, 5, 5), (6, 5, 5))
    near, far = inside.clip_range(bounds)
    assert 0 < near < 1e-3 and far >= 5


@pytest.mark.parametrize(
    "kwargs",
    [
        {"width": 0},
        {"height": 100_000},
        {"width": 12.5},
        {"fov": 0},
        {"fov": 180},
        {"fov": float("nan")},
        {"eye": (0, 0, float("nan"))},
        {"eye": (1, 2, 3), "target": (1, 2, 3)},
        {"up": (0, 0, 0)},
        {"projection": "fisheye"},
        {"projection": "orthographic"},
        {"near": 10, "far": 1},
        {"fov": True},  # was a 1 degree view
        {"near": "1"},  # these three were math's TypeError "must be real number, not str"
        {"far": "100"},
        {"projection": "orthographic", "ortho_height": "10"},
    ],
)
def test_impossible_cameras_raise_one_line_errors(kwargs):
    base = {"eye": (0, 0, 10), "target": (0, 0, 0), "up": (0, 1, 0)}
    base.update(kwargs)
    with pytest.raises(CameraError) as err:
        Camera(**base)
    assert "\n" not in str(err.value)


def test_up_parallel_to_view_is_repaired():
    cam = Camera.look_at((0, 0, 10), (0, 0, 0), up=(0, 0, 1), width=100, height=100)
    px, py, _ = project(cam, (0, 0, 0))
    assert (px, py) == pytest.approx((50, 50))


def test_ray_through_a_pixel_hits_the_projected_point():
    cam = Camera.look_at((3, -40, 12), (0, 0, 0), width=300, height=200)
    p = np.array([2.0, 5.0, -1.0])
    px, py, _ = project(cam, p)
    origin, direction = cam.ray(px, py)
    t = np.dot(p - origin, direction)
    np.testing.assert_allclose(origin + t * direction, p, atol=1e-9)
    for bad in ((np.nan, 0), (0, np.inf), ("a", 0), (None, 1)):  # NaN gave a NaN ray, "a" a TypeError
        with pytest.raises(CameraError, match=r"^ray: pixel coordinates must be finite numbers, got \("):
            cam.ray(*bad)
    assert np.isfinite(cam.ray(np.int64(3), 2)[1]).all()


def test_fit_refuses_an_unknown_projection():
    """``Camera.fit(bounds, projection='ortho')`` gave a perspective camera without a word."""
    with pytest.raises(CameraError, match=r"^camera projection must be 'perspective' or 'orthographic', got 'ortho'$"):
        Camera.fit((np.zeros(3), np.ones(3)), projection="ortho")
    assert Camera.fit((np.zeros(3), np.ones(3)), projection="perspective").projection == "perspective"


def test_fit_cloud_takes_a_view_given_as_a_numpy_pair():
    """``fit_cloud(cloud, view=np.array([30, 40]))`` raised numpy's "truth value of an array ...
    is ambiguous" (``view == "auto"`` compared element-wise); ``fit`` takes the same pair."""
    import gigapoint as gp

    rng = np.random.default_rng(0)
    cloud = gp.from_arrays(rng.random((500, 3)) * (10, 4, 2))
    cam = Camera.fit_cloud(cloud, view=np.array([30.0, 40.0]), width=64, height=48)
    assert cam == Camera.fit(cloud.bounds, view=(30.0, 40.0), width=64, height=48)


def test_an_unknown_keyword_names_the_constructor_and_what_it_takes():
    """``Camera.fit_cloud(cloud, foo=1)`` was Python's "Camera.__init__() got an unexpected keyword
    argument 'foo'"; fit's ortho_height (which its projection sets) "got multiple values"."""
    import gigapoint as gp

    cloud = gp.from_arrays(np.random.default_rng(0).random((50, 3)))
    box = (np.zeros(3), np.ones(3))
    fit = "view, width, height, fov, projection, margin, recenter, trim, up, near, far"
    for call, message in (
        (lambda: Camera.fit_cloud(cloud, foo=1), f"Camera.fit_cloud: unknown keyword foo (it takes cloud, {fit})"),
        (lambda: Camera.fit_cloud(cloud, points=np.zeros((3, 3))), f"Camera.fit_cloud: unknown keyword points (it takes cloud, {fit})"),
        (lambda: Camera.fit(box, projection="orthographic", ortho_height=3), ("Camera.fit: unknown keyword ortho_height (it takes bounds, "
         "view, width, height, fov, projection, margin, recenter, points, trim, up, near, far)")),
        (lambda: Camera.look_at((0, 0, 1), (0, 0, 0), zoom=2), ("Camera.look_at: unknown keyword zoom (it takes eye, target, up, fov, width, "
         "height, projection, ortho_height, near, far)")),
        (lambda: Camera.orbit((0, 0, 0), 0, 10, 5, dist=1), ("Camera.orbit: unknown keyword dist (it takes target, yaw, pitch, distance, up, "
         "fov, width, height, projection, ortho_height, near, far)")),
    ):  # fmt: skip
        with pytest.raises(CameraError) as err:
            call()
        assert str(err.value) == message
    assert Camera.fit_cloud(cloud, view="top", width=64, height=48, near=0.5, far=99.0, margin=1.2).near == 0.5  # what it takes: taken


def test_a_perspective_camera_refuses_an_ortho_height():
    """``Camera.look_at(eye, target, ortho_height=5)`` (perspective) was taken, the height ignored."""
    with pytest.raises(CameraError) as err:
        Camera.look_at((0, 0, 10), (0, 0, 0), ortho_height=5)
    assert str(err.value) == "camera ortho_height is for projection='orthographic'; a perspective camera's view is set by fov, got ortho_height 5"
    assert Camera.look_at((0, 0, 10), (0, 0, 0), ortho_height=None).projection == "perspective"


@pytest.mark.parametrize("kw", [{"yaw": "a"}, {"pitch": None}, {"distance": "5"}, {"yaw": np.nan}])
def test_orbit_refuses_non_numbers_in_one_line(kw):
    """``Camera.orbit(target, 'a', 10, 5)`` was a TypeError ("must be real number, not str"), a
    NaN yaw a camera eye that "must be finite"."""
    args = {"yaw": 30.0, "pitch": 10.0, "distance": 5.0} | kw
    name, value = next(iter(kw.items()))
    with pytest.raises(CameraError, match=rf"^orbit {name} must be a finite number, got {value!r}$"):
        Camera.orbit((0, 0, 0), **args)


@pytest.mark.parametrize("bounds", [((0, 0, 0),), (0, 1), None, "ab"])
def test_fit_refuses_bounds_that_are_not_a_min_max_pair(bounds):
    """``Camera.fit(((0, 0, 0),))`` was an IndexError ("tuple index out of range")."""
    with pytest.raises(CameraError, match=r"^camera bounds (must be \(min, max\), two points of three numbers|min must be three numbers), got "):
        Camera.fit(bounds)


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: Camera.look_at((0, 0, 10), (0, 0, 0), fov=0.0), "camera fov must be between 0.01 and 179 degrees, got 0"),
        (lambda: Camera.look_at((0, 0, 10), (0, 0, 0), near=10.0, far=1.0), "camera near (10) must be less than far (1)"),
        (lambda: Camera.look_at((0, 0, 10), (0, 0, 0), far=np.float64(-2.5)), "camera far must be > 0, got -2.5"),
        (lambda: Camera.look_at((0.0, 0.0, math.nan), (0, 0, 0)), "camera eye must be finite, got (0, 0, nan)"),
        (lambda: Camera.look_at((0, 0, 10), (0, 0, 0), projection="orthographic", ortho_height=0.0), "orthographic camera needs ortho_height > 0, got 0"),
        (lambda: Camera.orbit((0, 0, 0), 30, 10, -1e13), "orbit distance must be > 0, got -1e+13"),
        (lambda: Camera.fit((np.zeros(3), np.ones(3)), margin=0.0), "camera margin must be a number in (0, 1000] (1: the data touches the frame), got 0"),
        (lambda: Camera.top_down((np.zeros(3), np.ones(3)), 1e13), "gsd (ground sample distance) must be a number > 0 and at most 2e+12, got 1e+13"),
        (lambda: Camera.look_at((0, 0, 10), (0, 0, 0)).ray(np.float64(np.inf), 2.0), "ray: pixel coordinates must be finite numbers, got (inf, 2)"),
    ],
)  # fmt: skip
def test_camera_errors_spell_the_numbers_given_compactly(call, message):
    """A camera's errors say a number as ``errors.number_text`` does: 'got 0', 'got 1e+13', not
    'got 0.0', 'got 10000000000000.0' (nor numpy's 'np.float64(-2.5)')."""
    with pytest.raises(CameraError) as err:
        call()
    assert str(err.value) == message


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: Camera.look_at((1e200, 0, 0), (5, 5, 5)), "camera eye must lie within ±1e+30, got (1e+200, 0, 0)"),
        (lambda: Camera.look_at((0, 0, 0), (0, 0, 1), up=(0, 1e300, 0)), "camera up must lie within ±1e+30, got (0, 1e+300, 0)"),
        (lambda: Camera.orbit((5, 5, 5), 0, 30, 1e300), "orbit distance must be at most 1e+30, got 1e+300"),
        (lambda: Camera.fit(((0, 0, 0), (1e300, 1, 1))), "camera bounds max must lie within ±1e+30, got (1e+300, 1, 1)"),
        (lambda: Camera.look_at((0, 0, 10), (0, 0, 0), projection="orthographic", ortho_height=1e308), "orthographic camera needs ortho_height at most 1e+30, got 1e+308"),
    ],
)  # fmt: skip
def test_camera_refuses_coordinates_whose_float64_sums_overflow(call, message):
    """An eye at 1e200, an up of 1e300, an orbit 1e300 away drew a blank image with numpy's
    'overflow encountered in dot' warnings (a box of 1e300 said 'eye and target are the same
    point'): one line naming the vector instead."""
    with pytest.raises(CameraError) as err:
        call()
    assert str(err.value) == message


def test_camera_takes_a_whole_numpy_float32_size():
    """np.float32(64) was 'must be an integer', np.float64(64) taken: both are 64."""
    cam = Camera.look_at((0, 0, 10), (0, 0, 0), width=np.float32(64), height=np.float64(48))
    assert (cam.width, cam.height) == (64, 48) and type(cam.width) is int
