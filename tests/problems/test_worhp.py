"""Seed 000's aerospace benchmarks (olado/problems/worhp.py; docs/aerospace-worhp.md).

Seed 000 reports no optimal value for either problem (only NLP sizes and CPU times), so nothing
published can be matched. The tests check instead:

* the models: each right-hand side against Newton's law written independently in Cartesian
  coordinates (inertial plane for the transfer; Earth-fixed frame with Coriolis and centrifugal
  terms for the landing), by central differences of the coordinate change (relative error
  ~1e-9; tolerance 1e-6). This is where the landing's v' equation, misprinted in the seed, is
  settled;
* the derivatives of the transcription against finite differences at the start;
* one solve each by sqp-ip, agreeing with IPOPT on the same DOCP;
* the transcription against an independent integrator: the optimal piecewise-constant controls of
  the RK4 transcription, re-simulated by scipy's adaptive DOP853 (rtol 1e-11), meet the terminal
  conditions and give the objective to the RK4 error at that N (tolerances at the tests).
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("casadi")

import olado  # noqa: E402
from fixtures import REPO  # noqa: E402
from olado.problems import PROBLEMS, check_derivatives  # noqa: E402
from olado.errors import ProblemDefinitionError  # noqa: E402
from olado.problems import worhp  # noqa: E402

SQP = str(REPO / "configs" / "sqp-ip.ini")
IPOPT = str(REPO / "configs" / "ipopt.ini")


# ---------------------------------------------------------------------------- the models
def _central(state_of, s, rate, eps):
    """d/dt of the state along the Cartesian motion: central difference of the coordinate change
    ``state_of`` along the first-order motion ``rate(eps)``."""
    return (state_of(*rate(eps)) - state_of(*rate(-eps))) / (2 * eps)


def _polar(pos, vel):
    r = np.hypot(*pos)
    th = np.arctan2(pos[1], pos[0])
    er, et = pos / r, np.array([-pos[1], pos[0]]) / r
    return np.array([r, vel @ er, vel @ et, th])


def test_geo_model_is_newton_in_the_plane():
    """x' of seed 000 sec. VI.1 = the polar form of r'' = -mu r/|r|^3 + a (sin u e_r + cos u e_t)."""
    rng = np.random.default_rng(0)
    mu, a = worhp.GEO["mu"], worhp.GEO["accel"]
    for _ in range(5):
        r, vr, vt, th = 6.0 + rng.random(), 0.3 * rng.standard_normal(), 3.0 + rng.random(), rng.random()
        u = 3 * rng.standard_normal()
        er, et = np.array([np.cos(th), np.sin(th)]), np.array([-np.sin(th), np.cos(th)])
        pos, vel = r * er, vr * er + vt * et
        acc = -mu * pos / r ** 3 + a * (np.sin(u) * er + np.cos(u) * et)
        fd = _central(_polar, None, lambda e: (pos + e * vel, vel + e * acc), 1e-5)
        f = np.array(worhp.geo_rhs(0.0, [r, vr, vt, th], [u], None), dtype=float)
        np.testing.assert_allclose(f, fd, rtol=1e-6, atol=1e-9)


def _local_frame(la, th):
    up = np.array([np.cos(la) * np.cos(th), np.cos(la) * np.sin(th), np.sin(la)])
    east = np.array([-np.sin(th), np.cos(th), 0.0])
    north = np.array([-np.sin(la) * np.cos(th), -np.sin(la) * np.sin(th), np.cos(la)])
    return up, east, north


def _spherical(R, V, r0):
    """(v, gamma, chi, h, Lambda, Theta) of an Earth-fixed position and velocity: Lambda the
    latitude, Theta the longitude, chi the heading from east towards north."""
    r = np.linalg.norm(R)
    la, th = np.arcsin(R[2] / r), np.arctan2(R[1], R[0])
    up, east, north = _local_frame(la, th)
    v = np.linalg.norm(V)
    return np.array([v, np.arcsin(V @ up / v), np.arctan2(V @ north, V @ east), r - r0, la, th])


def _rotating_frame_acceleration(s, u, d):
    """Newton's law in the Earth-fixed frame: gravity, drag against the air-relative velocity,
    lift perpendicular to it banked by mu (towards the left of the velocity for mu > 0), Coriolis
    -2 w x V and centrifugal -w x (w x R); returns (R, V, dV/dt)."""
    v, ga, chi, h, la, th = s
    CL, mu = u
    up, east, north = _local_frame(la, th)
    r = d["r0"] + h
    R = r * up
    vhat = np.sin(ga) * up + np.cos(ga) * (np.cos(chi) * east + np.sin(chi) * north)
    V = v * vhat
    n1 = np.cos(ga) * up - np.sin(ga) * (np.cos(chi) * east + np.sin(chi) * north)   # lift at mu = 0
    n2 = np.cross(n1, vhat)                                                          # horizontal, left
    q = d["rho0"] * np.exp(-d["beta"] * h) * v ** 2 / d["c"]
    lift, drag = q * d["F"] * CL, q * d["F"] * (d["cD0"] + d["k"] * CL ** 2)
    w = np.array([0.0, 0.0, d["omega"]])
    g = d["g0"] * (d["r0"] / r) ** 2
    acc = (-g * up + (-drag * vhat + lift * (np.cos(mu) * n1 + np.sin(mu) * n2)) / d["m"]
           - 2 * np.cross(w, V) - np.cross(w, np.cross(w, R)))
    return R, V, acc


