"""The infeasibility verdict of the SQP (olado/solvers/sqp/restoration.py, relaxation.py; issue 13:
``sqp-ip.ini`` calls a problem infeasible only when IPOPT does too): robustness-set entries that
used to end INFEASIBLE although IPOPT solves them, solved to IPOPT's stored objective; a
deliberately infeasible entry still reported infeasible; no INFEASIBLE verdict at a feasible
point."""

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import olado
from olado.problems.suites import load_references, load_suite
from olado.result import Status
from olado.solvers.sqp import restoration
from olado.solvers.sqp.step import hessian_scale, shift_scale

CONFIGS = Path(__file__).resolve().parents[3] / "configs"
SQP_IP = CONFIGS / "sqp-ip.ini"


def _entry(name):
    entry = next(e for e in load_suite("robustness") if e.name == name)
    problem, guess = entry.build()
    return entry, problem, guess


def test_a_zero_hessian_shifts_on_the_unit_scale():
    """A linear objective with zero multipliers (every free-time or Mayer problem at the start)
    gives H = 0: the inertia correction's shifts after a failed QP, multiples of max|H|, then use
    1, so that they can bound the QP (they used to multiply 1e-300)."""
    assert shift_scale(hessian_scale(np.zeros((3, 2, 2)), np.zeros((2, 2)))) == 1.0
    Bk = np.zeros((3, 2, 2)); Bk[1, 0, 1] = -4.0
    assert shift_scale(hessian_scale(Bk, np.eye(2))) == 4.0


def test_orbit_raising_is_solved_from_a_zero_hessian_start():
    """Its first QP (H = 0, linear objective) was unbounded for every shift 1e-300 * 10^k, the
    restoration phase drove the violation to 3e-15 and then called the problem infeasible there."""
    entry, problem, guess = _entry("orbit-raising")
    ref = load_references()["entries"][entry.name]
    assert ref["status"] == "success"
    r = olado.solve(problem, config=SQP_IP, guess=guess)
    assert r.success, r.message
    assert r.objective == pytest.approx(ref["objective"], rel=1e-6)
    assert r.max_constraint_violation < 1e-8


@pytest.mark.slow
def test_steering_too_short_is_still_infeasible():
    """The deliberately infeasible entry (IPOPT: infeasible too) -- it used to crawl through 190
    first-order restoration steps to MAX_ITERATIONS; now its QPs that fail numerically are relaxed,
    and the relaxed QP's stationarity test, at the states simulated from the controls, ends it
    INFEASIBLE, naming the final constraint left violated."""
    entry, problem, guess = _entry("steering-too-short")
    assert not entry.feasible
    assert load_references()["entries"][entry.name]["status"] == "infeasible"
    r = olado.solve(problem, config=SQP_IP, guess=guess)
    assert r.status == Status.INFEASIBLE, r.message
    assert "locally infeasible" in r.message and "final_constraints" in r.message
    assert r.max_constraint_violation > 1.0


class _Merit:
    def __init__(self, violation):
        self.violation = violation

    def max_violation(self, pt):
        return self.violation

    def worst(self, pt):
        return f"final constraint 0 (violation {self.violation:g})", self.violation

    def penalty(self, pt, weights):
        return self.violation


class _State(SimpleNamespace):
    def stop(self, status, message):
        self.status, self.message = status, message
        return True


@pytest.mark.parametrize("violation, status", [(1e-10, Status.NUMERICAL_ERROR), (0.5, Status.INFEASIBLE)])
def test_the_infeasible_verdict_needs_a_positive_violation(violation, status):
    """A stationary l1 violation at a point that satisfies the constraints to constr_viol_tol
    (1e-8 in sqp-ip) is a degeneracy of the constraints there, not a proof of infeasibility."""
    setup = SimpleNamespace(merit=_Merit(violation), options=SimpleNamespace(constr_viol_tol=1e-8),
                            problem=SimpleNamespace(N=1, n=1, r=0, rN=1, m=1))
    st = _State(pt=None, it=7)
    assert restoration.infeasible(setup, st, "the l1 constraint violation is stationary") is True
    assert st.status == status
    assert ("locally infeasible" in st.message) == (status == Status.INFEASIBLE)


