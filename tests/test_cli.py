"""The olado command line: list, solve, --set, exit codes 0 / 1 / 2, no tracebacks on bad input."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from olado.cli import main
from olado.solvers import registry
from fixtures import REPO



def ipopt_available():
    return registry.get_solver_class("ipopt").available()


needs_ipopt = pytest.mark.skipif(not ipopt_available(), reason="cyipopt not installed")


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


# ---------------------------------------------------------------------------- list
def test_list(capsys):
    code, out, err = run(capsys, "list")
    assert code == 0 and err == ""
    problems, solvers = out.split("solvers:")
    assert "problems:" in problems
    for name in ("zambezi", "zambezi8", "zambezi12"):
        assert f"  {name} " in problems
    for name in ("ipopt", "slsqp", "trust-constr"):
        assert f"  {name} " in solvers


def test_list_marks_missing_backend(capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "cyipopt", None)  # importlib.util.find_spec then finds nothing
    code, out, _ = run(capsys, "list")
    assert code == 0
    line = next(l for l in out.splitlines() if l.strip().startswith("ipopt"))
    assert "not installed" in line and "cyipopt-wheels" in line
    line = next(l for l in out.splitlines() if l.strip().startswith("slsqp"))
    assert "not installed" not in line


# ---------------------------------------------------------------------------- solve
@needs_ipopt
def test_solve_zambezi12_saves_json_and_plot(capsys, tmp_path):
    save, plot = tmp_path / "out.json", tmp_path / "out.png"
    code, out, err = run(capsys, "solve", "zambezi12", "--N", "12", "--set", "ipopt.tol=1e-9",
                         "--set", "ipopt.raw.print_level=0", "--save", str(save), "--plot", str(plot))
    assert code == 0, err
    # Table-1 counts of zambezi12 at N=12 (6 states, 7 controls)
    assert "variables 162" in out and "equalities 78" in out and "inequalities 272" in out
    assert "status       : success" in out and "solved by ipopt" in out
    data = json.loads(save.read_text())
    for key in ("problem", "N", "solver", "status", "success", "objective", "max_constraint_violation",
                "iterations", "qp_iterations", "time_s", "x", "u"):
        assert key in data, key
    assert data["problem"].startswith("zambezi12") and data["N"] == 12 and data["solver"] == "ipopt"
    assert data["success"] is True and data["options"]["tol"] == 1e-9
    assert data["options"]["ipopt_options"] == {"print_level": 0}
    assert len(data["x"]) == 13 and len(data["x"][0]) == 6 and len(data["u"]) == 12
    assert data["objective"] < 0
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert save.with_suffix(".npz").exists()


def test_not_converged_exits_1(capsys):
    code, out, err = run(capsys, "solve", "zambezi12", "--N", "12", "--solver", "slsqp",
                         "--set", "slsqp.max_iter=1")
    assert code == 1, err
    assert "max_iterations" in out


@needs_ipopt
def test_config_problem_section_and_quiet(capsys, tmp_path):
    ini = tmp_path / "run.ini"
    ini.write_text("[solver]\nname = ipopt\n[ipopt]\ntol = 1e-8\n[problem]\nname = zambezi12\nN = 12\n"
                   "start = sif\n")
    save = tmp_path / "r.json"
    code, out, err = run(capsys, "solve", "--config", str(ini), "--quiet", "--save", str(save))
    assert code == 0, err
    assert out == "" and err == ""
    data = json.loads(save.read_text())
    assert data["N"] == 12 and data["solver"] == "ipopt"
    # the command line wins over the [problem] section
    code, out, err = run(capsys, "solve", "--config", str(ini), "--N", "24", "--quiet", "--save", str(save))
    assert code == 0, err
    assert json.loads(save.read_text())["N"] == 24


@pytest.mark.parametrize("argv,fragment", [
    (["solve", "nosuchproblem"], "unknown problem 'nosuchproblem'"),
    (["solve", "zambezi12", "--N", "12", "--config", "/nonexistent/olado.ini"], "/nonexistent/olado.ini"),
    (["solve", "zambezi12", "--N", "12", "--set", "ipopt.tol=abc"], "key 'tol'"),
    (["solve", "zambezi12", "--N", "12", "--set", "ipopt.toll=1"], "unknown option"),
    (["solve", "zambezi12", "--N", "12", "--set", "nosection.key=1"], "unknown section"),
    (["solve", "zambezi12", "--N", "12", "--set", "tol"], "section.key=value"),
    (["solve", "zambezi12", "--N", "12", "--solver", "nope"], "unknown solver 'nope'"),
    (["solve", "zambezi12", "--N", "0"], "N"),
    (["solve", "zambezi12", "--N", "12", "--start", "nowhere"], "start"),
    (["solve", "zambezi12", "--N", "twelve"], "invalid int value"),
    (["solve"], "no problem given"),
    (["frobnicate"], "invalid choice"),
    ([], "usage"),
])
def test_bad_input_exits_2_without_traceback(capsys, argv, fragment):
    code, out, err = run(capsys, *argv)
    assert code == 2
    assert fragment in err, err
    assert "Traceback" not in err + out


def test_unwritable_output_exits_2(capsys, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    code, out, err = run(capsys, "solve", "zambezi12", "--N", "12", "--solver", "slsqp",
                         "--set", "slsqp.max_iter=1", "--save", str(blocker / "sub" / "r.json"))
    assert code == 2 and "Traceback" not in err and "olado: error" in err


# ---------------------------------------------------------------------------- as a program
def test_python_dash_m(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "olado", "list"], capture_output=True, text=True,
                          cwd=REPO, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "zambezi12" in proc.stdout and "slsqp" in proc.stdout
    proc = subprocess.run([sys.executable, "-m", "olado", "solve", "nosuchproblem"],
                          capture_output=True, text=True, cwd=REPO, timeout=120)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr


@pytest.mark.parametrize("argv,code", [(["list"], 0), (["solve", "nosuchproblem"], 2)])
def test_run_exits_with_mains_code_after_freezing_the_heap(argv, code):
    script = ("import atexit, gc, sys\n"
              "atexit.register(lambda: print('frozen at exit:', gc.get_freeze_count() > 0))\n"
              f"sys.argv = ['olado', *{argv!r}]\n"
              "from olado.cli import run\n"
              "run()\n"
              "print('not reached')\n")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert proc.returncode == code, proc.stderr
    assert proc.stdout.rstrip().endswith("frozen at exit: True") and "not reached" not in proc.stdout


def _console_script():
    """The installed ``olado`` command of this interpreter's environment, else one on PATH."""
    beside = Path(sys.executable).parent / "olado"
    return str(beside) if beside.exists() else shutil.which("olado")


@pytest.mark.skipif(_console_script() is None, reason="olado is not installed as a command")
def test_console_script():
    import olado

    proc = subprocess.run([_console_script(), "--version"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == f"olado {olado.__version__}"
    proc = subprocess.run([_console_script(), "solve", "zambezi12", "--N", "12", "--solver", "slsqp",
                           "--set", "slsqp.max_iter=1", "--quiet"], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 1, proc.stderr
