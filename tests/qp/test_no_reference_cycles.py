"""A solve leaves no reference cycles behind.

Objects in a cycle are freed only when Python's cyclic garbage collector runs, which it does by
object counts, not by memory: a cycle that holds a solve's arrays (the interior-point QP's
prepared problem and its directions, a Newton-matrix failure's traceback frames, the IPOPT
adapter) kept about 100 MB per QP solve at N = 12 000 alive, so memory grew from solve to solve
and repeated solves slowed down by up to 2x (fresh pages to fault in). Each test solves once to
warm up, then counts what ``gc.collect()`` finds unreachable after a second solve.
"""

import gc
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from olado.config import load_config, make_solver
from olado.problems.zambezi import zambezi_problem
from olado.qp.interior_point import GondzioQP, MehrotraQP

from fixtures.qp_problems import random_qp  # noqa: E402
from fixtures import REPO

CONFIGS = REPO / "configs"


def _garbage_of(fn):
    """The objects ``fn()`` leaves in reference cycles (their types)."""
    fn()
    gc.collect()
    gc.disable()
    gc.set_debug(gc.DEBUG_SAVEALL)
    try:
        fn()
        gc.collect()
        return [type(o).__name__ for o in gc.garbage]
    finally:
        gc.garbage.clear()
        gc.set_debug(0)
        gc.enable()


@pytest.mark.parametrize("cls", [MehrotraQP, GondzioQP], ids=lambda c: c.name)
def test_interior_point_qp_leaves_no_cycles(cls):
    qp = random_qp(0, nc=0, ncN=0)
    R = qp.R.copy(); R[2] = -np.eye(qp.m)          # nonconvex: failed factorizations, regularization
    Q = qp.Q.copy(); Q[3] = Q[3] - np.eye(qp.n)
    nonconvex = replace(qp, R=R, Q=Q)
    res = cls().solve(nonconvex)
    assert any(h["regularization"] > 1e-9 for h in res.history), "the QP must exercise a failed factorization"
    assert _garbage_of(lambda: cls().solve(random_qp(1))) == []
    assert _garbage_of(lambda: cls().solve(nonconvex)) == []


@pytest.mark.parametrize("config", ["sqp-ip", "ipopt", "penalty-al"])
def test_nlp_solvers_leave_no_cycles(config):
    if config == "ipopt":
        pytest.importorskip("cyipopt")
    # two outer iterations of the penalty method are enough to exercise its inner solves
    overrides = ["penalty.max_iter=2", "penalty.inner_max_iter=50"] if config.startswith("penalty") else []
    solver = make_solver(load_config(CONFIGS / f"{config}.ini", overrides=overrides))
    problem = zambezi_problem("zambezi12", N=12 if config.startswith("penalty") else 24)
    assert _garbage_of(lambda: solver.solve(problem)) == []
