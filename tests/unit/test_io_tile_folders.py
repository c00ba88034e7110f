"""A folder of LAS/LAZ tiles as a city delivers it: hundreds of tiles, and files beside them."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import GigapointWarning

laspy = pytest.importorskip("laspy")


def write_tiles(folder: Path, n: int, points: int = 50, suffix: str = ".laz", cols: int = 10) -> list[Path]:
    """``n`` tiles of ``points`` points on a grid of 100 m tiles, one scale and offset."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    out = []
    for i in range(n):
        r, c = divmod(i, cols)
        header = laspy.LasHeader(point_format=3, version="1.2")
        header.scales, header.offsets = [0.01] * 3, [500000.0, 4000000.0, 0.0]
        las = laspy.LasData(header)
        las.x = 500000 + c * 100 + rng.random(points) * 100
        las.y = 4000000 + r * 100 + rng.random(points) * 100
        las.z = 100 + rng.random(points) * 10
        out.append(folder / f"tile_{r:02d}_{c:02d}{suffix}")
        las.write(out[-1])
    return out


def test_a_tile_folder_skips_its_readme_lax_and_hidden_files_and_reads_point_rows(tmp_path):
    """A README.txt beside the tiles stopped every command ("line 1: not numeric point data"),
    and so did macOS's hidden ._tile.laz / .x.csv; .lax index files were and are skipped."""
    tiles = write_tiles(tmp_path, 6)
    (tmp_path / "README.txt").write_text("City of X aerial LiDAR 2024, EPSG:32610\ncontact: gis@x.org\n")
    (tmp_path / "grid.asc").write_text("ncols 2\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\n1 2\n3 4\n")
    for t in tiles:
        t.with_suffix(".lax").write_bytes(b"LASX" + bytes(60))
    (tmp_path / "._tile_00_00.laz").write_bytes(b"\x00\x05\x16\x07" + bytes(200))  # macOS AppleDouble
    (tmp_path / ".notes.csv").write_text("x,y,z\n")
    (tmp_path / "extra.csv").write_text("x,y,z\n500000,4000000,100\n500001,4000001,101\n")  # point rows: read
    (tmp_path / "sub").mkdir()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cloud = gp.open(tmp_path)
    assert cloud.n_points == 6 * 50 + 2
    said = sorted(str(w.message) for w in caught if issubclass(w.category, GigapointWarning) and "skipped" in str(w.message))
    assert said == [
        f"{tmp_path / 'README.txt'}: no point rows at its beginning (a readme?), skipped",
        f"{tmp_path / 'grid.asc'}: no point rows at its beginning (a readme?), skipped",
    ]


def test_small_laz_tiles_share_one_decoding_process(tmp_path, monkeypatch):
    """Each LAZ file started its own decoding process (io/laz_process.py), 50-120 ms a tile:
    a folder of 1 500 tiles of 2 000 points took 206 s to render, one file of the same points
    17 s. Small files now go to the one child all of them share; the points are the same."""
    import subprocess

    from gigapoint.io import laz_process

    if not laz_process.available():
        pytest.skip("no LAZ child process here")
    write_tiles(tmp_path, 20)
    started = []
    popen = subprocess.Popen

    def counting(*args, **kwargs):
        started.append(args[0])
        return popen(*args, **kwargs)

    monkeypatch.setattr(laz_process.subprocess, "Popen", counting)
    cloud = gp.open(tmp_path)
    assert cloud.n_points == 20 * 50
    assert len(started) <= 1  # (0 where an earlier test started the shared one)
    monkeypatch.setenv(laz_process.ENV_SWITCH, "0")  # decoded in this process: the same points
    here = gp.open(tmp_path)
    assert np.array_equal(cloud.positions(), here.positions()) and np.array_equal(cloud.rgba, here.rgba)


def test_info_of_a_folder_of_many_tiles_is_one_block_and_names_the_damaged_ones(cli, tmp_path):
    """``gigapoint info`` of 1 500 tiles printed 21 000 lines, a block a tile; now one block
    (--each: a block a file), what the tiles do not share said, a damaged tile named."""
    tiles = write_tiles(tmp_path, 14)
    las = laspy.read(tiles[13])
    las.header.scales = [0.001] * 3  # one tile of another grid
    las.write(tiles[13])
    tiles[12].write_bytes(tiles[12].read_bytes()[:600])  # cut off
    rc, out, err = cli("info", tmp_path)
    assert rc == 1 and out.count("points:") == 1
    lines = out.splitlines()
    assert lines[0] == f"{tmp_path} (13 files)" and "  points:      650" in lines
    lo = np.min([laspy.open(t).header.mins for t in tiles if t != tiles[12]], axis=0)  # (3 decimals: the scales differ)
    assert lines[3] == f"  bounds min:  {lo[0]:.3f}, {lo[1]:.3f}, {lo[2]:.3f} (header)"
    assert "  scales:      0.01, 0.01, 0.01 (12 files); 0.001, 0.001, 0.001 (1 file)" in lines
    said = err.strip().splitlines()
    assert len(said) == 2 and said[0].startswith(f"error: {tiles[12]}: ") and said[1] == "error: info: 1 of 14 files could not be read (said above)"
    rc, out, err = cli("info", "--each", tmp_path)
    assert rc == 1 and out.count("points:") == 13


def test_an_empty_tile_is_skipped_by_a_progressive_load_as_by_open(tmp_path, loaded):
    """An empty tile (0 points) among many: gp.open and convert skip it with a warning, but a
    progressive load (``view``, ``render --progressive``) stopped on it ("LAZ file holds no points")."""
    write_tiles(tmp_path, 5)
    header = laspy.LasHeader(point_format=3, version="1.2")
    laspy.LasData(header).write(tmp_path / "tile_00_05.laz")
    for progressive in (False, True):
        with pytest.warns(GigapointWarning) as caught:
            cloud = loaded(tmp_path) if progressive else gp.open(tmp_path)
        assert cloud.n_points == 250
        assert f"{tmp_path / 'tile_00_05.laz'}: holds no points, skipped" in [str(w.message) for w in caught]


def test_info_of_a_folder_tells_offsets_apart_as_one_files_info_prints_them(cli, tmp_path):
    """Offsets that differ in their 11th digit (PDAL's offset 'auto': each tile its own) were
    counted as one offset in the folder's block, printed to 10 digits."""
    tiles = write_tiles(tmp_path, 12)
    las = laspy.read(tiles[11])
    las.header.offsets = [500000.00001, 4000000.0, 0.0]
    las.write(tiles[11])
    rc, out, _ = cli("info", tmp_path)
    assert rc == 0 and "  offsets:     500000, 4000000, 0 (11 files); 500000.00001, 4000000, 0 (1 file)" in out.splitlines()
