"""Writing COPC (copc.io): octree nodes -> one ``.copc.laz`` file, written atomically.

``CopcWriter`` takes nodes one at a time (key, float64 points, 16-bit colors, attributes),
turns each into LAS 1.4 point records (format 6, 7 or 8; coordinates as integers of the given
scale and offset) and compresses every node into one variable-size LAZ chunk with lazrs
(node batches of ~1 M points compressed in parallel by ``ParLasZipCompressor``), then writes
the LAZ chunk table, the hierarchy EVLR (pages of 32-byte entries; ``page_level`` splits it
into child pages) and last the header and VLRs (the COPC info VLR first, the LASzip VLR, the
WKT CRS VLR) at the start of the file. ``write_copc`` wraps it in ``atomic_open``: the file
appears under its name only once complete. The converter's write phase calls
``write_copc_sets`` on its built node sets; an in-memory octree calls ``write_copc`` with its
node arrays. Layouts: copc.py.
"""

from __future__ import annotations

import datetime
import io
from collections.abc import Iterable
from pathlib import Path

import numpy as np
from numba import njit

from ..atomic import atomic_open
from ..errors import GigapointWarning, warn
from ..io.las import PROJECTION_USER_ID, WKT_RECORD
from ..io.las_fields import (
    EXTRA_BYTES_TYPES,
    FLAG_BITS,
    LAS_FIELD_OF,
    choose_point_format,
    extra_attributes,
    las_field_values,
    warn_clipped,
)
from .copc import (
    COPC_HIERARCHY_RECORD,
    COPC_INFO_DTYPE,
    EVLR_HEADER_DTYPE,
    EXTRA_BYTES_DTYPE,
    EXTRA_BYTES_RECORD,
    EXTRA_BYTES_USER_ID,
    HIERARCHY_ENTRY_DTYPE,
    LAS14_HEADER_DTYPE,
    LASZIP_RECORD,
    LASZIP_USER_ID,
    POINT_DTYPES,
    VLR_HEADER_DTYPE,
)
from .grid import output_grid
from .keys import ROOT_KEY, level_of
from .kinds import COPC_INFO_RECORD, COPC_USER_ID
from .octree_dir import OutputExistsError
from .voxel_octree import key_to_voxel

#: Points compressed together (in parallel, one LAZ chunk per node).
BATCH_POINTS = 1 << 20


@njit(cache=True)
def _las_integers(xyz, offset, scale, X, Y, Z, lo, hi) -> bool:
    """X, Y, Z = round((xyz - offset) / scale) (LAS's integer coordinates), their running min
    ``lo`` and max ``hi`` updated; False when one does not fit 32 bits."""
    for i in range(xyz.shape[0]):
        for a in range(3):
            v = np.rint((xyz[i, a] - offset[a]) / scale[a])
            if not (-2147483648.0 <= v <= 2147483647.0):
                return False
            iv = np.int64(v)
            lo[a] = min(lo[a], iv)
            hi[a] = max(hi[a], iv)
            if a == 0:
                X[i] = iv
            elif a == 1:
                Y[i] = iv
            else:
                Z[i] = iv
    return True




def _extra_bytes_vlr(extra: dict[str, np.dtype]) -> bytes:
    """The Extra Bytes VLR's descriptors of ``extra`` ({name: dtype}, in record order)."""
    code = {dt: k for k, dt in EXTRA_BYTES_TYPES.items()}
    d = np.zeros(len(extra), EXTRA_BYTES_DTYPE)
    for i, (name, dt) in enumerate(extra.items()):
        d[i]["data_type"], d[i]["name"], d[i]["description"] = code[np.dtype(dt)], name.encode(), b"gigapoint attribute"
    return _vlr(EXTRA_BYTES_USER_ID, EXTRA_BYTES_RECORD, d.tobytes(), "Extra Bytes")


def _vlr(user: bytes, record: int, data: bytes, description: str) -> bytes:
    h = np.zeros(1, VLR_HEADER_DTYPE)
    h["user_id"], h["record_id"], h["record_length"], h["description"] = user, record, len(data), description.encode()
    return h.tobytes() + data


