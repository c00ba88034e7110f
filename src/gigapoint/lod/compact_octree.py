"""The compact octree payload (gigapoint octree format version 2): node points in ~1/2 the bytes.

Positions are core/compact.py's layout, one batch per node: the low word a point
(``low.npy``, at the point's index as in version 1) and the node's extension bits
(``ext.npy``: every node's u64 bit stream back to back, ``pack.npy``: one PACK_DTYPE record
a node, sorted like ``nodes.npy``). A node whose points sit on the source grid (a LAS file's
scale through the cloud's smallest coordinate) gets a grid-aligned box 2^B steps wide
(``nodes.npy``'s bbox) and B - 10 bits an axis; any other node is *wide*: the tight box and
version 1's 30-bit quantization, so its three words are version 1's, bit for bit. Positions
are exact at the source's scale either way (compact.py).

Every other per-point array is a **field**, stored per node as a frame of reference: the
node's smallest value (``base``) and each point's difference from it in as many bits as the
node's range needs (``bits``, 0..64), packed back to back in the field's u64 stream
(``field.<name>.npy``) from word ``word0``. Values are packed as unsigned integers of their
own width (signed ones with the sign bit flipped, floats by their bit patterns), so every
field is lossless; ``fields.npy`` holds one FIELD_DTYPE record per node and field, in the
order of ``octree.json``'s ``fields``. The fields are:

- ``rgba``: the source colours, u32 RGBA8 (an opaque colour's alpha byte is constant: 24 bits
  at most), or u16 RGB565 when converted with ``colors="rgb565"`` (core/compact.py's rounding);
- ``color``: the LOD's filtered colours as the XOR with ``rgba`` (a leaf's are its own: 0
  bits; an inner node's averages: what differs);
- ``attr.<name>``: each attribute in its own dtype.

A node loaded into the arena keeps the compact layout (``node_payload``: its low words and
extension bits as stored, its fields decoded by ``compact.read_ext``; store.Arena), which the
kernels draw as any compact cloud, so a render equals the one of the same boxes in three
words; ``node_arrays`` decodes a node into the three-word layout (``compact.expand_tails``).
Malformed files (a truncated array, a stream shorter than its records say, counts that do
not add up) are a one-line ``InputError`` naming the file when the octree opens; a flipped
byte inside a node's payload, when the node is first loaded: ``crc.npy`` holds a CRC-32 per
node of each of its arrays (``node_checksums``; octrees written without it are not checked).
"""

from __future__ import annotations

import zlib
from collections.abc import Mapping

import numpy as np
from numba import njit, prange

from ..core.compact import (
    _expand_all,
    centre_half,
    compact_positions,
    expand_tails,
    ext_bits_per_point,
    pack_rgb565,
    read_ext,
    rgba32,
    stream_words,
)
from ..core.layout import BATCH_DTYPE, EXT_FULL_BITS, PACK_DTYPE
from ..errors import InputError
from .keys import key_name
from .octree_dir import OctreeDir
from .store import OctreeCloud, known_classes

FIELD_DTYPE = np.dtype([("base", "<u8"), ("word0", "<u8"), ("bits", "<u4"), ("_pad", "<u4")])
LAYOUTS = ("compact", "words")
COLOR_FORMATS = ("rgba", "rgb565")


def field_names(attributes) -> list[str]:
    """The fields of an octree with ``attributes``, in file order."""
    return ["rgba", "color", *(f"attr.{a}" for a in attributes)]


# --------------------------------------------------------------------------- values <-> u64 keys


def to_keys(values: np.ndarray) -> np.ndarray:
    """Unsigned integer keys of the values' own width, lossless: unsigned as they are, signed with
    the sign bit flipped (small magnitudes stay close), floats and bools by their bit patterns
    (views: no copy but for signed values)."""
    v = np.ascontiguousarray(values)
    kind, size = v.dtype.kind, v.dtype.itemsize
    if kind not in "uifb":
        raise InputError(f"a {v.dtype} array cannot be stored in a compact octree")
    u = v.view(f"u{size}")
    return u ^ np.array(1 << (8 * size - 1), u.dtype) if kind == "i" else u


