"""A demanding Python user's bad input to the API (gp.from_arrays, a progressive octree's add, a
live cloud's push, without_classes, point_info, save, Camera, gp.open, gp.convert, a progressive
load that fails): each case is one line of gigapoint's own errors naming the input and the
problem; never numpy's traceback, a hang, NaN points drawn or bounds gone NaN, or the user's
files touched."""

from __future__ import annotations

import re

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import CameraError, InputError, PointIndexError, SettingsError
from gigapoint.io import expand_paths
from gigapoint.lod.progressive import ProgressiveOctree

XYZ = np.arange(30, dtype=np.float64).reshape(10, 3)
CLASSES = np.repeat(np.array([1, 2], np.uint8), 5)

# positions that are no numbers: complex ones lost their imaginary part (a ComplexWarning), bools
# were 0 and 1, an object array's None a NaN point dropped without a word (an octree's add then
# returned 0), strings were parsed as numbers; a ragged list was numpy's ValueError
NOT_POSITIONS = [
    ("complex", np.ones((3, 3), complex), "xyz must hold numbers (integers or floats), got dtype complex128"),
    ("bool", np.ones((3, 3), bool), "xyz must hold numbers (integers or floats), got dtype bool"),
    ("object", np.array([[1.0, 2.0, None]] * 3, dtype=object), "xyz must hold numbers (integers or floats), got dtype object"),
    ("strings", np.array([["1", "2", "3"]] * 3), "xyz must hold numbers (integers or floats), got dtype <U1"),
    ("ragged", [[1.0, 2.0, 3.0], [4.0, 5.0]], "xyz must be an (N, 3) array of numbers, got a ragged list"),
]  # fmt: skip


@pytest.mark.parametrize(("values", "problem"), [case[1:] for case in NOT_POSITIONS], ids=[case[0] for case in NOT_POSITIONS])
@pytest.mark.parametrize(
    ("where", "call"),
    [
        ("arrays", lambda xyz: gp.from_arrays(xyz)),
        ("oct", lambda xyz: ProgressiveOctree("oct").add(xyz)),
        ("live: push", lambda xyz: gp.LiveCloud(name="live").push(xyz)),
    ],
    ids=["from_arrays", "progressive-add", "live-push"],
)
def test_positions_that_are_no_numbers_are_one_line(where, call, values, problem):
    with pytest.raises(InputError, match=f"^{re.escape(f'{where}: {problem}')}$"):
        call(values)


# colours outside any range a colour has: clipped to black or white without a word
BAD_COLORS = [
    ("nan", np.full((10, 3), np.nan), "nan"),
    ("negative-float", np.full((10, 3), -5.0), "-5.0"),
    ("negative-int", np.full((10, 3), -1), "-1"),
    ("over-16-bits", np.full((10, 3), 70_000, np.uint32), "70000"),
]  # fmt: skip


@pytest.mark.parametrize(("rgb", "value"), [case[1:] for case in BAD_COLORS], ids=[case[0] for case in BAD_COLORS])
@pytest.mark.parametrize(
    ("where", "call"),
    [
        ("arrays", lambda rgb: gp.from_arrays(XYZ, rgb)),
        ("arrays: set_colors", lambda rgb: gp.from_arrays(XYZ).set_colors(rgb)),
        ("oct", lambda rgb: ProgressiveOctree("oct").add(XYZ, rgb)),
        ("live: push", lambda rgb: gp.LiveCloud(name="live").push(XYZ, rgb)),
    ],
    ids=["from_arrays", "set_colors", "progressive-add", "live-push"],
)
def test_colors_out_of_any_range_are_one_line(where, call, rgb, value):
    with pytest.raises(InputError, match=f"^{re.escape(f'{where}: colors must be 0..1, 0..255 or 0..65535 (16 bits), got {value}')}$"):
        call(rgb)


def test_colors_of_each_range_are_taken():
    """Floats of 0..1 and of 0..255 and 16-bit integers are the same grey."""
    for rgb in (np.full((10, 3), 0.5), np.full((10, 3), 128.0), np.full((10, 3), 128 * 256, np.uint16)):
        assert gp.from_arrays(XYZ, rgb).rgba[0].tolist() == [128, 128, 128, 255]


