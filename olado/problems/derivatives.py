"""Comparison of derivative sources over the whole horizon (paper 001 sec. 2.1: "procedures to
compare the values of functions and their derivatives for two dynamic optimization problems, on
the whole control horizon").

``check_derivatives(problem)`` compares the problem's own derivatives (analytic where provided)
with finite differences of its functions; ``check_derivatives(problem, other)`` compares function
values and derivatives of two problems (e.g. a hand-written and a vectorized version). The report
names, for every quantity, the largest error, the stage and the entry where it occurs.
"""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass
class DerivativeCheck:
    """One compared quantity: the worst absolute and relative error and where it occurs."""

    name: str
    max_abs_error: float
    max_rel_error: float
    stage: int | None
    entry: tuple
    value: float
    reference: float
    ok: bool


@dataclasses.dataclass
class DerivativeReport:
    """All comparisons of :func:`check_derivatives`; ``ok`` when every one is within tolerance."""

    checks: list
    label_a: str
    label_b: str
    rtol: float
    atol: float

    @property
    def ok(self) -> bool:
        return all(c.ok for c in self.checks)

    @property
    def worst(self) -> DerivativeCheck:
        return max(self.checks, key=lambda c: c.max_rel_error)

    def __getitem__(self, name) -> DerivativeCheck:
        for c in self.checks:
            if c.name == name:
                return c
        raise KeyError(name)

    def __str__(self) -> str:
        lines = [f"derivative check: {self.label_a} vs {self.label_b} (rtol={self.rtol:g}, atol={self.atol:g})",
                 f"  {'quantity':<26}{'max abs err':>13}{'max rel err':>13}  {'stage':>6}  entry      {'value':>12} {'reference':>12}"]
        for c in self.checks:
            st = "-" if c.stage is None else str(c.stage)
            flag = "" if c.ok else "  <-- FAIL"
            lines.append(f"  {c.name:<26}{c.max_abs_error:13.3e}{c.max_rel_error:13.3e}  {st:>6}  {str(c.entry):<10} "
                         f"{c.value:12.5g} {c.reference:12.5g}{flag}")
        lines.append("  result: " + ("OK" if self.ok else f"FAILED (worst: {self.worst.name})"))
        return "\n".join(lines)


def _compare(name, a, b, rtol, atol, staged):
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    if a.size == 0:
        return DerivativeCheck(name, 0.0, 0.0, None, (), 0.0, 0.0, True)
    diff = np.abs(a - b)
    scale = np.maximum(np.abs(a), np.abs(b))
    rel = diff / np.maximum(scale, 1.0)
    idx = np.unravel_index(int(np.argmax(rel)), a.shape)
    ok = bool(np.all(diff <= atol + rtol * scale))
    stage = int(idx[0]) if staged else None
    entry = tuple(int(i) for i in (idx[1:] if staged else idx))
    return DerivativeCheck(name, float(diff.max()), float(rel.max()), stage, entry, float(a[idx]), float(b[idx]), ok)


