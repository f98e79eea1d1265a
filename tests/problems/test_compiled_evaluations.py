"""A DOCP's compiled evaluations (olado/problems/compiled.py, DOCP.compiled_evaluations) called
as numba first-class functions from a compiled kernel: Zambezi's four give the bits of its Python
entry points (eval_values, eval_first_derivatives, eval_stage_hessians, eval_final_hessian) and
name the counters those add; a non-finite value gives NaN / False; a replaced function or
finite-difference derivatives give None; a kernel receiving them is loaded from numba's cache in
a second process."""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import textwrap

import numba as nb
import numpy as np
import pytest

from olado.problems import DOCP
from olado.problems.compiled import DERIVATIVES, FINAL_HESSIAN, HESSIANS, VALUES, CompiledEvaluations
from olado.problems.testproblems import PROBLEMS
from olado.problems import zambezi_kernels as kernels
from olado.problems.zambezi import Zambezi, zambezi_problem
from test_eval_point import _point


@nb.njit(cache=True)
def _call_all(values, derivatives, hessians, final_hessian, data, idata, X, U, sigma, P):
    """A receiving kernel: each of the four functions once, outputs allocated here."""
    N, n, m = U.shape[0], X.shape[1], U.shape[1]
    f, cost = np.empty((N, n)), np.empty(N)
    J = values(data, idata, X, U, f, cost)
    lx, lu, lN = np.empty((N, n)), np.empty((N, m)), np.empty(n)
    A, B = np.empty((N, n, n)), np.empty((N, n, m))
    ok_d = derivatives(data, idata, X, U, lx, lu, lN, A, B)
    hxx, hxu, huu = np.empty((N, n, n)), np.empty((N, n, m)), np.empty((N, m, m))
    ok_h = hessians(data, idata, X, U, sigma, P, hxx, hxu, huu)
    H = np.full((n, n), np.nan)
    ok_f = final_hessian(data, idata, X[N], sigma, H)
    return J, f, cost, ok_d, lx, lu, lN, A, B, ok_h, hxx, hxu, huu, ok_f, H


def _compiled(ev, X, U, sigma, P):
    return _call_all(ev.values, ev.derivatives, ev.hessians, ev.final_hessian, ev.data, ev.idata,
                     np.ascontiguousarray(X), np.ascontiguousarray(U), sigma, np.ascontiguousarray(P))


def _equal(a, b):
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.dtype == b.dtype
    assert np.array_equal(a, b)


def _counted(p, method, *args):
    before = p.counters.copy()
    out = getattr(p, method)(*args)
    return out, p.counters - before


@pytest.mark.parametrize("family", ["zambezi", "zambezi12"])
@pytest.mark.parametrize("N", [12, 36, 252])
@pytest.mark.parametrize("where", ["balance", "perturbed"])
def test_compiled_functions_give_the_entry_points_bits(family, N, where):
    p = zambezi_problem(family, N=N)
    if where == "balance":
        U = p.initial_guess()
        X = p.simulate(U)
    else:
        X, U = _point(p, seed=N)
    P = np.random.default_rng(N).standard_normal((N, 6))
    sigma = 0.7
    ev = p.compiled_evaluations()
    assert isinstance(ev, CompiledEvaluations)
    (J, f, cost, ok_d, lx, lu, lN, A, B, ok_h, hxx, hxu, huu, ok_f, H) = _compiled(ev, X, U, sigma, P)

    values, c_values = _counted(p, "eval_values", X, U)
    assert type(J) is float and J == values.J
    _equal(f, values.f)
    _equal(cost, p.eval_stage_costs(X, U))
    first, c_first = _counted(p, "eval_first_derivatives", X, U)
    assert ok_d
    for got, ref in zip((lx, lu, lN, A, B), first[:5]):
        _equal(got, ref)
    stage, c_stage = _counted(p, "eval_stage_hessians", X, U, sigma, P)
    assert ok_h
    for got, ref in zip((hxx, hxu, huu), stage):
        _equal(got, ref)
    final, c_final = _counted(p, "eval_final_hessian", X[-1], sigma)
    assert ok_f
    _equal(H, final)

    counted = {"values": c_values, "derivatives": c_first, "hessians": c_stage, "final_hessian": c_final}
    assert set(ev.counters) == set(counted)
    for kind, diff in counted.items():
        assert dict(diff) == {key: 1 for key in ev.counters[kind]}, kind