def from_keys(keys: np.ndarray, dtype) -> np.ndarray:
    """Values of ``dtype`` from their keys (``to_keys``), given in any unsigned width."""
    dt = np.dtype(dtype)
    u = keys.astype(f"u{dt.itemsize}")
    if dt.kind == "i":
        u ^= np.array(1 << (8 * dt.itemsize - 1), u.dtype)
    return u.view(dt)


# --------------------------------------------------------------------------- fields: frame of reference + bit packing


@njit(parallel=True, cache=True)
def _field_plan(keys, firsts, counts, base, bits):
    for b in prange(firsts.shape[0]):
        f = firsts[b]
        c = counts[b]
        if c == 0:
            continue
        lo = np.uint64(keys[f])
        hi = lo
        for k in range(f + 1, f + c):
            v = np.uint64(keys[k])
            lo = min(lo, v)
            hi = max(hi, v)
        r = hi - lo
        t = 0
        while r:
            t += 1
            r >>= np.uint64(1)
        base[b] = lo
        bits[b] = t


@njit(parallel=True, cache=True)
def _field_write(keys, firsts, counts, base, bits, word0, out):
    """The points' differences from their node's base into ``out`` (zeroed), t bits each."""
    for b in prange(firsts.shape[0]):
        t = np.uint64(bits[b])
        if t == 0:
            continue
        f = firsts[b]
        w0 = np.uint64(word0[b])
        for k in range(counts[b]):
            v = np.uint64(keys[f + k]) - base[b]
            p = np.uint64(k) * t
            w = w0 + (p >> np.uint64(6))
            s = p & np.uint64(63)
            out[w] |= v << s
            if s + t > 64:
                out[w + np.uint64(1)] |= v >> (np.uint64(64) - s)


@njit(cache=True)
def _field_read(stream, word0, t, base, out):
    """Values of the len(out) points of a node: base + their t bits (compact.read_ext)."""
    mask = np.uint64(0xFFFFFFFFFFFFFFFF) if t >= 64 else (np.uint64(1) << np.uint64(t)) - np.uint64(1)
    for j in range(out.shape[0]):
        out[j] = base + (read_ext(stream, word0, t, j) & mask)


@njit(parallel=True, cache=True)
def _field_read_all(stream, firsts, counts, word0s, bits, bases, out):
    for b in prange(firsts.shape[0]):
        f = firsts[b]
        _field_read(stream, word0s[b], bits[b], bases[b], out[f : f + counts[b]])


@njit(cache=True)
def _node_tails(ext, word0, code, med, high):
    """Medium and high words of a node's points (``expand_tails`` over the whole node, compiled
    once into the cache: a first frame does not wait for it)."""
    n = med.shape[0]
    expand_tails(ext, word0, code, np.int64(0), n, np.int64(1), med, high, np.empty(n, np.uint64))


