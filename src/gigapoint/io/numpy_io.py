"""NPY and NPZ point arrays, read in chunks (NPY memory-mapped, NPZ members streamed from the zip).

Layouts understood (NPY, or one array of an NPZ without named keys):

- 2-D numeric (N, 3) x y z; (N, 4) x y z intensity; (N, 6) x y z r g b; (N, 7) x y z r g b a.
- structured with fields x, y, z [red green blue [alpha] | r g b [a]]; other numeric fields
  become attributes. Without red green blue, a 4-byte ``rgb``/``rgba`` field is PCL's packed
  colour (0x..RRGGBB, as Open3D/PCL exports write it; read as the PLY reader reads it).

NPZ keys: ``xyz`` / ``positions`` / ``points`` / ``pos`` (N, 3) or separate ``x``, ``y``, ``z``;
``rgb`` / ``rgba`` / ``colors`` / ``color``; every other array with N rows is an attribute.
Colors may be uint8, uint16 or floats (of 0..1, 0..255 or 0..65535: ``ColorScaler``).
"""

from __future__ import annotations

import tokenize
import zipfile
import zlib
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ..core.chunk import PointChunk, safe_attribute_name
from ..errors import EmptyCloudError
from ._base import (
    DEFAULT_CHUNK_SIZE,
    ColorScaler,
    Reader,
    attribute_names,
    check_chunk_size,
    check_file,
    color_names,
    fail,
    packed_rgb_field,
    rows_to_chunk,
    scanned_info,
    unpack_rgb,
)

NPY_MAGIC = b"\x93NUMPY"
_COLUMNS = {3: ["x", "y", "z"], 4: ["x", "y", "z", "intensity"], 6: ["x", "y", "z", "r", "g", "b"], 7: ["x", "y", "z", "r", "g", "b", "a"]}
XYZ_KEYS = ("xyz", "positions", "position", "points", "pos")
COLOR_KEYS = ("rgb", "rgba", "colors", "color", "colours")


def _read_npy_header(f) -> tuple[tuple, bool, np.dtype]:
    """(shape, fortran_order, dtype) of the NPY stream at its start; leaves f at the data. A
    header that is not one is a ValueError (numpy's parse of a garbled one raised tokenize's
    TokenError, a traceback instead of a line naming the file)."""
    version = np.lib.format.read_magic(f)
    try:
        if version == (1, 0):
            return np.lib.format.read_array_header_1_0(f)
        return np.lib.format.read_array_header_2_0(f)  # 2.0 and 3.0 (utf-8 names) share the layout
    except (SyntaxError, tokenize.TokenError, TypeError) as exc:
        raise ValueError(f"its header is not an NPY header ({type(exc).__name__}: {exc})") from None


def _check_positions(path: Path, what: str, dtype: np.dtype) -> None:
    """Positions of integers or floats, in points_for's words (bools were read as 0 and 1)."""
    if dtype.kind not in "iuf":
        raise fail(path, f"{what}: xyz must hold numbers (integers or floats), got dtype {dtype}")


def _layout_names(path: Path, what: str, dtype: np.dtype, shape: tuple) -> list[str]:
    """Column names of an array used as a whole point table (raises on shapes that are not one)."""
    if dtype.names:
        if not {"x", "y", "z"} <= {n.lower() for n in dtype.names}:
            raise fail(path, f"{what}: structured array without x, y, z fields (fields: {', '.join(dtype.names)})")
        if len(shape) != 1:
            raise fail(path, f"{what}: structured point array must be 1-D, got shape {shape}")
        for name in dtype.names:
            if name.lower() in ("x", "y", "z"):
                _check_positions(path, f"{what} field {name!r}", dtype[name])
        return list(dtype.names)
    _check_positions(path, what, dtype)
    if len(shape) != 2 or shape[1] not in _COLUMNS:
        raise fail(path, f"{what}: expected an (N, 3), (N, 4), (N, 6) or (N, 7) array, got shape {shape}")
    return _COLUMNS[shape[1]]


def _packed_rgb(dtype: np.dtype) -> str | None:
    """The field of a structured array without red green blue that holds PCL's packed colours (a
    4-byte ``rgb``/``rgba``, as the PLY reader takes it), else None: it was an attribute of
    nonsense numbers, the points drawn grey."""
    return packed_rgb_field({n: dtype[n].itemsize for n in dtype.names if dtype[n].shape == ()}) if dtype.names else None


