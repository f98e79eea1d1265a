"""Automatic scaling of a DOCP (seed 004, Sagliano 2014): a wrapper DOCP that any solver solves.

The scaled problem keeps the DOCP's structure. Its variables are, per stage and component (seed 004 eqs. (3)-(4); ``d`` = 1/K_x,
``s`` = -b_x/K_x)::

    x^k = dx^k * x~^k + sx^k,    u^k = du^k * u~^k + su^k                                   (3)

The factors are the same at every stage where the bounds are (stationary bounds), and differ
where a problem's bounds do (e.g. the parameter stage 0 of a free-final-time problem, whose
control is the final time): a per-stage affine change of variables keeps a DOCP a DOCP.

its functions, with c = K_j the objective factor, w the constraint row factors (eq. (5)) and
phi the nonlinear constraint transforms of sec. 5 (identity for linear scaling)::

    f~^k(x~, u~)  = (f^k(x, u) - sx^{k+1}) / dx^{k+1}   the dynamics rows: K_f = K_x (isoscaling)
    f~_0^k        = c f_0^k,    F~^N = c F^N                                              (8)
    g~^k_i        = phi_i(w^k_i g^k_i(x, u)),     g~^N_i = phi_i(w^N_i g^N_i(x))            (5), (9), (13)

In a DOCP the next state appears with coefficient one in its dynamics row (x^{k+1} = f^k), so the
dynamics rows are necessarily scaled like the states: K_f = K_x. The seed's choice between IS,
JRN and PJRN for the rows F (eqs. (4), (6), (7)) therefore becomes a choice of the state scale
``dx`` (:func:`state_scale`); the constraints G get their own row factors (eq. (6) or (7), per
stage and component) or the nonlinear transforms of sec. 5 on the components a problem declares
intrinsically positive (:data:`POSITIVE_ATTRIBUTE`).

Derivatives are transformed exactly (chain rule; the Hessian of a nonlinear row adds
phi'' w^2 grad g grad g^T), and :meth:`ScaledDOCP.to_original` / :func:`unscale_multipliers`
map a solution back. The quality measure is eq. (16), :func:`condition_ratio`. The design and
the measurements: docs/scaling.md.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..errors import ConfigError, NonFiniteEvaluationError, ProblemDefinitionError
from .docp import DOCP

#: the methods of the ``scaling`` option (docs/scaling.md)
METHODS = ("none", "auto", "iso", "jrn", "pjrn")

#: a DOCP may declare constraint components intrinsically positive (g_i > -1 wherever it is
#: evaluated, seed 004 eq. (11)): ``positive_constraints = {"stage": [i, ...], "final": [j, ...]}``
POSITIVE_ATTRIBUTE = "positive_constraints"

#: the nonlinear transforms of seed 004 sec. 5 for g >= 0 (C = 1, eq. (11)), written so that
#: phi(0) = 0 and phi' > 0: the constraint g~ >= 0 (= 0) holds exactly where g >= 0 (= 0)
NONLINEAR = ("log", "ip")

#: the factor of the objective is 1 / |grad J~| clipped to [OBJECTIVE_MIN, 1 / OBJECTIVE_FLOOR]:
#: at most 100 upward and 1e8 downward (IPOPT's nlp_scaling_min_value: a start far from the
#: solution -- lq-box at N = 400 has |grad J| ~ 1e23 there -- would otherwise leave an objective
#: too small for any stopping test near the solution)
OBJECTIVE_FLOOR = 1e-2
OBJECTIVE_MIN = 1e-8

#: the (state, constraint) methods of each preset (module docstring; docs/scaling.md)
PRESETS = {
    "iso": ("iso", "none", None),     # seed 004 sec. 4: isoscaling leaves G alone
    "jrn": ("jrn", "jrn", None),      # eq. (6) for F and G
    "pjrn": ("pjrn", "pjrn", None),   # eq. (7) for F and G
    "auto": ("iso", "pjrn", "ip"),    # the seed's proposals: PJRN for G, inverse power where positive
}


@dataclasses.dataclass
class Scaling:
    """The scale factors of one scaled DOCP (module docstring for the symbols)."""

    method: str
    dx: np.ndarray            # (N+1, n) state scales, the reciprocal of K_x (and of K_f)
    sx: np.ndarray            # (N+1, n) state shifts
    du: np.ndarray            # (N, m)
    su: np.ndarray            # (N, m)
    objective: float          # c = K_j
    stage_rows: np.ndarray    # (N, r) w^k: linear factors of the stage constraints
    final_rows: np.ndarray    # (rN,)
    stage_kind: tuple = ()    # per stage-constraint component: "linear", "log" or "ip"
    final_kind: tuple = ()
    stage_power: np.ndarray = None   # (r,) the exponent n of eq. (14) where the kind is "ip"
    final_power: np.ndarray = None
    notes: list = dataclasses.field(default_factory=list)

    def summary(self) -> dict:
        """The factors in a form for a Result's info and for printing."""
        def span(a):
            a = np.asarray(a, dtype=float)
            return [float(a.min()), float(a.max())] if a.size else []

        def per_component(a):   # [min, max] over the stages, per component
            return [span(a[:, i]) for i in range(a.shape[1])]
        return {"method": self.method, "objective_factor": self.objective,
                "state_scale": per_component(self.dx), "state_shift": per_component(self.sx),
                "control_scale": per_component(self.du), "control_shift": per_component(self.su),
                "stage_row_factor_range": span(self.stage_rows), "final_row_factors": self.final_rows.tolist(),
                "stage_transforms": list(self.stage_kind), "final_transforms": list(self.final_kind),
                "notes": list(self.notes)}


