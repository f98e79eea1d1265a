"""One common iteration of the interior-point solver as one compiled call
(:mod:`olado.solvers.ipm.compiled`; Waechter and Biegler 2006, Math. Program. 106, 25-57,
Algorithm A; docs/interior-point-nlp.md): the stopping test and the monotone barrier update
(rule (7)), the Newton matrix with delta_w = 0 on the fixed-size Riccati kernels (eqs. (11)-(13)),
the direction, the fraction-to-boundary rule (15), the filter line search (sec. 2.3, eqs.
(18)-(23)) and the step of the multipliers (eqs. (14)-(16)), calling the problem's compiled
evaluations through first-class function pointers (olado.problems.compiled).

It is the Python path's iteration (solver.iterate) operation by operation: the same kernels
(kernels.py, the Riccati kernels of olado.linalg.riccati_fixed) and the same float expressions in
the same order, so the iterates are the same bit for bit. What it does not do it hands back
after the stopping test and the barrier update, before anything else changes (a return code >=
BAIL): the inertia correction with delta_w > 0, the tiny step, the watchdog, second-order
corrections, a trial point that is not finite, Hessians that are not, the restoration phase; the
Python path then does the rest of that iteration.

The problem's functions are not compiled into it: it calls them at their addresses
(:func:`_function_at`). Nor are the kernels of kernels.py and riccati_fixed.py (:data:`KERNELS`):
it calls their compiled versions -- the ones the Python path compiles and caches, for the same
argument types -- at their addresses (:func:`_native_at`, :func:`kernel_addresses`), so that its
own compilation does not link their code in and optimize it all once more (that took most of its
cold compilation). numba caches a kernel keyed on its own source file; a change of those kernels
needs none here (the addresses are looked up in each process) unless their types change:
:data:`KERNELS` declares them (kernel_addresses checks the return types; a call with other
argument types does not compile).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np
from numba.core import cgutils, types
from numba.core.errors import TypingError
from numba.experimental.function_type import _get_jit_address
from numba.extending import intrinsic

from ...linalg.riccati_fixed import _factor_unconstrained_fixed, _solve_unconstrained_fixed
from ...problems.compiled import DERIVATIVES, FINAL_HESSIAN, HESSIANS, VALUES
from . import kernels as K
from .evaluation import S_MAX

_JIT = {"cache": True, "error_model": "numpy"}
#: plain_iteration's helpers: called from it only, so without the wrappers for calls from Python
#: and from C that numba makes otherwise (less to compile)
_INNER = {"no_cpython_wrapper": True, "no_cfunc_wrapper": True}

# ---------------------------------------------------------------------------- the slots
# sc: the iterate's floats (in and out)
MU, TAU, S_OBJ, J, LOGS, DAMPED, THETA, MX, THETA_MAX, THETA_MIN = range(10)
E0, INF_DU, INF_PR, COMPL, ALPHA, ALPHA_Z = range(10, 16)
N_SC = 16
# ic: the counters (in and out)
IT, ACCEPTABLE, SHORTENED, FACTORIZATIONS, NF, RESETS, REJECTED, FILTER_REJECTIONS = range(8)
N_VALUES, N_DERIVS, N_HESS = range(8, 11)
N_IC = 11
# opt: the options and constants (in)
(TOL, DUAL_INF_TOL, CONSTR_VIOL_TOL, COMPL_INF_TOL, ACC_TOL, ACC_VIOL, ACC_ITER, KAPPA_EPS, KAPPA_MU, THETA_MU,
 TAU_MIN, MAX_SOC, WD_TRIGGER, MAX_ITER, GAMMA_THETA, GAMMA_PHI, DELTA, S_THETA, S_PHI, ETA_PHI, GAMMA_ALPHA,
 OBJ_MAX_INC, RESET_TRIGGER, MAX_RESETS, KAPPA_D, NZ, NY, ONE_SIDED, EPS, EPS_MOVE, TINY, PRODUCTS, ROWS) = range(33)
N_OPT = 33

# the return codes: the iteration was taken; the solve ends; the Python path takes the iteration
STEP, SUCCESS, ACCEPTABLE_END, MAX_ITERATIONS = 0, 1, 2, 3
BAIL = 10
HESSIAN_NOT_FINITE, INERTIA, TINY_STEP, WATCHDOG, TRIAL_NOT_FINITE, SOC, RESTORATION, DERIVATIVES_NOT_FINITE = range(
    10, 18)


def _function_at(signature):
    """An intrinsic that makes the first-class function of ``signature`` at an address (an int64:
    problems.compiled.CompiledFunction's wrapper address), called through it as numba calls a
    compiled function passed as an argument -- without the per-call unboxing of one (a Python
    look-up of about 7 us per function and call)."""
    fn_type = types.FunctionType(signature)

    @intrinsic
    def at(typingctx, address):
        def codegen(context, builder, sig, args):
            f = cgutils.create_struct_proxy(fn_type)(context, builder)
            ptr = context.get_value_type(types.voidptr)
            f.c_addr = builder.inttoptr(args[0], ptr)
            f.py_addr = cgutils.get_null_value(ptr)
            f.jit_addr = cgutils.get_null_value(ptr)
            return f._getvalue()

        return fn_type(types.int64), codegen

    return at


_values_at, _derivatives_at, _hessians_at, _final_hessian_at = (_function_at(s)
                                                                 for s in (VALUES, DERIVATIVES, HESSIANS, FINAL_HESSIAN))


# ---------------------------------------------------------------------------- the kernels at their addresses
def _native_at(signature):
    """An intrinsic ``call(address, *args)`` that calls the compiled version of a numba function
    at ``address`` (its native entry, numba's own calling convention: tuples returned as they
    are, an error status passed on) with the argument types of ``signature`` -- a Signature, or a
    function of the argument types giving it (a kernel whose types depend on the sizes). The
    call's argument types must be those exactly (a typing error otherwise): the address is that
    of the version compiled for them (:func:`kernel_addresses`)."""
    def expected(args):
        return signature(args) if callable(signature) else signature

    @intrinsic
    def call(typingctx, address, *args):
        sig = expected(args)
        if tuple(args) != tuple(sig.args):
            raise TypingError(f"a native call with {args}: its compiled version takes {sig.args}")

        def codegen(context, builder, _, llargs):
            fnty = context.call_conv.get_function_type(sig.return_type, sig.args)
            ptr = builder.inttoptr(llargs[0], fnty.as_pointer())
            vals = [builder.extract_value(llargs[1], i) for i in range(len(sig.args))]
            status, res = context.call_conv.call_function(builder, ptr, sig.return_type, sig.args, vals)
            with cgutils.if_unlikely(builder, status.is_error):
                context.call_conv.return_status_propagate(builder, status)
            return res

        return sig.return_type(types.int64, types.StarArgTuple.from_types(tuple(args))), codegen

    return call


_F8, _I8, _B = types.float64, types.int64, types.boolean
_F1, _F2, _F3, _B1 = types.float64[::1], types.float64[:, ::1], types.float64[:, :, ::1], types.boolean[::1]


def _factor_signature(args):
    """_factor_unconstrained_fixed's: (tags, (Q, S, R), (A, B), ipt, reg, fac) -> int64; the size
    tags', interior-point terms' and factors' types are those of plain_iteration's arguments."""
    tags, _, _, ipt, _, fac = args
    return _I8(tags, types.UniTuple(_F3, 3), types.UniTuple(_F3, 2), ipt, _F8, fac)


def _solve_signature(args):
    """_solve_unconstrained_fixed's: (tags, (A, B), ipt, fac, (q, r, h, x0, none2, none1, none2),
    (dX, dU, lam, nu0)) -> none."""
    tags, _, ipt, fac, _, _ = args
    return types.none(tags, types.UniTuple(_F3, 2), ipt, fac, types.Tuple((_F2, _F2, _F2, _F1, _F2, _F1, _F2)),
                      types.UniTuple(_F2, 4))


#: the kernels plain_iteration calls at their addresses (slots 4, 5, ... of its ``addresses``):
#: (name, dispatcher, signature) with the argument types of the Python path's calls
KERNELS = (
    ("error_pass", K.error_pass, types.Tuple((_F8, _F8, _F8, _I8, _F8, _F8, _I8, _F8, _F8, _F8, _F8, _F8, _F8))(
        _F8, _F2, _F2, _F1, _F3, _F3, _F2, _F2, _B, _F2, _F2, _F2, _F1, _B, _B, _F2, _F1, _F1, _F1, _F2, _F1, _F1, _F1,
        _B1, _B1, _F8, _F8)),
    ("newton_terms", K.newton_terms, types.none(_F8, _F2, _F1, _F2, _F1, _F1, _F1, _F1, _B1, _B1, _F8, _F8, _F2, _F2,
                                                _F2, _F1, _F2, _F2, _F2, _F1, _F1)),
    ("shifted_diagonals", K.shifted_diagonals, types.none(_F2, _F2, _F8, _F2, _F2)),
    ("step_terms", K.step_terms, types.UniTuple(_F8, 2)(_F2, _F2, _F2, _F1, _F1, _F1, _F1, _B1, _B1, _F8, _F8, _F1)),
    ("trial_point", K.trial_point, types.none(_F1, _F1, _F8, _F1, _F1, _F2, _F2)),
    ("point_terms", K.point_terms, types.Tuple((_F8, _F8, _B, _F8))(_F1, _F1, _F1, _B1, _B1, _F1, _F1, _F1, _F2, _F2,
                                                                     _F1, _F2, _F1)),
    ("step_bound_multipliers", K.step_bound_multipliers, types.Tuple((_F8, _I8))(
        _F1, _F1, _F1, _F1, _F1, _F1, _B1, _B1, _F1, _F1, _F8, _F8, _F8, _F8, _F8, _F8, _F1, _F1, _F1, _F1, _F2, _F2,
        _F8, _F2)),
    ("barrier_logs", K.barrier_logs, types.Tuple((_B, _F8))(_F1, _F1, _F1, _B1, _B1, _F1, _F1, _F1)),
    ("dot", K.dot, _F8(_F1, _F1)),
    ("factor", _factor_unconstrained_fixed, _factor_signature),
    ("solve", _solve_unconstrained_fixed, _solve_signature),
)
(ERROR_PASS, NEWTON_TERMS, SHIFTED_DIAGONALS, STEP_TERMS, TRIAL_POINT, POINT_TERMS, STEP_BOUND_MULTIPLIERS,
 BARRIER_LOGS, DOT, FACTOR, SOLVE) = range(4, 4 + len(KERNELS))
(_error_pass, _newton_terms, _shifted_diagonals, _step_terms, _trial_point, _point_terms, _step_bound_multipliers,
 _barrier_logs, _dot, _factor, _solve) = (_native_at(sig) for _, _, sig in KERNELS)


def kernel_addresses(tags, ipt, fac):
    """The addresses of :data:`KERNELS`' compiled versions for plain_iteration's ``tags``,
    ``ipt``, ``fac`` (each compiled, or loaded from the cache, if it is not yet: the version the
    Python path uses, for the same types). TypeError when a kernel returns another type than
    :data:`KERNELS` says (plain_iteration would read its result wrongly)."""
    t = tuple(nb.typeof(a) for a in (tags, ipt, fac))
    args = {"factor": (t[0], None, None, t[1], None, t[2]), "solve": (t[0], None, t[1], t[2], None, None)}
    out = []
    for name, dispatcher, sig in KERNELS:
        sig = sig(args[name]) if callable(sig) else sig
        if tuple(sig.args) not in dispatcher.overloads:       # as a call from Python compiles it
            dispatcher.compile(tuple(sig.args))
        returns = dispatcher.overloads[tuple(sig.args)].signature.return_type
        if returns != sig.return_type:
            raise TypeError(f"iteration_kernels.KERNELS: {name} returns {returns}, not {sig.return_type}")
        out.append(_get_jit_address(dispatcher, sig))
    return out


@nb.njit(**_INNER)
def _py_max(a, b):
    """Python's max(a, b) of floats: b only when b > a."""
    return b if b > a else a


