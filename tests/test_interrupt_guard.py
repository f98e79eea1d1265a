"""InterruptGuard over the underlying _signal functions (no enum conversions): an ignored signal
and SIG_DFL as either form, and what ``signal.getsignal`` shows after the guard."""

import os
import signal
import time

from olado.interrupts import InterruptGuard, _replaceable, interrupt_requested


def test_default_and_ignored_handlers_in_either_form():
    assert _replaceable(signal.SIGTERM, signal.SIG_DFL) and _replaceable(signal.SIGTERM, int(signal.SIG_DFL))
    assert not _replaceable(signal.SIGTERM, signal.SIG_IGN) and not _replaceable(signal.SIGTERM, int(signal.SIG_IGN))
    assert _replaceable(signal.SIGINT, signal.default_int_handler)
    assert not _replaceable(signal.SIGTERM, signal.default_int_handler)
    assert not _replaceable(signal.SIGINT, None) and not _replaceable(signal.SIGINT, lambda s, f: None)


def test_guard_leaves_an_ignored_signal_ignored():
    previous = signal.signal(signal.SIGTERM, signal.SIG_IGN)
    try:
        with InterruptGuard((signal.SIGINT, signal.SIGTERM)):
            assert signal.getsignal(signal.SIGTERM) is signal.SIG_IGN
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.01)
            assert not interrupt_requested()
        assert signal.getsignal(signal.SIGTERM) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_guard_restores_sig_dfl_as_signal_shows_it():
    previous = signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        for _ in range(2):
            with InterruptGuard((signal.SIGTERM,)) as guard:
                assert guard.installed == {signal.SIGTERM: signal.SIG_DFL}
                assert signal.getsignal(signal.SIGTERM) not in (signal.SIG_DFL, signal.SIG_IGN)
            assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL and not guard.installed
    finally:
        signal.signal(signal.SIGTERM, previous)