# ============================================================================ scale factors
def check_method(method, key="scaling"):
    """``method`` if it is one of :data:`METHODS`; ConfigError naming ``key`` otherwise."""
    if not isinstance(method, str) or method not in METHODS:
        raise ConfigError(f"unknown scaling method {method!r}; choose one of {', '.join(METHODS)}", key=key)
    return method


#: an artificial range (bound_scale) takes the start trajectory's magnitude up to this multiple
#: of the component's known size (x^0, finite bounds, 1)
TRAJECTORY_TRUST = 1e3


def bound_scale(lower, upper, reference, trajectory):
    """Per-stage scale and shift of eq. (4): d^k = x_U^k - x_L^k, s^k = x_L^k where both bounds
    are finite and apart. Elsewhere (a fixed or unbounded component at a stage) the component's
    largest finite range over the stages, else an artificial range (Betts sec. 4.8): the
    component's size over the start trajectory, at least its known size (the magnitudes of
    ``reference`` -- x^0 for the states -- and of its finite bounds, and 1) and at most
    TRAJECTORY_TRUST times that. The shift is the lower bound where both bounds are finite,
    else 0. Returns (d, s) shaped like the bounds.

    The cap matters: a simulated start can diverge (lq-box at N = 400 simulates states of 1e19),
    and a scale taken from it makes the scaled feasibility tolerance meaningless in the
    original units."""
    lower, upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    with np.errstate(invalid="ignore"):
        rng = upper - lower
    apart = np.isfinite(rng) & (rng > 0)
    widest = np.max(np.where(apart, rng, 0.0), axis=0)
    finite = np.where(np.isfinite(lower), np.abs(lower), 0.0), np.where(np.isfinite(upper), np.abs(upper), 0.0)
    known = np.maximum.reduce([np.ones(lower.shape[1]), np.abs(np.asarray(reference, dtype=float)),
                               finite[0].max(axis=0), finite[1].max(axis=0)])
    seen = np.max(np.abs(trajectory), axis=0) if np.size(trajectory) else known
    seen = np.where(np.isfinite(seen), seen, np.inf)
    size = np.clip(seen, known, TRAJECTORY_TRUST * known)
    fallback = np.where(widest > 0, widest, size)
    d = np.where(apart, rng, fallback[None, :])
    s = np.where(np.isfinite(lower) & np.isfinite(upper), lower, 0.0)
    return d, s


def _row_norms(*blocks):
    """Euclidean norms of the rows of the concatenated blocks (each (N, rows, cols))."""
    return np.sqrt(sum(np.einsum("kij,kij->ki", b, b) for b in blocks))