@nb.njit(**_INNER)
def _py_min(a, b):
    """Python's min(a, b) of floats: b only when b < a."""
    return b if b < a else a


@nb.njit(**_INNER)
def _sides_max(n_lo, m_lo, n_hi, m_hi):
    """barrier._sides_max."""
    if not n_lo:
        return m_hi if n_hi else 0.0
    return m_hi if n_hi and m_hi > m_lo else m_lo


@nb.njit(**_INNER)
def _products_complementarity(n_lo, lo_min, lo_max, n_hi, hi_min, hi_max, mu):
    """evaluation.products_complementarity."""
    if lo_max != lo_max:
        s_lo = math.nan
    else:
        s_lo = abs(mu - lo_min if mu - lo_min > lo_max - mu else lo_max - mu)
    if hi_max != hi_max:
        s_hi = math.nan
    else:
        s_hi = abs(mu - hi_min if mu - hi_min > hi_max - mu else hi_max - mu)
    return _sides_max(n_lo, s_lo, n_hi, s_hi)


# ---------------------------------------------------------------------------- the filter (filter.Filter)
@nb.njit(**_INNER)
def _filter_reset(F, sc, ic):
    """Filter.reset."""
    F[0, 0], F[0, 1] = sc[THETA_MAX], -np.inf
    ic[NF] = 1
    ic[REJECTED] = 0
    ic[FILTER_REJECTIONS] = 0


