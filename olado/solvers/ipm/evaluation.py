"""The evaluations at an iterate of the interior-point solver (:mod:`olado.solvers.ipm.solver`):
the Point at a flat vector, the constraint residuals and their norms (theta), the barrier value,
the gradients of the objective and of the Lagrangian, and the optimality error (5) of Waechter and
Biegler 2006 (Math. Program. 106, 25-57; docs/interior-point-nlp.md) with its dual infeasibility,
constraint violation and complementarity, each computed once per iterate and cached on it.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..common import stage_gradient_terms
from ..sqp.state import Point
from .barrier import _kernels, _sides_max
from .newton import Residuals

#: s_max of eq. (5): the scaling of the optimality error by the multipliers' size
S_MAX = 100.0


def evaluate(setup, v, clock, derivatives=False):
    """The Point (values; derivatives on request) at the flat vector v."""
    X, U = setup.layout.states_controls(v)
    return Point(setup.problem, X, U, derivatives=derivatives, clock=clock)


def residuals(setup, pt, v) -> Residuals:
    """The constraint residuals at the point: dynamics, equalities, inequality rows d - s.
    Computed once per (point, v) (the line search's theta at the trial point, the optimality
    error and the next direction at the accepted one ask for them): like the iterate's arrays
    (:func:`error_terms`), v is replaced, never changed in place, and the residuals are read only."""
    return _residual_entry(setup, pt, v)[2]


def _residual_entry(setup, pt, v):
    """The point's cache entry [v, setup, Residuals, (l1, max) or None]."""
    cached = getattr(pt, "_ipm_residuals", None)
    if cached is not None and cached[0] is v and cached[1] is setup:
        return cached
    L = setup.layout
    if L.rows:
        s, sN = L.slack_views(v)
        res = Residuals(pt.h, pt.g[:, L.eq], pt.gN[L.eqN], pt.g[:, L.ineq] - s, pt.gN[L.ineqN] - sN)
    else:
        res = Residuals(pt.h, *L.no_rows)
    cached = pt._ipm_residuals = [v, setup, res, None]
    return cached


def residual_norms(setup, pt, v):
    """(theta, max-norm) of the residuals at the point (Residuals.norms), cached with them."""
    entry = _residual_entry(setup, pt, v)
    if entry[3] is None:
        entry[3] = entry[2].norms()
    return entry[3]


def theta(setup, pt, v):
    """The constraint violation theta (the 1-norm of every constraint residual)."""
    return residual_norms(setup, pt, v)[0]


def barrier_value(setup, pt, v, mu, s_obj):
    """(phi_mu at the point, None): the line search and the restoration phase compare values
    only (element 0); the gradient is :func:`.solver.barrier_gradient`'s, at the iterate alone."""
    return s_obj * pt.J + setup.bounds.barrier_value(v, mu), None


def objective_gradient(pt, s_obj):
    """s_f grad J over the free variables as (q (N+1, n) with row 0 the x^0 part, r (N, m))."""
    q = np.empty_like(pt.X)
    q[:-1] = pt.lx
    q[-1] = pt.lN
    return s_obj * q, s_obj * pt.lu


def full_multipliers(L, st):
    """(Lg (N, r), LgN (rN,)): the equality and inequality multipliers in the problem's order."""
    if not L.rows:
        return L.no_rows[0], L.no_rows[1]       # empty: shared
    Lg = np.zeros((L.N, L.eq.size))
    Lg[:, L.eq], Lg[:, L.ineq] = st.nu, st.yd
    LgN = np.zeros(L.eqN.size)
    LgN[L.eqN], LgN[L.ineqN] = st.nuN, st.ydN
    return Lg, LgN


def lagrangian_gradient(setup, st):
    """The gradient of the Lagrangian s_f J + lam.h + Lg.g + LgN.gN - y_d.s over v (without the
    bound multipliers), flat."""
    L = setup.layout
    Lg, LgN = full_multipliers(L, st)
    gx, gu = stage_gradient_terms(setup.problem, st.pt, st.lam[1:], Lg, LgN, sigma=st.s_obj)
    return L.pack(gx, gu, -st.yd, -st.ydN)


