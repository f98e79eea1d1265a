"""Primal-dual interior-point methods for the stage QP (14) (paper 001 sec. 4.2.2).

Three methods share one base class, :class:`InteriorPointQP`, which owns the data preparation,
the residuals, the Newton step through a pluggable KKT back-end and the bookkeeping; they differ
only in how the search direction is built from one factorization per iteration:

* :class:`MehrotraQP` -- Mehrotra's predictor-corrector (Mehrotra 1992) with the safeguard of
  Salahi, Peng and Terlaky (2005 report; SIAM J. Optim. 18 (2007) 1377-1397);
* :class:`GondzioQP` -- the same plus Gondzio's multiple centrality correctors (Gondzio 1996,
  Comput. Optim. Appl. 6, 137-156; paper 003);
* :class:`WeightedCorrectorQP` -- the same, every corrector weighted by a line search on its
  weight (paper 003 "weighted correctors"; Colombo and Gondzio 2008, Comput. Optim. Appl. 41).

Problem (the :class:`~olado.qp.stageqp.StageQP`, z_k = (x_k, u_k))::

    min 1/2 z^T H z + g.z  s.t.  dynamics, x_0 = x0, E z + e = 0,
        c_lower <= C_k z_k <= c_upper,  cN_lower <= C_N x_N <= cN_upper,  bounds on x_k (k >= 1), u_k

Inequalities (paper 003, "handling both sided constraints").  Every inequality is a box
``lo <= w <= hi`` on w = (x_1..x_N, u_0..u_{N-1}, C_k z_k, C_N x_N).  Each *finite* side gets its
own slack and multiplier (tl = w - lo >= 0 with zl, tu = hi - w >= 0 with zu) and an infinite side
carries nothing; a two-sided row stays one row of C in the KKT matrix (no duplicated rows), its
multiplier is zu - zl (paper 003's z_d).  The slacks are stored iterate variables (the relations
w - lo - tl = 0, hi - w - tu = 0 are primal residuals of the infeasible method), so no slack is
ever recomputed by a cancelling difference and a warm start may begin outside the boxes.  The
bounds of x_0 are not iterated on (x_0 = x0 is fixed); ``solve`` checks x0 against them and
reports INFEASIBLE when it violates them.

Newton step (paper 001 (22)-(25)).  With r_l = w - lo - tl, r_u = hi - w - tu, the linearized
complementarity equations zl*dtl + tl*dzl = rho_l, zu*dtu + tu*dzu = rho_u and dtl = dw + r_l,
dtu = -dw + r_u eliminate to dzu - dzl = D dw + g with

    D = zl/tl + zu/tu,   g = (rho_u - zu r_u)/tu - (rho_l - zl r_l)/tl

(paper 003's (S_u^-1 Z_u + S_l^-1 Z_l)).  For bounds D goes into ``Dx``/``Du`` of the LQ-DOCP
solver and g into the gradient; for stage rows into ``sigma`` with ``Ci = C_k`` and ``ci = g/D``;
for final rows C_N^T diag(D) C_N is added to Q_N and C_N^T g to q_N.  The KKT back-end (option
``kkt``) factorizes once per iteration; predictor and every corrector are further right-hand
sides of the same factorization.  After a solve the residual of the unreduced, unregularized
Newton system (stationarity, dynamics, equalities, slack and complementarity rows) is measured
in one compiled pass; only when it exceeds max(1e-3 tol (1 + |rhs|), ``refinement_tol`` |rhs|)
(|rhs| the max-norm of the right-hand side) follow up to ``refinement_steps`` steps of iterative
refinement (corrections from the same factorization), which keeps the directions accurate when
D spans many orders of magnitude near the solution.  Refinement stops as soon as a correction
does not halve the residual (and undoes it when the residual grew): then the factored matrix is
too far from the Newton matrix -- a regularization that made an indefinite (nonconvex) system
definite, not one that only cures rounding -- and further corrections only pull the direction
towards the indefinite system's.  The first solve of a factorization
measures its relative error |residual| / |rhs|; later solves with it (corrector, centrality
correctors) skip the measurement when that relative error times their |rhs| is below 10 % of
their target.  Primal and dual variables
take separate step lengths alpha = min(1, step_to_boundary * alpha_max) (option ``step_rule``;
``common`` takes the smaller one for both).  ``regularization`` (delta)
adds delta*I to the Hessian of the Newton system only (the residuals are exact), a
proximal-point regularization that keeps the step defined for merely semidefinite H (e.g. free
controls with R = 0).

Fixed variables and equal bounds (paper 003, "fixed variables are eliminated"):

* a control with u_lower = u_upper (to 1e-12 relative) is eliminated: its column of B, S, F and C
  times its value moves into c, q, r, e and the row bounds; in the reduced problem the component
  is a decoupled dummy (unit Hessian, zero gradient) whose step is exactly zero.  Its bound
  multipliers are recovered from the u-stationarity of the original Lagrangian;
* a state with x_lower = x_upper (k >= 1) and a general row with c_lower = c_upper become
  equality rows (E_k x_k + e_k = 0 at stage k, E_N at k = N) of the LQ-DOCP solver; their
  multiplier nu is split into the two bound multipliers by sign (upper = max(nu, 0),
  lower = max(-nu, 0)).

Stopping (all norms max-norms; "relative" means scaled by 1 + the norm of the data and iterate
terms that make up the residual, as in Clarabel/OSQP):

* primal: |dynamics, x_0, equality and slack residuals| <= tol * (1 + max(|c|, |x0|, |e|, |z|));
* dual: |gradient of the Lagrangian| <= tol * (1 + max(|q|, |r|, |H z|));
* complementarity: the gap sum(zl*tl + zu*tu) (the duality gap at a feasible point)
  <= tol * (1 + |objective|).

Infeasibility (documented criterion).  Two certificates are evaluated at every iterate that
looks suspicious -- a scaled primal (dual) residual above tol that the last two steps did not at
least halve, or an iterate with |z|_inf > 1e10 (1 + data) -- (on a converging QP the residuals fall by
the factor 1 - alpha per step, on an infeasible or unbounded one the steps shrink):

* primal infeasibility (Farkas): the constraint part y = (lam, nu, zl, zu) of the multipliers
  gives a Lagrangian term y.constraints(z) = G(y).z + kappa(y) that is <= 0 at every feasible z
  (equalities vanish, inequality terms are <= 0).  If kappa > 0, every feasible z has
  |z|_inf >= B := kappa / (n_z |G|_inf).  The quality of the certificate is
  B / (1 + |z_k|_inf + |data|_inf), how much farther than the iterate and the data (bounds,
  offsets) any feasible point would have to be;
* dual infeasibility (recession direction): d = the last primal step (or the iterate itself once
  it exceeds 1e10 (1 + data)), normalized to |d|_inf = 1.  If g.d < 0 and the largest of |H d|,
  the homogeneous equality residuals of d and the violation of the recession cone of the boxes
  is at most eps |g.d|, the objective decreases without bound along d.

Strict test (at the suspicious iterates): quality >= 1/``infeasibility_tol`` -> INFEASIBLE, eps =
``infeasibility_tol`` -> UNBOUNDED.  In an infeasible QP the multipliers grow geometrically while
the steps shrink, so the certificate sharpens but slowly; therefore, when the iterates *stall*
(10 iterations without reducing the best scaled KKT measure by 1 %, or three steps below 1e-8),
the loose test is applied: quality >= 10 -> INFEASIBLE, eps = 1e-3 -> UNBOUNDED.  A stall without
any certificate is reported as NUMERICAL_ERROR (a stall alone proves nothing: tight tolerances,
near-singular or nonconvex Hessians stall too); the message says which rule fired and the numbers.

Step length: alpha = min(1, step_to_boundary * alpha_max), shortened by factors 0.9 until every
product t_i z_i >= gamma mu (the N_inf^- neighbourhood of Salahi, Peng and Terlaky, gamma =
``neighborhood`` or half the current min t_i z_i / mu if the iterate is already outside), which
keeps the products from collapsing far below mu and the Newton systems from degenerating.

Implementation: an iterate (or direction) is one flat vector with views X, U, lam, nu, tl, tu,
zl, zu; the residuals with the measures of the stopping test, the elimination of the slack and
multiplier parts before and after a KKT solve, the Newton residual, the ratio tests, the
neighbourhood test and the corrector right-hand sides are numba kernels over the stacked stage
arrays of the prepared problem (which also holds the work arrays), so an iteration costs one
factorization, its solves and a few O(N (n+m)^2) passes.  The prepared problem also holds the
objects reused from iteration to iteration (no per-iteration allocation of views): two residual
vectors used in turn, the complementarity right-hand sides and the directions of the predictor,
the corrector, further correctors and refinement -- each overwritten only after its last use
(see ``_Prepared.directions``); iterates and combined directions (``plus``) are new vectors.

Failures: a factorization that fails (``NotPositiveDefiniteError``: loss of definiteness when D
spans many orders of magnitude, or a Hessian that is indefinite on the null space of the
equalities while the slacks are still large, as the exact Hessian of an SQP subproblem can be)
is retried with the regularization raised tenfold, up to ``max_regularization`` * max|H|; if it
still fails the solve ends with NUMERICAL_ERROR naming the stage and the delta tried
(``QPResult.regularization``).  With ``nonconvex = "shift"`` a delta above the base
``regularization`` is instead added to the QP's Hessian for the rest of the solve (residuals
recomputed, progress measures restarted): the solve returns the solution of the convexified QP
with H + delta I and delta in ``QPResult.regularization`` -- what the SQP's inertia correction
needs, in one solve instead of a sequence of failing ones.  When a solve ends with NUMERICAL_ERROR or MAX_ITERATIONS but
an earlier iterate met ``acceptable_tol``, that iterate is returned with status ACCEPTABLE and a
message saying what happened.

Polishing (``polish``, on by default).  An ACCEPTABLE result is usually a good estimate of the
active set whose last iterations were cut short -- near the solution D spans so many orders of
magnitude (z/t ~ 1e16 on active bounds, 1e-16 on inactive ones) that the Newton matrices stop
factorizing, typically in the tightly-toleranced local phase of the SQP.  Every side whose
multiplier exceeds its slack is then held at its bound (fixed controls eliminated, fixed states
and rows as equality rows, the other sides dropped) and the resulting equality-constrained QP is
solved in one Newton step; bounds its solution violates are added and it is solved again (at
most ``polish_rounds`` times).  The polished point replaces the result, as SUCCESS, only if it
meets ``tol`` in stationarity, primal feasibility and complementarity with every multiplier of
the right sign (OSQP's solution polishing, Stellato et al. 2020, in interior-point form).
"""

from __future__ import annotations

import dataclasses
import math
import time

import numba as nb
import numpy as np
from numba import types
from llvmlite import ir as llir
from numba.core import cgutils
from numba.extending import intrinsic, overload

from ..linalg.backend import KKT_SOLVERS, RHS, Solution, make_kkt_solver
from ..linalg.codegen import F64 as _F64, I32 as _I32, ContractRowCode as _ContractRowCode, SizeTags, fixed_size_tags
from ..linalg.codegen import pieces as _pieces, stack_vector as _stack_vector
from ..linalg.backend import NotPositiveDefiniteError
from ..linalg.riccati import RiccatiStatusError
from .stageqp import BOX_FIELDS, QPResult, StageQP, box_values, qp_kkt_residuals
from ..result import Status
from ..solvers.base import make_options, option

KKT_BACKENDS = KKT_SOLVERS   # riccati, superlu-full, superlu-reduced, minres, gmres

_FIX_RTOL = 1e-12
# restart of a cold start whose iterates stall or crawl (InteriorPointQP.solve): the words put
# in the message that mark such an end, and the number of restarts
_STALLED, _CRAWLED, _MAX_RESTARTS = "stalled", "crawled", 2
_CRAWL_W, _CRAWL_A = 10, 0.1   # crawling: _CRAWL_W successive steps (primal and dual) shorter than _CRAWL_A

def _equal_bounds(lo, hi):
    """Entries with finite lo = hi (to _FIX_RTOL relative): fixed variables and equality rows."""
    with np.errstate(invalid="ignore"):
        return np.isfinite(lo) & np.isfinite(hi) & (hi - lo <= _FIX_RTOL * (1 + np.abs(lo)))




# ============================================================================= options
@dataclasses.dataclass
class InteriorPointQPOptions:
    """Options shared by the interior-point QP methods."""

    tol: float = option(1e-8, "relative KKT tolerance (primal, dual residual and complementarity; see the module docstring)",
                        min=0.0, min_exclusive=True)
    max_iter: int = option(100, "maximum number of interior-point iterations", min=0)
    kkt: str = option("riccati", "KKT back-end for the Newton systems", choices=KKT_BACKENDS)
    step_to_boundary: float = option(0.995, "fraction of the step to the boundary that is taken", min=0.99, max=0.9995)
    initial_mu: float = option(0.1, "cold start: slacks t >= 1 and multipliers z = initial_mu / t (the starting "
                               "complementarity products)", min=0.0, min_exclusive=True)
    stall_restart_mu: float = option(100.0, "a cold start that stalls or crawls without regularizing the Newton "
                                     "systems is solved again (at most twice, within max_iter) from initial_mu "
                                     "times this (1: no restart)", min=1.0)
    step_rule: str = option("primal-dual", "'common': one step length for primal and dual variables; 'primal-dual': "
                            "separate step lengths for (x, u, slacks) and (multipliers) (Mehrotra 1992 sec. 7)",
                            choices=("common", "primal-dual"))
    regularization: float = option(1e-10, "primal (proximal) regularization delta*I added to the Newton Hessian", min=0.0)
    max_regularization: float = option(100.0, "largest primal regularization tried when a KKT factorization fails, "
                                       "relative to max|H| (inertia correction per Newton step)", min=0.0)
    nonconvex: str = option("regularize", "a KKT factorization that needs delta*I (a Hessian that is not positive "
                            "definite on the null space of the equalities): 'regularize' adds delta to that Newton "
                            "matrix only; 'shift' adds it to the QP's Hessian for the rest of the solve, which then "
                            "solves the shifted (convexified) QP and reports the total shift in "
                            "QPResult.regularization", choices=("regularize", "shift"))
    refinement_steps: int = option(3, "maximum iterative refinement steps per Newton solve (0 = none)", min=0, max=20)
    refinement_tol: float = option(1e-4, "a Newton solve is refined only when its residual exceeds this times the "
                                   "size of the right-hand side (and 1e-3 tol (1 + that size)); 0 = refine down to "
                                   "the latter", min=0.0, max=1e-2)
    polish: bool = option(True, "a solve that ends ACCEPTABLE (the iterates could not reach tol, e.g. because the "
                          "Newton matrices break down as the slacks of active bounds approach 0) is polished: the "
                          "equality-constrained QP with the bounds active at the best iterate held at their values is "
                          "solved exactly (bounds it violates are added, up to polish_rounds times); the polished point "
                          "replaces the result, with status SUCCESS, when it meets tol with multipliers of the right sign")
    polish_rounds: int = option(3, "polishing: equality-constrained solves (active-set updates) at most", min=1, max=20)
    acceptable_tol: float = option(1e-6, "if the solve ends without meeting tol, the best iterate is returned as "
                                   "ACCEPTABLE when it meets this looser tolerance", min=0.0, min_exclusive=True)
    infeasibility_tol: float = option(1e-8, "tolerance of the infeasibility / unboundedness certificates",
                                      min=0.0, min_exclusive=True)
    safeguard_step: float = option(0.1, "Salahi-Peng-Terlaky: affine or corrector steps below this trigger the safeguard",
                                   min=0.0, max=1.0)
    safeguard_gamma: float = option(0.1, "Salahi-Peng-Terlaky safeguard sigma = gamma/(1-gamma)",
                                    min=0.0, max=0.5, min_exclusive=True)
    neighborhood: float = option(1e-3, "steps keep every product t_i z_i >= neighborhood * mu (N_inf^- neighbourhood)",
                                 min=0.0, max=0.5)
    warm_start_push: float = option(1e-2, "warm start: slacks and multipliers are raised to at least this (times 1 + their max)",
                                    min=0.0, max=1.0, min_exclusive=True)
    verbose: int = option(0, "0 silent, 1 summary, 2 iteration log", min=0, max=12)
    kkt_options: dict = option({}, "extra keyword arguments for the KKT back-end", ini=False)


@dataclasses.dataclass
class GondzioQPOptions(InteriorPointQPOptions):
    """Options of :class:`GondzioQP` (and :class:`WeightedCorrectorQP`)."""

    max_correctors: int = option(3, "maximum number of centrality correctors per iteration", min=0, max=20)
    aspiration_step: float = option(0.1, "delta_alpha: correctors aim at alpha + delta_alpha", min=0.0,
                                    max=1.0, min_exclusive=True)
    acceptance: float = option(0.1, "a corrector is kept if alpha grows by at least acceptance*delta_alpha", min=0.0,
                               max=1.0)
    beta_min: float = option(0.1, "centrality targets are projected on [beta_min*mu, beta_max*mu]", min=0.0,
                             max=1.0, min_exclusive=True)
    beta_max: float = option(10.0, "upper factor of the centrality box", min=1.0)


@dataclasses.dataclass
class WeightedCorrectorQPOptions(GondzioQPOptions):
    """Options of :class:`WeightedCorrectorQP`."""

    weight_points: int = option(10, "number of weights tried by the line search on [omega_min, 1]", min=2, max=100)


# ============================================================================= compiled kernels
# The per-iteration vector work runs in these kernels over the stacked stage arrays: one pass
# each for the KKT residuals (with the measures of the stopping test), the elimination of the
# slack/multiplier parts before and after a KKT solve, the Newton residual that decides on
# iterative refinement, the ratio tests and the neighbourhood test of the step length.  The
# flat box vectors w = (x_1..x_N, u_0..u_{N-1}, C_k z_k, C_N x_N) are indexed as in _Prepared:
# x_k (k >= 1) at (k-1) n, u_k at N n + k m, row l of C_k z_k at N (n+m) + k nc + l, then C_N x_N.
# The reductions (sums, maxima) may be reassociated and multiply-adds contracted (no NaN/inf
# assumptions, so non-finite values still propagate): results agree with the plain loops up to rounding.
_REASSOC = {"reassoc", "contract", "nsz"}

