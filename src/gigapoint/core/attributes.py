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

from ..errors import InputError
from .chunk import attribute_problem
from .pages import zeros

#: unsigned dtypes tried for ``maximum - minimum``, narrowest first
_NARROW = (np.uint8, np.uint16, np.uint32)
#: float64 values checked for float32 this many at a time
_FLOAT_BLOCK = 1 << 16
#: entries a widened holder copies at a time (its temporaries stay small)
_COPY_BLOCK = 1 << 20


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

    def encode(self, values, out: np.ndarray | None = None) -> np.ndarray:
        """``values`` (within ``offset``.. the stored dtype's range) as stored, into ``out`` (of the
        stored dtype) where given: ``value - offset``, or the float32 of a float64."""
        v = np.asarray(values)
        v = v if v.dtype == self.dtype else v.astype(self.dtype)
        out = np.empty(len(v), self.stored.dtype) if out is None else out
        if self.dtype.kind == "f":
            out[:] = v
        else:
            # one pass, in the values' own dtype: the difference wraps there (signed) but fits the
            # narrow dtype, so the cast's truncation gives it exactly (an int64 detour costs a pass
            # and 8 bytes a point more)
            np.subtract(v, v.dtype.type(self.offset), out=out, casting="unsafe")
        return out

    def decode(self, indices=None) -> np.ndarray:
        """The original values of every point, or of ``indices`` (an array, or a slice)."""
        if self.stored is None:
            count = self.n if indices is None else len(range(self.n)[indices] if isinstance(indices, slice) else np.atleast_1d(indices))
            return np.full(count, self.offset, self.dtype)
        stored = self.stored if indices is None else self.stored[_index(indices)]
        if self.dtype.kind == "f":  # float64 exactly representable as float32
            return stored.astype(self.dtype)
        # in int64 (or u64 for u64 attributes): offset + stored never overflows the original range
        wide = np.uint64 if self.dtype == np.uint64 else np.int64
        return (stored.astype(wide) + wide(self.offset)).astype(self.dtype)


def _index(indices):
    return indices if isinstance(indices, slice) else np.atleast_1d(np.asarray(indices, np.int64))


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
            held.encode(v, out=held.stored)
        return held
    if v.dtype == np.float64:
        if _one_float(v[:_FLOAT_BLOCK]) and _one_float(v):  # one value, bit for bit (the first block decides most)
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
        self._owner: tuple[str, int] | None = None  # (cloud name, points): what ``belong_to`` checks against
        for name, values in (arrays or {}).items():
            self[name] = values
        self._pack = True  # attributes stored later (normals) are packed

    def __getitem__(self, name: str) -> np.ndarray:
        held = self._held[name]
        return held.decode() if isinstance(held, Packed) else held

    def __setitem__(self, name: str, values) -> None:
        if self._owner is not None:  # a program's own: 5 values for 20 000 points read past them in a render
            values = np.asarray(values)
            problem = attribute_problem(name, values, self._owner[1])
            if problem:
                raise InputError(f"{self._owner[0]}: {problem}")
        self._held[name] = pack(values) if self._pack else values

    def belong_to(self, cloud_name: str, n_points: int) -> None:
        """Check attributes stored from now on as a chunk's are (one number a point, ``n_points``):
        a cloud's, to which the program may add its own."""
        self._owner = (cloud_name, n_points)

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
        """The original values of points ``indices`` (an array, or a slice) only (no decoding of the rest)."""
        held = self._held[name]
        if isinstance(held, Packed):
            return held.decode(indices)
        return held[_index(indices)]

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
        out._held, out._owner = dict(self._held), self._owner
        return out


# ---------------------------------------------------------------- holders filled batch by batch
# An arena that fills as points come (the progressive octree's pool) holds each attribute in a
# form chosen from the values seen so far: one value (no array), an integer range in a narrow
# dtype with room either side, else the values' dtype. A batch that does not fit widens it once
# (``widened``), and kernels move the stored arrays as bytes. A 20 M-point LAS file's attributes
# while it loads: 16 bytes an entry as read, 3 held (docs/lod.md, "Memory").


def stored(held) -> np.ndarray | None:
    """The array an attribute's entries are stored in: an array itself, a Packed's ``stored``
    (None: a constant, nothing stored)."""
    return held.stored if isinstance(held, Packed) else held


def length(held) -> int:
    return held.n if isinstance(held, Packed) else len(held)


def _one_float(v: np.ndarray) -> bool:
    """Whether float64 ``v`` is one value, bit for bit (-0.0 is not 0.0), and not NaN."""
    bits = v.view(np.uint64)
    return bits.min() == bits.max() and not np.isnan(v[0])


