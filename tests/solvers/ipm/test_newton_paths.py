"""The short paths of the ipm Newton matrix without constraint rows (KKTMatrix.plain: the shifted
diagonals written into the taken-over back-end and ``refactor_in_place``; the solve with shared
empty row parts) against the general Riccati path they replace, bit for bit; riccati.set_blocks'
keep-or-copy rule; barrier.dot's fixed order."""

import numpy as np
import pytest

from olado.linalg.riccati import RiccatiFactorization
from olado.solvers.ipm.barrier import dot
from olado.solvers.ipm.newton import KKTMatrix, Residuals


def _system(seed, N=6, n=3, m=2, convex=True):
    r = np.random.default_rng(seed)
    H = r.standard_normal((N + 1, n + m, n + m))
    H = np.einsum("kij,klj->kil", H, H) / (n + m) + 0.1 * np.eye(n + m)
    Q, S, R = (np.ascontiguousarray(a) for a in (H[:, :n, :n], H[:N, :n, n:], H[:N, n:, n:]))
    if not convex:
        R[3] -= 40.0 * np.eye(m)        # negative curvature: the inertia correction shifts
    A, B = r.standard_normal((N, n, n)) * 0.5, r.standard_normal((N, n, m))
    Sx, Su = r.uniform(0.0, 2.0, (N + 1, n)), r.uniform(0.0, 2.0, (N, m))
    res = Residuals(r.standard_normal((N, n)), np.zeros((N, 0)), np.zeros(0), np.zeros((N, 0)), np.zeros(0))
    return (Q, S, R, A, B, Sx, Su), res, r.standard_normal((N + 1, n)), r.standard_normal((N, m))


def _chain(plain):
    """Four Newton matrices in a row, each taking the last one's back-end over (the third one
    nonconvex); with ``plain`` False the general Riccati branch of try_factor and solve is forced.
    Returns every matrix's (delta, factorizations, Step)."""
    out, prev, last = [], None, 0.0
    for seed in (1, 2, 3, 4):
        blocks, res, q, r = _system(seed, convex=seed != 3)
        kkt = KKTMatrix(*(a.copy() for a in blocks), reuse=prev)
        assert kkt.plain
        kkt.plain = plain
        delta = kkt.factor(last)
        assert delta is not None and (delta > 0.0) == (seed == 3)
        if prev is not None:
            assert prev.kkt is None         # taken over
        step = kkt.solve(q, r, res)
        # a second solve with the same matrix (a second-order correction's) gives the same step
        again = kkt.solve(q, r, res)
        for a, b in zip(step, again):
            assert np.array_equal(a, b)
        out.append((delta, kkt.factorizations, step))
        prev, last = kkt, delta or last
    return out


def test_the_plain_path_takes_the_general_paths_steps_bit_for_bit():
    for (d1, f1, s1), (d2, f2, s2) in zip(_chain(True), _chain(False)):
        assert d1 == d2 and f1 == f2
        for a, b in zip(s1, s2):
            assert a.shape == b.shape and np.array_equal(a, b)


def test_the_plain_solve_leaves_its_right_hand_side_alone():
    blocks, res, q, r = _system(7)
    kkt = KKTMatrix(*blocks)
    assert kkt.factor(0.0) == 0.0
    q0, r0, h0 = q.copy(), r.copy(), res.h.copy()
    kkt.solve(q, r, res)
    assert np.array_equal(q, q0) and np.array_equal(r, r0) and np.array_equal(res.h, h0)


def test_refactor_in_place_is_refactor_with_the_held_diagonals():
    (Q, S, R, A, B, Sx, Su), _, q, r = _system(11)
    one = RiccatiFactorization(Q, S, R, A, B, Dx=Sx, Du=Su)
    two = RiccatiFactorization(Q, S, R, A, B, Dx=Sx, Du=Su)
    for f in (one, two):
        f.data.Dx += 0.5
        f.data.Du += 0.25
    one.refactor(Dx=one.data.Dx, Du=one.data.Du)
    two.refactor_in_place()
    for a, b in ((one.P, two.P), (one.K, two.K), (one.Lww, two.Lww)):
        assert np.array_equal(a, b)
    c, x0 = np.random.default_rng(3).standard_normal((B.shape[0], B.shape[1])), np.zeros(B.shape[1])
    for a, b in zip(one.solve(q, r, c, x0).X, two.solve(q, r, c, x0).X):
        assert np.array_equal(a, b)


