"""The KKT residual kernel of the interior-point QP: the equations (16)-(20) of paper 001
(sec. 4.2.2) at a point -- stationarity, dynamics and equality rows, the slack rows of the boxes
-- with the measures of the stopping test, in one pass (:func:`_kkt_map`).

The same kernel gives the residuals of an iterate and, with the right-hand side's residuals as
offsets, the residual of the unreduced Newton system (22) at a direction (the measurement that
decides on iterative refinement), and the linear maps of the infeasibility certificates. For
small blocks it is compiled for the sizes (size tags, :mod:`olado.linalg.codegen`) with the
stages as straight-line SIMD code (:func:`_kkt_stage`, :func:`_kkt_boxes`); otherwise, or for
arrays that are not C-contiguous, the loop kernel :func:`_kkt_map_loops` runs.
"""

from __future__ import annotations

import numba as nb
import numpy as np
from llvmlite import ir as llir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic, overload

from ...linalg.codegen import F64, I32, I64, REASSOC, ContractRowCode, SizeTags, as_bundle, pieces, stack_vector
from .bundles import KKTData, PointArrays, Residuals



def _size(x):
    """Block size from a size argument of a compiled kernel: an int (run-time size) or a size tag
    (olado.linalg.codegen.size_tags: a tuple whose length is the size, a compile-time constant)."""
    return x if isinstance(x, int) else len(x)


@overload(_size)
def _size_overload(x):
    if isinstance(x, types.Integer):
        return lambda x: x
    return lambda x: len(x)


def _work(x):
    """A float workspace of size _size(x): on the heap for an int, on the stack for a size tag."""
    return np.empty(_size(x))


@overload(_work)
def _work_overload(x):
    if isinstance(x, types.Integer):
        return lambda x: np.empty(x)
    return lambda x: stack_vector(x)


@nb.njit(inline="always")
def _add_row_terms(k, nz, ne, nc, os_, nu, eqm, EF, C, zl, zu, g):
    """g += sum_l nu_kl eqm_kl [E F]_k[l, :] + sum_l (zu - zl)_(stage row l) C_k[l, :]: the stage
    rows' part of the Lagrangian gradient of stage k (both _kkt_map kernels)."""
    for l in range(ne):
        t = nu[k, l] * eqm[k, l]
        if t != 0.0:
            for i in range(nz):
                g[i] += EF[k, l, i] * t
    for l in range(nc):
        idx = os_ + k * nc + l
        t = zu[idx] - zl[idx]
        if t != 0.0:
            for i in range(nz):
                g[i] += C[k, l, i] * t


@nb.njit(inline="always")
def _kkt_final_stage(N, n, QN, X, lam, nu, EN, CN, zl, zu, bx, bx0, beN, rx, x0r, rEN, w, osN, hz, g,
                     dmax, xmax, hmax, obj, pmax):
    """The final stage of _kkt_map (both kernels): rx[N], x0r, rEN, the final rows' values
    C_N x_N into w, and the measures updated (hz, g: work vectors of length >= n)."""
    ncN = CN.shape[0]
    neN = EN.shape[0]
    for i in range(n):
        t = 0.0
        for j in range(n):
            t += QN[i, j] * X[N, j]
        hz[i] = t
    for i in range(n):
        g[i] = hz[i] - lam[N, i]
    for l in range(neN):
        t = nu[N, l]
        for i in range(n):
            g[i] += EN[l, i] * t
    if N >= 1:
        for i in range(n):
            idx = (N - 1) * n + i
            g[i] += zu[idx] - zl[idx]
    for l in range(ncN):
        t = zu[osN + l] - zl[osN + l]
        for i in range(n):
            g[i] += CN[l, i] * t
    for i in range(n):
        v = g[i] + bx[N, i]
        rx[N, i] = v
        dmax = max(dmax, abs(v))
        xmax = max(xmax, abs(X[N, i]))
        hmax = max(hmax, abs(hz[i]))
        obj += 0.5 * X[N, i] * hz[i] + bx[N, i] * X[N, i]
    for i in range(n):
        v = bx0[i] - X[0, i]
        x0r[i] = v
        pmax = max(pmax, abs(v))
    for l in range(neN):
        s = 0.0
        for j in range(n):
            s += EN[l, j] * X[N, j]
        v = s + beN[l]
        rEN[l] = v
        pmax = max(pmax, abs(v))
    for l in range(ncN):
        s = 0.0
        for j in range(n):
            s += CN[l, j] * X[N, j]
        w[osN + l] = s
    return dmax, xmax, hmax, obj, pmax


