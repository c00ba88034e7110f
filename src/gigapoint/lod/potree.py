"""Potree 2.0 interop (see ../shared/POTREE2.md): writer (DEFAULT or BROTLI) and reader (both).

Writing: the converter's node sets are streamed into ``octree.bin``; ``hierarchy.bin`` is one
chunk holding every node breadth-first (sorted keys are breadth-first); ``metadata.json``
comes last. Reading: the hierarchy (with proxy chunks) and every node are decoded into
gigapoint's batch layout, so the result renders like any converted octree.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ..core.layout import BATCH_DTYPE
from ..core.quantize import quantize
from ..errors import InputError
from .keys import MAX_LEVEL, key_cube, level_of

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
#: what the writer stores (LAS order): position, intensity, classification, rgb
WRITE_ATTRIBUTES = (("position", "int32", 3), ("intensity", "uint16", 1), ("classification", "uint8", 1), ("rgb", "uint16", 3))


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


def _attribute_entries(scale, offset, stats) -> list[dict]:
    out = []
    for name, typ, n in WRITE_ATTRIBUTES:
        size = np.dtype(_TYPES[typ]).itemsize
        lo, hi = stats[name]
        e = {
            "name": name,
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


def encode_node(
    xyz: np.ndarray, rgb16: np.ndarray, intensity: np.ndarray, classification: np.ndarray, scale, offset, encoding: str
) -> bytes:
    """One node's octree.bin blob."""
    ixyz = np.floor((xyz - np.asarray(offset)) / np.asarray(scale) + 0.5).astype(np.int64)
    ixyz = np.clip(ixyz, 0, 2**31 - 1).astype(np.int32)
    if encoding == "DEFAULT":
        rec = np.empty(len(xyz), np.dtype([(n, _TYPES[t], (k,)) if k > 1 else (n, _TYPES[t]) for n, t, k in WRITE_ATTRIBUTES]))
        rec["position"] = ixyz
        rec["intensity"] = intensity
        rec["classification"] = classification
        rec["rgb"] = rgb16
        return rec.tobytes()
    # BROTLI: attribute by attribute, points in Morton order, position and rgb as Morton codes
    u = ixyz.astype(np.uint64)
    lower = _spread16(u[:, 0]) | _spread16(u[:, 1]) << np.uint64(1) | _spread16(u[:, 2]) << np.uint64(2)
    upper = (
        _spread16(u[:, 0] >> np.uint64(16))
        | _spread16(u[:, 1] >> np.uint64(16)) << np.uint64(1)
        | _spread16(u[:, 2] >> np.uint64(16)) << np.uint64(2)
    )
    order = np.lexsort((lower, upper))
    pos = np.empty((len(xyz), 2), np.uint64)
    pos[:, 0] = upper[order]
    pos[:, 1] = lower[order]
    c = rgb16[order].astype(np.uint64)
    rgbm = _spread16(c[:, 0]) | _spread16(c[:, 1]) << np.uint64(1) | _spread16(c[:, 2]) << np.uint64(2)
    raw = (
        pos.astype("<u8").tobytes()
        + np.asarray(intensity)[order].astype("<u2").tobytes()
        + np.asarray(classification)[order].astype("u1").tobytes()
        + rgbm.astype("<u8").tobytes()
    )
    return _brotli().compress(raw)


