"""The fused passes of the ipm loop (olado.solvers.ipm.kernels: trial_point, point_terms,
step_terms, step_bound_multipliers and the Bounds / solver functions around them) give, bit for
bit, what the numpy expressions and the separate passes they replace give -- on random data with
infinite bound sides, slacks within rounding of a bound (the slack move), points outside the
bounds, special values and zero-size parts -- and a solve through them takes the iterates of the
reference (numpy) forms, step for step."""

import numpy as np
import pytest

from olado.problems import PROBLEMS
from olado.problems.zambezi import zambezi_problem
from olado.errors import NonFiniteEvaluationError
from olado.solvers.ipm import evaluation as E, kernels, linesearch, solver as S
from olado.solvers.ipm.barrier import Bounds, Layout
from olado.solvers.ipm.newton import Residuals, Step

from test_barrier_kernels import (EPS, _bounds, _inside, _special, ref_barrier, ref_dual_step, ref_max_dual_step,
                                  ref_max_step, ref_move_tiny, ref_safeguard, ref_slacks)


class _Dims:
    """A problem's dimensions as barrier.Layout reads them."""

    def __init__(self, N, n, m, ni, niN, ne=0, neN=0):
        self.N, self.n, self.m, self.x0 = N, n, m, np.arange(n, dtype=float)
        self.stage_equality_mask = np.array([False] * ni + [True] * ne, dtype=bool)
        self.final_equality_mask = np.array([False] * niN + [True] * neN, dtype=bool)


#: (N, n, m, ni, niN): with and without slacks, a single stage, empty controls
SHAPES = [(7, 4, 3, 2, 1), (5, 3, 2, 0, 0), (1, 2, 1, 0, 2), (4, 2, 0, 1, 0), (0, 3, 2, 0, 0)]


def _case(seed, shape, special=False):
    rng = np.random.default_rng(seed)
    L = Layout(_Dims(*shape))
    b = _bounds(rng, L.size)
    v = _inside(rng, b)
    zl, zu = rng.exponential(size=v.size), rng.exponential(size=v.size)
    dv = rng.normal(size=v.size) * 10.0 ** rng.integers(-12, 3, size=v.size)
    if special:
        zl, zu, dv = _special(rng, zl), _special(rng, zu), _special(rng, dv)
    return rng, L, b, v, zl, zu, dv


def _special_nd(rng, x, share=0.05):
    """_special of an array of any shape."""
    return _special(rng, x.ravel(), share).reshape(x.shape)


def _same(x, y):
    return np.array_equal(x, y, equal_nan=True) and np.array_equal(np.signbit(x), np.signbit(y))


def _same_float(x, y):
    return x == y or (np.isnan(x) and np.isnan(y))


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("seed", range(3))
def test_trial_point_is_v_plus_alpha_dv_split(shape, seed):
    _, L, b, v, _, _, dv = _case(seed, shape, special=seed == 2)
    for alpha in (1.0, 0.37, 2.0 ** -20):
        v_t, X, U = np.empty_like(v), np.empty((L.N + 1, L.n)), np.empty((L.N, L.m))
        with np.errstate(all="ignore"):
            kernels.trial_point(v, dv, alpha, L.x0, v_t, X, U)
            want = v + alpha * dv
        assert _same(v_t, want)
        WX, WU = L.states_controls(want)
        assert _same(X, WX) and _same(U, WU)


def _residuals(rng, L, special=False):
    arrays = [rng.normal(size=(L.N, L.n)), rng.normal(size=(L.N, L.ne)), rng.normal(size=L.neN),
              rng.normal(size=(L.N, L.ni)), rng.normal(size=L.niN)]
    if special:
        arrays = [_special_nd(rng, a, 0.2) for a in arrays]
    return Residuals(*arrays)


def ref_norms(res):
    return float(sum(np.abs(a).sum() for a in res)), max((float(np.abs(a).max()) for a in res if a.size), default=0.0)


