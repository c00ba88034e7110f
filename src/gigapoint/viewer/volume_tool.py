"""The viewer's stockpile volume: ``gigapoint.volume`` (survey/volume.py) inside the measuring
tool's closed polygon, its toe, of the cloud the viewer shows.

The session computes it off the render loop, as the section tool computes its section
(``Session._compute_volume``'s thread): the points of the polygon's box are read first without
the render lock (a cloud in memory filtered; an LOD octree's nodes that meet the box, down to the
levels the grid needs, as ``gp.volume`` reads an octree: lod/query.py, survey/change.py's
SURFACE_SPACING), then ``gp.volume`` draws its surface model of them under the lock (the renderer's
scratch buffers are shared with the frames'). Classes hidden in the Classes panel are left out:
the volume is of what the view shows.

A box holding more than MAX_POINTS points (a polygon drawn round much of a large cloud in memory;
an octree's levels the grid needs rarely hold as many) is thinned to every k-th point as it is read (``section_tool.every_kth``, the section tool's cap: at
most MAX_POINTS held at once), the grid then no finer than the thinned points' spacing, and the result's
``note`` says so. A polygon crossing itself is refused (measure.summary's ``crossing``).
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np

from ..core.chunk import PointChunk
from ..core.cloud import PointCloud, build_cloud
from ..errors import GigapointError, InputError, count_text
from ..io.filters import PointFilter, point_filter
from ..io.polygon import no_area_problem
from ..lod.query import is_octree, points_meeting
from ..lod.reader import open_octree
from ..lod.voxel_octree import VoxelOctree
from ..survey.change import SURFACE_SPACING, unit_names
from ..survey.volume import BASES, MARGIN_PIXELS, Volume
from . import protocol as P
from .section_tool import MAX_POINTS as SECTION_MAX_POINTS
from .section_tool import every_kth, own_reader_source

MAX_POINTS = SECTION_MAX_POINTS  # a polygon's box holding more is read thinned to every k-th point
GRID_PIXELS = 500  # the grid offered first: the polygon's larger side this many pixels across
MAX_GRID_PIXELS = 4096  # a finer gsd asked for is refused (the grid's memory, the TIN's time)
POLYGON = "the measured polygon"  # how gp.volume's messages name it


def parse(msg: dict) -> dict:
    """The checked values of a volume message: ``base`` ("plane", "lowest" or an elevation) and ``gsd`` (> 0); those given."""
    out = {}
    if "base" in msg:
        base = msg["base"]
        if isinstance(base, str) and base not in BASES:
            raise P.ProtocolError(f"volume: base must be 'plane', 'lowest' or an elevation (a number), got {base[:20]!r}")
        out["base"] = base if isinstance(base, str) else P.number(msg, "base", -P.MAX_ABS_COORD, P.MAX_ABS_COORD)
    if "gsd" in msg:
        gsd = P.number(msg, "gsd", 0, P.MAX_ABS_COORD)
        if gsd <= 0:
            raise P.ProtocolError("volume: gsd must be above 0")
        out["gsd"] = gsd
    return out


def side(points) -> float:
    """The polygon's larger horizontal side."""
    xy = np.asarray(points, np.float64)[:, :2]
    return float((xy.max(axis=0) - xy.min(axis=0)).max())


def point_spacing(bounds, n_points: int) -> float:
    """The cloud's mean horizontal point spacing s, from its box and its point count: each point
    the centre of an s x s cell, the box grown by half a cell each side holds the n cells,
    (w + s)(h + s) = n s^2. The box alone runs through the outer points' centres: a k x k grid's
    holds (k - 1)^2 cells, not k^2 (a 10 x 10 grid 1 apart read 0.9: a grid on which 19 % of
    the pixels held no point); this is exact on a regular grid and a line's w / (n - 1). Gaps make it larger: a
    coarser grid, the safe side. 0 for fewer than 2 points or one spot."""
    lo, hi = (np.asarray(b, np.float64) for b in bounds)
    w, h = float(hi[0] - lo[0]), float(hi[1] - lo[1])
    if n_points < 2 or w + h <= 0:
        return 0.0
    # (n - 1) s^2 - (w + h) s - w h = 0: its positive root
    return ((w + h) + math.sqrt((w + h) ** 2 + 4 * (n_points - 1) * w * h)) / (2 * (n_points - 1))


def default_gsd(points, spacing: float) -> tuple[float, str]:
    """(the grid offered first, the line that says why): the polygon's larger side GRID_PIXELS
    pixels across, but no finer than the points' ``spacing`` (gp.volume reads two pixels beyond
    the toe: a finer grid finds no point there, and the toe no height to lay the base on); to 2
    significant digits."""
    across = side(points) / GRID_PIXELS
    if across >= spacing:
        gsd = float(f"{across:.2g}")
        return gsd, f"a grid of {gsd:g}: the polygon about {GRID_PIXELS} pixels across"
    gsd = float(f"{spacing:.2g}")
    return gsd, f"a grid of {gsd:g}, the points' mean spacing: the polygon {side(points) / gsd:,.0f} pixels across"


