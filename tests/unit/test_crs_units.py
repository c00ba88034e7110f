"""The length units of a cloud's CRS (io.crs_units), from real WKT strings and LAS GeoTIFF keys:
what the viewer's measuring tool says its numbers are in."""

from __future__ import annotations

import json
import math
import sys
import types
from pathlib import Path

import numpy as np
import pytest
from test_geo_coords import UTM10_NAVD88_WKT1, UTM10_NAVD88_WKT2, UTM11_NAVD88_WKT1, without_pyproj  # (tests/unit is on sys.path)

import gigapoint as gp
from gigapoint.io import crs_units, files_units, horizontal_epsg, vertical_crs
from gigapoint.io.crs import crs_identity
from gigapoint.io.las import geokeys, read_las_header, vertical_in_unit
from gigapoint.viewer import measure as M

DATA = Path(__file__).parent / "data" / "pdal_ept"
US_FOOT = 0.304800609601219  # as EPSG's WKT writes it (1200 / 3937)

FOOT = {"name": "foot", "symbol": "ft", "metres": 0.3048}
METRE = {"name": "metre", "symbol": "m", "metres": 1.0}
UNKNOWN = {"horizontal": None, "vertical": None, "vertical_assumed": False}

# PROJ's WKT2:2019 of EPSG:2927: the base CRS in degrees, the conversion's parameters in both
# units, each axis its own LENGTHUNIT
WASHINGTON_SOUTH_FTUS = (
    'PROJCRS["NAD83(HARN) / Washington South (ftUS)",BASEGEOGCRS["NAD83(HARN)",DATUM["NAD83 (High Accuracy Reference Network)",'
    'ELLIPSOID["GRS 1980",6378137,298.257222101,LENGTHUNIT["metre",1]]],PRIMEM["Greenwich",0,ANGLEUNIT["degree",0.0174532925199433]],'
    'ID["EPSG",4152]],CONVERSION["SPCS83 Washington South zone (US Survey feet)",METHOD["Lambert Conic Conformal (2SP)",ID["EPSG",9802]],'
    'PARAMETER["Latitude of false origin",45.3333333333333,ANGLEUNIT["degree",0.0174532925199433],ID["EPSG",8821]],'
    'PARAMETER["Easting at false origin",1640416.667,LENGTHUNIT["US survey foot",0.304800609601219],ID["EPSG",8826]],'
    'PARAMETER["Northing at false origin",0,LENGTHUNIT["US survey foot",0.304800609601219],ID["EPSG",8827]]],'
    'CS[Cartesian,2],AXIS["easting (X)",east,ORDER[1],LENGTHUNIT["US survey foot",0.304800609601219]],'
    'AXIS["northing (Y)",north,ORDER[2],LENGTHUNIT["US survey foot",0.304800609601219]],'
    'USAGE[SCOPE["Engineering survey, topographic mapping."],AREA["United States (USA) - Washington - counties south of 47\u00b030\'N"],'
    'BBOX[45.54,-124.79,47.61,-116.91]],ID["EPSG",2927]]'
)
# PROJ's WKT2:2019 of EPSG:6339+6360: metres east and north, heights in US survey feet
UTM10_NAVD88_FTUS = (
    'COMPOUNDCRS["NAD83(2011) / UTM zone 10N + NAVD88 height (ftUS)",PROJCRS["NAD83(2011) / UTM zone 10N",'
    'BASEGEOGCRS["NAD83(2011)",DATUM["NAD83 (National Spatial Reference System 2011)",ELLIPSOID["GRS 1980",6378137,298.257222101,'
    'LENGTHUNIT["metre",1]]],PRIMEM["Greenwich",0,ANGLEUNIT["degree",0.0174532925199433]],ID["EPSG",6318]],'
    'CONVERSION["UTM zone 10N",METHOD["Transverse Mercator",ID["EPSG",9807]],PARAMETER["Longitude of natural origin",-123,'
    'ANGLEUNIT["degree",0.0174532925199433],ID["EPSG",8802]],PARAMETER["False easting",500000,LENGTHUNIT["metre",1],ID["EPSG",8806]]],'
    'CS[Cartesian,2],AXIS["easting (E)",east,ORDER[1],LENGTHUNIT["metre",1]],AXIS["northing (N)",north,ORDER[2],LENGTHUNIT["metre",1]]],'
    'VERTCRS["NAVD88 height (ftUS)",VDATUM["North American Vertical Datum 1988"],CS[vertical,1],'
    'AXIS["gravity-related height (H)",up,LENGTHUNIT["US survey foot",0.304800609601219]],ID["EPSG",6360]],'
    'USAGE[SCOPE["Engineering survey, topographic mapping."],AREA["United States (USA) - between 126\u00b0W and 120\u00b0W"],BBOX[30.54,-126,49.09,-119.99]]]'
)
# PROJ's WKT2:2019 of EPSG:4979 (3D: latitude and longitude in degrees, ellipsoidal height in metres)
WGS84_3D = (
    'GEOGCRS["WGS 84",ENSEMBLE["World Geodetic System 1984 ensemble",MEMBER["World Geodetic System 1984 (Transit)"],'
    'MEMBER["World Geodetic System 1984 (G2139)"],ELLIPSOID["WGS 84",6378137,298.257223563,LENGTHUNIT["metre",1]],ENSEMBLEACCURACY[2.0]],'
    'PRIMEM["Greenwich",0,ANGLEUNIT["degree",0.0174532925199433]],CS[ellipsoidal,3],'
    'AXIS["geodetic latitude (Lat)",north,ORDER[1],ANGLEUNIT["degree",0.0174532925199433]],'
    'AXIS["geodetic longitude (Lon)",east,ORDER[2],ANGLEUNIT["degree",0.0174532925199433]],'
    'AXIS["ellipsoidal height (h)",up,ORDER[3],LENGTHUNIT["metre",1]],USAGE[SCOPE["Geodesy."],AREA["World."],BBOX[-90,-180,90,180]],ID["EPSG",4979]]'
)
# GDAL's WKT1 of EPSG:4326
WGS84_WKT1 = (
    'GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563,AUTHORITY["EPSG","7030"]],AUTHORITY["EPSG","6326"]],'
    'PRIMEM["Greenwich",0,AUTHORITY["EPSG","8901"]],UNIT["degree",0.0174532925199433,AUTHORITY["EPSG","9122"]],'
    'AXIS["Latitude",NORTH],AXIS["Longitude",EAST],AUTHORITY["EPSG","4326"]]'
)


