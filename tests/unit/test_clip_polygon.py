"""Clip polygons (io/polygon.py, the filter's ``clip_polygon``): the kernel against a plain Python
ray-casting reference (a polygon with a hole, a multipolygon, a 2 000-vertex boundary, points on
edges), GeoJSON and WKT read alike, autzen cut through ``gp.open``, ``convert -o x.laz`` and
``render``, an octree read only where its nodes meet the polygon, the filter's spec through JSON
(a Dask task's), and every bad input a one-line error naming the file before anything is read."""

from __future__ import annotations

import json
import math
import re
import struct
import sys

import laspy
import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import EmptyCloudError, InputError, warnings_kept
from gigapoint.io import read_chunks
from gigapoint.io.filters import PointFilter, point_filter
from gigapoint.io.polygon import clip_polygon_of
from gigapoint.lod.store import Arena, OctreeCloud

SQUARE_WITH_HOLE = [[[0, 0], [10, 0], [10, 10], [0, 10], [0, 0]], [[2, 2], [6, 2], [6, 6], [2, 6], [2, 2]]]
CONCAVE = [[[12, 0], [20, 0], [20, 10], [16, 4], [12, 10], [12, 0]]]  # a V cut out of its top
#: autzen's middle (feet), a quadrilateral with a square hole
SITE = {
    "type": "Feature",
    "properties": {},
    "geometry": {
        "type": "Polygon",
        "coordinates": [
            [[636400, 848900], [637200, 849000], [637000, 849600], [636300, 849400], [636400, 848900]],
            [[636600, 849100], [636800, 849100], [636800, 849300], [636600, 849300], [636600, 849100]],
        ],
    },
}
SITE_WKT = "POLYGON ((636400 848900, 637200 849000, 637000 849600, 636300 849400, 636400 848900), (636600 849100, 636800 849100, 636800 849300, 636600 849300, 636600 849100))"


def ray_casting(x: float, y: float, rings) -> bool:
    """Even-odd over one polygon's rings, edges included: the reference, one point at a time."""
    inside = False
    for ring in rings:
        for (x1, y1), (x2, y2) in zip(ring, ring[1:] + ring[:1]):
            if min(x1, x2) <= x <= max(x1, x2) and min(y1, y2) <= y <= max(y1, y2) and (x2 - x1) * (y - y1) == (y2 - y1) * (x - x1):
                return True  # on an edge
            if (y1 > y) != (y2 > y) and x < x1 + (y - y1) * (x2 - x1) / (y2 - y1):
                inside = not inside
    return inside


def reference(xy: np.ndarray, polygons) -> np.ndarray:
    """Inside any of ``polygons`` (each a list of rings)."""
    rings = [[[tuple(map(float, v)) for v in ring] for ring in polygon] for polygon in polygons]
    return np.array([any(ray_casting(float(x), float(y), polygon) for polygon in rings) for x, y in xy])


def star(n: int, centre=(30.0, 30.0)) -> list:
    """A wiggly star of ``n`` vertices (concave everywhere), radius 5 to 15."""
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    r = 10 + 5 * np.sin(37 * t)
    return [np.column_stack([centre[0] + r * np.cos(t), centre[1] + r * np.sin(t)]).tolist()]


@pytest.mark.parametrize(
    "geometry",
    [
        {"type": "Polygon", "coordinates": SQUARE_WITH_HOLE},
        {"type": "MultiPolygon", "coordinates": [SQUARE_WITH_HOLE, CONCAVE]},
        {"type": "FeatureCollection", "features": [{"type": "Feature", "geometry": {"type": "Polygon", "coordinates": star(2_000)}}]},
    ],
    ids=["hole", "multipolygon", "2000-vertex"],
)
def test_points_inside_match_a_ray_casting_reference(geometry):
    polygon = clip_polygon_of(geometry, "test")
    polygons = [p for p in (geometry["coordinates"] if "coordinates" in geometry else [star(2_000)])]
    polygons = [polygons] if geometry.get("type") == "Polygon" else polygons
    lo, hi = polygon.lo - 3, polygon.hi + 3
    xy = np.random.default_rng(7).uniform(lo, hi, (4_000, 2))
    want = reference(xy, polygons)
    got = polygon.inside(np.column_stack([xy, np.zeros(len(xy))]))
    assert np.array_equal(got, want)
    assert 500 < np.count_nonzero(want) < 3_500  # (both sides well sampled)


def test_overlapping_features_keep_their_overlap_and_a_hole_another_covers(autzen_path, autzen):
    """Two Features of a collection that overlap keep the points of their union (even-odd over all
    their rings left their overlap out: autzen kept 40,319 points of 58,034); a hole of one that
    the other covers keeps its points too."""
    west = [[[0, 0], [10, 0], [10, 10], [0, 10], [0, 0]], [[6, 2], [9, 2], [9, 8], [6, 8], [6, 2]]]  # a hole under east
    east = [[[5, 0], [15, 0], [15, 10], [5, 10], [5, 0]]]
    features = {"type": "FeatureCollection", "features": [{"type": "Feature", "geometry": {"type": "Polygon", "coordinates": p}} for p in (west, east)]}
    polygon = clip_polygon_of(features, "test")
    points = {(2, 5): True, (7, 5): True, (12, 5): True, (5, 5): True, (7.5, 1): True, (16, 5): False, (-1, 5): False}
    assert dict(zip(points, polygon.inside(np.array([[x, y, 0.0] for x, y in points])).tolist())) == points
    xy = np.random.default_rng(3).uniform(-2, 17, (4_000, 2))
    assert np.array_equal(polygon.inside(np.column_stack([xy, np.zeros(len(xy))])), reference(xy, [west, east]))

    xyz = autzen[0]
    (x0, y0), (x1, y1) = xyz[:, :2].mean(axis=0) - (300, 200), xyz[:, :2].mean(axis=0) + (300, 200)
    halves = [[[[a, y0], [b, y0], [b, y1], [a, y1], [a, y0]]] for a, b in ((x0, x1 - 200), (x0 + 200, x1))]  # overlapping by 200 ft
    collection = {"type": "FeatureCollection", "features": [{"type": "Feature", "geometry": {"type": "Polygon", "coordinates": h}} for h in halves]}
    in_box = (xyz[:, 0] >= x0) & (xyz[:, 0] <= x1) & (xyz[:, 1] >= y0) & (xyz[:, 1] <= y1)
    assert gp.open(autzen_path, clip_polygon=collection).n_points == np.count_nonzero(in_box) == 58_034


def test_a_feature_without_geometry_is_passed_over():
    """A Feature whose geometry is null (RFC 7946: unlocated; QGIS writes one for a row without a
    geometry) holds no area: the collection's other Features clip (it was refused: 'GeoJSON of type
    None'); a collection of none but those holds no polygon."""
    unlocated = {"type": "Feature", "properties": {"name": "no survey yet"}, "geometry": None}
    polygon = clip_polygon_of({"type": "FeatureCollection", "features": [unlocated, SITE]}, "site.geojson")
    assert polygon == clip_polygon_of(SITE, "site.geojson") and polygon.features == [0]
    with pytest.raises(InputError, match=r"^site\.geojson: holds no polygon$"):
        clip_polygon_of({"type": "FeatureCollection", "features": [unlocated]}, "site.geojson")


