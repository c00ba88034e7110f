"""Stockpile volume from one survey (a quarry's, an aggregate yard's, a landfill's): CloudCompare's
2.5D volume against a base, Propeller's and Pix4D's volume tool.

Each pile is a polygon, its boundary (the toe) drawn on the ground; a GeoJSON Feature's
MultiPolygon is one pile in parts (a stockpile a road runs through is one stock item): its
volume the sum of its parts', each part measured against its own base (below). A toe whose
GeoJSON names a CRS is moved into the survey's first, as a read filter moves its polygon
(``_in_survey_crs``); one in longitude/latitude naming none over a projected survey is refused. The survey is
drawn as a surface model (``change.surface``: the highest point in each pixel) on a grid of ``gsd``
over the polygons' box, a little beyond it, so that the pixels along the toe hold the ground on
both sides. A pixel is the pile's when its centre lies inside the polygon (polygon.py's
even-odd rule: holes left out). Holes in the surface (pixels with no point) are filled by a TIN
by default (render/raster_fill.py): a pile's volume must not drop where points are missing; the
share filled is reported, as is the share left empty (beyond the data's footprint, or
``fill_nodata=None``), which then counts no volume: a pile more than EMPTY_WARNING_SHARE empty is
warned of (its volume is short by those pixels; a TIN does not extrapolate beyond the data).

The base is the surface the pile stands on:

* ``"plane"`` (the default): the least-squares plane through the surface's heights sampled every
  half pixel along the polygon's rings (Pix4D's "triangulated"/"best fit" base); it follows a
  pile standing on a slope;
* ``"lowest"``: flat, at the lowest of those heights (a pile on a slope then counts the wedge
  of ground between the slope and that level too);
* a number: flat, at that elevation (a pad's design height).

Volumes are (surface - base) summed over the pile's pixels, times a pixel's area: ``fill`` where
the surface is above the base (the stockpile; Pix4D calls it "cut", the material to take away),
``cut`` where it is below (a pit, or a toe drawn outside the pile), ``net`` = fill - cut.

A pile in parts lays a base under each part from that part's own toe, not one through the
toes of all: the parts may stand on ground at different heights (either side of a road, on two
benches), and a plane through all of them would tilt across the gap between; so a pile's volume
is what its parts measured one by one add up to, and grouping them changes only how it is reported.

``Volume.above_base`` is what the volumes sum: each pixel's height above its pile's base;
``write_geotiff`` writes it, ``write_preview`` a colour image of it with the toes drawn."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..core.cloud import PointCloud
from ..errors import EmptyCloudError, InputError, check_switch, is_real, number_text, warn
from ..io._base import headers_once
from ..io.crs import refuse_angles
from ..io.filters import may_move, placed_in, placed_over, point_filter
from ..io.polygon import UNNAMED_GEOMETRY, ClipPolygon, check_simple, clip_polygon_of, polygon_text
from ..lod.query import is_octree
from ..lod.reader import cloud_crs_units
from ..lod.store import OctreeCloud
from ..lod.voxel_octree import VoxelOctree
from ..render import Camera
from ..render.colors import ramp_image
from ..render.contours import draw_lines
from ..render.georef import write_map
from ..render.raster_fill import check_max_distance, fill_heights
from .change import open_survey, surface, survey_label, unit_names
from .raster_grid import RasterGrid

#: how far (in pixels) the grid reaches beyond the polygons: the toe's pixels are then whole
MARGIN_PIXELS = 2
#: how often (in pixels) the toe is sampled along the polygon's rings for the base
TOE_STEP_PIXELS = 0.5
#: a pile whose pixels are empty (no height, no volume) more than this share of them is warned of:
#: its volume is short by their share of it, which the figures report but a script may not read
EMPTY_WARNING_SHARE = 0.01
BASES = ("plane", "lowest")
PREVIEW_COLORMAP = "viridis"  # sequential: dark purple at the base, yellow at the highest pile's top
TOE_RGB, TOE_PIXELS = (220, 20, 60), 2  # the toes in the preview: crimson reads against viridis' purple to yellow and on white


@dataclass(frozen=True)
class Pile:
    """One pile's figures, in the survey's units: ``fill`` (above the base), ``cut`` (below it),
    ``area`` (its pixels' area: the footprint drawn), ``polygon_area`` (the polygon's own, holes
    left out), ``highest`` (x, y, z of its highest pixel), ``height`` (the most the surface rises
    above the base), ``base`` (what it was: type, z: the base's mean height under the pile, and
    for a plane its slope (dz/dx, dz/dy) and the toe's rms distance from it), ``filled`` and
    ``empty``: shares of its pixels filled by interpolation and left without a height. A pile in
    parts (a Feature's MultiPolygon) sums its parts; its ``base`` lists each part's in ``parts``."""

    name: str
    fill: float
    cut: float
    area: float
    polygon_area: float
    highest: tuple[float, float, float]
    height: float
    base: dict
    filled: float
    empty: float
    pixels: int

    @property
    def net(self) -> float:
        return self.fill - self.cut

    def summary(self) -> dict:
        return {
            "name": self.name, "fill": self.fill, "cut": self.cut, "net": self.net, "area": self.area,
            "polygon_area": self.polygon_area, "highest": list(self.highest), "height": self.height, "base": self.base,
            "filled": self.filled, "empty": self.empty, "pixels": self.pixels,
        }  # fmt: skip


@dataclass(frozen=True)
class Volume:
    """The piles of one survey (``piles``, in the polygons' order) measured on one grid:
    ``heights`` (H, W) float32 the surface model inside the piles (holes filled), NaN outside,
    drawn through ``camera`` (``Camera.top_down``), pixels ``gsd`` a side; ``above_base`` (H, W)
    float32 the surface's height above its pile's base there (negative below it), NaN outside the
    piles and where the surface is empty: the volumes are its sums times a pixel's area; ``toes``
    the piles' polygons (ClipPolygon.polygons); ``base`` as asked; ``crs`` and ``units``
    (io.crs_units) the survey's."""

    piles: tuple[Pile, ...]
    heights: np.ndarray
    above_base: np.ndarray
    toes: list
    camera: Camera
    gsd: float
    base: str | float
    crs: str | None
    units: dict

    @property
    def fill(self) -> float:
        return math.fsum(p.fill for p in self.piles)

    @property
    def cut(self) -> float:
        return math.fsum(p.cut for p in self.piles)

    @property
    def net(self) -> float:
        return self.fill - self.cut

    @property
    def area(self) -> float:
        return math.fsum(p.area for p in self.piles)

    def summary(self) -> dict:
        """The figures as ``gigapoint volume --json`` gives them: each pile's and the total."""
        return {
            "piles": [p.summary() for p in self.piles],
            "total": {"fill": self.fill, "cut": self.cut, "net": self.net, "area": self.area},
            "base": self.base, "gsd": self.gsd, "units": unit_names(self.units), "crs": self.crs,
        }  # fmt: skip

    def write_dsm(self, path, overwrite: bool = False) -> list[Path]:
        """``heights`` as ``path``, a float32 GeoTIFF (.tif, NaN nodata) with its world file and
        .prj, as ``gigapoint volume --dsm-out PATH`` writes it. Returns the paths."""
        check_switch("overwrite", overwrite, "volume")
        return write_map(self.camera, self.crs, self.units, [(path, self.heights)], overwrite)

    def write_geotiff(self, path, overwrite: bool = False) -> list[Path]:
        """``above_base`` as ``path``, a float32 GeoTIFF (.tif, NaN nodata) with its world file and
        .prj, as ``gigapoint volume -o PATH`` writes it, all or none; an existing file is replaced
        only with ``overwrite=True``. Returns the paths."""
        check_switch("overwrite", overwrite, "volume")
        return write_map(self.camera, self.crs, self.units, [(path, self.above_base)], overwrite)

    def preview(self) -> np.ndarray:
        """(H, W, 4) uint8 image of ``above_base`` on a sequential colormap (``PREVIEW_COLORMAP``)
        from 0 (the base) to the highest pile's ``height`` (below the base: the colour of 0),
        transparent outside the piles and where the surface is empty, each toe's rings drawn over
        it (``TOE_RGB``)."""
        top = max(pile.height for pile in self.piles)
        image = ramp_image(self.above_base, 0.0, top, PREVIEW_COLORMAP)
        rings = [np.vstack([ring, ring[:1]]) for polygon in self.toes for ring in polygon]  # (closed)
        return draw_lines(image, rings, [TOE_PIXELS] * len(rings), self.camera.world_file(), TOE_RGB)

    def write_preview(self, path, overwrite: bool = False) -> list[Path]:
        """``preview()`` as the image ``path`` (.png, ...; a .tif is a GeoTIFF), with its world file
        and .prj (one already beside it holding this CRS is kept), as ``gigapoint volume --preview
        PATH`` writes them. Returns the paths."""
        check_switch("overwrite", overwrite, "volume")
        return write_map(self.camera, self.crs, self.units, [(path, self.preview())], overwrite)


def _check_base(base) -> str | float:
    if isinstance(base, str) and base in BASES:
        return base
    if is_real(base):
        return float(base)
    raise InputError(f"volume: base must be 'plane', 'lowest' or an elevation (a number), got {number_text(base)}")


def _toe(rings: list[np.ndarray], step: float) -> np.ndarray:
    """(k, 2) positions every ``step`` at most along ``rings`` (each closed back to its first vertex)."""
    points = []
    for ring in rings:
        for start, end in zip(ring, np.roll(ring, -1, axis=0)):
            n = max(1, math.ceil(math.dist(start, end) / step))
            points.append(start + np.arange(n)[:, None] / n * (end - start))
    return np.concatenate(points)


def ring_area(ring: np.ndarray) -> float:
    """The area of the ring of (k, 2) vertices ``ring`` (the shoelace formula; without its closing vertex)."""
    x, y = ring[:, 0] - ring[0, 0], ring[:, 1] - ring[0, 1]  # (from a vertex: no cancellation at UTM sizes)
    return abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))) / 2


