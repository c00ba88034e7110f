"""``convert`` into one plain point file (lod/convert/to_file.py): tiles merged, filtered, into
one .las/.laz/.ply file, faithful to the inputs' integers, classes, colours and CRS."""

from __future__ import annotations

import importlib
import re

import laspy
import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import EmptyCloudError, GigapointWarning, InputError
from gigapoint.io import read_chunks
from gigapoint.io.filters import PointFilter
from gigapoint.io.las import read_las_header, wkt_of
from gigapoint.lod import ConvertError, convert

CLIP = (636_500.0, 849_000.0, 637_000.0, 849_300.0)


def _tile(path, n: int, seed: int, color_factor: int):
    """A LAS tile (format 3, millimetre grid) of random points; its colours stored x ``color_factor`` (257: 16-bit, 1: 8-bit values)."""
    rng = np.random.default_rng(seed)
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = [0.001] * 3, [0.0] * 3
    las = laspy.LasData(header)
    las.X, las.Y, las.Z = (rng.integers(0, 1_000_000, n, dtype=np.int32) for _ in range(3))
    rgb = rng.integers(0, 256, (3, n)).astype(np.uint16) * color_factor
    las.red, las.green, las.blue = rgb
    las.classification = rng.integers(0, 8, n).astype(np.uint8)
    las.write(str(path))
    return path


def _wkt(path) -> str | None:
    hdr = read_las_header(path)
    return wkt_of(hdr.vlrs + hdr.evlrs)


def test_two_tiles_merge_into_one_laz_of_their_integers_classes_and_colours(tmp_path):
    a = _tile(tmp_path / "a.las", 3_000, 1, 257)
    b = _tile(tmp_path / "b.las", 2_000, 2, 1)  # 8-bit values in the 16-bit fields: written back so
    res = convert([a, b], tmp_path / "merged.laz")
    merged, sources = laspy.read(str(tmp_path / "merged.laz")), [laspy.read(str(p)) for p in (a, b)]
    assert (res.points, res.nodes, res.format) == (5_000, 0, "laz")
    for field in ("X", "Y", "Z", "classification", "red", "green", "blue"):
        assert np.array_equal(np.asarray(merged[field]), np.concatenate([np.asarray(s[field]) for s in sources])), field
    assert list(merged.header.scales) == [0.001] * 3


def test_autzen_ground_through_the_cli_holds_its_class_2_points_and_crs(cli, autzen_path, tmp_path):
    src = laspy.read(str(autzen_path))
    ground = src.classification == 2
    out = tmp_path / "ground.laz"
    rc, stdout, err = cli("convert", autzen_path, "-o", out, "--classes", "2", "-q")
    assert rc == 0, err
    assert stdout.startswith(f"{out}: {np.count_nonzero(ground):,} points (laz), ")
    written = laspy.read(str(out))
    assert np.array_equal(written.X, src.X[ground]) and np.array_equal(written.Z, src.Z[ground])
    assert np.array_equal(written.red, src.red[ground])  # (autzen's 8-bit values, as it stores them)
    assert _wkt(out) == _wkt(autzen_path) is not None


def test_a_clip_box_keeps_the_points_inside_it(autzen_path, tmp_path):
    src = laspy.read(str(autzen_path))
    xy = np.stack([src.x, src.y], axis=1)
    inside = np.all((xy >= CLIP[:2]) & (xy <= CLIP[2:]), axis=1)
    res = convert(autzen_path, tmp_path / "clip.las", clip=CLIP)
    written = laspy.read(str(tmp_path / "clip.las"))
    assert res.points == len(written.points) == np.count_nonzero(inside) > 0
    assert np.array_equal(written.X, src.X[inside]) and np.array_equal(written.gps_time, src.gps_time[inside])


def test_paths_given_as_strings_write_the_file(autzen_path, tmp_path):
    out = str(tmp_path / "strings.laz")  # a str output was "'str' object has no attribute 'is_dir'"
    res = gp.convert(str(autzen_path), out, classes=[2])
    written = laspy.read(out)
    assert res.points == len(written.points) == int(np.count_nonzero(laspy.read(str(autzen_path)).classification == 2)) > 0
    assert res.out == tmp_path / "strings.laz"