@nb.njit(**_INNER)
def _filter_add(F, ic, opt, theta, phi):
    """Filter.add: the corner (22), the entries it dominates dropped (the others keep their order)."""
    t, p = (1.0 - opt[GAMMA_THETA]) * theta, phi - opt[GAMMA_PHI] * theta
    k = 0
    for j in range(ic[NF]):
        if not (F[j, 0] >= t and F[j, 1] >= p):
            F[k, 0], F[k, 1] = F[j, 0], F[j, 1]
            k += 1
    F[k, 0], F[k, 1] = t, p
    ic[NF] = k + 1


@nb.njit(**_INNER)
def _decrease(opt, theta, phi, theta_t, phi_t):
    """Filter._decrease."""
    if phi_t > phi:
        base = math.log10(abs(phi)) if abs(phi) > 10.0 else 1.0
        if math.log10(phi_t - phi) > opt[OBJ_MAX_INC] + base:
            return False
    return theta_t <= (1.0 - opt[GAMMA_THETA]) * theta or phi_t <= phi - opt[GAMMA_PHI] * theta


@nb.njit(**_INNER)
def _filter_accept(F, sc, ic, opt, alpha, theta, phi, gphi, theta_t, phi_t):
    """Filter.accept: (accepted, f_type), the reset heuristic included."""
    if not math.isfinite(phi_t) or theta_t > sc[THETA_MAX]:
        return False, False
    switching = gphi < 0 and alpha * (-gphi) ** opt[S_PHI] > opt[DELTA] * theta ** opt[S_THETA]
    armijo = phi_t <= phi + opt[ETA_PHI] * alpha * gphi
    if theta <= sc[THETA_MIN] and switching:
        ok = armijo
    elif phi_t > phi:
        ok = _decrease(opt, theta, phi, theta_t, phi_t)
    else:
        ok = theta_t <= (1.0 - opt[GAMMA_THETA]) * theta or phi_t <= phi - opt[GAMMA_PHI] * theta
    if not ok:
        ic[REJECTED] = 0
        return False, False
    for j in range(ic[NF]):
        if not (theta_t < F[j, 0] or phi_t < F[j, 1]):
            ic[REJECTED] = 1
            return False, False
    if ic[RESETS] < opt[MAX_RESETS]:            # Filter._reset_heuristic
        if ic[REJECTED]:
            ic[FILTER_REJECTIONS] += 1
            if ic[FILTER_REJECTIONS] >= opt[RESET_TRIGGER]:
                ic[RESETS] += 1
                _filter_reset(F, sc, ic)
        else:
            ic[FILTER_REJECTIONS] = 0
    ic[REJECTED] = 0
    return True, switching and armijo


