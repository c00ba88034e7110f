"""Real-world coordinates: tiles with different CRSs opened or converted together are warned
about (nothing is reprojected), tiles on different LAS grids merge at the files' values."""

from __future__ import annotations

import struct
import sys
import warnings

import laspy
import numpy as np
import pytest
from laspy.vlrs.known import WktCoordinateSystemVlr
from laspy.vlrs.vlrlist import VLRList

import gigapoint as gp
from gigapoint.errors import GigapointWarning
from gigapoint.io.las import read_las_header

UTM10_WKT = (
    'PROJCS["WGS 84 / UTM zone 10N",GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563]],'
    'PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433]],PROJECTION["Transverse_Mercator"],'
    'PARAMETER["central_meridian",-123],PARAMETER["scale_factor",0.9996],PARAMETER["false_easting",500000],'
    'UNIT["metre",1],AUTHORITY["EPSG","32610"]]'
)


# GDAL's WKT1 of EPSG:26910+5703 (NAD83 / UTM zone 10N + NAVD88 height): a COMPD_CS of the two
# parts, each with its AUTHORITY code, the whole with none (its text ends in ']]]')
UTM10_NAVD88_WKT1 = (
    'COMPD_CS["NAD83 / UTM zone 10N + NAVD88 height",PROJCS["NAD83 / UTM zone 10N",GEOGCS["NAD83",DATUM["North_American_Datum_1983",'
    'SPHEROID["GRS 1980",6378137,298.257222101,AUTHORITY["EPSG","7019"]],AUTHORITY["EPSG","6269"]],PRIMEM["Greenwich",0,AUTHORITY["EPSG","8901"]],'
    'UNIT["degree",0.0174532925199433,AUTHORITY["EPSG","9122"]],AUTHORITY["EPSG","4269"]],PROJECTION["Transverse_Mercator"],'
    'PARAMETER["latitude_of_origin",0],PARAMETER["central_meridian",-123],PARAMETER["scale_factor",0.9996],PARAMETER["false_easting",500000],'
    'PARAMETER["false_northing",0],UNIT["metre",1,AUTHORITY["EPSG","9001"]],AXIS["Easting",EAST],AXIS["Northing",NORTH],AUTHORITY["EPSG","26910"]],'
    'VERT_CS["NAVD88 height",VERT_DATUM["North American Vertical Datum 1988",2005,AUTHORITY["EPSG","5103"]],UNIT["metre",1,AUTHORITY["EPSG","9001"]],'
    'AXIS["Gravity-related height",UP],AUTHORITY["EPSG","5703"]]]'
)
# PROJ's WKT2:2019 of the same (its USAGE left out): the parts' codes as ID["EPSG",n]
UTM10_NAVD88_WKT2 = (
    'COMPOUNDCRS["NAD83 / UTM zone 10N + NAVD88 height",PROJCRS["NAD83 / UTM zone 10N",BASEGEOGCRS["NAD83",DATUM["North American Datum 1983",'
    'ELLIPSOID["GRS 1980",6378137,298.257222101,LENGTHUNIT["metre",1]]],PRIMEM["Greenwich",0,ANGLEUNIT["degree",0.0174532925199433]],ID["EPSG",4269]],'
    'CONVERSION["UTM zone 10N",METHOD["Transverse Mercator",ID["EPSG",9807]],PARAMETER["Latitude of natural origin",0,ANGLEUNIT["degree",0.0174532925199433],'
    'ID["EPSG",8801]],PARAMETER["Longitude of natural origin",-123,ANGLEUNIT["degree",0.0174532925199433],ID["EPSG",8802]],'
    'PARAMETER["Scale factor at natural origin",0.9996,SCALEUNIT["unity",1],ID["EPSG",8805]],PARAMETER["False easting",500000,LENGTHUNIT["metre",1],'
    'ID["EPSG",8806]],PARAMETER["False northing",0,LENGTHUNIT["metre",1],ID["EPSG",8807]]],CS[Cartesian,2],AXIS["(E)",east,ORDER[1],'
    'LENGTHUNIT["metre",1]],AXIS["(N)",north,ORDER[2],LENGTHUNIT["metre",1]],ID["EPSG",26910]],VERTCRS["NAVD88 height",'
    'VDATUM["North American Vertical Datum 1988"],CS[vertical,1],AXIS["gravity-related height (H)",up,LENGTHUNIT["metre",1]],ID["EPSG",5703]]]'
)
# GDAL's WKT1 of EPSG:2994, NAD83(HARN) / Oregon GIC Lambert (ft): autzen's projection, by OGC's names
OREGON_LAMBERT_FT_WKT1 = (
    'PROJCS["NAD83(HARN) / Oregon GIC Lambert (ft)",GEOGCS["NAD83(HARN)",DATUM["NAD83_High_Accuracy_Reference_Network",SPHEROID["GRS 1980",'
    '6378137,298.257222101,AUTHORITY["EPSG","7019"]],AUTHORITY["EPSG","6152"]],PRIMEM["Greenwich",0,AUTHORITY["EPSG","8901"]],'
    'UNIT["degree",0.0174532925199433,AUTHORITY["EPSG","9122"]],AUTHORITY["EPSG","4152"]],PROJECTION["Lambert_Conformal_Conic_2SP"],'
    'PARAMETER["latitude_of_origin",41.75],PARAMETER["central_meridian",-120.5],PARAMETER["standard_parallel_1",43],PARAMETER["standard_parallel_2",45.5],'
    'PARAMETER["false_easting",1312335.958],PARAMETER["false_northing",0],UNIT["foot",0.3048,AUTHORITY["EPSG","9002"]],'
    'AXIS["Easting",EAST],AXIS["Northing",NORTH],AUTHORITY["EPSG","2994"]]'
)
# the next zone east (EPSG:26911+5703), written as UTM10_NAVD88_WKT1 is: another CRS
UTM11_NAVD88_WKT1 = UTM10_NAVD88_WKT1.replace("zone 10N", "zone 11N").replace("-123", "-117").replace("26910", "26911")


