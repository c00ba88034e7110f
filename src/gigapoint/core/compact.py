"""The compact point layout: batch-relative positions with the bits the source really holds.

Todoran (2019) stores a point relative to its brick in as few bits as the brick's extent
needs; a LAS file at 0.01 m needs 10 bits an axis inside a 10 m batch, not 30. Here a batch
of a cloud whose source grid is known (``source_scale``: a LAS file's scale) gets a box
aligned to that grid, 2^B source steps wide per axis (B >= 10: as many bits as the batch's
extent over the scale needs), its points at the centres of the cells of a 2^B grid, so:

- the **low word** (u32, 10-10-10: bits 20-29 of X30) is exactly today's low word, and a
  batch drawn at 10-bit precision reads nothing else (4 bytes a point);
- the B - 10 bits per axis below it (``e``: 0..19) are the point's **extension**, packed
  back to back in a per-batch bit stream (``ext``, u64 words), e_x + e_y + e_z bits a
  point; the bits under those are implied: the half-cell bit (1 << (19 - e)) and zeros.

The medium and high words decode from them by integer shifts (``tail_words``), so a compact
batch and the same batch expanded to three words give the same float32 grid coordinates in
the same operation order (layout.py contract): images are identical bit for bit. Positions
are exact at the source's scale: the decoded cell centre is the source coordinate (to
float64 rounding, far below the scale). The half-cell bit makes X30 that centre already, so
the float64 decoder (``quantize.dequantize``) adds no half of a 30-bit cell here
(``centre_half``: 0, where floor-quantized words take 0.5); with 0.5 every point sat
scale * 2^(B - 31) past its source value (3e-7 ft on autzen's 2^16-step batches, a quarter
of a step 2^29 steps wide). The renderers' float32 decoding keeps the 0.5 of both layouts:
2^-31 of a batch's size is below float32's resolution of it.

A batch whose points are not on the cloud's grid (files of one scene with other offsets)
or whose extent needs more than 29 bits an axis is stored *wide*: today's tight box and
30-bit quantization, its medium and high words as e = 20 bits an axis (no half bit) in the
same stream, 60 bits a point, within half a 30-bit cell of the source: under half a step
while the batch spans under 2^30 steps (rounding to the grid gives the source back); a wider
one (a LAS file's int32 grid spans up to 2^32 steps: far outliers) is up to 4 steps a cell, 2 off.

Per batch a ``PACK_DTYPE`` record (core/layout.py) holds the stream's first u64 word and the
three widths. Decoding is one function per side: ``tail_words`` here (the numba kernels and
the numpy reference use it) and ``compact_words`` in backends/wgpu/shaders/common.wgsl,
which follows it step by step.
"""

from __future__ import annotations

import functools
import weakref

import numpy as np
from llvmlite import ir
from numba import njit, prange, types
from numba.extending import intrinsic

from .layout import COMPACT_MIN_BITS, EXT_FULL_BITS, PACK_DTYPE, WORD_BITS, WORD_MASK
from .palette import PaletteColors
from .palette import decode as decode_palette
from .quantize import gather_batch

_SCALE30 = float(1 << 30)
_MAX30 = (1 << 30) - 1
_U1 = np.uint64(1)
_M20 = (1 << 20) - 1
#: arrays up to this many colors are packed and unpacked by numpy (as cloud.py's NUMPY_MAX)
NUMPY_MAX = 1 << 20
#: a batch's points must sit on the grid within this fraction of a step (float64 rounding of
#: UTM-sized values is ~1e-8 of a centimetre step)
GRID_TOLERANCE = 1e-4
#: ... and within this share of their own size (at least 1): float64 rounding is ~2e-16 of it.
#: A step far larger than the points' spread (a scale of 1e4 given for points a metre apart)
#: put them all within GRID_TOLERANCE of one grid node, and they were drawn there, metres off.
GRID_SNAP = 1e-9


