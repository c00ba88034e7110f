"""The gigapoint octree writer: built node sets assembled into an octree folder (layout:
octree_dir.py), its metadata file last."""

from __future__ import annotations

import io
import itertools
import json
import os
from pathlib import Path

import numpy as np

from ..atomic import atomic_json, atomic_npy, fsync_file, mapped_npy, start_writeback, write_at
from ..core.compact import ext_bits_per_point
from ..core.layout import BATCH_DTYPE
from ..core.quantize import quantize
from .class_counts import join_class_counts
from .compact_octree import checksum_table, field_names
from .keys import key_cube, level_of
from .octree_dir import CLASSES, FORMAT_NAME, FORMAT_VERSION, FORMAT_VERSION_WORDS, POINT_ARRAYS, OctreeDir


def point_dtypes(attributes: dict, compact: bool = False) -> dict[str, np.dtype]:
    """The octree's per-point arrays and their dtypes: POINT_ARRAYS (u32 each) and
    ``attr.<name>`` of every attribute in ``attributes`` ({name: dtype}); ``compact`` (version 2):
    only the low words (the rest is in per-node streams, compact_octree.py)."""
    if compact:
        return {"low": np.dtype(np.uint32)}
    dtypes = {k: np.dtype(np.uint32) for k in POINT_ARRAYS}
    dtypes.update({f"attr.{a}": np.dtype(d) for a, d in attributes.items()})
    return dtypes


CRC_PARTS = 4  # version 2's checksums: computed in this many calls (ranges of nodes, ~equal points)


def run_serially(fn, calls: list) -> list:
    """``[fn(*args) for args in calls]``: how write_gigapoint runs its independent steps unless
    told otherwise (the Dask converter runs them as tasks, lod/convert/distributed.py)."""
    return [fn(*args) for args in calls]


def write_gigapoint(out: OctreeDir, sources: list[Path], st: dict, name: str, sampler: str, max_leaf: int, progress, run=run_serially) -> int:
    """Assemble built node sets into the octree folder ``out``; returns the number of nodes.

    A node set is a dir with keys.npy and either nodes.npy + span.npy (its points already written
    into ``out.array_in_progress(<array>)`` by the converter: only the node records are gathered
    here) or counts/xyz/color/rgba/attr.* (quantized and copied here). ``run(fn, calls)``: runs
    independent steps (version 2's stream joins and checksums), like run_serially.
    """
    attrs = st["attributes"]
    origin, edge = np.array(st["origin"]), float(st["edge"])
    plan = st.get("compact")
    dtypes = point_dtypes(attrs, compact=plan is not None)
    tmp_paths = {k: out.array_in_progress(k) for k in dtypes}
    direct = all((src / "span.npy").exists() for src in sources)
    if plan is not None and not direct:
        raise RuntimeError("internal error: a compact octree's node sets are written in place")
    if direct:
        total = int(st["points"])
        if sum(int(np.diff(np.load(src / "span.npy"))[0]) for src in sources) != total:
            raise RuntimeError("internal error: built node sets do not cover every point once")
        outs = {}
    else:
        total = sum(int(np.load(src / "xyz.npy", mmap_mode="r").shape[0]) for src in sources)
        outs = {k: mapped_npy(tmp_paths[k], dtypes[k], (total,)) for k in dtypes}
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
        if p.exists() or not out.array(k).exists():  # a write phase resumed after its renames
            os.replace(p, out.array(k))  # filled over several phases, renamed only once complete
    keys = np.concatenate(all_keys)
    nodes = np.concatenate(all_nodes)
    order = np.argsort(keys, kind="stable")
    if len(np.unique(keys)) != len(keys):
        raise RuntimeError("internal error: duplicate octree node keys")
    extra = {}
    if plan is not None:
        extra = write_streams(out, sources, order, attrs, plan, run)
    atomic_npy(out.array("nodes"), nodes[order])
    atomic_npy(out.array("keys"), keys[order])
    classes = join_class_counts(sources, [len(k) for k in all_keys], order)
    if classes is not None:  # (no file: an octree without classification, read as before)
        atomic_npy(out.array(CLASSES), classes)
    if plan is not None:
        atomic_npy(out.array("crc"), write_checksums(out, nodes[order], extra["fields"], run))
    lo, hi = np.array(st["lo"]), np.array(st["hi"])
    meta = {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION if plan is not None else FORMAT_VERSION_WORDS,
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
        "crs": (st.get("source") or {}).get("crs"),  # 'EPSG:n' or WKT from the LAS/COPC inputs (info shows it)
        "has_color": bool((st.get("source") or {}).get("has_color", True)),  # false: the colours stored are the grey of points without
    }
    meta.update(extra)
    atomic_json(out.meta, meta, durable=True)  # last: the folder is complete from here on
    return len(keys)


