"""The matrix work the solvers share (docs/architecture.md, "The linalg and qp layers"): the KKT
back-end interface and its table (:mod:`.backend`), the block Riccati LQ-DOCP solver
(:mod:`.riccati`, compiled kernels in :mod:`.riccati_kernels` and :mod:`.riccati_fixed`), the
general sparse back-ends (:mod:`.kkt`) and the kernel toolkit (:mod:`.codegen`).

Importing the package is cheap: the names below load their module on first access (PEP 562),
so listing the KKT back-ends does not import numba.
"""

from __future__ import annotations

from .._registry import lazy_attributes

# public name -> module that defines it
_LAZY = {
    "KKT_BACKENDS": "olado.linalg.backend",
    "KKT_SOLVERS": "olado.linalg.backend",
    "KKTBackend": "olado.linalg.backend",
    "LQSolution": "olado.linalg.backend",
    "NotPositiveDefiniteError": "olado.linalg.backend",
    "StageData": "olado.linalg.backend",
    "make_kkt_solver": "olado.linalg.backend",
    "RiccatiFactorization": "olado.linalg.riccati",
    "RiccatiStatusError": "olado.linalg.riccati",
    "solve_lq_docp": "olado.linalg.riccati",
    "KKTSolveError": "olado.linalg.kkt",
}

__all__ = list(_LAZY)


__getattr__, __dir__ = lazy_attributes(__name__, _LAZY)
