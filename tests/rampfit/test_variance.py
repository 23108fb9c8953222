"""Tests of :mod:`scenesim.rampfit.variance`: the theoretical slope variances against
dense-covariance closed forms, and the model chi-square of any rate.

Ramps and reference variances come from ``tests/ramp_sim.py`` (built from the read
times alone, independently of the simulator and of the package's formulas).
"""

import numpy as np
import pytest

from noise.errors import ParameterError
from ramp_sim import (READOUTS, SIGMA, T_JWST, dense_cov, dense_gls, dense_ols,
                      jwst_times, roman_times, simulate)
from scenesim.rampfit import (fit_ramps, model_chi2, ols_variance, optimal_variance,
                              rauscher2007_variance)


@pytest.mark.parametrize("name", list(READOUTS))
@pytest.mark.parametrize("rate", [0.0, 0.01, 1.0, 100.0, 1e4])
def test_optimal_variance_equals_dense_gls(name, rate):
    times = READOUTS[name]()
    # Same quantity by two exact routes (tridiagonal difference covariance vs dense
    # resultant covariance with a free intercept): agreement to rounding.
    assert optimal_variance(rate, times, SIGMA) == pytest.approx(
        dense_gls(rate, times, SIGMA)[0], rel=1e-9)


def test_optimal_variance_broadcasts():
    times = jwst_times()
    rates = np.array([[0.0, 1.0], [10.0, 100.0]])
    rn = np.array([5.0, 10.0])
    got = optimal_variance(rates, times, rn)
    assert got.shape == (2, 2)
    assert got[1, 1] == pytest.approx(optimal_variance(100.0, times, 10.0), rel=1e-12)
    assert optimal_variance(0.0, times, 0.0) == 0.0
    # Global-reset times: each pixel's reads shifted by its clock offset.
    shifted = [t[:, None, None] + np.array([[0.0, 0.3]])[None] for t in times]
    assert optimal_variance(5.0, shifted, 10.0) == pytest.approx(
        optimal_variance(5.0, times, 10.0), rel=1e-12)
    assert ols_variance(5.0, shifted, 10.0) == pytest.approx(
        ols_variance(5.0, times, 10.0), rel=1e-12)


@pytest.mark.parametrize("ngroups,nframes,groupgap", [(20, 1, 0), (10, 4, 1), (5, 8, 12),
                                                      (2, 2, 3), (88, 1, 0)])
@pytest.mark.parametrize("rate", [0.0, 1.0, 1e3])
def test_rauscher2007_equals_matrix_ols(ngroups, nframes, groupgap, rate):
    times = jwst_times(ngroups, nframes, groupgap)
    ref = dense_ols(rate, times, SIGMA)
    # Closed form vs the exact matrix computation: equal to rounding.
    assert rauscher2007_variance(rate, ngroups, nframes, groupgap, T_JWST, SIGMA) == \
        pytest.approx(ref, rel=1e-9)
    assert ols_variance(rate, times, SIGMA) == pytest.approx(ref, rel=1e-9)


def test_ols_is_up_to_seven_percent_worse_at_high_flux():
    # DESIGN: equal weights lose up to ~7 % in sigma at high flux for 20 groups.
    # Poisson limit, n equally spaced single reads (spacing d): OLS variance
    # f 6 (n^2 + 1) / (5 n (n^2 - 1) d) (Rauscher et al. 2007, eq. 1), optimal
    # f / ((n - 1) d), so ratio^2 = 6 (n^2 + 1) / (5 n (n + 1)) = 1.14571 for n = 20.
    # The read-noise terms are 10 sigma^2 / (d f (n^2 + 1)) ~ 2e-6 of the Poisson
    # ones at f = 1e5 e-/s, far below the 1e-4 tolerance.
    n = 20
    times = jwst_times(ngroups=n)
    ratio = np.sqrt(ols_variance(1e5, times, SIGMA) / optimal_variance(1e5, times, SIGMA))
    assert ratio == pytest.approx(np.sqrt(6 * (n**2 + 1) / (5 * n * (n + 1))), rel=1e-4)
    # DESIGN.md's '~7 %' for 20 groups, stated as numbers (closed form: 1.0704)
    assert 1.06 < ratio < 1.075
    assert ols_variance(0.0, times, SIGMA) == pytest.approx(
        optimal_variance(0.0, times, SIGMA), rel=1e-9)


