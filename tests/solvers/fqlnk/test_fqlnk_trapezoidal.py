"""The seed's own transcription of its Earth-to-Mars problem (benchmarks/bench_fqlnk.py,
``trapezoidal_problem``: the trapezoidal rule with node controls, seed 002 sec. 2.3 and 4.1)
against the seed's published grid test (Table 4.3), and FQLNK on it: the discrete problem the
seed solved, the local solution its iteration reached at 8 subintervals."""

import sys
from pathlib import Path

import numpy as np
import pytest

import olado
from olado.result import Status
from olado.solvers.base import Solver

from fixtures import CONFIGS

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "benchmarks"))
from bench_fqlnk import trapezoidal_problem  # noqa: E402

IPOPT = str(CONFIGS / "ipopt.ini")
#: seed 002's Table 4.3: |p.i.(N) - p.i.(256)| for N = 8, 16, 32 subintervals
SEED_PI_ERROR = {8: 3.8179e-02, 16: 5.0925e-03, 32: 1.2153e-03}


def test_trapezoidal_residuals_vanish_at_the_integrated_start():
    """The start integrates the trapezoidal rule (seed sec. 4.3): the dynamics and R_k rows hold
    there to rounding, only the two terminal rows are violated."""
    p = trapezoidal_problem(8, np.linspace(0.5, -1.0, 9))
    X, U = Solver.initial_point(p, None)        # the start every solver takes
    np.testing.assert_allclose(p.simulate(U), X, atol=1e-12)         # x^{k+1} = f^k(x^k, u^k) holds
    g = p.eval_stage_constraints(X, U)
    assert np.abs(g[:, p.stage_equality_mask]).max() < 1e-12
    assert abs(p.eval_final_constraints(X[-1])).max() > 1e-2


def test_trapezoidal_problem_is_the_seeds():
    """IPOPT's r(t_f) at N = 16 and 32 plus the seed's performance-index errors give the same
    256-subinterval value to 1e-5 (1.52526): olado's rebuild is the seed's discrete problem."""
    ref = {}
    for N in (16, 32):
        r = olado.solve(trapezoidal_problem(N, np.zeros(N + 1)), config=IPOPT)
        assert r.status is Status.SUCCESS, r.message
        ref[N] = r.x[-1, 0] + SEED_PI_ERROR[N]
    assert ref[16] == pytest.approx(ref[32], abs=1e-5)
    assert ref[32] == pytest.approx(1.52526, abs=1e-4)


def test_fqlnk_bfgs_reaches_the_seeds_point_at_8_subintervals():
    """From phi = 0.5 -> -1 rad, BFGS reaches r(t_f) = 1.48708 = 1.52526 - 0.038179, the seed's
    N = 8 value, in about the seed's 14 Newton iterations (IPOPT from phi = 0 finds 1.50337)."""
    r = olado.solve(trapezoidal_problem(8, np.linspace(0.5, -1.0, 9)), solver="fqlnk")
    assert r.status is Status.SUCCESS, r.message
    assert r.x[-1, 0] + SEED_PI_ERROR[8] == pytest.approx(1.52526, abs=1e-4)
    assert r.iterations <= 20
