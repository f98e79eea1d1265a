"""Stopping a solve from outside its algorithm: the wall-clock limit and interrupts
(docs/interrupts.md).

Two things end a solve that the algorithm does not decide: its ``max_time`` and an interrupt
(Ctrl-C / SIGINT, SIGTERM to ``olado solve``, a ``KeyboardInterrupt`` raised by the user's code).
Both end it the same way: at the next safe point, with the last accepted iterate in the Result
and the status MAX_TIME or INTERRUPTED. This module is the one mechanism every solver uses:

* the process-wide interrupt flag and the signal handler that sets it. :class:`InterruptGuard`
  installs the handler while a solve runs (``Solver.solve``: SIGINT; ``olado solve``: SIGINT
  and SIGTERM) -- only in the main thread, only over Python's default handlers, and restores
  them afterwards. The first signal sets the flag; a second one raises :class:`AbortSolve`
  (a ``KeyboardInterrupt``) at once, which no solver catches.
* :class:`Limits`, one per solve: ``reason()`` is "deadline expired or interrupt requested" in
  one call; ``check()`` raises :class:`StopRequested` inside a :meth:`Limits.catch` block. The
  solvers call ``check()`` at iteration boundaries, after every evaluation batch (their
  counting wrappers), in every interior-point QP iteration and in every line-search trial; the
  block around each solver's loop turns the exception -- or a ``KeyboardInterrupt`` from the
  user's functions -- into its ``reason`` and the solver returns its last accepted iterate.
  Outside such a block ``check()`` does nothing, so the evaluations that build the Result
  after a stop never raise.

A leaf module: the standard library and olado.errors only, so the QP layer can check too.
"""

from __future__ import annotations

import math
import os
import signal
import threading
import time

__all__ = ["AbortSolve", "InterruptGuard", "Limits", "StopRequested", "clear_interrupt", "interrupt_age",
           "interrupt_requested", "interrupt_source", "request_interrupt"]

#: why a solve was stopped from outside: the value of the matching olado.result.Status
INTERRUPTED, MAX_TIME = "interrupted", "max_time"


class StopRequested(BaseException):
    """Raised by :meth:`Limits.check` to unwind a solve to its loop (never reaches the user:
    the loop's :meth:`Limits.catch` block, or ``Solver.solve``, ends the solve with a status).
    A BaseException, like KeyboardInterrupt: no ``except Exception`` on the way may swallow it."""

    def __init__(self, reason):
        super().__init__(reason)
        self.reason = reason


class AbortSolve(KeyboardInterrupt):
    """The second interrupt signal during a solve: abort at once, keep nothing. Raised by the
    signal handler; solvers let it through (it is not an interrupt to stop at a safe point)."""

    def __init__(self, signum):
        super().__init__(f"second {_signal_name(signum)}: solve aborted")
        self.signum = signum


# ---------------------------------------------------------------------------- the process-wide flag
class _Flag:
    """The interrupt flag: the first signal number received while a guard is active (None:
    none), the source of an interrupt requested otherwise, and the main thread's guard depth."""

    signum = None
    source = None
    time = None         # time.monotonic() when it was requested
    depth = 0


_FLAG = _Flag()


def _signal_name(signum):
    try:
        return signal.Signals(signum).name
    except (ValueError, TypeError):
        return f"signal {signum}"


def interrupt_requested() -> bool:
    """True when an interrupt signal arrived during the active guard (any solve may read it)."""
    return _FLAG.source is not None


def interrupt_source() -> str:
    """What requested the interrupt: "SIGINT", "SIGTERM", ... or "" when none."""
    return _FLAG.source or ""


def request_interrupt(signum=None, source=None):
    """Set the flag as the handler does (signal ``signum``), e.g. from a GUI's stop button in
    another thread: every running solve stops at its next safe point. The flag stays set until
    the outermost guard of the main thread ends, or :func:`clear_interrupt`."""
    _FLAG.signum = signum
    _FLAG.source = source or (_signal_name(signum) if signum is not None else "interrupt")
    _FLAG.time = time.monotonic()


def interrupt_age():
    """Seconds since the interrupt was requested (None: none is)."""
    return None if _FLAG.time is None else time.monotonic() - _FLAG.time


def clear_interrupt():
    """Clear the flag (the outermost guard does this when it starts and ends)."""
    _FLAG.signum = _FLAG.source = _FLAG.time = None



def _handler(signum, frame):
    """First signal: set the flag (the solve stops at its next safe point); second: abort."""
    if _FLAG.source is not None:
        raise AbortSolve(signum)
    request_interrupt(signum)
    try:
        os.write(2, (f"olado: {_signal_name(signum)} received, stopping at the next safe point "
                     "(send it again to abort at once)\n").encode())
    except OSError:  # pragma: no cover - stderr closed
        pass


def _replaceable(signum, handler) -> bool:
    """Only Python's default behaviour is replaced: SIGINT's default_int_handler, SIG_DFL; a
    handler the program installed itself, or an ignored signal, is left alone. ``handler`` as
    ``signal.getsignal`` or the underlying ``_signal.getsignal`` gives it (SIG_DFL the
    Handlers member or its int)."""
    if handler is signal.default_int_handler:
        return signum == signal.SIGINT
    return type(handler) in _DEFAULT_TYPES and handler == signal.SIG_DFL


