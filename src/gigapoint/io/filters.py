"""Read-time point filters: keep or drop LAS classes, keep a clip box, a clip polygon or a corridor
along a line (PDAL's filters.range and filters.crop, LAStools' -keep_class, -drop_class, -keep_xy,
lasclip -poly; the corridor is what a cross-section draws, ``gigapoint section``; the polygon's
parsing and kernels are polygon.py's).

One ``PointFilter`` is made from the options (``point_filter``: every bad value a one-line
error before anything is read) and applied to each chunk right after its reader gives it, by
every read path: ``gp.open`` (in memory, chunked and progressive), ``gp.convert`` (one process
and its Dask tasks, which get it as ``as_spec``). A filter counts the points it saw and let
pass, so that a filter that lets nothing pass says so (``check_passed``) rather than the
generic "no valid points". Header point counts are then upper bounds: progress bars and
presizing may use them, nothing may expect that many points.

A clip polygon whose GeoJSON names a CRS (a ``crs`` member; an EWKT's SRID) other than a LAS/LAZ file's is moved
into the file's CRS before its points are tested (``placed_polygon``: pyproj, the ``gis`` extra);
without pyproj, or over a file naming no CRS, it is taken in the files' coordinates (warned of
where both name EPSG codes that differ). One in longitude/latitude's range over a file in a
projected CRS far from it (a GeoJSON without a ``crs`` member is lon/lat by RFC 7946, or one
naming lon/lat without pyproj to move it) is refused in one line: it would clip nothing.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, replace

import numpy as np

from ..core.chunk import PointChunk
from ..core.coords import MAX_ABS_COORDINATE, MAX_SPAN
from ..errors import (
    EmptyCloudError,
    GigapointWarning,
    InputError,
    counted,
    is_real,
    is_whole_number,
    number_text,
    numbers_text,
    value_text,
    warn,
)
from ._base import read_once
from .polygon import UNNAMED_GEOMETRY, ClipPolygon, clip_polygon_of, far_apart, looks_like_lon_lat, moved_polygon, polygon_text

#: The option names as Python's keywords and the CLI's options say them
PYTHON_NAMES = {"classes": "classes=", "drop_classes": "drop_classes=", "clip": "clip=", "corridor": "corridor=", "clip_polygon": "clip_polygon="}
CLI_NAMES = {"classes": "--classes ", "drop_classes": "--drop-classes ", "clip": "--clip ", "clip_polygon": "--clip-polygon "}


@dataclass
class PointFilter:
    """Which points of a chunk are kept: those of ``classes`` (empty: any), not of
    ``drop_classes``, inside ``clip`` ((xmin, ymin, xmax, ymax): any z, or (xmin, ymin, zmin,
    xmax, ymax, zmax); bounds included; empty: anywhere), inside ``corridor`` ((x1, y1, x2, y2,
    width): at most width / 2 from the segment (x1, y1)-(x2, y2), measured square to it in x and
    y, and between its ends; any z; empty: anywhere), inside ``polygon`` (polygon.py: in one of
    its polygons, even-odd over that one's rings, edges included, any z; None: anywhere). ``read``/``passed``: points seen and
    kept so far (one operation's: ``fresh`` gives a copy at zero); ``seen``: the x and y box
    of the points read where a polygon is given (a hint when none of them passes)."""

    classes: tuple[int, ...] = ()
    drop_classes: tuple[int, ...] = ()
    clip: tuple[float, ...] = ()
    corridor: tuple[float, ...] = ()
    polygon: ClipPolygon | None = None
    read: int = field(default=0, compare=False)
    passed: int = field(default=0, compare=False)
    seen: tuple[np.ndarray, np.ndarray] | None = field(default=None, compare=False)

    def fresh(self) -> PointFilter:
        """This filter with its counts at zero (a pass of a read that reads the files again)."""
        return replace(self, read=0, passed=0, seen=None)

    def dropping(self, classes: tuple[int, ...]) -> PointFilter:
        """This filter (fresh) also leaving out LAS ``classes``: an LOD octree's hidden classes
        join its read filter as its nodes load (lod/store.py)."""
        return replace(self.fresh(), drop_classes=tuple(sorted({*self.drop_classes, *classes})))

    def keeps_class(self, code: int) -> bool:
        """Whether points of LAS class ``code`` may pass: one of its ``classes`` (or any), none of
        its ``drop_classes`` (their positions aside)."""
        return (not self.classes or code in self.classes) and code not in self.drop_classes

    def describe(self) -> str:
        """'classes 2, 6; clip 1, 2, 3, 4; corridor 0, 0 to 10, 0, width 2': what the messages say of it."""
        parts = [
            f"{label} {', '.join(f'{v:.15g}' for v in values)}"
            for label, values in (("classes", self.classes), ("drop classes", self.drop_classes), ("clip", self.clip))
            if values
        ]
        if self.corridor:
            x1, y1, x2, y2, width = self.corridor
            parts.append(f"corridor {x1:.15g}, {y1:.15g} to {x2:.15g}, {y2:.15g}, width {width:.15g}")
        if self.polygon is not None:
            parts.append(self.polygon.describe())
        return "; ".join(parts)

    def as_spec(self) -> dict:
        """JSON-able, as the keywords of ``point_filter`` (and gp.open's, gp.convert's; None: not
        given): for a conversion's fingerprint, its Dask tasks (``from_spec``), the CLI's calls. A
        corridor and a polygon (its vertices: ``ClipPolygon.as_spec``) are there only where given
        (a conversion's fingerprint without one is as before)."""
        spec = {name: list(values) or None for name, values in (("classes", self.classes), ("drop_classes", self.drop_classes), ("clip", self.clip))}
        if self.corridor:
            spec["corridor"] = list(self.corridor)
        if self.polygon is not None:
            spec["clip_polygon"] = self.polygon.as_spec()
        return spec

    @classmethod
    def from_spec(cls, spec: dict | None) -> PointFilter | None:
        if spec is None:
            return None
        polygon = None if spec.get("clip_polygon") is None else clip_polygon_of(spec["clip_polygon"], "clip_polygon=")
        return cls(*(tuple(spec.get(name) or ()) for name in ("classes", "drop_classes", "clip", "corridor")), polygon)

    @property
    def needs_positions(self) -> bool:
        """Whether it tests positions (a clip box, corridor or polygon), not classes alone."""
        return bool(self.clip or self.corridor or self.polygon is not None)

    def kept(self, chunk: PointChunk, path) -> PointChunk:
        """The points of ``chunk`` (read from ``path``) the filter keeps, counted."""
        keep = self.keeps(chunk.xyz, chunk.attributes.get("classification"), path)
        if self.polygon is not None:
            self._see(chunk.xyz)
        n = int(np.count_nonzero(keep))
        self.read += len(chunk)
        self.passed += n
        if n == len(chunk):
            return chunk
        return chunk.subset(keep)  # (its colour bits: a save writes the colours back so)

    def keeps(self, xyz: np.ndarray | None, classification: np.ndarray | None, path) -> np.ndarray:
        """Which points (positions ``xyz``, None where it ``needs_positions`` not; their
        ``classification``, None where they hold none) of ``path`` the filter keeps, not counted:
        what ``kept`` keeps, and an LOD octree's arena as it loads a node (lod/store.py)."""
        n = len(xyz) if xyz is not None else len(classification)
        keep = np.ones(n, bool)
        if self.classes or self.drop_classes:
            if classification is None:
                raise InputError(f"{path}: holds no classification, which the filter ({self.describe()}) needs")
            if self.classes:
                keep &= np.isin(classification, self.classes)
            if self.drop_classes:
                keep &= ~np.isin(classification, self.drop_classes)
        if self.clip:
            axes = len(self.clip) // 2  # 2: x and y (any z), 3: x, y and z
            lo, hi = np.array(self.clip[:axes]), np.array(self.clip[axes:])
            keep &= np.all((xyz[:, :axes] >= lo) & (xyz[:, :axes] <= hi), axis=1)  # (NaN positions fail both: left out)
        if self.corridor:
            distance, offset = along_and_across(xyz, self.corridor[:4])
            length, half = math.dist(self.corridor[:2], self.corridor[2:4]), self.corridor[4] / 2
            keep &= (distance >= 0) & (distance <= length) & (np.abs(offset) <= half)  # (NaN: left out)
        if self.polygon is not None:
            keep &= self.placed_polygon(path).inside(xyz)
        return keep

    def apply(self, chunks: Iterable[PointChunk], path) -> Iterator[PointChunk]:
        """``chunks`` of ``path`` with only the points kept; a chunk left without any is not given."""
        if self.polygon is not None:
            self.placed_polygon(path)  # (moved, warned of or refused before a chunk is read)
        for chunk in chunks:
            chunk = self.kept(chunk, path)
            if len(chunk):
                yield chunk

    def placed_polygon(self, path) -> ClipPolygon:
        """The polygon in the coordinates of ``path``'s points (module notes; ``_placed``), placed
        once a file: kept with the polygon, which a filter's fresh copies share."""
        placed = self.polygon.placed_by_file
        if str(path) not in placed:
            placed[str(path)] = _placed(self.polygon, path)
        return placed[str(path)]

    def _box_polygon(self) -> ClipPolygon | None:
        """The polygon boxes are tested against (no file named): as it is where it names no CRS;
        else as placed over the files filtered so far where that is one polygon; None before
        (where it may yet move: no test)."""
        if self.polygon.epsg is None:
            return self.polygon
        placed = {id(p): p for p in self.polygon.placed_by_file.values()}
        return next(iter(placed.values())) if len(placed) == 1 else None

    def check_passed(self, label: str) -> None:
        """An EmptyCloudError naming ``label`` (the files) where points were read and none passed."""
        if self.passed == 0 and self.read:  # (no point read at all: the readers' own errors say so)
            raise EmptyCloudError(f"{label}: no point passes the filter ({self.describe()}): {counted(self.read, 'point')} read{self.polygon_hint()}")

    def _see(self, xyz: np.ndarray) -> None:
        """Widen ``seen`` by the x and y of ``xyz`` (NaN positions left out)."""
        finite = xyz[np.isfinite(xyz[:, :2]).all(axis=1), :2]
        if len(finite):
            lo, hi = finite.min(axis=0), finite.max(axis=0)
            self.seen = (lo, hi) if self.seen is None else (np.minimum(self.seen[0], lo), np.maximum(self.seen[1], hi))

    def polygon_hint(self) -> str:
        """Where no point passes a polygon: '; site.geojson lies far from the points (...)' where
        it does (taken in another CRS), and the CRS its GeoJSON names; else ''."""
        if self.polygon is None:
            return ""
        polygon = self._box_polygon() or self.polygon  # (as the points were tested)
        hint = ""
        if self.seen is not None and far_apart(polygon, *self.seen):
            (x0, y0), (x1, y1) = polygon.lo, polygon.hi
            (px0, py0), (px1, py1) = self.seen
            moved = f" (given in {polygon.moved_from})" if polygon.moved_from else ""
            advice = f"is it in {polygon.moved_from}?" if moved else "give it in the files' coordinates"
            hint = (
                f"; {polygon.source}{moved} spans x {x0:.6g}..{x1:.6g}, y {y0:.6g}..{y1:.6g}, far from the points' x {px0:.6g}..{px1:.6g}, "
                f"y {py0:.6g}..{py1:.6g}: {advice}"
            )
        if polygon.epsg is not None:  # (named, and taken as it is: no pyproj, or a file naming no CRS)
            hint += f"; {polygon.source} names EPSG:{polygon.epsg} (it is taken in the files' coordinates, not reprojected)"
        return hint

    def meets(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Which of the boxes ``lo``..``hi`` ((k, 3) arrays, bounds included) may hold points the
        filter keeps: those meeting the clip box and the corridor's rectangle in x and y (tested
        on the four axes that can separate two rectangles: x, y, along and across the line), and
        the polygon (``ClipPolygon.meets``: an edge passes through the box, or it lies inside);
        classes are not known from a box."""
        lo, hi = np.atleast_2d(np.asarray(lo, np.float64)), np.atleast_2d(np.asarray(hi, np.float64))
        meets = np.ones(len(lo), bool)
        if self.clip:
            axes = len(self.clip) // 2
            meets &= np.all((hi[:, :axes] >= self.clip[:axes]) & (lo[:, :axes] <= self.clip[axes:]), axis=1)
        if self.corridor:
            ends, half = np.reshape(self.corridor[:4], (2, 2)), self.corridor[4] / 2
            length = math.dist(self.corridor[:2], self.corridor[2:4])
            ux, uy = (ends[1] - ends[0]) / length
            reach = half * np.array([abs(uy), abs(ux)])  # how far the rectangle's corners lie beyond its ends in x and y
            meets &= np.all((hi[:, :2] >= ends.min(axis=0) - reach) & (lo[:, :2] <= ends.max(axis=0) + reach), axis=1)
            centre, extent = (lo[:, :2] + hi[:, :2]) / 2, (hi[:, :2] - lo[:, :2]) / 2
            distance, offset = along_and_across(centre, self.corridor[:4])
            along, across = extent @ [abs(ux), abs(uy)], extent @ [abs(uy), abs(ux)]  # the boxes' half spans on those axes
            meets &= (distance + along >= 0) & (distance - along <= length) & (np.abs(offset) - across <= half)
        polygon = None if self.polygon is None else self._box_polygon() or self.polygon  # (an octree's: its files' CRS unknown here, as it is)
        if polygon is not None and meets.any():
            meets[meets] = polygon.meets(lo[meets], hi[meets])
        return meets

    def box_shares(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """The share of each box ``lo``..``hi`` ((k, 3) arrays) inside the clip box, in the axes it
        tests (its volume's, or its area's in x and y): the share of a box's points it keeps where
        they spread evenly (an LOD octree weighs a node not loaded by it, lod/store.py). 1 where it
        cannot tell: no clip box (a corridor's or polygon's share is not measured), a box flat in
        an axis it lies within."""
        lo, hi = np.atleast_2d(np.asarray(lo, np.float64)), np.atleast_2d(np.asarray(hi, np.float64))
        if not self.clip:
            return np.ones(len(lo))
        axes = len(self.clip) // 2
        size = hi[:, :axes] - lo[:, :axes]
        inside = np.clip(np.minimum(hi[:, :axes], self.clip[axes:]) - np.maximum(lo[:, :axes], self.clip[:axes]), 0.0, None)
        return np.prod(np.where(size > 0, np.minimum(inside, size) / np.where(size > 0, size, 1.0), 1.0), axis=1)

    def clipped_bounds(self, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bounds ``lo``..``hi`` (a header's) cut to the clip box, the corridor's and the polygon's
        boxes: where the kept points can be."""
        lo, hi = np.array(lo, np.float64), np.array(hi, np.float64)
        if self.clip:
            axes = len(self.clip) // 2
            lo[:axes] = np.maximum(lo[:axes], self.clip[:axes])
            hi[:axes] = np.minimum(hi[:axes], self.clip[axes:])
        if self.corridor:
            ends, half = np.reshape(self.corridor[:4], (2, 2)), self.corridor[4] / 2
            lo[:2] = np.maximum(lo[:2], ends.min(axis=0) - half)
            hi[:2] = np.minimum(hi[:2], ends.max(axis=0) + half)
        polygon = None if self.polygon is None else self._box_polygon()  # (None: it may yet move; bounds not cut)
        if polygon is not None:
            lo[:2] = np.maximum(lo[:2], polygon.lo)
            hi[:2] = np.minimum(hi[:2], polygon.hi)
        return lo, hi


def _placed(polygon: ClipPolygon, path) -> ClipPolygon:
    """``polygon`` in the coordinates of ``path``'s points (``placed_over``)."""
    return placed_over(polygon, [path], path)


def placed_over(polygon: ClipPolygon, files, where) -> ClipPolygon:
    """``polygon`` in the coordinates of the points of ``files`` (named ``where`` in messages):
    ``placed_in`` the CRS the first of them naming one names (``first_crs``: a LAS header, a PLY
    comment), over its LAS header's box (a PLY's header has none); as it is where none names one
    (an octree, a file of another format)."""
    from .crs import first_crs

    if not may_move(polygon):
        return polygon  # in the points' coordinates (the usual case: no header read)
    found = first_crs(files)
    if found is None:
        return polygon
    _, crs, units, header = found
    return placed_in(polygon, crs, units, None if header is None else (header.mins, header.maxs), where)


def may_move(polygon: ClipPolygon) -> bool:
    """Whether ``polygon`` may be moved into its points' CRS, or refused there (``placed_in``): it
    names a CRS, or looks like longitude/latitude; any other is in the points' coordinates."""
    return polygon.moved_from is None and (polygon.epsg is not None or looks_like_lon_lat(polygon))


def placed_in(polygon: ClipPolygon, crs: str | None, units: dict, bounds, where) -> ClipPolygon:
    """``polygon`` in the coordinates of points in ``crs`` (the module's notes; ``units``: its
    io.crs_units, ``bounds``: the points' (lo, hi) box, ``where``: how messages name them, a file
    or a survey; the polygon as ``named``, a bare GeoJSON dict's as its caller labels it:
    'volume: the GeoJSON geometry', ``clip_polygon_of``): moved from the CRS its GeoJSON names into ``crs`` where pyproj is installed;
    else as it is (a warning where both name EPSG codes that differ), or a one-line InputError
    where it lies in longitude/latitude's range far from points in a projected CRS
    (``refuse_lon_lat``: it would clip nothing). As it is where ``crs`` is None."""
    from .crs import crs_identity, horizontal_epsg

    if not may_move(polygon) or crs is None:
        return polygon
    if polygon.epsg is not None:
        moved = polygon.moved_by_crs
        # once a CRS, not once a file (a survey's thousands of tiles share one), however each
        # file writes it (a WKT, GeoTIFF keys' EPSG:n): one polygon for all files in one CRS
        identity = crs_identity(crs)
        if identity not in moved:
            moved[identity] = _moved_into(polygon, crs, where)
        if moved[identity] is not None:
            return moved[identity]
    refuse_lon_lat(polygon, crs, units, bounds, where)
    epsg = horizontal_epsg(crs)
    if polygon.epsg is not None and epsg is not None and epsg != polygon.epsg:
        message = f"{polygon.named} names EPSG:{polygon.epsg}, {where} EPSG:{epsg}: the polygon is taken in the files' coordinates, not reprojected"
        read_once("clip polygon CRS", f"{polygon.source} EPSG:{epsg}", lambda: warn(message, GigapointWarning))
    return polygon


def refuse_lon_lat(polygon: ClipPolygon, crs: str, units: dict, bounds, where) -> None:
    """A one-line InputError, naming it ``named``, where ``polygon``, taken as it is, lies within longitude/latitude's
    range far from the ``bounds`` (lo, hi) of points (named ``where``) in ``crs``, a projected CRS
    (``units``: its io.crs_units): it would clip nothing. ``bounds`` None (a PLY header tells
    none): not here, the points as read tell (PointFilter). One naming no CRS is lon/lat by RFC 7946;
    one naming a CRS is here only without pyproj to move it."""
    from .crs import crs_name

    horizontal = units["horizontal"]
    projected = horizontal is not None and horizontal["metres"] is not None
    if not (projected and bounds is not None and looks_like_lon_lat(polygon) and far_apart(polygon, *bounds)):
        return
    (x0, y0), (x1, y1) = polygon.lo, polygon.hi
    if polygon.epsg is None:
        raise InputError(
            f"{polygon.named}: x {x0:.6g}..{x1:.6g}, y {y0:.6g}..{y1:.6g} looks like longitude/latitude (RFC 7946 GeoJSON) while {where} "
            f"is in {crs_name(crs)}: add a crs member naming its CRS, or reproject it into the files' coordinates"
        )
    raise InputError(
        f"{polygon.named}: names EPSG:{polygon.epsg} while {where} is in {crs_name(crs)}: moving it there needs pyproj "
        f"(pip install 'gigapoint[gis]'), or reproject it into the files' coordinates"
    )


def _moved_into(polygon: ClipPolygon, crs: str, path) -> ClipPolygon | None:
    """``polygon`` moved from the EPSG code it names into ``crs``
    (``path``'s); None without pyproj. A code or CRS PROJ does not know: a one-line InputError
    naming its file."""
    from .crs import crs_name

    try:
        import pyproj
    except ImportError:
        return None
    try:
        source = pyproj.CRS.from_epsg(polygon.epsg)
    except pyproj.exceptions.CRSError:
        raise InputError(f"{polygon.named}: names EPSG:{polygon.epsg}, a CRS PROJ does not know: cannot move it into {path}'s CRS") from None
    try:
        target = pyproj.CRS.from_user_input(crs)
    except pyproj.exceptions.CRSError:
        raise InputError(f"{path}: its CRS ({crs_name(crs)}) is not one PROJ knows: cannot move {polygon.source} (EPSG:{polygon.epsg}) into it") from None
    return moved_polygon(polygon, source, target)


def filtered(chunks: Iterable[PointChunk], path, point_filter: PointFilter | None) -> Iterable[PointChunk]:
    """``chunks`` through ``point_filter`` (``PointFilter.apply``); as they are without one."""
    return chunks if point_filter is None else point_filter.apply(chunks, path)


def along_and_across(xyz: np.ndarray, line) -> tuple[np.ndarray, np.ndarray]:
    """(distance, offset) of points ``xyz`` from ``line`` = (x1, y1, x2, y2), in x and y: how far
    along the line from its start (negative before it), and how far square to it, positive to
    the left of the line looking from its start to its end."""
    x1, y1, x2, y2 = line
    length = math.dist((x1, y1), (x2, y2))
    ux, uy = (x2 - x1) / length, (y2 - y1) / length
    dx, dy = xyz[:, 0] - x1, xyz[:, 1] - y1
    return dx * ux + dy * uy, dy * ux - dx * uy


def point_filter(classes=None, drop_classes=None, clip=None, where: str = "open", names: dict = PYTHON_NAMES, shown: dict | None = None,
                 corridor=None, clip_polygon=None) -> PointFilter | None:  # fmt: skip
    """The PointFilter of the options given (None for none), or a one-line InputError naming the
    bad one (``where``: the operation, ``names``: how the options are spelt, ``PYTHON_NAMES`` or
    ``CLI_NAMES``; ``shown``: the values as given, where not their repr): a class outside 0..255
    or not an integer, a class both kept and dropped, a clip box of other than 4 or 6 numbers,
    NaN or infinite, or with a min above its max, a corridor that is not 5 finite numbers, whose
    line has no length or whose width is not above 0 (``corridor_of``'s checks), a clip polygon
    that cannot be read or is no area (``polygon.clip_polygon_of``'s checks)."""
    given = {"classes": classes, "drop_classes": drop_classes, "clip": clip}
    # (a class given as 2.0 stays visibly a float: why it is refused)
    spell = {"classes": value_text, "drop_classes": value_text, "clip": number_text}
    label = {name: f"{where}: {names[name]}{(shown or {}).get(name) or numbers_text(value, spell[name])}" for name, value in given.items()}
    keep = _classes(classes, label["classes"])
    drop = _classes(drop_classes, label["drop_classes"])
    both = sorted(set(keep) & set(drop))
    if both:
        raise InputError(f"{where}: {names['classes'].strip()} and {names['drop_classes'].strip()} both name class {', '.join(map(str, both))}; keep it or drop it")
    box = _clip(clip, label["clip"])
    lane = () if corridor is None else _corridor(corridor, f"{where}: {names['corridor']}{numbers_text(corridor)}")
    polygon_label = f"{where}: {names['clip_polygon']}{polygon_text(clip_polygon, (shown or {}).get('clip_polygon'))}"
    # (a bare GeoJSON dict named as gigapoint.volume names its own: its refusals once placed over the files start 'open: the GeoJSON geometry: ')
    area = None if clip_polygon is None else clip_polygon_of(clip_polygon, polygon_label, f"{where}: {UNNAMED_GEOMETRY}")
    if not (keep or drop or box or lane or area):
        return None
    return PointFilter(keep, drop, box, lane, area)


def _items(value) -> list | None:
    """The values of ``value`` given as several (a list, a tuple, a 1-D array), None for one that
    is not (a number, a string, an array of other than one dimension: a 2-D array's rows were
    counted as numbers, a 0-d array's iteration a TypeError)."""
    if isinstance(value, (str, bytes)) or not isinstance(value, Iterable) or isinstance(value, np.ndarray) and value.ndim != 1:
        return None
    return list(value)


def _classes(value, label: str) -> tuple[int, ...]:
    """``classes``/``drop_classes`` (an integer, or integers) as a sorted tuple of class numbers
    (``label``: the option and its value, as errors start)."""
    if value is None:
        return ()
    values = [value] if is_whole_number(value) else _items(value)
    problem = f"{label}: class numbers are integers from 0 to 255 (LAS classes)"
    if values is None:
        raise InputError(problem)
    bad = [v for v in values if not (is_whole_number(v) and 0 <= v <= 255)]
    if bad or not values:
        raise InputError(problem + (f", got {value_text(bad[0])}" if bad else ", got none"))
    return tuple(sorted({int(v) for v in values}))


def _clip(value, label: str) -> tuple[float, ...]:
    """``clip`` as a tuple of 4 (x and y) or 6 (x, y and z) finite numbers, mins before maxes."""
    if value is None:
        return ()
    shape = "xmin, ymin, xmax, ymax (any z) or xmin, ymin, zmin, xmax, ymax, zmax"
    values = _items(value)
    if values is None:
        raise InputError(f"{label}: a clip box is {shape}")
    if len(values) not in (4, 6):
        raise InputError(f"{label}: a clip box is {shape}; got {len(values)} numbers")
    if not all(isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v) for v in values):
        raise InputError(f"{label}: a clip box's bounds are finite numbers")
    axes = len(values) // 2
    for axis in range(axes):
        if values[axis] > values[axis + axes]:
            raise InputError(f"{label}: {'xyz'[axis]}min {number_text(values[axis])} is above {'xyz'[axis]}max {number_text(values[axis + axes])}")
    return tuple(float(v) for v in values)


def _corridor(value, label: str) -> tuple[float, ...]:
    """``corridor`` (x1, y1, x2, y2, width) checked as ``corridor_of`` does, with ``label`` naming it."""
    if (values := _items(value)) is None or len(values) != 5:
        raise InputError(f"{label}: a corridor is x1, y1, x2, y2, width (a line's two ends and the corridor's width)")
    return corridor_of(values[:4], values[4], label, label)


def corridor_of(line, width, line_label: str, width_label: str) -> tuple[float, float, float, float, float]:
    """(x1, y1, x2, y2, width) of a corridor along ``line`` (its two ends, x and y) ``width`` wide,
    or a one-line InputError starting with the label of the bad value: a line of other than 4
    finite numbers or whose ends are one point, a width that is not a finite number above 0."""
    ends = _items(line)
    if ends is None or len(ends) != 4:
        raise InputError(f"{line_label}: a line is x1, y1, x2, y2 (its two ends)")
    if not all(is_real(v) for v in ends):
        raise InputError(f"{line_label}: a line's ends are finite numbers")
    if max(map(abs, ends)) > MAX_ABS_COORDINATE:  # (as points beyond it are: 1e300 said 'camera eye and target are the same point')
        raise InputError(f"{line_label}: a line's end lies beyond ±{MAX_ABS_COORDINATE:g}: no point can be there")
    if ends[:2] == ends[2:]:
        raise InputError(f"{line_label}: the line's two ends are one point; it has no direction")
    if not (is_real(width) and width > 0):
        raise InputError(f"{width_label}: the corridor's width must be a finite number above 0")
    if width > MAX_SPAN:  # (1e300 overflowed the camera's sums: a blank image and numpy's warnings)
        raise InputError(f"{width_label}: the corridor's width must be at most {MAX_SPAN:g}, the span points can have")
    return (*(float(v) for v in ends), float(width))


def cli_point_filter(classes: str | None, drop_classes: str | None, clip: str | None, where: str = "filter", clip_polygon: str | None = None) -> PointFilter | None:
    """``point_filter`` of the CLI's ``--classes 2,6``, ``--drop-classes 7,18`` and ``--clip
    x0,y0,x1,y1``: comma-separated numbers (one that is not a number: a one-line error), and
    ``--clip-polygon AREA`` (a file, or WKT text)."""

    def numbers_of(text: str | None, name: str, kind):
        if text is None:
            return None
        try:
            return [kind(t) for t in text.split(",")]
        except ValueError:
            what = "integers from 0 to 255" if kind is int else "numbers"
            raise InputError(f"{where}: {CLI_NAMES[name]}{text}: give {what}, separated by commas") from None

    shown = {"classes": classes, "drop_classes": drop_classes, "clip": clip, "clip_polygon": clip_polygon}
    keep, drop, box = numbers_of(classes, "classes", int), numbers_of(drop_classes, "drop_classes", int), numbers_of(clip, "clip", float)
    return point_filter(keep, drop, box, where, CLI_NAMES, shown, clip_polygon=clip_polygon)


__all__ = ["PointFilter", "along_and_across", "cli_point_filter", "corridor_of", "filtered", "point_filter"]
