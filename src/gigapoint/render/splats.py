"""Point size and shape: each point covers a footprint of pixels, all at the point's own depth.

The footprint is a list of pixel offsets (dx, dy) with the smallest point size that covers
each (``need``), sorted by it, so one table serves every size up to ``point_size``:
a point of size s writes the offsets with need <= s. Squares of even size extend one
pixel more to the right/bottom; round points are discs of diameter s around the pixel.
Every footprint pixel goes through the normal depth test with the point's own key, so a
nearer small point is never hidden by a farther large one.

``size_mode='attenuated'``: the size is ``point_world_size`` metres projected at the
point's depth (perspective: scale / depth, with scale = world size x focal length in
pixels), clamped to 1 .. point_size.

``size_mode='adaptive'`` (Potree's default, and ours: ``size_mode='auto'`` without a
point_size or point_world_size): the same, with the world size the cloud's own point
spacing (``point_spacing``: each batch's points over the area of its box, the median over
the points) times ``ADAPTIVE_FILL`` times ``point_size``, clamped to 1 .. ``ADAPTIVE_MAX_PX``:
neighbouring points touch on screen, so sparse real data looks solid at every distance.
``size_mode='fixed'`` with ``point_size=1`` is the exact one-pixel render.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from ..errors import GigapointError


@functools.lru_cache(maxsize=16)
def footprint(size: int, shape: str = "square") -> np.ndarray:
    """(k, 3) int32 rows (dx, dy, need), sorted by need, for point sizes up to ``size``."""
    r = size // 2
    rows = []
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            if shape == "round":
                need = max(1, math.ceil(2.0 * math.sqrt(dx * dx + dy * dy) - 1e-9))
            else:
                nx = 2 * dx if dx > 0 else 2 * -dx + 1
                ny = 2 * dy if dy > 0 else 2 * -dy + 1
                need = max(nx, ny, 1)
            if need <= size:
                rows.append((dx, dy, need))
    rows.sort(key=lambda t: (t[2], t[1], t[0]))
    return np.array(rows, np.int32).reshape(-1, 3)


#: the ``splat`` of one-pixel points, what None stands for: footprint (dx, dy, need) of the
#: point's own pixel, size 1, no attenuation
ONE_PIXEL = (np.array([[0, 0, 1]], np.int32), np.float32(1.0), np.float32(0.0))

#: adaptive points cover this many times the point spacing: at 1 they would touch on a regular
#: grid (``point_spacing`` is its spacing); real scans are not one (lines of a scanner, overlapping
#: strips): autzen_trim's default frame covers 75 % of its footprint at 1, 88 % at 1.25, 90 % at
#: 1.4 and 91 % at 1.5 (sizes are whole pixels, so coverage moves in steps)
ADAPTIVE_FILL = 1.4
ADAPTIVE_MAX_PX = 16  # the largest adaptive point, in pixels
FLOAT32_MAX = float(np.finfo(np.float32).max)


#: ``point_spacing`` looks at up to this many batches (spread over the cloud) and this many
#: points of each (16 k points: ~2 ms whatever the cloud's size; a live cloud pays it per change)
SPACING_BATCHES = 64
SPACING_SAMPLE = 256


def point_spacing(points, step: int = 1) -> float:
    """World distance between neighbouring points of a cloud's buffers (``points.batches``, 10-bit
    ``points.low`` words), drawing every ``step``-th point: sqrt(surface area / points) per batch,
    the median over points (``batch_spacings``); 0 for a cloud without extent (a point, a line)."""
    _, spacing, drawn = batch_spacings(points, step)
    return weighted_median(spacing, drawn) if len(spacing) else 0.0


def batch_spacings(
    points, step: int = 1, batches: np.ndarray | None = None, sample: int = SPACING_SAMPLE, limit: int | None = SPACING_BATCHES
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(batch ids, spacing of each, points drawn of each) for ``point_spacing``, of up to
    ``limit`` non-empty batches spread over them (of ``batches`` only, if given; None: all).

    A batch's surface area is the voxels its points occupy (cubes of the side its box would give:
    sqrt(area of the box's two largest sides / points)) times a voxel's face, as the progressive
    octree's voxel grids count it: a box overstates the area (a Morton run's box holds more than
    the run; on autzen_trim 3.2 m against ~2 m, on a regular grid 1.2-1.4 times), the voxels do
    not (a regular grid and uniform random points within 2 %). Measured on up to ``sample``
    points of a batch (every k-th: an even thinning, whose spacing is sqrt(k) times the whole's)."""
    rec = points.batches
    counts = rec["count"].astype(np.int64)
    ids = np.flatnonzero(counts > 0) if batches is None else np.unique(np.asarray(batches, np.int64))
    ids = ids[counts[ids] > 0]
    if limit is not None and len(ids) > limit:
        ids = ids[np.linspace(0, len(ids) - 1, limit).astype(np.int64)]
    n = counts[ids]
    m = np.minimum(n, sample)
    owner = np.repeat(np.arange(len(ids)), m)
    j = np.arange(int(m.sum())) - np.repeat(np.cumsum(m) - m, m)
    idx = rec["first"][ids].astype(np.int64)[owner] + j * n[owner] // np.maximum(m[owner], 1)  # every (n/m)-th point
    low = np.asarray(points.low[idx]).astype(np.int64)
    ext = (rec["bbox_max"][ids] - rec["bbox_min"][ids]).astype(np.float64)
    q = np.stack([(low >> (10 * axis)) & 1023 for axis in range(3)], axis=1)
    starts = np.cumsum(m) - m
    spread = np.maximum.reduceat(q, starts) > np.minimum.reduceat(q, starts) if len(ids) else q[:0] > 0
    # an axis the points do not spread along has no extent, whatever the box: a compact layout's
    # box is a grid cell of >= 1024 steps (10.24 m at 1 cm), one point's too (read as its spacing)
    sides = np.sort(np.where(spread, ext, 0.0), axis=1)
    cell = np.sqrt(sides[:, 2] * sides[:, 1] / np.maximum(m, 1))
    # cells no finer than the low word's grid (1024 a side): indices below 2^11 an axis
    cell = np.where(cell > 0, np.maximum(cell, sides[:, 2] / 1024.0), np.inf)
    scale = ext / (1024.0 * cell[:, None])  # 10-bit grid units -> cells
    key = owner.astype(np.int64)
    for axis in range(3):
        key = (key << 11) | np.minimum(((q[:, axis] + 0.5) * scale[owner, axis]).astype(np.int64), 2047)
    voxels = np.bincount(np.unique(key) >> 33, minlength=len(ids)).astype(np.float64)
    drawn = np.ceil(n / max(1, step))
    return ids, np.where(np.isfinite(cell), cell, 0.0) * np.sqrt(voxels / drawn), drawn  # sqrt(voxels x cell^2 / drawn)


