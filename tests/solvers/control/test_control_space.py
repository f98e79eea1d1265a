"""The reduced problem J(u): adjoint gradient and second-order adjoint Hessian-vector products
against finite differences and a dense reduced Hessian."""

import numpy as np
import pytest

from olado.solvers.control.control_space import ReducedProblem

from fixtures.toy_problems import Pendulum, PendulumVectorized


@pytest.mark.parametrize("cls", [Pendulum, PendulumVectorized])
def test_adjoint_gradient_matches_finite_differences(cls):
    p = cls(N=9)
    rp = ReducedProblem(p)
    rng = np.random.default_rng(0)
    U = rng.uniform(-1, 1, (9, 1))
    J, g, X, costate = rp.gradient(U)
    assert J == pytest.approx(p.objective(p.simulate(U), U))
    h = 1e-6
    fd = np.zeros_like(U)
    for k in range(9):
        e = np.zeros_like(U); e[k, 0] = h
        fd[k, 0] = (rp.value(U + e)[0] - rp.value(U - e)[0]) / (2 * h)
    assert np.allclose(g, fd, atol=1e-7)


def test_hessian_vector_matches_finite_differences_of_the_gradient():
    p = Pendulum(N=7)
    rp = ReducedProblem(p)
    rng = np.random.default_rng(1)
    U = rng.uniform(-1, 1, (7, 1)); V = rng.standard_normal((7, 1))
    Hv = rp.hessian_vector(U, V)
    h = 1e-5
    fd = (rp.gradient(U + h * V)[1] - rp.gradient(U - h * V)[1]) / (2 * h)
    assert np.allclose(Hv, fd, atol=1e-6)
    # the dense reduced Hessian assembled column by column is symmetric
    H = np.column_stack([rp.hessian_vector(U, np.eye(7)[:, [j]]).ravel() for j in range(7)])
    assert np.allclose(H, H.T, atol=1e-10)
