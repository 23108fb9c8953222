"""Tests of :mod:`scenesim.rampfit.covariance` and of the one implementation of the
resultant time moments, :func:`scenesim.detector.readout.resultant_moments`.

References, independent of the code under test: for ``N`` reads at times ``t_k`` the
Poisson variance of their mean at rate ``f`` is ``(f / N^2) sum_jk min(t_j, t_k)``,
so ``tau`` is the mean of the matrix ``min(t_j, t_k)``; for evenly spaced reads
``t_bar = t_1 + d (N - 1) / 2`` and ``tau = t_1 + d (N - 1)(2N - 1) / (6N)``.
"""

import numpy as np
import pytest

from noise.errors import ParameterError
from ramp_sim import dense_cov, roman_times
from scenesim.detector.readout import (ROMAN_LIKE_SKIP_TABLE, ROMAN_LIKE_TABLE, Readout,
                                       resultant_moments)
from scenesim.rampfit import RampCovariance


def test_moments_against_the_dense_definition_and_closed_forms():
    rng = np.random.default_rng(40)
    times = [np.sort(rng.uniform(0, 100, n)) + 100 * i for i, n in enumerate((1, 3, 8))]
    n, tbar, tau = resultant_moments(times)
    np.testing.assert_array_equal(n, [1, 3, 8])
    np.testing.assert_allclose(tbar, [t.mean() for t in times], rtol=1e-15)
    np.testing.assert_allclose(tau, [np.minimum.outer(t, t).mean() for t in times],
                               rtol=1e-14)
    t1, d, m = 3.0, 0.5, 7                                   # evenly spaced reads
    _, tb, ta = resultant_moments([t1 + d * np.arange(m)])
    assert tb[0] == pytest.approx(t1 + d * (m - 1) / 2, rel=1e-15)
    assert ta[0] == pytest.approx(t1 + d * (m - 1) * (2 * m - 1) / (6 * m), rel=1e-15)
    with pytest.raises(ParameterError, match=r"'read_times'\[1\]"):
        resultant_moments([np.ones(2), np.array([])])


def _ulps(got, exact):
    """|got - exact| in units of the float64 spacing at ``exact`` (a Fraction)."""
    from fractions import Fraction
    return abs(Fraction(got) - exact) / Fraction(float(np.spacing(float(exact))))


@pytest.mark.parametrize("readout", [Readout.named("MEDIUM8", 10),
                                     Readout.from_ma_table(ROMAN_LIKE_TABLE)],
                         ids=["medium8", "roman"])
def test_moments_are_exactly_rounded_sums(readout):
    """t_bar and tau against exact rational arithmetic.  Computed as exactly rounded
    sums (math.fsum), so no CPU-dependent summation order can enter: t_bar =
    fl(fl(sum t) / N) is within 1 ulp of the exact mean (two roundings of half an
    ulp); tau rounds each product (2N - 2k + 1) t_k too (relative 2**-53 each, all
    terms positive), so the sum is within 1.5 ulp and the quotient within 2 ulp."""
    from fractions import Fraction
    t_frame = 10.737
    n, tbar, tau = resultant_moments(readout.read_times(t_frame))
    for r, t in enumerate(readout.read_times(t_frame)):
        m = t.size
        exact_mean = sum(Fraction(x) for x in t) / m
        exact_tau = sum((2 * m - 2 * k + 1) * Fraction(x)
                        for k, x in enumerate(t, start=1)) / (m * m)
        assert _ulps(tbar[r], exact_mean) <= 1
        assert _ulps(tau[r], exact_tau) <= 2


@pytest.mark.parametrize("readout", [Readout.named("MEDIUM8", 10),
                                     Readout.from_ma_table(ROMAN_LIKE_TABLE),
                                     Readout.from_ma_table(ROMAN_LIKE_SKIP_TABLE),
                                     Readout.named("RAPID", 5, reset_mode="global")],
                         ids=["medium8", "roman", "roman_skip", "rapid_global"])
def test_readout_and_fitter_share_the_moments(readout):
    # One implementation: the readout's mean times and tau and the fitter's covariance
    # constants are resultant_moments of the read times, bit for bit.
    t_frame = 10.737
    times = readout.read_times(t_frame)
    n, tbar, tau = resultant_moments(times)
    np.testing.assert_array_equal(readout.mean_times(t_frame), tbar)
    np.testing.assert_array_equal(readout.tau(t_frame), tau)
    cov = RampCovariance(times)
    for got, want in ((cov.n, n), (cov.tbar, tbar), (cov.tau, tau)):
        np.testing.assert_array_equal(got, want)


def test_covariance_coefficients_against_the_dense_resultant_covariance():
    # C = D Sigma D^T for the rate estimates d = D R; its read part per sigma^2 and
    # Poisson part per unit rate are the tridiagonal Ar/Br and Ap/Bp.
    times = roman_times()
    r, m = dense_cov(times, 1.0)
    cov = RampCovariance(times)
    nd = len(times) - 1
    dmat = np.zeros((nd, nd + 1))
    for i in range(nd):
        dmat[i, i], dmat[i, i + 1] = -1 / cov.dt[i], 1 / cov.dt[i]
    for part, (a, b) in ((r, (cov.Ar, cov.Br)), (m, (cov.Ap, cov.Bp))):
        c = dmat @ part @ dmat.T
        np.testing.assert_allclose(np.diag(c), a, rtol=1e-12)
        np.testing.assert_allclose(np.diag(c, 1), b, rtol=1e-10, atol=1e-15)
        np.testing.assert_allclose(np.triu(c, 2), 0, atol=1e-15)
