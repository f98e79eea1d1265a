"""Variants of olado's built-in problems (:mod:`olado.problems.testproblems`) with more
constraints, for the robustness set.

=================  =========================================================================
``rayleigh-mixed``  the Rayleigh problem with the mixed control-state constraint u + x1/6 <= 0
=================  =========================================================================
"""

from __future__ import annotations

from .testproblems import Rayleigh

__all__ = ["RayleighMixed", "PROBLEMS"]


class RayleighMixed(Rayleigh):
    """The Rayleigh problem (:class:`~olado.problems.testproblems.Rayleigh`) with the mixed
    control-state constraint of Maurer and Augustin (2001) (also Büskens and Maurer, J. Comput.
    Appl. Math. 120 (2000) 85-108)::

        u(t) + x1(t) / 6 <= 0,   written g^k = -u^k - x1^k / 6 >= 0,  k = 0..N-1.

    Published: no value is quoted here (none was verified for this exact formulation). The
    constraint is linear, so the stage Hessians are those of the unconstrained problem. Start:
    u = -1 (the constraint holds at the start: x1(0)/6 = -5/6 and u <= 5/6).
    """

    def __init__(self, N=50, **options):
        options.setdefault("name", "rayleigh-mixed")
        options.setdefault("u_guess", -1.0)
        super().__init__(N, path_constraints=lambda t, x, u, p: [-u[0] - x[0] / 6.0], **options)


def _rayleigh_mixed(N=50, method="rk4"):
    """Rayleigh problem with u + x1/6 <= 0 (Maurer and Augustin 2001); see RayleighMixed."""
    return RayleighMixed(N=N, method=method)


#: name -> factory (registered lazily by olado.problems.catalog)
PROBLEMS = {"rayleigh-mixed": _rayleigh_mixed}
