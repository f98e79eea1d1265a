"""FQLNK: the full-space quasi Lagrange-Newton-Krylov method of seed 002 (Wang, Lo, Hwang and
Hwang; docs/fqlnk.md) on olado's DOCP.

The KKT conditions F(p) = (grad_v L, c) = 0 of the equality-constrained NLP (seed eqs. (2.9),
(3.1)) in the full space p = (v, lam) are solved by an inexact Newton method with backtracking
(the seed's Algorithm 1, "QNB"):

1. stop when ||F(p^k)||_2 <= atol or ||F(p^k)||_2 <= rtol ||F(p^0)||_2 (seed sec. 4: both 1e-6)
   -- and, olado's addition, when olado's certificate (olado.solvers.certificate) holds there;
   while it does not, the iteration goes on;
2. form K^k = [[H^k, G^k'], [G^k, 0]] with H^k (option ``hessian``): the damped BFGS matrix
   (sec. 3.2, :mod:`olado.solvers.fqlnk.bfgs`), the problem's exact Hessian (the seed's "AD") or
   second central differences of the Lagrangian's values (the seed's "FD", eq. (3.2));
3. solve K dp = -F inexactly, ||F + K dp|| <= eta ||F||, by ILUTP-preconditioned GMRES (sec.
   3.3, :mod:`olado.solvers.fqlnk.krylov`);
4. choose alpha by Armijo backtracking on the augmented Lagrangian merit (3.3)-(3.4)
   (:mod:`olado.solvers.fqlnk.merit`); p <- p + alpha dp.

The start (sec. 4.3): the problem's guess (states simulated from the controls, as the seed does),
the least-squares multipliers of eq. (4.4). Inequalities (option ``inequalities``): the seed's
method has none; ``refuse`` (default) raises a ConfigError naming the problem's bounds and rows,
``squared-slacks`` rewrites each as an equality with a squared slack, g - s^2 = 0 (eq. (4.6)).
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ...errors import ConfigError, NonFiniteEvaluationError
from ...interrupts import Limits
from ...options import option
from ...result import Result, Status
from ..base import Solver, SolverOptions
from ..certificate import CertificateSettings, certify
from ..common import EVALUATION_KINDS, MULTIPLIER_CONVENTION, Stoppable, run_iterations
from ..sqp.residuals import stage_kkt
from ..sqp.state import BoundMultipliers, Clock, Multipliers, Point
from .bfgs import damped_bfgs_update, positive_definite_start, scaled_identity_start, scaled_start
from .krylov import kkt_matrix, solve_kkt
from .layout import Layout
from .merit import armijo_backtracking, augmented_lagrangian, penalty_and_slope, residual_merit


@dataclasses.dataclass
class FQLNKOptions(SolverOptions):
    """Options of FQLNK (the seed's values as defaults, seed 002 sec. 4 and 4.6)."""

    max_iter: int = option(500, "maximum number of Newton iterations", min=0)
    hessian: str = option("bfgs", "the (1,1) block of the KKT matrix: bfgs (damped BFGS, seed sec. 3.2), exact (the "
                          "problem's second derivatives: the seed's AD) or fd (second central differences of the "
                          "Lagrangian's values, seed eq. (3.2))", choices=("bfgs", "exact", "fd"))
    bfgs_init: str = option("exact", "B^(0) of the BFGS matrix: exact (the problem's Hessian at the start, its "
                            "eigenvalues made positive; the seed's choice) or identity (y'y/s'y I after the first step)",
                            choices=("exact", "identity"))
    bfgs_damping: str = option("powell", "a BFGS update whose curvature s'y is below bfgs_threshold s'Bs: powell "
                               "(damped, the seed's sec. 3.2) or skip (B unchanged)", choices=("powell", "skip"))
    bfgs_threshold: float = option(0.2, "t of the damping: undamped when s'y >= t s'Bs, else damped to s'r = t s'Bs "
                                   "(the seed: 0.2)", min=0.0, max=0.99, min_exclusive=True)
    bfgs_scaling: str = option("none", "B^(0) = exact scaled by s'y / s'Bs after the first step (first-step) or not "
                               "(none, the seed)", choices=("none", "first-step"))
    atol: float = option(1e-6, "absolute tolerance of the seed's stopping test ||F||_2 <= atol", min=0.0)
    rtol: float = option(1e-6, "relative tolerance of the seed's stopping test ||F||_2 <= rtol ||F_0||_2", min=0.0)
    forcing: float = option(1e-6, "forcing term eta_k: GMRES stops at ||F + K dp|| <= eta_k ||F||", min=0.0, max=0.5,
                            min_exclusive=True)
    gmres_restart: int = option(50, "GMRES restart length", min=1)
    gmres_max_iter: int = option(20, "GMRES restart cycles at most", min=1)
    ilu_drop_tol: float = option(1e-6, "ILUTP drop tolerance tau (SuperLU's ILU, scipy spilu)", min=0.0)
    ilu_fill_factor: float = option(10.0, "ILUTP fill factor (nonzeros of the factors over those of K at most)",
                                    min=1.0)
    ilu_retries: int = option(2, "a failed ILUTP factorization is tried again with the fill factor tripled, this "
                              "many times", min=0)
    ilu_permc_spec: str = option("COLAMD", "ILUTP column ordering", choices=("COLAMD", "MMD_AT_PLUS_A", "MMD_ATA",
                                                                           "NATURAL"))
    ilu_pivot_threshold: float = option(0.1, "ILUTP threshold of the partial pivoting (1: always the largest entry)",
                                        min=0.0, max=1.0)
    line_search: str = option("merit", "merit (Armijo backtracking on the augmented Lagrangian, seed sec. 3.4) or "
                              "none (full steps: the seed's 'without backtracking' of Fig. 4.10)",
                              choices=("merit", "none"))
    armijo: float = option(1e-4, "beta of Armijo's condition (3.4)", min=0.0, max=0.5, min_exclusive=True)
    alpha_min: float = option(1e-8, "smallest step length of the backtracking", min=0.0, min_exclusive=True)
    rho_init: float = option(1.0, "rho^(-1), the merit's first penalty parameter", min=0.0, min_exclusive=True)
    inequalities: str = option("refuse", "bounds and inequality rows: refuse (the seed's method has none) or "
                               "squared-slacks (g - s^2 = 0, seed eq. (4.6))", choices=("refuse", "squared-slacks"))
    certificate_attempts: int = option(10, "iterations past the seed's stopping test while olado's certificate "
                                       "does not hold", min=0)


# ---------------------------------------------------------------------------- refusal
def unsupported_inequalities(problem) -> list:
    """The problem's bounds (on x^1..x^N and u) and inequality rows, in words; empty when it
    has none (x^0 is fixed and not a bound)."""
    p = problem
    parts = []
    for what, lo, hi in (("states x^1..x^N", p.x_lower[1:], p.x_upper[1:]), ("controls", p.u_lower, p.u_upper)):
        count = int(np.isfinite(lo).sum() + np.isfinite(hi).sum())
        if count:
            parts.append(f"{count} finite bounds on the {what}")
    ni, niN = int((~p.stage_equality_mask).sum()), int((~p.final_equality_mask).sum())
    if ni:
        parts.append(f"{ni} stage inequality row{'s' if ni > 1 else ''} g^k >= 0")
    if niN:
        parts.append(f"{niN} final inequality row{'s' if niN > 1 else ''} g^N >= 0")
    return parts


def check_supported(problem, options):
    """A ConfigError when the problem has inequalities that the chosen treatment cannot take:
    any, with inequalities = refuse; fixed variables (lb = ub) with squared-slacks."""
    name = getattr(problem, "name", type(problem).__name__)
    parts = unsupported_inequalities(problem)
    if parts and options.inequalities == "refuse":
        raise ConfigError(f"fqlnk solves equality-constrained DOCPs (seed 002 sec. 3), but problem {name!r} has "
                          f"{' and '.join(parts)}; set inequalities = 'squared-slacks' (each becomes g - s^2 = 0, "
                          f"seed eq. (4.6)) or use sqp-ip / ipm", section="fqlnk", key="inequalities")
    fixed = int((problem.x_lower[1:] == problem.x_upper[1:]).sum() + (problem.u_lower == problem.u_upper).sum())
    if fixed and options.inequalities == "squared-slacks":
        raise ConfigError(f"problem {name!r} fixes {fixed} variables by equal bounds (lb = ub): their two squared "
                          f"slacks would both be 0 at every feasible point (a singular KKT matrix); fqlnk does not "
                          f"solve it, use sqp-ip / ipm", section="fqlnk", key="inequalities")


# ---------------------------------------------------------------------------- per-solve state
@dataclasses.dataclass
class Iterate:
    """A point of the full space: v, lam, the evaluated stage point (with derivatives), c, G,
    grad_v L and F = (grad_v L, c)."""

    v: np.ndarray
    lam: np.ndarray
    pt: Point
    c: np.ndarray
    G: object
    gradL: np.ndarray
    F: np.ndarray

    @property
    def norm(self):
        return float(np.linalg.norm(self.F))


@dataclasses.dataclass
class FQLNKState(Stoppable):
    it: Iterate
    F0: float
    rho: float
    clock: Clock
    B: np.ndarray | None = None
    k: int = 0
    gmres_iterations: int = 0
    hessian_time: float = 0.0
    kkt_time: float = 0.0
    residual_searches: int = 0
    damped_updates: int = 0
    skipped_updates: int = 0
    bfgs_negative_eigenvalue: float = 0.0
    bfgs_start_scale: float = 1.0
    certificates: int = 0
    certificate: object = None
    status: Status = Status.MAX_ITERATIONS
    message: str = ""
    history: list = dataclasses.field(default_factory=list)


class Setup:
    def __init__(self, options, problem, limits, callback):
        self.options, self.problem, self.limits, self.callback = options, problem, limits, callback
        self.layout = Layout(problem, slacks=options.inequalities == "squared-slacks")
        self.certificate = CertificateSettings.from_options(options) if options.certify else None
        self.t_start = time.perf_counter()


# ---------------------------------------------------------------------------- evaluations
def point_at(setup, v, clock, derivatives=True):
    X, U, _ = setup.layout.unpack(v)
    return Point(setup.problem, X, U, derivatives=derivatives, clock=clock)


def make_iterate(setup, v, lam, pt) -> Iterate:
    L = setup.layout
    pt.add_derivatives(setup.problem)
    c = L.constraints(pt, v)
    gradL = L.lagrangian_gradient(pt, v, lam)
    return Iterate(v, lam, pt, c, L.jacobian(pt, v), gradL, np.concatenate([gradL, c]))


def least_squares_multipliers(setup, v, pt):
    """lam^(0) = -(G G')^-1 G grad J (seed eq. (4.4), olado's sign), through the augmented
    system [[I, G'], [G, 0]] (the same least-squares solution without forming G G'); zeros when
    G is rank deficient there."""
    L = setup.layout
    G = L.jacobian(pt, v)
    gJ = L.lagrangian_gradient(pt, v, np.zeros(L.nc))
    A = sp.bmat([[sp.identity(L.nv), G.T], [G, None]], format="csc")
    try:
        sol = spla.splu(A).solve(np.concatenate([-gJ, np.zeros(L.nc)]))
    except RuntimeError:
        return np.zeros(L.nc)
    lam = sol[L.nv:]
    return lam if np.all(np.isfinite(lam)) else np.zeros(L.nc)


def initial_state(setup, X0, U0, clock) -> FQLNKState:
    L = setup.layout
    X0 = np.array(X0, dtype=float)
    X0[0] = setup.problem.x0
    v = L.pack(X0, np.asarray(U0, dtype=float))
    pt = point_at(setup, v, clock)
    if L.ns:
        v[L.ny:] = L.initial_slacks(pt, v)
    lam = least_squares_multipliers(setup, v, pt)
    it = make_iterate(setup, v, lam, pt)
    st = FQLNKState(it=it, F0=it.norm, rho=setup.options.rho_init, clock=clock)
    if setup.options.hessian == "bfgs":
        t0 = time.perf_counter()
        if setup.options.bfgs_init == "exact":
            st.B, st.bfgs_negative_eigenvalue = positive_definite_start(L.hessian(pt, v, lam))
        else:
            st.B = scaled_identity_start(L.nv)
        st.hessian_time += time.perf_counter() - t0
    return st


# ---------------------------------------------------------------------------- one iteration
def hessian_block(setup, st):
    """H^k: the BFGS matrix, or the problem's Hessian (exact or finite differences) at the iterate."""
    o, it = setup.options, st.it
    t0 = time.perf_counter()
    H = st.B if o.hessian == "bfgs" else setup.layout.hessian(it.pt, it.v, it.lam, source="fd" if o.hessian == "fd" else None)
    H = sp.csr_matrix(H) if not sp.issparse(H) else H
    if o.hessian != "bfgs":
        st.clock.add(("hessian",), t0)
    st.hessian_time += time.perf_counter() - t0
    return H


def trial(setup, st, dp, alpha):
    """The values at p + alpha dp, without derivatives: (v, lam, pt, c); None where the
    functions are not finite."""
    L = setup.layout
    v = st.it.v + alpha * dp[:L.nv]
    lam = st.it.lam + alpha * dp[L.nv:]
    try:
        pt = point_at(setup, v, st.clock, derivatives=False)
    except NonFiniteEvaluationError:
        return None
    c = L.constraints(pt, v)
    if not (np.isfinite(pt.J) and np.all(np.isfinite(c))):
        return None
    return v, lam, pt, c


def search(setup, st, dp, K):
    """Step 5 of Algorithm 1: alpha by Armijo backtracking on the merit. (alpha, trial values,
    merit kind), or (None, the reason in words)."""
    o, it, L = setup.options, st.it, setup.layout
    if o.line_search == "none":
        t = trial(setup, st, dp, 1.0)
        return (1.0, t, "none") if t is not None else (None, "its full step reaches a point where the problem's "
                                                             "functions are not finite (line_search = none)")
    slope = penalty_and_slope(it.F, it.c, it.G @ dp[:L.nv], dp, st.rho, F=it.F, Kdp=K @ dp)
    st.rho = slope.rho
    st.residual_searches += slope.kind == "residual"
    if not slope.derivative < 0.0:
        return None, "its step is no descent direction of the merit function"
    cache = {}

    def merit(alpha):
        t = trial(setup, st, dp, alpha)
        cache[alpha] = t
        if t is None:
            return math.inf
        v, lam, pt, c = t
        if slope.kind == "augmented-lagrangian":
            return augmented_lagrangian(pt.J, lam, c, st.rho)
        return residual_merit(make_iterate(setup, v, lam, pt).F)

    m0 = (augmented_lagrangian(it.pt.J, it.lam, it.c, st.rho) if slope.kind == "augmented-lagrangian"
          else residual_merit(it.F))
    res = armijo_backtracking(merit, m0, slope.derivative, o.armijo, o.alpha_min, check=setup.limits.check)
    if res.alpha is None:
        return None, f"its line search reached alpha_min = {o.alpha_min:g}"
    return res.alpha, cache[res.alpha], slope.kind


def bfgs_update(setup, st, old: Iterate):
    """s = v^k - v^{k-1}, y = grad_v L(v^k, lam^k) - grad_v L(v^{k-1}, lam^k) (sec. 3.2); before
    the first update B^(0) is scaled (bfgs_init = identity: y'y/s'y I; bfgs_scaling = first-step:
    s'y/s'Bs B^(0)), then damped (or skipped, bfgs_damping) with bfgs_threshold."""
    t0 = time.perf_counter()
    L, new = setup.layout, st.it
    s = new.v - old.v
    y = new.gradL - L.lagrangian_gradient(old.pt, old.v, new.lam)
    o = setup.options
    if o.bfgs_init == "identity" and st.k == 1:
        st.B = scaled_identity_start(L.nv, s, y)
    elif o.bfgs_scaling == "first-step" and st.k == 1:
        st.B, st.bfgs_start_scale = scaled_start(st.B, s, y)
    up = damped_bfgs_update(st.B, s, y, o.bfgs_threshold, skip=o.bfgs_damping == "skip")
    st.B = up.B
    st.damped_updates += up.theta < 1.0
    st.skipped_updates += up.skipped
    st.hessian_time += time.perf_counter() - t0


def seed_test(setup, st) -> bool:
    o = setup.options
    return st.it.norm <= o.atol or st.it.norm <= o.rtol * st.F0


def result_multipliers(setup, it):
    """The Result's multipliers from lam: the dynamics, stage and final rows (a squared-slack
    row's multiplier is its inequality's), and z_L, z_U = -mu of the bound rows."""
    L, p = setup.layout, setup.problem
    dyn, Lg, LgN, mb = L.split_multipliers(it.lam)
    lam = np.zeros((p.N + 1, p.n))
    lam[1:] = dyn
    zx, zu = np.zeros((2, p.N + 1, p.n)), np.zeros((2, p.N, p.m))
    if L.nb:
        b = L.bounds
        z = np.zeros((2, L.ny))
        side = (b.sign < 0).astype(int)
        z[side, b.col] = -mb
        for j, (zxj, zuj) in enumerate(zip(zx, zu)):
            X, U, _ = L.unpack(np.concatenate([z[j], np.zeros(L.ns)]))
            zxj[1:] = X[1:]
            zuj[:] = U
    return Multipliers(lam, Lg, LgN), BoundMultipliers(zx[0], zx[1], zu[0], zu[1])


def certified(setup, st) -> bool:
    """olado's certificate at the iterate (True: holds; no certificate asked: True)."""
    if setup.certificate is None:
        return True
    mult, _ = result_multipliers(setup, st.it)
    cert = certify(setup.problem, st.it.pt.X, st.it.pt.U, {"dynamics": mult.lam[1:], "stage_constraints": mult.Lg,
                                                            "final_constraints": mult.LgN}, setup.certificate)
    st.certificates += 1
    st.certificate = cert
    return cert.level == "success"


def converged(setup, st) -> bool:
    o = setup.options
    if not seed_test(setup, st):
        return False
    norm = st.it.norm
    if certified(setup, st):
        return st.stop(Status.SUCCESS, f"converged in {st.k} Newton iterations: ||F|| = {norm:.2e} <= "
                       f"max(atol, rtol ||F_0||) = {max(o.atol, o.rtol * st.F0):.2e}; olado's certificate holds")
    if st.certificates > o.certificate_attempts:
        return st.stop(Status.UNCERTIFIED, f"the seed's stopping test holds after {st.k} Newton iterations "
                       f"(||F|| = {norm:.2e}) but olado's certificate does not after {o.certificate_attempts} further "
                       f"iterations: {st.certificate.reason}")
    return False


def iterate(setup, st) -> bool:
    """One Newton iteration of Algorithm 1; True when the solve ends."""
    o = setup.options
    setup.limits.check()
    if converged(setup, st):
        return True
    if st.k >= o.max_iter:
        return st.stop(Status.MAX_ITERATIONS, f"iteration limit {o.max_iter} reached; ||F|| = {st.it.norm:.2e} "
                       f"(||F_0|| = {st.F0:.2e})")
    H = hessian_block(setup, st)
    K = kkt_matrix(H, st.it.G)
    sol = solve_kkt(K, st.it.F, o)
    st.kkt_time += sol.ilu_time + sol.gmres_time
    st.gmres_iterations += sol.iterations
    if sol.dp is None:
        return st.stop(Status.NUMERICAL_ERROR, f"Newton iteration {st.k + 1}: {sol.message}")
    found = search(setup, st, sol.dp, K)
    if found[0] is None:
        gmres = f" ({sol.message})" if sol.message else ""
        return st.stop(Status.NUMERICAL_ERROR, f"Newton iteration {st.k + 1}: {found[1]}{gmres}; "
                       f"||F|| = {st.it.norm:.2e}")
    alpha, (v, lam, pt, _), kind = found
    old = st.it
    st.it = make_iterate(setup, v, lam, pt)
    st.k += 1
    if o.hessian == "bfgs":
        bfgs_update(setup, st, old)
    entry = {"iter": st.k, "norm_F": st.it.norm, "alpha": alpha, "gmres": sol.iterations,
             "gmres_residual": sol.relative_residual, "rho": st.rho, "merit": kind, "objective": float(pt.J),
             "violation": float(np.max(np.abs(st.it.c), initial=0.0))}
    st.history.append(entry)
    if o.verbose >= 2:
        print(f"{st.k:4d} ||F|| {st.it.norm:.3e} J {pt.J: .10e} alpha {alpha:.2e} gmres {sol.iterations:3d} "
              f"rho {st.rho:.1e} {kind}")
    if setup.callback(dict(entry)):
        return st.stop(Status.USER_STOP, f"stopped by the callback after {st.k} Newton iterations")
    return False


# ---------------------------------------------------------------------------- the result
def finish(setup, st) -> Result:
    p, it = setup.problem, st.it
    solve_time = time.perf_counter() - setup.t_start
    mult, zb = result_multipliers(setup, it)
    kkt = stage_kkt(p, it.pt, mult, zb)
    z = kkt.bounds
    k = max(st.k, 1)
    info = {"callback_time_s": st.clock.time_s, "solve_time_s": solve_time,
            "callback_share": st.clock.time_s / solve_time if solve_time > 0 else float("nan"),
            "kkt_residual_kind": "max-norm of stationarity and complementarity at the final point",
            "stationarity_residual": kkt.stationarity, "complementarity_residual": kkt.complementarity,
            "multiplier_convention": MULTIPLIER_CONVENTION,
            "norm_F": it.norm, "norm_F0": st.F0, "hessian": setup.options.hessian,
            "newton_iterations": st.k, "gmres_iterations": st.gmres_iterations,
            "avg_gmres_iterations": st.gmres_iterations / k, "hessian_time_s": st.hessian_time,
            "kkt_time_s": st.kkt_time, "avg_hessian_time_s": st.hessian_time / k, "avg_kkt_time_s": st.kkt_time / k,
            "rho": st.rho, "residual_merit_searches": st.residual_searches,
            "damped_bfgs_updates": st.damped_updates, "skipped_bfgs_updates": st.skipped_updates,
            "bfgs_initial_negative_eigenvalue": st.bfgs_negative_eigenvalue,
            "bfgs_start_scale": st.bfgs_start_scale, "variables": setup.layout.nv, "constraints": setup.layout.nc,
            "slacks": setup.layout.ns, "kkt": "ilutp-gmres"}
    multipliers = {"dynamics": mult.lam[1:].copy(), "stage_constraints": mult.Lg, "final_constraints": mult.LgN,
                   "bound_lower_x": z.zl_x, "bound_lower_u": z.zl_u, "bound_upper_x": z.zu_x, "bound_upper_u": z.zu_u}
    res = Result(status=st.status, message=st.message, objective=float(it.pt.J), x=it.pt.X.copy(), u=it.pt.U.copy(),
                 multipliers=multipliers, max_constraint_violation=kkt.violation,
                 kkt_residual=max(kkt.stationarity, kkt.complementarity), iterations=int(st.k),
                 evaluations={kd: int(st.clock.counts[kd]) for kd in EVALUATION_KINDS}, history=list(st.history),
                 info=info)
    if st.status in (Status.SUCCESS, Status.UNCERTIFIED) and st.certificate is not None:
        res.certificate = st.certificate
    return res


class FQLNKSolver(Solver):
    """Full-space quasi Lagrange-Newton-Krylov (seed 002): BFGS / exact / FD Hessian, ILUTP-GMRES,
    augmented Lagrangian merit."""

    name = "fqlnk"
    Options = FQLNKOptions

    def _solve(self, problem, X0, U0):
        check_supported(problem, self.options)
        limits = Limits(self.options.max_time)
        setup = Setup(self.options, problem, limits, self._call_callback)
        st = run_iterations(limits, lambda: initial_state(setup, X0, U0, Clock(limits)),
                            lambda st: iterate(setup, st), lambda: initial_state(setup, X0, U0, Clock(None)),
                            lambda st: f"after {st.k} Newton iterations")
        return finish(setup, st)
