"""Tests of :func:`scenesim.rampfit.fit_ramps` against closed forms and seeded Monte
Carlo ramps: efficiency and calibrated errors of every fitter, the reported variance,
several integrations, saturation and short ramps, invariances, null limits and input
checks.

Ramps and reference variances come from ``tests/ramp_sim.py`` (built from the read
times alone, independently of the simulator and of the package's formulas).
"""

import numpy as np
import pytest

from noise.errors import ParameterError
from ramp_sim import (READOUTS, SIGMA, T_ROMAN, dense_cov, dense_gls, dense_ols,
                      expected_z2, jwst_times, roman_times, simulate)
from scenesim.detector.dq import BAD_VARIANCE, DO_NOT_USE, REFERENCE_PIXEL, SATURATED
from scenesim.rampfit import FITTERS, fit_ramps, optimal_variance


# 160000 pixels per case: the ratio r = std(fit - truth)/sqrt(V_opt) has a standard
# error of about 1/sqrt(2 n) = 0.0018, so 5 sigma = 0.0088 < 0.01 (the required
# [0.99, 1.01] band is a >= 5 sigma test).
NPIX_SIDE = 400


@pytest.mark.parametrize("name", list(READOUTS))
@pytest.mark.parametrize("rate", [0.01, 1.0, 100.0, 1e4])
def test_fitters_against_theory(name, rate):
    times = READOUTS[name]()
    rng = np.random.default_rng([7, int(rate * 100), len(times)])
    shape = (NPIX_SIDE, NPIX_SIDE)
    n = shape[0] * shape[1]
    res = simulate(rng, rate, times, SIGMA, shape)
    v_opt = dense_gls(rate, times, SIGMA)[0]

    g = fit_ramps(res, times, read_noise=SIGMA, fitter="gls")
    e = g.slope.astype(float) - rate
    assert g.dq.max() == 0 and np.all(g.dof == len(times) - 2)
    # Efficiency: see the comment on NPIX_SIDE (5 sigma = 0.0088 inside +-0.01).
    ratio = e.std() / np.sqrt(v_opt)
    assert 0.99 <= ratio <= 1.01, ratio
    # Bias below 0.05 sigma; the mean's own standard error is 1/sqrt(n) = 0.0025.
    assert abs(e.mean()) / np.sqrt(v_opt) < 0.05
    # chi2 per dof: its mean has standard error sqrt(2/dof/n) < 0.001; the band
    # +-0.03 leaves room for the covariance being evaluated at the fitted rate.
    assert abs(g.chi2.mean() - 1) < 0.03, g.chi2.mean()
    # Reported errors (requirement: mean chi^2 = mean((f_hat - f)^2 / V_hat) within
    # 1 +- 0.03).  With the default local variance rate, uncorrelated with the
    # pixel's own error, E[z^2] - 1 is second order, q_p^2 Var(r) / V^2 < 0.01 here
    # (module notes).  z^2 of a normal has variance 2, so the mean of n values has
    # standard error sqrt(2/n) = 0.0035: an estimator whose true E[z^2] is within
    # 1 +- 0.012 passes with probability > 1 - 6e-7 (5 sigma = 0.018), one off by
    # more than 0.048 fails as surely.
    z2 = np.mean(e ** 2 / g.var)
    assert abs(z2 - 1) < 0.03, z2
    # The old practice, the pixel's own clipped rate, departs from 1 as predicted by
    # expected_z2 (0.93 / 0.91 at 0.01 e-/s): same slopes, same 5 sigma of the mean.
    # (Its slopes are the first fit's, weighted at the pixel's own rate; they
    # differ from the default's only where the neighbours set the weights.)
    own = fit_ramps(res, times, read_noise=SIGMA, fitter="gls", variance_rate="fit")
    e = own.slope.astype(float) - rate
    z2_own = np.mean(e ** 2 / own.var)
    assert abs(z2_own - expected_z2(rate, times, SIGMA)) < 5 * np.sqrt(2 / n), z2_own
    # Read/Poisson split: the read part against the dense optimal weights' read
    # variance (weights at the fitted rate differ slightly: 0.5 % allowance).
    vr = dense_gls(rate, times, SIGMA)[1]
    assert np.mean(g.var_read) == pytest.approx(vr, rel=0.005)

    # OLS: measured variance vs the exact matrix variance; a variance ratio has
    # standard error sqrt(2/n) = 0.0035, 5 sigma = 0.018.
    o = fit_ramps(res, times, read_noise=SIGMA, fitter="ols")
    eo = o.slope.astype(float) - rate
    v_ols = dense_ols(rate, times, SIGMA)
    assert eo.var() / v_ols == pytest.approx(1, abs=5 * np.sqrt(2 / n))
    assert abs(eo.mean()) / np.sqrt(v_ols) < 5 / np.sqrt(n)
    # Reported OLS errors: requirement 1 +- 0.03, as for GLS (same derivation).
    assert abs(np.mean(eo ** 2 / o.var) - 1) < 0.03
    # Reported OLS variance at a given rate: the weights do not depend on the data,
    # so V = c^T (sigma^2 R + f M) c exactly (float32 rounding: 1e-5).
    r, m = dense_cov(times, SIGMA)
    tb = np.array([t.mean() for t in times])
    cw = (tb - tb.mean()) / np.sum((tb - tb.mean()) ** 2)
    ot = fit_ramps(res, times, read_noise=SIGMA, fitter="ols",
                   variance_rate=np.full(shape, rate))
    np.testing.assert_allclose(ot.var, cw @ r @ cw + (cw @ m @ cw) * rate, rtol=1e-4)
    np.testing.assert_allclose(ot.var_poisson, (cw @ m @ cw) * rate, rtol=1e-4)

    # CDS: exact variance of (R_last - R_first) / (tbar_last - tbar_first).
    c = fit_ramps(res, times, read_noise=SIGMA, fitter="cds")
    ec = c.slope.astype(float) - rate
    r, m = dense_cov(times, SIGMA)
    w = np.zeros(len(times))
    w[0], w[-1] = -1, 1
    w /= times[-1].mean() - times[0].mean()
    v_cds = w @ (r + rate * m) @ w
    assert ec.var() / v_cds == pytest.approx(1, abs=5 * np.sqrt(2 / n))
    assert abs(ec.mean()) / np.sqrt(v_cds) < 5 / np.sqrt(n)
    assert abs(np.mean(ec ** 2 / c.var) - 1) < 0.03       # as for GLS