def test_landing_model_is_newton_in_the_rotating_frame():
    """Every line of landing_rhs (seed 000 sec. VI.II, v' corrected) against the spherical form
    of Newton's law over the rotating Earth, at random states around the trajectory."""
    rng = np.random.default_rng(1)
    d = worhp.LANDING
    for _ in range(8):
        s = np.array([300 + 2000 * rng.random(), 0.6 * rng.standard_normal(), 6 * rng.random() - 3,
                      40000 * rng.random(), 0.3 + rng.random(), rng.standard_normal()])
        u = (rng.random(), 2 * rng.random() - 1)
        R, V, acc = _rotating_frame_acceleration(s, u, d)
        fd = _central(lambda R, V: _spherical(R, V, d["r0"]), s, lambda e: (R + e * V, V + e * acc), 1e-4)
        f = np.array(worhp.landing_rhs(s, u), dtype=float)
        np.testing.assert_allclose(f, fd, rtol=1e-6, atol=1e-9 * np.abs(f).max())


def test_the_seeds_printed_v_equation_is_not_newtons_law():
    """The centrifugal term as printed in the seed (with '+ cos(gamma) cos(La)' and '/ v') differs
    from Newton's law by more than its size: the correction is needed, not cosmetic."""
    d = worhp.LANDING
    s = np.array(worhp.LANDING_X0)
    v, ga, chi, h, la = s[:5]
    r, w = d["r0"] + h, d["omega"]
    printed = w ** 2 * np.cos(la) * (np.sin(ga) * np.cos(la) - np.cos(ga) * np.sin(chi) * np.sin(la)
                                     + np.cos(ga) * np.cos(la)) * r / v
    used = w ** 2 * np.cos(la) * (np.sin(ga) * np.cos(la) - np.cos(ga) * np.sin(chi) * np.sin(la)) * r
    R, V, acc = _rotating_frame_acceleration(s, (0.1, 0.2), d)
    fd = _central(lambda R, V: _spherical(R, V, d["r0"]), s, lambda e: (R + e * V, V + e * acc), 1e-4)
    f = np.array(worhp.landing_rhs(s, (0.1, 0.2)), dtype=float)
    assert abs(f[0] - fd[0]) < 1e-7
    assert abs((f[0] - used + printed) - fd[0]) > 0.5 * abs(used)


# ---------------------------------------------------------------------------- the transcription
#: intervals for the derivative checks: one integrator step per interval where the landing's
#: start is stable (LANDING_MIN_STEPS; substeps multiply the traced expression and its compile time)
CHECK_N = {("low-thrust-geo", "euler"): 20, ("low-thrust-geo", "rk4"): 20,
           ("hypersonic-landing", "euler"): 200, ("hypersonic-landing", "rk4"): 50}


@pytest.mark.parametrize("name, method", [("low-thrust-geo", "euler"), ("low-thrust-geo", "rk4"),
                                          ("hypersonic-landing", "euler"),
                                          # compiling the landing's RK4 step and Hessians: 5-7 s
                                          pytest.param("hypersonic-landing", "rk4", marks=pytest.mark.slow)])
def test_derivatives_at_the_start_against_finite_differences(name, method):
    p = PROBLEMS[name](N=CHECK_N[name, method], method=method)
    assert p.substeps == 1
    report = check_derivatives(p, rtol=1e-5, atol=1e-7)
    assert report.ok, str(report)


def test_sizes_and_defaults():
    geo, land = PROBLEMS["low-thrust-geo"](), PROBLEMS["hypersonic-landing"]()
    # the seed's smallest cases: n = 101 and n = 201 points, i.e. 100 and 200 Euler steps
    assert (geo.intervals, geo.substeps, geo.method, geo.nx, geo.nu) == (100, 1, "euler", 4, 1)
    assert (land.intervals, land.substeps, land.method, land.nx, land.nu) == (200, 1, "euler", 6, 2)
    # few intervals: enough substeps for a stable start (200 Euler or 50 RK4 steps in all)
    assert worhp.hypersonic_landing(N=20).substeps == 10
    assert worhp.hypersonic_landing(N=20, method="rk4").substeps == 3
    assert worhp.hypersonic_landing(N=20, substeps=2).substeps == 2


