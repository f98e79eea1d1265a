"""The solver table (olado.solvers.registry.SOLVERS): names, summaries, availability, and that
choosing or listing solvers imports only what is needed."""

import json
import subprocess
import sys

import pytest

import olado
from olado._registry import Entry
from olado.config import config_from_kwargs, default_solver_name, load_config
from olado.errors import ConfigError, SolverNotAvailableError
from olado.solvers.base import Solver
from olado.solvers.control.penalty import INNER_METHODS, _inner_solver_class
from olado.solvers.registry import SOLVERS, get_solver_class
from fixtures import CONFIGS, REPO

NAMES = ["cg", "ddp", "fqlnk", "gradient", "ipm", "ipopt", "newton", "pdmin", "penalty", "slsqp", "sqp", "stagewise-newton",
         "trust-constr", "variable-metric"]


def modules_after(code: str) -> set:
    """The modules imported by running ``code`` in a fresh interpreter in the repository."""
    script = code + "\nimport json, sys\nprint(json.dumps(sorted(sys.modules)))\n"
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=REPO, timeout=300)
    assert out.returncode == 0, out.stderr
    return set(json.loads(out.stdout.strip().splitlines()[-1]))


# ---------------------------------------------------------------------------- the table
def test_table_names_classes_and_summaries():
    assert list(SOLVERS) == NAMES
    for name in NAMES:
        cls = SOLVERS[name]
        assert issubclass(cls, Solver) and cls.name == name
        assert cls.summary() == SOLVERS.summary(name) and SOLVERS.summary(name)
        # the summary is declared once, in the table
        assert not any("description" in vars(c) for c in cls.__mro__), name


def test_unregistered_solver_summary_is_its_docstring():
    class Custom(Solver):
        """A custom solver.

        More text."""

        name = "custom"

    assert Custom.summary() == "A custom solver."


def test_unknown_solver_names_the_allowed_ones():
    for call in (lambda: SOLVERS["nope"], lambda: get_solver_class("nope"), lambda: config_from_kwargs("nope"),
                 lambda: olado.solve(_Dummy(), solver="nope")):
        with pytest.raises(ConfigError) as exc:
            call()
        assert "unknown solver 'nope'" in str(exc.value)
        assert exc.value.allowed == ", ".join(NAMES)


class _Dummy:  # olado.solve resolves the solver before it looks at the problem
    pass


# ---------------------------------------------------------------------------- availability
def test_available_default_and_ipopt(monkeypatch):
    assert Solver.available() is True
    assert all(SOLVERS[name].available() for name in NAMES if name != "ipopt")
    assert SOLVERS.missing("sqp") == [] and SOLVERS.entry("ipopt").requires == ("cyipopt",)
    monkeypatch.setitem(sys.modules, "cyipopt", None)  # `import cyipopt` fails, find_spec finds nothing
    assert SOLVERS["ipopt"].available() is False
    assert SOLVERS.missing("ipopt") == ["cyipopt"]
    assert default_solver_name() == "trust-constr"


def test_ipopt_available_when_cyipopt_imports():
    pytest.importorskip("cyipopt")
    assert SOLVERS["ipopt"].available() is True and SOLVERS.missing("ipopt") == []
    assert default_solver_name() == "ipopt"


def test_broken_backend_counts_as_missing(monkeypatch):
    import olado.solvers.nlp.ipopt as ipopt_module

    def broken():
        raise OSError("libipopt.so: cannot open shared object file")

    monkeypatch.setattr(ipopt_module, "import_cyipopt", broken)
    assert SOLVERS["ipopt"].available() is False


# ---------------------------------------------------------------------------- penalty's inner solvers
def test_penalty_inner_solvers_come_from_the_registry():
    assert INNER_METHODS[0] == "lbfgsb"
    for name in INNER_METHODS[1:]:
        assert _inner_solver_class(name) is SOLVERS[name]


def test_penalty_inner_solver_that_cannot_be_imported():
    SOLVERS.add("broken-inner", Entry("olado_test_module_that_does_not_exist:Solver"))
    try:
        with pytest.raises(SolverNotAvailableError) as exc:
            _inner_solver_class("broken-inner")
    finally:
        SOLVERS.remove("broken-inner")
    assert "olado_test_module_that_does_not_exist" in str(exc.value) and "inner = lbfgsb" in str(exc.value)


# ---------------------------------------------------------------------------- what gets imported
SOLVER_MODULES = {"olado.solvers.control.ddp", "olado.solvers.control.pdmin", "olado.solvers.control.penalty",
                  "olado.solvers.control.reduced_gradient", "olado.solvers.nlp.ipopt",
                  "olado.solvers.nlp.scipy_nlp", "olado.solvers.sqp.solver"}


def test_list_imports_no_solver_module():
    mods = modules_after("import contextlib, io\nfrom olado.cli import main\n"
                         "with contextlib.redirect_stdout(io.StringIO()):\n    assert main(['list']) == 0")
    assert not mods & SOLVER_MODULES, mods & SOLVER_MODULES
    assert not {m for m in mods if m.startswith(("scipy.optimize", "cyipopt", "matplotlib"))}


def test_loading_a_config_imports_only_its_solver():
    mods = modules_after(f"from olado.config import load_config\nload_config({str(CONFIGS / 'sqp-ip.ini')!r})")
    assert mods & SOLVER_MODULES == {"olado.solvers.sqp.solver"}


def test_sqp_ip_solve_imports_only_what_it_needs():
    mods = modules_after("import contextlib, io\nfrom olado.cli import main\n"
                         "with contextlib.redirect_stdout(io.StringIO()):\n"
                         "    assert main(['solve', 'zambezi12', '--N', '12', '--config', 'configs/sqp-ip.ini']) == 0")
    assert "olado.solvers.sqp.solver" in mods and "olado.qp.interior_point" in mods  # it did solve
    for unwanted in ("olado.solvers.control.ddp", "olado.solvers.nlp.scipy_nlp", "olado.solvers.nlp.ipopt",
                     "olado.qp.external", "scipy.optimize", "cyipopt", "matplotlib", "qpsolvers"):
        assert unwanted not in mods, unwanted

