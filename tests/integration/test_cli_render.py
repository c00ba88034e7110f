"""`gigapoint render` and `gigapoint demo` end to end, including every bad input."""

import subprocess
import sys
from unittest.mock import patch

import laspy
import numpy as np
import pytest
from PIL import Image


@pytest.fixture(scope="module")
def small_las(tmp_path_factory):
    from gigapoint.io.demo import demo_arrays

    xyz, rgba, _ = demo_arrays(30_000)
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = [0.001] * 3
    header.offsets = [637_000.0, 851_000.0, 0.0]
    las = laspy.LasData(header)
    xyz = xyz + [637_000.0, 851_000.0, 0.0]
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.red, las.green, las.blue = (rgba[:, :3].astype(np.uint16) * 257).T
    path = tmp_path_factory.mktemp("las") / "town.las"
    las.write(path)
    return path


def test_render_writes_a_png_with_stats(cli, tmp_path, small_las):
    out = tmp_path / "town.png"
    rc, stdout, err = cli("render", small_las, "-o", out, "--width", 320, "--height", 200, "--stats", "--background", "white")
    assert rc == 0, err
    img = np.asarray(Image.open(out))
    assert img.shape == (200, 320, 4)
    assert (img[..., :3] != 255).any(axis=2).mean() > 0.05  # points drawn on white
    assert "30,000 of 30,000 points" in err and "batches drawn" in err
    assert "wrote" in stdout


def test_render_several_files_merge_into_one_scene(cli, tmp_path, small_las):
    import shutil

    out, copy = tmp_path / "two.png", tmp_path / "copy.las"
    shutil.copyfile(small_las, copy)  # another file (one named twice is read once)
    rc, _, err = cli("render", small_las, copy, "-o", out, "-W", 64, "-H", 64, "--stats")
    assert rc == 0, err
    assert "60,000 of 60,000 points" in err
    rc, _, err = cli("render", small_las, small_las, "-o", out, "-W", 64, "-H", 64, "--stats", "--overwrite")
    assert rc == 0 and "named more than once; its points are read once" in err and "30,000 of 30,000 points" in err, err


def test_max_points_previews_a_subsample(cli, tmp_path, small_las):
    out = tmp_path / "preview.png"
    rc, stdout, err = cli("render", small_las, "-o", out, "-W", 160, "-H", 100, "--stats", "--max-points", 15_000)
    assert rc == 0, err
    assert "15,000 of 30,000 points" in err  # every second point of each batch
    assert stdout.strip() == f"wrote {out} (160x100, 15,000 of 30,000 points drawn)"  # (it said '30,000 points', the cloud's)
    assert (np.asarray(Image.open(out))[..., :3] != 0).any(axis=2).mean() > 0.05


def test_max_points_caps_what_an_octree_draws(cli, tmp_path, small_las):
    """`render octree/ --max-points N` (and a file above the point budget, read into an octree
    progressively) drew the whole budget: the option was dropped without a word. Now it caps
    the point budget, as the viewer's cap does (the root node is always drawn)."""
    import re

    import gigapoint as gp

    gp.convert(small_las, tmp_path / "oct")
    drawn = {}
    for cap in (None, 20_000):
        out = tmp_path / f"{cap}.png"
        rc, _, err = cli("render", tmp_path / "oct", "-o", out, "-W", 320, "-H", 240, "--stats", *(["--max-points", cap] if cap else []))
        assert rc == 0, err
        drawn[cap] = int(re.match(r"([\d,]+) of", err).group(1).replace(",", ""))
        assert (np.asarray(Image.open(out))[..., :3] != 0).any(axis=2).mean() > 0.05
    assert drawn[None] == 30_000 and drawn[20_000] <= 20_000
    assert "memory: peak RSS" in err and "Octree" not in err  # (it said 'CompactOctree has no breakdown', a class's name)