def geokeys(epsg: int, vertical: int | None = None) -> laspy.VLR:
    """A LAS 1.2 GeoTIFF key directory naming a projected CRS by its EPSG code (and ``vertical``:
    VerticalCSTypeGeoKey's code, heights' CRS; LasHeader.crs reads both as 'EPSG:h+v')."""
    keys = [(1024, 0, 1, 1), (3072, 0, 1, epsg)]  # model type projected; ProjectedCSTypeGeoKey
    keys += [(4096, 0, 1, vertical)] if vertical else []
    data = struct.pack("<4H", 1, 1, 0, len(keys)) + b"".join(struct.pack("<4H", *k) for k in keys)
    return laspy.VLR("LASF_Projection", 34735, "GeoKeyDirectoryTag", data)


def write_tile(path, xyz, scale, offset, crs=None, version="1.2", evlrs=()):
    """A LAS tile; ``crs``: a VLR; ``evlrs``: LAS 1.4 EVLRs after the points."""
    header = laspy.LasHeader(point_format=6 if version == "1.4" else 0, version=version)
    header.scales, header.offsets = np.array([scale] * 3), np.array(offset, np.float64)
    if crs is not None:
        header.vlrs.append(crs)
    las = laspy.LasData(header)
    if evlrs:
        las.evlrs = VLRList(list(evlrs))
    las.x, las.y, las.z = xyz.T
    las.write(str(path))
    return np.column_stack([las.x, las.y, las.z])  # the file's values: on its grid


def tile_points(seed, x0):
    rng = np.random.default_rng(seed)
    return rng.uniform(0, 50, (2000, 3)) * [1, 1, 0.1] + [x0, 4_800_000.0, 100.0]


def crs_warnings(caught) -> list[str]:
    return [str(w.message) for w in caught if issubclass(w.category, GigapointWarning) and "CRS" in str(w.message)]


@pytest.mark.parametrize("progressive", [False, True])
def test_tiles_with_different_crs_are_warned_about(tmp_path, progressive):
    """Two UTM zones' tiles drawn in one space: said once, with each file's CRS (it was silent)."""
    write_tile(tmp_path / "a.las", tile_points(0, 500_000.0), 0.001, (500_000, 4_800_000, 0), geokeys(32610))
    write_tile(tmp_path / "b.las", tile_points(1, 500_050.0), 0.001, (500_000, 4_800_000, 0), geokeys(32611))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cloud = gp.open(tmp_path, progressive=progressive)
        if progressive:
            cloud.wait()
    assert cloud.n_points == 4000
    said = crs_warnings(caught)
    assert len(said) == 1, said
    assert "2 different CRSs (a.las: EPSG:32610; b.las: EPSG:32611)" in said[0] and "not reprojected" in said[0]