def test_without_classes_refuses_what_is_no_las_class():
    """'a', -1 and 1.5 hid nothing without a word (the cloud came back whole)."""
    cloud = gp.from_arrays(XYZ, classification=CLASSES)
    for hidden, problem in (
        ("a", "hidden must be LAS classes (whole numbers in 0..255, e.g. 7,18), got 'a'"),
        ([-1], "hidden: -1 is not a LAS class (whole numbers in 0..255), got [-1]"),
        ([1.5], "hidden: 1.5 is not a LAS class (whole numbers in 0..255), got [1.5]"),
        (None, "hidden must be LAS classes (whole numbers in 0..255, e.g. 7,18), got None"),
    ):
        with pytest.raises(SettingsError, match=f"^{re.escape(f'arrays: without_classes: {problem}')}$"):
            cloud.without_classes(hidden)
    assert cloud.without_classes([2]).n_points == 5 and cloud.without_classes("1,2").n_points == 0


def _closed_octree():
    octree = ProgressiveOctree("oct")
    octree.close()
    return octree


# cases that were already one line: kept so (a table of what the API says)
@pytest.mark.parametrize(
    ("call", "error", "message"),
    [
        (lambda: ProgressiveOctree("oct").add(XYZ[:, :2]), InputError, "oct: xyz must have shape (N, 3), got (10, 2)"),
        (lambda: ProgressiveOctree("oct").add(np.c_[XYZ, XYZ[:, 0]]), InputError, "oct: xyz must have shape (N, 3), got (10, 4)"),
        (lambda: ProgressiveOctree("oct").add(XYZ[:, 0]), InputError, "oct: xyz must have shape (N, 3), got (10,)"),
        (lambda: ProgressiveOctree("oct").add(XYZ, rgb=np.zeros((9, 3), np.uint8)), InputError, "oct: rgb has 9 rows, xyz has 10"),
        (lambda: ProgressiveOctree("oct").add(XYZ, rgb=np.full((10, 3), "a")), InputError, "oct: colors must be numbers, got dtype <U1"),
        (lambda: ProgressiveOctree("oct").add(XYZ, intensity=np.zeros(9)), InputError, "oct: attribute 'intensity' must be 1-D of length 10, got shape (9,)"),
        (lambda: _closed_octree().add(XYZ), InputError, "oct: the octree is closed; open it again to add points"),
        (lambda: gp.from_arrays(np.empty((0, 3))), InputError, "arrays: no valid points"),
        (lambda: gp.from_arrays(XYZ).point_info(10), PointIndexError, "arrays: point index 10 out of range 0..9 (-1: no point)"),
        (lambda: gp.from_arrays(XYZ).point_info(-2), PointIndexError, "arrays: point index -2 out of range 0..9 (-1: no point)"),
        (lambda: gp.Camera.look_at((1, 1, 1), (1, 1, 1)), CameraError, "camera eye and target are the same point"),
        (lambda: gp.Camera.look_at((20, 20, 20), (5, 5, 5), width=0), CameraError, "image width must be an integer in 1..16384, got 0"),
        (lambda: gp.open([]), InputError, "open: no file given"),
        (lambda: gp.open([], progressive=True), InputError, "open: no file given"),
        # (errors.check_whole: numpy's integer in digits, not np.int64(0); a float as one, why it is refused)
        (lambda: gp.demo(n_points=np.int64(0)), InputError, "demo: n_points must be an integer >= 1, got 0"),
        (lambda: gp.demo(n_points=2.0), InputError, "demo: n_points must be an integer >= 1, got 2.0"),
    ],
    ids=["add-N2", "add-N4", "add-1d", "add-rgb-rows", "add-rgb-strings", "add-attribute-rows", "add-closed", "from-arrays-empty",
         "point-info-past-end", "point-info-minus-2", "camera-eye-is-target", "camera-width-0", "open-empty-list", "open-progressive-empty-list",
         "demo-numpy-integer", "demo-float"],
)  # fmt: skip
def test_bad_input_is_one_line(call, error, message):
    with pytest.raises(error, match=f"^{re.escape(message)}$"):
        call()


def test_a_nan_row_is_skipped_not_drawn():
    """NaN and inf rows added are left out and counted: the bounds stay those of the others."""
    octree = ProgressiveOctree("oct")
    assert octree.add(np.vstack([XYZ, [[np.nan, 0, 0], [np.inf, 1, 1]]])) == 10
    assert octree.skipped == 2 and [b.tolist() for b in octree.bounds] == [[0, 1, 2], [27, 28, 29]]
    with pytest.warns(gp.GigapointWarning, match=r"^arrays: skipped 1 invalid point \(NaN, inf or beyond ±1e\+12\)$"):
        assert gp.from_arrays(np.vstack([XYZ, [[np.nan, 0, 0]]])).n_points == 10


