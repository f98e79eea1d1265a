"""The Zambezi reservoir system benchmark of paper 001 sec. 5 (eqs. (40)-(47), Fig. 3, Table 1).

Four reservoirs with hydropower stations on the Zambezi river (Arnold, Tatjewski and
Wolochowicz, JOTA 81(1994) 221-248), in the form of the CUTEr test problems ZAMB2*.SIF
(E. Arnold, 1996); the numbers live in ``data/zambezi.json`` (written by
``tools/extract_zambezi.py``). Monthly stages, k = 0..N-1, N a multiple of 12, the horizon
starting in January of the start year.

States (n = 6) and controls (m = 7, in the SIF's variable order)::

    x = (V1, V2, V3, V4, F2(k-1), F2(k-2))      volumes [km^3]; delayed spillage of reservoir 2
    u = (Q1, Q3, Q4, F1, F2, F3, F4)            turbine outflows Q_i, spillages F_i

Reservoir 2 has no power station: its only outflow is F2, which reaches reservoir 3 two months
later (the delay theta_2 = 2 of eq. (40), realised by the states x5, x6); reservoir 4 receives
Q1 + F1 + Q3 + F3 without delay. Balance equations (eq. (40); SIF groups SE1..SE4)::

    V1+ = V1 + Z1 - Q1 - F1                     - E1(mo) fa1(V1)
    V2+ = V2 + Z2 - F2                          - E1(mo) fa2(V2)
    V3+ = V3 + Z3 + F2(k-2) - Q3 - F3           - E1(mo) fa3(V3)
    V4+ = V4 + Z4 + Q1 + F1 + Q3 + F3 - Q4 - F4 - E4(mo) fa4(V4)
    F2(k-1)+ = F2,  F2(k-2)+ = F2(k-1)

with fa_i(V) = A V^2 + B V + C, mo = k mod 12 the calendar month, Z_i the inflows IN1, IN2, IN3
(constant), IN4 of record month j = (year - 1930)*12 + k. Note that, as in the SIF's GROUP USES,
reservoirs 2 and 3 use the evaporation coefficients E1 of reservoir 1.

Cost (eq. (44), exactly the SIF objective including its scaling; see :class:`Zambezi`)::

    J = sum_k [ -alpha (Q1 (h1(V1)+h1(V1+)) + Q3 (h3(V3)+h3(V3+)) + Q4 (h4(V4)+h4(V4+)))
                + psi ((Q1-Q1ref)^2 + (F2-F2ref)^2 + (Q3-Q3ref)^2 + (Q4-Q4ref)^2) ]
        + sum_i phi_i (V_i(N) - V_i,ref)^2 - nu_E sum_i fe_i(V_i(N))

where V_i+ is replaced by the right-hand side of the balance equation ("if only the volume
V^{k+1} in the water-level term of the cost function is replaced by the right-hand side of the
balance equation", paper 001 sec. 5), so that f_0^k depends on (x^k, u^k) only.
"""

from __future__ import annotations

import json
import math
import os

import numpy as np

from ..errors import ProblemDefinitionError
from .docp import DOCP, FirstDerivatives, PointValues, _plain, check_problem_size
from .zambezi_kernels import (_COUNTS, _D_STAGES, _JCOLS, _LU, _LX, _compiled_entries, _derivatives_kernel,
                              _final_cost_kernel, _final_gradient_kernel, _final_hessian_kernel, _pack,
                              _simulate_kernel, _stage_hessian_kernel, _values_kernel)

DATA_PATH = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", "zambezi.json")

STATE_NAMES = ("V1", "V2", "V3", "V4", "F2(k-1)", "F2(k-2)")
CONTROL_NAMES = ("Q1", "Q3", "Q4", "F1", "F2", "F3", "F4")

#: families of paper 001 sec. 5 and their default start years
FAMILIES = ("zambezi", "zambezi8", "zambezi9", "zambezi10", "zambezi11", "zambezi12")

_DATA_CACHE = {}
#: (family, N, start year) -> the arrays of _stage_data for the packaged data (Zambezi copies them)
_STAGE_DATA = {}
#: (family, N, start year, start) -> the start controls of Zambezi's own start functions
_START_U = {}


def load_data(path=None):
    """The extracted ZAMB2 numbers (dict, see ``tools/extract_zambezi.py``), cached."""
    path = os.path.abspath(path or DATA_PATH)
    if path not in _DATA_CACHE:
        with open(path, encoding="utf-8") as fh:
            _DATA_CACHE[path] = json.load(fh)
    return _DATA_CACHE[path]


#: an empty array: no final point for the fused kernels (the stage functions alone)
_NONE = np.empty(0)
#: the functions the fused kernels compute or bypass (Zambezi.eval_values,
#: Zambezi.eval_first_derivatives; stage_constraints, final_constraints (r = rN = 0) and their
#: Jacobians are DOCP's); their (name, function) pairs are _FUSED (below the class)
_VALUE_FUNCTIONS = frozenset(("dynamics", "stage_cost", "final_cost", "stage_constraints", "final_constraints",
                              "objective", "eval_stage_costs", "eval_final_cost", "eval_dynamics",
                              "eval_stage_constraints", "eval_final_constraints"))
_DERIVATIVE_FUNCTIONS = frozenset(("dynamics_jacobian", "stage_cost_gradient", "final_cost_gradient",
                                   "stage_constraints_jacobian", "final_constraints_jacobian",
                                   "eval_stage_cost_gradients", "eval_final_cost_gradient",
                                   "eval_dynamics_jacobians", "eval_stage_constraint_jacobians",
                                   "eval_final_constraint_jacobian"))