@njit(inline="always")
def on_the_grid(x, r, q, step, tolerance) -> bool:
    """Whether coordinate ``x``, ``r`` steps from the grid's origin and rounded to node ``q``,
    is on the grid: within ``tolerance`` steps of the node, and moved no further than float64
    rounding could have put it there (``GRID_SNAP``)."""
    d = abs(r - q)
    return d <= tolerance and d * step <= GRID_SNAP * max(abs(x), 1.0)


def centre_half(code=None) -> np.ndarray:
    """Per axis, what ``quantize.dequantize`` adds to 30-bit words of a batch with layout
    ``code`` (None: the three-word layout) to reach its points: 0.5, the centre of the 30-bit
    cell floor quantization put a point in, on a wide axis (e = 20) or without a layout; 0 on
    a grid-aligned one, whose words hold the source cell's centre already (the half-cell bit)."""
    if code is None:
        return np.full(3, 0.5)
    c = int(code)
    return np.array([0.5 if (c >> (8 * a)) & 0xFF == EXT_FULL_BITS else 0.0 for a in range(3)])


def pack_code(ex: int, ey: int, ez: int) -> int:
    """The per-batch layout word: e_x | e_y << 8 | e_z << 16 (each 0..20)."""
    return int(ex) | int(ey) << 8 | int(ez) << 16


@njit(inline="always")
def _bits_of(code, axis):
    return np.int64((code >> np.uint32(8 * axis)) & np.uint32(0xFF))


@njit
def read_ext(ext, word0, t, j):
    """The t (<= 60) bits of point j of a batch whose stream starts at u64 word ``word0``."""
    if t == 0:
        return np.uint64(0)
    p = np.uint64(j) * np.uint64(t)
    k = np.uint64(word0) + (p >> np.uint64(6))  # unsigned: no negative-index wraparound
    s = p & np.uint64(63)
    lo = ext[k] >> s
    hi = (ext[k + _U1] << (np.uint64(63) - s)) << _U1  # 64 - s without shifting by 64 when s = 0
    return lo | hi


@njit
def write_ext(ext, word0, t, j, v):
    """Point j's t (1..60) bits of a batch whose stream starts at u64 word ``word0`` set to
    ``v`` (its t bits; the neighbours' bits kept): ``read_ext``'s inverse, for rewriting a
    stream in place (builders write streams once, into zeroed words, by or-ing)."""
    p = np.uint64(j) * np.uint64(t)
    k = np.uint64(word0) + (p >> np.uint64(6))
    s = p & np.uint64(63)
    mask = (_U1 << np.uint64(t)) - _U1
    ext[k] = (ext[k] & ~(mask << s)) | (v << s)
    if s + np.uint64(t) > np.uint64(64):
        r = np.uint64(64) - s
        ext[k + _U1] = (ext[k + _U1] & ~(mask >> r)) | (v >> r)


#: widest field the one-load reader takes: a u32 read at the field's byte holds 32 - 7 bits past it
ONE_LOAD_BITS = 25


@intrinsic
def _u32_at_byte(typingctx, words, byte):
    """The u32 at byte offset ``byte`` of a u64 array (unaligned; x86 and little-endian ARM
    number a stream's bits the same way in bytes as in u64 words)."""
    if not (isinstance(words, types.Array) and words.dtype == types.uint64 and words.layout == "C"):
        return None
    sig = types.uint32(words, types.uint64)

    def codegen(context, builder, signature, args):
        array, offset = args
        data = context.make_array(signature.args[0])(context, builder, array).data
        ptr = builder.gep(builder.bitcast(data, ir.IntType(8).as_pointer()), [offset])
        return builder.load(builder.bitcast(ptr, ir.IntType(32).as_pointer()), align=1)

    return sig, codegen


