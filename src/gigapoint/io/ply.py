"""PLY (ascii and binary little/big endian): the ``vertex`` element, streamed in chunks.

plyfile parses the header (element and property types). Binary vertex data without list
properties is memory-mapped and copied chunk by chunk; ascii vertex lines are parsed
chunk by chunk with numpy.loadtxt (a list property's values left out of each line). Binary
list properties before or inside the vertex element fall back to plyfile reading the whole file.
Vertex properties: x y z, red green blue [alpha] (also r g b, diffuse_*), the rest
(nx ny nz, intensity, scalar_*...) become attributes: those gigapoint reads by name (normals,
LAS fields) in lower case whatever the file's case, any other as the file spells it
(``_base.attribute_spelling``). Without those, colours come from PCL's
packed 4-byte ``rgb``/``rgba`` (consumed) or a 3D Gaussian splat's ``f_dc_0..2`` (kept).
A binary mesh's elements after the vertices (faces) are walked, not read, to check that they
end where the file does: a header that overstates the vertex count is refused, not read as
vertices made of the faces' bytes. PLY has no field for a CRS: gigapoint writes it in a
``comment crs <WKT or EPSG:n>`` header line and reads it back (other readers skip comments).
"""

from __future__ import annotations

import io
import itertools
import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ..core.chunk import ColorScaler, PointChunk
from ..errors import EmptyCloudError
from ._base import (
    DEFAULT_CHUNK_SIZE,
    SALVAGE_HINT,
    Reader,
    attribute_names,
    check_chunk_size,
    check_file,
    color_names,
    fail,
    packed_rgb_field,
    rows_to_chunk,
    scan_bounds,
    unpack_rgb,
)

_MAX_HEADER = 1 << 20
#: the header's last line (blanks after the word taken, as other readers take them)
_END_HEADER = re.compile(rb"[\r\n]end_header[ \t\r]*\n")

#: a header comment naming the points' CRS starts so (io/write.py writes it)
PLY_CRS_COMMENT = "crs "

#: 3D Gaussian splats' degree-0 spherical harmonic, 1 / (2 sqrt(pi)): colour = 0.5 + SH_C0 * f_dc
SH_C0 = 0.28209479177387814


def _without_lists(line: str, props, lists: set) -> str:
    """An ASCII vertex line without its list properties' values (a length, then that many):
    the points leave them out. A line they do not fit stays as it is, for the column check to name."""
    tokens, kept, i = line.split(), [], 0
    for p in props:
        if i >= len(tokens):
            return line
        if p.name in lists:
            if not tokens[i].isdigit():
                return line
            i += 1 + int(tokens[i])
        else:
            kept.append(tokens[i])
            i += 1
    return " ".join(kept) + "\n" if i == len(tokens) else line


