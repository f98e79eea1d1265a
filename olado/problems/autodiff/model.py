"""The DOCP written once (:class:`AutoDiffDOCP`) and its traced symbolic model (:class:`StageModel`)."""

from __future__ import annotations

import time

import numpy as np

from ...errors import ProblemDefinitionError
from ..docp import DOCP
from .backends import EXACT, make_backend, resolve_backend, split_final
from .numpy_backend import FD_NOTE, NumpyModel


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
        fin, gN = split_final(problem.final(self.xN))
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


class AutoDiffDOCP(DOCP):
    """A DOCP written once as :meth:`stage` and :meth:`final` (module docstring); every DOCP
    function and derivative, the Lagrangian Hessian blocks included, comes from the back-end
    :attr:`ad_backend` ("casadi" or "sympy"), vectorized over the stages; with "numpy" the
    functions are evaluated on numpy arrays and the derivatives are DOCP's finite differences
    (:mod:`~olado.problems.autodiff.numpy_backend`).

    The model is traced and compiled on first use (so a subclass may set its data after
    ``super().__init__``); :attr:`setup_time` holds the seconds that took. A missing back-end
    raises :class:`~olado.errors.AutoDiffNotAvailableError` at construction; "auto" (the
    default) is CasADi when it is installed, else "numpy" (a one-time warning says so, and
    :attr:`derivative_note` goes into every result).
    """

    vectorized = True
    #: "auto" (CasADi if installed, else "numpy"), "casadi", "sympy" or "numpy"
    ad_backend = "auto"
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
        self.backend_used()

    def backend_used(self) -> str:
        """The back-end :attr:`ad_backend` stands for ("auto" resolved once)."""
        cached = self.__dict__.get("_ad_backend_used")
        if cached is None or cached[0] != self.ad_backend:
            cached = self._ad_backend_used = (self.ad_backend, resolve_backend(self.ad_backend))
        return cached[1]

    @property
    def derivative_note(self) -> str:
        """A sentence for the results when the derivatives are finite differences (else "")."""
        return "" if self.backend_used() in EXACT else FD_NOTE

    def provides(self, name) -> bool:
        """DOCP's answer with an exact back-end; False on the numeric one (finite differences)."""
        return super().provides(name) and self.backend_used() in EXACT

    def ad_functions(self):
        """The compiled functions (built on first call; :attr:`setup_time` seconds)."""
        funs = self.__dict__.get("_ad_functions")
        if funs is None:
            t0 = time.perf_counter()
            name = self.backend_used()
            if name in EXACT:
                backend = make_backend(name, **self.ad_options)
                funs = backend.build(StageModel(self, backend))
            else:
                self._ad_numpy_model = NumpyModel(self)
                funs = self._ad_numpy_model.functions()
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
        fun = self.ad_functions().get(name)
        if fun is None:
            raise ProblemDefinitionError(f"the {self.backend_used()} back-end provides no {name} (finite "
                                         "differences serve it)", function=name)
        return fun(*self._stage_args(k, x, u), *extra)

    def simulate(self, U):
        """States X (N+1, n) from x^0 under controls U (eq. (2)): with the LLVM evaluator one compiled
        loop over the stages (:func:`~olado.problems.autodiff.trampoline.simulate_stages`); on the
        numpy back-end its loop of model calls (:meth:`NumpyModel.simulate`, the states checked
        once); else DOCP's loop of one-stage calls (about 10 us per stage in Python)."""
        funs = self.ad_functions()
        model = self.__dict__.get("_ad_numpy_model")
        if model is not None and type(self).dynamics is AutoDiffDOCP.dynamics:
            return self._simulate_numpy(model, U)
        address = getattr(getattr(funs["dynamics"], "kernel", None), "address", None)
        if address is None:
            return super().simulate(U)
        from .trampoline import simulate_stages   # noqa: PLC0415 - loads numba
        U = np.ascontiguousarray(self.check_array(U, (self.N, self.m), "simulate", "u"), dtype=np.float64)
        X = np.empty((self.N + 1, self.n))
        X[0] = self.x0
        self.counters["dynamics"] += 1
        simulate_stages(address, X, U, self._data())
        return self._check_stacked(X, (self.N + 1, self.n), "simulate", "x")

    def _simulate_numpy(self, model, U):
        """DOCP.simulate's states and errors (a non-finite x^{k+1} named as dynamics() at stage k)
        from the numpy model's loop."""
        U = np.ascontiguousarray(self.check_array(U, (self.N, self.m), "simulate", "u"), dtype=np.float64)
        X = np.empty((self.N + 1, self.n))
        X[0] = self.x0
        self.counters["dynamics"] += 1
        model.simulate(X, U, self._data())
        if not np.all(np.isfinite(X)):
            k = int(np.argwhere(~np.isfinite(X))[0, 0]) - 1
            self.check_array(X[k + 1], (self.n,), "dynamics", "x_next", stage=k)
        return X

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
        return [None if o is None else o[0] for o in self.ad_functions()["final"](x)]

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
        name = self.backend_used()
        if name not in EXACT:
            return {meth: f"{src} of the numpy-evaluated model" for meth, src in super().derivative_sources().items()}
        what = f"automatic differentiation ({name}, {self.ad_options.get('mode', 'llvm')})" \
            if name == "casadi" else f"automatic differentiation ({name})"
        return {meth: what if src == "analytic" else src for meth, src in super().derivative_sources().items()}
