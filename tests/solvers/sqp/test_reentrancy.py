"""One SQPSolver instance runs several solves at once: everything per solve lives in the solve's
state (olado.solvers.sqp.state), the solver holds only options."""

import threading

import numpy as np
import pytest

from olado.problems.zambezi import zambezi_problem
from olado.solvers.sqp.solver import SQPSolver

from fixtures.toy_problems import Pendulum


def same(a, b):
    """Two Results of the same solve: same iterates, counts and residuals, bit for bit."""
    assert a.status == b.status and a.message == b.message
    assert a.iterations == b.iterations and a.qp_iterations == b.qp_iterations
    assert a.objective == b.objective and a.kkt_residual == b.kkt_residual
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.u, b.u)
    for key in a.multipliers:
        np.testing.assert_array_equal(a.multipliers[key], b.multipliers[key])
    assert [h["mode"] for h in a.history] == [h["mode"] for h in b.history]
    assert [h["shift"] for h in a.history] == [h["shift"] for h in b.history]


PROBLEMS = {"zambezi12": lambda: zambezi_problem("zambezi12", N=48),
            "pendulum": lambda: Pendulum(N=20),
            "zambezi9": lambda: zambezi_problem("zambezi9", N=24, start="sif")}


@pytest.mark.parametrize("options", [{}, pytest.param({"adaptive_proximal": True, "hessian": "sr1"}, marks=pytest.mark.slow)],
                         ids=["exact", "sr1-adaptive"])
def test_one_instance_solves_different_problems_in_threads(options):
    """Three threads share one solver instance and each solves its own problem twice; every
    result equals the one of a separate instance."""
    alone = {name: SQPSolver(**options).solve(make()) for name, make in PROBLEMS.items()}
    shared = SQPSolver(**options)
    start = threading.Barrier(len(PROBLEMS))
    results, errors = {}, []

    def run(name):
        try:
            start.wait()
            results[name] = [shared.solve(PROBLEMS[name]()) for _ in range(2)]
        except Exception as exc:  # pragma: no cover - reported below
            errors.append(exc)

    threads = [threading.Thread(target=run, args=(name,)) for name in PROBLEMS]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    for name, ref in alone.items():
        assert ref.iterations > 2           # long enough for the solves to interleave
        for r in results[name]:
            same(r, ref)


def test_a_callback_may_start_another_solve_with_the_same_instance():
    """The callback of the first iteration solves another problem with the same solver; the
    outer solve goes on unchanged (with adaptive_proximal the QP's proximal term depends on the
    last relative KKT residual, which a solver-wide attribute would take from the inner solve)."""
    inner = {}

    def callback(info):
        if not inner:
            inner["result"] = None
            inner["result"] = solver.solve(Pendulum(N=20))
        return False

    solver = SQPSolver(adaptive_proximal=True, callback=callback)
    outer = solver.solve(zambezi_problem("zambezi12", N=48))
    ref_outer = SQPSolver(adaptive_proximal=True).solve(zambezi_problem("zambezi12", N=48))
    ref_inner = SQPSolver(adaptive_proximal=True).solve(Pendulum(N=20))
    assert ref_outer.iterations > 1 and ref_inner.iterations > 1
    same(outer, ref_outer)
    same(inner["result"], ref_inner)
