"""A folder of many small tiles: the per-tile costs of the read phase (a state save, an fsync,
per tile was 1 529 of them for 1 500 tiles), and a resume part-way through such a folder."""

from __future__ import annotations

import importlib

import pytest

from gigapoint.lod import OctreeDir, convert
from gigapoint.lod.convert import state as state_mod

OPTS = {"max_leaf": 500, "partition_points": 2_000}
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
    assert 1 <= reads <= 3, saved  # was one a tile: 40


def test_a_run_stopped_part_way_through_many_tiles_resumes_to_the_same_output(tiles, tmp_path, monkeypatch, out_of_core):
    whole = convert(tiles, tmp_path / "whole", **OPTS)
    read = importlib.import_module("gigapoint.lod.convert.read")
    real = read._read_chunks
    monkeypatch.setattr(state_mod, "SAVE_EVERY_S", 3600.0, raising=False)  # the saved state lags the read tiles

    def stops(path, size):
        if path.name == "t25.las":
            raise KeyboardInterrupt("test")
        return real(path, size)

    out = tmp_path / "oct"
    monkeypatch.setattr(read, "_read_chunks", stops)
    with pytest.raises(KeyboardInterrupt):
        convert(tiles, out, **OPTS)
    st = OctreeDir(out).read_state()
    assert st["phase"] == "read" and 1 <= st["chunks"] < 25  # tiles read after the last save: read again
    monkeypatch.setattr(read, "_read_chunks", real)
    res = convert(tiles, out, **OPTS)
    assert (res.resumed, res.points) == (True, whole.points) and whole.points == N_TILES * 150
    assert _files(out) == _files(tmp_path / "whole")