def test_autzen_is_in_feet_by_its_wkt_and_by_its_geotiff_keys_alone(autzen_path):
    hdr = read_las_header(autzen_path)
    said = {"horizontal": FOOT, "vertical": FOOT, "vertical_assumed": True}  # its WKT names no vertical CRS: heights as x and y
    assert hdr.crs().startswith('PROJCS["NAD_1983_HARN_Lambert_Conformal_Conic"') and 'UNIT["foot",0.3048' in hdr.crs()
    assert crs_units(hdr.crs()) == said
    keys = geokeys(hdr.vlrs)
    assert keys[3076] == 9002 and 4099 not in keys  # ProjLinearUnitsGeoKey: foot; no VerticalUnitsGeoKey
    assert crs_units(None, keys) == crs_units("EPSG:2992", keys) == said
    assert files_units([autzen_path]) == said


def test_a_compound_crs_gives_its_vertical_parts_unit():
    copc = gp.open(DATA / "autzen_clip_native.copc.laz")  # PDAL's COPC of autzen: WKT1 COMPD_CS, metres and US survey feet
    assert copc.meta["crs"].startswith('COMPD_CS["NAD83 / Oregon LCC (m) + NAVD88 height (ftUS)"')
    us_foot = {"name": "US survey foot", "symbol": "US ft", "metres": US_FOOT}
    assert crs_units(copc.meta["crs"]) == {"horizontal": METRE, "vertical": us_foot, "vertical_assumed": False}
    assert crs_units(UTM10_NAVD88_FTUS) == {"horizontal": METRE, "vertical": us_foot, "vertical_assumed": False}  # WKT2
    ftus = crs_units(WASHINGTON_SOUTH_FTUS)  # WKT2: each axis's unit, not the base CRS's degrees
    assert ftus["horizontal"] == us_foot and ftus["vertical_assumed"]


