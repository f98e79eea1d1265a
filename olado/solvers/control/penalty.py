"""The quadratic penalty method and the augmented Lagrangian method for constrained DOCPs (paper
001 sec. 2.2: "the traditional penalty function algorithm for constrained dynamic optimization
problems (Findeisen et al., 1980; Wierzbicki, 1984)").

The constraints of eqs. (3)-(5) -- stage constraints g^k(x^k, u^k) >= 0 or = 0, final constraints
g^N(x^N), state bounds x_L <= x^k <= x_U (k = 1..N; x^0 is fixed) and, when the inner method
cannot keep them, control bounds -- are moved into the cost. Outer iteration j minimizes the
unconstrained DOCP (states eliminated by the state equation (2), so the dynamics never need a
penalty)

    J(u) + sum_c phi_rho(c(x, u); lam_c)                                                   (P)

with the Powell-Hestenes-Rockafellar terms (Hestenes 1969, Powell 1969; Rockafellar 1973 for
inequalities)

    equality  c = 0:    phi = lam c + rho/2 c^2,                       phi' = lam + rho c
    inequality c >= 0:  phi = (max(0, lam - rho c)^2 - lam^2) / (2 rho), phi' = -max(0, lam - rho c)

With lam = 0 (the pure quadratic penalty, option ``augmented_lagrangian = false``) these are
rho/2 c^2 and rho/2 max(0, -c)^2: the squared violations. After each subproblem the violation
v = max |violation| is measured; the method stops when v <= constr_viol_tol. Otherwise

* quadratic penalty: rho <- rho_factor * rho (the solution of (P) approaches the constrained one
  as O(1/rho), so rho must grow to about |multiplier| / constr_viol_tol);
* augmented Lagrangian: lam <- phi'(c) (first-order multiplier update, lam >= 0 kept for the
  inequalities through the max), and rho grows only when v did not fall below
  ``al_decrease`` times its previous value (Bertsekas 1982, sec. 2.2) -- rho stays moderate.

The subproblems are DOCPs (:class:`PenalizedProblem`) whose stage and final costs carry the
penalty terms with analytic first and second derivatives built from the original problem's
derivatives: gradient phi'(c) grad c, Hessian phi''(c) grad c grad c^T (Gauss-Newton part) plus
phi'(c) times the constraint's second derivatives, obtained from the problem's own
``eval_stage_hessians`` with the stage-constraint weights phi'. They are solved by any
unconstrained method of the library (option ``inner``): ``lbfgsb`` (built in: SciPy's L-BFGS-B on
the reduced problem J(u) with the adjoint gradient of :mod:`olado.solvers.control.control_space`; it
keeps the control bounds as bounds), ``pdmin`` (keeps the control bounds too), ``gradient``,
``cg``, ``variable-metric``, ``newton``, ``ddp``, ``stagewise-newton`` (control bounds are then
penalized as well).

Multipliers in the result follow the convention of the NLP solvers (olado.solvers.common:
grad J + Jc^T lam - z_L + z_U = 0): stage/final constraint multipliers phi'(c) (<= 0 for active
inequalities), bound multipliers z_L, z_U >= 0, and the dynamics multipliers are the costates
p^{k+1} of the penalized problem.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections import Counter

import numpy as np

from ...errors import NonFiniteEvaluationError, ProblemDefinitionError, SolverNotAvailableError
from ...interrupts import Limits
from ...problems.docp import DOCP, as_real_array
from ...result import Result, Status
from ...options import option
from ..base import Solver, SolverOptions
from ..common import stop_outcome
from .control_space import ReducedProblem
from ..registry import SOLVERS

#: inner methods: SciPy's L-BFGS-B, or an unconstrained solver of olado.solvers.registry.SOLVERS
INNER_METHODS = ("lbfgsb", "gradient", "cg", "variable-metric", "newton", "ddp", "stagewise-newton", "pdmin")
#: inner methods that keep simple control bounds as bounds (the others get them penalized)
BOUND_INNER_METHODS = ("lbfgsb", "pdmin")


# ============================================================================ penalty terms
def _phi(c, lam, rho, eq):
    """Values, first and second derivatives of the PHR terms (module docstring), elementwise;
    ``eq`` a boolean array broadcastable to c (True: equality)."""
    t = lam - rho * c
    tp = np.maximum(t, 0.0)
    val = np.where(eq, lam * c + 0.5 * rho * c * c, (tp * tp - lam * lam) / (2.0 * rho))
    d1 = np.where(eq, lam + rho * c, -tp)
    d2 = np.where(eq | (t > 0.0), rho, 0.0)
    return val, d1, d2


def _violation(c, eq):
    """Elementwise violation: |c| for equalities, max(0, -c) for inequalities."""
    return np.where(eq, np.abs(c), np.maximum(-c, 0.0))


class PenalizedProblem(DOCP):
    """The unconstrained DOCP (P) of an outer iteration: costs of ``base`` plus the PHR terms of
    its constraints, with the base's dynamics; see the module docstring.

    Penalized: stage constraints (N, r), final constraints (rN,), finite state bounds at
    k = 1..N, and the finite control bounds unless ``keep_control_bounds`` (then they are the
    bounds of this problem). ``set_penalty(rho, multipliers)`` changes rho and the multiplier
    estimates. Derivatives come from the base's ``eval_*`` methods (analytic where it provides
    them); the user-function forms (``dynamics``, ``stage_cost``, ``final_cost``) exist for
    per-stage callers and finite-difference checks.
    """

    def __init__(self, base, rho=1.0, keep_control_bounds=True):
        self.base = base
        self.vectorized = base.vectorized
        self.keep_control_bounds = bool(keep_control_bounds)
        self.name = f"{getattr(base, 'name', 'docp')}-penalized"
        u_bounds = (base.u_lower, base.u_upper) if keep_control_bounds else None
        super().__init__(base.n, base.m, base.N, base.x0, u_bounds=u_bounds,
                         derivatives=base.derivatives, fd_method=base.fd_method, fd_step=base.fd_step)
        N, n, m = base.N, base.n, base.m
        self.eq_stage = base.stage_equality_mask.copy()
        self.eq_final = base.final_equality_mask.copy()
        # finite bounds: masks and the bounds with inf replaced (masked out anyway)
        self.xl_mask = np.isfinite(base.x_lower)
        self.xu_mask = np.isfinite(base.x_upper)
        self.xl_mask[0] = self.xu_mask[0] = False          # x^0 is fixed
        self.xl = np.where(self.xl_mask, base.x_lower, 0.0)
        self.xu = np.where(self.xu_mask, base.x_upper, 0.0)
        pen_u = not keep_control_bounds
        self.ul_mask = np.isfinite(base.u_lower) & pen_u
        self.uu_mask = np.isfinite(base.u_upper) & pen_u
        self.ul = np.where(self.ul_mask, base.u_lower, 0.0)
        self.uu = np.where(self.uu_mask, base.u_upper, 0.0)
        self.multipliers = {
            "stage_constraints": np.zeros((N, base.r)), "final_constraints": np.zeros(base.rN),
            "bound_lower_x": np.zeros((N + 1, n)), "bound_upper_x": np.zeros((N + 1, n)),
            "bound_lower_u": np.zeros((N, m)), "bound_upper_u": np.zeros((N, m)),
        }
        self.rho = float(rho)

    def set_penalty(self, rho, multipliers=None):
        """New rho and (augmented Lagrangian) multiplier estimates (dict as ``multipliers``)."""
        self.rho = float(rho)
        if multipliers is not None:
            for key, val in multipliers.items():
                self.multipliers[key] = np.array(val, dtype=float)

    @property
    def penalizes_anything(self):
        return bool(self.base.r or self.base.rN or self.xl_mask.any() or self.xu_mask.any()
                    or self.ul_mask.any() or self.uu_mask.any())

    # ------------------------------------------------------------------ penalty pieces
    def _bound_terms(self, Z, lo, hi, lo_mask, hi_mask, lam_lo, lam_hi):
        """PHR terms of lo <= Z <= hi (masked entries only): values summed over the last axis,
        first derivative w.r.t. Z and its second derivative (diagonal)."""
        rho = self.rho
        vl, dl, hl = _phi(np.where(lo_mask, Z - lo, 1.0), np.where(lo_mask, lam_lo, 0.0), rho, False)
        vu, du, hu = _phi(np.where(hi_mask, hi - Z, 1.0), np.where(hi_mask, lam_hi, 0.0), rho, False)
        vl, dl, hl = (np.where(lo_mask, a, 0.0) for a in (vl, dl, hl))
        vu, du, hu = (np.where(hi_mask, a, 0.0) for a in (vu, du, hu))
        return (vl + vu).sum(axis=-1), dl - du, hl + hu

    def _stage_pieces(self, k, X, U, G):
        """Penalty value per stage, phi'(g) (.., r), phi''(g), and the state/control bound
        gradient and curvature terms, for stages k (int or array) with G = g^k(x, u)."""
        mult = self.multipliers
        val, d1, d2 = _phi(G, mult["stage_constraints"][k], self.rho, self.eq_stage)
        total = val.sum(axis=-1)
        bx = self._bound_terms(X, self.xl[k], self.xu[k], self.xl_mask[k], self.xu_mask[k],
                               mult["bound_lower_x"][k], mult["bound_upper_x"][k])
        bu = self._bound_terms(U, self.ul[k], self.uu[k], self.ul_mask[k], self.uu_mask[k],
                               mult["bound_lower_u"][k], mult["bound_upper_u"][k])
        return total + bx[0] + bu[0], d1, d2, bx, bu

    def _final_pieces(self, x, gN):
        mult = self.multipliers
        N = self.N
        val, d1, d2 = _phi(gN, mult["final_constraints"], self.rho, self.eq_final)
        bx = self._bound_terms(x, self.xl[N], self.xu[N], self.xl_mask[N], self.xu_mask[N],
                               mult["bound_lower_x"][N], mult["bound_upper_x"][N])
        return float(val.sum() + bx[0]), d1, d2, bx

    def _base_stage_constraints_raw(self, k, x, u):
        b = self.base
        if b.r == 0:
            return np.zeros(np.shape(x)[:-1] + (0,))
        return as_real_array(b.stage_constraints(k, x, u), "stage_constraints", "g")

    # ------------------------------------------------------------------ user functions
    def dynamics(self, k, x, u):
        return self.base.dynamics(k, x, u)

    def stage_cost(self, k, x, u):
        G = self._base_stage_constraints_raw(k, x, u)
        return as_real_array(self.base.stage_cost(k, x, u), "stage_cost", "cost") + self._stage_pieces(k, x, u, G)[0]

    def final_cost(self, x):
        b = self.base
        gN = as_real_array(b.final_constraints(x), "final_constraints", "gN") if b.rN else np.zeros(0)
        return float(as_real_array(b.final_cost(x), "final_cost", "cost")) + self._final_pieces(x, gN)[0]

    # ------------------------------------------------------------------ solver-facing evaluations
    def simulate(self, U):
        return self.base.simulate(U)

    def initial_guess(self):
        return self.base.initial_guess()

    def provides(self, name) -> bool:
        b = self.base
        need = {"dynamics_jacobian": ["dynamics_jacobian"],
                "stage_cost_gradient": ["stage_cost_gradient"] + (["stage_constraints_jacobian"] if b.r else []),
                "final_cost_gradient": ["final_cost_gradient"] + (["final_constraints_jacobian"] if b.rN else []),
                "stage_hessian": ["stage_hessian"], "final_hessian": ["final_hessian"],
                "stage_constraints_jacobian": [], "final_constraints_jacobian": []}[name]
        return self.derivatives == "auto" and all(b.provides(nm) for nm in need)

    def eval_dynamics(self, X, U):
        return self.base.eval_dynamics(X, U)

    def _constraints(self, X, U):
        return self.base.eval_stage_constraints(X, U)

    def eval_stage_costs(self, X, U):
        X, U = self._split_xu(X, U)
        G = self._constraints(X, U)
        return self.base.eval_stage_costs(X, U) + self._stage_pieces(self._K, X[:-1], U, G)[0]

    def eval_final_cost(self, xN):
        xN = np.asarray(xN, dtype=float)
        gN = self.base.eval_final_constraints(xN)
        return self.base.eval_final_cost(xN) + self._final_pieces(xN, gN)[0]

    def eval_dynamics_jacobians(self, X, U, source=None):
        if source == "fd":
            return super().eval_dynamics_jacobians(X, U, source="fd")
        return self.base.eval_dynamics_jacobians(X, U, source=source)

    def eval_stage_cost_gradients(self, X, U, source=None):
        if source == "fd":
            return super().eval_stage_cost_gradients(X, U, source="fd")
        X, U = self._split_xu(X, U)
        b = self.base
        lx, lu = b.eval_stage_cost_gradients(X, U, source=source)
        G = self._constraints(X, U)
        _, d1, _, bx, bu = self._stage_pieces(self._K, X[:-1], U, G)
        lx = lx + bx[1]
        lu = lu + bu[1]
        if b.r:
            Cx, Cu = b.eval_stage_constraint_jacobians(X, U, source=source)
            lx = lx + np.einsum("ki,kij->kj", d1, Cx)
            lu = lu + np.einsum("ki,kij->kj", d1, Cu)
        return lx, lu

    def eval_final_cost_gradient(self, xN, source=None):
        if source == "fd":
            return super().eval_final_cost_gradient(xN, source="fd")
        b = self.base
        xN = np.asarray(xN, dtype=float)
        g = b.eval_final_cost_gradient(xN, source=source)
        gN = b.eval_final_constraints(xN)
        _, d1, _, bx = self._final_pieces(xN, gN)
        g = g + bx[1]
        if b.rN:
            g = g + d1 @ b.eval_final_constraint_jacobian(xN, source=source)
        return g

    def eval_stage_hessians(self, X, U, sigma, P, L=None, source=None):
        """sigma * (f_0 + penalty)'' + P.f'': the base's Hessian with constraint weights
        sigma*phi'(g), plus sigma * (phi''(g) grad g grad g^T + bound curvature)."""
        if source == "fd":
            return super().eval_stage_hessians(X, U, sigma, P, L, source="fd")
        X, U = self._split_xu(X, U)
        b = self.base
        sigma = float(sigma)
        G = self._constraints(X, U)
        _, d1, d2, bx, bu = self._stage_pieces(self._K, X[:-1], U, G)
        Hxx, Hxu, Huu = b.eval_stage_hessians(X, U, sigma, P, sigma * d1 if b.r else None, source=source)
        Hxx, Hxu, Huu = Hxx.copy(), Hxu.copy(), Huu.copy()
        if b.r:
            Cx, Cu = b.eval_stage_constraint_jacobians(X, U, source=source)
            W = sigma * d2
            Hxx += np.einsum("ki,kia,kib->kab", W, Cx, Cx)
            Hxu += np.einsum("ki,kia,kib->kab", W, Cx, Cu)
            Huu += np.einsum("ki,kia,kib->kab", W, Cu, Cu)
        n, m = self.n, self.m
        Hxx[:, np.arange(n), np.arange(n)] += sigma * bx[2]
        Huu[:, np.arange(m), np.arange(m)] += sigma * bu[2]
        return Hxx, Hxu, Huu

    def eval_final_hessian(self, xN, sigma, lN=None, source=None):
        if source == "fd":
            return super().eval_final_hessian(xN, sigma, lN, source="fd")
        b = self.base
        xN = np.asarray(xN, dtype=float)
        sigma = float(sigma)
        gN = b.eval_final_constraints(xN)
        _, d1, d2, bx = self._final_pieces(xN, gN)
        H = np.array(b.eval_final_hessian(xN, sigma, sigma * d1 if b.rN else None, source=source), dtype=float)
        if b.rN:
            C = b.eval_final_constraint_jacobian(xN, source=source)
            H += C.T @ ((sigma * d2)[:, None] * C)
        H[np.arange(self.n), np.arange(self.n)] += sigma * bx[2]
        return H

    # ------------------------------------------------------------------ constraint measures
    def violations(self, X, U):
        """Max-norm violation of every penalized constraint of the base problem, and a dict of
        the violation per kind."""
        b = self.base
        parts = {}
        G = b.eval_stage_constraints(X, U)
        parts["stage_constraints"] = float(np.max(_violation(G, self.eq_stage), initial=0.0))
        gN = b.eval_final_constraints(X[-1])
        parts["final_constraints"] = float(np.max(_violation(gN, self.eq_final), initial=0.0))
        vx = np.maximum(np.where(self.xl_mask, self.xl - X, 0.0), np.where(self.xu_mask, X - self.xu, 0.0))
        parts["state_bounds"] = float(np.max(vx, initial=0.0))
        lo, hi = b.u_lower, b.u_upper
        with np.errstate(invalid="ignore"):
            vu = np.maximum(np.where(np.isfinite(lo), lo - U, 0.0), np.where(np.isfinite(hi), U - hi, 0.0))
        parts["control_bounds"] = float(np.max(vu, initial=0.0))
        return max(parts.values()), parts

    def first_order_multipliers(self, X, U):
        """phi'(c) for every penalized constraint at (X, U): the next augmented Lagrangian
        estimates and the multipliers of the result. Bound multipliers are returned >= 0."""
        b = self.base
        mult = self.multipliers
        G = b.eval_stage_constraints(X, U)
        _, d1, _ = _phi(G, mult["stage_constraints"], self.rho, self.eq_stage)
        gN = b.eval_final_constraints(X[-1])
        _, d1N, _ = _phi(gN, mult["final_constraints"], self.rho, self.eq_final)
        out = {"stage_constraints": d1, "final_constraints": d1N}
        for key, Z, lo, hi, lm, hm in (("x", X, self.xl, self.xu, self.xl_mask, self.xu_mask),
                                       ("u", U, self.ul, self.uu, self.ul_mask, self.uu_mask)):
            _, dl, _ = _phi(np.where(lm, Z - lo, 1.0), np.where(lm, mult["bound_lower_" + key], 0.0), self.rho, False)
            _, du, _ = _phi(np.where(hm, hi - Z, 1.0), np.where(hm, mult["bound_upper_" + key], 0.0), self.rho, False)
            out["bound_lower_" + key] = np.where(lm, -dl, 0.0)
            out["bound_upper_" + key] = np.where(hm, -du, 0.0)
        return out


