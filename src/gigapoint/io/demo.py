"""A deterministic procedural demo scene of any size: terrain, roads, water, buildings, trees.

Every point is a pure function of its index (a counter-based hash), so the scene is the
same whatever the thread count, any sub-range can be generated alone, and generation runs
at memory speed in parallel. The geometry does not depend on the point count: more points
only mean a denser sampling of the same 1 km x 1 km town.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numba import njit, prange

from ..core import pages

SCENE_SIZE = 1000.0  # metres
MAX_DEMO_POINTS = 4_000_000_000  # the largest scene `gigapoint demo` and `bench` make
_LOT = 100.0  # roads every 100 m
_ROAD_HALF_WIDTH = 6.0
_N_LOTS = int(SCENE_SIZE / _LOT)

# ASPRS classes used by the scene
CLASS_GROUND, CLASS_VEGETATION, CLASS_BUILDING, CLASS_WATER, CLASS_ROAD = 2, 5, 6, 9, 11


@njit(inline="always")
def _mix(z):
    """splitmix64 finaliser: a well-distributed 64-bit hash."""
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@njit(inline="always")
def _uniform(seed, i, k):
    """The k-th uniform [0, 1) number of point i."""
    h = _mix(np.uint64(seed) * np.uint64(0x9E3779B97F4A7C15) + np.uint64(i) * np.uint64(8) + np.uint64(k))
    return float(h >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@njit(inline="always")
def _height(x, y):
    """Terrain height: rolling hills and a river valley along a sine."""
    h = 12.0 * math.sin(x * 0.004) * math.cos(y * 0.005) + 4.0 * math.sin(x * 0.013 + y * 0.011)
    h += 1.5 * math.sin(x * 0.041) * math.sin(y * 0.037)
    river = y - (300.0 + 80.0 * math.sin(x * 0.006))
    h -= 10.0 * math.exp(-(river * river) / 1800.0)
    return h


_GRID = 512  # terrain height samples per side (2 m spacing), bilinearly interpolated
_N_TREES = 1500


@njit(cache=True)
def _height_grid():
    g = np.empty((_GRID + 1, _GRID + 1))
    step = SCENE_SIZE / _GRID
    for a in range(_GRID + 1):
        for b in range(_GRID + 1):
            g[a, b] = _height(a * step, b * step)
    return g


@njit(inline="always")
def _grid_height(grid, x, y):
    fx = min(max(x / SCENE_SIZE * _GRID, 0.0), _GRID - 1e-9)
    fy = min(max(y / SCENE_SIZE * _GRID, 0.0), _GRID - 1e-9)
    ix = int(fx)
    iy = int(fy)
    tx = fx - ix
    ty = fy - iy
    h0 = grid[ix, iy] * (1 - tx) + grid[ix + 1, iy] * tx
    h1 = grid[ix, iy + 1] * (1 - tx) + grid[ix + 1, iy + 1] * tx
    return h0 * (1 - ty) + h1 * ty


@njit(inline="always")
def _mod(a, m):
    """a mod m for a >= 0, as Python's ``a % m`` but without its libm ``fmod`` call (which
    took ~15 % of the generator's time); the fix-up covers a quotient rounded up to the next
    integer, so the result stays in [0, m)."""
    r = a - m * math.floor(a / m)
    return r + m if r < 0.0 else r


@njit(inline="always")
def _is_road(x, y):
    dx = abs(_mod(x, _LOT) - _LOT * 0.5)
    dy = abs(_mod(y, _LOT) - _LOT * 0.5)
    return dx > _LOT * 0.5 - _ROAD_HALF_WIDTH or dy > _LOT * 0.5 - _ROAD_HALF_WIDTH


@njit(cache=True)
def _lot_table(seed, grid):
    """Per lot: has_building, width, depth, height, base height, gabled, style."""
    lots = np.zeros((_N_LOTS, _N_LOTS, 7))
    for lx in range(_N_LOTS):
        for ly in range(_N_LOTS):
            lot = lx * 131 + ly
            cx = (lx + 0.5) * _LOT
            cy = (ly + 0.5) * _LOT
            river = cy - (300.0 + 80.0 * math.sin(cx * 0.006))  # lots by the river are parks
            lots[lx, ly, 0] = 1.0 if abs(river) >= 90.0 and _uniform(seed, lot, 7) < 0.8 else 0.0
            lots[lx, ly, 1] = 25.0 + 45.0 * _uniform(seed, lot, 1)
            lots[lx, ly, 2] = 25.0 + 45.0 * _uniform(seed, lot, 2)
            lots[lx, ly, 3] = 8.0 + 40.0 * _uniform(seed, lot, 3) ** 2
            lots[lx, ly, 4] = _grid_height(grid, cx, cy)
            lots[lx, ly, 5] = 1.0 if _uniform(seed, lot, 4) < 0.5 else 0.0
            lots[lx, ly, 6] = _uniform(seed, lot, 5)
    return lots


@njit(cache=True)
def _tree_table(seed, grid, lots):
    """Per tree: x, y, base height, height, crown radius."""
    trees = np.empty((_N_TREES, 5))
    for t in range(_N_TREES):
        tx = _uniform(seed, t, 61) * SCENE_SIZE
        ty = _uniform(seed, t, 62) * SCENE_SIZE
        lx = min(int(tx / _LOT), _N_LOTS - 1)
        ly = min(int(ty / _LOT), _N_LOTS - 1)
        if lots[lx, ly, 0] > 0 and _uniform(seed, t, 63) < 0.85:
            # trees in built lots stand along the lot border
            tx = (lx + 0.12) * _LOT if _uniform(seed, t, 64) < 0.5 else (lx + 0.88) * _LOT
        base = _grid_height(grid, tx, ty)
        if base < -5.0:  # no trees in the river
            ty = min(ty + 120.0, SCENE_SIZE)
            base = _grid_height(grid, tx, ty)
        trees[t, 0] = tx
        trees[t, 1] = ty
        trees[t, 2] = base
        trees[t, 3] = 6.0 + 14.0 * _uniform(seed, t, 65)
        trees[t, 4] = 2.0 + 4.0 * _uniform(seed, t, 66)
    return trees


@njit(inline="always")
def _terrain_xyn(seed, i):
    """A terrain point's position on the ground plane and its colour noise."""
    return _uniform(seed, i, 1) * SCENE_SIZE, _uniform(seed, i, 2) * SCENE_SIZE, _uniform(seed, i, 3)


