"""SciPy's constrained NLP methods on the NLP view of a DOCP (paper 001 sec. 4.1, eq. (6)).

Two wrappers of :func:`scipy.optimize.minimize`, meant for small problems and as independent
references for the structured solvers:

* ``slsqp`` -- Kraft's sequential least-squares QP (an SQP method with a dense BFGS Hessian,
  sec. 4.2); gets dense gradients and Jacobians;
* ``trust-constr`` -- Byrd-Omojokun trust-region SQP for equality-constrained problems, and a
  trust-region interior-point (barrier) method when there are inequalities or bounds (sec. 4.3);
  gets the sparse Jacobian and the sparse exact Lagrangian Hessian of the NLP view (or a
  quasi-Newton approximation).

Fixed variables (lb == ub, i.e. x^0) are removed before SciPy sees the problem (see
:class:`~olado.solvers.common.FreeVariableNLP`); their multipliers are recovered from
stationarity. Multipliers are returned in the IPOPT sign convention of
:mod:`olado.solvers.common`, whatever the SciPy method's own convention.
"""

from __future__ import annotations

import dataclasses
import time
import warnings

import numpy as np
from scipy import optimize

from ...interrupts import Limits
from ...result import Status
from .. import common
from ...options import option
from ..base import Solver, SolverOptions


class _SciPyNLPSolver(Solver):
    """Common driver: NLP view, fixed-variable removal, callbacks, time limit, Result.

    The time limit and interrupts (olado.interrupts) are checked after every evaluation (the
    solve's TimedNLP) and in the iteration callback; SciPy's minimize runs in the limits' catch
    block, and a stopped solve returns the last iterate SciPy reported to the callback
    (``state["z"]``; the initial point before the first)."""

    def _setup(self, problem, X0, U0, limits):
        nlp = common.make_nlp(problem)
        timed = common.TimedNLP(nlp, limits)
        free = common.FreeVariableNLP(timed)
        y0 = np.asarray(nlp.pack(X0, U0), dtype=float)
        z0 = free.reduce(y0)
        lbz, ubz = free.bounds()
        z0 = np.clip(z0, lbz, ubz)
        return nlp, timed, free, z0

    @staticmethod
    def _scipy_bounds(free):
        lbz, ubz = free.bounds()
        if not (np.isfinite(lbz).any() or np.isfinite(ubz).any()):
            return None
        return optimize.Bounds(lbz, ubz)

    def _make_callback(self, nlp, free, history, limits, state, extra=lambda r: {}):
        """A SciPy ``callback(intermediate_result)`` that records history and the iterate
        (``state["z"]``, ``state["v"]``: trust-constr's multipliers), calls the user's callback
        (StopIteration stops SciPy) and checks the time limit and interrupts (raise)."""
        opts = self.options

        def callback(intermediate_result):
            it = len(history) + 1
            z = np.array(intermediate_result.x, dtype=float)
            state["z"] = z
            state["v"] = getattr(intermediate_result, "v", None)
            state["fun"] = float(intermediate_result.fun)
            row = {"iter": it, "objective": float(intermediate_result.fun)}
            row.update(extra(intermediate_result))
            row["time_s"] = limits.elapsed()
            history.append(row)
            if opts.verbose == 2:
                print("  ".join(f"{k} {v:.6e}" if isinstance(v, float) else f"{k} {v}"
                                for k, v in row.items()))
            if opts.callback is not None:
                X, U = nlp.unpack(free.full(z))
                if self._call_callback(dict(row, x=X, u=U, solver=self.name)):
                    state["stop"] = "callback"
                    raise StopIteration
            limits.check()

        return callback

    @staticmethod
    def _stopped(state, stop, limits):
        """(status, why) of a solve stopped by the callback, the time limit or an interrupt; None."""
        if stop.reason:
            return common.stop_outcome(stop.reason, limits, f"after {state.get('iterations', 0)} iterations")
        if state.get("stop") == "callback":
            return Status.USER_STOP, "the user callback returned True"
        return None

    @staticmethod
    def _stopped_iterate(state, z0):
        """The last iterate SciPy reported (the initial point before the first)."""
        return np.asarray(state.get("z", z0), dtype=float)

    @staticmethod
    def _known_objective(stop, state):
        """J at the returned point when a time limit or an interrupt stopped SciPy at a
        reported iterate (None: build_result evaluates it) -- such a solve evaluates no more
        than it must."""
        return state.get("fun") if stop.reason and "z" in state else None


