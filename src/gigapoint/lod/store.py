"""The gigapoint octree directory: writer, reader (OctreeCloud), node arena and LOD selection.

Directory layout (every array a .npy file, memory-mapped when read):

- ``octree.json``  metadata, written last (its presence means the directory is complete)
- ``nodes.npy``    one BATCH_DTYPE record per node (first, count, level, tight bbox), sorted by key
- ``keys.npy``     u64 integer node key per record (keys.py)
- ``low.npy``, ``med.npy``, ``high.npy``  u32 node-relative 10-bit precision words per point
- ``color.npy``    u32 RGBA, inner-node colors averaged over the points they stand for
- ``rgba.npy``     u32 RGBA as read (source colors)
- ``attr.<name>.npy``  per-point attributes (intensity, classification, ...)

Rendering never transcodes: selected nodes are copied slot by slot into an Arena (one
preallocated set of point buffers cut into fixed-size chunks, SimLOD-style) and the arena
is drawn by the same kernel as any PointCloud, each chunk a batch.
"""

from __future__ import annotations

import json
import os
from collections import OrderedDict
from pathlib import Path

import numpy as np
from numba import njit

from ..core.layout import BATCH_DTYPE
from ..core.quantize import quantize
from ..errors import InputError
from ..render.selection import box_in_view
from .keys import key_cube, level_of

META_NAME = "octree.json"
FORMAT_NAME = "gigapoint-octree"
FORMAT_VERSION = 1
ARENA_CHUNK = 4096  # points per arena slot (a node spans ceil(count / ARENA_CHUNK) slots)
_ARRAYS = ("low", "med", "high", "color", "rgba")


# --------------------------------------------------------------------------- writer


def write_gigapoint(out: Path, sources: list[Path], st: dict, name: str, sampler: str, max_leaf: int, progress) -> int:
    """Assemble built node sets into ``out``.

    A node set is a dir with keys.npy and either nodes.npy + span.npy (its points already written
    into ``out/<array>.tmp.npy`` by the converter: only the node records are gathered here) or
    counts/xyz/color/rgba/attr.* (quantized and copied here).
    """
    attrs = st["attributes"]
    origin, edge = np.array(st["origin"]), float(st["edge"])
    dtypes = {"low": np.uint32, "med": np.uint32, "high": np.uint32, "color": np.uint32, "rgba": np.uint32}
    dtypes.update({f"attr.{a}": np.dtype(d) for a, d in attrs.items()})
    tmp_paths = {k: out / f"{k}.tmp.npy" for k in dtypes}
    direct = all((src / "span.npy").exists() for src in sources)
    if direct:
        total = int(st["points"])
        if sum(int(np.diff(np.load(src / "span.npy"))[0]) for src in sources) != total:
            raise RuntimeError("internal error: built node sets do not cover every point once")
        outs = {}
    else:
        total = sum(int(np.load(src / "xyz.npy", mmap_mode="r").shape[0]) for src in sources)
        outs = {k: np.lib.format.open_memmap(tmp_paths[k], mode="w+", dtype=dtypes[k], shape=(total,)) for k in dtypes}
    all_nodes, all_keys = [], []
    offset = 0
    for src in sources:
        keys = np.load(src / "keys.npy")
        counts = np.load(src / "counts.npy")
        if direct:
            nodes = np.load(src / "nodes.npy")
            n = int(counts.sum())
        else:
            xyz = np.load(src / "xyz.npy")
            n = len(xyz)
            nodes = np.zeros(len(keys), BATCH_DTYPE)
            nodes["first"] = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.uint64)
            nodes["count"] = counts
            nodes["level"] = level_of(keys)
            low, med, high = quantize(xyz, np.arange(n, dtype=np.int64), nodes)
            nodes["first"] += np.uint64(offset)
            sl = slice(offset, offset + n)
            outs["low"][sl], outs["med"][sl], outs["high"][sl] = low, med, high
            outs["color"][sl] = np.load(src / "color.npy", mmap_mode="r")
            outs["rgba"][sl] = np.load(src / "rgba.npy", mmap_mode="r")
            for a in attrs:
                outs[f"attr.{a}"][sl] = np.load(src / f"attr.{a}.npy", mmap_mode="r")
        empty = counts == 0
        if empty.any():  # an empty inner node: its cube stands in for the bbox
            cmin, cedge = key_cube(keys[empty], origin, edge)
            nodes["bbox_min"][empty] = cmin
            nodes["bbox_max"][empty] = cmin + cedge[:, None]
        all_nodes.append(nodes)
        all_keys.append(keys)
        offset += n
        progress.advance(n)
    for k, arr in outs.items():
        arr.flush()
        del arr
    outs.clear()
    for k, p in tmp_paths.items():
        if p.exists() or not (out / f"{k}.npy").exists():  # a write phase resumed after its renames
            os.replace(p, out / f"{k}.npy")
    keys = np.concatenate(all_keys)
    nodes = np.concatenate(all_nodes)
    order = np.argsort(keys, kind="stable")
    if len(np.unique(keys)) != len(keys):
        raise RuntimeError("internal error: duplicate octree node keys")
    for fname, arr in (("nodes.npy", nodes[order]), ("keys.npy", keys[order])):
        tmp = out / (fname + ".tmp.npy")
        np.save(tmp, arr)
        os.replace(tmp, out / fname)
    lo, hi = np.array(st["lo"]), np.array(st["hi"])
    meta = {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "name": name,
        "points": int(total),
        "nodes": len(keys),
        "cube_min": origin.tolist(),
        "cube_edge": edge,
        "bounds": {"min": lo.tolist(), "max": hi.tolist()},
        "sampler": sampler,
        "spacing": edge / 128.0,
        "max_leaf": max_leaf,
        "attributes": attrs,
        "skipped": int(st.get("skipped", 0)),
    }
    tmp = out / (META_NAME + ".tmp")
    with open(tmp, "w") as f:
        json.dump(meta, f, indent=1)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, out / META_NAME)
    return len(keys)


