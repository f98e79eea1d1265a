"""External QP backends (qpsolvers: OSQP, Clarabel, ...) on StageQP: solutions, multiplier
signs under the QPResult convention, status mapping and the missing-backend error."""

import sys

import numpy as np
import pytest
import scipy.optimize as so
import scipy.sparse as sp

from olado.errors import ConfigError, SolverNotAvailableError
from olado.linalg import RiccatiFactorization
from olado.qp.stageqp import StageQP, qp_kkt_residuals
from olado.result import Status
from fixtures.clarabel_spy import spy_on_clarabel
from olado.qp.external import ExternalQP, _build_rows, _osqp_polish_key, available_qp_backends, map_backend_status

qpsolvers = pytest.importorskip("qpsolvers")

BACKENDS = [b for b in ("osqp", "clarabel", "piqp", "proxqp") if b in available_qp_backends()]
if not BACKENDS:
    pytest.skip("no qpsolvers backend installed", allow_module_level=True)

# tight settings: OSQP with polishing (active-set refinement), Clarabel with its gap/feasibility tolerances
TIGHT = {"osqp": dict(eps_abs=1e-10, eps_rel=1e-10, polish=True, max_iter=100000),
         "clarabel": dict(tol_gap_abs=1e-10, tol_gap_rel=1e-10, tol_feas=1e-10),
         "piqp": dict(eps_abs=1e-10, eps_rel=1e-10), "proxqp": dict(eps_abs=1e-10, eps_rel=0.0)}


def tight(backend, **kw):
    return ExternalQP(backend, **{**TIGHT[backend], **kw})


def spd(rng, k, d):
    M = rng.standard_normal((k, d, d))
    return M @ M.transpose(0, 2, 1) + np.eye(d)


def equality_qp(seed=0, N=5, n=3, m=2):
    rng = np.random.default_rng(seed)
    return StageQP(Q=spd(rng, N + 1, n), R=spd(rng, N, m), q=rng.standard_normal((N + 1, n)),
                   r=rng.standard_normal((N, m)), A=0.5 * rng.standard_normal((N, n, n)),
                   B=rng.standard_normal((N, n, m)), c=rng.standard_normal((N, n)), x0=rng.standard_normal(n),
                   S=0.1 * rng.standard_normal((N, n, m)), E=rng.standard_normal((N, 1, n)),
                   F=rng.standard_normal((N, 1, m)), e=rng.standard_normal((N, 1)),
                   EN=rng.standard_normal((1, n)), eN=rng.standard_normal(1))


