"""The compiled kernels of the Zambezi benchmark (:mod:`olado.problems.zambezi`, paper 001 sec. 5,
eqs. (40), (44)): the stage values, first derivatives and Hessian blocks in one pass over the
stages, the final cost and its derivatives, the simulation, and the problem's compiled
evaluations (:mod:`olado.problems.compiled`) over the same kernels. One file, so that numba's
cache of an entry sees a change of the kernels it calls (docs/architecture.md, "Caches")."""

from __future__ import annotations

import math
from types import MappingProxyType

import numba as nb
import numpy as np
from numba.core.imputils import impl_ret_borrowed
from numba.extending import intrinsic


# linear parts of the state equation: f = Lx x + Lu u + [Z - e fa(V), 0, 0]
_LX = np.zeros((6, 6))
_LX[[0, 1, 2, 3], [0, 1, 2, 3]] = 1.0
_LX[2, 5] = 1.0            # reservoir 3 receives F2(k-2)
_LX[5, 4] = 1.0            # F2(k-2)+ = F2(k-1)
_LU = np.zeros((6, 7))
_LU[0, [0, 3]] = -1.0      # Q1, F1 leave reservoir 1
_LU[1, 4] = -1.0           # F2 leaves reservoir 2
_LU[2, [1, 5]] = -1.0      # Q3, F3 leave reservoir 3
_LU[3, [0, 3, 1, 5]] = 1.0  # ... and enter reservoir 4
_LU[3, [2, 6]] = -1.0      # Q4, F4 leave reservoir 4
_LU[4, 4] = 1.0            # F2(k-1)+ = F2
#: reservoirs with a power station (0-based) and the column of their turbine flow in w = (x, u)
_TURBINE_RES = np.array([0, 2, 3])
_TURBINE_COL = np.array([6, 7, 8])   # Q1, Q3, Q4
#: controls in the reference-outflow term (SIF groups F0Q1, F0F2, F0Q3, F0Q4), columns of u
_REF_U = np.array([0, 4, 1, 2])


# ============================================================================ compiled stage kernels
# One pass over the stages per call, no temporaries: the same formulas as the numpy reference
# Zambezi._next_volumes / Zambezi._quad, written out per stage (paper 001 eqs. (40), (44)).
# k[i] is the stage of row i (it selects the inflow and evaporation of that month).

@nb.njit(cache=True)
def _volumes(kk, xi, ui, inflow, evap, fa, Vn, dV, d2V):
    """V^{k+1} (4,) of eq. (40) at one stage, dV+_j/dV_j and d2V+_j/dV_j^2 (into Vn, dV, d2V)."""
    lin0 = xi[0] + (-ui[0] - ui[3])
    lin1 = xi[1] + (-ui[4])
    lin2 = (xi[2] + xi[5]) + (-ui[1] - ui[5])
    lin3 = xi[3] + (ui[0] + ui[1] - ui[2] + ui[3] + ui[5] - ui[6])
    lin = (lin0, lin1, lin2, lin3)
    for j in range(4):
        V = xi[j]
        e = evap[kk, j]
        A, B, C = fa[0, j], fa[1, j], fa[2, j]
        Vn[j] = (lin[j] + inflow[kk, j]) - e * ((A * V + B) * V + C)
        dV[j] = 1.0 - e * (2.0 * A * V + B)
        d2V[j] = -e * (2.0 * A)


@nb.njit(cache=True)
def _turbine_heads(xi, Vn, fh, h, dh, hn, dhn, d2h):
    """h(V_r), h(V+_r) and their derivatives for the turbine reservoirs r = 1, 3, 4 (0, 2, 3)."""
    for t in range(3):
        r = 0 if t == 0 else t + 1
        A, B, C = fh[0, t], fh[1, t], fh[2, t]
        V, W = xi[r], Vn[r]
        h[t] = (A * V + B) * V + C
        hn[t] = (A * W + B) * W + C
        dh[t] = 2.0 * A * V + B
        dhn[t] = 2.0 * A * W + B
        d2h[t] = 2.0 * A


@nb.njit(cache=True)
def _stage_jacobian_rows(dV, LX, LU, J):
    """dV+/dw (4, 13), w = (x, u), at one stage."""
    for j in range(4):
        for b in range(6):
            J[j, b] = LX[j, b]
        for b in range(7):
            J[j, 6 + b] = LU[j, b]
        J[j, j] = dV[j]