_F8 = np.dtype(np.float64)
#: builds a NamedTuple from a tuple without its Python-level __new__
_new_tuple = tuple.__new__


class _Fusion:
    """What Zambezi's one-pass evaluations (:meth:`Zambezi.eval_values`,
    :meth:`Zambezi.eval_first_derivatives`, :meth:`Zambezi.eval_stage_hessians`,
    :meth:`Zambezi.eval_final_hessian`) may do for one instance, decided once per instance (and
    again after any attribute of it is set or deleted, :meth:`Zambezi.__setattr__`) instead of
    on every call: which kinds of :data:`_FUSED` are Zambezi's own functions, the shapes and
    strides of a C-ordered point (X, U) that goes to the kernels as it is, the empty
    constraint arrays (r = rN = 0) the entry points return, and the last weight vector of the
    stage Hessians (sigma on every stage)."""

    __slots__ = ("values", "derivatives", "hessian", "X", "U", "P", "no_g", "no_gN", "no_Cx", "no_Cu", "no_CN",
                 "sigma")

    def __init__(self, problem):
        cls, names = type(problem), problem.__dict__.keys()
        analytic = problem.derivatives == "auto"
        fused = {}
        for kind, functions in _FUSED.items():
            plain = _PLAIN.get((cls, kind))
            if plain is None:
                plain = _PLAIN[cls, kind] = all(getattr(cls, nm) is fn for nm, fn in functions)
            fused[kind] = plain and not (names & _NAMES[kind])
        N = problem.N
        self.values = fused["values"]
        self.derivatives = fused["derivatives"] and analytic
        self.hessian = fused["hessian"] and analytic
        self.X = ((N + 1, 6), (48, 8))          # (shape, strides) of a C-ordered float64 array
        self.U = ((N, 7), (56, 8))
        self.P = ((N, 6), (48, 8))              # the dynamics multipliers of the stage Hessians
        self.no_g, self.no_gN = np.zeros((N, 0)), np.zeros(0)
        self.no_Cx, self.no_Cu, self.no_CN = np.zeros((N, 0, 6)), np.zeros((N, 0, 7)), np.zeros((0, 6))
        self.sigma = (None, None)

    def point(self, X, U):
        """True when (X, U) are C-ordered float64 arrays of the problem's shapes (nothing to
        convert or check: :meth:`DOCP._split_xu` and :meth:`Zambezi._rows` would return them)."""
        return (type(X) is np.ndarray and type(U) is np.ndarray and X.dtype is _F8 and U.dtype is _F8
                and (X.shape, X.strides) == self.X and (U.shape, U.strides) == self.U)

    def multipliers(self, P):
        """True when the stage Hessians' ``P`` is a C-ordered float64 array (N, 6)."""
        return type(P) is np.ndarray and P.dtype is _F8 and (P.shape, P.strides) == self.P

    def weights(self, sigma, N):
        """sigma on each of the N stages (the stage Hessian kernel's weights), remembered for the
        last sigma (a solve uses one objective scale); read only."""
        last, sig = self.sigma
        if sigma != last or sigma == 0.0:       # 0.0 and -0.0 compare equal: not remembered
            sig = np.full(N, sigma)
            sig.flags.writeable = False
            self.sigma = (sigma, sig)
        return sig


def _stage_data(d, fam, N, year):
    """The arrays of a Zambezi problem that depend on the data, the family, N and the start year
    only: phi, V_ref, u_ref, fa, fe, fh (the weights and the element curves), the record month
    and calendar month of each stage, inflow Z (N, 4), evaporation e (N, 4), the state and control
    bounds and x0."""
    first, months = int(d["first_year"]), int(d["record_months"])
    SC = fam["SC"]
    phi = np.array([1.0, 1.0, fam["PHI3"], 1.0]) * fam["PHI"] * SC
    V_ref = np.array([fam[f"V{i}REF"] for i in (1, 2, 3, 4)])
    u_ref = np.array([fam["Q1REF"], fam["F2REF"], fam["Q3REF"], fam["Q4REF"]])  # _REF_U order
    el = d["elements"]
    abc = lambda kind, ids: np.array([[el[kind][str(i)][c] for c in "ABC"] for i in ids]).T  # noqa: E731
    fa = abc("FA", (1, 2, 3, 4))        # (3, 4): rows A, B, C
    fe = abc("FE", (1, 2, 3, 4))
    fh = abc("FHQ", (1, 3, 4))          # (3, 3) for reservoirs 1, 3, 4

    # stage data: record month j, calendar month, inflow Z (N, 4), evaporation e (N, 4)
    k = np.arange(N)
    record_index = ((year - first) * 12 + k) % months
    month = k % 12
    rec = d["record"]
    inflow = np.column_stack([np.asarray(rec["IN1"])[record_index], np.asarray(rec["IN2"])[record_index],
                              np.full(N, rec["IN3"]), np.asarray(rec["IN4"])[record_index]])
    E1 = np.asarray(d["evaporation"]["E1"])[month]
    E4 = np.asarray(d["evaporation"]["E4"])[month]
    evaporation = np.column_stack([E1, E1, E1, E4])

    b = d["bounds"]
    lo = lambda nm: -np.inf if b[nm][0] is None else b[nm][0]  # noqa: E731
    hi = lambda nm: np.inf if b[nm][1] is None else b[nm][1]   # noqa: E731
    x_lo = np.array([lo(f"V{i}") for i in (1, 2, 3, 4)] + [-np.inf, -np.inf])
    x_hi = np.array([hi(f"V{i}") for i in (1, 2, 3, 4)] + [np.inf, np.inf])
    u_lo = np.tile([lo(nm) for nm in CONTROL_NAMES], (N, 1))
    u_hi = np.tile([hi(nm) for nm in CONTROL_NAMES], (N, 1))
    u_lo[:, 4] = np.asarray(b["F2_lower_by_month"])[month]
    x0 = np.array([fam["V10"], fam["V20"], fam["V30"], fam["V40"], fam["F2REF"], fam["F2REF"]])
    return (phi, V_ref, u_ref, fa, fe, fh, record_index, month, inflow, evaporation, x_lo, x_hi, u_lo, u_hi, x0)


