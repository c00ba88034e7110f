"""The viewable preview of a conversion in progress: sampler, resume, open/render/info, viewer swap."""

from __future__ import annotations

import importlib
import json
import re
import shutil
import time
import warnings

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.cli import main
from gigapoint.errors import GigapointWarning, InputError
from gigapoint.lod import OctreeCloud, OctreeDir, convert
from gigapoint.lod.convert import hooks
from gigapoint.lod.octree_dir import PREVIEW as PREVIEW_NAME
from gigapoint.lod.preview import PreviewSampler, preview_points

laspy = pytest.importorskip("laspy")
conv_mod = importlib.import_module("gigapoint.lod.convert")  # the package (gigapoint.lod.convert is the function)
read_mod = importlib.import_module("gigapoint.lod.convert.read")  # the read phase: where input files are read


def _interrupt_after(monkeypatch, n):
    """The conversion stops (KeyboardInterrupt) once it has built ``n`` partitions in a run; None: never."""

    def hook(done):
        if done == n:
            raise KeyboardInterrupt(f"test interrupt after {done} partitions")

    monkeypatch.setattr(hooks, "after_partition_built", hook)


def _chunk(start: int, n: int, with_intensity: bool = True):
    """n points whose x is their global index (so the sample's x values show what was kept)."""
    x = np.arange(start, start + n, dtype=np.float64)
    xyz = np.column_stack([x, x % 7, x % 11])
    rgba = (np.arange(start, start + n) % 256).astype(np.uint32) * 0x01010101
    attrs = {"intensity": (x % 1000).astype(np.uint16)} if with_intensity else {}
    return xyz, rgba, attrs


def _feed(sampler: PreviewSampler, sizes, start: int = 0, check=None):
    for n in sizes:
        sampler.add(*_chunk(start, n))
        start += n
        if check:
            check(sampler, start)
    return start


def _kept_x(sampler: PreviewSampler) -> np.ndarray:
    return sampler._merged()["xyz"][:, 0]


def test_unknown_total_keeps_a_uniform_thinning_within_the_target(tmp_path):
    s = PreviewSampler(tmp_path / PREVIEW_NAME, target=1000, total=None)

    def check(s, seen):
        assert s.held <= 1000
        np.testing.assert_array_equal(_kept_x(s), np.arange(0, seen, s.stride))  # every stride-th point, none else

    _feed(s, [7, 900, 33, 5000, 1, 12_345, 999], check=check)
    assert s.stride == 32 and s.held > 500  # the stride doubled only as far as needed


def test_known_total_fixes_the_stride(tmp_path):
    s = PreviewSampler(tmp_path / PREVIEW_NAME, target=1000, total=50_000)
    seen = _feed(s, [20_000, 20_000, 10_000])
    assert s.stride == 50 and s.held == 1000
    np.testing.assert_array_equal(_kept_x(s), np.arange(0, seen, 50))
    np.testing.assert_array_equal(s._merged()["attr.intensity"], np.arange(0, seen, 50) % 1000)


def test_attributes_some_chunks_lack_are_dropped(tmp_path):
    s = PreviewSampler(tmp_path / PREVIEW_NAME, target=10_000, total=None)
    s.add(*_chunk(0, 100))
    s.add(*_chunk(100, 100, with_intensity=False))
    assert set(s._merged()) == {"xyz", "rgba"} and s.held == 200


def test_write_is_atomic_timed_and_opens_as_a_cloud(tmp_path):
    path = tmp_path / PREVIEW_NAME
    s = PreviewSampler(path, target=10_000, total=None, interval_s=3600)
    assert not s.maybe_write()  # nothing yet
    s.add(*_chunk(0, 500))
    assert s.maybe_write()  # the first chunk is written at once
    s.add(*_chunk(500, 500))
    assert not s.maybe_write()  # not due for an hour
    assert s.maybe_write(force=True)
    assert not s.maybe_write(force=True)  # unchanged since
    assert sorted(p.name for p in tmp_path.iterdir()) == [PREVIEW_NAME]  # no temporary file left
    cloud = gp.open(path)
    assert cloud.n_points == 1000 and set(cloud.attributes) == {"intensity"}
    np.testing.assert_array_equal(np.sort(np.round(cloud.positions()[:, 0])), np.arange(1000))


def test_resume_continues_the_same_sample(tmp_path):
    whole = PreviewSampler(tmp_path / "a.npz", target=300, total=None)
    _feed(whole, [400, 400, 400, 400])
    part = PreviewSampler(tmp_path / "b.npz", target=300, total=None)
    seen = _feed(part, [400, 400])
    part.maybe_write(force=True)
    resumed = PreviewSampler(tmp_path / "b.npz", target=300, total=None)
    resumed.resume(seen, part.stride)
    _feed(resumed, [400, 400], start=seen)
    np.testing.assert_array_equal(_kept_x(resumed), _kept_x(whole))
    assert resumed.stride == whole.stride