@nb.njit(inline="always")
def _kkt_row_boxes(i0, i1, al, au, fl, fu, tl, tu, zl, zu, rl, rup, w, pmax, comp):
    """The box residuals rl, rup of the flat boxes i0..i1-1 of _kkt_map (values w), the primal
    max-norm and the complementarity sum updated."""
    for idx in range(i0, i1):
        comp += zl[idx] * tl[idx] + zu[idx] * tu[idx]
        if fl[idx]:
            v = w[idx] + al[idx] - tl[idx]
            rl[idx] = v
            pmax = max(pmax, abs(v))
        else:
            rl[idx] = 0.0
        if fu[idx]:
            v = au[idx] - w[idx] - tu[idx]
            rup[idx] = v
            pmax = max(pmax, abs(v))
        else:
            rup[idx] = 0.0
    return pmax, comp


@nb.njit(cache=True, fastmath=REASSOC)
def _kkt_map_loops(sizes, data, point, offsets, out, w, stats):
    """_kkt_map with loops over the blocks (the any-size kernel; see _kkt_map)."""
    data = as_bundle(data, KKTData)
    H, QN, AB, EF, EFt, eqm, EN = data.H, data.QN, data.AB, data.EF, data.EFt, data.eqm, data.EN
    C, Ct, CN, fl, fu = data.C, data.Ct, data.CN, data.fl, data.fu
    point = as_bundle(point, PointArrays)
    X, U, lam, nu, tl, tu, zl, zu = point.X, point.U, point.lam, point.nu, point.tl, point.tu, point.zl, point.zu
    offsets = as_bundle(offsets, Residuals)
    bx, bu, bdyn, bx0, be, beN = offsets.rx, offsets.ru, offsets.dyn, offsets.x0r, offsets.rE, offsets.rEN
    al, au = offsets.rl, offsets.rup
    out = as_bundle(out, Residuals)
    rx, ru, dyn, x0r, rE, rEN, rl, rup = out.rx, out.ru, out.dyn, out.x0r, out.rE, out.rEN, out.rl, out.rup
    nt, mt, zt = sizes[0], sizes[1], sizes[2]
    n, m, nz = _size(nt), _size(mt), _size(zt)
    z, hz, g, ax = _work(zt), _work(zt), _work(zt), _work(nt)
    N = AB.shape[0]
    ne = EF.shape[1]
    nc = C.shape[1]
    ou = N * n
    os_ = ou + N * m
    osN = os_ + N * nc
    ae = np.empty(max(ne, 1))
    ac = np.empty(max(nc, 1))
    pmax = 0.0
    dmax = 0.0
    xmax = 0.0
    hmax = 0.0
    obj = 0.0
    for k in range(N):
        for i in range(n):
            z[i] = X[k, i]
        for i in range(m):
            z[n + i] = U[k, i]
        for i in range(nz):
            t = 0.0
            for j in range(nz):
                t += H[k, i, j] * z[j]
            hz[i] = t
        for i in range(n):
            t = 0.0
            for j in range(nz):
                t += AB[k, i, j] * z[j]
            ax[i] = t
        for i in range(ne):
            ae[i] = 0.0
        for i in range(nc):
            ac[i] = 0.0
        for j in range(nz):
            t = z[j]
            for i in range(ne):
                ae[i] += EFt[k, j, i] * t
            for i in range(nc):
                ac[i] += Ct[k, j, i] * t
        for i in range(nz):
            g[i] = hz[i]
        # constraint part of the Lagrangian gradient
        for l in range(n):
            t = lam[k + 1, l]
            for i in range(nz):
                g[i] += AB[k, l, i] * t
        for i in range(n):
            g[i] -= lam[k, i]
        _add_row_terms(k, nz, ne, nc, os_, nu, eqm, EF, C, zl, zu, g)
        if k >= 1:
            for i in range(n):
                idx = (k - 1) * n + i
                g[i] += zu[idx] - zl[idx]
        for i in range(m):
            idx = ou + k * m + i
            g[n + i] += zu[idx] - zl[idx]
        for i in range(n):
            v = g[i] + bx[k, i]
            rx[k, i] = v
            dmax = max(dmax, abs(v))
        for i in range(m):
            v = g[n + i] + bu[k, i]
            ru[k, i] = v
            dmax = max(dmax, abs(v))
        # measures
        for i in range(nz):
            xmax = max(xmax, abs(z[i]))
            hmax = max(hmax, abs(hz[i]))
            obj += 0.5 * z[i] * hz[i]
        for i in range(n):
            obj += bx[k, i] * z[i]
        for i in range(m):
            obj += bu[k, i] * z[n + i]
        # dynamics, equality rows
        for i in range(n):
            v = ax[i] - X[k + 1, i] + bdyn[k, i]
            dyn[k, i] = v
            pmax = max(pmax, abs(v))
        for l in range(ne):
            v = ae[l] * eqm[k, l] + be[k, l]
            rE[k, l] = v
            pmax = max(pmax, abs(v))
        # box values w of x_k (k >= 1), u_k and C_k z_k
        if k >= 1:
            for i in range(n):
                w[(k - 1) * n + i] = z[i]
        for i in range(m):
            w[ou + k * m + i] = z[n + i]
        for l in range(nc):
            w[os_ + k * nc + l] = ac[l]
    # final stage
    dmax, xmax, hmax, obj, pmax = _kkt_final_stage(N, n, QN, X, lam, nu, EN, CN, zl, zu, bx, bx0, beN, rx, x0r, rEN,
                                                   w, osN, hz, g, dmax, xmax, hmax, obj, pmax)
    if N >= 1:
        for i in range(n):
            w[(N - 1) * n + i] = X[N, i]
    pmax, comp = _kkt_row_boxes(0, w.shape[0], al, au, fl, fu, tl, tu, zl, zu, rl, rup, w, pmax, 0.0)
    stats[0] = pmax
    stats[1] = dmax
    stats[2] = xmax
    stats[3] = hmax
    stats[4] = obj
    stats[5] = comp