def test_camera_options_and_extra_outputs(cli, tmp_path, small_las):
    depth, index = tmp_path / "d.npy", tmp_path / "i.npy"
    rc, _, err = cli(
        "render", small_las, "-o", tmp_path / "a.png", "-W", 80, "-H", 60,
        "--camera", "eye=637500,850500,400 target=637500,851500,0", "--depth-out", depth, "--index-out", index,
    )  # fmt: skip
    assert rc == 0, err
    d, i = np.load(depth), np.load(index)
    assert d.shape == (60, 80) and i.shape == (60, 80)
    assert np.isfinite(d[i >= 0]).all() and np.isinf(d[i < 0]).all()
    rc, _, err = cli("render", small_las, "-o", tmp_path / "b.png", "-W", 80, "-H", 60, "--camera", "yaw=30;pitch=60")
    assert rc == 0, err
    rc, _, err = cli("render", small_las, "-o", tmp_path / "c.jpg", "-W", 80, "-H", 60, "--view", "top", "--projection", "orthographic")
    assert rc == 0, err
    assert Image.open(tmp_path / "c.jpg").size == (80, 60)


def test_an_eye_and_target_camera_keeps_the_orthographic_projection(cli, tmp_path, small_las):
    """--projection orthographic with --camera eye=.. target=.. drew a perspective image (the
    projection was dropped); its height is the perspective view's at the target."""
    import gigapoint as gp

    cloud = gp.open(small_las)
    eye, target = (637_000.0, 851_000.0, 150.0), (637_000.0, 851_000.0, 0.0)
    images = {}
    for projection in ("perspective", "orthographic"):
        out = tmp_path / f"{projection}.png"
        rc, _, err = cli("render", small_las, "-o", out, "-W", 80, "-H", 60, "--size-mode", "fixed", "--projection", projection,
                         "--camera", "eye=637000,851000,150 target=637000,851000,0 up=0,1,0")  # fmt: skip
        assert rc == 0, err
        images[projection] = np.asarray(Image.open(out))
    cam = gp.Camera.look_at(eye, target, up=(0, 1, 0), width=80, height=60, projection="orthographic", ortho_height=2 * 150 * np.tan(np.radians(30)))
    np.testing.assert_array_equal(images["orthographic"], gp.render(cloud, cam, size_mode="fixed"))
    assert (images["orthographic"][..., :3] != 0).any(axis=2).mean() > 0.03  # points in view
    assert (images["orthographic"] != images["perspective"]).any()


def test_an_output_that_is_an_input_or_another_output_is_refused_before_anything_is_read(cli, tmp_path):
    """``--index-out pts.npy --overwrite`` replaced the points it drew with the index buffer."""
    pts = tmp_path / "tiles" / "pts.npy"
    pts.parent.mkdir()
    np.save(pts, np.random.default_rng(0).random((500, 3)))
    before = pts.read_bytes()
    for inputs, extra, problem in (
        ([pts], ["--index-out", pts], f"{pts}: is one of the inputs; write it elsewhere (it would replace the points being read)"),
        ([pts.parent], ["--depth-out", pts], f"{pts}: is one of the inputs"),  # a point cloud file of a folder named
        ([pts.parent / "*.npy"], ["--index-out", pts], f"{pts}: is one of the inputs"),  # a file a quoted pattern matches
        ([pts], ["--depth-out", tmp_path / "d.npy", "--index-out", tmp_path / "tiles" / ".." / "d.npy"], "d.npy: named for two outputs"),
    ):
        rc, _, err = cli("render", *inputs, "-o", tmp_path / "a.png", "-W", 32, "-H", 24, "--overwrite", *extra)
        assert rc == 1 and err.startswith("error: ") and problem in err and err.count("\n") == 1, err
        assert pts.read_bytes() == before and not (tmp_path / "a.png").exists()
    rc, _, err = cli("render", pts.parent, "-o", tmp_path / "tiles" / "a.png", "-W", 32, "-H", 24, "--index-out", tmp_path / "i.npy")
    assert rc == 0, err  # an image beside the points it draws is no input