@pytest.mark.parametrize("shape", SHAPES + [(6, 3, 2, 2, 1, 1, 2)])
@pytest.mark.parametrize("seed", range(4))
def test_point_terms_are_the_residual_norms_and_the_barrier_value(shape, seed):
    """Bounds.point_terms (kernels.point_terms) against Residuals' numpy norms and the numpy
    barrier value, inside and outside the bounds; the point's cache then holds what
    Bounds.barrier_terms and Bounds.slacks compute."""
    rng, L, b, v, _, _, _ = _case(seed, shape)
    if seed == 3 and v.size:       # outside: one entry beyond its finite bound
        i = int(np.flatnonzero(b.has_lo)[0]) if b.has_lo.any() else None
        if i is not None:
            v[i] = b.lo[i] - 1.0
    res = _residuals(rng, L, special=seed == 2)
    mu = 0.03
    l1, mx, barrier = b.point_terms(v, res, mu)
    want_l1, want_max = ref_norms(res)
    assert _same_float(l1, want_l1) and _same_float(mx, want_max)
    with np.errstate(all="ignore"):
        want, _ = ref_barrier(b, v, mu)
    assert barrier == want
    fresh = Bounds(b.lo, b.hi, b.has_lo, b.has_hi)
    assert fresh.barrier_value(v, mu) == barrier
    for x, y in zip(b.slacks(v), fresh.slacks(v)):
        assert _same(x, y)
    # asked again at the same point: the cached terms
    again = b.point_terms(v, res, mu)
    assert all(_same_float(x, y) for x, y in zip(again, (l1, mx, barrier)))


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("seed", range(4))
def test_step_terms_are_pack_max_step_and_the_tiny_step_measure(shape, seed):
    rng, L, b, v, _, _, _ = _case(seed, shape, special=seed >= 2)
    scale = 10.0 ** rng.integers(-12, 3, size=4)
    step = Step(rng.normal(size=(L.N + 1, L.n)) * scale[0], rng.normal(size=(L.N, L.m)) * scale[1],
                rng.normal(size=(L.N, L.ni)) * scale[2], rng.normal(size=L.niN) * scale[3], None, None, None, None,
                None)
    if seed >= 2:
        step = Step(_special_nd(rng, step.dX), _special_nd(rng, step.dU), step.ds, step.dsN, *step[4:])
    for tau in (0.99, 1.0 - 1e-9):
        with np.errstate(all="ignore"):
            dv, alpha_max, tiny = b.step_terms(v, step, tau)
            want_dv = L.pack(step.dX, step.dU, step.ds, step.dsN)
            assert _same(dv, want_dv)
            assert _same_float(alpha_max, ref_max_step(b, v, want_dv, tau))
            assert _same_float(tiny, float(np.max(np.abs(want_dv) / (1 + np.abs(v)), initial=0.0)))


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("seed", range(6))
def test_step_bound_multipliers_are_the_separate_steps(shape, seed):
    """Bounds.step_multipliers against Bounds.dual_step_length, move_tiny and safeguard_step in
    turn (and those against their numpy forms), with steps that end within rounding of a bound
    (the slack move) and special values."""
    rng, L, b, v, zl, zu, dv = _case(seed, shape, special=seed >= 4)
    v_new = v + 0.5 * np.where(np.isfinite(dv), dv, 0.0)
    v_new = np.where(b.has_lo, np.maximum(v_new, b.lo + 1e-3), v_new)
    v_new = np.where(b.has_hi, np.minimum(v_new, b.hi - 1e-3), v_new)
    near = rng.random(v.size) < 0.2      # onto the bound: moved
    v_new[near & b.has_lo] = b.lo[near & b.has_lo] + EPS * 0.1
    ref = Bounds(b.lo.copy(), b.hi.copy(), b.has_lo, b.has_hi)
    for mu, tau in ((0.1, 0.99), (1e-11, 1.0 - 1e-9)):
        with np.errstate(all="ignore"):
            dzl, dzu, alpha_z = ref.dual_step_length(v, dv, zl, zu, mu, tau)
            rl, ru = ref_dual_step(ref, v, dv, zl, zu, mu)
            assert _same(dzl, rl) and _same(dzu, ru)
            assert _same_float(alpha_z, min(ref_max_dual_step(zl, rl, tau), ref_max_dual_step(zu, ru, tau)))
            lo, hi, count = ref_move_tiny(ref, v_new)
            assert ref.move_tiny(v_new) == count and _same(ref.lo, lo) and _same(ref.hi, hi)
            want = ref.safeguard_step(v_new, zl, zu, dzl, dzu, alpha_z, mu)
            for x, y in zip(want, ref_safeguard(ref, v_new, zl + alpha_z * rl, zu + alpha_z * ru, mu)):
                assert _same(x, y)
            lam, lam_step = rng.normal(size=(L.N + 1, L.n)), _special_nd(rng, rng.normal(size=(L.N + 1, L.n)))
            got_l, got_u, got_a, got_lam = b.step_multipliers(b.slacks(v), v_new, dv, zl, zu, mu, tau, lam, lam_step,
                                                              0.3)
            assert _same(got_lam, lam + 0.3 * (lam_step - lam))
        assert _same_float(got_a, alpha_z)
        assert _same(got_l, want[0]) and _same(got_u, want[1])
        assert _same(b.lo, ref.lo) and _same(b.hi, ref.hi)
        for x, y in zip(b.slacks(v_new), ref_slacks(ref, v_new)):      # cached after the move
            assert _same(x, y)