# --------------------------------------------------------------------------- selection kernels


@njit(cache=True)
def _box_test(rows, bmin, size, width, height, near, far):
    """(in the frustum, projected size in px, distance of its projection from the image centre
    as a fraction of the half diagonal) of a box; size inf and distance 0 when it crosses the near plane."""
    visible, in_front, xmin, xmax, ymin, ymax = box_in_view(rows, bmin[0], bmin[1], bmin[2], size[0], size[1], size[2], width, height, near, far)
    if not in_front:
        return visible, np.inf, 0.0
    cx = min(max(width * 0.5, xmin), xmax) - width * 0.5
    cy = min(max(height * 0.5, ymin), ymax) - height * 0.5
    return visible, max(xmax - xmin, ymax - ymin), np.sqrt(cx * cx + cy * cy) / (0.5 * np.sqrt(width * width + height * height))


@njit(inline="always")
def _heap_place(hp, hi, n, j, p, item):
    """Put (priority ``p``, ``item``) into the hole at ``j`` of the max-heap ``hp``/``hi`` of ``n``
    entries: entries move down into the hole while their priority is lower (sift up), then up
    while a child's is higher (sift down). A push fills a hole at the end, a pop the one at 0."""
    while j > 0:
        q = (j - 1) // 2
        if hp[q] >= p:
            break
        hp[j] = hp[q]
        hi[j] = hi[q]
        j = q
    while True:
        c = 2 * j + 1
        if c >= n:
            break
        if c + 1 < n and hp[c + 1] > hp[c]:
            c += 1
        if hp[c] <= p:
            break
        hp[j] = hp[c]
        hi[j] = hi[c]
        j = c
    hp[j] = p
    hi[j] = item