def test_the_signatures_and_the_objects():
    """The functions carry their signatures and numba types and are shared by every call and
    instance (a pickled one finds its address again); the data are packed at each call (an array
    changed in place is seen)."""
    p = zambezi_problem("zambezi12", N=24)
    ev = p.compiled_evaluations()
    for fn, sig in zip(ev[:4], (VALUES, DERIVATIVES, HESSIANS, FINAL_HESSIAN)):
        assert fn.signature() == sig and nb.typeof(fn) == nb.types.FunctionType(sig)
        assert isinstance(fn.__wrapper_address__(), int) and fn.__wrapper_address__() != 0
    assert ev.data.flags.c_contiguous and ev.data.dtype == np.float64
    assert ev.idata.flags.c_contiguous and ev.idata.dtype == np.int64
    again = p.compiled_evaluations()
    assert again.values is ev.values and again.data is not ev.data     # the code shared, the data not
    assert np.array_equal(again.data, ev.data) and np.array_equal(again.idata, ev.idata)
    assert zambezi_problem("zambezi12", N=24).compiled_evaluations().values is ev.values
    copied = pickle.loads(pickle.dumps(ev.values))
    assert copied.__wrapper_address__() == ev.values.__wrapper_address__()
    X, U = _point(p)
    P = np.zeros((24, 6))
    p.inflow[3, 1] += 0.25
    p.phi[2] *= 1.5
    got = _compiled(p.compiled_evaluations(), X, U, 1.0, P)
    assert got[0] == p.eval_values(X, U).J
    _equal(got[14], p.eval_final_hessian(X[-1], 1.0))


def test_the_entries_call_the_kernels_with_the_python_paths_types():
    """The entries hand the kernels Fortran-ordered fa, fe, fh and writable _LX, _LU, _JCOLS, as
    the Python entry points do: one compiled version of each kernel serves both (a second one
    would add seconds to a cold start)."""
    p = zambezi_problem("zambezi12", N=12)
    X, U = _point(p)
    P = np.ones((12, 6))
    p.eval_values(X, U), p.eval_first_derivatives(X, U), p.eval_stage_hessians(X, U, 1.0, P)
    _compiled(p.compiled_evaluations(), X, U, 1.0, P)
    checks = {kernels._values_kernel: ((6, 7, 13), ()), kernels._derivatives_kernel: ((6, 7, 13), (15, 16)),
              kernels._stage_hessian_kernel: ((5, 6), (11, 12, 13))}
    for kernel, (fortran, writable) in checks.items():
        for sig in kernel.signatures:
            assert all(sig[i].layout == "F" for i in fortran), kernel
            assert all(sig[i].mutable for i in writable), kernel
    assert len(kernels._values_kernel.signatures) == len(kernels._derivatives_kernel.signatures) == 1


def test_a_value_not_finite_gives_nan_or_false():
    p = zambezi_problem("zambezi12", N=12)
    ev = p.compiled_evaluations()
    X, U = _point(p)
    P = np.zeros((12, 6))
    X[5, 2] = np.nan
    out = _compiled(ev, X, U, 1.0, P)
    assert np.isnan(out[0]) and not out[3] and not out[9] and out[13]
    X, U = _point(p)
    U[3, 0] = np.inf
    out = _compiled(ev, X, U, 1.0, P)
    assert np.isnan(out[0]) and not out[3] and not out[9]
    X, U = _point(p)
    out = _compiled(ev, X, U, np.inf, P)
    assert out[0] == p.eval_values(X, U).J and out[3] and not out[9] and not out[13]


class _OwnCost(Zambezi):
    def stage_cost(self, k, x, u):
        return 2.0 * super().stage_cost(k, x, u)


class _OwnHessian(Zambezi):
    def final_hessian(self, x, sigma, lam):
        return super().final_hessian(x, sigma, lam)