# The fixed-size _kkt_map (_kkt_map_fixed): the stage loop calls _kkt_stage, an intrinsic that
# writes one stage as straight-line SIMD code on pieces of 4, 2 and 1 doubles (as _eliminate_stage
# in olado.linalg.riccati_fixed, with the helpers of olado.linalg.codegen): H z = sum_j z_j H[j, :] and
# g = H z + sum_l lam_{k+1,l} [A B][l, :] as axpys over the rows of H and [A B] (H is symmetric),
# [A B] z as row products summed by a transposing reduction.  The box residuals follow in a
# second pass over the flat box vectors, branch-free (selects on the fl/fu masks) in chunks of
# _KKT_CHUNK entries (_kkt_boxes): fused into the stage pass they would add some 20 concurrent
# memory streams, which made it slower than the scalar loops once the arrays leave the caches.
# The measures stay in vector accumulators on the stack (maxima as select(v > acc, v, acc) lane by
# lane, exactly what max(acc, v) does: NaN is skipped, inf kept; sums reassociated), reduced at
# the end (_kkt_acc_reduce).
_KKT_MAX = ("p", "d", "x", "h", "bp")   # max |primal| (stages, boxes), max |dual|, max |z|, max |H z|
_KKT_SUM = ("oh", "ob", "bc")           # sum z.H z, sum b.z, sum zl tl + zu tu
_KKT_CHUNK = 8                          # box entries per _kkt_boxes
_I8 = llir.IntType(8)


def _kkt_layouts(n, m):
    """(box pieces, matrix pieces, accumulator slots {(name, width): offset}, carry offset, size)
    of _kkt_stage: box pieces cover x (columns 0..n-1) and u (n..n+m-1) separately, matrix pieces
    the n + m columns of z; the carry holds the multipliers zu - zl of x_{k+1} for stage k + 1."""
    bp = pieces(0, n) + pieces(n, m)
    mp = pieces(0, n + m)
    bw = sorted({w for _, w in bp})
    mw = sorted({w for _, w in mp})
    slots, off = {}, 0
    for name in _KKT_MAX + _KKT_SUM:
        for w in (mw if name in ("h", "oh") else [4] if name in ("bp", "bc") else bw):
            slots[(name, w)] = off
            off += w
    return bp, mp, slots, off, off + n


