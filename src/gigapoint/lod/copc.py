"""COPC (Cloud Optimized Point Cloud, copc.io): a LAS 1.4 / LAZ file that is an octree, read as
one (CopcCloud) from a local file or over HTTP; its binary layouts, shared with the writer
(copc_write.py).

A COPC file: the LAS 1.4 header (375 bytes), the COPC info VLR first (user ``copc``, record 1:
the octree's cube as centre and half size, spacing, the root hierarchy page's offset and size),
the LASzip VLR (variable-size chunks), a WKT CRS VLR, point data in point format 6, 7 or 8 as
one LAZ chunk per octree node, the LAZ chunk table, and the hierarchy EVLR (user ``copc``,
record 1000): pages of 32-byte entries (VoxelKey, offset, byte size, point count; count -1: the
node's entry and subtree are in the child page at offset). Opening reads the header and VLRs
(one request), then the root hierarchy page; pages below and node chunks are read when a frame
draws them (voxel_octree.py), a chunk decoded with lazrs into the layouts below. A file cut off
(shorter than its header and hierarchy EVLR say) gives the nodes and pages before the cut, with
one warning; cut before its root page (the hierarchy comes last), it is a one-line error (a local
one whose points are whole is read as plain LAZ instead: ``copc_file_kind``).
"""

from __future__ import annotations

import io

import numpy as np

from ..core.chunk import safe_attribute_name
from ..errors import EmptyCloudError, GigapointWarning, InputError, warn
from ..io import laz_process
from ..io._base import ATTRIBUTE_DTYPES
from ..io.http import ByteSource, LocalFile, last_name, open_source
from ..io.las import EVLR_HEADER, PROJECTION_USER_ID, WKT_RECORD, evlr_headers, read_las_header, truncated_header, wkt_of
from ..io.las_fields import EXTRA_BYTES_TYPES, FLAG_BITS, field_attributes
from ..io.las_kernels import _scaled_xyz
from .kinds import (
    COPC_INFO_DTYPE,
    INFO_OFFSET,
    LAS14_HEADER_DTYPE,
    VLR_HEADER_DTYPE,
    copc_file_kind,
    is_copc_head,
    potree_part,
)
from .store import check_grid, tight_bounds
from .voxel_octree import VOXEL_KEY_DTYPE, VoxelOctree, valid_voxels, voxel_name, voxel_to_key

# --------------------------------------------------------------------------- layouts

EVLR_HEADER_DTYPE = np.dtype(
    [("reserved", "<u2"), ("user_id", "S16"), ("record_id", "<u2"), ("record_length", "<u8"), ("description", "S32")]
)
#: One hierarchy entry (32 bytes).
HIERARCHY_ENTRY_DTYPE = np.dtype([("key", VOXEL_KEY_DTYPE), ("offset", "<u8"), ("byte_size", "<i4"), ("point_count", "<i4")])
#: LAS point data record formats 6, 7 and 8 (``point_dtype`` adds extra bytes).
_PDRF6 = [
    ("X", "<i4"),
    ("Y", "<i4"),
    ("Z", "<i4"),
    ("intensity", "<u2"),
    ("returns", "u1"),  # return number (bits 0-3), number of returns (bits 4-7)
    ("flags", "u1"),  # classification flags, scanner channel, scan direction, edge of flight line
    ("classification", "u1"),
    ("user_data", "u1"),
    ("scan_angle", "<i2"),
    ("point_source_id", "<u2"),
    ("gps_time", "<f8"),
]
POINT_DTYPES = {
    6: np.dtype(_PDRF6),
    7: np.dtype([*_PDRF6, ("red", "<u2"), ("green", "<u2"), ("blue", "<u2")]),
    8: np.dtype([*_PDRF6, ("red", "<u2"), ("green", "<u2"), ("blue", "<u2"), ("nir", "<u2")]),
}

