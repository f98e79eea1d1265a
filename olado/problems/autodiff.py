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

import hashlib
import importlib.util
import math
import os
import sys
import time

import numpy as np

from ..errors import AutoDiffNotAvailableError, ProblemDefinitionError
from .docp import DOCP

__all__ = ["AutoDiffDOCP", "ADModel", "BACKENDS", "sin", "cos", "tan", "exp", "log", "sqrt", "tanh",
           "atan", "atan2", "asin", "acos", "sinh", "cosh", "fabs", "fmax", "fmin"]

#: back-end -> (module it needs, the extra that installs it)
BACKENDS = {"casadi": ("casadi", "olado[ad]"), "sympy": ("sympy", "olado[ad-sympy]")}


# ============================================================================ elementary functions
def _elementary(name, casadi_name=None, sympy_name=None, numpy_name=None):
    """An elementary function that works on numbers and arrays (numpy), CasADi SX and SymPy
    expressions alike, so that a model's code is the same for every back-end."""
    casadi_name = casadi_name or name
    sympy_name = sympy_name or name
    numpy_fn = getattr(np, numpy_name or name)

    def fn(*args):
        mod = type(args[0]).__module__ if args else ""
        for a in args:
            mod = type(a).__module__
            if mod.startswith(("casadi", "sympy")):
                break
        if mod.startswith("casadi"):
            import casadi   # noqa: PLC0415 - the extra is imported on use
            return getattr(casadi, casadi_name)(*args)
        if mod.startswith("sympy"):
            import sympy    # noqa: PLC0415
            return getattr(sympy, sympy_name)(*args)
        return numpy_fn(*args)

    fn.__name__ = name
    fn.__doc__ = f"{name} of a number, array, CasADi or SymPy expression."
    return fn


sin, cos, tan, exp, log, sqrt, tanh = (_elementary(nm) for nm in ("sin", "cos", "tan", "exp", "log", "sqrt", "tanh"))
sinh, cosh = _elementary("sinh"), _elementary("cosh")
atan = _elementary("atan", numpy_name="arctan")
asin = _elementary("asin", numpy_name="arcsin")
acos = _elementary("acos", numpy_name="arccos")
atan2 = _elementary("atan2", numpy_name="arctan2")
fabs = _elementary("fabs", sympy_name="Abs", numpy_name="abs")
fmax = _elementary("fmax", sympy_name="Max", numpy_name="fmax")
fmin = _elementary("fmin", sympy_name="Min", numpy_name="fmin")


# ============================================================================ the traced model
class StageModel:
    """The user's model as symbolic expressions: per stage f (n), l (scalar), g (r); at the end
    F (scalar) and gN (rN), in the symbols x, u, d (and xN); built by a back-end's symbols."""

    def __init__(self, problem, backend):
        self.n, self.m, self.q = problem.n, problem.m, problem.n_stage_data
        self.r, self.rN = problem.r, problem.rN
        self.x, self.u, self.d = backend.vector("x", self.n), backend.vector("u", self.m), backend.vector("d", self.q)
        self.xN = backend.vector("xN", self.n)
        out = problem.stage(self.x, self.u, self.d)
        if not isinstance(out, (tuple, list)) or len(out) not in (2, 3):
            raise ProblemDefinitionError("must return (x_next, cost) or (x_next, cost, g)", function="stage")
        self.f = self._vector(out[0], self.n, "stage", "x_next")
        self.l = self._scalar(out[1], "stage", "cost")
        self.g = self._vector(out[2] if len(out) == 3 else (), self.r, "stage", "g")
        fin = problem.final(self.xN)
        if isinstance(fin, (tuple, list)):
            if len(fin) != 2:
                raise ProblemDefinitionError("must return cost or (cost, gN)", function="final")
            fin, gN = fin
        else:
            gN = ()
        self.F = self._scalar(fin, "final", "cost")
        self.gN = self._vector(gN, self.rN, "final", "gN")

    @staticmethod
    def _entries(value):
        if hasattr(value, "shape") and not isinstance(value, np.ndarray) and hasattr(value, "nnz"):
            # a CasADi SX/MX/DM vector: its entries
            return [value[i] for i in range(value.numel())]
        if isinstance(value, (list, tuple, np.ndarray)) or type(value).__module__.startswith("sympy.matrices"):
            return list(np.asarray(value, dtype=object).reshape(-1)) if isinstance(value, np.ndarray) else list(value)
        return [value]

    def _vector(self, value, size, function, array):
        entries = self._entries(value)
        if len(entries) != size:
            raise ProblemDefinitionError(f"returned {len(entries)} entries, the problem declares {size}",
                                         function=function, array=array)
        return entries

    def _scalar(self, value, function, array):
        entries = self._entries(value)
        if len(entries) != 1:
            raise ProblemDefinitionError(f"expected one scalar expression, got {len(entries)}",
                                         function=function, array=array)
        return entries[0]


