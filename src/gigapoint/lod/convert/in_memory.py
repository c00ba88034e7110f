"""A conversion whose input fits its memory limit: the read chunks stay in memory and are
partitioned there, with no spill files and no partition files (docs/lod.md, "Inputs that fit
in memory").

The phases and their results are the out-of-core ones (read.py, partition.py): the same count
grid, plan, refinement and partitions, each holding its points in input order, so the octree
is the same byte for byte. Only where the points wait between phases differs. A run killed
before its partitions are built resumes by reading the input again (nothing of it was kept on
disk) and building only the partitions not built yet: the plan is the saved one.

Files whose headers give their point count are held only when those points fit. Chunks of
unknown number (an iterable, or files without a count) are held until they outgrow the memory;
then every chunk held is spilled, and the conversion goes on (and resumes) out of core.
"""

from __future__ import annotations

import numpy as np

from .options import BYTES_PER_POINT_BUILD
from .partition import CellCounts, PartitionPhases, built_name, grid_cells, partition_lut
from .read import ReadPhase, chunk_constants, constant_value, valid_chunk
from .spill import decode_xyz, encode_xyz, las_xyz_code, save_raw_chunk

# what a held point costs at the peak (the read's end): its position (int32 for a LAS file's), RGBA,
# the attributes that vary (a constant one is held as its value), the next chunk being decoded and
# what the allocator keeps of the chunks before. Measured as the growth of the peak anonymous
# memory (RssAnon, sampled) from 2.5 M to 5 M points of a LAS file (format 3), converted in
# memory with partitions of 500 000: 52 bytes a point where 11 of its 13 attributes are constant
# (23 bytes a point held), 58 where every one varies (42 held); the peak RSS, with the write
# phase's file pages, grows 59 and 71. Not derived from the attributes: the choice is made from
# the header's count, before a point is read.
HELD_BYTES_PER_POINT = 64


def held_points(job) -> int:
    """How many points ``job`` may hold: their bytes and one partition's build within what it may use."""
    return max(0, job.usable - job.partition_points * BYTES_PER_POINT_BUILD) // HELD_BYTES_PER_POINT


def fits_in_memory(job) -> bool:
    """Whether ``job``'s input is converted in memory: files whose headers give a point count
    that ``held_points`` allows, or chunks of unknown number (held until they exceed it, then
    spilled: ``InMemoryPhases._take_chunk``)."""
    return job.point_total is None or job.point_total <= held_points(job)


