"""Per-batch colour palettes: 8 bits a point of colour (issue #22).

A compact cloud built with ``colors="palette"`` holds, per batch of ``stride`` consecutive
points (a PointCloud's batches: ``make_batches`` cuts them every ``batch_size`` points), a
palette of ``PALETTE_SIZE`` RGBA8 colours and one u8 index a point: 1 byte a point plus
1024 bytes a batch (0.1 byte a point at 10 240-point batches), against RGB565's 2.

**The quantizer** (``quantize_palettes``) is a greedy variance split (after Wu 1991: median cut
that cuts where the squared error is least), deterministic and without iterations: a batch's colours start as
one box; the box with the largest sum of squared errors (SSE) is cut along its channel of
largest variance at the value that leaves the smallest SSE in its two halves (a 256-bin
histogram of that channel gives every cut's SSE in one scan), until 256 boxes or every box
holds one colour. A point's colour is its box's mean (rounded). A batch with at most 256
distinct colours therefore keeps every colour exactly; others lose a little (measured in
docs/benchmarks.md, #22: autzen_trim 45.7 dB PSNR against RGB565's 41.7). The split works on a
batch's distinct colours (a hash table finds them), weighted by their points: ~8 histogram
passes over ~2 000 colours instead of 10 240 points; batches are quantized in parallel
(``prange``): 76 M points/s for the 20 M demo town on two shared cores, autzen_trim's
11 batches 30 M points/s on one.

**The decoder** is ``palette_rgba`` (point ``i``'s RGBA8: its batch's palette entry of its
index, the index read from the u32 word ``i >> 2``): the numba resolve kernel
(backends/numba_cpu/raster.py) and ``decode`` here (``rgba32``: every consumer that wants
RGBA8 per point) use it; backends/wgpu/shaders/resolve.wgsl follows it step by step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange

#: colours a batch's palette holds (indices are u8)
PALETTE_SIZE = 256


@dataclass(eq=False)
class PaletteColors:
    """A cloud's colours as per-batch palettes and u8 indices (module doc).

    ``words``: the indices, four a u32 word (point i in byte i & 3 of word i >> 2, little
    endian), the layout the kernels read; ``palette``: u32 RGBA8, ``PALETTE_SIZE`` per batch
    (unused entries 0); ``stride``: points per batch (the last may hold fewer); ``n``: points."""

    words: np.ndarray
    palette: np.ndarray
    stride: int
    n: int

    def __post_init__(self) -> None:
        n_batches = -(-self.n // self.stride) if self.n else 0
        if self.words.dtype != np.uint32 or len(self.words) != -(-self.n // 4):
            raise ValueError(f"palette colours: {self.n} points need {-(-self.n // 4)} u32 index words, got {len(self.words)} {self.words.dtype}")
        if self.palette.dtype != np.uint32 or len(self.palette) != n_batches * PALETTE_SIZE:
            raise ValueError(f"palette colours: {n_batches} batches need {n_batches * PALETTE_SIZE} u32 palette entries, got {len(self.palette)}")

    @property
    def index(self) -> np.ndarray:
        """u8 palette index of every point (a view)."""
        return self.words.view(np.uint8)[: self.n]

    @property
    def nbytes(self) -> int:
        return int(self.words.nbytes + self.palette.nbytes)

    def __len__(self) -> int:
        return self.n

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """The arrays held (GPU copies are made of these)."""
        return self.words, self.palette


# --- the decoder -----------------------------------------------------------------------------
@njit(inline="always")
def batch_of(i, stride):
    """``i // stride`` for u64 ``i`` < 2^51, by a float64 multiply (an integer division per pixel
    tripled the resolve's time): (i + 0.5) / stride lies at least 0.5 / stride from an integer,
    and the product's rounding error is below 2^-52 (i + 0.5) / stride, far less."""
    return np.uint64((np.float64(np.int64(i)) + 0.5) * (1.0 / np.float64(stride)))


@njit(inline="always")
def palette_rgba(words, palette, stride, i):
    """u32 RGBA8 of point ``i`` (u64): entry ``index`` of its batch's palette; resolve.wgsl does the same."""
    index = (words[i >> np.uint64(2)] >> np.uint32((i & np.uint64(3)) << np.uint64(3))) & np.uint32(0xFF)
    return palette[batch_of(i, stride) * np.uint64(PALETTE_SIZE) + np.uint64(index)]


@njit(parallel=True, cache=True)
def _decode_all(words, palette, stride, out):
    for i in prange(out.shape[0]):
        out[i] = palette_rgba(words, palette, stride, np.uint64(i))