#: the types of SIG_DFL as getsignal gives it: signal.Handlers' member, _signal's int
_DEFAULT_TYPES = (type(signal.SIG_DFL), int)

# signal.signal and signal.getsignal are _signal's with their arguments and results converted
# between ints and the Signals / Handlers enums (~4 us per call in Enum's lookups of a function
# that is no member): a guard, entered and left once per solve, calls the underlying functions
# with what they take and give back -- the numbers, SIG_DFL and SIG_IGN as ints, handlers as they
# are -- and stores and restores a handler as _signal gave it
try:
    from _signal import getsignal as _getsignal, signal as _setsignal
except ImportError:     # pragma: no cover - an interpreter without CPython's module: the public functions
    _getsignal, _setsignal = signal.getsignal, signal.signal


class InterruptGuard:
    """``with InterruptGuard(signals):`` -- while the block runs, the ``signals`` (default:
    SIGINT) set the interrupt flag instead of raising KeyboardInterrupt or ending the process;
    a second one raises :class:`AbortSolve`. Main thread only (elsewhere a no-op: Python runs
    signal handlers in the main thread); nested guards leave the outer one's handlers in place;
    the outermost clears the flag on entry and exit. ``received`` (after the block, or inside
    it) is the first signal number received, or None."""

    def __init__(self, signals=(signal.SIGINT,)):
        self.signals = tuple(signals)
        self.installed = {}
        self.active = False
        self._received = None

    def __enter__(self):
        if threading.current_thread() is not threading.main_thread():
            return self
        self.active = True
        if _FLAG.depth == 0:
            clear_interrupt()
        _FLAG.depth += 1
        for signum in self.signals:
            current = _getsignal(signum)
            if current is not _handler and _replaceable(signum, current):
                _setsignal(signum, _handler)
                self.installed[signum] = current
        return self

    @property
    def received(self):
        return _FLAG.signum if self.active else self._received

    def __exit__(self, *exc):
        if not self.active:
            return False
        self._received = _FLAG.signum
        for signum, previous in self.installed.items():
            _setsignal(signum, previous)
        self.installed = {}
        _FLAG.depth -= 1
        if _FLAG.depth == 0:
            clear_interrupt()
        self.active = False
        return False


# ---------------------------------------------------------------------------- one solve's limits
class Limits:
    """What may end one solve from outside: ``max_time`` seconds from construction, and the
    interrupt flag (or a KeyboardInterrupt seen by this solve). See the module docstring."""

    def __init__(self, max_time=math.inf):
        self.t0 = time.perf_counter()
        self.max_time = float(max_time)
        self._timed = math.isfinite(self.max_time)
        self.armed = 0              # > 0 inside a catch() block: check() raises there
        self.keyboard = False       # a KeyboardInterrupt from the user's code was seen

    def elapsed(self) -> float:
        return time.perf_counter() - self.t0

    def expired(self) -> bool:
        """The time limit alone."""
        return self._timed and time.perf_counter() - self.t0 >= self.max_time

    def reason(self):
        """"interrupted", "max_time" or None: deadline expired or interrupt requested, in one call."""
        if _FLAG.source is not None or self.keyboard:
            return INTERRUPTED
        if self._timed and time.perf_counter() - self.t0 >= self.max_time:
            return MAX_TIME
        return None

    def check(self):
        """Inside a :meth:`catch` block: raise :class:`StopRequested` when :meth:`reason` says
        so. Cheap (a flag, a clock read): called per evaluation, QP iteration, line-search trial."""
        # reason()'s tests inline (called several times per interior-point iteration)
        if self.armed and (_FLAG.source is not None or self.keyboard or
                           (self._timed and time.perf_counter() - self.t0 >= self.max_time)):
            raise StopRequested(self.reason())

    def source(self) -> str:
        """What interrupted this solve ("SIGINT", "SIGTERM", "KeyboardInterrupt"), "" if nothing."""
        return _FLAG.source or ("KeyboardInterrupt" if self.keyboard else "")

    def interrupt(self, exc=None):
        """Mark this solve interrupted: a KeyboardInterrupt ``exc`` raised in the user's code
        (an :class:`AbortSolve` is re-raised: it is not a request to stop at a safe point), or
        an inner solve that was interrupted."""
        if isinstance(exc, AbortSolve):
            raise exc
        self.keyboard = True

    def catch(self):
        """The block a solver's loop runs in (``with limits.catch() as stop:``): check() raises
        there, and a StopRequested or KeyboardInterrupt (not AbortSolve) ends the block with
        ``stop.reason`` set instead of propagating."""
        return _Catch(self)


class _Catch:
    """See :meth:`Limits.catch`."""

    def __init__(self, limits):
        self.limits = limits
        self.reason = None

    def __enter__(self):
        self.limits.armed += 1
        return self

    def __exit__(self, typ, exc, tb):
        self.limits.armed -= 1
        if typ is None:
            return False
        if issubclass(typ, StopRequested):
            self.reason = exc.reason
            return True
        if issubclass(typ, KeyboardInterrupt) and not issubclass(typ, AbortSolve):
            self.limits.keyboard = True
            self.reason = INTERRUPTED
            return True
        return False