class InMemoryPhases(ReadPhase, PartitionPhases):
    """The read, count and distribute phases with the points held in memory, until they outgrow it."""

    spilled = False  # True where the input outgrew the memory (or would): the out-of-core phases

    @property
    def read_ahead(self) -> bool:
        """Held chunks are decoded here, not in a read-ahead thread: glibc gives that thread its
        own malloc arena, so their memory, once freed, could not be reused by this thread's
        distribute and build, which then faulted in new pages (20 M LAS: 6.8 s and 1.85 GB peak
        against 5.1-5.2 s and 1.4 GB). With no spill files to write, the read-ahead overlapped
        little anyway. Spilling, the next file is read ahead again."""
        return self.spilled

    _held: list  # the read chunks: {"xyz", "rgba", "attr.<name>"}, then their count-grid cells
    _pieces: dict  # (level, prefix) -> the partition's points, piece by piece in input order
    #: the LAS files' [scale, offset] (every input file's the same) under which the held positions
    #: are int32 (spill.encode_xyz: 12 bytes a point, not 24; 240 MB of a 20 M-point conversion),
    #: decoded a partition at a time for its build; None: float64
    _xyz_code = None
    # An attribute every point read so far holds one value of (the state's ``constant``,
    # ReadPhase._note_constants: a LAS file's flags, its user_data, often: ~7 bytes a point) is
    # held as that value alone, a point at a time only once it varies (``_hold_constant``), and
    # made again for each partition's build (``_with_constants``); spilled, as that value too.

    def resume_state(self, saved: dict) -> dict:
        """A run killed before its partitions were all built has nothing but its plan and the
        partitions it built: it reads the input again under the same plan (``partition_points``).
        One that had spilled resumes out of core."""
        if saved.get("spilled"):  # it outgrew the memory: it resumes as any out-of-core run
            self.spilled = True
        if self.spilled or saved["phase"] not in ("read", "count", "distribute", "build"):
            return saved
        return {k: saved[k] for k in ("fingerprint", "partition_points") if k in saved} | {"phase": "read"}

    def read(self) -> None:
        if not self.spilled:  # a fresh run (a spilled one resumes spilled): held while it fits
            self.spilled = self.state["spilled"] = not fits_in_memory(self)
        self._held, self._held_points = [], 0
        self._xyz_code = None if self.spilled or self.reprojection is not None else _shared_las_code(self.paths)  # (moved points: off the files' grid)
        super().read()

    def _take_chunk(self, i: int, chunk) -> tuple:
        """Chunk ``i`` held; once the chunks outgrow ``held_points``, every chunk held so far and
        every one after is spilled, and the conversion goes on out of core."""
        if self.spilled:
            return super()._take_chunk(i, chunk)
        taken = valid_chunk(chunk)
        xyz, rgba, kept = taken[:3]
        held_xyz = xyz
        if self._xyz_code is not None:
            held_xyz = encode_xyz(xyz, self._xyz_code)
            if held_xyz is None:  # a point off the grid (not from the file's integers): floats from now on
                for held in self._held:
                    held["xyz"] = decode_xyz(held["xyz"], self._xyz_code)
                self._xyz_code, held_xyz = None, xyz
        held = {"xyz": held_xyz, "rgba": rgba}
        was = self._note_constants(chunk_constants(kept))
        now = self.state["constant"]
        for a, v in kept.items():
            if now.get(a, 0) is None or not len(v):  # it varies (constant so far: its value alone is held)
                if now.get(a) is None and was.get(a) is not None:
                    self._hold_constant(a, constant_value(was[a]))  # it varies from this chunk on: the chunks before hold it too
                held["attr." + a] = v
        self._held.append(held)
        self._held_points += len(xyz)
        if self._held_points > held_points(self):
            self.spilled = True
            constant = {a: constant_value(c) for a, c in now.items() if c is not None}
            for j, held in enumerate(self._held):  # (a constant one spilled as its value alone)
                values = constant | {k[5:]: v for k, v in held.items() if k.startswith("attr.")}
                save_raw_chunk(self.dir.raw, j, held.pop("xyz"), held.pop("rgba"), values, self._xyz_code)
            self._held = []
            self.state["spilled"] = True  # once every held chunk is spilled (a run stopped in between saves its state)
        return taken

    def _hold_constant(self, a: str, value) -> None:
        """Attribute ``a`` held a point at a time (``value``) in the held chunks that held only its value."""
        for held in self._held:
            held.setdefault("attr." + a, np.full(len(held["xyz"]), value))

    def _positions(self, xyz):
        if self.spilled or self._xyz_code is None:
            return super()._positions(xyz)
        return decode_xyz(xyz, self._xyz_code)

    def count(self) -> None:
        if self.spilled:
            return super().count()
        st = self.state
        constants = self._constants()
        for chunk in self._held:  # (an empty chunk's empty arrays)
            for a in constants:
                chunk.pop("attr." + a, None)
        origin, edge = np.array(st["origin"]), st["edge"]
        counts = CellCounts()
        self.progress.phase("count", st["points"])
        for chunk in self._held:
            cells = grid_cells(self._positions(chunk["xyz"]), origin, edge) if len(chunk["xyz"]) else np.zeros(0, np.int64)
            chunk["cell"] = cells.astype(np.int32)  # for the distribute phase
            counts.add(chunk["cell"])
            self.progress.advance(len(cells))
        self._plan(counts.total())

    def distribute(self) -> None:
        if self.spilled:
            return super().distribute()
        st = self.state
        parts = st["partitions"]
        keys = list(self._dtypes())
        self._pieces = {(lev, prefix): [] for lev, prefix, _ in parts}
        counts = [0] * len(parts)
        lut = partition_lut(parts)
        self.progress.phase("distribute", st["points"])
        while self._held:
            chunk = self._held.pop(0)  # each chunk freed once it is grouped
            data = {k: chunk[k] for k in keys}
            if len(parts) == 1:
                self._pieces[(parts[0][0], parts[0][1])].append(data)
                counts[0] += len(data["xyz"])
            elif len(data["xyz"]):
                self._append(parts, [self._by_partition(data, lut[chunk["cell"]], len(parts))], counts)
            self.progress.advance(len(data["xyz"]))
        st.update(part_counts=counts, distributed=0)
        self._refine()
        st["phase"] = "build"
        self.save_state()

    def _append(self, parts: list, pieces: list, counts: list) -> None:
        if self.spilled:
            return super()._append(parts, pieces, counts)
        for grouped, cuts in pieces:
            for p in np.flatnonzero(np.diff(cuts)):
                lev, prefix = parts[p][:2]
                if not (self.dir.built / built_name(lev, prefix)).exists():  # a resumed run's built partition is not held again
                    self._pieces.setdefault((lev, prefix), []).append({k: v[cuts[p] : cuts[p + 1]] for k, v in grouped.items()})
                counts[p] += int(cuts[p + 1] - cuts[p])

    def _partition_arrays(self, level: int, prefix: int, n: int) -> dict:
        if self.spilled:
            return super()._partition_arrays(level, prefix, n)
        pieces = self._pieces.get((level, prefix), [])
        if len(pieces) == 1:
            return pieces[0]
        return {k: np.concatenate([p[k] for p in pieces]) for k in pieces[0]} if pieces else {}

    def _drop_partition(self, level: int, prefix: int) -> None:
        if self.spilled:
            return super()._drop_partition(level, prefix)
        self._pieces.pop((level, prefix), None)

    def _partition_input(self, lev: int, prefix: int) -> tuple[dict, list]:
        if self.spilled:
            return super()._partition_input(lev, prefix)
        data = self._partition_arrays(lev, prefix, 0)
        self._drop_partition(lev, prefix)  # its memory goes once the build has it
        if "xyz" in data:
            data = self._with_constants({**data, "xyz": self._positions(data["xyz"])})
        return data, []


def _shared_las_code(paths) -> np.ndarray | None:
    """The input files' LAS grid (spill.las_xyz_code) where every one is a LAS/LAZ file with the
    same, else None (chunks given, other formats, several grids)."""
    codes = set()
    for p in paths or [None]:
        try:
            code = None if p is None else las_xyz_code(p)
        except Exception:  # noqa: BLE001 - only a memory saving: the read phase says what is wrong with a file
            code = None
        if code is None:
            return None
        codes.add(tuple(code.tolist()))
    return np.array(codes.pop(), np.float64) if len(codes) == 1 else None
