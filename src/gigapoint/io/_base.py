"""What every reader shares: the Reader interface, path checks, one-line errors, color scaling."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator
from contextvars import ContextVar
from pathlib import Path
from typing import TypeVar

import numpy as np

from ..core.chunk import ColorScaler, PointChunk, safe_attribute_name
from ..core.coords import valid_mask
from ..errors import EmptyCloudError, InputError, check_whole

#: Points per chunk a reader yields unless told otherwise (about 100 MB of xyz + rgba + attributes).
DEFAULT_CHUNK_SIZE = 2_000_000
#: Points per chunk of the commands that only stream points through (``convert -o x.laz``,
#: ``tile``, ``info --stats``): they hold a chunk or two of every attribute at a time and nothing
#: else, so their peak memory is that (a 2 M-point chunk ~130 bytes a point, ~2 held at once:
#: 270 of ``info --stats``'s 437 MiB), and smaller chunks cost no speed (docs/benchmarks.md, "Streaming
#: commands' memory"). The octree builders keep their own, tuned chunk sizes.
STREAM_CHUNK_SIZE = 250_000

#: What a reader's refusal of a file cut off adds: where the points before the cut can be seen
#: (``Reader.read_salvaged``).
SALVAGE_HINT = "; `gigapoint view` shows the points before the cut (gigapoint.open(..., progressive=True))"

#: Bytes of a file's beginning that readers' ``sniff`` sees.
HEAD_BYTES = 4096

T = TypeVar("T")

#: what the operation under way (``headers_once``) has read of its files: {(kind, path): result}; None outside one
_kept: ContextVar[dict | None] = ContextVar("gigapoint_headers", default=None)


@contextlib.contextmanager
def headers_once():
    """Within it (one operation: an open, a conversion), each file's header is read once and
    kept (``read_once``): the operation's steps (point counts, scan angles, the LAS grid, then
    the points) each read it again, 3-6 times a file, a seek or a request each for a folder of
    2 000 tiles or files on a network. Threads the operation starts take it along
    (contextvars.copy_context). Nested: the outermost one's. Also a decorator."""
    if _kept.get() is not None:
        yield
        return
    token = _kept.set({})
    try:
        yield
    finally:
        _kept.reset(token)


def read_once(kind: str, path, read: Callable[[], T]) -> T:
    """``read()``, or within ``headers_once`` what it gave for (``kind``, ``path``) before (an error is not kept)."""
    kept = _kept.get()
    if kept is None:
        return read()
    key = (kind, str(path))
    if key not in kept:
        kept[key] = read()
    return kept[key]


class Reader:
    """One point cloud file format. Subclasses set the class attributes and implement the methods.

    ``sniff(head)`` answers True only when the first bytes prove the format (a magic number);
    ``weak_sniff(head)`` may guess from content (text readers) and is tried after suffixes.
    ``read_chunks`` yields PointChunks of at most ``chunk_size`` points and raises InputError
    subclasses for bad input; ``info`` returns a dict as described in ``gigapoint.io.file_info``.
    """

    name: str = ""
    suffixes: tuple[str, ...] = ()
    #: suffixes that other files share (a README.txt, a spreadsheet .csv, an ASCII grid .asc):
    #: in a folder, such a file is taken only where ``weak_sniff`` finds points in its beginning
    shared_suffixes: tuple[str, ...] = ()

    def sniff(self, head: bytes) -> bool:
        return False

    def weak_sniff(self, head: bytes) -> bool:
        return False

    def read_chunks(self, path: Path, chunk_size: int = DEFAULT_CHUNK_SIZE) -> Iterator[PointChunk]:
        raise NotImplementedError

    def info(self, path: Path) -> dict:
        raise NotImplementedError

    def point_count(self, path: Path) -> int | None:
        """Number of points when the header tells it cheaply, else None (used for progress bars)."""
        return None

    def reads_slowly(self, path: Path) -> bool:
        """Whether reading the file's points costs far more than copying them (decompression,
        text parsing): a build that reads its source more than once (core/chunked.py) then
        reads it once and keeps the points it read."""
        return False

    def header(self, path: Path, salvage: bool = False) -> dict:
        """What the file's header tells without reading its points: ``point_count`` (None when
        it does not), and where the format's header holds them ``bounds`` ((min, max) of its
        points, as the header says), ``offset`` and ``scale`` (its integer grid). ``info`` may
        read every point (text, NPY: ``bounds_source`` "scan"); this never does. ``salvage``:
        a file cut off is not refused here (``read_salvaged`` gives what it holds):
        ``truncated`` says why it is short. ``attributes``: the names ``read_chunks`` gives its
        points' attributes, where the header tells them (absent: known once read)."""
        return {"point_count": self.point_count(path)}

    def read_salvaged(self, path: Path, chunk_size: int = DEFAULT_CHUNK_SIZE) -> Iterator[PointChunk]:
        """``read_chunks`` of a file that may be cut off or damaged: the points it still holds,
        then its error (what a progressive load keeps drawable). Readers that find damage as
        they read give the chunks before it anyway; one that refuses a short file up front
        (LAS/LAZ: its header's counts) reads up to the cut here."""
        return self.read_chunks(path, chunk_size)

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name}>"


