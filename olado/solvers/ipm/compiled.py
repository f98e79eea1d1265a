"""The interior-point solver's common iteration compiled (:mod:`.iteration_kernels`; up to
:data:`BATCH` iterations per call) for small problems that hand their evaluations over as compiled
functions (:meth:`olado.problems.docp.DOCP.compiled_evaluations`): at small N an iteration of the
Python path is mostly the Python between its fifteen compiled passes, not their arithmetic.

:class:`PlainPath` holds the iterate in its own arrays while the compiled iterations run (two
sets: the iterate and the trial point, swapped when a step is taken) and keeps the solver's
state (:class:`.solver.IPMState`) current in its counters, barrier parameter, errors and history;
the iterate's arrays, point and filter go back into the state (:meth:`PlainPath.leave`, copies)
whenever the Python path takes over -- an iteration the compiled one hands back (inertia
correction, second-order correction, watchdog, tiny step, a trial point that is not finite,
restoration), the end of the solve, an interrupt -- and are read from it again (copies) when the
compiled iterations resume. The numbers are the Python path's, bit for bit (tests/solvers/ipm/
test_compiled_iteration.py).
"""

from __future__ import annotations

import threading
from typing import NamedTuple

import numpy as np

from ...errors import NonFiniteEvaluationError
from ..sqp.state import _DERIVATIVE_KINDS, _VALUE_KINDS, Point
from . import iteration_kernels as IK
from .barrier import EPS, KAPPA_D
from .evaluation import residual_norms
from .filter import FilterConstants
from .linesearch import TINY_STEP

#: the Clock's evaluation kinds of one call of each compiled function (those sqp.state.Point and
#: solver.newton_system count)
_CLOCK_KINDS = {"values": _VALUE_KINDS, "derivatives": _DERIVATIVE_KINDS, "hessians": ("hessian",)}

#: the iterations one compiled call takes at most (the time limit and interrupts are checked
#: between calls: at PLAIN_MAX entries an iteration is about 0.5 ms)
BATCH = 8

#: the largest flat iterate (entries) the compiled iteration takes (zambezi N <= 315): where it
#: pays. Measured on zambezi12 against the Python path in one process (RESULTS.md, "ipm's common
#: iteration compiled"): 0.45 of its time at N = 24, 0.65 at 120, 0.75 at 252, but about 1.1 at
#: N = 1 200 (not understood yet; the arithmetic is the same); above it the Python path also lets
#: blocks go between iterations (less memory at its peak)
PLAIN_MAX = 4096


def plain_path(setup):
    """The :class:`PlainPath` of a solve, or None where the compiled iteration does not apply:
    the adaptive barrier update, stage or final constraint rows, a problem without compiled
    evaluations, blocks beyond the fixed-size Riccati kernels, n or m below 2 (the error pass's
    products then follow numpy's einsum in SIMD lanes), or a flat iterate above PLAIN_MAX entries."""
    o, L, p = setup.options, setup.layout, setup.problem
    if o.mu_strategy != "monotone" or L.rows or L.size > PLAIN_MAX or L.n < 2 or L.m < 2:
        return None
    get = getattr(p, "compiled_evaluations", None)
    evals = get() if get is not None else None
    if evals is None:
        return None
    from ...problems.compiled import DERIVATIVES, FINAL_HESSIAN, HESSIANS, VALUES  # noqa: PLC0415

    for f, signature in zip((evals.values, evals.derivatives, evals.hessians, evals.final_hessian),
                            (VALUES, DERIVATIVES, HESSIANS, FINAL_HESSIAN)):
        if f.signature() != signature:      # the kernel calls the address with this signature
            raise TypeError(f"{type(p).__name__}.compiled_evaluations: {f!r} has the signature {f.signature()}, "
                            f"not {signature}")
    arrays = _take((L.N, L.n, L.m, L.size, o.max_iter))
    return None if arrays is None else PlainPath(setup, evals, arrays)


