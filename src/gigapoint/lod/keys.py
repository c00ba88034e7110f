"""Integer octree node keys and the point codes they are cut from.

A point's *code* interleaves 21 bits per axis of its position in the octree's cube with
Potree's child order (bit 2 = x, bit 1 = y, bit 0 = z at every level), so sorting points
by code makes every node's points one contiguous run and a node's 128³ sampling cells
contiguous sub-runs. A node *key* is the code prefix of its level with a sentinel bit on
top: ``key = 1 << 3·level | code >> 3·(21 − level)``. The root is 1, ``parent = key >> 3``,
``child = key << 3 | index`` and sorting keys sorts nodes breadth-first (by level, then in
Potree's name order), with no strings anywhere.
"""

from __future__ import annotations

import numpy as np

from ..core.morton import MORTON_BITS_PER_AXIS, morton_codes  # one Morton kernel for every code

CODE_BITS = MORTON_BITS_PER_AXIS  # bits per axis of a point code
MAX_LEVEL = 20  # keys stay below 2^61
ROOT_KEY = 1


def point_codes(xyz, origin, edge):
    """u64 code of each point inside the cube [origin, origin + edge]^3 (x in bit 2 of each digit)."""
    return morton_codes(xyz, origin, edge, True)


def key_of(codes, level: int):
    """Key of the level-``level`` node holding each code."""
    codes = np.asarray(codes, np.uint64)
    return (np.uint64(1) << np.uint64(3 * level)) | (codes >> np.uint64(3 * (CODE_BITS - level)))


def level_of(keys) -> np.ndarray:
    """Level of each key (position of the sentinel bit / 3)."""
    keys = np.atleast_1d(np.asarray(keys, np.uint64))
    lev = np.zeros(len(keys), np.int32)
    k = keys.copy()
    for _ in range(MAX_LEVEL + 1):
        more = k > 1
        lev += more
        k = np.where(more, k >> np.uint64(3), k)
    return lev


def key_range(key: int) -> tuple[int, int, int]:
    """(level, first code, end code) of the codes a node covers."""
    level = (int(key).bit_length() - 1) // 3
    prefix = int(key) ^ (1 << 3 * level)
    shift = 3 * (CODE_BITS - level)
    return level, prefix << shift, (prefix + 1) << shift


def morton_position(keys, levels=None) -> np.ndarray:
    """Where each node's cube starts in the Morton order of the codes (its first code, the
    sentinel bit on top): sorting nodes by it sorts them along the curve, a parent just before
    its first child. ``levels``: the keys' levels, where the caller holds them."""
    keys = np.asarray(keys, np.uint64)
    levels = level_of(keys) if levels is None else np.asarray(levels)
    return keys << (np.uint64(3) * (CODE_BITS - levels).astype(np.uint64))


def key_cube(keys, origin, edge: float) -> tuple[np.ndarray, np.ndarray]:
    """(mins (k, 3), edges (k,)) of the cubes of node keys inside the octree cube."""
    keys = np.atleast_1d(np.asarray(keys, np.uint64))
    levels = level_of(keys)
    prefix = keys ^ (np.uint64(1) << (np.uint64(3) * levels.astype(np.uint64)))
    ijk = np.zeros((len(keys), 3), np.int64)
    for bit in range(MAX_LEVEL):
        digit = (prefix >> np.uint64(3 * bit)) & np.uint64(7)
        active = bit < levels
        for axis in range(3):
            b = ((digit >> np.uint64(2 - axis)) & np.uint64(1)).astype(np.int64)
            ijk[:, axis] |= np.where(active, b << bit, 0)
    edges = edge / np.exp2(levels)
    return np.asarray(origin, np.float64) + ijk * edges[:, None], edges


def key_name(key: int) -> str:
    """Potree node name ('r', 'r0', 'r07', ...) of a key."""
    level = (int(key).bit_length() - 1) // 3
    return "r" + "".join(str((int(key) >> 3 * (level - 1 - i)) & 7) for i in range(level))


def name_key(name: str) -> int:
    """Key of a Potree node name."""
    if not name.startswith("r") or any(c not in "01234567" for c in name[1:]):
        raise ValueError(f"not a Potree node name: {name!r}")
    key = 1
    for c in name[1:]:
        key = key << 3 | int(c)
    return key
