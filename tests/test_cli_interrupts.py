"""Signals sent to a real ``olado solve`` process (docs/interrupts.md): the first SIGINT or
SIGTERM stops the solver at its next safe point, the result is printed and saved (``--save``:
a complete file that Result.load reads, status interrupted, the last accepted iterate), and the
process ends with 128 + the signal number; a second SIGINT aborts at once and saves nothing."""

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from olado.result import Result, Status

from fixtures import CONFIGS, REPO


def default_signals():
    """SIGINT and SIGTERM at their defaults in the child (a test run started as a background job
    of a non-interactive shell has SIGINT ignored, and ignored signals are inherited)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def start(tmp_path, *options):
    """``olado solve zambezi12 --N 2400 --save out.json`` started; returns when the solve begins
    (the CLI prints the solver line, flushed, just before it)."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    proc = subprocess.Popen([sys.executable, "-m", "olado", "solve", "zambezi12", "--N", "2400",
                             "--save", str(tmp_path / "out.json"), *options],
                            cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=default_signals)
    lines = []
    while True:
        line = proc.stdout.readline()
        assert line, f"olado ended before the solve started: {proc.communicate()}"
        lines.append(line)
        if line.startswith("solver "):
            return proc, lines


def finish(proc, lines):
    out, err = proc.communicate(timeout=300)
    return proc.returncode, "".join(lines) + out, err


@pytest.mark.parametrize("signum,options", [(signal.SIGINT, ()),
                                            (signal.SIGTERM, ("--config", str(CONFIGS / "sqp-ip.ini")))],
                         ids=["sigint-ipopt", "sigterm-sqp"])
def test_first_signal_saves_the_interrupted_result(tmp_path, signum, options):
    proc, lines = start(tmp_path, *options)
    time.sleep(0.5)
    sent = time.perf_counter()
    proc.send_signal(signum)
    code, out, err = finish(proc, lines)
    assert code == 128 + signum, (out, err)
    assert time.perf_counter() - sent < 60
    name = signal.Signals(signum).name
    assert f"{name} received, stopping at the next safe point" in err and "Traceback" not in err
    assert f"status       : interrupted -- interrupted ({name})" in out and "saved result to" in out
    result = Result.load(tmp_path / "out.json")
    assert result.status is Status.INTERRUPTED and f"interrupted ({name})" in result.message
    assert result.x.shape == (2401, 6) and result.u.shape == (2400, 7)
    assert np.all(np.isfinite(result.x)) and np.isfinite(result.objective)
    assert 0.0 <= result.info["interrupt_latency_s"] < 5.0
    assert not list(tmp_path.glob(".*.tmp"))        # no temporary file left behind


def test_second_sigint_aborts_without_saving(tmp_path):
    proc, lines = start(tmp_path, "--config", str(CONFIGS / "sqp-ip.ini"))
    time.sleep(0.5)
    proc.send_signal(signal.SIGINT)
    time.sleep(0.05)            # the first is handled (a stop requested) before the second comes
    proc.send_signal(signal.SIGINT)
    code, out, err = finish(proc, lines)
    assert code == 130, (out, err)
    assert "olado: aborted" in err and "Traceback" not in err
    assert not (tmp_path / "out.json").exists() and not list(tmp_path.glob(".*.tmp"))