class Zambezi(DOCP):
    """Zambezi reservoir DOCP, paper 001 eqs. (40)-(44), vectorized with analytic first and
    second derivatives.

    Parameters
    ----------
    family : one of ``FAMILIES`` (paper 001 sec. 5): ``zambezi`` = ZAMB2.SIF (start 1931),
        ``zambezi8`` = ZAMB2-8 (1948), ``zambezi9`` = ZAMB2-9 (1960), ``zambezi10`` = ZAMB2-10
        (1960), ``zambezi11`` = ZAMB2-11 (1930), ``zambezi12`` = ZAMB2-10's parameters with the
        reference-outflow term removed (PSI = 0), start 1945.
    N : horizon in months; a positive multiple of 12.
    start : initial control trajectory returned by :meth:`initial_guess`: ``"balance"``
        (eqs. (46)-(47), see :meth:`balance_start`) or ``"sif"`` (the SIF START POINT).
    year : start year (January); default the family's. 1930 <= year <= 1965.
    extend : ``"cyclic"`` lets the horizon run past December 1965 by continuing with January
        1930 (the 36-year inflow record 1930-1965 repeated; months stay aligned because the
        record has 432 = 36*12 months). This is for scaling studies (N = 1200, 12000, 120000);
        it is not historical data. ``None`` forbids N beyond the record.

    Scaling of the objective (SIF 'SCALE'): a SIF group with scale factor s contributes
    g/s to the objective. The SIF sets ALFA, PHI, PSI, VE := value*SC, SPSI = 1/PSI,
    SPHI = 1/PHI, SPHI3 = 1/(PHI*PHI3), and scales the groups F0Q*, V*END by SPSI, SPHI, SPHI3;
    so the weights of eq. (44) are psi = PSI*SC, phi_i = PHI*SC (phi_3 = PHI*PHI3*SC),
    nu_E = VE*SC, alpha = ALFA*SC. Dividing by the scale is what makes the SIF's terms equal
    the weights psi, phi of eq. (44); multiplying would give 1/psi.

    Bounds (eqs. (41)-(43)): volume bounds at every stage k = 0..N (the SIF bounds V(1..N) and
    fixes V(0) = V0, which lies inside them); the delayed-F2 states are unbounded; control
    bounds per stage with the monthly lower bound of F2 (nonstationary ``u_lower``).
    """

    name = "zambezi"
    vectorized = True
    state_names = STATE_NAMES
    control_names = CONTROL_NAMES

    def __init__(self, family="zambezi12", N=24, start="balance", year=None, extend="cyclic",
                 *, data=None, **docp_options):
        d = data if isinstance(data, dict) else load_data(data)
        if family not in d["families"]:
            raise ProblemDefinitionError(
                f"unknown Zambezi family {family!r}; choose one of {', '.join(d['families'])}",
                function="Zambezi", array="family")
        fam = d["families"][family]
        first, months = int(d["first_year"]), int(d["record_months"])
        last = first + months // 12 - 1
        if year is None:
            year = fam["YEAR"]
        if isinstance(year, bool) or not isinstance(year, (int, np.integer)) or not first <= year <= last:
            raise ProblemDefinitionError(
                f"start year must be an integer in {first}..{last} (the inflow record), got {year!r}",
                function="Zambezi", array="year")
        if extend not in ("cyclic", None):
            raise ProblemDefinitionError(f"extend must be 'cyclic' or None, got {extend!r}",
                                         function="Zambezi", array="extend")
        max_N = 12 * (last + 1 - int(year))
        if isinstance(N, bool) or not isinstance(N, (int, np.integer)) or N <= 0 or N % 12:
            raise ProblemDefinitionError(
                f"N must be a positive multiple of 12 (whole years: the F2 lower bound and the "
                f"evaporation are monthly and the horizon starts in January), got N={N!r}",
                function="Zambezi", array="N")
        if extend is None and N > max_N:
            raise ProblemDefinitionError(
                f"N={N} months from January {year} runs past the inflow record (1930-1965); "
                f"N <= {max_N} for this start year, or use extend='cyclic' to repeat the record",
                function="Zambezi", array="N")
        if start not in ("balance", "sif"):
            raise ProblemDefinitionError(f"start must be 'balance' or 'sif', got {start!r}",
                                         function="Zambezi", array="start")
        N = int(N)
        check_problem_size(len(STATE_NAMES), len(CONTROL_NAMES), N, function="Zambezi")
        self.family, self.start_year, self.extend, self.start = family, int(year), extend, start
        self.max_N = max_N
        self.params = dict(fam)
        SC = fam["SC"]
        #: weights of eq. (44) after the SIF scaling (see the class docstring)
        self.alpha = fam["ALFA"] * SC
        self.psi = fam["PSI"] * SC
        self.nu_E = fam["VE"] * SC
        key = (family, N, self.start_year) if data is None else None
        stage = _STAGE_DATA.get(key) if key is not None else None
        if stage is None:
            stage = _stage_data(d, fam, N, self.start_year)
            if key is not None:
                _STAGE_DATA[key] = stage
        # each instance its own arrays (a user may change a problem's data in place)
        (self.phi, self.V_ref, self.u_ref, self.fa, self.fe, self.fh, self.record_index, self.month, self.inflow,
         self.evaporation, x_lo, x_hi, u_lo, u_hi, x0) = (a.copy(order="K") for a in stage)
        super().__init__(6, 7, N, x0, x_bounds=(x_lo, x_hi), u_bounds=(u_lo, u_hi), **docp_options)
        self.name = family
        # the start controls depend on the stage data and bounds only: remembered with them
        # (for Zambezi's own start functions)
        plain = key is not None and _START_FUNCTIONS == (type(self).balance_start, type(self).sif_start)
        U = _START_U.get(key + (start,)) if plain else None
        if U is None:
            U = self.balance_start() if start == "balance" else self.sif_start()
            if plain:
                _START_U[key + (start,)] = U.copy()
        self._start_U = U.copy()

    # ------------------------------------------------------------------ helpers
    @staticmethod
    def _quad(c, V):
        """A V^2 + B V + C, its first and second derivative; c is (3, r), V is (K, r)."""
        A, B, C = c
        return (A * V + B) * V + C, 2.0 * A * V + B, np.broadcast_to(2.0 * A, V.shape)

    def _next_volumes(self, k, x, u):
        """V^{k+1} (K, 4) of eq. (40), its derivative dV+/dV_i (diagonal, (K, 4)) and the
        diagonal second derivative (K, 4). (Reference numpy form; the stage functions below use
        the compiled kernels of :mod:`olado.problems.zambezi_kernels`, which compute the same
        quantities.)"""
        V = x[:, :4]
        fa, dfa, d2fa = self._quad(self.fa, V)
        e = self.evaporation[k]
        Vn = x @ _LX[:4].T + u @ _LU[:4].T + self.inflow[k] - e * fa
        return Vn, 1.0 - e * dfa, -e * d2fa

    @staticmethod
    def _stages(k, K):
        """The stage indices as an int64 array (K,) (a scalar k applies to every row)."""
        if type(k) is np.ndarray and k.dtype == np.int64 and k.ndim == 1 and k.flags.c_contiguous:
            return k
        k = np.asarray(k)
        if k.ndim == 0:
            return np.full(K, int(k), dtype=np.int64)
        return np.ascontiguousarray(k.reshape(-1), dtype=np.int64)

    @staticmethod
    def _rows(a):
        """A stage array as C-contiguous float64 (K, d): no copy when it already is one."""
        if type(a) is np.ndarray and a.dtype == np.float64 and a.flags.c_contiguous:
            return a
        return np.ascontiguousarray(a, dtype=np.float64)

    def _args(self, k, x, u):
        x, u = self._rows(x), self._rows(u)
        return self._stages(k, x.shape[0]), x, u

    # ------------------------------------------------------------------ DOCP functions
    def _values_of_stages(self, k, x, u):
        """(f (K, 6), stage costs (K,)) of the stage rows, one pass (:func:`_values_kernel`)."""
        k, x, u = self._args(k, x, u)
        K = x.shape[0]
        f, cost = np.empty((K, 6)), np.empty(K)
        _values_kernel(k, x, u, _NONE, self.inflow, self.evaporation, self.fa, self.fh, self.alpha,
                       self.psi, self.u_ref, self.V_ref, self.phi, self.fe, self.nu_E, f, cost)
        return f, cost

    def _derivatives_of_stages(self, k, x, u):
        """(l_x (K, 6), l_u (K, 7), f_x (K, 6, 6), f_u (K, 6, 7)), one pass (:func:`_derivatives_kernel`)."""
        k, x, u = self._args(k, x, u)
        K = x.shape[0]
        gx, gu, fx, fu = np.empty((K, 6)), np.empty((K, 7)), np.empty((K, 6, 6)), np.empty((K, 6, 7))
        _derivatives_kernel(k, x, u, _NONE, self.inflow, self.evaporation, self.fa, self.fh, self.alpha,
                            self.psi, self.u_ref, self.V_ref, self.phi, self.fe, self.nu_E, _LX, _LU,
                            gx, gu, fx, fu, _NONE)
        return gx, gu, fx, fu

    def dynamics(self, k, x, u):
        """f^k(x, u) of eq. (40) plus the delay states, all stages at once, (K, 6)."""
        return self._values_of_stages(k, x, u)[0]

    def dynamics_jacobian(self, k, x, u):
        """(f_x (K, 6, 6), f_u (K, 6, 7)) of eq. (40)."""
        return self._derivatives_of_stages(k, x, u)[2:]

    def stage_cost(self, k, x, u):
        """f_0^k of eq. (44) with V^{k+1} replaced by the balance equation, (K,)."""
        return self._values_of_stages(k, x, u)[1]

    def stage_cost_gradient(self, k, x, u):
        """(l_x (K, 6), l_u (K, 7)) of the stage cost."""
        return self._derivatives_of_stages(k, x, u)[:2]

    # ------------------------------------------------------------------ a point at once
    _fusion = None          # the instance's _Fusion (made on first use)

    def __setattr__(self, name, value):
        """Set an attribute; the instance's :class:`_Fusion` is decided again on its next use
        (a function replaced on the instance is then called, not bypassed)."""
        super().__setattr__(name, value)
        self.__dict__.pop("_fusion", None)

    def __delattr__(self, name):
        super().__delattr__(name)
        self.__dict__.pop("_fusion", None)

    def _fuse(self):
        """The instance's :class:`_Fusion` (made once, kept in the instance's dict)."""
        fusion = self.__dict__["_fusion"] = _Fusion(self)
        return fusion

    def _fused(self, kind):
        """True when the functions of ``kind`` ("values", "derivatives", "hessian": :data:`_FUSED`)
        are Zambezi's own (not replaced by a subclass -- a class is checked once -- or on the
        instance) and, for derivatives and Hessians, the problem's analytic derivatives are in use:
        then :meth:`eval_values`, :meth:`eval_first_derivatives`, :meth:`eval_stage_hessians`
        compute them in one compiled pass instead of calling them one by one."""
        return getattr(self._fusion or self._fuse(), kind)

    def _point(self, fusion, X, U):
        """(X, U) as the kernels take them (C-ordered float64; :meth:`DOCP._split_xu`'s checks)."""
        if fusion.point(X, U):
            return X, U
        X, U = self._split_xu(X, U)
        return self._rows(X), self._rows(U)

    def eval_values(self, X, U):
        """:meth:`DOCP.eval_values` in one compiled pass (:func:`_values_kernel`): the same numbers
        and counters; a NaN or inf (or a replaced stage function) takes the default path, which
        names the function, stage and array."""
        fusion = self._fusion or self._fuse()
        if not fusion.values:
            return super().eval_values(X, U)
        X, U = self._point(fusion, X, U)
        N = self.N
        f, cost = np.empty((N, 6)), np.empty(N)
        F, finite = _values_kernel(self._K, X[:-1], U, X[-1], self.inflow, self.evaporation, self.fa, self.fh,
                                   self.alpha, self.psi, self.u_ref, self.V_ref, self.phi, self.fe,
                                   self.nu_E, f, cost)
        if not finite:
            return super().eval_values(X, U)
        c = self.counters
        c["stage_cost"] += 1
        c["final_cost"] += 1
        c["dynamics"] += 1
        return _new_tuple(PointValues, (float(cost.sum() + F), f, fusion.no_g, fusion.no_gN))

    def _stacked_values(self, K, X, U, XN):
        """:meth:`DOCP._stacked_values` in one compiled pass over the stage rows
        (:func:`_values_kernel`) and :func:`_final_cost_kernel` per final row without the wrappers
        (the numbers of :meth:`final_cost`), under the rules of :meth:`eval_values`."""
        if not self._fused("values"):
            return super()._stacked_values(K, X, U, XN)
        k, x, u = self._args(K, X, U)
        nK = x.shape[0]
        f, cost = np.empty((nK, 6)), np.empty(nK)
        _, finite = _values_kernel(k, x, u, _NONE, self.inflow, self.evaporation, self.fa, self.fh, self.alpha,
                                   self.psi, self.u_ref, self.V_ref, self.phi, self.fe, self.nu_E, f, cost)
        final = np.array([_final_cost_kernel(x, self.V_ref, self.phi, self.fe, self.nu_E) for x in self._rows(XN)])
        if not (finite and np.isfinite(final).all()):
            return super()._stacked_values(K, X, U, XN)
        self.counters["final_cost"] += len(final)
        return cost, f, np.zeros((nK, 0)), final

    def eval_first_derivatives(self, X, U):
        """:meth:`DOCP.eval_first_derivatives` in one compiled pass (:func:`_derivatives_kernel`),
        under the rules of :meth:`eval_values`."""
        fusion = self._fusion or self._fuse()
        if not fusion.derivatives:
            return super().eval_first_derivatives(X, U)
        X, U = self._point(fusion, X, U)
        N = self.N
        gx, gu, fx, fu, gN = np.empty((N, 6)), np.empty((N, 7)), np.empty((N, 6, 6)), np.empty((N, 6, 7)), np.zeros(6)
        if not _derivatives_kernel(self._K, X[:-1], U, X[-1], self.inflow, self.evaporation, self.fa, self.fh,
                                   self.alpha, self.psi, self.u_ref, self.V_ref, self.phi, self.fe,
                                   self.nu_E, _LX, _LU, gx, gu, fx, fu, gN):
            return super().eval_first_derivatives(X, U)
        c = self.counters
        c["stage_cost_gradient"] += 1
        c["final_cost_gradient"] += 1
        c["dynamics_jacobian"] += 1
        return _new_tuple(FirstDerivatives, (gx, gu, gN, fx, fu, fusion.no_Cx, fusion.no_Cu, fusion.no_CN))

    def stage_hessian(self, k, x, u, sigma, p, lam):
        """Blocks of the Hessian of sigma*f_0^k + p.f^k (no stage constraints), all stages."""
        k, x, u = self._args(k, x, u)
        K = x.shape[0]
        if np.ndim(sigma):
            sig = np.ascontiguousarray(np.broadcast_to(np.asarray(sigma, dtype=np.float64).reshape(-1), (K,)))
        else:
            sig = np.full(K, float(sigma))
        p = self._rows(p)
        hxx, hxu, huu = np.empty((K, 6, 6)), np.empty((K, 6, 7)), np.empty((K, 7, 7))
        _stage_hessian_kernel(k, x, u, self.inflow, self.evaporation, self.fa, self.fh,
                              self.alpha, self.psi, sig, p, _LX, _LU, _JCOLS, hxx, hxu, huu)
        return hxx, hxu, huu

    def eval_stage_hessians(self, X, U, sigma, P, L=None, source=None):
        """:meth:`DOCP.eval_stage_hessians` with the analytic :meth:`stage_hessian` called
        without its wrappers (one compiled pass, :func:`_stage_hessian_kernel`), under the rules of
        :meth:`eval_values`: anything but plain arrays of the expected shapes and a float ``sigma``
        -- or an entry that comes out NaN or inf -- takes the default path."""
        fusion = self._fusion or self._fuse()
        N = self.N
        if (source is not None or not fusion.hessian or not isinstance(sigma, float)
                or not fusion.multipliers(P)
                or not (L is None or _plain(L, (N, 0)))):
            return super().eval_stage_hessians(X, U, sigma, P, L, source)
        X, U = self._point(fusion, X, U)
        hxx, hxu, huu = np.empty((N, 6, 6)), np.empty((N, 6, 7)), np.empty((N, 7, 7))
        if not _stage_hessian_kernel(self._K, X[:-1], U, self.inflow, self.evaporation, self.fa, self.fh,
                                     self.alpha, self.psi, fusion.weights(float(sigma), N), P, _LX, _LU,
                                     _JCOLS, hxx, hxu, huu):
            return super().eval_stage_hessians(X, U, sigma, P, L, source)
        self.counters["stage_hessian"] += 1
        return hxx, hxu, huu

    def eval_final_hessian(self, xN, sigma, lN=None, source=None):
        """:meth:`DOCP.eval_final_hessian` without the wrappers, under the rules of
        :meth:`eval_stage_hessians`."""
        fusion = self._fusion or self._fuse()
        if (source is not None or not fusion.hessian or not isinstance(sigma, float)
                or not (lN is None or _plain(lN, (0,)))):
            return super().eval_final_hessian(xN, sigma, lN, source)
        H = np.zeros((6, 6))
        _final_hessian_kernel(float(sigma), self.phi, self.fe, self.nu_E, H)
        if not math.isfinite(H[0, 0] + H[1, 1] + H[2, 2] + H[3, 3]):
            return super().eval_final_hessian(xN, sigma, lN, source)
        self.counters["final_hessian"] += 1
        return H

    def compiled_evaluations(self):
        """:meth:`DOCP.compiled_evaluations`: the one-pass kernels of :meth:`eval_values`,
        :meth:`eval_first_derivatives`, :meth:`eval_stage_hessians` and :meth:`eval_final_hessian`
        as compiled functions (:mod:`olado.problems.compiled`; the same numbers bit for bit), when
        those entry points use them (Zambezi's own functions, analytic derivatives: the instance's
        :class:`_Fusion`); None otherwise. The functions are made once per process; the data are
        the instance's numbers as they are at this call, in arrays of this call's own (~6 us): a
        copy or a pickle of the problem shares nothing compiled or packed with it."""
        fusion = self._fusion or self._fuse()
        if not (fusion.values and fusion.derivatives and fusion.hessian) or not self._own_entries():
            return None
        from .compiled import CompiledEvaluations
        data, idata = np.empty(_D_STAGES + 8 * self.N), np.empty(self.N + _JCOLS.size, dtype=np.int64)
        _pack(data, idata, self._K, self.inflow, self.evaporation, self.fa, self.fh, self.alpha, self.psi, self.u_ref,
              self.V_ref, self.phi, self.fe, self.nu_E)
        return CompiledEvaluations(*_compiled_entries(), data, idata, _COUNTS)

    def _own_entries(self):
        """Whether the entry points the compiled evaluations stand for (:data:`_ENTRY_POINTS`) are
        Zambezi's own: a subclass or instance replacing one (a penalty added to eval_values, say)
        must be evaluated through it."""
        cls = type(self)
        return (all(getattr(cls, nm) is getattr(Zambezi, nm) for nm in _ENTRY_POINTS)
                and not self.__dict__.keys() & _ENTRY_POINTS)

    def final_cost(self, x):
        """F^N = sum_i phi_i (V_i - V_i,ref)^2 - nu_E sum_i fe_i(V_i), eq. (44)."""
        return _final_cost_kernel(self._rows(x), self.V_ref, self.phi, self.fe, self.nu_E)

    def final_cost_gradient(self, x):
        g = np.zeros(6)
        _final_gradient_kernel(self._rows(x), self.V_ref, self.phi, self.fe, self.nu_E, g)
        return g

    def final_hessian(self, x, sigma, lam):
        H = np.zeros((6, 6))
        if np.ndim(sigma):
            idx = np.arange(4)
            H[idx, idx] = sigma * (2.0 * self.phi - self.nu_E * 2.0 * self.fe[0])
        else:
            _final_hessian_kernel(float(sigma), self.phi, self.fe, self.nu_E, H)
        return H

    def simulate(self, U):
        """States X (N+1, 6) from x^0 under controls U, eq. (40): the same recursion as
        :meth:`DOCP.simulate`, with the stage data precomputed, for long horizons."""
        U = self.check_array(U, (self.N, self.m), "simulate", "u")
        self.counters["dynamics"] += 1
        N = self.N
        # everything that does not depend on the states, per stage: Z + Lu u, and e
        drive = np.ascontiguousarray(self.inflow + U @ _LU[:4].T)
        X = np.empty((N + 1, 6))
        X[0] = self.x0
        _simulate_kernel(drive, self.evaporation, self.fa, self._rows(U), X)
        return self._check_stacked(X, (N + 1, 6), "simulate", "x")

    # ------------------------------------------------------------------ start points
    def plot_result(self, result, path=None, **kwargs):
        """Fig. 3-style plot of a result (used by ``Result.plot(path, problem=...)``)."""
        if path is None:
            raise ValueError("plot_result needs a file path for the Zambezi figure")
        return plot_zambezi(result, self, path)

    def initial_guess(self):
        """Initial controls (N, 7): the balance start (default) or the SIF start point."""
        return self._start_U.copy()

    def initial_state_guess(self, U):
        """With ``start="sif"``: the SIF START POINT's states, V_i(k) = V_i^0 at every stage, and
        the delay states consistent with U (F2 of the two months before; exact, they are linear).
        Simulating the SIF controls instead (outflow = inflow, evaporation ignored) lets the
        volumes drift below their bounds, where the quadratic evaporation term makes them
        diverge: zambezi and zambezi11 overflowed for N >= 288. None (simulate) otherwise."""
        if self.start != "sif":
            return None
        X = np.empty((self.N + 1, 6))
        X[:, :4] = self.x0[:4]
        X[0, 4:] = self.x0[4:]
        X[1:, 4] = U[:, 4]
        X[1:, 5] = X[:-1, 4]
        return X

    def sif_start(self):
        """The SIF START POINT controls: Q1 = IN1, F2 = IN2, Q3 = IN2, Q4 = IN1, F1 = F3 = F4 = 0
        (taken verbatim, not clipped to the bounds; the SIF also starts V(k) = V0)."""
        U = np.zeros((self.N, 7))
        U[:, 0] = self.inflow[:, 0]
        U[:, 4] = self.inflow[:, 1]
        U[:, 1] = self.inflow[:, 1]
        U[:, 2] = self.inflow[:, 0]
        return U

    def balance_start(self):
        """Initial controls from the reservoir balance, paper 001 eqs. (46)-(47).

        Reservoirs in upstream order 1, 2, 3, 4 with U_3 = {2}, U_4 = {1, 3}:

            Zbar_i = (sum_k Z_i^k - (V_ref,i - V_i^0)) / N + mean upstream inflow
            Q_i = Q_max if Zbar_i > Q_max else max(Zbar_i, Q_min);  F_i = max(Zbar_i - Q_max, 0)

        held constant over k and clipped to each stage's bounds. Readings: reservoir 2 has no
        turbine, its outflow F2 plays the role of Q_2 (bounds [F2_min^k, F2_max]); reservoir 3
        receives F2 two months late, so its mean upstream inflow is (2 F2ref + sum_{k<N-2}
        F2^k) / N (the delay states start at F2ref) rather than F2^0; reservoir 4 receives
        Q1 + F1 + Q3 + F3 of the same month. Evaporation is not in eq. (47) and is left out,
        as in the paper. The controls lie within their bounds; the simulated volumes need not
        (e.g. V2 can fall below its minimum when the monthly F2 minimum exceeds the inflow) --
        it is a starting trajectory, not a feasible point.
        """
        N = self.N
        lo, hi = self.u_lower, self.u_upper
        Zsum = self.inflow.sum(axis=0)
        dV = self.V_ref - self.x0[:4]
        U = np.zeros((N, 7))

        def release(zbar, q, f):
            qmax, qmin = hi[0, q], lo[0, q]
            if zbar > qmax:
                Q, F = qmax, zbar - qmax
            else:
                Q, F = max(zbar, qmin), 0.0
            U[:, q] = np.clip(Q, lo[:, q], hi[:, q])
            if f is not None:
                U[:, f] = np.clip(F, lo[:, f], hi[:, f])

        release((Zsum[0] - dV[0]) / N, 0, 3)                          # Q1, F1
        release((Zsum[1] - dV[1]) / N, 4, None)                       # F2 (no turbine)
        upstream3 = (self.x0[4] + self.x0[5] + U[:max(N - 2, 0), 4].sum()) / N
        release((Zsum[2] - dV[2]) / N + upstream3, 1, 5)              # Q3, F3
        upstream4 = U[0, 0] + U[0, 3] + U[0, 1] + U[0, 5]
        release((Zsum[3] - dV[3]) / N + upstream4, 2, 6)              # Q4, F4
        return U

    # ------------------------------------------------------------------ reporting
    def month_labels(self):
        """'YYYY-MM' of each stage k = 0..N-1 (cyclic extension continues the calendar)."""
        return [f"{self.start_year + k // 12}-{k % 12 + 1:02d}" for k in range(self.N)]

    def describe(self):
        text = super().describe()
        return (text + f"\n  family {self.family}, start January {self.start_year}, "
                f"N={self.N} months{' (cyclic inflow extension)' if self.N > self.max_N else ''}, "
                f"start={self.start}")