def _agree(p, tol_obj, tol_tf):
    rs, ri = olado.solve(p, config=SQP), olado.solve(p, config=IPOPT)
    assert rs.success and ri.success, (rs.message, ri.message)
    assert rs.objective == pytest.approx(ri.objective, rel=tol_obj)
    assert p.solution(rs).tf == pytest.approx(p.solution(ri).tf, rel=tol_tf)
    return rs


def test_geo_transfer_solves_and_agrees_with_ipopt():
    p = worhp.low_thrust_geo()
    r = _agree(p, 1e-10, 1e-10)
    sol = p.solution(r)
    # the Euler transcription at the seed's n = 101: t_f within the discretization error (O(1/N),
    # 0.03 at N = 100) of the continuous-time 17.1258 (RK4, N = 1000)
    assert abs(sol.tf - 17.1258) < 0.05
    assert sol.x[-1, 0] == pytest.approx(6.6, abs=1e-8) and abs(sol.x[-1, 1]) < 1e-8


@pytest.mark.slow
def test_landing_solves_and_agrees_with_ipopt():
    p = worhp.hypersonic_landing()
    # the range is flat in t_f near the optimum: t_f agrees to 1e-6, the objective to 1e-8
    r = _agree(p, 1e-8, 1e-6)
    sol = p.solution(r)
    S = np.asarray(worhp.LANDING_SCALE)
    x = sol.x * S
    assert x[-1, 3] == pytest.approx(500.0, abs=1e-5)
    # the safeguard bounds (not in the seed) are inactive except perhaps at the last point, whose
    # velocity only the non-unique last Euler control sets
    assert x[:-1, 0].min() > 20.0 and np.abs(x[:, 1]).max() < 1.4 and x[:-1, 3].min() > 500.0
    # bounds of the seed: 0 <= C_L, mu <= 1
    assert sol.u.min() >= -1e-8 and sol.u.max() <= 1 + 1e-8
    assert -r.objective == pytest.approx(1.5015, abs=1e-3)


def _resimulate(p, sol, rhs):
    """The piecewise-constant controls of ``sol`` integrated by DOP853 (rtol 1e-11)."""
    from scipy.integrate import solve_ivp

    x = np.array(sol.x[0], dtype=float)
    for k in range(len(sol.u)):
        out = solve_ivp(lambda t, y: np.array(rhs(t, y, sol.u[k], None), dtype=float), (sol.t[k], sol.t[k + 1]), x,
                        method="DOP853", rtol=1e-11, atol=1e-12)
        x = out.y[:, -1]
    return x


@pytest.mark.slow
def test_rk4_transcriptions_against_an_adaptive_integrator():
    geo = worhp.low_thrust_geo(N=100, method="rk4")
    sol = geo.solution(olado.solve(geo, config=SQP))
    xf = _resimulate(geo, sol, worhp.geo_rhs)
    np.testing.assert_allclose(xf[:3], [6.6, 0.0, np.sqrt(62.5 / 6.6)], atol=1e-4)
    assert sol.tf == pytest.approx(17.1258, abs=2e-3)     # RK4 N = 100 vs N = 1000: 1.2e-3

    land = worhp.hypersonic_landing(N=100, method="rk4")
    r = olado.solve(land, config=SQP)
    sol = land.solution(r)
    xf = _resimulate(land, sol, worhp._scaled_landing_rhs)
    # RK4's error at N = 100 (steps of 7.4 s) in the last seconds, where v falls from 140 to 55
    # m/s: 6.6 m in h(t_f) (1.1 m at N = 200, 0.11 m at N = 400), 6e-7 in the objective
    assert xf[3] * worhp.LANDING_SCALE[3] == pytest.approx(500.0, abs=10.0)
    assert worhp._landing_distance(None, xf, None) == pytest.approx(r.objective, rel=1e-5)


@pytest.mark.slow
def test_landing_from_the_seeds_start():
    """The seed's start (every state at its initial value; sec. VI.II): the same optimum."""
    ref = olado.solve(worhp.hypersonic_landing(), config=SQP)
    p = PROBLEMS["hypersonic-landing"](start="seed")
    X = p.initial_state_guess(p.initial_guess())
    np.testing.assert_allclose(X[1:, :6], np.tile(np.asarray(worhp.LANDING_X0) / worhp.LANDING_SCALE, (p.N, 1)))
    r = olado.solve(p, config=SQP)
    assert r.success and r.objective == pytest.approx(ref.objective, rel=1e-9)
    with pytest.raises(ProblemDefinitionError, match="start must be"):
        worhp.hypersonic_landing(start="zero")
