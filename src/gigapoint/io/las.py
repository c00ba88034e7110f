"""LAS and LAZ 1.0-1.4, point formats 0-10, through laspy (+ lazrs for LAZ).

The header is parsed and checked against the file size here, with struct, *before* laspy
sees the file: laspy trusts counts and offsets (EVLR lengths, LAZ chunk tables) and would
allocate or loop on whatever a corrupt header claims.
"""

from __future__ import annotations

import contextlib
import functools
import io
import logging
import math
import os
import struct
from collections.abc import Iterator
from contextvars import ContextVar
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core import pages
from ..core.chunk import ColorScaler, PointChunk, safe_attribute_name
from ..core.coords import MAX_ABS_COORDINATE, NUMPY_MAX
from ..errors import EmptyCloudError, GigapointWarning, InputError, warn
from . import laz_process
from ._base import DEFAULT_CHUNK_SIZE, SALVAGE_HINT, Reader, check_chunk_size, check_file, fail, one_line, read_once

#: Minimum point record length of each point format (bytes).
RECORD_SIZE = {0: 20, 1: 28, 2: 26, 3: 34, 4: 57, 5: 63, 6: 30, 7: 36, 8: 38, 9: 59, 10: 67}
#: Header size of each LAS 1.x minor version.
HEADER_SIZE = {0: 227, 1: 227, 2: 227, 3: 235, 4: 375}
#: Largest |scale| accepted: one unit of the stored integers must be less than a kilometre (or degree...).
MAX_SCALE = 1e3
VLR_HEADER = 54
EVLR_HEADER = 60
LASZIP_USER_ID = b"laszip encoded"
LASZIP_RECORD_ID = 22204

#: Attributes read from every point format that has them (laspy's dimension names are gigapoint's):
#: scan_angle_rank is formats 0-5's (int8 degrees), scan_angle 6-10's (int16, 0.006 degrees);
#: the flags are 0/1 (scanner_channel 0-3), uint8. A field all zero costs no memory once held
#: (core/attributes.py: a constant is no array).
LAS_ATTRIBUTES = (
    "intensity", "classification", "return_number", "number_of_returns", "point_source_id", "gps_time", "nir",
    "scan_angle_rank", "scan_angle", "user_data", "scan_direction_flag", "edge_of_flight_line",
    "synthetic", "key_point", "withheld", "overlap", "scanner_channel",
)  # fmt: skip


def scan_angle_units(degrees) -> np.ndarray:
    """Formats 0-5's scan angle (``scan_angle_rank``, degrees) in formats 6-10's ``scan_angle``
    units: int16 steps of 0.006 degrees, within ±180 degrees as LAS 1.4 says."""
    return np.clip(np.rint(np.asarray(degrees, np.float64) / 0.006), -30000, 30000).astype(np.int16)


def with_scan_angle(chunks: Iterator[PointChunk]) -> Iterator[PointChunk]:
    """``chunks`` with ``scan_angle_rank`` as ``scan_angle`` (``scan_angle_units``), in its place:
    a file merged with files of point formats 6-10 (io's ``scan_angles_differ``)."""
    for chunk in chunks:
        if "scan_angle_rank" in chunk.attributes:
            chunk.attributes = {
                ("scan_angle" if a == "scan_angle_rank" else a): (scan_angle_units(v) if a == "scan_angle_rank" else v)
                for a, v in chunk.attributes.items()
            }
        yield chunk


def _attribute_fields(point_format) -> dict[str, str | tuple[str, int]]:
    """{attribute: record field} of a file's points: the standard fields among ``LAS_ATTRIBUTES``,
    then its extra bytes (scaled where the file gives a scale: laspy returns them as floats), in
    record order, named as the file names them but for path separators ('a/b' is read as 'a_b':
    core/chunk.safe_attribute_name); an array of k values a point (``3f8``, a normal) is k
    attributes ``name_0`` .. (field, element) (it was left out without a word); bytes the file
    does not describe are left out."""
    dims = set(point_format.dimension_names)
    fields: dict[str, str | tuple[str, int]] = {a: a for a in LAS_ATTRIBUTES if a in dims}
    for d in point_format.extra_dimensions:
        name = safe_attribute_name(d.name)
        if d.name == "ExtraBytes" or name is None:  # (ExtraBytes: laspy's name for undescribed bytes)
            continue
        if d.num_elements == 1:
            fields.setdefault(name, d.name)
        else:
            for k in range(d.num_elements):
                fields.setdefault(f"{name}_{k}", (d.name, k))
    return fields


def _header_attributes(hdr: LasHeader) -> list[str] | None:
    """``_attribute_fields`` of the header's point format and extra-bytes VLR (laspy's parse of
    the record, no file opened); None where the records hold bytes described elsewhere (an EVLR)."""
    import laspy
    from laspy.vlrs.known import ExtraBytesVlr

    fmt = laspy.PointFormat(hdr.point_format)
    for user_id, record_id, data in hdr.vlrs:
        if user_id == b"LASF_Spec" and record_id == 4:
            vlr = ExtraBytesVlr()
            try:
                vlr.parse_record_data(data)
                for param in vlr.type_of_extra_dims():
                    fmt.add_extra_dimension(param)
            except (ValueError, TypeError):  # a damaged record: told when the points are read
                return None
    return list(_attribute_fields(fmt)) if fmt.size == hdr.record_length else None


def _field_values(points, field: str | tuple[str, int]) -> np.ndarray:
    """One attribute's values (``_attribute_fields``' field) as a contiguous copy."""
    if isinstance(field, tuple):
        return np.ascontiguousarray(np.asarray(points[field[0]])[:, field[1]])
    return np.ascontiguousarray(np.asarray(points[field]))