def state_scale(method, A, B, d_bound, du):
    """The state scale dx (N+1, n), which is also the dynamics rows' scale (K_f = K_x in a DOCP:
    row i of stage k, x^{k+1}_i - f^k_i, is scaled by 1 / dx^{k+1}_i).

    iso: eq. (4) (d_bound). jrn: K_f of eq. (6), 1 / |grad F_i| of the row [A^k_i, B^k_i, -e_i];
    pjrn: K_f of eq. (7), the same row projected by the bound scales,
    [A^k_i diag(d^k), B^k_i diag(du^k), -d^{k+1}_i]. x^0 (fixed) keeps its bound scale."""
    if method == "iso":
        return d_bound.copy()
    out = d_bound.copy()
    if method == "jrn":
        out[1:] = np.sqrt(_row_norms(A, B) ** 2 + 1.0)
    elif method == "pjrn":
        out[1:] = np.sqrt(_row_norms(A * d_bound[:-1, None, :], B * du[:, None, :]) ** 2 + d_bound[1:] ** 2)
    else:  # pragma: no cover - guarded by PRESETS
        raise ValueError(method)
    return out


def _safe_reciprocal(norms):
    """1/norm, and 1 for a row without gradient (norm 0: nothing to normalise)."""
    tiny = 1e-300
    return np.where(norms > tiny, 1.0 / np.maximum(norms, tiny), 1.0)


def constraint_rows(method, Cx, Cu, dx, du):
    """Row factors w of the constraints (K, r), per stage: eq. (6) (jrn: 1/|grad G_i|), eq. (7)
    (pjrn: 1/|grad G_i K_x^{-1}|, in the scaled variables; dx (K, n), du (K, m)) or 1 (none)."""
    if method == "none":
        return np.ones(Cx.shape[:2])
    if method == "jrn":
        return _safe_reciprocal(_row_norms(Cx, Cu))
    return _safe_reciprocal(_row_norms(Cx * dx[:, None, :], Cu * du[:, None, :]))


def _positive_components(problem, which, size):
    spec = getattr(problem, POSITIVE_ATTRIBUTE, None) or {}
    idx = np.asarray(spec.get(which, ()), dtype=int).ravel()
    if np.any((idx < 0) | (idx >= size)):
        raise ProblemDefinitionError(f"{POSITIVE_ATTRIBUTE}[{which!r}] holds indices outside 0..{size - 1}: "
                                     f"{idx.tolist()}", array=POSITIVE_ATTRIBUTE)
    mask = np.zeros(size, dtype=bool)
    mask[idx] = True
    return mask


def inverse_power(g):
    """The exponent n of eq. (14), n = ceil(log(G + C)) with C = 1 (eq. (11)), over the values g
    of one component at the start point; at least 1."""
    top = float(np.max(g)) if np.size(g) else 0.0
    return float(max(1, math.ceil(math.log1p(max(top, 0.0)))))


def _kinds(mask, nonlinear, size):
    return tuple((nonlinear if mask[i] else "linear") for i in range(size))


def compute_scaling(problem, method="auto", X=None, U=None, *, positive=None) -> Scaling:
    """The scale factors of ``method`` (:data:`METHODS`) for ``problem`` at the start point
    (X, U) (default: the problem's initial guess and its simulated states) and its bounds.

    ``positive`` overrides the preset's transform ("log", "ip" or None) of the components the
    problem declares intrinsically positive (:data:`POSITIVE_ATTRIBUTE`)."""
    check_method(method)
    p = problem
    X, U = start_point(p, X, U)
    if method == "none":
        return _identity(p)
    fmethod, gmethod, nonlinear = PRESETS[method]
    if positive is not None:
        if positive not in NONLINEAR:
            raise ConfigError(f"unknown transform {positive!r} of positive constraints; choose log or ip",
                              key="positive")
        nonlinear = positive
    d_bound, sx = bound_scale(p.x_lower, p.x_upper, p.x0, X)
    du, su = bound_scale(p.u_lower, p.u_upper, np.zeros(p.m), U)
    A, B = p.eval_dynamics_jacobians(X, U)
    dx = state_scale(fmethod, A, B, d_bound, du)
    notes = []
    if not np.all(np.isfinite(dx) & (dx > 0)):
        notes.append("a state scale was not finite and positive: replaced by 1")
        dx = np.where(np.isfinite(dx) & (dx > 0), dx, 1.0)
    Cx, Cu = p.eval_stage_constraint_jacobians(X, U)
    CN = p.eval_final_constraint_jacobian(X[-1])
    W = constraint_rows(gmethod, Cx, Cu, dx[:-1], du)
    WN = constraint_rows(gmethod, CN[None], np.zeros((1, p.rN, 0)), dx[-1:], np.zeros((1, 0)))[0]
    smask = _positive_components(p, "stage", p.r) if nonlinear else np.zeros(p.r, bool)
    fmask = _positive_components(p, "final", p.rN) if nonlinear else np.zeros(p.rN, bool)
    W[:, smask] = 1.0          # sec. 5: the nonlinear transforms act on G itself
    WN[fmask] = 1.0
    g = p.eval_stage_constraints(X, U)
    gN = p.eval_final_constraints(X[-1])
    spow = np.array([inverse_power(g[:, i]) for i in range(p.r)])
    fpow = np.array([inverse_power(gN[i:i + 1]) for i in range(p.rN)])
    c = _objective_factor(p, X, U, dx, du)
    return Scaling(method=method, dx=dx, sx=sx, du=du, su=su, objective=c, stage_rows=W, final_rows=WN,
                   stage_kind=_kinds(smask, nonlinear, p.r), final_kind=_kinds(fmask, nonlinear, p.rN),
                   stage_power=spow, final_power=fpow, notes=notes)


