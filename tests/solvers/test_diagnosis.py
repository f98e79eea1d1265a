"""The infeasibility diagnosis (olado.solvers.diagnosis, docs/errors.md "Infeasibility diagnosis"):
its figures at a hand-computed point, the least-infeasible points of the solvers on problems whose
least violation is known by hand or by a linear program, the deliberately infeasible problems of
the robustness set, the result file and the command line."""

import json

import numpy as np
import pytest
import scipy.optimize
import scipy.sparse

import olado
from olado.cli import main
from olado.errors import ResultFileError
from olado.problems import DOCP, PROBLEMS
from olado.result import Infeasibility, Result, Status, ViolatedArray, Violation
from olado.solvers.diagnosis import diagnose

from fixtures import CONFIGS
from fixtures.safeguard_problems import Annulus, DegenerateFinalConstraint, fail_first_line_search

pytest.importorskip("cyipopt")


def _solve(problem, config, **options):
    return olado.solve(problem, config=CONFIGS / f"{config}.ini", **options)


def _array(diag, name):
    """The ViolatedArray ``name`` of a diagnosis (None when the array is not violated)."""
    return next((a for a in diag.arrays if a.array == name), None)


# ---------------------------------------------------------------------------- hand-built problems
class Additive(DOCP):
    """x+ = x + u, x0 = 0, the stage constraint 2 - x - u >= 0, the final constraint x_N = 5,
    x <= 3, -1 <= u <= 1.5 (vectorized: any N quickly)."""

    vectorized = True

    def __init__(self, N=4):
        super().__init__(1, 1, N, [0.0], x_bounds=(-np.inf, 3.0), u_bounds=(-1.0, 1.5), n_stage_constraints=1,
                         n_final_constraints=1, final_equalities=[0])

    def dynamics(self, k, x, u):
        return x + u

    def stage_cost(self, k, x, u):
        return 0.5 * u[:, 0] ** 2

    def final_cost(self, x):
        return 0.0

    def stage_constraints(self, k, x, u):
        return 2.0 - x - u

    def final_constraints(self, x):
        return x - 5.0


def test_diagnosis_at_a_hand_computed_point():
    p = Additive()
    U = np.array([[1.5], [1.5], [2.0], [-1.25]])
    X = np.array([[0.0], [1.5], [3.0], [5.0], [3.45]])        # x^4 = 3.75 by the dynamics: 0.3 off
    d = diagnose(p, X, U)
    # by hand: g^k = 2 - x^k - u^k = 0.5, -1, -3, -1.75; x^N - 5 = -1.55; x^3, x^4 above 3 by 2, 0.45;
    # u^2 above 1.5 by 0.5, u^3 below -1 by 0.25; the dynamics of stage 3 off by 0.3
    expected = [("stage_constraints", 2, 3.0, "inequality"), ("x_bounds", 3, 2.0, "upper bound"),
                ("stage_constraints", 3, 1.75, "inequality"), ("final_constraints", None, 1.55, "equality"),
                ("stage_constraints", 1, 1.0, "inequality"), ("u_bounds", 2, 0.5, "upper bound"),
                ("x_bounds", 4, 0.45, "upper bound"), ("dynamics", 3, 0.3, "equality"),
                ("u_bounds", 3, 0.25, "lower bound")]
    got = [(v.array, v.stage, v.value, v.kind) for v in d.violations]
    assert [g[:2] + g[3:] for g in got] == [e[:2] + e[3:] for e in expected]
    assert [g[2] for g in got] == pytest.approx([e[2] for e in expected], abs=1e-12)
    assert all(v.component == 0 for v in d.violations)
    assert d.count == 9 and d.largest == pytest.approx(3.0) and d.total == pytest.approx(10.8)
    summary = {a.array: (a.count, a.size, a.largest, a.total, a.first_stage, a.last_stage) for a in d.arrays}
    assert [a.array for a in d.arrays] == ["stage_constraints", "x_bounds", "final_constraints", "u_bounds",
                                           "dynamics"]
    assert summary["stage_constraints"] == pytest.approx((3, 4, 3.0, 5.75, 1, 3))
    assert summary["x_bounds"] == pytest.approx((2, 5, 2.0, 2.45, 3, 4))
    assert summary["u_bounds"] == pytest.approx((2, 4, 0.5, 0.75, 2, 3))
    assert summary["dynamics"] == pytest.approx((1, 4, 0.3, 0.3, 3, 3))
    assert summary["final_constraints"][:4] == pytest.approx((1, 1, 1.55, 1.55))
    assert summary["final_constraints"][4:] == (None, None)
    # a tolerance above 0.3 leaves out the dynamics and u^3 (the sums keep every violation)
    loose = diagnose(p, X, U, tolerance=0.4)
    assert loose.count == 7 and _array(loose, "dynamics") is None and loose.total == pytest.approx(10.8)
    assert loose.tolerance == 0.4 and loose.violations[-1].value == pytest.approx(0.45)