def _names_read(names: list[str], dtype: np.dtype, packed: str | None = None) -> list[str]:
    """A point table's column names as read: a packed colour field (``packed``, else found) becomes red green blue."""
    packed = packed or _packed_rgb(dtype)
    return names if packed is None else [*(n for n in names if n != packed), "red", "green", "blue"]


def _table_chunk(path: Path, names: list[str], block: np.ndarray, scaler: ColorScaler) -> PointChunk:
    if block.dtype.names:
        block = block.astype(block.dtype.newbyteorder("="), copy=False) if not block.dtype.isnative else block
        packed = _packed_rgb(block.dtype)
        cols = [np.asarray(block[n]) for n in names if n != packed]
        if packed is not None:
            cols += list(unpack_rgb(block[packed]).T)
        names = _names_read(names, block.dtype, packed)
    else:
        cols = [block[:, i] for i in range(block.shape[1])]
    return rows_to_chunk(path, names, cols, scaler)


class NpyReader(Reader):
    name = "NPY"
    suffixes = (".npy",)

    def sniff(self, head: bytes) -> bool:
        return head[:6] == NPY_MAGIC

    def _shape(self, path: Path) -> tuple:
        """The array's shape from its header, after checking the header, the dtype and that the
        data the header declares is all there (no memory map: counting 2 000 tiles' points
        mapped each, 0.18 ms a file)."""
        try:
            with open(path, "rb") as f:
                if f.read(6) != NPY_MAGIC:
                    raise fail(path, "not an NPY file (no \\x93NUMPY magic)")
                f.seek(0)
                shape, _fortran, dtype = _read_npy_header(f)
                data_start = f.tell()
            if dtype.hasobject:
                raise fail(path, f"NPY array holds Python objects (dtype {dtype}), which gigapoint does not unpickle")
            nbytes = int(np.prod(shape, dtype=object)) * dtype.itemsize
            have = path.stat().st_size - data_start
        except ValueError as exc:  # bad header
            raise fail(path, f"corrupt or truncated NPY file: {exc}") from None
        except OSError as exc:
            raise fail(path, exc.strerror or exc) from None
        if nbytes > have:
            raise fail(path, f"truncated NPY file: its header declares shape {tuple(shape)} ({nbytes:,} bytes) but only {have:,} bytes follow")
        return tuple(shape)

    def _open(self, path: Path) -> np.ndarray:
        self._shape(path)
        try:
            return np.load(path, mmap_mode="r", allow_pickle=False)
        except ValueError as exc:  # truncated data ("mmap length is greater than file size"), object arrays
            raise fail(path, f"corrupt or truncated NPY file: {exc}") from None
        except OSError as exc:
            raise fail(path, exc.strerror or exc) from None

    def point_count(self, path: Path) -> int | None:
        shape = self._shape(check_file(path))
        return shape[0] if shape else None

    def header(self, path: Path, salvage: bool = False) -> dict:
        """Also ``has_color``: whether its columns hold colors (a COPC output of points without
        them is written without colors)."""
        arr = self._open(check_file(path))  # (memory-mapped: only its header is read)
        names = _names_read(_layout_names(path, "NPY array", arr.dtype, arr.shape), arr.dtype)
        cols = color_names(names)
        return {"point_count": len(arr) if arr.ndim else None, "has_color": bool(cols), "attributes": attribute_names(names, cols)}

    def read_chunks(self, path: Path, chunk_size: int = DEFAULT_CHUNK_SIZE) -> Iterator[PointChunk]:
        chunk_size = check_chunk_size(chunk_size)
        path = check_file(path)
        arr = self._open(path)
        names = _layout_names(path, "NPY array", arr.dtype, arr.shape)
        if len(arr) == 0:
            raise fail(path, "NPY array holds no points (0 rows)", EmptyCloudError)
        scaler = ColorScaler()
        for start in range(0, len(arr), chunk_size):
            yield _table_chunk(path, names, np.array(arr[start : start + chunk_size]), scaler)

    def info(self, path: Path) -> dict:
        path = check_file(path)
        arr = self._open(path)
        names = _names_read(_layout_names(path, "NPY array", arr.dtype, arr.shape), arr.dtype)
        cols = color_names(names)
        attributes = attribute_names(names, cols)  # as read (_base.attribute_spelling)
        chunks = self.read_chunks(path) if len(arr) else None
        return scanned_info(path, "NPY", chunks, bool(cols), attributes, dtype=str(arr.dtype), shape=list(arr.shape))