def diff_matrix(times):
    """(nd, nres) operator taking resultants to rate estimates (R_{i+1} - R_i)/dt_i."""
    tb = np.array([t.mean() for t in times])
    nres = tb.size
    d = np.zeros((nres - 1, nres))
    i = np.arange(nres - 1)
    d[i, i] = -1.0
    d[i, i + 1] = 1.0
    return d / np.diff(tb)[:, None]


def test_model_chi2_white_single_read_closed_form():
    """Single-read resultants, rate <= 0 (covariance at max(rate, 0) = 0): white noise
    only, Cov(R) = sigma^2 I.  chi2 (n - ddof) = r^T (D D^T)^-1 r / sigma^2 with
    r = D R - rate, computed here with a dense inverse; per-pixel read noise."""
    rng = np.random.default_rng(41)
    times = jwst_times(7, t_frame=3.0)
    shape = (5, 6)
    res = rng.normal(100.0, 20.0, (7,) + shape)
    rate = -rng.uniform(0.0, 2.0, shape)                  # clipped to 0 in C
    sigma = rng.uniform(2.0, 12.0, shape)
    D = diff_matrix(times)
    r = np.einsum("ij,jyx->iyx", D, res) - rate
    q = np.einsum("iyx,ij,jyx->yx", r, np.linalg.inv(D @ D.T), r) / sigma ** 2
    for ddof in (0, 1):
        got = model_chi2(res, times, rate, sigma, ddof=ddof)
        assert got.dtype == np.float32 and got.shape == shape
        # float32 arithmetic in the recursion: relative error ~1e-6 per term
        np.testing.assert_allclose(got, q / (6 - ddof), rtol=2e-5)


def test_model_chi2_against_dense_covariance_with_gaps():
    """Uneven multi-read table, Poisson + read covariance, two integrations, masked
    differences, per-pixel rate and read noise: the dense form
    sum_k r_k^T (C_d restricted to the usable differences)^-1 r_k / (n - ddof) with
    C_d = D (sigma^2 diag(1/N) + max(f, 0) M) D^T built from the read times."""
    rng = np.random.default_rng(42)
    times = roman_times()
    nres, nd = len(times), len(times) - 1
    shape = (4, 5)
    res = rng.normal(500.0, 50.0, (2, nres) + shape)
    rate = rng.uniform(-5.0, 50.0, shape)
    sigma = rng.uniform(3.0, 15.0, shape)
    valid = rng.random((2, nd) + shape) > 0.25
    valid[0, :, 0, 0] = False                              # an empty integration
    res[1, :, 1, 1] = np.where(valid[1, :, 1, 1].tolist() + [True], 500.0, np.nan)
    valid[1, :, 1, 1] &= np.isfinite(res[1, 1:, 1, 1]) & np.isfinite(res[1, :-1, 1, 1])
    D = diff_matrix(times)
    rd, m = dense_cov(times, 1.0)
    want = np.zeros(shape)
    for y in range(shape[0]):                              # 20 pixels: dense algebra
        for x in range(shape[1]):
            c = D @ (sigma[y, x] ** 2 * rd + max(rate[y, x], 0.0) * m) @ D.T
            for k in range(2):
                v = valid[k, :, y, x]
                rr = (D @ np.nan_to_num(res[k, :, y, x]) - rate[y, x])[v]
                want[y, x] += rr @ np.linalg.solve(c[np.ix_(v, v)], rr)
    n = valid.sum(axis=(0, 1))
    got = model_chi2(res, times, rate, sigma, valid=valid, ddof=1)
    expect = np.divide(want, n - 1, out=np.zeros(shape), where=n > 1)
    np.testing.assert_allclose(got, expect, rtol=5e-5)
    assert np.all(got[n <= 1] == 0)


@pytest.mark.parametrize("name", list(READOUTS))
def test_model_chi2_has_unit_mean_at_the_true_rate(name):
    """Simulated ramps (Poisson charge, Gaussian reads) at the true rate, ddof=0: the
    model covariance is the true one, so E[chi2] = 1 exactly.  Per pixel chi2 has
    variance 2/n (Gaussian; Poisson at >= 300 e- per interval adds < 1 %), so the
    mean of P pixels has sd sqrt(2 / (n P)): 5 sigma."""
    times = READOUTS[name]()
    rng = np.random.default_rng(43)
    shape = (40, 50)
    rate = 100.0
    res = simulate(rng, rate, times, SIGMA, shape)
    chi2 = model_chi2(res, times, rate, SIGMA, ddof=0)
    n, npix = len(times) - 1, chi2.size
    assert abs(chi2.mean() - 1.0) < 5.0 * np.sqrt(2.0 / (n * npix))


