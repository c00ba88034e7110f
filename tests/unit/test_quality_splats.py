"""Point size and shape (issue #5): footprints written with the point's own depth."""

from __future__ import annotations

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.render.reference import reference_visibility
from gigapoint.render.splats import footprint

W, H = 48, 32


def top_camera(width=W, height=H, z=50.0):
    c = (width / 2, height / 2)
    return gp.Camera.look_at(
        (c[0], c[1], z), (c[0], c[1], 0.0), up=(0, 1, 0), width=width, height=height, projection="orthographic", ortho_height=float(height)
    )


def at(x, row, z):
    """World position of the centre of pixel (x, row) under top_camera, at height z."""
    return (x + 0.5, H - row - 0.5, z)


def test_footprints():
    assert footprint(1, "square").tolist() == [[0, 0, 1]]
    sq = footprint(4, "square")
    assert len(sq) == 16 and sq[:, 0].min() == -1 and sq[:, 0].max() == 2
    assert sorted(sq[:, 2]) == list(sq[:, 2])
    rd = footprint(5, "round")
    assert len(rd) == 21 and [0, 0, 1] in rd.tolist() and not any((abs(dx) == 2 and abs(dy) == 2) for dx, dy, _ in rd)


def test_a_large_far_splat_does_not_cover_a_near_point():
    xyz = np.array([at(20, 10, 10.0), at(22, 10, -30.0), at(40, 25, 0.0)])
    rgba = np.array([[255, 0, 0, 255], [0, 0, 255, 255], [0, 255, 0, 255]], np.uint8)
    cloud = gp.from_arrays(xyz, rgba, name="splats")
    f = gp.render_frame(cloud, top_camera(), gp.RenderSettings(backend="cpu", point_size=5))
    img = f.image
    near_idx = int(np.flatnonzero(cloud.rgba[:, 0] == 255)[0])
    far_idx = int(np.flatnonzero(cloud.rgba[:, 2] == 255)[0])
    idx = f.index
    # near (red) 5x5 around (20, 10); far (blue) 5x5 around (22, 10): overlap columns 20..22 stay red
    assert np.all(idx[8:13, 18:23] == near_idx)
    assert np.all(idx[8:13, 23:25] == far_idx)
    assert tuple(img[10, 20]) == (255, 0, 0, 255)
    assert (idx == far_idx).sum() == 10
    assert (idx >= 0).sum() == 25 + 10 + 25
    # the near point's own pixel is red whatever the draw order or size
    for size in (3, 7, 9):
        f2 = gp.render_frame(cloud, top_camera(), gp.RenderSettings(backend="cpu", point_size=size, point_shape="round"))
        assert f2.index[10, 20] == near_idx


@pytest.mark.parametrize("kw", [{"point_size": 3}, {"point_size": 4, "point_shape": "round"}, {"point_size": 2},
                                {"point_size": 6, "size_mode": "attenuated", "point_world_size": 40.0}])  # fmt: skip
def test_kernel_equals_reference(kw):
    cloud = gp.demo(5_000, seed=9)
    cam = gp.Camera.fit(cloud.bounds, view=(-40.0, 35.0), width=150, height=90, fov=45.0, margin=0.7)
    s = gp.RenderSettings(backend="cpu", **kw)
    f = gp.render_frame(cloud, cam, s)
    ref = reference_visibility(cloud, cam, s)
    np.testing.assert_array_equal(f.visibility, ref)
    plain = gp.render_frame(cloud, cam, gp.RenderSettings(backend="cpu", size_mode="fixed"))  # one-pixel points
    assert (f.index >= 0).sum() > 1.5 * (plain.index >= 0).sum()  # bigger points cover more
    for threads in (1, 2):
        np.testing.assert_array_equal(gp.render_frame(cloud, cam, s.replace(threads=threads)).visibility, ref)


def test_attenuated_points_shrink_with_distance():
    # two points of 2 m world size, one 10 m and one 40 m from the camera
    cam = gp.Camera.look_at((0.0, -1.0, 0.0), (0.0, 0.0, 0.0), up=(0, 0, 1), width=101, height=101, fov=90.0)
    xyz = np.array([[-2.0, 9.0, 0.0], [8.0, 39.0, 0.0]])
    cloud = gp.from_arrays(xyz, name="two")
    f = gp.render_frame(cloud, cam, gp.RenderSettings(backend="cpu", point_size=32, size_mode="attenuated", point_world_size=2.0))
    counts = [(f.index == i).sum() for i in range(2)]
    near = int(np.argmin(cloud.positions()[:, 1]))
    assert counts[near] > 4 * counts[1 - near] > 0