@nb.njit(cache=True)
def _final_cost_kernel(x, V_ref, phi, fe, nu_E):
    """F^N of eq. (44): sum_i phi_i (V_i - V_i,ref)^2 - nu_E sum_i fe_i(V_i)."""
    dev, evap = 0.0, 0.0
    for i in range(4):
        V = x[i]
        d = V - V_ref[i]
        dev += phi[i] * d * d
        evap += (fe[0, i] * V + fe[1, i]) * V + fe[2, i]
    return dev - nu_E * evap


@nb.njit(cache=True)
def _final_gradient_kernel(x, V_ref, phi, fe, nu_E, g):
    for i in range(4):
        V = x[i]
        g[i] = 2.0 * phi[i] * (V - V_ref[i]) - nu_E * (2.0 * fe[0, i] * V + fe[1, i])


@nb.njit(cache=True)
def _final_hessian_kernel(sigma, phi, fe, nu_E, H):
    for i in range(4):
        H[i, i] = sigma * (2.0 * phi[i] - nu_E * 2.0 * fe[0, i])


@nb.njit(cache=True)
def _values_kernel(k, x, u, xN, inflow, evap, fa, fh, alpha, psi, uref, V_ref, phi, fe, nu_E, f, cost):
    """The dynamics f (K, 6) of eq. (40) and the stage costs (K,) of eq. (44) in one pass over the
    stages, and the final cost F^N at xN when xN has 6 entries (0 otherwise); returns (F^N, every
    value finite). The formulas of the reference Zambezi._next_volumes / Zambezi._quad."""
    Vn, dV, d2V = np.empty(4), np.empty(4), np.empty(4)
    h, dh, hn, dhn, d2h = np.empty(3), np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    finite = True
    for i in range(x.shape[0]):
        _volumes(k[i], x[i], u[i], inflow, evap, fa, Vn, dV, d2V)
        for j in range(4):
            f[i, j] = Vn[j]
        f[i, 4] = u[i, 4]
        f[i, 5] = x[i, 4]
        _turbine_heads(x[i], Vn, fh, h, dh, hn, dhn, d2h)
        energy = u[i, 0] * (h[0] + hn[0]) + u[i, 1] * (h[1] + hn[1]) + u[i, 2] * (h[2] + hn[2])
        d0, d1, d2, d3 = u[i, 0] - uref[0], u[i, 4] - uref[1], u[i, 1] - uref[2], u[i, 2] - uref[3]
        cost[i] = -alpha * energy + psi * (d0 * d0 + d1 * d1 + d2 * d2 + d3 * d3)
        finite &= math.isfinite(cost[i])
        for j in range(6):
            finite &= math.isfinite(f[i, j])
    F = 0.0
    if xN.shape[0]:
        F = _final_cost_kernel(xN, V_ref, phi, fe, nu_E)
        finite &= math.isfinite(F)
    return F, finite


@nb.njit(cache=True)
def _derivatives_kernel(k, x, u, xN, inflow, evap, fa, fh, alpha, psi, uref, V_ref, phi, fe, nu_E, LX, LU,
                        gx, gu, fx, fu, gN):
    """The stage cost gradients (gx (K, 6), gu (K, 7)) and the dynamics Jacobians (fx (K, 6, 6),
    fu (K, 6, 7)) in one pass over the stages, and the final cost gradient gN (6,) at xN when
    xN has 6 entries; returns True when every entry is finite."""
    Vn, dV, d2V = np.empty(4), np.empty(4), np.empty(4)
    h, dh, hn, dhn, d2h = np.empty(3), np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    J = np.empty((4, 13))
    g = np.empty(13)
    ref = (0, 4, 1, 2)
    finite = True
    for i in range(x.shape[0]):
        _volumes(k[i], x[i], u[i], inflow, evap, fa, Vn, dV, d2V)
        for a in range(6):
            for b in range(6):
                fx[i, a, b] = LX[a, b]
            for b in range(7):
                fu[i, a, b] = LU[a, b]
        for j in range(4):
            fx[i, j, j] = dV[j]       # 1 - e (2 A V + B): the only entries that depend on the point
            finite &= math.isfinite(dV[j])
        _turbine_heads(x[i], Vn, fh, h, dh, hn, dhn, d2h)
        _stage_jacobian_rows(dV, LX, LU, J)
        # d/dw [Q (h(V) + h(V+))] = e_Q (h + h+) + Q h'(V) e_V + Q h'(V+) dV+/dw
        c0, c1, c2 = u[i, 0] * dhn[0], u[i, 1] * dhn[1], u[i, 2] * dhn[2]
        for w in range(13):
            g[w] = c0 * J[0, w] + c1 * J[2, w] + c2 * J[3, w]
        g[0] += u[i, 0] * dh[0]
        g[2] += u[i, 1] * dh[1]
        g[3] += u[i, 2] * dh[2]
        for t in range(3):
            g[6 + t] += h[t] + hn[t]
        for w in range(13):
            g[w] *= -alpha
        for j in range(4):
            g[6 + ref[j]] += 2.0 * psi * (u[i, ref[j]] - uref[j])
        for w in range(6):
            gx[i, w] = g[w]
        for w in range(7):
            gu[i, w] = g[6 + w]
        for w in range(13):
            finite &= math.isfinite(g[w])
    if xN.shape[0]:
        _final_gradient_kernel(xN, V_ref, phi, fe, nu_E, gN)
        for w in range(gN.shape[0]):
            finite &= math.isfinite(gN[w])
    return finite