def _size(x):
    """Block size from a size argument of a compiled kernel: an int (run-time size) or a size tag
    (olado.linalg.riccati._size_tags: a tuple whose length is the size, a compile-time constant)."""
    return x if isinstance(x, int) else len(x)


@overload(_size)
def _size_overload(x):
    if isinstance(x, types.Integer):
        return lambda x: x
    return lambda x: len(x)


def _work(x):
    """A float workspace of size _size(x): on the heap for an int, on the stack for a size tag."""
    return np.empty(_size(x))


@overload(_work)
def _work_overload(x):
    if isinstance(x, types.Integer):
        return lambda x: np.empty(x)
    return lambda x: _stack_vector(x)


@nb.njit(inline="always")
def _add_row_terms(k, nz, ne, nc, os_, nu, eqm, EF, C, zl, zu, g):
    """g += sum_l nu_kl eqm_kl [E F]_k[l, :] + sum_l (zu - zl)_(stage row l) C_k[l, :]: the stage
    rows' part of the Lagrangian gradient of stage k (both _kkt_map kernels)."""
    for l in range(ne):
        t = nu[k, l] * eqm[k, l]
        if t != 0.0:
            for i in range(nz):
                g[i] += EF[k, l, i] * t
    for l in range(nc):
        idx = os_ + k * nc + l
        t = zu[idx] - zl[idx]
        if t != 0.0:
            for i in range(nz):
                g[i] += C[k, l, i] * t


@nb.njit(inline="always")
def _kkt_final_stage(N, n, QN, X, lam, nu, EN, CN, zl, zu, bx, bx0, beN, rx, x0r, rEN, w, osN, hz, g,
                     dmax, xmax, hmax, obj, pmax):
    """The final stage of _kkt_map (both kernels): rx[N], x0r, rEN, the final rows' values
    C_N x_N into w, and the measures updated (hz, g: work vectors of length >= n)."""
    ncN = CN.shape[0]
    neN = EN.shape[0]
    for i in range(n):
        t = 0.0
        for j in range(n):
            t += QN[i, j] * X[N, j]
        hz[i] = t
    for i in range(n):
        g[i] = hz[i] - lam[N, i]
    for l in range(neN):
        t = nu[N, l]
        for i in range(n):
            g[i] += EN[l, i] * t
    if N >= 1:
        for i in range(n):
            idx = (N - 1) * n + i
            g[i] += zu[idx] - zl[idx]
    for l in range(ncN):
        t = zu[osN + l] - zl[osN + l]
        for i in range(n):
            g[i] += CN[l, i] * t
    for i in range(n):
        v = g[i] + bx[N, i]
        rx[N, i] = v
        dmax = max(dmax, abs(v))
        xmax = max(xmax, abs(X[N, i]))
        hmax = max(hmax, abs(hz[i]))
        obj += 0.5 * X[N, i] * hz[i] + bx[N, i] * X[N, i]
    for i in range(n):
        v = bx0[i] - X[0, i]
        x0r[i] = v
        pmax = max(pmax, abs(v))
    for l in range(neN):
        s = 0.0
        for j in range(n):
            s += EN[l, j] * X[N, j]
        v = s + beN[l]
        rEN[l] = v
        pmax = max(pmax, abs(v))
    for l in range(ncN):
        s = 0.0
        for j in range(n):
            s += CN[l, j] * X[N, j]
        w[osN + l] = s
    return dmax, xmax, hmax, obj, pmax


@nb.njit(inline="always")
def _kkt_row_boxes(i0, i1, al, au, fl, fu, tl, tu, zl, zu, rl, rup, w, pmax, comp):
    """The box residuals rl, rup of the flat boxes i0..i1-1 of _kkt_map (values w), the primal
    max-norm and the complementarity sum updated."""
    for idx in range(i0, i1):
        comp += zl[idx] * tl[idx] + zu[idx] * tu[idx]
        if fl[idx]:
            v = w[idx] + al[idx] - tl[idx]
            rl[idx] = v
            pmax = max(pmax, abs(v))
        else:
            rl[idx] = 0.0
        if fu[idx]:
            v = au[idx] - w[idx] - tu[idx]
            rup[idx] = v
            pmax = max(pmax, abs(v))
        else:
            rup[idx] = 0.0
    return pmax, comp


@nb.njit(cache=True, fastmath=_REASSOC)
def _kkt_map_loops(sizes, H, QN, AB, EF, EFt, eqm, EN, C, Ct, CN, al, au, fl, fu,
                   X, U, lam, nu, tl, tu, zl, zu, bx, bu, bdyn, bx0, be, beN,
                   rx, ru, dyn, x0r, rE, rEN, rl, rup, w, stats):
    """_kkt_map with loops over the blocks (the any-size kernel; see _kkt_map)."""
    nt, mt, zt = sizes[0], sizes[1], sizes[2]
    n, m, nz = _size(nt), _size(mt), _size(zt)
    z, hz, g, ax = _work(zt), _work(zt), _work(zt), _work(nt)
    N = AB.shape[0]
    ne = EF.shape[1]
    neN = EN.shape[0]
    nc = C.shape[1]
    ncN = CN.shape[0]
    ou = N * n
    os_ = ou + N * m
    osN = os_ + N * nc
    ae = np.empty(max(ne, 1))
    ac = np.empty(max(nc, 1))
    pmax = 0.0
    dmax = 0.0
    xmax = 0.0
    hmax = 0.0
    obj = 0.0
    for k in range(N):
        for i in range(n):
            z[i] = X[k, i]
        for i in range(m):
            z[n + i] = U[k, i]
        for i in range(nz):
            t = 0.0
            for j in range(nz):
                t += H[k, i, j] * z[j]
            hz[i] = t
        for i in range(n):
            t = 0.0
            for j in range(nz):
                t += AB[k, i, j] * z[j]
            ax[i] = t
        for i in range(ne):
            ae[i] = 0.0
        for i in range(nc):
            ac[i] = 0.0
        for j in range(nz):
            t = z[j]
            for i in range(ne):
                ae[i] += EFt[k, j, i] * t
            for i in range(nc):
                ac[i] += Ct[k, j, i] * t
        for i in range(nz):
            g[i] = hz[i]
        # constraint part of the Lagrangian gradient
        for l in range(n):
            t = lam[k + 1, l]
            for i in range(nz):
                g[i] += AB[k, l, i] * t
        for i in range(n):
            g[i] -= lam[k, i]
        _add_row_terms(k, nz, ne, nc, os_, nu, eqm, EF, C, zl, zu, g)
        if k >= 1:
            for i in range(n):
                idx = (k - 1) * n + i
                g[i] += zu[idx] - zl[idx]
        for i in range(m):
            idx = ou + k * m + i
            g[n + i] += zu[idx] - zl[idx]
        for i in range(n):
            v = g[i] + bx[k, i]
            rx[k, i] = v
            dmax = max(dmax, abs(v))
        for i in range(m):
            v = g[n + i] + bu[k, i]
            ru[k, i] = v
            dmax = max(dmax, abs(v))
        # measures
        for i in range(nz):
            xmax = max(xmax, abs(z[i]))
            hmax = max(hmax, abs(hz[i]))
            obj += 0.5 * z[i] * hz[i]
        for i in range(n):
            obj += bx[k, i] * z[i]
        for i in range(m):
            obj += bu[k, i] * z[n + i]
        # dynamics, equality rows
        for i in range(n):
            v = ax[i] - X[k + 1, i] + bdyn[k, i]
            dyn[k, i] = v
            pmax = max(pmax, abs(v))
        for l in range(ne):
            v = ae[l] * eqm[k, l] + be[k, l]
            rE[k, l] = v
            pmax = max(pmax, abs(v))
        # box values w of x_k (k >= 1), u_k and C_k z_k
        if k >= 1:
            for i in range(n):
                w[(k - 1) * n + i] = z[i]
        for i in range(m):
            w[ou + k * m + i] = z[n + i]
        for l in range(nc):
            w[os_ + k * nc + l] = ac[l]
    # final stage
    dmax, xmax, hmax, obj, pmax = _kkt_final_stage(N, n, QN, X, lam, nu, EN, CN, zl, zu, bx, bx0, beN, rx, x0r, rEN,
                                                   w, osN, hz, g, dmax, xmax, hmax, obj, pmax)
    if N >= 1:
        for i in range(n):
            w[(N - 1) * n + i] = X[N, i]
    pmax, comp = _kkt_row_boxes(0, w.shape[0], al, au, fl, fu, tl, tu, zl, zu, rl, rup, w, pmax, 0.0)
    stats[0] = pmax
    stats[1] = dmax
    stats[2] = xmax
    stats[3] = hmax
    stats[4] = obj
    stats[5] = comp


# The fixed-size _kkt_map (_kkt_map_fixed): the stage loop calls _kkt_stage, an intrinsic that
# writes one stage as straight-line SIMD code on pieces of 4, 2 and 1 doubles (as _eliminate_stage
# in olado.linalg.riccati, whose _pieces and _ContractRowCode it reuses): H z = sum_j z_j H[j, :] and
# g = H z + sum_l lam_{k+1,l} [A B][l, :] as axpys over the rows of H and [A B] (H is symmetric),
# [A B] z as row products summed by a transposing reduction.  The box residuals follow in a
# second pass over the flat box vectors, branch-free (selects on the fl/fu masks) in chunks of
# _KKT_CHUNK entries (_kkt_boxes): fused into the stage pass they would add some 20 concurrent
# memory streams, which made it slower than the scalar loops once the arrays leave the caches.
# The measures stay in vector accumulators on the stack (maxima as select(v > acc, v, acc) lane by
# lane, exactly what max(acc, v) does: NaN is skipped, inf kept; sums reassociated), reduced at
# the end (_kkt_acc_reduce).
_KKT_MAX = ("p", "d", "x", "h", "bp")   # max |primal| (stages, boxes), max |dual|, max |z|, max |H z|
_KKT_SUM = ("oh", "ob", "bc")           # sum z.H z, sum b.z, sum zl tl + zu tu
_KKT_CHUNK = 8                          # box entries per _kkt_boxes
_I8 = llir.IntType(8)
_I64 = llir.IntType(64)


def _kkt_layouts(n, m):
    """(box pieces, matrix pieces, accumulator slots {(name, width): offset}, carry offset, size)
    of _kkt_stage: box pieces cover x (columns 0..n-1) and u (n..n+m-1) separately, matrix pieces
    the n + m columns of z; the carry holds the multipliers zu - zl of x_{k+1} for stage k + 1."""
    bp = _pieces(0, n) + _pieces(n, m)
    mp = _pieces(0, n + m)
    bw = sorted({w for _, w in bp})
    mw = sorted({w for _, w in mp})
    slots, off = {}, 0
    for name in _KKT_MAX + _KKT_SUM:
        for w in (mw if name in ("h", "oh") else [4] if name in ("bp", "bc") else bw):
            slots[(name, w)] = off
            off += w
    return bp, mp, slots, off, off + n


class _KktRowCode(_ContractRowCode):
    """_ContractRowCode (olado.linalg.riccati) with what _kkt_stage needs besides: absolute
    values, maxima with max()'s semantics, masks, conversions between piece layouts."""

    def const(self, x, w):
        return llir.Constant(self.vtype(w), x if w == 1 else [x] * w)

    def abs(self, v, w):
        fn = cgutils.get_or_insert_function(self.b.module, llir.FunctionType(self.vtype(w), [self.vtype(w)]),
                                            "llvm.fabs.f64" if w == 1 else f"llvm.fabs.v{w}f64")
        return self.b.call(fn, [v])

    def max(self, acc, v):
        """max(acc, v) of numba (lane by lane): v if v > acc else acc."""
        return self.b.select(self.b.fcmp_ordered(">", v, acc), v, acc)

    def at(self, data, offset):
        return self.b.gep(data, [offset])

    def row(self, data, pieces, shift=0):
        """The pieces of a row at data (column c0 at data + c0 - shift)."""
        return [(c0, w, self.load(data, 0, 0, c0 - shift, w)) for c0, w in pieces]

    def mask(self, data, j, w):
        """Lanes j..j+w-1 of a boolean array as i1 (vector)."""
        p = self.b.gep(data, [llir.Constant(_I64, j)])
        if w > 1:
            p = self.b.bitcast(p, llir.VectorType(_I8, w).as_pointer())
        v = self.b.load(p, align=1)
        return self.b.icmp_unsigned("!=", v, llir.Constant(v.type, None))

    def repiece(self, row, pieces):
        """The same values in other pieces (shuffles)."""
        have = {(c0, w): v for c0, w, v in row}
        out = []
        for c0, w in pieces:
            if (c0, w) in have:
                out.append((c0, w, have[(c0, w)]))
            elif w == 1:
                out.append((c0, w, self.entry(row, c0)))
            else:
                v = llir.Constant(self.vtype(w), llir.Undefined)
                for j in range(w):
                    v = self.b.insert_element(v, self.entry(row, c0 + j), llir.Constant(_I32, j))
                out.append((c0, w, v))
        return out


def _is_c_array(t, dtype=types.float64, ndim=None):
    return isinstance(t, types.Array) and t.dtype == dtype and t.layout == "C" and (ndim is None or t.ndim == ndim)


@intrinsic
def _kkt_acc(typingctx, tags):
    """The accumulators (and the carry) of _kkt_stage on the stack, zeroed."""
    n, m = len(tags[0]), len(tags[1])
    size = _kkt_layouts(n, m)[4]

    def codegen(context, builder, signature, args):
        p = cgutils.alloca_once(builder, _F64, size=context.get_constant(types.intp, size))
        for i in range(size):
            builder.store(llir.Constant(_F64, 0.0), builder.gep(p, [llir.Constant(_I64, i)]))
        return p
    return types.CPointer(types.float64)(tags), codegen


@intrinsic
def _kkt_acc_reduce(typingctx, tags, acc):
    """(max |primal|, max |dual|, max |z|, max |H z|, objective, complementarity) of the
    accumulators of _kkt_stage."""
    n, m = len(tags[0]), len(tags[1])
    slots = _kkt_layouts(n, m)[2]

    def codegen(context, builder, signature, args):
        g = _KktRowCode(builder)
        p = args[1]
        out = {}
        for (name, w), off in slots.items():
            name = {"bp": "p", "bc": "c"}.get(name, name)
            for j in range(w):
                v = g.load(p, 0, 0, off + j)
                if name not in out:
                    out[name] = v
                elif name in ("p", "d", "x", "h"):
                    out[name] = g.max(out[name], v)
                else:
                    out[name] = g.add(out[name], v)
        obj = g.add(g.mul(llir.Constant(_F64, 0.5), out["oh"]), out["ob"])
        vals = [out["p"], out["d"], out["x"], out["h"], obj, out["c"]]
        return context.make_tuple(builder, signature.return_type, vals)
    return types.UniTuple(types.float64, 6)(tags, acc), codegen


