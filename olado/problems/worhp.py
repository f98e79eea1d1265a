"""The two aerospace benchmarks of seed 000 (Nikolayzik, Buskens and Wassel, *Nonlinear
optimization in space applications with WORHP*, sec. VI) as :class:`~olado.problems.ocp.OCP`
problems: exact derivatives by CasADi, Euler (the seed's scheme) or RK4 transcription
(docs/aerospace-worhp.md).

=======================  ===========================================================================
``low-thrust-geo``       time-optimal low-thrust planar transfer to GEO (seed sec. VI.1; Kluever 1995)
``hypersonic-landing``   emergency landing of a hypersonic upper stage, maximal distance from the
                         separation point (seed sec. VI.II; Mayrhofer and Sachs 1996; Buskens and
                         Gerdts 2003)
=======================  ===========================================================================

**What the seed reports.** For both problems the seed gives the model and its data, the
discretization (explicit Euler on n points, its Tables 3 and 6: the NLP sizes), and the CPU times
of WORHP, IPOPT, KNITRO and SNOPT (Tables 4-5 and 7-8, on an Intel Core2 Quad Q6600). It reports
**no optimal value**: no final time, objective or range, only Figures 5 and 6 (plots without
numbers). So there is no published number to match; the values olado reports here are checked by
(i) IPOPT on the same DOCP, (ii) the convergence of the Euler and RK4 transcriptions as N grows,
(iii) re-simulating the optimal controls with an independent adaptive integrator
(tests/problems/test_worhp.py), and (iv) for the models themselves, Newton's law in a rotating
Cartesian frame (the equations of motion are checked term by term).

Objectives are minimized: the landing's maximization appears with a minus sign.
"""

from __future__ import annotations

import numpy as np

from ..errors import ProblemDefinitionError
from .autodiff import cos, exp, sin, tan
from .ocp import OCP

__all__ = ["GEO", "LANDING", "LANDING_X0", "LANDING_SCALE", "LANDING_TIME_UNIT", "SEED_000", "geo_rhs",
           "landing_rhs", "LANDING_MIN_STEPS", "low_thrust_geo", "hypersonic_landing", "PROBLEMS"]

# ============================================================================ low-thrust transfer to GEO
#: Seed 000 sec. VI.1: gravitational parameter r_mu, thrust acceleration (the 0.01 of the
#: dynamics), initial and final (GEO) radius. Nondimensional; the seed states no units (r_f = 6.6
#: is the GEO radius, 42 164 km, in LU ~ 6390 km ~ one Earth radius; with mu_Earth = 398600 km^3/s^2,
#: TU = sqrt(62.5 LU^3 / mu_Earth) ~ 6390 s -- an inference, not the seed's statement).
GEO = {"mu": 62.5, "accel": 0.01, "r0": 6.0, "rf": 6.6}


def geo_rhs(t, x, u, p, data=GEO):
    """Seed 000 sec. VI.1: planar motion in polar coordinates under a constant thrust
    acceleration a = 0.01 in the direction u (from the local horizontal, towards the radius)::

        x1' = x2,  x2' = x3^2/x1 - mu/x1^2 + a sin u,  x3' = -x2 x3/x1 + a cos u,  x4' = x3/x1

    x = (radius, radial velocity, circumferential velocity, polar angle). The model has no mass
    state: the seed takes the thrust acceleration constant (no mass flow), and so does this
    problem."""
    mu, a = data["mu"], data["accel"]
    r, vr, vt = x[0], x[1], x[2]
    return [vr, vt ** 2 / r - mu / r ** 2 + a * sin(u[0]), -vr * vt / r + a * cos(u[0]), vt / r]


def _geo_terminal(data):
    vf = float(np.sqrt(data["mu"] / data["rf"]))
    return lambda t, x, p: [x[0] - data["rf"], x[1], x[2] - vf]