def test_resume_from_a_missing_or_corrupt_file_starts_afresh(tmp_path):
    (tmp_path / PREVIEW_NAME).write_bytes(b"PK\x03\x04 torn")
    s = PreviewSampler(tmp_path / PREVIEW_NAME, target=300, total=None)
    s.resume(1000, 4)
    assert s.held == 0 and s.seen == 0


def test_preview_size_follows_the_memory_limit():
    assert preview_points(24 << 30) == 2_000_000
    assert preview_points(256 << 20) == 256 * 2**20 // 50 // 48
    assert preview_points(1 << 20) == 50_000


# ------------------------------------------------------------------ inside a conversion


OPTS = {"max_leaf": 3_000, "partition_points": 25_000, "chunk_size": 20_000}


@pytest.fixture(scope="module")
def las_file(tmp_path_factory, las_writer):
    path = las_writer(tmp_path_factory.mktemp("las") / "scan.las", 100_000, seed=3)
    with laspy.open(str(path)) as f:
        las = f.read()
    return path, np.column_stack([las.x, las.y, las.z])


def _stop_reading_after(monkeypatch, k: int):
    real = read_mod._read_chunks

    def chunks(path, size):
        for i, c in enumerate(real(path, size)):
            if i == k:
                raise KeyboardInterrupt("test: stopped while reading")
            yield c

    monkeypatch.setattr(read_mod, "_read_chunks", chunks)
    return real


def _same_points(cloud, xyz):
    """Same point set, at the LAS file's millimetres (the cloud decodes at 30-bit batch precision)."""
    np.testing.assert_array_equal(np.unique(np.round(cloud.positions(), 3), axis=0), np.unique(np.round(xyz, 3), axis=0))


def _open_preview(out):
    with pytest.warns(GigapointWarning, match="conversion not finished"):
        return gp.open(out)


def test_killed_while_reading_shows_what_was_read_and_resumes_exactly(las_file, tmp_path, monkeypatch):
    path, xyz = las_file
    out = tmp_path / "oct"
    monkeypatch.setattr(read_mod, "preview_points", lambda mem: 10_000)  # stride 10 for 100 000 points
    real = _stop_reading_after(monkeypatch, 3)
    with pytest.raises(KeyboardInterrupt):
        convert([path], out, **OPTS)
    state = json.loads((out / ".partial" / "state.json").read_text())
    assert state["phase"] == "read" and state["chunks"] == 3 and state["preview"]["stride"] == 10
    shown = state["preview"]["seen"]
    preview = _open_preview(out)
    assert 20_000 <= shown <= 60_000 and preview.n_points == shown // 10
    _same_points(preview, xyz[:shown:10])
    img = gp.render(preview, gp.Camera.fit(preview.bounds, width=160, height=120))
    assert (img[..., :3] != 0).any(axis=2).mean() > 0.05  # it draws something

    # resumed and stopped again after the read phase: the preview is exactly every 10th point
    monkeypatch.setattr(read_mod, "_read_chunks", real)
    _interrupt_after(monkeypatch, 1)
    with pytest.raises(KeyboardInterrupt):
        convert([path], out, **OPTS)
    preview = _open_preview(out)
    _same_points(preview, xyz[::10])

    _interrupt_after(monkeypatch, None)
    res = convert([path], out, **OPTS)
    assert res.resumed and res.first_view_seconds == 0.0  # the interrupted run's preview was there all along
    assert isinstance(gp.open(out), OctreeCloud) and not (out / ".partial").exists()


def test_first_view_comes_after_the_first_chunk(las_file, tmp_path):
    path, _ = las_file
    res = convert([path], tmp_path / "oct", **OPTS)
    assert res.first_view_seconds is not None and 0 < res.first_view_seconds < res.seconds
    assert res.first_view_seconds < res.phase_seconds["read"] + 1e-3  # during the read phase, not after it


def test_unfinished_conversion_without_a_preview_is_a_clear_error(tmp_path):
    out = tmp_path / "oct"
    (out / ".partial").mkdir(parents=True)
    (out / ".partial" / "state.json").write_text(json.dumps({"phase": "read"}))
    with pytest.raises(InputError, match="no preview written yet"):
        gp.open(out)
    assert main(["render", str(out), "-o", str(tmp_path / "x.png")]) == 1
    assert not (tmp_path / "x.png").exists()


