"""Optimal-control problems of the literature (Bryson and Ho; Betts; Luus; Sager; Kelly),
discretized by RK4 (or Euler) with piecewise-constant controls: written on OCP
(:mod:`olado.problems.continuous_ocp`, exact derivatives), except free-flying-robot, a
ContinuousDOCP (:mod:`olado.problems.continuous`; its docstring says why).

Each class states its source, its formulation and the published continuous-time optimal value,
or says that none is published (or that the value is the analytic one, derived in the
docstring). Objectives are minimized: a maximization of the source appears with a minus sign.
Free final times are written with the time scaling as a state set by a parameter stage (N
stages, N - 1 integration steps).

==========================  ======================================================================
``brachistochrone``         Bernoulli's curve to a vertical line (analytic T = sqrt(pi x_f / g))
``brachistochrone-point``   the same to a point (analytic, the cycloid through it)
``double-integrator``       minimum energy x'' = u between rest-like states (analytic J = 2)
``bryson-denham``           the same with the state constraint x <= 1/9 (analytic J = 4)
``bang-bang-cart``          minimum time x'' = u, |u| <= 1 (analytic T = 1 + sqrt 6)
``moon-lander``             minimum-fuel vertical landing (analytic J = 2 sqrt 17)
``lotka-fishing``           Lotka-Volterra fishing, relaxed (Sager 2005: 1.34408)
``batch-reactor``           consecutive reactions A -> B -> C (Ray 1981, Luus 2000: 0.57353)
``alp-rider``               Betts's alp rider, a stiff path constraint (Betts 2010: 2030.85609)
``free-flying-robot``       Sakawa's free-flying robot (Betts 2010: 7.91055654)
``dubins``                  minimum-time Dubins car (analytic pi + 2)
``rigid-body``              minimum-time reorientation of an asymmetric rigid body (Betts 2010: 28.6304077)
``obstacle``                minimum-energy point mass around a disc (none published)
``cart-pole``               cart-pole swing-up (Kelly 2017; none published)
``orbit-raising``           maximal radius low-thrust orbit transfer (Bryson and Ho 1975: 1.525)
==========================  ======================================================================
"""

from __future__ import annotations

import numpy as np

from .autodiff.functions import cos, exp, sin
from .continuous import ContinuousDOCP, ExactHessians
from .continuous_ocp import ContinuousOCP

__all__ = ["Brachistochrone", "BrachistochronePoint", "DoubleIntegrator", "BrysonDenham", "BangBangCart",
           "MoonLander", "LotkaFishing", "BatchReactor", "AlpRider", "FreeFlyingRobot", "Dubins",
           "RigidBody", "Obstacle", "CartPole", "OrbitRaising", "PROBLEMS"]


def _z(K, rows, cols):
    return np.zeros((K, rows, cols))


# ============================================================================ brachistochrone
class Brachistochrone(ContinuousOCP):
    """Brachistochrone to a vertical line (Johann Bernoulli 1696; Bryson and Ho, *Applied
    Optimal Control*, 1975, sec. 2.6)::

        min T,   x' = v cos th,   y' = v sin th,   v' = g sin th   (y downwards),
        (x, y, v)(0) = 0,   x(T) = x_f = 1,   y(T) free,   |th| <= pi/2,   g = 9.81.

    Analytic value: the optimum is the cycloid x = a (p - sin p), y = a (1 - cos p), t = p
    sqrt(a/g) whose lowest point lies on the line x = x_f (y free: the costate of y vanishes,
    so the path meets the line horizontally, p_f = pi, a = x_f/pi), hence
    T* = sqrt(pi x_f / g) = 0.5659010 for x_f = 1, g = 9.81.
    Start: T = 1, th = pi/4 (states simulated).
    """

    name = "brachistochrone"
    STATES = ("x", "y", "v")
    CONTROLS = ("theta",)
    G = 9.81
    X0 = (0.0, 0.0, 0.0)
    T = None
    T_BOUNDS = (0.01, 10.0)
    T_GUESS = 1.0
    U_BOUNDS = ((-np.pi / 2,), (np.pi / 2,))
    N_TERMINAL = 1
    TERMINAL_EQUALITIES = [0]
    DEFAULT_N = 51
    TARGET = (1.0,)
    MINIMUM_TIME = True

    def ode_rhs(self, x, u):
        return [x[2] * cos(u[0]), x[2] * sin(u[0]), self.G * sin(u[0])]

    def ode_terminal(self, x, T):
        return [x[i] - t for i, t in enumerate(self.TARGET)]

    def control_guess(self):
        return np.full((self.steps, 1), np.pi / 4)


