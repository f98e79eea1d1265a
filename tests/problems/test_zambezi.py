"""Tests of the Zambezi benchmark (paper 001 sec. 5, eqs. (40)-(47), Table 1).

The central test compares the DOCP with an independent second transcription: a small test-only
evaluator of the SIF subset used by the CUTEr ZAMB2 files, run over the SIF's own variable vector
(V(0..N), Q1, Q3, Q4, F1..F4 (0..N-1), F2-1, F2-2) straight from the SIF groups, elements,
constants and element/group function definitions. It shares no code with
``olado/problems/zambezi.py`` or ``tools/extract_zambezi.py``. The SIF files are not in the
repository; the tests that need them skip when ``../shared/data/cuter`` is absent.
"""

from __future__ import annotations

import os
import re

import numpy as np
import pytest

from olado.errors import ProblemDefinitionError
from olado.problems.zambezi import (FAMILIES, PROBLEMS, Zambezi, load_data, plot_zambezi,
                                    table1_counts, zambezi_problem)
from fixtures import REPO

ROOT = str(REPO)
SIF_DIR = os.path.join(ROOT, "..", "shared", "data", "cuter")
HAVE_SIF = os.path.isfile(os.path.join(SIF_DIR, "ZAMB2-10.SIF"))
needs_sif = pytest.mark.skipif(not HAVE_SIF, reason=f"CUTEr ZAMB2 SIF files not found in {SIF_DIR}")

# family -> (SIF file, parameter overrides beyond NY)
SIF_OF = {
    "zambezi": ("ZAMB2.SIF", {}),
    "zambezi8": ("ZAMB2-8.SIF", {}),
    "zambezi9": ("ZAMB2-9.SIF", {}),
    "zambezi10": ("ZAMB2-10.SIF", {}),
    "zambezi11": ("ZAMB2-11.SIF", {}),
    "zambezi12": ("ZAMB2-10.SIF", {"PSI": 0.0, "YEAR": 1945}),   # paper 001 sec. 5
}


