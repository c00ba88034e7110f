"""Points read from files moved into another coordinate reference system, a chunk at a time
(PDAL's filters.reprojection, LAStools' las2las -target_epsg): ``convert -o out.laz --to-crs``
and ``tile --to-crs`` (lod/convert/to_file.py's PointFiles), ``convert -o octree/`` or ``-o
out.copc.laz`` (lod/convert/read.py's read phase), through pyproj (PROJ), an optional
dependency (``pip install 'gigapoint[gis]'``). A clip polygon is moved into the target, where the
points are filtered, from the inputs' CRS or the one its GeoJSON names (``clip_polygon``).

Each file's CRS is the one its header names (its WKT, else its GeoTIFF keys: LasHeader.crs), or
``from_crs`` for every file where given (PDAL's in_srs). x and y are transformed with
``always_xy`` (east, north; longitude, latitude). z follows PROJ's rule: it is transformed only
where both CRSs have a vertical part (compound CRSs such as 'EPSG:2994+6360'); between 2D CRSs
PROJ passes it through as it is, so a feet -> metres transform of x and y leaves z in feet unless
the vertical CRSs say otherwise (warned of: the output header's 2D CRS says nothing of z).

The output's LAS grid keeps the inputs' precision in the new units (one step of the source's grid,
as far as it moves the points, rounded down to a power of ten: 0.01 ft -> 0.001 m) on an offset
that is a round number below the points (``output_grid``); the output's bounds are those of the
headers' boxes transformed (a grid of samples over each box: projections bend straight edges).

Fast path (reproject_grid.py): a chunk's points are interpolated from PROJ's exact transform of a
grid of control points over their box, the grid refined until the interpolation is within
``tolerance`` (set by ``output_grid``: a tenth of the output grid's step, 0.0001 m for 0.001 m)
at every cell's and edge's middle, checked against PROJ. The exact path (every point through
PROJ) where no grid gets there (near a projection's singularity), for small chunks, where
``exact=True`` (``--exact-transform``), where no tolerance is set (outputs with no grid: PLY),
where an operation PROJ may use applies a grid file (datum and geoid grids are interpolated
bilinearly by PROJ: kinks a smooth interpolation would miss between check points), and for a
chunk whose box crosses the edge of the area of use of one of several operations PROJ picks
among point by point (a jump there)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..core.chunk import PointChunk
from ..core.coords import MAX_ABS_COORDINATE
from ..errors import GigapointWarning, InputError, counted, first_line, warn
from .crs import crs_identity, crs_name, crs_units, file_crs, same_horizontal
from .filters import PointFilter, may_move, placed_in, placed_over
from .las import LasReader
from .las_fields import las_grid, power_of_ten_below
from .polygon import ClipPolygon, moved_polygon
from .registry import reader_for

#: samples along each horizontal edge of a header's box (a grid of them over it, at both heights)
#: whose transforms bound the box's: a projection turns straight edges into curves
BOX_SAMPLES = 21
#: steps of the output grid between its offset and the points' minimum, at most: the offset a
#: round number (a power of ten times the step) that is near the points
OFFSET_STEPS = 10**6
#: the interpolation's tolerance (the fast path's bound), in output grid steps
TOLERANCE_STEPS = 0.1
#: chunks of fewer points are transformed exactly (a grid's own exact transforms cost as much)
MIN_INTERPOLATED = 4096
#: degrees kept between a chunk's box and the edge of an operation's area of use (the fast path's
#: test of which operation PROJ picks; PROJ tests the area's box in the source CRS)
AREA_MARGIN = 0.01


def pyproj_module(option: str):
    """pyproj, or a one-line InputError naming ``option`` where it is not installed."""
    try:
        import pyproj
    except ImportError:
        raise InputError(f"{option}: reprojecting needs pyproj (pip install 'gigapoint[gis]')") from None
    return pyproj


def parse_crs(value, option: str):
    """``value`` ('EPSG:32610', a WKT, a PROJ string) as a pyproj CRS, or a one-line InputError
    starting with ``option`` (e.g. "convert: to_crs='EPSG:0'"): checked before a point is read."""
    pyproj = pyproj_module(option)
    if not isinstance(value, str) or not value.strip():
        raise InputError(f"{option}: a CRS is a string such as 'EPSG:32610', a WKT or a PROJ string")
    try:
        return pyproj.CRS.from_user_input(value)
    except pyproj.exceptions.CRSError as exc:
        raise InputError(f"{option}: not a CRS PROJ knows ({first_line(exc)})") from None


def parse_output_crs(value, option: str):
    """``parse_crs`` of a target CRS, refusing one that cannot place points: a vertical CRS alone
    (x, y came out in degrees labelled heights), a geocentric one (z in feet was taken as metres)."""
    crs = parse_crs(value, option)
    if crs.is_vertical and not crs.sub_crs_list:
        raise InputError(f"{option}: {crs.name} is a vertical CRS only: give a horizontal or compound CRS (e.g. EPSG:32610+5703)")
    if crs.is_geocentric:
        raise InputError(
            f"{option}: {crs.name} is a geocentric CRS (x, y, z from the earth's centre), not a point cloud's output CRS: "
            "give a projected, geographic or compound CRS (e.g. EPSG:32610+5703)"
        )
    return crs


def round_offset(lo: np.ndarray, step: np.ndarray) -> np.ndarray:
    """A round offset at or below ``lo`` for a grid of ``step``: a multiple of step x 10^6, a power
    of ten (1000 m for a millimetre grid), rounded to the step's decimals (no 0.30000000000000004)."""
    unit = step * OFFSET_STEPS
    decimals = np.maximum(0, -np.floor(np.log10(step))).astype(int)
    return np.array([round(math.floor(v / u) * u, d) for v, u, d in zip(lo, unit, decimals)])


