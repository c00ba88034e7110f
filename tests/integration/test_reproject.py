"""``convert -o out.laz --to-crs`` / ``tile --to-crs`` (io/reproject.py): every point moved as
pyproj moves it, onto a grid of the source's precision in the new units, the output naming the
target CRS; bad CRSs and files naming none refused in one line before a point is read."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import laspy
import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import GigapointWarning, InputError
from gigapoint.io import files_crs
from gigapoint.io.crs import crs_identity
from gigapoint.io.las import read_las_header
from gigapoint.io.reproject import Reprojection, output_grid

pyproj = pytest.importorskip("pyproj")

UTM = "EPSG:32610"
ATTRIBUTES = ("intensity", "classification", "return_number", "gps_time", "point_source_id", "red", "green", "blue")


def _pyproj_moved(path, to_crs, from_crs=None):
    """The points of ``path`` as pyproj moves them (always_xy), x, y, z as three arrays."""
    las = laspy.read(str(path))
    source = pyproj.CRS.from_user_input(from_crs or read_las_header(path).crs())
    move = pyproj.Transformer.from_crs(source, to_crs, always_xy=True)
    return move.transform(np.asarray(las.x), np.asarray(las.y), np.asarray(las.z))


def _plain_tile(path, xyz, scale=0.01, offsets=(0.0, 0.0, 0.0)):
    """A LAS 1.2 file of ``xyz`` naming no CRS."""
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = [scale] * 3, list(offsets)
    las = laspy.LasData(header)
    las.x, las.y, las.z = np.asarray(xyz, np.float64).T
    las.write(str(path))
    return path


def test_autzen_to_utm_moves_every_point_as_pyproj_does_and_names_utm(cli, autzen_path, tmp_path):
    out = tmp_path / "utm.laz"
    rc, stdout, err = cli("convert", autzen_path, "-o", out, "--to-crs", UTM, "-q")
    assert rc == 0, err
    assert err.startswith(f"warning: {autzen_path}: z is kept as it is, in its own unit, while x and y change unit: neither CRS has a vertical part")
    assert stdout.startswith(f"{out}: 110,000 points (laz), ")
    written, source = laspy.read(str(out)), laspy.read(str(autzen_path))
    # 0.01 ft -> 0.001 m across; z kept as it is (2D CRSs: PROJ's rule), on its own grid
    assert list(written.header.scales) == [0.001, 0.001, 0.01]
    assert list(written.header.offsets) == [494_000.0, 4_877_000.0, 0.0]
    x, y, z = _pyproj_moved(autzen_path, UTM)
    assert np.abs(np.asarray(written.x) - x).max() <= 0.0005 + 1e-9
    assert np.abs(np.asarray(written.y) - y).max() <= 0.0005 + 1e-9
    assert np.array_equal(np.asarray(written.z), np.asarray(source.z))
    assert 494_000 < x.min() < x.max() < 495_000 and 4_877_000 < y.min() < y.max() < 4_878_000  # (metres of UTM 10N: Eugene, Oregon)
    for field in ATTRIBUTES:
        assert np.array_equal(np.asarray(written[field]), np.asarray(source[field])), field
    assert crs_identity(files_crs([out])) == UTM  # gigapoint's own reading of its WKT VLR
    assert written.header.parse_crs() == pyproj.CRS.from_epsg(32610)
    rc, stdout, _ = cli("info", out)
    assert "  crs:         WGS 84 / UTM zone 10N (EPSG:32610)" in stdout.splitlines()  # (its WKT by name and code, as info shows a WKT)


def test_a_ply_naming_its_crs_in_a_comment_is_reprojected_from_it(cli, autzen_path, tmp_path):
    """A PLY's ``comment crs`` line is its CRS to move from, as a LAS header's is (it was "names
    no CRS to reproject from"): autzen as PLY lands where the LAZ does."""
    ply, out = tmp_path / "autzen.ply", tmp_path / "utm.las"
    gp.open(autzen_path, colors="rgba").save(ply)
    rc, _, err = cli("convert", ply, "-o", out, "--to-crs", UTM, "-q")
    assert rc == 0, err
    x, y, _ = _pyproj_moved(autzen_path, UTM)
    written = laspy.read(str(out))
    assert np.abs(np.sort(np.asarray(written.x)) - np.sort(x)).max() <= 0.0005 + 1e-9
    assert np.abs(np.sort(np.asarray(written.y)) - np.sort(y)).max() <= 0.0005 + 1e-9
    assert crs_identity(files_crs([out])) == UTM


def test_a_round_trip_back_to_the_source_crs_lands_within_two_of_its_steps(autzen_path, tmp_path):
    utm, back = tmp_path / "utm.las", tmp_path / "back.las"
    with pytest.warns(GigapointWarning, match="z is kept"):
        gp.convert(autzen_path, utm, to_crs=UTM)
    with pytest.warns(GigapointWarning, match="z is kept"):
        gp.convert(utm, back, to_crs=read_las_header(autzen_path).crs())
    source, returned = laspy.read(str(autzen_path)), laspy.read(str(back))
    assert list(returned.header.scales) == [0.001, 0.001, 0.01]  # (0.001 m is 0.0033 ft: its power of ten below)
    for axis in "xyz":
        assert np.abs(np.asarray(returned[axis]) - np.asarray(source[axis])).max() <= 2 * 0.01, axis
    assert read_las_header(back).crs().startswith('PROJCS["NAD_1983_HARN_Lambert_Conformal_Conic"')


def test_compound_crss_move_z_too_feet_to_metres(autzen_path, tmp_path, recwarn):
    out = tmp_path / "utm_navd88_m.las"
    source_crs, target_crs = "EPSG:2994+6360", "EPSG:32610+5703"  # Oregon GIC Lambert (ft) + NAVD88 (US ft) -> UTM 10N + NAVD88 (m)
    gp.convert(autzen_path, out, to_crs=target_crs, from_crs=source_crs)
    assert not [w for w in recwarn if issubclass(w.category, GigapointWarning)]  # (z changes unit with x and y: nothing to warn of)
    written, source = laspy.read(str(out)), laspy.read(str(autzen_path))
    x, y, z = _pyproj_moved(autzen_path, target_crs, source_crs)
    assert list(written.header.scales) == [0.001, 0.001, 0.001]  # 0.01 US ft of z: 0.003 m
    assert np.abs(np.asarray(written.z) - z).max() <= 0.0005 + 1e-9
    assert np.allclose(np.asarray(written.z), np.asarray(source.z) * 1200 / 3937, atol=0.0006)  # (the same vertical datum: the unit alone)
    assert np.abs(np.asarray(written.x) - x).max() <= 0.0005 + 1e-9
    assert pyproj.CRS.from_wkt(read_las_header(out).crs()) == pyproj.CRS.from_user_input(target_crs)


def test_a_file_naming_no_crs_is_refused_unless_from_crs_says_it(tmp_path, recwarn):
    plain = _plain_tile(tmp_path / "plain.las", [[-123.0, 44.0, 100.0], [-122.9, 44.1, 110.0]], scale=1e-7)
    with pytest.raises(InputError, match=r"^.*plain\.las: names no CRS to reproject from; give the CRS its coordinates are in with gp\.convert\(\.\.\., from_crs=\.\.\.\)$"):
        gp.convert(plain, tmp_path / "utm.laz", to_crs=UTM)
    assert not (tmp_path / "utm.laz").exists()
    gp.convert(plain, tmp_path / "utm.laz", to_crs=UTM, from_crs="EPSG:4326")
    x, y, _ = _pyproj_moved(plain, UTM, "EPSG:4326")
    written = laspy.read(str(tmp_path / "utm.laz"))
    assert np.abs(np.asarray(written.x) - x).max() <= 0.0005 + 1e-9 and np.abs(np.asarray(written.y) - y).max() <= 0.0005 + 1e-9
    assert not [w for w in recwarn if issubclass(w.category, GigapointWarning)]  # (degrees to metres: z, in metres, is no unit off)
    assert list(written.header.scales)[:2] == [0.001, 0.001]  # 1e-7 degree (~1 cm east-west here): its power of ten below in metres


@pytest.mark.parametrize(("source", "xy", "warned"), [("EPSG:2994", (636_000.0, 849_000.0), True), (UTM, (494_000.0, 4_877_000.0), False)])
def test_to_degrees_z_is_said_kept_where_it_is_not_in_metres(tmp_path, recwarn, source, xy, warned):
    """A geographic CRS's heights are in metres: Oregon's feet to EPSG:4326 keep z in feet (that was
    said nothing of, where feet to UTM's metres warned); UTM's metres to degrees keep it right."""
    plain = _plain_tile(tmp_path / "plain.las", [[xy[0], xy[1], 100.0], [xy[0] + 10, xy[1] + 10, 110.0]])
    gp.convert(plain, tmp_path / "lonlat.laz", to_crs="EPSG:4326", from_crs=source)
    said = [str(w.message) for w in recwarn if issubclass(w.category, GigapointWarning)]
    kept = (
        f"{plain}: z is kept as it is, in its own unit, while x and y change unit: neither CRS has a vertical part, and PROJ "
        "transforms heights only between vertical CRSs; give compound CRSs (e.g. from 'EPSG:2994+6360' to 'EPSG:32610+5703') to convert z"
    )
    assert said == ([kept] if warned else [])


def test_a_3d_geographic_target_that_wkt1_cannot_say_is_written_as_wkt2(cli, tmp_path):
    """EPSG:4979 (WGS 84 with ellipsoidal heights) has no WKT1: its output was pyproj's CRSError, a
    traceback; it is written as WKT2, which laspy (pyproj) and gigapoint read back as EPSG:4979."""
    plain = _plain_tile(tmp_path / "plain.las", [[494_000.0, 4_877_000.0, 100.0], [494_010.0, 4_877_010.0, 110.0]])
    out = tmp_path / "lonlat3d.laz"
    rc, _, err = cli("convert", plain, "-o", out, "--to-crs", "EPSG:4979", "--from-crs", UTM, "-q")
    assert (rc, err) == (0, "")
    written = laspy.read(str(out))
    assert written.header.parse_crs() == pyproj.CRS.from_epsg(4979)
    assert read_las_header(out).crs().startswith('GEOGCRS["WGS 84"')
    x, y, z = _pyproj_moved(plain, "EPSG:4979", UTM)
    assert np.abs(np.asarray(written.x) - x).max() <= 5e-9 and np.abs(np.asarray(written.y) - y).max() <= 5e-9  # (a 1e-8 degree grid)
    assert np.allclose(np.asarray(written.z), [100.0, 110.0]) and np.allclose(z, [100.0, 110.0])  # (2D to 3D: PROJ keeps z)
    rc, stdout, _ = cli("info", out)
    assert "  crs:         WGS 84 (EPSG:4979)" in stdout.splitlines()


def test_from_crs_over_a_file_naming_another_crs_is_warned_of(cli, autzen_path, tmp_path):
    """from_crs reads every file in it (PDAL's in_srs): a file naming UTM read as Oregon feet came
    out 1,000 km off without a word. autzen's ESRI WKT of EPSG:2994 is no other CRS."""
    utm = tmp_path / "utm.laz"
    with pytest.warns(GigapointWarning, match="z is kept"):
        gp.convert(autzen_path, utm, to_crs=UTM)
    rc, _, err = cli("convert", autzen_path, utm, "-o", tmp_path / "out.laz", "--to-crs", "EPSG:3857", "--from-crs", "EPSG:2994", "-q")
    assert rc == 0
    assert err.splitlines()[0] == (
        f"warning: {utm}: names WGS 84 / UTM zone 10N (EPSG:32610), another CRS than the one given for every input "
        "(NAD83(HARN) / Oregon GIC Lambert (ft)): its coordinates are taken to be in the one given; "
        "leave it out to move each file from the CRS its header names"
    )
    assert sum("another CRS than the one given" in line for line in err.splitlines()) == 1


def test_the_cli_names_the_file_without_a_crs(cli, tmp_path):
    """It said '(convert: from_crs=, --from-crs)': the Python keyword and the option at once."""
    plain = _plain_tile(tmp_path / "plain.las", [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    rc, _, err = cli("convert", plain, "-o", tmp_path / "out.laz", "--to-crs", UTM, "-q")
    assert (rc, err) == (1, f"error: {plain}: names no CRS to reproject from; give the CRS its coordinates are in with --from-crs\n")
    rc, _, err = cli("tile", plain, "-o", tmp_path / "tiles", "--size", "1", "--to-crs", UTM, "-q")
    assert (rc, err) == (1, f"error: {plain}: names no CRS to reproject from; give the CRS its coordinates are in with --from-crs\n")
    with pytest.raises(InputError, match=r"give the CRS its coordinates are in with gp\.tile\(\.\.\., from_crs=\.\.\.\)$"):
        gp.tile(plain, tmp_path / "tiles", 1.0, to_crs=UTM)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plain.las"]


def test_an_unknown_crs_is_refused_before_a_point_is_read(cli, autzen_path, tmp_path, monkeypatch):
    def no_read(*args):
        raise AssertionError("read")

    monkeypatch.setattr(importlib.import_module("gigapoint.lod.convert.to_file"), "read_chunks", no_read)
    rc, _, err = cli("convert", autzen_path, "-o", tmp_path / "out.laz", "--to-crs", "EPSG:999999", "-q")
    assert rc == 1 and err.startswith("error: convert: --to-crs EPSG:999999: not a CRS PROJ knows (") and len(err.strip().splitlines()) == 1
    with pytest.raises(InputError, match=r"^tile: from_crs='nowhere': not a CRS PROJ knows \("):
        gp.tile(autzen_path, tmp_path / "tiles", 100, to_crs=UTM, from_crs="nowhere")
    assert not (tmp_path / "out.laz").exists() and not (tmp_path / "tiles").exists()


def test_points_outside_the_projections_domain_are_refused_naming_the_file(tmp_path):
    beyond = _plain_tile(tmp_path / "beyond.las", [[10.0, 45.0, 0.0], [10.0, 95.0, 0.0], [10.0, 46.0, 0.0]])  # latitude 95: no Mercator y
    with pytest.raises(InputError, match=r"beyond\.las: 1 point lies outside the domain of the transform to WGS 84 / Pseudo-Mercator \(e\.g\. 10, 95, 0\): nothing was written"):
        gp.convert(beyond, tmp_path / "out.laz", to_crs="EPSG:3857", from_crs="EPSG:4326")
    assert not (tmp_path / "out.laz").exists()


def test_a_file_beyond_gigapoints_reach_is_no_valid_point_not_an_internal_error(cli, tmp_path):
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = [1.0] * 3, [1e12, 1e12, 0.0]  # (the farthest offset a header may have: its points just beyond)
    las = laspy.LasData(header)
    las.X, las.Y, las.Z = np.array([1, 5], np.int32), np.array([1, 5], np.int32), np.array([0, 1], np.int32)
    far = tmp_path / "far.las"
    las.write(str(far))
    rc, _, err = cli("convert", far, "-o", tmp_path / "out.laz", "--to-crs", "EPSG:4326", "--from-crs", UTM)
    assert rc == 1 and err.strip() == f"error: {far}: no valid points (2 invalid points: NaN, inf or beyond ±1e+12)"  # (was "internal error: ValueError")
    assert not (tmp_path / "out.laz").exists()


def test_a_box_outside_the_domain_names_its_middle_not_a_count_of_made_up_points(tmp_path):
    one = _plain_tile(tmp_path / "one.las", [[473.18, 511.82, 755.16]])  # metres taken for degrees: latitude 511
    with pytest.raises(InputError, match=r"^.*one\.las: the middle of its points' box \(473\.18, 511\.82, 755\.16, as its header says\) lies outside the domain of the transform to WGS 84 / UTM zone 10N: nothing was written"):
        gp.convert(one, tmp_path / "out.laz", to_crs=UTM, from_crs="EPSG:4326")  # (was "4 points lie outside": the file has 1)
    assert not (tmp_path / "out.laz").exists()


def test_without_pyproj_the_option_says_how_to_install_it(autzen_path, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "pyproj", None)  # (import pyproj raises ImportError)
    with pytest.raises(InputError, match=r"^convert: to_crs='EPSG:32610': reprojecting needs pyproj \(pip install 'gigapoint\[gis\]'\)$"):
        gp.convert(autzen_path, tmp_path / "out.laz", to_crs=UTM)


def test_from_crs_without_to_crs_is_refused(autzen_path, tmp_path):
    with pytest.raises(InputError, match=r"^convert: from_crs='EPSG:2994': the CRS the inputs are in, for to_crs; give to_crs too$"):
        gp.convert(autzen_path, tmp_path / "out.laz", from_crs="EPSG:2994")


def test_tiles_in_utm_hold_their_squares_points_in_metres(cli, autzen_path, tmp_path):
    rc, stdout, err = cli("tile", autzen_path, "--size", 100, "-o", tmp_path / "tiles", "--to-crs", UTM, "-q")
    assert rc == 0 and "z is kept" in err, err
    tiles = sorted((tmp_path / "tiles").glob("*.laz"))
    x, y, _ = _pyproj_moved(autzen_path, UTM)
    expected = {(int(i), int(j)) for i, j in zip(np.floor(x / 100), np.floor(y / 100))}
    assert {tuple(int(v) // 100 for v in p.stem.split("_")[-2:]) for p in tiles} == expected  # (named after UTM corners)
    total = 0
    for p in tiles:
        las = laspy.read(str(p))
        xmin, ymin = (float(v) for v in p.stem.split("_")[-2:])
        assert xmin - 0.0005 <= las.x.min() and las.x.max() < xmin + 100 + 0.0005 and ymin - 0.0005 <= las.y.min() and las.y.max() < ymin + 100 + 0.0005
        assert crs_identity(files_crs([p])) == UTM
        total += len(las.points)
    assert total == 110_000


def _read_xyz(path):
    las = laspy.read(str(path))
    return np.column_stack([las.x, las.y, las.z]).astype(np.float64)


def _fast_and_exact(reprojection, xyz, path):
    """(the fast path's points, PROJ's exact ones) of ``xyz``, and the fast path's counts."""
    fast = reprojection.transformed(xyz, path)
    exact = np.column_stack(reprojection.transformer(path).transform(*(xyz[:, k].copy() for k in range(3))))
    return fast, exact


def test_the_fast_path_is_within_a_tenth_of_the_grid_step_of_proj_and_writes_the_same_file(autzen_path, tmp_path):
    reprojection = Reprojection(UTM)
    reprojection.check_files([autzen_path])
    with pytest.warns(GigapointWarning, match="z is kept"):
        output_grid([autzen_path], reprojection)
    assert reprojection.tolerance == (pytest.approx(0.0001), pytest.approx(0.001))  # (0.001 m grid: 0.1 mm)
    xyz = _read_xyz(autzen_path)
    fast, exact = _fast_and_exact(reprojection, xyz, autzen_path)
    assert reprojection.interpolated_points == 110_000
    off = np.abs(fast[:, :2] - exact[:, :2]).max()
    assert off <= 1e-6  # (measured 7.5e-9 m: far inside the 1e-4 m bound)
    assert np.array_equal(fast[:, 2], xyz[:, 2])  # (z passed through as it is, untouched)
    with pytest.warns(GigapointWarning, match="z is kept"):
        gp.convert(autzen_path, tmp_path / "fast.las", to_crs=UTM)
    with pytest.warns(GigapointWarning, match="z is kept"):
        gp.convert(autzen_path, tmp_path / "exact.las", to_crs=UTM, exact_transform=True)
    written_fast, written_exact = laspy.read(str(tmp_path / "fast.las")), laspy.read(str(tmp_path / "exact.las"))
    # the same grid integers, but where PROJ's point lies within the fast path's distance of a rounding boundary
    near = np.zeros(110_000, bool)
    for k, axis in enumerate("XY"):
        steps = (exact[:, k] - written_exact.header.offsets[k]) / written_exact.header.scales[k]
        near |= np.abs(steps - np.floor(steps) - 0.5) <= off / 0.001 + 1e-9
        same = np.asarray(written_fast[axis]) == np.asarray(written_exact[axis])
        assert same[~near].all(), axis
    assert near.sum() <= 10  # (2 x 7.5e-6 of a step: ~2 by chance)
    assert np.array_equal(np.asarray(written_fast.Z), np.asarray(written_exact.Z))


def test_a_reprojection_made_again_from_its_spec_moves_points_bit_for_bit_as_it_does(autzen_path):
    """What a Dask read task gets (lod/convert/distributed.py): the CRSs, the exact switch and the
    fast path's tolerance, so its chunks are interpolated as the driver's would be, not moved exactly."""
    reprojection = Reprojection(UTM, "EPSG:2994")
    with pytest.warns(GigapointWarning, match="z is kept"):
        output_grid([autzen_path], reprojection)
    again = Reprojection.from_spec(reprojection.as_spec())
    assert again.as_spec() == reprojection.as_spec() and again.tolerance == reprojection.tolerance
    xyz = _read_xyz(autzen_path)
    assert np.array_equal(again.transformed(xyz, autzen_path), reprojection.transformed(xyz, autzen_path))
    assert again.interpolated_points == reprojection.interpolated_points == 110_000
    exact = Reprojection.from_spec({**reprojection.as_spec(), "exact": True})
    exact.transformed(xyz, autzen_path)
    assert (exact.interpolated_points, exact.exact_points) == (0, 110_000)


def test_a_200_km_box_across_a_utm_zone_edge_takes_a_finer_grid_and_stays_within_the_bound(tmp_path):
    rng = np.random.default_rng(7)
    lonlat = np.column_stack([rng.uniform(-121.3, -118.7, 200_000), rng.uniform(44.0, 45.8, 200_000), rng.uniform(0, 500, 200_000)])
    path = _plain_tile(tmp_path / "wide.las", lonlat, scale=1e-6)  # (across 120 W, zone 10's east edge, into zone 11)
    reprojection = Reprojection(UTM, "EPSG:4326")
    reprojection.tolerance = (0.0001, 0.0001)
    from gigapoint.io import reproject_grid

    fitted = reproject_grid.fit(reprojection.transformer(path).transform, lonlat.min(axis=0), lonlat.max(axis=0), reprojection.tolerance, len(lonlat))
    assert fitted is not None and fitted[0].n > reproject_grid.FIRST_CELLS  # (a finer grid than the first)
    fast, exact = _fast_and_exact(reprojection, lonlat, path)
    assert reprojection.interpolated_points == 200_000
    assert np.abs(fast - exact).max() <= 0.0001


def test_polar_stereographic_to_lon_lat_across_the_pole_falls_back_to_proj(tmp_path):
    rng = np.random.default_rng(3)
    xyz = np.column_stack([rng.uniform(-50_000, 50_000, 20_000), rng.uniform(-50_000, 50_000, 20_000), np.zeros(20_000)])
    path = _plain_tile(tmp_path / "pole.las", xyz)
    reprojection = Reprojection("EPSG:4326", "EPSG:3413")  # (longitude turns all the way round the pole: no smooth grid)
    reprojection.tolerance = (1e-8, 0.001)  # (a 1e-7 degree grid)
    fast, exact = _fast_and_exact(reprojection, xyz, path)
    assert (reprojection.interpolated_points, reprojection.exact_points) == (0, 20_000)
    assert np.array_equal(fast, exact)


def test_exact_transform_sends_every_point_through_proj(autzen_path):
    reprojection = Reprojection(UTM, exact=True)
    reprojection.tolerance = (0.0001, 0.001)
    fast, exact = _fast_and_exact(reprojection, _read_xyz(autzen_path), autzen_path)
    assert (reprojection.interpolated_points, reprojection.exact_points) == (0, 110_000) and np.array_equal(fast, exact)


#: a site of autzen (its Lambert feet): four corners, a few hundred feet apart
SITE_FEET = [(636_200.0, 849_000.0), (637_000.0, 848_990.0), (636_900.0, 849_400.0), (636_300.0, 849_350.0)]


def _site_geojson(path, corners, epsg=None):
    """A GeoJSON Polygon of ``corners``, naming EPSG:``epsg`` in its crs member where given."""
    import json

    document = {"type": "Polygon", "coordinates": [[*map(list, corners), list(corners[0])]]}
    if epsg is not None:
        document["crs"] = {"type": "name", "properties": {"name": f"urn:ogc:def:crs:EPSG::{epsg}"}}
    path.write_text(json.dumps(document))
    return path


def test_a_clip_polygon_in_the_source_crs_or_named_in_the_target_or_lon_lat_clips_the_same_points(cli, autzen_path, tmp_path):
    from gigapoint.io.polygon import clip_polygon_of

    source = laspy.read(str(autzen_path))
    inside = clip_polygon_of(_site_geojson(tmp_path / "feet.geojson", SITE_FEET), "test").inside(np.column_stack([source.x, source.y, source.z]))
    assert 10_000 < inside.sum() < 100_000  # (a cut, not all or nothing)
    feet = pyproj.CRS.from_wkt(read_las_header(autzen_path).crs())
    areas = {"feet": SITE_FEET}  # (the inputs' CRS: the polygon names none)
    for name, crs in (("utm", UTM), ("lonlat", "EPSG:4326")):  # the same corners, named in the target's CRS and in another
        x, y = pyproj.Transformer.from_crs(feet, crs, always_xy=True).transform(*np.array(SITE_FEET).T)
        areas[name] = list(zip(x, y))
    for name, corners in areas.items():
        polygon = _site_geojson(tmp_path / f"{name}.geojson", corners, None if name == "feet" else int(pyproj.CRS(UTM if name == "utm" else "EPSG:4326").to_epsg()))
        out = tmp_path / f"{name}.laz"
        rc, stdout, err = cli("convert", autzen_path, "-o", out, "--to-crs", UTM, "--clip-polygon", polygon, "-q")
        assert rc == 0, err
        assert "names EPSG" not in err  # (a polygon in the target's CRS was said to be "taken in the files' coordinates")
        assert stdout.startswith(f"{out}: {inside.sum():,} points (laz)"), name
        written = laspy.read(str(out))
        assert np.array_equal(np.asarray(written.gps_time), np.asarray(source.gps_time)[inside]), name  # (the same points, in order)
    rc, stdout, err = cli("tile", autzen_path, "--size", 1000, "-o", tmp_path / "tiles", "--to-crs", UTM, "--clip-polygon", tmp_path / "feet.geojson", "-q")
    assert rc == 0, err
    assert sum(len(laspy.read(str(p)).points) for p in (tmp_path / "tiles").glob("*.laz")) == inside.sum()
    copc = tmp_path / "site.copc.laz"  # (an octree's read stage moves the polygon too)
    rc, _, err = cli("convert", autzen_path, "-o", copc, "--to-crs", UTM, "--clip-polygon", tmp_path / "feet.geojson", "-q")
    assert rc == 0 and len(laspy.read(str(copc)).points) == inside.sum(), err


def test_a_clip_polygon_naming_no_crs_over_inputs_in_two_crss_is_refused_before_a_point_is_read(autzen_path, tmp_path, recwarn):
    utm = tmp_path / "utm.las"
    with pytest.warns(GigapointWarning, match="z is kept"):
        gp.convert(autzen_path, utm, to_crs=UTM)
    polygon = _site_geojson(tmp_path / "site.geojson", SITE_FEET)
    with pytest.raises(InputError, match=r"^.*site\.geojson: names no CRS while the inputs are in 2 CRSs: give it as GeoJSON naming its CRS \(a crs member\), or the CRS of every input with gp\.convert\(\.\.\., from_crs=\.\.\.\)$"):
        gp.convert([autzen_path, utm], tmp_path / "both.laz", to_crs="EPSG:32611", clip_polygon=str(polygon))
    assert not (tmp_path / "both.laz").exists()


def test_a_lon_lat_clip_polygon_naming_no_crs_with_to_crs_is_refused_before_a_point_is_read(cli, autzen_path, tmp_path):
    """RFC 7946 GeoJSON (no crs member) is longitude/latitude: --to-crs took it in the inputs'
    feet and said "no point passes" once every point was read; now the one line a read filter
    gives without --to-crs, for a file, an octree and tiles alike."""
    lonlat = _site_geojson(tmp_path / "lonlat.geojson", [(-123.1, 44.0), (-123.0, 44.0), (-123.0, 44.1)])
    want = (
        f"error: {lonlat}: x -123.1..-123, y 44..44.1 looks like longitude/latitude (RFC 7946 GeoJSON) while {autzen_path} is in "
        "NAD_1983_HARN_Lambert_Conformal_Conic (WKT): add a crs member naming its CRS, or reproject it into the files' coordinates"
    )
    _refused_into_each_output(cli, autzen_path, ("--to-crs", UTM, "--clip-polygon", lonlat), want, tmp_path)


def _refused_into_each_output(cli, source, options, want, tmp_path):
    """convert into a LAZ file and a COPC file, and tile, of ``source`` with ``options``: each
    refused with the one line ``want`` (after the warning that z keeps its feet), nothing written."""
    for out in ("out.laz", "out.copc.laz", "tiles"):
        command = ("tile", source, "--size", 1000) if out == "tiles" else ("convert", source)
        rc, _, err = cli(*command, "-o", tmp_path / out, *options, "-q")
        assert rc != 0 and err.strip().splitlines()[-1] == want, out
        assert not (tmp_path / out).exists() or not any((tmp_path / out).iterdir()), out



def test_a_lon_lat_clip_polygon_naming_no_crs_is_refused_over_inputs_in_a_projected_from_crs_too(cli, tmp_path):
    """--from-crs (its inputs' headers naming no CRS: no header said which) took a lon/lat polygon
    in autzen's feet, and "no point passes" came once every point was read: the one line it gets
    where the headers name that CRS, for a file, an octree and tiles alike. Over inputs in lon/lat
    (--from-crs EPSG:4326) the same polygon is theirs: kept as it is."""
    feet = _plain_tile(tmp_path / "feet.las", [[636_000.0, 849_000.0, 100.0], [637_000.0, 849_500.0, 110.0]])
    lonlat = _site_geojson(tmp_path / "lonlat.geojson", [(-123.1, 44.0), (-123.0, 44.0), (-123.0, 44.1)])
    want = (
        f"error: {lonlat}: x -123.1..-123, y 44..44.1 looks like longitude/latitude (RFC 7946 GeoJSON) while {feet} is in "
        "NAD83(HARN) / Oregon GIC Lambert (ft) (EPSG:2994): add a crs member naming its CRS, or reproject it into the files' coordinates"
    )
    _refused_into_each_output(cli, feet, ("--to-crs", UTM, "--from-crs", "EPSG:2994", "--clip-polygon", lonlat), want, tmp_path)
    degrees = _plain_tile(tmp_path / "degrees.las", [[-123.05, 44.01, 100.0], [-122.9, 44.2, 110.0]], scale=1e-7)
    rc, stdout, err = cli("convert", degrees, "-o", tmp_path / "kept.laz", "--to-crs", UTM, "--from-crs", "EPSG:4326", "--clip-polygon", lonlat, "-q")
    assert rc == 0 and stdout.startswith(f"{tmp_path / 'kept.laz'}: 1 point (laz)"), err


def _densified(corners, pieces=64):
    """The ring ``corners`` with each edge cut into ``pieces``: moved into another CRS, its edges
    still follow the straight ones in the first (a projection bends them: millimetres over autzen's
    hundreds of feet, where a few points lie)."""
    ring = np.array(corners, np.float64)
    along = np.arange(pieces)[None, :, None] / pieces
    return (ring[:, None, :] + along * (np.roll(ring, -1, axis=0) - ring)[:, None, :]).reshape(-1, 2)


def test_a_clip_polygon_naming_another_crs_than_the_files_is_moved_into_theirs_without_to_crs(cli, autzen_path, tmp_path):
    """autzen's Lambert feet cut by one site given in those feet, in lon/lat and in UTM (a crs
    member naming each): the same points kept by open, convert, render and info --stats."""
    import json

    from gigapoint.io.polygon import clip_polygon_of

    source = laspy.read(str(autzen_path))
    ring = _densified(SITE_FEET)
    feet = _site_geojson(tmp_path / "feet.geojson", ring)
    inside = clip_polygon_of(feet, "test").inside(np.column_stack([source.x, source.y, source.z]))
    assert 10_000 < inside.sum() < 100_000  # (a cut, not all or nothing)
    lambert = pyproj.CRS.from_wkt(read_las_header(autzen_path).crs())
    for epsg in (4326, 32610):
        x, y = pyproj.Transformer.from_crs(lambert, f"EPSG:{epsg}", always_xy=True).transform(*ring.T)
        polygon = _site_geojson(tmp_path / f"site{epsg}.geojson", list(zip(x, y)), epsg)
        cloud = gp.open(autzen_path, clip_polygon=polygon)
        assert cloud.n_points == inside.sum(), epsg
        kept_time = np.concatenate([c.attributes["gps_time"] for c in cloud.chunks()])
        assert np.array_equal(np.sort(kept_time), np.sort(np.asarray(source.gps_time)[inside])), epsg  # (the same points)
        out = tmp_path / f"site{epsg}.laz"
        rc, stdout, err = cli("convert", autzen_path, "-o", out, "--clip-polygon", polygon, "-q")
        assert rc == 0 and "names EPSG" not in err, err
        assert np.array_equal(np.asarray(laspy.read(str(out)).gps_time), np.asarray(source.gps_time)[inside]), epsg  # (in order)
        rc, stdout, err = cli("render", autzen_path, "-o", tmp_path / f"site{epsg}.png", "-W", 60, "-H", 40, "--clip-polygon", polygon)
        assert rc == 0 and f"{inside.sum():,} points" in stdout, err
        rc, stdout, err = cli("info", "--stats", "--json", "--clip-polygon", polygon, autzen_path)
        assert rc == 0, err
        assert json.loads(stdout)["filter"]["points_kept"] == inside.sum(), epsg


def test_a_clip_polygon_in_lon_lat_far_from_its_points_says_which_crs_it_was_given_in(autzen_path, tmp_path):
    """Named EPSG:4326 and moved into autzen's feet, a site in Florida keeps nothing: the hint says
    which CRS it was given in, and where it landed."""
    import json

    from gigapoint.errors import EmptyCloudError

    florida = tmp_path / "florida.geojson"
    crs = {"type": "name", "properties": {"name": "EPSG:4326"}}
    florida.write_text(json.dumps({"type": "Polygon", "crs": crs, "coordinates": [[[-81.1, 28.0], [-81.0, 28.0], [-81.0, 28.1]]]}))
    with pytest.raises(EmptyCloudError) as err:
        gp.open(autzen_path, clip_polygon=florida)
    assert str(err.value).startswith(f"{autzen_path}: no point passes the filter (clip polygon {florida} (3 vertices)): 110,000 points read; {florida} (given in EPSG:4326) spans x ")
    assert str(err.value).endswith("far from the points' x 636002..637179, y 848935..849498: is it in EPSG:4326?")
    x0 = float(str(err.value).split(" spans x ")[1].split("..")[0])
    assert 1.3e7 < x0 < 1.5e7  # (Florida in Oregon's Lambert feet: 14 million feet east)


def test_a_clip_polygon_naming_no_crs_over_one_crs_written_two_ways_is_taken_in_it(autzen_path, tmp_path):
    """autzen's ESRI WKT and a tile of its points naming EPSG:2994 by GeoTIFF keys (the same
    projection, another text) were "inputs in 2 CRSs" and the polygon refused: it is taken in
    theirs, and cuts both tiles' points alike."""
    from gigapoint.io.polygon import clip_polygon_of

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "unit"))
    from test_crs_units import geokeys_vlr

    source = laspy.read(str(autzen_path))
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = source.header.scales, source.header.offsets
    header.vlrs.append(geokeys_vlr({1024: 1, 3072: 2994}))
    keyed = laspy.LasData(header)
    keyed.x, keyed.y, keyed.z = source.x[::10], source.y[::10], source.z[::10]
    keyed.write(str(tmp_path / "keyed.las"))
    polygon = _site_geojson(tmp_path / "site.geojson", SITE_FEET)
    inside = clip_polygon_of(polygon, "test").inside(np.column_stack([source.x, source.y, source.z]))
    with pytest.warns(GigapointWarning, match="z is kept"):
        gp.convert([autzen_path, tmp_path / "keyed.las"], tmp_path / "both.laz", to_crs=UTM, clip_polygon=str(polygon))
    assert len(laspy.read(str(tmp_path / "both.laz")).points) == inside.sum() + inside[::10].sum() > 10_000
    assert crs_identity(files_crs([tmp_path / "keyed.las"])) == crs_identity(files_crs([autzen_path]))


#: the attributes that, with z, tell autzen's points apart (their order in an octree is its own)
KEYS = ("gps_time", "intensity", "return_number", "point_source_id")


def _sorted_by_keys(xy, z, attributes):
    """``xy`` (n x 2) in the order of (``KEYS``' ``attributes``, z)."""
    return xy[np.lexsort([np.asarray(z), *(np.asarray(attributes[k]) for k in KEYS)])]


def test_octrees_and_copc_take_to_crs_their_points_where_pyproj_moves_them_and_name_the_target(cli, autzen_path, tmp_path):
    from gigapoint.lod import open_octree

    source = laspy.read(str(autzen_path))
    x, y, _ = _pyproj_moved(autzen_path, UTM)
    expected = _sorted_by_keys(np.column_stack([x, y]), source.z, source)
    copc = tmp_path / "utm.copc.laz"
    rc, stdout, err = cli("convert", autzen_path, "-o", copc, "--to-crs", UTM, "-q")
    assert rc == 0 and "z is kept" in err, err
    assert stdout.startswith(f"{copc}: 110,000 points in ")
    written = laspy.read(str(copc))
    assert written.header.parse_crs() == pyproj.CRS.from_epsg(32610)  # (its WKT VLR)
    assert list(written.header.scales) == [0.001, 0.001, 0.01] and list(written.header.offsets) == [494_000.0, 4_877_000.0, 0.0]
    moved = _sorted_by_keys(np.column_stack([written.x, written.y]), written.z, written)
    assert np.abs(moved - expected).max() <= 0.0005 + 1e-6  # (half the output grid's step: its rounding; the fast path's 7.5e-9 m)
    octree = tmp_path / "utm"
    with pytest.warns(GigapointWarning, match="z is kept"):
        gp.convert(autzen_path, octree, to_crs=UTM)
    tree = open_octree(octree)
    parts = [tree.node_points(i) for i in range(len(tree.nodes))]
    xyz = np.concatenate([p["xyz"] for p in parts])
    moved = _sorted_by_keys(xyz[:, :2], xyz[:, 2], {k: np.concatenate([p[k] for p in parts]) for k in KEYS})
    assert np.abs(moved - expected).max() <= 0.0005 + 1e-6
    assert pyproj.CRS.from_wkt(tree.meta["crs"]) == pyproj.CRS.from_epsg(32610)  # (octree.json's, as gigapoint info shows it)


def test_an_octree_conversion_resumes_only_under_the_same_to_crs_and_spills_the_moved_points(autzen_path, tmp_path, recwarn, interrupted_read):
    out = tmp_path / "utm"
    interrupted_read(lambda: gp.convert(autzen_path, out, to_crs=UTM, chunk_size=20_000))
    zone_11 = gp.convert(autzen_path, out, to_crs="EPSG:32611", chunk_size=20_000)  # another CRS: starts over, not a mix of both
    assert (zone_11.resumed, zone_11.points) == (False, 110_000)
    x, y, _ = _pyproj_moved(autzen_path, "EPSG:32611")
    tree = importlib.import_module("gigapoint.lod").open_octree(out)
    bounds = tree.meta["bounds"]
    assert np.allclose(bounds["min"][:2], [x.min(), y.min()], atol=0.001) and np.allclose(bounds["max"][:2], [x.max(), y.max()], atol=0.001)


def test_an_octree_conversion_resumes_only_under_the_same_proj(autzen_path, tmp_path, recwarn, interrupted_read, monkeypatch):
    """Another PROJ (an upgrade, or PROJ_NETWORK turned on: other grids) may pick other operations and
    move the points elsewhere: a resume under it mixed points moved two ways. It starts over; under
    the same PROJ, the same command resumes."""
    for out in (tmp_path / "same", tmp_path / "upgraded"):
        interrupted_read(lambda out=out: gp.convert(autzen_path, out, to_crs=UTM, chunk_size=20_000))
    same = gp.convert(autzen_path, tmp_path / "same", to_crs=UTM, chunk_size=20_000)
    assert (same.resumed, same.points) == (True, 110_000)
    monkeypatch.setattr(pyproj, "proj_version_str", "0.0.1")  # PROJ upgraded in between
    upgraded = gp.convert(autzen_path, tmp_path / "upgraded", to_crs=UTM, chunk_size=20_000)
    assert (upgraded.resumed, upgraded.points) == (False, 110_000)


def test_a_millimetre_grid_moved_into_its_own_crs_keeps_its_millimetre(tmp_path):
    """One step of 0.001 measured near y = 4.9e6 is 0.00099999998929: its power of ten below was
    1e-4, a grid ten times finer than the points' own."""
    from gigapoint.io.las_fields import power_of_ten_below

    assert power_of_ten_below((494_295.3 + 0.001) - 494_295.3) == 0.001
    assert power_of_ten_below(0.00099) == 0.0001 and power_of_ten_below(0.01) == 0.01
    plain = _plain_tile(tmp_path / "utm.las", [[494_295.3, 4_877_123.4, 120.0], [494_395.3, 4_877_223.4, 130.0]], 0.001, (494_000.0, 4_877_000.0, 0.0))
    gp.convert(plain, tmp_path / "same.las", to_crs=UTM, from_crs=UTM)
    assert list(laspy.read(str(tmp_path / "same.las")).header.scales) == [0.001, 0.001, 0.001]


def test_a_vertical_only_target_is_refused_before_a_point_is_read(cli, autzen_path, tmp_path, monkeypatch):
    """EPSG:5703 was taken: x, y came out in degrees labelled NAVD88 height."""

    def no_read(*args):
        raise AssertionError("read")

    monkeypatch.setattr(importlib.import_module("gigapoint.lod.convert.to_file"), "read_chunks", no_read)
    rc, _, err = cli("convert", autzen_path, "-o", tmp_path / "out.laz", "--to-crs", "EPSG:5703", "-q")
    assert (rc, err) == (1, "error: convert: --to-crs EPSG:5703: NAVD88 height is a vertical CRS only: give a horizontal or compound CRS (e.g. EPSG:32610+5703)\n")
    with pytest.raises(InputError, match=r"^tile: to_crs='EPSG:5703': NAVD88 height is a vertical CRS only: "):
        gp.tile(autzen_path, tmp_path / "tiles", 100, to_crs="EPSG:5703")
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("source", "target", "which"),
    [("EPSG:2994", UTM, "neither CRS has a vertical part"), ("EPSG:2994+6360", UTM, "the target CRS has no vertical part"), ("EPSG:2994", "EPSG:4979", "the source CRS has no vertical part")],
)
def test_the_z_kept_warning_names_the_crs_lacking_a_vertical_part(tmp_path, recwarn, source, target, which):
    """It said 'neither CRS has a vertical part' where one had one."""
    plain = _plain_tile(tmp_path / "plain.las", [[636_000.0, 849_000.0, 400.0], [636_010.0, 849_010.0, 410.0]])
    gp.convert(plain, tmp_path / "out.laz", to_crs=target, from_crs=source)
    said = [str(w.message) for w in recwarn if issubclass(w.category, GigapointWarning)]
    assert said == [f"{plain}: z is kept as it is, in its own unit, while x and y change unit: {which}, and PROJ transforms heights only between vertical CRSs; give compound CRSs (e.g. from 'EPSG:2994+6360' to 'EPSG:32610+5703') to convert z"]


def test_a_geocentric_target_is_refused_before_a_point_is_read(cli, autzen_path, tmp_path):
    """EPSG:4978 took autzen's z in feet as metres without a word."""
    rc, _, err = cli("convert", autzen_path, "-o", tmp_path / "out.laz", "--to-crs", "EPSG:4978", "-q")
    assert (rc, err) == (1, "error: convert: --to-crs EPSG:4978: WGS 84 is a geocentric CRS (x, y, z from the earth's centre), not a point cloud's output CRS: give a projected, geographic or compound CRS (e.g. EPSG:32610+5703)\n")
    assert not (tmp_path / "out.laz").exists()


@pytest.mark.parametrize("target", ["EPSG:32610+5703", UTM])
def test_z_in_metres_of_a_compound_source_in_feet_is_kept_without_a_warning(tmp_path, recwarn, target):
    """EPSG:2994+5703 has x in feet, z in metres (NAVD88): z's unit was taken as x's, and z, kept in
    metres as it should be, was warned of ('PROJ found no height transform')."""
    plain = _plain_tile(tmp_path / "plain.las", [[636_000.0, 849_000.0, 400.0], [636_010.0, 849_010.0, 410.0]])
    gp.convert(plain, tmp_path / "out.las", to_crs=target, from_crs="EPSG:2994+5703")
    assert [str(w.message) for w in recwarn if issubclass(w.category, GigapointWarning)] == []
    assert np.allclose(np.asarray(laspy.read(str(tmp_path / "out.las")).z), [400.0, 410.0], atol=0.0005)


def test_z_kept_between_two_vertical_crss_proj_finds_no_transform_for_is_warned_of(tmp_path, recwarn):
    """EGM2008 (m) to NAVD88 (US ft) needs a geoid grid: without one PROJ keeps z, in metres, read as feet."""
    if pyproj.Transformer.from_crs("EPSG:32610+3855", "EPSG:2994+6360", always_xy=True).transform(494_000.0, 4_877_000.0, 100.0)[2] != 100.0:
        pytest.skip("PROJ has the geoid grid here: it moves z")
    plain = _plain_tile(tmp_path / "plain.las", [[494_000.0, 4_877_000.0, 100.0], [494_010.0, 4_877_010.0, 110.0]])
    gp.convert(plain, tmp_path / "out.las", to_crs="EPSG:2994+6360", from_crs="EPSG:32610+3855")
    said = [str(w.message) for w in recwarn if issubclass(w.category, GigapointWarning)]
    assert said == [f"{plain}: z is kept as it is, in its own unit, while x and y change unit: PROJ found no height transform, and PROJ transforms heights only between vertical CRSs; give compound CRSs (e.g. from 'EPSG:2994+6360' to 'EPSG:32610+5703') to convert z"]
