"""The RLS recursion (eq. 48-50) against the closed form it must equal: after N
updates with forgetting factor lambda and P0 = delta I, theta_N minimises
lambda^N (theta - theta0)^T P0^-1 (theta - theta0) + sum_k lambda^(N-k) (y_k - theta^T x_k)^2,
i.e.

    theta_N = (lambda^N P0^-1 + sum_k lambda^(N-k) x_k x_k^T)^-1
              (lambda^N P0^-1 theta0 + sum_k lambda^(N-k) x_k y_k)

(Ljung, System Identification, Sec. 11.2). A recursion that drops or misplaces lambda,
or mis-signs the gain, misses this by far more than round-off."""
import numpy as np
import pytest

from cosim.algorithms.rls import RLSIdentifier, RLSParams


def _closed_form(X, Y, lam, delta, theta0):
    N = len(Y)
    w = lam ** (N - 1 - np.arange(N))            # lambda^(N-k), k = 1..N
    A = lam ** N * np.eye(X.shape[1]) / delta + (X * w[:, None]).T @ X
    b = lam ** N * np.asarray(theta0) / delta + (X * w[:, None]).T @ Y
    return np.linalg.solve(A, b)


@pytest.mark.parametrize("lam", [1.0, 0.999, 0.98])
def test_rls_recursion_equals_exponentially_weighted_least_squares(lam):
    rng = np.random.default_rng(7)
    N = 400
    X = rng.normal(size=(N, 3)) * np.array([1.0, 3.0, 0.5])
    # a parameter that drifts, so forgetting changes the answer by much more than 1e-9
    theta_true = np.array([0.9, 2.0, -0.3]) + np.outer(np.linspace(0, 1, N), [0.05, -0.8, 0.4])
    Y = np.einsum("ij,ij->i", X, theta_true) + 0.01 * rng.normal(size=N)
    theta0, delta = (0.1, -0.2, 0.3), 50.0
    rls = RLSIdentifier(RLSParams(forgetting_factor=lam, delta=delta, theta0=theta0,
                                  regression="eq44"))
    for x, y in zip(X, Y):
        rls.update(x, y)
    expected = _closed_form(X, Y, lam, delta, theta0)
    np.testing.assert_allclose(rls.theta, expected, rtol=1e-8, atol=1e-10)
    # the weighting matters here: the unforgetting answer is far from the forgetting one
    if lam < 1.0:
        other = _closed_form(X, Y, 1.0, delta, theta0)
        assert np.max(np.abs(other - expected)) > 1e-3


def test_rls_covariance_equals_the_weighted_information_inverse():
    """P_N = (lambda^N P0^-1 + sum lambda^(N-k) x x^T)^-1 (eq. 50 unrolled)."""
    rng = np.random.default_rng(3)
    X = rng.normal(size=(200, 3))
    lam, delta = 0.99, 10.0
    rls = RLSIdentifier(RLSParams(forgetting_factor=lam, delta=delta, regression="eq44"))
    for x in X:
        rls.update(x, 0.0)
    N = len(X)
    w = lam ** (N - 1 - np.arange(N))
    info = lam ** N * np.eye(3) / delta + (X * w[:, None]).T @ X
    np.testing.assert_allclose(rls.P, np.linalg.inv(info), rtol=1e-7, atol=1e-12)
