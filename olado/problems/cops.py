"""Optimal-control problems of the COPS collection (Dolan, Moré and Munson, *Benchmarking
optimization software with COPS 3.0*, Argonne ANL/MCS-TM-273, 2004), discretized by RK4 (or
Euler) with piecewise-constant controls on the stages: written on OCP
(:mod:`olado.problems.continuous_ocp`, exact derivatives).

COPS itself discretizes by the trapezoidal rule (or collocation) on nh intervals; its tables give
the optimal values of those discretizations, which the published values below quote together
with nh. Where the continuous-time optimum is published elsewhere (Betts 2010), that value is
quoted too. The values of *this* discretization differ from both by the discretization error;
the robustness suite (:mod:`olado.problems.suites`) records IPOPT's value for each entry and the
relative difference.

==================  ============================================================================
``goddard``         COPS 'rocket': Goddard rocket, maximal altitude, free final time (sec. 10)
``hang-glider``     COPS 'glider': range of a hang glider in a thermal, free final time (sec. 9)
``robot-arm``       COPS 'robot': minimum-time motion of a robot arm (sec. 8)
``particle-steering`` COPS 'steering': minimum-time particle steering (sec. 11)
``catalyst-mixing`` COPS 'catmix': catalyst mixing in a tubular reactor (sec. 14)
``hanging-chain``   COPS 'chain': hanging chain of given length (sec. 5)
==================  ============================================================================

Objectives are minimized: a maximization of the literature appears with a minus sign.
"""

from __future__ import annotations

import numpy as np

from .autodiff.functions import cos, exp, sin, sqrt
from .continuous_ocp import ContinuousOCP

__all__ = ["Goddard", "HangGlider", "RobotArm", "ParticleSteering", "CatalystMixing", "HangingChain", "PROBLEMS"]


# ============================================================================ Goddard rocket
class Goddard(ContinuousOCP):
    """Goddard rocket, maximal final altitude (COPS 3.0 'rocket'; Goddard 1919)::

        max h(T)   (here: min -h(T)),   T free,
        h' = v,   v' = (u - D(h, v)) / m - 1/h^2,   m' = -u / c,
        D = D_c v^2 exp(-h_c (h - 1)),   h(0) = 1, v(0) = 0, m(0) = 1,   m(T) = 0.6,
        0 <= u <= 3.5,   h >= 1,   v >= 0,   0.6 <= m <= 1,

    with c = 0.5, h_c = 500, D_c = 0.5 * 620 (COPS's normalized data, g0 = h0 = m0 = 1).
    Published: max h(T) = 1.01283 (COPS 3.0, trapezoidal rule with nh = 400), i.e. objective
    -1.01283 here; no separate continuous-time value is quoted. The optimal thrust is
    bang-singular-bang (a singular arc), a classic hard case.

    Free final time by the parameter stage (:mod:`olado.problems.continuous`): N stages, N - 1
    RK4 steps. Start: COPS's (T = 1, u = 1.75, states h = 1, v = t(1 - t), m linear to 0.6).
    """

    name = "goddard"
    STATES = ("h", "v", "m")
    CONTROLS = ("u",)
    X0 = (1.0, 0.0, 1.0)
    T = None
    T_BOUNDS = (1e-3, 10.0)
    T_GUESS = 1.0
    C, HC, DC, MF, TMAX = 0.5, 500.0, 0.5 * 620.0, 0.6, 3.5
    X_BOUNDS = ((1.0, 0.0, 0.6), (np.inf, np.inf, 1.0))
    U_BOUNDS = ((0.0,), (3.5,))
    N_TERMINAL = 1
    TERMINAL_EQUALITIES = [0]
    DEFAULT_N = 61

    def ode_rhs(self, x, u):
        h, v, m = x[0], x[1], x[2]
        D = self.DC * v * v * exp(-self.HC * (h - 1.0))
        return [v, (u[0] - D) / m - 1.0 / (h * h), -u[0] / self.C]

    def ode_final_cost(self, x, T):
        return -x[0]

    def ode_terminal(self, x, T):
        return [x[2] - self.MF]

    def control_guess(self):
        return np.full((self.steps, 1), self.TMAX / 2.0)

    def state_guess(self):
        t = np.linspace(0.0, 1.0, self.steps + 1)
        return np.column_stack([np.ones_like(t), t * (1.0 - t), 1.0 + (self.MF - 1.0) * t])