@pytest.mark.parametrize("name", list(READOUTS))
def test_variance_rate_with_hot_pixels(name):
    # 2 % hot pixels (1 e-/s) in a read-noise dominated 0.01 e-/s field.
    times = READOUTS[name]()
    rng = np.random.default_rng([21, len(times)])
    shape = (200, 200)
    rate = np.full(shape, 0.01)
    hot = rng.random(shape) < 0.02
    rate[hot] = 1.0
    res = simulate(rng, rate, times, SIGMA, shape)
    g = fit_ramps(res, times, read_noise=SIGMA)
    # A hot pixel is ~25 sigma above its neighbours' median: it must get its own
    # rate, not theirs (which would make its variance 5 times too small).  At
    # 1 e-/s f_hat > 0 always (12 sigma), so E[V_hat] = V(1 e-/s); the mean over
    # n_hot pixels has relative standard error q_p sigma / (V sqrt(n_hot)) < 0.002,
    # 5 sigma < 0.01.
    v1 = dense_gls(1.0, times, SIGMA)[0]
    nh = hot.sum()
    assert np.mean(g.var[hot]) == pytest.approx(v1, rel=0.01)
    # The field keeps calibrated errors despite hot neighbours (left out of the
    # neighbours' median by the 4-sigma clip): requirement 1 +- 0.03 with the mean
    # of z^2 over n_bg pixels, standard error sqrt(2 / n_bg) = 0.007, 5 sigma = 0.036
    # added to the band (200^2 pixels only, to keep the test fast).
    bg = ~hot
    e = g.slope - rate
    assert abs(np.mean(e[bg] ** 2 / g.var[bg]) - 1) < 0.03 + 5 * np.sqrt(2 / bg.sum())
    # Hot pixels follow the own-rate theory: 5 sigma of a mean of nh values of z^2.
    assert abs(np.mean(e[hot] ** 2 / g.var[hot]) - expected_z2(1.0, times, SIGMA)) < \
        5 * np.sqrt(2 / nh)


