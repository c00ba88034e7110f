"""Vector operations numba does not generate by itself, written as LLVM intrinsics.

A splat writes short runs of 2-16 pixels per row. Written as a loop, each pixel is a scalar
load, min and store: the frame's splat writes were bound by one store a cycle. numba leaves
LLVM's SLP vectorizer off and LLVM unrolls short fixed loops fully, so no loop form of a run
becomes vector code; ``min_run8`` is the vector form by hand: one masked load, an unsigned
min against the point's key, one masked store, for up to 8 pixels (one AVX-512 register;
LLVM splits or scalarises it on CPUs with narrower vectors, with the same result). Masked-off
lanes are neither read nor written, so a run next to another thread's pixels is safe.
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.extending import intrinsic

_I32 = ir.IntType(32)
_LANES = 8
_VEC = ir.VectorType(ir.IntType(64), _LANES)
_MASK = ir.VectorType(ir.IntType(1), _LANES)


def _splat(builder, value, vec=_VEC):
    """A vector (of type ``vec``) of _LANES copies of a scalar."""
    one = builder.insert_element(ir.Constant(vec, None), value, ir.Constant(_I32, 0))
    return builder.shuffle_vector(one, ir.Constant(vec, None), ir.Constant(ir.VectorType(_I32, _LANES), [0] * _LANES))


def _declare(module, name, fnty):
    return module.globals.get(name) or ir.Function(module, fnty, name)


def _lanes_below(builder, count):
    """<8 x i1>: lane i < count."""
    return builder.icmp_signed("<", ir.Constant(_VEC, list(range(_LANES))), _splat(builder, count))


def _data(context, builder, ty, array):
    return context.make_array(ty)(context, builder, array).data


def _vec_name(vec):
    """LLVM's name of a vector type in intrinsic names: "v8i64"."""
    return f"v{vec.count}i{vec.element.width}"