@njit(parallel=True, cache=True)
def _decode_at(words, palette, stride, points, out):
    for k in prange(points.shape[0]):
        out[k] = palette_rgba(words, palette, stride, np.uint64(points[k]))


def decode(colors: PaletteColors, points: np.ndarray | None = None) -> np.ndarray:
    """u32 RGBA8 of every point (``points`` None) or of point indices ``points``."""
    if points is None:
        out = np.empty(colors.n, np.uint32)
        _decode_all(colors.words, colors.palette, colors.stride, out)
        return out
    points = np.ascontiguousarray(points, np.int64).reshape(-1)
    if len(points) and (points.min() < 0 or points.max() >= colors.n):
        raise IndexError(f"palette colours: point index out of range 0..{colors.n - 1}")
    out = np.empty(len(points), np.uint32)
    _decode_at(colors.words, colors.palette, colors.stride, points, out)
    return out


# --- the quantizer ---------------------------------------------------------------------------
@njit(inline="always")
def _channel(c, k):
    return np.int64((c >> np.uint32(8 * k)) & np.uint32(0xFF))


@njit(cache=True)
def _distinct(c, uniq, weight, of_point):
    """The distinct colours of ``c`` (into ``uniq``, first seen first), how many points hold each
    (``weight``) and each point's (``of_point``); returns their number. An open-addressing hash
    table: a batch of 10 240 points of aerial-photo colours holds ~2 000 distinct ones, and the
    split's passes then go over those."""
    m = c.shape[0]
    size = 1
    while size < 2 * m:
        size <<= 1
    table = np.full(size, -1, np.int32)
    mask = np.uint32(size - 1)
    d = 0
    for p in range(m):
        col = c[p]
        h = (col * np.uint32(2654435761)) >> np.uint32(7)
        while True:
            slot = h & mask
            u = table[slot]
            if u < 0:
                table[slot] = d
                uniq[d] = col
                weight[d] = 1
                of_point[p] = d
                d += 1
                break
            if uniq[u] == col:
                weight[u] += 1
                of_point[p] = u
                break
            h += np.uint32(1)
    return d