@pytest.mark.parametrize("fitter", ["ols", "gls"])
def test_model_chi2_equals_fit_ramps_chi2(fitter):
    """fit_ramps' CHI2 is model_chi2 at its own slope (ddof=1), saturation included.

    'ols': its chi2 uses the covariance at max(slope, 0) as model_chi2 does (float32
    rounding only).  'gls': the covariance is that of the previous iteration's rate;
    with 6 iterations the rate has converged to float32 precision."""
    times = roman_times()
    rng = np.random.default_rng(44)
    shape = (12, 10)
    rate = rng.uniform(0.0, 200.0, shape)
    res = simulate(rng, rate, times, SIGMA, shape, nints=2)
    sat = np.zeros(res.shape, bool)
    sat[0, 6:, :3] = True                   # saturated from resultant 6 on
    g = fit_ramps(res, times, read_noise=SIGMA, fitter=fitter, saturated=sat,
                  n_iter=6, variance_rate="fit")
    valid = ~(sat[:, 1:] | sat[:, :-1])
    got = model_chi2(np.where(sat, np.nan, res), times, g.slope, SIGMA, valid=valid)
    np.testing.assert_allclose(got, g.chi2, rtol=1e-4)
    assert np.all(g.dof == valid.sum(axis=(0, 1)) - 1)


@pytest.mark.parametrize("kwargs, match", [
    (dict(valid=np.ones((4, 3, 3), bool)), "valid"),
    (dict(valid=np.ones((3, 3, 3), int)), "valid"),
    (dict(ddof=-1), "ddof"),
    (dict(resultants=np.zeros((1, 3, 3))), ">= 2 resultants"),
    (dict(resultants=np.full((4, 3, 3), np.nan)), "finite"),
    (dict(rate=np.zeros((2, 2))), "rate"),
    (dict(read_noise=-1.0), "read_noise"),
])
def test_model_chi2_bad_input(kwargs, match):
    args = dict(resultants=np.zeros((4, 3, 3)), read_times=[[1.0], [2.0], [3.0], [4.0]],
                rate=0.0, read_noise=1.0)
    args.update(kwargs)
    if args["resultants"].shape[0] == 1:
        args["read_times"] = [[1.0]]
    with pytest.raises(ParameterError, match=match):
        model_chi2(args.pop("resultants"), args.pop("read_times"), args.pop("rate"),
                   args.pop("read_noise"), **args)


def test_bad_input_theory_functions():
    with pytest.raises(ParameterError, match="rate"):
        optimal_variance(-1.0, jwst_times(3), 1.0)
    with pytest.raises(ParameterError, match="read_noise"):
        ols_variance(1.0, jwst_times(3), -1.0)
    with pytest.raises(ParameterError, match="2 resultants"):
        optimal_variance(1.0, jwst_times(1), 1.0)
    with pytest.raises(ParameterError, match="ngroups"):
        rauscher2007_variance(1.0, 1, 1, 0, T_JWST, 1.0)
    with pytest.raises(ParameterError, match="t_frame"):
        rauscher2007_variance(1.0, 5, 1, 0, 0.0, 1.0)


@pytest.mark.parametrize("sigma, quoted", [(5.0, 1.06), (2.0, 1.18), (0.5, 1.8)])
def test_fit_rate_variance_is_too_large_at_rate_zero(sigma, quoted):
    """variance_rate='fit' at rate 0 reports a variance too large (never too small),
    by the factor its docstring quotes (about 1.06, 1.18 and 1.8 at 5, 2 and 0.5 e-):
    the Poisson part is evaluated at max(slope, 0), biased up at rate 0.

    Estimator: r = mean(reported variance) / mean(slope^2) over n = 8192 pixels with a
    true slope of 0.  mean(slope^2) of Gaussian slopes has relative sd sqrt(2 / n) =
    1.6 %; the reported variance's mean is far more precise.  5 sigma = 7.8 % of r:
    r must be within 8 % of the quoted factor."""
    times = [np.array([(k + 1) * 10.0]) for k in range(10)]
    rng = np.random.default_rng(2026)
    res = simulate(rng, 0.0, times, sigma, (64, 128))
    g = fit_ramps(res, times, read_noise=sigma, threads=1, variance_rate="fit")
    r = np.mean(g.var_read + g.var_poisson) / np.mean(np.square(g.slope, dtype=float))
    assert abs(r / quoted - 1.0) < 0.08, r