# ============================================================================ CasADi back-end
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
            compiled = _LLVMKernel if self.mode == "llvm" else sx_to_numba
            return {name: _NumbaEvaluator(compiled(fun), shapes, flat=True) for name, (fun, shapes) in funs.items()}
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


# ============================================================================ CasADi SX -> numba
_UNARY = {"ASSIGN": "{0}", "NEG": "-{0}", "EXP": "math.exp({0})", "LOG": "math.log({0})",
          "SQRT": "math.sqrt({0})", "SQ": "{0} * {0}", "TWICE": "2.0 * {0}", "INV": "1.0 / {0}",
          "SIN": "math.sin({0})", "COS": "math.cos({0})", "TAN": "math.tan({0})",
          "ASIN": "math.asin({0})", "ACOS": "math.acos({0})", "ATAN": "math.atan({0})",
          "SINH": "math.sinh({0})", "COSH": "math.cosh({0})", "TANH": "math.tanh({0})",
          "ASINH": "math.asinh({0})", "ACOSH": "math.acosh({0})", "ATANH": "math.atanh({0})",
          "FABS": "abs({0})", "FLOOR": "float(math.floor({0}))", "CEIL": "float(math.ceil({0}))",
          "ERF": "math.erf({0})", "LOG1P": "math.log1p({0})", "EXPM1": "math.expm1({0})",
          "SIGN": "(1.0 if {0} > 0 else (-1.0 if {0} < 0 else 0.0))",
          "NOT": "(1.0 if {0} == 0 else 0.0)"}
_BINARY = {"ADD": "{0} + {1}", "SUB": "{0} - {1}", "MUL": "{0} * {1}", "DIV": "{0} / {1}",
           "POW": "{0} ** {1}", "CONSTPOW": "{0} ** {1}", "ATAN2": "math.atan2({0}, {1})",
           "FMIN": "min({0}, {1})", "FMAX": "max({0}, {1})", "FMOD": "math.fmod({0}, {1})",
           "COPYSIGN": "math.copysign({0}, {1})", "HYPOT": "math.hypot({0}, {1})",
           "LT": "(1.0 if {0} < {1} else 0.0)", "LE": "(1.0 if {0} <= {1} else 0.0)",
           "EQ": "(1.0 if {0} == {1} else 0.0)", "NE": "(1.0 if {0} != {1} else 0.0)",
           "AND": "(1.0 if ({0} != 0 and {1} != 0) else 0.0)",
           "OR": "(1.0 if ({0} != 0 or {1} != 0) else 0.0)",
           "IF_ELSE_ZERO": "({1} if {0} != 0 else 0.0)"}


def _constant(value):
    if math.isfinite(value):
        return repr(float(value))
    return "math.nan" if math.isnan(value) else ("math.inf" if value > 0 else "-math.inf")


def sx_source(fun, name="kernel"):
    """Python source of a loop over the stages evaluating the CasADi SX function ``fun``: the
    function's instruction list (its algorithm, the same one CasADi's code generator prints as
    C) as straight-line scalar code. Argument j is a (K, nnz_in(j)) array, result j a
    (K, nnz_out(j)) array, entries in CasADi's column-major nonzero order."""
    import casadi as ca   # noqa: PLC0415
    ops = {getattr(ca, f"OP_{nm}"): nm for nm in list(_UNARY) + list(_BINARY) + ["CONST", "INPUT", "OUTPUT"]}
    n_in, n_out = fun.n_in(), fun.n_out()
    args = [f"a{j}" for j in range(n_in)] + [f"r{j}" for j in range(n_out)]
    lines = [f"def {name}({', '.join(args)}):", "    for i in range(a0.shape[0]):"]
    for k in range(fun.n_instructions()):
        op = ops.get(fun.instruction_id(k))
        if op is None:
            raise ProblemDefinitionError(f"the CasADi operation {fun.instruction_id(k)} has no numba translation; "
                                         "use the back-end option mode='vm'", function="autodiff")
        ins, outs = fun.instruction_input(k), fun.instruction_output(k)
        if op == "OUTPUT":
            lines.append(f"        r{outs[0]}[i, {outs[1]}] = w{ins[0]}")
            continue
        if op == "INPUT":
            rhs = f"a{ins[0]}[i, {ins[1]}]"
        elif op == "CONST":
            rhs = _constant(fun.instruction_constant(k))
        elif op in _UNARY:
            rhs = _UNARY[op].format(f"w{ins[0]}")
        else:
            rhs = _BINARY[op].format(f"w{ins[0]}", f"w{ins[1]}")
        lines.append(f"        w{outs[0]} = {rhs}")
    if len(lines) == 2:
        lines.append("        pass")
    return "\n".join(lines) + "\n"


