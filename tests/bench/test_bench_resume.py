"""The store and resume semantics (issue 14, "what it must show"): ``kill -9`` of a running
``olado bench`` and a restart leave exactly one record per key, with the statuses and objectives
of an uninterrupted run; an incomplete last line is dropped on opening, a damaged line elsewhere
is an error naming the line; two runs cannot write one store."""

import json
import os
import signal
import subprocess
import time

import pytest

import olado.bench as bench
from olado.errors import ConfigError, ResultFileError
from fixtures.bench_helpers import SQP, by_key, cli_env, olado_cmd, store_lines, write_suite

# slow_lq sleeps 0.4 s while it builds (twice for a worker's first solve: the warm-up), so a run of
# these 8 solves lasts several seconds and the kill lands in the middle of it
SUITE = """
[[problem]]
problem = "fixtures.bench_problems:slow_lq"
name = "slow-lq"
N = [4, 5, 6, 7, 8, 9, 10, 11]
settings = { delay = 0.4 }
"""


def _bench(suite, store):
    return olado_cmd("bench", str(suite), "--config", SQP, "--store", str(store), "--jobs", "1",
                     "--time-limit", "120", "--quiet")


def test_kill_and_resume_equals_an_uninterrupted_run(tmp_path):
    suite = write_suite(tmp_path, SUITE)
    store = tmp_path / "killed.jsonl"
    proc = subprocess.Popen(_bench(suite, store), env=cli_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while len(store_lines(store)) < 2 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert proc.poll() is None, "the run ended before it could be killed: " + proc.stderr.read().decode()[-500:]
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(30)
    killed_at = len(store_lines(store))
    assert 2 <= killed_at < 8
    # the restart runs the rest only
    done = subprocess.run(_bench(suite, store), env=cli_env(), capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    resumed = store_lines(store)
    keys = [(r["problem"], r["N"], r["start"], r["config_hash"]) for r in resumed]
    assert len(keys) == len(set(keys)) == 8
    # an uninterrupted run of the same suite, in this process
    reference = bench.run(suite, [SQP], tmp_path / "whole.jsonl", limits=bench.Limits(time_limit=120.0),
                          progress=False)
    ref = by_key(reference.records)
    got = by_key(resumed)
    assert set(got) == set(ref)
    for key, (status, objective) in ref.items():
        assert status == "success" and got[key][0] == status
        assert got[key][1] == pytest.approx(objective, rel=1e-12, abs=1e-14)
    # a third run finds nothing to do
    again = subprocess.run(_bench(suite, store), env=cli_env(), capture_output=True, text=True, timeout=120)
    assert again.returncode == 0 and len(store_lines(store)) == 8


def _record(problem, N, config_hash="abc", **extra):
    return {"problem": problem, "N": N, "start": "problem", "config_hash": config_hash, "config": "c",
            "status": "success", "success": True, "objective": 1.0, **extra}


def test_incomplete_last_line_is_dropped_and_rerun(tmp_path):
    path = tmp_path / "store.jsonl"
    good = json.dumps(_record("a", 1)) + "\n"
    path.write_text(good + json.dumps(_record("b", 2))[:25], encoding="utf-8")
    assert [r["problem"] for r in bench.read_records(path)] == ["a"]        # readers ignore it
    with bench.ResultStore(path) as store:
        assert store.repaired == 25 and store.keys() == {("a", 1, "problem", "abc")}
        store.append(_record("b", 2))
    assert path.read_text(encoding="utf-8") == good + json.dumps(_record("b", 2), sort_keys=True) + "\n"


def test_damaged_line_is_an_error_naming_it(tmp_path):
    path = tmp_path / "store.jsonl"
    path.write_text(json.dumps(_record("a", 1)) + "\n{not json\n" + json.dumps(_record("b", 1)) + "\n")
    with pytest.raises(ResultFileError, match=r"store.jsonl: line 2 is not a JSON record"):
        bench.read_records(path)
    with pytest.raises(ResultFileError, match="line 2"):
        bench.ResultStore(path).open()


def test_duplicate_keys_keep_the_last_record(tmp_path):
    path = tmp_path / "store.jsonl"
    path.write_text("".join(json.dumps(_record("a", 1, objective=v)) + "\n" for v in (1.0, 2.0)))
    (rec,) = bench.read_records(path)
    assert rec["objective"] == 2.0
    assert len(bench.read_records(path, last_per_key=False)) == 2


def test_one_writer_per_store(tmp_path):
    path = tmp_path / "store.jsonl"
    with bench.ResultStore(path):
        with pytest.raises(ConfigError, match="in use by another run"):
            bench.ResultStore(path).open()
    with bench.ResultStore(path) as again:      # released on close
        assert again.records == []


def test_missing_store_is_an_error(tmp_path):
    with pytest.raises(ResultFileError, match="no such results store"):
        bench.read_records(tmp_path / "nothing.jsonl")