def test_a_moved_initial_state_and_a_non_finite_residual_are_named():
    p = Additive()
    U = np.zeros((4, 1))
    X = p.simulate(U)
    X[0, 0] = 0.125                                 # x^0 = x0 is a constraint of the NLP
    d = diagnose(p, X, U)
    assert d.violations[0] == Violation("final_constraints", None, 0, 5.0, "equality")
    x0 = next(v for v in d.violations if v.array == "x0")
    assert (x0.stage, x0.component, x0.kind) == (None, 0, "equality") and x0.value == pytest.approx(0.125)
    assert _array(d, "dynamics").first_stage == 0   # x^1 = x^0 + u^0 no longer holds either
    X[2, 0] = np.nan                                # the problem cannot be evaluated there
    assert "cannot be evaluated" in diagnose(p, X, U).note


def test_a_long_horizon_is_summarized_in_a_few_lines():
    N = 100_000
    p = Additive(N)
    U = np.full((N, 1), 1.5)                        # every u at its bound, x^k = 1.5 k
    X = p.simulate(U)
    d = diagnose(p, X, U)
    # by hand: g^k = 2 - 1.5 k - 1.5 < 0 for k >= 1 (largest at k = N - 1); x^k > 3 for k >= 3
    over = _array(d, "stage_constraints")
    assert (over.count, over.first_stage, over.last_stage) == (N - 1, 1, N - 1)
    assert over.total == pytest.approx(sum(1.5 * k + 1.5 - 2.0 for k in range(1, N)))
    assert _array(d, "x_bounds").count == N - 2 and _array(d, "x_bounds").first_stage == 3
    assert len(d.violations) == Infeasibility.SHOWN
    assert d.violations[0] == Violation("stage_constraints", N - 1, 0, pytest.approx(1.5 * N - 2.0), "inequality")
    r = Result(status=Status.INFEASIBLE, message="m", objective=0.0, x=X, u=U, N=N, infeasibility=d)
    lines = r.summary().splitlines()
    assert len(lines) < 20 and f"({Infeasibility.LISTED} of {d.count} shown)" in r.summary()


