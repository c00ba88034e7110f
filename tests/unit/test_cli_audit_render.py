"""A demanding user's bad input to `render`, `demo`, `bench` and `view` (before its server starts):
impossible camera, image, stereo, video and size settings, bad input files, bad output paths.
Each case is one line naming the file or option and the problem, exit 1, and no output left
behind; or, for absurd but meaningful values, the image they mean (not a traceback, a hang,
numpy's warnings or a blank image)."""

from __future__ import annotations

import laspy
import numpy as np
import pytest
from PIL import Image
from test_cli_audit_survey import refused_in_one_line  # tests/unit is on sys.path

from gigapoint.viewer.protocol import settings_schema


def write_las(path, xyz):
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = [0.01] * 3, [0.0] * 3
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.write(str(path))
    return path


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """small.las (2,000 points over 100 x 50, z 0..5, its corners among them), pts.npy (100
    points), nan.npy (all NaN), empty.npy (no rows), zero.laz (0 bytes), png.laz (a PNG) and
    cut.laz (a LAZ file cut off after its header: no point can be read)."""
    folder = tmp_path_factory.mktemp("in")
    rng = np.random.default_rng(0)
    xyz = np.column_stack([rng.random(2000) * 100, rng.random(2000) * 50, rng.random(2000) * 5])
    xyz[:2] = [(0, 0, 0), (100, 50, 5)]
    write_las(folder / "small.las", xyz)
    np.save(folder / "pts.npy", xyz[:100])
    np.save(folder / "nan.npy", np.full((100, 3), np.nan))
    np.save(folder / "empty.npy", np.zeros((0, 3)))
    (folder / "zero.laz").write_bytes(b"")
    Image.fromarray(np.zeros((10, 10, 3), np.uint8)).save(folder / "png.laz", format="PNG")
    laz = write_las(folder / "whole.laz", xyz)
    (folder / "cut.laz").write_bytes(laz.read_bytes()[: laspy.read(laz).header.offset_to_point_data + 100])
    return folder


