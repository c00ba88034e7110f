"""Each LAS/LAZ file's header is read once per operation (io headers_once): counts, scan angles,
the LAS grid and the points each read it again before, 3-6 times a file (a seek or a request
each, for a folder of 2 000 tiles or files on a network)."""

from __future__ import annotations

import builtins
from collections import Counter

import laspy
import pytest
from test_io_las import write_las

import gigapoint as gp
from gigapoint.errors import InputError
from gigapoint.io import _base, las

N_TILES = 4


@pytest.fixture
def tiles(tmp_path):
    """A folder of LAS and LAZ tiles, of point formats 3 and 6 (the scan angle under both names)."""
    folder = tmp_path / "tiles"
    folder.mkdir()
    for i in range(N_TILES):
        write_las(folder / f"t{i}.{'laz' if i % 2 else 'las'}", n=3000, point_format=3 if i < 2 else 6, version="1.2" if i < 2 else "1.4", seed=i)
    return folder


@pytest.fixture
def reads(monkeypatch, tiles):
    """Counters of the tiles' opens ({file name: count}): ``header`` by gigapoint's header
    parser (io/las.py's ``open``), ``head`` by the format sniff (io/_base.py's read_head), ``laspy``
    by laspy for the points."""
    counts = {"header": Counter(), "head": Counter(), "laspy": Counter()}

    def counting(kind, real):
        def opener(file, *args, **kwargs):
            name = str(file)
            if name.startswith(str(tiles)):
                counts[kind][name.rsplit("/", 1)[-1]] += 1
            return real(file, *args, **kwargs)

        return opener

    monkeypatch.setattr(las, "open", counting("header", builtins.open), raising=False)
    monkeypatch.setattr(_base, "open", counting("head", builtins.open), raising=False)
    monkeypatch.setattr(laspy, "open", counting("laspy", laspy.open))
    return counts


#: one open a tile
ONCE = {f"t{i}.{'laz' if i % 2 else 'las'}": 1 for i in range(N_TILES)}


def test_open_reads_each_header_once(tiles, reads):
    with pytest.warns(gp.GigapointWarning, match="scanner_channel not in every file"):
        cloud = gp.open(tiles)
    assert cloud.n_points == N_TILES * 3000
    assert reads["header"] == ONCE and reads["head"] == ONCE
    assert reads["laspy"] == ONCE  # the points, once


def test_progressive_open_reads_each_header_once(tiles, reads, loaded):
    with pytest.warns(gp.GigapointWarning, match="scanner_channel not in every file"):  # (said by the loader's thread)
        octree = loaded(tiles)
    assert octree.n_points == N_TILES * 3000
    assert reads["header"] == ONCE and reads["head"] == ONCE  # file_sources, then the loader thread


@pytest.mark.parametrize("spilled", [False, True], ids=["in-memory", "out-of-core"])
def test_convert_reads_each_header_once(tiles, reads, tmp_path, monkeypatch, spilled):
    import importlib

    if spilled:  # (12 000 points fit any memory limit)
        monkeypatch.setattr(importlib.import_module("gigapoint.lod.convert.in_memory"), "fits_in_memory", lambda job: False)
    with pytest.warns(gp.GigapointWarning, match="scanner_channel not in every file"):  # (point formats 3 and 6)
        result = gp.convert(tiles, tmp_path / "out")
    assert result.in_memory is not spilled
    assert reads["header"] == ONCE and reads["head"] == ONCE  # (out of core: read in prefetch's thread)


def test_info_reads_each_header_once(tiles, reads, capsys):
    from gigapoint.cli import main

    assert main(["info", str(tiles)]) == 0
    assert capsys.readouterr().out.count("points:      3,000") == N_TILES
    assert reads["header"] == ONCE and reads["head"] == ONCE


def test_file_info_of_a_las_file_naming_a_crs_reads_its_header_once(autzen_path, monkeypatch):
    """file_info read the header for the file's info, then again for its CRS's units (first_crs):
    ``gigapoint info`` of a folder of tiles paid it per file."""
    from gigapoint.io import file_info

    parses, real = [], las._read_las_header
    monkeypatch.setattr(las, "_read_las_header", lambda *a, **k: parses.append(a) or real(*a, **k))
    info = file_info(autzen_path)
    assert info["crs"] and info["units"]["horizontal"]["name"] == "foot"
    assert len(parses) == 1


def test_warn_mixed_crs_asks_each_files_format_once(tmp_path, autzen_path, monkeypatch):
    """warn_mixed_crs asked each file's reader for its LAS/PLY check, then file_crs asked again;
    a format naming no CRS (an NPY file) is still not said to lack one."""
    import numpy as np

    from gigapoint.io import crs

    np.save(tmp_path / "points.npy", np.zeros((10, 3)))
    write_las(tmp_path / "plain.las", n=100)
    files = [autzen_path, tmp_path / "plain.las", tmp_path / "points.npy"]
    asked, real = [], crs.reader_for
    monkeypatch.setattr(crs, "reader_for", lambda path: asked.append(path) or real(path))
    with pytest.warns(gp.GigapointWarning) as said:
        crs.warn_mixed_crs(files)
    assert len(said) == 1 and str(said[0].message).startswith("plain.las names no CRS, where autzen_trim.laz names ")
    assert asked == files


def test_render_reads_each_header_once(tiles, reads, tmp_path):
    """``gigapoint render`` (open_sized: the headers, then the cloud or a progressive octree)."""
    from gigapoint.cli import main

    assert main(["render", str(tiles), "-o", str(tmp_path / "a.png"), "--width", "64", "--height", "48"]) == 0
    assert reads["header"] == ONCE and reads["head"] == ONCE


def test_kept_header_of_a_cut_file_still_refused_by_a_plain_read(tmp_path):
    """A header kept from a salvaging read (a file cut off: its points up to the cut) is refused
    by a plain read as without headers_once, with the same message."""
    from gigapoint.io._base import headers_once

    path = tmp_path / "cut.las"
    write_las(path, n=1000)
    path.write_bytes(path.read_bytes()[:-100])
    with pytest.raises(InputError) as plain:
        las.read_las_header(path)
    with headers_once():
        assert "truncated LAS file" in las.read_las_header(path, salvage=True).truncated
        with pytest.raises(InputError) as kept:
            las.read_las_header(path)
    assert str(kept.value) == str(plain.value)


def test_a_file_cut_in_its_evlrs_has_its_header_read_once(tmp_path, monkeypatch):
    """Its points are whole (read with a warning), so a plain read takes the header kept: it was
    parsed again at every step, as a salvaging read's header of a file cut in its points is."""
    import os

    from test_io_errors import _las14_with_evlrs

    path, _ = _las14_with_evlrs(tmp_path, ".las", 3000)
    os.truncate(path, os.path.getsize(path) - 50)
    parses, real = [], las._read_las_header
    monkeypatch.setattr(las, "_read_las_header", lambda *a, **k: parses.append(a) or real(*a, **k))
    with pytest.warns(gp.GigapointWarning, match="extended VLRs are cut"):
        cloud = gp.open(path)
    assert cloud.n_points == 3000 and len(parses) == 1
