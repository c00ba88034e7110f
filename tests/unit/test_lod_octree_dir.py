"""OctreeDir: the one owner of an octree folder's kind, completeness, state, lock and clearing."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.core import PointChunk, PointCloud
from gigapoint.errors import GigapointWarning, InputError
from gigapoint.lod import ConvertError, OctreeDir, OutputExistsError, convert, is_octree_dir
from gigapoint.lod.convert import hooks
from gigapoint.lod.preview import ConversionPreview


def _chunks(n=20_000, seed=0):
    rng = np.random.default_rng(seed)
    xyz = np.round(rng.random((n, 3)) * 100, 3)
    return [PointChunk(xyz[s : s + 5_000]) for s in range(0, n, 5_000)]


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    """A finished gigapoint octree, a finished Potree one and an unfinished conversion."""
    base = tmp_path_factory.mktemp("dirs")
    convert(_chunks(), base / "gp", max_leaf=1_000)
    convert(_chunks(), base / "pt", max_leaf=1_000, format="potree")

    def stop(done):
        raise KeyboardInterrupt("test interrupt")

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(hooks, "after_partition_built", stop)
        with pytest.raises(KeyboardInterrupt):
            convert(_chunks(), base / "half", max_leaf=1_000, partition_points=5_000)
    return base


def test_kind_completeness_and_what_opens_as_an_octree(folders, tmp_path):
    gp_dir, pt_dir, half = OctreeDir(folders / "gp"), OctreeDir(folders / "pt"), OctreeDir(folders / "half")
    assert (gp_dir.kind, pt_dir.kind, half.kind) == ("gigapoint", "potree", "unfinished")
    assert gp_dir.complete and pt_dir.complete and not half.complete
    assert gp_dir.is_octree and pt_dir.is_octree and half.is_octree
    assert gp_dir.meta.is_file() and pt_dir.potree_meta.is_file() and pt_dir.potree_hierarchy.is_file() and pt_dir.potree_octree.is_file()
    assert half.state_file.is_file() and half.preview.is_file() and half.built.is_dir()
    assert not gp_dir.partial.exists() and not half.meta.exists()
    (tmp_path / "empty").mkdir()
    (tmp_path / "file.las").write_bytes(b"x")
    for p in (tmp_path / "empty", tmp_path / "file.las", tmp_path / "missing"):
        assert OctreeDir(p).kind is None and not OctreeDir(p).is_octree and not is_octree_dir(p)
    lone = tmp_path / "lone"  # Potree metadata without its hierarchy: not openable as an octree
    lone.mkdir()
    (lone / pt_dir.potree_meta.name).write_text("{}")
    assert OctreeDir(lone).kind == "potree" and not OctreeDir(lone).is_octree


def test_state_and_status_of_an_unfinished_conversion(folders, tmp_path):
    half = OctreeDir(folders / "half")
    state = half.read_state()
    assert state["phase"] == "build" and state["points"] == 20_000
    s = half.status()
    assert s == {
        "phase": "build",
        "points": 20_000,
        "total": None,
        "preview_points": state["preview"]["points"],
        "attributes": [],
        "running": False,
    }
    d = OctreeDir(tmp_path / "x")
    d.partial.mkdir(parents=True)
    assert d.read_state() is None and d.status() == {}
    d.state_file.write_text("{torn")
    assert d.read_state() is None
    d.write_state({"phase": "read", "points": 5})
    assert json.loads(d.state_file.read_text()) == {"phase": "read", "points": 5}
    assert d.awaiting_preview and not half.awaiting_preview


def test_lock_and_running(tmp_path):
    d = OctreeDir(tmp_path / "out")
    assert d.running is None  # no folder yet
    with d.lock():
        assert d.path.is_dir() and d.running is True
        with pytest.raises(ConvertError, match="another conversion is writing into it"):
            OctreeDir(tmp_path / "out").lock()
    assert d.running is False
    (tmp_path / "f").write_text("x")
    with pytest.raises(OutputExistsError, match="not a directory"):
        OctreeDir(tmp_path / "f").lock()



@pytest.mark.parametrize("name", ["sub", "sub.copc.laz"])
def test_an_output_under_a_file_is_refused_without_promising_a_resume(tmp_path, name):
    """-o notes/sub where notes is a file said "Not a directory; the conversion to notes/sub
    stopped unfinished (run it again once the cause is gone: it resumes)": nothing had begun."""
    (tmp_path / "notes").write_text("keep")
    out = tmp_path / "notes" / name
    with pytest.raises(ConvertError) as e:
        convert([PointChunk(np.zeros((10, 3)))], out)
    assert str(e.value) == f"{out.parent / name}{'.work' if name.endswith('.laz') else ''}: Not a directory"
    assert (tmp_path / "notes").read_text() == "keep"


