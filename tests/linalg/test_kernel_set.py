"""Bound kernels (olado.linalg.codegen.KernelSet): after the first call through numba's
dispatcher a kernel is called through its compiled entry point, with the same results; with the
type check on (the test suite's default, tests/conftest.py) a call with other argument types is
an error, and a QP solved without the check gives the same iterates bit for bit."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numba
import numpy as np
import pytest

from olado.linalg import codegen

ROOT = Path(__file__).resolve().parents[2]


@numba.njit(cache=False)
def _weighted_sum(bundle, w):
    a, b = bundle
    return w * (a.sum() + 2.0 * b.sum())


_TABLE = {"weighted_sum": _weighted_sum}


def test_first_call_binds_the_entry_point_with_the_same_result(monkeypatch):
    monkeypatch.setenv(codegen.CHECK_TYPES_ENV, "0")
    ks = codegen.KernelSet(_TABLE)
    args = ((np.arange(3.0), np.ones(2)), 0.5)
    first = ks.weighted_sum(*args)
    assert first == pytest.approx(0.5 * (3.0 + 4.0))
    bound = ks.weighted_sum
    assert not isinstance(bound, codegen._FirstCall)
    assert bound is _weighted_sum.overloads[tuple(numba.typeof(a) for a in args)].entry_point
    assert bound(*args) == first == _weighted_sum(*args)


def test_a_stale_first_call_object_delegates_to_the_bound_kernel(monkeypatch):
    monkeypatch.setenv(codegen.CHECK_TYPES_ENV, "0")
    ks = codegen.KernelSet(_TABLE)
    stale = ks.weighted_sum
    args = ((np.ones(2), np.ones(2)), 1.0)
    assert ks.weighted_sum(*args) == 6.0
    assert stale(*args) == 6.0
    assert not isinstance(ks.weighted_sum, codegen._FirstCall)


def test_the_check_names_the_arguments_whose_types_differ(monkeypatch):
    monkeypatch.setenv(codegen.CHECK_TYPES_ENV, "1")
    ks = codegen.KernelSet(_TABLE)
    ks.weighted_sum((np.ones(4), np.ones(4)), 1.0)
    strided = np.ones(8)[::2]                      # layout 'A', not the 'C' of the first call
    with pytest.raises(codegen.KernelTypeError, match=r"weighted_sum .* arguments \[0\]"):
        ks.weighted_sum((strided, np.ones(4)), 1.0)


def test_the_check_tells_scalars_of_other_numba_types_from_equal_ones(monkeypatch):
    """The scalar keys of the check: a Python int where the kernel was bound to a float is another
    numba type (int64, not float64) and is named; numpy's float64 for a Python float is the same
    type and passes."""
    monkeypatch.setenv(codegen.CHECK_TYPES_ENV, "1")
    ks = codegen.KernelSet(_TABLE)
    pair = (np.ones(4), np.ones(4))
    ks.weighted_sum(pair, 1.0)
    assert ks.weighted_sum(pair, np.float64(2.0)) == 24.0   # 2 (4 + 2 x 4)
    with pytest.raises(codegen.KernelTypeError, match=r"weighted_sum .* arguments \[1\]: \[int64\]"):
        ks.weighted_sum(pair, 2)


def test_kernel_sets_are_shared_per_table_and_key():
    assert codegen.kernel_set(_TABLE, (2, 3)) is codegen.kernel_set(_TABLE, (2, 3))
    assert codegen.kernel_set(_TABLE, (2, 3)) is not codegen.kernel_set(_TABLE, (3, 2))
    assert codegen.kernel_set(_TABLE) is not codegen.kernel_set(_TABLE, (2, 3))


# a QP solved in a fresh process, with or without the type check: iterations, objective and a
# checksum of the solution
_SOLVE = textwrap.dedent("""
    import json, sys
    sys.path.insert(0, sys.argv[1])
    from fixtures.qp_problems import random_qp
    from olado.qp import make_qp_solver
    out = []
    for seed, kw in ((0, {}), (1, {"eq": True}), (2, {"fixed": True}), (3, {"n": 9, "m": 7})):
        res = make_qp_solver("mehrotra").solve(random_qp(seed=seed, N=8, **kw))
        out.append([res.status.value, res.iterations, res.objective.hex(), float(abs(res.X).sum() + abs(res.U).sum()).hex()])
    print(json.dumps(out))
""")


def _solve_in_process(check):
    env = {**os.environ, codegen.CHECK_TYPES_ENV: check, "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", _SOLVE, str(ROOT / "tests")], env=env, capture_output=True,
                         text=True, timeout=600, cwd=ROOT)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_bound_kernels_give_the_iterates_of_the_checked_calls():
    checked, direct = _solve_in_process("1"), _solve_in_process("0")
    assert checked == direct
    assert all(status == "success" for status, *_ in direct)
