"""The SQP's safeguards from WORHP (seed 000; docs/structure-exploiting-sqp.md, "Safeguards"):
Hessian regularization after untrusted steps, the relaxed QP for inconsistent linearizations,
feasibility restoration and local infeasibility, non-finite evaluations at trial points,
UNBOUNDED, and the augmented-Lagrangian merit function. Reference solutions from IPOPT."""

from pathlib import Path

import numpy as np
import pytest

import olado
from olado.problems import PROBLEMS
from olado.result import Status
from olado.solvers.sqp import phases, regularization, restoration
from olado.solvers.sqp.line_search import Direction, line_search
from olado.solvers.sqp.solver import SQPOptions

from fixtures.safeguard_problems import (Annulus, DegenerateFinalConstraint, NarrowDomain, UnboundedBelow,
                                         fail_first_line_search)
from fixtures.toy_problems import Pendulum

pytest.importorskip("cyipopt")

CONFIGS = Path(__file__).resolve().parents[3] / "configs"
SQP_IP = CONFIGS / "sqp-ip.ini"
IPOPT = CONFIGS / "ipopt.ini"


def _ipopt(problem):
    return olado.solve(problem, config=IPOPT)


# ---------------------------------------------------------------------------- built-in problems
@pytest.mark.parametrize("name", ["vanderpol", "rayleigh", "vanderpol-path", "cstr"])
def test_sqp_ip_reaches_ipopts_objective_on_the_builtin_ode_problems(name):
    ref = _ipopt(PROBLEMS[name]())
    r = olado.solve(PROBLEMS[name](), config=SQP_IP)
    assert ref.success and r.success, r.message
    assert r.objective == pytest.approx(ref.objective, rel=1e-6)
    assert r.max_constraint_violation < 1e-8


def test_vanderpol_switches_on_the_hessian_regularization_which_then_decays():
    # from zero multipliers (the first Hessian the objective's only) its second QP step (2e4 long)
    # took the L1 merit from 12 to 3.5e76 as a relaxed step
    r = olado.solve(PROBLEMS["vanderpol"](), config=SQP_IP, initial_multipliers="zero")
    taus = [h["tau"] for h in r.history]
    assert max(taus) > 0.0                   # the untrusted step switched WORHP's tau on ...
    assert taus[-1] <= 1e-3 * max(taus)      # ... and it decayed as the model agreed again
    assert max(h["objective"] for h in r.history) < 100.0     # no runaway iterate accepted
    assert r.success


def test_vanderpol_path_starts_from_a_relaxed_qp():
    # the first linearization is inconsistent: x1 >= -0.4 cannot be reached with -0.3 <= u <= 1
    r = olado.solve(PROBLEMS["vanderpol-path"](), config=SQP_IP)
    assert np.isfinite(r.history[0]["eta"])          # the elastic QP was used at iteration 0 ...
    assert all(np.isnan(h["eta"]) for h in r.history[2:])   # ... and the QPs were consistent later
    assert r.success


@pytest.mark.parametrize("cfg", ["sqp-as", "sqp-gondzio", "sqp-sr1", "sqp-schittkowski", "sqp-schittkowski-as"])
def test_vanderpol_path_with_other_presets(cfg):
    """The relaxed QP with every QP method (its slacks have a little curvature, which the dual
    active-set method needs: a strictly convex QP)."""
    ref = _ipopt(PROBLEMS["vanderpol-path"]())
    r = olado.solve(PROBLEMS["vanderpol-path"](), config=CONFIGS / f"{cfg}.ini")
    assert r.success, r.message
    assert r.objective == pytest.approx(ref.objective, rel=1e-6)


# ---------------------------------------------------------------------------- regularization
def test_gerschgorin_bounds_and_tau_one_make_every_block_positive_definite():
    rng = np.random.default_rng(0)
    Bk = rng.standard_normal((5, 4, 4)); Bk = Bk + Bk.transpose(0, 2, 1)
    BN = np.array([[1.0, 3.0], [3.0, -2.0]])
    sigma = regularization.gerschgorin_bounds(Bk, BN)
    for H, s in zip(list(Bk) + [BN], sigma):
        d = np.diag(H)
        assert s == pytest.approx(np.min(d - (np.sum(np.abs(H), axis=1) - np.abs(d))))
        assert np.linalg.eigvalsh(H)[0] >= s - 1e-12                 # a lower bound of the spectrum
    delta = regularization.tau_shift(1.0, Bk, BN, hscale=1e-3)
    for H, d in zip(list(Bk) + [BN], delta):
        assert np.linalg.eigvalsh(H + d * np.eye(len(H)))[0] > 0.0
    assert not np.any(regularization.tau_shift(0.0, Bk, BN, 1.0))


