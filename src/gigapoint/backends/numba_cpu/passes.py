"""The image-quality passes on the CPU: drivers of the numba kernels in pass_kernels.py.

Each function prepares its kernel's tables (from gigapoint.render.params, shared with the
GPU and the numpy references in gigapoint.render.passes) and scratch buffers, and gives
the reference's image bit for bit; :class:`CpuPasses` is the backend's ``Passes``. Scratch
buffers are reused between frames: callers hold the backend's lock (the renderer does).
"""

from __future__ import annotations

import contextlib
import functools
import threading
from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np

from ...core.compact import full_words, rgb565_table, rgb565_words
from ...core.palette import PaletteColors
from ...core.threads import numba_threads
from ...render.params import (
    AMBIENT,
    DEPTH_GAP,
    DIFFUSE,
    SPECULAR,
    TR_LAYERS,
    edl_scale,
    neighbour_offsets,
    radius_map,
    transmittance_table,
    view_directions,
    window,
)
from ...render.splats import ONE_PIXEL
from . import pass_kernels as kernels
from . import raster


# --- resolve ---------------------------------------------------------------------------------
def resolve(vis: np.ndarray, point_colors: np.ndarray, background) -> tuple[np.ndarray, int]:
    """(u32 RGBA per pixel: the winning point's color or the background, covered pixels)."""
    vis = np.ascontiguousarray(vis).reshape(-1)
    bg = np.array(background, np.uint8).view(np.uint32)[0]
    out = np.empty(vis.shape[0], np.uint32)
    if isinstance(point_colors, PaletteColors):  # per-block palettes (core/palette.py)
        covered = raster.resolve_colors(vis, point_colors.words, bg, out, raster.NO_TABLE, point_colors.palette, point_colors.shift)
    elif point_colors.dtype == np.uint16:  # a compact cloud's 16-bit colors
        covered = raster.resolve_colors(vis, rgb565_words(point_colors), bg, out, rgb565_table(), raster.NO_TABLE, 0)
    else:
        covered = raster.resolve_colors(vis, point_colors, bg, out, raster.NO_TABLE, raster.NO_TABLE, 0)
    return out, int(covered)


# --- eye-dome lighting -----------------------------------------------------------------------
_EDL_SCRATCH: dict = {}


