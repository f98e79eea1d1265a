"""An x0 outside the problem's own x_bounds (issue 13): x^0 is fixed at x0 (the NLP view's
x_lower[0] = x_upper[0] = x0, olado.solvers.certificate.StageBounds.of), so the bounds of stage 0
are moot -- every family solves such a problem as IPOPT does, and no result counts them as
violated. The SQP's QP drops them (olado.solvers.sqp.step.build_qp: the x0 row fixes x^0), its
merit functions and the diagnosis give them no violation, the certificate and the residuals
replace them by x0."""

from pathlib import Path

import numpy as np
import pytest

import olado
from olado.problems import get_problems

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
#: lq-box at N = 50 (olado.problems.testproblems.LinearQuadratic): J* = 16.0606421 (docstring;
#: the robustness set's lq-box row), which stage-0 bounds cannot change
LQ_BOX = 16.06064214


def _lq_box_with_unreachable_stage0_bounds():
    """Every component of x0 = (1, -1, 0.5, 2) above its stage-0 upper bound x0 - 1; no bound on
    the other stages."""
    p = get_problems()["lq-box"]()
    xl, xu = p.x_lower.copy(), p.x_upper.copy()
    xu[0] = p.x0 - 1.0
    p.x_bounds = (xl, xu)
    return p


@pytest.mark.parametrize("config", ["ipopt", "sqp-ip", "sqp-as", "sqp-bounds", "penalty"])
def test_stage0_bounds_that_x0_violates_are_moot(config):
    p = _lq_box_with_unreachable_stage0_bounds()
    r = olado.solve(p, config=CONFIGS / f"{config}.ini")
    assert r.success, r.message
    assert r.objective == pytest.approx(LQ_BOX, rel=1e-6)
    assert r.max_constraint_violation < 1e-6
    assert np.array_equal(r.x[0], p.x0)


@pytest.mark.parametrize("guess", ["controls", "states at x0", "states at the stage-0 bound"])
def test_any_guess_of_x0_is_replaced_by_x0(guess):
    """sqp-ip from a guess (X, U) whose X[0] honours the stage-0 bounds instead of x0: X[0] is
    replaced by x0, the same solution."""
    p = _lq_box_with_unreachable_stage0_bounds()
    U = np.zeros((p.N, p.m))
    X = p.simulate(U)
    if guess == "states at the stage-0 bound":
        X[0] = p.x_upper[0]
    r = olado.solve(p, config=CONFIGS / "sqp-ip.ini", guess=U if guess == "controls" else (X, U))
    assert r.success, r.message
    assert r.objective == pytest.approx(LQ_BOX, rel=1e-6)


def test_uniform_bounds_that_only_x0_violates_match_ipopt():
    """vanderpol from x0 = (-0.5, 1) with x1 >= -0.4 at every stage: x0 violates it by 0.1, x^1
    can honour it; sqp-ip reaches IPOPT's objective."""
    def make():
        return get_problems()["vanderpol"](x0=np.array([-0.5, 1.0]), x_bounds=((-0.4, -np.inf), (np.inf, np.inf)))
    ref = olado.solve(make(), config=CONFIGS / "ipopt.ini")
    r = olado.solve(make(), config=CONFIGS / "sqp-ip.ini")
    assert ref.success and r.success, (ref.message, r.message)
    assert r.objective == pytest.approx(ref.objective, rel=1e-6)
    assert np.all(r.x[1:, 0] >= -0.4 - 1e-8)
