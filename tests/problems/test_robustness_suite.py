"""The robustness suite as data (olado/problems/suites): every entry builds, has an IPOPT
reference and a stated source; published values appear in the problems' docstrings; perturbed
starts are seeded and inside the bounds; small entries solved by IPOPT match their stored
reference; the independent point check (verify_point) against hand-made points."""

from __future__ import annotations

import importlib.util
import math
import tomllib

import numpy as np
import pytest

from fixtures import REPO
from olado.problems.suites import load_references, load_suite, perturbed_start, verify_point
from olado.problems.suites.robustness import SEEDS, ZAMBEZI

ENTRIES = load_suite("robustness")
BY_NAME = {e.name: e for e in ENTRIES}
REFS = load_references("robustness")
GROUPS = {"built-in", "cops", "literature", "infeasible", "zambezi"}


def test_entries_are_unique_and_complete():
    assert len(BY_NAME) == len(ENTRIES) >= 100
    assert {e.group for e in ENTRIES} == GROUPS
    assert len({e.problem for e in ENTRIES}) >= 40                     # distinct problems (issue 13: >= 40)
    for e in ENTRIES:
        assert e.source and (e.published is not None or e.published_note), e.name
        assert (e.group == "infeasible") == (not e.feasible), e.name
        assert (e.start == "perturbed") == (e.seed is not None), e.name
    zambezi = [e for e in ENTRIES if e.group == "zambezi"]
    assert len(zambezi) == len(ZAMBEZI) * (2 + len(SEEDS))


def test_every_entry_builds_with_a_start_of_the_right_shape():
    for e in ENTRIES:
        p, (X, U) = e.build()
        assert X.shape == (p.N + 1, p.n) and U.shape == (p.N, p.m), e.name
        assert np.all(np.isfinite(X)) and np.all(np.isfinite(U)), e.name


def test_every_entry_has_a_reference_with_commit_and_date():
    meta = REFS["meta"]
    assert meta["config"] == "configs/ipopt.ini" and meta["olado_commit"] and meta["date"]
    assert set(REFS["entries"]) == set(BY_NAME)
    for name, ref in REFS["entries"].items():
        e = BY_NAME[name]
        assert ref["olado_commit"] and ref["date"] and ref["feasible"] == e.feasible
        if e.feasible:
            # IPOPT solves every feasible entry of the set, at a verified feasible point
            assert ref["status"] == "success" and ref["verified_violation"] <= 1e-6, name
            assert ref["verified_kkt_scaled"] <= 1e-4, name
        else:
            assert ref["status"] != "success", name
        if e.published is not None:
            rel = (ref["objective"] - e.published) / abs(e.published)
            assert ref["published_rel_diff"] == pytest.approx(rel)


def test_published_values_are_stated_in_the_problems_docstrings():
    for e in ENTRIES:
        if e.published is None or e.group == "zambezi":
            continue
        doc = type(e.make_problem()).__doc__
        value = abs(e.published)
        assert repr(value) in doc or f"{value:g}" in doc, (e.name, value)


def test_published_values_agree_with_ipopt_up_to_the_discretization():
    """The relative difference stays below 3 % except where the docs explain it (alp-rider)."""
    for e in ENTRIES:
        rel = REFS["entries"][e.name].get("published_rel_diff")
        if rel is None or e.name == "alp-rider":
            continue
        assert abs(rel) < 0.03, (e.name, rel)


def test_perturbed_starts_are_seeded_and_inside_the_bounds():
    e1, e2 = BY_NAME["zambezi12-N72-sif-p1"], BY_NAME["zambezi12-N72-sif-p2"]
    p, (X1, U1) = e1.build()
    _, (X1b, U1b) = e1.build()
    _, (X2, U2) = e2.build()
    assert np.array_equal(U1, U1b) and np.array_equal(X1, X1b)
    assert not np.allclose(U1, U2)
    assert np.all(U1 >= p.u_lower) and np.all(U1 <= p.u_upper)
    assert np.all(X1 >= p.x_lower) and np.all(X1 <= p.x_upper) and np.array_equal(X1[0], p.x0)
    base = BY_NAME["zambezi12-N72-sif"]
    Xs, Us = base.start_point(p)
    dU = U1 - Us
    # controls moved by about 0.1 of their bound range (before clipping)
    span = p.u_upper - p.u_lower
    assert 0.03 < np.median(np.abs(dU) / span) < 0.1


