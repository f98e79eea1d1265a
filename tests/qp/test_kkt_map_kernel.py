"""The fixed-size _kkt_map kernel (straight-line SIMD stages, olado.qp.interior_point.kkt_map._kkt_stage and
_kkt_boxes) against numpy formulas and the any-size (scalar-loop) kernel: random data for several
block sizes with and without stage rows and equality rows, a prepared QP and non-finite inputs."""

import sys
from pathlib import Path

import numpy as np
import pytest
from numba import typeof

from olado.linalg.codegen import size_tags
from olado.qp.interior_point import kkt_map as qp_ip
from olado.qp.interior_point.bundles import KKTData, PointArrays, Residuals
from olado.qp.interior_point.presolve import _Prepared
from olado.qp.interior_point import MehrotraQP

from fixtures.qp_problems import random_qp  # noqa: E402

OUTPUTS = ("rx", "ru", "dyn", "x0r", "rE", "rEN", "rl", "rup", "w", "stats")


def random_args(seed, N, n, m, ne=0, nc=0, neN=0, ncN=0):
    """The arguments of _kkt_map (without sizes) as a dict: random data, masks and point."""
    rng = np.random.default_rng(seed)
    nz = n + m
    H = rng.standard_normal((N, nz, nz))
    H = 0.5 * (H + H.transpose(0, 2, 1))
    QN = rng.standard_normal((n, n))
    QN = 0.5 * (QN + QN.T)
    AB = rng.standard_normal((N, n, nz))
    EF = rng.standard_normal((N, ne, nz))
    eqm = (rng.uniform(size=(N, ne)) < 0.7).astype(float)
    C = rng.standard_normal((N, nc, nz))
    nw = N * nz + N * nc + ncN
    n_nu = max(ne, neN, 1)
    d = dict(H=H, QN=QN, AB=AB, EF=EF, EFt=np.ascontiguousarray(EF.transpose(0, 2, 1)), eqm=eqm,
             EN=rng.standard_normal((neN, n)), C=C, Ct=np.ascontiguousarray(C.transpose(0, 2, 1)),
             CN=rng.standard_normal((ncN, n)), al=rng.standard_normal(nw), au=rng.standard_normal(nw),
             fl=rng.uniform(size=nw) < 0.6, fu=rng.uniform(size=nw) < 0.6,
             X=rng.standard_normal((N + 1, n)), U=rng.standard_normal((N, m)), lam=rng.standard_normal((N + 1, n)),
             nu=rng.standard_normal((N + 1, n_nu)), tl=rng.uniform(0.1, 2, nw), tu=rng.uniform(0.1, 2, nw),
             zl=rng.uniform(0.1, 2, nw), zu=rng.uniform(0.1, 2, nw), bx=rng.standard_normal((N + 1, n)),
             bu=rng.standard_normal((N, m)), bdyn=rng.standard_normal((N, n)), bx0=rng.standard_normal(n),
             be=rng.standard_normal((N, ne)), beN=rng.standard_normal(neN))
    d["be"] *= eqm
    d.update(outputs(N, n, m, ne, neN, nw))
    return d


def outputs(N, n, m, ne, neN, nw, fill=np.nan):
    return dict(rx=np.full((N + 1, n), fill), ru=np.full((N, m), fill), dyn=np.full((N, n), fill),
                x0r=np.full(n, fill), rE=np.full((N, ne), fill), rEN=np.full(neN, fill), rl=np.full(nw, fill),
                rup=np.full(nw, fill), w=np.full(nw, fill), stats=np.full(6, fill))


def bundles(a):
    """The bundles of _kkt_map (data, point, offsets, out) of the arrays of the dict a."""
    offsets = Residuals(a["bx"], a["bu"], a["bdyn"], a["bx0"], a["be"], a["beN"], a["al"], a["au"])
    return tuple(tuple(b) for b in (KKTData(*(a[k] for k in KKTData._fields)),
                                    PointArrays(*(a[k] for k in PointArrays._fields)), offsets,
                                    Residuals(*(a[k] for k in Residuals._fields))))


def run(sizes, d):
    """_kkt_map on copies of the arrays of d; returns the outputs."""
    a = {k: v.copy() for k, v in d.items()}
    qp_ip._kkt_map(sizes, *bundles(a), a["w"], a["stats"])
    return {k: a[k] for k in OUTPUTS}