# ---------------------------------------------------------------------------- the same iterates
def _reference_trial(setup, st, dv, alpha):
    """linesearch._trial by the numpy forms it replaces (v + alpha dv, Layout.states_controls, the
    residual norms and the barrier value by their separate passes)."""
    v_t = st.v + alpha * dv
    try:
        pt = E.evaluate(setup, v_t, st.clock)
    except NonFiniteEvaluationError:
        return v_t, None, np.inf, np.inf
    res = E.residuals(setup, pt, v_t)
    l1, _ = ref_norms(res)
    return v_t, pt, l1, st.s_obj * pt.J + setup.bounds.barrier_value(v_t, st.mu)


@np.errstate(all="ignore")
def _reference_step_terms(self, v, step, tau, dv=None):
    dv = np.concatenate([step.dX[1:].ravel(), step.dU.ravel(), np.asarray(step.ds, float).ravel(),
                         np.asarray(step.dsN, float).ravel()])
    return dv, ref_max_step(self, v, dv, tau), float(np.max(np.abs(dv) / (1 + np.abs(v)), initial=0.0))


@np.errstate(all="ignore")
def _reference_step_multipliers(self, slacks, v_new, dv, zl, zu, mu, tau, lam, lam_step, alpha, kappa_sigma=1e10,
                                out=None):     # new arrays, not ``out``'s
    sl, su = slacks
    rl = np.where(self.has_lo, mu / sl - zl - zl / sl * dv, 0.0)
    ru = np.where(self.has_hi, mu / su - zu + zu / su * dv, 0.0)
    alpha_z = min(ref_max_dual_step(zl, rl, tau), ref_max_dual_step(zu, ru, tau))
    self.move_tiny(v_new)
    out = ref_safeguard(self, v_new, zl + alpha_z * rl, zu + alpha_z * ru, mu, kappa_sigma)
    return out[0], out[1], alpha_z, lam + alpha * (lam_step - lam)


def _reference_iterate_errors(setup, st):
    """evaluation.iterate_errors by its parts: einsum's products, the dual infeasibility's own pass
    (kernels.dual_infeasibility, itself checked against numpy in test_barrier_kernels), the
    numpy complementarity at mu = 0 and at the iterate's mu, and the numpy ranges of the products
    s z (test_start_costs.ref_product_ranges)."""
    from test_barrier_kernels import ref_complementarity
    from test_start_costs import ref_product_ranges

    p, pt, b = setup.problem, st.pt, setup.bounds
    lam = st.lam[1:]
    EA, EB = np.einsum("kij,ki->kj", pt.A, lam), np.einsum("kij,ki->kj", pt.B, lam)
    ECx, ECu, CNL = EA, EB, pt.lN
    if p.r or p.rN:
        Lg, LgN = E.full_multipliers(setup.layout, st)
        if p.r:
            ECx, ECu = np.einsum("kij,ki->kj", pt.Cx, Lg), np.einsum("kij,ki->kj", pt.Cu, Lg)
        if p.rN:
            CNL = pt.CN.T @ LgN
    mx, zsum, ysum = kernels.dual_infeasibility(float(st.s_obj), pt.lx, pt.lu, pt.lN, EA, EB, lam, ECx, ECu, CNL,
                                                bool(p.r), bool(p.rN), st.yd, st.ydN, st.zl, st.zu, st.nu, st.nuN)
    with np.errstate(all="ignore"):
        compl = tuple(ref_complementarity(b, st.v, st.zl, st.zu, m) for m in (0.0, st.mu))
        ranges = ref_product_ranges(b, st.v, st.zl, st.zu)
    return (float(mx), float(zsum), float(ysum)), compl, ranges


def _reference_newton_terms(setup, st):
    return (*setup.bounds.sigma_blocks(st.v, st.zl, st.zu, setup.layout), S.barrier_gradient(setup, st))


def _history(result):
    keys = ("alpha", "alpha_z", "soc", "objective", "inf_pr", "inf_du", "mu", "delta_w", "restoration")
    return [tuple(None if isinstance(h[k], float) and np.isnan(h[k]) else h[k] for k in keys) for h in result.history]


