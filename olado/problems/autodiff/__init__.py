"""Exact derivatives by automatic differentiation: a DOCP written once, symbolically
(docs/autodiff.md).

The user subclasses :class:`AutoDiffDOCP` and writes one function per stage and one for the
final stage, in terms of the DOCP of paper 001, eqs. (1)-(3)::

    stage(x, u, d) -> (f^k(x, u), f_0^k(x, u))  or  (f^k, f_0^k, g^k)
    final(x)       -> F^N(x)  or  (F^N(x), g^N(x))

``x`` (n,), ``u`` (m,) and ``d`` (q,) are symbolic vectors (index them: ``x[0]``, ``d[4]``);
``d`` is the stage's row of the per-stage numeric data :meth:`AutoDiffDOCP.stage_data` (N, q)
(inflows, time, reference values: whatever the stage index selected in a hand-written model).
The functions use + - * / ** and the elementary functions of this module (:func:`sin`,
:func:`exp`, ... which also accept numbers); they return sequences of scalar expressions.

From this one model the class supplies every DOCP function and derivative, vectorized over the
stages: the values, the first derivatives (f_x, f_u, l_x, l_u, g_x, g_u, F^N_x, g^N_x) and the
Lagrangian's stage and final Hessian blocks (the blocks of eq. (12)),

    d^2/dz^2 [sigma f_0^k + p.f^k + lam.g^k],  z = (x, u);      d^2/dx^2 [sigma F^N + lam.g^N].

Back-ends (measured in docs/autodiff.md and benchmarks/RESULTS.md):

* ``"casadi"`` (default): CasADi SX expressions differentiated by CasADi's algorithmic
  differentiation; each function's SX algorithm translated to LLVM IR (a loop over the stages)
  and compiled by llvmlite, numba's own dependency (``ad_options = {"mode": "llvm"}``, the
  default), or to Python compiled by numba (``"numba"``), or mapped over the stages and run by
  CasADi's virtual machine (``"vm"``) or by C code from the system's compiler (``"jit"``).
* ``"sympy"``: SymPy expressions differentiated symbolically, common subexpressions eliminated,
  printed as one loop over the stages per function and compiled by numba.

Both are optional extras (``pip install olado[ad]`` installs CasADi, ``olado[ad-sympy]`` SymPy);
without them the class raises :class:`~olado.errors.AutoDiffNotAvailableError` naming the
extra, and every other problem keeps its analytic or finite-difference derivatives.
"""

from __future__ import annotations

from .backends import BACKENDS, make_backend, require_backend
from .functions import acos, asin, atan, atan2, cos, cosh, exp, fabs, fmax, fmin, log, sin, sinh, sqrt, tan, tanh
from .model import AutoDiffDOCP, StageModel
from .ode import ADModel

__all__ = ["AutoDiffDOCP", "ADModel", "BACKENDS", "StageModel", "make_backend", "require_backend", "sin", "cos", "tan",
           "exp", "log", "sqrt", "tanh", "atan", "atan2", "asin", "acos", "sinh", "cosh", "fabs", "fmax", "fmin"]