class _KktRowCode(ContractRowCode):
    """ContractRowCode (olado.linalg.codegen) with what _kkt_stage needs besides: absolute
    values, maxima with max()'s semantics, masks, conversions between piece layouts."""

    def const(self, x, w):
        return llir.Constant(self.vtype(w), x if w == 1 else [x] * w)

    def abs(self, v, w):
        fn = cgutils.get_or_insert_function(self.b.module, llir.FunctionType(self.vtype(w), [self.vtype(w)]),
                                            "llvm.fabs.f64" if w == 1 else f"llvm.fabs.v{w}f64")
        return self.b.call(fn, [v])

    def max(self, acc, v):
        """max(acc, v) of numba (lane by lane): v if v > acc else acc."""
        return self.b.select(self.b.fcmp_ordered(">", v, acc), v, acc)

    def at(self, data, offset):
        return self.b.gep(data, [offset])

    def row(self, data, pieces, shift=0):
        """The pieces of a row at data (column c0 at data + c0 - shift)."""
        return [(c0, w, self.load(data, 0, 0, c0 - shift, w)) for c0, w in pieces]

    def mask(self, data, j, w):
        """Lanes j..j+w-1 of a boolean array as i1 (vector)."""
        p = self.b.gep(data, [llir.Constant(I64, j)])
        if w > 1:
            p = self.b.bitcast(p, llir.VectorType(_I8, w).as_pointer())
        v = self.b.load(p, align=1)
        return self.b.icmp_unsigned("!=", v, llir.Constant(v.type, None))

    def repiece(self, row, pieces):
        """The same values in other pieces (shuffles)."""
        have = {(c0, w): v for c0, w, v in row}
        out = []
        for c0, w in pieces:
            if (c0, w) in have:
                out.append((c0, w, have[(c0, w)]))
            elif w == 1:
                out.append((c0, w, self.entry(row, c0)))
            else:
                v = llir.Constant(self.vtype(w), llir.Undefined)
                for j in range(w):
                    v = self.b.insert_element(v, self.entry(row, c0 + j), llir.Constant(I32, j))
                out.append((c0, w, v))
        return out


def _is_c_array(t, dtype=types.float64, ndim=None):
    return isinstance(t, types.Array) and t.dtype == dtype and t.layout == "C" and (ndim is None or t.ndim == ndim)


@intrinsic
def _kkt_acc(typingctx, tags):
    """The accumulators (and the carry) of _kkt_stage on the stack, zeroed."""
    n, m = len(tags[0]), len(tags[1])
    size = _kkt_layouts(n, m)[4]

    def codegen(context, builder, signature, args):
        p = cgutils.alloca_once(builder, F64, size=context.get_constant(types.intp, size))
        for i in range(size):
            builder.store(llir.Constant(F64, 0.0), builder.gep(p, [llir.Constant(I64, i)]))
        return p
    return types.CPointer(types.float64)(tags), codegen


@intrinsic
def _kkt_acc_reduce(typingctx, tags, acc):
    """(max |primal|, max |dual|, max |z|, max |H z|, objective, complementarity) of the
    accumulators of _kkt_stage."""
    n, m = len(tags[0]), len(tags[1])
    slots = _kkt_layouts(n, m)[2]

    def codegen(context, builder, signature, args):
        g = _KktRowCode(builder)
        p = args[1]
        out = {}
        for (name, w), off in slots.items():
            name = {"bp": "p", "bc": "c"}.get(name, name)
            for j in range(w):
                v = g.load(p, 0, 0, off + j)
                if name not in out:
                    out[name] = v
                elif name in ("p", "d", "x", "h"):
                    out[name] = g.max(out[name], v)
                else:
                    out[name] = g.add(out[name], v)
        obj = g.add(g.mul(llir.Constant(F64, 0.5), out["oh"]), out["ob"])
        vals = [out["p"], out["d"], out["x"], out["h"], obj, out["c"]]
        return context.make_tuple(builder, signature.return_type, vals)
    return types.UniTuple(types.float64, 6)(tags, acc), codegen