@njit(cache=True)
def select_nodes(rows, box_min, box_size, counts, children, width, height, near, far, threshold, budget, out_ids, out_size, foveation=0.0):
    """Largest-projected-first traversal: visible nodes of ≥ threshold px (the root always), within budget.

    ``foveation`` f > 0 raises the threshold away from the image centre: threshold · (1 + f·d),
    d = 0 at the centre .. 1 in the corners (the 2022 paper's 100/200/300 px is f = 2).

    ``box_min``/``box_size`` (k, 3): each node's cube clipped to the cloud's bounds (it holds
    every point of the node's subtree, without the cube's empty space).

    Returns (number of selected nodes written to out_ids/out_size, their point total).
    """
    n = counts.shape[0]
    hp = np.empty(n, np.float64)
    hi = np.empty(n, np.int64)
    hn = 0
    vis, s, _ = _box_test(rows, box_min[0], box_size[0], width, height, near, far)
    if not vis:
        return 0, 0
    hp[0] = s
    hi[0] = 0
    hn = 1
    k = 0
    total = 0
    while hn > 0:
        node = hi[0]
        size = hp[0]
        hn -= 1
        _heap_place(hp, hi, hn, 0, hp[hn], hi[hn])  # pop: the last entry fills the top's hole
        cnt = counts[node]
        if total + cnt > budget and k > 0:
            break
        out_ids[k] = node
        out_size[k] = size
        k += 1
        total += cnt
        for d in range(8):
            ch = children[node, d]
            if ch < 0:
                continue
            vis, s, dist = _box_test(rows, box_min[ch], box_size[ch], width, height, near, far)
            if not vis or s < threshold * (1.0 + foveation * dist):
                continue
            hn += 1
            _heap_place(hp, hi, hn, hn - 1, s, ch)  # push: into the new hole at the end
    return k, total


@njit(cache=True)
def _copy_slots(src, first, count, slots, chunk, dst):
    """A node's points src[first:first+count] into arena slots (chunk points each) of dst."""
    for j in range(slots.shape[0]):
        s0 = first + j * chunk
        d0 = slots[j] * chunk
        for i in range(min(chunk, count - j * chunk)):
            dst[d0 + i] = src[s0 + i]


# --------------------------------------------------------------------------- arena