def cache_directory():
    """Where the compiled kernels of AD models are kept between runs: ``$OLADO_CACHE_DIR/autodiff``
    or ``~/.cache/olado/autodiff``; None (no disk cache) when neither can be written."""
    root = os.environ.get("OLADO_CACHE_DIR") or os.path.join(os.path.expanduser("~"), ".cache", "olado")
    path = os.path.join(root, "autodiff")
    try:
        os.makedirs(path, exist_ok=True)
    except OSError:
        return None
    return path if os.access(path, os.W_OK) else None


def compile_kernel(source, n_args):
    """Compile the loop ``kernel`` of ``source`` (arguments: ``n_args`` C-contiguous float64
    matrices) with numba, now (an explicit signature: the set-up time holds the compilation).

    The source is written to a file of the cache directory named by its hash and imported from
    there, so that numba's disk cache serves the next run of the same model (the same source)
    in milliseconds; without a writable cache directory it is compiled in memory every time."""
    import numba as nb   # noqa: PLC0415
    signature = nb.void(*([nb.float64[:, ::1]] * n_args))
    directory = cache_directory()
    if directory is None:
        namespace = {"math": math}
        exec(source, namespace)   # noqa: S102 - source generated from the model
        return nb.njit(signature)(namespace["kernel"])
    digest = hashlib.sha1(source.encode("utf-8")).hexdigest()[:20]
    name = f"olado_ad_{digest}"
    path = os.path.join(directory, name + ".py")
    if not os.path.exists(path):
        text = ("# generated by olado.problems.autodiff from a model's SX algorithm\n"
                "import math\nimport numba as nb\n\n" + source.replace("def kernel(", "def _kernel(", 1)
                + "\n\nmatrix = nb.float64[:, ::1]\n"
                f"kernel = nb.njit(nb.void(*([matrix] * {n_args})), cache=True)(_kernel)\n")
        tmp = f"{path}.{os.getpid()}.tmp"
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, path)
    module = sys.modules.get(name)
    if module is None:
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module    # before running it: numba's cache names the module
        try:
            spec.loader.exec_module(module)
        except BaseException:
            del sys.modules[name]
            raise
    return module.kernel


def sx_to_numba(fun):
    """The CasADi SX function ``fun`` compiled by numba as a loop over stages (:func:`sx_source`)."""
    return compile_kernel(sx_source(fun), fun.n_in() + fun.n_out())


# ============================================================================ CasADi SX -> LLVM IR
_LLVM_LIBM1 = {"EXP": "exp", "LOG": "log", "SQRT": "sqrt", "SIN": "sin", "COS": "cos", "TAN": "tan",
               "ASIN": "asin", "ACOS": "acos", "ATAN": "atan", "SINH": "sinh", "COSH": "cosh",
               "TANH": "tanh", "ASINH": "asinh", "ACOSH": "acosh", "ATANH": "atanh", "FABS": "fabs",
               "FLOOR": "floor", "CEIL": "ceil", "ERF": "erf", "LOG1P": "log1p", "EXPM1": "expm1"}
_LLVM_LIBM2 = {"POW": "pow", "CONSTPOW": "pow", "ATAN2": "atan2", "FMOD": "fmod", "COPYSIGN": "copysign",
               "HYPOT": "hypot", "FMIN": "fmin", "FMAX": "fmax"}
_LLVM_ARITH = {"ADD": "fadd", "SUB": "fsub", "MUL": "fmul", "DIV": "fdiv"}
_LLVM_CMP = {"LT": "<", "LE": "<=", "EQ": "=="}
#: the execution engines of the compiled kernels (a kernel's code lives as long as its engine)
#: and the kernels' addresses by their IR: a model built again in the same process is not
#: compiled again
_ENGINES = []
_COMPILED = {}