def _rows(chunks) -> np.ndarray:
    """Points as sorted rows of position, colour and classification."""
    chunks = list(chunks)
    xyz = np.concatenate([c.xyz for c in chunks])
    rest = np.concatenate([np.column_stack([c.rgba, c.attributes["classification"]]) for c in chunks]).astype(np.float64)
    rows = np.column_stack([xyz, rest])
    return rows[np.lexsort(rows.T[::-1])]


def test_a_ply_output_reads_back_as_the_points_it_was_written_from(autzen_path, tmp_path):
    res = convert(autzen_path, tmp_path / "clip.ply", clip=CLIP)
    back, source = gp.open(tmp_path / "clip.ply", colors="rgba"), gp.open(autzen_path, clip=CLIP, colors="rgba")
    assert res.points == back.n_points == source.n_points
    assert np.array_equal(back.bounds, source.bounds)
    # every point (the clouds hold positions quantized each its own way): as the readers give them, exact
    assert np.array_equal(_rows(read_chunks(tmp_path / "clip.ply")), _rows(PointFilter(clip=CLIP).apply(read_chunks(autzen_path), autzen_path)))
    crs = f"comment crs {read_las_header(autzen_path).crs()}\n"  # (PLY has no field for it: a comment, io/write.py)
    assert (tmp_path / "clip.ply").read_bytes().startswith(f"ply\nformat binary_little_endian 1.0\n{crs}element vertex {res.points:020d}\n".encode())


def test_an_existing_output_is_refused_before_anything_is_read(autzen_path, tmp_path, monkeypatch):
    out = tmp_path / "ground.laz"
    out.write_bytes(b"the user's file")

    def no_read(*args):
        raise AssertionError("read")

    monkeypatch.setattr(importlib.import_module("gigapoint.lod.convert.to_file"), "read_chunks", no_read)
    with pytest.raises(InputError, match=r"ground\.laz: already exists; pass overwrite=True to replace it$"):
        convert(autzen_path, out, classes=2)
    assert out.read_bytes() == b"the user's file"


def test_an_input_named_as_the_output_is_refused(tmp_path):
    a = _tile(tmp_path / "a.las", 100, 1, 257)
    with pytest.raises(InputError, match=r"a\.las: is one of the inputs; write it elsewhere"):
        convert(a, a, overwrite=True)
    assert len(laspy.read(str(a)).points) == 100


@pytest.mark.parametrize(
    ("option", "named"),
    [
        ({"sampler": "poisson"}, "sampler"),
        ({"memory_limit": "1G"}, "memory_limit"),
        ({"max_leaf": 1000}, "max_leaf"),
        ({"layout": "words"}, "layout"),
        ({"colors": "rgb565"}, "colors"),
        ({"encoding": "BROTLI"}, "encoding"),
        ({"client": 2}, "client"),
        ({"name": "scan"}, "name"),
    ],
)
def test_an_octree_option_with_a_point_file_output_is_refused_in_one_line(autzen_path, tmp_path, option, named):
    with pytest.raises(ConvertError) as info:
        convert(autzen_path, tmp_path / "out.laz", **option)
    assert str(info.value) == f"{tmp_path / 'out.laz'}: {named}: an option of an octree, not of a plain LAZ file"
    assert not (tmp_path / "out.laz").exists()


def test_the_cli_refuses_octree_options_with_a_point_file_output(cli, autzen_path, tmp_path):
    out = tmp_path / "out.las"
    rc, _, err = cli("convert", autzen_path, "-o", out, "--sampler", "poisson", "--workers", "2")
    assert (rc, err.strip()) == (1, f"error: {out}: --sampler, --dask/--workers (client): options of an octree, not of a plain LAS file")


