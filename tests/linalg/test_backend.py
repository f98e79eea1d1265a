"""The KKT back-end protocol (olado.linalg.backend): one table of back-ends, every one of them
refactors to exactly the factorization a fresh construction gives and solves into given arrays
as it solves; the table loads without numba."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from olado.linalg.backend import KKT_BACKENDS, KKT_SOLVERS, RHS, KKTBackend, Solution, StageData, make_kkt_solver

from test_kkt import well_conditioned_problem

ROOT = Path(__file__).resolve().parents[2]


def test_one_table_of_back_ends():
    assert KKT_SOLVERS == tuple(KKT_BACKENDS) == ("riccati", "superlu-full", "superlu-reduced", "minres", "gmres")
    for name in KKT_SOLVERS:
        cls = KKT_BACKENDS[name]
        for method in ("refactor", "solve", "solve_into"):
            assert callable(getattr(cls, method)), (name, method)


@pytest.mark.parametrize("name", KKT_SOLVERS)
@pytest.mark.parametrize("ne, ni", [(0, 0), (0, 2), (1, 2)])
def test_refactor_is_a_fresh_factorization_and_solve_into_is_solve(name, ne, ni):
    """refactor with new diagonal terms (arrays updated in place, as the interior-point QP does)
    gives bit for bit the solution of a back-end built with those terms; solve_into writes the
    solution of solve into the given arrays (nu zero where no row counts)."""
    rng = np.random.default_rng(10 * ne + ni)
    N, n, m = 7, 3, 2
    mats, rhs = well_conditioned_problem(rng, N, n, m, ne=ne, neN=ne, ni=ni, bounds=True, zero_weights=True)
    Dx, Du = mats["Dx"].copy(), mats["Du"].copy()
    solver = make_kkt_solver(name, **mats)
    assert isinstance(solver.data, StageData) and isinstance(solver, KKTBackend)
    mats["Dx"][...] = 2.0 * Dx + 0.5
    mats["Du"][...] = 3.0 * Du
    if ni:
        mats["sigma"][...] = mats["sigma"][::-1]
    solver.refactor(Dx=mats["Dx"], Du=mats["Du"], sigma=mats.get("sigma"))
    fresh = make_kkt_solver(name, **{k: v.copy() for k, v in mats.items()})
    a, b = solver.solve(**rhs), fresh.solve(**rhs)
    for field in ("X", "U", "lam", "nu"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)
    assert a.x0_residual == b.x0_residual
    d = solver.data
    out = Solution(np.empty((N + 1, n)), np.empty((N, m)), np.empty((N + 1, n)), np.full((N + 1, max(d.ne_max, d.neN)), 7.0))
    defect = solver.solve_into(d.rhs_arrays(rhs["q"], rhs["r"], rhs["c"], rhs["x0"], rhs.get("e"), rhs.get("eN"),
                                            rhs.get("ci")), out)
    assert isinstance(defect, float) and defect == a.x0_residual
    for field in ("X", "U", "lam", "nu"):
        np.testing.assert_array_equal(getattr(out, field), getattr(a, field), err_msg=field)
    plain = tuple(np.full_like(x, 7.0) for x in out)         # plain tuples, as the interior-point QP passes
    assert solver.solve_into(tuple(d.rhs_arrays(rhs["q"], rhs["r"], rhs["c"], rhs["x0"], rhs.get("e"), rhs.get("eN"),
                                                rhs.get("ci"))), plain) == defect
    for x, y in zip(plain, out):
        np.testing.assert_array_equal(x, y)
    assert isinstance(d.rhs_arrays(rhs["q"], rhs["r"], rhs["c"], rhs["x0"], None, None, None), RHS)


def test_the_table_loads_without_numba():
    code = ("import sys; import olado.linalg as L; from olado.linalg.backend import KKT_SOLVERS; "
            "import olado.solvers.sqp.solver; print(KKT_SOLVERS, L.KKT_BACKENDS.target('riccati'), 'numba' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    assert out.strip().endswith("False"), out