@njit(inline="always")
def _store_point(out, rgba, cls, inten, j, x, y, z, r, g, b, c, intensity):
    """Point j's position, opaque colour, class and intensity: terrain's, buildings' and trees' stores."""
    out[j, 0], out[j, 1], out[j, 2] = x, y, z
    rgba[j, 0], rgba[j, 1], rgba[j, 2], rgba[j, 3] = r, g, b, 255
    cls[j] = c
    inten[j] = intensity


@njit(inline="always")
def _store_terrain(x, y, z, n, out, rgba, cls, inten, j):
    """Water, road or ground at height z: the point's colour and class, then its stores."""
    if z < -5.0:  # water surface
        z = -5.0
        r, g, b, c = 40 + 20 * n, 90 + 30 * n, 160 + 40 * n, CLASS_WATER
    elif _is_road(x, y):
        r = g = b = 95 + 30 * n
        c = CLASS_ROAD
    else:
        t = min(max((z + 5.0) / 25.0, 0.0), 1.0)
        r, g, b, c = 70 + 90 * t + 30 * n, 120 + 40 * t + 30 * n, 50 + 20 * t + 20 * n, CLASS_GROUND
    _store_point(out, rgba, cls, inten, j, x, y, z, r, g, b, c, 20000 + 20000 * n)


@njit(inline="always")
def _terrain_point(seed, i, grid, out, rgba, cls, inten, j):
    x, y, n = _terrain_xyn(seed, i)
    _store_terrain(x, y, _grid_height(grid, x, y), n, out, rgba, cls, inten, j)


