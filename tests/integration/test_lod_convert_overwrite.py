"""`convert --overwrite`: the complete octree in OUT stays, and opens, until the new one is
complete; a replacement that fails part-way (disk full, Ctrl+C, a kill) leaves it as it was."""

from __future__ import annotations

import errno
import hashlib
import importlib
import shutil
from pathlib import Path

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.cli import main
from gigapoint.errors import InputError
from gigapoint.lod import ConvertError, OctreeDir, OutputExistsError, convert
from gigapoint.lod.convert import hooks

OPTS = {"max_leaf": 3_000, "partition_points": 25_000, "chunk_size": 40_000}
phases = importlib.import_module("gigapoint.lod.convert.phases")


@pytest.fixture(scope="module")
def inputs(tmp_path_factory, las_writer):
    """Two LAS files: what the old octree was made of, and what replaces it."""
    d = tmp_path_factory.mktemp("las")
    return las_writer(d / "old.las", 60_000, seed=1), las_writer(d / "new.las", 90_000, seed=2)


def _files(out: Path) -> dict:
    """Every file under ``out`` with the SHA-256 of its bytes."""
    return {str(p.relative_to(out)): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(out.rglob("*")) if p.is_file()}


def _points(out: Path) -> tuple[int, str]:
    """The octree ``out`` as gp.open reads it: its point count and a checksum of its positions
    (every node's, decoded; a Potree octree: of its octree.bin, which holds them)."""
    cloud = gp.open(out)
    if (out / "metadata.json").exists():
        return cloud.n_points, hashlib.sha256((out / "octree.bin").read_bytes()).hexdigest()
    xyz = np.concatenate([cloud.node_points(i)["xyz"] for i in range(len(cloud.nodes))])
    return cloud.n_points, hashlib.sha256(np.ascontiguousarray(xyz[np.lexsort(xyz.T)]).tobytes()).hexdigest()


def _fail_in_build(monkeypatch, exc):
    """The build phase raises ``exc`` after its first partition."""

    def hook(done):
        if done == 1:
            raise exc

    monkeypatch.setattr(hooks, "after_partition_built", hook)


@pytest.mark.parametrize("fmt", ["gigapoint", "potree"])
def test_a_replacement_that_fails_in_the_build_keeps_the_old_octree(inputs, tmp_path, monkeypatch, capsys, fmt):
    """A full disk in the build phase: OUT was already cleared, so the user had lost the old
    octree and held an unfinished conversion."""
    old, new = inputs
    out = tmp_path / "oct"
    convert([old], out, format=fmt, **OPTS)
    files, points = _files(out), _points(out)
    assert points[0] == 60_000
    _fail_in_build(monkeypatch, OSError(errno.ENOSPC, "No space left on device", str(out / ".partial" / "x.npy")))
    with pytest.raises(ConvertError) as err:
        convert([new], out, format=fmt, overwrite=True, **OPTS)
    assert str(err.value) == (
        f"{out}/.partial/x.npy: No space left on device; {out} still holds the octree it was to replace "
        "(run it again with overwrite=True once the cause is gone: it resumes)"
    )
    assert _points(out) == points  # opens as the old octree, every file as it was
    assert {k: v for k, v in _files(out).items() if not k.startswith(".partial") and ".tmp" not in k} == files
    # the CLI: one line, worded for it; `info` reads the old octree
    capsys.readouterr()
    assert main(["convert", str(new), "-o", str(out), "--format", fmt, "--overwrite", "--quiet", "--max-leaf", "3000"]) == 1
    warning, err = capsys.readouterr().err.split("\n", 1)  # (its options are not the Python run's: that run's work goes, and it says so)
    assert warning == f"warning: {out}: the unfinished conversion there was started with other inputs or options: starting over"
    assert err.count("\n") == 1 and err.endswith(f"; {out} still holds the octree it was to replace (run it again with --overwrite once the cause is gone: it resumes)\n")
    assert _points(out) == points
    monkeypatch.setattr(hooks, "after_partition_built", lambda done: None)
    assert main(["info", str(out)]) == 0


