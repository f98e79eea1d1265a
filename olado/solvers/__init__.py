"""How problems are solved: the Solver base class and the solver families (paper 001 sec. 2.2).

The solvers are listed, by name, in :data:`olado.solvers.registry.SOLVERS`; importing this
package imports none of them (names below load on first access, PEP 562).
"""

from __future__ import annotations

from .._registry import lazy_attributes

#: public name -> module that defines it
_LAZY = {
    "Solver": "olado.solvers.base",
    "SolverOptions": "olado.solvers.base",
    "option": "olado.options",
    "SOLVERS": "olado.solvers.registry",
    "available_solvers": "olado.solvers.registry",
    "get_solver_class": "olado.solvers.registry",
}

__all__ = list(_LAZY)


__getattr__, __dir__ = lazy_attributes(__name__, _LAZY)