COPC_HIERARCHY_RECORD = 1000
LASZIP_USER_ID = b"laszip encoded"
LASZIP_RECORD = 22204
EXTRA_BYTES_USER_ID = b"LASF_Spec"
EXTRA_BYTES_RECORD = 4
#: One Extra Bytes descriptor (LAS 1.4 R15 section 2.5.4: 192 bytes), naming bytes that follow
#: a point record's standard fields; the writer stores attributes point format 6/7/8 has no
#: field for there.
EXTRA_BYTES_DTYPE = np.dtype(
    [
        ("reserved", "<u2"),
        ("data_type", "u1"),  # 1-10: the scalars of EXTRA_BYTES_TYPES, 11-30 arrays of them; 0: ``options`` untyped bytes
        ("options", "u1"),  # bit 0 no_data, 1 min, 2 max, 3 scale, 4 offset are set
        ("name", "S32"),
        ("unused", "V4"),
        ("no_data", "V24"),
        ("min", "V24"),
        ("max", "V24"),
        ("scale", "<f8", (3,)),
        ("offset", "<f8", (3,)),
        ("description", "S32"),
    ]
)
HEAD_READ = 64 << 10  # the first request reads this much (the header and VLRs, usually)
EVLR_READ = 1 << 20  # the most EVLR bytes read at open over HTTP for a CRS in them, in one request (CopcCloud._evlr_wkt)
EVLR_WALK = 4  # past it, the most EVLR headers read over HTTP (a request each) to find the CRS's


def point_dtype(point_format: int, record_length: int, extra: list[ExtraField] | None = None) -> np.dtype:
    """The record layout of point format 6/7/8 with ``record_length - base`` extra bytes: the
    ``extra`` fields (extra_fields) first, any bytes they do not describe as ``extra_bytes``.
    The values of an array (``element`` 0 .. k-1, in order) are one field of k values."""
    base = POINT_DTYPES[point_format]
    layout = {}
    for f in extra or []:  # (an array's last value sets its length)
        layout[f.name] = f.dtype if f.element is None else np.dtype((f.dtype, (f.element + 1,)))
    fields = list(layout.items())
    named = sum(dt.itemsize for _, dt in fields)
    rest = record_length - base.itemsize - named
    if rest < 0:
        what = f" and {named} extra bytes" if named else ""
        raise ValueError(
            f"point record length {record_length} is smaller than point format {point_format}{what} need ({base.itemsize + named})"
        )
    return np.dtype([*base.descr, *fields, *([("extra_bytes", f"V{rest}")] if rest else [])])


class ExtraField:
    """One attribute stored in a point's extra bytes: ``name``, its stored ``dtype``, and the
    ``scale``/``offset`` its descriptor applies (value = stored * scale + offset), or None.
    ``element``: the place of its value in field ``name`` of several values a point (a LAS
    extra-bytes array, as a COPC file or an EPT node may hold: ``dtype`` is then one value's), or
    None."""

    def __init__(self, name: str, dtype, scale: float | None = None, offset: float | None = None, element: int | None = None):
        self.name, self.dtype, self.scale, self.offset, self.element = name, np.dtype(dtype), scale, offset, element

    @property
    def attribute(self) -> str:
        """The attribute it is read as: ``name``, or ``name_<element>`` for a value of an array
        (the LAS reader's names: io/las.py ``_attribute_fields``)."""
        return self.name if self.element is None else f"{self.name}_{self.element}"

    @property
    def scaling(self) -> tuple[float, float] | None:
        """(scale, offset) its values are (a missing one 1 or 0), or None where stored as they are."""
        if self.scale is None and self.offset is None:
            return None
        return (1.0 if self.scale is None else self.scale, 0.0 if self.offset is None else self.offset)

    @property
    def value_dtype(self) -> np.dtype:
        """The attribute's dtype once decoded: float64 where a scale or offset applies."""
        return self.dtype if self.scaling is None else np.dtype(np.float64)

    def values(self, rec: np.ndarray) -> np.ndarray:
        """The field of point records ``rec`` as values: stored * scale + offset where scaled."""
        v = rec[self.name] if self.element is None else np.ascontiguousarray(rec[self.name][:, self.element])
        if self.scaling is None:
            return v
        scale, offset = self.scaling
        return v.astype(np.float64) * scale + offset  # (float32 * a Python float stays float32 in NumPy 2)


