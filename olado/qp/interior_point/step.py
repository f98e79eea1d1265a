"""The Newton step of an interior-point iteration (paper 001 (22)-(25)): the KKT back-end's
factorization of the reduced system (25) with a regularization ladder, the solves for the
predictor and corrector right-hand sides with the elimination of the slack and multiplier rows,
the measured Newton residual of (22) and iterative refinement, and the step lengths of (23).

The back-end is any :class:`~olado.linalg.backend.KKTBackend`: factored once per QP solve, then
refactored with each iteration's diagonal terms; its solutions go straight into the
direction's arrays (``solve_into``).
"""

from __future__ import annotations

import math

import numpy as np

from ...linalg.backend import NotPositiveDefiniteError, make_kkt_solver
from ...linalg.codegen import kernel_set
from ...linalg.riccati import RiccatiFactorization
from .kernels import _newton_solve_fixed

#: the fused Newton solve (right-hand side, Riccati solve, recovery in one kernel), called
#: through a KernelSet per block sizes (olado.linalg.codegen.kernel_set)
_FUSED_KERNELS = {"newton_solve": _newton_solve_fixed}


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
        rungs = P.reg_rungs(solver.options)
        # D, and the diagonal terms Dx, Du with the base regularization, in one pass
        P.kernels.scaling(it.slacks, P.fl, P.fu, self.inv_tl, self.inv_tu, D, rungs[0], P.work_Dx, P.work_Du)
        self._diag_reg = rungs[0]   # the regularization in work_Dx, work_Du
        self.Ds = P.Ds
        if P.ncN:
            P.Q_final[-1] = P.Q[-1] + P.CN.T @ (D[P.sl_sN][:, None] * P.CN)
        # factorize with the regularization delta; when the factorization fails (loss of
        # definiteness by cancellation when D spans many orders of magnitude, or a Hessian that is
        # indefinite on the null space of the equalities -- the exact Hessian of an SQP step --
        # while the slacks are still large) retry with delta raised 10-fold, up to
        # max_regularization * max|H| (the inertia correction of Waechter & Biegler 2006, applied
        # per Newton step). Refinement works against the unregularized system.
        # The KKT back-end is factored once per QP solve and then refactored with the new diagonal
        # terms (same arrays: Q, S, R, A, B, the stage rows and the work arrays Dx, Du, D of the
        # prepared problem, updated in place before each refactorization; the Riccati back-end
        # overwrites its factors in place, a sparse one assembles its matrix again).
        # The regularizations tried form a fixed ladder (rungs): base, then tenfold steps from
        # 1e-10 (1 + max|H|), at most 12, up to max_regularization * max|H|. The result is the
        # lowest rung whose factorization succeeds -- as if the ladder were climbed from the base
        # every time -- but after a failed base the search starts one rung below the last
        # iteration's, climbs from there to a success and bisects below it (positive
        # definiteness is monotone in delta): an iteration that needs the same delta as the last
        # costs three factorizations instead of one per rung.
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
        # the fused Newton solve when the factorization is the plain Riccati recursion of small
        # blocks (kernels._newton_solve_fixed: the same values as newton_rhs, solve_into and
        # recover_step in turn); other back-ends take the three steps
        f = self.fact
        self._fused = (kernel_set(_FUSED_KERNELS, (P.n, P.m)).newton_solve
                       if type(f) is RiccatiFactorization and f.fixed_solve_operands() is not None else None)
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
        if reg != self._diag_reg:
            Dx[0] = reg; np.add(P.Dxb, reg, out=Dx[1:])
            np.add(P.Dub, reg, out=Du)
            self._diag_reg = reg
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
                                         Dx=Dx, Du=Du, limits=P.limits, **kw)
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
        overwritten) or a new one.  With the plain Riccati recursion of small blocks the
        right-hand side, the solve and the recovery are one kernel call (kernels._newton_solve_fixed,
        the same values as the three calls of the other back-ends)."""
        P, it = self.P, self.it
        self.n_solves += 1
        d = P.point(np.empty(P.point_layout.size)) if out is None else out
        fused = self._fused
        if fused is not None:
            ok, ap, ad = fused(*self.fact.fixed_solve_operands(), res.kkt_rhs, d.solution, res.arrays, rho_l,
                               rho_u, it.slacks, self.inv_tl, self.inv_tu, self.Ds, P.Ct, P.CN, P.fl, P.fu, d.slacks,
                               P.work_w)
        else:
            P.kernels.newton_rhs(res.rx, res.ru, res.rl, res.rup, rho_l, rho_u, it.slacks, self.inv_tl, self.inv_tu,
                                 self.Ds, P.CN, P.work_q, P.work_r, P.work_ci)
            # the work arrays were validated when the QP was prepared: the solution goes straight
            # into the direction's arrays
            defect = self.fact.solve_into(res.kkt_rhs, d.solution)
            if defect:
                _check_rows(P, defect, res, "Newton step")
            ok, ap, ad = P.kernels.recover_step(d.X, d.U, P.Ct, P.CN, P.fl, P.fu, res.rl, res.rup, rho_l, rho_u,
                                                self.inv_tl, self.inv_tu, it.slacks, d.slacks, P.work_w)
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
        k = P.kernels
        k.kkt_map(P.sizes, P.kkt_data, d.arrays, res.arrays, e.arrays, P.work_w, st)
        e._size = max(st[0], st[1])
        big = k.complementarity_residual(rho_l, rho_u, it.slacks, d.slacks, P.work_el, P.work_eu)
        return e, P.work_el, P.work_eu, max(e._size, big)

    def solve(self, res, rho_l, rho_u, out=None, rho_size=None):
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
        :meth:`InteriorPointQP.solve`).  ``out``: as in :meth:`_reduced_solve`; ``rho_size``:
        max |rho_l, rho_u| when the caller knows it (the kernels that form them return it)."""
        d = self._reduced_solve(res, rho_l, rho_u, out)
        if self.refinement_steps == 0:
            return d
        if rho_size is None:
            max_abs = self.P.kernels.max_abs
            rho_size = max(max_abs(rho_l), max_abs(rho_u))
        rhs = max(res.size(), rho_size)
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
        it = self.it
        if corr is None:
            if d.max_step is None:
                d.max_step = self.P.kernels.max_step(it.slacks, d.slacks, d.slacks, 0.0)
            return d.max_step
        return self.P.kernels.max_step(it.slacks, d.slacks, corr.slacks, float(omega))

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
                d.max_split = P.kernels.max_step_split(it.slacks, d.slacks)
            ap, ad = d.max_split
            alpha, alpha_dual = min(1.0, opts.step_to_boundary * ap), min(1.0, opts.step_to_boundary * ad)
        if P.n_comp == 0:
            return alpha, alpha_dual
        a = P.kernels.neighbourhood_step(it.slacks, P.fl, P.fu, d.slacks, alpha, opts.neighborhood, self.mu, alpha_dual)
        return a, alpha_dual * (a / alpha) if alpha > 0 else alpha_dual