def test_metres_of_real_ept_and_geographic_crss_in_degrees():
    mercator = json.loads((DATA / "ellipsoid-binary-2k" / "ept.json").read_text())["srs"]["wkt"]
    assert crs_units(mercator) == {"horizontal": METRE, "vertical": METRE, "vertical_assumed": True}
    degree = {"name": "degree", "symbol": "°", "metres": None}
    assert crs_units(WGS84_WKT1) == {"horizontal": degree, "vertical": None, "vertical_assumed": False}  # heights: not said
    assert crs_units(WGS84_3D) == {"horizontal": degree, "vertical": METRE, "vertical_assumed": False}
    assert crs_units(None, {1024: 2, 2048: 4326}) == {"horizontal": degree, "vertical": None, "vertical_assumed": False}
    assert crs_units(None, {1024: 1, 3072: 32610, 3076: 9001, 4099: 9003})["vertical"]["symbol"] == "US ft"


@pytest.mark.parametrize("crs", [None, "", "EPSG:2992", "+proj=geocent +R=1000 +units=m +no_defs", 'PROJCS["cut off', "LOCAL_CS[]"])
def test_units_unknown(crs, monkeypatch):
    monkeypatch.setitem(sys.modules, "pyproj", None)  # (an import of it raises ImportError: an EPSG code alone says nothing)
    assert crs_units(crs) == UNKNOWN
    assert crs_units(crs, {1024: 1, 3072: 32767, 3076: 9036}) == UNKNOWN  # a unit code not known here


def test_measured_lengths_in_the_crs_units():
    us_foot = crs_units(UTM10_NAVD88_FTUS)
    s = M.summary([[0, 0, 0], [30, 40, 10 / US_FOOT]], us_foot)  # 50 m across, 10 m up (in US feet)
    assert s["units"] == us_foot
    assert s["total"]["horizontal"] == 50.0 and math.isclose(s["total"]["length"], math.hypot(50, 10), rel_tol=1e-12)
    assert math.isclose(s["total"]["vertical"], 32.80833333, rel_tol=1e-9)  # heights stay in their own unit
    s = M.summary([[-123.0, 45.0, 10.0], [-123.001, 45.0, 12.0]], crs_units(WGS84_3D))
    assert s["segments"] == [{"length": None, "horizontal": None, "vertical": 2.0}]  # degrees are no length


def write_geokeys_only(path: Path, code: int, more_keys: dict | None = None) -> Path:
    """A LAS 1.2 file naming its CRS by GeoTIFF keys alone: GTModelTypeGeoKey 1 (projected),
    ProjectedCSTypeGeoKey ``code``, no ProjLinearUnitsGeoKey (as many LAS 1.2 files do); and
    ``more_keys`` ({key: value})."""
    laspy = pytest.importorskip("laspy")
    header = laspy.LasHeader(point_format=0, version="1.2")
    header.vlrs.append(geokeys_vlr({1024: 1, 3072: code, **(more_keys or {})}))
    las = laspy.LasData(header)
    las.x = las.y = las.z = np.arange(5.0)
    las.write(str(path))
    return path


def geokeys_vlr(keys: dict):
    """laspy's GeoKeyDirectory VLR of ``keys`` ({key: value}, each held in place: LAS 1.2-1.3 files' CRS)."""
    from laspy.vlrs.known import GeoKeyDirectoryVlr, GeoKeyEntryStruct

    vlr = GeoKeyDirectoryVlr()
    vlr.geo_keys_header.number_of_keys = len(keys)
    vlr.geo_keys = []
    for key_id, value in keys.items():
        key = GeoKeyEntryStruct()
        key.id, key.tiff_tag_location, key.count, key.value_offset = key_id, 0, 1, value
        vlr.geo_keys.append(key)
    return vlr