class Tripling(DOCP):
    """x+ = 3 x + u, x0 = 0, |u| <= 1, N = 3, x^1 <= 1/4 (a bound at stage 1 only), x^3 >= 15.

    Infeasible: x^3 = 9 x^1 + 3 u^1 + u^2 <= 9/4 + 4 < 15. The least l1 violation by hand:

    * the dynamics held (as the SQP's relaxed QP holds them): raising x^1 = u^0 above its bound by
      t costs t and gains 9 t on x^3, so u = (1, 1, 1): x^1 = 1 (the bound violated by 3/4) and
      x^3 = 13 (the final constraint by 2);
    * the bounds held (IPOPT keeps every variable within its bounds, also in its restoration
      phase) and the dynamics relaxed: a violation delta of the dynamics row of stage 1 (x^2)
      gains 3 delta on x^3, of stage 2 or of the final constraint delta (stage 0 cannot help,
      x^1 is at its bound), so x^1 = 1/4, u^1 = u^2 = 1 and delta = (15 - 9/4 - 4) / 3 = 35/12."""

    def __init__(self):
        upper = np.full((4, 1), np.inf)
        upper[1] = 0.25
        super().__init__(1, 1, 3, [0.0], x_bounds=(-np.inf, upper), u_bounds=(-1.0, 1.0), n_final_constraints=1)

    def dynamics(self, k, x, u):
        return 3.0 * x + u

    def dynamics_jacobian(self, k, x, u):
        return np.array([[3.0]]), np.array([[1.0]])

    def stage_cost(self, k, x, u):
        return 0.0

    def final_cost(self, x):
        return 0.0

    def final_constraints(self, x):
        return x - 15.0

    def final_constraints_jacobian(self, x):
        return np.eye(1)


@pytest.mark.parametrize("config, expected", [
    ("sqp-ip", {("x_bounds", 1): (0.75, "upper bound"), ("final_constraints", None): (2.0, "inequality")}),
    ("ipopt", {("dynamics", 1): (35 / 12, "equality")}),
])
def test_solvers_end_at_the_hand_computed_least_infeasible_point(config, expected):
    r = _solve(Tripling(), config)
    assert r.status is Status.INFEASIBLE, r.message
    got = {(v.array, v.stage): (v.value, v.kind) for v in r.infeasibility.violations}
    assert got.keys() == expected.keys()
    for key, (value, kind) in expected.items():
        assert got[key][0] == pytest.approx(value, abs=1e-6) and got[key][1] == kind, key
    assert r.infeasibility.total == pytest.approx(sum(v for v, _ in expected.values()), abs=1e-6)


def test_the_annulus_is_violated_by_three_at_every_constrained_stage():
    """x1^2 + x2^2 >= 4 and <= 1 (stages 1..4): max(0, 4 - s) + max(0, s - 1) >= 3 for every
    radius^2 s, = 3 for s in [1, 4]."""
    r = _solve(Annulus(), "sqp-ip")
    assert r.status is Status.INFEASIBLE
    d = r.infeasibility
    assert [a.array for a in d.arrays] == ["stage_constraints"]
    over = d.arrays[0]
    assert (over.first_stage, over.last_stage) == (1, 4) and over.total == pytest.approx(12.0, rel=1e-9)


def test_the_restoration_phase_returns_its_last_point_not_its_start(monkeypatch):
    """Started at the first iterate of lq-unreachable, the restoration steps reduce the l1
    violation to its least value (the linear program with the dynamics held, as the feasibility
    QP holds them), and the result carries that point."""
    failed = fail_first_line_search(monkeypatch)
    p = PROBLEMS["lq-unreachable"]()
    r = _solve(p, "sqp-ip")
    assert failed and r.status is Status.INFEASIBLE, r.message
    modes = [h["mode"] for h in r.history]
    assert modes and set(modes) == {"restoration"}
    least = least_l1_violation(p, exact_dynamics=True)
    assert r.infeasibility.total == pytest.approx(least, rel=1e-8)
    assert r.infeasibility.total == pytest.approx(r.history[-1]["merit"], rel=1e-12)   # theta at the last step
    assert r.history[0]["merit"] > 2 * least                      # the phase started far from it
    assert [a.array for a in r.infeasibility.arrays] == ["final_constraints"]


def test_a_degenerate_final_constraint_ends_at_its_least_violation():
    """(x_N - 1)^2 + 1 = 0: the violation is at least 1, exactly 1 at x_N = 1 only."""
    r = _solve(DegenerateFinalConstraint(), "sqp-ip")
    assert r.status is Status.INFEASIBLE, r.message
    assert r.infeasibility.total == pytest.approx(1.0, abs=1e-9)
    assert r.infeasibility.largest == pytest.approx(r.history[-1]["violation"], rel=1e-12)
    assert r.infeasibility.violations == [Violation("final_constraints", None, 0, pytest.approx(1.0, abs=1e-9),
                                                    "equality")]
    assert abs(r.x[-1, 0] - 1.0) < 1e-3


