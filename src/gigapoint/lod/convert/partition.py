"""Partitions: the count grid, the plan that merges its cells into subtrees that fit the memory
limit (phase 2, count), the partitions' files filled from the spilled chunks and split further
where a spot is denser than the grid (phase 3, distribute), and the plan that groups partition
roots for the upper phases."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ...atomic import append_file
from ...core.cloud import take
from ...core.morton import counting_order
from ..keys import CODE_BITS, point_codes
from .read import constant_value
from .spill import decode_xyz, load_raw_chunk, raw_chunk_files, raw_xyz_code
from .state import Job

COUNT_LEVEL = 7  # the count grid: 128³ cells of the cube


def plan_partitions(counts: np.ndarray, level: int, prefix: int, depth: int, budget: int) -> list[list[int]]:
    """Merge the cells of a count grid ``depth`` levels below node (level, prefix) into the largest
    subtrees holding at most ``budget`` points: [[level, prefix, count], ...] in Morton order."""
    pyramid = [counts]
    for _ in range(depth):
        pyramid.insert(0, pyramid[0].reshape(-1, 8).sum(axis=1))
    parts: list[list[int]] = []

    def visit(d: int, rel: int) -> None:
        c = int(pyramid[d][rel])
        if c == 0:
            return
        if c <= budget or d == depth:
            parts.append([level + d, (prefix << 3 * d) | rel, c])
        else:
            for k in range(8):
                visit(d + 1, rel * 8 + k)

    visit(0, 0)
    return parts


def plan_groups(carried: dict, budget: int) -> list[list]:
    """Partitions (level, prefix) -> [[level, prefix, [[plevel, pprefix], ...]], ...]: groups of
    partitions under a common ancestor node (level, prefix) whose carried points (their
    roots' samples) sum to at most ``budget``, at the coarsest level where every group fits.
    No groups when all carried points fit at once; a partition alone under its ancestor stays
    ungrouped (a group of one saves nothing)."""
    if sum(carried.values()) <= budget:
        return []
    deepest = max(lev for lev, _ in carried)
    best = None
    for level in range(1, deepest):
        groups: dict = {}
        for (lev, prefix), n in carried.items():
            if lev > level:
                g = groups.setdefault(prefix >> 3 * (lev - level), [0, []])
                g[0] += n
                g[1].append([lev, prefix])
        best = [[level, anc, sorted(members)] for anc, (_, members) in sorted(groups.items()) if len(members) > 1]
        if all(n <= budget for n, _ in groups.values()):
            break
    return best or []


def _shared_code(raw: Path, n_chunks: int) -> list | None:
    """The LAS grid every spilled chunk's positions are on (spill.raw_xyz_code: one file's, or
    several files' of one scale and offset), as the state keeps it; None: float64 partitions."""
    codes = [raw_xyz_code(raw, i) for i in range(n_chunks)]
    if not codes or any(c is None or not np.array_equal(c, codes[0]) for c in codes):
        return None
    return codes[0].tolist()


def grid_cells(xyz: np.ndarray, origin, edge: float) -> np.ndarray:
    """Each point's cell of the count grid (int64: its node key's low bits at COUNT_LEVEL)."""
    return (point_codes(np.ascontiguousarray(xyz), origin, edge) >> np.uint64(3 * (CODE_BITS - COUNT_LEVEL))).astype(np.int64)


def partition_lut(parts: list) -> np.ndarray:
    """The partition (its index in ``parts``, a plan_partitions result) of every count-grid cell."""
    lut = np.empty(8**COUNT_LEVEL, np.int32)
    for pid, (lev, prefix, _) in enumerate(parts):
        span = 8 ** (COUNT_LEVEL - lev)
        lut[prefix * span : (prefix + 1) * span] = pid
    return lut


def built_name(level: int, prefix: int) -> str:
    """A partition's name (its files, its built node set): its root's node key in hex."""
    return f"p{(1 << 3 * level) | prefix:x}"


def group_name(level: int, prefix: int) -> str:
    """A group's name (its built node set): its root's node key in hex."""
    return f"g{(1 << 3 * level) | prefix:x}"


def set_name(level: int, prefix: int, kind: str) -> str:
    """A built node set's directory name: a partition ("p") or a group of roots ("g")."""
    return (built_name if kind == "p" else group_name)(level, prefix)


class CellCounts:
    """Points per cell of the count grid (8^COUNT_LEVEL cells). Small chunks' cells are counted
    together: a bincount a chunk, of 2M bins, took 1.7 s for 2 000 small tiles."""

    TOGETHER = 1 << 20  # points whose cells one bincount counts

    def __init__(self):
        self.counts = np.zeros(8**COUNT_LEVEL, np.int64)
        self._pending: list[np.ndarray] = []
        self._held = 0

    def add(self, cells: np.ndarray) -> None:
        self._pending.append(cells)
        self._held += len(cells)
        if self._held >= self.TOGETHER:
            self._flush()

    def _flush(self) -> None:
        if self._pending:
            self.counts += np.bincount(np.concatenate(self._pending), minlength=len(self.counts))
        self._pending, self._held = [], 0

    def total(self) -> np.ndarray:
        self._flush()
        return self.counts


class PartitionPhases(Job):
    # -- phase 2
    def count(self) -> None:
        st = self.state
        origin, edge = np.array(st["origin"]), st["edge"]
        counts = CellCounts()
        self.progress.phase("count", st["points"])
        for i in range(st["chunks"]):
            xyz = load_raw_chunk(self.dir.raw, i, [])["xyz"]
            if len(xyz):
                counts.add(grid_cells(xyz, origin, edge))
            self.progress.advance(len(xyz))
        self._plan(counts.total())

    def _plan(self, counts: np.ndarray) -> None:
        """The partitions of the count grid ``counts`` (saved in the state): the distribute phase is next."""
        st = self.state
        budget = st.setdefault("partition_points", self.partition_points)  # a resumed run keeps the first run's plan
        parts = plan_partitions(counts, 0, 0, COUNT_LEVEL, budget)
        st.update(partitions=parts, part_counts=[0] * len(parts), distributed=0, phase="distribute")
        self.save_state()

    # -- phase 3
    def _constants(self) -> dict:
        """The attributes every point holds one value of (the read's ``constant``): {name: that
        value, a numpy scalar}. Partitions hold them as that value alone, not a point at a time."""
        st = self.state
        return {a: constant_value(c) for a, c in st.get("constant", {}).items() if c is not None and st["attributes"].get(a) == c[0]}

    def _with_constants(self, data: dict) -> dict:
        """A partition's points ``data`` with its constant attributes made, a point at a time, for its build."""
        return data | {"attr." + a: np.full(len(data["xyz"]), c, c.dtype) for a, c in self._constants().items()}

    def _part_files(self, level: int, prefix: int) -> dict[str, Path]:
        d = self.dir.parts
        stem = built_name(level, prefix)  # named by node key: refined partitions never clash
        return {k: d / f"{stem}.{k}" for k in self._dtypes()}

    def _dtypes(self) -> dict[str, np.dtype]:
        """The arrays a partition holds a point at a time, and their dtypes (positions int32 under
        the state's ``part_code``: ``distribute``)."""
        dts = {"xyz": np.dtype(np.int32 if self.state.get("part_code") is not None else np.float64), "rgba": np.dtype(np.uint32)}
        constants = self._constants()
        for a, dt in self.state["attributes"].items():
            if a not in constants:
                dts["attr." + a] = np.dtype(dt)
        return dts

    def _varying(self) -> list[str]:
        """The attributes a partition holds a point at a time (``_dtypes``)."""
        return [k[5:] for k in self._dtypes() if k.startswith("attr.")]

    @staticmethod
    def _by_partition(data: dict, pid: np.ndarray, n_parts: int) -> tuple[dict, np.ndarray]:
        """The rows of ``data`` grouped by partition ``pid`` (stable), and each group's start (n_parts + 1)."""
        order, per = counting_order(pid, n_parts)
        return {k: take(np.asarray(v), order) for k, v in data.items()}, np.concatenate([[0], np.cumsum(per)])

    def _append(self, parts: list, pieces: list, counts: list) -> None:
        """Append grouped rows (``_by_partition`` results, in order) to their partitions' files.

        Each file is opened once for all pieces: with ~900 partitions of ~8 files, opening them
        for every 2 M-point chunk made the distribute phase quadratic (156 s of 618 at 10^9 points).
        """
        per = sum(np.diff(cuts) for _, cuts in pieces)
        for p in np.flatnonzero(per):
            for key, path in self._part_files(parts[p][0], parts[p][1]).items():
                append_file(path, [sorted_data[key][cuts[p] : cuts[p + 1]] for sorted_data, cuts in pieces])
            counts[p] += int(per[p])

    def distribute(self) -> None:
        st = self.state
        self.dir.parts.mkdir(exist_ok=True)
        origin, edge = np.array(st["origin"]), st["edge"]
        parts = st["partitions"]
        counts = st["part_counts"]
        if len(parts) == 1:  # one partition: the build reads the spilled chunks themselves
            st.update(part_counts=[st["points"]], distributed=st["chunks"], from_raw=True, phase="build")
            self.save_state()
            return
        if st["distributed"] < st["chunks"]:
            if not st["distributed"]:  # (a run resumed part-way keeps what its files were written with)
                st["part_code"] = _shared_code(self.dir.raw, st["chunks"])
            lut = partition_lut(parts)
            dts = self._dtypes()
            # a chunk interrupted half-way: cut every partition file back to the last checkpoint
            for pid, (lev, prefix, _) in enumerate(parts):
                for key, path in self._part_files(lev, prefix).items():
                    if path.exists():
                        os.truncate(path, counts[pid] * dts[key].itemsize * (3 if key == "xyz" else 1))  # xyz rows are 3 values
            self.progress.phase("distribute", st["points"])
            pieces, held = [], 0  # chunks grouped since the last checkpoint, and their bytes
            for i in range(st["distributed"], st["chunks"]):
                data = load_raw_chunk(self.dir.raw, i, self._varying(), decode=st.get("part_code") is None)
                xyz = np.ascontiguousarray(data["xyz"])
                if len(xyz):
                    pieces.append(self._by_partition(data, lut[grid_cells(self._positions(xyz), origin, edge)], len(parts)))
                    held += sum(v.nbytes for v in pieces[-1][0].values())
                del data
                if held >= self.distribute_bytes or i == st["chunks"] - 1:
                    # checkpoint: files hold every chunk up to i; only then are those spills deleted
                    self._append(parts, pieces, counts)
                    pieces, held = [], 0
                    first = st["distributed"]
                    st["distributed"] = i + 1
                    self.save_state()
                    for f in raw_chunk_files(self.dir.raw, range(first, i + 1)):
                        f.unlink()
                self.progress.advance(len(xyz))
        self._refine()
        st["phase"] = "build"
        self.save_state()

    def _partition_arrays(self, level: int, prefix: int, n: int) -> dict:
        """The ``n`` points distributed to partition (level, prefix) so far, read through memory maps."""
        dts = self._dtypes()
        files = self._part_files(level, prefix)
        return {k: np.memmap(path, dtype=dts[k], mode="r", shape=(n, 3) if k == "xyz" else (n,)) for k, path in files.items()}

    def _positions(self, xyz):
        """Held or spilled positions as float64 (partition files of one LAS grid hold them as its
        int32: ``part_code``; in_memory.py holds a LAS file's so too)."""
        code = self.state.get("part_code")
        if code is None or xyz.dtype == np.float64:
            return xyz
        return decode_xyz(np.ascontiguousarray(xyz), np.asarray(code, np.float64))

    def _drop_partition(self, level: int, prefix: int) -> None:
        """Forget partition (level, prefix)'s points (refined into smaller ones, or partial)."""
        for path in self._part_files(level, prefix).values():
            path.unlink(missing_ok=True)

    def _refine(self) -> None:
        """Split partitions that still exceed the budget (dense spots finer than the count grid)."""
        st = self.state
        origin, edge = np.array(st["origin"]), st["edge"]
        budget = st["partition_points"]
        unsplittable = st.setdefault("unsplittable", [])
        while True:
            big = [
                i
                for i, (lev, prefix, _) in enumerate(st["partitions"])
                if st["part_counts"][i] > budget and lev < CODE_BITS and [lev, prefix] not in unsplittable
            ]
            if not big:
                return
            i = big[0]
            lev, prefix, _ = st["partitions"][i]
            n = st["part_counts"][i]
            sub = min(lev + COUNT_LEVEL, CODE_BITS)
            base = np.uint64(prefix << 3 * (sub - lev))
            shift = np.uint64(3 * (CODE_BITS - sub))
            arrays = self._partition_arrays(lev, prefix, n)
            step = self.chunk_size
            counts = np.zeros(8 ** (sub - lev), np.int64)
            for s in range(0, n, step):
                rel = (point_codes(np.ascontiguousarray(self._positions(arrays["xyz"][s : s + step])), origin, edge) >> shift) - base
                counts += np.bincount(rel.astype(np.int64), minlength=len(counts))
            plan = plan_partitions(counts, lev, prefix, sub - lev, budget)
            if len(plan) == 1 and plan[0][0] == lev:
                unsplittable.append([lev, prefix])  # everything in one finest cell: it stays big
                self.save_state()
                continue
            lut = np.empty(len(counts), np.int32)
            for pid, (plev, pprefix, _) in enumerate(plan):
                span = 8 ** (sub - plev)
                rel0 = pprefix * span - int(base)
                lut[rel0 : rel0 + span] = pid
            for plev, pprefix, _ in plan:  # a run killed half-way left partial files: start them over
                self._drop_partition(plev, pprefix)
            new_counts = [0] * len(plan)
            for s in range(0, n, step):
                data = {k: np.ascontiguousarray(v[s : s + step]) for k, v in arrays.items()}
                rel = (point_codes(np.ascontiguousarray(self._positions(data["xyz"])), origin, edge) >> shift) - base
                self._append(plan, [self._by_partition(data, lut[rel.astype(np.int64)], len(plan))], new_counts)
            del arrays
            st["partitions"][i : i + 1] = plan
            st["part_counts"][i : i + 1] = new_counts
            self.save_state()
            self._drop_partition(lev, prefix)