@njit
def tail_constants(code):
    """Per axis of a batch with layout ``code``: (position of its bits in a point's stream bits,
    their mask, the shift that puts them under the low word's bits, the half-cell bit), and the
    bits a point holds: the loop-invariant part of ``tail_words``."""
    ex = np.uint64(code & np.uint32(0xFF))
    ey = np.uint64((code >> np.uint32(8)) & np.uint32(0xFF))
    ez = np.uint64((code >> np.uint32(16)) & np.uint32(0xFF))
    hx = _U1 << (np.uint64(19) - ex) if ex < 20 else np.uint64(0)
    hy = _U1 << (np.uint64(19) - ey) if ey < 20 else np.uint64(0)
    hz = _U1 << (np.uint64(19) - ez) if ez < 20 else np.uint64(0)
    c20 = np.uint64(20)
    return (
        (np.uint64(0), (_U1 << ex) - _U1, c20 - ex, hx),
        (ex, (_U1 << ey) - _U1, c20 - ey, hy),
        (ex + ey, (_U1 << ez) - _U1, c20 - ez, hz),
        np.int64(ex + ey + ez),
    )


@njit(inline="always")
def _tail(v, axis):
    """The 20 bits under the low word of one axis: (f << (20 - e)) | half, f the axis's e bits."""
    pos, mask, shift, half = axis
    return (((v >> pos) & mask) << shift) | half


@njit(inline="always")
def _pack_tails(tx, ty, tz):
    """(medium, high) words of three axes' 20-bit tails."""
    m10 = np.uint64(WORD_MASK)
    c10 = np.uint64(10)
    c20 = np.uint64(20)
    med = ((tx >> c10) & m10) | (((ty >> c10) & m10) << c10) | (((tz >> c10) & m10) << c20)
    high = (tx & m10) | ((ty & m10) << c10) | ((tz & m10) << c20)
    return np.uint32(med), np.uint32(high)


@njit
def tail_words(v, code):
    """(medium, high) u32 words of a point from its extension bits ``v`` and the batch's
    layout ``code``: per axis the 20 bits under the low word are (f << (20 - e)) | half, with
    f the axis's e bits and half = 1 << (19 - e) (none for e = 20, a wide batch). The decoder
    of the layout; ``expand_tails`` is the same steps over a batch, WGSL ``compact_words``
    the same on the GPU."""
    ax, ay, az, _ = tail_constants(code)
    return _pack_tails(_tail(v, ax), _tail(v, ay), _tail(v, az))


@njit
def wide_bits(v, code):
    """A point's extension bits ``v`` of a batch with layout ``code`` as a wide batch holds them:
    each axis's 20 bits under the low word (``tail_words``' before they are split into the
    medium and high words), x y z back to back: 60 bits."""
    ax, ay, az, _ = tail_constants(code)
    c20 = np.uint64(20)
    return _tail(v, ax) | (_tail(v, ay) << c20) | (_tail(v, az) << (c20 + c20))


@njit
def code_bits(code):
    """Bits a point of a batch with layout ``code`` holds in the stream."""
    return _bits_of(code, 0) + _bits_of(code, 1) + _bits_of(code, 2)


@njit(error_model="numpy")
def expand_tails(ext, word0, code, start, n, step, med, high, bits):
    """Medium and high words of points start, start + step, ... (n of them) of one compact
    batch into med[:n], high[:n] (the CPU kernel's phase-1 input at 20 and 30 bits); ``bits``:
    u64 scratch of n. Two loops: the stream reads (a gather) and the decoding (tail_words's
    steps with the batch's constants hoisted: it vectorises), 1.1 instead of 2.7 ns a point.
    Fields of up to ONE_LOAD_BITS bits (e_x + e_y + e_z: a batch up to 2^18 source steps
    wide on every axis, 2.6 km at 1 cm) are read by one unaligned u32 load at their first
    byte instead of ``read_ext``'s two u64 loads, into u32 scratch: the gather moves a quarter
    of the bytes (``stream_words``'s spare word keeps the load inside the stream), and decoded
    by ``_decode_tails``: 0.53-0.57 instead of 0.97 ns a point. Few paths on purpose: each loop
    is ~0.1 s more of the first render's compile (issue #17)."""
    ax, ay, az, t = tail_constants(code)
    if t > ONE_LOAD_BITS:  # a wide batch (or one over 2^18 steps): two loads, all of tail_words's steps
        for j in range(n):
            bits[j] = read_ext(ext, word0, t, start + j * step)
        for j in range(n):
            v = bits[j]
            med[j], high[j] = _pack_tails(_tail(v, ax), _tail(v, ay), _tail(v, az))
        return
    fields = bits[:n].view(np.uint32)
    if t == 0:  # no stream (and no words of its own to read)
        for j in range(n):
            fields[j] = 0
    else:
        at = np.uint64(word0) * np.uint64(8)
        width = np.uint64(t)
        for j in range(n):
            p = np.uint64(start + j * step) * width
            fields[j] = _u32_at_byte(ext, at + (p >> np.uint64(3))) >> np.uint32(p & np.uint64(7))
    _decode_tails(fields, n, ax, ay, az, med, high)