def test_a_ply_naming_another_crs_among_las_tiles_is_warned_about(tmp_path):
    """A PLY's ``comment crs`` line is its CRS as a LAS header's is (the PLY was skipped: silent)."""
    write_tile(tmp_path / "a.las", tile_points(0, 500_000.0), 0.001, (500_000, 4_800_000, 0), geokeys(32610))
    write_tile(tmp_path / "b.las", tile_points(1, 500_050.0), 0.001, (500_000, 4_800_000, 0), geokeys(32611))
    gp.open(tmp_path / "b.las").save(tmp_path / "b.ply")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cloud = gp.open([tmp_path / "a.las", tmp_path / "b.ply"])
    assert cloud.n_points == 4000
    said = crs_warnings(caught)
    assert len(said) == 1 and "2 different CRSs (a.las: EPSG:32610; b.ply: EPSG:32611)" in said[0], said


def test_one_crs_as_wkt_and_as_geokeys_is_not_warned_about(tmp_path):
    """The same CRS (EPSG 32610) as a LAS 1.4 WKT in one tile and GeoTIFF keys in the other."""
    wkt = laspy.VLR("LASF_Projection", 2112, "OGC WKT", UTM10_WKT.encode() + b"\0")
    write_tile(tmp_path / "a.las", tile_points(0, 500_000.0), 0.001, (500_000, 4_800_000, 0), wkt, version="1.4")
    write_tile(tmp_path / "b.las", tile_points(1, 500_050.0), 0.001, (500_000, 4_800_000, 0), geokeys(32610))
    assert gp.io.file_info(tmp_path / "a.las")["crs"].startswith('PROJCS["WGS 84 / UTM zone 10N"')
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gp.open(tmp_path)
    assert crs_warnings(caught) == []


def test_convert_of_tiles_with_different_crs_warns_once(tmp_path):
    write_tile(tmp_path / "a.las", tile_points(0, 500_000.0), 0.001, (500_000, 4_800_000, 0), geokeys(32610))
    write_tile(tmp_path / "b.las", tile_points(1, 500_050.0), 0.001, (500_000, 4_800_000, 0), geokeys(32611))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gp.convert([tmp_path / "a.las", tmp_path / "b.las"], tmp_path / "out")
    said = crs_warnings(caught)
    assert len(said) == 1 and "a.las: EPSG:32610; b.las: EPSG:32611" in said[0] and "the output takes the first CRS named" in said[0]


@pytest.mark.parametrize("how", ["open", "progressive", "convert"])
def test_tiles_without_a_crs_among_tiles_with_one_are_named(tmp_path, how):
    """One tile names EPSG:32610, four name none (VLRs lost, or another CRS unsaid): that was
    silent. Said once, naming three of the four; a conversion's output takes the CRS named."""
    write_tile(tmp_path / "a.las", tile_points(0, 500_000.0), 0.001, (500_000, 4_800_000, 0), geokeys(32610))
    for i, name in enumerate("bcde"):
        write_tile(tmp_path / f"{name}.las", tile_points(i + 1, 500_050.0 + 50 * i), 0.001, (500_000, 4_800_000, 0))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if how == "convert":
            gp.convert(sorted(tmp_path.glob("*.las")), tmp_path / "out")
        else:
            cloud = gp.open(tmp_path, progressive=how == "progressive")
            if how == "progressive":
                cloud.wait()
    said = crs_warnings(caught)
    assert len(said) == 1, said
    assert said[0].startswith("b.las, c.las, d.las and 1 more name no CRS, where a.las names EPSG:32610: ")
    assert said[0].endswith("not reprojected, so they may not line up" + ("; the output takes the first CRS named" if how == "convert" else ""))
    if how == "convert":
        assert gp.lod.octree_info(tmp_path / "out")["crs"] == "EPSG:32610"


