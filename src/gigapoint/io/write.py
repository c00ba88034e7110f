"""Writing points to a LAS, LAZ or PLY file, chunk by chunk: a cloud's ``save`` (core/cloud.py,
through ``save_cloud``) and a live cloud's (live/save.py) share these writers.

The points come as a function giving their ``PointChunk``s (called once a pass: the PLY writer
looks at 64-bit integer attributes first), so no writer holds more than a chunk beyond what the
cloud holds. Files appear under their name only once whole (atomic.atomic_write); an existing
file is replaced only with ``overwrite``; every failure is a one-line InputError naming the file."""

from __future__ import annotations

import contextlib
import dataclasses
import os
import shutil
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from ..atomic import atomic_write, folders_for, nearest_folder, output_file_refusal, refuse, write_failure
from ..core.chunk import PointChunk
from ..core.cloud import PointCloud, set_cloud_writer
from ..errors import GigapointWarning, InputError, first_line, warn
from .crs import crs_name, crs_wkt, first_named_crs, own_epsg
from .las import GEOKEYS_RECORD, PROJECTION_USER_ID, WKT_RECORD, LasReader, read_las_header, vlrs_crs, wkt_of
from .las_fields import LAS_FIELD_OF, choose_point_format, extra_attributes, field_attributes, las_field_values, las_grid, warn_clipped
from .paths import is_copc_name
from .ply import PLY_CRS_COMMENT
from .registry import reader_for

#: the point files ``write_points`` writes, by suffix
POINT_FILE_SUFFIXES = (".las", ".laz", ".ply")
#: a GeoTIFF CRS's records: the keys and their double and ASCII parameters
_GEOTIFF_RECORDS = (GEOKEYS_RECORD, 34736, 34737)

Chunks = Callable[[], Iterable[PointChunk]]


def check_point_file_output(path: Path, overwrite: bool) -> None:
    """Refuse, in one line naming ``path``, a point file that cannot be written there: a folder
    (overwrite=True was os.replace's IsADirectoryError: a folder is never replaced by a file), an
    existing file without ``overwrite``, a path through a file, a folder not writable. Folders
    missing on the way are made as it is written (``write_points``), as they are for an octree's
    folder or a COPC file: save("out/t.copc.laz") made out/, save("out/t.laz") refused it."""
    if is_copc_name(path):  # (save, classify_noise, ... wrote a plain LAZ under a COPC's name: no COPC reader opened it as one)
        raise InputError(f"{path}: a COPC file is an octree, not a plain LAZ file: name it .laz, or write the COPC with gigapoint.convert(..., {str(path)!r})")
    suffix = path.suffix.lower()  # (named where it is one written: a folder 'out' was "not a  file")
    what = f"a {suffix[1:].upper()} file" if suffix in POINT_FILE_SUFFIXES else "a point file"
    refuse(path, output_file_refusal(path, overwrite, f"{what}; not replaced"), InputError)


def las_color_bits(source_bits: int | None) -> int:
    """The ``color_bits`` a cloud's save writes with, of its source's (``source_color_bits``):
    8 where the source stored 8-bit values (kept as they were), else LAS's own 16."""
    return 8 if source_bits == 8 else 16


