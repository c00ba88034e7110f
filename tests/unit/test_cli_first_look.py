"""What a new user meets first (issue #17): compiling said aloud, progress on a terminal only,
clean --help, info formatted from the file's scale, picking an empty pixel, overwrite rules."""

from __future__ import annotations

import io
import json
import re

import numba
import numpy as np
import pytest
from rich.console import Console

import gigapoint as gp
from gigapoint.cli import compiling
from gigapoint.cli.progress import progress_bar
from gigapoint.errors import GigapointError, PointIndexError


def terminal() -> tuple[Console, io.StringIO]:
    buf = io.StringIO()
    return Console(file=buf, force_terminal=True, width=100), buf


def fresh_kernel():
    """A numba kernel of 'gigapoint' that no cache holds: its first call compiles."""

    def kernel(x):
        return x * 2 + 1

    kernel.__module__ = "gigapoint._first_look_test"
    return numba.njit(kernel)


# --- compiling, said aloud --------------------------------------------------------------------------
def test_a_compile_shows_the_notice_on_a_terminal_and_a_warm_call_nothing():
    console, buf = terminal()
    kernel = fresh_kernel()
    with compiling.watching(console) as watch:
        assert kernel(20) == 41
    assert watch.kernels == 1 and watch.seconds > 0
    text = buf.getvalue()
    assert compiling.MESSAGE in text and "kernel" in text  # the spinner, then the closing line... or the spinner alone
    console, buf = terminal()
    with compiling.watching(console) as watch:
        assert kernel(21) == 43  # compiled: no event, no notice
    assert watch.kernels == 0 and buf.getvalue() == ""


def test_no_notice_when_piped():
    buf = io.StringIO()
    with compiling.watching(Console(file=buf)) as watch:  # not a terminal
        fresh_kernel()(1)
    assert watch.kernels == 1 and buf.getvalue() == ""


def test_numba_helpers_alone_do_not_count():
    @numba.njit
    def not_ours(x):
        return x + 1

    with compiling.watching(Console(file=io.StringIO())) as watch:
        not_ours(1)
    assert watch.kernels == 0


def test_a_progress_bar_on_a_terminal_only_and_the_compile_notice_inside_it():
    console, buf = terminal()
    with progress_bar("frames", 3, console) as advance:
        for i in range(3):
            advance(i + 1)
    assert "frames" in buf.getvalue()
    piped = io.StringIO()
    with progress_bar("frames", 3, Console(file=piped)) as advance:
        advance(1, "text")
    assert piped.getvalue() == ""
    console, buf = terminal()
    with compiling.watching(console) as watch, progress_bar("frames", 2, console) as advance:
        assert watch.sink is not None  # the bar shows the notice: one live display at a time
        fresh_kernel()(3)
        advance(2)
    assert watch.sink is None and watch.kernels == 1


def test_compile_command_reports_each_step(cli, monkeypatch):
    from gigapoint.cli import compile_cmd

    kernel = fresh_kernel()
    monkeypatch.setattr(compile_cmd, "steps", lambda folder: [("a kernel", lambda: kernel(1)), ("the same again", lambda: kernel(2))])
    rc, out, err = cli("compile")
    assert rc == 0, err
    lines = out.splitlines()
    assert re.match(r"\s+a kernel\s+compiled in \d+\.\d s$", lines[0]) and re.match(r"\s+the same again\s+cached$", lines[1])
    assert "later runs load them from numba's cache" in lines[-1]
    rc, out, _ = cli("compile")
    assert rc == 0 and out.splitlines()[-1].startswith("every kernel was compiled already")


def test_compile_command_promises_no_cache_where_numba_could_not_save(cli, monkeypatch):
    """A read-only install (or a full disk) compiles in memory: "later runs load them" was untrue."""
    from gigapoint.cli import compile_cmd
    from gigapoint.core import kernel_cache

    kernel = fresh_kernel()
    monkeypatch.setattr(compile_cmd, "steps", lambda folder: [("a kernel", lambda: kernel(1))])
    monkeypatch.setattr(kernel_cache, "_done", kernel_cache._done | {"save"})  # as after a failed save
    rc, out, err = cli("compile")
    assert rc == 0, err
    assert out.splitlines()[-1].endswith("; numba could not save them in its cache: later runs compile them again")


