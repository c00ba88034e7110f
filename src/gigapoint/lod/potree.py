"""Potree 2.0 interop (see ../shared/POTREE2.md): writer (DEFAULT or BROTLI) and reader (both).

Writing: the converter's node sets are streamed into the octree file; the hierarchy file is
one chunk holding every node breadth-first (sorted keys are breadth-first); the metadata file
comes last (file names: octree_dir.py). Reading (PotreeCloud): the hierarchy (with proxy chunks) is parsed at open; a node's
payload is read from the octree file and decoded into gigapoint's batch layout only when the
node is drawn (made resident in the arena), so the result renders like any converted octree,
in bounded memory.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ..atomic import atomic_bytes, atomic_json, atomic_npy, fsync_file, write_at
from ..core.layout import BATCH_DTYPE
from ..core.quantize import quantize
from ..errors import InputError
from .grid import output_grid
from .keys import MAX_LEVEL, key_cube, level_of
from .octree_dir import OctreeDir
from .store import OctreeCloud, check_grid, check_placement, tight_bounds

HIERARCHY_DTYPE = np.dtype([("type", "u1"), ("mask", "u1"), ("points", "<u4"), ("offset", "<i8"), ("size", "<i8")])
_TYPES = {
    "int8": "i1",
    "int16": "<i2",
    "int32": "<i4",
    "int64": "<i8",
    "uint8": "u1",
    "uint16": "<u2",
    "uint32": "<u4",
    "uint64": "<u8",
    "float": "<f4",
    "double": "<f8",
}
#: what the writer stores first (LAS order): position, intensity, classification (zeros where
#: the points have none: viewers expect them), then every other attribute, then rgb
WRITE_ATTRIBUTES = (("position", "int32", 3), ("intensity", "uint16", 1), ("classification", "uint8", 1), ("rgb", "uint16", 3))
#: gigapoint's attribute names as PotreeConverter writes them (the reader maps them back)
POTREE_NAMES = {"return_number": "return number", "number_of_returns": "number of returns", "point_source_id": "point source id", "gps_time": "gps-time"}
_TYPE_OF = {np.dtype(t): name for name, t in _TYPES.items()}


def _potree_type(dtype) -> str:
    """The Potree type an attribute of ``dtype`` is written as (booleans as uint8, half floats as float)."""
    dt = np.dtype(dtype)
    return _TYPE_OF[np.dtype(np.uint8) if dt == np.bool_ else np.dtype(np.float32) if dt == np.float16 else dt]


BROTLI_QUALITY = 5


def _brotli():
    try:
        import brotli
    except ImportError:
        raise InputError("BROTLI-encoded Potree data needs the brotli package (pip install 'gigapoint[lod]')") from None
    return brotli


# --------------------------------------------------------------------------- Morton helpers (BROTLI)


def _spread16(v: np.ndarray) -> np.ndarray:
    """Low 16 bits of v spread to every third bit (bit i -> bit 3i), uint64."""
    v = v.astype(np.uint64) & np.uint64(0xFFFF)
    out = np.zeros_like(v)
    for i in range(16):
        out |= ((v >> np.uint64(i)) & np.uint64(1)) << np.uint64(3 * i)
    return out


def _compact16(m: np.ndarray) -> np.ndarray:
    """Inverse of _spread16: bits 0, 3, 6, ... 45 of m -> a 16-bit value."""
    m = m.astype(np.uint64)
    out = np.zeros_like(m)
    for i in range(16):
        out |= ((m >> np.uint64(3 * i)) & np.uint64(1)) << np.uint64(i)
    return out


# --------------------------------------------------------------------------- writer


def _attribute_entries(layout: list[tuple[str, str, int]], scale, offset, stats) -> list[dict]:
    """metadata.json's attribute records of ``layout`` ((name, Potree type, elements) in record order)."""
    out = []
    for name, typ, n in layout:
        size = np.dtype(_TYPES[typ]).itemsize
        lo, hi = stats[name]
        e = {
            "name": POTREE_NAMES.get(name, name),
            "description": "",
            "size": size * n,
            "numElements": n,
            "elementSize": size,
            "type": typ,
            "min": list(map(float, lo)),
            "max": list(map(float, hi)),
        }
        if name == "position":
            e.update(scale=list(scale), offset=list(offset))
        else:
            e.update(scale=[1.0] * n, offset=[0.0] * n)
        out.append(e)
    return out


