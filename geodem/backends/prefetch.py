"""``prefetch_line(arr, i, offset)``: a cache hint for the CPU kernels (LLVM's ``llvm.prefetch``).

Asks the processor to start loading the cache line that holds the byte ``offset`` of row ``i``
(index along the first axis) of a C-ordered array of any dimension, so that a later read there
does not wait on memory. It changes no value and cannot fault (a prefetch of any address is
allowed), so the kernels' results do not depend on it. Used by
``geodem.backends.step_bodies.prefetch_partners`` and ``prefetch_rows``; numba only (not CUDA).
"""
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic


@intrinsic
def prefetch_line(typingctx, arr, i, offset):
    if not (isinstance(arr, types.Array) and isinstance(i, types.Integer)
            and isinstance(offset, types.Integer)):
        return None
    sig = types.void(arr, i, offset)

    def codegen(context, builder, signature, args):
        aryty, ity, oty = signature.args
        ary = context.make_array(aryty)(context, builder, args[0])
        idx = context.cast(builder, args[1], ity, types.intp)
        off = context.cast(builder, args[2], oty, types.intp)
        stride0 = cgutils.unpack_tuple(builder, ary.strides)[0]  # bytes
        i8p = ir.IntType(8).as_pointer()
        base = builder.bitcast(ary.data, i8p)
        ptr = builder.gep(base, [builder.add(builder.mul(idx, stride0), off)])
        i32 = ir.IntType(32)
        # LLVM >= 15 with opaque pointers (numba >= 0.6x) names it .p0; typed pointers .p0i8
        name = "llvm.prefetch.p0" if getattr(ptr.type, "is_opaque", False) else "llvm.prefetch.p0i8"
        fnty = ir.FunctionType(ir.VoidType(), [ptr.type, i32, i32, i32])
        fn = cgutils.get_or_insert_function(builder.module, fnty, name)
        # read (0), keep in all cache levels (locality 3), data cache (1)
        builder.call(fn, [ptr, ir.Constant(i32, 0), ir.Constant(i32, 3), ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return sig, codegen
