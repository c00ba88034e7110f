"""E57 (ASTM E2807), the format terrestrial laser scanners export, read through pye57's libE57 bindings.

Every scan (a ``data3D`` entry) is read in bounded chunks (libE57's CompressedVectorReader
filling buffers of ``chunk_size`` points, never a whole scan) and moved by its pose (rotation
quaternion w x y z, then translation) into the file's common frame. A scan without cartesian
coordinates has its spherical ones (range, azimuth, elevation) converted. A point whose
``cartesianInvalidState`` (``sphericalInvalidState``) is not 0 gets NaN coordinates: the cloud
builders skip such points and say how many, as of any file's invalid points.

Colours are scaled from the scan's ``colorLimits`` to 8 bits, intensity from ``intensityLimits``
to 0..65535 (LAS's range, uint16); ``rowIndex``, ``columnIndex`` and ``timeStamp`` become the
attributes row_index, column_index and timestamp (float64; NaN where the point's
``isTimeStampInvalid`` is not 0: its time stamp means nothing; the point is kept). Scans that
differ in their fields keep the attributes all of them have (the others are said, once; a scan
without points has no say). The header (point count, bounds: each
scan's ``cartesianBounds``, local to the scan, its 8 corners moved by its pose) comes from the
file's XML section, without reading points. pye57 is an optional dependency
(``pip install 'gigapoint[e57]'``).
"""

from __future__ import annotations

import contextlib
import itertools
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.chunk import DEFAULT_COLOR, PointChunk, warn_dropped_attributes
from ..errors import EmptyCloudError, first_line
from ._base import DEFAULT_CHUNK_SIZE, Reader, check_chunk_size, check_file, fail, read_head, scan_bounds

E57_MAGIC = b"ASTM-E57"

CARTESIAN = ("cartesianX", "cartesianY", "cartesianZ")
SPHERICAL = ("sphericalRange", "sphericalAzimuth", "sphericalElevation")
COLORS = ("colorRed", "colorGreen", "colorBlue")

#: E57 point fields kept as attributes, by the name gigapoint gives them
ATTRIBUTES = {"intensity": "intensity", "rowIndex": "row_index", "columnIndex": "column_index", "timeStamp": "timestamp"}

#: LAS intensity's range, which E57 intensities are scaled to
INTENSITY_MAX = 65535


def _libe57(path: Path):
    try:
        from pye57 import libe57
    except ImportError:
        raise fail(path, "reading E57 needs pye57 (pip install 'gigapoint[e57]')") from None
    return libe57


@contextlib.contextmanager
def _opened(path: Path):
    """(libe57, the file's root node), the file closed after; libE57's errors (a file cut off,
    a bad page checksum, a node missing) as one line naming the file."""
    libe57 = _libe57(path)
    head = read_head(path, len(E57_MAGIC))
    if head != E57_MAGIC:
        raise fail(path, f"not an E57 file (starts with {head!r}, expected {E57_MAGIC!r})")
    try:
        image = libe57.ImageFile(str(path), "r")
    except libe57.E57Exception as exc:
        raise fail(path, f"corrupt or truncated E57 file: {first_line(exc)}") from None
    try:
        yield libe57, image
    except libe57.E57Exception as exc:
        raise fail(path, f"corrupt E57 file: {first_line(exc)}") from None
    finally:
        image.close()


def _value(libe57, node) -> float | int | str:
    """A leaf node's value (a scaled integer's as scaled)."""
    return node.scaledValue() if isinstance(node, libe57.ScaledIntegerNode) else node.value()


def _child(libe57, node, name: str, default=None):
    """The value of child ``name`` of a structure node, ``default`` where it has none."""
    return _value(libe57, node[name]) if node.isDefined(name) else default