class BrachistochronePoint(Brachistochrone):
    """Brachistochrone to the point (x_f, y_f) = (1, 0.6) (y downwards; Bryson and Ho 1975,
    sec. 2.6), otherwise as ``brachistochrone``.

    Analytic value: the cycloid x = a (p - sin p), y = a (1 - cos p) through the end point,
    (1 - cos p_f)/(p_f - sin p_f) = y_f/x_f gives p_f = 3.2339751, a = 0.3006410, and
    T* = p_f sqrt(a/g) = 0.5661432 (g = 9.81). The path dips below y_f (p_f > pi).
    """

    name = "brachistochrone-point"
    N_TERMINAL = 2
    TERMINAL_EQUALITIES = [0, 1]
    TARGET = (1.0, 0.6)


# ============================================================================ double integrator
class DoubleIntegrator(ContinuousOCP):
    """Minimum-energy double integrator (Bryson and Ho 1975, sec. 3.11, without the state
    constraint)::

        min 1/2 int_0^1 u^2 dt,   x' = v,  v' = u,   (x, v)(0) = (0, 1),   (x, v)(1) = (0, -1).

    Analytic value: u = -2, x = t - t^2, J* = 2 (the unconstrained arc of Bryson-Denham;
    max x = 1/4). Linear-quadratic: exact second derivatives.
    """

    name = "double-integrator"
    STATES = ("x", "v")
    CONTROLS = ("u",)
    X0 = (0.0, 1.0)
    T = 1.0
    N_TERMINAL = 2
    TERMINAL_EQUALITIES = [0, 1]
    DEFAULT_N = 50

    def ode_rhs(self, x, u):
        return [x[1], u[0]]

    def ode_cost(self, x, u):
        return 0.5 * u[0] * u[0]

    def ode_terminal(self, x, T):
        return [x[0], x[1] + 1.0]


class BrysonDenham(DoubleIntegrator):
    """The Bryson-Denham problem: ``double-integrator`` with the state constraint x <= l = 1/9
    (Bryson, Denham and Dreyfus, AIAA J. 1 (1963) 2544-2550; Bryson and Ho 1975, sec. 3.11).

    Analytic value: for l <= 1/6 the optimum has a boundary arc x = l on [3l, 1 - 3l] and
    J* = 4/(9 l) = 4 for l = 1/9. Written as the state bound x^k <= 1/9, k = 0..N.
    """

    name = "bryson-denham"
    X_BOUNDS = ((-np.inf, -np.inf), (1.0 / 9.0, np.inf))


# ============================================================================ minimum time cart
class BangBangCart(ContinuousOCP):
    """Minimum-time control of a cart, x'' = u, |u| <= 1, to the origin (Bryson and Ho 1975,
    sec. 7.3; Pontryagin et al. 1962)::

        min T,   x' = v,  v' = u,   (x, v)(0) = (1, 1),   (x, v)(T) = (0, 0),   |u| <= 1.

    Analytic value: u = -1 until the switching curve x = -v |v|/2 is reached at t = 1 +
    sqrt(3/2) with v = -sqrt(3/2), then u = +1: T* = 1 + sqrt(6) = 3.4494897. Bang-bang: the
    switch falls between grid points, so the discrete optimum lies slightly above T*. Start:
    T = 4, u = 0 (states simulated).
    """

    name = "bang-bang-cart"
    STATES = ("x", "v")
    CONTROLS = ("u",)
    X0 = (1.0, 1.0)
    T = None
    T_BOUNDS = (0.1, 20.0)
    T_GUESS = 4.0
    U_BOUNDS = ((-1.0,), (1.0,))
    N_TERMINAL = 2
    TERMINAL_EQUALITIES = [0, 1]
    DEFAULT_N = 51
    MINIMUM_TIME = True

    def ode_rhs(self, x, u):
        return [x[1], u[0]]

    def ode_terminal(self, x, T):
        return [x[0], x[1]]

    def control_guess(self):
        return np.zeros((self.steps, 1))