class _Member:
    """One array inside an NPZ, read row block by row block without loading it whole."""

    def __init__(self, path: Path, zf: zipfile.ZipFile, name: str):
        self.path, self.zf, self.name = path, zf, name
        self.key = name.removesuffix(".npy")
        info = zf.getinfo(name)
        try:
            with zf.open(name) as m:
                try:
                    shape, fortran, dtype = _read_npy_header(m)
                    header_len = m.tell() if m.seekable() else None
                except ValueError as exc:
                    raise fail(path, f"NPZ member {self.key!r} is not a valid NPY array: {exc}") from None
        except (zipfile.BadZipFile, zlib.error, EOFError) as exc:  # a damaged member's zip header or data (was zipfile's traceback)
            raise fail(path, f"corrupt NPZ (zip) member {self.key!r}: {exc}") from None
        if dtype.hasobject:
            raise fail(path, f"NPZ member {self.key!r} holds Python objects (dtype {dtype}), which gigapoint does not unpickle")
        self.shape, self.fortran, self.dtype = tuple(shape), fortran, dtype
        nbytes = int(np.prod(shape, dtype=object)) * dtype.itemsize
        if header_len is not None and nbytes > info.file_size - header_len:
            raise fail(path, f"corrupt NPZ member {self.key!r}: its header claims shape {self.shape} ({nbytes:,} bytes) but it holds {info.file_size - header_len:,} bytes")
        self.rows = self.shape[0] if self.shape else 0

    def blocks(self, chunk_size: int) -> Iterator[np.ndarray]:
        if self.fortran or not self.shape:  # rare: read whole
            data = np.load(self.zf.open(self.name), allow_pickle=False)
            for start in range(0, max(self.rows, 1), chunk_size):
                yield data[start : start + chunk_size]
            return
        row_shape = self.shape[1:]
        row_bytes = int(np.prod(row_shape, dtype=np.int64)) * self.dtype.itemsize
        with self.zf.open(self.name) as m:
            _read_npy_header(m)
            done = 0
            while done < self.rows:
                n = min(chunk_size, self.rows - done)
                buf = m.read(n * row_bytes)
                if len(buf) < n * row_bytes:
                    raise fail(self.path, f"truncated NPZ member {self.key!r}: {done + len(buf) // max(row_bytes, 1):,} of {self.rows:,} rows present")
                yield np.frombuffer(buf, self.dtype).reshape((n, *row_shape))
                done += n


def _check_colors(path: Path, members: dict[str, _Member], positions: _Member) -> None:
    """A colour member that does not fit the points is an error: left out with the other arrays
    of another row count, it drew the cloud in the default colour without a word."""
    for m in members.values():
        if m.key.lower() not in COLOR_KEYS:
            continue
        if m.rows != positions.rows:
            raise fail(path, f"NPZ member {m.key!r} has {m.rows:,} rows, {positions.key!r} has {positions.rows:,}")
        if len(m.shape) != 1 and (m.shape[1:] not in ((3,), (4,)) or m.dtype.kind not in "biuf"):  # (N,): an attribute
            raise fail(path, f"NPZ member {m.key!r} must be an (N, 3) or (N, 4) colour array, got shape {m.shape} dtype {m.dtype}")


def _npz_plan(path: Path, zf: zipfile.ZipFile) -> tuple[dict[str, _Member], list[str] | None, dict[str, _Member]]:
    """(members by key, names when one member is a whole point table else None, members to read)."""
    members = {}
    for name in zf.namelist():
        m = _Member(path, zf, name)
        members[m.key] = m
    if not members:
        raise fail(path, "NPZ archive holds no arrays", EmptyCloudError)
    lower = {k.lower(): k for k in members}
    xyz_key = next((lower[k] for k in XYZ_KEYS if k in lower), None)
    if xyz_key is None and {"x", "y", "z"} <= set(lower):
        first = members[lower["x"]]
        for a in "xyz":  # (one of another length was dropped below, then a KeyError)
            m = members[lower[a]]
            if len(m.shape) != 1:
                raise fail(path, f"NPZ member {m.key!r} must be a numeric (N,) array, got shape {m.shape} dtype {m.dtype}")
            _check_positions(path, f"NPZ member {m.key!r}", m.dtype)
            if m.rows != first.rows:
                raise fail(path, f"NPZ member {m.key!r} has {m.rows:,} rows, {first.key!r} has {first.rows:,}")
        use = {k: m for k, m in members.items() if m.rows == first.rows and len(m.shape) in (1, 2)}
        _check_colors(path, members, first)
        return members, None, use
    if xyz_key is None:
        if len(members) == 1:
            (m,) = members.values()
            return members, _layout_names(path, f"NPZ member {m.key!r}", m.dtype, m.shape), {m.key: m}
        raise fail(path, f"NPZ archive has no point positions: expected a key named one of {', '.join(XYZ_KEYS)} or x, y, z (keys: {', '.join(members)})")
    xm = members[xyz_key]
    if xm.dtype.names or len(xm.shape) != 2 or xm.shape[1] != 3:
        if len(members) == 1 or xm.dtype.names:
            return members, _layout_names(path, f"NPZ member {xm.key!r}", xm.dtype, xm.shape), {xm.key: xm}
        raise fail(path, f"NPZ member {xyz_key!r} must be a numeric (N, 3) array, got shape {xm.shape} dtype {xm.dtype}")
    _check_positions(path, f"NPZ member {xm.key!r}", xm.dtype)
    _check_colors(path, members, xm)
    use = {xyz_key: xm}
    for k, m in members.items():
        if k != xyz_key and m.rows == xm.rows and len(m.shape) in (1, 2) and m.dtype.kind in "biuf":
            use[k] = m
    return members, None, use


