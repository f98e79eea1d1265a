"""Interrupts, time limits and concurrency for every solver family (docs/interrupts.md).

An interrupt -- a KeyboardInterrupt raised by the user's callback or problem function, or a
real SIGINT (the handler olado.solve installs) -- ends the solve at the next safe point with
status INTERRUPTED and the last accepted iterate: the same point as a run with ``max_iter`` set
to the iterations the interrupted run reports. ``max_time`` is checked after every evaluation
batch. One solver instance may run solves in several threads; one problem instance may not."""

import os
import signal
import threading
import time

import numpy as np
import pytest

import olado
from olado.api import resolve_solver
from olado.errors import ProblemInUseError
from olado.result import Status
from olado.solvers.base import Solver

from fixtures.pdmin_problems import BoundedPendulum
from fixtures.reduced_gradient_problems import VanDerPol
from fixtures.toy_problems import Pendulum


#: Python's own SIGINT handler in every test here (tests/conftest.py)
pytestmark = pytest.mark.usefixtures("python_default_sigint")

#: solver -> a problem it solves in several iterations (constraints, none, control bounds)
CASES = {
    "sqp": lambda: Pendulum(N=20), "ipopt": lambda: Pendulum(N=20), "slsqp": lambda: Pendulum(N=20),
    "trust-constr": lambda: Pendulum(N=20), "penalty": lambda: Pendulum(N=20),
    "gradient": VanDerPol, "cg": VanDerPol, "variable-metric": VanDerPol, "newton": VanDerPol,
    "ddp": VanDerPol, "stagewise-newton": VanDerPol, "pdmin": BoundedPendulum, "ipm": BoundedPendulum,
    "fqlnk": VanDerPol,
}
SOLVERS = sorted(CASES)
K = 2       # the iteration at which the interrupt comes


def same_iterate(result, name):
    """``result`` holds the iterate a max_iter run with its iteration count returns (SciPy's
    methods make one iteration with max_iter = 0: there, the initial point)."""
    if result.iterations == 0 and name in ("slsqp", "trust-constr"):
        X0, U0 = Solver.initial_point(CASES[name](), None)
        np.testing.assert_array_equal(result.x, X0)
        np.testing.assert_array_equal(result.u, U0)
        return
    ref = olado.solve(CASES[name](), solver=name, max_iter=result.iterations)
    np.testing.assert_array_equal(result.x, ref.x)
    np.testing.assert_array_equal(result.u, ref.u)
    assert result.objective == pytest.approx(ref.objective, rel=1e-12, abs=1e-14)


def interrupted(result, source):
    assert result.status is Status.INTERRUPTED, result.message
    assert f"interrupted ({source})" in result.message and "last accepted iterate" in result.message
    assert Status.INTERRUPTED.sentence and not result.success


@pytest.mark.parametrize("name", SOLVERS)
def test_keyboard_interrupt_in_the_callback(name):
    def callback(info):
        if info.get("iter") == K:
            raise KeyboardInterrupt

    r = olado.solve(CASES[name](), solver=name, callback=callback)
    interrupted(r, "KeyboardInterrupt")
    assert r.iterations == K
    same_iterate(r, name)


class _Raising:
    """Mixed into a problem: its final cost raises KeyboardInterrupt at the ``after``-th call."""

    after = 0

    def final_cost(self, x):
        self.calls = getattr(self, "calls", 0) + 1
        if self.calls == self.after:
            raise KeyboardInterrupt
        return super().final_cost(x)


def with_mixin(problem, mixin, **attrs):
    problem.__class__ = type(f"{mixin.__name__}{type(problem).__name__}", (mixin, type(problem)), attrs)
    return problem


@pytest.mark.parametrize("name", SOLVERS)
def test_keyboard_interrupt_in_a_problem_function(name):
    """Raised inside an evaluation (a line-search trial, a derivative, an inner solve): the
    last accepted iterate. The penalty method returns its inner solver's last iterate (the
    progress of the subproblem in hand), so it is compared with the outer count only."""
    r = olado.solve(with_mixin(CASES[name](), _Raising, after=4), solver=name)
    interrupted(r, "KeyboardInterrupt")
    assert np.all(np.isfinite(r.x)) and np.isfinite(r.objective)
    if name == "penalty":
        assert r.iterations <= 1
        return
    same_iterate(r, name)


@pytest.mark.parametrize("name", SOLVERS)
def test_sigint_stops_at_the_next_safe_point_and_a_second_one_aborts(name):
    """A real SIGINT from the callback of iteration K: the handler olado.solve installed sets
    the flag, the solve returns after K iterations; two SIGINTs raise KeyboardInterrupt."""
    def once(info):
        if info.get("iter") == K:
            os.kill(os.getpid(), signal.SIGINT)

    r = olado.solve(CASES[name](), solver=name, callback=once)
    interrupted(r, "SIGINT")
    assert r.iterations == K and r.info["interrupt_latency_s"] >= 0.0
    same_iterate(r, name)
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler     # restored

    def twice(info):
        if info.get("iter") == K:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.01)          # Python runs the handler between the two signals
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(1.0)           # not reached: the second signal raises

    with pytest.raises(KeyboardInterrupt):
        olado.solve(CASES[name](), solver=name, callback=twice)
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


