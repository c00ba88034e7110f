"""What files' points hold, read once in bounded chunks (``gigapoint info --stats``,
``gigapoint.io.point_stats``): the QA a surveyor runs on a delivery, as ``lasinfo -histo`` and
``pdal info --stats`` give it.

``PointStats`` is a running accumulator: ``add(chunk)`` a chunk at a time (memory stays one
chunk's whatever the file's size), ``merge`` another's (a folder's files summed), ``result()``
the numbers as a JSON-able dict. ``stream_stats`` counts any one dataset's chunks (an octree's
nodes: lod/query.py's ``octree_stats``); ``file_stats`` reads one file so and compares the
points' true bounds with its header's (a stale header is a finding); given a ``PointFilter``
(io/filters.py: what is inside a site boundary, the ground points), of the points it keeps.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np

from ..core.chunk import DEFAULT_COLOR, ColorScaler, PointChunk
from ..core.coords import valid_mask as _valid_mask
from ._base import STREAM_CHUNK_SIZE, check_chunk_size, headers_once
from .filters import PointFilter, filtered
from .las import LasReader, read_las_header
from .las_fields import class_name
from .registry import reader_for

#: flight lines (point_source_id) listed one by one up to this many; above, only how many
SOURCES_LISTED = 20

#: adjusted standard GPS time is GPS time (seconds since this epoch) less 1e9 (LAS 1.4 R15, global encoding bit 0)
GPS_EPOCH = datetime(1980, 1, 6, tzinfo=UTC)
ADJUSTED_GPS_OFFSET = 1e9

#: how a file's gps_time counts (``time_kind``)
ADJUSTED, WEEK, UNKNOWN = "adjusted standard GPS time", "seconds of a GPS week", "unknown"


def gps_date(t: float) -> str:
    """An adjusted standard GPS time as a date, 'YYYY-MM-DD HH:MM:SS' on the GPS time scale (no
    leap seconds: 18 s ahead of UTC since 2017)."""
    return (GPS_EPOCH + timedelta(seconds=t + ADJUSTED_GPS_OFFSET)).strftime("%Y-%m-%d %H:%M:%S")


def _codes(values: np.ndarray, most: int) -> np.ndarray | None:
    """``values`` as int64 codes 0..``most`` (a text file's float column of whole numbers too),
    None where any is not one (a histogram of them would be no histogram)."""
    if values.size == 0:
        return np.zeros(0, np.int64)
    if values.dtype.kind == "f" and not np.all(np.isfinite(values) & (values == np.round(values))):
        return None
    codes = values.astype(np.int64, copy=False).ravel()
    return codes if 0 <= codes.min() and codes.max() <= most else None


class PointStats:
    """Running statistics of points, added a chunk at a time; invalid points (NaN, inf, beyond
    ``MAX_ABS_COORDINATE``: those every build skips) are counted and left out of the rest."""

    def __init__(self) -> None:
        self.files = 0
        self.filter: str | None = None  # what the filter applied keeps (``PointFilter.describe``), None without one
        self.read = 0  # points read, before the filter: ``points`` are those it kept
        self.scale: np.ndarray | None = None  # the finest resolution the files store coordinates at, where they say
        self.points = 0
        self.invalid = 0
        self.lo, self.hi = np.full(3, np.inf), np.full(3, -np.inf)
        self.header_lo, self.header_hi = np.full(3, np.inf), np.full(3, -np.inf)
        self.stale: list[str] = []  # files whose header bounds are not their points'
        self.attributes: dict[str, list] = {}  # name -> [count, min, max, sum]
        self.classes = np.zeros(256, np.int64)
        self.returns = np.zeros((16, 16), np.int64)  # [return_number, number_of_returns]
        self.sources = np.zeros(65536, np.int64)  # points per point_source_id
        self.time_kinds: set[str] = set()
        self.colored = False
        self.color_lo, self.color_hi = np.full(3, 255, np.int64), np.zeros(3, np.int64)
        self.color_bits: set[int | None] = set()

    def add(self, chunk: PointChunk) -> None:
        """Count one chunk's points."""
        valid = _valid_mask(chunk.xyz)
        every = bool(valid.all())
        self.points += len(chunk)
        self.invalid += len(chunk) - int(valid.sum())
        xyz = chunk.xyz if every else chunk.xyz[valid]
        if len(xyz) == 0:
            return
        self.lo, self.hi = np.minimum(self.lo, xyz.min(axis=0)), np.maximum(self.hi, xyz.max(axis=0))
        attrs = chunk.attributes if every else {name: values[valid] for name, values in chunk.attributes.items()}
        for name, values in attrs.items():
            self._add_attribute(name, values)
        if "return_number" in attrs and "number_of_returns" in attrs:
            self._add_returns(attrs["return_number"], attrs["number_of_returns"])
        rgb = chunk.rgba[:, :3] if every else chunk.rgba[valid, :3]
        self.colored = self.colored or bool(np.any(rgb != np.array(DEFAULT_COLOR[:3], np.uint8)))
        self.color_lo = np.minimum(self.color_lo, rgb.min(axis=0))
        self.color_hi = np.maximum(self.color_hi, rgb.max(axis=0))

    def _add_attribute(self, name: str, values: np.ndarray) -> None:
        v = values.astype(np.uint8) if values.dtype.kind == "b" else values
        if v.dtype.kind == "f":
            v = v[np.isfinite(v)]  # (an extra bytes field's "no data" NaN)
        if v.size:
            count, lo, hi, total = self.attributes.get(name, [0, np.inf, -np.inf, 0.0])
            self.attributes[name] = [count + v.size, min(lo, v.min().item()), max(hi, v.max().item()), total + float(np.sum(v, dtype=np.float64))]
        codes = _codes(values, 255) if name == "classification" else None
        if codes is not None:
            self.classes += np.bincount(codes, minlength=256)
        codes = _codes(values, 65535) if name == "point_source_id" else None
        if codes is not None:
            self.sources += np.bincount(codes, minlength=65536)

    def _add_returns(self, return_number: np.ndarray, number_of_returns: np.ndarray) -> None:
        """Count a chunk's (return_number, number_of_returns) pairs (LAS: 0..15 each)."""
        r, n = _codes(return_number, 15), _codes(number_of_returns, 15)
        if r is not None and n is not None:
            self.returns += np.bincount(r * 16 + n, minlength=256).reshape(16, 16)

    def merge(self, other: PointStats) -> None:
        """Add another's points (a folder's next file)."""
        self.files += other.files
        self.filter = self.filter or other.filter  # (one filter an operation)
        self.read += other.read
        self.points += other.points
        self.invalid += other.invalid
        self.lo, self.hi = np.minimum(self.lo, other.lo), np.maximum(self.hi, other.hi)
        self.header_lo, self.header_hi = np.minimum(self.header_lo, other.header_lo), np.maximum(self.header_hi, other.header_hi)
        self.stale += other.stale
        if other.scale is not None:
            self.scale = other.scale if self.scale is None else np.minimum(self.scale, other.scale)
        for name, (count, lo, hi, total) in other.attributes.items():
            mine = self.attributes.get(name, [0, np.inf, -np.inf, 0.0])
            self.attributes[name] = [mine[0] + count, min(mine[1], lo), max(mine[2], hi), mine[3] + total]
        self.classes += other.classes
        self.returns += other.returns
        self.sources += other.sources
        self.time_kinds |= other.time_kinds
        if other.colored:
            self.colored = True
            self.color_lo, self.color_hi = np.minimum(self.color_lo, other.color_lo), np.maximum(self.color_hi, other.color_hi)
            self.color_bits |= other.color_bits

    def result(self) -> dict:
        """The statistics as plain numbers (JSON-able)."""
        out: dict = {"files": self.files, "point_count": self.points, "invalid_points": self.invalid}
        out["filter"] = None if self.filter is None else {"applied": self.filter, "points_read": self.read, "points_kept": self.points}
        seen = bool(np.all(np.isfinite(self.lo)))
        out["bounds"] = {"min": self.lo.tolist(), "max": self.hi.tolist()} if seen else None
        headed = bool(np.all(np.isfinite(self.header_lo)))
        out["header_bounds"] = {"min": self.header_lo.tolist(), "max": self.header_hi.tolist()} if headed else None
        out["header_bounds_differ"] = list(self.stale)
        out["scale"] = None if self.scale is None else self.scale.tolist()
        out["attributes"] = {name: {"min": lo, "max": hi, "mean": total / count} for name, (count, lo, hi, total) in self.attributes.items()}
        classified = self.classes.sum()
        if classified:
            out["classification"] = [
                {"class": c, "name": class_name(c), "count": int(self.classes[c]), "percent": 100 * float(self.classes[c]) / classified}
                for c in np.flatnonzero(self.classes).tolist()
            ]  # fmt: skip
        if self.returns.any():
            out["returns"] = self._returns()
        sources = np.flatnonzero(self.sources)
        if len(sources):
            listed = {str(s): int(self.sources[s]) for s in sources} if len(sources) <= SOURCES_LISTED else None
            out["point_source_ids"] = {"count": len(sources), "points": listed}
        if "gps_time" in self.attributes:
            out["gps_time"] = self._gps_time()
        out["color"] = None  # (files without colours: every point the default one)
        if self.colored:
            bits = next(iter(self.color_bits)) if len(self.color_bits) == 1 else None  # (files of both: not one)
            out["color"] = {"bits": bits, "min": self.color_lo.tolist(), "max": self.color_hi.tolist()}
        return out

    def _returns(self) -> dict:
        """Points by return: single (1 of 1), first (1 of any), last (n of n), intermediate, and
        those whose numbers cannot be (return 0, a return number above the number of returns)."""
        m = self.returns
        r, n = np.indices(m.shape)
        by = [{"return_number": int(i), "number_of_returns": int(j), "count": int(m[i, j])} for i, j in zip(*np.nonzero(m))]
        return {
            "single": int(m[1, 1]),
            "first": int(m[1, 1:].sum()),
            "last": int(m[(r == n) & (n > 0)].sum()),
            "intermediate": int(m[(r > 1) & (r < n)].sum()),
            "invalid": int(m[(r == 0) | (n == 0) | (r > n)].sum()),
            "by_number": by,
        }

    def _gps_time(self) -> dict:
        lo, hi = self.attributes["gps_time"][1:3]
        kind = next(iter(self.time_kinds)) if len(self.time_kinds) == 1 else "mixed" if self.time_kinds else UNKNOWN
        out = {"min": lo, "max": hi, "kind": kind}
        if kind == ADJUSTED:
            out.update(first=gps_date(lo), last=gps_date(hi))
        return out


def stream_stats(chunks: Iterable[PointChunk], path, point_filter: PointFilter | None = None, on_chunk: Callable[[int], None] | None = None) -> PointStats:
    """The ``PointStats`` of one dataset's ``chunks`` (read from ``path``: a file, an octree's
    nodes), a chunk at a time: every point read counted (``on_chunk(points)`` after each chunk:
    a progress bar), those ``point_filter`` keeps added (it counts them too: one filter an
    operation). gps_time is of an ``UNKNOWN`` kind here (a LAS file's header says which)."""
    stats = PointStats()
    stats.files = 1
    stats.filter = None if point_filter is None else point_filter.describe()

    def counted(chunks):  # every point read is counted, before the filter keeps some (the progress bar counts the header's)
        for chunk in chunks:
            stats.read += len(chunk)
            stats.scale = np.array(chunk.scale) if chunk.scale is not None else stats.scale
            if on_chunk is not None:
                on_chunk(len(chunk))
            yield chunk

    for chunk in filtered(counted(chunks), path, point_filter):
        stats.add(chunk)
    if "gps_time" in stats.attributes:
        stats.time_kinds = {UNKNOWN}
    return stats


@headers_once()  # (its header: read for its reader, its chunks, its bounds, its time encoding)
def file_stats(path, chunk_size: int = STREAM_CHUNK_SIZE, on_chunk: Callable[[int], None] | None = None, point_filter: PointFilter | None = None) -> PointStats:
    """One file's ``PointStats``, its points read once in chunks of at most ``chunk_size``
    (``on_chunk(points)`` after each: a progress bar); its header's bounds, where it has them,
    kept beside its points' and the file named in ``stale`` where they differ by more than half
    a step of its stored resolution. A damaged file raises its reader's one-line InputError.
    ``point_filter``: the statistics of the points it keeps (it counts them too, over all the
    files it is given for: one filter an operation); the header's bounds, of every point, are
    then neither kept nor compared. A file none of whose points it keeps is no error here: the
    caller checks the operation's (``PointFilter.check_passed``)."""
    path, chunk_size = Path(path), check_chunk_size(chunk_size)
    reader = reader_for(path)
    scaler = ColorScaler()
    # a LAS file's colour depth is the scaler's decision (8-bit values in its 16-bit fields, or 16-bit)
    chunks = reader.read_chunks(path, chunk_size, scaler=scaler) if isinstance(reader, LasReader) else reader.read_chunks(path, chunk_size)
    stats = stream_stats(chunks, path, point_filter, on_chunk)
    if isinstance(reader, LasReader):
        stats.color_bits = {{"8": 8, "16": 16}.get(scaler.mode or "")}
        if "gps_time" in stats.attributes:
            stats.time_kinds = {ADJUSTED if read_las_header(path).adjusted_gps_time else WEEK}
    bounds = reader.header(path).get("bounds") if point_filter is None else None
    if bounds is not None and None not in bounds[0] + bounds[1]:
        stats.header_lo, stats.header_hi = np.array(bounds[0], np.float64), np.array(bounds[1], np.float64)
        tolerance = (stats.scale if stats.scale is not None else np.zeros(3)) / 2 + 1e-9 * np.maximum(1, np.abs(stats.header_hi))
        if np.all(np.isfinite(stats.lo)) and (np.any(np.abs(stats.lo - stats.header_lo) > tolerance) or np.any(np.abs(stats.hi - stats.header_hi) > tolerance)):
            stats.stale.append(str(path))
    return stats