def test_the_cli_refuses_octree_options_itself_before_the_library_runs(cli, autzen_path, tmp_path, monkeypatch):
    """The command knows its output and options: it refused them by rewriting the library's
    refusal (a parse of its words, which a change there broke without a word), after the call."""
    called = []
    monkeypatch.setattr(gp.lod, "convert", lambda *args, **kwargs: called.append(args))
    out = tmp_path / "out.ply"
    rc, _, err = cli("convert", autzen_path, "-o", out, "--max-leaf", "1000", "--workers", "2")
    assert (rc, err.strip(), called) == (1, f"error: {out}: --max-leaf, --dask/--workers (client): options of an octree, not of a plain PLY file", [])


def test_a_point_file_output_makes_the_folders_missing_on_its_way(cli, autzen_path, tmp_path):
    """As an octree folder or a COPC file output does (-o out/scan.copc.laz made out/, -o out/scan.laz refused it)."""
    assert convert(autzen_path, tmp_path / "lib" / "deeper" / "out.laz", progress=False).points == 110_000
    rc, _, err = cli("convert", autzen_path, "-o", tmp_path / "cli" / "deeper" / "out.las", "--quiet")
    assert rc == 0, err
    assert [len(laspy.read(tmp_path / d / "deeper" / f).points) for d, f in (("lib", "out.laz"), ("cli", "out.las"))] == [110_000, 110_000]


def test_the_cli_names_each_octree_option_it_refuses_with_a_point_file_output(cli, autzen_path, tmp_path):
    """The library says the keywords (sampler, memory_limit, ...; above), the command line its options."""
    out = tmp_path / "out.laz"
    rc, _, err = cli("convert", autzen_path, "-o", out, "--memory-limit", "1G", "--max-leaf", "1000", "--layout", "words", "--colors", "rgba", "--dask", "tcp://127.0.0.1:9")
    assert (rc, err.strip()) == (1, f"error: {out}: --memory-limit, --max-leaf, --layout, --colors, --dask/--workers (client): options of an octree, not of a plain LAZ file")
    assert not out.exists()
    rc, _, err = cli("convert", autzen_path, "-o", f"file://{out}", "--sampler", "random")  # (the library names the URL's path)
    assert (rc, err.strip()) == (1, f"error: {out}: --sampler: an option of an octree, not of a plain LAZ file")


def test_a_filter_keeping_nothing_is_its_error_and_leaves_no_file(autzen_path, tmp_path):
    with pytest.raises(EmptyCloudError, match=r"autzen_trim\.laz: no point passes the filter \(classes 200\): 110,000 points read$"):
        convert(autzen_path, tmp_path / "none.laz", classes=200)
    assert list(tmp_path.iterdir()) == []


def test_invalid_points_are_skipped_with_a_warning(tmp_path):
    xyz = np.array([[0.0, 0.0, 0.0], [np.nan, 1.0, 1.0], [1.0, 2.0, 3.0]])
    src = tmp_path / "pts.npy"
    np.save(src, xyz)
    with pytest.warns(GigapointWarning, match=r"pts\.npy: skipped 1 invalid point \("):
        res = convert(src, tmp_path / "pts.las")
    written = laspy.read(str(tmp_path / "pts.las"))
    assert (res.points, res.skipped) == (2, 1)
    off = np.abs(np.column_stack([written.x, written.y, written.z]) - xyz[[0, 2]])
    assert np.all(off <= written.header.scales / 2)  # (on the grid made from their bounds)


