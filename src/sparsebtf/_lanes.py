"""Sixteen lanes of a float array as one value in numba-compiled code: the lookup's group sums.

The grouped lookup (:mod:`sparsebtf.runtime.wavefront`) sums, per data point, a coefficient
into an accumulator for every query of a group at once: ``s[j] += v · T12[e, j]`` over the
group's lanes j. Written as a loop over j, LLVM vectorises it but keeps ``s`` in memory
(the group's width is a run-time value, and with a compile-time width it unrolls the loop
into scalar code instead), so every coefficient costs a load and a store of the
accumulators besides its term: measured 3× the time of the same sums held in vector
registers (``benchmarks/bench_lookup.py``). numba has no vector type to hold them; this
module adds one — :data:`Lanes` values are LLVM vectors of 16 elements (float32 or float64,
the array's dtype), which LLVM keeps in registers across loops — and the handful of
operations the sums need. Loads and stores are unchecked: the caller keeps ``i + 16`` within
the array. Beside them, :func:`pow2` (2^k from exponent bits) for the runtime's exp.

Only imported where numba is (``sparsebtf._numba.HAVE_NUMBA``).
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic, models, register_model

__all__ = ["WIDTH", "Lanes", "lanes_fma", "lanes_load", "lanes_mul", "lanes_store",
           "lanes_zeros", "pow2"]  # fmt: skip

#: Elements per :data:`Lanes` value (one AVX-512 register of float32).
WIDTH = 16


class Lanes(types.Type):
    """WIDTH consecutive elements of a float array of ``dtype``, held as one value."""

    def __init__(self, dtype: types.Float) -> None:
        self.dtype = dtype
        super().__init__(name=f"Lanes{WIDTH}({dtype})")


def _vector(dtype: types.Float) -> ir.VectorType:
    return ir.VectorType(ir.FloatType() if dtype == types.float32 else ir.DoubleType(), WIDTH)


@register_model(Lanes)
class _LanesModel(models.PrimitiveModel):
    def __init__(self, dmm, fe_type: Lanes) -> None:
        super().__init__(dmm, fe_type, _vector(fe_type.dtype))


def _float_array(arr) -> bool:
    return isinstance(arr, types.Array) and arr.dtype in (types.float32, types.float64)


def _pointer(context, builder, aryty, ary, idx):
    data = context.make_array(aryty)(context, builder, ary).data
    return builder.bitcast(builder.gep(data, [idx]), _vector(aryty.dtype).as_pointer())


@intrinsic
def lanes_zeros(typingctx, like):
    """Zero lanes of the dtype of array ``like``."""
    if not _float_array(like):
        return None

    def codegen(context, builder, sig, args):
        return ir.Constant(_vector(like.dtype), [0.0] * WIDTH)

    return Lanes(like.dtype)(like), codegen


@intrinsic
def lanes_load(typingctx, arr, idx):
    """``arr[idx:idx + WIDTH]`` (unchecked)."""
    if not _float_array(arr) or not isinstance(idx, types.Integer):
        return None

    def codegen(context, builder, sig, args):
        load = builder.load(_pointer(context, builder, sig.args[0], args[0], args[1]))
        load.align = arr.dtype.bitwidth // 8  # element alignment: any idx
        return load

    return Lanes(arr.dtype)(arr, idx), codegen


@intrinsic
def lanes_store(typingctx, arr, idx, value):
    """``arr[idx:idx + WIDTH] = value`` (unchecked)."""
    if not _float_array(arr) or value != Lanes(arr.dtype):
        return None

    def codegen(context, builder, sig, args):
        store = builder.store(args[2], _pointer(context, builder, sig.args[0], args[0], args[1]))
        store.align = arr.dtype.bitwidth // 8
        return context.get_dummy_value()

    return types.void(arr, idx, value), codegen


def _fma(builder, vt, a, b, c):
    fn = cgutils.get_or_insert_function(
        builder.module, ir.FunctionType(vt, [vt, vt, vt]),
        f"llvm.fma.v{WIDTH}f{32 if vt.element == ir.FloatType() else 64}")  # fmt: skip
    return builder.call(fn, [a, b, c])


@intrinsic
def lanes_fma(typingctx, acc, a, b):
    """``acc + a·b`` fused, lane by lane; ``a`` lanes or a scalar (every lane)."""
    if not isinstance(acc, Lanes) or b != acc:
        return None
    if a != acc and not isinstance(a, (types.Float, types.Integer)):
        return None

    def codegen(context, builder, sig, args):
        vt = _vector(acc.dtype)
        x = args[1]
        if a != acc:  # broadcast the scalar
            x = context.cast(builder, x, a, acc.dtype)
            x = builder.insert_element(ir.Constant(vt, ir.Undefined), x, ir.IntType(32)(0))
            x = builder.shuffle_vector(x, ir.Constant(vt, ir.Undefined),
                                       ir.Constant(ir.VectorType(ir.IntType(32), WIDTH),
                                                   [0] * WIDTH))  # fmt: skip
        return _fma(builder, vt, x, args[2], args[0])

    return acc(acc, a, b), codegen


@intrinsic
def lanes_mul(typingctx, a, b):
    """``a·b`` lane by lane."""
    if not isinstance(a, Lanes) or b != a:
        return None

    def codegen(context, builder, sig, args):
        return builder.fmul(args[0], args[1])

    return a(a, b), codegen


@intrinsic
def pow2(typingctx, k):
    """2.0**k as float64 for an integer k in [-1022, 1023], from its exponent bits (plain
    integer and bit operations, so a loop around it vectorises; ``np.ldexp`` is a call)."""
    if not isinstance(k, types.Integer):
        return None

    def codegen(context, builder, sig, args):
        i64 = ir.IntType(64)
        e = builder.add(context.cast(builder, args[0], k, types.int64), i64(1023))
        return builder.bitcast(builder.shl(e, i64(52)), ir.DoubleType())

    return types.float64(k), codegen