@intrinsic
def _kkt_stage(typingctx, tags, k, ou, H, AB, X, U, lam, bx, bu, bdyn, rx, ru, dyn, zl, zu, ge, acc):
    """Stage k of _kkt_map_fixed as straight-line SIMD code (see the comment above): for the
    sizes of tags = size_tags(n, m) and C-contiguous float64 arrays of the shapes of
    _kkt_map; ou = N n (the offset of the u boxes), ge = None or the stage's further gradient
    terms E^T nu + C^T (zu - zl) (n + m values), acc from _kkt_acc.  Writes rx[k], ru[k],
    dyn[k]; updates the accumulators and carries zu - zl of x_{k+1} to stage k + 1."""
    if not (all(_is_c_array(a) for a in (H, AB, X, U, lam, bx, bu, bdyn, rx, ru, dyn, zl, zu))
            and (ge == types.none or _is_c_array(ge, ndim=1))
            and isinstance(k, types.Integer) and isinstance(ou, types.Integer)):
        return None
    n, m = len(tags[0]), len(tags[1])
    nz = n + m
    bp, mp, slots, carry, _ = _kkt_layouts(n, m)
    xp, up = bp[:len(pieces(0, n))], bp[len(pieces(0, n)):]
    W = max(w_ for _, w_ in mp)
    names = ("H", "AB", "X", "U", "lam", "bx", "bu", "bdyn", "rx", "ru", "dyn", "zl", "zu", "ge")

    def codegen(context, builder, signature, args):
        g = _KktRowCode(builder)
        data = {name: context.make_array(t)(context, builder, v).data
                for name, t, v in zip(names, signature.args[3:-1], args[3:-1]) if t != types.none}
        accp = args[-1]
        c = lambda v: llir.Constant(I64, v)  # noqa: E731
        kk = builder.sext(args[1], I64) if args[1].type.width < 64 else args[1]
        oub = builder.sext(args[2], I64) if args[2].type.width < 64 else args[2]
        kn, km = builder.mul(kk, c(n)), builder.mul(kk, c(m))
        Hk = g.at(data["H"], builder.mul(kk, c(nz * nz)))
        ABk = g.at(data["AB"], builder.mul(kk, c(n * nz)))
        Xk, Xk1 = g.at(data["X"], kn), g.at(data["X"], builder.add(kn, c(n)))
        Uk = g.at(data["U"], km)
        lamk, lamk1 = g.at(data["lam"], kn), g.at(data["lam"], builder.add(kn, c(n)))
        bxk, buk, bdk = g.at(data["bx"], kn), g.at(data["bu"], km), g.at(data["bdyn"], kn)
        rxk, ruk, dynk = g.at(data["rx"], kn), g.at(data["ru"], km), g.at(data["dyn"], kn)
        ouk = builder.add(oub, km)       # flat offsets of the boxes of x_{k+1} (kn) and u_k
        acc = {key: g.load(accp, 0, 0, off, key[1]) for key, off in slots.items() if key[0] not in ("bp", "bc")}

        def acc_max(name, v, w_):
            acc[(name, w_)] = g.max(acc[(name, w_)], g.abs(v, w_))

        def acc_add(name, v, w_):
            acc[(name, w_)] = g.add(acc[(name, w_)], v)

        # ---- loads
        zB = g.row(Xk, xp) + g.row(Uk, up, n)            # z in box pieces
        zM = g.repiece(zB, mp)                           # z in matrix pieces
        zs = [g.load(Xk, 0, 0, j) if j < n else g.load(Uk, 0, 0, j - n) for j in range(nz)]
        xn = g.row(Xk1, xp)
        bB = g.row(bxk, xp) + g.row(buk, up, n)
        zdiff = lambda o, c0, w_: g.sub(g.load(g.at(data["zu"], o), 0, 0, c0, w_),  # noqa: E731
                                        g.load(g.at(data["zl"], o), 0, 0, c0, w_))
        dx = [(c0, w_, zdiff(kn, c0, w_)) for c0, w_ in xp]          # zu - zl of x_{k+1}
        du = [(c0, w_, zdiff(ouk, c0 - n, w_)) for c0, w_ in up]     # zu - zl of u_k
        # ---- H z = sum_j z_j H[j, :], g = H z + sum_l lam_{k+1,l} AB[l, :]
        hz = g.scale(g.row(Hk, mp), zs[0])
        for j in range(1, nz):
            hz = g.axpy(hz, zs[j], g.row(g.at(Hk, c(j * nz)), mp))
        ABrows = [g.row(g.at(ABk, c(l * nz)), mp) for l in range(n)]
        gr = hz
        for l in range(n):
            gr = g.axpy(gr, g.load(lamk1, 0, 0, l), ABrows[l])
        if "ge" in data:
            gr = [(c0, w_, g.add(v, u)) for (c0, w_, v), (_, _, u) in zip(gr, g.row(data["ge"], mp))]
        # ---- [A B] z: the products of the full-width pieces summed by rows (a transposing
        # reduction), those of narrower pieces added by columns
        full = [c0 for c0, w_ in mp if w_ == W]
        narrow = [j for c0, w_ in mp if w_ < W for j in range(c0, c0 + w_)]
        zMd = {c0: v for c0, w_, v in zM}
        V = []
        for l in range(n):
            rowd = {c0: v for c0, w_, v in ABrows[l]}
            s = g.mul(rowd[full[0]], zMd[full[0]])
            for c0 in full[1:]:
                s = g.add(s, g.mul(rowd[c0], zMd[c0]))
            V.append(s)
        ax = []
        for r0, wo in xp:
            v = g.row_sums(V[r0:r0 + wo], W)
            v = v if wo == W else g.lanes(v, 0, wo)
            for j in narrow:        # column j of the rows r0.. of AB
                col = g.repiece([(r0 + i, 1, g.load(ABk, nz, r0 + i, j)) for i in range(wo)], [(r0, wo)])[0][2]
                v = g.add(v, g.mul(col, g.splat(zs[j], wo)))
            ax.append((r0, wo, v))
        # ---- measures
        for (c0, w_, zv), (_, _, bv) in zip(zB, bB):
            acc_max("x", zv, w_)
            acc_add("ob", g.mul(bv, zv), w_)
        for (c0, w_, hv), (_, _, zv) in zip(hz, zM):
            acc_max("h", hv, w_)
            acc_add("oh", g.mul(zv, hv), w_)
        stores = []
        # ---- gradient rows rx[k], ru[k]
        gB = g.repiece(gr, bp)
        for c0, w_, v in gB[:len(xp)]:
            v = g.add(g.add(g.sub(v, g.load(lamk, 0, 0, c0, w_)), g.load(accp, 0, 0, carry + c0, w_)),
                      g.load(bxk, 0, 0, c0, w_))
            stores.append((v, rxk, c0, w_))
            acc_max("d", v, w_)
        for (c0, w_, v), (_, _, d) in zip(gB[len(xp):], du):
            v = g.add(g.add(v, d), g.load(buk, 0, 0, c0 - n, w_))
            stores.append((v, ruk, c0 - n, w_))
            acc_max("d", v, w_)
        # ---- dynamics
        for (r0, w_, a), (_, _, xv) in zip(ax, xn):
            v = g.add(g.sub(a, xv), g.load(bdk, 0, 0, r0, w_))
            stores.append((v, dynk, r0, w_))
            acc_max("p", v, w_)
        # ---- stores (after all loads)
        for c0, w_, d in dx:
            stores.append((d, accp, carry + c0, w_))
        for v, p, j, w_ in stores:
            g.store(v, p, 0, 0, j, w_)
        for key, v in acc.items():
            g.store(v, accp, 0, 0, slots[key], key[1])
        return context.get_dummy_value()
    return types.none(tags, k, ou, H, AB, X, U, lam, bx, bu, bdyn, rx, ru, dyn, zl, zu, ge, acc), codegen