def _cells_tiles(tmp_path):
    """Two LAS tiles (millimetre grid, offset -4 so cells -4..3 on x and y) of 6 points in each of
    8 x 8 x 3 one-unit cells, in shuffled order, with colours, classes, intensities and times all
    distinct enough to tell the points apart; returns their paths and the points' cells in file order."""
    rng = np.random.default_rng(7)
    cells = np.stack(np.meshgrid(np.arange(-4, 4), np.arange(-4, 4), np.arange(3), indexing="ij"), axis=-1).reshape(-1, 3)
    cells = np.repeat(cells, 6, axis=0)
    inside = rng.integers(0, 1000, cells.shape)  # millimetres inside the cell, its lower faces included
    ints = (cells + [4, 4, 0]) * 1000 + inside  # (the offsets: x = X * 0.001 - 4, z = Z * 0.001)
    order = rng.permutation(len(ints))
    ints, cells = ints[order], cells[order]
    paths = []
    for k, rows in enumerate((slice(0, 700), slice(700, None))):
        header = laspy.LasHeader(point_format=3, version="1.2")
        header.scales, header.offsets = [0.001] * 3, [-4.0, -4.0, 0.0]
        las = laspy.LasData(header)
        las.X, las.Y, las.Z = (ints[rows, a].astype(np.int32) for a in range(3))
        n = len(las.X)
        las.red, las.green, las.blue = (rng.integers(0, 256, n).astype(np.uint16) * 257 for _ in range(3))  # (8-bit colours, as held)
        las.classification = rng.integers(0, 32, n).astype(np.uint8)
        las.intensity = rng.integers(0, 65536, n).astype(np.uint16)
        las.gps_time = rng.uniform(0, 1e6, n)
        paths.append(tmp_path / f"tile{k}.las")
        las.write(str(paths[-1]))
    return paths, cells


def test_thin_keeps_the_first_point_of_each_occupied_cell_over_both_files_and_every_chunk(tmp_path):
    paths, cells = _cells_tiles(tmp_path)
    res = convert(paths, tmp_path / "thin.laz", thin=1.0, chunk_size=100)  # 12 chunks: a cell's points in several
    first = np.sort(np.unique(cells, axis=0, return_index=True)[1])  # the first point of each cell, in file order
    assert (res.points, res.thinned_from) == (8 * 8 * 3, 1152)
    assert res.points_per_second == pytest.approx(1152 / res.seconds)  # points thinned a second, not the few kept
    thin, sources = laspy.read(str(tmp_path / "thin.laz")), [laspy.read(str(p)) for p in paths]
    for field in ("X", "Y", "Z", "red", "green", "blue", "classification", "intensity", "gps_time"):
        assert np.array_equal(np.asarray(thin[field]), np.concatenate([np.asarray(s[field]) for s in sources])[first]), field
    assert list(thin.header.scales) == [0.001] * 3 and list(thin.header.offsets) == [-4.0, -4.0, 0.0]
    # one point a cell: its position's cell (the grid anchored at 0, not at the offset)
    kept_cells = np.floor(np.column_stack([thin.x, thin.y, thin.z])).astype(np.int64)
    assert np.array_equal(kept_cells, cells[first])


def test_autzen_thinned_at_10_ft_keeps_one_point_of_each_occupied_cell_with_its_crs(cli, autzen_path, tmp_path):
    src = laspy.read(str(autzen_path))
    cells = np.floor(np.column_stack([src.x, src.y, src.z]) / 10)
    first = np.sort(np.unique(cells, axis=0, return_index=True)[1])
    out = tmp_path / "thin.laz"
    rc, stdout, err = cli("convert", autzen_path, "-o", out, "--thin", "10", "-q")
    assert rc == 0, err
    assert stdout.startswith(f"{out}: {len(first):,} points (laz), thinned from 110,000, ")
    written = laspy.read(str(out))
    assert len(first) == 7_788
    assert np.array_equal(written.X, src.X[first]) and np.array_equal(written.red, src.red[first])
    assert _wkt(out) == _wkt(autzen_path) is not None


