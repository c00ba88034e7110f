"""Cross-sections (survey/section.py, `gigapoint section`): the corridor's points as distances along
the line, offsets and heights, checked against a hand-built scene (a sloped plane and a wall), on
a line along x and the same scene turned 30 degrees; the image's pixels where the profile is;
autzen_trim.laz across; bad values one line before reading."""

from __future__ import annotations

import math
from pathlib import Path

import laspy
import numpy as np
import pytest
from PIL import Image

import gigapoint as gp
from gigapoint.errors import EmptyCloudError, InputError
from gigapoint.io.filters import PointFilter
from gigapoint.survey.section import BORDER

# the line (-0.25, 0) -> (70.25, 0), a corridor 5 wide: |y| <= 2.5, x in -0.25..70.25. Distances
# (x + 0.25) and heights lie a quarter unit from every half unit: at 2 pixels a unit, mid-pixel
LINE, WIDTH = (-0.25, 0.0, 70.25, 0.0), 5.0
ORIGIN = np.array([637_000.0, 851_000.0, 0.0])  # a projected CRS's size of numbers
TURN = math.radians(30)


def scene() -> tuple[np.ndarray, np.ndarray]:
    """(xyz, classification): a plane rising 0.25 a unit of x (class 2), x -4..80 step 2, y -6..6,
    and a wall (class 6) x 40..42 step 0.5, y -4..4, z 111.25..125.25 on it (above the plane's top)."""
    x, y = np.meshgrid(np.arange(-4.0, 81.0, 2.0), np.arange(-6.0, 7.0))
    plane = np.column_stack([x.ravel(), y.ravel(), 100.25 + 0.25 * x.ravel()])
    wx, wy, wz = np.meshgrid(np.arange(40.0, 42.1, 0.5), np.arange(-4.0, 5.0), np.arange(111.25, 125.3, 0.5))
    wall = np.column_stack([wx.ravel(), wy.ravel(), wz.ravel()])
    return np.concatenate([plane, wall]), np.repeat([2, 6], [len(plane), len(wall)]).astype(np.uint8)


def in_corridor(xyz: np.ndarray) -> np.ndarray:
    """The scene's points the corridor holds, by hand: |y| <= 2.5 and x between the line's ends."""
    return (np.abs(xyz[:, 1]) <= 2.5) & (xyz[:, 0] >= -0.25) & (xyz[:, 0] <= 70.25)


def turned(xy: np.ndarray) -> np.ndarray:
    """``xy`` turned 30 degrees about (0, 0), then moved to ORIGIN."""
    c, s = math.cos(TURN), math.sin(TURN)
    return np.column_stack([c * xy[:, 0] - s * xy[:, 1], s * xy[:, 0] + c * xy[:, 1]]) + ORIGIN[:2]


def write_las(path, xyz, classification):
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.scales, header.offsets = [0.0001] * 3, [float(ORIGIN[0]), float(ORIGIN[1]), 0.0]
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.classification = classification
    las.write(str(path))
    return path


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """The scene as LAS files: along x at ORIGIN ("straight"), and turned 30 degrees ("diagonal")."""
    xyz, classification = scene()
    folder = tmp_path_factory.mktemp("section")
    straight = write_las(folder / "straight.las", xyz + ORIGIN, classification)
    diagonal = write_las(folder / "diagonal.las", np.column_stack([turned(xyz[:, :2]), xyz[:, 2]]), classification)
    return {"straight": straight, "diagonal": diagonal}


def line_of(kind: str) -> tuple[float, float, float, float]:
    ends = np.array([LINE[:2], LINE[2:]])
    ends = ends + ORIGIN[:2] if kind == "straight" else turned(ends)
    return tuple(ends.ravel().tolist())


def expected_rows(classes=None) -> np.ndarray:
    """(distance, offset, z, classification) of the corridor's points, by hand, in ``sorted_rows``' order."""
    xyz, classification = scene()
    keep = in_corridor(xyz) & (np.isin(classification, classes) if classes else True)
    return sorted_rows(np.column_stack([xyz[keep, 0] + 0.25, xyz[keep, 1], xyz[keep, 2], classification[keep]]))


def sorted_rows(rows: np.ndarray) -> np.ndarray:
    """``rows`` by distance, then offset, z (ties of distance in any order), each rounded to 0.01
    for the order (the turned file's distances differ from the hand-made ones by ~1e-5)."""
    return rows[np.lexsort(np.round(rows, 2)[:, ::-1].T)]


