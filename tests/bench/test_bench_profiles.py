"""Performance profiles (paper 001 eqs. (48)-(51)) against a hand computation, the tables, the
comparison of two runs, and the ``--where`` language."""

import math

import numpy as np
import pytest

import olado.bench as bench
from olado.bench.profiles import compare_runs, format_table, per_problem_table, summary_table
from olado.errors import ConfigError


def rec(problem, config, time_s, ok=True, sqp=5, N=10, objective=1.0, status=None):
    return {"problem": problem, "N": N, "start": "problem", "config": config, "config_hash": config,
            "success": ok, "status": status or ("success" if ok else "max_iterations"), "solve_s": time_s,
            "sqp_iterations": sqp, "qp_iterations": 3 * sqp, "function_evaluations": sqp + 1,
            "objective": objective, "message": ""}


# times (A, B); None = failed. Ratios by hand (49), r_M = 2 * max finite ratio = 2 * 4 = 8:
#   p1: 1, 2 -> A 1, B 2      p2: 4, 1 -> A 4, B 1       p3: fail, 6 -> A r_M, B 1
#   p4: fail, fail -> r_M, r_M                            p5: 2, 2 -> 1, 1 (a tie: both win)
#   p6: A only -> left out (not run by B)
TIMES = {"p1": (1.0, 2.0), "p2": (4.0, 1.0), "p3": (None, 6.0), "p4": (None, None), "p5": (2.0, 2.0)}
RECORDS = [rec(p, c, t if t is not None else 0.5, ok=t is not None)
           for p, ts in TIMES.items() for c, t in zip("AB", ts)] + [rec("p6", "A", 1.0)]


def test_ratios_and_profile_by_hand():
    prof = bench.performance_profile(RECORDS, "time")
    assert prof.configs == ["A", "B"] and prof.dropped == 1
    assert prof.r_M == 8.0
    ratios = dict(zip([p[0] for p in prof.problems], prof.ratios.tolist()))
    assert ratios == {"p1": [1, 2], "p2": [4, 1], "p3": [8, 1], "p4": [8, 8], "p5": [1, 1]}
    phi = prof.phi([0.0, 1.0, 2.0, 2.99, 3.0])
    np.testing.assert_allclose(phi[0], [2 / 5, 2 / 5, 3 / 5, 3 / 5, 1.0])
    np.testing.assert_allclose(phi[1], [3 / 5, 4 / 5, 4 / 5, 4 / 5, 1.0])
    np.testing.assert_allclose(prof.wins(), [2 / 5, 3 / 5])
    np.testing.assert_allclose(prof.solved_share(), [3 / 5, 4 / 5])      # phi(log2 r_M^-), eq. (51)


def test_iteration_metric_and_floor():
    records = [rec("p", "A", 1.0, sqp=0), rec("p", "B", 1.0, sqp=3)]
    prof = bench.performance_profile(records, "sqp")
    assert prof.ratios.tolist() == [[1.0, 3.0]]                          # 0 iterations floored at 1
    prof = bench.performance_profile(records, "qp")
    assert prof.ratios.tolist() == [[1.0, 9.0]]


def test_where_selects_the_subset():
    records = [rec("p", c, t, N=N) for N in (100, 216, 300) for c, t in (("A", 1.0), ("B", N / 100))]
    prof = bench.performance_profile(records, "time", where="N >= 216")
    assert [p[1] for p in prof.problems] == [216, 300]
    np.testing.assert_allclose(prof.ratios, [[1.0, 2.16], [1.0, 3.0]])


def test_unknown_metric_and_config():
    with pytest.raises(ConfigError, match="unknown metric 'speed'"):
        bench.performance_profile(RECORDS, "speed")
    with pytest.raises(ConfigError, match="no record of the configuration 'C'"):
        bench.performance_profile(RECORDS, "time", configs=["C"])


def test_tables():
    prof = bench.performance_profile(RECORDS, "time")
    header, rows = summary_table(RECORDS, [prof])
    assert header[:5] == ["config", "solved", "time phi(0)", "time phi(1)", "time phi(2)"]
    assert rows[0][:5] == ["A", "3 / 5", "0.40", "0.40", "0.60"]
    assert rows[1][:5] == ["B", "4 / 5", "0.60", "0.80", "0.80"]
    md = format_table(header, rows, "md").splitlines()
    assert md[0].startswith("| config | solved |") and md[2].startswith("| A | 3 / 5 |")
    csv = format_table(header, rows, "csv").splitlines()
    assert csv[1].startswith("A,3 / 5,0.40")
    header, rows = per_problem_table(RECORDS)
    assert header[:4] == ["problem", "N", "start", "A status"]
    assert [r[0] for r in rows] == ["p1", "p2", "p3", "p4", "p5", "p6"] and rows[-1][8] == ""