def test_the_real_compile_steps_cover_every_pass(tmp_path):
    from gigapoint.cli.compile_cmd import steps

    names = " ".join(name for name, _ in steps(tmp_path))
    for word in ("LAS", "demo", "rendering", "point sizes", "eye-dome", "hole filling", "high-quality", "supersampling", "color modes", "octrees", "progressive"):
        assert word in names


def test_the_progressive_step_compiles_the_colour_sums_of_big_sets_too(tmp_path):
    """A progressive octree's sets of 2^24 points and more sum colours in u64 (smaller ones in
    u32): that variant of sample_runs compiled mid-load on the first big set. The compile step
    leaves both: the same signature, the sums u32 in one and u64 in the other."""
    import inspect

    from gigapoint.cli.compile_cmd import steps
    from gigapoint.lod.progressive import kernels

    dict(steps(tmp_path))["progressive loading"]()
    at = list(inspect.signature(kernels.sample_runs.py_func).parameters).index("e_sum")
    by_sums = {str(signature[at].dtype): signature[:at] + signature[at + 1 :] for signature in kernels.sample_runs.signatures}
    assert {"uint32", "uint64"} <= set(by_sums)
    assert by_sums["uint32"] == by_sums["uint64"]


# --- --help ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("command", [[], ["render"], ["info"], ["convert"], ["view"], ["bench"], ["demo"], ["compile"]])
def test_help_lists_no_bool_type_for_flags_and_no_braced_arguments(cli, monkeypatch, command):
    monkeypatch.setenv("COLUMNS", "160")
    rc, out, err = cli(*command, "--help")
    assert rc == 0, err
    assert "<bool>" not in out and not re.search(r"\{\w+\}", out), out
    assert re.search(r"--help\s+Show this message", out)
    if command in (["render"], ["info"], ["convert"]):
        usage = next(line for line in out.splitlines() if "Usage:" in line)
        assert re.search(r"\[OPTIONS\] [A-Z]+\.\.\.", usage), usage


@pytest.mark.parametrize(("command", "option", "text"), [
    ("convert", "--dask", "(needs gigapoint[dask])"), ("convert", "--workers", "(needs gigapoint[dask])"),
    ("render", "--fps", "[default: 30]"), ("view", "--keep", "[default: 100]"),
])
def test_help_keeps_bracketed_words(cli, monkeypatch, command, option, text):
    # rich read '[dask]' and '[default: 30]' as markup and dropped them from --help
    monkeypatch.setenv("COLUMNS", "400")
    rc, out, err = cli(command, "--help")
    assert rc == 0, err
    line = next(line for line in out.splitlines() if f" {option} " in line)
    assert text in line, line


@pytest.mark.parametrize(("args", "line"), [
    (["convert", "x.laz", "-o", "o", "--workers", "abc"], "gigapoint convert: --workers: 'abc' is not a valid integer"),
    (["tile", "x.laz", "-o", "t", "--size", "abc"], "gigapoint tile: --size: 'abc' is not a valid number"),
    (["tile", "x.laz", "-o", "t"], "gigapoint tile: missing option --size"),
    # click suggested options over difflib's 0.6 ('--bogus (Possible options: --gsd)'): only close ones now
    (["render", "x.laz", "--bogus"], "gigapoint render: no such option: --bogus"),
    (["render", "x.laz", "--outptu", "x.png"], "gigapoint render: no such option: --outptu; did you mean --output?"),
    (["render", "x.laz", "--ips=0.1"], "gigapoint render: no such option: --ips; did you mean --ipd or --fps?"),
    (["render", "x.laz", "--point"], "gigapoint render: no such option: --point; did you mean --point-size, --point-shape or --point-budget?"),
    (["render", "x.laz", "--c"], "gigapoint render: no such option: --c"),
    (["--verson"], "gigapoint: no such option: --verson; did you mean --version?"),
    (["render"], "gigapoint render: missing argument INPUTS"),
    (["tile", "x.laz", "-o", "t", "--size"], "gigapoint tile: option '--size' requires an argument"),
    (["rendr", "x.laz"], "gigapoint: no such command 'rendr'. Did you mean 'render'?"),
])  # fmt: skip
def test_a_usage_error_is_one_line_naming_the_option(cli, tmp_path, monkeypatch, args, line):
    """click printed the usage line, a 'Try ... --help' line and 'Error: Invalid value for
    '--workers': Input should be a valid integer, unable to parse string as an integer'."""
    monkeypatch.chdir(tmp_path)
    rc, out, err = cli(*args)
    command = line.split(":")[0]
    assert (rc, out, err) == (2, "", f"error: {line} (see {command} --help)\n")