@intrinsic
def _kkt_boxes(typingctx, tags, src, so, i0, al, au, fl, fu, tl, tu, zl, zu, rl, rup, w, acc):
    """The box residuals of _KKT_CHUNK entries i0.. of the flat box vectors with the values
    w[i0 + j] = src.flat[so + j], branch-free (selects on the masks fl, fu); updates the box
    accumulators ("bp", "bc") of acc."""
    if not (all(_is_c_array(a) for a in (src, al, au, tl, tu, zl, zu, rl, rup, w))
            and _is_c_array(fl, types.boolean, 1) and _is_c_array(fu, types.boolean, 1)
            and isinstance(so, types.Integer) and isinstance(i0, types.Integer)):
        return None
    slots = _kkt_layouts(len(tags[0]), len(tags[1]))[2]
    names = ("al", "au", "fl", "fu", "tl", "tu", "zl", "zu", "rl", "rup", "w")

    def codegen(context, builder, signature, args):
        g = _KktRowCode(builder)
        sx = lambda v: builder.sext(v, I64) if v.type.width < 64 else v  # noqa: E731
        so_, i0_ = sx(args[2]), sx(args[3])
        vals = g.at(context.make_array(signature.args[1])(context, builder, args[1]).data, so_)
        data = {}
        for name, t, v in zip(names, signature.args[4:-1], args[4:-1]):
            p = context.make_array(t)(context, builder, v).data
            data[name] = g.at(builder.bitcast(p, _I8.as_pointer()) if name in ("fl", "fu") else p, i0_)
        accp = args[-1]
        ap, ac = g.load(accp, 0, 0, slots[("bp", 4)], 4), g.load(accp, 0, 0, slots[("bc", 4)], 4)
        stores = []
        for j, w_ in pieces(0, _KKT_CHUNK):
            v = g.load(vals, 0, 0, j, w_)
            ld = {name: g.load(data[name], 0, 0, j, w_) for name in ("al", "au", "tl", "tu", "zl", "zu")}
            zero = g.const(0.0, w_)
            vl = builder.select(g.mask(data["fl"], j, w_), g.sub(g.add(v, ld["al"]), ld["tl"]), zero)
            vu = builder.select(g.mask(data["fu"], j, w_), g.sub(g.sub(ld["au"], v), ld["tu"]), zero)
            stores += [(v, data["w"], j, w_), (vl, data["rl"], j, w_), (vu, data["rup"], j, w_)]
            ap = g.max(ap, g.abs(vl, w_))
            ap = g.max(ap, g.abs(vu, w_))
            ac = g.add(ac, g.add(g.mul(ld["zl"], ld["tl"]), g.mul(ld["zu"], ld["tu"])))
        for v, p, j, w_ in stores:
            g.store(v, p, 0, 0, j, w_)
        g.store(ap, accp, 0, 0, slots[("bp", 4)], 4)
        g.store(ac, accp, 0, 0, slots[("bc", 4)], 4)
        return context.get_dummy_value()
    return types.none(tags, src, so, i0, al, au, fl, fu, tl, tu, zl, zu, rl, rup, w, acc), codegen


