"""The disk cache of the LLVM kernels' object code (olado/problems/autodiff/object_cache.py,
docs/autodiff.md "Set-up time and the kernel cache").

A kernel loaded from the cache computes the same bits as a fresh compilation (a small SX
function and its Jacobian, and every derivative of the Van der Pol problem); a corrupted or
truncated entry is ignored and rewritten; OLADO_KERNEL_CACHE=0 writes nothing; two processes
building the same problem at once into an empty cache both succeed with the same numbers.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys

import numpy as np
import pytest

ca = pytest.importorskip("casadi")
pytest.importorskip("llvmlite")

from olado.problems.autodiff import llvm_kernels, object_cache   # noqa: E402
from olado.problems.autodiff.llvm_kernels import compile_ir, sx_llvm_ir   # noqa: E402


@pytest.fixture
def cache_dir(tmp_path, monkeypatch):
    """An empty cache root for this test, the cache on, no kernel compiled in this process."""
    monkeypatch.setenv("OLADO_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv("OLADO_KERNEL_CACHE", raising=False)
    monkeypatch.setattr(llvm_kernels, "_COMPILED", {})
    return tmp_path / "autodiff"


@pytest.fixture
def loads(monkeypatch):
    """Records, per compile_ir call, whether the object code came from the cache."""
    seen = []
    real = llvm_kernels._engine_address

    def spy(machine, module, cached, compiled):
        seen.append(cached is not None)
        return real(machine, module, cached, compiled)

    monkeypatch.setattr(llvm_kernels, "_engine_address", spy)
    return seen


def _function():
    """A small SX function with library calls, division and a branch, and its Jacobian."""
    x, u = ca.SX.sym("x", 3), ca.SX.sym("u", 2)
    f = ca.vertcat(ca.exp(-x[0]) * ca.sin(x[1]) + u[0] / (1 + x[2] ** 2),
                   ca.if_else(x[0] > 0, ca.sqrt(1 + x[1] ** 2), ca.atan2(x[2], u[1])),
                   ca.log(2 + ca.cos(x[0] * u[1])))
    return ca.Function("f", [x, u], [ca.densify(f), ca.densify(ca.jacobian(f, ca.vertcat(x, u)).T)])


def _run(address, fun, X, U):
    from olado.problems.autodiff.trampoline import call_kernel
    outs = [np.empty((X.shape[0], fun.nnz_out(j))) for j in range(fun.n_out())]
    call_kernel(address, (X, U, *outs))
    return outs


def _points(seed=0, K=64):
    rng = np.random.default_rng(seed)
    return np.ascontiguousarray(rng.normal(size=(K, 3))), np.ascontiguousarray(rng.normal(size=(K, 2)))


def _bits(arrays):
    return [a.view(np.uint64) for a in arrays]


def _entries(directory):
    return sorted(p for p in os.listdir(directory) if p.startswith("llvm_") and p.endswith(".o"))


def test_cache_hit_gives_the_bits_of_a_fresh_compilation(cache_dir, loads):
    fun = _function()
    text = sx_llvm_ir(fun)
    X, U = _points()
    fresh = _run(compile_ir(text), fun, X, U)
    assert len(_entries(cache_dir)) == 1
    hit = _run(compile_ir(text), fun, X, U)
    assert loads == [False, True]
    for a, b in zip(_bits(fresh), _bits(hit)):
        np.testing.assert_array_equal(a, b)
    # and both are the function: CasADi's own evaluation, stage by stage
    for k in (0, 17, 63):
        ref = fun(X[k], U[k])
        np.testing.assert_allclose(hit[0][k], np.asarray(ref[0]).ravel(), rtol=1e-14, atol=1e-15)
        np.testing.assert_allclose(hit[1][k], np.asarray(ref[1]).ravel(order="F"), rtol=1e-14, atol=1e-15)


@pytest.mark.parametrize("damage", ["flip", "truncate", "empty", "garbage"])
def test_corrupt_entry_is_ignored_and_rewritten(cache_dir, loads, damage):
    fun = _function()
    text = sx_llvm_ir(fun)
    X, U = _points(1)
    fresh = _run(compile_ir(text), fun, X, U)
    (name,) = _entries(cache_dir)
    path = cache_dir / name
    blob = bytearray(path.read_bytes())
    if damage == "flip":
        blob[len(blob) // 2] ^= 0xFF
    elif damage == "truncate":
        blob = blob[: len(blob) // 2]
    elif damage == "empty":
        blob = bytearray()
    else:
        blob = bytearray(os.urandom(len(blob)))
    path.write_bytes(bytes(blob))
    assert object_cache.load_object(object_cache.object_key(text)) is None
    again = _run(compile_ir(text), fun, X, U)
    assert loads == [False, False]                       # compiled, not loaded
    for a, b in zip(_bits(fresh), _bits(again)):
        np.testing.assert_array_equal(a, b)
    assert object_cache.load_object(object_cache.object_key(text)) is not None   # rewritten intact


def test_disabled_cache_writes_nothing(cache_dir, loads, monkeypatch):
    monkeypatch.setenv("OLADO_KERNEL_CACHE", "0")
    fun = _function()
    text = sx_llvm_ir(fun)
    X, U = _points(2)
    first = _run(compile_ir(text), fun, X, U)
    second = _run(compile_ir(text), fun, X, U)
    assert loads == [False, False]
    assert not cache_dir.exists() or not _entries(cache_dir)
    for a, b in zip(_bits(first), _bits(second)):
        np.testing.assert_array_equal(a, b)


def test_key_depends_on_the_ir_and_the_pipeline(monkeypatch):
    fun = _function()
    text = sx_llvm_ir(fun)
    key = object_cache.object_key(text)
    assert key == object_cache.object_key(text)
    assert key != object_cache.object_key(text.replace("kernel", "kernel2"))
    monkeypatch.setattr(object_cache, "PIPELINE", object_cache.PIPELINE + "-other")
    object_cache._target_signature.cache_clear()
    try:
        assert key != object_cache.object_key(text)
    finally:
        monkeypatch.undo()
        object_cache._target_signature.cache_clear()


def test_functions_differing_in_one_bit_of_data_get_their_own_kernels(cache_dir, loads):
    """The user's data are constants of the traced function: a kernel of other data is never
    served (keys differ, each kernel computes its own constant)."""
    x = ca.SX.sym("x")
    c1 = 0.1
    c2 = float(np.nextafter(c1, 1.0))
    funs = [ca.Function("f", [x], [x * c]) for c in (c1, c2)]
    keys = [object_cache.function_key(f) for f in funs]
    assert keys[0] != keys[1]
    kernels = [llvm_kernels.LLVMKernel(f) for f in funs]
    assert loads == [False, False]
    again = [llvm_kernels.LLVMKernel(f) for f in funs]          # same process: no new compile
    assert loads == [False, False] and [k.address for k in again] == [k.address for k in kernels]
    outs = []
    for k in kernels:
        out = np.empty((1, 1))
        k(np.ones((1, 1)), out)
        outs.append(out[0, 0])
    assert outs == [c1, c2]


def _vanderpol_derivatives():
    import olado
    prob = olado.problems.get_problems()["vanderpol"](N=12)
    rng = np.random.default_rng(3)
    x, u = rng.normal(size=(prob.N, prob.n)), rng.normal(size=(prob.N, prob.m))
    p = rng.normal(size=(prob.N, prob.n))
    lam = rng.normal(size=(prob.N, prob.r))
    xN = rng.normal(size=prob.n)
    K = np.arange(prob.N)
    outs = [prob.dynamics(K, x, u), prob.stage_cost(K, x, u), *prob.dynamics_jacobian(K, x, u),
            *prob.stage_cost_gradient(K, x, u), *prob.stage_hessian(K, x, u, 0.7, p, lam),
            np.atleast_1d(prob.final_cost(xN)), prob.final_cost_gradient(xN),
            prob.final_hessian(xN, 0.7, rng.normal(size=prob.rN))]
    if prob.r:
        outs += [prob.stage_constraints(K, x, u), *prob.stage_constraints_jacobian(K, x, u)]
    return [np.ascontiguousarray(o, dtype=np.float64) for o in outs]


def test_problem_built_from_cache_has_the_same_derivatives(cache_dir, loads, monkeypatch):
    fresh = _vanderpol_derivatives()
    n_kernels = len(loads)
    assert n_kernels >= 6 and not any(loads)
    monkeypatch.setattr(llvm_kernels, "_COMPILED", {})    # as in a new process
    hit = _vanderpol_derivatives()
    assert loads[n_kernels:] == [True] * n_kernels
    for a, b in zip(_bits(fresh), _bits(hit)):
        np.testing.assert_array_equal(a, b)


_CHILD = """
import json, sys
import numpy as np
sys.path.insert(0, sys.argv[1])
from tests.problems.test_kernel_cache import _vanderpol_derivatives
print(json.dumps([o.ravel().tolist() for o in _vanderpol_derivatives()]))
"""


def test_two_processes_fill_the_same_cache_at_once(tmp_path):
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    env = dict(os.environ, OLADO_CACHE_DIR=str(tmp_path), PYTHONPATH=root)
    env.pop("OLADO_KERNEL_CACHE", None)
    procs = [subprocess.Popen([sys.executable, "-c", _CHILD, root], env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for _ in range(2)]
    results = [p.communicate(timeout=300) for p in procs]
    for p, (out, err) in zip(procs, results):
        assert p.returncode == 0, err
    first, second = (json.loads(out) for out, _ in results)
    assert first == second
    directory = tmp_path / "autodiff"
    names = _entries(directory)
    assert names and not [p for p in os.listdir(directory) if p.endswith(".tmp")]
    for name in names:                                    # every entry intact
        blob = (directory / name).read_bytes()
        head = len(object_cache._MAGIC)
        assert blob.startswith(object_cache._MAGIC)
        assert hashlib.sha256(blob[head + 32:]).digest() == blob[head:head + 32]
