"""olado's certificate of a success (olado.solvers.certificate, docs/certificate.md): the figures
against hand-computed KKT residuals and a dense least-squares reference, bad multipliers rescued
by the least-squares multipliers, a wrong derivative caught by the spot check, and the SQP's
former false success at iteration 0 (against IPOPT)."""

import json

import numpy as np
import pytest

import olado
from fixtures.toy_problems import Pendulum, PendulumFD, RestToRestCart
from olado.problems import DOCP, get_problems
from olado.problems.zambezi import zambezi_problem
from olado.errors import ResultFileError
from olado.result import Certificate, Result, Status
from olado.solvers.certificate import (CertificateSettings, StageBounds, StagePoint, certify, kkt_figures,
                                       least_squares_multipliers)

CONFIGS = "configs"


class Scalar(DOCP):
    """x^{k+1} = x^k + u^k, f0 = (x^2 + u^2)/2, F = x^2/2, x^0 = 1, u <= 0.5 (hand computations)."""

    def __init__(self, N=2):
        super().__init__(1, 1, N, [1.0], u_bounds=(-10.0, 0.5))

    def dynamics(self, k, x, u):
        return np.array([x[0] + u[0]])

    def stage_cost(self, k, x, u):
        return 0.5 * (x[0] ** 2 + u[0] ** 2)

    def final_cost(self, x):
        return 0.5 * x[0] ** 2

    def dynamics_jacobian(self, k, x, u):
        return np.eye(1), np.eye(1)

    def stage_cost_gradient(self, k, x, u):
        return np.array([x[0]]), np.array([u[0]])

    def final_cost_gradient(self, x):
        return np.array([x[0]])


def test_figures_match_hand_computed_kkt():
    p = Scalar()
    U = np.array([[0.2], [-0.1]])
    X = np.array([[1.0], [1.2], [1.101]])           # h^1 = 1.2 - 0.1 - 1.101 = -1e-3
    p1, p2 = -1.0, -1.05
    fig = kkt_figures(p, X, U, {"dynamics": np.array([[p1], [p2]])})
    J = 0.5 * (1 + 0.04) + 0.5 * (1.44 + 0.01) + 0.5 * 1.101 ** 2
    # grad J + Jc' lam with h^k = x^k + u^k - x^{k+1}
    r_x1, r_x2 = 1.2 - p1 + p2, 1.101 - p2
    r_u0, r_u1 = 0.2 + p1, -0.1 + p2                 # both < 0: the upper bound 0.5 can cancel them
    z0, z1 = -r_u0 / (1 + 0.3), -r_u1 / (1 + 0.6)    # z = |r| w / (w + slack), w = 1
    stat = [abs(r_x1), abs(r_x2), -r_u0 - z0, -r_u1 - z1]
    scaled = [abs(r_x1) * 1.2, abs(r_x2) * 1.101, -r_u0 - z0, -r_u1 - z1]
    assert fig.stationarity == pytest.approx(max(stat), rel=1e-12)
    assert fig.stationarity_scaled == pytest.approx(max(scaled) / J, rel=1e-12)
    assert fig.stationarity_at == "x^2[0]" and fig.residual_at == pytest.approx(r_x2, rel=1e-12)
    assert fig.complementarity == pytest.approx(max(z0 * 0.3, z1 * 0.6), rel=1e-12)
    assert fig.complementarity_scaled == pytest.approx(max(z0 * 0.3, z1 * 0.6) / J, rel=1e-12)
    cert = certify(p, X, U, {"dynamics": np.array([[p1], [p2]])})
    assert cert.violation == pytest.approx(1e-3, rel=1e-9)
    assert cert.solver_stationarity_scaled == pytest.approx(max(scaled) / J, rel=1e-12)
    assert cert.level == "failed" and "constraint violation 1.00e-03" in cert.reason and "dynamics[stage 1, component 0]" in cert.reason