# ============================================================================ inner method: L-BFGS-B
def solve_lbfgsb(problem, U0, *, tol, max_iter, memory=20, ftol=1e-15, max_restarts=50, limits=None):
    """Built-in inner method: SciPy's L-BFGS-B on the reduced problem J(u) of ``problem``
    (values and adjoint gradients of :class:`~olado.solvers.control.control_space.ReducedProblem`),
    with the problem's control bounds as bounds. Stops when the projected gradient max-norm is
    <= ``tol`` (``gtol``), when restarts no longer decrease J (converged to rounding level), or
    after ``max_iter`` iterations in all. ``limits`` (:class:`olado.interrupts.Limits`) is
    checked after every evaluation: a time limit or an interrupt returns L-BFGS-B's last
    iterate (the caller's own check then ends its solve).

    Returns (U, converged, iterations, message, evaluations)."""
    from scipy.optimize import Bounds, minimize

    limits = limits if limits is not None else Limits()
    rp = ReducedProblem(problem, limits)
    N, m = problem.N, problem.m
    lo, hi = problem.u_lower.ravel(), problem.u_upper.ravel()
    bounded = bool(np.isfinite(lo).any() or np.isfinite(hi).any())
    u0 = np.clip(np.asarray(U0, dtype=float).ravel(), lo, hi)

    def fg(u):
        try:
            J, g, _, _ = rp.gradient(u.reshape(N, m))
        except NonFiniteEvaluationError:
            return np.inf, np.zeros_like(u)
        return J, g.ravel()

    best = {"u": u0}

    def remember(u):
        best["u"] = np.array(u)

    # L-BFGS-B stops on "relative reduction of f <= ftol" on badly scaled problems (large rho,
    # unstable dynamics) well before the gradient is small; a restart (fresh memory) from the
    # point reached continues. Converged: projected gradient <= tol, or a restart that cannot
    # decrease f any more (the floating-point limit of the penalized function).
    u = u0
    total, restarts, f_prev = 0, 0, math.inf
    converged = False
    while True:
        with limits.catch() as stop:
            res = minimize(fg, u, jac=True, method="L-BFGS-B", bounds=Bounds(lo, hi) if bounded else None,
                           callback=remember,
                           options={"maxiter": max(int(max_iter) - total, 1), "gtol": float(tol), "ftol": float(ftol),
                                    "maxcor": int(memory), "maxfun": max(15000, 20 * int(max_iter)), "maxls": 40})
        if stop.reason:
            return best["u"].reshape(N, m), False, total, stop.reason.replace("_", " "), rp.n_gradient
        total += int(res.nit)
        u = res.x
        best["u"] = u
        msg = res.message if isinstance(res.message, str) else res.message.decode()
        pg = _projected_gradient_norm(rp, problem, u.reshape(N, m))
        stalled = not (res.fun < f_prev - 1e-15 * max(1.0, abs(f_prev)))
        f_prev = res.fun
        if pg <= tol or (stalled and restarts > 0):
            converged = True
            break
        if total >= max_iter or restarts >= max_restarts or not np.isfinite(res.fun):
            break
        restarts += 1
    U = u.reshape(N, m)
    note = f" after {restarts} restart(s)" if restarts else ""
    return U, converged, total, f"{msg}{note} (projected gradient {pg:.2e})", rp.n_gradient


