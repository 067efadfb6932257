"""A software prefetch for numba kernels: ``prefetch(rows, i, j)`` asks the CPU to bring the cache line
holding ``rows[i, j]`` towards L1 (LLVM's ``llvm.prefetch``, read, high locality). A hint only: it never
faults (the address must still lie in the array: it is computed without bounds checks) and changes no result.

Why: a kernel that gathers from the next profile's row, at bins only it knows, waits on memory for every
cache line it first touches; the hardware prefetcher does not foresee a jump to another row. Asking for those
lines a few profiles ahead overlaps the wait with the work on the current profile.
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic


@intrinsic
def prefetch(typingctx, rows, i, j):
    """Prefetch the cache line of ``rows[i, j]`` (a 2-D array, integer indices) for reading."""
    if not (isinstance(rows, types.Array) and rows.ndim == 2 and isinstance(i, types.Integer) and isinstance(j, types.Integer)):
        return None
    sig = types.void(rows, i, j)

    def codegen(context, builder, signature, args):
        array_type = signature.args[0]
        array = context.make_array(array_type)(context, builder, args[0])
        index = [context.cast(builder, v, t, types.intp) for v, t in zip(args[1:], signature.args[1:])]
        pointer = cgutils.get_item_pointer(context, builder, array_type, array, index, wraparound=False)
        i8_pointer = builder.bitcast(pointer, ir.IntType(8).as_pointer())
        i32 = ir.IntType(32)
        function = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [i8_pointer.type, i32, i32, i32]),
                                                  "llvm.prefetch.p0")
        # (address, 0 = read, 3 = keep in all cache levels, 1 = data cache)
        builder.call(function, [i8_pointer, ir.Constant(i32, 0), ir.Constant(i32, 3), ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return sig, codegen