# ============================================================================ moon lander
class MoonLander(ContinuousOCP):
    """Minimum-fuel soft landing (Meditch, IEEE Trans. Automat. Control 9 (1964) 477-484, in the
    unit-mass form of many textbooks)::

        min int_0^T u dt,   h' = v,  v' = -g + u,   (h, v)(0) = (10, -2),   (h, v)(T) = 0,
        0 <= u <= 3,   h >= 0,   g = 1.5,   T free.

    Analytic value: int u = v(T) - v(0) + g T = 2 + 1.5 T, so minimum fuel is minimum time:
    free fall until v^2 = 17 (h = 17/3), then full thrust for sqrt(17)/1.5; J* = 2 sqrt(17) =
    8.2462113. Start: T = 5, u = 1.5 (hover thrust; states simulated).
    """

    name = "moon-lander"
    STATES = ("h", "v")
    CONTROLS = ("u",)
    G = 1.5
    X0 = (10.0, -2.0)
    T = None
    T_BOUNDS = (0.1, 50.0)
    T_GUESS = 5.0
    X_BOUNDS = ((0.0, -np.inf), None)
    U_BOUNDS = ((0.0,), (3.0,))
    N_TERMINAL = 2
    TERMINAL_EQUALITIES = [0, 1]
    DEFAULT_N = 51

    def ode_rhs(self, x, u):
        return [x[1], u[0] - self.G]

    def ode_cost(self, x, u):
        return u[0]

    def ode_terminal(self, x, T):
        return [x[0], x[1]]

    def control_guess(self):
        return np.full((self.steps, 1), self.G)


# ============================================================================ Lotka-Volterra
class LotkaFishing(ContinuousOCP):
    """Lotka-Volterra fishing problem, relaxed (Sager, *Numerical methods for mixed-integer
    optimal control problems*, Der andere Verlag 2005; the mintOC library)::

        min int_0^12 (x0 - 1)^2 + (x1 - 1)^2 dt,
        x0' = x0 - x0 x1 - c0 x0 w,   x1' = -x1 + x0 x1 - c1 x1 w,   x(0) = (0.5, 0.7),
        0 <= w <= 1,   c0 = 0.4,  c1 = 0.2.

    Published: 1.34408 (Sager 2005, the relaxed problem). Exact second derivatives. Start:
    w = 0 (no fishing).
    """

    name = "lotka-fishing"
    STATES = ("x0", "x1")
    CONTROLS = ("w",)
    C0, C1 = 0.4, 0.2
    X0 = (0.5, 0.7)
    T = 12.0
    U_BOUNDS = ((0.0,), (1.0,))
    DEFAULT_N = 60

    def ode_rhs(self, x, u):
        a, b, w = x[0], x[1], u[0]
        return [a - a * b - self.C0 * a * w, -b + a * b - self.C1 * b * w]

    def ode_cost(self, x, u):
        return (x[0] - 1) ** 2 + (x[1] - 1) ** 2

    def control_guess(self):
        return np.zeros((self.steps, 1))


# ============================================================================ batch reactor
class BatchReactor(ContinuousOCP):
    """Consecutive reactions A -> B -> C in a batch reactor (Ray, *Advanced Process Control*,
    McGraw-Hill 1981; Luus, *Iterative Dynamic Programming*, Chapman & Hall/CRC 2000)::

        max x2(1)   (here: min -x2(1)),   x1' = -(u + u^2/2) x1,   x2' = u x1,
        x(0) = (1, 0),   0 <= u <= 5.

    Published: max x2(1) = 0.57353 (Luus 2000), i.e. objective -0.57353 here. Exact second
    derivatives. Start: u = 2.5 (midpoint). ``min_yield`` adds the terminal constraint
    x2(1) >= min_yield (the infeasible variant ``batch-overyield``: x1 + x2 never grows above 1).
    """

    name = "batch-reactor"
    STATES = ("x1", "x2")
    CONTROLS = ("u",)
    X0 = (1.0, 0.0)
    T = 1.0
    U_BOUNDS = ((0.0,), (5.0,))
    DEFAULT_N = 50

    def ode_rhs(self, x, u):
        return [-(u[0] + 0.5 * u[0] * u[0]) * x[0], u[0] * x[0]]

    def ode_final_cost(self, x, T):
        return -x[1]