@pytest.mark.slow
def test_hang_glider_resumes_after_restoration_with_reset_multipliers():
    """hang-glider's QP multipliers grow to 5e13 in its first nine iterations; the restoration
    phase used to hand them (and a Hessian shift of 8e13) back to the optimality phase, which then
    stopped on step_tol at -1232.65 (UNCERTIFIED). With IPOPT's reset after restoration
    (olado.solvers.sqp.restoration.reset_multipliers) it reaches IPOPT's objective -- with
    local_tol = 0.1, set when the proximal term's linear tail needed more than 200 iterations at
    the default 1e-2 (now the crawl test of the local phase ends it: test_proximal_crawl.py).
    multiplier_reset off: with
    it the multipliers never grow and the restoration phase is not entered. max_iter 300: since
    the bounds of fixed states are dropped (olado.solvers.sqp.step.drop_fixed_bounds; here the
    bounds of the parameter stage's copies of x(0) = 0 and vx(0), and of the final vx row) this
    path took 211 iterations (170 before; the default configuration keeps its 102); on
    ContinuousOCP's exact Hessians (the hand-written problem's were finite differences of its
    Jacobians, 2.5e-10 off) it takes 143, 18 of them in restoration as before, to the same
    objective. ~50-150 s."""
    entry, problem, guess = _entry("hang-glider")
    ref = load_references()["entries"][entry.name]
    assert ref["status"] == "success"
    r = olado.solve(problem, config=SQP_IP, guess=guess, local_tol=0.1, multiplier_reset=False, max_iter=300)
    modes = [h["mode"] for h in r.history]
    assert "restoration" in modes
    assert r.success, r.message
    assert r.objective == pytest.approx(ref["objective"], rel=1e-6)
    assert r.max_constraint_violation < 1e-8


@pytest.mark.slow
def test_cart_pole_reaches_ipopts_objective():
    """cart-pole's QP multipliers grew 1.3e3 -> 1.4e7 in five full steps, the line search then
    failed and the restoration phase crawled to max_time. With ``multiplier_reset`` (the
    least-squares estimate replaces QP multipliers above multiplier_init_max) it converges without
    restoration. ~20 s."""
    entry, problem, guess = _entry("cart-pole")
    ref = load_references()["entries"][entry.name]
    assert ref["status"] == "success"
    r = olado.solve(problem, config=SQP_IP, guess=guess)
    assert r.success, r.message
    assert "restoration" not in [h["mode"] for h in r.history]
    assert r.objective == pytest.approx(ref["objective"], rel=1e-6)
    assert r.max_constraint_violation < 1e-8


def test_a_feasibility_qp_leaves_the_iterate_gradient_alone(monkeypatch):
    """The feasibility QPs (the gradient removed) must not zero the iterate's own cost gradient:
    the relaxed QP that follows at the same point reads it. lq-unreachable takes the relaxed phase
    at every iteration; every zero-gradient QP is checked against a copy of pt.lu taken before."""
    from olado.problems import get_problems
    from olado.solvers.sqp import step as qp_step

    calls = []
    solve_qp = qp_step.solve_qp

    def checked(setup, st, pt, *args, zero_gradient=False, **kw):
        before = (pt.lu.copy(), pt.lx.copy())
        out = solve_qp(setup, st, pt, *args, zero_gradient=zero_gradient, **kw)
        if zero_gradient:
            calls.append(np.array_equal(pt.lu, before[0]) and np.array_equal(pt.lx, before[1]))
        return out

    monkeypatch.setattr(qp_step, "solve_qp", checked)
    problem = get_problems()["lq-unreachable"]()
    r = olado.solve(problem, config=SQP_IP)
    assert r.status is Status.INFEASIBLE
    assert calls and all(calls), calls
