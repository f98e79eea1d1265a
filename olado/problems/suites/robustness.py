"""The robustness test set (issue 13, item 7) as data: one row per entry, read by
:func:`olado.problems.suites.load_suite`.

Each row: the entry's name, the registered problem it builds and its settings (the factory's
keyword arguments), the start (the problem's own, or that start perturbed with a seed), the
source, the published continuous-time optimal value in olado's sign convention (minimization;
None when none is published, ``published_note`` says what there is), and whether the problem is
feasible. IPOPT's values for every entry are stored beside this file
(``robustness_refs.json``, written by ``benchmarks/make_robustness_refs.py``).

Zambezi: families zambezi8..zambezi12 of paper 001 sec. 5, each at one modest N, from the SIF
start point (the project's reading of the paper's start (45): outflow = inflow, every volume at
V0; see :mod:`.zambezi_testset`), from the balance start (46)-(47), and from ten seeded
perturbations of the SIF start (:func:`olado.problems.suites.perturbed_start`: controls moved by
``PERTURBATION['controls']`` times their bound range, volumes by ``PERTURBATION['states']`` times
theirs, normal draws of ``numpy.random.default_rng(seed)``, clipped to the bounds).
"""

from __future__ import annotations

#: the perturbation of the Zambezi starts: scales relative to the bound ranges (see the module docstring)
PERTURBATION = {"controls": 0.1, "states": 0.05}

_NONE = "none published"


def _row(name, problem, settings, source, published=None, note=_NONE, feasible=True, group="literature", **extra):
    row = {"name": name, "problem": problem, "settings": dict(settings), "start": "problem", "seed": None,
           "source": source, "published": published, "published_note": note, "feasible": feasible,
           "group": group}
    row.update(extra)
    return row


_LUUS = "Luus, Iterative Dynamic Programming, 2000"
_BUILTIN = [
    _row("lq", "lq", {"N": 50}, "olado built-in (Bryson and Ho 1975 sec. 2.3)", None,
         "discrete-time problem (no continuous counterpart); exact optimum by the Riccati recursion 13.0669348",
         group="built-in"),
    _row("lq-box", "lq-box", {"N": 50}, "olado built-in, |u_i| <= 1", None,
         "discrete-time problem (no continuous counterpart)", group="built-in"),
    _row("vanderpol", "vanderpol", {"N": 50, "method": "rk4"}, _LUUS, group="built-in",
         note="none verified for this formulation; RK4 N = 1600 gives 2.866955 (olado's testproblems)"),
    _row("vanderpol-euler", "vanderpol", {"N": 50, "method": "euler"}, _LUUS, group="built-in",
         note="none verified for this formulation"),
    _row("vanderpol-box", "vanderpol-box", {"N": 50, "method": "rk4"}, _LUUS + ", -0.3 <= u <= 1",
         group="built-in", note="none verified for this formulation"),
    _row("vanderpol-path", "vanderpol-path", {"N": 50, "method": "rk4"},
         "Vassiliadis, Sargent and Pantelides 1994 (x1 >= -0.4)", group="built-in",
         note="none verified for this formulation"),
    _row("vanderpol-path-euler", "vanderpol-path", {"N": 50, "method": "euler"},
         "Vassiliadis, Sargent and Pantelides 1994 (x1 >= -0.4)", group="built-in",
         note="none verified for this formulation"),
    _row("rayleigh", "rayleigh", {"N": 50, "method": "rk4"}, "Maurer and Augustin 2001", group="built-in",
         note="none verified for this formulation"),
    _row("rayleigh-euler", "rayleigh", {"N": 50, "method": "euler"}, "Maurer and Augustin 2001",
         group="built-in", note="none verified for this formulation"),
    _row("rayleigh-box", "rayleigh-box", {"N": 50, "method": "rk4"}, "Maurer and Augustin 2001, |u| <= 1",
         group="built-in", note="none verified for this formulation"),
    _row("rayleigh-mixed", "rayleigh-mixed", {"N": 50, "method": "rk4"},
         "Maurer and Augustin 2001, u + x1/6 <= 0", group="built-in", note="none verified for this formulation"),
    _row("cstr", "cstr", {"N": 50, "method": "rk4"}, "Lapidus and Luus 1967; " + _LUUS, 0.13309,
         "Luus 2000 (iterative dynamic programming)", group="built-in"),
    _row("cstr-euler", "cstr", {"N": 100, "method": "euler"}, "Lapidus and Luus 1967; " + _LUUS, 0.13309,
         "Luus 2000 (iterative dynamic programming)", group="built-in"),
]

_COPS = "Dolan, Moré and Munson, COPS 3.0, ANL/MCS-TM-273, 2004"
_BETTS = "Betts, Practical Methods for Optimal Control and Estimation Using Nonlinear Programming, 2nd ed., SIAM 2010"
_COPS_ROWS = [
    _row("goddard", "goddard", {"N": 61}, _COPS + ", 'rocket'", -1.01283,
         "COPS 3.0, max h(T) = 1.01283 (trapezoidal rule, nh = 400)", group="cops"),
    _row("hang-glider", "hang-glider", {"N": 101}, _BETTS + ", sec. 6.5; " + _COPS + ", 'glider'", -1248.03103,
         "Betts 2010, max x(T) = 1248.03103 (continuous time); COPS 3.0: 1255.05 (nh = 100)", group="cops"),
    _row("robot-arm", "robot-arm", {"N": 61}, _COPS + ", 'robot'", 9.14138,
         "COPS 3.0 (trapezoidal rule, nh = 200)", group="cops"),
    _row("particle-steering", "particle-steering", {"N": 51}, _BETTS + "; " + _COPS + ", 'steering'", 0.554570879,
         "Betts 2010 (continuous time); COPS 3.0: 0.554577 (nh = 200)", group="cops"),
    _row("catalyst-mixing", "catalyst-mixing", {"N": 50}, _COPS + ", 'catmix'", -0.0480556,
         "COPS 3.0 (collocation, nh = 100)", group="cops"),
    _row("hanging-chain", "hanging-chain", {"N": 50}, _COPS + ", 'chain'", 5.06891,
         "COPS 3.0 (trapezoidal rule, nh = 800)", group="cops"),
]