def write_checksums(out: OctreeDir, nodes: np.ndarray, names: list[str], run=run_serially) -> np.ndarray:
    """Version 2's ``crc.npy``: per node a CRC-32 of each array's part of it, its record
    included (compact_octree.node_checksums), from the files as written; in CRC_PARTS ranges of
    nodes holding about as many points each (``run``)."""
    ends = np.cumsum(nodes["count"], dtype=np.int64)
    cuts = [0, *np.searchsorted(ends, np.linspace(0, ends[-1] if len(ends) else 0, CRC_PARTS + 1)[1:-1]).tolist(), len(nodes)]
    ranges = [(a, b) for a, b in itertools.pairwise(cuts) if b > a]
    parts = run(checksum_rows, [(str(out.path), nodes[a:b], names, a) for a, b in ranges])
    return np.concatenate(parts) if parts else np.empty((0, 2 + len(names)), np.uint32)


def checksum_rows(out_path: str, nodes: np.ndarray, names: list[str], first: int) -> np.ndarray:
    """write_checksums' rows of ``nodes``, the octree's nodes ``first``.. (in key order)."""
    out = OctreeDir(out_path)
    low, ext, pack, fields = (np.load(out.array(k), mmap_mode="r") for k in ("low", "ext", "pack", "fields"))
    pack, fields = np.asarray(pack[first : first + len(nodes)]), np.asarray(fields[first : first + len(nodes)])
    streams = [np.load(out.array(f"field.{k}"), mmap_mode="r") for k in names]
    bits = ext_bits_per_point(pack, nodes["count"])
    return checksum_table(nodes, low, ext, pack, bits, fields, streams, 0, len(nodes))


STREAM_HEADER = 128  # bytes of a stream's .npy header, whatever its length (numpy pads it for the shape to grow in place)
WORDS = "words.json"  # a node set's streams appended in place: {stream: [first word, end]}


def _npy_header(words: int) -> bytes:
    f = io.BytesIO()
    np.lib.format.write_array_header_1_0(f, {"descr": "<u8", "fortran_order": False, "shape": (words,)})
    if len(f.getvalue()) != STREAM_HEADER:
        raise RuntimeError(f"internal error: numpy wrote a stream header of {len(f.getvalue())} bytes, not {STREAM_HEADER}")
    return f.getvalue()


def append_streams(out: OctreeDir, dest: Path, streams: dict, next_words: dict) -> None:
    """A node set's bit streams ({name: uint64 words}) written where the build has got to in
    each stream (``next_words``, moved on) of ``out.stream_in_progress``, rather than into its
    own files that the write phase would copy again (20 M points: 0.7 s less); the words'
    places go to ``dest/words.json``. A killed run's set written part-way is written again at
    the same place: ``next_words`` comes from the sets finished (``streams_end``)."""
    places = {}
    for k, words in streams.items():
        path = out.stream_in_progress(k)
        first = next_words.get(k, 0)
        if first == 0:  # the real length is written by finish_stream
            write_at(path, 0, [_npy_header(0)])
        # through a memory map, not write(): 4x faster here (160 MB in 17 sets: 0.14 against
        # 0.57-0.68 s); a killed run's words past the end go
        write_at(path, STREAM_HEADER + 8 * first, [np.asarray(words, np.uint64)])
        start_writeback(path, STREAM_HEADER + 8 * first, 8 * len(words))  # (finish_stream's fsync waits for less)
        places[k] = [first, first + len(words)]
        next_words[k] = first + len(words)
    atomic_json(dest / WORDS, places)


def streams_end(sets) -> dict:
    """Where the next node set's streams go: after the words of the finished ``sets``."""
    ends: dict = {}
    for src in sets:
        if (src / WORDS).exists():
            for k, (_first, end) in json.loads((src / WORDS).read_text()).items():
                ends[k] = max(ends.get(k, 0), end)
    return ends