def sx_llvm_ir(fun):
    """LLVM IR (text) of ``void kernel(i64 K, double* a0, ..., double* r0, ...)``: a loop over the
    K stages evaluating the CasADi SX function ``fun`` -- its instruction list (the algorithm
    CasADi's C code generator prints) as one SSA value per instruction, the elementary functions
    as calls to the C math library. Argument j is a C-contiguous (K, nnz_in(j)) array, result j
    a (K, nnz_out(j)) array, entries in CasADi's column-major nonzero order."""
    import casadi as ca   # noqa: PLC0415
    from llvmlite import ir   # noqa: PLC0415 - numba's own dependency
    names = (["ASSIGN", "NEG", "SQ", "TWICE", "INV", "CONST", "INPUT", "OUTPUT", "SIGN", "NOT", "NE",
              "AND", "OR", "IF_ELSE_ZERO"] + list(_LLVM_CMP) + list(_LLVM_ARITH) + list(_LLVM_LIBM1)
             + list(_LLVM_LIBM2))
    ops = {getattr(ca, f"OP_{nm}"): nm for nm in names}
    dbl, i64 = ir.DoubleType(), ir.IntType(64)
    n_in, n_out = fun.n_in(), fun.n_out()
    module = ir.Module(name="olado_ad")
    kernel = ir.Function(module, ir.FunctionType(ir.VoidType(), [i64] + [dbl.as_pointer()] * (n_in + n_out)),
                         name="kernel")
    libm = {}

    def call(b, name, *args):
        if name not in libm:
            libm[name] = ir.Function(module, ir.FunctionType(dbl, [dbl] * len(args)), name=name)
        return b.call(libm[name], list(args))

    entry, loop, done = (kernel.append_basic_block(nm) for nm in ("entry", "loop", "done"))
    b = ir.IRBuilder(entry)
    K = kernel.args[0]
    b.cbranch(b.icmp_signed(">", K, i64(0)), loop, done)
    b.position_at_end(loop)
    i = b.phi(i64)
    i.add_incoming(i64(0), entry)
    rows_in = [b.gep(kernel.args[1 + j], [b.mul(i, i64(fun.nnz_in(j)))]) for j in range(n_in)]
    rows_out = [b.gep(kernel.args[1 + n_in + j], [b.mul(i, i64(fun.nnz_out(j)))]) for j in range(n_out)]
    zero, one = dbl(0.0), dbl(1.0)
    truth = lambda v: b.fcmp_unordered("!=", v, zero)   # noqa: E731 - nonzero (NaN counts), as in C
    w = {}
    for k in range(fun.n_instructions()):
        op = ops.get(fun.instruction_id(k))
        if op is None:
            raise ProblemDefinitionError(f"the CasADi operation {fun.instruction_id(k)} has no translation; "
                                         "use the back-end option mode='vm'", function="autodiff")
        ins, outs = fun.instruction_input(k), fun.instruction_output(k)
        a = w.get(ins[0]) if ins else None
        c = w.get(ins[1]) if len(ins) > 1 else None
        if op == "OUTPUT":
            b.store(a, b.gep(rows_out[outs[0]], [i64(outs[1])]))
            continue
        if op == "INPUT":
            v = b.load(b.gep(rows_in[ins[0]], [i64(ins[1])]))
        elif op == "CONST":
            v = dbl(fun.instruction_constant(k))
        elif op == "ASSIGN":
            v = a
        elif op == "NEG":
            v = b.fneg(a)
        elif op == "SQ":
            v = b.fmul(a, a)
        elif op == "TWICE":
            v = b.fadd(a, a)
        elif op == "INV":
            v = b.fdiv(one, a)
        elif op in _LLVM_ARITH:
            v = getattr(b, _LLVM_ARITH[op])(a, c)
        elif op in _LLVM_CMP:
            v = b.uitofp(b.fcmp_ordered(_LLVM_CMP[op], a, c), dbl)
        elif op == "NE":
            v = b.uitofp(b.fcmp_unordered("!=", a, c), dbl)
        elif op == "NOT":
            v = b.uitofp(b.fcmp_ordered("==", a, zero), dbl)
        elif op in ("AND", "OR"):
            v = b.uitofp(b.and_(truth(a), truth(c)) if op == "AND" else b.or_(truth(a), truth(c)), dbl)
        elif op == "IF_ELSE_ZERO":
            v = b.select(truth(a), c, zero)
        elif op == "SIGN":
            v = b.select(b.fcmp_ordered(">", a, zero), one, b.select(b.fcmp_ordered("<", a, zero), dbl(-1.0), a))
        elif op in _LLVM_LIBM1:
            v = call(b, _LLVM_LIBM1[op], a)
        else:
            v = call(b, _LLVM_LIBM2[op], a, c)
        w[outs[0]] = v
    step = b.add(i, i64(1))
    i.add_incoming(step, b.block)
    b.cbranch(b.icmp_signed("<", step, K), loop, done)
    b.position_at_end(done)
    b.ret_void()
    return str(module)


