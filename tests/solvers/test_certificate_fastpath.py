"""The certificate's cheaper passes (olado.solvers.certificate, diagnosis.largest_violation_of,
DOCP._stacked_values) give bit for bit the figures of the reference forms they replace: the
bound choice per variable (_bound_choice), the violation arrays with their kinds
(violation_arrays + largest_violation), the spot check's directions drawn one by one (_direction)
and its values point by point (_values) -- on Zambezi (bounds only), the pendulum (a stage
inequality, a final equality or inequality), points the certificate accepts and points it
rejects (a perturbed point, a wrong derivative)."""

import numpy as np
import pytest

import olado
from fixtures.toy_problems import Pendulum, RestToRestCart
from olado.problems.zambezi import zambezi_problem
from olado.solvers import certificate as C
from olado.solvers.common import stage_gradient_terms
from olado.solvers.diagnosis import largest_violation, largest_violation_of, violation_arrays


def _bound_choice(r, y, lo, hi, w):
    """Per variable, the bound multiplier that minimises max(|r - z| w, z slack) (the certificate's module docstring,
    step 2): returns the remaining |r - z| and z * slack. Fixed variables (lo == hi) take any
    multiplier: both are 0 there. (The certificate's reference form: its _figures computes the same
    numbers with _BoundSides.)"""
    with np.errstate(invalid="ignore", over="ignore"):
        slack = np.where(r > 0, y - lo, hi - y)            # the bound that can cancel r; inf: none
        slack = np.maximum(slack, 0.0)
        bounded = np.isfinite(slack)
        a = np.abs(r)
        z = np.where(bounded, a * w / (w + np.where(bounded, slack, 0.0)), 0.0)
        stat = a - z
        comp = np.where(bounded, z * np.where(bounded, slack, 0.0), 0.0)
    fixed = lo == hi
    return np.where(fixed, 0.0, stat), np.where(fixed, 0.0, comp)


class PendulumFinalInequality(Pendulum):
    """The pendulum with its final constraint x0 - 0.2 >= 0 (an inequality)."""

    def __init__(self, N=8):
        super().__init__(N=N)
        self.final_equality_mask = np.zeros(1, dtype=bool)


class WrongGradient(Pendulum):
    """The pendulum with the control part of the stage-cost gradient doubled at stage 3."""

    def stage_cost_gradient(self, k, x, u):
        lx, lu = super().stage_cost_gradient(k, x, u)
        return lx, (2.0 * lu if k == 3 else lu)


# ---------------------------------------------------------------------------- reference forms
def _reference_figures(p, pt, bounds, W, S, lam, Lg, LgN, kind):
    """The figures as the certificate computed them before (two _bound_choice calls)."""
    ineq, ineqN = ~p.stage_equality_mask, ~p.final_equality_mask
    Lg, LgN = np.array(Lg, dtype=float), np.array(LgN, dtype=float)
    if p.r:
        Lg[:, ineq] = np.minimum(Lg[:, ineq], 0.0)
    if p.rN:
        LgN[ineqN] = np.minimum(LgN[ineqN], 0.0)
    rx, ru = stage_gradient_terms(p, pt, lam, Lg, LgN)
    wx, wu = W
    sx, cx = _bound_choice(rx, pt.X, bounds.xl, bounds.xu, wx)
    su, cu = _bound_choice(ru, pt.U, bounds.ul, bounds.uu, wu)
    sx[0] = cx[0] = 0.0

    def largest(arrays):
        best = (-1.0, "", 0, 0)
        for name, a in arrays:
            if a.size and float(np.max(a)) > best[0]:
                k, i = np.unravel_index(int(np.argmax(a)), a.shape)
                best = (float(a[k, i]), name, int(k), int(i))
        return best

    stat_scaled, name, k, i = largest((("x", sx * wx / S), ("u", su * wu / S)))
    residual = float((rx if name == "x" else ru)[k, i])
    rows = [("x bounds", cx), ("u bounds", cu)]
    if p.r and ineq.any():
        g = np.zeros_like(pt.g)
        g[:, ineq] = np.abs(Lg[:, ineq] * pt.g[:, ineq])
        rows.append(("stage constraint", g))
    if p.rN and ineqN.any():
        g = np.zeros((1, p.rN))
        g[0, ineqN] = np.abs(LgN[ineqN] * pt.gN[ineqN])
        rows.append(("final constraint", g))
    comp, cname, ck, ci = largest(rows)
    comp_at = f"{cname} {ci}" if cname == "final constraint" else f"{cname}, stage {ck}, component {ci}"
    stat = max(float(np.max(sx, initial=0.0)), float(np.max(su, initial=0.0)))
    return C.KKTFigures(kind, stat, comp, stat_scaled, comp / S, f"{name}^{k}[{i}]", comp_at, residual)