@njit(inline="always")
def _building_point(seed, i, grid, lots, out, rgba, cls, inten, j):
    lx = 0
    ly = 0
    found = False
    for k in range(16):  # pick a lot that carries a building (bounded rejection)
        lx = int(_uniform(seed, i, 10 + k) * _N_LOTS)
        ly = int(_uniform(seed, i, 30 + k) * _N_LOTS)
        if lots[lx, ly, 0] > 0:
            found = True
            break
    if not found:
        _terrain_point(seed, i, grid, out, rgba, cls, inten, j)
        return
    w, d, h, base, gabled, style = lots[lx, ly, 1], lots[lx, ly, 2], lots[lx, ly, 3], lots[lx, ly, 4], lots[lx, ly, 5], lots[lx, ly, 6]
    cx = (lx + 0.5) * _LOT
    cy = (ly + 0.5) * _LOT
    u = _uniform(seed, i, 50)
    v = _uniform(seed, i, 51)
    n = _uniform(seed, i, 52)
    wall_area = 2.0 * (w + d) * h
    roof_area = w * d
    if _uniform(seed, i, 53) * (wall_area + roof_area) < wall_area:
        p = u * 2.0 * (w + d)
        if p < w:
            x, y = cx - w / 2 + p, cy - d / 2
        elif p < w + d:
            x, y = cx + w / 2, cy - d / 2 + (p - w)
        elif p < 2 * w + d:
            x, y = cx + w / 2 - (p - w - d), cy + d / 2
        else:
            x, y = cx - w / 2, cy + d / 2 - (p - 2 * w - d)
        z = base + v * h
        # windows: darker cells in a regular pattern
        window = _mod(p, 4.0) < 2.0 and _mod(z - base, 3.5) < 1.8 and (z - base) > 1.0
        if style < 0.33:
            r, g, b = 200, 190, 170
        elif style < 0.66:
            r, g, b = 170, 80, 60
        else:
            r, g, b = 220, 220, 225
        if window:
            r, g, b = 50, 70, 90
        r, g, b = r * (0.85 + 0.15 * n), g * (0.85 + 0.15 * n), b * (0.85 + 0.15 * n)
    else:
        x = cx - w / 2 + u * w
        y = cy - d / 2 + v * d
        z = base + h
        if gabled > 0:
            z += 0.35 * min(w, d) * (1.0 - abs(y - cy) / (d / 2)) * 0.5
            r, g, b = 150 + 40 * n, 50 + 20 * n, 40 + 15 * n
        else:
            r, g, b = 90 + 25 * n, 90 + 25 * n, 95 + 25 * n
    _store_point(out, rgba, cls, inten, j, x, y, z, r, g, b, CLASS_BUILDING, 30000 + 15000 * n)


@njit(inline="always")
def _tree_point(seed, i, trees, out, rgba, cls, inten, j):
    t = int(_uniform(seed, i, 60) * _N_TREES)
    tx, ty, base, height, radius = trees[t, 0], trees[t, 1], trees[t, 2], trees[t, 3], trees[t, 4]
    n = _uniform(seed, i, 67)
    a = _uniform(seed, i, 71) * 2 * math.pi
    if _uniform(seed, i, 68) < 0.08:  # trunk
        x = tx + 0.3 * math.cos(a)
        y = ty + 0.3 * math.sin(a)
        z = base + _uniform(seed, i, 70) * height * 0.5
        r, g, b = 90 + 20 * n, 60 + 15 * n, 35 + 10 * n
    else:  # crown: points in an ellipsoid shell
        cz = 2.0 * _uniform(seed, i, 72) - 1.0
        s = math.sqrt(1.0 - cz * cz)
        rr = radius * (0.7 + 0.3 * _uniform(seed, i, 73))
        x = tx + rr * s * math.cos(a)
        y = ty + rr * s * math.sin(a)
        z = base + height * 0.55 + cz * height * 0.45
        shade = 0.6 + 0.4 * (cz + 1.0) * 0.5
        r, g, b = (30 + 40 * n) * shade, (90 + 80 * n) * shade, (25 + 30 * n) * shade
    _store_point(out, rgba, cls, inten, j, x, y, z, r, g, b, CLASS_VEGETATION, 8000 + 12000 * n)


_BLOCK = 4096  # points a thread generates at a time, grouped by kind


@njit(inline="always")
def _kind(seed, i):
    """0 terrain (55 %), 1 building (25 %), 2 tree (20 %)."""
    u = _uniform(seed, i, 0)
    return np.uint8(0) if u < 0.55 else (np.uint8(1) if u < 0.80 else np.uint8(2))