@intrinsic
def _kkt_stage(typingctx, tags, k, ou, H, AB, X, U, lam, bx, bu, bdyn, rx, ru, dyn, zl, zu, ge, acc):
    """Stage k of _kkt_map_fixed as straight-line SIMD code (see the comment above): for the
    sizes of tags = _size_tags(n, m, n + m) and C-contiguous float64 arrays of the shapes of
    _kkt_map; ou = N n (the offset of the u boxes), ge = None or the stage's further gradient
    terms E^T nu + C^T (zu - zl) (n + m values), acc from _kkt_acc.  Writes rx[k], ru[k],
    dyn[k]; updates the accumulators and carries zu - zl of x_{k+1} to stage k + 1."""
    if not (all(_is_c_array(a) for a in (H, AB, X, U, lam, bx, bu, bdyn, rx, ru, dyn, zl, zu))
            and (ge == types.none or _is_c_array(ge, ndim=1))
            and isinstance(k, types.Integer) and isinstance(ou, types.Integer)):
        return None
    n, m = len(tags[0]), len(tags[1])
    nz = n + m
    bp, mp, slots, carry, _ = _kkt_layouts(n, m)
    xp, up = bp[:len(_pieces(0, n))], bp[len(_pieces(0, n)):]
    W = max(w_ for _, w_ in mp)
    names = ("H", "AB", "X", "U", "lam", "bx", "bu", "bdyn", "rx", "ru", "dyn", "zl", "zu", "ge")

    def codegen(context, builder, signature, args):
        g = _KktRowCode(builder)
        data = {name: context.make_array(t)(context, builder, v).data
                for name, t, v in zip(names, signature.args[3:-1], args[3:-1]) if t != types.none}
        accp = args[-1]
        c = lambda v: llir.Constant(_I64, v)  # noqa: E731
        kk = builder.sext(args[1], _I64) if args[1].type.width < 64 else args[1]
        oub = builder.sext(args[2], _I64) if args[2].type.width < 64 else args[2]
        kn, km = builder.mul(kk, c(n)), builder.mul(kk, c(m))
        Hk = g.at(data["H"], builder.mul(kk, c(nz * nz)))
        ABk = g.at(data["AB"], builder.mul(kk, c(n * nz)))
        Xk, Xk1 = g.at(data["X"], kn), g.at(data["X"], builder.add(kn, c(n)))
        Uk = g.at(data["U"], km)
        lamk, lamk1 = g.at(data["lam"], kn), g.at(data["lam"], builder.add(kn, c(n)))
        bxk, buk, bdk = g.at(data["bx"], kn), g.at(data["bu"], km), g.at(data["bdyn"], kn)
        rxk, ruk, dynk = g.at(data["rx"], kn), g.at(data["ru"], km), g.at(data["dyn"], kn)
        ouk = builder.add(oub, km)       # flat offsets of the boxes of x_{k+1} (kn) and u_k
        acc = {key: g.load(accp, 0, 0, off, key[1]) for key, off in slots.items() if key[0] not in ("bp", "bc")}

        def acc_max(name, v, w_):
            acc[(name, w_)] = g.max(acc[(name, w_)], g.abs(v, w_))

        def acc_add(name, v, w_):
            acc[(name, w_)] = g.add(acc[(name, w_)], v)

        # ---- loads
        zB = g.row(Xk, xp) + g.row(Uk, up, n)            # z in box pieces
        zM = g.repiece(zB, mp)                           # z in matrix pieces
        zs = [g.load(Xk, 0, 0, j) if j < n else g.load(Uk, 0, 0, j - n) for j in range(nz)]
        xn = g.row(Xk1, xp)
        bB = g.row(bxk, xp) + g.row(buk, up, n)
        zdiff = lambda o, c0, w_: g.sub(g.load(g.at(data["zu"], o), 0, 0, c0, w_),  # noqa: E731
                                        g.load(g.at(data["zl"], o), 0, 0, c0, w_))
        dx = [(c0, w_, zdiff(kn, c0, w_)) for c0, w_ in xp]          # zu - zl of x_{k+1}
        du = [(c0, w_, zdiff(ouk, c0 - n, w_)) for c0, w_ in up]     # zu - zl of u_k
        # ---- H z = sum_j z_j H[j, :], g = H z + sum_l lam_{k+1,l} AB[l, :]
        hz = g.scale(g.row(Hk, mp), zs[0])
        for j in range(1, nz):
            hz = g.axpy(hz, zs[j], g.row(g.at(Hk, c(j * nz)), mp))
        ABrows = [g.row(g.at(ABk, c(l * nz)), mp) for l in range(n)]
        gr = hz
        for l in range(n):
            gr = g.axpy(gr, g.load(lamk1, 0, 0, l), ABrows[l])
        if "ge" in data:
            gr = [(c0, w_, g.add(v, u)) for (c0, w_, v), (_, _, u) in zip(gr, g.row(data["ge"], mp))]
        # ---- [A B] z: the products of the full-width pieces summed by rows (a transposing
        # reduction), those of narrower pieces added by columns
        full = [c0 for c0, w_ in mp if w_ == W]
        narrow = [j for c0, w_ in mp if w_ < W for j in range(c0, c0 + w_)]
        zMd = {c0: v for c0, w_, v in zM}
        V = []
        for l in range(n):
            rowd = {c0: v for c0, w_, v in ABrows[l]}
            s = g.mul(rowd[full[0]], zMd[full[0]])
            for c0 in full[1:]:
                s = g.add(s, g.mul(rowd[c0], zMd[c0]))
            V.append(s)
        ax = []
        for r0, wo in xp:
            v = g.row_sums(V[r0:r0 + wo], W)
            v = v if wo == W else g.lanes(v, 0, wo)
            for j in narrow:        # column j of the rows r0.. of AB
                col = g.repiece([(r0 + i, 1, g.load(ABk, nz, r0 + i, j)) for i in range(wo)], [(r0, wo)])[0][2]
                v = g.add(v, g.mul(col, g.splat(zs[j], wo)))
            ax.append((r0, wo, v))
        # ---- measures
        for (c0, w_, zv), (_, _, bv) in zip(zB, bB):
            acc_max("x", zv, w_)
            acc_add("ob", g.mul(bv, zv), w_)
        for (c0, w_, hv), (_, _, zv) in zip(hz, zM):
            acc_max("h", hv, w_)
            acc_add("oh", g.mul(zv, hv), w_)
        stores = []
        # ---- gradient rows rx[k], ru[k]
        gB = g.repiece(gr, bp)
        for c0, w_, v in gB[:len(xp)]:
            v = g.add(g.add(g.sub(v, g.load(lamk, 0, 0, c0, w_)), g.load(accp, 0, 0, carry + c0, w_)),
                      g.load(bxk, 0, 0, c0, w_))
            stores.append((v, rxk, c0, w_))
            acc_max("d", v, w_)
        for (c0, w_, v), (_, _, d) in zip(gB[len(xp):], du):
            v = g.add(g.add(v, d), g.load(buk, 0, 0, c0 - n, w_))
            stores.append((v, ruk, c0 - n, w_))
            acc_max("d", v, w_)
        # ---- dynamics
        for (r0, w_, a), (_, _, xv) in zip(ax, xn):
            v = g.add(g.sub(a, xv), g.load(bdk, 0, 0, r0, w_))
            stores.append((v, dynk, r0, w_))
            acc_max("p", v, w_)
        # ---- stores (after all loads)
        for c0, w_, d in dx:
            stores.append((d, accp, carry + c0, w_))
        for v, p, j, w_ in stores:
            g.store(v, p, 0, 0, j, w_)
        for key, v in acc.items():
            g.store(v, accp, 0, 0, slots[key], key[1])
        return context.get_dummy_value()
    return types.none(tags, k, ou, H, AB, X, U, lam, bx, bu, bdyn, rx, ru, dyn, zl, zu, ge, acc), codegen


@intrinsic
def _kkt_boxes(typingctx, tags, src, so, i0, al, au, fl, fu, tl, tu, zl, zu, rl, rup, w, acc):
    """The box residuals of _KKT_CHUNK entries i0.. of the flat box vectors with the values
    w[i0 + j] = src.flat[so + j], branch-free (selects on the masks fl, fu); updates the box
    accumulators ("bp", "bc") of acc."""
    if not (all(_is_c_array(a) for a in (src, al, au, tl, tu, zl, zu, rl, rup, w))
            and _is_c_array(fl, types.boolean, 1) and _is_c_array(fu, types.boolean, 1)
            and isinstance(so, types.Integer) and isinstance(i0, types.Integer)):
        return None
    slots = _kkt_layouts(len(tags[0]), len(tags[1]))[2]
    names = ("al", "au", "fl", "fu", "tl", "tu", "zl", "zu", "rl", "rup", "w")

    def codegen(context, builder, signature, args):
        g = _KktRowCode(builder)
        sx = lambda v: builder.sext(v, _I64) if v.type.width < 64 else v  # noqa: E731
        so_, i0_ = sx(args[2]), sx(args[3])
        vals = g.at(context.make_array(signature.args[1])(context, builder, args[1]).data, so_)
        data = {}
        for name, t, v in zip(names, signature.args[4:-1], args[4:-1]):
            p = context.make_array(t)(context, builder, v).data
            data[name] = g.at(builder.bitcast(p, _I8.as_pointer()) if name in ("fl", "fu") else p, i0_)
        accp = args[-1]
        ap, ac = g.load(accp, 0, 0, slots[("bp", 4)], 4), g.load(accp, 0, 0, slots[("bc", 4)], 4)
        stores = []
        for j, w_ in _pieces(0, _KKT_CHUNK):
            v = g.load(vals, 0, 0, j, w_)
            ld = {name: g.load(data[name], 0, 0, j, w_) for name in ("al", "au", "tl", "tu", "zl", "zu")}
            zero = g.const(0.0, w_)
            vl = builder.select(g.mask(data["fl"], j, w_), g.sub(g.add(v, ld["al"]), ld["tl"]), zero)
            vu = builder.select(g.mask(data["fu"], j, w_), g.sub(g.sub(ld["au"], v), ld["tu"]), zero)
            stores += [(v, data["w"], j, w_), (vl, data["rl"], j, w_), (vu, data["rup"], j, w_)]
            ap = g.max(ap, g.abs(vl, w_))
            ap = g.max(ap, g.abs(vu, w_))
            ac = g.add(ac, g.add(g.mul(ld["zl"], ld["tl"]), g.mul(ld["zu"], ld["tu"])))
        for v, p, j, w_ in stores:
            g.store(v, p, 0, 0, j, w_)
        g.store(ap, accp, 0, 0, slots[("bp", 4)], 4)
        g.store(ac, accp, 0, 0, slots[("bc", 4)], 4)
        return context.get_dummy_value()
    return types.none(tags, src, so, i0, al, au, fl, fu, tl, tu, zl, zu, rl, rup, w, acc), codegen


@nb.njit(inline="always", fastmath=_REASSOC)
def _kkt_boxes_range(tags, src, so, start, stop, al, au, fl, fu, tl, tu, zl, zu, rl, rup, w, acc, pmax, comp):
    """The box residuals of the entries start..stop-1 with the values w[i] = src.flat[so + i - start]
    (_kkt_boxes on chunks, a loop on the rest); returns the updated (pmax, comp) of the rest."""
    i = start
    while i + _KKT_CHUNK <= stop:
        _kkt_boxes(tags, src, so + i - start, i, al, au, fl, fu, tl, tu, zl, zu, rl, rup, w, acc)
        i += _KKT_CHUNK
    vals = src.reshape(src.size)
    for idx in range(i, stop):
        w[idx] = vals[so + idx - start]
    return _kkt_row_boxes(i, stop, al, au, fl, fu, tl, tu, zl, zu, rl, rup, w, pmax, comp)


@nb.njit(cache=True, fastmath=_REASSOC)
def _kkt_map_fixed(tags, H, QN, AB, EF, EFt, eqm, EN, C, Ct, CN, al, au, fl, fu,
                   X, U, lam, nu, tl, tu, zl, zu, bx, bu, bdyn, bx0, be, beN,
                   rx, ru, dyn, x0r, rE, rEN, rl, rup, w, stats):
    """_kkt_map for the sizes of tags = _size_tags(n, m, n + m) and C-contiguous arrays: the
    stages by _kkt_stage, the stage-row and equality terms, the final stage and the boxes of the
    stage and final rows by loops."""
    nt, mt, zt = tags.n, tags.m, tags.nz
    n, m, nz = len(nt), len(mt), len(zt)
    N = AB.shape[0]
    ne = EF.shape[1]
    neN = EN.shape[0]
    nc = C.shape[1]
    ncN = CN.shape[0]
    ou = N * n
    os_ = ou + N * m
    osN = os_ + N * nc
    acc = _kkt_acc(tags)
    pmax = 0.0
    if ne > 0 or nc > 0:
        ge = _stack_vector(zt)
        for k in range(N):
            for i in range(nz):
                ge[i] = 0.0
            _add_row_terms(k, nz, ne, nc, os_, nu, eqm, EF, C, zl, zu, ge)
            _kkt_stage(tags, k, ou, H, AB, X, U, lam, bx, bu, bdyn, rx, ru, dyn, zl, zu, ge, acc)
            for l in range(ne):
                s = 0.0
                for j in range(n):
                    s += EFt[k, j, l] * X[k, j]
                for j in range(m):
                    s += EFt[k, n + j, l] * U[k, j]
                v = s * eqm[k, l] + be[k, l]
                rE[k, l] = v
                pmax = max(pmax, abs(v))
            for l in range(nc):
                s = 0.0
                for j in range(n):
                    s += C[k, l, j] * X[k, j]
                for j in range(m):
                    s += C[k, l, n + j] * U[k, j]
                w[os_ + k * nc + l] = s
    else:
        for k in range(N):
            _kkt_stage(tags, k, ou, H, AB, X, U, lam, bx, bu, bdyn, rx, ru, dyn, zl, zu, None, acc)
    # boxes of x_1..x_N (values X[1:]) and u (values U)
    pmax, comp = _kkt_boxes_range(tags, X, n, 0, ou, al, au, fl, fu, tl, tu, zl, zu, rl, rup, w, acc, pmax, 0.0)
    pmax, comp = _kkt_boxes_range(tags, U, 0, ou, os_, al, au, fl, fu, tl, tu, zl, zu, rl, rup, w, acc, pmax, comp)
    p_acc, dmax, xmax, hmax, obj, c_acc = _kkt_acc_reduce(tags, acc)
    pmax = max(pmax, p_acc)
    comp += c_acc
    # final stage
    hz = _stack_vector(nt)
    g = _stack_vector(nt)
    dmax, xmax, hmax, obj, pmax = _kkt_final_stage(N, n, QN, X, lam, nu, EN, CN, zl, zu, bx, bx0, beN, rx, x0r, rEN,
                                                   w, osN, hz, g, dmax, xmax, hmax, obj, pmax)
    # boxes of the stage and final rows
    pmax, comp = _kkt_row_boxes(os_, w.shape[0], al, au, fl, fu, tl, tu, zl, zu, rl, rup, w, pmax, comp)
    stats[0] = pmax
    stats[1] = dmax
    stats[2] = xmax
    stats[3] = hmax
    stats[4] = obj
    stats[5] = comp


def _kkt_map_kernel(sizes, H, QN, AB, EF, EFt, eqm, EN, C, Ct, CN, al, au, fl, fu,
                    X, U, lam, nu, tl, tu, zl, zu, bx, bu, bdyn, bx0, be, beN,
                    rx, ru, dyn, x0r, rE, rEN, rl, rup, w, stats):
    """_kkt_map_fixed or _kkt_map_loops, chosen by the argument types."""


def _kkt_fixed_applies(sizes, H, QN, AB, EF, EFt, eqm, EN, C, Ct, CN, al, au, fl, fu,
                       X, U, lam, nu, tl, tu, zl, zu, bx, bu, bdyn, bx0, be, beN,
                       rx, ru, dyn, x0r, rE, rEN, rl, rup, w, stats):
    """Whether _kkt_map with arguments of these numba types runs _kkt_map_fixed: size tags of
    n, m >= 1 and C-contiguous arrays where _kkt_stage and _kkt_boxes read and write."""
    tagged = isinstance(sizes, types.BaseNamedTuple) and sizes.instance_class is SizeTags
    return (tagged and len(sizes[0]) > 0 and len(sizes[1]) > 0
            and all(_is_c_array(a) for a in (H, AB, X, U, lam, bx, bu, bdyn, rx, ru, dyn, al, au, tl, tu, zl, zu,
                                              rl, rup, w))
            and _is_c_array(fl, types.boolean, 1) and _is_c_array(fu, types.boolean, 1))


@overload(_kkt_map_kernel)
def _kkt_map_kernel_overload(sizes, H, QN, AB, EF, EFt, eqm, EN, C, Ct, CN, al, au, fl, fu,
                             X, U, lam, nu, tl, tu, zl, zu, bx, bu, bdyn, bx0, be, beN,
                             rx, ru, dyn, x0r, rE, rEN, rl, rup, w, stats):
    fixed = _kkt_fixed_applies(sizes, H, QN, AB, EF, EFt, eqm, EN, C, Ct, CN, al, au, fl, fu,
                               X, U, lam, nu, tl, tu, zl, zu, bx, bu, bdyn, bx0, be, beN,
                               rx, ru, dyn, x0r, rE, rEN, rl, rup, w, stats)
    kernel = _kkt_map_fixed if fixed else _kkt_map_loops

    def impl(sizes, H, QN, AB, EF, EFt, eqm, EN, C, Ct, CN, al, au, fl, fu,
             X, U, lam, nu, tl, tu, zl, zu, bx, bu, bdyn, bx0, be, beN,
             rx, ru, dyn, x0r, rE, rEN, rl, rup, w, stats):
        kernel(sizes, H, QN, AB, EF, EFt, eqm, EN, C, Ct, CN, al, au, fl, fu,
               X, U, lam, nu, tl, tu, zl, zu, bx, bu, bdyn, bx0, be, beN,
               rx, ru, dyn, x0r, rE, rEN, rl, rup, w, stats)
    return impl


@nb.njit(cache=True)
def _kkt_map(sizes, H, QN, AB, EF, EFt, eqm, EN, C, Ct, CN, al, au, fl, fu,
             X, U, lam, nu, tl, tu, zl, zu, bx, bu, bdyn, bx0, be, beN,
             rx, ru, dyn, x0r, rE, rEN, rl, rup, w, stats):
    """The equations of the KKT system at (X, U, lam, nu, tl, tu, zl, zu) with offsets b:

        rx, ru = H z + (A^T lam_+ - lam, B^T lam_+) + E^T nu + C^T (zu - zl) + box (zu - zl) + (bx, bu)
        dyn = A x + B u - x_+ + bdyn,  x0r = bx0 - x_0,  rE = E z + be,  rEN = E_N x_N + beN
        rl = w + al - tl,  rup = au - w - tu   (finite sides)

    (the residuals of the iterate with b = (q, r, c, x0, e, eN), al = -lo, au = hi, or the
    Newton residual of a direction with b = the right-hand side's residuals).  stats receives
    max |primal parts|, max |rx, ru|, max |X, U|, max |H z|, 1/2 z.H z + bx.X + bu.U and the
    complementarity sum(zl tl + zu tu).
    H (N, n+m, n+m) and QN are symmetric (the symmetric parts of the QP's blocks), so H z is
    computed row-wise; AB = [A B] serves both A x + B u (rows) and A^T lam, B^T lam (axpy).
    ``sizes`` = (n, m, n + m) as ints, or as size tags for a kernel compiled for those sizes
    (_kkt_map_call chooses): _kkt_map_fixed (straight-line SIMD stages) when the arrays are
    C-contiguous (as in the solver), else the loop kernel _kkt_map_loops."""
    _kkt_map_kernel(sizes, H, QN, AB, EF, EFt, eqm, EN, C, Ct, CN, al, au, fl, fu,
                    X, U, lam, nu, tl, tu, zl, zu, bx, bu, bdyn, bx0, be, beN,
                    rx, ru, dyn, x0r, rE, rEN, rl, rup, w, stats)


def _kkt_map_call(P, *args):
    """_kkt_map of the prepared problem P (the fixed-size kernel when its blocks are small)."""
    _kkt_map(P.sizes, P.H, P.QN, P.AB, P.EF, P.EFt, P.eqm, P.EN, P.C, P.Ct, P.CN, *args)


@nb.njit(cache=True)
def _complementarity_residual(rho_l, rho_u, tl, tu, zl, zu, dtl, dtu, dzl, dzu, el, eu):
    """el = rho_l - zl dtl - tl dzl, eu = rho_u - zu dtu - tu dzu; returns max |el, eu|."""
    big = 0.0
    for i in range(tl.shape[0]):
        a = rho_l[i] - zl[i] * dtl[i] - tl[i] * dzl[i]
        b = rho_u[i] - zu[i] * dtu[i] - tu[i] * dzu[i]
        el[i] = a
        eu[i] = b
        big = max(big, abs(a), abs(b))
    return big


@nb.njit(cache=True)
def _scaling(tl, tu, zl, zu, fl, fu, inv_tl, inv_tu, D):
    """1/t on the finite sides (0 elsewhere) and D = zl/tl + zu/tu."""
    for i in range(tl.shape[0]):
        a = 1.0 / tl[i] if fl[i] else 0.0
        b = 1.0 / tu[i] if fu[i] else 0.0
        inv_tl[i] = a
        inv_tu[i] = b
        D[i] = zl[i] * a + zu[i] * b


