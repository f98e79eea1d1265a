"""The interior-point QP methods (paper 001 sec. 4.2.2: Mehrotra, Gondzio, Franke; paper 003:
weighted correctors): they differ only in how the search direction is built from the one
factorization per iteration (and Franke's method in its starting point and hot start).
"""

from __future__ import annotations

import time

import numpy as np

from ...result import Status
from .kernels import _centrality_rhs
from .options import FrankeQPOptions, GondzioQPOptions, WeightedCorrectorQPOptions
from .solver import InteriorPointQP


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
            _centrality_rhs(it.slacks, P.fl, P.fu, d.slacks, a_asp, lo_t, hi_t, rl, ru)
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


class _HotStartFailed(Exception):
    """Franke's hot start is abandoned (the duality gap grew); ``iterations`` were spent."""

    def __init__(self, iterations, gap, gap1):
        super().__init__(f"the duality gap grew from {gap1:.3g} (after the first iteration) to {gap:.3g}")
        self.iterations = iterations


class _FrankeState:
    """The per-solve state of Franke's barrier rule (kept on the prepared problem)."""

    __slots__ = ("alphabar", "rhomin", "alpha", "hot", "calls", "gap1")

    def __init__(self, rhomin, hot):
        self.alphabar, self.rhomin, self.alpha, self.hot, self.calls, self.gap1 = 1.0, rhomin, 1.0, hot, 0, None


def watch_hot_start(st, gap):
    """Count the iteration; in a hot start remember the gap after its first iteration and raise
    _HotStartFailed when a later gap exceeds it (Franke's test for a bad hot start)."""
    st.calls += 1
    if st.hot and st.calls == 2:
        st.gap1 = gap
    elif st.hot and st.calls > 2 and gap > st.gap1:
        raise _HotStartFailed(st.calls - 1, gap, st.gap1)


class FrankeQP(InteriorPointQP):
    """Franke's interior-point method (paper 001 sec. 4.2.2: "Mehrotra's algorithm modified by R.
    Franke (Franke, 1994)", "derived from several interior-point algorithms known from the
    literature, with most impact from Wright (Wright, 1993)"; the QP method of the paper's
    SQP-IP, HQP's ``Hqp_IpsFranke``). An infeasible primal-dual path-following method with one
    Newton solve per iteration -- no predictor-corrector -- of (22) with the complementarity
    target tau (t_i z_i -> tau in (20)), the gap = sum t_i z_i over the m inequality sides:

    * tau = alphabar gap / rho_min + (1 - alphabar) gap / m while gap > 1 / rho_min or the last
      step was shorter than 1 -- a mix of a potential-reduction target and centring, weighted by
      alphabar, the running mean (alphabar + alpha) / 2 of the step lengths (1 at the start);
    * tau = gap^2 once gap <= 1 / rho_min after a full step (quadratic convergence);
    * rho_min starts at ``rho_min`` m, doubles when alphabar reaches 1 and halves when
      alphabar < 1/2 (while it exceeds 100 m);
    * one step length for all variables (``step_rule = common``), ``step_to_boundary`` (0.995)
      of the step to the boundary;
    * cold start (Wright 1993): x = 0, the multipliers of the equalities 0, every slack L + d_i
      (d_i the value of the side at x = 0), every multiplier L / m^2, L = max(|d|_inf, 100 m);
    * hot start: the warm start's point (as the other methods); abandoned for a cold start when it
      is not optimal within ``max_warm_iter`` iterations or its gap grows above the gap after its
      first iteration (Franke's ``qp_max_warm_iters``); rho_min is taken over from the warm start.

    The residuals, the stopping test, the certificates and the polish are the shared ones of
    :class:`InteriorPointQP` (docs/qp-interior-point.md)."""

    name = "franke"
    Options = FrankeQPOptions

    def solve(self, qp, warm_start=None, limits=None):
        """As :meth:`InteriorPointQP.solve`; a hot start that fails is replaced by a cold start."""
        if warm_start is None:
            return super().solve(qp, limits=limits)
        opts = self.options
        t0 = time.perf_counter()
        try:
            try:
                res = self._solve(qp, warm_start, min(opts.max_warm_iter, opts.max_iter), limits=limits)
                if res.status is Status.SUCCESS:
                    return res
                spent, why = res.iterations, f"ended {res.status.value}: {res.message}"
            except _HotStartFailed as exc:
                spent, why = exc.iterations, str(exc)
            cold = self._solve(qp, None, max(opts.max_iter - spent, 0), limits=limits)
            cold.iterations += spent
            cold.time_s = time.perf_counter() - t0
            cold.message = f"{cold.message} (cold start after {spent} iterations of a hot start that {why})"
            return cold
        finally:
            self._release()     # also when a time limit or an interrupt ends the QP (as solve does)

    def _initial_point(self, P, mu0=None):
        opts = self.options
        P.franke = _FrankeState(opts.rho_min * max(P.n_comp, 1), hot=False)
        if opts.start == "centred":
            return super()._initial_point(P, mu0)
        N, n, m = P.N, P.n, P.m
        m_sides = P.n_comp
        d = np.concatenate([-P.lo[P.fl], P.hi[P.fu]])       # the sides' values at x = 0
        L = max(float(np.max(np.abs(d), initial=0.0)), 100.0 * m_sides)
        tl = np.where(P.fl, L - P.lo + 1e-10, 0.0)
        tu = np.where(P.fu, L + P.hi + 1e-10, 0.0)
        zval = L / max(m_sides, 1) ** 2
        zl = np.where(P.fl, zval, 0.0)
        zu = np.where(P.fu, zval, 0.0)
        z = np.zeros
        return P.point_from(z((N + 1, n)), z((N, m)), z((N + 1, n)), z((N + 1, P.n_nu)), tl, tu, zl, zu)

    def _warm_point(self, P, ws):
        rho = None
        if ws.history and "rho_min" in ws.history[-1]:
            rho = float(ws.history[-1]["rho_min"])
        P.franke = _FrankeState(rho or self.options.rho_min * max(P.n_comp, 1), hot=True)
        return super()._warm_point(P, ws)

    def _direction(self, ctx):
        """One Newton direction with Franke's complementarity target (class docstring)."""
        P, it, st = ctx.P, ctx.it, ctx.P.franke
        m = P.n_comp
        gap = ctx.mu * m
        watch_hot_start(st, gap)
        if m == 0:
            tau = 0.0
        elif gap * st.rhomin > 1.0 or st.alpha < 1.0:
            tau = st.alphabar * gap / st.rhomin + (1.0 - st.alphabar) * gap / m
        else:
            tau = gap * gap
        rho_l, rho_u = P.rho_l, P.rho_u
        np.subtract(tau, it.zl * it.tl, out=rho_l)
        np.subtract(tau, it.zu * it.tu, out=rho_u)
        rho_l[~P.fl] = 0.0
        rho_u[~P.fu] = 0.0
        P.directions()
        d = ctx.solve(ctx.res, rho_l, rho_u, P.dir_main)
        alpha = ctx.step_length(d)[0]     # the step the iteration takes (deterministic)
        st.alpha = alpha
        st.alphabar = 0.5 * (st.alphabar + alpha)
        if st.alphabar == 1.0:
            st.rhomin *= 2.0
        elif st.alphabar < 0.5 and st.rhomin > 100.0 * m:
            st.rhomin *= 0.5
        return d, {"alpha_aff": alpha, "sigma": tau / ctx.mu if ctx.mu > 0 else 0.0, "safeguard": False,
                   "correctors": 0, "omega": 1.0, "rho_min": st.rhomin}
