"""Options of the interior-point QP methods (docs/qp-interior-point.md explains each mechanism)."""

from __future__ import annotations

import dataclasses

from ...linalg.backend import KKT_SOLVERS
from ...options import option


@dataclasses.dataclass
class InteriorPointQPOptions:
    """Options shared by the interior-point QP methods."""

    tol: float = option(1e-8, "relative KKT tolerance (primal, dual residual and complementarity; docs/qp-interior-point.md)",
                        min=0.0, min_exclusive=True)
    max_iter: int = option(100, "maximum number of interior-point iterations", min=0)
    kkt: str = option("riccati", "KKT back-end for the Newton systems", choices=KKT_SOLVERS)
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


@dataclasses.dataclass
class FrankeQPOptions(InteriorPointQPOptions):
    """Options of :class:`FrankeQP`: Franke's defaults for the shared ones (one step length for
    primal and dual variables, no neighbourhood, no olado restart) and Franke's own."""

    step_rule: str = option("common", "'common' (Franke: one step length alpha for every variable) or 'primal-dual'",
                            choices=("common", "primal-dual"))
    neighborhood: float = option(0.0, "steps keep every product t_i z_i >= neighborhood * mu (Franke: 0, the step "
                                 "to the boundary only)", min=0.0, max=0.5)
    stall_restart_mu: float = option(1.0, "a cold start that stalls or crawls is solved again from initial_mu times "
                                     "this (1: never, Franke's method has its own restart of a failed hot start)",
                                     min=1.0)
    start: str = option("wright", "cold start: 'wright' (Franke after Wright 1993: x = 0, every slack "
                        "L + d_i, every multiplier L / m^2 with L = max(|d|_inf, 100 m), m the number of "
                        "inequality sides) or 'centred' (olado's start of the other methods, initial_mu)",
                        choices=("wright", "centred"))
    rho_min: float = option(1000.0, "rho_min of the barrier rule at a cold start, per inequality side (Franke: "
                            "1000 m); it doubles after full steps and halves after short ones", min=1.0)
    max_warm_iter: int = option(15, "a hot (warm) start that is not optimal after this many iterations, or whose "
                                "duality gap grows above the gap after its first iteration, is abandoned for a cold "
                                "start (the iterations count)", min=1)