@njit(inline="always")
def _decode_tails(fields, n, ax, ay, az, med, high):
    """``expand_tails``'s second loop: u32 fields to medium and high words.
    Where every axis has e <= 9 extension bits (shift = 20 - e >= 11: most batches of a survey)
    a tail's bits and its half bit all lie above its 10 high-word bits, so the high word is 0 and
    the medium word is each axis's bits shifted into place plus the half bits: the same values
    as ``_pack_tails`` in 5 operations an axis fewer (0.21 instead of 0.34 ns a point)."""
    c10 = np.uint64(10)
    if ax[2] > c10 and ay[2] > c10 and az[2] > c10:
        halves = (ax[3] >> c10) | ((ay[3] >> c10) << c10) | ((az[3] >> c10) << np.uint64(20))
        for j in range(n):
            v = np.uint64(fields[j])
            med[j] = np.uint32(_med_bits(v, ax, 0) | _med_bits(v, ay, 1) | _med_bits(v, az, 2) | halves)
            high[j] = 0
        return
    for j in range(n):
        v = np.uint64(fields[j])
        med[j], high[j] = _pack_tails(_tail(v, ax), _tail(v, ay), _tail(v, az))


@njit(inline="always")
def _med_bits(v, axis, a):
    """Axis ``a``'s e bits of ``v`` where they go in the medium word (an axis with e <= 9)."""
    pos, mask, shift, _ = axis
    return ((v >> pos) & mask) << (shift - np.uint64(10) + np.uint64(10 * a))


@njit(parallel=True, cache=True)
def _expand_all(ext, firsts, counts, word0s, codes, med, high):
    for b in prange(firsts.shape[0]):
        f = firsts[b]
        n = counts[b]
        expand_tails(ext, word0s[b], codes[b], np.int64(0), n, np.int64(1), med[f : f + n], high[f : f + n], np.empty(n, np.uint64))


#: the last compact buffers ``full_words`` decoded: id -> (weak reference, version, med, high)
_FULL_WORDS: dict[int, tuple] = {}


def full_words(points) -> tuple[np.ndarray, np.ndarray]:
    """(med, high) u32 words of every point of ``points``: its arrays for the three-word layout,
    decoded for a compact one (8 bytes a point, kept for the last compact cloud asked, so a pass
    run every frame decodes once). For the consumers that have not learnt the compact layout
    (HQS and transparency on the CPU, elevations); the rasterizers read it directly."""
    if points.med is not None:
        return points.med, points.high
    hit = _FULL_WORDS.get(id(points))
    if hit is not None and hit[0]() is points and hit[1] == points.version:  # an LOD arena refills in place
        return hit[2], hit[3]
    pack = points.packing
    n = len(points.low)
    med = np.zeros(n, np.uint32)
    high = np.zeros(n, np.uint32)
    b = points.batches
    firsts, counts = b["first"].astype(np.int64), b["count"].astype(np.int64)
    _expand_all(points.ext, firsts, counts, pack["ext_first"].astype(np.int64), pack["code"].astype(np.uint32), med, high)
    _FULL_WORDS.clear()
    _FULL_WORDS[id(points)] = (weakref.ref(points), points.version, med, high)
    return med, high