def extra_fields(vlrs, point_format: int = 8) -> list[ExtraField]:
    """The named, typed fields of a LAS 1.4 file's Extra Bytes VLR (LASF_Spec 4), in record order.
    An array of k values a point (data types 11-30: ``normal``, 3 x float64) is k fields
    (``element`` 0 .. k-1), each scaled by its own scale and offset, as laspy reads it. Untyped
    bytes, and fields whose name is empty, repeated or a standard attribute's, become
    ``_extra<i>`` fields that only hold their place."""
    for user, rec, data in vlrs:
        if user != EXTRA_BYTES_USER_ID or rec != EXTRA_BYTES_RECORD:
            continue
        if len(data) % EXTRA_BYTES_DTYPE.itemsize:
            raise ValueError(f"its Extra Bytes VLR holds {len(data)} bytes, not whole {EXTRA_BYTES_DTYPE.itemsize}-byte descriptors")
        out, seen = [], set()
        for i, d in enumerate(np.frombuffer(data, EXTRA_BYTES_DTYPE)):
            kind, opts = int(d["data_type"]), int(d["options"])
            name = safe_attribute_name(bytes(d["name"]).split(b"\0")[0].decode("ascii", "replace").strip()) or ""  # 'a/b' as 'a_b'
            if kind == 0:
                out.append(ExtraField(f"_extra{i}", f"V{max(opts, 1)}"))
                continue
            if not 1 <= kind <= 30:
                raise ValueError(f"its extra bytes field {name!r} has data type {kind}, which LAS 1.4 does not define (1-30)")
            # 11-20: two values a point, 21-30: three, of the scalar type 1-10 of the same last
            # digit (LAS 1.4 R13; R15 deprecates them, laspy still writes them and PDAL reads them)
            scalar, count = EXTRA_BYTES_TYPES[(kind - 1) % 10 + 1], (kind - 1) // 10 + 1
            names = [name] if count == 1 else [name, *(f"{name}_{k}" for k in range(count))]
            if not name or seen.intersection(names) or field_attributes(point_format).intersection(names):
                out.append(ExtraField(f"_extra{i}", scalar if count == 1 else np.dtype((scalar, (count,)))))
                continue
            seen.update(names)
            for k in range(count):
                scale = float(d["scale"][k]) if opts & 8 else None
                offset = float(d["offset"][k]) if opts & 16 else None
                out.append(ExtraField(name, scalar, scale, offset, element=None if count == 1 else k))
        return out
    return []


def read_vlrs(data: bytes, start: int, count: int, end: int, header=VLR_HEADER_DTYPE) -> list[tuple[bytes, int, bytes]]:
    """(user id, record id, data) of ``count`` VLRs from byte ``start`` of ``data`` (ending by
    ``end``); EVLRs with ``header=EVLR_HEADER_DTYPE``."""
    out, pos = [], start
    for i in range(count):
        if pos + header.itemsize > end:
            raise ValueError(f"VLR {i + 1} of {count} runs into the point data")
        h = np.frombuffer(data, header, count=1, offset=pos)[0]
        n = int(h["record_length"])
        pos += header.itemsize
        if pos + n > end:
            raise ValueError(f"VLR {i + 1} of {count} ({n} bytes) runs into the point data")
        out.append((bytes(h["user_id"]).rstrip(b"\0"), int(h["record_id"]), data[pos : pos + n]))
        pos += n
    return out


# --------------------------------------------------------------------------- reader