class ErrorTerms(NamedTuple):
    """The parts of the optimality error (5) that do not depend on mu: the dual infeasibility
    |grad L - z_L + z_U|_inf (scaled problem), the constraint violation (max-norm), and the
    scalings s_d, s_c."""

    inf_du: float
    inf_pr: float
    s_d: float
    s_c: float


def dual_terms(setup, st):
    """(|grad L - z_L + z_U|_inf, |z_L|_1 + |z_U|_1, the constraint multipliers' 1-norm) at the
    iterate: :func:`lagrangian_gradient`'s arithmetic, the sums numpy's (:func:`iterate_errors`)."""
    return iterate_errors(setup, st)[0]


def iterate_errors(setup, st):
    """(:func:`dual_terms`, (complementarity at mu = 0, at the iterate's mu), the ranges of the
    products s z (:func:`products_complementarity`: the complementarity of any other mu)) in one
    compiled pass (kernels.error_pass: the stage products A^T lam, B^T lam where
    :func:`_plain_products` says einsum's order is the plain one, the dual infeasibility,
    kernels.dual_infeasibility, the complementarity and the ranges, kernels.complementarity_ranges);
    the products with the constraint rows by numpy."""
    p, pt, b = setup.problem, st.pt, setup.bounds
    lam = st.lam[1:]
    products = _plain_products(pt.A, pt.B, lam)
    if products:
        EA, EB = setup.ws.products()            # scratch of the compiled pass
    else:
        EA, EB = np.einsum("kij,ki->kj", pt.A, lam), np.einsum("kij,ki->kj", pt.B, lam)
    ECx, ECu, CNL = EA, EB, pt.lN       # placeholders without stage or final constraints
    if p.r or p.rN:
        Lg, LgN = full_multipliers(setup.layout, st)
        if p.r:
            ECx, ECu = np.einsum("kij,ki->kj", pt.Cx, Lg), np.einsum("kij,ki->kj", pt.Cu, Lg)
        if p.rN:
            CNL = pt.CN.T @ LgN
    sl, su = b.slacks(st.v)
    mx, zsum, ysum, n_lo, m_lo, m_lo1, n_hi, m_hi, m_hi1, lo_min, lo_max, hi_min, hi_max = _kernels().error_pass(
        float(st.s_obj), pt.lx, pt.lu, pt.lN, pt.A, pt.B, EA, EB, products, lam, ECx, ECu, CNL, bool(p.r), bool(p.rN),
        st.yd, st.ydN, st.zl, st.zu, st.nu, st.nuN, sl, su, b.has_lo, b.has_hi, 0.0, float(st.mu))
    return ((float(mx), float(zsum), float(ysum)),
            (_sides_max(n_lo, m_lo, n_hi, m_hi), _sides_max(n_lo, m_lo1, n_hi, m_hi1)),
            (n_lo, lo_min, lo_max, n_hi, hi_min, hi_max))


def products_complementarity(ranges, mu):
    """max |s z - mu| over the finite sides (Bounds.complementarity, the same float) from the ranges
    (n_lo, min, max, n_hi, min, max) of the products p = s z (kernels.complementarity_ranges):
    fl(p - mu) is monotone in p and rounding symmetric, so a side's max |fl(p - mu)| is
    max(fl(p_max - mu), fl(mu - p_min)) exactly (one of them >= 0; abs gives a zero as +0), NaN
    with a NaN product; the sides joined by barrier._sides_max as the compiled pass's are."""
    sides = [math.nan if p_max != p_max else abs(mu - p_min if mu - p_min > p_max - mu else p_max - mu)
             for p_min, p_max in (ranges[1:3], ranges[4:6])]
    return _sides_max(ranges[0], sides[0], ranges[3], sides[1])


