"""The solvers olado knows, by name: one explicit lazy table (``name -> "module:Class"``).

Used by :func:`olado.solve`, the ini configuration and the command line. The table is data: it
holds each solver's one-line summary and the optional module its back-end needs, so ``olado
list`` prints every solver without importing any solver module, and choosing one solver imports
that solver's module only. A solver's summary is declared here and nowhere else
(:meth:`olado.solvers.base.Solver.summary` reads it).
"""

from __future__ import annotations

from .._registry import Entry, LazyRegistry

__all__ = ["SOLVERS", "get_solver_class", "available_solvers"]

_CONTROL = "olado.solvers.control"

#: solver name -> Entry(class, summary, optional modules, install hint); alphabetical
SOLVERS = LazyRegistry("solver", {
    "cg": Entry(f"{_CONTROL}.reduced_gradient:ConjugateGradientSolver",
                "conjugate directions in the control space, strong Wolfe line search, restarts"),
    "ddp": Entry(f"{_CONTROL}.ddp:DDPSolver",
                 "differential dynamic programming (unconstrained DOCPs), shifted Q_uu, O(N) per iteration"),
    "fqlnk": Entry("olado.solvers.fqlnk.solver:FQLNKSolver",
                   "full-space quasi Lagrange-Newton-Krylov (seed 002): Newton on the KKT conditions, damped BFGS "
                   "(or exact / FD) Hessian, ILUTP-preconditioned GMRES, augmented Lagrangian merit; equality "
                   "constraints (inequalities refused, or squared slacks)"),
    "gradient": Entry(f"{_CONTROL}.reduced_gradient:GradientSolver",
                      "steepest descent in the control space (adjoint gradient), strong Wolfe line search"),
    "ipm": Entry("olado.solvers.ipm.solver:IPMSolver",
                 "IPOPT's primal-dual interior-point filter method on the DOCP, one block Riccati "
                 "factorization per Newton system (bounds, stage and final constraints through slacks)"),
    "ipopt": Entry("olado.solvers.nlp.ipopt:IpoptSolver",
                   "IPOPT interior-point method (cyipopt) on the sparse NLP view, sec. 4.3.2",
                   requires=("cyipopt",), install='pip install "cyipopt-wheels>=1.7.0.dev0"'),
    "newton": Entry(f"{_CONTROL}.reduced_gradient:NewtonSolver",
                    "Newton's method in the control space: truncated CG on reduced-Hessian products "
                    "(second-order adjoint), negative-curvature exit, strong Wolfe line search"),
    "pdmin": Entry(f"{_CONTROL}.pdmin:PDMINSolver",
                   "projected descent (Schwartz-Polak / Bertsekas) on the controls: steepest descent, "
                   "Polak-Ribiere CG or L-BFGS on the free variables, Armijo rule along the projection arc; "
                   "simple control bounds only"),
    "penalty": Entry(f"{_CONTROL}.penalty:PenaltySolver",
                     "quadratic penalty / augmented Lagrangian method with an unconstrained inner solver"),
    "slsqp": Entry("olado.solvers.nlp.scipy_nlp:SLSQPSolver",
                   "SciPy SLSQP (dense SQP, BFGS) on the NLP view; small problems"),
    "sqp": Entry("olado.solvers.sqp.solver:SQPSolver",
                 "Powell's SQP, L1 merit + watchdog, block Hessians, interior-point QP with the Riccati "
                 "KKT solver"),
    "stagewise-newton": Entry(f"{_CONTROL}.ddp:StagewiseNewtonSolver",
                              "Pantoja's stagewise Newton method (unconstrained DOCPs), shifted Hessian, "
                              "O(N) per iteration"),
    "trust-constr": Entry("olado.solvers.nlp.scipy_nlp:TrustConstrSolver",
                          "SciPy trust-constr (trust-region SQP / barrier) with sparse Jacobian and Hessian"),
    "variable-metric": Entry(f"{_CONTROL}.reduced_gradient:VariableMetricSolver",
                             "variable metric (BFGS) in the control space, strong Wolfe line search"),
})


def get_solver_class(name: str):
    """The solver class registered as ``name`` (its module imported now); an unknown name is a
    :class:`~olado.errors.ConfigError` naming the known ones."""
    return SOLVERS[name]


def available_solvers() -> dict:
    """``{name: class}`` of every registered solver (imports every solver module: a listing that
    needs no class should iterate :data:`SOLVERS` instead)."""
    return {name: SOLVERS[name] for name in SOLVERS}
