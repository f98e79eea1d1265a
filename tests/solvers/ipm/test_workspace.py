"""The per-solve workspace of the interior-point solver (olado.solvers.ipm.solver.Workspace): the
arrays an iteration writes are reused from iteration to iteration, and a solve with them takes
the same iterates, bit for bit, as one that allocates every array afresh (the reference) --
also through the watchdog (which keeps an iteration's arrays past it), second-order corrections,
inertia corrections with delta > 0 and restoration phases."""

from __future__ import annotations

import numpy as np
import pytest

import olado.solvers.ipm.linesearch as linesearch
import olado.solvers.ipm.solver as S
from olado.problems import PROBLEMS
from olado.problems.zambezi import zambezi_problem
from olado.solvers.ipm.newton import stage_blocks


class FreshWorkspace(S.Workspace):
    """The reference: new arrays at every request (nothing reused)."""

    def newton(self):
        self._newton = None
        return super().newton()

    def step(self):
        self._step = None
        return super().step()

    def hessian_blocks(self, prev, shape):
        self.Q = None
        return super().hessian_blocks(prev, shape)

    def trial_arrays(self, v):
        self._trials = []
        return super().trial_arrays(v)

    def multiplier_arrays(self, st):
        self._multipliers = []
        return super().multiplier_arrays(st)


def _history(result):
    keys = ("alpha", "alpha_z", "soc", "objective", "inf_pr", "inf_du", "mu", "delta_w", "restoration", "watchdog")
    return [tuple(None if isinstance(h[k], float) and np.isnan(h[k]) else h[k] for k in keys) for h in result.history]


def _events(result):
    h = result.history
    return (sum(e["watchdog"] for e in h), sum(e["restoration"] for e in h), sum(e["soc"] > 0 for e in h),
            sum(e["delta_w"] > 0 for e in h))


@pytest.mark.parametrize("name, events", [
    ("zambezi12", (False, False, False, False)),
    ("obstacle", (True, False, True, True)),            # watchdog, second-order correction, delta > 0
    ("steering-too-short", (True, True, True, True)),   # ... and restoration phases
])
def test_a_solve_with_the_workspace_takes_the_reference_iterates(name, events, monkeypatch):
    from olado.config import load_config, make_solver

    make = (lambda: zambezi_problem("zambezi12", N=24, start="balance")) if name == "zambezi12" else PROBLEMS[name]
    solver = make_solver(load_config("configs/ipm.ini"))
    fast = solver.solve(make())
    # the paths the case is meant to cover were taken
    assert tuple(n > 0 for n in _events(fast)) == events
    with monkeypatch.context() as mp:
        mp.setattr(S, "Workspace", FreshWorkspace)
        ref = solver.solve(make())
    assert fast.status == ref.status and fast.iterations == ref.iterations
    assert _history(fast) == _history(ref)
    assert fast.objective == ref.objective and np.array_equal(fast.x, ref.x) and np.array_equal(fast.u, ref.u)


def test_the_common_iteration_reuses_the_workspace_arrays(monkeypatch):
    """On zambezi12 (no watchdog, no restoration) every iteration's Newton right-hand side, step
    and Q are the same arrays; a watchdog start detaches them (the next ones are new)."""
    from olado.config import load_config, make_solver

    seen, iterates = [], []
    monkeypatch.setattr(S, "plain_path", lambda setup: None)   # the Python path's iterations
    direction, take_step = linesearch.direction, S.take_step

    def spy(setup, st, kkt, g):
        d = direction(setup, st, kkt, g)
        seen.append((id(g.q), id(d.step.dX), id(d.dv), id(kkt.Q)))
        return d

    def spy_step(setup, st, accepted):
        out = take_step(setup, st, accepted)
        iterates.append((id(st.v), id(st.pt.X), id(st.zl), id(st.lam)))
        return out

    monkeypatch.setattr(linesearch, "direction", spy)      # line_search
    monkeypatch.setattr(S, "take_step", spy_step)
    solver = make_solver(load_config("configs/ipm.ini"))
    result = solver.solve(zambezi_problem("zambezi12", N=24, start="balance"))
    assert result.iterations == len(seen) == len(iterates) > 5
    assert len({s[:3] for s in seen}) == 1                 # q, the step, dv: one set of arrays
    assert len({s[3] for s in seen[1:]}) == 1              # Q: the first matrix's from the second on
    # the iterate's v, X, z_L, lam: two sets of arrays in turn
    assert len(set(iterates)) == 2 and all(a != b for a, b in zip(iterates, iterates[1:]))

    ws = S.Workspace(S.Layout(zambezi_problem("zambezi12", N=24, start="balance")))
    q, step = ws.newton()[4], ws.step()
    assert ws.newton()[4] is q and ws.step() is step
    v = np.zeros(ws.layout.size)
    t = ws.trial_arrays(v)
    assert ws.trial_arrays(v) is t and ws.trial_arrays(t[0]) is not t      # never the iterate's own
    ws.detach()
    assert ws.newton()[4] is not q and ws.step()[1] is not step[1] and ws.trial_arrays(v) is not t


def test_stage_blocks_into_a_given_q_are_the_new_arrays():
    rng = np.random.default_rng(0)
    N, n, m = 7, 3, 2
    Hxx, Hxu, Huu, HN = rng.normal(size=(N, n, n)), rng.normal(size=(N, n, m)), rng.normal(size=(N, m, m)), \
        rng.normal(size=(n, n))
    Q0, S0, R0 = stage_blocks(Hxx, Hxu, Huu, HN)
    Q = np.full((N + 1, n, n), np.nan)
    Q1, S1, R1 = stage_blocks(Hxx, Hxu, Huu, HN, Q)
    assert Q1 is Q and np.array_equal(Q1, Q0) and np.array_equal(S1, S0) and np.array_equal(R1, R0)


def test_above_the_rotation_size_the_same_iterates_with_new_arrays(monkeypatch):
    """Above REUSE_MAX (large N: the memory of the arrays kept between iterations) every
    request takes new arrays; the iterates are the same."""
    from olado.config import load_config, make_solver

    solver = make_solver(load_config("configs/ipm.ini"))
    make = lambda: zambezi_problem("zambezi12", N=24, start="balance")     # noqa: E731
    fast = solver.solve(make())
    with monkeypatch.context() as mp:
        mp.setattr(S, "REUSE_MAX", 0)
        assert not S.Workspace(S.Layout(make())).reuse
        ref = solver.solve(make())
    assert S.Workspace(S.Layout(make())).reuse
    assert _history(fast) == _history(ref) and fast.iterations == ref.iterations
    assert np.array_equal(fast.x, ref.x) and np.array_equal(fast.u, ref.u)
