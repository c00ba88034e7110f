"""A demanding user's bad input to the survey commands (`classify`, `change`, `volume`, `section`)
and the options --clip-polygon, --to-crs/--from-crs, --colorize of convert and tile: each case is
one line naming the file or option and the problem, exit 1, and no output left behind; or, for
absurd but meaningful values, the answer they mean (not a traceback, a hang or a blank image)."""

from __future__ import annotations

import json

import laspy
import numpy as np
import pytest


def write_las(path, xyz, classification=None):
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = [0.01] * 3, [0.0] * 3
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    if classification is not None:
        las.classification = classification
    las.write(str(path))
    return path


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """small.las (2,000 points over 100 x 100, z 0..5, classes 1 and 2), beside.las (its points
    1,000 further east), a polygon inside small.las, one
    with a vertex far beyond any point's reach, a PNG that no world file places, and the octree
    oct/ converted from small.las."""
    from PIL import Image

    from gigapoint.lod import convert

    folder = tmp_path_factory.mktemp("in")
    rng = np.random.default_rng(0)
    xyz = np.column_stack([rng.random((2000, 2)) * 100, rng.random(2000) * 5])
    write_las(folder / "small.las", xyz, np.where(rng.random(2000) < 0.5, 2, 1).astype(np.uint8))
    write_las(folder / "beside.las", xyz + (1000, 0, 0))
    square = [[10, 10], [60, 10], [60, 60], [10, 60], [10, 10]]
    (folder / "good.geojson").write_text(json.dumps({"type": "Polygon", "coordinates": [square]}))
    far = [[-1e300, -1e300], [1e300, -1e300], [1e300, 1e300], [-1e300, 1e300], [-1e300, -1e300]]
    (folder / "huge.geojson").write_text(json.dumps({"type": "Polygon", "coordinates": [far]}))
    Image.fromarray(np.full((10, 10, 3), 200, np.uint8)).save(folder / "plain.png")
    convert([str(folder / "small.las")], folder / "oct")
    return folder


def files_in(folder) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def refused_in_one_line(cli, inputs, tmp_path, args, problem) -> None:
    """The command ``args`` ({in}: the inputs' folder, {out}: an empty one) exits 1 saying
    ``problem`` in one line on stderr, nothing on stdout, and leaves {out} empty (the audits'
    tables: this file's, test_cli_audit_convert's, test_cli_audit_render's)."""
    out = tmp_path / "out"
    out.mkdir()
    rc, stdout, err = cli(*(a.format(**{"in": inputs, "out": out}) for a in args))
    assert (rc, stdout, err) == (1, "", f"error: {problem.format(**{'in': inputs, 'out': out})}\n")
    assert files_in(out) == []


