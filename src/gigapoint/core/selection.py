"""Per-frame batch selection: frustum culling, projected size, precision, batch matrices.

Which batches of the quantized layout a view draws and at which precision (10/20/30-bit
words), with the matrices that map a batch's 10-bit grid onto the screen. It needs of a
camera only its ``View`` (screen rows, image size, clip range), so clouds of every kind
(core's PointCloud, lod's octrees) select with it without knowing the renderer.

All of it in float64 on the host (a few thousand batches a frame); only the composed
per-batch matrices are cast to float32, camera-relative, so UTM-sized coordinates do
not jitter (DESIGN.md, "Coordinates").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from .layout import WORD_BITS


@dataclass(frozen=True)
class View:
    """What a selection needs of a camera: world -> screen rows and the image it fills."""

    rows: np.ndarray  # (4, 4) float64: world -> (x', y', w, depth); pixel = (x'/w, y'/w)
    width: int
    height: int
    near: float
    far: float


@dataclass
class Selection:
    ids: np.ndarray  # int64 batch numbers drawn, ascending
    bits: np.ndarray  # int32 precision (10, 20, 30) per drawn batch
    matrices: np.ndarray  # float32 (k, 4, 4): 10-bit grid units -> (x', y', w, depth)
    projected_px: np.ndarray  # float64 projected size per drawn batch (inf if it crosses the near plane)
    n_culled: int


def visible_and_size(rows, bbox_min, bbox_max, width, height, near, far):
    """Per box: in the frustum (conservatively) and projected size in pixels. The boxes may be
    fields of a structured array (strided): the kernel reads them in place, no copy."""
    k = len(bbox_min)
    visible = np.empty(k, np.bool_)
    size = np.empty(k, np.float64)
    _boxes_in_view(np.ascontiguousarray(rows, np.float64), _as_f64(bbox_min), _as_f64(bbox_max), float(width), float(height), float(near), float(far), visible, size)
    return visible, size


def _as_f64(a):
    return a if a.dtype == np.float64 else a.astype(np.float64)


@njit(inline="always")
def box_in_view(rows, x0, y0, z0, dx, dy, dz, width, height, near, far):
    """(in the frustum, all corners in front of the near plane, x_lo, x_hi, y_lo, y_hi) of the box
    [x0, x0 + dx] x [y0, y0 + dy] x [z0, z0 + dz] under the screen rows ``rows``.

    A box is outside when all 8 corners are beyond one frustum plane (conservative); the
    rectangle bounds the screen positions of the corners in front of the eye. Shared by the
    batch selection here and the octree's node selection (gigapoint.lod).
    """
    left = right = below = above = closer = farther = True
    in_front = True
    x_lo = y_lo = np.inf
    x_hi = y_hi = -np.inf
    for c in range(8):
        x = x0 + dx * ((c >> 2) & 1)
        y = y0 + dy * ((c >> 1) & 1)
        z = z0 + dz * (c & 1)
        sx = rows[0, 0] * x + rows[0, 1] * y + rows[0, 2] * z + rows[0, 3]
        sy = rows[1, 0] * x + rows[1, 1] * y + rows[1, 2] * z + rows[1, 3]
        sw = rows[2, 0] * x + rows[2, 1] * y + rows[2, 2] * z + rows[2, 3]
        sd = rows[3, 0] * x + rows[3, 1] * y + rows[3, 2] * z + rows[3, 3]
        left &= sx < 0
        right &= sx > width * sw
        below &= sy < 0
        above &= sy > height * sw
        closer &= sd < near
        farther &= sd > far
        if sw <= 0 or sd < near:
            in_front = False
        else:
            px = sx / sw
            py = sy / sw
            x_lo = min(x_lo, px)
            x_hi = max(x_hi, px)
            y_lo = min(y_lo, py)
            y_hi = max(y_hi, py)
    visible = not (left or right or below or above or closer or farther)
    return visible, in_front, x_lo, x_hi, y_lo, y_hi


@njit(cache=True)
def _boxes_in_view(rows, bbox_min, bbox_max, width, height, near, far, visible, size):
    """visible_and_size for k boxes in one compiled loop (numpy took 1.2 ms for 2 000 boxes); the
    size is the larger side of the corners' screen rectangle, inf when a corner is not in front."""
    for b in range(bbox_min.shape[0]):
        x0, y0, z0 = bbox_min[b, 0], bbox_min[b, 1], bbox_min[b, 2]
        vis, in_front, x_lo, x_hi, y_lo, y_hi = box_in_view(
            rows, x0, y0, z0, bbox_max[b, 0] - x0, bbox_max[b, 1] - y0, bbox_max[b, 2] - z0, width, height, near, far
        )
        visible[b] = vis
        size[b] = max(x_hi - x_lo, y_hi - y_lo) if in_front else np.inf


