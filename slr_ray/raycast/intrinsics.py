"""numba intrinsics of the cast loop (:mod:`slr_ray.raycast.cast`): an integer address as a
pointer, a cache-line prefetch, and calls of C functions (Embree's) through their addresses."""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

__all__ = ["as_pointer", "prefetch", "call3", "call4"]


@intrinsic
def as_pointer(typingctx, address):
    """An integer address as a ``void*`` (for numba.carray)."""
    sig = types.voidptr(address)

    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], cgutils.voidptr_t)

    return sig, codegen


@intrinsic
def prefetch(typingctx, address):
    """Start loading the cache line at an integer address (LLVM's prefetch; no fault)."""
    sig = types.void(address)

    def codegen(context, builder, signature, args):
        i32 = ir.IntType(32)
        fnty = ir.FunctionType(ir.VoidType(), [cgutils.voidptr_t, i32, i32, i32])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "llvm.prefetch.p0i8")
        builder.call(fn, [builder.inttoptr(args[0], cgutils.voidptr_t), ir.Constant(i32, 0), ir.Constant(i32, 3),
                          ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return sig, codegen


def _c_call(fptr, *args):
    """Signature and code of a call to the C function at address ``fptr`` with
    pointer-sized integer arguments (None: not integers, numba tries no other)."""
    if not all(isinstance(x, types.Integer) for x in (fptr, *args)):
        return None

    def codegen(context, builder, signature, values):
        i64 = ir.IntType(64)
        f = builder.inttoptr(values[0], ir.FunctionType(ir.VoidType(), [i64] * len(args)).as_pointer())
        builder.call(f, [builder.zext(x, i64) if x.type.width < 64 else x for x in values[1:]])
        return context.get_dummy_value()

    return types.void(fptr, *args), codegen


@intrinsic
def call3(typingctx, fptr, a, b, c):
    """Call the C function at address ``fptr`` with three pointer-sized arguments."""
    return _c_call(fptr, a, b, c)


@intrinsic
def call4(typingctx, fptr, a, b, c, d):
    """Call the C function at address ``fptr`` with four pointer-sized arguments."""
    return _c_call(fptr, a, b, c, d)