def _plain_products(A, B, lam):
    """Whether np.einsum("kij,ki->kj", .) of A and of B with lam sums in the plain order of
    kernels.stage_products (C-contiguous float64 operands, rows of two or more entries in both
    products: einsum's loop then runs along the output row; with one entry it sums in SIMD lanes)."""
    n, m = B.shape[1], B.shape[2]
    return (n >= 2 and m >= 2 and A.dtype == np.float64 and B.dtype == np.float64 and lam.dtype == np.float64
            and A.flags.c_contiguous and B.flags.c_contiguous and lam.flags.c_contiguous)


#: the iterate's parts the optimality error reads (with s_obj)
ERROR_INPUTS = ("v", "pt", "lam", "nu", "nuN", "yd", "ydN", "zl", "zu")


def error_terms(setup, st) -> ErrorTerms:
    """:class:`ErrorTerms` at the iterate, computed once per iterate: the stopping test and the
    barrier update (several mu) ask for them at the same point. The iterate's arrays are
    replaced, never changed in place, so their identities name the iterate."""
    cached = st.error_cache
    if cached is not None and cached[1] == st.s_obj:
        k = cached[0]           # ERROR_INPUTS
        if (k[0] is st.v and k[1] is st.pt and k[2] is st.lam and k[3] is st.nu and k[4] is st.nuN and k[5] is st.yd
                and k[6] is st.ydN and k[7] is st.zl and k[8] is st.zu):
            return cached[2]
    return store_errors(setup, st, iterate_errors(setup, st))


def store_errors(setup, st, figures):
    """The :class:`ErrorTerms` of the iterate from :func:`iterate_errors`' figures, kept for
    :func:`error_terms`, and the products' ranges for :func:`complementarity`."""
    key = (st.v, st.pt, st.lam, st.nu, st.nuN, st.yd, st.ydN, st.zl, st.zu)
    b = setup.bounds
    (inf_du, zsum, ysum), (c0, c1), ranges = figures
    # the complementarities of the same pass, and the products' ranges for another mu (complementarity's cache)
    st.compl_cache = (b.slacks(st.v), st.zl, st.zu, ranges, {0.0: c0, st.mu: c1})
    inf_pr = residual_norms(setup, st.pt, st.v)[1]
    nz = max(b.count, 1)
    ny = st.lam[1:].size + st.nu.size + st.nuN.size + st.yd.size + st.ydN.size
    s_d = max(S_MAX, (ysum + zsum) / (ny + nz)) / S_MAX
    s_c = max(S_MAX, zsum / nz) / S_MAX
    terms = ErrorTerms(inf_du, inf_pr, s_d, s_c)
    st.error_cache = (key, st.s_obj, terms)
    return terms


def complementarity(setup, st, mu):
    """max |s z - mu| over the finite sides at the iterate (Bounds.complementarity). The stopping
    test (mu = 0) and the barrier update (the iterate's mu) ask at the same iterate: both are
    computed in one pass (:func:`iterate_errors`, with the error terms) and kept until the slacks
    (the point, or the bounds moved) or the bound multipliers change; another mu (each lower one
    the barrier update sets) is had from the same pass's ranges of the products s z
    (:func:`products_complementarity`, exactly), not by another pass."""
    slacks = setup.bounds.slacks(st.v)
    c = st.compl_cache
    if c is None or c[0] is not slacks or c[1] is not st.zl or c[2] is not st.zu:
        figures = iterate_errors(setup, st)
        c = st.compl_cache = (slacks, st.zl, st.zu, figures[2], dict(zip((0.0, st.mu), figures[1])))
    values = c[4]
    value = values.get(mu)
    if value is None:
        value = values[mu] = products_complementarity(c[3], mu)
    return value


def optimality_errors(setup, st, mu):
    """(E_mu scaled (eq. (5)), dual infeasibility unscaled, constraint violation max-norm,
    complementarity unscaled) at the current iterate."""
    inf_du, inf_pr, s_d, s_c = error_terms(setup, st)
    compl = complementarity(setup, st, mu)
    return max(inf_du / s_d, inf_pr, compl / s_c), inf_du / st.s_obj, inf_pr, compl / st.s_obj
