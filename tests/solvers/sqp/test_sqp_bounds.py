"""The simple-bounds versions of Powell's and Schittkowski's SQP (paper 001 sec. 2.2; presets
configs/sqp-bounds.ini and configs/sqp-schittkowski-bounds.ini, QP method olado.qp.bounds):
against IPOPT (configs/ipopt.ini) on the bounds-only problems of the built-ins and of the
robustness set, and their refusal of problems with general constraints."""

from pathlib import Path

import numpy as np
import pytest

import olado
from olado.errors import ConfigError
from olado.problems import PROBLEMS
from olado.problems.suites import load_references, load_suite
from olado.qp.bounds import PrimalDualActiveSetQP
from olado.result import Status

pytest.importorskip("cyipopt")
CONFIGS = Path(__file__).resolve().parents[3] / "configs"
PRESETS = ("sqp-bounds", "sqp-schittkowski-bounds")
#: bounds-only entries of the robustness set (control bounds; a state bound: vanderpol-path; zambezi12)
ENTRIES = ("lq-box", "vanderpol-box", "rayleigh-box", "vanderpol-path", "lotka-fishing", "batch-reactor",
           "catalyst-mixing", "zambezi12-N72-sif")


@pytest.fixture
def qp_solvers(monkeypatch):
    """The ``solver`` names of the QP results of the solves in the test ('bounds': the active-set
    iteration solved the QP; 'bounds+mehrotra': the fallback did)."""
    names = []
    solve = PrimalDualActiveSetQP.solve

    def spy(self, qp, warm_start=None, limits=None):
        res = solve(self, qp, warm_start=warm_start, limits=limits)
        names.append(res.solver)
        return res

    monkeypatch.setattr(PrimalDualActiveSetQP, "solve", spy)
    return names


@pytest.mark.parametrize("preset", PRESETS)
@pytest.mark.parametrize("name", ENTRIES)
def test_presets_reach_ipopt_on_the_bounds_only_robustness_entries(name, preset, qp_solvers):
    entry = {e.name: e for e in load_suite()}[name]
    ref = load_references()["entries"][name]
    assert ref["status"] == "success"
    problem, guess = entry.build()
    assert problem.r == 0 and problem.rN == 0
    r = olado.solve(problem, config=CONFIGS / f"{preset}.ini", guess=guess)
    assert r.status is Status.SUCCESS, r.message
    assert r.info["qp"] == "bounds"
    assert abs(r.objective - ref["objective"]) <= 1e-6 * max(1.0, abs(ref["objective"]))
    assert r.max_constraint_violation < 1e-8
    assert qp_solvers and all(s.startswith("bounds") for s in qp_solvers)
    states_bounded = np.isfinite(problem.x_lower[1:]).any() or np.isfinite(problem.x_upper[1:]).any()
    if not states_bounded:      # control bounds only: the active-set iteration solves most QPs itself
        assert qp_solvers.count("bounds") >= len(qp_solvers) / 2, qp_solvers
    else:                       # state bounds: the interior-point method (state_bounds = 'interior-point')
        assert set(qp_solvers) == {"bounds+mehrotra"}


@pytest.mark.parametrize("preset", PRESETS)
@pytest.mark.parametrize("name", ["vanderpol-box", "rayleigh-box"])
def test_presets_reach_ipopt_at_a_longer_horizon(name, preset):
    ref = olado.solve(PROBLEMS[name](N=400), config=CONFIGS / "ipopt.ini")
    r = olado.solve(PROBLEMS[name](N=400), config=CONFIGS / f"{preset}.ini")
    assert ref.status is Status.SUCCESS and r.status is Status.SUCCESS, r.message
    assert abs(r.objective - ref.objective) <= 1e-6 * max(1.0, abs(ref.objective))
    # the bound and dynamics multipliers agree with IPOPT's
    for key in ("bound_lower_u", "bound_upper_u", "dynamics"):
        a, b = r.multipliers[key], ref.multipliers[key]
        assert np.max(np.abs(a - b)) <= 1e-4 * (1 + np.max(np.abs(b))), key


@pytest.mark.parametrize("preset", PRESETS)
def test_presets_refuse_problems_with_general_constraints(preset):
    with pytest.raises(ConfigError) as exc:
        olado.solve(PROBLEMS["rayleigh-mixed"](N=20), config=CONFIGS / f"{preset}.ini")
    msg = str(exc.value)
    assert "key 'qp'" in msg and "1 stage constraint g^k" in msg and "simple bounds" in msg and "mehrotra" in msg
    with pytest.raises(ConfigError, match="2 final constraints g"):
        olado.solve(PROBLEMS["double-integrator"](N=20), config=CONFIGS / f"{preset}.ini")
