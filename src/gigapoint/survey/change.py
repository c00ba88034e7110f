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

Volumes are the difference summed over the pixels compared, times a pixel's area: fill where the
after surface is higher, cut where it is lower, net = fill - cut. ``min_change`` is a level of
detection: only pixels that moved by more count in the volumes and the changed area (0: all
that moved by more than the float32 heights can tell from their rounding, ``Change.resolution``)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from ..core.cloud import PointCloud, build_cloud
from ..errors import CameraError, InputError, check_switch, is_real
from ..io.crs import crs_identity, crs_name
from ..io.filters import point_filter
from ..lod.reader import cloud_crs, cloud_units
from ..render import Camera, RenderSettings, render_frame
from ..render.colors import colormap_table, ramp
from ..render.georef import write_map
from ..render.raster_fill import check_max_distance, fill_heights

#: a surface model's drawing: each point in its exact pixel (no splat reaches a neighbour), 30-bit positions
SURFACE_SETTINGS = {"size_mode": "fixed", "point_size": 1, "adaptive_precision": False}
PREVIEW_COLORMAP = "rdbu"  # diverging, white at 0: red where ground was cut, blue where it was filled
PREVIEW_PERCENTILE = 98.0  # of |dz|: the preview's default range (a few outliers do not wash it out)


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
        """Compared pixels that moved by more than ``min_change`` and than the heights' ``resolution``."""
        return self.compared & (np.abs(np.where(self.compared, self.dz, 0.0)) > max(self.min_change, self.resolution))

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
            raise InputError(f"change: the preview's range must be a number > 0 (a height difference), got {limit!r}")
        image = ramp(self.dz, -limit, limit, colormap_table(PREVIEW_COLORMAP)).view(np.uint8).reshape(*self.dz.shape, 4)
        image[~self.compared] = 0
        return image

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
    across, up = units.get("horizontal"), units.get("vertical")
    length = across["symbol"] if across and across["metres"] is not None else None
    height = up["symbol"] if up and up["metres"] is not None else length
    if length is None:
        return {"length": "units", "area": "square units", "volume": "cubic units"}
    return {"length": length, "area": f"{length}²", "volume": f"{length}³" if height == length else f"{length}²·{height}"}


def survey_label(source) -> str:
    """How messages name a survey: its path(s) as given, or its cloud's name."""
    if isinstance(source, PointCloud):
        return source.name
    paths = [source] if isinstance(source, (str, os.PathLike)) else list(source)
    return ", ".join(map(str, paths[:3])) + (f" and {len(paths) - 3} more" if len(paths) > 3 else "")


def read_survey(source, filters: dict, where: str = "change") -> PointCloud:
    """``source`` (paths as ``gigapoint.open`` takes them, or a PointCloud) as one PointCloud of
    the points the filters keep (only those read from files); ``where``: the operation messages name."""
    if isinstance(source, PointCloud):
        keep = point_filter(**filters, where=where)
        if keep is None:
            return source
        kept = list(keep.apply(source.chunks(), source.name))
        keep.check_passed(source.name)
        return build_cloud(kept, name=source.name, colors="rgba")
    from .. import open as open_points

    cloud = open_points(source, **filters)
    if not isinstance(cloud, PointCloud):  # an octree draws a level of detail, not every point
        raise InputError(f"{survey_label(source)}: an LOD octree; {where} draws a surface of every point: give the point files")
    return cloud


def check_crs(before: PointCloud, after: PointCloud, labels: tuple[str, str]) -> str | None:
    """The CRS both surveys are in (one naming none takes the other's); a one-line InputError
    naming both where they name different ones: nothing is reprojected, their pixels would not
    be the same ground."""
    crs = [cloud_crs(before), cloud_crs(after)]
    if all(crs) and crs_identity(crs[0]) != crs_identity(crs[1]):
        raise InputError(
            f"{labels[0]} is in {crs_name(crs[0])}, {labels[1]} in {crs_name(crs[1])}: change compares two surveys in one CRS; reproject one first"
        )
    return crs[0] or crs[1]


def surface(cloud, camera: Camera, fill_nodata=None) -> np.ndarray:
    """(H, W) float32 heights of ``cloud``'s highest point in each of ``camera``'s pixels (NaN:
    none); ``fill_nodata`` "all" or N: holes filled (raster_fill.fill_heights)."""
    heights = camera.heights(render_frame(cloud, camera, RenderSettings().replace(**SURFACE_SETTINGS)).depth)
    return heights if fill_nodata is None else fill_heights(heights, None if fill_nodata == "all" else fill_nodata)


def change(before, after, gsd, classes=None, drop_classes=None, clip=None, fill_nodata=None, min_change=0.0) -> Change:
    """The change from survey ``before`` to survey ``after`` (each paths as ``gigapoint.open``
    takes them: a file, a folder, a glob pattern, a list; or a PointCloud), as two surface models
    on one grid of ``gsd`` units a pixel over the union of their bounds (``Change``: ``dz``,
    ``cut``, ``fill``, ``net``, ``area_compared``, ``area_changed``, ``preview()``).

    ``classes``/``drop_classes``/``clip``: only those points read of both (``classes=[2]``:
    ground against ground); ``fill_nodata``: "all" or N pixels, each surface's holes filled
    linearly inside its footprint first (needs scipy); ``min_change``: pixels that moved by no
    more are left out of the volumes and the changed area. Surveys that name different CRSs, or
    that share no pixel, are one-line InputErrors."""
    if not (is_real(gsd) and gsd > 0):
        raise InputError(f"change: gsd must be a number > 0 (cloud units per pixel), got {gsd!r}")
    if not (is_real(min_change) and min_change >= 0):
        raise InputError(f"change: min_change must be a number >= 0 (a height difference), got {min_change!r}")
    if fill_nodata is not None and fill_nodata != "all":
        check_max_distance("change: fill_nodata", fill_nodata)
    filters = {"classes": classes, "drop_classes": drop_classes, "clip": clip}
    point_filter(**filters, where="change")  # bad values told before anything is read
    labels = (survey_label(before), survey_label(after))
    clouds = [read_survey(before, filters), read_survey(after, filters)]
    crs = check_crs(*clouds, labels)
    lows, highs = zip(*(c.bounds for c in clouds))
    try:
        camera = Camera.top_down((np.minimum(*lows), np.maximum(*highs)), gsd)  # one grid, one eye: pixel to pixel
    except CameraError as exc:  # the grid spans both: name them (a huge survey beside a tiny one said neither)
        raise CameraError(f"{labels[0]} and {labels[1]}: {exc}") from None
    heights = [surface(c, camera, fill_nodata) for c in clouds]
    units = cloud_units(clouds[0]) if cloud_crs(clouds[0]) else cloud_units(clouds[1])
    result = Change(*heights, camera=camera, gsd=float(gsd), crs=crs, units=units, min_change=float(min_change))
    if not result.compared.any():
        raise InputError(f"{labels[0]} and {labels[1]}: no {gsd:g}-unit pixel holds points of both: the surveys do not overlap")
    return result


__all__ = ["Change", "change", "unit_names"]
