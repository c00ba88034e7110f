"""``gigapoint tile`` / ``gp.tile`` (lod/convert/tiles.py): point files split into square LAS/LAZ
tiles on a grid anchored at 0, each holding exactly its points (and its buffer's, flagged), as
``convert -o x.laz`` writes them; nothing left behind by a run that fails."""

from __future__ import annotations

import errno
import importlib
import os
import shutil

import laspy
import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import GigapointWarning, InputError
from gigapoint.io.las import read_las_header, wkt_of
from gigapoint.io.las_fields import las_grid
from gigapoint.io.text import TextReader
from gigapoint.lod.convert.tiles import TileAxis, tile_groups, tile_index, tile_name

FIELDS = ("X", "Y", "Z", "intensity", "classification", "gps_time", "red", "green", "blue")


def _strips(tmp_path):
    """Two LAS files (centimetre grid, offset -10, 0, 0) of points over x -10..20, y 0..20, none
    in [10, 20) x [10, 20); every point's Z (its number) tells it apart; a's colours 16-bit, b's
    8-bit values. Returns their paths and their points joined (a's first)."""
    rng = np.random.default_rng(3)
    X = rng.integers(0, 3000, 4000)  # x = X / 100 - 10
    Y = rng.integers(0, 2000, 4000)
    X[:8] = [0, 999, 1000, 1999, 2000, 2999, 1000, 999]  # on the tiles' edges: x -10, -0.01, 0, 9.99, 10, 19.99
    Y[:8] = [0, 999, 1000, 1999, 0, 999, 0, 1999]
    keep = ~((X >= 2000) & (Y >= 1000))
    X, Y = X[keep], Y[keep]
    n = len(X)
    points = {"X": X, "Y": Y, "Z": np.arange(n), "intensity": rng.integers(0, 65536, n), "classification": rng.integers(0, 32, n), "gps_time": rng.uniform(0, 1e6, n)}
    points.update(zip(("red", "green", "blue"), rng.integers(0, 256, (3, n))))
    paths = []
    for name, rows, factor in (("a.las", slice(0, 2500), 257), ("b.las", slice(2500, None), 1)):
        header = laspy.LasHeader(point_format=3, version="1.2")
        header.scales, header.offsets = [0.01] * 3, [-10.0, 0.0, 0.0]
        las = laspy.LasData(header)
        for field, values in points.items():
            las[field] = values[rows] * (factor if field in ("red", "green", "blue") else 1)
        las.write(str(tmp_path / name))
        paths.append(tmp_path / name)
    points.update({c: np.concatenate([points[c][:2500] * 257, points[c][2500:]]) for c in ("red", "green", "blue")})  # as stored
    points["x"], points["y"] = X / 100 - 10, Y / 100
    return paths, points


def _expected(points, xmin, ymin, size, buffer=0.0):
    """The rows of ``points`` in the tile of corner (xmin, ymin), in file order, and which of them are its buffer's."""
    x, y = points["x"], points["y"]
    own = (x >= xmin) & (x < xmin + size) & (y >= ymin) & (y < ymin + size)
    near = (x >= xmin - buffer) & (x <= xmin + size + buffer) & (y >= ymin - buffer) & (y <= ymin + size + buffer)
    rows = np.flatnonzero(own | near) if buffer else np.flatnonzero(own)
    return rows, ~own[rows]


def test_two_files_split_into_exactly_their_tiles_with_every_points_attributes(tmp_path):
    paths, points = _strips(tmp_path)
    out = tmp_path / "tiles"
    res = gp.tile(paths, out, 10, chunk_size=700)  # chunks of 700: a tile's points in several
    corners = [(-10, 0), (-10, 10), (0, 0), (0, 10), (10, 0)]  # (10, 10) holds no point: not written
    assert [p.name for p in res.tiles] == [f"tiles_{x}_{y}.laz" for x, y in corners]
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in res.tiles)  # nothing else (no work folder)
    for path, (xmin, ymin), count in zip(res.tiles, corners, res.points_per_tile):
        written, (rows, _) = laspy.read(str(path)), _expected(points, xmin, ymin, 10)
        assert len(written.points) == count == len(rows) > 0
        for field in FIELDS:  # every point of the tile, in the files' order, its attributes and colours as stored
            assert np.array_equal(np.asarray(written[field]), points[field][rows]), (path.name, field)
        assert "overlap" not in written.point_format.dimension_names or not np.any(written.overlap)
        assert list(written.header.scales) == [0.01] * 3 and list(written.header.offsets) == [-10.0, 0.0, 0.0]
    assert (res.points, res.buffer_points, res.skipped) == (len(points["X"]), 0, 0) == (sum(res.points_per_tile), 0, 0)


def test_a_buffer_adds_the_points_near_each_tile_flagged_in_the_overlap_bit(tmp_path):
    paths, points = _strips(tmp_path)
    res = gp.tile(paths, tmp_path / "tiles", 10, buffer=1.0, format="las", name="strip")
    corners = [(-10, 0), (-10, 10), (0, 0), (0, 10), (10, 0)]  # (10, 10): buffer points alone, not written
    assert [p.name for p in res.tiles] == [f"strip_{x}_{y}.las" for x, y in corners]
    buffered = 0
    for path, (xmin, ymin) in zip(res.tiles, corners):
        written = laspy.read(str(path))
        rows, flagged = _expected(points, xmin, ymin, 10, buffer=1.0)
        assert np.array_equal(np.asarray(written.Z), points["Z"][rows]), path.name
        assert np.array_equal(np.asarray(written.overlap, bool), flagged) and 0 < flagged.sum() < len(rows), path.name
        assert written.header.point_format.id == 7 and not np.any(written.withheld)  # (withheld: readers would drop them)
        buffered += int(flagged.sum())
    assert res.buffer_points == buffered == sum(res.points_per_tile) - len(points["X"])