def test_variance_rate_options():
    times = jwst_times(6, t_frame=1.0)
    rng = np.random.default_rng(22)
    shape = (20, 30)
    res = simulate(rng, 5.0, times, 3.0, shape)
    known = rng.uniform(0, 10, shape)
    g = fit_ramps(res, times, read_noise=3.0, variance_rate=known)
    own = fit_ramps(res, times, read_noise=3.0, variance_rate="fit")
    loc = fit_ramps(res, times, read_noise=3.0)
    # A known rate sets the GLS weights and the Poisson part: the reported variance
    # is the optimal variance 1 / (1^T C(rate)^-1 1) at that rate, pixel by pixel
    # (float32 arithmetic: 1e-4).
    np.testing.assert_allclose(g.var, optimal_variance(known, times, 3.0), rtol=1e-4)
    # 'fit': the Poisson part at the pixel's own rate clipped at 0.
    assert np.all((own.var_poisson > 0) == (own.slope > 0))
    # The usable differences, flags and jump counts do not depend on the rate.
    for key in ("dq", "dof", "n_jumps"):
        np.testing.assert_array_equal(getattr(g, key), getattr(own, key))
        np.testing.assert_array_equal(getattr(loc, key), getattr(own, key))
    # One integration: var_ints = var.
    np.testing.assert_allclose(g.var_ints[0], g.var, rtol=1e-6)
    assert np.all(loc.var_poisson >= 0)
    for bad in ("median", np.ones((3, 3)), np.full(shape, np.nan)):
        with pytest.raises(ParameterError, match="variance_rate"):
            fit_ramps(res, times, read_noise=3.0, variance_rate=bad)


def test_multiple_integrations_combined_inverse_variance():
    times = jwst_times(10)
    rate, nints = 50.0, 3
    rng = np.random.default_rng(11)
    shape = (200, 200)
    n = shape[0] * shape[1]
    res = simulate(rng, rate, times, SIGMA, shape, nints=nints)
    v1 = dense_gls(rate, times, SIGMA)[0]
    g = fit_ramps(res, times, read_noise=SIGMA)
    assert g.slope_ints.shape == (nints,) + shape
    # Independent integrations with equal weights: V = V_1 / nints.  Variance
    # ratios have standard error sqrt(2/n) = 0.007 -> 5 sigma = 0.035.
    e = g.slope - rate
    assert e.var() / (v1 / nints) == pytest.approx(1, abs=5 * np.sqrt(2 / n))
    for k in range(nints):
        ek = g.slope_ints[k] - rate
        assert ek.var() / v1 == pytest.approx(1, abs=5 * np.sqrt(2 / n))
        assert np.mean(g.var_ints[k]) == pytest.approx(v1, rel=0.01)
    assert np.allclose(g.slope, g.slope_ints.mean(axis=0), rtol=0, atol=1e-4 * rate)
    assert np.mean(g.var) == pytest.approx(v1 / nints, rel=0.01)
    assert np.all(g.dof == nints * 9 - 1)


def test_saturation_midway_uses_unsaturated_resultants():
    times = roman_times()
    rng = np.random.default_rng(13)
    shape = (200, 200)
    rate = 300.0
    res = simulate(rng, rate, times, SIGMA, shape)
    tb = np.array([t.mean() for t in times])
    # Each pixel saturates after a random number of usable resultants 2..9.
    nuse = rng.integers(2, 10, shape)
    sat = np.arange(len(times))[:, None, None] >= nuse[None]
    res[sat] = np.nan                        # saturated values are never used
    g = fit_ramps(res, times, read_noise=SIGMA, saturated=sat)
    assert np.all(g.dq[nuse < 9] == SATURATED)
    assert np.all(g.dq[nuse == 9] == 0)
    assert np.all(g.dof == nuse - 2)
    # Per-pixel optimal variance of the truncated ramp; z has unit variance.
    vopt = np.array([dense_gls(rate, times[:k], SIGMA)[0] for k in range(2, 10)])
    v = vopt[nuse - 2]
    z = (g.slope - rate) / np.sqrt(v)
    n = z.size
    # Mean: standard error 1/sqrt(n) = 0.005 -> 5 sigma.  Variance: sqrt(2/n).
    assert abs(z.mean()) < 5 / np.sqrt(n)
    assert z.var() == pytest.approx(1, abs=5 * np.sqrt(2 / n) + 0.01)
    assert np.all(np.isfinite(g.var)) and np.all(tb > 0)


