"""Numba kernels of the progressive octree (octree.py): routing a sorted batch down the tree,
sampling voxels, allocating chunks, writing points and voxels.

A batch is sorted by point code (lod/keys.py: 21 bits an axis in the root cube, Potree's
child order), so every node's share of it is one contiguous run and every 128³ voxel cell
of a node one contiguous sub-run: routing is a few binary searches per node, and sampling
a linear pass per run, with no hash lookups per point.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ...core.compact import code_bits, on_the_grid, read_ext, tail_words, wide_bits, write_ext
from ...core.layout import COORD_BITS, EXT_FULL_BITS, WORD_BITS, WORD_MASK
from ..keys import CODE_BITS

GRID_BITS = 7  # voxel cells per axis and inner node: 2^7 = 128 (SimLOD, Wand et al.)
# Entry lists a node has: a leaf's points are list 0; an inner node's voxels go to the list of
# the child octant they lie in, so a frame can draw a node's voxels but where a child is drawn.
# List ``l`` belongs to node ``l // LISTS``.
LISTS = 8
EMPTY_KEY = np.uint64(0xFFFFFFFFFFFFFFFF)
_HASH_MUL = np.uint64(0x9E3779B97F4A7C15)
_SCALE30 = float(1 << COORD_BITS)
_MAX30 = (1 << COORD_BITS) - 1
_STACK = 8 * (CODE_BITS + 2)  # a depth-first walk holds at most 8 siblings a level
# The pool is in the compact layout (core/compact.py): a point chunk is a wide batch (its medium
# and high words as 60 bits a point in its own stream); a voxel chunk holds the low word alone
# (layout code 0: no stream), which places a voxel at the centre of a 1024-grid cell: its box is
# its node's cube moved half such a cell down, so that centre is the voxel cell's centre.
WIDE_CODE = EXT_FULL_BITS | EXT_FULL_BITS << 8 | EXT_FULL_BITS << 16
WIDE_BITS = 3 * EXT_FULL_BITS
VOXEL_SHIFT = 0.5 / (1 << WORD_BITS)  # of the node's edge
#: a voxel's colour sums are u32 (r, g, b, a, n: 20 bytes a voxel while it is built): once it
#: stands for 2^VOXEL_WEIGHT_BITS points they and the count are halved, the mean kept, so that
#: 255 times the count never overflows (it did past 16.8 M points in one voxel, a live cloud's
#: snapshots of one scene taken for long enough); the points added later then weigh more.
VOXEL_WEIGHT_BITS = 23
_M20 = (1 << EXT_FULL_BITS) - 1


@njit(inline="always")
def _new_node(parent, d, key, level, parent_of, children, leaf, count, first_chunk, last_chunk, cmin, edge, n):
    """Node ``n`` as child ``d`` (Potree order: x in bit 2) of ``parent``: an empty leaf."""
    key[n] = (key[parent] << np.uint64(3)) | np.uint64(d)
    level[n] = level[parent] + 1
    parent_of[n] = parent
    for c in range(8):
        children[n, c] = -1
    leaf[n] = 1
    count[n] = 0
    for o in range(LISTS):
        first_chunk[n * LISTS + o] = -1
        last_chunk[n * LISTS + o] = -1
    e = edge[parent] * 0.5
    edge[n] = e
    cmin[n, 0] = cmin[parent, 0] + e * ((d >> 2) & 1)
    cmin[n, 1] = cmin[parent, 1] + e * ((d >> 1) & 1)
    cmin[n, 2] = cmin[parent, 2] + e * (d & 1)
    children[parent, d] = n


@njit(cache=True)
def distribute(
    codes, roots, key, level, parent_of, children, leaf, count, first_chunk, last_chunk, cmin, edge, n_nodes, leaf_runs, inner_runs
):
    """Route the sorted ``codes`` down to the leaves, ``roots[j]`` = (node, lo, hi): codes[lo:hi]
    from that node (disjoint subtrees), creating missing children as empty leaves. Returns (leaf
    runs, inner runs, nodes): ``leaf_runs[k]`` / ``inner_runs[k]`` = (node, lo, hi) of the points
    each node receives, parents before children; -1 leaf runs when the node arrays are full."""
    cap = key.shape[0]
    size = _STACK + roots.shape[0]
    st_node = np.empty(size, np.int64)
    st_lo = np.empty(size, np.int64)
    st_hi = np.empty(size, np.int64)
    top = 0
    for j in range(roots.shape[0] - 1, -1, -1):
        st_node[top], st_lo[top], st_hi[top] = roots[j, 0], roots[j, 1], roots[j, 2]
        top += 1
    nl = 0
    ni = 0
    while top > 0:
        top -= 1
        node, lo, hi = st_node[top], st_lo[top], st_hi[top]
        if hi <= lo:
            continue
        if leaf[node]:
            leaf_runs[nl, 0], leaf_runs[nl, 1], leaf_runs[nl, 2] = node, lo, hi
            nl += 1
            continue
        inner_runs[ni, 0], inner_runs[ni, 1], inner_runs[ni, 2] = node, lo, hi
        ni += 1
        lev = level[node]
        prefix = key[node] ^ (np.uint64(1) << np.uint64(3 * lev))
        shift = np.uint64(3 * (CODE_BITS - lev - 1))
        s = lo
        for d in range(8):
            # the first code at or past child d + 1's range (the last child takes the rest: a
            # spilled point's code, taken from its decoded position, may round past its leaf's range)
            bound = ((prefix << np.uint64(3)) | np.uint64(d + 1)) << shift
            a, b = (s, hi) if d < 7 else (hi, hi)
            while a < b:
                m = (a + b) >> 1
                if codes[m] < bound:
                    a = m + 1
                else:
                    b = m
            if a > s:
                ch = children[node, d]
                if ch < 0:
                    if n_nodes >= cap:
                        return -1, 0, n_nodes
                    _new_node(node, d, key, level, parent_of, children, leaf, count, first_chunk, last_chunk, cmin, edge, n_nodes)
                    ch = n_nodes
                    n_nodes += 1
                st_node[top], st_lo[top], st_hi[top] = ch, s, a
                top += 1
            s = a
    return nl, ni, n_nodes


@njit(parallel=True, cache=True)
def sort_keys(codes, index_bits, keys):
    """Each code's top bits with its index under them, for a plain sort of the keys (numpy's SIMD
    sort of u64 values: 5-7 ms for 10^6 on the Intel Xeon, 14 on the AMD EPYC Zen 2 (50-65 on an
    earlier one), where ``radix_sort`` takes 10 for the town's keys; its argsort of the codes
    16-40 ms). Codes have 63 bits,
    so ``index_bits - 1`` of their lowest are dropped: code_order breaks the ties they leave."""
    drop = np.uint64(index_bits - 1)
    for i in prange(codes.shape[0]):
        keys[i] = ((codes[i] >> drop) << np.uint64(index_bits)) | np.uint64(i)


RADIX_BITS = 11  # radix_sort's first digit: 2 048 buckets a thread, its counts in L1
_BUCKET_BITS = 11  # the digits a bucket is sorted by after it: 11 bits, or 8 in a bucket of under 4 096 keys
_BUCKET_SMALL_BITS = 8  # (256 counts: a small bucket's passes are then mostly its keys)
_SMALL_BUCKET = 32  # buckets of at most this many keys: an insertion sort


@njit(parallel=True, cache=True)
def radix_sort(keys, scratch, lo_bit, n_parts):
    """``keys`` sorted in place by their bits lo_bit..63, stably: keys equal there keep their
    order, so ``sort_keys``' keys (the index under bit ``index_bits``, ascending as given) come
    out as a plain sort of them would leave them. Most significant digit first: the highest 11
    bits in which keys differ (those above, all keys share: a set from a few leaves) scatter the
    keys into 2 048 buckets (counted and scattered by ``n_parts`` threads, each its block of
    keys), then each bucket, in cache, is sorted by the bits under them least significant digit
    first (a digit its keys share skipped), the buckets spread over the threads by keys: one pass
    over memory, not one a digit (the town's 10^6 keys: 14.8 -> 9.7 ms on the AMD EPYC, Zen 2).
    ``scratch``: as large as keys."""
    n = keys.shape[0]
    if n < 2:
        return
    block = (n + n_parts - 1) // n_parts
    differ = np.zeros(n_parts, np.uint64)
    for p in prange(n_parts):
        d = np.uint64(0)
        for i in range(p * block, min(n, (p + 1) * block)):
            d |= keys[i] ^ keys[0]
        differ[p] = d
    d = np.uint64(0)
    for p in range(n_parts):
        d |= differ[p]
    top = lo_bit  # one past the highest bit of the sorted ones in which keys differ
    d >>= np.uint64(lo_bit)
    while d:
        top += 1
        d >>= np.uint64(1)
    if top == lo_bit:
        return
    shift = max(lo_bit, top - RADIX_BITS)
    sh = np.uint64(shift)
    n_buckets = 1 << RADIX_BITS
    mask = np.uint64(n_buckets - 1)
    place = np.zeros((n_parts, n_buckets), np.int64)
    for p in prange(n_parts):
        counts = place[p]
        for i in range(p * block, min(n, (p + 1) * block)):
            counts[(keys[i] >> sh) & mask] += 1
    start = np.empty(n_buckets + 1, np.int64)
    at = 0
    for b in range(n_buckets):  # where each part's keys of each digit go: digit-major, parts in order
        start[b] = at
        for p in range(n_parts):
            c = place[p, b]
            place[p, b] = at
            at += c
    start[n_buckets] = n
    for p in prange(n_parts):
        to = place[p]
        for i in range(p * block, min(n, (p + 1) * block)):
            k = keys[i]
            d = (k >> sh) & mask
            scratch[to[d]] = k
            to[d] += 1
    # the buckets back into keys, sorted by the bits under the digit; part p takes those starting in its share of keys
    first = np.empty(n_parts + 1, np.int64)
    b = 0
    for p in range(n_parts):
        first[p] = b
        while b < n_buckets and start[b] < (p + 1) * block:
            b += 1
    first[n_parts] = n_buckets
    for p in prange(n_parts):
        counts = np.empty(1 << _BUCKET_BITS, np.int64)
        for b in range(first[p], first[p + 1]):
            _sort_bucket(scratch, keys, start[b], start[b + 1], lo_bit, shift, counts)


@njit(inline="always")
def _sort_bucket(src, dst, lo, hi, lo_bit, hi_bit, counts):
    """src[lo:hi] into dst[lo:hi] sorted stably by bits lo_bit..hi_bit (8 a pass, least
    significant first, the two slices taking turns; a digit all share skipped)."""
    m = hi - lo
    if m <= _SMALL_BUCKET:
        below = np.uint64(lo_bit)
        for i in range(lo, hi):
            k = src[i]
            j = i - 1
            while j >= lo and (dst[j] >> below) > (k >> below):
                dst[j + 1] = dst[j]
                j -= 1
            dst[j + 1] = k
        return
    d = np.uint64(0)
    for i in range(lo, hi):
        d |= src[i] ^ src[lo]
    a, z = src, dst
    in_dst = False
    bits = _BUCKET_BITS if m >= 4096 else _BUCKET_SMALL_BITS
    for shift in range(lo_bit, hi_bit, bits):
        sh = np.uint64(shift)
        width = min(bits, hi_bit - shift)
        mask = np.uint64((1 << width) - 1)
        if ((d >> sh) & mask) == 0:
            continue
        counts[:] = 0
        for i in range(lo, hi):
            counts[(a[i] >> sh) & mask] += 1
        at = lo
        for c in range(1 << width):
            k = counts[c]
            counts[c] = at
            at += k
        for i in range(lo, hi):
            k = a[i]
            c = (k >> sh) & mask
            z[counts[c]] = k
            counts[c] += 1
        a, z = z, a
        in_dst = not in_dst
    if not in_dst:
        for i in range(lo, hi):
            dst[i] = src[i]


@njit(parallel=True, cache=True)
def code_order(keys, codes, rgba, index_bits, order, sorted_codes, sorted_rgba):
    """From the sorted ``sort_keys``: ``order`` (sorted point k is point order[k]), the codes
    sorted, the points whose keys tie (equal code prefixes: a few a million) ordered by their
    full codes, and the colours sorted (read by sample_runs and write_points in this order: one
    gather, in parallel)."""
    mask = (np.uint64(1) << np.uint64(index_bits)) - np.uint64(1)
    for k in prange(keys.shape[0]):
        i = np.int64(keys[k] & mask)
        order[k] = i
        sorted_codes[k] = codes[i]
        sorted_rgba[k] = rgba[i]
    _break_ties(keys, mask, order, sorted_codes, sorted_rgba)


@njit(cache=True)
def _break_ties(keys, mask, order, sorted_codes, sorted_rgba):
    """Runs of keys with equal prefixes (above ``mask``) sorted by their full codes: an insertion
    sort where a run is a few points (nearly always), else numba's sort (a dense cluster in a wide
    cube). Not in the parallel kernel: numba would make every array expression there a parallel
    region of its own."""
    n = keys.shape[0]
    k = 0
    while k < n - 1:
        e = k + 1
        while e < n and (keys[k] ^ keys[e]) <= mask:
            e += 1
        if e - k > 32:
            by_code = np.argsort(sorted_codes[k:e])
            order[k:e] = order[k:e][by_code]
            sorted_codes[k:e] = sorted_codes[k:e][by_code]
            sorted_rgba[k:e] = sorted_rgba[k:e][by_code]
            k = e
            continue
        for i in range(k + 1, e):
            c, o, col = sorted_codes[i], order[i], sorted_rgba[i]
            j = i - 1
            while j >= k and sorted_codes[j] > c:
                sorted_codes[j + 1], order[j + 1], sorted_rgba[j + 1] = sorted_codes[j], order[j], sorted_rgba[j]
                j -= 1
            sorted_codes[j + 1], order[j + 1], sorted_rgba[j + 1] = c, o, col
        k = e


@njit(inline="always")
def _add_color(sums, e, col):
    sums[e, 0] += col & np.uint32(255)
    sums[e, 1] += (col >> np.uint32(8)) & np.uint32(255)
    sums[e, 2] += (col >> np.uint32(16)) & np.uint32(255)
    sums[e, 3] += col >> np.uint32(24)
    sums[e, 4] += 1


@njit(parallel=True, cache=True)
def cell_counts(codes, inner_runs, level, counts):
    """The voxel cells each inner run's points occupy in its node: distinct code prefixes
    ``GRID_BITS`` levels below it, runs of equal ones in the sorted codes. sample_runs makes one
    entry for each, so where each node's entries go is known before it runs."""
    for r in prange(inner_runs.shape[0]):
        lo, hi = inner_runs[r, 1], inner_runs[r, 2]
        shift = np.uint64(3 * (CODE_BITS - min(level[inner_runs[r, 0]] + GRID_BITS, CODE_BITS)))
        c = 1
        for i in range(lo + 1, hi):
            c += ((codes[i] ^ codes[i - 1]) >> shift) != 0
        counts[r] = c