def write_points(
    path: Path, chunks: Chunks, n_points: int | None, *, grid=None, crs_records=(), color_bits: int | None = 16, has_color: bool = True
) -> int:
    """Write the ``n_points`` points of ``chunks()`` to ``path`` (checked by ``check_point_file_output``), as its suffix
    says: .las/.laz (LAS 1.4 point format 7, 8 with ``nir``; 6 where not ``has_color``: points whose
    source had no colours get none, not the grey they are drawn in; ``grid``: the (scale, offset) to store
    positions on, else one fine enough for their bounds; ``crs_records``: (user id, record id,
    data) VLRs naming their CRS; ``color_bits``: 16 stores 8-bit colours x 257, 8 as they are, as a
    file of 8-bit values in 16-bit fields had them; None: as each chunk says, its ``color_bits``,
    16 where it does not) or .ply (red, green, blue only ``has_color``; the CRS the records name in a
    ``comment crs`` header line, PLY having no field of its own for one). ``n_points`` None: not known before the points are read (a
    filter's, files': a PLY header's count is written once they are). The first chunk's attributes
    (names and dtypes) stand for every chunk's. Returns the points written."""
    from lazrs import LazrsError

    suffix = path.suffix.lower()
    written = 0

    def flat_chunks() -> Iterable[PointChunk]:
        return (dataclasses.replace(chunk, attributes=one_value_a_point(chunk.attributes)) for chunk in chunks())

    def write(tmp: Path) -> None:
        nonlocal written
        if suffix == ".ply":
            written = _write_ply(tmp, path, flat_chunks, n_points, has_color, _ply_crs(path, vlrs_crs(crs_records)))
        else:
            written = _write_las(tmp, path, flat_chunks, grid, crs_records, color_bits, has_color)

    try:
        with folders_for(path):  # (those missing: check_point_file_output; removed if the write fails)
            atomic_write(path, write)
    except (OSError, LazrsError) as exc:  # a full disk: lazrs said "IoError: Failed to call write", naming no file, not an OSError
        reason = write_failure(exc) if isinstance(exc, OSError) else first_line(exc)
        if not isinstance(exc, OSError) and "Failed to call" in reason:  # lazrs names no cause: the disk's room tells a full one
            reason += f"; {shutil.disk_usage(nearest_folder(path.parent)).free:,} bytes free on its disk"
        raise InputError(f"{path}: not written ({reason}); nothing was left there") from None
    return written


def one_value_a_point(attributes: dict) -> dict:
    """``attributes`` with one of k values a point (an NPZ's (N, 3) ``normals``) as k columns:
    ``nx``, ``ny``, ``nz`` for normals (as PLY files and the renderer name them), else ``name_0``
    .. (as the LAS reader names an extra bytes array's). A file's fields hold one value a point:
    such an attribute was numpy's "could not broadcast input array" traceback; an octree
    conversion (lod/convert/read.py ``valid_chunk``) left it out without a word. A column whose
    name an attribute has already is left to that attribute."""
    out = {a: v for a, v in attributes.items() if v.ndim == 1}
    for a, v in attributes.items():
        if v.ndim == 1:
            continue
        columns = v.reshape(len(v), -1).T
        names = ("nx", "ny", "nz") if a in ("normal", "normals") and len(columns) == 3 else [f"{a}_{k}" for k in range(len(columns))]
        for name, column in zip(names, columns):
            out.setdefault(name, column)
    return out


#: no point: what a writer given no chunk at all writes (a header, no record)
_NO_POINTS = PointChunk(np.empty((0, 3)))


def _las_layout(path: Path, attributes: dict, grid, crs_records, has_color: bool) -> tuple:
    """(laspy header, {attribute: its point format field}, {attribute: extra bytes dtype}) of a
    file of points with ``attributes`` ({name: values}, the first chunk's): point format 7 (8 with
    ``nir``; 6 without ``has_color``, nir then in extra bytes), LAS 1.4, the (scale, offset) ``grid`` and the CRS records."""
    import laspy

    attrs = {a: v.dtype for a, v in attributes.items()}
    fmt = choose_point_format(attrs, has_color)
    header = laspy.LasHeader(point_format=fmt, version="1.4")
    header.scales, header.offsets = (np.asarray(v, np.float64) for v in grid)
    extra = extra_attributes(attrs, where=str(path), point_format=fmt)
    for a, dt in extra.items():
        header.add_extra_dim(laspy.ExtraBytesParams(name=a, type=dt))
    for user, record, data in crs_records:
        header.vlrs.append(laspy.VLR(user.decode(), record, "CRS", data))
    header.global_encoding.wkt = any(record == WKT_RECORD for _, record, _ in crs_records)
    fields = {a: LAS_FIELD_OF.get(a, a) for a in attrs if a in field_attributes(fmt)}
    return header, fields, extra


