"""Primal-dual interior-point methods for the stage QP (14) (paper 001 sec. 4.2.2).

Four methods share one base class, :class:`InteriorPointQP`, which owns the preparation, the
residuals, the Newton step through a pluggable KKT back-end and the bookkeeping; they differ
only in how the search direction is built from one factorization per iteration:
:class:`MehrotraQP` (Mehrotra's predictor-corrector with the Salahi-Peng-Terlaky safeguard),
:class:`GondzioQP` (plus Gondzio's multiple centrality correctors),
:class:`WeightedCorrectorQP` (every corrector weighted by a line search) and :class:`FrankeQP`
(Franke's single-solve method with its barrier rule, Wright's start and its hot start). They
are reached by name through :func:`olado.qp.make_qp_solver`.

The method, its numerics and the modules of this package are described in
docs/qp-interior-point.md.
"""

from .methods import FrankeQP, GondzioQP, MehrotraQP, WeightedCorrectorQP
from .options import FrankeQPOptions, GondzioQPOptions, InteriorPointQPOptions, WeightedCorrectorQPOptions
from .solver import InteriorPointQP

__all__ = ["InteriorPointQP", "MehrotraQP", "GondzioQP", "WeightedCorrectorQP", "FrankeQP", "InteriorPointQPOptions",
           "GondzioQPOptions", "WeightedCorrectorQPOptions", "FrankeQPOptions"]