class _RecordPlan:
    """Where a point format's values lie in its records, for ``_decode_records``: every attribute
    stored as plain little-endian bytes (1, 2, 4 or 8 of them, a bit field of one byte), grouped
    by size, and the colour channels. Scaled extra bytes (laspy computes their floats) and
    fields of other sizes stay laspy's: not in ``rows``."""

    def __init__(self, point_format, attrs: dict, has_rgb: bool):
        from laspy.point.dims import get_sub_fields_dict

        fields = point_format.dtype().fields
        subs = get_sub_fields_dict(point_format.id)
        scaled = {d.name for d in point_format.extra_dimensions if d.scales is not None or d.offsets is not None}
        specs: dict[int, list] = {1: [], 2: [], 4: [], 8: []}
        self.rows: dict[str, tuple[int, int, np.dtype]] = {}  # attribute -> (bytes, row, dtype)

        def add(size, spec, dtype) -> tuple[int, int, np.dtype]:
            specs[size].append(spec)
            return size, len(specs[size]) - 1, dtype

        for a, f in attrs.items():
            name, k = (f, 0) if isinstance(f, str) else f
            if name in subs:  # a bit field: laspy gives its bits, shifted down, as uint8
                parent, sub = subs[name]
                shift = (sub.mask & -sub.mask).bit_length() - 1
                self.rows[a] = add(1, (fields[parent][1], shift, sub.mask >> shift), np.dtype(np.uint8))
                continue
            dtype, off = fields[name][:2]
            base = dtype.base
            if name in scaled or base.itemsize not in specs or base.kind not in "biuf":
                continue
            at = off + k * base.itemsize
            self.rows[a] = add(base.itemsize, (at, 0, 0xFF) if base.itemsize == 1 else at, base)
        self.rgb = np.array([fields[c][1] for c in ("red", "green", "blue")] if has_rgb else [], np.int64)  # their own array: freed once made RGBA
        self.specs = {
            size: np.array(v, np.int64).reshape((-1, 3) if size == 1 else (-1,)) for size, v in specs.items()
        }

    def decode(self, raw, scale, offset, limits) -> tuple[np.ndarray, list, dict, int]:
        """``raw``'s positions (float64, as ``_positions``), its 16-bit colour channels (rows of
        their own array), its attributes of ``rows`` (rows of one array a size) and
        ``_first_outside`` ``limits``, in one parallel pass."""
        n = len(raw)
        rec = np.ascontiguousarray(raw).view(np.uint8).reshape(n, -1)
        xyz = np.empty((n, 3), np.float64)
        outs = {size: np.empty((len(spec), n), f"<u{size}") for size, spec in self.specs.items()}
        rgb = np.empty((len(self.rgb), n), np.uint16)
        from .las_kernels import _decode_records

        first = _decode_records(rec, scale, offset, limits, xyz, self.rgb, rgb, self.specs[1], outs[1], self.specs[2], outs[2], self.specs[4], outs[4], self.specs[8], outs[8])
        attributes = {a: outs[size][row].view(dtype) for a, (size, row, dtype) in self.rows.items()}
        return xyz, list(rgb), attributes, first if first < n else -1


def _first_outside(raw, limits: np.ndarray) -> int:
    """Index of the first record whose X, Y or Z lies outside ``limits`` (``_record_limits``), -1
    where none does: LAZ's decoder does not notice damaged bytes, it decodes them into garbage
    (integers up to ±2e9) without a word. By numpy (``_decode_records`` finds it in its pass)."""
    out = np.zeros(len(raw), bool)
    for a, axis in enumerate("XYZ"):
        out |= (raw[axis] < limits[a, 0]) | (raw[axis] > limits[a, 1])
    return int(np.argmax(out)) if out.any() else -1


#: what a header's bounds may be off by, of their widest extent (headers round them)
BOUNDS_SLACK = 0.001


def header_slack(lo, hi) -> float:
    """How far points may lie outside header bounds ``lo``..``hi`` (``BOUNDS_SLACK``): a damaged
    file's check (``_record_limits``) and a progressive load's root cube allow that much."""
    return BOUNDS_SLACK * max(float(np.max(np.asarray(hi, np.float64) - np.asarray(lo, np.float64))), 1e-9)


@dataclass
class LasHeader:
    """The fields of a LAS header gigapoint checks and reports (parsed without laspy)."""

    version: str
    point_format: int
    compressed: bool
    record_length: int
    point_count: int
    header_size: int
    offset_to_point_data: int
    number_of_vlrs: int
    scale: tuple[float, float, float]
    offset: tuple[float, float, float]
    mins: tuple[float, float, float]
    maxs: tuple[float, float, float]
    file_size: int
    start_of_first_evlr: int = 0
    number_of_evlrs: int = 0
    generating_software: str = ""
    vlrs: list[tuple[bytes, int, bytes]] = field(default_factory=list)  # (user_id, record_id, data)
    #: its EVLRs' WKT CRS record (LAS 1.4 may keep it there), as ``vlrs``: the one EVLR whose data is read
    evlrs: list[tuple[bytes, int, bytes]] = field(default_factory=list)
    #: why the file's point data ends early (read_las_header(salvage=True): a file cut off, its
    #: points before the cut readable), else None
    truncated: str | None = None
    #: why the EVLRs after the point data are not all there (a file cut before or inside them: its
    #: points read, with this warning; none of its EVLRs), else None
    evlrs_cut: str | None = None
    #: points in each LAZ chunk (its chunk table), where a damaged point's chunk is named
    laz_chunks: list[int] | None = None
    #: its global encoding bits (bit 0: gps_time is adjusted GPS standard time, not seconds of a GPS week)
    global_encoding: int = 0

    @property
    def adjusted_gps_time(self) -> bool:
        """Whether its points' gps_time is adjusted standard GPS time (seconds since the GPS epoch
        less 1e9: a date), not seconds into an unnamed GPS week (global encoding bit 0)."""
        return bool(self.global_encoding & 1)

    def crs(self) -> str | None:
        """The CRS its VLRs or EVLRs name (vlrs_crs'), None without one."""
        return vlrs_crs(self.vlrs + self.evlrs)


def _u(fmt: str, buf: bytes, off: int):
    return struct.unpack_from("<" + fmt, buf, off)


def read_las_header(path: Path, salvage: bool = False) -> LasHeader:
    """Parse and validate a LAS/LAZ header against the file size; raise InputError on any
    inconsistency. ``salvage``: a file whose point data is cut off (a LAS short of records, a
    LAZ whose chunk table at its end is gone with the tail) is not an error: ``truncated`` says
    why (the points before the cut can be read: LasReader.read_chunks(salvage=True)).
    Within ``headers_once`` a file's header is read once (callers do not change it)."""
    hdr = read_once("las", path, lambda: _read_las_header(path, salvage))
    if not salvage and hdr.truncated:  # kept from a salvaging read: refused as a plain read refuses it (EVLRs cut: read alike)
        return _read_las_header(path)
    return hdr


def truncated_header(size: int) -> str:
    """What is wrong with a LAS file of ``size`` bytes too short for any LAS header, else ''
    (a local file's and a COPC URL's alike)."""
    if size >= HEADER_SIZE[0]:
        return ""
    return f"truncated LAS header: the file has {size} bytes, a LAS header needs at least {HEADER_SIZE[0]}"