def _write_las(tmp: Path, path: Path, chunks: Chunks, grid, crs_records, color_bits: int | None, has_color: bool) -> int:
    """Point format 7 (8 with ``nir``; 6 without ``has_color``), LAS 1.4: attributes the format has a field for go to
    it, clipped to its range as the COPC writer does, said once a field (they were added as extra bytes under the
    field's own name, which laspy refused: "field 'intensity' occurs more than once"); others
    as extra bytes (las_fields.extra_attributes: booleans as u8, half floats as f4). The header
    is made from the first chunk, as it comes: one pass over the points (files are read once)."""
    import laspy

    grid = grid if grid is not None else _grid_of(chunks)
    written, clipped = 0, {}
    with contextlib.ExitStack() as open_file:
        writer = None
        for chunk in chunks():
            if writer is None:
                header, fields, extra = _las_layout(path, chunk.attributes, grid, crs_records, has_color)
                writer = open_file.enter_context(laspy.open(str(tmp), mode="w", header=header, do_compress=path.suffix.lower() == ".laz"))
            rec = laspy.ScaleAwarePointRecord.zeros(len(chunk), header=header)
            for k, axis in enumerate("XYZ"):  # the grid's integers, rounded: not laspy's truncation of x
                rec[axis] = _grid_integers(path, chunk.xyz[:, k], header.offsets[k], header.scales[k], axis)
            bits = color_bits if color_bits is not None else chunk.color_bits or 16
            for k, channel in enumerate(("red", "green", "blue") if has_color else ()):
                rec[channel] = chunk.rgba[:, k].astype(np.uint16) * np.uint16(257 if bits == 16 else 1)
            for a, field in fields.items():
                rec[field] = las_field_values(a, chunk.attributes[a], clipped).astype(rec[field].dtype)
            for a, dt in extra.items():
                rec[a] = chunk.attributes[a].astype(dt)
            writer.write_points(rec)
            written += len(chunk)
        warn_clipped(path, clipped)
        if writer is None:  # no chunk: a header alone
            header = _las_layout(path, _NO_POINTS.attributes, grid, crs_records, has_color)[0]
            open_file.enter_context(laspy.open(str(tmp), mode="w", header=header, do_compress=path.suffix.lower() == ".laz"))
    return written


def _grid_integers(path: Path, values: np.ndarray, offset: float, scale: float, axis: str) -> np.ndarray:
    """``values`` as the grid's 32-bit integers; one beyond them (a grid made from headers' bounds
    that the points overstep) a one-line InputError, not a position wrapped around."""
    ints = np.rint((values - offset) / scale)
    if len(ints) and not (-(2**31) <= ints.min() and ints.max() < 2**31):
        far = values[np.argmax(np.abs(ints))]
        raise InputError(f"{path}: {axis.lower()} {far:.15g} lies beyond the LAS grid (scale {scale:g}, offset {offset:.15g}): not written")
    return ints.astype(np.int32)


def _grid_of(chunks: Chunks) -> tuple[np.ndarray, np.ndarray]:
    """``las_grid`` of the points' bounds (one pass over them): points that came without a grid."""
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for chunk in chunks():
        if len(chunk):
            lo, hi = np.minimum(lo, chunk.xyz.min(axis=0)), np.maximum(hi, chunk.xyz.max(axis=0))
    return las_grid(np.minimum(lo, hi), np.maximum(lo, hi)) if np.all(lo <= hi) else las_grid(np.zeros(3), np.zeros(3))


#: PLY's name of each numpy type it holds
_PLY_NAMES = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int", "u4": "uint", "f4": "float", "f8": "double"}


#: digits of a PLY header's count written before the points are counted (``_write_ply``): any 64-bit count
_PLY_COUNT_DIGITS = 20


