"""``prefetch_row(arr, i)``: a cache hint for the CPU kernels (LLVM's ``llvm.prefetch``).

Asks the processor to start loading the cache line that holds ``arr[i, 0]`` of a C-ordered
2-D array, so that a later read of that row does not wait on memory. It changes no value and
cannot fault (a prefetch of any address is allowed), so the kernels' results do not depend on
it. Used by ``geodem.backends.step_bodies.prefetch_partners``; numba only (not CUDA).
"""
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic


@intrinsic
def prefetch_row(typingctx, arr, i):
    if not (isinstance(arr, types.Array) and arr.ndim == 2 and isinstance(i, types.Integer)):
        return None
    sig = types.void(arr, i)

    def codegen(context, builder, signature, args):
        aryty, ity = signature.args
        ary = context.make_array(aryty)(context, builder, args[0])
        idx = context.cast(builder, args[1], ity, types.intp)
        zero = context.get_constant(types.intp, 0)
        ptr = cgutils.get_item_pointer2(context, builder, ary.data,
                                        cgutils.unpack_tuple(builder, ary.shape),
                                        cgutils.unpack_tuple(builder, ary.strides),
                                        aryty.layout, [idx, zero], wraparound=False)
        i32 = ir.IntType(32)
        if getattr(ptr.type, "is_opaque", False):
            name = "llvm.prefetch.p0"  # LLVM >= 15, opaque pointers (numba >= 0.6x)
        else:
            ptr = builder.bitcast(ptr, ir.IntType(8).as_pointer())  # typed pointers
            name = "llvm.prefetch.p0i8"
        fnty = ir.FunctionType(ir.VoidType(), [ptr.type, i32, i32, i32])
        fn = cgutils.get_or_insert_function(builder.module, fnty, name)
        # read (0), keep in all cache levels (locality 3), data cache (1)
        builder.call(fn, [ptr, ir.Constant(i32, 0), ir.Constant(i32, 3), ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return sig, codegen
