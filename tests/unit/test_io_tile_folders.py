"""A folder of LAS/LAZ tiles as a city delivers it: hundreds of tiles, and files beside them."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import EmptyCloudError, GigapointWarning
from gigapoint.io import READ_SUBFOLDERS, point_stats

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
    # --json: the same block as one object (it printed a line a file, as --each does)
    rc, out, err = cli("info", "--json", tmp_path)
    damaged, summed = map(json.loads, out.splitlines())
    assert rc == 1 and damaged["path"] == str(tiles[12]) and damaged["error"].startswith(f"{tiles[12]}: ")
    assert {k: summed[k] for k in ("path", "files", "point_count", "format", "las_version", "crs")} == {
        "path": str(tmp_path), "files": 13, "point_count": 650, "format": "LAZ", "las_version": "1.2", "crs": None}
    assert summed["bounds"]["min"] == lo.tolist() and "scale" not in summed and summed["offset"] == [500000.0, 4000000.0, 0.0]
    assert summed["details"] == {"scales": "0.01, 0.01, 0.01 (12 files); 0.001, 0.001, 0.001 (1 file)"}
    rc, out, err = cli("info", "--json", "--each", tmp_path)
    assert rc == 1 and [json.loads(line).get("point_count") for line in out.splitlines()] == [50] * 12 + [None, 50]


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


def _empty_file(folder: Path, kind: str) -> Path:
    """An input without a point: a 0-byte text file, a text file of blank lines, a LAS file counting none."""
    if kind == "las":
        laspy.LasData(laspy.LasHeader(point_format=3, version="1.2")).write(folder / "empty.las")
        return folder / "empty.las"
    (folder / "empty.xyz").write_text("" if kind == "0-byte" else "\n\n  \n")
    return folder / "empty.xyz"


def _loaded_points(cloud) -> int:
    """The points a progressive load holds once done (its warnings issued by the wait)."""
    assert cloud.wait(timeout=120)
    return cloud.n_points


# each operation's count of the points it read: a 0-byte text file, one of blank lines or a LAS file counting none among them
EMPTY_AMONG_SEVERAL = [
    ("open", lambda files, out: gp.open(files).n_points),
    ("progressive", lambda files, out: _loaded_points(gp.open(files, progressive=True))),
    ("convert-las", lambda files, out: gp.convert(files, out / "all.las").points),
    ("convert-octree", lambda files, out: gp.convert(files, out / "octree").points),
    ("tile", lambda files, out: gp.tile(files, out / "tiles", 100.0).points),
    ("point-stats", lambda files, out: point_stats(files)["point_count"]),  # (refused the 0-byte file and the blank one)
]
#: what each kind of empty file alone is refused with
EMPTY_ALONE = {"0-byte": "file is empty (0 bytes)", "blank-lines": "holds no points", "las": "LAS file holds no points (header point count is 0)"}


@pytest.mark.parametrize("kind", ["0-byte", "blank-lines", "las"])
@pytest.mark.parametrize("call", [c[1] for c in EMPTY_AMONG_SEVERAL], ids=[c[0] for c in EMPTY_AMONG_SEVERAL])
def test_an_empty_input_among_several_is_skipped_with_one_warning_by_every_operation(tmp_path, kind, call):
    """A 0-byte file or one of blank lines among several: gp.open skipped the blank one, but its
    progressive load, convert and tile stopped on it ("holds no points"), and every one on a
    0-byte file ("file is empty"); an empty LAS file was said twice by a conversion to .las (a pass each)."""
    tiles = write_tiles(tmp_path / "in", 2)
    empty = _empty_file(tmp_path / "in", kind)
    with pytest.warns(GigapointWarning) as caught:
        assert call([tiles[0], empty, tiles[1]], tmp_path) == 100
    assert [str(w.message) for w in caught if str(empty) in str(w.message)] == [f"{empty}: holds no points, skipped"]  # every warning naming it: one


@pytest.mark.parametrize("kind", ["0-byte", "blank-lines"])
def test_render_color_attribute_reads_the_headers_of_the_files_with_points(tmp_path, cli, kind):
    """render's --color-attribute check read every input's header: an empty file among several,
    which the render skips, was "file is empty (0 bytes)" / "holds no points" before a point was read."""
    tiles = write_tiles(tmp_path / "in", 2)
    empty = _empty_file(tmp_path / "in", kind)
    out = tmp_path / "x.png"
    args = ("render", empty, *tiles, "--color-mode", "attribute", "--color-attribute", "intensity", "--width", "32", "--height", "24", "-o", out)
    rc, _, err = cli(*args)
    assert (rc, err.strip()) == (0, f"warning: {empty}: holds no points, skipped") and out.is_file()


def test_an_empty_las_file_beside_a_text_file_is_said_once_by_a_conversion_to_las(tmp_path):
    """Points of a text file have no LAS grid: written in two passes, each said the empty LAS file again."""
    text = tmp_path / "a.xyz"
    text.write_text("0 0 0\n1 1 1\n2 2 1\n")
    empty = _empty_file(tmp_path, "las")
    with pytest.warns(GigapointWarning) as caught:
        assert gp.convert([text, empty], tmp_path / "all.las").points == 3
    assert [str(w.message) for w in caught] == [f"{empty}: holds no points, skipped"]


@pytest.mark.parametrize("kind", ["0-byte", "blank-lines", "las"])
@pytest.mark.parametrize("call", [c[1] for c in EMPTY_AMONG_SEVERAL], ids=[c[0] for c in EMPTY_AMONG_SEVERAL])
def test_an_empty_input_alone_is_an_error_naming_it(tmp_path, kind, call):
    empty = _empty_file(tmp_path, kind)
    with pytest.raises(EmptyCloudError) as caught:
        call([empty], tmp_path)
    assert str(caught.value) == f"{empty}: {EMPTY_ALONE[kind]}"


def test_only_empty_inputs_of_any_kind_say_no_file_holds_a_point(tmp_path):
    """A 0-byte text file beside a LAS file counting none: each pair says what two empty LAS files say
    (one was judged alone: "holds no points" one way round, "no file holds any point" the other)."""
    files = [_empty_file(tmp_path, "0-byte"), _empty_file(tmp_path, "las")]
    for pair in (files, files[::-1]):
        with pytest.raises(EmptyCloudError) as caught:
            gp.open(pair)
        assert str(caught.value) == f"{pair[0]}, {pair[1]}: no file holds any point"


def _empty_tiles(folder) -> list:
    """Two LAS tiles without a point, a.laz and b.laz in ``folder``."""
    files = [folder / "a.laz", folder / "b.laz"]
    for f in files:
        laspy.LasData(laspy.LasHeader(point_format=3, version="1.2")).write(f)
    return files


@pytest.mark.parametrize("options", [{}, {"chunked": True}, {"progressive": True}], ids=["in_memory", "chunked", "progressive"])
def test_a_folder_of_empty_tiles_says_no_file_holds_a_point(tmp_path, options):
    """Every tile empty (each skipped with a warning): gp.open said 'no valid points', as of NaN
    or absurd positions; it says what a progressive load says."""
    _empty_tiles(tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GigapointWarning)  # (each tile's "holds no points, skipped")
        with pytest.raises(EmptyCloudError) as caught:
            gp.open(tmp_path, **options)
    assert str(caught.value) == f"{tmp_path / 'a.laz'}, {tmp_path / 'b.laz'}: no file holds any point"
    # (no "no valid points ... During handling of the above exception" above it in a traceback)
    assert caught.value.__context__ is None or caught.value.__suppress_context__


@pytest.mark.parametrize(
    "make",
    [
        lambda files, out: gp.convert(files, out / "octree"),
        lambda files, out: gp.convert(files, out / "all.laz"),
        lambda files, out: gp.convert(files, out / "filtered", classes=[2]),
        lambda files, out: gp.tile(files, out / "tiles", 100.0),
    ],
    ids=["convert-octree", "convert-laz", "convert-filtered", "tile"],
)
def test_converting_or_tiling_only_empty_tiles_says_no_file_holds_a_point(tmp_path, make):
    """Every tile empty (each skipped with a warning): convert and tile said 'no valid points',
    the words for NaN or absurd positions; they say what gp.open says."""
    files = _empty_tiles(tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GigapointWarning)  # (each tile's "holds no points, skipped")
        with pytest.raises(EmptyCloudError) as caught:
            make(files, tmp_path)
    assert str(caught.value) == f"{files[0]}, {files[1]}: no file holds any point"


def test_info_of_a_folder_tells_offsets_apart_as_one_files_info_prints_them(cli, tmp_path):
    """Offsets that differ in their 11th digit (PDAL's offset 'auto': each tile its own) were
    counted as one offset in the folder's block, printed to 10 digits."""
    tiles = write_tiles(tmp_path, 12)
    las = laspy.read(tiles[11])
    las.header.offsets = [500000.00001, 4000000.0, 0.0]
    las.write(tiles[11])
    rc, out, _ = cli("info", tmp_path)
    assert rc == 0 and "  offsets:     500000, 4000000, 0 (11 files); 500000.00001, 4000000, 0 (1 file)" in out.splitlines()


def city_of_subfolders(root: Path) -> Path:
    """city/north (2 tiles), city/south (1 tile), and what must not be read: a hidden folder's
    tile, a symlink from north back to city (a loop), an EPT dataset's folder."""
    write_tiles(root / "city" / "north", 2, suffix=".las")
    write_tiles(root / "city" / "south", 1, suffix=".las")
    write_tiles(root / "city" / ".trash", 1, suffix=".las")
    (root / "city" / "north" / "loop").symlink_to(root / "city", target_is_directory=True)
    (root / "city" / "ept").mkdir()
    (root / "city" / "ept" / "ept.json").write_text("{}")
    return root / "city"


def test_a_folder_of_subfolders_of_tiles_names_them_and_recursive_reads_every_tile_below(tmp_path, cli):
    """city/north/*.las and city/south/*.las: every command said "directory holds no supported
    point cloud file", not that its subfolders do, nor how to read them."""
    from gigapoint.errors import EmptyCloudError, InputError

    city = city_of_subfolders(tmp_path)
    said = (f"{city}: holds no point cloud file, but its subfolders north, south do: read every file below it "
            f"with --recursive (recursive=True in Python), or name them ({city}/*/)")  # fmt: skip
    with pytest.raises(EmptyCloudError) as caught:
        gp.open(city)
    assert str(caught.value) == said
    assert cli("info", city) == (1, "", f"error: {said}\n")
    with pytest.warns(GigapointWarning) as caught:  # the EPT folder is an octree, not tiles
        cloud = gp.open(city, recursive=True)
    assert [str(w.message) for w in caught] == [f"{city / 'ept'}: an octree, not read with the point files around it (open it alone)"]
    assert cloud.n_points == 150 and cloud.name == "3 files"
    assert [f.relative_to(city).as_posix() for f in cloud.source_files] == ["north/tile_00_00.las", "north/tile_00_01.las", "south/tile_00_00.las"]
    rc, out, _ = cli("info", "--recursive", "--json", city)
    assert rc == 0 and [json.loads(line)["path"] for line in out.splitlines()] == [str(f) for f in cloud.source_files]
    assert gp.open(city / "north", city / "south").n_points == 150  # the shell's city/*/
    with pytest.raises(InputError, match=r"^open: recursive must be True or False, got 'yes'$"):
        gp.open(city, recursive="yes")
    for name in "abc":
        write_tiles(city / name, 1, suffix=".las")
    with pytest.raises(EmptyCloudError, match=r": holds no point cloud file, but its subfolders a, b, c and 2 more do: "):
        gp.open(city)


def test_a_quoted_glob_pattern_reads_the_files_it_matches_in_name_order(tmp_path, cli):
    """gigapoint view "tiles/*.laz" (quoted: Windows' shells, scripts, Makefiles) and
    gp.open("tiles/*.laz") said "no such file": no shell had expanded the pattern."""
    from gigapoint.errors import InputError
    from gigapoint.io import expand_paths

    tiles = tmp_path / "tiles"
    write_tiles(tiles, 3)
    write_tiles(tiles / "sub" / "deeper", 1, points=20, suffix=".las")
    write_tiles(tiles / "sub", 2, points=10, suffix=".las")
    (tiles / "tile_00_00.laz").rename(tiles / "scan[1].laz")  # a real file named with glob characters
    write_tiles(tmp_path / "other", 1, points=7)[0].rename(tiles / "scan1.laz")  # what scan[1].laz matches as a pattern

    def names(cloud):
        return [f.relative_to(tiles).as_posix() for f in cloud.source_files]

    cloud = gp.open(str(tiles / "*.laz"))
    assert names(cloud) == ["scan1.laz", "scan[1].laz", "tile_00_01.laz", "tile_00_02.laz"] and cloud.n_points == 157
    assert names(gp.open(tiles / "scan[1].laz")) == ["scan[1].laz"]  # the file of that name, not scan1.laz
    assert names(gp.open(str(tiles / "scan?.laz"))) == ["scan1.laz"]
    cloud = gp.open(str(tiles / "**" / "*.las"))  # ** : any depth of folders, none included
    assert names(cloud) == ["sub/deeper/tile_00_00.las", "sub/tile_00_00.las", "sub/tile_00_01.las"] and cloud.n_points == 40
    assert cloud.name == "3 files"
    missing = tiles / "*.ply"
    with pytest.raises(InputError) as caught:
        gp.open(str(missing))
    assert str(caught.value) == f"{missing}: matches no file"
    assert cli("info", missing) == (1, "", f"error: {missing}: matches no file\n")
    rc, out, _ = cli("render", tiles / "t*.laz", "-o", tmp_path / "x.png", "-W", 64, "-H", 48)
    assert rc == 0 and out == f"wrote {tmp_path / 'x.png'} (64x48, 100 points)\n"
    assert gp.convert(str(tiles / "sub" / "*.las"), tmp_path / "oct").points == 20
    with pytest.raises(InputError) as caught:  # a URL is never a pattern (not "matches no file")
        expand_paths(["ftp://host/tiles/*.laz"])
    assert str(caught.value) == "ftp://host/tiles/*.laz: only http:// and https:// URLs are read (COPC and EPT octrees)"


def test_a_glob_pattern_matching_folders_reads_each_as_a_folder_named(tmp_path, cli):
    """city/*: north and south read as folders (recursive=True: every file below each); an
    octree it matches is left out as one below a folder is; a hidden folder is not matched."""
    city = city_of_subfolders(tmp_path)
    (city / "north" / "loop").unlink()
    write_tiles(city / "south" / "deep", 1, points=5, suffix=".las")
    octree = "an octree, not read with the point files around it (open it alone)"
    pattern = str(city / "*")
    with pytest.warns(GigapointWarning) as caught:
        cloud = gp.open(pattern)
    assert [f.relative_to(city).as_posix() for f in cloud.source_files] == ["north/tile_00_00.las", "north/tile_00_01.las", "south/tile_00_00.las"]
    said = [f"{city / 'ept'}: {octree}", f"{city / 'south'}: its subfolders deep hold point files too, not read: {READ_SUBFOLDERS}"]
    assert [str(w.message) for w in caught] == said
    with pytest.warns(GigapointWarning) as caught:
        cloud = gp.open(pattern, recursive=True)
    assert [f.relative_to(city).as_posix() for f in cloud.source_files] == [
        "north/tile_00_00.las", "north/tile_00_01.las", "south/tile_00_00.las", "south/deep/tile_00_00.las"]  # fmt: skip
    assert [str(w.message) for w in caught] == [f"{city / 'ept'}: {octree}"] and cloud.n_points == 155
    rc, out, err = cli("convert", "-q", "--recursive", pattern, "-o", tmp_path / "oct")
    assert rc == 0 and out.startswith(f"{tmp_path / 'oct'}: 155 points in ") and err == f"warning: {city / 'ept'}: {octree}\n"


@pytest.mark.parametrize(
    ("where", "call"),
    [
        ("open", lambda pattern, out: gp.open(pattern)),
        ("convert", lambda pattern, out: gp.convert(pattern, out / "oct")),
        ("convert", lambda pattern, out: gp.convert(pattern, out / "c.las")),
        ("tile", lambda pattern, out: gp.tile(pattern, out / "tiles", 100)),
        ("classify_ground", lambda pattern, out: gp.classify_ground(pattern, out / "g.las")),
        ("section", lambda pattern, out: gp.section(pattern, (0, 0, 1, 1), 1)),
        ("orthophoto", lambda pattern, out: gp.orthophoto(pattern, 1.0)),
        ("volume", lambda pattern, out: gp.volume(pattern, "POLYGON ((500000 4000000, 500100 4000000, 500100 4000100, 500000 4000000))", 1)),
        ("volume", lambda pattern, out: gp.volume(pattern, "POLYGON ((0 0, 1 0, 1 1, 0 0))", 1)),  # (lon/lat-like: placed over the headers first)
        ("change", lambda pattern, out: gp.change(pattern, pattern, 1)),
    ],
    ids=["open", "convert", "convert-las", "tile", "classify-ground", "section", "orthophoto", "volume", "volume-lon-lat", "change"],
)
def test_a_pattern_matching_only_octrees_is_said_under_the_operation_with_why(tmp_path, where, call):
    """Each octree a pattern matches is skipped with a warning; where nothing else is left, every
    operation said gp.open's "open: no file given", and not why (section, orthophoto, volume and
    change, reading through gp.open, still said "open: ...")."""
    from gigapoint.errors import InputError

    for name in ("ept_a", "ept_b"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "ept.json").write_text("{}")
    with pytest.raises(InputError) as caught, pytest.warns(GigapointWarning) as warned:
        call(str(tmp_path / "ept_*"), tmp_path)
    assert str(caught.value) == f"{where}: no point file given: only octrees matched (ept_a, ept_b), not read with point files (open one alone)"
    assert [str(w.message) for w in warned] == [f"{tmp_path / o}: an octree, not read with the point files around it (open it alone)" for o in ("ept_a", "ept_b")]


def test_recursive_is_an_option_of_render_view_and_convert(tmp_path, cli, monkeypatch):
    from gigapoint.errors import InputError
    from gigapoint.viewer.server import ViewerServer

    city = city_of_subfolders(tmp_path)
    rc, out, _ = cli("render", "--recursive", city, "-o", tmp_path / "x.png", "-W", 64, "-H", 48)
    assert rc == 0 and out == f"wrote {tmp_path / 'x.png'} (64x48, 150 points)\n"
    monkeypatch.setattr(ViewerServer, "serve_forever", lambda self: None)  # (not until Ctrl+C)
    rc, _, err = cli("view", "--recursive", "--no-browser", city)
    assert rc == 0 and "gigapoint viewer: 3 files, 150 points\n" in err
    rc, out, _ = cli("convert", "-q", "--recursive", city, "-o", tmp_path / "oct")
    assert rc == 0 and out.startswith(f"{tmp_path / 'oct'}: 150 points in ")
    result = gp.convert(city, tmp_path / "oct2", recursive=True)
    assert result.points == 150
    with pytest.raises(InputError, match=r"^convert: recursive=True reads the subfolders of folders; the inputs are a cloud or PointChunks$"):
        gp.convert(gp.open(city / "south"), tmp_path / "oct3", recursive=True)


def test_recursive_leaves_out_an_octree_beside_the_tiles_whatever_was_imported_first(tmp_path):
    """A conversion's output beside its tiles was left out of a recursive read only once
    gigapoint.lod was imported (lod/reader.py registered its octree test then): ``render
    --recursive`` and io.with_subfolders read its .npy arrays as points. In a fresh process."""
    import os
    import subprocess
    import sys

    city = city_of_subfolders(tmp_path)
    gp.convert(city / "south", city / "octree")
    read = (
        "import sys; from pathlib import Path; from gigapoint.io import with_subfolders; "
        "assert 'gigapoint.lod' not in sys.modules; city = Path(sys.argv[1]); "
        "print(*[f.relative_to(city).as_posix() for f in with_subfolders([city])])"
    )
    src = str(Path(gp.__file__).parents[1])
    done = subprocess.run([sys.executable, "-c", read, city], capture_output=True, text=True, env={**os.environ, "PYTHONPATH": src})
    assert done.returncode == 0, done.stderr
    assert done.stdout == "north/tile_00_00.las north/tile_00_01.las south/tile_00_00.las\n"
    skipped = [line.split(" GigapointWarning: ")[1] for line in done.stderr.splitlines() if " GigapointWarning: " in line]
    assert skipped == [f"{city / o}: an octree, not read with the point files around it (open it alone)" for o in ("ept", "octree")]


def test_a_folder_with_its_own_tiles_and_subfolders_of_tiles_warns_once_that_they_are_not_read(tmp_path, cli):
    """Tiles beside raw/ and classified/ copies of them: only the folder's own are read (the
    copies would double every point), but the subfolders were passed over without a word."""
    write_tiles(tmp_path, 2, suffix=".las")
    write_tiles(tmp_path / "raw", 2, suffix=".las")
    write_tiles(tmp_path / "classified", 2, suffix=".las")
    said = (f"{tmp_path}: its subfolders classified, raw hold point files too, not read: read every file below it "
            f"with --recursive (recursive=True in Python), or name them")  # fmt: skip
    with pytest.warns(GigapointWarning) as caught:
        cloud = gp.open(tmp_path)
    assert cloud.n_points == 100 and [str(w.message) for w in caught] == [said]
    rc, _, err = cli("render", tmp_path, "-o", tmp_path / "x.png", "-W", 64, "-H", 48)
    assert rc == 0 and err == f"warning: {said}\n"


def test_a_subfolder_that_cannot_be_listed_stops_only_a_recursive_read(tmp_path, monkeypatch):
    """A folder's own tiles are read whatever its subfolders are (a root-owned lost+found); with
    recursive=True a subfolder that cannot be listed is a one-line error naming it."""
    from gigapoint.errors import InputError

    write_tiles(tmp_path, 2, suffix=".las")
    (tmp_path / "lost+found").mkdir()
    listing = Path.iterdir

    def iterdir(self):
        if self.name == "lost+found":
            raise PermissionError(13, "Permission denied")
        return listing(self)

    monkeypatch.setattr(Path, "iterdir", iterdir)
    assert gp.open(tmp_path).n_points == 100
    with pytest.raises(InputError) as caught:
        gp.open(tmp_path, recursive=True)
    assert str(caught.value) == f"{tmp_path / 'lost+found'}: cannot list the folder (Permission denied)"


def test_view_refuses_recursive_without_paths(cli, monkeypatch):
    """``view --demo N --recursive`` dropped the option without a word (as --live and --replay did)."""
    from gigapoint.viewer.server import ViewerServer

    monkeypatch.setattr(ViewerServer, "serve_forever", lambda self: None)  # (without the check: not until Ctrl+C)
    said = "error: --recursive: reads the subfolders of the folders given as PATH...; none is given\n"
    assert cli("view", "--recursive", "--no-browser", "--demo", 1000) == (1, "", said)


def test_a_glob_pattern_matching_one_octree_opens_it(tmp_path, cli):
    """"out/city*" matching a converted octree alone: the octree, as when named (the point files'
    expansion leaves octrees out: it was "open: no file given"); among tiles it is still left out."""
    tiles = write_tiles(tmp_path / "tiles", 2, points=20, suffix=".las")
    result = gp.convert(tiles, tmp_path / "out" / "city_octree")
    cloud = gp.open(str(tmp_path / "out" / "city*"))
    assert type(cloud).__name__ != "PointCloud" and cloud.n_points == result.points == 40
    rc, out, err = cli("render", str(tmp_path / "out" / "city*"), "-o", tmp_path / "x.png", "-W", 64, "-H", 48)
    assert rc == 0 and out.startswith(f"wrote {tmp_path / 'x.png'} (64x48, ") and err == ""


def test_info_of_a_glob_pattern_of_many_tiles_sums_them_up_as_a_folders(cli, tmp_path):
    """``gigapoint info "tiles/*.laz"`` printed a block a tile where ``gigapoint info tiles/`` sums
    them up in one: a pattern names a folder's files (--each: a block a file; --json: one object)."""
    write_tiles(tmp_path / "tiles", 12)
    (tmp_path / "tiles" / "notes.csv").write_text("x,y,z\n1,2,3\n")  # not matched
    pattern = str(tmp_path / "tiles" / "*.laz")
    rc, out, err = cli("info", pattern)
    lines = out.splitlines()
    assert (rc, err, out.count("points:")) == (0, "", 1)
    assert lines[0] == f"{pattern} (12 files)" and "  points:      600" in lines
    rc, out, _ = cli("info", "--json", pattern)
    [summed] = map(json.loads, out.splitlines())
    assert {k: summed[k] for k in ("path", "files", "point_count", "format")} == {"path": pattern, "files": 12, "point_count": 600, "format": "LAZ"}
    rc, out, _ = cli("info", "--each", pattern)
    assert rc == 0 and out.count("points:") == 12
    rc, out, _ = cli("info", "--json", "--each", pattern)
    assert [json.loads(line)["point_count"] for line in out.splitlines()] == [50] * 12
    rc, out, _ = cli("info", "--json", str(tmp_path / "tiles" / "tile_00_0[12].laz"))  # a few: a block a file, as a folder's few
    assert [json.loads(line)["path"] for line in out.splitlines()] == [str(tmp_path / "tiles" / f"tile_00_0{i}.laz") for i in (1, 2)]
    rc, out, _ = cli("info", "--stats", "--json", str(tmp_path / "tiles" / "tile_00_0[12].laz"))  # --stats: summed, as any folder's
    [summed] = map(json.loads, out.splitlines())
    assert (rc, summed["path"], summed["files"], summed["point_count"]) == (0, str(tmp_path / "tiles" / "tile_00_0[12].laz"), 2, 100)


def test_a_glob_pattern_is_matched_once_an_operation(tmp_path, monkeypatch):
    """gp.open's steps and convert's expand the paths again each; a pattern was globbed by each
    (a "**" walks a whole tree): once an operation now, as a folder's listing is."""
    import glob as glob_module

    write_tiles(tmp_path / "tiles", 12, points=20, suffix=".las")
    calls, real = [], glob_module.glob

    def counting(pattern, **kwargs):
        calls.append(pattern)
        return real(pattern, **kwargs)

    monkeypatch.setattr(glob_module, "glob", counting)
    pattern = str(tmp_path / "tiles" / "*.las")
    assert gp.open(pattern, progressive=True).wait(timeout=60)
    assert calls == [pattern]
    calls.clear()
    assert gp.convert(pattern, tmp_path / "oct").points == 240
    assert calls == [pattern]
