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
                                {"point_size": 6, "size_mode": "attenuated", "point_world_size": 40.0},
                                # runs longer than one vector write (8 pixels): written 8 at a time
                                {"point_size": 12}, {"point_size": 11, "point_shape": "round"}])  # fmt: skip
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


@pytest.mark.parametrize("kw", [{}, {"point_size": 7, "size_mode": "fixed"}, {"point_size": 5, "point_shape": "round", "size_mode": "fixed"}])
def test_two_threads_draw_bands_of_rows_like_one_thread(kw):
    """Splats on two threads: each thread writes its own band of rows straight into the frame
    (``band_plan``), drawing every batch that may reach them. Every batch that wins a pixel of a
    band is in that band's list, the bands cut the image where the work splits (not at the
    middle of the image when the points sit in its top), and the frame is the one thread's."""
    from gigapoint.backends.numba_cpu.backend import band_plan
    from gigapoint.render.passes import splat_for

    cloud = gp.demo(80_000, seed=5)
    lo, hi = (np.asarray(b) for b in cloud.bounds)
    cam = gp.Camera.orbit(tuple((lo + hi) / 2), -70.0, 25.0, float(np.linalg.norm(hi - lo)) * 0.3, width=320, height=200)
    s = gp.RenderSettings(backend="cpu", **kw)
    one = gp.render_frame(cloud, cam, s.replace(threads=1))
    two = gp.render_frame(cloud, cam, s.replace(threads=2))
    np.testing.assert_array_equal(two.visibility, one.visibility)
    np.testing.assert_array_equal(two.visibility, reference_visibility(cloud, cam, s))

    view = cam.view(cloud.bounds)
    draw = cloud.prepare(view, s)
    ids = draw.selection.ids
    rec = draw.points.batches[ids]
    splat = splat_for(s, cam, draw, view.near)
    starts, entries, bands = band_plan(draw.selection.matrices, rec["first"].astype(np.int64), rec["count"].astype(np.int64), draw.points.low, 320, 200, splat, 2)
    assert bands[0] == 0 and bands[-1] == 200 and 0 < bands[1] < 200
    rows, cols = np.nonzero(one.index >= 0)
    batch_of = np.searchsorted(rec["first"].astype(np.int64), one.index[rows, cols], side="right") - 1  # the selection entry of each winner
    for t in range(2):
        in_band = (rows >= bands[t]) & (rows < bands[t + 1])
        assert set(np.unique(batch_of[in_band]).tolist()) <= set(entries[starts[t] : starts[t + 1]].tolist())

    top = gp.from_arrays(np.column_stack([np.random.default_rng(1).random((20_000, 2)) * 100.0, np.zeros(20_000)]))
    # a flat plane seen level from above it: all its points lie in the image's bottom half
    look = gp.Camera.look_at((50.0, -60.0, 10.0), (50.0, 50.0, 10.0), up=(0, 0, 1), width=320, height=200, fov=60.0)
    view = look.view(top.bounds)
    draw = top.prepare(view, gp.RenderSettings(point_size=3, size_mode="fixed"))
    rec = draw.points.batches[draw.selection.ids]
    lit = np.nonzero(gp.render_frame(top, look, gp.RenderSettings(point_size=3, size_mode="fixed")).index >= 0)[0]
    _, _, bands = band_plan(draw.selection.matrices, rec["first"].astype(np.int64), rec["count"].astype(np.int64), draw.points.low, 320, 200,
                            splat_for(gp.RenderSettings(point_size=3, size_mode="fixed"), look, draw, view.near), 2)  # fmt: skip
    assert lit.min() > 100 and lit.min() < bands[1] < lit.max()  # the cut lies among them, not at the middle