# ============================================================================ hang glider
class HangGlider(ContinuousOCP):
    """Range of a hang glider in a thermal updraft (Bulirsch, Nerz, Pesch and von Stryk 1993;
    COPS 3.0 'glider'; Betts, *Practical Methods for Optimal Control and Estimation Using
    Nonlinear Programming*, 2nd ed., SIAM 2010, sec. 6.5 / ex. 10.54)::

        max x(T)   (here: min -x(T)),   T free,
        x' = vx,  y' = vy,  vx' = -q v_r (c_L w + c_D vx),  vy' = q v_r (c_L vx - c_D w) - g,
        w = vy - u_a(x),  v_r = sqrt(vx^2 + w^2),  c_D = c_0 + k c_L^2,  q = rho S / (2 m),
        u_a(x) = u_M (1 - X) exp(-X),  X = (x / R - 2.5)^2,
        x(0) = 0, y(0) = 1000, y(T) = 900, (vx, vy)(0) = (vx, vy)(T) = (13.2275675, -1.28750052),
        0 <= c_L <= 1.4,   x >= 0,   vx >= 0,

    with u_M = 2.5, R = 100, c_0 = 0.034, k = 0.069662, S = 14, rho = 1.13, m = 100,
    g = 9.80665 (Betts's data; COPS rounds the boundary velocities to 13.23, -1.288 and uses
    g = 9.81). Published: max x(T) = 1248.03103 at T = 98.436940 (Betts 2010, continuous time),
    i.e. objective -1248.03103 here; COPS 3.0 reports 1255.05 for its trapezoidal nh = 100.

    Free final time by the parameter stage, N = 101 by default (100 RK4 steps: from the start
    below IPOPT fails with 60 steps of about 1.6 s). Start: T = 100, c_L = 0.7 (COPS), states
    linear from the initial to the final values with x linear to 1250.
    """

    name = "hang-glider"
    STATES = ("x", "y", "vx", "vy")
    CONTROLS = ("cL",)
    VX, VY = 13.2275675, -1.28750052
    X0 = (0.0, 1000.0, VX, VY)
    T = None
    T_BOUNDS = (1.0, 200.0)
    T_GUESS = 100.0
    UM, R, C0, KD, S, RHO, MASS, G = 2.5, 100.0, 0.034, 0.069662, 14.0, 1.13, 100.0, 9.80665
    X_BOUNDS = ((0.0, -np.inf, 0.0, -np.inf), None)
    U_BOUNDS = ((0.0,), (1.4,))
    N_TERMINAL = 3
    TERMINAL_EQUALITIES = [0, 1, 2]
    DEFAULT_N = 101

    def ode_rhs(self, x, u):
        vx, vy, cL = x[2], x[3], u[0]
        s = x[0] / self.R - 2.5
        Xa = s * s
        w = vy - self.UM * (1.0 - Xa) * exp(-Xa)
        vr = sqrt(vx * vx + w * w)
        q = 0.5 * self.RHO * self.S / self.MASS
        cD = self.C0 + self.KD * cL * cL
        return [vx, vy, -q * vr * (cL * w + cD * vx), q * vr * (cL * vx - cD * w) - self.G]

    def ode_final_cost(self, x, T):
        return -x[0]

    def ode_terminal(self, x, T):
        return [x[1] - 900.0, x[2] - self.VX, x[3] - self.VY]

    def control_guess(self):
        return np.full((self.steps, 1), 0.7)

    def state_guess(self):
        t = np.linspace(0.0, 1.0, self.steps + 1)
        return np.column_stack([1250.0 * t, 1000.0 - 100.0 * t, np.full_like(t, self.VX), np.full_like(t, self.VY)])


