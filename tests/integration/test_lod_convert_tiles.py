"""A folder of many small tiles: the per-tile costs of the read phase (a state save, an fsync,
per tile was 1 529 of them for 1 500 tiles), and a resume part-way through such a folder."""

from __future__ import annotations

import importlib
import json

import pytest

from gigapoint.errors import GigapointWarning, InputError
from gigapoint.lod import OctreeDir, convert
from gigapoint.lod.convert import state as state_mod

OPTS = {"max_leaf": 500, "partition_points": 2_000, "chunk_size": 1_000}  # tiles of 150 points: joined 6 a chunk
N_TILES = 40


@pytest.fixture(scope="module")
def tiles(tmp_path_factory, las_writer):
    d = tmp_path_factory.mktemp("tiles")
    for i in range(N_TILES):
        las_writer(d / f"t{i:02d}.las", 150, seed=i)
    return d


@pytest.fixture
def out_of_core(monkeypatch):
    monkeypatch.setattr(importlib.import_module("gigapoint.lod.convert.in_memory"), "fits_in_memory", lambda job: False)


def _files(out):
    return {p.relative_to(out): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}


def test_the_read_phase_saves_its_state_once_a_second_not_once_a_tile(tiles, tmp_path, monkeypatch, out_of_core):
    saved = []
    real = OctreeDir.write_state
    monkeypatch.setattr(OctreeDir, "write_state", lambda d, st: (saved.append(st["phase"]), real(d, st)))
    monkeypatch.setattr(state_mod, "SAVE_EVERY_S", 3600.0, raising=False)  # only the preview's writes save it
    convert(tiles, tmp_path / "oct", **OPTS)
    reads = saved.count("read")
    assert 1 <= reads <= 10, saved  # the preview's writes (every 2 s) and the read's end; was one a tile: 41


def test_a_run_stopped_part_way_through_many_tiles_resumes_to_the_same_output(tiles, tmp_path, monkeypatch, out_of_core):
    whole = convert(tiles, tmp_path / "whole", **OPTS)
    read = importlib.import_module("gigapoint.lod.convert.read")
    real = read._read_chunks

    def stops(path, size):
        if path.name == "t25.las":
            raise KeyboardInterrupt("test")
        return real(path, size)

    out = tmp_path / "oct"
    monkeypatch.setattr(read, "_read_chunks", stops)
    with pytest.raises(KeyboardInterrupt):
        convert(tiles, out, **OPTS)
    assert OctreeDir(out).read_state()["chunks"] == 4  # a stop saves the state as it stands: tiles 0-23 joined 6 a chunk
    monkeypatch.setattr(read, "_read_chunks", real)
    res = convert(tiles, out, **OPTS)
    assert (res.resumed, res.points) == (True, whole.points) and whole.points == N_TILES * 150
    assert _files(out) == _files(tmp_path / "whole")


def test_a_run_killed_between_two_saves_reads_the_tiles_after_the_last_again(tiles, tmp_path, monkeypatch, out_of_core):
    """Killed (no save on the way out): the state saved last names fewer tiles than were spilled."""
    whole = convert(tiles, tmp_path / "whole", **OPTS)
    read = importlib.import_module("gigapoint.lod.convert.read")
    real, saved = read._read_chunks, []

    def killed(path, size):
        if path.name == "t25.las":
            raise KeyboardInterrupt("test")
        return real(path, size)

    real_write = OctreeDir.write_state
    monkeypatch.setattr(OctreeDir, "write_state", lambda d, st: (saved.append(json.dumps(st)), real_write(d, st)))
    monkeypatch.setattr(read, "_read_chunks", killed)
    out = tmp_path / "oct"
    with pytest.raises(KeyboardInterrupt):
        convert(tiles, out, **OPTS)
    # as a kill leaves it: the last save before the stop (the first chunk's preview's, often), not the stop's own
    last = [s for s in saved[:-1] if json.loads(s).get("chunks")][-1]
    (out / ".partial" / "state.json").write_text(last)
    monkeypatch.setattr(read, "_read_chunks", real)
    res = convert(tiles, out, **OPTS)
    assert (res.resumed, res.points) == (True, whole.points)
    assert _files(out) == _files(tmp_path / "whole")


