"""The stop mechanism of olado.interrupts: Limits (one call for "deadline expired or interrupt
requested", raising only inside its catch block), the signal handler's guard (main thread only,
Python's default handlers only, restored afterwards, nested guards), the second signal, and the
interior-point QP's per-iteration check."""

import math
import os
import signal
import threading
import time

import numpy as np
import pytest

from olado.interrupts import (AbortSolve, InterruptGuard, Limits, StopRequested, interrupt_requested,
                              interrupt_source, request_interrupt)
from olado.qp import make_qp_solver

from fixtures.qp_problems import random_qp


#: Python's own SIGINT handler in every test here (tests/conftest.py)
pytestmark = pytest.mark.usefixtures("python_default_sigint")


def test_limits_reason_time_and_interrupt():
    assert Limits().reason() is None and not Limits().expired()
    slow = Limits(max_time=0.05)
    assert slow.reason() is None
    time.sleep(0.06)
    assert slow.expired() and slow.reason() == "max_time"
    with InterruptGuard():
        request_interrupt(signal.SIGINT)
        assert interrupt_requested() and interrupt_source() == "SIGINT"
        # an interrupt wins over the time limit, and every solve sees it
        assert slow.reason() == "interrupted" and Limits().reason() == "interrupted"
    assert not interrupt_requested() and Limits().reason() is None   # the guard cleared the flag


def test_check_raises_only_inside_catch_and_catch_sets_the_reason():
    limits = Limits(max_time=1e-9)
    time.sleep(0.001)
    limits.check()                          # outside a catch block: nothing (result assembly)
    with limits.catch() as stop:
        limits.check()
        pytest.fail("check() inside the block must raise")   # pragma: no cover
    assert stop.reason == "max_time" and limits.armed == 0
    with limits.catch() as stop:
        raise KeyboardInterrupt             # from the user's code: an interrupt
    assert stop.reason == "interrupted" and limits.source() == "KeyboardInterrupt"
    with pytest.raises(AbortSolve):         # a second signal is not caught
        with limits.catch():
            raise AbortSolve(signal.SIGINT)
    with pytest.raises(ValueError):         # nor anything else
        with limits.catch():
            raise ValueError("bug")
    assert issubclass(StopRequested, BaseException) and not issubclass(StopRequested, Exception)


def test_guard_installs_over_the_default_handler_only_and_restores_it():
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    with InterruptGuard((signal.SIGINT, signal.SIGTERM)) as guard:
        assert signal.getsignal(signal.SIGINT) is not signal.default_int_handler
        assert signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL
        with InterruptGuard() as inner:     # nested: the outer handler stays
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.01)                # the handler runs between bytecodes
            assert inner.received == signal.SIGTERM and interrupt_requested()
        assert interrupt_requested(), "an inner guard must not clear the outer one's flag"
        with pytest.raises(AbortSolve) as exc:     # the second signal aborts at once
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.5)
        assert exc.value.signum == signal.SIGINT and isinstance(exc.value, KeyboardInterrupt)
    assert guard.received == signal.SIGTERM
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
    assert not interrupt_requested()


def test_guard_leaves_a_programs_own_handler_alone():
    seen = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: seen.append(signum))
    try:
        with InterruptGuard():
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.01)
            assert not interrupt_requested()
        assert seen == [signal.SIGINT]
    finally:
        signal.signal(signal.SIGINT, previous)


def test_guard_in_another_thread_is_a_no_op():
    out = {}

    def run():
        with InterruptGuard() as guard:
            out["active"] = guard.active
            out["handler"] = signal.getsignal(signal.SIGINT)

    t = threading.Thread(target=run)
    t.start()
    t.join()
    assert out == {"active": False, "handler": signal.default_int_handler}


@pytest.mark.parametrize("method", ["mehrotra", "franke", "active-set", "bounds"])
def test_olado_qp_methods_check_the_limits_every_iteration(method):
    """An interrupt requested before the QP starts: the QP raises at its first iteration (or
    working-set change) inside the solve's catch block; outside one it solves to the end (e.g.
    after the solver stopped)."""
    qp = random_qp(seed=3, N=8)
    solver = make_qp_solver(method)
    ref = solver.solve(qp)
    assert ref.success and ref.iterations > 2
    with InterruptGuard():
        request_interrupt(signal.SIGINT)
        limits = Limits()
        with limits.catch() as stop:
            solver.solve(qp, limits=limits)
        assert stop.reason == "interrupted"
        again = solver.solve(qp, limits=limits)       # not armed: the QP runs to the end
        warm = solver.solve(qp, warm_start=ref, limits=limits)
        with limits.catch() as stop:
            solver.solve(qp, warm_start=ref, limits=limits)
        assert stop.reason == "interrupted" or warm.iterations == 0
    np.testing.assert_array_equal(again.X, ref.X)
    limits = Limits(max_time=math.inf)
    with limits.catch() as stop:
        res = solver.solve(qp, limits=limits)
    assert stop.reason is None and res.iterations == ref.iterations