def test_never_overwrites_without_asking(cli, tmp_path, small_las):
    out = tmp_path / "keep.png"
    out.write_bytes(b"precious")
    rc, _, err = cli("render", small_las, "-o", out)
    assert rc == 1 and "already exists" in err and "--overwrite" in err
    assert out.read_bytes() == b"precious"
    rc, _, err = cli("render", small_las, "-o", out, "-W", 32, "-H", 32, "--overwrite")
    assert rc == 0 and Image.open(out).size == (32, 32)


def test_a_failed_render_leaves_no_output_behind(cli, tmp_path, small_las):
    out = tmp_path / "x.png"
    rc, _, err = cli("render", small_las, "-o", out, "--camera", "eye=1,2,3")
    assert rc == 1 and not out.exists()
    assert not list(tmp_path.glob(".x.png*"))  # no temporary left either


@pytest.mark.parametrize(
    "args, message",
    [
        (["--width", "0"], "width"),
        (["--height", "100000"], "height"),
        (["--camera", "eye=1,2"], "--camera"),
        (["--camera", "eye=1,2,3"], "target"),
        (["--camera", "banana"], "--camera"),
        (["--camera", "eye=a,b,c target=0,0,0"], "--camera"),
        (["--camera", "eye=0,0,nan target=0,0,0"], "--camera"),
        (["--camera", "eye=1,1,1 target=1,1,1"], "--camera: camera eye and target are the same point"),
        (["--camera", "yaw=10 pitch=5 distance=0"], "--camera: orbit distance must be > 0"),
        (["--camera", "yaw=10 pitch=5", "--view", "top"], "--view top and --camera: give one"),  # --view was dropped
        (["--camera", "yaw=10 pitch=5 fov=30", "--fov", "40"], "--fov and --camera fov=: give one"),  # --fov was dropped
        (["--camera", "yaw=10 eye=1,1,1 target=0,0,0"], "not both"),
        (["--camera", "target=1,2,3"], "give eye=x,y,z target=x,y,z or yaw=deg pitch=deg"),  # was an internal KeyError
        (["--camera", "fov=30"], "give eye=x,y,z target=x,y,z or yaw=deg pitch=deg"),
        (["--camera", "yaw=10 yaw=20 pitch=5"], "yaw is given twice"),
        (["--camera", "yaw=10 pitch=5 up=1,0,0"], "up goes with eye and target"),
        (["--fov", "0"], "fov"),
        (["--view", "sideways"], "view"),
        (["--background", "chartreuse-ish"], "background"),
        (["--projection", "fisheye"], "projection"),
        (["--backend", "quantum"], "backend"),
        (["--threads", "0"], "threads"),
        (["--max-points", "-5"], "max_points"),
        (["--point-budget", "0"], "point_budget"),
    ],
)
def test_bad_options_give_one_line_errors(cli, tmp_path, small_las, args, message):
    out = tmp_path / "bad.png"
    rc, _, err = cli("render", small_las, "-o", out, *args)
    assert rc != 0
    if args[0] == "--camera":  # told before the inputs are read (it was once a large file was): a missing one is not reached
        rc, _, err_first = cli("render", tmp_path / "missing.laz", "-o", out, *args)
        assert rc == 1 and err_first == err, err_first
    lines = err.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], err
    assert "Traceback" not in err and not out.exists()


@pytest.mark.parametrize("suffix", [".gif2", ".txt", ""])
def test_bad_output_type(cli, tmp_path, small_las, suffix):
    rc, _, err = cli("render", small_las, "-o", tmp_path / f"out{suffix}")
    assert rc == 1 and "unsupported output type" in err


def test_an_image_its_format_cannot_hold_is_refused_before_the_render(cli, tmp_path, small_las):
    """A WebP 16 384 pixels wide was an 'internal error: ValueError: encoding error 5' once the
    render was done (libwebp's limit is 16 383); side-by-side stereo writes twice --width, and
    'wrote' says so (it said --width)."""
    out = tmp_path / "wide.webp"
    for args, size in ((["-W", 16_384, "-H", 8], "16384x8"), (["-W", 9000, "-H", 8, "--stereo", "side-by-side"], "18000x8")):
        rc, _, err = cli("render", small_las, "-o", out, *args)
        assert rc == 1 and err.strip().splitlines() == [f"error: {out}: a WebP image is at most 16,383 pixels a side, this one would be {size}; write .png or .tif"], err
        assert not out.exists()
    rc, out_text, err = cli("render", small_las, "-o", tmp_path / "s.webp", "-W", 40, "-H", 20, "--stereo", "side-by-side")
    assert rc == 0 and Image.open(tmp_path / "s.webp").size == (80, 20) and "(80x20, 30,000 points)" in out_text, err