def start_point(problem, X=None, U=None):
    """(X, U) as given, or the start point every solver uses without a guess: the problem's
    initial controls and its ``initial_state_guess`` of them, else the states they simulate."""
    if U is None:
        U = problem.initial_guess()
    if X is None:
        X = problem.initial_state_guess(np.asarray(U, dtype=float))
    if X is None:
        X = problem.simulate(U)
    return np.asarray(X, dtype=float), np.asarray(U, dtype=float)


def _identity(p) -> Scaling:
    N, n, m = p.N, p.n, p.m
    return Scaling(method="none", dx=np.ones((N + 1, n)), sx=np.zeros((N + 1, n)), du=np.ones((N, m)),
                   su=np.zeros((N, m)),
                   objective=1.0, stage_rows=np.ones((p.N, p.r)), final_rows=np.ones(p.rN),
                   stage_kind=("linear",) * p.r, final_kind=("linear",) * p.rN,
                   stage_power=np.ones(p.r), final_power=np.ones(p.rN))


def _objective_factor(p, X, U, dx, du):
    """K_j of eq. (8): 1 / |grad J K_x^{-1}| (the objective's row of eq. (2) normalised in the
    scaled variables, x^0 excluded: it is fixed), within [OBJECTIVE_MIN, 1/OBJECTIVE_FLOOR]."""
    lx, lu = p.eval_stage_cost_gradients(X, U)
    gN = p.eval_final_cost_gradient(X[-1])
    norm2 = float(np.sum((lx[1:] * dx[1:-1]) ** 2) + np.sum((lu * du) ** 2) + np.sum((gN * dx[-1]) ** 2))
    return max(1.0 / max(math.sqrt(norm2), OBJECTIVE_FLOOR), OBJECTIVE_MIN)


# ============================================================================ nonlinear transforms
def transform(kind, t, power):
    """(phi(t), phi'(t), phi''(t)) of seed 004 sec. 5 with C = 1: log(1 + t) (eq. (9)) or
    (1 + t)^(1/n) - 1 (eq. (13)); the identity for "linear". Arrays broadcast; ``kind`` per
    component (a sequence, last axis)."""
    t = np.asarray(t, dtype=float)
    phi, d1, d2 = t.copy(), np.ones_like(t), np.zeros_like(t)
    kinds = np.asarray(kind)
    if kinds.size == 0 or np.all(kinds == "linear"):
        return phi, d1, d2
    one = 1.0 + t
    with np.errstate(invalid="ignore", divide="ignore"):
        log_ = kinds == "log"
        ip = kinds == "ip"
        if log_.any():
            phi = np.where(log_, np.log(one), phi)
            d1 = np.where(log_, 1.0 / one, d1)
            d2 = np.where(log_, -1.0 / one ** 2, d2)
        if ip.any():
            a = 1.0 / np.asarray(power, dtype=float)
            phi = np.where(ip, one ** a - 1.0, phi)
            d1 = np.where(ip, a * one ** (a - 1.0), d1)
            d2 = np.where(ip, a * (a - 1.0) * one ** (a - 2.0), d2)
    return phi, d1, d2


