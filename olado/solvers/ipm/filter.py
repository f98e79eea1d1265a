"""The filter of the line search (Waechter and Biegler 2006, Math. Program. 106, sec. 2.3-2.4).

A trial point is judged by the pair (theta, phi): theta the constraint violation (1-norm of the
dynamics residuals), phi the barrier function (eq. (3)). The filter F is a set of pairs; a point
is acceptable to it when it is not dominated by any of them (eq. (18): theta < theta_j or
phi < phi_j for every (theta_j, phi_j) in F).

Acceptance of a trial step of length alpha along d from (theta, phi) with barrier directional
derivative g = grad phi . d:

* switching condition (19): g < 0 and alpha (-g)^s_phi > delta theta^s_theta;
* if it holds and theta <= theta_min: Armijo condition (20), phi_trial <= phi + eta_phi alpha g;
* otherwise sufficient decrease with respect to the current point (18):
  theta_trial <= (1 - gamma_theta) theta or phi_trial <= phi - gamma_phi theta;
* after acceptance the filter is augmented (22) by ((1 - gamma_theta) theta, phi - gamma_phi theta)
  unless (19) and (20) both hold for the accepted alpha (an "f-type" iteration; step A-8 of
  Algorithm A, IPOPT's FilterLSAcceptor::UpdateForNextIteration), also above theta_min.
* alpha_min (23): below it the line search gives up and the restoration phase starts.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np


@dataclasses.dataclass(frozen=True)
class FilterConstants:
    """The constants of the filter line search (Waechter and Biegler 2006, Table 1 / IPOPT's
    defaults)."""

    gamma_theta: float = 1e-5
    gamma_phi: float = 1e-8
    delta: float = 1.0
    s_theta: float = 1.1
    s_phi: float = 2.3
    eta_phi: float = 1e-8
    gamma_alpha: float = 0.05
    obj_max_inc: float = 5.0        # IPOPT: reject a barrier increase of more than this many orders
    filter_reset_trigger: int = 5   # IPOPT: clear the filter after this many acceptances in a row that
    max_filter_resets: int = 5      # followed a rejection by the filter (at most max_filter_resets times)


@dataclasses.dataclass
class Filter:
    """The filter F (a list of (theta, phi) corner points) with theta_max and theta_min of
    sec. 2.3 (theta_max = 1e4 max(1, theta_0), theta_min = 1e-4 max(1, theta_0))."""

    theta_max: float
    theta_min: float
    const: FilterConstants = dataclasses.field(default_factory=FilterConstants)
    entries: list = dataclasses.field(default_factory=list)
    resets: int = 0                 # filter resets by the heuristic
    rejected_by_filter: bool = False    # the last rejected trial was rejected by the filter
    filter_rejections: int = 0      # acceptances in a row that followed a rejection by the filter

    @classmethod
    def start(cls, theta0, const=None, theta_max_fact=1e4):
        """F_0 at the start theta0; theta_max = theta_max_fact max(1, theta0) (IPOPT's theta_max_fact:
        1e4, 1e8 in the restoration problem)."""
        f = cls(theta_max_fact * max(1.0, theta0), 1e-4 * max(1.0, theta0), const or FilterConstants())
        f.reset()
        return f

    def reset(self):
        """F_0 = {(theta, phi): theta >= theta_max} (sec. 2.3); also after a barrier update and by
        the reset heuristic (IPOPT's FilterLSAcceptor::Reset)."""
        self.entries = [(self.theta_max, -np.inf)]
        self.rejected_by_filter = False
        self.filter_rejections = 0

    def acceptable(self, theta, phi) -> bool:
        """Whether (theta, phi) is acceptable to the filter: not dominated by any entry (a pair
        with theta >= theta_j and phi >= phi_j is rejected)."""
        return all(theta < tj or phi < pj for tj, pj in self.entries)

    def add(self, theta, phi):
        """Augment the filter by the corner (22) of the current point."""
        c = self.const
        t, p = (1.0 - c.gamma_theta) * theta, phi - c.gamma_phi * theta
        # drop the entries the new one dominates (they add nothing to the forbidden region)
        self.entries = [(tj, pj) for tj, pj in self.entries if not (tj >= t and pj >= p)] + [(t, p)]

    def switching(self, alpha, theta, gphi) -> bool:
        """Switching condition (19)."""
        c = self.const
        return gphi < 0 and alpha * (-gphi) ** c.s_phi > c.delta * theta ** c.s_theta

    def accept(self, alpha, theta, phi, gphi, theta_t, phi_t):
        """Judge a trial point: (accepted, f_type). ``f_type`` says the switching condition (19)
        and the Armijo condition (20) both hold for alpha -- then the filter is not augmented
        (Algorithm A, step A-8), whatever decided the acceptance. The order of the tests and the
        two safeguards are IPOPT's (FilterLSAcceptor::CheckAcceptabilityOfTrialPoint): theta_max,
        the barrier function rising by more than obj_max_inc orders of magnitude, the decrease
        with respect to the current point, then the filter; and the filter reset heuristic."""
        c = self.const
        if not math.isfinite(phi_t) or theta_t > self.theta_max:
            return False, False
        # switching (19), the Armijo test (20), the decrease (18) and acceptable() inline (the
        # line search asks once per trial point)
        switching = gphi < 0 and alpha * (-gphi) ** c.s_phi > c.delta * theta ** c.s_theta
        armijo = bool(phi_t <= phi + c.eta_phi * alpha * gphi)
        if theta <= self.theta_min and switching:
            ok = armijo
        elif phi_t > phi:
            ok = self._decrease(theta, phi, theta_t, phi_t)
        else:
            ok = theta_t <= (1.0 - c.gamma_theta) * theta or phi_t <= phi - c.gamma_phi * theta
        if not ok:
            self.rejected_by_filter = False
            return False, False
        for tj, pj in self.entries:
            if not (theta_t < tj or phi_t < pj):
                self.rejected_by_filter = True
                return False, False
        self._reset_heuristic()
        return True, switching and armijo

    def acceptable_to_iterate(self, theta, phi, theta_t, phi_t) -> bool:
        """Sufficient decrease (18) of (theta_t, phi_t) with respect to the iterate (theta, phi) (IPOPT's
        IsAcceptableToCurrentIterate, also the restoration phase's test against the original iterate)."""
        return self._decrease(theta, phi, theta_t, phi_t)

    def _decrease(self, theta, phi, theta_t, phi_t):
        """Sufficient decrease (18) with respect to the current point, after IPOPT's obj_max_inc test."""
        c = self.const
        if phi_t > phi:
            base = np.log10(abs(phi)) if abs(phi) > 10.0 else 1.0
            if np.log10(phi_t - phi) > c.obj_max_inc + base:
                return False
        return theta_t <= (1.0 - c.gamma_theta) * theta or phi_t <= phi - c.gamma_phi * theta

    def _reset_heuristic(self):
        """IPOPT's filter reset: an accepted trial after a rejection by the filter counts; after
        filter_reset_trigger of them in a row the filter is cleared (at most max_filter_resets times)."""
        c = self.const
        if self.resets < c.max_filter_resets:
            if self.rejected_by_filter:
                self.filter_rejections += 1
                if self.filter_rejections >= c.filter_reset_trigger:
                    self.resets += 1
                    self.reset()
            else:
                self.filter_rejections = 0
        self.rejected_by_filter = False

    def alpha_min(self, theta, gphi) -> float:
        """alpha_min of (23): the smallest step the backtracking tries before the restoration."""
        c = self.const
        if gphi < 0:
            a = min(c.gamma_theta, -c.gamma_phi * theta / gphi, c.delta * theta ** c.s_theta / (-gphi) ** c.s_phi)
            if theta > self.theta_min:
                a = min(c.gamma_theta, -c.gamma_phi * theta / gphi)
        else:
            a = c.gamma_theta
        return c.gamma_alpha * a