def test_a_pattern_matching_nothing_names_it(tmp_path):
    pattern = str(tmp_path / "*.laz")
    for progressive in (False, True):
        with pytest.raises(InputError, match=f"^{re.escape(pattern)}: matches no file$"):
            gp.open(pattern, progressive=progressive)


def test_outputs_that_exist_are_left_alone(tmp_path, autzen_path):
    """Saving or converting onto what the user has refuses in one line and leaves it as it was."""
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    (tmp_path / "o.laz").write_text("mine")
    from gigapoint.lod.octree_dir import OutputExistsError

    octree = ProgressiveOctree("oct")
    octree.add(XYZ)
    with pytest.raises(OutputExistsError, match=f"^{re.escape(str(mine))}: directory is not empty and is not a gigapoint/Potree output; refusing to write into it$"):
        octree.save(mine)
    with pytest.raises(InputError, match=f"^{re.escape(str(tmp_path / 'o.laz'))}: already exists; pass overwrite=True to replace it$"):
        gp.convert(autzen_path, tmp_path / "o.laz")
    assert [p.name for p in mine.iterdir()] == ["notes.txt"] and (tmp_path / "o.laz").read_text() == "mine"


def test_waiting_on_a_truncated_laz_raises_its_one_line_error(tmp_path, autzen_path):
    """The loader's error, raised by wait (not a hang), again by a second wait; nothing drawn."""
    cut = tmp_path / "cut.laz"
    cut.write_bytes(autzen_path.read_bytes()[:20_000])
    cloud = gp.open(cut, progressive=True)
    problem = f"{cut}: truncated or corrupt LAZ file: chunk table offset 603,333 lies past the end of the file (20,000 bytes): 0 of its 110,000 points read"
    for _ in range(2):
        with pytest.raises(InputError, match=f"^{re.escape(problem)}$"):
            cloud.wait(60)
    assert cloud.n_points == 0 and str(cloud.error) == problem
    cloud.close()


def _octree_of_points():
    octree = ProgressiveOctree("oct")
    octree.add(XYZ)
    return octree


# paths with something else among them (a number, None) were pathlib's TypeError from deep inside
# ("expected str, bytes or os.PathLike object, not int", "'int' object is not iterable"): the entry is named
NOT_A_PATH = "is not a path (a str or os.PathLike)"
NOT_PATHS = [
    ("tile", lambda src, out: gp.tile([5], out, 100), f"tile: inputs[0]: 5 {NOT_A_PATH}"),
    ("tile-mixed", lambda src, out: gp.tile([src, None], out, 100), f"tile: inputs[1]: None {NOT_A_PATH}"),
    ("tile-bare", lambda src, out: gp.tile(5, out, 100), f"tile: inputs: 5 {NOT_A_PATH}"),
    ("convert-mixed", lambda src, out: gp.convert([src, None], out), f"convert: inputs[1]: None {NOT_A_PATH}"),  # (was "item 0 is a str")
    ("convert", lambda src, out: gp.convert([5], out),
     "convert: inputs[0]: 5 is neither a path nor a PointChunk (inputs are files and folders, a cloud, or PointChunks)"),
    ("convert-bare", lambda src, out: gp.convert(5, out), "convert: inputs are files, folders, a cloud or PointChunks, got an int"),
    ("open", lambda src, out: gp.open([5]), f"open: paths[0]: 5 {NOT_A_PATH}"),
    ("open-mixed", lambda src, out: gp.open(src, [src, 2.5]), f"open: paths[1][1]: 2.5 {NOT_A_PATH}"),
    ("change", lambda src, out: gp.change(src, [src, 5], 10), f"change: after[1]: 5 {NOT_A_PATH}"),
    ("change-bare", lambda src, out: gp.change(5, src, 10), f"change: before: 5 {NOT_A_PATH}"),
    ("volume-bare", lambda src, out: gp.volume(5, "POLYGON ((0 0, 1 0, 1 1, 0 0))", 1), f"volume: source: 5 {NOT_A_PATH}"),
    ("volume", lambda src, out: gp.volume([None], "POLYGON ((0 0, 1 0, 1 1, 0 0))", 1), f"volume: source[0]: None {NOT_A_PATH}"),
    ("expand-paths", lambda src, out: expand_paths([src, 5]), f"open: inputs[1]: 5 {NOT_A_PATH}"),  # (a caller that named none: gp.open's, as its other errors)
    ("expand-paths-where", lambda src, out: expand_paths([src, 5], where="tile"), f"tile: inputs[1]: 5 {NOT_A_PATH}"),  # (where= was not passed on: "inputs[1]")
    # operations that read through gp.open or expand_paths name themselves (they said "open: paths[0]" and a nameless "inputs[0]")
    ("section", lambda src, out: gp.section([5], (0, 0, 1, 1), 1), f"section: source[0]: 5 {NOT_A_PATH}"),
    ("orthophoto", lambda src, out: gp.orthophoto([src, 5], 1.0), f"orthophoto: source[1]: 5 {NOT_A_PATH}"),
    ("classify-ground", lambda src, out: gp.classify_ground([5], out.with_suffix(".las")), f"classify_ground: source[0]: 5 {NOT_A_PATH}"),
    ("classify-noise-bare", lambda src, out: gp.classify_noise(5, out.with_suffix(".las")), f"classify_noise: source: 5 {NOT_A_PATH}"),  # (was "'int' object is not iterable")
    ("height-above-ground", lambda src, out: gp.height_above_ground([src, None], out.with_suffix(".las")), f"height_above_ground: source[1]: None {NOT_A_PATH}"),
    ("render", lambda src, out: gp.render(5), "render: cannot draw an int; give a cloud (gigapoint.open, from_arrays, demo)"),
]  # fmt: skip


