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


def _splat(builder, value):
    """A vector of _LANES copies of a scalar."""
    one = builder.insert_element(ir.Constant(_VEC, None), value, ir.Constant(_I32, 0))
    return builder.shuffle_vector(one, ir.Constant(_VEC, None), ir.Constant(ir.VectorType(_I32, _LANES), [0] * _LANES))


def _declare(module, name, fnty):
    return module.globals.get(name) or ir.Function(module, fnty, name)


@intrinsic
def min_run8(typingctx, buf, start, n, key):
    """buf[start + i] = min(buf[start + i], key) for 0 <= i < n, n <= 8 (nothing for n <= 0; buf: 1-D C-contiguous uint64)."""
    if not (isinstance(buf, types.Array) and buf.ndim == 1 and buf.layout == "C" and buf.dtype == types.uint64):
        return None
    sig = types.void(buf, types.int64, types.int64, types.uint64)

    def codegen(context, builder, signature, args):
        array, first, count, value = args
        ptr = builder.gep(context.make_array(signature.args[0])(context, builder, array).data, [first])
        # the intrinsics' names carry the pointer type: "p0" where LLVM's pointers are opaque
        # (llvmlite >= 0.45), "p0v8i64" (a pointer to the vector) where they are still typed
        ptr = builder.bitcast(ptr, _VEC.as_pointer())
        suffix = "p0" if str(ptr.type) == "ptr" else "p0v8i64"
        module = builder.module
        load = _declare(module, f"llvm.masked.load.v8i64.{suffix}", ir.FunctionType(_VEC, [ptr.type, _I32, _MASK, _VEC]))
        store = _declare(module, f"llvm.masked.store.v8i64.{suffix}", ir.FunctionType(ir.VoidType(), [_VEC, ptr.type, _I32, _MASK]))
        mask = builder.icmp_signed("<", ir.Constant(_VEC, list(range(_LANES))), _splat(builder, count))
        align = ir.Constant(_I32, 8)
        old = builder.call(load, [ptr, align, mask, ir.Constant(_VEC, None)])
        keys = _splat(builder, value)
        builder.call(store, [builder.select(builder.icmp_unsigned("<", keys, old), keys, old), ptr, align, mask])
        return context.get_dummy_value()

    return sig, codegen