# ============================================================================ alp rider
class AlpRider(ContinuousOCP):
    """Betts's alp rider (Betts, *Practical Methods for Optimal Control and Estimation Using
    Nonlinear Programming*, 2nd ed., SIAM 2010, pp. 163-165)::

        min int_0^20 100 (y1^2 + y2^2 + y3^2 + y4^2) + 0.01 (u1^2 + u2^2) dt,
        y1' = -10 y1 + u1 + u2,       y2' = -2 y2 + u1 + 2 u2,
        y3' = -3 y3 + 5 y4 + u1 - u2,  y4' = 5 y3 - 3 y4 + u1 + 3 u2,
        |y|^2 >= 3 p(t,3,12) + 3 p(t,6,10) + 3 p(t,10,6) + 8 p(t,15,4) + 0.01,  p(t,a,b) = exp(-b (t-a)^2),
        y(0) = (2, 1, 2, 1),   y(20) = (2, 3, 1, -2).

    Published: 2030.85609 (Betts 2010). The path constraint depends on t: the time is a fifth
    state t' = 1. The path constraint is imposed at the stages k = 0..N-1 (at the grid points;
    between them a discrete trajectory may cut the ridges). Exact second derivatives. Start:
    u = 0 with y linear between its end values (see :meth:`state_guess`); the default N = 100
    gives h = 0.2, inside RK4's stability region for the fastest mode (-10).
    """

    name = "alp-rider"
    STATES = ("y1", "y2", "y3", "y4", "t")
    CONTROLS = ("u1", "u2")
    X0 = (2.0, 1.0, 2.0, 1.0, 0.0)
    YF = (2.0, 3.0, 1.0, -2.0)
    T = 20.0
    A = np.array([[-10.0, 0, 0, 0], [0, -2.0, 0, 0], [0, 0, -3.0, 5.0], [0, 0, 5.0, -3.0]])
    B = np.array([[1.0, 1.0], [1.0, 2.0], [1.0, -1.0], [1.0, 3.0]])
    BUMPS = ((3.0, 3.0, 12.0), (3.0, 6.0, 10.0), (3.0, 10.0, 6.0), (8.0, 15.0, 4.0))
    N_PATH = 1
    N_TERMINAL = 4
    TERMINAL_EQUALITIES = [0, 1, 2, 3]
    DEFAULT_N = 100

    def ode_rhs(self, x, u):
        A, B = self.A, self.B
        return [sum(A[i, j] * x[j] for j in range(4) if A[i, j]) + sum(B[i, j] * u[j] for j in range(2))
                for i in range(4)] + [1.0 + 0.0 * x[4]]

    def ode_cost(self, x, u):
        return 100.0 * sum(x[i] * x[i] for i in range(4)) + 0.01 * (u[0] * u[0] + u[1] * u[1])

    def ode_path(self, x, u):
        t, q = x[4], 0.01
        for c, a, b in self.BUMPS:
            q = q + c * exp(-b * (t - a) ** 2)
        return [sum(x[i] * x[i] for i in range(4)) - q]

    def ode_terminal(self, x, T):
        return [x[i] - v for i, v in enumerate(self.YF)]

    def control_guess(self):
        return np.zeros((self.steps, 2))

    def state_guess(self):
        """y linear from y(0) to y(20) (simulating u = 0 would not do: the (y3, y4) block has
        the eigenvalue +2, so y grows like exp(2 t) to about 1e17)."""
        t = np.linspace(0.0, 1.0, self.steps + 1)[:, None]
        y = (1 - t) * np.asarray(self.X0[:4]) + t * np.asarray(self.YF)
        return np.column_stack([y, self.horizon * t[:, 0]])


