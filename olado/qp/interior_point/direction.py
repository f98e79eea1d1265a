"""The search direction of the interior-point QP methods (paper 001 (22), one factorization per
iteration): Mehrotra's predictor-corrector (Mehrotra 1992) with the safeguard of Salahi, Peng
and Terlaky (2007); the methods of :mod:`.methods` add centrality correctors and corrector
weights through the solver's hooks.
"""

from __future__ import annotations


def predictor_corrector(solver, ctx, combined):
    """Mehrotra's predictor-corrector direction with the Salahi-Peng-Terlaky safeguard (see
    :class:`~olado.qp.interior_point.MehrotraQP`), then the solver's centrality correctors
    (``solver._centrality_correctors``), each corrector weighted by ``solver._corrector_weight``.
    ``combined``: the correctors are unweighted (predictor and corrector are then solved as one
    right-hand side). Returns (direction, info)."""
    P, it, mu = ctx.P, ctx.it, ctx.mu
    opts = solver.options
    P.directions()
    # predictor (affine scaling, sigma = 0); the right-hand sides of every solve are written
    # into P.rho_l, P.rho_u (each solve is done with them before the next one is formed)
    # (the kernels forming them return max |rho_l, rho_u|, which the solve's refinement test reads)
    rho_l, rho_u = P.rho_l, P.rho_u
    size = P.kernels.predictor_rhs(it.slacks, rho_l, rho_u)
    d_aff = ctx.solve(ctx.res, rho_l, rho_u, P.dir_aff, size)
    a_aff = min(1.0, ctx.max_step(d_aff))
    if P.n_comp == 0:
        return d_aff, {"alpha_aff": a_aff, "sigma": 0.0, "safeguard": False, "correctors": 0, "omega": 1.0}
    # Mehrotra's second-order term: the products dt_aff * dz_aff
    fl, fu = P.fl, P.fu
    safeguard = a_aff < opts.safeguard_step
    omega = 1.0
    # unweighted correctors (Mehrotra, Gondzio; ``combined``): d_aff + d_c in one solve with the
    # combined right-hand side (the same direction up to rounding, one vector pass less)
    if not safeguard:
        sigma = (1.0 - a_aff) ** 3
        if combined:
            size = P.kernels.combined_rhs(it.slacks, fl, fu, d_aff.slacks, sigma * mu, 1.0, rho_l, rho_u)
            d = ctx.solve(ctx.res, rho_l, rho_u, P.dir_main, size)
        else:
            size = P.kernels.corrector_rhs(fl, fu, d_aff.slacks, sigma * mu, 1.0, rho_l, rho_u)
            d_c = ctx.solve(ctx.zero_res, rho_l, rho_u, P.dir_corr, size)
            omega = solver._corrector_weight(ctx, d_aff, d_c, a_aff)
            d = d_aff.plus(omega, d_c)
        safeguard = min(1.0, ctx.max_step(d)) < opts.safeguard_step
    if safeguard:
        gam = opts.safeguard_gamma
        sigma = gam / (1.0 - gam)
        size = P.kernels.corrector_rhs(fl, fu, d_aff.slacks, sigma * mu, a_aff, rho_l, rho_u)
        d_c = ctx.solve(ctx.zero_res, rho_l, rho_u, P.dir_corr, size)
        omega = solver._corrector_weight(ctx, d_aff, d_c, a_aff)
        d = d_aff.plus(omega, d_c)
    d, ncorr = solver._centrality_correctors(ctx, d, sigma * mu)
    return d, {"alpha_aff": a_aff, "sigma": sigma, "safeguard": bool(safeguard), "correctors": ncorr,
               "omega": omega}