def _edl_scratch(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Reused log-depth and empty-flag buffers: two fresh 8 MB arrays a 1080p frame cost ~2 ms
    of page faults."""
    if n not in _EDL_SCRATCH:
        _EDL_SCRATCH.clear()
        _EDL_SCRATCH[n] = (np.empty(n, np.float32), np.empty(n, np.float32))
    return _EDL_SCRATCH[n]


def eye_dome_lighting(vis: np.ndarray, colors: np.ndarray, width: int, height: int, strength: float = 1.0, radius: float = 1.4) -> np.ndarray:
    """(H*W,) u32 RGBA colors shaded by EDL (vis: (H*W,) u64 visibility buffer)."""
    vis = np.ascontiguousarray(vis).reshape(-1)
    logd, empty = _edl_scratch(vis.shape[0])
    kernels.log_depth(vis, logd, empty)
    out = np.empty_like(colors)
    offsets = neighbour_offsets(radius)
    scale = edl_scale(float(np.float32(strength)), len(offsets))  # the kernel took the strength as float32
    kernels.edl(logd, empty, np.ascontiguousarray(colors).reshape(-1), width, height, offsets, scale, out)
    return out


# --- hole filling ----------------------------------------------------------------------------
def fill_holes(vis: np.ndarray, width: int, height: int, level: int, foveated: bool = False, depth_gap: float = DEPTH_GAP) -> np.ndarray:
    """Filled copy of the (H*W,) u64 visibility buffer (render/passes/holes.py describes the rule)."""
    vis = np.ascontiguousarray(vis).reshape(-1)
    if level <= 0:
        return vis
    offsets, bits, ring = window(level)
    sectors = np.log2(bits).astype(np.int64)
    radii = radius_map(width, height, level, foveated)
    runs, run_start = radius_runs(width, height, level, foveated)
    masks = ring_masks(width, height, level, foveated)
    n_threads = numba.get_num_threads()
    n_bands = min(height, 8 * n_threads)  # bands of rows, each gone down once
    out = np.empty_like(vis)
    gap = np.float32(1.0 / (1.0 + depth_gap))
    _in_bands(kernels.fill_holes, (vis, vis.view(np.float32), width, height, radii, runs, run_start, masks, offsets, bits, sectors, ring, gap, n_bands, out), n_bands, n_threads)
    return out


def _in_bands(kernel, args: tuple, n_bands: int, n_threads: int) -> None:
    """``kernel(*args, band_lo, band_hi)`` over bands 0..n_bands - 1 on ``n_threads`` threads,
    each a contiguous run of them (prange's static split): this one and a pool's (the kernels
    release the GIL). What a prange over the bands did, without numba's parfor compile (3.5x
    longer for ``pass_kernels.fill_holes``). All parts finish before an error of one is raised
    (they write the same buffers)."""
    n_threads = max(1, min(n_threads, n_bands))
    parts = [(t * n_bands // n_threads, (t + 1) * n_bands // n_threads) for t in range(n_threads)]
    others = [_band_pool(n_threads - 1).submit(kernel, *args, lo, hi) for lo, hi in parts[1:]] if n_threads > 1 else []
    try:
        kernel(*args, *parts[0])
    finally:
        for f in others:
            f.exception()  # waits
    for f in others:
        f.result()


_BAND_POOLS: dict[int, ThreadPoolExecutor] = {}
_BAND_POOLS_LOCK = threading.Lock()


def _band_pool(workers: int) -> ThreadPoolExecutor:
    """The threads that run the other bands of ``_in_bands``, one pool per thread count, kept
    between frames (several renderers, e.g. viewer sessions with other thread settings, may
    draw at once: a pool is never shut down under another's frame)."""
    with _BAND_POOLS_LOCK:
        pool = _BAND_POOLS.get(workers)
        if pool is None:
            pool = _BAND_POOLS[workers] = ThreadPoolExecutor(workers, thread_name_prefix="gigapoint-bands")
        return pool


@functools.lru_cache(maxsize=8)
def radius_runs(width: int, height: int, level: int, foveated: bool):
    """(runs (k, 3) int64, start (H+1,) int64): the runs (xa, xb, r) of one window radius r in
    each row of ``radius_map``, row y's are runs[start[y] : start[y + 1]]."""
    radii = radius_map(width, height, level, foveated)
    brk = np.ones((height, width), bool)
    brk[:, 1:] = radii[:, 1:] != radii[:, :-1]
    ys, xa = np.nonzero(brk)
    nxt = np.append(xa[1:], width)
    xb = np.where(np.append(ys[1:], height) == ys, nxt, width)
    runs = np.stack([xa, xb, radii[ys, xa]], axis=1).astype(np.int64)
    start = np.searchsorted(ys, np.arange(height + 1)).astype(np.int64)
    return runs, start


@functools.lru_cache(maxsize=8)
def ring_masks(width: int, height: int, level: int, foveated: bool) -> np.ndarray:
    """(H, level+1, nw) u64 bit rows: bit x of [y, m] set where pixel (x, y)'s window radius >= m."""
    radii = radius_map(width, height, level, foveated)
    nw = (width + 63) // 64
    bits = np.zeros((height, level + 1, nw * 64), bool)
    for m in range(level + 1):
        bits[:, m, :width] = radii >= m
    return np.packbits(bits, axis=-1, bitorder="little").view(np.uint64)


# --- high-quality shading --------------------------------------------------------------------
_HQS_BUFFERS: dict = {}
# corners of a batch's 10-bit grid (every point decodes inside it), homogeneous
_GRID_CORNERS = np.array([[x, y, z, 1.0] for x in (0, 1024) for y in (0, 1024) for z in (0, 1024)])
_ROW_MARGIN = 4  # rows added around a batch's projected corners (float32 rounding of the points)
_RESOLVE_POINTS_PER_ROW = 0.15  # cost of resolving one pixel, in points accumulated (for balancing)


def _accumulators(n_pixels: int):
    """Packed sums and spill sums, zero on entry; ``hqs_shade`` sets them back to zero.
    The spill arrays are calloc'ed: pages no pixel spills into never take memory."""
    bufs = _HQS_BUFFERS.get(n_pixels)
    if bufs is None:
        _HQS_BUFFERS.clear()
        bufs = tuple(np.zeros(n_pixels, t) for t in (np.uint64, np.uint64, np.uint64, np.uint32))
        _HQS_BUFFERS[n_pixels] = bufs
    return bufs


def batch_rows(matrices: np.ndarray, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(first row, last row, rows spanned) each batch's points can land on: its grid cube's 8
    corners projected (float64) with a margin; the whole screen where the cube reaches behind
    the eye. The span (unclipped, >= 1) spreads a batch's points over rows for balancing."""
    p = np.einsum("cj,kij->kci", _GRID_CORNERS, matrices.astype(np.float64))  # (k, 8, 4): x', y', w, depth
    w = p[..., 2]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        y = p[..., 1] / w
        lo = np.floor(y.min(axis=1)) - _ROW_MARGIN
        hi = np.floor(y.max(axis=1)) + _ROW_MARGIN
    whole = ~(np.all(w > 0, axis=1) & np.isfinite(lo) & np.isfinite(hi))
    lo[whole], hi[whole] = 0, height - 1
    span = np.maximum(hi - lo + 1, 1.0)
    return np.clip(lo, -1, height).astype(np.int64), np.clip(hi, -1, height).astype(np.int64), span


def split_rows(row_lo, row_hi, span, counts, width: int, height: int, n_bands: int) -> np.ndarray:
    """bands[0..n_bands]: row bounds giving each band about the same work, counting each batch's
    points spread evenly over the rows it spans plus the resolve of every row."""
    if n_bands == 1:
        return np.array([0, height], np.int64)
    lo = np.clip(row_lo, 0, height)
    hi = np.clip(row_hi + 1, 0, height)
    on = hi > lo
    per_row = counts[on] / span[on]
    density = np.bincount(lo[on], per_row, height + 1) - np.bincount(hi[on], per_row, height + 1)
    cost = np.cumsum(np.cumsum(density)[:height] + width * _RESOLVE_POINTS_PER_ROW)
    inner = np.searchsorted(cost, cost[-1] * np.arange(1, n_bands) / n_bands) + 1
    return np.concatenate([[0], np.minimum(inner, height), [height]]).astype(np.int64)


def _banding(points, sel, width, height, threads, bands, step):
    """(threads, firsts, counts, float32 matrices, row_lo, row_hi, band bounds) of a pass over
    screen bands (``hqs_shade``, ``transparency_shade``) of the selection ``sel``, drawing every
    step-th point: ``bands`` bands (default: one per thread), balanced by ``split_rows``."""
    n_threads = max(1, min(threads or numba.get_num_threads(), numba.config.NUMBA_NUM_THREADS, height))
    batches = points.batches[sel.ids]
    counts = batches["count"].astype(np.int64)
    matrices = np.ascontiguousarray(sel.matrices, np.float32)
    row_lo, row_hi, span = batch_rows(matrices, height)
    bounds = split_rows(row_lo, row_hi, span, counts // step, width, height, max(1, min(int(bands or n_threads), height)))
    return n_threads, batches["first"].astype(np.int64), counts, matrices, row_lo, row_hi, bounds


@contextlib.contextmanager
def _banded_run(n_threads: int, scratch: dict):
    """Run a banded kernel on ``n_threads`` threads; if it fails half-way its ``scratch`` buffers
    are dirty (not back to their empty state): drop them."""
    with numba_threads(n_threads):
        try:
            yield
        except BaseException:
            scratch.clear()
            raise


def hqs_colors(
    points, sel, vis, width, height, near, far, point_colors, fallback, tolerance=0.01, threads=None, splat=None, softness=0.0, step=1,
    bands=None,
) -> np.ndarray:  # fmt: skip
    """(H*W,) u32 mean color of the points within ``tolerance`` of each pixel's closest depth.

    The screen is cut into one band of rows per thread; a thread re-projects only the batches
    that reach its band, sums into one packed u64 per pixel (exact integer sums, spilled into
    wider ones past 32 points a pixel: exact for up to 2^24) and resolves its own rows right
    away. The mean is rounded half up and every pixel is summed by one thread, so the image
    does not depend on the thread count (render/passes/hqs.py: the rule and its reference).

    ``vis`` is the depth pass's (H*W,) visibility buffer; ``fallback`` the colors of pixels
    no point contributed to. ``splat``: (footprint, size, atten) of points larger than a
    pixel; each footprint pixel blends. ``bands``: how many bands of rows the screen is cut
    into (default: one per thread). ``step``: every step-th point of each batch, as the depth
    pass drew them (a point cap: the points it skipped must not blend in)."""
    footprint, size, atten = splat if splat is not None else ONE_PIXEL
    vis = np.ascontiguousarray(vis).reshape(-1)
    step = max(1, int(step))
    n_threads, firsts, counts, matrices, row_lo, row_hi, bands = _banding(points, sel, width, height, threads, bands, step)
    acc, spill_rg, spill_ba, spill_n = _accumulators(width * height)
    out = np.empty(width * height, np.uint32)
    with _banded_run(n_threads, _HQS_BUFFERS):
        kernels.hqs_shade(
            firsts, counts, np.ascontiguousarray(sel.bits, np.int32), matrices, row_lo, row_hi,
            points.low, *full_words(points), width, height, near, far, step, bands, vis.view(np.float32), np.float32(1.0 + tolerance),
            point_colors, np.ascontiguousarray(footprint, np.int32), np.float32(size), np.float32(atten), float(softness),
            acc, spill_rg, spill_ba, spill_n, np.ascontiguousarray(fallback).reshape(-1), out, raster.shape_token(matrices),
        )  # fmt: skip
    return out


# --- transparency ----------------------------------------------------------------------------
_TR_BUFFERS: dict = {}


def _transparency_buffers(n_pixels: int):
    """The k-buffer (EMPTY), its alphas and the sums (zero) between frames; ``transparency_shade``
    restores them."""
    bufs = _TR_BUFFERS.get(n_pixels)
    if bufs is None:
        _TR_BUFFERS.clear()
        kbuf = np.empty((n_pixels, TR_LAYERS), np.uint64)
        raster.fill_empty(kbuf.reshape(-1))
        bufs = _TR_BUFFERS[n_pixels] = (kbuf, np.zeros((n_pixels, TR_LAYERS), np.uint8), np.zeros((n_pixels, 5), np.uint64))
    return bufs


def transparent_colors(
    points, sel, vis, width, height, near, far, point_colors, alphas, fallback, background, threads=None, splat=None, step=1, bands=None
) -> np.ndarray:
    """(H*W,) u32 hybrid transparency composite of the selected batches' points
    (render/passes/transparency.py gives the rule and its reference): ``alphas`` (k, 2) u32 per
    selected batch (8-bit alpha, revealage term: params.batch_alphas), ``fallback`` the colors of
    pixels no point reaches, ``background`` RGBA; ``vis`` is not read (the k-buffer holds the
    fronts). One band of rows per thread, as high-quality shading (``hqs_colors``; ``bands``: how
    many bands instead; more than one a thread was slower in every view measured, the
    re-projection outweighing the smaller working set). ``step``: every step-th point of each
    batch, as the depth pass drew them."""
    footprint, size, atten = splat if splat is not None else ONE_PIXEL
    step = max(1, int(step))
    n_threads, firsts, counts, matrices, row_lo, row_hi, bands = _banding(points, sel, width, height, threads, bands, step)
    alphas = np.ascontiguousarray(alphas, np.uint32).reshape(-1, 2)
    kbuf, kalpha, sums = _transparency_buffers(width * height)
    out = np.empty(width * height, np.uint32)
    with _banded_run(n_threads, _TR_BUFFERS):
        kernels.transparency_shade(
            firsts, counts, np.ascontiguousarray(sel.bits, np.int32), matrices, row_lo, row_hi, points.low, *full_words(points),
            width, height, near, far, step, bands, alphas, np.ascontiguousarray(point_colors, np.uint32),
            np.ascontiguousarray(footprint, np.int32), np.float32(size), np.float32(atten), kbuf, kalpha, sums, transmittance_table(),
            np.array(background, np.int64), np.ascontiguousarray(fallback, np.uint32).reshape(-1), out, raster.shape_token(matrices),
        )  # fmt: skip
    return out


# --- lighting --------------------------------------------------------------------------------
def shade(vis, colors, normals: np.ndarray, camera, shininess: float = 32.0) -> np.ndarray:
    """Blinn-Phong headlight (params: AMBIENT, DIFFUSE, SPECULAR) from float32 (N, 3) normals."""
    out = np.empty_like(colors)
    kernels.blinn_phong(np.ascontiguousarray(vis).reshape(-1), normals, np.ascontiguousarray(colors).reshape(-1), view_directions(camera),
                        np.float32(AMBIENT), np.float32(DIFFUSE), np.float32(SPECULAR), np.float32(shininess), out)  # fmt: skip
    return out


# --- supersampling ---------------------------------------------------------------------------
def downsample(vis: np.ndarray, image: np.ndarray, width: int, height: int, s: int) -> tuple[np.ndarray, np.ndarray]:
    """(closest key, rounded mean RGBA as u32) of each s x s block of a (height*s, width*s) frame."""
    vis_out = np.empty(width * height, np.uint64)
    image_out = np.empty(width * height, np.uint32)
    kernels.downsample(np.ascontiguousarray(vis).reshape(-1), np.ascontiguousarray(image).reshape(-1), width, height, s, vis_out, image_out)
    return vis_out, image_out


class CpuPasses:
    """The ``Passes`` of the CPU backend (gigapoint.render.backend): the functions above."""

    resolve = staticmethod(resolve)
    fill_holes = staticmethod(fill_holes)
    hqs_colors = staticmethod(hqs_colors)
    transparent_colors = staticmethod(transparent_colors)
    shade = staticmethod(shade)
    eye_dome_lighting = staticmethod(eye_dome_lighting)
    downsample = staticmethod(downsample)