def test_tau_update_follows_worhps_rule():
    o = SQPOptions()
    theta = o.tau_increase
    # predicted reduction -alpha D - alpha^2/2 s.H s = 1 - 0.5 = 0.5 for alpha = 1, D = -1, sHs = 1
    assert regularization.update_tau(1e-2, o, 0.1, 1.0, -1.0, 1.0, 0.5) == pytest.approx(theta * 1e-2)   # rho_1 <= 0.25 rho_2
    assert regularization.update_tau(1e-2, o, 0.45, 1.0, -1.0, 1.0, 0.5) == pytest.approx(1e-2 * 0.5 if 0.5 < 1 / theta else 1e-3)
    assert regularization.update_tau(1e-2, o, 0.45, 1.0, -1.0, 1.0, 1e-3) == pytest.approx(1e-5)     # min(1/theta, rho_3)
    assert regularization.update_tau(1e-2, o, 0.3, 1.0, -1.0, 1.0, 1e-3) == 1e-2                      # in between: kept
    assert regularization.update_tau(0.5, o, -1.0, 1.0, -1.0, 1.0, 1.0) == 1.0                        # capped at 1
    assert regularization.update_tau(1e-9, o, 0.45, 1.0, -1.0, 1.0, 1e-3) == 0.0                      # below tau_min: off


def test_an_untrusted_full_step_is_never_relaxed_and_stops_the_search_when_asked():
    p = Pendulum(N=4)
    pt = phases.Point(p, p.simulate(np.zeros((4, 1))), np.zeros((4, 1)))
    d = Direction(pt, np.ones_like(pt.X), np.ones_like(pt.U), 1.0, -1.0)
    o = SQPOptions()
    huge = lambda q, alpha=1.0: 1e80 if alpha == 1.0 else 0.5    # noqa: E731 - the full step explodes
    untrusted = lambda phi: regularization.untrusted(phi, 1.0, -1.0, o)   # noqa: E731
    found = line_search(o, p, d, huge, None, untrusted=untrusted, stop_untrusted=True)
    assert found.mode == "untrusted" and found.point is None
    found = line_search(o, p, d, huge, None, untrusted=untrusted)
    assert found.mode == "backtrack" and found.alpha == 0.5       # backtracked, not relaxed
    assert line_search(o, p, d, huge, None).mode == "relaxed"        # without the test: the old relaxed step


# ---------------------------------------------------------------------------- infeasibility
@pytest.mark.parametrize("problem, where, configs", [(Annulus, "stage_constraints[stage ", ("sqp-ip", "sqp-sr1")),
                                                     (DegenerateFinalConstraint, "final_constraints[component 0]",
                                                      ("sqp-ip",))])
def test_locally_infeasible_problems_end_infeasible_naming_the_largest_violation(problem, where, configs):
    # (DegenerateFinalConstraint with the quasi-Newton presets: their first iterates take the
    # states to ~1e10, where the restoration crawls in the rounding noise of the dynamics rows
    # and ends at max_iter; docs/structure-exploiting-sqp.md)
    assert _ipopt(problem()).status == Status.INFEASIBLE
    for cfg in configs:
        r = olado.solve(problem(), config=CONFIGS / f"{cfg}.ini")
        assert r.status == Status.INFEASIBLE, r.message
        assert "locally infeasible" in r.message and where in r.message


def test_restoration_returns_to_the_optimality_phase(monkeypatch):
    """A line search that fails once at an infeasible point starts the restoration phase; its
    steps reduce the l1 violation and the SQP then converges to IPOPT's solution."""
    failed = fail_first_line_search(monkeypatch)
    p = PROBLEMS["vanderpol-path"]()
    r = olado.solve(p, config=SQP_IP)
    modes = [h["mode"] for h in r.history]
    assert failed and "restoration" in modes
    first = modes.index("restoration")
    assert any(m != "restoration" for m in modes[first:])            # the optimality phase resumed
    assert r.success
    assert r.objective == pytest.approx(_ipopt(PROBLEMS["vanderpol-path"]()).objective, rel=1e-6)