@pytest.mark.parametrize("value", [0, -1.5, float("nan"), float("inf"), True, "10"])
def test_a_bad_thin_spacing_is_refused_in_one_line(autzen_path, tmp_path, value):
    with pytest.raises(InputError) as info:
        convert(autzen_path, tmp_path / "thin.laz", thin=value)
    assert str(info.value) == f"convert: thin={value!r}: the cells' edge is a number above 0, in the cloud's units"
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("typed", "message"),
    [
        ("0", "convert: --thin 0: the cells' edge is a number above 0, in the cloud's units"),
        ("ten", "convert: --thin ten: the cells' edge is a number above 0, in the cloud's units"),
        ("1e-9", "convert: --thin 1e-9: cells too small for the data's extent ({}: 1.18e+12 x 5.63e+11 x 1.14e+11 cells, over 2^63)"),
    ],
)
def test_the_cli_refuses_a_bad_thin_spacing_before_reading_a_point(cli, autzen_path, tmp_path, monkeypatch, typed, message):
    def no_read(*args):
        raise AssertionError("read")

    monkeypatch.setattr(importlib.import_module("gigapoint.lod.convert.to_file"), "read_chunks", no_read)
    rc, _, err = cli("convert", autzen_path, "-o", tmp_path / "thin.laz", "--thin", typed)
    assert (rc, err.strip()) == (1, "error: " + message.format(autzen_path))
    assert list(tmp_path.iterdir()) == []


def test_thin_of_points_beyond_the_keys_reach_names_their_file(tmp_path):
    src = tmp_path / "pts.npy"  # (no header bounds: the keys sized around the first point)
    np.save(src, np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [1e4, 0.0, 0.0]]))
    assert convert(src, tmp_path / "ok.ply", thin=1.0).points == 2
    with pytest.raises(InputError, match=r"^convert: thin=1e-06: cells too small for the data's extent \(.*pts\.npy: a point at 10000, 0, 0 is beyond the reach of 63-bit cell keys\)$"):
        convert(src, tmp_path / "far.ply", thin=1e-6)
    assert not (tmp_path / "far.ply").exists()


@pytest.mark.parametrize("name", ["octree", "thin.copc.laz"])
def test_thin_with_an_octree_output_is_refused(cli, autzen_path, tmp_path, name):
    out = tmp_path / name
    rc, _, err = cli("convert", autzen_path, "-o", out, "--thin", "10")
    fmt = "copc" if name.endswith(".copc.laz") else "gigapoint"
    assert (rc, err.strip()) == (1, f"error: {out}: --thin: an option of a plain .las, .laz or .ply file of the files' points, not of a {fmt} octree")
    assert not out.exists()


@pytest.mark.parametrize("given", [None, 10_000])
def test_the_streaming_commands_read_chunks_of_the_stream_size_unless_told(autzen_path, tmp_path, monkeypatch, given):
    """``convert -o x.laz`` and ``tile`` read their inputs in chunks of STREAM_CHUNK_SIZE (their peak
    memory is a chunk or two: not the 2 M points of DEFAULT_CHUNK_SIZE), or of the ``chunk_size`` given."""
    from gigapoint.io._base import DEFAULT_CHUNK_SIZE, STREAM_CHUNK_SIZE

    to_file = importlib.import_module("gigapoint.lod.convert.to_file")
    read_chunks_of, asked, sizes = to_file.read_chunks, [], []

    def recorded(path, chunk_size):
        asked.append(chunk_size)
        for chunk in read_chunks_of(path, chunk_size):
            sizes.append(len(chunk))
            yield chunk

    monkeypatch.setattr(to_file, "read_chunks", recorded)
    expected = given or STREAM_CHUNK_SIZE
    assert STREAM_CHUNK_SIZE < DEFAULT_CHUNK_SIZE
    convert(autzen_path, tmp_path / "copy.laz", chunk_size=given)
    gp.tile(autzen_path, tmp_path / "tiles", 500, chunk_size=given)
    assert asked == [expected, expected]
    assert max(sizes) == min(expected, 110_000) and sum(sizes) == 2 * 110_000