def _projected_gradient_norm(rp, problem, U):
    _, g, _, _ = rp.gradient(U)
    lo, hi = problem.u_lower, problem.u_upper
    pg = np.clip(U - g, lo, hi) - U
    return float(np.max(np.abs(pg), initial=0.0))


# ============================================================================ the solver
@dataclasses.dataclass
class PenaltyOptions(SolverOptions):
    """Options of the penalty / augmented Lagrangian method."""

    max_iter: int = option(30, "maximum number of outer (penalty) iterations", min=0)
    tol: float = option(1e-8, "tolerance of the inner solves (projected-gradient max-norm of the penalized problem)",
                        min=0.0, min_exclusive=True)
    constr_viol_tol: float = option(1e-6, "stop when the max-norm constraint violation is <= this",
                                    min=0.0, min_exclusive=True)
    inner: str = option("lbfgsb", "unconstrained method for the penalized subproblems",
                        choices=tuple(INNER_METHODS))
    inner_max_iter: int = option(2000, "iteration limit of each inner solve", min=1)
    inner_memory: int = option(20, "lbfgsb: number of stored correction pairs", min=1)
    rho_init: float = option(10.0, "initial penalty parameter", min=0.0, min_exclusive=True)
    rho_factor: float = option(10.0, "factor by which rho grows", min=1.0, min_exclusive=True)
    rho_max: float = option(1e12, "stop (status failed) when rho would exceed this", min=0.0, min_exclusive=True)
    augmented_lagrangian: bool = option(False, "Hestenes-Powell-Rockafellar multiplier updates")
    infeasible_stall: int = option(3, "status infeasible after this many consecutive rho increases that each reduce "
                                      "the violation by less than 10%", min=1)
    al_decrease: float = option(0.25, "augmented Lagrangian: grow rho only when the violation fell by less than this factor",
                                min=0.0, max=1.0)
    inner_options: dict = option({}, "further options of the inner solver (ini section [penalty.raw])", raw=True)


