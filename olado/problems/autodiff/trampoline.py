"""The numba side of the LLVM back-end of :mod:`olado.problems.autodiff`: one compiled
trampoline that calls a kernel by its address with the data pointers of C-contiguous float64
arrays (imported on first use, so that importing olado.problems does not load numba).

Calling a compiled kernel through ctypes costs about 2 µs per array argument just to read the
arrays' addresses (``ndarray.ctypes``); numba reads them in a few nanoseconds. The trampoline
is typed by the number of arrays only (the address is an argument), so numba compiles it once
per arity and keeps it in its disk cache."""

from __future__ import annotations

import numba as nb
from llvmlite import ir
from numba import types
from numba.extending import intrinsic


@intrinsic
def _call_address(typingctx, address, count, arrays):
    """kernel(count, data(arrays[0]), ..., data(arrays[-1])) with kernel at ``address``."""
    if not isinstance(arrays, types.BaseTuple) or not isinstance(address, types.Integer):
        return None
    sig = types.void(address, count, arrays)

    def codegen(context, builder, signature, args):
        address_v, count_v, tup = args
        double_ptr = ir.DoubleType().as_pointer()
        pointers = []
        for j, array_type in enumerate(arrays.types):
            array = context.make_array(array_type)(context, builder, builder.extract_value(tup, j))
            pointers.append(builder.bitcast(array.data, double_ptr))
        fnty = ir.FunctionType(ir.VoidType(), [ir.IntType(64)] + [double_ptr] * len(pointers))
        builder.call(builder.inttoptr(address_v, fnty.as_pointer()), [count_v] + pointers)
        return context.get_dummy_value()

    return sig, codegen


@nb.njit(cache=True)
def call_kernel(address, arrays):
    """Run the kernel at ``address`` on ``arrays`` (a tuple of C-contiguous float64 (K, size)
    matrices; K = the first one's rows)."""
    _call_address(address, arrays[0].shape[0], arrays)


@nb.njit(cache=True)
def simulate_stages(address, X, U, D):
    """X[k+1] = f(X[k], U[k], D[k]) for k = 0, ..., N-1 (eq. (2) of paper 001) by the dynamics
    kernel at ``address``, one stage per call: the state of a stage is the next call's input, so
    the stages run in sequence (X (N+1, n) with X[0] set; U (N, m), D (N, q) C-contiguous)."""
    for k in range(U.shape[0]):
        _call_address(address, 1, (X[k:k + 1], U[k:k + 1], D[k:k + 1], X[k + 1:k + 2]))