class _Slow:
    """Mixed into a problem: every objective evaluation (one per evaluation batch: the final
    cost is evaluated once per point) sleeps ``delay`` seconds."""

    delay = 0.0

    def final_cost(self, x):
        time.sleep(self.delay)
        return super().final_cost(x)


#: objective evaluations after the stop to build the Result at the returned point (the penalty
#: method records its inner solver's last point and its KKT residual; SciPy's methods stopped
#: before their first iteration evaluate J at the start)
ASSEMBLY = {"penalty": 2, "slsqp": 1, "trust-constr": 1}


@pytest.mark.parametrize("name", SOLVERS)
def test_max_time_inside_long_iterations(name):
    """Evaluations of 0.3 s and max_time = 0.6 s: the solve returns within the limit plus the
    batch in progress (and the result's own evaluations), with the iterate of a max_iter run."""
    delay, limit = 0.3, 0.6
    problem = with_mixin(CASES[name](), _Slow, delay=delay)
    t0 = time.perf_counter()
    r = olado.solve(problem, solver=name, max_time=limit)
    elapsed = time.perf_counter() - t0
    assert r.status is Status.MAX_TIME, r.message
    assert elapsed <= limit + delay * (1 + ASSEMBLY.get(name, 0)) + 0.5, elapsed
    if name != "penalty":
        same_iterate(r, name)


def _in_threads(fn, count):
    barrier = threading.Barrier(count)
    out, errors = [None] * count, []

    def run(i):
        try:
            barrier.wait()
            out[i] = fn(i)
        except Exception as exc:
            errors.append(exc)

    threads = [threading.Thread(target=run, args=(i,)) for i in range(count)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return out, errors


@pytest.mark.parametrize("name", SOLVERS)
def test_one_solver_instance_in_threads(name):
    """Three threads share one solver instance, each with its own problem: every result equals
    the one of a solve alone (iterates, counts, history) -- the per-solve state lives in the
    solve, not on the instance (the CG direction and BFGS pairs used to)."""
    solver = resolve_solver(solver=name)
    alone = solver.solve(CASES[name]())
    results, errors = _in_threads(lambda i: solver.solve(CASES[name]()), 3)
    assert not errors, errors
    for r in results:
        assert r.status == alone.status and r.iterations == alone.iterations
        assert r.qp_iterations == alone.qp_iterations and r.evaluations == alone.evaluations
        np.testing.assert_array_equal(r.x, alone.x)
        np.testing.assert_array_equal(r.u, alone.u)


def test_one_problem_instance_in_two_solves_is_refused():
    """Its counters are per solve: the second solve of the same instance, from another thread
    or from a callback, gets ProblemInUseError naming the problem; the first one is unharmed."""
    problem = Pendulum(N=20)
    alone = olado.solve(Pendulum(N=20), solver="sqp")
    started, release = threading.Event(), threading.Event()

    def hold(info):
        started.set()
        release.wait(10)

    out = {}
    worker = threading.Thread(target=lambda: out.setdefault("r", olado.solve(problem, solver="sqp", callback=hold)))
    worker.start()
    assert started.wait(60)
    with pytest.raises(ProblemInUseError, match="pendulum.*being solved by another thread"):
        olado.solve(problem, solver="ipopt")
    release.set()
    worker.join()
    assert out["r"].status is Status.SUCCESS and out["r"].evaluations == alone.evaluations

    nested = {}

    def again(info):
        try:
            olado.solve(problem, solver="sqp")
        except ProblemInUseError as exc:
            nested["error"] = str(exc)

    olado.solve(problem, solver="sqp", callback=again)
    assert "a callback" in nested["error"]
    assert olado.solve(problem, solver="sqp").status is Status.SUCCESS       # released afterwards


def test_request_interrupt_from_another_thread():
    """Embedding code (a GUI's stop button) calls request_interrupt() while a solve runs in a
    worker thread: the solve stops at its next safe point with the last accepted iterate."""
    from olado.interrupts import clear_interrupt, request_interrupt

    started = threading.Event()

    def callback(info):
        started.set()
        time.sleep(0.005)

    out = {}
    worker = threading.Thread(target=lambda: out.setdefault(
        "r", olado.solve(VanDerPol(), solver="gradient", callback=callback)))
    worker.start()
    try:
        assert started.wait(60)
        request_interrupt(source="stop button")
        worker.join(60)
    finally:
        clear_interrupt()
    interrupted(out["r"], "stop button")
    assert 0 < out["r"].iterations < 1000
    same_iterate(out["r"], "gradient")