# ============================================================================ SLSQP
@dataclasses.dataclass
class SLSQPOptions(SolverOptions):
    """Options of :class:`SLSQPSolver`.

    SLSQP has no KKT tolerance: it stops when the objective changes by less than ``ftol``
    (absolute). olado passes ``ftol = max(tol**2, 1e-12)`` unless ``ftol`` is set: near a
    nondegenerate minimum an objective accurate to tol**2 means a point accurate to about tol,
    but much below 1e-12 rounding errors can keep SLSQP wandering until max_iter (zambezi12 at
    1e-14). Set ftol (down to ~1e-15) for tighter solutions of well-scaled small problems."""

    max_iter: int = option(500, "maximum number of SLSQP iterations (scipy maxiter)", min=0)
    ftol: float = option(0.0, "SLSQP's own stopping accuracy on the objective change; "
                         "0 means max(tol**2, 1e-12)", min=0.0)
    active_tol: float = option(1e-8, "relative distance below which a bound counts as active "
                               "when bound multipliers are recovered", min=0.0)


class SLSQPSolver(_SciPyNLPSolver):
    """SciPy SLSQP (dense SQP with BFGS) on the NLP view; for small problems."""

    name = "slsqp"
    Options = SLSQPOptions

    #: SLSQP exit mode -> olado status
    STATUS = {
        0: Status.SUCCESS,
        2: Status.INVALID_PROBLEM,   # more equality constraints than variables
        3: Status.NUMERICAL_ERROR,   # more than 3n iterations in the LSQ subproblem
        4: Status.INFEASIBLE,        # inequality constraints incompatible
        5: Status.NUMERICAL_ERROR,   # singular matrix E in LSQ subproblem
        6: Status.NUMERICAL_ERROR,   # singular matrix C in LSQ subproblem
        7: Status.NUMERICAL_ERROR,   # rank-deficient equality constraint subproblem
        8: Status.NUMERICAL_ERROR,   # positive directional derivative in line search
        9: Status.MAX_ITERATIONS,
    }

    def _solve(self, problem, X0, U0):
        opts = self.options
        limits = Limits(opts.max_time)
        nlp, timed, free, z0 = self._setup(problem, X0, U0, limits)
        cl, cu = free.cl, free.cu
        eq = cl == cu
        lo = ~eq & np.isfinite(cl)
        hi = ~eq & np.isfinite(cu)

        cache = {"c": (None, None), "J": (None, None)}

        def cons(z):
            key, val = cache["c"]
            if key is None or not np.array_equal(key, z):
                val = free.constraints(z)
                cache["c"] = (np.array(z), val)
            return val

        def jac(z):
            key, val = cache["J"]
            if key is None or not np.array_equal(key, z):
                val = free.jacobian(z).toarray()
                cache["J"] = (np.array(z), val)
            return val

        constraints = []
        if eq.any():
            constraints.append({"type": "eq", "fun": lambda z: cons(z)[eq] - cl[eq],
                                "jac": lambda z: jac(z)[eq]})
        if lo.any() or hi.any():
            constraints.append({"type": "ineq",
                                "fun": lambda z: np.concatenate([cons(z)[lo] - cl[lo], cu[hi] - cons(z)[hi]]),
                                "jac": lambda z: np.vstack([jac(z)[lo], -jac(z)[hi]])})

        history, state = [], {}
        callback = self._make_callback(nlp, free, history, limits, state)
        t0 = time.perf_counter()
        res = None
        with warnings.catch_warnings(), limits.catch() as stop:
            warnings.simplefilter("ignore", optimize.OptimizeWarning)
            res = optimize.minimize(
                free.objective, z0, jac=free.gradient, method="SLSQP",
                bounds=self._scipy_bounds(free), constraints=constraints, callback=callback,
                options={"maxiter": max(int(opts.max_iter), 1),
                         "ftol": float(opts.ftol or max(opts.tol ** 2, 1e-12)), "disp": opts.verbose >= 3,
                         "iprint": 2 if opts.verbose >= 3 else 0})
        solve_time = time.perf_counter() - t0
        state["iterations"] = len(history)
        if res is None:     # stopped inside SciPy: its last reported iterate, no multipliers
            res = optimize.OptimizeResult(x=self._stopped_iterate(state, z0), status=-1, nit=len(history),
                                          message="stopped", multipliers=np.zeros(0))

        # multipliers: SLSQP's L = f - mu . (constraints as given), equalities first
        mu = np.asarray(getattr(res, "multipliers", np.zeros(0)), dtype=float)
        n_eq, n_lo = int(eq.sum()), int(lo.sum())
        lam = np.zeros(nlp.n_cons)
        if mu.size >= n_eq + n_lo + int(hi.sum()):
            lam[eq] = -mu[:n_eq]
            lam[lo] = -mu[n_eq:n_eq + n_lo]
            lam[hi] += mu[n_eq + n_lo:n_eq + n_lo + int(hi.sum())]
        y = free.full(np.asarray(res.x, dtype=float))
        zl, zu = self._bound_multipliers(nlp, free, y, lam)

        stopped = self._stopped(state, stop, limits)
        code = int(res.status)
        if stopped is not None:
            status, why = stopped
            message = f"SLSQP stopped: {why}"
        elif opts.max_iter == 0:
            status, message = Status.MAX_ITERATIONS, "max_iter = 0: no iteration was made"
        else:
            status = self.STATUS.get(code, Status.FAILED)
            message = f"SLSQP exit mode {code}: {res.message}"
        return common.build_result(
            nlp=nlp, y=y, lam=lam, zl=zl, zu=zu, status=status, message=message,
            iterations=int(res.nit), history=history, timed=timed, solve_time_s=solve_time,
            objective=self._known_objective(stop, state),
            info={"scipy_status": code, "scipy_message": str(res.message),
                  "bound_multipliers": "recovered from stationarity on the active bounds"},
        )

    def _bound_multipliers(self, nlp, free, y, lam):
        """SLSQP returns no bound multipliers: recover them on the active bounds of the free
        variables from the residual grad J + Jc^T lam (fixed variables: build_result)."""
        grad = np.asarray(nlp.gradient(y), dtype=float)
        jac = common.jacobian_matrix(nlp, y)
        r = common.stationarity_residual(grad, jac, lam, np.zeros_like(y), np.zeros_like(y))
        return common.bound_multipliers_from_residual(r, y, free.lb, free.ub,
                                                      tol=self.options.active_tol, only=free.free)


