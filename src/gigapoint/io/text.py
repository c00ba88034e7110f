"""XYZ / TXT / CSV / PTS: one point per line, streamed in chunks with numpy.loadtxt.

Delimiter sniffed from the first data line (semicolon, comma, else whitespace: spaces or tabs);
a separator that ends a line ("1,2,3,", as some exports write every line) opens no column.
An optional header line names the columns (x y z, red green blue [alpha] or r g b [a],
anything else becomes an attribute, e.g. intensity, nx); CloudCompare's ``//X,Y,Z`` header
works too. Without a header, columns are read by count:

====  ==============================================
 3    x y z
 4    x y z intensity
 6    x y z r g b
 7    x y z intensity r g b   (the PTS layout)
 9    x y z r g b nx ny nz
 10   x y z intensity r g b nx ny nz
 k    x y z, then attributes column_3 ... column_{k-1}
====  ==============================================

A PTS file's first line (the point count alone) is skipped, and so is a count line between two
scans (a multi-scan PTS); a file holding more or fewer points than they sum to is said. Lines starting with ``#`` or
``//`` are comments, and so is what follows either on a line of points ("1 2 3 # note") or on
the header line ("x y z intensity # note"); blank lines are skipped.
"""

from __future__ import annotations

import contextlib
import itertools
import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ..core.chunk import ColorScaler, PointChunk
from ..errors import EmptyCloudError, GigapointWarning, warn
from ._base import (
    DEFAULT_CHUNK_SIZE,
    Reader,
    attribute_names,
    attribute_spelling,
    check_chunk_size,
    check_distinct_names,
    check_file,
    color_names,
    fail,
    read_once,
    rows_to_chunk,
    scanned_info,
)

_BY_COUNT = {
    3: ["x", "y", "z"],
    4: ["x", "y", "z", "intensity"],
    6: ["x", "y", "z", "r", "g", "b"],
    7: ["x", "y", "z", "intensity", "r", "g", "b"],
    9: ["x", "y", "z", "r", "g", "b", "nx", "ny", "nz"],
    10: ["x", "y", "z", "intensity", "r", "g", "b", "nx", "ny", "nz"],
}
_ALIASES = {"red": "r", "green": "g", "blue": "b", "alpha": "a", "//x": "x"}
_MAX_HEADER_LINES = 100
_HEADER_COMMENT = re.compile(r"\s(?:#|//)")
_MAX_LINE = 1 << 16


def _is_comment(line: str) -> bool:
    s = line.lstrip()
    return s.startswith(("#", "//"))


def _without_comment(line: str) -> str:
    """A line of points before the ``#`` or ``//`` comment that may end it ("1 2 3 # note"), as
    loadtxt reads the lines after the first: the first line's comment, split into columns, made
    the file "not numeric point data" (or a column count the header did not name)."""
    for mark in ("#", "//"):
        line = line.split(mark, 1)[0]
    return line


def _sniff_delimiter(line: str) -> str | None:
    for d in (";", ",", "\t"):
        if d in line:
            return d if d != "\t" else None
    return None


def _split(line: str, delimiter: str | None) -> list[str]:
    return [t.strip() for t in (line.split(delimiter) if delimiter else line.split())]


def _values(line: str, delimiter: str | None) -> list[str]:
    """A line's values: "1,2,3," ends with a separator (some exports end every line so), which
    opens no column (the file was "not numeric point data", and not taken from a folder)."""
    tokens = _split(line, delimiter)
    return tokens[:-1] if delimiter is not None and len(tokens) > 1 and tokens[-1] == "" else tokens


def _numeric(tokens: list[str]) -> bool:
    try:
        for t in tokens:
            float(t.strip('"'))  # "1.5": a spreadsheet's quoted number
    except ValueError:
        return False
    return bool(tokens)


def _names_by_count(k: int) -> list[str]:
    return _BY_COUNT.get(k) or (["x", "y", "z"] + [f"column_{i}" for i in range(3, k)])


