"""The Zambezi problem of paper 001 sec. 5 written once for automatic differentiation
(:mod:`olado.problems.autodiff`): the same data, bounds and start points as
:class:`~olado.problems.zambezi.Zambezi`, the same eqs. (40) and (44), but no hand-written
derivative. It exists to measure the AD path against the hand-written kernels
(benchmarks/bench_autodiff.py, docs/autodiff.md) and as a worked example of a model with
per-stage data (the month's inflows and evaporation coefficients)."""

from __future__ import annotations

import numpy as np

from .autodiff import AutoDiffDOCP
from .zambezi import Zambezi


class ZambeziAD(AutoDiffDOCP, Zambezi):
    """:class:`Zambezi` with every derivative from the AD back-end ``backend`` ("casadi" or
    "sympy"); the stage data d = (Z_1..Z_4, e_1..e_4) are the month's inflows and evaporation."""

    simulate = AutoDiffDOCP.simulate     # the stage function, not Zambezi's hand-written recursion

    def __init__(self, family="zambezi12", N=24, start="balance", year=None, extend="cyclic", *,
                 backend="casadi", backend_options=None, **options):
        self.ad_backend = backend
        self.ad_options = dict(backend_options or {})
        super().__init__(family=family, N=N, start=start, year=year, extend=extend, **options)
        self.name = f"{self.name}-ad"

    def stage_data(self):
        return np.column_stack([self.inflow, self.evaporation])

    def stage(self, x, u, d):
        """Balance equations (40) with the delay states, and the stage cost (44) with V^{k+1}
        replaced by the balance equation (module :mod:`olado.problems.zambezi`)."""
        A, B, C = (row.tolist() for row in self.fa)
        fh = self.fh.tolist()
        lin = [x[0] - u[0] - u[3], x[1] - u[4], x[2] + x[5] - u[1] - u[5],
               x[3] + u[0] + u[1] - u[2] + u[3] + u[5] - u[6]]
        Vn = [lin[j] + d[j] - d[4 + j] * ((A[j] * x[j] + B[j]) * x[j] + C[j]) for j in range(4)]

        def head(t, V):           # h_t(V) of turbine t (reservoirs 1, 3, 4)
            return (fh[0][t] * V + fh[1][t]) * V + fh[2][t]

        energy = (u[0] * (head(0, x[0]) + head(0, Vn[0])) + u[1] * (head(1, x[2]) + head(1, Vn[2]))
                  + u[2] * (head(2, x[3]) + head(2, Vn[3])))
        ref = self.u_ref.tolist()
        dev = [u[0] - ref[0], u[4] - ref[1], u[1] - ref[2], u[2] - ref[3]]
        cost = -float(self.alpha) * energy + float(self.psi) * sum(e * e for e in dev)
        return Vn + [u[4], x[4]], cost

    def final(self, x):
        """F^N of eq. (44): sum_i phi_i (V_i - V_i,ref)^2 - nu_E sum_i fe_i(V_i)."""
        phi, ref, fe = self.phi.tolist(), self.V_ref.tolist(), self.fe.tolist()
        dev = sum(phi[i] * (x[i] - ref[i]) * (x[i] - ref[i]) for i in range(4))
        evap = sum((fe[0][i] * x[i] + fe[1][i]) * x[i] + fe[2][i] for i in range(4))
        return dev - float(self.nu_E) * evap