@nb.njit(**_INNER)
def _alpha_min(sc, opt, theta, gphi):
    """Filter.alpha_min (23)."""
    gt = opt[GAMMA_THETA]
    if gphi < 0:
        a = _py_min(_py_min(gt, -opt[GAMMA_PHI] * theta / gphi), opt[DELTA] * theta ** opt[S_THETA] / (-gphi) ** opt[S_PHI])
        if theta > sc[THETA_MIN]:
            a = _py_min(gt, -opt[GAMMA_PHI] * theta / gphi)
    else:
        a = gt
    return opt[GAMMA_ALPHA] * a


# ---------------------------------------------------------------------------- the iteration
@nb.njit(**_INNER)
def _errors(addresses, lx, lu, lN, A, B, lam, zl, zu, sl, su, has_lo, has_hi, EA, EB, none2, none1, sc, opt):
    """The stopping test's figures at the iterate (evaluation.iterate_errors, store_errors,
    optimality_errors at mu = 0): sets E0, INF_DU, INF_PR, COMPL; returns (inf_du, s_d, s_c, the
    products' ranges and the iterate's-mu complementarity) for the barrier update."""
    s_obj = sc[S_OBJ]
    mx, zsum, ysum, n_lo, m_lo, m_lo1, n_hi, m_hi, m_hi1, lo_min, lo_max, hi_min, hi_max = _error_pass(
        addresses[ERROR_PASS], s_obj, lx, lu, lN, A, B, EA, EB, opt[PRODUCTS] != 0.0, lam[1:], EA, EB, lN,
        opt[ROWS] != 0.0, opt[ROWS] != 0.0, none2, none1, zl, zu, none2, none1, sl, su, has_lo, has_hi, 0.0, sc[MU])
    nz, ny = opt[NZ], opt[NY]
    s_d = _py_max(S_MAX, (ysum + zsum) / (ny + nz)) / S_MAX
    s_c = _py_max(S_MAX, zsum / nz) / S_MAX
    inf_pr = sc[MX]
    compl = _sides_max(n_lo, m_lo, n_hi, m_hi)
    sc[E0] = _py_max(_py_max(mx / s_d, inf_pr), compl / s_c)
    sc[INF_DU], sc[INF_PR], sc[COMPL] = mx / s_obj, inf_pr, compl / s_obj
    return mx, s_d, s_c, (n_lo, lo_min, lo_max, n_hi, hi_min, hi_max), _sides_max(n_lo, m_lo1, n_hi, m_hi1)