def test_autzen_in_500_ft_tiles_through_the_cli(cli, autzen_path, tmp_path):
    src = laspy.read(str(autzen_path))
    keys, counts = np.unique(np.column_stack([np.floor(src.x / 500), np.floor(src.y / 500)]).astype(int), axis=0, return_counts=True)
    out = tmp_path / "tiles"
    rc, stdout, err = cli("tile", autzen_path, "--size", "500", "-o", out, "-q")
    assert rc == 0, err
    assert counts.sum() == 110_000 and len(counts) == 6
    assert (counts.min(), np.median(counts), counts.max()) == (2_998, 7_433, 49_550)
    assert stdout.startswith(f"{out}: 6 tiles of 500 x 500 (laz), 110,000 points; points per tile: min 2,998, median 7,433, max 49,550; ")
    names = [f"autzen_trim_{x * 500}_{y * 500}.laz" for x, y in keys]
    assert sorted(p.name for p in out.iterdir()) == names
    total, ints = 0, []
    for name, (i, j), count in zip(names, keys, counts):
        written = laspy.read(str(out / name))
        total += len(written.points)
        assert len(written.points) == count
        assert i * 500 <= written.x.min() and written.x.max() < (i + 1) * 500 and j * 500 <= written.y.min() and written.y.max() < (j + 1) * 500
        assert i * 500 <= written.header.mins[0] and written.header.maxs[0] < (i + 1) * 500, name
        assert j * 500 <= written.header.mins[1] and written.header.maxs[1] < (j + 1) * 500, name
        hdr = read_las_header(out / name)
        assert wkt_of(hdr.vlrs + hdr.evlrs) == wkt_of(read_las_header(autzen_path).vlrs + read_las_header(autzen_path).evlrs) is not None
        ints.append(np.column_stack([written.X, written.Y, written.Z, written.gps_time.view(np.int64)]))
    assert total == 110_000
    tiled, source = np.concatenate(ints), np.column_stack([src.X, src.Y, src.Z, src.gps_time.view(np.int64)])
    assert np.array_equal(tiled[np.lexsort(tiled.T)], source[np.lexsort(source.T)])  # every point once, its integers as stored


def test_tiles_are_indexed_and_named_by_their_lower_left_corner():
    assert tile_index(np.array([-10.0, -0.01, 0.0, 9.99, 10.0]), 10.0).tolist() == [-1, -1, 0, 0, 1]
    # 0.7 / 0.1 is 6.999999999999999, floored to 6; 7 * 0.1 is 0.7000000000000001, above 0.7: tile 6 holds it, as the products say
    values = np.array([0.3, 0.7, 1e6 + 0.1, -0.3])
    assert tile_index(values, 0.1).tolist() == [2, 6, 10_000_000, -3]
    assert all(i * 0.1 <= v < (i + 1) * 0.1 for i, v in zip(tile_index(values, 0.1).tolist(), values))
    assert tile_name("s", 1, -1, 2.5, "laz") == "s_2.5_-2.5.laz"
    assert tile_name("s", 636, 849, 1000.0, "las") == "s_636000_849000.las"


