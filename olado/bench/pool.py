"""Isolated worker processes: each task runs in a separate Python process with a hard time limit
and a memory guard, and a crash, hang or exception of one task becomes an answer, never the end
of the caller's loop (issue 14; docs/benchmarking.md, "Isolation").

A worker is a child process started with :mod:`subprocess` (``python -m olado.bench._worker``),
not :mod:`multiprocessing`, so that a pool can also live inside a daemonic process (a Dask
worker). Parent and worker talk through two pipes wrapped as
:class:`multiprocessing.connection.Connection` (pickled messages); the worker's standard output
goes to /dev/null (a solver's verbose printing would otherwise garble the caller's progress
line) and its standard error to a temporary file whose tail becomes the message of a crash.

* **Time limit.** A task that has not answered ``time_limit + grace`` seconds after its clock
  started is a hang (the clock starts when the task is sent to a ready worker -- a new worker first
  imports its target and the ``preload`` modules and says it is ready -- and again when the task
  says so, :func:`olado.bench._worker.reset_clock`: a warm-up phase gets twice the time limit,
  for imports and compilation, the measured phase after it the time limit again): the worker is killed (SIGKILL) and replaced, the answer is :class:`Failure` ``timeout``.
* **Exception.** A task function that raises gives :class:`Failure` ``exception`` with the
  exception's type and message (and the traceback's tail); the worker goes on.
  (The bench also gives the solver ``max_time = time_limit``, so a solver that honours it stops
  by itself and returns its last iterate well before the kill.)
* **Memory guard.** The worker lowers its own address-space limit (``resource.setrlimit
  (RLIMIT_AS)``) to ``memory_limit`` bytes before it imports anything; an allocation beyond it
  fails inside the worker (a ``MemoryError`` the task function reports, or the death of the
  worker, a ``crash``) instead of pushing the machine into swap.
* **Crash.** A worker that dies (a signal, an abort in compiled code, ``os._exit``) gives the
  answer :class:`Failure` ``crash`` with its exit code and the tail of its standard error; the
  worker is replaced.
* **Orphans.** A worker asks the kernel (Linux ``prctl(PR_SET_PDEATHSIG)``) to be killed when its
  parent dies, so ``kill -9`` of the caller leaves no solve running; elsewhere it ends when it
  finds its parent gone (its pipe closed) after the current task.

Workers are reused from task to task (starting one costs the imports and numba's cache loads).
POSIX only (pipes passed by file descriptor; ``resource``).
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import tempfile
import time
from multiprocessing.connection import Connection, wait

#: extra seconds a worker gets beyond the time limit before it is killed
GRACE = 15.0
#: seconds a new worker may take to import its target and preloads (not counted in a task's limit)
STARTUP = 120.0


@dataclasses.dataclass(frozen=True)
class Failure:
    """The answer for a task that gave none: ``status`` ``timeout`` (killed at the time limit plus
    grace), ``crash`` (the worker died) or ``exception`` (the task function raised); ``message``
    says what happened. ``restart``: the worker was replaced."""

    status: str
    message: str
    wall_s: float
    traceback: str = ""
    restart: bool = True


@dataclasses.dataclass
class _Worker:
    proc: subprocess.Popen
    conn_out: Connection          # parent -> worker
    conn_in: Connection           # worker -> parent
    stderr: object                # the temporary file holding the worker's standard error
    task: object = None
    busy: bool = False
    t0: float = 0.0               # when the task's clock started (None: the worker is not ready yet)
    ready: bool = False
    started: float = 0.0
    warmup: bool = False          # the task is in its warm-up phase (twice the time limit)


def _child_path() -> str:
    """PYTHONPATH for a worker: the parent's sys.path, so it imports the same olado and the same
    user modules."""
    parts = [p if p else os.getcwd() for p in sys.path]
    old = os.environ.get("PYTHONPATH")
    return os.pathsep.join(parts + ([old] if old else []))


class IsolatedPool:
    """``jobs`` worker processes answering tasks with ``target(task)``, ``target`` a
    ``"module:function"`` string the workers import. :meth:`run` yields ``(task, answer)`` in
    completion order; ``answer`` is the function's return value, or a :class:`Failure` when the
    worker hung or died. Use as a context manager (or call :meth:`close`)."""

    def __init__(self, target: str, jobs: int = 1, time_limit: float = 60.0, grace: float = GRACE,
                 memory_limit: int | None = None, preload=()):
        self.target = str(target)
        self.preload = ",".join(preload)
        self.jobs = max(1, int(jobs))
        self.time_limit = float(time_limit)
        self.grace = float(grace)
        self.memory_limit = memory_limit
        self._workers: list[_Worker] = []

    # ------------------------------------------------------------------ workers
    def _start(self) -> _Worker:
        to_child_r, to_child_w = os.pipe()
        from_child_r, from_child_w = os.pipe()
        stderr = tempfile.TemporaryFile()
        cmd = [sys.executable, "-m", "olado.bench._worker", self.target, str(to_child_r), str(from_child_w),
               str(os.getpid()), str(self.memory_limit or 0), self.preload]
        env = dict(os.environ, PYTHONPATH=_child_path())
        try:
            proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=stderr,
                                    pass_fds=(to_child_r, from_child_w), env=env, close_fds=True)
        finally:
            os.close(to_child_r)
            os.close(from_child_w)
        return _Worker(proc, Connection(to_child_w, readable=False), Connection(from_child_r, writable=False), stderr,
                       started=time.perf_counter())

    def _stop(self, w: _Worker) -> None:
        for conn in (w.conn_out, w.conn_in):
            try:
                conn.close()
            except OSError:
                pass
        if w.proc.poll() is None:
            w.proc.kill()
        try:
            w.proc.wait(5)
        except subprocess.TimeoutExpired:  # pragma: no cover - a process that ignores SIGKILL
            pass
        w.stderr.close()

    def _stderr_tail(self, w: _Worker, chars: int = 400) -> str:
        try:
            w.stderr.seek(0)
            text = w.stderr.read().decode("utf-8", "replace").strip()
        except (OSError, ValueError):
            return ""
        return text[-chars:]

    def close(self) -> None:
        """Stop every worker (a running task is killed)."""
        for w in self._workers:
            try:
                if not w.busy:
                    w.conn_out.send(None)
            except OSError:
                pass
            self._stop(w)
        self._workers = []

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # ------------------------------------------------------------------ tasks
    def _send(self, w: _Worker, task) -> _Worker:
        """Give ``task`` to ``w`` (a fresh worker replaces one whose pipe is broken)."""
        try:
            w.conn_out.send(task)
        except OSError:
            self._stop(w)
            w = self._start()
            w.conn_out.send(task)
        w.task, w.busy, w.t0, w.warmup = task, True, (time.perf_counter() if w.ready else None), False
        return w

    def run(self, tasks):
        """Yield ``(task, answer)`` for every task of ``tasks`` (an iterable), in completion order."""
        pending = list(tasks)
        while len(self._workers) < min(self.jobs, max(1, len(pending))):
            self._workers.append(self._start())
        while pending or any(w.busy for w in self._workers):
            for i, w in enumerate(self._workers):
                if not w.busy and pending:
                    self._workers[i] = self._send(w, pending.pop(0))
            busy = [w for w in self._workers if w.busy]
            wait([w.conn_in for w in busy] + [w.proc.sentinel for w in busy if hasattr(w.proc, "sentinel")],
                 timeout=0.05)
            for i, w in enumerate(self._workers):
                if w.busy:
                    answer = self._poll(w)
                    if answer is None:
                        continue
                    task = w.task
                    w.task, w.busy = None, False
                    if isinstance(answer, Failure) and answer.restart:
                        self._stop(w)
                        self._workers[i] = self._start()
                    yield task, answer

    def _poll(self, w: _Worker):
        """The answer of ``w``'s task, a Failure (hang, death), or None (still working). The
        task's clock starts when the worker is ready (imports done) and again when the worker
        says so (after a warm-up: ``_worker.reset_clock``)."""
        try:
            while w.conn_in.poll(0):
                answer = w.conn_in.recv()
                if answer[0] in ("ready", "clock", "warmup"):
                    w.ready, w.t0, w.warmup = True, time.perf_counter(), answer[0] == "warmup"
                    continue
                elapsed = time.perf_counter() - w.t0
                if answer[0] is True:
                    return answer[1]
                return Failure("exception", answer[1], elapsed, answer[2], restart=False)
        except (EOFError, OSError):
            pass
        now = time.perf_counter()
        elapsed = now - (w.t0 if w.t0 is not None else w.started)
        code = w.proc.poll()
        if code is not None:
            how = f"killed by signal {-code}" if code < 0 else f"exit code {code}"
            tail = self._stderr_tail(w)
            return Failure("crash", f"the worker process died ({how})" + (f"; its last output: {tail}" if tail else ""),
                           elapsed)
        if w.t0 is None and elapsed > STARTUP + self.grace:
            return Failure("timeout", f"the worker was not ready {elapsed:.1f} s after its start (imports)", elapsed)
        limit = self.time_limit * (2.0 if w.warmup else 1.0)
        if w.t0 is not None and elapsed > limit + self.grace:
            what = "in its warm-up solve " if w.warmup else ""
            return Failure("timeout", f"killed {what}after {elapsed:.1f} s without an answer (time limit "
                                      f"{limit:g} s + {self.grace:g} s grace)", elapsed)
        return None
