"""The CasADi back-end: SX differentiation, evaluated by compiled LLVM or numba kernels, CasADi's
virtual machine or its C code generator."""

from __future__ import annotations

import numpy as np

from ...errors import ProblemDefinitionError
from .llvm_kernels import LLVMKernel
from .numba_kernels import NumbaEvaluator, sx_to_numba


class _CasadiMapped:
    """One CasADi function mapped over K stages and bound to the buffer interface: the inputs and
    outputs are the caller's C-contiguous (K, ...) arrays, which are CasADi's column-major
    (..., K) layout, so nothing is copied."""

    def __init__(self, fun, K, out_shapes):
        self.fun = fun.map(K) if K > 1 else fun
        self.buf, self.trigger = self.fun.buffer()
        self.K, self.out_shapes = K, out_shapes

    def __call__(self, *args):
        outs = tuple(np.empty((self.K,) + s) for s in self.out_shapes)
        for i, a in enumerate(args):
            self.buf.set_arg(i, memoryview(a))
        for i, o in enumerate(outs):
            self.buf.set_res(i, memoryview(o))
        self.trigger()
        return outs


class CasadiBackend:
    """CasADi SX: algorithmic differentiation of the traced model, then one of four evaluators
    for each function (``mode``):

    * ``"llvm"`` (default): the SX function's instruction list translated to LLVM IR, a loop over
      the stages, and compiled by llvmlite (:func:`sx_llvm_ir`; a fraction of a second);
    * ``"numba"``: the same instruction list as straight-line Python in a loop over the stages,
      compiled by numba (:func:`sx_to_numba`; seconds, then served from the disk cache);
    * ``"vm"``: ``Function.map`` over the stages, evaluated by CasADi's virtual machine;
    * ``"jit"``: ``Function.map`` of the function compiled by the system's C compiler
      (CasADi's ``jit`` option; needs gcc or cc).
    """

    name = "casadi"
    MODES = ("llvm", "numba", "vm", "jit")

    def __init__(self, mode="llvm", jit=None):
        import casadi   # noqa: PLC0415 - the optional extra
        self.ca = casadi
        if jit:                      # older spelling of mode="jit"
            mode = "jit"
        if mode not in self.MODES:
            raise ProblemDefinitionError(f"CasADi back-end mode must be one of {', '.join(self.MODES)}, got {mode!r}",
                                         function="autodiff", array="mode")
        self.mode = mode

    def vector(self, name, size):
        return self.ca.SX.sym(name, size)

    def build(self, model):
        """The stage and final functions of ``model`` (a :class:`StageModel`) with their
        derivatives: name -> (casadi.Function, output shapes per stage)."""
        ca = self.ca
        x, u, d, xN = model.x, model.u, model.d, model.xN
        n, m, r, rN = model.n, model.m, model.r, model.rN
        sx = lambda entries: ca.vertcat(*[ca.SX(e) for e in entries]) if entries else ca.SX(0, 1)  # noqa: E731
        f, l, g = sx(model.f), ca.SX(model.l), sx(model.g)
        sigma, p, lam = ca.SX.sym("sigma"), ca.SX.sym("p", n), ca.SX.sym("lam", r)
        z = ca.vertcat(x, u)
        opts = {"jit": True, "compiler": "shell", "jit_options": {"flags": ["-O2"]}} if self.mode == "jit" else {}

        def fn(name, ins, outs):
            # dense outputs (the buffer interface and the translation write structural nonzeros
            # only), common subexpressions shared (5-10 % fewer instructions)
            return ca.Function(name, ins, ca.cse([ca.densify(o) for o in outs]), opts)

        # C order of a per-stage (a, b) block == CasADi's column-major (b, a): transposes below
        fx, fu = ca.jacobian(f, x), ca.jacobian(f, u)
        funs = {
            "dynamics": (fn("f", [x, u, d], [f]), [(n,)]),
            "stage_cost": (fn("l", [x, u, d], [l]), [()]),
            "dynamics_jacobian": (fn("fj", [x, u, d], [fx.T, fu.T]), [(n, n), (n, m)]),
            "stage_cost_gradient": (fn("lj", [x, u, d], [ca.gradient(l, x), ca.gradient(l, u)]), [(n,), (m,)]),
        }
        lag = sigma * l + ca.dot(p, f) + (ca.dot(lam, g) if r else 0)
        H = ca.hessian(lag, z)[0]
        funs["stage_hessian"] = (fn("h", [x, u, d, sigma, p, lam], [H[:n, :n], H[:n, n:].T, H[n:, n:]]),
                                 [(n, n), (n, m), (m, m)])
        if r:
            funs["stage_constraints"] = (fn("g", [x, u, d], [g]), [(r,)])
            funs["stage_constraints_jacobian"] = (fn("gj", [x, u, d], [ca.jacobian(g, x).T, ca.jacobian(g, u).T]),
                                                  [(r, n), (r, m)])
        F, gN = ca.SX(model.F), sx(model.gN)
        lamN = ca.SX.sym("lamN", rN)
        final_lag = sigma * F + (ca.dot(lamN, gN) if rN else 0)
        funs["final"] = (fn("F", [xN], [F, ca.gradient(F, xN), gN, ca.jacobian(gN, xN).T]),
                         [(), (n,), (rN,), (rN, n)])
        funs["final_hessian"] = (fn("FH", [xN, sigma, lamN], [ca.hessian(final_lag, xN)[0]]), [(n, n)])
        return self.evaluators(funs)

    def evaluators(self, funs):
        """name -> evaluator(*stage arrays) -> output arrays, for ``funs`` (name -> (SX function,
        output shapes per stage)), in this back-end's mode."""
        if self.mode in ("llvm", "numba"):
            compiled = LLVMKernel if self.mode == "llvm" else sx_to_numba
            return {name: NumbaEvaluator(compiled(fun), shapes, flat=True) for name, (fun, shapes) in funs.items()}
        return {name: _CasadiEvaluator(fun, shapes) for name, (fun, shapes) in funs.items()}


class _CasadiEvaluator:
    """A CasADi function of per-stage arguments, evaluated on K rows (mapped functions cached
    per K)."""

    def __init__(self, fun, shapes):
        self.fun, self.shapes, self._mapped = fun, shapes, {}

    def __call__(self, *args):
        K = args[0].shape[0] if np.ndim(args[0]) else 1
        mapped = self._mapped.get(K)
        if mapped is None:
            mapped = self._mapped[K] = _CasadiMapped(self.fun, K, self.shapes)
        return mapped(*args)
