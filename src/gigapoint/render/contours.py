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

``draw_contours`` draws them onto the orthophoto of the same grid: thin dark lines, index
contours twice as wide, anti-aliased by drawing at ``SUPERSAMPLE`` times the size with Pillow's
ImageDraw and averaging back, so each pixel is darkened by the share of it a line covers.

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
from ..errors import GigapointError, InputError, count_or_inf, count_text, is_real
from ..io import horizontal_epsg

INDEX_EVERY = 5  # every 5th line an index contour
MAX_LEVELS = 1000  # more lines than anyone can read on a map; a typo in the interval, most often
LINE_RGB = (48, 32, 16)  # a dark brown, as topographic maps draw contours: it reads on grass, roofs and roads
LINE_PIXELS, INDEX_LINE_PIXELS = 1, 2  # widths on the image
SUPERSAMPLE = 4  # quarter-pixel anti-aliasing (even: the lines' widths in the mask are even, see draw_contours)
STRIP_PIXELS = 1 << 20  # image pixels drawn at a time: the supersampled strip's mask is 16 MB, whatever the image's size


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


def check_base(where: str, base) -> float:
    """``base`` as a float, or a one-line InputError unless it is a finite number."""
    if not is_real(base):
        raise InputError(f"{where}: the contour base must be a finite number, got {base!r}")
    return float(base)


def contour_levels(z_min: float, z_max: float, interval: float, base: float = 0.0, where: str = "contour_lines", unit: str = "") -> np.ndarray:
    """The whole steps k (int64) whose levels ``base + k * interval`` lie in ``z_min..z_max``;
    more than MAX_LEVELS a one-line InputError (``unit``: the heights' unit symbol, for it)."""
    count = count_or_inf(lambda: math.floor((z_max - base) / interval) - math.ceil((z_min - base) / interval) + 1)
    if count > MAX_LEVELS:
        raise InputError(
            f"{where}: interval {interval:g}{unit} gives {count_text(count)} levels over {z_max - z_min:g}{unit}; give a larger one (at most {MAX_LEVELS:,} levels)"
        )
    first = math.ceil((z_min - base) / interval)
    return np.arange(first, first + count, dtype=np.int64)


def contour_lines(heights, world_file, interval, base=0.0, where: str = "contour_lines", unit: str = "") -> list[ContourLine]:
    """The contour lines of the (H, W) ``heights`` (NaN: no data; lines never cross it) every
    ``interval`` from ``base``, in world coordinates through ``world_file`` (the six numbers of
    ``Camera.world_file``: pixel centres), lowest level first. ``where`` and ``unit`` name the
    caller and the heights' unit in the errors. Needs contourpy."""
    interval = check_interval(where, interval)
    base = check_base(where, base)
    heights = np.asarray(heights, np.float64)
    if heights.ndim != 2:
        raise InputError(f"{where}: takes an (H, W) array of heights, got shape {heights.shape}")
    if len(world_file) != 6 or not all(is_real(v) for v in world_file):
        raise InputError(f"{where}: world_file must be six finite numbers (Camera.world_file), got {world_file!r}")
    require_contourpy(where)
    valid = ~np.isnan(heights)
    if valid.sum() < 2 or min(heights.shape) < 2:  # no square of data to trace
        return []
    steps = contour_levels(float(heights[valid].min()), float(heights[valid].max()), interval, base, where, unit)
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


def draw_contours(image, lines: list[ContourLine], world_file) -> np.ndarray:
    """A copy of the (H, W, 4) uint8 ``image`` (the orthophoto whose pixel centres ``world_file``,
    ``Camera.world_file``'s six numbers, places) with ``lines`` drawn on it (``LINE_RGB``, index
    contours ``INDEX_LINE_PIXELS`` wide, others ``LINE_PIXELS``), anti-aliased (``draw_lines``)."""
    widths = [INDEX_LINE_PIXELS if line.index else LINE_PIXELS for line in lines]
    return draw_lines(image, [line.xy for line in lines], widths, world_file)


def draw_lines(image, polylines: list[np.ndarray], pixel_widths: list[int], world_file, rgb=LINE_RGB) -> np.ndarray:
    """A copy of the (H, W, 4) uint8 ``image`` (whose pixel centres ``world_file`` places) with
    ``polylines`` ((N, 2) world x, y each; a ring closed by repeating its first vertex) drawn on it
    in ``rgb``, each ``pixel_widths`` wide, anti-aliased; an empty pixel a line covers becomes
    opaque by its share. Contour lines, a stockpile's toe (survey/volume.py)."""
    from PIL import Image, ImageDraw

    image = np.array(image, np.uint8)
    height, width = image.shape[:2]
    a, d, b, e, c, f = (float(v) for v in world_file)
    to_pixel = np.linalg.inv([[a, b], [d, e]])  # world x, y less the first pixel centre -> col, row
    # vertices in the supersampled mask, where Pillow's line of an even width w at the whole
    # number y fills rows y - w/2 .. y + w/2 - 1, centred on y when row i spans [i, i + 1): the
    # pixel centre (col, row) is there at ((col + 0.5) S, (row + 0.5) S), to a sample (Pillow draws
    # from whole numbers: rounded here, half to even, rather than as Pillow would)
    paths = [np.rint(((np.asarray(xy, np.float64) - (c, f)) @ to_pixel.T + 0.5) * SUPERSAMPLE) for xy in polylines]
    widths = [pixels * SUPERSAMPLE for pixels in pixel_widths]
    strip_rows = max(1, STRIP_PIXELS // width)
    for top in range(0, height, strip_rows):
        rows = min(strip_rows, height - top)
        y0 = top * SUPERSAMPLE
        mask = Image.new("L", (width * SUPERSAMPLE, rows * SUPERSAMPLE))
        draw = ImageDraw.Draw(mask)
        for path, line_width in zip(paths, widths):
            reach = line_width  # a line's edge or round joint lies within its width of its vertices
            if path[:, 1].max() + reach < y0 or path[:, 1].min() - reach > y0 + rows * SUPERSAMPLE:
                continue  # none of it in this strip
            draw.line([(x, y - y0) for x, y in path.tolist()], fill=255, width=line_width, joint="curve")
        cover = np.asarray(mask.resize((width, rows), Image.Resampling.BOX), np.float32)[..., None] / 255  # each pixel's share under a line
        strip = image[top : top + rows].astype(np.float32)
        strip[..., :3] += (np.array(rgb, np.float32) - strip[..., :3]) * cover
        strip[..., 3:] += (255 - strip[..., 3:]) * cover
        image[top : top + rows] = np.rint(strip).astype(np.uint8)
    return image