class _LLVMKernel:
    """A kernel compiled from :func:`sx_llvm_ir` by LLVM (llvmlite, numba's own dependency: no C
    compiler), called like the numba kernels: kernel(*arrays), every array a C-contiguous
    float64 (K, size) matrix (through the compiled trampoline of :mod:`._ad_kernels`)."""

    def __init__(self, fun):
        import llvmlite.binding as llvm   # noqa: PLC0415
        from ._ad_kernels import call_kernel   # noqa: PLC0415 - loads numba
        llvm.initialize_native_target()
        llvm.initialize_native_asmprinter()
        text = sx_llvm_ir(fun)
        self.call = call_kernel
        self.address = _COMPILED.get(text)
        if self.address is not None:        # the same function compiled before in this process
            return
        machine = llvm.Target.from_default_triple().create_target_machine(opt=3)
        module = llvm.parse_assembly(text)
        module.verify()
        builder = llvm.create_pass_builder(machine, llvm.create_pipeline_tuning_options(speed_level=2))
        builder.getModulePassManager().run(module, builder)
        engine = llvm.create_mcjit_compiler(module, machine)
        engine.finalize_object()
        _ENGINES.append(engine)
        self.address = _COMPILED[text] = engine.get_function_address("kernel")

    def __call__(self, *arrays):
        self.call(self.address, arrays)


# ============================================================================ SymPy + numba back-end
class SympyBackend:
    """SymPy: symbolic derivatives, common subexpressions eliminated, one numba-compiled loop over
    the stages per function."""

    name = "sympy"

    def __init__(self):
        import sympy   # noqa: PLC0415 - the optional extra
        self.sp = sympy

    def vector(self, name, size):
        return self.sp.Matrix(self.sp.symbols(f"{name}0:{size}", real=True)) if size else self.sp.zeros(0, 1)

    def build(self, model):
        sp = self.sp
        x, u, d, xN = list(model.x), list(model.u), list(model.d), list(model.xN)
        n, m, r, rN = model.n, model.m, model.r, model.rN
        z = x + u
        sigma = sp.Symbol("sigma", real=True)
        p = list(sp.symbols(f"p0:{n}", real=True))
        lam = list(sp.symbols(f"lam0:{r}", real=True)) if r else []
        lamN = list(sp.symbols(f"lamN0:{rN}", real=True)) if rN else []
        f, l, g = [sp.sympify(e) for e in model.f], sp.sympify(model.l), [sp.sympify(e) for e in model.g]
        jac = lambda exprs, vs: [[sp.diff(e, v) for v in vs] for e in exprs]  # noqa: E731
        lag = sigma * l + sum(pi * fi for pi, fi in zip(p, f)) + sum(li * gi for li, gi in zip(lam, g))
        grad = [sp.diff(lag, v) for v in z]
        H = [[sp.diff(grad[i], z[j]) if j >= i else None for j in range(n + m)] for i in range(n + m)]
        Hs = lambda i, j: H[min(i, j)][max(i, j)]  # noqa: E731
        stage_in = [("X", x), ("U", u), ("D", d)]
        specs = {
            "dynamics": (stage_in, [f]),
            "stage_cost": (stage_in, [l]),
            "dynamics_jacobian": (stage_in, [jac(f, x), jac(f, u)]),
            "stage_cost_gradient": (stage_in, [[sp.diff(l, v) for v in x], [sp.diff(l, v) for v in u]]),
            "stage_hessian": (stage_in + [("S", sigma), ("P", p), ("L", lam)],
                              [[[Hs(i, j) for j in range(n)] for i in range(n)],
                               [[Hs(i, n + j) for j in range(m)] for i in range(n)],
                               [[Hs(n + i, n + j) for j in range(m)] for i in range(m)]]),
        }
        if r:
            specs["stage_constraints"] = (stage_in, [g])
            specs["stage_constraints_jacobian"] = (stage_in, [jac(g, x), jac(g, u)])
        F, gN = sp.sympify(model.F), [sp.sympify(e) for e in model.gN]
        specs["final"] = ([("X", xN)], [F, [sp.diff(F, v) for v in xN], gN, jac(gN, xN)])
        flag = sigma * F + sum(li * gi for li, gi in zip(lamN, gN))
        specs["final_hessian"] = ([("X", xN), ("S", sigma), ("L", lamN)], [jac([sp.diff(flag, v) for v in xN], xN)])
        return {name: self._compile(name, ins, outs) for name, (ins, outs) in specs.items()}

    def _compile(self, name, inputs, outputs):
        """Python source of one loop over the stages writing every output entry, compiled by
        numba like the CasADi translation (:func:`compile_kernel`: every argument a (K, size)
        matrix, sigma (K, 1), an output's entries in C order)."""
        from sympy.printing.pycode import PythonCodePrinter   # noqa: PLC0415
        sp = self.sp
        flat, targets, shapes = [], [], []
        for o, out in enumerate(outputs):
            arr = np.array(out, dtype=object)
            shapes.append(arr.shape)
            for j, idx in enumerate(np.ndindex(arr.shape)):
                flat.append(sp.sympify(arr[idx]))
                targets.append(f"o{o}[i, {j}]")
        subs, reduced = sp.cse(flat, symbols=sp.numbered_symbols("t"), optimizations="basic")
        printer = PythonCodePrinter({"standard": "python3", "fully_qualified_modules": True})
        args = [nm for nm, _ in inputs]
        lines = [f"def kernel({', '.join(args + [f'o{o}' for o in range(len(outputs))])}):",
                 f"    for i in range({args[0]}.shape[0]):"]
        for nm, syms in inputs:
            for j, sym in enumerate([syms] if nm == "S" else syms):
                lines.append(f"        {sym} = {nm}[i, {j}]")
        for sym, expr in subs:
            lines.append(f"        {sym} = {printer.doprint(expr)}")
        for tgt, expr in zip(targets, reduced):
            lines.append(f"        {tgt} = {printer.doprint(expr)}")
        if not targets:
            lines.append("        pass")
        kernel = compile_kernel("\n".join(lines) + "\n", len(inputs) + len(outputs))
        return _NumbaEvaluator(kernel, shapes, flat=True)


