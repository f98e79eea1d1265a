"""A structure-exploiting primal-dual interior-point NLP solver: IPOPT's algorithm (Waechter and
Biegler 2006, Math. Program. 106, 25-57; docs/interior-point-nlp.md) on the DOCP of paper 001
(eqs. (1)-(5)) with one block Riccati factorization per Newton system instead of a sparse LDL^T.

The barrier problem (eq. (3)) of the DOCP,

    min  phi_mu(y, s) = s_f J(y) - mu sum ln(y - lb) - mu sum ln(ub - y) - mu sum ln(s)
    s.t. h(y) = 0,  g_E(y) = 0,  g_I(y) - s = 0,

y = (x^1..x^N, u^0..u^{N-1}) (x^0 fixed), h the dynamics residuals, g_E the stage and final
equalities, g_I the inequalities with their slacks s (sec. 3.4), is solved approximately for
a decreasing sequence of mu (the monotone Fiacco-McCormick rule (7); or IPOPT's adaptive update,
:mod:`olado.solvers.ipm.adaptive`); each iteration takes a
primal-dual Newton step (eqs. (11)-(13), :mod:`olado.solvers.ipm.newton`: the Riccati recursion
on the LQ-DOCP the system is), the fraction-to-boundary rule (15), the multiplier safeguard
(16), and a filter line search with second-order corrections (sec. 2.3-2.4,
:mod:`olado.solvers.ipm.filter`); the inertia correction of sec. 3.1 shifts the Hessian when a
factorization finds the reduced Hessian not positive definite, and a feasibility restoration
phase (:mod:`olado.solvers.ipm.restoration`) takes over when the line search fails; IPOPT's
watchdog lets full steps through after a run of shortened ones.

Code layout: ``barrier.py`` (the flat iterate, bounds, barrier function, Sigma, step rules; their
passes over the flat vector compiled in ``kernels.py``),
``newton.py`` (the KKT matrix on the Riccati back-end with the slacks eliminated, Algorithm IC),
``filter.py`` (the filter and IPOPT's acceptance safeguards), ``restoration.py`` (least-squares
multipliers, the restoration phases), ``elastic.py`` (the l1 restoration problem as a DOCP),
``adaptive.py`` (the quality-function oracle of the adaptive mu update), ``evaluation.py`` (the
point, residuals, theta, barrier value, gradients and the optimality error (5) at an iterate),
``linesearch.py`` (the Newton direction, the filter line search with second-order corrections, the
watchdog), this module (options, the per-solve state, the start, the barrier update, the Newton
system, the step, the loop, the Result).
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from ...interrupts import Limits
from ...options import option
from ...result import Result, Status
from ..base import Solver, SolverOptions
from ..common import EVALUATION_KINDS, MULTIPLIER_CONVENTION, Stoppable, run_iterations
from ..sqp.residuals import stage_kkt
from ..sqp.state import BoundMultipliers, Clock, Multipliers, Point
from .adaptive import (FILTER_MARGIN_FACT, FILTER_MAX_MARGIN, MONOTONE_INIT_FACTOR, MU_MAX_FACT, MU_MIN, AdaptiveMu,
                       QualityFunction, average_complementarity, quality_function_sigma)
from .barrier import KAPPA_D, Bounds, Layout, _kernels
from .evaluation import (barrier_value, evaluate, full_multipliers, iterate_errors, lagrangian_gradient,
                         objective_gradient, optimality_errors, residuals, store_errors, theta)
from . import iteration_kernels as _IK
from .compiled import plain_path
from .filter import Filter
from .linesearch import line_search, step_vector
from .newton import Constraints, Direction, KKTMatrix, stage_blocks
from .restoration import Restoration, largest_multiplier, least_squares_multipliers, restore, restore_l1

#: the largest flat iterate (entries) whose iterations reuse their arrays (Workspace): at small N
#: allocating them is a tenth of an iteration's time; at large N the arrays kept between
#: iterations (~1 kB per stage of zambezi) would count at the peak of memory
REUSE_MAX = 1 << 15


@dataclasses.dataclass
class IPMOptions(SolverOptions):
    """Options of the interior-point NLP solver (IPOPT's names where IPOPT has the option)."""

    mu_init: float = option(0.1, "initial barrier parameter (IPOPT mu_init)", min=0.0, min_exclusive=True)
    mu_strategy: str = option("monotone", "barrier parameter update: monotone Fiacco-McCormick (eq. (7)) or "
                              "adaptive (IPOPT's quality-function oracle with the obj-constr-filter "
                              "globalization, olado.solvers.ipm.adaptive)", choices=("monotone", "adaptive"))
    barrier_tol_factor: float = option(10.0, "kappa_epsilon: mu is decreased once the barrier problem's "
                                       "optimality error is below kappa_epsilon * mu", min=0.0, min_exclusive=True)
    mu_linear_decrease_factor: float = option(0.2, "kappa_mu of eq. (7)", min=0.0, max=1.0, min_exclusive=True)
    mu_superlinear_decrease_power: float = option(1.5, "theta_mu of eq. (7)", min=1.0, max=2.0)
    tau_min: float = option(0.99, "smallest fraction-to-boundary factor tau (tau = max(tau_min, 1 - mu))",
                            min=0.0, max=1.0, min_exclusive=True)
    bound_push: float = option(1e-2, "kappa_1 of sec. 3.6: least absolute distance of the start from a bound",
                               min=0.0, min_exclusive=True)
    bound_frac: float = option(1e-2, "kappa_2 of sec. 3.6: least relative distance of the start from a bound",
                               min=0.0, max=0.5, min_exclusive=True)
    bound_relax_factor: float = option(1e-8, "bounds relaxed by this factor times max(1, |bound|), at most "
                                       "by constr_viol_tol (IPOPT)", min=0.0)
    constr_mult_init_max: float = option(1e3, "least-squares dynamics multipliers larger than this start at 0",
                                         min=0.0)
    acceptable_tol: float = option(1e-6, "scaled optimality error of an acceptable iterate", min=0.0,
                                   min_exclusive=True)
    acceptable_iter: int = option(15, "stop as ACCEPTABLE after this many acceptable iterates in a row "
                                  "(0: never)", min=0)
    dual_inf_tol: float = option(1.0, "unscaled dual infeasibility a success must also meet (IPOPT)",
                                 min=0.0, min_exclusive=True)
    compl_inf_tol: float = option(1e-4, "unscaled complementarity a success must also meet (IPOPT)",
                                  min=0.0, min_exclusive=True)
    max_soc: int = option(4, "second-order corrections per line search at most (p_max of sec. 2.4)", min=0)
    kappa_soc: float = option(0.99, "a further second-order correction only while it reduces theta by this "
                              "factor", min=0.0, max=1.0, min_exclusive=True)
    obj_scaling: str = option("gradient-based", "objective scaling: gradient-based (IPOPT: s_f = min(1, "
                              "100 / |grad J(y_0)|_inf)) or none", choices=("gradient-based", "none"))
    watchdog_shortened_iter_trigger: int = option(10, "start the watchdog after this many successive "
                                                  "shortened steps (IPOPT's; 0: never)", min=0)
    watchdog_trial_iter_max: int = option(3, "full steps the watchdog takes at most before it returns to "
                                          "where it started (IPOPT's)", min=1)
    restoration: str = option("l1", "the restoration phase: l1 (IPOPT's l1 restoration problem, solved by this "
                              "method; INFEASIBLE where it converges at a positive violation) or gauss-newton "
                              "(minimum-distance Gauss-Newton steps)", choices=("l1", "gauss-newton"))
    max_restoration_iter: int = option(50, "iterations of one Gauss-Newton restoration phase at most (the l1 "
                                       "phase shares max_iter, as IPOPT's)", min=1)


@dataclasses.dataclass
class IPMState(Stoppable):
    """One solve's iterate and bookkeeping: the flat free variables v with the evaluated point,
    the dynamics multipliers lam (N+1, n) (row k+1: the dynamics of stage k; of the scaled
    problem), the bound multipliers, mu, tau, the filter, the last Hessian shift."""

    v: np.ndarray
    pt: Point
    lam: np.ndarray
    zl: np.ndarray
    zu: np.ndarray
    mu: float
    tau: float
    filt: Filter
    s_obj: float
    clock: Clock
    nu: np.ndarray = None       # stage equality multipliers (N, ne)
    nuN: np.ndarray = None      # final equality multipliers (neN,)
    yd: np.ndarray = None       # multipliers of the stage inequality rows g - s = 0 (N, ni); <= 0 at a solution
    ydN: np.ndarray = None      # ... of the final ones (niN,)
    delta: float = 0.0          # delta_w of the last factorization
    delta_last: float = 0.0     # the last nonzero delta_w (Algorithm IC's delta_w^last)
    it: int = 0
    acceptable: int = 0
    factorizations: int = 0
    restorations: int = 0
    status: Status = Status.MAX_ITERATIONS
    message: str = ""
    history: list = dataclasses.field(default_factory=list)
    errors: tuple = (math.inf, math.inf, math.inf)
    shortened: int = 0          # successive iterations whose line search shortened the step
    watch: object = None        # the watchdog (Watchdog) while it runs
    infeasibility_certificate: dict = None   # the converged l1 restoration's figures (restoration.restore_l1)
    adaptive: AdaptiveMu = None  # the adaptive mu update's memory (mu_strategy = adaptive)
    error_cache: tuple = None   # (inputs, s_obj, ErrorTerms) of the last error_terms call
    compl_cache: tuple = None   # (slacks, zl, zu, product ranges, {mu: value}) of the iterate (complementarity)
    compiled_steps: int = 0     # iterations taken by the compiled iteration (.compiled.PlainPath)


class Setup:
    """What stays fixed during a solve."""

    def __init__(self, options, problem, limits, callback):
        self.options, self.problem, self.limits, self.callback = options, problem, limits, callback
        self.layout = Layout(problem)
        #: the restoration phase: IPOPT's l1 problem (restoration.restore_l1), or the Gauss-Newton
        #: steps (restoration.restore) inside a restoration problem and with restoration = gauss-newton
        self.l1_restoration = options.restoration == "l1"
        self.bounds = Bounds.of(problem, self.layout, options.bound_relax_factor, options.constr_viol_tol)
        self.t_start = time.perf_counter()
        #: called after mu changed (the l1 restoration problem's objective follows mu)
        self.on_mu_change = None
        #: the last Newton matrix (newton_system): the next one takes its back-end over
        self.last_kkt = None
        #: the arrays the common iteration writes, allocated once (at small N)
        self.ws = Workspace(self.layout)
        #: the compiled iteration (None where it does not apply)
        self.plain = plain_path(self)


class Workspace:
    """The arrays an iteration writes, allocated once per solve and reused (at small N their
    allocation and release are a tenth of an iteration's time): the Newton matrix's Sigma blocks
    and the barrier gradient (:func:`newton_system`), the Newton step and dv of the direction
    (:func:`.linesearch.direction`), the stage products of the error pass
    (:func:`.evaluation.iterate_errors`), the
    Hessian blocks Q, which the previous Newton matrix held until it let them go
    (KKTMatrix.release_blocks), and two sets each for the trial points (v, X, U and the slacks)
    and for the multiplier step's results (the iterate's and a spare one, in turn). The watchdog
    keeps an iteration's search and iterate past it: :meth:`detach` then leaves those arrays to
    it, and new ones are allocated. Above REUSE_MAX entries every request gets new arrays (the
    arrays kept between iterations would count at the peak of memory)."""

    def __init__(self, layout):
        self.layout = layout
        #: whether the arrays are reused (REUSE_MAX)
        self.reuse = layout.size <= REUSE_MAX
        self._products = None
        self.detach()

    def detach(self):
        """Forget the Newton and step arrays, Q, the trial points' and the multipliers' arrays
        (their holder keeps them); new ones on next use."""
        self._newton = self._step = self.Q = self.Q_owner = self.no_rows = None
        self._trials, self._multipliers = [], []

    def _kept(self, name, make):
        """The arrays kept as ``name``, made by ``make()`` on first use (kept only with reuse:
        without it every request gets new ones)."""
        arrays = getattr(self, name)
        if arrays is None:
            arrays = make()
            if self.reuse:
                setattr(self, name, arrays)
        return arrays

    def products(self):
        """(EA (N, n), EB (N, m)): the error pass's scratch."""
        L = self.layout
        return self._kept("_products", lambda: (np.empty((L.N, L.n)), np.empty((L.N, L.m))))

    def newton(self):
        """(Sx (N+1, n), Su (N, m), Ss (N, ni), SsN (niN,), q (N+1, n), r (N, m), gs (N, ni), gsN (niN,), grad)."""
        L = self.layout
        return self._kept("_newton", lambda: (
            np.empty((L.N + 1, L.n)), np.empty((L.N, L.m)), np.empty((L.N, L.ni)), np.empty(L.niN),
            np.empty((L.N + 1, L.n)), np.empty((L.N, L.m)), np.empty((L.N, L.ni)), np.empty(L.niN), np.empty(L.size)))

    def step(self):
        """((dX (N+1, n), dU (N, m), lam (N+1, n)), dv): the Newton step's output arrays and dv."""
        L = self.layout
        return self._kept("_step", lambda: (
            (np.empty((L.N + 1, L.n)), np.empty((L.N, L.m)), np.empty((L.N + 1, L.n))), np.empty(L.size)))

    def hessian_blocks(self, prev, shape):
        """Q of the shape for the next Newton matrix: the one ``prev`` (the previous matrix, released)
        held, or a new one."""
        Q = self.Q
        if not self.reuse or Q is None or prev is None or self.Q_owner is not prev or Q.shape != shape:
            Q = np.empty(shape)
            self.Q = Q if self.reuse else None
        return Q

    def trial_arrays(self, v):
        """(v_t, X (N+1, n), U (N, m), its slacks (s_L, s_U)) for a trial point of the iterate v:
        of two sets, the one that is not the iterate's (the other: the last accepted trial's, now
        the iterate). The caller forgets what Bounds cached at v_t (barrier.Bounds.forget) before
        writing it."""
        for t in self._trials:
            if t[0] is not v:
                return t
        L = self.layout
        t = (np.empty(L.size), np.empty((L.N + 1, L.n)), np.empty((L.N, L.m)), (np.empty(L.size), np.empty(L.size)))
        if self.reuse:
            self._trials.append(t)
        return t

    def multiplier_arrays(self, st):
        """(s_L, s_U, z_L, z_U, lam) for the multiplier step of take_step: of two sets, one whose
        z_L, z_U, lam are not the iterate's (the step's inputs), else new ones; None without
        reuse (Bounds.step_multipliers allocates them)."""
        if not self.reuse:
            return None
        for m in self._multipliers:
            if m[2] is not st.zl and m[3] is not st.zu and m[4] is not st.lam:
                return m
        L = self.layout
        m = (np.empty(L.size), np.empty(L.size), np.empty(L.size), np.empty(L.size), np.empty(st.lam.shape))
        if len(self._multipliers) < 2:
            self._multipliers.append(m)
        return m


# ---------------------------------------------------------------------------- start
def initial_state(setup, X0, U0, clock):
    """The starting point of sec. 3.6: the guess pushed inside the bounds, the slacks the
    inequality values pushed inside theirs, z = 1, the least-squares multipliers (0 when larger
    than constr_mult_init_max), the objective scaling s_f, mu = mu_init, the filter F_0."""
    o, b, L = setup.options, setup.bounds, setup.layout
    X0 = np.array(X0, dtype=float)
    X0[0] = L.x0
    pt0 = Point(setup.problem, X0, np.asarray(U0, dtype=float), derivatives=o.obj_scaling != "none", clock=clock)
    # x, u pushed into their bounds first, then the slacks d(x) at the pushed point pushed into theirs
    # (IPOPT's DefaultIterateInitializer)
    v = b.push(L.pack(X0, U0, pt0.g[:, L.ineq], pt0.gN[L.ineqN]), o.bound_push, o.bound_frac)
    pt = evaluate(setup, v, clock, derivatives=True)
    if L.ni or L.niN:
        v = b.push(L.pack(pt.X, pt.U, pt.g[:, L.ineq], pt.gN[L.ineqN]), o.bound_push, o.bound_frac)
    # the scaling from the user's point, before the push into the bounds (IPOPT scales the NLP first)
    q, r = objective_gradient(pt0 if o.obj_scaling != "none" else pt, 1.0)
    gmax = max(float(np.abs(q[1:]).max(initial=0.0)), float(np.abs(r).max(initial=0.0)))
    s_obj = min(1.0, 100.0 / gmax) if o.obj_scaling == "gradient-based" and gmax > 0 else 1.0
    del pt0, q, r               # the user's point and its derivatives: not kept through the multipliers
    zl, zu = b.has_lo.astype(float), b.has_hi.astype(float)
    # the multipliers' factored matrix is handed to the first Newton matrix (newton_system)
    mult = least_squares_multipliers(setup, pt, zl, zu, s_obj, hand_over=True)
    if largest_multiplier(mult) > o.constr_mult_init_max:
        mult = tuple(np.zeros_like(a) for a in mult)
    lam, nu, nuN, yd, ydN = mult
    mu = o.mu_init
    return IPMState(v=v, pt=pt, lam=lam, zl=zl, zu=zu, mu=mu, tau=max(o.tau_min, 1.0 - mu),
                    filt=Filter.start(theta(setup, pt, v)), s_obj=s_obj, clock=clock, nu=nu, nuN=nuN, yd=yd, ydN=ydN)


# ---------------------------------------------------------------------------- one iteration
def constraint_blocks(setup, pt, Ss, SsN):
    """The iteration's :class:`Constraints` from the constraint Jacobians at pt."""
    L = setup.layout
    if not L.rows:      # the same object while Sigma's slack blocks are the workspace's
        cons = setup.ws.no_rows
        if cons is None or cons.Ss is not Ss or cons.SsN is not SsN:
            cons = setup.ws.no_rows = Constraints(*L.no_constraint_rows, Ss, SsN)
        return cons
    Ci = np.ascontiguousarray(np.concatenate([pt.Cx[:, L.ineq], pt.Cu[:, L.ineq]], axis=2))
    return Constraints(np.ascontiguousarray(pt.Cx[:, L.eq]), np.ascontiguousarray(pt.Cu[:, L.eq]),
                       np.ascontiguousarray(pt.CN[L.eqN]), Ci, np.ascontiguousarray(pt.CN[L.ineqN]), Ss, SsN)


def newton_system(setup, st, gradient=False):
    """The iteration's KKT matrix (Hessian blocks of the Lagrangian at (pt, multipliers), Sigma)
    factored with the inertia correction; None when Algorithm IC gives up. With ``gradient``:
    (the matrix or None, :func:`barrier_gradient` at the iterate), its Sigma and the gradient in
    one compiled pass (kernels.newton_terms)."""
    p, pt, L = setup.problem, st.pt, setup.layout
    Lg, LgN = full_multipliers(L, st)
    # the previous iteration's back-end is taken over, unless the watchdog keeps that iteration's
    # direction (its line search may solve with it again, line_search); a matrix taken over has
    # let its blocks go (take_step; here after a restoration phase) before the new Hessians
    prev = setup.last_kkt
    if st.watch is not None and st.watch.search.kkt is prev:
        prev = None
    elif prev is not None:
        prev.release_blocks()
    t0 = time.perf_counter()
    Hxx, Hxu, Huu = p.eval_stage_hessians(pt.X, pt.U, st.s_obj, st.lam[1:], Lg)
    HN = p.eval_final_hessian(pt.X[-1], st.s_obj, LgN)
    st.clock.add(("hessian",), t0)
    ws = setup.ws
    Q = ws.hessian_blocks(prev, (L.N + 1, L.n, L.n))
    Q, S, R = stage_blocks(Hxx, Hxu, Huu, HN, Q)
    del Hxx                     # copied into Q: gone before Sigma's arrays and the factorization
    if gradient:
        Sx, Su, Ss, SsN, g = _newton_terms(setup, st)
    else:
        Sx, Su, Ss, SsN = setup.bounds.sigma_blocks(st.v, st.zl, st.zu, L)
    kkt = setup.last_kkt = ws.Q_owner = KKTMatrix(Q, S, R, pt.A, pt.B, Sx, Su, constraint_blocks(setup, pt, Ss, SsN),
                                                  reuse=prev)
    delta = kkt.factor(st.delta_last)
    st.factorizations += kkt.factorizations
    if delta is None:
        return (None, g) if gradient else None
    if not ws.reuse:            # (at small N the workspace keeps Q anyway)
        kkt.release_costs()     # the plain fixed-size recursion's solves read no cost blocks
    st.delta = delta
    if delta > 0.0:       # delta_w^last of Algorithm IC: the last shift that was needed (IC-4)
        st.delta_last = delta
    return (kkt, g) if gradient else kkt


def _newton_terms(setup, st):
    """(Sx, Su, Ss, SsN) of Bounds.sigma_blocks and :func:`barrier_gradient` at the iterate, in one
    compiled pass (kernels.newton_terms: the two kernels in turn), into the workspace's arrays."""
    b, pt, mu = setup.bounds, st.pt, st.mu
    sl, su = b.slacks(st.v)
    Sx, Su, Ss, SsN, q, r, gs, gsN, grad = setup.ws.newton()
    _kernels().newton_terms(float(st.s_obj), pt.lx, pt.lN, pt.lu, sl, su, st.zl, st.zu, b.has_lo,
                            b.has_hi, mu, KAPPA_D * mu, Sx, Su, Ss, SsN, q, r, gs, gsN, grad)
    return Sx, Su, Ss, SsN, Direction(q, r, gs, gsN, grad)


def update_barrier(setup, st):
    """The monotone rule (7): while the barrier problem is solved to kappa_eps mu, mu <- max(tol / 10,
    min(kappa_mu mu, mu^theta_mu)), tau <- max(tau_min, 1 - mu), and the filter starts afresh."""
    o = setup.options
    while optimality_errors(setup, st, st.mu)[0] <= o.barrier_tol_factor * st.mu:
        mu = max(o.tol / 10.0, min(o.mu_linear_decrease_factor * st.mu, st.mu ** o.mu_superlinear_decrease_power))
        if mu >= st.mu:
            break
        set_mu(setup, st, mu, max(o.tau_min, 1.0 - mu))


def set_mu(setup, st, mu, tau):
    """A new barrier parameter: mu, tau, the filter cleared, the restoration problem's objective
    told (Setup.on_mu_change)."""
    st.mu, st.tau = mu, tau
    st.filt.reset()
    if setup.on_mu_change is not None:
        setup.on_mu_change()
        st.error_cache = None       # the objective followed mu in place: its dual infeasibility changed


def adaptive_barrier(setup, st, kkt):
    """IPOPT's adaptive update (olado.solvers.ipm.adaptive; AdaptiveMuUpdate::UpdateBarrierParameter):
    the obj-constr filter decides between the free mode (mu from the quality-function oracle on
    the factored Newton matrix ``kkt``, tau = max(tau_min, 1 - E_0)) and the monotone mode (mu =
    0.8 avg(s z), then rule (7)); the filter of the line search is cleared whenever mu is set."""
    o, b = setup.options, setup.bounds
    ad = st.adaptive = st.adaptive or AdaptiveMu()
    mu_min = min(MU_MIN, 0.5 * min(o.tol, o.compl_inf_tol * st.s_obj))
    if b.count == 0:
        st.mu, st.tau = mu_min, o.tau_min
        return
    avg = average_complementarity(b, st.v, st.zl, st.zu)
    if ad.mu_max < 0:
        ad.mu_max = MU_MAX_FACT * avg
    f, th = st.s_obj * st.pt.J, theta(setup, st.pt, st.v)
    e0 = optimality_errors(setup, st, 0.0)[0]
    progress = ad.acceptable(f, th, FILTER_MARGIN_FACT * min(FILTER_MAX_MARGIN, e0))
    if progress:
        ad.free = True
        ad.remember(f, th)
    elif ad.free:       # no progress: the monotone mode from mu = 0.8 avg(s z)
        ad.free = False
        mu = min(max(MONOTONE_INIT_FACTOR * avg, mu_min), ad.mu_max)
        set_mu(setup, st, mu, max(o.tau_min, 1.0 - mu))
        return
    else:               # the monotone mode: rule (7), once per iteration
        if optimality_errors(setup, st, st.mu)[0] <= o.barrier_tol_factor * st.mu:
            mu = min(o.mu_linear_decrease_factor * st.mu, st.mu ** o.mu_superlinear_decrease_power)
            mu = max(mu, min(o.compl_inf_tol * st.s_obj, o.tol) / (o.barrier_tol_factor + 1.0))
            set_mu(setup, st, mu, max(o.tau_min, 1.0 - mu))
        return
    tau = max(o.tau_min, 1.0 - e0)
    st.tau = tau
    res = residuals(setup, st.pt, st.v)
    dv0, dv1 = (step_vector(setup, kkt.solve(g.q, g.r, res, g.gs, g.gsN))
                for g in (barrier_gradient(setup, st, 0.0), barrier_gradient(setup, st, avg)))
    dual = lagrangian_gradient(setup, st) - st.zl + st.zu
    q = QualityFunction(b, st.v, st.zl, st.zu, tau, avg, dv0, dv1, dual, res)
    sigma = quality_function_sigma(q, avg, mu_min, ad.mu_max)
    set_mu(setup, st, min(max(sigma * avg, mu_min), ad.mu_max), tau)


def converged(setup, st):
    """IPOPT's stopping test: E_0 <= tol and the unscaled dual infeasibility, constraint
    violation and complementarity within dual_inf_tol, constr_viol_tol, compl_inf_tol; or
    acceptable_iter acceptable iterates in a row."""
    o = setup.options
    e0, inf_du, inf_pr, compl = st.errors = optimality_errors(setup, st, 0.0)
    if e0 <= o.tol and inf_du <= o.dual_inf_tol and inf_pr <= o.constr_viol_tol and compl <= o.compl_inf_tol:
        return _stop_optimal(setup, st)
    if e0 <= o.acceptable_tol and inf_pr <= max(o.constr_viol_tol, 1e-2 * o.acceptable_tol ** 0.5):
        st.acceptable += 1
        if o.acceptable_iter and st.acceptable >= o.acceptable_iter:
            return _stop_acceptable(setup, st)
    else:
        st.acceptable = 0
    return False


def _stop_optimal(setup, st):
    return st.stop(Status.SUCCESS, f"optimal: scaled optimality error {st.errors[0]:.2e} <= tol = "
                   f"{setup.options.tol:g} after {st.it} iterations")


def _stop_acceptable(setup, st):
    o = setup.options
    return st.stop(Status.ACCEPTABLE, f"acceptable: {st.acceptable} iterates in a row with scaled optimality "
                   f"error <= acceptable_tol = {o.acceptable_tol:g} (last {st.errors[0]:.2e}), tol = {o.tol:g} not met")


def _stop_iterations(setup, st):
    return st.stop(Status.MAX_ITERATIONS, f"iteration limit {setup.options.max_iter} reached; scaled optimality "
                   f"error {st.errors[0]:.2e}, constraint violation {st.errors[2]:.2e}")


def barrier_gradient(setup, st, mu=None) -> Direction:
    """grad phi_mu at the iterate (mu: the iterate's unless given), split for the Newton system."""
    L, b, pt = setup.layout, setup.bounds, st.pt
    mu = st.mu if mu is None else mu
    # s_f grad J (objective_gradient) plus the barrier gradient (Bounds.gradient), split and
    # packed, in one compiled pass (the same operations)
    sl, su = b.slacks(st.v)
    q, r = np.empty((L.N + 1, L.n)), np.empty((L.N, L.m))
    gs, gsN, grad = np.empty((L.N, L.ni)), np.empty(L.niN), np.empty(L.size)
    s_obj = float(st.s_obj)
    _kernels().barrier_direction(s_obj, pt.lx, pt.lN, pt.lu, sl, su, b.has_lo, b.has_hi, mu, KAPPA_D * mu,
                                 q, r, gs, gsN, grad)
    return Direction(q, r, gs, gsN, grad)


def take_step(setup, st, accepted):
    """Accept a step: the primal variables, every constraint multiplier y <- y + alpha (y_new - y),
    the bound multipliers by their own fraction-to-boundary step (eqs. (14)-(15)) and the
    safeguard (16)."""
    b = setup.bounds
    v_new, pt_new, dv, step, alpha, soc = accepted
    slacks = b.slacks(st.v)     # the step of the bound multipliers is taken at the old point's
    if setup.layout.rows:
        for name in ("nu", "nuN", "yd", "ydN"):
            old = getattr(st, name)
            if old.size:            # an empty one (no such rows) stays
                setattr(st, name, old + alpha * (getattr(step, name) - old))
    st.v, st.pt = v_new, pt_new
    # before the new point's derivatives: the iteration's Newton matrix lets its blocks go (the
    # next one takes its back-end over) and the caches keyed by the old point are dropped (the
    # pass below makes the new point's), so the old point's derivatives go with them
    # (at small N the workspace keeps Sigma's arrays and the slacks' anyway: those stay)
    kkt, large = setup.last_kkt, not setup.ws.reuse
    if kkt is not None and (st.watch is None or st.watch.search.kkt is not kkt):   # (newton_system's test)
        kkt.release_blocks(sigma=large)
    st.error_cache = st.compl_cache = None
    st.pt.add_derivatives(setup.problem)
    # lam + alpha (lam^+ - lam), dz and the step of both sides (dz = 0 off the bounds:
    # Bounds.dual_step_length), the bounds moved (Bounds.move_tiny) and the safeguard
    # (Bounds.safeguard_step) in one compiled pass
    st.zl, st.zu, alpha_z, lam = b.step_multipliers(slacks, v_new, dv, st.zl, st.zu, st.mu, st.tau, st.lam, step.lam,
                                                    alpha, out=setup.ws.multiplier_arrays(st))
    if lam.size:                # an empty one stays
        st.lam = lam
    # the optimality error's pass at the new iterate now (the next stopping test's: error_terms
    # finds it), while its arrays are in cache
    store_errors(setup, st, iterate_errors(setup, st))
    if large:
        b.keep_only(v_new)      # the old point's slacks served the multiplier step
    return alpha, alpha_z, soc


def iterate(setup, st):
    """One iteration of Algorithm A; True when the solve ends. Where it applies, the compiled
    iteration (.compiled.PlainPath) takes it, and hands the uncommon ones back after the
    stopping test and the barrier update (:func:`_body`)."""
    o = setup.options
    setup.limits.check()
    plain = setup.plain
    if plain is not None and st.watch is None and setup.on_mu_change is None:
        done = plain.iterate(st)
        if done is not None:
            return _after_compiled(setup, st, *done)
    if converged(setup, st):
        return True
    if st.it >= o.max_iter:
        return _stop_iterations(setup, st)
    if o.mu_strategy == "monotone":
        update_barrier(setup, st)
    return _body(setup, st)


def _after_compiled(setup, st, code, rows):
    """The solver's part of compiled iterations: the history entries of the steps taken (``rows``,
    iteration_kernels.plain_iteration's), then what the last one's ``code`` says."""
    for it, inf_pr, inf_du, mu, alpha, alpha_z, J in rows:
        if _record(setup, st, {"iter": int(it), "inf_pr": inf_pr, "inf_du": inf_du, "mu": mu, "delta_w": 0.0,
                               "watchdog": False, "alpha": alpha, "alpha_z": alpha_z, "soc": 0,
                               "restoration": False, "objective": J}):
            return True         # (the callback stopped the solve: one step per call then)
    if code == _IK.STEP:
        return False
    if code == _IK.SUCCESS:
        return _stop_optimal(setup, st)
    if code == _IK.ACCEPTABLE_END:
        return _stop_acceptable(setup, st)
    if code == _IK.MAX_ITERATIONS:
        return _stop_iterations(setup, st)
    return _body(setup, st)         # handed back after the stopping test and the barrier update


def _body(setup, st):
    """Algorithm A after the stopping test and the monotone barrier update: the Newton system,
    the line search, the step (or the restoration phase)."""
    o = setup.options
    if o.mu_strategy == "adaptive":
        kkt = newton_system(setup, st)      # the matrix does not depend on mu: the oracle uses it
        if kkt is not None:
            adaptive_barrier(setup, st, kkt)
        g = None if kkt is None else barrier_gradient(setup, st)
    else:
        kkt, g = newton_system(setup, st, gradient=True)
    factored = kkt is not None
    accepted = None if kkt is None else line_search(setup, st, kkt, g)
    # (the matrix stays as setup.last_kkt for the next one to take its back-end over; take_step
    # lets its blocks go before the new point's derivatives)
    del kkt
    st.it += 1
    # the objective after the iteration (IPOPT's log), the errors at its start
    entry = {"iter": st.it, "inf_pr": st.errors[2], "inf_du": st.errors[1], "mu": st.mu, "delta_w": st.delta,
             "watchdog": st.watch is not None}
    if accepted is None and st.acceptable:
        # IPOPT's ACCEPTABLE_POINT_REACHED: no restoration phase from an acceptable iterate
        st.history.append(dict(entry, alpha=float("nan"), alpha_z=float("nan"), soc=0, restoration=False,
                               objective=float(st.pt.J)))
        return st.stop(Status.ACCEPTABLE, f"acceptable: the line search failed at an iterate with scaled "
                       f"optimality error {st.errors[0]:.2e} <= acceptable_tol = {o.acceptable_tol:g} after "
                       f"{st.it} iterations (tol = {o.tol:g} not met)")
    if accepted is None:
        why = ("the inertia correction found no shift up to 1e20" if not factored
               else "the filter line search reached alpha_min")
        st.filt.add(theta(setup, st.pt, st.v), barrier_value(setup, st.pt, st.v, st.mu, st.s_obj)[0])
        st.restorations += 1
        setup.ws.detach()           # nothing of the iteration's arrays is reused across the phase
        fns = Restoration(evaluate, theta, barrier_value, residuals, lagrangian_gradient)
        # the entry of the phase's start (IPOPT's "r" line: the point where it starts); the l1
        # phase appends one entry per iteration of the restoration problem after it
        entry.update(restoration=True, alpha=float("nan"), alpha_z=float("nan"), soc=0, objective=float(st.pt.J))
        st.history.append(entry)
        outcome = (restore_l1 if setup.l1_restoration else restore)(setup, st, fns)
        if outcome is not None:
            return st.stop(*outcome(why))
    else:
        alpha, alpha_z, soc = take_step(setup, st, accepted)
        entry.update(alpha=alpha, alpha_z=alpha_z, soc=soc, restoration=False, objective=float(st.pt.J))
        st.history.append(entry)
    return _report(setup, st, entry)


def _record(setup, st, entry):
    """A step's history entry, then :func:`_report`."""
    st.history.append(entry)
    return _report(setup, st, entry)


def _report(setup, st, entry):
    """The iteration's log line (verbose >= 2) and the callback; True when the callback stops."""
    o = setup.options
    if o.verbose >= 2:
        plain = setup.plain     # (while compiled iterations run, the iterate is theirs)
        J = float(plain.sc[_IK.J]) if plain is not None and plain.active else st.pt.J
        print(f"{st.it:4d} {J: .10e} {st.errors[2]:.2e} {st.errors[1]:.2e} mu={st.mu:.1e} "
              f"dw={st.delta:.1e} a={entry['alpha']:.2e}{' soc' if entry['soc'] else ''}"
              f"{' resto' if entry['restoration'] else ''}")
    # (without a callback option the solver's callback says False: no copy of the entry for it)
    if o.callback is not None and setup.callback(dict(entry)):
        return st.stop(Status.USER_STOP, f"stopped by the callback after {st.it} iterations")
    return False


# ---------------------------------------------------------------------------- the result
def finish(setup, st) -> Result:
    """The Result at the last accepted iterate: multipliers of the unscaled problem, KKT
    quantities stage by stage (olado.solvers.sqp.residuals.stage_kkt)."""
    plain = setup.plain
    if plain is not None:
        if plain.active:
            plain.leave(st)         # the iterate of the compiled iterations
        plain.release()
        setup.plain = None
    p, pt, L = setup.problem, st.pt, setup.layout
    solve_time = time.perf_counter() - setup.t_start
    setup.last_kkt = None       # the last matrix's factors and blocks go before stage_kkt's arrays
    pt.add_derivatives(p)
    zero_x = np.zeros(p.n)
    zl_x, zl_u, _, _ = L.split(st.zl / st.s_obj, zero_x)
    zu_x, zu_u, _, _ = L.split(st.zu / st.s_obj, zero_x)
    Lg, LgN = full_multipliers(L, st)
    mult = Multipliers(st.lam / st.s_obj, Lg / st.s_obj, LgN / st.s_obj)
    kkt = stage_kkt(p, pt, mult, BoundMultipliers(zl_x, zu_x, zl_u, zu_u))
    z = kkt.bounds
    clock = st.clock
    info = {"callback_time_s": clock.time_s, "solve_time_s": solve_time,
            "callback_share": clock.time_s / solve_time if solve_time > 0 else float("nan"),
            "kkt_residual_kind": "max-norm of stationarity and complementarity at the final point (unscaled)",
            "stationarity_residual": kkt.stationarity, "complementarity_residual": kkt.complementarity,
            "multiplier_convention": MULTIPLIER_CONVENTION, "mu": st.mu, "objective_scaling": st.s_obj,
            "factorizations": st.factorizations, "restorations": st.restorations,
            "scaled_optimality_error": st.errors[0], "kkt": "riccati",
            # the evaluations inside them are counted, not timed (callback_time_s leaves them out)
            "compiled_iterations": st.compiled_steps}
    if st.infeasibility_certificate is not None:
        info["infeasibility_certificate"] = dict(st.infeasibility_certificate)
    multipliers = {"dynamics": mult.lam[1:].copy(), "stage_constraints": mult.Lg, "final_constraints": mult.LgN,
                   "bound_lower_x": z.zl_x, "bound_lower_u": z.zl_u, "bound_upper_x": z.zu_x, "bound_upper_u": z.zu_u}
    return Result(status=st.status, message=st.message, objective=float(pt.J), x=pt.X.copy(), u=pt.U.copy(),
                  multipliers=multipliers, max_constraint_violation=kkt.violation,
                  kkt_residual=max(kkt.stationarity, kkt.complementarity), iterations=int(st.it),
                  evaluations={k: int(clock.counts[k]) for k in EVALUATION_KINDS}, history=list(st.history),
                  info=info)


class IPMSolver(Solver):
    """IPOPT's primal-dual interior-point filter method on the Riccati KKT back-end."""

    name = "ipm"
    Options = IPMOptions

    def _solve(self, problem, X0, U0):
        limits = Limits(self.options.max_time)
        setup = Setup(self.options, problem, limits, self._call_callback)
        st = run_iterations(limits, lambda: initial_state(setup, X0, U0, Clock(limits)),
                            lambda st: iterate(setup, st), lambda: initial_state(setup, X0, U0, Clock(None)),
                            lambda st: f"after {st.it} iterations")
        return finish(setup, st)