@nb.njit(**_INNER)
def _prefix(F, inf_du, s_d, s_c, ranges, c_mu, sc, ic, opt):
    """solver.converged, the iteration limit and solver.update_barrier from :func:`_errors`'
    figures; a return code or -1 (go on)."""
    e0, inf_pr = sc[E0], sc[INF_PR]
    if (e0 <= opt[TOL] and sc[INF_DU] <= opt[DUAL_INF_TOL] and inf_pr <= opt[CONSTR_VIOL_TOL]
            and sc[COMPL] <= opt[COMPL_INF_TOL]):
        return SUCCESS
    if e0 <= opt[ACC_TOL] and inf_pr <= opt[ACC_VIOL]:
        ic[ACCEPTABLE] += 1
        if opt[ACC_ITER] and ic[ACCEPTABLE] >= opt[ACC_ITER]:
            return ACCEPTABLE_END
    else:
        ic[ACCEPTABLE] = 0
    if ic[IT] >= opt[MAX_ITER]:
        return MAX_ITERATIONS
    mu_err = sc[MU]
    n_lo, lo_min, lo_max, n_hi, hi_min, hi_max = ranges
    while True:         # update_barrier: the monotone rule (7)
        mu = sc[MU]
        compl = c_mu if mu == mu_err else _products_complementarity(n_lo, lo_min, lo_max, n_hi, hi_min, hi_max, mu)
        if not (_py_max(_py_max(inf_du / s_d, inf_pr), compl / s_c) <= opt[KAPPA_EPS] * mu):
            break
        new = _py_max(opt[TOL] / 10.0, _py_min(opt[KAPPA_MU] * mu, mu ** opt[THETA_MU]))
        if new >= mu:
            break
        sc[MU], sc[TAU] = new, _py_max(opt[TAU_MIN], 1.0 - new)
        _filter_reset(F, sc, ic)
    return -1


