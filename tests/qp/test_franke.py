"""Franke's interior-point QP (olado.qp.interior_point.FrankeQP, paper 001 sec. 4.2.2): its own
parts -- Wright's starting point, the barrier rule, one Newton solve per iteration, the hot start
and its cold fallback -- checked by hand computations. (The shared behaviour -- agreement with
Clarabel, certificates, warm start, KKT back-ends -- is in test_interior_point.py, where FrankeQP
is one of the METHODS.)"""

import numpy as np
import pytest

from fixtures.qp_problems import random_qp, replace, zambezi_qp
from olado.qp import make_qp_solver
from olado.qp.interior_point import FrankeQP, MehrotraQP
from olado.qp.interior_point import methods as ip_methods
from olado.qp.interior_point.presolve import _Prepared
from olado.result import Status


def test_wright_starting_point():
    qp = random_qp(3, fixed=True)
    P = _Prepared(qp)
    it = FrankeQP()._initial_point(P)
    m = P.n_comp
    d = np.concatenate([-P.lo[P.fl], P.hi[P.fu]])     # the sides' values at x = 0
    L = max(np.abs(d).max(), 100.0 * m)
    assert L == 100.0 * m                                 # the data are O(1)
    assert not it.X.any() and not it.U.any() and not it.lam.any() and not it.nu.any()
    assert np.allclose(it.tl[P.fl], L - P.lo[P.fl] + 1e-10) and np.allclose(it.tu[P.fu], L + P.hi[P.fu] + 1e-10)
    assert np.all(it.zl[P.fl] == L / m ** 2) and np.all(it.zu[P.fu] == L / m ** 2)
    assert not it.tl[~P.fl].any() and not it.zu[~P.fu].any()
    assert P.franke.rhomin == 1000.0 * m and P.franke.alphabar == 1.0


def replay_barrier_rule(history, m, rhomin):
    """The complementarity targets tau / mu (sigma) and rho_min of Franke's rule, replayed from the
    step lengths of ``history`` (class docstring of FrankeQP)."""
    alphabar, alpha, out = 1.0, 1.0, []
    for h in history:
        gap = h["mu"] * m
        if gap * rhomin > 1.0 or alpha < 1.0:
            tau = alphabar * gap / rhomin + (1.0 - alphabar) * gap / m
        else:
            tau = gap * gap
        alpha = h["alpha"]
        alphabar = 0.5 * (alphabar + alpha)
        if alphabar == 1.0:
            rhomin *= 2.0
        elif alphabar < 0.5 and rhomin > 100.0 * m:
            rhomin *= 0.5
        out.append((tau / h["mu"], rhomin, tau == gap * gap))
    return out


@pytest.mark.parametrize("qp", [random_qp(0), random_qp(4, N=10, n=4, m=3), zambezi_qp(N=48)], ids=["r0", "r4", "zambezi"])
def test_barrier_rule_and_one_solve_per_iteration(qp):
    res = FrankeQP(tol=1e-10).solve(qp)
    assert res.status is Status.SUCCESS, res.message
    m = _Prepared(qp).n_comp
    replay = replay_barrier_rule(res.history, m, 1000.0 * m)
    for h, (sigma, rhomin, _) in zip(res.history, replay):
        assert h["sigma"] == pytest.approx(sigma, rel=1e-12) and h["rho_min"] == rhomin
        assert h["solves"] - h["refinements"] == 1 and h["correctors"] == 0
        assert h["alpha"] == h["alpha_dual"]                  # one step length
    assert replay[0][0] == pytest.approx(1e-3)                # first target: gap / rho_min = mu / 1000
    ref = MehrotraQP(tol=1e-11).solve(qp)
    assert res.objective == pytest.approx(ref.objective, rel=1e-8)


def test_hot_start_keeps_rho_min_and_needs_fewer_iterations():
    qp = random_qp(1, fixed=True)
    rng = np.random.default_rng(9)
    qp2 = replace(qp, q=qp.q + 0.01 * rng.standard_normal(qp.q.shape))
    solver = FrankeQP(tol=1e-10)
    first = solver.solve(qp)
    warm, cold = solver.solve(qp2, warm_start=first), solver.solve(qp2)
    assert warm.status is Status.SUCCESS and "cold start" not in warm.message
    assert warm.iterations < cold.iterations
    m = _Prepared(qp2).n_comp
    replay = replay_barrier_rule(warm.history, m, first.history[-1]["rho_min"])
    assert all(h["sigma"] == pytest.approx(s, rel=1e-12) for h, (s, _, _) in zip(warm.history, replay))


def test_failed_hot_start_falls_back_to_a_cold_start():
    qp = random_qp(0)
    first = FrankeQP().solve(qp)
    far = replace(qp, q=-3.0 * qp.q, r=-3.0 * qp.r)
    res = FrankeQP(max_warm_iter=3).solve(far, warm_start=first)
    assert res.status is Status.SUCCESS
    assert "cold start after 3 iterations of a hot start that ended max_iterations" in res.message
    cold = FrankeQP().solve(far)
    assert res.iterations == cold.iterations + 3 and np.allclose(res.X, cold.X, atol=1e-12)


def test_a_growing_gap_abandons_the_hot_start(monkeypatch):
    st = ip_methods._FrankeState(1e3, hot=True)
    ip_methods.watch_hot_start(st, 10.0)
    ip_methods.watch_hot_start(st, 1.0)                       # the gap after the first iteration
    ip_methods.watch_hot_start(st, 0.5)
    with pytest.raises(ip_methods._HotStartFailed) as exc:
        ip_methods.watch_hot_start(st, 2.0)
    assert exc.value.iterations == 3 and "grew from 1 " in str(exc.value)
    cold = ip_methods._FrankeState(1e3, hot=False)
    for gap in (1.0, 0.1, 5.0):
        ip_methods.watch_hot_start(cold, gap)                  # a cold start is never abandoned
    # and solve() restarts cold when it happens
    qp = random_qp(2)
    first = FrankeQP().solve(qp)
    real = FrankeQP._direction

    def direction(self, ctx):
        if ctx.P.franke.hot and ctx.P.franke.calls == 2:
            raise ip_methods._HotStartFailed(2, 3.0, 1.0)
        return real(self, ctx)

    monkeypatch.setattr(FrankeQP, "_direction", direction)
    res = FrankeQP().solve(qp, warm_start=first)
    assert res.status is Status.SUCCESS and "cold start after 2 iterations of a hot start that the duality gap grew" in res.message


def test_registry_and_options():
    s = make_qp_solver("franke", tol=1e-7, max_iter=50)
    assert isinstance(s, FrankeQP) and s.options.step_rule == "common" and s.options.neighborhood == 0.0
    assert s.options.tol == 1e-7 and s.options.max_iter == 50
    res = FrankeQP(start="centred", tol=1e-10).solve(random_qp(3))
    assert res.status is Status.SUCCESS
    assert res.objective == pytest.approx(MehrotraQP(tol=1e-11).solve(random_qp(3)).objective, rel=1e-8)