def test_perturbed_start_of_a_problem_without_state_guess_perturbs_its_simulation():
    p = BY_NAME["vanderpol-box"].make_problem()
    X, U = perturbed_start(p, None, p.initial_guess(), seed=3)
    assert np.all(U >= -0.3) and np.all(U <= 1.0) and np.array_equal(X[0], p.x0)
    assert not np.allclose(X[1:], p.simulate(p.initial_guess())[1:])


def test_refs_are_package_data():
    cfg = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))
    data = cfg["tool"]["setuptools"]["package-data"]
    assert "robustness_refs.json" in " ".join(data.get("olado.problems.suites", []))


# ---------------------------------------------------------------------------- IPOPT against the refs
needs_ipopt = pytest.mark.skipif(importlib.util.find_spec("cyipopt") is None, reason="cyipopt not installed")

SMALL = ["double-integrator", "bryson-denham", "catalyst-mixing", "batch-reactor", "hanging-chain",
         "moon-lander", "dubins", "rayleigh-mixed", "zambezi11-N24-sif-p4", "cart-too-short"]


@needs_ipopt
@pytest.mark.parametrize("name", SMALL)
def test_ipopt_reproduces_the_stored_reference(name):
    from olado.config import load_config, make_solver

    e = BY_NAME[name]
    ref = REFS["entries"][name]
    problem, guess = e.build()
    r = make_solver(load_config(REPO / "configs" / "ipopt.ini")).solve(problem, guess=guess)
    assert r.status.value == ref["status"]
    assert abs(r.objective - ref["objective"]) <= 1e-6 * max(abs(ref["objective"]), 1e-3)


# ---------------------------------------------------------------------------- verify_point
def test_verify_point_at_the_analytic_optimum_and_away_from_it():
    p = BY_NAME["double-integrator"].make_problem()
    U = np.full((p.N, 1), -2.0)
    X = p.simulate(U)
    c = verify_point(p, X, U)
    assert c.objective == pytest.approx(2.0) and c.violation < 1e-13 and c.kkt_residual < 1e-8
    # a feasible but not optimal point: move u along a direction that keeps the (linear) end
    # conditions, i.e. in the null space of the map u -> (x(1), v(1))
    end = lambda V: p.simulate(V)[-1]                      # noqa: E731
    M = np.column_stack([end(U + np.eye(p.N)[:, [j]]) - end(U) for j in range(p.N)])
    d = np.sin(np.linspace(0.0, 3.0, p.N))
    d -= np.linalg.lstsq(M, M @ d, rcond=None)[0]
    U2 = U + d[:, None]
    c2 = verify_point(p, p.simulate(U2), U2)
    assert c2.violation < 1e-12 and c2.objective > 2.0 + 1e-3 and c2.kkt_residual > 1e-3


@needs_ipopt
def test_verify_point_sees_active_bounds_with_the_right_sign():
    """Bryson-Denham's optimum rides the state bound x <= 1/9: at IPOPT's point the check finds
    multipliers of the right sign (small residual); the unconstrained optimum violates the bound."""
    from olado.config import load_config, make_solver

    e = BY_NAME["bryson-denham"]
    problem, guess = e.build()
    r = make_solver(load_config(REPO / "configs" / "ipopt.ini")).solve(problem, guess=guess)
    c = verify_point(problem, r.x, r.u)
    assert c.violation < 1e-7 and c.kkt_residual < 1e-5 and c.active_bounds > 0
    # the unconstrained optimum u = -2 violates the bound (max x = 1/4): a large violation
    U = np.full((problem.N, 1), -2.0)
    c2 = verify_point(problem, problem.simulate(U), U)
    assert c2.violation == pytest.approx(0.25 - 1 / 9, rel=1e-3)


def test_verify_point_of_an_infeasible_problem_reports_its_violation():
    p = BY_NAME["vanderpol-contradict"].make_problem()
    U = np.zeros((p.N, 1))
    c = verify_point(p, p.simulate(U), U)
    assert c.violation >= 0.05 and math.isfinite(c.kkt_residual)