# ============================================================================ trust-constr
@dataclasses.dataclass
class TrustConstrOptions(SolverOptions):
    """Options of :class:`TrustConstrSolver`. ``tol`` is trust-constr's ``gtol`` (norm of the
    Lagrangian gradient and constraint violation) and ``barrier_tol``."""

    max_iter: int = option(3000, "maximum number of trust-constr iterations (scipy maxiter)", min=0)
    hessian: str = option("exact", "Lagrangian Hessian: exact sparse one of the NLP view, or SciPy's "
                          "quasi-Newton bfgs / sr1 approximations", choices=("exact", "bfgs", "sr1"))
    xtol: float = option(1e-12, "stop when the trust radius falls below xtol (scipy xtol)",
                         min=0.0, min_exclusive=True)
    initial_tr_radius: float = option(1.0, "initial trust radius", min=0.0, min_exclusive=True)
    initial_barrier_parameter: float = option(0.1, "initial barrier parameter (interior-point branch)",
                                              min=0.0, min_exclusive=True)
    initial_constr_penalty: float = option(1.0, "initial merit-function penalty", min=0.0, min_exclusive=True)
    barrier_restarts: int = option(5, "restarts of the barrier branch from its solution with a "
                                   "smaller barrier parameter when SciPy stops while it is still "
                                   "above tol (SciPy checks gtol before the barrier parameter)", min=0)
    factorization_method: str = option("auto", "factorization of the constraint Jacobian "
                                       "(sparse: NormalEquation or AugmentedSystem)",
                                       choices=("auto", "NormalEquation", "AugmentedSystem"))