class CopcWriter:
    """Nodes -> a COPC file on the binary file object ``f`` (positioned at 0, seekable), the
    output ``path`` (what its warnings name)."""

    def __init__(
        self, f, path, *, scale, offset, cube_min, cube_edge: float, point_format: int = 7, wkt: str | None = None, spacing=None, extra=None
    ):
        import lazrs

        if point_format not in POINT_DTYPES:
            raise ValueError(f"COPC point format must be 6, 7 or 8, got {point_format}")
        self.f, self.path = f, path
        self.clipped: dict = {}  # {attribute: values clipped to its LAS field}: said once, by finish
        self.lazrs = lazrs
        self.point_format = point_format
        self.extra = {str(k): np.dtype(v) for k, v in (extra or {}).items()}  # {name: dtype}: extra_attributes
        self.dtype = np.dtype([*POINT_DTYPES[point_format].descr, *self.extra.items()])
        extra_size = self.dtype.itemsize - POINT_DTYPES[point_format].itemsize
        self.scale = np.asarray(scale, np.float64).reshape(3)
        self.offset = np.asarray(offset, np.float64).reshape(3)
        self.cube_min = np.asarray(cube_min, np.float64).reshape(3)
        self.cube_edge = float(cube_edge)
        self.spacing = float(spacing) if spacing is not None else self.cube_edge / 128.0
        self.vlr = lazrs.LazVlr.new_for_compression(point_format, extra_size, True)
        self.wkt = wkt
        self.vlrs = [
            _vlr(COPC_USER_ID, COPC_INFO_RECORD, bytes(COPC_INFO_DTYPE.itemsize), "COPC info VLR"),
            _vlr(LASZIP_USER_ID, LASZIP_RECORD, bytes(self.vlr.record_data()), "lazrs variant"),
        ]
        if self.extra:
            self.vlrs.append(_extra_bytes_vlr(self.extra))
        if wkt:
            self.vlrs.append(_vlr(PROJECTION_USER_ID, WKT_RECORD, wkt.encode() + b"\0", "WKT"))
        self.data_start = LAS14_HEADER_DTYPE.itemsize + sum(map(len, self.vlrs))
        f.write(bytes(self.data_start + 8))  # header and VLRs (written last), the chunk table's offset
        self.entries: dict[int, tuple[int, int, int]] = {}  # key -> (offset, byte size, points)
        self.table: list[tuple[int, int]] = []
        self._batch: list[tuple[int, np.ndarray]] = []
        self._batch_keys: set[int] = set()
        self._batch_points = 0
        self.n_points = 0
        self.int_min = np.full(3, np.iinfo(np.int64).max, np.int64)
        self.int_max = np.full(3, np.iinfo(np.int64).min, np.int64)
        self.by_return = np.zeros(15, np.uint64)
        self.gps = [np.inf, -np.inf]

    def add(self, key: int, xyz: np.ndarray, rgb16: np.ndarray | None = None, attributes: dict | None = None) -> None:
        """One node: ``key`` (keys.py), its points (float64 (n, 3)), 16-bit colors (n, 3) and
        attributes (intensity, classification, return_number, number_of_returns,
        point_source_id, gps_time, nir, user_data, scan_angle (or scan_angle_rank), the flags
        of FLAG_BITS, and the writer's ``extra`` ones: the rest is not stored)."""
        key = int(key)
        if key in self.entries or key in self._batch_keys:
            raise ValueError(f"node key {key} given twice")
        n = len(xyz)
        if n == 0:
            self.entries[key] = (0, 0, 0)
            return
        attributes = attributes or {}
        rec = np.zeros(n, self.dtype)
        xyz = np.ascontiguousarray(xyz, np.float64)
        if not _las_integers(xyz, self.offset, self.scale, rec["X"], rec["Y"], rec["Z"], self.int_min, self.int_max):
            raise ValueError(
                f"coordinates do not fit LAS's 32-bit integers with scale {self.scale.tolist()} and offset {self.offset.tolist()}"
            )
        for name in ("intensity", "classification", "point_source_id", "user_data", "scan_angle_rank", "scan_angle"):
            if name in attributes:  # (scan_angle after scan_angle_rank: the finer one where both are given)
                rec[LAS_FIELD_OF.get(name, name)] = las_field_values(name, attributes[name], self.clipped)
        for name, bit in FLAG_BITS.items():
            if name in attributes:
                rec["flags"] |= las_field_values(name, attributes[name], self.clipped).astype(np.uint8) << np.uint8(bit)
        rn = las_field_values("return_number", np.asarray(attributes["return_number"], np.int64), self.clipped) if "return_number" in attributes else None
        nr = las_field_values("number_of_returns", np.asarray(attributes["number_of_returns"], np.int64), self.clipped) if "number_of_returns" in attributes else None
        if rn is not None or nr is not None:
            rec["returns"] = (rn if rn is not None else 0) | ((nr if nr is not None else 0) << 4)
        if rn is not None:
            self.by_return += np.bincount(rn, minlength=16)[1:16].astype(np.uint64)
        if "gps_time" in attributes:
            g = las_field_values("gps_time", attributes["gps_time"])
            rec["gps_time"] = g
            self.gps = [min(self.gps[0], float(g.min())), max(self.gps[1], float(g.max()))]
        if self.point_format >= 7 and rgb16 is not None:
            rgb16 = np.asarray(rgb16)
            rec["red"], rec["green"], rec["blue"] = rgb16[:, 0], rgb16[:, 1], rgb16[:, 2]
        if self.point_format == 8 and "nir" in attributes:
            rec["nir"] = las_field_values("nir", attributes["nir"], self.clipped)
        for name in self.extra:
            if name in attributes:
                rec[name] = attributes[name]
        self._batch.append((key, rec))
        self._batch_keys.add(key)
        self._batch_points += n
        self.n_points += n
        if self._batch_points >= BATCH_POINTS:
            self._flush()

    def _flush(self) -> None:
        """Compress the batch's nodes (one LAZ chunk each, in parallel) and append them."""
        if not self._batch:
            return
        buf = io.BytesIO()
        c = self.lazrs.ParLasZipCompressor(buf, self.vlr)
        c.reserve_offset_to_chunk_table()
        c.compress_chunks([rec.view(np.uint8) for _, rec in self._batch])
        c.done()
        data = buf.getbuffer()
        buf.seek(0)
        table = self.lazrs.read_chunk_table(buf, self.vlr)
        pos = 8
        for (key, rec), (count, size) in zip(self._batch, table, strict=True):
            if int(count) != len(rec):
                raise RuntimeError(f"internal error: LAZ chunk of {count} points for a node of {len(rec)}")
            offset = self.f.tell()
            self.f.write(data[pos : pos + size])
            self.entries[key] = (offset, int(size), len(rec))
            self.table.append((len(rec), int(size)))
            pos += size
        del data
        self._batch, self._batch_keys, self._batch_points = [], set(), 0

    def finish(self, page_level: int | None = None) -> dict:
        """The chunk table, hierarchy EVLR, header and VLRs; returns {points, nodes, pages}.
        Attribute values clipped to their LAS field are said once a field (as io/write.py's LAS save)."""
        self._flush()
        warn_clipped(self.path, self.clipped)
        f = self.f
        for key in list(self.entries):  # every ancestor has an entry, so that readers reach every node
            k = key
            while k > ROOT_KEY:
                k >>= 3
                if k in self.entries:
                    break
                self.entries[k] = (0, 0, 0)
        self.entries.setdefault(ROOT_KEY, (0, 0, 0))
        table_offset = f.tell()
        self.lazrs.write_chunk_table(f, self.table, self.vlr)
        evlr_start = f.tell()
        base = evlr_start + EVLR_HEADER_DTYPE.itemsize
        pages = hierarchy_pages(self.entries, base, page_level)
        blob = b"".join(p.tobytes() for _, p in pages)
        eh = np.zeros(1, EVLR_HEADER_DTYPE)
        eh["user_id"], eh["record_id"], eh["record_length"], eh["description"] = (
            COPC_USER_ID,
            COPC_HIERARCHY_RECORD,
            len(blob),
            b"EPT hierarchy",
        )
        f.write(eh.tobytes())
        f.write(blob)
        # the header and the VLRs, at the start
        info = np.zeros(1, COPC_INFO_DTYPE)
        half = self.cube_edge / 2
        info["center"] = self.cube_min + half
        info["halfsize"] = half
        info["spacing"] = self.spacing
        info["root_hier_offset"] = base
        info["root_hier_size"] = pages[0][1].nbytes
        if np.isfinite(self.gps[0]):
            info["gpstime_minimum"], info["gpstime_maximum"] = self.gps
        self.vlrs[0] = self.vlrs[0][: VLR_HEADER_DTYPE.itemsize] + info.tobytes()
        h = np.zeros(1, LAS14_HEADER_DTYPE)
        today = datetime.date.today()
        h["file_signature"] = b"LASF"
        h["global_encoding"] = 1 << 4  # WKT CRS (point formats 6-10)
        h["version_major"], h["version_minor"] = 1, 4
        h["system_identifier"] = b"gigapoint"
        h["generating_software"] = b"gigapoint"
        h["creation_day"], h["creation_year"] = today.timetuple().tm_yday, today.year
        h["header_size"] = LAS14_HEADER_DTYPE.itemsize
        h["offset_to_point_data"] = self.data_start
        h["number_of_vlrs"] = len(self.vlrs)
        h["point_format"] = self.point_format | 0x80  # LAZ-compressed
        h["point_record_length"] = self.dtype.itemsize
        h["scale"], h["offset"] = self.scale, self.offset
        if self.n_points:
            lo = self.int_min * self.scale + self.offset
            hi = self.int_max * self.scale + self.offset
            h["min_x"], h["min_y"], h["min_z"] = lo
            h["max_x"], h["max_y"], h["max_z"] = hi
        h["start_of_first_evlr"] = evlr_start
        h["number_of_evlrs"] = 1
        h["point_count"] = self.n_points
        h["points_by_return"] = self.by_return
        f.seek(0)
        f.write(h.tobytes() + b"".join(self.vlrs))
        f.write(np.int64(table_offset).tobytes())
        f.seek(0, io.SEEK_END)
        return {"points": self.n_points, "nodes": len(self.entries), "pages": len(pages)}


