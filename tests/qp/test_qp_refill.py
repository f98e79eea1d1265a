"""A prepared interior-point QP refilled with the next QP's numbers (InteriorPointQP._prepare,
_Prepared.refill: the QPs of an SQP solve) gives the same iterates, entry for entry, as a QP
prepared afresh: same shapes with other numbers, other finite box sides, a QP of other shapes in
between, a QP that eliminates fixed entries (prepared afresh, not kept), warm starts, and every
KKT back-end."""

import dataclasses

import numpy as np
import pytest

from fixtures.qp_problems import random_qp, replace
from olado.qp.interior_point import FrankeQP, GondzioQP, MehrotraQP
from olado.qp.stageqp import QPResult

_ARRAYS = [f.name for f in dataclasses.fields(QPResult) if f.name in
           ("X", "U", "lam", "nu", "zx_lower", "zx_upper", "zu_lower", "zu_upper", "yc_lower", "yc_upper",
            "yN_lower", "yN_upper")]


def assert_same(a, b):
    """Two results of the same iterates: equal arrays, counts, messages and histories."""
    assert a.status is b.status and a.message == b.message
    assert a.iterations == b.iterations and a.regularization == b.regularization
    for name in _ARRAYS:
        assert np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True), name
    assert a.history == b.history


def _sequence():
    """QPs in the order an SQP solve might send them, with warm starts (index of the result to
    start from, or None)."""
    q1 = random_qp(1, eq=True)
    q2 = random_qp(2, eq=True)
    # other finite sides: an upper bound removed, a lower bound added, a row side removed
    xl, xu, cl = q2.x_lower.copy(), q2.x_upper.copy(), q2.c_lower.copy()
    xu[2, 1] = np.inf
    xl[3, 2] = -2.0
    cl[1, 1] = -np.inf
    q3 = replace(q2, x_lower=xl, x_upper=xu, c_lower=cl)
    other = random_qp(4, N=5, eq=True)                   # other shapes
    fixed = random_qp(5, eq=True, fixed=True)            # fixed entries: prepared afresh
    q6 = random_qp(6, eq=True)
    return [(q1, None), (q2, 0), (q3, None), (other, None), (q2, 2), (fixed, None), (q6, None), (q6, 6)]


@pytest.mark.parametrize("cls, kkt", [(MehrotraQP, "riccati"), (GondzioQP, "riccati"), (FrankeQP, "riccati"),
                                      (MehrotraQP, "superlu-reduced")])
def test_refilled_qps_give_the_iterates_of_fresh_ones(cls, kkt):
    reused = cls(kkt=kkt, tol=1e-9)
    out_reused, out_fresh = [], []
    for qp, warm in _sequence():
        fresh = cls(kkt=kkt, tol=1e-9)
        r1 = reused.solve(qp, warm_start=None if warm is None else out_reused[warm])
        r2 = fresh.solve(qp, warm_start=None if warm is None else out_fresh[warm])
        assert r2.success
        assert_same(r1, r2)
        out_reused.append(r1)
        out_fresh.append(r2)


def test_the_prepared_qp_and_its_riccati_backend_are_reused():
    solver = MehrotraQP(tol=1e-9)
    solver.solve(random_qp(1, eq=True))
    (P,) = solver._prepared.values()
    fact, pool = P.fact, P.iterate_pool
    for seed in (2, 3):
        solver.solve(random_qp(seed, eq=True))
        assert list(solver._prepared.values()) == [P] and P.fact is fact
        assert P.iterate_pool is pool     # the start is written into one of the three iterate points
        assert P.qp is None     # the QP itself is not kept between solves
    # a QP with fixed entries is prepared afresh and not kept
    solver.solve(random_qp(5, eq=True, fixed=True))
    assert list(solver._prepared.values()) == [P]


def test_a_refill_writes_what_a_fresh_preparation_computes():
    from olado.qp.interior_point.presolve import _Prepared

    P = _Prepared(random_qp(1, eq=True))
    qp = random_qp(2, eq=True)
    assert P.refill(qp)
    ref = _Prepared(qp)
    for name in ("Q", "S", "R", "q", "r", "A", "B", "c", "x0", "E", "F", "e", "EN", "eN", "C", "CN", "lo", "hi",
                 "fl", "fu", "H", "QN", "AB", "EF", "EFt", "be", "Ct", "neg_lo", "qr", "Q_final"):
        assert np.array_equal(getattr(P, name), getattr(ref, name)), name
    for name in ("n_comp", "p_data", "d_data", "h_scale", "shift", "reg_rung"):
        assert getattr(P, name) == getattr(ref, name), name
    # not refilled: other shapes, fixed entries, a crossed box
    assert not P.refill(random_qp(3, N=5, eq=True))
    assert not P.refill(random_qp(3, eq=True, fixed=True))
    bad = random_qp(3, eq=True)
    bad.u_lower[2, 1], bad.u_upper[2, 1] = 1.0, 0.0
    assert not P.refill(bad)


