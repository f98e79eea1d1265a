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
    fact = P.fact
    for seed in (2, 3):
        solver.solve(random_qp(seed, eq=True))
        assert list(solver._prepared.values()) == [P] and P.fact is fact
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
