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
from numba import njit, prange

from ..atomic import atomic_bytes, atomic_json, atomic_npy, fsync_file, start_writeback, write_at
from ..core.chunk import DEFAULT_COLOR, ColorScaler, safe_attribute_name
from ..core.cloud import byte_views
from ..core.layout import BATCH_DTYPE
from ..core.quantize import gather_batch, quantize
from ..errors import InputError
from .grid import output_grid
from .keys import MAX_LEVEL, key_cube, level_of
from .octree_dir import OctreeDir
from .store import OctreeCloud, check_grid, check_placement, known_classes, tight_bounds

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
#: the points have none: viewers expect them), then every other attribute, then rgb (left out
#: for points without colours, as PotreeConverter 2 leaves it out)
WRITE_ATTRIBUTES = (("position", "int32", 3), ("intensity", "uint16", 1), ("classification", "uint8", 1), ("rgb", "uint16", 3))
#: gigapoint's attribute names as PotreeConverter writes them (the reader maps them back)
POTREE_NAMES = {"return_number": "return number", "number_of_returns": "number of returns", "point_source_id": "point source id",
                "gps_time": "gps-time", "scan_angle_rank": "scan angle rank", "user_data": "user data", "scan_angle": "scan angle"}  # fmt: skip
_FROM_POTREE = {v: k for k, v in POTREE_NAMES.items()}
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


def write_layout(attributes: dict, has_color: bool = True) -> list[tuple[str, str, int]]:
    """(name, Potree type, elements) of every field a node's record holds, in order, for points
    with ``attributes`` ({name: dtype}): ``WRITE_ATTRIBUTES``' position, intensity and
    classification, the other attributes, rgb (not for points without colours: ``has_color``
    False; their grey is no colour of theirs)."""
    first, rgb = list(WRITE_ATTRIBUTES[:3]), WRITE_ATTRIBUTES[3]
    taken = {name for name, _, _ in first}
    return first + [(a, _potree_type(dt), 1) for a, dt in attributes.items() if a not in taken] + ([rgb] if has_color else [])


def record_dtype(layout) -> np.dtype:
    """A point's record in a DEFAULT-encoded octree.bin: the fields of ``layout``, packed."""
    return np.dtype([(a, _TYPES[t], (k,)) if k > 1 else (a, _TYPES[t]) for a, t, k in layout])


_RECORDS_A_TASK = 8192  # a task's records stay in the cache while it writes them field by field