def finest_spacing(points, slots: np.ndarray, slot_node: np.ndarray, nodes: np.ndarray, children: np.ndarray, counts: np.ndarray,
                   gain: np.ndarray | None = None, own: np.ndarray | None = None) -> float:  # fmt: skip
    """Spacing of an octree's drawn points, for ``DrawList.spacing``. Drawn ``nodes`` (ancestors
    before descendants) have their points in batches ``slots`` (batch i: node
    ``nodes[slot_node[i]]``, all of its points); ``children`` (all nodes, 8; -1: none) and
    ``counts`` (their points) are the hierarchy. Where a node is drawn without any of its
    children it is the finest level drawn, its drawn ancestors' points there adding to its own
    (``gain``: ``union_gain`` of the hierarchy); the spacing there is its own points' area
    (``batch_spacings`` of all its points: the same whatever their order or slots) over that
    union, the median over the points. ``own``: each node's own spacing, NaN until measured,
    filled here: an octree keeps both arrays (lod/store.OctreeCloud), so a frame measures only
    the nodes it draws finest for the first time and pays a median otherwise.

    What it replaces: the spacing of every drawn node's batches alone (what a frame without
    ``DrawList.spacing`` gets) counts each level's sparse subsample, 1.5-3 times too large; the
    levels' grid spacing (the converter's cube edge / 128 / 2^level) is a bound only: data
    sparser than a level's grid fills it with every point it has."""
    gain = union_gain(children, counts) if gain is None else gain
    own = np.full(len(counts), np.nan) if own is None else own
    finest = nodes[~np.isin(children[nodes], nodes).any(axis=1)]
    finest = np.unique(finest[counts[finest] > 0])
    unknown = finest[np.isnan(own[finest])]
    if len(unknown):
        node_of_slot = nodes[slot_node]
        ids, spacing, drawn = batch_spacings(points, batches=slots[np.isin(node_of_slot, unknown)], sample=1 << 30, limit=None)
        order = np.argsort(slots, kind="stable")
        where = np.searchsorted(unknown, node_of_slot[order][np.searchsorted(slots[order], ids)])
        area = np.bincount(where, spacing * spacing * drawn, minlength=len(unknown))  # each batch's sqrt(area / points)
        total = np.bincount(where, drawn, minlength=len(unknown))
        own[unknown] = np.sqrt(np.divide(area, total, out=np.zeros(len(unknown)), where=total > 0))
    if len(finest) == 0:
        return 0.0
    g = gain[finest]
    return weighted_median(own[finest] / np.sqrt(g), counts[finest] * g)


