"""Contour lines of a top-down heights raster (a DSM/DTM: ``Camera.heights``, NaN = no data), a
surveyor's deliverable beside the surface model, and their GeoJSON.

The marching squares are contourpy's (the engine behind matplotlib's ``contour``): a small wheel
that needs only numpy, which masks NaN heights itself, so no line is traced across a hole, and
which gives each line as one polyline, closed rings ending where they start. (scikit-image's
``find_contours`` does the same job, but pulls in a much larger package for one function.)

Lines are traced through the pixel centres (pixel (row, col) at the world file's
``(x0 + col * size, y0 - row * size)``) at ``base + k * interval`` for every k whose level lies
within the heights' range; every ``INDEX_EVERY``-th (k a multiple of it) is an index contour,
which surveyors draw heavier.

GeoJSON: a FeatureCollection of LineString features, properties ``elevation`` and ``index``,
coordinates in the cloud's CRS. RFC 7946 GeoJSON allows WGS 84 only, so the CRS goes in the
GeoJSON 2008 ``crs`` member, which GDAL (and so QGIS) read: its name is
``urn:ogc:def:crs:EPSG::n`` where the CRS's horizontal part names an EPSG code, else the WKT itself
(GDAL passes the name to OSRSetFromUserInput, which takes WKT). One file holds it all: GDAL's
GeoJSON driver reads no .prj beside the file.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..atomic import atomic_bytes
from ..errors import GigapointError, InputError, is_real
from ..io import horizontal_epsg

INDEX_EVERY = 5  # every 5th line an index contour
MAX_LEVELS = 1000  # more lines than anyone can read on a map; a typo in the interval, most often


@dataclass(frozen=True)
class ContourLine:
    """One contour line: its ``elevation``, whether it is an ``index`` contour (every
    ``INDEX_EVERY``-th level), its vertices ``xy`` ((N, 2) float64 world x, y; a closed ring's
    last vertex is its first)."""

    elevation: float
    index: bool
    xy: np.ndarray

    @property
    def closed(self) -> bool:
        return len(self.xy) > 2 and bool(np.array_equal(self.xy[0], self.xy[-1]))


def require_contourpy(what: str = "contour lines") -> None:
    """A one-line error naming the extra to install where contourpy is missing."""
    try:
        import contourpy  # noqa: F401
    except ImportError:
        raise GigapointError(f"{what} needs contourpy (pip install 'gigapoint[quality]')") from None


def check_interval(where: str, interval) -> float:
    """``interval`` as a float, or a one-line InputError unless it is a finite number > 0."""
    if not (is_real(interval) and interval > 0):
        raise InputError(f"{where}: the contour interval must be a number > 0, got {interval!r}")
    return float(interval)


def contour_levels(z_min: float, z_max: float, interval: float, base: float = 0.0, where: str = "contour_lines", unit: str = "") -> np.ndarray:
    """The whole steps k (int64) whose levels ``base + k * interval`` lie in ``z_min..z_max``;
    more than MAX_LEVELS a one-line InputError (``unit``: the heights' unit symbol, for it)."""
    first, last = math.ceil((z_min - base) / interval), math.floor((z_max - base) / interval)
    count = last - first + 1
    if count > MAX_LEVELS:
        raise InputError(
            f"{where}: interval {interval:g}{unit} gives {count:,} levels over {z_max - z_min:g}{unit}; give a larger one (at most {MAX_LEVELS:,} levels)"
        )
    return np.arange(first, last + 1, dtype=np.int64)


def contour_lines(heights, world_file, interval, base=0.0, where: str = "contour_lines", unit: str = "") -> list[ContourLine]:
    """The contour lines of the (H, W) ``heights`` (NaN: no data; lines never cross it) every
    ``interval`` from ``base``, in world coordinates through ``world_file`` (the six numbers of
    ``Camera.world_file``: pixel centres), lowest level first. ``where`` and ``unit`` name the
    caller and the heights' unit in the errors. Needs contourpy."""
    interval = check_interval(where, interval)
    if not is_real(base):
        raise InputError(f"{where}: the contour base must be a finite number, got {base!r}")
    heights = np.asarray(heights, np.float64)
    if heights.ndim != 2:
        raise InputError(f"{where}: takes an (H, W) array of heights, got shape {heights.shape}")
    if len(world_file) != 6 or not all(is_real(v) for v in world_file):
        raise InputError(f"{where}: world_file must be six finite numbers (Camera.world_file), got {world_file!r}")
    require_contourpy(where)
    valid = ~np.isnan(heights)
    if valid.sum() < 2 or min(heights.shape) < 2:  # no square of data to trace
        return []
    steps = contour_levels(float(heights[valid].min()), float(heights[valid].max()), interval, float(base), where, unit)
    import contourpy

    # (x, y omitted: contourpy's x is the column, y the row; NaN heights are masked)
    tracer = contourpy.contour_generator(z=heights, line_type=contourpy.LineType.Separate)
    a, d, b, e, c, f = (float(v) for v in world_file)  # ESRI order: x = a col + b row + c, y = d col + e row + f
    lines = []
    for k in steps:
        level = float(f"{base + k * interval:.12g}")  # (0.30000000000000004 read back as 0.3)
        for cols_rows in tracer.lines(base + k * interval):
            col, row = cols_rows[:, 0], cols_rows[:, 1]
            xy = np.column_stack((a * col + b * row + c, d * col + e * row + f))
            lines.append(ContourLine(level, bool(k % INDEX_EVERY == 0), xy))
    return lines


def crs_member(crs: str | None, wkt: str | None) -> dict | None:
    """The GeoJSON 2008 ``crs`` member naming ``crs`` (its horizontal part's EPSG URN, else its
    ``wkt``); None where neither is known."""
    code = horizontal_epsg(crs)
    name = f"urn:ogc:def:crs:EPSG::{code}" if code is not None else wkt
    return {"type": "name", "properties": {"name": name}} if name else None


def contours_geojson(lines: list[ContourLine], crs: str | None = None, wkt: str | None = None, digits: int = 3) -> dict:
    """``lines`` as a GeoJSON FeatureCollection of LineStrings (properties ``elevation``,
    ``index``), coordinates rounded to ``digits`` decimals, with a ``crs`` member (``crs_member``) where known."""
    features = [
        {
            "type": "Feature",
            "properties": {"elevation": line.elevation, "index": line.index},
            "geometry": {"type": "LineString", "coordinates": np.round(line.xy, digits).tolist()},
        }
        for line in lines
    ]
    collection = {"type": "FeatureCollection", "features": features}
    member = crs_member(crs, wkt)
    if member is not None:
        collection["crs"] = member
    return collection


def coordinate_digits(pixel_size: float) -> int:
    """Decimals that keep coordinates to a thousandth of ``pixel_size``: finer is noise, and bytes."""
    return max(0, 3 - math.floor(math.log10(pixel_size)))


def write_contours(path, lines: list[ContourLine], crs: str | None = None, wkt: str | None = None, pixel_size: float = 1.0) -> Path:
    """``lines`` as the GeoJSON file ``path`` (``contours_geojson``), atomically."""
    collection = contours_geojson(lines, crs, wkt, coordinate_digits(pixel_size))
    return atomic_bytes(path, json.dumps(collection, separators=(",", ":")).encode())