def one_line(text: object) -> str:
    """Collapse a message (possibly from a third-party library) to one trimmed line."""
    s = " ".join(str(text).split())
    return s if len(s) <= 300 else s[:297] + "..."


def fail(path: Path | str, problem: object, cls: type[InputError] = InputError) -> InputError:
    """An InputError (or subclass) whose one-line message starts with the path."""
    return cls(f"{path}: {one_line(problem)}")


def check_file(path: Path | str, empty_ok: bool = False) -> Path:
    """The path as a Path, after checking it names a readable, non-empty regular file
    (``empty_ok``: or an empty one, which its reader refuses, or an operation skips among several)."""
    p = Path(path)
    try:
        st = p.stat()
    except FileNotFoundError:
        raise fail(p, "no such file") from None
    except OSError as exc:
        raise fail(p, exc.strerror or exc) from None
    if p.is_dir():
        raise fail(p, "is a directory, expected a point cloud file")
    if not p.is_file():
        raise fail(p, "is not a regular file")
    if not os.access(p, os.R_OK):
        raise fail(p, "permission denied")
    if st.st_size == 0 and not empty_ok:
        raise fail(p, "file is empty (0 bytes)", EmptyCloudError)
    return p


def read_head(path: Path, n: int = HEAD_BYTES) -> bytes:
    try:
        with open(path, "rb") as f:
            return f.read(n)
    except OSError as exc:
        raise fail(path, exc.strerror or exc) from None


def check_chunk_size(chunk_size: int) -> int:
    """Points per chunk: a whole number >= 1 (True was 1, a chunk a point; 2.5 read as 2)."""
    return check_whole("open", "chunk_size", chunk_size, 1)


#: Point attributes gigapoint reads from (and writes to) these formats, as the LAS reader names them.
ATTRIBUTE_DTYPES = {
    "intensity": np.dtype(np.uint16),
    "classification": np.dtype(np.uint8),
    "return_number": np.dtype(np.uint8),
    "number_of_returns": np.dtype(np.uint8),
    "point_source_id": np.dtype(np.uint16),
    "gps_time": np.dtype(np.float64),
    "user_data": np.dtype(np.uint8),
    "scan_angle": np.dtype(np.int16),  # 0.006 degrees
    **dict.fromkeys(("scan_direction_flag", "edge_of_flight_line", "synthetic", "key_point", "withheld", "overlap", "scanner_channel"),
                    np.dtype(np.uint8)),
}  # fmt: skip
#: Attributes point format 6/7/8 has a field for (nir: 8 only; scan_angle_rank, formats 0-5's
#: degrees, is written to scan_angle); the writer stores any other in extra bytes.
LAS_FIELD_ATTRIBUTES = frozenset({*ATTRIBUTE_DTYPES, "nir", "scan_angle_rank"})


#: the fields gigapoint reads by name, in any case: x y z, colours, LAS fields, normals
_READ_BY_NAME = frozenset({
    *LAS_FIELD_ATTRIBUTES, "x", "y", "z", "nx", "ny", "nz",
    "red", "green", "blue", "alpha", "r", "g", "b", "a", "diffuse_red", "diffuse_green", "diffuse_blue", "diffuse_alpha",
})  # fmt: skip


def attribute_spelling(field: str) -> str:
    """The name a point file's field is read under, by every reader (text, NPY, PLY; LAS keeps its
    extra bytes' names too): one gigapoint reads by name ('X', 'Classification': PDAL's; 'NX') in
    lower case, any other as the file spells it ('scalar_Intensity' came back 'scalar_intensity',
    and a PLY's 'Hag' no longer met a CSV's 'Hag' once one reader kept the case and one did not)."""
    lower = field.lower()
    return lower if lower in _READ_BY_NAME else field


def check_distinct_names(path: Path, names: list[str], keys: list[str] | None = None) -> None:
    """Two fields read under one name (``keys``: those, default ``attribute_spelling``'s: 'X' and
    'x', 'Intensity' and 'intensity') were one, the last kept without a word: refused."""
    seen: dict[str, str] = {}
    for name, key in zip(names, keys or [attribute_spelling(n) for n in names]):
        if key in seen:
            raise fail(path, f"fields {seen[key]!r} and {name!r} are both read as {key!r}; rename one")
        seen[key] = name