def test_set_blocks_keeps_contiguous_float64_blocks_and_copies_the_others():
    (Q, S, R, A, B, Sx, Su), _, _, _ = _system(12)
    f = RiccatiFactorization(Q, S, R, A, B, Dx=Sx, Du=Su)
    Q2, S2, R2 = Q * 1.5, S * 0.5, R + 0.0
    A_f = np.asfortranarray(A)                  # not C-contiguous: copied
    B32 = B.astype(np.float32)                  # not float64: converted
    f.set_blocks(Q2, S2, R2, A_f, B32)
    d = f.data
    assert d.Q is Q2 and d.S is S2 and d.R is R2
    assert d.A is not A_f and d.A.flags.c_contiguous and np.array_equal(d.A, A)
    assert d.B.dtype == np.float64 and np.array_equal(d.B, B32.astype(np.float64))
    # the kernels' tuples hold the new arrays
    ref = RiccatiFactorization(Q2, S2, R2, A, B32.astype(np.float64), Dx=Sx, Du=Su)
    f.refactor_in_place()
    assert np.array_equal(f.P, ref.P) and np.array_equal(f.K, ref.K)
    with pytest.raises(ValueError, match="Q"):
        f.set_blocks(Q[:-1], S, R, A, B)


def _dot_reference(a, b):
    """barrier.dot's order in Python floats: eight partial sums of the products i = j (mod 8),
    combined pairwise, then the tail in order (a plain loop below eight entries)."""
    p = [float(x) * float(y) for x, y in zip(a, b)]
    if len(p) < 8:
        res = 0.0
        for t in p:
            res += t
        return res
    r = p[:8]
    end = len(p) - len(p) % 8
    for i in range(8, end, 8):
        for j in range(8):
            r[j] += p[i + j]
    res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
    for t in p[end:]:
        res += t
    return res


def test_dot_has_a_fixed_order():
    """barrier.dot sums in one order on every CPU (the compiled iteration's): bit for bit the
    Python reference, and within rounding of numpy's product."""
    rng = np.random.default_rng(4)
    for size in (0, 1, 7, 8, 9, 312, 5001):
        a, b = rng.standard_normal(size), rng.standard_normal(size)
        assert dot(a, b) == _dot_reference(a, b)
        assert dot(a, b) == pytest.approx(float(np.einsum("i,i->", a, b)), rel=1e-12, abs=1e-12)
        assert type(dot(a, b)) is float


@pytest.mark.parametrize("plain", [True, False])
def test_a_released_matrix_lets_its_blocks_go_and_is_taken_over_alike(plain):
    """release_blocks (before the next iteration's Hessians are evaluated): while the previous
    matrix is still alive, its blocks are no longer referenced by it or its back-end; the next
    matrix's take-over gives the same steps as without the release."""
    import gc
    import weakref

    def chain(release):
        out, prev, refs = [], None, None
        for seed in (1, 2, 3):
            blocks, res, q, r = _system(seed)
            blocks = tuple(a.copy() for a in blocks)
            if prev is not None and release:
                prev.release_blocks()
                gc.collect()
                assert all(ref() is None for ref in refs)      # prev alive, its blocks gone
            kkt = KKTMatrix(*blocks, reuse=prev)
            kkt.plain = plain
            assert kkt.factor(0.0) is not None
            out.append(kkt.solve(q, r, res))
            refs = [weakref.ref(a) for a in blocks[:5]]
            del blocks
            prev = kkt
        return out

    steps = chain(True)
    for s1, s2 in zip(steps, chain(False)):
        for a, b in zip(s1, s2):
            assert np.array_equal(a, b)