def test_gigapoint_alone_still_shows_its_help(cli):
    rc, out, err = cli()
    assert rc == 2 and "Usage: gigapoint [OPTIONS] COMMAND" in out + err and "error:" not in out + err


# --- info formatted from the file's scale -------------------------------------------------------------
def test_info_prints_bounds_with_the_decimals_of_the_scale(cli, las_writer, tmp_path):
    path = las_writer(tmp_path / "mm.las", 5_000)  # scale 0.001
    rc, out, err = cli("info", path)
    assert rc == 0, err
    for label in ("bounds min", "bounds max", "extent"):
        values = next(line for line in out.splitlines() if line.strip().startswith(label + ":")).split(":", 1)[1]
        values = values.replace("(header)", "").strip().split(", ")
        assert len(values) == 3 and all(re.fullmatch(r"-?\d+\.\d{3}", v) for v in values), values  # no 1,234 separators


def test_info_on_real_utm_data(cli, autzen_path):
    rc, out, _ = cli("info", autzen_path)
    assert rc == 0
    assert "bounds min:  636001.76, 848935.20, 406.26 (header)" in out
    assert "extent:      1177.46, 562.70, 114.25" in out


def test_info_of_a_converted_octree_prints_bounds_at_the_source_scale(cli, autzen_path, tmp_path):
    """A gigapoint octree records its LAS grid (format 2): info prints its bounds at that scale's
    decimals, not float noise (848935.2000000001) or a fixed 3."""
    out = tmp_path / "oct"
    gp.convert([autzen_path], out)
    rc, text, err = cli("info", out)
    assert rc == 0, err
    assert "bounds min:  636001.76, 848935.20, 406.26" in text and "extent:      1177.46, 562.70, 114.25" in text, text
    assert "scale:       0.01, 0.01, 0.01" in text and "offset:" not in text


def test_info_of_a_reprojected_octree_prints_bounds_at_its_scale_not_float_digits(cli, autzen_path, tmp_path):
    """An octree converted --to-crs holds the moved points as floats on no grid: info printed
    them with as many decimals as reach them (494115.3218665); now the scale's, as a LAS file
    converted the same way prints them (docs/survey.md section 11)."""
    out = tmp_path / "utm"
    rc, _, err = cli("convert", autzen_path, "-o", out, "--to-crs", "EPSG:32610")
    assert rc == 0, err
    rc, text, err = cli("info", out)
    assert rc == 0, err
    assert "scale:       0.001, 0.001, 0.01" in text, text
    assert "bounds min:  494115.322, 4877429.190, 406.26\n" in text, text
    assert "bounds max:  494475.305, 4877589.854, 520.51\n" in text and "extent:      359.983, 160.664, 114.25\n" in text, text


# --- picking -------------------------------------------------------------------------------------------
def test_point_info_of_an_empty_pixel_is_none_and_a_bad_index_a_clear_error():
    cloud = gp.from_arrays(np.random.default_rng(1).random((500, 3)) * 10)
    cam = gp.Camera.fit(cloud.bounds, width=64, height=48)
    frame = gp.render_frame(cloud, cam, gp.RenderSettings(backend="cpu", size_mode="fixed"))
    ys, xs = np.nonzero(frame.index == -1)
    empty = int(frame.index[ys[0], xs[0]])
    assert empty == -1 and cloud.point_info(empty) is None and frame.point_info(empty) is None
    hit = int(frame.index[frame.index >= 0][0])
    assert cloud.point_info(hit)["index"] == hit and frame.point_info(hit)["index"] == hit
    for bad in (500, -2, 10**9):
        with pytest.raises(PointIndexError, match=r"out of range 0\.\.499 \(-1: no point\)"):
            cloud.point_info(bad)
    for bad in (3.5, float(hit), "3", None, True):  # 3.5 was read as point 3
        for where in (cloud, frame):
            with pytest.raises(PointIndexError, match=r"^point index must be a whole number \(frame.index\[y, x\]\), got "):
                where.point_info(bad)
    assert frame.point_info(np.int64(hit))["index"] == hit
    for bad in ([10**9], [-1], [0, 500]):  # positions() read past its arrays: a segmentation fault
        with pytest.raises(PointIndexError, match=rf"point index {bad[-1]} out of range 0\.\.499$"):
            cloud.positions(bad)
    with pytest.raises(PointIndexError, match=r"point indices must be whole numbers, got float64$"):
        cloud.positions([1.5])
    for bad in ([-1], [0, 500], [10**9]):  # batch_of(-1) was an OverflowError, one past the end the last batch
        with pytest.raises(PointIndexError, match=rf"point index {bad[-1]} out of range 0\.\.499$"):
            cloud.batch_of(bad)
    assert cloud.batch_of([0, 499]).tolist() == [0, len(cloud.batches) - 1]
    assert cloud.positions([]).shape == (0, 3) and np.array_equal(cloud.positions([hit, 0]), cloud.positions()[[hit, 0]])
    assert issubclass(PointIndexError, IndexError) and issubclass(PointIndexError, GigapointError)