class FakeAxis:
    def __init__(self, direction: str, unit_name: str, factor: float):
        self.direction, self.unit_name, self.unit_conversion_factor = direction, unit_name, factor


#: what pyproj.CRS.from_epsg(code).axis_info says of these codes (pyproj 3.7.2)
FAKE_EPSG = {
    2994: (False, [FakeAxis("east", "foot", 0.3048), FakeAxis("north", "foot", 0.3048)]),  # NAD83(HARN) / Oregon GIC Lambert (ft)
    26910: (False, [FakeAxis("east", "metre", 1.0), FakeAxis("north", "metre", 1.0)]),  # NAD83 / UTM zone 10N
    4979: (True, [FakeAxis("north", "degree", 0.017453292519943295), FakeAxis("east", "degree", 0.017453292519943295), FakeAxis("up", "metre", 1.0)]),
    4978: (False, [FakeAxis("geocentricX", "metre", 1.0), FakeAxis("geocentricY", "metre", 1.0), FakeAxis("geocentricZ", "metre", 1.0)]),
}


@pytest.fixture
def fake_pyproj(monkeypatch):
    """A pyproj module of the few codes above (another code: its CRSError); the codes looked up."""
    asked = []

    def from_epsg(code):
        asked.append(code)
        if code not in FAKE_EPSG:
            raise RuntimeError(f"crs not found: EPSG:{code}")
        geographic, axes = FAKE_EPSG[code]
        return types.SimpleNamespace(is_geographic=geographic, axis_info=axes)

    module = types.ModuleType("pyproj")
    module.CRS = types.SimpleNamespace(from_epsg=from_epsg)
    monkeypatch.setitem(sys.modules, "pyproj", module)
    return asked


def test_an_epsg_code_without_unit_keys_has_its_units_from_pyproj(tmp_path, fake_pyproj):
    """A LAS 1.2 file naming its CRS by an EPSG code's GeoTIFF keys alone (no ProjLinearUnitsGeoKey)
    was measured in "unknown" units: pyproj, where installed, says the code's axes' units."""
    feet = write_geokeys_only(tmp_path / "oregon.las", 2994)
    assert files_units([feet]) == {"horizontal": FOOT, "vertical": FOOT, "vertical_assumed": True}
    metres = write_geokeys_only(tmp_path / "utm.las", 26910)
    assert files_units([metres]) == {"horizontal": METRE, "vertical": METRE, "vertical_assumed": True}
    assert crs_units(None, {1024: 1, 3072: 26910}) == crs_units("epsg:26910") == files_units([metres])
    degree = {"name": "degree", "symbol": "°", "metres": None}
    assert crs_units("EPSG:4979") == {"horizontal": degree, "vertical": METRE, "vertical_assumed": False}
    assert crs_units("EPSG:4978") == crs_units("EPSG:1234") == UNKNOWN  # geocentric: no east/north axes; a code pyproj knows not
    assert crs_units(None, {1024: 1, 3072: 26910, 3076: 9002})["horizontal"] == FOOT  # a unit key said is taken as said
    assert fake_pyproj == [2994, 26910, 26910, 26910, 26910, 4979, 4978, 1234]  # (none where a unit key says it)


def test_an_epsg_code_without_pyproj_is_in_unknown_units(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "pyproj", None)  # (an import of it raises ImportError)
    assert files_units([write_geokeys_only(tmp_path / "oregon.las", 2994)]) == UNKNOWN
    assert crs_units("EPSG:26910") == UNKNOWN


def test_real_pyprojs_units_of_epsg_codes():
    pytest.importorskip("pyproj")
    assert crs_units(None, {1024: 1, 3072: 2994}) == {"horizontal": FOOT, "vertical": FOOT, "vertical_assumed": True}
    assert crs_units("EPSG:26910") == {"horizontal": METRE, "vertical": METRE, "vertical_assumed": True}
    us_foot = {"name": "US survey foot", "symbol": "US ft", "metres": pytest.approx(US_FOOT, rel=1e-12)}
    assert crs_units("EPSG:2927")["horizontal"] == us_foot
    assert crs_units("EPSG:4979")["vertical"] == METRE and crs_units("EPSG:4978") == UNKNOWN