def test_a_replacement_stopped_by_a_corrupt_input_keeps_the_old_octree(inputs, tmp_path):
    """A truncated second input: its one-line error says what became of OUT."""
    old, new = inputs
    out, cut = tmp_path / "oct", tmp_path / "cut.las"
    convert([old], out, **OPTS)
    files, points = _files(out), _points(out)
    cut.write_bytes(new.read_bytes()[:1_000_000])
    with pytest.raises(InputError, match=rf"^{cut}: truncated LAS file: .*; {out} still holds the octree it was to replace \(") as err:
        convert([old, cut], out, overwrite=True, **OPTS)
    # it said "once the cause is gone: it resumes": unchanged, the file stops it again; mended, it starts over
    assert "\n" not in str(err.value) and str(err.value).endswith("(run it again with overwrite=True once that file is whole, or without it: it starts over)")
    assert {k: v for k, v in _files(out).items() if not k.startswith(".partial")} == files and _points(out) == points


def test_a_copc_file_is_replaced_only_once_the_new_one_is_complete(inputs, tmp_path, monkeypatch):
    """A COPC output is written under a temporary name and renamed (atomic_open): a failed
    replacement leaves the old file, and says so."""
    old, new = inputs
    out = tmp_path / "scan.copc.laz"
    convert([old], out, **OPTS)
    before = out.read_bytes()
    _fail_in_build(monkeypatch, OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "x")))
    with pytest.raises(ConvertError, match=rf"; {out} still holds the octree it was to replace \(.*: it resumes\)$"):
        convert([new], out, overwrite=True, **OPTS)
    assert out.read_bytes() == before and gp.open(out).n_points == 60_000
    monkeypatch.setattr(hooks, "after_partition_built", lambda done: None)
    ready = []
    assert convert([new], out, overwrite=True, on_ready=lambda: ready.append(1), **OPTS).points == 90_000
    assert gp.open(out).n_points == 90_000 and ready == [1]  # the work folder's preview was there to watch


def _reference(new: Path, tmp_path: Path, fmt: str) -> dict:
    ref = tmp_path / f"ref-{fmt}"
    if not ref.exists():
        convert([new], ref, format=fmt, **OPTS)
    return _files(ref)


@pytest.mark.parametrize("fmt", ["gigapoint", "potree"])
def test_an_interrupted_replacement_is_never_mixed_and_overwrite_resumes_it(inputs, tmp_path, monkeypatch, capsys, fmt):
    """Ctrl+C while replacing: OUT opens as the old octree; a run without --overwrite refuses
    (it neither resumes into nor mixes with the old files); with --overwrite it resumes, and
    the result is byte for byte a fresh conversion of the new input, the old files gone."""
    old, new = inputs
    out = tmp_path / "oct"
    convert([old], out, format="potree" if fmt == "gigapoint" else "gigapoint", **OPTS)  # the other format: none of its files may stay
    points = _points(out)
    _fail_in_build(monkeypatch, KeyboardInterrupt("test"))
    with pytest.raises(KeyboardInterrupt):
        convert([new], out, format=fmt, overwrite=True, **OPTS)
    assert _points(out) == points
    for _ in range(2):
        with pytest.raises(OutputExistsError, match="already holds a converted point cloud; pass overwrite=True"):
            convert([new], out, format=fmt, **OPTS)
    assert _points(out) == points
    monkeypatch.setattr(hooks, "after_partition_built", lambda done: None)
    res = convert([new], out, format=fmt, overwrite=True, **OPTS)
    assert res.resumed and res.points == 90_000 and res.first_view_seconds is None  # OUT showed the old octree, never a preview
    assert _files(out) == _reference(new, tmp_path, fmt)
    assert _points(out)[0] == 90_000


@pytest.mark.parametrize("fmt", ["gigapoint", "potree"])
def test_a_replacement_that_fails_in_the_write_phase_puts_the_old_octree_back(inputs, tmp_path, monkeypatch, fmt):
    """The write phase moves the old files aside before the new ones take their names: a full
    disk there put neither octree in OUT."""
    old, new = inputs
    out = tmp_path / "oct"
    convert([old], out, format=fmt, **OPTS)
    files, points = _files(out), _points(out)
    full = OSError(errno.ENOSPC, "No space left on device", str(out / "hierarchy.bin"))

    def fails(*args, **kwargs):  # after the new octree's point files took their names
        assert not (out / "octree.json").exists() and not (out / "metadata.json").exists()
        raise full

    writer = importlib.import_module("gigapoint.lod.writer" if fmt == "gigapoint" else "gigapoint.lod.potree")
    monkeypatch.setattr(writer, "write_streams" if fmt == "gigapoint" else "_finish_potree", fails)
    with pytest.raises(ConvertError) as err:
        convert([new], out, format=fmt, overwrite=True, **OPTS)
    assert str(err.value) == (
        f"{out}/hierarchy.bin: No space left on device; {out} still holds the octree it was to replace "
        "(run it again with overwrite=True once the cause is gone: it starts over)"
    )
    assert _files(out) == files and _points(out) == points  # nothing else left: no work, no new file