# ---------------------------------------------------------------------------- the robustness set
def _affine(p):
    """(A, B, c, CN, d) of a problem with an affine step x+ = A x + B u + c (the same at every
    stage) and affine final constraints CN x + d."""
    A, B = (a[0] for a in p.eval_dynamics_jacobians(np.zeros((p.N + 1, p.n)), np.zeros((p.N, p.m))))
    c = p.eval_dynamics(np.zeros((p.N + 1, p.n)), np.zeros((p.N, p.m)))[0]
    return A, B, c, p.eval_final_constraint_jacobian(np.zeros(p.n)), p.eval_final_constraints(np.zeros(p.n))


def least_l1_violation(p, exact_dynamics):
    """min sum |h| + sum |g^N| over the trajectories with the controls in their bounds, h the
    dynamics residual (0 when ``exact_dynamics``), for a problem with affine dynamics and equality
    final constraints and no other constraints: a linear program."""
    A, B, c, CN, d = _affine(p)
    N, n, m, rN = p.N, p.n, p.m, p.rN
    nx, nu, ns = N * n, N * m, N * n
    nv = nx + nu + 2 * ns + 2 * rN          # x^1..x^N, u, h = s+ - s-, g^N = t+ - t-
    M = scipy.sparse.lil_matrix((nx + rN, nv))
    rhs = np.zeros(nx + rN)
    for k in range(N):
        rows = slice(k * n, (k + 1) * n)
        if k:
            M[rows, (k - 1) * n:k * n] = A
        else:
            rhs[rows] -= A @ p.x0
        M[rows, nx + k * m:nx + (k + 1) * m] = B
        M[rows, k * n:(k + 1) * n] = -np.eye(n)
        M[rows, nx + nu + k * n:nx + nu + (k + 1) * n] = -np.eye(n)
        M[rows, nx + nu + ns + k * n:nx + nu + ns + (k + 1) * n] = np.eye(n)
        rhs[rows] -= c
    M[nx:, (N - 1) * n:N * n] = CN
    M[nx:, nx + nu + 2 * ns:nx + nu + 2 * ns + rN] = -np.eye(rN)
    M[nx:, nx + nu + 2 * ns + rN:] = np.eye(rN)
    rhs[nx:] = -d
    cost = np.r_[np.zeros(nx + nu), np.ones(2 * ns + 2 * rN)]
    bounds = ([(None, None)] * nx + list(zip(p.u_lower.ravel(), p.u_upper.ravel()))
              + [(0, 0 if exact_dynamics else None)] * (2 * ns) + [(0, None)] * (2 * rN))
    res = scipy.optimize.linprog(cost, A_eq=M.tocsr(), b_eq=rhs, bounds=bounds, method="highs")
    assert res.status == 0, res.message
    return res.fun


@pytest.mark.parametrize("name", ["lq-unreachable", "cart-too-short"])
@pytest.mark.parametrize("config", ["sqp-ip", "ipopt"])
def test_linear_infeasible_problems_end_at_the_least_l1_violation(name, config):
    """The SQP holds the (linearized) dynamics and minimizes the violation of the other
    constraints; IPOPT's restoration phase relaxes the dynamics too: each point is the minimum
    of its l1 violation (a linear program here), and the diagnosis adds up to it."""
    p = PROBLEMS[name]()
    r = _solve(p, config)
    assert r.status is Status.INFEASIBLE, r.message
    exact = config.startswith("sqp")
    # (IPOPT's restoration point is the least within its tolerance only: its proximity term)
    assert r.infeasibility.total == pytest.approx(least_l1_violation(p, exact), rel=1e-8 if exact else 1e-5)
    arrays = {a.array for a in r.infeasibility.arrays}
    assert arrays == {"final_constraints"} if exact else arrays <= {"dynamics", "final_constraints"}
    assert least_l1_violation(p, False) <= least_l1_violation(p, True) + 1e-9