@pytest.mark.parametrize("kind", ["straight", "diagonal"])
def test_section_gives_the_corridors_points_as_distance_offset_and_height(files, kind):
    cut = gp.section(files[kind], line_of(kind), WIDTH)
    want = expected_rows()
    assert cut.cloud.n_points == len(want) == 36 * 5 + 5 * 5 * 29  # the plane's x 0..70 and the wall, at y -2..2
    assert np.all(np.diff(cut.distance) >= 0)  # by distance
    got = sorted_rows(np.column_stack([cut.distance, cut.offset, cut.z, cut.classification]))
    np.testing.assert_allclose(got, want, rtol=0, atol=2e-4)  # (the file's 0.0001 grid, turned)


def test_the_csv_holds_the_rows_and_the_command_says_what_it_wrote(cli, files, tmp_path):
    png, csv = tmp_path / "img" / "wall.png", tmp_path / "rows" / "sub" / "wall.csv"  # their folders made on the way
    line = ",".join(f"{v:.15g}" for v in line_of("diagonal"))
    rc, out, err = cli("section", files["diagonal"], "--line", line, "--width", WIDTH, "-o", png, "--csv", csv, "--scale", 2)
    assert rc == 0, err
    n = len(expected_rows())
    width, height = Image.open(png).size
    assert out == f"wrote {png} ({width}x{height}, {n:,} points in the corridor, a pixel 0.5 units a side)\nwrote {csv} ({n:,} rows)\n"
    lines = csv.read_text().splitlines()
    assert lines[0] == "distance_along,offset,z,classification"
    table = np.loadtxt(csv, delimiter=",", skiprows=1)
    assert np.all(np.diff(table[:, 0]) >= 0)
    np.testing.assert_allclose(sorted_rows(table), expected_rows(), rtol=0, atol=2e-4)


@pytest.mark.parametrize("suffix", [".jpg", ".png"])
def test_a_see_through_background_in_a_jpeg_is_warned_as_render_warns_it(cli, files, tmp_path, suffix):
    """section -o s.jpg --background '#ff000080' wrote it opaque without the word render says."""
    out = tmp_path / f"s{suffix}"
    line = ",".join(f"{v:.15g}" for v in line_of("straight"))
    rc, _, err = cli("section", files["straight"], "--line", line, "--width", WIDTH, "-o", out, "--scale", 2, "--background", "#ff000080")
    assert rc == 0
    warned = f"warning: {out}: a JPG file holds no alpha: the background's alpha 128 is written opaque\n"
    assert err == (warned if suffix == ".jpg" else "")
    assert Image.open(out).mode == ("RGB" if suffix == ".jpg" else "RGBA")
    if suffix == ".png":
        assert np.asarray(Image.open(out))[0, 0].tolist() == [255, 0, 0, 128]  # (a PNG keeps it)


def test_write_csv_replaces_a_file_only_with_overwrite(files, tmp_path):
    """Section.write_csv replaced an existing file silently, where every other writer refuses
    without overwrite=True (the CLI checked --overwrite itself)."""
    cut = gp.section(files["straight"], line_of("straight"), WIDTH)
    mine = tmp_path / "mine.csv"
    mine.write_text("my survey notes\n")
    with pytest.raises(gp.GigapointError) as error:
        cut.write_csv(mine)
    assert str(error.value) == f"{mine}: already exists; pass overwrite=True to replace it"
    assert mine.read_text() == "my survey notes\n"
    cut.write_csv(mine, overwrite=True)
    assert mine.read_text().splitlines()[0] == "distance_along,offset,z,classification"


def test_write_csv_writes_rows_under_any_name(files, tmp_path):
    """write_csv refused any suffix but .csv ("unsupported output type '.txt'"), where rows.txt
    was written before; the CLI's --csv asks for a .csv itself."""
    cut = gp.section(files["straight"], line_of("straight"), WIDTH)
    cut.write_csv(tmp_path / "mine.csv")
    for name in ("rows.txt", "rows"):
        cut.write_csv(tmp_path / name)
        assert (tmp_path / name).read_text() == (tmp_path / "mine.csv").read_text()