def _int_range(lo: int, hi: int, dtype, n: int) -> np.ndarray | Packed:
    """A zeroed holder of ``n`` entries for integers ``lo..hi`` of ``dtype``: the narrowest
    unsigned dtype with the range in its middle (values a little beyond fit too), else ``dtype``."""
    narrow = narrow_dtype(lo, hi, dtype)
    if narrow is None:
        return zeros(n, dtype)
    top, info = int(np.iinfo(narrow).max), np.iinfo(dtype)
    offset = min(max(lo - (top - (hi - lo)) // 2, int(info.min)), int(info.max) - top)
    return Packed(zeros(n, narrow), offset, np.dtype(dtype), n)


def holder_for(values: np.ndarray, n: int) -> np.ndarray | Packed:
    """A zeroed holder of ``n`` entries in the form ``values`` suggest (a 1-D batch of them):
    their one value (integers, float64), their integer range with room, else their dtype."""
    v = np.asarray(values)
    if v.ndim == 1 and len(v) and v.dtype.kind in "iu":
        lo, hi = int(v.min()), int(v.max())
        return Packed(None, lo, v.dtype, n) if lo == hi else _int_range(lo, hi, v.dtype, n)
    if v.ndim == 1 and len(v) and v.dtype == np.float64 and _one_float(v):
        return Packed(None, float(v[0]), v.dtype, n)
    return zeros((n, *v.shape[1:]), v.dtype)


def fits(held, values: np.ndarray) -> bool:
    """Whether ``held`` stores ``values`` (of its dtype) exactly."""
    if not isinstance(held, Packed) or not len(values):
        return True
    if held.stored is None:
        if held.dtype.kind == "f":
            return _one_float(values) and values[0].view(np.uint64) == np.float64(held.offset).view(np.uint64)
        return values.min() == values.max() == held.offset
    if held.dtype.kind == "f":  # float64 held as float32 (pack's): exact, bit for bit
        return np.array_equal(values.astype(np.float32).astype(np.float64).view(np.uint64), values.view(np.uint64))
    return int(values.min()) >= held.offset and int(values.max()) - held.offset <= np.iinfo(held.stored.dtype).max


def encode(held, values: np.ndarray, out: np.ndarray | None = None) -> np.ndarray | None:
    """``values`` (that ``fits``) as ``held`` stores them (``Packed.encode``), into ``out`` (of the
    stored dtype) where given; the values themselves where held as they are; None for a
    constant (nothing to store)."""
    if not isinstance(held, Packed):
        return values
    return None if held.stored is None else held.encode(values, out)


def widened(held, values: np.ndarray, used: int) -> np.ndarray | Packed:
    """A holder as long as ``held`` that stores its first ``used`` entries (copied in, block by
    block: no temporary of their size) and ``values`` (which ``held`` does not fit, or of another
    dtype), in the dtype of both (numpy's ``result_type``: uint16 and float32 give float32, as
    merging files does): the integer range of both with room, else that dtype."""
    n = length(held)
    dtype = np.result_type(held.dtype, values.dtype)
    if dtype.kind in "iu":
        lo, hi = int(values.min()), int(values.max())
        if isinstance(held, Packed) and used:
            lo, hi = min(lo, held.offset), max(hi, held.offset)
            if held.stored is not None:
                lo, hi = min(lo, held.offset + int(held.stored[:used].min())), max(hi, held.offset + int(held.stored[:used].max()))
        elif used:  # held as its dtype (an integer or bool one narrower than dtype)
            lo, hi = min(lo, int(held[:used].min())), max(hi, int(held[:used].max()))
        new = _int_range(lo, hi, dtype, n)
    else:
        new = zeros(n, dtype)
    for start in range(0, used, _COPY_BLOCK):
        block = slice(start, min(start + _COPY_BLOCK, used))
        old = (held.decode(block) if isinstance(held, Packed) else held[block]).astype(dtype, copy=False)
        target = stored(new)[block]
        encoded = encode(new, old, target)
        if encoded is not target:
            target[:] = encoded
    return new


def resized(held, n: int) -> np.ndarray | Packed:
    """``held`` for ``n`` entries: a view of its first ``n`` where it has as many, else a zeroed
    one (new memory) with its entries in front."""
    have = stored(held)
    if have is not None and n <= len(have):
        part = have[:n]
    elif have is not None:
        part = zeros((n, *have.shape[1:]), have.dtype)
        part[: len(have)] = have
    else:
        part = None
    return Packed(part, held.offset, held.dtype, n) if isinstance(held, Packed) else part


def zeroed_like(held, n: int) -> np.ndarray | Packed:
    """A holder of ``n`` zeroed entries in ``held``'s form (dtype, packing), none of its entries."""
    return resized(resized(held, 0), n)


def repacked(held) -> np.ndarray | Packed:
    """``held`` in the real range of what it stores (``pack``: a filled holder, every entry a
    value; an integer range's offset and the narrower one's add up)."""
    if not isinstance(held, Packed):
        return pack(held)
    if held.stored is None or held.dtype.kind == "f":
        return held
    tighter = pack(held.stored)
    if not isinstance(tighter, Packed):
        return held
    return Packed(tighter.stored, held.offset + int(tighter.offset), held.dtype, held.n)


__all__ = ["Attributes", "Packed", "encode", "fits", "holder_for", "narrow_dtype", "pack", "packed_range", "repacked", "resized", "stored",
           "widened", "zeroed_like"]