def write_layout(attributes: dict) -> list[tuple[str, str, int]]:
    """(name, Potree type, elements) of every field a node's record holds, in order, for points
    with ``attributes`` ({name: dtype}): ``WRITE_ATTRIBUTES``' position, intensity and
    classification, the other attributes, rgb."""
    first, rgb = list(WRITE_ATTRIBUTES[:3]), WRITE_ATTRIBUTES[3]
    taken = {name for name, _, _ in first}
    return first + [(a, _potree_type(dt), 1) for a, dt in attributes.items() if a not in taken] + [rgb]


def record_dtype(layout) -> np.dtype:
    """A point's record in a DEFAULT-encoded octree.bin: the fields of ``layout``, packed."""
    return np.dtype([(a, _TYPES[t], (k,)) if k > 1 else (a, _TYPES[t]) for a, t, k in layout])


def encode_node(xyz: np.ndarray, rgb16: np.ndarray, attributes: dict, layout, scale, offset, encoding: str, out=None) -> bytes | None:
    """Points as octree.bin holds them: their fields in ``layout`` order (``write_layout``; an
    attribute the points lack is zeros). DEFAULT: into ``out``, their records (``record_dtype``:
    a node's blob is its points' records, so a node set's are made at once), None returned;
    BROTLI: one node's blob."""
    n = len(xyz)
    ixyz = np.floor((xyz - np.asarray(offset)) / np.asarray(scale) + 0.5).astype(np.int64)
    ixyz = np.clip(ixyz, 0, 2**31 - 1).astype(np.int32)

    def values(name, typ):
        v = attributes.get(name)
        return np.zeros(n, _TYPES[typ]) if v is None else np.asarray(v).astype(_TYPES[typ])

    if encoding == "DEFAULT":
        for a, t, _ in layout:
            out[a] = ixyz if a == "position" else rgb16 if a == "rgb" else values(a, t)
        return None
    # BROTLI: attribute by attribute, points in Morton order, position and rgb as Morton codes
    u = ixyz.astype(np.uint64)
    lower = _spread16(u[:, 0]) | _spread16(u[:, 1]) << np.uint64(1) | _spread16(u[:, 2]) << np.uint64(2)
    upper = (
        _spread16(u[:, 0] >> np.uint64(16))
        | _spread16(u[:, 1] >> np.uint64(16)) << np.uint64(1)
        | _spread16(u[:, 2] >> np.uint64(16)) << np.uint64(2)
    )
    order = np.lexsort((lower, upper))
    parts = []
    for a, t, _ in layout:
        if a == "position":
            pos = np.empty((n, 2), np.uint64)
            pos[:, 0] = upper[order]
            pos[:, 1] = lower[order]
            parts.append(pos.astype("<u8").tobytes())
        elif a == "rgb":
            c = rgb16[order].astype(np.uint64)
            parts.append((_spread16(c[:, 0]) | _spread16(c[:, 1]) << np.uint64(1) | _spread16(c[:, 2]) << np.uint64(2)).astype("<u8").tobytes())
        else:
            parts.append(values(a, t)[order].tobytes())
    # quality 5, not the default 11: ~47x faster (1.8 M instead of 0.04 M points/s on one core)
    # for a file ~2 % larger, measured on node-sized payloads
    return _brotli().compress(b"".join(parts), quality=BROTLI_QUALITY)


PLACED = "potree.npy"  # a node set whose nodes the build placed in octree.bin: (byte offset, size) a node
PLACED_STATS = "potree_stats.json"  # ... and its fields' minimum and maximum, as written


def potree_plan(st: dict) -> tuple[list, np.ndarray, np.ndarray]:
    """(write_layout, scale, offset) of the Potree octree a conversion's state makes."""
    scale, offset = output_grid(st, unsigned=True)
    return write_layout({a: np.dtype(d) for a, d in (st.get("attributes") or {}).items()}), scale, offset