def _base_heights(base, toe_xy: np.ndarray, toe_z: np.ndarray, xy: np.ndarray, where: str) -> tuple[np.ndarray, dict]:
    """The base's heights at ``xy`` and what it is (``Pile.base``), from the toe's heights ``toe_z`` at ``toe_xy``."""
    if not isinstance(base, str):
        return np.full(len(xy), base), {"type": "elevation", "z": base}
    if base == "lowest":
        lowest = float(toe_z.min())
        return np.full(len(xy), lowest), {"type": "lowest", "z": lowest}
    centre = toe_xy.mean(axis=0)  # (fitted about the toe's centre: UTM-sized x and y lose no digits)
    design = np.column_stack([toe_xy - centre, np.ones(len(toe_xy))])
    (slope_x, slope_y, z0), _, rank, _ = np.linalg.lstsq(design, toe_z, rcond=None)
    if rank < 3:
        raise InputError(f"{where}: the heights along its boundary lie on one line; no plane fits them (try --base lowest)")
    rms = float(np.sqrt(np.mean((design @ (slope_x, slope_y, z0) - toe_z) ** 2)))
    heights = (xy - centre) @ (slope_x, slope_y) + z0
    return heights, {"type": "plane", "slope": [float(slope_x), float(slope_y)], "boundary_rms": rms}


