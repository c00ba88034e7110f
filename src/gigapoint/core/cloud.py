"""PointCloud: points in Morton order, grouped into batches, quantized batch-relative.

This is the in-memory form every backend renders (DESIGN.md, "Contracts"). Nothing
downstream sees float64 points: positions live as three u32 precision words per point
inside float64 batch boxes.
"""

from __future__ import annotations

import contextlib
import math
import warnings
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
from numba import njit, prange

from ..errors import EmptyCloudError, GigapointWarning, InputError, PointIndexError
from .chunk import PointChunk
from .layout import BATCH_DTYPE, BATCH_SIZE
from .morton import cube_of, morton_codes, morton_order
from .quantize import dequantize, make_batches, quantize
from .renderable import DrawList, MultiViewDrawList, SelectionSettings
from .selection import View, select_view, select_views, subsample_step

#: Coordinates beyond this magnitude are not of this planet in any CRS: skipped as invalid.
MAX_ABS_COORDINATE = 1e12


@dataclass
class PointCloud:
    """A renderable point cloud (unstructured: batches of consecutive Morton-ordered points).

    It is its own point buffers (renderable.py): built once, never rewritten in place."""

    batches: np.ndarray  # BATCH_DTYPE records
    low: np.ndarray  # u32 per point: bits 20-29 of x, y, z
    med: np.ndarray  # u32 per point: bits 10-19
    high: np.ndarray  # u32 per point: bits 0-9
    color: np.ndarray  # u32 per point: RGBA8 little-endian (r in the low byte)
    attributes: dict[str, np.ndarray] = field(default_factory=dict)
    name: str = "cloud"
    skipped: int = 0  # invalid input points (NaN, inf, absurd) left out
    # the resolution the source stored coordinates at, per axis (a LAS file's scale; the finest
    # of several files'), None where unknown: positions it reports are rounded to it
    source_scale: tuple[float, float, float] | None = None

    version: ClassVar[None] = None  # PointBuffers: the arrays never change once built
    batch_version: ClassVar[None] = None
    load_progress: ClassVar[float] = 1.0  # Renderable: built whole

    @property
    def n_points(self) -> int:
        return len(self.low)

    def __len__(self) -> int:
        return self.n_points

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(min, max) float64 corners of the box around all points."""
        return self.batches["bbox_min"].min(axis=0), self.batches["bbox_max"].max(axis=0)

    @property
    def rgba(self) -> np.ndarray:
        """(N, 4) uint8 view of the colors."""
        return self.color.view(np.uint8).reshape(-1, 4)

    def batch_of(self, indices) -> np.ndarray:
        """Batch number of each point index."""
        return np.searchsorted(self.batches["first"], np.asarray(indices, np.uint64), side="right") - 1

    def positions(self, indices=None) -> np.ndarray:
        """float64 (k, 3) world positions (30-bit precision) of point indices (all if None)."""
        if indices is None:
            indices = np.arange(self.n_points)
        indices = np.atleast_1d(np.asarray(indices, np.int64))
        b = self.batch_of(indices)
        out = np.empty((len(indices), 3))
        for batch in np.unique(b):
            sel = b == batch
            i = indices[sel]
            rec = self.batches[batch]
            out[sel] = dequantize(self.low[i], self.med[i], self.high[i], rec["bbox_min"], rec["bbox_max"], 30)
        return out

    def point_info(self, index: int) -> dict | None:
        """Everything known about one point: position, color and attributes; None for index -1
        (what ``Frame.index`` holds where a pixel shows no point).

        The position is rounded to the source's resolution (``source_scale``: a LAS file's
        scale), so it reads as the file wrote it (636317.71, not 636317.7100002308)."""
        if index == -1:
            return None
        if not 0 <= index < self.n_points:
            raise PointIndexError(f"{self.name}: point index {index} out of range 0..{self.n_points - 1} (-1: no point)")
        position = self.positions([index])[0]
        if self.source_scale is not None:
            position = [round(float(v), scale_decimals(s)) for v, s in zip(position, self.source_scale)]
        info = {"index": int(index), "position": [float(v) for v in position]}
        info["rgba"] = self.rgba[index].tolist()
        for name, values in self.attributes.items():
            v = values[index]
            info[name] = v.tolist() if hasattr(v, "tolist") else v
        return info

    # -- Renderable (renderable.py)
    def prepare(self, view: View, settings: SelectionSettings) -> DrawList:
        """The batches in view; with ``settings.max_points``, every k-th point of each."""
        sel = select_view(self.batches, view, settings)
        step = subsample_step(self.batches["count"][sel.ids].astype(np.int64), settings.max_points)
        return DrawList(self, sel, len(self.batches), step)

    def reading(self) -> contextlib.nullcontext:
        """Nothing to hold: the buffers never change."""
        return contextlib.nullcontext()

    def prepare_views(self, views: list[View], settings: SelectionSettings) -> MultiViewDrawList:
        ids, bits, matrices, sels = select_views(self.batches, views, settings)
        return MultiViewDrawList(self, ids, bits, matrices, [DrawList(self, sel, len(self.batches)) for sel in sels])

    def __repr__(self) -> str:
        lo, hi = self.bounds
        return f"PointCloud({self.name!r}, {self.n_points:,} points, {len(self.batches):,} batches, bounds {lo.tolist()} .. {hi.tolist()})"


def scale_decimals(scale: float) -> int:
    """Decimals that show a coordinate stored at resolution ``scale`` (0.01 -> 2, 0.001 -> 3, 0.5 -> 1)."""
    if not (math.isfinite(scale) and scale > 0):
        return 6
    return max(0, min(12, math.ceil(-math.log10(scale) - 1e-9)))


def _valid_mask(xyz: np.ndarray) -> np.ndarray:
    """The rule of ``_scan_blocks``: |x| <= the limit on every axis (False for NaN and inf)."""
    return np.all(np.abs(xyz) <= MAX_ABS_COORDINATE, axis=1)


_SCAN_BLOCKS = 64


@njit(parallel=True, cache=True)
def _scan_blocks(xyz, limit, bad, lo, hi):
    """Per block of points: the invalid count (NaN, inf, beyond ``limit``) and the bounds of the
    valid ones; one pass instead of numpy's six full-size temporaries (2 s for 20 M points)."""
    n = xyz.shape[0]
    nb = bad.shape[0]
    for b in prange(nb):
        count = 0
        for axis in range(3):
            lo[b, axis] = np.inf
            hi[b, axis] = -np.inf
        for i in range(b * n // nb, (b + 1) * n // nb):
            x = xyz[i, 0]
            y = xyz[i, 1]
            z = xyz[i, 2]
            if abs(x) <= limit and abs(y) <= limit and abs(z) <= limit:  # False for NaN too
                lo[b, 0] = min(lo[b, 0], x)
                lo[b, 1] = min(lo[b, 1], y)
                lo[b, 2] = min(lo[b, 2], z)
                hi[b, 0] = max(hi[b, 0], x)
                hi[b, 1] = max(hi[b, 1], y)
                hi[b, 2] = max(hi[b, 2], z)
            else:
                count += 1
        bad[b] = count


#: arrays up to this many points are scanned and gathered by numpy (milliseconds): a small
#: cloud's first run does not wait for the parallel kernels to compile
NUMPY_MAX = 1 << 20


def scan_points(xyz: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
    """(invalid points, min, max of the valid ones) of float64 (N, 3) positions."""
    if len(xyz) <= NUMPY_MAX:
        valid = xyz[_valid_mask(xyz)]
        if len(valid) == 0:
            return len(xyz), np.full(3, np.inf), np.full(3, -np.inf)
        return len(xyz) - len(valid), valid.min(axis=0), valid.max(axis=0)
    bad = np.empty(_SCAN_BLOCKS, np.int64)
    lo = np.empty((_SCAN_BLOCKS, 3))
    hi = np.empty((_SCAN_BLOCKS, 3))
    _scan_blocks(np.ascontiguousarray(xyz, np.float64), MAX_ABS_COORDINATE, bad, lo, hi)
    return int(bad.sum()), lo.min(axis=0), hi.max(axis=0)


@njit(parallel=True, cache=True)
def _gather(src, order, out):
    for i in prange(order.shape[0]):
        out[i] = src[order[i]]


def gather(values: np.ndarray, order: np.ndarray) -> np.ndarray:
    """values[order] along the first axis, on all cores (numpy's take is single-threaded)."""
    if values.ndim != 1 or not values.flags.c_contiguous or len(order) <= NUMPY_MAX:
        return np.ascontiguousarray(values[order])
    out = np.empty(len(order), values.dtype)
    _gather(values, order, out)
    return out


def build_cloud(chunks: Iterable[PointChunk], name: str = "cloud", batch_size: int = BATCH_SIZE) -> PointCloud:
    """Collect chunks, drop invalid points (counted and warned), sort by Morton code, batch, quantize."""
    xyz_parts, rgba_parts, attr_parts = [], [], {}
    scales: list[tuple | None] = []
    skipped = 0
    total = 0
    attr_names: list[str] | None = None
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for chunk in chunks:
        n_bad, chunk_lo, chunk_hi = scan_points(chunk.xyz)
        lo, hi = np.minimum(lo, chunk_lo), np.maximum(hi, chunk_hi)
        skipped += n_bad
        keep = slice(None) if n_bad == 0 else _valid_mask(chunk.xyz)
        names = sorted(chunk.attributes)
        if attr_names is None:
            attr_names = names
        elif names != attr_names:  # files of one scene with different attributes: keep the common ones
            attr_names = [a for a in attr_names if a in names]
        scales.append(chunk.scale)
        xyz_parts.append(chunk.xyz[keep])
        rgba_parts.append(chunk.rgba[keep])
        for a, values in chunk.attributes.items():
            attr_parts.setdefault(a, []).append(values[keep])
        total += len(xyz_parts[-1])
    if total == 0:
        detail = f" ({skipped:,} invalid points: NaN, inf or beyond ±{MAX_ABS_COORDINATE:g})" if skipped else ""
        raise EmptyCloudError(f"{name}: no valid points{detail}")
    if skipped:
        warnings.warn(f"{name}: skipped {skipped:,} invalid points (NaN, inf or beyond ±{MAX_ABS_COORDINATE:g})", GigapointWarning, stacklevel=2)
    xyz = xyz_parts[0] if len(xyz_parts) == 1 else np.concatenate(xyz_parts)
    del xyz_parts
    rgba = rgba_parts[0] if len(rgba_parts) == 1 else np.concatenate(rgba_parts)
    del rgba_parts
    attributes = {a: (v[0] if len(v) == 1 else np.concatenate(v)) for a, v in attr_parts.items() if a in (attr_names or [])}
    cloud = cloud_from_points(xyz, rgba, attributes, name=name, skipped=skipped, batch_size=batch_size, bounds=(lo, hi))
    if scales and all(s is not None for s in scales):  # the finest: rounding to it loses nothing any file holds
        cloud.source_scale = tuple(float(v) for v in np.min(np.array(scales, np.float64), axis=0))
    return cloud


def cloud_from_points(xyz, rgba, attributes=None, name="cloud", skipped=0, batch_size=BATCH_SIZE, bounds=None) -> PointCloud:
    """Build a PointCloud from valid float64 xyz (N, 3) and uint8 rgba (N, 4) (``bounds``: their
    (min, max) if already known)."""
    if batch_size < 1:
        raise InputError(f"{name}: batch size must be >= 1, got {batch_size}")
    lo, hi = bounds if bounds is not None else scan_points(xyz)[1:]
    origin, edge = cube_of(lo, hi)
    order = morton_order(morton_codes(xyz, origin, edge))
    batches = make_batches(len(xyz), batch_size)
    low, med, high = quantize(xyz, order, batches)
    rgba = np.ascontiguousarray(rgba, np.uint8)
    color = gather(rgba.view(np.uint32).reshape(-1), order)  # RGBA8 as one u32 a point
    attrs = {a: gather(v, order) for a, v in (attributes or {}).items()}
    return PointCloud(batches, low, med, high, color, attrs, name=name, skipped=skipped)


def from_arrays(xyz, rgb=None, name: str = "arrays", **attributes) -> PointCloud:
    """A PointCloud from numpy arrays: float64 (N, 3) positions, (N, 3|4) uint8/uint16/float colors."""
    xyz = np.asarray(xyz)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise InputError(f"{name}: xyz must have shape (N, 3), got {xyz.shape}")
    try:
        chunk = PointChunk(xyz, rgb, {k: np.asarray(v) for k, v in attributes.items()})
    except ValueError as exc:
        raise InputError(f"{name}: {exc}") from None
    return build_cloud([chunk], name=name)


__all__ = ["BATCH_DTYPE", "PointCloud", "build_cloud", "cloud_from_points", "from_arrays"]
