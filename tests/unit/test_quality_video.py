"""Turntable / fly-through videos (issue #5)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import GigapointError
from gigapoint.render.camera import VIEWS
from gigapoint.render.video import circular_mean, interpolate_cameras, render_flythrough, render_turntable, turntable_cameras

AUTZEN = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "autzen_trim.laz"


@pytest.fixture(scope="module")
def cloud():
    return gp.demo(30_000, seed=4)


@pytest.mark.parametrize("suffix", [".mp4", ".webm", ".mkv", ".mov", ".avi"])
def test_turntable_video_has_the_rendered_frames(cloud, tmp_path, suffix):
    """Every video suffix the CLI offers (.webm failed each time: imageio's default H.264 is not
    allowed in WebM, which gets VP9 now)."""
    iio = pytest.importorskip("imageio.v2")
    pytest.importorskip("imageio_ffmpeg")
    out = render_turntable(cloud, 6, tmp_path / f"spin{suffix}", width=96, height=64, settings=gp.RenderSettings(backend="cpu"))
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
    assert not list(tmp_path.glob(f".spin{suffix}.*"))  # no temporary left behind


_FULL = """
import resource, sys
from gigapoint.cli import main
resource.setrlimit(resource.RLIMIT_FSIZE, (60_000, 60_000))  # files stop at 60 kB: a full disk for ffmpeg
sys.exit(main(["render", sys.argv[1], "-o", sys.argv[2], "--turntable", "30", "--width", "320", "--height", "240"]))
"""


@pytest.mark.parametrize("suffix", [".mp4", ".webm"])
def test_a_video_ffmpeg_could_not_write_whole_is_an_error_and_no_file(tmp_path, suffix):
    """imageio-ffmpeg does not look at ffmpeg's exit status: an .mp4 cut short by a full disk (no
    index: unreadable) was reported written, with ffmpeg's errors over many lines."""
    import subprocess
    import sys

    pytest.importorskip("imageio_ffmpeg")
    out = tmp_path / f"spin{suffix}"
    proc = subprocess.run([sys.executable, "-c", _FULL, str(AUTZEN), str(out)], capture_output=True, text=True, timeout=300)
    err = proc.stderr.strip()
    assert proc.returncode == 1 and "\n" not in err, err
    assert err.startswith(f"error: {out}: ffmpeg could not write the video (") and ("of 30 frames" in err or "no readable video" in err), err
    assert list(tmp_path.iterdir()) == []  # neither the cut video nor its temporary