# ============================================================================ the scaled problem
class ScaledDOCP(DOCP):
    """The DOCP ``problem`` in the scaled variables of ``scaling`` (module docstring). Every
    evaluation goes through the original problem's ``eval_*`` methods (analytic derivatives or
    its finite differences), transformed exactly; its counters are the original's."""

    vectorized = True

    def __init__(self, problem, scaling: Scaling):
        self.inner = problem
        self.scaling = s = scaling
        super().__init__(problem.n, problem.m, problem.N, (problem.x0 - s.sx[0]) / s.dx[0],
                         ((problem.x_lower - s.sx) / s.dx, (problem.x_upper - s.sx) / s.dx),
                         ((problem.u_lower - s.su) / s.du, (problem.u_upper - s.su) / s.du),
                         n_stage_constraints=problem.r, n_final_constraints=problem.rN,
                         stage_equalities=problem.stage_equality_mask,
                         final_equalities=problem.final_equality_mask)
        self.name = problem.name
        self.counters = problem.counters
        self._linear = all(k == "linear" for k in s.stage_kind + s.final_kind)

    # -------------------------------------------------------------- variables
    def to_original(self, X, U):
        """(X (N+1, n), U (N, m)) of the original problem from scaled trajectories (eq. (3))."""
        s = self.scaling
        return np.asarray(X) * s.dx + s.sx, np.asarray(U) * s.du + s.su

    def to_scaled(self, X, U):
        """Scaled trajectories from the original problem's (eq. (3) inverted)."""
        s = self.scaling
        return (np.asarray(X) - s.sx) / s.dx, (np.asarray(U) - s.su) / s.du

    def _stages(self, k, x, u):
        """(K, original x^k rows, original u^k rows) of a call with stages k."""
        s = self.scaling
        K = np.atleast_1d(np.asarray(k, dtype=int)).reshape(-1)
        return K, np.atleast_2d(x) * s.dx[K] + s.sx[K], np.atleast_2d(u) * s.du[K] + s.su[K]

    def _full(self, k, x, u):
        """Original trajectories (N+1, n), (N, m) holding the stage rows of a call at its stages
        K (the other stages repeat the first row: stage functions are separable), K, and whether
        K is every stage in order (then no row is evaluated twice)."""
        K, Xo, Uo = self._stages(k, x, u)
        every = len(K) == self.N and np.array_equal(K, self._K)
        if every:
            return np.vstack([Xo, Xo[-1:]]), Uo, K, True
        X = np.repeat(Xo[:1], self.N + 1, axis=0)
        U = np.repeat(Uo[:1], self.N, axis=0)
        X[K], U[K] = Xo, Uo
        return X, U, K, False

    @staticmethod
    def _rows(values, K, every):
        return values if every else values[K]

    def _final_x(self, x):
        return np.asarray(x, dtype=float) * self.scaling.dx[-1] + self.scaling.sx[-1]

    # -------------------------------------------------------------- values
    def dynamics(self, k, x, u):
        s = self.scaling
        K, X, U = self._stages(k, x, u)
        f = self.inner._stage_values("dynamics", K, X, U, (self.n,), "x_next")
        return (f - s.sx[K + 1]) / s.dx[K + 1]

    def simulate(self, U):
        U = self.check_array(U, (self.N, self.m), "simulate", "u")
        Xo = self.inner.simulate(U * self.scaling.du + self.scaling.su)
        return (Xo - self.scaling.sx) / self.scaling.dx

    def stage_cost(self, k, x, u):
        K, X, U = self._stages(k, x, u)
        return self.scaling.objective * self.inner._stage_values("stage_cost", K, X, U, (), "cost")

    def final_cost(self, x):
        return self.scaling.objective * self.inner.eval_final_cost(self._final_x(x))

    def _stage_g(self, K, Xo, Uo):
        """(w g, (phi, phi', phi'') of the transforms) of the stage constraints at original rows."""
        s = self.scaling
        t = s.stage_rows[K] * self.inner._stage_values("stage_constraints", K, Xo, Uo, (self.r,), "g")
        return t, transform(s.stage_kind, t, s.stage_power)

    def _final_g(self, xo):
        s = self.scaling
        t = s.final_rows * self.inner.eval_final_constraints(xo)
        return t, transform(s.final_kind, t, s.final_power)

    def _finite(self, values, function):
        if not np.all(np.isfinite(values)):
            raise NonFiniteEvaluationError("a nonlinearly scaled constraint left the domain g > -1 of its transform "
                                           f"(seed 004 eq. (9)/(13)); is it intrinsically positive ({POSITIVE_ATTRIBUTE})?",
                                           function=function, array="g")
        return values

    def stage_constraints(self, k, x, u):
        if self.r == 0:
            return np.zeros((np.size(k), 0))
        _, (phi, _, _) = self._stage_g(*self._stages(k, x, u))
        return self._finite(phi, "stage_constraints")

    def final_constraints(self, x):
        if self.rN == 0:
            return np.zeros(0)
        _, (phi, _, _) = self._final_g(self._final_x(x))
        return self._finite(phi, "final_constraints")

    # -------------------------------------------------------------- first derivatives
    def dynamics_jacobian(self, k, x, u):
        s = self.scaling
        X, U, K, every = self._full(k, x, u)
        A, B = self.inner.eval_dynamics_jacobians(X, U)
        A, B = self._rows(A, K, every), self._rows(B, K, every)
        out = 1.0 / s.dx[K + 1][:, :, None]
        return A * out * s.dx[K][:, None, :], B * out * s.du[K][:, None, :]

    def stage_cost_gradient(self, k, x, u):
        s = self.scaling
        X, U, K, every = self._full(k, x, u)
        lx, lu = self.inner.eval_stage_cost_gradients(X, U)
        return (s.objective * self._rows(lx, K, every) * s.dx[K],
                s.objective * self._rows(lu, K, every) * s.du[K])

    def final_cost_gradient(self, x):
        s = self.scaling
        return s.objective * self.inner.eval_final_cost_gradient(self._final_x(x)) * s.dx[-1]

    def _stage_g_jacobians(self, k, x, u):
        """Original Jacobians (Cx, Cu) at the call's stages K, the row factors w phi'(w g) and
        w^2 phi''(w g) there, K and the original trajectories."""
        s = self.scaling
        X, U, K, every = self._full(k, x, u)
        Cx, Cu = self.inner.eval_stage_constraint_jacobians(X, U)
        Cx, Cu = self._rows(Cx, K, every), self._rows(Cu, K, every)
        w = s.stage_rows[K]
        if self._linear:
            return Cx, Cu, w, None, K, X, U
        _, (_, d1, d2) = self._stage_g(K, X[K], U[K])
        return Cx, Cu, self._finite(w * d1, "stage_constraints_jacobian"), d2 * w ** 2, K, X, U

    def stage_constraints_jacobian(self, k, x, u):
        s = self.scaling
        if self.r == 0:
            K = np.size(k)
            return np.zeros((K, 0, self.n)), np.zeros((K, 0, self.m))
        Cx, Cu, rho, _, K, _, _ = self._stage_g_jacobians(k, x, u)
        return rho[:, :, None] * Cx * s.dx[K][:, None, :], rho[:, :, None] * Cu * s.du[K][:, None, :]

    def final_constraints_jacobian(self, x):
        s = self.scaling
        if self.rN == 0:
            return np.zeros((0, self.n))
        xo = self._final_x(x)
        C = self.inner.eval_final_constraint_jacobian(xo)
        _, (_, d1, _) = self._final_g(xo)
        return self._finite(s.final_rows * d1, "final_constraints_jacobian")[:, None] * C * s.dx[-1][None, :]

    # -------------------------------------------------------------- second derivatives
    def stage_hessian(self, k, x, u, sigma, p, lam):
        """Blocks of sigma c f_0 + (p/dx^{k+1}).f + sum_i lam_i phi_i(w_i g_i) in the scaled
        variables: the original Hessian with the multipliers (sigma c, p/dx^{k+1}, lam w phi')
        plus lam w^2 phi'' grad g grad g^T, congruence-transformed by diag(dx^k, du^k)."""
        s = self.scaling
        if self.r:
            Cx, Cu, rho, curv, K, X, U = self._stage_g_jacobians(k, x, u)
        else:
            X, U, K, _ = self._full(k, x, u)
            rho = curv = None
        every = len(K) == self.N and np.array_equal(K, self._K)
        L = np.atleast_2d(lam)
        Pf, Lf = np.zeros((self.N, self.n)), np.zeros((self.N, self.r))
        Pf[K] = np.atleast_2d(p) / s.dx[K + 1]
        if self.r:
            Lf[K] = L * rho
        Hxx, Hxu, Huu = (self._rows(h, K, every) for h in
                         self.inner.eval_stage_hessians(X, U, float(sigma) * s.objective, Pf, Lf))
        if curv is not None:
            c = L * curv
            Hxx = Hxx + np.einsum("ki,kia,kib->kab", c, Cx, Cx)
            Hxu = Hxu + np.einsum("ki,kia,kib->kab", c, Cx, Cu)
            Huu = Huu + np.einsum("ki,kia,kib->kab", c, Cu, Cu)
        dx, du = s.dx[K], s.du[K]
        return (Hxx * dx[:, :, None] * dx[:, None, :], Hxu * dx[:, :, None] * du[:, None, :],
                Huu * du[:, :, None] * du[:, None, :])

    def final_hessian(self, x, sigma, lam):
        s = self.scaling
        xo = self._final_x(x)
        lam = np.asarray(lam, dtype=float).reshape(-1)
        if self.rN:
            _, (_, d1, d2) = self._final_g(xo)
            rho, curv = s.final_rows * d1, s.final_rows ** 2 * d2
        else:
            rho = curv = np.zeros(0)
        H = self.inner.eval_final_hessian(xo, float(sigma) * s.objective, lam * rho)
        if self.rN and np.any(curv != 0):
            C = self.inner.eval_final_constraint_jacobian(xo)
            H = H + np.einsum("i,ia,ib->ab", lam * curv, C, C)
        d = s.dx[-1]
        return H * d[:, None] * d[None, :]

    # -------------------------------------------------------------- guesses
    def initial_guess(self):
        return (self.inner.initial_guess() - self.scaling.su) / self.scaling.du

    def initial_state_guess(self, U):
        X = self.inner.initial_state_guess(U * self.scaling.du + self.scaling.su)
        return None if X is None else (np.asarray(X, dtype=float) - self.scaling.sx) / self.scaling.dx