def test_a_stopped_conversion_of_chunks_says_it_cannot_resume(tmp_path, monkeypatch, capsys):
    """Chunks given from Python leave no state a rerun could resume from: `info` and `gp.open`
    said "run `gigapoint convert` again to resume it" of a cloud's interrupted save."""
    out = tmp_path / "half"
    _interrupt_after(monkeypatch, 1)
    with pytest.raises(KeyboardInterrupt):
        convert(gp.demo(20_000, colors="rgba"), out, max_leaf=1_000, partition_points=5_000)
    hint = "its points were given from Python (a cloud's save), so it cannot resume: save the cloud again"
    assert main(["info", str(out)]) == 0
    assert f"stopped: {hint}" in capsys.readouterr().out
    with pytest.warns(GigapointWarning, match=re.escape(f"it has stopped: {hint}")):
        gp.open(out)
    copc = tmp_path / "half.copc.laz"  # its work folder, named by info
    with pytest.raises(KeyboardInterrupt):
        convert(gp.demo(20_000, colors="rgba"), copc, max_leaf=1_000, partition_points=5_000)
    assert main(["info", str(copc)]) == 1
    assert capsys.readouterr().err.strip().endswith(f"(its work folder {copc}.work is there); {hint}")

def test_info_describes_octrees_and_unfinished_conversions(las_file, tmp_path, monkeypatch, capsys):
    path, _ = las_file
    done = tmp_path / "done"
    convert([path], done, **OPTS)
    _stop_reading_after(monkeypatch, 2)
    with pytest.raises(KeyboardInterrupt):
        convert([path], tmp_path / "half", **OPTS)
    assert main(["info", str(done), str(tmp_path / "half")]) == 0
    text = capsys.readouterr().out
    assert "gigapoint octree" in text and "100,000" in text and " nodes in " in text and "grid sampler" in text
    assert "unfinished conversion" in text and "phase read, 40,000 of 100,000 points read" in text
    assert "stopped: run `gigapoint convert` again to resume it" in text  # nothing holds its lock
    assert main(["info", "--json", str(done)]) == 0
    data = json.loads(capsys.readouterr().out)
    oc = gp.open(done)
    assert data["point_count"] == 100_000 and data["nodes"] == len(oc.keys) and data["attributes"] == sorted(oc.attributes)
    assert "intensity" in data["attributes"] and data["levels"] == int(oc.nodes["level"].max()) + 1


def test_info_of_a_conversion_whose_work_files_go_while_it_is_read(tmp_path, monkeypatch, capsys):
    """A running conversion renames and removes its work folders while `info` sums their sizes:
    info failed with "OUT/.partial/built/g282.tmp: No such file or directory"."""
    import os

    out = tmp_path / "out.copc.laz.work"
    (out / ".partial" / "built" / "g1.tmp").mkdir(parents=True)
    (out / ".partial" / "built" / "g1.tmp" / "x.npy").write_bytes(b"x" * 1000)
    (out / ".partial" / "state.json").write_text(json.dumps({"phase": "build", "points": 5, "total": 5}))
    real = os.scandir

    def removed_once_listed(path="."):  # g1.tmp goes between the listing of built/ and its own
        if os.fspath(path).endswith("g1.tmp"):
            raise FileNotFoundError(2, "No such file or directory", os.fspath(path))
        return real(path)

    monkeypatch.setattr(os, "scandir", removed_once_listed)
    assert main(["info", str(out)]) == 0
    text = capsys.readouterr().out
    assert "phase build, 5 of 5 points read" in text
    assert re.search(r"file size: +\d+ bytes", text), text  # state.json's, not g1.tmp's 1000


