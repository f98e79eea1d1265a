"""The first step's trust region (olado/solvers/sqp/trust.py; issue 13: sqp-ip calls a problem
infeasible only when IPOPT does too): bang-bang-cart, whose first QP is an LP in effect, solved to
IPOPT's stored objective; from the point the old path ended at (T = 1, u = -1) IPOPT and sqp-ip
both report local infeasibility (the verdict there is IPOPT's too: the path was the fault); the
tests of linearity, agreement and the box on hand-computed data."""

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import olado
from olado.problems.suites import load_references, load_suite
from olado.result import Status
from olado.solvers.sqp import trust
from olado.solvers.sqp.state import BoundMultipliers

CONFIGS = Path(__file__).resolve().parents[3] / "configs"


def _entry(name):
    entry = next(e for e in load_suite("robustness") if e.name == name)
    problem, guess = entry.build()
    return entry, problem, guess


@pytest.mark.parametrize("config", ["sqp-ip", pytest.param("sqp-gondzio", marks=pytest.mark.slow),
                                    pytest.param("sqp-sr1", marks=pytest.mark.slow)])
def test_bang_bang_cart_is_solved_from_its_start(config):
    """T = 4, u = 0: the first QP (max|H| = 2.4e-3, s.H s = -0.24 beside g.s = -3.9) stepped T to
    its bound 0.1, where theta fell from 6 to 5.73 instead of 0; the SQP then ended INFEASIBLE at
    T = 1, u = -1. With the box it reaches IPOPT's objective (a verified feasible point)."""
    entry, problem, guess = _entry("bang-bang-cart")
    ref = load_references()["entries"][entry.name]
    assert ref["status"] == "success"
    r = olado.solve(problem, config=CONFIGS / f"{config}.ini", guess=guess)
    assert r.success, r.message
    assert r.objective == pytest.approx(ref["objective"], rel=1e-6)
    assert r.max_constraint_violation < 1e-8
    # the bang-bang structure of Bryson & Ho sec. 7.3: u = -1, then +1 (one switching stage between)
    u = r.u[1:, 0]
    assert np.sum(np.abs(np.abs(u) - 1.0) > 1e-6) <= 1 and u[0] == pytest.approx(-1.0) and u[-1] == pytest.approx(1.0)


def test_the_old_end_point_is_locally_infeasible_for_ipopt_too():
    """T = 1, u = -1: x(T) = 1.5, v(T) = 0 is a strict local minimizer of the discrete l1
    violation (its basin is about one step h wide in T); IPOPT started there converges to a point
    of local infeasibility as the SQP does -- so the old verdict was honest, its path was not."""
    _, problem, _ = _entry("bang-bang-cart")
    U = np.full((problem.N, 1), -1.0)
    U[0, 0] = 1.0
    for config in ("ipopt", "sqp-ip"):
        r = olado.solve(problem, config=CONFIGS / f"{config}.ini", guess=U)
        assert r.status == Status.INFEASIBLE, (config, r.message)
        assert r.u[0, 0] == pytest.approx(1.0, abs=1e-3)


def _step(dX, dU, delta=0.0, slacks=None):
    N = len(dU)
    return SimpleNamespace(dX=np.asarray(dX, float), dU=np.asarray(dU, float), delta=np.full(N + 1, delta),
                           slacks=slacks)


def _state(X, U, Bk, BN, lx, lu, lN):
    pt = SimpleNamespace(X=np.asarray(X, float), U=np.asarray(U, float), lx=np.asarray(lx, float),
                         lu=np.asarray(lu, float), lN=np.asarray(lN, float))
    return SimpleNamespace(pt=pt, Bk=np.asarray(Bk, float), BN=np.asarray(BN, float), clock=None)


def test_a_step_is_linear_when_its_curvature_is_a_tenth_of_its_slope():
    """N = 1, n = m = 1, H = diag(h, h) on (x0, u), HN = 0; s = (dx0, du, dxN) = (0, 2, 2),
    g = (0, 1, 0): s.H s = 4 h, g.s = 2: linear iff 4 h <= 0.2, i.e. h <= 0.05; a shift delta
    counts like h on the stage block and on the final one (|s|^2 = 4 + 4)."""
    step = _step([[0.0], [2.0]], [[2.0]])
    for h, linear in ((0.05, True), (0.051, False), (-0.05, True), (-0.06, False)):
        st = _state([[0.0], [0.0]], [[0.0]], np.full((1, 2, 2), 0.0) + h * np.eye(2), np.zeros((1, 1)),
                    [[0.0]], [[1.0]], [0.0])
        assert trust.linear_step(st, step) is linear, h
    st = _state([[0.0], [0.0]], [[0.0]], np.zeros((1, 2, 2)), np.zeros((1, 1)), [[0.0]], [[1.0]], [0.0])
    assert trust.linear_step(st, _step([[0.0], [2.0]], [[2.0]], delta=0.025))        # 0.025 * 8 = 0.2
    assert not trust.linear_step(st, _step([[0.0], [2.0]], [[2.0]], delta=0.026))


