"""Building a layered-point-cloud octree over points sorted by code (see keys.py).

Every node is a contiguous run ``starts[k]:ends[k]`` of the sorted points; a point is
*owned* by the node at level ``ownlevel[i]`` on its path. Leaves own their whole run at
first; sampling then goes bottom-up, level by level: an inner node's candidates are the
points its children own (``ownlevel == level + 1``), and the ones its sampler accepts move
up to it. Every point is therefore owned by exactly one node: stored exactly once.

Color filtering: each point carries the sum of the colors it stands for and their count
(``wsum``, ``wcount``); an accepted point absorbs the sums of the candidates it stands for
(its grid cell, or the ones its Poisson disc rejected), so inner-node colors are the
average of all the input points they represent.

Samplers (both give the spacing ``cube edge / 128 / 2^level``):

- ``grid``: the first candidate (in code order) of each cell of the node's 128³ grid;
  cells are code prefixes, so they are contiguous runs and need no hash table.
- ``poisson``: a candidate is accepted only when no accepted point lies closer than the
  spacing (a hash grid of spacing-sized cells, 27 neighbours checked).
"""

from __future__ import annotations

import numba
import numpy as np
from numba import njit, prange

from .keys import CODE_BITS, MAX_LEVEL, key_cube, key_range

SAMPLERS = {"grid": 0, "poisson": 1}
_OFFSETS = np.array(
    sorted(([x, y, z] for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1)), key=lambda v: abs(v[0]) + abs(v[1]) + abs(v[2])),
    np.int64,
)
GRID_BITS = 7  # 128 cells per axis and node


@njit(inline="always")
def _grid_node(codes, ownlevel, wsum, wcount, s, e, level, grid_bits):
    cell_level = min(level + grid_bits, CODE_BITS)
    shift = np.uint64(3 * (CODE_BITS - cell_level))
    acc = -1
    prev = np.uint64(0)
    child = level + 1
    for i in range(s, e):
        if ownlevel[i] != child:
            continue
        cell = codes[i] >> shift
        if acc < 0 or cell != prev:
            acc = i
            prev = cell
            ownlevel[i] = level
        else:
            wsum[acc, 0] += wsum[i, 0]
            wsum[acc, 1] += wsum[i, 1]
            wsum[acc, 2] += wsum[i, 2]
            wcount[acc] += wcount[i]


@njit(inline="always")
def _poisson_node(xyz, ownlevel, wsum, wcount, s, e, level, nmin, radius, cells, heads, near):
    """Poisson-disc sampling of one node; ``heads`` ((cells + 2)³, all -1: a cell grid with a
    border, so the 27 neighbours of a cell need no bounds tests) is the thread's, handed back
    all -1; ``near`` the 27 neighbour offsets into it, own cell first."""
    child = level + 1
    m = 0
    for i in range(s, e):
        if ownlevel[i] == child:
            m += 1
    # 32-bit links and cell ids: half the cache footprint of the grid walk
    nxt = np.empty(m, np.int32)
    pid = np.empty(m, np.int32)
    pcell = np.empty(m, np.int32)
    n_acc = 0
    r2 = radius * radius
    inv = 1.0 / radius
    cp = cells + 2
    for i in range(s, e):
        if ownlevel[i] != child:
            continue
        c0 = min(max(np.int64((xyz[i, 0] - nmin[0]) * inv), 0), cells - 1)
        c1 = min(max(np.int64((xyz[i, 1] - nmin[1]) * inv), 0), cells - 1)
        c2 = min(max(np.int64((xyz[i, 2] - nmin[2]) * inv), 0), cells - 1)
        cid = ((c0 + 1) * cp + c1 + 1) * cp + c2 + 1
        found = -1
        for o in range(27):  # the point's own cell first: that is where a close neighbour usually is
            j = heads[cid + near[o]]
            while j >= 0:
                q = pid[j] + s
                d0 = xyz[i, 0] - xyz[q, 0]
                d1 = xyz[i, 1] - xyz[q, 1]
                d2 = xyz[i, 2] - xyz[q, 2]
                if d0 * d0 + d1 * d1 + d2 * d2 < r2:
                    found = q
                    break
                j = nxt[j]
            if found >= 0:
                break
        if found >= 0:
            wsum[found, 0] += wsum[i, 0]
            wsum[found, 1] += wsum[i, 1]
            wsum[found, 2] += wsum[i, 2]
            wcount[found] += wcount[i]
        else:
            ownlevel[i] = level
            pid[n_acc] = i - s
            pcell[n_acc] = cid
            nxt[n_acc] = heads[cid]
            heads[cid] = n_acc
            n_acc += 1
    for j in range(n_acc):
        heads[pcell[j]] = -1


