"""IPOPT's adaptive barrier parameter update (``mu_strategy = adaptive``): Nocedal, Waechter and
Waltz, Adaptive barrier update strategies for nonlinear interior methods, SIAM J. Optim. 19
(2009) 1674-1693 (below "NWW"), as IPOPT implements it (AdaptiveMuUpdate with the
quality-function oracle and the obj-constr-filter globalization; Waechter and Biegler 2006
sec. 3.2 describe the monotone rule it falls back to).

Free mode (every iteration while the globalization sees progress): tau = max(tau_min, 1 - E_0),
mu = sigma * avg(s z), sigma minimizing the quality function (NWW sec. 4: the linearized KKT error
after the step of the Newton system with mu = sigma avg(s z), whose steps are affine in sigma --
the affine-scaling step (mu = 0) plus sigma times the centering step, one factorization),

    q(sigma) = (1 - alpha_d)^2 |grad L|^2 / n_d + (1 - alpha_p)^2 |c|^2 / n_p
               + |(s + alpha_p ds)(z + alpha_d dz)|^2 / n_c,

with alpha_p, alpha_d the fraction-to-boundary steps, by a golden-section search in sigma on
[max(sigma_min, mu_min / avg), 0.99] or [1, min(sigma_max, mu_max / avg)] (the side where q
decreases from sigma = 1), at most 8 sections; mu_max = 1e3 avg(s z) at the start, mu_min =
min(1e-11, tol / 2). The filter of the line search is cleared whenever mu is set.

Globalization (NWW sec. 5, IPOPT's obj-constr-filter): the accepted iterates' pairs (s_f J, theta)
form a filter; an iterate that the filter does not accept with the margin 1e-5 min(1, E_0) ends
the free mode: mu = 0.8 avg(s z) and the monotone rule (7) until an iterate is acceptable again.
"""

from __future__ import annotations

import dataclasses
import math


#: IPOPT's defaults: sigma_min, sigma_max, quality_function_section_sigma_tol,
#: quality_function_max_section_steps, mu_max_fact, adaptive_mu_monotone_init_factor,
#: filter_margin_fact, filter_max_margin, mu_min
SIGMA_MIN, SIGMA_MAX, SIGMA_TOL, MAX_SECTIONS = 1e-6, 100.0, 1e-2, 8
MU_MAX_FACT, MONOTONE_INIT_FACTOR = 1e3, 0.8
FILTER_MARGIN_FACT, FILTER_MAX_MARGIN, MU_MIN = 1e-5, 1.0, 1e-11
GOLDEN = (3.0 - math.sqrt(5.0)) / 2.0


@dataclasses.dataclass
class AdaptiveMu:
    """The adaptive update's memory: free or monotone mode, mu_max, and the obj-constr filter of
    accepted iterates (a list of (s_f J, theta))."""

    free: bool = True
    mu_max: float = -1.0
    entries: list = dataclasses.field(default_factory=list)

    def acceptable(self, f, theta, margin):
        return all(f + margin < fj or theta + margin < tj for fj, tj in self.entries)

    def remember(self, f, theta):
        self.entries = [(fj, tj) for fj, tj in self.entries if not (f <= fj and theta <= tj)] + [(f, theta)]


def average_complementarity(bounds, v, zl, zu):
    """avg(s z) over the finite bound sides (IPOPT's curr_avrg_compl)."""
    sl, su = bounds.slacks(v)
    total = float((sl * zl)[bounds.has_lo].sum() + (su * zu)[bounds.has_hi].sum())
    return total / max(bounds.count, 1)


class QualityFunction:
    """q(sigma) of the module docstring for the steps dv(sigma) = dv0 + sigma (dv1 - dv0) (dv0 the
    affine-scaling step, dv1 the step with mu = avg(s z)) at the iterate (v, zl, zu)."""

    def __init__(self, bounds, v, zl, zu, tau, avg, dv0, dv1, dual, res):
        self.b, self.v, self.zl, self.zu, self.tau, self.avg = bounds, v, zl, zu, tau, avg
        self.dv0, self.ddv = dv0, dv1 - dv0
        self.dual2 = float(dual @ dual) / max(dual.size, 1)
        npri = sum(a.size for a in res)
        self.primal2 = sum(float((a * a).sum()) for a in res) / max(npri, 1)
        self.sl, self.su = bounds.slacks(v)
        self.evaluations = 0

    def __call__(self, sigma):
        b = self.b
        self.evaluations += 1
        dv = self.dv0 + sigma * self.ddv
        dzl, dzu = b.dual_step(self.v, dv, self.zl, self.zu, sigma * self.avg)
        ap = b.max_step(self.v, dv, self.tau)
        ad = min(b.max_dual_step(self.zl, dzl, self.tau), b.max_dual_step(self.zu, dzu, self.tau))
        cl = ((self.sl + ap * dv) * (self.zl + ad * dzl))[b.has_lo]
        cu = ((self.su - ap * dv) * (self.zu + ad * dzu))[b.has_hi]
        compl = (float(cl @ cl) + float(cu @ cu)) / max(b.count, 1)
        return (1.0 - ad) ** 2 * self.dual2 + (1.0 - ap) ** 2 * self.primal2 + compl


def golden_section(q, lo, up, q_lo=None, q_up=None):
    """The sigma in [lo, up] minimizing q by golden sections (IPOPT's PerformGoldenSection, in
    sigma itself -- IPOPT's ScaleSigma is the identity: at most MAX_SECTIONS, while the interval
    is at least SIGMA_TOL of its upper end; an end of the original interval is taken when q is
    smaller there)."""
    a, c = lo, up
    m1, m2 = a + GOLDEN * (c - a), a + (1.0 - GOLDEN) * (c - a)
    q1, q2 = q(m1), q(m2)
    for _ in range(MAX_SECTIONS):
        if (c - a) < SIGMA_TOL * c:
            break
        if q1 > q2:
            a, m1, q1 = m1, m2, q2
            m2 = a + (1.0 - GOLDEN) * (c - a)
            q2 = q(m2)
        else:
            c, m2, q2 = m2, m1, q1
            m1 = a + GOLDEN * (c - a)
            q1 = q(m1)
    best, qb = (m1, q1) if q1 < q2 else (m2, q2)
    if c == up:
        if (q(c) if q_up is None else q_up) < qb:
            best = c
    elif a == lo:
        if (q(a) if q_lo is None else q_lo) < qb:
            best = a
    return best


def quality_function_sigma(q, avg, mu_min, mu_max):
    """IPOPT's QualityFunctionMuOracle: compare q(1) with q(1 - SIGMA_TOL) and search the side
    where q decreases; returns sigma."""
    q1 = q(1.0)
    s1m = 1.0 - max(1e-4, SIGMA_TOL)
    q1m = q(s1m)
    if q1m > q1:
        up = min(SIGMA_MAX, mu_max / avg)
        return up if 1.0 >= up else golden_section(q, 1.0, up, q_lo=q1)
    lo = max(SIGMA_MIN, mu_min / avg)
    up = min(max(lo, s1m), mu_max / avg)
    return lo if lo >= up else golden_section(q, lo, up, q_up=q1m)