@pytest.mark.parametrize(
    ("args", "problem"),
    [
        # an eye, a target or an orbit's distance of 1e300 overflowed the camera's sums: numpy's warnings and a blank image, exit 0
        (["render", "{in}/small.las", "-o", "{out}/x.png", "--camera", "eye=1e300,0,10 target=0,0,0"],
         "--camera: eye 1e300,0,10 lies beyond ±1e+12, where no point can be"),
        (["render", "{in}/small.las", "-o", "{out}/x.png", "--camera", "eye=0,0,10 target=0,-1e13,0"],
         "--camera: target 0,-1e13,0 lies beyond ±1e+12, where no point can be"),
        (["render", "{in}/small.las", "-o", "{out}/x.png", "--camera", "yaw=0 pitch=10 distance=1e300"],
         "--camera: distance must be at most 2e+12, the span points can have, got 1e300"),
        # every frame was drawn, then ffmpeg's empty file was blamed on the disk
        (["render", "{in}/small.las", "-o", "{out}/v.mp4", "--turntable", "2", "--fps", "1e-9"], "--fps: video fps must be a number in [0.01, 1000], got 1e-09"),
        # 1e200: numpy's warnings, then 'a world file needs an orthographic camera looking straight down' (1e100: a blank image)
        (["render", "{in}/small.las", "-o", "{out}/x.png", "--gsd", "1e200"], "--gsd must be a number > 0 and at most 2e+12 (cloud units per pixel), got 1e+200"),
        # the image's size was said in 300 digits
        (["render", "{in}/small.las", "-o", "{out}/x.png", "--gsd", "1e-300"],
         "{in}/small.las: --gsd 1e-300 makes a 1e+302x5e+301 image, over 16,384 pixels a side: a gsd of 0.00611 or more fits"),
        # a subnormal gsd overflowed the division: "internal error: OverflowError"
        (["render", "{in}/small.las", "-o", "{out}/x.png", "--gsd", "5e-324"],
         "{in}/small.las: --gsd 4.94066e-324 makes a infxinf image, over 16,384 pixels a side: a gsd of 0.00611 or more fits"),
        # a count of points and of terabytes in 100 digits each
        (["bench", "-n", "1e99", "--json", "{out}/b.json"], "--points: the demo scene has at most 4,000,000,000 points, got '1e99'"),
        # a grid step said as '5000.0', a number given as 5000 (errors.number_text)
        (["demo", "-o", "{out}/d.png", "--scale", "5000"], "--scale must be 0 (float positions) or a grid step between 1e-6 and 1000 metres, got 5000"),
        # (told as they were before)
        (["render", "{in}/small.las", "-o", "{out}/x.png", "--fov", "0"], "--fov: camera fov must be between 0.01 and 179 degrees, got 0"),
        (["render", "{in}/small.las", "-o", "{out}/x.png", "--fov", "nan"], "--fov: camera fov must be between 0.01 and 179 degrees, got nan"),
        (["render", "{in}/small.las", "-o", "{out}/x.png", "--width", "0"], "--width: image width must be an integer in 1..16384, got 0"),
        (["render", "{in}/small.las", "-o", "{out}/x.png", "--height", "1000000000"], "--height: image height must be an integer in 1..16384, got 1000000000"),
        (["render", "{in}/small.las", "-o", "{out}/x.png", "--camera", "eye=1,2,3 target=1,2,3"], "--camera: camera eye and target are the same point"),
        (["render", "{in}/small.las", "-o", "{out}/x.png", "--camera", "eye=nan,0,10 target=0,0,0"], "--camera: eye needs 3 finite number(s), got 'nan,0,10'"),
        (["render", "{in}/small.las", "-o", "{out}/x.png", "--camera", "eye=0,0,10 target=0,0,0 up=0,0,0"], "--camera: camera up vector is zero"),
        (["render", "{in}/small.las", "-o", "{out}/x.png", "--stereo", "anaglyph", "--ipd", "nan"], "--ipd: ipd must be a number in [0, 2e+12], got nan"),
        # the bound and the value were said in full ('[0.0, 2000000000000.0], got 10000000000000.0')
        (["render", "{in}/small.las", "-o", "{out}/x.png", "--stereo", "anaglyph", "--ipd", "1e13"], "--ipd: ipd must be a number in [0, 2e+12], got 1e+13"),
        # the auto eye distance (convergence / 30) put the eyes 3e298 apart: a blank image and a warning without a reason
        (["render", "{in}/small.las", "-o", "{out}/x.png", "--stereo", "anaglyph", "--convergence", "1e300"],
         "--convergence: convergence must be a number in (0, 2e+12], got 1e+300"),
        (["render", "{in}/small.las", "-o", "{out}/v.mp4", "--turntable", "0"], "--turntable: number of frames must be an integer from 1 to 100,000, got 0"),
        (["render", "{in}/small.las", "-o", "{out}/x.png", "--point-size", "0"], "--point-size: point_size must be an integer in [1, 64], got 0"),
        (["render", "{in}/small.las", "-o", "{out}/x.png", "--point-budget", "0"], "--point-budget: point_budget must be an integer >= 1, got 0"),
        (["render", "{in}/small.las", "-o", "{out}/x.png", "--gsd", "nan"], "--gsd must be a number > 0 and at most 2e+12 (cloud units per pixel), got nan"),
        (["render", "{in}/missing.laz", "-o", "{out}/x.png"], "{in}/missing.laz: no such file"),
        (["render", "{in}/zero.laz", "-o", "{out}/x.png"], "{in}/zero.laz: file is empty (0 bytes)"),
        (["render", "{in}/png.laz", "-o", "{out}/x.png"], "{in}/png.laz: not a LAS/LAZ file (starts with b'\\x89PNG', expected b'LASF')"),
        (["render", "{in}/nan.npy", "-o", "{out}/x.png"], "{in}/nan.npy: no valid points (100 invalid points: NaN, inf or beyond ±1e+12)"),
        (["render", "{in}/empty.npy", "-o", "{out}/x.png"], "{in}/empty.npy: NPY array holds no points (0 rows)"),
        (["render", "{in}/small.las", "-o", "{out}/x.foo"], "{out}/x.foo: unsupported output type '.foo'; use one of .bmp, .jpeg, .jpg, .png, .tif, .tiff, .webp"),
        # folders missing on the output's way are made only as it is written: a refusal before leaves none
        (["render", "{in}/missing.laz", "-o", "{out}/nodir/x.png"], "{in}/missing.laz: no such file"),
        (["render", "{in}/small.las", "-o", "{out}/x.png", "--depth-out", "{in}/small.las/d.npy"], "{in}/small.las/d.npy: {in}/small.las is a file, not a folder"),
        (["render", "{in}/pts.npy", "-o", "{out}/x.png", "--index-out", "{in}/pts.npy", "--overwrite"],
         "{in}/pts.npy: is one of the inputs; write it elsewhere (it would replace the points being read)"),
        (["demo", "-n", "0", "-o", "{out}/d.png"], "--points must be between 1 and 4,000,000,000, got 0"),
        (["view", "--demo", "0"], "--demo: point count must be in 1..2e9, got 0"),
    ],
    ids=["camera-eye-1e300", "camera-target-1e13", "camera-distance-1e300", "fps-1e-9", "gsd-1e200", "gsd-1e-300", "gsd-5e-324", "bench-points-1e99", "demo-scale-5000",
         "fov-0", "fov-nan", "width-0", "height-1e9", "eye-is-target", "eye-nan", "up-zero", "ipd-nan", "ipd-1e13", "convergence-1e300", "turntable-0", "point-size-0",
         "point-budget-0", "gsd-nan", "missing", "zero-bytes", "png-as-laz", "all-nan", "no-rows", "unknown-suffix", "missing-no-folder-made", "through-a-file",
         "output-is-input", "demo-points-0", "view-demo-0"],
)  # fmt: skip
def test_bad_input_is_one_line_and_leaves_no_output(cli, inputs, tmp_path, args, problem):
    refused_in_one_line(cli, inputs, tmp_path, args, problem)


