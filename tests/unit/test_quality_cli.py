"""`gigapoint render` quality options and --turntable (issue #5)."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

import gigapoint as gp
from gigapoint.cli import main
from gigapoint.cli.quality_opts import prepare_cloud


@pytest.fixture(scope="module")
def npy(tmp_path_factory):
    xyz = gp.demo_arrays(20_000, seed=11)[0]
    path = tmp_path_factory.mktemp("cli") / "scene.npy"
    np.save(path, xyz)
    return path


def test_render_with_quality_options_matches_the_api(npy, tmp_path):
    out = tmp_path / "q.png"
    args = ["render", str(npy), "-o", str(out), "-W", "96", "-H", "64", "--view", "iso", "--backend", "cpu", "--edl", "--fill-holes", "1", "--hqs",
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


def test_color_attribute_alone_colours_by_that_attribute(tmp_path, capsys):
    """``--color-attribute NAME`` means ``--color-mode attribute`` too (the schema's ``implies``)."""
    xyz = gp.demo_arrays(20_000, seed=11)[0]
    path = tmp_path / "hag.npz"
    np.savez(path, xyz=xyz, hag=(xyz[:, 2] - xyz[:, 2].min()).astype(np.float32))
    out = tmp_path / "a.png"
    assert main(["render", str(path), "-o", str(out), "-W", "96", "-H", "64", "--view", "iso", "--backend", "cpu", "--color-attribute", "hag",
                 "--colormap", "turbo", "--attribute-range", "0,20"]) == 0  # fmt: skip
    cloud = gp.open(path)
    cam = gp.Camera.fit(cloud.bounds, view="iso", width=96, height=64)
    want = gp.render(cloud, cam, backend="cpu", color_mode="attribute", color_attribute="hag", colormap="turbo", attribute_range=(0, 20))
    np.testing.assert_array_equal(np.asarray(Image.open(out)), want)
    assert not np.array_equal(want, gp.render(cloud, cam, backend="cpu"))
    # an attribute the file lacks is found while drawing: still named as the option typed (it said "color_attribute:")
    for extra in ([], ["--turntable", "2"]):
        assert main(["render", str(path), "-o", str(tmp_path / ("b.mp4" if extra else "b.png")), "--color-attribute", "nope", *extra]) == 1
        assert capsys.readouterr().err.strip() == "error: --color-attribute: hag.npz has no attribute 'nope' (attributes: hag)"


def test_a_missing_color_attribute_is_refused_before_the_inputs_are_read(tmp_path, capsys, monkeypatch):
    """It was told once every input was read (minutes for a large file): now from the headers of
    LAS/LAZ, PLY, NPY and text files (their attributes as the read cloud names them); of several
    files, those they all have (what the merged cloud keeps)."""
    import laspy

    from gigapoint.cli import render_cmd
    from gigapoint.io import reader_for

    xyz = np.arange(12.0).reshape(4, 3)
    header = laspy.LasHeader(point_format=1, version="1.4")
    header.add_extra_dim(laspy.ExtraBytesParams(name="hag", type=np.float32))
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz.T
    las.write(str(tmp_path / "a.laz"))
    (tmp_path / "b.ply").write_text("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
                                    "property float Hag\nend_header\n1 2 3 7\n")  # fmt: skip
    np.save(tmp_path / "c.npy", np.c_[xyz, np.ones(4)])  # (N, 4): x y z intensity
    (tmp_path / "d.csv").write_text("x,y,z,Hag,a/b\n1,2,3,4,5\n")  # (as the PLY spells it: one attribute, every reader keeping the case)
    for name in ("a.laz", "b.ply", "c.npy", "d.csv"):
        path = tmp_path / name
        assert reader_for(path).header(path)["attributes"] == list(gp.open(path).attribute_names), name
    monkeypatch.setattr(render_cmd, "open_inputs", lambda *a: pytest.fail("the inputs were read"))
    for inputs, problem in (
        (["a.laz"], ("a.laz has no attribute 'nope' (attributes: classification, edge_of_flight_line, gps_time, hag, intensity, key_point, "
                     "number_of_returns, point_source_id, return_number, scan_angle_rank, scan_direction_flag, synthetic, user_data, withheld)")),
        (["c.npy"], "c.npy has no attribute 'nope' (attributes: intensity)"),
        (["b.ply", "d.csv"], "2 files has no attribute 'nope' (attributes: Hag)"),
    ):  # fmt: skip
        args = [str(tmp_path / f) for f in inputs]
        assert main(["render", *args, "-o", str(tmp_path / "x.png"), "--color-attribute", "nope"]) == 1
        assert capsys.readouterr().err == f"error: --color-attribute: {problem}\n"


def test_width_or_height_alone_keeps_16_by_9(npy, tmp_path, capsys):
    """``render --width 33`` was 33x1080 (the other option's default): the side not given follows
    16:9 as in gp.render; ``demo`` the same."""
    for extra, size in ((["-W", "33"], (33, 19)), (["-H", "90"], (160, 90)), (["-W", "40", "-H", "40"], (40, 40))):
        out = tmp_path / f"{size[0]}x{size[1]}.png"
        assert main(["render", str(npy), "-o", str(out), "--backend", "cpu", *extra]) == 0
        assert Image.open(out).size == size
        assert f"wrote {out} ({size[0]}x{size[1]}, 20,000 points)" in capsys.readouterr().out
    assert main(["demo", "-n", "1000", "-o", str(tmp_path / "demo.png"), "-H", "36"]) == 0
    assert Image.open(tmp_path / "demo.png").size == (64, 36)


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


def test_a_colour_option_the_color_mode_does_not_read_is_refused(npy, tmp_path, capsys):
    """--colormap turbo alone drew the cloud's own colours, --color-attribute x with --color-mode
    elevation the elevation: each option was dropped without a word."""
    for extra, problem in (
        (["--colormap", "turbo"], "--colormap needs --color-mode elevation or attribute"),
        (["--colormap", "viridis"], "--colormap needs --color-mode elevation or attribute"),  # (its default, yet typed)
        (["--color-mode", "elevation", "--color-attribute", "z"], "--color-attribute needs --color-mode attribute, not elevation"),
        (["--color-mode", "intensity", "--elevation-range", "0,5"], "--elevation-range needs --color-mode elevation, not intensity"),
        (["--color-mode", "elevation", "--intensity-range", "0,5"], "--intensity-range needs --color-mode intensity, not elevation"),
        (["--attribute-range", "0,5"], "--attribute-range needs --color-mode attribute"),
    ):
        assert main(["render", str(npy), "-o", str(tmp_path / "x.png"), "-W", "32", "-H", "24", *extra]) == 1
        assert capsys.readouterr().err == f"error: {problem} (it would be ignored)\n"
    assert not list(tmp_path.iterdir())
    assert main(["render", str(npy), "-o", str(tmp_path / "x.png"), "-W", "32", "-H", "24", "--color-mode", "elevation", "--colormap", "turbo"]) == 0


@pytest.mark.parametrize(
    "extra, problem",
    [
        (["--ipd", "0.1"], "--ipd needs --stereo side-by-side or anaglyph"),
        (["--convergence", "5"], "--convergence needs --stereo side-by-side or anaglyph"),
        (["--edl-strength", "2"], "--edl-strength needs --edl"),
        (["--edl-strength", "1"], "--edl-strength needs --edl"),  # its default, yet typed: counted
        (["--edl-radius", "2"], "--edl-radius needs --edl"),
        (["--supersample-filter", "lanczos"], "--supersample-filter needs --supersample 2 or 4"),
        (["--supersample", "1", "--supersample-filter", "lanczos"], "--supersample-filter needs --supersample 2 or 4"),
        (["--foveated"], "--foveated needs --fill-holes 1, 2 or 3"),
        (["--shininess", "8"], "--shininess needs --lighting"),
        (["--hqs-depth-tolerance", "0.05"], "--hqs-depth-tolerance needs --hqs"),
        (["--size-mode", "adaptive", "--point-world-size", "2"], "--point-world-size needs --size-mode auto or attenuated, not adaptive"),
    ],
)
def test_an_option_its_switch_is_off_for_is_refused(npy, tmp_path, capsys, extra, problem):
    """--ipd without --stereo, --edl-strength without --edl, --foveated without --fill-holes, ...
    drew the image without them, without a word."""
    assert main(["render", str(npy), "-o", str(tmp_path / "x.png"), "-W", "32", "-H", "24", *extra]) == 1
    assert capsys.readouterr().err == f"error: {problem} (it would be ignored)\n"
    assert not list(tmp_path.iterdir())


def test_hqs_with_an_opacity_below_1_is_refused(npy, tmp_path, capsys):
    """--hqs --opacity 0.5 drew the transparent image alone (transparency replaces HQS), without a word."""
    assert main(["render", str(npy), "-o", str(tmp_path / "x.png"), "-W", "32", "-H", "24", "--hqs", "--opacity", "0.5"]) == 1
    said = "--hqs: high-quality shading is not drawn at opacity 0.5, whose transparent points replace it; turn hqs off or set opacity to 1"
    assert capsys.readouterr().err == f"error: {said}\n"
    assert not list(tmp_path.iterdir())
    assert main(["render", str(npy), "-o", str(tmp_path / "x.png"), "-W", "32", "-H", "24", "--backend", "cpu", "--hqs", "--opacity", "1"]) == 0


def test_a_switch_given_lets_its_options_through(npy, tmp_path):
    for extra in (["--edl", "--edl-strength", "1", "--edl-radius", "2"], ["--fill-holes", "2", "--foveated"], ["--hqs", "--hqs-depth-tolerance", "0.05"],
                  ["--stereo", "anaglyph", "--ipd", "0.1", "--convergence", "5"], ["--supersample", "4", "--supersample-filter", "lanczos"]):  # fmt: skip
        assert main(["render", str(npy), "-o", str(tmp_path / "x.png"), "-W", "32", "-H", "24", "--overwrite", "--backend", "cpu", *extra]) == 0, extra


@pytest.mark.parametrize("suffix", [".jpg", ".bmp"])
def test_a_see_through_background_written_where_the_format_has_no_alpha_is_warned_once(npy, tmp_path, capsys, suffix):
    """--background '#ff000080' -o x.jpg wrote an opaque red background without a word."""
    out = tmp_path / f"x{suffix}"
    assert main(["render", str(npy), "-o", str(out), "-W", "32", "-H", "24", "--backend", "cpu", "--background", "#ff000080"]) == 0
    kind = suffix[1:].upper()
    assert capsys.readouterr().err == f"warning: {out}: a {kind} file holds no alpha: the background's alpha 128 is written opaque\n"
    assert main(["render", str(npy), "-o", str(tmp_path / "x.png"), "-W", "32", "-H", "24", "--backend", "cpu", "--background", "#ff000080"]) == 0
    assert capsys.readouterr().err == ""
    assert np.asarray(Image.open(tmp_path / "x.png"))[0, 0].tolist() == [255, 0, 0, 128]  # (a PNG keeps it)
    assert main(["render", str(npy), "-o", str(out), "-W", "32", "-H", "24", "--backend", "cpu", "--overwrite", "--background", "#ff0000"]) == 0
    assert capsys.readouterr().err == ""


def test_a_bad_turntable_is_refused_before_the_inputs_are_read(tmp_path, capsys):
    """--fps 0, an odd --width of an MP4 and --turntable 0 were told only once the inputs were
    read (minutes for a large file); here the input is missing, so it is told first only if read."""
    missing = tmp_path / "big.laz"
    for extra, problem in (
        (["--turntable", "2", "--fps", "0"], "--fps: video fps must be a number in [0.01, 1000], got 0"),
        (["--turntable", "2", "-W", "33"], f"{tmp_path / 'spin.mp4'}: width and height must be even for video encoding, got 33x24"),
        (["--turntable", "0"], "--turntable: number of frames must be an integer from 1 to 100,000, got 0"),
    ):
        assert main(["render", str(missing), "-o", str(tmp_path / "spin.mp4"), "-W", "32", "-H", "24", *extra]) == 1
        assert capsys.readouterr().err == f"error: {problem}\n"
    assert not list(tmp_path.iterdir())


def test_a_native_window_refuses_the_servers_options(capsys):
    """`view --window --port 8080` showed a window and listened on nothing, without a word."""
    assert main(["view", "--demo", "100", "--window", "--port", "8080", "--host", "0.0.0.0"]) == 1
    assert capsys.readouterr().err == "error: --host and --port: options of the browser viewer, not of --window\n"


def test_options_a_turntable_or_a_still_image_would_drop_are_refused(npy, tmp_path, capsys):
    """--depth-out with --turntable wrote no depth file, --camera/--view/--projection/--stats were
    dropped, and --fps without --turntable too, each without a word."""
    gif = tmp_path / "spin.gif"
    for extra, problem in (
        (["--depth-out", str(tmp_path / "d.npy")], "--depth-out"),
        (["--camera", "yaw=10 pitch=20", "--view", "top"], "--camera, --view"),
        (["--projection", "orthographic", "--stats"], "--projection, --stats"),
    ):
        assert main(["render", str(npy), "-o", str(gif), "-W", "32", "-H", "24", "--turntable", "2", *extra]) == 1
        assert capsys.readouterr().err == f"error: {problem}: options of a still image, not of --turntable (it orbits the cloud at its own distance)\n"
    assert main(["render", str(npy), "-o", str(tmp_path / "x.png"), "-W", "32", "-H", "24", "--fps", "5"]) == 1
    assert capsys.readouterr().err == "error: --fps: an option of --turntable videos\n"
    assert not list(tmp_path.iterdir())
    assert main(["render", str(npy), "-o", str(gif), "-W", "32", "-H", "24", "--turntable", "2", "--fps", "5", "--backend", "cpu"]) == 0
    assert gif.exists()


def test_ipd_is_automatic_unless_given(npy, tmp_path):
    """--ipd was a fixed 0.065 world units by default; now the default is the 1/30 rule (target
    distance / 30) and --ipd 0.1 draws eyes 0.1 apart, both as the API draws them."""
    cloud = gp.open(npy)
    cam = gp.Camera.fit(cloud.bounds, view="iso", width=80, height=56)
    s = gp.RenderSettings(backend="cpu", stereo="anaglyph")
    auto = _render(npy, tmp_path / "a.png", "--stereo", "anaglyph")
    np.testing.assert_array_equal(auto, gp.render(cloud, cam, s))
    rule = float(np.linalg.norm(np.subtract(cam.target, cam.eye))) / 30.0
    np.testing.assert_array_equal(auto, gp.render(cloud, cam, s.replace(ipd=rule)))
    given = _render(npy, tmp_path / "b.png", "--stereo", "anaglyph", "--ipd", "0.1")
    np.testing.assert_array_equal(given, gp.render(cloud, cam, s.replace(ipd=0.1)))
    assert not np.array_equal(auto, given)


def _render(npy, out, *extra):
    assert main(["render", str(npy), "-o", str(out), "-W", "80", "-H", "56", "--view", "iso", "--backend", "cpu", *extra]) == 0
    return np.asarray(Image.open(out))


@pytest.mark.parametrize(
    "base, base_settings, option, setting",
    [
        (["--supersample", "2"], {"supersample": 2}, ["--supersample-filter", "lanczos"], {"supersample_filter": "lanczos"}),
        (
            ["--stereo", "side-by-side", "--ipd", "20"],
            {"stereo": "side-by-side", "ipd": 20.0},
            ["--convergence", "40"],
            {"convergence": 40.0},
        ),
        (
            ["--hqs", "--color-mode", "elevation"],
            {"hqs": True, "color_mode": "elevation"},
            ["--hqs-depth-tolerance", "0.3"],
            {"hqs_depth_tolerance": 0.3},
        ),
        (["--lighting"], {"lighting": True}, ["--shininess", "2"], {"shininess": 2.0}),
    ],
)
def test_each_new_quality_option_changes_the_image_like_the_api(npy, tmp_path, base, base_settings, option, setting):
    if "lighting" in base_settings:
        pytest.importorskip("scipy")
    without = _render(npy, tmp_path / "a.png", *base)
    with_option = _render(npy, tmp_path / "b.png", *base, *option)
    assert without.shape == with_option.shape and not np.array_equal(without, with_option)
    cloud = gp.open(npy)
    s = gp.RenderSettings(backend="cpu", **base_settings, **setting)
    prepare_cloud(cloud, s)
    np.testing.assert_array_equal(with_option, gp.render(cloud, gp.Camera.fit(cloud.bounds, view="iso", width=80, height=56), s))


def test_every_quality_setting_has_a_render_option():
    import dataclasses

    import typer

    from gigapoint.cli import app, commands  # noqa: F401  (commands registers `render`)
    from gigapoint.cli.settings_opts import option_of

    names = [f.name for f in dataclasses.fields(gp.RenderSettings)]
    quality = names[names.index("color_mode") :]  # the image-quality block of RenderSettings
    option = option_of(gp.RenderSettings)  # every field -> its option
    assert set(quality) <= set(option)
    render = typer.main.get_command(app).commands["render"]
    opts = {o for p in render.params for o in p.opts}
    assert {option[f] for f in quality} <= opts


@pytest.mark.parametrize(
    "extra, option",
    [
        (["--supersample", "2", "--supersample-filter", "bicubic"], "--supersample-filter"),
        (["--stereo", "anaglyph", "--convergence", "-3"], "--convergence"),
        (["--hqs", "--hqs-depth-tolerance", "2"], "--hqs-depth-tolerance"),
        (["--lighting", "--shininess", "-1"], "--shininess"),
    ],
)
def test_bad_new_options_are_one_line_errors_naming_the_option(npy, tmp_path, capsys, extra, option):
    assert main(["render", str(npy), "-o", str(tmp_path / "x.png"), "-W", "32", "-H", "32", *extra]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"error: {option}:") and "\n" not in err
    assert not (tmp_path / "x.png").exists()