def _read_las_header(path: Path, salvage: bool = False) -> LasHeader:
    path = check_file(path)
    with open(path, "rb") as f:
        f.seek(0, 2)
        size = f.tell()
        f.seek(0)
        head = f.read(375)
        if head[:4] != b"LASF":
            raise fail(path, f"not a LAS/LAZ file (starts with {head[:4]!r}, expected b'LASF')")
        truncated = truncated_header(size)
        if truncated:
            raise fail(path, truncated)
        major, minor = head[24], head[25]
        if major != 1 or minor > 4:
            raise fail(path, f"unsupported LAS version {major}.{minor} (gigapoint reads 1.0-1.4)")
        (global_encoding,) = _u("H", head, 6)  # (LAS 1.0: reserved, 0)
        (header_size,) = _u("H", head, 94)
        offset_to_data, n_vlrs = _u("II", head, 96)
        fmt_id, record_length, legacy_count = _u("BHI", head, 104)
        scale = _u("3d", head, 131)
        offset = _u("3d", head, 155)
        mm = _u("6d", head, 179)
        need = HEADER_SIZE[minor]
        if size < need:
            raise fail(path, f"truncated LAS {major}.{minor} header: the file has {size} bytes, the header needs {need}")
        if header_size < need:
            raise fail(path, f"corrupt LAS header: header size {header_size} is smaller than LAS {major}.{minor} needs ({need})")
        if header_size > size:
            raise fail(path, f"truncated LAS file: header size {header_size} lies past the end of the file ({size} bytes)")
        compressed = bool(fmt_id & 0xC0)
        point_format = fmt_id & 0x3F
        if point_format not in RECORD_SIZE:
            raise fail(path, f"unsupported LAS point format {point_format} (gigapoint reads 0-10)")
        if record_length < RECORD_SIZE[point_format]:
            raise fail(path, f"corrupt LAS header: point record length {record_length} is smaller than point format {point_format} needs ({RECORD_SIZE[point_format]})")
        point_count = legacy_count
        start_evlr = n_evlrs = 0
        if minor >= 4:
            start_evlr, n_evlrs, count64 = _u("QIQ", head, 235)
            point_count = count64 if count64 else legacy_count
        if offset_to_data < header_size:
            raise fail(path, f"corrupt LAS header: offset to point data {offset_to_data} lies inside the {header_size}-byte header")
        if offset_to_data > size:
            raise fail(path, f"truncated LAS file: offset to point data {offset_to_data:,} lies past the end of the file ({size:,} bytes)")
        if n_vlrs * VLR_HEADER > offset_to_data - header_size:
            raise fail(path, f"corrupt LAS header: it lists {n_vlrs:,} VLRs but only {offset_to_data - header_size:,} bytes lie between header and point data")
        for axis, s, o in zip("xyz", scale, offset):
            if not math.isfinite(s) or s == 0 or abs(s) > MAX_SCALE:
                raise fail(path, f"corrupt LAS header: absurd {axis} scale {s!r} (expected a finite, non-zero value up to {MAX_SCALE:g})")
            if not math.isfinite(o) or abs(o) > MAX_ABS_COORDINATE:
                raise fail(path, f"corrupt LAS header: absurd {axis} offset {o!r} (expected a finite value within ±{MAX_ABS_COORDINATE:g})")
        # bounds at NaN or 1e300 were info's 300-digit extent, tile's count of 10^299 tiles, and
        # the output grid of convert -o x.las (scale nan): "x 63.7 lies beyond the LAS grid". Corrupt
        # is what no record can reach (its int32 times the scale, plus the offset) beyond any
        # coordinate gigapoint takes: stale and wrong bounds within it are read (they do not spoil
        # an octree), and points honestly beyond ±1e12 are said as such when read.
        for k, (name, bound) in enumerate(zip(("max x", "min x", "max y", "min y", "max z", "min z"), mm)):
            s, o = scale[k // 2], offset[k // 2]
            reach = 2**31 * abs(s) * (1 + 1e-9)
            if not math.isfinite(bound) or (abs(bound - o) > reach and abs(bound) > MAX_ABS_COORDINATE):
                raise fail(path, f"corrupt LAS header: absurd {name} {bound!r} (its records reach {o - reach:.6g}..{o + reach:.6g})")
        # VLRs: each record's length is a u16, so walking them is bounded by offset_to_data
        vlrs = []
        pos = header_size
        f.seek(pos)
        vlr_bytes = f.read(offset_to_data - header_size)
        for i in range(n_vlrs):
            rel = pos - header_size
            if rel + VLR_HEADER > len(vlr_bytes):
                raise fail(path, f"corrupt LAS file: VLR {i + 1} of {n_vlrs} runs into the point data")
            user_id = vlr_bytes[rel + 2 : rel + 18].rstrip(b"\0")
            record_id, length = _u("HH", vlr_bytes, rel + 18)
            data_start = rel + VLR_HEADER
            if data_start + length > len(vlr_bytes):
                raise fail(path, f"corrupt LAS file: VLR {i + 1} of {n_vlrs} ({length} bytes) runs into the point data")
            vlrs.append((user_id, record_id, vlr_bytes[data_start : data_start + length]))
            pos += VLR_HEADER + length
        hdr = LasHeader(
            version=f"{major}.{minor}",
            point_format=point_format,
            compressed=compressed,
            record_length=record_length,
            point_count=point_count,
            header_size=header_size,
            offset_to_point_data=offset_to_data,
            number_of_vlrs=n_vlrs,
            scale=scale,
            offset=offset,
            mins=(mm[1], mm[3], mm[5]),
            maxs=(mm[0], mm[2], mm[4]),
            file_size=size,
            start_of_first_evlr=start_evlr,
            number_of_evlrs=n_evlrs,
            generating_software=head[58:90].split(b"\0")[0].decode("ascii", "replace").strip(),
            vlrs=vlrs,
            global_encoding=global_encoding,
        )
        data_end = size
        if n_evlrs and start_evlr >= size:  # cut before its EVLRs: its points checked below, as any cut file's
            cut = f"its {n_evlrs:,} EVLRs, said to start at byte {start_evlr:,}, lie past the end of the file ({size:,} bytes)"
            hdr.evlrs_cut = _evlrs_cut(hdr, cut)
        elif n_evlrs:
            data_end = _check_evlrs(path, f, hdr)
        if compressed:
            _check_laz(path, f, hdr, salvage)
        else:
            have = data_end - offset_to_data
            need_bytes = point_count * record_length
            if need_bytes > have:
                fits = have // record_length
                hdr.truncated = (
                    f"truncated LAS file: the header claims {point_count:,} points ({need_bytes:,} bytes) "
                    f"but only {have:,} bytes of point data follow (room for {fits:,} points)"
                )
                if not salvage:
                    raise fail(path, hdr.truncated + SALVAGE_HINT)
    return hdr


def _check_evlrs(path: Path, f, hdr: LasHeader) -> int:
    """Check that every EVLR lies inside the file; return where the EVLRs start (end of point
    data). An EVLR cut off by the file's end is no error (the points before it are whole, read
    with a warning): ``hdr.evlrs_cut`` says what is missing."""
    start, n, size = hdr.start_of_first_evlr, hdr.number_of_evlrs, hdr.file_size
    if start < hdr.offset_to_point_data:
        raise fail(path, f"truncated or corrupt LAS file: {n:,} EVLRs said to start at byte {start:,} do not fit in the file ({size:,} bytes)")
    cut = None
    for i, pos, user, rec, length in evlr_headers(lambda o, k: (f.seek(o), f.read(k))[1], start, n, size):
        if length is None:
            cut = f"EVLR {i + 1} of {n:,} is cut off at byte {size:,}", f"at least {pos + EVLR_HEADER - size:,}"  # (its length unknown)
            break
        if pos + EVLR_HEADER + length > size:
            cut = f"EVLR {i + 1} of {n:,} ({length:,} bytes) runs past the end of the file ({size:,} bytes)", f"{pos + EVLR_HEADER + length - size:,}"
            break
        if (user, rec) == (PROJECTION_USER_ID, WKT_RECORD) and not hdr.evlrs:  # (only its bytes read: not a COPC hierarchy's)
            f.seek(pos + EVLR_HEADER)
            hdr.evlrs.append((user, rec, f.read(length)))
    if cut is not None:
        hdr.evlrs_cut = _evlrs_cut(hdr, f"{cut[0]}: {cut[1]} bytes missing")
    return start


def evlr_headers(read, start: int, n: int, size: int) -> Iterator[tuple[int, int, bytes, int, int | None]]:
    """(number, offset, user_id, record_id, data length) of each of the ``n`` EVLRs from byte
    ``start`` of a ``size``-byte file, their 60-byte headers read through ``read(offset, size)``
    (their data skipped: a COPC hierarchy may be large, or a request away). Ends after one whose
    header is cut off by the file's end (its length None); one whose data is cut is the caller's."""
    pos = start
    for i in range(n):  # (at most size / 60 turns: each header lies inside the file)
        if pos + EVLR_HEADER > size:
            yield i, pos, b"", 0, None
            return
        buf = read(pos, EVLR_HEADER)
        (record_id, length) = _u("HQ", buf, 18)
        yield i, pos, buf[2:18].rstrip(b"\0"), record_id, length
        pos += EVLR_HEADER + length


def _evlrs_cut(hdr: LasHeader, cut: str) -> str:
    """Why ``hdr``'s EVLRs are not all there (``cut``), said as a COPC file's where it is one
    (its COPC info VLR first): its hierarchy is an EVLR, so gigapoint reads it as plain LAZ."""
    if hdr.vlrs and hdr.vlrs[0][:2] == (b"copc", 1):
        return f"truncated COPC file: its hierarchy is cut off ({cut}), so it is read as a plain LAZ file, without its level of detail; the points are whole"
    return f"truncated LAS file: its extended VLRs are cut ({cut}); the points are whole"


@contextlib.contextmanager
def _rust_panics_unprinted():
    """fd 2 pointed at /dev/null for a short lazrs call: a panic raises a PanicException, said
    in the one-line error, but Rust's panic hook first prints it (and, with RUST_BACKTRACE, a
    backtrace) to stderr itself. Milliseconds: another thread's stderr meanwhile is lost."""
    try:
        saved, null = os.dup(2), os.open(os.devnull, os.O_WRONLY)
    except OSError:  # no fds to spare: printed, then
        yield
        return
    try:
        os.dup2(null, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(null)


def _check_laz(path: Path, f, hdr: LasHeader, salvage: bool = False) -> None:
    """Check a LAZ file's chunk table against the file size and the header's point count
    (``salvage``: a table past the end of the file, in chunks of a fixed size, is a file cut
    off: ``hdr.truncated``)."""
    import lazrs

    laszip = [d for u, r, d in hdr.vlrs if u == LASZIP_USER_ID and r == LASZIP_RECORD_ID]
    if not laszip:
        raise fail(path, "corrupt LAZ file: compressed point format but no LASzip VLR")
    vlr_data = laszip[0]
    if len(vlr_data) < 34:
        raise fail(path, f"corrupt LAZ file: LASzip VLR has {len(vlr_data)} bytes, expected at least 34")
    (chunk_size,) = _u("I", vlr_data, 12)
    start = hdr.offset_to_point_data
    end = hdr.start_of_first_evlr if hdr.number_of_evlrs and hdr.start_of_first_evlr > start else hdr.file_size
    if hdr.point_count == 0:
        return
    if start + 8 > end:
        raise fail(path, f"truncated LAZ file: no compressed point data after byte {start:,} (file has {hdr.file_size:,} bytes)")
    f.seek(start)
    (table_offset,) = _u("q", f.read(8), 0)
    if table_offset == -1:  # written by a streaming writer: the offset is in the last 8 bytes
        f.seek(hdr.file_size - 8)
        (table_offset,) = _u("q", f.read(8), 0)
    if table_offset > hdr.file_size - 8 and chunk_size != 0xFFFFFFFF:  # (variable chunks: the table tells their points)
        hdr.truncated = f"truncated or corrupt LAZ file: chunk table offset {table_offset:,} lies past the end of the file ({hdr.file_size:,} bytes)"
        if not salvage:
            raise fail(path, hdr.truncated + SALVAGE_HINT)
        return
    if table_offset > hdr.file_size - 8 and start + 8 <= table_offset:  # (a COPC file's nodes: each chunk's points are in the table only)
        raise fail(path, f"truncated LAZ file: its chunk table (at byte {table_offset:,}) lies past the end of the file ({hdr.file_size:,} bytes), "
                         "and its chunks are of variable size: without the table no point can be read")  # fmt: skip
    if not start + 8 <= table_offset <= hdr.file_size - 8:
        raise fail(path, f"truncated or corrupt LAZ file: chunk table offset {table_offset:,} lies outside the file's point data (bytes {start + 8:,}..{hdr.file_size:,})")
    f.seek(table_offset)
    _version, n_chunks = _u("II", f.read(8), 0)
    min_chunk_bytes = RECORD_SIZE[hdr.point_format]  # each chunk starts with one raw point
    max_chunks = (table_offset - start - 8) // min_chunk_bytes + 1
    if n_chunks > max_chunks:
        raise fail(path, f"corrupt LAZ file: chunk table lists {n_chunks:,} chunks, the compressed data has room for at most {max_chunks:,}")
    f.seek(start)
    try:
        with _rust_panics_unprinted():
            table = lazrs.read_chunk_table(f, lazrs.LazVlr(vlr_data))
    except BaseException as exc:  # lazrs.LazrsError, OSError, a panic...: a corrupt table, said in one line
        if not laz_process.bad_data(exc):
            raise
        raise fail(path, f"corrupt LAZ chunk table: {one_line(exc) or type(exc).__name__}") from None
    if table is None:
        return
    counts = hdr.laz_chunks = [int(c[0]) for c in table]
    sizes = [int(c[1]) for c in table]
    if sum(sizes) > table_offset - start:  # chunks lie between the 8-byte table offset and the table
        raise fail(path, f"truncated LAZ file: the chunk table lists {sum(sizes):,} bytes of compressed points, only {table_offset - start:,} are present")
    if chunk_size != 0xFFFFFFFF:
        capacity = len(table) * chunk_size
    else:
        capacity = sum(counts)
    if hdr.point_count > capacity:
        raise fail(path, f"truncated or corrupt LAZ file: the header claims {hdr.point_count:,} points but the compressed chunks hold at most {capacity:,}")


def _record_limits(hdr: LasHeader) -> np.ndarray:
    """(3, 2) int64: the least and greatest stored X, Y, Z the header's bounds allow: twice an
    axis's extent wider each way (at least ``header_slack``), and half a scale step; every int32 where
    the bounds are none to go by (not finite, min above max, all 0: never filled in, or out of
    the integers' reach). So wide because a header's bounds may be stale (a writer that did not
    update them): such a file reads as other tools read it, where damaged LAZ bytes decode into
    points kilometres away (integers up to ±2e9)."""
    lo, hi = np.array(hdr.mins), np.array(hdr.maxs)
    every = np.array([[-(2**31), 2**31 - 1]] * 3, np.int64)
    if not (np.all(np.isfinite(lo) & np.isfinite(hi) & (lo <= hi)) and (lo.any() or hi.any())):
        return every
    scale, offset = np.array(hdr.scale), np.array(hdr.offset)
    pad = np.abs(scale) / 2 + np.maximum(2 * (hi - lo), header_slack(lo, hi))  # (2: a mirrored axis's stale bounds)
    ends = np.sort([(lo - pad - offset) / scale, (hi + pad - offset) / scale], axis=0)
    if np.any(ends[0] > 2**31 - 1) or np.any(ends[1] < -(2**31)):
        return every
    return np.stack([np.ceil(ends[0]), np.floor(ends[1])], 1).clip(every[0, 0], every[0, 1]).astype(np.int64)


def _outside_bounds(kind: str, hdr: LasHeader, record, i: int, scale, offset, limits) -> str:
    """What ``read_chunks`` says of point ``i`` (``record``), found outside the header's bounds."""
    a = next(a for a, axis in enumerate("XYZ") if not limits[a, 0] <= record[axis] <= limits[a, 1])
    first, end = _damaged_span(hdr, i)
    span = f"; its LAZ chunk, points {first:,}..{end - 1:,}, is damaged" if hdr.compressed else ""
    return (
        f"corrupt {kind} point data: point {i:,} lies far outside the header's bounds "
        f"({'xyz'[a]} {record['XYZ'[a]] * scale[a] + offset[a]:,.3f}, bounds {hdr.mins[a]:,.3f}..{hdr.maxs[a]:,.3f}){span}"
    )


def _damaged_span(hdr: LasHeader, i: int) -> tuple[int, int]:
    """(first, end) of the points a damage found at point ``i`` may have spoilt: its LAZ chunk
    (chunks decode apart; the chunk table's, else the LASzip VLR's fixed size), a LAS record alone."""
    if not hdr.compressed:
        return i, i + 1
    if hdr.laz_chunks:
        ends = np.cumsum(hdr.laz_chunks)
        k = min(int(np.searchsorted(ends, i, side="right")), len(ends) - 1)
        return int(ends[k]) - hdr.laz_chunks[k], int(ends[k])
    size = next(_u("I", d, 12)[0] for u, r, d in hdr.vlrs if u == LASZIP_USER_ID and r == LASZIP_RECORD_ID)
    return i - i % size, i - i % size + size


class _Las10AsLas11(io.RawIOBase):
    """A LAS 1.0 file seen as 1.1 (same header layout and point formats 0-1): laspy reads 1.1-1.4 only."""

    def __init__(self, path: Path):
        self._f = open(path, "rb")  # noqa: SIM115 - closed by close()

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def seek(self, pos: int, whence: int = 0) -> int:
        return self._f.seek(pos, whence)

    def tell(self) -> int:
        return self._f.tell()

    def readinto(self, b) -> int:
        pos = self._f.tell()
        n = self._f.readinto(b)
        if n and pos <= 25 < pos + n:
            memoryview(b)[25 - pos] = 1
        return n

    def close(self) -> None:
        self._f.close()
        super().close()


#: the file laspy is reading in this context (``_laspy_reports``), None where gigapoint is not reading one
_laspy_file: ContextVar[str | None] = ContextVar("gigapoint_laspy_file", default=None)


class _LaspyRecordsAsWarnings(logging.Handler):
    """laspy's log records about a file gigapoint reads (a VLR it cannot parse: "Failed to parse
    ... GeoKeyDirectoryVlr ...", points it could not read) as gigapoint warnings naming the file,
    ``FILE: laspy: MESSAGE``, each once an operation (``read_once``: convert opens a file twice),
    issued where gigapoint's warnings are (a progressive load's wait: ``errors.warn``). They were
    lost (laspy's NullHandler keeps Python's last-resort printing off), or where the user set up
    logging, printed without the file's name, from the thread that read it, once per open. It
    is added beside the handlers on laspy's logger and its parents and stops none of them: a
    user's logging gets laspy's records as before."""

    def emit(self, record: logging.LogRecord) -> None:
        path = _laspy_file.get()
        if path is None:  # laspy used by other code (the user's own, a write): left to logging
            return
        message = f"{path}: laspy: {record.getMessage()}"
        read_once("laspy log", message, lambda: warn(message, GigapointWarning))


_LASPY_RECORDS = _LaspyRecordsAsWarnings(logging.WARNING)


@contextlib.contextmanager
def _laspy_reports(path):
    """laspy's log records in the block are warnings about ``path`` (``_LaspyRecordsAsWarnings``).
    Only around laspy's own calls, none that yields: the file is this context's, a generator's
    consumer does not see it."""
    # (added again where a logging.config call removed it; addHandler adds it once)
    logging.getLogger("laspy").addHandler(_LASPY_RECORDS)
    token = _laspy_file.set(str(path))
    try:
        yield
    finally:
        _laspy_file.reset(token)


def _laspy_header(path: Path):
    """laspy's header of the file (its point format, scales, offsets), its points left unopened."""
    import laspy

    with open(path, "rb") as f, _laspy_reports(path):
        return laspy.LasHeader.read_from(f)


def _laspy_open(path: Path, hdr: LasHeader):
    """laspy's reader of the file; its EVLRs read only where they are all there (a file cut
    before them is read up to the cut: read_las_header(salvage=True))."""
    import laspy

    with _laspy_reports(path):
        if hdr.version == "1.0":
            return laspy.open(io.BufferedReader(_Las10AsLas11(path)), closefd=True)
        return laspy.open(str(path), read_evlrs=hdr.evlrs_cut is None)


PROJECTION_USER_ID = b"LASF_Projection"
WKT_RECORD = 2112
GEOKEYS_RECORD = 34735


def wkt_of(vlrs) -> str | None:
    """The WKT CRS of a LAS 1.4 file's VLRs ((user_id, record_id, data) each: LASF_Projection 2112), None without one."""
    for user, rec, data in vlrs:
        if user == PROJECTION_USER_ID and rec == WKT_RECORD:
            text = data.split(b"\0")[0].decode("utf-8", "replace").strip()
            if text:
                return text
    return None


#: VerticalCSTypeGeoKey values of GeoTIFF 1.0's own list that are no EPSG vertical CRS (5001-5033:
#: heights above an ellipsoid; 5101-5106: EPSG's codes of datums, or of other CRSs, since): GDAL
#: leaves them out of the CRS too
GEOTIFF10_VERTICAL_CODES = (range(5001, 5034), range(5101, 5107))


EPSG_LENGTH_UNITS = {9001: ("metre", 1.0), 9002: ("foot", 0.3048), 9003: ("US survey foot", 1200 / 3937)}


def vlrs_crs(vlrs) -> str | None:
    """The CRS VLRs name (as wkt_of's): their WKT, else 'EPSG:n' of their GeoTIFF keys' projected
    or geographic CRS code, 'EPSG:n+v' where VerticalCSTypeGeoKey names the heights' vertical
    CRS v as well (pyproj reads that compound CRS; a user-defined one leaves its unit to
    VerticalUnitsGeoKey: io.crs_units), v in VerticalUnitsGeoKey's unit where that is another
    (``vertical_in_unit``); None without either."""
    wkt = wkt_of(vlrs)
    if wkt:
        return wkt
    keys = geokeys(vlrs)
    horizontal = next((keys[k] for k in (3072, 2048) if 0 < keys.get(k, 0) < 32767), None)  # Projected-, GeographicTypeGeoKey (32767: user-defined)
    if horizontal is None:
        return None
    vertical = keys.get(4096, 0)
    if 0 < vertical < 32767 and not any(vertical in codes for codes in GEOTIFF10_VERTICAL_CODES):
        return vertical_in_unit(horizontal, vertical, keys.get(4099))
    return f"EPSG:{horizontal}"


@functools.lru_cache(maxsize=256)  # (pyproj's look-ups take ~18 ms; each header read asks again)
def vertical_in_unit(horizontal: int, vertical: int, unit: int | None) -> str:
    """'EPSG:h+v', where the EPSG length ``unit`` (VerticalUnitsGeoKey) is not v's own: 'EPSG:h+w' of
    the EPSG vertical CRS w of v's datum and axis in that unit (NAVD88 height in US feet: 6360),
    else the compound's WKT with v's axis in that unit (heights in feet read as metres were
    converted as metres). Without pyproj, 'EPSG:h+v' (nothing converts heights then)."""
    text = f"EPSG:{horizontal}+{vertical}"
    if unit not in EPSG_LENGTH_UNITS:
        return text
    try:
        import pyproj
    except ImportError:
        return text
    try:
        own = pyproj.CRS.from_epsg(vertical)
    except pyproj.exceptions.CRSError:
        return text
    if not own.is_vertical or own.axis_info[0].unit_code == str(unit):
        return text
    other = _epsg_vertical_in_unit(pyproj, vertical, unit)
    if other is not None:
        return f"EPSG:{horizontal}+{other}"
    moved = own.to_json_dict()
    name, metres = EPSG_LENGTH_UNITS[unit]
    moved["coordinate_system"]["axis"][0]["unit"] = {"type": "LinearUnit", "name": name, "conversion_factor": metres, "id": {"authority": "EPSG", "code": unit}}
    moved["name"] = f"{own.name} ({name})"
    moved.pop("id", None)  # (no longer EPSG's v)
    flat = pyproj.CRS.from_epsg(horizontal)
    compound = pyproj.CRS.from_json_dict({"type": "CompoundCRS", "name": f"{flat.name} + {moved['name']}", "components": [flat.to_json_dict(), moved]})
    return compound.to_wkt()


def _epsg_vertical_in_unit(pyproj, vertical: int, unit: int) -> int | None:
    """The EPSG vertical CRS of EPSG ``vertical``'s datum and axis direction in EPSG length ``unit``
    (PROJ's database), None where EPSG has none."""
    import sqlite3

    database = os.path.join(pyproj.datadir.get_data_dir(), "proj.db")
    query = """SELECT v.code FROM vertical_crs v, axis a, vertical_crs s, axis sa
        WHERE s.auth_name = 'EPSG' AND s.code = ? AND sa.coordinate_system_auth_name = s.coordinate_system_auth_name
        AND sa.coordinate_system_code = s.coordinate_system_code AND v.auth_name = 'EPSG' AND v.deprecated = 0
        AND v.datum_auth_name = s.datum_auth_name AND v.datum_code = s.datum_code
        AND a.coordinate_system_auth_name = v.coordinate_system_auth_name AND a.coordinate_system_code = v.coordinate_system_code
        AND a.orientation = sa.orientation AND a.uom_auth_name = 'EPSG' AND a.uom_code = ? ORDER BY v.code"""
    try:
        with contextlib.closing(sqlite3.connect(f"file:{database}?mode=ro", uri=True)) as db:
            row = db.execute(query, (str(vertical), str(unit))).fetchone()
    except sqlite3.Error:
        return None
    return int(row[0]) if row else None


def geokeys(vlrs) -> dict[int, int]:
    """The GeoTIFF keys of LAS VLRs (LASF_Projection 34735) whose values are held in place
    (EPSG codes of a CRS, of a unit): {key id: value}; empty without them."""
    for user, rec, data in vlrs:
        if user == PROJECTION_USER_ID and rec == GEOKEYS_RECORD and len(data) >= 8:
            n = min(_u("H", data, 6)[0], len(data) // 8 - 1)  # (the key count after 3 version words)
            return {k: value for k, loc, _, value in struct.iter_unpack("<4H", data[8 : 8 + 8 * n]) if loc == 0}
    return {}


def _parse_crs(header, hdr: LasHeader) -> str | None:
    """CRS of a file as ``hdr.crs()`` says it (gigapoint's header parse, as warn_mixed_crs and
    convert see it: the file's own WKT, else 'EPSG:n' or 'EPSG:n+v' of its GeoTIFF keys); where that finds none,
    pyproj's reading of laspy's header ('EPSG:n' or WKT) when pyproj is installed. The file's own
    words come first so that info, .prj files and GeoTIFF keys are the same with pyproj or without
    (pyproj's 'EPSG:32610' for a WKT dropped its name and its exact text)."""
    own = hdr.crs()
    if own:
        return own
    try:
        import pyproj
    except ImportError:
        pyproj = None
    if pyproj is not None:
        try:
            crs = header.parse_crs()
        except Exception:  # noqa: BLE001 - an unreadable CRS leaves the points readable: 'unknown'
            crs = None
        if crs is not None:
            epsg = crs.to_epsg()
            return f"EPSG:{epsg}" if epsg else crs.to_wkt()
    return None


def prepare_kernel_calls() -> None:
    """core/threads.py's ``prepare_kernel_calls`` (numba imported only where a kernel is to run)."""
    from ..core.threads import prepare_kernel_calls as prepare

    prepare()


def _positions(raw, scale, offset) -> np.ndarray:
    """float64 (N, 3) positions of records (fields X, Y, Z) by numpy, for files up to
    ``NUMPY_MAX`` points (milliseconds; a small file's first open compiles no kernel). Larger
    ones are ``_decode_records``': the same operations, so the same values."""
    xyz = np.empty((len(raw), 3), np.float64)
    for a, axis in enumerate("XYZ"):
        np.add(raw[axis] * scale[a], offset[a], out=xyz[:, a])
    return xyz


def _colors(r, g, b, scaler) -> np.ndarray:
    """Opaque 8-bit RGBA (N, 4) of 16-bit record colors (``ColorScaler`` picks the shift from
    the largest value seen); numpy up to ``NUMPY_MAX`` points, the parallel kernel beyond."""
    n = len(r)
    shift = scaler.int_shift(int(max(r.max(), g.max(), b.max())) if n else 0)
    rgba = np.empty((n, 4), np.uint8)
    if n <= NUMPY_MAX:
        for a, v in enumerate((r, g, b)):
            rgba[:, a] = np.minimum(v >> np.uint16(shift), 255)
        rgba[:, 3] = 255
    else:
        from .las_kernels import _rgb8

        _rgb8(r, g, b, shift, rgba)
    return rgba


class _Records:
    """The next point records of an open laspy reader, into one byte buffer reused chunk after
    chunk: laspy's ``read_points`` gives each chunk a new zeroed ``bytearray``, and its first
    writes to new pages took 0.3 s of reading 20 M points (the records alone: LAS 0.55-0.72 s -> 0.20-0.32 s, LAZ
    4.9 -> 4.6 s). The records of one ``read`` are valid until the next. Point sources other
    than lazrs's decompressor and a readable file (none that laspy makes today) keep laspy's way."""

    def __init__(self, reader, most: int):
        import laspy

        self.reader = reader
        self.point_format = reader.header.point_format
        self.record = laspy.PackedPointRecord
        self.size = self.point_format.size
        source = reader.point_source
        decompressor = getattr(source, "decompressor", None)
        readinto = getattr(getattr(source, "source", None), "readinto", None)
        if decompressor is not None:  # laspy's lazrs backend
            self.fill = lambda view: decompressor.decompress_many(view) or len(view)
        elif type(source).__name__ == "UncompressedPointReader" and readinto is not None:
            self.fill = readinto  # bytes read: short at the end of a truncated file
        else:
            self.fill = None
        self.buffer = pages.empty(most * self.size if self.fill else 0, np.uint8)

    def close(self) -> None:
        """Nothing to free (the buffer goes with this object); ``ChildRecords`` stops its process."""

    def read(self, n: int):
        """Up to ``n`` records (fewer where the file ends early), as a laspy PackedPointRecord."""
        if self.fill is None:
            return self.reader.read_points(n)
        view = memoryview(self.buffer)[: n * self.size]
        got = int(self.fill(view)) // self.size
        return self.record(np.frombuffer(self.buffer, self.point_format.dtype(), count=got), self.point_format)


class LasReader(Reader):
    name = "LAS/LAZ"
    suffixes = (".las", ".laz")

    def sniff(self, head: bytes) -> bool:
        return head[:4] == b"LASF"

    def point_count(self, path: Path) -> int | None:
        return read_las_header(path).point_count

    def header(self, path: Path, salvage: bool = False) -> dict:
        hdr = read_las_header(path, salvage)  # (info opens the file with laspy too: its VLRs, CRS, dimensions)
        head = {"point_count": hdr.point_count, "bounds": (list(hdr.mins), list(hdr.maxs)), "offset": list(hdr.offset), "scale": list(hdr.scale)}
        attributes = _header_attributes(hdr)
        if attributes is not None:
            head["attributes"] = attributes
        return head if hdr.truncated is None else {**head, "truncated": hdr.truncated}  # (EVLRs cut: every point read, with a warning)

    def reads_slowly(self, path: Path) -> bool:
        return read_las_header(path).compressed  # LAZ: decompression, ~0.3 us a point on 2 cores

    #: ``read_chunks`` takes ``start``/``stop``/``scaler``: one file read in parts (lod/convert/distributed.py)
    reads_ranges = True

    def read_chunks(
        self,
        path: Path,
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        *,
        start: int = 0,
        stop: int | None = None,
        scaler: ColorScaler | None = None,
        salvage: bool = False,
    ) -> Iterator[PointChunk]:
        """Chunks of points ``start``..``stop`` (default: all) of the file. ``scaler``: the color
        decision of the points before ``start`` (a new one by default); it is updated chunk by chunk.
        ``salvage``: a file cut off yields the points before the cut, then its error (read_salvaged)."""
        chunk_size = check_chunk_size(chunk_size)
        hdr = read_las_header(path, salvage)
        cut_laz = hdr.truncated is not None and hdr.compressed  # no chunk table: laspy cannot open its points
        kind = "LAZ" if hdr.compressed else "LAS"
        if hdr.point_count == 0:
            raise fail(path, f"{kind} file holds no points (header point count is 0)", EmptyCloudError)
        stop = hdr.point_count if stop is None else min(stop, hdr.point_count)
        done = start

        def corrupt(exc: Exception) -> InputError:
            # nothing given yet: where the decoder failed is not known (a small LAZ is decoded whole
            # by a child), and "after 0" read as if the first point were bad
            where = f" after {done:,} of the {hdr.point_count:,} points the header claims" if done > start else f"; the header claims {hdr.point_count:,} points"
            return fail(path, f"truncated or corrupt {kind} point data: reading failed{where} ({one_line(exc) or type(exc).__name__})")

        # only laspy's and lazrs's work is in the try blocks: an error of the decoding below
        # (a kernel that fails to compile, say) is not the file's and keeps its own message
        with contextlib.ExitStack() as stack:
            try:
                if cut_laz:
                    if start or not laz_process.available():  # only a child decodes a file without its table
                        raise fail(path, hdr.truncated)
                    reader, decompressor, in_child = None, None, True
                    header = _laspy_header(path)
                else:
                    reader = stack.enter_context(_laspy_open(path, hdr))
                    header = reader.header
                if header.point_count != hdr.point_count:  # LAS 1.4 with only the legacy count filled in (before laspy
                    header.point_count = hdr.point_count  # makes its point source: of 0 points, an empty one)
                if reader is not None:
                    decompressor = getattr(reader.point_source, "decompressor", None)
                    in_child = hdr.compressed and laz_process.usable(decompressor)
                dims = set(header.point_format.dimension_names)
                scale = np.asarray(header.scales, np.float64)
                offset = np.asarray(header.offsets, np.float64)
                if start and not in_child:  # (a child seeks itself)
                    reader.seek(start)
            except (InputError, MemoryError, GigapointWarning):  # (a warning: laspy's record, made an error by -W error)
                raise
            except BaseException as exc:  # laspy / lazrs / OS errors (and lazrs's panics) on corrupt data
                if not laz_process.bad_data(exc):
                    raise
                raise corrupt(exc) from None
            attrs = _attribute_fields(header.point_format)
            has_rgb = {"red", "green", "blue"} <= dims
            stored_scale = tuple(float(abs(s)) for s in scale)  # PointChunk.scale: the resolution the file stores
            scaler = ColorScaler() if scaler is None else scaler
            most = min(chunk_size, stop - done)
            records = plan = None
            if in_child:  # decoded by a child process (io/laz_process.py: a crash of lazrs is an error there, and no GIL is held)
                laszip = next(d for u, r, d in hdr.vlrs if u == LASZIP_USER_ID and r == LASZIP_RECORD_ID)
                parallel = type(decompressor).__name__ == "ParLasZipDecompressor"
                if not cut_laz and (start, stop) == (0, hdr.point_count):  # a small file: by the child all files share
                    records = laz_process.decode_file(path, hdr.file_size, hdr.offset_to_point_data, laszip, stop, header.point_format, parallel)
                with contextlib.suppress(OSError):  # no process or memory to be had: decoded here, as below
                    records = records if records is not None else laz_process.ChildRecords(
                        path, hdr.offset_to_point_data, laszip, done, stop, most, header.point_format, parallel,
                        cut=hdr.file_size if cut_laz else None,
                    )  # fmt: skip
                if records is None and cut_laz:
                    raise fail(path, hdr.truncated)
                if records is None and start:
                    reader.seek(start)
            if records is None:
                records = _Records(reader, most)
            stack.callback(records.close)
            if stop - start > NUMPY_MAX and isinstance(records, laz_process.ChildRecords):
                prepare_kernel_calls()  # the decoding kernel's first call sets numba up: now, while the child decodes
            limits, damage = _record_limits(hdr), None
            while done < stop:
                try:
                    with _laspy_reports(path):  # (laspy's reader: "Could only read n of the requested m points")
                        pts = records.read(min(chunk_size, stop - done))
                except (InputError, MemoryError, GigapointWarning):
                    raise
                except BaseException as exc:  # as above
                    if not laz_process.bad_data(exc):
                        raise
                    if cut_laz:  # the cut, found: the points before it were given
                        raise fail(path, f"{hdr.truncated}: {done:,} of its {hdr.point_count:,} points read") from None
                    raise corrupt(exc) from None
                n = len(pts)
                if n == 0:
                    break
                raw = pts.array  # the records as read (valid until the next read)
                large = stop - start > NUMPY_MAX  # one parallel pass over the records (chunks of any size: a progressive load's are small)
                if large:
                    plan = plan or _RecordPlan(header.point_format, attrs, has_rgb)
                    xyz, rgb, decoded, bad = plan.decode(raw, scale, offset, limits)
                else:
                    bad = _first_outside(raw, limits)
                if bad >= 0:  # damage: the points before its LAZ chunk are given, then the error
                    damage = _outside_bounds(kind, hdr, raw[bad], done + bad, scale, offset, limits)
                    pts = pts[: max(0, _damaged_span(hdr, done + bad)[0] - done)]
                    raw, n = pts.array, len(pts)
                    if n == 0:
                        break
                    if large:  # (those kept, decoded again: rare)
                        xyz, rgb, decoded, _ = plan.decode(raw, scale, offset, limits)
                if large:
                    rgba = _colors(*rgb, scaler) if has_rgb else None
                    attributes = {a: decoded[a] if a in decoded else _field_values(pts, f) for a, f in attrs.items()}
                else:  # numpy and laspy, a field at a time: a small file's first open compiles no kernel
                    xyz = _positions(raw, scale, offset)
                    rgba = _colors(raw["red"], raw["green"], raw["blue"], scaler) if has_rgb else None
                    # copies (a field of the records is a strided view of the reused buffer, a bit field a new array)
                    attributes = {a: _field_values(pts, f) for a, f in attrs.items()}
                done += n
                color_bits = (16 if scaler.mode == "16" else 8) if has_rgb else None  # (a save writes them back so)
                yield PointChunk(xyz, rgba, attributes, scale=stored_scale, color_bits=color_bits)
                if damage is not None:
                    break
        if damage is not None:  # (the child stopped with the reader: it decodes no garbage for nothing)
            raise fail(path, f"{damage}: {done:,} of the {hdr.point_count:,} points read")
        if done < stop:
            raise fail(path, f"truncated {kind} file: the header claims {hdr.point_count:,} points, only {done:,} could be read")
        if hdr.evlrs_cut is not None and stop == hdr.point_count:  # every point there, the EVLRs after them cut off
            warn(f"{path}: {hdr.evlrs_cut}", GigapointWarning)

    def read_salvaged(self, path: Path, chunk_size: int = DEFAULT_CHUNK_SIZE) -> Iterator[PointChunk]:
        return self.read_chunks(path, chunk_size, salvage=True)

    def info(self, path: Path) -> dict:
        hdr = read_las_header(path)
        if hdr.evlrs_cut is not None:  # (its VLRs shown, not its EVLRs)
            warn(f"{path}: {hdr.evlrs_cut}", GigapointWarning)
        try:
            with _laspy_open(path, hdr) as reader:
                header = reader.header
                dims = list(header.point_format.dimension_names)
                crs = _parse_crs(header, hdr)
                creation = header.creation_date.isoformat() if header.creation_date else None
        except (InputError, GigapointWarning):  # (as read_chunks)
            raise
        except BaseException as exc:  # laspy raises many types on corrupt headers (lazrs panics too)
            if not laz_process.bad_data(exc):
                raise
            raise fail(path, f"corrupt {'LAZ' if hdr.compressed else 'LAS'} header: {exc}") from None
        attrs = list(_attribute_fields(header.point_format))
        return {
            "path": str(path),
            "format": "LAZ" if hdr.compressed else "LAS",
            "point_count": hdr.point_count,
            "bounds": {"min": list(hdr.mins), "max": list(hdr.maxs)},
            "bounds_source": "header",
            "has_color": {"red", "green", "blue"} <= set(dims),
            "attributes": attrs,
            "dimensions": dims,
            "las_version": hdr.version,
            "point_format": hdr.point_format,
            "point_record_length": hdr.record_length,
            "scale": list(hdr.scale),
            "offset": list(hdr.offset),
            "crs": crs,
            "generating_software": hdr.generating_software,
            "creation_date": creation,
            "file_size": hdr.file_size,
        }