# an empty list of paths: the operation's name leads (section, orthophoto and classify_ground said "open: no file given")
NO_PATHS = [
    ("section", lambda out: gp.section([], (0, 0, 1, 1), 1), "section: no file given"),
    ("orthophoto", lambda out: gp.orthophoto([], 1.0), "orthophoto: no file given"),
    ("classify-ground", lambda out: gp.classify_ground([], out.with_suffix(".las")), "classify_ground: no file given"),
    ("classify-noise", lambda out: gp.classify_noise([[]], out.with_suffix(".las")), "classify_noise: no file given"),
    ("tile", lambda out: gp.tile([], out, 100), "tile: no file given"),
    ("open", lambda out: gp.open([[], ()]), "open: no file given"),
]  # fmt: skip


@pytest.mark.parametrize(("call", "message"), [case[1:] for case in NO_PATHS], ids=[case[0] for case in NO_PATHS])
def test_no_path_given_is_said_by_the_operation(tmp_path, call, message):
    out = tmp_path / "out"
    with pytest.raises(InputError) as err:
        call(out)
    assert str(err.value) == message
    assert not out.exists() and not out.with_suffix(".las").exists()


def test_open_for_names_the_operation_in_every_error_of_its_options(autzen_path):
    """open_for("section", ...) named the operation for its paths only: its chunked=, progress=,
    name= and unknown options said "open: ..."."""
    from gigapoint.io import open_cloud

    cases = [
        (lambda: gp.open_for("section", autzen_path, chunked="no"), "section: chunked must be True or False or None, got 'no'"),
        (lambda: gp.open_for("orthophoto", autzen_path, progress="yes"), "orthophoto: progress must be True or False, got 'yes'"),
        (lambda: gp.open_for("volume", autzen_path, name=5), "volume: name must be a string, got 5"),
        (lambda: open_cloud(where="change"), "change: no file given"),
    ]
    for call, message in cases:
        with pytest.raises(InputError) as err:
            call()
        assert str(err.value) == message
    with pytest.raises(InputError) as err:
        gp.open_for("section", autzen_path, bogus=1)
    assert str(err.value).startswith("section: unknown option(s) bogus; it takes chunk_size, ")


@pytest.mark.parametrize(("call", "message"), [case[1:] for case in NOT_PATHS], ids=[case[0] for case in NOT_PATHS])
def test_an_input_that_is_not_a_path_is_named_in_one_line(autzen_path, tmp_path, call, message):
    out = tmp_path / "out"
    with pytest.raises(gp.GigapointError) as err:
        call(autzen_path, out)
    assert str(err.value) == message
    assert not out.exists()