def test_tiles_of_two_crss_and_one_without_are_said_in_one_warning(tmp_path):
    write_tile(tmp_path / "a.las", tile_points(0, 500_000.0), 0.001, (500_000, 4_800_000, 0), geokeys(32610))
    write_tile(tmp_path / "b.las", tile_points(1, 500_050.0), 0.001, (500_000, 4_800_000, 0), geokeys(32611))
    write_tile(tmp_path / "c.las", tile_points(2, 500_100.0), 0.001, (500_000, 4_800_000, 0))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gp.open(tmp_path)
    want = (
        "the files name 2 different CRSs (a.las: EPSG:32610; b.las: EPSG:32611); c.las names no CRS: their coordinates "
        "are used as they are, not reprojected, so they do not line up"
    )
    assert crs_warnings(caught) == [want]


def test_a_wkt_in_an_evlr_counts_as_the_files_crs(tmp_path):
    """LAS 1.4 may keep its WKT in an EVLR (laspy writes it there, its WKT bit unset): the
    mixed-CRS check read the VLRs only, so a tile of another CRS beside it was not warned about."""
    other = laspy.VLR("test", 1, "before the WKT", b"x" * 100)  # (the header walk skips its data)
    write_tile(tmp_path / "a.las", tile_points(0, 500_000.0), 0.001, (500_000, 4_800_000, 0), version="1.4",
               evlrs=[other, WktCoordinateSystemVlr(UTM10_WKT)])  # fmt: skip
    write_tile(tmp_path / "b.las", tile_points(1, 500_050.0), 0.001, (500_000, 4_800_000, 0), geokeys(32611))
    assert gp.io.file_info(tmp_path / "a.las")["crs"] == UTM10_WKT
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gp.open(tmp_path)
        gp.convert([tmp_path / "a.las"], tmp_path / "a.copc.laz")
    said = crs_warnings(caught)
    assert len(said) == 1 and "2 different CRSs (a.las: EPSG:32610; b.las: EPSG:32611)" in said[0], said
    assert gp.open(tmp_path / "a.copc.laz").meta["crs"] == UTM10_WKT


def test_info_of_a_folder_of_tiles_of_two_crss_does_not_call_the_crs_unknown(tmp_path):
    """A folder's summed ``info`` printed "crs: unknown" above "crs differs: ...": known, and they
    differ. Now the one line that says which (a WKT by its name, not its 400 characters)."""
    wkt = laspy.VLR("LASF_Projection", 2112, "OGC WKT", UTM10_WKT.encode() + b"\0")
    write_tile(tmp_path / "a.las", tile_points(0, 500_000.0), 0.001, (500_000, 4_800_000, 0), wkt, version="1.4")
    write_tile(tmp_path / "b.las", tile_points(1, 500_050.0), 0.001, (500_000, 4_800_000, 0), geokeys(32611), version="1.4")
    summed = gp.io.folder_info(tmp_path, [gp.io.file_info(tmp_path / f) for f in ("a.las", "b.las")])
    assert summed["las_version"] == "1.4" and "crs" not in summed  # (``info --json``: no "crs": null)
    assert summed["details"]["crs differs"] == "WGS 84 / UTM zone 10N (EPSG:32610) (1 file); EPSG:32611 (1 file)"
    lines = gp.io.format_info(summed).splitlines()
    assert [line for line in lines if "crs" in line] == ["  crs differs: WGS 84 / UTM zone 10N (EPSG:32610) (1 file); EPSG:32611 (1 file)"]


def test_info_of_a_folder_counts_one_crs_as_wkt_and_as_geotiff_keys_once(tmp_path):
    """EPSG:32610 as WKT in one tile and as GeoTIFF keys in another is one CRS, as the mixed-CRS
    warning counts it (io.crs_identity); the folder's summary said "crs differs"."""
    wkt = laspy.VLR("LASF_Projection", 2112, "OGC WKT", UTM10_WKT.encode() + b"\0")
    write_tile(tmp_path / "a.las", tile_points(0, 500_000.0), 0.001, (500_000, 4_800_000, 0), wkt, version="1.4")
    write_tile(tmp_path / "b.las", tile_points(1, 500_050.0), 0.001, (500_000, 4_800_000, 0), geokeys(32610), version="1.4")
    summed = gp.io.folder_info(tmp_path, [gp.io.file_info(tmp_path / f) for f in ("a.las", "b.las")])
    assert "crs differs" not in summed["details"] and summed["crs"] == gp.io.file_info(tmp_path / "a.las")["crs"]
    assert "  crs:         WGS 84 / UTM zone 10N (EPSG:32610)" in gp.io.format_info(summed).splitlines()