def test_missing_input_and_output_folders_made_on_the_way(cli, tmp_path, small_las):
    rc, _, err = cli("render", tmp_path / "nope.laz", "-o", tmp_path / "new" / "o.png")
    assert rc == 1 and "nope.laz" in err and len(err.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []  # refused before any folder was made
    # the folders missing on each output's way are made as it is written, as convert -o's are
    # (an image, its depth and index, a map's surface model, a video were refused: 'directory X does not exist')
    out, depth, index = tmp_path / "a" / "b" / "o.png", tmp_path / "d" / "d.npy", tmp_path / "i" / "j" / "i.npy"
    rc, _, err = cli("render", small_las, "-o", out, "--depth-out", depth, "--index-out", index, "-W", 32, "-H", 24)
    assert rc == 0, err
    assert Image.open(out).size == (32, 24) and np.load(depth).shape == np.load(index).shape == (24, 32) and (np.load(index) >= 0).any()
    ortho, dsm = tmp_path / "m" / "map.tif", tmp_path / "dsm" / "sub" / "dsm.tif"
    rc, _, err = cli("render", small_las, "-o", ortho, "--gsd", 20, "--depth-out", dsm)
    assert rc == 0, err
    heights = np.asarray(Image.open(dsm))
    assert heights.dtype == np.float32 and heights.shape == np.asarray(Image.open(ortho)).shape[:2] and np.isfinite(heights).any()
    assert sorted(p.name for p in dsm.parent.iterdir()) == ["dsm.tfw", "dsm.tif"]  # its world file beside it
    video = tmp_path / "v" / "w" / "t.gif"
    rc, _, err = cli("render", small_las, "-o", video, "--turntable", 2, "-W", 32, "-H", 24)
    assert rc == 0 and Image.open(video).n_frames == 2, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "d", "dsm", "i", "m", "v"]
    afile = tmp_path / "afile"  # a file where the folder should be: was "Not a directory" once the render was done
    afile.write_bytes(b"x")
    for bad, args in ((afile / "o.png", []), (afile / "o.mp4", ["--turntable", 2]), (afile / "sub" / "d.npy", ["--depth-out", afile / "sub" / "d.npy"])):
        out = bad if not args or args[0] == "--turntable" else tmp_path / "o.png"
        rc, _, err = cli("render", small_las, "-o", out, *args, "-W", 32, "-H", 24)
        assert rc == 1 and err.strip().splitlines() == [f"error: {bad}: {afile} is a file, not a folder"], err
        assert not out.exists() and afile.read_bytes() == b"x"


def test_camera_looking_away_warns_and_renders_background(cli, tmp_path, small_las):
    out = tmp_path / "away.png"
    rc, _, err = cli("render", small_las, "-o", out, "-W", 40, "-H", 30, "--camera", "eye=0,0,0 target=-1,-1,0")
    assert rc == 0 and "no point is in view" in err
    assert (np.asarray(Image.open(out))[..., :3] == 0).all()


def test_demo_command(cli, tmp_path):
    out = tmp_path / "demo.png"
    rc, stdout, err = cli("demo", "--points", 50_000, "-o", out, "-W", 160, "-H", 90)
    assert rc == 0, err
    assert "M points/s" in stdout and "Morton sort" in stdout
    assert Image.open(out).size == (160, 90)
    rc, _, err = cli("demo", "--points", 0, "-o", tmp_path / "z.png")
    assert rc == 1 and "--points" in err
    rc, _, err = cli("demo", "--points", 1000, "--seed", 2**64, "-o", tmp_path / "s.png")  # an internal error in the generator
    assert rc == 1 and err == f"error: --seed: seed must be an integer from -9,223,372,036,854,775,807 to 9,223,372,036,854,775,807, got {2**64}\n"
    assert not (tmp_path / "s.png").exists()
    with patch("gigapoint.io.demo.demo_arrays", side_effect=AssertionError("the scene was generated")):
        rc, _, err = cli("demo", "--points", 1000, "--view", "sideways", "-o", tmp_path / "v.png")  # said once the scene was made, without --view
    assert rc == 1 and err == "error: --view: unknown view 'sideways'; choose one of top, front, back, side, left, right, iso, auto\n"


