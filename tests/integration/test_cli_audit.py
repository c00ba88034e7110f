"""A new user's command line (the audit of fix-audit-cli): unreadable inputs and unwritable
folders told in one line, no image left without the depth asked for beside it, hints a shell can
run, options named in their errors."""

from __future__ import annotations

import errno
import os
import re
import shlex
import shutil
import subprocess
import sys

import numpy as np
import pytest

SIZE = ["-W", "64", "-H", "48", "--backend", "cpu"]



@pytest.fixture(scope="module")
def cloud_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("in") / "cloud.npy"
    np.save(path, np.random.default_rng(0).random((3000, 3)) * 10)
    return path


def unprivileged(*args, timeout=120) -> subprocess.CompletedProcess:
    """``gigapoint ARGS`` in a process that file permissions apply to: root (CI, containers)
    reads a chmod 000 file anyway, so as root without the capabilities that bypass them."""
    cmd = [sys.executable, "-m", "gigapoint.cli", *map(str, args)]
    if os.geteuid() == 0:
        drop = ["setpriv", "--inh-caps=-dac_override,-dac_read_search", "--bounding-set=-dac_override,-dac_read_search"]
        if shutil.which("setpriv") is None or subprocess.run([*drop, "true"], capture_output=True).returncode != 0:
            pytest.skip("root, and setpriv cannot drop the capabilities that bypass file permissions")
        cmd = drop + cmd
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)


def test_an_unreadable_input_is_one_line_for_every_command(cloud_file, tmp_path):
    """typer's own check answered a chmod 000 file with a usage message and 'Invalid value for
    'inputs': path ... is not readable' (three lines, exit 2)."""
    locked = tmp_path / "locked.npy"
    shutil.copyfile(cloud_file, locked)
    locked.chmod(0)
    for args in (["render", locked, "-o", tmp_path / "x.png"], ["info", locked], ["convert", locked, "-o", tmp_path / "oct"], ["view", locked, "--no-browser"]):
        done = unprivileged(*args)
        assert (done.returncode, done.stderr) == (1, f"error: {locked}: permission denied\n"), args
    assert not (tmp_path / "x.png").exists() and not (tmp_path / "oct").exists()


def test_an_unwritable_folder_is_refused_before_anything_is_written(cloud_file, tmp_path):
    """--depth-out into a read-only folder failed once the image was written: the image stayed,
    and the same command again said it already exists."""
    locked = tmp_path / "readonly"
    locked.mkdir()
    locked.chmod(0o555)
    image = tmp_path / "x.png"
    done = unprivileged("render", cloud_file, "-o", image, *SIZE, "--depth-out", locked / "d.npy")
    assert (done.returncode, done.stderr) == (1, f"error: {locked / 'd.npy'}: cannot write into {locked} (permission denied)\n")
    assert not image.exists()
    done = unprivileged("render", cloud_file, "-o", locked / "x.png", *SIZE)
    assert (done.returncode, done.stderr) == (1, f"error: {locked / 'x.png'}: cannot write into {locked} (permission denied)\n")


def test_a_side_output_that_fails_takes_the_image_with_it(cloud_file, tmp_path, cli, monkeypatch):
    """A disk that fills while the index buffer is written: no image and depth left without it."""
    from gigapoint.cli import render_cmd

    save = render_cmd.save_array

    def full_disk(array, path):
        if path.name == "index.npy":
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        save(array, path)

    monkeypatch.setattr(render_cmd, "save_array", full_disk)
    out = [tmp_path / "x.png", "--depth-out", tmp_path / "depth.npy", "--index-out", tmp_path / "index.npy"]
    rc, stdout, err = cli("render", cloud_file, "-o", *out, *SIZE)
    assert (rc, stdout, err) == (1, "", f"error: {tmp_path / 'index.npy'}: No space left on device\n")
    assert sorted(os.listdir(tmp_path)) == []