@pytest.mark.parametrize("kind", ["straight", "diagonal"])
def test_the_image_draws_the_profile_where_distances_and_heights_put_it(files, kind):
    """At 2 pixels a unit, column floor(2 * distance) + BORDER and row floor(2 * (top - z)) (top:
    the highest point's half unit above, and a border pixel): each point's own pixel, nothing else."""
    cut = gp.section(files[kind], line_of(kind), WIDTH)
    frame = cut.render_frame(scale=2, size_mode="fixed")
    rows = expected_rows()
    top = (math.ceil(2 * rows[:, 2].max()) + BORDER) / 2
    want = {(int(r), int(c)) for r, c in zip(np.floor(2 * (top - rows[:, 2])), np.floor(2 * rows[:, 0]) + BORDER)}
    drawn = set(zip(*np.nonzero(frame.index >= 0)))
    assert drawn == want
    # the whole line across (70.5 units: 70.49999999 turned), heights 100.25..125.25 up, and a border
    assert cut.length == pytest.approx(70.5, abs=1e-6)
    assert frame.image.shape[:2] == (math.ceil(2 * 125.25) - math.floor(2 * 100.25) + 1 + 2 * BORDER, math.floor(2 * cut.length) + 1 + 2 * BORDER)
    # above the plane's top (117.75) only the wall: the columns of distances 40.25..42.25
    assert {c for r, c in drawn if r <= 2 * (top - 118.25)} == set(range(80 + BORDER, 85 + BORDER))
    assert min(r for r, c in drawn) == BORDER == int(2 * (top - 125.25))  # its top in the first row under the border
    # equal scale: the wall is 2 units wide (5 columns of half units), 14 high over the plane's 110.25 at x 40 (29 rows)
    assert len({r for r, c in drawn if c == 80 + BORDER and r <= 2 * (top - 111.25)}) == 29


def test_vertical_exaggeration_stretches_heights_only(files):
    cut = gp.section(files["straight"], line_of("straight"), WIDTH)
    plain, tall = cut.camera(scale=2), cut.camera(scale=2, vertical_exaggeration=3)
    assert tall.width == plain.width
    # heights 100.25..125.25 (25 units: 50 rows and a pixel of rounding), 300.75..375.75 at 3x
    assert (plain.height, tall.height) == (51 + 1 + 2 * BORDER, 151 + 1 + 2 * BORDER)
    frame = cut.render_frame(scale=2, vertical_exaggeration=3, size_mode="fixed")
    drawn = np.nonzero(frame.index >= 0)
    assert (np.ptp(drawn[0]), np.ptp(drawn[1])) == (150, 140)  # 75 units up, 70 across, at 2 pixels a unit


def test_a_size_fits_the_section_with_one_scale_on_both_axes(files):
    cut = gp.section(files["straight"], line_of("straight"), WIDTH)
    cam = cut.camera(size=(300, 300))
    assert (cam.width, cam.height) == (300, 300)
    pixel = cam.ortho_height / cam.height
    assert pixel == pytest.approx(70.5 / (300 - 2 * BORDER - 1), rel=1e-6)  # the line's length fills the width
    right, up, _ = cam.basis()
    np.testing.assert_allclose(right, (1, 0, 0), atol=1e-12)  # the line's start on the left, +z up
    np.testing.assert_allclose(up, (0, 0, 1), atol=1e-12)


def test_a_cloud_in_memory_and_classes(files):
    cloud = gp.open(files["straight"])
    cut = gp.section(cloud, line_of("straight"), WIDTH, classes=[6])
    got = sorted_rows(np.column_stack([cut.distance, cut.offset, cut.z, cut.classification]))
    np.testing.assert_allclose(got, expected_rows(classes=[6]), rtol=0, atol=2e-4)


@pytest.mark.timeout(600)  # a deadlock guard: the load's kernels compile in its thread, minutes on a cold cache under load
def test_the_corridor_filter_reads_only_its_points_on_every_path(files):
    xyz, _ = scene()
    corridor = (*line_of("straight"), WIDTH)
    want = np.count_nonzero(in_corridor(xyz))
    assert gp.open(files["straight"], corridor=corridor).n_points == want
    assert gp.open(files["straight"], corridor=corridor, chunked=True).n_points == want
    progressive = gp.open(files["straight"], corridor=corridor, progressive=True)
    assert progressive.wait() and progressive.n_points == want  # (until the load ends: wait(120) failed one still compiling)
    progressive.close()
    spec = PointFilter(corridor=corridor).as_spec()  # a conversion's Dask tasks get it so
    assert PointFilter.from_spec(spec).corridor == corridor
    assert "corridor" not in PointFilter(classes=(2,)).as_spec()  # (fingerprints of conversions without one as before)