class _Layout:
    """What the first lines of a text file say: lines to skip, delimiter, column names."""

    def __init__(self, path: Path, skip: int, delimiter: str | None, names: list[str], header: bool, quoted: bool,
                 columns: list[int] | None = None, n_columns: int | None = None, comments_end_lines: bool = True,
                 declared: int | None = None):  # fmt: skip
        self.path, self.skip, self.delimiter, self.names, self.header = path, skip, delimiter, names, header
        self.declared = declared  # a PTS file's point count (its first line); None: not a PTS file
        # a '#' or '//' ends a line of points ("1 2 3 # note"), unless a named column's text starts
        # with one ("#ff0000" under "x y z color": its lines count that column)
        self.comments_end_lines = comments_end_lines
        self.quoted = quoted  # the data's numbers are in double quotes (a spreadsheet's CSV)
        self.columns = columns  # the columns read (None: all); a header's text columns are left out
        self.n_columns = len(names) if n_columns is None else n_columns  # the columns every line has


def _layout(path: Path) -> _Layout:
    """The file's layout, read once an operation (``read_once``): its header, the empty-file
    check and its points each ask, and its warnings are said once."""
    return read_once("text layout", path, lambda: _read_layout(path))


def _read_layout(path: Path) -> _Layout:
    try:
        with open(path, encoding="utf-8-sig") as f:
            first: list[tuple[int, str]] = []
            for lineno in itertools.count(1):
                line = f.readline(_MAX_LINE + 1)
                if not line:
                    break
                if len(line) > _MAX_LINE:
                    raise fail(path, f"line {lineno} is longer than {_MAX_LINE:,} characters: not a text point file")
                if not line.strip():
                    continue
                first.append((lineno, line.rstrip("\r\n")))
                if sum(not _is_comment(ln) for _, ln in first) >= 3 or lineno > _MAX_HEADER_LINES:
                    break
    except UnicodeDecodeError:
        raise fail(path, "not a text point file (bytes that are not UTF-8 text)") from None
    except OSError as exc:
        raise fail(path, exc.strerror or exc) from None
    skip = 0
    header_names: list[str] | None = None
    candidates = list(first)
    # header: the first line that is not a comment, or a comment line naming x y z (CloudCompare's "//X,Y,Z")
    for i, (lineno, line) in enumerate(candidates):
        # a comment ends it where its mark starts a word ("x y z intensity # note" named 3 more
        # columns); one inside a name is the name's ("x,y,z,#returns", "Scan#")
        body = _HEADER_COMMENT.split(line.lstrip().lstrip("#/"), maxsplit=1)[0].strip()
        tokens = _split(body, _sniff_delimiter(body))
        spelled = [_ALIASES.get(t.strip("'\"").lower(), attribute_spelling(t.strip("'\""))) for t in tokens]
        if not _numeric(tokens) and {"x", "y", "z"} <= set(spelled):
            check_distinct_names(path, [t.strip("'\"") for t in tokens], spelled)
            header_names = spelled
            skip = lineno
            candidates = candidates[i + 1 :]
            break
        if not _is_comment(line):
            break
    # PTS: a point count alone on the first line
    declared = None
    if header_names is None and len(candidates) >= 2 and _pts_count(candidates[0][1]) is not None and len(candidates[1][1].split()) >= 3:
        skip, declared = candidates[0][0], _pts_count(candidates[0][1])
        candidates = candidates[1:]
    data = [c for c in candidates if not _is_comment(c[1])]
    if not data and first and first[-1][0] > _MAX_HEADER_LINES:
        raise fail(path, f"no point data in the first {_MAX_HEADER_LINES} lines (only comments)")
    if not data:
        if header_names is not None:
            raise fail(path, "holds a header line but no points", EmptyCloudError)
        raise fail(path, "holds no points", EmptyCloudError)
    lineno, line = data[0]
    values = _without_comment(line)  # (its separator a comma in the comment: "1 2 3 # a, b")
    delimiter = _sniff_delimiter(values)
    tokens, n_columns = _values(values, delimiter), len(_split(values, delimiter))
    if header_names and header_names[-1] == "":  # ("x,y,z,": its last separator names no column either)
        header_names = header_names[:-1]
    hash_column = header_names is not None and len(header_names) == len(_split(line, delimiter)) != len(tokens)
    if hash_column:
        values = line  # a named column of text starting with '#' ("#ff0000"), not a comment: left out below, as before
        tokens, n_columns = _split(line, delimiter), len(header_names)
    columns = list(range(len(tokens))) if len(tokens) < n_columns else None
    if header_names is None and not _numeric(tokens):
        raise fail(path, f"line {lineno}: not numeric point data: {line[:80]!r}")
    quoted = '"' in values
    if header_names is not None:
        if len(header_names) != len(tokens):
            raise fail(path, f"line {lineno} has {len(tokens)} columns, the header names {len(header_names)}")
        # a named column of text (a label, a class name) is left out, said once: it refused the whole file
        text = [i for i, t in enumerate(tokens) if not _numeric([t]) and header_names[i] not in ("x", "y", "z")]
        if text:
            warn(
                f"{path}: column(s) {', '.join(header_names[i] for i in text)} hold text, not numbers: left out", GigapointWarning
            )
            kept = [i for i in range(len(tokens)) if i not in text]
            return _Layout(path, skip, delimiter, [header_names[i] for i in kept], True, quoted, kept, n_columns, not hash_column)
        names = header_names
    else:
        if len(tokens) < 3:
            raise fail(path, f"line {lineno} has {len(tokens)} columns, expected at least 3 (x y z)")
        names = _names_by_count(len(tokens))
    return _Layout(path, skip, delimiter, names, header_names is not None, quoted, columns, n_columns, declared=declared)