def hierarchy_pages(entries: dict, base: int, page_level: int | None = None) -> list[tuple[int, np.ndarray]]:
    """The hierarchy pages of ``entries`` {key: (offset, byte size, points)}, laid out from file
    offset ``base`` (root page first): [(page root key, entries)]. ``page_level`` k > 0: every
    node at a level that is a multiple of k and has children heads a child page of its own
    (its parent's page holds a -1 entry pointing to it); None: one page."""
    keys = np.array(sorted(entries), np.uint64)
    key_set = set(keys.tolist())
    roots = {ROOT_KEY}
    if page_level:
        lev = level_of(keys)
        parents = {k >> 3 for k in key_set if k != ROOT_KEY}
        roots |= {k for k, lv in zip(keys.tolist(), lev.tolist()) if lv > 0 and lv % page_level == 0 and k in parents}

    def page_of(k: int) -> int:
        while k not in roots:
            k >>= 3
        return k

    members: dict[int, list[int]] = {r: [] for r in roots}
    for k in keys.tolist():
        members[page_of(k)].append(k)
    pointers: dict[int, list[int]] = {r: [] for r in roots}
    for r in roots:
        if r != ROOT_KEY:
            pointers[page_of(r >> 3)].append(r)
    order = sorted(roots)  # the root page (key 1) first
    size = {r: HIERARCHY_ENTRY_DTYPE.itemsize * (len(members[r]) + len(pointers[r])) for r in order}
    where, pos = {}, base
    for r in order:
        where[r] = pos
        pos += size[r]
    out = []
    for r in order:
        ks = sorted(members[r] + pointers[r])
        page = np.zeros(len(ks), HIERARCHY_ENTRY_DTYPE)
        d, x, y, z = key_to_voxel(np.array(ks, np.uint64))
        page["key"]["level"], page["key"]["x"], page["key"]["y"], page["key"]["z"] = d, x, y, z
        ptr = set(pointers[r])
        for i, k in enumerate(ks):
            if k in ptr:
                page[i]["offset"], page[i]["byte_size"], page[i]["point_count"] = where[k], size[k], -1
            else:
                off, nbytes, n = entries[k]
                page[i]["offset"], page[i]["byte_size"], page[i]["point_count"] = off, nbytes, n
        out.append((r, page))
    return out


