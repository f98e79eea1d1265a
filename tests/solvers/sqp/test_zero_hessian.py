"""A zero Lagrangian Hessian (a Mayer or linear objective at zero multipliers) and the QP methods
that need a strictly convex QP. The proximal term and the elastic slacks' curvature were relative
to max|H|, floored at 1e-300: the QP got the Hessian 1e-304 I, which a Cholesky factorization
accepts as positive definite, and Goldfarb-Idnani's first EQP had its minimizer near 1e300 --
batch-reactor from zero multipliers ended INFEASIBLE at SQP iteration 0 ("the lower bound of
u[41, 0] (violated by 9.29e+282) is linearly dependent ..."), free-flying-robot made no SQP
iteration in 60 s. Both terms are now relative to shift_scale (1 when H = 0). References: the
stored IPOPT objectives of the robustness set."""

from pathlib import Path

import numpy as np
import pytest

import olado
import olado.solvers.sqp.step as sqp_step
from olado.problems.suites import load_references, load_suite
from olado.result import Status

CONFIGS = Path(__file__).resolve().parents[3] / "configs"


def _entry(name):
    problem, guess = next(e for e in load_suite("robustness") if e.name == name).build()
    return problem, guess, load_references()["entries"][name]["objective"]


def test_first_qp_hessian_is_not_1e_304(monkeypatch):
    """batch-reactor (objective -x2(1)) from zero multipliers: H = 0 at the first iterate; the
    QP's Hessian is the proximal term relative to 1, not to 1e-300."""
    problem, guess, _ = _entry("batch-reactor")
    seen = []
    build = sqp_step.build_qp

    def keep(p, pt, Bd, BNd, *args, **kw):
        seen.append(float(np.min(np.diagonal(Bd, axis1=1, axis2=2))))
        return build(p, pt, Bd, BNd, *args, **kw)

    assemble = sqp_step.assemble_qp

    def keep_assembled(p, pt, Bk, BN, shift, *args, **kw):      # the compiled assembly: Bk + shift_k I
        diag = np.diagonal(Bk, axis1=1, axis2=2) + (0.0 if shift is None else shift[:-1][:, None])
        seen.append(float(np.min(diag)))
        return assemble(p, pt, Bk, BN, shift, *args, **kw)

    monkeypatch.setattr(sqp_step, "build_qp", keep)
    monkeypatch.setattr(sqp_step, "assemble_qp", keep_assembled)
    olado.solve(problem, guess=guess, config=CONFIGS / "sqp-as.ini", initial_multipliers="zero", max_iter=1)
    assert seen and seen[0] == pytest.approx(1e-4, rel=1e-12)       # proximal (1e-4) * shift_scale (1)


def test_active_set_sqp_from_zero_multipliers_on_batch_reactor():
    problem, guess, ref = _entry("batch-reactor")
    r = olado.solve(problem, guess=guess, config=CONFIGS / "sqp-as.ini", initial_multipliers="zero")
    assert r.status is Status.SUCCESS, r.message
    assert r.objective == pytest.approx(ref, rel=1e-6)


@pytest.mark.slow
def test_active_set_sqp_on_free_flying_robot():
    """Its first QP is INFEASIBLE (at u = 0 the linearized thrusters push along the body axis
    only: two terminal rows reach x_0), the elastic QP then has H = 0 on the controls."""
    problem, guess, ref = _entry("free-flying-robot")
    r = olado.solve(problem, guess=guess, config=CONFIGS / "sqp-as.ini", max_time=300)
    assert r.status is Status.SUCCESS, r.message
    assert r.objective == pytest.approx(ref, rel=1e-6)


def test_shifts_of_a_zero_hessian_are_relative_to_one():
    """WORHP's tau shift (eq. [11]) and the inertia correction's raise were relative to max|H|
    = 1e-300 at H = 0: tau (|sigma| + 1e-300) ~ 0 and shift_init * 1e-300, so raising tau or delta
    changed nothing, and hang-glider (objective -x(T), zero multipliers at the start) reached
    tau = 1 at its second iterate without any shift; once its Hessian was nonzero that tau = 1
    made delta >= max|H| and the QP multipliers grew to 1e34. Both are now relative to
    shift_scale (1 when H = 0), as the proximal term."""
    from olado.solvers.sqp import regularization
    from olado.solvers.sqp.solver import SQPOptions

    N, n, m = 3, 2, 1
    Bk, BN = np.zeros((N, n + m, n + m)), np.zeros((n, n))
    hscale = sqp_step.hessian_scale(Bk, BN)
    assert hscale == 1e-300
    np.testing.assert_allclose(regularization.tau_shift(1e-3, Bk, BN, hscale), np.full(N + 1, 1e-3))
    o = SQPOptions()
    raised = sqp_step.ShiftRule(o).raise_(np.zeros(N + 1), hscale)
    np.testing.assert_allclose(raised, np.full(N + 1, o.shift_init))      # shift_init * 1
    # a nonzero Hessian keeps its own scale
    Bk[:, 0, 0] = -2.0
    np.testing.assert_allclose(regularization.tau_shift(0.5, Bk, BN, 2.0), [2.0, 2.0, 2.0, 1.0])