def test_the_convert_hint_is_a_command_a_shell_runs(cloud_file, tmp_path, cli):
    """`gigapoint view my scans` named two paths: the hint quotes an output with a space."""
    out = tmp_path / "my octree ü"
    rc, _, err = cli("convert", cloud_file, "-o", out)
    assert rc == 0, err
    assert f"while this runs, `gigapoint view '{out}'` shows what has been read so far" in err
    assert shlex.split(f"gigapoint view {shlex.quote(str(out))}")[2] == str(out)


def test_bench_out_makes_its_folder(tmp_path, cli):
    """--out NEW (a folder the benchmark makes) was refused: 'NEW/bench_render.json: directory
    NEW does not exist'."""
    out = tmp_path / "new" / "run"
    rc, _, err = cli("bench", "-n", "2k", "--threads", "1", "--repeats", "1", "--no-gl", "--no-naive", "--out", out, "-W", 64, "-H", 48)
    assert rc == 0, err
    assert sorted(p.name for p in out.iterdir()) == ["bench_render.json", "gigapoint_2000_closeup.png", "gigapoint_2000_overview.png"]
    rc, _, err = cli("bench", "-n", "2k", "--threads", "1", "--repeats", "1", "--no-gl", "--no-naive", "--out", out)
    assert (rc, err) == (1, f"error: {out / 'bench_render.json'}: already exists; pass --overwrite to replace it\n")


def test_turntable_errors_name_their_options(cloud_file, tmp_path, cli):
    video = tmp_path / "turntable.mp4"
    rc, _, err = cli("render", cloud_file, "-o", video, "--turntable", 3, "--fps", 0)
    assert (rc, err) == (1, "error: --fps: video fps must be a number in [0.01, 1000], got 0\n")
    rc, _, err = cli("render", cloud_file, "-o", video, "--turntable", 0)
    assert (rc, err) == (1, "error: --turntable: number of frames must be an integer from 1 to 100,000, got 0\n")
    video.write_bytes(b"mine")  # a file named turntable.mp4 is not the --turntable option
    rc, _, err = cli("render", cloud_file, "-o", video, "--turntable", 3)
    assert (rc, err) == (1, f"error: {video}: already exists; pass --overwrite to replace it\n")


def test_a_folder_named_as_the_output_says_so(cloud_file, tmp_path, cli):
    """-o FOLDER said "unsupported output type '(none)'"."""
    folder = tmp_path / "shots"
    folder.mkdir()
    rc, _, err = cli("render", cloud_file, "-o", folder, *SIZE)
    assert (rc, err) == (1, f"error: {folder}: is a directory, not an output file\n")


def test_an_interrupted_convert_says_it_resumes(cloud_file, tmp_path, cli, monkeypatch):
    """Ctrl+C said only 'interrupted': whether OUT was lost or half-done was left to guess."""
    import functools

    import gigapoint.lod
    from gigapoint.lod.convert import hooks

    def stop(done):
        raise KeyboardInterrupt

    convert, built = gigapoint.lod.convert, hooks.after_partition_built
    monkeypatch.setattr(gigapoint.lod, "convert", functools.partial(convert, partition_points=1_000))  # partitions to stop after
    monkeypatch.setattr(hooks, "after_partition_built", stop)
    out = tmp_path / "oct"
    rc, _, err = cli("convert", cloud_file, "-o", out, "--quiet")
    assert (rc, err) == (130, f"{out}: kept unfinished; run the same convert command again to resume it\ninterrupted\n")
    monkeypatch.setattr(hooks, "after_partition_built", built)
    rc, stdout, err = cli("convert", cloud_file, "-o", out, "--quiet")
    assert rc == 0 and "3,000 points" in stdout and "(resumed)" in stdout, err



@pytest.mark.parametrize("args, problem", [
    (["--max-leaf", 0], "--max-leaf: max_leaf must be an integer >= 100, got 0"),
    (["--workers", 0], "--workers: needs at least 1 worker, got 0"),
])  # fmt: skip
def test_convert_option_errors_are_one_line_naming_the_option(cloud_file, tmp_path, cli, args, problem):
    """--max-leaf 0 said 'max_leaf must be ...'; --workers 0 was a four-line usage error (exit 2)."""
    if args[0] == "--workers":
        pytest.importorskip("distributed")  # (without it: 'needs gigapoint[dask]')
    rc, _, err = cli("convert", cloud_file, "-o", tmp_path / "oct", *args)
    assert (rc, err) == (1, f"error: {problem}\n")
    assert not (tmp_path / "oct").exists()


