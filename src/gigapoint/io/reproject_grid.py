"""io/reproject.py's fast path: a chunk's points moved by interpolating PROJ's transform from a grid
of control points, with a checked error bound. Apart from reproject.py so that checking
``--to-crs`` (before anything is read) imports no numba.

Point clouds cover small areas, over which a projection is smooth: the transform of a grid of
nodes over the chunk's xy box (exact, through pyproj) gives every point's by tensor-product cubic
(Lagrange, 4 x 4 nodes: error O(h^4)) interpolation. Each node is transformed at two heights
(the chunk's lowest and highest z), and a point's result is linear in z between them: that holds
z passed through (2D CRSs), a unit change, a geoid height added (a function of xy), and the small
pull of height on x and y of a datum change through geocentric coordinates.

The bound is enforced, not hoped for: the grid is accepted only where the interpolation, at every
cell's middle and every edge's middle at both heights and at every cell's middle at mid-height,
is within half the tolerance of PROJ's exact transform of those points (for a smooth function the
error of a cubic peaks near the middles; the factor 2 covers the rest). Otherwise the grid is
refined (cells halved) while its exact transforms cost at most ``EXACT_SHARE`` of the chunk's
points; a grid that never gets there, or a node or check point outside the transform's domain,
and the chunk takes the exact path (near a projection's singularity: polar to geographic)."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

#: cells along each side of the first grid tried (then 8, 16, ...): a cubic needs 3 at least
FIRST_CELLS = 4
#: the exact transforms that fitting a grid may cost, as a share of the chunk's points
EXACT_SHARE = 1 / 4
#: the check points' error must be within tolerance / this (the error between them peaks near them)
CHECK_MARGIN = 2.0


class ControlGrid:
    """Exact transforms of (n + 1) x (n + 1) nodes from (x0, y0), ``h`` apart, at heights z0 and
    z0 + dz (``low``, ``high``: (n + 1, n + 1, 3) arrays, [row (y), column (x), axis])."""

    def __init__(self, x0, y0, h, n, z0, dz, low, high):
        self.x0, self.y0, self.h, self.n, self.z0, self.dz, self.low, self.high = x0, y0, h, n, z0, dz, low, high

    def at(self, x, y, z, keep_z: bool) -> np.ndarray:
        """The interpolated transform of each point (x, y, z), n x 3; z as it is where ``keep_z``."""
        out = np.empty((len(x), 3))
        _interpolate(x, y, z, self.x0, self.y0, self.h[0], self.h[1], self.n, self.low, self.high, self.z0, self.dz, keep_z, out)
        return out


def fit(transform, lo, hi, tolerance, points: int) -> tuple[ControlGrid, bool] | None:
    """(a grid whose interpolation of ``transform`` (x, y, z arrays -> moved arrays, exact) is within
    ``tolerance`` (xy, z) over the box ``lo``..``hi`` (x, y, z), whether z passes through as it is),
    or None where none costs at most ``EXACT_SHARE`` of ``points`` exact transforms."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    z0, dz = lo[2], max(hi[2] - lo[2], 1.0)  # (flat: any second height gives the slope in z)
    spent, n = 0, FIRST_CELLS
    while True:
        nodes, checks = (n + 1) ** 2, 4 * n * n + 2 * n  # (nodes; middles at 2 heights + cell middles at mid-height)
        spent += 2 * nodes + checks
        if spent > EXACT_SHARE * points:
            return None
        h = np.maximum((hi[:2] - lo[:2]) / n, 1e-9 * np.maximum(1.0, np.abs(lo[:2])))  # (a box flat in x or y: cells of some width)
        ix, iy = np.meshgrid(np.arange(n + 1.0), np.arange(n + 1.0))
        low = _moved(transform, lo[0] + ix * h[0], lo[1] + iy * h[1], z0)
        high = _moved(transform, lo[0] + ix * h[0], lo[1] + iy * h[1], z0 + dz)
        if low is None or high is None:
            return None
        grid = ControlGrid(lo[0], lo[1], h, n, z0, dz, low.reshape(n + 1, n + 1, 3), high.reshape(n + 1, n + 1, 3))
        within = _checked(transform, grid, tolerance)
        if within is None:
            return None
        if within[0]:
            return grid, within[1]
        n *= 2