@njit(parallel=True, cache=True)
def _generate(start, n, seed, grid, lots, trees, xyz, rgba, cls, inten):
    """Points start..start+n into the arrays, a block of _BLOCK at a time.

    Each block is generated kind by kind (a list of its terrain points, then buildings, then
    trees), so the kind branch does not mispredict on every other point. Terrain points go
    in three loops: positions, heights, then colours and stores. The height grid (2 MB) is
    read in a loop of independent lookups, whose latency overlaps; inside the whole point
    it held up everything after it. 1.15-1.64x (5 M points, 1 and 2 threads), the same
    points bit for bit."""
    for block in prange((n + _BLOCK - 1) // _BLOCK):
        j0 = block * _BLOCK
        m = min(_BLOCK, n - j0)
        kinds = np.empty(m, np.uint8)
        for k in range(m):
            kinds[k] = _kind(seed, start + j0 + k)
        idx = np.empty(m, np.int64)
        xs = np.empty(m)
        ys = np.empty(m)
        zs = np.empty(m)
        ns = np.empty(m)
        for kind in range(3):
            c = 0
            for k in range(m):  # the block's points of this kind, branch-free
                idx[c] = j0 + k
                c += kinds[k] == kind
            if kind == 0:
                for q in range(c):
                    xs[q], ys[q], ns[q] = _terrain_xyn(seed, start + idx[q])
                for q in range(c):
                    zs[q] = _grid_height(grid, xs[q], ys[q])
                for q in range(c):
                    _store_terrain(xs[q], ys[q], zs[q], ns[q], xyz, rgba, cls, inten, idx[q])
            elif kind == 1:
                for q in range(c):
                    _building_point(seed, start + idx[q], grid, lots, xyz, rgba, cls, inten, idx[q])
            else:
                for q in range(c):
                    _tree_point(seed, start + idx[q], trees, xyz, rgba, cls, inten, idx[q])


_PAGE = 4096


@njit(parallel=True, cache=True)
def _prefault(buffer):
    """Write one byte of every page of ``buffer`` (u8, flat) in parallel, before generating.

    At 100 M points the four new output arrays are 3.1 GB. Their first-touch faults,
    taken inside the (then per-point) ``_generate``, made it 1.1-1.4x slower (median 1.18,
    8 alternating pairs) than faulting them here first; at 20 M there was no difference."""
    for k in prange((buffer.shape[0] + _PAGE - 1) // _PAGE):
        buffer[k * _PAGE] = 0


@functools.lru_cache(maxsize=4)
def _scene_tables(seed: int):
    grid = _height_grid()
    lots = _lot_table(seed, grid)
    return grid, lots, _tree_table(seed, grid, lots)


def check_seed(where: str, seed) -> int:
    """``seed`` as an int the generator's kernels take (int64), else a one-line InputError: a
    string was numba's TypingError, 2**64 an internal error from the command line."""
    from ..errors import check_whole

    return check_whole(where, "seed", seed, -(2**63) + 1, 2**63 - 1)


def demo_arrays(n_points: int, seed: int = 0, start: int = 0, offset=(0.0, 0.0, 0.0)):
    """Points ``start .. start+n_points`` of the demo scene: (xyz, rgba, attributes)."""
    if n_points < 0:
        raise ValueError(f"n_points must be >= 0, got {n_points}")
    xyz = pages.empty((n_points, 3), np.float64)  # written once: small pages (core/pages.py)
    rgba = pages.empty((n_points, 4), np.uint8)
    cls = pages.empty(n_points, np.uint8)
    inten = pages.empty(n_points, np.uint16)
    for array in (xyz, rgba, cls, inten):
        _prefault(array.reshape(-1).view(np.uint8))
    _generate(start, n_points, seed, *_scene_tables(seed), xyz, rgba, cls, inten)
    if any(offset):
        xyz += np.asarray(offset, np.float64)
    return xyz, rgba, {"classification": cls, "intensity": inten}


def round_to_grid(xyz: np.ndarray, scale: float) -> None:
    """xyz = np.round(xyz / scale) * scale, in place: the positions a LAS file at ``scale`` holds."""
    np.divide(xyz, scale, out=xyz)
    np.round(xyz, out=xyz)
    np.multiply(xyz, scale, out=xyz)


def demo_chunks(n_points: int, seed: int = 0, chunk_size: int = 5_000_000, offset=(0.0, 0.0, 0.0), scale: float | None = None):
    """The demo scene as a stream of PointChunks (bounded memory per chunk). ``scale``: positions
    rounded to a grid of that step (metres), and the chunks say so, as a LAS export of the town
    at that scale would (``build_cloud`` then holds it in the compact layout)."""
    from ..core.chunk import PointChunk

    for start in range(0, n_points, chunk_size):
        xyz, rgba, attrs = demo_arrays(min(chunk_size, n_points - start), seed, start, offset)
        if scale is not None:
            round_to_grid(xyz, scale)
        yield PointChunk(xyz, rgba, attrs, scale=None if scale is None else (float(scale),) * 3)