# ============================================================================ robot arm
class RobotArm(ContinuousOCP):
    """Minimum-time motion of a robot arm (Monika Mössner-Beigel's thesis, IWR Heidelberg; COPS
    3.0 'robot')::

        min T,   rho'' = u_rho / L,   theta'' = u_theta / I_theta,   phi'' = u_phi / I_phi,
        I_phi = ((L - rho)^3 + rho^3) / 3,   I_theta = I_phi sin(phi)^2,   L = 5,
        (rho, theta, phi)(0) = (4.5, 0, pi/4),  (rho, theta, phi)(T) = (4.5, 2 pi/3, pi/4),
        all rates 0 at both ends,   |u_i| <= 1,   0 <= rho <= L,  -pi <= theta <= pi,  0 <= phi <= pi.

    Published: T = 9.14138 (COPS 3.0, trapezoidal rule, nh = 200); no continuous-time value is
    quoted here. Free final time by the parameter stage (u^0_0 = T; the stage's two other
    controls are the dummies of :mod:`olado.problems.continuous`). Start: COPS's (T = 1, u = 0,
    rho = 4.5, phi = pi/4, theta = 2 pi/3 t^2, theta' = 4 pi/3 t).
    """

    name = "robot-arm"
    STATES = ("rho", "theta", "phi", "rho_dot", "theta_dot", "phi_dot")
    CONTROLS = ("u_rho", "u_theta", "u_phi")
    L = 5.0
    X0 = (4.5, 0.0, np.pi / 4, 0.0, 0.0, 0.0)
    XF = (4.5, 2 * np.pi / 3, np.pi / 4, 0.0, 0.0, 0.0)
    T = None
    T_BOUNDS = (0.1, 50.0)
    T_GUESS = 1.0
    X_BOUNDS = ((0.0, -np.pi, 0.0, -np.inf, -np.inf, -np.inf), (5.0, np.pi, np.pi, np.inf, np.inf, np.inf))
    U_BOUNDS = ((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0))
    N_TERMINAL = 6
    TERMINAL_EQUALITIES = list(range(6))
    DEFAULT_N = 61

    MINIMUM_TIME = True

    def ode_rhs(self, x, u):
        rho, phi, L = x[0], x[2], self.L
        Iphi = ((L - rho) ** 3 + rho ** 3) / 3.0
        Ith = Iphi * sin(phi) ** 2
        return [x[3], x[4], x[5], u[0] / L, u[1] / Ith, u[2] / Iphi]

    def ode_terminal(self, x, T):
        return [x[i] - v for i, v in enumerate(self.XF)]

    def control_guess(self):
        return np.zeros((self.steps, 3))

    def state_guess(self):
        t = np.linspace(0.0, 1.0, self.steps + 1)
        one = np.ones_like(t)
        return np.column_stack([4.5 * one, 2 * np.pi / 3 * t ** 2, np.pi / 4 * one,
                                0 * t, 4 * np.pi / 3 * t, 0 * t])


# ============================================================================ particle steering
class ParticleSteering(ContinuousOCP):
    """Minimum-time particle steering, the linear tangent steering problem (Bryson and Ho,
    *Applied Optimal Control*, 1975, sec. 2.4; COPS 3.0 'steering'; Betts 2010, ex. 'lts')::

        min T,   x1' = x3,  x2' = x4,  x3' = a cos u,  x4' = a sin u,   a = 100,
        x(0) = 0,   x2(T) = 5,  x3(T) = 45,  x4(T) = 0,   |u| <= pi/2.

    Published: T = 0.554570879 (Betts 2010, continuous time); COPS 3.0: 0.554577 (trapezoidal,
    nh = 200). Free final time by the parameter stage (or a fixed ``T_fixed``, used by the
    infeasible variant ``steering-too-short``). Start: COPS's (T = 1, u = 0, x2 and x3 linear
    to their final values).
    """

    name = "particle-steering"
    STATES = ("x1", "x2", "x3", "x4")
    CONTROLS = ("u",)
    A = 100.0
    X0 = (0.0, 0.0, 0.0, 0.0)
    T = None
    T_BOUNDS = (0.01, 10.0)
    T_GUESS = 1.0
    U_BOUNDS = ((-np.pi / 2,), (np.pi / 2,))
    N_TERMINAL = 3
    TERMINAL_EQUALITIES = [0, 1, 2]
    DEFAULT_N = 51

    MINIMUM_TIME = True      # (a fixed T, as in steering-too-short, leaves no objective)

    def ode_rhs(self, x, u):
        return [x[2], x[3], self.A * cos(u[0]), self.A * sin(u[0])]

    def ode_terminal(self, x, T):
        return [x[1] - 5.0, x[2] - 45.0, x[3]]

    def control_guess(self):
        return np.zeros((self.steps, 1))

    def state_guess(self):
        t = np.linspace(0.0, 1.0, self.steps + 1)
        return np.column_stack([0 * t, 5.0 * t, 45.0 * t, 0 * t])