_BH = "Bryson and Ho, Applied Optimal Control, 1975"
_LIT_ROWS = [
    _row("brachistochrone", "brachistochrone", {"N": 51}, _BH + ", sec. 2.6", 0.5659010,
         "analytic: sqrt(pi x_f / g)"),
    _row("brachistochrone-point", "brachistochrone-point", {"N": 51}, _BH + ", sec. 2.6", 0.5661432,
         "analytic: the cycloid through (1, 0.6)"),
    _row("double-integrator", "double-integrator", {"N": 50}, _BH + ", sec. 3.11", 2.0, "analytic"),
    _row("bryson-denham", "bryson-denham", {"N": 50}, _BH + ", sec. 3.11 (Bryson, Denham and Dreyfus 1963)",
         4.0, "analytic: 4/(9 l), l = 1/9"),
    _row("bang-bang-cart", "bang-bang-cart", {"N": 51}, _BH + ", sec. 7.3", 3.4494897, "analytic: 1 + sqrt 6"),
    _row("moon-lander", "moon-lander", {"N": 51}, "Meditch, IEEE TAC 9 (1964) 477-484", 8.2462113,
         "analytic: 2 sqrt 17"),
    _row("lotka-fishing", "lotka-fishing", {"N": 60}, "Sager, Numerical methods for mixed-integer optimal control "
         "problems, 2005 (mintOC)", 1.34408, "Sager 2005, the relaxed problem"),
    _row("batch-reactor", "batch-reactor", {"N": 50}, "Ray 1981; " + _LUUS, -0.57353, "Luus 2000: max x2(1) = 0.57353"),
    _row("alp-rider", "alp-rider", {"N": 100}, _BETTS + ", pp. 163-165", 2030.85609,
         "Betts 2010; not reproduced here: the bound int 100 q(t) dt = 1267.7 and RK4 solutions approach "
         "it from above (1275.8 at N = 400), see the problem's docstring"),
    _row("free-flying-robot", "free-flying-robot", {"N": 60}, _BETTS + ", sec. 6.13 (Sakawa 1999)", 7.91055654,
         "Betts 2010 (IPOPT on this discretization: 7.9107 at N = 240)"),
    _row("dubins", "dubins", {"N": 51}, "Dubins, Amer. J. Math. 79 (1957)", 5.1415927, "analytic: pi + 2 (LSL)"),
    _row("rigid-body", "rigid-body", {"N": 61}, _BETTS + ", sec. 6.8 (Fleming, Sekhavat and Ross 2008)",
         28.6304077, "Betts 2010"),
    _row("obstacle", "obstacle", {"N": 50}, "written for olado (two local minima)"),
    _row("cart-pole", "cart-pole", {"N": 50}, "Kelly, SIAM Review 59 (2017) 849-904", None,
         "none published (Kelly shows the trajectory only)"),
    _row("orbit-raising", "orbit-raising", {"N": 50}, _BH + ", sec. 2.5 (Moyer and Pinkham 1964)", -1.525,
         "Bryson and Ho 1975: r(T) = 1.525 (three digits)"),
]

_INF = "deliberately infeasible (proof in the problem's docstring)"
_INFEASIBLE = [
    _row(name, name, settings, _INF, None, "infeasible", feasible=False, group="infeasible")
    for name, settings in (("lq-unreachable", {"N": 50}), ("cart-too-short", {"N": 50}),
                           ("chain-too-short", {"N": 50}), ("catalyst-overfull", {"N": 50}),
                           ("steering-too-short", {"N": 50}), ("vanderpol-contradict", {"N": 50}),
                           ("batch-overyield", {"N": 50}))
]

#: Zambezi families and their horizon in the set
ZAMBEZI = {"zambezi8": 24, "zambezi9": 72, "zambezi10": 48, "zambezi11": 24, "zambezi12": 72}
#: seeds of the perturbed starts
SEEDS = tuple(range(1, 11))
_PAPER = "Błaszczyk, Karbowski, Malinowski (paper 001), sec. 5; CUTEr ZAMB2"


def _zambezi_rows():
    rows = []
    for fam, N in ZAMBEZI.items():
        base = f"{fam}-N{N}"
        note = "discrete-time problem (no continuous counterpart)"
        rows.append(_row(f"{base}-sif", fam, {"N": N, "start": "sif"}, _PAPER + ", start (45) (SIF start point)",
                         None, note, group="zambezi"))
        rows.append(_row(f"{base}-balance", fam, {"N": N, "start": "balance"}, _PAPER + ", start (46)-(47)",
                         None, note, group="zambezi"))
        for seed in SEEDS:
            rows.append(_row(f"{base}-sif-p{seed}", fam, {"N": N, "start": "sif"},
                             _PAPER + f", start (45) perturbed (seed {seed})", None, note, group="zambezi",
                             start="perturbed", seed=seed))
    return rows


#: every entry of the set, in order
ENTRIES = _BUILTIN + _COPS_ROWS + _LIT_ROWS + _INFEASIBLE + _zambezi_rows()