# ============================================================================ free-flying robot
class FreeFlyingRobot(ExactHessians, ContinuousDOCP):
    """Sakawa's free-flying robot (Sakawa, Optim. Control Appl. Meth. 20 (1999) 235-248; Betts
    2010, sec. 6.13, ex. 'ffrb')::

        min int_0^12 (u1 + u2 + u3 + u4) dt,
        x' = vx,  y' = vy,  th' = w,   vx' = (F1 + F2) cos th,   vy' = (F1 + F2) sin th,
        w' = alpha F1 - beta F2,   F1 = u1 - u2,  F2 = u3 - u4,   alpha = beta = 0.2,
        0 <= u_i <= 1,   u1 + u2 <= 1,   u3 + u4 <= 1   (path constraints),
        (x, y, th, vx, vy, w)(0) = (-10, -10, pi/2, 0, 0, 0),   all six = 0 at t = 12.

    The thrusts |F1| + |F2| of Sakawa are split into nonnegative parts (Betts's form). Published:
    7.91055654 (Betts 2010). Exact second derivatives. Start: u = 0 (states simulated).

    It stays a ContinuousDOCP (hand-written model and second derivatives) while the other
    literature problems are ContinuousOCPs, on a measurement: its rewrite on ContinuousOCP is the
    same DOCP (values and first derivatives equal to 3.6e-16 relative, Hessians to 2.2e-16;
    ``benchmarks/bench_builtins_ocp.py``), but IPOPT (configs/ipopt.ini) from the robustness start
    then leaves this implementation's path at its second iteration -- the inertia correction on a
    nearly singular KKT matrix settles on delta_w = 1e8 instead of 3.3e7 and the line search
    sends IPOPT into restoration at once -- and stops at its 3000-iteration limit at 9.38
    (KKT residual 0.2) instead of converging to 7.7074 in 283 iterations (sqp-ip, sqp-as and ipm
    reach 7.7074 on both). That success is itself fragile: on this implementation, from the
    robustness start perturbed by 1e-12 (seeds 1, 2, 3) IPOPT also stops at its iteration limit
    (8.50, 8.06, 12.48). The class is kept so that the robustness reference (IPOPT's run, 7.7074)
    stays reproducible, not because the hand-written model is better.
    """

    name = "free-flying-robot"
    STATES = ("x", "y", "theta", "vx", "vy", "omega")
    CONTROLS = ("u1", "u2", "u3", "u4")
    ALPHA = BETA = 0.2
    X0 = (-10.0, -10.0, np.pi / 2, 0.0, 0.0, 0.0)
    T = 12.0
    U_BOUNDS = ((0.0,) * 4, (1.0,) * 4)
    N_PATH = 2
    N_TERMINAL = 6
    TERMINAL_EQUALITIES = list(range(6))
    DEFAULT_N = 60

    def model(self, X, U, order):
        th = X[:, 2]
        K = len(th)
        F1, F2 = U[:, 0] - U[:, 1], U[:, 2] - U[:, 3]
        S = F1 + F2
        c, s = np.cos(th), np.sin(th)
        F = np.stack([X[:, 3], X[:, 4], X[:, 5], S * c, S * s, self.ALPHA * F1 - self.BETA * F2,
                      U.sum(axis=1)], axis=1)
        if order < 1:
            return F, None, None
        sign = np.array([1.0, -1.0, 1.0, -1.0])
        J = _z(K, 7, 10)
        J[:, 0, 3] = J[:, 1, 4] = J[:, 2, 5] = 1.0
        J[:, 3, 2], J[:, 4, 2] = -S * s, S * c
        J[:, 3, 6:] = c[:, None] * sign
        J[:, 4, 6:] = s[:, None] * sign
        J[:, 5, 6:] = [self.ALPHA, -self.ALPHA, -self.BETA, self.BETA]
        J[:, 6, 6:] = 1.0
        H = None
        if order >= 2:
            H = np.zeros((K, 7, 10, 10))
            H[:, 3, 2, 2], H[:, 4, 2, 2] = -S * c, -S * s
            H[:, 3, 2, 6:] = H[:, 3, 6:, 2] = -s[:, None] * sign
            H[:, 4, 2, 6:] = H[:, 4, 6:, 2] = c[:, None] * sign
        return F, J, H

    def path(self, X, U, order):
        K = X.shape[0]
        G = np.stack([1.0 - U[:, 0] - U[:, 1], 1.0 - U[:, 2] - U[:, 3]], axis=1)
        if order < 1:
            return G, None, None, None
        Gu = np.zeros((K, 2, 4))
        Gu[:, 0, :2] = Gu[:, 1, 2:] = -1.0
        Gzz = np.zeros((K, 2, self.n + 4, self.n + 4)) if order >= 2 else None
        return G, np.zeros((K, 2, self.n)), Gu, Gzz

    def terminal(self, x, order):
        return x.copy(), np.eye(6), np.zeros((6, 6, 6))

    def control_guess(self):
        return np.zeros((self.steps, 4))


