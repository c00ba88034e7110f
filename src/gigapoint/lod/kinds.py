"""What a path is, as lod opens it, told without numba (``gigapoint info`` of a point file asks
whether it is an octree: reader.py's ``lod_source_kind``): a COPC file from its head (its LAS
1.4 header and COPC info VLR, copc.py's layouts), an EPT dataset from its ``ept.json``."""

from __future__ import annotations

import os
from pathlib import Path
from urllib.parse import urlsplit, urlunsplit

import numpy as np

from ..errors import InputError
from ..io.http import as_url, last_name, shown_url
from ..io.las import read_las_header
from ..io.paths import file_url_path, is_copc_name
from .octree_dir import POTREE_HIERARCHY, POTREE_META, POTREE_OCTREE, RESUME_HINT, OctreeDir

# --------------------------------------------------------------------------- COPC's head (copc.py)

#: The LAS 1.4 public header block.
LAS14_HEADER_DTYPE = np.dtype(
    [
        ("file_signature", "S4"),
        ("file_source_id", "<u2"),
        ("global_encoding", "<u2"),
        ("project_id", "V16"),
        ("version_major", "u1"),
        ("version_minor", "u1"),
        ("system_identifier", "S32"),
        ("generating_software", "S32"),
        ("creation_day", "<u2"),
        ("creation_year", "<u2"),
        ("header_size", "<u2"),
        ("offset_to_point_data", "<u4"),
        ("number_of_vlrs", "<u4"),
        ("point_format", "u1"),
        ("point_record_length", "<u2"),
        ("legacy_point_count", "<u4"),
        ("legacy_points_by_return", "<u4", (5,)),
        ("scale", "<f8", (3,)),
        ("offset", "<f8", (3,)),
        ("max_x", "<f8"),
        ("min_x", "<f8"),
        ("max_y", "<f8"),
        ("min_y", "<f8"),
        ("max_z", "<f8"),
        ("min_z", "<f8"),
        ("start_of_waveform", "<u8"),
        ("start_of_first_evlr", "<u8"),
        ("number_of_evlrs", "<u4"),
        ("point_count", "<u8"),
        ("points_by_return", "<u8", (15,)),
    ]
)
VLR_HEADER_DTYPE = np.dtype(
    [("reserved", "<u2"), ("user_id", "S16"), ("record_id", "<u2"), ("record_length", "<u2"), ("description", "S32")]
)
#: The COPC info VLR's 160 bytes.
COPC_INFO_DTYPE = np.dtype(
    [
        ("center", "<f8", (3,)),
        ("halfsize", "<f8"),
        ("spacing", "<f8"),
        ("root_hier_offset", "<u8"),
        ("root_hier_size", "<u8"),
        ("gpstime_minimum", "<f8"),
        ("gpstime_maximum", "<f8"),
        ("reserved", "<u8", (11,)),
    ]
)
COPC_USER_ID = b"copc"
COPC_INFO_RECORD = 1
HEADER_SIZE = LAS14_HEADER_DTYPE.itemsize  # 375
INFO_OFFSET = HEADER_SIZE + VLR_HEADER_DTYPE.itemsize  # the info VLR's data: byte 429
MAGIC_END = INFO_OFFSET  # bytes needed to tell a COPC file


def is_copc_head(head: bytes) -> bool:
    """The first bytes of a COPC file: 'LASF', LAS 1.4, the COPC info VLR first (copc.io's
    reader notes: 'copc' at byte 377, record id 1 at 393)."""
    if len(head) < MAGIC_END or head[:4] != b"LASF" or head[24:26] != b"\x01\x04":
        return False
    vlr = np.frombuffer(head, VLR_HEADER_DTYPE, count=1, offset=HEADER_SIZE)[0]
    return vlr["user_id"].rstrip(b"\0") == COPC_USER_ID and int(vlr["record_id"]) == COPC_INFO_RECORD


def copc_file_kind(path) -> str | None:
    """A local file's kind, from one read of its head: "copc" (it starts as a COPC file does,
    ``is_copc_head``), "laz" (a COPC file cut in its EVLRs, after the points: its root hierarchy
    page is gone, so no node can be found, but its LAZ chunk table is whole: it reads as the
    plain LAZ file it still is, every point; ``lod_source_kind`` sends it to the LAS reader,
    which warns) or None (not a COPC file)."""
    if not os.path.isfile(path):  # a FIFO named x.las: reading it waited for a writer for good
        return None
    end = INFO_OFFSET + COPC_INFO_DTYPE.itemsize
    try:
        with open(path, "rb") as f:
            head, size = f.read(end), os.fstat(f.fileno()).st_size
    except OSError:
        return None
    if not is_copc_head(head):
        return None
    if len(head) < end:  # its info VLR cut: COPC's error says so
        return "copc"
    info = np.frombuffer(head, COPC_INFO_DTYPE, count=1, offset=INFO_OFFSET)[0]
    if int(info["root_hier_offset"]) + int(info["root_hier_size"]) <= size:
        return "copc"
    try:  # (a whole file whose info VLR points past its end stays COPC's error)
        return "laz" if read_las_header(Path(path)).evlrs_cut is not None else "copc"
    except InputError:  # its points cut too: COPC's error says what is left
        return "copc"


