"""`gigapoint convert` end to end: LAS input, interruption and resume, overwrite safety, bad input."""

from __future__ import annotations

import json
import os
import re
import shutil as sh
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from gigapoint.cli import main
from gigapoint.lod import ConvertError, OctreeDir, OutputExistsError, convert, open_octree
from gigapoint.lod.convert import hooks

laspy = pytest.importorskip("laspy")

SHARED = Path(__file__).resolve().parents[2] / ".." / "shared" / "data"


def _interrupt_after(monkeypatch, n):
    """The conversion stops (KeyboardInterrupt) once it has built ``n`` partitions in a run; None: never."""

    def hook(done):
        if done == n:
            raise KeyboardInterrupt(f"test interrupt after {done} partitions")

    monkeypatch.setattr(hooks, "after_partition_built", hook)


def _spilling(monkeypatch):
    """Conversions spill their chunks and partitions to files however small the input (the
    out-of-core path, which an input that fits the memory limit skips: in_memory.py)."""
    import importlib

    monkeypatch.setattr(importlib.import_module("gigapoint.lod.convert.in_memory"), "fits_in_memory", lambda job: False)


@pytest.fixture(scope="module")
def demo_las(tmp_path_factory, las_writer):
    return las_writer(tmp_path_factory.mktemp("las") / "demo.las", 150_000)


OPTS = {"max_leaf": 3_000, "partition_points": 25_000, "chunk_size": 40_000}


def _snapshot(path: Path) -> dict:
    oc = open_octree(path)
    d = {"keys": oc.keys, "nodes": oc.nodes}
    for k, v in oc.arrays.items():
        d[k] = np.asarray(v)
    for k, v in oc.attributes.items():
        d["attr." + k] = np.asarray(v)
    return d


def _assert_same(a: dict, b: dict):
    assert a.keys() == b.keys()
    for k, v in a.items():
        np.testing.assert_array_equal(v, b[k], err_msg=k)


@pytest.fixture(scope="module")
def reference(demo_las, tmp_path_factory):
    out = tmp_path_factory.mktemp("ref") / "oct"
    res = convert([demo_las], out, **OPTS)
    assert res.points == 150_000 and not res.resumed
    return _snapshot(out)


def test_las_conversion_counts_and_layout(reference, demo_las):
    assert int(reference["nodes"]["count"].sum()) == 150_000
    assert set(reference) >= {"low", "med", "high", "color", "rgba", "attr.intensity", "attr.classification"}
    with laspy.open(str(demo_las)) as f:
        las = f.read()
    # every LAS classification value is there exactly as often as in the file
    np.testing.assert_array_equal(
        np.bincount(reference["attr.classification"], minlength=32), np.bincount(np.asarray(las.classification), minlength=32)
    )


def test_interrupted_conversion_resumes_to_the_same_result(demo_las, reference, tmp_path, monkeypatch):
    out = tmp_path / "oct"
    _interrupt_after(monkeypatch, 2)
    with pytest.raises(KeyboardInterrupt):
        convert([demo_las], out, **OPTS)
    assert not (out / "octree.json").exists() and (out / ".partial" / "state.json").exists()
    state = json.loads((out / ".partial" / "state.json").read_text())
    assert state["phase"] == "build" and len(state["partitions"]) > 3
    import gigapoint as gp
    from gigapoint.errors import GigapointWarning
    from gigapoint.lod import OctreeCloud

    with pytest.warns(GigapointWarning, match="conversion not finished"):
        preview = gp.open(out)  # an unfinished output opens as its preview, never as the octree
    assert not isinstance(preview, OctreeCloud)
    with laspy.open(str(demo_las)) as f:
        las = f.read()
    every = np.column_stack([las.x, las.y, las.z])[:: state["preview"]["stride"]]
    assert preview.n_points == len(every) == state["preview"]["points"]
    # positions come back at 30-bit batch precision, far finer than the LAS file's millimetres
    np.testing.assert_array_equal(np.unique(np.round(preview.positions(), 3), axis=0), np.unique(np.round(every, 3), axis=0))
    _interrupt_after(monkeypatch, None)
    res = convert([demo_las], out, **OPTS)
    assert res.resumed
    assert not (out / ".partial").exists()
    _assert_same(_snapshot(out), reference)


def test_a_conversion_interrupted_under_one_gigapoint_starts_clean_under_another(demo_las, reference, tmp_path, monkeypatch, capsys):
    """The fingerprint held no code version: a run interrupted, gigapoint upgraded, then run again
    resumed the old version's work files under the new code. Now it starts clean, as with other
    inputs; and info, gp.open and the rerun say so (they said "run `gigapoint convert` again to
    resume it", then the rerun discarded the work without a word)."""
    import gigapoint as gp
    from gigapoint.errors import GigapointWarning
    from gigapoint.lod import code

    out = tmp_path / "oct"
    monkeypatch.setattr(code, "_CODE_VERSION", "0.0.1+000000000000")
    _interrupt_after(monkeypatch, 2)
    with pytest.raises(KeyboardInterrupt):
        convert([demo_las], out, **OPTS)
    state = json.loads((out / ".partial" / "state.json").read_text())
    assert state["phase"] == "build" and state["code_version"] == "0.0.1+000000000000"
    assert main(["info", str(out)]) == 0
    assert "stopped: run `gigapoint convert` again to resume it" in capsys.readouterr().out  # under the same gigapoint
    monkeypatch.setattr(code, "_CODE_VERSION", "0.0.2+000000000000")  # upgraded
    hint = "it was started by gigapoint 0.0.1+000000000000, not this gigapoint 0.0.2+000000000000: running `gigapoint convert` again starts it over"
    assert main(["info", str(out)]) == 0
    assert f"stopped: {hint}" in capsys.readouterr().out
    with pytest.warns(GigapointWarning, match=re.escape(f"it has stopped: {hint}")):
        gp.open(out)
    _interrupt_after(monkeypatch, None)
    said = re.escape(f"{out}: the unfinished conversion there was started by gigapoint 0.0.1+000000000000 (this is 0.0.2+000000000000): starting over")
    with pytest.warns(GigapointWarning, match=said):
        res = convert([demo_las], out, **OPTS)
    assert not res.resumed and res.points == 150_000
    _assert_same(_snapshot(out), reference)


