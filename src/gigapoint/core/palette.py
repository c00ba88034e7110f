"""Per-block colour palettes: 8 bits a point of colour (issue #22).

A cloud built with ``colors="palette"`` holds, per block of ``2^shift`` consecutive points
(``PALETTE_SHIFT`` = 13: 8 192 points, in the cloud's Morton order, so a block is as compact
in space as a batch), a palette of ``PALETTE_SIZE`` RGBA8 colours and one u8 index a point:
1 byte a point plus 1024 bytes a block (0.125 byte a point), against RGB565's 2. Blocks are
a power of two, not the batches (10 240 points), so a point's palette is ``i >> shift``: a
batch by ``i // batch_size`` cost the resolve an integer division or a float multiply per
pixel (0.3-0.4 ms of a 1080p frame on one thread; docs/benchmarks.md, #22).

**The quantizer** (``quantize_palettes``) is a greedy variance split (after Wu 1991: median cut
that cuts where the squared error is least), deterministic and without iterations: a block's colours start as
one box; the box with the largest sum of squared errors (SSE) is cut along its channel of
largest variance at the value that leaves the smallest SSE in its two halves (a 256-bin
histogram of that channel gives every cut's SSE in one scan), until 256 boxes or every box
holds one colour. A point's colour is its box's mean (rounded). A block with at most 256
distinct colours therefore keeps every colour exactly; others lose a little (measured in
docs/benchmarks.md, #22: autzen_trim 46.2 dB PSNR against RGB565's 41.7). The split works on a
block's distinct colours (a hash table finds them), weighted by their points: ~8 histogram
passes over ~2 000 colours instead of 8 192 points; blocks are quantized in parallel
(``prange``): 150 M points/s for the 20 M demo town on two shared cores (docs/benchmarks.md).

**The decoder** is ``palette_rgba`` (point ``i``'s RGBA8: its block's palette entry of its
index, the index read from the u32 word ``i >> 2``): the numba resolve kernel
(backends/numba_cpu/raster.py) and ``decode`` here (``rgba32``: every consumer that wants
RGBA8 per point) use it; backends/wgpu/shaders/resolve.wgsl follows it step by step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange

#: colours a block's palette holds (indices are u8)
PALETTE_SIZE = 256
#: a palette serves 2^PALETTE_SHIFT consecutive points (8 192)
PALETTE_SHIFT = 13
#: blocks of at least 256 points: a page of palettes is never larger than the page's points'
#: RGBA8 colours would be (the GPU's page sizes hold)
MIN_SHIFT = 8


@dataclass(eq=False)
class PaletteColors:
    """A cloud's colours as per-block palettes and u8 indices (module doc).

    ``words``: the indices, four a u32 word (point i in byte i & 3 of word i >> 2, little
    endian), the layout the kernels read; ``palette``: u32 RGBA8, ``PALETTE_SIZE`` per block
    (unused entries 0); ``shift``: a block is 2^shift points (the last may hold fewer); ``n``: points."""

    words: np.ndarray
    palette: np.ndarray
    shift: int
    n: int

    def __post_init__(self) -> None:
        if not MIN_SHIFT <= self.shift <= 31:
            raise ValueError(f"palette colours: shift must be {MIN_SHIFT}..31, got {self.shift}")
        n_blocks = -(-self.n // self.block) if self.n else 0
        if self.words.dtype != np.uint32 or len(self.words) != -(-self.n // 4):
            raise ValueError(f"palette colours: {self.n} points need {-(-self.n // 4)} u32 index words, got {len(self.words)} {self.words.dtype}")
        if self.palette.dtype != np.uint32 or len(self.palette) != n_blocks * PALETTE_SIZE:
            raise ValueError(f"palette colours: {n_blocks} blocks need {n_blocks * PALETTE_SIZE} u32 palette entries, got {len(self.palette)}")

    @property
    def block(self) -> int:
        """Points a palette serves."""
        return 1 << self.shift

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
def palette_rgba(words, palette, shift, i):
    """u32 RGBA8 of point ``i`` (u64): entry ``index`` of its block's palette; resolve.wgsl does the same."""
    index = (words[i >> np.uint64(2)] >> np.uint32((i & np.uint64(3)) << np.uint64(3))) & np.uint32(0xFF)
    return palette[((i >> np.uint64(shift)) << np.uint64(8)) + np.uint64(index)]