class _Part(NamedTuple):
    """One polygon of a pile measured: its pixels (``rows``, ``cols``), the surface's height
    ``above`` its base there (float64, NaN: empty) and the ``base`` described (``Pile.base``)."""

    rows: np.ndarray
    cols: np.ndarray
    above: np.ndarray
    base: dict


def _part(rings, inside: np.ndarray, drawn: np.ndarray, heights: np.ndarray, grid: RasterGrid, base, where: str, label: str) -> _Part:
    """The polygon ``rings`` of a pile (its pixels ``inside``) against its own base, from the
    surface ``drawn`` and ``heights`` (its holes filled); ``where``: how messages name it."""
    if not inside.any():
        raise InputError(f"{where}: no pixel centre of the {grid.cell:g} grid lies inside it: give a finer gsd")
    if np.isnan(drawn[inside]).all():
        raise InputError(f"{where}: no point of {label} lies inside it")
    toe_xy = _toe(rings, TOE_STEP_PIXELS * grid.cell)
    toe_z = heights[grid.cells_of(toe_xy)]
    known_toe = ~np.isnan(toe_z)
    if known_toe.sum() < 3 and not is_real(base):
        raise InputError(
            f"{where}: the surface has no height along its boundary to lay a base on: no point near the toe (it runs off the data, or the "
            f"points lie further apart than the {grid.cell:g} grid: a coarser gsd); or give a base elevation (--base Z)"
        )
    rows, cols = np.nonzero(inside)
    base_z, description = _base_heights(base, toe_xy[known_toe], toe_z[known_toe].astype(np.float64), grid.centres(rows, cols), where)
    return _Part(rows, cols, heights[rows, cols].astype(np.float64) - base_z, {**description, "z": float(base_z.mean())})