@njit(parallel=True, cache=True)
def _pack_records(xyz, rgba, idx, offset, scale, pos_at, rgb_at, attr_src, attr_stride, attr_width, attr_at, attr_kind, rec_size, out, lo, hi):
    """Record j of ``out`` (u8, ``rec_size`` bytes a point, little-endian) from point idx[j], with
    no gathered copy of the inputs (a task's values only): its position on the grid (int32, clipped at 0 and 2^31 - 1),
    its attributes (``attr_src[a]``'s bytes from idx[j] * attr_stride[a]: a stride 0 reads a
    value of zeros, for a field the points lack), its colour (8 to 16 bits a channel: x 257;
    none where ``rgb_at`` is negative: a layout without rgb).
    Task t's minimum and maximum of each field as written go to lo[t], hi[t]: the position
    (3, as float grid steps), the attributes (attr_kind 0 unsigned, 1 signed, 2 float; a NaN
    wins, as numpy's min), the colour (3). A task goes field by field, each field's values
    gathered first in a loop of independent loads (they overlap their cache misses; a loop
    that also encodes does not), and fetches a numba list's item once, not once a point."""
    n = idx.shape[0]
    n_attr = len(attr_src)
    for t in prange((n + _RECORDS_A_TASK - 1) // _RECORDS_A_TASK):
        j0, j1 = t * _RECORDS_A_TASK, min(n, (t + 1) * _RECORDS_A_TASK)
        tlo, thi = lo[t], hi[t]
        pts = gather_batch(xyz, idx, j0, j1 - j0)
        for a in range(3):
            q_lo, q_hi, o, sc = np.inf, -np.inf, offset[a], scale[a]  # (in registers, not through lo and hi a point)
            for j in range(j0, j1):
                q = np.floor((pts[j - j0, a] - o) / sc + 0.5)  # as numpy computed it: the same bits
                q_lo, q_hi = min(q_lo, q), max(q_hi, q)
                _put(out, j * rec_size + pos_at + 4 * a, np.uint64(min(max(np.int64(q), 0), 2**31 - 1)), 4)
            tlo[a], thi[a] = q_lo, q_hi
        vals = np.empty(j1 - j0, np.uint64)
        for a in range(n_attr):
            _gather_values(attr_src[a], attr_stride[a], attr_width[a], idx, j0, j1, vals)
            _pack_field(vals, attr_width[a], attr_at[a], attr_kind[a], j0, j1, rec_size, out, tlo, thi, 3 + a)
        if rgb_at < 0:
            continue
        for j in range(j0, j1):
            vals[j - j0] = rgba[idx[j]]
        for ch in range(3):
            c_lo, c_hi = np.uint64(0xFFFF), np.uint64(0)
            for j in range(j0, j1):
                v16 = ((vals[j - j0] >> np.uint64(8 * ch)) & np.uint64(0xFF)) * np.uint64(257)
                c_lo, c_hi = min(c_lo, v16), max(c_hi, v16)
                _put(out, j * rec_size + rgb_at + 2 * ch, v16, 2)
            tlo[3 + n_attr + ch], thi[3 + n_attr + ch] = np.float64(c_lo), np.float64(c_hi)


@njit(inline="always")
def _gather_values(src, stride, w, idx, j0, j1, vals):
    """vals[j - j0] = the w-byte value of ``src`` (bytes) at row idx[j], j in j0..j1; 0 where
    ``stride`` is 0 (a field the points lack)."""
    if stride == 0:
        vals[:] = 0
    elif w == 1:
        for j in range(j0, j1):
            vals[j - j0] = src[idx[j]]
    elif w == 2:
        v2 = src.view(np.uint16)
        for j in range(j0, j1):
            vals[j - j0] = v2[idx[j]]
    elif w == 4:
        v4 = src.view(np.uint32)
        for j in range(j0, j1):
            vals[j - j0] = v4[idx[j]]
    else:
        v8 = src.view(np.uint64)
        for j in range(j0, j1):
            vals[j - j0] = v8[idx[j]]


@njit(inline="always")
def _pack_field(vals, w, at, kind, j0, j1, rec_size, out, tlo, thi, f):
    """One attribute's values (``_gather_values``) into records j0..j1 (``_pack_records``), their
    minimum and maximum as numbers into tlo[f], thi[f]."""
    bits64 = np.empty(1, np.uint64)  # a value's bits read back as a float
    bits32 = np.empty(1, np.uint32)
    as64, as32 = bits64.view(np.float64), bits32.view(np.float32)
    v_lo, v_hi = tlo[f], thi[f]
    for j in range(j0, j1):
        u = vals[j - j0]
        if w == 1:  # (constant widths: each _put one store)
            _put(out, j * rec_size + at, u, 1)
        elif w == 2:
            _put(out, j * rec_size + at, u, 2)
        elif w == 4:
            _put(out, j * rec_size + at, u, 4)
        else:
            _put(out, j * rec_size + at, u, 8)
        if kind == 0:
            v = np.float64(u)
        elif kind == 1:
            v = np.float64(np.int64(u) - (np.int64(1) << (8 * w)) if w < 8 and u >> np.uint64(8 * w - 1) else np.int64(u))
        elif w == 4:
            bits32[0] = np.uint32(u)
            v = np.float64(as32[0])
        else:
            bits64[0] = u
            v = as64[0]
        if v < v_lo or np.isnan(v):  # (once NaN, it stays)
            v_lo = v
        if v > v_hi or np.isnan(v):
            v_hi = v
    tlo[f], thi[f] = v_lo, v_hi


@njit(inline="always")
def _put(out, at, v, width):
    """The low ``width`` bytes of ``v`` at out[at:], little-endian."""
    for k in range(width):
        out[at + k] = np.uint8((v >> np.uint64(8 * k)) & np.uint64(0xFF))


def pack_records(xyz, rgba, attributes: dict, idx, layout, scale, offset, out: np.ndarray) -> dict:
    """Records of the points ``idx`` of ``xyz``, u32 ``rgba`` and ``attributes`` ({name: values},
    all rows in input order), in that order, into ``out`` (u8, ``record_dtype(layout)``'s size a
    point: a DEFAULT octree.bin's bytes), positions on the grid ``offset`` + ``scale`` steps.
    Returns the written fields' minimum and maximum ({field: [lo list, hi list]}; positions in
    grid steps), as metadata.json states them."""
    rec = record_dtype(layout)
    fields = [(a, t) for a, t, _ in layout if a not in ("position", "rgb")]
    n = len(idx)
    src, stride, width, at, kind = [], [], [], [], []
    for a, t in fields:
        dt = np.dtype(_TYPES[t])
        v = attributes.get(a)
        present = v is not None
        src.append(np.ascontiguousarray(np.asarray(v).astype(dt, copy=False)) if present else np.zeros(1, dt))
        stride.append(dt.itemsize if present else 0)
        width.append(dt.itemsize)
        at.append(rec.fields[a][1])
        kind.append({"u": 0, "i": 1, "f": 2}[dt.kind])
    n_tasks = (n + _RECORDS_A_TASK - 1) // _RECORDS_A_TASK
    has_rgb = "rgb" in rec.names
    n_fields = 3 + len(fields) + 3 * has_rgb
    lo, hi = np.full((n_tasks, n_fields), np.inf), np.full((n_tasks, n_fields), -np.inf)
    if n:
        _pack_records(np.ascontiguousarray(xyz, np.float64), np.ascontiguousarray(rgba, np.uint32), np.ascontiguousarray(idx, np.int64),
                      np.asarray(offset, np.float64), np.asarray(scale, np.float64), rec.fields["position"][1], rec.fields["rgb"][1] if has_rgb else -1,
                      byte_views(src), np.array(stride, np.int64), np.array(width, np.int64), np.array(at, np.int64),
                      np.array(kind, np.int64), rec.itemsize, out, lo, hi)  # fmt: skip
    lo, hi = lo.min(axis=0, initial=np.inf), hi.max(axis=0, initial=-np.inf)
    stats, f = {}, 3
    for a, _, k in layout:
        cols = slice(0, 3) if a == "position" else slice(3 + len(fields), n_fields) if a == "rgb" else slice(f, f + 1)
        f += a not in ("position", "rgb")
        stats[a] = [lo[cols].tolist(), hi[cols].tolist()]
    return stats


def _brotli_node(rec: np.ndarray, layout) -> bytes:
    """A BROTLI node's blob from its points' records (``pack_records``): attribute by attribute,
    points in Morton order, position and rgb as Morton codes."""
    u = rec["position"].astype(np.uint64)
    lower = _spread16(u[:, 0]) | _spread16(u[:, 1]) << np.uint64(1) | _spread16(u[:, 2]) << np.uint64(2)
    upper = (
        _spread16(u[:, 0] >> np.uint64(16))
        | _spread16(u[:, 1] >> np.uint64(16)) << np.uint64(1)
        | _spread16(u[:, 2] >> np.uint64(16)) << np.uint64(2)
    )
    order = np.lexsort((lower, upper))
    parts = []
    for a, _, _ in layout:
        if a == "position":
            pos = np.empty((len(rec), 2), np.uint64)
            pos[:, 0] = upper[order]
            pos[:, 1] = lower[order]
            parts.append(pos.astype("<u8").tobytes())
        elif a == "rgb":
            c = rec["rgb"][order].astype(np.uint64)
            parts.append((_spread16(c[:, 0]) | _spread16(c[:, 1]) << np.uint64(1) | _spread16(c[:, 2]) << np.uint64(2)).astype("<u8").tobytes())
        else:
            parts.append(rec[a][order].tobytes())
    # quality 5, not the default 11: ~47x faster (1.8 M instead of 0.04 M points/s on one core)
    # for a file ~2 % larger, measured on node-sized payloads
    return _brotli().compress(b"".join(parts), quality=BROTLI_QUALITY)


PLACED = "potree.npy"  # a node set whose nodes the build placed in octree.bin: (byte offset, size) a node
PLACED_STATS = "potree_stats.json"  # ... and its fields' minimum and maximum, as written


def potree_plan(st: dict, out=None) -> tuple[list, np.ndarray, np.ndarray]:
    """(write_layout, scale, offset) of the Potree octree a conversion's state makes: rgb only
    for sources with colours (``source_facts``' has_color, as the gigapoint and COPC writers);
    ``out``: the output named where the inputs' scale must coarsen (said by the write phase alone)."""
    scale, offset = output_grid(st, unsigned=True, out=out)
    has_color = bool((st.get("source") or {}).get("has_color", True))
    return write_layout({a: np.dtype(d) for a, d in (st.get("attributes") or {}).items()}, has_color), scale, offset


def place_node_set(out: OctreeDir, at: int, dest: Path, xyz, rgba, attributes: dict, counts, plan, encoding: str, idx=None) -> int:
    """A node set's nodes (``counts`` points each: the points ``idx`` of ``xyz``, u32 ``rgba``
    and ``attributes``, in that order; None: all of them, in order) encoded straight into the
    octree.bin being built (``out.potree_octree_in_progress``) from byte ``at`` on, instead of
    kept in float64 for the write phase to encode and write again (a 20 M-point Potree
    conversion wrote 44 bytes a point twice); their places and statistics into ``dest``
    (PLACED, PLACED_STATS). The records are made from the unsorted inputs in one pass
    (``pack_records``) and copied into the file at once (made in its memory map instead, they
    took longer: every store a fresh file page's). Returns where the next set goes."""
    layout, scale, offset = plan
    idx = np.arange(len(xyz)) if idx is None else idx
    counts = np.asarray(counts, np.int64)
    rec = np.empty(len(idx), record_dtype(layout))
    stats = pack_records(xyz, rgba, attributes, idx, layout, scale, offset, rec.view(np.uint8))
    if encoding == "DEFAULT":  # a point's record is all there is: a node's blob is its points' records
        payload, sizes = [rec], counts * rec.dtype.itemsize
    else:
        ends = np.cumsum(counts)
        payload = [_brotli_node(rec[e - c : e], layout) if c else b"" for c, e in zip(counts.tolist(), ends.tolist())]
        sizes = np.array([len(b) for b in payload], np.int64)
    end = write_at(out.potree_octree_in_progress, at, payload)
    start_writeback(out.potree_octree_in_progress, at, end - at)  # on its way to the disk: the write phase's fsync waits for less
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


def write_potree(out: OctreeDir, sources: list[Path], st: dict, name: str, progress, encoding: str = "DEFAULT") -> int:
    """Assemble built node sets into the Potree 2.0 folder ``out``, its metadata last; returns
    the number of nodes. Node sets the build placed in the octree.bin being built
    (``place_node_set``) are taken as they are; those kept in files (built on Dask workers) are
    placed now, in ``sources`` order, the build's: a single process's bytes."""
    plan = potree_plan(st, out.path)  # the inputs' grid (a LAS file's 0.1 mm was cut to 1 mm), else a fine enough one (grid.py)
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


def _read_type(a: dict) -> np.dtype:
    """The dtype attribute ``a``'s values are read as: its type's, signed where the type is
    unsigned but its stated minimum is negative (PotreeConverter 2.1.1 writes LAS's signed
    scan angle rank as "uint8", with min -18: read as uint8 it was 238)."""
    t = _TYPES.get(a["type"])
    if t is None:
        raise ValueError(f"unknown attribute type {a['type']!r}")
    dt = np.dtype(t)
    if dt.kind == "u" and min(a.get("min") or [0]) < 0:
        dt = np.dtype(dt.str.replace("u", "i"))
    return dt


def _node_dtype(attributes: list[dict]) -> np.dtype:
    fields = []
    for a in attributes:
        t = _read_type(a)
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
            dt = _read_type(a)
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
            # the file's colour range decided once, from rgb's stated maximum, as a LAS file's
            # is (16-bit when over 255): one value at a time, dark 16-bit colours (under 256) came out bright
            self.colors = ColorScaler()
            for a in self.potree_attributes:
                if a["name"] == "rgb" and a.get("max"):
                    self.colors.int_shift(int(max(a["max"])))
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
        # gigapoint attribute name -> (decoded name, element or None, dtype); an attribute of k
        # numbers a point is k attributes name_0 .. (as the LAS reader reads a 3f4 normal; it was left out)
        self.extra = {}
        for a in self.potree_attributes:
            name, k = _gigapoint_name(a["name"]), int(a.get("numElements", 1))
            if a["name"] in ("position", "rgb") or not name:
                continue
            for e in [None] if k == 1 else range(k):
                self.extra[name if e is None else f"{name}_{e}"] = (a["name"], e, _read_type(a))
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
            "source_points": meta.get("points"),  # (PotreeConverter's poisson_average stores more: copies in inner nodes)
            **_class_meta(self.potree_attributes),
        }
        super().__init__(meta.get("name") or p.name, cloud_meta, nodes, keys, {}, {}, p)
        self.node_reads = 0
        self.bytes_read = 0

    def _attribute_dtypes(self) -> dict:
        return {name: dt for name, (_, _, dt) in self.extra.items()}

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
        rgba = np.empty((n, 4), np.uint8)
        rgba[:] = DEFAULT_COLOR  # no rgb (PotreeConverter --attributes intensity): a colourless LAS file's grey, not white
        if "rgb" in d:
            c = d["rgb"]
            rgba[:, :3] = np.minimum(c >> self.colors.int_shift(int(c.max())), 255)  # (no stated maximum: the first node decides)
        color = rgba.view(np.uint32).reshape(-1)
        attrs = {
            name: np.zeros(n, dt) if a not in d else d[a] if e is None else np.ascontiguousarray(d[a][:, e])
            for name, (a, e, dt) in self.extra.items()
        }
        return {"low": low, "med": med, "high": high, "color": color, "rgba": color}, attrs, 0

    @property
    def attribute_names(self) -> list[str]:
        return sorted(self.extra)

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


def _gigapoint_name(name: str) -> str | None:
    """A Potree attribute's name in gigapoint: a LAS field's as the LAS reader names it ('gps-time':
    gps_time), any other (extra bytes) kept, as the LAS reader keeps it ('height above ground'
    was 'height_above_ground' from PotreeConverter's output, and from our own); None: unusable."""
    return _FROM_POTREE.get(name) or safe_attribute_name(name)


def _class_meta(attributes: list[dict]) -> dict:
    """What metadata.json says of the classes held (store.known_classes as ``classes`` or
    ``class_range``): the codes its classification histogram counts (PotreeConverter 2 writes
    one for 1-byte attributes), else its min and max."""
    for a in attributes:
        if a.get("name") == "classification":
            hist, lo, hi = a.get("histogram"), a.get("min"), a.get("max")
            counted = isinstance(hist, list) and len(hist) == 256 and all(isinstance(n, int) for n in hist)
            codes = [c for c, n in enumerate(hist) if n > 0] if counted else None
            one = [v[0] if isinstance(v, list) and len(v) == 1 else None for v in (lo, hi)]
            return known_classes(codes, *one)
    return {}


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