@njit(parallel=True, cache=True)
def _sample_level(codes, xyz, ownlevel, wsum, wcount, starts, ends, node_min, level, sampler, radius, grid_bits, n_threads):
    """Sample every inner node of one level (nodes are disjoint). Thread t takes nodes t, t + T, ...
    (largest first), reusing one dense cell grid for the Poisson sampler."""
    cells = 1 << grid_bits
    cp = cells + 2
    near = np.empty(27, np.int64)
    for o in range(27):
        near[o] = (_OFFSETS[o, 0] * cp + _OFFSETS[o, 1]) * cp + _OFFSETS[o, 2]
    sizes = ends - starts
    by_size = np.argsort(-sizes)
    for t in prange(n_threads):
        heads = np.full(cp * cp * cp if sampler == 1 else 1, -1, np.int32)
        for r in range(t, starts.shape[0], n_threads):
            k = by_size[r]
            if sampler == 0:
                _grid_node(codes, ownlevel, wsum, wcount, starts[k], ends[k], level, grid_bits)
            else:
                _poisson_node(xyz, ownlevel, wsum, wcount, starts[k], ends[k], level, node_min[k], radius, cells, heads, near)


@njit(parallel=True, cache=True)
def _count_owned(ownlevel, starts, ends, levels, counts):
    for k in prange(starts.shape[0]):
        c = 0
        lev = levels[k]
        for i in range(starts[k], ends[k]):
            if ownlevel[i] == lev:
                c += 1
        counts[k] = c


@njit(parallel=True, cache=True)
def _scatter_owned(ownlevel, starts, ends, levels, offsets, perm):
    for k in prange(starts.shape[0]):
        p = offsets[k]
        lev = levels[k]
        for i in range(starts[k], ends[k]):
            if ownlevel[i] == lev:
                perm[p] = i
                p += 1