def test_plot_is_written(tmp_path):
    profiles = [bench.performance_profile(RECORDS, m) for m in ("time", "sqp")]
    bench.plot_profiles(profiles, tmp_path / "p.svg")
    text = (tmp_path / "p.svg").read_text()
    assert text.lstrip().startswith("<?xml") and "</svg>" in text


def test_compare_runs():
    old = [rec("p1", "A", 1.0), rec("p2", "A", 1.0), rec("p3", "A", 1.0, ok=False), rec("p4", "A", 1.0),
           rec("p5", "A", 1.0)]
    new = [rec("p1", "A", 1.0, ok=False), rec("p2", "A", 1.0, objective=1.01), rec("p3", "A", 1.0),
           rec("p4", "A", 2.0), rec("p6", "A", 1.0)]
    c = compare_runs(new, old, rtol=1e-6, slower=1.5)
    assert len(c.regressions) == 1 and c.regressions[0].startswith("A: p1 N=10 start problem: success -> max_iterations")
    assert len(c.fixed) == 1 and "p3" in c.fixed[0]
    assert len(c.objective_changes) == 1 and "p2" in c.objective_changes[0] and "+1.0e-02" in c.objective_changes[0]
    assert len(c.slower) == 1 and "p4" in c.slower[0] and "2.00x" in c.slower[0]
    assert (c.matched, c.only_old, c.only_new) == (4, 1, 1) and c.has_regressions
    assert not compare_runs(old, old).has_regressions


# ---------------------------------------------------------------------------- --where
R = {"N": 216, "problem": "zambezi12", "start": "sif", "success": True, "status": "acceptable",
     "objective": -1.5, "machine": {"host": "vm"}, "kkt_residual": None}


@pytest.mark.parametrize("text, expected", [
    ("N >= 216", True), ("N > 216", False), ("N==216 and problem == 'zambezi12'", True),
    ('start != "sif" or N < 100', False), ("not (N < 100)", True), ("status in ['success', 'acceptable']", True),
    ("problem not in ['zambezi8', 'zambezi9']", True), ("success", True), ("not success", False),
    ("machine.host == 'vm'", True), ("objective < -1", True), ("N >= 2.16e2", True),
    ("kkt_residual < 1", False), ("kkt_residual == null", True), ("problem < 3", False),
    ("missing_field == 1 or N == 216", True), ("(N >= 200 and N <= 300) and not start == 'balance'", True),
])
def test_where_evaluates(text, expected):
    assert bench.parse_where(text)(R) is expected


@pytest.mark.parametrize("text, message", [
    ("N >=", "expected a field, a number, a quoted string, '(' or '[', found the end at column 5"),
    ("N = 216", "unexpected character '=' at column 3"),
    ("N >= 216)", "expected 'and', 'or' or the end, found ')' at column 9"),
    ("problem == 'zambezi", "unterminated string at column 12"),
    ("", "empty expression"),
    ("(N > 1", "expected ')', found the end"),
    ("status in ['a' 'b']", "expected ',' or ']'"),
    ("__import__('os')", "found '(' at column 11"),
    ("open('x').read()", "unexpected character '.' at column 10"),
    ("N >= 1 and", "found the end at column 11"),
    ("N ! 3", "unexpected character '!'"),
])
def test_where_errors_are_named(text, message):
    with pytest.raises(ConfigError) as info:
        bench.parse_where(text)
    assert "key '--where'" in str(info.value) and message in str(info.value)


def test_where_unknown_field_is_named():
    with pytest.raises(ConfigError, match=r"no record has the field 'n'.*allowed: N, "):
        bench.performance_profile(RECORDS, "time", where="n >= 216")


def test_where_never_evaluates_python():
    w = bench.parse_where("problem == '__import__(\"os\")'")
    assert w({"problem": '__import__("os")'}) is True and math.isfinite(1.0)