def fixed_applies(sizes, d):
    """Whether _kkt_map runs the fixed-size kernel on the arrays of d."""
    return qp_ip._kkt_fixed_applies(typeof(sizes), *(typeof(b) for b in bundles(d)), typeof(d["w"]), typeof(d["stats"]))


def reference(d):
    """The outputs by the formulas of the _kkt_map docstring (numpy)."""
    H, AB, X, U, lam, nu = d["H"], d["AB"], d["X"], d["U"], d["lam"], d["nu"]
    N, n, nz = AB.shape
    m = nz - n
    ne, nc, neN, ncN = d["EF"].shape[1], d["C"].shape[1], d["EN"].shape[0], d["CN"].shape[0]
    zd = d["zu"] - d["zl"]
    ou, os_ = N * n, N * nz
    z = np.concatenate([X[:-1], U], axis=1)
    hz = np.einsum("kij,kj->ki", H, z)
    g = hz + np.einsum("kli,kl->ki", AB, lam[1:])
    g[:, :n] -= lam[:-1]
    g += np.einsum("kli,kl->ki", d["EF"], nu[:-1, :ne] * d["eqm"])
    g += np.einsum("kli,kl->ki", d["C"], zd[os_:os_ + N * nc].reshape(N, nc))
    g[1:, :n] += zd[:(N - 1) * n].reshape(N - 1, n)
    g[:, n:] += zd[ou:os_].reshape(N, m)
    hN = d["QN"] @ X[N]
    gN = hN - lam[N] + d["EN"].T @ nu[N, :neN] + zd[(N - 1) * n:N * n] + d["CN"].T @ zd[len(zd) - ncN:]
    rx = np.vstack([g[:, :n] + d["bx"][:N], gN + d["bx"][N]])
    ru = g[:, n:] + d["bu"]
    dyn = np.einsum("kij,kj->ki", AB, z) - X[1:] + d["bdyn"]
    x0r = d["bx0"] - X[0]
    rE = np.einsum("kij,kj->ki", d["EF"], z) * d["eqm"] + d["be"]
    rEN = d["EN"] @ X[N] + d["beN"]
    w = np.concatenate([X[1:].ravel(), U.ravel(), np.einsum("kij,kj->ki", d["C"], z).ravel(), d["CN"] @ X[N]])
    rl = np.where(d["fl"], w + d["al"] - d["tl"], 0.0)
    rup = np.where(d["fu"], d["au"] - w - d["tu"], 0.0)
    amax = lambda *arrays: max(np.nanmax(np.abs(a), initial=0.0) for a in arrays)  # noqa: E731  (max() skips NaN)
    obj = 0.5 * (np.sum(z * hz) + X[N] @ hN) + np.sum(d["bx"] * X) + np.sum(d["bu"] * U)
    stats = np.array([amax(dyn, x0r, rE, rEN, rl, rup), amax(rx, ru), amax(X, U), amax(hz, hN), obj,
                      d["zl"] @ d["tl"] + d["zu"] @ d["tu"]])
    return dict(rx=rx, ru=ru, dyn=dyn, x0r=x0r, rE=rE, rEN=rEN, rl=rl, rup=rup, w=w, stats=stats)


def assert_close(out, ref, rtol=1e-12, atol=1e-12):
    for k in OUTPUTS:
        np.testing.assert_allclose(out[k], ref[k], rtol=rtol, atol=atol, err_msg=k)


@pytest.mark.parametrize("n, m, ne, nc, neN, ncN", [
    (1, 1, 0, 0, 0, 0), (6, 7, 0, 0, 0, 0), (3, 2, 2, 2, 1, 1), (1, 1, 1, 1, 1, 1), (6, 7, 1, 3, 2, 1),
    (4, 4, 0, 0, 0, 0), (2, 5, 0, 1, 0, 0), (5, 2, 1, 0, 0, 2), (9, 3, 0, 0, 0, 0), (12, 12, 2, 2, 1, 1),
])
@pytest.mark.parametrize("N", [1, 2, 7])
def test_fixed_size_kernel_matches_the_formulas_and_the_loops(n, m, ne, nc, neN, ncN, N):
    d = random_args(1000 * n + 10 * m + N, N, n, m, ne, nc, neN, ncN)
    sizes = size_tags(n, m)
    assert fixed_applies(sizes, d)
    fixed = run(sizes, d)
    loops = run((n, m, n + m), d)
    ref = reference(d)
    assert all(np.all(np.isfinite(v)) for v in fixed.values())
    assert_close(fixed, ref)
    assert_close(fixed, loops)
    # the maxima are maxima of the same values (rounding aside): exactly those of the loops when
    # the arguments of the maxima are computed the same way (x, the box values)
    assert fixed["stats"][2] == loops["stats"][2]
    np.testing.assert_array_equal(fixed["w"][:N * (n + m)], loops["w"][:N * (n + m)])