@nb.njit(cache=True)
def _newton_rhs(rx, ru, rl, rup, rho_l, rho_u, zl, zu, inv_tl, inv_tu, Ds, CN, q, r, ci):
    """Eliminate (dtl, dtu, dzl, dzu): g = (rho_u - zu rup)/tu - (rho_l - zl rl)/tl enters the
    gradient (q, r; C_N^T g for final rows) and the stage-row constants ci = g / D."""
    N = ru.shape[0]
    n = rx.shape[1]
    m = ru.shape[1]
    nc = Ds.shape[1]
    ncN = CN.shape[0]
    ou = N * n
    os_ = ou + N * m
    osN = os_ + N * nc
    for i in range(n):
        q[0, i] = rx[0, i]
    for k in range(1, N + 1):
        for i in range(n):
            idx = (k - 1) * n + i
            g = (rho_u[idx] - zu[idx] * rup[idx]) * inv_tu[idx] - (rho_l[idx] - zl[idx] * rl[idx]) * inv_tl[idx]
            q[k, i] = rx[k, i] + g
    for k in range(N):
        for i in range(m):
            idx = ou + k * m + i
            g = (rho_u[idx] - zu[idx] * rup[idx]) * inv_tu[idx] - (rho_l[idx] - zl[idx] * rl[idx]) * inv_tl[idx]
            r[k, i] = ru[k, i] + g
        for l in range(nc):
            idx = os_ + k * nc + l
            g = (rho_u[idx] - zu[idx] * rup[idx]) * inv_tu[idx] - (rho_l[idx] - zl[idx] * rl[idx]) * inv_tl[idx]
            d = Ds[k, l]
            ci[k, l] = g / d if d > 0 else 0.0
    for l in range(ncN):
        idx = osN + l
        g = (rho_u[idx] - zu[idx] * rup[idx]) * inv_tu[idx] - (rho_l[idx] - zl[idx] * rl[idx]) * inv_tl[idx]
        for i in range(n):
            q[N, i] += CN[l, i] * g


@nb.njit(cache=True)
def _recover_step(dX, dU, Ct, CN, rl, rup, rho_l, rho_u, tl, tu, zl, zu, inv_tl, inv_tu, fl, fu, dtl, dtu, dzl, dzu, w):
    """After the KKT solve: dtl = dw + rl, dtu = -dw + rup, dzl = (rho_l - zl dtl)/tl,
    dzu = (rho_u - zu dtu)/tu.  Returns (ok, ap, ad): ok False if dX or dU is not finite; ap, ad
    the largest primal (slacks) and dual (multipliers) step lengths along the direction (as
    _max_step_split, in the same pass; min(ap, ad) is _max_step's common one)."""
    N = dU.shape[0]
    n = dX.shape[1]
    m = dU.shape[1]
    nc = Ct.shape[2]
    ncN = CN.shape[0]
    ou = N * n
    os_ = ou + N * m
    osN = os_ + N * nc
    ap = 1e30
    ad = 1e30
    inf = np.inf
    for k in range(N + 1):
        for i in range(n):
            if not np.isfinite(dX[k, i]):
                return False, ap, ad
    for k in range(N):
        for i in range(m):
            if not np.isfinite(dU[k, i]):
                return False, ap, ad
    for k in range(1, N + 1):
        for i in range(n):
            w[(k - 1) * n + i] = dX[k, i]
    for k in range(N):
        for i in range(m):
            w[ou + k * m + i] = dU[k, i]
        o = os_ + k * nc
        for l in range(nc):
            w[o + l] = 0.0
        for j in range(n):
            t = dX[k, j]
            for l in range(nc):
                w[o + l] += Ct[k, j, l] * t
        for j in range(m):
            t = dU[k, j]
            for l in range(nc):
                w[o + l] += Ct[k, n + j, l] * t
    for l in range(ncN):
        s = 0.0
        for j in range(n):
            s += CN[l, j] * dX[N, j]
        w[osN + l] = s
    for i in range(w.shape[0]):
        a = w[i] + rl[i] if fl[i] else 0.0
        b = -w[i] + rup[i] if fu[i] else 0.0
        c = (rho_l[i] - zl[i] * a) * inv_tl[i]
        e = (rho_u[i] - zu[i] * b) * inv_tu[i]
        dtl[i] = a
        dtu[i] = b
        dzl[i] = c
        dzu[i] = e
        ap = min(ap, -tl[i] / a if a < 0.0 else inf)
        ap = min(ap, -tu[i] / b if b < 0.0 else inf)
        ad = min(ad, -zl[i] / c if c < 0.0 else inf)
        ad = min(ad, -zu[i] / e if e < 0.0 else inf)
    return True, ap, ad


@nb.njit(cache=True, fastmath=_REASSOC)
def _max_step(tl, tu, zl, zu, fl, fu, dtl, dtu, dzl, dzu, ctl, ctu, czl, czu, omega):
    """Largest alpha (capped at 1e30) keeping tl, tu, zl, zu positive along d + omega c
    (omega = 0: along d).  Infinite sides hold t = z = 0 and zero steps (by construction of the
    iterates and directions), so they never limit the step and need no test (fl, fu are unused:
    the loop is branch-free and vectorizes)."""
    a = 1e30
    inf = np.inf
    for i in range(tl.shape[0]):
        v = dtl[i] + omega * ctl[i]
        a = min(a, -tl[i] / v if v < 0.0 else inf)
        v = dzl[i] + omega * czl[i]
        a = min(a, -zl[i] / v if v < 0.0 else inf)
        v = dtu[i] + omega * ctu[i]
        a = min(a, -tu[i] / v if v < 0.0 else inf)
        v = dzu[i] + omega * czu[i]
        a = min(a, -zu[i] / v if v < 0.0 else inf)
    return a


@nb.njit(cache=True, fastmath=_REASSOC)
def _max_step_split(tl, tu, zl, zu, fl, fu, dtl, dtu, dzl, dzu):
    """Largest primal (slacks) and dual (multipliers) step lengths (capped at 1e30) keeping
    tl, tu resp. zl, zu positive along d (infinite sides: see _max_step)."""
    ap = 1e30
    ad = 1e30
    inf = np.inf
    for i in range(tl.shape[0]):
        v = dtl[i]
        ap = min(ap, -tl[i] / v if v < 0.0 else inf)
        v = dtu[i]
        ap = min(ap, -tu[i] / v if v < 0.0 else inf)
        v = dzl[i]
        ad = min(ad, -zl[i] / v if v < 0.0 else inf)
        v = dzu[i]
        ad = min(ad, -zu[i] / v if v < 0.0 else inf)
    return ap, ad


@nb.njit(cache=True)
def _axpy_split(x, ap, ad, y, dual):
    """x + a y in a new array with a = ad where ``dual`` else ap (one pass)."""
    out = np.empty_like(x)
    for i in range(x.shape[0]):
        out[i] = x[i] + (ad if dual[i] else ap) * y[i]
    return out


@nb.njit(cache=True, fastmath=_REASSOC)
def _neighbourhood_step(tl, tu, zl, zu, fl, fu, dtl, dtu, dzl, dzu, alpha, neighborhood, mu, alpha_dual=-1.0):
    """Shorten alpha by factors 0.9 (at most 60 times) until min t_i z_i >= gamma mean t_i z_i at
    it + alpha d, gamma = min(neighborhood, 1/2 min_i t_i z_i / mu) at the current iterate.
    With ``alpha_dual`` >= 0 the multipliers move by alpha_dual (shortened by the same factors) and
    the slacks by alpha; returns the (primal) alpha (the dual one is alpha_dual * alpha / alpha_in)."""
    if alpha_dual < 0.0:
        alpha_dual = alpha
    ratio = alpha_dual / alpha if alpha > 0.0 else 1.0
    nw = tl.shape[0]
    cur = np.inf
    cnt = 0
    for i in range(nw):
        if fl[i]:
            cur = min(cur, tl[i] * zl[i])
            cnt += 1
        if fu[i]:
            cur = min(cur, tu[i] * zu[i])
            cnt += 1
    if cnt == 0:
        return alpha
    gamma = min(neighborhood, 0.5 * cur / max(mu, 1e-300))
    for _ in range(60):
        pmin = np.inf
        psum = 0.0
        ad = ratio * alpha
        for i in range(nw):
            if fl[i]:
                v = (tl[i] + alpha * dtl[i]) * (zl[i] + ad * dzl[i])
                pmin = min(pmin, v)
                psum += v
            if fu[i]:
                v = (tu[i] + alpha * dtu[i]) * (zu[i] + ad * dzu[i])
                pmin = min(pmin, v)
                psum += v
        if pmin >= gamma * (psum / cnt):
            break
        alpha *= 0.9
    return alpha


@nb.njit(cache=True)
def _corrector_rhs(fl, fu, dtl, dtu, dzl, dzu, target, scale, rho_l, rho_u):
    """Mehrotra's corrector: rho = target - scale * dt_aff dz_aff on the finite sides."""
    for i in range(fl.shape[0]):
        rho_l[i] = target - scale * (dtl[i] * dzl[i]) if fl[i] else 0.0
        rho_u[i] = target - scale * (dtu[i] * dzu[i]) if fu[i] else 0.0


@nb.njit(cache=True, fastmath=_REASSOC)
def _implied_newton_residual(new, old, ap, ad, n_dual):
    """Max-norm of the Newton residual of the linear KKT rows of the last direction, implied by
    the residuals before (old) and after (new) the step: each linear row r moves to
    (1 - a) r + a e (e its Newton residual) with a = ap on the primal rows (entries from n_dual
    on, functions of x, u and the slacks only) and, when ap == ad, on the stationarity rows
    (the first n_dual entries); with ap != ad those are skipped."""
    e = 0.0
    if ap == ad:
        for i in range(n_dual):
            e = max(e, abs(new[i] - (1.0 - ad) * old[i]))
    for i in range(n_dual, new.shape[0]):
        e = max(e, abs(new[i] - (1.0 - ap) * old[i]))
    return e / ap


@nb.njit(cache=True)
def _combined_rhs(tl, tu, zl, zu, fl, fu, dtl, dtu, dzl, dzu, target, scale, rho_l, rho_u):
    """Predictor plus Mehrotra corrector in one right-hand side: rho = -t z + target
    - scale * dt_aff dz_aff on the finite sides (the direction d_aff + d_c in one solve)."""
    for i in range(fl.shape[0]):
        rho_l[i] = target - tl[i] * zl[i] - scale * (dtl[i] * dzl[i]) if fl[i] else 0.0
        rho_u[i] = target - tu[i] * zu[i] - scale * (dtu[i] * dzu[i]) if fu[i] else 0.0


@nb.njit(cache=True)
def _centrality_rhs(tl, tu, zl, zu, fl, fu, dtl, dtu, dzl, dzu, alpha, lo_t, hi_t, rho_l, rho_u):
    """Gondzio's corrector: products v at it + alpha d projected on [lo_t, hi_t], decrease capped
    at -hi_t: rho = max(clip(v) - v, -hi_t) on the finite sides."""
    for i in range(fl.shape[0]):
        if fl[i]:
            v = (tl[i] + alpha * dtl[i]) * (zl[i] + alpha * dzl[i])
            rho_l[i] = max(min(max(v, lo_t), hi_t) - v, -hi_t)
        else:
            rho_l[i] = 0.0
        if fu[i]:
            v = (tu[i] + alpha * dtu[i]) * (zu[i] + alpha * dzu[i])
            rho_u[i] = max(min(max(v, lo_t), hi_t) - v, -hi_t)
        else:
            rho_u[i] = 0.0


@nb.njit(cache=True)
def _axpy(x, alpha, y):
    """x + alpha y in a new array (one pass)."""
    out = np.empty_like(x)
    for i in range(x.shape[0]):
        out[i] = x[i] + alpha * y[i]
    return out


@nb.njit(cache=True)
def _max_abs(a):
    big = 0.0
    for i in range(a.shape[0]):
        big = max(big, abs(a[i]))
    return big


@nb.njit(cache=True)
def _dot(a, b):
    """a.b by an elementwise loop (no threaded BLAS: it stalls on long vectors on a busy machine)."""
    s = 0.0
    for i in range(a.shape[0]):
        s += a[i] * b[i]
    return s


@nb.njit(cache=True)
def _farkas_kappa(lam, c, x0, zl, lo, zu, hi, nu, be, eN):
    """kappa = lam_+.c + lam_0.x0 + zl.lo - zu.hi + nu.e + nu_N.eN of the primal certificate
    (be = e on the valid stage rows, 0 elsewhere)."""
    N = c.shape[0]
    s = 0.0
    for k in range(N):
        for i in range(c.shape[1]):
            s += lam[k + 1, i] * c[k, i]
        for l in range(be.shape[1]):
            s += nu[k, l] * be[k, l]
    for i in range(x0.shape[0]):
        s += lam[0, i] * x0[i]
    for i in range(zl.shape[0]):
        s += zl[i] * lo[i] - zu[i] * hi[i]
    for l in range(eN.shape[0]):
        s += nu[N, l] * eN[l]
    return s


@nb.njit(cache=True)
def _cone_violation(w, fl, fu):
    """max(0, max over finite lower sides of -w, max over finite upper sides of w)."""
    v = 0.0
    for i in range(w.shape[0]):
        if fl[i]:
            v = max(v, -w[i])
        if fu[i]:
            v = max(v, w[i])
    return v


@nb.njit(cache=True)
def _all_finite(a):
    for i in range(a.shape[0]):
        if not np.isfinite(a[i]):
            return False
    return True