def write_copc(
    path,
    nodes: Iterable,
    *,
    scale,
    offset,
    cube_min,
    cube_edge: float,
    point_format: int = 7,
    wkt: str | None = None,
    spacing=None,
    page_level: int | None = None,
    overwrite: bool = False,
    durable: bool = True,
    extra=None,
) -> dict:
    """Write octree nodes as the COPC file ``path``, atomically (it appears only when complete).

    ``nodes``: (key, float64 xyz (n, 3), u16 rgb (n, 3) or None, {attribute: array}) per node,
    in any order (missing ancestors get empty entries); ``scale``/``offset``: the LAS integer
    grid; ``cube_min``/``cube_edge``: the octree's cube (keys are relative to it); ``wkt``: the
    CRS; ``extra``: {name: dtype} of attributes stored in extra bytes (``extra_attributes``).
    Returns {points, nodes, pages}."""
    check_copc_output(path, overwrite)
    with atomic_open(path, durable=durable) as f:
        w = CopcWriter(
            f, path, scale=scale, offset=offset, cube_min=cube_min, cube_edge=cube_edge, point_format=point_format, wkt=wkt, spacing=spacing,
            extra=extra,
        )  # fmt: skip
        for key, xyz, rgb, attrs in nodes:
            w.add(key, xyz, rgb, attrs)
        return w.finish(page_level)


