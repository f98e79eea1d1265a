"""IPOPT on the NLP view of a DOCP (paper 001 sec. 4.3.2, eqs. (26)-(38)).

IPOPT (Wächter and Biegler, 2006) is the primal-dual interior-point method with a filter line
search described in sec. 4.3.2: it solves the barrier problems (27) by Newton steps on the
primal-dual system (28)-(30) through the symmetric system (34). olado hands it the large sparse
NLP (6) of :class:`~olado.problems.nlp.StructuredNLP` through cyipopt: sparse constraint Jacobian
and lower-triangle Lagrangian Hessian with fixed patterns, nothing dense.

cyipopt is one of olado's dependencies (the ``cyipopt-wheels`` package: IPOPT 3.14 with MUMPS
inside the wheel); where it is missing or broken, ``pip install "cyipopt-wheels>=1.7.0.dev0"``
or, on Debian/Ubuntu, ``apt install coinor-libipopt-dev pkg-config`` followed by
``pip install cyipopt`` brings it back.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from ...errors import ConfigError, NonFiniteEvaluationError, SolverNotAvailableError
from ...result import Status
from .. import common
from ...options import option
from ..base import Solver, SolverOptions

INSTALL_HINT = ('IPOPT support needs cyipopt, a dependency of olado that is missing here: '
                'pip install "cyipopt-wheels>=1.7.0.dev0" (IPOPT 3.14 and MUMPS inside the wheel), '
                "or on Debian/Ubuntu: apt install coinor-libipopt-dev pkg-config && pip install cyipopt")


def import_cyipopt():
    """Import cyipopt or raise SolverNotAvailableError with the install instructions."""
    try:
        import cyipopt  # noqa: PLC0415 - optional dependency, imported lazily
    except ImportError as exc:
        raise SolverNotAvailableError(f"{INSTALL_HINT} ({exc})") from exc
    return cyipopt


#: IPOPT's ApplicationReturnStatus -> (olado status, IPOPT's name)
IPOPT_STATUS = {
    0: (Status.SUCCESS, "Solve_Succeeded"),
    1: (Status.ACCEPTABLE, "Solved_To_Acceptable_Level"),
    2: (Status.INFEASIBLE, "Infeasible_Problem_Detected"),
    3: (Status.NUMERICAL_ERROR, "Search_Direction_Becomes_Too_Small"),
    4: (Status.UNBOUNDED, "Diverging_Iterates"),
    5: (Status.USER_STOP, "User_Requested_Stop"),
    6: (Status.ACCEPTABLE, "Feasible_Point_Found"),
    -1: (Status.MAX_ITERATIONS, "Maximum_Iterations_Exceeded"),
    -2: (Status.NUMERICAL_ERROR, "Restoration_Failed"),
    -3: (Status.NUMERICAL_ERROR, "Error_In_Step_Computation"),
    -4: (Status.MAX_TIME, "Maximum_CpuTime_Exceeded"),
    -5: (Status.MAX_TIME, "Maximum_WallTime_Exceeded"),
    -10: (Status.INVALID_PROBLEM, "Not_Enough_Degrees_Of_Freedom"),
    -11: (Status.INVALID_PROBLEM, "Invalid_Problem_Definition"),
    -12: (Status.FAILED, "Invalid_Option"),
    -13: (Status.INVALID_PROBLEM, "Invalid_Number_Detected"),
    -100: (Status.FAILED, "Unrecoverable_Exception"),
    -101: (Status.FAILED, "NonIpopt_Exception_Thrown"),
    -102: (Status.FAILED, "Insufficient_Memory"),
    -199: (Status.FAILED, "Internal_Error"),
}


def map_ipopt_status(code: int, ipopt_message: str = ""):
    """(Status, message) for an IPOPT return code; the message quotes IPOPT's own text."""
    status, name = IPOPT_STATUS.get(int(code), (Status.FAILED, "Unknown_Status"))
    text = ipopt_message.decode() if isinstance(ipopt_message, bytes) else str(ipopt_message or "")
    message = f"IPOPT status {int(code)} ({name})" + (f": {text}" if text else "")
    return status, message