def test_autzen_across_gives_heights_within_the_files(autzen_path, cli, tmp_path):
    lo, hi = gp.open(autzen_path).bounds
    line = (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))  # corner to corner, 10 feet wide
    cut = gp.section(autzen_path, line, 10)
    assert 1000 < cut.cloud.n_points < 110_000
    assert lo[2] <= cut.z.min() < cut.z.max() <= hi[2]
    assert np.all(np.abs(cut.offset) <= 5) and 0 <= cut.distance.min() and cut.distance.max() <= math.dist(line[:2], line[2:])
    png = tmp_path / "autzen.png"
    rc, out, err = cli("section", autzen_path, "--line", ",".join(map(str, line)), "--width", 10, "-o", png, "--color-mode", "classification")
    assert rc == 0, err
    image = np.asarray(Image.open(png))
    assert image.shape[1] == 1920 and (image[..., :3] != 0).any(axis=2).sum() > 1000


def test_the_command_names_the_pixel_in_the_crs_unit_of_a_file_and_of_an_octree(autzen_path, cli, tmp_path):
    """autzen's CRS is in feet: a pixel was '0.561833 units' where change and volume say 'ft'; an
    octree's section (its nodes read, its CRS in octree.json) names them as the file's does."""
    octree = tmp_path / "oct"
    gp.convert([autzen_path], octree)
    line = ("--line", "636100,849000,637100,849400", "--width", 10)
    for source in (autzen_path, octree):
        png = tmp_path / "side.png"
        rc, out, err = cli("section", source, *line, "-o", png, "--overwrite")
        assert rc == 0, err
        assert out == f"wrote {png} (1920x109, 1,972 points in the corridor, a pixel 0.561833 ft a side)\n"
        rc, out, err = cli("section", source, *line, "-o", png, "--overwrite", "--scale", 2, "--vertical-exaggeration", 5)
        assert rc == 0, err
        assert out == f"wrote {png} (2157x597, 1,972 points in the corridor, a pixel 0.5 ft across, 0.1 ft up)\n"
    assert gp.section(octree, (636100, 849000, 637100, 849400), 10).units["horizontal"]["symbol"] == "ft"


@pytest.mark.parametrize(
    ("line", "width", "message"),
    [
        ((0, 0, 0, 0), 1, "section: line=(0, 0, 0, 0): the line's two ends are one point; it has no direction"),
        ((0, 0, 1, 1), 0, "section: width=0: the corridor's width must be a finite number above 0"),
        ((0, 0, 1, 1), -2, "section: width=-2: the corridor's width must be a finite number above 0"),
        ((0, 0, 1, math.nan), 1, "section: line=(0, 0, 1, nan): a line's ends are finite numbers"),
        ((0, 0, 1, 1), math.nan, "section: width=nan: the corridor's width must be a finite number above 0"),
        ((0, 0, 1), 1, "section: line=(0, 0, 1): a line is x1, y1, x2, y2 (its two ends)"),
        ((1e13, 0.0, 1e13, 0.0), 1, "section: line=(1e+13, 0, 1e+13, 0): a line's end lies beyond ±1e+12: no point can be there"),
    ],
)
def test_bad_values_are_one_line_errors_before_reading(tmp_path, line, width, message):
    with pytest.raises(InputError) as err:
        gp.section(tmp_path / "missing.laz", line, width)  # read first, it would be "no such file"
    assert str(err.value) == message
    with pytest.raises(InputError) as err:
        gp.open(tmp_path / "missing.laz", corridor=(*line, width))
    assert str(err.value).startswith("open: corridor=")


