"""Turntable / fly-through videos (issue #5)."""

from __future__ import annotations

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import GigapointError
from gigapoint.render.video import interpolate_cameras, render_flythrough, render_turntable, turntable_cameras


@pytest.fixture(scope="module")
def cloud():
    return gp.demo(30_000, seed=4)


def test_turntable_mp4_has_the_rendered_frames(cloud, tmp_path):
    iio = pytest.importorskip("imageio.v2")
    pytest.importorskip("imageio_ffmpeg")
    out = render_turntable(cloud, 6, tmp_path / "spin.mp4", width=96, height=64, settings=gp.RenderSettings(backend="cpu"))
    frames = [f for f in iio.get_reader(out)]
    assert len(frames) == 6 and frames[0].shape == (64, 96, 3)
    cams = turntable_cameras(cloud, 6, 96, 64)
    def blocks(img):  # 4x4 block means: the lossy codec's pixel noise averages out, the picture stays
        return img.astype(float).reshape(16, 4, 24, 4, 3).mean(axis=(1, 3))

    for i in (0, 3):
        expected = blocks(gp.render(cloud, cams[i], backend="cpu")[..., :3])
        assert np.abs(blocks(frames[i]) - expected).mean() < 2.0  # measured 0.7; another frame gives 5
        other = blocks(gp.render(cloud, cams[3 - i], backend="cpu")[..., :3])
        assert np.abs(blocks(frames[i]) - other).mean() > 2 * np.abs(blocks(frames[i]) - expected).mean()  # its own frame
    assert np.abs(frames[0].astype(float) - frames[3].astype(float)).mean() > 1.0  # the camera moved
    assert not list(tmp_path.glob(".spin.mp4.*"))  # no temporary left behind


def test_turntable_cameras_orbit_once(cloud):
    cams = turntable_cameras(cloud, 8, 64, 48)
    c = (np.asarray(cloud.bounds[0]) + np.asarray(cloud.bounds[1])) / 2
    d = [np.linalg.norm(np.subtract(k.eye, c)) for k in cams]
    np.testing.assert_allclose(d, d[0])
    np.testing.assert_allclose(cams[0].target, c)
    assert cams[0].eye != cams[4].eye


def test_flythrough_gif_and_errors(cloud, tmp_path):
    keys = turntable_cameras(cloud, 4, 48, 32)[:2]
    cams = interpolate_cameras(keys, 5)
    np.testing.assert_allclose(cams[0].eye, keys[0].eye)
    np.testing.assert_allclose(cams[-1].eye, keys[1].eye)
    out = render_flythrough(cloud, cams, tmp_path / "fly.gif", fps=10)
    from PIL import Image

    assert Image.open(out).n_frames == 5
    with pytest.raises(GigapointError, match="unsupported video type"):
        render_turntable(cloud, 3, tmp_path / "x.png")
    with pytest.raises(GigapointError, match="even"):
        render_turntable(cloud, 3, tmp_path / "x.mp4", width=33)
    with pytest.raises(GigapointError, match="positive integer"):
        render_turntable(cloud, 0, tmp_path / "x.mp4")