@pytest.mark.parametrize(
    ("args", "problem"),
    [
        # a polygon vertex at 1e300: volume's grid over it was said as a 300-digit image size
        (["volume", "{in}/small.las", "--gsd", "1", "--clip-polygon", "{in}/huge.geojson", "-o", "{out}/v.tif"],
         "{in}/huge.geojson: a polygon vertex lies beyond ±1e+12 ([-1e+300, -1e+300]): no point can be there"),
        (["convert", "{in}/small.las", "-o", "{out}/c.las", "--clip-polygon", "{in}/huge.geojson"],
         "{in}/huge.geojson: a polygon vertex lies beyond ±1e+12 ([-1e+300, -1e+300]): no point can be there"),
        # the grid spans the polygon's box (not the data's): said only "gsd 0.001 makes a ... image"
        (["volume", "{in}/small.las", "--gsd", "0.001", "--clip-polygon", "{in}/good.geojson", "-o", "{out}/v.tif"],
         "{in}/good.geojson: --gsd over its box: gsd 0.001 makes a 50,006x50,006 image, over 16,384 pixels a side: a gsd of 0.00306 or more fits"),
        # surveys side by side were drawn on the grid of their union: said "gsd 0.01 makes a 109,993x9,995 image"
        (["change", "{in}/small.las", "{in}/beside.las", "--gsd", "0.01", "-o", "{out}/c.tif"],
         ("{in}/small.las and {in}/beside.las: the surveys do not overlap ({in}/small.las x 0.04..99.96, y 0.02..99.96; "
          "{in}/beside.las x 1000.04..1099.96, y 0.02..99.96): nothing to compare")),
        # a line's end at 1e300 said "camera eye and target are the same point", naming nothing
        (["section", "{in}/small.las", "--line", "0,0,1e300,1e300", "--width", "10", "-o", "{out}/s.png"],
         "section: --line 0,0,1e300,1e300: a line's end lies beyond ±1e+12: no point can be there"),
        # a width of 1e300 overflowed the camera's sums: numpy's warnings and a blank image, exit 0
        (["section", "{in}/small.las", "--line", "0,50,100,50", "--width", "1e300", "-o", "{out}/s.png"],
         "section: --width 1e+300: the corridor's width must be at most 2e+12, the span points can have"),
        # said "give to_crs too": the library's keyword, not the option
        (["convert", "{in}/small.las", "-o", "{out}/c.las", "--from-crs", "EPSG:32610"],
         "convert: --from-crs EPSG:32610: the CRS the inputs are in, for --to-crs; give --to-crs too"),
        (["tile", "{in}/small.las", "-o", "{out}/tiles", "--size", "10", "--from-crs", "EPSG:32610"],
         "tile: --from-crs EPSG:32610: the CRS the inputs are in, for --to-crs; give --to-crs too"),
        # an octree folder's arrays were read as point files: "oct/crc.npy: NPY array: expected an (N, 3) ... array"
        (["classify", "{in}/oct", "-o", "{out}/c.las", "--ground"], "{in}/oct: is a converted octree (or a conversion in progress), not an input point cloud"),
        (["classify", "{in}/oct", "-o", "{out}/c.las", "--noise"], "{in}/oct: is a converted octree (or a conversion in progress), not an input point cloud"),
        (["tile", "{in}/oct", "-o", "{out}/tiles", "--size", "10"], "{in}/oct: is a converted octree (or a conversion in progress), not an input point cloud"),
        (["convert", "{in}/oct", "-o", "{out}/c.las"], "{in}/oct: is a converted octree (or a conversion in progress), not an input point cloud"),
        # named the library's function ("classify_noise writes ...") for the command's output
        (["classify", "{in}/small.las", "-o", "{out}/c.txt", "--noise"], "{out}/c.txt: classify writes a .las, .laz or .ply file"),
        (["classify", "{in}/small.las", "-o", "{out}/c.txt", "--ground"], "{out}/c.txt: classify writes a .las, .laz or .ply file"),
        (["classify", "{in}/small.las", "-o", "{out}/c.txt", "--height-above-ground"], "{out}/c.txt: classify writes a .las, .laz or .ply file"),
        # a subnormal cell overflowed the raster's division: numpy's warning, then "internal error: OverflowError"
        (["classify", "{in}/small.las", "-o", "{out}/c.las", "--ground", "--cell", "5e-324"],
         "{in}/small.las: cells of 4.94066e-324 make a inf x inf raster over the files' extent, more than 120,000,000 cells: give a larger cell, or classify tiles of it (gigapoint tile)"),
    ],
    ids=["volume-polygon-1e300", "convert-polygon-1e300", "volume-gsd-over-polygon-box", "change-apart", "section-line-1e300", "section-width-1e300",
         "convert-from-crs-alone", "tile-from-crs-alone", "classify-ground-octree", "classify-noise-octree", "tile-octree", "convert-octree",
         "classify-noise-txt", "classify-ground-txt", "classify-heights-txt", "classify-ground-cell-5e-324"],
)  # fmt: skip
def test_bad_input_is_one_line_and_leaves_no_output(cli, inputs, tmp_path, args, problem):
    refused_in_one_line(cli, inputs, tmp_path, args, problem)