@njit(cache=True)
def plan_levels(inner_runs, level, n_bins, tasks, group_start):
    """sample_runs' order: the inner runs level by level, deepest first (a node's children are a
    level deeper), each level's spread over ``n_bins`` bins by points, largest first into the least
    loaded; bin t of group g is tasks[group_start[g * n_bins + t] : group_start[g * n_bins + t + 1]].
    Returns the number of groups."""
    ni = inner_runs.shape[0]
    lev = np.empty(ni, np.int64)
    for r in range(ni):
        lev[r] = level[inner_runs[r, 0]]
    by_level = np.argsort(-lev, kind="mergesort")
    load = np.zeros(n_bins, np.int64)
    g = 0
    k = 0
    pos = 0
    while k < ni:
        e = k
        while e < ni and lev[by_level[e]] == lev[by_level[k]]:
            e += 1
        points = np.empty(e - k, np.int64)
        for j in range(k, e):
            points[j - k] = inner_runs[by_level[j], 2] - inner_runs[by_level[j], 1]
        bin_of = np.empty(e - k, np.int64)
        load[:] = 0
        for j in np.argsort(-points):
            t = np.argmin(load)
            bin_of[j] = t
            load[t] += points[j]
        for t in range(n_bins):
            group_start[g * n_bins + t] = pos
            for j in range(e - k):
                if bin_of[j] == t:
                    tasks[pos] = by_level[k + j]
                    pos += 1
        g += 1
        k = e
    group_start[g * n_bins] = pos
    return g