class TrustConstrSolver(_SciPyNLPSolver):
    """SciPy trust-constr (trust-region SQP / interior point) with the sparse NLP view."""

    name = "trust-constr"
    Options = TrustConstrOptions

    #: trust-constr status -> olado status (2 and 3 are refined in _solve)
    STATUS = {0: Status.MAX_ITERATIONS, 1: Status.SUCCESS, 2: Status.ACCEPTABLE, 3: Status.USER_STOP,
              -1: Status.FAILED}

    def _solve(self, problem, X0, U0):
        opts = self.options
        limits = Limits(opts.max_time)
        nlp, timed, free, z0 = self._setup(problem, X0, U0, limits)
        n_cons = nlp.n_cons
        zeros_m = np.zeros(n_cons)

        if opts.hessian == "exact":
            obj_hess = lambda z: free.hessian(z, zeros_m, 1.0)  # noqa: E731
            con_hess = lambda z, v: free.hessian(z, np.asarray(v, dtype=float), 0.0)  # noqa: E731
        else:
            cls = optimize.BFGS if opts.hessian == "bfgs" else optimize.SR1
            obj_hess, con_hess = cls(), cls()

        constraints = []
        if n_cons:
            constraints.append(optimize.NonlinearConstraint(
                free.constraints, free.cl, free.cu, jac=lambda z: free.jacobian(z).tocsr(),
                hess=con_hess))

        def extra(r):
            return {k: float(getattr(r, k)) for k in ("optimality", "constr_violation", "tr_radius",
                                                       "barrier_parameter") if hasattr(r, k)} | \
                   {"cg_niter": int(getattr(r, "cg_niter", 0))}

        history, state = [], {}
        callback = self._make_callback(nlp, free, history, limits, state, extra)
        scipy_opts = {"maxiter": max(int(opts.max_iter), 1), "gtol": float(opts.tol),
                      "xtol": float(opts.xtol), "barrier_tol": float(opts.tol),
                      "initial_tr_radius": float(opts.initial_tr_radius),
                      "initial_barrier_parameter": float(opts.initial_barrier_parameter),
                      "initial_constr_penalty": float(opts.initial_constr_penalty),
                      "sparse_jacobian": True,
                      "verbose": 3 if opts.verbose >= 3 else 0}
        if opts.factorization_method != "auto":
            scipy_opts["factorization_method"] = opts.factorization_method
        t0 = time.perf_counter()
        restarts, nit, cg_niter = 0, 0, 0
        while True:
            res = None
            with warnings.catch_warnings(), limits.catch() as stop:
                warnings.simplefilter("ignore", UserWarning)  # "delta_grad == 0.0" etc.
                res = optimize.minimize(free.objective, z0, jac=free.gradient, hess=obj_hess,
                                        method="trust-constr", bounds=self._scipy_bounds(free),
                                        constraints=constraints, callback=callback, options=scipy_opts)
            if res is None:     # stopped inside SciPy: its last reported iterate and multipliers
                v = state.get("v")
                res = optimize.OptimizeResult(x=self._stopped_iterate(state, z0), status=-1, message="stopped",
                                              nit=len(history) - nit, cg_niter=0, v=v if v is not None else [],
                                              constr_violation=float("nan"), optimality=float("nan"))
                nit += int(res.nit)
                break
            nit += int(res.nit)
            cg_niter += int(res.cg_niter)
            # trust-constr's barrier branch may stop ("gtol satisfied") while the barrier
            # parameter mu is still large: the point is then only about mu/z accurate near
            # active bounds. Restart from it with a smaller mu until mu <= tol.
            mu = float(getattr(res, "barrier_parameter", 0.0) or 0.0)
            if (res.status != 1 or getattr(res, "method", "") != "tr_interior_point" or mu <= opts.tol
                    or restarts >= opts.barrier_restarts or state.get("stop")
                    or nit >= opts.max_iter):
                break
            restarts += 1
            z0 = np.asarray(res.x, dtype=float)
            scipy_opts["initial_barrier_parameter"] = max(mu * 1e-2, opts.tol)
            scipy_opts["initial_barrier_tolerance"] = max(mu * 1e-2, opts.tol)
            scipy_opts["initial_tr_radius"] = max(float(res.tr_radius), 1e-3)
            scipy_opts["maxiter"] = max(int(opts.max_iter) - nit, 1)
        solve_time = time.perf_counter() - t0

        y = free.full(np.asarray(res.x, dtype=float))
        v = list(getattr(res, "v", []))
        lam = np.asarray(v[0], dtype=float) if (n_cons and v) else np.zeros(n_cons)
        zl, zu = np.zeros(nlp.n_vars), np.zeros(nlp.n_vars)
        if self._scipy_bounds(free) is not None and len(v) > (1 if n_cons else 0):
            vb = np.asarray(v[-1], dtype=float)     # bound multipliers: z_U - z_L
            zl[free.free] = np.maximum(-vb, 0.0)
            zu[free.free] = np.maximum(vb, 0.0)

        code = int(res.status)
        state["iterations"] = nit
        stopped = self._stopped(state, stop, limits)
        if stopped is not None:
            status, why = stopped
            message = f"trust-constr stopped: {why}"
        elif opts.max_iter == 0:
            status, message = Status.MAX_ITERATIONS, "max_iter = 0: one iteration at most was made"
        else:
            status = self.STATUS.get(code, Status.FAILED)
            message = f"trust-constr status {code}: {res.message}"
            if code == 2 and float(res.constr_violation) > opts.constr_viol_tol:
                status = Status.NUMERICAL_ERROR
                message += f" (constraint violation {float(res.constr_violation):.2e} not met)"
        result = common.build_result(
            nlp=nlp, y=y, lam=lam, zl=zl, zu=zu, status=status, message=message,
            iterations=nit, history=history, timed=timed, solve_time_s=solve_time,
            objective=self._known_objective(stop, state),
            info={"scipy_status": code, "scipy_message": str(res.message),
                  "scipy_method": getattr(res, "method", ""), "cg_iterations": cg_niter,
                  "scipy_optimality": float(res.optimality), "barrier_restarts": restarts,
                  "barrier_parameter": float(getattr(res, "barrier_parameter", 0.0) or 0.0)},
        )
        result.qp_iterations = cg_niter  # projected-CG iterations of the subproblems
        return result