def test_an_existing_image_is_kept_without_overwrite(cli, inputs, tmp_path):
    out = tmp_path / "x.png"
    out.write_bytes(b"mine")
    rc, stdout, err = cli("render", inputs / "small.las", "-o", out, "--width", "64")
    assert (rc, stdout, err) == (1, "", f"error: {out}: already exists; pass --overwrite to replace it\n")
    assert out.read_bytes() == b"mine"


def lit_pixels(path) -> np.ndarray:
    """(row, column) of the pixels of an image that are not the black background."""
    return np.argwhere(np.asarray(Image.open(path))[..., :3].any(axis=-1))


def test_a_single_point_is_framed_and_drawn(cli, tmp_path):
    """The camera fitted to one point divides by no extent: the point lies in the image's centre;
    the summary said '1 points'."""
    path = tmp_path / "one.npy"
    np.save(path, np.array([[10.0, 20.0, 30.0]]))
    out = tmp_path / "one.png"
    rc, stdout, err = cli("render", path, "-o", out, "--width", "64", "--height", "64")
    assert (rc, stdout, err) == (0, f"wrote {out} (64x64, 1 point)\n", "")
    assert lit_pixels(out).tolist() == [[32, 32]]


def test_an_absurd_stereo_shift_is_a_warning_not_an_overflow(cli, inputs, tmp_path):
    """--ipd 1e300 at --convergence 1e-300 moved each eye's image by an infinite number of pixels:
    an internal OverflowError; --ipd 1e300 alone said the shift in 300 digits. (Eyes past the span
    points can have are refused now: the widest, 2e12, at 1e-300 overflows the same.) Both eyes'
    images move out of the picture: the pair's warning, with a number it can say."""
    out = tmp_path / "s.png"
    rc, stdout, err = cli("render", inputs / "small.las", "-o", out, "--width", "64", "--stereo", "anaglyph", "--ipd", "2e12", "--convergence", "1e-300")
    assert rc == 0, err
    assert err == ("warning: small.las: no point is in view of the stereo camera (each eye's image moves over 1e+15 px of 64: "
                   "ipd 2e+12 world units is wide for this scene); the image shows only the background\n")  # fmt: skip
    assert lit_pixels(out).size == 0


