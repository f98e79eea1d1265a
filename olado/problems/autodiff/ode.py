"""The model (F, J, H) of a ContinuousDOCP from a right-hand side written once."""

from __future__ import annotations

import numpy as np

from ...errors import ProblemDefinitionError
from .backends import require_backend
from .casadi_backend import CasadiBackend
from .model import StageModel


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