def test_a_corridor_without_points_names_the_files(files):
    with pytest.raises(EmptyCloudError) as err:
        gp.section(files["straight"], (0, 0, 10, 0), 2)
    assert str(err.value) == f"{files['straight']}: no point passes the filter (corridor 0, 0 to 10, 0, width 2): {len(scene()[0]):,} points read"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--line", "0,0,0,0", "--width", "2"], "error: section: --line 0,0,0,0: the line's two ends are one point; it has no direction"),
        (["--line", "0,0,1", "--width", "2"], "error: section: --line 0,0,1: give X1,Y1,X2,Y2 (the line's two ends, in the files' coordinates)"),
        (["--line", "0,0,1,x", "--width", "2"], "error: section: --line 0,0,1,x: give X1,Y1,X2,Y2 (the line's two ends, in the files' coordinates)"),
        (["--line", "0,0,1,1", "--width", "0"], "error: section: --width 0: the corridor's width must be a finite number above 0"),
        (["--line", "0,0,1,1", "--width", "nan"], "error: section: --width nan: the corridor's width must be a finite number above 0"),
        (["--line", "0,0,1,1", "--width", "1", "--size", "300"], "error: section: --size 300: give WIDTHxHEIGHT in pixels (1600x400)"),
        (["--line", "0,0,1,1", "--width", "1", "--size", "3x3"], "error: section: an image of 3x3 pixels has no room for a section; give at least 5 a side"),
        (["--line", "0,0,1,1", "--width", "1", "--scale", "2", "--size", "300x100"], "error: section: --scale and --size: give one (a size sets the scale)"),
        (["--line", "0,0,1,1", "--width", "1", "--scale", "-1"], "error: section: --scale must be a number > 0 (pixels per unit), got -1"),
        (["--line", "0,0,1,1", "--width", "1", "--vertical-exaggeration", "0"], "error: section: --vertical-exaggeration must be a number > 0, got 0"),
        (["--line", "0,0,1,1", "--width", "1", "--classes", "2,x"], "error: section: --classes 2,x: give integers from 0 to 255, separated by commas"),
        # stereo's options are section's to refuse: --ipd said it needs --stereo, which section refuses
        (["--line", "0,0,1,1", "--width", "1", "--ipd", "0.1"], "error: section: --ipd: a section is one orthographic view (no stereo)"),
        (["--line", "0,0,1,1", "--width", "1", "--convergence", "5"], "error: section: --convergence: a section is one orthographic view (no stereo)"),
        (["--line", "0,0,1,1", "--width", "1", "--stereo", "anaglyph"], "error: section: --stereo: a section is one orthographic view (no stereo)"),
    ],
)
def test_the_command_refuses_bad_values_in_one_line(cli, tmp_path, args, message):
    rc, out, err = cli("section", tmp_path / "missing.laz", "-o", tmp_path / "s.png", *args)
    assert (rc, out, err.strip()) == (1, "", message)
    assert not (tmp_path / "s.png").exists()


def test_a_corridor_thinner_than_float32_depths_draws_its_points(cli, tmp_path):
    """A corridor 1e-9 wide holds the three points on the line (a file at 0.01: batches 10.24
    units across): the eye stood 1e-9 from them, and float32 depths (~1e-7 of a batch's size
    off) put every one outside near and far (a blank image and a warning)."""
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.scales, header.offsets = [0.01] * 3, [0.0] * 3
    las = laspy.LasData(header)
    las.x, las.y, las.z = np.array([10.0, 12.0, 14.0, 16.0]), np.array([20.0, 20.0, 20.0, 21.0]), np.array([5.0, 6.0, 7.0, 8.0])
    las.classification = np.full(4, 2, np.uint8)
    las.write(str(tmp_path / "line.las"))
    png = tmp_path / "thin.png"
    rc, out, err = cli("section", tmp_path / "line.las", "--line", "9,20,17,20", "--width", 1e-9, "-o", png, "--scale", 2,
                       "--color-mode", "classification", "--size-mode", "fixed")  # fmt: skip
    assert rc == 0 and err == "", err
    assert out == f"wrote {png} (19x7, 3 points in the corridor, a pixel 0.5 units a side)\n"
    drawn = np.argwhere(np.asarray(Image.open(png))[..., :3].any(axis=2))
    # column floor(2 * distance) + BORDER; rows 2 a unit down from the border over z 7 (as a corridor 1 wide draws them)
    assert sorted(map(tuple, drawn.tolist())) == [(1, 11), (3, 7), (5, 3)]