def test_prepare_output_resumes_clears_or_refuses(tmp_path):
    d = OctreeDir(tmp_path / "out")
    assert d.prepare_output({"v": 1}, overwrite=False, state=None) is None and d.partial.is_dir()
    d.write_state({"fingerprint": {"v": 1}, "phase": "count"})
    assert d.prepare_output({"v": 1}, overwrite=False, state=d.read_state()) == {"fingerprint": {"v": 1}, "phase": "count"}
    (d.raw).mkdir()
    assert d.prepare_output({"v": 2}, overwrite=False, state=d.read_state()) is None  # other inputs or options: a clean start
    assert not d.raw.exists() and d.partial.is_dir()
    d.meta.write_text("{}")
    with pytest.raises(OutputExistsError, match=r"overwrite=True"):  # a Python caller's keyword (the CLI says --overwrite)
        d.prepare_output({"v": 2}, overwrite=False, state=d.read_state())
    d.write_state({"fingerprint": {"v": 2}, "phase": "count"})  # a replacement stopped part-way: resumed with overwrite only
    assert d.prepare_output({"v": 2}, overwrite=True, state=d.read_state()) == {"fingerprint": {"v": 2}, "phase": "count"}
    assert d.prepare_output({"v": 3}, overwrite=True, state=d.read_state()) is None and d.meta.read_text() == "{}"  # replaced once the new one is complete
    assert d.read_state() is None and d.partial.is_dir()
    foreign = OctreeDir(tmp_path / "photos")
    foreign.path.mkdir()
    (foreign.path / "holiday.jpg").write_bytes(b"x")
    with pytest.raises(OutputExistsError, match="not a gigapoint/Potree output"):
        foreign.prepare_output(None, overwrite=True, state=None)
    assert [p.name for p in foreign.path.iterdir()] == ["holiday.jpg"]


def test_a_stopped_conversion_of_another_gigapoint_says_a_rerun_starts_over(tmp_path, monkeypatch):
    """The fingerprint holds the code version, so after an upgrade a rerun starts over: the folder
    said "run `gigapoint convert` again to resume it" all the same. A state saved before states
    named their version was an older gigapoint's; chunks' work resumes under none."""
    from gigapoint.lod import code
    from gigapoint.lod.octree_dir import NO_RESUME_HINT, RESUME_HINT

    monkeypatch.setattr(code, "_CODE_VERSION", "0.2.0+bbbbbbbbbbbb")
    d = OctreeDir(tmp_path / "out")
    d.partial.mkdir(parents=True)
    d.write_state({"fingerprint": "sha256:1", "code_version": "0.2.0+bbbbbbbbbbbb", "phase": "build"})
    assert d.resume_hint == RESUME_HINT and d.other_work("sha256:1", d.read_state()) is None
    assert d.other_work("sha256:2", d.read_state()) == "with other inputs or options"
    d.write_state({"fingerprint": "sha256:1", "code_version": "0.1.0+aaaaaaaaaaaa", "phase": "build"})
    assert d.resume_hint == "it was started by gigapoint 0.1.0+aaaaaaaaaaaa, not this gigapoint 0.2.0+bbbbbbbbbbbb: running `gigapoint convert` again starts it over"
    assert d.other_work("sha256:2", d.read_state()) == "by gigapoint 0.1.0+aaaaaaaaaaaa (this is 0.2.0+bbbbbbbbbbbb)"
    d.write_state({"fingerprint": "sha256:1", "phase": "build"})  # saved by a gigapoint that named no version
    assert d.resume_hint.startswith("it was started by an older gigapoint, not this gigapoint 0.2.0+bbbbbbbbbbbb:")
    d.write_state({"fingerprint": None, "code_version": "0.1.0+aaaaaaaaaaaa", "phase": "build"})  # chunks from Python
    assert d.resume_hint == NO_RESUME_HINT and d.other_work("sha256:2", d.read_state()) is None


def test_clear_removes_what_a_conversion_writes_and_nothing_else(tmp_path):
    d = OctreeDir(tmp_path / "out")
    d.raw.mkdir(parents=True)
    ours = [d.meta, d.potree_meta, d.potree_hierarchy, d.potree_octree, d.array("nodes"), d.array("keys"), d.array("low"),
            d.array("attr.intensity"), d.array_in_progress("color"), d.path / ".octree.json.0123abcd.tmp.json"]  # fmt: skip
    theirs = [d.path / "README.md", d.path / "notes.npy", d.path / "sub" / "low.npy"]
    (d.path / "sub").mkdir()
    for p in ours + theirs:
        p.write_bytes(b"x")
    d.clear()
    assert sorted(p.relative_to(d.path).as_posix() for p in d.path.rglob("*")) == ["README.md", "notes.npy", "sub", "sub/low.npy"]


def test_an_unfinished_conversion_opens_as_a_conversion_preview(folders):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GigapointWarning)
        preview = gp.open(folders / "half")
    assert type(preview) is ConversionPreview and isinstance(preview, PointCloud)
    assert preview.octree_dir == OctreeDir(folders / "half") and preview.name == "half"
    assert not hasattr(preview, "preview_of")
    assert repr(preview).startswith("PointCloud('half',")