def test_kkt_point_is_certified_with_hand_multipliers():
    """At the optimum of Scalar (no bound active) the costates make every residual vanish."""
    p = Scalar()
    # min (1 + x1^2 + u0^2 + u1^2 + x2^2)/2: stationarity gives u1 = -x2 = -(x1 + u1) -> u1 = -x1/2,
    # u0 = -(x1 + x2) with x2 = x1/2 -> u0 = -3 x1 / 2, x1 = 1 + u0 -> x1 = 2/5
    x1 = 0.4
    X = np.array([[1.0], [x1], [x1 / 2]])
    U = np.array([[-1.5 * x1], [-0.5 * x1]])
    lam = np.array([[-U[0, 0]], [-U[1, 0]]])          # u^k + lam_{k+1} = 0
    cert = certify(p, X, U, {"dynamics": lam})
    assert cert.level == "success" and cert.multipliers == "solver"
    assert cert.stationarity < 1e-15 and cert.violation < 1e-15


class NonlinearFinal(DOCP):
    """Equality constraints only (dynamics and one final equality): the least-squares multipliers
    have a closed form to compare with."""

    def __init__(self, N=6):
        super().__init__(2, 1, N, [0.5, -0.2], n_final_constraints=1, final_equalities=[0])

    def dynamics(self, k, x, u):
        return np.array([x[0] + 0.1 * np.sin(x[1]), x[1] + 0.1 * (u[0] - x[0] ** 2)])

    def stage_cost(self, k, x, u):
        return 0.5 * u[0] ** 2 + 0.3 * x[0] * x[1]

    def final_cost(self, x):
        return x[0] ** 2

    def final_constraints(self, x):
        return np.array([x[0] + x[1] ** 2 - 0.3])


def test_least_squares_multipliers_equal_dense_weighted_least_squares():
    """Without inequalities the projection QP's multipliers minimise |W (grad J + Jc' lam)| over
    the free variables: compare with numpy's lstsq on the flat NLP's sparse Jacobian."""
    p = NonlinearFinal()
    rng = np.random.default_rng(3)
    U = rng.standard_normal((p.N, 1))
    X = p.simulate(U)
    pt, bounds = StagePoint(p, X, U), StageBounds.of(p)
    W = (np.maximum(1.0, np.abs(X)), np.maximum(1.0, np.abs(U)))
    lam, Lg, LgN = least_squares_multipliers(p, pt, bounds, W)
    nlp = olado.problems.StructuredNLP(p)
    y = nlp.pack(X, U)
    g, Jc = nlp.gradient(y), nlp.jacobian_matrix(y).toarray()
    lb, ub = nlp.variable_bounds()
    free = lb < ub
    w = np.maximum(1.0, np.abs(y))[free]
    ref, *_ = np.linalg.lstsq(w[:, None] * Jc[:, free].T, -w * g[free], rcond=None)
    ours = np.concatenate([lam.ravel(), LgN])
    assert np.allclose(ours, ref, rtol=1e-7, atol=1e-9)
    cert = certify(p, X, U, None)
    r = g[free] + Jc[:, free].T @ ref
    assert cert.multipliers == "least-squares"
    assert cert.stationarity_scaled == pytest.approx(np.max(np.abs(r) * w) / max(1.0, abs(pt.J)), rel=1e-6)
    assert cert.level == "failed" and "scaled stationarity" in cert.reason


@pytest.fixture(scope="module")
def pendulum_ipopt():
    pytest.importorskip("cyipopt")
    p = Pendulum(N=12)
    r = olado.solve(p, config=f"{CONFIGS}/ipopt.ini")
    assert r.status == Status.SUCCESS and r.certificate.level == "success"
    return p, r


def test_bad_multipliers_are_rescued_by_least_squares(pendulum_ipopt):
    """IPOPT's multipliers with flipped signs (inequality multipliers of the wrong sign are
    projected away, the rest make the residual large): the certificate falls back on its
    sign-constrained least-squares multipliers, which reproduce IPOPT's."""
    p, r = pendulum_ipopt
    assert np.any(r.multipliers["stage_constraints"] < -1e-3)       # an active stage constraint
    bad = {k: -v for k, v in r.multipliers.items()}
    cert = certify(p, r.x, r.u, bad)
    assert cert.level == "success" and cert.multipliers == "least-squares"
    assert cert.solver_stationarity_scaled > 1e-2
    pt, bounds = StagePoint(p, r.x, r.u), StageBounds.of(p)
    lam, Lg, LgN = least_squares_multipliers(p, pt, bounds, (np.maximum(1, np.abs(r.x)), np.maximum(1, np.abs(r.u))))
    assert np.allclose(lam, r.multipliers["dynamics"], atol=1e-6)
    assert np.allclose(Lg, r.multipliers["stage_constraints"], atol=1e-6)
    assert np.allclose(LgN, r.multipliers["final_constraints"], atol=1e-6)
    none = certify(p, r.x, r.u, None)
    assert none.level == "success" and none.multipliers == "least-squares"