class Arena:
    """Preallocated point buffers cut into ``ARENA_CHUNK``-point slots, with an LRU of resident nodes.

    It quacks like a PointCloud for the backends: ``low``, ``med``, ``high``, ``color`` and
    ``batches`` (one BATCH_DTYPE record per slot).
    """

    def __init__(self, capacity_points: int, name: str, bounds, attribute_dtypes: dict | None = None):
        n_slots = max(1, -(-int(capacity_points) // ARENA_CHUNK))
        size = n_slots * ARENA_CHUNK
        self.low = np.zeros(size, np.uint32)
        self.med = np.zeros(size, np.uint32)
        self.high = np.zeros(size, np.uint32)
        self.color = np.zeros(size, np.uint32)
        self.attributes = {a: np.zeros(size, dt) for a, dt in (attribute_dtypes or {}).items()}
        self.batches = np.zeros(n_slots, BATCH_DTYPE)
        self.batches["first"] = np.arange(n_slots, dtype=np.uint64) * ARENA_CHUNK
        self.resident: OrderedDict[int, np.ndarray] = OrderedDict()
        self.free = list(range(n_slots - 1, -1, -1))
        self.name = name
        self.bounds = bounds
        self.loads = 0  # nodes copied in since creation (cache misses)
        # Bumped on every write; per slot, the version that last filled it (GPU backends re-upload those slots)
        self.version = 0
        self.batch_version = np.zeros(n_slots, np.int64)

    @property
    def n_slots(self) -> int:
        return len(self.batches)

    @property
    def n_points(self) -> int:
        return len(self.low)

    def ensure(self, nodes: np.ndarray, cloud: OctreeCloud) -> bool:
        """Make every node in ``nodes`` resident; False when they cannot all fit."""
        need = 0
        wanted = set(nodes.tolist())
        for nd in nodes.tolist():
            if nd in self.resident:
                self.resident.move_to_end(nd)
            else:
                need += -(-int(cloud.nodes["count"][nd]) // ARENA_CHUNK)
        if need > len(self.free):
            for nd in list(self.resident):
                if len(self.free) >= need:
                    break
                if nd not in wanted:
                    self.free.extend(self.resident.pop(nd).tolist())
        if need > len(self.free):
            return False
        for nd in nodes.tolist():
            if nd in self.resident:
                continue
            arrays, attrs, first = cloud.node_arrays(nd)  # a Potree node is read and decoded here
            rec = cloud.nodes[nd]
            count = int(rec["count"])
            k = -(-count // ARENA_CHUNK)
            slots = np.array([self.free.pop() for _ in range(k)], np.int64)
            src_color = arrays["color"] if cloud.filtered_colors else arrays["rgba"]
            for a, b in ((arrays["low"], self.low), (arrays["med"], self.med), (arrays["high"], self.high), (src_color, self.color)):
                _copy_slots(a, first, count, slots, ARENA_CHUNK, b)
            for a, b in self.attributes.items():
                _copy_slots(attrs[a], first, count, slots, ARENA_CHUNK, b)
            b = self.batches[slots]
            b["count"] = np.minimum(ARENA_CHUNK, count - np.arange(k) * ARENA_CHUNK)
            b["level"] = rec["level"]
            b["bbox_min"] = rec["bbox_min"]
            b["bbox_max"] = rec["bbox_max"]
            self.batches[slots] = b
            self.resident[nd] = slots
            self.loads += 1
            self.version += 1
            self.batch_version[slots] = self.version
        return True


# --------------------------------------------------------------------------- reader


def octree_complete(path) -> bool:
    """A finished octree: its metadata file (gigapoint's or Potree's) is written last, atomically."""
    p = Path(path)
    return (p / META_NAME).is_file() or (p / "metadata.json").is_file()


def is_octree_dir(path) -> bool:
    """A gigapoint or Potree 2.0 octree directory, or an unfinished conversion into one."""
    try:
        p = Path(path)
        if not p.is_dir():
            return False
    except (TypeError, OSError):
        return False
    return (
        (p / META_NAME).is_file()
        or ((p / "metadata.json").is_file() and (p / "hierarchy.bin").is_file())
        or (p / ".partial" / "state.json").is_file()
    )


class OctreeCloud:
    """A converted LOD octree, drawn through node selection + an arena (see ``select``)."""

    def __init__(
        self, name: str, meta: dict, nodes: np.ndarray, keys: np.ndarray, arrays: dict, attributes: dict, path: Path | None = None
    ):
        self.name = name
        self.meta = meta
        self.nodes = nodes
        self.keys = np.asarray(keys, np.uint64)
        self.arrays = arrays
        self.attributes = attributes
        self.path = path
        self.filtered_colors = True
        self.arena: Arena | None = None
        self.counts = nodes["count"].astype(np.int64)  # node counts never change: widened once, not per frame
        self.cube_min, self.cube_edge = key_cube(self.keys, meta["cube_min"], float(meta["cube_edge"]))
        lo, hi = self.bounds
        self.box_min = np.clip(self.cube_min, lo, hi)
        self.box_size = np.clip(self.cube_min + self.cube_edge[:, None], lo, hi) - self.box_min
        self.children = np.full((len(self.keys), 8), -1, np.int64)
        if len(self.keys) > 1:
            kid = np.arange(1, len(self.keys))
            parents = np.searchsorted(self.keys, self.keys[1:] >> np.uint64(3))
            if np.any(parents >= len(self.keys)) or np.any(
                self.keys[np.minimum(parents, len(self.keys) - 1)] != self.keys[1:] >> np.uint64(3)
            ):
                raise InputError(f"{path or name}: octree hierarchy is broken (a node without its parent)")
            self.children[parents, (self.keys[1:] & np.uint64(7)).astype(np.int64)] = kid
        if len(self.keys) == 0 or self.keys[0] != 1:
            raise InputError(f"{path or name}: octree has no root node")

    # -- PointCloud-like facts
    @property
    def n_points(self) -> int:
        return int(self.meta["points"])

    def __len__(self) -> int:
        return self.n_points

    @property
    def batches(self) -> np.ndarray:
        return self.nodes

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        b = self.meta["bounds"]
        return np.array(b["min"], np.float64), np.array(b["max"], np.float64)

    @property
    def levels(self) -> np.ndarray:
        return self.nodes["level"]

    def __repr__(self) -> str:
        lo, hi = self.bounds
        return f"OctreeCloud({self.name!r}, {self.n_points:,} points, {len(self.nodes):,} nodes, depth {int(self.levels.max())}, bounds {lo.tolist()} .. {hi.tolist()})"

    def node_arrays(self, index: int) -> tuple[dict, dict, int]:
        """(point arrays ``low``, ``med``, ``high``, ``color``, ``rgba``; attribute arrays; where node
        ``index``'s points start in them). Here: the memory-mapped files (only the pages a node's
        slice touches are read); a Potree cloud reads and decodes the node instead."""
        return self.arrays, self.attributes, int(self.nodes["first"][index])

    def node_points(self, index: int) -> dict:
        """Decoded float64 positions (30-bit) and colors of one node (for tests and tools)."""
        from ..core.quantize import dequantize

        arrays, attrs, first = self.node_arrays(index)
        rec = self.nodes[index]
        s = slice(first, first + int(rec["count"]))
        xyz = dequantize(arrays["low"][s], arrays["med"][s], arrays["high"][s], rec["bbox_min"], rec["bbox_max"], 30)
        out = {"xyz": xyz, "color": np.asarray(arrays["color"][s]), "rgba": np.asarray(arrays["rgba"][s])}
        for a, v in attrs.items():
            out[a] = np.asarray(v[s])
        return out

    # -- rendering
    def select_nodes(self, camera, settings, near: float, far: float) -> tuple[np.ndarray, np.ndarray, int]:
        """(node indices, projected cube sizes, point total) chosen for a view."""
        out_ids = np.empty(len(self.keys), np.int64)
        out_size = np.empty(len(self.keys), np.float64)
        counts = self.counts
        k, total = select_nodes(
            camera.screen_rows(), self.box_min, self.box_size, counts, self.children, float(camera.width), float(camera.height),
            float(near), float(far), float(settings.lod_threshold_px), int(settings.point_budget), out_ids, out_size,
            float(getattr(settings, "lod_foveation", 0.0)),
        )  # fmt: skip
        return out_ids[:k], out_size[:k], int(total)

    def _attribute_dtypes(self) -> dict:
        return {a: v.dtype for a, v in self.attributes.items() if v.ndim == 1}

    def select(self, camera, settings):
        """(arena, Selection) for one frame: selected nodes made resident, one batch per arena slot."""
        from ..render.selection import Selection, batch_matrices, precision_for, visible_and_size

        near, far = camera.clip_range(self.bounds)
        ids, _, total = self.select_nodes(camera, settings, near, far)
        ids = ids[self.nodes["count"][ids] > 0]
        if self.arena is None or self.arena.n_points < total:
            cap = max(total, min(int(settings.point_budget), self.n_points)) * 5 // 4 + 64 * ARENA_CHUNK
            self.arena = Arena(
                min(cap, self.n_points + (len(self.keys) + 1) * ARENA_CHUNK), self.name, self.bounds, self._attribute_dtypes()
            )
        arena = self.arena
        if not arena.ensure(ids, self):
            # a selection of many small nodes that wastes slots: grow and retry once
            self.arena = arena = Arena(arena.n_points * 2 + (len(ids) + 1) * ARENA_CHUNK, self.name, self.bounds, self._attribute_dtypes())
            arena.ensure(ids, self)
        rows = camera.screen_rows()
        recs = self.nodes[ids]
        _, size = visible_and_size(rows, recs["bbox_min"], recs["bbox_max"], camera.width, camera.height, near, far)
        bits = precision_for(size, settings.precision_threshold_px) if settings.adaptive_precision else np.full(len(ids), 30, np.int32)
        mats = batch_matrices(rows, recs["bbox_min"], recs["bbox_max"])
        slot_lists = [arena.resident[nd] for nd in ids.tolist()]
        n_slots = np.array([len(s) for s in slot_lists], np.int64)
        slots = np.concatenate(slot_lists) if slot_lists else np.empty(0, np.int64)
        owner = np.repeat(np.arange(len(ids)), n_slots)
        order = np.argsort(slots, kind="stable")
        slots, owner = slots[order], owner[order]
        sel = Selection(slots.astype(np.int64), bits[owner].astype(np.int32), mats[owner], size[owner], int(len(self.keys) - len(ids)))
        sel.nodes = ids  # type: ignore[attr-defined]  (node indices drawn, for stats and tests)
        return arena, sel


def open_octree(path) -> OctreeCloud:
    """Open a converted octree directory (gigapoint format or Potree 2.0) for rendering."""
    p = Path(path)
    if not p.is_dir():
        raise InputError(f"{p}: not a directory (an octree is a directory made by `gigapoint convert`)")
    if not (p / META_NAME).is_file():
        if (p / "metadata.json").is_file():
            from .potree import read_potree

            return read_potree(p)
        if (p / ".partial").exists():
            from .preview import open_preview

            return open_preview(p)
        raise InputError(f"{p}: no {META_NAME} or metadata.json: not a converted octree")
    try:
        meta = json.loads((p / META_NAME).read_text())
    except ValueError as exc:
        raise InputError(f"{p / META_NAME}: invalid JSON ({exc})") from None
    if meta.get("format") != FORMAT_NAME or meta.get("version") != FORMAT_VERSION:
        raise InputError(f"{p / META_NAME}: not a gigapoint octree of version {FORMAT_VERSION}")
    try:
        nodes = np.load(p / "nodes.npy")
        keys = np.load(p / "keys.npy")
        arrays = {k: np.load(p / f"{k}.npy", mmap_mode="r") for k in _ARRAYS}
        attributes = {a: np.load(p / f"attr.{a}.npy", mmap_mode="r") for a in meta.get("attributes", {})}
    except (OSError, ValueError) as exc:
        raise InputError(f"{p}: cannot read octree data ({' '.join(str(exc).split())})") from None
    if nodes.dtype != BATCH_DTYPE or len(nodes) != len(keys):
        raise InputError(f"{p}: nodes.npy / keys.npy do not match the gigapoint layout")
    n = int(meta["points"])
    if any(len(a) != n for a in arrays.values()) or int(nodes["count"].astype(np.int64).sum()) != n:
        raise InputError(f"{p}: point arrays hold a different number of points than {META_NAME} says ({n:,})")
    return OctreeCloud(meta.get("name", p.name), meta, nodes, keys, arrays, attributes, p)


def octree_info(path) -> dict:
    """What ``gigapoint info`` says about an octree directory (gigapoint or Potree 2.0) or an
    unfinished conversion, in ``file_info``'s keys plus nodes, levels, sampler and conversion."""
    p = Path(path)
    size = sum(f.stat().st_size for f in p.rglob("*") if f.is_file())
    if not octree_complete(p):
        from .preview import conversion_status

        s = conversion_status(p)
        return {
            "path": str(p),
            "format": "unfinished conversion",
            "point_count": int(s.get("points", 0)),
            "has_color": True,
            "attributes": s.get("attributes", []),
            "conversion": s,
            "file_size": size,
        }
    cloud = open_octree(p)
    lo, hi = cloud.bounds
    potree = cloud.meta.get("format") != FORMAT_NAME
    return {
        "path": str(p),
        "format": "Potree 2.0 octree" if potree else f"gigapoint octree {FORMAT_VERSION}",
        "encoding": cloud.meta.get("encoding") if potree else None,
        "point_count": int(cloud.n_points),
        "bounds": {"min": np.asarray(lo).tolist(), "max": np.asarray(hi).tolist()},
        "has_color": True,
        "attributes": sorted(cloud.attributes),
        "nodes": len(cloud.keys),
        "levels": int(cloud.nodes["level"].max()) + 1,
        "sampler": cloud.meta.get("sampler"),
        "spacing": cloud.meta.get("spacing"),
        "file_size": size,
    }