# ============================================================================ Dubins car
class Dubins(ContinuousOCP):
    """Minimum-time Dubins car (Dubins, Amer. J. Math. 79 (1957) 497-516)::

        min T,   x' = cos th,  y' = sin th,  th' = w,   |w| <= 1   (unit speed and turning radius),
        (x, y, th)(0) = (0, 0, 0),   (x, y, th)(T) = (0, 4, pi).

    Analytic value: Dubins' shortest path is a left quarter circle, a straight segment of
    length 2 and another left quarter circle (LSL), T* = pi + 2 = 5.1415927. Start: T = 6,
    w = 0.5 (states simulated).
    """

    name = "dubins"
    STATES = ("x", "y", "theta")
    CONTROLS = ("w",)
    X0 = (0.0, 0.0, 0.0)
    XF = (0.0, 4.0, np.pi)
    T = None
    T_BOUNDS = (0.1, 50.0)
    T_GUESS = 6.0
    U_BOUNDS = ((-1.0,), (1.0,))
    N_TERMINAL = 3
    TERMINAL_EQUALITIES = [0, 1, 2]
    DEFAULT_N = 51
    MINIMUM_TIME = True

    def ode_rhs(self, x, u):
        return [cos(x[2]), sin(x[2]), u[0]]

    def ode_terminal(self, x, T):
        return [x[i] - xf for i, xf in enumerate(self.XF)]

    def control_guess(self):
        return np.full((self.steps, 1), 0.5)


# ============================================================================ rigid body
class RigidBody(ContinuousOCP):
    """Minimum-time reorientation of an asymmetric rigid body (Fleming, Sekhavat and Ross,
    AIAA 2008-7012; Betts 2010, sec. 6.8)::

        min T,   q' = 1/2 Omega(w) q   (quaternion q = (q1, q2, q3, q4), q4 scalar),
        Ix w1' = u1 - (Iz - Iy) w2 w3,  Iy w2' = u2 - (Ix - Iz) w1 w3,  Iz w3' = u3 - (Iy - Ix) w1 w2,
        q(0) = (0, 0, 0, 1), w(0) = 0,   (q1, q2, q3)(T) = (sin(phi/2), 0, 0), w(T) = 0,   |u_i| <= 50,

    with (Ix, Iy, Iz) = (5621, 4547, 2364) and a rest-to-rest rotation by phi = 150 deg about the
    x axis. Published: T* = 28.6304077 (Betts 2010). q4 is a state here (Betts eliminates it by
    |q| = 1; RK4 keeps |q| = 1 to its local error). Start: the eigenaxis maneuver, u1 = +-50 over
    the two halves of T = 2 sqrt(phi Ix / 50) = 34.31, with u2 = 10 cos(pi t/T) and u3 = 5 cos(pi
    t/T) added (states simulated); from the pure eigenaxis maneuver, a KKT point of the discrete
    problem, IPOPT does not move.
    """

    name = "rigid-body"
    STATES = ("q1", "q2", "q3", "q4", "w1", "w2", "w3")
    CONTROLS = ("u1", "u2", "u3")
    INERTIA = (5621.0, 4547.0, 2364.0)
    PHI = 150.0 * np.pi / 180.0
    X0 = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
    T = None
    T_BOUNDS = (1.0, 200.0)
    T_GUESS = 2.0 * np.sqrt(150.0 * np.pi / 180.0 * 5621.0 / 50.0)
    U_BOUNDS = ((-50.0,) * 3, (50.0,) * 3)
    N_TERMINAL = 6
    TERMINAL_EQUALITIES = list(range(6))
    DEFAULT_N = 61
    MINIMUM_TIME = True

    def ode_rhs(self, x, u):
        Ix, Iy, Iz = self.INERTIA
        q1, q2, q3, q4, w1, w2, w3 = (x[i] for i in range(7))
        return [0.5 * (w1 * q4 - w2 * q3 + w3 * q2), 0.5 * (w1 * q3 + w2 * q4 - w3 * q1),
                0.5 * (-w1 * q2 + w2 * q1 + w3 * q4), 0.5 * (-w1 * q1 - w2 * q2 - w3 * q3),
                (u[0] - (Iz - Iy) * w2 * w3) / Ix, (u[1] - (Ix - Iz) * w1 * w3) / Iy, (u[2] - (Iy - Ix) * w1 * w2) / Iz]

    def ode_terminal(self, x, T):
        target = (np.sin(self.PHI / 2), 0.0, 0.0, 0.0, 0.0, 0.0)
        return [x[i] - v for i, v in zip((0, 1, 2, 4, 5, 6), target)]

    def control_guess(self):
        U = np.zeros((self.steps, 3))
        half = self.steps // 2
        U[:half, 0], U[half:, 0] = 50.0, -50.0
        t = (np.arange(self.steps) + 0.5) / self.steps
        U[:, 1], U[:, 2] = 10.0 * np.cos(np.pi * t), 5.0 * np.cos(np.pi * t)
        return U