def test_picked_positions_read_as_the_file_wrote_them(autzen_path):
    """A LAS file's points come back rounded to its scale (0.01 here), not 636317.7100002308."""
    import laspy

    cloud = gp.open(autzen_path)
    assert cloud.source_scale == (0.01, 0.01, 0.01)
    las = laspy.read(autzen_path)
    file_xyz = {(round(x, 2), round(y, 2), round(z, 2)) for x, y, z in zip(las.x[:2000], las.y[:2000], las.z[:2000])}
    raw = cloud.positions(np.arange(0, cloud.n_points, 97))
    assert np.abs(raw * 100 - np.round(raw * 100)).max() < 1e-7  # the decoded positions are the file's to float64 rounding...
    hits = 0
    for i in range(0, cloud.n_points, 97):
        pos = cloud.point_info(i)["position"]
        assert all(repr(v) == repr(round(v, 2)) for v in pos), pos  # ...point_info none
        hits += tuple(pos) in file_xyz
    assert hits > 0  # and they are the file's own values
    assert gp.from_arrays(np.zeros((3, 3))).source_scale is None


def test_the_finest_scale_of_several_files(las_writer, tmp_path):
    import laspy

    a = las_writer(tmp_path / "a.las", 2_000)  # 0.001
    las = laspy.read(a)
    las.header.scales = np.array([0.01, 0.01, 0.01])
    las.write(tmp_path / "b.las")
    assert gp.open(tmp_path / "b.las").source_scale == (0.01, 0.01, 0.01)
    assert gp.open(a, tmp_path / "b.las").source_scale == (0.001, 0.001, 0.001)


# --- overwrite, worded for the caller --------------------------------------------------------------------
def test_turntable_does_not_replace_a_file_silently(tmp_path):
    pytest.importorskip("PIL")
    cloud = gp.demo(5_000)
    out = tmp_path / "spin.gif"
    out.write_bytes(b"mine")
    with pytest.raises(GigapointError, match=r"already exists; pass overwrite=True to replace it") as err:
        gp.render_turntable(cloud, 2, out, width=32, height=24)
    assert "--overwrite" not in str(err.value) and out.read_bytes() == b"mine"
    frames = []
    gp.render_turntable(cloud, 2, out, width=32, height=24, overwrite=True, progress=lambda done, total: frames.append((done, total)))
    assert out.read_bytes()[:3] == b"GIF" and frames == [(1, 2), (2, 2)]


def test_convert_says_overwrite_true_to_python_and_overwrite_to_the_command_line(tmp_path, cli, las_writer):
    from gigapoint.lod import OutputExistsError

    src = las_writer(tmp_path / "in.las", 3_000)
    out = tmp_path / "oct"
    gp.convert([src], out)
    with pytest.raises(OutputExistsError, match=r"pass overwrite=True to replace it") as err:
        gp.convert([src], out)
    assert "--overwrite" not in str(err.value)
    rc, _, stderr = cli("convert", src, "-o", out, "--quiet")
    assert rc == 1 and "pass --overwrite to replace it" in stderr and "overwrite=True" not in stderr
    assert cli("render", src, "-o", tmp_path / "x.png", "-W", 64, "-H", 48)[0] == 0
    rc, _, stderr = cli("render", src, "-o", tmp_path / "x.png", "-W", 64, "-H", 48)  # again: the image exists
    assert rc == 1 and "already exists; pass --overwrite to replace it" in stderr