def test_the_orbits_running_mean_is_the_windows_mean_in_linear_memory():
    """Targets and distances glide as means over an eighth of the orbit, wrapping around: the
    same numbers as gathering each frame's window, without the n * n / 8 of them (a 100 000-frame
    turntable ended in "out of memory")."""
    import tracemalloc

    rng = np.random.default_rng(1)
    for n, half in ((1, 0), (7, 3), (50, 3), (400, 25)):
        v = rng.random((n, 3)) * 100 + [637000.0, 4850000.0, 30.0]  # UTM-sized targets
        ring = (np.arange(-half, half + 1)[:, None] + np.arange(n)[None, :]) % n
        np.testing.assert_allclose(circular_mean(v, half), v[ring].mean(axis=0), rtol=0, atol=1e-8)
        np.testing.assert_allclose(circular_mean(v[:, 0], half), v[ring, 0].mean(axis=0), rtol=0, atol=1e-8)
    n = 200_000
    v = rng.random((n, 3))
    tracemalloc.start()
    smooth = circular_mean(v, n // 16)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 40 * v.nbytes  # measured ~5x; the windows were 12 500 x 200 000 x 3 numbers (60 GB)
    assert np.allclose(smooth, v.mean(axis=0), atol=0.01)  # an eighth of the orbit: near the mean of uniform numbers


@pytest.mark.parametrize("n_frames", [0, -3, 2.5, True, 100_001, 10**8])
def test_a_turntable_of_no_or_too_many_frames_is_refused_at_once(cloud, n_frames):
    """10**8 frames ran out of memory seconds in (and would have been framed for days)."""
    with pytest.raises(gp.GigapointError, match=f"turntable: number of frames must be an integer from 1 to 100,000, got {n_frames!r}"):
        turntable_cameras(cloud, n_frames, 64, 48)


def test_turntable_cameras_orbit_once(cloud):
    cams = turntable_cameras(cloud, 8, 64, 48, start_yaw=10.0, pitch=VIEWS["iso"][1])  # a level orbit
    back = np.array([np.subtract(k.eye, k.target) for k in cams])
    yaws = np.degrees(np.arctan2(back[:, 1], back[:, 0]))
    np.testing.assert_allclose(np.remainder(yaws - 10.0 - 45.0 * np.arange(8) + 180.0, 360.0) - 180.0, 0.0, atol=1e-9)
    np.testing.assert_allclose(np.degrees(np.arcsin(back[:, 2] / np.linalg.norm(back, axis=1))), VIEWS["iso"][1])
    lo, hi = (np.asarray(b) for b in cloud.bounds)
    assert all(np.linalg.norm(np.subtract(k.target, (lo + hi) / 2)) < np.linalg.norm(hi - lo) / 4 for k in cams)  # at the cloud
    assert cams[0].eye != cams[4].eye


def test_turntable_fills_the_frame_with_a_long_cloud():
    """A flat strip 4 x 1: the orbit starts side-on (the strip across the image) and every frame
    is framed on its own, so the strip fills the frame end-on too (one distance for all frames
    left it at a sliver); nothing leaves the frame."""
    rng = np.random.default_rng(3)
    xyz = np.column_stack([rng.random(40_000) * 400.0, rng.random(40_000) * 100.0, rng.random(40_000)])
    strip = gp.from_arrays(xyz)
    s = gp.RenderSettings(backend="cpu", point_size=3)
    cams = turntable_cameras(strip, 8, 160, 90)
    back = np.subtract(cams[0].eye, cams[0].target)
    assert abs(back[0]) < 1e-3 * np.linalg.norm(back)  # side-on: looking along y, the strip's x across
    for cam in cams:
        p = np.c_[xyz, np.ones(len(xyz))] @ cam.screen_rows().T
        px, py = p[:, 0] / p[:, 2], p[:, 1] / p[:, 2]
        assert ((px < 0) | (px > 160) | (py < 0) | (py > 90)).mean() < 0.02  # (nearly) every point in the frame
        rows, cols = np.nonzero(gp.render_frame(strip, cam, s).index >= 0)
        assert max((cols.max() - cols.min()) / 160, (rows.max() - rows.min()) / 90) > 0.8  # spanning its width or height


def test_turntable_pitch_adapts_so_real_data_fills_every_frame():
    """autzen_trim (a flat trapezoid with a sparse river): at iso's pitch its least-filled frame
    held 26 % of the image (mean 35 %); each yaw's own pitch (``fill_pitches``) keeps every
    frame's footprint, the lit pixels closed over small gaps, at 35 % or more; the pitch glides."""
    ndimage = pytest.importorskip("scipy.ndimage")
    from gigapoint.render.video import TURNTABLE_PITCHES

    autzen = gp.open(AUTZEN)
    level = turntable_cameras(autzen, 36, 320, 180, pitch=VIEWS["iso"][1])
    cams = turntable_cameras(autzen, 36, 320, 180)
    disc = np.add.outer(np.arange(-2, 3) ** 2, np.arange(-2, 3) ** 2) <= 4

    def footprint(cam):  # the share of the frame: lit pixels closed by a 2-pixel disc (8 px at 1280x720)
        lit = np.pad(~gp.render_frame(autzen, cam, gp.RenderSettings(backend="cpu")).empty, 3)
        return ndimage.binary_closing(lit, structure=disc)[3:-3, 3:-3].mean()

    shares = np.array([footprint(c) for c in cams])
    assert shares.min() >= 0.35 and min(footprint(c) for c in level) < 0.30, shares
    pitch = np.array([_pitch(k) for k in cams])
    assert TURNTABLE_PITCHES[0] - 1e-9 <= pitch.min() and pitch.max() <= TURNTABLE_PITCHES[1] + 1e-9
    assert pitch.max() - pitch.min() > 15  # it does adapt
    assert np.abs(np.diff(np.r_[pitch, pitch[0]])).max() <= 8  # in 10 degrees of yaw: a glide, not a jump
    np.testing.assert_allclose(pitch[::3], [_pitch(k) for k in turntable_cameras(autzen, 12, 320, 180)], atol=1e-9)  # any frame count


def _pitch(camera) -> float:
    back = np.subtract(camera.eye, camera.target)
    return float(np.degrees(np.arcsin(back[2] / np.linalg.norm(back))))


def test_a_flythrough_keeps_its_key_cameras_projection_and_glides_their_fov_and_height():
    """An orthographic fly-through was drawn in perspective (the keys' projection, height and
    clip planes were dropped); a fractional frame count was numpy's TypeError."""
    a = gp.Camera.look_at((0, 0, 10), (0, 0, 0), projection="orthographic", ortho_height=4.0, width=64, height=48, near=0.5, far=50.0)
    b = gp.Camera.look_at((10, 0, 10), (0, 0, 0), projection="orthographic", ortho_height=8.0, width=64, height=48, near=0.5, far=50.0)
    cams = interpolate_cameras([a, b], 5)
    assert [c.projection for c in cams] == ["orthographic"] * 5 and {(c.near, c.far) for c in cams} == {(0.5, 50.0)}
    np.testing.assert_allclose([c.ortho_height for c in cams], [4, 5, 6, 7, 8])
    np.testing.assert_allclose([c.eye[0] for c in cams], [0, 2.5, 5, 7.5, 10])
    wide = gp.Camera.look_at((0, 0, 10), (0, 0, 0), fov=30.0, width=64, height=48)
    narrow = gp.Camera.look_at((0, 0, 20), (0, 0, 0), fov=90.0, width=64, height=48)
    np.testing.assert_allclose([c.fov for c in interpolate_cameras([wide, narrow], 3)], [30, 60, 90])
    for keys, n, problem in (
        ([a, wide], 3, r"fly-through: the key cameras must have one projection, got \['orthographic', 'perspective'\]"),
        ([a, "x"], 3, "fly-through: key cameras: camera 1 must be a gigapoint.Camera, got str"),
        ([wide, gp.Camera.look_at((1, 0, 0), (0, 0, 0), width=32, height=48)], 3, "fly-through: key cameras: every camera must have one size"),
        ([a, b], 2.5, "fly-through: number of frames must be an integer from 2 to 100,000, got 2.5"),
        ([a, b], 10**9, "fly-through: number of frames must be an integer from 2 to 100,000, got 1000000000"),
        ([a], 5, "fly-through: needs at least 2 key cameras, got 1"),
    ):
        with pytest.raises(GigapointError, match=problem):
            interpolate_cameras(keys, n)


def test_flythrough_gif_and_errors(cloud, tmp_path):
    keys = turntable_cameras(cloud, 4, 48, 32)[:2]
    cams = interpolate_cameras(keys, 5)
    np.testing.assert_allclose(cams[0].eye, keys[0].eye)
    np.testing.assert_allclose(cams[-1].eye, keys[1].eye)
    # the folders missing on its way are made as it is written (were: 'directory ... does not exist')
    out = render_flythrough(cloud, cams, tmp_path / "new" / "dir" / "fly.gif", fps=10)
    from PIL import Image

    assert out == tmp_path / "new" / "dir" / "fly.gif" and Image.open(out).n_frames == 5
    with pytest.raises(GigapointError, match="unsupported video type"):
        render_turntable(cloud, 3, tmp_path / "x.png")
    with pytest.raises(GigapointError, match="even"):
        render_turntable(cloud, 3, tmp_path / "odd" / "x.mp4", width=33)
    with pytest.raises(GigapointError, match="an integer from 1 to 100,000"):
        render_turntable(cloud, 0, tmp_path / "x.mp4")
    (tmp_path / "afile").write_bytes(b"x")  # a file as the folder: was "Not a directory" once every frame was drawn
    with pytest.raises(GigapointError, match=f"^{tmp_path / 'afile' / 'sub' / 'x.mp4'}: {tmp_path / 'afile'} is a file, not a folder$"):
        render_turntable(cloud, 3, tmp_path / "afile" / "sub" / "x.mp4", progress=lambda done, total: pytest.fail("a frame was drawn"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile", "new"]  # a refusal made no folder


def test_a_flythrough_that_cannot_be_one_video_is_refused_before_a_frame(cloud, tmp_path):
    """Cameras of two sizes failed in ffmpeg at the second frame with imageio's ValueError and
    left a part-written temporary file beside the output; now each problem is one line before
    anything is rendered, and the folder stays as it was."""
    a, b = turntable_cameras(cloud, 2, 48, 32)
    small = turntable_cameras(cloud, 2, 32, 32)[0]
    odd = turntable_cameras(cloud, 2, 47, 32)[0]
    for cams, path, message in (
        ([a, small], "two.mp4", r"^video: every camera must have one size: camera 1 is 32x32, camera 0 48x32$"),
        ([a, small], "two.gif", r"^video: every camera must have one size"),
        ([a, "iso"], "str.mp4", r"^video: camera 1 must be a gigapoint.Camera, got str$"),
        ([odd, odd], "odd.mp4", r"odd.mp4: width and height must be even for video encoding, got 47x32$"),
    ):
        with pytest.raises(GigapointError, match=message):
            render_flythrough(cloud, cams, tmp_path / path)
    assert not list(tmp_path.iterdir())
    assert render_flythrough(cloud, [odd, odd], tmp_path / "odd.gif").exists()  # a GIF takes any size
    assert render_flythrough(cloud, [a, b], tmp_path / "ok.mp4").exists()
    assert render_turntable(cloud, 2, tmp_path / "odd_turn.gif", width=47, height=33).exists()  # was refused: "must be even"
    with pytest.raises(GigapointError, match=r"odd_turn.mp4: width and height must be even for video encoding, got 47x33$"):
        render_turntable(cloud, 2, tmp_path / "odd_turn.mp4", width=47, height=33)


def test_odd_turntable_and_camera_settings_are_one_line_errors_before_a_frame(cloud, tmp_path):
    """fps="a" was a TypeError (after every camera was fitted), 1e9 taken; pitch=100 drew the
    orbit upside down over the top, NaN said "camera eye must be finite"; width="a" was a
    TypeError of width / height; a path for a cloud an AttributeError. Camera.fit's margin of
    0 or -1 was framed as if 1.05, trim=5 numpy's ValueError, view=(1,) an unpacking error."""
    for kw, message in (
        ({"fps": "a"}, r"^video fps must be a number in \[0.01, 1000\], got 'a'$"),
        ({"fps": 1e9}, r"^video fps must be a number in \[0.01, 1000\], got 1e\+09$"),
        ({"pitch": 100}, r"^turntable: pitch must be None or degrees in -90..90, got 100$"),
        ({"pitch": float("nan")}, r"^turntable: pitch must be None or degrees in -90..90, got nan$"),
        ({"width": "a"}, r"^image width must be an integer in 1..16384, got 'a'$"),
    ):
        with pytest.raises(GigapointError, match=message):
            render_turntable(cloud, 3, tmp_path / "t.gif", **{"width": 48, "height": 32, **kw})
    with pytest.raises(GigapointError, match=r"^render: cannot draw a str; give a cloud"):
        render_turntable("cloud.laz", 3, tmp_path / "t.gif")
    assert not list(tmp_path.iterdir())
    for kw, message in (
        ({"margin": 0}, r"^camera margin must be a number in \(0, 1000\] \(1: the data touches the frame\), got 0$"),
        ({"margin": -1}, r"^camera margin must be a number"),
        ({"trim": 5}, r"^camera trim must be a share of the points in \[0, 0.5\), got 5$"),
        ({"view": (1,)}, r"^camera view must be one of top, front, back, side, left, right, iso, auto or \(yaw, pitch\) degrees, got \(1,\)$"),
        ({"view": (float("nan"), 0)}, r"^camera view must be one of .* got \(nan, 0\)$"),
    ):
        with pytest.raises(GigapointError, match=message):
            gp.Camera.fit_cloud(cloud, **kw)
    assert gp.Camera.fit_cloud(cloud, view=(30, 20), margin=1, trim=0).width == 1920


def test_videos_take_settings_as_keywords_as_render_does(cloud, tmp_path):
    """render_turntable(cloud, 4, "t.gif", edl=True) was a TypeError: settings are keywords
    there as in render (a keyword means what its option means; a wrong one is told before any frame)."""
    from PIL import Image

    cams = turntable_cameras(cloud, 3, 48, 32)
    out = render_turntable(cloud, 3, tmp_path / "t.gif", width=48, height=32, backend="cpu", color_mode="elevation", point_size=3)
    with Image.open(out) as gif:
        gif.seek(1)
        second = np.asarray(gif.convert("RGB"))
    expected = gp.render(cloud, cams[1], backend="cpu", color_mode="elevation", point_size=3)[..., :3]
    plain = gp.render(cloud, cams[1], backend="cpu")[..., :3]
    # (a GIF's palette shifts colours a little)
    assert np.abs(second.astype(float) - expected).mean() < 0.5 * np.abs(second.astype(float) - plain).mean()
    with pytest.raises(GigapointError, match="unknown render setting"):
        render_flythrough(cloud, cams, tmp_path / "f.gif", pointsize=3)
    assert not (tmp_path / "f.gif").exists()
