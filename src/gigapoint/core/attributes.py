"""Per-point attributes held in their real range, lossless (issue #22: "attributes packed to their
real range").

A LAS file's intensity is a u16 that often spans a few hundred values, its return numbers fit in
three bits, its point source id is one value for a whole flight line: 15 bytes a point of
autzen_trim's attributes carry ~5 of information. ``Attributes`` holds each integer attribute as
its offset (the minimum) and ``value - minimum`` in the narrowest unsigned dtype that holds
``maximum - minimum`` (u8/u16/u32), a constant one as its value alone (no array; float64 too,
bit for bit, but NaN), and float64 values that float32 represents bit for bit as float32; everything else as given. Reading gives
the original dtype and values exactly: ``attributes[name]`` the whole array (decoded into a new
one; unpacked attributes are the array itself), ``attributes.at(name, indices)`` a few points'
without decoding the rest (picking).

It is a mapping, so ``cloud.attributes`` reads as the dict it was: names, ``in``, items, and
``update`` / item assignment (normals estimated later) store new attributes, packed too.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, MutableMapping
from dataclasses import dataclass

import numpy as np

#: unsigned dtypes tried for ``maximum - minimum``, narrowest first
_NARROW = (np.uint8, np.uint16, np.uint32)
#: float64 values checked for float32 this many at a time
_FLOAT_BLOCK = 1 << 16


@dataclass(frozen=True)
class Packed:
    """One attribute held narrow: the original ``value = stored + offset`` (``stored`` None:
    every point holds ``offset``), of ``dtype`` and ``n`` points."""

    stored: np.ndarray | None
    offset: int | float
    dtype: np.dtype
    n: int

    @property
    def nbytes(self) -> int:
        return 0 if self.stored is None else int(self.stored.nbytes)

    def encode(self, values) -> np.ndarray:
        """``values`` (within ``offset``.. the stored dtype's range) as stored: ``value - offset``."""
        wide = np.uint64 if self.dtype == np.uint64 else np.int64
        return (np.asarray(values).astype(wide) - wide(self.offset)).astype(self.stored.dtype)

    def decode(self, indices=None) -> np.ndarray:
        """The original values of every point, or of ``indices``."""
        if self.stored is None:
            count = self.n if indices is None else len(np.atleast_1d(indices))
            return np.full(count, self.offset, self.dtype)
        stored = self.stored if indices is None else self.stored[np.atleast_1d(np.asarray(indices, np.int64))]
        if self.dtype.kind == "f":  # float64 exactly representable as float32
            return stored.astype(self.dtype)
        # in int64 (or u64 for u64 attributes): offset + stored never overflows the original range
        wide = np.uint64 if self.dtype == np.uint64 else np.int64
        return (stored.astype(wide) + wide(self.offset)).astype(self.dtype)


def narrow_dtype(lo: int, hi: int, dtype) -> type | None:
    """The narrowest unsigned dtype that holds ``hi - lo`` where it is narrower than integer
    ``dtype`` (None: no narrower one)."""
    narrow = next((d for d in _NARROW if hi - lo <= np.iinfo(d).max), np.uint64)
    return narrow if np.dtype(narrow).itemsize < np.dtype(dtype).itemsize else None


def packed_range(lo: int, hi: int, dtype, n: int) -> Packed | None:
    """An empty (zeroed) Packed of ``n`` points for values known to lie in ``lo..hi``: buffers
    filled later through ``Packed.encode`` (an LOD arena); None where packing saves nothing."""
    if lo == hi:
        return Packed(None, lo, np.dtype(dtype), n)
    narrow = narrow_dtype(lo, hi, dtype)
    return None if narrow is None else Packed(np.zeros(n, narrow), lo, np.dtype(dtype), n)


def pack(values: np.ndarray) -> np.ndarray | Packed:
    """``values`` held in their real range (module doc), or ``values`` itself where packing saves
    nothing (multi-component, bool, already narrowest, float not exactly float32)."""
    v = np.asarray(values)
    if v.ndim != 1 or len(v) == 0:
        return values
    if v.dtype.kind in "iu":
        held = packed_range(int(v.min()), int(v.max()), v.dtype, len(v))
        if held is None:
            return values
        if held.stored is not None:
            # one pass, in the values' own dtype: the difference wraps there (signed) but fits the
            # narrow dtype, so the cast's truncation gives it exactly (encode's int64 detour costs
            # a pass and 8 bytes a point more)
            np.subtract(v, v.dtype.type(held.offset), out=held.stored, casting="unsafe")
        return held
    if v.dtype == np.float64:
        bits, first = v.view(np.uint64), v.view(np.uint64)[:_FLOAT_BLOCK]
        if first.min() == first.max() == bits.min() == bits.max() and not np.isnan(v[0]):  # one value, bit for bit
            return Packed(None, float(v[0]), v.dtype, len(v))
        # block by block: a real GPS time stops at the first block, and no temporary the size of
        # the values is made (new memory costs more than the work on these machines)
        narrow = np.empty(len(v), np.float32)
        for start in range(0, len(v), _FLOAT_BLOCK):
            block, into = v[start : start + _FLOAT_BLOCK], narrow[start : start + _FLOAT_BLOCK]
            into[:] = block
            if not np.array_equal(into.astype(np.float64).view(np.uint64), block.view(np.uint64)):  # bit for bit: NaN, -0.0 too
                return values
        return Packed(narrow, 0, v.dtype, len(v))
    return values


class Attributes(MutableMapping):
    """A cloud's attributes by name (module doc); ``Attributes(arrays, packed=True)`` packs them."""

    def __init__(self, arrays: Mapping | None = None, packed: bool = False) -> None:
        self._held: dict[str, np.ndarray | Packed] = {}
        self._pack = packed
        for name, values in (arrays or {}).items():
            self[name] = values
        self._pack = True  # attributes stored later (normals) are packed

    def __getitem__(self, name: str) -> np.ndarray:
        held = self._held[name]
        return held.decode() if isinstance(held, Packed) else held

    def __setitem__(self, name: str, values) -> None:
        self._held[name] = pack(values) if self._pack else values

    def __delitem__(self, name: str) -> None:
        del self._held[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._held)

    def __len__(self) -> int:
        return len(self._held)

    def __repr__(self) -> str:
        return f"Attributes({', '.join(f'{k}: {self.held_dtype(k)}' for k in self._held)})"

    def held(self, name: str) -> np.ndarray | Packed:
        """What holds attribute ``name``: its array, or its Packed (written in place by an arena)."""
        return self._held[name]

    def hold(self, name: str, holder: np.ndarray | Packed) -> None:
        """Hold ``name`` as given (an array or a Packed), without packing."""
        self._held[name] = holder

    def at(self, name: str, indices) -> np.ndarray:
        """The original values of points ``indices`` only (no decoding of the rest)."""
        held = self._held[name]
        if isinstance(held, Packed):
            return held.decode(indices)
        return held[np.atleast_1d(np.asarray(indices, np.int64))]

    def held_dtype(self, name: str) -> str:
        """How one attribute is held: its dtype, or e.g. 'uint16 in uint8 + 1200', 'uint16
        constant 7326', 'int32 in uint16 - 70000', 'float64 in float32' where packed."""
        held = self._held[name]
        if not isinstance(held, Packed):
            return str(held.dtype)
        if held.stored is None:
            return f"{held.dtype} constant {held.offset}"
        offset = f" + {held.offset}" if held.offset > 0 else f" - {-held.offset}" if held.offset < 0 else ""
        return f"{held.dtype} in {held.stored.dtype}{offset}"

    def nbytes_of(self, name: str) -> int:
        held = self._held[name]
        return held.nbytes if isinstance(held, Packed) else int(held.nbytes)

    @property
    def nbytes(self) -> int:
        """Bytes held (the packed sizes)."""
        return sum(self.nbytes_of(k) for k in self._held)

    def copy(self) -> Attributes:
        """Another mapping over the same held arrays (no decoding)."""
        out = Attributes()
        out._held = dict(self._held)
        return out


__all__ = ["Attributes", "Packed", "narrow_dtype", "pack", "packed_range"]