@njit(parallel=True, cache=True)
def _decode_all(words, palette, shift, out):
    for i in prange(out.shape[0]):
        out[i] = palette_rgba(words, palette, shift, np.uint64(i))


@njit(parallel=True, cache=True)
def _decode_at(words, palette, shift, points, out):
    for k in prange(points.shape[0]):
        out[k] = palette_rgba(words, palette, shift, np.uint64(points[k]))


def decode(colors: PaletteColors, points: np.ndarray | None = None) -> np.ndarray:
    """u32 RGBA8 of every point (``points`` None) or of point indices ``points``."""
    if points is None:
        out = np.empty(colors.n, np.uint32)
        _decode_all(colors.words, colors.palette, colors.shift, out)
        return out
    points = np.ascontiguousarray(points, np.int64).reshape(-1)
    if len(points) and (points.min() < 0 or points.max() >= colors.n):
        raise IndexError(f"palette colours: point index out of range 0..{colors.n - 1}")
    out = np.empty(len(points), np.uint32)
    _decode_at(colors.words, colors.palette, colors.shift, points, out)
    return out


# --- the quantizer ---------------------------------------------------------------------------
@njit(inline="always")
def _channel(c, k):
    return np.int64((c >> np.uint32(8 * k)) & np.uint32(0xFF))


@njit(cache=True)
def _distinct(c, uniq, weight, of_point):
    """The distinct colours of ``c`` (into ``uniq``, first seen first), how many points hold each
    (``weight``) and each point's (``of_point``); returns their number. An open-addressing hash
    table: a block of 8 192 points of aerial-photo colours holds ~2 000 distinct ones, and the
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


@njit(inline="always")
def _rgb565_error(v, bits):
    """Squared error of channel value ``v`` (0..255) stored in ``bits`` (5 or 6) bits the way
    compact.pack_rgb565 rounds it and rgb565_rgba widens it back (bit replication)."""
    top = (1 << bits) - 1
    q = (v * top + 127) // 255
    d = ((q << (8 - bits)) | (q >> (2 * bits - 8))) - v
    return d * d


@njit(cache=True)
def _quantize_block(c, index, palette, errors):
    """Palette (``palette``: PALETTE_SIZE u32, written) and u8 indices (``index``) of the u32
    RGBA8 colours ``c`` of one block: the module doc's variance split, over its distinct colours
    weighted by their points. ``errors`` (2 int64, written): the block's summed squared error over
    R, G and B of its palette colours and of RGB565 (``choose_palette`` compares them)."""
    m = c.shape[0]
    for b in range(PALETTE_SIZE):  # loops, not slice assignments: those compile numpy's broadcasting (~0.1 s each)
        palette[b] = 0
    errors[0] = 0
    errors[1] = 0
    if m == 0:
        return
    uniq = np.empty(m, np.uint32)
    weight = np.empty(m, np.int64)
    of_point = np.empty(m, np.int32)
    d = _distinct(c, uniq, weight, of_point)
    perm = np.empty(d, np.int32)
    for u in range(d):
        perm[u] = u
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
    # the errors, over the distinct colours (weighted): ~2 000 a block, not 8 192 points
    for u in range(d):
        col = uniq[u]
        entry = palette[box_of[u]]
        w = weight[u]
        for k in range(3):
            diff = _channel(entry, k) - _channel(col, k)
            errors[0] += w * diff * diff
        errors[1] += w * (_rgb565_error(_channel(col, 0), 5) + _rgb565_error(_channel(col, 1), 6) + _rgb565_error(_channel(col, 2), 5))


@njit(parallel=True, cache=True)
def _quantize_all(c, block, index, palette, sse):
    n = c.shape[0]
    for b in prange((n + block - 1) // block):
        s = b * block
        e = min(s + block, n)
        _quantize_block(c[s:e], index[s:e], palette[b * PALETTE_SIZE : (b + 1) * PALETTE_SIZE], sse[b])


def quantize_palettes(color: np.ndarray, shift: int = PALETTE_SHIFT, sse: np.ndarray | None = None) -> PaletteColors:
    """Per-block palettes of u32 RGBA8 colours (blocks of 2^shift consecutive points).
    ``sse``: int64 (blocks, 2), filled with each block's squared error of the palette and of
    RGB565 (``choose_palette``)."""
    c = np.ascontiguousarray(color, np.uint32)
    n = len(c)
    out = empty_palettes(n, shift)
    if sse is None:
        sse = block_errors(n, shift)
    if n:
        _quantize_all(c, out.block, out.words.view(np.uint8)[:n], out.palette, sse)
    return out


def block_errors(n: int, shift: int = PALETTE_SHIFT) -> np.ndarray:
    """Zeroed int64 (blocks, 2) for the quantizer's per-block errors of ``n`` points."""
    return np.zeros((-(-n >> shift), 2), np.int64)


