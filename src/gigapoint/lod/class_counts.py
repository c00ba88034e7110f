"""Per-node class counts of a gigapoint octree (``classes.npy``, layout: octree_dir.py).

For each node, one (node, class, count) record per LAS class its points hold, sorted by node
(key order) then class: 9 bytes a class present in a node, nothing for the classes absent. The
converter counts them where it has each node's points (``node_class_counts``, from
convert/phases.py's ``_save_nodes``), the writer gathers them (``join_class_counts``) and the
reader checks them (``read_class_counts``), so a selection through a class filter (hidden
classes, ``classes=``) knows what a node not yet loaded keeps (``kept_by_class``) rather than
guessing it from its loaded ancestors (store.py). Octrees written before have none.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io.filters import PointFilter
from .octree_dir import CLASSES, OctreeDir

CLASS_COUNT_DTYPE = np.dtype([("node", "<u4"), ("class", "u1"), ("count", "<u4")])


def class_histogram(values) -> np.ndarray:
    """Points per LAS class among ``values`` (a classification array): 256 int64 counts. Values
    that are no LAS class (below 0, above 255, fractional) are left out: no class hides them."""
    values = np.asarray(values)
    if values.dtype != np.uint8:  # (a LAS file's uint8 is counted as it is: one pass, no sort)
        whole = (values >= 0) & (values <= 255)
        if values.dtype.kind == "f":
            whole &= values == np.floor(values)
        values = values[whole].astype(np.uint8)
    return np.bincount(values, minlength=256).astype(np.int64, copy=False)


def node_class_counts(classification: np.ndarray, counts: np.ndarray) -> np.ndarray | None:
    """The CLASS_COUNT_DTYPE records of nodes 0, 1, ... holding ``counts`` points each, whose
    ``classification`` is given in node order; None where it is not LAS classes (integers 0-255)."""
    codes = np.asarray(classification)
    if codes.dtype.kind not in "ui" or (len(codes) and (int(codes.min()) < 0 or int(codes.max()) > 255)):
        return None
    present = np.flatnonzero(np.bincount(codes, minlength=256))
    column = np.zeros(256, np.int64)
    column[present] = np.arange(len(present))
    owner = np.repeat(np.arange(len(counts), dtype=np.int64), counts)
    # a node × class table of the classes present only (a few), so it stays small however many nodes
    table = np.bincount(owner * len(present) + column[codes], minlength=len(counts) * len(present)).reshape(len(counts), len(present))
    node, col = np.nonzero(table)
    out = np.empty(len(node), CLASS_COUNT_DTYPE)
    out["node"], out["class"], out["count"] = node, present[col], table[node, col]
    return out


def join_class_counts(sets: list[Path], node_counts: list[int], order: np.ndarray) -> np.ndarray | None:
    """The octree's records from its built node ``sets`` (each holding ``node_counts`` nodes,
    numbered from 0 in it), renumbered as the octree's nodes are: the sets' nodes one after
    another, put in key order by ``order``. None where a set has none (no classification, or
    built before sets had them): a selection then guesses for every node, as before."""
    paths = [s / f"{CLASSES}.npy" for s in sets]
    if not all(p.exists() for p in paths):
        return None
    starts = np.cumsum([0, *node_counts[:-1]])
    parts = []
    for path, start in zip(paths, starts.tolist()):
        part = np.load(path)
        part["node"] += np.uint32(start)
        parts.append(part)
    records = np.concatenate(parts) if parts else np.empty(0, CLASS_COUNT_DTYPE)
    rank = np.empty(len(order), np.int64)
    rank[order] = np.arange(len(order))
    records["node"] = rank[records["node"]]
    return records[np.argsort(records["node"], kind="stable")]  # (a node's records come from one set, in class order)


def read_class_counts(d: OctreeDir, nodes: np.ndarray) -> np.ndarray | None:
    """The octree's records, checked against its ``nodes`` (each node's add up to its count);
    None where it has none (written before, or without classification). A damaged file is a
    one-line InputError naming it."""
    path = d.array(CLASSES)
    if not path.exists():
        return None
    records = d.load(CLASSES, mmap=False)
    counts = nodes["count"].astype(np.int64)
    if records.dtype != CLASS_COUNT_DTYPE or records.ndim != 1:
        raise InputError(f"{path}: holds {records.dtype} records, not (node, class, count) ones")
    if len(records) and int(records["node"].max()) >= len(nodes):
        raise InputError(f"{path}: names node #{int(records['node'].max())} of {len(nodes):,}")
    per_node = np.bincount(records["node"], records["count"].astype(np.float64), minlength=len(nodes))
    if not np.array_equal(per_node, counts):
        bad = int(np.flatnonzero(per_node != counts)[0])
        raise InputError(f"{path}: node #{bad}'s classes count {int(per_node[bad]):,} points, {d.array('nodes').name} says {int(counts[bad]):,}")
    return records


def kept_by_class(records: np.ndarray, n_nodes: int, keep: PointFilter) -> np.ndarray:
    """How many points of each of the ``n_nodes`` nodes the classes of ``keep`` let pass (its
    ``classes``, ``drop_classes``; its positions aside), from the octree's records."""
    passes = np.array([keep.keeps_class(c) for c in range(256)])
    return np.bincount(records["node"], records["count"] * passes[records["class"]], minlength=n_nodes).astype(np.int64)
