"""The interior-point iteration for the stage QP (14) of paper 001 sec. 4.2.2: the Newton
iterations on the perturbed KKT conditions (16)-(21), stopping, restarts, the best iterate and
the result (docs/qp-interior-point.md describes the method and where each part lives).
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from ...linalg.backend import NotPositiveDefiniteError
from ...linalg.riccati import RiccatiStatusError
from ...result import Status
from ...options import make_options
from ..stageqp import QPResult, StageQP
from .certificates import STALLED as _STALLED, certificates, stall_status
from .direction import predictor_corrector
from .options import InteriorPointQPOptions
from .polish import polish
from .presolve import _Prepared
from .start import START_WEIGHTS, initial_point, start_weight, warm_point
from .step import _InconsistentRows, _StepContext

# restart of a cold start whose iterates stall or crawl (InteriorPointQP.solve): the words put
# in the message that mark such an end, and the number of restarts
_CRAWLED, _MAX_RESTARTS = "crawled", 2
_CRAWL_W, _CRAWL_A = 10, 0.1   # crawling: _CRAWL_W successive steps (primal and dual) shorter than _CRAWL_A


def _failure(opts, exc):
    """The sentence of a failed Newton solve: the KKT back-end's own message (a
    :class:`olado.linalg.kkt.KKTSolveError` names the back-end), else the exception with the
    back-end named."""
    if getattr(exc, "backend", None):
        return str(exc)
    return f"{type(exc).__name__} with KKT back-end '{opts.kkt}': {exc}"


class InteriorPointQP:
    """Infeasible primal-dual interior-point method for :class:`StageQP` (docs/qp-interior-point.md).

    Subclasses choose the search direction (:meth:`_direction` and its hooks); the loop,
    stopping and the result live here, the other parts in the package's modules (preparation:
    presolve, starting points: start, factorization and step: step, certificates, polish).  ``solve(qp, warm_start=None)`` returns a
    :class:`~olado.qp.stageqp.QPResult` with the multipliers in its documented convention,
    ``kkt`` = :func:`~olado.qp.stageqp.qp_kkt_residuals` and one history entry per iteration."""

    name = "ip-qp"
    Options = InteriorPointQPOptions

    def __init__(self, options=None, **overrides):
        self.options = make_options(self.Options, options, **overrides)
        # the prepared QPs kept for the next QPs of the same shapes (_prepare), by shapes
        self._prepared = {}

    def _prepare(self, qp: StageQP) -> _Prepared:
        """The prepared form of ``qp``: a kept one of the same shapes refilled with its numbers
        (:meth:`_Prepared.refill`: the QPs of an SQP solve, whose solver lives for the solve, share
        their layouts, work arrays and KKT back-end), else a new one, kept when it can be refilled
        later (at most a few: the SQP's QPs come in few shapes -- the step QP, the elastic one,
        the multiplier estimate's). A back-end other than the Riccati recursion is made afresh
        for every QP (a sparse or iterative one is not assumed to give the same results when
        refactored with other matrices)."""
        key = (qp.N, qp.n, qp.m, qp.E.shape[1], qp.EN.shape[0], qp.C.shape[1], qp.CN.shape[0])
        P = self._prepared.get(key)
        opts = self.options
        if P is not None and P.refill(qp):
            if opts.kkt != "riccati" or P.kkt_used != (opts.kkt, opts.kkt_options):
                P.fact = None
        else:
            P = _Prepared(qp)
            if P.simple and P.bad_box is None:
                if len(self._prepared) >= 4:
                    self._prepared.clear()
                self._prepared[key] = P
        P.kkt_used = (opts.kkt, dict(opts.kkt_options))
        return P

    # ------------------------------------------------------------------ public entry
    def solve(self, qp: StageQP, warm_start: QPResult | None = None, limits=None) -> QPResult:
        """Solve ``qp``; ``warm_start`` is a previous :class:`QPResult` of a QP of the same shape
        (its primal and dual values are used, slacks and multipliers pushed into the interior).
        ``limits`` (:class:`olado.interrupts.Limits` of the solve the QP belongs to) is checked
        at every iteration: a time limit or an interrupt ends the QP there (StopRequested).

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
        try:
            opts = self.options
            restartable = warm_start is None and opts.stall_restart_mu > 1.0
            res = self._solve(qp, warm_start, opts.max_iter, crawl_exit=restartable, limits=limits)
            mu = opts.initial_mu
            for attempt in range(_MAX_RESTARTS):
                if not (restartable and res.status is Status.NUMERICAL_ERROR and res.iterations < opts.max_iter
                        and res.regularization <= opts.regularization
                        and (_STALLED in res.message or _CRAWLED in res.message)):
                    break
                mu *= opts.stall_restart_mu
                why = "stalled" if _STALLED in res.message else "crawling"
                again = self._solve(qp, None, opts.max_iter - res.iterations, crawl_exit=attempt + 1 < _MAX_RESTARTS,
                                    initial_mu=mu, limits=limits)
                again.iterations += res.iterations
                again.time_s += res.time_s
                again.history = list(res.history) + list(again.history)
                again.message = (f"{again.message} (restarted from initial_mu = {mu:g} after {res.iterations} "
                                 f"iterations, {why})")
                res = again
            return res
        finally:
            self._release()     # also when a time limit or an interrupt ends the QP (StopRequested)

    def _release(self):
        """Drop the kept prepared QPs' references to the QP and the limits of the last solve (their
        arrays stay for the next QP; the QP's data is not kept alive by them between solves)."""
        for P in self._prepared.values():
            P.qp = P.limits = None
            if P.fact is not None:
                P.fact.limits = None

    def _solve(self, qp: StageQP, warm_start: QPResult | None, max_iter: int, crawl_exit: bool = False,
               initial_mu: float | None = None, limits=None) -> QPResult:
        t0 = time.perf_counter()
        opts = self.options
        P = self._prepare(qp)
        P.limits = limits
        if P.fact is not None:
            P.fact.limits = limits
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
            weight = start_weight(P, START_WEIGHTS[-1])
            res = self._finish(P, None, Status.NUMERICAL_ERROR,
                               f"{Status.NUMERICAL_ERROR.sentence} (starting point: the KKT factorization with "
                               f"diagonal terms up to {weight:.3g} failed at stage k={exc.stage}: {exc})", 0, history, t0)
            res.regularization = weight   # the largest diagonal of the starting-point system
            return res
        except RiccatiStatusError as exc:
            return self._finish(P, None, Status.NUMERICAL_ERROR,
                                f"{Status.NUMERICAL_ERROR.sentence} (starting point: {exc})", 0, history, t0)
        except np.linalg.LinAlgError as exc:
            # a sparse back-end (olado.linalg.kkt.KKTSolveError: a singular matrix, an iterative
            # solve that did not converge) or numpy: a failed QP like a failed Newton step below,
            # which the SQP's inertia correction answers with a larger Hessian shift
            return self._finish(P, None, Status.NUMERICAL_ERROR,
                                f"{Status.NUMERICAL_ERROR.sentence} (starting point: {_failure(opts, exc)})", 0,
                                history, t0)
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
        # running counts of the history's tails the stopping tests read: successive steps (both
        # lengths) below 1e-8 and below _CRAWL_A, and the largest regularization so far
        n_tiny = n_short = 0
        max_reg = 0.0
        huge = 1e10 * (1.0 + P.p_data + P.d_data)
        status, message = Status.MAX_ITERATIONS, Status.MAX_ITERATIONS.sentence
        # (what the loop reads often, as locals; the residuals of _residuals written out in the loop)
        tol, n_comp, kernels, stats = opts.tol, P.n_comp, P.kernels, P.stats
        kkt_map, sizes, kkt_data, offsets, work_w = kernels.kkt_map, P.sizes, P.kkt_data, P.offsets, P.work_w
        p_data, d_data = P.p_data, P.d_data
        while True:
            res = P.residual_buffer()
            kkt_map(sizes, kkt_data, it.arrays, offsets, res.arrays, work_w, stats)
            pr, du, znorm, hnorm, obj, comp = stats.tolist()
            res._size = max(pr, du)
            s_pr, s_du = 1.0 + max(p_data, znorm), 1.0 + max(d_data, hnorm)
            if pending is not None:
                old, a_p, a_d, rhs_old, target_old = pending
                e = kernels.implied_newton_residual(res.buf, old.buf, a_p, a_d, n_dual)
                rel_last, rel_age = (e / rhs_old, 0) if e <= target_old and rhs_old > 0 else (None, 0)
                # all rows verified (common step) and within the target: the next direction is
                # trusted as well and checked in the same way afterwards
                verified = rel_last is not None and a_p == a_d
                pending = None
            mu = comp / n_comp if n_comp else 0.0
            gap = mu * n_comp
            if pr <= tol * s_pr and du <= tol * s_du and gap <= tol * (1.0 + abs(obj)):
                status, message = Status.SUCCESS, Status.SUCCESS.sentence
                break
            # the certificates are evaluated only when the iterates look suspicious: a primal or
            # dual residual above tolerance that the last two steps did not halve, or a huge iterate
            slow = (pr > tol * s_pr and pr > 0.5 * pr_prev) or (du > tol * s_du and du > 0.5 * du_prev)
            n_slow = n_slow + 1 if slow else 0
            if n_slow >= 2 or znorm > huge:
                cert = self._certificates(P, it, last_d)
                if cert is not None:
                    status, message = cert
                    break
            pr_prev, du_prev = pr, du
            merit = max(pr / s_pr, du / s_du, gap / (1.0 + abs(obj)))
            if merit < 0.99 * best:
                best, stall = merit, 0
            else:
                stall += 1
            if merit < best_merit:
                best_merit, best_it, best_k = merit, it, k
            if stall >= 10 or n_tiny >= 3:
                status, message = self._certificates(P, it, last_d, loose=True) or self._stall_status(
                    pr / s_pr, du / s_du, gap / (1.0 + abs(obj)))
                break
            # crawling (see solve): only a convex QP whose Newton systems were never regularized
            if crawl_exit and P.shift == 0.0 and n_short >= _CRAWL_W and max_reg <= opts.regularization:
                status = Status.NUMERICAL_ERROR
                message = (f"{status.sentence} The iterates {_CRAWLED} ({_CRAWL_W} successive steps shorter than "
                           f"{_CRAWL_A:g}; scaled primal {pr / s_pr:.3g}, dual {du / s_du:.3g}, gap "
                           f"{gap / (1.0 + abs(obj)):.3g}).")
                break
            if k >= max_iter:
                break
            if limits is not None:
                limits.check()
            try:
                ctx = _StepContext(self, P, it, res, mu)
                # separate primal and dual step lengths only until the primal residual meets its
                # tolerance: after that a dual step shorter than the primal one would put
                # (alpha - alpha_dual) H dz back into the dual residual at every iteration
                ctx.split = opts.step_rule == "primal-dual" and pr > tol * s_pr
                if ctx.shifted:
                    res, pr, du, (s_pr, s_du), obj, znorm, comp = self._residuals(P, it)
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
                message = f"{status.sentence} (iteration {k + 1}: {_failure(opts, exc)})"
                break
            alpha, alpha_dual = ctx.step_length(d)
            if ctx.first is not None and ctx.n_refine == 0 and min(alpha, alpha_dual) >= 0.1:
                pending = (ctx.res, alpha, alpha_dual) + ctx.first
            it = it.step_into(alpha, alpha_dual, d, P.iterate_buffer(it, best_it))
            last_d = d
            k += 1
            history.append({"iter": k, "mu": mu, "primal": pr, "dual": du, "gap": gap, "objective": obj,
                            "alpha": alpha, "alpha_dual": alpha_dual, **info, "solves": ctx.n_solves,
                            "refinements": ctx.n_refine, "regularization": ctx.reg})
            longer = max(alpha, alpha_dual)
            n_tiny = n_tiny + 1 if longer < 1e-8 else 0
            n_short = n_short + 1 if longer < _CRAWL_A else 0
            max_reg = max(max_reg, ctx.reg)
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
                              else max(failed_reg, max_reg))
        if opts.polish and status == Status.ACCEPTABLE and P.shift == 0.0:
            polished = self._polish(qp, res, limits)
            if polished is not None:
                polished.time_s = time.perf_counter() - t0
                return polished
        return res

    # ------------------------------------------------------------------ polishing

    # ------------------------------------------------------------------ parts (the package's modules)
    def _polish(self, qp, res, limits=None):
        """:func:`.polish.polish` of ``res``: the polished result or None."""
        return polish(self, qp, res, limits)

    def _direction(self, ctx):
        """The search direction of one iteration: Mehrotra's predictor-corrector with the
        Salahi-Peng-Terlaky safeguard (:func:`.direction.predictor_corrector`), then
        :meth:`_centrality_correctors`. Returns (direction, info)."""
        return predictor_corrector(self, ctx, combined=type(self)._corrector_weight is InteriorPointQP._corrector_weight)

    def _corrector_weight(self, ctx, base, corr, omega_min):
        """Weight of a corrector added to ``base``: 1 (plain correctors) unless overridden."""
        return 1.0

    def _centrality_correctors(self, ctx, d, mu_target):
        """Further correctors after the predictor-corrector direction: none in the base class.
        Returns (direction, number of correctors used)."""
        return d, 0

    def _initial_point(self, P, mu0=None):
        """The cold start (:func:`.start.initial_point`)."""
        return initial_point(P, self.options, mu0)

    def _warm_point(self, P, ws: QPResult):
        """The warm start from ``ws`` (:func:`.start.warm_point`)."""
        return warm_point(P, self.options, ws)

    def _certificates(self, P, it, d, loose=False):
        """(status, message) of an infeasibility certificate, or None (:func:`.certificates.certificates`)."""
        return certificates(P, it, d, self.options, loose)

    def _stall_status(self, pr, du, gap):
        return stall_status(pr, du, gap)

    # ------------------------------------------------------------------ residuals and measures
    def _residuals(self, P, it):
        """Residuals of the KKT conditions at ``it`` and the measures of the stopping test:
        (res, primal, dual, (primal scale, dual scale), objective, max |X, U|, sum(zl tl + zu tu)) with max-norms and
        scales as in docs/qp-interior-point.md, "Stopping" (one pass of a compiled kernel)."""
        res = P.residual_buffer()
        st = P.stats
        P.kernels.kkt_map(P.sizes, P.kkt_data, it.arrays, P.offsets, res.arrays, P.work_w, st)
        pr, du, znorm, hnorm, obj, comp = st.tolist()
        res._size = max(pr, du)
        scales = (1.0 + max(P.p_data, znorm), 1.0 + max(P.d_data, hnorm))
        return res, pr, du, scales, obj, znorm, comp

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
        if P.any_ufix:
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
        if P.any_ufix:
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
                       iterations=iters, history=history, solver=self.name)
        res.defer_measures(qp)
        res.time_s = time.perf_counter() - t0
        if self.options.verbose >= 1:
            kkt = ", ".join(f"{key} {val:.1e}" for key, val in res.kkt.items())
            print(f"{self.name}: {status.value} after {iters} iterations, objective {res.objective:.10g}, {kkt}, "
                  f"{res.time_s:.3f} s")
        return res
