"""The structured NLP view (paper 001 sec. 4.1): values, sparse derivatives, counts."""

import numpy as np
import pytest

from olado.problems import StructuredNLP

from fixtures.toy_problems import Pendulum, PendulumFD


def _point(nlp, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(-1, 1, nlp.n_vars)


def test_pack_unpack_round_trip_and_layout():
    p = Pendulum(N=4)
    nlp = StructuredNLP(p)
    assert nlp.n_vars == 4 * 3 + 2 and nlp.n_cons == 4 * 2 + 4 + 1
    X = np.arange(10.0).reshape(5, 2); U = -np.arange(4.0)[:, None]
    y = nlp.pack(X, U)
    assert np.array_equal(y[:5], [0, 1, 0, 2, 3])  # x0, u0, x1 ...
    X2, U2 = nlp.unpack(y)
    assert np.array_equal(X, X2) and np.array_equal(U, U2)


def test_constraints_are_dynamics_residuals_and_g():
    p = Pendulum(N=4)
    nlp = StructuredNLP(p)
    y = _point(nlp)
    X, U = nlp.unpack(y)
    c = nlp.constraints(y)
    assert np.allclose(c[:8].reshape(4, 2), [p.dynamics(k, X[k], U[k]) - X[k + 1] for k in range(4)])
    assert np.allclose(c[8:12], [p.stage_constraints(k, X[k], U[k])[0] for k in range(4)])
    assert c[12] == pytest.approx(X[4, 0] - 0.2)
    cl, cu = nlp.constraint_bounds()
    assert np.all(cl == 0) and np.all(cu[:8] == 0) and np.all(np.isinf(cu[8:12])) and cu[12] == 0


def test_variable_bounds_fix_x0():
    p = Pendulum(N=3, x_bounds=([-5, -5], [5, 5]))
    nlp = StructuredNLP(p)
    lb, ub = nlp.variable_bounds()
    assert np.array_equal(lb[:2], p.x0) and np.array_equal(ub[:2], p.x0)
    assert lb[2] == -2 and ub[2] == 2 and lb[3] == -5


def _fd_matrix(fun, y, h=1e-6):
    cols = []
    for i in range(y.size):
        e = np.zeros_like(y); e[i] = h
        cols.append((fun(y + e) - fun(y - e)) / (2 * h))
    return np.array(cols).T


@pytest.mark.parametrize("cls", [Pendulum, PendulumFD])
def test_gradient_and_jacobian_against_finite_differences(cls):
    nlp = StructuredNLP(cls(N=5))
    y = _point(nlp, 1)
    assert np.allclose(nlp.gradient(y), _fd_matrix(lambda z: np.array([nlp.objective(z)]), y)[0], atol=1e-7)
    J = nlp.jacobian_matrix(y).toarray()
    assert np.allclose(J, _fd_matrix(nlp.constraints, y), atol=1e-7)
    rows, cols = nlp.jacobian_structure()
    assert len(set(zip(rows.tolist(), cols.tolist()))) == rows.size  # no duplicate entries


def test_hessian_against_finite_differences_of_the_lagrangian_gradient():
    nlp = StructuredNLP(Pendulum(N=5))
    y = _point(nlp, 2)
    lam = np.random.default_rng(5).standard_normal(nlp.n_cons)

    def grad_lagrangian(z):
        return 0.6 * nlp.gradient(z) + nlp.jacobian_matrix(z).T @ lam

    H = nlp.hessian_matrix(y, lam, 0.6).toarray()
    assert np.allclose(H, H.T)
    assert np.allclose(H, _fd_matrix(grad_lagrangian, y), atol=1e-6)
    rows, cols = nlp.hessian_structure()
    assert np.all(rows >= cols)
    # block diagonal: nothing couples different stages
    nz = nlp.nz
    assert np.all((rows // nz) == (cols // nz))


def test_counts_follow_table1_convention():
    p = Pendulum(N=4, x_bounds=([-5, -np.inf], [5, np.inf]))
    c = StructuredNLP(p).counts()
    assert c["variables"] == 14
    assert c["equalities"] == 8 + 2 + 1          # dynamics, fixed x0, final equality
    assert c["inequalities"] == 2 * 5 + 2 * 4 + 4  # x bounds k=0..4, u bounds, g^k
    assert c["breakdown"]["state_bounds"] == 10