def check_gsd(points, gsd: float) -> None:
    """A ProtocolError where the polygon has no area, or where ``gsd`` makes it more than
    MAX_GRID_PIXELS pixels across."""
    no_area = no_area_problem(points)  # (gp.volume's check, said as the viewer's error: of two points it said its clip_polygon's repr)
    if no_area:
        raise P.ProtocolError(f"volume: {no_area}")
    across = side(points) / gsd
    if across > MAX_GRID_PIXELS:
        raise P.ProtocolError(f"volume: a gsd of {gsd:g} makes the polygon {count_text(across)} pixels across, over {MAX_GRID_PIXELS:,}: give {side(points) / MAX_GRID_PIXELS:.2g} or more")


def toe(points) -> dict:
    """The closed polygon as a GeoJSON geometry (``gp.volume``'s clip_polygon), named POLYGON in messages."""
    return {"type": "Polygon", "coordinates": [[p[:2] for p in [*points, points[0]]]], "source": POLYGON}


def points_in_box(cloud, points, gsd: float, drop_classes, limit: int) -> tuple[PointCloud, int, int]:
    """(the points of ``cloud``, what the viewer shows, in the box ``gp.volume`` reads around the
    polygon, but those of ``drop_classes``: at most ``limit``, every k-th where there are more;
    the points in the box; k). A cloud in memory's, an octree's nodes meeting the box down to the
    levels a ``gsd`` grid needs (a COPC file or EPT dataset through a reader of its own); a
    one-line GigapointError for any other cloud."""
    xy = np.asarray(points, np.float64)[:, :2]
    margin = MARGIN_PIXELS * gsd
    box = [*(xy.min(axis=0) - margin), *(xy.max(axis=0) + margin)]
    keep = point_filter(drop_classes=list(drop_classes) or None, clip=box, where="volume")
    kept, seen, step = every_kth(_kept_chunks(cloud, keep, SURFACE_SPACING * gsd), limit)  # (never the whole box at once)
    if not kept:
        (x0, y0, x1, y1) = box
        raise InputError(f"{POLYGON}: no point of {cloud.name} lies in its box x {x0:.6g}..{x1:.6g}, y {y0:.6g}..{y1:.6g}")
    return build_cloud(kept, name=cloud.name, colors="rgba"), seen, step


def _kept_chunks(cloud, keep: PointFilter, max_spacing: float) -> Iterator[PointChunk]:
    """The points of ``cloud`` that ``keep`` keeps, a chunk (an octree's: a node, down to the level
    whose points are at most ``max_spacing`` apart) at a time."""
    if isinstance(cloud, PointCloud):
        yield from keep.apply(cloud.chunks(), cloud.name)
    elif isinstance(cloud, VoxelOctree):  # a reader of its own: the frames' reads change its pages and nodes as they go
        own = open_octree(own_reader_source(cloud))
        try:
            yield from keep.apply(points_meeting(own, keep.meets, max_spacing), cloud.name)
        finally:
            own.close()
    elif is_octree(cloud):
        yield from keep.apply(points_meeting(cloud, keep.meets, max_spacing), cloud.name)
    else:
        raise GigapointError(f"{cloud.name}: volumes need the points in memory or an LOD octree; this cloud is neither (view the point files instead)")


def thinned_grid(points, box: PointCloud, seen: int, step: int, gsd: float, gsd_note: str) -> tuple[float, str, str]:
    """(the grid, the line that says why, the note) for the volume of ``box``, 1 point in
    ``step`` of the ``seen`` in the polygon's box (``points_in_box``): where points were left out,
    a grid finer than those read coarsened to their spacing (``default_gsd``), and a note that
    says so ("" where none was left out)."""
    if step == 1:
        return gsd, gsd_note, ""
    spacing = point_spacing(box.bounds, box.n_points)
    if gsd < spacing:
        gsd, gsd_note = default_gsd(points, spacing)
    return gsd, gsd_note, f"on thinned points: 1 in {step} of the {seen:,} in the polygon's box (at most {MAX_POINTS:,} kept); draw a smaller polygon for all"


def summary(measured: Volume, units: dict, gsd_note: str, note: str, warnings: list[str]) -> dict:
    """The pile's figures as the panel shows them (``Pile.summary``), in the cloud's ``units``
    (its CRS's: the points read from an octree's nodes name none); ``note``: thinned points
    (``thinned_grid``'s; "" none); ``warnings``: what reading and measuring them warned of (a
    toe beyond the data: why its pixels are empty and how to mend it)."""
    (pile,) = measured.piles
    return {**pile.summary(), "gsd": measured.gsd, "gsd_note": gsd_note, "note": note, "warnings": warnings, "units": unit_names(units)}