#: Zambezi's own start functions (their controls are remembered per family, N, year and start)
_START_FUNCTIONS = (Zambezi.balance_start, Zambezi.sif_start)
#: (name, function) of what the fused kernels replace, as Zambezi defines or inherits them
_FUSED = {"values": tuple((nm, getattr(Zambezi, nm)) for nm in _VALUE_FUNCTIONS),
          "derivatives": tuple((nm, getattr(Zambezi, nm)) for nm in _DERIVATIVE_FUNCTIONS)}
_HESSIAN_FUNCTIONS = frozenset(("stage_hessian", "final_hessian"))
_FUSED["hessian"] = tuple((nm, getattr(Zambezi, nm)) for nm in _HESSIAN_FUNCTIONS)
_NAMES = {"values": _VALUE_FUNCTIONS, "derivatives": _DERIVATIVE_FUNCTIONS, "hessian": _HESSIAN_FUNCTIONS}
#: (class, functions) -> the class keeps Zambezi's functions (checked once per class)
_PLAIN = {}
#: the entry points Zambezi.compiled_evaluations stands for
_ENTRY_POINTS = frozenset(("eval_values", "eval_first_derivatives", "eval_stage_hessians", "eval_final_hessian"))

def zambezi_problem(family="zambezi12", N=24, start="balance", year=None, extend="cyclic", **options):
    """Build a Zambezi DOCP (paper 001 sec. 5). See :class:`Zambezi` for the arguments."""
    return Zambezi(family=family, N=N, start=start, year=year, extend=extend, **options)