# ---------------------------------------------------------------------------- non-finite values
@pytest.mark.parametrize("nan_in, cfg", [("values", "sqp-ip"), ("jacobian", "sqp-ip"), ("jacobian", "sqp-sr1"),
                                          ("hessian", "sqp-ip")])
def test_a_non_finite_evaluation_at_a_trial_point_rejects_the_step(nan_in, cfg):
    """dynamics NaN for |u| >= 0.5 ("values"; the optimum has |u| = 0.499), or finite values but a
    NaN Jacobian / Hessian for |u| > 0.4 (the optimum has |u| = 0.34): trial points there are
    rejected steps, and the SQP reaches IPOPT's solution."""
    kw = dict(target=2.0) if nan_in == "values" else dict(target=0.1, nan_above=0.4, nan_in=nan_in)
    ref = _ipopt(NarrowDomain(target=kw["target"]))   # the same optimum (IPOPT's result assembly cannot take the NaN derivatives)
    p = NarrowDomain(**kw)
    r = olado.solve(p, config=CONFIGS / f"{cfg}.ini")
    assert (p.nan_values if nan_in == "values" else p.nan_derivatives) > 0     # the safeguard was needed
    assert r.success, r.message
    assert r.objective == pytest.approx(ref.objective, rel=1e-6)


# ---------------------------------------------------------------------------- unbounded
@pytest.mark.parametrize("cfg", ["sqp-ip", "sqp-sr1", "sqp-clarabel"])
def test_an_unbounded_problem_ends_unbounded(cfg):
    assert _ipopt(UnboundedBelow()).status == Status.UNBOUNDED
    r = olado.solve(UnboundedBelow(), config=CONFIGS / f"{cfg}.ini")
    assert r.status == Status.UNBOUNDED, r.message
    assert "unbounded below" in r.message and r.iterations < 20
    assert r.objective < -1e4


def test_a_badly_scaled_convex_problem_is_not_called_unbounded():
    """lq-box at N = 200 (unstable dynamics: J ~ 1e19 at the start) is a convex QP bounded below;
    the QP model's minimum along the steps lies two iterate sizes away, so the steps are no
    directions of recession (olado.solvers.sqp.recession.REACH); it was UNBOUNDED at iteration 5."""
    from olado.problems.testproblems import PROBLEMS

    r = olado.solve(PROBLEMS["lq-box"](N=200), config=SQP_IP, max_iter=30)
    assert r.status is not Status.UNBOUNDED, r.message
    assert r.iterations == 30


def test_a_bounded_problem_is_not_called_unbounded():
    r = olado.solve(UnboundedBelow(u_bounds=(-1.0, 100.0)), config=SQP_IP)
    assert r.success and r.u[-1, 0] == pytest.approx(100.0, abs=1e-6)


# ---------------------------------------------------------------------------- augmented Lagrangian merit
def test_augmented_lagrangian_directional_derivative_matches_finite_differences():
    from olado.solvers.sqp.augmented import AugmentedLagrangian
    from olado.solvers.sqp.state import BoundMultipliers, ConstraintMasks, Multipliers

    p = Pendulum(N=5)
    rng = np.random.default_rng(1)
    U = 0.3 * rng.standard_normal((5, 1))
    X = p.simulate(U) + 0.05 * rng.standard_normal((6, 2))       # infeasible: the dynamics terms count
    X[0] = p.x0
    pt = phases.Point(p, X, U)
    merit = AugmentedLagrangian(p, ConstraintMasks.of(p))
    w = merit.initial_weights()
    w = w._replace(r_e=rng.uniform(0.5, 2, w.r_e.shape), r_c=rng.uniform(0.5, 2, w.r_c.shape),
                   lam=rng.standard_normal(w.lam.shape), y=rng.uniform(0, 1, w.y.shape))

    class Step:
        dX = 0.1 * rng.standard_normal(X.shape)
        dU = 0.1 * rng.standard_normal(U.shape)
        mult_new = Multipliers(rng.standard_normal((6, 2)), rng.standard_normal((5, 1)), rng.standard_normal(1))
        bounds = BoundMultipliers(*(rng.uniform(0, 1, a.shape) for a in BoundMultipliers.zeros(5, 2, 1)))
        slacks = None

    Step.dX[0] = 0.0
    psi = merit.along(w, Step)
    h = 1e-6
    fd = (psi(phases.Point(p, X + h * Step.dX, U + h * Step.dU), h)
          - psi(phases.Point(p, X - h * Step.dX, U - h * Step.dU), -h)) / (2 * h)
    assert merit.derivative(pt, Step, w) == pytest.approx(fd, rel=1e-6, abs=1e-8)
    assert psi(pt, 0.0) == pytest.approx(merit.value(pt, w))


