"""CasADi SX (or SymPy) functions as Python loops over the stages compiled by numba, cached on
disk by the hash of their source."""

from __future__ import annotations

import hashlib
import importlib.util
import math
import os
import sys

import numpy as np

from .sx import instructions


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
    n_in, n_out = fun.n_in(), fun.n_out()
    args = [f"a{j}" for j in range(n_in)] + [f"r{j}" for j in range(n_out)]
    lines = [f"def {name}({', '.join(args)}):", "    for i in range(a0.shape[0]):"]
    names = list(_UNARY) + list(_BINARY) + ["CONST", "INPUT", "OUTPUT"]
    for k, op, ins, outs in instructions(fun, names, "numba"):
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
    or ``~/.cache/olado/autodiff``; None (no disk cache) when it cannot be written or
    ``OLADO_KERNEL_CACHE`` is 0 (off, no, false)."""
    if os.environ.get("OLADO_KERNEL_CACHE", "1").strip().lower() in ("0", "off", "no", "false"):
        return None
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


class NumbaEvaluator:
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