def _pile(parts: list, insides: list, name: str, drawn: np.ndarray, heights: np.ndarray, grid: RasterGrid, base, where: str, label: str):
    """The pile ``name`` made of the polygons ``parts`` (each a list of rings; their pixels
    ``insides``), each part against its own base; ``where``: how messages name it. Returns the
    Pile, and its pixels (rows, cols) with their heights above the base (``Volume.above_base``)."""
    measured = [
        _part(rings, inside, drawn, heights, grid, base, f"{where}, part {k + 1}" if len(parts) > 1 else where, label)
        for k, (rings, inside) in enumerate(zip(parts, insides))
    ]
    rows, cols, above = (np.concatenate(arrays) for arrays in zip(*((part.rows, part.cols, part.above) for part in measured)))
    pixels = len(rows)
    known = ~np.isnan(above)
    cell_area = grid.cell * grid.cell
    highest = drawn[rows, cols]
    top = int(np.nanargmax(np.where(np.isnan(highest), -np.inf, highest)))
    base_z = math.fsum(part.base["z"] * len(part.rows) for part in measured) / pixels  # the mean under all its pixels
    pile = Pile(
        name=name,
        fill=float(above[above > 0].sum(dtype=np.float64)) * cell_area,
        cut=abs(float(above[above < 0].sum(dtype=np.float64))) * cell_area,  # (abs: no -0.0)
        area=pixels * cell_area,
        polygon_area=sum(ring_area(outline) - sum(map(ring_area, holes)) for outline, *holes in parts),
        highest=(*map(float, grid.centres(rows[top : top + 1], cols[top : top + 1])[0]), float(highest[top])),
        height=float(above[known].max()),
        base=measured[0].base if len(parts) == 1 else {"type": measured[0].base["type"], "z": base_z, "parts": [part.base for part in measured]},
        filled=float((np.isnan(highest) & known).sum()) / pixels,
        empty=float((~known).sum()) / pixels,
        pixels=pixels,
    )
    return pile, rows, cols, above


def _warn_if_empty(pile: Pile, where: str, fill_nodata) -> None:
    """A warning where more than EMPTY_WARNING_SHARE of ``pile``'s pixels are empty: they count
    no volume (``Pile.empty``), so the fill is short; where from and how to mend it."""
    if pile.empty <= EMPTY_WARNING_SHARE:
        return
    unfilled = "" if fill_nodata == "all" else f", or holes are left unfilled (fill_nodata={fill_nodata}; 'all' fills them)"
    warn(
        f"{where}: {pile.empty:.1%} of the pile's pixels hold no height and count no volume (its figures are short by them): "
        f"the toe runs beyond the data's footprint (draw it inside the points){unfilled}"
    )


def _pile_parts(polygon: ClipPolygon) -> list[tuple[str, list[int]]]:
    """Each pile's name and its polygons (indices into ``polygon.polygons``), in their order: the
    polygons of one GeoJSON Feature (its MultiPolygon's parts) one pile, each other polygon one.
    A pile is named by its Feature's ``name`` ('pile N' without one); a name several piles share
    is numbered 'A (1)', 'A (2)'."""
    members: dict = {}
    for i, feature in enumerate(polygon.features):
        members.setdefault(("feature", feature) if feature is not None else ("polygon", i), []).append(i)
    groups = list(members.values())
    names = [polygon.names[group[0]] or f"pile {n + 1}" for n, group in enumerate(groups)]
    shared = {name for name, count in Counter(names).items() if count > 1}
    seen: Counter = Counter()
    numbered = []
    for name in names:
        seen[name] += 1
        numbered.append(f"{name} ({seen[name]})" if name in shared else name)
    return list(zip(numbered, groups))