def test_demo_command_holds_the_town_at_1_cm_in_the_compact_layout(cli, tmp_path):
    """By default the town is quantized to 1 cm, as a LAS export holds it: the compact layout and
    per-block palettes, under 7 bytes a point of position and colour; --scale 0 keeps float
    positions in three words (16 bytes); a bad --scale is one line and exit 1, no image."""
    import re

    def pos_color(stdout):
        m = re.search(r"positions ([0-9.]+), color ([0-9.]+)", " ".join(stdout.split()))
        return float(m.group(1)) + float(m.group(2))

    rc, stdout, err = cli("demo", "--points", 200_000, "-o", tmp_path / "a.png", "-W", 160, "-H", 90)
    assert rc == 0, err
    assert "compact layout" in " ".join(stdout.split()) and pos_color(stdout) <= 7.0
    rc, stdout, err = cli("demo", "--points", 200_000, "-o", tmp_path / "b.png", "-W", 160, "-H", 90, "--scale", 0)
    assert rc == 0, err
    assert "words layout" in " ".join(stdout.split()) and pos_color(stdout) == 16.0
    for bad in ("nan", "-0.01", "1e9"):
        rc, _, err = cli("demo", "--points", 1000, "-o", tmp_path / "c.png", "--scale", bad)
        assert rc == 1 and "--scale" in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "c.png").exists()


def test_installed_entry_point_exit_codes(tmp_path, small_las):
    ok = subprocess.run([sys.executable, "-m", "gigapoint.cli", "render", str(small_las), "-o", str(tmp_path / "e.png"), "-W", "32", "-H", "32"], capture_output=True, text=True)
    assert ok.returncode == 0, ok.stderr
    bad = subprocess.run([sys.executable, "-m", "gigapoint.cli", "render", str(tmp_path / "missing.las"), "-o", str(tmp_path / "f.png")], capture_output=True, text=True)
    assert bad.returncode == 1 and bad.stderr.startswith("error: ") and "Traceback" not in bad.stderr


def test_console_script_skips_teardown_but_keeps_exit_handlers_output_and_threads(tmp_path, small_las):
    """``run`` (the console script) ends with os._exit: what a command printed into a pipe, the
    atexit handlers and a thread still running must all survive that, and the exit code too."""
    out = tmp_path / "r.png"
    code = (
        "import atexit, sys, threading, time\n"
        "from gigapoint.cli import run\n"
        "atexit.register(print, 'atexit ran')\n"
        "if sys.argv[1] == 'thread':\n"
        "    threading.Thread(target=lambda: (time.sleep(0.5), print('thread finished'))).start()\n"
        "sys.argv = ['gigapoint', *sys.argv[2:]]\n"
        "run()\n"
    )
    args = ["render", str(small_las), "-o", str(out), "-W", "48", "-H", "32"]
    ok = subprocess.run([sys.executable, "-c", code, "-", *args], capture_output=True, text=True)
    assert ok.returncode == 0, ok.stderr
    assert ok.stdout.splitlines() == [f"wrote {out} (48x32, 30,000 points)", "atexit ran"]
    assert np.asarray(Image.open(out)).shape == (32, 48, 4)
    bad = subprocess.run([sys.executable, "-c", code, "thread", "render", str(tmp_path / "missing.las"), "-o", str(tmp_path / "m.png")], capture_output=True, text=True)
    assert bad.returncode == 1 and "no such file" in bad.stderr
    assert "thread finished" in bad.stdout and "atexit ran" in bad.stdout  # waited for, the normal way