def test_format_info_of_a_dict_with_a_crs_and_no_units(autzen_path):
    """format_info (public) of a dict a caller built with a crs but no units was a KeyError:
    the units are those of its crs."""
    wkt = read_las_header(autzen_path).crs()
    lines = gp.io.format_info({"path": "made.las", "crs": wkt}).splitlines()
    assert "  units:       x, y: foot; z: foot (assumed: the CRS names no vertical unit)" in lines


def test_render_gsd_reads_the_header_naming_the_crs_once(cli, tmp_path, autzen_path, monkeypatch):
    from PIL import Image

    from gigapoint.io import crs

    read, first = [], crs.first_crs
    monkeypatch.setattr(crs, "first_crs", lambda files: read.append(list(files)) or first(files))
    rc, _, err = cli("render", autzen_path, "-o", tmp_path / "ortho.tif", "--gsd", 20)
    assert rc == 0, err
    assert read == [[autzen_path]]  # its CRS and its units from one read (there were two)
    keys = Image.open(tmp_path / "ortho.tif").tag_v2[34735]  # GeoKeyDirectory: 4 shorts of header, then (key, where, count, value)
    entries = {keys[i]: keys[i + 3] for i in range(4, len(keys), 4)}
    assert entries[3076] == 9002  # ProjLinearUnitsGeoKey: foot, the units that read told


US_FOOT_UNIT = {"name": "US survey foot", "symbol": "US ft", "metres": pytest.approx(US_FOOT, rel=1e-12)}
NAVD88_FTUS = {"epsg": 6360, "name": "NAVD88 height (ftUS)", "unit": US_FOOT_UNIT}


@pytest.mark.parametrize("pyproj_installed", [True, False])
def test_vertical_crs_of_a_compound_wkt_with_pyproj_or_without(pyproj_installed, autzen_path, monkeypatch):
    """What a DSM's heights are measured from and in (GeoTIFF's vertical keys): a compound WKT's
    vertical part, read alike by pyproj and by the WKT parse; none in a 2D or 3D geographic CRS."""
    if not pyproj_installed:
        monkeypatch.setitem(sys.modules, "pyproj", None)  # (an import of it raises ImportError)
    else:
        pytest.importorskip("pyproj")
    copc = gp.open(DATA / "autzen_clip_native.copc.laz")  # PDAL's WKT1 COMPD_CS: EPSG:2991 + 6360
    assert vertical_crs(copc.meta["crs"]) == vertical_crs(UTM10_NAVD88_FTUS) == NAVD88_FTUS  # WKT1, WKT2
    local = UTM10_NAVD88_FTUS.replace(',ID["EPSG",6360]]', "]").replace("NAVD88 height (ftUS)", "site height")
    assert vertical_crs(local) == {"epsg": None, "name": "site height", "unit": US_FOOT_UNIT}  # no code: by its name
    for crs in (read_las_header(autzen_path).crs(), WASHINGTON_SOUTH_FTUS, WGS84_3D, WGS84_WKT1, None, "", 'COMPD_CS["cut off'):
        assert vertical_crs(crs) is None


