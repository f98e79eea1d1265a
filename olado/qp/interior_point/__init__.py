"""Primal-dual interior-point methods for the stage QP (14) (paper 001 sec. 4.2.2).

Three methods share one base class, :class:`InteriorPointQP`, which owns the preparation, the
residuals, the Newton step through a pluggable KKT back-end and the bookkeeping; they differ
only in how the search direction is built from one factorization per iteration:
:class:`MehrotraQP` (Mehrotra's predictor-corrector with the Salahi-Peng-Terlaky safeguard),
:class:`GondzioQP` (plus Gondzio's multiple centrality correctors) and
:class:`WeightedCorrectorQP` (every corrector weighted by a line search). They are reached by
name through :func:`olado.qp.make_qp_solver`.

The method, its numerics and the modules of this package are described in
docs/qp-interior-point.md.
"""

from .methods import GondzioQP, MehrotraQP, WeightedCorrectorQP
from .options import GondzioQPOptions, InteriorPointQPOptions, WeightedCorrectorQPOptions
from .solver import InteriorPointQP

__all__ = ["InteriorPointQP", "MehrotraQP", "GondzioQP", "WeightedCorrectorQP", "InteriorPointQPOptions",
           "GondzioQPOptions", "WeightedCorrectorQPOptions"]