def test_ctrl_c_exits_130_with_a_message(tmp_path):
    """SIGINT in the middle of a command: exit status 130 and one line, never a silent 0."""
    import signal
    import subprocess
    import sys
    import time

    code = (
        # a shell's background job (CI runners can be one) starts with SIGINT ignored, which
        # children inherit: give the child what a terminal user's process has
        "import signal; signal.signal(signal.SIGINT, signal.default_int_handler)\n"
        "import time, gigapoint.cli as c, typer\n"
        "@c.app.command('sleepy-test')\n"
        "def sleepy():\n"
        "    print('ready', flush=True); time.sleep(30)\n"
        "raise SystemExit(c.main(['sleepy-test']))\n"
    )
    p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "ready"
    time.sleep(0.2)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=20)
    assert p.returncode == 130 and err.strip().splitlines()[-1] == "interrupted", (p.returncode, err)


def test_sigterm_exits_143_and_removes_the_half_written_file(tmp_path):
    """SIGTERM (kill, a batch system's stop) unwinds as Ctrl+C does: the temporary file of the
    output being written goes (a killed turntable left a playable half video beside OUT)."""
    import signal
    import subprocess
    import sys

    out = tmp_path / "out" / "video.mp4"
    out.parent.mkdir()
    code = (
        "import sys, time, gigapoint.cli as c\n"
        "from gigapoint.atomic import atomic_write\n"
        "@c.app.command('slow-write-test')\n"
        "def slow():\n"
        "    atomic_write(sys.argv[1], lambda tmp: (tmp.write_bytes(b'half'), print('ready', flush=True), time.sleep(30)))\n"
        "raise SystemExit(c.main(['slow-write-test']))\n"
    )
    p = subprocess.Popen([sys.executable, "-c", code, str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "ready"
    assert len(list(out.parent.iterdir())) == 1  # the temporary file, half written
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=20)
    assert (p.returncode, err.strip().splitlines()[-1:]) == (143, ["terminated"]), (p.returncode, err)
    assert list(out.parent.iterdir()) == []


def test_main_gives_back_the_callers_sigterm_handler():
    import signal

    from gigapoint.cli import main

    mine = signal.signal(signal.SIGTERM, lambda *a: None)
    try:
        handler = signal.getsignal(signal.SIGTERM)
        assert main(["--help"]) == 0
        assert signal.getsignal(signal.SIGTERM) is handler
    finally:
        signal.signal(signal.SIGTERM, mine)


# --- --colors and --chunked: how the files' points are held (cli/cloud_opts.py) -------------------
def color_bytes(err: str) -> float:
    line = next(x for x in err.splitlines() if x.startswith("memory:"))
    return float(line.split("color ")[1].split(",")[0])


@pytest.mark.parametrize(("colors", "per_point"), [("rgba", 4.0), ("rgb565", 2.0), ("palette", 1.14)])
def test_colors_option_chooses_how_colours_are_held(cli, tmp_path, small_las, colors, per_point):
    rc, _, err = cli("render", small_las, "-o", tmp_path / "c.png", "-W", 64, "-H", 48, "--stats", "--colors", colors)
    assert rc == 0, err
    assert color_bytes(err) == pytest.approx(per_point, abs=0.01)
    rc, out, err = cli("info", "--memory", "--colors", colors, small_las)
    assert rc == 0, err
    assert color_bytes(out) == pytest.approx(per_point, abs=0.01)


def test_info_of_a_folder_shows_every_file_it_can_read_and_names_the_others(cli, tmp_path, small_las):
    """One damaged file stopped info of a folder there: the files after it were never shown."""
    import json
    import shutil

    folder = tmp_path / "tiles"
    folder.mkdir()
    shutil.copy(small_las, folder / "a.las")
    (folder / "b.las").write_bytes(b"LASF" + bytes(50))  # damaged
    shutil.copy(small_las, folder / "c.las")
    rc, out, err = cli("info", folder)
    assert rc == 1 and out.count("points:") == 2 and f"{folder / 'c.las'}" in out
    lines = err.strip().splitlines()
    assert len(lines) == 2 and lines[0].startswith(f"error: {folder / 'b.las'}: ") and lines[1] == "error: info: 1 of 3 files could not be read (said above)"
    rc, out, err = cli("info", "--json", folder)
    rows = [json.loads(line) for line in out.strip().splitlines()]
    assert rc == 1 and [r["path"] for r in rows] == [str(folder / n) for n in ("a.las", "b.las", "c.las")]
    assert rows[1]["error"].startswith(f"{folder / 'b.las'}: ") and rows[2]["point_count"] == 30_000
    rc, out, err = cli("info", folder / "b.las")  # one file: its error alone
    assert rc == 1 and err.count("\n") == 1 and err.startswith(f"error: {folder / 'b.las'}: ")
    rc, out, err = cli("info", folder / "nope.las", folder / "a.las")  # a missing name stopped the others being shown
    assert rc == 1 and out.count("points:") == 1 and f"{folder / 'a.las'}" in out
    assert err.strip().splitlines() == [f"error: {folder / 'nope.las'}: no such file", "error: info: 1 of 2 files could not be read (said above)"]
    rc, out, err = cli("info", folder / "nope.las")
    assert rc == 1 and err == f"error: {folder / 'nope.las'}: no such file\n"


def test_chunked_option_builds_the_same_image(cli, tmp_path, small_las):
    images = []
    for flag in ("--chunked", "--no-chunked"):
        out = tmp_path / f"{flag}.png"
        rc, _, err = cli("render", small_las, "-o", out, "-W", 96, "-H", 64, flag)
        assert rc == 0, err
        images.append(np.asarray(Image.open(out)))
    np.testing.assert_array_equal(images[0], images[1])


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["render", "{las}", "-o", "{out}", "--colors", "rgb8"], "--colors: unknown colour format 'rgb8'"),
        (["render", "{las}", "-o", "{out}", "--colors", "rgba", "--progressive"], "--colors: "),
        (["render", "{las}", "-o", "{out}", "--chunked", "--progressive"], "--chunked: "),
        (["info", "{las}", "--colors", "palette"], "--colors: only with --memory"),
        (["info", "{las}", "--memory", "--colors", "PALETTE"], "--colors"),
        (["demo", "-n", "1000", "-o", "{out}", "--colors", "16bit"], "--colors"),
        (["view", "--live", "demo", "--colors", "rgba"], "--colors: "),
        (["view", "--demo", "1000", "--progressive", "--no-chunked"], "--chunked: "),
        (["view", "{las}", "--colors", "x"], "--colors"),
    ],
)
def test_colors_and_chunked_errors_name_the_option(cli, tmp_path, small_las, args, message):
    out = tmp_path / "bad.png"
    rc, _, err = cli(*(a.format(las=small_las, out=out) for a in args))
    assert rc == 1
    lines = err.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], err
    assert not out.exists()


def test_colors_option_refuses_an_octree(cli, tmp_path, small_las):
    import gigapoint as gp

    octree = tmp_path / "octree"
    gp.convert([str(small_las)], octree, max_leaf=20_000)
    rc, _, err = cli("render", octree, "-o", tmp_path / "o.png", "--colors", "rgb565")
    assert rc == 1 and len(err.strip().splitlines()) == 1
    assert "--colors: " in err and "is an octree" in err


def test_info_memory_of_an_octree_says_why_there_is_no_figure(cli, tmp_path, small_las):
    """``info OCTREE --memory`` printed nothing of memory, without a word."""
    import json

    import gigapoint as gp

    octree = tmp_path / "octree"
    gp.convert([str(small_las)], octree, max_leaf=20_000)
    why = "an octree is read node by node as views need them; --memory measures point files"
    rc, out, _ = cli("info", octree, "--memory")
    assert rc == 0 and out.strip().splitlines()[-1] == f"memory: {why}"
    rc, out, _ = cli("info", octree, "--memory", "--json")
    assert rc == 0 and json.loads(out.strip().splitlines()[-1]) == {"path": str(octree), "memory": None, "why": why}