def place_node_set(out: OctreeDir, at: int, dest: Path, xyz, rgba, attributes: dict, counts, plan, encoding: str) -> int:
    """A node set's nodes (``counts`` points each, in order: ``xyz``, u32 ``rgba``, ``attributes``)
    encoded straight into the octree.bin being built (``out.potree_octree_in_progress``) from
    byte ``at`` on, instead of kept in float64 for the write phase to encode and write again
    (a 20 M-point Potree conversion wrote 44 bytes a point twice); their places and statistics
    into ``dest`` (PLACED, PLACED_STATS). Returns where the next set goes."""
    layout, scale, offset = plan
    rgb16 = np.asarray(rgba).view(np.uint8).reshape(-1, 4)[:, :3].astype(np.uint16) * np.uint16(257)
    stats = {a: [[np.inf] * k, [-np.inf] * k] for a, _, k in layout}
    if len(xyz):
        _add_stats(stats, layout, xyz, rgb16, attributes, scale, offset)
    counts = np.asarray(counts, np.int64)
    if encoding == "DEFAULT":  # a point's record is all there is: the set's records at once, nodes one after another
        rec = np.empty(len(xyz), record_dtype(layout))
        encode_node(xyz, rgb16, attributes, layout, scale, offset, encoding, out=rec)
        payload, sizes = [rec.view(np.uint8)], counts * rec.dtype.itemsize
    else:
        ends = np.cumsum(counts)
        payload = [encode_node(xyz[e - c : e], rgb16[e - c : e], {a: v[e - c : e] for a, v in attributes.items()}, layout, scale, offset, encoding)
                   if c else b"" for c, e in zip(counts.tolist(), ends.tolist())]  # fmt: skip
        sizes = np.array([len(b) for b in payload], np.int64)
    end = write_at(out.potree_octree_in_progress, at, payload)
    atomic_json(dest / PLACED_STATS, stats)
    atomic_npy(dest / PLACED, np.stack([at + np.cumsum(sizes) - sizes, sizes], axis=1).astype(np.int64).reshape(-1, 2))
    return end


def placed_end(sets) -> int:
    """Where the next node set's nodes go in the octree.bin being built: after the finished ``sets``'."""
    end = 0
    for src in sets:
        if (src / PLACED).exists():
            placed = np.load(src / PLACED)
            end = max(end, int((placed[:, 0] + placed[:, 1]).max(initial=0)))
    return end


def _add_stats(stats: dict, layout, xyz, rgb16, attrs: dict, scale, offset) -> None:
    """A node set's minimum and maximum of each field as written, into ``stats``: positions from
    the set's extremes (rounding to the grid keeps their order), not from every point's integers
    (1.5 of a 20 M-point write's 5 s)."""
    def columns(v):  # column by column: numpy's min(axis=0) of (n, 3) runs an inner loop of 3 (10x slower)
        return np.array([v[:, j].min() for j in range(3)]), np.array([v[:, j].max() for j in range(3)])

    for a, t, _ in layout:
        if a == "position":
            lo, hi = (np.floor((v - offset) / scale + 0.5) for v in columns(xyz))
        elif a == "rgb":
            lo, hi = columns(rgb16)
        elif a in attrs:
            v = attrs[a] if attrs[a].dtype == np.dtype(_TYPES[t]) else attrs[a].astype(_TYPES[t])
            lo, hi = np.array([v.min()]), np.array([v.max()])
        else:
            lo = hi = np.zeros(1)
        stats[a][0] = np.minimum(stats[a][0], lo).tolist()
        stats[a][1] = np.maximum(stats[a][1], hi).tolist()