def test_the_relaxed_qp_penalty_of_the_augmented_lagrangian_is_its_largest_multiplier_estimate():
    """An elastic penalty stands for a multiplier: the floor of eta is the largest |v|, not the
    penalties r (which weigh squared violations and grow with (u - v)^2)."""
    from olado.solvers.sqp.augmented import AugmentedLagrangian
    from olado.solvers.sqp.merit import Merit
    from olado.solvers.sqp.state import ConstraintMasks

    p = Pendulum(N=5)
    al = AugmentedLagrangian(p, ConstraintMasks.of(p))
    w = al.initial_weights()
    lam = np.zeros_like(w.lam); lam[3] = -3.0; lam[7] = 1.0
    y = np.zeros_like(w.y); y[0] = 2.5
    w = w._replace(r_e=np.full_like(w.r_e, 1e12), r_c=np.full_like(w.r_c, 1e12), lam=lam, y=y)
    assert al.elastic_floor(w) == 3.0 and al.largest_weight(w) == 1e12
    l1 = Merit(p, ConstraintMasks.of(p))
    rho = tuple(np.full_like(a, 0.5) for a in l1.initial_weights()); rho[1][2, 0] = 7.0
    assert l1.elastic_floor(rho) == 7.0 == l1.largest_weight(rho)


@pytest.mark.slow
def test_schittkowskis_sqp_on_an_infeasible_problem_keeps_the_elastic_penalty_bounded():
    """vanderpol-contradict (contradicting path constraints): with r as the floor of eta, eta grew
    like eta^2 from one relaxed QP to the next (15, 1.6e4, 4.9e8, 6.4e20; the active-set QP then
    ran 20 000 working-set changes on one QP); with the multiplier estimates it stays at the
    L1 merit's level and the SQP ends INFEASIBLE at sqp-ip's least-infeasible point."""
    ip = olado.solve(PROBLEMS["vanderpol-contradict"](), config=SQP_IP)
    r = olado.solve(PROBLEMS["vanderpol-contradict"](), config=CONFIGS / "sqp-schittkowski.ini")
    assert ip.status == r.status == Status.INFEASIBLE, r.message
    etas = [h["eta"] for h in r.history if np.isfinite(h["eta"])]
    assert etas and max(etas) <= 10.0 * max(h["eta"] for h in ip.history if np.isfinite(h["eta"]))
    assert r.objective == pytest.approx(ip.objective, rel=1e-6)


@pytest.mark.parametrize("cfg, qp", [("sqp-schittkowski", "mehrotra"), ("sqp-schittkowski-as", "active-set")])
@pytest.mark.parametrize("name", ["vanderpol", "rayleigh", "vanderpol-path"])
def test_schittkowski_preset_reaches_ipopts_objective(name, cfg, qp):
    ref = _ipopt(PROBLEMS[name]())
    r = olado.solve(PROBLEMS[name](), config=CONFIGS / f"{cfg}.ini")
    assert r.success and r.options["merit"] == "augmented-lagrangian" and r.options["qp"] == qp
    assert r.objective == pytest.approx(ref.objective, rel=1e-6)


# ---------------------------------------------------------------------------- external QP solvers
@pytest.mark.parametrize("qp", ["osqp", "clarabel"])
@pytest.mark.parametrize("name", ["cstr", "vanderpol-path"])
def test_external_qp_with_the_exact_hessian_reaches_ipopts_objective(qp, name):
    """The exact Hessian passed as H + rho A_eq^T A_eq (before: every block shifted to positive
    definiteness; cstr stopped after 200 iterations at another local minimum, 0.244)."""
    pytest.importorskip("qpsolvers")
    ref = _ipopt(PROBLEMS[name]())
    r = olado.solve(PROBLEMS[name](), config=SQP_IP, qp=qp)
    assert r.success, r.message
    assert r.objective == pytest.approx(ref.objective, rel=1e-6)