@dataclasses.dataclass
class IpoptOptions(SolverOptions):
    """Options of :class:`IpoptSolver`. Common options map to IPOPT's ``max_iter``, ``tol``,
    ``constr_viol_tol`` and ``max_wall_time``; ``ipopt_options`` passes any IPOPT option
    verbatim (it wins over everything else)."""

    hessian: str = option("exact", "Lagrangian Hessian: exact (second derivatives of the NLP view) "
                          "or limited-memory (IPOPT's L-BFGS)", choices=("exact", "limited-memory"))
    mu_strategy: str = option("monotone", "barrier parameter update (IPOPT mu_strategy)",
                              choices=("monotone", "adaptive"))
    linear_solver: str = option("mumps", "sparse symmetric indefinite solver for system (34) "
                                "(IPOPT linear_solver; ma27/ma57/... need HSL)",
                                choices=("mumps", "ma27", "ma57", "ma77", "ma86", "ma97", "pardiso",
                                         "pardisomkl", "spral", "wsmp", "custom"))
    print_level: int = option(0, "IPOPT's own output level (0 silent .. 12); with verbose >= 3 and "
                              "print_level 0, level 5 is used", min=0, max=12)
    acceptable_tol: float = option(1e-6, "IPOPT acceptable_tol: the looser tolerance of the "
                                   "'acceptable' stop (status acceptable)",
                                   min=0.0, min_exclusive=True)
    acceptable_iter: int = option(15, "IPOPT acceptable_iter: stop after this many consecutive "
                                  "'acceptable' iterates (0 disables the acceptable stop)", min=0)
    bound_push: float = option(1e-2, "IPOPT bound_push: minimal relative distance of the "
                               "initial point from its bounds", min=0.0, min_exclusive=True)
    bound_frac: float = option(1e-2, "IPOPT bound_frac: minimal distance of the initial point from "
                               "its bounds, as a fraction of the distance between the two bounds",
                               min=0.0, max=0.5, min_exclusive=True)
    mu_init: float = option(0.1, "IPOPT mu_init: initial barrier parameter", min=0.0, min_exclusive=True)
    nlp_scaling_method: str = option("gradient-based", "how IPOPT scales the objective and the "
                                     "constraints (IPOPT nlp_scaling_method)",
                                     choices=("gradient-based", "none", "equilibration-based"))
    ipopt_options: dict = option({}, "raw IPOPT options passed verbatim ([ipopt.raw] in ini files)",
                                 ini=True)


class IpoptSolver(Solver):
    """IPOPT (interior point, filter line search; paper 001 sec. 4.3.2) on the sparse NLP view."""

    name = "ipopt"
    Options = IpoptOptions

    @classmethod
    def available(cls) -> bool:
        """True when cyipopt imports (a broken installation counts as a missing one)."""
        try:
            import_cyipopt()
        except Exception:
            return False
        return True

    # ------------------------------------------------------------------ IPOPT options
    def ipopt_option_values(self) -> dict:
        """The options handed to IPOPT, in order (later keys win)."""
        o = self.options
        opts = {
            "tol": float(o.tol),
            "constr_viol_tol": float(o.constr_viol_tol),
            "max_iter": int(o.max_iter),
            "hessian_approximation": o.hessian,
            "mu_strategy": o.mu_strategy,
            "linear_solver": o.linear_solver,
            "print_level": int(o.print_level if (o.print_level or o.verbose < 3) else 5),
            "acceptable_tol": float(o.acceptable_tol),
            "acceptable_iter": int(o.acceptable_iter),
            "bound_push": float(o.bound_push),
            "bound_frac": float(o.bound_frac),
            "mu_init": float(o.mu_init),
            "nlp_scaling_method": o.nlp_scaling_method,
            "sb": "yes",  # no IPOPT banner
        }
        if math.isfinite(o.max_time):
            opts["max_wall_time"] = float(o.max_time)
        opts.update(o.ipopt_options or {})
        return opts

    @staticmethod
    def _add_option(nlp_solver, key, value):
        """Set one IPOPT option; an int given for a numeric option is retried as a float."""
        if isinstance(value, bool):
            value = "yes" if value else "no"
        elif isinstance(value, np.integer):
            value = int(value)
        elif isinstance(value, np.floating):
            value = float(value)
        try:
            nlp_solver.add_option(key, value)
            return
        except (TypeError, OverflowError):  # OverflowError: an int beyond IPOPT's C int
            if isinstance(value, int):
                try:
                    nlp_solver.add_option(key, float(value))
                    return
                except (TypeError, OverflowError):
                    pass
        raise ConfigError(f"IPOPT rejected the option value {value!r} (unknown option, wrong type "
                          "or out of range; see IPOPT's options reference)", section="ipopt.raw", key=key)

    # ------------------------------------------------------------------ solve
    def _solve(self, problem, X0, U0):
        cyipopt = import_cyipopt()
        nlp = common.make_nlp(problem)
        timed = common.TimedNLP(nlp)
        lb, ub = (np.asarray(a, dtype=float) for a in nlp.variable_bounds())
        cl, cu = (np.asarray(a, dtype=float) for a in nlp.constraint_bounds())
        y0 = np.asarray(nlp.pack(X0, U0), dtype=float)
        adapter = _IpoptAdapter(self, nlp, timed)
        nlp_solver = cyipopt.Problem(n=nlp.n_vars, m=nlp.n_cons, problem_obj=adapter,
                                     lb=lb, ub=ub, cl=cl, cu=cu)
        adapter.ipopt = nlp_solver
        for key, value in self.ipopt_option_values().items():
            self._add_option(nlp_solver, key, value)

        t0 = time.perf_counter()
        try:
            y, info = nlp_solver.solve(y0)
        finally:
            # the adapter and the cyipopt problem refer to each other (its callbacks are the
            # adapter's bound methods): break the cycle, else the NLP's arrays outlive the solve
            # until Python's cyclic garbage collector runs
            adapter.ipopt = None
        solve_time = time.perf_counter() - t0

        code = int(info["status"])
        status, message = map_ipopt_status(code, info.get("status_msg", ""))
        if adapter.stop_reason == "max_time" and status is Status.USER_STOP:
            status, message = Status.MAX_TIME, message + " (olado: time limit reached)"
        elif adapter.stop_reason == "callback" and status is Status.USER_STOP:
            message += " (olado: the user callback returned True)"
        if adapter.evaluation_error is not None and status in (Status.INVALID_PROBLEM, Status.NUMERICAL_ERROR,
                                                               Status.FAILED):
            message += f"; last evaluation error: {adapter.evaluation_error}"
        last = adapter.history[-1] if adapter.history else {}
        extra = {
            "ipopt_status": code,
            "ipopt_status_msg": (info.get("status_msg", b"").decode() if isinstance(info.get("status_msg"), bytes)
                                 else str(info.get("status_msg", ""))),
            "ipopt_inf_du_scaled": last.get("inf_du"),
            "ipopt_inf_pr": last.get("inf_pr"),
            "ipopt_options": {k: v for k, v in self.ipopt_option_values().items()},
            "restoration_iterations": sum(1 for h in adapter.history if h.get("restoration")),
        }
        return common.build_result(
            nlp=nlp, y=y, lam=info["mult_g"], zl=info["mult_x_L"], zu=info["mult_x_U"],
            status=status, message=message,
            iterations=adapter.iterations, history=adapter.history, timed=timed,
            solve_time_s=solve_time, objective=info.get("obj_val"), constraints=info.get("g"),
            info=extra,
        )