def write_potree(out: Path, sources: list[Path], st: dict, name: str, progress, encoding: str = "DEFAULT") -> int:
    """Assemble built node sets into a Potree 2.0 directory; metadata.json last."""
    origin, edge = np.array(st["origin"]), float(st["edge"])
    scale = max(0.001, edge / 2**30)
    scale3 = [scale] * 3
    n_total = 0
    records: dict[int, tuple[int, int, int]] = {}
    stats = {
        "position": [[np.inf] * 3, [-np.inf] * 3],
        "intensity": [[np.inf], [-np.inf]],
        "classification": [[np.inf], [-np.inf]],
        "rgb": [[np.inf] * 3, [-np.inf] * 3],
    }
    tmp_bin = out / "octree.bin.tmp"
    pos = 0
    with open(tmp_bin, "wb") as f:
        for src in sources:
            keys = np.load(src / "keys.npy")
            counts = np.load(src / "counts.npy")
            xyz = np.load(src / "xyz.npy")
            rgba = np.load(src / "rgba.npy").view(np.uint8).reshape(-1, 4)
            n = len(xyz)
            inten = (
                np.load(src / "attr.intensity.npy").astype(np.uint16) if (src / "attr.intensity.npy").exists() else np.zeros(n, np.uint16)
            )
            cls = (
                np.load(src / "attr.classification.npy").astype(np.uint8)
                if (src / "attr.classification.npy").exists()
                else np.zeros(n, np.uint8)
            )
            rgb16 = rgba[:, :3].astype(np.uint16) * np.uint16(257)
            starts = np.concatenate([[0], np.cumsum(counts)])
            for k, key in enumerate(keys.tolist()):
                s, e = int(starts[k]), int(starts[k + 1])
                blob = encode_node(xyz[s:e], rgb16[s:e], inten[s:e], cls[s:e], scale3, origin, encoding) if e > s else b""
                f.write(blob)
                records[key] = (e - s, pos, len(blob))
                pos += len(blob)
            if n:
                ip = np.floor((xyz - origin) / scale + 0.5)
                for nm, arr in (("position", ip), ("intensity", inten[:, None]), ("classification", cls[:, None]), ("rgb", rgb16)):
                    stats[nm][0] = np.minimum(stats[nm][0], arr.min(axis=0)).tolist()
                    stats[nm][1] = np.maximum(stats[nm][1], arr.max(axis=0)).tolist()
            n_total += n
            progress.advance(n)
        f.flush()
        os.fsync(f.fileno())
    keys = np.array(sorted(records), np.uint64)
    key_set = set(records)
    hier = np.zeros(len(keys), HIERARCHY_DTYPE)
    for i, key in enumerate(keys.tolist()):
        mask = sum(1 << c for c in range(8) if (key << 3 | c) in key_set)
        n, off, size = records[key]
        hier[i] = (0 if mask else 1, mask, n, off, size)
    tmp_h = out / "hierarchy.bin.tmp"
    with open(tmp_h, "wb") as f:
        f.write(hier.tobytes())
    os.replace(tmp_bin, out / "octree.bin")
    os.replace(tmp_h, out / "hierarchy.bin")
    stats["position"] = [
        [v * scale + o for v, o in zip(stats["position"][0], origin)],
        [v * scale + o for v, o in zip(stats["position"][1], origin)],
    ]
    meta = {
        "version": "2.0",
        "name": name,
        "description": "",
        "points": int(n_total),
        "projection": "",
        "hierarchy": {"firstChunkSize": int(HIERARCHY_DTYPE.itemsize * len(keys)), "stepSize": 4, "depth": int(level_of(keys).max())},
        "offset": list(map(float, origin)),
        "scale": scale3,
        "spacing": edge / 128.0,
        "boundingBox": {"min": list(map(float, origin)), "max": list(map(float, origin + edge))},
        "encoding": encoding,
        "attributes": _attribute_entries(scale3, list(map(float, origin)), stats),
    }
    tmp = out / "metadata.json.tmp"
    with open(tmp, "w") as f:
        json.dump(meta, f, indent="\t")
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, out / "metadata.json")
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