def _inner_solver_class(name):
    """The registered solver class of inner method ``name``."""
    try:
        return SOLVERS[name]
    except ImportError as exc:
        raise SolverNotAvailableError(f"inner method {name!r} needs {SOLVERS.target(name)}, which cannot be "
                                      f"imported ({exc}); use inner = lbfgsb") from None


@dataclasses.dataclass
class _Outer:
    """One penalty solve's state: the last recorded point (X, U) and its violation, the outer
    and inner iteration counts, the history, the status."""

    X: np.ndarray
    U: np.ndarray
    viol: float
    iters: int = 0
    inner_total: int = 0
    history: list = dataclasses.field(default_factory=list)
    status: Status = Status.MAX_ITERATIONS
    message: str = ""


class PenaltySolver(Solver):
    """Quadratic penalty / augmented Lagrangian method (paper 001 sec. 2.2); see the module
    docstring. Result: history per outer iteration (rho, violation, inner iterations and status,
    objective, penalized objective), multipliers phi'(c) (or the augmented Lagrangian
    estimates), ``info["inner_iterations"]``."""

    name = "penalty"
    Options = PenaltyOptions

    def _solve(self, problem, X0, U0) -> Result:
        o = self.options
        keep_u = o.inner in BOUND_INNER_METHODS
        inner_cls = None if o.inner == "lbfgsb" else _inner_solver_class(o.inner)
        pen = PenalizedProblem(problem, o.rho_init, keep_control_bounds=keep_u)
        limits = Limits(o.max_time)
        U = np.asarray(U0, dtype=float).copy()
        if keep_u:
            U = np.clip(U, problem.u_lower, problem.u_upper)
        try:
            X = problem.simulate(U)
        except NonFiniteEvaluationError as exc:
            return self._unevaluable_start(problem, X0, U, keep_u, exc)
        out = _Outer(X=X, U=U, viol=pen.violations(X, U)[0])
        self._log(2, f"{'iter':>4} {'rho':>9} {'violation':>10} {'objective':>16} {'inner':>6}  inner status")
        with limits.catch() as stop:    # a time limit or an interrupt: the last recorded iterate
            try:
                self._loop(problem, pen, inner_cls, limits, out)
            except NonFiniteEvaluationError as exc:
                out.status, out.message = Status.NUMERICAL_ERROR, f"non-finite values: {exc}"
        if stop.reason:
            out.status, out.message = stop_outcome(stop.reason, limits, f"after {out.iters} penalty iterations")
        return self._result(problem, pen, out, out.status, out.message)

    def _loop(self, problem, pen, inner_cls, limits, out):
        """The outer iterations over the solve's state ``out`` (updated in place). The time limit
        and interrupts raise from ``limits.check()`` after an iteration's record (an inner solve
        stopped by them returns its last iterate first), so ``out`` holds the point recorded."""
        o = self.options
        t0 = limits.t0
        rho = o.rho_init
        stall, viol_at_growth = 0, math.inf
        history = out.history
        for it in range(1, o.max_iter + 1):
            pen.set_penalty(rho)
            if inner_cls is None:
                U, inner_ok, nit, imsg, _ = solve_lbfgsb(pen, out.U, tol=o.tol, max_iter=o.inner_max_iter,
                                                         memory=o.inner_memory, limits=limits)
            else:
                opts = dict(o.inner_options)
                opts.setdefault("tol", o.tol)
                opts.setdefault("max_iter", o.inner_max_iter)
                opts.setdefault("certify", False)   # the penalized subproblem: the outer result is certified
                if math.isfinite(o.max_time):
                    opts.setdefault("max_time", max(o.max_time - (time.perf_counter() - t0), 1e-3))
                res = inner_cls(**opts).solve(pen, guess=out.U)
                U = res.u
                inner_ok, nit, imsg = res.status.success, res.iterations, res.status.value
                if res.status is Status.INTERRUPTED:    # e.g. a KeyboardInterrupt seen by the inner solve
                    limits.interrupt()
                if res.status in (Status.NUMERICAL_ERROR, Status.INVALID_PROBLEM) and not np.all(np.isfinite(U)):
                    out.status, out.message = res.status, f"inner solver {o.inner}: {res.message}"
                    return
            X = problem.simulate(U)
            J = problem.objective(X, U)
            viol, parts = pen.violations(X, U)
            out.X, out.U, out.viol, out.iters = X, U, viol, it
            out.inner_total += max(nit, 0)
            row = {"iter": it, "rho": rho, "violation": viol, "objective": J,
                   "penalized_objective": pen.objective(X, U), "inner_iterations": nit,
                   "inner_converged": bool(inner_ok), "inner_message": imsg,
                   "time_s": time.perf_counter() - t0}
            row.update({f"violation_{k}": v for k, v in parts.items()})
            history.append(row)
            self._log(2, f"{it:4d} {rho:9.2e} {viol:10.3e} {J:16.9e} {nit:6d}  {imsg}")
            if self._call_callback(dict(row, x=X, u=U)):
                out.status, out.message = Status.USER_STOP, "stopped by the callback"
                return
            if viol <= o.constr_viol_tol:
                if inner_ok:
                    out.status, out.message = Status.SUCCESS, (f"violation {viol:.2e} <= {o.constr_viol_tol:g} after "
                                                               f"{it} penalty iterations (rho = {rho:.3g})")
                else:
                    out.status, out.message = Status.ACCEPTABLE, (f"violation {viol:.2e} <= {o.constr_viol_tol:g} but "
                                                                  f"the last inner solve did not converge: {imsg}")
                return
            limits.check()
            if it == o.max_iter:
                break
            # ---- update multipliers / rho
            grow = True
            if o.augmented_lagrangian:
                pen.set_penalty(rho, pen.first_order_multipliers(X, U))
                prev = history[-2]["violation"] if len(history) > 1 else math.inf
                grow = viol > o.al_decrease * prev
            if grow:
                stall = stall + 1 if viol > 0.9 * viol_at_growth else 0
                viol_at_growth = viol
                if stall >= o.infeasible_stall:
                    out.status, out.message = Status.INFEASIBLE, (
                        f"the violation stays at {viol:.2e} while rho grows ({stall} increases to {rho:.3g} "
                        f"reduced it by less than 10% each): locally infeasible")
                    return
                if rho * o.rho_factor > o.rho_max:
                    out.status, out.message = Status.FAILED, (f"penalty parameter would exceed rho_max = "
                                                              f"{o.rho_max:g} with violation {out.viol:.2e} > "
                                                              f"{o.constr_viol_tol:g}")
                    return
                rho *= o.rho_factor
        out.message = (f"{o.max_iter} penalty iterations without reaching violation <= {o.constr_viol_tol:g} "
                       f"(violation {out.viol:.2e}, rho = {rho:.3g})")

    # ------------------------------------------------------------------ result
    def _unevaluable_start(self, problem, X0, U, clipped, exc):
        """INVALID_PROBLEM when the initial controls simulate to non-finite states: the method
        is sequential (the states are always x(u), eq. (2)), so it has no point to start from.
        (The zambezi SIF start clipped into the control bounds lets the volumes diverge.) No
        other start is made up: which controls keep a given model's simulation finite is the
        user's knowledge; the guess's own states serve the simultaneous methods."""
        where = " (clipped into their bounds)" if clipped else ""
        message = (f"the {self.name} method simulates the states from the controls, and the initial controls{where} "
                   f"cannot be simulated: {exc}. Start from controls whose simulated states stay finite, or use a "
                   "simultaneous method (sqp, ipopt), which starts from the guess's states")
        return Result(status=Status.INVALID_PROBLEM, message=message, objective=float("nan"),
                      x=np.asarray(X0, dtype=float), u=U, max_constraint_violation=float("nan"),
                      info={"inner": self.options.inner, "augmented_lagrangian": self.options.augmented_lagrangian})

    def _result(self, problem, pen, out, status, message):
        X, U, iterations, inner_total, history, viol = out.X, out.U, out.iters, out.inner_total, out.history, out.viol
        saved = Counter(problem.counters)
        multipliers, kkt = {}, None
        try:
            multipliers, kkt, stat, compl = _kkt(problem, pen, X, U)
        except ProblemDefinitionError:   # pragma: no cover - the point was evaluated before
            stat = compl = None
        problem.counters.clear()
        problem.counters.update(saved)
        if history and out.iters:       # the recorded point: its J is known
            J = history[-1]["objective"]
        else:
            J = problem.objective(X, U) if np.all(np.isfinite(U)) and np.all(np.isfinite(X)) else math.nan
        problem.counters.clear()
        problem.counters.update(saved)
        return Result(status=status, message=message or status.sentence, objective=float(J), x=X, u=U,
                      multipliers=multipliers, max_constraint_violation=float(viol), kkt_residual=kkt,
                      iterations=iterations, history=history,
                      info={"inner": self.options.inner, "inner_iterations": inner_total,
                            "rho": pen.rho, "augmented_lagrangian": self.options.augmented_lagrangian,
                            "stationarity_residual": stat, "complementarity_residual": compl,
                            "multiplier_convention": "grad J + Jc^T lam - z_L + z_U = 0 (IPOPT's sign convention); "
                                                     "multipliers are phi'(c) of the last penalized problem"})