def write_copc_sets(path: Path, sources: list[Path], st: dict, progress, page_level: int | None = None, overwrite: bool = True) -> int:
    """The converter's write phase for ``--format copc``: its built node sets (keys, counts, xyz,
    rgba, attr.* arrays each) as the COPC file ``path``; returns the number of nodes. The CRS,
    scale, offset and colors come from what the read phase recorded (``st["source"]``)."""
    src = st.get("source") or {}
    attrs = st.get("attributes") or {}
    origin, edge = np.array(st["origin"], np.float64), float(st["edge"])
    scale, offset = output_grid(st, out=path)
    fmt = choose_point_format(attrs, src.get("has_color", True))
    if src.get("crs") and not src.get("wkt"):  # LAS 1.2 GeoTIFF keys: their EPSG code, no WKT, and no pyproj to make one
        warn(
            f"{path}: the inputs' CRS ({src['crs'][:60]}) is not written: COPC holds a CRS as WKT only, and making WKT "
            "of an EPSG code needs pyproj (pip install pyproj)",
            GigapointWarning,
        )

    def nodes():
        for d in sources:
            keys = np.load(d / "keys.npy")
            counts = np.load(d / "counts.npy").astype(np.int64)
            xyz = np.load(d / "xyz.npy", mmap_mode="r")
            rgba = np.load(d / "rgba.npy", mmap_mode="r").view(np.uint8).reshape(-1, 4)
            data = {a: np.load(d / f"attr.{a}.npy", mmap_mode="r") for a in attrs if (d / f"attr.{a}.npy").exists()}
            starts = np.concatenate([[0], np.cumsum(counts)])
            for i, key in enumerate(keys.tolist()):
                s, e = int(starts[i]), int(starts[i + 1])
                rgb16 = np.asarray(rgba[s:e, :3], np.uint16) * np.uint16(257)
                yield key, np.asarray(xyz[s:e]), rgb16, {a: np.asarray(v[s:e]) for a, v in data.items()}
            progress.advance(int(counts.sum()))

    summary = write_copc(
        path, nodes(), scale=scale, offset=offset, cube_min=origin, cube_edge=edge, point_format=fmt,
        wkt=src.get("wkt"), spacing=edge / 128.0, page_level=page_level, overwrite=overwrite,
        extra=extra_attributes(attrs, str(path), fmt),
    )  # fmt: skip
    return int(summary["nodes"])


def check_copc_output(out, overwrite: bool) -> None:
    """A COPC output ``out`` may be written: not a folder, and not an existing file without ``overwrite``."""
    out = Path(out)
    if out.is_dir():
        raise OutputExistsError(f"{out}: is a directory; a COPC output is one file (e.g. -o cloud.copc.laz)")
    if out.exists() and not overwrite:
        raise OutputExistsError(f"{out}: already exists; pass overwrite=True to replace it")
