"""A demanding user's bad input to `convert`, `tile` and `info` (test_cli_audit_survey.py's for
the survey commands): each case is one line naming the file or option and the problem, exit 1,
and no output left behind; or, for absurd but meaningful values, the answer they mean."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from test_cli_audit_survey import files_in, refused_in_one_line, write_las  # tests/unit is on sys.path


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """small.las (2,000 points over 100 x 100, z 0..5, classes 1 and 2); its copies whose
    header's max x is 1e300 (big_bound.las) and NaN (nan_bound.las); a PNG renamed pic.laz; a
    text file with a row at 1e300 (far.xyz) and an array of them (far.npy)."""
    from PIL import Image

    folder = tmp_path_factory.mktemp("in")
    rng = np.random.default_rng(0)
    xyz = np.column_stack([rng.random((2000, 2)) * 100, rng.random(2000) * 5])
    small = write_las(folder / "small.las", xyz, np.where(rng.random(2000) < 0.5, 2, 1).astype(np.uint8))
    for name, max_x in (("big_bound.las", 1e300), ("nan_bound.las", float("nan"))):
        data = bytearray(small.read_bytes())
        struct.pack_into("<d", data, 179, max_x)  # the header's max x
        (folder / name).write_bytes(bytes(data))
    Image.fromarray(np.full((10, 10, 3), 200, np.uint8)).save(folder / "pic.laz", format="PNG")
    far = np.array([[1.0, 2.0, 3.0], [1e300, 2.0, 3.0], [4.0, 5.0, 6.0]])
    np.savetxt(folder / "far.xyz", far)
    np.save(folder / "far.npy", far)
    return folder


@pytest.fixture
def home(tmp_path):
    """A user's folder: a LAS file of 10 points and notes."""
    folder = tmp_path / "home"
    folder.mkdir()
    write_las(folder / "a.las", np.column_stack([np.arange(10.0), np.arange(10.0), np.zeros(10)]))
    (folder / "notes.txt").write_text("my notes\n")
    return folder


@pytest.mark.parametrize(
    ("args", "problem"),
    [
        # a header's bound at 1e300: info's 300-digit extent; tile's "100,000,...,017 x 10 tiles"
        (["info", "{in}/big_bound.las"], "{in}/big_bound.las: corrupt LAS header: absurd max x 1e+300 (its records reach -2.14748e+07..2.14748e+07)"),
        (["tile", "{in}/big_bound.las", "-o", "{out}/t", "--size", "10"],
         "{in}/big_bound.las: corrupt LAS header: absurd max x 1e+300 (its records reach -2.14748e+07..2.14748e+07)"),
        # at NaN: convert -o x.las made its LAS grid of it: "out/o.las: x 63.7 lies beyond the LAS grid (scale nan, offset nan)"
        (["convert", "{in}/nan_bound.las", "-o", "{out}/o.las"], "{in}/nan_bound.las: corrupt LAS header: absurd max x nan (its records reach -2.14748e+07..2.14748e+07)"),
        # tile named its hidden work folder: "out/t/.nan_bound.x1y2.tiling/nan_bound_0_0.laz: x 4.1 lies beyond the LAS grid"
        (["tile", "{in}/nan_bound.las", "-o", "{out}/t", "--size", "10"],
         "{in}/nan_bound.las: corrupt LAS header: absurd max x nan (its records reach -2.14748e+07..2.14748e+07)"),
        # a PNG given as the clip polygon: "cannot be read as a clip polygon (UnicodeDecodeError)"
        (["convert", "{in}/small.las", "-o", "{out}/o.las", "--clip-polygon", "{in}/pic.laz"],
         "{in}/pic.laz: not a text file: neither GeoJSON nor WKT (POLYGON, MULTIPOLYGON): not a clip polygon"),
        # (said well before: pinned)
        (["convert", "{in}/pic.laz", "-o", "{out}/o"], "{in}/pic.laz: not a LAS/LAZ file (starts with b'\\x89PNG', expected b'LASF')"),
        (["convert", "{in}/small.las", "-o", "{out}/o.las", "--thin", "nan"], "convert: --thin nan: the cells' edge is a number above 0, in the cloud's units"),
        # (numpy's "warning: overflow encountered in divide" came first)
        (["convert", "{in}/small.las", "-o", "{out}/o.las", "--thin", "5e-324"],
         "convert: --thin 5e-324: cells too small for the data's extent ({in}/small.las: cells 0 to inf from the origin)"),
        (["convert", "{in}/small.las", "-o", "{out}/o", "--workers", "0"], "--workers: needs at least 1 worker, got 0"),
        (["convert", "{in}/small.las", "-o", "{out}/o.las", "--clip", "10,10,5,5"], "convert: --clip 10,10,5,5: xmin 10 is above xmax 5"),
        (["convert", "{in}/small.las", "-o", "{out}/o.las", "--classes", "999"], "convert: --classes 999: class numbers are integers from 0 to 255 (LAS classes), got 999"),
        (["tile", "{in}/small.las", "-o", "{out}/t", "--size", "nan"], "tile: --size nan: a tile's edge is a number above 0, in the files' units"),
        (["tile", "{in}/small.las", "-o", "{out}/t", "--size", "1e-12"],
         "tile: --size 1e-12: 99,920,000,000,001 x 99,940,000,000,001 tiles over the extent of {in}/small.las, above 1,000,000; take larger tiles"),
        # a subnormal size overflowed the division: numpy's warning, then "internal error: OverflowError"
        (["tile", "{in}/small.las", "-o", "{out}/t", "--size", "5e-324"], "tile: --size 4.94066e-324: inf x inf tiles over the extent of {in}/small.las, above 1,000,000; take larger tiles"),
    ],
    ids=["info-bound-1e300", "tile-bound-1e300", "convert-bound-nan", "tile-bound-nan", "convert-polygon-png",
         "convert-png-as-laz", "convert-thin-nan", "convert-thin-5e-324", "convert-workers-0", "convert-clip-inverted", "convert-classes-999", "tile-size-nan", "tile-size-1e-12",
         "tile-size-5e-324"],
)  # fmt: skip
def test_bad_input_is_one_line_and_leaves_no_output(cli, inputs, tmp_path, args, problem):
    refused_in_one_line(cli, inputs, tmp_path, args, problem)