def _reference_spot_check(p, pt, bounds, W):
    """(worst, index of the largest ratio, that ratio) of the spot check with its directions drawn
    one by one and its values computed point by point."""
    rng, h = np.random.default_rng(C.CHECK_SEED), C.CHECK_STEP
    directions = [C._direction(rng, pt, bounds, W, h) for _ in range(C.CHECK_DIRECTIONS)]
    saved = p.counters.copy()
    vals = C._pointwise_values(p, pt, directions, h)
    p.counters.clear()
    p.counters.update(saved)
    v1, m1, v2, m2 = (vals[:, i] for i in range(4))
    an, size = C._directional(pt, np.array([v[0] for v in directions]), np.array([v[1] for v in directions]))
    d_h, d_2h = (v1 - m1) / (2 * h), (v2 - m2) / (4 * h)
    d5 = (4 * d_h - d_2h) / 3
    rounding = C._EPS * (np.abs(v1) + np.abs(m1) + np.abs(v2) + np.abs(m2)) / h
    allowed = C.CHECK_RTOL * np.maximum(size, np.abs(d5)) + 10 * (np.abs(d_h - d_2h) + rounding) + 1e-300
    err = np.abs(d5 - an)
    rel = err / np.maximum(np.maximum(size, np.abs(d5)), 1e-300)
    worst = max(0.0, float(np.where(err > 10 * rounding, rel, 0.0).max()))
    ratio = (err / allowed).ravel()
    return worst, directions, vals, ratio


# ---------------------------------------------------------------------------- the cases
@pytest.fixture(scope="module")
def cases():
    """(problem, X, U, multipliers) at solutions and at points the certificate rejects."""
    out = {}
    z = zambezi_problem("zambezi12", N=24, start="balance")
    r = olado.solve(z, config="configs/ipm.ini")
    assert r.certificate.level == "success"
    out["zambezi12-24"] = (z, r.x, r.u, r.multipliers)
    rng = np.random.default_rng(7)
    out["zambezi12-24-perturbed"] = (z, r.x + 1e-3 * rng.standard_normal(r.x.shape), r.u, r.multipliers)
    for name, p in (("pendulum", Pendulum(N=8)), ("pendulum-final-inequality", PendulumFinalInequality())):
        r = olado.solve(p, config="configs/ipm.ini")      # its point, certified or not
        out[name] = (p, r.x, r.u, r.multipliers)
        # multipliers of both signs everywhere: the projection and the complementarity rows
        wild = {k: rng.standard_normal(np.shape(v)) for k, v in r.multipliers.items()}
        out[name + "-wild-multipliers"] = (p, r.x, r.u, wild)
    p = out["pendulum"][0]
    out["pendulum-wrong-derivative"] = (WrongGradient(N=8), *out["pendulum"][1:])
    U = p.initial_guess()
    out["pendulum-initial-guess"] = (p, p.simulate(U), U, None)
    cart = RestToRestCart()
    U = cart.initial_guess() + 0.3
    out["cart-infeasible-guess"] = (cart, cart.simulate(U), U, None)
    return out


CASES = ["zambezi12-24", "zambezi12-24-perturbed", "pendulum", "pendulum-wild-multipliers",
         "pendulum-final-inequality", "pendulum-final-inequality-wild-multipliers", "pendulum-wrong-derivative",
         "pendulum-initial-guess", "cart-infeasible-guess"]


def _setup(case):
    p, X, U, mult = case
    X, U = np.asarray(X, dtype=float), np.asarray(U, dtype=float)
    pt, bounds = C.StagePoint(p, X, U), C.StageBounds.of(p)
    W = (np.maximum(1.0, np.abs(X)), np.maximum(1.0, np.abs(U)))
    return p, pt, bounds, W, max(1.0, abs(pt.J)), C._solver_multipliers(p, mult)


@pytest.mark.parametrize("name", CASES)
def test_figures_equal_the_reference_bit_for_bit(cases, name):
    p, pt, bounds, W, S, given = _setup(cases[name])
    if given is None:
        given = C.least_squares_multipliers(p, pt, bounds, W)
    assert C._figures(p, pt, bounds, W, S, *given, "solver") == _reference_figures(p, pt, bounds, W, S, *given,
                                                                                       "solver")