def attribute_names(names: list[str], colors: list[str]) -> list[str]:
    """The attributes ``rows_to_chunk`` makes of fields ``names`` (``colors``: color_names'), as it names them."""
    out = (safe_attribute_name(attribute_spelling(n)) for n in names if n.lower() not in ("x", "y", "z") and n.lower() not in colors)
    return [n for n in out if n is not None]


def rows_to_chunk(path: Path, names: list[str], columns: list[np.ndarray], scaler: ColorScaler) -> PointChunk:
    """A PointChunk from named 1-D columns: x y z, red green blue [alpha] (or r g b [a]), found in
    any case, the rest attributes, named as ``attribute_spelling`` reads them."""
    check_distinct_names(path, names)
    lower = [n.lower() for n in names]
    col = dict(zip(lower, columns))
    try:
        xyz = np.column_stack([col["x"], col["y"], col["z"]]).astype(np.float64, copy=False)
    except KeyError:
        raise fail(path, f"no x, y, z columns (found {', '.join(names) or 'none'})") from None
    rgba = None
    for keys in (("red", "green", "blue", "alpha"), ("r", "g", "b", "a"), ("diffuse_red", "diffuse_green", "diffuse_blue", "diffuse_alpha")):
        if all(k in col for k in keys[:3]):
            used = [k for k in keys if k in col]
            rgba = scaler(np.column_stack([col[k] for k in used]))
            break
    else:
        used = []
    attributes = {}
    for field, key, values in zip(names, lower, columns):
        if key in ("x", "y", "z") or key in used:
            continue
        name = safe_attribute_name(attribute_spelling(field))  # 'a/b' as 'a_b': a file's own names are kept, not refused
        if name is not None:
            attributes[name] = np.ascontiguousarray(values)
    return PointChunk(xyz, rgba, attributes)


def unpack_rgb(packed: np.ndarray) -> np.ndarray | None:
    """(N, 3) uint8 of PCL's packed colours, a 4-byte ``rgb``/``rgba`` field holding 0x..RRGGBB
    (a float32's bits in a float field; the top byte, rgba's alpha, left out: opaque points),
    or None for a field of another size."""
    packed = np.ascontiguousarray(packed)
    if packed.dtype.itemsize != 4:
        return None
    v = packed.view(np.dtype(np.uint32).newbyteorder(packed.dtype.byteorder))  # a big-endian message's colours were byte-swapped
    return np.stack([(v >> 16) & 255, (v >> 8) & 255, v & 255], axis=1).astype(np.uint8)


def color_names(names: list[str]) -> list[str]:
    lower = [n.lower() for n in names]
    for keys in (("red", "green", "blue", "alpha"), ("r", "g", "b", "a"), ("diffuse_red", "diffuse_green", "diffuse_blue", "diffuse_alpha")):
        if all(k in lower for k in keys[:3]):
            return [k for k in keys if k in lower]
    return []


def packed_rgb_field(itemsizes: dict[str, int]) -> str | None:
    """Of a table's scalar fields (name: bytes a value), the one holding PCL's packed colours (a
    4-byte ``rgb``/``rgba``) where none is red green blue, else None (PLY and NPY tables alike)."""
    if color_names(list(itemsizes)):
        return None
    return next((n for n, size in itemsizes.items() if n.lower() in ("rgb", "rgba") and size == 4), None)


def scan_bounds(chunks: Iterator[PointChunk]) -> tuple[int, list[float] | None, list[float] | None]:
    """(count, min, max) over the valid points of a chunk stream (``valid_mask``: those a read
    keeps; bounds None when none is): a row at 1e300 in a text file was ``info``'s 300-digit bounds."""
    n = 0
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for chunk in chunks:
        n += len(chunk)
        ok = valid_mask(chunk.xyz)
        if ok.any():
            v = chunk.xyz[ok]
            lo = np.minimum(lo, v.min(axis=0))
            hi = np.maximum(hi, v.max(axis=0))
    if not np.all(np.isfinite(lo)):
        return n, None, None
    return n, lo.tolist(), hi.tolist()


def scanned_info(path: Path, fmt: str, chunks: Iterator[PointChunk] | None, has_color: bool, attributes: list[str], **extra) -> dict:
    """``info()`` of a format whose header holds no bounds: count and bounds scanned from ``chunks``
    (None: a file without points); ``extra`` entries follow the common ones, ``file_size`` comes last."""
    n, lo, hi = scan_bounds(chunks) if chunks is not None else (0, None, None)
    return {
        "path": str(path),
        "format": fmt,
        "point_count": n,
        "bounds": {"min": lo, "max": hi},
        "bounds_source": "data",
        "has_color": has_color,
        "attributes": attributes,
        **extra,
        "file_size": path.stat().st_size,
    }