@njit(cache=True)
def _node_cells(node, level, leaf, children, codes, rgba, order, run_lo, run_hi, ent_start, ent_count, e_cell, e_first, e_sum, e_node, e_local):
    """The entries of one inner node, at ent_start[node] on, from its leaf children's points and
    its inner children's entries (made before: a level deeper). (The two loops open entries
    alike, written out twice on purpose: an inline helper taking the arrays made this 1.9x
    slower, numba keeping reference counting in the loop.)"""
    lev = level[node]
    cl = min(lev + GRID_BITS, CODE_BITS)
    shift = np.uint64(3 * (CODE_BITS - cl))
    start = ent_start[node]
    m = start
    for d in range(8):
        c = children[node, d]
        if c < 0 or run_lo[c] < 0:
            continue
        if leaf[c]:
            for i in range(run_lo[c], run_hi[c]):
                cell = codes[i] >> shift
                if m == start or cell != e_cell[m - 1]:
                    e_cell[m] = cell
                    e_first[m] = order[i]
                    for ch in range(5):
                        e_sum[m, ch] = 0
                    m += 1
                _add_color(e_sum, m - 1, rgba[i])
        else:
            ccl = min(lev + 1 + GRID_BITS, CODE_BITS)
            up = np.uint64(3 * (ccl - cl))
            for k in range(ent_start[c], ent_start[c] + ent_count[c]):
                cell = e_cell[k] >> up
                if m == start or cell != e_cell[m - 1]:
                    e_cell[m] = cell
                    e_first[m] = e_first[k]
                    for ch in range(5):
                        e_sum[m, ch] = 0
                    m += 1
                for ch in range(5):
                    e_sum[m - 1, ch] += e_sum[k, ch]
    mask = (np.uint64(1) << np.uint64(3 * (cl - lev))) - np.uint64(1)
    top = np.uint64(3 * (cl - lev - 1))  # the cell's child octant: its highest digit
    for k in range(start, m):
        e_local[k] = e_cell[k] & mask
        e_node[k] = node * LISTS + np.int64((e_local[k] >> top) & np.uint64(7))


@njit(parallel=True, cache=True)
def sample_runs(codes, rgba, order, inner_runs, leaf_runs, ent_start, ent_count, tasks, group_start, n_groups, n_bins, level, leaf, children,
                run_lo, run_hi, e_cell, e_first, e_sum, e_node, e_local):  # fmt: skip
    """The voxel cells (code prefixes ``GRID_BITS`` levels below the node) that the routed points
    occupy in every inner node they pass, with their first point and colour sums (r, g, b, a, n).

    Bottom-up and shared: the cells of a node whose children are leaves come from a linear pass
    over the leaves' points; a node's cells over an inner child are that child's cells (a level
    finer, so consecutive ones merge when shifted by one digit). Each point is read once, not
    once per level. Entries of node n go to e_*[ent_start[n] : ent_start[n] + ent_count[n]]
    (cell_counts' counts laid out in ``distribute``'s order reversed, children before parents),
    sorted by cell. The nodes of a level are independent: plan_levels' bins of each, deepest
    level first, one thread a bin (``n_bins`` 1: in order, no parallel region)."""
    for r in range(leaf_runs.shape[0]):
        run_lo[leaf_runs[r, 0]] = leaf_runs[r, 1]
        run_hi[leaf_runs[r, 0]] = leaf_runs[r, 2]
    for r in range(inner_runs.shape[0]):
        run_lo[inner_runs[r, 0]] = inner_runs[r, 1]
        run_hi[inner_runs[r, 0]] = inner_runs[r, 2]
    if n_bins == 1:
        for k in range(group_start[n_groups]):
            _node_cells(inner_runs[tasks[k], 0], level, leaf, children, codes, rgba, order, run_lo, run_hi, ent_start, ent_count, e_cell,
                        e_first, e_sum, e_node, e_local)  # fmt: skip
    else:
        for g in range(n_groups):
            for t in prange(n_bins):
                for k in range(group_start[g * n_bins + t], group_start[g * n_bins + t + 1]):
                    _node_cells(inner_runs[tasks[k], 0], level, leaf, children, codes, rgba, order, run_lo, run_hi, ent_start, ent_count,
                                e_cell, e_first, e_sum, e_node, e_local)  # fmt: skip
    for r in range(leaf_runs.shape[0]):
        run_lo[leaf_runs[r, 0]] = -1
    for r in range(inner_runs.shape[0]):
        run_lo[inner_runs[r, 0]] = -1