def check_derivatives(problem, other=None, X=None, U=None, *, P=None, L=None, lN=None, sigma=1.0,
                      rtol=1e-5, atol=1e-8, hessians=True, seed=0, noise=0.0):
    """Compare two derivative sources over every stage.

    Without ``other``: the problem's derivatives (analytic where it provides them) against
    finite differences of its own functions. With ``other``: function values and derivatives of
    ``problem`` against those of ``other`` (same dimensions). The point is ``(X, U)``; by default
    the problem's initial guess (plus ``noise`` times a standard normal perturbation) simulated
    from x^0. Multipliers ``P`` (N, n), ``L`` (N, r), ``lN`` (rN,) for the Hessians default to
    standard normal draws. Returns a :class:`DerivativeReport`.
    """
    p = problem
    rng = np.random.default_rng(seed)
    if U is None:
        U = p.initial_guess() + noise * rng.standard_normal((p.N, p.m))
    if X is None:
        X = p.simulate(U)
    P = rng.standard_normal((p.N, p.n)) if P is None else P
    L = rng.standard_normal((p.N, p.r)) if L is None else L
    lN = rng.standard_normal(p.rN) if lN is None else lN
    checks = []

    if other is None:
        src_a, src_b, q = None, "fd", p
        label_a, label_b = f"{p.name} (own derivatives)", f"{p.name} (finite differences, {p.fd_method})"
    else:
        if (other.n, other.m, other.N, other.r, other.rN) != (p.n, p.m, p.N, p.r, p.rN):
            raise ValueError("the two problems have different dimensions")
        src_a = src_b = None
        q = other
        label_a, label_b = p.name, other.name
        checks.append(_compare("dynamics", p.eval_dynamics(X, U), q.eval_dynamics(X, U), rtol, atol, True))
        checks.append(_compare("stage_cost", p.eval_stage_costs(X, U)[:, None], q.eval_stage_costs(X, U)[:, None], rtol, atol, True))
        checks.append(_compare("final_cost", p.eval_final_cost(X[-1]), q.eval_final_cost(X[-1]), rtol, atol, False))
        if p.r:
            checks.append(_compare("stage_constraints", p.eval_stage_constraints(X, U), q.eval_stage_constraints(X, U), rtol, atol, True))
        if p.rN:
            checks.append(_compare("final_constraints", p.eval_final_constraints(X[-1]), q.eval_final_constraints(X[-1]), rtol, atol, False))

    A1, B1 = p.eval_dynamics_jacobians(X, U, source=src_a)
    A2, B2 = q.eval_dynamics_jacobians(X, U, source=src_b)
    checks += [_compare("dynamics_jacobian fx", A1, A2, rtol, atol, True), _compare("dynamics_jacobian fu", B1, B2, rtol, atol, True)]
    lx1, lu1 = p.eval_stage_cost_gradients(X, U, source=src_a)
    lx2, lu2 = q.eval_stage_cost_gradients(X, U, source=src_b)
    checks += [_compare("stage_cost_gradient lx", lx1, lx2, rtol, atol, True), _compare("stage_cost_gradient lu", lu1, lu2, rtol, atol, True)]
    checks.append(_compare("final_cost_gradient", p.eval_final_cost_gradient(X[-1], source=src_a),
                           q.eval_final_cost_gradient(X[-1], source=src_b), rtol, atol, False))
    if p.r:
        C1 = p.eval_stage_constraint_jacobians(X, U, source=src_a)
        C2 = q.eval_stage_constraint_jacobians(X, U, source=src_b)
        checks += [_compare("stage_constraints_jac gx", C1[0], C2[0], rtol, atol, True),
                   _compare("stage_constraints_jac gu", C1[1], C2[1], rtol, atol, True)]
    if p.rN:
        checks.append(_compare("final_constraints_jacobian", p.eval_final_constraint_jacobian(X[-1], source=src_a),
                               q.eval_final_constraint_jacobian(X[-1], source=src_b), rtol, atol, False))
    if hessians:
        h1 = p.eval_stage_hessians(X, U, sigma, P, L, source=src_a)
        h2 = q.eval_stage_hessians(X, U, sigma, P, L, source=src_b)
        # second differences are less accurate than first ones: loosen by the usual factor
        hr, ha = (max(rtol, 1e-4), max(atol, 1e-6)) if src_b == "fd" else (rtol, atol)
        for nm, a, b in zip(("stage_hessian hxx", "stage_hessian hxu", "stage_hessian huu"), h1, h2):
            checks.append(_compare(nm, a, b, hr, ha, True))
        checks.append(_compare("final_hessian", p.eval_final_hessian(X[-1], sigma, lN, source=src_a),
                               q.eval_final_hessian(X[-1], sigma, lN, source=src_b), hr, ha, False))
    return DerivativeReport(checks, label_a, label_b, rtol, atol)