def low_thrust_geo(N=None, method="euler", substeps=None):
    """Time-optimal low-thrust planar transfer to GEO (seed 000 sec. VI.1; Kluever 1995)::

        min t_f   s.t.  x' = geo_rhs(x, u)  (see :func:`geo_rhs`),
        x(0) = (6, 0, sqrt(mu/6), 0),   x1(t_f) = 6.6,  x2(t_f) = 0,  x3(t_f) = sqrt(mu/6.6),

    mu = 62.5, thrust acceleration 0.01, u unbounded (the seed states no bound), t_f free
    (bounds 1 <= t_f <= 100, inactive). Data in the seed's nondimensional units (already O(1)-O(10):
    no further scaling).

    Discretization: N intervals (default 100, i.e. the seed's n = N + 1 = 101 points), explicit
    Euler (the seed's scheme; ``method="rk4"`` for RK4), ``substeps`` steps per interval (default
    1), time scaling for t_f (docs/continuous-time.md).

    Seed-reported value: none (only the NLP sizes of Table 3 and the CPU times of Tables 4-5).
    olado (docs/aerospace-worhp.md): t_f = 17.1533 TU at Euler N = 100, 17.1288 at Euler N = 3200
    (first order in 1/N), 17.12575 at RK4 N = 1000 (the continuous-time value to ~1e-5).

    Start: u = 0 (tangential thrust) and t_f = (sqrt(mu/r0) - sqrt(mu/rf)) / a = 15.0, the speed
    difference of the two circular orbits over the acceleration; states simulated.
    """
    d = GEO
    v0 = float(np.sqrt(d["mu"] / d["r0"]))
    T_guess = (v0 - float(np.sqrt(d["mu"] / d["rf"]))) / d["accel"]
    return OCP(geo_rhs, [d["r0"], 0.0, v0, 0.0], controls=1, N=100 if N is None else N, T=None,
               T_bounds=(1.0, 100.0), T_guess=T_guess, minimum_time=True, terminal=_geo_terminal(d),
               terminal_equalities=[0, 1, 2], method=method, substeps=1 if substeps is None else substeps, u_guess=0.0,
               name="low-thrust-geo")


# ============================================================================ hypersonic emergency landing
#: Seed 000 sec. VI.II, SI units: q = rho v^2 / c, rho = rho0 exp(-beta h), c_D = cD0 + k C_L^2,
#: L = q F C_L, D = q F c_D, g = g0 (r0 / r)^2, r = r0 + h, Earth rate omega, mass m (constant).
LANDING = {"c": 2.0, "cD0": 0.017, "r0": 6.371e6, "F": 305.0, "g0": 9.80665, "k": 2.0,
           "omega": 7.270e-5, "beta": 1.0 / 6900.0, "rho0": 1.249512, "m": 115000.0, "h_final": 500.0}
#: Seed 000 sec. VI.II: (v [m/s], gamma, chi, h [m], Lambda, Theta) at separation, ~33 km over Bremen
#: (Lambda = 0.92688 rad = 53.1 deg N, Theta = 0.15449 rad = 8.85 deg E: Lambda is the latitude and
#: Theta the longitude, as the equations use them; the seed's text names them the other way round).
LANDING_X0 = (2150.5452900, 0.1520181770, 2.2689279889, 33900.0, 0.9268828079, 0.1544927057)
#: state scaling of the OCP: its states are (v / 1000 m/s, gamma, chi, h / 10 km, Lambda, Theta)
LANDING_SCALE = (1.0e3, 1.0, 1.0, 1.0e4, 1.0, 1.0)
#: time unit of the OCP: 100 s (t_f ~ 7.4 instead of 740)
LANDING_TIME_UNIT = 100.0


def landing_rhs(x, u, data=LANDING):
    """Seed 000 sec. VI.II in SI units: the point-mass equations over a rotating spherical Earth,
    x = (v, gamma, chi, h, Lambda, Theta), u = (C_L, mu)::

        v'      = -D/m - g sin(gamma) + w^2 r cos(La) (sin(gamma) cos(La) - cos(gamma) sin(chi) sin(La))
        gamma'  = L cos(mu)/(m v) - (g/v - v/r) cos(gamma) + 2 w cos(chi) cos(La)
                  + w^2 cos(La) (sin(gamma) sin(chi) sin(La) + cos(gamma) cos(La)) r/v
        chi'    = L sin(mu)/(m v cos(gamma)) - cos(gamma) cos(chi) tan(La) v/r
                  + 2 w (sin(chi) cos(La) tan(gamma) - sin(La)) - w^2 cos(La) sin(La) cos(chi) r/(v cos(gamma))
        h'      = v sin(gamma),   La' = cos(gamma) sin(chi) v/r,   Theta' = cos(gamma) cos(chi) v/(r cos(La))

    The v' line differs from the seed's printed text, whose centrifugal term reads
    w^2 cos(La) (sin(gamma) cos(La) - cos(gamma) sin(chi) sin(La) + cos(gamma) cos(La)) r/v: that
    term has the unit 1/s, not m/s^2 (a typesetting slip: "+ cos(gamma) cos(La)) r/v" belongs to
    the gamma' line below it). The form above is the one Newton's law gives in the rotating frame
    (checked term by term in tests/problems/test_worhp.py) and the one of the model's sources."""
    d = data
    v, ga, chi, h, la = x[0], x[1], x[2], x[3], x[4]
    CL, mu = u[0], u[1]
    r = d["r0"] + h
    g = d["g0"] * (d["r0"] / r) ** 2
    q = d["rho0"] * exp(-d["beta"] * h) * v ** 2 / d["c"]
    lift, drag = q * d["F"] * CL, q * d["F"] * (d["cD0"] + d["k"] * CL ** 2)
    m, w = d["m"], d["omega"]
    sg, cg, sc, cc, sl, cl = sin(ga), cos(ga), sin(chi), cos(chi), sin(la), cos(la)
    return [-drag / m - g * sg + w ** 2 * cl * (sg * cl - cg * sc * sl) * r,
            lift * cos(mu) / (m * v) - (g / v - v / r) * cg + 2 * w * cc * cl
            + w ** 2 * cl * (sg * sc * sl + cg * cl) * r / v,
            lift * sin(mu) / (m * v * cg) - cg * cc * tan(la) * v / r + 2 * w * (sc * cl * tan(ga) - sl)
            - w ** 2 * cl * sl * cc * r / (v * cg),
            v * sg, cg * sc * v / r, cg * cc * v / (r * cl)]