def constructed_qp(seed=0, N=4, n=2, m=4, nc=2):
    """A QP whose unique solution and multipliers are known by construction: pick X*, U*, the
    active sets and the multipliers, then choose the data (c, e, bounds, sides, q, r) so that
    the KKT conditions of the QPResult convention hold exactly. Covers every row kind: two-sided
    stage inequalities active at the lower and at the upper side, one-sided and equal-sided
    rows, active lower/upper bounds, fixed variables (equal bounds) and inactive constraints;
    few enough active rows (9 for 11 degrees of freedom) that the multipliers are unique."""
    rng = np.random.default_rng(seed)
    Q, R = spd(rng, N + 1, n), spd(rng, N, m)
    S = 0.1 * rng.standard_normal((N, n, m))
    A, B = 0.5 * rng.standard_normal((N, n, n)), rng.standard_normal((N, n, m))
    X, U = rng.standard_normal((N + 1, n)), rng.standard_normal((N, m))
    c = X[1:] - np.einsum("kij,kj->ki", A, X[:-1]) - np.einsum("kij,kj->ki", B, U)
    E, F = rng.standard_normal((N, 1, n)), rng.standard_normal((N, 1, m))
    e = -(np.einsum("kij,kj->ki", E, X[:-1]) + np.einsum("kij,kj->ki", F, U))
    EN = rng.standard_normal((1, n))
    C = rng.standard_normal((N, nc, n + m))
    CZ = np.einsum("kij,kj->ki", C, np.hstack([X[:-1], U]))
    CN = rng.standard_normal((2, n))
    CNx = CN @ X[-1]
    pos = lambda: 0.5 + rng.random()  # noqa: E731
    # stage rows: pattern per stage over the nc rows (cycled): active lower, active upper, inactive
    # two-sided, equal sides (an equality as a two-sided row), one-sided active upper
    kinds = ["lo", "in", "up", "in", "eq", "in", "up1", "in"]
    c_lower, c_upper = np.empty((N, nc)), np.empty((N, nc))
    yc_l, yc_u = np.zeros((N, nc)), np.zeros((N, nc))
    for k in range(N):
        for i in range(nc):
            kind = kinds[(k * nc + i) % len(kinds)]
            v = CZ[k, i]
            if kind == "lo":
                c_lower[k, i], c_upper[k, i] = v, v + 1.0; yc_l[k, i] = pos()
            elif kind == "up":
                c_lower[k, i], c_upper[k, i] = v - 1.0, v; yc_u[k, i] = pos()
            elif kind == "in":
                c_lower[k, i], c_upper[k, i] = v - 0.5, v + 0.7
            elif kind == "eq":
                c_lower[k, i] = c_upper[k, i] = v; w = rng.standard_normal()
                yc_l[k, i], yc_u[k, i] = max(-w, 0.0), max(w, 0.0)
            else:
                c_lower[k, i], c_upper[k, i] = -np.inf, v; yc_u[k, i] = pos()
    cN_lower, cN_upper = np.array([CNx[0], -np.inf]), np.array([np.inf, CNx[1] + 0.3])
    yN_l, yN_u = np.array([pos(), 0.0]), np.zeros(2)
    # bounds: u[0, 0] active lower, u[1, 0] active upper, else inactive; u[:, 1] inactive
    # two-sided; x[1, 0] active upper, x[k, 0] inactive upper for k > 1; u[N-1, 1] fixed
    x_lower, x_upper = np.full((N + 1, n), -np.inf), np.full((N + 1, n), np.inf)
    u_lower, u_upper = np.full((N, m), -np.inf), np.full((N, m), np.inf)
    zx_l, zx_u, zu_l, zu_u = np.zeros((N + 1, n)), np.zeros((N + 1, n)), np.zeros((N, m)), np.zeros((N, m))
    for k in range(N):
        if k == 0:
            u_lower[k, 0], u_upper[k, 0] = U[k, 0], U[k, 0] + 2.0; zu_l[k, 0] = pos()
        elif k == 1:
            u_lower[k, 0], u_upper[k, 0] = U[k, 0] - 2.0, U[k, 0]; zu_u[k, 0] = pos()
        else:
            u_lower[k, 0], u_upper[k, 0] = U[k, 0] - 2.0, U[k, 0] + 0.5
        u_lower[k, 1], u_upper[k, 1] = U[k, 1] - 1.0, U[k, 1] + 1.0
    for k in range(1, N + 1):
        x_upper[k, 0] = X[k, 0] + (0.0 if k == 1 else 0.4)
        zx_u[k, 0] = pos() if k == 1 else 0.0
    u_lower[N - 1, 1] = u_upper[N - 1, 1] = U[N - 1, 1]
    w = rng.standard_normal(); zu_l[N - 1, 1], zu_u[N - 1, 1] = max(-w, 0.0), max(w, 0.0)
    lam, nu = rng.standard_normal((N + 1, n)), rng.standard_normal((N + 1, 1))
    qp = StageQP(Q=Q, R=R, q=np.zeros((N + 1, n)), r=np.zeros((N, m)), A=A, B=B, c=c, x0=X[0], S=S,
                 E=E, F=F, e=e, EN=EN, eN=-EN @ X[-1], C=C, c_lower=c_lower, c_upper=c_upper,
                 CN=CN, cN_lower=cN_lower, cN_upper=cN_upper, x_lower=x_lower, x_upper=x_upper,
                 u_lower=u_lower, u_upper=u_upper)
    known = dict(X=X, U=U, lam=lam, nu=nu, zx_lower=zx_l, zx_upper=zx_u, zu_lower=zu_l, zu_upper=zu_u,
                 yc_lower=yc_l, yc_upper=yc_u, yN_lower=yN_l, yN_upper=yN_u)
    # q, r from stationarity of the Lagrangian at the known point (gradient without q, r)
    from olado.qp.stageqp import QPResult

    probe = QPResult(Status.SUCCESS, "", **known)
    gx, gu = _lagrangian_gradient(qp, probe)
    qp.q, qp.r = -gx, -gu
    return qp, known