def _metres_across(crs) -> float | None:
    """Metres in the unit of a projected CRS's x (a compound one's horizontal part's); None for a
    geographic one (degrees: no length)."""
    axis = crs.axis_info[0] if crs.axis_info else None
    return None if axis is None or crs.is_geographic or axis.unit_name.startswith("deg") else axis.unit_conversion_factor


def _z_metres(crs) -> float | None:
    """Metres in the unit z is in: its vertical axis's (a compound CRS's is its last, as pyproj
    lists them; a 3D geographic one's ellipsoidal heights); without one, its x's
    (``_metres_across``), metres for a geographic one (its heights are ellipsoidal, in metres: feet
    to degrees keeps z in feet, which was said nothing of)."""
    if len(crs.axis_info) == 3:  # (EPSG:2994+5703 has x in feet, z in metres: x's unit warned of z kept in metres)
        return crs.axis_info[2].unit_conversion_factor
    return 1.0 if crs.is_geographic else _metres_across(crs)


def _operation_areas(transformer) -> list | None:
    """The areas of use (lon/lat boxes: west, south, east, north) of the operations a new
    ``transformer`` (not used yet) has PROJ pick among point by point ([] where it has one); None
    where one applies a grid file (the exact path: module notes)."""
    from pyproj.transformer import TransformerGroup

    candidates = [transformer]
    if not transformer.operations:  # (several candidates: PROJ picks one per point, by their areas of use)
        candidates = TransformerGroup(transformer.source_crs, transformer.target_crs, always_xy=True).transformers
    if any(op.grids for t in candidates for op in (t.operations or [])):
        return None
    return [t.area_of_use.bounds if t.area_of_use else (-180.0, -90.0, 180.0, 90.0) for t in candidates] if len(candidates) > 1 else []