def read_potree(path) -> OctreeCloud:  # noqa: F821
    """A Potree 2.0 directory (PotreeConverter 2.x or ``gigapoint convert --format potree``) as an OctreeCloud."""
    from .store import OctreeCloud

    p = Path(path)
    try:
        meta = json.loads((p / "metadata.json").read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"{p / 'metadata.json'}: cannot read ({' '.join(str(exc).split())})") from None
    if not str(meta.get("version", "")).startswith("2."):
        raise InputError(f"{p / 'metadata.json'}: Potree version {meta.get('version')!r} is not supported (2.x only)")
    encoding = meta.get("encoding", "DEFAULT")
    if encoding not in ("DEFAULT", "BROTLI"):
        raise InputError(f"{p / 'metadata.json'}: unknown encoding {encoding!r}")
    try:
        attributes = meta["attributes"]
        scale, offset = np.array(meta["scale"], np.float64), np.array(meta["offset"], np.float64)
        bmin, bmax = np.array(meta["boundingBox"]["min"], np.float64), np.array(meta["boundingBox"]["max"], np.float64)
        first = int(meta["hierarchy"]["firstChunkSize"])
        hier = (p / "hierarchy.bin").read_bytes()
        nodes_info: dict[int, tuple[int, int, int]] = {}
        _parse_hierarchy(hier, 0, first, 1, nodes_info)
    except (KeyError, TypeError, ValueError, OSError) as exc:
        raise InputError(f"{p}: invalid Potree hierarchy/metadata ({' '.join(str(exc).split())})") from None
    keys = np.array(sorted(nodes_info), np.uint64)
    counts = np.array([nodes_info[k][0] for k in keys.tolist()], np.int64)
    total = int(counts.sum())
    low, med, high = (np.empty(total, np.uint32) for _ in range(3))
    rgba = np.full((total, 4), 255, np.uint8)
    extra = {
        a["name"]: np.zeros(total, _TYPES[a["type"]])
        for a in attributes
        if a["name"] not in ("position", "rgb") and int(a.get("numElements", 1)) == 1
    }
    nodes = np.zeros(len(keys), BATCH_DTYPE)
    nodes["level"] = level_of(keys)
    pos = 0
    lo_all, hi_all = np.full(3, np.inf), np.full(3, -np.inf)
    with open(p / "octree.bin", "rb") as f:
        for i, key in enumerate(keys.tolist()):
            n, off, size = nodes_info[key]
            nodes[i]["first"] = pos
            nodes[i]["count"] = n
            if n == 0:
                continue
            f.seek(off)
            blob = f.read(size)
            try:
                d = decode_node(blob, n, attributes, encoding)
            except Exception as exc:  # noqa: BLE001 - any decoding failure is a corrupt node
                raise InputError(f"{p / 'octree.bin'}: cannot decode node {_name(key)} ({' '.join(str(exc).split())})") from None
            xyz = d["position"] * scale + offset
            rec = nodes[i : i + 1].copy()
            rec["first"] = 0
            l_, m_, h_ = quantize(xyz, np.arange(n, dtype=np.int64), rec)
            nodes[i]["bbox_min"], nodes[i]["bbox_max"] = rec[0]["bbox_min"], rec[0]["bbox_max"]
            lo_all, hi_all = np.minimum(lo_all, rec[0]["bbox_min"]), np.maximum(hi_all, rec[0]["bbox_max"])
            s = slice(pos, pos + n)
            low[s], med[s], high[s] = l_, m_, h_
            if "rgb" in d:
                c = d["rgb"].astype(np.int64)
                rgba[s, :3] = np.clip(np.where(c > 255, c // 256, c), 0, 255)
            for a, values in extra.items():
                if a in d:
                    values[s] = d[a]
            pos += n
    empty = counts == 0
    if empty.any():
        cmin, cedge = key_cube(keys[empty], bmin, float(np.max(bmax - bmin)))
        nodes["bbox_min"][empty] = cmin
        nodes["bbox_max"][empty] = cmin + cedge[:, None]
    if total == 0:
        lo_all, hi_all = bmin, bmax
    color = rgba.view(np.uint32).reshape(-1)
    arrays = {"low": low, "med": med, "high": high, "color": color, "rgba": color}
    cloud_meta = {
        "format": "potree-2.0",
        "points": total,
        "nodes": len(keys),
        "cube_min": bmin.tolist(),
        "cube_edge": float(np.max(bmax - bmin)),
        "bounds": {"min": lo_all.tolist(), "max": hi_all.tolist()},
        "encoding": encoding,
        "spacing": meta.get("spacing"),
    }
    rename = {"classification": "classification", "intensity": "intensity"}
    attrs = {rename.get(k, k.replace(" ", "_").replace("-", "_")): v for k, v in extra.items()}
    return OctreeCloud(meta.get("name") or p.name, cloud_meta, nodes, keys, arrays, attrs, p)


def _name(key: int) -> str:
    from .keys import key_name

    return key_name(key)