@nb.njit(inline="always", fastmath=REASSOC)
def _kkt_boxes_range(tags, src, so, start, stop, al, au, fl, fu, tl, tu, zl, zu, rl, rup, w, acc, pmax, comp):
    """The box residuals of the entries start..stop-1 with the values w[i] = src.flat[so + i - start]
    (_kkt_boxes on chunks, a loop on the rest); returns the updated (pmax, comp) of the rest."""
    i = start
    while i + _KKT_CHUNK <= stop:
        _kkt_boxes(tags, src, so + i - start, i, al, au, fl, fu, tl, tu, zl, zu, rl, rup, w, acc)
        i += _KKT_CHUNK
    vals = src.reshape(src.size)
    for idx in range(i, stop):
        w[idx] = vals[so + idx - start]
    return _kkt_row_boxes(i, stop, al, au, fl, fu, tl, tu, zl, zu, rl, rup, w, pmax, comp)


@nb.njit(cache=True, fastmath=REASSOC)
def _kkt_map_fixed(tags, data, point, offsets, out, w, stats):
    """_kkt_map for the sizes of tags = size_tags(n, m) and C-contiguous arrays: the
    stages by _kkt_stage, the stage-row and equality terms, the final stage and the boxes of the
    stage and final rows by loops."""
    data = as_bundle(data, KKTData)
    H, QN, AB, EF, EFt, eqm, EN = data.H, data.QN, data.AB, data.EF, data.EFt, data.eqm, data.EN
    C, CN, fl, fu = data.C, data.CN, data.fl, data.fu
    point = as_bundle(point, PointArrays)
    X, U, lam, nu, tl, tu, zl, zu = point.X, point.U, point.lam, point.nu, point.tl, point.tu, point.zl, point.zu
    offsets = as_bundle(offsets, Residuals)
    bx, bu, bdyn, bx0, be, beN = offsets.rx, offsets.ru, offsets.dyn, offsets.x0r, offsets.rE, offsets.rEN
    al, au = offsets.rl, offsets.rup
    out = as_bundle(out, Residuals)
    rx, ru, dyn, x0r, rE, rEN, rl, rup = out.rx, out.ru, out.dyn, out.x0r, out.rE, out.rEN, out.rl, out.rup
    tags = as_bundle(tags, SizeTags)
    nt, mt, zt = tags.n, tags.m, tags.nz
    n, m, nz = len(nt), len(mt), len(zt)
    N = AB.shape[0]
    ne = EF.shape[1]
    nc = C.shape[1]
    ou = N * n
    os_ = ou + N * m
    osN = os_ + N * nc
    acc = _kkt_acc(tags)
    pmax = 0.0
    if ne > 0 or nc > 0:
        ge = stack_vector(zt)
        for k in range(N):
            for i in range(nz):
                ge[i] = 0.0
            _add_row_terms(k, nz, ne, nc, os_, nu, eqm, EF, C, zl, zu, ge)
            _kkt_stage(tags, k, ou, H, AB, X, U, lam, bx, bu, bdyn, rx, ru, dyn, zl, zu, ge, acc)
            for l in range(ne):
                s = 0.0
                for j in range(n):
                    s += EFt[k, j, l] * X[k, j]
                for j in range(m):
                    s += EFt[k, n + j, l] * U[k, j]
                v = s * eqm[k, l] + be[k, l]
                rE[k, l] = v
                pmax = max(pmax, abs(v))
            for l in range(nc):
                s = 0.0
                for j in range(n):
                    s += C[k, l, j] * X[k, j]
                for j in range(m):
                    s += C[k, l, n + j] * U[k, j]
                w[os_ + k * nc + l] = s
    else:
        for k in range(N):
            _kkt_stage(tags, k, ou, H, AB, X, U, lam, bx, bu, bdyn, rx, ru, dyn, zl, zu, None, acc)
    # boxes of x_1..x_N (values X[1:]) and u (values U)
    pmax, comp = _kkt_boxes_range(tags, X, n, 0, ou, al, au, fl, fu, tl, tu, zl, zu, rl, rup, w, acc, pmax, 0.0)
    pmax, comp = _kkt_boxes_range(tags, U, 0, ou, os_, al, au, fl, fu, tl, tu, zl, zu, rl, rup, w, acc, pmax, comp)
    p_acc, dmax, xmax, hmax, obj, c_acc = _kkt_acc_reduce(tags, acc)
    pmax = max(pmax, p_acc)
    comp += c_acc
    # final stage
    hz = stack_vector(nt)
    g = stack_vector(nt)
    dmax, xmax, hmax, obj, pmax = _kkt_final_stage(N, n, QN, X, lam, nu, EN, CN, zl, zu, bx, bx0, beN, rx, x0r, rEN,
                                                   w, osN, hz, g, dmax, xmax, hmax, obj, pmax)
    # boxes of the stage and final rows
    pmax, comp = _kkt_row_boxes(os_, w.shape[0], al, au, fl, fu, tl, tu, zl, zu, rl, rup, w, pmax, comp)
    stats[0] = pmax
    stats[1] = dmax
    stats[2] = xmax
    stats[3] = hmax
    stats[4] = obj
    stats[5] = comp


