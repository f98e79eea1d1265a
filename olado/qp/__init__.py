"""The QP layer: the stage-structured QP (paper 001 sec. 4.2.2), olado's QP methods -- the
interior-point methods whose Newton steps are KKT back-end solves and the active-set method whose
equality-constrained subproblems are Riccati solves -- and adapters to external QP solvers.

``QP_METHODS`` is the one table of QP methods: olado's own methods (``OLADO_METHODS``, classes
loaded on first use; ``INTERIOR_POINT_METHODS`` names the interior-point ones among them) and the
external qpsolvers back-ends (:class:`~olado.qp.external.ExternalQP` with that back-end).
:func:`make_qp_solver` builds either by name.
"""

from __future__ import annotations

from .._registry import LazyRegistry

#: olado's own QP methods: name -> class (lazy). They solve the stage QP with its structure (O(N)
#: Riccati solves), take ``tol`` and ``max_iter``, and report a KKT factorization that finds a
#: reduced Hessian not positive definite as NUMERICAL_ERROR (the SQP's inertia correction)
OLADO_METHODS = LazyRegistry("QP method", {
    "mehrotra": "olado.qp.interior_point:MehrotraQP",
    "gondzio": "olado.qp.interior_point:GondzioQP",
    "weighted": "olado.qp.interior_point:WeightedCorrectorQP",
    "franke": "olado.qp.interior_point:FrankeQP",
    "active-set": "olado.qp.active_set:GoldfarbIdnaniQP",
    "bounds": "olado.qp.bounds:PrimalDualActiveSetQP",
}, key="qp")
#: the interior-point methods among them (their Newton systems go through a KKT back-end, ``kkt``)
INTERIOR_POINT_METHODS = ("mehrotra", "gondzio", "weighted", "franke")
#: olado's methods that take a KKT back-end (``kkt``): the interior-point ones, and the simple-bounds
#: method (``bounds``: stage QPs with simple bounds only), whose fallback is an interior-point method
KKT_METHODS = (*INTERIOR_POINT_METHODS, "bounds")
#: external QP solvers reached through qpsolvers (olado.qp.external)
EXTERNAL_METHODS = ("osqp", "clarabel", "piqp", "proxqp", "highs", "quadprog", "cvxopt")
#: every QP method name accepted by ``make_qp_solver`` (and the SQP's ``qp`` option)
QP_METHODS = (*OLADO_METHODS, *EXTERNAL_METHODS)
#: the active-set method's iteration limit is this times ``max_iter`` (it counts working-set
#: changes, one per constraint added or dropped, not Newton iterations)
ACTIVE_SET_ITER_FACTOR = 100


def make_qp_solver(name="mehrotra", options=None, *, kkt=None, tol=None, max_iter=None, **overrides):
    """QP method by name: olado's interior-point methods (Newton steps by the KKT back-end
    ``kkt``), the active-set method (``active-set``: ``kkt`` ignored, the Riccati recursion; up
    to ``ACTIVE_SET_ITER_FACTOR`` (100) times ``max_iter`` working-set changes), the simple-bounds
    method (``bounds``: ``kkt`` and ``max_iter`` are its interior-point fallback's) or an external
    qpsolvers back-end (OSQP, Clarabel, ...). ``options`` (an options object) and ``overrides``
    are validated like every option; ``kkt``, ``tol`` and ``max_iter`` left at None keep the
    method's defaults. An external back-end ignores ``kkt`` and ``tol`` (its own tolerances are
    set through ``overrides``); OSQP, a first-order method, gets ``max(100 max_iter, 50 000)``
    iterations."""
    if name in OLADO_METHODS:
        given = {k: v for k, v in (("kkt", kkt), ("tol", tol), ("max_iter", max_iter)) if v is not None}
        if name not in KKT_METHODS:
            given.pop("kkt", None)
            if "max_iter" in given:
                given["max_iter"] *= ACTIVE_SET_ITER_FACTOR
        return OLADO_METHODS[name](options, **{**given, **overrides})
    if name not in EXTERNAL_METHODS:
        from ..errors import ConfigError

        raise ConfigError(f"unknown QP method {name!r}", key="qp", allowed=", ".join(QP_METHODS))
    from .external import ExternalQP

    if name == "osqp":
        overrides.setdefault("max_iter", max(100 * (200 if max_iter is None else max_iter), 50_000))
    return ExternalQP(backend=name, options=options, **overrides)


__all__ = ["QP_METHODS", "OLADO_METHODS", "INTERIOR_POINT_METHODS", "KKT_METHODS", "EXTERNAL_METHODS", "make_qp_solver"]
