"""The cheaper start and error terms of the ipm solver give the same numbers as before, bit for bit:
the complementarity max |s z - mu| of every mu from the ranges of the products s z
(evaluation.products_complementarity, kernels.complementarity_ranges) against the numpy form, on random data
with special values and on products within rounding of mu; the least-squares multipliers' matrix
handed to the first Newton matrix (restoration.least_squares_multipliers(hand_over=True)) against
a first Newton matrix of its own; and a solve's barrier updates without further error passes."""

import math

import numpy as np
import pytest

from olado.config import load_config, make_solver
from olado.problems import PROBLEMS
from olado.problems.zambezi import zambezi_problem
from olado.solvers.ipm import evaluation as E, kernels, linesearch, solver as S
from olado.solvers.ipm.barrier import _sides_max
from olado.solvers.ipm.restoration import largest_multiplier, least_squares_multipliers
from olado.solvers.sqp.state import Clock

from test_barrier_kernels import _bounds, _inside, _special, ref_complementarity, ref_slacks


def ref_product_ranges(b, v, zl, zu):
    """(n_lo, min, max, n_hi, min, max) of the products s_L z_L over has_lo and s_U z_U over has_hi
    by numpy (min inf, max -inf for an empty side; numpy's min and max propagate a NaN)."""
    sl, su = ref_slacks(b, v)
    out = []
    for p in ((sl * zl)[b.has_lo], (su * zu)[b.has_hi]):
        out += [p.size, float(p.min()) if p.size else math.inf, float(p.max()) if p.size else -math.inf]
    return tuple(out)


def _same_float(x, y):
    """Equal as floats, a NaN equal to a NaN, and a zero's sign the same."""
    if x != x or y != y:
        return x != x and y != y
    return x == y and math.copysign(1.0, x) == math.copysign(1.0, y)


def _case(seed, size=2001):
    rng = np.random.default_rng(seed)
    b = _bounds(rng, size)
    v = _inside(rng, b)
    zl, zu = rng.exponential(size=v.size), rng.exponential(size=v.size)
    if seed % 3 == 1:                # special values (0, -0, +-inf, NaN) in the multipliers
        zl, zu = _special(rng, zl, 0.002), _special(rng, zu, 0.002)
    return rng, b, v, zl, zu


def _mus(rng, ranges):
    """Barrier parameters at and within rounding of the products' ends, and the usual ones."""
    mus = [0.0, 1e-300, 1e-11, 1e-9, 2e-4, 0.1, 0.5, 1.0, 3.0, 1e20]
    for x in ranges[1:3] + ranges[4:6]:
        if math.isfinite(x) and x >= 0:
            mus += [x, np.nextafter(x, np.inf), np.nextafter(x, 0.0), 0.5 * x, 2.0 * x]
    return mus + list(rng.exponential(size=5))


@pytest.mark.parametrize("seed", range(9))
def test_complementarity_ranges_are_numpys(seed):
    """kernels.complementarity_ranges: the complementarities at two mu and the products' ranges
    as numpy has them (the counts, maxima and the ranges' ends, NaN and zero signs included)."""
    _, b, v, zl, zu = _case(seed)
    sl, su = b.slacks(v)
    for mu, mu1 in ((0.0, 0.1), (1e-9, 1e-9), (0.5, 0.0)):
        n_lo, m_lo, m_lo1, n_hi, m_hi, m_hi1, *ends = kernels.complementarity_ranges(sl, su, zl, zu, b.has_lo,
                                                                                      b.has_hi, mu, mu1)
        with np.errstate(all="ignore"):
            want = ref_product_ranges(b, v, zl, zu)
            got = (n_lo, ends[0], ends[1], n_hi, ends[2], ends[3])
            assert all(_same_float(float(x), float(y)) for x, y in zip(got, want))
            for m, (lo, hi) in ((mu, (m_lo, m_hi)), (mu1, (m_lo1, m_hi1))):
                assert _same_float(_sides_max(n_lo, lo, n_hi, hi), ref_complementarity(b, v, zl, zu, m))


@pytest.mark.parametrize("seed", range(9))
def test_complementarity_from_the_ranges_is_the_numpy_form(seed):
    rng, b, v, zl, zu = _case(seed)
    with np.errstate(all="ignore"):
        ranges = ref_product_ranges(b, v, zl, zu)
        for mu in _mus(rng, ranges):
            assert _same_float(E.products_complementarity(ranges, mu), ref_complementarity(b, v, zl, zu, mu)), mu


def test_complementarity_from_the_ranges_within_rounding_of_mu():
    """Products a few ulps either side of mu (where fl(p - mu) rounds) and exact ties: the largest
    |fl(p - mu)| is at the smallest or the largest product, as the numpy form finds it."""
    rng = np.random.default_rng(7)
    for _ in range(300):
        mu = float(10.0 ** rng.uniform(-12, 2))
        steps = rng.integers(-40, 40, size=int(rng.integers(1, 6)))
        p = np.array([mu * (1.0 + float(k) * 2.0 ** -52 * float(rng.uniform(0.5, 8.0))) for k in steps] +
                     list(mu * rng.uniform(0.0, 2.0, size=int(rng.integers(0, 3)))))
        side_lo = rng.random(p.size) < 0.6
        lo, hi = p[side_lo], p[~side_lo]
        ranges = (lo.size, lo.min(initial=math.inf), lo.max(initial=-math.inf),
                  hi.size, hi.min(initial=math.inf), hi.max(initial=-math.inf))
        parts = [np.abs(lo - mu), np.abs(hi - mu)]
        want = max((float(q.max()) for q in parts if q.size), default=0.0)
        assert _same_float(E.products_complementarity(ranges, mu), want)