def test_fixed_size_kernel_on_a_prepared_qp():
    """A QP with fixed variables, equal-bound rows, stage and final rows and equality rows
    (tests/fixtures/qp_problems.random_qp): the residuals of the compiled solver match the formulas."""
    qp = random_qp(5, fixed=True, eq=True)
    P = _Prepared(qp)
    assert isinstance(P.sizes[0], tuple)       # the fixed-size kernel
    it = MehrotraQP()._initial_point(P)
    rng = np.random.default_rng(3)
    it = it.plus(1.0, P.point(rng.standard_normal(it.v.shape)))
    d = dict(H=P.H, QN=P.QN, AB=P.AB, EF=P.EF, EFt=P.EFt, eqm=P.eqm, EN=P.EN, C=P.C, Ct=P.Ct, CN=P.CN,
             al=P.neg_lo, au=P.hi, fl=P.fl, fu=P.fu, X=it.X, U=it.U, lam=it.lam, nu=it.nu, tl=it.tl, tu=it.tu,
             zl=it.zl, zu=it.zu, bx=P.q, bu=P.r, bdyn=P.c, bx0=P.x0, be=P.be, beN=P.eN)
    d.update(outputs(P.N, P.n, P.m, P.EF.shape[1], P.EN.shape[0], P.nw))
    fixed, loops = run(P.sizes, d), run((P.n, P.m, P.n + P.m), d)
    assert fixed_applies(P.sizes, d)
    assert_close(fixed, reference(d))
    assert_close(fixed, loops)


@pytest.mark.parametrize("n, m, ne, nc", [(6, 7, 0, 0), (3, 2, 1, 2), (1, 1, 0, 0)])
def test_non_finite_inputs_propagate_as_in_the_loops(n, m, ne, nc):
    """NaN and inf in the point and the data reach the same outputs as in the scalar loops; the
    max-norms skip NaN and keep inf exactly as max() in the loops does."""
    N = 9
    for case in range(4):
        d = random_args(7 + case, N, n, m, ne, nc, 1, 1)
        rng = np.random.default_rng(case)
        if case == 0:
            d["X"][3, 0] = np.nan
        elif case == 1:
            d["U"][2, m - 1] = np.inf
            d["lam"][5, n - 1] = -np.inf
        elif case == 2:
            nw = d["tl"].shape[0]
            d["tl"][rng.integers(0, nw, 5)] = np.nan
            d["zu"][rng.integers(0, nw, 5)] = np.inf
            d["al"][rng.integers(0, nw, 5)] = np.nan      # on either side of the masks
        else:
            d["X"][...] = np.nan
            d["H"][1, 0, 0] = np.inf
        fixed = run(size_tags(n, m), d)
        loops = run((n, m, n + m), d)
        for k in OUTPUTS:
            a, b = fixed[k], loops[k]
            np.testing.assert_array_equal(np.isnan(a), np.isnan(b), err_msg=f"case {case}: {k}")
            np.testing.assert_array_equal(np.isposinf(a), np.isposinf(b), err_msg=f"case {case}: {k}")
            np.testing.assert_array_equal(np.isneginf(a), np.isneginf(b), err_msg=f"case {case}: {k}")
            fin = np.isfinite(a)
            np.testing.assert_allclose(a[fin], b[fin], rtol=1e-12, atol=1e-12, err_msg=f"case {case}: {k}")
        assert not np.all(np.isfinite(fixed["stats"]))       # the objective or the gap at least
        if case == 3:
            assert np.isnan(fixed["stats"][4]) and np.isnan(fixed["rx"]).all()


def test_non_contiguous_arrays_take_the_loop_kernel():
    """Arrays that are not C-contiguous are accepted (the loop kernel), with the same results."""
    n, m, N = 3, 2, 5
    d = random_args(11, N, n, m, 1, 1, 1, 1)
    ref = run(size_tags(n, m), d)
    d2 = dict(d)
    d2["X"] = np.asfortranarray(d["X"])
    big = np.zeros((N, 2 * (n + m), n + m))
    big[:, ::2] = d["H"]
    d2["H"] = big[:, ::2]
    assert not fixed_applies(size_tags(n, m), d2)
    out = run(size_tags(n, m), d2)
    assert_close(out, ref)
