"""The LAS 1.4 point record as gigapoint writes it (point formats 6, 7 and 8): which attribute
goes to which field, in which range, which go to extra bytes and as what type, and the integer
grid positions are stored on. Shared by every LAS-style writer: a cloud's save (io/write.py), a
live cloud's, and COPC (lod/copc_write.py), whose reader (lod/copc.py) decodes the same fields."""

from __future__ import annotations

import math

import numpy as np

from ..errors import GigapointWarning, counted, warn
from ._base import LAS_FIELD_ATTRIBUTES
from .las import scan_angle_units

#: ASPRS LAS 1.4 classes (R15, table 17; 8 and 12 as LAS 1.2 named them before 1.4 reserved them):
#: one table for ``info --stats`` and the viewer's Classes panel
CLASS_NAMES = {
    0: "created, never classified",
    1: "unclassified",
    2: "ground",
    3: "low vegetation",
    4: "medium vegetation",
    5: "high vegetation",
    6: "building",
    7: "low point (noise)",
    8: "model key-point",  # reserved in LAS 1.4; LAS 1.2's name
    9: "water",
    10: "rail",
    11: "road surface",
    12: "overlap",  # reserved in LAS 1.4; LAS 1.2's name
    13: "wire guard (shield)",
    14: "wire conductor (phase)",
    15: "transmission tower",
    16: "wire-structure connector",
    17: "bridge deck",
    18: "high noise",
    19: "overhead structure",
    20: "ignored ground",
    21: "snow",
    22: "temporal exclusion",
}
STANDARD_CLASSES = tuple(range(19))  # the classes a viewer offers where a cloud's are unknown (Potree's list)


def class_name(code: int) -> str:
    """The ASPRS name of LAS class ``code``: 23..63 'reserved', 64..255 'user defined' (said beside
    their code: ``info --stats``' histogram, the viewer's Classes panel)."""
    return CLASS_NAMES.get(code) or ("reserved" if code < 64 else "user defined")


#: The bits of the ``flags`` byte (of formats 6-10) each flag is stored at (scanner_channel: 2 bits).
FLAG_BITS = {"synthetic": 0, "key_point": 1, "withheld": 2, "overlap": 3, "scanner_channel": 4, "scan_direction_flag": 6, "edge_of_flight_line": 7}


def field_attributes(point_format: int) -> frozenset:
    """The attributes point format 6/7/8 has a field for: nir in 8 only (in 6 and 7 it is
    extra bytes, read and written under its name)."""
    return LAS_FIELD_ATTRIBUTES if point_format == 8 else LAS_FIELD_ATTRIBUTES - {"nir"}


#: The scalar types of extra bytes by their data_type code (LAS 1.4 R15, section 2.5.4).
EXTRA_BYTES_TYPES = {
    1: np.dtype("u1"), 2: np.dtype("i1"), 3: np.dtype("<u2"), 4: np.dtype("<i2"), 5: np.dtype("<u4"),
    6: np.dtype("<i4"), 7: np.dtype("<u8"), 8: np.dtype("<i8"), 9: np.dtype("<f4"), 10: np.dtype("<f8"),
}  # fmt: skip


#: the range of each integer LAS field (the return counts: 4 bits in point formats 6-8; scan_angle:
#: ±180 degrees in 0.006 degree steps, as LAS 1.4 says)
LAS_FIELD_RANGE = {
    "intensity": (0, 65535), "classification": (0, 255), "return_number": (0, 15), "number_of_returns": (0, 15),
    "point_source_id": (0, 65535), "nir": (0, 65535), "user_data": (0, 255), "scan_angle": (-30000, 30000), "scanner_channel": (0, 3),
    **{flag: (0, 1) for flag in FLAG_BITS if flag != "scanner_channel"},
}  # fmt: skip
#: Attributes written to a field of another name: formats 0-5's scan angle, in degrees
LAS_FIELD_OF = {"scan_angle_rank": "scan_angle"}