def test_complementarity_of_no_bounds_is_zero():
    assert _same_float(E.products_complementarity((0, math.inf, -math.inf, 0, math.inf, -math.inf), 0.1), 0.0)


def _start(problem):
    solver = make_solver(load_config("configs/ipm.ini"))
    setup = S.Setup(solver.options, problem, S.Limits(), lambda info: False)
    X0, U0 = solver.initial_point(problem, None)
    return setup, S.initial_state(setup, X0, U0, Clock())


@pytest.mark.parametrize("make", [
    lambda: zambezi_problem("zambezi12", N=12, start="balance"),
    lambda: PROBLEMS["rayleigh-mixed"](),
    lambda: PROBLEMS["obstacle"](),
])
def test_the_first_newton_matrix_takes_the_multipliers_matrix_over(make):
    """The start hands the least-squares system's factored matrix to the first Newton matrix,
    which takes its back-end over; the Newton step is the one of a matrix of its own, bit for bit
    (the take-over sets every block and factors afresh)."""
    setup, st = _start(make())
    lsq = setup.last_kkt
    assert lsq is not None and lsq.kkt is not None
    backend = lsq.kkt
    kkt, g = S.newton_system(setup, st, gradient=True)
    assert kkt.kkt is backend and lsq.kkt is None
    step = linesearch.direction(setup, st, kkt, g).step
    taken = [np.array(a, copy=True) for a in step]

    setup2, st2 = _start(make())
    setup2.last_kkt = None          # a first Newton matrix with a back-end of its own
    kkt2, g2 = S.newton_system(setup2, st2, gradient=True)
    assert kkt2.kkt is not backend and kkt2.delta == kkt.delta
    own = linesearch.direction(setup2, st2, kkt2, g2).step
    assert all(np.array_equal(a, b) for a, b in zip(taken, own))


def test_the_multipliers_without_hand_over_leave_the_last_matrix():
    setup, st = _start(zambezi_problem("zambezi12", N=12, start="balance"))
    kept = setup.last_kkt
    least_squares_multipliers(setup, st.pt, st.zl, st.zu, st.s_obj)
    assert setup.last_kkt is kept


def test_barrier_updates_take_no_further_error_pass(monkeypatch):
    """A solve lowers mu several times at one iterate (update_barrier); each new mu's
    complementarity comes from the cached product ranges: one error pass per iterate (the start
    and each accepted step), none for the barrier updates, and the same history as a solve whose
    complementarity is the numpy form at every mu."""
    problem = lambda: zambezi_problem("zambezi12", N=24, start="balance")  # noqa: E731
    solver = make_solver(load_config("configs/ipm.ini"))
    monkeypatch.setattr(S, "plain_path", lambda setup: None)   # the Python path's iterations
    calls = [0]
    passes = E.iterate_errors

    def counted(setup, st):
        calls[0] += 1
        return passes(setup, st)

    with monkeypatch.context() as mp:
        mp.setattr(E, "iterate_errors", counted)        # error_terms, complementarity
        mp.setattr(S, "iterate_errors", counted)        # take_step
        fast = solver.solve(problem())
    mus = [h["mu"] for h in fast.history]
    assert len(set(mus)) >= 4                       # mu fell several times
    assert calls[0] == fast.iterations + 1          # the start's pass and one per accepted step

    def numpy_complementarity(setup, st, mu):
        with np.errstate(all="ignore"):
            return ref_complementarity(setup.bounds, st.v, st.zl, st.zu, mu)

    with monkeypatch.context() as mp:
        mp.setattr(E, "complementarity", numpy_complementarity)     # optimality_errors
        ref = solver.solve(problem())
    keys = ("alpha", "alpha_z", "objective", "inf_pr", "inf_du", "mu", "delta_w")
    assert [tuple(h[k] for k in keys) for h in fast.history] == [tuple(h[k] for k in keys) for h in ref.history]
    assert fast.objective == ref.objective and np.array_equal(fast.x, ref.x)


def test_largest_multiplier_is_the_generator_form():
    """The multipliers' size tested against constr_mult_init_max: the same float as
    max((float(np.abs(a).max(initial=0.0)) for a in arrays), default=0.0), empty arrays, NaN
    (kept only where Python's max keeps it) and -0 included."""
    rng = np.random.default_rng(11)
    pool = [np.zeros((3, 0)), np.zeros(0), np.array([np.nan, 1.0]), np.array([-0.0]), np.array([2.0, -5.0]),
            rng.normal(size=(4, 3)), np.array([np.inf]), np.array([[np.nan]])]
    for _ in range(400):
        arrays = [pool[i] for i in rng.integers(0, len(pool), size=int(rng.integers(0, 6)))]
        want = max((float(np.abs(a).max(initial=0.0)) for a in arrays), default=0.0)
        assert _same_float(largest_multiplier(arrays), want)