@pytest.mark.parametrize("name", ["far.xyz", "far.npy"])
def test_info_bounds_leave_out_a_point_beyond_reach(cli, inputs, name):
    """A row at 1e300 (an invalid point: every read skips it) was info's bounds: a 300-digit max
    and extent; NaN rows were left out already."""
    rc, stdout, err = cli("info", inputs / name)
    assert (rc, err) == (0, ""), err
    lines = stdout.splitlines()
    assert lines[2:6] == ["  points:      3", "  bounds min:  1.000, 2.000, 3.000", "  bounds max:  4.000, 5.000, 6.000", "  extent:      3.000, 3.000, 3.000"]


def test_tile_refuses_to_write_into_an_input_folder(cli, home):
    """`tile home -o home --overwrite` wrote its tiles among the files it read (the next run read
    them as input points, and replaced those of the same names)."""
    rc, stdout, err = cli("tile", home, "-o", home, "--size", "50", "--overwrite")
    assert (rc, stdout, err) == (1, "", f"error: {home}: is one of the inputs; write it elsewhere (it would replace the points being read)\n")
    assert files_in(home) == ["a.las", "notes.txt"]


def test_tile_refuses_a_folder_inside_one_read_recursively(cli, home):
    """`tile home -o home/tiles --recursive`, run twice, read the first run's tiles as input: every
    point twice (and --overwrite replaced files it was reading)."""
    rc, stdout, err = cli("tile", home, "-o", home / "tiles", "--size", "50", "--recursive")
    assert (rc, stdout) == (1, "")
    assert err == f"error: {home / 'tiles'}: lies in {home}, read with --recursive; write the tiles elsewhere (the next run would read them as input points)\n"
    assert files_in(home) == ["a.las", "notes.txt"]


def test_overwrite_never_clears_a_folder_that_is_no_octree(cli, inputs, home):
    """(pinned) --overwrite pointed at a user's folder of other files refuses; nothing is removed."""
    rc, stdout, err = cli("convert", inputs / "small.las", "-o", home, "--overwrite")
    assert (rc, stdout, err) == (1, "", f"error: {home}: directory is not empty and is not a gigapoint/Potree output; refusing to write into it\n")
    assert files_in(home) == ["a.las", "notes.txt"]


def test_gp_tile_refuses_an_input_folder_as_the_command_does(home):
    """The check is the library's (gp.tile), said for Python there, for the command by its options."""
    import gigapoint as gp
    from gigapoint.errors import InputError

    with pytest.raises(InputError, match=r"lies in .*, read with recursive=True; write the tiles elsewhere"):
        gp.tile(home, home / "tiles", size=50, recursive=True)
    assert files_in(home) == ["a.las", "notes.txt"]


def test_dask_missing_is_said_as_the_options(cli, inputs, tmp_path, monkeypatch):
    """The library says ``client: ...`` (convert's keyword): the CLI the options typed, as before."""
    import sys

    monkeypatch.setitem(sys.modules, "distributed", None)  # (import distributed: an ImportError)
    rc, _, err = cli("convert", inputs / "small.las", "-o", tmp_path / "o", "--workers", "2", "-q")
    assert (rc, err) == (1, "error: --dask/--workers: a distributed conversion needs Dask: pip install 'gigapoint[dask]'\n")
    assert not (tmp_path / "o").exists()