def _limits(libe57, scan, group: str, key: str, proto) -> tuple[float, float]:
    """A field's (minimum, maximum): the scan's ``group`` (colorLimits, intensityLimits) says it;
    where it does not, the range the prototype's node declares (as the standard says)."""
    if scan.isDefined(group):
        lo, hi = _child(libe57, scan[group], key + "Minimum"), _child(libe57, scan[group], key + "Maximum")
        if lo is not None and hi is not None:
            return float(lo), float(hi)
    return _declared_range(libe57, proto[key])


def _declared_range(libe57, node) -> tuple[float, float]:
    """The (minimum, maximum) a prototype's node declares its values within."""
    if isinstance(node, libe57.ScaledIntegerNode):
        return float(node.scaledMinimum()), float(node.scaledMaximum())
    return float(node.minimum()), float(node.maximum())


def _in_scan_frame(libe57, proto, lo: list[float], hi: list[float]) -> bool:
    """Whether cartesianBounds ``lo``..``hi`` can be the scan's own (the standard's frame): within
    the range its coordinates' nodes declare. pye57 writes them moved by the pose already;
    moved again they missed the points."""
    for axis, name in enumerate(CARTESIAN):
        if name not in {proto.get(k).elementName() for k in range(proto.childCount())}:
            continue
        low, high = _declared_range(libe57, proto[name])
        slack = 1e-6 * max(1.0, abs(low), abs(high))  # (single precision limits of double bounds)
        if lo[axis] < low - slack or hi[axis] > high + slack:
            return False
    return True


def rotation_matrix(w: float, x: float, y: float, z: float) -> np.ndarray:
    """The 3x3 rotation of a quaternion (normalized here: files round it)."""
    q = np.array([w, x, y, z], np.float64)
    norm = np.linalg.norm(q)
    if not np.isfinite(norm) or norm == 0:
        return np.eye(3)
    w, x, y, z = q / norm
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])  # fmt: skip


def _scaled(values: np.ndarray, limits: tuple[float, float], top: int, dtype) -> np.ndarray:
    """``values`` from ``limits`` to 0..``top`` (0 where the limits span nothing)."""
    lo, hi = limits
    if not hi > lo:
        return np.zeros(len(values), dtype)
    return np.clip((values - lo) * (top / (hi - lo)) + 0.5, 0, top).astype(dtype)


