"""Default framing (issue #17): the 'auto' view turns a long cloud across the image and frames
its points, not its bounding box."""

from __future__ import annotations

import math

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.render.camera import VIEWS, auto_view, sample_points
from gigapoint.viewer.state import OrbitState


def strip(angle_deg: float, length=400.0, width=100.0, n=40_000, seed=0):
    """A flat strip (length x width) turned by ``angle_deg`` around z."""
    rng = np.random.default_rng(seed)
    u, v = rng.random(n) * length, rng.random(n) * width
    a = math.radians(angle_deg)
    x, y = u * math.cos(a) - v * math.sin(a), u * math.sin(a) + v * math.cos(a)
    return gp.from_arrays(np.column_stack([x + 637_000.0, y + 851_000.0, rng.random(n)]))


def project(cam, xyz):
    p = np.c_[xyz, np.ones(len(xyz))] @ cam.screen_rows().T
    return p[:, 0] / p[:, 2], p[:, 1] / p[:, 2]


@pytest.mark.parametrize("angle", [0.0, 30.0, 90.0, 135.0])
def test_auto_turns_a_long_cloud_across_the_image(angle):
    cloud = strip(angle)
    pts = cloud.positions()
    cam = gp.Camera.fit_cloud(cloud, width=320, height=180)
    right, _, back = cam.basis()
    axis = np.array([math.cos(math.radians(angle)), math.sin(math.radians(angle)), 0.0])
    assert abs(right @ axis) > 0.999  # the long axis runs across the image
    if angle == 0.0:
        assert back[1] < 0  # seen from the south
    px, py = project(cam, pts)
    inside = (px >= 0) & (px <= 320) & (py >= 0) & (py <= 180)
    assert inside.mean() > 0.99  # (nearly) every point in the frame...
    assert (px.max() - px.min()) / 320 > 0.9  # ...spanning its width
    yaw, pitch = auto_view(pts, 16 / 9)
    assert VIEWS["iso"][1] <= pitch <= 55.0


def test_auto_keeps_iso_for_a_square_cloud_and_frames_the_data_not_the_box():
    rng = np.random.default_rng(2)
    square = gp.from_arrays(rng.random((20_000, 3)) * [100.0, 100.0, 5.0])
    assert auto_view(square.positions()) == VIEWS["iso"]
    box = gp.Camera.fit(square.bounds, view="iso", width=200, height=150)
    auto = gp.Camera.fit_cloud(square, width=200, height=150)
    np.testing.assert_allclose(np.subtract(auto.eye, auto.target) / np.linalg.norm(np.subtract(auto.eye, auto.target)),
                               np.subtract(box.eye, box.target) / np.linalg.norm(np.subtract(box.eye, box.target)), atol=1e-9)  # fmt: skip
    # a diagonal strip: its box is square and mostly empty; framing its points brings it closer
    diag = strip(45.0)
    by_box = gp.Camera.fit(diag.bounds, view="auto", width=200, height=150)
    by_points = gp.Camera.fit_cloud(diag, width=200, height=150)
    assert np.linalg.norm(np.subtract(by_points.eye, by_points.target)) < 0.9 * np.linalg.norm(np.subtract(by_box.eye, by_box.target))


def test_sample_points_are_spread_over_the_cloud():
    cloud = gp.demo(100_000)
    pts = sample_points(cloud, n=5_000)
    lo, hi = (np.asarray(b) for b in cloud.bounds)
    assert 4_000 <= len(pts) <= 12_000
    assert np.all(pts >= lo - 1e-6) and np.all(pts <= hi + 1e-6)
    assert np.all(pts.max(axis=0) - pts.min(axis=0) > 0.9 * (hi - lo))


def test_the_named_views_are_unchanged():
    """'iso' and the others frame the box exactly as before (the bit-exact tests and benchmarks use them)."""
    lo, hi = np.array([0.0, 0.0, 0.0]), np.array([100.0, 40.0, 10.0])
    cam = gp.Camera.fit((lo, hi), view="iso", width=320, height=200)
    back = np.subtract(cam.eye, cam.target)
    assert math.degrees(math.atan2(back[1], back[0])) == pytest.approx(-135.0)
    assert math.degrees(math.asin(back[2] / np.linalg.norm(back))) == pytest.approx(35.264)