# ---------------------------------------------------------------------------- initial multipliers
def _start(problem, U=None, **options):
    """The SQP's setup and initial state for ``problem`` from the controls U (default: its
    initial guess) and the states they simulate."""
    from olado.config import load_config
    from olado.solvers.sqp.solver import make_setup
    from olado.solvers.sqp.state import Clock
    o = load_config(SQP_IP, {f"sqp.{k}": v for k, v in options.items()}).options
    setup, hess = make_setup(o, problem, lambda rec: False)
    U = np.asarray(problem.initial_guess() if U is None else U, dtype=float)
    return setup, phases.initial_state(setup, problem.simulate(U), U, hess, Clock(setup.limits))


def test_least_squares_initial_multipliers_minimize_the_lagrangian_gradient():
    """cstr has only the dynamics h_k = f(x_k, u_k) - x_{k+1}: the initial multipliers are the
    least-squares solution of grad J + J_h^T lam = 0 over (x^1..x^N, u), checked against a dense
    lstsq of the assembled Jacobian (x^0 fixed)."""
    setup, st = _start(PROBLEMS["cstr"]())
    pt, p = st.pt, setup.problem
    N, n, m = p.N, p.n, p.m
    nx = N * n
    Jh = np.zeros((N * n, nx + N * m))
    for k in range(N):
        rows = slice(k * n, (k + 1) * n)
        if k > 0:
            Jh[rows, (k - 1) * n:k * n] = pt.A[k]
        Jh[rows, k * n:(k + 1) * n] = -np.eye(n)
        Jh[rows, nx + k * m:nx + (k + 1) * m] = pt.B[k]
    g = np.concatenate([pt.lx[1:].ravel(), pt.lN, pt.lu.ravel()])
    lam = np.linalg.lstsq(Jh.T, -g, rcond=None)[0].reshape(N, n)
    assert np.max(np.abs(lam)) > 0.1
    assert np.max(np.abs(st.mult.lam[1:] - lam)) <= 1e-8 * np.max(np.abs(lam))
    assert st.qp_iters >= 1
    zero = _start(PROBLEMS["cstr"](), initial_multipliers="zero")[1]
    assert not np.any(zero.mult.lam) and zero.qp_iters == 0


@pytest.mark.parametrize("init_max, least_squares", [(1e3, True), (1e-12, False)])
def test_the_optimality_phase_resumes_after_restoration_with_reset_multipliers(init_max, least_squares):
    """IPOPT's reset after restoration (olado.solvers.sqp.restoration.reset_multipliers): the
    multipliers, shift and tau of the point where the phase started (on hang-glider |lambda| 5e13
    and a shift 8e13) are replaced by the least-squares estimate -- the one the test above checks
    against a dense lstsq -- or by 0 when its largest exceeds multiplier_init_max."""
    from olado.solvers.sqp import step as qp_step
    setup, st = _start(PROBLEMS["cstr"](), multiplier_init_max=init_max)
    p = setup.problem
    st.mult = type(st.mult)(np.full((p.N + 1, p.n), 5e13), np.full((p.N, p.r), 5e13), np.full(p.rN, 5e13))
    st.tau, st.shift = 0.5, np.full(p.N + 1, 8e13)
    st.Bk = np.zeros(1)
    restoration.reset_multipliers(setup, st)
    est, size, _ = qp_step.least_squares_multipliers(setup, st.pt)
    assert 0.0 < size < 1e3                  # cstr's estimate: accepted with the default bound only
    expected = est.lam if least_squares else np.zeros_like(est.lam)
    np.testing.assert_allclose(st.mult.lam, expected, rtol=1e-12, atol=0.0)
    assert st.tau == 0.0 and not np.any(st.shift) and st.Bk is None