#: nonzero columns of dV+_r/dw (w = (x, u)) for the turbine reservoirs r = 1, 3, 4 (rows 0, 2, 3 of
#: [_LX | _LU] plus the diagonal entry dV+_r/dV_r), padded with -1
_JCOLS = np.full((3, 7), -1, dtype=np.int64)
for _t, _r in enumerate(_TURBINE_RES):
    _nzc = sorted(set(np.flatnonzero(np.concatenate([_LX[_r], _LU[_r]])).tolist()) | {int(_r)})
    _JCOLS[_t, :len(_nzc)] = _nzc
del _t, _r, _nzc


@nb.njit(cache=True)
def _stage_hessian_kernel(k, x, u, inflow, evap, fa, fh, alpha, psi, sig, p, LX, LU, jcols,
                          hxx, hxu, huu):
    """The blocks (hxx, hxu, huu) of the Hessian of sig[i] f_0 + p[i].f at the stage rows i;
    returns True when every entry is finite."""
    finite = True           # and-ed without branches: no dependency chain of additions
    Vn, dV, d2V = np.empty(4), np.empty(4), np.empty(4)
    h, dh, hn, dhn, d2h = np.empty(3), np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    J = np.empty((4, 13))
    H = np.empty((13, 13))
    ref = (0, 4, 1, 2)
    for i in range(x.shape[0]):
        _volumes(k[i], x[i], u[i], inflow, evap, fa, Vn, dV, d2V)
        _turbine_heads(x[i], Vn, fh, h, dh, hn, dhn, d2h)
        _stage_jacobian_rows(dV, LX, LU, J)
        H[:, :] = 0.0
        for t in range(3):
            r = 0 if t == 0 else t + 1
            # a_t = d/dw of h(V_r) + h(V+_r) = h'(V) e_V + h'(V+) dV+/dw, in row and column 6+t
            for q in range(jcols.shape[1]):
                w = jcols[t, q]
                if w < 0:
                    break
                aw = dhn[t] * J[r, w]
                if w == r:
                    aw += dh[t]
                H[6 + t, w] += aw
                H[w, 6 + t] += aw
        # Q (h''(V) e_V e_V^T + h''(V+) dV+ dV+^T + h'(V+) d2V+)
        for t in range(3):
            r = 0 if t == 0 else t + 1
            c = u[i, t] * (2.0 * fh[0, t])
            for q in range(jcols.shape[1]):
                w = jcols[t, q]
                if w < 0:
                    break
                cw = c * J[r, w]
                for q2 in range(jcols.shape[1]):
                    v = jcols[t, q2]
                    if v < 0:
                        break
                    H[w, v] += cw * J[r, v]
            H[r, r] += u[i, t] * d2h[t] + u[i, t] * dhn[t] * d2V[r]
        # sigma (-alpha H + 2 psi on the reference-outflow diagonal) + p . d2f (evaporation terms)
        s = sig[i]
        for w in range(6):
            for v in range(6):
                hxx[i, w, v] = s * (H[w, v] * -alpha)
            for v in range(7):
                hxu[i, w, v] = s * (H[w, 6 + v] * -alpha)
        for w in range(7):
            for v in range(7):
                huu[i, w, v] = s * (H[6 + w, 6 + v] * -alpha)
        for j in range(4):
            c = ref[j]
            huu[i, c, c] = s * (H[6 + c, 6 + c] * -alpha + 2.0 * psi)
        for j in range(4):
            hxx[i, j, j] += p[i, j] * d2V[j]
        for w in range(6):
            for v in range(6):
                finite &= math.isfinite(hxx[i, w, v])
            for v in range(7):
                finite &= math.isfinite(hxu[i, w, v])
        for w in range(7):
            for v in range(7):
                finite &= math.isfinite(huu[i, w, v])
    return finite


