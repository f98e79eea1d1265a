"""The proximal-point crawl of the exact-Hessian SQP (olado.solvers.sqp.phases.proximal_dominated):
a full step whose curvature comes almost only from the proximal term p max|H| converges at the
linear rate omega = p |s|^2 / (s.H s + p |s|^2). Two such steps in a row, the first reducing the
KKT residual (phases.crawling), start the local phase (global factor), and in the local phase make
the next proximal factor smaller (local_proximal_scale). hang-glider crawled at omega ~ 0.97 in the
global phase (its relative KKT residual, |grad J| = 1, never reached local_tol), goddard (with
sqp-gondzio) at omega ~ 0.98 in the local phase on its singular arc.
References: hand computations, and IPOPT's stored objectives of the robustness set."""

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import olado
from olado.problems.suites import load_references, load_suite
from olado.result import Status
from olado.solvers.sqp.phases import crawling, local_proximal_scale, proximal_dominated
from olado.solvers.sqp.solver import SQPOptions
from olado.solvers.sqp.step import hessian_scale

CONFIGS = Path(__file__).resolve().parents[3] / "configs"


def _case(h_x, dx, du, delta=0.0, tau=0.0):
    """N = 1, n = m = 1: the stage block diag(h_x, 1) (max|H| = 1), a zero final block, the step
    (dx^0, du^0) with dx^1 = 0."""
    Bk = np.array([[[h_x, 0.0], [0.0, 1.0]]])
    BN = np.zeros((1, 1))
    setup = SimpleNamespace(options=SQPOptions(), inertia=True)
    st = SimpleNamespace(tau=tau, Bk=Bk, BN=BN)
    step = SimpleNamespace(delta=np.full(2, delta), dX=np.array([[dx], [0.0]]), dU=np.array([[du]]),
                           hscale=hessian_scale(Bk, BN))
    return setup, st, step


def test_a_step_along_a_flat_direction_is_dominated():
    # s = (1, 0): s.H s = 0, |s|^2 = 1, omega = p / p = 1
    assert proximal_dominated(*_case(0.0, 1.0, 0.0), factor=1e-4)
    # s.H s / |s|^2 = 1e-5 against p = 1e-4: omega = 1e-4 / 1.1e-4 = 0.909 >= 0.9
    assert proximal_dominated(*_case(1e-5, 1.0, 0.0), factor=1e-4)
    # ... against p = 1e-6 (the local factor): omega = 0.091
    assert not proximal_dominated(*_case(1e-5, 1.0, 0.0), factor=1e-6)


def test_a_step_with_curvature_of_its_own_is_not():
    # s = (1, 1): s.H s = 1, |s|^2 = 2, omega = 2e-4 / (1 + 2e-4)
    assert not proximal_dominated(*_case(0.0, 1.0, 1.0), factor=1e-4)


def test_negative_curvature_shifted_or_regularized_steps_are_not():
    # s.H s = -1e-6 < 0: the proximal term convexifies the model along s (Zambezi's global steps)
    assert not proximal_dominated(*_case(-1e-6, 1.0, 0.0), factor=1e-4)
    # an inertia shift or WORHP's tau in effect: not the proximal term alone
    assert not proximal_dominated(*_case(0.0, 1.0, 0.0, delta=1e-3), factor=1e-4)
    assert not proximal_dominated(*_case(0.0, 1.0, 0.0, tau=1e-3), factor=1e-4)
    # local_share = 1 switches the test off
    setup, st, step = _case(0.0, 1.0, 0.0)
    setup.options.local_share = 1.0
    assert not proximal_dominated(setup, st, step, factor=1e-4)


def test_a_crawl_is_two_dominated_full_steps_with_progress():
    """One dominated step proves nothing (the first step of a Mayer problem at H = 0 is one); the
    crawl is a dominated step after a dominated step that reduced the KKT residual."""
    setup, st, step = _case(0.0, 1.0, 0.0)
    st.qp_local, st.local_proximal_scale = False, 1.0
    st.dominated, st.kkt_prev, st.kkt_res = (False, False), float("inf"), 1.0
    step.search = SimpleNamespace(mode="full")
    assert crawling(setup, st, step) == (False, False)           # the first dominated step
    assert st.dominated == (True, False) and st.kkt_prev == 1.0
    st.kkt_res = 0.9                                               # it reduced the residual
    assert crawling(setup, st, step) == (True, False)
    st.kkt_res = 2.0                                               # residual grew: no crawl
    assert crawling(setup, st, step) == (False, False)
    st.kkt_res = 1.5
    step.search = SimpleNamespace(mode="relaxed")                  # not a full step
    assert crawling(setup, st, step) == (False, False)
    assert st.dominated == (False, False)


def test_local_proximal_scale_falls_to_shift_min_and_resets():
    o = SQPOptions()          # local_proximal 1e-6, shift_increase 10, shift_min 1e-8
    scale = 1.0
    seen = []
    for _ in range(4):
        scale = local_proximal_scale(o, scale, local=True, crawl_local=True)
        seen.append(scale)
    np.testing.assert_allclose(seen, [0.1, 0.01, 0.01, 0.01])     # floor shift_min / local_proximal
    assert local_proximal_scale(o, 0.01, local=True, crawl_local=False) == 0.01
    assert local_proximal_scale(o, 0.01, local=False, crawl_local=True) == 1.0


def _entry(name):
    problem, guess = next(e for e in load_suite("robustness") if e.name == name).build()
    return problem, guess, load_references()["entries"][name]["objective"]


@pytest.mark.slow
def test_goddard_singular_arc_with_gondzio():
    """sqp-gondzio, before: SUCCESS after 186 iterations, the local proximal factor 1e-6 crawling
    on the singular arc (omega ~ 0.98); its falling local factor takes 40."""
    problem, guess, ref = _entry("goddard")
    r = olado.solve(problem, guess=guess, config=CONFIGS / "sqp-gondzio.ini")
    assert r.status is Status.SUCCESS, r.message
    assert r.objective == pytest.approx(ref, rel=1e-6)
    assert r.iterations <= 60


@pytest.mark.slow
def test_hang_glider_leaves_the_proximal_crawl():
    """Before: MAX_ITERATIONS (200) at -1247.69, full steps with delta = 0 at the KKT rate 0.985."""
    problem, guess, ref = _entry("hang-glider")
    r = olado.solve(problem, guess=guess, config=CONFIGS / "sqp-ip.ini")
    assert r.status is Status.SUCCESS, r.message
    assert r.objective == pytest.approx(ref, rel=1e-6)
    assert r.iterations <= 120