def _stream_bases(by_points: list[Path], k: str) -> tuple[list[int], int]:
    """Where each set's stream ``k`` starts in the joined stream, and the joined stream's words."""
    bases, total = [], 0
    for src in by_points:
        bases.append(total)
        total += int(np.load(src / f"{k}.npy", mmap_mode="r").shape[0])
    return bases, total


def join_stream(out_path: str, k: str, by_points: list[str]) -> None:
    """Stream ``k`` of the node sets ``by_points`` (in the order of their points) joined into the
    octree's array ``k``, written under its in-progress name and renamed."""
    out, sets = OctreeDir(out_path), [Path(p) for p in by_points]
    bases, total = _stream_bases(sets, k)
    dest = out.array_in_progress(k)
    joined = mapped_npy(dest, np.uint64, (total,))
    for src, b in zip(sets, bases):
        part = np.load(src / f"{k}.npy", mmap_mode="r")
        joined[b : b + len(part)] = part
    joined.flush()
    del joined
    fsync_file(dest)
    os.replace(dest, out.array(k))


def finish_stream(out_path: str, k: str, words: int) -> None:
    """Stream ``k`` written in place (``append_streams``) made the octree's array ``k``: its
    header says its length, anything past it (a killed run's set written part-way) is cut off.
    Moved already (a write phase resumed): nothing to do."""
    out = OctreeDir(out_path)
    path = out.stream_in_progress(k)
    if not path.exists() and out.array(k).exists():
        return
    with open(path, "r+b" if path.exists() else "w+b") as f:
        f.write(_npy_header(words))
        f.truncate(STREAM_HEADER + 8 * words)
    fsync_file(path)
    os.replace(path, out.array(k))


def write_streams(out: OctreeDir, sources: list[Path], order: np.ndarray, attrs: dict, plan: dict, run=run_serially) -> dict:
    """Version 2: the node sets' bit streams (ext, field.<name>) joined in the order of their
    points (span.npy), so the single-process and the Dask converter write the same bytes, a
    stream a call (``run``), and their per-node records (pack, fields; concatenated in
    ``sources`` order like the node records, then put in key order by ``order``) pointing into
    them. Returns what octree.json says about them."""
    names = field_names(attrs)
    streams = ["ext", *(f"field.{k}" for k in names)]
    by_points = sorted(sources, key=lambda s: int(np.load(s / "span.npy")[0]))
    base = {}  # (set, stream) -> its first word in the joined stream
    in_place = [(s / WORDS).exists() for s in by_points]
    if all(in_place):  # the words stay where the build wrote them
        places = {s: json.loads((s / WORDS).read_text()) for s in by_points}
        for k in streams:
            for src in by_points:
                base[src, k] = places[src][k][0]
        run(finish_stream, [(str(out.path), k, max((p[k][1] for p in places.values()), default=0)) for k in streams])
    elif any(in_place):  # (a Dask run starts over rather than resume a single-process run's state)
        raise RuntimeError("internal error: node sets with their streams in place and in their own files")
    else:  # each set's streams in its own files (built on Dask workers): joined here
        for k in streams:
            for src, b in zip(by_points, _stream_bases(by_points, k)[0]):
                base[src, k] = b
        run(join_stream, [(str(out.path), k, [str(s) for s in by_points]) for k in streams])
    packs, fields = [], []
    for src in sources:
        pack, rec = np.load(src / "pack.npy"), np.load(src / "fields.npy")
        pack["ext_first"] += np.uint64(base[src, "ext"])
        for j, k in enumerate(names):
            rec[:, j]["word0"] += np.uint64(base[src, f"field.{k}"])
        packs.append(pack)
        fields.append(rec)
    atomic_npy(out.array("pack"), np.concatenate(packs)[order])
    atomic_npy(out.array("fields"), np.concatenate(fields)[order])
    dtypes = {"rgba": "<u2" if plan["colors"] == "rgb565" else "<u4", **{f"attr.{a}": np.dtype(d).str for a, d in attrs.items()}}
    dtypes["color"] = dtypes["rgba"]
    return {"layout": "compact", "colors": plan["colors"], "scale": plan["scale"], "fields": names, "field_dtypes": dtypes}