@nb.njit(cache=True)
def _simulate_kernel(drive, evap, fa, u, X):
    """The recursion of eq. (40) from X[0] (Zambezi.simulate): drive = Z + Lu u per stage."""
    v1, v2, v3, v4, d1, d2 = X[0, 0], X[0, 1], X[0, 2], X[0, 3], X[0, 4], X[0, 5]
    A0, A1, A2, A3 = fa[0, 0], fa[0, 1], fa[0, 2], fa[0, 3]
    B0, B1, B2, B3 = fa[1, 0], fa[1, 1], fa[1, 2], fa[1, 3]
    C0, C1, C2, C3 = fa[2, 0], fa[2, 1], fa[2, 2], fa[2, 3]
    for k in range(drive.shape[0]):
        n1 = v1 + drive[k, 0] - evap[k, 0] * ((A0 * v1 + B0) * v1 + C0)
        n2 = v2 + drive[k, 1] - evap[k, 1] * ((A1 * v2 + B1) * v2 + C1)
        n3 = v3 + d2 + drive[k, 2] - evap[k, 2] * ((A2 * v3 + B2) * v3 + C2)
        n4 = v4 + drive[k, 3] - evap[k, 3] * ((A3 * v4 + B3) * v4 + C3)
        v1, v2, v3, v4, d1, d2 = n1, n2, n3, n4, u[k, 4], d1
        X[k + 1, 0], X[k + 1, 1], X[k + 1, 2], X[k + 1, 3], X[k + 1, 4], X[k + 1, 5] = v1, v2, v3, v4, d1, d2


# ============================================================================ compiled evaluations
# Zambezi.compiled_evaluations: the kernels above behind the signatures of olado.problems.compiled,
# with the instance's numbers packed into one float64 array (_pack, offsets _D_*) and the
# stage indices and _JCOLS into one int64 array. The entries hand the kernels views of the same
# types as the Python entry points do (fa, fe, fh Fortran-ordered, _LX, _LU, _JCOLS writable
# arrays rather than numba's read-only constants): the kernels' compiled versions are shared
# (or loaded from numba's cache) instead of being compiled a second time. The four entries are
# compiled (or loaded) on first use, not when this module is imported.

#: offsets in the packed data: alpha, psi, nu_E, then u_ref, V_ref, phi (4 each), fa, fe (3x4) and
#: fh (3x3) in Fortran order, _LX (6x6), _LU (6x7), then inflow and evaporation (N x 4 each)
_D_UREF, _D_VREF, _D_PHI, _D_FA, _D_FE, _D_FH, _D_LX, _D_LU, _D_STAGES = 3, 7, 11, 15, 27, 39, 48, 84, 126

#: _LX and _LU, packed
_LINEAR = np.concatenate((_LX.ravel(), _LU.ravel()))

#: numpy's pairwise sum, compiled (olado.linalg.numpy_sums.pairwise_sum), bound by
#: _compiled_entries before it compiles: olado.problems does not import olado.linalg at module level
_pairwise_sum = None


@nb.njit(cache=True)
def _unpack(data, N):
    """The arrays and weights of the packed data (views of it): inflow, evaporation, fa, fh,
    alpha, psi, u_ref, V_ref, phi, fe, nu_E -- the kernels' arguments in their order."""
    inflow = data[_D_STAGES:_D_STAGES + 4 * N].reshape((N, 4))
    evap = data[_D_STAGES + 4 * N:_D_STAGES + 8 * N].reshape((N, 4))
    return (inflow, evap, data[_D_FA:_D_FE].reshape((4, 3)).T, data[_D_FH:_D_LX].reshape((3, 3)).T, data[0],
            data[1], data[_D_UREF:_D_VREF], data[_D_VREF:_D_PHI], data[_D_PHI:_D_FA],
            data[_D_FE:_D_FH].reshape((4, 3)).T, data[2])


@intrinsic
def _read_only(typingctx, a):
    """``a`` typed as a read-only array (the same data): the stage Hessian kernel's weights as
    :meth:`_Fusion.weights` gives them to it (one compiled version of the kernel, not two)."""
    def codegen(context, builder, signature, args):
        return impl_ret_borrowed(context, builder, signature.return_type, args[0])
    return a.copy(readonly=True)(a), codegen


@nb.njit(cache=True)
def _linear_parts(data):
    """_LX and _LU (views of the packed data)."""
    return data[_D_LX:_D_LU].reshape((6, 6)), data[_D_LU:_D_STAGES].reshape((6, 7))