def write_potree(out: OctreeDir, sources: list[Path], st: dict, name: str, progress, encoding: str = "DEFAULT") -> int:
    """Assemble built node sets into the Potree 2.0 folder ``out``, its metadata last; returns
    the number of nodes. Node sets the build placed in the octree.bin being built
    (``place_node_set``) are taken as they are; those kept in files (built on Dask workers) are
    placed now, in ``sources`` order, the build's: a single process's bytes."""
    plan = potree_plan(st)  # the inputs' grid (a LAS file's 0.1 mm was cut to 1 mm), else a fine enough one (grid.py)
    layout, scale, offset = plan
    part = out.potree_octree_in_progress
    moved = not part.exists() and out.potree_octree.exists()  # a write phase resumed after the move: every set was placed
    if not moved:
        at = placed_end(sources)
        for src in sources:
            if not (src / PLACED).exists():  # (a resumed write phase placed those before it)
                attrs = {a: np.load(src / f"attr.{a}.npy") for a in st.get("attributes") or {} if (src / f"attr.{a}.npy").exists()}
                at = place_node_set(out, at, src, np.load(src / "xyz.npy"), np.load(src / "rgba.npy"), attrs, np.load(src / "counts.npy"), plan, encoding)
    records: dict[int, tuple[int, int, int]] = {}
    stats = {a: [[np.inf] * k, [-np.inf] * k] for a, _, k in layout}
    for src in sources:  # every node's place and the sets' statistics
        at, counts = np.load(src / PLACED), np.load(src / "counts.npy")
        for key, n, (off, size) in zip(np.load(src / "keys.npy").tolist(), counts.tolist(), at.tolist()):
            records[key] = (n, off, size)
        for a, (lo, hi) in json.loads((src / PLACED_STATS).read_text()).items():
            stats[a] = [np.minimum(stats[a][0], lo).tolist(), np.maximum(stats[a][1], hi).tolist()]
        progress.advance(int(counts.sum()))
    if not moved:
        with open(part, "r+b") as f:
            f.truncate(max((off + size for _, off, size in records.values()), default=0))  # a killed set's bytes past the end
        fsync_file(part)
        os.replace(part, out.potree_octree)
    return _finish_potree(out, records, stats, layout, st, name, scale, offset, encoding)


def _finish_potree(out: OctreeDir, records: dict, stats: dict, layout, st: dict, name: str, scale, offset, encoding: str) -> int:
    """octree.bin written: the hierarchy and, last, the metadata; returns the number of nodes."""
    origin, edge = np.array(st["origin"]), float(st["edge"])
    scale3 = scale.tolist()
    n_total = sum(n for n, _, _ in records.values())
    keys = np.array(sorted(records), np.uint64)
    key_set = set(records)
    hier = np.zeros(len(keys), HIERARCHY_DTYPE)
    for i, key in enumerate(keys.tolist()):
        mask = sum(1 << c for c in range(8) if (key << 3 | c) in key_set)
        n, off, size = records[key]
        hier[i] = (0 if mask else 1, mask, n, off, size)
    atomic_bytes(out.potree_hierarchy, hier.tobytes())
    stats["position"] = [
        [v * s + o for v, s, o in zip(stats["position"][0], scale, offset)],
        [v * s + o for v, s, o in zip(stats["position"][1], scale, offset)],
    ]
    meta = {
        "version": "2.0",
        "name": name,
        "description": "",
        "points": int(n_total),
        "projection": (st.get("source") or {}).get("crs") or "",
        "hierarchy": {"firstChunkSize": int(HIERARCHY_DTYPE.itemsize * len(keys)), "stepSize": 4, "depth": int(level_of(keys).max())},
        "offset": offset.tolist(),
        "scale": scale3,
        "spacing": edge / 128.0,
        "boundingBox": {"min": list(map(float, origin)), "max": list(map(float, origin + edge))},
        "encoding": encoding,
        "attributes": _attribute_entries(layout, scale3, offset.tolist(), stats),
    }
    atomic_json(out.potree_meta, meta, indent="\t", durable=True)  # last: the folder is complete from here on
    return len(keys)


# --------------------------------------------------------------------------- reader


