"""The progressive cloud's lifecycle as a demanding user drives it (gp.open(..., progressive=True),
add, wait, progress, close, save, gp.render): bad input or misuse is one line of gigapoint's own
errors naming the file and the problem, never a hang, a traceback or a half-written output that
looks complete; nothing the user had is overwritten without asking; what a load holds when a
file fails stays; closing stops the loader's threads and frees the memory."""

from __future__ import annotations

import math
import re
import threading

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import EmptyCloudError, GigapointWarning, InputError
from gigapoint.lod.octree_dir import ConvertError, OutputExistsError
from gigapoint.lod.progressive import ProgressiveOctree

INVALID = "NaN, inf or beyond ±1e+12"


@pytest.fixture(scope="module")
def files(tmp_path_factory, las_writer):
    """Small inputs, by name: two LAS files of the demo town, the second cut off mid-points, a
    file that is no point cloud, a text file of words, an empty folder, a LAS file of no points."""
    import laspy

    d = tmp_path_factory.mktemp("inputs")
    a, b = las_writer(d / "a.las", 20_000, seed=1), las_writer(d / "b.las", 20_000, seed=2)
    whole = b.read_bytes()
    (d / "trunc.las").write_bytes(whole[: len(whole) // 2])
    (d / "notcloud.las").write_bytes(b"hello, this is not a LAS file" * 10)
    (d / "notes.txt").write_text("hello\n")
    (d / "emptydir").mkdir()
    laspy.LasData(laspy.LasHeader(point_format=3, version="1.2")).write(str(d / "empty.las"))
    return {p.stem: p for p in (a, b, d / "trunc.las", d / "notcloud.las", d / "notes.txt", d / "emptydir", d / "empty.las")}


@pytest.fixture
def cloud(files, loaded):
    """a.las loaded whole (20 000 points, a LAS file's attributes), closed after the test."""
    c = loaded(files["a"])
    yield c
    c.close()


def _loader_threads() -> list[str]:
    """A progressive load's threads (its loader's and its decoder's; not the render pools' other
    tests leave, 'gigapoint-bands_0')."""
    return sorted(t.name for t in threading.enumerate() if t.name.startswith(("gigapoint-load-", "gigapoint-decode")))


def _closed(c):
    c.close()
    return c


def _all_nan() -> ProgressiveOctree:
    o = ProgressiveOctree("allnan")
    assert o.add(np.full((2, 3), np.nan)) == 0 and o.skipped == 2
    return o


# (id, call(cloud, files, out), error, message): each a one-line error, nothing added, nothing written
# at ``out`` (a folder or file named by the case); {a}, {trunc}, ... are the files' paths, {out} the output
MISUSE = [
    ("add-after-close", lambda c, f, out: _closed(c).add(np.zeros((3, 3))), InputError, "a.las: the octree is closed; open it again to add points"),
    ("save-after-close", lambda c, f, out: _closed(c).save(out), InputError, "a.las: the octree is closed (its points were freed); open it again to save it"),
    ("save-laz-after-close", lambda c, f, out: _closed(c).save(out.with_suffix(".laz")), InputError,
     "a.las: the octree is closed (its points were freed); open it again to save it"),
    ("chunks-after-close", lambda c, f, out: list(_closed(c).chunks()), InputError, "a.las: the octree is closed (its points were freed); open it again to read its points"),
    ("wait-nan", lambda c, f, out: c.wait(timeout=math.nan), InputError, "a.las: wait: timeout must be a number of seconds or None, got nan"),
    ("wait-string", lambda c, f, out: c.wait(timeout="1"), InputError, "a.las: wait: timeout must be a number of seconds or None, got '1'"),
    ("save-bogus-format", lambda c, f, out: c.save(out, format="bogus"), ConvertError, "format: unknown format 'bogus'; choose gigapoint or potree or copc"),
    ("save-unknown-option", lambda c, f, out: c.save(out, banana=1), InputError, "a.las: save: unknown option(s) banana; it takes "),
    ("save-overwrite-not-a-switch", lambda c, f, out: c.save(out, overwrite="no"), InputError, "convert: overwrite must be True or False, got 'no'"),
    ("save-laz-octree-option", lambda c, f, out: c.save(out.with_suffix(".laz"), max_leaf=1000), InputError,
     "{out}.laz: max_leaf: options of an octree, not of a plain LAZ file"),
    ("add-rgb-rows", lambda c, f, out: c.add(np.zeros((4, 3)), rgb=np.zeros((3, 3), np.uint8)), InputError, "a.las: rgb has 3 rows, xyz has 4"),
    ("add-rgb-shape", lambda c, f, out: c.add(np.zeros((4, 3)), rgb=np.zeros((4, 2), np.uint8)), InputError, "a.las: colors must have shape (N, 3) or (N, 4), got (4, 2)"),
    ("add-rgb-strings", lambda c, f, out: c.add(np.zeros((2, 3)), rgb=[["r", "g", "b"]] * 2), InputError, "a.las: colors must be numbers, got dtype <U1"),
    ("add-rgb-negative", lambda c, f, out: c.add(np.zeros((2, 3)), rgb=np.full((2, 3), -1)), InputError,
     "a.las: colors must be 0..1, 0..255 or 0..65535 (16 bits), got -1"),
    ("add-rgb-nan", lambda c, f, out: c.add(np.zeros((2, 3)), rgb=np.full((2, 3), np.nan)), InputError,
     "a.las: colors must be 0..1, 0..255 or 0..65535 (16 bits), got nan"),
    ("add-rgb-over-16-bits", lambda c, f, out: c.add(np.zeros((2, 3)), rgb=np.full((2, 3), 70_000, np.uint32)), InputError,
     "a.las: colors must be 0..1, 0..255 or 0..65535 (16 bits), got 70000"),
    ("add-attribute-length", lambda c, f, out: c.add(np.zeros((4, 3)), intensity=np.ones(3, np.uint16)), InputError,
     "a.las: attribute 'intensity' must be 1-D of length 4, got shape (3,)"),
    ("add-attribute-2d", lambda c, f, out: c.add(np.zeros((4, 3)), intensity=np.ones((4, 2), np.uint16)), InputError,
     "a.las: attribute 'intensity' must be 1-D of length 4, got shape (4, 2)"),
    ("add-attribute-strings", lambda c, f, out: c.add(np.zeros((2, 3)), intensity=np.array(["a", "b"])), InputError,
     "a.las: attribute 'intensity' has dtype <U1: attributes are numbers (bool, integers, floats of at most 64 bits)"),
    ("add-attribute-unknown", lambda c, f, out: c.add(np.zeros((2, 3)), label=np.ones(2)), InputError,
     "a.las: attribute 'label' is not one of this cloud's (intensity, classification, return_number, "),
    ("add-xyz-shape", lambda c, f, out: c.add(np.zeros((4, 2))), InputError, "a.las: xyz must have shape (N, 3), got (4, 2)"),
    ("add-xyz-strings", lambda c, f, out: c.add([["1", "2", "3"]]), InputError, "a.las: xyz must hold numbers (integers or floats), got dtype <U1"),
    ("open-empty-list", lambda c, f, out: gp.open([], progressive=True), InputError, "open: no file given"),
    ("open-no-path", lambda c, f, out: gp.open(progressive=True), InputError, "open: no file given"),
    ("open-folder-of-no-cloud", lambda c, f, out: gp.open(f["emptydir"], progressive=True), EmptyCloudError,
     "{emptydir}: directory holds no supported point cloud file (.asc, .csv, .e57, .las, .laz, .npy, .npz, .ply, .pts, .txt, .xyz, .xyzrgb)"),
    ("open-empty-file", lambda c, f, out: gp.open(f["empty"], progressive=True), EmptyCloudError, "{empty}: LAS file holds no points (header point count is 0)"),
    ("open-second-not-a-cloud", lambda c, f, out: gp.open(f["a"], f["notcloud"], progressive=True), InputError,
     "{notcloud}: not a LAS/LAZ file (starts with b'hell', expected b'LASF')"),
    ("open-second-not-points", lambda c, f, out: gp.open(f["a"], f["notes"], progressive=True), InputError, "{notes}: line 1: not numeric point data: 'hello'"),
    ("open-second-missing", lambda c, f, out: gp.open(f["a"], f["a"].with_name("gone.las"), progressive=True), InputError, "{gone}: no such file"),
    ("open-memory-limit", lambda c, f, out: gp.open(f["a"], progressive=True, memory_limit="lots"), InputError,
     "memory_limit: cannot read 'lots' (use e.g. 4G, 512M)"),
    ("open-option-of-the-plain-cloud", lambda c, f, out: gp.open(f["a"], progressive=True, chunked=True), InputError,
     "open(progressive=True) takes memory_limit= only, not chunked"),
    ("open-progressive-not-a-switch", lambda c, f, out: gp.open(f["a"], progressive="yes"), InputError, "open: progressive must be True or False, got 'yes'"),
    # an octree holding no point: its save into a folder said the converter's "no valid points", into a
    # point file it wrote a LAS file of no points, as though the cloud were saved
    ("save-empty-octree", lambda c, f, out: ProgressiveOctree("empty").save(out), EmptyCloudError, "empty: no valid points"),
    ("save-empty-octree-laz", lambda c, f, out: ProgressiveOctree("empty").save(out.with_suffix(".laz")), EmptyCloudError, "empty: no valid points"),
    ("save-all-nan-octree", lambda c, f, out: _all_nan().save(out), EmptyCloudError, f"allnan: no valid points (2 invalid points: {INVALID})"),
    ("save-all-nan-octree-ply", lambda c, f, out: _all_nan().save(out.with_suffix(".ply")), EmptyCloudError, f"allnan: no valid points (2 invalid points: {INVALID})"),
]  # fmt: skip


@pytest.mark.timeout(120)  # (a wait that hangs fails here, not the whole run)
@pytest.mark.parametrize(("call", "error", "message"), [case[1:] for case in MISUSE], ids=[case[0] for case in MISUSE])
def test_misuse_is_one_line_and_changes_nothing(cloud, files, tmp_path, call, error, message):
    out = tmp_path / "out"
    threads = _loader_threads()
    held = (cloud.n_points, cloud.attribute_names) if not cloud.closed else None
    want = message.format(**{k: str(v) for k, v in files.items()}, gone=files["a"].with_name("gone.las"), out=out)
    with pytest.raises(error) as caught:
        call(cloud, files, out)
    assert type(caught.value) is error and str(caught.value).startswith(want) and "\n" not in str(caught.value)
    assert list(tmp_path.iterdir()) == []  # nothing written: no folder, no file of no points
    if held is not None and not cloud.closed:  # a refused add added nothing
        assert (cloud.n_points, cloud.attribute_names) == held and held[0] == 20_000
    assert _loader_threads() == threads  # an open refused started no loader


# (id, what save is given, make what is there already, overwrite, error, message): save refuses and
# what was there is kept byte for byte
THERE_ALREADY = [
    ("folder-of-the-users", "out", lambda out: (out.mkdir(), (out / "keep.txt").write_text("mine")), False,
     OutputExistsError, "{out}: directory is not empty and is not a gigapoint/Potree output; refusing to write into it"),
    ("folder-of-the-users-overwrite", "out", lambda out: (out.mkdir(), (out / "keep.txt").write_text("mine")), True,
     OutputExistsError, "{out}: directory is not empty and is not a gigapoint/Potree output; refusing to write into it"),
    ("a-file", "out", lambda out: out.write_text("mine"), False, OutputExistsError, "{out}: exists and is not a directory"),
    ("a-laz-file", "out.laz", lambda out: out.write_text("mine"), False, InputError, "{out}: already exists; pass overwrite=True to replace it"),
]  # fmt: skip


@pytest.mark.parametrize(("name", "make", "overwrite", "error", "message"), [case[1:] for case in THERE_ALREADY], ids=[case[0] for case in THERE_ALREADY])
def test_save_over_what_the_user_has_is_refused(cloud, tmp_path, name, make, overwrite, error, message):
    out = tmp_path / name
    make(out)
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    with pytest.raises(error, match=f"^{re.escape(message.format(out=out))}$"):
        cloud.save(out, overwrite=overwrite)
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before


@pytest.mark.parametrize("name", ["t.laz", "t.ply", "tree", "t.copc.laz"])
def test_save_makes_the_folders_missing_on_its_way_for_a_point_file_as_for_an_octree(cloud, tmp_path, name):
    """save("missing/dir/t.laz") refused the folder while save("missing/dir/t.copc.laz") and an
    octree folder made it: one rule, as convert -o and a plain cloud's save follow (io/write.py)."""
    out = tmp_path / "missing" / "dir" / name
    assert cloud.save(out).points == 20_000
    assert gp.open(out).n_points == 20_000


def test_save_through_a_file_is_refused_in_one_line(cloud, tmp_path):
    (tmp_path / "afile").write_text("mine")
    with pytest.raises(InputError, match=f"^{re.escape(str(tmp_path / 'afile' / 'dir' / 't.laz'))}: {re.escape(str(tmp_path / 'afile'))} is a file, not a folder$"):
        cloud.save(tmp_path / "afile" / "dir" / "t.laz")
    assert [p.name for p in tmp_path.iterdir()] == ["afile"] and (tmp_path / "afile").read_text() == "mine"


def test_a_second_save_asks_for_overwrite(cloud, tmp_path):
    out = tmp_path / "tree"
    assert cloud.save(out).points == 20_000
    with pytest.raises(OutputExistsError, match=f"^{re.escape(str(out))}: already holds a converted point cloud; pass overwrite=True to replace it$"):
        cloud.save(out)
    assert cloud.save(out, overwrite=True).points == 20_000


@pytest.mark.timeout(120)
def test_close_twice_and_wait_after_close(files):
    c = gp.open(files["a"], progressive=True)
    c.close()
    c.close()  # (a second close is nothing)
    assert c.closed and c.n_points == 0 and c.nbytes < 100_000 and not c.loading
    assert c.wait() is False and c.wait(timeout=0) is False  # stopped part-way or freed: never "complete"
    assert repr(c).endswith(", closed)")


@pytest.mark.timeout(120)
@pytest.mark.parametrize("timeout", [0, -1, 0.0, -math.inf])
def test_wait_of_no_time_answers_at_once(timeout):
    """0 and below: whether the load is done, without waiting (a big load is not)."""
    with gp.demo(3_000_000, progressive=True) as c:
        assert c.wait(timeout=timeout) is False and c.loading
    assert c.closed


@pytest.mark.timeout(120)
@pytest.mark.parametrize("timeout", [None, math.inf, 120])
def test_wait_without_limit_waits_for_every_point(files, timeout):
    c = gp.open(files["a"], progressive=True)
    assert c.wait(timeout=timeout) is True and c.progress == 1.0 and c.n_points == 20_000
    c.close()


# (id, points added, rgb or None, n inserted, skipped): invalid rows are skipped and counted, the
# bounds stay those of the valid points
ADDS = [
    ("no-points", np.empty((0, 3)), None, 0, 0),
    ("nan-and-inf", np.array([[np.nan, 0, 0], [np.inf, 0, 0], [0, -np.inf, 0], [5.0, 6.0, 7.0]]), None, 1, 3),
    ("absurd-1e300", np.array([[1e300, 0, 0], [-1e300, 1e300, 0], [5.0, 6.0, 7.0]]), None, 1, 2),
    ("beyond-1e12", np.array([[2e12, 0, 0], [5.0, 6.0, 7.0]]), np.full((2, 3), 0.5), 1, 1),
    ("rgb-16-bits", np.array([[5.0, 6.0, 7.0]]), np.full((1, 3), 65535, np.uint16), 1, 0),
]  # fmt: skip


@pytest.mark.parametrize(("xyz", "rgb", "inserted", "skipped"), [case[1:] for case in ADDS], ids=[case[0] for case in ADDS])
def test_adding_odd_points(xyz, rgb, inserted, skipped):
    o = ProgressiveOctree("o")
    assert o.add(np.array([[1.0, 2.0, 3.0]])) == 1
    assert o.add(xyz, rgb) == inserted
    assert (o.n_points, o.skipped) == (1 + inserted, skipped)
    lo, hi = o.bounds
    assert lo.tolist() == [1.0, 2.0, 3.0] and hi.tolist() == ([5.0, 6.0, 7.0] if inserted else [1.0, 2.0, 3.0])


@pytest.mark.timeout(600)  # a deadlock guard: the load's and the render's kernels compile here, minutes on a cold cache under load
def test_a_file_cut_off_among_several_keeps_what_was_loaded(files):
    """The second file cut off mid-points: the first's points and the second's before the cut stay
    drawable; the error is one line naming that file; progress stays short of 1."""
    c = gp.open(files["a"], files["trunc"], progressive=True)
    want = f"{files['trunc']}: truncated LAS file: the header claims 20,000 points, only "
    with pytest.raises(InputError) as caught:
        c.wait()  # until the load ends in its error (wait(120) returned False, no error yet, on one still compiling)
    assert str(caught.value).startswith(want) and "\n" not in str(caught.value) and c.error is caught.value
    kept = int(re.search(r"only ([\d,]+) could be read", str(caught.value))[1].replace(",", ""))
    assert 0 < kept < 20_000 and c.n_points == 20_000 + kept and c.progress == pytest.approx(c.n_points / 40_000)
    cam = gp.Camera.fit(c.bounds, view="top", width=64, height=48)
    assert gp.render_frame(c, cam).stats.visible_pixels > 0
    with pytest.raises(InputError, match=f"^{re.escape(want)}"):  # save refuses a load that ended in an error
        c.save(files["a"].parent / "partial")
    assert not (files["a"].parent / "partial").exists()
    c.close()


@pytest.mark.timeout(120)
def test_the_same_file_twice_is_read_once(files):
    twice = f"^{re.escape(str(files['a']))}: named more than once; its points are read once$"
    with pytest.warns(GigapointWarning, match=twice):
        c = gp.open(files["a"], files["a"], progressive=True)
    with pytest.warns(GigapointWarning, match=twice):
        plain = gp.open(files["a"], files["a"])
    assert c.wait(timeout=120) and c.n_points == 20_000 == plain.n_points
    c.close()


def test_a_cloud_of_no_point_yet_renders_the_background_and_says_so():
    """A progressive cloud draws what it holds at any moment: none yet is the background, with the
    warning any render with no point in view gives. (A plain cloud cannot be empty: from_arrays
    of no point is refused when it is made.)"""
    cam = gp.Camera.look_at((0, -10, 5), (0, 0, 0), width=32, height=24)
    with pytest.warns(GigapointWarning, match=r"^empty: no point is in view of the camera \(it holds none: .*the image shows only the background$"):
        image = gp.render(ProgressiveOctree("empty"), cam)
    assert image.shape == (24, 32, 4) and (image == image[0, 0]).all()
    nothing_in_view = gp.from_arrays(np.array([[0.0, 0.0, 0.0]]))
    behind = gp.Camera.look_at((0, 10, 0), (0, 20, 0), width=32, height=24)
    with pytest.warns(GigapointWarning, match=r"^arrays: no point is in view of the camera; the image shows only the background$"):
        assert (gp.render(nothing_in_view, behind) == image).all()
    with pytest.raises(EmptyCloudError, match="^arrays: no valid points$"):
        gp.from_arrays(np.empty((0, 3)))


@pytest.mark.timeout(120)
def test_a_closed_cloud_renders_the_background_and_says_it_may_be_closed(cloud):
    cloud.close()
    cam = gp.Camera.look_at((0, -10, 5), (0, 0, 0), width=32, height=24)
    with pytest.warns(GigapointWarning, match=r"^a\.las: no point is in view of the camera \(it holds none: nothing loaded yet, or closed\)"):
        image = gp.render(cloud, cam)
    assert (image == image[0, 0]).all()


@pytest.mark.timeout(120)
def test_progress_only_grows_from_0_to_1(autzen_path, files):
    with pytest.warns(GigapointWarning, match="names no CRS"):  # (a.las names none)
        c = gp.open(autzen_path, files["a"], progressive=True)
    seen = [c.progress]
    while not c.wait(timeout=0.001):
        seen.append(c.progress)
    seen.append(c.progress)
    assert all(0.0 <= p <= 1.0 for p in seen) and seen == sorted(seen) and seen[-1] == 1.0
    assert c.n_points == 130_000
    c.close()


@pytest.mark.timeout(120)
@pytest.mark.parametrize("how", ["close", "with"])
def test_closing_mid_load_stops_its_threads_and_frees_its_memory(how):
    before = _loader_threads()
    c = gp.demo(3_000_000, progressive=True)
    if how == "close":
        while c.n_points == 0:
            c.wait(timeout=0.01)
        held = c.nbytes
        c.close()
    else:
        with c:
            while c.n_points == 0:
                c.wait(timeout=0.01)
            held = c.nbytes
    assert _loader_threads() == before and not c.loader._thread.is_alive()
    assert held > 10_000_000 and c.nbytes < 100_000 and c.n_points == 0 and c.progress < 1.0


@pytest.mark.timeout(120)
def test_an_error_in_the_with_block_closes_the_cloud_and_propagates():
    with pytest.raises(KeyError, match="mine"), gp.demo(3_000_000, progressive=True) as c:
        raise KeyError("mine")
    assert c.closed and not c.loading and _loader_threads() == []


@pytest.mark.timeout(120)
def test_save_while_loading_waits_for_every_point(autzen_path, tmp_path):
    """save() right after the open waits for the load (its docstring says so), then writes all of it."""
    c = gp.open(autzen_path, progressive=True)
    assert c.save(tmp_path / "all.laz").points == 110_000 and not c.loading and c.progress == 1.0
    assert gp.open(tmp_path / "all.laz").n_points == 110_000
    c.close()


@pytest.mark.timeout(120)
def test_points_added_while_files_load_keep_the_files_attributes(autzen_path):
    """An add() before the loader's first points fixed the attribute set as the add's (none): each
    of the file's 13 attributes was dropped, with a warning that they were not in every file. The
    add waits for the files' first points, which fix the set; its points get 0 for each."""
    mine = np.array([[637_000.0, 851_000.0, 400.0]])
    c = gp.open(autzen_path, progressive=True)
    assert c.add(mine) == 1
    assert c.wait(timeout=120) and c.n_points == 110_001 and c.warnings == ()
    assert list(c.attribute_names) == gp.open(autzen_path).attribute_names and "intensity" in c.attribute_names
    found = [chunk.attributes["intensity"][hit] for chunk in c.chunks() for hit in np.flatnonzero(np.all(np.abs(chunk.xyz - mine) < 1e-3, axis=1))]
    assert found == [0]
    c.close()


@pytest.mark.timeout(120)
def test_an_add_waiting_for_the_files_first_points_goes_on_when_the_load_fails_before_any():
    """The load's end lets an add() waiting for the first points go (it waits for none that come)."""
    from gigapoint.lod.progressive import Loader

    def failing():
        raise InputError("tiles/b.laz: corrupt LAZ chunk 0")
        yield

    o = ProgressiveOctree("failing")
    o.attach(Loader(o, [("tiles/b.laz", failing)], 1_000).start())
    assert o.add(np.array([[1.0, 2.0, 3.0]])) == 1 and o.n_points == 1
    with pytest.raises(InputError, match=r"^tiles/b\.laz: corrupt LAZ chunk 0$"):
        o.wait(timeout=60)
    o.close()
