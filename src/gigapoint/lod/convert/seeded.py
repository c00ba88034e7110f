"""A conversion whose tree a builder has grown already: a progressive octree's ``save`` (issue
#18, item 3: one LOD builder; docs/lod.md, "One LOD builder").

In the same cube and with the same leaf size, a ProgressiveOctree has exactly the nodes the
converter's split of the sorted codes makes (``build.split_tree``; tested in
tests/unit/test_lod_progressive.py). So its leaves are the runs the read, count and distribute
phases would have found: here those three phases are one, which plans the partitions from the
leaves' counts, in the octree's cube, and the build phase takes each partition's points
straight from its leaves (no spill, no partition files: a grown tree's conversion does not
resume, it is in memory already). The build, group, upper and write phases run as for any
input (Potree, COPC, the compact layout: all theirs).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..keys import level_of
from .partition import COUNT_LEVEL, partition_lut, plan_partitions
from .state import Job


@dataclass
class GrownTree:
    """What a builder hands a conversion: its root cube, the bounds and count of its points, their
    attributes, its leaves (u64 keys, point counts) and ``points(keys)``, the points of those
    leaves ({"xyz" float64 (n, 3), "rgba" u32, "attr.<name>"}, leaf by leaf)."""

    origin: np.ndarray
    edge: float
    lo: np.ndarray
    hi: np.ndarray
    skipped: int
    attributes: dict  # name -> numpy dtype
    leaf_keys: np.ndarray
    leaf_counts: np.ndarray
    points: object  # callable: keys -> dict of arrays


def _grid_cells(keys: np.ndarray) -> np.ndarray:
    """Each leaf's cell of the count grid (COUNT_LEVEL): a leaf at or below the grid's level is
    in one cell; a larger one stands in the first cell of its span. The partition plan never
    splits a node of at most ``budget`` points, and every leaf holds fewer, so a larger leaf's
    points counted in one cell of it give the plan they would give spread out, and that cell's
    partition (``partition_lut``) is the leaf's."""
    keys = np.asarray(keys, np.uint64)
    lev = level_of(keys).astype(np.int64)
    prefix = keys ^ (np.uint64(1) << (np.uint64(3) * lev.astype(np.uint64)))
    down = np.uint64(3) * np.maximum(lev - COUNT_LEVEL, 0).astype(np.uint64)
    up = np.uint64(3) * np.maximum(COUNT_LEVEL - lev, 0).astype(np.uint64)
    return ((prefix >> down) << up).astype(np.int64)


class SeededPhases(Job):
    """The read, count and distribute phases from a GrownTree (``self.inputs``)."""

    def read(self) -> None:
        tree: GrownTree = self.inputs
        st = self.state
        total = int(tree.leaf_counts.sum())
        st["attributes"] = {a: np.dtype(dt).str for a, dt in tree.attributes.items()}
        st.update(total=total, points=total, skipped=int(tree.skipped), chunks=0, chunk_scale=None, lo=np.asarray(tree.lo).tolist(),
                  hi=np.asarray(tree.hi).tolist())  # fmt: skip
        self.progress.phase("read", total)
        budget = st.setdefault("partition_points", self.partition_points)
        cells = _grid_cells(tree.leaf_keys)
        parts = plan_partitions(np.bincount(cells, tree.leaf_counts, 8**COUNT_LEVEL).astype(np.int64), 0, 0, COUNT_LEVEL, budget)
        pid = partition_lut(parts)[cells]
        self._leaves_of = {(lev, prefix): tree.leaf_keys[pid == p] for p, (lev, prefix, _) in enumerate(parts)}
        counts = np.bincount(pid, tree.leaf_counts, len(parts)).astype(np.int64).tolist()
        assert sum(counts) == total, (sum(counts), total)
        self.progress.advance(total)
        st.setdefault("source", self.source_facts(self.source_files))  # CRS, LAS grid, colours: for outputs that hold them
        st["compact"] = self.compact_plan()
        st.update(origin=np.asarray(tree.origin, np.float64).tolist(), edge=float(tree.edge), partitions=parts, part_counts=counts,
                  distributed=0, phase="build")  # fmt: skip
        self.save_state()

    def count(self) -> None:
        """Done by ``read``: the partitions come from the leaves."""

    def distribute(self) -> None:
        """Nothing to do: the build phase takes each partition's points from its leaves."""

    def _partition_input(self, lev: int, prefix: int) -> tuple[dict, list]:
        """A partition's points, from its leaves (no files to remove afterwards)."""
        data = self.inputs.points(self._leaves_of[(lev, prefix)])
        return {"xyz": np.ascontiguousarray(data.pop("xyz")), **data}, []