class NpzReader(Reader):
    name = "NPZ"
    suffixes = (".npz",)

    def sniff(self, head: bytes) -> bool:
        return head[:4] == b"PK\x03\x04" and b".npy" in head[:200]

    def _zip(self, path: Path) -> zipfile.ZipFile:
        try:
            return zipfile.ZipFile(path)
        except (zipfile.BadZipFile, zlib.error, EOFError, ValueError) as exc:
            raise fail(path, f"corrupt or truncated NPZ (zip) file: {exc}") from None

    def point_count(self, path: Path) -> int | None:
        with self._zip(check_file(path)) as zf:
            _, _table, use = _npz_plan(path, zf)
            return next(iter(use.values())).rows

    def read_chunks(self, path: Path, chunk_size: int = DEFAULT_CHUNK_SIZE) -> Iterator[PointChunk]:
        chunk_size = check_chunk_size(chunk_size)
        path = check_file(path)
        with self._zip(path) as zf:
            try:
                yield from self._chunks(path, zf, chunk_size)
            except (zipfile.BadZipFile, zlib.error, EOFError) as exc:
                raise fail(path, f"corrupt NPZ (zip) data: {exc}") from None

    def _chunks(self, path: Path, zf: zipfile.ZipFile, chunk_size: int) -> Iterator[PointChunk]:
        _, table, use = _npz_plan(path, zf)
        rows = next(iter(use.values())).rows
        if rows == 0:
            raise fail(path, "NPZ archive holds no points (0 rows)", EmptyCloudError)
        scaler = ColorScaler()
        if table is not None:
            (m,) = use.values()
            for block in m.blocks(chunk_size):
                yield _table_chunk(path, table, block, scaler)
            return
        iters = {k: m.blocks(chunk_size) for k, m in use.items()}
        lower = {k.lower(): k for k in use}
        xyz_key = next((lower[k] for k in XYZ_KEYS if k in lower), None)
        color_key = next((lower[k] for k in COLOR_KEYS if k in lower and use[lower[k]].shape[1:] in ((3,), (4,))), None)
        for _ in range(0, rows, chunk_size):
            blocks = {k: next(it) for k, it in iters.items()}
            if xyz_key is not None:
                xyz = blocks.pop(xyz_key)
            else:
                xyz = np.column_stack([blocks.pop(lower[a]) for a in "xyz"])
            rgba = scaler(blocks.pop(color_key)) if color_key else None
            named = ((safe_attribute_name(k), v) for k, v in blocks.items())  # 'a/b' as 'a_b' (core/chunk.py)
            yield PointChunk(xyz.astype(np.float64), rgba, {k: np.array(v) for k, v in named if k is not None})

    def info(self, path: Path) -> dict:
        path = check_file(path)
        with self._zip(path) as zf:
            members, table, use = _npz_plan(path, zf)
        lower = [k.lower() for k in use]
        has_color = any(k in lower for k in COLOR_KEYS) or bool(table and color_names(_names_read(table, next(iter(use.values())).dtype)))
        attributes = [k for k in use if k.lower() not in XYZ_KEYS + COLOR_KEYS + ("x", "y", "z")]
        arrays = {k: {"shape": list(m.shape), "dtype": str(m.dtype)} for k, m in members.items()}
        return scanned_info(path, "NPZ", self.read_chunks(path), has_color, attributes, arrays=arrays)
