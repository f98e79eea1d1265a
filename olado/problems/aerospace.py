"""The aerospace benchmark problems of the seeds (issue 15 item 4; docs/aerospace.md), written on
:class:`olado.OCP` (exact derivatives by CasADi through the RK4 transcription).

==========================  ======================================================================
``shuttle-entry``           Space Shuttle entry, maximum crossrange (Betts 2010, ex. 6.1: 34.1412 deg)
``shuttle-entry-heating``   the same with the heat-rate limit q <= 70 BTU/ft^2/s (Betts 2010:
                            30.6255 deg; seed 004 sec. 6 'SS': 30.6385 deg)
==========================  ======================================================================

The other problems of seeds 002 and 004 are built-ins already and are the same problems (checked
in docs/aerospace.md): the hang glider (``hang-glider``, olado/problems/cops.py, Betts 2010 /
seed 004 'HG'), the asymmetric rigid body (``rigid-body``, olado/problems/literature.py,
Betts 2010; seed 004 'AB' adds an angular-speed limit it does not state) and the Earth-to-Mars maximum-radius transfer
(``orbit-raising``, literature.py; seed 002 sec. 4.1). The three-stage launch vehicle of seed 002
sec. 4.2 is not built: the seed does not give its drag-coefficient data (a figure only) nor its
initial state, and OCP has no multi-phase transcription (docs/aerospace.md, "Three-stage launch
vehicle").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .autodiff import cos, exp, sin, sqrt
from .ocp import OCP

__all__ = ["ShuttleEntry", "shuttle_entry", "PROBLEMS"]

DEG = np.pi / 180.0


# ============================================================================ Space Shuttle entry
class ShuttleEntry:
    """Model data of the Space Shuttle entry (Betts, *Practical Methods for Optimal Control and
    Estimation Using Nonlinear Programming*, 2nd ed., SIAM 2010, example 6.1, pp. 247-251, in
    Betts's English units: ft, s, slug, lb, BTU). Every constant is Betts's.
    """

    #: Earth radius R_e (ft) and gravitational parameter mu (ft^3/s^2)
    RE = 20902900.0
    MU = 0.14076539e17
    #: exponential atmosphere rho = rho_0 exp(-h / h_r): rho_0 (slug/ft^3), h_r (ft)
    RHO0 = 0.002378
    HR = 23800.0
    #: reference area S (ft^2), weight w (lb), g_0 (ft/s^2); mass m = w / g_0 (slug)
    S = 2690.0
    WEIGHT = 203000.0
    G0 = 32.174
    #: lift and drag coefficients c_L = a0 + a1 alpha, c_D = b0 + b1 alpha + b2 alpha^2 (alpha in deg)
    A0, A1 = -0.20704, 0.029244
    B0, B1, B2 = 0.07854, -0.61592e-2, 0.621408e-3
    #: heat rate at the wing leading edge q = q_a q_r (BTU/ft^2/s), q_r = 17700 sqrt(rho) (1e-4 v)^3.07,
    #: q_a = c0 + c1 alpha + c2 alpha^2 + c3 alpha^3 (alpha in deg)
    C0, C1, C2, C3 = 1.0672181, -0.19213774e-1, 0.21286289e-3, -0.10117249e-5
    Q_MAX = 70.0
    #: entry interface (h, phi, theta, v, gamma, psi) = (260 000 ft, 0, 0, 25 600 ft/s, -1 deg, 90 deg)
    X0 = (260000.0, 0.0, 0.0, 25600.0, -1.0 * DEG, 90.0 * DEG)
    #: terminal area energy management interface: h = 80 000 ft, v = 2500 ft/s, gamma = -5 deg
    HF, VF, GAMMAF = 80000.0, 2500.0, -5.0 * DEG
    #: control bounds: -90 <= alpha <= 90 deg, -90 <= beta <= 1 deg (Betts)
    ALPHA_BOUNDS = (-90.0 * DEG, 90.0 * DEG)
    BETA_BOUNDS = (-90.0 * DEG, 1.0 * DEG)
    #: Betts's published optima (2010, example 6.1): crossrange theta(t_f) and t_f without and with
    #: the heat limit (docs/aerospace.md: where the numbers come from)
    PUBLISHED = {"crossrange_deg": 34.1412, "tf_s": 2008.59}
    PUBLISHED_HEATING = {"crossrange_deg": 30.6255, "tf_s": 2198.67}
    #: seed 004 Table 1 (SPARTAN, 50 flipped-Radau nodes, with the heat limit): J = -theta(t_f) in deg
    SEED_004 = {"crossrange_deg": 30.63850}

    STATES = ("h", "phi", "theta", "v", "gamma", "psi")
    CONTROLS = ("alpha", "beta")
    #: scaled units (a manual scaling of the NLP; the model stays in Betts's units): h in 1e5 ft, v in 1e4 ft/s, angles in rad, time in 100 s
    UNITS = np.array([1e5, 1.0, 1.0, 1e4, 1.0, 1.0])
    TIME_UNIT = 100.0

    @classmethod
    def physical_rhs(cls, x, u):
        """Betts's equations of motion (example 6.1) at physical (h, phi, theta, v, gamma, psi) and (alpha, beta) in rad."""
        h, theta, v, gamma, psi = x[0], x[2], x[3], x[4], x[5]
        alpha, beta = u[0], u[1]
        r = cls.RE + h
        g = cls.MU / r ** 2
        rho = cls.RHO0 * exp(-h / cls.HR)
        a = alpha / DEG
        qS = 0.5 * rho * v ** 2 * cls.S
        L = qS * (cls.A0 + cls.A1 * a)
        D = qS * (cls.B0 + cls.B1 * a + cls.B2 * a ** 2)
        m = cls.WEIGHT / cls.G0
        return [v * sin(gamma),
                v / r * cos(gamma) * sin(psi) / cos(theta),
                v / r * cos(gamma) * cos(psi),
                -D / m - g * sin(gamma),
                L / (m * v) * cos(beta) + cos(gamma) * (v / r - g / v),
                L * sin(beta) / (m * v * cos(gamma)) + v / (r * cos(theta)) * cos(gamma) * sin(psi) * sin(theta)]

    @classmethod
    def heat_rate(cls, x, u):
        """q = q_a q_r (BTU/ft^2/s) of Betts's example 6.1 at physical x and u (rad)."""
        a = u[0] / DEG
        rho = cls.RHO0 * exp(-x[0] / cls.HR)
        qr = 17700.0 * sqrt(rho) * (1e-4 * x[3]) ** 3.07
        qa = cls.C0 + cls.C1 * a + cls.C2 * a ** 2 + cls.C3 * a ** 3
        return qa * qr


@dataclass
class EntryResult:
    """A shuttle-entry solution in Betts's units: crossrange theta(t_f) (deg), t_f (s), and the
    largest heat rate on the grid (BTU/ft^2/s)."""

    crossrange_deg: float
    tf_s: float
    max_heat_rate: float


def shuttle_entry(N=100, heating=False, scaled=True, substeps=1, mode="llvm", heat_limit="linear"):
    """Space Shuttle entry, maximum crossrange (Betts 2010 ex. 6.1; seed 004 'SS')::

        max theta(t_f),  t_f free,   x = (h, phi, theta, v, gamma, psi),  u = (alpha, beta),
        x' = f(x, u) (Betts's equations of motion, :meth:`ShuttleEntry.physical_rhs`),
        x(0) = (260 000 ft, 0, 0, 25 600 ft/s, -1 deg, 90 deg),
        h(t_f) = 80 000 ft,  v(t_f) = 2500 ft/s,  gamma(t_f) = -5 deg,
        -90 <= alpha <= 90 deg,  -90 <= beta <= 1 deg,  [q(x, alpha) <= 70 BTU/ft^2/s: heating=True]

    Published (Betts 2010, example 6.1): theta(t_f) = 34.1412 deg at t_f = 2008.59 s; with the heat
    limit 30.6255 deg at 2198.67 s. Seed 004 (Table 1, with the heat limit): J = -30.6385 deg.
    State bounds: h >= 0, v >= 1 ft/s, |theta|, |gamma| <= 89 deg (Betts).

    Transcription: N RK4 intervals (``substeps`` steps each), piecewise-constant controls, free
    final time by time scaling. ``scaled``: states in (1e5 ft, rad, rad, 1e4 ft/s, rad, rad) and
    time in 100 s (the model is the same; only the NLP's units change); ``scaled=False`` is the
    problem in Betts's raw units, badly scaled on purpose (seed 004's subject). The objective is
    -theta(t_f) in rad, the heat limit is written 1 - q/70 >= 0 (``heat_limit="linear"``) or
    70/q - 1 >= 0 (``heat_limit="ratio"``, declared intrinsically positive for the nonlinear
    scaling of seed 004 sec. 5: :func:`heat_limit_row`). Start: alpha = 17 deg, beta = -75
    deg, t_f = 2000 s, states linear from x(0) to (h_f, 0, 30 deg, v_f, gamma_f, 0), the longitude to 75 deg.
    """
    M = ShuttleEntry
    units = M.UNITS if scaled else np.ones(6)
    tu = M.TIME_UNIT if scaled else 1.0

    def phys(x):
        return [x[i] * units[i] for i in range(6)]

    def rhs(t, x, u, p):
        f = M.physical_rhs(phys(x), u)
        return [f[i] * tu / units[i] for i in range(6)]

    def terminal(t, x, p):
        xp = phys(x)
        return [(xp[0] - M.HF) / units[0], (xp[3] - M.VF) / units[3], xp[4] - M.GAMMAF]

    path = heat_limit_row(heat_limit, phys) if heating else None
    x0 = np.array(M.X0) / units
    lo = np.array([0.0, -np.inf, -89.0 * DEG, 1.0, -89.0 * DEG, -np.inf]) / units
    hi = np.array([np.inf, np.inf, 89.0 * DEG, np.inf, 89.0 * DEG, np.inf]) / units
    xf_guess = np.array([M.HF, 0.0, 30.0 * DEG, M.VF, M.GAMMAF, 0.0]) / units
    x_guess = x0 + np.linspace(0.0, 1.0, N + 1)[:, None] * (xf_guess - x0)
    x_guess[:, 1] = np.linspace(0.0, 1.3, N + 1)       # longitude: about 75 deg downrange
    ocp = OCP(rhs, x0, controls=2, N=N, T=None, T_bounds=(100.0 / tu, 4000.0 / tu), T_guess=2000.0 / tu,
              final_cost=lambda t, x, p: -x[2], terminal=terminal, terminal_equalities=[0, 1, 2],
              path=path, x_bounds=(lo, hi), u_bounds=((M.ALPHA_BOUNDS[0], M.BETA_BOUNDS[0]),
                                                      (M.ALPHA_BOUNDS[1], M.BETA_BOUNDS[1])),
              u_guess=(17.0 * DEG, -75.0 * DEG), x_guess=x_guess, substeps=substeps, mode=mode,
              name="shuttle-entry-heating" if heating else "shuttle-entry")
    if heating and heat_limit == "ratio":
        ocp.positive_constraints = {"stage": [0]}
    return ocp


def heat_limit_row(form, phys):
    """The path constraint q <= 70 BTU/ft^2/s of Betts's example 6.1 as g >= 0 at scaled x.

    ``"linear"``: g = 1 - q/70. ``"ratio"``: g = 70/q - 1, intrinsically positive in the sense of
    seed 004 eq. (11) (g > -1 wherever it is evaluated): q = q_a q_r > 0 on the whole box of the
    bounds, because q_r = 17700 sqrt(rho) (v/1e4)^3.07 > 0 for v >= 1 ft/s and the cubic
    q_a(alpha) is decreasing on [-90, 90] deg (its derivative has no real root) with
    q_a(90 deg) = 0.325. The log transform of sec. 5 then gives log(1 + g) = log 70 - log q,
    the seed's eq. (9) on the heat rate itself. The linear form has the domain q < 140 only (g > -1),
    which the iterates can leave (q reaches 167 on the unconstrained optimum), so it is not declared."""
    M = ShuttleEntry
    if form == "linear":
        return lambda t, x, u, p: [1.0 - M.heat_rate(phys(x), u) / M.Q_MAX]
    if form == "ratio":
        return lambda t, x, u, p: [M.Q_MAX / M.heat_rate(phys(x), u) - 1.0]
    raise ValueError(f"heat_limit must be 'linear' or 'ratio', not {form!r}")


def entry_result(ocp, result, scaled=True) -> EntryResult:
    """Crossrange (deg), t_f (s) and the largest heat rate on the grid of a shuttle-entry solve."""
    M = ShuttleEntry
    units = M.UNITS if scaled else np.ones(6)
    tu = M.TIME_UNIT if scaled else 1.0
    sol = ocp.solution(result)
    x = sol.x * units
    q = M.heat_rate(x[:len(sol.u)].T, sol.u.T)        # every stage at once (the formula broadcasts)
    return EntryResult(crossrange_deg=float(x[-1, 2] / DEG), tf_s=float(sol.tf * tu), max_heat_rate=float(q.max()))


def _shuttle(N=100, heating=False, scaled=True):
    return shuttle_entry(N=N, heating=heating, scaled=scaled)


def _shuttle_heating(N=100, scaled=True, heat_limit="linear"):
    return shuttle_entry(N=N, heating=True, scaled=scaled, heat_limit=heat_limit)


_shuttle.__doc__ = "Space Shuttle entry, maximum crossrange, free final time (Betts 2010 ex. 6.1; seed 004)."
_shuttle_heating.__doc__ = "Space Shuttle entry with the heat-rate limit q <= 70 BTU/ft^2/s (Betts 2010 ex. 6.1; seed 004)."

#: name -> factory (registered lazily by olado.problems.catalog)
PROBLEMS = {"shuttle-entry": _shuttle, "shuttle-entry-heating": _shuttle_heating}