def potree_part(path) -> str | None:
    """What to say of a Potree 2.0 octree's octree.bin or hierarchy.bin (a URL's, or a local one's
    beside its metadata.json) given where a point file or a COPC file is read, else None: it was
    "not a COPC file" or "unknown point cloud format", its octree's folder unnamed."""
    url = as_url(path)
    name = last_name(url or path)
    if name not in (POTREE_OCTREE, POTREE_HIERARCHY):
        return None
    if url is not None:
        return f"{shown_url(url)}: a Potree octree's {name}, part of its folder; Potree octrees open from a local folder (over HTTP: COPC files and EPT datasets)"
    folder = Path(path).parent
    if not (folder / POTREE_META).is_file():
        return None
    return f"{path}: a Potree octree's {name}, part of its folder; open the folder {folder}"


# --------------------------------------------------------------------------- EPT (ept.py)

EPT_FILE = "ept.json"


def ept_location(path) -> str | Path | None:
    """The ``ept.json`` that ``path`` names (the file, its folder, or a URL ending in
    ``ept.json`` or ``/``), else None."""
    url = as_url(path)
    if url is not None:
        # the URL's path, not its query: '.../ept.json?sig=...' was taken for a COPC file
        try:
            parts = urlsplit(url)
        except ValueError:  # 'http://[::1': the HTTP client says so, naming the URL
            return None
        if parts.path.endswith("/"):
            return urlunsplit(parts._replace(path=parts.path + EPT_FILE))
        return url if parts.path.rsplit("/", 1)[-1].endswith(".json") else None
    p = Path(path)
    if p.is_dir() and (p / EPT_FILE).is_file():
        return p / EPT_FILE
    if p.is_file() and p.name == EPT_FILE:
        return p
    return None


# --------------------------------------------------------------------------- a COPC output's names (copc_write.py)


def work_dir(out) -> Path:
    """The folder a conversion into the COPC file ``out`` works in (an OctreeDir: its state,
    preview and node sets; removed once ``out`` is written): ``<out>.work`` beside it."""
    out = Path(out)
    return out.with_name(out.name + ".work")


def copc_of_work_dir(work) -> Path | None:
    """The COPC file a conversion working in the folder ``work`` writes (``work_dir``'s
    inverse), or None where ``work`` is not named as such a folder."""
    work = Path(work)
    return work.with_name(work.name.removesuffix(".work")) if work.name.endswith(".work") and work.name != ".work" else None


def refuse_unwritten_copc(paths) -> None:
    """A one-line InputError for the first of ``paths`` that is not there because a conversion
    into a COPC file is at work (the file appears once complete; ``<out>.work`` meanwhile): the
    file before it is written (running: its work folder shows what is read so far; stopped: what
    to do), or that work folder once it is gone. A bare "no such file" left users to guess."""
    for path in paths:
        try:
            path = file_url_path(os.fspath(path)) or path  # (file:///x.copc.laz: the path it names)
        except InputError:  # (another machine's file: the input checks say so in their words)
            continue
        if as_url(path) is not None or Path(path).exists():
            continue
        work, copc = work_dir(path), copc_of_work_dir(path)
        d = OctreeDir(work)
        if work.is_dir() and (d.running or d.state_file.is_file()):  # (a folder of that name a conversion did not make: no word of one)
            if d.running:
                raise InputError(f"{path}: no such file yet: a conversion is writing it; open its work folder {work} to see what it has read so far")
            hint = d.resume_hint  # (a bad input that stopped it: its error, and what to do)
            again = "run the same convert command again to resume it" if hint == RESUME_HINT else hint
            raise InputError(f"{path}: no such file yet: a conversion to it is unfinished (its work folder {work} is there); {again}")
        if copc is not None and is_copc_name(copc) and copc.is_file():  # (b.las beside a missing b.las.work: no conversion's)
            raise InputError(f"{path}: no such folder: the conversion that worked in it has finished; open {copc}")
