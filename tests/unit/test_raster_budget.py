"""RenderSettings.max_points: a point budget for plain clouds (every k-th point of each batch)."""

import numpy as np
import pytest

import gigapoint as gp
from gigapoint import Camera, RenderSettings
from gigapoint.core.layout import EMPTY_PIXEL
from gigapoint.core.selection import select, subsample_step
from gigapoint.errors import GigapointError
from gigapoint.render.reference import projected_batches


def _reference_subsample(cloud, cam, step):
    """numpy reference: the plain reference render restricted to every step-th point of each batch."""
    w, h = cam.width, cam.height
    near, far = cam.clip_range(cloud.bounds)
    sel = select(cloud.batches, cam.screen_rows(), w, h, near, far)
    vis = np.full(w * h, EMPTY_PIXEL, np.uint64)
    for first, idx, x, y, d in projected_batches(cloud, sel, w, h, near, far):
        keep = idx % step == 0
        keys = (d[keep].view(np.uint32).astype(np.uint64) << np.uint64(32)) | (first + idx[keep]).astype(np.uint64)
        np.minimum.at(vis, y[keep] * w + x[keep], keys)
    return vis.reshape(h, w)


@pytest.mark.parametrize("view", ["iso", "top"])
def test_budget_draws_every_kth_point_exactly(demo_small, view):
    cam = Camera.fit(demo_small.bounds, view=view, width=160, height=90)
    budget = demo_small.n_points // 3
    frame = gp.render_frame(demo_small, cam, RenderSettings(max_points=budget, backend="cpu", size_mode="fixed"))  # one-pixel points
    counts = demo_small.batches["count"].astype(np.int64)
    step = subsample_step(counts, budget)
    assert step == 3 or step == 4
    assert frame.stats.points_processed == int(((counts + step - 1) // step).sum()) <= budget
    np.testing.assert_array_equal(frame.visibility, _reference_subsample(demo_small, cam, step))
    # the subsample still covers the scene: most pixels of the full render are covered
    full = gp.render_frame(demo_small, cam, RenderSettings(backend="cpu", size_mode="fixed"))
    covered_full = (full.visibility != EMPTY_PIXEL).sum()
    assert (frame.visibility != EMPTY_PIXEL).sum() > 0.8 * covered_full


def test_budget_close_up_gathers_every_precision_exactly():
    """A close-up's batches are drawn at 10, 20 and 30 bits: under a cap, rasterize gathers the
    medium and high words of every step-th point only where the batch's precision reads them;
    the numpy reference projects every point and keeps every step-th (the overviews above are
    all 10-bit)."""
    cloud = gp.demo(150_000, seed=1, scale=None)  # (its close-up below draws batches at all three precisions)
    lo, hi = cloud.bounds
    c = (lo + hi) / 2
    cam = Camera.look_at((c[0] - 120, c[1] - 120, c[2] + 40.0), tuple(c), fov=60, width=200, height=120)
    budget = cloud.n_points // 3
    settings = RenderSettings(max_points=budget, backend="cpu", size_mode="fixed")
    draw = cloud.prepare(cam.view(cloud.bounds), settings)
    assert {10, 20, 30} <= set(np.unique(draw.selection.bits).tolist())
    frame = gp.render_frame(cloud, cam, settings)
    np.testing.assert_array_equal(frame.visibility, _reference_subsample(cloud, cam, draw.step))


def test_budget_image_identical_with_one_and_two_threads(demo_small):
    cam = Camera.fit(demo_small.bounds, view="iso", width=200, height=120)
    a = gp.render_frame(demo_small, cam, RenderSettings(max_points=50_000, threads=1, backend="cpu"))
    b = gp.render_frame(demo_small, cam, RenderSettings(max_points=50_000, threads=2, backend="cpu"))
    np.testing.assert_array_equal(a.visibility, b.visibility)


def test_budget_with_splats_matches_full_render_of_the_subsample(demo_small):
    """Point sizes go through the same strided path: every drawn key belongs to the subsample."""
    cam = Camera.fit(demo_small.bounds, view="iso", width=160, height=90)
    frame = gp.render_frame(demo_small, cam, RenderSettings(max_points=40_000, point_size=3, backend="cpu"))
    step = subsample_step(demo_small.batches["count"].astype(np.int64), 40_000)
    idx = (frame.visibility[frame.visibility != EMPTY_PIXEL] & np.uint64(0xFFFFFFFF)).astype(np.int64)
    first = demo_small.batches["first"].astype(np.int64)[demo_small.batch_of(idx)]
    assert len(idx) > 0 and np.all((idx - first) % step == 0)


def test_subsample_step():
    counts = np.array([10240, 10240, 5000], np.int64)
    assert subsample_step(counts, 0) == 1
    assert subsample_step(counts, 10**9) == 1
    assert subsample_step(counts, 12_740) == 2
    step = subsample_step(counts, 8_000)
    assert ((counts + step - 1) // step).sum() <= 8_000 < ((counts + step - 2) // (step - 1)).sum()
    assert subsample_step(counts, 1) == 10240  # never below one point per batch


def test_max_points_is_validated():
    with pytest.raises(GigapointError, match="max_points"):
        RenderSettings(max_points=-1)