@pytest.mark.parametrize("name", CASES)
def test_largest_violation_equals_the_violation_arrays(cases, name):
    p, pt, *_ = _setup(cases[name])
    assert largest_violation_of(p, pt) == largest_violation(violation_arrays(p, pt))


def test_largest_violation_counts_nan_as_infinite():
    p = Pendulum(N=4)
    U = p.initial_guess()
    pt = C.StagePoint(p, p.simulate(U), U)
    pt.g = pt.g.copy()
    pt.g[2, 0] = np.nan
    pt.h = pt.h.copy()
    pt.h[3, 1] = np.inf                 # an earlier array's infinite entry wins over the NaN
    assert largest_violation_of(p, pt) == largest_violation(violation_arrays(p, pt))
    assert largest_violation_of(p, pt)[1].array == "dynamics"
    pt.h[3, 1] = 0.0
    best, where = largest_violation_of(p, pt)
    assert (best, where) == largest_violation(violation_arrays(p, pt)) and best == np.inf
    assert (where.array, where.stage, where.kind) == ("stage_constraints", 2, "inequality")


@pytest.mark.parametrize("name", CASES)
def test_spot_check_equals_the_reference_bit_for_bit(cases, name):
    p, pt, bounds, W, *_ = _setup(cases[name])
    worst, directions, vals, ratio = _reference_spot_check(p, pt, bounds, W)
    Vx, Vu = C._directions(C._uniform_draws(C.CHECK_SEED, C.CHECK_DIRECTIONS, pt.X.size + pt.U.size), pt, bounds, W,
                           C.CHECK_STEP)
    assert np.array_equal(Vx, [v[0] for v in directions]) and np.array_equal(Vu, [v[1] for v in directions])
    counters = p.counters.copy()
    stacked = C._stacked_shifted_values(p, pt, Vx, Vu, C.CHECK_STEP)
    assert np.array_equal(stacked, vals)
    check = C.spot_check(p, pt, bounds, W)
    assert check.worst == worst and check.failed == (ratio.max() > 1.0)
    assert (name == "pendulum-wrong-derivative") == check.failed
    del counters


def test_zambezi_stacked_values_equal_the_default_and_count_alike():
    """Zambezi's one-pass _stacked_values against DOCP's (the stage functions one by one, the
    final cost point by point): the same numbers, the same counters."""
    from olado.problems.docp import DOCP
    z = zambezi_problem("zambezi12", N=24, start="balance")
    rng = np.random.default_rng(3)
    X = z.simulate(z.initial_guess())
    P = 5
    Xs = np.repeat(X[None, :-1], P, axis=0).reshape(-1, 6) * (1 + 1e-3 * rng.standard_normal((P * 24, 6)))
    Us = np.tile(z.initial_guess(), (P, 1)) + 1e-2 * rng.standard_normal((P * 24, 7))
    K, ends = np.tile(z._K, P), X[-1] + 1e-2 * rng.standard_normal((P, 6))
    z.reset_counters()
    fast = z._stacked_values(K, Xs, Us, ends)
    counted = dict(z.counters)
    z.reset_counters()
    slow = DOCP._stacked_values(z, K, Xs, Us, ends)
    assert counted == dict(z.counters) == {"final_cost": P}
    for a, b in zip(fast, slow, strict=True):
        assert a.shape == b.shape and np.array_equal(a, b)


def test_uniform_draws_are_the_generator_s_and_read_only():
    draw = C._uniform_draws(C.CHECK_SEED, 2, 17)
    assert np.array_equal(draw, np.random.default_rng(C.CHECK_SEED).uniform(-1.0, 1.0, (2, 17)))
    assert C._uniform_draws(C.CHECK_SEED, 2, 17) is draw and not draw.flags.writeable


@pytest.mark.parametrize("name", CASES)
def test_certificate_is_reproducible_and_leaves_the_counters(cases, name):
    """Two certificates of the same point (the second one on remembered draws and prepared
    bounds) are the same, and the problem's counters are as they were."""
    p, X, U, mult = cases[name]
    before = dict(p.counters)
    a, b = (C.certify(p, X, U, mult) for _ in range(2))
    a.time_s = b.time_s = 0.0
    assert repr(a) == repr(b) and dict(p.counters) == before      # repr: NaN fields compare equal