class _Header:
    def __init__(self, path: Path):
        import plyfile

        self.path = path
        with open(path, "rb") as f:
            head = f.read(_MAX_HEADER)
        if not head.startswith(b"ply"):
            raise fail(path, f"not a PLY file (starts with {head[:4]!r}, expected b'ply')")
        end = _END_HEADER.search(head)  # the line, not the first "end_header": a property may be named so
        if end is None:
            raise fail(path, "truncated or corrupt PLY header (no 'end_header' line)")
        self.data_offset = end.end()
        self.header_lines = head[: self.data_offset].count(b"\n")
        # plyfile takes the line end from the first line and no blank after a line's words:
        # "end_header \n", or "end_header\r\n" after "ply\n", was "early end-of-file" (other readers take them)
        self.header_text = b"".join(line.rstrip() + b"\n" for line in head[: self.data_offset].splitlines())
        try:
            ply = plyfile.PlyData._parse_header(io.BytesIO(self.header_text))
        except Exception as exc:  # noqa: BLE001 - plyfile.PlyHeaderParseError and friends
            raise fail(path, f"corrupt PLY header: {exc}") from None
        negative = [el for el in ply.elements if el.count < 0]
        if negative:  # plyfile takes "element vertex -5": numpy's "negative dimensions" came later
            raise fail(path, f"corrupt PLY header: element {negative[0].name!r} has a negative count ({negative[0].count})")
        self.ply = ply
        self.crs = next((c.removeprefix(PLY_CRS_COMMENT).strip() for c in ply.comments if c.startswith(PLY_CRS_COMMENT)), None) or None
        self.text = ply.text
        self.byte_order = ply.byte_order
        self.file_size = path.stat().st_size
        self.vertex = None
        self.before = []
        for el in ply.elements:
            if el.name == "vertex":
                self.vertex = el
                break
            self.before.append(el)
        self.after = ply.elements[len(self.before) + 1 :]  # (a mesh's faces)
        if self.vertex is None:
            raise fail(path, f"PLY file has no 'vertex' element (elements: {', '.join(e.name for e in ply.elements) or 'none'})")
        self.names = [p.name for p in self.vertex.properties]
        self.scalar_names = [p.name for p in self.vertex.properties if not isinstance(p, plyfile.PlyListProperty)]  # lists are left out
        if not {"x", "y", "z"} <= {n.lower() for n in self.names}:
            raise fail(path, f"PLY vertex element has no x, y, z properties (has {', '.join(self.names)})")
        self.count = self.vertex.count
        self.colors = color_names(self.names)
        lower = [n.lower() for n in self.scalar_names]
        self.packed = self.splat = None  # where colours come from without red green blue (a field name; f_dc's names)
        if not self.colors:
            self.packed = packed_rgb_field({p.name: np.dtype(p.val_dtype).itemsize for p in self.vertex.properties if p.name in self.scalar_names})
            if self.packed is None and {"f_dc_0", "f_dc_1", "f_dc_2"} <= set(lower):
                self.splat = [self.scalar_names[lower.index(f"f_dc_{k}")] for k in range(3)]
        self.has_color = bool(self.colors or self.packed or self.splat)
        self.attributes = attribute_names([n for n in self.scalar_names if n != self.packed], self.colors)
        self.has_lists = any(isinstance(p, plyfile.PlyListProperty) for el in [*self.before, self.vertex] for p in el.properties)

    def chunk(self, names: list[str], cols: list[np.ndarray], scaler: ColorScaler) -> PointChunk:
        """rows_to_chunk of the vertices' columns, with red green blue made of a packed ``rgb`` or ``f_dc_0..2``."""
        if self.packed or self.splat:
            col = dict(zip(names, cols))
            if self.packed:
                rgb = unpack_rgb(col.pop(self.packed))
            else:  # (as splat viewers draw them: the view-independent colour, clamped)
                dc = np.column_stack([col[n] for n in self.splat]).astype(np.float64)
                rgb = (np.clip(0.5 + SH_C0 * np.nan_to_num(dc), 0, 1) * 255 + 0.5).astype(np.uint8)
            names, cols = [*col, "red", "green", "blue"], [*col.values(), *rgb.T]
        return rows_to_chunk(self.path, names, cols, scaler)


#: a face's list of vertex indices (as the PLY format names it; some writers drop the s): 3 at least
_FACE_CORNERS = ("vertex_indices", "vertex_index")

#: bytes an ASCII vertex takes at least: three one-digit numbers, two spaces and a newline
_LEAST_ASCII_VERTEX = 6