def test_the_command_names_the_files_of_an_empty_corridor(cli, files, tmp_path):
    rc, out, err = cli("section", files["straight"], "--line", "0,0,10,0", "--width", 2, "-o", tmp_path / "s.png")
    assert rc == 1 and err.startswith(f"error: {files['straight']}: no point passes the filter (corridor 0, 0 to 10, 0, width 2)")


def test_a_cloud_in_degrees_is_refused_not_drawn_two_pixels_wide(tmp_path):
    """In WGS 84 the section drew its 0.0007 degrees along the line on the heights' scale (metres):
    a 1920 x 16,384 image, the points in its first two columns; refused in the one wording the
    surveys refuse degrees in (io.crs.refuse_angles)."""
    from test_change import write_degrees_grid  # (tests/unit is on sys.path)

    path = write_degrees_grid(tmp_path / "wgs84.las", 40, lambda x, y: 2.0 + x * 1e4)
    with pytest.raises(InputError) as caught:
        gp.section(path, (-123.0, 44.0004, -122.9993, 44.0004), 0.00004)
    assert str(caught.value) == (
        f"section: {path} has coordinates in degrees (EPSG:4326); drawing heights against distances along the line needs metres or feet: "
        "reproject first (gigapoint convert --to-crs EPSG:32610, WGS 84 / UTM zone 10N, where the data lie)"
    )


def test_degrees_are_refused_before_the_corridor_is_read(tmp_path):
    """The refusal of degrees came after the corridor's points were read, and only where it held
    some: a UTM line over a cloud in degrees was "no point passes the filter", for files, an
    opened cloud and an octree alike. The units are checked first, the CRS named."""
    from test_change import write_degrees_grid  # (tests/unit is on sys.path)

    path = write_degrees_grid(tmp_path / "wgs84.las", 40, lambda x, y: 2.0 + x * 1e4)
    copc = Path(__file__).parent / "data" / "pdal_ept" / "autzen_clip_4326.copc.laz"
    why = "has coordinates in degrees (EPSG:4326); drawing heights against distances along the line needs metres or feet: reproject first"
    wgs84 = "has coordinates in degrees (WGS 84 (EPSG:4326)); drawing heights against distances along the line needs metres or feet: reproject first"
    for source, said in ((path, f"{path} {why}"), (gp.open(path), f"wgs84.las {why}"), (copc, f"{copc} {wgs84}"), (gp.open(copc), f"autzen_clip_4326.copc.laz {wgs84}")):
        with pytest.raises(InputError) as caught:
            gp.section(source, (637000, 851000, 637500, 851500), 10)  # (in UTM metres: no point of the cloud in its corridor)
        assert str(caught.value).startswith(f"section: {said} (gigapoint convert --to-crs EPSG:32610"), source


def test_a_ply_in_degrees_is_refused_as_a_las_file_is(tmp_path):
    """A PLY file names its CRS in a ``comment crs`` line: the units check read LAS headers only,
    so the LAS file's points in degrees were refused and the same points in a PLY file drawn. A
    PLY header has no bounds: no UTM zone is offered."""
    from test_change import write_degrees_grid  # (tests/unit is on sys.path)

    ply = tmp_path / "wgs84.ply"
    gp.convert(write_degrees_grid(tmp_path / "wgs84.las", 40, lambda x, y: 2.0 + x * 1e4), ply)
    with pytest.raises(InputError) as caught:
        gp.section(ply, (-123.0, 44.0004, -122.9993, 44.0004), 0.00004)
    assert str(caught.value) == (
        f"section: {ply} has coordinates in degrees (EPSG:4326); drawing heights against distances along the line needs metres or feet: "
        "reproject first (gigapoint convert --to-crs EPSG:n of a projected CRS)"
    )


def test_a_file_named_twice_is_warned_of_once(tmp_path, recwarn):
    """gp.section expands its paths for the units, then opens them: a file named twice was warned
    of twice (each expansion said it; io.paths now says it once an operation)."""
    from test_change import write_las  # (tests/unit is on sys.path)

    rng = np.random.default_rng(0)
    path = write_las(tmp_path / "a.las", np.column_stack([rng.uniform(0, 100, 2000), rng.uniform(0, 100, 2000), rng.uniform(0, 5, 2000)]))
    gp.section([path, path], (500_000, 4_000_050, 500_100, 4_000_050), 2)
    assert [str(w.message) for w in recwarn if "named more than once" in str(w.message)] == [f"{path}: named more than once; its points are read once"]