_NEAR_CELLS = 6  # a voxel key's lowest bits (the finest digits of its cell) kept as the low bits of its home slot


@njit(inline="always")
def _hash(k, mask):
    """A key's home slot: the 2^_NEAR_CELLS cells of one block of a node's grid (one Morton code
    prefix) get neighbouring slots, the blocks scattered: a batch's entries come sorted by cell,
    so neighbours found or entered one after the other share cache lines."""
    near = np.uint64(_NEAR_CELLS)
    return ((((k >> near) * _HASH_MUL) >> np.uint64(32 - _NEAR_CELLS)) & ~((np.uint64(1) << near) - np.uint64(1)) | (k & ((np.uint64(1) << near) - np.uint64(1)))) & mask


@njit(inline="always")
def _voxel_key(node, cell):
    return (np.uint64(node) << np.uint64(3 * GRID_BITS)) | cell


@njit(parallel=True, cache=True)
def voxel_lookup(hkeys, hvals, node, cell, vid, is_new):
    """Look each (list, cell) up in the open-addressing table (a list names its node): its voxel
    id into vid[e], or is_new[e] = 1. Returns how many are new (voxel_enter enters them; the
    caller first makes the table room for those, not for every entry: a batch in no spatial
    order has ~2 entries a point, most of them voxels already). The table is only read."""
    mask = np.uint64(hkeys.shape[0] - 1)
    n = node.shape[0]
    n_new = 0
    for e in prange(n):
        k = _voxel_key(node[e], cell[e])
        h = _hash(k, mask)
        new = 0
        while True:
            hk = hkeys[h]
            if hk == k:
                vid[e] = hvals[h]
                break
            if hk == EMPTY_KEY:
                new = 1
                break
            h = (h + np.uint64(1)) & mask
        is_new[e] = new
        n_new += new
    return n_new


@njit(parallel=True, cache=True)
def voxel_enter(hkeys, hvals, node, cell, next_vid, vid, is_new, n_parts):
    """Number the new entries (voxel_lookup's) ``next_vid`` on, in entry order, and enter them in
    the table (kept at most two thirds full by the caller), in parallel: a batch's entries never
    repeat a key, so part t of ``n_parts`` takes the keys whose home slot lies in its share of
    the table, and a key whose probe would run past that share is left to a pass in order after
    them (linear probing finds a key wherever it went, as long as no slot is emptied). Returns
    the next free id."""
    mask = np.uint64(hkeys.shape[0] - 1)
    n = node.shape[0]
    for e in range(n):
        if is_new[e]:
            vid[e] = next_vid
            next_vid += 1
    share = (np.int64(mask) + 1) // n_parts
    for t in prange(n_parts):
        lo = t * share
        hi = lo + share if t < n_parts - 1 else np.int64(mask) + 1
        for e in range(n):
            if is_new[e] != 1:
                continue
            k = _voxel_key(node[e], cell[e])
            h = np.int64(_hash(k, mask))
            if h < lo or h >= hi:
                continue
            while h < hi and hkeys[h] != EMPTY_KEY:
                h += 1
            if h == hi:
                is_new[e] = 2  # entered below
                continue
            hkeys[h] = k
            hvals[h] = vid[e]
    for e in range(n):
        if is_new[e] == 2:
            is_new[e] = 1
            k = _voxel_key(node[e], cell[e])
            h = _hash(k, mask)
            while hkeys[h] != EMPTY_KEY:
                h = (h + np.uint64(1)) & mask
            hkeys[h] = k
            hvals[h] = vid[e]
    return next_vid


@njit(cache=True)
def voxel_ids(hkeys, hvals, node, cell, next_vid, vid, is_new, n_parts):
    """voxel_lookup, then voxel_enter, for a table known to have room for every entry."""
    voxel_lookup(hkeys, hvals, node, cell, vid, is_new)
    return voxel_enter(hkeys, hvals, node, cell, next_vid, vid, is_new, n_parts)


@njit(cache=True)
def rehash(old_keys, old_vals, hkeys, hvals):
    """Enter every (key, voxel id) of the table ``old_keys``/``old_vals`` into the empty, larger
    table ``hkeys``/``hvals`` (the table is where voxel keys are kept: no array of its own)."""
    mask = np.uint64(hkeys.shape[0] - 1)
    for j in range(old_keys.shape[0]):
        k = old_keys[j]
        if k == EMPTY_KEY:
            continue
        h = _hash(k, mask)
        while hkeys[h] != EMPTY_KEY:
            h = (h + np.uint64(1)) & mask
        hkeys[h] = k
        hvals[h] = old_vals[j]


