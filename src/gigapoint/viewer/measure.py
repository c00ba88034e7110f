"""The viewer's measuring tool: a polyline through picked points, its lengths (closed: a
polygon's area and perimeter; volume_tool.py its stockpile volume), and its drawing.

The session keeps the points in world coordinates (as the pick gives them: a file's points at
its scale) and draws the polyline into each frame's image before it is encoded, projected with
the camera that frame was drawn with, so the lines sit exactly on the points as the view moves.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from ..io import crs_units
from ..io.crs import angular_across
from ..io.polygon import crossing_problem
from ..survey.volume import ring_area

MAX_POINTS = 1000
COLOR = (255, 214, 0)  # yellow, with a black edge so it reads on any ground
LINE_RADIUS = 1  # pixels either side of a segment's centre: 3 px wide
POINT_RADIUS = 3  # a point is a 7 x 7 square


def summary(points, units: dict | None = None, closed: bool = False) -> dict:
    """The lengths of the polyline through ``points``: per segment its 3D length, its
    horizontal (xy) length and its height difference (z, signed: up is positive); the total
    of each (the total height difference is the last point's z minus the first's).

    ``closed`` (3 points or more): the polyline closed into a polygon, its last segment back to
    the first point; ``area`` is then its horizontal area (shoelace, in the horizontal unit
    squared) and ``perimeter`` its horizontal length (None both where open). A closed polygon
    whose edges cross (a bow tie) has no area: the shoelace's would be wrong, and gp.volume's
    pixels inside (the even-odd rule) another shape; ``crossing`` then says so (None otherwise),
    the area None, and volume_tool refuses it.

    ``units`` (crs_units of the cloud's CRS, carried in the reply): heights in another length
    unit than x and y (a compound CRS: metres, heights in US feet) count in the 3D length in
    the horizontal unit; where x and y are angles (a geographic CRS) the 3D and horizontal
    lengths and the area are None: degrees are no length."""
    units = units or crs_units(None)
    h, v = units["horizontal"], units["vertical"]
    p = np.asarray(points, np.float64).reshape(-1, 3)
    closed = bool(closed) and len(p) >= 3
    d = np.diff(np.vstack([p, p[:1]]) if closed else p, axis=0)
    z_in_xy_unit = v["metres"] / h["metres"] if h and v and h["metres"] and v["metres"] else 1.0
    horizontal, vertical = np.hypot(d[:, 0], d[:, 1]), d[:, 2]
    length = np.hypot(horizontal, vertical * z_in_xy_unit)
    angular = angular_across(units) is not None

    def lengths(a, b, c) -> dict:
        return {"length": None if angular else float(a), "horizontal": None if angular else float(b), "vertical": float(c)}

    segments = [lengths(a, b, c) for a, b, c in zip(length, horizontal, vertical)]
    total = lengths(length.sum(), horizontal.sum(), vertical.sum())
    crossing = crossing_problem(p[:, :2]) if closed else None
    polygon = closed and not angular
    return {
        "points": p.tolist(), "segments": segments, "total": total, "units": units, "closed": closed,
        "area": ring_area(p[:, :2]) if polygon and not crossing else None, "perimeter": total["horizontal"] if polygon else None,
        "crossing": crossing and f"{crossing}: no area or volume; move a point so that no two edges cross",
    }  # fmt: skip


def drawn(points, closed: bool) -> list:
    """The points of the line frames draw: a closed polygon's back to its first."""
    return [*points, *points[:1]] if closed and len(points) >= 3 else list(points)


def _clip_depth(a: np.ndarray, b: np.ndarray):
    """The part of the segment a-b (rows x', y', w, depth) in front of the camera, or None."""
    eps = 1e-6 * max(abs(a[3]), abs(b[3]), 1e-12)
    if a[3] < eps and b[3] < eps:
        return None
    if a[3] < eps or b[3] < eps:  # homogeneous coordinates interpolate linearly before the divide
        t = (eps - a[3]) / (b[3] - a[3])
        cut = a + t * (b - a)
        a, b = (cut, b) if a[3] < eps else (a, cut)
    return a[:2] / a[2], b[:2] / b[2]


def _clip_rect(a: np.ndarray, b: np.ndarray, lo: float, hi: np.ndarray):
    """Liang-Barsky: the part of the 2D segment a-b inside [lo, hi] per axis, or None (a point
    just in front of the eye projects millions of pixels away: only what is seen is sampled)."""
    t0, t1, d = 0.0, 1.0, b - a
    for k in range(2):
        for p, q in ((-d[k], a[k] - lo), (d[k], hi[k] - a[k])):
            if p == 0:
                if q < 0:
                    return None
            elif p < 0:
                t0 = max(t0, q / p)
            else:
                t1 = min(t1, q / p)
    return None if t0 > t1 else (a + t0 * d, a + t1 * d)


def _stamp(out: np.ndarray, xs: np.ndarray, ys: np.ndarray, radius: int, color) -> None:
    """Squares of side 2 * radius + 1 around pixels (xs, ys), in ``color``; what falls off the image is dropped."""
    off = np.arange(-radius, radius + 1)
    cx, cy = np.floor(xs).astype(np.int64), np.floor(ys).astype(np.int64)  # pixel x covers [x, x + 1)
    X, Y = (a.ravel() for a in np.broadcast_arrays(cx[:, None, None] + off[None, None, :], cy[:, None, None] + off[None, :, None]))
    h, w = out.shape[:2]
    keep = (X >= 0) & (X < w) & (Y >= 0) & (Y < h)
    out[Y[keep], X[keep]] = np.array(color, out.dtype)[: out.shape[2]]


def draw(image: np.ndarray, camera, points, line_color=COLOR) -> np.ndarray:
    """A copy of ``image`` (drawn with ``camera``) with the polyline through the world
    ``points`` drawn over it in ``line_color`` (the section tool's line has its own); what lies
    behind the camera is cut off."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    if len(p) == 0:
        return image
    out = image.copy()
    color = (*line_color, 255)
    q = np.column_stack([p, np.ones(len(p))]) @ camera.screen_rows().T  # (x', y', w, depth) per point
    h, w = out.shape[:2]
    pad = POINT_RADIUS + 2
    lines = []
    for a, b in itertools.pairwise(q):
        seen = _clip_depth(a, b)
        seen = seen and _clip_rect(*seen, -pad, np.array([w + pad, h + pad], np.float64))
        if seen:
            n = math.ceil(np.abs(seen[1] - seen[0]).max()) + 1
            lines.append(np.linspace(seen[0], seen[1], n))
    front = q[q[:, 3] > 0]
    ends = front[:, :2] / front[:, 2:3]
    ends = ends[np.all(np.abs(ends) < 1e7, axis=1)]  # (one far off the view draws nothing)
    line = np.concatenate(lines) if lines else np.zeros((0, 2))
    for grow, c in ((1, (0, 0, 0, 255)), (0, color)):  # the black edge first, then the colour over it
        _stamp(out, line[:, 0], line[:, 1], LINE_RADIUS + grow, c)
        _stamp(out, ends[:, 0], ends[:, 1], POINT_RADIUS + grow, c)
    return out