# ============================================================================= internal data
class _Prepared:
    """The QP after elimination of fixed controls, with the inequality boxes flattened over
    w = (x_1..x_N, u, C_k z_k, C_N x_N)."""

    def __init__(self, qp: StageQP):
        N, n, m = qp.N, qp.n, qp.m
        self.N, self.n, self.m = N, n, m
        self.qp = qp
        self.Q = qp.Q.copy(); self.S = qp.S.copy(); self.R = qp.R.copy()
        self.q = qp.q.copy(); self.r = qp.r.copy(); self.A = qp.A; self.B = qp.B.copy()
        self.c = qp.c.copy(); self.x0 = qp.x0.copy()
        ne0, neN0 = qp.E.shape[1], qp.EN.shape[0]
        self.ne0, self.neN0 = ne0, neN0
        F0, e0 = qp.F.copy(), qp.e.copy()
        C = qp.C.copy(); clo = qp.c_lower.copy(); chi = qp.c_upper.copy()
        nc, ncN = C.shape[1], qp.CN.shape[0]
        self.nc, self.ncN = nc, ncN
        self.CN = qp.CN; cNlo = qp.cN_lower; cNhi = qp.cN_upper

        # ---- inconsistent boxes
        self.bad_box = None
        for name, lo, hi in (("x", qp.x_lower, qp.x_upper), ("u", qp.u_lower, qp.u_upper),
                             ("C_k z_k", clo, chi), ("C_N x_N", cNlo, cNhi)):
            viol = lo - hi
            if viol.size and np.any(viol > _FIX_RTOL * (1 + np.abs(lo))):
                idx = np.unravel_index(np.argmax(viol), viol.shape)
                self.bad_box = f"lower bound above upper bound for {name} at index {tuple(int(i) for i in idx)}"
        fix = _equal_bounds

        # ---- fixed controls: eliminated (their value moves into c, q, r, e and the row bounds)
        self.ufix = fix(qp.u_lower, qp.u_upper)
        self.uval = np.where(self.ufix, 0.5 * (np.where(self.ufix, qp.u_lower, 0.0) + np.where(self.ufix, qp.u_upper, 0.0)), 0.0)
        if self.ufix.any():
            v = self.uval
            self.c += np.einsum("kij,kj->ki", self.B, v)
            self.q[:-1] += np.einsum("kij,kj->ki", self.S, v)
            self.r += np.einsum("kij,kj->ki", self.R, v)
            e0 = e0 + np.einsum("kij,kj->ki", F0, v)
            if nc:
                Cv = np.einsum("kij,kj->ki", C[:, :, n:], v)
                clo, chi = clo - Cv, chi - Cv
            keep = ~self.ufix
            self.B *= keep[:, None, :]
            self.S *= keep[:, None, :]
            F0 = F0 * keep[:, None, :]
            if nc:
                C[:, :, n:] *= keep[:, None, :]
            self.R = self.R * (keep[:, :, None] & keep[:, None, :])
            kk, ii = np.nonzero(self.ufix)
            self.R[kk, ii, ii] = 1.0
            self.r[self.ufix] = 0.0
        self.C = C

        # ---- fixed states (k >= 1) and equal-bound rows become equality rows
        xfix = fix(qp.x_lower, qp.x_upper)
        xfix[0] = False
        cfix = fix(clo, chi) if nc else np.zeros((N, 0), bool)
        cNfix = fix(cNlo, cNhi) if ncN else np.zeros(0, bool)
        mid = lambda lo, hi, f: np.where(f, 0.5 * (np.where(f, lo, 0.0) + np.where(f, hi, 0.0)), 0.0)  # noqa: E731
        xval = mid(qp.x_lower, qp.x_upper, xfix)
        cval = mid(clo, chi, cfix)
        cNval = mid(cNlo, cNhi, cNfix)
        # rows of stage k < N: the QP's own rows, then fixed x_k, then equal-bound C_k rows
        self.n_eq = (ne0 + xfix[:N].sum(axis=1) + cfix.sum(axis=1)).astype(np.int64)
        ne = int(self.n_eq.max(initial=0))
        self.ne = ne
        E = np.zeros((N, ne, n)); F = np.zeros((N, ne, m)); e = np.zeros((N, ne))
        E[:, :ne0] = qp.E; F[:, :ne0] = F0; e[:, :ne0] = e0
        self.eq_map = []   # (k, row, kind, index) of the appended stage rows
        for k in np.nonzero(xfix[:N].any(axis=1) | cfix.any(axis=1))[0]:   # only stages with fixed entries
            k = int(k)
            row = ne0
            for i in np.nonzero(xfix[k])[0]:
                E[k, row, i] = 1.0; e[k, row] = -xval[k, i]; self.eq_map.append((k, row, "x", int(i))); row += 1
            for i in np.nonzero(cfix[k])[0]:
                E[k, row] = C[k, i, :n]; F[k, row] = C[k, i, n:]; e[k, row] = -cval[k, i]
                self.eq_map.append((k, row, "c", int(i))); row += 1
        rowsN = [qp.EN]; eN = [qp.eN]; self.eqN_map = []
        row = neN0
        for i in np.nonzero(xfix[N])[0]:
            rowsN.append(np.eye(n)[i:i + 1]); eN.append([-xval[N, i]]); self.eqN_map.append((row, "x", int(i))); row += 1
        for i in np.nonzero(cNfix)[0]:
            rowsN.append(self.CN[i:i + 1]); eN.append([-cNval[i]]); self.eqN_map.append((row, "c", int(i))); row += 1
        self.EN = np.vstack(rowsN)
        self.eN = np.concatenate([np.asarray(a, float) for a in eN])
        self.neN = self.EN.shape[0]
        self.E, self.F, self.e = E, F, e
        self.eq_mask = np.arange(ne)[None, :] < self.n_eq[:, None]
        self.has_eq = bool(self.n_eq.any()) or self.neN > 0
        self.n_nu = max(ne, self.neN)

        # ---- flat boxes lo <= w <= hi; fixed entries (handled above) have none
        inf = np.inf
        xl = np.where(xfix[1:], -inf, qp.x_lower[1:]); xh = np.where(xfix[1:], inf, qp.x_upper[1:])
        ul = np.where(self.ufix, -inf, qp.u_lower); uh = np.where(self.ufix, inf, qp.u_upper)
        sl = np.where(cfix, -inf, clo); sh = np.where(cfix, inf, chi)
        sNl = np.where(cNfix, -inf, cNlo); sNh = np.where(cNfix, inf, cNhi)
        lo = np.concatenate([xl.ravel(), ul.ravel(), sl.ravel(), sNl])
        hi = np.concatenate([xh.ravel(), uh.ravel(), sh.ravel(), sNh])
        self.fl, self.fu = np.isfinite(lo), np.isfinite(hi)
        self.lo = np.where(self.fl, lo, 0.0); self.hi = np.where(self.fu, hi, 0.0)
        self.n_comp = int(self.fl.sum() + self.fu.sum())
        o = np.cumsum([0, N * n, N * m, N * nc, ncN])
        self.sl_x, self.sl_u, self.sl_s, self.sl_sN = (slice(int(o[i]), int(o[i + 1])) for i in range(4))
        self.nw = int(o[-1])
        self.n_z = N * (n + m) + n
        fin = lambda a: float(np.max(np.abs(a), initial=0.0))  # noqa: E731
        self.p_data = max(fin(self.c), fin(self.x0), fin(self.e), fin(self.eN), fin(self.lo), fin(self.hi))
        self.d_data = max(fin(self.q), fin(self.r))
        self.h_scale = max(fin(self.Q), fin(self.R), fin(self.S))

        # ---- stacked arrays of the compiled kernels and the per-iteration work arrays
        nz = n + m
        tr = lambda a: np.ascontiguousarray(np.swapaxes(a, -1, -2))  # noqa: E731
        # the symmetric parts (what the objective 1/2 z.H z sees, and what the Riccati kernels use)
        self.H = _symmetric_stage_hessians(np.ascontiguousarray(self.Q), np.ascontiguousarray(self.S),
                                           np.ascontiguousarray(self.R), np.empty((N, nz, nz)))
        self.QN = np.ascontiguousarray(0.5 * (self.Q[N] + self.Q[N].T))
        self.AB = np.ascontiguousarray(np.concatenate([self.A, self.B], axis=2))
        self.sizes = fixed_size_tags(n, m) or (n, m, n + m)
        self.EF = np.ascontiguousarray(np.concatenate([self.E, self.F], axis=2)); self.EFt = tr(self.EF)
        self.eqm = self.eq_mask.astype(float)
        self.be = self.e * self.eqm
        self.C = np.ascontiguousarray(self.C); self.CN = np.ascontiguousarray(self.CN); self.Ct = tr(self.C)
        self.neg_lo = -self.lo
        self.point_layout = _layout((("X", (N + 1, n)), ("U", (N, m)), ("lam", (N + 1, n)), ("nu", (N + 1, self.n_nu)),
                                     ("tl", (self.nw,)), ("tu", (self.nw,)), ("zl", (self.nw,)), ("zu", (self.nw,))))
        self.rhs_layout = _layout((("rx", (N + 1, n)), ("ru", (N, m)), ("dyn", (N, n)), ("x0r", (n,)), ("rE", (N, ne)),
                                   ("rEN", (self.neN,)), ("rl", (self.nw,)), ("rup", (self.nw,))))
        # the fields as (slice, shape) of the 2-d ones and slices of the 1-d ones (_Point, _Rhs)
        sls = lambda layout: tuple(slice(a, b) if len(shape) == 1 else (slice(a, b), shape)  # noqa: E731
                                   for _, a, b, shape in layout[0])
        self.point_slices, self.rhs_slices = sls(self.point_layout), sls(self.rhs_layout)
        (_, x_a, _, _), (_, _, u_b, _), (_, l_a, _, _), (_, _, n_b, _), _, _, (_, zl_a, _, _), (_, _, zu_b, _) = \
            self.point_layout[0]
        self.part_slices = (slice(x_a, u_b), slice(l_a, n_b), slice(zl_a, zu_b))
        self.qr = np.concatenate([self.q.ravel(), self.r.ravel()])   # the gradient, laid out as (X, U)
        self.dual_mask = np.zeros(self.point_layout[1], dtype=np.bool_)
        for name, a, b, _ in self.point_layout[0]:
            self.dual_mask[a:b] = name in ("lam", "nu", "zl", "zu")
        self.point_form = _PointForm(self.point_slices, self.dual_mask)
        self.zero_res = _Rhs(self, np.zeros(self.rhs_layout[1]))
        self.zero_res._size = 0.0
        self.stats = np.empty(6)
        self.inv_tl, self.inv_tu, self.D = np.empty(self.nw), np.empty(self.nw), np.empty(self.nw)
        # views of D: the stage-row weights and the diagonal terms of the bounds on x_1..x_N, u
        self.Ds = self.D[self.sl_s].reshape(N, nc)
        self.Dxb, self.Dub = self.D[self.sl_x].reshape(N, n), self.D[self.sl_u].reshape(N, m)
        self.work_q, self.work_r, self.work_ci = np.empty((N + 1, n)), np.empty((N, m)), np.empty((N, nc))
        self.newton_res = _Rhs(self, np.empty(self.rhs_layout[1]))
        # objects reused from iteration to iteration (their lifetimes: InteriorPointQP.solve and
        # _direction): two residual vectors used in turn (the last one may be pending for the
        # implied Newton residual), the complementarity right-hand sides of one solve, and the
        # directions of the predictor, of the (combined) corrector, of further correctors (the
        # Salahi-Peng-Terlaky and centrality correctors, consumed by ``plus``) and of refinement
        self.res_pool, self.res_turn = None, 0
        self.rho_l, self.rho_u = np.empty(self.nw), np.empty(self.nw)
        self.dir_aff = self.dir_main = self.dir_corr = self.dir_refine = None
        self.work_el, self.work_eu, self.work_w = np.empty(self.nw), np.empty(self.nw), np.empty(self.nw)
        self.Q_final = self.Q.copy() if ncN else self.Q   # Q with C_N^T diag(D) C_N added to Q_N
        self.shift = 0.0   # delta added to the Hessian by the nonconvex = "shift" mode
        self.fact = None   # the KKT back-end's factorization, refactored in every iteration
        self.reg_rung = 0  # index (in reg_rungs) of the last iteration's Newton-system regularization
        self._rungs = None
        self.work_Dx, self.work_Du = np.empty((N + 1, n)), np.empty((N, m))
        self._zero_point = None

    def reg_rungs(self, options):
        """The regularizations a Newton-system factorization may use, in increasing order:
        options.regularization, then max(10 delta, 1e-10 (1 + max|H|)) while at most
        options.max_regularization * max|H| (12 at most)."""
        if self._rungs is None:
            rungs = [options.regularization]
            cap = options.max_regularization * max(self.h_scale, 1e-300)
            while len(rungs) < 12:
                nxt = max(10.0 * rungs[-1], 1e-10 * (1.0 + self.h_scale))
                if nxt > cap:
                    break
                rungs.append(nxt)
            self._rungs = rungs
        return self._rungs

    def point(self, v):
        return _Point(self.point_form, v)

    def directions(self):
        """The reused direction objects (predictor, main, corrector, refinement), made on first use."""
        if self.dir_aff is None:
            size = self.point_layout[1]
            self.dir_aff, self.dir_main, self.dir_corr, self.dir_refine = (_Point(self.point_form, np.empty(size)) for _ in range(4))

    def residual_buffer(self):
        """A residual object not holding the last one returned (the two are used in turn)."""
        if self.res_pool is None:
            self.res_pool = (_Rhs(self, np.empty(self.rhs_layout[1])), _Rhs(self, np.empty(self.rhs_layout[1])))
        self.res_turn ^= 1
        res = self.res_pool[self.res_turn]
        res._size = None
        return res

    def shift_hessian(self, delta):
        """H <- H + delta I on every stage block and on Q_N (the ``nonconvex = "shift"`` mode)."""
        idx = np.arange(self.n)
        self.Q[:, idx, idx] += delta
        iu = np.arange(self.m)
        self.R[:, iu, iu] += delta
        iz = np.arange(self.n + self.m)
        self.H[:, iz, iz] += delta
        self.QN[idx, idx] += delta
        if self.ncN:
            self.Q_final[...] = self.Q
        self.shift += delta

    def point_from(self, X, U, lam, nu, tl, tu, zl, zu):
        return _Point(self.point_form, np.concatenate([np.asarray(a, dtype=float).ravel() for a in (X, U, lam, nu, tl, tu, zl, zu)]))

    # ------------------------------------------------------------------ linear maps
    def w_of(self, X, U):
        """w = (x_1..x_N, u, C_k z_k, C_N x_N), flat."""
        parts = [X[1:].ravel(), U.ravel()]
        if self.nc:
            parts.append(self.cz(X, U).ravel())
        if self.ncN:
            parts.append(self.CN @ X[-1])
        return np.concatenate(parts)

    def zero_point(self):
        """A point of zeros (made on first use; never written)."""
        if self._zero_point is None:
            self._zero_point = _Point(self.point_form, np.zeros(self.point_layout[1]))
        return self._zero_point

    def linear_parts(self, X, U, lam, nu, zl, zu):
        """The linear maps of the infeasibility certificates in one pass of the compiled _kkt_map
        (offsets 0, written into the scratch arrays newton_res and work_w): (max |H z + constraint
        gradient of lam, nu, zu - zl|, max |homogeneous equality residuals A x + B u - x_+, -x_0,
        E z, E_N x_N|, the box values w of z). With z = 0 the first is |constraint gradient| (the
        primal certificate); with zero multipliers it is |H z| (the dual one)."""
        e, z, st = self.newton_res, self.zero_res, self.stats
        _kkt_map_call(self, z.rl, z.rup, self.fl, self.fu, X, U, lam, nu, z.rl, z.rup, zl, zu,
                      z.rx, z.ru, z.dyn, z.x0r, z.rE, z.rEN,
                      e.rx, e.ru, e.dyn, e.x0r, e.rE, e.rEN, e.rl, e.rup, self.work_w, st)
        eqs = max(_max_abs(e.dyn.ravel()), _max_abs(e.x0r), _max_abs(e.rE.ravel()), _max_abs(e.rEN))
        return float(st[1]), eqs, self.work_w

    def cz(self, X, U):
        n = self.n
        return np.einsum("kij,kj->ki", self.C[:, :, :n], X[:-1]) + np.einsum("kij,kj->ki", self.C[:, :, n:], U)

    def hess_z(self, X, U):
        """H z as (N+1, n) and (N, m) parts."""
        hx = np.empty_like(X)
        hx[:-1] = np.einsum("kij,kj->ki", self.Q[:-1], X[:-1]) + np.einsum("kij,kj->ki", self.S, U)
        hx[-1] = self.Q[-1] @ X[-1]
        hu = np.einsum("kji,kj->ki", self.S, X[:-1]) + np.einsum("kij,kj->ki", self.R, U)
        return hx, hu

    def constraint_grad(self, lam, nu, zd):
        """Gradient in (x, u) of the constraint part of the Lagrangian for multipliers lam, nu and
        zd = zu - zl (flat over the boxes)."""
        N, n, m, nc = self.N, self.n, self.m, self.nc
        gx = np.empty((N + 1, n))
        gx[:-1] = np.einsum("kji,kj->ki", self.A, lam[1:]) - lam[:-1]
        gx[-1] = -lam[-1]
        gu = np.einsum("kji,kj->ki", self.B, lam[1:])
        if self.ne:
            nus = nu[:N, :self.ne] * self.eq_mask
            gx[:-1] += np.einsum("kji,kj->ki", self.E, nus)
            gu += np.einsum("kji,kj->ki", self.F, nus)
        if self.neN:
            gx[-1] += self.EN.T @ nu[N, :self.neN]
        gx[1:] += zd[self.sl_x].reshape(N, n)
        gu += zd[self.sl_u].reshape(N, m)
        if nc:
            zs = zd[self.sl_s].reshape(N, nc)
            gx[:-1] += np.einsum("kji,kj->ki", self.C[:, :, :n], zs)
            gu += np.einsum("kji,kj->ki", self.C[:, :, n:], zs)
        if self.ncN:
            gx[-1] += self.CN.T @ zd[self.sl_sN]
        return gx, gu

    def eq_residuals(self, X, U, hom=False):
        """Dynamics (N, n), x_0 (n,), stage (N, ne) and final (neN,) equality residuals; with
        ``hom`` only their linear parts (for recession directions)."""
        dyn = np.einsum("kij,kj->ki", self.A, X[:-1]) + np.einsum("kij,kj->ki", self.B, U) - X[1:]
        x0r = -X[0] if hom else self.x0 - X[0]
        if not hom:
            dyn = dyn + self.c
        rE = np.zeros((self.N, self.ne))
        if self.ne:
            rE = np.einsum("kij,kj->ki", self.E, X[:-1]) + np.einsum("kij,kj->ki", self.F, U)
            if not hom:
                rE = rE + self.e
            rE *= self.eq_mask
        rEN = (self.EN @ X[-1] + (0.0 if hom else self.eN)) if self.neN else np.zeros(0)
        return dyn, x0r, rE, rEN


def _layout(fields):
    """((name, start, stop, shape), ...), total size) of a flat vector holding the fields."""
    out, o = [], 0
    for name, shape in fields:
        size = int(np.prod(shape))
        out.append((name, o, o + size, shape))
        o += size
    return tuple(out), o


@nb.njit(cache=True)
def _symmetric_stage_hessians(Q, S, R, H):
    """H_k = the symmetric part of [Q_k S_k; S_k^T R_k] (k < N), in one pass."""
    N, n, m = S.shape
    for k in range(N):
        for i in range(n):
            for j in range(n):
                H[k, i, j] = 0.5 * (Q[k, i, j] + Q[k, j, i])
            for j in range(m):
                v = 0.5 * (S[k, i, j] + S[k, i, j])
                H[k, i, n + j] = v
                H[k, n + j, i] = v
        for i in range(m):
            for j in range(m):
                H[k, n + i, n + j] = 0.5 * (R[k, i, j] + R[k, j, i])
    return H


class _InconsistentRows(ArithmeticError):
    """The equality rows (dynamics, stage and final rows, fixed states) contradict each other:
    the Riccati recursion's consistency defect of the rows it dropped as dependent, or of the
    rows reaching the fixed x_0 (``LQSolution.x0_residual``), is above the data's rounding level."""


def _check_rows(P, defect, rhs, where):
    """Raise _InconsistentRows if a solve found inconsistent equality rows: its defect
    (``LQSolution.x0_residual``) above the rounding level of the data and of the right-hand side
    ``rhs`` (an _Rhs, or None for a right-hand side made of the data)."""
    if defect > 1e-6 * (1.0 + P.p_data) and defect > 1e-6 * (1.0 + P.p_data + (0.0 if rhs is None else rhs.size())):
        raise _InconsistentRows(f"the equality constraints (dynamics, equality rows, fixed states and x_0) are "
                                f"inconsistent: a combination of them is violated by {defect:.3g} at every point "
                                f"({where})")


class _PointForm:
    """The layout of the points of a prepared problem: the (slice, shape) of each field and the
    mask of the dual fields (lam, nu, zl, zu)."""

    __slots__ = ("slices", "dual_mask")

    def __init__(self, slices, dual_mask):
        self.slices, self.dual_mask = slices, dual_mask


class _Point:
    """An iterate, or a direction (same fields): states X, controls U, dynamics and equality
    multipliers lam, nu, and the slacks tl, tu and multipliers zl, zu of the finite box sides
    (flat, 0 on infinite sides) -- views into one flat vector ``v``."""

    __slots__ = ("v", "X", "U", "lam", "nu", "tl", "tu", "zl", "zu", "_form", "max_step", "max_split")

    def __init__(self, form, v):
        """``form``: the _PointForm of the prepared problem (not the problem itself: a point held
        by the problem -- its reused directions -- would make a reference cycle, and the
        problem's large arrays would then outlive the solve until Python's cyclic garbage
        collector runs, ~100 MB per solve at N = 12 000)."""
        self._form, self.v = form, v
        self.max_step = None    # cache of _StepContext.max_step for a direction
        self.max_split = None   # and of its (primal, dual) step lengths (set by _reduced_solve)
        (sx, shx), (su, shu), (sl, shl), (sn, shn), stl, stu, szl, szu = form.slices
        self.X = v[sx].reshape(shx); self.U = v[su].reshape(shu)
        self.lam = v[sl].reshape(shl); self.nu = v[sn].reshape(shn)
        self.tl = v[stl]; self.tu = v[stu]; self.zl = v[szl]; self.zu = v[szu]

    def plus(self, alpha, d):
        return _Point(self._form, _axpy(self.v, float(alpha), d.v))

    def plus_split(self, alpha, alpha_dual, d):
        """The point + alpha d on (X, U, tl, tu) and + alpha_dual d on (lam, nu, zl, zu)."""
        return _Point(self._form, _axpy_split(self.v, float(alpha), float(alpha_dual), d.v, self._form.dual_mask))

    def finite(self):
        return _all_finite(self.v)

    # kernel argument helpers
    def tz(self):
        return self.tl, self.tu, self.zl, self.zu