def _lagrangian_gradient(qp, res):
    """Gradient of the QPResult Lagrangian w.r.t. (x, u), as (N+1, n), (N, m)."""
    d = qp.to_sparse()
    y = qp.pack(res.X, res.U)
    N, n = qp.N, qp.n
    ne, neN = qp.E.shape[1], qp.EN.shape[0]
    w = np.concatenate([-res.lam[0], res.lam[1:].ravel(), res.nu[:N, :ne].ravel(), res.nu[N, :neN]])
    yg = np.concatenate([(res.yc_upper - res.yc_lower).ravel(), res.yN_upper - res.yN_lower])
    zb = qp.pack(res.zx_upper - res.zx_lower, res.zu_upper - res.zu_lower)
    g = d["P"] @ y + d["q"] + d["A_eq"].T @ w + d["G"].T @ yg + zb
    return qp.unpack(g)


def random_ineq_qp(seed, N=3, n=2, m=2, nc=2):
    """A random feasible QP with box bounds and two-sided stage / final inequalities (no known
    solution; compared against scipy)."""
    rng = np.random.default_rng(seed)
    Xf, Uf = rng.standard_normal((N + 1, n)), rng.standard_normal((N, m))   # a feasible point
    A, B = 0.6 * rng.standard_normal((N, n, n)), rng.standard_normal((N, n, m))
    c = Xf[1:] - np.einsum("kij,kj->ki", A, Xf[:-1]) - np.einsum("kij,kj->ki", B, Uf)
    C = rng.standard_normal((N, nc, n + m))
    CZ = np.einsum("kij,kj->ki", C, np.hstack([Xf[:-1], Uf]))
    CN = rng.standard_normal((1, n))
    return StageQP(Q=spd(rng, N + 1, n), R=spd(rng, N, m), q=3 * rng.standard_normal((N + 1, n)),
                   r=3 * rng.standard_normal((N, m)), A=A, B=B, c=c, x0=Xf[0],
                   C=C, c_lower=CZ - rng.random((N, nc)), c_upper=CZ + rng.random((N, nc)),
                   CN=CN, cN_lower=CN @ Xf[-1] - 0.1, cN_upper=CN @ Xf[-1] + 0.1,
                   x_lower=Xf - 0.5, x_upper=Xf + 0.5 * rng.random((N + 1, n)),
                   u_lower=Uf - 0.3, u_upper=np.where(rng.random((N, m)) < 0.5, np.inf, Uf + 0.2))


def scipy_reference(qp):
    """Dense SLSQP solve of the sparse form (independent of qpsolvers)."""
    d = qp.to_sparse()
    P, qv = d["P"].toarray(), d["q"]
    Aeq, beq, G = d["A_eq"].toarray(), d["b_eq"], d["G"].toarray()
    fl, fu = np.isfinite(d["h_lower"]), np.isfinite(d["h_upper"])
    cons = [{"type": "eq", "fun": lambda y: Aeq @ y - beq, "jac": lambda y: Aeq},
            {"type": "ineq", "fun": lambda y: np.concatenate([G[fl] @ y - d["h_lower"][fl], d["h_upper"][fu] - G[fu] @ y]),
             "jac": lambda y: np.vstack([G[fl], -G[fu]])}]
    bounds = so.Bounds(d["lb"], d["ub"])
    y0 = np.clip(np.zeros(qp.n_vars), d["lb"], d["ub"])
    # ftol 1e-14 sits at the rounding level of the objective: on some machines SLSQP's last line
    # search then ends with "Positive directional derivative" at the optimum (exit mode 8); the
    # solve is repeated with ftol 1e-12, still far below the tests' tolerances
    for ftol in (1e-14, 1e-12):
        r = so.minimize(lambda y: 0.5 * y @ P @ y + qv @ y, y0, jac=lambda y: P @ y + qv, method="SLSQP",
                        constraints=cons, bounds=bounds, options={"ftol": ftol, "maxiter": 1000})
        if r.success:
            break
    assert r.success, r.message
    return qp.unpack(r.x), float(r.fun)