def test_no_compiled_evaluations_when_the_entry_points_do_not_fuse():
    """A replaced function (subclass or instance) or finite-difference derivatives: None, as the
    entry points then take DOCP's per-function path; deleting the instance's function restores them."""
    assert _OwnCost("zambezi12", N=12).compiled_evaluations() is None
    assert _OwnHessian("zambezi12", N=12).compiled_evaluations() is None
    assert zambezi_problem("zambezi12", N=12, derivatives="fd").compiled_evaluations() is None
    p = zambezi_problem("zambezi12", N=12)
    ev = p.compiled_evaluations()
    p.dynamics = lambda k, x, u: Zambezi.dynamics(p, k, x, u)
    assert p.compiled_evaluations() is None
    del p.dynamics
    again = p.compiled_evaluations()
    assert again is not None and again.values is ev.values


class _Penalized(Zambezi):
    """A subclass that changes an entry point itself (not a stage function)."""

    def eval_values(self, X, U):
        J, f, g, gN = super().eval_values(X, U)
        return type(super().eval_values(X, U))(J + 1.0, f, g, gN)


def test_no_compiled_evaluations_when_an_entry_point_is_replaced():
    """The compiled evaluations stand for Zambezi's own eval_values, eval_first_derivatives,
    eval_stage_hessians and eval_final_hessian: a subclass or an instance replacing one gets None,
    and ipm then solves through the replacement (its objective shifted by exactly 1)."""
    from olado.solvers.ipm.solver import IPMSolver

    assert _Penalized("zambezi12", N=12).compiled_evaluations() is None
    p = zambezi_problem("zambezi12", N=12)
    p.eval_final_hessian = p.eval_final_hessian
    assert p.compiled_evaluations() is None
    shifted = IPMSolver().solve(_Penalized("zambezi12", N=12))
    plain = IPMSolver().solve(zambezi_problem("zambezi12", N=12))
    assert shifted.objective == pytest.approx(plain.objective + 1.0, rel=1e-12, abs=1e-12)


def test_docp_default_is_none():
    p = PROBLEMS["vanderpol"](N=5)
    assert type(p).compiled_evaluations is DOCP.compiled_evaluations
    assert p.compiled_evaluations() is None


_SCRIPT = """
import numba as nb
import numpy as np
from olado.problems.zambezi import zambezi_problem
from olado.problems.zambezi_kernels import _compiled_entries


@nb.njit(cache=True)
def receive(values, data, idata, X, U):
    f, cost = np.empty((U.shape[0], X.shape[1])), np.empty(U.shape[0])
    return values(data, idata, X, U, f, cost)


p = zambezi_problem("zambezi12", N=24)
ev = p.compiled_evaluations()
U = p.initial_guess()
X = p.simulate(U)
J = receive(ev.values, ev.data, ev.idata, X, U)
assert J == p.eval_values(X, U).J
entries = sum(sum(e.dispatcher._cache_hits.values()) for e in _compiled_entries())
print(sum(receive._cache_hits.values()), sum(receive._cache_misses.values()), entries)
"""


@pytest.mark.slow
def test_a_receiving_kernel_is_loaded_from_the_cache_in_a_second_process(tmp_path):
    """A kernel taking the function pointers is cached on disk (its argument type is the
    signature): the second process loads it and the four entries from numba's cache."""
    script = tmp_path / "receiver.py"
    script.write_text(textwrap.dedent(_SCRIPT))
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"),
               PYTHONPATH=os.pathsep.join([str(p) for p in sys.path if p]))
    runs = [subprocess.run([sys.executable, str(script)], env=env, capture_output=True, text=True, timeout=600)
            for _ in range(2)]
    for run in runs:
        assert run.returncode == 0, run.stderr
    first, second = ([int(v) for v in run.stdout.split()] for run in runs)
    assert first[:2] == [0, 1]                  # compiled in the first process
    assert second == [1, 0, 4]                  # loaded in the second, with the four entries


def test_the_problem_interface_does_not_import_numba():
    """DOCP.compiled_evaluations' default and olado.problems load without numba (compiled.py is
    imported by a problem that has compiled evaluations)."""
    code = "import sys, olado, olado.problems; from olado.problems import docp; print('numba' in sys.modules)"
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         env=dict(os.environ, PYTHONPATH=os.pathsep.join([str(p) for p in sys.path if p])))
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "False"