@pytest.mark.parametrize("config", ["sqp-ip", "ipopt"])
def test_contradicting_path_constraints_are_named_at_every_stage(config):
    """x1 >= 0.2 and x1 <= 0.1 at every stage: the two violations add up to at least 0.1 per stage,
    and x1(0) = 0 violates the first by 0.2: the least l1 violation is 0.2 + 0.1 (N - 1)."""
    p = PROBLEMS["vanderpol-contradict"]()
    r = _solve(p, config)
    assert r.status is Status.INFEASIBLE, r.message
    d = r.infeasibility
    assert [a.array for a in d.arrays] == ["stage_constraints"]
    assert (d.arrays[0].first_stage, d.arrays[0].last_stage) == (0, p.N - 1)
    assert d.arrays[0].count >= p.N
    assert d.total == pytest.approx(0.2 + 0.1 * (p.N - 1), abs=1e-6)
    assert d.violations[0] == Violation("stage_constraints", 0, 0, pytest.approx(0.2, abs=1e-9), "inequality")


def test_catalyst_overfull_misses_its_final_constraint_by_the_invariants_margin():
    """x1 + x2 <= 1 along every trajectory (the problem's docstring), = 1 at the start: with the
    dynamics held, x1(1) + x2(1) >= 1.05 is violated by 0.05 at least, and the SQP's point attains it."""
    r = _solve(PROBLEMS["catalyst-overfull"](), "sqp-ip")
    assert r.status is Status.INFEASIBLE, r.message
    assert r.infeasibility.violations == [Violation("final_constraints", None, 0, pytest.approx(0.05, abs=1e-9),
                                                    "inequality")]
    r = _solve(PROBLEMS["catalyst-overfull"](), "ipopt")     # spreads 0.05 over the dynamics of x1, x2
    assert r.status is Status.INFEASIBLE, r.message
    assert {a.array for a in r.infeasibility.arrays} <= {"dynamics", "final_constraints"}
    assert r.infeasibility.total == pytest.approx(0.05, rel=1e-2)


def test_steering_too_short_is_named_by_its_final_x3_and_the_x3_dynamics():
    """x3^N = sum_k (h a cos u^k - h_k) <= 40 - sum_k h_k (RK4 is exact for x3, h_k the residual of
    the x3 row): the final constraint x3^N = 45 and the x3 rows violate by 5 together at least."""
    p = PROBLEMS["steering-too-short"]()
    r = _solve(p, "ipopt")
    assert r.status is Status.INFEASIBLE, r.message
    X, U = r.x, r.u
    h3 = p.eval_dynamics(X, U)[:, 2] - X[1:, 2]
    assert abs(X[-1, 2] - 45.0) + np.sum(np.abs(h3)) >= 5.0 - 1e-9
    d = r.infeasibility
    assert {a.array for a in d.arrays} <= {"dynamics", "final_constraints"}
    assert _array(d, "dynamics").total + _array(d, "final_constraints").total >= 5.0 - 1e-9
    final = [v for v in d.violations if v.array == "final_constraints" and v.component == 1]
    assert final and final[0].value == pytest.approx(abs(X[-1, 2] - 45.0), rel=1e-12)


def test_chain_too_short_lacks_exactly_the_chords_excess_length():
    """Every chain from (0, 1) to (1, 3) is at least sqrt 5 long; with length 2 the SQP's point
    keeps the end points and violates the length's dynamics by sqrt 5 - 2 in all."""
    r = _solve(PROBLEMS["chain-too-short"](), "sqp-ip")
    assert r.status is Status.INFEASIBLE, r.message
    d = r.infeasibility
    assert [a.array for a in d.arrays] == ["dynamics"]
    assert {v.component for v in d.violations} == {1}
    assert d.total == pytest.approx(np.sqrt(5.0) - 2.0, rel=1e-6)


