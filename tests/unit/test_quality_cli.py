"""`gigapoint render` quality options and --turntable (issue #5)."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

import gigapoint as gp
from gigapoint.cli import main


@pytest.fixture(scope="module")
def npy(tmp_path_factory):
    xyz = gp.demo_arrays(20_000, seed=11)[0]
    path = tmp_path_factory.mktemp("cli") / "scene.npy"
    np.save(path, xyz)
    return path


def test_render_with_quality_options_matches_the_api(npy, tmp_path):
    out = tmp_path / "q.png"
    args = ["render", str(npy), "-o", str(out), "-W", "96", "-H", "64", "--backend", "cpu", "--edl", "--fill-holes", "1", "--hqs",
            "--point-size", "2", "--splat-softness", "2", "--color-mode", "elevation", "--colormap", "turbo", "--elevation-range", "-5,30"]  # fmt: skip
    assert main(args) == 0
    cloud = gp.open(npy)
    cam = gp.Camera.fit(cloud.bounds, view="iso", width=96, height=64)
    s = gp.RenderSettings(
        backend="cpu",
        edl=True,
        fill_holes=1,
        hqs=True,
        point_size=2,
        splat_softness=2.0,
        color_mode="elevation",
        colormap="turbo",
        elevation_range=(-5, 30),
    )
    np.testing.assert_array_equal(np.asarray(Image.open(out)), gp.render(cloud, cam, s))


def test_bad_quality_options_are_one_line_errors(npy, tmp_path, capsys):
    for extra in (["--fill-holes", "7"], ["--color-mode", "rainbow"], ["--elevation-range", "1"], ["--supersample", "3"]):
        assert main(["render", str(npy), "-o", str(tmp_path / "x.png"), "-W", "32", "-H", "32", *extra]) == 1
        err = capsys.readouterr().err.strip()
        assert err.startswith("error:") and "\n" not in err
    assert not (tmp_path / "x.png").exists()


def test_turntable_option_writes_a_video(npy, tmp_path):
    pytest.importorskip("imageio_ffmpeg")
    import imageio.v2 as iio

    out = tmp_path / "spin.mp4"
    assert main(["render", str(npy), "-o", str(out), "-W", "64", "-H", "48", "--turntable", "4", "--backend", "cpu"]) == 0
    assert len([f for f in iio.get_reader(out)]) == 4
    assert main(["render", str(npy), "-o", str(tmp_path / "spin.png"), "--turntable", "4"]) == 1