def test_the_cold_start_is_the_centred_point_of_the_start_system():
    """initial_point (the start system solved by the prepared QP's own back-end, the point written
    in place) against the formulas: the least-distance system solved by a back-end of its own,
    t = max(w - lo, 1) resp. max(hi - w, 1) and z = mu0 / t on the finite sides, 0 elsewhere."""
    from olado.linalg.backend import make_kkt_solver
    from olado.qp.interior_point.presolve import _Prepared
    from olado.qp.interior_point.start import initial_point

    solver = MehrotraQP()
    for seed in (1, 2):
        qp = random_qp(seed, eq=True)
        P = solver._prepare(qp)
        it = initial_point(P, solver.options, mu0=3.0)
        ref = _Prepared(qp)
        D = 1.0
        two = ref.fl & ref.fu
        wref = np.where(two, 0.5 * (ref.lo + ref.hi),
                        np.clip(0.0, np.where(ref.fl, ref.lo, -np.inf), np.where(ref.fu, ref.hi, np.inf)))
        N, n, m, nc = ref.N, ref.n, ref.m, ref.nc
        q = ref.q.copy(); r = ref.r.copy()
        q[1:] -= D * wref[ref.sl_x].reshape(N, n); r -= D * wref[ref.sl_u].reshape(N, m)
        q[-1] -= D * (ref.CN.T @ wref[ref.sl_sN])
        Q = ref.Q.copy(); Q[-1] = Q[-1] + D * (ref.CN.T @ ref.CN)
        sol = make_kkt_solver("riccati", Q, ref.S, ref.R, ref.A, ref.B, Dx=np.full((N + 1, n), D),
                              Du=np.full((N, m), D), Ci=ref.C, sigma=np.full((N, nc), D), E=ref.E, F=ref.F,
                              n_eq=ref.n_eq, EN=ref.EN).solve(q, r, ref.c, ref.x0, e=ref.e, eN=ref.eN,
                                                              ci=-D * wref[ref.sl_s].reshape(N, nc))
        w = ref.w_of(sol.X, sol.U)
        tl = np.where(ref.fl, np.maximum(w - ref.lo, 1.0), 0.0)
        tu = np.where(ref.fu, np.maximum(ref.hi - w, 1.0), 0.0)
        expected = dict(X=sol.X, U=sol.U, lam=sol.lam, nu=sol.nu, tl=tl, tu=tu,
                        zl=np.where(ref.fl, 3.0 / np.where(ref.fl, tl, 1.0), 0.0),
                        zu=np.where(ref.fu, 3.0 / np.where(ref.fu, tu, 1.0), 0.0))
        for name, value in expected.items():
            assert np.array_equal(getattr(it, name), value), name


def test_the_warm_start_is_the_pushed_point_of_the_result():
    """warm_point (written in place) against the formulas: X, U, lam, nu of the result, the box
    multipliers flat (NaN -> 0), theta = push (1 + max |z|), t = max(w - lo, theta) resp.
    max(hi - w, theta) and z = max(z, theta) on the finite sides, 0 elsewhere."""
    from olado.qp.interior_point.start import warm_point

    solver = MehrotraQP(warm_start_push=1e-3)
    ws = solver.solve(random_qp(1, eq=True))
    ws.zu_lower[0, 0] = np.nan
    qp = random_qp(2, eq=True)
    P = solver._prepare(qp)
    it = warm_point(P, solver.options, ws)
    flat = lambda *a: np.concatenate([np.ravel(v) for v in a])  # noqa: E731
    zl = np.nan_to_num(flat(ws.zx_lower[1:], ws.zu_lower, ws.yc_lower, ws.yN_lower))
    zu = np.nan_to_num(flat(ws.zx_upper[1:], ws.zu_upper, ws.yc_upper, ws.yN_upper))
    theta = 1e-3 * (1.0 + np.max(np.abs(np.concatenate([zl, zu]))))
    w = P.w_of(ws.X, ws.U)
    expected = dict(X=ws.X, U=ws.U, lam=ws.lam, nu=ws.nu, tl=np.where(P.fl, np.maximum(w - P.lo, theta), 0.0),
                    tu=np.where(P.fu, np.maximum(P.hi - w, theta), 0.0), zl=np.where(P.fl, np.maximum(zl, theta), 0.0),
                    zu=np.where(P.fu, np.maximum(zu, theta), 0.0))
    for name, value in expected.items():
        assert np.array_equal(getattr(it, name), value), name


@pytest.mark.parametrize("where", [None, "c", "r", "S"])
def test_the_data_scales_are_the_maxima_of_the_parts(where):
    """p_data, d_data, h_scale (one reduction per group) against Python's max of each part's
    numpy max |.| -- with a NaN in one part, the NaN rule of that formula."""
    from olado.qp.interior_point.presolve import _Prepared

    qp = random_qp(3, eq=True)
    if where is not None:
        getattr(qp, where)[1, 0] = np.nan
    P = _Prepared(qp)
    fin = lambda a: float(np.abs(a).max(initial=0.0))  # noqa: E731
    expected = (max(fin(P.c), fin(P.x0), fin(P.e), fin(P.eN), fin(P.lo), fin(P.hi)), max(fin(P.q), fin(P.r)),
                max(fin(P.Q), fin(P.R), fin(P.S)))
    assert np.array_equal([P.p_data, P.d_data, P.h_scale], expected, equal_nan=True)


def test_a_qp_ended_by_its_time_limit_releases_the_qp_and_the_limits():
    """A QP stopped by the solve's limits (StopRequested through solve) still drops its kept
    preparation's references to the QP and the limits."""
    from olado.interrupts import Limits, StopRequested

    solver = MehrotraQP(tol=1e-9)
    solver.solve(random_qp(1, eq=True))
    limits = Limits(max_time=0.0)
    limits.armed = 1           # as inside a solver's catch block: check() raises
    with pytest.raises(StopRequested):
        solver.solve(random_qp(2, eq=True), limits=limits)
    for P in solver._prepared.values():
        assert P.qp is None and P.limits is None
        assert P.fact is None or P.fact.limits is None