@pytest.mark.parametrize(
    "change, problem",
    [
        ({"cube_edge": 0}, "cube_edge must be a positive number: 0"),  # drew nothing, without a word
        ({"cube_min": [float("nan")] * 3}, r"cube_min is not three finite numbers: \[nan, nan, nan\]"),
        ({"scale": 0}, "scale is not three finite numbers: 0"),
        ({"scale": [0.0, 0.01, 0.01]}, r"scale must be positive: \[0.0, 0.01, 0.01\]"),
        ({"spacing": -1}, "spacing must be a number >= 0: -1"),
        ({"points": 2.5}, "points is not a count: 2.5"),
        ({"bounds": [[0, 0, 0], [1, 1, 1]]}, "bounds is not "),  # an internal TypeError before
        ({"bounds": {"min": [0, 0, 9], "max": [1, 1, 1]}}, r"bounds.min \[0.0, 0.0, 9.0\] exceeds bounds.max"),
        ({"cube_edge": "DELETE"}, "no 'cube_edge'"),
    ],
)
def test_octree_metadata_that_cannot_place_points_is_refused_at_open(folders, tmp_path, change, problem):
    import shutil

    path = tmp_path / "gp"
    shutil.copytree(folders / "gp", path)
    meta = json.loads((path / "octree.json").read_text())
    assert gp.open(path).n_points == 20_000  # the copy opens as it is
    meta.update(change)
    meta = {k: v for k, v in meta.items() if v != "DELETE"}
    (path / "octree.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match=f"octree.json: invalid metadata \\({problem}") as e:
        gp.open(path)
    assert "\n" not in str(e.value)


def test_many_small_files_convert_in_time_linear_in_the_files(tmp_path, monkeypatch):
    """2 000 tiles of 50 points took 14 s to convert, 4 000 took 39 s: the state held every
    tile's path, size and time and was written again with each tile's chunk, the count phase made
    a bincount of 8^7 cells a chunk, and deleting the spills listed the folder once a chunk
    (benchmarks/bench_many_tiles.py). The state holds the fingerprint's digest; the counts and
    the spills' files are what they were."""
    from gigapoint.lod.convert import partition, spill
    from gigapoint.lod.octree_dir import OctreeDir as Dir

    tiles = tmp_path / "tiles"
    tiles.mkdir()
    rng = np.random.default_rng(7)
    xyz = rng.uniform(0, 100, (300 * 40, 3))
    for k in range(300):
        np.save(tiles / f"t{k:04d}.npy", xyz[k * 40 : (k + 1) * 40])
    sizes = []
    write = Dir.write_state
    monkeypatch.setattr(Dir, "write_state", lambda self, state: (sizes.append(len(json.dumps(state))), write(self, state))[1])
    monkeypatch.setattr(partition.CellCounts, "TOGETHER", 1000)  # several flushes, and chunks counted together
    for limit, name in ((None, "held"), ("64M", "spilled")):
        sizes.clear()
        result = convert([tiles], tmp_path / name, memory_limit=limit)
        assert result.points == len(xyz) and result.in_memory == (limit is None)
        assert sizes and max(sizes) < 3000  # (it grew to ~40 kB with 300 tiles' fingerprint; saved once a tile then, at most once a second now)
        octree = gp.open(tmp_path / name)
        cam = gp.Camera.fit(octree.bounds, view="top", width=120, height=120)
        img = gp.render(octree, cam, backend="cpu", point_budget=10**9, lod_threshold_px=0, size_mode="fixed")
        plain = gp.render(gp.from_arrays(xyz), cam, backend="cpu", size_mode="fixed")
        a, b = img[..., :3].sum(-1) > 0, plain[..., :3].sum(-1) > 0
        assert (a & b).sum() / (a | b).sum() > 0.95
    counts = partition.CellCounts()
    cells = [rng.integers(0, 8**partition.COUNT_LEVEL, n) for n in (5, 999, 0, 3000, 7)]
    for c in cells:
        counts.add(c)
    np.testing.assert_array_equal(counts.total(), np.bincount(np.concatenate(cells), minlength=8**partition.COUNT_LEVEL))
    raw = tmp_path / "raw"
    raw.mkdir()
    for i in range(5):
        spill.save_raw_chunk(raw, i, np.zeros((2, 3)), np.zeros(2, np.uint32), {"a.b": np.arange(2.0)})  # (varies: a point at a time)
    assert sorted(f.name for f in spill.raw_chunk_files(raw, range(1, 3))) == sorted(
        f"c{i:06d}.{k}.npy" for i in (1, 2) for k in ("xyz", "rgba", "attr.a.b")
    )
    assert len(spill.raw_chunk_files(raw, 4)) == 3 and len(spill.raw_chunk_files(raw)) == 15