def wkt_vlr(wkt: str) -> laspy.VLR:
    """A LAS 1.4 OGC WKT VLR of ``wkt``."""
    return laspy.VLR("LASF_Projection", 2112, "OGC WKT", wkt.encode() + b"\0")


def without_pyproj(pyproj_installed: bool, monkeypatch) -> None:
    """pyproj's import made to fail where ``pyproj_installed`` is False (it needs it where True)."""
    if pyproj_installed:
        pytest.importorskip("pyproj")
    else:
        monkeypatch.setitem(sys.modules, "pyproj", None)  # (an import of it raises ImportError)


@pytest.mark.parametrize("pyproj_installed", [True, False])
def test_one_compound_crs_as_geotiff_keys_wkt1_and_wkt2_is_one_crs(tmp_path, pyproj_installed, monkeypatch):
    """EPSG:26910+5703 as GeoTIFF keys with a vertical code ('EPSG:26910+5703'), as GDAL's
    COMPD_CS and as PROJ's COMPOUNDCRS: they were three CRSs (the whole WKT their identity: no
    code at its end), so opening, converting or summing up such tiles said they were mixed. The
    next zone's COMPD_CS is another CRS, said by its two codes; pyproj or not."""
    without_pyproj(pyproj_installed, monkeypatch)
    write_tile(tmp_path / "a.las", tile_points(0, 500_000.0), 0.001, (500_000, 4_800_000, 0), geokeys(26910, 5703))
    write_tile(tmp_path / "b.las", tile_points(1, 500_050.0), 0.001, (500_000, 4_800_000, 0), wkt_vlr(UTM10_NAVD88_WKT1), version="1.4")
    write_tile(tmp_path / "c.las", tile_points(2, 500_100.0), 0.001, (500_000, 4_800_000, 0), wkt_vlr(UTM10_NAVD88_WKT2), version="1.4")
    files = [tmp_path / f"{name}.las" for name in "abc"]
    assert [gp.io.file_info(f)["crs"][:9] for f in files] == ["EPSG:2691", "COMPD_CS[", "COMPOUNDC"]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert gp.open(tmp_path).n_points == 6000
        gp.convert(files, tmp_path / "out")
    assert crs_warnings(caught) == []
    summed = gp.io.folder_info(tmp_path, [gp.io.file_info(f) for f in files])
    assert "crs differs" not in summed["details"] and summed["crs"] == "EPSG:26910+5703"
    write_tile(tmp_path / "d.las", tile_points(3, 500_150.0), 0.001, (500_000, 4_800_000, 0), wkt_vlr(UTM11_NAVD88_WKT1), version="1.4")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gp.open(tmp_path)
    said = crs_warnings(caught)
    assert len(said) == 1 and "the files name 2 different CRSs (a.las: EPSG:26910+5703; d.las: EPSG:26911+5703)" in said[0], said


@pytest.mark.parametrize("pyproj_installed", [True, False])
def test_autzens_esri_wkt_and_its_epsg_code_are_one_crs_where_pyproj_tells(tmp_path, autzen_path, pyproj_installed, monkeypatch):
    """autzen's ESRI-flavoured WKT names no code; EPSG:2994 (NAD83(HARN) / Oregon GIC Lambert
    (ft)) is the same projection, as GeoTIFF keys and as GDAL's OGC WKT: pyproj tells them one
    (``CRS.equals``), the text alone cannot (still warned without pyproj, the two forms of 2994
    one). The same WKT in metres (false easting 400,000 m) is another CRS either way."""
    without_pyproj(pyproj_installed, monkeypatch)
    wkt = read_las_header(autzen_path).crs()  # ESRI's names (NAD_1983_HARN_Lambert_Conformal_Conic), no EPSG code of its own
    write_tile(tmp_path / "a.las", tile_points(0, 500_000.0), 0.01, (0, 0, 0), wkt_vlr(wkt), version="1.4")
    write_tile(tmp_path / "b.las", tile_points(1, 500_050.0), 0.01, (0, 0, 0), geokeys(2994))
    write_tile(tmp_path / "c.las", tile_points(2, 500_100.0), 0.01, (0, 0, 0), wkt_vlr(OREGON_LAMBERT_FT_WKT1), version="1.4")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gp.open(tmp_path)
    said = crs_warnings(caught)
    if pyproj_installed:
        assert said == []
    else:
        assert len(said) == 1 and '2 different CRSs (a.las: PROJCS["NAD_1983_HARN_Lambert_Conformal_Conic",GEOGCS["GCS_N; b.las: EPSG:2994)' in said[0], said
    (tmp_path / "c.las").unlink()
    metres = wkt.replace('UNIT["foot",0.3048,AUTHORITY["EPSG","9002"]]', 'UNIT["metre",1,AUTHORITY["EPSG","9001"]]').replace("1312335.958005249", "400000")
    assert metres != wkt
    write_tile(tmp_path / "b.las", tile_points(1, 500_050.0), 0.01, (0, 0, 0), wkt_vlr(metres), version="1.4")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gp.open(tmp_path)
    said = crs_warnings(caught)
    assert len(said) == 1 and '2 different CRSs (a.las: ' in said[0] and '; b.las: PROJCS["NAD_1983_HARN_Lambert_Conformal_Conic"' in said[0], said