def _band_rows_and_work_numpy(m, firsts, counts, low, height, reach, size, atten, n_samples, point_cost):
    """``band_plan``'s per-batch part as numpy formulated it before its kernel: the reference."""
    corners = np.array([[x, y, z, 1.0] for x in (0, 1024) for y in (0, 1024) for z in (0, 1024)])
    projected = np.einsum("kij,cj->kci", m, corners)
    w = projected[:, :, 2]
    seen = (w > 0).all(axis=1)
    ys = projected[:, :, 1] / np.where(w > 0, w, 1.0)
    top = np.where(seen, np.floor(ys.min(axis=1)) - reach - 1, 0).clip(0, height - 1).astype(np.int64)
    bottom = np.where(seen, np.floor(ys.max(axis=1)) + reach + 1, height - 1).clip(0, height - 1).astype(np.int64)
    picks = firsts[:, None] + (counts[:, None] * (np.arange(n_samples) + 0.5) / n_samples).astype(np.int64)
    words = low[np.minimum(picks, len(low) - 1)].astype(np.int64)
    cells = np.stack([words & 1023, (words >> 10) & 1023, (words >> 20) & 1023, np.full_like(words, 1)], axis=-1) + np.array([0.5, 0.5, 0.5, 0.0])
    sample = np.einsum("kij,ksj->ksi", m, cells)
    ahead = sample[:, :, 2] > 0
    row = np.where(ahead, sample[:, :, 1] / np.where(ahead, sample[:, :, 2], 1.0), -1.0)
    inside = ahead & (row >= 0) & (row < height)
    depth = np.maximum(sample[:, :, 3], 1e-9)
    sizes = np.floor(np.minimum(size, np.maximum(1.0, atten / depth))) if atten > 0 else np.full(row.shape, np.floor(size))
    weight = counts[:, None] / n_samples * (point_cost + sizes * sizes)
    work = np.bincount(row[inside].astype(np.int64), weight[inside], minlength=height)[:height]
    return top, bottom, work


@pytest.mark.parametrize("where", ["outside", "inside"])
@pytest.mark.parametrize("atten", [0.0, 40.0])
def test_band_plan_kernel_is_the_numpy_reference(where, atten):
    """The band plan's kernel (one loop over batches, corners and sample points) gives each
    batch the rows and the image the work per row that numpy's stacked products gave, from a
    camera outside the cloud and from one inside it (corners behind the eye: every row)."""
    from gigapoint.backends.numba_cpu.backend import BAND_POINT_COST, BAND_SAMPLES, _band_rows_and_work

    cloud = gp.demo(60_000, seed=3)
    lo, hi = (np.asarray(b) for b in cloud.bounds)
    centre = (lo + hi) / 2
    if where == "outside":
        cam = gp.Camera.orbit(tuple(centre), -70.0, 25.0, float(np.linalg.norm(hi - lo)), width=320, height=200)
    else:
        cam = gp.Camera.look_at(tuple(centre + [0, 0, 2.0]), tuple(centre + [50.0, 40.0, 0.0]), up=(0, 0, 1), width=320, height=200)
    view = cam.view(cloud.bounds)
    draw = cloud.prepare(view, gp.RenderSettings())
    rec = draw.points.batches[draw.selection.ids]
    m = draw.selection.matrices.astype(np.float64)
    args = (m, rec["first"].astype(np.int64), rec["count"].astype(np.int64), draw.points.low, 200, 3, 4.0, atten, BAND_SAMPLES, BAND_POINT_COST)
    top, bottom, work = _band_rows_and_work(*args)
    ref_top, ref_bottom, ref_work = _band_rows_and_work_numpy(*args)
    if where == "inside":
        assert (top == 0).any() and (bottom == 199).any() and ((top == 0) & (bottom == 199)).any()
    assert len(top) > 5 and work.sum() > 0
    np.testing.assert_array_equal(top, ref_top)
    np.testing.assert_array_equal(bottom, ref_bottom)
    np.testing.assert_allclose(work, ref_work, rtol=1e-9, atol=1e-9)