@pytest.mark.parametrize(
    ("low", "high", "n"),
    [(0, 3, 1000), (-2, 2, 5000), (-3_000, 3_000, 2000), (-(2**40), 2**40, 500), (-(2**62), 2**62, 300), (5, 6, 0)],
    ids=["few-tiles", "negative", "sparse", "wide", "beyond-one-key", "empty"],
)
def test_a_chunks_tiles_are_grouped_as_numpys_unique_over_rows_groups_them(low, high, n):
    # the table (few keys), the sort of one key a point (sparse) and rows (beyond 2^62 keys) give one answer
    rng = np.random.default_rng(7)
    i, j = rng.integers(low, high, n, dtype=np.int64), rng.integers(low, high, n, dtype=np.int64)
    keys, where, counts = tile_groups(i, j)
    want_keys, want_where, want_counts = np.unique(np.column_stack([i, j]), axis=0, return_inverse=True, return_counts=True)
    assert np.array_equal(keys, want_keys.reshape(-1, 2)) and keys.dtype == np.int64
    assert np.array_equal(where, want_where.ravel()) and where.shape == (n,)
    assert np.array_equal(counts, want_counts)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"size": 0}, "tile: size=0: a tile's edge is a number above 0, in the files' units"),
        ({"size": float("nan")}, "tile: size=nan: a tile's edge is a number above 0, in the files' units"),
        ({"size": -5.0}, "tile: size=-5.0: a tile's edge is a number above 0, in the files' units"),
        ({"size": "500"}, "tile: size='500': a tile's edge is a number above 0, in the files' units"),
        ({"size": 500, "buffer": -1}, "tile: buffer=-1: a buffer is a number from 0 to the tile's edge (500), in the files' units"),
        ({"size": 500, "buffer": float("nan")}, "tile: buffer=nan: a buffer is a number from 0 to the tile's edge (500), in the files' units"),
        ({"size": 500, "buffer": 501}, "tile: buffer=501: a buffer is a number from 0 to the tile's edge (500), in the files' units"),
        ({"size": 500, "format": "ply"}, "tile: format='ply': tiles are written as laz or las"),
        ({"size": 0.01}, "tile: size=0.01: 117,747 x 56,271 tiles over the extent of {}, above 1,000,000; take larger tiles"),
        # the count was said in 306 digits
        ({"size": 1e-300}, "tile: size=1e-300: 1.18e+303 x 5.63e+302 tiles over the extent of {}, above 1,000,000; take larger tiles"),
        # a subnormal size overflowed the division: an internal OverflowError
        ({"size": 5e-324}, "tile: size=5e-324: inf x inf tiles over the extent of {}, above 1,000,000; take larger tiles"),
        # an internal OverflowError as points were placed (and tile -1 would be named by its 301-digit corner)
        ({"size": 1e300}, "tile: size=1e+300: a tile's edge must be at most 2e+12, the span points can have"),
    ],
)
def test_bad_values_are_refused_in_one_line_before_a_point_is_read(autzen_path, tmp_path, monkeypatch, options, message):
    def no_read(*args):
        raise AssertionError("read")

    monkeypatch.setattr(importlib.import_module("gigapoint.lod.convert.to_file"), "read_chunks", no_read)
    with pytest.raises(InputError) as info:
        gp.tile(autzen_path, tmp_path / "tiles", **options)
    assert str(info.value) == message.format(autzen_path)
    assert list(tmp_path.iterdir()) == []


def test_the_cli_names_the_option_of_a_bad_value(cli, autzen_path, tmp_path):
    rc, _, err = cli("tile", autzen_path, "--size", "nan", "-o", tmp_path / "tiles")
    assert (rc, err.strip()) == (1, "error: tile: --size nan: a tile's edge is a number above 0, in the files' units")
    rc, _, err = cli("tile", autzen_path, "--size", "500", "--buffer", "-2", "-o", tmp_path / "tiles")
    assert (rc, err.strip()) == (1, "error: tile: --buffer -2: a buffer is a number from 0 to the tile's edge (500), in the files' units")
    assert list(tmp_path.iterdir()) == []


def test_a_size_in_the_wrong_unit_on_points_without_header_bounds_is_refused_before_a_tile_is_written(cli, tmp_path):
    """A .npy (or text) file has no header bounds to check the tiles' count against before reading:
    --size 1e-9 wrote a tile a point (minutes on a large file) until a million tiles stopped it."""
    points = tmp_path / "pts.npy"
    xy = np.linspace(0.0, 0.5, 2000)
    np.save(points, np.column_stack([xy, xy / 2, np.zeros(2000)]))
    rc, out, err = cli("tile", points, "--size", "1e-9", "-o", tmp_path / "tiles")
    assert (rc, out) == (1, "")
    assert err == f"error: tile: --size 1e-09: 500,000,000 x 250,000,000 tiles over the extent of {points}, above 1,000,000; take larger tiles\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pts.npy"]  # no tiles' folder, nor its hidden work folder


def test_points_without_header_bounds_have_the_tiles_count_checked_once_a_chunk_and_land_in_their_tiles(tmp_path, monkeypatch):
    """A .npy's tile count is checked in the pass that makes its grid, a chunk at a time, and not
    again as the same points are tiled (was: every chunk checked twice, its bounds taken twice);
    the file is read twice, its points not kept (a read of a memory-mapped NPY costs less than
    keeping them: tiles.py's _grid_of_points). Each tile holds the points numpy places in it."""
    tiles = importlib.import_module("gigapoint.lod.convert.tiles")
    to_file = importlib.import_module("gigapoint.lod.convert.to_file")
    rng = np.random.default_rng(11)
    n, chunk_size, size, buffer = 20_000, 3_000, 7.0, 1.5
    # whole centimetres and 4 mm: no point within a grid step (a millimetre) of an edge or a buffer's, where floats and the stored grid could differ
    x, y = rng.integers(-500, 7000, n) / 100 + 0.004, rng.integers(-300, 2100, n) / 100 + 0.004
    np.save(tmp_path / "pts.npy", np.column_stack([x, y, rng.normal(0, 1, n)]))
    checks, reads = [], []
    check_tile_count, read_chunks = tiles._check_tile_count, to_file.read_chunks

    def counted_check(*args):
        checks.append(args)
        return check_tile_count(*args)

    def counted_read(path, chunk_size):
        reads.append(path)
        yield from read_chunks(path, chunk_size)

    monkeypatch.setattr(tiles, "_check_tile_count", counted_check)
    monkeypatch.setattr(to_file, "read_chunks", counted_read)
    res = gp.tile(tmp_path / "pts.npy", tmp_path / "tiles", size, buffer=buffer, chunk_size=chunk_size)
    assert len(checks) == 7  # the grid pass's 7 chunks (was 14: the tiling pass checked them again)
    assert reads == [tmp_path / "pts.npy"] * 2
    keys = np.unique(np.column_stack([np.floor(x / size), np.floor(y / size)]).astype(int), axis=0)
    assert [p.name for p in res.tiles] == [tile_name("pts", i, j, size, "laz") for i, j in keys] and len(keys) == 44
    wanted = [len(_expected({"x": x, "y": y}, i * size, j * size, size, buffer)[0]) for i, j in keys]
    assert res.points_per_tile == wanted and res.points == n and res.buffer_points == sum(wanted) - n
    assert [len(laspy.read(str(p)).points) for p in res.tiles] == wanted


