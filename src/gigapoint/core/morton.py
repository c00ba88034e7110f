"""63-bit Morton codes and a parallel radix sort that orders points by them.

``np.argsort`` takes ~9 s for 20 M int64 keys on this class of machine; the sort here is
an MSD pass on the top 12 bits that vary (4096 buckets, per-thread histograms) followed by an LSD
radix sort of each bucket in cache, with passes skipped where every key shares a digit
(flat or clustered clouds).
"""

from __future__ import annotations

import time

import numba
import numpy as np
from numba import njit, prange

MORTON_BITS_PER_AXIS = 21
_TOP_BITS = 12
# parallel loops from prange only, numpy calls left serial: the sort's few small array calls
# need no parfors, and compiling them as such took a quarter of its 2.7 s compile (a fresh
# dict each use: numba consumes it)
_PRANGE_ONLY = {"comprehension": False, "reduction": False, "inplace_binop": False, "setitem": False, "numpy": False, "stencil": False, "fusion": False}


@njit(inline="always")
def _spread_bits_3(v):
    """Spread the low 21 bits of v so that bit i lands on bit 3*i."""
    v = v & np.uint64(0x1FFFFF)
    v = (v | (v << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
    v = (v | (v << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
    v = (v | (v << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
    v = (v | (v << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
    v = (v | (v << np.uint64(2))) & np.uint64(0x1249249249249249)
    return v


@njit(parallel=True, cache=True)
def morton_codes(xyz, origin, cube_size, x_high=False):
    """Morton code of each point inside the cube [origin, origin + cube_size]^3: x in the lowest
    bit of every 3-bit digit, or with ``x_high`` in the highest (Potree's child order, lod/keys.py)."""
    n = xyz.shape[0]
    codes = np.empty(n, np.uint64)
    cells = float(1 << MORTON_BITS_PER_AXIS)
    top = np.int64((1 << MORTON_BITS_PER_AXIS) - 1)
    inv = cells / cube_size if cube_size > 0.0 else 0.0
    for i in prange(n):
        code = np.uint64(0)
        for axis in range(3):
            c = np.int64((xyz[i, axis] - origin[axis]) * inv)
            c = min(max(c, 0), top)
            code |= _spread_bits_3(np.uint64(c)) << np.uint64(2 - axis if x_high else axis)
        codes[i] = code
    return codes


@njit(cache=True)
def _insertion_sort(keys, idx, lo, hi):
    for i in range(lo + 1, hi):
        k = keys[i]
        v = idx[i]
        j = i - 1
        while j >= lo and keys[j] > k:
            keys[j + 1] = keys[j]
            idx[j + 1] = idx[j]
            j -= 1
        keys[j + 1] = k
        idx[j + 1] = v


@njit(cache=True)
def _lsd_sort_range(keys, idx, tmp_keys, tmp_idx, lo, hi, bits):
    """Stable LSD radix sort of keys[lo:hi] on their low ``bits`` bits, 8 bits a pass."""
    n = hi - lo
    if n < 2:
        return
    if n <= 48:
        _insertion_sort(keys, idx, lo, hi)
        return
    counts = np.empty(256, np.int64)
    src_k, src_i, dst_k, dst_i = keys, idx, tmp_keys, tmp_idx
    in_tmp = False
    for shift in range(0, bits, 8):
        counts[:] = 0
        s = np.uint64(shift)
        for i in range(lo, hi):
            counts[(src_k[i] >> s) & np.uint64(255)] += 1
        if counts.max() == n:  # every key shares this digit: nothing to move
            continue
        total = lo
        for d in range(256):
            c = counts[d]
            counts[d] = total
            total += c
        for i in range(lo, hi):
            d = (src_k[i] >> s) & np.uint64(255)
            p = counts[d]
            dst_k[p] = src_k[i]
            dst_i[p] = src_i[i]
            counts[d] = p + 1
        src_k, src_i, dst_k, dst_i = dst_k, dst_i, src_k, src_i
        in_tmp = not in_tmp
    if in_tmp:
        keys[lo:hi] = tmp_keys[lo:hi]
        idx[lo:hi] = tmp_idx[lo:hi]


@njit(parallel=dict(_PRANGE_ONLY), cache=True)
def _sort_codes(codes, n_threads, index_type):
    n = codes.shape[0]
    n_buckets = 1 << _TOP_BITS
    mask = np.uint64(n_buckets - 1)
    step = (n + n_threads - 1) // n_threads
    # 0. the bits every code shares (an octree partition's prefix) are skipped: the buckets are
    # the top 12 bits that vary, else a partition lands in one bucket sorted by one thread
    lows = np.full(n_threads, np.uint64(0xFFFFFFFFFFFFFFFF))
    highs = np.zeros(n_threads, np.uint64)
    for t in prange(n_threads):
        for i in range(t * step, min(n, (t + 1) * step)):
            lows[t] = min(lows[t], codes[i])
            highs[t] = max(highs[t], codes[i])
    varying = highs.max() ^ lows.min()
    top = 0
    while varying >> np.uint64(top):
        top += 1
    low_bits = max(top - _TOP_BITS, 0)
    shift = np.uint64(low_bits)
    # 1. per-thread histograms of the bucket bits over contiguous slices (keeps the sort stable)
    hist = np.zeros((n_threads, n_buckets), np.int64)
    for t in prange(n_threads):
        for i in range(t * step, min(n, (t + 1) * step)):
            hist[t, (codes[i] >> shift) & mask] += 1
    offsets = np.empty((n_threads, n_buckets), np.int64)
    bucket_start = np.empty(n_buckets + 1, np.int64)
    total = 0
    for b in range(n_buckets):
        bucket_start[b] = total
        for t in range(n_threads):
            offsets[t, b] = total
            total += hist[t, b]
    bucket_start[n_buckets] = total
    # 2. scatter into buckets
    keys = np.empty(n, np.uint64)
    idx = np.empty(n, index_type)
    for t in prange(n_threads):
        off = offsets[t]
        for i in range(t * step, min(n, (t + 1) * step)):
            b = (codes[i] >> shift) & mask
            p = off[b]
            keys[p] = codes[i]
            idx[p] = i
            off[b] = p + 1
    # 3. each bucket sorted on the remaining bits, buckets in parallel
    tmp_keys = np.empty(n, np.uint64)
    tmp_idx = np.empty(n, index_type)
    for b in prange(n_buckets):
        _lsd_sort_range(keys, idx, tmp_keys, tmp_idx, bucket_start[b], bucket_start[b + 1], low_bits)
    return keys, idx


#: up to this many codes numpy's stable sort orders them (milliseconds): a small cloud's first
#: run then does not wait for the parallel sort to compile (2.7 s)
NUMPY_SORT_MAX = 1 << 20


def morton_order(codes: np.ndarray) -> np.ndarray:
    """Stable permutation that sorts ``codes`` (uint64) ascending (uint32 or int64 indices)."""
    codes = np.ascontiguousarray(codes, dtype=np.uint64)
    if len(codes) == 0:
        return np.empty(0, np.int64)
    if len(codes) <= NUMPY_SORT_MAX:  # the same permutation (both stable), in the same index type
        return np.argsort(codes, kind="stable").astype(np.uint32)
    previous = numba.get_parallel_chunksize()
    numba.set_parallel_chunksize(8)  # buckets vary wildly in size: hand them out dynamically
    try:
        # 32-bit indices where they fit: a third less memory traffic in every pass
        index_type = np.uint32 if len(codes) < 2**32 else np.int64
        _, order = _sort_codes(codes, numba.get_num_threads(), index_type)
    finally:
        numba.set_parallel_chunksize(previous)
    return order


_SORT_KIND: list[str] = []  # the faster of numpy's two sorts on this CPU, once measured


def _faster_sort_kind() -> str:
    """numpy's SIMD quicksort (x86-simd-sort) or its stable sort (timsort: it finds the runs that
    points arrive in, a frame's rows, a file's scan lines), whichever sorts codes faster here.
    They trade places between CPUs: a 512x424 depth frame took 3 ms by quicksort and 10 by the
    stable sort on the Intel Xeon, 10.7 and 4.7 on the AMD EPYC (docs/benchmarks.md). Timed once
    a process, on a fixed sample (128 k codes in shuffled runs of 8; ~25 ms)."""
    if not _SORT_KIND:
        rng = np.random.default_rng(0)
        runs = np.sort(rng.integers(0, 1 << 62, 1 << 17, dtype=np.uint64)).reshape(-1, 8)
        sample = runs[rng.permutation(len(runs))].ravel()
        _SORT_KIND.append(fastest({kind: lambda kind=kind: np.argsort(sample, kind=kind) for kind in ("quicksort", "stable")}))
    return _SORT_KIND[0]


def fastest(ways: dict, repeats: int = 3) -> str:
    """The name of the fastest of ``ways`` (name -> a call doing the same work), best of
    ``repeats`` each: how this CPU's sorts are chosen once a process."""
    best = {}
    for name, call in ways.items():
        times = []
        for _ in range(repeats):
            t = time.perf_counter()
            call()
            times.append(time.perf_counter() - t)
        best[name] = min(times)
    return min(best, key=best.get)


def argsort_codes(codes: np.ndarray) -> np.ndarray:
    """A permutation that sorts ``codes`` ascending by numpy's faster sort on this CPU; equal
    codes (points in the same cell) may come in either order. For the batches the progressive
    octree and live frames sort (10^5-10^6 codes); ``morton_order`` is the stable one."""
    return np.argsort(codes, kind=_faster_sort_kind())


def cube_of(bmin: np.ndarray, bmax: np.ndarray) -> tuple[np.ndarray, float]:
    """The cube (origin, edge) enclosing a box; Morton codes are taken in it."""
    bmin = np.asarray(bmin, np.float64)
    size = float(np.max(np.asarray(bmax, np.float64) - bmin))
    return bmin, size


@njit(cache=True)
def counting_order(keys, n_bins):
    """(stable permutation sorting small integer keys, per-bin counts): a counting sort."""
    counts = np.zeros(n_bins, np.int64)
    for i in range(keys.shape[0]):
        counts[keys[i]] += 1
    pos = np.empty(n_bins, np.int64)
    total = 0
    for b in range(n_bins):
        pos[b] = total
        total += counts[b]
    order = np.empty(keys.shape[0], np.int64)
    for i in range(keys.shape[0]):
        k = keys[i]
        order[pos[k]] = i
        pos[k] += 1
    return order, counts