class _IpoptAdapter:
    """The object cyipopt calls: evaluations from the NLP view (timed, counted), iteration
    history, user callback and the time limit."""

    def __init__(self, solver: IpoptSolver, nlp, timed):
        self.solver, self.nlp, self.timed = solver, nlp, timed
        self.ipopt = None
        self.history = []
        self.iterations = 0
        self.stop_reason = None
        self.evaluation_error = None
        self.deadline = common.Deadline(solver.options.max_time)
        self._cyipopt_error = import_cyipopt().CyIpoptEvaluationError

    def _guard(self, fn, *args):
        """Turn a non-finite evaluation into an IPOPT evaluation error (IPOPT then cuts the
        step, or stops with Invalid_Number_Detected); definition bugs propagate."""
        try:
            return fn(*args)
        except NonFiniteEvaluationError as exc:
            self.evaluation_error = str(exc)
            raise self._cyipopt_error(str(exc)) from exc

    def objective(self, y):
        return self._guard(self.timed.objective, y)

    def gradient(self, y):
        return self._guard(self.timed.gradient, y)

    def constraints(self, y):
        return self._guard(self.timed.constraints, y)

    def jacobian(self, y):
        return self._guard(self.timed.jacobian, y)

    def jacobianstructure(self):
        return self.timed.jacobian_structure()

    def hessian(self, y, lagrange, obj_factor):
        return self._guard(self.timed.hessian, y, lagrange, obj_factor)

    def hessianstructure(self):
        return self.timed.hessian_structure()

    def intermediate(self, alg_mod, iter_count, obj_value, inf_pr, inf_du, mu, d_norm,
                     regularization_size, alpha_du, alpha_pr, ls_trials):
        """One IPOPT iteration: record it, log it, run the user callback, check the time."""
        self.iterations = int(iter_count)
        row = {
            "iter": int(iter_count), "objective": float(obj_value), "inf_pr": float(inf_pr),
            "inf_du": float(inf_du), "mu": float(mu), "d_norm": float(d_norm),
            "regularization": float(regularization_size), "alpha_pr": float(alpha_pr),
            "alpha_du": float(alpha_du), "ls_trials": int(ls_trials),
            "restoration": bool(alg_mod == 1), "time_s": self.deadline.elapsed(),
        }
        self.history.append(row)
        opts = self.solver.options
        if opts.verbose == 2:
            if iter_count == 0 or iter_count % 20 == 0:
                print(f"{'iter':>5} {'objective':>16} {'inf_pr':>9} {'inf_du':>9} {'lg(mu)':>6} "
                      f"{'alpha_du':>9} {'alpha_pr':>9} {'ls':>3}")
            lgmu = math.log10(mu) if mu > 0 else float("-inf")
            print(f"{iter_count:5d}{'r' if alg_mod == 1 else ' '}{obj_value:16.8e} {inf_pr:9.2e} "
                  f"{inf_du:9.2e} {lgmu:6.1f} {alpha_du:9.2e} {alpha_pr:9.2e} {ls_trials:3d}")
        if opts.callback is not None:
            info = dict(row, solver=self.solver.name)
            try:
                it = self.ipopt.get_current_iterate(scaled=False)
                if it is not None:
                    info["x"], info["u"] = self.nlp.unpack(np.asarray(it["x"]))
            except Exception:  # pragma: no cover - older IPOPT without GetIpoptCurrentIterate
                pass
            if self.solver._call_callback(info):
                self.stop_reason = "callback"
                return False
        if self.deadline.expired():
            self.stop_reason = "max_time"
            return False
        return True
