"""Compiled evaluations of a DOCP: its values and derivatives at a point as numba first-class
function pointers, for a solver loop compiled as a whole (:meth:`olado.problems.docp.DOCP.compiled_evaluations`).

A solver kernel ``@njit(cache=True)`` takes the four functions as arguments of type
``numba.types.FunctionType(SIG)``. Such a kernel is cached on disk like any other (the argument's
type is the signature, not the function), and it calls the problem's code through an address:
the problem's compiled functions can change without the kernel being compiled again.

The four signatures (arrays C-contiguous; ``data``, ``idata`` the problem's packed numbers, read
only; the arrays after them are the point, then the outputs, which the function fills)::

    VALUES(data F1, idata I1, X F2 (N+1,n), U F2 (N,m), f F2 (N,n), cost F1 (N,)) -> float64
        f^k(x^k, u^k) and the stage costs f_0^k; returns J as DOCP.eval_values gives it, or NaN
        when a value is not finite
    DERIVATIVES(data, idata, X, U, lx F2 (N,n), lu F2 (N,m), lN F1 (n,), A F3 (N,n,n),
                B F3 (N,n,m)) -> boolean
        DOCP.eval_first_derivatives' lx, lu, lN, A, B; True when every entry is finite
    HESSIANS(data, idata, X, U, sigma float64, P F2 (N,n), hxx F3 (N,n,n), hxu F3 (N,n,m),
             huu F3 (N,m,m)) -> boolean
        DOCP.eval_stage_hessians(X, U, sigma, P) (P the dynamics multipliers lam^1..lam^N)
    FINAL_HESSIAN(data, idata, xN F1 (n,), sigma float64, H F2 (n,n)) -> boolean
        DOCP.eval_final_hessian(xN, sigma)

with F1 = float64[::1], F2 = float64[:, ::1], F3 = float64[:, :, ::1], I1 = int64[::1]. Only
problems without stage and final constraint rows (r = rN = 0) have them for now.

The numbers are those of the Python entry points bit for bit; one call adds 1 to the
``problem.counters`` keys of :attr:`CompiledEvaluations.counters` when it succeeds (the caller
does the counting; a NaN or False result counts nothing: the caller evaluates again through the
Python entry point, which counts and names the function, stage and array).

This module imports numba; ``import olado`` does not import it (only a problem's
``compiled_evaluations`` does).
"""

from __future__ import annotations

from typing import Mapping, NamedTuple

import numpy as np
from numba.core import types
from numba.experimental.function_type import _get_wrapper_address

__all__ = ["F1", "F2", "F3", "I1", "VALUES", "DERIVATIVES", "HESSIANS", "FINAL_HESSIAN",
           "CompiledFunction", "CompiledEvaluations"]

F1 = types.float64[::1]
F2 = types.float64[:, ::1]
F3 = types.float64[:, :, ::1]
I1 = types.int64[::1]

VALUES = types.float64(F1, I1, F2, F2, F2, F1)
DERIVATIVES = types.boolean(F1, I1, F2, F2, F2, F2, F1, F3, F3)
HESSIANS = types.boolean(F1, I1, F2, F2, types.float64, F2, F3, F3, F3)
FINAL_HESSIAN = types.boolean(F1, I1, F1, types.float64, F2)

#: the names of CompiledEvaluations' functions
KINDS = ("values", "derivatives", "hessians", "final_hessian")


class CompiledFunction(types.WrapperAddressProtocol):
    """A compiled function as a numba first-class function value: the address of the
    dispatcher's compiled version for ``signature``, looked up once. numba types an instance
    through its ``_numba_type_`` (no look-up per call) and a compiled caller calls the address;
    the instance keeps the dispatcher, hence the code, alive."""

    def __init__(self, dispatcher, signature):
        self.dispatcher = dispatcher
        self._signature = signature
        self._address = _get_wrapper_address(dispatcher, signature)
        self._numba_type_ = types.FunctionType(signature)

    def __reduce__(self):
        """Pickled as its dispatcher and signature: the address is looked up again where it is
        loaded (an address is valid in its own process only)."""
        return CompiledFunction, (self.dispatcher, self._signature)

    def __wrapper_address__(self):
        return self._address

    def signature(self):
        return self._signature

    def __call__(self, *args):
        """A call from Python (through the dispatcher; tests and debugging)."""
        return self.dispatcher(*args)

    def __repr__(self):
        return f"CompiledFunction({getattr(self.dispatcher, '__name__', self.dispatcher)}, {self._signature})"


class CompiledEvaluations(NamedTuple):
    """A problem's compiled evaluations (the signatures of this module) and the numbers they read.

    ``counters`` maps each of ``KINDS`` to the ``problem.counters`` keys one successful call of
    that function adds 1 to (what the problem's Python entry point adds)."""

    values: CompiledFunction
    derivatives: CompiledFunction
    hessians: CompiledFunction
    final_hessian: CompiledFunction
    data: np.ndarray            # float64 (d,), C-contiguous
    idata: np.ndarray           # int64 (di,), C-contiguous
    counters: Mapping[str, tuple]