def _kkt(problem, pen, X, U):
    """Multipliers of the last penalized problem and the KKT residual of the original problem
    (the NLP view's stationarity and complementarity max-norms)."""
    from ..common import complementarity_residual, fill_fixed_bound_multipliers, jacobian_matrix, stationarity_residual
    from ...problems.nlp import StructuredNLP

    mult = pen.first_order_multipliers(X, U)
    _, g, _, costate = ReducedProblem(pen).gradient(U, X)
    if pen.keep_control_bounds:
        lo, hi = problem.u_lower, problem.u_upper
        tol = 1e-8
        at_lo = np.isfinite(lo) & (U - lo <= tol * (1 + np.abs(np.where(np.isfinite(lo), lo, 0))))
        at_hi = np.isfinite(hi) & (hi - U <= tol * (1 + np.abs(np.where(np.isfinite(hi), hi, 0))))
        mult["bound_lower_u"] = np.where(at_lo, np.maximum(g, 0.0), 0.0)
        mult["bound_upper_u"] = np.where(at_hi, np.maximum(-g, 0.0), 0.0)
    mult["dynamics"] = costate[1:].copy()
    nlp = StructuredNLP(problem)
    y = nlp.pack(X, U)
    lam = np.concatenate([mult["dynamics"].ravel(), mult["stage_constraints"].ravel(), mult["final_constraints"].ravel()])
    zl = nlp.pack(mult["bound_lower_x"], mult["bound_lower_u"])
    zu = nlp.pack(mult["bound_upper_x"], mult["bound_upper_u"])
    grad = np.asarray(nlp.gradient(y), dtype=float)
    jac = jacobian_matrix(nlp, y)
    zl, zu = fill_fixed_bound_multipliers(nlp, y, lam, zl, zu, grad=grad, jac=jac)
    X0l, _ = nlp.unpack(zl)
    X0u, _ = nlp.unpack(zu)
    mult["bound_lower_x"][0] = X0l[0]
    mult["bound_upper_x"][0] = X0u[0]
    stat = float(np.max(np.abs(stationarity_residual(grad, jac, lam, zl, zu)), initial=0.0))
    compl = complementarity_residual(nlp, y, nlp.constraints(y), lam, zl, zu)
    return mult, max(stat, compl), stat, compl


__all__ = ["PenaltySolver", "PenaltyOptions", "PenalizedProblem", "solve_lbfgsb", "INNER_METHODS",
           "BOUND_INNER_METHODS"]