def test_fully_saturated_and_single_resultant():
    times = jwst_times(6)
    tb = np.array([t.mean() for t in times])
    rng = np.random.default_rng(14)
    shape = (100, 100)
    rate, zp = 20.0, 1000.0
    res = simulate(rng, rate, times, SIGMA, shape) + zp
    sat = np.zeros(res.shape, bool)
    sat[:, :, :50] = True                    # fully saturated
    sat[1:, :, 50:] = True                   # one usable resultant
    g = fit_ramps(res, times, read_noise=SIGMA, saturated=sat)
    full, one = np.s_[:, :50], np.s_[:, 50:]
    assert np.all(g.dq[full] == SATURATED | DO_NOT_USE)
    assert np.all(g.dq[one] == SATURATED | DO_NOT_USE)
    for arr in (g.slope, g.var_read, g.var_poisson, g.chi2):
        assert np.all(np.isfinite(arr))
    assert np.all(g.slope[full] == 0) and np.all(g.var_read[full] == BAD_VARIANCE)
    # With the zero point known, one resultant gives (R_0 - zp) / tbar_0 with
    # variance (sigma^2 / N_0 + f tau_0) / tbar_0^2 (N_0 = 1, tau_0 = tbar_0).
    g1 = fit_ramps(res, times, read_noise=SIGMA, saturated=sat, zero_point=zp)
    assert np.all(g1.dq[one] == SATURATED) and np.all(g1.dq[full] == SATURATED | DO_NOT_USE)
    v1 = (SIGMA ** 2 + rate * tb[0]) / tb[0] ** 2
    e = g1.slope[one] - rate
    n = e.size
    assert abs(e.mean()) < 5 * np.sqrt(v1 / n)
    assert e.var() / v1 == pytest.approx(1, abs=5 * np.sqrt(2 / n))
    assert np.mean(g1.var[one]) == pytest.approx(v1, rel=0.02)


