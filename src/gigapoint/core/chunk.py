"""PointChunk: what every reader yields, a bounded slice of a point cloud."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import GigapointWarning, InputError, warn

#: Color given to points of files that carry none (a light grey that reads on black and white).
DEFAULT_COLOR = (200, 200, 200, 255)


@dataclass
class PointChunk:
    """A bounded number of points: float64 xyz (N, 3), uint8 rgba (N, 4), named attributes.

    Attributes are 1-D (or (N, k)) numpy arrays of length N, e.g. ``intensity``,
    ``classification``, ``return_number``. ``scale``: the resolution the source stored the
    coordinates at, per axis (a LAS file's scale), where it has one. ``color_bits``: 8 or 16, how
    the source's integer colours were stored (a LAS file's: 8-bit values in its 16-bit fields, or
    16-bit ones, shifted to 8), where it says; a save writes them back so.
    """

    xyz: np.ndarray
    rgba: np.ndarray | None = None
    attributes: dict[str, np.ndarray] = field(default_factory=dict)
    scale: tuple[float, float, float] | None = None
    color_bits: int | None = None

    def __post_init__(self) -> None:
        self.xyz = np.ascontiguousarray(self.xyz, dtype=np.float64).reshape(-1, 3)
        n = len(self.xyz)
        if self.rgba is None:
            self.rgba = np.empty((n, 4), np.uint8)
            self.rgba[:] = DEFAULT_COLOR
        else:
            self.rgba = to_rgba8(self.rgba)
            if len(self.rgba) != n:
                raise ValueError(f"rgba has {len(self.rgba)} rows, xyz has {n}")
        for name, values in self.attributes.items():
            problem = attribute_problem(name, values, n)
            if problem:
                raise ValueError(problem)

    def __len__(self) -> int:
        return len(self.xyz)

    def subset(self, rows: np.ndarray) -> PointChunk:
        """The points ``rows`` (a mask or indices) selects, with every attribute, the scale and colour bits."""
        attributes = {a: v[rows] for a, v in self.attributes.items()}
        return PointChunk(self.xyz[rows], self.rgba[rows], attributes, scale=self.scale, color_bits=self.color_bits)


def join_chunks(chunks: list[PointChunk]) -> PointChunk:
    """One chunk of ``chunks``' points, in order, with the first's attributes (every chunk has them)."""
    if len(chunks) == 1:
        return chunks[0]
    attrs = {a: np.concatenate([c.attributes[a] for c in chunks]) for a in chunks[0].attributes}
    return PointChunk(np.concatenate([c.xyz for c in chunks]), np.concatenate([c.rgba for c in chunks]), attrs)


def attribute_problem(name, values, n: int) -> str | None:
    """Why ``values`` cannot be attribute ``name`` of ``n`` points (a chunk's, or a cloud's stored
    later by the program), or None."""
    if np.ndim(values) == 0:  # intensity=5: len() of a 0-d array was a TypeError
        value = " ".join(repr(np.asarray(values).item()).split())  # one line, however long the object
        return f"attribute {name!r} is one value ({value[:60]}{'...' if len(value) > 60 else ''}), not one per point"
    if len(values) != n:
        return f"attribute {name!r} has {len(values):,} rows for {n:,} points"
    return attribute_name_problem(name) or attribute_dtype_problem(name, values)


def attribute_name_problem(name) -> str | None:
    """Why ``name`` cannot name an attribute, or None: octrees store each attribute in a file
    named after it (``attr.<name>.npy``), so no path separator or NUL, not empty, '.' or '..'."""
    if not isinstance(name, str) or name in ("", ".", "..") or any(c in name for c in "/\\\0"):
        return f"attribute name {name!r} cannot be stored (a file name part: not empty, '.' or '..', no /, \\ or NUL)"
    return None


def safe_attribute_name(name: str) -> str | None:
    """``name`` with path separators and NUL as '_' (a file's own field names, kept rather than
    refused: an extra bytes field 'a/b' is read as 'a_b'); None for one that stays unusable."""
    name = "".join("_" if c in "/\\\0" else c for c in name)
    return None if attribute_name_problem(name) else name


def attribute_dtype_problem(name: str, values: np.ndarray) -> str | None:
    """Why ``values`` cannot be an attribute, or None: attributes are numbers of at most 8 bytes
    (the kernels move them as 1, 2, 4 or 8 byte words; strings, objects and complex numbers
    broke renders and conversions, or were cut to 8 bytes)."""
    dt = np.asarray(values).dtype
    if dt.kind in "biuf" and dt.itemsize <= 8:
        return None
    return f"attribute {name!r} has dtype {dt}: attributes are numbers (bool, integers, floats of at most 64 bits)"


def attributes_in_common(kept: list[str] | None, chunk_attributes, dropped: set[str]) -> list[str]:
    """The attributes every chunk so far has, with ``chunk_attributes`` (``kept``: None before
    the first chunk); those one chunk lacks or brings alone are added to ``dropped``."""
    names = sorted(chunk_attributes)
    if kept is None:
        return names
    dropped.update(set(kept) ^ set(names))
    return [a for a in kept if a in names]


def warn_dropped_attributes(name: str, dropped, parts: str = "files") -> None:
    """Say which attributes files of one scene (``parts``: the scans of one E57 file) did not all
    have (they were left out without a word)."""
    if dropped:
        warn(
            f"{name}: attribute(s) {', '.join(sorted(dropped))} not in every {parts[:-1]}: left out (only those all the {parts} have are kept)",
            GigapointWarning,
        )


def to_rgba8(colors: np.ndarray) -> np.ndarray:
    """(N, 3|4) colors of any integer or float type to uint8 RGBA.

    uint16 colors (LAS) are scaled down by 256 when any value exceeds 255, as Potree does;
    floats are taken as 0..1.
    """
    c = np.asarray(colors)
    if c.ndim != 2 or c.shape[1] not in (3, 4):
        raise ValueError(f"colors must have shape (N, 3) or (N, 4), got {c.shape}")
    if c.dtype.kind == "f":
        c8 = np.clip(np.nan_to_num(c) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    elif c.dtype == np.uint8:
        c8 = c
    else:
        c = c.astype(np.int64, copy=False)
        if c.size and c.max() > 255:
            c = c >> 8
        c8 = np.clip(c, 0, 255).astype(np.uint8)
    if c8.shape[1] == 3:
        out = np.empty((len(c8), 4), np.uint8)
        out[:, :3] = c8
        out[:, 3] = 255
        return out
    return np.ascontiguousarray(c8)


class ColorScaler:
    """Turns a file's color columns into uint8, deciding the file's color range once.

    uint8 colors pass through. Other colors are judged on the first chunk that holds a
    non-zero color: floats all within 0..1 are unit colors (x 255); integer-valued colors
    above 255 are 16-bit (>> 8); otherwise 8-bit. An 8-bit decision is revised to 16-bit
    when a later chunk holds values above 255, and a 0..1 one to 8- or 16-bit when a later
    chunk holds values above ``UNIT_OVERSHOOT`` (never back), so a dark first chunk of a
    16-bit LAS file or of a 0..255 float file does not make the rest of it white. Chunks
    already converted keep their colours.
    """

    UNIT_OVERSHOOT = 1.5  # 0..1 colours that stray a little above 1 (1.025) stay 0..1, clipped

    def __init__(self) -> None:
        self.mode: str | None = None  # "unit", "8", "16"

    def int_shift(self, hi: int) -> int:
        """Right shift (0 or 8) to 8 bits for unsigned integer colors whose maximum is ``hi``:
        the decision ``__call__`` makes, for readers that convert their columns themselves."""
        if self.mode is None and hi > 0:
            self.mode = "16" if hi > 255 else "8"
        if self.mode == "8" and hi > 255:
            self.mode = "16"
        return 8 if self.mode == "16" else 0

    def __call__(self, colors: np.ndarray) -> np.ndarray:
        c = np.asarray(colors)
        if c.dtype == np.uint8:
            return to_rgba8(c)
        if c.dtype.kind == "b":
            c = c.astype(np.uint8) * 255
            return to_rgba8(c)
        if c.dtype.kind == "f":
            c = np.nan_to_num(c, nan=0.0, posinf=0.0, neginf=0.0)
        if self.mode == "unit" and c.size and c.max() > self.UNIT_OVERSHOOT:
            self.mode = None  # decided again on this chunk: 0..255 or 16-bit colours whose first were all <= 1
        if self.mode is None and c.size and np.any(c):
            hi = float(c.max())
            if c.dtype.kind == "f" and hi <= 1.0:
                self.mode = "unit"
            else:
                self.mode = "16" if hi > 255 else "8"
        if self.mode == "unit":
            return to_rgba8(c.astype(np.float64, copy=False))
        if c.dtype in (np.uint16, np.uint32, np.uint64) and c.size:  # the PLY fast path (LAS: io/las.py)
            hi = int(c.max())
            shift = self.int_shift(hi)
            c, hi = c >> shift, hi >> shift
            return to_rgba8(c.astype(np.uint8) if hi <= 255 else np.minimum(c, 255).astype(np.uint8))
        ci = np.clip(np.rint(c) if c.dtype.kind == "f" else c, 0, 65535).astype(np.int64)
        if self.mode == "8" and ci.size and ci.max() > 255:
            self.mode = "16"
        if self.mode == "16":
            ci >>= 8
        return to_rgba8(np.clip(ci, 0, 255).astype(np.uint8))


def points_for(xyz, where: str) -> np.ndarray:
    """Positions given as an array (from_arrays, a frame pushed, points added) as an (N, 3)
    array of integers or floats, in their own dtype; a one-line InputError starting with
    ``where`` otherwise: a ragged list was numpy's ValueError, complex positions lost their
    imaginary part (a ComplexWarning), bools became 0 and 1, an object array's None a NaN point
    dropped without a word and strings were parsed as numbers."""
    try:
        a = np.asarray(xyz)
    except (TypeError, ValueError):  # a ragged list: numpy's "setting an array element with a sequence. The requested array ..."
        raise InputError(f"{where}: xyz must be an (N, 3) array of numbers, got a ragged {type(xyz).__name__}") from None
    if a.ndim != 2 or a.shape[1] != 3:
        raise InputError(f"{where}: xyz must have shape (N, 3), got {a.shape}")
    if a.dtype.kind not in "uif":
        raise InputError(f"{where}: xyz must hold numbers (integers or floats), got dtype {a.dtype}")
    return a


def colors_for(rgb, n: int, where: str, scalers: dict | None = None) -> np.ndarray:
    """Colors given with ``n`` points (from_arrays, a frame pushed, points added) as uint8 RGBA
    (n, 4), their range judged as a file's (``ColorScaler``: floats of 0..255 were all white);
    a one-line InputError starting with ``where`` when they are not (N, 3|4) colors of 0..65535
    or not ``n`` rows.

    ``scalers``: a stream's ColorScalers (a dict kept from one frame to the next, filled here;
    one for float colours, one for integer ones), so its range is decided on its first frame as
    a file's is: judged frame by frame, a 0..1 frame that overshot to 1.025 was read as 0..255,
    all but black beside its neighbours. None: these colours are judged alone."""
    try:
        try:
            rgb = np.asarray(rgb)
        except ValueError:  # a ragged list: numpy's "setting an array element with a sequence. The requested array ..."
            raise ValueError(f"colors must have shape (N, 3) or (N, 4), got a ragged {type(rgb).__name__}") from None
        if rgb.ndim != 2 or rgb.shape[1] not in (3, 4):
            raise ValueError(f"colors must have shape (N, 3) or (N, 4), got {rgb.shape}")
        if rgb.dtype.kind not in "biuf":  # strings were a UFuncTypeError traceback of the range check
            raise ValueError(f"colors must be numbers, got dtype {rgb.dtype}")
        if rgb.dtype.kind in "iuf" and rgb.dtype not in (np.uint8, np.uint16) and rgb.size:  # NaN, -5, 70000 were clipped: black or white points without a word
            lo, hi = rgb.min(), rgb.max()
            if not (0 <= lo and hi <= 65535):  # (NaN fails both)
                bad = rgb.reshape(-1)[np.flatnonzero(~((rgb >= 0) & (rgb <= 65535)))[0]].item()
                raise ValueError(f"colors must be 0..1, 0..255 or 0..65535 (16 bits), got {bad!r}")
        scaler = ColorScaler() if scalers is None else scalers.setdefault("float" if rgb.dtype.kind == "f" else "integer", ColorScaler())
        rgba = scaler(rgb)
    except ValueError as exc:
        raise InputError(f"{where}: {exc}") from None
    if len(rgba) != n:
        raise InputError(f"{where}: rgb has {len(rgba)} rows, xyz has {n}")
    return rgba