@nb.njit(**_INNER)
def _trial_terms(addresses, v_t, X_t, f_t, h_t, sl_t, su_t, lo, hi, has_lo, has_hi, one_lo_f, one_hi_f, none2, none1,
                 logs_work, J_t, sc, opt):
    """linesearch._trial after the values J_t, f_t at the trial point (finite): the residuals,
    their norms and phi; (theta, max, phi, logs, damped)."""
    N = h_t.shape[0]
    for k in range(N):
        for i in range(h_t.shape[1]):
            h_t[k, i] = f_t[k, i] - X_t[k + 1, i]
    l1, mx, inside, logs = _point_terms(addresses[POINT_TERMS], v_t, lo, hi, has_lo, has_hi, sl_t, su_t, logs_work,
                                        h_t, none2, none1, none2, none1)
    if not inside:
        return l1, mx, sc[S_OBJ] * J_t + math.inf, logs, 0.0
    dot = addresses[DOT]
    damped = _dot(dot, one_lo_f, sl_t) + _dot(dot, one_hi_f, su_t) if opt[ONE_SIDED] else 0.0
    mu = sc[MU]
    return l1, mx, sc[S_OBJ] * J_t + (-mu * logs + opt[KAPPA_D] * mu * damped), logs, damped


#: the columns of plain_iteration's history rows (one per step taken): the iteration, the
#: constraint violation and dual infeasibility at its start, mu, alpha, alpha_z, the objective after it
H_IT, H_INF_PR, H_INF_DU, H_MU, H_ALPHA, H_ALPHA_Z, H_J = range(7)
N_H = 7


@nb.njit(no_cfunc_wrapper=True, **_JIT)
def plain_iteration(addresses, data, idata, tags, ipt, reg, fac, F, cur, trial, mult, mult_new, bounds, x0, sc, ic, opt,
                    H):
    """Up to ``H.shape[0]`` iterations (solver.iterate) of :func:`_iteration`, one after another;
    returns (the last one's code, the steps taken). After each step the new iterate's arrays and
    multipliers become the iterate's (the sets swapped, as compiled.PlainPath._swap does: after an
    odd number of steps the caller swaps its sets once) and the step's history row is written into
    ``H``. Several iterations per call save the call's unboxing of about fifty arrays and the Python
    around it; a solve with a callback or a log line per iteration asks for one."""
    steps = 0
    while True:
        code = _iteration(addresses, data, idata, tags, ipt, reg, fac, F, cur, trial, mult, mult_new, bounds, x0, sc, ic,
                          opt)
        if code != STEP:
            return code, steps
        H[steps, H_IT], H[steps, H_INF_PR], H[steps, H_INF_DU], H[steps, H_MU] = ic[IT], sc[INF_PR], sc[INF_DU], sc[MU]
        H[steps, H_ALPHA], H[steps, H_ALPHA_Z], H[steps, H_J] = sc[ALPHA], sc[ALPHA_Z], sc[J]
        steps += 1
        cur, trial = ((trial[0], trial[1], trial[2], trial[4], trial[6], trial[7], trial[8], trial[9], trial[10],
                       trial[11], trial[12]),
                      (cur[0], cur[1], cur[2], trial[3], cur[3], trial[5], cur[4], cur[5], cur[6], cur[7], cur[8], cur[9],
                       cur[10]))
        mult, mult_new = mult_new, mult
        if steps == H.shape[0]:
            return STEP, steps