class Reprojection:
    """The move of every input file's points into ``to_crs`` (``from_crs``: the CRS of every file,
    in place of what their headers name). ``where``: the operation ('convert', 'tile') its errors
    start with, and how they name the options (``to_crs=``, ``from_crs=``). Bad CRSs, a file naming
    none without ``from_crs``: one-line InputErrors, before a point is read (``check_files``)."""

    def __init__(self, to_crs, from_crs=None, where: str = "convert", exact: bool = False):
        self.where = where
        self.exact = exact
        self.tolerance = None  # (xy, z) of the fast path's bound (``output_grid``); None: exact
        self.interpolated_points = self.exact_points = 0  # (how each point was moved)
        self._areas: dict[int, list | None] = {}  # per transformer (by id): its ``_operation_areas``
        self.target = parse_output_crs(to_crs, f"{where}: to_crs={to_crs!r}")
        self.given_source = None if from_crs is None else parse_crs(from_crs, f"{where}: from_crs={from_crs!r}")
        self._by_crs: dict[str, object] = {}  # transformers, by their source CRS's text
        self._by_file: dict[str, object] = {}
        self._z_warned = False

    @property
    def from_crs_hint(self) -> str:
        """How an error tells a Python caller to give the inputs' CRS; the command line says its
        option instead (cli/__init__.py's ``PYTHON_HINTS``)."""
        return f"gp.{self.where}(..., from_crs=...)"

    def check_files(self, files) -> None:
        """Each file's transformer made: a file without a CRS, or one PROJ cannot read, is an error
        now. With ``from_crs``, files whose headers name another horizontal CRS are warned of."""
        for f in files:
            self.transformer(f)
        if self.given_source is not None:
            self._warn_of_other_crss(files)

    def _warn_of_other_crss(self, files) -> None:
        """Warn where ``from_crs`` overrides another horizontal CRS the files' headers name (a
        UTM file read as Oregon feet comes out far off, where its own CRS would have moved it right):
        their coordinates are read in ``from_crs`` all the same, as PDAL's in_srs reads them."""
        import pyproj

        others, other_by_text = [], {}  # (each header text parsed once: thousands of tiles name one CRS)
        for f in files:
            text = file_crs(f)[0]
            if text and text not in other_by_text:
                try:
                    other_by_text[text] = not same_horizontal(pyproj.CRS.from_user_input(text), self.given_source)
                except pyproj.exceptions.CRSError:  # (a CRS PROJ cannot read: from_crs is given for such a file)
                    other_by_text[text] = False
            if text and other_by_text[text]:
                others.append((f, text))
        if others:
            f, text = others[0]
            more = f" (and {counted(len(others) - 1, 'more file')})" if len(others) > 1 else ""
            warn(
                f"{f}: names {crs_name(text)[:60]}{more}, another CRS than the one given for every input ({self.given_source.name}): "
                "its coordinates are taken to be in the one given; leave it out to move each file from the CRS its header names",
                GigapointWarning,
            )

    def transformer(self, path):
        """The pyproj Transformer from ``path``'s CRS to the target (one per distinct CRS)."""
        key = str(path)
        if key not in self._by_file:
            self._by_file[key] = self._transformer_of(path)
        return self._by_file[key]

    def _transformer_of(self, path):
        import pyproj

        text = "" if self.given_source is not None else self._file_crs(path)  # ("": every file's, given)
        if text not in self._by_crs:
            source = self.given_source if self.given_source is not None else parse_crs(text, f"{path}: its CRS {text[:60]!r}")
            self._by_crs[text] = pyproj.Transformer.from_crs(source, self.target, always_xy=True)
            self._areas[id(self._by_crs[text])] = _operation_areas(self._by_crs[text])  # (before its first use: then it names that one)
        return self._by_crs[text]

    def _file_crs(self, path) -> str:
        """The CRS ``path``'s header names (WKT or 'EPSG:n'); a one-line InputError where it names none."""
        text = file_crs(path)[0]
        if not text:
            raise InputError(f"{path}: names no CRS to reproject from; give the CRS its coordinates are in with {self.from_crs_hint}")
        return text

    def transformed(self, xyz: np.ndarray, path) -> np.ndarray:
        """``xyz`` (n x 3, float64) in the target CRS: a new array. A valid point that is not
        finite once moved (outside the projection's domain) is a one-line InputError naming
        ``path``; invalid points (NaN, inf, beyond gigapoint's reach) come out as NaN, for the
        readers' rule to skip them (1e30 would come out finite, as if it were a point)."""
        out, lost = self._moved(xyz, path)
        if lost.any():
            at = xyz[np.argmax(lost)]
            raise InputError(
                f"{path}: {counted(int(lost.sum()), 'point lies', 'points lie')} outside the domain of the transform to {self.target.name} "
                f"(e.g. {at[0]:.15g}, {at[1]:.15g}, {at[2]:.15g}): nothing was written; are its coordinates in the CRS it is read in?"
            )
        return out

    def _moved(self, xyz: np.ndarray, path) -> tuple[np.ndarray, np.ndarray]:
        """(``xyz`` in the target CRS, invalid ones NaN; whether each valid point came out not
        finite): interpolated from a control grid where one is within the tolerance, else exact."""
        from ..core.bounds import valid_bounds  # (numba: only once points are moved)

        valid, lo, hi = valid_bounds(xyz, MAX_ABS_COORDINATE)  # (one pass: numpy's mask and box took ~0.1 s a 1 M chunk)
        out = self._interpolated(xyz, valid, lo, hi, path)
        if out is None:
            out = self._exact(xyz, path)
            self.exact_points += len(xyz)
        else:
            self.interpolated_points += len(xyz)
        out[~valid] = np.nan
        return out, valid & ~np.isfinite(out).all(axis=1)

    def _exact(self, xyz: np.ndarray, path) -> np.ndarray:
        """``xyz`` moved by PROJ, every point."""
        x, y, z = (np.array(xyz[:, k], np.float64) for k in range(3))
        self.transformer(path).transform(x, y, z, inplace=True)
        return np.column_stack([x, y, z])

    def _interpolated(self, xyz: np.ndarray, valid: np.ndarray, lo: np.ndarray, hi: np.ndarray, path) -> np.ndarray | None:
        """``xyz`` (its ``valid`` points, within ``lo``..``hi``) moved by a control grid within
        the tolerance; None where the fast path is off, or no grid gets there (the module's notes)."""
        count = int(np.count_nonzero(valid))
        if self.exact or self.tolerance is None or count < MIN_INTERPOLATED:
            return None
        transformer = self.transformer(path)
        areas = self._areas[id(transformer)]
        if areas is None or (areas and not self._one_operation(transformer, areas, lo, hi)):
            return None
        from .reproject_grid import fit

        fitted = fit(lambda x, y, z: transformer.transform(x, y, z), lo, hi, self.tolerance, count)
        if fitted is None:
            return None
        grid, keep_z = fitted
        x, y, z = (np.where(valid, xyz[:, k], np.nan) for k in range(3))  # (invalid points: NaN, no node of theirs)
        return grid.at(x, y, z, keep_z)

    def _one_operation(self, transformer, areas, lo, hi) -> bool:
        """Whether the box ``lo``..``hi`` (source coordinates) lies inside or outside each of the
        operations' ``areas`` (by ``AREA_MARGIN`` at least): PROJ then picks one operation for all
        its points."""
        import pyproj

        geodetic = pyproj.Transformer.from_crs(transformer.source_crs, transformer.source_crs.geodetic_crs, always_xy=True)
        xs, ys = (np.linspace(lo[k], hi[k], BOX_SAMPLES) for k in (0, 1))
        gx, gy = np.meshgrid(xs, ys)
        lon, lat = geodetic.transform(gx.ravel(), gy.ravel())
        if not (np.isfinite(lon).all() and np.isfinite(lat).all()):
            return False
        m = AREA_MARGIN
        for west, south, east, north in areas:
            wraps = west > east  # (an area across the antimeridian)
            inside_lon = ((lon >= west + m) | (lon <= east - m)) if wraps else ((lon >= west + m) & (lon <= east - m))
            outside_lon = ((lon < west - m) & (lon > east + m)) if wraps else ((lon < west - m) | (lon > east + m))
            inside = inside_lon & (lat >= south + m) & (lat <= north - m)
            outside = outside_lon | (lat < south - m) | (lat > north + m)
            if not (inside.all() or outside.all()):
                return False
        return True

    def chunk(self, chunk: PointChunk, path) -> PointChunk:
        """``chunk`` with its positions in the target CRS (its colours and attributes as they are)."""
        return PointChunk(self.transformed(chunk.xyz, path), chunk.rgba, chunk.attributes, color_bits=chunk.color_bits)

    def box(self, path, lo, hi) -> tuple[np.ndarray, np.ndarray]:
        """The bounds in the target CRS of ``path``'s box ``lo``..``hi``: those of a grid of samples
        over it at its lowest and highest z (its corners and edges among them); samples outside the
        transform's domain are left out (the points there, if any, are refused as they are read)."""
        xs, ys = (np.linspace(lo[k], hi[k], BOX_SAMPLES) for k in (0, 1))
        gx, gy, gz = np.meshgrid(xs, ys, [lo[2], hi[2]])
        moved = self._exact(np.column_stack([gx.ravel(), gy.ravel(), gz.ravel()]), path)
        moved = moved[np.isfinite(moved).all(axis=1)]
        return (moved.min(axis=0), moved.max(axis=0)) if len(moved) else (np.zeros(3), np.zeros(3))

    def step(self, path, lo, hi, scale) -> np.ndarray:
        """The output grid's step of ``path``'s points (its grid's ``scale``) per axis: how far one
        step of its grid moves them in the target CRS, at its box's middle, rounded down to a power
        of ten; x and y alike (the finer of the two). Warns once where z is kept as it is while its unit
        changes (between 2D CRSs: PROJ keeps z; a geographic CRS's heights are in metres)."""
        mid = (np.asarray(lo, np.float64) + np.asarray(hi, np.float64)) / 2
        scale = np.asarray(scale, np.float64)
        moved, lost = self._moved(np.array([mid, mid + [scale[0], 0, 0], mid + [0, scale[1], 0], mid + [0, 0, scale[2]]]), path)
        if lost.any():  # (transformed's "4 points lie outside" counted these probes, not the file's points: one file had 1)
            raise InputError(
                f"{path}: the middle of its points' box ({mid[0]:.15g}, {mid[1]:.15g}, {mid[2]:.15g}, as its header says) lies outside the "
                f"domain of the transform to {self.target.name}: nothing was written; are its coordinates in the CRS it is read in?"
            )
        across = min(float(np.hypot(*(moved[k, :2] - moved[0, :2]))) for k in (1, 2))
        up = abs(moved[3, 2] - moved[0, 2])
        units = [_z_metres(c) for c in (self.transformer(path).source_crs, self.target)]
        if math.isclose(up, scale[2], rel_tol=1e-9) and None not in units and not math.isclose(*units, rel_tol=1e-9):
            self._warn_z_kept(path, self.transformer(path).source_crs)
        return np.array([power_of_ten_below(across)] * 2 + [power_of_ten_below(up)])

    def _warn_z_kept(self, path, source) -> None:
        """Says which CRS lacks a vertical part (a 3D geographic CRS's ellipsoidal heights count as one)."""
        if self._z_warned:
            return
        self._z_warned = True
        lacking = [side for side, crs in (("the source CRS", source), ("the target CRS", self.target)) if len(crs.axis_info) < 3]
        which = "neither CRS has a vertical part" if len(lacking) == 2 else f"{lacking[0]} has no vertical part" if lacking else "PROJ found no height transform"
        warn(
            f"{path}: z is kept as it is, in its own unit, while x and y change unit: {which}, and PROJ "
            f"transforms heights only between vertical CRSs; give compound CRSs (e.g. from 'EPSG:2994+6360' to 'EPSG:32610+5703') to convert z",
            GigapointWarning,
        )

    def moved_filter(self, keep: PointFilter | None, files) -> PointFilter | None:
        """``keep`` as it filters the moved points (in the target CRS): its clip polygon moved there
        from its own CRS (``clip_polygon``); its clip box is the target's already."""
        if keep is None or keep.polygon is None:
            return keep
        return replace(keep, polygon=self.clip_polygon(keep.polygon, files))

    def clip_polygon(self, polygon: ClipPolygon, files) -> ClipPolygon:
        """``polygon`` in the target CRS, in which the moved points are filtered: from the CRS its
        GeoJSON names (a ``crs`` member), else the inputs' (``from_crs``, else the one their headers
        name; inputs in several CRSs are refused: which would it be in?), its edges cut into pieces
        whose moved ends follow the curves a projection makes of straight edges (polygon.py's
        ``moved_polygon``, within the fast path's tolerance where set). It names no CRS any more:
        it is in the points' coordinates (no "names EPSG:n" warning). Naming none, in
        longitude/latitude's range far from inputs in a projected CRS (``from_crs``, else the one
        their headers name): refused in one line, as a read filter refuses it (RFC 7946 GeoJSON is
        lon/lat: it would keep nothing)."""
        if polygon.epsg is not None:
            source = parse_crs(f"EPSG:{polygon.epsg}", f"{polygon.source}: its CRS EPSG:{polygon.epsg}")
        elif self.given_source is not None:
            source = self.given_source
            self._refuse_lon_lat_polygon(polygon, files)
        else:
            named = {crs_identity(text): text for text in map(self._file_crs, files)}  # (one CRS as WKT and as GeoTIFF keys: one)
            if len(named) > 1:
                raise InputError(
                    f"{polygon.source}: names no CRS while the inputs are in {len(named)} CRSs: give it as GeoJSON naming "
                    f"its CRS (a crs member), or the CRS of every input with {self.from_crs_hint}"
                )
            text = named.popitem()[1]
            source = parse_crs(text, f"{files[0]}: its CRS {text[:60]!r}")
            placed_over(polygon, files[:1], files[0])  # (lon/lat far from projected inputs: refused in one line, as without --to-crs)
        return moved_polygon(polygon, source, self.target, None if self.tolerance is None else self.tolerance[0])

    def _refuse_lon_lat_polygon(self, polygon: ClipPolygon, files) -> None:
        """A one-line InputError where ``polygon`` (naming no CRS) looks like longitude/latitude far
        from the first of ``files`` whose header gives its box, in ``from_crs`` if that is projected:
        as ``placed_over`` refuses it over inputs whose headers name that CRS (``from_crs`` is
        theirs here: their headers may name none). Files whose headers give no box: not refused."""
        if not may_move(polygon):
            return  # (in the points' coordinates: no header read)
        boxed = next(((f, box) for f in files if (box := reader_for(f).header(f, salvage=True).get("bounds")) is not None), None)
        if boxed is not None:
            crs = self.given_source.to_wkt()
            placed_in(polygon, crs, crs_units(crs), boxed[1], boxed[0])

    def as_spec(self) -> dict:
        """What tells two reprojections apart (a conversion's fingerprint: one resumed under another
        mixed points moved two ways), and all a Dask read task needs to move points the same
        (``from_spec``): the CRSs, as WKT, whether every point goes through PROJ, and the fast
        path's tolerance (``output_grid``'s: it decides which chunks are interpolated)."""
        source = None if self.given_source is None else self.given_source.to_wkt()
        tolerance = None if self.tolerance is None else [float(t) for t in self.tolerance]
        return {"to_crs": self.target.to_wkt(), "from_crs": source, "exact": self.exact, "tolerance": tolerance}

    @classmethod
    def from_spec(cls, spec: dict, where: str = "convert") -> Reprojection:
        """The reprojection ``as_spec`` describes, made again (in a Dask worker): it moves points
        as the one described does, bit for bit."""
        made = cls(spec["to_crs"], spec["from_crs"], where, spec["exact"])
        made.tolerance = None if spec["tolerance"] is None else tuple(spec["tolerance"])
        return made

    def proj_setup(self) -> list:
        """PROJ's version and whether it may fetch grid files (PROJ_NETWORK): besides ``as_spec``,
        what decides the operations PROJ picks, so where the points land (a conversion's
        fingerprint: one resumed under another PROJ mixed points moved two ways)."""
        import pyproj
        from pyproj.network import is_network_enabled

        return [pyproj.proj_version_str, is_network_enabled()]

    def target_wkt(self) -> str:
        """The target CRS as the output's WKT VLR holds it: OGC WKT1, as LAS 1.4 says, or WKT2
        where WKT1 cannot say it (a 3D geographic CRS, EPSG:4979: pyproj raised CRSError, a
        traceback; laspy, PDAL and gigapoint read WKT2 too)."""
        import pyproj

        try:
            return self.target.to_wkt("WKT1_GDAL")
        except pyproj.exceptions.CRSError:
            return self.target.to_wkt("WKT2_2019")