def test_a_copc_file_not_written_yet_and_its_finished_work_folder_say_why(tmp_path, capsys):
    """`render`/`view`/`gp.open` of a COPC file a conversion is still making said a bare "no such
    file", and `info` said "run the same convert command again to resume it" of a conversion at
    work; the work folder `convert` names, once the file is written and the folder removed, was
    "no such file" too."""
    out = tmp_path / "out.copc.laz"
    work = tmp_path / "out.copc.laz.work"
    (work / ".partial").mkdir(parents=True)
    (work / ".partial" / "state.json").write_text(json.dumps({"phase": "read"}))

    def said(args) -> str:
        assert main(args) == 1
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and "Traceback" not in err
        return err

    running = f"{out}: no such file yet: a conversion is writing it; open its work folder {work} to see what it has read so far"
    lock = OctreeDir(work).lock()  # a conversion at work
    try:
        with pytest.raises(InputError) as caught:
            gp.open(out)
        assert str(caught.value) == running
        assert said(["info", str(out)]) == f"error: {running}"
        assert said(["render", str(out), "-o", str(tmp_path / "x.png")]) == f"error: {running}"
        assert said(["view", str(out), "--port", "0", "--no-browser"]) == f"error: {running}"
    finally:
        lock.release()
    stopped = f"{out}: no such file yet: a conversion to it is unfinished (its work folder {work} is there); run the same convert command again to resume it"
    with pytest.raises(InputError) as caught:
        gp.open(out)
    assert str(caught.value) == stopped
    assert said(["render", str(out), "-o", str(tmp_path / "x.png")]) == f"error: {stopped}"

    shutil.rmtree(work)  # finished: the file written, its work folder removed
    out.write_bytes(b"a COPC file")
    finished = f"{work}: no such folder: the conversion that worked in it has finished; open {out}"
    with pytest.raises(InputError) as caught:
        gp.open(work)
    assert str(caught.value) == finished
    for args in (["info", str(work)], ["render", str(work), "-o", str(tmp_path / "x.png")], ["view", str(work), "--port", "0", "--no-browser"]):
        assert said(args) == f"error: {finished}"
    assert not (tmp_path / "x.png").exists()


def test_convert_tile_and_change_of_a_copc_file_not_written_yet_say_why(tmp_path, capsys):
    """`convert`, `tile` (CLI and library) of a COPC file a conversion has not finished said a bare
    "no such file", as `gp.open` once did; `change` (through `gp.open`) says why too."""
    out = tmp_path / "out.copc.laz"
    (tmp_path / "out.copc.laz.work" / ".partial").mkdir(parents=True)
    (tmp_path / "out.copc.laz.work" / ".partial" / "state.json").write_text(json.dumps({"phase": "read"}))
    stopped = f"{out}: no such file yet: a conversion to it is unfinished (its work folder {out}.work is there); run the same convert command again to resume it"
    calls = {
        "convert to a point file": lambda: gp.convert(out, tmp_path / "x.laz"),
        "convert to an octree": lambda: gp.convert([out], tmp_path / "octree", recursive=True),
        "tile": lambda: gp.tile(out, tmp_path / "tiles", 100.0),
        "change": lambda: gp.change(out, out, 5.0),
        "open a file:// URL": lambda: gp.open(out.as_uri()),  # (the URL's path looked for as given: a bare "no such file")
        "convert a file:// URL": lambda: gp.convert(out.as_uri(), tmp_path / "x.laz"),
        "tile a file:// URL": lambda: gp.tile(out.as_uri(), tmp_path / "tiles", 100.0),
    }
    for what, call in calls.items():
        with pytest.raises(InputError) as caught:
            call()
        assert (what, str(caught.value)) == (what, stopped)
    for args in (["convert", out, "-o", tmp_path / "x.laz"], ["convert", out, "-o", tmp_path / "x.copc.laz"], ["tile", out, "--size", "100", "-o", tmp_path / "tiles"],
                 ["change", out, out, "--gsd", "5", "-o", tmp_path / "dz.tif"]):  # fmt: skip
        assert main([str(a) for a in args]) == 1
        assert (args[0], capsys.readouterr().err) == (args[0], f"error: {stopped}\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.copc.laz.work"]  # (nothing written, the work folder kept)


def test_folders_and_files_no_conversion_made_are_not_said_to_be_ones(tmp_path, capsys):
    """A folder named `a.laz.work` that no conversion made (empty) beside a missing `a.laz` was said
    to be an unfinished conversion to resume; a plain `b.las` made `b.las.work` "a conversion
    that has finished". Both are the plain "no such file" again."""
    (tmp_path / "a.laz.work").mkdir()
    (tmp_path / "b.las").write_bytes(b"not a COPC file")
    for missing in (tmp_path / "a.laz", tmp_path / "b.las.work"):
        with pytest.raises(InputError) as caught:
            gp.open(missing)
        assert "conversion" not in str(caught.value) and str(missing) in str(caught.value)
        assert main(["info", str(missing)]) == 1
        err = capsys.readouterr().err
        assert "conversion" not in err and str(missing) in err