def point_words(points, batch: int, start: int, stop: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(low, med, high) u32 words of points start..stop (global indices) of batch ``batch``,
    whatever the layout (the numpy reference and host-side decoding)."""
    low = points.low[start:stop]
    if points.med is not None:
        return low, points.med[start:stop], points.high[start:stop]
    pack = points.packing
    n = stop - start
    med = np.empty(n, np.uint32)
    high = np.empty(n, np.uint32)
    first = int(points.batches["first"][batch])
    rec = pack[batch]
    expand_tails(points.ext, int(rec["ext_first"]), np.uint32(rec["code"]), start - first, n, 1, med, high, np.empty(n, np.uint64))
    return low, med, high


# --- building --------------------------------------------------------------------------------
@njit(parallel=True, cache=True)
def _compact_batches(phase, xyz, order, firsts, counts, gmin, scale, tol, qmin, bits, bbox_min, bbox_max, word0s, low, ext):
    """One parallel kernel for both phases (one parfor to compile, not two): phase 0 plans
    each batch (``_plan``), phase 1 writes its words (``_write``). ``np.int64(b)``: the index
    is unsigned in the parallel loop's own compile, signed when numba types the function; one
    type compiles each helper once, not twice (1.5 s of a first render)."""
    for b in prange(firsts.shape[0]):
        if phase == 0:
            _plan(np.int64(b), xyz, order, firsts, counts, gmin, scale, tol, qmin, bits, bbox_min, bbox_max)
        else:
            _write(np.int64(b), xyz, order, firsts, counts, gmin, scale, qmin, bits, bbox_min, bbox_max, word0s, low, ext)


@njit
def _plan(b, xyz, order, firsts, counts, gmin, scale, tol, qmin, bits, bbox_min, bbox_max):
    """Batch b: the smallest integer grid coordinate (steps from gmin) and the bits B per axis
    its extent needs (>= COMPACT_MIN_BITS), the grid-aligned box; bits[b, 0] = -1 where the batch
    must be wide (a point off the grid, or B > 29): then the tight box."""
    f = firsts[b]
    c = counts[b]
    lo = np.empty(3, np.int64)
    hi = np.empty(3, np.int64)
    flo = np.empty(3)
    fhi = np.empty(3)
    for a in range(3):
        lo[a] = np.iinfo(np.int64).max
        hi[a] = np.iinfo(np.int64).min
        flo[a] = np.inf
        fhi[a] = -np.inf
    pts = gather_batch(xyz, order, f, c)
    on_grid = True
    for a in range(3):
        inv = 1.0 / scale[a]
        g = gmin[a]
        for k in range(c):
            x = pts[k, a]
            flo[a] = min(flo[a], x)
            fhi[a] = max(fhi[a], x)
            r = (x - g) * inv
            q = np.int64(np.floor(r + 0.5))
            on_grid &= on_the_grid(x, r, q, scale[a], tol)
            lo[a] = min(lo[a], q)
            hi[a] = max(hi[a], q)
    for a in range(3):
        need = COMPACT_MIN_BITS
        while need < 30 and (hi[a] - lo[a]) >> need:
            need += 1
        bits[b, a] = need
        if need > 29:
            on_grid = False
    if not on_grid:
        bits[b, 0] = -1
        for a in range(3):
            bbox_min[b, a] = flo[a]
            bbox_max[b, a] = fhi[a]
        return
    for a in range(3):
        qmin[b, a] = lo[a]
        bbox_min[b, a] = gmin[a] + (lo[a] - 0.5) * scale[a]
        bbox_max[b, a] = bbox_min[b, a] + float(np.int64(1) << bits[b, a]) * scale[a]


@njit
def _write(b, xyz, order, firsts, counts, gmin, scale, qmin, bits, bbox_min, bbox_max, word0s, low, ext):
    """Batch b: low words and the extension stream (``ext`` zeroed on entry)."""
    f = firsts[b]
    c = counts[b]
    wide = bits[b, 0] < 0
    e = np.empty(3, np.int64)
    inv = np.empty(3)
    for a in range(3):
        e[a] = 20 if wide else bits[b, a] - WORD_BITS
        size = bbox_max[b, a] - bbox_min[b, a]
        inv[a] = _SCALE30 / size if size > 0.0 else 0.0
    t = e[0] + e[1] + e[2]
    w0 = word0s[b]
    pts = gather_batch(xyz, order, f, c)
    for k in range(c):
        wl = np.uint32(0)
        v = np.uint64(0)
        pos = np.uint64(0)
        for a in range(3):
            x = pts[k, a]
            if wide:  # today's quantization (quantize.py)
                q = max(min(np.int64((x - bbox_min[b, a]) * inv[a]), _MAX30), 0)
                top = q >> 20
                f_a = q & _M20
            else:
                kq = np.int64(np.floor((x - gmin[a]) * (1.0 / scale[a]) + 0.5)) - qmin[b, a]
                top = kq >> e[a]
                f_a = kq & ((np.int64(1) << e[a]) - 1)
            wl |= np.uint32(top & WORD_MASK) << np.uint32(WORD_BITS * a)
            v |= np.uint64(f_a) << pos
            pos += np.uint64(e[a])
        low[f + k] = wl
        if t:
            p = k * t
            w = w0 + (p >> 6)
            s = np.uint64(p & 63)
            ext[w] |= v << s
            if (p & 63) + t > 64:
                ext[w + 1] |= v >> (np.uint64(64) - s)


def compact_positions(xyz: np.ndarray, order: np.ndarray, batches: np.ndarray, scale, origin=None):
    """Fill the batches' boxes and return (low u32 per point, ext u64 words, PACK_DTYPE per
    batch) for the points xyz[order] on a grid of step ``scale`` (per axis) through ``origin``
    (default: the smallest coordinate, a source point). ``scale`` None: no grid, every batch
    wide (today's 30-bit words, as the octree stores points of sources without a scale)."""
    tol = GRID_TOLERANCE
    if scale is None:
        scale, tol = np.ones(3), -1.0  # no point is ever within -1 of the grid
    scale = np.asarray(scale, np.float64).reshape(3)
    if not np.all(np.isfinite(scale) & (scale > 0)):
        raise ValueError(f"source scale must be finite and positive, got {scale.tolist()}")
    xyz = np.ascontiguousarray(xyz, np.float64)
    gmin = np.asarray(xyz.min(axis=0) if origin is None else origin, np.float64).reshape(3)
    nb = len(batches)
    firsts = batches["first"].astype(np.int64)
    counts = batches["count"].astype(np.int64)
    qmin = np.zeros((nb, 3), np.int64)
    bits = np.zeros((nb, 3), np.int64)
    bmin = np.empty((nb, 3))
    bmax = np.empty((nb, 3))
    low = np.empty(len(order), np.uint32)
    no_ext = np.zeros(0, np.uint64)
    _compact_batches(0, xyz, order, firsts, counts, gmin, scale, tol, qmin, bits, bmin, bmax, firsts, low, no_ext)
    wide = bits[:, 0] < 0
    e = np.where(wide[:, None], EXT_FULL_BITS, bits - WORD_BITS)
    t = e.sum(axis=1)
    words = stream_words(t, counts)
    word0s = np.concatenate([[0], np.cumsum(words)[:-1]]).astype(np.int64) if nb else np.zeros(0, np.int64)
    ext = np.zeros(int(words.sum()), np.uint64)
    _compact_batches(1, xyz, order, firsts, counts, gmin, scale, tol, qmin, bits, bmin, bmax, word0s, low, ext)
    batches["bbox_min"] = bmin
    batches["bbox_max"] = bmax
    pack = np.zeros(nb, PACK_DTYPE)
    pack["ext_first"] = word0s
    pack["code"] = e[:, 0] | e[:, 1] << 8 | e[:, 2] << 16
    return low, ext, pack


def expand_cloud_words(points) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(low, med, high) of every point in the three-word layout (a copy of low): what the
    same cloud holds in today's layout (tests, the A/B benchmark)."""
    med, high = full_words(points)
    return points.low.copy(), np.asarray(med), np.asarray(high)


@njit(cache=True)
def _gather_fields(ext, old_word0s, codes, new_word0s, starts, positions, out):
    for b in range(new_word0s.shape[0]):
        t = code_bits(codes[b])
        if t == 0:
            continue
        for m in range(starts[b], starts[b + 1]):
            write_ext(out, new_word0s[b], t, m - starts[b], read_ext(ext, old_word0s[b], t, positions[m]))


def stream_subset(ext: np.ndarray, code: int, positions: np.ndarray) -> np.ndarray:
    """The stream of one batch (layout ``code``) holding only its points ``positions``, their fields as stored."""
    pack = np.zeros(1, PACK_DTYPE)
    pack["code"] = code
    out = np.zeros(int(stream_words(ext_bits_per_point(pack, None), np.int64(len(positions)))[0]), np.uint64)
    starts = np.array([0, len(positions)], np.int64)
    _gather_fields(ext, np.zeros(1, np.int64), pack["code"], np.zeros(1, np.int64), starts, positions.astype(np.int64), out)
    return out


def subset_streams(points, batches: np.ndarray, counts: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(ext, packing) of new batches that hold some points of compact ``points``' ``batches``
    (``counts`` each: points ``positions``, batch-relative, batch after batch), in the same boxes:
    their fields are moved as stored, so the positions stay exact."""
    pack = points.packing[batches].copy()
    words = stream_words(ext_bits_per_point(pack, counts), counts)
    pack["ext_first"] = np.cumsum(words) - words
    ext = np.zeros(int(words.sum()), np.uint64)
    streams_into(points, batches, counts, positions, ext, pack["ext_first"])
    return ext, pack


def streams_into(points, batches: np.ndarray, counts: np.ndarray, positions: np.ndarray, out: np.ndarray, firsts: np.ndarray) -> None:
    """``subset_streams``' fields written into ``out`` at u64 words ``firsts`` (one stream a batch,
    in each batch's own layout): rooms of buffers refilled in place (a progressive octree's kept
    chunks), whose stale bits need no zeroing (each field is rewritten whole)."""
    starts = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    old = points.packing["ext_first"][batches].astype(np.int64)
    codes = points.packing["code"][batches]
    _gather_fields(points.ext, old, codes, np.asarray(firsts).astype(np.int64), starts, positions.astype(np.int64), out)


def wide_batches(pack: np.ndarray) -> np.ndarray:
    """Bool per batch: stored wide (off the source grid or beyond 29 bits an axis)."""
    return (pack["code"] & 0xFF) == EXT_FULL_BITS


def ext_bits_per_point(pack: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Extension bits a point of each batch holds."""
    code = pack["code"].astype(np.int64)
    return (code & 0xFF) + ((code >> 8) & 0xFF) + ((code >> 16) & 0xFF)


def stream_words(t: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """u64 words of each batch's extension stream (``t`` bits a point, ``counts`` points): one
    more than the bits need, so ``read_ext``'s second word stays inside; none where t is 0."""
    return np.where(t > 0, (counts * t + 63) // 64 + 1, 0)


__all__ = [
    "GRID_TOLERANCE",
    "centre_half",
    "compact_positions",
    "expand_cloud_words",
    "expand_tails",
    "ext_bits_per_point",
    "full_words",
    "pack_code",
    "point_words",
    "read_ext",
    "stream_subset",
    "stream_words",
    "streams_into",
    "subset_streams",
    "tail_words",
    "wide_batches",
    "wide_bits",
]


# --- colors ----------------------------------------------------------------------------------
# RGB565 (16 bits a point) for clouds whose colors are opaque: each channel rounded to 5/6/5 bits
# and widened back by bit replication (r8 = r5 << 3 | r5 >> 2), at most 4/255 off (measured:
# 41.7 dB PSNR on autzen_trim and the demo town, mean 2/255 red and blue, 1/255 green).
def pack_rgb565(color: np.ndarray) -> np.ndarray:
    """u16 RGB565 of u32 RGBA8 colors (alpha dropped: opaque colors only)."""
    c = np.ascontiguousarray(color, np.uint32)
    n = len(c)
    out = np.zeros(n + (n & 1), np.uint16)[:n]  # an even-length buffer: ``rgb565_words`` views it as u32
    if n <= NUMPY_MAX:  # numpy: a small cloud's first load does not wait for a compile
        ch = c.view(np.uint8).reshape(-1, 4)[:, :3].astype(np.uint32)
        r, g, b = ((ch * np.array([31, 63, 31], np.uint32) + 127) // 255).T
        out[:] = r << 11 | g << 5 | b
        return out
    _pack565(c, out)
    return out


def rgb565_words(colors: np.ndarray) -> np.ndarray:
    """16-bit colors as u32 words (point i in the low half of word i >> 1 when i is even, the high
    half when odd): the view the resolve kernel gathers 32 bits at a time from (vectorised),
    without a copy for arrays made by ``pack_rgb565``."""
    c = np.ascontiguousarray(colors, np.uint16)
    if len(c) % 2 == 0:
        return c.view(np.uint32)
    base = c.base
    if (
        isinstance(base, np.ndarray)
        and base.dtype == np.uint16
        and base.ndim == 1
        and len(base) == len(c) + 1
        and base.ctypes.data == c.ctypes.data
    ):
        return base.view(np.uint32)
    return np.append(c, np.uint16(0)).view(np.uint32)


@functools.cache
def rgb565_table() -> np.ndarray:
    """u32 RGBA8 of every RGB565 color (256 KB, read-only): the resolve kernel's decoder."""
    table = rgba32(np.arange(1 << 16, dtype=np.uint16))
    table.flags.writeable = False
    return table


@njit(parallel=True, cache=True)
def _pack565(c, out):
    for i in prange(c.shape[0]):
        v = c[i]
        r = ((v & np.uint32(0xFF)) * np.uint32(31) + np.uint32(127)) // np.uint32(255)
        g = (((v >> np.uint32(8)) & np.uint32(0xFF)) * np.uint32(63) + np.uint32(127)) // np.uint32(255)
        b = (((v >> np.uint32(16)) & np.uint32(0xFF)) * np.uint32(31) + np.uint32(127)) // np.uint32(255)
        out[i] = np.uint16(r << np.uint32(11) | g << np.uint32(5) | b)


@njit(inline="always")
def rgb565_rgba(c):
    """u32 RGBA8 (opaque) of one u16 RGB565 color; the WGSL resolve pass does the same."""
    v = np.uint32(c)
    r = v >> np.uint32(11)
    g = (v >> np.uint32(5)) & np.uint32(63)
    b = v & np.uint32(31)
    r8 = (r << np.uint32(3)) | (r >> np.uint32(2))
    g8 = (g << np.uint32(2)) | (g >> np.uint32(4))
    b8 = (b << np.uint32(3)) | (b >> np.uint32(2))
    return r8 | (g8 << np.uint32(8)) | (b8 << np.uint32(16)) | np.uint32(0xFF000000)


@njit(parallel=True, cache=True)
def _unpack565(c, out):
    for i in prange(c.shape[0]):
        out[i] = rgb565_rgba(c[i])


def rgba32(colors) -> np.ndarray:
    """u32 RGBA8 colors of an array in either format (the same array when already u32), or of
    per-block palettes (core/palette.py)."""
    if isinstance(colors, PaletteColors):
        return decode_palette(colors)
    if colors.dtype == np.uint32:
        return colors
    c = np.ascontiguousarray(colors, np.uint16)
    if len(c) <= NUMPY_MAX:
        v = c.astype(np.uint32)
        r, g, b = v >> 11, (v >> 5) & 63, v & 31
        return ((r << 3) | (r >> 2)) | ((g << 2) | (g >> 4)) << 8 | ((b << 3) | (b >> 2)) << 16 | np.uint32(0xFF000000)
    out = np.empty(len(c), np.uint32)
    _unpack565(c, out)
    return out


def colors_at(colors, points) -> np.ndarray:
    """u32 RGBA8 of point indices ``points`` of colors in any format (u32, RGB565, palettes)."""
    if isinstance(colors, PaletteColors):
        return decode_palette(colors, points)
    return rgba32(colors[np.asarray(points, np.int64)])


def color_arrays(colors) -> tuple[np.ndarray, ...]:
    """The arrays colors in any format are held in (what a GPU copies and forgets)."""
    return colors.arrays() if isinstance(colors, PaletteColors) else (colors,)