class _Arrays(NamedTuple):
    """What a :class:`PlainPath` works on that depends on the shapes only: the Riccati back-end's
    operands (fixed_factor_operands; the back-end object keeps them), the addresses of the kernels
    plain_iteration calls (iteration_kernels.kernel_addresses: they depend on the sizes), the two
    point sets, the two multiplier sets and the filter's (plain_iteration makes its scratch arrays
    itself)."""

    fact: object
    operands: tuple
    kernels: np.ndarray
    cur: tuple
    trial: tuple
    mult: tuple
    mult_new: tuple
    F: np.ndarray

    @classmethod
    def make(cls, N, n, m, size, max_iter):
        """New arrays, or None where the fixed-size straight-line Riccati kernels do not apply."""
        from ...linalg.riccati import RiccatiFactorization  # noqa: PLC0415

        eye = np.broadcast_to(np.eye(n), (N + 1, n, n)).copy()
        fact = RiccatiFactorization(eye, np.zeros((N, n, m)), np.broadcast_to(np.eye(m), (N, m, m)).copy(),
                                    np.zeros((N, n, n)), np.zeros((N, n, m)), Dx=np.ones((N + 1, n)),
                                    Du=np.ones((N, m)))
        operands = fact.fixed_factor_operands()
        if operands is None:
            return None
        lam_shape = (N + 1, n)
        tags, ipt, _, fac = operands
        kernels = np.array(IK.kernel_addresses(tags, ipt, fac), dtype=np.int64)
        return cls(fact, operands, kernels, _point_set(N, n, m, size, False), _point_set(N, n, m, size, True),
                   (np.empty(lam_shape), np.empty(size), np.empty(size)),
                   (np.empty(lam_shape), np.empty(size), np.empty(size)), np.empty((max_iter + 8, 2)))


def _point_set(N, n, m, size, trial):
    """(v, X, U, h, lx, lu, lN, A, B, s_L, s_U); the trial set has f and the stage costs after h."""
    head = (np.empty(size), np.empty((N + 1, n)), np.empty((N, m)))
    values = (np.empty((N, n)), np.empty((N, n)), np.empty(N)) if trial else (np.empty((N, n)),)
    return head + values + (np.empty((N, n)), np.empty((N, m)), np.empty(n), np.empty((N, n, n)),
                            np.empty((N, n, m)), np.empty(size), np.empty(size))


#: the arrays of finished solves, one set per key (N, n, m, size, max_iter), the POOL_MAX latest keys:
#: a solve takes a set (or makes one) and gives it back when it ends; each is written before it is
#: read, and nothing a Result holds is one of them (PlainPath.leave copies)
_POOL: dict = {}
_POOL_LOCK = threading.Lock()
POOL_MAX = 4


def _take(key):
    with _POOL_LOCK:
        arrays = _POOL.pop(key, None)
    return arrays if arrays is not None else _Arrays.make(*key)


def _give(key, arrays):
    with _POOL_LOCK:
        _POOL[key] = arrays
        while len(_POOL) > POOL_MAX:
            del _POOL[next(iter(_POOL))]