# the library said the CLI's options to a Python caller ("--format: unknown format 'bogus'",
# "--dask tcp://...: cannot reach ...", "--port must be ..."): it says the keyword given
# (cli/convert_cmd.py and cli/live_cmd.py say the options, test_lod_convert.py and test_live_cli.py)
CALLER_WORDS = [
    ("convert-format", lambda src, out: gp.convert(src, out, format="bogus"), "format: unknown format 'bogus'; choose gigapoint or potree or copc"),
    ("save-format", lambda src, out: _octree_of_points().save(out, format="bogus"), "format: unknown format 'bogus'; choose gigapoint or potree or copc"),
    ("convert-sampler", lambda src, out: gp.convert(src, out, sampler="random"), "sampler: unknown sampler 'random'; choose grid or poisson"),
    ("convert-layout", lambda src, out: gp.convert(src, out, layout="bits"), "layout: unknown layout 'bits'; choose compact or words"),
    ("convert-colors", lambda src, out: gp.convert(src, out, colors="rgb332"), "colors: unknown colour format 'rgb332'; choose rgba or rgb565"),
    ("convert-words-rgb565", lambda src, out: gp.convert(src, out, layout="words", colors="rgb565"),
     "colors='rgb565': an option of the compact layout; words holds 32-bit colours"),
    ("convert-copc-layout", lambda src, out: gp.convert(src, out, format="copc", layout="compact", colors="rgba"),
     "layout and colors: options of the gigapoint format, not of copc"),
    ("convert-thin-octree", lambda src, out: gp.convert(src, out, thin=10),
     "{out}: thin: an option of a plain .las, .laz or .ply file of the files' points, not of a gigapoint octree"),
    ("convert-octree-named-as-a-file", lambda src, out: gp.convert(src, out.with_name("oct.xyz")),
     "{out}.xyz: convert writes .las, .laz or .ply files, an octree folder or a .copc.laz file, not .xyz"),
    ("convert-octree-format-named-as-a-file", lambda src, out: gp.convert(src, out.with_name("oct.las"), format="potree"),
     "{out}.las: a potree octree is a folder; name it without a point file's suffix, or write format='copc' into a .copc.laz file"),
    ("convert-octree-keywords-to-a-file", lambda src, out: gp.convert(src, out.with_name("oct.laz"), sampler="grid", max_leaf=1000, client=2),
     "{out}.laz: sampler, max_leaf, client: options of an octree, not of a plain LAZ file"),
    ("convert-out-empty", lambda src, out: gp.convert(src, ""), "convert: no output directory given (out='')"),
    ("save-out-none", lambda src, out: _octree_of_points().save(None), "convert: no output directory given (out=None)"),
    ("convert-client-0", lambda src, out: gp.convert(src, out, client=0), "client: needs at least 1 worker, got 0"),
    ("convert-client-unreachable", lambda src, out: gp.convert(src, out, client="tcp://127.0.0.1:9"),
     "client='tcp://127.0.0.1:9': cannot reach a Dask scheduler there (nothing listens on that port)"),
    ("convert-client-address-with-a-limit", lambda src, out: gp.convert(src, out, client="tcp://127.0.0.1:9", memory_limit="1G", colorize=out.with_name("oct_nope.tif")),
     "{out}_nope.tif: no such raster file (convert: colorize)"),  # the inputs checked before the scheduler is reached (no memory plan asks it)
    ("viewer-port", lambda src, out: gp.Viewer(gp.from_arrays(XYZ), port=70000, display=False), "port must be in 0..65535, got 70000"),
    ("viewer-host", lambda src, out: gp.Viewer(gp.from_arrays(XYZ), host="", display=False),
     "host must be an address or a host name (127.0.0.1: this machine only), got ''"),
]  # fmt: skip


@pytest.mark.parametrize(("call", "message"), [case[1:] for case in CALLER_WORDS], ids=[case[0] for case in CALLER_WORDS])
def test_errors_name_the_keyword_the_caller_gave(autzen_path, tmp_path, call, message):
    out = tmp_path / "oct"
    with pytest.raises(gp.GigapointError, match=f"^{re.escape(message.format(out=out))}$"):
        call(autzen_path, out)
    assert not out.exists()


def test_too_many_workers_says_the_keyword(autzen_path, tmp_path):
    import os

    pytest.importorskip("distributed")
    cores = os.cpu_count()
    with pytest.raises(gp.GigapointError, match=f"^client: 100000 local worker processes on a machine of {cores} cores .*; for more, start a Dask cluster and give client its scheduler's address$"):
        gp.convert(autzen_path, tmp_path / "oct", client=100_000)


def test_a_conversion_on_dask_without_dask_says_the_keyword(autzen_path, tmp_path, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "distributed", None)  # (import distributed: an ImportError)
    with pytest.raises(gp.GigapointError, match=r"^client: a distributed conversion needs Dask: pip install 'gigapoint\[dask\]'$"):
        gp.convert(autzen_path, tmp_path / "oct", client=2)