# ============================================================================ SIF evaluator
class SIFModel:
    """Minimal interpreter of the SIF subset of the ZAMB2 files (test-only).

    Handles integer/real parameter statements (IE IA IM I+ I- I/ RE R* RD RM RA), DO/DI/OD loops,
    the VARIABLES, GROUPS (incl. 'SCALE'), CONSTANTS, BOUNDS, START POINT, ELEMENT TYPE, ELEMENT
    USES, GROUP TYPE and GROUP USES sections and the element/group function sections (the
    ``F`` and ``A`` expressions are evaluated as Python expressions). SIF names of indexed
    quantities are the base name followed by the index values joined by commas, e.g. V1(k+1)
    with k = 3 is ``V14`` and F2(k-2) with k = 0 is ``F2-2``. An objective group with scale s
    contributes g/s (SIF: groups are divided by their scale factors).
    """

    def __init__(self, path, overrides=None):
        self.overrides = dict(overrides or {})
        self.ip, self.rp = {}, {}
        self.vars, self.var_index = [], {}
        self.groups = {}        # name -> dict(kind, linear{var: coef}, const, scale, type, elements[(el, w)])
        self.group_order = []
        self.lower, self.upper, self.start = {}, {}, {}
        self.default_free = False
        self.etypes, self.elements, self.gtypes = {}, {}, {}
        self.efun, self.gfun = {}, {}
        with open(path) as fh:
            lines = fh.read().splitlines()
        data, funcs = [], []
        target = data
        for line in lines:
            if line.startswith("ENDATA"):
                target = funcs
                continue
            target.append(line)
        self._run_data(data)
        self._read_functions(funcs)

    # ------------------------------------------------------------------ data part
    def _resolve_int(self, tok):
        if tok in self.ip:
            return self.ip[tok]
        return int(tok)

    def _real(self, tok):
        if tok in self.rp:
            return self.rp[tok]
        return float(tok)

    def _name(self, tok):
        m = re.fullmatch(r"([^()]+)\(([^()]*)\)", tok)
        if not m:
            return tok
        idx = [str(self._resolve_int(t.strip())) for t in m.group(2).split(",")]
        return m.group(1) + ",".join(idx)

    def _run_data(self, lines):
        stmts, section = [], None
        for line in lines:
            if not line.strip() or line.lstrip().startswith("*"):
                continue
            if not line.startswith(" "):
                section = line.split("  ")[0].strip()
                stmts.append(("SECTION", section))
                continue
            stmts.append(tuple(line.split("$")[0].split()))
        self.section = None
        self._execute(stmts, 0, len(stmts))

    def _execute(self, stmts, i, end):
        while i < end:
            s = stmts[i]
            if s[0] == "SECTION":
                self.section = s[1]
                i += 1
                continue
            if s[0] == "DO":
                depth, j = 1, i + 1
                while depth:
                    if stmts[j][0] == "DO":
                        depth += 1
                    elif stmts[j][0] == "OD":
                        depth -= 1
                    j += 1
                body_end = j - 1          # index of the matching OD
                var, lo, hi = s[1], self._resolve_int(s[2]), self._resolve_int(s[3])
                body = i + 1
                step = 1
                if stmts[body][0] == "DI":
                    step = self._resolve_int(stmts[body][2])
                    body += 1
                v = lo
                while v <= hi:
                    self.ip[var] = v
                    self._execute(stmts, body, body_end)
                    v += step
                i = j
                continue
            self._statement(s)
            i += 1

    def _statement(self, s):
        code = s[0]
        # parameters (any section)
        if code in ("IE", "RE"):
            name = self._name(s[1])
            val = self.overrides.get(name, float(s[2]) if code == "RE" else int(s[2]))
            (self.ip if code == "IE" else self.rp)[name] = val
            return
        if code in ("IA", "IM"):
            a = self._resolve_int(s[2])
            self.ip[s[1]] = a + int(s[3]) if code == "IA" else a * int(s[3])
            return
        if code in ("I+", "I-", "I/", "I*"):
            a, b = self._resolve_int(s[2]), self._resolve_int(s[3])
            ops = {"I+": lambda: a + b, "I-": lambda: a - b, "I/": lambda: a // b, "I*": lambda: a * b}
            self.ip[s[1]] = ops[code]()
            return
        if code in ("RA", "RM", "RD"):
            a, c = self._real(s[2]), float(s[3])
            if code == "RA":
                self.rp[s[1]] = a + c
            elif code == "RM":
                self.rp[s[1]] = a * c
            else:   # RD: A = value / B
                self.rp[s[1]] = np.inf if a == 0 else c / a
            return
        if code in ("R*", "R+", "R-", "R/"):
            a, b = self._real(s[2]), self._real(s[3])
            ops = {"R*": lambda: a * b, "R+": lambda: a + b, "R-": lambda: a - b, "R/": lambda: a / b}
            self.rp[s[1]] = ops[code]()
            return
        sec = self.section
        if sec == "VARIABLES" and code == "X":
            name = self._name(s[1])
            self.var_index[name] = len(self.vars)
            self.vars.append(name)
        elif sec == "GROUPS":
            name = self._name(s[1])
            if name not in self.groups:
                self.groups[name] = dict(kind=code[1], linear={}, const=0.0, scale=1.0,
                                         type=None, elements=[])
                self.group_order.append(name)
            g = self.groups[name]
            rest = list(s[2:])
            while rest:
                if rest[0] == "'SCALE'":
                    g["scale"] = self._real(rest[1]) if code[0] == "Z" else float(rest[1])
                else:
                    var = self._name(rest[0])
                    coef = self._real(rest[1]) if code[0] == "Z" else float(rest[1])
                    g["linear"][var] = g["linear"].get(var, 0.0) + coef
                rest = rest[2:]
        elif sec == "CONSTANTS":
            for j in range(2, len(s), 2):
                g = self._name(s[j])
                self.groups[g]["const"] = self._real(self._name(s[j + 1])) if code == "Z" else float(s[j + 1])
        elif sec == "BOUNDS":
            if code == "FR" and s[2] == "'DEFAULT'":
                self.default_free = True
                return
            var = self._name(s[2])
            val = self._real(self._name(s[3])) if code[0] == "Z" else (float(s[3]) if len(s) > 3 else None)
            kind = code[1]
            if kind in ("L", "X"):
                self.lower[var] = val
            if kind in ("U", "X"):
                self.upper[var] = val
            if kind == "R":
                self.lower[var], self.upper[var] = -np.inf, np.inf
        elif sec == "START POINT":
            var = self._name(s[2])
            self.start[var] = self._real(self._name(s[3])) if code == "ZV" else float(s[3])
        elif sec == "ELEMENT TYPE":
            t = self.etypes.setdefault(s[1], {"vars": [], "params": []})
            (t["vars"] if code == "EV" else t["params"]).extend(s[2:])
        elif sec == "ELEMENT USES":
            name = self._name(s[1])
            e = self.elements.setdefault(name, {"type": None, "vars": {}, "params": {}})
            if code == "XT":
                e["type"] = s[2]
            elif code in ("ZV", "XV"):
                e["vars"][s[2]] = self._name(s[3])
            elif code in ("XP", "ZP"):
                for j in range(2, len(s), 2):
                    e["params"][s[j]] = self._real(s[j + 1]) if code == "ZP" else float(s[j + 1])
        elif sec == "GROUP TYPE":
            self.gtypes[s[1]] = s[2]
        elif sec == "GROUP USES":
            g = self.groups[self._name(s[1])]
            if code == "XT":
                g["type"] = s[2]
            elif code in ("XE", "ZE"):
                el = self._name(s[2])
                w = 1.0
                if len(s) > 3:
                    w = self._real(self._name(s[3])) if code == "ZE" else float(s[3])
                g["elements"].append((el, w))

    # ------------------------------------------------------------------ function part
    def _read_functions(self, lines):
        kind, current, target = None, None, None
        for line in lines:
            if not line.strip() or line.lstrip().startswith("*"):
                continue
            head = line.split()[0]
            if not line.startswith(" "):
                if head in ("ELEMENTS", "GROUPS"):
                    kind = head
                continue
            code = line[1:3].strip()
            if code == "T":
                current = line[4:14].strip()
                target = self.efun if kind == "ELEMENTS" else self.gfun
                target[current] = {"temps": [], "F": None}
            elif code == "A" and current is not None:
                target[current]["temps"].append((line[4:14].strip(), compile(line[24:].strip(), "sif", "eval")))
            elif code == "F" and current is not None:
                target[current]["F"] = compile(line[24:].strip(), "sif", "eval")

    def _element_value(self, name, x):
        e = self.elements[name]
        fn = self.efun[e["type"]]
        env = dict(e["params"])
        for ev, var in e["vars"].items():
            env[ev] = x[self.var_index[var]]
        for t, expr in fn["temps"]:
            env[t] = eval(expr, {}, env)
        return eval(fn["F"], {}, env)

    def _group_argument(self, g, x):
        val = sum(c * x[self.var_index[v]] for v, c in g["linear"].items())
        val += sum(w * self._element_value(el, x) for el, w in g["elements"])
        return val - g["const"]

    def objective(self, x):
        total = 0.0
        for name in self.group_order:
            g = self.groups[name]
            if g["kind"] != "N":
                continue
            a = self._group_argument(g, x)
            if g["type"] is not None:
                gt = self.gfun[g["type"]]
                a = eval(gt["F"], {}, {self.gtypes[g["type"]]: a})
            total += a / g["scale"]
        return total

    def equalities(self, x):
        return {nm: self._group_argument(self.groups[nm], x)
                for nm in self.group_order if self.groups[nm]["kind"] == "E"}

    def bounds(self, var):
        lo = self.lower.get(var, -np.inf if self.default_free else 0.0)
        hi = self.upper.get(var, np.inf)
        return lo, hi


_SIF_CACHE = {}


def sif_model(family, N):
    key = (family, N)
    if key not in _SIF_CACHE:
        fname, over = SIF_OF[family]
        over = dict(over, NY=N // 12)
        _SIF_CACHE[key] = SIFModel(os.path.join(SIF_DIR, fname), over)
    return _SIF_CACHE[key]


def to_sif_vector(model, X, U, x0):
    """DOCP (X, U) -> the SIF variable vector."""
    val = {}
    N = U.shape[0]
    for k in range(N + 1):
        for i in range(4):
            val[f"V{i + 1}{k}"] = X[k, i]
    for k in range(N):
        for j, nm in enumerate(("Q1", "Q3", "Q4", "F1", "F2", "F3", "F4")):
            val[f"{nm}{k}"] = U[k, j]
    val["F2-1"], val["F2-2"] = x0[4], x0[5]
    assert set(val) == set(model.vars), "variable sets of the SIF and the DOCP differ"
    return np.array([val[v] for v in model.vars])


def random_controls(p, rng):
    lo = np.where(np.isfinite(p.u_lower), p.u_lower, -1.0)
    hi = np.where(np.isfinite(p.u_upper), p.u_upper, 1.0)
    return lo + (hi - lo) * rng.random((p.N, p.m))


# ============================================================================ (1) SIF vs DOCP
@needs_sif
@pytest.mark.parametrize("family", FAMILIES)
def test_docp_matches_sif_transcription(family):
    N = 24
    p = zambezi_problem(family, N=N)
    model = sif_model(family, N)
    assert len(model.vars) == 11 * N + 6          # SIF: "number of variables is 11*(12*NY)+6"
    rng = np.random.default_rng(7)
    for trial in range(3):
        U = random_controls(p, rng)
        # objective at a dynamically consistent trajectory (the DOCP eliminates V(k+1) from the
        # energy term through the balance equation, paper 001 sec. 5)
        X = p.simulate(U)
        y = to_sif_vector(model, X, U, p.x0)
        J_sif = model.objective(y)
        J_docp = p.objective(X, U)
        assert J_docp == pytest.approx(J_sif, rel=1e-12, abs=1e-12 * max(1.0, abs(J_sif)))
        # balance equations at random volumes (delay states made consistent with U, as they are
        # SIF variables F2(k-1), F2(k-2) there and not independent unknowns)
        Xr = X.copy()
        Xr[:, :4] = np.array([lo + (hi - lo) * rng.random(N + 1) for lo, hi in
                              zip(p.x_lower[0, :4], p.x_upper[0, :4])]).T
        h = p.eval_dynamics(Xr, U) - Xr[1:]          # NLP view: h = f(x, u) - x_next
        assert np.allclose(h[:, 4:], 0.0)
        eq = model.equalities(to_sif_vector(model, Xr, U, p.x0))
        assert len(eq) == 4 * N
        sif_h = np.array([[eq[f"SE{i}{k}"] for i in (1, 2, 3, 4)] for k in range(N)])
        # SIF group SEi(k) = V_i(k+1) - (right-hand side of eq. (40)) = -h
        np.testing.assert_allclose(-h[:, :4], sif_h, rtol=1e-12, atol=1e-12)


@needs_sif
@pytest.mark.parametrize("family", FAMILIES)
def test_bounds_x0_and_start_match_sif(family):
    N = 24
    p = zambezi_problem(family, N=N, start="sif")
    model = sif_model(family, N)
    for k in range(1, N + 1):      # the SIF bounds V(1..N); V(0) is fixed
        for i in range(4):
            assert model.bounds(f"V{i + 1}{k}") == (p.x_lower[k, i], p.x_upper[k, i])
    for i in range(4):
        assert model.bounds(f"V{i + 1}0") == (p.x0[i], p.x0[i])
        assert p.x_lower[0, i] <= p.x0[i] <= p.x_upper[0, i]
    assert model.bounds("F2-1") == (p.x0[4], p.x0[4])
    assert model.bounds("F2-2") == (p.x0[5], p.x0[5])
    U0 = p.initial_guess()
    for k in range(N):
        for j, nm in enumerate(("Q1", "Q3", "Q4", "F1", "F2", "F3", "F4")):
            assert model.bounds(f"{nm}{k}") == (p.u_lower[k, j], p.u_upper[k, j])
            assert model.start[f"{nm}{k}"] == U0[k, j]


# ============================================================================ (2) derivatives
def _stage_lagrangian_gradient(p, X, U, sigma, P):
    lx, lu = p.eval_stage_cost_gradients(X, U, source="analytic")
    A, B = p.eval_dynamics_jacobians(X, U, source="analytic")
    gx = sigma * lx + np.einsum("ki,kij->kj", P, A)
    gu = sigma * lu + np.einsum("ki,kij->kj", P, B)
    return np.concatenate([gx, gu], axis=1)


@pytest.mark.parametrize("family", FAMILIES)
def test_first_derivatives_by_finite_differences(family):
    p = zambezi_problem(family, N=24)
    rng = np.random.default_rng(3)
    U = random_controls(p, rng)
    X = p.simulate(U) + 0.5 * rng.standard_normal((p.N + 1, p.n))
    n, m = p.n, p.m
    Z = np.concatenate([X[:-1], U], axis=1)
    A, B = p.eval_dynamics_jacobians(X, U, source="analytic")
    lx, lu = p.eval_stage_cost_gradients(X, U, source="analytic")
    Jf, Jl = np.concatenate([A, B], axis=2), np.concatenate([lx, lu], axis=1)
    h = 1e-6 * np.maximum(1.0, np.abs(Z))
    for j in range(n + m):
        Zp, Zm = Z.copy(), Z.copy()
        Zp[:, j] += h[:, j]
        Zm[:, j] -= h[:, j]
        XP, XM = np.vstack([Zp[:, :n], X[-1:]]), np.vstack([Zm[:, :n], X[-1:]])
        df = (p.eval_dynamics(XP, Zp[:, n:]) - p.eval_dynamics(XM, Zm[:, n:])) / (2 * h[:, j:j + 1])
        dl = (p.eval_stage_costs(XP, Zp[:, n:]) - p.eval_stage_costs(XM, Zm[:, n:])) / (2 * h[:, j])
        np.testing.assert_allclose(Jf[:, :, j], df, rtol=1e-7, atol=1e-8)
        np.testing.assert_allclose(Jl[:, j], dl, rtol=1e-6, atol=1e-11)
    xN = X[-1]
    g = p.eval_final_cost_gradient(xN, source="analytic")
    for j in range(n):
        e = np.zeros(n)
        e[j] = 1e-5 * max(1.0, abs(xN[j]))
        fd = (p.eval_final_cost(xN + e) - p.eval_final_cost(xN - e)) / (2 * e[j])
        assert g[j] == pytest.approx(fd, rel=1e-6, abs=1e-10)


@pytest.mark.parametrize("family", FAMILIES)
def test_second_derivatives_by_finite_differences(family):
    p = zambezi_problem(family, N=24)
    rng = np.random.default_rng(5)
    U = random_controls(p, rng)
    X = p.simulate(U) + 0.5 * rng.standard_normal((p.N + 1, p.n))
    P = rng.standard_normal((p.N, p.n))
    sigma = 1.7
    n, m = p.n, p.m
    hxx, hxu, huu = p.eval_stage_hessians(X, U, sigma, P, source="analytic")
    H = np.concatenate([np.concatenate([hxx, hxu], axis=2),
                        np.concatenate([np.transpose(hxu, (0, 2, 1)), huu], axis=2)], axis=1)
    np.testing.assert_allclose(H, np.transpose(H, (0, 2, 1)), atol=0)
    Z = np.concatenate([X[:-1], U], axis=1)
    h = 1e-5 * np.maximum(1.0, np.abs(Z))
    for j in range(n + m):
        Zp, Zm = Z.copy(), Z.copy()
        Zp[:, j] += h[:, j]
        Zm[:, j] -= h[:, j]
        gp = _stage_lagrangian_gradient(p, np.vstack([Zp[:, :n], X[-1:]]), Zp[:, n:], sigma, P)
        gm = _stage_lagrangian_gradient(p, np.vstack([Zm[:, :n], X[-1:]]), Zm[:, n:], sigma, P)
        fd = (gp - gm) / (2 * h[:, j:j + 1])
        np.testing.assert_allclose(H[:, :, j], fd, rtol=1e-6, atol=1e-10)
    xN = X[-1]
    HN = p.eval_final_hessian(xN, sigma, source="analytic")
    for j in range(n):
        e = np.zeros(n)
        e[j] = 1e-5 * max(1.0, abs(xN[j]))
        fd = sigma * (p.eval_final_cost_gradient(xN + e) - p.eval_final_cost_gradient(xN - e)) / (2 * e[j])
        np.testing.assert_allclose(HN[:, j], fd, rtol=1e-6, atol=1e-10)


def test_core_derivative_check_passes():
    from olado.problems import check_derivatives
    p = zambezi_problem("zambezi12", N=24)
    report = check_derivatives(p, noise=0.2, seed=2, rtol=1e-5, atol=1e-8, hessians=False)
    assert report.ok, str(report)


# ============================================================================ (3) Table 1
TABLE1 = {12: (162, 78, 272), 24: (318, 150, 536), 36: (474, 222, 800), 48: (630, 294, 1064),
          60: (786, 366, 1328), 72: (942, 438, 1592), 84: (1098, 510, 1856),
          96: (1254, 582, 2120), 108: (1410, 654, 2384), 120: (1566, 726, 2648),
          132: (1722, 798, 2912), 144: (1878, 870, 3176), 156: (2034, 942, 3440),
          168: (2190, 1014, 3704), 180: (2346, 1086, 3968), 192: (2502, 1158, 4232),
          204: (2658, 1230, 4496), 216: (2814, 1302, 4760), 228: (2970, 1374, 5024),
          240: (3126, 1446, 5288), 252: (3282, 1518, 5552)}


@pytest.mark.parametrize("N", sorted(TABLE1))
def test_table1_counts(N):
    p = zambezi_problem("zambezi12", N=N, extend=None)
    c = table1_counts(p)
    assert (c["variables"], c["equalities"], c["inequalities"]) == TABLE1[N]
    assert c["state_bounds"] == 8 * (N + 1) and c["control_bounds"] == 14 * N
    from olado.problems import StructuredNLP
    nc = StructuredNLP(p).counts()
    assert (nc["variables"], nc["equalities"], nc["inequalities"]) == TABLE1[N]


# ============================================================================ (4) bad N
@pytest.mark.parametrize("N", [0, -12, 13, 6, 24.0, True, "24"])
def test_bad_N_is_rejected(N):
    with pytest.raises(ProblemDefinitionError, match="multiple of 12"):
        zambezi_problem("zambezi12", N=N)


def test_N_beyond_record_needs_cyclic_extension():
    with pytest.raises(ProblemDefinitionError, match="N <= 252"):
        zambezi_problem("zambezi12", N=264, extend=None)
    with pytest.raises(ProblemDefinitionError, match="N <= 72"):
        zambezi_problem("zambezi9", N=84, extend=None)
    for fam, top in (("zambezi", 420), ("zambezi8", 216), ("zambezi9", 72), ("zambezi10", 72),
                     ("zambezi11", 432), ("zambezi12", 252)):
        assert zambezi_problem(fam, N=top, extend=None).N == top
    assert zambezi_problem("zambezi12", N=264).N == 264


def test_bad_family_start_year_extend():
    with pytest.raises(ProblemDefinitionError, match="zambezi12"):
        zambezi_problem("zambezi7")
    with pytest.raises(ProblemDefinitionError, match="start"):
        zambezi_problem(start="middle")
    with pytest.raises(ProblemDefinitionError, match="1930..1965"):
        zambezi_problem(year=1966)
    with pytest.raises(ProblemDefinitionError, match="extend"):
        zambezi_problem(extend="mirror")


# ============================================================================ (5) start points
@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("N", [12, 24, 72])
def test_balance_start_within_bounds_and_finite(family, N):
    p = zambezi_problem(family, N=N, start="balance")
    U = p.initial_guess()
    assert U.shape == (N, 7)
    assert np.all(U >= p.u_lower) and np.all(U <= p.u_upper)
    X = p.simulate(U)
    assert np.all(np.isfinite(X)) and np.isfinite(p.objective(X, U))
    # turbine flows and F2 are constant except where a monthly bound clips them (eq. (46))
    assert np.ptp(U[:, [0, 1, 2, 3, 5, 6]], axis=0).max() == 0.0


def test_balance_start_follows_eq_46_47():
    """Hand computation of eqs. (46)-(47) for reservoir 1 (no upstream reservoir)."""
    p = zambezi_problem("zambezi12", N=24)
    U = p.initial_guess()
    zbar = (p.inflow[:, 0].sum() - (p.V_ref[0] - p.x0[0])) / p.N
    qmin, qmax = p.u_lower[0, 0], p.u_upper[0, 0]
    assert U[0, 0] == pytest.approx(qmax if zbar > qmax else max(zbar, qmin))
    assert U[0, 3] == pytest.approx(max(zbar - qmax, 0.0))
    # reservoir 4 receives the releases of reservoirs 1 and 3 without delay
    zbar4 = (p.inflow[:, 3].sum() - (p.V_ref[3] - p.x0[3])) / p.N + U[0, 0] + U[0, 3] + U[0, 1] + U[0, 5]
    assert U[0, 2] == pytest.approx(np.clip(zbar4, p.u_lower[0, 2], p.u_upper[0, 2]))


def test_sif_start():
    p = zambezi_problem("zambezi10", N=24, start="sif")
    U = p.initial_guess()
    np.testing.assert_array_equal(U[:, 0], p.inflow[:, 0])
    np.testing.assert_array_equal(U[:, 4], p.inflow[:, 1])
    np.testing.assert_array_equal(U[:, 1], p.inflow[:, 1])
    np.testing.assert_array_equal(U[:, 2], p.inflow[:, 0])
    assert np.all(U[:, [3, 5, 6]] == 0.0)


def test_sif_start_states_are_the_sif_start_point():
    """The SIF START POINT fixes V(k) = V0 for every k; simulating its controls instead made the
    volumes diverge (inf at k = 44 for zambezi N = 288), so every solver failed to start."""
    from olado.solvers.base import Solver

    p = zambezi_problem("zambezi", N=300, start="sif", extend=None)
    X, U = Solver.initial_point(p, None)
    np.testing.assert_array_equal(X[:, :4], np.tile(p.x0[:4], (301, 1)))
    assert np.array_equal(X[0], p.x0)
    h = p.dynamics(np.arange(300), X[:-1], U)[:, 4:] - X[1:, 4:]       # delay states exact
    assert np.abs(h).max() == 0.0
    with pytest.raises(ProblemDefinitionError, match="non-finite"):
        p.simulate(U)                                                   # what the start used to be
    assert zambezi_problem("zambezi", N=24).initial_state_guess(U[:24]) is None   # balance: simulate
    import olado

    pytest.importorskip("cyipopt")
    ref = olado.solve(p, solver="ipopt")
    r = olado.solve(p, config="configs/sqp-ip.ini")
    assert ref.success and r.success, (ref.message, r.message)
    assert abs(r.objective - ref.objective) <= 1e-6 * abs(ref.objective)


# ============================================================================ (6) extension
def test_cyclic_extension_repeats_the_record():
    d = load_data()
    p = zambezi_problem("zambezi12", N=1200)
    assert p.N == 1200
    j0 = (1945 - 1930) * 12
    rec = np.asarray(d["record"]["IN1"])
    expected = rec[(j0 + np.arange(1200)) % 432]
    np.testing.assert_array_equal(p.inflow[:, 0], expected)
    np.testing.assert_array_equal(p.inflow[432:864], p.inflow[:432])   # period of 36 years
    # January 1966 continues with January 1930
    k1966 = (1966 - 1945) * 12
    assert p.inflow[k1966, 3] == d["record"]["IN4"][0]
    assert np.all(p.month == np.arange(1200) % 12)
    np.testing.assert_array_equal(p.u_lower[:12, 4], p.u_lower[1188:, 4])
    X = p.simulate(p.initial_guess())
    assert np.all(np.isfinite(X))


def test_large_horizon_is_vectorized():
    p = zambezi_problem("zambezi12", N=12000)
    U = p.initial_guess()
    X = np.tile(p.x0, (p.N + 1, 1))
    assert p.eval_dynamics(X, U).shape == (12000, 6)
    hxx, hxu, huu = p.eval_stage_hessians(X, U, 1.0, np.ones((p.N, 6)))
    assert hxx.shape == (12000, 6, 6) and np.all(np.isfinite(huu))
    assert p.counters["stage_hessian"] == 1


# ============================================================================ misc
def test_registry_and_problem_metadata():
    assert set(PROBLEMS) == set(FAMILIES)
    p = PROBLEMS["zambezi9"](N=12)
    assert isinstance(p, Zambezi) and p.name == "zambezi9" and p.start_year == 1960
    assert p.vectorized
    from olado.problems import get_problems
    assert set(FAMILIES) <= set(get_problems())
    z12 = zambezi_problem("zambezi12")
    assert z12.psi == 0.0 and z12.start_year == 1945
    z10 = zambezi_problem("zambezi10")
    assert z10.psi == pytest.approx(100.0 * 1e-5) and z10.alpha == pytest.approx(1.2285e-5)
    assert z10.phi[2] == pytest.approx(1e-10 * 20 * 1e-5)
    assert zambezi_problem("zambezi11", N=12, year=1950).inflow[0, 0] == load_data()["record"]["IN1"][240]


def test_plot_zambezi(tmp_path):
    p = zambezi_problem("zambezi12", N=24)
    U = p.initial_guess()
    X = p.simulate(U)
    out = tmp_path / "fig3.png"
    assert plot_zambezi((X, U), p, out) == str(out)
    assert out.stat().st_size > 10000
    assert [f.name for f in tmp_path.iterdir()] == ["fig3.png"]   # no temporary left behind


def test_fast_simulate_matches_the_generic_recursion():
    from olado.problems.docp import DOCP
    p = zambezi_problem("zambezi11", N=48)
    U = random_controls(p, np.random.default_rng(11))
    np.testing.assert_allclose(p.simulate(U), DOCP.simulate(p, U), rtol=1e-14, atol=1e-13)