# ----------------------------------------------------------------------------- equality QP
@pytest.mark.parametrize("backend", BACKENDS)
def test_equality_qp_matches_riccati_primal_and_multipliers(backend):
    qp = equality_qp(0)
    ref = RiccatiFactorization(qp.Q, qp.S, qp.R, qp.A, qp.B, E=qp.E, F=qp.F, EN=qp.EN).solve(
        qp.q, qp.r, qp.c, qp.x0, e=qp.e, eN=qp.eN)
    res = tight(backend).solve(qp)
    assert res.status == Status.SUCCESS, res.message
    assert res.solver == backend and backend in res.message
    scale = max(1.0, np.abs(ref.lam).max())
    assert np.abs(res.X - ref.X).max() < 1e-8 and np.abs(res.U - ref.U).max() < 1e-8
    assert np.abs(res.lam - ref.lam).max() < 1e-7 * scale
    assert np.abs(res.nu - ref.nu).max() < 1e-7 * scale
    assert res.kkt["stationarity"] < 1e-7 and res.kkt["primal"] < 1e-8
    assert np.isclose(res.objective, qp.objective(ref.X, ref.U), rtol=1e-10, atol=1e-10)
    assert res.time_s > 0


# ----------------------------------------------------------------------------- known solution
@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("seed", [0, 1])
def test_constructed_qp_recovers_known_solution_and_multiplier_signs(backend, seed):
    qp, known = constructed_qp(seed)
    res = tight(backend).solve(qp)
    assert res.status == Status.SUCCESS, res.message
    k = qp_kkt_residuals(qp, res)
    assert k == res.kkt
    assert k["stationarity"] < 1e-6 and k["primal"] < 1e-7 and k["complementarity"] < 1e-6
    assert k["dual_sign"] < 1e-7
    assert np.abs(res.X - known["X"]).max() < 1e-6 and np.abs(res.U - known["U"]).max() < 1e-6
    for name in ("lam", "nu", "zx_lower", "zx_upper", "zu_lower", "zu_upper", "yc_lower", "yc_upper",
                 "yN_lower", "yN_upper"):
        assert np.abs(getattr(res, name) - known[name]).max() < 1e-5, name


def test_a_sign_error_would_be_seen():
    """The residual check above has teeth: flipping one multiplier family breaks stationarity."""
    qp, known = constructed_qp(0)
    res = tight(BACKENDS[0]).solve(qp)
    res.zu_lower, res.zu_upper = res.zu_upper, res.zu_lower
    assert qp_kkt_residuals(qp, res)["stationarity"] > 1e-2
    res = tight(BACKENDS[0]).solve(qp)
    res.lam = -res.lam
    assert qp_kkt_residuals(qp, res)["stationarity"] > 1e-2