def test_ewkt_names_the_crs_its_polygon_is_moved_from(autzen_path, tmp_path):
    """PostGIS's EWKT, 'SRID=4326;POLYGON ((...))', as text or in a file, is the polygon in the
    CRS its SRID names, moved into the files' as a GeoJSON naming it is (it was 'no such file')."""
    pytest.importorskip("pyproj")
    ring = [[-123.0723, 44.0495], [-123.0703, 44.0495], [-123.0703, 44.0515], [-123.0723, 44.0515], [-123.0723, 44.0495]]
    wkt = f"POLYGON (({', '.join(f'{x} {y}' for x, y in ring)}))"
    (tmp_path / "site.wkt").write_text(f"SRID=4326; {wkt}\n")
    for ewkt in (f"SRID=4326;{wkt}", tmp_path / "site.wkt"):
        polygon = clip_polygon_of(ewkt, "test")
        assert polygon.epsg == 4326 and np.array_equal(polygon.edges, clip_polygon_of(wkt, "test").edges)
    named = {"type": "Polygon", "coordinates": [ring], "crs": {"type": "name", "properties": {"name": "EPSG:4326"}}}
    assert gp.open(autzen_path, clip_polygon=f"SRID=4326;{wkt}").n_points == gp.open(autzen_path, clip_polygon=named).n_points == 51_774


def test_a_polygon_naming_its_crs_is_moved_into_a_ply_files_crs_as_into_a_las_files(autzen_path, tmp_path):
    """A PLY's ``comment crs`` line names its CRS as a LAS header does: a polygon in EPSG:4326 over
    autzen saved as PLY clips what it clips of the LAZ (it kept nothing: only LAS headers were read)."""
    pytest.importorskip("pyproj")
    ply = tmp_path / "autzen.ply"
    gp.open(autzen_path, colors="rgba").save(ply)
    ring = [[-123.0723, 44.0495], [-123.0703, 44.0495], [-123.0703, 44.0515], [-123.0723, 44.0515], [-123.0723, 44.0495]]
    named = {"type": "Polygon", "coordinates": [ring], "crs": {"type": "name", "properties": {"name": "EPSG:4326"}}}
    assert gp.open(ply, clip_polygon=named).n_points == gp.open(autzen_path, clip_polygon=named).n_points == 51_774


def test_points_on_edges_and_vertices_are_kept_those_in_holes_not():
    polygon = clip_polygon_of({"type": "MultiPolygon", "coordinates": [SQUARE_WITH_HOLE, CONCAVE]}, "test")
    x, y = np.meshgrid(np.arange(-1.0, 22.0, 0.5), np.arange(-1.0, 12.0, 0.5))  # the vertices and edges among them
    xy = np.column_stack([x.ravel(), y.ravel()])
    got = polygon.inside(np.column_stack([xy, np.zeros(len(xy))]))
    assert np.array_equal(got, reference(xy, [SQUARE_WITH_HOLE, CONCAVE]))
    points = {(0, 0): True, (10, 5): True, (2, 4): True, (4, 4): False, (6, 6): True, (16, 4): True, (16, 8): False, (10.5, 5): False, (11, 5): False}
    inside = polygon.inside(np.array([[px, py, 0.0] for px, py in points], np.float64))
    assert dict(zip(points, inside.tolist())) == points
    assert not polygon.inside(np.array([[np.nan, 5.0, 0.0], [5.0, np.nan, 0.0]])).any()


def test_geojson_and_wkt_files_and_text_give_one_polygon(tmp_path, monkeypatch):
    geojson, wkt = tmp_path / "site.geojson", tmp_path / "POLYGON.wkt"  # (a file, not WKT text, by that name)
    geojson.write_text(json.dumps(SITE))
    wkt.write_text(SITE_WKT + "\n")
    monkeypatch.chdir(tmp_path)  # ("POLYGON.wkt": a file name, not WKT text)
    polygons = [clip_polygon_of(value, "test") for value in (geojson, "POLYGON.wkt", SITE_WKT, SITE["geometry"])]
    assert all(np.array_equal(p.edges, polygons[0].edges) for p in polygons)
    assert len(polygons[0].edges) == 8
    assert polygons[0].describe() == f"clip polygon {geojson} (1 hole, 8 vertices)"
    multi = clip_polygon_of("MULTIPOLYGON (((0 0, 1 0, 1 1, 0 0)), ((5 5, 6 5, 6 6, 5 5)))", "test")
    assert multi.describe() == "clip polygon WKT MULTIPOLYGON (((0 0, 1 0, 1 1,... (2 polygons, 6 vertices)"


@pytest.fixture(scope="module")
def autzen(autzen_path):
    chunks = list(read_chunks(autzen_path))
    xyz = np.concatenate([c.xyz for c in chunks])
    return xyz, reference(xyz[:, :2], [SITE["geometry"]["coordinates"]])


def test_open_keeps_autzen_inside_the_site(autzen_path, autzen, tmp_path):
    xyz, inside = autzen
    site = tmp_path / "site.geojson"
    site.write_text(json.dumps(SITE))
    cloud = gp.open(autzen_path, clip_polygon=site)
    assert cloud.n_points == np.count_nonzero(inside) == 59_071
    kept = np.sort(np.concatenate([c.xyz for c in cloud.chunks()])[:, 0])
    assert np.allclose(kept, np.sort(xyz[inside, 0]), atol=0.01)  # (the cloud's grid)
    assert gp.open(autzen_path, clip_polygon=SITE_WKT, classes=[2]).n_points < 59_071  # with the other filters


def test_convert_to_laz_render_and_tile_keep_the_site(cli, autzen_path, autzen, tmp_path):
    xyz, inside = autzen
    site = tmp_path / "site.geojson"
    site.write_text(json.dumps(SITE))
    out = tmp_path / "site.laz"
    rc, _, err = cli("convert", autzen_path, "-o", out, "--clip-polygon", site, "--quiet")
    assert rc == 0, err
    las = laspy.read(str(out))
    assert len(las.points) == 59_071
    assert reference(np.column_stack([las.x, las.y])[::50], [SITE["geometry"]["coordinates"]]).all()
    rc, out_text, err = cli("render", autzen_path, "-o", tmp_path / "site.png", "-W", 120, "-H", 80, "--clip-polygon", SITE_WKT)
    assert rc == 0, err
    assert "59,071 points" in out_text
    rc, out_text, err = cli("tile", autzen_path, "--size", 500, "-o", tmp_path / "tiles", "--clip-polygon", site, "-q")
    assert rc == 0, err
    assert "6 tiles of 500 x 500 (laz), 59,071 points" in out_text


def _grid_las(path):
    """A 300 x 300 grid of points a unit apart (z 0), as a LAS file."""
    x, y = np.meshgrid(np.arange(0.0, 300.0), np.arange(0.0, 300.0))
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.scales, header.offsets = [0.001] * 3, [0.0, 0.0, 0.0]
    las = laspy.LasData(header)
    las.x, las.y, las.z = x.ravel() + 0.25, y.ravel() + 0.25, np.zeros(x.size)
    las.classification = np.full(x.size, 2, np.uint8)
    las.write(str(path))
    return path