def test_las_points_beyond_their_headers_bounds_are_checked_as_they_are_tiled(tmp_path, points_las_writer):
    """A LAS file whose header tells no bounds (all 0) has the tiles' count checked on its points as
    they are read: a size in the wrong unit is refused at the first chunk, before a tile is written."""
    xyz = np.column_stack([np.linspace(0, 0.5, 2000), np.linspace(0, 0.25, 2000), np.zeros(2000)])
    path = points_las_writer(tmp_path / "pts.las", xyz, np.zeros((2000, 3), np.uint16), scale=0.01)  # (centimetres: the first chunk's 0.12 x 0.06)
    data = bytearray(path.read_bytes())
    data[179 : 179 + 48] = bytes(48)  # (LAS 1.2's max x, min x, max y, min y, max z, min z)
    path.write_bytes(bytes(data))
    assert laspy.read(str(path)).header.maxs.tolist() == [0.0] * 3
    with pytest.raises(InputError) as refusal:
        gp.tile(path, tmp_path / "tiles", 1e-9, chunk_size=500)
    assert str(refusal.value) == f"tile: size=1e-09: 120,000,000 x 60,000,000 tiles over the extent of {path}, above 1,000,000; take larger tiles"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pts.las"]  # no tiles' folder, nor its hidden work folder


def test_a_folder_holding_las_files_is_refused_and_overwrite_leaves_the_users_files(autzen_path, tmp_path):
    out = tmp_path / "tiles"
    out.mkdir()
    (out / "mine.laz").write_bytes(b"the user's file")
    (out / "autzen_trim_0_0.laz").write_bytes(b"an earlier run's tile")
    (out / "autzen_trim_636000_849000.laz").write_bytes(b"a tile of this run's name")
    with pytest.raises(InputError, match=r"tiles: holds 3 LAS/LAZ files already \(autzen_trim_0_0\.laz, autzen_trim_636000_849000\.laz, mine\.laz\); pass overwrite=True"):
        gp.tile(autzen_path, out, 500)
    assert len(list(out.iterdir())) == 3 and (out / "autzen_trim_636000_849000.laz").read_bytes() == b"a tile of this run's name"
    with pytest.warns(GigapointWarning, match=r"tiles: tiles named as this run's but not written by it are left as they were \(1 tile: autzen_trim_0_0\.laz\)"):
        res = gp.tile(autzen_path, out, 500, overwrite=True)
    assert len(res.tiles) == 6 and len(laspy.read(str(out / "autzen_trim_636000_849000.laz")).points) == res.points_per_tile[1]
    assert (out / "mine.laz").read_bytes() == b"the user's file" and (out / "autzen_trim_0_0.laz").read_bytes() == b"an earlier run's tile"
    assert len(list(out.iterdir())) == 8  # the 6 tiles (one replaced) and the two others, no work folder


def _reads_fail_after_5_chunks(monkeypatch) -> None:
    """Every input's read fails after 5 chunks ('PATH: truncated'), as a disk giving out."""
    to_file = importlib.import_module("gigapoint.lod.convert.to_file")
    read_chunks = to_file.read_chunks

    def failing(path, chunk_size):
        for k, chunk in enumerate(read_chunks(path, chunk_size)):
            if k == 5:
                raise InputError(f"{path}: truncated")
            yield chunk

    monkeypatch.setattr(to_file, "read_chunks", failing)


def test_a_read_failing_midway_leaves_no_tile(autzen_path, tmp_path, monkeypatch):
    _reads_fail_after_5_chunks(monkeypatch)
    out = tmp_path / "tiles"
    with pytest.raises(InputError, match=r"autzen_trim\.laz: truncated$"):
        gp.tile(autzen_path, out, 500, chunk_size=10_000)
    assert list(tmp_path.iterdir()) == []  # the folder it made, gone with its work
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    with pytest.raises(InputError, match=r"truncated$"):
        gp.tile(autzen_path, out, 500, chunk_size=10_000)
    assert [p.name for p in out.iterdir()] == ["notes.txt"]