# ============================================================================ obstacle
class Obstacle(ContinuousOCP):
    """Minimum-energy transfer of a point mass around a circular obstacle (a standard test of
    path-constrained trajectory optimization, written here; no published value)::

        min 1/2 int_0^1 |u|^2 dt,   p'' = u  (p, u in R^2),   p(0) = (0, 0),  p(1) = (1, 0),
        p'(0) = p'(1) = 0,   |p - c|^2 >= r^2,   c = (0.5, 0.05),  r = 0.2.

    The disc sits slightly above the straight line, so passing below (the global minimum) and
    passing above (a local minimum with a higher value) are both KKT points; the straight line
    u = 0 crosses the obstacle (IPOPT does not recover from it). Start: u = (0, -20 cos 2 pi t),
    which bends the path below the disc first (states simulated). Exact second derivatives.
    """

    name = "obstacle"
    STATES = ("x", "y", "vx", "vy")
    CONTROLS = ("ux", "uy")
    CENTER, RADIUS = (0.5, 0.05), 0.2
    X0 = (0.0, 0.0, 0.0, 0.0)
    T = 1.0
    N_PATH = 1
    N_TERMINAL = 4
    TERMINAL_EQUALITIES = [0, 1, 2, 3]
    DEFAULT_N = 50

    def ode_rhs(self, x, u):
        return [x[2], x[3], u[0], u[1]]

    def ode_cost(self, x, u):
        return 0.5 * (u[0] * u[0] + u[1] * u[1])

    def ode_path(self, x, u):
        (cx, cy), r = self.CENTER, self.RADIUS
        return [(x[0] - cx) ** 2 + (x[1] - cy) ** 2 - r ** 2]

    def ode_terminal(self, x, T):
        return [x[0] - 1.0, x[1], x[2], x[3]]

    def control_guess(self):
        t = (np.arange(self.steps) + 0.5) / self.steps
        U = np.zeros((self.steps, 2))
        U[:, 1] = -20.0 * np.cos(2.0 * np.pi * t)
        return U