def test_vertical_crs_of_epsg_codes_needs_pyproj(monkeypatch):
    """An 'EPSG:...' compound code, and a WKT2 whose parts carry no ID of their own (PROJ writes
    the registered compound EPSG:5498's so), name their vertical code through pyproj alone."""
    pyproj = pytest.importorskip("pyproj")
    navd88 = {"epsg": 5703, "name": "NAVD88 height", "unit": METRE}
    nad83_navd88 = pyproj.CRS.from_epsg(5498).to_wkt()
    assert 'ID["EPSG",5703]' not in nad83_navd88
    assert vertical_crs("EPSG:26910+5703") == vertical_crs("EPSG:5498") == vertical_crs(nad83_navd88) == navd88
    assert vertical_crs("EPSG:2994+6360") == NAVD88_FTUS
    assert vertical_crs("EPSG:26910") is None and vertical_crs("EPSG:4979") is None
    monkeypatch.setitem(sys.modules, "pyproj", None)
    assert vertical_crs("EPSG:26910+5703") == {"epsg": 5703, "name": "EPSG:5703", "unit": None}  # its code is text; its unit unknown
    assert vertical_crs("EPSG:5498") is None  # a registered compound code: unknown without pyproj
    assert vertical_crs(nad83_navd88) == {**navd88, "epsg": None}  # its name and unit still


@pytest.mark.parametrize("pyproj_installed", [True, False])
def test_horizontal_epsg_of_compound_codes(pyproj_installed, monkeypatch):
    """The map grid's code of 'EPSG:h+v' is h, text with pyproj or without; a registered compound
    code's (EPSG:5498 NAD83 + NAVD88 height, EPSG:7407 NAD27 / Texas North + NGVD29 height (ftUS))
    is its horizontal part's, which pyproj alone knows (without it the code is taken as it is)."""
    if pyproj_installed:
        pytest.importorskip("pyproj")
    else:
        monkeypatch.setitem(sys.modules, "pyproj", None)
    assert horizontal_epsg("EPSG:26910+5703") == horizontal_epsg(" epsg:26910+5703 ") == horizontal_epsg("EPSG:26910") == 26910
    assert horizontal_epsg("EPSG:4269+5703") == 4269
    registered = {5498: 4269, 7407: 32037} if pyproj_installed else {5498: 5498, 7407: 7407}
    assert {code: horizontal_epsg(f"EPSG:{code}") for code in registered} == registered
    assert horizontal_epsg("EPSG:26910+") is None and horizontal_epsg("EPSG:+5703") is None


def test_units_of_a_compound_code_name_its_heights_unit():
    """'EPSG:h+v' (a LAS file's GeoTIFF keys naming a vertical CRS): lengths in h's unit, heights in v's."""
    pytest.importorskip("pyproj")
    assert crs_units("EPSG:26910+6360") == {"horizontal": METRE, "vertical": US_FOOT_UNIT, "vertical_assumed": False}
    assert crs_units("EPSG:2994+5703") == {"horizontal": FOOT, "vertical": METRE, "vertical_assumed": False}
    keys = {1024: 1, 3072: 26910, 4096: 5703, 4099: 9003}  # NAVD88 in US feet by the file's own unit key
    assert crs_units("EPSG:26910+5703", keys)["vertical"] == US_FOOT_UNIT


def test_geokeys_name_a_compound_crs_where_a_vertical_code_is_given(tmp_path):
    """VerticalCSTypeGeoKey's EPSG code joins the map grid's; a user-defined one, or a code of
    GeoTIFF 1.0's own list EPSG has no vertical CRS for (5001-5033, 5101-5106), leaves the grid's alone
    and the heights' unit to VerticalUnitsGeoKey."""
    said = {}
    for vertical, units in ((5703, None), (6360, 9003), (32767, 9003), (5030, None), (5103, 9002), (0, 9002)):
        keys = {4096: vertical} if vertical else {}
        path = write_geokeys_only(tmp_path / f"v{vertical}.las", 26910, {**keys, **({4099: units} if units else {})})
        said[vertical] = read_las_header(path).crs()
    assert said == {5703: "EPSG:26910+5703", 6360: "EPSG:26910+6360", 32767: "EPSG:26910", 5030: "EPSG:26910", 5103: "EPSG:26910", 0: "EPSG:26910"}
    assert crs_units(None, {1024: 1, 3072: 26910, 4096: 32767, 4099: 9003})["vertical"] == US_FOOT_UNIT