class _Slacks:
    def __init__(self, total):
        self._total = total

    def total(self):
        return self._total


def test_the_agreement_is_the_actual_over_the_predicted_reduction_of_theta(monkeypatch):
    """theta(y) = 6, theta(y + s) = 4.5: predicted 6 (a consistent QP) gives 0.25; predicted 6 - 2
    (a relaxed QP with slacks 2) gives 0.375; nothing predicted (theta(y) <= constr_viol_tol)
    gives 1; a non-finite trial point gives -inf."""
    values = {0.0: 6.0, 1.0: 4.5}

    class FakePoint:
        def __init__(self, problem, X, U, derivatives=True, clock=None):
            self.key = float(U[0, 0])

    monkeypatch.setattr(trust, "Point", FakePoint)
    theta = lambda q: values[q.key] if hasattr(q, "key") else values[0.0]
    st = SimpleNamespace(pt=SimpleNamespace(X=np.zeros((2, 1)), U=np.zeros((1, 1))), clock=None)
    setup = SimpleNamespace(problem=None, options=SimpleNamespace(constr_viol_tol=1e-8))
    step = _step([[0.0], [0.0]], [[1.0]])
    assert trust.agreement(setup, st, step, theta) == pytest.approx(0.25)
    assert trust.agreement(setup, st, _step([[0.0], [0.0]], [[1.0]], slacks=_Slacks(2.0)), theta) == pytest.approx(0.375)
    values[0.0] = 1e-9
    assert trust.agreement(setup, st, step, theta) == 1.0
    values[0.0], values[1.0] = 6.0, float("nan")
    assert trust.agreement(setup, st, step, theta) == -np.inf


def test_the_box_halves_the_largest_relative_control_step():
    """U = (4, 0, -3), dU = (-3.9, 1, 0.5): |dU| / (1 + |U|) = (0.78, 1, 0.125), kappa = 0.5, box
    0.5 (5, 1, 4); a step of relative size below 2 KAPPA_MIN gives no box."""
    st = SimpleNamespace(pt=SimpleNamespace(U=np.array([[4.0], [0.0], [-3.0]])))
    box = trust.next_box(st, SimpleNamespace(dU=np.array([[-3.9], [1.0], [0.5]])))
    assert box == pytest.approx(np.array([[2.5], [0.5], [2.0]]))
    assert trust.next_box(st, SimpleNamespace(dU=np.full((3, 1), 1e-3))) is None


def test_the_box_rows_multipliers_are_dropped():
    """u in [-1, 1] at U = (0, 0.8), box 0.5: at stage 0 both box sides are tighter than the
    bounds (their multipliers go), at stage 1 the upper side is the bound's own (1.3 > 1: kept)."""
    b = BoundMultipliers(np.zeros((3, 1)), np.zeros((3, 1)), np.array([[2.0], [3.0]]), np.array([[4.0], [5.0]]))
    out = trust.drop_box_multipliers(b, np.array([[0.0], [0.8]]), -np.ones((2, 1)), np.ones((2, 1)),
                                     np.full((2, 1), 0.5))
    assert out.zl_u.tolist() == [[0.0], [0.0]]
    assert out.zu_u.tolist() == [[0.0], [5.0]]


def test_a_suspect_first_step_is_boxed_only_after_an_infeasible_end(monkeypatch):
    """zambezi12 N = 24 from its balance start has an LP first step the functions do not follow
    (agreement 0.14); the SQP recovers and converges, so no QP is ever boxed (boxing it doubled
    the QP iterations, 49 -> 95). bang-bang-cart's first attempt ends INFEASIBLE: the second
    attempt from the start boxes its first step, and the iterations of both attempts are counted
    and numbered on."""
    from olado.problems.zambezi import zambezi_problem
    from olado.solvers.sqp import phases

    boxes = []
    real_next_box = trust.next_box
    monkeypatch.setattr(trust, "next_box", lambda st, step: boxes.append(st.it) or real_next_box(st, step))
    suspects = []
    real_first = phases.first_step_trust

    def spy(setup, st, step):
        out = real_first(setup, st, step)
        if st.first_suspect and not suspects:
            suspects.append(st.it)
        return out

    monkeypatch.setattr(phases, "first_step_trust", spy)
    r = olado.solve(zambezi_problem("zambezi12", N=24), config=CONFIGS / "sqp-ip.ini")
    assert r.success and suspects == [0] and boxes == []
    entry, problem, guess = _entry("bang-bang-cart")
    r = olado.solve(problem, config=CONFIGS / "sqp-ip.ini", guess=guess)
    assert r.success
    assert boxes and min(boxes) > 0                     # boxed in the second attempt only
    assert [h["iter"] for h in r.history] == list(range(1, r.iterations + 1))
