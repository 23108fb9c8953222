"""White noise added once per resultant (the rounding of an on-board average):
``optimal_variance(..., resultant_noise=q)`` against the dense GLS definition, and
``fit_ramps(..., resultant_noise=q)`` against the same definition and against
digitised ramps."""

import numpy as np
import pytest

import ramp_sim
from noise.adc import averaging_noise
from noise.errors import ParameterError
from scenesim.detector.dq import JUMP_DET
from scenesim.rampfit import fit_ramps, optimal_variance


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


# ---------------------------------------------------------------- fit_ramps with q
# Ramps digitised read by read and averaged on board into rounded means
# (tests/ramp_sim.py, independent of the simulator's ADC), fitted with the per-read
# noise sqrt(sigma^2 + gain^2/12) and, per resultant, the rounding of the mean,
# gain^2/12 (1 + 2/N^2) for these even N (noise.adc.averaging_noise).  JWST MEDIUM8 (10 groups of 8
# frames), 5 e-/DN and 6 e- per read, read-noise dominated (0.002 e-/s): the
# rounding is 43 % of a resultant's white variance.

GAIN, SIGMA_READ, RATE = 5.0, 6.0, 0.002


def _digitised_ramps(seed, shape=(200, 200)):
    rng = np.random.default_rng(seed)
    times = ramp_sim.jwst_times(10, nframes=8, groupgap=2)
    res = ramp_sim.simulate(rng, RATE, times, SIGMA_READ, shape, gain=GAIN)
    return res, times


def _z2(result, rate):
    v = result.var_read.astype(float) + result.var_poisson.astype(float)
    z2 = (result.slope.astype(float) - rate) ** 2 / v
    return z2.mean(), z2.std() / np.sqrt(z2.size)


def test_rounded_means_report_calibrated_errors():
    res, times = _digitised_ramps(11)
    rn = float(np.hypot(SIGMA_READ, GAIN / np.sqrt(12)))
    q = averaging_noise(GAIN, [len(t) for t in times])
    known = np.full(res.shape[1:], RATE)
    with_q = fit_ramps(res, times, read_noise=rn, resultant_noise=q,
                       variance_rate=known, threads=1)
    without = fit_ramps(res, times, read_noise=rn, variance_rate=known, threads=1)
    m, se = _z2(with_q, RATE)
    # E[z^2] = 1 for calibrated errors; 5 standard errors of the 40000-pixel mean
    # (se ~ 0.007; the rounding errors are uniform, z is close to Gaussian)
    assert abs(m - 1) < 5 * se, (m, se)
    m0, se0 = _z2(without, RATE)
    assert m0 > 1 + 5 * se0            # the defect this fixes (1.31 measured)
    # the reported variance is the optimal one of the covariance with q (theory)
    vopt = optimal_variance(RATE, times, rn, resultant_noise=q)
    v = (with_q.var_read + with_q.var_poisson).astype(float)
    np.testing.assert_allclose(v, vopt, rtol=1e-4)   # float32 solve of a float64 value


def test_gls_with_q_is_the_dense_gls():
    # the weights of the solve with the constant part are those of the dense GLS of
    # the covariance with q (same rate: an array passed as variance_rate)
    rng = np.random.default_rng(3)
    times = ramp_sim.roman_times()
    shape = (4, 5)
    rate = 20.0
    res = ramp_sim.simulate(rng, rate, times, 5.0, shape)
    q = np.array([0.0, 1.0, 2.5, 0.3, 4.0, 0.0, 1.5, 2.0, 0.7])
    got = fit_ramps(res, times, read_noise=5.0, resultant_noise=q,
                    variance_rate=np.full(shape, rate), threads=1, n_iter=1)
    r, m = ramp_sim.dense_cov(times, 5.0)
    cov = r + np.diag(q ** 2) + rate * m
    tb = np.array([t.mean() for t in times])
    X = np.column_stack([np.ones(tb.size), tb])
    ci = np.linalg.inv(cov)
    w = np.linalg.solve(X.T @ ci @ X, X.T @ ci)[1]           # slope weights
    want = np.tensordot(w, res, axes=(0, 0))
    # float32 differences and solve: relative 1e-5 of the slopes' scale
    np.testing.assert_allclose(got.slope, want, rtol=0, atol=2e-5 * rate)
    vwant = np.linalg.inv(X.T @ ci @ X)[1, 1]
    np.testing.assert_allclose(got.var_read + got.var_poisson, vwant, rtol=1e-4)


def test_jump_test_counts_the_rounding():
    # gain 8 e-/DN and 1 e- read noise: the rounding of 8-read means (5.25 e-^2)
    # dwarfs the per-read variance of the mean (~0.8 e-^2); with it in the
    # covariance a 5-sigma test flags almost no clean pixel (Gaussian:
    # ~8 differences x 6e-7 per pixel; allowed 1e-3 of the 40000 pixels)
    rng = np.random.default_rng(5)
    times = ramp_sim.roman_times()
    gain = 8.0
    res = ramp_sim.simulate(rng, 0.5, times, 1.0, (200, 200), gain=gain)
    rn = float(np.hypot(1.0, gain / np.sqrt(12)))
    q = averaging_noise(gain, [len(t) for t in times])
    got = fit_ramps(res, times, read_noise=rn, resultant_noise=q, jump_threshold=5.0,
                    threads=1)
    flagged = ((got.dq & np.uint32(JUMP_DET)) != 0).mean()
    assert flagged < 1e-3, flagged


@pytest.mark.parametrize("bad", [-1.0, np.nan, [1.0, 2.0], "x"])
def test_bad_resultant_noise_is_refused(bad):
    times = ramp_sim.jwst_times(4)
    res = np.zeros((4, 3, 3))
    with pytest.raises(ParameterError, match="resultant_noise"):
        fit_ramps(res, times, read_noise=1.0, resultant_noise=bad)


def test_averaging_noise():
    # one read: nothing beyond the per-read quantisation; N reads: the error of the
    # rounded mean of N integers (DN^2): mean square of k/N, k = -1..1 for N = 3,
    # k = 0, 1 for N = 2 (1/2 rounds to even: +-1/2), k = -3..4 for N = 8
    np.testing.assert_allclose(averaging_noise(2.0, [1, 2, 3, 8]), 2.0 * np.sqrt(
        [0.0, 0.25 / 2, (2 / 9) / 3, (2 * (1 + 4 + 9) + 16) / 64 / 8]))
    rng = np.random.default_rng(0)
    for n in (2, 3, 4, 5, 8):
        codes = rng.integers(0, 1000, size=(200_000, n))
        err = np.rint(codes.mean(axis=1)) - codes.mean(axis=1)
        # half-to-even at exact halves (even n) keeps the mean at 0; the variance of
        # 200000 uniform-like errors has a relative standard error ~0.003; 5 of them
        assert err.var() == pytest.approx(averaging_noise(1.0, n) ** 2, rel=0.015)