def test_a_rerun_with_other_options_says_it_starts_over_and_a_resume_says_nothing(demo_las, tmp_path, monkeypatch, capsys):
    """A rerun with other inputs or options discarded the unfinished conversion's work without a
    word (hours of it, for a mistyped option); the CLI now warns, and a resume does not."""
    out = tmp_path / "oct"
    _interrupt_after(monkeypatch, 2)
    with pytest.raises(KeyboardInterrupt):
        convert([demo_las], out, **OPTS)
    _interrupt_after(monkeypatch, 1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the same conversion resumes: no word of starting over
        with pytest.raises(KeyboardInterrupt):
            convert([demo_las], out, **OPTS)
    _interrupt_after(monkeypatch, None)
    assert main(["convert", str(demo_las), "-o", str(out), "--quiet", "--max-leaf", "5000"]) == 0
    err = capsys.readouterr().err
    assert f"warning: {out}: the unfinished conversion there was started with other inputs or options: starting over" in " ".join(err.split()), err
    assert open_octree(out).n_points == 150_000


def test_a_conversion_reads_its_state_file_once_to_start_or_resume(demo_las, tmp_path, monkeypatch):
    """Whose unfinished work is there (other_work) and whether it resumes (prepare_output) each
    read the state file: twice at every start. It is read once, fresh or resumed."""
    out = tmp_path / "oct"
    reads = []
    real = OctreeDir.read_state
    monkeypatch.setattr(OctreeDir, "read_state", lambda d: reads.append(d.state_file) or real(d))
    _interrupt_after(monkeypatch, 2)
    with pytest.raises(KeyboardInterrupt):
        convert([demo_las], out, **OPTS)
    assert reads == [out / ".partial" / "state.json"]
    reads.clear()
    _interrupt_after(monkeypatch, None)
    assert convert([demo_las], out, **OPTS).resumed
    assert reads == [out / ".partial" / "state.json"]


def test_a_set_written_part_way_into_the_streams_is_written_again_in_its_place(demo_las, reference, tmp_path, monkeypatch):
    """Node sets append their bit streams to one file each (writer.append_streams). A run killed
    while a set was writing leaves words past the finished sets' ends: the resumed run writes
    that set again in their place, and the finished octree holds no stray word."""
    out = tmp_path / "oct"
    _interrupt_after(monkeypatch, 2)
    with pytest.raises(KeyboardInterrupt):
        convert([demo_las], out, **OPTS)
    streams = sorted((out / ".partial").glob("*.stream.npy"))
    assert [p.name for p in streams][:1] == ["ext.stream.npy"] and len(streams) > 2
    for p in streams:  # a third set's words, written part-way when the process died
        with open(p, "ab") as f:
            f.write(np.full(300_000, 0xDEADBEEF, np.uint64).tobytes())  # past where the streams end
    _interrupt_after(monkeypatch, None)
    assert convert([demo_las], out, **OPTS).resumed
    _assert_same(_snapshot(out), reference)
    ext = np.load(out / "ext.npy")
    assert ext.dtype == np.uint64 and not np.any(ext == 0xDEADBEEF)
    assert os.path.getsize(out / "ext.npy") == 128 + 8 * len(ext)


@pytest.mark.parametrize("encoding", ["DEFAULT", "BROTLI"])
def test_a_potree_conversion_resumes_to_the_same_files_with_its_nodes_placed_by_the_build(demo_las, tmp_path, stop_conversion_after, encoding):
    """The build encodes each node set into the octree.bin being built (potree.place_node_set),
    at the next free byte after the finished sets'; a set written part-way by a killed run is
    written again in its place, the bytes past the end cut off."""
    opts = dict(OPTS, format="potree", encoding=encoding)
    whole = tmp_path / "whole"
    convert([demo_las], whole, **opts)
    out = tmp_path / "oct"
    stop_conversion_after(2)
    with pytest.raises(KeyboardInterrupt):
        convert([demo_las], out, **opts)
    with open(out / ".partial" / "octree.bin", "ab") as f:  # a third set's bytes, half written when the process died
        f.write(b"\xab" * 3_000_000)  # past where the whole octree.bin ends
    stop_conversion_after(None)
    assert convert([demo_las], out, **opts).resumed
    assert sorted(p.name for p in out.iterdir()) == ["hierarchy.bin", "metadata.json", "octree.bin"]
    for name in ("hierarchy.bin", "metadata.json", "octree.bin"):
        assert (out / name).read_bytes() == (whole / name).read_bytes(), name


def test_a_damaged_work_file_stops_the_resume_in_one_line_and_overwrite_starts_over(demo_las, reference, tmp_path, monkeypatch):
    """A truncated work file (a machine that crashed before the disk had it) was numpy's
    ValueError part-way through the resume, every time it was run again; a missing one said
    "run it again once the cause is gone: it resumes", which failed the same way every time."""
    import shutil

    def interrupted(out) -> Path:
        """An unfinished conversion into ``out`` and the first node set's nodes.npy."""
        _interrupt_after(monkeypatch, 2)
        with pytest.raises(KeyboardInterrupt):
            convert([demo_las], out, **OPTS)
        _interrupt_after(monkeypatch, None)
        return min((out / ".partial" / "built").rglob("nodes.npy"))

    out = tmp_path / "oct"
    victim = interrupted(out)
    cut = tmp_path / "cut"  # the same run with a write cut by a kill (atomic.py's hidden temporary): no damage
    shutil.copytree(out, cut)
    (cut / victim.relative_to(out)).with_name(f".{victim.name}.1a2b3c4d.tmp.npy").write_bytes(b"\x93NUMPY")
    assert convert([demo_las], cut, **OPTS).resumed
    _assert_same(_snapshot(cut), reference)
    # truncated: found before the resume; missing: found when the resume reads it, and remembered
    missing = interrupted(tmp_path / "gone")
    missing.unlink()
    with open(victim, "r+b") as f:
        f.truncate(60)
    for where, file, problem in ((out, victim, r"damaged \(.*\)"), (missing.parents[3], missing, "missing")):
        for _ in range(2):  # the same line each time, nothing changed by trying
            with pytest.raises(ConvertError, match=rf"^{file}: a work file of the unfinished conversion is {problem}; run it again with --overwrite to start over$"):
                convert([demo_las], where, **OPTS)
        assert not (where / "octree.json").exists()
        assert not convert([demo_las], where, overwrite=True, **OPTS).resumed
        _assert_same(_snapshot(where), reference)


def test_conversion_interrupted_while_grouping_resumes_to_the_same_result(demo_las, tmp_path, monkeypatch):
    """Killed after the first group of partition roots is joined: the re-run resumes in the
    group phase and gives the uninterrupted result."""
    import importlib

    conv = importlib.import_module("gigapoint.lod.convert")
    opts = dict(OPTS, upper_points=8_000)  # 150 000 points in 25 000-point partitions: their roots are joined in groups
    convert([demo_las], tmp_path / "whole", **opts)
    join, calls = conv._Converter._join_roots, []

    def stop_at_second(self, parts, top, dest):
        calls.append(top)
        if len(calls) == 2:
            raise KeyboardInterrupt("test interrupt while grouping")
        return join(self, parts, top, dest)

    monkeypatch.setattr(conv._Converter, "_join_roots", stop_at_second)
    with pytest.raises(KeyboardInterrupt):
        convert([demo_las], tmp_path / "oct", **opts)
    state = json.loads((tmp_path / "oct" / ".partial" / "state.json").read_text())
    assert state["phase"] == "group" and calls[0] != 1
    monkeypatch.setattr(conv._Converter, "_join_roots", join)
    res = convert([demo_las], tmp_path / "oct", **opts)
    assert res.resumed and "group" in res.phase_seconds
    _assert_same(_snapshot(tmp_path / "oct"), _snapshot(tmp_path / "whole"))


def test_another_upper_points_resumes_an_interrupted_grouping_to_the_same_octree(demo_las, tmp_path, monkeypatch):
    """upper_points only sizes the groups (phases.group): any grouping gives the same octree, byte
    for byte, so it is left out of the fingerprint and a re-run with another value resumes the
    groups the first one planned. Were it to change the output, this resume would mix two."""
    import importlib

    conv = importlib.import_module("gigapoint.lod.convert")
    convert([demo_las], tmp_path / "whole", **OPTS)  # upper_points 25 000: no groups at all
    join = conv._Converter._join_roots

    def stop(self, parts, top, dest):
        raise KeyboardInterrupt("test interrupt while grouping")

    monkeypatch.setattr(conv._Converter, "_join_roots", stop)
    with pytest.raises(KeyboardInterrupt):
        convert([demo_las], tmp_path / "oct", **dict(OPTS, upper_points=8_000))
    assert OctreeDir(tmp_path / "oct").read_state()["round"], "groups planned"
    monkeypatch.setattr(conv._Converter, "_join_roots", join)
    res = convert([demo_las], tmp_path / "oct", **dict(OPTS, upper_points=20_000))
    assert res.resumed and "group" in res.phase_seconds
    _assert_same(_snapshot(tmp_path / "oct"), _snapshot(tmp_path / "whole"))


def test_a_full_disk_stops_a_conversion_in_one_line_and_it_resumes(demo_las, tmp_path, monkeypatch):
    """A write that fails for want of room (an OSError without a file name, as a file object's
    ENOSPC is) said only "error: No space left on device": now the file or folder, and that the
    unfinished conversion resumes; run again, it does, to the uninterrupted result."""
    import errno
    import importlib

    from gigapoint.lod import ConvertError

    conv = importlib.import_module("gigapoint.lod.convert")
    opts = dict(OPTS, upper_points=8_000)
    convert([demo_las], tmp_path / "whole", **opts)
    join = conv._Converter._join_roots

    def full(self, parts, top, dest):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(conv._Converter, "_join_roots", full)
    out = tmp_path / "oct"
    with pytest.raises(ConvertError, match=rf"^{out}: No space left on device; the conversion to {out} stopped unfinished \(run it again .*: it resumes\)$"):
        convert([demo_las], out, **opts)
    monkeypatch.setattr(conv._Converter, "_join_roots", join)
    res = convert([demo_las], out, **opts)
    assert res.resumed
    _assert_same(_snapshot(out), _snapshot(tmp_path / "whole"))



def test_a_cloud_conversion_stopped_by_a_full_disk_leaves_no_work_behind(tmp_path, monkeypatch):
    """A conversion of chunks from Python (a cloud, a progressive octree's or a live cloud's
    save) cannot resume: stopped by a full disk, its folder was left (holding the disk) as an
    "unfinished conversion" that `gigapoint info` said to resume, and the error said "it
    resumes". Its work goes; a folder that was there before stays."""
    import errno

    import gigapoint as gp

    def full(done):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(hooks, "after_partition_built", full)
    cloud = gp.demo(5_000, colors="rgba")
    mine = tmp_path / "mine"
    mine.mkdir()
    for out in (tmp_path / "new", mine):
        with pytest.raises(ConvertError, match=rf"^{out}: No space left on device; the conversion to {out} stopped unfinished \(its work was removed: run it again once the cause is gone\)$"):
            convert(cloud, out, max_leaf=1_000)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine"] and list(mine.iterdir()) == []

@pytest.fixture
def small_disk(tmp_path):
    """mount(size_kb) -> a tmpfs of that size (remounted at each call), unmounted at the end;
    skipped where this process may not mount (not root, or a container without the right)."""
    where = tmp_path / "disk"
    where.mkdir()
    mounted = []

    def mount(size_kb: int) -> Path:
        opts = f"remount,size={size_kb}k" if mounted else f"size={size_kb}k"
        proc = subprocess.run(["mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(where)], capture_output=True, text=True)
        if proc.returncode != 0:
            pytest.skip(f"cannot mount a tmpfs here: {proc.stderr.strip()}")
        mounted.append(size_kb)
        return where

    if os.geteuid() != 0 or sh.which("mount") is None:
        pytest.skip("mounting a small disk needs root")
    yield mount
    if mounted:
        subprocess.run(["umount", str(where)], capture_output=True)


@pytest.mark.parametrize("fmt, sizes_kb", [("gigapoint", (4800, 5000, 5600, 6200, 7000, 7200)), ("potree", (5000, 6000, 8000))])
def test_a_full_disk_at_any_point_of_a_conversion_is_one_line_and_it_resumes(small_disk, tmp_path, fmt, sizes_kb):
    """A real full disk (a small tmpfs), at sizes that run out in each phase: the build's files
    filled through memory maps (the output's low words, the bit streams) killed the process
    with SIGBUS before their space was reserved (atomic.reserve), with no word said, and
    numpy's short writes said "26979 requested and 13296 written". Each size converts or stops
    with one line naming a file on that disk; then, with room, the run resumes to the octree
    a conversion with room from the start writes, byte for byte."""
    autzen = SHARED / "autzen_trim.laz"
    if not autzen.exists():
        pytest.skip("../shared/data/autzen_trim.laz is not here")
    ref = tmp_path / "ref"
    convert([autzen], ref, max_leaf=2000, format=fmt)
    cmd = [sys.executable, "-m", "gigapoint.cli", "convert", str(autzen), "--max-leaf", "2000", "--format", fmt, "-o"]
    failed_in = []
    for size_kb in sizes_kb:  # autzen_trim's octree needs ~7.5 MB at its peak (Potree's ~8.5)
        disk = small_disk(size_kb)
        out = disk / f"oct{size_kb}"
        proc = subprocess.run([*cmd, str(out)], capture_output=True, text=True, timeout=300)
        err = [line for line in proc.stderr.splitlines() if not line.startswith("while this runs")]
        assert proc.returncode in (0, 1), f"{size_kb} kB: exit {proc.returncode} {proc.stderr[-500:]}"
        if proc.returncode == 1:
            assert len(err) == 1 and re.match(rf"error: {disk}/\S+: (No space left on device|only \d+ of \d+ bytes written)", err[0]), err
            failed_in.append(err[0].split(":")[1])
            small_disk(40_000)
            proc = subprocess.run([*cmd, str(out)], capture_output=True, text=True, timeout=300)
            assert proc.returncode == 0, proc.stderr
        for f in ref.iterdir():
            assert (out / f.name).read_bytes() == f.read_bytes(), f"{size_kb} kB: {f.name} differs"
        assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in ref.iterdir())
        sh.rmtree(out)
    assert any(".stream.npy" in f or "low.tmp.npy" in f or ".partial/octree.bin" in f for f in failed_in), failed_in  # the mapped files' sizes were among them


def test_conversion_killed_while_distributing_resumes_to_the_same_result(demo_las, reference, tmp_path, monkeypatch):
    """Chunks are grouped and written at checkpoints; killed half-way through writing one, the
    re-run cuts the partition files back to the last checkpoint and gives the uninterrupted result."""
    import importlib

    conv = importlib.import_module("gigapoint.lod.convert")
    partition = importlib.import_module("gigapoint.lod.convert.partition")
    C = conv._Converter
    real_distribute, real_append, real_files = C.distribute, C._append, C._part_files
    seen = {"append": 0, "files": 0, "groups": []}

    def distribute(self):
        self.state["part_code"] = partition._shared_code(self.dir.raw, self.state["chunks"])  # (what distribute decides: int32 positions)
        point = sum(dt.itemsize * (3 if k == "xyz" else 1) for k, dt in self._dtypes().items())
        self.distribute_bytes = int(1.5 * OPTS["chunk_size"] * point)  # a checkpoint every second chunk (of its bytes a point)
        return real_distribute(self)

    def append(self, parts, pieces, counts):
        seen["append"] += 1
        seen["groups"].append(len(pieces))
        return real_append(self, parts, pieces, counts)

    def part_files(self, level, prefix):
        if seen["append"] == 2:  # the second checkpoint: some partitions written, then killed
            seen["files"] += 1
            if seen["files"] == 3:
                raise KeyboardInterrupt("test interrupt while distributing")
        return real_files(self, level, prefix)

    _spilling(monkeypatch)
    monkeypatch.setattr(C, "distribute", distribute)
    monkeypatch.setattr(C, "_append", append)
    monkeypatch.setattr(C, "_part_files", part_files)
    out = tmp_path / "oct"
    with pytest.raises(KeyboardInterrupt):
        convert([demo_las], out, **OPTS)
    state = json.loads((out / ".partial" / "state.json").read_text())
    assert state["phase"] == "distribute" and seen["groups"][0] == 2 and state["distributed"] == 2
    raw = sorted(p.name.split(".")[0] for p in (out / ".partial" / "raw").glob("*.xyz.npy"))
    assert raw == ["c000002", "c000003"]  # spills are deleted only once their checkpoint is written
    for name, f in [("distribute", real_distribute), ("_append", real_append), ("_part_files", real_files)]:
        monkeypatch.setattr(C, name, f)
    res = convert([demo_las], out, **OPTS)
    assert res.resumed
    _assert_same(_snapshot(out), reference)

@pytest.fixture(scope="module")
def town_and_spot(demo_las, tmp_path_factory):
    """The demo town and a 30 000-point spot in a 5 cm cube (one count-grid cell): the spot's
    partition is refined below the count grid."""
    rng = np.random.default_rng(3)
    lo = np.array(laspy.read(str(demo_las)).header.mins, np.float64)
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = [0.001] * 3, [0.0] * 3
    las = laspy.LasData(header)
    spot = lo + 20.0 + rng.random((30_000, 3)) * 0.05
    las.x, las.y, las.z = spot.T
    las.red, las.green, las.blue = rng.integers(0, 65535, (3, 30_000)).astype(np.uint16)
    las.intensity = np.arange(30_000, dtype=np.uint16)
    path = tmp_path_factory.mktemp("spot") / "spot.las"
    las.write(str(path))
    return [demo_las, path]


def _files_of(d: Path) -> dict:
    return {str(f.relative_to(d)): f.read_bytes() for f in sorted(d.rglob("*")) if f.is_file()}


@pytest.mark.parametrize("fmt, opts", [
    ("gigapoint", OPTS),  # 180 000 points in partitions of 25 000, the spot's refined
    ("gigapoint", {"max_leaf": 3_000}),  # one partition
    ("potree", OPTS),
    ("gigapoint", dict(OPTS, layout="words", sampler="poisson")),
])  # fmt: skip
def test_an_input_that_fits_in_memory_converts_to_the_spilled_octree_without_a_file_between(town_and_spot, tmp_path, monkeypatch, fmt, opts):
    """Byte for byte the out-of-core conversion's output, with no spill and no partition file written."""
    import importlib

    with monkeypatch.context() as m:
        _spilling(m)
        spilled = convert(town_and_spot, tmp_path / "spilled", format=fmt, **opts)

    def written(*args, **kwargs):
        pytest.fail("a file was written between the phases")

    for module in ("read", "in_memory"):  # raw chunks
        monkeypatch.setattr(importlib.import_module(f"gigapoint.lod.convert.{module}"), "save_raw_chunk", written)
    monkeypatch.setattr(importlib.import_module("gigapoint.lod.convert.partition"), "append_file", written)  # partitions
    held = convert(town_and_spot, tmp_path / "held", format=fmt, **opts)
    assert held.in_memory and not spilled.in_memory
    assert held.points == spilled.points == 180_000 and held.nodes == spilled.nodes
    a, b = _files_of(tmp_path / "spilled"), _files_of(tmp_path / "held")
    assert a.keys() == b.keys() and [k for k in a if a[k] != b[k]] == []
    assert set(held.phase_seconds) == {"read", "count", "distribute", "build", "group", "upper", "write"}


@pytest.mark.parametrize("spilled", [False, True])
def test_the_output_arrays_go_to_the_disk_while_the_build_writes_them(demo_las, tmp_path, monkeypatch, spilled):
    """Every byte of the point arrays and bit streams past their headers is handed to
    atomic.start_writeback (sync_file_range) as the build writes it, once: the write phase's
    fsyncs then wait for little (a 20 M-point conversion's ~0.4 s)."""
    from gigapoint import atomic

    sent: dict[str, list] = {}

    def sync_file_range(fd, offset, length, flags):
        assert flags == 2  # SYNC_FILE_RANGE_WRITE: started, not waited for
        sent.setdefault(os.readlink(f"/proc/self/fd/{fd}"), []).append((offset, length))
        return 0

    monkeypatch.setattr(atomic, "_sync_file_range", lambda: sync_file_range)
    if spilled:
        _spilling(monkeypatch)
    out = OctreeDir(tmp_path / "oct")
    convert([demo_las], out.path, **OPTS)
    arrays = [k for k in ("low", "ext", "field.rgba", "field.color", "field.attr.intensity", "field.attr.classification")]
    assert all(out.array(k).exists() for k in arrays)
    for k in arrays:
        ranges = sorted(sent.pop(str(out.stream_in_progress(k) if k.startswith(("ext", "field.")) else out.array_in_progress(k))))
        header = os.path.getsize(out.array(k)) - np.load(out.array(k), mmap_mode="r").nbytes
        ends = [header] + [o + n for o, n in ranges]
        assert [o for o, _ in ranges] == ends[:-1] and ends[-1] == os.path.getsize(out.array(k)), k  # back to back, all of it
    assert not [p for p in sent if "/oct/" in p]  # no other output file


def test_potree_octree_bin_goes_to_the_disk_while_the_build_writes_it(demo_las, tmp_path, monkeypatch):
    """Potree format: every byte of octree.bin is handed to atomic.start_writeback as the build
    places each node set in it, once, back to back (its write phase's fsync waited 1.2 s of a
    20 M-point conversion for the whole file)."""
    from gigapoint import atomic

    sent: dict[str, list] = {}

    def sync_file_range(fd, offset, length, flags):
        sent.setdefault(os.readlink(f"/proc/self/fd/{fd}"), []).append((offset, length))
        return 0

    monkeypatch.setattr(atomic, "_sync_file_range", lambda: sync_file_range)
    out = OctreeDir(tmp_path / "oct")
    convert([demo_las], out.path, format="potree", **OPTS)
    ranges = sorted(sent.pop(str(out.potree_octree_in_progress)))
    ends = [0] + [o + n for o, n in ranges]
    assert len(ranges) > 1 and [o for o, _ in ranges] == ends[:-1] and ends[-1] == os.path.getsize(out.potree_octree)
    assert not sent


@pytest.mark.parametrize("code", ["files", "off the grid at the 3rd chunk"])
def test_held_las_positions_are_int32_and_the_octree_is_the_spilled_ones(town_and_spot, tmp_path, monkeypatch, code):
    """An input held in memory whose files share a LAS grid holds its positions as int32 (12
    bytes a point, not 24), decoded a partition at a time for the build (and for the refinement's
    codes): the octree is the out-of-core conversion's byte for byte. A chunk off that grid turns
    every held chunk back to float64 and the rest are held so, to the same octree."""
    import importlib

    in_memory = importlib.import_module("gigapoint.lod.convert.in_memory")
    with monkeypatch.context() as m:
        _spilling(m)
        convert(town_and_spot, tmp_path / "spilled", **OPTS)
    if code != "files":  # encode_xyz finds the 3rd chunk off the grid
        encode, calls = in_memory.encode_xyz, []

        def encoding(xyz, c):
            calls.append(1)
            return None if len(calls) == 3 else encode(xyz, c)

        monkeypatch.setattr(in_memory, "encode_xyz", encoding)
    dtypes = []
    count = in_memory.InMemoryPhases.count

    def counting(self):
        dtypes.extend(c["xyz"].dtype for c in self._held)
        return count(self)

    monkeypatch.setattr(in_memory.InMemoryPhases, "count", counting)
    held = convert(town_and_spot, tmp_path / "held", **OPTS)
    assert held.in_memory and len(dtypes) == 5  # 150 000 points in chunks of 40 000, then the spot
    assert set(dtypes) == ({np.dtype(np.int32)} if code == "files" else {np.dtype(np.float64)})
    a, b = _files_of(tmp_path / "spilled"), _files_of(tmp_path / "held")
    assert a.keys() == b.keys() and [k for k in a if a[k] != b[k]] == []


@pytest.mark.filterwarnings("ignore:.*not in every file")  # (the text file has no attributes)
def test_spilled_las_positions_are_int32_and_the_octree_the_same(town_and_spot, tmp_path, monkeypatch):
    """Out of core in one process, the chunks of LAS files spill their positions as each file's
    int32 (12 bytes a point, not 24: 60 MB of a 5 M-point conversion), as Dask's read tasks do;
    a text file's stay float64. The octree is the float64 spill's byte for byte."""
    import importlib

    read, spill = (importlib.import_module(f"gigapoint.lod.convert.{m}") for m in ("read", "spill"))
    text = tmp_path / "more.xyz"
    np.savetxt(text, np.asarray(laspy.read(str(town_and_spot[1])).xyz)[:500] + 1.0, fmt="%.3f")
    inputs = [*town_and_spot, text]
    _spilling(monkeypatch)
    with monkeypatch.context() as m:
        m.setattr(read.ReadPhase, "_spill_code", None)
        m.setattr(read, "_grid_of", lambda path: None)  # as before: float64 positions
        convert(inputs, tmp_path / "wide", **OPTS)
    saved, save = [], spill.save_raw_chunk
    monkeypatch.setattr(read, "save_raw_chunk", lambda raw, i, xyz, *a: (saved.append(xyz.dtype), save(raw, i, xyz, *a))[1])
    convert(inputs, tmp_path / "ints", **OPTS)
    assert saved == [np.dtype(np.int32)] * (len(saved) - 1) + [np.dtype(np.float64)] and len(saved) == 6  # 4 + 1 LAS chunks, the text's
    a, b = _files_of(tmp_path / "wide"), _files_of(tmp_path / "ints")
    assert a.keys() == b.keys() and [k for k in a if a[k] != b[k]] == []


def test_partitions_of_one_las_grid_hold_int32_positions(demo_las, tmp_path, monkeypatch):
    """Partition files of inputs on one LAS grid hold their positions as its int32 (12 bytes a
    point, not 24), decoded for each partition's refinement and build: the octree is the float64
    partitions' byte for byte."""
    import importlib

    partition = importlib.import_module("gigapoint.lod.convert.partition")
    _spilling(monkeypatch)
    with monkeypatch.context() as m:
        m.setattr(partition, "_shared_code", lambda raw, n: None)  # as before: float64 partitions
        convert([demo_las], tmp_path / "wide", **OPTS)
    sizes, append = [], partition.append_file
    monkeypatch.setattr(partition, "append_file", lambda path, arrays: (sizes.append((path.name, arrays[0].dtype)), append(path, arrays))[1])
    convert([demo_las], tmp_path / "ints", **OPTS)
    xyz = {dt for name, dt in sizes if name.endswith(".xyz")}
    assert xyz == {np.dtype(np.int32)} and len(sizes) > 10
    a, b = _files_of(tmp_path / "wide"), _files_of(tmp_path / "ints")
    assert a.keys() == b.keys() and [k for k in a if a[k] != b[k]] == []


@pytest.mark.parametrize("varies", [False, True])
def test_held_constant_attributes_are_not_held_a_point_at_a_time(town_and_spot, tmp_path, monkeypatch, varies):
    """An attribute every point holds the same value of (a LAS file's flags, its user_data) is
    held as that value, not a point at a time (7 bytes a point of the LAS flags: 140 MB of a
    20 M-point conversion); each partition's build gets it made again: the octree is the
    out-of-core conversion's byte for byte. ``varies``: a last file whose user_data is 5 (the
    chunks before then hold it a point at a time)."""
    import importlib

    in_memory = importlib.import_module("gigapoint.lod.convert.in_memory")
    if varies:
        las = laspy.read(str(town_and_spot[1]))
        las.user_data = np.full(len(las.points), 5, np.uint8)
        town_and_spot = [*town_and_spot, tmp_path / "five.las"]
        las.write(str(town_and_spot[-1]))
    with monkeypatch.context() as m:
        _spilling(m)
        convert(town_and_spot, tmp_path / "spilled", **OPTS)
    held_keys, constant = set(), {}
    count = in_memory.InMemoryPhases.count

    def counting(self):  # what the read held, at its end
        for c in self._held:
            held_keys.update(k for k, v in c.items() if len(v))
        result = count(self)
        constant.update(self._constants())
        return result

    monkeypatch.setattr(in_memory.InMemoryPhases, "count", counting)
    held = convert(town_and_spot, tmp_path / "held", **OPTS)
    assert held.in_memory
    assert {"synthetic", "withheld", "scan_direction_flag"} <= set(constant)
    assert ("user_data" not in constant and "attr.user_data" in held_keys) if varies else constant["user_data"] == 0
    assert "attr.intensity" in held_keys and "intensity" not in constant and "classification" not in constant  # (they vary)
    assert not {"attr." + a for a in constant} & held_keys
    a, b = _files_of(tmp_path / "spilled"), _files_of(tmp_path / "held")
    assert a.keys() == b.keys() and [k for k in a if a[k] != b[k]] == []
    assert "synthetic" in open_octree(tmp_path / "held").attribute_names


@pytest.mark.parametrize("varies", [False, True])
def test_spilled_constant_attributes_are_saved_as_their_value_alone(town_and_spot, tmp_path, monkeypatch, varies):
    """Out of core, an attribute every point holds one value of is spilled as that value: no
    byte a point in the raw chunks or the partitions' files (a LAS file's flags and user_data:
    ~7 bytes a point), made again for each partition's build: the octree is the in-memory
    conversion's byte for byte. ``varies``: a last file whose user_data is 5: each chunk still
    spills it as its value, the partitions a point at a time."""
    import importlib

    spill, partition = (importlib.import_module(f"gigapoint.lod.convert.{m}") for m in ("spill", "partition"))
    if varies:
        las = laspy.read(str(town_and_spot[1]))
        las.user_data = np.full(len(las.points), 5, np.uint8)
        town_and_spot = [*town_and_spot, tmp_path / "five.las"]
        las.write(str(town_and_spot[-1]))
    assert convert(town_and_spot, tmp_path / "held", **OPTS).in_memory
    raw, parts = {}, {}
    save, append = spill.atomic_npy, partition.append_file

    def saving(path, array, **kw):  # bytes of each spilled array, by name ("attr.intensity.npy")
        raw[path.name.split(".", 1)[1]] = raw.get(path.name.split(".", 1)[1], 0) + array.nbytes
        return save(path, array, **kw)

    def appending(path, arrays):  # bytes of each partition array, by name ("attr.intensity")
        parts[path.name.split(".", 1)[1]] = parts.get(path.name.split(".", 1)[1], 0) + sum(a.nbytes for a in arrays)
        return append(path, arrays)

    monkeypatch.setattr(spill, "atomic_npy", saving)
    monkeypatch.setattr(partition, "append_file", appending)
    _spilling(monkeypatch)
    spilled = convert(town_and_spot, tmp_path / "spilled", **OPTS)
    n = spilled.points
    assert not spilled.in_memory and n == (210_000 if varies else 180_000)
    attrs = open_octree(tmp_path / "spilled").attributes
    constant = {a for a, v in attrs.items() if np.all(np.asarray(v) == np.asarray(v)[0])}
    assert {"synthetic", "withheld", "scan_direction_flag"} <= constant and "intensity" not in constant
    assert ("user_data" not in constant) if varies else ("user_data" in constant)
    for a in constant:  # a value a chunk (5 chunks: 4 of the town, the spot; 6 with the five)
        assert "attr." + a + ".npy" not in raw and raw["const." + a + ".npy"] == (6 if varies else 5) * attrs[a].dtype.itemsize, a
        assert "attr." + a not in parts, a
    assert raw["attr.intensity.npy"] == 2 * n and parts["attr.intensity"] >= 2 * n  # (the refined spot: its points twice)
    assert "attr.user_data.npy" not in raw and (parts["attr.user_data"] >= n if varies else "attr.user_data" not in parts)
    a, b = _files_of(tmp_path / "spilled"), _files_of(tmp_path / "held")
    assert a.keys() == b.keys() and [k for k in a if a[k] != b[k]] == []


@pytest.mark.parametrize("spilled", [False, True])
def test_an_attribute_of_zeros_and_one_minus_zero_is_not_held_as_a_constant(tmp_path, monkeypatch, spilled):
    """One value is one value bit for bit: float zeros with a -0.0 among them were held as the
    constant 0.0 in memory (``==`` finds -0.0 equal), and the octree lost its -0.0."""
    from gigapoint.core.chunk import PointChunk

    rng = np.random.default_rng(1)
    height = np.zeros(20_000)
    height[1234] = -0.0
    chunks = [PointChunk(rng.random((10_000, 3)) * 100, rng.integers(0, 255, (10_000, 4), np.uint8), {"height": h}) for h in np.split(height, 2)]
    if spilled:
        _spilling(monkeypatch)
    res = convert(chunks, tmp_path / "oct", **OPTS)
    assert res.in_memory != spilled
    held = np.asarray(open_octree(tmp_path / "oct").attributes["height"])
    assert len(held) == 20_000 and int(np.signbit(held).sum()) == 1


def test_an_input_beyond_the_memory_limit_is_spilled(demo_las, tmp_path):
    """The choice: the points held (64 bytes each) and one partition's build within what the
    conversion may use; chunks of unknown number are held until they outgrow it (below)."""
    import importlib

    conv = importlib.import_module("gigapoint.lod.convert.converter")
    in_memory = importlib.import_module("gigapoint.lod.convert.in_memory")
    job = conv._Converter([demo_las], tmp_path / "o", "grid", 8 << 30, "gigapoint", 3_000, 25_000, None, conv.NullProgress(), None)
    job.usable = 150_000 * in_memory.HELD_BYTES_PER_POINT + 25_000 * in_memory.BYTES_PER_POINT_BUILD
    assert in_memory.fits_in_memory(job)
    job.usable -= 1
    assert not in_memory.fits_in_memory(job)
    assert in_memory.held_points(job) == 150_000 - 1 // in_memory.HELD_BYTES_PER_POINT - 1
    chunks = conv._Converter(iter([]), tmp_path / "o", "grid", 8 << 30, "gigapoint", 3_000, 25_000, None, conv.NullProgress(), None)
    assert in_memory.fits_in_memory(chunks)


def test_the_plan_comes_from_the_memory_limit_not_from_what_the_process_holds(demo_las, tmp_path):
    """The same limit plans the same partitions in a process holding 200 MB more (it was the
    limit less the process's size: 3.7 M points a partition here, 2.7 M with the 200 MB)."""
    import importlib

    conv = importlib.import_module("gigapoint.lod.convert.converter")

    def plan():
        job = conv._Converter([demo_las], tmp_path / "o", "grid", 1 << 30, "gigapoint", 3_000, None, None, conv.NullProgress(), None)
        return job.partition_points, job.upper_points, job.usable, job.distribute_bytes

    before = plan()
    ballast = np.ones(200 << 20, np.uint8)  # resident: every page written
    assert plan() == before == (3_965_523, 3_965_523, (1 << 30) - (192 << 20), 109_051_904)
    del ballast


@pytest.mark.parametrize("inputs", ["chunks", "a file without a point count"])
def test_an_input_that_outgrows_the_memory_while_it_is_read_is_spilled_from_then_on(town_and_spot, tmp_path, monkeypatch, inputs):
    """Held until the points read exceed what may be held (here 60 000), then every chunk held is
    spilled and the rest is converted out of core: the same octree as a conversion spilled from
    the start. A file conversion killed after that resumes out of core (it reads nothing again)."""
    import importlib

    import gigapoint as gp

    in_memory = importlib.import_module("gigapoint.lod.convert.in_memory")
    read = importlib.import_module("gigapoint.lod.convert.read")

    def source():
        if inputs == "chunks":  # the town's chunks, then the spot's
            return [c for path in town_and_spot for c in gp.io.read_chunks(path, 40_000)]
        return town_and_spot

    if inputs != "chunks":
        monkeypatch.setattr(read, "_point_total", lambda paths: None)  # as for a format whose header has no count
    with monkeypatch.context() as m:
        _spilling(m)
        spilled = convert(source(), tmp_path / "spilled", **OPTS)
    assert not spilled.in_memory
    monkeypatch.setattr(in_memory, "held_points", lambda job: 60_000)
    held = convert(source(), tmp_path / "held", **OPTS)
    assert not held.in_memory and held.points == spilled.points == 180_000
    a, b = _files_of(tmp_path / "spilled"), _files_of(tmp_path / "held")
    assert a.keys() == b.keys() and [k for k in a if a[k] != b[k]] == []
    monkeypatch.setattr(in_memory, "held_points", lambda job: 10**9)
    assert convert(source(), tmp_path / "all", **OPTS).in_memory  # held to the end when it fits
    if inputs == "chunks":
        return
    monkeypatch.setattr(in_memory, "held_points", lambda job: 60_000)
    _interrupt_after(monkeypatch, 2)
    with pytest.raises(KeyboardInterrupt):
        convert(source(), tmp_path / "killed", **OPTS)
    state = json.loads((tmp_path / "killed" / ".partial" / "state.json").read_text())
    assert state["spilled"] and state["phase"] == "build"
    _interrupt_after(monkeypatch, None)
    monkeypatch.setattr(read.ReadPhase, "read", lambda self: pytest.fail("read again"))
    res = convert(source(), tmp_path / "killed", **OPTS)
    assert res.resumed and not res.in_memory
    c = _files_of(tmp_path / "killed")
    assert a.keys() == c.keys() and [k for k in a if a[k] != c[k]] == []


def test_a_conversion_held_in_memory_resumes_by_reading_again_and_builds_only_what_is_missing(town_and_spot, tmp_path, monkeypatch):
    import importlib

    phases = importlib.import_module("gigapoint.lod.convert.phases")
    built, real = [], phases.BuildPhases._build_subtree
    monkeypatch.setattr(phases.BuildPhases, "_build_subtree", lambda self, data, key, *a: built.append(key) or real(self, data, key, *a))
    whole = convert(town_and_spot, tmp_path / "whole", **OPTS)
    every, built[:] = sorted(built), []
    _interrupt_after(monkeypatch, 3)
    with pytest.raises(KeyboardInterrupt):
        convert(town_and_spot, tmp_path / "oct", **OPTS)
    first, built[:] = list(built), []
    assert len(first) == 3 and json.loads((tmp_path / "oct" / ".partial" / "state.json").read_text())["phase"] == "build"
    _interrupt_after(monkeypatch, None)
    res = convert(town_and_spot, tmp_path / "oct", **OPTS)
    assert res.resumed and res.points == whole.points == 180_000
    assert len(every) > 6 and sorted(first + built) == every  # each partition built once over the two runs
    a, b = _files_of(tmp_path / "whole"), _files_of(tmp_path / "oct")
    assert a.keys() == b.keys() and [k for k in a if a[k] != b[k]] == []


def test_killed_conversion_resumes_via_cli(demo_las, tmp_path):
    """SIGKILL in the middle of the build phase, then the same command again: it resumes."""
    out = tmp_path / "oct"
    code = "import sys; from gigapoint.cli import main; sys.exit(main(sys.argv[1:]))"
    # the first run kills itself once it has built one partition
    kill = "import os, signal; from gigapoint.lod.convert import hooks; hooks.after_partition_built = lambda done: os.kill(os.getpid(), signal.SIGKILL); "
    args = ["convert", str(demo_las), "-o", str(out), "--memory-limit", "64M", "--max-leaf", "3000", "--quiet"]
    argv = [sys.executable, "-c", code, *args]
    proc = subprocess.run([sys.executable, "-c", kill + code, *args], capture_output=True, timeout=300, check=False)
    assert proc.returncode == -9, proc.stderr.decode()[-2000:]
    assert not (out / "octree.json").exists()
    state = json.loads((out / ".partial" / "state.json").read_text())
    assert state["phase"] == "build" and len(state["partitions"]) >= 2
    proc = subprocess.run(argv, capture_output=True, timeout=300, check=False)
    assert proc.returncode == 0, proc.stderr.decode()[-2000:]
    assert "(resumed)" in proc.stdout.decode() and "in memory" not in proc.stdout.decode()  # 64M: spilled
    ref = tmp_path / "ref"
    convert([demo_las], ref, max_leaf=3000)  # one partition, in one go
    a, b = open_octree(out), open_octree(ref)
    assert a.n_points == b.n_points == 150_000
    np.testing.assert_array_equal(a.keys, b.keys)
    np.testing.assert_array_equal(a.nodes["count"], b.nodes["count"])
    np.testing.assert_array_equal(np.sort(a.arrays["rgba"]), np.sort(b.arrays["rgba"]))


def test_chunks_never_resume_another_runs_chunks(tmp_path, monkeypatch):
    """An interrupted conversion of chunks (no files: no fingerprint), then other chunks into the
    same folder: a clean start with the new points, never the old run's."""
    import gigapoint as gp

    out = tmp_path / "oct"
    _interrupt_after(monkeypatch, 1)
    with pytest.raises(KeyboardInterrupt):
        convert(gp.io.demo_chunks(200_000, chunk_size=50_000), out, **OPTS)
    assert (out / ".partial" / "state.json").exists()
    _interrupt_after(monkeypatch, None)
    res = convert(gp.io.demo_chunks(100_000, seed=7, chunk_size=50_000), out, **OPTS)
    assert not res.resumed and res.points == 100_000
    xyz = gp.io.demo_arrays(100_000, 7)[0]
    oc = open_octree(out)
    assert int(oc.nodes["count"].sum()) == 100_000
    np.testing.assert_allclose(oc.bounds[0], xyz.min(axis=0), atol=1e-3)  # the new run's points
    np.testing.assert_allclose(oc.bounds[1], xyz.max(axis=0), atol=1e-3)


def test_changed_input_restarts_clean(demo_las, tmp_path, monkeypatch, las_writer):
    src = las_writer(tmp_path / "a.las", 60_000, seed=1)
    out = tmp_path / "oct"
    _interrupt_after(monkeypatch, 1)
    with pytest.raises(KeyboardInterrupt):
        convert([src], out, **OPTS)
    _interrupt_after(monkeypatch, None)
    las_writer(src, 40_000, seed=2)  # the input changed meanwhile: no resume
    res = convert([src], out, **OPTS)
    assert not res.resumed and res.points == 40_000


def test_refuses_to_overwrite(demo_las, tmp_path, capsys):
    out = tmp_path / "oct"
    assert main(["convert", str(demo_las), "-o", str(out), "--quiet", "--max-leaf", "5000"]) == 0
    before = (out / "octree.json").stat().st_mtime_ns
    said = capsys.readouterr().out.strip().splitlines()[-1]
    assert "150,000 points" in said and ", in memory;" in said  # it fits the default limit: no spill
    assert main(["convert", str(demo_las), "-o", str(out), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "--overwrite" in err and err.count("\n") == 1
    assert (out / "octree.json").stat().st_mtime_ns == before
    with pytest.raises(OutputExistsError):
        convert([demo_las], out)
    assert main(["convert", str(demo_las), "-o", str(out), "--quiet", "--overwrite", "--sampler", "poisson"]) == 0
    assert json.loads((out / "octree.json").read_text())["sampler"] == "poisson"
    # a directory that is not ours is never written into, even with --overwrite
    foreign = tmp_path / "photos"
    foreign.mkdir()
    (foreign / "holiday.jpg").write_bytes(b"x")
    assert main(["convert", str(demo_las), "-o", str(foreign), "--quiet", "--overwrite"]) == 1
    assert sorted(p.name for p in foreign.iterdir()) == ["holiday.jpg"]
    # nor is an input replaced by its own conversion (a COPC output is one file: it was, with --overwrite)
    copy = tmp_path / "scan.laz"
    copy.write_bytes(demo_las.read_bytes())
    capsys.readouterr()
    (tmp_path / "sub").mkdir()
    for argv in (["convert", str(copy)], ["convert", str(demo_las), str(tmp_path)]):
        assert main([*argv, "-o", f"{tmp_path}/sub/../scan.laz", "--format", "copc", "--overwrite", "--quiet"]) == 1
        err = capsys.readouterr().err
        assert err == f"error: {tmp_path}/sub/../scan.laz: is one of the inputs; write the COPC file elsewhere (it would replace the file it is read from)\n"
        assert copy.read_bytes() == demo_las.read_bytes() and not list(tmp_path.glob("*.work"))


@pytest.mark.parametrize(
    "args, message",
    [
        (["{missing}"], "no such file"),
        (["{garbage}"], "garbage.las"),
        (["{las}", "--sampler", "random"], "error: --sampler: unknown sampler 'random'; choose grid or poisson"),
        (["{las}", "--memory-limit", "lots"], "--memory-limit"),
        (["{las}", "--memory-limit", "1M"], "--memory-limit"),
        (["{las}", "--memory-limit", "infG"], "--memory-limit: cannot read 'infG'"),  # an internal error (OverflowError) before
        (["{las}", "--format", "ept"], "error: --format: unknown format 'ept'; choose gigapoint or potree or copc"),
        # the library says its keywords (layout: ..., colors='rgb565': ...): the options' words here
        (["{las}", "--layout", "bits"], "error: --layout: unknown layout 'bits'; choose compact or words"),
        (["{las}", "--colors", "rgb332"], "error: --colors: unknown colour format 'rgb332'; choose rgba or rgb565"),
        (["{las}", "--format", "potree", "--colors", "rgb565"], "error: --colors: an option of the gigapoint format, not of potree"),
        (["{octree}"], "converted octree"),
        # each was dropped without a word: Potree's own layout, 32-bit colours
        (["{las}", "--format", "potree", "--layout", "words"], "error: --layout: an option of the gigapoint format, not of potree"),
        (["{las}", "--format", "copc", "--layout", "compact", "--colors", "rgb565"], "--layout and --colors: options of the gigapoint format, not of copc"),
        (["{las}", "--layout", "words", "--colors", "rgb565"], "--colors rgb565: an option of the compact layout; words holds 32-bit colours"),
    ],
)
def test_bad_input_one_line_errors(demo_las, tmp_path, capsys, args, message):
    garbage = tmp_path / "garbage.las"
    garbage.write_bytes(b"LASF" + b"\x00" * 50)
    (tmp_path / "oct").mkdir()
    (tmp_path / "oct" / "octree.json").write_text("{}")
    subst = {"missing": str(tmp_path / "missing.las"), "garbage": str(garbage), "las": str(demo_las), "octree": str(tmp_path / "oct")}
    argv = ["convert", *[a.format(**subst) for a in args], "-o", str(tmp_path / "out"), "--quiet"]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and err.startswith("error: "), err
    assert not (tmp_path / "out" / "octree.json").exists()


def test_options_of_one_format_are_refused_for_another(tmp_path):
    from gigapoint.io import demo_arrays

    xyz, rgba, _ = demo_arrays(2_000)
    cloud = __import__("gigapoint").from_arrays(xyz, rgba)
    with pytest.raises(ConvertError, match=r"^encoding: an option of the potree format, not of gigapoint$"):
        convert(cloud, tmp_path / "g", encoding="BROTLI")
    with pytest.raises(ConvertError, match=r"^colors: an option of the gigapoint format, not of potree$"):
        convert(cloud, tmp_path / "p", format="potree", colors="rgb565")
    assert not list(tmp_path.iterdir())
    assert convert(cloud, tmp_path / "w", layout="words", colors="rgba").points == 2_000  # words holds rgba: consistent


@pytest.mark.parametrize("knob, value", [
    ("partition_points", -5),  # every point its own partition: a conversion of hours for a large input
    ("partition_points", 2.5),  # (taken as a budget of 2.5 points)
    ("partition_points", "abc"),  # a TypeError inside the Job
    ("upper_points", 0),  # (0 was taken as "derive it", -1 as a budget no group fits)
    ("chunk_size", "x"),  # "open: chunk_size ...; the conversion stopped unfinished: run it again once that file is whole"
])  # fmt: skip
def test_a_bad_tuning_knob_is_refused_in_one_line_before_the_output_is_touched(demo_las, tmp_path, knob, value):
    from gigapoint.errors import InputError

    out = tmp_path / "oct"
    with pytest.raises(InputError) as caught:
        convert([demo_las], out, **{knob: value})
    assert str(caught.value) == f"convert: {knob} must be an integer >= 1, got {value!r}"
    assert not out.exists()


@pytest.mark.parametrize("fmt", ["gigapoint", "potree", "copc"])
def test_a_las_file_with_a_negative_scale_converts_like_it_reads(demo_las, tmp_path, fmt):
    """A negative LAS scale (a mirrored axis; the reader takes it) was an internal "source scale
    must be finite and positive" in every conversion, and the finest-scale pick took the most
    negative one."""
    import struct

    import gigapoint as gp

    data = bytearray(demo_las.read_bytes())
    scale = struct.unpack_from("<3d", data, 131)
    struct.pack_into("<3d", data, 131, -scale[0], scale[1], -scale[2])  # (the header's bounds now lie: they keep their sign)
    mirrored = tmp_path / "m.las"
    mirrored.write_bytes(bytes(data))
    plain = gp.open(mirrored)
    out = tmp_path / ("m.copc.laz" if fmt == "copc" else "m_out")
    assert convert([mirrored], out, format=fmt, **OPTS).points == plain.n_points
    cam = gp.Camera.fit_cloud(plain, width=160, height=120)
    a = gp.render(plain, cam, backend="cpu")[..., :3].sum(-1) > 0
    b = gp.render(gp.open(out), cam, backend="cpu", point_budget=10**9, lod_threshold_px=0)[..., :3].sum(-1) > 0
    assert (a & b).sum() / (a | b).sum() >= 0.95
    progressive = gp.open(mirrored, progressive=True)
    assert progressive.wait(timeout=60) and progressive.grid is not None and progressive.grid[1] == abs(scale[0])  # on the file's grid
    c = gp.render(progressive, cam, backend="cpu", point_budget=10**9, lod_threshold_px=0)[..., :3].sum(-1) > 0
    assert (a & c).sum() / (a | c).sum() >= 0.95


def test_autzen_laz_converts_and_renders(tmp_path):
    autzen = SHARED / "autzen_trim.laz"
    if not autzen.exists():
        pytest.skip("shared sample not present")
    out = tmp_path / "autzen"
    assert main(["convert", str(autzen), "-o", str(out), "--quiet", "--format", "gigapoint"]) == 0
    import gigapoint as gp

    oc = gp.open(out)
    assert oc.n_points == 110_000
    png = tmp_path / "a.png"
    assert main(["render", str(out), "-o", str(png), "--width", "320", "--height", "200", "--backend", "cpu"]) == 0
    assert png.stat().st_size > 1000


def test_partition_appends_survive_short_writes(tmp_path, monkeypatch):
    """writev may write less than asked (a signal, a nearly full disk): the rest follows, in order."""
    from gigapoint.atomic import append_file

    real = os.writev
    monkeypatch.setattr(os, "writev", lambda fd, bufs: real(fd, [bytes(memoryview(bufs[0]))[:5]]))  # 5 bytes a call
    arrays = [np.arange(7, dtype=np.float64).reshape(-1, 1)[2:5], np.zeros(0, np.uint32), np.arange(3, dtype=np.uint16)]
    path = tmp_path / "part.bin"
    path.write_bytes(b"head")
    append_file(path, arrays)
    assert path.read_bytes() == b"head" + b"".join(a.tobytes() for a in arrays)


def test_large_partition_appends_go_through_a_map_and_a_full_disk_leaves_the_file_as_it_was(tmp_path, monkeypatch):
    """1 MB or more is appended through a memory map of the file's new part, its space reserved
    first: a full disk is an OSError naming the file (a store into the map would be a SIGBUS),
    and the file keeps its length."""
    import errno

    from gigapoint.atomic import append_file

    rng = np.random.default_rng(3)
    arrays = [rng.random((40_000, 3)), np.zeros(0, np.uint32), rng.integers(0, 2**31, 300_001).astype(np.uint32)]  # 2.2 MB
    path = tmp_path / "part.bin"
    path.write_bytes(b"odd head")  # the map starts inside a page
    append_file(path, arrays)
    append_file(path, arrays[::-1])
    whole = b"".join(a.tobytes() for a in arrays)
    assert path.read_bytes() == b"odd head" + whole + b"".join(a.tobytes() for a in arrays[::-1])

    def full(fd, offset, length):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "posix_fallocate", full)
    size = path.stat().st_size
    with pytest.raises(OSError, match="No space left on device") as err:
        append_file(path, arrays)
    assert err.value.filename == str(path) and path.stat().st_size == size


def test_a_second_conversion_into_the_same_directory_stops_at_once(demo_las, reference, tmp_path, capsys):
    """Two conversions into one OUT would clear or interleave each other's files: the second one
    is refused while the first holds OUT (here: this process holding its lock), and once the
    first is gone a re-run works."""
    out = tmp_path / "oct"
    held = OctreeDir(out).lock()
    try:
        assert main(["convert", str(demo_las), "-o", str(out), "--quiet"]) == 1
        err = capsys.readouterr().err
        assert "another conversion is writing into it" in err and err.count("\n") == 1
        assert sorted(p.name for p in out.iterdir()) == []  # nothing was written or cleared
    finally:
        held.release()
    res = convert([demo_las], out, **OPTS)
    assert res.points == 150_000
    _assert_same(_snapshot(out), reference)


def test_the_lock_goes_with_a_killed_conversion(demo_las, tmp_path):
    """flock is dropped by the kernel when the process dies: a SIGKILLed conversion does not
    leave OUT locked."""
    out = tmp_path / "oct"
    code = (
        "import os, signal; from gigapoint.lod import OctreeDir; "
        f"OctreeDir({str(out)!r}).lock(); os.kill(os.getpid(), signal.SIGKILL)"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, check=False)
    assert proc.returncode == -9
    assert convert([demo_las], out, **OPTS).points == 150_000


def _octree_points(path) -> np.ndarray:
    """Every point of a converted octree as rows (x, y, z in cm, intensity), sorted."""
    oc = open_octree(path)
    parts = [oc.node_points(i) for i in range(len(oc.nodes))]
    xyz = np.round(np.concatenate([p["xyz"] for p in parts]) * 100)
    rows = np.column_stack([xyz, np.concatenate([p["intensity"] for p in parts])])
    return rows[np.lexsort(rows.T[::-1])]


def test_a_cloud_converts_as_the_file_it_was_read_from(autzen_path, tmp_path):
    """gp.convert(cloud, out) was "'PointCloud' object is not iterable": a cloud in memory (read,
    generated, made from arrays) converts through its chunks to the same points as its file."""
    import gigapoint as gp

    path = autzen_path
    cloud = gp.open(path)
    assert sum(len(c.xyz) for c in cloud.chunks(50_000)) == cloud.n_points == 110_000
    np.testing.assert_array_equal(np.concatenate([c.xyz for c in cloud.chunks(50_000)]), cloud.positions())
    for held in (cloud, gp.demo(30_000, colors="palette")):  # colours decoded chunk by chunk, in any format
        np.testing.assert_array_equal(np.concatenate([c.rgba for c in held.chunks(7_000)]), held.rgba)
    words = gp.from_arrays(cloud.positions()[:30_000], intensity=np.arange(30_000))  # the three-word layout
    assert words.layout == "words" and [len(c.xyz) for c in words.chunks(15_000)] == [20_480, 9_520]  # whole batches
    np.testing.assert_array_equal(np.concatenate([c.xyz for c in words.chunks(15_000)]), words.positions())
    np.testing.assert_array_equal(np.concatenate([c.attributes["intensity"] for c in words.chunks()]), words.attributes["intensity"])
    assert not cloud.colors_exact  # gp.open's colors="auto": a palette or RGB565, which the conversion is told of
    with pytest.warns(gp.GigapointWarning, match=r"holds its colours approximated .*convert its files \(.*autzen_trim.laz\) or open them with colors='rgba'"):
        from_cloud = convert(cloud, tmp_path / "from_cloud")
    exact = gp.open(path, colors="rgba")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # colours as the file's: no word
        convert(exact, tmp_path / "exact")
    convert([path], tmp_path / "from_file")
    assert from_cloud.points == 110_000
    np.testing.assert_array_equal(_octree_points(tmp_path / "from_cloud"), _octree_points(tmp_path / "from_file"))
    assert open_octree(tmp_path / "from_cloud").name == cloud.name
    assert open_octree(tmp_path / "from_cloud").meta["crs"] == open_octree(tmp_path / "from_file").meta["crs"] is not None  # its file's
    assert cloud.source_files == (path,) and words.source_files == ()
    progressive = gp.open(path, progressive=True)  # waited for, converted from its leaves, its file's CRS kept
    assert progressive.colors_exact
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        convert(progressive, tmp_path / "from_progressive")
    np.testing.assert_array_equal(_octree_points(tmp_path / "from_progressive"), _octree_points(tmp_path / "from_file"))
    assert open_octree(tmp_path / "from_progressive").meta["crs"] == open_octree(tmp_path / "from_file").meta["crs"] is not None
    progressive.close()
    with pytest.raises(gp.GigapointError, match=r"from_file: is a converted octree \(opened\), not an input point cloud; convert the point files it was made from$"):
        convert(open_octree(tmp_path / "from_file"), tmp_path / "again")


def test_potree_and_copc_outputs_keep_the_inputs_grid_and_a_small_clouds_shape(tmp_path):
    """The Potree writer stored every output on a millimetre grid (a LAS file's 0.1 mm points
    moved up to 0.5 mm) and both it and COPC put float positions without a grid on a millimetre:
    a cloud 0.1 m across (an object scan) became ~100 steps a side, coverage IoU 0.75 against
    the plain cloud. The inputs' grid is kept; a grid-less cloud gets 65 536 steps across it."""
    import laspy

    import gigapoint as gp

    rng = np.random.default_rng(6)
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = np.full(3, 0.0001), np.array([500_000.0, 4_000_000.0, 100.0])
    las = laspy.LasData(header)
    xyz = rng.uniform(-10, 10, (5_000, 3)) + header.offsets  # points below the offset too (negative LAS integers)
    las.x, las.y, las.z = xyz.T
    las.write(tmp_path / "fine.las")
    def rows(a):
        a = np.asarray(a, np.float64)
        return a[np.lexsort(a.T[::-1])]

    want = rows(laspy.read(tmp_path / "fine.las").xyz)
    for fmt, out in (("potree", tmp_path / "fine_potree"), ("copc", tmp_path / "fine.copc.laz")):
        convert([tmp_path / "fine.las"], out, format=fmt, max_leaf=1000)
        oc = open_octree(out)
        got = np.concatenate([oc.node_points(i)["xyz"] for i in range(len(oc.nodes))])
        np.testing.assert_allclose(rows(got), want, atol=1e-6, rtol=0)  # on the 0.1 mm grid: a millimetre's moved them 0.5 mm
    assert json.loads((tmp_path / "fine_potree" / "metadata.json").read_text())["scale"] == [0.0001] * 3

    small = rng.random((20_000, 3)) * [0.1, 0.1, 0.01] + 1e6  # 10 cm across, float positions
    plain = gp.from_arrays(small, rgb=rng.integers(0, 255, (20_000, 3)).astype(np.uint8))
    cam = gp.Camera.fit_cloud(plain, width=160, height=120, view="top")
    covered = (gp.render(plain, cam, size_mode="fixed")[..., :3] != 0).any(axis=-1)
    for fmt, out in (("potree", tmp_path / "small_potree"), ("copc", tmp_path / "small.copc.laz")):
        gp.convert(plain, out, format=fmt)
        drawn = (gp.render(open_octree(out), cam, size_mode="fixed", point_budget=10**6)[..., :3] != 0).any(axis=-1)
        assert (drawn & covered).sum() / (drawn | covered).sum() > 0.95, fmt


def test_convert_checks_its_name_switches_and_source_files(autzen_path, tmp_path):
    """source_files='a.laz' was read letter by letter and a missing file skipped (no CRS, no
    word); name=5 went into octree.json as a number; progress='no' was true. A progressive
    octree whose file went away since it loaded still saves (without the file's CRS)."""
    import shutil

    import gigapoint as gp

    cloud = gp.demo(3_000, colors="rgba")  # (colours as made: no warning of approximated ones)
    convert(cloud, tmp_path / "crs", source_files=str(autzen_path))
    assert open_octree(tmp_path / "crs").meta["crs"] is not None  # one path, not its letters
    for kw, problem in (
        ({"source_files": "gone.laz"}, "gone.laz: no such file"),
        ({"source_files": [5]}, "convert: source_files[0]: 5 is not a path (a str or os.PathLike)"),
        ({"name": 5}, "convert: name must be a string, got 5"),
        ({"progress": "no"}, "convert: progress must be True or False, got 'no'"),
    ):
        with pytest.raises(gp.GigapointError, match=f"^{re.escape(problem)}$"):
            convert(cloud, tmp_path / "x", **kw)
    assert not (tmp_path / "x").exists()
    copy = tmp_path / "copy.laz"
    shutil.copy(autzen_path, copy)
    grown = gp.open(copy, progressive=True)
    grown.wait()
    copy.unlink()
    assert grown.save(tmp_path / "saved").points == 110_000
    grown.close()


def test_a_copc_name_writes_copc_and_a_folder_is_not_named_like_a_point_file(autzen_path, tmp_path, capsys):
    """`gigapoint convert a.laz -o scan.copc.laz` without --format wrote a gigapoint folder named
    scan.copc.laz, and `-o web.las --format potree` a folder named web.las; a progressive save alike.
    `-o scan.csv` (.xyz, .npz, ...) said "a gigapoint octree is a folder", not that convert writes no CSV.
    (`-o scan.laz` without --format writes one plain LAZ file: test_convert_to_file.py.)"""
    import gigapoint as gp

    assert main(["convert", str(autzen_path), "-o", str(tmp_path / "scan.copc.laz"), "--quiet"]) == 0
    assert (tmp_path / "scan.copc.laz").is_file() and open_octree(tmp_path / "scan.copc.laz").meta["points"] == 110_000
    potree_said = "a potree octree is a folder; name it without a point file's suffix, or write --format copc into a .copc.laz file"
    no_such_file = "convert writes .las, .laz or .ply files, an octree folder or a .copc.laz file, not "  # (was "a gigapoint octree is a folder")
    for name, fmt, said in (("web.las", ["--format", "potree"], potree_said), *((f"scan.{s}", [], no_such_file + "." + s.lower()) for s in ("xyz", "CSV", "txt", "npz", "npy", "e57"))):
        assert main(["convert", str(autzen_path), "-o", str(tmp_path / name), "--quiet", *fmt]) == 1
        assert capsys.readouterr().err.strip() == f"error: {tmp_path / name}: {said}"
        assert not (tmp_path / name).exists()
    grown = gp.open(autzen_path, progressive=True)
    assert grown.save(tmp_path / "grown.copc.laz").format == "copc"
    grown.close()


def test_numpy_integer_tuning_knobs_are_taken_as_ints(demo_las, tmp_path):
    """A knob given as np.int64 (a value computed with numpy) passed the check but reached the
    conversion's saved state as it was: 'Object of type int64 is not JSON serializable'."""
    result = convert([demo_las], tmp_path / "oct", partition_points=np.int64(50_000), chunk_size=np.int64(20_000))
    assert result.points == len(laspy.read(str(demo_las)).points)


def test_no_input_at_all_is_said_in_one_line(tmp_path):
    """An empty tuple of inputs was a TypeError from os.fspath (the COPC check took it for one path); a list said it."""
    from gigapoint.errors import InputError

    for nothing in ((), []):
        with pytest.raises(InputError, match=r"^convert: no input given$"):
            convert(nothing, tmp_path / "oct")
    assert not (tmp_path / "oct").exists()