class _NumbaEvaluator:
    """A compiled loop over the stages: inputs (K, size) (sigma (K,)), outputs (K,) + shape; with
    ``flat`` the kernel sees every argument as (K, size) (CasADi's column-major entry order)."""

    def __init__(self, kernel, shapes, flat=False):
        self.kernel, self.shapes, self.flat = kernel, shapes, flat

    def __call__(self, *args):
        K = args[0].shape[0]
        outs = tuple(np.empty((K,) + s) for s in self.shapes)
        if self.flat:
            self.kernel(*(a.reshape(K, -1) for a in args), *(o.reshape(K, -1) for o in outs))
        else:
            self.kernel(*args, *outs)
        return outs


def require_backend(name):
    """Check that the back-end ``name`` ("casadi" or "sympy") is installed, without importing it:
    AutoDiffNotAvailableError naming the optional extra otherwise."""
    if name not in BACKENDS:
        raise ProblemDefinitionError(f"unknown automatic-differentiation back-end {name!r}; choose one of "
                                     f"{', '.join(BACKENDS)}", function="autodiff", array="backend")
    module, extra = BACKENDS[name]
    if importlib.util.find_spec(module) is None:
        raise AutoDiffNotAvailableError(
            f"exact derivatives with the {name} back-end need the optional package '{module}': "
            f"pip install {extra} (or write the derivatives by hand, or use finite differences: "
            "a plain DOCP subclass)", function="autodiff", array="backend")


def make_backend(name, **options):
    """The back-end ``name`` with its ``options`` (:func:`require_backend` first)."""
    require_backend(name)
    return CasadiBackend(**options) if name == "casadi" else SympyBackend(**options)