def _factory(family):
    def make(N=24, start="balance", year=None, extend="cyclic", **options):
        return zambezi_problem(family, N=N, start=start, year=year, extend=extend, **options)
    make.__name__ = f"{family}_problem"
    make.__doc__ = f"Zambezi reservoirs (paper 001 sec. 5): {_FAMILY_NOTES[family]}; see :class:`Zambezi`."
    return make


_FAMILY_NOTES = {
    "zambezi": "CUTEr ZAMB2, from January 1931, N <= 420",
    "zambezi8": "CUTEr ZAMB2-8, from 1948, N <= 216",
    "zambezi9": "CUTEr ZAMB2-9, from 1960, N <= 72",
    "zambezi10": "CUTEr ZAMB2-10, from 1960, N <= 72",
    "zambezi11": "CUTEr ZAMB2-11, from 1930, N <= 432",
    "zambezi12": "ZAMB2-10 without the reference-outflow term, from 1945, N <= 252 (Table 1)",
}


#: name -> factory(N=24, start="balance", year=None, extend="cyclic", **options)
PROBLEMS = {fam: _factory(fam) for fam in FAMILIES}


def table1_counts(problem):
    """Problem size as counted in paper 001 Table 1: variables, equality constraints including
    fixed variables, inequality constraints including bounds.

    variables   = (N+1) n + N m                  (y = x^0, u^0, ..., x^N)
    equalities  = N n (balance/delay equations) + n (fixed x^0) + equality constraints
    inequalities = finite bounds in x_lower, x_upper over k = 0..N (x^0 included, as its volume
                   bounds are part of the stationary bounds) + finite bounds in u_lower, u_upper
                   over k = 0..N-1 + inequality constraints.

    For the Zambezi problem: 8 volume bounds (x5, x6 unbounded) at N+1 stages + 14 control
    bounds (all 7 controls two-sided) at N stages, e.g. N = 12: 104 + 168 = 272.
    """
    N, n, m = problem.N, problem.n, problem.m
    n_eq_g = int(problem.stage_equality_mask.sum()) * N + int(problem.final_equality_mask.sum())
    n_in_g = (problem.r - int(problem.stage_equality_mask.sum())) * N + \
        (problem.rN - int(problem.final_equality_mask.sum()))
    xb = int(np.isfinite(problem.x_lower).sum() + np.isfinite(problem.x_upper).sum())
    ub = int(np.isfinite(problem.u_lower).sum() + np.isfinite(problem.u_upper).sum())
    return {"N": N, "variables": (N + 1) * n + N * m, "equalities": N * n + n + n_eq_g,
            "inequalities": xb + ub + n_in_g, "state_bounds": xb, "control_bounds": ub}


