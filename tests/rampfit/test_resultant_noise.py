"""``optimal_variance(..., resultant_noise=q)``: white noise added once per resultant
(the rounding of an on-board average) against the dense GLS definition."""

import numpy as np
import pytest

from scenesim.rampfit import optimal_variance


def _dense(times, f, s, q):
    q = np.broadcast_to(np.asarray(q, dtype=float), (len(times),))
    """1 / (X^T C^-1 X)[slope] with a free intercept, C built from its definition:
    Var(R_i) = s^2/N_i + q^2 + f tau_i, Cov(R_i, R_j) = f tbar_min(i, j)."""
    n = [len(t) for t in times]
    tb = [t.mean() for t in times]

    def tau(t):
        N = len(t)
        k = np.arange(1, N + 1)
        return ((2 * N - 2 * k + 1) * t).sum() / N ** 2

    m = len(times)
    C = np.empty((m, m))
    for i in range(m):
        for j in range(m):
            C[i, j] = (s ** 2 / n[i] + q[i] ** 2 + f * tau(times[i]) if i == j
                       else f * tb[min(i, j)])
    X = np.column_stack([np.ones(m), tb])
    return np.linalg.inv(X.T @ np.linalg.inv(C) @ X)[1, 1]


@pytest.mark.parametrize("f, s, q", [(0.0, 3.0, 0.5), (30.0, 5.0, 1.2), (1e4, 1.0, 0.3),
                                     (0.0, 0.0, 0.5), (7.0, 2.0, (0.3, 0.0, 1.1, 0.5))])
def test_resultant_noise_matches_the_dense_gls(f, s, q):
    times = [np.array([1.0, 2.0, 3.0]), np.array([5.0, 6.0]),
             np.array([9.0, 10.0, 11.0, 12.0]), np.array([20.0])]
    got = optimal_variance(f, times, s, resultant_noise=q)
    assert got == pytest.approx(_dense(times, f, s, q), rel=1e-12)


def test_zero_resultant_noise_changes_nothing():
    times = [np.array([1.0, 2.0]), np.array([3.0, 4.0]), np.array([5.0, 6.0])]
    rate = np.array([0.0, 1.0, 100.0])
    np.testing.assert_array_equal(optimal_variance(rate, times, 4.0),
                                  optimal_variance(rate, times, 4.0, resultant_noise=0.0))
