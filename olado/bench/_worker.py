"""The worker process of :class:`olado.bench.pool.IsolatedPool` (``python -m olado.bench._worker
TARGET READ_FD WRITE_FD PARENT_PID MEMORY_LIMIT PRELOAD``): set the memory guard and the
parent-death signal, import ``TARGET`` ("module:function") and the modules of PRELOAD (comma
separated), say ``("ready",)``, then answer each task received on READ_FD with
``(True, function(task))`` -- or ``(False, message, traceback)`` when the function raised --
on WRITE_FD until it receives None or the parent is gone."""

from __future__ import annotations

import os
import sys

_CONN = None


def reset_clock(phase: str = "clock") -> None:
    """Tell the pool that a part of the current task starts now: ``"warmup"`` (an unmeasured
    warm-up solve: twice the time limit, for imports and compilation) or ``"clock"`` (the
    measured part: the time limit). A no-op outside a worker."""
    if _CONN is not None:
        _CONN.send((phase,))


def _guard_memory(limit: int) -> None:
    """Address-space limit of this process (RLIMIT_AS), never above the current hard limit."""
    if limit <= 0:
        return
    try:
        import resource

        soft, hard = resource.getrlimit(resource.RLIMIT_AS)
        if hard != resource.RLIM_INFINITY:
            limit = min(limit, hard)
        resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
    except (ImportError, ValueError, OSError):  # pragma: no cover - not POSIX, or not permitted
        pass


def _die_with_parent(parent_pid: int) -> None:
    """Linux: SIGKILL this process when its parent dies (prctl PR_SET_PDEATHSIG); exit at once if
    the parent is already gone."""
    try:
        import ctypes
        import signal

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)  # 1 = PR_SET_PDEATHSIG
    except (OSError, AttributeError):  # pragma: no cover - not Linux
        pass
    if os.getppid() != parent_pid:
        os._exit(0)


def _import(target: str):
    import importlib

    module, _, name = target.partition(":")
    return getattr(importlib.import_module(module), name)


def main(argv) -> int:
    global _CONN
    target, read_fd, write_fd, parent_pid, memory, preload = argv
    _die_with_parent(int(parent_pid))
    _guard_memory(int(memory))
    import signal
    from multiprocessing.connection import Connection

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is for the parent, which stops its workers
    conn_in = Connection(int(read_fd), writable=False)
    conn_out = Connection(int(write_fd), readable=False)
    function = _import(target)
    import importlib

    for module in filter(None, preload.split(",")):
        try:
            importlib.import_module(module)
        except ImportError:  # the task reports it, if it needs the module
            pass
    _CONN = conn_out
    if __name__ == "__main__":  # run as a script: the task code imports this module under its real name
        importlib.import_module("olado.bench._worker")._CONN = conn_out
    conn_out.send(("ready",))
    while True:
        try:
            task = conn_in.recv()
        except (EOFError, OSError):
            return 0
        if task is None:
            return 0
        try:
            answer = (True, function(task))
        except Exception as exc:  # noqa: BLE001 - reported to the parent as the task's failure
            import traceback

            answer = (False, f"{type(exc).__name__}: {exc}"[:500], traceback.format_exc()[-1500:])
        try:
            conn_out.send(answer)
        except (BrokenPipeError, OSError):
            return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
