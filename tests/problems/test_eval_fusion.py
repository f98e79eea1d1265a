"""Zambezi's one-pass evaluations decide once per instance what they may bypass (the _Fusion
record of olado.problems.zambezi) and take a C-ordered point without converting it: the same
bits and counters as the per-function path of DOCP for any point layout and weight, the record
renewed when an attribute of the instance is set or deleted, and a NaN or inf still named by
function, stage and array exactly as the per-function path names it."""

import copy
import pickle

import numpy as np
import pytest

from olado.errors import NonFiniteEvaluationError
from olado.problems import DOCP
from olado.problems.zambezi import Zambezi, zambezi_problem
from olado.solvers.sqp.state import Clock, Point
from test_eval_point import _point, _same


def _all(p, X, U, sigma, P):
    """Values, first derivatives and Hessian blocks of the instance's entry points."""
    return (list(p.eval_values(X, U)) + list(p.eval_first_derivatives(X, U))
            + list(p.eval_stage_hessians(X, U, sigma, P, np.zeros((p.N, 0)))) + [p.eval_final_hessian(X[-1], sigma)])


def _reference(p, X, U, sigma, P):
    """The same through DOCP's per-function path (the stage functions called one by one)."""
    return (list(DOCP.eval_values(p, X, U)) + list(DOCP.eval_first_derivatives(p, X, U))
            + list(DOCP.eval_stage_hessians(p, X, U, sigma, P, np.zeros((p.N, 0))))
            + [DOCP.eval_final_hessian(p, X[-1], sigma)])


@pytest.mark.parametrize("layout", ["C", "F", "strided", "list"])
def test_any_point_layout_gives_the_per_function_bits(layout):
    """A C-ordered point goes to the kernels as it is; a Fortran-ordered, strided or list point
    is converted first: the same numbers as DOCP's path in every case."""
    p = zambezi_problem("zambezi12", N=24)
    X, U = _point(p, 1)
    P = np.random.default_rng(2).standard_normal((24, 6))
    ref = _reference(p, X, U, 1.0, P)
    if layout == "F":
        X, U = np.asfortranarray(X), np.asfortranarray(U)
    elif layout == "strided":
        X = np.repeat(X, 2, axis=1)[:, ::2]
        U = np.repeat(U, 2, axis=1)[:, ::2]
        assert not X.flags.c_contiguous
    elif layout == "list":
        X, U = X.tolist(), U.tolist()
    _same(_all(p, X, U, 1.0, P), ref)


def test_weights_follow_sigma_and_are_not_shared_with_the_caller():
    """sigma changes between calls (the weight vector of the last one is remembered): each call
    gives the bits of DOCP's path, -0.0 included."""
    p = zambezi_problem("zambezi12", N=12)
    X, U = _point(p, 3)
    P = np.random.default_rng(4).standard_normal((12, 6))
    for sigma in (1.0, 0.5, 0.5, np.float64(0.25), 1.0, 0.0, -0.0, 0.0, 1e-300):
        got = p.eval_stage_hessians(X, U, sigma, P)
        ref = DOCP.eval_stage_hessians(p, X, U, sigma, P)
        _same(got, ref)
        for a, b in zip(got, ref):
            assert np.array_equal(np.signbit(a), np.signbit(b))
    assert not p._fusion.weights(1.0, 12).flags.writeable


def test_setting_an_attribute_renews_the_decision():
    """A function or the derivative option set on the instance after the fused path was used is
    honoured at the next call; deleting it again restores the fused path and its bits."""
    p = zambezi_problem("zambezi12", N=12)
    X, U = _point(p)
    fused = p.eval_values(X, U)
    p.stage_cost = lambda k, x, u: Zambezi.stage_cost(p, k, x, u) * 2.0
    assert p.eval_values(X, U).J == pytest.approx(2.0 * fused.J - p.final_cost(X[-1]), rel=1e-12)
    del p.stage_cost
    _same(p.eval_values(X, U), fused)
    p.derivatives = "fd"            # finite differences: the per-function path, its counters
    before = p.counters.copy()
    d = p.eval_first_derivatives(X, U)
    assert (p.counters - before)["stage_cost"] > 1
    p.derivatives = "auto"
    _same(p.eval_first_derivatives(X, U), DOCP.eval_first_derivatives(p, X, U))
    np.testing.assert_allclose(d.lx, p.eval_first_derivatives(X, U).lx, rtol=1e-5, atol=1e-5)


def test_copies_and_pickles_evaluate_alike():
    p = zambezi_problem("zambezi12", N=12)
    X, U = _point(p)
    P = np.ones((12, 6))
    ref = _all(p, X, U, 1.0, P)
    for q in (copy.copy(p), copy.deepcopy(p), pickle.loads(pickle.dumps(p))):
        _same(_all(q, X, U, 1.0, P), ref)


def _message(fn, *args):
    with pytest.raises(NonFiniteEvaluationError) as e:
        fn(*args)
    return str(e.value)


@pytest.mark.parametrize("stage", [0, 5, 23])
def test_a_nan_at_a_stage_is_named_as_before(stage):
    """A NaN in the states of one stage: the fused passes fall back and every entry point --
    and the solvers' Point -- raises the per-function path's error, naming the function, the
    stage and the array."""
    p = zambezi_problem("zambezi12", N=24)
    X, U = _point(p, 5)
    X = X.copy()
    X[stage, 0] = np.nan
    P = np.ones((24, 6))
    got = _message(p.eval_values, X, U)
    assert got == _message(lambda *a: DOCP.eval_values(p, *a), X, U)
    assert f"stage k={stage}" in got and "stage_cost()" in got and "'cost'" in got
    assert _message(Point, p, X, U, False, Clock()) == got
    got = _message(p.eval_first_derivatives, X, U)
    assert got == _message(lambda *a: DOCP.eval_first_derivatives(p, *a), X, U)
    assert f"stage k={stage}" in got
    got = _message(p.eval_stage_hessians, X, U, 1.0, P)
    assert got == _message(lambda *a: DOCP.eval_stage_hessians(p, *a), X, U, 1.0, P)
    assert f"stage k={stage}" in got and "stage_hessian()" in got


def test_point_counts_its_evaluations():
    """Point's values and derivatives are counted by kind on the solve's clock."""
    p = zambezi_problem("zambezi12", N=12)
    X, U = _point(p)
    clock = Clock()
    pt = Point(p, X, U, derivatives=False, clock=clock)
    assert clock.counts["objective"] == clock.counts["constraints"] == 1 and clock.counts["gradient"] == 0
    pt.add_derivatives(p)
    pt.add_derivatives(p)             # once per point
    assert clock.counts["gradient"] == clock.counts["jacobian"] == 1
    np.testing.assert_array_equal(pt.h, p.eval_values(X, U).f - X[1:])