# ============================================================================ catalyst mixing
class CatalystMixing(ContinuousOCP):
    """Catalyst mixing in a tubular plug-flow reactor (Gunn and Thomas 1965; COPS 3.0
    'catmix')::

        min -1 + x1(1) + x2(1),
        x1' = u (10 x2 - x1),   x2' = u (x1 - 10 x2) - (1 - u) x2,   x(0) = (1, 0),   0 <= u <= 1.

    Published: -0.0480556 (COPS 3.0, collocation with nh = 100); no separate continuous-time
    value is quoted. The optimal control is bang-singular-bang. Exact second derivatives. Start:
    u = 0 (COPS).
    """

    name = "catalyst-mixing"
    STATES = ("x1", "x2")
    CONTROLS = ("u",)
    X0 = (1.0, 0.0)
    T = 1.0
    U_BOUNDS = ((0.0,), (1.0,))
    DEFAULT_N = 50

    def ode_rhs(self, x, u):
        x1, x2, v = x[0], x[1], u[0]
        return [v * (10 * x2 - x1), v * (x1 - 10 * x2) - (1 - v) * x2]

    def ode_final_cost(self, x, T):
        return -1.0 + x[0] + x[1]

    def control_guess(self):
        return np.zeros((self.steps, 1))


# ============================================================================ hanging chain
class HangingChain(ContinuousOCP):
    """Hanging chain of length L between two points (Cesari 1983; COPS 3.0 'chain')::

        min int_0^1 x sqrt(1 + u^2) dt   (potential energy),   x' = u,   l' = sqrt(1 + u^2),
        x(0) = a = 1,  x(1) = b = 3,   l(0) = 0,  l(1) = L = 4.

    Published: 5.06891 (COPS 3.0, trapezoidal rule, nh = 800); no separate continuous-time
    value is quoted. Exact second derivatives. Start: COPS's,
    u = 4 |b - a| (t - 1/4) (states simulated). ``length`` changes L (the infeasible variant
    ``chain-too-short`` uses L = 2 < sqrt(5), the distance of the end points).
    """

    name = "hanging-chain"
    STATES = ("x", "length")
    CONTROLS = ("u",)
    A, B, LENGTH = 1.0, 3.0, 4.0
    X0 = (1.0, 0.0)
    T = 1.0
    N_TERMINAL = 2
    TERMINAL_EQUALITIES = [0, 1]
    DEFAULT_N = 50

    def __init__(self, N=None, *, length=None, **options):
        self.length = self.LENGTH if length is None else float(length)
        super().__init__(N, **options)

    def ode_rhs(self, x, u):
        return [u[0], sqrt(1.0 + u[0] * u[0])]

    def ode_cost(self, x, u):
        return x[0] * sqrt(1.0 + u[0] * u[0])

    def ode_terminal(self, x, T):
        return [x[0] - self.B, x[1] - self.length]

    def control_guess(self):
        t = (np.arange(self.steps) + 0.5) / self.steps
        return (4.0 * abs(self.B - self.A) * (t - 0.25))[:, None]


def _factory(cls):
    def make(N=None, method="rk4"):
        return cls(N=N, method=method)
    make.__doc__ = (cls.__doc__ or "").strip().splitlines()[0]
    make.__name__ = cls.name.replace("-", "_")
    return make


#: name -> factory(N=None, method="rk4") (registered lazily by olado.problems.catalog)
PROBLEMS = {cls.name: _factory(cls) for cls in (Goddard, HangGlider, RobotArm, ParticleSteering,
                                                 CatalystMixing, HangingChain)}