class CopcCloud(VoxelOctree):
    """A COPC file (local path or http(s) URL) opened as an octree: the header, VLRs and root
    hierarchy page are read at open, deeper pages and node chunks when a frame draws them
    (voxel_octree.py). ``meta`` holds the LAS facts ``gigapoint info`` shows (``crs``,
    ``point_format``, ``scale``, ``offset``, ``spacing``)."""

    def __init__(self, source: ByteSource):
        self.source = source
        name = source.name
        head = source.read_head(HEAD_READ)
        if not head:  # (a URL's was "bytes 0..65,536 lie past the end of the file (HTTP 416)")
            raise EmptyCloudError(f"{name}: file is empty (0 bytes)")
        truncated = truncated_header(len(head)) if head[:4] == b"LASF" else ""
        if truncated:  # (a URL's was "not a COPC file": a local one's words)
            raise InputError(f"{name}: {truncated}")
        if not is_copc_head(head):
            part = potree_part(name)
            if part is not None:
                raise InputError(part)
            if head[:4] == b"LASF" and len(head) > 104:  # its own version and kind: every LAS file was "a LAS 1.4 file"
                kind = "LAZ" if head[104] & 0x80 else "LAS"
                what = f"{kind} {head[24]}.{head[25]} file without the COPC info VLR first"
            else:
                what = "LAS file without the COPC info VLR first" if head[:4] == b"LASF" else f"file that starts with {head[:4]!r}"
            raise InputError(f"{name}: not a COPC file (a {what}); gigapoint reads COPC (.copc.laz) and EPT (ept.json) as octrees")
        if len(head) < INFO_OFFSET + COPC_INFO_DTYPE.itemsize:
            raise InputError(f"{name}: truncated COPC file ({len(head)} bytes: no room for the COPC info VLR)")
        hdr = np.frombuffer(head, LAS14_HEADER_DTYPE, count=1)[0]
        fmt_id, rec_len = int(hdr["point_format"]), int(hdr["point_record_length"])
        fmt = fmt_id & 0x3F
        if fmt not in POINT_DTYPES:
            raise InputError(f"{name}: COPC point format {fmt} is not 6, 7 or 8")
        data_start = int(hdr["offset_to_point_data"])
        n_vlrs = int(hdr["number_of_vlrs"])
        file_size = source.size()
        if file_size is not None and data_start > file_size:
            raise InputError(f"{name}: truncated COPC file: its point data would start at byte {data_start:,}, the file has {file_size:,}")
        if data_start > len(head):
            head = head + source.read(len(head), data_start - len(head))
        try:
            vlrs = read_vlrs(head, int(hdr["header_size"]), n_vlrs, data_start)
        except ValueError as exc:
            raise InputError(f"{name}: corrupt COPC file: {exc}") from None
        try:
            fields = extra_fields(vlrs, fmt)
            self.record = point_dtype(fmt, rec_len, fields)
            self.extra = [f for f in fields if not f.name.startswith("_extra")]  # the named ones: attributes
        except ValueError as exc:
            raise InputError(f"{name}: corrupt COPC header: {exc}") from None
        info = np.frombuffer(head, COPC_INFO_DTYPE, count=1, offset=INFO_OFFSET)[0]
        laszip = [d for u, r, d in vlrs if u == LASZIP_USER_ID and r == LASZIP_RECORD]
        if not laszip:
            raise InputError(f"{name}: corrupt COPC file: no LASzip VLR")
        self.laszip = laszip[0]
        self.scale = np.array(hdr["scale"], np.float64)
        self.offset = np.array(hdr["offset"], np.float64)
        self.coordinate_step = float(np.max(np.abs(self.scale)))
        center, half = np.array(info["center"], np.float64), float(info["halfsize"])
        lo = np.array([hdr["min_x"], hdr["min_y"], hdr["min_z"]], np.float64)
        hi = np.array([hdr["max_x"], hdr["max_y"], hdr["max_z"]], np.float64)
        if not (np.all(np.isfinite(center)) and np.isfinite(half) and half > 0):
            raise InputError(f"{name}: corrupt COPC info VLR: octree centre {center.tolist()} and half size {half!r}")
        if not (np.all(np.isfinite(self.scale)) and np.all(self.scale != 0) and np.all(np.isfinite(self.offset))):
            raise InputError(f"{name}: corrupt COPC header: scale {self.scale.tolist()}, offset {self.offset.tolist()}")
        check_grid(name, "COPC header", self.scale, self.offset)
        cube_min = center - half
        n_points = int(hdr["point_count"]) or int(hdr["legacy_point_count"])
        lo, hi = tight_bounds(name, "COPC file (header bounds, info VLR cube)", lo, hi, cube_min, 2.0 * half, self.coordinate_step)
        self.data_start = data_start
        self.file_size = file_size
        self.point_format = fmt
        self._attr_dtypes = dict(ATTRIBUTE_DTYPES, **({"nir": np.dtype(np.uint16)} if fmt == 8 else {}))
        self._attr_dtypes.update({f.attribute: f.value_dtype for f in self.extra})
        self._evlrs = (int(hdr["start_of_first_evlr"]), int(hdr["number_of_evlrs"]))
        crs = wkt_of(vlrs) or self._evlr_wkt(data_start)
        meta = {
            "format": "copc",
            "points": n_points,
            "cube_min": cube_min.tolist(),
            "cube_edge": 2.0 * half,
            "bounds": {"min": lo.tolist(), "max": hi.tolist()},
            "spacing": float(info["spacing"]),
            "crs": crs,
            "las_version": f"{hdr['version_major']}.{hdr['version_minor']}",
            "point_format": fmt,
            "scale": self.scale.tolist(),
            "offset": self.offset.tolist(),
            "generating_software": bytes(hdr["generating_software"]).split(b"\0")[0].decode("ascii", "replace").strip(),
        }
        root = (int(info["root_hier_offset"]), int(info["root_hier_size"]))
        self._root, self._expected, self._cut_said = root, None, False
        if file_size is not None and root[0] + root[1] > file_size and self._cut():
            raise InputError(
                f"{name}: truncated COPC file: it has {file_size:,} bytes, its header says at least {self._expected:,} "
                f"(its hierarchy, at bytes {root[0]:,}..{root[0] + root[1]:,}, is cut off: no node can be found){self._as_laz()}"
            )
        self._check_range(root[0], root[1], "the root hierarchy page")
        self._open(last_name(name), meta, root, path=None)

    def _evlr_wkt(self, data_start: int) -> str | None:
        """The WKT of a LASF_Projection EVLR (copc-lib writes its CRS so, after the hierarchy
        pages). Over HTTP read in one request where the EVLRs end the file within ``EVLR_READ``
        bytes (a hierarchy of up to 30 000 nodes); else each EVLR's header is read (a local file:
        all of them; over HTTP: the first ``EVLR_WALK``, a request each), then only the WKT's
        bytes. None without one, in a cut file, or over HTTP past those."""
        (start, n), end = self._evlrs, self.file_size or 0
        remote = not isinstance(self.source, LocalFile)
        if not n or start < data_start or end <= start:
            return None
        if remote and end - start <= EVLR_READ:
            try:
                return wkt_of(read_vlrs(self.source.read(start, end - start), 0, n, end - start, EVLR_HEADER_DTYPE))
            except ValueError:  # cut: _parse_page says what is missing
                return None
        for i, pos, user, record, length in evlr_headers(self.source.read, start, n, end):
            if (remote and i >= EVLR_WALK) or length is None or pos + EVLR_HEADER + length > end:  # (cut: as above)
                return None
            if (user, record) == (PROJECTION_USER_ID, WKT_RECORD):
                return wkt_of([(user, record, self.source.read(pos + EVLR_HEADER, length))])
        return None

    def _cut(self) -> bool:
        """Whether the file is shorter than its header says: its hierarchy (an EVLR, after the
        points: the last thing a COPC file holds) and root page end past its end. Then nodes and
        pages past the cut are left out (``_parse_page``), where in a whole file they are an
        error. Asked when something lies past the end (the EVLR's header read then, if there)."""
        if self._expected is None:
            (start, n), (off, size) = self._evlrs, self._root
            self._expected = off + size
            if n and start >= self.data_start:
                self._expected = max(self._expected, start + EVLR_HEADER_DTYPE.itemsize)
                if start + EVLR_HEADER_DTYPE.itemsize <= self.file_size:
                    head = np.frombuffer(self.source.read(start, EVLR_HEADER_DTYPE.itemsize), EVLR_HEADER_DTYPE)[0]
                    self._expected = max(self._expected, start + EVLR_HEADER_DTYPE.itemsize + int(head["record_length"]))
        return self.file_size < self._expected

    def _as_laz(self) -> str:
        """What a cut file whose hierarchy is gone still offers: a local one whose LAZ chunk table
        is whole (cut in its EVLRs) is read as plain LAZ, every point; else nothing (its table,
        after the points, is gone too, and its chunks are of variable size: no point can be read)."""
        if not isinstance(self.source, LocalFile):
            return ""
        try:
            whole = read_las_header(self.source.path).truncated is None
        except InputError:
            return ""
        return "; its points can still be read as a plain LAZ file (`gigapoint view --progressive`, gigapoint.open(..., progressive=True))" if whole else ""

    def _check_range(self, offset: int, size: int, what: str) -> None:
        if offset < 0 or size < 0 or (self.file_size is not None and offset + size > self.file_size):
            raise InputError(
                f"{self.source.name}: {what} at bytes {offset:,}..{offset + size:,} lies past the end of the file ({self.file_size:,} bytes)"
            )

    # -- VoxelOctree
    def _fetch_pages(self, locators: list) -> list[bytes]:
        return self.source.read_many(locators)

    def _parse_page(self, blob: bytes, locator) -> tuple[dict, dict]:
        offset, size = locator
        name = self.source.name
        if size == 0 or size % HIERARCHY_ENTRY_DTYPE.itemsize or len(blob) != size:
            raise InputError(
                f"{name}: truncated hierarchy page at byte {offset:,}: {size:,} bytes is not a whole number of "
                f"{HIERARCHY_ENTRY_DTYPE.itemsize}-byte entries"
            )
        e = np.frombuffer(blob, HIERARCHY_ENTRY_DTYPE)
        k = e["key"]
        ok = valid_voxels(k["level"], k["x"], k["y"], k["z"])
        if not ok.all():
            i = int(np.flatnonzero(~ok)[0])
            raise InputError(
                f"{name}: invalid node key {k['level'][i]}-{k['x'][i]}-{k['y'][i]}-{k['z'][i]} in the hierarchy page at byte {offset:,}"
            )
        voxels = voxel_to_key(k["level"], k["x"], k["y"], k["z"])
        keys = voxels.tolist()
        counts, offs, sizes = e["point_count"].astype(np.int64), e["offset"].astype(np.int64), e["byte_size"].astype(np.int64)
        # a key may be listed once as a node and once as the pointer to the page below it
        # (copc-lib writes a page's key so: the node's own entry stays in the parent page)
        for kind in (counts == -1, counts != -1):
            if len(np.unique(voxels[kind])) != int(kind.sum()):
                raise InputError(f"{name}: the hierarchy page at byte {offset:,} lists a node twice")
        # checked all at once (a page may hold 10^5 entries); the first bad entry is named
        page, chunk = counts == -1, counts > 0
        end = offs + sizes
        beyond = (end > self.file_size) if self.file_size is not None else np.zeros(len(keys), bool)
        if beyond.any() and self._cut():  # nodes and pages past the cut left out, said once
            lost, gone = chunk & beyond & (offs >= self.data_start), page & beyond & (offs >= 0) & (sizes > 0)
            if (lost.any() or gone.any()) and not self._cut_said:
                self._cut_said = True
                what = [f"{int(counts[lost].sum()):,} points in {lost.sum():,} nodes past the cut"] if lost.any() else []
                what += [f"the nodes below {gone.sum():,} hierarchy pages past it"] if gone.any() else []
                warn(
                    f"{name}: truncated COPC file: it has {self.file_size:,} bytes, its header says at least {self._expected:,}: "
                    f"{' and '.join(what)} are left out",
                    GigapointWarning,
                )
            self._meta["points"] -= int(counts[lost].sum())
            counts[lost], chunk, page = 0, chunk & ~lost, page & ~gone
        problems = (
            (counts < -1, "has an invalid point count {c} in the hierarchy"),
            (
                page & ((sizes <= 0) | (offs < 0) | beyond),
                "has its hierarchy page at bytes {o:,}..{e:,}, past the end of the file ({f:,} bytes)",
            ),
            (chunk & ((sizes <= 0) | (offs < self.data_start)), "has its chunk at bytes {o:,}..{e:,}, outside the point data"),
            (chunk & beyond, "has its chunk at bytes {o:,}..{e:,}, which lies past the end of the file ({f:,} bytes)"),
        )
        for bad, text in problems:
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                what = text.format(c=int(counts[i]), o=int(offs[i]), e=int(end[i]), f=self.file_size or 0)
                raise InputError(f"{name}: node {voxel_name(keys[i])} {what}")
        locs = list(zip(offs.tolist(), sizes.tolist()))
        pages = {keys[i]: locs[i] for i in np.flatnonzero(page).tolist()}
        entries = {keys[i]: ((int(counts[i]), locs[i]) if chunk[i] else (0, None)) for i in np.flatnonzero(~page).tolist()}
        return entries, pages

    def _fetch_nodes(self, locators: list) -> list[bytes]:
        return self.source.read_many(locators)

    def _decode(self, index: int, blob: bytes) -> dict:
        return self._decode_batch([index], [blob])[0]

    def _decode_batch(self, indices: list[int], blobs: list[bytes]) -> list[dict]:
        """The nodes' chunks as one LAZ point block (offset, chunks, chunk table), decoded by
        lazrs's parallel decompressor (a chunk per thread) in a child process (io/laz_process.py:
        lazrs crashes on some corrupt data), then split by node."""
        import lazrs

        counts = [int(self.counts[i]) for i in indices]
        table = io.BytesIO()
        lazrs.write_chunk_table(table, [(n, len(b)) for n, b in zip(counts, blobs)], lazrs.LazVlr(self.laszip))
        data = b"".join(blobs)
        block = np.int64(8 + len(data)).tobytes() + data + table.getvalue()
        out = laz_process.decode_block(block, self.laszip, sum(counts) * self.record.itemsize)
        rec = out.view(self.record)
        starts = np.concatenate([[0], np.cumsum(counts)])
        return [self._points(rec[starts[k] : starts[k + 1]]) for k in range(len(indices))]

    def _points(self, rec: np.ndarray) -> dict:
        """Positions, colors and attributes of point records."""
        xyz = np.empty((len(rec), 3), np.float64)
        _scaled_xyz(rec["X"], rec["Y"], rec["Z"], self.scale, self.offset, xyz)
        attrs = {
            "intensity": rec["intensity"],
            "classification": rec["classification"],
            "return_number": rec["returns"] & np.uint8(0x0F),
            "number_of_returns": rec["returns"] >> np.uint8(4),
            "point_source_id": rec["point_source_id"],
            "gps_time": rec["gps_time"],
            "user_data": rec["user_data"],
            "scan_angle": rec["scan_angle"],
        }
        for name, bit in FLAG_BITS.items():
            attrs[name] = (rec["flags"] >> np.uint8(bit)) & np.uint8(3 if name == "scanner_channel" else 1)
        rgb = None
        if self.point_format >= 7:
            rgb = np.stack([rec["red"], rec["green"], rec["blue"]], axis=1)
        if self.point_format == 8:
            attrs["nir"] = rec["nir"]
        for f in self.extra:
            attrs[f.attribute] = f.values(rec)
        return {"xyz": xyz, "rgb": rgb, "attributes": attrs}


def open_copc(path_or_url) -> CopcCloud:
    """A COPC file (local path or http(s) URL) as an octree (CopcCloud)."""
    return CopcCloud(open_source(path_or_url))


__all__ = [
    "ATTRIBUTE_DTYPES",
    "COPC_INFO_DTYPE",
    "EVLR_HEADER_DTYPE",
    "EXTRA_BYTES_DTYPE",
    "HIERARCHY_ENTRY_DTYPE",
    "LAS14_HEADER_DTYPE",
    "POINT_DTYPES",
    "VLR_HEADER_DTYPE",
    "CopcCloud",
    "ExtraField",
    "copc_file_kind",
    "extra_fields",
    "is_copc_head",
    "open_copc",
    "point_dtype",
]