def _moved(transform, x, y, z) -> np.ndarray | None:
    """(x, y, z) moved exactly, k x 3; None where one came out not finite (outside the domain)."""
    x, y = np.ravel(x).astype(np.float64), np.ravel(y).astype(np.float64)
    z = np.broadcast_to(np.asarray(z, np.float64), x.shape).copy()
    out = np.column_stack(transform(x, y, z))
    return out if np.isfinite(out).all() else None


def _checked(transform, grid: ControlGrid, tolerance) -> tuple[bool, bool] | None:
    """(whether ``grid`` interpolates within the tolerance at its check points, whether z passes
    through as it is there and at the nodes), None where a check point is outside the domain."""
    n, h = grid.n, grid.h
    # every half-step point of the grid that is no node: cell middles, horizontal and vertical edge middles
    hx, hy = np.meshgrid(np.arange(2 * n + 1) / 2, np.arange(2 * n + 1) / 2)
    mids = ((2 * hx) % 2 == 1) | ((2 * hy) % 2 == 1)
    x, y = grid.x0 + hx[mids] * h[0], grid.y0 + hy[mids] * h[1]
    centres = ((2 * hx) % 2 == 1) & ((2 * hy) % 2 == 1)
    cx, cy = grid.x0 + hx[centres] * h[0], grid.y0 + hy[centres] * h[1]
    xs, ys = np.concatenate([x, x, cx]), np.concatenate([y, y, cy])
    zs = np.concatenate([np.full(len(x), grid.z0), np.full(len(x), grid.z0 + grid.dz), np.full(len(cx), grid.z0 + grid.dz / 2)])
    exact = _moved(transform, xs, ys, zs)
    if exact is None:
        return None
    keep_z = bool(np.array_equal(exact[:, 2], zs) and np.array_equal(grid.low[..., 2], np.full((n + 1, n + 1), grid.z0))
                  and np.array_equal(grid.high[..., 2], np.full((n + 1, n + 1), grid.z0 + grid.dz)))  # fmt: skip
    error = np.abs(grid.at(xs, ys, zs, keep_z) - exact)
    xy_ok = error[:, :2].max() <= tolerance[0] / CHECK_MARGIN
    return bool(xy_ok and (keep_z or error[:, 2].max() <= tolerance[1] / CHECK_MARGIN)), keep_z


@njit(inline="always")
def _weights(t):
    """Lagrange weights of nodes 0, 1, 2, 3 at ``t`` (0..3)."""
    return (
        -(t - 1.0) * (t - 2.0) * (t - 3.0) / 6.0,
        t * (t - 2.0) * (t - 3.0) / 2.0,
        -t * (t - 1.0) * (t - 3.0) / 2.0,
        t * (t - 1.0) * (t - 2.0) / 6.0,
    )


@njit(inline="always")
def _stencil(u, n):
    """(the first of the 4 nodes around grid coordinate ``u``: those of its cell and one either side,
    shifted inwards at the grid's edges, ``u``'s place among them)."""
    first = min(max(int(np.floor(u)) - 1, 0), n - 3)
    return first, u - first


@njit(cache=True, parallel=True)
def _interpolate(x, y, z, x0, y0, hx, hy, n, low, high, z0, dz, keep_z, out):
    axes = 2 if keep_z else 3
    for i in prange(x.shape[0]):
        if not (np.isfinite(x[i]) and np.isfinite(y[i]) and np.isfinite(z[i])):
            out[i, 0] = out[i, 1] = out[i, 2] = np.nan
            continue
        cx, tx = _stencil((x[i] - x0) / hx, n)
        cy, ty = _stencil((y[i] - y0) / hy, n)
        wx, wy = _weights(tx), _weights(ty)
        f = (z[i] - z0) / dz
        for k in range(axes):
            a = 0.0
            b = 0.0
            for p in range(4):
                ra = 0.0
                rb = 0.0
                for q in range(4):
                    ra += wx[q] * low[cy + p, cx + q, k]
                    rb += wx[q] * high[cy + p, cx + q, k]
                a += wy[p] * ra
                b += wy[p] * rb
            out[i, k] = a + f * (b - a)
        if keep_z:
            out[i, 2] = z[i]