def test_tiles_on_different_las_grids_merge_at_the_files_values(tmp_path):
    """Same CRS, different scales and offsets: every point where its file puts it (to 1e-7 m)."""
    a = write_tile(tmp_path / "a.las", tile_points(0, 637_000.0), 0.001, (637_000, 4_800_000, 0), geokeys(32610))
    b = write_tile(tmp_path / "b.las", tile_points(1, 637_050.0), 0.0001, (637_049.12345, 4_799_999.5, 99.98765), geokeys(32610))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        got = gp.open(tmp_path).positions()
    assert crs_warnings(caught) == []
    want = np.concatenate([a, b])
    got, want = got[np.lexsort(got.T)], want[np.lexsort(want.T)]
    assert np.abs(got - want).max() < 1e-7


def test_copc_of_a_geotiff_keyed_file_keeps_its_crs_or_says_why(tmp_path):
    """COPC holds a CRS as WKT only: a LAS 1.2 file's GeoTIFF keys (EPSG:32610) become WKT through
    pyproj; without it the output had no CRS and nothing said so."""
    try:
        import pyproj
    except ImportError:
        pyproj = None
    write_tile(tmp_path / "a.las", tile_points(0, 500_000.0), 0.001, (500_000, 4_800_000, 0), geokeys(32610))
    out = tmp_path / "a.copc.laz"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gp.convert([tmp_path / "a.las"], out)
    said = [str(w.message) for w in caught if "is not written" in str(w.message)]
    if pyproj is not None:
        assert said == [] and "32610" in gp.open(out).meta["crs"]
    else:
        assert gp.open(out).meta["crs"] is None
        assert len(said) == 1 and "the inputs' CRS (EPSG:32610) is not written" in said[0] and "pip install pyproj" in said[0]


def test_info_shows_offsets_to_the_scale_and_a_wkt_crs_by_name_and_code(tmp_path):
    """An ECEF offset at 0.1 mm printed whole (10 digits cut 4200000.1234 to 4200000.123); a WKT
    CRS by its name and EPSG code (the first 100 characters of the WKT cut the code off)."""
    from gigapoint.io import file_info, format_info

    ecef = write_tile(tmp_path / "ecef.las", tile_points(0, 0.0) - [0, 4_800_000, 0] + [4_200_000.5, 900_000.5, 4_700_000.5], 0.0001,
                      (4_200_000.1234, 900_000.5678, 4_700_000.9012))  # fmt: skip
    text = format_info(file_info(tmp_path / "ecef.las"))
    assert "offset:      4200000.1234, 900000.5678, 4700000.9012" in text
    assert f"bounds min:  {ecef[:, 0].min():.4f}, " in text and "crs:         unknown" in text
    wkt = laspy.VLR("LASF_Projection", 2112, "OGC WKT", UTM10_WKT.encode() + b"\0")
    write_tile(tmp_path / "utm.las", tile_points(0, 500_000.0), 0.001, (500_000, 4_800_000, 0), wkt, version="1.4")
    assert "crs:         WGS 84 / UTM zone 10N (EPSG:32610)\n" in format_info(file_info(tmp_path / "utm.las"))