def _pts_count(line: str) -> int | None:
    """The point count of a PTS count line (one integer alone), else None."""
    tokens = line.split()
    return int(tokens[0]) if len(tokens) == 1 and tokens[0].isdecimal() else None


def _line_columns(line: str, layout: _Layout) -> list[str]:
    """A line of points split into its columns, as the layout counts them."""
    line = line.rstrip("\r\n")
    return _split(_without_comment(line) if layout.comments_end_lines else line, layout.delimiter)


def _first_bad_line(path: Path, lines: list[str], first_lineno: int, layout: _Layout, ncols: int, columns=None) -> tuple[int, str]:
    """The index in ``lines`` of the first unparsable line of a chunk and what is wrong with it
    (only called after loadtxt failed); ``columns``: those read (None: all)."""
    for i, line in enumerate(lines):
        if not line.strip() or _is_comment(line):
            continue
        tokens = _line_columns(line, layout)
        if len(tokens) != ncols:
            return i, f"line {first_lineno + i} has {len(tokens)} columns, expected {ncols}"
        for t in tokens if columns is None else [tokens[c] for c in columns]:
            try:
                float(t.strip('"'))
            except ValueError:
                return i, f"line {first_lineno + i}: {t[:40]!r} is not a number"
    return 0, "unparsable data"


def _parsed(lines: list[str], delimiter: str | None, columns: list[int] | None = None) -> np.ndarray:
    # a chunk of comments and blank lines is not given to loadtxt, which warns "input contained no data":
    # a catch_warnings here, on a progressive load's decoder thread, swapped the process's filters
    # under the caller's own catch (its records lost, its filters left behind)
    if not any(ln.strip() and not _is_comment(ln) for ln in lines):
        return np.empty((0, 0))
    return np.loadtxt(lines, delimiter=delimiter, comments=("#", "//"), ndmin=2, dtype=np.float64, usecols=columns)


def _parsed_lines(lines: list[str], layout: _Layout) -> np.ndarray | None:
    """Lines of points as an array of the columns read; None where a line does not parse."""
    try:
        arr = _parsed(lines, layout.delimiter, layout.columns)
    except ValueError:
        return None
    if arr.size and arr.shape[1] != len(layout.names):
        return None
    # usecols reads short lines as long as they reach the columns used
    if layout.columns is not None and not all(len(_line_columns(ln, layout)) == layout.n_columns for ln in lines if ln.strip() and not _is_comment(ln)):
        return None
    return arr