@pytest.mark.parametrize("problem", [
    lambda: zambezi_problem("zambezi12", N=12, start="balance"),
    lambda: PROBLEMS["rayleigh-mixed"](),
    lambda: PROBLEMS["obstacle"](),
])
def test_a_solve_takes_the_reference_iterates(problem, monkeypatch):
    """A solve with the fused passes and one with the numpy forms they replace (monkeypatched in)
    take the same steps: the same history (step lengths, objective, errors, mu, shifts), bit for
    bit, and the same result."""
    from olado.config import load_config, make_solver

    solver = make_solver(load_config("configs/ipm.ini"))
    fast = solver.solve(problem())
    with monkeypatch.context() as mp:
        mp.setattr(linesearch, "_trial", _reference_trial)
        mp.setattr(Bounds, "step_terms", _reference_step_terms)
        mp.setattr(Bounds, "step_multipliers", _reference_step_multipliers)
        mp.setattr(E, "iterate_errors", _reference_iterate_errors)     # error_terms, complementarity
        mp.setattr(S, "iterate_errors", _reference_iterate_errors)     # take_step
        mp.setattr(S, "_newton_terms", _reference_newton_terms)
        ref = solver.solve(problem())
    assert fast.status == ref.status and fast.iterations == ref.iterations
    assert _history(fast) == _history(ref)
    assert fast.objective == ref.objective and np.array_equal(fast.x, ref.x) and np.array_equal(fast.u, ref.u)


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("seed", range(4))
def test_two_complementarities_in_one_pass_are_the_numpy_forms(shape, seed):
    from test_barrier_kernels import ref_complementarity

    _, _, b, v, zl, zu, _ = _case(seed, shape, special=seed >= 2)
    for mu, mu1 in ((0.0, 0.1), (1e-9, 1e-9), (0.5, 0.0)):
        with np.errstate(all="ignore"):
            got = b.complementarities(v, zl, zu, mu, mu1)
            want = ref_complementarity(b, v, zl, zu, mu), ref_complementarity(b, v, zl, zu, mu1)
        assert all(_same_float(x, y) for x, y in zip(got, want))


@pytest.mark.parametrize("delta", [0.0, 1e-4, 3.7e8])
def test_shifted_diagonals_are_np_add(delta):
    rng = np.random.default_rng(3)
    for N, n, m in ((5, 3, 2), (1, 1, 0), (0, 2, 1)):
        Sx, Su = _special_nd(rng, rng.exponential(size=(N + 1, n))), rng.exponential(size=(N, m))
        Dx, Du = np.full((N + 1, n), np.nan), np.full((N, m), np.nan)
        kernels.shifted_diagonals(Sx, Su, delta, Dx, Du)
        want = Sx + delta
        want[0] = 0.0
        assert _same(Dx, want) and _same(Du, Su + delta)


def _sequential_products(A, lam):
    """A^T lam per stage, summed over i in order from 0 (the reference formula)."""
    out = np.zeros((A.shape[0], A.shape[2]))
    for i in range(A.shape[1]):
        out = out + A[:, i, :] * lam[:, i, None]
    return out


@pytest.mark.parametrize("seed", range(40))
def test_stage_products_are_the_sequential_sums_and_einsums(seed):
    """kernels.stage_products equals the sequential sums (the reference) and, where the solver
    uses it (evaluation._plain_products), numpy's einsum (whose order it follows there); one-entry
    rows and non-contiguous operands go to einsum."""
    rng = np.random.default_rng(seed)
    N, n, m = int(rng.integers(1, 40)), int(rng.integers(1, 12)), int(rng.integers(1, 12))
    if seed < 4:
        n, m = (1, 3, 2, 1)[seed], (3, 1, 1, 2)[seed]
    A = rng.normal(size=(N, n, n)) * 10.0 ** rng.integers(-8, 8, size=(N, n, n))
    B = rng.normal(size=(N, n, m)) * 10.0 ** rng.integers(-8, 8, size=(N, n, m))
    lam = (rng.normal(size=(N + 1, n)) * 10.0 ** rng.integers(-8, 8, size=(N + 1, n)))[1:]
    if seed == 5:
        A = np.ascontiguousarray(A.transpose(0, 2, 1)).transpose(0, 2, 1)      # not C-contiguous: einsum
    plain = E._plain_products(A, B, lam)
    assert plain == (n >= 2 and m >= 2 and seed != 5)
    EA, EB = np.full((N, n), np.nan), np.full((N, m), np.nan)
    kernels.stage_products(np.ascontiguousarray(A), B, lam, EA, EB)
    assert np.array_equal(EA, _sequential_products(A, lam)) and np.array_equal(EB, _sequential_products(B, lam))
    if plain:       # where the solver takes the compiled products: einsum's own values
        assert np.array_equal(EA, np.einsum("kij,ki->kj", A, lam))
        assert np.array_equal(EB, np.einsum("kij,ki->kj", B, lam))
    EA, EB = np.empty((0, n)), np.empty((0, m))
    kernels.stage_products(np.zeros((0, n, n)), np.zeros((0, n, m)), np.zeros((0, n)), EA, EB)