def scale_problem(problem, method="auto", X=None, U=None, *, positive=None) -> ScaledDOCP:
    """The scaled DOCP of ``method`` at the start point (X, U) (:func:`compute_scaling`)."""
    return ScaledDOCP(problem, compute_scaling(problem, method, X, U, positive=positive))


# ============================================================================ back to the original
def constraint_row_factors(scaled: ScaledDOCP, X, U):
    """d g~ / d g at the original point (X, U): w phi'(w g) per stage and component (N, r) and
    for the final constraints (rN,) -- the factors between the two problems' multipliers."""
    s = scaled.scaling
    p = scaled.inner
    if p.r:
        t = s.stage_rows * p.eval_stage_constraints(X, U)
        rho = s.stage_rows * transform(s.stage_kind, t, s.stage_power)[1]
    else:
        rho = np.zeros((p.N, 0))
    if p.rN:
        t = s.final_rows * p.eval_final_constraints(X[-1])
        rhoN = s.final_rows * transform(s.final_kind, t, s.final_power)[1]
    else:
        rhoN = np.zeros(0)
    return rho, rhoN


def unscale_multipliers(scaled: ScaledDOCP, multipliers: dict, X, U) -> dict:
    """The original problem's multipliers from the scaled problem's, at the original point.

    The scaled Lagrangian c J + lam~.c~(y) - z~.(y~ - lb~) ... is stationary in y~ = D^{-1}(y - s)
    exactly when the original one is stationary with lam = lam~ (d c~/d c) / c and z = z~ / (c D):
    dynamics rows d c~/d c = 1/dx^{k+1} (the next state's component), constraint rows w phi'(w g).
    Keys the map does not know are kept as the solver gave them (scaled units)."""
    s = scaled.scaling
    c = s.objective
    out = dict(multipliers)
    rho, rhoN = constraint_row_factors(scaled, X, U)
    factors = {"dynamics": 1.0 / (c * s.dx[1:]), "stage_constraints": rho / c, "final_constraints": rhoN / c,
               "bound_lower_x": 1.0 / (c * s.dx), "bound_upper_x": 1.0 / (c * s.dx),
               "bound_lower_u": 1.0 / (c * s.du), "bound_upper_u": 1.0 / (c * s.du)}
    for key, factor in factors.items():
        if key in out and out[key] is not None:
            out[key] = np.asarray(out[key], dtype=float) * factor
    return out