def pack_field(values: np.ndarray, firsts: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(FIELD_DTYPE per node, u64 stream) of ``values`` cut into nodes (``firsts``/``counts``)."""
    keys = to_keys(values)
    nb = len(firsts)
    firsts = np.asarray(firsts, np.int64)
    counts = np.asarray(counts, np.int64)
    base = np.zeros(nb, np.uint64)
    bits = np.zeros(nb, np.int64)
    _field_plan(keys, firsts, counts, base, bits)
    words = stream_words(bits, counts)
    word0 = np.concatenate([[0], np.cumsum(words)[:-1]]).astype(np.int64) if nb else np.zeros(0, np.int64)
    stream = np.zeros(int(words.sum()), np.uint64)
    _field_write(keys, firsts, counts, base, bits, word0, stream)
    rec = np.zeros(nb, FIELD_DTYPE)
    rec["base"], rec["word0"], rec["bits"] = base, word0, bits
    return rec, stream


def field_words(rec: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """u64 words each node's part of a field stream takes."""
    return stream_words(rec["bits"].astype(np.int64), np.asarray(counts, np.int64))


# --------------------------------------------------------------------------- checksums


def checksum_files(names: list[str]) -> list[str]:
    """The arrays ``crc.npy``'s columns check, in order (``names``: the octree's fields)."""
    return ["low", "ext", *(f"field.{k}" for k in names)]


def node_checksums(index, nodes, low, ext, pack, ext_bits, fields, streams: list) -> np.ndarray:
    """u32 CRC-32 per ``checksum_files`` column of node ``index``: each over the node's record
    (nodes, pack, fields) and its slice of the array, so a flipped byte of either shows."""
    return checksum_table(nodes, low, ext, pack, ext_bits, fields, streams, index, index + 1)[0]


def checksum_table(nodes, low, ext, pack, ext_bits, fields, streams: list, start: int, stop: int) -> np.ndarray:
    """``node_checksums`` of nodes start..stop-1, a row each: the slices' bounds worked out for
    all the nodes at once, so a row is its zlib calls alone (3 650 nodes of a 20 M-point octree:
    0.37 s a node at a time, mostly Python around the CRCs)."""
    count = nodes["count"][start:stop].astype(np.int64)
    low_from = nodes["first"][start:stop].astype(np.int64)
    ext_from = pack["ext_first"][start:stop].astype(np.int64)
    ext_to = ext_from + stream_words(np.asarray(ext_bits[start:stop], np.int64), count)
    recs = np.ascontiguousarray(fields[start:stop])  # (nodes, fields)
    field_from = recs["word0"].astype(np.int64)
    field_to = field_from + stream_words(recs["bits"].astype(np.int64), count[:, None])
    node_bytes, pack_bytes, field_bytes = nodes[start:stop].tobytes(), pack[start:stop].tobytes(), recs.tobytes()
    n_size, p_size, f_size = nodes.dtype.itemsize, pack.dtype.itemsize, fields.dtype.itemsize
    crc = zlib.crc32
    # plain views: slicing a np.memmap runs its Python __getitem__ and __array_finalize__ (4x the
    # CRC of a node's slice; 0.2 s of a 20 M-point conversion's write phase)
    low, ext, streams = np.asarray(low), np.asarray(ext), [np.asarray(s) for s in streams]
    out = np.empty((stop - start, 2 + len(streams)), np.uint32)
    for r, (f0, n, e0, e1) in enumerate(zip(low_from.tolist(), count.tolist(), ext_from.tolist(), ext_to.tolist())):
        out[r, 0] = crc(low[f0 : f0 + n], crc(node_bytes[r * n_size : (r + 1) * n_size]))
        out[r, 1] = crc(ext[e0:e1], crc(pack_bytes[r * p_size : (r + 1) * p_size]))
        for j, stream in enumerate(streams):
            k = r * len(streams) + j  # record (r, j) of the C-ordered field records
            out[r, 2 + j] = crc(stream[field_from[r, j] : field_to[r, j]], crc(field_bytes[k * f_size : (k + 1) * f_size]))
    return out


# --------------------------------------------------------------------------- a node set, encoded


def encode_nodes(xyz, idx, nodes: np.ndarray, scale, origin, colors: tuple[np.ndarray, np.ndarray], data: dict, color_format: str):
    """One node set's payload: the points ``xyz[idx]`` cut into ``nodes`` (BATCH_DTYPE, ``first``
    relative to idx; their boxes are filled), their colours (``colors``: filtered, source RGBA,
    u32 each) and ``data`` ({"attr.<name>": values in idx order}). ``scale`` None: no source
    grid (every node wide). Returns (low, ext, PACK_DTYPE per node, FIELD_DTYPE (nodes, fields),
    {field: stream})."""
    low, ext, pack = compact_positions(xyz, np.ascontiguousarray(idx, np.int64), nodes, scale, origin=origin)
    color, rgba = colors
    if color_format == "rgb565":
        color, rgba = pack_rgb565(color), pack_rgb565(rgba)
    values = {"rgba": rgba, "color": color ^ rgba, **data}
    firsts, counts = nodes["first"].astype(np.int64), nodes["count"].astype(np.int64)
    recs = np.zeros((len(nodes), len(values)), FIELD_DTYPE)
    streams = {}
    for j, (k, v) in enumerate(values.items()):
        recs[:, j], streams[k] = pack_field(v, firsts, counts)
    return low, ext, pack, recs, streams


# --------------------------------------------------------------------------- reading


class _Decoded(Mapping):
    """Whole per-point arrays of a compact octree, decoded on first use and kept (tests, tools,
    ``to_memory``-like uses; the renderer decodes node by node instead)."""

    def __init__(self, cloud: CompactOctree, names: list[str]):
        self._cloud = cloud
        self._names = names
        self._cache: dict = {}

    def __getitem__(self, name):
        if name not in self._names:
            raise KeyError(name)
        if name not in self._cache:
            self._cache[name] = self._cloud.decode_all(name)
        return self._cache[name]

    def __iter__(self):
        return iter(self._names)

    def __len__(self):
        return len(self._names)


class CompactOctree(OctreeCloud):
    """A gigapoint octree of format version 2 (see the module's docstring): an OctreeCloud whose
    arena holds nodes in the compact layout, checked against ``crc.npy`` as they are loaded."""

    def __init__(self, name, meta, nodes, keys, low, ext, pack, fields, streams, path, crc=None):
        self.low, self.ext, self.pack, self.fields, self.streams = low, ext, pack, fields, streams
        self.crc = crc  # crc.npy's rows (None: an octree written without them, not checked)
        self._checked = np.zeros(len(nodes), bool)
        self.field_index = {k: j for j, k in enumerate(meta["fields"])}
        self.color_format = meta.get("colors", "rgba")
        self.ext_bits = ext_bits_per_point(pack, nodes["count"])  # extension bits a point of each node holds
        self._dtypes = {k: np.dtype(d) for k, d in meta["field_dtypes"].items()}
        attrs = list(meta.get("attributes", {}))
        super().__init__(name, meta, nodes, keys, _Decoded(self, ["low", "med", "high", "color", "rgba"]), _Decoded(self, attrs), path)

    def _attribute_dtypes(self) -> dict:
        return {a: self._dtypes[f"attr.{a}"] for a in self.meta.get("attributes", {})}

    def _field(self, name: str, index: int, count: int) -> np.ndarray:
        """Field ``name`` of node ``index``'s ``count`` points, in its dtype."""
        rec = self.fields[index, self.field_index[name]]
        out = np.empty(count, np.uint64)
        _field_read(self.streams[name], np.uint64(rec["word0"]), np.uint64(rec["bits"]), np.uint64(rec["base"]), out)
        return from_keys(out, self._dtypes[name])

    def arena_layout(self) -> dict:
        """The arena holds nodes as stored (``node_payload``): low words, each slot's room for
        the extension bits of the octree's widest node, colours in the octree's format, integer
        attributes in their range over the octree (``attribute_ranges``)."""
        ext_bits = int(self.ext_bits.max()) if len(self.ext_bits) else 0
        return {"ext_bits": ext_bits, "color_dtype": self._dtypes["rgba"], "attribute_ranges": self.attribute_ranges()}

    def metadata_class_facts(self) -> dict:
        """Its classification's range over the octree (``attribute_ranges``: the lowest class
        held, and a bound of the highest)."""
        return known_classes(None, *self.attribute_ranges().get("classification", (None, None)))

    def attribute_ranges(self) -> dict[str, tuple[int, int]]:
        """(min, max) bounds of each integer attribute over all nodes, from the fields' records
        alone (a node's keys lie in base .. base + 2^bits - 1; keys order as the values do)."""
        out = {}
        used = self.counts > 0
        for a in self.meta.get("attributes", {}):
            dt = self._dtypes[f"attr.{a}"]
            if dt.kind not in "iu" or not used.any():
                continue
            rec = self.fields[used, self.field_index[f"attr.{a}"]]
            key_max = np.uint64((1 << (8 * dt.itemsize)) - 1)
            base, bits = rec["base"].astype(np.uint64), rec["bits"].astype(np.uint64)
            span = np.where(bits >= 64, key_max, (np.uint64(1) << np.minimum(bits, np.uint64(63))) - np.uint64(1))
            top = base + np.minimum(span, key_max - np.minimum(base, key_max))  # never past the dtype's largest key
            lo, hi = from_keys(np.array([base.min(), top.max()], np.uint64), dt).tolist()
            out[a] = (int(lo), int(hi))
        return out

    def check_node(self, index: int) -> None:
        """A one-line InputError naming the file and the node when node ``index``'s payload
        does not match its checksums (once a node: a node loaded again is not read twice)."""
        if self.crc is None or self._checked[index]:
            return
        streams = [self.streams[k] for k in self.meta["fields"]]
        got = node_checksums(index, self.nodes, self.low, self.ext, self.pack, self.ext_bits, self.fields, streams)
        bad = np.flatnonzero(got != self.crc[index])
        if len(bad):
            name = checksum_files(self.meta["fields"])[int(bad[0])]
            where = self.path / f"{name}.npy" if self.path is not None else name
            raise InputError(f"{where}: node {key_name(int(self.keys[index]))} (#{index}) does not match its checksum in crc.npy: the file is damaged")
        self._checked[index] = True

    def node_payload(self, index: int) -> tuple[dict, dict]:
        """Node ``index`` in the compact layout: ({"low", "ext": its stream's u64 words (from
        word 0), "code", "bits": a point's in the stream, "color", "rgba": colours in the
        octree's format}, attributes)."""
        self.check_node(index)
        rec = self.nodes[index]
        first, count = int(rec["first"]), int(rec["count"])
        p = self.pack[index]
        w0, words = int(p["ext_first"]), int(stream_words(self.ext_bits[index], count))
        rgba = self._field("rgba", index, count)
        payload = {
            "low": np.asarray(self.low[first : first + count]),
            "ext": self.ext[w0 : w0 + words],
            "code": np.uint32(p["code"]),
            "bits": int(self.ext_bits[index]),
            "color": rgba ^ self._field("color", index, count),
            "rgba": rgba,
        }
        return payload, {a: self._field(f"attr.{a}", index, count) for a in self.meta.get("attributes", {})}

    def node_half(self, index: int) -> np.ndarray:
        """0 on a grid-aligned node's axes (its words hold its points' grid values, core/compact.py), 0.5 on a wide one's."""
        return centre_half(self.pack["code"][index])

    def node_arrays(self, index: int) -> tuple[dict, dict, int]:
        """Node ``index`` decoded: (low, med, high, color, rgba in the three-word layout; its
        attributes; 0, where its points start in them)."""
        payload, attrs = self.node_payload(index)
        med, high = self.payload_tails(payload)
        arrays = {"low": payload["low"], "med": med, "high": high, "color": rgba32(payload["color"]), "rgba": rgba32(payload["rgba"])}
        return arrays, attrs, 0

    def payload_tails(self, payload: dict) -> tuple[np.ndarray, np.ndarray]:
        """(med, high): the three-word layout's other words of a ``node_payload``'s points."""
        count = len(payload["low"])
        med = np.empty(count, np.uint32)
        high = np.empty(count, np.uint32)
        _node_tails(payload["ext"], np.int64(0), payload["code"], med, high)
        return med, high

    def decode_all(self, name: str) -> np.ndarray:
        """Array ``name`` (low, med, high, color, rgba or an attribute) of every point."""
        n = self.n_points
        firsts, counts = self.nodes["first"].astype(np.int64), self.counts
        for i in range(len(self.nodes)):
            self.check_node(i)
        if name == "low":
            return np.asarray(self.low)
        if name in ("med", "high"):
            med, high = np.zeros(n, np.uint32), np.zeros(n, np.uint32)
            _expand_all(self.ext, firsts, counts, self.pack["ext_first"].astype(np.int64), self.pack["code"].astype(np.uint32), med, high)
            return med if name == "med" else high

        def field(k):
            rec = self.fields[:, self.field_index[k]]
            out = np.zeros(n, np.uint64)
            _field_read_all(self.streams[k], firsts, counts, rec["word0"].copy(), rec["bits"].astype(np.uint64), rec["base"].copy(), out)
            return from_keys(out, self._dtypes[k])

        if name in ("color", "rgba"):
            rgba = field("rgba")
            return rgba32(rgba if name == "rgba" else rgba ^ field("color"))
        return field(f"attr.{name}")


def read_compact(d: OctreeDir, meta: dict) -> CompactOctree:
    """A version 2 octree folder opened (``reader.open_octree`` dispatches here and reads its class counts): its arrays
    memory-mapped and checked against each other, so a damaged file is an error naming it now,
    not a crash or garbage when its node is drawn."""
    p = d.path
    n = int(meta["points"])
    names, dtypes = meta.get("fields"), meta.get("field_dtypes")
    if not isinstance(names, list) or not isinstance(dtypes, dict) or names != field_names(meta.get("attributes", {})) or set(names) - set(dtypes):
        raise InputError(f"{d.meta}: its fields do not match its attributes")
    for k, v in dtypes.items():  # a damaged one was numpy's TypeError ("data type 'u0' not understood")
        try:
            dt = np.dtype(v)
        except (TypeError, ValueError):
            dt = None
        if dt is None or dt.kind not in ("u" if k in ("rgba", "color") else "biuf") or dt.shape:  # (colours: unsigned words)
            raise InputError(f"{d.meta}: field {k!r} has dtype {v!r}, not {'an unsigned integer' if k in ('rgba', 'color') else 'a number'} type")
    nodes, keys, pack, fields = (d.load(k, mmap=False) for k in ("nodes", "keys", "pack", "fields"))
    if nodes.dtype != BATCH_DTYPE or keys.ndim != 1 or len(nodes) != len(keys):
        raise InputError(f"{d.array('nodes')}: does not match {d.array('keys').name} ({len(nodes):,} and {len(keys):,} nodes)")
    if pack.dtype != PACK_DTYPE or len(pack) != len(nodes):
        raise InputError(f"{d.array('pack')}: holds {len(pack):,} records for {len(nodes):,} nodes")
    if fields.dtype != FIELD_DTYPE or fields.shape != (len(nodes), len(names)):
        raise InputError(f"{d.array('fields')}: holds {fields.shape} records for {len(nodes):,} nodes and {len(names)} fields")
    counts = nodes["count"].astype(np.int64)
    ends = nodes["first"].astype(np.int64) + counts
    if int(counts.sum()) != n or (len(ends) and int(ends.max()) > n):
        raise InputError(f"{d.array('nodes')}: its nodes hold {int(counts.sum()):,} points, {d.meta.name} says {n:,}")
    low = d.load("low")
    if low.dtype != np.uint32 or low.shape != (n,):
        raise InputError(f"{d.array('low')}: holds {low.shape[0] if low.ndim else 0:,} points, {d.meta.name} says {n:,}")
    ext = d.load("ext")
    code = pack["code"].astype(np.int64)
    widths = np.stack([(code >> s) & 0xFF for s in (0, 8, 16)], axis=1)
    if np.any(widths > EXT_FULL_BITS):
        raise InputError(f"{d.array('pack')}: a node's layout code is invalid")
    need = pack["ext_first"].astype(np.int64) + stream_words(widths.sum(axis=1), counts)
    if ext.dtype != np.uint64 or (len(need) and int(need.max()) > len(ext)):
        raise InputError(f"{d.array('ext')}: the bit stream is shorter ({len(ext):,} words) than its nodes need ({int(need.max()):,})")
    streams = {}
    for j, k in enumerate(names):
        s = d.load(f"field.{k}")
        rec = fields[:, j]
        need = rec["word0"].astype(np.int64) + field_words(rec, counts)
        if s.dtype != np.uint64 or np.any(rec["bits"] > 64) or (len(need) and int(need.max()) > len(s)):
            raise InputError(f"{d.array(f'field.{k}')}: the bit stream is shorter ({len(s):,} words) than its nodes need")
        streams[k] = np.asarray(s)
    crc = None
    if d.array("crc").exists():  # octrees written before checksums have none: not checked
        crc = d.load("crc", mmap=False)
        if crc.dtype != np.uint32 or crc.shape != (len(nodes), len(names) + 2):
            raise InputError(f"{d.array('crc')}: holds {crc.shape} checksums for {len(nodes):,} nodes and {len(names) + 2} arrays")
    return CompactOctree(meta.get("name", p.name), meta, nodes, keys, low, np.asarray(ext), pack, fields, streams, p, crc)


__all__ = [
    "COLOR_FORMATS",
    "FIELD_DTYPE",
    "LAYOUTS",
    "CompactOctree",
    "checksum_files",
    "checksum_table",
    "encode_nodes",
    "field_names",
    "from_keys",
    "node_checksums",
    "pack_field",
    "read_compact",
    "to_keys",
]