# ----------------------------------------------------------------------------- random QPs vs scipy
@pytest.mark.parametrize("seed", range(4))
def test_random_qps_backends_agree_with_each_other_and_scipy(seed):
    qp = random_ineq_qp(seed)
    (Xs, Us), fs = scipy_reference(qp)
    results = {b: tight(b).solve(qp) for b in BACKENDS}
    for b, res in results.items():
        assert res.status == Status.SUCCESS, res.message
        assert abs(res.objective - fs) < 1e-7 * max(1.0, abs(fs)), b
        assert np.abs(res.X - Xs).max() < 1e-5 and np.abs(res.U - Us).max() < 1e-5, b
        assert res.kkt["stationarity"] < 1e-6 and res.kkt["primal"] < 1e-7, (b, res.kkt)
        assert res.kkt["complementarity"] < 1e-6 and res.kkt["dual_sign"] < 1e-7, (b, res.kkt)
    first, *others = results.values()
    for res in others:
        assert np.abs(res.X - first.X).max() < 1e-6 and np.abs(res.U - first.U).max() < 1e-6
        assert np.abs(res.lam - first.lam).max() < 1e-5
        assert np.abs((res.yc_upper - res.yc_lower) - (first.yc_upper - first.yc_lower)).max() < 1e-5
        assert np.abs((res.zu_upper - res.zu_lower) - (first.zu_upper - first.zu_lower)).max() < 1e-5


def test_default_options_are_accurate_enough_for_sqp():
    qp, known = constructed_qp(2)
    for b in BACKENDS:
        res = ExternalQP(b).solve(qp)
        assert res.success, res.message
        assert np.abs(res.U - known["U"]).max() < 1e-5, b


# ----------------------------------------------------------------------------- statuses
def _infeasible_qp():
    qp = equality_qp(1, N=3)
    N, m = qp.N, qp.m
    return StageQP(Q=qp.Q, R=qp.R, q=qp.q, r=qp.r, A=qp.A, B=qp.B, c=qp.c, x0=qp.x0,
                   u_lower=np.ones((N, m)), u_upper=np.full((N, m), 2.0),
                   C=np.concatenate([np.zeros((N, 1, qp.n)), np.ones((N, 1, m))], axis=2),
                   c_lower=np.full((N, 1), -np.inf), c_upper=np.zeros((N, 1)))   # sum(u) <= 0 but u >= 1


@pytest.mark.parametrize("backend", BACKENDS)
def test_infeasible_qp_is_reported_infeasible(backend):
    res = ExternalQP(backend).solve(_infeasible_qp())
    assert res.status == Status.INFEASIBLE, res.message
    assert not res.success and backend in res.message


@pytest.mark.parametrize("backend", [b for b in BACKENDS if b in ("osqp", "clarabel")])
def test_unbounded_qp_is_reported_unbounded(backend):
    qp = equality_qp(2, N=3)
    N, n, m = qp.N, qp.n, qp.m
    qp = StageQP(Q=qp.Q, R=np.zeros((N, m, m)), q=qp.q, r=np.ones((N, m)), A=qp.A, B=np.zeros((N, n, m)),
                 c=qp.c, x0=qp.x0)   # u enters neither the dynamics nor the curvature: r.u -> -inf
    res = ExternalQP(backend).solve(qp)
    assert res.status == Status.UNBOUNDED, res.message


def test_iteration_limit_is_max_iterations():
    if "osqp" not in BACKENDS:
        pytest.skip("osqp not installed")
    res = ExternalQP("osqp", max_iter=3, eps_abs=1e-12, eps_rel=1e-12, polish=False).solve(random_ineq_qp(0))
    assert res.status == Status.MAX_ITERATIONS, res.message
    assert "osqp" in res.message and res.iterations == 3


@pytest.mark.parametrize("text, found, status", [
    ("solved", True, Status.SUCCESS), ("Solved", True, Status.SUCCESS), ("PIQP_SOLVED", True, Status.SUCCESS),
    ("solved inaccurate", False, Status.ACCEPTABLE), ("AlmostSolved", False, Status.ACCEPTABLE),
    ("maximum iterations reached", False, Status.MAX_ITERATIONS), ("MaxIterations", False, Status.MAX_ITERATIONS),
    ("PROXQP_MAX_ITER_REACHED", False, Status.MAX_ITERATIONS),
    ("primal infeasible", False, Status.INFEASIBLE), ("primal infeasible inaccurate", False, Status.INFEASIBLE),
    ("AlmostPrimalInfeasible", False, Status.INFEASIBLE), ("PrimalInfeasible", False, Status.INFEASIBLE),
    ("dual infeasible", False, Status.UNBOUNDED), ("DualInfeasible", False, Status.UNBOUNDED),
    ("run time limit reached", False, Status.MAX_TIME), ("MaxTime", False, Status.MAX_TIME),
    ("NumericalError", False, Status.NUMERICAL_ERROR), ("unsolved", False, Status.FAILED),
    ("problem non convex", False, Status.FAILED), ("InsufficientProgress", False, Status.FAILED),
    (None, True, Status.SUCCESS), (None, False, Status.FAILED),
])
def test_backend_status_mapping(text, found, status):
    assert map_backend_status(text, found) == status