@dataclass
class _Scan:
    """What one scan's header says."""

    node: object  # its data3D structure node
    count: int
    fields: set[str]
    name: str
    scanner: str
    rotation: np.ndarray
    translation: np.ndarray
    local_bounds: tuple[np.ndarray, np.ndarray] | None  # cartesianBounds, in the scan's own frame

    @property
    def spherical(self) -> bool:
        return not set(CARTESIAN) <= self.fields

    @property
    def has_color(self) -> bool:
        return set(COLORS) <= self.fields

    def bounds(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The bounds of its 8 corners moved by its pose (a rotated box's corners bound the points)."""
        if self.local_bounds is None:
            return None
        corners = np.array(list(itertools.product(*zip(*self.local_bounds))), np.float64)
        moved = corners @ self.rotation.T + self.translation
        return moved.min(axis=0), moved.max(axis=0)


def _scans(path: Path, libe57, image) -> list[_Scan]:
    root = image.root()
    if not root.isDefined("data3D"):
        return []
    data3d = root["data3D"]
    scans = []
    for i in range(data3d.childCount()):
        node = data3d[i]
        points = node["points"]
        proto = libe57.StructureNode(points.prototype())
        fields = {proto.get(k).elementName() for k in range(proto.childCount())}
        if not (set(CARTESIAN) <= fields or set(SPHERICAL) <= fields):
            raise fail(path, f"scan {i} has neither cartesian nor spherical coordinates (fields: {', '.join(sorted(fields))})")
        rotation, translation = np.eye(3), np.zeros(3)
        if node.isDefined("pose"):
            pose = node["pose"]
            if pose.isDefined("rotation"):
                rotation = rotation_matrix(*(_child(libe57, pose["rotation"], k, 0.0) for k in "wxyz"))
            if pose.isDefined("translation"):
                translation = np.array([_child(libe57, pose["translation"], k, 0.0) for k in "xyz"], np.float64)
        local_bounds = None
        if node.isDefined("cartesianBounds"):
            b = node["cartesianBounds"]
            lo = [_child(libe57, b, f"{a}Minimum") for a in "xyz"]
            hi = [_child(libe57, b, f"{a}Maximum") for a in "xyz"]
            ordered = None not in lo + hi and np.all(np.isfinite(lo + hi)) and np.all(np.array(lo) <= np.array(hi))
            if ordered and _in_scan_frame(libe57, proto, lo, hi):
                local_bounds = (np.array(lo, np.float64), np.array(hi, np.float64))
        scanner = " ".join(str(_child(libe57, node, k, "")) for k in ("sensorVendor", "sensorModel")).strip()
        scans.append(_Scan(node, int(points.childCount()), fields, str(_child(libe57, node, "name", f"scan {i}")), scanner,
                           rotation, translation, local_bounds))  # fmt: skip
    return scans


def _common(scans: list[_Scan]) -> tuple[list[str], set[str]]:
    """(the E57 fields kept as attributes: those every scan with points has; the attributes some
    of them lack). A scan without points (a station aborted) lacks nothing: it dropped the
    intensity of every other scan."""
    present = [{f for f in ATTRIBUTES if f in s.fields} for s in scans if s.count]
    common = set.intersection(*present) if present else set()
    return [f for f in ATTRIBUTES if f in common], {ATTRIBUTES[f] for f in set().union(*present) - common}


class E57Reader(Reader):
    name = "E57"
    suffixes = (".e57",)

    def sniff(self, head: bytes) -> bool:
        return head.startswith(E57_MAGIC)

    def reads_slowly(self, path: Path) -> bool:
        return True  # bit-packed, checksummed pages: decoded, not copied

    def point_count(self, path: Path) -> int | None:
        return self.header(path)["point_count"]

    def header(self, path: Path, salvage: bool = False) -> dict:
        """``bounds``: None where a scan has no cartesianBounds. A file cut off cannot be salvaged:
        its XML section, the scans' description, is at its end."""
        path = check_file(path)
        with _opened(path) as (libe57, image):
            scans = _scans(path, libe57, image)
        boxes = [s.bounds() for s in scans if s.count]
        bounds = None
        if boxes and None not in boxes:
            bounds = (np.min([b[0] for b in boxes], axis=0).tolist(), np.max([b[1] for b in boxes], axis=0).tolist())
        return {
            "point_count": sum(s.count for s in scans),
            "bounds": bounds,
            "has_color": any(s.has_color for s in scans if s.count),
            "attributes": [ATTRIBUTES[f] for f in _common(scans)[0]],
            "scans": [{"name": s.name, "points": s.count, "scanner": s.scanner} for s in scans],
        }

    def read_chunks(self, path: Path, chunk_size: int = DEFAULT_CHUNK_SIZE) -> Iterator[PointChunk]:
        chunk_size = check_chunk_size(chunk_size)
        path = check_file(path)
        with _opened(path) as (libe57, image):
            scans = _scans(path, libe57, image)
            if not any(s.count for s in scans):
                raise fail(path, f"E57 file holds no points ({len(scans)} scan{'s' * (len(scans) != 1)})", EmptyCloudError)
            kept, dropped = _common(scans)
            warn_dropped_attributes(str(path), dropped, parts="scans")
            for scan in scans:
                if scan.count:
                    yield from self._read_scan(libe57, image, scan, kept, min(chunk_size, scan.count))

    @staticmethod
    def _read_scan(libe57, image, scan: _Scan, kept: list[str], capacity: int) -> Iterator[PointChunk]:
        coords = SPHERICAL if scan.spherical else CARTESIAN
        invalid = "sphericalInvalidState" if scan.spherical else "cartesianInvalidState"
        colors = list(COLORS) if scan.has_color else []
        flags = [f for f in ("isColorInvalid", "isIntensityInvalid") if f in scan.fields]
        flags += ["isTimeStampInvalid"] if "timeStamp" in kept and "isTimeStampInvalid" in scan.fields else []
        fields = [*coords, *colors, *kept, *(f for f in (invalid, *flags) if f in scan.fields)]
        # every field read as float64 (whole up to 2^53): pye57 takes numpy's int64 ('l') as a narrower
        # type, and the reader left most of such a buffer unwritten (random invalid states)
        buffers = {f: np.empty(capacity, np.float64) for f in fields}
        dest = libe57.VectorSourceDestBuffer()
        for f, array in buffers.items():
            dest.append(libe57.SourceDestBuffer(image, f, array, capacity, True, True))
        proto = libe57.StructureNode(scan.node["points"].prototype())
        color_limits = [_limits(libe57, scan.node, "colorLimits", c, proto) for c in colors]
        intensity_limits = _limits(libe57, scan.node, "intensityLimits", "intensity", proto) if "intensity" in kept else None
        reader = scan.node["points"].reader(dest)
        try:
            while n := reader.read():
                b = {f: a[:n] for f, a in buffers.items()}
                if scan.spherical:
                    r, az, el = b[coords[0]], b[coords[1]], b[coords[2]]
                    local = np.column_stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)])
                else:
                    local = np.column_stack([b[c] for c in coords])
                xyz = local @ scan.rotation.T + scan.translation
                if invalid in b:
                    xyz[b[invalid] != 0] = np.nan  # skipped and counted by the cloud builders
                rgba = None
                if colors:
                    rgba = np.full((n, 4), 255, np.uint8)
                    for k, (c, limits) in enumerate(zip(colors, color_limits)):
                        rgba[:, k] = _scaled(b[c], limits, 255, np.uint8)
                    if "isColorInvalid" in b:
                        rgba[b["isColorInvalid"] != 0] = DEFAULT_COLOR
                attributes = {}
                for f in kept:
                    if f == "intensity":
                        values = _scaled(b[f], intensity_limits, INTENSITY_MAX, np.uint16)
                        if "isIntensityInvalid" in b:
                            values[b["isIntensityInvalid"] != 0] = 0
                    else:  # (a copy: the buffers are filled again)
                        values = b[f].astype(np.int32) if f in ("rowIndex", "columnIndex") else b[f].copy()
                        if f == "timeStamp" and "isTimeStampInvalid" in b:  # (it kept the meaningless value written)
                            values[b["isTimeStampInvalid"] != 0] = np.nan
                    attributes[ATTRIBUTES[f]] = values
                yield PointChunk(xyz, rgba, attributes)
        finally:
            reader.close()

    def info(self, path: Path) -> dict:
        path = check_file(path)
        head = self.header(path)
        bounds, source = head["bounds"], "header"
        if bounds is None and head["point_count"]:  # a scan without cartesianBounds: its points tell them
            _, lo, hi = scan_bounds(self.read_chunks(path))
            bounds, source = (lo, hi), "data"
        scans = head["scans"]
        scanners = sorted({s["scanner"] for s in scans if s["scanner"]})
        details = {"scans": f"{len(scans):,}" + (f" ({', '.join(s['name'] for s in scans[:5])}{', ...' * (len(scans) > 5)})" if scans else "")}
        if scanners:
            details["scanners"] = ", ".join(scanners)
        return {
            "path": str(path),
            "format": "E57",
            "point_count": head["point_count"],
            "bounds": {"min": bounds[0] if bounds else None, "max": bounds[1] if bounds else None},
            "bounds_source": source,
            "has_color": head["has_color"],
            "attributes": head["attributes"],
            "scans": scans,
            "details": details,
            "file_size": path.stat().st_size,
        }