def output_grid(files, reprojection: Reprojection):
    """(scale, offset) of the LAS grid of the reprojected points of LAS ``files``: the finest step
    of theirs in the target CRS (``Reprojection.step``), a round offset below their headers' boxes
    transformed (of the files within gigapoint's reach); None where a file is no LAS file, or none is within it (a grid is then made from the points' bounds, a
    pass over them)."""
    if not all(isinstance(reader_for(f), LasReader) for f in files):
        return None
    boxes, steps = [], []
    for f in files:
        header = reader_for(f).header(f)
        lo, hi = (np.asarray(b, np.float64) for b in header["bounds"])
        if not (np.all(np.isfinite(lo) & np.isfinite(hi)) and max(np.abs(lo).max(), np.abs(hi).max()) <= MAX_ABS_COORDINATE):
            continue  # beyond gigapoint's reach: no grid of its (a NaN step was "cannot convert float NaN to integer"); its points are skipped as read
        boxes.append(reprojection.box(f, lo, hi))
        steps.append(reprojection.step(f, lo, hi, np.abs(np.asarray(header["scale"], np.float64))))
    if not boxes:
        return None
    lo, hi = np.min([b[0] for b in boxes], axis=0), np.max([b[1] for b in boxes], axis=0)
    step = np.min(steps, axis=0)
    reprojection.tolerance = (step[0] * TOLERANCE_STEPS, step[2] * TOLERANCE_STEPS)
    return las_grid(lo, hi, step, round_offset(lo, step))


__all__ = ["Reprojection", "output_grid", "parse_crs", "round_offset"]