@pytest.mark.parametrize("args, problem", [
    (["-W", 0], "--width: image width must be an integer in 1..16384, got 0"),
    (["--repeats", 0], "--repeats: benchmark repeats must be >= 1, got 0"),
])  # fmt: skip
def test_bench_errors_name_their_option(cli, args, problem):
    rc, _, err = cli("bench", "-n", "1k", "--no-gl", "--no-naive", *args)
    assert (rc, err) == (1, f"error: {problem}\n")


def test_an_orbit_distance_is_from_the_clouds_centre(autzen_path, tmp_path, cli):
    """--camera 'yaw=30 pitch=45 distance=100' orbited the framing's target, moved to centre the
    box's image: 150 m under autzen, so the eye was under the ground and the image empty."""
    from PIL import Image

    out = tmp_path / "near.png"
    rc, _, err = cli("render", autzen_path, "-o", out, *SIZE, "--camera", "yaw=30 pitch=45 distance=100", "--stats")
    assert rc == 0 and "no point is in view" not in err, err
    img = np.asarray(Image.open(out))
    assert (img[..., :3] > 0).any(axis=2).mean() > 0.5  # close over the ground: most of the frame is points


@pytest.mark.parametrize("mode", ["fixed", "adaptive"])
def test_a_world_size_the_size_mode_ignores_is_refused(cloud_file, tmp_path, cli, mode):
    """--size-mode fixed --point-world-size 2 drew 16-pixel points (the size's implied
    --point-size), the world size ignored without a word."""
    rc, _, err = cli("render", cloud_file, "-o", tmp_path / "x.png", *SIZE, "--size-mode", mode, "--point-world-size", 2)
    assert (rc, err) == (1, f"error: --point-world-size needs --size-mode auto or attenuated, not {mode} (it would be ignored)\n")
    assert not (tmp_path / "x.png").exists()
    assert cli("render", cloud_file, "-o", tmp_path / "x.png", *SIZE, "--size-mode", "attenuated", "--point-world-size", 2)[0] == 0


def test_a_video_name_without_turntable_says_which_option_makes_one(cloud_file, tmp_path, cli):
    """-o spin.mp4 alone said "unsupported output type '.mp4'; use one of .bmp, ...", the
    option that writes a video left to be found."""
    rc, _, err = cli("render", cloud_file, "-o", tmp_path / "spin.MP4", *SIZE)
    assert (rc, err) == (1, f"error: {tmp_path / 'spin.MP4'}: a video needs --turntable N (its number of frames); a still image is .png, .jpg, .webp or .tif\n")


def test_a_turntables_output_is_refused_in_the_words_of_a_video(cloud_file, tmp_path, cli):
    """render --turntable checked its output as a still image's ("is a directory, not an output
    file", "unsupported output type"), where the library's turntable says a video's."""
    (tmp_path / "spin.mp4").mkdir()
    rc, _, err = cli("render", cloud_file, "-o", tmp_path / "spin.mp4", "--turntable", 2, *SIZE)
    assert (rc, err) == (1, f"error: {tmp_path / 'spin.mp4'}: is a directory, not a video file\n")
    rc, _, err = cli("render", cloud_file, "-o", tmp_path / "spin.txt", "--turntable", 2, *SIZE)
    assert (rc, err) == (1, f"error: {tmp_path / 'spin.txt'}: unsupported video type '.txt'; use one of .avi, .gif, .mkv, .mov, .mp4, .webm\n")
    (tmp_path / "clips").mkdir()  # a folder first, as a still image's (was "unsupported video type '(none)'")
    rc, _, err = cli("render", cloud_file, "-o", tmp_path / "clips", "--turntable", 2, *SIZE)
    assert (rc, err) == (1, f"error: {tmp_path / 'clips'}: is a directory, not a video file\n")


def test_version(cli):
    import gigapoint

    assert cli("--version") == (0, f"gigapoint {gigapoint.__version__}\n", "")