class WrongGradient(Pendulum):
    """The pendulum with the control part of the stage-cost gradient off by ``factor`` at stage 3."""

    def __init__(self, N, factor=2.0):
        super().__init__(N=N)
        self.factor = factor

    def stage_cost_gradient(self, k, x, u):
        lx, lu = super().stage_cost_gradient(k, x, u)
        return lx, (self.factor * lu if k == 3 else lu)


def test_wrong_derivative_is_caught_by_the_spot_check(pendulum_ipopt):
    p, r = pendulum_ipopt
    wrong = WrongGradient(N=12)
    cert = certify(wrong, r.x, r.u, r.multipliers)
    assert cert.level == "failed"
    assert "stage_cost at stage 3" in cert.reason and "analytic" in cert.reason
    assert cert.gradient_check > 1e-3
    # the same point with the right derivatives, and with finite differences only, passes
    assert certify(p, r.x, r.u, r.multipliers).gradient_check < 1e-8
    assert certify(PendulumFD(N=12), r.x, r.u, r.multipliers).level == "success"


@pytest.mark.parametrize("config", ["sqp-ip", "ipopt"])
def test_solve_with_wrong_derivative_is_not_a_success(config):
    """A gradient 10 % off at one stage: the solvers converge on it (their own tests hold); the
    certificate says what is wrong instead of a success."""
    if config == "ipopt":
        pytest.importorskip("cyipopt")
    res = olado.solve(WrongGradient(N=12, factor=1.1), config=f"{CONFIGS}/{config}.ini")
    assert res.status == Status.UNCERTIFIED and not res.success
    assert "stage_cost at stage 3" in res.message
    assert res.certificate.level == "failed"


def test_false_success_at_iteration_zero_is_gone():
    """Issue 18: a problem with a final equality, written as a new user would, from the natural
    zero guess: sqp-ip.ini reported 'converged in 0 SQP iterations' at a point that is not
    stationary. Now it reaches IPOPT's objective, certified."""
    pytest.importorskip("cyipopt")
    p = RestToRestCart()
    zero = np.zeros((p.N, 1))
    assert certify(p, p.simulate(zero[:, :]), zero, None).level == "failed"   # the guess is no KKT point
    res = olado.solve(p, config=f"{CONFIGS}/sqp-ip.ini", guess=zero)
    ref = olado.solve(p, config=f"{CONFIGS}/ipopt.ini", guess=zero)
    assert ref.status == Status.SUCCESS
    assert res.status == Status.SUCCESS and res.iterations >= 1
    assert res.certificate.level == "success"
    assert res.objective == pytest.approx(ref.objective, rel=1e-6)
    assert ref.objective < -0.4                      # the zero guess has J = 0


def test_lq_sqp_iterates_on_to_the_riccati_solution():
    """sqp-ip stopped on lq at a stationarity residual of 8e-5 (its test is relative to the largest
    gradient seen); after the failed certificate it iterates on to the exact solution."""
    p = get_problems()["lq"]()
    res = olado.solve(p, config=f"{CONFIGS}/sqp-ip.ini")
    assert res.status == Status.SUCCESS and res.certificate.level == "success"
    assert res.objective == pytest.approx(13.0669348, rel=1e-8)
    assert res.certificate.stationarity < 1e-6


