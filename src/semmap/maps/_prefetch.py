"""A software prefetch for numba kernels (LLVM's ``llvm.prefetch``), so hash-table passes keep several cache
misses in flight instead of waiting for each in turn."""

from __future__ import annotations

from llvmlite import ir
from numba.core import cgutils, types
from numba.extending import intrinsic

_READ_WRITE = 1  # prefetch for a write (the line is about to be updated)
_LOCALITY = 3  # keep in all cache levels
_DATA = 1  # data cache, not instructions


@intrinsic
def prefetch(typingctx, array, index):
    """Ask the CPU to fetch the cache line of element ``index`` of a C-contiguous array, counted in elements
    from its start whatever its shape (row r of an (n, k) array: ``r * k``); unchecked, a hint, never a fault."""
    if not isinstance(array, types.Array) or array.layout != "C" or not isinstance(index, types.Integer):
        return None
    sig = types.void(array, index)

    def codegen(context, builder, signature, args):
        array_type = signature.args[0]
        ary = context.make_array(array_type)(context, builder, args[0])
        offset = context.cast(builder, args[1], signature.args[1], types.intp)
        ptr = builder.gep(ary.data, [offset])
        i8p = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]),
                                            "llvm.prefetch.p0")
        builder.call(fn, [builder.bitcast(ptr, i8p), ir.Constant(i32, _READ_WRITE), ir.Constant(i32, _LOCALITY),
                          ir.Constant(i32, _DATA)])
        return context.get_dummy_value()

    return sig, codegen
