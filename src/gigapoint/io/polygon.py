"""A clip polygon (``--clip-polygon AREA``, ``gp.open(clip_polygon=)``): a site cut out by its
boundary, as PDAL's filters.crop polygon= and LAStools' lasclip -poly do.

AREA is a GeoJSON file (a Polygon, a MultiPolygon, a Feature or FeatureCollection of them), a
WKT file or string (POLYGON, MULTIPOLYGON), or (Python) a GeoJSON geometry as a dict. Its
coordinates are taken in the cloud's own, x and y (any z), unless it names a CRS: a GeoJSON's
``crs`` member, an EWKT's ``SRID=code;`` (then filters.py moves it into the files'). A point is kept when it lies inside
one of the polygons, each by the even-odd rule over its rings: holes are left out, the polygons
joined (where two overlap, as Features of one collection may, their overlap is kept); a point
exactly on an edge (outer or a hole's) is kept, as a clip box's bounds are.

Parsed with json and a small WKT reader (no shapely or GDAL); every bad input is a one-line
InputError naming the file before anything is read (a hole outside its outline or over another hole
too: ``check_holes``). The kernels are in polygon_kernels.py. A
polygon is moved from one CRS into another by pyproj (``moved_polygon``: a GeoJSON naming a CRS
other than the files', filters.py; ``--to-crs``, reproject.py).
"""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path

import numpy as np

from ..core.coords import MAX_ABS_COORDINATE
from ..errors import REPR_MAX, InputError, value_text

#: How WKT of a polygon starts (a file named POLYGON.wkt does not)
_WKT_START = re.compile(r"\s*(?:SRID=\d+\s*;)?\s*(MULTI)?POLYGON\s*(Z|M|ZM)?\s*(\(|EMPTY)", re.IGNORECASE)

#: How WKT text of any geometry starts, well formed or not: what a message quotes by its start alone
_WKT_KEYWORD = re.compile(r"\s*(?:SRID=\d+\s*;)?\s*(?:(?:MULTI)?(?:POLYGON|POINT|LINESTRING)|GEOMETRYCOLLECTION)[\s(]", re.IGNORECASE)

#: EWKT's SRID prefix (PostGIS's ST_AsEWKT: "SRID=2994;POLYGON ((...))"): the EPSG code of its
#: coordinates, moved from as a GeoJSON's crs member (was "no such file" of such text)
_EWKT_SRID = re.compile(r"\s*SRID=(\d+)\s*;", re.IGNORECASE)

#: How WKT of another geometry starts: named in the error (was "no such file" of WKT text)
_WKT_NOT_AREA = re.compile(r"\s*(?:SRID=\d+\s*;)?\s*(POINT|MULTIPOINT|LINESTRING|MULTILINESTRING|GEOMETRYCOLLECTION)\s*(Z|M|ZM)?\s*(\(|EMPTY)", re.IGNORECASE)

#: GeoJSON geometry types that are not areas, named in the error
_NOT_AREAS = {"Point", "MultiPoint", "LineString", "MultiLineString"}

#: how far a moved clip polygon's edges may stray from the curves a projection makes of them,
#: as a share of its size, where no output grid sets the tolerance (no --to-crs, or a PLY output)
POLYGON_SHARE = 1e-8
#: pieces an edge of a clip polygon is cut into, at most, to follow its curve once moved
MAX_EDGE_PIECES = 1024
#: the source of a GeoJSON dict naming none of its own: its messages start with the caller's label
UNNAMED_GEOMETRY = "the GeoJSON geometry"