def choose_palette(sse: np.ndarray) -> bool:
    """``colors="auto"``'s rule: the palette where its squared error over every point's R, G and
    B (its PSNR) is at most RGB565's on the same colours. A cloud-wide sum, so one format holds
    every point. On aerial-photo colours the palette wins (autzen_trim 46.2 against 41.7 dB, the
    demo town 59.1); on noisy colours of thousands of distinct values a block it loses (a ramp
    with noise of 6 levels: 36.9 dB), and RGB565 keeps its bound of 4/255 a channel."""
    total = np.asarray(sse, np.int64).reshape(-1, 2).sum(axis=0)
    return bool(total[0] <= total[1])


def empty_palettes(n: int, shift: int = PALETTE_SHIFT) -> PaletteColors:
    """PaletteColors of ``n`` points, every index and entry 0 (``palette_into`` fills them)."""
    if not MIN_SHIFT <= shift <= 31:
        raise ValueError(f"palette colours: shift must be {MIN_SHIFT}..31, got {shift}")
    return PaletteColors(np.zeros(-(-n // 4), np.uint32), np.zeros(-(-n >> shift) * PALETTE_SIZE, np.uint32), int(shift), int(n))


def palette_into(out: PaletteColors, first: int, color: np.ndarray, sse: np.ndarray | None = None) -> None:
    """Quantize the u32 colours of points ``first``.. (whole blocks: ``first`` a multiple of
    ``out.block``, and the count too unless they reach the end) into ``out``'s arrays (the
    chunked build, partition by partition); their blocks' errors into ``sse`` (``block_errors(out.n)``)."""
    end = first + len(color)
    if first % out.block or end > out.n or (end % out.block and end != out.n):
        raise ValueError(f"palette colours: points {first}..{end} are not whole blocks of {out.block}")
    c = np.ascontiguousarray(color, np.uint32)
    if len(c):
        b0 = first >> out.shift
        nb = -(-len(c) >> out.shift)
        pal = out.palette[b0 * PALETTE_SIZE : (b0 + nb) * PALETTE_SIZE]
        errors = block_errors(len(c), out.shift) if sse is None else sse[b0 : b0 + nb]
        _quantize_all(c, out.block, out.words.view(np.uint8)[first:end], pal, errors)


__all__ = ["PALETTE_SHIFT", "PALETTE_SIZE", "PaletteColors", "block_errors", "choose_palette", "decode", "empty_palettes", "palette_into", "palette_rgba", "quantize_palettes"]