def plot_zambezi(result_or_XU, problem, path):
    """Plot volumes, turbine outflows and spillages with their bounds, like paper 001 Fig. 3.

    ``result_or_XU`` is a Result (``.x``, ``.u``) or a pair (X (N+1, 6), U (N, 7)). Rows:
    volumes V1..V4; outflows Q1, Q3, Q4 (solid); spillages F1..F4 (dashed); bounds dotted;
    x axis: month k from January of the start year (units as in the SIF data).
    The figure is written to a temporary file and moved to ``path`` (atomic). Returns ``path``.
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if isinstance(result_or_XU, (tuple, list)):
        X, U = result_or_XU
    else:
        X, U = result_or_XU.x, result_or_XU.u
    X, U = np.asarray(X, float), np.asarray(U, float)
    N = problem.N
    kx = np.arange(N + 1)
    ext = lambda a: np.append(a, a[-1])   # noqa: E731  piecewise-constant control over [k, k+1)
    fig, axes = plt.subplots(3, 4, figsize=(14, 8), sharex=True)
    bound = dict(color="k", linestyle=":", linewidth=1)
    for i in range(4):
        ax = axes[0, i]
        ax.plot(kx, X[:, i], "b-")
        ax.plot(kx, problem.x_lower[:, i], **bound)
        ax.plot(kx, problem.x_upper[:, i], **bound)
        ax.set_title(f"volume V{i + 1}")
    for col, (j, nm) in zip((0, 2, 3), ((0, "Q1"), (1, "Q3"), (2, "Q4"))):
        ax = axes[1, col]
        ax.step(kx, ext(U[:, j]), "b-", where="post")
        ax.step(kx, ext(problem.u_lower[:, j]), where="post", **bound)
        ax.step(kx, ext(problem.u_upper[:, j]), where="post", **bound)
        ax.set_title(f"turbine outflow {nm}")
    axes[1, 1].text(0.5, 0.5, "reservoir 2:\nno power station\n(outflow F2 only)",
                    ha="center", va="center", transform=axes[1, 1].transAxes)
    axes[1, 1].set_frame_on(False)
    axes[1, 1].tick_params(left=False, labelleft=False, bottom=False)
    for i, j in enumerate((3, 4, 5, 6)):
        ax = axes[2, i]
        ax.step(kx, ext(U[:, j]), "r--", where="post")
        ax.step(kx, ext(problem.u_lower[:, j]), where="post", **bound)
        ax.step(kx, ext(problem.u_upper[:, j]), where="post", **bound)
        ax.set_title(f"spillage F{i + 1}")
        ax.set_xlabel("month k")
    year = getattr(problem, "start_year", None)
    fig.suptitle(f"{getattr(problem, 'name', 'zambezi')}, N = {N}"
                 + (f", from January {year}" if year is not None else ""))
    fig.tight_layout()
    from ..result import save_figure   # the one atomic writer (temporary file + os.replace)

    try:
        save_figure(fig, path)
    finally:
        plt.close(fig)
    return os.fspath(path)