def _parse_hierarchy(data: bytes, offset: int, size: int, first_key: int, out: dict, depth: int = 0) -> None:
    if depth > MAX_LEVEL + 1 or offset < 0 or size < 0 or offset + size > len(data) or size % HIERARCHY_DTYPE.itemsize:
        raise ValueError(f"hierarchy chunk at {offset} (+{size}) is out of range or misaligned")
    recs = np.frombuffer(data, HIERARCHY_DTYPE, count=size // HIERARCHY_DTYPE.itemsize, offset=offset)
    keys = [first_key]
    for i, r in enumerate(recs):
        if i >= len(keys):
            raise ValueError("hierarchy chunk holds more records than its child masks announce")
        key = keys[i]
        if r["type"] == 2 and i > 0:  # proxy: the node and its subtree live in another chunk
            _parse_hierarchy(data, int(r["offset"]), int(r["size"]), key, out, depth + 1)
            continue
        out[key] = (int(r["points"]) if r["size"] > 0 else 0, int(r["offset"]), int(r["size"]))
        for c in range(8):
            if r["mask"] >> c & 1:
                if key.bit_length() > 3 * MAX_LEVEL + 1:
                    raise ValueError("hierarchy deeper than 20 levels")
                keys.append(key << 3 | c)


def _node_dtype(attributes: list[dict]) -> np.dtype:
    fields = []
    for a in attributes:
        t = _TYPES.get(a["type"])
        if t is None:
            raise ValueError(f"unknown attribute type {a['type']!r}")
        n = int(a.get("numElements", 1))
        fields.append((a["name"], t, (n,)) if n > 1 else (a["name"], t))
    return np.dtype(fields)


def decode_node(blob: bytes, n: int, attributes: list[dict], encoding: str) -> dict:
    """{attribute name: array} of one node (position as int64 (n, 3) integers)."""
    if n == 0:
        return {}
    if encoding == "DEFAULT":
        dt = _node_dtype(attributes)
        if len(blob) != n * dt.itemsize:
            raise ValueError(f"node holds {len(blob)} bytes, {n} points need {n * dt.itemsize}")
        rec = np.frombuffer(blob, dt)
        return {a["name"]: (rec[a["name"]].astype(np.int64) if a["name"] == "position" else rec[a["name"]]) for a in attributes}
    raw = _brotli().decompress(blob)
    out, off = {}, 0
    for a in attributes:
        name = a["name"]
        if name == "position":
            m = np.frombuffer(raw, "<u8", count=2 * n, offset=off).reshape(n, 2)
            off += 16 * n
            upper, lower = m[:, 0], m[:, 1]
            out[name] = np.stack(
                [
                    (_compact16(upper >> np.uint64(k)) << np.uint64(16) | _compact16(lower >> np.uint64(k))).astype(np.int64)
                    for k in range(3)
                ],
                axis=1,
            )
        elif name == "rgb":
            m = np.frombuffer(raw, "<u8", count=n, offset=off)
            off += 8 * n
            out[name] = np.stack([_compact16(m >> np.uint64(k)) for k in range(3)], axis=1).astype(np.uint16)
        else:
            dt = np.dtype(_TYPES[a["type"]])
            k = int(a.get("numElements", 1))
            v = np.frombuffer(raw, dt, count=n * k, offset=off)
            off += dt.itemsize * n * k
            out[name] = v.reshape(n, k) if k > 1 else v
    return out


class PotreeCloud(OctreeCloud):
    """A Potree 2.0 directory opened for rendering: the hierarchy is read at open (it is small),
    a node's payload only when the node is made resident in the arena (the bounded node cache
    every OctreeCloud draws through) or asked for by ``node_points``, so a dataset larger than
    the memory renders. ``node_reads``/``bytes_read`` count the payloads read.

    A node's record (``nodes``) holds its cube clipped to the cloud's bounds until the node is
    first decoded, then its tight bbox, which is what it is quantized against and drawn with,
    exactly as if every node had been decoded at open. The cloud's bounds are the ``position``
    attribute's min/max from the metadata (the bounding box where absent).
    """

    def __init__(self, folder, meta: dict):
        d = OctreeDir(folder)
        p = d.path
        self.encoding = meta.get("encoding", "DEFAULT")
        if self.encoding not in ("DEFAULT", "BROTLI"):
            raise InputError(f"{d.potree_meta}: unknown encoding {self.encoding!r}")
        try:
            self.potree_attributes = meta["attributes"]
            self.scale, self.offset = np.array(meta["scale"], np.float64), np.array(meta["offset"], np.float64)
            bmin, bmax = np.array(meta["boundingBox"]["min"], np.float64), np.array(meta["boundingBox"]["max"], np.float64)
            first = int(meta["hierarchy"]["firstChunkSize"])
            hier = d.potree_hierarchy.read_bytes()
            info: dict[int, tuple[int, int, int]] = {}
            _parse_hierarchy(hier, 0, first, 1, info)
            record = _node_dtype(self.potree_attributes)
            if "position" not in (record.names or ()) or record["position"].shape != (3,):  # (each node's KeyError when drawn)
                raise ValueError("its attributes hold no 'position' of three numbers")
            check_placement(
                {"scale": self.scale, "offset": self.offset, "boundingBox.min": bmin, "boundingBox.max": bmax},
                positive="scale",
                box=("boundingBox.min", "boundingBox.max"),
            )
            lo, hi = _position_range(str(d.potree_meta), self.potree_attributes, bmin, bmax, float(np.max(np.abs(self.scale))))
        except (KeyError, TypeError, ValueError, OSError) as exc:
            raise InputError(f"{p}: invalid Potree hierarchy/metadata ({' '.join(str(exc).split())})") from None
        check_grid(str(d.potree_meta), "Potree metadata", self.scale, self.offset)
        self.octree_bin = d.potree_octree
        try:
            bin_size = self.octree_bin.stat().st_size
        except OSError as exc:
            raise InputError(f"{self.octree_bin}: cannot read ({exc.strerror or exc})") from None
        keys = np.array(sorted(info), np.uint64)
        table = np.array([info[k] for k in keys.tolist()], np.int64).reshape(-1, 3)
        counts, self.byte_offset, self.byte_size = table[:, 0], table[:, 1], table[:, 2]
        # payload ranges are checked here, so that a truncated file fails at open, not mid-render
        full = counts > 0
        outside = full & ((self.byte_offset < 0) | (self.byte_offset + self.byte_size > bin_size))
        wrong_size = full & (self.byte_size != counts * record.itemsize) if self.encoding == "DEFAULT" else np.zeros_like(full)
        if outside.any() or wrong_size.any():
            i = int(np.flatnonzero(outside | wrong_size)[0])
            off, size, n = int(self.byte_offset[i]), int(self.byte_size[i]), int(counts[i])
            problem = (
                f"bytes {off}..{off + size} lie beyond the file's {bin_size}"
                if outside[i]
                else f"node holds {size} bytes, {n} points need {n * record.itemsize}"
            )
            raise InputError(f"{self.octree_bin}: cannot decode node {_name(int(keys[i]))} ({problem})")
        edge = float(np.max(bmax - bmin))
        nodes = np.zeros(len(keys), BATCH_DTYPE)
        nodes["level"] = level_of(keys)
        nodes["count"] = counts
        nodes["first"] = np.cumsum(counts) - counts  # where each node's points go in to_memory()
        cmin, cedge = key_cube(keys, bmin, edge)
        nonempty = counts > 0  # until decoded: the cube clipped to the bounds (an empty node keeps its cube)
        nodes["bbox_min"] = np.where(nonempty[:, None], np.clip(cmin, lo, hi), cmin)
        nodes["bbox_max"] = np.where(nonempty[:, None], np.clip(cmin + cedge[:, None], lo, hi), cmin + cedge[:, None])
        self.extra = {  # decoded name -> (gigapoint attribute name, dtype)
            a["name"]: (a["name"].replace(" ", "_").replace("-", "_"), np.dtype(_TYPES[a["type"]]))
            for a in self.potree_attributes
            if a["name"] not in ("position", "rgb") and int(a.get("numElements", 1)) == 1
        }
        cloud_meta = {
            "format": "potree-2.0",
            "points": int(counts.sum()),
            "nodes": len(keys),
            "cube_min": bmin.tolist(),
            "cube_edge": edge,
            "bounds": {"min": lo.tolist(), "max": hi.tolist()},
            "encoding": self.encoding,
            "spacing": meta.get("spacing"),
            "crs": meta.get("projection") or None,
        }
        super().__init__(meta.get("name") or p.name, cloud_meta, nodes, keys, {}, {}, p)
        self.node_reads = 0
        self.bytes_read = 0

    def _attribute_dtypes(self) -> dict:
        return {name: dt for name, dt in self.extra.values()}

    def new_arena(self, points: int):
        arena = super().new_arena(points)
        arena.source_scale = self.scale.tolist()  # positions are integers at this scale: point_info rounds to it
        return arena

    def node_arrays(self, index: int) -> tuple[dict, dict, int]:
        """Node ``index`` read from octree.bin, decoded and quantized against its tight bbox
        (which its record takes from now on): (point arrays, attribute arrays, 0)."""
        n = int(self.nodes["count"][index])
        if n == 0:
            empty = np.empty(0, np.uint32)
            return (
                dict.fromkeys(("low", "med", "high", "color", "rgba"), empty),
                {a: np.empty(0, dt) for a, dt in self._attribute_dtypes().items()},
                0,
            )
        off, size = int(self.byte_offset[index]), int(self.byte_size[index])
        with open(self.octree_bin, "rb") as f:
            f.seek(off)
            blob = f.read(size)
        self.node_reads += 1
        self.bytes_read += len(blob)
        try:
            d = decode_node(blob, n, self.potree_attributes, self.encoding)
        except Exception as exc:  # noqa: BLE001 - any decoding failure is a corrupt node
            raise InputError(
                f"{self.octree_bin}: cannot decode node {_name(int(self.keys[index]))} ({' '.join(str(exc).split())})"
            ) from None
        rec = self.nodes[index : index + 1].copy()
        rec["first"] = 0
        low, med, high = quantize(d["position"] * self.scale + self.offset, np.arange(n, dtype=np.int64), rec)
        self.nodes[index]["bbox_min"], self.nodes[index]["bbox_max"] = rec[0]["bbox_min"], rec[0]["bbox_max"]
        rgba = np.full((n, 4), 255, np.uint8)
        if "rgb" in d:
            c = d["rgb"].astype(np.int64)
            rgba[:, :3] = np.clip(np.where(c > 255, c // 256, c), 0, 255)
        color = rgba.view(np.uint32).reshape(-1)
        attrs = {name: (d[a] if a in d else np.zeros(n, dt)) for a, (name, dt) in self.extra.items()}
        return {"low": low, "med": med, "high": high, "color": color, "rgba": color}, attrs, 0

    @property
    def attribute_names(self) -> list[str]:
        return sorted(name for name, _ in self.extra.values())

    def to_memory(self) -> OctreeCloud:
        """Every node decoded into one in-memory OctreeCloud (small datasets; the eager reading)."""
        total = self.n_points
        arrays = {k: np.empty(total, np.uint32) for k in ("low", "med", "high", "color")}
        arrays["rgba"] = arrays["color"]
        attrs = {name: np.zeros(total, dt) for name, dt in self._attribute_dtypes().items()}
        for i in np.flatnonzero(self.nodes["count"] > 0).tolist():
            src, src_attrs, _ = self.node_arrays(i)
            s = slice(int(self.nodes["first"][i]), int(self.nodes["first"][i]) + int(self.nodes["count"][i]))
            for k in ("low", "med", "high", "color"):
                arrays[k][s] = src[k]
            for a, v in src_attrs.items():
                attrs[a][s] = v
        nodes = self.nodes.copy()
        meta = dict(self.meta)
        full = nodes["count"] > 0
        if full.any():
            meta["bounds"] = {"min": nodes["bbox_min"][full].min(axis=0).tolist(), "max": nodes["bbox_max"][full].max(axis=0).tolist()}
        return OctreeCloud(self.name, meta, nodes, self.keys, arrays, attrs, self.path)


def _position_range(name: str, attributes: list[dict], bmin: np.ndarray, bmax: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """The points' bounds: the ``position`` attribute's min/max (world coordinates, as
    PotreeConverter 2 and our writer store them) when they are there, else the bounding box; a
    bounding box beside them is a one-line error (it culled every node: a blank image)."""
    for a in attributes:
        if a.get("name") == "position":
            try:
                lo, hi = np.array(a["min"], np.float64), np.array(a["max"], np.float64)
            except (KeyError, TypeError, ValueError):
                break
            if lo.shape == hi.shape == (3,):
                # (its step: our writer's cube is chosen before positions are rounded to the grid, a step beyond at most)
                return tight_bounds(name, "Potree metadata (position min/max, boundingBox)", lo, hi, bmin, float(np.max(bmax - bmin)), step)
            break
    return bmin, bmax


def read_potree(folder) -> PotreeCloud:
    """A Potree 2.0 folder (an OctreeDir or a path; PotreeConverter 2.x or ``gigapoint convert
    --format potree``), nodes loaded on demand (see PotreeCloud)."""
    d = OctreeDir(folder)
    try:
        meta = json.loads(d.potree_meta.read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"{d.potree_meta}: cannot read ({' '.join(str(exc).split())})") from None
    if not str(meta.get("version", "")).startswith("2."):
        raise InputError(f"{d.potree_meta}: Potree version {meta.get('version')!r} is not supported (2.x only)")
    return PotreeCloud(d, meta)


def _name(key: int) -> str:
    from .keys import key_name

    return key_name(key)