def las_field_values(name: str, values, clipped: dict | None = None) -> np.ndarray:
    """An attribute's ``values`` in the range of its LAS field (clipped; gps_time as float64;
    scan_angle_rank, degrees, in scan_angle's 0.006 degree units): what the COPC writer and a
    live cloud's LAS save store (in field ``LAS_FIELD_OF.get(name, name)``). ``clipped``:
    {name: how many values were clipped}, added to (``warn_clipped`` says them)."""
    if name == "gps_time":
        return np.asarray(values, np.float64)
    if name == "scan_angle_rank":
        return scan_angle_units(values)
    values, (lo, hi) = np.asarray(values), LAS_FIELD_RANGE[name]
    if clipped is not None:
        clipped[name] = clipped.get(name, 0) + int(np.count_nonzero((values < lo) | (values > hi)))
    return np.clip(values, lo, hi)


def warn_clipped(where, clipped: dict) -> None:
    """One line a field of ``clipped`` ({name: count}, ``las_field_values``') whose values were
    beyond its LAS field: -5 or 70 000 became 0 or 65 535 without a word."""
    for name, n in clipped.items():
        if n:
            lo, hi = LAS_FIELD_RANGE[name]
            warn(f"{where}: {counted(n, f'{name} value')} beyond {lo}..{hi}, what its LAS field holds: written as {lo} or {hi}", GigapointWarning)


def record_names(point_format: int) -> frozenset:
    """The names point format ``point_format``'s record already uses (its fields, the bytes its
    flags are packed in, laspy's scaled x, y, z): an extra bytes field of one of them made
    laspy's "field 'red' occurs more than once" or an IndexError, not a file."""
    import laspy

    fmt = laspy.PointFormat(point_format)
    return frozenset({*fmt.dtype().names, *fmt.dimension_names, "x", "y", "z"})


def extra_attributes(attributes: dict, where: str = "COPC", point_format: int = 8) -> dict[str, np.dtype]:
    """The attributes ({name: dtype}) that ``point_format`` (6/7/8) has no field for, as they will be
    stored in extra bytes (LAS 1.4 types: booleans as u8, half floats as f4). An attribute that
    cannot be stored (a name that is not ASCII or longer than 32 bytes, or that the record's own
    fields use: ``x``, ``X``, ``red`` in format 7; a non-scalar dtype) is left out with a warning."""
    out = {}
    taken = record_names(point_format)
    for name, dt in attributes.items():
        if name in field_attributes(point_format):
            continue
        dt = np.dtype(dt)
        stored = np.dtype(np.uint8) if dt == np.bool_ else np.dtype(np.float32) if dt == np.float16 else dt.newbyteorder("<")
        problem = None
        if not name.isascii() or not 0 < len(name) <= 32:
            problem = "its name is not 1-32 ASCII characters"
        elif name in taken:
            problem = f"LAS point format {point_format} has a field of that name"
        elif stored not in EXTRA_BYTES_TYPES.values():
            problem = f"its dtype {dt} is not a LAS extra bytes type (8-64-bit integers and floats)"
        if problem:
            warn(f"{where}: attribute {name!r} is not written: {problem}", GigapointWarning)
            continue
        out[name] = stored
    return out


def choose_point_format(attributes, has_color: bool = True) -> int:
    """6 (no color), 7 (RGB) or 8 (RGB + NIR), as the points' attributes need: NIR without
    colors is format 6 with NIR in extra bytes (format 8 gave every point a grey color)."""
    if not has_color:
        return 6
    return 8 if "nir" in attributes else 7


_INT32 = (-(2**31), 2**31 - 1)


def power_of_ten_below(value: float) -> float:
    """The power of ten at or below ``value`` (0.003048 -> 0.001; 0.01 -> 0.01)."""
    # (log10(0.001) is -2.9999999999999996; a step measured as a difference of coordinates near 5e6 is
    # 0.00099999998929: within float rounding of a power of ten, it is that power)
    exponent = math.floor(math.log10(value) + 1e-6)
    return 10.0**exponent if exponent >= 0 else 1 / 10.0**-exponent


