"""The bounds of the DOCP as IPOPT's barrier sees them (Waechter and Biegler 2006, sec. 2.1,
3.4-3.6): the free variables y = (x^1..x^N, u^0..u^{N-1}) and the slacks of the inequalities as
one flat vector (:class:`Layout`), the finite sides
of their bounds (relaxed by IPOPT's bound_relax_factor), the slacks s_L = y - lb, s_U = ub - y,
the barrier function phi_mu (eq. (3), with the damping term of sec. 3.7 for one-sided bounds),
its gradient, Sigma (eq. (12)), the bound-multiplier step (eq. (13)), the fraction-to-boundary
rule (eq. (15)) and the multiplier safeguard (eq. (16))."""

from __future__ import annotations

import dataclasses

import numpy as np

#: kappa_d of sec. 3.7: the linear damping of variables with one finite bound only
KAPPA_D = 1e-5
EPS = float(np.finfo(float).eps)
#: empty residual arrays (h, e, eN, d, dN) for kernels.point_terms without residuals, and an empty
#: point (v, lo, hi, has_lo, has_hi, sl, su, work) for it without a point: the one compiled pass
#: serves the barrier terms, the residual norms (newton.Residuals.norms) and both at a trial point
NO_RESIDUALS = (np.zeros((0, 0)), np.zeros((0, 0)), np.zeros(0), np.zeros((0, 0)), np.zeros(0))
NO_POINT = (np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0, dtype=bool), np.zeros(0, dtype=bool), np.zeros(0),
            np.zeros(0), np.zeros(0))


def dot(a, b):
    """a.b of two flat vectors in a fixed order (kernels.dot: the same float on every CPU, and the
    one a compiled iteration computes; not BLAS, whose threaded ddot spins its threads on a busy
    machine)."""
    return float(_kernels().dot(a, b))


class Layout:
    """The flat vector of the iterate: v = (x^1..x^N, u^0..u^{N-1}, s (N, ni), s_N (niN,)) with the
    slacks s = g^k of the stage inequalities g^k >= 0 and s_N of the final ones (IPOPT's
    d(x) - s = 0, sec. 3.4 of Waechter and Biegler); equality rows have no slack."""

    def __init__(self, problem):
        p = problem
        self.N, self.n, self.m, self.x0 = p.N, p.n, p.m, np.asarray(p.x0, dtype=float)
        self.eq, self.eqN = np.asarray(p.stage_equality_mask, bool), np.asarray(p.final_equality_mask, bool)
        self.ineq, self.ineqN = ~self.eq, ~self.eqN
        self.ni, self.niN = int(self.ineq.sum()), int(self.ineqN.sum())
        self.ne, self.neN = int(self.eq.sum()), int(self.eqN.sum())
        self.ny = self.N * (self.n + self.m)
        self.size = self.ny + self.N * self.ni + self.niN
        #: whether there are stage or final constraint rows (else the residuals are the dynamics')
        self.rows = bool(self.eq.size or self.eqN.size)
        #: the (empty) residual arrays of the constraint rows of a problem without any
        self.no_rows = (np.zeros((self.N, 0)), np.zeros(0), np.zeros((self.N, 0)), np.zeros(0))
        #: the (empty) Jacobian rows E, F, EN, Ci, CNi of newton.Constraints without any
        N, n, m = self.N, self.n, self.m
        self.no_constraint_rows = (np.zeros((N, 0, n)), np.zeros((N, 0, m)), np.zeros((0, n)), np.zeros((N, 0, n + m)),
                                   np.zeros((0, n)))

    def pack(self, X, U, s=None, sN=None):
        parts = [X[1:].ravel(), U.ravel()]
        parts.append(np.zeros(self.N * self.ni) if s is None else np.asarray(s, float).ravel())
        parts.append(np.zeros(self.niN) if sN is None else np.asarray(sN, float).ravel())
        return np.concatenate(parts)

    def states_controls(self, v):
        """(X, U) of :meth:`split` alone (X row 0 the problem's x0; new arrays)."""
        N, n, m = self.N, self.n, self.m
        X = np.empty((N + 1, n))
        X[0] = self.x0
        X[1:] = v[:N * n].reshape(N, n)
        return X, v[N * n:self.ny].reshape(N, m).copy()

    def slack_views(self, v):
        """(s (N, ni), s_N (niN,)) as views into v (read only by the caller)."""
        return v[self.ny:self.ny + self.N * self.ni].reshape(self.N, self.ni), v[self.ny + self.N * self.ni:]

    def split(self, v, x0=None):
        """(X (N+1, n) with row 0 = x0 (default: the problem's), U (N, m), s (N, ni), s_N (niN,))."""
        N, n, m = self.N, self.n, self.m
        X = np.empty((N + 1, n))
        X[0] = self.x0 if x0 is None else x0
        X[1:] = v[:N * n].reshape(N, n)
        U = v[N * n:self.ny].reshape(N, m).copy()
        s = v[self.ny:self.ny + N * self.ni].reshape(N, self.ni).copy()
        return X, U, s, v[self.ny + N * self.ni:].copy()