# ----------------------------------------------------------------------------- options, warm start
def test_options_are_validated():
    with pytest.raises(ConfigError, match="eps_abs"):
        ExternalQP(BACKENDS[0], eps_abs=-1.0)
    with pytest.raises(ConfigError, match="unknown option"):
        ExternalQP(BACKENDS[0], eps=1e-3)
    q = ExternalQP(BACKENDS[0], max_iter=50)
    assert q.options.max_iter == 50 and q.backend == BACKENDS[0]


def test_osqp_warm_start_from_the_solution_needs_fewer_iterations():
    """The warm start carries the multipliers too (mapped back to OSQP's rows): restarting at a
    solution of the same QP converges in a fraction of the cold iterations."""
    if "osqp" not in BACKENDS:
        pytest.skip("osqp not installed")
    qp = random_ineq_qp(1, N=10)
    solver = ExternalQP("osqp", eps_abs=1e-8, eps_rel=1e-8, polish=False)
    cold = solver.solve(qp)
    warm = solver.solve(qp, warm_start=cold)
    assert cold.success and warm.success, (cold.message, warm.message)
    assert warm.iterations < cold.iterations / 2
    assert np.abs(warm.U - cold.U).max() < 1e-5
    # a nearby QP (perturbed linear term) still profits
    qp2 = random_ineq_qp(1, N=10)
    qp2.q = qp2.q + 1e-3
    assert solver.solve(qp2, warm_start=cold).iterations < solver.solve(qp2).iterations
    off = ExternalQP("osqp", eps_abs=1e-8, eps_rel=1e-8, polish=False, warm_start=False).solve(qp, warm_start=cold)
    assert off.iterations == cold.iterations


def test_warm_start_dual_mapping_is_the_inverse_of_the_result_mapping():
    from olado.qp.external import _backend_duals, _build_rows, _map_back

    qp, known = constructed_qp(1)
    for backend in ("osqp", "clarabel"):
        rows = _build_rows(qp, backend)
        res = tight(BACKENDS[0]).solve(qp)
        y_eq, z, z_box = _backend_duals(qp, rows, res)
        back = _map_back(qp, rows, qp.pack(res.X, res.U), y_eq, z, z_box)
        names = ("X", "U", "lam", "nu", "zx_lower", "zx_upper", "zu_lower", "zu_upper", "yc_lower", "yc_upper",
                 "yN_lower", "yN_upper")
        for name, arr in zip(names, back):
            # multipliers that are both nonzero on one side pair collapse to their difference
            if name.endswith(("lower", "upper")):
                continue
            assert np.allclose(arr, getattr(res, name), atol=1e-12), (backend, name)
        for lo, up in (("zx_lower", "zx_upper"), ("zu_lower", "zu_upper"), ("yc_lower", "yc_upper"),
                       ("yN_lower", "yN_upper")):
            i, j = names.index(lo), names.index(up)
            assert np.allclose(back[j] - back[i], getattr(res, up) - getattr(res, lo), atol=1e-12), (backend, lo)


def test_backend_options_are_passed_through():
    if "osqp" not in BACKENDS:
        pytest.skip("osqp not installed")
    res = ExternalQP("osqp", backend_options={"max_iter": 2}, polish=False, eps_abs=1e-12).solve(random_ineq_qp(0))
    assert res.status == Status.MAX_ITERATIONS and res.iterations == 2