def test_small_tiles_are_spilled_joined_up_to_a_chunk(tiles, tmp_path, monkeypatch, out_of_core):
    read = importlib.import_module("gigapoint.lod.convert.read")
    real, sizes = read.spill_chunk, []
    monkeypatch.setattr(read, "spill_chunk", lambda raw, i, chunk, code=None: (sizes.append(len(chunk)), real(raw, i, chunk, code))[1])
    res = convert(tiles, tmp_path / "oct", **OPTS)
    assert sizes == [900] * 6 + [600] and res.points == N_TILES * 150  # was 40 chunks of 150


def _copy(tiles, d):
    d.mkdir()
    for p in sorted(tiles.iterdir()):
        (d / p.name).write_bytes(p.read_bytes())
    return d


def test_an_empty_tile_among_joined_ones_is_skipped(tiles, tmp_path, las_writer, out_of_core):
    d = _copy(tiles, tmp_path / "in")
    las_writer(d / "t10b.las", 0)  # (sorted between t10 and t11)
    with pytest.warns(GigapointWarning, match=f"{d / 't10b.las'}: holds no points, skipped"):
        res = convert(d, tmp_path / "oct", **OPTS)
    whole = convert(tiles, tmp_path / "whole", **OPTS)
    assert res.points == whole.points == N_TILES * 150
    assert _files(tmp_path / "oct") == _files(tmp_path / "whole")


def test_a_damaged_tile_among_joined_ones_is_named(tiles, tmp_path, out_of_core):
    d = _copy(tiles, tmp_path / "in")
    cut = d / "t10.las"
    cut.write_bytes(cut.read_bytes()[:-1000])
    with pytest.raises(InputError) as err:
        convert(d, tmp_path / "oct", **OPTS)
    assert str(err.value).startswith(f"{cut}: truncated LAS file: the header claims 150 points") and "\n" not in str(err.value)
    st = OctreeDir(tmp_path / "oct").read_state()  # tiles 0-5 joined, then 6-9, taken before the stop
    assert (st["chunks"], st["points"], st["stopped_by"].split(":")[0]) == (2, 10 * 150, str(cut))


def test_dask_batches_small_tiles_into_few_tasks_with_the_same_output(tiles, thread_client, tmp_path, monkeypatch):
    """A Dask task a tile cost ~39 ms: read tasks are batched up to a chunk's points, and so the
    count and distribute tasks that follow them."""
    from gigapoint.lod.convert.distributed import DaskPhases

    runs = []
    real = DaskPhases._run
    monkeypatch.setattr(DaskPhases, "_run", lambda self, kind, calls, *a, **k: (runs.append((kind, len(calls))), real(self, kind, calls, *a, **k))[1])
    d = _copy(tiles, tmp_path / "in")
    cut = d / "t10.las"
    cut.write_bytes(cut.read_bytes()[:-1000])
    res = convert(tiles, tmp_path / "dask", client=thread_client, **OPTS)
    with pytest.raises(InputError) as err:  # a damaged tile in a batch: named, in one line
        convert(d, tmp_path / "bad", client=thread_client, **OPTS)
    assert str(err.value).startswith(f"{cut}: truncated LAS file: the header claims 150 points") and "\n" not in str(err.value)
    convert(tiles, tmp_path / "one", **OPTS)
    assert res.points == N_TILES * 150
    assert [r for r in runs if r[0] in ("read", "count", "distribute")] == [("read", 7), ("count", 7), ("distribute", 7)]  # was 40 each
    assert _files(tmp_path / "dask") == _files(tmp_path / "one")