def union_gain(children: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Per octree node n: (points of n and of its ancestors inside n's cube) / (n's own points),
    the ancestors' share estimated by the data's: a node at level L holds ``subtree[n] /
    subtree[a]`` of ancestor a's points (``subtree``: points of a node and all its descendants).
    Nodes are numbered parents first (sorted keys). 1 for an empty node."""
    n = len(counts)
    c = counts.astype(np.float64)
    parent = np.full(n, -1, np.int64)
    has = children >= 0
    parent[children[has]] = np.nonzero(has)[0]
    subtree = c.copy()
    for i in range(n - 1, 0, -1):  # children after parents: add each node into its parent
        if parent[i] >= 0:
            subtree[parent[i]] += subtree[i]
    share = np.divide(c, subtree, out=np.zeros(n), where=subtree > 0)
    acc = share.copy()
    for i in range(1, n):
        if parent[i] >= 0:
            acc[i] += acc[parent[i]]
    return np.divide(subtree * acc, c, out=np.ones(n), where=c > 0)


def weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """The median of ``values`` with each counted ``weights`` times (the median over points of a
    per-batch figure). ``weights`` > 0, not empty."""
    order = np.argsort(values, kind="stable")
    cum = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cum, cum[-1] / 2.0)])


def splat_params(settings, camera, spacing: float | None = None):
    """(footprint, size, atten) for the rasterizer: float32 size is the fixed size in pixels
    (or the clamp for attenuated points), atten the perspective scale (0: fixed size).
    ``spacing``: the cloud's ``point_spacing`` (needed by ``size_mode='adaptive'``)."""
    size = np.float32(settings.point_size)
    atten = np.float32(0.0)
    mode, largest, world = settings.point_sizing, settings.point_size, settings.point_world_size
    if mode == "adaptive":
        if spacing is None:
            raise GigapointError("size_mode 'adaptive' needs the cloud's point spacing (splats.point_spacing)")
        largest, world = ADAPTIVE_MAX_PX, spacing * ADAPTIVE_FILL * settings.point_size
        size = np.float32(largest)
    if mode != "fixed":  # (this float64 operation order is the attenuated mode's since #5)
        if camera.projection == "perspective":
            # (a world size of 1e300 overflowed float32: numpy's warning; any scale that large
            # draws every point at the largest size alike)
            atten = np.float32(min(world * (camera.height / 2.0) / math.tan(math.radians(camera.fov) / 2.0), FLOAT32_MAX))
            if mode == "adaptive" and atten == 0:  # no spacing (a single point, a line): one pixel
                size = np.float32(1.0)
        else:
            size = np.float32(min(largest, max(1.0, world * camera.height / camera.ortho_height)))
    return footprint(largest, settings.point_shape), size, atten


def largest_size(splat, nearest_depth: float) -> float:
    """The largest size in pixels a point of ``splat`` gets at depths >= ``nearest_depth``."""
    _, size, atten = splat
    if atten == 0:
        return float(size)
    return float(min(size, max(np.float32(1.0), atten / np.float32(max(nearest_depth, 1e-30)))))


def point_sizes(depth: np.ndarray, size: np.float32, atten: np.float32) -> np.ndarray:
    """float32 per-point size in pixels (the same float32 arithmetic as the kernel)."""
    if atten == 0:
        return np.full(depth.shape, size, np.float32)
    return np.minimum(size, np.maximum(np.float32(1.0), atten / depth.astype(np.float32)))