def test_the_penalty_method_ends_at_the_least_squares_violation():
    """The quadratic penalty's points approach the least sum of squared violations (here of the
    final constraints, the dynamics held by simulation): a bounded linear least-squares problem."""
    p = PROBLEMS["cart-too-short"]()
    r = _solve(p, "penalty")
    assert r.status is Status.INFEASIBLE, r.message
    A, B, c, CN, d = _affine(p)
    N, m = p.N, p.m
    M = np.hstack([CN @ np.linalg.matrix_power(A, N - 1 - k) @ B for k in range(N)])
    free = CN @ (np.linalg.matrix_power(A, N) @ p.x0 + sum(np.linalg.matrix_power(A, j) @ c for j in range(N))) + d
    best = scipy.optimize.lsq_linear(M, -free, bounds=(p.u_lower.ravel(), p.u_upper.ravel()), tol=1e-12)
    gN = p.eval_final_constraints(r.x[-1])
    assert float(gN @ gN) == pytest.approx(2 * best.cost, rel=1e-3)
    assert {a.array for a in r.infeasibility.arrays} == {"final_constraints"}
    assert r.infeasibility.total == pytest.approx(float(np.sum(np.abs(gN))), rel=1e-12)


def test_only_infeasible_results_are_diagnosed():
    assert _solve(PROBLEMS["lq-box"](), "sqp-ip").infeasibility is None
    r = _solve(PROBLEMS["vanderpol-contradict"](), "sqp-ip", max_iter=1)
    assert r.status is Status.MAX_ITERATIONS and r.infeasibility is None
    d = diagnose(PROBLEMS["vanderpol-contradict"](), r.x, r.u)      # on request: any point
    assert _array(d, "stage_constraints").first_stage == 0 and d.largest >= 0.2 - 1e-12    # x1(0) = 0 < 0.2


# ---------------------------------------------------------------------------- result file, command line
def _infeasible_result():
    return _solve(PROBLEMS["vanderpol-contradict"](), "sqp-ip")


def test_save_and_load_keep_the_diagnosis(tmp_path):
    r = _infeasible_result()
    back = Result.load(r.save(tmp_path / "r.json"))
    assert back.infeasibility == r.infeasibility
    assert all(isinstance(v, Violation) for v in back.infeasibility.violations)
    assert all(isinstance(a, ViolatedArray) for a in back.infeasibility.arrays)
    assert back.summary() == r.summary()


def test_a_corrupted_diagnosis_is_a_result_file_error_naming_the_field(tmp_path):
    """(the catalogue of bad diagnosis fields: tests/bad_inputs/test_bad_results.py)"""
    path = _infeasible_result().save(tmp_path / "r.json")
    doc = json.loads(path.read_text())
    doc["infeasibility"]["violations"][2]["stage"] = "one"
    path.write_text(json.dumps(doc))
    with pytest.raises(ResultFileError) as info:
        Result.load(path)
    assert info.value.field == "infeasibility.violations[2].stage" and "non-negative integer" in str(info.value)


def test_the_command_line_prints_the_diagnosis_and_exits_1(capsys, tmp_path):
    save = tmp_path / "r.json"
    code = main(["solve", "vanderpol-contradict", "--config", str(CONFIGS / "sqp-ip.ini"), "--save", str(save)])
    out = capsys.readouterr().out
    assert code == 1                                # docs/errors.md: the solver ran and did not converge
    assert "status       : infeasible" in out
    assert "infeasible at: 51 constraint components violated beyond 1e-08" in out
    assert "stage_constraints: 51 of 100 components violated at stages 0..49, largest 0.2, sum 5.1" in out
    assert "stage_constraints[stage 0, component 0]: 0.2 (inequality)" in out
    assert Result.load(save).infeasibility.count == 51