def _scaled_landing_rhs(t, x, u, p):
    """dx_s/dtau = T_u S^-1 f(S x_s, u): the OCP's states x_s = x / S, time tau = t / T_u."""
    S, Tu = LANDING_SCALE, LANDING_TIME_UNIT
    f = landing_rhs([xi * si for xi, si in zip([x[i] for i in range(6)], S)], u)
    return [Tu * fi / si for fi, si in zip(f, S)]


def _landing_distance(t, x, p):
    """-F(t_f) of the seed: -((La(t_f) - La0)/La0)^2 - ((Theta(t_f) - Theta0)/Theta0)^2."""
    la0, th0 = LANDING_X0[4], LANDING_X0[5]
    return -(((x[4] - la0) / la0) ** 2 + ((x[5] - th0) / th0) ** 2)


#: the fewest integrator steps over [0, t_f] for the landing (step <= ~3.7 s Euler, ~15 s RK4):
#: with fewer, the start's simulation diverges (Euler at 50 steps overflows)
LANDING_MIN_STEPS = {"euler": 200, "rk4": 50}


def _landing_substeps(N, method):
    """Steps per interval for LANDING_MIN_STEPS steps in all (1 for an N the OCP will refuse)."""
    if isinstance(N, bool) or not isinstance(N, (int, np.integer)) or N < 1:
        return 1
    return max(1, -(-LANDING_MIN_STEPS.get(method, 1) // int(N)))


def hypersonic_landing(N=None, method="euler", substeps=None, start="simulate"):
    """Emergency landing of a hypersonic flight system (seed 000 sec. VI.II; Mayrhofer and Sachs
    1996; Buskens and Gerdts 2003): the upper stage of a two-stage vehicle, its engine failed after
    separation, glides as far as possible from the separation point::

        max F = ((La(t_f) - La0)/La0)^2 + ((Theta(t_f) - Theta0)/Theta0)^2   (here: min -F),  t_f free,
        x' = landing_rhs(x, u)  (see :func:`landing_rhs`),  x(0) = LANDING_X0,  h(t_f) = 500 m,
        0 <= C_L <= 1,  0 <= mu <= 1   (the seed's control bounds; it states no dynamic-pressure
                                    or heating limit, nor does this problem),

    with the seed's data (:data:`LANDING`: c = 2, cD0 = 0.017, k = 2, F = 305 m^2, m = 115 000 kg,
    rho0 = 1.249512 kg/m^3, beta = 1/6900 1/m, r0 = 6.371e6 m, g0 = 9.80665 m/s^2,
    omega = 7.27e-5 1/s). The seed states no state bounds; two safeguards are added, inactive at
    the optimum (the tests check it), that keep the iterates where the model is defined (v and
    cos(gamma) divide): v >= 10 m/s, |gamma| <= 1.5 rad. Without them sqp-ip still solves it,
    IPOPT's iterates pass through v = 0 (N = 200: 3000 iterations); which safeguards are there changes
    the solvers' paths and even the local minimum found (docs/aerospace-worhp.md).

    Scaling: states (v / 1000 m/s, gamma, chi, h / 10 km, Lambda, Theta) and time in units of 100 s
    (:data:`LANDING_SCALE`, :data:`LANDING_TIME_UNIT`): ``solution(r).tf`` is in units of 100 s.

    Discretization: N intervals (default 200, the seed's n = 201 points), explicit Euler (the
    seed's scheme; ``method="rk4"`` for RK4), ``substeps`` steps per interval (default: one where
    N >= 200 (Euler) or 50 (RK4), else enough for :data:`LANDING_MIN_STEPS` steps in all). With
    Euler the last interval's control acts on no quantity the objective or the constraints see
    (the Euler step's h, Lambda and Theta do not depend on u): it is not unique, and solvers
    return different values for it.

    Seed-reported value: none (the NLP sizes of Table 6, the CPU times of Tables 7-8, a plot of
    one trajectory in Figure 6). olado (docs/aerospace-worhp.md): F = 1.501464 and t_f = 736.2 s
    at Euler N = 200, F = 1.514567 and t_f = 736.6 s at RK4 N = 400 (the continuous-time value to
    ~3e-5).

    Start: C_L = sqrt(cD0/k) = 0.0922 (maximal lift-to-drag ratio), mu = 0.3, t_f = 700 s, states
    simulated (constant controls reach h = 500 m after 693 s); ``start="seed"``: the same controls
    and t_f, every state at its initial value (the seed's "the initial values are also used as
    starting point"; its controls and t_f guesses are not stated).
    """
    if start not in ("simulate", "seed"):
        raise ProblemDefinitionError(f"start must be 'simulate' or 'seed', got {start!r}",
                                     function="hypersonic_landing", array="start")
    d = LANDING
    N = 200 if N is None else N
    if substeps is None:
        substeps = _landing_substeps(N, method)
    S = np.asarray(LANDING_SCALE)
    h_final = d["h_final"] / S[3]
    lower = np.array([10.0, -1.5, -np.inf, -np.inf, -np.inf, -np.inf]) / S
    return OCP(_scaled_landing_rhs, np.asarray(LANDING_X0) / S, controls=2, N=N, T=None,
               T_bounds=(1.0, 30.0), T_guess=700.0 / LANDING_TIME_UNIT, final_cost=_landing_distance,
               terminal=lambda t, x, p: [x[3] - h_final], terminal_equalities=[0],
               u_bounds=([0.0, 0.0], [1.0, 1.0]), x_bounds=(lower, [np.inf, 1.5, np.inf, np.inf, np.inf, np.inf]),
               u_guess=[float(np.sqrt(d["cD0"] / d["k"])), 0.3], method=method, substeps=substeps,
               x_guess=np.asarray(LANDING_X0) / S if start == "seed" else None, name="hypersonic-landing")


#: What seed 000 reports for each problem (sec. VI): the NLP sizes as functions of the number of
#: points n, the sizes it ran, and the CPU times [s] of its Tables 4-5 and 7-8 (Intel Core2 Quad
#: Q6600, 2.4 GHz; tolerance 1e-6, at most 10 000 iterations, 30 min limit). No optimal values.
SEED_000 = {
    "low-thrust-geo": {
        "variables": lambda n: 5 * n + 1, "constraints": lambda n: 4 * (n - 1) + 7 + 2,
        "times": {101: {"WORHP": 0.88, "IPOPT": 0.32, "KNITRO": 0.28, "SNOPT": 0.54},
                  1001: {"WORHP": 3.83, "IPOPT": 7.12, "KNITRO": 3.31, "SNOPT": 102.68},
                  5001: {"WORHP": 145.55, "IPOPT": 33.11, "KNITRO": 93.41, "SNOPT": 374.30},
                  10001: {"WORHP": 194.73, "IPOPT": "Timeout", "KNITRO": 252.58, "SNOPT": 1786.85},
                  40001: {"WORHP": 939.58, "IPOPT": 741.13, "KNITRO": 312.62, "SNOPT": "Timeout"}},
        "optimal_value": None},
    "hypersonic-landing": {
        "variables": lambda n: 8 * n + 1, "constraints": lambda n: 6 * (n - 1) + 4 * n + 7,
        "times": {201: {"WORHP": 2.49, "IPOPT": 8.79, "KNITRO": "MaxIter", "SNOPT": 28.73},
                  2001: {"WORHP": 59.30, "IPOPT": "MaxIter", "KNITRO": "Error", "SNOPT": "Error"},
                  5001: {"WORHP": 146.80, "IPOPT": "Timeout", "KNITRO": "Timeout", "SNOPT": "Error"},
                  10001: {"WORHP": 184.08, "IPOPT": "Timeout", "KNITRO": "Timeout", "SNOPT": "Timeout"},
                  20001: {"WORHP": 591.61, "IPOPT": "Timeout", "KNITRO": "Timeout", "SNOPT": "Timeout"},
                  40001: {"WORHP": 1477.32, "IPOPT": "Timeout", "KNITRO": "Timeout", "SNOPT": "Timeout"}},
        "optimal_value": None},
}


def _geo_factory(N=None, method="euler", substeps=None):
    return low_thrust_geo(N=N, method=method, substeps=substeps)


def _landing_factory(N=None, method="euler", substeps=None, start="simulate"):
    return hypersonic_landing(N=N, method=method, substeps=substeps, start=start)


for _make, _fn in ((_geo_factory, low_thrust_geo), (_landing_factory, hypersonic_landing)):
    _make.__doc__ = _fn.__doc__.strip().splitlines()[0]

#: name -> factory(N=None, method="euler", substeps=None[, start]) (registered lazily by olado.problems.catalog)
PROBLEMS = {"low-thrust-geo": _geo_factory, "hypersonic-landing": _landing_factory}