@pytest.mark.parametrize("command", [["convert", "-o", "{out}/c.las"], ["tile", "-o", "{out}/tiles", "--size", "10"]], ids=["convert", "tile"])
@pytest.mark.parametrize("bad", [["--to-crs", "EPSG:999999"], ["--to-crs", "EPSG:32610", "--from-crs", "EPSG:999999"]], ids=["to-crs", "from-crs"])
def test_a_crs_proj_does_not_know_is_said_as_its_option(cli, inputs, tmp_path, command, bad):
    """The library says ``convert: to_crs='EPSG:999999': ...`` (its keyword); the command the option
    typed, ``convert: --to-crs EPSG:999999: ...``, in one line, leaving nothing behind."""
    pytest.importorskip("pyproj")
    out = tmp_path / "out"
    out.mkdir()
    rc, stdout, err = cli(command[0], inputs / "small.las", *(a.format(out=out) for a in command[1:]), *bad)
    assert (rc, stdout) == (1, "")
    assert err.startswith(f"error: {command[0]}: {bad[-2]} EPSG:999999: not a CRS PROJ knows (") and len(err.splitlines()) == 1, err
    assert files_in(out) == []


def test_colorize_refuses_a_raster_no_world_file_places(cli, inputs, tmp_path):
    """A PNG without a world file was read with GDAL's stand-in transform: each point coloured by
    the pixel whose row and column were its coordinates, exit 0."""
    pytest.importorskip("rasterio")
    for command in (["convert", inputs / "small.las", "-o", tmp_path / "c.las"], ["tile", inputs / "small.las", "-o", tmp_path / "tiles", "--size", "10"]):
        rc, stdout, err = cli(*command, "--colorize", inputs / "plain.png")
        assert (rc, stdout) == (1, "")  # (before it: rasterio's own warning that the raster has no geotransform)
        assert err.splitlines()[-1] == f"error: {inputs / 'plain.png'}: not georeferenced (no geotransform, nor a world file beside it): colorize needs to know where its pixels lie"
    assert files_in(tmp_path) == []


def test_an_absurd_isolated_count_makes_every_point_noise(cli, inputs, tmp_path):
    """--isolated 1e20 (more than any block holds: every point isolated) overflowed the kernel's
    int64: a 16-line numba typing error, exit 2."""
    out = tmp_path / "n.las"
    rc, stdout, err = cli("classify", inputs / "small.las", "-o", out, "--noise", "--isolated", "99999999999999999999")
    assert (rc, err) == (0, ""), err
    assert stdout.startswith(f"{out}: 2,000 points, 2,000 isolated found noise (7); ")
    assert (laspy.read(out).classification == 7).all()


def test_a_window_wider_than_the_data_opens_no_more_than_the_raster(cli, inputs, tmp_path, monkeypatch):
    """--window 1e12 ran 3e11 openings of a 100 x 100 raster (a hang): a diamond as wide as the
    raster's rows + columns covers it from any cell, larger ones open it alike."""
    from gigapoint.survey import ground

    radii = []
    opened = ground._opened

    def counted(surface, radius):
        radii.append(radius)
        assert len(radii) <= 1_000, "more openings than the raster has rows + columns"
        return opened(surface, radius)

    monkeypatch.setattr(ground, "_opened", counted)
    out = tmp_path / "g.las"
    rc, stdout, err = cli("classify", inputs / "small.las", "-o", out, "--ground", "--cell", "5", "--window", "1e12")
    assert (rc, err) == (0, ""), err
    assert "window 1e+12" in stdout
    assert max(radii) == 20 + 20  # (the 20 x 20 cells of 5 over 100 x 100: radius 1 of the low outliers' pass, then 1..40)
    assert set(np.unique(laspy.read(out).classification)) <= {1, 2}


def test_a_section_of_one_point_says_one_point(cli, tmp_path):
    """'1 points in the corridor', '(1 rows)'."""
    path = write_las(tmp_path / "one.las", np.array([[5.0, 0.0, 1.0], [5.0, 10.0, 1.0]]))
    rc, stdout, err = cli("section", path, "--line", "0,0,10,0", "--width", "2", "-o", tmp_path / "s.png", "--csv", tmp_path / "s.csv")
    assert (rc, err) == (0, ""), err
    assert " 1 point in the corridor, " in stdout and f"wrote {tmp_path / 's.csv'} (1 row)\n" in stdout


def test_a_pile_on_an_elevation_says_an(cli, inputs):
    """'2.990 units above a elevation base'."""
    rc, stdout, err = cli("volume", inputs / "small.las", "--gsd", "1", "--clip-polygon", inputs / "good.geojson", "--base", "0")
    assert (rc, err) == (0, ""), err
    assert " units above an elevation base (mean z 0.000)\n" in stdout
