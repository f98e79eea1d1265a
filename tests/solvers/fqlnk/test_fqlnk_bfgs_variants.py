"""FQLNK's BFGS variants (olado.solvers.fqlnk.bfgs; docs/fqlnk.md, "Closing the iteration gap"):
the damping with another threshold t, skipping instead of damping, and the scaling of a Hessian
start after the first step, by hand and on random data; and the start the iteration count of the
Earth-to-Mars transfer depends on (a linear thrust-angle guess against olado's phi = 0)."""

import numpy as np
import pytest

import olado
from olado.problems import PROBLEMS
from olado.result import Status
from olado.solvers.fqlnk.bfgs import damped_bfgs_update, damping_theta, scaled_start

from fixtures import CONFIGS

IPOPT = str(CONFIGS / "ipopt.ini")


# ---------------------------------------------------------------------------- by hand
def test_threshold_damping_by_hand():
    """B = diag(2, 1), s = e1, y = (-1, 0.5): s'Bs = 2, s'y = -1 < t s'Bs for t = 0.1, so
    theta = 0.9 * 2 / (2 + 1) = 0.6, r = 0.6 y + 0.4 B s = (0.2, 0.3), s'r = 0.2 = t s'Bs, and
    B+ = B - diag(2, 0) + r r' / 0.2 = [[0.2, 0.3], [0.3, 1.45]] (det 0.2, positive definite)."""
    B, s, y = np.diag([2.0, 1.0]), np.array([1.0, 0.0]), np.array([-1.0, 0.5])
    assert damping_theta(2.0, -1.0, 0.1) == pytest.approx(0.6, rel=1e-15)
    assert damping_theta(2.0, 0.2, 0.1) == 1.0              # s'y = t s'Bs: undamped
    up = damped_bfgs_update(B, s, y, threshold=0.1)
    assert up.theta == pytest.approx(0.6, rel=1e-15) and not up.skipped
    np.testing.assert_allclose(up.B, [[0.2, 0.3], [0.3, 1.45]], rtol=1e-14)
    np.testing.assert_allclose(up.B @ s, [0.2, 0.3], rtol=1e-14)      # B+ s = r
    assert np.linalg.det(up.B) == pytest.approx(0.2, rel=1e-13)


def test_skip_leaves_b_unchanged_where_powell_would_damp():
    """skip: with s'y = -1 < 0.2 s'Bs the update is skipped (B+ = B, the same array values); with
    s'y = 3 >= 0.4 it is the undamped update of test_fqlnk's hand computation."""
    B, s = np.diag([2.0, 1.0]), np.array([1.0, 0.0])
    up = damped_bfgs_update(B, s, np.array([-1.0, 0.5]), skip=True)
    assert up.skipped and up.theta == 1.0
    np.testing.assert_array_equal(up.B, B)
    up = damped_bfgs_update(B, s, np.array([3.0, 1.0]), skip=True)
    assert not up.skipped and up.theta == 1.0
    np.testing.assert_allclose(up.B, [[3.0, 1.0], [1.0, 4.0 / 3.0]], rtol=1e-15)


def test_scaled_start_by_hand():
    """B0 = diag(2, 1), s = e1, y = (3, 1): gamma = s'y / s'B0 s = 3 / 2, B0 -> diag(3, 1.5); with
    s'y <= 0 the start is kept (factor 1)."""
    B, gamma = scaled_start(np.diag([2.0, 1.0]), np.array([1.0, 0.0]), np.array([3.0, 1.0]))
    assert gamma == pytest.approx(1.5, rel=1e-15)
    np.testing.assert_allclose(B, np.diag([3.0, 1.5]), rtol=1e-15)
    B0 = np.diag([2.0, 1.0])
    B, gamma = scaled_start(B0, np.array([1.0, 0.0]), np.array([-3.0, 1.0]))
    assert gamma == 1.0 and np.array_equal(B, B0)


@pytest.mark.parametrize("threshold", [1e-4, 0.1, 0.2, 0.5])
def test_damping_with_any_threshold_keeps_positive_definiteness(threshold):
    """Random positive definite B, arbitrary (s, y): B+ s = r (the secant equation with the damped
    r; r = y where undamped), s'r >= t s'Bs, B+ symmetric positive definite; and with skip, B+ is
    either B (skipped) or the same undamped update."""
    rng = np.random.default_rng(11)
    for _ in range(100):
        n = rng.integers(2, 7)
        M = rng.standard_normal((n, n))
        B = M @ M.T + 0.1 * np.eye(n)
        s, y = rng.standard_normal(n), rng.standard_normal(n)
        up = damped_bfgs_update(B, s, y, threshold=threshold)
        r = up.theta * y + (1 - up.theta) * B @ s
        if up.theta == 1.0:
            np.testing.assert_array_equal(r, y)
        np.testing.assert_allclose(up.B @ s, r, rtol=1e-7, atol=1e-9 * np.abs(r).max())
        sBs = s @ B @ s      # s'r = t s'Bs where damped, up to the rounding of theta y + (1 - theta) B s
        assert s @ r >= threshold * sBs - 1e-12 * (np.abs(s) @ (np.abs(y) + np.abs(B @ s)))
        np.testing.assert_allclose(up.B, up.B.T, atol=1e-12)
        assert np.linalg.eigvalsh(up.B).min() > 0.0
        sk = damped_bfgs_update(B, s, y, threshold=threshold, skip=True)
        if up.theta < 1.0:
            assert sk.skipped and np.array_equal(sk.B, B)
        else:
            np.testing.assert_array_equal(sk.B, up.B)


# ---------------------------------------------------------------------------- whole solves
@pytest.mark.parametrize("opts", [{"bfgs_threshold": 0.1}, {"bfgs_scaling": "first-step"},
                                  {"bfgs_damping": "skip", "bfgs_threshold": 1e-4}])
def test_variants_reach_ipopts_optimum_on_vanderpol(opts):
    ref = olado.solve(PROBLEMS["vanderpol"](N=20), config=IPOPT)
    r = olado.solve(PROBLEMS["vanderpol"](N=20), solver="fqlnk", **opts)
    assert r.status is Status.SUCCESS, r.message
    assert r.objective == pytest.approx(ref.objective, rel=1e-8)
    if opts.get("bfgs_scaling") == "first-step":
        assert r.info["bfgs_start_scale"] != 1.0


def test_earth_to_mars_iterations_depend_on_the_start():
    """The seed's problem (no r >= 0.5) at N = 16: BFGS from olado's phi = 0 needs 40+ Newton
    iterations, from the linear guess phi = 0.5 -> -1 rad about the seed's 17 (Table 4.5); both
    reach IPOPT's r(t_f) (docs/fqlnk.md, "Closing the iteration gap")."""
    ref = olado.solve(PROBLEMS["orbit-raising"](N=16), config=IPOPT)

    def solve(guess):
        p = PROBLEMS["orbit-raising"](N=16)
        p.x_bounds = None
        return olado.solve(p, solver="fqlnk", guess=guess)

    zero = solve(None)
    ramp = solve((0.5 - 1.5 * (np.arange(16) + 0.5) / 16)[:, None])
    for r in (zero, ramp):
        assert r.status is Status.SUCCESS, r.message
        assert r.x[-1, 0] == pytest.approx(ref.x[-1, 0], rel=1e-7)
    assert zero.iterations >= 30 and ramp.iterations <= 20