@njit(cache=True)
def _quantize_batch(c, index, palette):
    """Palette (``palette``: PALETTE_SIZE u32, written) and u8 indices (``index``) of the u32
    RGBA8 colours ``c`` of one batch: the module doc's variance split, over its distinct colours
    weighted by their points."""
    m = c.shape[0]
    palette[:] = 0
    if m == 0:
        return
    uniq = np.empty(m, np.uint32)
    weight = np.empty(m, np.int64)
    of_point = np.empty(m, np.int32)
    d = _distinct(c, uniq, weight, of_point)
    perm = np.arange(d).astype(np.int32)
    start = np.zeros(PALETTE_SIZE, np.int64)
    end = np.zeros(PALETTE_SIZE, np.int64)
    bn = np.zeros(PALETTE_SIZE, np.int64)  # per box: points
    bs = np.zeros((PALETTE_SIZE, 4), np.int64)  # per box: sum of each channel
    bq = np.zeros((PALETTE_SIZE, 4), np.int64)  # per box: sum of squares of each channel
    sse = np.zeros(PALETTE_SIZE)
    hn = np.zeros(256, np.int64)
    hs = np.zeros((256, 4), np.int64)
    hq = np.zeros((256, 4), np.int64)
    ls = np.zeros(4, np.int64)
    for u in range(d):
        w = weight[u]
        for k in range(4):
            v = _channel(uniq[u], k)
            bs[0, k] += w * v
            bq[0, k] += w * v * v
    end[0] = d
    bn[0] = m
    err = 0.0
    for k in range(4):
        err += bq[0, k] - bs[0, k] * bs[0, k] / m
    sse[0] = err
    boxes = 1
    while boxes < PALETTE_SIZE:
        b = 0
        for j in range(1, boxes):  # the first of the largest: deterministic
            if sse[j] > sse[b]:
                b = j
        if sse[b] <= 0.0:
            break
        s0, e0, n = start[b], end[b], bn[b]
        axis = 0
        best_var = -1.0
        for k in range(4):
            var = bq[b, k] - bs[b, k] * bs[b, k] / n
            if var > best_var:
                best_var = var
                axis = k
        lo, hi = 255, 0
        for j in range(s0, e0):
            col = uniq[perm[j]]
            w = weight[perm[j]]
            v = _channel(col, axis)
            lo = min(lo, v)
            hi = max(hi, v)
            hn[v] += w
            for k in range(4):
                x = _channel(col, k)
                hs[v, k] += w * x
                hq[v, k] += w * x * x
        # the cut: left = values <= cut; every cut's SSE from running sums (two divisions a value)
        ln = 0
        lq = 0
        tq = 0
        for k in range(4):
            ls[k] = 0
            tq += bq[b, k]
        best = np.inf
        cut = lo
        best_left = 0.0
        best_right = 0.0
        for v in range(lo, hi):
            if hn[v] == 0:
                continue
            ln += hn[v]
            s2l = 0
            s2r = 0
            for k in range(4):
                ls[k] += hs[v, k]
                lq += hq[v, k]
                rs = bs[b, k] - ls[k]
                s2l += ls[k] * ls[k]
                s2r += rs * rs
            el = lq - s2l / ln
            er = (tq - lq) - s2r / (n - ln)
            if el + er < best:
                best = el + er
                cut = v
                best_left = el
                best_right = er
        # the new box's sums (the right half), the left's by difference; histogram cleared
        rn = 0
        for v in range(lo, hi + 1):
            if v > cut:
                rn += hn[v]
                for k in range(4):
                    bs[boxes, k] += hs[v, k]
                    bq[boxes, k] += hq[v, k]
            hn[v] = 0
            for k in range(4):
                hs[v, k] = 0
                hq[v, k] = 0
        for k in range(4):
            bs[b, k] -= bs[boxes, k]
            bq[b, k] -= bq[boxes, k]
        bn[boxes] = rn
        bn[b] = n - rn
        # partition perm[s0:e0]: values <= cut first
        i, j = s0, e0 - 1
        while i <= j:
            if _channel(uniq[perm[i]], axis) <= cut:
                i += 1
            else:
                t = perm[i]
                perm[i] = perm[j]
                perm[j] = t
                j -= 1
        start[boxes], end[boxes] = i, e0
        end[b] = i
        sse[b] = max(best_left, 0.0)
        sse[boxes] = max(best_right, 0.0)
        boxes += 1
    box_of = np.empty(d, np.uint8)
    for b in range(boxes):
        n = bn[b]
        rgba = np.uint32(0)
        for k in range(4):
            mean = (2 * bs[b, k] + n) // (2 * n)  # rounded half up
            rgba |= np.uint32(mean) << np.uint32(8 * k)
        palette[b] = rgba
        for j in range(start[b], end[b]):
            box_of[perm[j]] = np.uint8(b)
    for p in range(m):
        index[p] = box_of[of_point[p]]


@njit(parallel=True, cache=True)
def _quantize_all(c, stride, index, palette):
    n = c.shape[0]
    for b in prange((n + stride - 1) // stride):
        s = b * stride
        e = min(s + stride, n)
        _quantize_batch(c[s:e], index[s:e], palette[b * PALETTE_SIZE : (b + 1) * PALETTE_SIZE])


def quantize_palettes(color: np.ndarray, stride: int) -> PaletteColors:
    """Per-batch palettes of u32 RGBA8 colours (batches of ``stride`` consecutive points)."""
    c = np.ascontiguousarray(color, np.uint32)
    n = len(c)
    if stride < 1:
        raise ValueError(f"palette colours: stride must be >= 1, got {stride}")
    words = np.zeros(-(-n // 4), np.uint32)
    palette = np.zeros(-(-n // stride) * PALETTE_SIZE, np.uint32)
    if n:
        _quantize_all(c, int(stride), words.view(np.uint8)[:n], palette)
    return PaletteColors(words, palette, int(stride), n)


def palette_into(out: PaletteColors, first: int, color: np.ndarray) -> None:
    """Quantize the u32 colours of points ``first``.. (whole batches: ``first`` a multiple of
    ``out.stride``) into ``out``'s arrays (the chunked build, partition by partition)."""
    if first % out.stride or first + len(color) > out.n:
        raise ValueError(f"palette colours: points {first}..{first + len(color)} are not whole batches of {out.stride}")
    c = np.ascontiguousarray(color, np.uint32)
    if len(c):
        b0 = first // out.stride
        nb = -(-len(c) // out.stride)
        _quantize_all(c, out.stride, out.words.view(np.uint8)[first : first + len(c)], out.palette[b0 * PALETTE_SIZE : (b0 + nb) * PALETTE_SIZE])


__all__ = ["PALETTE_SIZE", "PaletteColors", "decode", "palette_into", "palette_rgba", "quantize_palettes"]