def _colourless_tile(path, n: int, seed: int):
    """A LAS tile of point format 1 (no RGB): positions, intensities, classes, returns and GPS times."""
    rng = np.random.default_rng(seed)
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.scales, header.offsets = [0.01] * 3, [1000.0, 2000.0, 0.0]
    las = laspy.LasData(header)
    las.X, las.Y, las.Z = (rng.integers(0, 100_000, n, dtype=np.int32) for _ in range(3))
    las.intensity = rng.integers(0, 65536, n).astype(np.uint16)
    las.classification = rng.integers(0, 8, n).astype(np.uint8)
    las.return_number, las.number_of_returns = np.ones(n, np.uint8), np.full(n, 2, np.uint8)
    las.gps_time = rng.uniform(0, 1e6, n)
    las.write(str(path))
    return path


def test_a_colourless_las_is_written_in_point_format_6_with_its_points_and_attributes(cli, tmp_path):
    src = _colourless_tile(tmp_path / "norgb.las", 2_000, 11)
    out = tmp_path / "out.las"
    rc, _, err = cli("convert", src, "-o", out, "-q")
    assert rc == 0, err
    written, source = laspy.read(str(out)), laspy.read(str(src))
    assert written.header.point_format.id == 6  # (was 7, every point red = green = blue = 51400: the viewer's grey)
    assert "red" not in written.point_format.dimension_names
    for field in ("X", "Y", "Z", "intensity", "classification", "return_number", "number_of_returns", "gps_time"):
        assert np.array_equal(written[field], source[field]), field
    assert list(written.header.scales) == [0.01] * 3 and list(written.header.offsets) == [1000.0, 2000.0, 0.0]


def test_a_colourless_ply_round_trip_writes_no_colour_properties(tmp_path):
    src = _colourless_tile(tmp_path / "norgb.las", 500, 12)
    convert(src, tmp_path / "a.ply")
    convert(tmp_path / "a.ply", tmp_path / "b.ply")  # a PLY without colours read, then written
    for name in ("a.ply", "b.ply"):
        head = (tmp_path / name).read_bytes().split(b"end_header")[0].decode()
        assert "property uchar red" not in head and "property double x" in head, name
    source = laspy.read(str(src))
    back = np.concatenate([c.xyz for c in read_chunks(tmp_path / "b.ply")])
    assert np.array_equal(back, np.column_stack([source.x, source.y, source.z]))
    assert np.array_equal(np.concatenate([c.attributes["intensity"] for c in read_chunks(tmp_path / "b.ply")]), source.intensity)


def test_colourless_tiles_among_coloured_ones_are_written_black_with_a_warning(tmp_path):
    coloured = _tile(tmp_path / "rgb.las", 1_000, 13, 257)
    plain = _colourless_tile(tmp_path / "norgb.las", 600, 14)
    with pytest.warns(GigapointWarning, match=r"^norgb\.las: no colours; their points are written black \(0, 0, 0\) beside the other files' colours"):
        res = convert([coloured, plain], tmp_path / "mixed.laz")
    written = laspy.read(str(tmp_path / "mixed.laz"))
    assert res.points == 1_600 and written.header.point_format.id == 7
    rgb = np.column_stack([written.red, written.green, written.blue])
    source = laspy.read(str(coloured))
    assert np.array_equal(rgb[:1_000], np.column_stack([source.red, source.green, source.blue]))
    assert not rgb[1_000:].any()  # (not the grey 51400 made up for them)


def test_one_point_is_said_as_1_point_in_the_summary_and_the_filters_error(cli, tmp_path):
    """A one-point file: '1 point', not '1 points' (the summary line and the empty filter's error)."""
    src = _tile(tmp_path / "one.las", 1, 5, 257)
    out = tmp_path / "out.laz"
    rc, stdout, err = cli("convert", src, "-o", out, "-q")
    assert rc == 0, err
    assert stdout.startswith(f"{out}: 1 point (laz), ")
    rc, _, err = cli("convert", src, "-o", tmp_path / "none.laz", "--classes", "31", "-q")
    assert rc == 1
    assert err.strip() == f"error: {src}: no point passes the filter (classes 31): 1 point read"