class PlainPath:
    """The compiled iterations of one solve (module docstring)."""

    def __init__(self, setup, evals, arrays):
        o, L, b = setup.options, setup.layout, setup.bounds
        self.setup, self.evals, self.arrays = setup, evals, arrays
        self.key = (L.N, L.n, L.m, L.size, o.max_iter)
        self.tags, self.ipt, self.reg, self.fac = arrays.operands
        #: the functions' wrapper addresses (iteration_kernels calls them there; the CompiledFunctions
        #: in ``evals`` keep the code alive), then the kernels' (iteration_kernels.KERNELS)
        functions = (evals.values, evals.derivatives, evals.hessians, evals.final_hessian)
        self.addresses = np.concatenate((np.array([f.__wrapper_address__() for f in functions], dtype=np.int64),
                                         arrays.kernels))
        self.cur, self.trial, self.mult, self.mult_new = arrays.cur, arrays.trial, arrays.mult, arrays.mult_new
        self.F = arrays.F
        self.bounds = (b.lo, b.hi, b.has_lo, b.has_hi, b.one_lo_f, b.one_hi_f)
        self.x0 = L.x0
        self.sc, self.ic = np.zeros(IK.N_SC), np.zeros(IK.N_IC, dtype=np.int64)
        #: the history rows of the steps one call takes (iteration_kernels.plain_iteration): one
        #: with a callback or a log line per iteration, else up to BATCH
        steps = 1 if o.callback is not None or o.verbose >= 2 else BATCH
        self.H = np.empty((steps, IK.N_H))
        self.opt = self._options(o, L, b)
        self.active = False

    def release(self):
        """The arrays back to the pool (the solve has ended; the state holds copies)."""
        self.active = False
        a = self.arrays
        _give(self.key, _Arrays(a.fact, a.operands, a.kernels, self.cur, self.trial, self.mult, self.mult_new, self.F))

    @staticmethod
    def _options(o, L, b):
        f = FilterConstants()
        opt = np.zeros(IK.N_OPT)
        for slot, value in ((IK.TOL, o.tol), (IK.DUAL_INF_TOL, o.dual_inf_tol), (IK.CONSTR_VIOL_TOL, o.constr_viol_tol),
                            (IK.COMPL_INF_TOL, o.compl_inf_tol), (IK.ACC_TOL, o.acceptable_tol),
                            (IK.ACC_VIOL, max(o.constr_viol_tol, 1e-2 * o.acceptable_tol ** 0.5)),
                            (IK.ACC_ITER, o.acceptable_iter), (IK.KAPPA_EPS, o.barrier_tol_factor),
                            (IK.KAPPA_MU, o.mu_linear_decrease_factor), (IK.THETA_MU, o.mu_superlinear_decrease_power),
                            (IK.TAU_MIN, o.tau_min), (IK.MAX_SOC, o.max_soc),
                            (IK.WD_TRIGGER, o.watchdog_shortened_iter_trigger), (IK.MAX_ITER, o.max_iter),
                            (IK.GAMMA_THETA, f.gamma_theta), (IK.GAMMA_PHI, f.gamma_phi), (IK.DELTA, f.delta),
                            (IK.S_THETA, f.s_theta), (IK.S_PHI, f.s_phi), (IK.ETA_PHI, f.eta_phi),
                            (IK.GAMMA_ALPHA, f.gamma_alpha), (IK.OBJ_MAX_INC, f.obj_max_inc),
                            (IK.RESET_TRIGGER, f.filter_reset_trigger), (IK.MAX_RESETS, f.max_filter_resets),
                            (IK.KAPPA_D, KAPPA_D), (IK.NZ, max(b.count, 1)), (IK.NY, L.N * L.n),
                            (IK.ONE_SIDED, float(b.one_sided)), (IK.EPS, EPS), (IK.EPS_MOVE, EPS ** 0.75),
                            (IK.TINY, TINY_STEP), (IK.PRODUCTS, 1.0), (IK.ROWS, 0.0)):
            # (the error pass's flags as data, not constants: the pass then has the Python path's
            # argument types, and its compiled version is shared, not compiled again)
            opt[slot] = value
        return opt

    # ------------------------------------------------------------------------ the state in and out
    def enter(self, st):
        """Copy the iterate of ``st`` into the arrays (False, nothing copied, when its barrier terms
        are not finite: the Python path then goes on)."""
        setup = self.setup
        b, pt, v = setup.bounds, st.pt, st.v
        terms = b.barrier_terms(v)
        if terms is None or st.filt.const != FilterConstants() or len(st.filt.entries) > self.F.shape[0]:
            return False
        pt.add_derivatives(setup.problem)
        sl, su = b.slacks(v)
        for dst, src in zip(self.cur, (v, pt.X, pt.U, pt.h, pt.lx, pt.lu, pt.lN, pt.A, pt.B, sl, su)):
            np.copyto(dst, src)
        for dst, src in zip(self.mult, (st.lam, st.zl, st.zu)):
            np.copyto(dst, src)
        theta, mx = residual_norms(setup, pt, v)
        sc, ic, f = self.sc, self.ic, st.filt
        sc[[IK.MU, IK.TAU, IK.S_OBJ, IK.J, IK.LOGS, IK.DAMPED, IK.THETA, IK.MX, IK.THETA_MAX, IK.THETA_MIN]] = (
            st.mu, st.tau, st.s_obj, pt.J, terms[0], terms[1], theta, mx, f.theta_max, f.theta_min)
        ic[:] = 0
        ic[[IK.IT, IK.ACCEPTABLE, IK.SHORTENED, IK.NF, IK.RESETS, IK.REJECTED, IK.FILTER_REJECTIONS]] = (
            st.it, st.acceptable, st.shortened, len(f.entries), f.resets, f.rejected_by_filter, f.filter_rejections)
        self.F[:len(f.entries)] = f.entries
        self.active = True
        return True

    def leave(self, st):
        """The iterate back into ``st`` (copies: the state never holds these arrays)."""
        setup, L = self.setup, self.setup.layout
        v, X, U, h, lx, lu, lN, A, B, _, _ = self.cur
        sc, ic = self.sc, self.ic
        no_g, no_gN = L.no_rows[:2]                     # (no constraint rows: the Layout's empty arrays)
        no_Cx, no_Cu, no_CN = L.no_constraint_rows[:3]
        pt = Point.evaluated(st.clock, X.copy(), U.copy(), (float(sc[IK.J]), h.copy(), no_g, no_gN),
                             (lx.copy(), lu.copy(), lN.copy(), A.copy(), B.copy(), no_Cx, no_Cu, no_CN))
        st.v, st.pt = v.copy(), pt
        st.lam, st.zl, st.zu = (a.copy() for a in self.mult)
        self._state_scalars(st)
        self._count(st)
        f = st.filt
        f.entries = [(float(t), float(p)) for t, p in self.F[:ic[IK.NF]]]
        f.resets, f.rejected_by_filter, f.filter_rejections = (int(ic[IK.RESETS]), bool(ic[IK.REJECTED]),
                                                               int(ic[IK.FILTER_REJECTIONS]))
        st.error_cache = st.compl_cache = None
        setup.bounds._points = []       # (its lo, hi are the arrays the compiled steps moved)
        setup.last_kkt = None
        self.active = False

    def _state_scalars(self, st):
        """The counters, barrier parameter, errors of the compiled iterations into ``st``."""
        sc, ic = self.sc, self.ic
        st.mu, st.tau = float(sc[IK.MU]), float(sc[IK.TAU])
        st.errors = (float(sc[IK.E0]), float(sc[IK.INF_DU]), float(sc[IK.INF_PR]), float(sc[IK.COMPL]))
        st.it, st.acceptable, st.shortened = int(ic[IK.IT]), int(ic[IK.ACCEPTABLE]), int(ic[IK.SHORTENED])

    # ------------------------------------------------------------------------ one iteration
    def iterate(self, st):
        """Compiled iterations (iteration_kernels.plain_iteration): (the last one's return code --
        STEP, SUCCESS, ACCEPTABLE_END, MAX_ITERATIONS, or >= BAIL, that iteration left to the
        Python path with the state back in ``st`` --, the history rows of the steps taken); None
        when the iterate cannot enter (the Python path goes on)."""
        if not self.active and not self.enter(st):
            return None
        ev, H = self.evals, self.H
        code, steps = IK.plain_iteration(self.addresses, ev.data, ev.idata, self.tags, self.ipt, self.reg, self.fac,
                                         self.F, self.cur, self.trial, self.mult, self.mult_new, self.bounds, self.x0,
                                         self.sc, self.ic, self.opt, H)
        if steps % 2:
            self._swap()
        if steps:
            st.delta = 0.0
            st.compiled_steps += steps
        if code == IK.DERIVATIVES_NOT_FINITE:
            self._raise_not_finite()
        self._state_scalars(st)
        if code >= IK.BAIL:
            self.leave(st)
        return code, H[:steps].tolist()

    def _count(self, st):
        """The evaluations and factorizations of the steps taken since :meth:`enter` into the
        solve's clock, the problem's counters and ``st`` (once, when the state goes back)."""
        ic, counts, counters = self.ic, st.clock.counts, self.setup.problem.counters
        st.factorizations += int(ic[IK.FACTORIZATIONS])
        for name, calls in (("values", ic[IK.N_VALUES]), ("derivatives", ic[IK.N_DERIVS]),
                            ("hessians", ic[IK.N_HESS]), ("final_hessian", ic[IK.N_HESS])):
            calls = int(calls)
            for key in _CLOCK_KINDS.get(name, ()):
                counts[key] += calls
            for key in self.evals.counters[name]:
                counters[key] += calls

    def _swap(self):
        """The trial point becomes the iterate (its f and stage costs stay with the trial set), the
        new multipliers the iterate's."""
        c, t = self.cur, self.trial
        self.cur = t[:3] + (t[4],) + t[6:]
        self.trial = c[:3] + (t[3], c[3], t[5]) + c[4:]
        self.mult, self.mult_new = self.mult_new, self.mult

    def _raise_not_finite(self):
        """The derivatives at an accepted trial point are not finite: the problem's own entry point
        names the function, stage and array (as the Python path's evaluation does)."""
        X, U = self.trial[1], self.trial[2]
        self.setup.problem.eval_first_derivatives(X.copy(), U.copy())
        raise NonFiniteEvaluationError("the first derivatives are not finite at the accepted trial point")