@pytest.mark.parametrize("progressive", [False, True])
def test_picked_position_is_the_files_value_where_its_offset_is_off_the_scales_decimals(tmp_path, progressive):
    """PDAL's offset 'auto' (the data's minimum: 637000.123456 at scale 0.001): a pick showed the
    position rounded to 3 decimals, up to half a step (0.5 mm) from the file's value."""
    from gigapoint.io import file_info, format_info

    written = write_tile(tmp_path / "auto.las", tile_points(3, 637_000.0), 0.001, (637_000.123456, 4_800_000.654321, 100.0123))
    cloud = gp.open(tmp_path / "auto.las", progressive=progressive)
    if progressive:
        cloud.wait()
    frame = gp.render_frame(cloud, width=160, height=120, size_mode="fixed")
    picked = [frame.point_info(i)["position"] for i in np.unique(frame.index[frame.index >= 0])[:200]]
    assert len(picked) == 200
    for p in picked:  # each the file's value as its float prints (no noise digits), none rounded off it
        assert np.abs(written - p).max(axis=1).min() < 1e-9, p
        assert all(len(repr(v).split(".")[1]) <= 6 for v in p), p
    lo = written.min(axis=0)
    assert f"bounds min:  {lo[0]:.6f}, {lo[1]:.6f}, {lo[2]:.4f} (header)" in format_info(file_info(tmp_path / "auto.las"))


@pytest.mark.parametrize("fmt", ["potree", "copc", "gigapoint"])
def test_convert_says_where_a_tile_is_off_the_outputs_las_grid(tmp_path, fmt):
    """Potree and COPC hold every point as integers on one grid (the finest scale, the first
    file's offset): a tile whose offset is off it by a fraction of a step (PDAL's offset 'auto')
    has its points moved up to half a step, which was silent. The gigapoint format keeps them."""
    write_tile(tmp_path / "a.las", tile_points(0, 637_000.0), 0.001, (637_000.123456, 4_800_000.654321, 100.0123))
    write_tile(tmp_path / "b.las", tile_points(1, 637_050.0), 0.001, (637_050.987654, 4_800_000.111111, 100.00077))
    write_tile(tmp_path / "c.las", tile_points(2, 637_100.0), 0.0001, (637_100.123456, 4_800_000.154321, 100.0124))  # on a's grid
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gp.convert([tmp_path / "a.las", tmp_path / "b.las", tmp_path / "c.las"], tmp_path / ("out.copc.laz" if fmt == "copc" else "out"), format=fmt)
    said = [str(w.message) for w in caught if "LAS grid" in str(w.message)]
    if fmt == "gigapoint":
        assert said == []
    else:
        want = (
            "b.las: off the LAS grid the output stores every point on (scale 0.0001, 0.0001, 0.0001, offset 637000.123456, "
            "4800000.654321, 100.0123: a.las's): their points move to it, by up to half a step (5e-05)"
        )
        assert said == [want]


def test_an_object_at_ecef_coordinates_renders_as_at_the_origin(tmp_path):
    """A 1 m sheet sampled at 1 cm, 0.1 mm scale, at (4.2e6, 0.9e6, 4.7e6) and at the origin, seen
    from 0.3 m: the same pixels (float64 camera-relative matrices: no jitter, no coarser grid)."""
    g = np.arange(0, 1.0001, 0.01)
    x, y = np.meshgrid(g, g, indexing="ij")
    sheet = np.column_stack([x.ravel(), y.ravel(), 0.05 * np.sin(12 * x.ravel())])
    shift = np.array([4_200_000.12, 900_000.57, 4_700_000.9])
    write_tile(tmp_path / "origin.las", sheet, 0.0001, (0, 0, 0))
    write_tile(tmp_path / "ecef.las", sheet + shift, 0.0001, np.floor(shift))
    frames = []
    for name, at in (("origin", 0.0), ("ecef", shift)):
        cam = gp.Camera.look_at(np.add((0.3, 0.2, 0.3), at), np.add((0.35, 0.3, 0.0), at), up=(0, 0, 1), width=200, height=150)
        frames.append(gp.render_frame(gp.open(tmp_path / f"{name}.las"), cam, size_mode="fixed"))
    assert (frames[0].index >= 0).sum() > 500
    np.testing.assert_array_equal(frames[0].index >= 0, frames[1].index >= 0)
    np.testing.assert_array_equal(frames[0].depth, frames[1].depth)