def test_two_resultant_ramps_are_cds():
    times = [np.array([1.0, 2.0, 3.0]) * T_ROMAN, np.array([10.0, 11.0]) * T_ROMAN]
    rng = np.random.default_rng(15)
    shape = (200, 200)
    rate = 40.0
    res = simulate(rng, rate, times, SIGMA, shape)
    r, m = dense_cov(times, SIGMA)
    w = np.array([-1.0, 1.0]) / (times[1].mean() - times[0].mean())
    v = w @ (r + rate * m) @ w
    n = shape[0] * shape[1]
    slopes = []
    for fitter in FITTERS:
        g = fit_ramps(res, times, read_noise=SIGMA, fitter=fitter)
        e = g.slope - rate
        assert e.var() / v == pytest.approx(1, abs=5 * np.sqrt(2 / n))
        assert np.all(g.dof == 0) and np.all(g.chi2 == 0) and np.all(g.dq == 0)
        slopes.append(g.slope)
    np.testing.assert_allclose(slopes[0], slopes[2], rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(slopes[1], slopes[2], rtol=1e-5, atol=1e-4)


def test_one_resultant_input():
    times = [np.array([1.0, 2.0]) * T_ROMAN]
    res = np.full((1, 3, 4), 500.0)
    g = fit_ramps(res, times, read_noise=SIGMA)
    assert np.all(g.dq == DO_NOT_USE) and np.all(g.slope == 0)
    assert np.all(np.isfinite(g.var))
    g1 = fit_ramps(res, times, read_noise=SIGMA, zero_point=np.full((3, 4), 200.0))
    assert np.all(g1.dq == 0)
    np.testing.assert_allclose(g1.slope, 300.0 / (1.5 * T_ROMAN), rtol=1e-6)
    # Read part: sigma^2 / N / tbar^2.
    np.testing.assert_allclose(g1.var_read, SIGMA ** 2 / 2 / (1.5 * T_ROMAN) ** 2,
                               rtol=1e-6)


def test_global_reset_shift_and_noise_map():
    times = jwst_times(6, t_frame=1.0)
    rng = np.random.default_rng(16)
    shape = (24, 16)
    res = simulate(rng, 5.0, times, 3.0, shape).astype(np.float32)
    base = fit_ramps(res, times, read_noise=3.0, jump_threshold=4.0)
    # Global reset: each pixel's reads shifted by its clock offset.  The difference
    # covariance only involves time differences, so the fit is unchanged.
    shift = rng.uniform(0, 0.9, shape)
    ptimes = [t[:, None, None] - 1.0 + shift[None] for t in times]
    g = fit_ramps(res, ptimes, read_noise=np.full(shape, 3.0), jump_threshold=4.0)
    np.testing.assert_allclose(g.slope, base.slope, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(g.var, base.var, rtol=1e-5)


@pytest.mark.parametrize("fitter", ["gls", "ols"])
def test_result_does_not_depend_on_rows_fitted_together_or_threads(fitter):
    # A frame of 96 x 2048 pixels x 6 resultants spans several row chunks of the
    # fitter (about 2**19 values each).  Bit for bit: (i) the result does not depend
    # on the thread count; (ii) a pixel's result does not depend on which other rows
    # are fitted with it (row slices fitted alone, with the variance at each pixel's
    # own rate, which involves no neighbours).
    times = jwst_times(6, t_frame=1.0)
    rng = np.random.default_rng(16)
    shape = (96, 2048)
    res = simulate(rng, 5.0, times, 3.0, shape).astype(np.float32)
    hits = rng.random(shape) < 0.01                 # jumps in some pixels
    res[3:, hits] += 200.0
    kw = dict(read_noise=3.0, jump_threshold=4.0, fitter=fitter)
    base = fit_ramps(res, times, threads=1, **kw)
    g2 = fit_ramps(res, times, threads=2, **kw)
    keys = ("slope", "var_read", "var_poisson", "chi2", "dof", "dq", "slope_ints",
            "var_ints", "n_jumps")
    for key in keys:
        np.testing.assert_array_equal(getattr(g2, key), getattr(base, key))
    assert base.n_jumps.sum() > 0
    whole = fit_ramps(res, times, threads=1, variance_rate="fit", **kw)
    for y0, y1 in ((0, 1), (1, 40), (40, 96)):
        part = fit_ramps(res[:, y0:y1], times, threads=1, variance_rate="fit", **kw)
        for key in keys:
            np.testing.assert_array_equal(getattr(part, key),
                                          getattr(whole, key)[..., y0:y1, :])


def test_null_limits_and_refmask():
    times = jwst_times(5, t_frame=2.0)
    tb = np.array([t.mean() for t in times])
    # No charge, no noise: zero rate, zero variance, no NaN.
    res = np.zeros((5, 4, 4))
    for thr in (None, 5.0):
        g = fit_ramps(res, times, read_noise=0.0, jump_threshold=thr)
        assert np.all(g.slope == 0) and np.all(np.isfinite(g.var)) and np.all(g.dq == 0)
    # No read noise, noise-free ramp: exact rate, no jump flagged.
    g = fit_ramps(np.broadcast_to((4.0 * tb)[:, None, None], (5, 4, 4)), times,
                  read_noise=0.0, jump_threshold=5.0)
    np.testing.assert_allclose(g.slope, 4.0, rtol=1e-5)
    assert np.all(g.dq == 0)
    # Noise-free ramp with an offset: every fitter returns the exact rate.
    res = np.broadcast_to((7.0 + 2.5 * tb)[:, None, None], (5, 4, 4))
    mask = np.zeros((4, 4), bool)
    mask[0] = True
    for fitter in FITTERS:
        g = fit_ramps(res, times, read_noise=1.0, fitter=fitter, refmask=mask)
        np.testing.assert_allclose(g.slope, 2.5, rtol=1e-5)
        assert np.all(g.dq[0] == REFERENCE_PIXEL | DO_NOT_USE) and np.all(g.dq[1:] == 0)
        assert np.all(g.chi2 < 1e-6)


@pytest.mark.parametrize("kwargs,match", [
    (dict(fitter="wls"), "fitter"),
    (dict(read_noise=-1.0), "read_noise"),
    (dict(read_noise=np.ones((2, 2))), "read_noise"),
    (dict(gain=0.0), "gain"),
    (dict(n_iter=0), "n_iter"),
    (dict(jump_threshold=-3.0), "jump_threshold"),
    (dict(saturated=np.zeros((3, 4, 4), bool)), "saturated"),
    (dict(saturated=np.zeros((4, 4, 4), int)), "saturated"),
    (dict(refmask=np.zeros((3, 3), bool)), "refmask"),
    (dict(read_times=[[1.0], [2.0]]), "read_times"),
    (dict(read_times=[[1.0], [3.0], [2.0], [4.0]]), "overlap"),
    (dict(read_times=[[1.0], [2.0, 1.5], [3.0], [4.0]]), "increasing"),
    (dict(resultants=np.zeros((4, 4))), "resultants"),
    (dict(resultants=np.full((4, 4, 4), np.nan)), "finite"),
    (dict(threads=0), "threads"),
    # a read noise whose float32 square overflows (1e200: a bare OverflowError; 1e30:
    # every pixel DO_NOT_USE, with warnings), complex values (the imaginary part was
    # dropped with a ComplexWarning)
    (dict(read_noise=1e200), r"'read_noise' must be <= 1e\+15"),
    (dict(read_noise=1e30), r"'read_noise' must be <= 1e\+15"),
    (dict(read_noise=np.full((4, 4), 1 + 1j)), "read_noise"),
    (dict(read_times=[[1.0 + 0j], [2.0], [3.0], [4.0]]), "complex"),
    # inputs whose rates overflow the float32 fit: every pixel came out DO_NOT_USE
    # (spacing 1e-30 s, resultants of 1e300, int64 resultants of 1e18) or inf
    # (variance_rate 1e300) with only numpy warnings; read times of 1e30 s
    # underflowed 1 / dt^2
    (dict(read_times=[[1e-30], [2e-30], [3e-30], [4e-30]]),
     r"'read_noise' up to 1 e- over the shortest read spacing .* 1e-30 s"),
    (dict(resultants=np.full((4, 4, 4), 1e300)), r"'resultants' up to 1e\+300 e-"),
    (dict(resultants=np.full((4, 4, 4), 10 ** 18, np.int64)),
     r"'resultants' up to 1e\+18 e-.*takes rates up to 1e\+15"),
    (dict(variance_rate=1e300), r"'variance_rate' must be <= 1e\+15"),
    (dict(variance_rate=np.full((4, 4), 1e16)), r"'variance_rate' must be <= 1e\+15"),
    (dict(read_times=[[1e30], [2e30], [3e30], [4e30]]), r"<= 1e\+09 s"),
])
def test_bad_input(kwargs, match):
    args = dict(resultants=np.zeros((4, 4, 4)), read_times=[[1.0], [2.0], [3.0], [4.0]],
                read_noise=1.0)
    args.update(kwargs)
    resultants, read_times = args.pop("resultants"), args.pop("read_times")
    with pytest.raises(ParameterError, match=match):
        fit_ramps(resultants, read_times, **args)


def test_the_rate_scale_bound_keeps_flagged_and_integer_values_out():
    """The bound looks at the values the fit uses: a saturated (flagged) 1e30 is not
    counted, an int32 cube is read (its dtype allows 2e9), and a uint16 cube is
    bounded by its dtype (65535 over 1e-11 s is refused without a pass)."""
    t = [[10.0 * (k + 1)] for k in range(4)]
    res = np.cumsum(np.full((4, 4, 4), 50.0), axis=0)
    sat = np.zeros(res.shape, bool)
    sat[2:, 0, 0] = True
    big = res.copy()
    big[2:, 0, 0] = 1e30
    a = fit_ramps(big, t, read_noise=1.0, saturated=sat, fitter="ols")
    b = fit_ramps(res, t, read_noise=1.0, saturated=sat, fitter="ols")
    np.testing.assert_array_equal(a.slope, b.slope)
    np.testing.assert_allclose(b.slope, 5.0, rtol=1e-6)
    c = fit_ramps(res.astype(np.int32), t, read_noise=1.0, fitter="ols")
    np.testing.assert_allclose(c.slope, 5.0, rtol=1e-6)
    with pytest.raises(ParameterError, match=r"'resultants' up to 65535 e-"):
        fit_ramps(res.astype(np.uint16), [[1e-11 * (k + 1)] for k in range(4)],
                  read_noise=0.0)