def test_stalled_sqp_ends_acceptable_at_the_right_point():
    """WORHP's low-pass filter termination: the Gerschgorin-convexified SQP converges linearly at
    rate ~0.95 on cstr and used to end at the iteration limit; it now stops once the objective and
    the violation have stalled, the certificate holding."""
    p = get_problems()["cstr"]()
    res = olado.solve(p, config=f"{CONFIGS}/sqp-gerschgorin.ini")
    assert res.status in (Status.ACCEPTABLE, Status.SUCCESS) and res.iterations < 200
    assert "stalled" in res.message and res.certificate.holds
    assert res.objective == pytest.approx(0.13326686733, rel=1e-8)


def test_certify_option_off_and_summary():
    p = get_problems()["lq"]()
    off = olado.solve(p, solver="sqp", certify=False)
    assert off.certificate is None
    on = olado.solve(p, solver="sqp")
    assert "certificate  : holds" in on.summary()


def test_certificate_round_trip_and_old_files(tmp_path):
    p = Scalar()
    res = olado.solve(p, solver="sqp")
    path = res.save(tmp_path / "r.json")
    back = Result.load(path)
    assert back.certificate == res.certificate
    doc = json.loads(path.read_text())
    del doc["certificate"]
    path.write_text(json.dumps(doc))
    assert Result.load(path).certificate is None
    doc["certificate"] = {"level": "bogus"}
    path.write_text(json.dumps(doc))
    with pytest.raises(ResultFileError, match="certificate.level"):
        Result.load(path)


def test_settings_follow_the_solver_tolerances():
    from olado.solvers.sqp.solver import SQPOptions

    s = CertificateSettings.from_options(SQPOptions(tol=1e-3, constr_viol_tol=1e-5))
    assert s.tol == 1e-3 and s.acceptable_tol == 1e-3 and s.constr_viol_tol == 1e-5
    assert s.acceptable_constr_viol_tol == 1e-5


@pytest.mark.parametrize("entry", ["rayleigh-mixed", "particle-steering"])
def test_least_squares_multipliers_from_the_point_alone(entry):
    """The independent certificate (no multipliers at all) of IPOPT's solution holds at level
    success. rayleigh-mixed has a path constraint at slack 1.3e-6 with IPOPT multiplier -3.2e-3:
    a hard activity threshold on the slack left it out (scaled stationarity 6.9e-5); the soft
    rows weighted by 1/g^2 take it. particle-steering's controls sit at their bounds (weights
    1e-12) next to three terminal equalities: the Riccati projection of the last stages broke
    down (a u-part of 1e-9 of its row used as a pivot) until the static pivots of
    olado.linalg.riccati; the sparse LU of the whole KKT matrix stays the certificate's fallback
    (tests/linalg/test_riccati_static_pivots.py solves these QPs on the Riccati back-end alone)."""
    pytest.importorskip("cyipopt")
    from olado.problems.suites import load_suite

    problem, guess = next(e for e in load_suite("robustness") if e.name == entry).build()
    r = olado.solve(problem, guess=guess, config=f"{CONFIGS}/ipopt.ini")
    assert r.status == Status.SUCCESS
    cert = certify(problem, r.x, r.u, None)
    assert cert.multipliers == "least-squares"
    assert cert.level == "success", cert.reason
    assert max(cert.stationarity_scaled, cert.complementarity_scaled) <= 1e-6
    # the least-squares multipliers of the soft rows keep the sign of g >= 0 rows
    lam, Lg, LgN = least_squares_multipliers(problem, StagePoint(problem, r.x, r.u), StageBounds.of(problem),
                                             (np.maximum(1.0, np.abs(r.x)), np.maximum(1.0, np.abs(r.u))))
    assert np.all(Lg[:, ~problem.stage_equality_mask] <= 0.0)


