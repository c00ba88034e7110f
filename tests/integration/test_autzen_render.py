"""The shared real sample: UTM coordinates render without jitter and match a reference image."""

import os
from pathlib import Path

import laspy
import numpy as np
import pytest
from PIL import Image

import gigapoint as gp
from gigapoint import Camera, RenderSettings

REFERENCE_DIR = Path(__file__).resolve().parents[1] / "reference_images"


@pytest.fixture(scope="module")
def autzen(autzen_path):
    return gp.open(autzen_path)


@pytest.fixture(scope="module")
def autzen_original(autzen_path):
    las = laspy.read(autzen_path)
    return np.column_stack([las.x, las.y, las.z])


def test_positions_survive_quantization(autzen, autzen_original):
    assert autzen.n_points == len(autzen_original) == 110_000
    lo, hi = autzen.bounds
    np.testing.assert_allclose(lo, autzen_original.min(axis=0))
    np.testing.assert_allclose(hi, autzen_original.max(axis=0))
    back = autzen.positions()
    # the file stores centimetre integers: every decoded point is within micrometres of one,
    # and the multiset of those integers is exactly the file's
    grid = np.round(back * 100)
    assert np.abs(back * 100 - grid).max() < 1e-3  # 30-bit batch-relative: 10 µm, not centimetres
    a = np.round(autzen_original * 100)
    np.testing.assert_array_equal(a[np.lexsort(a.T)], grid[np.lexsort(grid.T)])


def _project64(cam, xyz):
    p = np.c_[xyz, np.ones(len(xyz))] @ cam.screen_rows().T
    return p[:, 0] / p[:, 2], p[:, 1] / p[:, 2], p[:, 3]


@pytest.mark.parametrize("bits_mode", ["adaptive", "full"])
def test_no_jitter_far_from_the_origin(autzen, bits_mode):
    """Every drawn pixel holds a point whose float64 projection lands in (or next to) it."""
    lo, hi = autzen.bounds
    centre = (lo + hi) / 2
    # a close-up 40 m from the middle of the scan: 637 km from the origin in x
    cam = Camera.look_at(centre + [-30, -25, 15], centre, width=400, height=300, fov=50)
    settings = RenderSettings(adaptive_precision=(bits_mode == "adaptive"), size_mode="fixed")  # one-pixel points
    frame = gp.render_frame(autzen, cam, settings)
    rows, cols = np.nonzero(frame.index >= 0)
    assert len(rows) > 1000
    px, py, depth = _project64(cam, autzen.positions(frame.index[rows, cols]))
    off = np.maximum(np.abs(np.floor(px) - cols), np.abs(np.floor(py) - rows))
    if bits_mode == "full":
        assert (off == 0).mean() > 0.999  # float32 rounding only at pixel edges
    else:
        assert (off <= 1).mean() > 0.999 and (off == 0).mean() > 0.9
    np.testing.assert_allclose(frame.depth[rows, cols], depth, rtol=1e-4)


def _compare_reference(image, name, tolerance=2.0):
    path = REFERENCE_DIR / name
    if os.environ.get("GIGAPOINT_REGEN") == "1" or not path.exists():
        if not os.environ.get("GIGAPOINT_REGEN") and os.environ.get("CI"):
            pytest.fail(f"reference image {path} missing (regenerate with GIGAPOINT_REGEN=1)")
        REFERENCE_DIR.mkdir(exist_ok=True)
        Image.fromarray(image).save(path)
    ref = np.asarray(Image.open(path).convert("RGBA")).astype(np.int16)
    assert ref.shape == image.shape
    diff = np.abs(ref - image.astype(np.int16))
    assert diff.mean() < tolerance, f"{name}: mean difference {diff.mean():.2f} over tolerance"
    assert (diff.max(axis=2) > 40).mean() < 0.01


def test_autzen_matches_reference_image(autzen):
    image = gp.render(autzen, Camera.fit(autzen.bounds, view="iso", width=320, height=180), size_mode="fixed")  # the exact render
    _compare_reference(image, "core_autzen_iso.png")


def test_demo_matches_reference_image(demo_small):
    image = gp.render(demo_small, Camera.fit(demo_small.bounds, view="iso", width=320, height=180), size_mode="fixed")
    _compare_reference(image, "core_demo_iso.png")


def test_a_picked_point_reads_as_the_file_wrote_it_in_every_kind_of_cloud(autzen_path, autzen_original, tmp_path):
    """``point_info`` of a picked point: its position rounded to the file's centimetres and its
    LAS attributes, from the plain cloud, the progressive octree and converted octrees alike
    (the octrees gave 637174.3300006103, and a converted octree's pick no attributes)."""
    las = laspy.read(autzen_path)
    by_position = {tuple(np.round(p * 100).astype(np.int64)): i for i, p in enumerate(autzen_original)}
    progressive = gp.open(autzen_path, progressive=True)
    assert progressive.wait(120)
    gp.convert(autzen_path, tmp_path / "g")
    gp.convert(autzen_path, tmp_path / "p", format="potree")
    plain = gp.open(autzen_path)
    cam = Camera.fit_cloud(plain, width=160, height=100)
    for cloud in (plain, progressive, gp.open(tmp_path / "g"), gp.open(tmp_path / "p")):
        frame = gp.render_frame(cloud, cam, RenderSettings(size_mode="fixed", lod_threshold_px=0.0))  # every leaf: no voxel picked
        picked = frame.index[frame.index >= 0][::97][:40]
        assert len(picked) == 40
        for index in picked.tolist():
            info = frame.point_info(index)
            pos = info["position"]
            assert pos == [round(v, 2) for v in pos], (type(cloud).__name__, pos)
            i = by_position[tuple(np.round(np.array(pos) * 100).astype(np.int64))]  # one of the file's points, exactly
            assert info["intensity"] == int(las.intensity[i]) and info["classification"] == int(las.classification[i]), type(cloud).__name__