def _masked_load(builder, ptr, vec, mask, passthru):
    """LLVM's masked load of ``vec`` at ``ptr``. The intrinsics' names carry the pointer type: "p0"
    where LLVM's pointers are opaque (llvmlite >= 0.45), "p0v8i64" (a pointer to the vector) where
    they are still typed."""
    ptr = builder.bitcast(ptr, vec.as_pointer())
    suffix = "p0" if str(ptr.type) == "ptr" else f"p0{_vec_name(vec)}"
    load = _declare(builder.module, f"llvm.masked.load.{_vec_name(vec)}.{suffix}", ir.FunctionType(vec, [ptr.type, _I32, _MASK, vec]))
    return builder.call(load, [ptr, ir.Constant(_I32, vec.element.width // 8), mask, passthru])


def _masked_store(builder, value, ptr, mask):
    ptr = builder.bitcast(ptr, value.type.as_pointer())
    suffix = "p0" if str(ptr.type) == "ptr" else f"p0{_vec_name(value.type)}"
    store = _declare(builder.module, f"llvm.masked.store.{_vec_name(value.type)}.{suffix}", ir.FunctionType(ir.VoidType(), [value.type, ptr.type, _I32, _MASK]))
    builder.call(store, [value, ptr, ir.Constant(_I32, value.type.element.width // 8), mask])


@intrinsic
def min_run8(typingctx, buf, start, n, key):
    """buf[start + i] = min(buf[start + i], key) for 0 <= i < n, n <= 8 (nothing for n <= 0; buf: 1-D C-contiguous uint64)."""
    if not (isinstance(buf, types.Array) and buf.ndim == 1 and buf.layout == "C" and buf.dtype == types.uint64):
        return None
    sig = types.void(buf, types.int64, types.int64, types.uint64)

    def codegen(context, builder, signature, args):
        array, first, count, value = args
        ptr = builder.gep(_data(context, builder, signature.args[0], array), [first])
        mask = _lanes_below(builder, count)
        old = _masked_load(builder, ptr, _VEC, mask, ir.Constant(_VEC, None))
        keys = _splat(builder, value)
        _masked_store(builder, builder.select(builder.icmp_unsigned("<", keys, old), keys, old), ptr, mask)
        return context.get_dummy_value()

    return sig, codegen


# --- the resolve pass, 8 pixels at a time -----------------------------------------------------
# A frame is mostly empty pixels (autzen_trim's overview covers 4 %). Written as a loop, the
# resolve vectorises into masked gathers, which cost as much with no lane set as with eight.
# A u32 colour is one gather a group and the loop is bound by memory anyway; a 16-bit or
# palette colour takes two dependent gathers, and that resolve was 1.3-1.6x the u32 one. Here a
# group of 8 pixels is tested first (one vector compare) and an empty group is one store of
# the background; only groups with a point gather their colours.
_W32 = ir.VectorType(_I32, _LANES)
_EMPTY = ir.Constant(_VEC, [(1 << 64) - 1] * _LANES)


def _gather32(builder, base, index, mask, passthru):
    """<8 x i32>: base[index[i]] where mask[i], else passthru[i] (index: <8 x i64>, elements)."""
    addr = builder.add(_splat(builder, builder.ptrtoint(base, ir.IntType(64))), builder.shl(index, _splat(builder, ir.Constant(ir.IntType(64), 2))))
    opaque = str(base.type) == "ptr"
    ptrs = builder.inttoptr(addr, ir.VectorType(base.type if opaque else _I32.as_pointer(), _LANES))
    name = "llvm.masked.gather.v8i32." + ("v8p0" if opaque else "v8p0i32")
    gather = _declare(builder.module, name, ir.FunctionType(_W32, [ptrs.type, _I32, _MASK, _W32]))
    return builder.call(gather, [ptrs, ir.Constant(_I32, 4), mask, passthru])


def _check_resolve_args(frame, out):
    return (
        isinstance(frame, types.Array) and frame.ndim == 1 and frame.layout == "C" and frame.dtype == types.uint64
        and isinstance(out, types.Array) and out.ndim == 1 and out.layout == "C" and out.dtype == types.uint32
    )  # fmt: skip


def _resolve8(decode):
    """An intrinsic (frame, start, count, out, background, colors, table, shift) writing out[start + i]
    for i < min(count, 8): the colour ``decode`` gathers for the points of frame[start + i], or the
    background; a group with no point is one store. Returns how many of the pixels hold a point. ``decode(builder, index, mask, colors, table,
    shift, background)`` gives the <8 x i32> colours of the point indices (<8 x i64>) where mask."""

    @intrinsic
    def resolve8(typingctx, frame, start, count, out, background, colors, table, shift):
        if not _check_resolve_args(frame, out):
            return None
        sig = types.int64(frame, types.int64, types.int64, out, types.uint32, colors, table, types.int64)

        def codegen(context, builder, signature, args):
            frame_a, first, n, out_a, bg, colors_a, table_a, shift_v = args
            lanes = _lanes_below(builder, n)
            keys = _masked_load(builder, builder.gep(_data(context, builder, signature.args[0], frame_a), [first]), _VEC, lanes, _EMPTY)
            hit = builder.icmp_unsigned("!=", keys, _EMPTY)
            bg_vec = _splat(builder, bg, _W32)
            dst = builder.gep(_data(context, builder, signature.args[3], out_a), [first])
            bits = builder.bitcast(hit, ir.IntType(_LANES))
            any_hit = builder.icmp_unsigned("!=", bits, ir.Constant(ir.IntType(_LANES), 0))
            with builder.if_else(any_hit) as (points, empty):
                with points:
                    index = builder.and_(keys, _splat(builder, ir.Constant(ir.IntType(64), 0xFFFFFFFF)))
                    colors_p = _data(context, builder, signature.args[5], colors_a)
                    table_p = _data(context, builder, signature.args[6], table_a)
                    _masked_store(builder, decode(builder, index, hit, colors_p, table_p, shift_v, bg_vec), dst, lanes)
                with empty:
                    _masked_store(builder, bg_vec, dst, lanes)
            ctpop = _declare(builder.module, "llvm.ctpop.i8", ir.FunctionType(ir.IntType(_LANES), [ir.IntType(_LANES)]))
            return builder.zext(builder.call(ctpop, [bits]), ir.IntType(64))

        return sig, codegen

    return resolve8


def _u64(builder, value):
    return _splat(builder, ir.Constant(ir.IntType(64), value))


def _decode_rgb565(builder, index, mask, words, table, shift, background):
    """16-bit colours two a u32 word, decoded through table (65 536 RGBA8): core/compact.py."""
    word = _gather32(builder, words, builder.lshr(index, _u64(builder, 1)), mask, ir.Constant(_W32, None))
    half = builder.trunc(builder.shl(builder.and_(index, _u64(builder, 1)), _u64(builder, 4)), _W32)
    value = builder.and_(builder.lshr(word, half), ir.Constant(_W32, [0xFFFF] * _LANES))
    return _gather32(builder, table, builder.zext(value, _VEC), mask, background)


def _decode_palette(builder, index, mask, words, palette, shift, background):
    """Per-block palettes (core/palette.py ``palette_rgba``): a u8 index four a word, 256 entries a block of 2^shift points."""
    word = _gather32(builder, words, builder.lshr(index, _u64(builder, 2)), mask, ir.Constant(_W32, None))
    byte = builder.trunc(builder.shl(builder.and_(index, _u64(builder, 3)), _u64(builder, 3)), _W32)
    entry = builder.zext(builder.and_(builder.lshr(word, byte), ir.Constant(_W32, [0xFF] * _LANES)), _VEC)
    block = builder.shl(builder.lshr(index, _splat(builder, shift)), _u64(builder, 8))
    return _gather32(builder, palette, builder.add(block, entry), mask, background)


resolve8_rgb565 = _resolve8(_decode_rgb565)
resolve8_palette = _resolve8(_decode_palette)