def _write_ply(tmp: Path, path: Path, chunks: Chunks, n: int | None, has_color: bool, crs: str | None) -> int:
    """Binary little-endian PLY: x, y, z (double), red, green, blue (uchar; ``has_color`` only), then the attributes;
    the header (made from the first chunk) first, then the records chunk by chunk. ``n`` None: the
    header's count is written as zeros of a fixed width and patched once the points are counted,
    not counted in a pass of their own (files' points, decoded again)."""
    with open(tmp, "wb") as f:
        fields = count_at = None
        written = 0
        for chunk in chunks():
            if fields is None:
                fields = _ply_fields(path, chunk, chunks, has_color)
                count_at = _write_ply_header(f, fields, n, crs)
            data = np.empty(len(chunk), fields)
            for k, a in enumerate("xyz"):
                data[a] = chunk.xyz[:, k]
            for k, a in enumerate(("red", "green", "blue") if has_color else ()):
                data[a] = chunk.rgba[:, k]
            for a in data.dtype.names[3 + 3 * has_color :]:  # (the attributes written)
                data[a] = chunk.attributes[a]
            f.write(data.tobytes())
            written += len(chunk)
        if fields is None:  # no chunk: a header alone
            count_at = _write_ply_header(f, _ply_fields(path, _NO_POINTS, chunks, has_color), n, crs)
        if n is None:
            f.seek(count_at)
            f.write(f"{written:0{_PLY_COUNT_DIGITS}d}".encode())
    if n is not None and written != n:  # (a file whose header says otherwise would read as damaged)
        raise InputError(f"{path}: {written:,} points came to be written, not the {n:,} expected; nothing was written")
    return written


def _ply_fields(path: Path, first: PointChunk, chunks: Chunks, has_color: bool) -> list[tuple[str, str]]:
    """The PLY records' (name, dtype) of points with ``first``'s attributes: 64-bit integers,
    which PLY has no type for, narrowed to their range (a pass over ``chunks()`` for it); those
    whose name a PLY file cannot hold left out (``_ply_name_problem``)."""
    fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")] + ([("red", "u1"), ("green", "u1"), ("blue", "u1")] if has_color else [])
    taken = {a for a, _ in fields} | ({"alpha"} if has_color else set())  # (alpha would be read as the colours' own)
    kept = {}
    for a, v in first.attributes.items():
        problem = _ply_name_problem(a, taken)
        if problem:
            warn(f"{path}: attribute {a!r} is not written: {problem}", GigapointWarning)
            continue
        taken.add(a.lower())
        kept[a] = v.dtype
    wide = [a for a, dt in kept.items() if dt.kind in "iu" and dt.itemsize == 8]
    lo, hi = dict.fromkeys(wide, 0), dict.fromkeys(wide, 0)
    for chunk in chunks() if wide else ():
        for a in wide:
            if len(chunk):
                lo[a], hi[a] = min(lo[a], int(chunk.attributes[a].min())), max(hi[a], int(chunk.attributes[a].max()))
    return fields + [(a, _ply_type(path, a, dt, lo.get(a, 0), hi.get(a, 0))) for a, dt in kept.items()]


def _ply_name_problem(name: str, taken: set[str]) -> str | None:
    """Why a PLY file cannot hold an attribute under ``name``, or None: its header is ASCII words
    ("property float my attr", "café": every reader refused the file written), and readers find
    x, red... in any case ('X' was read as a second x) and refuse two fields of one name in lower
    case ('Q' beside 'q'; ``taken``: those already in the file, lowered)."""
    if not (name.isascii() and name.isprintable()) or any(c.isspace() for c in name):
        return "its name is not one word of ASCII characters"
    if name.lower() in taken:
        return f"the file has a field of that name read in lower case ({name.lower()!r})"
    return None


#: the longest ``comment crs`` line written: RPly (Open3D, CloudCompare) refuses a header line of 1024 bytes
_PLY_CRS_LINE_MAX = 1000