class ClipPolygon:
    """The rings of one or more polygons (``polygons``: per polygon a list of rings, each a (k, 2)
    array without the closing vertex; the first ring the outline, the rest its holes), read from
    ``source`` (the file, or the WKT text's start: what messages name). ``epsg``: the CRS a
    GeoJSON's ``crs`` member (an EWKT's SRID) names, None without one (filters.py moves it from there into the
    files' CRS). ``names``: per
    polygon the ``name`` property of the GeoJSON Feature it came from (None: none; a stockpile's
    label in ``gigapoint volume``). ``features``: per polygon the number of that Feature (0, 1, ...
    in the file's order; None outside one): a Feature's MultiPolygon is one stockpile in parts.
    ``moved_from``: the CRS it was moved from into the points' (``moved_polygon``; None: as read):
    it is in their coordinates, never moved again. ``named``: how a message starting with it names
    it, its source unless its caller labels a bare GeoJSON dict ('volume: the GeoJSON geometry';
    not in ``as_spec``: a conversion's fingerprint and a Dask task's copy keep the source). filters.py's caches: ``placed_by_file``, this
    polygon in the coordinates of each file filtered (by its path); ``moved_by_crs``, it moved
    into each CRS (by io.crs_identity: one CRS however its files write it; None: no pyproj to
    move it), once a CRS however many files are in it."""

    def __init__(
        self, polygons: list[list[np.ndarray]], source: str, epsg: int | None = None, names: list[str | None] | None = None, features: list[int | None] | None = None,
        moved_from: str | None = None, named: str | None = None,
    ):  # fmt: skip
        self.polygons = polygons
        self.source = source
        self.named = named or source
        self.epsg = epsg
        self.names = names or [None] * len(polygons)
        self.features = features or [None] * len(polygons)
        self.moved_from = moved_from
        self.placed_by_file: dict[str, ClipPolygon] = {}
        self.moved_by_crs: dict[str, ClipPolygon | None] = {}
        rings = [ring for polygon in polygons for ring in polygon]
        xy = np.concatenate(rings)
        self.edges = np.hstack([xy, xy[_following([len(ring) for ring in rings])]])  # rows x1, y1, x2, y2
        # the polygon of each edge: a point is inside by even-odd over its polygon's rings, the polygons joined
        self.owners = np.repeat(np.repeat(np.arange(len(polygons)), [len(polygon) for polygon in polygons]), [len(ring) for ring in rings])
        self.lo, self.hi = xy.min(axis=0), xy.max(axis=0)
        self.n_vertices = len(xy)
        self._buckets = None  # (starts, members) of the edges by y: made on first use

    def __eq__(self, other) -> bool:
        return (
            isinstance(other, ClipPolygon)
            and self.source == other.source
            and len(self.edges) == len(other.edges)
            and bool(np.array_equal(self.edges, other.edges))
        )

    __hash__ = None

    def describe(self) -> str:
        """'clip polygon site.geojson (2 polygons, 1 hole, 12 vertices)'."""
        holes = sum(len(p) - 1 for p in self.polygons)
        parts = [f"{len(self.polygons)} polygon{'s' * (len(self.polygons) > 1)}"] if len(self.polygons) > 1 else []
        parts += [f"{holes} hole{'s' * (holes > 1)}"] if holes else []
        parts.append(f"{self.n_vertices:,} vertices")
        return f"clip polygon {self.source} ({', '.join(parts)})"

    def as_spec(self) -> dict:
        """A GeoJSON MultiPolygon (with ``source``, ``epsg``, any ``moved_from`` and a ``named`` other
    than the source): JSON-able, read back by ``clip_polygon_of``."""
        closed = [[[*map(list, ring.tolist()), list(ring[0].tolist())] for ring in polygon] for polygon in self.polygons]
        spec = {"type": "MultiPolygon", "coordinates": closed, "source": self.source, "epsg": self.epsg}
        if self.moved_from is not None:  # (only where moved: a conversion's fingerprint without is as before)
            spec["moved_from"] = self.moved_from
        if self.named != self.source:  # (a bare dict's caller label: a Dask task's refusals start 'convert: ' too)
            spec["named"] = self.named
        return spec

    def buckets(self) -> tuple[np.ndarray, np.ndarray]:
        """(starts, members): the edges by bands of y (``polygon_kernels.edge_buckets``), made once."""
        from .polygon_kernels import edge_buckets

        if self._buckets is None:
            self._buckets = edge_buckets(self.edges, self.lo[1], self.hi[1])
        return self._buckets

    def inside(self, xyz: np.ndarray) -> np.ndarray:
        """Whether each point (x and y of ``xyz``) is in the polygon (NaN positions: not)."""
        from .polygon_kernels import points_inside

        starts, members = self.buckets()
        height = (self.hi[1] - self.lo[1]) / (len(starts) - 1) if self.hi[1] > self.lo[1] else 1.0
        inside = np.empty(len(xyz), bool)
        box = np.array([*self.lo, *self.hi])
        points_inside(np.ascontiguousarray(xyz[:, :2], np.float64), self.edges, self.owners, box, float(self.lo[1]), float(height), starts, members, inside)
        return inside

    def meets(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Which boxes ``lo``..``hi`` ((k, >=2) arrays, x and y) hold some of the area: one an
        edge passes through, or else one wholly inside (then its centre is inside)."""
        from .polygon_kernels import boxes_crossed

        near = np.all((hi[:, :2] >= self.lo) & (lo[:, :2] <= self.hi), axis=1)
        meets = np.zeros(len(lo), bool)
        if near.any():
            lo_near, hi_near = np.ascontiguousarray(lo[near, :2], np.float64), np.ascontiguousarray(hi[near, :2], np.float64)
            meets[near] = boxes_crossed(lo_near, hi_near, self.edges) | self.inside((lo_near + hi_near) / 2)
        return meets


def polygon_text(value, shown: str | None = None) -> str:
    """How a message quotes a clip polygon: as ``shown`` (the command line's text) or ``value_text``;
    WKT text of more than ``REPR_MAX`` characters by its start and its length (a WKT string of
    10,000 vertices was quoted whole, as a file's name is)."""
    if not (isinstance(value, str) and len(value) > REPR_MAX and _WKT_KEYWORD.match(value)):
        return shown or value_text(value)
    start = value.strip()[:30] + "..."
    return f"{start if shown else repr(start)} ({len(value):,} characters)"


def clip_polygon_of(value, label: str, unnamed: str = UNNAMED_GEOMETRY) -> ClipPolygon:
    """The ClipPolygon of ``value``: a path to a GeoJSON or WKT file, a WKT string, a GeoJSON
    geometry (a dict: ``as_spec``'s too; where it names no source, 'the GeoJSON geometry',
    ``named`` ``unnamed`` in the messages that start with it: 'open: the GeoJSON geometry') or a ClipPolygon; a
    one-line InputError starting with ``label`` (the option as given) for anything else."""
    if isinstance(value, ClipPolygon):
        return value
    if isinstance(value, dict):
        source = value["source"] if isinstance(value.get("source"), str) else UNNAMED_GEOMETRY
        polygon = _geojson_polygon(value, source, label)
        if isinstance(value.get("named"), str):  # (as_spec's: a Dask task's copy names it as its caller did)
            polygon.named = value["named"]
        elif source == UNNAMED_GEOMETRY:
            polygon.named = unnamed
        return polygon
    if not isinstance(value, (str, os.PathLike)):
        raise InputError(f"{label}: a clip polygon is a GeoJSON or WKT file, or WKT text (POLYGON ((x y, ...)))")
    text = str(value)
    if isinstance(value, str) and _WKT_START.match(text):
        return _wkt_polygon(text, f"WKT {text.strip()[:30]}{'...' * (len(text.strip()) > 30)}")
    path = Path(value)
    try:
        is_dir, is_file = path.is_dir(), path.is_file()
    except OSError:  # a name too long for a file: WKT text gone wrong ("POLYGON 0 0, ..." was an OSError quoting it whole)
        is_dir = is_file = False
    if is_dir:  # (was "no such file" of a folder that is there)
        raise InputError(f"{label}: is a folder, not a clip polygon file (GeoJSON or WKT)")
    if not is_file:
        if isinstance(value, str):  # (a file named "POINT (1).geojson" is read as one)
            _refuse_other_wkt(text, label)
        raise InputError(f"{label}: no such file{' (nor WKT text: POLYGON ((x y, ...)))' * isinstance(value, str)}")
    try:
        content = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:  # (a PNG given as the polygon was "cannot be read ... (UnicodeDecodeError)")
        raise InputError(f"{path}: not a text file: neither GeoJSON nor WKT (POLYGON, MULTIPOLYGON): not a clip polygon") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot be read as a clip polygon ({exc.strerror or type(exc).__name__})") from None
    if content.lstrip().startswith("{"):
        try:
            document = json.loads(content)
        except ValueError as exc:
            raise InputError(f"{path}: not valid GeoJSON ({exc})") from None
        return _geojson_polygon(document, str(path), str(path))
    if _WKT_START.match(content):
        return _wkt_polygon(content, str(path))
    _refuse_other_wkt(content, str(path))
    raise InputError(f"{path}: neither GeoJSON nor WKT (POLYGON, MULTIPOLYGON): not a clip polygon")


def _refuse_other_wkt(text: str, label: str) -> None:
    """A one-line InputError naming the geometry of WKT ``text`` that is not an area (POINT (1 2))."""
    other = _WKT_NOT_AREA.match(text)
    if other:
        raise InputError(f"{label}: a {other[1].upper()}, not a polygon: a clip polygon is a POLYGON or MULTIPOLYGON")


def _geojson_polygon(document, source: str, label: str) -> ClipPolygon:
    """The polygons of a GeoJSON Polygon, MultiPolygon, Feature or FeatureCollection."""
    if not isinstance(document, dict):
        raise InputError(f"{label}: not a GeoJSON object")
    polygons: list = []
    names: list = []
    features: list = []
    _collect(document, polygons, names, features, label)
    if not polygons:
        raise InputError(f"{label}: holds no polygon")
    moved_from = document.get("moved_from") if isinstance(document.get("moved_from"), str) else None  # (as_spec's)
    polygon = ClipPolygon(_polygon_rings(polygons, label), source, _epsg(document), names, features, moved_from)
    if moved_from is None:  # (a moved one's were checked before it was moved)
        check_holes(polygon, label)  # (a dict's: named as the caller names it, 'volume: the GeoJSON geometry')
    return polygon


def _collect(node, polygons: list, names: list, features: list, label: str, name: str | None = None, feature: int | None = None) -> None:
    """Append the coordinate lists of the polygons of GeoJSON ``node`` to ``polygons``, to
    ``names`` the ``name`` of the Feature each is in (``name``; None outside a Feature) and to
    ``features`` that Feature's number (``feature``)."""
    kind = node.get("type") if isinstance(node, dict) else None
    if kind == "FeatureCollection":
        for item in node.get("features") or []:
            _collect(item, polygons, names, features, label)
    elif kind == "Feature":
        if node.get("geometry") is None:  # (RFC 7946's unlocated Feature, QGIS's of a row without one: no area, was "GeoJSON of type None")
            return
        properties = node.get("properties")
        named = properties.get("name") if isinstance(properties, dict) else None
        number = next((f + 1 for f in reversed(features) if f is not None), 0)  # (the last one's the highest so far)
        _collect(node.get("geometry"), polygons, names, features, label, None if named is None else str(named), number)
    elif kind == "Polygon":
        polygons.append(_list(node.get("coordinates"), label))
        names.append(name)
        features.append(feature)
    elif kind == "MultiPolygon":
        parts = [_list(p, label) for p in _list(node.get("coordinates"), label)]
        polygons.extend(parts)
        names.extend([name] * len(parts))
        features.extend([feature] * len(parts))
    elif kind in _NOT_AREAS:
        raise InputError(f"{label}: a {kind}, not a polygon: a clip polygon is a Polygon or MultiPolygon")
    else:
        raise InputError(f"{label}: GeoJSON of type {kind!r}; a clip polygon is a Polygon, MultiPolygon, Feature or FeatureCollection of them")


def _list(value, label: str) -> list:
    if not isinstance(value, list) or not value:
        raise InputError(f"{label}: a polygon's coordinates are lists of rings of [x, y] positions")
    return value


def _polygon_rings(polygons: list, label: str) -> list[list[np.ndarray]]:
    """The rings of each polygon (lists of positions) read by ``_ring``, each named in its errors as ``_ring_name`` names it."""
    several = len(polygons) > 1
    return [[_ring(ring, label, _ring_name(p, r, several)) for r, ring in enumerate(rings)] for p, rings in enumerate(polygons, start=1)]


def _ring_name(p: int, r: int, several: bool) -> str:
    """How messages name ring ``r`` (0: the outline) of polygon ``p`` (from 1) of ``several`` or one:
    'the polygon', 'polygon 2', "polygon 2's hole 1"."""
    name = f"polygon {p}" if several else "the polygon"
    return f"{name}'s hole {r}" if r else name


def _ring(positions, label: str, name: str) -> np.ndarray:
    """One ring (called ``name`` in messages) as a (k, 2) array, without a closing vertex; a
    one-line error for positions that are not numbers, NaN or infinite, or that enclose no area
    (``no_area_problem``: every clip, section, orthophoto and volume refuses it here, before
    anything is read; it kept nothing, or only the points on its line)."""
    try:
        xy = np.array([p[:2] for p in _list(positions, label)], np.float64)
    except (TypeError, ValueError, IndexError):
        raise InputError(f"{label}: a polygon's positions are [x, y] numbers") from None
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise InputError(f"{label}: a polygon's positions are [x, y] numbers")
    if not np.isfinite(xy).all():
        raise InputError(f"{label}: a polygon vertex is NaN or infinite ({xy[~np.isfinite(xy).all(axis=1)][0].tolist()})")
    if np.abs(xy).max() > MAX_ABS_COORDINATE:  # (as points beyond it are: a volume's grid over it was a 300-digit size)
        raise InputError(f"{label}: a polygon vertex lies beyond ±{MAX_ABS_COORDINATE:g} ({xy[(np.abs(xy) > MAX_ABS_COORDINATE).any(axis=1)][0].tolist()}): no point can be there")
    if len(xy) > 1 and np.array_equal(xy[0], xy[-1]):
        xy = xy[:-1]
    problem = no_area_problem(xy, name)
    if problem:
        raise InputError(f"{label}: {problem}")
    return xy


def no_area_problem(ring, name: str = "the polygon") -> str | None:
    """"the polygon's points lie on one line: ..." where the vertices of ring ``ring`` ((k, 2+))
    do, within a billionth of its size (not its shoelace area: a bow tie's halves cancel, and
    clip by the even-odd rule), or "... are at one x, y" (a point repeated); None for a ring with an area."""
    xy = np.asarray(ring, np.float64)[:, :2]
    size = float(np.ptp(xy, axis=0).max())
    if size == 0:
        return f"{name}'s points are at one x, y: it has no area"
    centred = xy - xy.mean(axis=0)
    across = np.linalg.svd(centred, full_matrices=False)[2][-1]  # the direction square to the line that fits best
    if np.abs(centred @ across).max() <= 1e-9 * size:
        return f"{name}'s points lie on one line: it has no area; move a point off the line"
    return None


def _epsg(document: dict) -> int | None:
    """The EPSG code of a GeoJSON's (2008 draft) ``crs`` member ('EPSG:2992',
    'urn:ogc:def:crs:EPSG::2992'), or an ``epsg`` (``as_spec``'s); None without one."""
    if isinstance(document.get("epsg"), int):
        return document["epsg"]
    name = ((document.get("crs") or {}).get("properties") or {}).get("name") if isinstance(document.get("crs"), dict) else None
    found = re.search(r"EPSG:+(\d+)", name or "", re.IGNORECASE)
    if found:
        return int(found.group(1))
    return 4326 if re.search(r"CRS84$", name or "") else None


def _wkt_polygon(text: str, source: str) -> ClipPolygon:
    """The polygons of WKT ``POLYGON ((x y, ...), (...))`` or ``MULTIPOLYGON (((...)), ((...)))``
    (a Z, M or ZM tag allowed; only x and y are read; an EWKT ``SRID=code;`` before it names its CRS)."""
    srid = _EWKT_SRID.match(text)
    text = text[srid.end():] if srid else text
    tokens = re.findall(r"[()]|,|[^\s(),]+", text)
    kind = tokens[0].upper() if tokens else ""
    at = 1
    if at < len(tokens) and tokens[at].upper() in ("Z", "M", "ZM"):
        at += 1

    def problem(what: str) -> InputError:
        return InputError(f"{source}: not WKT POLYGON or MULTIPOLYGON ({what})")

    def nested(at: int) -> tuple[list, int]:
        """The parenthesised list at ``tokens[at]``: its items, each a nested list or a vertex."""
        if at >= len(tokens) or tokens[at] != "(":
            raise problem("a '(' was expected")
        items, at = [], at + 1
        while True:
            if at < len(tokens) and tokens[at] == "(":
                item, at = nested(at)
            else:
                item = []
                while at < len(tokens) and tokens[at] not in "(),":
                    item.append(tokens[at])
                    at += 1
                try:
                    item = [float(v) for v in item]
                except ValueError:
                    raise problem(f"{' '.join(item)!r} is not a vertex") from None
            items.append(item)
            if at >= len(tokens):
                raise problem("a ')' is missing")
            if tokens[at] == ")":
                return items, at + 1
            if tokens[at] != ",":
                raise problem(f"{tokens[at]!r} where ',' or ')' was expected")
            at += 1

    if kind not in ("POLYGON", "MULTIPOLYGON"):
        raise problem(f"it starts {kind or 'empty'}")
    if at < len(tokens) and tokens[at].upper() == "EMPTY":
        raise InputError(f"{source}: an empty polygon; it encloses no area")
    body, end = nested(at)
    if end != len(tokens):
        raise problem(f"{' '.join(tokens[end:end + 3])!r} after its end")
    polygons = [body] if kind == "POLYGON" else body
    if not all(isinstance(rings, list) and rings and all(isinstance(r, list) and r and isinstance(r[0], list) for r in rings) for rings in polygons):
        raise problem("its rings are lists of 'x y' vertices in parentheses")
    if any(len(v) < 2 for rings in polygons for r in rings for v in r):
        raise problem("a vertex has fewer than 2 numbers")
    polygon = ClipPolygon(_polygon_rings(polygons, source), source, int(srid[1]) if srid else None)
    check_holes(polygon)
    return polygon


def far_apart(polygon: ClipPolygon, lo, hi) -> bool:
    """Whether the polygon's box and the points' x and y box ``lo``..``hi`` are apart by more than
    both their sizes: a polygon in another CRS (degrees against metres or feet)."""
    size = max(float(np.max(polygon.hi - polygon.lo)), float(np.max(np.asarray(hi[:2]) - np.asarray(lo[:2]))), 1.0)
    gap = np.maximum(np.asarray(lo[:2]) - polygon.hi, polygon.lo - np.asarray(hi[:2]))
    return bool(np.max(gap) > size) and math.isfinite(float(np.max(gap)))


def looks_like_lon_lat(polygon: ClipPolygon) -> bool:
    """Whether every vertex is within longitude/latitude's range (|x| <= 180, |y| <= 90)."""
    return bool(np.all(np.abs(polygon.lo) <= (180, 90)) and np.all(np.abs(polygon.hi) <= (180, 90)))


def moved_polygon(polygon: ClipPolygon, source, target, tolerance: float | None = None) -> ClipPolygon:
    """``polygon`` moved from pyproj CRS ``source`` into ``target`` (their horizontal parts), its
    edges cut into pieces whose moved ends follow the curves a projection makes of straight edges
    (``_moved_ring``: within ``tolerance``, in target units, else a share ``POLYGON_SHARE`` of its
    size); as it is where the two are one CRS. It names no CRS then (``moved_from`` says which it
    came from): it is in the target's coordinates."""
    import pyproj

    from .crs import pyproj_horizontal, same_horizontal

    same = same_horizontal(source, target)  # (named the target: already in the points' coordinates)
    # (bound kept: a WKT1's TOWGS84 is how its datum is moved; unbound, PROJ's own shift, metres off)
    source, target = pyproj_horizontal(source, bound=True), pyproj_horizontal(target, bound=True)
    came_from = f"EPSG:{polygon.epsg}" if polygon.epsg is not None else source.name
    if same:
        return ClipPolygon(polygon.polygons, polygon.source, None, polygon.names, polygon.features, came_from, polygon.named)
    move = pyproj.Transformer.from_crs(source, target, always_xy=True)
    moved = [[_moved_ring(ring, move, tolerance, polygon.named, target.name) for ring in rings] for rings in polygon.polygons]
    return ClipPolygon(moved, polygon.source, None, polygon.names, polygon.features, came_from, polygon.named)


def _moved_ring(ring: np.ndarray, move, tolerance: float | None, source: str, target_name: str) -> np.ndarray:
    """``ring`` moved by ``move``, each edge cut into as many equal pieces (a power of two, at
    most ``MAX_EDGE_PIECES``) as keep the moved pieces' middles within ``tolerance`` (a share
    ``POLYGON_SHARE`` of the ring's size where None) of their moved chords: the curve a
    projection makes of a straight edge, followed. Vertices outside the transform's domain:
    a one-line InputError naming ``source``."""
    step = np.roll(ring, -1, axis=0) - ring
    pieces = 1
    while True:
        at = np.arange(2 * pieces + 1) / (2 * pieces)  # each piece's start, middle (odd) and the edge's end
        points = ring[:, None, :] + at[None, :, None] * step[:, None, :]
        x, y = move.transform(points[..., 0].ravel(), points[..., 1].ravel())
        moved = np.stack([x, y], axis=-1).reshape(points.shape)
        if not np.isfinite(moved).all():
            raise InputError(f"{source}: the clip polygon lies outside the domain of the transform to {target_name}: is it in the CRS it is read in?")
        starts, middles, ends = moved[:, 0:-1:2], moved[:, 1::2], moved[:, 2::2]
        size = float(np.max(moved.max(axis=(0, 1)) - moved.min(axis=(0, 1))))
        off = float(np.max(np.hypot(*np.moveaxis(middles - (starts + ends) / 2, -1, 0))))
        if off <= (size * POLYGON_SHARE if tolerance is None else tolerance) or pieces >= MAX_EDGE_PIECES:
            return starts.reshape(-1, 2)
        pieces *= 2


def crossing_edges(ring) -> tuple[int, int] | None:
    """The first two edges of the ring of (k, 2) vertices ``ring`` (without its closing vertex;
    edges numbered from 1: edge 1 from the first vertex to the second, the last back to the
    first) that cross or touch, other than neighbours at the vertex they share; None for a simple
    ring. A vertex repeated in a row (a point picked twice) is no edge. Edges are compared only
    with those whose x and y ranges overlap theirs: a 20,000-vertex ring in a few hundredths of a second."""
    xy = np.asarray(ring, np.float64)[:, :2]
    numbers = np.flatnonzero(np.any(xy != np.roll(xy, -1, axis=0), axis=1))  # the edges of some length, by their start
    n = len(numbers)
    if n < 4:  # a triangle's edges all meet their neighbours only
        return None
    a = xy[numbers] - xy[0]  # (from a vertex: no cancellation at UTM sizes)

    def apart(i, j):  # not i nor its neighbours
        return ((j - i) % n > 1) & ((j - i) % n < n - 1)

    found = _meeting_pairs(a, np.roll(a, -1, axis=0), apart, touching=True)
    if found is None:
        return None
    return int(numbers[found[0]]) + 1, int(numbers[found[1]]) + 1


def _meeting_pairs(a: np.ndarray, b: np.ndarray, compared, touching: bool) -> tuple[int, int] | None:
    """The first pair (i < j) of the segments ``a[i]``..``b[i]`` that meet (cross, or touch too
    where ``touching``) among those ``compared(i, j)`` (index arrays) allows; None where none do.
    Only segments whose x and y ranges overlap are compared."""
    found = []
    for i, j in _overlapping_boxes(np.minimum(a, b), np.maximum(a, b), compared=compared):  # (i < j: no others)
        meet = _segments_meet(a[i], b[i], a[j], b[j], touching)
        found += list(zip(i[meet].tolist(), j[meet].tolist()))
    return min(found) if found else None


def _overlapping_boxes(lo: np.ndarray, hi: np.ndarray, others: tuple[np.ndarray, np.ndarray] | None = None, compared=None):
    """The pairs (i, j) of the boxes ``lo[i]``..``hi[i]`` and the ``others`` (their (lo, hi);
    None: the same boxes) whose x and y ranges overlap, among those ``compared(i, j)`` allows
    (None: all): index arrays, about a million pairs at a time, each pair once (i < j where
    ``others`` is None: no box with itself). The boxes are
    bucketed in a grid of cells about as wide as they are, and paired in the cell holding the
    corner where they start to overlap (in both boxes' cells). (A sweep along x alone paired each
    hole of a grid of touching ones with its whole column: seconds for 8,000 holes.)"""
    other_lo, other_hi = (lo, hi) if others is None else others
    if not (len(lo) and len(other_lo)):
        return
    origin = np.minimum(lo.min(axis=0), other_lo.min(axis=0))
    cell, rows = _grid_cell(origin, (lo, hi), (other_lo, other_hi))

    def cell_of(at: np.ndarray) -> np.ndarray:
        return ((at - origin) // cell).astype(np.int64)

    def covered(box_lo: np.ndarray, box_hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # (box, cell key) of each cell a box covers
        first, span = cell_of(box_lo), cell_of(box_hi) - cell_of(box_lo) + 1
        box = np.repeat(np.arange(len(box_lo)), span[:, 0] * span[:, 1])
        k = _counting_runs(span[:, 0] * span[:, 1])
        return box, (first[box, 0] + k // span[box, 1]) * rows + first[box, 1] + k % span[box, 1]

    (box, key), (other, other_key) = (_by_key(*covered(*boxes)) for boxes in ((lo, hi), (other_lo, other_hi)))  # (sorted: searched in order)
    first = np.searchsorted(other_key, key, side="left")
    counts = np.searchsorted(other_key, key, side="right") - first
    for block in np.array_split(np.arange(len(key)), max(1, int(counts.sum()) // 1_000_000)):
        entry = np.repeat(block, counts[block])
        i, j = box[entry], other[first[entry] + _counting_runs(counts[block])]
        corner = cell_of(np.maximum(lo[i], other_lo[j]))
        tested = np.all((other_lo[j] <= hi[i]) & (other_hi[j] >= lo[i]), axis=1) & (corner[:, 0] * rows + corner[:, 1] == key[entry])
        if others is None:
            tested &= i < j
        if compared is not None:
            tested &= compared(i, j)
        yield i[tested], j[tested]


def _by_key(box: np.ndarray, key: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    order = np.argsort(key, kind="stable")
    return box[order], key[order]


def _grid_cell(origin: np.ndarray, *boxes: tuple[np.ndarray, np.ndarray]) -> tuple[float, int]:
    """(the width of ``_overlapping_boxes``' cells, the rows of its grid): the boxes' median
    size, doubled until they cover at most a few cells each on the whole (a long edge over
    many small holes), and at least a millionth of their extent (the keys in range)."""
    sides = np.concatenate([np.max(h - lo, axis=1) for lo, h in boxes])
    top = np.max([h.max(axis=0) for _, h in boxes], axis=0)
    extent = float(np.max(top - origin))
    positive = sides[sides > 0]
    cell = max(float(np.median(positive)) if len(positive) else extent, extent / 2**20, np.finfo(np.float64).tiny)
    while sum(int(np.prod((lo_h[1] - origin) // cell - (lo_h[0] - origin) // cell + 1, axis=1).sum()) for lo_h in boxes) > 8 * len(sides) + 64:
        cell *= 2
    return cell, int((top[1] - origin[1]) // cell) + 1


def _counting_runs(lengths: np.ndarray) -> np.ndarray:
    """0, 1, .. counted along each of the runs ``lengths`` long, one after another."""
    return np.arange(int(lengths.sum())) - np.repeat(np.cumsum(lengths) - lengths, lengths)


def _segments_meet(p: np.ndarray, q: np.ndarray, r: np.ndarray, s: np.ndarray, touching: bool = True) -> np.ndarray:
    """Whether segment p..q meets each of the segments r..s ((k, 2) arrays): crosses, or touches
    too where ``touching``."""

    def orientation(a, b, c):
        return np.sign((b[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1]) - (b[..., 1] - a[..., 1]) * (c[..., 0] - a[..., 0]))

    def within(a, b, c):  # c in the box of a..b (on the segment, where the three are on one line)
        return np.all((np.minimum(a, b) <= c) & (c <= np.maximum(a, b)), axis=-1)

    d1, d2, d3, d4 = orientation(r, s, p), orientation(r, s, q), orientation(p, q, r), orientation(p, q, s)
    crossing = (d1 * d2 < 0) & (d3 * d4 < 0)
    if not touching:
        return crossing
    touches = ((d1 == 0) & within(r, s, p)) | ((d2 == 0) & within(r, s, q)) | ((d3 == 0) & within(p, q, r)) | ((d4 == 0) & within(p, q, s))
    return crossing | touches


def crossing_problem(ring, name: str = "the polygon") -> str | None:
    """'the polygon crosses itself (edges 2 and 4)' where ``ring`` does (``crossing_edges``); None for a simple one."""
    edges = crossing_edges(ring)
    return None if edges is None else f"{name} crosses itself (edges {edges[0]} and {edges[1]})"


def check_simple(polygon: ClipPolygon, why: str) -> None:
    """A one-line InputError naming ``polygon`` (``named``), the ring and its edges where a ring crosses
    itself, ending with ``why`` it matters. What measures an area calls it (a volume's toe): the
    shoelace's area and the even-odd rule's inside differ there. A clip is well defined by the
    even-odd rule, a self-crossing polygon's included: clipping does not call it."""
    several = len(polygon.polygons) > 1
    for p, rings in enumerate(polygon.polygons, start=1):
        for r, ring in enumerate(rings):
            problem = crossing_problem(ring, _ring_name(p, r, several))
            if problem:
                raise InputError(f"{polygon.named}: {problem}: {why}")


def check_holes(polygon: ClipPolygon, label: str | None = None) -> None:
    """A one-line InputError naming ``polygon``'s file (``label``: how else to name it) where a hole is not inside its outline (an
    edge crossing one of its edges, or a vertex or an edge's middle outside it) or two holes
    overlap (their edges cross, or a vertex, an edge's middle or a point inside one lies inside the other):
    by the even-odd rule the area between them was inside, not left out (a clip kept points
    beyond the outline; a volume's pixels and its polygon_area, the outline's less its holes',
    disagreed). A hole may touch its outline or another hole, at a vertex or along an edge."""
    label = label or polygon.source
    several = len(polygon.polygons) > 1
    for p, (outline, *holes) in enumerate(polygon.polygons, start=1):
        if not holes:
            continue
        name = _ring_name(p, 0, several)
        rings = [outline, *holes]
        ring_of = np.repeat(np.arange(len(rings)), [len(r) for r in rings])  # of each edge (by its start): 0 the outline, h hole h
        a = np.concatenate(rings) - outline[0]  # (from a vertex: no cancellation at UTM sizes)
        b = a[_following([len(r) for r in rings])]
        crossing = _meeting_pairs(a, b, lambda i, j, ring_of=ring_of: ring_of[i] != ring_of[j], touching=False)
        crossed = None if crossing is None else sorted(int(ring_of[e]) for e in crossing)
        # edges that only touch: each hole judged by its vertices, its edges' middles and a point inside it, those
        # on the edge of the ring they are tested in (inside it, by points_inside) left out
        n = len(outline)
        tolerance = POLYGON_SHARE * float(np.max(a[:n].max(axis=0) - a[:n].min(axis=0)))
        inner, inner_hole = _inner_points(a[n:], b[n:], ring_of[n:], tolerance)  # (two holes the same: one inside the other by it)
        points = np.concatenate([a[n:], (a[n:] + b[n:]) / 2, inner])
        hole_of = np.concatenate([np.tile(ring_of[n:], 2), inner_hole])
        outside = np.flatnonzero(~ClipPolygon([[a[:n]]], polygon.source).inside(points))
        outside = np.setdiff1d(outside, outside[_on_edges(points[outside], a[:n], b[:n], tolerance)[0]])
        strays = hole_of[outside].tolist() + ([crossed[1]] if crossed and crossed[0] == 0 else [])
        if strays:
            raise InputError(f"{label}: {name}'s hole {min(strays)} is not inside its outline (its first ring): redraw it, the outline first")
        overlap = crossed or _hole_in_hole(points, hole_of, a[n:], b[n:], ring_of[n:], tolerance)
        if overlap:
            raise InputError(f"{label}: {name}'s holes {overlap[0]} and {overlap[1]} overlap (by the even-odd rule their overlap is inside): make them one hole")


def _following(sizes: list[int]) -> np.ndarray:
    """The index of each vertex's next in its ring (the first after the last), the rings (of
    ``sizes`` vertices) one after another: the ends of their edges."""
    ends = np.cumsum(sizes)
    following = np.arange(1, int(ends[-1]) + 1)
    following[ends - 1] = ends - sizes
    return following


def _on_edges(points: np.ndarray, a: np.ndarray, b: np.ndarray, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """(point, edge) index arrays: the points within ``tolerance`` of the edges ``a[e]``..``b[e]``
    (an edge's middle computed misses an edge it shares by a rounding)."""
    on = [(np.zeros(0, np.int64), np.zeros(0, np.int64))]
    for edge, point in _overlapping_boxes(np.minimum(a, b) - tolerance, np.maximum(a, b) + tolerance, (points, points)):
        step = b[edge] - a[edge]
        along = np.clip(np.sum((points[point] - a[edge]) * step, axis=1) / np.maximum(np.sum(step * step, axis=1), np.finfo(np.float64).tiny), 0, 1)
        near = np.hypot(*(a[edge] + along[:, None] * step - points[point]).T) <= tolerance
        on.append((point[near], edge[near]))
    return np.concatenate([point for point, _ in on]), np.concatenate([edge for _, edge in on])


def _hole_in_hole(points: np.ndarray, hole_of: np.ndarray, a: np.ndarray, b: np.ndarray, ring_of: np.ndarray, tolerance: float) -> list[int] | None:
    """The numbers (from 1, the lower first) of two holes, a point of one (``hole_of``: each of
    ``points``' hole) inside the other, not on its edge (within ``tolerance``), or None. The
    holes' edges: ``a[e]``..``b[e]``, of hole ``ring_of[e]``. Only a point in another hole's box
    is tested in it (``_inside_holes``)."""
    starts = np.flatnonzero(np.diff(ring_of, prepend=0))
    lo, hi = np.minimum.reduceat(a, starts), np.maximum.reduceat(a, starts)  # each hole's box (hole h at h - 1)
    tested = [np.concatenate(pair) for pair in zip(*_overlapping_boxes(points, points, (lo, hi), compared=lambda p, h: hole_of[p] != h + 1))]
    if not tested:
        return None
    point, hole = tested[0], tested[1] + 1
    on_point, on_edge = _on_edges(points, a, b, tolerance)
    keep = ~np.isin(point * (len(lo) + 1) + hole, on_point * (len(lo) + 1) + ring_of[on_edge], kind="sort")  # (on its edge: touching)
    point, hole = point[keep], hole[keep]
    inside = _inside_holes(points[point], hole, a, b, ring_of)
    if not inside.any():
        return None
    return min(sorted((int(hole_of[p]), int(h))) for p, h in zip(point[inside], hole[inside]))


def _inside_holes(points: np.ndarray, hole: np.ndarray, a: np.ndarray, b: np.ndarray, ring_of: np.ndarray) -> np.ndarray:
    """Whether each of ``points`` is inside hole ``hole[k]`` (numbered as ``ring_of``, from 1), by
    the even-odd rule: the edges of that hole its ray to the right crosses."""
    starts = np.flatnonzero(np.diff(ring_of, prepend=0))
    right = np.maximum.reduceat(a[:, 0], starts)  # each hole's right end (hole h at h - 1)
    rays_hi = np.column_stack([np.maximum(right[hole - 1], points[:, 0]), points[:, 1]])
    crossings = np.zeros(len(points), np.int64)
    for ray, e in _overlapping_boxes(points, rays_hi, (np.minimum(a, b), np.maximum(a, b)), compared=lambda r, e: ring_of[e] == hole[r]):
        (px, py), (ax, ay), (bx, by) = points[ray].T, a[e].T, b[e].T
        rise = np.where(by != ay, by - ay, 1.0)  # (a level edge crosses no ray: the first test)
        crossed = ((ay > py) != (by > py)) & (px < ax + (py - ay) * (bx - ax) / rise)
        crossings += np.bincount(ray[crossed], minlength=len(points))
    return crossings % 2 == 1


def _inner_points(a: np.ndarray, b: np.ndarray, ring_of: np.ndarray, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """(points, their holes): a point of each hole inside it farther than ``tolerance`` from its
    edges ``a[e]``..``b[e]`` (of hole ``ring_of[e]``, from 1), an edge's middle moved twice
    ``tolerance`` to the edge's inner side (the left where the hole turns anticlockwise): its
    first edge's, else (a thin hole) the first that is; none for a hole thinner than that. Two
    holes the same (with a vertex more on an edge, or from another vertex) have all their vertices
    and edge middles on each other's edges: this one is inside the other."""
    step = b - a
    length = np.hypot(*step.T)
    turn = np.sign(np.bincount(ring_of, weights=a[:, 0] * b[:, 1] - b[:, 0] * a[:, 1]))  # each hole's sign of its area
    edges = np.flatnonzero(length > 0)

    def inside_of(edge: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # (points, holes): of each hole the first of edge's that is
        inward = np.column_stack([-step[edge, 1], step[edge, 0]]) * (2 * tolerance * turn[ring_of[edge]] / length[edge])[:, None]
        points, hole = (a[edge] + b[edge]) / 2 + inward, ring_of[edge]
        good = _inside_holes(points, hole, a, b, ring_of)
        on_point, on_edge = _on_edges(points, a, b, tolerance)
        good[on_point[ring_of[on_edge] == hole[on_point]]] = False
        first = np.unique(hole[good], return_index=True)[1]
        return points[good][first], hole[good][first]

    points, hole = inside_of(edges[np.unique(ring_of[edges], return_index=True)[1]])
    thin_points, thin_hole = inside_of(edges[~np.isin(ring_of[edges], hole)])
    return np.concatenate([points, thin_points]), np.concatenate([hole, thin_hole])


__all__ = [
    "UNNAMED_GEOMETRY", "ClipPolygon", "check_holes", "check_simple", "clip_polygon_of", "crossing_edges", "crossing_problem", "far_apart", "looks_like_lon_lat", "moved_polygon", "no_area_problem", "polygon_text",
]  # fmt: skip
