"""benchmarks/_peers.py: the CasADi peers (IPOPT, FATROP) solve the same DOCP as olado -- the same
objective as olado's own IPOPT from the same start, on Zambezi (box bounds, stage data) and on a
free-time OCP with path and terminal constraints (the stage-ordered constraint layout FATROP's
structure detection needs)."""

import sys
from pathlib import Path

import numpy as np
import pytest

import olado
from olado.problems.zambezi_ad import ZambeziAD

casadi = pytest.importorskip("casadi")
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from _peers import CasadiPeer  # noqa: E402

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def _car():
    return olado.OCP(rhs=lambda t, x, u, p: [x[1], u[0] - 0.1 * x[1] ** 2], x0=[0.0, 0.0], controls=1, N=30,
                     T=None, T_bounds=(1.0, 100.0), T_guess=10.0, minimum_time=True, u_bounds=(-1.0, 1.0),
                     x_bounds=([-np.inf, 0.0], None), path=lambda t, x, u, p: [1.0 - u[0] * x[1]],
                     terminal=lambda t, x, p: [x[0] - 10.0, x[1]], terminal_equalities=[0, 1])


@pytest.mark.parametrize("solver", ["ipopt", "fatrop"])
@pytest.mark.parametrize("make", [lambda: ZambeziAD("zambezi12", N=12), _car], ids=["zambezi12", "car"])
def test_peer_reaches_olados_ipopt_optimum(make, solver):
    problem = make()
    ref = olado.solve(make(), config=str(CONFIGS / "ipopt.ini"))
    assert ref.success
    peer = CasadiPeer(problem, solver)
    start = peer.start()
    n, m, N = problem.n, problem.m, problem.N
    assert start.shape == (N * (n + m) + n,)
    res = peer.solve()
    assert res.success, res.status
    assert res.infeasibility < 1e-7
    assert res.objective == pytest.approx(ref.objective, rel=1e-7, abs=1e-9)
    if solver == "ipopt":      # the same algorithm from the same start, exact Hessians both
        assert res.iterations == ref.iterations
