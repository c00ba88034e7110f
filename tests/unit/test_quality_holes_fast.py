"""The banded hole-filling kernel against the plain-numpy reference, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.backends.numba_cpu.passes import fill_holes
from gigapoint.core.layout import EMPTY_PIXEL
from gigapoint.render.passes.holes import fill_holes_reference


def random_vis(width, height, empty_frac, seed):
    """Keys with a few depth layers (so points lie far behind their neighbours) and holes."""
    rng = np.random.default_rng(seed)
    n = width * height
    depth = rng.choice(np.array([1.0, 1.05, 2.0, 5.0], np.float32), n) * rng.uniform(0.98, 1.02, n).astype(np.float32)
    keys = (depth.view(np.uint32).astype(np.uint64) << np.uint64(32)) | rng.integers(0, 2**32, n, dtype=np.uint64)
    keys[rng.random(n) < empty_frac] = EMPTY_PIXEL
    return keys


SIZES = [(1, 1), (5, 3), (64, 7), (70, 9), (130, 41), (191, 2), (33, 128)]


@pytest.mark.parametrize("width,height", SIZES)
@pytest.mark.parametrize("level", [1, 2, 3])
@pytest.mark.parametrize("foveated", [False, True])
def test_random_scenes_equal_reference(width, height, level, foveated):
    for seed, empty_frac in ((width * height + level, 0.3), (7, 0.75)):
        vis = random_vis(width, height, empty_frac, seed)
        keep = vis.copy()
        want = fill_holes_reference(vis, width, height, level, foveated)
        got = fill_holes(vis, width, height, level, foveated)
        np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(vis, keep)  # out of place: the input is left alone
        assert not np.shares_memory(got, vis)
        if width * height >= 1000:  # the scenes do exercise both fills: holes and points seen through gaps
            assert ((want != vis) & (vis == EMPTY_PIXEL)).sum() > 0
            assert ((want != vis) & (vis != EMPTY_PIXEL)).sum() > 0


@pytest.mark.parametrize("level", [1, 2, 3])
@pytest.mark.parametrize("foveated", [False, True])
def test_patches_in_an_empty_frame_equal_reference(level, foveated):
    # points only in a few patches: most 64-pixel words and some whole rows see no point at all
    width, height = 300, 90
    vis = random_vis(width, height, 0.4, 11).reshape(height, width)
    keep = np.zeros((height, width), bool)
    for x0, y0, w, h in ((3, 2, 40, 20), (150, 30, 61, 25), (290, 60, 10, 30), (70, 88, 90, 2)):
        keep[y0 : y0 + h, x0 : x0 + w] = True
    vis = np.where(keep, vis, EMPTY_PIXEL).reshape(-1)
    want = fill_holes_reference(vis, width, height, level, foveated)
    assert ((want != vis) & (vis != EMPTY_PIXEL)).sum() > 0
    np.testing.assert_array_equal(fill_holes(vis, width, height, level, foveated), want)


@pytest.mark.parametrize("threads", [1, 2])
def test_band_split_does_not_matter(threads):
    import numba

    vis = random_vis(97, 61, 0.5, 3)
    want = fill_holes_reference(vis, 97, 61, 3, True)
    old = numba.get_num_threads()
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        np.testing.assert_array_equal(fill_holes(vis, 97, 61, 3, True), want)
    finally:
        numba.set_num_threads(old)


@pytest.fixture(scope="module")
def frame():
    cloud = gp.demo(200_000, seed=2)
    cam = gp.Camera.fit(cloud.bounds, view=(-60.0, 35.0), width=333, height=190, fov=40.0, margin=0.6)
    return cam, gp.render_frame(cloud, cam, gp.RenderSettings(backend="cpu")).visibility.reshape(-1)


@pytest.mark.parametrize("level,foveated", [(1, False), (2, False), (3, False), (2, True), (3, True)])
def test_rendered_frame_equals_reference(frame, level, foveated):
    cam, vis = frame
    want = fill_holes_reference(vis, cam.width, cam.height, level, foveated)
    assert (want != vis).sum() > 100
    np.testing.assert_array_equal(fill_holes(vis, cam.width, cam.height, level, foveated), want)


def test_render_with_fill_equals_reference_on_the_plain_frame(frame):
    cloud = gp.demo(200_000, seed=2)
    cam, vis = frame
    f = gp.render_frame(cloud, cam, gp.RenderSettings(backend="cpu", fill_holes=2))
    np.testing.assert_array_equal(f.visibility.reshape(-1), fill_holes_reference(vis, cam.width, cam.height, 2))