# ============================================================================ ContinuousDOCP.model
class ADModel:
    """The model (F, J, H) of :meth:`ContinuousDOCP.model <olado.problems.continuous.ContinuousDOCP.model>`
    from a right-hand side written once: ``rhs(x, u) -> (f (n entries), L)`` in symbolic x (n,),
    u (m,) -- F = (f, L) (K, n+1), J = dF/dz (K, n+1, n+m), H = d2F/dz2 (K, n+1, n+m, n+m),
    z = (x, u), by CasADi's differentiation and the back-end's compiled kernels
    (``mode``: "llvm", "numba", "vm", "jit"). Built on first call::

        class Lotka(ExactHessians, ContinuousDOCP):
            _ad_model = ADModel(lambda x, u: ([x[0] - x[0] * x[1] - 0.4 * x[0] * u[0], ...], ...), 2, 1)

            def model(self, X, U, order):      # (not ``_rhs``: ContinuousDOCP has a method of that name)
                return self._ad_model(X, U, order)
    """

    def __init__(self, rhs, n, m, mode="llvm"):
        require_backend("casadi")
        self.rhs, self.n, self.m, self.mode = rhs, int(n), int(m), mode
        self._funs = None

    def _build(self):
        backend = CasadiBackend(mode=self.mode)
        ca = backend.ca
        x, u = ca.SX.sym("x", self.n), ca.SX.sym("u", self.m)
        out = self.rhs(x, u)
        if not isinstance(out, (tuple, list)) or len(out) != 2:
            raise ProblemDefinitionError("must return (f, L)", function="rhs")
        f = StageModel._entries(out[0])
        if len(f) != self.n:
            raise ProblemDefinitionError(f"returned {len(f)} entries, the model has {self.n} states",
                                         function="rhs", array="f")
        F = ca.vertcat(*[ca.SX(e) for e in f], ca.SX(StageModel._entries(out[1])[0]))
        z = ca.vertcat(x, u)
        nF, nz = self.n + 1, self.n + self.m
        J = ca.jacobian(F, z)
        # C order of (K, nF, nz[, nz]) = the entries in that order, one column per stage
        Jc = ca.vertcat(*[J[i, j] for i in range(nF) for j in range(nz)])
        Hc = ca.vertcat(*[e for i in range(nF) for e in
                          (lambda Hi: [Hi[j, l] for j in range(nz) for l in range(nz)])(ca.hessian(F[i], z)[0])])
        make = lambda name, outs: ca.Function(name, [x, u], ca.cse([ca.densify(o) for o in outs]))  # noqa: E731
        self._funs = backend.evaluators({"F": (make("F", [F]), [(nF,)]),
                                         "FJ": (make("FJ", [F, Jc]), [(nF,), (nF, nz)]),
                                         "FJH": (make("FJH", [F, Jc, Hc]), [(nF,), (nF, nz), (nF, nz, nz)])})

    def __call__(self, X, U, order):
        if self._funs is None:
            self._build()
        X = np.ascontiguousarray(X, dtype=np.float64)
        U = np.ascontiguousarray(U, dtype=np.float64)
        outs = self._funs[("F", "FJ", "FJH")[min(int(order), 2)]](X, U)
        return tuple(outs) + (None,) * (3 - len(outs))


