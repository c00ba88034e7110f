"""Change between two surveys of one place (a stockpile, a quarry, a cliff flown twice): what
moved and how much, as CloudCompare's 2.5D volume tool and a PDAL + GDAL DSM of difference give it.

Both surveys are drawn as surface models (the z of the highest point in each pixel, as
``render --gsd --depth-out`` draws one) through ONE top-down camera (``Camera.top_down``) over the
union of their bounds: the same pixel edges, on whole multiples of the gsd, and the same eye, so
the difference is pixel to pixel and both heights come from depths measured from one height.
The union (not the intersection) keeps the whole of both surveys on the map: a pixel only one of
them covers is NaN in the difference, as is one neither covers, and the compared area says how
much both cover. Each point lands in its exact pixel (one-pixel points, 30-bit positions): no
splat reaches a neighbour, so a pixel without a point is NaN, not a guess; ``fill_nodata`` fills
those holes of each surface (render/raster_fill.py: a TIN inside its footprint) before they are compared.

A survey kept as an LOD octree (a converted folder, a COPC file, an EPT dataset) is read node by
node: every point lives in exactly one node of these layered octrees (lod/query.py), so its
surface is the highest of the surfaces of its nodes meeting the area, drawn STREAM_POINTS points
at a time (memory bounded by those, not by the survey), its positions put back on its source's
LAS grid. Only the levels whose points are needed at the gsd are read: down to the first whose
spacing is at most SURFACE_SPACING of a pixel, a sample of the survey of which a coarse gsd
reads a small part (not the deep levels that hold most points). A pixel's height is then that of
the highest point sampled there, never above its highest point (but for a point on a pixel edge,
which other draws may put on either side) and below it by up to about the
spacing read (a sampler keeps one point of each cell of that side, not the highest): where the
ground rises within a cell (a roof's edge, a tree's crown), not on open ground. That bound is in
z, whatever the pixel's size, hence a quarter of a pixel and not half: autzen (110,000 points,
max_leaf 2,000) at 16 ft reads 79,000 points (levels down to 2.3 ft), 98 % of its pixels within
0.5 ft of every point's surface, 99.5 % within 2.3 ft; at half a pixel (4.6 ft) 30,000 points,
88 % within 0.5 ft. A sampled surface lies low where the ground is rough: sampled as the before
survey, fill comes out high and cut low; as the after survey, the reverse (``change`` warns where
only one of the two is sampled). ``full=True`` reads every node (every point: the surface of the
point files exactly).

A survey of fewer than STREAM_POINTS points is drawn whole, as its point files would be; in several draws
a point lying exactly on a pixel edge may fall on either side (each draw's batches have float32
transforms of their own): ~0.1 % of autzen's 4 ft pixels drawn 20,000 points at a time.

Both surveys must be in one CRS and one unit: nothing is reprojected (``gigapoint convert
--to-crs`` does that), and a height difference between feet and metres would be no length. A
geographic CRS is refused: its x and y are degrees, and areas and volumes in them (a pile's
fill of 4e-7 square degrees times metres, printed "0.000 cubic units") would be no measure.

Volumes are the difference summed over the pixels compared, times a pixel's area: fill where the
after surface is higher, cut where it is lower, net = fill - cut. ``min_change`` is a level of
detection: only pixels that moved by more count in the volumes and the changed area, "more" by
more than the float32 heights can tell from their rounding (``Change.resolution``: a move of
exactly ``min_change`` is no more; 0: all that moved by more than that rounding)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from ..core.chunk import PointChunk
from ..core.cloud import PointCloud, build_cloud
from ..errors import CameraError, InputError, check_switch, is_real, number_text, warn
from ..io.crs import crs_identity, crs_name, refuse_angles
from ..io.filters import PointFilter, point_filter
from ..io.paths import given_paths
from ..lod.potree import PotreeCloud
from ..lod.query import deepest_level, is_octree, points_meeting
from ..lod.reader import cloud_crs_units
from ..lod.store import OctreeCloud
from ..lod.voxel_octree import VoxelOctree
from ..render import Camera
from ..render.colors import ramp_image
from ..render.georef import write_map
from ..render.raster_fill import check_max_distance, fill_heights
from ..render.surface import surface_heights
from .raster_grid import RasterGrid

PREVIEW_COLORMAP = "rdbu"  # diverging, white at 0: red where ground was cut, blue where it was filled
PREVIEW_PERCENTILE = 98.0  # of |dz|: the preview's default range (a few outliers do not wash it out)
#: an octree's levels read for a surface: down to the first whose point spacing is at most this share of a pixel
#: (a pixel's height then at most about that spacing below its highest point's: see above)
SURFACE_SPACING = 0.25
#: points of an octree's nodes drawn at a time into its surface: its memory, whatever the survey's size
STREAM_POINTS = 4_000_000


@dataclass(frozen=True)
class Change:
    """Two surfaces on one grid: ``before`` and ``after`` (H, W) float32 heights (NaN: no point),
    drawn through ``camera`` (``Camera.top_down``: its ``world_file()``), pixels ``gsd`` a side;
    ``crs`` and ``units`` (io.crs_units) those of the surveys; ``min_change`` the level of detection."""

    before: np.ndarray
    after: np.ndarray
    camera: Camera
    gsd: float
    crs: str | None
    units: dict
    min_change: float = 0.0

    @cached_property
    def dz(self) -> np.ndarray:
        """(H, W) float32 after - before; NaN where either surface is empty."""
        return self.after - self.before

    @cached_property
    def compared(self) -> np.ndarray:
        """Pixels both surveys cover."""
        return ~np.isnan(self.dz)

    @cached_property
    def resolution(self) -> float:
        """The smallest difference the float32 heights can tell from rounding: two ulps of the
        largest |height| (each surface's height is rounded once from its depth, once to float32).
        Points that did not move came out an ulp apart where their batches differ (a moved point
        changed a batch's box): 3e-5 ft at autzen's 500 ft, in ~1 % of its pixels."""
        heights = np.abs(np.concatenate([self.before[self.compared], self.after[self.compared]]))
        return 2 * float(np.spacing(heights.max())) if len(heights) else 0.0

    @cached_property
    def changed(self) -> np.ndarray:
        """Compared pixels that moved by more than ``min_change`` plus the heights' ``resolution``
        (not the larger of the two: a move of exactly ``min_change`` came out up to an ulp above it)."""
        return self.compared & (np.abs(np.where(self.compared, self.dz, 0.0)) > self.min_change + self.resolution)

    @property
    def cell_area(self) -> float:
        return self.gsd * self.gsd

    def _summed(self, keep: np.ndarray) -> float:
        """The changed pixels' dz where ``keep``, summed in float64, times a pixel's area."""
        return float(self.dz[self.changed & keep].sum(dtype=np.float64)) * self.cell_area

    @property
    def fill(self) -> float:
        """Volume gained (after above before), in the units' cube."""
        return self._summed(self.dz > 0)

    @property
    def cut(self) -> float:
        """Volume lost (after below before), positive."""
        return abs(self._summed(self.dz < 0))  # (abs: no -0.0 where nothing was cut)

    @property
    def net(self) -> float:
        return self.fill - self.cut

    @property
    def area_compared(self) -> float:
        return int(self.compared.sum()) * self.cell_area

    @property
    def area_changed(self) -> float:
        return int(self.changed.sum()) * self.cell_area

    def summary(self) -> dict:
        """The figures as ``gigapoint change --json`` gives them, with their units."""
        return {
            "cut": self.cut, "fill": self.fill, "net": self.net,
            "area_compared": self.area_compared, "area_changed": self.area_changed,
            "min_change": self.min_change, "gsd": self.gsd, "pixels_compared": int(self.compared.sum()),
            "resolution": self.resolution, "units": unit_names(self.units), "crs": self.crs,
        }  # fmt: skip

    def preview_range(self) -> float:
        """The preview's default half-range: the 98th percentile of |dz| over the changed pixels
        (over all those compared, a pile on 1 % of the map was saturated at the noise's 3e-5);
        1 where none changed."""
        moved = np.abs(self.dz[self.changed])
        limit = float(np.percentile(moved, PREVIEW_PERCENTILE)) if len(moved) else 0.0
        return limit if limit > 0 else 1.0

    def preview(self, limit: float | None = None) -> np.ndarray:
        """(H, W, 4) uint8 image of dz on a diverging colormap symmetric around 0, from -``limit``
        (red: cut) through white (no change) to +``limit`` (blue: fill), clamped beyond; transparent
        where nothing is compared. ``limit`` None: ``preview_range()``."""
        if limit is None:
            limit = self.preview_range()
        elif not (is_real(limit) and limit > 0):
            raise InputError(f"change: the preview's range must be a number > 0 (a height difference), got {number_text(limit)}")
        return ramp_image(self.dz, -limit, limit, PREVIEW_COLORMAP)  # (not compared: dz NaN, transparent)

    def write_geotiff(self, path, overwrite: bool = False) -> list[Path]:
        """``dz`` as ``path``, a float32 GeoTIFF (.tif, NaN nodata) in the surveys' CRS, with its
        world file and .prj: the files ``gigapoint change -o PATH`` writes, byte for byte, all or
        none; an existing file is replaced only with ``overwrite=True``. Returns the paths."""
        check_switch("overwrite", overwrite, "change")
        return write_map(self.camera, self.crs, self.units, [(path, self.dz)], overwrite)

    def write_preview(self, path, limit: float | None = None, overwrite: bool = False) -> list[Path]:
        """``preview(limit)`` as the image ``path`` (.png, ...; a .tif is a GeoTIFF), with its world
        file and .prj (one already beside it holding this CRS is kept: change.tif's for change.png),
        as ``gigapoint change --preview PATH`` writes them. Returns the paths."""
        check_switch("overwrite", overwrite, "change")
        return write_map(self.camera, self.crs, self.units, [(path, self.preview(limit))], overwrite)


def unit_names(units: dict) -> dict:
    """{"length", "area", "volume"}: the symbols the surveys' coordinates give lengths, areas and
    volumes in ("ft", "ft²", "ft³"); a volume is an area times a height, whose unit may differ
    ("m²·ft"); "units" where the CRS names none."""
    length, height = unit_symbols(units)
    height = height or length
    if length is None:
        return {"length": "units", "area": "square units", "volume": "cubic units"}
    return {"length": length, "area": f"{length}²", "volume": f"{length}³" if height == length else f"{length}²·{height}"}


def unit_symbols(units: dict) -> tuple[str | None, str | None]:
    """(horizontal, vertical) symbols of ``units`` (io.crs_units): 'ft', 'm'; None where unknown or an angle."""
    across, up = (u["symbol"] if u and u["metres"] is not None else None for u in (units.get("horizontal"), units.get("vertical")))
    return across, up


def survey_label(source, where: str | None = None, name: str = "source") -> str:
    """How messages name a survey: its path(s) as given, or its cloud's (or opened octree's) name;
    anything else a one-line InputError (``io.given_paths``: ``where``, the operation; ``name``, the argument)."""
    if isinstance(source, PointCloud) or is_octree(source):
        return source.name
    paths = given_paths(source, where, name)
    return ", ".join(map(str, paths[:3])) + (f" and {len(paths) - 3} more" if len(paths) > 3 else "")


def open_survey(source, filters: dict, where: str = "change"):
    """``source`` (paths as ``gigapoint.open`` takes them, a PointCloud, or an LOD octree) as one
    PointCloud of the points the filters keep (only those read from files), or as the LOD octree
    it is or opens as (unread: ``surface`` reads its nodes; one opened from a path filtered as
    frames load it); ``where``: the operation messages name."""
    if isinstance(source, PointCloud):
        keep = point_filter(**filters, where=where)
        if keep is None:
            return source
        kept = list(keep.apply(source.chunks(), source.name))
        keep.check_passed(source.name)
        return build_cloud(kept, name=source.name, colors="rgba")
    if is_octree(source):
        if any(v is not None for v in filters.values()):  # (its own filter is the one it was opened with)
            raise InputError(f"{source.name}: an opened LOD octree reads no other filter; give its path, or open it with them (gigapoint.open(path, classes=...))")
        return source
    from .. import open_for

    cloud = open_for(where, source, **filters)
    if not (isinstance(cloud, PointCloud) or is_octree(cloud)):
        raise InputError(f"{survey_label(source)}: an unfinished conversion; its preview holds a sample of the points: give the point files, or wait for the octree")
    return cloud


def _lengths(units: dict) -> tuple:
    """(horizontal, vertical) metres of a unit of ``units`` (io.crs_units); None where unknown or an angle."""
    return tuple(u["metres"] if u else None for u in (units["horizontal"], units["vertical"]))


def units_named(units: dict) -> str:
    """How messages name a survey's units: 'lengths in ft', 'lengths in m, heights in ft', 'units unknown'."""
    across, up = unit_symbols(units)
    if across is None:
        return "units unknown" if up is None else f"heights in {up}"
    return f"lengths in {across}" + (f", heights in {up}" if up not in (None, across) else "")


def check_crs(before, after, labels: tuple[str, str]) -> tuple[str | None, dict]:
    """(The CRS both surveys are in, its units: io.crs_units); one naming none takes the
    other's. A one-line InputError naming both where they name different CRSs, or different
    units (autzen's WKT in feet and its copy in metres: one projection, other numbers): nothing
    is reprojected, their pixels would not be the same ground, nor their heights one unit; and
    where their x and y are angles (a geographic CRS): no area or volume is measured in degrees."""
    (crs_a, units_a), (crs_b, units_b) = cloud_crs_units(before), cloud_crs_units(after)
    other_crs = crs_a and crs_b and crs_identity(crs_a) != crs_identity(crs_b)
    known = [(a, b) for a, b in zip(_lengths(units_a), _lengths(units_b)) if a is not None and b is not None]
    if other_crs or not all(math.isclose(a, b, rel_tol=1e-9) for a, b in known):  # (ft and US ft: 2 ppm, 2 ft a million ft out)
        raise InputError(
            f"{labels[0]} is in {crs_name(crs_a)}, {units_named(units_a)}; {labels[1]} in {crs_name(crs_b)}, {units_named(units_b)}: "
            "change compares two surveys in one CRS and unit; reproject one first (gigapoint convert --to-crs)"
        )
    crs, units = (crs_a, units_a) if crs_a else (crs_b, units_b)
    # (degrees: a pixel's area and the volumes would be in square degrees, "0.000 cubic units")
    refuse_angles("change", labels[0] if crs_a else labels[1], crs, units, "measuring areas and volumes", bounds=before.bounds)
    return crs, units


def surface(cloud, camera: Camera, fill_nodata=None, full: bool = False) -> np.ndarray:
    """(H, W) float32 heights of ``cloud``'s highest point in each of ``camera``'s pixels (NaN:
    none); ``fill_nodata`` "all" or N: holes filled (raster_fill.fill_heights). An LOD octree's
    points are read node by node (``_octree_heights``): the levels the camera's gsd needs, every
    node with ``full``."""
    if is_octree(cloud):
        heights = _octree_heights(cloud, camera, full)
    else:
        heights = surface_heights(cloud, camera)
    return heights if fill_nodata is None else fill_heights(heights, None if fill_nodata == "all" else fill_nodata)


def _octree_heights(octree, camera: Camera, full: bool) -> np.ndarray:
    """``surface`` of the LOD octree ``octree`` (of the points its read filter keeps): the points of
    its nodes meeting the filter, at the levels down to a spacing of SURFACE_SPACING of a pixel
    (``full``: at every level, each point in one node), drawn STREAM_POINTS at a time, each pixel
    the highest of the heights drawn there; nodes outside the camera's footprint are not read."""
    pixels = RasterGrid.of_camera(camera)
    max_spacing = _spacing_read(camera, full)
    keep = octree.read_filter if isinstance(octree, OctreeCloud) and octree.read_filter is not None else PointFilter()
    footprint = PointFilter(clip=pixels.bounds)
    heights = np.full((camera.height, camera.width), np.nan, np.float32)
    group: list = []

    def draw_group():
        np.fmax(heights, surface(build_cloud(group, name=octree.name, colors="rgba"), camera), out=heights)
        group.clear()

    grid = _source_grid(octree)
    for points in points_meeting(octree, lambda lo, hi: keep.meets(lo, hi) & footprint.meets(lo, hi), max_spacing):
        kept = keep.kept(points, octree.name)
        if len(kept):
            group.append(kept if grid is None else _on_grid(kept, *grid))
        if sum(map(len, group)) >= STREAM_POINTS:
            draw_group()
    if group:
        draw_group()
    keep.check_passed(octree.name)
    return heights


def _spacing_read(camera: Camera, full: bool) -> float | None:
    """The spacing an octree's levels are read down to for ``camera``'s surface; None (every level) with ``full``."""
    return None if full else SURFACE_SPACING * RasterGrid.of_camera(camera).cell


def is_sampled(survey, camera: Camera, full: bool) -> bool:
    """Whether ``surface`` reads only a sample of ``survey``: an octree whose levels the camera's
    gsd needs stop above its deepest."""
    if not isinstance(survey, OctreeCloud):  # (a ProgressiveOctree's every leaf is read: points_meeting)
        return False
    deepest = deepest_level(survey, _spacing_read(camera, full))
    return deepest is not None and deepest < int(survey.levels.max())


def warn_one_sampled(surveys: list, labels: tuple[str, str], camera: Camera, full: bool) -> None:
    """One warning where one survey's surface is a sample (``is_sampled``) and the other's every
    point: its surface lies low, which biases fill and cut one way (not where both are sampled)."""
    sampled = [is_sampled(s, camera, full) for s in surveys]
    if sampled[0] == sampled[1]:
        return
    which = 0 if sampled[0] else 1
    bias = "fill comes out high and cut low" if which == 0 else "cut comes out high and fill low"
    warn(
        f"change: {labels[which]} is read down to the octree levels the gsd needs (a sample of its points), {labels[1 - which]} whole: "
        f"the sample's surface lies low where the ground is rough, so {bias}; --all-points (full=True) reads every point"
    )


def _source_grid(octree) -> tuple[np.ndarray, np.ndarray] | None:
    """(scale, offset) of the grid an octree's source stored its points on (a LAS file's, a
    Potree folder's own); None where it names none."""
    if isinstance(octree, PotreeCloud):
        return octree.scale, octree.offset
    if isinstance(octree, OctreeCloud) and octree.meta.get("scale") is not None:
        return np.asarray(octree.meta["scale"], np.float64), np.asarray(octree.meta.get("offset") or (0.0, 0.0, 0.0), np.float64)
    return None


def _on_grid(chunk: PointChunk, scale: np.ndarray, offset: np.ndarray) -> PointChunk:
    """``chunk``'s points moved back onto their source's grid, as a LAS reader gives them (integer
    * scale + offset), and said to be on it: a node's 30-bit positions lie up to 6e-5 ft off it,
    which moved autzen's points on a pixel edge into the next pixel (a 9 ft change in 20 of its
    4 ft pixels against the LAZ file), and the cloud drawn keeps them exact (core/compact.py)."""
    xyz = np.round((chunk.xyz - offset) / scale) * scale + offset
    return PointChunk(xyz, chunk.rgba, chunk.attributes, scale=tuple(map(float, scale)), color_bits=chunk.color_bits)


def change(before, after, gsd, classes=None, drop_classes=None, clip=None, fill_nodata=None, min_change=0.0, full=False) -> Change:
    """The change from survey ``before`` to survey ``after`` (each paths as ``gigapoint.open``
    takes them: a file, a folder, a glob pattern, a list; an LOD octree, read node by node down to
    the levels the gsd needs: a converted folder, a COPC file, an EPT dataset, or one opened; or a PointCloud), as two surface models
    on one grid of ``gsd`` units a pixel over the union of their bounds (``Change``: ``dz``,
    ``cut``, ``fill``, ``net``, ``area_compared``, ``area_changed``, ``preview()``).

    ``classes``/``drop_classes``/``clip``: only those points read of both (``classes=[2]``:
    ground against ground); ``fill_nodata``: "all" or N pixels, each surface's holes filled
    linearly inside its footprint first (needs scipy); ``min_change``: pixels that moved by no
    more are left out of the volumes and the changed area; ``full``: an octree's every node read,
    not only the levels the gsd needs (its surface then that of its point files exactly). Surveys that name different CRSs or
    units (feet and metres), or that share no pixel, are one-line InputErrors."""
    if not (is_real(gsd) and gsd > 0):
        raise InputError(f"change: gsd must be a number > 0 (cloud units per pixel), got {number_text(gsd)}")
    if not (is_real(min_change) and min_change >= 0):
        raise InputError(f"change: min_change must be a number >= 0 (a height difference), got {number_text(min_change)}")
    if fill_nodata is not None and fill_nodata != "all":
        check_max_distance("change: fill_nodata", fill_nodata)
    check_switch("full", full, "change")
    filters = {"classes": classes, "drop_classes": drop_classes, "clip": clip}
    point_filter(**filters, where="change")  # bad values told before anything is read
    labels = (survey_label(before, "change", "before"), survey_label(after, "change", "after"))
    surveys: list = []
    try:
        for source in (before, after):
            surveys.append(open_survey(source, filters))
        crs, units = check_crs(*surveys, labels)
        lows, highs = zip(*(s.bounds for s in surveys))  # (an octree's: its metadata's, cut to its read filter's region)
        if (np.maximum(*lows)[:2] > np.minimum(*highs)[:2]).any():  # (their union's grid was refused as too fine, or drawn for nothing)
            spans = "; ".join(f"{label} x {lo[0]:.6g}..{hi[0]:.6g}, y {lo[1]:.6g}..{hi[1]:.6g}" for label, lo, hi in zip(labels, lows, highs))
            raise InputError(f"{labels[0]} and {labels[1]}: the surveys do not overlap ({spans}): nothing to compare")
        try:
            camera = Camera.top_down((np.minimum(*lows), np.maximum(*highs)), gsd)  # one grid, one eye: pixel to pixel
        except CameraError as exc:  # the grid spans both: name them (a huge survey beside a tiny one said neither)
            raise CameraError(f"{labels[0]} and {labels[1]}: {exc}") from None
        warn_one_sampled(surveys, labels, camera, full)
        heights = [surface(s, camera, fill_nodata, full) for s in surveys]
    finally:
        for survey, source in zip(surveys, (before, after)):
            if isinstance(survey, VoxelOctree) and survey is not source:  # a COPC/EPT octree opened here (a URL's connections)
                survey.close()
    result = Change(*heights, camera=camera, gsd=float(gsd), crs=crs, units=units, min_change=float(min_change))
    if not result.compared.any():
        raise InputError(f"{labels[0]} and {labels[1]}: no {number_text(gsd)}-unit pixel holds points of both: the surveys do not overlap")
    return result


__all__ = ["Change", "change", "unit_names", "unit_symbols"]