class _Rhs:
    """Residuals of the Newton system's equations (see :meth:`_StepContext.solve`), views into
    one flat vector ``buf``: rx (N+1, n), ru (N, m), dyn (N, n), x0r (n,), rE (N, ne), rEN (neN,),
    rl, rup (flat over the boxes)."""

    __slots__ = ("buf", "rx", "ru", "dyn", "x0r", "rE", "rEN", "rl", "rup", "_size")

    def __init__(self, P, buf):
        self.buf, self._size = buf, None
        (sx, shx), (su, shu), (sd, shd), sx0, (se, she), seN, srl, sru = P.rhs_slices
        self.rx = buf[sx].reshape(shx); self.ru = buf[su].reshape(shu); self.dyn = buf[sd].reshape(shd)
        self.x0r = buf[sx0]; self.rE = buf[se].reshape(she); self.rEN = buf[seN]; self.rl = buf[srl]; self.rup = buf[sru]

    def size(self):
        """max-norm of all residuals."""
        if self._size is None:
            self._size = _max_abs(self.buf)
        return self._size


class _StepContext:
    """One iteration: the factorization, and the map from right-hand sides to directions."""

    def __init__(self, solver, P, it, res, mu):
        self.solver, self.P, self.it, self.res, self.mu = solver, P, it, res, mu
        self.split = False   # separate primal and dual step lengths (set by the caller)
        self.zero_res = P.zero_res
        self.n_solves = 0
        self.n_refine = 0
        self.tol = solver.options.tol
        self.refinement_steps = solver.options.refinement_steps
        self.refinement_tol = solver.options.refinement_tol
        self.rel_error = None   # Newton residual / |rhs| of this factorization's first solve, unrefined
        self.rel_prior = None   # bound on it from an earlier iteration's measurement (set by the caller)
        self.first = None       # (|rhs|, target) of the first solve
        self.inv_tl, self.inv_tu, D = P.inv_tl, P.inv_tu, P.D
        _scaling(it.tl, it.tu, it.zl, it.zu, P.fl, P.fu, self.inv_tl, self.inv_tu, D)
        self.Ds = P.Ds
        if P.ncN:
            P.Q_final[-1] = P.Q[-1] + P.CN.T @ (D[P.sl_sN][:, None] * P.CN)
        # factorize with the regularization delta; when the factorization fails (loss of
        # definiteness by cancellation when D spans many orders of magnitude, or a Hessian that is
        # indefinite on the null space of the equalities -- the exact Hessian of an SQP step --
        # while the slacks are still large) retry with delta raised 10-fold, up to
        # max_regularization * max|H| (the inertia correction of Waechter & Biegler 2006, applied
        # per Newton step). Refinement works against the unregularized system.
        # The Riccati back-end is factorized once per QP solve and then refactored in place with
        # the new diagonal terms (same arrays: Q, S, R, A, B, the stage rows and the work arrays
        # Dx, Du, D of the prepared problem, updated in place before each refactorization).
        # The regularizations tried form a fixed ladder (rungs): base, then tenfold steps from
        # 1e-10 (1 + max|H|), at most 12, up to max_regularization * max|H|. The result is the
        # lowest rung whose factorization succeeds -- as if the ladder were climbed from the base
        # every time -- but after a failed base the search starts one rung below the last
        # iteration's, climbs from there to a success and bisects below it (positive
        # definiteness is monotone in delta): an iteration that needs the same delta as the last
        # costs three factorizations instead of one per rung.
        rungs = P.reg_rungs(solver.options)
        self._failure = None
        factorize = self._factorize
        if factorize(rungs[0]):
            j = 0
        else:
            lo = 0                     # highest rung known to fail
            j = max(1, P.reg_rung - 1)
            while j < len(rungs) and not factorize(rungs[j]):
                lo = j
                j += 1
            if j == len(rungs):
                raise self._failure
            last_ok = True             # j succeeds; bisect (lo, j) for the lowest rung that does
            while j - lo > 1:
                mid = (lo + j) // 2
                if factorize(rungs[mid]):
                    j, last_ok = mid, True
                else:
                    lo, last_ok = mid, False
            if not last_ok:
                factorize(rungs[j])    # the lowest successful rung again (a failure overwrote it)
        P.reg_rung = j
        reg = rungs[j]
        self.reg = reg
        # nonconvex = "shift": a factorization that needed more than the base regularization makes
        # the delta part of the QP's Hessian (the caller recomputes the residuals); the factored
        # matrix is already the one of the shifted QP
        self.shifted = 0.0
        if solver.options.nonconvex == "shift" and reg > solver.options.regularization:
            self.shifted = reg - solver.options.regularization
            P.shift_hessian(self.shifted)

    def _factorize(self, reg):
        """Factorize the Newton matrix with the regularization ``reg`` (Dx, Du: the work arrays
        of the prepared problem, D + reg); False (the error kept in ``_failure``) if not positive definite."""
        P = self.P
        Dx, Du = P.work_Dx, P.work_Du
        Dx[0] = reg; np.add(P.Dxb, reg, out=Dx[1:])
        np.add(P.Dub, reg, out=Du)
        try:
            if P.fact is not None:
                P.fact.refactor(Dx=Dx, Du=Du, sigma=self.Ds if P.nc else None)
            else:
                kw = {}
                if P.nc:
                    kw.update(Ci=P.C, sigma=self.Ds)
                if P.has_eq:
                    kw.update(E=P.E, F=P.F, n_eq=P.n_eq, EN=P.EN)
                options = self.solver.options
                kw.update(options.kkt_options)
                P.fact = make_kkt_solver(options.kkt, P.Q_final if P.ncN else P.Q, P.S, P.R, P.A, P.B,
                                         Dx=Dx, Du=Du, **kw)
            self.fact = P.fact
            return True
        except NotPositiveDefiniteError as exc:
            exc.regularization = reg
            # kept without its traceback: the traceback's frames hold this context, which holds
            # the exception -- a reference cycle that kept each iteration's arrays alive until
            # the cyclic garbage collector ran (raised again, it gets a fresh traceback)
            self._failure = exc.with_traceback(None)
            return False

    # ------------------------------------------------------------------ solves
    def _reduced_solve(self, res, rho_l, rho_u, out=None):
        """Solve the Newton system

            H dz + delta dz + (constraint gradient of dlam, dnu, dzu - dzl) = -rx, -ru
            A dx + B du - dx_+ = -dyn,  dx_0 = x0r,  E dz = -rE,  E_N dx_N = -rEN
            dtl = dw + rl,  dtu = -dw + rup,  zl dtl + tl dzl = rho_l,  zu dtu + tu dzu = rho_u

        by elimination of (dtl, dtu, dzl, dzu) and one solve with the factorization.  The direction
        is written into ``out`` (a reused direction of the prepared problem, every field
        overwritten) or a new one."""
        P, it = self.P, self.it
        self.n_solves += 1
        q, r, ci = P.work_q, P.work_r, P.work_ci
        _newton_rhs(res.rx, res.ru, res.rl, res.rup, rho_l, rho_u, it.zl, it.zu, self.inv_tl, self.inv_tu,
                    self.Ds, P.CN, q, r, ci)
        if out is None:
            d = P.point(np.empty(P.point_layout[1]))
        else:
            d = out
        # the work arrays were validated when the QP was prepared: the solution goes straight into
        # the direction's arrays
        defect = self.fact.solve_into(RHS(q, r, res.dyn, res.x0r, res.rE, res.rEN, ci), Solution(d.X, d.U, d.lam, d.nu))
        _check_rows(P, defect, res, "Newton step")
        ok, ap, ad = _recover_step(d.X, d.U, P.Ct, P.CN, res.rl, res.rup, rho_l, rho_u, it.tl, it.tu, it.zl, it.zu,
                                   self.inv_tl, self.inv_tu, P.fl, P.fu, d.tl, d.tu, d.zl, d.zu, P.work_w)
        if not ok:
            raise FloatingPointError("non-finite Newton step")
        d.max_split = (ap, ad)
        d.max_step = min(ap, ad)
        return d

    def _newton_residual(self, d, res, rho_l, rho_u):
        """The residual of the unreduced, unregularized Newton system at d, as a right-hand side
        for the correction (the equations of :meth:`_reduced_solve` with delta = 0), written into
        the work arrays of the prepared problem; returns (residual, el, eu, max-norm of all)."""
        P, it = self.P, self.it
        e, st = P.newton_res, P.stats
        _kkt_map_call(P, res.rl, res.rup, P.fl, P.fu,
                 d.X, d.U, d.lam, d.nu, d.tl, d.tu, d.zl, d.zu, res.rx, res.ru, res.dyn, res.x0r, res.rE, res.rEN,
                 e.rx, e.ru, e.dyn, e.x0r, e.rE, e.rEN, e.rl, e.rup, P.work_w, st)
        e._size = max(st[0], st[1])
        big = _complementarity_residual(rho_l, rho_u, it.tl, it.tu, it.zl, it.zu, d.tl, d.tu, d.zl, d.zu,
                                        P.work_el, P.work_eu)
        return e, P.work_el, P.work_eu, max(e._size, big)

    def solve(self, res, rho_l, rho_u, out=None):
        """Direction for the residuals ``res`` and complementarity right-hand sides rho_l,
        rho_u (flat, 0 on infinite sides).  The Newton residual of the unreduced system is
        measured after the solve; only if it exceeds max(1e-3 tol (1 + |rhs|), refinement_tol
        |rhs|) is the direction refined (at most ``refinement_steps`` corrections, stopping at
        the first that does not halve the residual and undoing it if the residual grew).  The first
        solve of a factorization gives its relative error |residual| / |rhs|; later solves with
        the same factorization skip the measurement when that relative error times their |rhs|
        is below 10 % of their target (their relative errors stay within a small factor of the
        first one's: same matrix, same conditioning).  The first solve itself may skip it on
        ``rel_prior``, a bound carried over from the last measured iteration (see
        :meth:`InteriorPointQP.solve`).  ``out``: as in :meth:`_reduced_solve`."""
        d = self._reduced_solve(res, rho_l, rho_u, out)
        if self.refinement_steps == 0:
            return d
        rhs = max(res.size(), _max_abs(rho_l), _max_abs(rho_u))
        target = max(1e-3 * self.tol * (1.0 + rhs), self.refinement_tol * rhs)
        if self.first is None:
            self.first = (rhs, target)
        est = self.rel_error if self.rel_error is not None else self.rel_prior
        if est is not None and est * rhs <= 0.1 * target:
            return d
        prev, corr = math.inf, None
        for step in range(self.refinement_steps + 1):
            e, el, eu, size = self._newton_residual(d, res, rho_l, rho_u)
            if step == 0 and self.rel_error is None:
                self.rel_error = size / rhs if rhs > 0 else math.inf
            if size <= target:
                break
            if size > 0.5 * prev:
                # refinement does not converge: the factored matrix is too far from the Newton
                # matrix (a regularization that makes an indefinite system definite, not one that
                # only cures rounding) -- keep the better of the last two directions and stop
                if size > prev:
                    np.subtract(d.v, corr.v, out=d.v)
                    d.max_step = d.max_split = None
                break
            if step == self.refinement_steps:
                break
            prev = size
            self.n_refine += 1
            corr = self._reduced_solve(e, el, eu, self.P.dir_refine)
            np.add(d.v, corr.v, out=d.v)   # d is this solve's own direction: corrected in place
            d.max_step = d.max_split = None
        return d

    # ------------------------------------------------------------------ steps
    def max_step(self, d, corr=None, omega=0.0):
        """Largest alpha (capped at 1e30) keeping tl, tu, zl, zu positive along d (or along
        d + omega corr)."""
        P, it = self.P, self.it
        if corr is None:
            if d.max_step is None:
                d.max_step = _max_step(it.tl, it.tu, it.zl, it.zu, P.fl, P.fu, d.tl, d.tu, d.zl, d.zu,
                                       d.tl, d.tu, d.zl, d.zu, 0.0)
            return d.max_step
        return _max_step(it.tl, it.tu, it.zl, it.zu, P.fl, P.fu, d.tl, d.tu, d.zl, d.zu,
                         corr.tl, corr.tu, corr.zl, corr.zu, float(omega))

    def products_at(self, d, alpha):
        """Complementarity products (lower, upper; flat) at the trial point it + alpha d."""
        it = self.it
        return (it.tl + alpha * d.tl) * (it.zl + alpha * d.zl), (it.tu + alpha * d.tu) * (it.zu + alpha * d.zu)

    def step_length(self, d):
        """(alpha, alpha_dual): alpha = min(1, step_to_boundary * alpha_max) -- with
        ``step_rule = "primal-dual"`` separately for the primal variables (alpha_max of the
        slacks) and the multipliers (alpha_max of zl, zu), as in Mehrotra (1992) sec. 7 --
        then both shortened (by factors 0.9) until the new point lies in the neighbourhood
        N_inf^-(gamma) of Salahi, Peng and Terlaky: t_i z_i >= gamma_eff mu for every finite side,
        gamma_eff = min(``neighborhood``, half the current min_i t_i z_i / mu) (so a start outside
        the neighbourhood is not blocked).

        With separate step lengths the primal residuals still fall by the factor 1 - alpha; the
        dual residual becomes (1 - alpha_dual) r_d + (alpha - alpha_dual) H dz."""
        P, it = self.P, self.it
        opts = self.solver.options
        if not self.split or P.n_comp == 0:
            alpha = min(1.0, opts.step_to_boundary * self.max_step(d))
            alpha_dual = alpha
        else:
            if d.max_split is None:
                d.max_split = _max_step_split(it.tl, it.tu, it.zl, it.zu, P.fl, P.fu, d.tl, d.tu, d.zl, d.zu)
            ap, ad = d.max_split
            alpha, alpha_dual = min(1.0, opts.step_to_boundary * ap), min(1.0, opts.step_to_boundary * ad)
        if P.n_comp == 0:
            return alpha, alpha_dual
        a = _neighbourhood_step(it.tl, it.tu, it.zl, it.zu, P.fl, P.fu, d.tl, d.tu, d.zl, d.zu, alpha,
                                opts.neighborhood, self.mu, alpha_dual)
        return a, alpha_dual * (a / alpha) if alpha > 0 else alpha_dual


