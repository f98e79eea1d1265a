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
import bench_peers  # noqa: E402
from _peers import CasadiPeer, PeerResult, estimate_setup  # noqa: E402

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


# ---------------------------------------------------------------------------- set-up estimate

def test_setup_estimate_is_the_power_law_through_the_two_largest_smaller_horizons():
    quadratic = {n: 2e-6 * n ** 2 for n in (50, 100, 200)}
    assert estimate_setup(quadratic, 1000) == pytest.approx(2.0, rel=1e-12)
    # horizons at or above the target are not used; one measurement extrapolates with min_power
    assert estimate_setup({100: 1.0, 5000: 1e9}, 1000) == pytest.approx(10.0, rel=1e-12)
    assert estimate_setup({100: 1.0}, 1000, min_power=2.0) == pytest.approx(100.0, rel=1e-12)
    # a power below min_power (noise at small N, FATROP's power rising with N) is raised to it
    assert estimate_setup({100: 1.0, 200: 1.1}, 400) == pytest.approx(2.2, rel=1e-12)
    assert estimate_setup({100: 1.0, 200: 3.0}, 400, min_power=2.0) == pytest.approx(12.0, rel=1e-12)
    assert estimate_setup({}, 1000) is None and estimate_setup({2000: 1.0}, 1000) is None


class _FakePeer:
    """Stands in for CasadiPeer: set-up 1e-6 N^2 s (recorded, not slept), solves instantly."""

    built = []

    def __init__(self, problem, solver):
        self.setup_s = 1e-6 * problem.N ** 2
        _FakePeer.built.append(problem.N)

    def solve(self):
        return PeerResult(-1.0, 3, "success", True, 1e-3, 0.0)


@pytest.fixture
def fake_peer(monkeypatch):
    _FakePeer.built = []
    monkeypatch.setattr(bench_peers, "CasadiPeer", _FakePeer)
    return _FakePeer


def test_peer_estimated_above_the_limit_is_skipped_without_its_setup(fake_peer):
    measured = {"casadi-fatrop": {120: 1e-6 * 120 ** 2, 1200: 1e-6 * 1200 ** 2}}
    rows = bench_peers._peer_rows(["casadi-fatrop"], "zambezi", 12000, 1, 100.0, measured)
    assert fake_peer.built == []
    (row,) = rows
    assert row.status == "skipped: set-up estimated above the limit" and not row.success and row.estimated
    assert row.setup_s == pytest.approx(144.0, rel=1e-9)


def test_peer_setup_probed_at_smaller_horizons_when_the_run_has_none(fake_peer):
    measured = {}
    rows = bench_peers._peer_rows(["casadi-fatrop"], "zambezi", 12000, 1, 100.0, measured)
    assert fake_peer.built == [120, 1200]                    # the probes, not N = 12 000
    assert rows[0].status.startswith("skipped") and rows[0].setup_s == pytest.approx(144.0, rel=1e-9)
    # below the limit the peer is built and solved, and its set-up joins the measurements
    rows = bench_peers._peer_rows(["casadi-fatrop"], "zambezi", 2400, 1, 100.0, measured)
    assert fake_peer.built[-1] == 2400 and rows[0].success and 2400 in measured["casadi-fatrop"]


def test_peer_above_its_max_N_is_skipped(fake_peer):
    rows = bench_peers._peer_rows(["casadi-ipopt", "casadi-fatrop"], "zambezi12", 252, 1, 100.0, {},
                                  {"casadi-fatrop": 120})
    assert fake_peer.built == [252]
    assert rows[0].success and rows[1].status == "skipped: N above --peer-max-N 120"