def test_a_vertical_code_with_a_unit_key_without_pyproj_names_the_compound_code(tmp_path, monkeypatch, request):
    """Without pyproj, VerticalCSTypeGeoKey with VerticalUnitsGeoKey (metres or feet) read the
    header's CRS by an UnboundLocalError (pyproj, never imported, named in the except clause);
    'EPSG:h+v' is read (nothing converts heights then)."""
    vertical_in_unit.cache_clear()  # (a result cached with pyproj would hide the run without it)
    request.addfinalizer(vertical_in_unit.cache_clear)  # (nor may this run's results outlive it)
    monkeypatch.setitem(sys.modules, "pyproj", None)  # (an import of it raises ImportError)
    said = {}
    for units in (9001, 9002, 9003):
        path = write_geokeys_only(tmp_path / f"u{units}.las", 26910, {4096: 5703, 4099: units})
        said[units] = read_las_header(path).crs()
    assert said == {9001: "EPSG:26910+5703", 9002: "EPSG:26910+5703", 9003: "EPSG:26910+5703"}


def test_a_vertical_code_in_another_unit_by_its_unit_key_is_read_in_that_unit(tmp_path):
    """VerticalUnitsGeoKey 9003 over NAVD88 height (5703, metres) was read 'EPSG:2994+5703': heights
    in US feet taken as metres (--to-crs left them unconverted). EPSG's NAVD88 in that unit is
    taken; where EPSG has none, the vertical CRS's axis is in the key's unit."""
    pyproj = pytest.importorskip("pyproj")
    laspy = pytest.importorskip("laspy")
    header = laspy.LasHeader(point_format=0, version="1.2")
    header.offsets, header.scales = [636_000.0, 849_000.0, 0.0], [0.01] * 3
    header.vlrs.append(geokeys_vlr({1024: 1, 3072: 2994, 4096: 5703, 4099: 9003}))
    las = laspy.LasData(header)
    las.x, las.y, las.z = np.array([636_000.0, 637_000.0]), np.array([849_000.0, 850_000.0]), np.array([406.26, 520.51])
    las.write(str(tmp_path / "ftus.las"))
    assert read_las_header(tmp_path / "ftus.las").crs() == "EPSG:2994+6360"
    assert crs_units(read_las_header(tmp_path / "ftus.las").crs())["vertical"] == US_FOOT_UNIT
    target = "EPSG:32610+5703"
    gp.convert(tmp_path / "ftus.las", tmp_path / "utm.las", to_crs=target)
    _, _, z = pyproj.Transformer.from_crs("EPSG:2994+6360", target, always_xy=True).transform(np.asarray(las.x), np.asarray(las.y), np.asarray(las.z))
    assert np.abs(np.asarray(laspy.read(str(tmp_path / "utm.las")).z) - z).max() <= 0.001
    assert np.allclose(z, [123.828, 158.652], atol=0.001)
    feet = write_geokeys_only(tmp_path / "egm.las", 32610, {4096: 3855, 4099: 9002})  # EGM2008 height: EPSG has it in metres alone
    read = pyproj.CRS.from_user_input(read_las_header(feet).crs())
    assert read.sub_crs_list[0] == pyproj.CRS.from_epsg(32610) and read.sub_crs_list[1].name == "EGM2008 height (foot)"
    assert crs_units(read_las_header(feet).crs()) == {"horizontal": METRE, "vertical": FOOT, "vertical_assumed": False}
    _, _, z = pyproj.Transformer.from_crs(read, "EPSG:32610+3855", always_xy=True).transform(500_000.0, 4_877_000.0, 100.0)
    assert math.isclose(z, 30.48, rel_tol=1e-9)