# ============================================================================= the base class
class InteriorPointQP:
    """Infeasible primal-dual interior-point method for :class:`StageQP` (see the module docstring).

    Subclasses choose the search direction (:meth:`_direction` and its hooks); everything else --
    preparation, starting points, residuals, factorization, step, stopping, certificates and the
    result -- lives here.  ``solve(qp, warm_start=None)`` returns a
    :class:`~olado.qp.stageqp.QPResult` with the multipliers in its documented convention,
    ``kkt`` = :func:`~olado.qp.stageqp.qp_kkt_residuals` and one history entry per iteration."""

    name = "ip-qp"
    Options = InteriorPointQPOptions

    def __init__(self, options=None, **overrides):
        self.options = make_options(self.Options, options, **overrides)

    # ------------------------------------------------------------------ public entry
    def solve(self, qp: StageQP, warm_start: QPResult | None = None) -> QPResult:
        """Solve ``qp``; ``warm_start`` is a previous :class:`QPResult` of a QP of the same shape
        (its primal and dual values are used, slacks and multipliers pushed into the interior).

        A cold start whose iterates stall or crawl (10 successive steps shorter than 0.1) without
        any regularization of the Newton systems (i.e. not a nonconvex QP, whose regularized steps
        are short for another reason: zambezi12 N = 48) is solved again from a
        start ``stall_restart_mu`` (100) times as far inside (``initial_mu``), at most twice,
        within the same ``max_iter`` budget: complementarity products small against the distance
        the iterates must travel make every step short. The first SQP QP of block SR1 (Hessian I)
        on zambezi starts 53 outside the volume bounds: at N = 276 the steps were 0.01-0.1 for 82
        iterations until the iterates stalled, from initial_mu = 10 it takes 19 iterations; at
        N = 1 200 the steps stay 0.01-0.03 for 300 iterations from 0.1 and 1, from 10 it takes
        159, from 1 000 30."""
        opts = self.options
        restartable = warm_start is None and opts.stall_restart_mu > 1.0
        res = self._solve(qp, warm_start, opts.max_iter, crawl_exit=restartable)
        mu = opts.initial_mu
        for attempt in range(_MAX_RESTARTS):
            if not (restartable and res.status is Status.NUMERICAL_ERROR and res.iterations < opts.max_iter
                    and res.regularization <= opts.regularization
                    and (_STALLED in res.message or _CRAWLED in res.message)):
                break
            mu *= opts.stall_restart_mu
            why = "stalled" if _STALLED in res.message else "crawling"
            again = self._solve(qp, None, opts.max_iter - res.iterations, crawl_exit=attempt + 1 < _MAX_RESTARTS,
                                initial_mu=mu)
            again.iterations += res.iterations
            again.time_s += res.time_s
            again.history = list(res.history) + list(again.history)
            again.message = (f"{again.message} (restarted from initial_mu = {mu:g} after {res.iterations} "
                             f"iterations, {why})")
            res = again
        return res

    def _solve(self, qp: StageQP, warm_start: QPResult | None, max_iter: int, crawl_exit: bool = False,
               initial_mu: float | None = None) -> QPResult:
        t0 = time.perf_counter()
        opts = self.options
        P = _Prepared(qp)
        history = []
        if P.bad_box is not None:
            return self._finish(P, None, Status.INFEASIBLE, f"{Status.INFEASIBLE.sentence} ({P.bad_box})", 0, history, t0)
        x0tol = opts.tol * (1 + float(np.max(np.abs(qp.x0), initial=0.0)))
        v0 = max(float(np.max(qp.x_lower[0] - qp.x0, initial=-np.inf)), float(np.max(qp.x0 - qp.x_upper[0], initial=-np.inf)))
        if v0 > x0tol:
            return self._finish(P, None, Status.INFEASIBLE,
                                f"{Status.INFEASIBLE.sentence} (the fixed initial state x0 violates the bounds of x_0 "
                                f"by {v0:.3g})", 0, history, t0)
        try:
            it = self._initial_point(P, initial_mu) if warm_start is None else self._warm_point(P, warm_start)
        except NotPositiveDefiniteError as exc:
            res = self._finish(P, None, Status.NUMERICAL_ERROR,
                               f"{Status.NUMERICAL_ERROR.sentence} (starting point: the KKT factorization with unit "
                               f"diagonal terms failed at stage k={exc.stage}: {exc})", 0, history, t0)
            res.regularization = 1.0   # the unit diagonal of the starting-point system
            return res
        except RiccatiStatusError as exc:
            return self._finish(P, None, Status.NUMERICAL_ERROR,
                                f"{Status.NUMERICAL_ERROR.sentence} (starting point: {exc})", 0, history, t0)
        except _InconsistentRows as exc:
            return self._finish(P, None, Status.INFEASIBLE, f"{Status.INFEASIBLE.sentence} ({exc})", 0, history, t0)
        best, stall, k, last_d = math.inf, 0, 0, None
        failed_reg = 0.0
        # The relative error of the Newton solves grows with the conditioning of the Newton matrix,
        # i.e. slowly from one iteration to the next (a few-fold per iteration as mu falls): a
        # measurement bounds the next two iterations' errors by 100 x its value, and their first
        # solves skip the measurement (a kkt_map pass) when that bound is well within the target.
        # A direction taken unmeasured is checked afterwards for free: the residuals of the next
        # iterate imply its Newton residual on the linear rows (_implied_newton_residual); within
        # the target that counts as a measurement, else the next iteration measures again; after a
        # common step (all rows verified) the next direction is trusted and verified the same way
        # (a posteriori: an inaccurate direction is caught one iteration later and the following
        # solves are measured and refined again).
        rel_last, rel_age, pending, verified = None, 0, None, False
        n_dual = (P.N + 1) * P.n + P.N * P.m
        best_merit, best_it, best_k = math.inf, it, 0
        pr_prev = du_prev = math.inf
        n_slow = 0
        huge = 1e10 * (1.0 + P.p_data + P.d_data)
        status, message = Status.MAX_ITERATIONS, Status.MAX_ITERATIONS.sentence
        while True:
            res, pr, du, scales, obj, znorm, comp = self._residuals(P, it)
            if pending is not None:
                old, a_p, a_d, rhs_old, target_old = pending
                e = _implied_newton_residual(res.buf, old.buf, a_p, a_d, n_dual)
                rel_last, rel_age = (e / rhs_old, 0) if e <= target_old and rhs_old > 0 else (None, 0)
                # all rows verified (common step) and within the target: the next direction is
                # trusted as well and checked in the same way afterwards
                verified = rel_last is not None and a_p == a_d
                pending = None
            mu = comp / P.n_comp if P.n_comp else 0.0
            gap = mu * P.n_comp
            if pr <= opts.tol * scales[0] and du <= opts.tol * scales[1] and gap <= opts.tol * (1.0 + abs(obj)):
                status, message = Status.SUCCESS, Status.SUCCESS.sentence
                break
            # the certificates are evaluated only when the iterates look suspicious: a primal or
            # dual residual above tolerance that the last two steps did not halve, or a huge iterate
            slow = (pr > opts.tol * scales[0] and pr > 0.5 * pr_prev) or (du > opts.tol * scales[1] and du > 0.5 * du_prev)
            n_slow = n_slow + 1 if slow else 0
            if n_slow >= 2 or znorm > huge:
                cert = self._certificates(P, it, last_d)
                if cert is not None:
                    status, message = cert
                    break
            pr_prev, du_prev = pr, du
            merit = max(pr / scales[0], du / scales[1], gap / (1.0 + abs(obj)))
            if merit < 0.99 * best:
                best, stall = merit, 0
            else:
                stall += 1
            if merit < best_merit:
                best_merit, best_it, best_k = merit, it, k
            if stall >= 10 or (len(history) >= 3 and all(max(h["alpha"], h["alpha_dual"]) < 1e-8 for h in history[-3:])):
                status, message = self._certificates(P, it, last_d, loose=True) or self._stall_status(
                    pr / scales[0], du / scales[1], gap / (1.0 + abs(obj)))
                break
            # crawling (see solve): only a convex QP whose Newton systems were never regularized
            if (crawl_exit and P.shift == 0.0 and len(history) >= _CRAWL_W
                    and all(max(h["alpha"], h["alpha_dual"]) < _CRAWL_A for h in history[-_CRAWL_W:])
                    and all(h["regularization"] <= opts.regularization for h in history)):
                status = Status.NUMERICAL_ERROR
                message = (f"{status.sentence} The iterates {_CRAWLED} ({_CRAWL_W} successive steps shorter than "
                           f"{_CRAWL_A:g}; scaled primal {pr / scales[0]:.3g}, dual {du / scales[1]:.3g}, gap "
                           f"{gap / (1.0 + abs(obj)):.3g}).")
                break
            if k >= max_iter:
                break
            try:
                ctx = _StepContext(self, P, it, res, mu)
                # separate primal and dual step lengths only until the primal residual meets its
                # tolerance: after that a dual step shorter than the primal one would put
                # (alpha - alpha_dual) H dz back into the dual residual at every iteration
                ctx.split = opts.step_rule == "primal-dual" and pr > opts.tol * scales[0]
                if ctx.shifted:
                    res, pr, du, scales, obj, znorm, comp = self._residuals(P, it)
                    ctx.res = res
                    best, stall, best_merit = math.inf, 0, math.inf   # a new QP: progress measures restart
                if verified and ctx.reg == history[-1]["regularization"]:
                    ctx.rel_prior = 0.0
                elif rel_last is not None and rel_age < 2 and ctx.reg <= opts.regularization:
                    ctx.rel_prior = 100.0 * rel_last
                verified = False
                d, info = self._direction(ctx)
                if ctx.rel_error is not None:
                    rel_last, rel_age = ctx.rel_error, 0
                else:
                    rel_age += 1
            except NotPositiveDefiniteError as exc:
                status = Status.NUMERICAL_ERROR
                failed_reg = getattr(exc, "regularization", 0.0)
                message = (f"{status.sentence} (iteration {k + 1}: the KKT factorization failed at stage "
                           f"k={exc.stage} with regularization {failed_reg:.3g}: {exc})")
                break
            except _InconsistentRows as exc:
                status = Status.INFEASIBLE
                message = f"{status.sentence} (iteration {k + 1}: {exc})"
                break
            except (np.linalg.LinAlgError, FloatingPointError, ValueError, ZeroDivisionError, RiccatiStatusError) as exc:
                status = Status.NUMERICAL_ERROR
                message = f"{status.sentence} (iteration {k + 1}: {type(exc).__name__}: {exc})"
                break
            alpha, alpha_dual = ctx.step_length(d)
            if ctx.first is not None and ctx.n_refine == 0 and min(alpha, alpha_dual) >= 0.1:
                pending = (ctx.res, alpha, alpha_dual) + ctx.first
            it = it.plus(alpha, d) if alpha_dual == alpha else it.plus_split(alpha, alpha_dual, d)
            last_d = d
            k += 1
            entry = {"iter": k, "mu": mu, "primal": pr, "dual": du, "gap": gap, "objective": obj, "alpha": alpha,
                     "alpha_dual": alpha_dual}
            entry.update(info)
            entry["solves"] = ctx.n_solves
            entry["refinements"] = ctx.n_refine
            entry["regularization"] = ctx.reg
            history.append(entry)
            if opts.verbose >= 2:
                print(f"{self.name} {k:3d}  mu {mu:9.2e}  pr {pr:9.2e}  du {du:9.2e}  alpha {alpha:6.4f}/{alpha_dual:6.4f}  "
                      f"sigma {info['sigma']:7.1e}  corr {info['correctors']}  solves {ctx.n_solves}")
            if not it.finite():
                status = Status.NUMERICAL_ERROR
                message = f"{status.sentence} (iteration {k}: non-finite iterate)"
                break
        if status in (Status.NUMERICAL_ERROR, Status.MAX_ITERATIONS) and best_merit <= opts.acceptable_tol:
            message = (f"{Status.ACCEPTABLE.sentence} Returned the best iterate (iteration {best_k}, scaled KKT "
                       f"measure {best_merit:.2g} <= acceptable_tol) after: {message}")
            status, it = Status.ACCEPTABLE, best_it
        if P.shift > 0.0:
            message += (f" (nonconvex QP: its Hessian was shifted by {P.shift:.3g} I to make the Newton systems "
                        "positive definite; the result solves the shifted QP)")
        res = self._finish(P, it, status, message, k, history, t0)
        # the total shift (plus the delta at which a factorization failed on top of it), or the
        # largest Newton-system regularization
        res.regularization = (P.shift + failed_reg if P.shift > 0.0
                              else max([failed_reg] + [h["regularization"] for h in history]))
        if opts.polish and status == Status.ACCEPTABLE and P.shift == 0.0:
            polished = self._polish(qp, res)
            if polished is not None:
                polished.time_s = time.perf_counter() - t0
                return polished
        return res

    # ------------------------------------------------------------------ polishing
    def _polish(self, qp, res):
        """Polish an ACCEPTABLE result (see the ``polish`` option): every side of a box on which
        the multiplier exceeds the slack at ``res`` is taken as active; the QP with the active
        sides as equal bounds (fixed controls are eliminated, fixed states and rows become
        equality rows) and the inactive sides dropped is an equality-constrained QP, solved in
        one Newton step. Sides that its solution violates are added and it is solved again (at
        most ``polish_rounds`` solves). The result, with the multipliers of the equal bounds put
        back on the active sides, replaces ``res`` if it meets ``tol`` (stationarity, primal,
        complementarity) with multipliers of the right sign; else None (``res`` stays)."""
        opts = self.options
        tol = opts.tol
        inf = np.inf
        vals = box_values(qp, res.X, res.U)
        fixed, act = {}, {}
        for key, lo_name, hi_name, zl_name, zu_name in BOX_FIELDS:
            lo, hi, val = getattr(qp, lo_name), getattr(qp, hi_name), vals[key]
            fixed[key] = _equal_bounds(lo, hi)
            aL = np.isfinite(lo) & ~fixed[key] & (getattr(res, zl_name) > val - lo)
            aU = np.isfinite(hi) & ~fixed[key] & (getattr(res, zu_name) > hi - val) & ~aL
            if key == "x":
                aL[0] = aU[0] = False          # x_0 is fixed by its own row
            act[key] = [aL, aU]
        solver = type(self)(self.options, polish=False, max_iter=5, stall_restart_mu=1.0)
        r2, extra = None, 0
        for _ in range(opts.polish_rounds):
            kw = {}
            for key, lo_name, hi_name, _, _ in BOX_FIELDS:
                lo, hi = getattr(qp, lo_name), getattr(qp, hi_name)
                aL, aU = act[key]
                kw[lo_name] = np.where(fixed[key] | aL, lo, np.where(aU, hi, -inf))
                kw[hi_name] = np.where(fixed[key] | aU, hi, np.where(aL, lo, inf))
                if key == "x":
                    kw[lo_name][0], kw[hi_name][0] = lo[0], hi[0]
            try:
                r2 = solver.solve(dataclasses.replace(qp, **kw))
            except (np.linalg.LinAlgError, FloatingPointError, ValueError, ArithmeticError, RiccatiStatusError):
                return None
            if not r2.success:
                return None
            extra += r2.iterations
            vals = box_values(qp, r2.X, r2.U)
            violated = False
            for key, lo_name, hi_name, _, _ in BOX_FIELDS:
                v = vals[key]
                slack = tol * (1.0 + np.abs(v))
                vL, vU = v < getattr(qp, lo_name) - slack, v > getattr(qp, hi_name) + slack
                if key == "x":
                    vL[0] = vU[0] = False
                if vL.any() or vU.any():
                    violated = True
                    act[key][0] |= vL
                    act[key][1] |= vU & ~act[key][0]
            if not violated:
                break
        else:
            return None
        # the multipliers of the equal bounds (net lower minus upper) back on the active sides
        mult = {}
        for key, _, _, zl_name, zu_name in BOX_FIELDS:
            zl2, zu2 = getattr(r2, zl_name), getattr(r2, zu_name)
            aL, aU = act[key]
            net = zl2 - zu2
            mult[zl_name] = np.where(fixed[key], zl2, np.where(aL, net, 0.0))
            mult[zu_name] = np.where(fixed[key], zu2, np.where(aU, -net, 0.0))
        pol = dataclasses.replace(r2, **mult, history=res.history, iterations=res.iterations + extra,
                                  solver=res.solver, regularization=res.regularization)
        kkt = qp_kkt_residuals(qp, pol)
        d_scale = 1.0 + max(float(np.max(np.abs(qp.q), initial=0.0)), float(np.max(np.abs(qp.r), initial=0.0)))
        p_scale = 1.0 + max(float(np.max(np.abs(qp.c), initial=0.0)), float(np.max(np.abs(qp.x0), initial=0.0)),
                            float(np.max(np.abs(pol.X), initial=0.0)), float(np.max(np.abs(pol.U), initial=0.0)))
        if not (kkt["stationarity"] <= tol * d_scale and kkt["dual_sign"] <= tol * d_scale
                and kkt["primal"] <= tol * p_scale and kkt["complementarity"] <= tol * (1.0 + abs(pol.objective))):
            return None
        pol.kkt = kkt
        pol.status = Status.SUCCESS
        pol.message = (f"{Status.SUCCESS.sentence} Polished ({extra} Newton steps on the active set of the best "
                       f"iterate, counted in the iterations) after: {res.message}")
        return pol

    # ------------------------------------------------------------------ direction (subclasses)
    def _direction(self, ctx):
        """Mehrotra's predictor-corrector direction with the Salahi-Peng-Terlaky safeguard (see
        :class:`MehrotraQP`), then :meth:`_centrality_correctors`. Returns (direction, info)."""
        P, it, mu = ctx.P, ctx.it, ctx.mu
        opts = self.options
        P.directions()
        # predictor (affine scaling, sigma = 0); the right-hand sides of every solve are written
        # into P.rho_l, P.rho_u (each solve is done with them before the next one is formed)
        rho_l, rho_u = P.rho_l, P.rho_u
        np.multiply(np.negative(it.zl, out=rho_l), it.tl, out=rho_l)
        np.multiply(np.negative(it.zu, out=rho_u), it.tu, out=rho_u)
        d_aff = ctx.solve(ctx.res, rho_l, rho_u, P.dir_aff)
        a_aff = min(1.0, ctx.max_step(d_aff))
        if P.n_comp == 0:
            return d_aff, {"alpha_aff": a_aff, "sigma": 0.0, "safeguard": False, "correctors": 0, "omega": 1.0}
        # Mehrotra's second-order term: the products dt_aff * dz_aff
        fl, fu = P.fl, P.fu
        safeguard = a_aff < opts.safeguard_step
        omega = 1.0
        # unweighted correctors (Mehrotra, Gondzio): d_aff + d_c in one solve with the combined
        # right-hand side (the same direction up to rounding, one vector pass less)
        combined = type(self)._corrector_weight is InteriorPointQP._corrector_weight
        if not safeguard:
            sigma = (1.0 - a_aff) ** 3
            if combined:
                _combined_rhs(it.tl, it.tu, it.zl, it.zu, fl, fu, d_aff.tl, d_aff.tu, d_aff.zl, d_aff.zu, sigma * mu,
                              1.0, rho_l, rho_u)
                d = ctx.solve(ctx.res, rho_l, rho_u, P.dir_main)
            else:
                _corrector_rhs(fl, fu, d_aff.tl, d_aff.tu, d_aff.zl, d_aff.zu, sigma * mu, 1.0, rho_l, rho_u)
                d_c = ctx.solve(ctx.zero_res, rho_l, rho_u, P.dir_corr)
                omega = self._corrector_weight(ctx, d_aff, d_c, a_aff)
                d = d_aff.plus(omega, d_c)
            safeguard = min(1.0, ctx.max_step(d)) < opts.safeguard_step
        if safeguard:
            gam = opts.safeguard_gamma
            sigma = gam / (1.0 - gam)
            _corrector_rhs(fl, fu, d_aff.tl, d_aff.tu, d_aff.zl, d_aff.zu, sigma * mu, a_aff, rho_l, rho_u)
            d_c = ctx.solve(ctx.zero_res, rho_l, rho_u, P.dir_corr)
            omega = self._corrector_weight(ctx, d_aff, d_c, a_aff)
            d = d_aff.plus(omega, d_c)
        d, ncorr = self._centrality_correctors(ctx, d, sigma * mu)
        return d, {"alpha_aff": a_aff, "sigma": sigma, "safeguard": bool(safeguard), "correctors": ncorr,
                   "omega": omega}

    def _corrector_weight(self, ctx, base, corr, omega_min):
        """Weight of a corrector added to ``base``: 1 (plain correctors) unless overridden."""
        return 1.0

    def _centrality_correctors(self, ctx, d, mu_target):
        """Further correctors after the predictor-corrector direction: none in the base class.
        Returns (direction, number of correctors used)."""
        return d, 0

    # ------------------------------------------------------------------ starting points
    def _initial_point(self, P, mu0=None):
        """Cold start: (X, U) minimizes f + 1/2 |w - w_ref|^2 (+ 1/2 |z|^2 on unbounded
        components) subject to the equality constraints -- one factorization -- with w_ref the
        middle of two-sided boxes and 0 clipped into one-sided ones; its lam, nu are kept; slacks
        t = max(w - lo, 1) (resp. max(hi - w, 1)) and multipliers z = mu0 / t on every finite side
        (a perfectly centred start, mu = mu0, by default ``initial_mu``)."""
        N, n, m, nc = P.N, P.n, P.m, P.nc
        two = P.fl & P.fu
        ref = np.where(two, 0.5 * (P.lo + P.hi),
                       np.clip(np.zeros(P.nw), np.where(P.fl, P.lo, -np.inf), np.where(P.fu, P.hi, np.inf)))
        Dx = np.ones((N + 1, n)); Du = np.ones((N, m))
        q = P.q.copy(); r = P.r.copy()
        q[1:] -= ref[P.sl_x].reshape(N, n)
        r -= ref[P.sl_u].reshape(N, m)
        kw, rhs = dict(Dx=Dx, Du=Du), {}
        if nc:
            kw.update(Ci=P.C, sigma=np.ones((N, nc)))
            rhs["ci"] = -ref[P.sl_s].reshape(N, nc)
        Q = P.Q
        if P.ncN:
            Q = P.Q.copy(); Q[-1] = Q[-1] + P.CN.T @ P.CN
            q[-1] -= P.CN.T @ ref[P.sl_sN]
        if P.has_eq:
            kw.update(E=P.E, F=P.F, n_eq=P.n_eq, EN=P.EN)
            rhs.update(e=P.e, eN=P.eN)
        kw.update(self.options.kkt_options)
        sol = make_kkt_solver(self.options.kkt, Q, P.S, P.R, P.A, P.B, **kw).solve(q, r, P.c, P.x0, **rhs)
        _check_rows(P, float(sol.x0_residual), None, "starting point")
        X, U = np.array(sol.X, dtype=float), np.array(sol.U, dtype=float)
        w = P.w_of(X, U)
        tl = np.where(P.fl, np.maximum(w - P.lo, 1.0), 0.0)
        tu = np.where(P.fu, np.maximum(P.hi - w, 1.0), 0.0)
        nu = np.zeros((N + 1, P.n_nu))
        if P.n_nu:
            k = min(P.n_nu, sol.nu.shape[1])
            nu[:, :k] = sol.nu[:, :k]
        mu0 = self.options.initial_mu if mu0 is None else mu0
        zl = np.where(P.fl, mu0 / np.where(P.fl, tl, 1.0), 0.0)
        zu = np.where(P.fu, mu0 / np.where(P.fu, tu, 1.0), 0.0)
        return P.point_from(X, U, np.array(sol.lam, dtype=float), nu, tl, tu, zl, zu)

    def _warm_point(self, P, ws: QPResult):
        """Warm start from a previous result: X, U, lam, nu and the box multipliers are taken over
        (multipliers of eliminated or equality-row entries mapped as in :meth:`_finish`); slacks
        t = max(w - lo, theta) and multipliers z = max(z_ws, theta) on finite sides with
        theta = ``warm_start_push`` * (1 + max |z_ws|)."""
        N, n, m = P.N, P.n, P.m
        X = np.array(ws.X, dtype=float).reshape(N + 1, n).copy()
        U = np.array(ws.U, dtype=float).reshape(N, m).copy()
        U[P.ufix] = 0.0   # eliminated controls are 0 in the reduced problem
        lam = np.array(ws.lam, dtype=float).reshape(N + 1, n).copy()
        nu = np.zeros((N + 1, P.n_nu))
        wnu = np.asarray(ws.nu, dtype=float)
        if wnu.ndim == 2 and wnu.shape[0] == N + 1:
            a, b = min(P.ne0, wnu.shape[1]), min(P.neN0, wnu.shape[1])
            nu[:N, :a] = wnu[:N, :a]
            nu[N, :b] = wnu[N, :b]
        for k, row, kind, i in P.eq_map:
            nu[k, row] = (ws.zx_upper[k, i] - ws.zx_lower[k, i]) if kind == "x" else (ws.yc_upper[k, i] - ws.yc_lower[k, i])
        for row, kind, i in P.eqN_map:
            nu[N, row] = (ws.zx_upper[N, i] - ws.zx_lower[N, i]) if kind == "x" else (ws.yN_upper[i] - ws.yN_lower[i])
        flat = lambda *a: np.concatenate([np.asarray(v, dtype=float).ravel() for v in a])  # noqa: E731
        zl = flat(np.asarray(ws.zx_lower)[1:], ws.zu_lower, ws.yc_lower, ws.yN_lower)
        zu = flat(np.asarray(ws.zx_upper)[1:], ws.zu_upper, ws.yc_upper, ws.yN_upper)
        zl, zu = np.nan_to_num(zl), np.nan_to_num(zu)
        theta = self.options.warm_start_push * (1.0 + float(np.max(np.abs(np.concatenate([zl, zu])), initial=0.0)))
        w = P.w_of(X, U)
        tl = np.where(P.fl, np.maximum(w - P.lo, theta), 0.0)
        tu = np.where(P.fu, np.maximum(P.hi - w, theta), 0.0)
        zl = np.where(P.fl, np.maximum(zl, theta), 0.0)
        zu = np.where(P.fu, np.maximum(zu, theta), 0.0)
        return P.point_from(X, U, lam, nu, tl, tu, zl, zu)

    # ------------------------------------------------------------------ residuals and measures
    def _residuals(self, P, it):
        """Residuals of the KKT conditions at ``it`` and the measures of the stopping test:
        (res, primal, dual, (primal scale, dual scale), objective, max |X, U|, sum(zl tl + zu tu)) with max-norms and
        scales as in the module docstring (one pass of a compiled kernel)."""
        res = P.residual_buffer()
        st = P.stats
        _kkt_map_call(P, P.neg_lo, P.hi, P.fl, P.fu,
                 it.X, it.U, it.lam, it.nu, it.tl, it.tu, it.zl, it.zu, P.q, P.r, P.c, P.x0, P.be, P.eN,
                 res.rx, res.ru, res.dyn, res.x0r, res.rE, res.rEN, res.rl, res.rup, P.work_w, st)
        pr, du, znorm, hnorm, obj, comp = (float(v) for v in st)
        res._size = max(pr, du)
        scales = (1.0 + max(P.p_data, znorm), 1.0 + max(P.d_data, hnorm))
        return res, pr, du, scales, obj, znorm, comp

    # ------------------------------------------------------------------ infeasibility
    def _certificates(self, P, it, d, loose=False):
        """(status, message) if a certificate of primal or dual infeasibility holds (strict or,
        after a stall, loose thresholds; see the module docstring), else None."""
        eps = 1e-3 if loose else self.options.infeasibility_tol
        min_quality = 10.0 if loose else 1.0 / self.options.infeasibility_tol
        xu, lamnu, zlzu = P.part_slices       # (X, U), (lam, nu), (zl, zu): contiguous parts of a point
        z = P.zero_point()
        size_xu = _max_abs(it.v[xu])
        # primal infeasibility: y.constraints(z) = G.z + kappa <= 0 on the feasible set
        if _max_abs(it.v[lamnu]) > 0 or _max_abs(it.v[zlzu]) > 0:
            kappa = _farkas_kappa(it.lam, P.c, P.x0, it.zl, P.lo, it.zu, P.hi, it.nu, P.be, P.eN)
            G = math.inf
            if kappa > 0:   # the constraint gradient only when the certificate can hold
                G = P.linear_parts(z.X, z.U, it.lam, it.nu, it.zl, it.zu)[0]
            scale = 1.0 + size_xu + P.p_data
            if kappa > 0 and kappa >= min_quality * scale * P.n_z * G:
                bound = kappa / (P.n_z * G) if G > 0 else math.inf
                return Status.INFEASIBLE, (
                    f"{Status.INFEASIBLE.sentence} Farkas certificate from the multipliers: every point satisfying the "
                    f"constraints would have |z|_inf >= {bound:.3g}, {bound / scale:.3g} times the size of the iterate "
                    f"and the data{' (loose test after the iterates stalled)' if loose else ''}.")
        # dual infeasibility: a recession direction along which the objective decreases
        cands = []
        if d is not None:
            cands.append(("step", d))
        if size_xu > 1e10 * (1.0 + P.p_data + P.d_data):
            cands.append(("iterate", it))
        for what, p in cands:
            nrm = _max_abs(p.v[xu])
            if not nrm > 0:
                continue
            # the measures of the normalized direction (X, U) / nrm
            gd = _dot(P.qr, p.v[xu]) / nrm
            if gd >= 0:
                continue
            hd, eqs, dw = P.linear_parts(p.X, p.U, z.lam, z.nu, z.zl, z.zu)
            worst = max(hd, eqs, _cone_violation(dw, P.fl, P.fu)) / nrm
            if worst <= eps * -gd:
                return Status.UNBOUNDED, (
                    f"{Status.UNBOUNDED.sentence} Certificate: along the normalized {what} direction d the objective "
                    f"decreases (g.d = {gd:.3g}) while |H d|, the equality residuals and the bound violations of d "
                    f"are at most {worst:.3g}{' (loose test after the iterates stalled)' if loose else ''}.")
        return None

    def _stall_status(self, pr, du, gap):
        # Without a certificate a stall is not evidence of infeasibility (a tight tol, a nearly
        # singular or nonconvex Hessian stall too): report it as a numerical difficulty.
        return Status.NUMERICAL_ERROR, (f"{Status.NUMERICAL_ERROR.sentence} The iterates {_STALLED} (scaled primal "
                                        f"{pr:.3g}, dual {du:.3g}, gap {gap:.3g}); no infeasibility certificate was found.")

    # ------------------------------------------------------------------ result
    def _finish(self, P, it, status, message, iters, history, t0):
        qp = P.qp
        if P.shift > 0.0:   # the QP that was solved (nonconvex = "shift")
            d = P.shift
            qp = dataclasses.replace(qp, Q=qp.Q + d * np.eye(P.n), R=qp.R + d * np.eye(P.m))
        N, n, m, nc, ncN = P.N, P.n, P.m, P.nc, P.ncN
        ne_out = max(P.ne0, P.neN0)
        if it is None:
            z = np.zeros
            res = QPResult(status, message, np.full((N + 1, n), np.nan), np.full((N, m), np.nan), z((N + 1, n)),
                           z((N + 1, ne_out)), z((N + 1, n)), z((N + 1, n)), z((N, m)), z((N, m)), z((N, nc)),
                           z((N, nc)), z(ncN), z(ncN), iterations=iters, history=history, solver=self.name)
            res.time_s = time.perf_counter() - t0
            return res
        X = it.X.copy(); U = it.U.copy()
        U[P.ufix] = P.uval[P.ufix]
        lam = it.lam.copy()
        nu = np.zeros((N + 1, ne_out))
        nu[:N, :P.ne0] = it.nu[:N, :P.ne0]
        nu[N, :P.neN0] = it.nu[N, :P.neN0]
        zxl = np.zeros((N + 1, n)); zxu = np.zeros((N + 1, n))
        zxl[1:] = it.zl[P.sl_x].reshape(N, n); zxu[1:] = it.zu[P.sl_x].reshape(N, n)
        zul = it.zl[P.sl_u].reshape(N, m).copy(); zuu = it.zu[P.sl_u].reshape(N, m).copy()
        ycl = it.zl[P.sl_s].reshape(N, nc).copy(); ycu = it.zu[P.sl_s].reshape(N, nc).copy()
        yNl = it.zl[P.sl_sN].copy(); yNu = it.zu[P.sl_sN].copy()
        for k, row, kind, i in P.eq_map:
            v = float(it.nu[k, row])
            tgt = (zxu, zxl, (k, i)) if kind == "x" else (ycu, ycl, (k, i))
            tgt[0][tgt[2]], tgt[1][tgt[2]] = max(v, 0.0), max(-v, 0.0)
        for row, kind, i in P.eqN_map:
            v = float(it.nu[N, row])
            if kind == "x":
                zxu[N, i], zxl[N, i] = max(v, 0.0), max(-v, 0.0)
            else:
                yNu[i], yNl[i] = max(v, 0.0), max(-v, 0.0)
        if P.ufix.any():
            # multipliers of eliminated controls from the u-stationarity of the original Lagrangian
            g = (np.einsum("kji,kj->ki", qp.S, X[:-1]) + np.einsum("kij,kj->ki", qp.R, U) + qp.r
                 + np.einsum("kji,kj->ki", qp.B, lam[1:]))
            if P.ne0:
                g += np.einsum("kji,kj->ki", qp.F, nu[:N, :P.ne0])
            if nc:
                g += np.einsum("kji,kj->ki", qp.C[:, :, n:], ycu - ycl)
            zuu[P.ufix] = np.maximum(-g[P.ufix], 0.0)
            zul[P.ufix] = np.maximum(g[P.ufix], 0.0)
        res = QPResult(status, message, X, U, lam, nu, zxl, zxu, zul, zuu, ycl, ycu, yNl, yNu,
                       objective=qp.objective(X, U), iterations=iters, history=history, solver=self.name)
        res.kkt = qp_kkt_residuals(qp, res)
        res.time_s = time.perf_counter() - t0
        if self.options.verbose >= 1:
            kkt = ", ".join(f"{key} {val:.1e}" for key, val in res.kkt.items())
            print(f"{self.name}: {status.value} after {iters} iterations, objective {res.objective:.10g}, {kkt}, "
                  f"{res.time_s:.3f} s")
        return res