def test_an_octree_reads_only_the_nodes_meeting_the_polygon(cli, tmp_path, monkeypatch):
    las = _grid_las(tmp_path / "grid.las")
    octree_dir = tmp_path / "grid"
    gp.convert([las], octree_dir, max_leaf=100)
    area = {"type": "Polygon", "coordinates": [[[20, 20], [60, 25], [40, 70]], [[35, 35], [45, 35], [40, 45]]]}  # a triangle with a hole
    want = np.count_nonzero(reference(np.column_stack([np.arange(90_000) % 300 + 0.25, np.arange(90_000) // 300 + 0.25]), [area["coordinates"]]))
    loads = []  # render: the nodes its frame loads (level of detail, every node meeting the polygon with no threshold)
    real_load = Arena._load
    monkeypatch.setattr(Arena, "_load", lambda self, nd, *rest: loads.append(nd) or real_load(self, nd, *rest))
    site = tmp_path / "area.geojson"
    site.write_text(json.dumps(area))
    rc, out, err = cli("render", octree_dir, "-o", tmp_path / "a.png", "-W", 100, "-H", 100, "--clip-polygon", site, "--lod-threshold-px", 0)
    assert rc == 0, err
    assert f", {want:,} of 90,000 points drawn)" in out
    octree = gp.open(octree_dir)
    full = int(np.count_nonzero(octree.counts))
    assert len(loads) == len(set(loads)) and 0 < len(loads) < full / 3, (len(loads), full)
    # every node left unread holds no point inside
    keep = point_filter(clip_polygon=area)
    for index in sorted(set(np.flatnonzero(octree.counts).tolist()) - set(loads)):
        assert not keep.polygon.inside(octree.node_points(index)["xyz"]).any()
    reads = []  # section: the nodes whose every point it reads
    real = OctreeCloud.node_points
    monkeypatch.setattr(OctreeCloud, "node_points", lambda self, index: reads.append(index) or real(self, index))
    cut = gp.section(octree_dir, (0, 40.25, 300, 40.25), 1, clip_polygon=area)  # along a row of the grid, through the hole
    assert cut.cloud.n_points == gp.section(las, (0, 40.25, 300, 40.25), 1, clip_polygon=area).cloud.n_points == 20
    assert 0 < len(reads) < full / 3


def test_the_spec_carries_the_polygon_through_json():
    keep = point_filter(classes=[2], clip_polygon={"type": "MultiPolygon", "coordinates": [SQUARE_WITH_HOLE, CONCAVE]})
    again = PointFilter.from_spec(json.loads(json.dumps(keep.as_spec())))
    assert again == keep and again.describe() == keep.describe()
    xyz = np.random.default_rng(3).uniform(-1, 21, (2_000, 3))
    assert np.array_equal(again.polygon.inside(xyz), keep.polygon.inside(xyz))
    assert PointFilter.from_spec(point_filter(classes=[2]).as_spec()).polygon is None
    assert "clip_polygon" not in point_filter(classes=[2]).as_spec()  # (a conversion's fingerprint without one is as before)


def test_boxes_meet_the_polygon_where_sampled_points_say():
    """Boxes on a grid: those an edge crosses or lying inside meet it; those wholly outside, or
    wholly in its hole, not (what 20 x 20 points sampled in each box say)."""
    keep = PointFilter(polygon=clip_polygon_of({"type": "Polygon", "coordinates": SQUARE_WITH_HOLE}, "test"))
    corners = np.array([(x, y) for x in np.arange(-2.0, 12.0, 1.5) for y in np.arange(-2.0, 12.0, 1.5)])
    lo, hi = np.column_stack([corners + 0.1, np.zeros(len(corners))]), np.column_stack([corners + 1.2, np.ones(len(corners))])
    meets = keep.meets(lo, hi)
    s = np.linspace(0, 1, 20)
    sampled = []
    for box_lo, box_hi in zip(lo, hi):
        gx, gy = np.meshgrid(box_lo[0] + s * (box_hi[0] - box_lo[0]), box_lo[1] + s * (box_hi[1] - box_lo[1]))
        sampled.append(keep.polygon.inside(np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])).any())
    assert np.array_equal(meets, sampled)
    assert 0 < np.count_nonzero(meets) < len(meets) and not keep.meets(np.array([[3.0, 3.0, 0]]), np.array([[5.0, 5.0, 1]]))[0]  # (in the hole)
    lo, hi = keep.clipped_bounds([-50.0, 1.0, -5.0], [50.0, 60.0, 5.0])
    assert lo.tolist() == [0.0, 1.0, -5.0] and hi.tolist() == [10.0, 10.0, 5.0]


#: autzen's corner in longitude/latitude (it lies near -123.07, 44.06): a triangle of a few miles
LON_LAT_TRIANGLE = [[-123.1, 44.0], [-123.0, 44.0], [-123.0, 44.1]]
AUTZEN_CRS = "NAD_1983_HARN_Lambert_Conformal_Conic (WKT)"


def test_a_polygon_far_from_the_points_says_so(autzen_path, tmp_path):
    far = tmp_path / "far.geojson"  # (autzen's site 100,000 feet east: in its CRS, in the wrong place)
    far.write_text(json.dumps({"type": "Polygon", "coordinates": [[[x + 100_000, y] for x, y in SITE["geometry"]["coordinates"][0]]]}))
    with pytest.raises(EmptyCloudError) as err:
        gp.open(autzen_path, clip_polygon=far)
    assert str(err.value) == (
        f"{autzen_path}: no point passes the filter (clip polygon {far} (4 vertices)): 110,000 points read; "
        f"{far} spans x 736300..737200, y 848900..849600, far from the points' x 636002..637179, y 848935..849498: give it in the files' coordinates"
    )


def test_a_polygon_naming_a_crs_over_a_file_naming_none_is_taken_as_it_is_and_said_so(tmp_path):
    grid = _grid_las(tmp_path / "grid.las")  # (names no CRS: nothing to move the polygon into)
    named = tmp_path / "named.geojson"
    crs = {"type": "name", "properties": {"name": "EPSG:32610"}}
    named.write_text(json.dumps({"type": "Polygon", "crs": crs, "coordinates": [[[1000, 1000], [1100, 1000], [1100, 1100]]]}))
    with warnings_kept() as kept, pytest.raises(EmptyCloudError) as err:
        gp.open(grid, clip_polygon=named)
    assert kept == []
    assert str(err.value).endswith(
        f"{named} spans x 1000..1100, y 1000..1100, far from the points' x 0.25..299.25, y 0.25..299.25: give it in the files' coordinates; "
        f"{named} names EPSG:32610 (it is taken in the files' coordinates, not reprojected)"
    )
    assert gp.open(grid, clip_polygon={"type": "Polygon", "crs": crs, "coordinates": [[[0, 0], [100, 0], [100, 100], [0, 100]]]}).n_points == 100 * 100


def test_a_lon_lat_polygon_without_a_crs_over_projected_files_is_refused_naming_both(cli, autzen_path, tmp_path, monkeypatch):
    """RFC 7946 GeoJSON (no crs member) is longitude/latitude: over autzen's feet it would clip
    nothing; refused before a point is read, with or without pyproj (never guessed)."""
    lonlat = tmp_path / "lonlat.geojson"
    lonlat.write_text(json.dumps({"type": "Polygon", "coordinates": [LON_LAT_TRIANGLE]}))
    want = (
        f"{lonlat}: x -123.1..-123, y 44..44.1 looks like longitude/latitude (RFC 7946 GeoJSON) while {autzen_path} is in {AUTZEN_CRS}: "
        f"add a crs member naming its CRS, or reproject it into the files' coordinates"
    )
    with pytest.raises(InputError) as err:
        gp.open(autzen_path, clip_polygon=lonlat)
    assert str(err.value) == want
    for command in (["convert", autzen_path, "-o", tmp_path / "out.laz"], ["render", autzen_path, "-o", tmp_path / "out.png"], ["info", "--stats", autzen_path]):
        rc, _, err_text = cli(*command, "--clip-polygon", lonlat)
        assert rc != 0 and err_text.strip() == f"error: {want}", command
    assert not (tmp_path / "out.laz").exists()
    monkeypatch.setitem(sys.modules, "pyproj", None)  # (without pyproj alike: autzen's WKT says its feet)
    with pytest.raises(InputError, match="looks like longitude/latitude"):
        gp.open(autzen_path, clip_polygon=lonlat)
    grid = _grid_las(tmp_path / "grid.las")  # a file naming no CRS: small numbers may be its own coordinates, not refused
    with pytest.raises(EmptyCloudError, match=r"\(3 vertices\)\): 90,000 points read$"):
        gp.open(grid, clip_polygon=lonlat)


def test_without_pyproj_a_polygon_naming_lon_lat_over_projected_files_is_refused(autzen_path, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "pyproj", None)  # (import pyproj raises ImportError)
    degrees = tmp_path / "lonlat.geojson"
    crs = {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::4326"}}
    degrees.write_text(json.dumps({"type": "Polygon", "crs": crs, "coordinates": [LON_LAT_TRIANGLE]}))
    with pytest.raises(InputError) as err:
        gp.open(autzen_path, clip_polygon=degrees)
    assert str(err.value) == (
        f"{degrees}: names EPSG:4326 while {autzen_path} is in {AUTZEN_CRS}: moving it there needs pyproj (pip install 'gigapoint[gis]'), "
        f"or reproject it into the files' coordinates"
    )


def test_a_geojson_dicts_placement_refusals_start_with_the_operation_as_its_ring_errors_do(autzen_path, tmp_path, monkeypatch):
    """A bare GeoJSON dict refused in placing it over the files (lon/lat naming no CRS over
    autzen's feet; a CRS PROJ does not know; a CRS to move from without pyproj) said 'the GeoJSON
    geometry: ...' with no 'open: ' where its ring and hole errors start 'open: clip_polygon={...}';
    now 'open: the GeoJSON geometry: ', as gp.volume names its own, the dict quoted at most once."""
    lonlat = {"type": "Polygon", "coordinates": [LON_LAT_TRIANGLE]}
    unknown = {**lonlat, "crs": {"type": "name", "properties": {"name": "EPSG:99999"}}}
    far = {"type": "Polygon", "coordinates": [[[x + 100_000, y] for x, y in SITE["geometry"]["coordinates"][0]]]}

    def refusal(error, call, polygon) -> str:
        with pytest.raises(error) as err:
            call(polygon)
        assert str(err.value).count(repr(polygon)) <= 1
        return str(err.value)

    def opened(polygon):
        return gp.open(autzen_path, clip_polygon=polygon)

    looks = f"x -123.1..-123, y 44..44.1 looks like longitude/latitude (RFC 7946 GeoJSON) while {autzen_path} is in {AUTZEN_CRS}: "
    add_crs = "add a crs member naming its CRS, or reproject it into the files' coordinates"
    assert refusal(InputError, opened, lonlat) == f"open: the GeoJSON geometry: {looks}{add_crs}"
    converted = refusal(InputError, lambda polygon: gp.convert(autzen_path, tmp_path / "out.laz", clip_polygon=polygon), lonlat)
    assert converted == f"convert: the GeoJSON geometry: {looks}{add_crs}"
    assert refusal(InputError, opened, unknown) == (
        f"open: the GeoJSON geometry: names EPSG:99999, a CRS PROJ does not know: cannot move it into {autzen_path}'s CRS"
    )
    assert refusal(EmptyCloudError, opened, far) == (  # (the far-away hint: named once, the dict never quoted)
        f"{autzen_path}: no point passes the filter (clip polygon the GeoJSON geometry (4 vertices)): 110,000 points read; "
        "the GeoJSON geometry spans x 736300..737200, y 848900..849600, far from the points' x 636002..637179, y 848935..849498: give it in the files' coordinates"
    )
    monkeypatch.setitem(sys.modules, "pyproj", None)  # (import pyproj raises ImportError)
    degrees = {**lonlat, "crs": {"type": "name", "properties": {"name": "EPSG:4326"}}}
    assert refusal(InputError, opened, degrees) == (
        f"open: the GeoJSON geometry: names EPSG:4326 while {autzen_path} is in {AUTZEN_CRS}: moving it there needs pyproj (pip install 'gigapoint[gis]'), "
        f"or reproject it into the files' coordinates"
    )
    with pytest.raises(InputError, match=r"^open: clip_polygon=\{'type': 'Polygon', .*: the polygon's points lie on one line"):  # (its ring errors, as before)
        opened({**degrees, "coordinates": [LON_LAT_TRIANGLE[:2]]})
    # (the label is the messages', not the polygon's data: a conversion's fingerprint and a Dask task's copy keep its source)
    kept = point_filter(clip_polygon=lonlat, where="convert").polygon
    assert kept.named == "convert: the GeoJSON geometry" and kept.as_spec()["source"] == "the GeoJSON geometry"
    assert kept.describe() == "clip polygon the GeoJSON geometry (3 vertices)"
    assert PointFilter.from_spec(point_filter(clip_polygon=lonlat, where="convert").as_spec()).polygon.named == kept.named  # (a Dask task's copy)


def test_a_geojson_naming_another_crs_than_the_files_is_warned_of_without_pyproj(tmp_path, monkeypatch):
    las_path = _grid_las(tmp_path / "utm.las")
    las = laspy.read(str(las_path))
    las.header.vlrs.append(UTM10_GEOKEYS)
    las.write(str(las_path))
    area = {"type": "Polygon", "coordinates": [[[0, 0], [100, 0], [100, 100], [0, 100]]]}
    sites = {}
    for epsg in (32611, 32610):
        sites[epsg] = tmp_path / f"site{epsg}.geojson"
        sites[epsg].write_text(json.dumps({**area, "crs": {"type": "name", "properties": {"name": f"EPSG:{epsg}"}}}))
    with warnings_kept() as kept:
        assert gp.open(las_path, clip_polygon=sites[32610]).n_points == 100 * 100  # (its own CRS: as it is, with pyproj or not)
    assert kept == []
    monkeypatch.setitem(sys.modules, "pyproj", None)  # (import pyproj raises ImportError: nothing to move it with)
    with warnings_kept() as kept:
        cloud = gp.open(las_path, clip_polygon=sites[32611])
    assert cloud.n_points == 100 * 100  # (taken in the file's coordinates)
    assert [message for message, _ in kept] == [f"{sites[32611]} names EPSG:32611, {las_path} EPSG:32610: the polygon is taken in the files' coordinates, not reprojected"]



#: GeoTIFF keys naming ProjectedCSTypeGeoKey = EPSG:32610 (UTM zone 10N)
UTM10_GEOKEYS = laspy.VLR("LASF_Projection", 34735, "GeoTIFF keys", struct.pack("<8H", 1, 1, 0, 1, 3072, 0, 1, 32610))


def _utm10_tiles(tmp_path, crs_vlrs: dict) -> list:
    """``_grid_las`` tiles named by ``crs_vlrs``' keys, each naming UTM zone 10N by its VLR."""
    tiles = []
    for name, vlr in crs_vlrs.items():
        las = laspy.read(str(_grid_las(tmp_path / name)))
        las.header.vlrs.append(vlr)
        las.write(str(tmp_path / name))
        tiles.append(tmp_path / name)
    return tiles


def _utm10_square_in_lon_lat(pyproj):
    """A square over x and y 0..100 of UTM zone 10N, given in lon/lat (EPSG:4326)."""
    lon, lat = pyproj.Transformer.from_crs("EPSG:32610", "EPSG:4326", always_xy=True).transform([0, 100, 100, 0], [0, 0, 100, 100])
    crs = {"type": "name", "properties": {"name": "EPSG:4326"}}
    return clip_polygon_of({"type": "Polygon", "crs": crs, "coordinates": [[*zip(lon, lat)]]}, "test")


def _counted_moves(monkeypatch) -> list:
    """The target CRSs filters.moved_polygon is called with from now on."""
    from gigapoint.io import filters

    moves = []
    real = filters.moved_polygon
    monkeypatch.setattr(filters, "moved_polygon", lambda *args, **kwargs: moves.append(args[2]) or real(*args, **kwargs))
    return moves


def test_a_polygon_naming_another_crs_is_moved_once_a_crs_not_once_a_file(tmp_path, monkeypatch):
    """Two tiles in UTM zone 10 (GeoTIFF keys), a square over their first 100 units given in
    lon/lat: moved into their CRS once, and each tile's placement is that one polygon."""
    pyproj = pytest.importorskip("pyproj")
    tiles = _utm10_tiles(tmp_path, {"a.las": UTM10_GEOKEYS, "b.las": UTM10_GEOKEYS})
    polygon = _utm10_square_in_lon_lat(pyproj)
    moves = _counted_moves(monkeypatch)
    assert gp.open(*tiles, clip_polygon=polygon).n_points == 2 * 100 * 100  # (x and y 0.25 .. 99.25 of each tile)
    assert len(moves) == 1 and list(polygon.moved_by_crs) == ["EPSG:32610"]
    assert set(polygon.placed_by_file) == set(map(str, tiles))
    assert polygon.placed_by_file[str(tiles[0])] is polygon.placed_by_file[str(tiles[1])] is polygon.moved_by_crs["EPSG:32610"]


def test_one_crs_written_two_ways_moves_the_polygon_once(tmp_path, monkeypatch):
    """UTM zone 10 as GeoTIFF keys ('EPSG:32610') in one tile and as WKT in the other: the cache
    was keyed by the CRS's text, so the polygon was moved twice and the tiles held two polygons.
    It is moved once (keyed by io.crs_identity), and each tile keeps what it keeps alone."""
    pyproj = pytest.importorskip("pyproj")
    wkt = laspy.VLR("LASF_Projection", 2112, "OGC WKT", pyproj.CRS.from_epsg(32610).to_wkt("WKT1_GDAL").encode() + b"\0")
    keyed, written = _utm10_tiles(tmp_path, {"keyed.las": UTM10_GEOKEYS, "written.las": wkt})
    alone = [gp.open(tile, clip_polygon=_utm10_square_in_lon_lat(pyproj)).n_points for tile in (keyed, written)]
    assert alone == [100 * 100, 100 * 100]  # (x and y 0.25 .. 99.25 of each tile)
    polygon = _utm10_square_in_lon_lat(pyproj)
    moves = _counted_moves(monkeypatch)
    assert gp.open(keyed, written, clip_polygon=polygon).n_points == sum(alone)
    assert len(moves) == 1 and list(polygon.moved_by_crs) == ["EPSG:32610"]
    assert polygon.placed_by_file[str(keyed)] is polygon.placed_by_file[str(written)]


ON_ONE_LINE = "the polygon's points lie on one line: it has no area; move a point off the line"
BAD = {
    "missing": (None, "no such file (nor WKT text: POLYGON ((x y, ...)))"),
    "not-polygon-text": ("x,y,z\n1,2,3\n", "neither GeoJSON nor WKT (POLYGON, MULTIPOLYGON): not a clip polygon"),
    "broken-json": ("{\"type\": ", "not valid GeoJSON (Expecting value: line 1 column 10 (char 9))"),
    "two-vertices": (json.dumps({"type": "Polygon", "coordinates": [[[0, 0], [1, 1], [0, 0], [1, 1]]]}), ON_ONE_LINE),
    "one-spot": (json.dumps({"type": "Polygon", "coordinates": [[[3, 4], [3, 4], [3, 4], [3, 4]]]}), "the polygon's points are at one x, y: it has no area"),
    "wkt-on-one-line": ("POLYGON ((636400 848900, 637000 849200, 637600 849500, 636400 848900))", ON_ONE_LINE),
    "hole-on-one-line": (
        json.dumps({"type": "MultiPolygon", "coordinates": [SQUARE_WITH_HOLE, [CONCAVE[0], [[13, 1], [14, 2], [15, 3], [13, 1]]]]}),
        ON_ONE_LINE.replace("the polygon's", "polygon 2's hole 1's"),
    ),
    "nan": ("POLYGON ((0 0, 1 0, nan 1, 0 0))", "a polygon vertex is NaN or infinite ([nan, 1.0])"),
    "linestring": (json.dumps({"type": "LineString", "coordinates": [[0, 0], [1, 1]]}), "a LineString, not a polygon: a clip polygon is a Polygon or MultiPolygon"),
    "point": (json.dumps({"type": "Feature", "geometry": {"type": "Point", "coordinates": [0, 0]}}), "a Point, not a polygon: a clip polygon is a Polygon or MultiPolygon"),
    "wkt-unclosed": ("POLYGON ((0 0, 1 0, 1 1)", "not WKT POLYGON or MULTIPOLYGON (a ')' is missing)"),
    "wkt-linestring": ("LINESTRING (0 0, 1 1)", "a LINESTRING, not a polygon: a clip polygon is a POLYGON or MULTIPOLYGON"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_polygons_are_one_line_errors_naming_the_file_before_reading(cli, tmp_path, case):
    content, message = BAD[case]
    area = tmp_path / f"{case}.txt"
    if content is not None:
        area.write_text(content)
    with pytest.raises(InputError) as err:
        gp.open(tmp_path / "missing.laz", clip_polygon=str(area))  # (read first, it would be "no such file")
    want = f"open: clip_polygon={str(area)!r}: {message}" if content is None else f"{area}: {message}"
    assert str(err.value) == want
    rc, _, cli_err = cli("render", tmp_path / "missing.laz", "-o", tmp_path / "x.png", "--clip-polygon", area)
    assert rc != 0 and cli_err.strip() == "error: " + (f"render: --clip-polygon {area}: {message}" if content is None else f"{area}: {message}")


def test_a_polygon_on_one_line_is_refused_by_section_and_orthophoto_before_reading(tmp_path):
    """A ring on one line was read, every point of the file, to "no point passes the filter (clip
    polygon ...)" (of points in memory: those on its line kept); refused as gp.open refuses it."""
    line = "POLYGON ((0 0, 1 1, 2 2, 0 0))"
    want = f"^{re.escape(f'WKT {line}: {ON_ONE_LINE}')}$"
    with pytest.raises(InputError, match=want):
        gp.section(tmp_path / "missing.laz", (0, 0, 2, 2), 1, clip_polygon=line)
    with pytest.raises(InputError, match=want):
        gp.orthophoto(tmp_path / "missing.laz", 1, clip_polygon=line)
    on_line = gp.from_arrays(np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [2.0, 2.0, 0.0], [1.0, 0.0, 0.0]]))
    with pytest.raises(InputError, match=want):
        gp.section(on_line, (0, 0, 2, 2), 1, clip_polygon=line)


@pytest.mark.parametrize(
    ("ring", "problem"),
    [
        ([[637000.1, 4850000.3], [637010.2, 4850010.6], [637020.3, 4850020.9]], ON_ONE_LINE),  # UTM-sized, slanted: rounding off the line
        ([[0, 0], [10, 0], [0, 10], [10, 10]], None),  # a bow tie: its shoelace 0, its halves areas all the same
        ([[0, 0], [100, 0], [50, 0.01]], None),  # thin, but not a line
    ],
    ids=["slanted-utm", "bow-tie", "thin"],
)
def test_no_area_is_points_on_one_line_not_a_shoelace_of_zero(ring, problem):
    from gigapoint.io.polygon import no_area_problem

    assert no_area_problem(ring) == problem


def test_a_polygon_in_the_crs_a_bound_one_binds_is_not_moved_and_one_from_lon_lat_moves_by_its_towgs84():
    """moved_polygon compares CRSs by crs.same_horizontal (a WKT1 with TOWGS84 is the CRS it
    binds) and moves by the bound CRS: its TOWGS84 (zero here) moves the datum, not PROJ's own
    shift for Amersfoort (~100 m apart at Amersfoort)."""
    pyproj = pytest.importorskip("pyproj")
    from gigapoint.io.polygon import moved_polygon

    rd = pyproj.CRS.from_epsg(28992)
    wkt1 = rd.to_wkt("WKT1_GDAL").replace('DATUM["Amersfoort",', 'DATUM["Amersfoort",TOWGS84[0,0,0,0,0,0,0],')
    bound = pyproj.CRS.from_user_input(wkt1)
    compound = pyproj.CRS.from_user_input(f'COMPD_CS["RD + NAP",{wkt1},{pyproj.CRS.from_epsg(5709).to_wkt("WKT1_GDAL")}]')
    assert bound.is_bound and compound.sub_crs_list[0].is_bound
    square = clip_polygon_of("POLYGON ((155000 463000, 155100 463000, 155100 463100, 155000 463100, 155000 463000))", "test")
    for target in (bound, compound):
        kept = moved_polygon(square, rd, target)
        assert kept.polygons[0][0] is square.polygons[0][0] and kept.moved_from == "Amersfoort / RD New"
    lon_lat = clip_polygon_of("POLYGON ((5.387 52.156, 5.388 52.156, 5.388 52.157, 5.387 52.157, 5.387 52.156))", "test")
    by_towgs84 = pyproj.Transformer.from_crs("EPSG:4326", bound, always_xy=True).transform(5.387, 52.156)
    by_proj = pyproj.Transformer.from_crs("EPSG:4326", rd, always_xy=True).transform(5.387, 52.156)
    assert math.dist(by_towgs84, by_proj) > 50  # (the binding matters)
    for target in (bound, compound):
        moved = moved_polygon(lon_lat, pyproj.CRS.from_epsg(4326), target)
        assert np.allclose(moved.polygons[0][0][0], by_towgs84, rtol=0, atol=1e-6)


@pytest.mark.parametrize(
    ("text", "kind"),
    [("POINT (1 2)", "POINT"), ("LineString Z (0 0 0, 1 1 1)", "LINESTRING"), ("MULTIPOINT ((0 0), (1 1))", "MULTIPOINT"),
     ("GEOMETRYCOLLECTION (POINT (1 2))", "GEOMETRYCOLLECTION")],
)
def test_wkt_text_of_another_geometry_is_named(cli, tmp_path, text, kind):
    """(was "no such file (nor WKT text: POLYGON ((x y, ...)))")"""
    reason = f"a {kind}, not a polygon: a clip polygon is a POLYGON or MULTIPOLYGON"
    with pytest.raises(InputError) as err:
        gp.open(tmp_path / "missing.laz", clip_polygon=text)
    assert str(err.value) == f"open: clip_polygon={text!r}: {reason}"
    rc, _, cli_err = cli("render", tmp_path / "missing.laz", "-o", tmp_path / "x.png", "--clip-polygon", text)
    assert (rc, cli_err) == (1, f"error: render: --clip-polygon {text}: {reason}\n")


def test_a_folder_given_as_the_clip_polygon_is_said_to_be_one(cli, autzen_path, tmp_path):
    (tmp_path / "areas").mkdir()
    rc, _, err = cli("convert", autzen_path, "-o", tmp_path / "x.laz", "--clip-polygon", tmp_path / "areas")
    assert rc != 0 and err.strip() == f"error: convert: --clip-polygon {tmp_path / 'areas'}: is a folder, not a clip polygon file (GeoJSON or WKT)"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["areas"]  # (was "no such file (nor WKT text ...)" of a folder that is there)


def meet_reference(p, q, r, s) -> bool:
    """Whether segments p..q and r..s share a point (written out: orientations, then the collinear cases)."""

    def side(a, b, c):
        cross = float((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))
        return (cross > 0) - (cross < 0)

    def on(a, b, c):
        return min(a[0], b[0]) <= c[0] <= max(a[0], b[0]) and min(a[1], b[1]) <= c[1] <= max(a[1], b[1])

    d1, d2, d3, d4 = side(r, s, p), side(r, s, q), side(p, q, r), side(p, q, s)
    if d1 * d2 < 0 and d3 * d4 < 0:
        return True
    return (d1 == 0 and on(r, s, p)) or (d2 == 0 and on(r, s, q)) or (d3 == 0 and on(p, q, r)) or (d4 == 0 and on(p, q, s))


@pytest.mark.parametrize(
    ("ring", "edges"),
    [
        ([[0, 0], [10, 0], [0, 10], [10, 10]], (2, 4)),  # a bow tie: its two diagonals cross
        ([[0, 0], [10, 0], [10, 10], [0, 10]], None),
        (CONCAVE[0][:-1], None),
        ([[0, 0], [10, 0], [10, 0], [10, 10], [0, 10], [0, 10]], None),  # points picked twice: no edge between them
        ([[0, 0], [2, 0], [1, 1], [2, 2], [0, 2], [1, 1]], (2, 5)),  # a figure eight pinched at a vertex: it touches itself
        ([[0, 0], [4, 0], [4, 4], [2, 0.0], [0, 4]], (1, 3)),  # a vertex on another edge
        ([[637000.0, 4850000.0], [637000.5, 4850000.0], [637000.0, 4850000.5], [637000.5, 4850000.5]], (2, 4)),  # UTM-sized
    ],
)
def test_crossing_edges_names_the_first_two_edges_that_meet(ring, edges):
    from gigapoint.io.polygon import crossing_edges

    assert crossing_edges(ring) == edges


def test_a_clip_polygons_hole_outside_its_outline_is_refused_before_reading():
    """A hole half outside its outline kept, by the even-odd rule, the points in its part beyond
    the outline (as if the clip reached there); it is refused, as a volume's toe is."""
    with pytest.raises(InputError) as error:
        clip_polygon_of("POLYGON ((10 10, 30 10, 30 30, 10 30, 10 10), (25 15, 35 15, 35 20, 25 20, 25 15))", "test")
    assert str(error.value) == "WKT POLYGON ((10 10, 30 10, 30 30,...: the polygon's hole 1 is not inside its outline (its first ring): redraw it, the outline first"
    assert clip_polygon_of({"type": "Polygon", "coordinates": SQUARE_WITH_HOLE}, "test").describe() == "clip polygon the GeoJSON geometry (1 hole, 8 vertices)"


def test_the_same_hole_twice_is_refused_as_overlapping_and_named_as_the_caller_names_it(autzen_path):
    """The same ring twice (either way round, from any vertex) was accepted: each point of one
    lies on the other's edge. It overlaps wholly: refused, naming both. A GeoJSON geometry's hole
    errors start with the caller's label (gp.open's clip_polygon=...), as its other errors do."""
    ring = [[0, 0], [4, 0], [4, 4], [0, 4], [0, 0]]
    outline = [[-10, -10], [10, -10], [10, 10], [-10, 10], [-10, -10]]
    other = [[5, 5], [6, 5], [6, 6], [5, 5]]
    overlap = "the polygon's holes {} and {} overlap (by the even-odd rule their overlap is inside): make them one hole"
    for holes, pair in (([ring, ring], (1, 2)), ([ring, other, ring[::-1]], (1, 3)), ([other, ring, [[4, 4], [0, 4], [0, 0], [4, 0], [4, 4]]], (2, 3))):
        with pytest.raises(InputError) as error:
            clip_polygon_of({"type": "Polygon", "coordinates": [outline, *holes]}, "test: clip_polygon")
        assert str(error.value) == "test: clip_polygon: " + overlap.format(*pair)
    with pytest.raises(InputError) as error:
        gp.open(autzen_path, clip_polygon={"type": "Polygon", "coordinates": [outline, ring, ring]})
    assert str(error.value).startswith("open: clip_polygon={'type': 'Polygon', ") and str(error.value).endswith(": " + overlap.format(1, 2))


def test_the_same_hole_with_a_vertex_more_on_an_edge_is_refused_as_overlapping():
    """The same square twice, one with a vertex more in an edge's middle, was accepted: only rings
    of the same vertices were compared, and each vertex and edge middle of one lies on the other's
    edge. A point inside each hole (an edge's middle moved inward; for a hole too thin for its
    first edge's, another edge's) is tested too. Holes touching along an edge are still accepted."""
    outline = [[-10, -10], [10, -10], [10, 10], [-10, 10], [-10, -10]]  # (the tolerance: 2e-7)
    square, more = [[1, 1], [2, 1], [2, 2], [1, 2], [1, 1]], [[1, 1], [1.5, 1], [2, 1], [2, 2], [1, 2], [1, 1]]
    other = [[5, 5], [6, 5], [6, 6], [5, 5]]
    w = 5e-7  # (a middle moved 4e-7 in from a long edge is 1e-7 from the other: too near)
    thin, thin_more = [[0, 0], [1, 0], [1, w], [0, w], [0, 0]], [[0, w], [0, 0], [0.5, 0], [1, 0], [1, w], [0, w]]
    overlap = "test: the polygon's holes {} and {} overlap (by the even-odd rule their overlap is inside): make them one hole"
    for holes, pair in (([square, more], (1, 2)), ([more, other, square[::-1]], (1, 3)), ([other, thin, thin_more], (2, 3))):
        with pytest.raises(InputError) as error:
            clip_polygon_of({"type": "Polygon", "coordinates": [outline, *holes]}, "test")
        assert str(error.value) == overlap.format(*pair)
    above = [[0, w], [1, w], [1, 1], [0, 1], [0, w]]
    touching = clip_polygon_of({"type": "Polygon", "coordinates": [outline, thin, above, more, [[2, 1], [3, 1], [3, 2], [2, 2], [2, 1]]]}, "test")
    assert touching.describe() == "clip polygon the GeoJSON geometry (4 holes, 21 vertices)"


def test_holes_meeting_only_at_vertices_are_judged_by_points_strictly_inside_or_outside():
    """Edges meeting only at vertices are no crossing, and a point on an edge was counted inside:
    a triangle over a square (a vertex of each on the other's edge, its tip inside the square)
    and a hole in the notch of an L (every vertex on the outline) passed; two holes touching
    along edges (a triangle in an L-shaped hole's notch) were refused as nested."""
    square = "(-10 -10, 10 -10, 10 10, -10 10, -10 -10)"
    cases = [
        (f"POLYGON ({square}, (0 0, 4 0, 4 4, 0 4, 0 0), (2 2, 6 -2, -2 -2, 2 2))", "the polygon's holes 1 and 2 overlap (by the even-odd rule their overlap is inside): make them one hole"),
        ("POLYGON ((0 0, 6 0, 6 4, 4 4, 4 6, 0 6, 0 0), (6 4, 4 6, 4 4, 6 4))", "the polygon's hole 1 is not inside its outline (its first ring): redraw it, the outline first"),
    ]
    for wkt, message in cases:
        with pytest.raises(InputError) as error:
            clip_polygon_of(wkt, "test")
        assert str(error.value).endswith(f"...: {message}"), wkt
    touching = clip_polygon_of(f"POLYGON ({square}, (2 2, 6 2, 6 4, 4 4, 4 6, 2 6, 2 2), (6 4, 4 6, 4 4, 6 4))", "test")
    assert touching.describe() == "clip polygon WKT POLYGON ((-10 -10, 10 -10, 10 ... (2 holes, 13 vertices)"
    # holes sharing edges at coordinates whose middles round off the shared edge: touching, not overlapping
    x0, y0 = 637000.1, 4850000.3
    ring = [[x0 + 0.7 * x + 0.13 * y, y0 + 0.3 * y] for x, y in ((0, 0), (30, 0), (30, 30), (0, 30), (0, 0))]  # (sheared: edges aslant)
    holes = [[[x0 + 0.7 * x + 0.13 * y, y0 + 0.3 * y] for x, y in ((i, 1), (i + 1, 1), (i + 1, 2), (i, 2), (i, 1))] for i in range(1, 20)]
    assert clip_polygon_of({"type": "Polygon", "coordinates": [ring, *holes]}, "test").describe() == "clip polygon the GeoJSON geometry (19 holes, 80 vertices)"


def test_crossing_edges_match_every_pair_compared():
    from gigapoint.io.polygon import crossing_edges

    rng = np.random.default_rng(3)
    crossed = 0
    for _ in range(300):
        ring = rng.integers(0, 6, (int(rng.integers(4, 10)), 2)).astype(float)  # (a small lattice: many touching and collinear edges)
        if (ring == np.roll(ring, -1, axis=0)).all(axis=1).any():
            continue
        n = len(ring)
        pairs = [
            (i + 1, j + 1) for i in range(n) for j in range(i + 2, n)
            if not (i == 0 and j == n - 1) and meet_reference(ring[i], ring[(i + 1) % n], ring[j], ring[(j + 1) % n])
        ]  # fmt: skip
        assert crossing_edges(ring) == (min(pairs) if pairs else None), ring.tolist()
        crossed += bool(pairs)
    assert 50 < crossed < 250  # (both kinds met)
    circle = [[637000 + 50 * np.cos(t), 4850000 + 50 * np.sin(t)] for t in np.linspace(0, 2 * np.pi, 20_000, endpoint=False)]
    assert crossing_edges(circle) is None
    circle[10_000], circle[10_001] = circle[10_001], circle[10_000]  # two neighbours swapped: a tiny bow tie
    assert crossing_edges(circle) == (10_000, 10_002)


def test_a_self_crossing_polygon_still_clips_by_the_even_odd_rule():
    """Clipping (--clip-polygon on render, convert, ...) is well defined for a bow tie: both its triangles kept. Only what measures an area refuses it."""
    bow_tie = clip_polygon_of("POLYGON ((0 0, 10 0, 0 10, 10 10, 0 0))", "test")
    inside = bow_tie.inside(np.array([[5.0, 2.0, 0.0], [5.0, 8.0, 0.0], [2.0, 5.0, 0.0], [8.0, 5.0, 0.0]]))
    assert inside.tolist() == [True, True, False, False]  # the lower and upper triangles, not the sides


def test_a_long_vertex_list_is_quoted_short_in_its_error(autzen_path):
    """A clip_polygon list of 2,000 vertices (not a polygon gigapoint takes) was quoted whole:
    an error line of 85,000 characters; its label is cut, for gp.open and gp.volume alike."""
    vertices = [[float(i), float(i % 7)] for i in range(2000)]
    for where, call in (("open", lambda: gp.open(autzen_path, clip_polygon=vertices)), ("volume", lambda: gp.volume(autzen_path, vertices, 1.0))):
        with pytest.raises(InputError) as caught:
            call()
        said = str(caught.value)
        assert said.startswith(f"{where}: clip_polygon=[[0.0, 0.0], [1.0, 1.0],") and "...: a clip polygon is" in said, said
        assert len(said) < 300, len(said)


def test_long_wkt_text_is_quoted_by_its_start_and_length(cli, tmp_path):
    """WKT text of 10,000 vertices whose ring is not in parentheses (or of another geometry) was
    an OSError quoting it whole (a file's name too long: 150,000 characters); a string is quoted
    whole as a file's name, WKT text by its start and its length, in the API and the CLI alike."""
    ring = ", ".join(f"{i} {i % 7}" for i in range(10_000))
    for text, reason in ((f"POLYGON {ring}", "no such file (nor WKT text: POLYGON ((x y, ...)))"),
                         (f"LINESTRING ({ring})", "a LINESTRING, not a polygon: a clip polygon is a POLYGON or MULTIPOLYGON")):  # fmt: skip
        start = f"{text[:30]}... ({len(text):,} characters)"
        for where, call in (("open", lambda text=text: gp.open(tmp_path / "missing.laz", clip_polygon=text)), ("volume", lambda text=text: gp.volume(tmp_path / "missing.laz", text, 1.0))):
            with pytest.raises(InputError) as caught:
                call()
            assert str(caught.value) == f"{where}: clip_polygon={text[:30] + '...'!r} ({len(text):,} characters): {reason}"
            assert len(str(caught.value)) < 200
        rc, _, err = cli("render", tmp_path / "missing.laz", "-o", tmp_path / "x.png", "--clip-polygon", text)
        assert (rc, err) == (1, f"error: render: --clip-polygon {start}: {reason}\n")
    with pytest.raises(InputError) as caught:  # a hole with no area: named by the text's start too
        clip_polygon_of(f"POLYGON (({ring}, 0 0), (1 1, 2 2))", "test")
    assert str(caught.value) == "WKT POLYGON ((0 0, 1 1, 2 2, 3 3, ...: the polygon's hole 1's points lie on one line: it has no area; move a point off the line"


def test_a_grid_of_touching_holes_is_accepted_and_one_over_them_refused():
    """Holes sharing edges in a grid (every box meeting its neighbours') touch, not overlap; a
    hole laid over four of them overlaps the first it covers a point of."""
    from gigapoint.io.polygon import ClipPolygon, check_holes

    outline = np.array([[-1, -1], [31, -1], [31, 31], [-1, 31]], float)
    holes = [np.array([[i, j], [i + 1, j], [i + 1, j + 1], [i, j + 1]], float) for i in range(30) for j in range(30)]
    check_holes(ClipPolygon([[outline, *holes]], "grid"))
    over = np.array([[10.5, 10.5], [11.5, 10.5], [11.5, 11.5], [10.5, 11.5]])
    with pytest.raises(InputError, match=r"^grid: the polygon's holes \d+ and 901 overlap "):
        check_holes(ClipPolygon([[outline, *holes, over]], "grid"))


def test_overlapping_boxes_pairs_every_overlapping_pair_once():
    """The grid of cells the boxes are bucketed in finds each pair whose x and y ranges overlap
    (touching included), as comparing every pair does, of boxes of mixed sizes and points. The
    boxes with themselves: each pair once (i < j), none with itself (each pair came twice, and
    each box with itself: _meeting_pairs tested twice the segments)."""
    from gigapoint.io.polygon import _overlapping_boxes

    rng = np.random.default_rng(5)
    lo = rng.integers(0, 40, (300, 2)).astype(float)
    hi = lo + rng.choice([0, 1, 2, 30], (300, 2))
    points = rng.integers(0, 40, (200, 2)).astype(float)
    for others in (None, (points, points)):
        other_lo, other_hi = (lo, hi) if others is None else others
        pairs = [(int(i), int(j)) for i, j in zip(*(np.concatenate(p) for p in zip(*_overlapping_boxes(lo, hi, others))))]
        expected = {
            (i, j) for i in range(len(lo)) for j in range(len(other_lo))
            if np.all((other_lo[j] <= hi[i]) & (other_hi[j] >= lo[i])) and (others is not None or i < j)
        }  # fmt: skip
        assert len(pairs) == len(set(pairs)) and set(pairs) == expected