# ============================================================================ condition numbers
#: problems with at most this many Jacobian entries (rows x free variables) get an exact (dense
#: SVD) condition number; larger ones an estimate from the extreme eigenvalues of J J^T
DENSE_ENTRIES = 2_000_000


@dataclasses.dataclass
class ConditionRatio:
    """Seed 004 eq. (16): cond(Jac(X)) / cond(Jac~(X~)), Jac = [grad J; grad F; grad G] (eq. 2)."""

    original: float
    scaled: float
    kind: str                  # "dense SVD" or "estimate (eigsh of J J^T)"

    @property
    def ratio(self) -> float:
        return self.original / self.scaled if self.scaled > 0 else float("nan")

    def to_dict(self) -> dict:
        return {"cond_original": self.original, "cond_scaled": self.scaled, "ratio": self.ratio, "kind": self.kind}


def nlp_jacobian(problem, X, U):
    """The sparse matrix of eq. (2) at (X, U): the objective gradient over the rows of the
    constraint Jacobian of the NLP view (sec. 4.1 of paper 001), without the columns of x^0
    (fixed by the initial condition)."""
    import scipy.sparse as sp   # noqa: PLC0415

    from .nlp import StructuredNLP   # noqa: PLC0415

    nlp = StructuredNLP(problem)
    y = nlp.pack(X, U)
    J = sp.vstack([sp.csr_matrix(nlp.gradient(y)[None, :]), nlp.jacobian_matrix(y)]).tocsc()
    return J[:, problem.n:]