@pytest.fixture
def clarabel_spy(monkeypatch):
    return spy_on_clarabel(monkeypatch)


@pytest.mark.parametrize("seed", [0, 1])
def test_clarabel_iterations_are_clarabels_own_count(clarabel_spy, seed):
    """qpsolvers' Clarabel interface drops the iteration count (its Solution.extras holds s,
    status and solve time only); ExternalQP reports Clarabel's own: the same count as Clarabel
    gives for the very problem qpsolvers builds, and the same solution."""
    assert "clarabel" in BACKENDS, "clarabel is a core dependency (pyproject.toml)"
    qp = random_ineq_qp(seed)
    rows = _build_rows(qp, "clarabel")
    ref = qpsolvers.solve_problem(rows.problem, solver="clarabel", tol_gap_abs=1e-8, tol_gap_rel=1e-8, tol_feas=1e-8)
    assert "iterations" not in ref.extras and len(clarabel_spy) == 1
    res = ExternalQP("clarabel").solve(qp)
    assert res.status == Status.SUCCESS, res.message
    assert len(clarabel_spy) == 2 and res.iterations == clarabel_spy[0] == clarabel_spy[1] > 0
    assert np.allclose(qp.pack(res.X, res.U), ref.x, rtol=0, atol=1e-12)


def test_osqp_iterations_are_osqps_own_count():
    assert "osqp" in BACKENDS, "osqp is a core dependency (pyproject.toml)"
    import osqp

    qp = random_ineq_qp(0)
    res = ExternalQP("osqp").solve(qp)
    P, q, G, h, A, b, lb, ub = _build_rows(qp, "osqp").problem.unpack()
    solver = osqp.OSQP()
    solver.setup(P=sp.csc_matrix(P), q=q, A=sp.vstack([G, A, sp.identity(len(q))], format="csc"),
                 l=np.concatenate([np.full(len(h), -np.inf), b, lb]), u=np.concatenate([h, b, ub]), verbose=False,
                 eps_abs=1e-7, eps_rel=1e-7, **{_osqp_polish_key(): True})
    out = solver.solve(**({"raise_error": False} if _osqp_polish_key() == "polishing" else {}))
    assert res.status == Status.SUCCESS and res.iterations == out.info.iter > 0


# ----------------------------------------------------------------------------- missing backends
def test_missing_backend_names_the_install_command_and_the_installed_ones(monkeypatch):
    monkeypatch.setattr(qpsolvers, "available_solvers", ["clarabel"])
    with pytest.raises(SolverNotAvailableError) as info:
        ExternalQP("piqp")
    msg = str(info.value)
    assert "pip install qpsolvers osqp clarabel" in msg and "clarabel" in msg and "piqp" in msg
    assert isinstance(info.value, ImportError)
    assert available_qp_backends() == ["clarabel"]


def test_missing_qpsolvers_package(monkeypatch):
    monkeypatch.setitem(sys.modules, "qpsolvers", None)
    assert available_qp_backends() == []
    with pytest.raises(SolverNotAvailableError, match=r"pip install qpsolvers osqp clarabel"):
        ExternalQP("osqp")


def test_sparse_form_is_passed_without_infinite_bounds_to_row_backends():
    """Clarabel gets finite bounds as rows, equal sides as equality rows and no +-inf anywhere."""
    from olado.qp.external import _build_rows

    qp, _ = constructed_qp(0)
    rows = _build_rows(qp, "clarabel")
    pb = rows.problem
    assert pb.lb is None and pb.ub is None
    assert np.all(np.isfinite(pb.h)) and np.all(np.isfinite(pb.b))
    n_eq_sides = int(np.sum(qp.c_lower == qp.c_upper))
    assert len(rows.eq_g) == n_eq_sides and len(rows.eq_fix) == 1
    assert sp.issparse(pb.A) and sp.issparse(pb.G)
    native = _build_rows(qp, "osqp").problem
    assert native.lb is not None and np.isinf(native.lb).any()