def _chunks(path: Path, chunk_size: int, layout: _Layout, counts: list[int]) -> Iterator[np.ndarray]:
    """The file's points, ``chunk_size`` lines at a time; a PTS file's count lines are appended to ``counts``."""
    ncols, used, columns = layout.n_columns, len(layout.names), layout.columns
    try:
        with open(path, encoding="utf-8-sig") as f:
            lineno = layout.skip + 1
            for _ in range(layout.skip):
                next(f)
            while True:
                lines = list(itertools.islice(f, chunk_size))
                if not lines:
                    return
                if layout.quoted:  # "1.5": a spreadsheet's quoted numbers (loadtxt's quotechar excludes two comment marks)
                    lines = [ln.replace('"', "") for ln in lines]
                if layout.declared is not None:  # a multi-scan PTS: each next scan's count line, read as a blank one
                    # (found before parsing: one failed parse per count line re-read the chunk, quadratic in scans)
                    for i, line in enumerate(lines):
                        if line.strip().isdecimal():
                            counts.append(int(line))
                            lines[i] = "\n"
                arr = _parsed_lines(lines, layout)
                if arr is None:
                    bad, problem = _first_bad_line(path, lines, lineno, layout, ncols, columns)
                    with contextlib.suppress(ValueError):  # the lines before the bad one first: a progressive load keeps them
                        before = _parsed(lines[:bad], layout.delimiter, columns) if bad else np.empty((0, used))
                        if before.size and before.shape[1] == used:
                            yield before
                    raise fail(path, problem)
                lineno += len(lines)
                if arr.size:
                    yield arr
    except UnicodeDecodeError:
        raise fail(path, "not a text point file (bytes that are not UTF-8 text)") from None


class TextReader(Reader):
    name = "XYZ/TXT/CSV"
    suffixes = (".xyz", ".txt", ".csv", ".pts", ".asc", ".xyzrgb")
    shared_suffixes = (".txt", ".csv", ".asc")

    def reads_slowly(self, path: Path) -> bool:
        return True  # every value parsed

    def weak_sniff(self, head: bytes) -> bool:
        try:
            text = head.decode("utf-8")
        except UnicodeDecodeError:
            text = head[:-4].decode("utf-8", "ignore") if len(head) > 4 else ""
        lines = [ln for ln in text.splitlines()[:-1] if ln.strip() and not _is_comment(ln)] or [ln for ln in text.splitlines() if ln.strip()]
        for line in map(_without_comment, lines[:3]):
            tokens = _values(line, _sniff_delimiter(line))
            if len(tokens) >= 3 and _numeric(tokens):
                return True
        return False

    def read_chunks(self, path: Path, chunk_size: int = DEFAULT_CHUNK_SIZE) -> Iterator[PointChunk]:
        chunk_size = check_chunk_size(chunk_size)
        path = check_file(path)
        layout = _layout(path)
        scaler = ColorScaler()  # colors arrive as floats: 0..1, 0..255 or 0..65535, decided once per file
        total, counts = 0, [layout.declared]
        for arr in _chunks(path, chunk_size, layout, counts):
            total += len(arr)
            yield rows_to_chunk(path, layout.names, [arr[:, i] for i in range(arr.shape[1])], scaler)
        if total == 0:
            raise fail(path, "holds no points", EmptyCloudError)
        if layout.declared is not None and sum(counts) != total:  # (a PTS cut at a line's end was read without a word)
            scans = f" ({len(counts)} scans)" if len(counts) > 1 else ""
            warn(f"{path}: PTS file declares {sum(counts):,} points{scans}, holds {total:,}: those read", GigapointWarning)

    def header(self, path: Path, salvage: bool = False) -> dict:
        """Its columns from its first lines; the points are counted only when read."""
        names = _layout(check_file(path)).names
        return {"point_count": None, "attributes": attribute_names(names, color_names(names))}

    def info(self, path: Path) -> dict:
        path = check_file(path)
        layout = _layout(path)
        cols = color_names(layout.names)
        return scanned_info(
            path,
            "text",
            self.read_chunks(path),
            bool(cols),
            attribute_names(layout.names, cols),  # as read names them (foo/bar: foo_bar)
            columns=layout.names,
            delimiter={None: "whitespace", ",": "comma", ";": "semicolon"}[layout.delimiter],
            header_line=layout.header,
        )
