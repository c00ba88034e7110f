"""Per-frame batch selection: frustum culling, projected size, precision, batch matrices.

All of it in float64 on the host (a few thousand batches a frame); only the composed
per-batch matrices are cast to float32, camera-relative, so UTM-sized coordinates do
not jitter (DESIGN.md, "Coordinates").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.layout import WORD_BITS

_CORNERS = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], np.float64)


@dataclass
class Selection:
    ids: np.ndarray  # int64 batch numbers drawn, ascending
    bits: np.ndarray  # int32 precision (10, 20, 30) per drawn batch
    matrices: np.ndarray  # float32 (k, 4, 4): 10-bit grid units -> (x', y', w, depth)
    projected_px: np.ndarray  # float64 projected size per drawn batch (inf if it crosses the near plane)
    n_culled: int


def project_boxes(rows: np.ndarray, bbox_min: np.ndarray, bbox_max: np.ndarray) -> np.ndarray:
    """(k, 8, 4) screen-space (x', y', w, depth) of the 8 corners of each box."""
    size = bbox_max - bbox_min
    corners = bbox_min[:, None, :] + _CORNERS[None, :, :] * size[:, None, :]
    return corners @ rows[:, :3].T + rows[:, 3]


def visible_and_size(rows, bbox_min, bbox_max, width, height, near, far):
    """Per box: in the frustum (conservatively) and projected size in pixels."""
    p = project_boxes(rows, bbox_min, bbox_max)
    x, y, w, d = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    outside = (
        np.all(x < 0, axis=1)
        | np.all(x > width * w, axis=1)
        | np.all(y < 0, axis=1)
        | np.all(y > height * w, axis=1)
        | np.all(d < near, axis=1)
        | np.all(d > far, axis=1)
    )
    in_front = np.all(w > 0, axis=1) & np.all(d >= near, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        px = np.where(w > 0, x / w, 0.0)
        py = np.where(w > 0, y / w, 0.0)
    size = np.maximum(px.max(axis=1) - px.min(axis=1), py.max(axis=1) - py.min(axis=1))
    size = np.where(in_front, size, np.inf)
    return ~outside, size


def precision_for(size_px: np.ndarray, threshold_px: float) -> np.ndarray:
    """10 bits below the threshold, 20 below threshold * 1024, else 30 (the paper's rule)."""
    bits = np.full(len(size_px), 30, np.int32)
    bits[size_px < threshold_px * (1 << WORD_BITS)] = 20
    bits[size_px < threshold_px] = 10
    return bits


def batch_matrices(rows: np.ndarray, bbox_min: np.ndarray, bbox_max: np.ndarray) -> np.ndarray:
    """float32 (k, 4, 4): maps a point's 10-bit-grid coordinate (0..1024) to (x', y', w, depth).

    Composed in float64 relative to each batch's own corner, then cast.
    """
    scale = (bbox_max - bbox_min) / float(1 << WORD_BITS)
    m = np.empty((len(bbox_min), 4, 4))
    m[:, :, :3] = rows[None, :, :3] * scale[:, None, :]
    m[:, :, 3] = bbox_min @ rows[:, :3].T + rows[:, 3]
    return m.astype(np.float32)


def select(batches, rows, width, height, near, far, threshold_px=500.0, adaptive=True, culling=True) -> Selection:
    bmin = batches["bbox_min"]
    bmax = batches["bbox_max"]
    visible, size = visible_and_size(rows, bmin, bmax, width, height, near, far)
    if not culling:
        visible[:] = True
    ids = np.flatnonzero(visible)
    bits = precision_for(size[ids], threshold_px) if adaptive else np.full(len(ids), 30, np.int32)
    return Selection(ids, bits, batch_matrices(rows, bmin[ids], bmax[ids]), size[ids], int(len(batches) - len(ids)))