def sort_codes(codes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(sorted codes, stable order): ``morton_order`` plus the sorted keys the radix sort already
    holds, which saves gathering the codes again."""
    from ..core.morton import _sort_codes, morton_order

    codes = np.ascontiguousarray(codes, dtype=np.uint64)
    if len(codes) == 0:
        return codes, morton_order(codes)
    previous = numba.get_parallel_chunksize()
    numba.set_parallel_chunksize(8)  # as morton_order: buckets vary wildly in size
    try:
        return _sort_codes(codes, numba.get_num_threads(), np.uint32 if len(codes) < 2**32 else np.int64)
    finally:
        numba.set_parallel_chunksize(previous)


class Tree:
    """Nodes over sorted codes: keys, levels, runs and whether each is a leaf (parallel arrays)."""

    def __init__(self, keys, levels, starts, ends, leaf):
        self.keys = np.asarray(keys, np.uint64)
        self.levels = np.asarray(levels, np.int32)
        self.starts = np.asarray(starts, np.int64)
        self.ends = np.asarray(ends, np.int64)
        self.leaf = np.asarray(leaf, bool)

    def __len__(self) -> int:
        return len(self.keys)


def _child_runs(codes, key: int, s: int, e: int):
    level, lo, _ = key_range(key)
    shift = 3 * (CODE_BITS - level - 1)
    bounds = np.array([lo + (c << shift) for c in range(9)], np.uint64)
    cuts = s + np.searchsorted(codes[s:e], bounds, side="left")
    return [(key << 3 | c, int(cuts[c]), int(cuts[c + 1])) for c in range(8) if cuts[c + 1] > cuts[c]]


def split_tree(codes: np.ndarray, root_key: int, max_leaf: int, max_level: int = MAX_LEVEL) -> Tree:
    """Top-down: split runs of sorted ``codes`` until nodes hold at most ``max_leaf`` points."""
    keys, levels, starts, ends, leaf = [], [], [], [], []
    stack = [(int(root_key), 0, len(codes))]
    while stack:
        key, s, e = stack.pop()
        level = (key.bit_length() - 1) // 3
        is_leaf = e - s <= max_leaf or level >= max_level
        keys.append(key)
        levels.append(level)
        starts.append(s)
        ends.append(e)
        leaf.append(is_leaf)
        if not is_leaf:
            stack.extend(_child_runs(codes, key, s, e))
    return Tree(keys, levels, starts, ends, leaf)


def upper_tree(codes: np.ndarray, leaf_keys, top: int = 1) -> Tree:
    """The given nodes (as leaves) and all their ancestors up to ``top`` (the root by default;
    it must be an ancestor of every leaf), over sorted ``codes``."""
    leaf_keys = {int(k) for k in leaf_keys}
    nodes = set(leaf_keys)
    for k in leaf_keys:
        while k > top:
            k >>= 3
            nodes.add(k)
    keys = sorted(nodes)
    levels, starts, ends = [], [], []
    for k in keys:
        level, lo, hi = key_range(k)
        levels.append(level)
        s, e = np.searchsorted(codes, np.array([lo, hi], np.uint64), side="left")
        starts.append(int(s))
        ends.append(int(e))
    return Tree(keys, levels, starts, ends, [k in leaf_keys for k in keys])


def sample_tree(tree: Tree, codes, xyz, ownlevel, wsum, wcount, sampler: str, origin, edge: float) -> None:
    """Bottom-up sampling of the inner nodes of ``tree`` (``ownlevel`` must mark the leaves' points)."""
    mode = SAMPLERS[sampler]
    inner = ~tree.leaf
    for level in sorted(set(tree.levels[inner].tolist()), reverse=True):
        sel = np.flatnonzero(inner & (tree.levels == level))
        nmin, _ = key_cube(tree.keys[sel], origin, edge)
        radius = edge / (1 << GRID_BITS) / float(1 << level)
        n_threads = max(1, min(numba.get_num_threads(), len(sel)))
        _sample_level(codes, xyz, ownlevel, wsum, wcount, tree.starts[sel], tree.ends[sel], nmin, level, mode, radius, GRID_BITS, n_threads)


def init_ownlevel(tree: Tree, n: int) -> np.ndarray:
    own = np.full(n, -1, np.int8)
    for k in np.flatnonzero(tree.leaf):
        own[tree.starts[k] : tree.ends[k]] = tree.levels[k]
    return own


def owned_order(tree: Tree, ownlevel) -> tuple[np.ndarray, np.ndarray]:
    """(perm, counts): points grouped by owning node in tree order, and each node's count."""
    counts = np.empty(len(tree), np.int64)
    lev8 = tree.levels.astype(np.int8)
    _count_owned(ownlevel, tree.starts, tree.ends, lev8, counts)
    offsets = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    perm = np.empty(int(counts.sum()), np.int64)
    _scatter_owned(ownlevel, tree.starts, tree.ends, lev8, offsets, perm)
    return perm, counts


@njit(parallel=True, cache=True)
def _filtered(rgba8, wsum, wcount, idx, out8):
    for i in prange(idx.shape[0]):
        k = idx[i]
        inv = 1.0 / max(wcount[k], 1.0)
        for c in range(3):
            out8[i, c] = np.uint8(min(max(np.floor(wsum[k, c] * inv + 0.5), 0.0), 255.0))
        out8[i, 3] = rgba8[k, 3]


def filtered_colors(
    rgba_u32: np.ndarray, wsum: np.ndarray, wcount: np.ndarray, idx: np.ndarray | None = None, out: np.ndarray | None = None
) -> np.ndarray:
    """u32 RGBA of points ``idx``: the average color each stands for (alpha kept); into ``out`` when given."""
    if idx is None:
        idx = np.arange(len(rgba_u32), dtype=np.int64)
    out = np.empty(len(idx), np.uint32) if out is None else np.asarray(out)
    _filtered(np.ascontiguousarray(rgba_u32).view(np.uint8).reshape(-1, 4), wsum, wcount, idx, out.view(np.uint8).reshape(-1, 4))
    return out


@njit(parallel=True, cache=True)
def _color_sums(rgba8, wsum, wcount):
    for i in prange(rgba8.shape[0]):
        for c in range(3):
            wsum[i, c] = rgba8[i, c]
        wcount[i] = 1.0


def color_sums(rgba_u32: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(float64 (n, 3) RGB sums, float64 counts) of single points: their own color, weight 1."""
    n = len(rgba_u32)
    wsum = np.empty((n, 3), np.float64)
    wcount = np.empty(n, np.float64)
    _color_sums(np.ascontiguousarray(rgba_u32).view(np.uint8).reshape(-1, 4), wsum, wcount)
    return wsum, wcount