# ============================================================================ cart-pole
class CartPole(ContinuousOCP):
    """Cart-pole swing-up (Kelly, *An introduction to trajectory optimization*, SIAM Review 59
    (2017) 849-904, sec. 6 and appendix E)::

        min int_0^2 u^2 dt,   cart position q1, pole angle q2 (0 hanging down),
        q1'' = (l m2 sin q2 q2'^2 + u + m2 g cos q2 sin q2) / (m1 + m2 (1 - cos^2 q2)),
        q2'' = -(l m2 cos q2 sin q2 q2'^2 + u cos q2 + (m1 + m2) g sin q2) / (l m1 + l m2 (1 - cos^2 q2)),
        (q1, q2, q1', q2')(0) = 0,   (q1, q2, q1', q2')(2) = (1, pi, 0, 0),   |u| <= 20,  |q1| <= 2,

    with m1 = 1, m2 = 0.3, l = 0.5, g = 9.81. No published optimal value (Kelly shows the
    trajectory only). Start: u = 0 with the states linear from the initial to the final values
    (Kelly's guess).
    """

    name = "cart-pole"
    STATES = ("q1", "q2", "q1_dot", "q2_dot")
    CONTROLS = ("u",)
    M1, M2, LEN, G = 1.0, 0.3, 0.5, 9.81
    X0 = (0.0, 0.0, 0.0, 0.0)
    XF = (1.0, np.pi, 0.0, 0.0)
    T = 2.0
    X_BOUNDS = ((-2.0, -np.inf, -np.inf, -np.inf), (2.0, np.inf, np.inf, np.inf))
    U_BOUNDS = ((-20.0,), (20.0,))
    N_TERMINAL = 4
    TERMINAL_EQUALITIES = [0, 1, 2, 3]
    DEFAULT_N = 50

    def ode_rhs(self, x, u):
        q2, dq2, v = x[1], x[3], u[0]
        m1, m2, ln, g = self.M1, self.M2, self.LEN, self.G
        s, c = sin(q2), cos(q2)
        den = m1 + m2 * (1.0 - c * c)
        a1 = (ln * m2 * s * dq2 ** 2 + v + m2 * g * c * s) / den
        a2 = -(ln * m2 * c * s * dq2 ** 2 + v * c + (m1 + m2) * g * s) / (ln * den)
        return [x[2], dq2, a1, a2]

    def ode_cost(self, x, u):
        return u[0] * u[0]

    def ode_terminal(self, x, T):
        return [x[i] - v for i, v in enumerate(self.XF)]

    def control_guess(self):
        return np.zeros((self.steps, 1))

    def state_guess(self):
        t = np.linspace(0.0, 1.0, self.steps + 1)[:, None]
        return t * np.asarray(self.XF)[None, :]


# ============================================================================ orbit raising
class OrbitRaising(ContinuousOCP):
    """Maximal-radius low-thrust orbit transfer in fixed time (Moyer and Pinkham 1964; Bryson and
    Ho, *Applied Optimal Control*, 1975, sec. 2.5)::

        max r(T)   (here: min -r(T)),   T = 3.32  (normalized: mu = r(0) = m(0) = 1),
        r' = vr,   vr' = vt^2/r - 1/r^2 + a sin phi,   vt' = -vr vt / r + a cos phi,
        a = 0.1405 / (1 - 0.0749 t),   (r, vr, vt)(0) = (1, 0, 1),   vr(T) = 0,  vt(T) = 1/sqrt(r(T)),

    phi the thrust angle from the local horizontal (unbounded). Published: r(T) ~ 1.525 (Bryson
    and Ho 1975, sec. 2.5; three digits), i.e. objective -1.525 here. The thrust acceleration
    depends on t: the time is a fourth state t' = 1. Start: phi = 0 (tangential thrust; states
    simulated).
    """

    name = "orbit-raising"
    STATES = ("r", "vr", "vt", "t")
    CONTROLS = ("phi",)
    THRUST, MDOT = 0.1405, 0.0749
    X0 = (1.0, 0.0, 1.0, 0.0)
    T = 3.32
    X_BOUNDS = ((0.5, -np.inf, -np.inf, -np.inf), None)
    N_TERMINAL = 2
    TERMINAL_EQUALITIES = [0, 1]
    DEFAULT_N = 50

    def ode_rhs(self, x, u):
        r, vr, vt, t, ph = x[0], x[1], x[2], x[3], u[0]
        a = self.THRUST / (1.0 - self.MDOT * t)
        return [vr, vt * vt / r - 1.0 / (r * r) + a * sin(ph), -vr * vt / r + a * cos(ph), 1.0 + 0.0 * r]

    def ode_final_cost(self, x, T):
        return -x[0]

    def ode_terminal(self, x, T):
        return [x[1], x[2] - x[0] ** -0.5]

    def control_guess(self):
        return np.zeros((self.steps, 1))


def _factory(cls):
    def make(N=None, method="rk4"):
        return cls(N=N, method=method)
    make.__doc__ = (cls.__doc__ or "").strip().splitlines()[0]
    make.__name__ = cls.name.replace("-", "_")
    return make


#: name -> factory(N=None, method="rk4") (registered lazily by olado.problems.catalog)
PROBLEMS = {cls.name: _factory(cls) for cls in (
    Brachistochrone, BrachistochronePoint, DoubleIntegrator, BrysonDenham, BangBangCart, MoonLander,
    LotkaFishing, BatchReactor, AlpRider, FreeFlyingRobot, Dubins, RigidBody, Obstacle, CartPole,
    OrbitRaising)}