@dataclasses.dataclass
class Bounds:
    """The finite bound sides of the free variables (relaxed), as flat vectors with masks."""

    lo: np.ndarray
    hi: np.ndarray
    has_lo: np.ndarray
    has_hi: np.ndarray

    @classmethod
    def of(cls, problem, layout, relax=1e-8, relax_max=np.inf):
        """The bounds of ``problem`` relaxed by min(relax max(1, |bound|), relax_max) (IPOPT's
        bound_relax_factor, capped by constr_viol_tol as IPOPT does); the slacks >= 0."""
        L = layout
        s0 = (np.zeros((L.N, L.ni)), np.zeros(L.niN))
        lo = L.pack(problem.x_lower, problem.u_lower, *s0).astype(float)
        hi = L.pack(problem.x_upper, problem.u_upper, np.full((L.N, L.ni), np.inf), np.full(L.niN, np.inf))
        has_lo, has_hi = np.isfinite(lo), np.isfinite(hi)
        lo = np.where(has_lo, lo - np.minimum(relax * np.maximum(1.0, np.abs(np.where(has_lo, lo, 0.0))), relax_max),
                      -np.inf)
        hi = np.where(has_hi, hi + np.minimum(relax * np.maximum(1.0, np.abs(np.where(has_hi, hi, 0.0))), relax_max),
                      np.inf)
        return cls(lo, hi, has_lo, has_hi)

    def __post_init__(self):
        # the one-sided masks as floats, for the damping term's dot products (sec. 3.7)
        self.one_lo_f = (self.has_lo & ~self.has_hi).astype(float)
        self.one_hi_f = (self.has_hi & ~self.has_lo).astype(float)
        self.one_sided = bool(self.one_lo_f.any() or self.one_hi_f.any())
        #: the number of finite sides (the masks never change; lo, hi may be moved or replaced)
        self._count = int(self.has_lo.sum() + self.has_hi.sum())
        self._work = None
        #: what depends on the point alone, for the two points last asked about (:class:`AtPoint`)
        self._points = []

    def at(self, v) -> "AtPoint":
        """The cached quantities of the point ``v`` (by identity: the solver never changes an
        iterate in place, it makes a new vector). An iteration asks for the slacks of its
        iterate six times (errors, Sigma, barrier gradient, phi, step rules) and for those of the
        previous iterate once more (the dual step); the two latest points are kept."""
        for e in self._points:
            if e.v is v:
                return e
        e = AtPoint(v)
        self._points = [e] + self._points[:1]
        return e

    @property
    def count(self):
        return self._count

    def push(self, v, kappa1=1e-2, kappa2=1e-2):
        """The starting point moved strictly inside the bounds (sec. 3.6, IPOPT's bound_push and
        bound_frac)."""
        lo, hi = self.lo, self.hi
        width = np.where(self.has_lo & self.has_hi, hi - lo, np.inf)
        with np.errstate(invalid="ignore"):
            pl = np.minimum(kappa1 * np.maximum(1.0, np.abs(np.where(self.has_lo, lo, 0.0))), kappa2 * width)
            pu = np.minimum(kappa1 * np.maximum(1.0, np.abs(np.where(self.has_hi, hi, 0.0))), kappa2 * width)
        v = np.where(self.has_lo, np.maximum(v, lo + pl), v)
        return np.where(self.has_hi, np.minimum(v, hi - pu), v)

    def move_tiny(self, v):
        """IPOPT's slack_move: a side whose slack fell below rounding relative to the variable
        (eps max(1, |v|); then s = v - lb is no longer resolved) has its bound moved by
        eps^(3/4) max(1, |bound|), so that Sigma and the barrier stay finite. Returns the count."""
        eps = np.finfo(float).eps
        moved = _kernels().move_tiny(v, self.lo, self.hi, self.has_lo, self.has_hi, eps, eps ** 0.75)
        if moved:
            self._points = []          # the slacks changed with the bounds
        return moved

    def forget(self, v):
        """Drop what was computed at ``v`` (its array is about to hold another point)."""
        points = self._points
        if any(e.v is v for e in points):
            self._points = [e for e in points if e.v is not v]

    def keep_only(self, v):
        """Keep what was computed at ``v`` only (the solver's new iterate after its step: the
        previous iterate's entry served the multiplier step; asked again -- the watchdog going
        back -- it is computed again, the same numbers)."""
        points = self._points
        if len(points) > 1 or (points and points[0].v is not v):
            self._points = [e for e in points if e.v is v]

    def slacks(self, v):
        """(s_L, s_U), 1 where a side is infinite (they carry no multiplier). Cached per point:
        read them, never write into them."""
        points = self._points
        if points and points[0].v is v and points[0].slacks is not None:    # at()'s first entry, inline
            return points[0].slacks
        e = self.at(v)
        if e.slacks is None:
            e.slacks = np.empty_like(v), np.empty_like(v)
            _kernels().slacks(v, self.lo, self.hi, self.has_lo, self.has_hi, *e.slacks)
        return e.slacks

    def barrier_terms(self, v):
        """The parts of phi_mu's barrier terms that do not depend on mu: (sum ln s_L + sum ln s_U,
        the damped sides' sum of slacks), or None outside the bounds. Cached per point."""
        e = self.at(v)
        if e.terms is None:
            # the slacks (cached with the point) and np.log(sl).sum() + np.log(su).sum() in one
            # compiled pass (kernels.barrier_logs in kernels.point_terms, here without residuals:
            # numpy's sums); log(1) = 0 on the infinite sides
            self._prepare(e, v)
            _, _, inside, logs = _kernels().point_terms(v, self.lo, self.hi, self.has_lo, self.has_hi, *e.slacks,
                                                        self._work, *NO_RESIDUALS)
            self._store_terms(e, inside, logs)
        return None if e.terms[0] is None else e.terms

    def _prepare(self, e, v):
        """The slack arrays of the point's entry and the work array, allocated once."""
        if e.slacks is None:
            e.slacks = np.empty_like(v), np.empty_like(v)
        if self._work is None or self._work.size != v.size:
            self._work = np.empty_like(v)

    def _store_terms(self, e, inside, logs):
        """The entry's barrier terms from barrier_logs' (inside, sum of logs) and its slacks."""
        if not inside:
            e.terms = (None,)
        else:
            sl, su = e.slacks
            # 1/1 times a zero mask on the infinite sides; exactly 0 without one-sided bounds
            damped = dot(self.one_lo_f, sl) + dot(self.one_hi_f, su) if self.one_sided else 0.0
            e.terms = (logs, damped)

    def point_terms(self, v, res, mu, slacks=None):
        """(l1, max) of the residual arrays ``res`` (newton.Residuals) and :meth:`barrier_value`
        at v (the barrier terms cached with the point, as :meth:`barrier_terms`), in one compiled
        pass (kernels.point_terms) for a new point -- the line search's trial point. ``slacks``:
        the arrays (s_L, s_U) the point's slacks are written into and kept in (else new ones)."""
        e = self.at(v)
        if e.terms is not None:
            return (*res.norms(), self.barrier_value(v, mu))
        if e.slacks is None and slacks is not None:
            e.slacks = slacks
        self._prepare(e, v)
        l1, mx, inside, logs = _kernels().point_terms(v, self.lo, self.hi, self.has_lo, self.has_hi, *e.slacks,
                                                      self._work, *res)
        self._store_terms(e, inside, logs)
        if e.terms[0] is None:
            return l1, mx, np.inf
        logs, damped = e.terms          # barrier_value's formula
        return l1, mx, -mu * logs + KAPPA_D * mu * damped

    def barrier_value(self, v, mu):
        """The barrier terms of phi_mu at v (eq. (3) with the damping of sec. 3.7); +inf outside
        the bounds."""
        terms = self.barrier_terms(v)
        if terms is None:
            return np.inf
        logs, damped = terms
        return -mu * logs + KAPPA_D * mu * damped

    def barrier(self, v, mu):
        """The barrier terms of phi_mu at v (+inf outside the bounds) and their gradient
        mu (1 / s_U - 1 / s_L) + kappa_d mu (1 on lower-bounded-only, -1 on upper-bounded-only sides)."""
        if self.barrier_terms(v) is None:
            return np.inf, None
        return self.barrier_value(v, mu), self.gradient(v, mu)

    def gradient(self, v, mu):
        """The gradient of the barrier terms at v (inside the bounds), without their value."""
        sl, su = self.slacks(v)
        grad = np.empty_like(sl)
        _kernels().barrier_gradient(sl, su, self.has_lo, self.has_hi, mu, KAPPA_D * mu, grad)
        return grad

    def sigma(self, v, zl, zu):
        """Sigma = Z_L / S_L + Z_U / S_U (eq. (12))."""
        sl, su = self.slacks(v)
        out = np.empty_like(sl)
        _kernels().sigma(sl, su, zl, zu, out)
        return out

    def dual_step(self, v, dv, zl, zu, mu):
        """The bound-multiplier step of eq. (13): dz_L = mu / s_L - z_L - Sigma_L dv, and the
        same for the upper side (0 on infinite sides)."""
        sl, su = self.slacks(v)
        dzl, dzu = np.empty_like(sl), np.empty_like(sl)
        _kernels().dual_step(sl, su, zl, zu, dv, self.has_lo, self.has_hi, mu, dzl, dzu)
        return dzl, dzu

    def max_step(self, v, dv, tau):
        """The fraction-to-boundary rule (15) for the primal variables: the largest alpha in
        (0, 1] with s + alpha ds >= (1 - tau) s on every finite side."""
        sl, su = self.slacks(v)
        a_lo, a_hi = _kernels().max_step(sl, su, dv, self.has_lo, self.has_hi, -tau, tau)
        return min(1.0, float(a_lo), float(a_hi))

    def step_terms(self, v, step, tau, dv=None):
        """(dv, alpha_max, tiny) of a Newton step (newton.Step) at v in one compiled pass
        (kernels.step_terms): dv = Layout.pack(step.dX, step.dU, step.ds, step.dsN) (into ``dv`` if
        given), alpha_max = :meth:`max_step` (v, dv, tau), tiny = max |dv| / (1 + |v|) (IPOPT's tiny
        step test)."""
        sl, su = self.slacks(v)
        if dv is None:
            dv = np.empty_like(v)
        alpha_max, tiny = _kernels().step_terms(step.dX, step.dU, step.ds, step.dsN, v, sl, su, self.has_lo,
                                                self.has_hi, -tau, tau, dv)
        return dv, alpha_max, tiny

    def step_multipliers(self, slacks, v_new, dv, zl, zu, mu, tau, lam, lam_step, alpha, kappa_sigma=1e10, out=None):
        """The multipliers after a step from the point of ``slacks`` (its :meth:`slacks`) to v_new
        along dv: the bound multipliers by :meth:`dual_step_length`, :meth:`move_tiny` at v_new,
        then :meth:`safeguard_step` there, and lam + alpha (lam_step - lam) (the dynamics
        multipliers' step), in one compiled pass (kernels.step_bound_multipliers). Returns (z_L,
        z_U, alpha_z, the new lam); the slacks at v_new are cached with it. ``out``: the arrays
        (s_L, s_U, z_L, z_U, lam) to write into (none of them an input), else new ones."""
        sl, su = slacks
        if out is None:
            sl_new, su_new, zl_new, zu_new = (np.empty_like(v_new) for _ in range(4))
            lam_new = np.empty(lam.shape)
        else:
            sl_new, su_new, zl_new, zu_new, lam_new = out
        alpha_z, moved = _kernels().step_bound_multipliers(sl, su, v_new, dv, self.lo, self.hi, self.has_lo,
                                                           self.has_hi, zl, zu, mu, -tau, EPS, EPS ** 0.75,
                                                           kappa_sigma, kappa_sigma * mu, sl_new, su_new, zl_new,
                                                           zu_new, lam, lam_step, alpha, lam_new)
        if moved:
            self._points = []          # the slacks changed with the bounds
        e = self.at(v_new)
        if e.slacks is None:        # (the caller's arrays are its own: copies are kept)
            e.slacks = (sl_new, su_new) if out is None else (sl_new.copy(), su_new.copy())
        return zl_new, zu_new, alpha_z, lam_new

    def dual_step_length(self, v, dv, zl, zu, mu, tau):
        """(dz_L, dz_U, alpha_z): :meth:`dual_step` and the smaller of the two sides'
        :meth:`max_dual_step` in one compiled pass."""
        sl, su = self.slacks(v)
        dzl, dzu = np.empty_like(sl), np.empty_like(sl)
        r_l, r_u = _kernels().dual_step_lengths(sl, su, zl, zu, dv, self.has_lo, self.has_hi, mu, -tau, dzl, dzu)
        return dzl, dzu, min(min(1.0, float(r_l)), min(1.0, float(r_u)))

    def safeguard_step(self, v, zl, zu, dzl, dzu, alpha_z, mu, kappa_sigma=1e10):
        """:meth:`safeguard` of (zl + alpha_z dzl, zu + alpha_z dzu), in one compiled pass."""
        sl, su = self.slacks(v)
        out_l, out_u = np.empty_like(sl), np.empty_like(sl)
        _kernels().safeguard_step(sl, su, zl, zu, dzl, dzu, alpha_z, self.has_lo, self.has_hi, mu, kappa_sigma,
                                  kappa_sigma * mu, out_l, out_u)
        return out_l, out_u

    def sigma_blocks(self, v, zl, zu, layout):
        """:meth:`sigma` split by ``layout`` as (Sx (N+1, n) with row 0 zero, Su, Ss, SsN)."""
        L = layout
        sl, su = self.slacks(v)
        out = np.empty((L.N + 1, L.n)), np.empty((L.N, L.m)), np.empty((L.N, L.ni)), np.empty(L.niN)
        _kernels().sigma_blocks(sl, su, zl, zu, *out)
        return out

    @staticmethod
    def max_dual_step(z, dz, tau):
        """The fraction-to-boundary rule (15) for multipliers z >= 0."""
        return min(1.0, float(_kernels().max_dual_step(z, dz, -tau)))

    def safeguard(self, v, zl, zu, mu, kappa_sigma=1e10):
        """The multiplier reset (16): z within [mu / (kappa_sigma s), kappa_sigma mu / s]."""
        sl, su = self.slacks(v)
        out_l, out_u = np.empty_like(sl), np.empty_like(sl)
        _kernels().safeguard(sl, su, zl, zu, self.has_lo, self.has_hi, mu, kappa_sigma, kappa_sigma * mu, out_l, out_u)
        return out_l, out_u

    def complementarity(self, v, zl, zu, mu):
        """max |s z - mu| over the finite sides (the complementarity part of eq. (5))."""
        return self.complementarities(v, zl, zu, mu, mu)[0]

    def complementarities(self, v, zl, zu, mu, mu1):
        """:meth:`complementarity` for two barrier parameters, in one compiled pass."""
        sl, su = self.slacks(v)
        n_lo, m_lo, m_lo1, n_hi, m_hi, m_hi1 = _kernels().complementarity(sl, su, zl, zu, self.has_lo, self.has_hi,
                                                                          mu, mu1)
        return _sides_max(n_lo, m_lo, n_hi, m_hi), _sides_max(n_lo, m_lo1, n_hi, m_hi1)


def _sides_max(n_lo, m_lo, n_hi, m_hi):
    """max((m for n, m in ((n_lo, m_lo), (n_hi, m_hi)) if n), default=0.0): Python's max (a later
    value replaces only a smaller one, so a NaN first stays)."""
    if not n_lo:
        return float(m_hi) if n_hi else 0.0
    return float(m_hi) if n_hi and m_hi > m_lo else float(m_lo)


_KERNEL_MODULE = None


def _kernels():
    """The compiled passes (olado.solvers.ipm.kernels), loaded on first use: importing olado
    does not load numba. (Kept after the first call: an import statement costs a microsecond,
    and an ipm iteration asks about ten times.)"""
    global _KERNEL_MODULE
    if _KERNEL_MODULE is None:
        from . import kernels    # noqa: PLC0415

        _KERNEL_MODULE = kernels
    return _KERNEL_MODULE


class AtPoint:
    """What :class:`Bounds` computed at one point v: the slacks (s_L, s_U) and the barrier
    terms independent of mu (None until asked for)."""

    __slots__ = ("v", "slacks", "terms")

    def __init__(self, v):
        self.v, self.slacks, self.terms = v, None, None