def condition_number(J, dense_entries=DENSE_ENTRIES):
    """(sigma_max / sigma_min, kind) of the sparse matrix J: its min(rows, cols) singular values
    by dense SVD when small; otherwise the extreme eigenvalues of the smaller Gram matrix J J^T
    or J^T J (Lanczos; the smallest by shift-invert at 0), an estimate exact in exact arithmetic
    but limited to conditions of about 1e8 (the Gram matrix squares them)."""
    rows, cols = J.shape
    if rows * cols <= dense_entries:
        sv = np.linalg.svd(J.toarray(), compute_uv=False)
        return (float(sv[0] / sv[-1]) if sv[-1] > 0 else math.inf), "dense SVD"
    import scipy.sparse.linalg as spla   # noqa: PLC0415

    G = (J @ J.T if rows <= cols else J.T @ J).tocsc()
    big = spla.eigsh(G, k=1, which="LA", return_eigenvectors=False)[0]
    try:
        small = spla.eigsh(G, k=1, sigma=0.0, which="LM", return_eigenvectors=False)[0]
    except (RuntimeError, ArithmeticError):   # singular Gram matrix
        return math.inf, "estimate (eigsh of the Gram matrix: singular)"
    small = abs(small)
    return (math.sqrt(big / small) if small > 0 else math.inf), "estimate (eigsh of the Gram matrix)"


def condition_ratio(problem, scaled: ScaledDOCP | None = None, X=None, U=None, *, method="auto",
                    dense_entries=DENSE_ENTRIES) -> ConditionRatio:
    """Seed 004 eq. (16) at the start point (X, U) of the original problem (default: its initial
    guess, simulated): cond of eq. (2) for ``problem`` over cond for ``scaled`` (default: the
    problem scaled by ``method`` at that point) at the scaled point. Higher is better."""
    X, U = start_point(problem, X, U)
    if scaled is None:
        scaled = scale_problem(problem, method, X, U)
    Xs, Us = scaled.to_scaled(X, U)
    c0, kind = condition_number(nlp_jacobian(problem, X, U), dense_entries)
    c1, _ = condition_number(nlp_jacobian(scaled, Xs, Us), dense_entries)
    return ConditionRatio(c0, c1, kind)