def test_a_replacement_killed_in_its_write_phase_gives_the_old_octree_back_or_finishes(inputs, tmp_path, monkeypatch):
    """Killed once the old files were set aside (no handler runs): a run with other inputs puts
    them back and refuses without overwrite; the same run with overwrite finishes the new one."""
    old, new = inputs
    out = tmp_path / "oct"
    convert([old], out, **OPTS)
    files, points = _files(out), _points(out)
    writer = importlib.import_module("gigapoint.lod.writer")

    def killed(*args, **kwargs):
        raise SystemExit(137)

    monkeypatch.setattr(writer, "write_streams", killed)
    monkeypatch.setattr(OctreeDir, "restore", lambda self: False)  # a kill: nothing runs after it
    with pytest.raises(SystemExit):
        convert([new], out, overwrite=True, **OPTS)
    monkeypatch.undo()
    assert OctreeDir(out).kind == "unfinished" and (out / ".partial" / "old" / "octree.json").exists()
    kept = tmp_path / "kept"
    shutil.copytree(out, kept)
    with pytest.raises(OutputExistsError, match="already holds a converted point cloud"):
        convert([old], out, **OPTS)  # other inputs: the old octree is back, and kept
    assert _files(out) == files and _points(out) == points
    res = convert([new], kept, **OPTS)  # the same inputs: the replacement's write phase resumes
    assert res.resumed and _files(kept) == _reference(new, tmp_path, "gigapoint")


def test_a_cloud_saved_over_an_octree_that_fails_keeps_it(tmp_path, monkeypatch):
    """A cloud's points (chunks from Python, not resumable): the run's work goes, the old octree stays."""
    out = tmp_path / "oct"
    convert(gp.demo(30_000, seed=1, colors="rgba"), out, **OPTS)
    files = _files(out)
    _fail_in_build(monkeypatch, OSError(errno.ENOSPC, "No space left on device", str(out / ".partial" / "x.npy")))
    monkeypatch.setattr(importlib.import_module("gigapoint.lod.convert.in_memory"), "fits_in_memory", lambda job: False)
    with pytest.raises(ConvertError, match=rf"; {out} still holds the octree it was to replace \(.*: it starts over\)$"):
        convert(gp.demo(50_000, seed=2, colors="rgba"), out, overwrite=True, **OPTS)
    assert _files(out) == files


def test_a_replacement_that_succeeds_is_a_fresh_conversion(inputs, tmp_path):
    """Byte for byte what a conversion into an empty folder writes, and nothing of the old octree left."""
    old, new = inputs
    for fmt, before in (("gigapoint", "potree"), ("potree", "gigapoint"), ("gigapoint", "gigapoint")):
        out = tmp_path / f"{before}-{fmt}"
        convert([old], out, format=before, **OPTS)
        res = convert([new], out, format=fmt, overwrite=True, **OPTS)
        assert not res.resumed and res.points == 90_000
        assert _files(out) == _reference(new, tmp_path, fmt)


def test_an_interrupted_cloud_save_over_an_octree_leaves_only_the_old_octree(tmp_path, monkeypatch):
    """Ctrl+C in a cloud's save (chunks from Python: no run resumes them) left its .partial
    beside the old octree until the next save cleared it."""
    out = tmp_path / "oct"
    convert(gp.demo(30_000, seed=1, colors="rgba"), out, **OPTS)
    files, points = _files(out), _points(out)
    _fail_in_build(monkeypatch, KeyboardInterrupt("test"))
    monkeypatch.setattr(importlib.import_module("gigapoint.lod.convert.in_memory"), "fits_in_memory", lambda job: False)
    with pytest.raises(KeyboardInterrupt):
        convert(gp.demo(50_000, seed=2, colors="rgba"), out, overwrite=True, **OPTS)
    assert _files(out) == files and _points(out) == points  # no .partial, and it opens as before
