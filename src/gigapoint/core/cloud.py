"""PointCloud: points in Morton order, grouped into batches, quantized batch-relative.

This is the in-memory form every backend renders (DESIGN.md, "Contracts"). Nothing
downstream sees float64 points: positions live as three u32 precision words per point
inside float64 batch boxes.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
from numba import njit, prange, types
from numba.typed import List

from ..errors import EmptyCloudError, GigapointWarning, InputError, PointIndexError, check_switch, check_whole, counted, warn
from . import pages
from .attributes import Attributes
from .chunk import PointChunk, attributes_in_common, colors_for, points_for, warn_dropped_attributes
from .classes import parse_classes
from .compact import centre_half, colors_at, compact_positions, full_words, pack_rgb565, point_words, rgba32, subset_streams
from .coords import MAX_ABS_COORDINATE, NUMPY_MAX, value_decimals
from .coords import valid_mask as _valid_mask
from .hooks import wire
from .layout import BATCH_DTYPE, BATCH_SIZE, COLOR_FORMATS
from .morton import cube_of, morton_codes, morton_order
from .palette import PaletteColors, block_errors, choose_palette, quantize_palettes
from .quantize import dequantize, make_batches, quantize
from .renderable import DrawList, MultiViewDrawList, SelectionSettings, check_classified, check_point_index
from .selection import View, select_view, select_views, subsample_step

#: what ``PointCloud.save`` writes with: io/write.py's ``save_cloud``, set when gigapoint.io.write
#: is imported (gigapoint/__init__.py's wiring does it at the first save: core cannot import io)
_CLOUD_WRITER: list[Callable] = []


def set_cloud_writer(write: Callable) -> None:
    """io/write.py's writer of a cloud's points to a file (``PointCloud.save``)."""
    _CLOUD_WRITER[:] = [write]


@dataclass
class PointCloud:
    """A renderable point cloud (unstructured: batches of consecutive Morton-ordered points).

    It is its own point buffers (renderable.py). Its colours change through ``set_colors``;
    anything else changed in place (``rgba``'s view, an attribute replaced) is announced with
    ``changed()``, so every backend and cache draws the new values."""

    batches: np.ndarray  # BATCH_DTYPE records
    low: np.ndarray  # u32 per point: bits 20-29 of x, y, z
    med: np.ndarray | None  # u32 per point: bits 10-19 (None in the compact layout)
    high: np.ndarray | None  # u32 per point: bits 0-9 (None in the compact layout)
    # u32 per point: RGBA8 little-endian (r in the low byte); u16 RGB565 in the compact layout
    # (compact.py); or per-block palettes and u8 indices (palette.py: ``colors="palette"``, and
    # ``colors="auto"``'s choice where they are as faithful as RGB565)
    color: np.ndarray | PaletteColors
    # per point, by name; held in their real range where built from points (core/attributes.py),
    # read back in their own dtype: ``attributes[name]``, ``attributes.at(name, indices)``
    attributes: Attributes = field(default_factory=Attributes)
    name: str = "cloud"
    skipped: int = 0  # invalid input points (NaN, inf, absurd) left out
    # the resolution the source stored coordinates at, per axis (a LAS file's scale; the finest
    # of several files'), None where unknown: positions it reports are rounded to it
    source_scale: tuple[float, float, float] | None = None
    # the compact layout (core/compact.py), else None: per-batch extension bit streams (u64 words)
    # and their PACK_DTYPE records; its boxes are grid-aligned, ``data_bounds`` the points' own
    ext: np.ndarray | None = None
    packing: np.ndarray | None = None
    data_bounds: tuple[np.ndarray, np.ndarray] | None = None
    # PointSource: the files it was read from (io.open_cloud), whose headers give a conversion
    # of the cloud its CRS and LAS grid; empty where it was built from points
    source_files: tuple = ()
    # 8 where every source file stored its colours as 8-bit values in 16-bit fields (some LAS
    # files do), 16 where one held 16-bit colours, None where unknown (source_color_bits)
    source_color_bits: int | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.attributes, Attributes):  # a dict of arrays: held as given
            self.attributes = Attributes(self.attributes)
        self.attributes.belong_to(self.name, self.n_points)

    @property
    def colors_exact(self) -> bool:
        """PointSource: its colours are 32-bit RGBA, as given; RGB565 and palettes (``colors=``,
        "auto"'s choice) hold approximations, which ``chunks()`` and so a conversion give back."""
        return isinstance(self.color, np.ndarray) and self.color.dtype == np.uint32

    # PointBuffers: None while the arrays are as built; ``changed()`` makes it a counter and marks
    # the batches it names in ``batch_version`` (the GPU then re-sends those, caches recompute)
    version: int | None = field(default=None, init=False, repr=False, compare=False)
    batch_version: np.ndarray | None = field(default=None, init=False, repr=False, compare=False)
    load_progress: ClassVar[float] = 1.0  # Renderable: built whole
    # what frames with hidden classes draw: {hidden classes: (this cloud's version, its points of the
    # other classes)}, made once a set while the cloud is unchanged (``drawn``)
    _without: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @property
    def n_points(self) -> int:
        return len(self.low)

    def __len__(self) -> int:
        return self.n_points

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(min, max) float64 corners of the box around all points."""
        if self.data_bounds is not None:
            return self.data_bounds[0].copy(), self.data_bounds[1].copy()
        return self.batches["bbox_min"].min(axis=0), self.batches["bbox_max"].max(axis=0)

    @property
    def rgba(self) -> np.ndarray:
        """(N, 4) uint8 colors in the cloud's order (a view of u32 colors: call ``changed()``
        after writing to it; a read-only decoded copy of 16-bit colors or palettes). ``set_colors`` writes any."""
        colors = rgba32(self.color)
        if colors is not self.color:  # a copy: writes to it changed nothing, without a word
            colors.flags.writeable = False
        return colors.view(np.uint8).reshape(-1, 4)

    def set_colors(self, rgb, indices=None) -> None:
        """Colours of points ``indices`` (all if None; the cloud's order, as ``positions()``'s) set to
        ``rgb``: (k, 3|4) colours as ``from_arrays`` takes them, or one colour. Held in the cloud's
        format (RGB565 and palettes approximate them); every backend draws them from the next frame."""
        idx = slice(None) if indices is None else self._point_indices(indices)
        n = self.n_points if indices is None else len(idx)
        if np.ndim(rgb) == 1:  # one colour for all of them
            rgb = np.broadcast_to(rgb, (n, len(rgb)))
        elif np.ndim(rgb) == 2 and len(rgb) != n:  # (colors_for's "xyz has")
            raise InputError(f"{self.name}: set_colors: {len(rgb):,} colours for {n:,} points")
        new = colors_for(rgb, n, f"{self.name}: set_colors").view(np.uint32).reshape(-1)
        if isinstance(self.color, PaletteColors):  # palettes are chosen per block: quantized again
            full = rgba32(self.color)  # (a decoded copy)
            full[idx] = new
            self.color = encode_colors(full, "palette")
        elif self.color.dtype == np.uint32:
            self.color[idx] = new
        elif not (new >> 24 == 255).all():
            raise InputError(f"{self.name}: set_colors: 16-bit colors drop alpha, and some given are not opaque")
        else:
            self.color[idx] = pack_rgb565(new)
        self.changed(indices)

    def save(self, path, overwrite: bool = False) -> int:
        """Write every point, in the cloud's order, to ``path``: .las, .laz or .ply (its suffix
        says). A cloud read from LAS/LAZ files keeps their CRS and their X, Y, Z integers (on their
        grid); colours are written as held (8 bits a channel). An existing file is replaced only
        with ``overwrite=True``. Returns the points written."""
        check_switch("overwrite", overwrite, f"{self.name}: save")  # ("no" was taken as true)
        wire()  # io's writer registers itself on first use (core/hooks.py)
        return _CLOUD_WRITER[0](self, path, overwrite)

    def changed(self, indices=None) -> None:
        """Say that the arrays of points ``indices`` (all if None) were changed in place (``rgba``'s
        view written, an attribute replaced): the GPU sends their batches again and colours derived
        from them (colour modes) are computed again. Frames drawn before no longer pick points."""
        batches = slice(None) if indices is None else np.unique(self.batch_of(indices))
        if self.batch_version is None:
            self.batch_version = np.zeros(len(self.batches), np.int64)
        self.version = (self.version or 0) + 1
        self.batch_version[batches] = self.version

    def _point_indices(self, indices) -> np.ndarray:
        """``indices`` as int64 point indices (1-D), or a one-line PointIndexError for one that is
        not a point's."""
        indices = np.atleast_1d(np.asarray(indices))
        if indices.size and indices.dtype.kind not in "iu":
            raise PointIndexError(f"{self.name}: point indices must be whole numbers, got {indices.dtype}")
        indices = indices.astype(np.int64, copy=False)
        outside = indices[(indices < 0) | (indices >= self.n_points)]
        if len(outside):
            raise PointIndexError(f"{self.name}: point index {outside[0]} out of range 0..{self.n_points - 1}")
        return indices

    def batch_of(self, indices) -> np.ndarray:
        """Batch number of each point index (an index that is not a point's: a one-line
        PointIndexError; -1 was an OverflowError, one past the end the last batch's)."""
        return self._batches_of(self._point_indices(indices))

    def _batches_of(self, indices: np.ndarray) -> np.ndarray:
        return np.searchsorted(self.batches["first"], indices.astype(np.uint64), side="right") - 1

    def positions(self, indices=None) -> np.ndarray:
        """float64 (k, 3) world positions (30-bit precision) of point indices (all if None); an
        index that is not a point's a one-line PointIndexError (the kernels read past the arrays:
        a segmentation fault)."""
        indices = np.arange(self.n_points) if indices is None else self._point_indices(indices)
        b = self._batches_of(indices)
        out = np.empty((len(indices), 3))
        for batch in np.unique(b):
            sel = b == batch
            i = indices[sel]
            rec = self.batches[batch]
            lo, hi = int(i.min()), int(i.max()) + 1
            low, med, high = self._words(int(batch), lo, hi)
            out[sel] = dequantize(low[i - lo], med[i - lo], high[i - lo], rec["bbox_min"], rec["bbox_max"], 30, self._half(int(batch)))
        return out

    def chunks(self, points_per_chunk: int = 1_000_000):
        """The points as PointChunks, in the cloud's order, whole batches at a time: positions
        (30 bits a batch; exact on the source's grid in the compact layout), colours and
        attributes as they read back. What ``gigapoint.convert(cloud, out)`` converts."""
        check_whole(f"{self.name}: chunks", "points_per_chunk", points_per_chunk, 1)  # 0, -1 and 2.5 were taken
        first, count = self.batches["first"].astype(np.int64), self.batches["count"].astype(np.int64)
        start = 0
        while start < len(self.batches):
            end = start + 1 + int(np.searchsorted(np.cumsum(count[start:]), points_per_chunk))  # batches up to the size
            end = min(end, len(self.batches))
            lo, hi = int(first[start]), int(first[end - 1] + count[end - 1])
            xyz = np.concatenate([self._batch_positions(b) for b in range(start, end)])
            attributes = {a: self.attributes.at(a, slice(lo, hi)) for a in self.attributes}
            rgba = colors_at(self.color, np.arange(lo, hi)).view(np.uint8).reshape(-1, 4)  # this chunk's only: not all N x 4 bytes at once
            yield PointChunk(xyz, rgba, attributes, scale=self.source_scale)
            start = end

    def _batch_positions(self, batch: int) -> np.ndarray:
        """float64 positions of one batch's points (30-bit precision)."""
        rec = self.batches[batch]
        lo = int(rec["first"])
        return dequantize(*self._words(batch, lo, lo + int(rec["count"])), rec["bbox_min"], rec["bbox_max"], 30, self._half(batch))

    def _half(self, batch: int) -> np.ndarray:
        """``dequantize``'s half for ``batch``: 0 on a grid-aligned compact batch's axes (its words are the
        source's values), so positions equal them to float64 rounding, not scale * 2^(B - 31) past."""
        return centre_half(None if self.packing is None else self.packing["code"][batch])

    def _words(self, batch: int, lo: int, hi: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The three 10-bit-per-axis words of points lo..hi of ``batch`` (decoded in the compact layout)."""
        if self.packing is None:
            return self.low[lo:hi], self.med[lo:hi], self.high[lo:hi]
        return point_words(self, batch, lo, hi)

    @property
    def attribute_names(self) -> list[str]:
        return list(self.attributes)

    @property
    def layout(self) -> str:
        """"compact" (core/compact.py) or "words" (three u32 words a point)."""
        return "words" if self.packing is None else "compact"

    def memory(self) -> dict[str, int]:
        """Bytes held per component: positions (words or low word + extension streams), color,
        attributes, batches (records, and the compact layout's per-batch records)."""
        pos = self.low.nbytes
        if self.packing is None:
            pos += self.med.nbytes + self.high.nbytes
        else:
            pos += self.ext.nbytes
        batches = self.batches.nbytes + (0 if self.packing is None else self.packing.nbytes)
        return {
            "positions": int(pos),
            "color": int(self.color.nbytes),
            "attributes": self.attributes.nbytes,
            "batches": int(batches),
        }

    def expanded(self) -> PointCloud:
        """The same points in the three-word layout, with the same boxes: renders of the two are
        identical bit for bit (the compact layout's contract; tests and benchmarks compare them).
        Its ``positions`` decode the words as floor-quantized ones (+ half a 30-bit cell): up to
        2^-31 of a batch's size past the compact cloud's, which are the source's values."""
        if self.packing is None:
            return self
        med, high = full_words(self)
        return PointCloud(self.batches.copy(), self.low.copy(), med, high, rgba32(self.color), self.attributes.copy(), name=self.name,
                          skipped=self.skipped, source_scale=self.source_scale, data_bounds=self.data_bounds)  # fmt: skip

    @property
    def nbytes(self) -> int:
        """Bytes of all its arrays (``memory()`` has them per component)."""
        return sum(self.memory().values())

    def point_info(self, index: int) -> dict | None:
        """Everything known about one point: position, color and attributes; None for index -1
        (what ``Frame.index`` holds where a pixel shows no point). Colours held approximately
        (RGB565, palettes: ``colors_exact`` False) add ``rgba_approx``, saying how they are held.

        The position is rounded to the source's resolution (``source_scale``: a LAS file's
        scale), so it reads as the file wrote it (636317.71, not 636317.7100002308)."""
        check_point_index(index, self.n_points, self.name)
        if index == -1:
            return None
        info = {"index": int(index), "position": at_scale(self.positions([index])[0], self.source_scale)}
        info["rgba"] = colors_at(self.color, [index]).view(np.uint8).tolist()
        if not self.colors_exact:  # the source's own colour is not held (gp.open's colors="auto"): say this one is near it
            info["rgba_approx"] = "colours held as 256-colour palettes" if isinstance(self.color, PaletteColors) else "colours held in 16 bits (RGB565)"
        for name in self.attributes:
            v = self.attributes.at(name, [index])[0]  # one point's, not the whole array decoded
            info[name] = v.tolist() if hasattr(v, "tolist") else v
        return info

    def without_classes(self, hidden) -> PointCloud:
        """A cloud of the points whose ``classification`` is not in ``hidden``, in the same order:
        each batch's kept points a batch of their own in its box (their position words as held,
        so they draw where they drew), colours and attributes its own arrays. What frames with
        ``hidden_classes`` draw (``drawn``); a cloud without classification, or ``hidden`` not LAS
        classes, is a SettingsError."""
        hidden = parse_classes(hidden, f"{self.name}: without_classes: hidden")  # ("a", -1, 1.5 hid nothing without a word)
        check_classified(self.name, self.attributes, hidden)
        kept = ~np.isin(self.attributes["classification"], hidden)
        idx = np.flatnonzero(kept)
        count = self.batches["count"].astype(np.int64)
        kept_counts = np.bincount(np.repeat(np.arange(len(count)), count)[idx], minlength=len(count))
        nonempty = np.flatnonzero(kept_counts)
        batches = self.batches[nonempty].copy()
        batches["count"] = kept_counts[nonempty]
        batches["first"] = np.cumsum(kept_counts[nonempty]) - kept_counts[nonempty]
        ext = pack = None
        if self.packing is None:
            med, high = self.med[idx], self.high[idx]
        else:  # the kept points' extension fields moved into streams of their own
            med = high = None
            positions = idx - np.repeat(self.batches["first"][nonempty].astype(np.int64), kept_counts[nonempty])
            ext, pack = subset_streams(self, nonempty, kept_counts[nonempty], positions)
        # palettes are per block of the whole cloud: the kept points' colours decoded (what they draw)
        color = self.color[idx] if isinstance(self.color, np.ndarray) else colors_at(self.color, idx)
        attrs = Attributes({a: self.attributes.at(a, idx) for a in self.attributes}, packed=True)
        cloud = PointCloud(batches, self.low[idx], med, high, color, attrs, name=self.name, source_scale=self.source_scale, ext=ext,
                           packing=pack, data_bounds=self.data_bounds, source_files=self.source_files,
                           source_color_bits=self.source_color_bits)  # fmt: skip
        return cloud

    def drawn(self, settings: SelectionSettings) -> PointCloud:
        """The cloud a frame with these settings draws: itself, or with ``hidden_classes`` its
        points of the other classes, filtered once a set and kept until the cloud ``changed()``
        (toggling classes back and forth filters nothing again)."""
        hidden = settings.hidden_classes
        if not hidden:
            return self
        made = self._without.get(hidden)
        if made is None or made[0] != self.version:
            self._without = {h: m for h, m in self._without.items() if m[0] == self.version}  # those of older points dropped
            if len(self._without) >= 4:  # a few sets held (each a copy of the points kept), not every set ever shown
                self._without.pop(next(iter(self._without)))
            made = self._without[hidden] = (self.version, self.without_classes(hidden))
        return made[1]

    # -- Renderable (renderable.py)
    def prepare(self, view: View, settings: SelectionSettings) -> DrawList:
        """The batches in view; with ``settings.max_points``, every k-th point of each; with
        ``settings.hidden_classes``, those of the cloud of the other classes (``drawn``): the
        frame's indices are its points'."""
        cloud = self.drawn(settings)
        sel = select_view(cloud.batches, view, settings)
        step = subsample_step(cloud.batches["count"][sel.ids].astype(np.int64), settings.max_points)
        return DrawList(cloud, sel, len(self.batches), step)

    def reading(self) -> contextlib.nullcontext:
        """Nothing to hold: the buffers change only where the program changes them, between frames."""
        return contextlib.nullcontext()

    def prepare_views(self, views: list[View], settings: SelectionSettings) -> MultiViewDrawList:
        cloud = self.drawn(settings)
        ids, bits, matrices, sels = select_views(cloud.batches, views, settings)
        return MultiViewDrawList(cloud, ids, bits, matrices, [DrawList(cloud, sel, len(self.batches)) for sel in sels])

    def __repr__(self) -> str:
        lo, hi = (at_scale(b, self.source_scale) for b in self.bounds)  # as the file wrote them: 848935.2, not 848935.2000000001
        n = len(self.batches)
        return f"PointCloud({self.name!r}, {self.n_points:,} points, {n:,} batch{'' if n == 1 else 'es'}, bounds {lo} .. {hi})"


def at_scale(position, scale) -> list[float]:
    """A position as floats rounded to the resolution its source stored it at (``scale``: a
    LAS file's, per axis; None: as it is), so it reads as the file wrote it."""
    if scale is None:
        return [float(v) for v in position]
    return [round(float(v), value_decimals(float(v), s)) for v, s in zip(position, scale)]


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
def _take1(src, idx, out):
    for i in prange(idx.shape[0]):
        out[i] = src[idx[i]]


@njit(parallel=True, cache=True)
def _take2(src, idx, out):
    for i in prange(idx.shape[0]):
        for j in range(src.shape[1]):
            out[i, j] = src[idx[i], j]


@njit(cache=True)
def _new_byte_views():
    """An empty numba list of byte arrays. Made here, not with ``List.empty_list`` in Python:
    that compiles the list's methods in every process (0.2 s of a progressive load's first
    insertion, so of its first image); cached kernels are loaded instead."""
    return List.empty_list(types.uint8[::1])


@njit(cache=True)
def _append_byte_view(views, view):
    views.append(view)


def byte_views(arrays) -> List:
    """Contiguous 1-D arrays as a numba list of their bytes: what kernels take attributes of any
    types as, one compiled kernel for every set of attribute types."""
    views = _new_byte_views()
    for a in arrays:
        _append_byte_view(views, a.view(np.uint8))
    return views


_UINT_OF_SIZE = {1: np.uint8, 2: np.uint16, 4: np.uint32, 8: np.uint64}


def take(src: np.ndarray, idx: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """src[idx] along the first axis, in parallel (numpy's fancy indexing is single-threaded),
    into ``out`` when given (e.g. a slice of a memory-mapped output file).

    Values are moved as same-width unsigned integers, so the kernels compile for 4 types only.
    """
    src = np.ascontiguousarray(src)
    if out is None:
        out = np.empty((len(idx),) + src.shape[1:], src.dtype)
    else:
        out = np.asarray(out)
    u = _UINT_OF_SIZE.get(src.dtype.itemsize)
    idx = np.asarray(idx)
    if idx.dtype not in (np.int64, np.uint32, np.int32):  # sort orders are u32: gathered as they are, not widened
        idx = idx.astype(np.int64)
    idx = np.ascontiguousarray(idx)
    if u is not None and src.ndim == 1:
        _take1(src.view(u), idx, out.view(u))
    elif u is not None and src.ndim == 2:
        _take2(src.view(u), idx, out.view(u))
    else:
        out[:] = src[idx]
    return out


def gather(values: np.ndarray, order: np.ndarray) -> np.ndarray:
    """values[order] along the first axis: numpy up to ``NUMPY_MAX`` points (a small cloud's
    first load compiles no kernel), ``take`` on all cores beyond."""
    if len(order) <= NUMPY_MAX:
        return np.ascontiguousarray(values[order])
    return take(values, order)


def build_cloud(
    chunks: Iterable[PointChunk], name: str = "cloud", batch_size: int = BATCH_SIZE, layout: str = "auto", colors: str = "auto"
) -> PointCloud:
    """Collect chunks, drop invalid points (counted and warned), sort by Morton code, batch, quantize.

    ``layout``: "auto" stores the compact layout (core/compact.py) where every chunk says its
    source scale (LAS files), three u32 words a point otherwise; "words" always the latter;
    "compact" needs a scale. ``colors``: "rgba" always 32 bits (exact), "rgb565" always 16 (at most
    4/255 off a channel), "palette" 8 (a palette of 256 colours per 8 192 points, core/palette.py:
    exact where those hold at most 256 distinct colours; 46.2 dB PSNR on autzen_trim against
    RGB565's 41.7); "auto" holds opaque colors of a compact cloud as the palette where its PSNR
    over the cloud's colours is at least RGB565's, else as RGB565 (palette.choose_palette), and
    32-bit colors otherwise (three-word clouds, translucent colors)."""
    xyz_parts, rgba_parts, attr_parts = [], [], {}
    scales: list[tuple | None] = []
    color_bits: list[int | None] = []
    skipped = 0
    total = 0
    attr_names: list[str] | None = None
    dropped: set[str] = set()
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for chunk in chunks:
        n_bad, chunk_lo, chunk_hi = scan_points(chunk.xyz)
        lo, hi = np.minimum(lo, chunk_lo), np.maximum(hi, chunk_hi)
        skipped += n_bad
        keep = slice(None) if n_bad == 0 else _valid_mask(chunk.xyz)
        attr_names = attributes_in_common(attr_names, chunk.attributes, dropped)  # files of one scene: the common ones
        scales.append(chunk.scale)
        color_bits.append(chunk.color_bits)
        xyz_parts.append(chunk.xyz[keep])
        rgba_parts.append(chunk.rgba[keep])
        for a, values in chunk.attributes.items():
            held = attr_parts.setdefault(a, [])
            if held and held[0].shape[1:] != values.shape[1:]:  # (numpy's "must have same number of dimensions" at the join)
                raise InputError(f"{name}: attribute {a!r} holds {_per_point(held[0])} a point in one file and {_per_point(values)} in another")
            held.append(values[keep])
        total += len(xyz_parts[-1])
    chunk = values = held = None  # (the last chunk's arrays go with the parts, once joined)
    check_valid_count(name, total, skipped)
    warn_dropped_attributes(name, dropped)
    xyz = _joined(xyz_parts)
    del xyz_parts
    rgba = _joined(rgba_parts)
    del rgba_parts
    attributes = {a: _joined(v) for a, v in attr_parts.items() if a in (attr_names or [])}
    del attr_parts  # (held to the end, the chunks' attributes were a second copy through the sort: 20 M LAS points, 300 MB)
    source_scale = finest_scale(scales)
    compact, color_format = storage_format(name, layout, colors, source_scale, bool((rgba[:, 3] == 255).all()))
    cloud = cloud_from_points(
        xyz, rgba, attributes, name=name, skipped=skipped, batch_size=batch_size, bounds=(lo, hi), scale=compact, colors=color_format
    )
    cloud.source_scale = source_scale
    cloud.source_color_bits = source_color_bits(color_bits)
    return cloud


def _per_point(values: np.ndarray) -> str:
    k = int(np.prod(values.shape[1:]))
    return "1 value" if k == 1 and values.ndim == 1 else f"{k} values"


def _joined(parts: list[np.ndarray]) -> np.ndarray:
    """The chunks' arrays as one (written once: small pages, core/pages.py)."""
    if len(parts) == 1:
        return parts[0]
    out = pages.empty((sum(len(p) for p in parts), *parts[0].shape[1:]), np.result_type(*parts))  # numpy's dtype for them
    return np.concatenate(parts, out=out)


def check_valid_count(name: str, valid: int, skipped: int, from_files: bool = False) -> None:
    """No valid point is an error; invalid points skipped, a warning (``build_cloud``'s rule, and
    the chunked build's). ``from_files``: the points were read from the files ``name`` names; none
    read at all (each skipped as empty) is "no file holds any point", gp.open's words, not the
    NaN or absurd positions' "no valid points" (convert and tile said that)."""
    if from_files and valid == skipped == 0:
        raise EmptyCloudError(f"{name}: no file holds any point")
    if valid == 0:
        detail = f" ({counted(skipped, 'invalid point')}: NaN, inf or beyond ±{MAX_ABS_COORDINATE:g})" if skipped else ""
        raise EmptyCloudError(f"{name}: no valid points{detail}")
    if skipped:
        warn(f"{name}: skipped {counted(skipped, 'invalid point')} (NaN, inf or beyond ±{MAX_ABS_COORDINATE:g})", GigapointWarning)


#: ``build_cloud``'s layouts (its color formats: layout.py's COLOR_FORMATS)
LAYOUTS = ("auto", "words", "compact")


def finest_scale(scales) -> tuple[float, float, float] | None:
    """The finest of the chunks' scales per axis (rounding to it loses nothing any file holds);
    None where any chunk has none. A LAS header's negative scale (a mirrored axis) is its step's size."""
    if scales and all(s is not None for s in scales):
        return tuple(float(v) for v in np.min(np.abs(np.array(scales, np.float64)), axis=0))
    return None


def source_color_bits(bits) -> int | None:
    """The chunks' ``color_bits`` as one cloud's: 16 where any chunk's colours were 16-bit (a file
    that turned out 16-bit after a dark start among them), 8 where every chunk's were 8-bit, None
    where a chunk did not say."""
    if 16 in bits:
        return 16
    return 8 if bits and all(b == 8 for b in bits) else None


def storage_format(name: str, layout: str, colors: str, source_scale, opaque: bool):
    """(the compact layout's grid or None: three words, the colors' format: "rgba", "rgb565",
    "palette" or "auto": one of the two before, chosen on the colours by ``encode_colors``) for
    ``build_cloud``'s ``layout`` and ``colors`` options (and the chunked build's, core/chunked.py)."""
    if layout not in LAYOUTS:
        raise InputError(f"{name}: layout must be one of {', '.join(LAYOUTS)}, got {layout!r}")
    if layout == "compact" and source_scale is None:
        raise InputError(f"{name}: the compact layout needs the source's scale (a LAS file's); these chunks have none")
    if colors not in COLOR_FORMATS:
        raise InputError(f"{name}: colors must be one of {', '.join(COLOR_FORMATS)}, got {colors!r}")
    compact = source_scale if layout != "words" else None
    if colors == "rgb565" and not opaque:
        raise InputError(f"{name}: 16-bit colors drop alpha, and some points are not opaque; use colors='rgba'")
    if colors == "auto":  # "auto" stays for opaque compact clouds: cloud_from_points decides on the colours
        return compact, "auto" if compact is not None and opaque else "rgba"
    return compact, colors


def cloud_from_points(
    xyz, rgba, attributes=None, name="cloud", skipped=0, batch_size=BATCH_SIZE, bounds=None, scale=None, colors: str = "rgba"
) -> PointCloud:
    """Build a PointCloud from valid float64 xyz (N, 3) and uint8 rgba (N, 4) (``bounds``: their
    (min, max) if already known). ``scale``: the source grid's step per axis: the compact layout,
    exact on that grid (core/compact.py); None: three u32 words a point. ``colors``: "rgba" (u32),
    "rgb565" (16-bit colors), "palette" (per-block palettes, core/palette.py) or "auto" (the
    palette where it is as faithful as RGB565, else RGB565; opaque colors only)."""
    if batch_size < 1:
        raise InputError(f"{name}: batch size must be >= 1, got {batch_size}")
    lo, hi = bounds if bounds is not None else scan_points(xyz)[1:]
    origin, edge = cube_of(lo, hi)
    order = morton_order(morton_codes(xyz, origin, edge))
    batches = make_batches(len(xyz), batch_size)
    ext = pack = None
    if scale is None:
        low, med, high = quantize(xyz, order, batches)
    else:
        low, ext, pack = compact_positions(xyz, order, batches, scale, origin=lo)
        med = high = None
    rgba = np.ascontiguousarray(rgba, np.uint8)
    color = gather(rgba.view(np.uint32).reshape(-1), order)  # RGBA8 as one u32 a point
    color = encode_colors(color, colors)
    attrs = Attributes({a: gather(v, order) for a, v in (attributes or {}).items()}, packed=True)
    data_bounds = None if scale is None else (np.asarray(lo, np.float64).copy(), np.asarray(hi, np.float64).copy())
    return PointCloud(batches, low, med, high, color, attrs, name=name, skipped=skipped, ext=ext, packing=pack, data_bounds=data_bounds)


def encode_colors(color: np.ndarray, colors: str) -> np.ndarray | PaletteColors:
    """u32 RGBA8 colors (Morton order) held as ``colors`` says: "rgba" as they are, "rgb565",
    "palette", or "auto": the palette if ``choose_palette`` finds it as faithful as RGB565 (the
    quantizer measures both on every block: a few percent of its time), else RGB565."""
    if colors == "rgb565":
        return pack_rgb565(color)
    if colors in ("palette", "auto"):
        sse = block_errors(len(color))
        palettes = quantize_palettes(color, sse=sse)
        return palettes if colors == "palette" or choose_palette(sse) else pack_rgb565(color)
    return color


def from_arrays(xyz, rgb=None, name: str = "arrays", scale=None, colors: str = "auto", **attributes) -> PointCloud:
    """A PointCloud from numpy arrays: float64 (N, 3) positions, (N, 3|4) uint8/uint16/float colors
    (their range judged as a file's: floats of 0..1, 0..255 or 0..65535; ``ColorScaler``).

    ``scale``: the grid the positions were measured on (metres, one value or one per axis, as a
    LAS file's scale): the cloud is then held in the compact layout, exact on that grid
    (core/compact.py); points off it keep 30 bits a batch. ``colors``: how colours are held
    (``build_cloud``: "auto", "rgba", "rgb565" or "palette")."""
    if not isinstance(name, str):
        raise InputError(f"from_arrays: name must be a string, got {name!r}")
    xyz = points_for(xyz, name)
    if scale is not None:
        try:
            s = np.asarray(scale, np.float64).reshape(-1)
        except (TypeError, ValueError):
            s = np.zeros(0)
        if len(s) not in (1, 3) or not np.all(np.isfinite(s) & (s > 0)):
            raise InputError(f"{name}: scale must be a positive number or three, got {scale!r}")
        scale = tuple(float(v) for v in np.broadcast_to(s, (3,)))
    rgba = None if rgb is None else colors_for(rgb, len(xyz), name)  # floats of 0..255 as a file's
    for key, values in attributes.items():
        if isinstance(values, dict):  # attributes={"intensity": ...} printed the whole dict over many lines
            raise InputError(f"{name}: attribute {key!r} is a dict; give attributes as keywords: from_arrays(xyz, rgb, intensity=...) or **{key}")
    try:
        chunk = PointChunk(xyz, rgba, {k: np.asarray(v) for k, v in attributes.items()}, scale=scale)
    except ValueError as exc:
        raise InputError(f"{name}: {exc}") from None
    return build_cloud([chunk], name=name, colors=colors)


__all__ = ["BATCH_DTYPE", "PointCloud", "build_cloud", "cloud_from_points", "from_arrays"]