def test_a_point_file_whose_input_fails_part_way_leaves_no_folder_it_made(tmp_path, cli):
    """The folders missing on the way are made as the file is written, and its points are read as
    it is: a bad line read part-way left them behind, empty (the file itself is never left)."""
    bad = tmp_path / "bad.xyz"
    bad.write_text("".join(f"{i} {i} {i}\n" for i in range(1500)) + "abc 1 2\n")
    with pytest.raises(InputError, match="'abc' is not a number"):
        gp.convert(bad, tmp_path / "nd" / "sub" / "x.laz")
    assert not (tmp_path / "nd").exists()
    (tmp_path / "kept").mkdir()
    rc, _, err = cli("convert", bad, "-o", tmp_path / "kept" / "a" / "b" / "x.laz")
    assert rc == 1 and "'abc' is not a number" in err
    assert list((tmp_path / "kept").iterdir()) == []  # its own folder stays; those made go


def test_the_summary_says_a_slow_rate_in_points_not_zero_millions(cli, tmp_path):
    """A run below a million points a second printed "0.00 M points/s": its speed in points (1,000
    points take far longer than the millisecond that would make a million a second)."""
    from gigapoint.cli.cloud_opts import rate_note

    assert rate_note(2_345_678) == "2.35 M points/s" and rate_note(1234.4) == "1,234 points/s" and rate_note(0.0) == "0 points/s"
    np.save(tmp_path / "few.npy", np.random.default_rng(1).random((1000, 3)) * 100)
    rc, stdout, err = cli("convert", tmp_path / "few.npy", "-o", tmp_path / "few.las", "-q")
    assert rc == 0, err
    assert re.search(r", \d[\d,]* points/s$", stdout.strip()), stdout


def _ply_in_utm(path):
    """100 points in a PLY file naming EPSG:32610 in its ``comment crs`` line (as gigapoint writes it)."""
    import plyfile

    v = np.zeros(100, [("x", "<f8"), ("y", "<f8"), ("z", "<f8")])
    v["x"], v["y"], v["z"] = 500_000 + np.arange(100.0), 5_000_000.0, np.arange(100) % 7
    plyfile.PlyData([plyfile.PlyElement.describe(v, "vertex")], comments=["crs EPSG:32610"]).write(str(path))
    return path


@pytest.mark.parametrize("output", ["out.ply", "out.las", "octree"])
def test_a_ply_inputs_crs_is_kept_by_every_output(tmp_path, output):
    """The CRS of the outputs was read from LAS headers only: a PLY file's ``comment crs`` was
    lost converting it to PLY, LAS or an octree, without a word."""
    import json

    import plyfile

    pyproj = pytest.importorskip("pyproj")
    out = tmp_path / output
    convert(_ply_in_utm(tmp_path / "utm.ply"), out)
    if output == "out.ply":
        assert plyfile.PlyData.read(str(out)).comments == ["crs EPSG:32610"]
    else:
        crs = read_las_header(out).crs() if output == "out.las" else json.loads((out / "octree.json").read_text())["crs"]
        assert pyproj.CRS.from_user_input(crs).to_epsg() == 32610


def test_a_compound_crs_too_long_for_a_ply_header_line_is_written_by_its_codes(autzen_path, tmp_path):
    """The WKT of EPSG:6557+6360 is 1,042 bytes on one line: a PLY header line of that length is
    refused by RPly (Open3D, CloudCompare: 1024 at most). A CRS naming its EPSG codes is written
    by them, and read back as that CRS (its vertical unit too)."""
    import plyfile

    from gigapoint.io import files_crs_units

    pytest.importorskip("pyproj")
    out = tmp_path / "compound.ply"
    convert(autzen_path, out, clip=CLIP, to_crs="EPSG:6557+6360", from_crs="EPSG:2994+6360")
    head = out.read_bytes()[:4096].split(b"end_header\n")[0]
    assert max(len(line) for line in head.splitlines()) < 1024 and plyfile.PlyData.read(str(out)).comments == ["crs EPSG:6557+6360"]
    crs, units = files_crs_units([out])
    assert crs == "EPSG:6557+6360" and units["vertical"]["symbol"] == "US ft" and gp.open(out).n_points > 0