def _kkt_map_kernel(sizes, data, point, offsets, out, w, stats):
    """_kkt_map_fixed or _kkt_map_loops, chosen by the argument types."""


def _kkt_fixed_applies(sizes, data, point, offsets, out, w, stats):
    """Whether _kkt_map with arguments of these numba types runs _kkt_map_fixed: size tags of
    n, m >= 1 and C-contiguous arrays where _kkt_stage and _kkt_boxes read and write."""
    tagged = (isinstance(sizes, types.BaseTuple) and len(sizes) == len(SizeTags._fields)
              and all(isinstance(t, types.BaseTuple) for t in sizes))

    def field(bundle, cls, name):
        return bundle.types[cls._fields.index(name)]
    floats = ([field(data, KKTData, f) for f in ("H", "AB")]
              + [field(point, PointArrays, f) for f in PointArrays._fields if f != "nu"]
              + [field(b, Residuals, f) for b in (offsets, out) for f in ("rx", "ru", "dyn", "rl", "rup")] + [w])
    return (tagged and len(sizes[0]) > 0 and len(sizes[1]) > 0 and all(_is_c_array(a) for a in floats)
            and _is_c_array(field(data, KKTData, "fl"), types.boolean, 1)
            and _is_c_array(field(data, KKTData, "fu"), types.boolean, 1))


@overload(_kkt_map_kernel)
def _kkt_map_kernel_overload(sizes, data, point, offsets, out, w, stats):
    kernel = _kkt_map_fixed if _kkt_fixed_applies(sizes, data, point, offsets, out, w, stats) else _kkt_map_loops

    def impl(sizes, data, point, offsets, out, w, stats):
        kernel(sizes, data, point, offsets, out, w, stats)
    return impl


@nb.njit(cache=True)
def _kkt_map(sizes, data, point, offsets, out, w, stats):
    """The equations of the KKT system (16)-(20) at a point with offsets b:

        rx, ru = H z + (A^T lam_+ - lam, B^T lam_+) + E^T nu + C^T (zu - zl) + box (zu - zl) + (bx, bu)
        dyn = A x + B u - x_+ + bdyn,  x0r = bx0 - x_0,  rE = E z + be,  rEN = E_N x_N + beN
        rl = w + al - tl,  rup = au - w - tu   (finite sides)

    The arguments are bundles (plain tuples with the fields of bundles.py): ``data`` the stage
    data (KKTData: H, QN, AB, EF, EFt, eqm, EN, C, Ct, CN and the finite sides fl, fu of the
    boxes), ``point`` the point (PointArrays: X, U, lam, nu, tl, tu, zl, zu), ``offsets`` the
    offsets b (Residuals: bx, bu, bdyn, bx0, be, beN, al, au in the fields rx, ru, dyn, x0r, rE,
    rEN, rl, rup), ``out`` the residuals (Residuals); ``w`` receives the box values.
    With b = (q, r, c, x0, e, eN), al = -lo, au = hi these are the residuals of the iterate; with
    b = the right-hand side's residuals, the Newton residual of a direction (22). stats
    receives max |primal parts|, max |rx, ru|, max |X, U|, max |H z|, 1/2 z.H z + bx.X + bu.U and
    the complementarity sum(zl tl + zu tu).
    H (N, n+m, n+m) and QN are symmetric (the symmetric parts of the QP's blocks), so H z is
    computed row-wise; AB = [A B] serves both A x + B u (rows) and A^T lam, B^T lam (axpy).
    ``sizes`` = (n, m, n + m) as ints, or size tags (olado.linalg.codegen.size_tags) for a kernel
    compiled for those sizes: _kkt_map_fixed (straight-line SIMD stages) when the arrays are
    C-contiguous (as in the solver), else the loop kernel _kkt_map_loops."""
    _kkt_map_kernel(sizes, data, point, offsets, out, w, stats)