# ============================================================================= the three methods
class MehrotraQP(InteriorPointQP):
    """Mehrotra's predictor-corrector method with the Salahi-Peng-Terlaky safeguard.

    Per iteration (one factorization, two solves plus refinement):

    1. predictor: the affine-scaling direction (sigma = 0) and its largest step alpha_a;
    2. if alpha_a >= ``safeguard_step`` (0.1): sigma = (1 - alpha_a)^3 (the form of Mehrotra's
       heuristic analysed by Salahi, Peng and Terlaky) and the corrector with target sigma*mu and
       Mehrotra's second-order term dt_aff*dz_aff;
    3. safeguard (Salahi, Peng, Terlaky, "On Mehrotra-type predictor-corrector algorithms",
       McMaster AdvOL report 2005/4; SIAM J. Optim. 18 (2007) 1377-1397): if alpha_a <
       ``safeguard_step`` (a poor affine step, for which Mehrotra's heuristic would force an
       almost pure centering step) or if the largest step of the direction of 2. is below
       ``safeguard_step`` (the tiny corrector steps of their example), the corrector is recomputed
       with the fixed sigma = gamma/(1 - gamma) (``safeguard_gamma`` gamma = 0.1 -> sigma = 1/9)
       and the second-order term damped by alpha_a (their modified corrector system).

    The thresholds are options; the complexity constants of the paper (steps of order gamma/n^2)
    are far below what is useful in practice, so the practical 0.1 is the default.
    """

    name = "mehrotra"


class GondzioQP(InteriorPointQP):
    """Mehrotra's method (as :class:`MehrotraQP`) plus Gondzio's multiple centrality correctors.

    After the predictor-corrector direction d with largest step alpha, up to ``max_correctors``
    times: aim at alpha~ = min(1, alpha + delta_alpha) (``aspiration_step``), form the products
    v = t(alpha~) * z(alpha~) at the trial point, project them on [beta_min mu_t, beta_max mu_t]
    (mu_t = sigma mu; paper 003's gamma = beta_min = 1/beta_max) to get the targets, cap the
    decrease of products above beta_max mu_t at -beta_max mu_t, and solve with right-hand side
    (0, 0, target - v) for a corrector dc.  d + dc is accepted if its largest step is at least
    alpha + ``acceptance`` * delta_alpha (Gondzio 1996's test); otherwise correcting stops.
    All correctors reuse the iteration's factorization (Gondzio 1996, Comput. Optim. Appl. 6,
    137-156)."""

    name = "gondzio"
    Options = GondzioQPOptions

    def _centrality_correctors(self, ctx, d, mu_target):
        opts = self.options
        P = ctx.P
        if P.n_comp == 0 or opts.max_correctors == 0:
            return d, 0
        alpha = min(1.0, ctx.max_step(d))
        used = 0
        lo_t, hi_t = opts.beta_min * mu_target, opts.beta_max * mu_target
        for _ in range(opts.max_correctors):
            if alpha >= 1.0:
                break
            a_asp = min(1.0, alpha + opts.aspiration_step)
            it = ctx.it
            rl, ru = P.rho_l, P.rho_u
            _centrality_rhs(it.tl, it.tu, it.zl, it.zu, P.fl, P.fu, d.tl, d.tu, d.zl, d.zu, a_asp, lo_t, hi_t, rl, ru)
            dc = ctx.solve(ctx.zero_res, rl, ru, P.dir_corr)
            omega = self._corrector_weight(ctx, d, dc, alpha)
            d_new = d.plus(omega, dc)
            a_new = min(1.0, ctx.max_step(d_new))
            if a_new < alpha + opts.acceptance * opts.aspiration_step:
                break
            d, alpha = d_new, a_new
            used += 1
        return d, used


class WeightedCorrectorQP(GondzioQP):
    """Gondzio's method with weighted correctors (paper 003; Colombo and Gondzio 2008).

    Every corrector dc -- Mehrotra's and each centrality corrector -- enters as d + omega*dc
    instead of d + dc.  The weight comes from a simple line search (paper 003: "use simple line
    search to avoid bi-level optimization"): ``weight_points`` equally spaced values of omega on
    [omega_min, 1] are tried and the one with the largest step to the boundary is kept (ties go
    to the larger omega).  omega_min is the step already reached (alpha_aff for Mehrotra's
    corrector, the step of d for a centrality corrector) -- the lower end Colombo and Gondzio use,
    so a corrector is never damped below the progress the predictor already makes.  With
    ``max_correctors = 0`` this is a weighted Mehrotra method without centrality correctors."""

    name = "weighted"
    Options = WeightedCorrectorQPOptions

    def _corrector_weight(self, ctx, base, corr, omega_min):
        omega_min = min(max(omega_min, 0.0), 1.0)
        best_w, best_a = 1.0, -1.0
        for w in np.linspace(1.0, omega_min, self.options.weight_points):
            a = ctx.max_step(base, corr, w)
            if a > best_a * (1 + 1e-12):
                best_w, best_a = float(w), a
        return best_w


QP_METHODS = {cls.name: cls for cls in (MehrotraQP, GondzioQP, WeightedCorrectorQP)}


def make_qp_solver(method="mehrotra", options=None, **overrides):
    """An interior-point QP solver by name: ``mehrotra``, ``gondzio`` or ``weighted``."""
    try:
        cls = QP_METHODS[method]
    except KeyError:
        raise ValueError(f"unknown QP method {method!r}; choose from {', '.join(QP_METHODS)}") from None
    return cls(options, **overrides)


__all__ = ["InteriorPointQP", "MehrotraQP", "GondzioQP", "WeightedCorrectorQP", "InteriorPointQPOptions",
           "GondzioQPOptions", "WeightedCorrectorQPOptions", "QP_METHODS", "KKT_BACKENDS", "make_qp_solver"]