@nb.njit(error_model="numpy", **_INNER)
def _iteration(addresses, data, idata, tags, ipt, reg, fac, F, cur, trial, mult, mult_new, bounds, x0, sc, ic, opt):
    """One iteration (solver.iterate) on the dynamics-only Newton matrix with fixed-size Riccati
    kernels; returns STEP (the step taken: the new iterate in ``trial``, its multipliers in
    ``mult_new``, sc and ic updated), SUCCESS / ACCEPTABLE_END / MAX_ITERATIONS (the stopping test,
    the iterate unchanged), or a code >= BAIL (the stopping test and the barrier update done, the
    rest of the iteration left to the Python path, nothing else changed). The iteration's scratch
    arrays are made here (fewer arrays for the call to unbox: each costs about as much as making
    one)."""
    v, X, U, h, lx, lu, lN, A, B, sl, su = cur
    lam, zl, zu = mult
    lo, hi, has_lo, has_hi, one_lo_f, one_hi_f = bounds
    v_t, X_t, U_t, f_t, h_t, cost_t, lx_t, lu_t, lN_t, A_t, B_t, sl_t, su_t = trial
    N, n, m, size = X.shape[0] - 1, X.shape[1], U.shape[1], v.size
    EA, EB, none2, none1 = np.empty((N, n)), np.empty((N, m)), np.zeros((N, 0)), np.zeros(0)
    inf_du, s_d, s_c, ranges, c_mu = _errors(addresses, lx, lu, lN, A, B, lam, zl, zu, sl, su, has_lo, has_hi, EA, EB,
                                             none2, none1, sc, opt)
    code = _prefix(F, inf_du, s_d, s_c, ranges, c_mu, sc, ic, opt)
    if code >= 0:
        return code
    values, derivatives = _values_at(addresses[0]), _derivatives_at(addresses[1])
    hessians, final_hessian = _hessians_at(addresses[2]), _final_hessian_at(addresses[3])
    Q, S, R = np.empty((N + 1, n, n)), np.empty((N, n, m)), np.empty((N, m, m))
    Sx, Su, q, r = np.empty((N + 1, n)), np.empty((N, m)), np.empty((N + 1, n)), np.empty((N, m))
    dX, dU, lam_s, nu0 = np.empty((N + 1, n)), np.empty((N, m)), np.empty((N + 1, n)), np.empty((N + 1, 0))
    grad, dv, logs_work, sl_new, su_new = np.empty(size), np.empty(size), np.empty(size), np.empty(size), np.empty(size)
    Ss, SsN, gs, gsN, x0z = none2, none1, none2, none1, np.zeros(n)
    mu, tau, s_obj = sc[MU], sc[TAU], sc[S_OBJ]
    # newton_system: the Hessian blocks, Sigma and the barrier gradient, the factorization at delta_w = 0
    if not hessians(data, idata, X, U, s_obj, lam[1:], Q[:N], S, R):
        return HESSIAN_NOT_FINITE
    Q[N, :, :] = 0.0
    if not final_hessian(data, idata, X[N], s_obj, Q[N]):
        return HESSIAN_NOT_FINITE
    _newton_terms(addresses[NEWTON_TERMS], s_obj, lx, lN, lu, sl, su, zl, zu, has_lo, has_hi, mu, opt[KAPPA_D] * mu, Sx,
                  Su, Ss, SsN, q, r, gs, gsN, grad)
    _shifted_diagonals(addresses[SHIFTED_DIAGONALS], Sx, Su, 0.0, ipt[0], ipt[1])
    if _factor(addresses[FACTOR], tags, (Q, S, R), (A, B), ipt, reg, fac) >= 0:
        return INERTIA
    # linesearch.direction
    _solve(addresses[SOLVE], tags, (A, B), ipt, fac, (q, r, h, x0z, none2, none1, none2), (dX, dU, lam_s, nu0))
    alpha_max, tiny = _step_terms(addresses[STEP_TERMS], dX, dU, none2, none1, v, sl, su, has_lo, has_hi, -tau, tau, dv)
    phi = s_obj * sc[J] + (-mu * sc[LOGS] + opt[KAPPA_D] * mu * sc[DAMPED])
    gphi = _dot(addresses[DOT], grad, dv)
    th = sc[THETA]
    if tiny < opt[TINY]:
        return TINY_STEP
    if opt[WD_TRIGGER] and ic[SHORTENED] >= opt[WD_TRIGGER]:
        return WATCHDOG
    # linesearch.backtrack
    alpha_min = _alpha_min(sc, opt, th, gphi)
    alpha, trials = alpha_max, 0
    n_values = 0
    accepted = False
    th_t = mx_t = J_t = logs_t = damped_t = 0.0
    while alpha > alpha_min or trials == 0:
        trials += 1
        _trial_point(addresses[TRIAL_POINT], v, dv, alpha, x0, v_t, X_t, U_t)       # linesearch._trial
        J_t = values(data, idata, X_t, U_t, f_t, cost_t)
        if J_t != J_t:
            return TRIAL_NOT_FINITE
        th_t, mx_t, phi_t, logs_t, damped_t = _trial_terms(addresses, v_t, X_t, f_t, h_t, sl_t, su_t, lo, hi, has_lo,
                                                           has_hi, one_lo_f, one_hi_f, none2, none1, logs_work, J_t, sc,
                                                           opt)
        n_values += 1
        ok, f_type = _filter_accept(F, sc, ic, opt, alpha, th, phi, gphi, th_t, phi_t)
        if ok:
            if not f_type:
                _filter_add(F, ic, opt, th, phi)
            ic[SHORTENED] = ic[SHORTENED] + 1 if trials > 1 else 0
            accepted = True
            break
        if trials == 1 and th_t >= th and opt[MAX_SOC]:
            return SOC
        alpha *= 0.5
    if not accepted:
        return RESTORATION
    # solver.take_step: the new point's derivatives, the multipliers' step
    if not derivatives(data, idata, X_t, U_t, lx_t, lu_t, lN_t, A_t, B_t):
        return DERIVATIVES_NOT_FINITE
    lam_n, zl_n, zu_n = mult_new
    alpha_z, moved = _step_bound_multipliers(addresses[STEP_BOUND_MULTIPLIERS], sl, su, v_t, dv, lo, hi, has_lo, has_hi,
                                             zl, zu, mu, -tau, opt[EPS], opt[EPS_MOVE], 1e10, 1e10 * mu, sl_new, su_new,
                                             zl_n, zu_n, lam, lam_s, alpha, lam_n)
    if moved:       # the bounds moved: the new point's slacks (sl_new's numbers) and barrier terms after it
        inside, logs_t = _barrier_logs(addresses[BARRIER_LOGS], v_t, lo, hi, has_lo, has_hi, sl_t, su_t, logs_work)
        if inside:
            dot = addresses[DOT]
            damped_t = _dot(dot, one_lo_f, sl_t) + _dot(dot, one_hi_f, su_t) if opt[ONE_SIDED] else 0.0
        else:           # outside (barrier.Bounds.barrier_value: +inf): phi's -mu logs is +inf
            logs_t, damped_t = -math.inf, 0.0
    ic[IT] += 1
    ic[FACTORIZATIONS] += 1
    ic[N_VALUES] += n_values
    ic[N_DERIVS] += 1
    ic[N_HESS] += 1
    sc[J], sc[LOGS], sc[DAMPED], sc[THETA], sc[MX] = J_t, logs_t, damped_t, th_t, mx_t
    sc[ALPHA], sc[ALPHA_Z] = alpha, alpha_z
    return STEP