def test_the_folders_missing_on_the_tiles_way_are_made_once_every_tile_is_written(cli, autzen_path, tmp_path, monkeypatch):
    """`tile -o new/sub/tiles` was refused ('the folder new/sub does not exist') where convert -o
    made an octree's or a point file's folders: they are made now, as the tiles move in. A run
    failing midway leaves none of them; a path through a file is one line and writes nothing."""
    res = gp.tile(autzen_path, tmp_path / "new" / "sub" / "tiles", 500)
    out = tmp_path / "new" / "sub" / "tiles"
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in res.tiles) and len(res.tiles) == 6
    assert sum(len(laspy.read(str(p)).points) for p in res.tiles) == res.points == 110_000
    rc, stdout, err = cli("tile", autzen_path, "--size", "500", "-o", tmp_path / "cli" / "tiles", "-q")
    assert rc == 0 and stdout.startswith(f"{tmp_path / 'cli' / 'tiles'}: 6 tiles of 500 x 500 (laz), 110,000 points;"), err
    assert sorted(p.name for p in (tmp_path / "cli" / "tiles").iterdir()) == sorted(p.name for p in res.tiles)
    afile = tmp_path / "afile"
    afile.write_text("mine")
    rc, stdout, err = cli("tile", autzen_path, "--size", "500", "-o", afile / "tiles", "-q")
    assert (rc, stdout, err) == (1, "", f"error: {afile / 'tiles'}: {afile} is a file, not a folder\n")
    assert afile.read_text() == "mine" and sorted(p.name for p in tmp_path.iterdir()) == ["afile", "cli", "new"]
    _reads_fail_after_5_chunks(monkeypatch)
    with pytest.raises(InputError, match=r"truncated$"):
        gp.tile(autzen_path, tmp_path / "later" / "tiles", 500, chunk_size=10_000)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile", "cli", "new"]  # no folder made, no work folder left


def test_a_write_failing_at_the_third_tile_leaves_none_of_them(autzen_path, tmp_path, monkeypatch):
    tiles = importlib.import_module("gigapoint.lod.convert.tiles")
    write_points, written = tiles.write_points, []

    def failing(path, *args, **kwargs):
        if len(written) == 2:
            raise InputError(f"{path.name}: not written (No space left on device)")
        written.append(path.name)
        return write_points(path, *args, **kwargs)

    monkeypatch.setattr(tiles, "write_points", failing)
    with pytest.raises(InputError, match=r"^autzen_trim_636500_848500\.laz: not written"):
        gp.tile(autzen_path, tmp_path / "tiles", 500)
    assert written == ["autzen_trim_636000_848500.laz", "autzen_trim_636000_849000.laz"]
    assert list(tmp_path.iterdir()) == []  # the two whole tiles never appeared without the rest


def test_one_point_in_one_tile_is_said_in_the_singular(cli, tmp_path):
    """The summary line of a one-point file: '1 tile ..., 1 point', not '1 tiles ..., 1 points'."""
    header = laspy.LasHeader(point_format=3, version="1.2")
    las = laspy.LasData(header)
    las.x, las.y, las.z = [1.0], [2.0], [3.0]
    las.write(str(tmp_path / "one.las"))
    out = tmp_path / "tiles"
    rc, stdout, err = cli("tile", tmp_path / "one.las", "--size", "500", "-o", out, "-q")
    assert rc == 0, err
    assert stdout.startswith(f"{out}: 1 tile of 500 x 500 (laz), 1 point; points per tile: min 1, median 1, max 1; ")


def _line_of_points(path, scale, offset, X):
    """A LAS file of points at x = X * scale + offset (integers ``X`` on its grid), y = 0, z = their number."""
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = [scale] * 3, [offset, 0.0, 0.0]
    las = laspy.LasData(header)
    las.X, las.Y, las.Z = X, np.zeros_like(X), np.arange(len(X))
    las.write(str(path))
    return path


