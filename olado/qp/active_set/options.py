"""Options of the active-set QP method (docs/qp-active-set.md explains each mechanism)."""

from __future__ import annotations

import dataclasses

from ...options import option


@dataclasses.dataclass
class ActiveSetQPOptions:
    """Options of :class:`~olado.qp.active_set.GoldfarbIdnaniQP`."""

    tol: float = option(1e-9, "feasibility tolerance: a side n^T z >= b (general rows normalized to unit norm) is "
                        "violated when b - n^T z > tol (1 + |b|); the solve ends when none is", min=0.0,
                        min_exclusive=True)
    max_iter: int = option(10_000, "maximum number of working-set changes (constraints added or dropped)", min=0)
    init: str = option("bertsekas", "cold start's initial working set: 'bertsekas' (the sides of the boxes on which "
                       "the zero step lies, Bertsekas' epsilon-active set, then every one whose EQP multiplier is "
                       "negative dropped) or 'none' (only the equalities: Goldfarb and Idnani's own start); a warm "
                       "start begins with the warm start's working set instead", choices=("bertsekas", "none"))
    init_eps: float = option(1e-8, "'bertsekas' initialization: a side is epsilon-active at the zero step when "
                             "|b| <= init_eps", min=0.0)
    verbose: int = option(0, "0 silent, 1 summary, 2 one line per working-set change", min=0, max=12)