@pytest.mark.parametrize("reset, init_max, replaced", [(True, 1e3, True), (False, 1e3, False), (True, 1e-12, False)])
def test_qp_multipliers_above_the_bound_give_way_to_the_least_squares_estimate(reset, init_max, replaced):
    """``multiplier_reset``: QP multipliers whose largest exceeds multiplier_init_max are replaced
    by the least-squares estimate at the iterate when it stays below the bound (cstr's: < 1e3);
    kept when the option is off or the estimate exceeds the bound too."""
    from olado.solvers.sqp import step as qp_step
    setup, st = _start(PROBLEMS["cstr"](), multiplier_reset=reset, multiplier_init_max=init_max)
    p = setup.problem
    huge = type(st.mult)(np.full((p.N + 1, p.n), 5e13), np.full((p.N, p.r), 5e13), np.full(p.rN, 5e13))
    kept = phases.bounded_multipliers(setup, st, huge)
    est = qp_step.least_squares_multipliers(setup, st.pt)[0]
    if replaced:
        np.testing.assert_allclose(kept.lam, est.lam, rtol=1e-12, atol=0.0)
        assert kept.largest() < 1e3
    else:
        assert kept is huge
    small = type(st.mult)(np.full((p.N + 1, p.n), 0.5 * init_max), np.zeros((p.N, p.r)), np.zeros(p.rN))
    assert phases.bounded_multipliers(setup, st, small) is small     # below the bound: the QP's


def test_initial_multipliers_are_zero_where_a_bound_is_active_at_the_start():
    """vanderpol-box starts with u inside -0.3 <= u <= 1 (least squares); with one control on its
    bound the start is zero (the active bound's multiplier is unknown before the first QP)."""
    p = PROBLEMS["vanderpol-box"]()
    setup, st = _start(p)
    assert phases.strictly_inactive(setup, st.pt) and np.any(st.mult.lam)
    U = np.asarray(p.initial_guess(), dtype=float).copy()
    U[3] = p.u_lower[3]
    setup, st = _start(p, U)
    assert not phases.strictly_inactive(setup, st.pt) and not np.any(st.mult.lam) and st.qp_iters == 0


def test_cstr_euler_reaches_ipopts_minimum():
    """Robustness entry cstr-euler (N = 100, explicit Euler): from zero multipliers the first
    (convex) QP stepped u by 2 into the basin of the minimum near 0.24, where the SQP cycled and
    its multipliers exploded; with the least-squares start it reaches IPOPT's 0.1368144."""
    from olado.problems.suites import load_suite
    entry = next(e for e in load_suite("robustness") if e.name == "cstr-euler")
    problem, guess = entry.build()
    ref = olado.solve(problem, config=IPOPT, guess=guess)
    r = olado.solve(entry.build()[0], config=SQP_IP, guess=guess)
    assert ref.success and r.status is Status.SUCCESS, r.message
    assert r.objective == pytest.approx(ref.objective, rel=1e-6)
    assert r.max_constraint_violation < 1e-8


@pytest.mark.slow
def test_alp_rider_converges_now_that_its_qps_start():
    """Robustness entry alp-rider (N = 100): the path constraints |y|^2 >= q(t) make the
    Lagrangian Hessian indefinite, every QP's cold start failed (unit-weight start system without
    a minimizer) and the Hessian shift oscillated for 200 iterations (MAX_ITERATIONS). Now the
    QPs start (olado.qp.interior_point.start) and the SQP converges to a KKT point olado's
    certificate accepts: a local minimum at most IPOPT's (3170.06 from this start; sqp-ip finds
    3157.27 in 139 iterations, the path constraint's ridges followed differently). Which local
    minimum depends on last bits: on the hand-written ContinuousDOCP (values and derivatives equal
    to the exact ones to 5e-16) it found 3155.92 in 134 iterations, also a KKT point (independent
    KKT residual 5e-11 there, 2.4e-10 here); hence the bound, not an objective."""
    from olado.problems.suites import load_references, load_suite
    entry = next(e for e in load_suite("robustness") if e.name == "alp-rider")
    ref = load_references()["entries"]["alp-rider"]
    problem, guess = entry.build()
    r = olado.solve(problem, config=SQP_IP, guess=guess)
    assert r.status is Status.SUCCESS, r.message
    assert r.certificate is not None and r.certificate.level == "success"
    assert r.max_constraint_violation < 1e-8
    assert r.objective <= ref["objective"] * (1 + 1e-6)
