"""Batch selection: the compiled box test and matrix composition against plain numpy."""

from __future__ import annotations

import numpy as np

from gigapoint.core.layout import WORD_BITS
from gigapoint.core.selection import batch_matrices, visible_and_size
from gigapoint.render import Camera


def _boxes(rng, k):
    lo = rng.uniform(-200.0, 200.0, (k, 3))
    return lo, lo + rng.uniform(0.1, 60.0, (k, 3))


def _corners(lo, hi):
    c = np.arange(8)
    bits = np.stack([(c >> 2) & 1, (c >> 1) & 1, c & 1], axis=1)  # (8, 3)
    return lo[:, None, :] + bits[None] * (hi - lo)[:, None, :]  # (k, 8, 3)


def test_visible_and_size_matches_numpy_corner_projection():
    rng = np.random.default_rng(4)
    cam = Camera.look_at((0.0, -150.0, 40.0), (0.0, 0.0, 0.0), width=320, height=200, fov=60)
    near, far = 1.0, 300.0
    lo, hi = _boxes(rng, 4000)  # around, behind, beside and across the near plane of the camera
    rows = cam.screen_rows()
    visible, size = visible_and_size(rows, lo, hi, cam.width, cam.height, near, far)

    p = np.concatenate([_corners(lo, hi), np.ones((len(lo), 8, 1))], axis=2) @ rows.T  # (k, 8, 4): x', y', w, depth
    x, y, w, d = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    beyond = [x < 0, x > cam.width * w, y < 0, y > cam.height * w, d < near, d > far]
    ref_visible = ~np.any([b.all(axis=1) for b in beyond], axis=0)
    in_front = ((w > 0) & (d >= near)).all(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        px, py = x / w, y / w
    ref_size = np.where(in_front, np.maximum(np.ptp(px, axis=1), np.ptp(py, axis=1)), np.inf)

    np.testing.assert_array_equal(visible, ref_visible)
    assert 0 < visible.sum() < len(lo) and 0 < in_front.sum() < len(lo)  # both outcomes occur
    np.testing.assert_allclose(size[in_front], ref_size[in_front], rtol=1e-12)
    assert np.isinf(size[~in_front]).all()


def test_visible_and_size_reads_structured_fields_in_place():
    rng = np.random.default_rng(5)
    lo, hi = _boxes(rng, 50)
    rec = np.zeros(50, [("first", "<u8"), ("bbox_min", "<f8", (3,)), ("bbox_max", "<f8", (3,))])
    rec["bbox_min"], rec["bbox_max"] = lo, hi
    cam = Camera.look_at((0.0, -150.0, 40.0), (0.0, 0.0, 0.0), width=320, height=200)
    a = visible_and_size(cam.screen_rows(), rec["bbox_min"], rec["bbox_max"], 320, 200, 1.0, 300.0)
    b = visible_and_size(cam.screen_rows(), lo, hi, 320, 200, 1.0, 300.0)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])


def test_batch_matrices_map_the_grid_cube_onto_the_box():
    """Grid point g (0..1024 per axis) of batch k lands where the world point lo + g/1024 * (hi - lo) does."""
    rng = np.random.default_rng(6)
    lo = rng.uniform([-100.0, -50.0, -20.0], [100.0, 150.0, 20.0], (300, 3)) + [500_000.0, 500_000.0, 0.0]  # in front of the camera, UTM-sized:
    hi = lo + rng.uniform(0.1, 60.0, (300, 3))  # composed in float64 relative to each box
    cam = Camera.look_at((500_000.0, 499_850.0, 40.0), (500_000.0, 500_000.0, 0.0), width=320, height=200)
    rows = cam.screen_rows()
    ids = np.array([3, 0, 299, 17])
    m = batch_matrices(rows, lo, hi, ids)
    assert m.dtype == np.float32 and m.shape == (4, 4, 4)
    np.testing.assert_array_equal(batch_matrices(rows, lo, hi)[ids], m)  # default: every box
    g = rng.uniform(0, 1 << WORD_BITS, (4, 3))
    world = lo[ids] + g / (1 << WORD_BITS) * (hi - lo)[ids]
    want = np.c_[world, np.ones(4)] @ rows.T
    got = np.einsum("kij,kj->ki", m.astype(np.float64), np.c_[g, np.ones(4)])
    assert (want[:, 2] > 0).all()
    np.testing.assert_allclose(got[:, :2] / got[:, 2:3], want[:, :2] / want[:, 2:3], rtol=0, atol=0.01)  # pixels
    np.testing.assert_allclose(got[:, 2:], want[:, 2:], rtol=1e-5)  # w and depth