def test_soft_rows_pay_complementarity():
    """The least-squares multiplier of a stage row g >= 0 at slack s pays |mu s| in the least
    squares (module docstring, step 3), against the hand computation. One stage, x^1 = x^0 + u,
    f0 = (x^2 + u^2)/2, F = x^2/2, x^0 = 1, the row g = u - 1/2 >= 0 at u = 1/2 + s, x^1 = a,
    u = b. The Lagrangian gradient is (x^1 - lam, u + lam + mu); minimising
    w^2 (a - lam)^2 + v^2 (b + lam + mu)^2 + (s mu)^2 over lam (w = max(1, a), v = max(1, b))
    leaves c (a + b + mu)^2 + s^2 mu^2 with c = w^2 v^2 / (w^2 + v^2), so
    mu = -c (a + b) / (c + s^2) and lam = (w^2 a - v^2 (b + mu)) / (w^2 + v^2): the whole residual
    on the row at s = 1e-6, a share only at s = 1, almost nothing at s = 100."""

    class Row(Scalar):
        def __init__(self):
            DOCP.__init__(self, 1, 1, 1, [1.0], n_stage_constraints=1)

        def stage_constraints(self, k, x, u):
            return np.array([u[0] - 0.5])

        def stage_constraints_jacobian(self, k, x, u):
            return np.zeros((1, 1)), np.ones((1, 1))

    p = Row()
    for s in (1e-6, 1.0, 100.0):
        a, b = 1.5 + s, 0.5 + s
        X, U = np.array([[1.0], [a]]), np.array([[b]])
        W = (np.maximum(1.0, np.abs(X)), np.maximum(1.0, np.abs(U)))
        lam, Lg, LgN = least_squares_multipliers(p, StagePoint(p, X, U), StageBounds.of(p), W)
        w2, v2 = max(1.0, a) ** 2, max(1.0, b) ** 2
        c = w2 * v2 / (w2 + v2)
        mu = -c * (a + b) / (c + s ** 2)
        assert Lg[0, 0] == pytest.approx(mu, rel=1e-6, abs=1e-12)
        assert lam[0, 0] == pytest.approx((w2 * a - v2 * (b + mu)) / (w2 + v2), rel=1e-6)


@pytest.mark.parametrize("make", [lambda: zambezi_problem(N=24), lambda: RestToRestCart()],
                         ids=["zambezi12-vectorized", "cart-per-stage"])
def test_spot_check_stacked_evaluations_equal_point_by_point(make):
    """The spot check's stacked evaluation (every shifted point's stages in one call per stage
    function) gives the values, and advances the counters, as the point-by-point _values."""
    from olado.solvers import certificate as C
    p = make()
    X = p.simulate(p.initial_guess())
    U = p.initial_guess()
    pt = StagePoint(p, X, U)
    bounds = StageBounds.of(p)
    W = (np.maximum(1.0, np.abs(X)), np.maximum(1.0, np.abs(U)))
    rng = np.random.default_rng(C.CHECK_SEED)
    directions = [C._direction(rng, pt, bounds, W, C.CHECK_STEP) for _ in range(C.CHECK_DIRECTIONS)]
    p.reset_counters()
    stacked = C._shifted_values(p, pt, directions, C.CHECK_STEP)
    counted = p.counters.copy()
    p.reset_counters()
    for d, (Vx, Vu) in enumerate(directions):
        for i, s in enumerate(C._SHIFTS):
            ref = C._values(p, pt.X + s * C.CHECK_STEP * Vx, pt.U + s * C.CHECK_STEP * Vu)
            flat = np.concatenate([np.ravel(ref[name]) for name in C._NAMES])
            np.testing.assert_allclose(stacked[d, i], flat, rtol=1e-15, atol=0.0)
    assert counted == p.counters


def test_spot_check_names_the_stage_when_a_shifted_point_fails():
    """A stage function that fails near the point: the spot check is skipped with the message of
    the point-by-point evaluation (the stage it failed at, not a row of the stacked call)."""
    from olado.solvers import certificate as C

    class Fails(RestToRestCart):
        vectorized = False
        _at = None

        def dynamics(self, k, x, u):
            out = super().dynamics(k, x, u)
            bad = self._at is not None and k == 3 and np.max(np.abs(x - self._at[k])) > 1e-4  # not an FD step
            return out * np.nan if bad else out

    p = Fails()
    U = p.initial_guess()
    X = p.simulate(U)
    p._at = X
    pt = StagePoint(p, X, U)
    W = (np.maximum(1.0, np.abs(X)), np.maximum(1.0, np.abs(U)))
    check = C.spot_check(p, pt, StageBounds.of(p), W)
    assert check.note.startswith("spot check skipped") and "stage k=3" in check.note, check.note
