"""The three interior-point QP methods (paper 001 sec. 4.2.2: Mehrotra, Gondzio; paper 003:
weighted correctors): they differ only in how the search direction is built from the one
factorization per iteration.
"""

from __future__ import annotations

import numpy as np

from .kernels import _centrality_rhs
from .options import GondzioQPOptions, WeightedCorrectorQPOptions
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
