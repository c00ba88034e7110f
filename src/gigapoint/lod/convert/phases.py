"""Phases 4-7: build (a local octree per partition, its root's points carried up), group and
upper (the nodes above the partitions, sampled from the carried points a group at a time) and
write (the node sets assembled into the output format: ../writer.py or ../potree.py).

gigapoint format: the build and upper phases quantize each node set's points straight into
the output arrays (``OctreeDir.array_in_progress``); the write phase only gathers the node
records and renames the arrays. Potree: node sets keep float64 positions until written.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np

from ...atomic import atomic_npy, fsync_file, mapped_npy, start_writeback
from ...core.cloud import take
from ...core.layout import BATCH_DTYPE
from ...core.quantize import _quantize_batches
from ..build import color_sums, filtered_colors, init_ownlevel, owned_order, sample_tree, sort_codes, split_tree, upper_tree
from ..class_counts import node_class_counts
from ..compact_octree import encode_nodes
from ..copc_write import write_copc_sets
from ..keys import level_of, point_codes
from ..octree_dir import CLASSES
from ..potree import place_node_set, placed_end, potree_plan, write_potree
from ..writer import append_streams, point_dtypes, run_serially, streams_end, write_gigapoint
from . import hooks
from .partition import built_name, group_name, plan_groups, set_name
from .spill import copy_range, load_raw_chunks, npy_data_offset, raw_chunk_files
from .state import Job

LOCAL = "local."  # prefix of a node set's own copy of its output arrays and records (local_sets), until place_set


def place_set(dest: Path, outputs: dict, off: int) -> int:
    """A node set built with ``local_sets`` placed into the output arrays (``outputs``: {name:
    (path, dtype, data offset)}, as ``_outputs`` gives): its points copied to point ``off``, its
    node records' ``first`` moved there (nodes.npy), span.npy written last, its own copies then
    removed. Placed already (span.npy there): nothing to do. Returns its number of points."""
    span = dest / "span.npy"
    if span.exists():
        return int(np.diff(np.load(span))[0])
    nodes = np.load(dest / f"{LOCAL}nodes.npy")
    n = int(nodes["count"].sum())
    for k, (path, dt, data_off) in outputs.items():
        if n:
            src = dest / f"{LOCAL}{k}.npy"
            copy_range(src, npy_data_offset(src), path, data_off + off * dt.itemsize, n * dt.itemsize)
    nodes["first"] += np.uint64(off)
    atomic_npy(dest / "nodes.npy", nodes)
    atomic_npy(span, np.array([off, off + n], np.int64))
    for k in [*outputs, "nodes"]:
        (dest / f"{LOCAL}{k}.npy").unlink(missing_ok=True)
    return n


def save_carry(dest: Path, root_key: int, has_children: bool, gathered: dict, arrays: dict, idx) -> None:
    """A built set's root: the points it carries up (``carry.<name>.npy``: ``gathered`` maps a
    name to (array, its own indices), ``arrays`` to arrays taken at ``idx``) and root.npy (key,
    has children)."""
    for k, (v, i) in gathered.items():
        atomic_npy(dest / f"carry.{k}.npy", take(v, i))
    for k, v in arrays.items():
        atomic_npy(dest / f"carry.{k}.npy", take(v, idx))
    np.save(dest / "root.npy", np.array([root_key, 1 if has_children else 0], np.uint64))


class BuildPhases(Job):
    """The phases after partitioning; ``_outs`` and ``_next`` cache the output arrays' layout."""

    _outs: dict | None = None
    _next: int | None = None  # next free offset in the output arrays (_next_offset)
    _ends: dict | None = None  # next free word of each stream (_stream_ends)
    local_sets = False  # gigapoint format: node sets keep their points in their own folder until placed (place_set)
    potree_in_place = True  # Potree format: the build encodes node sets into octree.bin (potree.place_node_set); not on Dask
    _potree: list | None = None  # [plan, next byte of octree.bin] (potree_plan, placed_end)

    def _write_steps(self, fn, calls: list) -> list:
        """How the write phase runs its independent steps (writer.write_gigapoint's ``run``): here; as tasks on Dask."""
        return run_serially(fn, calls)

    # -- phase 4
    def build(self) -> None:
        st = self.state
        self.dir.built.mkdir(exist_ok=True)
        self.progress.phase("build", st["points"])
        self._build_partitions([(lev, prefix, st["part_counts"][pid]) for pid, (lev, prefix, _) in enumerate(st["partitions"])])
        st["phase"] = "group"
        self.save_state()

    def _build_partitions(self, parts: list) -> None:
        """Build the partitions [(level, prefix, points), ...] in turn (distributed.py: as tasks)."""
        done_now = 0
        for lev, prefix, n in parts:
            built_now = self.build_partition(lev, prefix, n)
            self.progress.advance(n)
            if built_now:
                done_now += 1
                hooks.after_partition_built(done_now)

    def build_partition(self, lev: int, prefix: int, n: int) -> bool:
        """Partition (lev, prefix) of ``n`` points -> its node set ``built/p<key>``: a local octree
        split to ``max_leaf`` points a leaf and sampled bottom-up, its root's points carried up;
        then its input files are removed. Written under a temporary name and renamed, so a
        repeated call (a resumed run, a retried task) finds it done. False: nothing to do (built
        already, or empty)."""
        st = self.state
        built = self.dir.built
        target = built / built_name(lev, prefix)
        if target.exists() or n == 0:
            return False
        data, files = self._partition_input(lev, prefix)
        tmp = built / (built_name(lev, prefix) + ".tmp")
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir()
        self._build_subtree(data, (1 << 3 * lev) | prefix, np.array(st["origin"]), st["edge"], tmp)
        os.replace(tmp, target)
        for path in files:
            path.unlink(missing_ok=True)
        return True

    def _partition_input(self, lev: int, prefix: int) -> tuple[dict, list[Path]]:
        """A partition's points ({"xyz": (n, 3), "rgba", "attr.<name>"}, in input order) and the
        files they were read from (removed once it is built)."""
        st = self.state
        if st.get("from_raw"):  # one partition: the spilled chunks themselves
            return self._with_constants(load_raw_chunks(self.dir.raw, range(st["chunks"]), self._varying())), raw_chunk_files(self.dir.raw)
        files = self._part_files(lev, prefix)
        dts = self._dtypes()
        data = {k: np.fromfile(path, dtype=dts[k]) for k, path in files.items()}
        data["xyz"] = self._positions(data["xyz"].reshape(-1, 3))  # (int32 of the inputs' LAS grid: decoded)
        return self._with_constants(data), list(files.values())

    def _build_subtree(self, data: dict, root_key: int, origin, edge, dest: Path) -> None:
        xyz = data.pop("xyz")
        codes, order = sort_codes(point_codes(xyz, origin, edge))
        rgba_sorted = take(data["rgba"], order)
        # the grid sampler needs only codes; Poisson measures distances on sorted positions
        xyz_sorted = take(xyz, order) if self.sampler == "poisson" else np.zeros((1, 3))
        tree = split_tree(codes, root_key, self.max_leaf)
        own = init_ownlevel(tree, len(codes))
        wsum, wcount = color_sums(rgba_sorted)
        sample_tree(tree, codes, xyz_sorted, own, wsum, wcount, self.sampler, origin, edge)
        del xyz_sorted
        perm, counts = owned_order(tree, own)  # indices into the sorted arrays
        src = take(order, perm)  # the same points as indices into the input arrays
        del order
        n0 = int(counts[0])
        carry, rest = perm[:n0], perm[n0:]
        # carried up: the subtree root's points, with their color sums (xyz and data are in
        # input order, the rest sorted)
        inputs = {"xyz": xyz, **data}
        save_carry(
            dest,
            root_key,
            not tree.leaf[0],
            {k: (v, src[:n0]) for k, v in inputs.items()},
            {"codes": codes, "wsum": wsum, "wcount": wcount},
            carry,
        )
        # final: every node below the root
        del codes
        self._save_nodes(dest, tree.keys[1:], counts[1:], ~tree.leaf[1:], xyz, data, src[n0:], (rgba_sorted, wsum, wcount, rest))

    def _outputs(self) -> dict:
        """gigapoint format: the final point arrays (OUT/<name>.tmp.npy), which the build and upper
        phases fill in place; the write phase only renames them. {name: (path, dtype, data offset)}."""
        if self._outs is None:
            total = int(self.state["points"])
            self._outs = {}
            for k, dt in self._output_dtypes().items():
                path = self.dir.array_in_progress(k)
                arr = np.load(path, mmap_mode="r") if path.exists() else None
                if arr is None or arr.shape != (total,) or arr.dtype != dt:
                    arr = mapped_npy(path, dt, (total,))
                self._outs[k] = (path, dt, arr.offset)
                del arr
        return self._outs

    def _output_dtypes(self) -> dict:
        """gigapoint format: the output point arrays' names and dtypes."""
        return point_dtypes(self.state["attributes"], compact=self.state.get("compact") is not None)

    def _output_slices(self, start: int, n: int) -> dict:
        """Memory maps of points start..start+n of every output array. Only this node set's pages
        are mapped, and only while it is written: whole-file maps would count every written page
        of the output in the process's resident memory."""
        return {
            k: np.memmap(path, dtype=dt, mode="r+", offset=off + start * dt.itemsize, shape=(n,))
            for k, (path, dt, off) in self._outputs().items()
        }

    def _close_outputs(self) -> None:
        """Output arrays on disk (fsync) before the write phase renames them and writes the metadata."""
        for path in map(self.dir.array_in_progress, self._output_dtypes()):
            if path.exists():  # not after a resumed write phase's renames
                fsync_file(path)
        self._outs = None

    def _next_offset(self) -> int:
        """Where the next node set's points go in the output arrays: after every finished one.
        Read from the finished sets once per process, then kept: reading every set's span per
        set made the build and group phases quadratic (14 of 24 s with 400 sets)."""
        if self._next is None:
            built = self.dir.built
            ends = [int(np.load(p)[1]) for p in built.glob("*/span.npy") if not p.parent.name.endswith(".tmp")]
            self._next = max(ends, default=0)
        return self._next

    def _stream_ends(self) -> dict:
        """Where the next node set's streams go (writer.append_streams): after every finished set's.
        Read from the finished sets once per process (as ``_next_offset``), then kept."""
        if self._ends is None:
            built = self.dir.built
            self._ends = streams_end(p.parent for p in built.glob("*/span.npy") if not p.parent.name.endswith(".tmp"))
        return self._ends

    def _save_nodes(self, dest: Path, keys, counts, inner, xyz, data, idx, colors) -> None:
        """One node set: nodes ``keys`` holding ``counts`` points each, in order: the points
        ``xyz[idx]``, ``data[k][idx]``, with colors ``filtered_colors(*colors)``.

        gigapoint format: quantized (node records with tight bboxes, the three precision words)
        and written straight into the output arrays at the next free offset (``span.npy``), so
        every array is gathered and written once. Potree: float64 positions, in ``dest``."""
        keep = (counts > 0) | inner  # empty leaves are dropped; empty inner nodes keep the hierarchy whole
        keys = np.asarray(keys, np.uint64)[keep]
        counts = np.asarray(counts, np.int64)[keep]
        atomic_npy(dest / "keys.npy", keys)
        atomic_npy(dest / "counts.npy", counts)
        n = len(idx)
        if self.format == "potree" and self.potree_in_place:
            if self._potree is None:  # (its plan, where the next set goes: after the finished sets', read once per process)
                built = self.dir.built
                self._potree = [potree_plan(self.state), placed_end(p.parent for p in built.glob("*/keys.npy") if not p.parent.name.endswith(".tmp"))]
            attrs = {a: data[f"attr.{a}"] for a in self.state["attributes"]}
            self._potree[1] = place_node_set(self.dir, self._potree[1], dest, xyz, data["rgba"], attrs, counts, self._potree[0], self.encoding, idx)
            return
        if self.format != "gigapoint":
            atomic_npy(dest / "xyz.npy", take(xyz, idx))
            atomic_npy(dest / "color.npy", filtered_colors(*colors))
            for k, v in data.items():
                atomic_npy(dest / f"{k}.npy", take(v, idx))
            return
        if self.local_sets:  # placed into the output arrays later (place_set), at an offset not known yet
            off = 0
            dts = self._output_dtypes()
            if n:
                outs = {k: mapped_npy(dest / f"{LOCAL}{k}.npy", dt, (n,)) for k, dt in dts.items()}
            else:
                outs = {k: np.empty(0, dt) for k, dt in dts.items()}
        else:
            off = self._next_offset()
            outs = self._output_slices(off, n) if n else {k: np.empty(0, dt) for k, (_, dt, _) in self._outputs().items()}
        sl = slice(0, n)
        nodes = np.zeros(len(keys), BATCH_DTYPE)
        first = np.cumsum(counts) - counts
        nodes["count"] = counts
        nodes["level"] = level_of(keys)
        plan = self.state.get("compact")
        if plan is not None:  # version 2: the low words at the points' offset, the rest as node streams in ``dest``
            nodes["first"] = first
            attrs = {f"attr.{a}": take(data[f"attr.{a}"], idx) for a in self.state["attributes"]}  # in the fields' order
            low, ext, pack, fields, streams = encode_nodes(
                xyz, idx, nodes, plan["scale"], np.array(self.state["origin"]), (filtered_colors(*colors), take(data["rgba"], idx)),
                attrs, plan["colors"],
            )  # fmt: skip
            outs["low"][sl] = low
            self._save_class_counts(dest, attrs.get("attr.classification"), counts)
            streams = {"ext": ext, **{f"field.{f}": v for f, v in streams.items()}}
            for k, v in {"pack": pack, "fields": fields, **(streams if self.local_sets else {})}.items():
                atomic_npy(dest / f"{k}.npy", v)
            if not self.local_sets:
                append_streams(self.dir, dest, streams, self._stream_ends())
            del outs, low
            if not self.local_sets:
                self._write_back(off, n)
            self._finish_set(dest, nodes, first, off, n)
            return
        bmin = np.empty((len(keys), 3))
        bmax = np.empty((len(keys), 3))
        low, med, high = (np.asarray(outs[k][sl]) for k in ("low", "med", "high"))
        _quantize_batches(xyz, np.ascontiguousarray(idx), first, counts, bmin, bmax, low, med, high)
        nodes["bbox_min"], nodes["bbox_max"] = bmin, bmax
        filtered_colors(*colors, out=outs["color"][sl])
        for k, v in data.items():
            take(v, idx, out=outs[k][sl])
        self._save_class_counts(dest, outs["attr.classification"][sl] if "attr.classification" in outs else None, counts)
        del outs, low, med, high  # unmapped; a killed process's writes stay in the page cache
        if not self.local_sets:
            self._write_back(off, n)
        self._finish_set(dest, nodes, first, off, n)

    def _save_class_counts(self, dest: Path, classification, counts) -> None:
        """gigapoint format: the set's per-node class counts (class_counts.py), from its points'
        ``classification`` in node order (None: it has none), while they are at hand."""
        records = None if classification is None else node_class_counts(classification, counts)
        if records is not None:
            atomic_npy(dest / f"{CLASSES}.npy", records)

    def _write_back(self, off: int, n: int) -> None:
        """Points off..off+n of the output arrays, just written, on their way to the disk while
        the build goes on (atomic.start_writeback): the write phase's fsyncs wait for less."""
        for path, dt, data_off in self._outputs().values():
            start_writeback(path, data_off + off * dt.itemsize, n * dt.itemsize)

    def _finish_set(self, dest: Path, nodes, first, off: int, n: int) -> None:
        """A node set's records written (``first`` moved to ``off``); placed: its span last."""
        nodes["first"] = (first + off).astype(np.uint64)
        if self.local_sets:
            atomic_npy(dest / f"{LOCAL}nodes.npy", nodes)
            return
        atomic_npy(dest / "nodes.npy", nodes)
        atomic_npy(dest / "span.npy", np.array([off, off + n], np.int64))  # (a full disk's error names it)
        self._next = off + n

    # -- phase 5
    def group(self) -> None:
        """Partition roots joined under common ancestors, a group at a time (``plan_groups``), so
        the upper phase never holds every root's sample at once: a 10^9-point input has ~900
        partitions whose roots carry ~22 M points, more than a 3 GB memory limit allows. A group
        is built like a partition: its nodes above the member roots, and its root's sample
        carried up; rounds repeat on the groups' roots until what is left fits. Sampling only
        ever looks at a node's children, so the tree is the same as without groups."""
        st = self.state
        built = self.dir.built
        if "top_sets" not in st:  # the built sets whose roots are not joined yet: [level, prefix, kind]
            st["top_sets"] = [[lev, pre, "p"] for lev, pre, _ in st["partitions"] if (built / built_name(lev, pre)).exists()]
            st["groups"] = []
            st["round"] = None
        while True:
            dirs = {(lev, pre): built / set_name(lev, pre, kind) for lev, pre, kind in st["top_sets"]}
            if st["round"] is None:
                carried = {k: int(np.load(d / "carry.codes.npy", mmap_mode="r").shape[0]) for k, d in dirs.items()}
                st["round"] = plan_groups(carried, self.upper_points)
                self.save_state()
            if not st["round"]:
                break
            self.progress.phase("group", None)
            self._join_groups([(level, prefix, [dirs[tuple(m)] for m in members]) for level, prefix, members in st["round"]])
            joined = {tuple(m) for _, _, members in st["round"] for m in members}
            st["top_sets"] = [t for t in st["top_sets"] if (t[0], t[1]) not in joined] + [[lev, pre, "g"] for lev, pre, _ in st["round"]]
            st["groups"] += [[lev, pre] for lev, pre, _ in st["round"]]
            st["round"] = None
            self.save_state()
        st["phase"] = "upper"
        self.save_state()

    def _join_groups(self, groups: list) -> None:
        """Join a round's groups [(level, prefix, member set dirs), ...] in turn (distributed.py: as tasks)."""
        for level, prefix, members in groups:
            self.join_group(level, prefix, members)

    def join_group(self, level: int, prefix: int, members: list[Path]) -> None:
        """The group (level, prefix) of the built sets ``members``: its node set ``built/g<key>``
        (temporary name, then renamed; nothing to do when it is there)."""
        built = self.dir.built
        target = built / group_name(level, prefix)
        if target.exists():
            return
        tmp = built / (group_name(level, prefix) + ".tmp")
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir()
        self._join_roots(members, (1 << 3 * level) | prefix, tmp)
        os.replace(tmp, target)

    def _top_sets(self) -> list[Path]:
        """The built sets whose roots the upper phase joins (every partition, before grouping)."""
        built = self.dir.built
        tops = self.state.get("top_sets") or [[lev, pre, "p"] for lev, pre, _ in self.state["partitions"]]
        paths = [built / set_name(lev, pre, kind) for lev, pre, kind in tops]
        return [p for p in paths if p.exists()]

    def _join_roots(self, parts: list[Path], top: int, dest: Path) -> None:
        """The nodes from the roots of the built sets ``parts`` up to node ``top``, sampled from
        the points those roots carry, as a node set in ``dest``. ``top`` = 1 (the octree's root):
        the whole upper tree; else a group, whose root's own points are carried up in turn."""
        st = self.state
        origin, edge = np.array(st["origin"]), st["edge"]
        names = ["rgba"] + ["attr." + a for a in st["attributes"]]
        root_info = [np.load(p / "root.npy") for p in parts]
        roots = [int(r[0]) for r in root_info]
        inner_roots = np.array([r[0] for r in root_info if r[1]], np.uint64)
        cat = {k: np.concatenate([np.load(p / f"carry.{k}.npy") for p in parts]) for k in ["xyz", "codes", "wsum", "wcount", *names]}
        codes, order = sort_codes(cat.pop("codes"))  # the sorted codes come with the order: no gather
        for k in list(cat):  # one array at a time, so only one unsorted array is alive next to the sorted ones
            cat[k] = take(cat[k], order)
        del order
        xyz, wsum, wcount = cat.pop("xyz"), cat.pop("wsum"), cat.pop("wcount")
        tree = upper_tree(codes, roots, top)
        own = init_ownlevel(tree, len(codes))
        sample_tree(tree, codes, xyz, own, wsum, wcount, self.sampler, origin, edge)
        perm, counts = owned_order(tree, own)
        self.progress.advance(len(codes))
        inner = ~tree.leaf | np.isin(tree.keys, inner_roots)  # roots with children stay even when emptied
        if top == 1:
            self._save_nodes(dest, tree.keys, counts, inner, xyz, cat, perm, (cat["rgba"], wsum, wcount, perm))
            return
        n0 = int(counts[0])  # the keys are sorted: node ``top`` comes first
        carry, rest = perm[:n0], perm[n0:]
        arrays = {"xyz": xyz, "codes": codes, "wsum": wsum, "wcount": wcount, **cat}
        save_carry(dest, top, True, {}, arrays, carry)  # a group's root has children
        self._save_nodes(dest, tree.keys[1:], counts[1:], inner[1:], xyz, cat, rest, (cat["rgba"], wsum, wcount, rest))

    # -- phase 6
    def upper(self) -> None:
        st = self.state
        built = self.dir.built
        target = built / "upper"
        if target.exists():
            st["phase"] = "write"
            self.save_state()
            return
        self.progress.phase("upper", None)
        self.build_upper(self._top_sets())
        st["phase"] = "write"
        self.save_state()

    def build_upper(self, tops: list[Path]) -> None:
        """The nodes above the built sets ``tops``, up to the root: ``built/upper`` (temporary name, then renamed)."""
        built = self.dir.built
        tmp = built / "upper.tmp"
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir()
        self._join_roots(tops, 1, tmp)
        os.replace(tmp, built / "upper")

    # -- phase 7
    def sources(self, built_order: bool = False) -> list[Path]:
        """The built node sets: the upper nodes, the groups, the partitions; ``built_order``: in
        the order this process builds them (the partitions, the groups round by round, the upper
        nodes), where Potree's build places them in octree.bin, so that a Dask conversion's write
        phase, writing them in this order, writes the same bytes."""
        built = self.dir.built
        groups = [built / group_name(level, prefix) for level, prefix in self.state.get("groups", [])]
        parts = [built / built_name(lev, prefix) for lev, prefix, _ in self.state["partitions"]]
        if built_order:
            return [p for p in parts + groups if p.exists()] + [built / "upper"]
        return [built / "upper"] + [p for p in groups + parts if p.exists()]

    def write(self) -> int:
        st = self.state
        self.progress.phase("write", st["points"])
        try:
            if self.format != "copc" and not st.get("aside"):  # an octree being replaced opened until now; its files go aside
                self.dir.set_aside()
                st["aside"] = True  # (from here on, the octree's names hold the new files)
                self.save_state()
            if self.format == "potree":
                n_nodes = write_potree(self.dir, self.sources(built_order=True), st, self.name, self.progress, self.encoding)
            elif self.format == "copc":  # one file beside the working folder, which goes once it is written
                n_nodes = write_copc_sets(self.out, self.sources(), st, self.progress)
            else:
                self._close_outputs()
                n_nodes = write_gigapoint(self.dir, self.sources(), st, self.name, self.sampler, self.max_leaf, self.progress, self._write_steps)
        except BaseException:
            self.dir.restore()  # the octree being replaced back in place, if this run had set it aside
            raise
        self.dir.remove_partial()
        if self.format == "copc":
            self.dir.path.rmdir()
        return n_nodes
