"""Bad-input catalogue, part 4: the command line. Bad input exits with code 2 and one line on
stderr naming the option, key or setting -- never a traceback (docs/errors.md)."""

import pytest

from olado.cli import main
from fixtures import CONFIGS

BIG = "99999999999999999999"


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


CLI_CASES = [
    ("int-option-overflow", ["solve", "zambezi12", "--N", "12", "--set", f"ipopt.max_iter={BIG}"],
     ["[ipopt]", "'max_iter'", "out of range"]),
    ("ipopt-raw-overflow", ["solve", "lq", "--N", "4", "--solver", "ipopt", "--set", f"ipopt.raw.max_iter={BIG}"],
     ["[ipopt.raw]", "'max_iter'", "IPOPT rejected"]),
    ("ipopt-raw-unknown", ["solve", "lq", "--N", "4", "--solver", "ipopt", "--set", "ipopt.raw.no_such_option=1"],
     ["[ipopt.raw]", "'no_such_option'"]),
    ("qp-raw-overflow", ["solve", "zambezi12", "--N", "12", "--config", str(CONFIGS / "sqp-osqp.ini"),
                         "--set", f"sqp.raw.max_iter={BIG}"], ["[sqp.raw", "'max_iter'", "out of range"]),
    ("start-for-lq", ["solve", "lq", "--N", "10", "--start", "sif"],
     ["'start'", "problem 'lq' takes no setting 'start'", "allowed: N"]),
    ("year-for-lq-box", ["solve", "lq-box", "--N", "10", "--year", "1950"], ["'year'", "'lq-box'"]),
    ("year-for-vanderpol", ["solve", "vanderpol", "--year", "1950"], ["'year'", "'vanderpol'"]),
    ("N-beyond-memory", ["solve", "zambezi12", "--N", "120000000000"],
     ["'N'", "N=120000000000", "cannot fit in memory", "GiB"]),
    ("N-beyond-memory-lq", ["solve", "lq", "--N", str(10**13)], ["'N'", "cannot fit in memory"]),
    ("N-not-years", ["solve", "zambezi12", "--N", "13"], ["'N'", "multiple of 12"]),
    ("N-negative", ["solve", "zambezi12", "--N", "-12"], ["'N'", ">= 1"]),
    ("N-text", ["solve", "zambezi12", "--N", "twelve"], ["--N", "invalid int value"]),
    ("year-outside-record", ["solve", "zambezi12", "--N", "12", "--year", "1800"], ["'year'", "1930..1965"]),
    ("start-unknown", ["solve", "zambezi12", "--N", "12", "--start", "nowhere"], ["'start'", "'nowhere'"]),
    ("plot-format", ["solve", "lq", "--N", "4", "--plot", "out.xyz"], ["'--plot'", ".xyz", ".png"]),
    ("config-folder", ["solve", "lq", "--config", "."], ["configuration path is a directory"]),
    ("config-missing", ["solve", "lq", "--config", "/nonexistent/x.ini"], ["/nonexistent/x.ini", "not found"]),
    ("solver-unknown", ["solve", "lq", "--solver", "nope"], ["unknown solver 'nope'"]),
    ("problem-unknown", ["solve", "nosuchproblem"], ["unknown problem 'nosuchproblem'", "zambezi12"]),
    ("no-problem", ["solve"], ["no problem given"]),
    ("unknown-command", ["frobnicate"], ["invalid choice"]),
    ("unknown-flag", ["solve", "lq", "--fast"], ["unrecognized arguments: --fast"]),
]


@pytest.mark.parametrize("case_id,argv,names", CLI_CASES, ids=[c[0] for c in CLI_CASES])
def test_bad_command_line(capsys, case_id, argv, names):
    code, out, err = run(capsys, *argv)
    assert code == 2, (code, out, err)
    assert "Traceback" not in out + err
    for name in names:
        assert name in err, f"{name!r} not in: {err}"


def test_save_into_an_existing_folder(capsys, tmp_path):
    code, _, err = run(capsys, "solve", "lq", "--N", "4", "--save", str(tmp_path))
    assert code == 2 and "'--save'" in err and "is a folder" in err


def test_save_below_a_file_is_refused_before_the_solve(capsys, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    code, out, err = run(capsys, "solve", "lq", "--N", "4", "--save", str(blocker / "sub" / "r.json"))
    assert code == 2 and "'--save'" in err and "not a writable folder" in err
    assert "olado result" not in out          # refused before solving: no work was lost


def test_problem_section_of_a_config_for_the_wrong_problem(capsys, tmp_path):
    ini = tmp_path / "lq.ini"
    ini.write_text("[solver]\nname = slsqp\n[problem]\nname = lq\nN = 4\nstart = sif\n")
    code, _, err = run(capsys, "solve", "--config", str(ini))
    assert code == 2 and "problem 'lq' takes no setting 'start'" in err


def test_not_converged_is_exit_1_not_an_error(capsys):
    code, out, err = run(capsys, "solve", "lq", "--N", "4", "--solver", "slsqp", "--set", "slsqp.max_iter=1")
    assert code == 1 and "max_iterations" in out and err == ""