def test_viewer_follows_the_conversion_to_the_octree(las_file, tmp_path, monkeypatch):
    from gigapoint.viewer.protocol import unpack_frame
    from gigapoint.viewer.session import ViewerCore

    path, _ = las_file
    out = tmp_path / "oct"
    real = _stop_reading_after(monkeypatch, 2)
    with pytest.raises(KeyboardInterrupt):
        convert([path], out, **OPTS)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GigapointWarning)
        preview = gp.open(out)
    core = ViewerCore(preview)
    notes = []  # the HUD line of every frame sent

    def send(kind, payload):
        if kind == "bytes":
            notes.append(unpack_frame(payload)[0]["note"])
        return True

    session = core.open_session(send, 96, 64)
    try:
        assert core.watcher is not None
        assert "conversion stopped (run `gigapoint convert` again" in core.note  # the killed run holds no lock
        core.watcher.interval_s = 0.05
        monkeypatch.setattr(read_mod, "_read_chunks", real)
        convert([path], out, **OPTS)  # finishes the conversion while the viewer is open
        deadline = time.monotonic() + 20
        while not (isinstance(core.cloud, OctreeCloud) and session.last is not None and session.last.cloud is core.cloud):
            assert time.monotonic() < deadline, "the viewer did not switch to the finished octree"
            time.sleep(0.05)
        assert core.watcher.finished.is_set() and core.cloud.n_points == 100_000
        assert core.note == "" and any(n.startswith("preview") for n in notes)
    finally:
        core.close_all()


def test_viewer_follows_a_copc_conversion_to_its_file(las_file, tmp_path, monkeypatch):
    """`gigapoint view out.copc.laz.work` (the hint convert prints): once the COPC file is written
    its work folder is removed, and the viewer kept the preview on screen for good."""
    from gigapoint.lod.preview import ConversionPreview
    from gigapoint.viewer.session import ViewerCore

    path, _ = las_file
    out = tmp_path / "out.copc.laz"
    real = _stop_reading_after(monkeypatch, 2)
    with pytest.raises(KeyboardInterrupt):
        convert([path], out, format="copc", **OPTS)
    preview = _open_preview(tmp_path / "out.copc.laz.work")
    assert isinstance(preview, ConversionPreview) and 0 < preview.n_points < 100_000
    core = ViewerCore(preview)
    core.open_session(lambda kind, payload: True, 96, 64)
    try:
        core.watcher.interval_s = 0.05
        monkeypatch.setattr(read_mod, "_read_chunks", real)
        convert([path], out, format="copc", **OPTS)  # finishes while the viewer is open: the work folder goes
        assert out.is_file() and not (tmp_path / "out.copc.laz.work").exists()
        deadline = time.monotonic() + 20
        while isinstance(core.cloud, ConversionPreview):
            assert time.monotonic() < deadline, "the viewer did not switch to the finished COPC file"
            time.sleep(0.05)
        assert core.cloud.n_points == 100_000 and core.cloud.name == "out.copc.laz"
        assert core.watcher.finished.is_set() and core.note == ""
    finally:
        core.close_all()


def test_view_waits_for_the_first_preview(tmp_path):
    import threading

    from gigapoint.lod.preview import awaiting_preview, wait_for_preview

    out = tmp_path / "oct"
    (out / ".partial").mkdir(parents=True)
    (out / ".partial" / "state.json").write_text(json.dumps({"phase": "read"}))
    # a conversion killed before its first preview: nothing to wait for
    t0 = time.monotonic()
    assert awaiting_preview(out) and not wait_for_preview(out, timeout_s=30, poll_s=0.05)
    assert time.monotonic() - t0 < 5
    lock = OctreeDir(out).lock()  # a conversion at work (it holds OUT's lock)
    try:
        assert not wait_for_preview(out, timeout_s=0.3, poll_s=0.05)  # times out

        def write_preview():
            s = PreviewSampler(out / ".partial" / PREVIEW_NAME, target=100, total=None)
            s.add(*_chunk(0, 50))
            s.maybe_write()

        threading.Timer(0.2, write_preview).start()
        t0 = time.monotonic()
        assert wait_for_preview(out, timeout_s=10, poll_s=0.05) and time.monotonic() - t0 < 5
        assert not awaiting_preview(out)
        with pytest.warns(GigapointWarning, match="conversion not finished") as caught:
            assert gp.open(out).n_points == 50
        assert "stopped" not in str(caught[0].message)
    finally:
        lock.release()
    with pytest.warns(GigapointWarning, match="it has stopped: run `gigapoint convert` again to resume it"):
        gp.open(out)


def test_conversion_running_follows_the_output_lock(tmp_path):
    out = tmp_path / "oct"
    out.mkdir()
    assert OctreeDir(out).running is False
    lock = OctreeDir(out).lock()
    try:
        assert OctreeDir(out).running is True
        assert OctreeDir(out).running is True  # probing leaves the lock where it was
        with pytest.raises(conv_mod.ConvertError, match="another conversion is writing into it"):
            OctreeDir(out).lock()
    finally:
        lock.release()
    assert OctreeDir(out).running is False
    assert OctreeDir(tmp_path / "missing").running is None