def test_stereo_distances_within_the_span_points_can_have_draw_the_pair(cli, inputs, tmp_path):
    """--ipd and --convergence are bounded by the span points can have (2e12, as --camera's
    distance): the settings schema carries it, so the viewer's panel bounds its inputs alike;
    a convergence in reach of the scene still draws both eyes."""
    schema = {d["name"]: d for d in settings_schema()}
    assert (schema["ipd"]["max"], schema["convergence"]["max"]) == (2e12, 2e12)
    out = tmp_path / "s.png"
    rc, stdout, err = cli("render", inputs / "small.las", "-o", out, "--width", "64", "--stereo", "anaglyph", "--convergence", "150", "--color-mode", "elevation")
    assert (rc, err) == (0, "")
    drawn = np.asarray(Image.open(out))[..., :3]
    assert drawn[..., 0].any() and drawn[..., 1:].any()  # the left eye in red, the right in green and blue


def test_a_convergence_far_beyond_the_cloud_says_why_the_pair_is_blank(cli, inputs, tmp_path):
    """--convergence 1e12 on a 100-unit cloud puts the automatic eyes (convergence / 30) 3.3e10
    apart, both beside the cloud: a blank pair whose warning gave no reason (one was given
    only for an explicit --ipd)."""
    out = tmp_path / "s.png"
    rc, stdout, err = cli("render", inputs / "small.las", "-o", out, "--width", "64", "--stereo", "anaglyph", "--convergence", "1e12")
    assert rc == 0, err
    assert err == ("warning: small.las: no point is in view of the stereo camera (the automatic ipd, 3.3e+10 world units from convergence 1e+12, "
                   "puts each eye beside the cloud, 100 across: give a convergence near the cloud's distance, or an ipd); "
                   "the image shows only the background\n")  # fmt: skip
    assert lit_pixels(out).size == 0


def test_a_huge_world_size_draws_the_largest_points_without_numpy_warnings(cli, inputs, tmp_path):
    """--point-world-size 1e300 overflowed float32: 'warning: overflow encountered in cast'."""
    out = tmp_path / "w.png"
    rc, stdout, err = cli("render", inputs / "small.las", "-o", out, "--width", "64", "--point-world-size", "1e300", "--color-mode", "elevation")
    assert (rc, err) == (0, "")
    assert len(lit_pixels(out)) > 64 * 36 / 2  # (16 px points: they cover most of the image)


def test_view_of_a_file_cut_off_before_any_point_says_so(cli, inputs, monkeypatch):
    """A LAZ file cut off after its header opened progressively (what it holds drawn, its error
    said): a server started that showed no point, its error a warning."""
    from gigapoint.viewer import server

    class NotServed:
        def __init__(self, cloud, **kw):
            raise AssertionError(f"a viewer was started for {cloud.n_points} points")

    monkeypatch.setattr(server, "ViewerServer", NotServed)
    rc, stdout, err = cli("view", "--no-browser", inputs / "cut.laz")
    assert (rc, stdout) == (1, "")
    assert err.startswith(f"error: {inputs / 'cut.laz'}: ") and err.endswith(": 0 of its 2,000 points read\n") and err.count("\n") == 1