@pytest.mark.parametrize("pyproj_installed", [True, False])
def test_crs_identity_of_one_crs_written_several_ways(pyproj_installed, monkeypatch):
    """One CRS as 'EPSG:h+v', as GDAL's COMPD_CS (its text ends ']]]': no code of its own) and as
    PROJ's COMPOUNDCRS is one identity, its parts' codes, with pyproj or without; a WKT1 AUTHORITY
    and a WKT2 ID alike. Another zone, datum or vertical CRS stays another; a registered compound
    code is its parts only where pyproj says what they are."""
    without_pyproj(pyproj_installed, monkeypatch)
    compound = {crs_identity(t) for t in ("EPSG:26910+5703", " epsg:26910+5703 ", UTM10_NAVD88_WKT1, UTM10_NAVD88_WKT2)}
    assert compound == {"EPSG:26910+5703"}
    assert crs_identity(UTM11_NAVD88_WKT1) == "EPSG:26911+5703"
    assert {crs_identity(t) for t in ("EPSG:4326", WGS84_WKT1)} == {"EPSG:4326"}
    differ = ["EPSG:26910", "EPSG:26911", "EPSG:32610", "EPSG:26910+6360", "EPSG:4269+5703", "EPSG:2994"]
    assert len({crs_identity(t) for t in differ}) == len(differ)
    assert (crs_identity("EPSG:5498") == "EPSG:4269+5703") is pyproj_installed  # NAD83 + NAVD88 height, registered


def test_crs_identity_reads_each_text_once_with_pyproj(monkeypatch, autzen_path):
    """Thousands of tiles share a few CRS texts: pyproj reads each once (a text it has not seen
    here: the identities are kept for the process)."""
    pyproj = pytest.importorskip("pyproj")
    autzen = read_las_header(autzen_path).crs()
    for other in ("EPSG:4326", "EPSG:32611", "EPSG:2994", autzen):  # CRSs seen before in the process (a whole test run's, an ESRI WKT too): not read again
        crs_identity(other)
    read, original = [], pyproj.CRS.from_user_input
    # (texts read: CRS.equals hands a CRS it holds to from_user_input too, which reads nothing)
    monkeypatch.setattr(pyproj.CRS, "from_user_input", lambda text, *args: (isinstance(text, str) and read.append(text)) or original(text, *args))
    tiles = [UTM10_NAVD88_WKT1.replace("NAD83 / UTM zone 10N + NAVD88 height", f"survey {i % 3}") for i in range(1000)]
    assert {crs_identity(t) for t in tiles} == {"EPSG:26910+5703"}
    assert len(read) == 3


def test_crs_identity_by_pyproj_tells_an_esri_wkt_from_another_unit(autzen_path):
    """autzen's ESRI WKT (no code of its own) is EPSG:2994 and PROJ's WKT2 of it, by CRS.equals;
    the same in metres is not."""
    pyproj = pytest.importorskip("pyproj")
    autzen = read_las_header(autzen_path).crs()
    same = {crs_identity(t) for t in (autzen, "EPSG:2994", pyproj.CRS.from_user_input(autzen).to_wkt(), pyproj.CRS(2994).to_wkt("WKT1_ESRI"))}
    assert len(same) == 1
    metres = autzen.replace('UNIT["foot",0.3048,AUTHORITY["EPSG","9002"]]', 'UNIT["metre",1,AUTHORITY["EPSG","9001"]]').replace("1312335.958005249", "400000")
    assert crs_identity(metres) not in same | {"EPSG:2994"}


def test_a_ply_files_crs_is_read_once_an_operation(tmp_path, monkeypatch):
    """A PLY file's ``comment crs`` header was parsed again for each question (its CRS, its
    units, the records to write): once an operation (``headers_once``), as LAS headers are."""
    import plyfile

    from gigapoint.io import files_crs, files_crs_units, ply
    from gigapoint.io._base import headers_once

    v = np.zeros(3, [("x", "<f8"), ("y", "<f8"), ("z", "<f8")])
    plyfile.PlyData([plyfile.PlyElement.describe(v, "vertex")], comments=["crs EPSG:32610"]).write(str(tmp_path / "a.ply"))
    parsed = []
    monkeypatch.setattr(ply, "_Header", lambda path, read=ply._Header: parsed.append(path) or read(path))
    with headers_once():
        assert files_crs([tmp_path / "a.ply"]) == "EPSG:32610" and files_crs_units([tmp_path / "a.ply"])[0] == "EPSG:32610"
    assert parsed == [tmp_path / "a.ply"]