def _survey_paths(source) -> list:
    """The paths of ``source`` (a path or several; a pattern matching one octree: its path)."""
    from ..io import given_paths, lone_match

    return lone_match(given_paths(source, "volume", "source"))


def _opened_octree(source):
    """The LOD octree ``source`` names (its path, or a pattern matching one) opened unread (its
    metadata; an unfinished conversion's preview, which ``open_survey`` refuses); None for any
    other source. Opened once: its CRS places the toe (``_in_survey_crs``), then its nodes are read."""
    from .. import open_for
    from ..lod import is_lod_source

    if isinstance(source, PointCloud) or is_octree(source):
        return None
    paths = _survey_paths(source)
    return open_for("volume", paths[0]) if len(paths) == 1 and is_lod_source(paths[0]) else None


def _in_survey_crs(toe: ClipPolygon, source, opened=None) -> ClipPolygon:
    """``toe`` in the survey's coordinates, as a read filter places its polygon (io/filters.py's
    ``placed_in``): moved from the CRS its GeoJSON names into the survey's (``cloud_crs``'s: that
    of its first point file naming one, or an octree's: ``opened``, where ``source`` is its path),
    refused in one line where it looks like longitude/latitude naming none over a projected
    survey (naming the toe by its source, as volume's other messages do). Only headers (or
    an octree's metadata) are read, before a point is: the toe's box bounds what is read."""
    if not may_move(toe):
        return toe
    from ..io import expand_paths

    label = survey_label(source)
    survey = source if opened is None else opened
    if not (isinstance(survey, PointCloud) or is_octree(survey)):
        return placed_over(toe, expand_paths(_survey_paths(source), where="volume"), label)
    crs, units = cloud_crs_units(survey)
    return placed_in(toe, crs, units, survey.bounds, label)


@headers_once()  # (one operation: the toe placed over the survey's headers, then its points read, each header read and each warning said once)
def volume(source, clip_polygon, gsd, base="plane", classes=None, drop_classes=None, fill_nodata="all", full=True) -> Volume:
    """The volume of each pile ``clip_polygon`` outlines (a GeoJSON or WKT file, WKT text, a GeoJSON
    geometry as a dict: polygon.py; several polygons, several piles, named by their Feature's
    ``name``; a Feature's MultiPolygon one pile in parts) in survey ``source`` (paths as ``gigapoint.open`` takes them, or a PointCloud;
    an LOD octree's path: every node near the piles read; ``full=False`` only its levels down to
    the spacing the gsd needs, as ``change.surface`` reads them: faster, and a pile's volume
    then a little low, each pixel the highest of a sample; volumes are paid by the cubic metre, so
    every point is the default), on a grid of ``gsd`` units a pixel,
    above and below ``base`` ("plane", "lowest" or an elevation).

    ``classes``/``drop_classes``: only those points read (``drop_classes=[7, 18]``: no noise);
    ``fill_nodata``: "all" (the default) every hole inside the data's footprint filled linearly
    (needs scipy), N only those within N pixels of a point, None none. Returns a ``Volume``
    (``piles``, ``fill``, ``cut``, ``net``, ``area``, ``summary()``, ``write_dsm()``,
    ``write_geotiff()``, ``write_preview()``). A GeoJSON naming another CRS than the survey's
    (a ``crs`` member) is moved into it first (pyproj). No polygon, a polygon crossing itself,
    outside the data or with no point inside are one-line InputErrors."""
    if clip_polygon is None:
        raise InputError("volume: clip_polygon is needed: the piles' boundaries (a GeoJSON or WKT polygon file, or WKT text)")
    if not (is_real(gsd) and gsd > 0):
        raise InputError(f"volume: gsd must be a number > 0 (cloud units per pixel), got {number_text(gsd)}")
    base = _check_base(base)
    check_switch("full", full, "volume")
    if fill_nodata is not None and fill_nodata != "all":
        check_max_distance("volume: fill_nodata", fill_nodata)
    unnamed = f"volume: {UNNAMED_GEOMETRY}"  # (a bare dict's name in the messages starting with it, as its ring and hole errors name it)
    if isinstance(clip_polygon, dict):  # one naming its source as it is (the viewer's "the measured polygon"), not as GeoJSON given
        label = f"volume: {clip_polygon['source']}" if isinstance(clip_polygon.get("source"), str) else unnamed
    else:
        label = f"volume: clip_polygon={polygon_text(clip_polygon)}"
    toe = clip_polygon_of(clip_polygon, label, unnamed)
    check_simple(toe, "a toe must not cross itself (its area and the pixels inside it would disagree): redraw it")
    point_filter(classes, drop_classes, where="volume")  # bad classes told before an octree is opened
    octree = _opened_octree(source)
    try:
        return _measured(toe, source, octree, gsd, base, classes, drop_classes, fill_nodata, full)
    finally:
        if isinstance(octree, VoxelOctree):  # (a COPC/EPT URL opened here: its connections)
            octree.close()