# ============================================================================ the DOCP
class AutoDiffDOCP(DOCP):
    """A DOCP written once as :meth:`stage` and :meth:`final` (module docstring); every DOCP
    function and derivative, the Lagrangian Hessian blocks included, comes from the back-end
    :attr:`ad_backend` ("casadi" or "sympy"), vectorized over the stages.

    The model is traced and compiled on first use (so a subclass may set its data after
    ``super().__init__``); :attr:`setup_time` holds the seconds that took. A missing back-end
    raises :class:`~olado.errors.AutoDiffNotAvailableError` at construction.
    """

    vectorized = True
    #: "casadi" or "sympy"
    ad_backend = "casadi"
    #: back-end options, e.g. ``{"mode": "vm"}`` (CasADi: "llvm" (default), "numba", "vm", "jit")
    ad_options: dict = {}

    # ------------------------------------------------------------------ the user's model
    def stage(self, x, u, d):
        """(f^k, f_0^k) or (f^k, f_0^k, g^k) of eqs. (1)-(3) in symbolic x (n,), u (m,), d (q,)."""
        raise ProblemDefinitionError(f"{type(self).__name__} must define stage(x, u, d)", function="stage")

    def final(self, x):
        """F^N(x) or (F^N(x), g^N(x)) in symbolic x (n,); default no final cost."""
        return 0

    def stage_data(self):
        """Per-stage numeric data (N, q) passed to :meth:`stage` as ``d`` (default none, q = 0)."""
        return np.zeros((self.N, 0))

    # ------------------------------------------------------------------ compilation
    @property
    def n_stage_data(self):
        """Number of per-stage data entries q (columns of :meth:`stage_data`, read once)."""
        return self._data().shape[1]

    def _data(self):
        data = self.__dict__.get("_ad_data")
        if data is None:
            raw = self.stage_data()
            cols = np.shape(raw)[1] if np.ndim(raw) == 2 else -1
            data = np.ascontiguousarray(self.check_array(raw, (self.N, cols), "stage_data", "d"))
            self._ad_data = data
        return data

    def check_functions(self):
        """DOCP's check, and the back-end is installed (AutoDiffNotAvailableError otherwise)."""
        super().check_functions()
        require_backend(self.ad_backend)

    def ad_functions(self):
        """The compiled functions (built on first call; :attr:`setup_time` seconds)."""
        funs = self.__dict__.get("_ad_functions")
        if funs is None:
            t0 = time.perf_counter()
            backend = make_backend(self.ad_backend, **self.ad_options)
            funs = backend.build(StageModel(self, backend))
            self._ad_functions = funs
            self.setup_time = time.perf_counter() - t0
        return funs

    def _stage_args(self, k, x, u):
        x = np.ascontiguousarray(x, dtype=np.float64)
        u = np.ascontiguousarray(u, dtype=np.float64)
        if x.ndim == 1:
            x, u = x[None, :], u[None, :]
        D = self._data()
        if not (k is self._K or (np.ndim(k) == 1 and len(k) == self.N and x.shape[0] == self.N
                                 and np.array_equal(k, self._K))):
            D = np.ascontiguousarray(D[np.asarray(k, dtype=np.int64).reshape(-1)])
            if D.shape[0] == 1 and x.shape[0] > 1:
                D = np.ascontiguousarray(np.broadcast_to(D, (x.shape[0], D.shape[1])))
        return x, u, D

    def _eval(self, name, k, x, u, *extra):
        return self.ad_functions()[name](*self._stage_args(k, x, u), *extra)

    # ------------------------------------------------------------------ DOCP functions
    def dynamics(self, k, x, u):
        return self._eval("dynamics", k, x, u)[0]

    def stage_cost(self, k, x, u):
        return self._eval("stage_cost", k, x, u)[0]

    def stage_constraints(self, k, x, u):
        if not self.r:
            return np.zeros((np.size(k), 0))
        return self._eval("stage_constraints", k, x, u)[0]

    def dynamics_jacobian(self, k, x, u):
        return self._eval("dynamics_jacobian", k, x, u)

    def stage_cost_gradient(self, k, x, u):
        return self._eval("stage_cost_gradient", k, x, u)

    def stage_constraints_jacobian(self, k, x, u):
        return self._eval("stage_constraints_jacobian", k, x, u)

    def stage_hessian(self, k, x, u, sigma, p, lam):
        K = np.atleast_2d(x).shape[0]
        sig = np.ascontiguousarray(np.broadcast_to(np.asarray(sigma, dtype=np.float64).reshape(-1), (K,)))
        p = np.ascontiguousarray(p, dtype=np.float64)
        lam = np.ascontiguousarray(lam, dtype=np.float64).reshape(K, self.r)
        return self._eval("stage_hessian", k, x, u, sig, p, lam)

    def _final(self, x):
        x = np.ascontiguousarray(np.asarray(x, dtype=np.float64).reshape(1, self.n))
        return [o[0] for o in self.ad_functions()["final"](x)]

    def final_cost(self, x):
        return float(self._final(x)[0])

    def final_cost_gradient(self, x):
        return self._final(x)[1]

    def final_constraints(self, x):
        return self._final(x)[2] if self.rN else np.zeros(0)

    def final_constraints_jacobian(self, x):
        return self._final(x)[3]

    def final_hessian(self, x, sigma, lam):
        x = np.ascontiguousarray(np.asarray(x, dtype=np.float64).reshape(1, self.n))
        sig = np.full(1, float(sigma))
        lam = np.ascontiguousarray(np.asarray(lam, dtype=np.float64).reshape(1, self.rN))
        return self.ad_functions()["final_hessian"](x, sig, lam)[0][0]

    def derivative_sources(self) -> dict:
        """As :meth:`DOCP.derivative_sources`, naming the AD back-end instead of "analytic"."""
        what = f"automatic differentiation ({self.ad_backend}, {self.ad_options.get('mode', 'llvm')})" \
            if self.ad_backend == "casadi" else f"automatic differentiation ({self.ad_backend})"
        return {meth: what if src == "analytic" else src for meth, src in super().derivative_sources().items()}