@njit(cache=True)
def voxel_table(lists, first_chunk, chunk_next, fill, chunk_size, level, low, hkeys, hvals, vox_slot):
    """The voxels of ``lists`` (inner nodes' lists) entered into an empty table, ids in list
    order, with their slots: a voxel's cell comes from its low word (the cell index
    per axis is its top bits). Returns the number of voxels."""
    mask = np.uint64(hkeys.shape[0] - 1)
    v = 0
    for j in range(lists.shape[0]):
        lst = lists[j]
        lev = level[lst // LISTS]
        bits = min(lev + GRID_BITS, CODE_BITS) - lev
        c = first_chunk[lst]
        while c >= 0:
            for s in range(c * chunk_size, c * chunk_size + fill[c]):
                w = low[s]
                cell = np.uint64(0)
                for a in range(3):
                    i = np.uint64(((w >> np.uint32(WORD_BITS * a)) & np.uint32(WORD_MASK)) >> np.uint32(WORD_BITS - bits))
                    for b in range(bits):
                        cell |= ((i >> np.uint64(b)) & np.uint64(1)) << np.uint64(3 * b + 2 - a)
                k = _voxel_key(lst, cell)
                h = _hash(k, mask)
                while hkeys[h] != EMPTY_KEY:
                    h = (h + np.uint64(1)) & mask
                hkeys[h] = k
                hvals[h] = v
                vox_slot[v] = s
                v += 1
            c = chunk_next[c]
    return v


@njit(cache=True)
def chunks_needed(lists, counts, chunk_size, last_chunk, fill):
    """How many new chunks appending counts[j] entries to list lists[j] takes, all j."""
    total = 0
    for j in range(lists.shape[0]):
        last = last_chunk[lists[j]]
        space = chunk_size - fill[last] if last >= 0 else 0
        extra = counts[j] - space
        if extra > 0:
            total += (extra + chunk_size - 1) // chunk_size
    return total


@njit(inline="always")
def _chunk_words(t, n):
    """u64 words of a stream of ``n`` points at t bits a point (core/compact.stream_words)."""
    return (n * t + 63) // 64 + 1 if t > 0 else 0


@njit(cache=True)
def allocate(lists, counts, chunk_size, first_chunk, last_chunk, level, leaf, cmin, edge, fill, chunk_next, chunk_node, bbox_min, bbox_max,
             chunk_level, ext_first, code, ext, level_bits, free, n_free, n_chunks, n_words, version, batch_version, slots):  # fmt: skip
    """Append counts[j] entries to list lists[j] (in this order): the pool slot of each entry
    in ``slots`` (entries of list j follow those of j - 1). A list's chunks are linked
    (first_chunk .. chunk_next .. last_chunk). A leaf's (point) chunk has its node's cube as
    box and a zeroed stream of level_bits[its level] bits an axis (EXT_FULL_BITS: wide; fewer
    where the points lie on a grid: ProgressiveOctree._level_bits), so a leaf's chunks share
    one code: it comes from the free list (split leaves' chunks, which keep their streams where
    those are long enough, else take a new one), else from the unused end of the pool with
    the next stream (``n_words`` in use: streams follow chunk order). An inner node's (voxel)
    chunk is new, of code 0 (an empty stream where the next one starts), its box the cube moved
    by VOXEL_SHIFT. The caller made room (``chunks_needed``; a wide stream for each new chunk).
    Every chunk written gets batch_version = version. Returns (n_free, n_chunks, n_words)."""
    e = 0
    for j in range(lists.shape[0]):
        lst = lists[j]
        node = lst // LISTS
        points = leaf[node] == 1
        bits = level_bits[level[node]] if points else 0
        want = _chunk_words(3 * bits, chunk_size)
        left = counts[j]
        while left > 0:
            c = last_chunk[lst]
            if c < 0 or fill[c] == chunk_size:
                if points and n_free > 0:
                    n_free -= 1
                    c = free[n_free]
                    f = np.int64(ext_first[c])  # a split leaf's chunk: its stream was written (a new one is the pool's zeros)
                    if want <= _chunk_words(code_bits(code[c]), chunk_size):
                        ext[f : f + want] = 0
                    else:  # a shorter stream than this leaf's: a new one at the end
                        ext_first[c] = n_words
                        n_words += want
                    code[c] = bits | bits << 8 | bits << 16
                else:
                    c = n_chunks
                    n_chunks += 1
                    ext_first[c] = n_words  # a voxel chunk's empty stream too: streams follow chunk order
                    code[c] = bits | bits << 8 | bits << 16
                    n_words += want
                fill[c] = 0
                chunk_next[c] = -1
                chunk_node[c] = node
                chunk_level[c] = level[node]
                shift = 0.0 if points else VOXEL_SHIFT * edge[node]
                for a in range(3):
                    bbox_min[c, a] = cmin[node, a] - shift
                    bbox_max[c, a] = bbox_min[c, a] + edge[node]
                if last_chunk[lst] >= 0:
                    chunk_next[last_chunk[lst]] = c
                else:
                    first_chunk[lst] = c
                last_chunk[lst] = c
            take = min(left, chunk_size - fill[c])
            base = c * chunk_size + fill[c]
            for t in range(take):
                slots[e + t] = base + t
            fill[c] += take
            batch_version[c] = version
            e += take
            left -= take
    return n_free, n_chunks, n_words


@njit(cache=True)
def list_slots(first_chunk, chunk_next, fill, chunk_size, lst, out):
    """The pool slots of a list's entries, in order, into ``out``; returns how many."""
    k = 0
    c = first_chunk[lst]
    while c >= 0:
        base = c * chunk_size
        for t in range(fill[c]):
            out[k] = base + t
            k += 1
        c = chunk_next[c]
    return k


@njit(cache=True)
def free_chunks(first_chunk, last_chunk, chunk_next, fill, lst, free, n_free):
    """Hand a list's chunks back to the free list (its entries are gone)."""
    c = first_chunk[lst]
    while c >= 0:
        nxt = chunk_next[c]
        fill[c] = 0
        chunk_next[c] = -1
        free[n_free] = c
        n_free += 1
        c = nxt
    first_chunk[lst] = -1
    last_chunk[lst] = -1
    return n_free


@njit(inline="always")
def _words(x, y, z, mx, my, mz, inv):
    """A position in the cube [m, m + 1/inv]^3 at 30 bits an axis: its low word (bits 20-29 of
    each axis) and the 20 bits under them, x y z back to back (a wide batch's stream bits)."""
    wl = np.uint32(0)
    v = np.uint64(0)
    for a in range(3):
        p = x if a == 0 else (y if a == 1 else z)
        m = mx if a == 0 else (my if a == 1 else mz)
        q = min(max(np.int64((p - m) * inv), 0), _MAX30)
        wl |= np.uint32((q >> 20) & WORD_MASK) << np.uint32(WORD_BITS * a)
        v |= np.uint64(q & _M20) << np.uint64(EXT_FULL_BITS * a)
    return wl, v


@njit(inline="always")
def _scatter(src, dst, order, slots, o, lo, hi):
    for i in range(lo, hi):
        dst[slots[o + i]] = src[order[i]]


@njit(inline="always")
def _scatter_attributes(attr_src, attr_dst, attr_width, order, slots, o, lo, hi):
    """dst[slots[o + i]] = src[order[i]], i in lo..hi, for every attribute (``attr_src[a]`` into
    ``attr_dst[a]``, as bytes, ``attr_width[a]`` (1, 2, 4 or 8) a value: one kernel for any
    set of attribute types)."""
    for a in range(len(attr_src)):
        src, dst, width = attr_src[a], attr_dst[a], attr_width[a]
        if width == 1:
            _scatter(src, dst, order, slots, o, lo, hi)
        elif width == 2:
            _scatter(src.view(np.uint16), dst.view(np.uint16), order, slots, o, lo, hi)
        elif width == 4:
            _scatter(src.view(np.uint32), dst.view(np.uint32), order, slots, o, lo, hi)
        else:
            _scatter(src.view(np.uint64), dst.view(np.uint64), order, slots, o, lo, hi)


_ROWS_A_TASK = 8192
_GATHER_BLOCK = 256  # points whose positions a kernel gathers before it works on them


@njit(parallel=True, cache=True)
def scatter_rows(attr_src, attr_dst, attr_width, rows, slots):
    """Every attribute's value of row rows[k] into pool slot slots[k] (new voxels take their
    cell's first point's: numpy's gather and scatter an attribute took 0.3 s of a 20 M-point load)."""
    n = rows.shape[0]
    for t in prange((n + _ROWS_A_TASK - 1) // _ROWS_A_TASK):
        lo = t * _ROWS_A_TASK
        _scatter_attributes(attr_src, attr_dst, attr_width, rows, slots, 0, lo, min(lo + _ROWS_A_TASK, n))


@njit(parallel=True, cache=True)
def write_points(xyz, rgba, attr_src, attr_dst, attr_width, order, leaf_runs, run_offsets, slots, cmin, edge, low, ext, ext_first,
                 code, chunk_size, color, run_min, run_max):  # fmt: skip
    """Each leaf run's points quantized into their leaf's cube (30 bits) at their slots: the low
    word, and in their chunk's stream (zeroed when allocated; a leaf's chunks are its own, so
    runs never share a stream word) the 20 bits under it an axis (a wide chunk), or the top e of
    them in a chunk of code e (e e e: the points lie on a grid of 2^(10 + e) steps an axis of
    the cube, and each is written as the grid cell it is in, whose centre it then is: the grid
    point nearest to it), their colour and attributes (``_scatter_attributes``: one
    parallel region for all of them). The runs index the sorted points, point k
    of which is xyz[order[k]] (no sorted copy of positions made), its colour rgba[k] (sorted).
    Each run's bounding box goes to run_min[r] / run_max[r] (``grow_bounds``)."""
    for r in prange(leaf_runs.shape[0]):
        node, lo, hi = leaf_runs[r, 0], leaf_runs[r, 1], leaf_runs[r, 2]
        inv = _SCALE30 / edge[node]
        mx, my, mz = cmin[node, 0], cmin[node, 1], cmin[node, 2]
        o = run_offsets[r] - lo
        c_start, c_end, c_words = np.int64(0), np.int64(-1), np.int64(0)  # the slots' chunk: slots run on within it
        t, e_bits = np.int64(WIDE_BITS), np.int64(EXT_FULL_BITS)
        lx = ly = lz = np.inf
        hx = hy = hz = -np.inf
        block = np.empty((_GATHER_BLOCK, 3))
        for b in range(lo, hi, _GATHER_BLOCK):
            e = min(b + _GATHER_BLOCK, hi)
            for i in range(b, e):  # gathered first, in a loop of independent loads whose misses overlap (as core/quantize.gather_batch): 2.3-2.8x
                j = order[i]
                block[i - b, 0], block[i - b, 1], block[i - b, 2] = xyz[j, 0], xyz[j, 1], xyz[j, 2]
            for i in range(b, e):
                s = slots[o + i]
                x, y, z = block[i - b, 0], block[i - b, 1], block[i - b, 2]
                lx, ly, lz = min(lx, x), min(ly, y), min(lz, z)
                hx, hy, hz = max(hx, x), max(hy, y), max(hz, z)
                wl, v = _words(x, y, z, mx, my, mz, inv)
                low[s] = wl
                if s < c_start or s >= c_end:  # a division a chunk, not a point: 1.2x the kernel's speed
                    c = s // chunk_size
                    c_start, c_end, c_words = c * chunk_size, (c + 1) * chunk_size, np.int64(ext_first[c])
                    t = code_bits(code[c])
                    e_bits = t // 3
                if e_bits != EXT_FULL_BITS:  # each axis's top e bits: its grid cell
                    v = _narrowed(v, e_bits)
                p = (s - c_start) * t
                w = c_words + (p >> 6)
                sh = np.uint64(p & 63)
                ext[w] |= v << sh
                if (p & 63) + t > 64:
                    ext[w + 1] |= v >> (np.uint64(64) - sh)
                color[s] = rgba[i]
        run_min[r, 0], run_min[r, 1], run_min[r, 2] = lx, ly, lz
        run_max[r, 0], run_max[r, 1], run_max[r, 2] = hx, hy, hz
        _scatter_attributes(attr_src, attr_dst, attr_width, order, slots, o, lo, hi)


@njit(inline="always")
def _narrowed(v, e):
    """A wide point's 60 stream bits (20 an axis) as e bits an axis: each axis's top e."""
    s = np.uint64(EXT_FULL_BITS - e)
    mask = (np.uint64(1) << np.uint64(e)) - np.uint64(1)
    w = np.uint64(0)
    for a in range(3):
        w |= ((v >> (np.uint64(EXT_FULL_BITS * a) + s)) & mask) << np.uint64(e * a)
    return w


@njit(inline="always")
def _bits(t):
    return (np.uint64(1) << np.uint64(t)) - np.uint64(1)


@njit(inline="always")
def _grid_cell(wl):
    """A point's cell of its leaf's own 128³ grid: the top GRID_BITS of each axis's low-word bits."""
    m = np.uint32((1 << GRID_BITS) - 1)
    sh = np.uint32(WORD_BITS - GRID_BITS)
    x = (wl >> sh) & m
    y = (wl >> (sh + np.uint32(WORD_BITS))) & m
    z = (wl >> (sh + np.uint32(2 * WORD_BITS))) & m
    return np.int64(x) | (np.int64(y) << GRID_BITS) | (np.int64(z) << (2 * GRID_BITS))


@njit(inline="always")
def _swap(a, front, back, m):
    """a[front[q]] and a[back[q]] traded, q < m."""
    for q in range(m):
        a[front[q]], a[back[q]] = a[back[q]], a[front[q]]


@njit(parallel=True, cache=True)
def order_leaves(leaves, first_chunk, chunk_next, fill, list_count, chunk_size, low, ext, ext_first, code, color, attr_views, attr_width,
                 batch_version, version, n_parts, grid_sample):  # fmt: skip
    """Each leaf's entries reordered in place (its chunks are its own) so that they begin with
    one point of every occupied cell of the leaf's own 128³ grid, the first of the cell in the
    list: a prefix of the list is then the grid sample a converted octree's node of that size
    holds, which frames draw where the leaf is too small on screen for its points to matter one
    by one (``grid_sample[leaf]``: the sample's size). Each such point behind the prefix trades
    places with one in it that is not (few move: the first of a cell is mostly near the front;
    neither part keeps its order). Positions (low word and stream bits), colours and attributes
    move together; the chunks' ``batch_version`` is bumped. Leaves spread over ``n_parts``
    threads, each its own bitmap of cells seen (cleared after each leaf)."""
    for t in prange(n_parts):
        seen = np.zeros((1 << (3 * GRID_BITS)) // 64, np.uint64)
        for j in range(t, leaves.shape[0], n_parts):
            lst = leaves[j] * LISTS
            slots = np.empty(list_count[lst], np.int64)
            n = list_slots(first_chunk, chunk_next, fill, chunk_size, lst, slots)
            c = first_chunk[lst]
            while c >= 0:  # its chunks change
                batch_version[c] = version
                c = chunk_next[c]
            cells = np.empty(n, np.int64)
            for i in range(n):  # once, in a loop of their own
                cells[i] = _grid_cell(low[slots[i]])
            first = np.zeros(n, np.bool_)
            n_first = 0
            for i in range(n):  # the first point of each cell
                cell = cells[i]
                bit = np.uint64(1) << np.uint64(cell & 63)
                if not seen[cell >> 6] & bit:
                    seen[cell >> 6] |= bit
                    first[i] = True
                    n_first += 1
            for i in range(n):  # the bitmap cleared for the next leaf
                if first[i]:
                    seen[cells[i] >> 6] = 0
            front = np.empty(n_first, np.int64)  # pairs to trade: one in the prefix that is no first, one behind it that is
            back = np.empty(n_first, np.int64)
            m = 0
            i, k = 0, n_first
            while True:  # as many of each: they run out together
                while i < n_first and first[i]:
                    i += 1
                while k < n and not first[k]:
                    k += 1
                if i >= n_first or k >= n:
                    break
                front[m], back[m] = slots[i], slots[k]
                m += 1
                i += 1
                k += 1
            t = code_bits(code[first_chunk[lst]])  # the stream bits a point (a leaf's chunks share one code)
            for q in range(m):
                ca, cb = front[q] // chunk_size, back[q] // chunk_size
                ja, jb = front[q] - ca * chunk_size, back[q] - cb * chunk_size
                va = read_ext(ext, ext_first[ca], t, ja) & _bits(t)
                vb = read_ext(ext, ext_first[cb], t, jb) & _bits(t)
                write_ext(ext, ext_first[ca], t, ja, vb)
                write_ext(ext, ext_first[cb], t, jb, va)
            _swap(low, front, back, m)
            _swap(color, front, back, m)
            for a in range(len(attr_views)):
                view, width = attr_views[a], attr_width[a]
                if width == 1:
                    _swap(view, front, back, m)
                elif width == 2:
                    _swap(view.view(np.uint16), front, back, m)
                elif width == 4:
                    _swap(view.view(np.uint32), front, back, m)
                else:
                    _swap(view.view(np.uint64), front, back, m)
            grid_sample[leaves[j]] = n_first


@njit(cache=True)
def grow_bounds(leaf_runs, run_min, run_max, parent, point_min, point_max):
    """Each run's box (write_points') into its leaf's and its ancestors' bounds of the points
    below them, up to the first that holds it already (its ancestors hold their descendants')."""
    for r in range(leaf_runs.shape[0]):
        node = leaf_runs[r, 0]
        while node >= 0:
            grew = False
            for a in range(3):
                if run_min[r, a] < point_min[node, a]:
                    point_min[node, a] = run_min[r, a]
                    grew = True
                if run_max[r, a] > point_max[node, a]:
                    point_max[node, a] = run_max[r, a]
                    grew = True
            if not grew:
                break
            node = parent[node]


@njit(inline="always")
def _add_sums(vox_sum, v, sums, e):
    """vox_sum[v] (u32) += sums[e] (a set's: u32 under 2^24 points, else u64), halved k times (rounded) where
    the count reaches 2^VOXEL_WEIGHT_BITS: the mean stays, the u32 sums cannot overflow."""
    n = np.uint64(vox_sum[v, 4]) + np.uint64(sums[e, 4])
    k = np.uint64(0)
    while (n >> k) >= np.uint64(1 << VOXEL_WEIGHT_BITS):
        k += np.uint64(1)
    half = (np.uint64(1) << k) >> np.uint64(1)
    for ch in range(5):
        vox_sum[v, ch] = np.uint32((np.uint64(vox_sum[v, ch]) + np.uint64(sums[e, ch]) + half) >> k)


@njit(cache=True)
def set_voxel_sums(vox_sum, vid, sums):
    """vox_sum[vid[e]] = sums[e] (u32 or u64, all the points a voxel stands for), fitted as ``_add_sums``
    fits them (the voxels' build state rebuilt after a trim)."""
    for e in range(vid.shape[0]):
        for ch in range(5):
            vox_sum[vid[e], ch] = 0
        _add_sums(vox_sum, vid[e], sums, e)


@njit(inline="always")
def _chunk_of(slot, per_chunk):
    """slot // chunk_size, ``per_chunk`` its reciprocal: a product, not a 64-bit division (~40
    cycles). Exact: slots are u32 and chunks at most 2^20 entries, so (slot + 0.5) / chunk_size
    lies at least 2^-21 from an integer, and the product's error is under 2^-24."""
    return np.int64((np.float64(slot) + 0.5) * per_chunk)


@njit(inline="always")
def _mean_color(sums, v):
    """The rounded mean, (sum + n / 2) // n a channel, by one reciprocal, not four integer
    divisions (~40 cycles each: a third of write_voxels): the mean is at most 255 and n < 2^24,
    so a quotient's fraction is 0 or at least 2^-24 from an integer, and the product's error
    (under 2^-43) plus 2^-32 never crosses one."""
    n = sums[v, 4]
    h = np.float64(n >> np.uint32(1)) + 2.0**-32 * np.float64(n)
    inv = 1.0 / np.float64(n)
    c = np.uint32(0)
    for ch in range(4):
        c |= np.uint32((np.float64(sums[v, ch]) + h) * inv) << np.uint32(8 * ch)
    return c


@njit(parallel=True, cache=True)
def write_voxels(vid, is_new, node, cell, sums, level, slots_of_new, first_new, vox_sum, vox_slot,
                 low, color, batch_version, chunk_size, version):  # fmt: skip
    """Add each entry's color sums to its voxel; a new voxel also gets its slot and
    position (its cell's centre: the low word alone, VOXEL_SHIFT); every touched voxel's
    drawn color becomes the rounded mean of the points it stands for. New voxels have the ids
    ``first_new`` on in entry order, so voxel v's slot is slots_of_new[v - first_new]."""
    per_chunk = 1.0 / chunk_size
    for e in prange(vid.shape[0]):
        v = vid[e]
        if is_new[e]:
            s = slots_of_new[v - first_new]
            vox_slot[v] = s
            for ch in range(5):
                vox_sum[v, ch] = 0
            lev = level[node[e] // LISTS]
            bits = min(lev + GRID_BITS, CODE_BITS) - lev  # bits per axis of the cell index
            c = cell[e]
            i0 = np.int64(0)
            i1 = np.int64(0)
            i2 = np.int64(0)
            for b in range(bits):
                digit = (c >> np.uint64(3 * b)) & np.uint64(7)
                i0 |= np.int64((digit >> np.uint64(2)) & np.uint64(1)) << b
                i1 |= np.int64((digit >> np.uint64(1)) & np.uint64(1)) << b
                i2 |= np.int64(digit & np.uint64(1)) << b
            shift = WORD_BITS - bits  # the cell's centre: index, then a one, then zeros (the low word's)
            wl = np.uint32(0)
            for a in range(3):
                ia = i0 if a == 0 else (i1 if a == 1 else i2)
                q = (ia << shift) | (np.int64(1) << (shift - 1))
                wl |= np.uint32(q & WORD_MASK) << np.uint32(WORD_BITS * a)
            low[s] = wl
        else:  # its chunk changes (a new voxel's got its version where allocate gave it its slot)
            batch_version[_chunk_of(vox_slot[v], per_chunk)] = version
        # entries of one batch never share a voxel (one entry per node and cell), so no race
        _add_sums(vox_sum, v, sums, e)
        color[vox_slot[v]] = _mean_color(vox_sum, v)


@njit(parallel=True, cache=True)
def dequantize_slots(low, ext, ext_first, code, chunk_size, slots, chunk_node, box_min, edge, out):
    """float64 positions (30-bit cell centres) of the entries at pool ``slots``, through the
    compact layout's decoder (core/compact.py): an entry's chunk belongs to a node, whose chunks'
    box starts at ``box_min[node]`` with edge ``edge[node]``. A wide axis's words are floor-quantized
    (+ half a 30-bit cell); a grid chunk's and a voxel's (code 0) hold their cell's centre already
    (``compact.centre_half``)."""
    for k in prange(slots.shape[0]):
        s = slots[k]
        c = s // chunk_size
        node = chunk_node[c]
        inv = edge[node] / _SCALE30
        cd = code[c]
        med, high = tail_words(read_ext(ext, ext_first[c], code_bits(cd), s - c * chunk_size), cd)
        for a in range(3):
            half = 0.5 if (cd >> np.uint32(8 * a)) & np.uint32(0xFF) == EXT_FULL_BITS else 0.0
            sh = np.uint32(WORD_BITS * a)
            q = (np.int64((low[s] >> sh) & np.uint32(WORD_MASK)) << 20) | (np.int64((med >> sh) & np.uint32(WORD_MASK)) << 10)
            q |= np.int64((high >> sh) & np.uint32(WORD_MASK))
            out[k, a] = box_min[node, a] + (q + half) * inv


# --- streams on the source's grid (ProgressiveOctree.trim) -----------------------------------
# A point on the source's grid, in a node cube 2^B source steps wide and aligned to that grid
# (ProgressiveOctree's ``grid``), sits at a cell centre of the cube's 2^B grid: its wide 20 bits
# an axis are the cell's B - 10 bits, then the half-cell bit and zeros, give or take what its
# quantization lost: a point spilled from a split leaf is inserted again from its position there
# (half a 30-bit cell of the first leaf it landed in, at worst the root: 2^(level - 1) cells of
# its leaf's), and truncation one more. The compact layout (core/compact.py) keeps the B - 10
# bits and implies the rest, so a trimmed point chunk holds 3 (B - 10) bits a point, not 60,
# and each point is its grid cell's centre again.
@njit(parallel=True, cache=True)
def grid_widths(fill, code, chunk_node, level, root_bits, ext, ext_first, out):
    """Per chunk, the stream bits an axis it keeps: e = B - 10 (1..10; B = ``root_bits`` -
    its node's level) where each of its points sits at a cell centre of its node's 2^B grid
    (the bits under the cell's within 2^level + 2 of the half-cell bit: what quantization may
    have lost, a 16th of a grid step at most); EXT_FULL_BITS where not (off the grid, B outside
    11..20, or an empty point chunk); 0 for a chunk without a stream (voxels)."""
    for c in prange(fill.shape[0]):
        if code[c] == 0:
            out[c] = 0
            continue
        if code[c] != WIDE_CODE:  # written on the grid already (ProgressiveOctree._level_bits)
            out[c] = np.int64(code[c] & 255)
            continue
        out[c] = EXT_FULL_BITS
        lev = level[chunk_node[c]]
        b = root_bits - lev
        if fill[c] == 0 or b <= WORD_BITS or b > EXT_FULL_BITS:
            continue
        s = np.uint64(EXT_FULL_BITS + WORD_BITS - b)  # the bits under the cell's, per axis
        tolerance = (np.int64(1) << lev) + 2
        if tolerance << 4 > np.int64(1) << np.int64(s):
            continue
        below = (np.uint64(1) << s) - np.uint64(1)
        half = np.int64(1) << np.int64(s - np.uint64(1))
        on_grid = True
        for j in range(fill[c]):
            v = read_ext(ext, ext_first[c], WIDE_BITS, j)
            for a in range(3):
                under = np.int64((v >> np.uint64(EXT_FULL_BITS * a)) & below)
                if abs(under - half) > tolerance:
                    on_grid = False
            if not on_grid:
                break
        if on_grid:
            out[c] = b - WORD_BITS


@njit(parallel=True, cache=True)
def pack_streams(fill, code, widths, ext, ext_first, out, out_first):
    """Each point chunk's stream (layout ``code``) rewritten into ``out`` (zeroed) at
    ``out_first``: e = widths[c] bits an axis (the compact layout's x y z back to back: a chunk
    of that width already as it is, else a wide chunk's each axis's cell bits, the bits under
    them dropped)."""
    for c in prange(fill.shape[0]):
        e = widths[c]
        if e == 0:
            continue
        t, held = 3 * e, code_bits(code[c])
        if held == t:  # written in these bits (while filling): its words as they are, cut to its points
            w = _chunk_words(t, fill[c])
            out[out_first[c] : out_first[c] + w] = ext[ext_first[c] : ext_first[c] + w]
            continue
        for j in range(fill[c]):  # a wide chunk's: each point's cell bits
            write_ext(out, out_first[c], t, j, _narrowed(read_ext(ext, ext_first[c], held, j) & _bits(held), e))


@njit(parallel=True, cache=True)
def on_grid(xyz, point, step, tolerance):
    """Whether every point lies within ``tolerance`` steps of the grid ``point`` + k ``step`` on
    each axis (so that writing it as its grid cell, write_points, moves it that little at most)."""
    off = 0
    for i in prange(xyz.shape[0]):
        for a in range(3):
            r = (xyz[i, a] - point[a]) / step
            if not on_the_grid(xyz[i, a], r, np.round(r), step, tolerance):
                off += 1
    return off == 0


@njit(parallel=True, cache=True)
def restream(fill, code, wide, ext, ext_first, out, out_first):
    """Each point chunk's stream (layout ``code``) into ``out`` (zeroed) at ``out_first``, where
    each has room for a whole chunk (``pack_streams`` left a stream as long as its points): as
    it is, or ``wide``, 60 bits a point, through the layout's decoder (``wide_bits``: the 20 bits
    an axis a frame draws)."""
    for c in prange(fill.shape[0]):
        cd = code[c]
        if cd == 0:
            continue
        t = code_bits(cd)
        if not wide:  # the same bits in a longer stream: its words as they are (as pack_streams copies them)
            w = _chunk_words(t, fill[c])
            out[out_first[c] : out_first[c] + w] = ext[ext_first[c] : ext_first[c] + w]
            continue
        for j in range(fill[c]):
            write_ext(out, out_first[c], WIDE_BITS, j, wide_bits(read_ext(ext, ext_first[c], t, j) & _bits(t), cd))