def _measured(toe: ClipPolygon, source, octree, gsd, base, classes, drop_classes, fill_nodata, full: bool) -> Volume:
    """``volume``'s figures, its arguments checked (``octree``: ``_opened_octree(source)``)."""
    toe = _in_survey_crs(toe, source, octree)  # (before its box bounds what is read)
    margin = MARGIN_PIXELS * gsd
    box = [*(toe.lo - margin), *(toe.hi + margin)]  # read-time: only the points near the piles
    filters = {"classes": classes, "drop_classes": drop_classes, "clip": box}
    keep = point_filter(**filters, where="volume")  # bad values told before anything is read
    label = survey_label(source)
    try:  # (an octree's points are read, and found missing, as its surface is drawn)
        if isinstance(octree, OctreeCloud):  # (its path's: filtered as gp.open(path, **filters) filters it, not opened again)
            octree.read_only(keep, label)
            cloud = octree
        else:  # (an opened octree takes no filter of its own: the grid's footprint bounds what is read of it)
            cloud = open_survey(source, {**filters, "clip": None} if is_octree(source) else filters, "volume")
        crs, units = cloud_crs_units(cloud)
        # (in degrees a pile's fill came out in square degrees times metres, labelled "cubic units")
        refuse_angles("volume", label, crs, units, "measuring a volume", bounds=(toe.lo, toe.hi))
        lo, hi = cloud.bounds
        camera = Camera.top_down(((box[0], box[1], lo[2]), (box[2], box[3], hi[2])), gsd)
        drawn = surface(cloud, camera, full=full)
        if np.isnan(drawn).all():  # (an octree's nodes not meeting the box are not read: none said so)
            raise EmptyCloudError(label)
    except EmptyCloudError:
        (x0, y0), (x1, y1) = toe.lo, toe.hi
        in_box = f"lies in its box x {x0:.6g}..{x1:.6g}, y {y0:.6g}..{y1:.6g}"
        if classes is None and drop_classes is None:
            raise InputError(f"{toe.named}: no point of {label} {in_box}: the polygon is outside the data") from None
        # (the class filter may have left none where the data is: "outside the data" misled)
        kept = point_filter(classes, drop_classes, where="volume").describe()
        raise InputError(f"{toe.named}: no point of {label} ({kept}) {in_box}: the class filter left none there, or the polygon is outside the data") from None
    heights = drawn if fill_nodata is None else fill_heights(drawn, None if fill_nodata == "all" else fill_nodata)
    grid = RasterGrid.of_camera(camera)
    groups = _pile_parts(toe)
    insides = [grid.centres_inside(ClipPolygon([rings], toe.source)) for rings in toe.polygons]
    above_base = np.full(grid.shape, np.nan, np.float32)
    piles = []
    for name, members in groups:
        where = f"{toe.named}: {name}" if len(groups) > 1 else toe.named
        pile, rows, cols, above = _pile([toe.polygons[i] for i in members], [insides[i] for i in members], name, drawn, heights, grid, base, where, label)
        piles.append(pile)
        _warn_if_empty(pile, where, fill_nodata)
        above_base[rows, cols] = above  # (piles that overlap: the later one's height where they do)
    dsm = np.where(np.logical_or.reduce(insides), heights, np.nan).astype(np.float32)
    return Volume(tuple(piles), dsm, above_base, toe.polygons, camera, float(gsd), base, crs, units)


__all__ = ["Pile", "Volume", "volume"]
