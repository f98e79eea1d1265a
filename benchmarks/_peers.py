"""The peers a user of olado would pick instead: CasADi + IPOPT and CasADi + FATROP (both in the
``casadi`` wheel), on the same DOCP as olado, built from a problem written for automatic
differentiation (:class:`olado.problems.autodiff.AutoDiffDOCP`, e.g. ZambeziAD).

The NLP is the DOCP of paper 001 eqs. (1)-(5) in multiple-shooting form with stage-ordered
variables and constraints, the layout FATROP's structure detection needs
(``structure_detection = "auto"``; CasADi's nlpsol documentation: the constraints in the order
gap_0, path_0, gap_1, path_1, ...):

    w = (x^0, u^0, x^1, u^1, ..., u^{N-1}, x^N),      x^0 fixed by its bounds,
    g = (x^1 - f^0(x^0, u^0), g^0(x^0, u^0), x^2 - f^1(x^1, u^1), g^1, ..., g^N(x^N)),
    J = sum_k f_0^k(x^k, u^k) + F^N(x^N),

every expression a CasADi SX expression of the problem's own :meth:`stage` and :meth:`final`
(the same code olado's AD back-end differentiates), so the peers solve the same problem from the
same start (olado's initial controls and the states of ``initial_state_guess`` or the
simulation). Both peers get exact Hessians from CasADi.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from olado.problems.autodiff.backends import split_final

#: the peers, by the name the tables use -> CasADi's plugin name
PEERS = {"casadi-ipopt": "ipopt", "casadi-fatrop": "fatrop"}

#: the least power of N :func:`estimate_setup` extrapolates a peer's set-up time with. CasADi +
#: IPOPT's set-up is linear in N (1.2 s at N = 1 200, 13 s at 12 000); FATROP's grows faster and
#: its power rises with N (1.6 from N = 252 to 1 200, 1.5-2.1 between 600, 1 200 and 2 400 in
#: CPU time, at least 1.8 from 1 200 to 12 000, where it took over 5 minutes), so it is
#: extrapolated as at least quadratic: an estimate from small N must not fall below the set-up
SETUP_MIN_POWER = {"casadi-ipopt": 1.0, "casadi-fatrop": 2.0}


@dataclass
class PeerResult:
    """One peer solve: objective, iterations, CasADi's status text and success flag, the solve's
    wall time (s) and the primal infeasibility of the returned point (max |g - bound|)."""

    objective: float
    iterations: int
    status: str
    success: bool
    time_s: float
    infeasibility: float


def estimate_setup(measured, N, min_power=1.0):
    """A peer's set-up time (s) at horizon ``N`` extrapolated from the times ``measured`` at
    smaller horizons ({N_i: seconds}, N_i < N): the power law t = c N^p through the two largest,
    with p at least ``min_power`` (``SETUP_MIN_POWER`` of the peer); with one measurement
    p = ``min_power``. None without any."""
    sizes = sorted(k for k in measured if k < N and measured[k] > 0)
    if not sizes:
        return None
    n1 = sizes[-1]
    p = min_power
    if len(sizes) > 1:
        n0 = sizes[-2]
        p = max(p, math.log(measured[n1] / measured[n0]) / math.log(n1 / n0))
    return measured[n1] * (N / n1) ** p


def _entries(value, size):
    import casadi as ca   # noqa: PLC0415 - the optional bench dependency

    if isinstance(value, (ca.SX, ca.MX, ca.DM)):
        return [value[i] for i in range(value.numel())]
    entries = list(value) if isinstance(value, (list, tuple, np.ndarray)) else [value]
    if len(entries) != size:
        raise ValueError(f"expected {size} entries, got {len(entries)}")
    return entries


class CasadiPeer:
    """``solver`` ("ipopt" or "fatrop") on the multiple-shooting NLP of ``problem`` (module
    docstring). Building it (the SX graph, CasADi's derivative functions, the solver) is timed
    in :attr:`setup_s`; :meth:`solve` times the solve alone."""

    def __init__(self, problem, solver, *, tol=1e-8, max_iter=3000, options=None):
        import casadi as ca   # noqa: PLC0415

        t0 = time.perf_counter()
        self.problem, self.solver_name = problem, solver
        nlp, self._bounds, self._equality = self._build(ca, problem)
        opts = {"expand": True, "print_time": False}
        if solver == "ipopt":
            opts.update({"ipopt.print_level": 0, "ipopt.sb": "yes", "ipopt.tol": tol, "ipopt.max_iter": max_iter})
        elif solver == "fatrop":
            opts.update({"structure_detection": "auto", "equality": self._equality, "fatrop.print_level": 0,
                         "fatrop.tol": tol, "fatrop.max_iter": max_iter})
        else:
            raise ValueError(f"unknown peer solver {solver!r}; choose ipopt or fatrop")
        opts.update(options or {})
        self._solver = ca.nlpsol(f"peer_{solver}", solver, nlp, opts)
        self.setup_s = time.perf_counter() - t0

    @staticmethod
    def _build(ca, p):
        """The NLP of the module docstring. The stage function is one SX function mapped over the
        stages (``Function.map``), so the graph has one copy of the stage, not N; ``expand``
        then turns the whole NLP into SX for the solvers (FATROP's structure detection needs it)."""
        n, m, N, r, rN = p.n, p.m, p.N, p.r, p.rN
        D = p._data()
        q = D.shape[1]
        x, u, d = ca.SX.sym("x", n), ca.SX.sym("u", m), ca.SX.sym("d", q)
        out = p.stage(x, u, d)          # SX vectors, as olado's CasADi back-end passes them
        stage_out = [ca.vertcat(*_entries(out[0], n)), out[1]]
        if r:
            stage_out.append(ca.vertcat(*_entries(out[2], r)))
        F = ca.Function("stage", [x, u, d], stage_out)
        xN = ca.SX.sym("xN", n)
        fin, gN = split_final(p.final(xN))
        FN = ca.Function("final", [xN], [fin, ca.vertcat(*_entries(gN, rN)) if rN else ca.SX(0, 1)])

        W = ca.MX.sym("w", N * (n + m) + n)
        Wm = ca.reshape(W[:N * (n + m)], n + m, N)          # column k = (x^k, u^k)
        XN = W[N * (n + m):]
        mapped = F.map(N, "serial")(Wm[:n, :], Wm[n:, :], ca.DM(D.T) if q else ca.DM(0, N))
        gaps = ca.horzcat(Wm[:n, 1:], XN) - mapped[0]
        G = ca.vertcat(gaps, mapped[2]) if r else gaps      # column k = (gap_k, g^k)
        JN, GN = FN(XN)
        g = ca.vertcat(ca.reshape(G, -1, 1), GN)
        J = ca.sum2(mapped[1]) + JN

        eq_stage = np.asarray(p.stage_equality_mask, dtype=bool).reshape(-1)
        eq_final = np.asarray(p.final_equality_mask, dtype=bool).reshape(-1)
        col = np.concatenate([np.ones(n, dtype=bool), eq_stage])
        equality = np.concatenate([np.tile(col, N), eq_final])
        lbg = np.zeros(equality.size)
        ubg = np.where(equality, 0.0, np.inf)
        lbx = np.concatenate([np.column_stack([p.x_lower[:N], p.u_lower]).reshape(-1), p.x_lower[N]])
        ubx = np.concatenate([np.column_stack([p.x_upper[:N], p.u_upper]).reshape(-1), p.x_upper[N]])
        lbx[:n] = ubx[:n] = p.x0
        nlp = {"x": W, "f": J, "g": g}
        return nlp, (lbx, ubx, lbg, ubg), [bool(e) for e in equality]

    def start(self):
        """olado's start point in the NLP's variable order: the initial controls and the states of
        ``initial_state_guess`` (the simulation of the controls where it gives none)."""
        p = self.problem
        U = p.initial_guess()
        X = p.initial_state_guess(U)
        if X is None:
            X = p.simulate(U)
        return np.concatenate([np.column_stack([X[:p.N], U]).reshape(-1), X[p.N]])

    def solve(self, w0=None) -> PeerResult:
        """One solve from ``w0`` (default :meth:`start`), timed."""
        lbx, ubx, lbg, ubg = self._bounds
        w0 = self.start() if w0 is None else w0
        t0 = time.perf_counter()
        sol = self._solver(x0=w0, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
        elapsed = time.perf_counter() - t0
        stats = self._solver.stats()
        gval = np.asarray(sol["g"]).reshape(-1)
        infeas = float(np.max(np.maximum(lbg - gval, 0) + np.maximum(gval - ubg, 0), initial=0.0))
        success = bool(stats.get("success", False))
        status = str(stats.get("return_status", ""))
        if self.solver_name == "fatrop":          # FATROP's return status is a number: 0 = converged
            status = "success" if success else f"fatrop status {status}"
        return PeerResult(objective=float(sol["f"]), iterations=int(stats.get("iter_count", -1)),
                          status=status, success=success,
                          time_s=elapsed, infeasibility=infeas)