@pytest.mark.parametrize(("scale", "offset"), [(0.01, 0.0), (0.001, 0.0), (0.01, -10.0), (0.001, 635000.0)])
def test_a_point_on_a_decimal_edge_is_placed_in_integers_on_its_las_grid(scale, offset):
    # x = 0.7 as a LAS grid stores it (70 * 0.01): floats put it in tile 0.6 (0.7 / 0.1 = 6.999999999999999)
    X = np.arange(-3000, 3000)
    axis = TileAxis(0.1, 0.0, scale, offset)
    steps, start = round(0.1 / scale), round(offset / scale)
    assert np.array_equal(axis.index(X * scale + offset), (X + start) // steps)  # each tile from the grid line on its edge
    buffered = TileAxis(0.1, 0.03, scale, offset)  # tile 4 (0.4..0.5) and its buffer: 0.37..0.53, both edges in
    at = np.array([0.37, 0.37 - scale, 0.53, 0.53 + scale])
    assert buffered.near(at + offset, np.full(4, 4 + start // steps)).tolist() == [True, False, True, False]


def test_edges_between_grid_lines_place_points_by_their_stored_positions():
    """A size of no whole number of grid steps: a point is in the tile whose square holds its
    position as stored (was: an edge counted as on the grid line nearest it, so x = 0.12 was in
    tile 0.123..0.246, below its edge)."""
    X = np.array([11, 12, 13, 24, 25])
    assert TileAxis(0.123, 0.0, 0.01, 0.0).index(X * 0.01).tolist() == [0, 0, 1, 1, 2]  # 0.12 is 0.003 below 0.123
    assert TileAxis(0.125, 0.0, 0.01, 0.0).index(X * 0.01).tolist() == [0, 0, 1, 1, 2]  # 0.125: between 0.12 and 0.13
    assert TileAxis(0.125, 0.0, 0.01, 0.005).index(X * 0.01 + 0.005).tolist() == [0, 1, 1, 1, 2]  # offset off the grid from 0: 0.125 on the edge
    # positions off the grid (reprojected): 0.1249, above the edge 0.123, is stored as 0.12, below it
    assert TileAxis(0.123, 0.0, 0.01, 0.0).index(np.array([0.1249, 0.1251])).tolist() == [0, 1]


def test_tiles_of_a_decimal_size_hold_the_points_on_their_edges_and_buffers(tmp_path):
    X = np.arange(0, 100)  # x = 0.00 .. 0.99, centimetres: tile i (0.1 i .. 0.1 (i + 1)) holds X 10 i .. 10 i + 9
    src = _line_of_points(tmp_path / "line.las", 0.01, 0.0, X)
    res = gp.tile(src, tmp_path / "tiles", 0.1, buffer=0.03, format="las")
    assert [p.name for p in res.tiles] == ["line_0_0.las"] + [f"line_0.{i}_0.las" for i in range(1, 10)]
    for i, path in enumerate(res.tiles):
        written = laspy.read(str(path))
        want = X[(X >= 10 * i - 3) & (X <= 10 * i + 13)]  # its own and those within 0.03, edges included
        assert np.array_equal(np.asarray(written.X), want), path.name
        assert np.array_equal(np.asarray(written.overlap, bool), (want < 10 * i) | (want >= 10 * i + 10)), path.name
    assert res.points == 100 and res.buffer_points == 9 * (3 + 4)  # each inner edge: the 3 points below it, the 4 from it to 0.03 above


def test_a_tile_far_larger_than_a_point_on_a_fine_grid_holds_it():
    """A size of 1e10 on the nanometre grid a one-point float file gets: 1e19 grid steps a tile,
    past int64, raised an OverflowError (an 'internal error' from the command); placed as floats,
    the point is in tile 0, as any size above it places it."""
    for size in (1e10, 2e12):
        assert TileAxis(size, 0.0, 1e-9, 5.0).index(np.array([5.0, 5.5, -1.0])).tolist() == [0, 0, -1]


def test_tiles_of_points_without_a_las_grid_share_one_grid(tmp_path):
    """Float positions (a .npy file) are stored on one grid for the run, made from all of them:
    tiles with a grid each (from their own bounds) could not be merged back without moving points."""
    rng = np.random.default_rng(5)
    xyz = np.concatenate([rng.uniform(0, 3, (500, 3)), rng.uniform([10, 0, 0], [10.5, 0.5, 0.5], (500, 3))])
    np.save(tmp_path / "pts.npy", xyz)
    res = gp.tile(tmp_path / "pts.npy", tmp_path / "tiles", 10)
    headers = [laspy.read(str(p)).header for p in res.tiles]
    scale, offset = las_grid(xyz.min(axis=0), xyz.max(axis=0))
    assert [p.name for p in res.tiles] == ["pts_0_0.laz", "pts_10_0.laz"]
    for header in headers:
        assert np.array_equal(header.scales, scale) and np.array_equal(header.offsets, offset)
    tiled = np.concatenate([np.column_stack([w.x, w.y, w.z]) for w in (laspy.read(str(p)) for p in res.tiles)])
    assert np.all(np.abs(tiled - xyz) <= scale / 2)  # (the points in file order: tile 0's, then tile 10's)


@pytest.mark.parametrize("killed_at", [1, 3])
def test_a_run_killed_as_its_tiles_move_into_place_leaves_no_folder_that_looks_whole(autzen_path, tmp_path, monkeypatch, killed_at):
    """A kill runs no clean-up: the folder a run makes is there with every tile or not at all (was:
    the tiles moved before the kill, under the output's name, as if they were all)."""
    moves = []
    real_replace, real_rename = os.replace, os.rename

    class Killed(BaseException):
        pass

    def moved(real):
        def move(src, dst):
            if ".tiling" in str(src) and ".tiling" not in str(dst):  # out of the work folder
                moves.append(dst)
                if len(moves) == killed_at:
                    raise Killed
            return real(src, dst)

        return move

    monkeypatch.setattr(os, "replace", moved(real_replace))
    monkeypatch.setattr(os, "rename", moved(real_rename))
    monkeypatch.setattr(shutil, "rmtree", lambda *args, **kwargs: None)  # (a kill removes nothing)
    out = tmp_path / "tiles"
    try:
        gp.tile(autzen_path, out, 500)
    except Killed:
        pass
    monkeypatch.undo()
    shown = sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) if out.exists() else None
    whole = gp.tile(autzen_path, tmp_path / "whole", 500)
    assert shown is None or shown == sorted(p.name for p in whole.tiles)
    assert shown == (None if killed_at == 1 else sorted(p.name for p in whole.tiles))  # one move: the folder itself


def _check_tiles_hold_their_stored_points(res, size, xyz):
    """Each tile's own points (not its buffer's), as laspy reads them back, lie in its half-open
    square (the corner its name gives), and the tiles together hold each of ``xyz`` once, as the
    grid stores it."""
    stored = []
    for path in res.tiles:
        written = laspy.read(str(path))
        own = ~np.asarray(written.overlap, bool)
        xmin, ymin = (float(c) for c in path.stem.split("_")[-2:])
        x, y = np.asarray(written.x)[own], np.asarray(written.y)[own]
        assert np.all((xmin <= x) & (x < xmin + size) & (ymin <= y) & (y < ymin + size)), (path.name, x.min(), x.max(), y.min(), y.max())
        stored.append(np.column_stack([written.X, written.Y, written.Z])[own])
        scale, offset = written.header.scales, written.header.offsets
    stored, wanted = np.concatenate(stored), np.rint((xyz - offset) / scale).astype(np.int64)
    assert np.array_equal(stored[np.lexsort(stored.T)], wanted[np.lexsort(wanted.T)])


@pytest.mark.parametrize("suffix", [".npy", ".xyz"])
def test_float_points_just_below_an_edge_are_stored_in_the_tile_that_holds_them(tmp_path, suffix):
    """Points of float files are stored on a grid made for the run (a millimetre here): one less
    than half a step below an edge is stored on it, and so belongs to the tile above (was: placed
    by its float, it sat on the lower tile's upper edge, outside its square)."""
    edges = np.array([10.0, 20.0])
    near = np.concatenate([edges, edges - 1e-7, edges - 0.0004, edges - 0.0006, edges + 0.0004])  # at, just below, within half a step, beyond it
    x = np.concatenate([near, np.full(len(near), 5.0), [0.0, 99.5]])  # (over 65.5 across: a millimetre grid)
    y = np.concatenate([np.full(len(near), 5.0), near, [0.0, 99.5]])
    xyz = np.column_stack([x, y, np.arange(len(x), dtype=np.float64)])
    path = tmp_path / f"pts{suffix}"
    if suffix == ".npy":
        np.save(path, xyz)
    else:
        np.savetxt(path, xyz, fmt="%.10f")
    res = gp.tile(path, tmp_path / "tiles", 10)
    assert list(laspy.read(str(res.tiles[0])).header.scales) == [0.001] * 3
    _check_tiles_hold_their_stored_points(res, 10.0, xyz)
    assert res.points == len(xyz)


def test_a_text_file_is_parsed_once_and_tiled_byte_for_byte_as_the_same_points_read_twice(tmp_path, monkeypatch):
    """Points of text, whose grid is made in a pass before they are tiled, are parsed once (that
    pass keeps them for the tiling pass: parsing twice took 1.75x the run of a 4 M-point .xyz):
    the tiles are byte for byte those of the same values in a .npy, which is read twice (16-bit
    colours, a buffer, several chunks, points less than half a step below an edge)."""
    rng = np.random.default_rng(7)
    n, chunk_size = 20_000, 3_000
    xyz = np.column_stack([rng.uniform(-5, 70, n), rng.uniform(-3, 21, n), rng.normal(0, 1, n)])  # (over 65.5 across: a millimetre grid)
    xyz[:300, 0] = np.round(xyz[:300, 0] / 7) * 7 - 0.0004  # (stored on the edge above)
    rows = np.column_stack([xyz, rng.integers(0, 65536, (n, 3))]).astype(np.float64)
    np.savetxt(tmp_path / "pts.xyz", rows, fmt=["%.17g"] * 3 + ["%d"] * 3)
    np.save(tmp_path / "pts.npy", rows)
    parsed = []
    read_chunks = TextReader.read_chunks

    def counted_read(self, path, chunk_size):
        for chunk in read_chunks(self, path, chunk_size):
            parsed.append(len(chunk))
            yield chunk

    monkeypatch.setattr(TextReader, "read_chunks", counted_read)
    options = {"size": 7, "buffer": 1.5, "chunk_size": chunk_size, "format": "las", "name": "pts"}
    text, npy = (gp.tile(tmp_path / f"pts.{kind}", tmp_path / kind, **options) for kind in ("xyz", "npy"))
    assert sum(parsed) == n  # every point once (was twice)
    assert [p.name for p in text.tiles] == [p.name for p in npy.tiles] and len(text.tiles) == 48
    assert all(a.read_bytes() == b.read_bytes() for a, b in zip(text.tiles, npy.tiles))
    assert laspy.read(str(text.tiles[0])).header.scales.tolist() == [0.001] * 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["npy", "pts.npy", "pts.xyz", "xyz"]  # (no work folder left, nor its kept points)


def test_las_points_between_edges_off_their_grid_are_in_the_tile_holding_their_stored_position(tmp_path):
    """A size of no whole number of grid steps (0.123 on a centimetre grid): x = 0.12 lies below
    the edge 0.123 and is in tile 0 (was: the edge taken at the nearest grid line, 0.12, so tile
    0.123 held x = 0.12, outside its square; and buffers reached half a step further)."""
    X = np.arange(0, 100)
    src = _line_of_points(tmp_path / "line.las", 0.01, 0.0, X)
    res = gp.tile(src, tmp_path / "tiles", 0.123, buffer=0.01, format="las")
    _check_tiles_hold_their_stored_points(res, 0.123, np.column_stack([X * 0.01, np.zeros(100), X * 0.01]))
    for i, path in enumerate(res.tiles):  # the buffer: within 0.01 of the square, edges included, as stored
        written = laspy.read(str(path))
        want = np.flatnonzero((X * 0.01 >= i * 0.123 - 0.01) & (X * 0.01 <= (i + 1) * 0.123 + 0.01))
        assert np.array_equal(np.asarray(written.X), want), path.name


def _files_in(folder):
    return {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()}


def _rerun_folders(autzen_path, tmp_path):
    """A tiles folder of an earlier run (the ground points' tiles) holding a file of the user's,
    its entries, and what the run of every point writes there (its tiles of the same names, the
    user's file kept)."""
    out = tmp_path / "tiles"
    gp.tile(autzen_path, out, 500, classes=[2])
    (out / "notes.txt").write_text("mine")
    new = gp.tile(autzen_path, tmp_path / "new", 500).out
    (new / "notes.txt").write_text("mine")
    old, whole = _files_in(out), _files_in(new)
    shutil.rmtree(new)
    assert old.keys() == whole.keys() and old != whole and len(old) == 7
    return out, old, whole


def test_a_rerun_into_a_folder_replaces_its_tiles_all_at_once_and_a_failure_leaves_the_old_ones(autzen_path, tmp_path, monkeypatch):
    """Tiles moved into a folder that was there one at a time: a failure part-way left a folder of
    old and new tiles that looked whole. Now the folder is swapped for one of the new tiles and
    its other files; a failure as it moves in puts the old one back."""
    out, old, whole = _rerun_folders(autzen_path, tmp_path)
    real = os.rename

    def failing(src, dst):
        if ".tiling" in os.fspath(src) and os.fspath(dst) == os.fspath(out.resolve()):  # the new folder moving in (not the old one back)
            raise OSError(errno.EIO, "Input/output error")
        return real(src, dst)

    monkeypatch.setattr(os, "rename", failing)
    with pytest.raises(InputError) as info:
        gp.tile(autzen_path, out, 500, overwrite=True)
    assert str(info.value) == f"{out}: the new tiles were not moved in (Input/output error); the folder is as it was"
    assert _files_in(out) == old
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tiles"]  # nothing hidden left beside it
    monkeypatch.undo()
    gp.tile(autzen_path, out, 500, overwrite=True)
    assert _files_in(out) == whole
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tiles"]


@pytest.mark.parametrize("killed_at", [1, 2])
def test_a_rerun_killed_as_its_tiles_move_in_leaves_all_old_tiles_or_all_new_ones(autzen_path, tmp_path, monkeypatch, killed_at):
    """A kill runs no clean-up: killed as the old folder moves away, it is there as it was; killed
    before the new one moves in, there is no folder, and the old one is whole beside it, hidden."""
    out, old, whole = _rerun_folders(autzen_path, tmp_path)
    moves, killed = [], []
    real_replace, real_rename = os.replace, os.rename

    class Killed(BaseException):
        pass

    def moved(real):
        def move(src, dst):
            if killed:  # (a killed run does nothing more)
                raise Killed
            if os.fspath(out.resolve()) in (os.fspath(src), os.fspath(dst)):
                moves.append(dst)
                if len(moves) == killed_at:
                    killed.append(dst)
                    raise Killed
            return real(src, dst)

        return move

    monkeypatch.setattr(os, "replace", moved(real_replace))
    monkeypatch.setattr(os, "rename", moved(real_rename))
    monkeypatch.setattr(shutil, "rmtree", lambda *args, **kwargs: None)
    with pytest.raises(Killed):
        gp.tile(autzen_path, out, 500, overwrite=True)
    monkeypatch.undo()
    if killed_at == 1:
        assert _files_in(out) == old
    else:
        assert not out.exists()
        (hidden,) = (p for p in tmp_path.iterdir() if p.name.endswith(".replaced"))
        assert _files_in(hidden) == old
        with pytest.warns(GigapointWarning, match=r"tiles: put back as it was before a run that was stopped while replacing its tiles$"):
            gp.tile(autzen_path, out, 500, overwrite=True)  # the next run finds the user's folder, and replaces its tiles
        assert _files_in(out) == whole
        assert not any(p.name.endswith(".replaced") for p in tmp_path.iterdir())
        assert not any(p.name.startswith(".") for p in out.iterdir())


def test_a_file_written_into_the_folder_as_its_tiles_are_swapped_in_is_kept(autzen_path, tmp_path, monkeypatch):
    """The folder's entries are linked into the new one, then the old one is removed: a file
    written meanwhile (another run's tile of another name, a user's) was removed with it."""
    out, old, whole = _rerun_folders(autzen_path, tmp_path)
    real = shutil.copystat

    def copystat_then_a_write(src, dst, **kwargs):  # (the step after the links)
        (out / "late.txt").write_text("written meanwhile")
        (out / "notes.txt").write_text("changed meanwhile")
        return real(src, dst, **kwargs)

    monkeypatch.setattr(shutil, "copystat", copystat_then_a_write)
    gp.tile(autzen_path, out, 500, overwrite=True)
    monkeypatch.undo()
    files = _files_in(out)
    assert files.pop("late.txt") == b"written meanwhile"
    assert files.pop("notes.txt") == b"changed meanwhile"
    whole.pop("notes.txt")
    assert files == whole


def test_a_set_aside_folder_of_another_output_is_not_put_back(autzen_path, tmp_path):
    """`.tiles.*.replaced` matched `.tiles.v2.XXXXXXXX.replaced`, tiles.v2's folder set aside by a
    killed run: a run into a missing `tiles` took it over as its own."""
    aside = tmp_path / ".tiles.v2.abcd1234.replaced"
    aside.mkdir()
    (aside / "notes.txt").write_text("tiles.v2's")
    gp.tile(autzen_path, tmp_path / "tiles", 500)
    assert (aside / "notes.txt").read_text() == "tiles.v2's"
    assert not (tmp_path / "tiles" / "notes.txt").exists()