def precision_for(size_px: np.ndarray, threshold_px: float) -> np.ndarray:
    """10 bits below the threshold, 20 below threshold * 1024, else 30 (the paper's rule)."""
    bits = np.full(len(size_px), 30, np.int32)
    bits[size_px < threshold_px * (1 << WORD_BITS)] = 20
    bits[size_px < threshold_px] = 10
    return bits


def batch_matrices(rows: np.ndarray, bbox_min: np.ndarray, bbox_max: np.ndarray, ids: np.ndarray | None = None) -> np.ndarray:
    """float32 (k, 4, 4): maps a point's 10-bit-grid coordinate (0..1024) to (x', y', w, depth),
    for boxes ``ids`` (default: all).

    Composed in float64 relative to each batch's own corner, then cast.
    """
    if ids is None:
        ids = np.arange(len(bbox_min))
    out = np.empty((len(ids), 4, 4), np.float32)
    _compose_matrices(np.ascontiguousarray(rows, np.float64), _as_f64(bbox_min), _as_f64(bbox_max), np.asarray(ids, np.int64), out)
    return out


@njit(cache=True)
def _compose_matrices(rows, bbox_min, bbox_max, ids, out):
    """out[k] = rows @ (scale to the grid of box ids[k], then its corner), in float64, cast."""
    inv_grid = 1.0 / (1 << WORD_BITS)
    for k in range(ids.shape[0]):
        b = ids[k]
        for r in range(4):
            for a in range(3):
                out[k, r, a] = rows[r, a] * ((bbox_max[b, a] - bbox_min[b, a]) * inv_grid)
            out[k, r, 3] = bbox_min[b, 0] * rows[r, 0] + bbox_min[b, 1] * rows[r, 1] + bbox_min[b, 2] * rows[r, 2] + rows[r, 3]


def select(batches, rows, width, height, near, far, threshold_px=500.0, adaptive=True, culling=True) -> Selection:
    bmin = batches["bbox_min"]
    bmax = batches["bbox_max"]
    visible, size = visible_and_size(rows, bmin, bmax, width, height, near, far)
    if not culling:
        visible[:] = True
    ids = np.flatnonzero(visible)
    bits = precision_for(size[ids], threshold_px) if adaptive else np.full(len(ids), 30, np.int32)
    return Selection(ids, bits, batch_matrices(rows, bmin, bmax, ids), size[ids], int(len(batches) - len(ids)))


def select_view(batches, view: View, settings, culling: bool | None = None) -> Selection:
    """``select`` for a View, with the precision rule and culling of ``settings``
    (precision_threshold_px, adaptive_precision, frustum_culling)."""
    culling = settings.frustum_culling if culling is None else culling
    return select(batches, view.rows, view.width, view.height, view.near, view.far, settings.precision_threshold_px, settings.adaptive_precision, culling)


def select_views(batches, views: list[View], settings) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[Selection]]:
    """Batches for drawing several views in one pass (2022 paper, 3.7): (ids, the union of
    what any view draws; bits (V, k) and matrices (V, k, 4, 4), every view's precision and
    matrix for each of them; each view's own Selection). A batch another view drew lands
    outside this view's frustum, so each view's image equals a separate render."""
    sels = [select_view(batches, v, settings) for v in views]
    ids = sels[0].ids
    for sel in sels[1:]:
        ids = np.union1d(ids, sel.ids)
    full = [select_view(batches, v, settings, culling=False) for v in views]
    bits = np.stack([fs.bits[ids] for fs in full])
    mats = np.stack([fs.matrices[ids] for fs in full])
    return ids, bits, mats, sels


def subsample_step(counts: np.ndarray, max_points: int) -> int:
    """Smallest k such that every k-th point of each batch stays within ``max_points`` (0: no cap;
    never fewer than one point per batch)."""
    total = int(counts.sum())
    if max_points <= 0 or total <= max_points:
        return 1
    step = -(-total // max_points)
    largest = int(counts.max())
    while step < largest and int(((counts + step - 1) // step).sum()) > max_points:  # each batch rounds up
        step += 1
    return min(step, largest)  # one point per batch is the floor