def default_step(lo, hi) -> float:
    """The grid step for points that came without one (float positions): a power of ten (decimal
    values of as many decimals lie on the grid: 3/65 536 stored a text file's 1.0 as 0.99998), the one at or below a millimetre, finer for a cloud under 65.5 m across (at least
    65 536 steps across it: a 10 cm object kept its shape, not 100 mm-steps); never below what float64
    tells apart at its coordinates (2e-15 of them: ~8 of its steps; no power of ten where it binds) or 1 nm. Points that floor does
    not tell apart (one point, equal points) get the millimetre (or that floor, where coarser):
    their zero extent gave the floor itself, 8.6e-9 at UTM coordinates, a scale other tools show
    as absurd."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    extent = float(np.max(hi - lo))
    floor = max(2e-15 * max(1.0, float(np.abs(lo).max()), float(np.abs(hi).max())), 1e-9)
    step = power_of_ten_below(min(0.001, extent / 2**16) if extent > floor else 0.001)
    return max(step, floor)  # (the floor where it binds, 0.002 at 1e12 m: rounded down to 0.001 it was ~1.6 of float64's steps at 4e11)


def las_grid(lo, hi, scale=None, offset=None, out=None) -> tuple[np.ndarray, np.ndarray]:
    """(scale, offset) per axis of 32-bit integers for points within [lo, hi]: the input's when
    both are given and the points fit on them; else ``scale`` (a grid the points lie on: from
    ``offset``, else from 0) or ``default_step``, with, per axis, the given offset where it holds
    the points, else the grid line at or below ``lo`` (a whole number for a decimal step without
    an offset), else one centred on them (the whole int32 range). Coarser only where that range is too short; said, for output ``out``, where it
    coarsens a given ``scale`` (the points then move by up to half the new step)."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    base = np.zeros(3) if offset is None else np.asarray(offset, np.float64)
    if scale is not None and offset is not None:
        s = np.asarray(scale, np.float64)
        if np.all(s > 0) and _fits_int32(lo, hi, s, base).all():
            return s, base
    s = np.broadcast_to(np.asarray(scale, np.float64), (3,)) if scale is not None else np.full(3, default_step(lo, hi))
    wide = np.maximum(s, (hi - lo) / (2**32 - 2**9))  # centred: half the span and half a step of rounding within 2**31 - 2 steps
    if out is not None and scale is not None:
        warn_coarsened(out, s, wide)
    s = wide
    if offset is None and all(v == power_of_ten_below(v) for v in s):  # a decimal step: from a whole number, exact in float64
        unit = np.maximum(s, 1.0)  # (a multiple of the step: 1.0 at scale 1e-5 read back 1.0, not 0.99999 + 1e-5)
        from_lo = np.floor(lo / unit) * unit
    else:
        from_lo = base + np.floor((lo - base) / s) * s
    centred = base + np.round(((lo + hi) / 2 - base) / s) * s
    o = np.where(_fits_int32(lo, hi, s, from_lo), from_lo, centred)
    return s, o if offset is None else np.where(_fits_int32(lo, hi, s, base), base, o)  # (the axes the given offset holds keep it)


def warn_coarsened(out, given, used) -> None:
    """One line, naming output ``out``, where the scale ``used`` (per axis) is coarser than the
    ``given`` one the inputs' points lie on: they then move by up to half its step."""
    given, used = np.broadcast_to(np.asarray(given, np.float64), (3,)), np.asarray(used, np.float64)
    if np.any(used > given):
        old, new = (", ".join(f"{v:.6g}" for v in scales) for scales in (given, used))
        warn(f"{out}: the points span more than 32-bit integers hold at scale {old}: written at scale {new}, "
             f"positions moved by up to {float(np.max(used)) / 2:.3g}", GigapointWarning)  # fmt: skip


def _fits_int32(lo, hi, s, o) -> np.ndarray:
    """Per axis: whether [lo, hi] lies within 32-bit integers on the grid (``s``, ``o``), a step inside their ends."""
    return ((lo - o) / s > _INT32[0] + 1) & ((hi - o) / s < _INT32[1] - 1)