def test_convert_says_how_to_watch_it_only_once_it_runs(tmp_path, cli, las_writer):
    """The hint to watch the output comes once the inputs and OUT are checked: a refused run
    (OUT holds a conversion, an empty input, a bad option) prints only its one-line error."""
    src = las_writer(tmp_path / "in.las", 3_000)
    (tmp_path / "empty.las").write_bytes(b"")
    out = tmp_path / "oct"
    rc, _, stderr = cli("convert", src, "-o", out)
    assert rc == 0 and f"`gigapoint view {out}` shows what has been read so far" in stderr
    for args in ((src, "-o", out), (tmp_path / "empty.las", "-o", tmp_path / "b"), (src, "-o", tmp_path / "c", "--memory-limit", "lots")):
        rc, _, stderr = cli("convert", *args)
        assert rc == 1 and stderr.startswith("error: ") and stderr.count("\n") == 1, stderr


# --- the Potree writer and info --------------------------------------------------------------------------
def test_potree_info_lists_its_attributes_and_keeps_the_crs(tmp_path, cli, autzen_path):
    from gigapoint.lod import octree_info

    out = tmp_path / "potree"
    gp.convert([autzen_path], out, format="potree")
    meta = json.loads((out / "metadata.json").read_text())
    assert "NAD_1983_HARN_Lambert_Conformal_Conic" in meta["projection"]
    info = octree_info(out)
    assert {"intensity", "classification"} <= set(info["attributes"]) and "NAD_1983" in info["crs"]
    rc, text, _ = cli("info", out)
    assert rc == 0 and "attributes:  none" not in text and "intensity" in text and "crs:" in text and "NAD_1983" in text


def test_the_viewer_process_prefers_passive_openmp_waits(monkeypatch):
    """`gigapoint view` (and `demo --live`) set OMP_WAIT_POLICY=passive before any kernel runs,
    unless the user set it: their frames share the cores with a loader or a sensor's producer."""
    import os

    from gigapoint.cli.app import prefer_passive_wait

    monkeypatch.delenv("OMP_WAIT_POLICY", raising=False)
    prefer_passive_wait()
    assert os.environ["OMP_WAIT_POLICY"] == "passive"
    monkeypatch.setenv("OMP_WAIT_POLICY", "active")
    prefer_passive_wait()
    assert os.environ["OMP_WAIT_POLICY"] == "active"


def test_a_bad_pick_is_the_same_one_line_error_in_every_kind_of_cloud(tmp_path):
    """An octree's frame gave numpy's IndexError or OverflowError for an index outside its
    arena, a progressive octree's an empty dict; the plain cloud's PointIndexError for all,
    whether asked of the frame or of the buffers it drew (an arena, a pool, a live ring)."""
    from gigapoint.live import LiveCloud
    from gigapoint.lod.progressive.octree import ProgressiveOctree

    xyz = np.random.default_rng(2).random((3000, 3)) * 10
    np.save(tmp_path / "p.npy", xyz)
    gp.convert([tmp_path / "p.npy"], tmp_path / "oct")
    progressive = ProgressiveOctree("prog")
    progressive.add(xyz)
    live = LiveCloud()
    live.push(xyz)
    for cloud in (gp.from_arrays(xyz), gp.open(tmp_path / "oct"), progressive, live):
        frame = gp.render_frame(cloud, gp.Camera.fit_cloud(cloud, width=64, height=48))
        hit = int(frame.index[frame.index >= 0][0])
        assert frame.point_info(hit)["position"] is not None and frame.point_info(-1) is None
        assert frame.points.point_info(hit) == frame.point_info(hit) and frame.points.point_info(-1) is None
        for bad in (10**9, -2, 2**40):
            for where in (frame, frame.points):
                with pytest.raises(PointIndexError, match=rf": point index {bad} out of range 0\.\.\d+ \(-1: no point\)$"):
                    where.point_info(bad)


def test_info_of_a_copc_output_still_being_converted_names_its_work_folder(cli, tmp_path):
    """A COPC file appears only once its conversion completes; until then ``<out>.work`` holds
    the partial work. info named only a missing file, as if the conversion had never run."""
    out = tmp_path / "out.copc.laz"
    (tmp_path / "out.copc.laz.work" / ".partial").mkdir(parents=True)
    (tmp_path / "out.copc.laz.work" / ".partial" / "state.json").write_text('{"phase": "read"}')  # (a conversion's: an empty folder is none)
    rc, _, err = cli("info", out)
    assert rc == 1
    assert err.count("\n") == 1 and f"{out}: no such file yet: a conversion to it is unfinished" in err, err
    assert f"work folder {out}.work" in err and "run the same convert command again to resume it" in err, err
