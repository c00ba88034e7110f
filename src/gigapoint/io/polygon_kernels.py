"""io/polygon.py's numba kernels: which points lie in a clip polygon, which boxes meet it. Apart
from polygon.py so that checking ``--clip-polygon`` (before anything is read) imports no numba.

A point is inside a polygon when a ray from it to +x crosses an odd number of the edges of its
rings (even-odd: its holes need no case of their own), and inside the clip polygon when inside
any of its polygons (their union: two overlapping Features of a FeatureCollection keep their
overlap, which even-odd over all their rings left out). Edges are bucketed by y
(``edge_buckets``): a point tests only the edges of its bucket, not all of them (a 10 000-vertex
site boundary: a few edges a point).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

#: Buckets hold at most this many edge entries an edge, on average (an edge spanning many
#: buckets is in each: a long thin polygon's two long edges would fill every bucket otherwise)
ENTRIES_PER_EDGE = 8


def edge_buckets(edges: np.ndarray, y_lo: float, y_hi: float) -> tuple[np.ndarray, np.ndarray]:
    """(starts, members): the edges ((k, 4) rows x1, y1, x2, y2) of each of ``n`` equal bands of
    y from ``y_lo`` to ``y_hi``, CSR-style (bucket b's edges: ``members[starts[b]:starts[b + 1]]``).
    As many bands as edges, fewer where edges spanning many would pass ``ENTRIES_PER_EDGE``."""
    k = len(edges)
    ys = np.sort(edges[:, [1, 3]], axis=1)
    n = max(1, k)
    while True:
        first, last = bucket_of(ys[:, 0], y_lo, y_hi, n), bucket_of(ys[:, 1], y_lo, y_hi, n)
        spans = last - first + 1
        if n == 1 or spans.sum() <= ENTRIES_PER_EDGE * k:
            break
        n = max(1, n // 2)
    starts = np.concatenate([[0], _edge_counts(first, last, n).cumsum()])
    members = np.empty(starts[-1], np.int64)
    _fill_buckets(first, last, starts, members)
    return starts, members


def bucket_of(y, y_lo: float, y_hi: float, n: int) -> np.ndarray:
    """The band (0..n-1) of each ``y``; the same arithmetic for edges and points, so an edge
    ending on a band's border is in the band a point on that border is."""
    height = (y_hi - y_lo) / n if y_hi > y_lo else 1.0
    return np.clip(np.floor((np.asarray(y, np.float64) - y_lo) / height), 0, n - 1).astype(np.int64)


@njit(cache=True)
def _edge_counts(first, last, n):
    counts = np.zeros(n, np.int64)
    for e in range(first.shape[0]):
        for b in range(first[e], last[e] + 1):
            counts[b] += 1
    return counts


@njit(cache=True)
def _fill_buckets(first, last, starts, members):
    fill = starts[:-1].copy()
    for e in range(first.shape[0]):
        for b in range(first[e], last[e] + 1):
            members[fill[b]] = e
            fill[b] += 1


@njit(inline="always")
def _on_edge(px, py, x1, y1, x2, y2):
    """Whether (px, py) lies exactly on the segment (x1, y1)-(x2, y2)."""
    if px < min(x1, x2) or px > max(x1, x2) or py < min(y1, y2) or py > max(y1, y2):
        return False
    return (x2 - x1) * (py - y1) == (y2 - y1) * (px - x1)


@njit(parallel=True, cache=True)
def points_inside(xy, edges, owners, box, y_lo, height, starts, members, inside):
    """``inside[i]``: whether point ``xy[i]`` lies in one of the polygons of ``edges`` (even-odd
    over each polygon's rings, ``owners[e]`` the polygon of edge e, non-decreasing; a point
    exactly on an edge is inside; NaN positions outside). ``box``: the polygons' (xmin, ymin,
    xmax, ymax), tested first; the y bands of ``edge_buckets`` (``y_lo`` and each band's
    ``height``) pick the edges a point tests."""
    n_bands = starts.shape[0] - 1
    for i in prange(xy.shape[0]):
        px, py = xy[i, 0], xy[i, 1]
        if not (px >= box[0] and px <= box[2] and py >= box[1] and py <= box[3]):  # (NaN: outside)
            inside[i] = False
            continue
        band = min(max(int(np.floor((py - y_lo) / height)), 0), n_bands - 1)
        odd = False
        owner = -1
        for j in range(starts[band], starts[band + 1]):
            # a band lists its edges in ascending order (_fill_buckets), so each polygon's come
            # together: the parity of one polygon is final where the next one's edges start
            if owners[members[j]] != owner:
                if odd:
                    break
                owner = owners[members[j]]
            x1, y1, x2, y2 = edges[members[j], 0], edges[members[j], 1], edges[members[j], 2], edges[members[j], 3]
            if _on_edge(px, py, x1, y1, x2, y2):
                odd = True
                break
            if (y1 > py) != (y2 > py) and px < x1 + (py - y1) * (x2 - x1) / (y2 - y1):
                odd = not odd
        inside[i] = odd


@njit(cache=True)
def _segment_meets_box(x1, y1, x2, y2, lx, ly, hx, hy):
    """Whether the segment (x1, y1)-(x2, y2) has a point in the box lx..hx, ly..hy (bounds
    included): the segment clipped to the box's slabs (Liang-Barsky) leaves some of it."""
    t0, t1 = 0.0, 1.0
    for d, p, lo, hi in ((x2 - x1, x1, lx, hx), (y2 - y1, y1, ly, hy)):
        if d == 0.0:
            if p < lo or p > hi:
                return False
            continue
        a, b = (lo - p) / d, (hi - p) / d
        if a > b:
            a, b = b, a
        t0, t1 = max(t0, a), min(t1, b)
        if t0 > t1:
            return False
    return True


@njit(cache=True)
def boxes_crossed(lo, hi, edges):
    """Which boxes (x and y of ``lo``..``hi``, (k, >=2) arrays) some edge passes through."""
    crossed = np.zeros(lo.shape[0], np.bool_)
    for b in range(lo.shape[0]):
        for e in range(edges.shape[0]):
            if _segment_meets_box(edges[e, 0], edges[e, 1], edges[e, 2], edges[e, 3], lo[b, 0], lo[b, 1], hi[b, 0], hi[b, 1]):
                crossed[b] = True
                break
    return crossed