def _ply_crs(path: Path, crs: str | None) -> str | None:
    """What a PLY file's ``comment crs`` line names ``crs`` by: 'EPSG:n' (or 'EPSG:h+v') where
    it names itself so (``own_epsg``), else its WKT on one line where that is ASCII
    (a PLY header is) and short enough for every reader (``_PLY_CRS_LINE_MAX``); else None, the
    CRS left out with a warning naming ``path``."""
    if not crs:
        return None
    code = own_epsg(crs)
    if code:
        return code
    text = " ".join(crs.split())
    if text.isascii() and len(f"comment {PLY_CRS_COMMENT}{text}") < _PLY_CRS_LINE_MAX:
        return text
    why = "is not ASCII" if not text.isascii() else f"is {len(text):,} characters"
    warn(f"{path}: its CRS ({crs_name(crs)}) is not written: its WKT {why}, and a PLY header line must be ASCII and under 1024 bytes; save as .las or .laz to keep it", GigapointWarning)
    return None


def _write_ply_header(f, fields: list, n: int | None, crs: str | None = None) -> int:
    """Write the PLY header of ``n`` points (None: zeros to patch), ``crs`` (``_ply_crs``'s) in a
    ``comment crs`` line (ply.PLY_CRS_COMMENT); returns where its count starts."""
    count = f"{0:0{_PLY_COUNT_DIGITS}d}" if n is None else str(n)
    properties = "".join(f"property {_PLY_NAMES[np.dtype(t).str[1:]]} {a}\n" for a, t in fields)
    comment = f"comment {PLY_CRS_COMMENT}{crs}\n" if crs else ""
    head = f"ply\nformat binary_little_endian 1.0\n{comment}element vertex "
    f.write(f"{head}{count}\n{properties}end_header\n".encode())
    return len(head.encode())


def _ply_type(path: Path, name: str, dt: np.dtype, lo: int, hi: int) -> str:
    """The PLY type that holds an attribute exactly: PLY has no 64-bit integers, half floats or
    booleans (plyfile refused them with a ValueError traceback, numpy's default int64 among
    them), so 64-bit integers (``lo``..``hi``) go to 32 bits when every value fits, and are refused otherwise."""
    if dt == np.bool_:
        return "u1"
    if dt.kind == "f":
        return "<f8" if dt.itemsize == 8 else "<f4"
    if dt.itemsize < 8:
        return dt.newbyteorder("<").str
    for narrow in ("<i4", "<u4"):
        info = np.iinfo(narrow)
        if lo >= info.min and hi <= info.max:
            return narrow
    far = lo if abs(lo) > abs(hi) else hi
    raise InputError(f"{path}: attribute {name!r} holds {dt} values PLY cannot hold (it has no 64-bit integers), e.g. {far}; save as .las or .laz")


def wkt_crs_records(wkt: str) -> list[tuple[bytes, int, bytes]]:
    """The LAS 1.4 OGC WKT VLR of a CRS, to write into a LAS file (``write_points``' crs_records)."""
    return [(PROJECTION_USER_ID, WKT_RECORD, wkt.encode() + b"\0")]


def source_crs_records(files) -> list[tuple[bytes, int, bytes]]:
    """The CRS records of the first LAS/LAZ file of ``files`` that names one, to write into a LAS
    file: its WKT (a VLR's, or an EVLR's), else its GeoTIFF key records as they are (LAS 1.4 wants
    WKT with point format 7; GeoTIFF keys are read by laspy, PDAL and gigapoint all the same, and
    making WKT of them needs pyproj); else a PLY file's ``comment crs`` CRS as WKT (an 'EPSG:n' by
    pyproj: none without it). Empty where none names one (``first_crs``)."""
    found = first_named_crs(files)
    if found is None:
        return []
    _, crs, hdr = found
    wkt = None if hdr is None else wkt_of(hdr.vlrs + hdr.evlrs)
    if hdr is not None and wkt is None:  # its GeoTIFF keys, as they are (no WKT made of them by pyproj: 0.13 s, unused)
        return [(u, r, d) for u, r, d in hdr.vlrs if u == PROJECTION_USER_ID and r in _GEOTIFF_RECORDS]
    wkt = wkt or crs_wkt(crs)
    return [] if wkt is None else wkt_crs_records(wkt)