# --- polish (fix-cli-polish) ---
FIELD_NAME = re.compile(r"\b[a-z]+(?:_[a-z]+)+\b")


def test_help_texts_name_options_not_python_names(cli, monkeypatch):
    """--attribute-range said 'values of color_attribute', --size-mode 'fixed: point_size
    pixels' (the Python names); bench's -W and -H had no help at all."""
    import typer

    from gigapoint.cli import app, commands  # noqa: F401  (commands registers them)
    from gigapoint.render.settings import RenderSettings, settings_fields

    fields = {spec.name for spec in settings_fields(RenderSettings)}
    group = typer.main.get_command(app)
    for name in ("render", "view", "convert", "bench"):
        for param in group.commands[name].params:
            assert param.help, (name, param.name)  # every option says what it does
            assert not fields & set(FIELD_NAME.findall(param.help)), (name, param.name, param.help)
    monkeypatch.setenv("COLUMNS", "400")  # one line an option
    rc, out, _ = cli("render", "--help")
    assert rc == 0
    assert "'low,high' values of --color-attribute mapped onto the colormap" in out
    assert "fixed: --point-size pixels (with --point-size 1: the exact one-pixel render); attenuated: --point-world-size, at most --point-size pixels" in out
    assert "it also means --size-mode attenuated, --point-size 16)" in out
    rc, out, _ = cli("bench", "--help")
    assert "Image width in pixels. [default: 1920]" in out and "Image height in pixels. [default: 1080]" in out


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="display check is for Linux")
def test_view_window_without_a_display_is_the_error_alone():
    """It printed 'gigapoint window: demo(1,000), 1,000 points (drag: orbit ...)' first."""
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    done = subprocess.run([sys.executable, "-m", "gigapoint.cli", "view", "--window", "--demo", "1000"], capture_output=True, text=True, env=env, timeout=120)
    hint = "install with: pip install 'gigapoint[window]' (rendercanvas + glfw) and run on a desktop with a display"
    assert (done.returncode, done.stdout, done.stderr) == (1, "", f"error: native window: no display (DISPLAY / WAYLAND_DISPLAY unset); {hint}\n")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="display check is for Linux")
def test_view_window_without_a_display_loads_nothing(cli, monkeypatch):
    """No display was found out only once the cloud was loaded (minutes for a large one)."""
    import gigapoint

    def load(*args, **kwargs):
        raise AssertionError("loaded the cloud")

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(gigapoint, "demo", load)
    rc, out, err = cli("view", "--window", "--demo", 1000)
    assert (rc, out) == (1, "") and err.startswith("error: native window: no display (DISPLAY / WAYLAND_DISPLAY unset); ")


def test_view_window_that_cannot_open_is_the_error_alone(cli, monkeypatch):
    """With a display, a window that failed to open (glfw, no GUI backend) came after the title line too."""
    from gigapoint.errors import BackendUnavailableError
    from gigapoint.viewer import window

    def refuse(cloud, *args, **kwargs):
        raise BackendUnavailableError("cannot open a window (no GLX)")

    monkeypatch.setenv("DISPLAY", ":99")
    monkeypatch.setattr(window, "open_window", refuse)
    assert cli("view", "--window", "--demo", 1000) == (1, "", "error: cannot open a window (no GLX)\n")


def test_convert_prints_the_output_as_given(cloud_file, tmp_path, cli, monkeypatch):
    """--workers 2 printed '/abs/path/oct: 3,000 points ...' (the Dask run resolves OUTPUT for
    its workers) where the one-process run printed 'oct: ...'."""
    import dataclasses

    import gigapoint.lod

    convert = gigapoint.lod.convert

    def as_a_dask_run(*args, **kwargs):  # its result: OUTPUT absolute
        result = convert(*args, **kwargs)
        return dataclasses.replace(result, out=result.out.resolve())

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(gigapoint.lod, "convert", as_a_dask_run)
    rc, out, err = cli("convert", cloud_file, "-o", "oct", "--quiet")
    assert rc == 0, err
    assert out.startswith("oct: 3,000 points in 1 node (gigapoint, grid), ")