class PlyReader(Reader):
    name = "PLY"
    suffixes = (".ply",)

    def sniff(self, head: bytes) -> bool:
        return head[:4] in (b"ply\n", b"ply\r")

    def reads_slowly(self, path: Path) -> bool:
        return _Header(check_file(path)).text  # ASCII: every value parsed

    def point_count(self, path: Path) -> int | None:
        """The header's vertex count, after checking the file can hold that many: a binary file's
        bytes exactly, an ASCII one's at 6 bytes a vertex at least ("0 0 0\\n"). A count of 10^12
        in 45 kB was refused for the memory it would take, with advice to load it progressively."""
        return self.header(path)["point_count"]

    def header(self, path: Path, salvage: bool = False) -> dict:
        """Also ``has_color``: whether its vertices have color properties (a COPC output of
        points without them is written without colors); ``crs``: what its ``comment crs`` line
        names, None without one."""
        path = check_file(path)
        h = _Header(path)
        short = None
        if not h.has_lists and h.text:
            have = h.file_size - h.data_offset
            if h.count * _LEAST_ASCII_VERTEX - 1 > have:  # (the last line may end without its newline)
                short = (f"truncated PLY file: the header declares {h.count:,} vertices but only {max(have, 0):,} bytes follow "
                         f"(room for {(max(have, 0) + 1) // _LEAST_ASCII_VERTEX:,} at most)")  # fmt: skip
        elif not h.has_lists:
            short = self._binary_span(path, h)[2]
        if short and not salvage:
            raise fail(path, short + SALVAGE_HINT)
        head = {"point_count": h.count, "has_color": h.has_color, "attributes": h.attributes, "crs": h.crs}
        return head if short is None else {**head, "truncated": short}

    def read_salvaged(self, path: Path, chunk_size: int = DEFAULT_CHUNK_SIZE) -> Iterator[PointChunk]:
        return self.read_chunks(path, chunk_size, salvage=True)

    def read_chunks(self, path: Path, chunk_size: int = DEFAULT_CHUNK_SIZE, salvage: bool = False) -> Iterator[PointChunk]:
        """``salvage``: a file cut off gives the vertices before the cut, then its error (``read_salvaged``)."""
        chunk_size = check_chunk_size(chunk_size)
        path = check_file(path)
        h = _Header(path)
        if h.count == 0:
            raise fail(path, "PLY file holds no points (vertex count is 0)", EmptyCloudError)
        scaler = ColorScaler()
        if h.text:
            yield from self._read_ascii(path, h, chunk_size, scaler)
        elif h.has_lists:
            yield from self._read_plyfile(path, h, chunk_size, scaler)
        else:
            yield from self._read_binary(path, h, chunk_size, scaler, salvage)

    @staticmethod
    def _binary_span(path, h: _Header) -> tuple[int, np.dtype, str | None]:
        """(offset, record dtype, why the vertices are not all there or None) of a binary file's vertices."""
        offset = h.data_offset + sum(el.count * el.dtype(h.byte_order).itemsize for el in h.before)
        dtype = h.vertex.dtype(h.byte_order)
        need = h.count * dtype.itemsize
        have = h.file_size - offset
        short = None
        if need > have:
            short = (f"truncated PLY file: the header declares {h.count:,} vertices ({need:,} bytes) "
                     f"but only {max(have, 0):,} bytes follow (room for {max(have, 0) // dtype.itemsize:,})")  # fmt: skip
        if short is None and h.after:
            PlyReader._check_after_vertices(path, h, offset + need)
        return offset, dtype, short

    @staticmethod
    def _check_after_vertices(path, h: _Header, vertex_end: int) -> None:
        """The elements after the vertices (a mesh's faces) end where the file ends. A header that
        declares more vertices than the file holds read the faces' bytes as vertices when the
        faces had room for them (their list lengths walked, as their records' sizes vary; a walk
        begun off a record's start can fall back into step, where a face of fewer than 3 corners,
        often a high byte of an index, gives it away)."""
        import plyfile

        end = vertex_end
        if h.file_size > vertex_end:
            data = np.memmap(h.path, dtype=np.uint8, mode="r")
            try:
                for el in h.after:
                    props = el.properties
                    lists = [isinstance(p, plyfile.PlyListProperty) for p in props]
                    len_types = [np.dtype(p.len_dtype) if is_list else None for p, is_list in zip(props, lists)]
                    from .ply_kernels import _records_end

                    end = _records_end(
                        data, end, el.count,
                        np.array([t.itemsize if t else 0 for t in len_types], np.int64),
                        np.array([bool(t and t.kind == "i") for t in len_types]),
                        np.array([np.dtype(p.val_dtype).itemsize for p in props], np.int64),
                        np.array([3 if el.name == "face" and p.name in _FACE_CORNERS else 0 for p in props], np.int64),
                        h.byte_order == ">",
                    )  # fmt: skip
                    if end < 0:
                        break
            finally:
                del data
        elif any(el.count for el in h.after):
            end = -1
        if end != h.file_size:
            after = ", ".join(f"{el.count:,} {el.name!r}" for el in h.after)
            raise fail(path, f"corrupt PLY file: the elements after its {h.count:,} vertices ({after}) do not fit the "
                             f"{h.file_size - vertex_end:,} bytes after them: the header's vertex count is not the number "
                             "of vertices the file holds, or the file is cut off")  # fmt: skip

    def _read_binary(self, path, h: _Header, chunk_size, scaler, salvage: bool = False) -> Iterator[PointChunk]:
        offset, dtype, short = self._binary_span(path, h)
        if short and not salvage:
            raise fail(path, short + SALVAGE_HINT)
        present = h.count if short is None else max(h.file_size - offset, 0) // dtype.itemsize
        mm = np.memmap(path, dtype=dtype, mode="r", offset=offset, shape=(present,)) if present else np.empty(0, dtype)
        try:
            for start in range(0, present, chunk_size):
                block = np.array(mm[start : start + chunk_size])  # copy out of the map
                native = block.astype(block.dtype.newbyteorder("="), copy=False)
                yield h.chunk(h.names, [np.asarray(native[n]) for n in h.names], scaler)
        finally:
            del mm
        if short:
            raise fail(path, short)

    def _read_ascii(self, path, h: _Header, chunk_size, scaler) -> Iterator[PointChunk]:
        props = [p for p in h.vertex.properties if p.name in h.scalar_names]
        lists = {p.name for p in h.vertex.properties} - set(h.scalar_names)
        ncols = len(props)
        dtypes = [p.val_dtype for p in props]
        with open(path, "rb") as raw:
            raw.seek(h.data_offset)
            f = io.TextIOWrapper(raw, encoding="ascii", errors="replace")
            skip = sum(el.count for el in h.before)
            lineno = h.header_lines + 1  # number of the first data line
            for _ in itertools.islice(f, skip):
                lineno += 1
            done, cut = 0, ""
            while done < h.count:
                lines = list(itertools.islice(f, min(chunk_size, h.count - done)))
                if lines and not lines[-1].endswith("\n") and done + len(lines) < h.count:
                    lines.pop()  # the file ends mid-line before its last vertex: a cut, not a vertex (its error below)
                    cut = " (the file ends part-way through the next)"
                if not lines:
                    break
                if lists:  # (plyfile's loadtxt of an empty list warned "no data": a catch_warnings is process-wide)
                    lines = [_without_lists(ln, h.vertex.properties, lists) for ln in lines]
                if not any(ln.strip() for ln in lines):  # blank: loadtxt's "no data" warning, not silenced by a catch_warnings
                    raise fail(path, self._bad_line(lines, lineno, ncols, lists))  # (process-wide: it swapped a caller's filters meanwhile)
                try:
                    arr = np.loadtxt(lines, ndmin=2, dtype=np.float64, comments=None)
                except ValueError:
                    raise fail(path, self._bad_line(lines, lineno, ncols, lists)) from None
                if len(arr) != len(lines) or (arr.size and arr.shape[1] != ncols):
                    raise fail(path, self._bad_line(lines, lineno, ncols, lists))
                for i, prop in enumerate(props):
                    self._check_integers(path, arr[:, i], prop, lineno)
                lineno += len(lines)
                done += len(arr)
                # each column in its declared type, as the binary path keeps it; x, y, z as parsed
                # (float64: the text may hold more digits than a declared float keeps)
                cols = [arr[:, i] if name.lower() in ("x", "y", "z") else arr[:, i].astype(np.dtype(dt), copy=False)
                        for i, (name, dt) in enumerate(zip(h.scalar_names, dtypes))]  # fmt: skip
                yield h.chunk(h.scalar_names, cols, scaler)
        if done < h.count:
            raise fail(path, f"truncated PLY file: the header declares {h.count:,} vertices, only {done:,} lines of them are present{cut}")

    @staticmethod
    def _check_integers(path, values: np.ndarray, prop, first_lineno: int) -> None:
        """An integer property's values are whole and in its type's range: a cast wrapped 300 to 44
        in a uchar and made a NaN any number (numpy's warning on the loader's thread, no error;
        plyfile refuses such a file too)."""
        dtype = np.dtype(prop.val_dtype)
        if dtype.kind not in "iu" or prop.name.lower() in ("x", "y", "z"):  # (x, y, z kept as parsed, below)
            return
        info = np.iinfo(dtype)
        bad = ~((values >= info.min) & (values <= info.max) & (values == np.round(values)))  # (NaN: every comparison False)
        if bad.any():
            i = int(np.argmax(bad))
            declared = str(prop).split()[-2]  # ("property uchar intensity")
            raise fail(path, f"line {first_lineno + i}: {prop.name} is {values[i]:g}, not a {declared} as the header declares")

    @staticmethod
    def _bad_line(lines, first_lineno, ncols, lists=()) -> str:
        for i, line in enumerate(lines):
            tokens = line.split()
            if len(tokens) != ncols:  # (a line with lists its lengths do not fit: as it was, _without_lists)
                declared = f"{ncols} besides its list {', '.join(sorted(lists))} (a length, then that many values)" if lists else ncols
                return f"line {first_lineno + i} has {len(tokens)} values, the vertex element declares {declared}"
            for t in tokens:
                try:
                    float(t)
                except ValueError:
                    return f"line {first_lineno + i}: {t[:40]!r} is not a number"
        return "corrupt vertex data"

    def _read_plyfile(self, path, h: _Header, chunk_size, scaler) -> Iterator[PointChunk]:
        """A binary file with list properties (an ASCII one's are left out of its lines: _read_ascii)."""
        import plyfile

        try:
            with open(path, "rb") as f:  # (the header as _Header took it)
                f.seek(h.data_offset)
                ply = plyfile.PlyData.read(io.BytesIO(h.header_text + f.read()))
            data = ply["vertex"].data
        except plyfile.PlyElementParseError as exc:
            if exc.message == "early end-of-file" and exc.element is not None and exc.row is not None:  # a cut, said as the other paths say it
                what = "vertices" if exc.element.name == "vertex" else f"{exc.element.name!r} elements"
                raise fail(path, f"truncated PLY file: {exc.row:,} of {exc.element.count:,} {what} present") from None
            raise fail(path, f"corrupt PLY data: {exc}") from None
        except Exception as exc:  # noqa: BLE001 - plyfile raises many types on corrupt data
            raise fail(path, f"corrupt PLY data: {exc}") from None
        if len(data) < h.count:
            raise fail(path, f"truncated PLY file: {len(data):,} of {h.count:,} vertices present")
        keep = [n for n in data.dtype.names if data.dtype[n].kind != "O"]
        for start in range(0, len(data), chunk_size):
            block = data[start : start + chunk_size]
            yield h.chunk(keep, [np.asarray(block[n]) for n in keep], scaler)

    def info(self, path: Path) -> dict:
        path = check_file(path)
        h = _Header(path)
        n, lo, hi = scan_bounds(self.read_chunks(path)) if h.count else (0, None, None)
        return {
            "path": str(path),
            "format": "PLY",
            "encoding": "ascii" if h.text else {"<": "binary little endian", ">": "binary big endian"}.get(h.byte_order, "binary"),
            "point_count": n,
            "bounds": {"min": lo, "max": hi},
            "bounds_source": "data",
            "has_color": h.has_color,
            "attributes": h.attributes,  # as read (attribute_spelling), no list property
            "elements": {el.name: el.count for el in h.ply.elements},
            "crs": h.crs,
            "file_size": h.file_size,
        }