def file_has_color(path) -> bool:
    """Whether the points of ``path`` have colours, as its header says: a LAS file's point format
    has RGB; other files where their header tells (PLY, NPY), else assumed."""
    reader = reader_for(path)
    if isinstance(reader, LasReader):
        return bool(reader.info(path).get("has_color"))
    return bool(reader.header(path).get("has_color", True))


def sources_have_color(files) -> bool:
    """Whether points read from ``files`` (a cloud's or an octree's sources) are written with
    colours: unless every one is still there and has none (the grey they are drawn in is no
    colour of theirs). No files (points built from arrays): they have colours."""
    there = [Path(p) for p in files if Path(p).is_file()]
    return not files or len(there) < len(files) or any(file_has_color(p) for p in there)


def _las_files(files) -> list[Path]:
    """The LAS/LAZ files among a cloud's source files that are still there (one removed since it
    was read gives nothing: its CRS and grid are lost, not the save)."""
    return [Path(p) for p in files if Path(p).is_file() and isinstance(reader_for(p), LasReader)]


def _source_grid(cloud: PointCloud, out: Path):
    """(scale, offset) of the grid the cloud's source stored positions on (its finest scale, its
    first LAS file's offset), where its points fit 32-bit integers on it (else a coarser one, said naming
    ``out``: ``las_grid``); None where it had none."""
    if cloud.source_scale is None:
        return None
    offset = next((read_las_header(p).offset for p in _las_files(cloud.source_files)), None)
    return las_grid(*cloud.bounds, cloud.source_scale, offset, out)  # (no offset: one from 0, a multiple of the scale)


#: points a chunk of ``save_cloud`` holds
SAVE_CHUNK_POINTS = 1_000_000


def save_cloud(cloud: PointCloud, path, overwrite: bool = False, points_per_chunk: int = SAVE_CHUNK_POINTS) -> int:
    """``PointCloud.save``: every point of ``cloud``, in its order, to ``path`` (.las, .laz, .ply),
    a chunk at a time. A cloud read from LAS/LAZ files keeps their CRS (the first file's naming
    one) and their grid (the X, Y, Z integers as the files had them, where every point lies on
    it); colours as held (8 bits a channel), in LAS's 16-bit fields x 257, or as they are where
    the source's were 8-bit values there (``source_color_bits``); none (LAS point format 6, a PLY
    without red, green, blue) where its files have none and its colours were never changed."""
    if not isinstance(path, (str, os.PathLike)) or not os.fspath(path):
        raise InputError(f"{cloud.name}: save: the output must be a path of a .las, .laz or .ply file, got {path!r}")
    path = Path(path)
    if path.suffix.lower() not in POINT_FILE_SUFFIXES:
        raise InputError(f"{path}: save writes .las, .laz or .ply files, not {path.suffix or 'a name without a suffix'}")
    check_point_file_output(path, overwrite)
    has_color = cloud.version is not None or sources_have_color(cloud.source_files)  # (changed: set_colors may have given it colours)
    if has_color and not cloud.colors_exact:  # gp.open's colors="auto": written as held, up to 12/255 off the file's (as convert says)
        files = ", ".join(str(f) for f in cloud.source_files)
        exact = f"open its files ({files}) with colors='rgba'" if files else "make the cloud with colors='rgba'"
        warn(f"{path}: the cloud holds its colours approximated (RGB565 or a palette), so the file gets those; {exact} for exact colours", GigapointWarning)
    crs = source_crs_records(cloud.source_files)
    return write_points(
        path, lambda: cloud.chunks(points_per_chunk), cloud.n_points, grid=_source_grid(cloud, path), crs_records=crs,
        color_bits=las_color_bits(cloud.source_color_bits),
        has_color=has_color,
    )


set_cloud_writer(save_cloud)

__all__ = ["POINT_FILE_SUFFIXES", "check_point_file_output", "file_has_color", "save_cloud", "source_crs_records", "sources_have_color", "wkt_crs_records", "write_points"]