def _pack(data, idata, k, inflow, evap, fa, fh, alpha, psi, uref, V_ref, phi, fe, nu_E):
    """Write a problem's numbers (the kernels' arguments) into the packed data in the layout
    :func:`_unpack` and :func:`_linear_parts` read, the stage indices k and _JCOLS into idata.
    (numpy, ~4 us at N = 24: a compiled copy would add more than a second to a cold start.)"""
    data[:3] = alpha, psi, nu_E
    np.concatenate((uref, V_ref, phi, fa.ravel("F"), fe.ravel("F"), fh.ravel("F"), _LINEAR, inflow.ravel(),
                    evap.ravel()), out=data[_D_UREF:])
    np.concatenate((k, _JCOLS.ravel()), out=idata)


def _values_entry(data, idata, X, U, f, cost):
    """VALUES: Zambezi.eval_values' f, stage costs and J (NaN when a value is not finite)."""
    N = U.shape[0]
    inflow, evap, fa, fh, alpha, psi, uref, V_ref, phi, fe, nu_E = _unpack(data, N)
    F, finite = _values_kernel(idata[:N], X[:N], U, X[N], inflow, evap, fa, fh, alpha, psi, uref, V_ref, phi, fe,
                               nu_E, f, cost)
    if not finite:
        return np.nan
    return _pairwise_sum(cost, 0, N, False) + F        # float(cost.sum() + F)


def _derivatives_entry(data, idata, X, U, lx, lu, lN, A, B):
    """DERIVATIVES: Zambezi.eval_first_derivatives' lx, lu, lN, A, B."""
    N = U.shape[0]
    inflow, evap, fa, fh, alpha, psi, uref, V_ref, phi, fe, nu_E = _unpack(data, N)
    LX, LU = _linear_parts(data)
    for j in range(lN.shape[0]):
        lN[j] = 0.0
    return _derivatives_kernel(idata[:N], X[:N], U, X[N], inflow, evap, fa, fh, alpha, psi, uref, V_ref, phi, fe,
                               nu_E, LX, LU, lx, lu, A, B, lN)


def _hessians_entry(data, idata, X, U, sigma, P, hxx, hxu, huu):
    """HESSIANS: Zambezi.eval_stage_hessians(X, U, sigma, P)."""
    N = U.shape[0]
    inflow, evap, fa, fh, alpha, psi, _, _, _, _, _ = _unpack(data, N)
    LX, LU = _linear_parts(data)
    jcols = idata[N:].reshape((3, 7))
    sig = _read_only(np.full(N, sigma))
    return _stage_hessian_kernel(idata[:N], X[:N], U, inflow, evap, fa, fh, alpha, psi, sig, P, LX, LU, jcols,
                                 hxx, hxu, huu)


def _final_hessian_entry(data, idata, xN, sigma, H):
    """FINAL_HESSIAN: Zambezi.eval_final_hessian(xN, sigma)."""
    for i in range(H.shape[0]):
        for j in range(H.shape[1]):
            H[i, j] = 0.0
    _final_hessian_kernel(sigma, data[_D_PHI:_D_FA], data[_D_FE:_D_FH].reshape((4, 3)).T, data[2], H)
    return math.isfinite(H[0, 0] + H[1, 1] + H[2, 2] + H[3, 3])


#: the compiled entries (CompiledFunction each, in compiled.KINDS' order), made once per process
_ENTRIES = []
#: the problem.counters keys one call of each entry adds 1 to (those of the Python entry points)
_COUNTS = MappingProxyType({"values": ("stage_cost", "final_cost", "dynamics"),
           "derivatives": ("stage_cost_gradient", "final_cost_gradient", "dynamics_jacobian"),
           "hessians": ("stage_hessian",), "final_hessian": ("final_hessian",)})


def _compiled_entries():
    """The four entries as :class:`olado.problems.compiled.CompiledFunction` (compiled, or loaded
    from numba's cache, on the first call in a process)."""
    global _pairwise_sum
    if not _ENTRIES:
        from ..linalg.numpy_sums import pairwise_sum
        from .compiled import DERIVATIVES, FINAL_HESSIAN, HESSIANS, VALUES, CompiledFunction
        _pairwise_sum = pairwise_sum
        _ENTRIES[:] = [CompiledFunction(nb.njit(sig, cache=True)(fn), sig)
                       for fn, sig in ((_values_entry, VALUES), (_derivatives_entry, DERIVATIVES),
                                       (_hessians_entry, HESSIANS), (_final_hessian_entry, FINAL_HESSIAN))]
    return _ENTRIES