def test_the_viewers_default_state_is_the_auto_view():
    cloud = strip(20.0)
    state = OrbitState.fit(cloud.bounds, view="auto", width=320, height=180, points=sample_points(cloud))
    cam = gp.Camera.fit_cloud(cloud, width=320, height=180)
    np.testing.assert_allclose(state.camera(320, 180).eye, cam.eye, rtol=0, atol=1e-6)
    assert state.yaw == pytest.approx(20.0 - 90.0, abs=0.5)


def test_the_viewer_opens_on_the_auto_view():
    from gigapoint.viewer.session import ViewerCore

    cloud = strip(0.0)
    core = ViewerCore(cloud)
    try:
        state = core.default_state(320, 180)
        assert state.yaw == pytest.approx(-90.0, abs=0.5) and state.pitch > VIEWS["iso"][1] - 1e-9
        iso = core.default_state(320, 180, view="iso")
        assert iso.yaw == pytest.approx(-135.0)
    finally:
        core.close_all()


@pytest.mark.parametrize("projection", ["perspective", "orthographic"])
def test_a_small_cloud_far_from_the_origin_is_framed_as_at_the_origin(projection):
    """The fitted camera kept at least 1e-6 of the coordinates' size as the cloud's radius: a
    cloud 0.1 m across at 1e9 (or 100 m across at 1e11) was framed from ~1000x too far, a few
    pixels in the middle. float64 places 1e-16 of it: the same image as at the origin; a single
    point is still drawn wherever it is."""
    rng = np.random.default_rng(1)
    xyz = rng.random((20_000, 3)) * [100, 100, 10]
    rgb = rng.integers(0, 255, (20_000, 3)).astype(np.uint8)

    def image(points):
        cloud = gp.from_arrays(points, rgb=rgb[: len(points)])
        return gp.render(cloud, gp.Camera.fit_cloud(cloud, width=160, height=120, view="top", projection=projection), size_mode="fixed")

    at_origin = image(xyz)
    for offset, spread in ((1e9, 1e-3), (1e11, 1.0), (1e11, 1e-3)):  # 0.1 m at 1e11: 1e-12 of it
        far = image(xyz * spread + offset)
        assert (far == at_origin).all(axis=-1).mean() > 0.97, (offset, spread)
    for p in ([0.0, 0, 0], [1e6, 1e6, 1e6], [9e11, -9e11, 5], [1e-9, 0, 0]):
        one = gp.from_arrays(np.array([p]))
        for view in ("auto", "top"):
            frame = gp.render_frame(one, gp.Camera.fit_cloud(one, width=32, height=24, projection=projection, view=view))
            assert frame.stats.visible_pixels > 0, (p, view)


@pytest.mark.filterwarnings("error")  # ("no point is in view of the camera")
@pytest.mark.parametrize("projection", ["perspective", "orthographic"])
@pytest.mark.parametrize("view", ["top", "side", "front", "iso", "auto", (0.0, 45.0)])
@pytest.mark.parametrize("where", [(3.0, 4.0, 5.0), (50.0, 50.0, 10.0)])
def test_a_single_point_of_a_las_file_is_drawn_at_the_images_centre(tmp_path, view, projection, where):
    """A one-point (or all-identical) cloud was framed 1e-6 of its coordinates across, finer than a
    LAS cloud's batch grid (float32 cells) resolves: a blank image and "no point is in view"
    (orthographic 'auto': the point at row 0). It is framed as a cube 1 unit from its centre."""
    import laspy

    header = laspy.LasHeader(point_format=0, version="1.2")
    header.scales, header.offsets = np.array([0.01] * 3), np.zeros(3)
    las = laspy.LasData(header)
    las.x, las.y, las.z = ([v] for v in where)
    las.write(str(tmp_path / "one.las"))
    cloud = gp.open(tmp_path / "one.las")
    cam = gp.Camera.fit_cloud(cloud, view=view, width=64, height=36, projection=projection)
    lit = np.argwhere(gp.render_frame(cloud, cam).index >= 0)
    assert len(lit) == 1 and np.abs(lit[0] + 0.5 - (18, 32)).max() <= 1, lit
