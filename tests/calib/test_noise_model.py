"""Tests of :mod:`scenesim.calib.noise_model`: the effective read noise measured from
the ramps, and the common mode of a group of pixels.

Ramps and reference variances come from ``tests/ramp_sim.py`` (built from the read
times alone, independently of the simulator and of the package's formulas).
"""

import numpy as np
import pytest

from noise.errors import ParameterError
from ramp_sim import READOUTS, SIGMA, jwst_times, simulate
from scenesim.calib.noise_model import common_mode, measure_read_noise
from scenesim.detector.dq import JUMP_DET
from scenesim.rampfit import fit_ramps, optimal_variance


@pytest.mark.parametrize("name", list(READOUTS))
def test_measure_read_noise_recovers_white_noise(name):
    times = READOUTS[name]()
    rng = np.random.default_rng([23, len(times)])
    shape = (128, 96)
    col = np.arange(shape[1]) // 32                    # groups 0, 1, 2 by column
    groups = np.broadcast_to(col, shape).astype(np.int64)
    sig_true = np.array([11.0, 13.0, 12.0])[col]       # per read, e-
    rate = np.full(shape, 0.1)
    bright = rng.random(shape) < 0.3
    bright[:, 64:] = True                              # group 2: no read-dominated pixel
    rate[bright] = 1e4
    res = simulate(rng, rate, times, sig_true[None, :], shape)
    rn = measure_read_noise(res, times, read_noise=8.0, groups=groups)
    assert rn.shape == shape and np.all(rn == rn[0])          # one value per group
    assert np.all(rn[0] == rn[0, col * 32])
    # Each group's estimate is the median over N ~ 0.7 * 128 * 32 read-dominated
    # pixels of chi2 / med_nu (1e4 e-/s pixels are Poisson dominated and left out),
    # whose standard deviation is sqrt(2 / dof): standard error of k^2
    # 1.2533 sqrt(2 / dof) / sqrt(N), of k half of it.  5 sigma, plus 1 % for the
    # chi2 of the first fit being ~1 % low at the lowest rates (its covariance uses
    # the clipped fitted rate, above the true one half of the time).
    n = 0.7 * 128 * 32
    dof = len(times) - 2
    tol = 5 * 0.5 * 1.2533 * np.sqrt(2 / dof) / np.sqrt(n) + 0.01
    for grp, true in ((0, 11.0), (1, 13.0)):
        assert rn[0, grp * 32] / true == pytest.approx(1, abs=tol)
    # Group 2 falls back on the median over all read-dominated pixels.
    assert 11.0 * (1 - tol) < rn[0, 64] < 13.0 * (1 + tol)
    # No read-dominated pixel at all: the model value is returned unchanged.
    rn_b = measure_read_noise(res[:, :, 64:], times, read_noise=8.0,
                              groups=groups[:, 64:])
    assert np.all(rn_b == 8.0)
    with pytest.raises(ParameterError, match="groups"):
        measure_read_noise(res, times, read_noise=8.0, groups=groups[:, :5])
    with pytest.raises(ParameterError, match="max_rows"):
        measure_read_noise(res, times, read_noise=8.0, groups=groups, max_rows=0)


def test_common_mode_removes_shared_wander_and_false_jumps():
    # Two "outputs" (64 columns each) share a slow random walk of their reads (the
    # 1/f noise of an output's amplifier); the white noise is 8 e- while the model
    # says 6 e-; 3 % of the pixels are hit by a cosmic ray.
    times = jwst_times(30)
    ng = len(times)
    rng = np.random.default_rng(31)
    shape = (128, 128)
    sig_true, sig_model, rate = 8.0, 6.0, 0.2
    groups = np.broadcast_to(np.arange(shape[1]) // 64, shape).astype(np.int64)
    sig_d = np.sqrt(2) * sig_true
    hit = rng.random(shape) < 0.03
    t_hit = rng.uniform(times[0][0], times[-1][-1], shape)
    amp = np.where(hit, rng.uniform(10, 40, shape) * sig_d, 0.0)
    res = simulate(rng, rate, times, sig_true, shape, hits=(t_hit, amp))
    wander = np.cumsum(rng.normal(0, 3.0, (ng, 2)), axis=0)      # e-, per group
    res += wander[:, groups]
    phi = np.stack([np.mean(t[:, None, None] > t_hit[None], axis=0) for t in times])
    strong = hit & ((amp[None] * np.diff(phi, axis=0)).max(axis=0) >= 10 * sig_d)
    clean = ~hit

    def rates(g):
        flagged = (g.dq & JUMP_DET) > 0
        return np.mean(flagged[clean]), np.mean(flagged[strong])

    # Null check: the white-noise model flags the wander as jumps (the step test
    # sees it), far above the nominal 29 Q(5) = 8.3e-6 per clean pixel (> 100 x
    # that; 1.8e-3 since the jump test takes its rate at the upper 2-sigma value,
    # which weighs the ramp's smooth components more, 1.3e-2 before).
    fp0, _ = rates(fit_ramps(res, times, read_noise=sig_model, jump_threshold=5.0))
    assert fp0 > 100 * 29 * 2.87e-7, fp0
    # The offsets: the wander minus its GLS-weighted mean rate, C_k = W_k - W_0 -
    # <m>_w (tbar_k - tbar_0), weights w = C^-1 1 for the covariance of white-noise
    # rate differences (single reads: 2 s^2/dt^2 on the diagonal, -s^2/dt^2 beside).  The running sum of per-difference medians over N pixels telescopes
    # to ~ a median of R_k - R_0, standard error 1.2533 sqrt(2) sigma / sqrt(N)
    # (N = 64 rows x 64 columns x 0.97 unhit, the default 64-row subsample); 5 sigma.
    C = common_mode(res, times, read_noise=sig_model, groups=groups)
    assert C.shape == (1, ng, 2)
    tb = np.array([t.mean() for t in times])
    m = np.diff(wander, axis=0) / np.diff(tb)[:, None]
    dtb = np.diff(tb)
    cov = (np.diag(2 / dtb ** 2) - np.diag(1 / (dtb[:-1] * dtb[1:]), 1)
           - np.diag(1 / (dtb[:-1] * dtb[1:]), -1))
    w = np.linalg.solve(cov, np.ones(dtb.size))
    w /= w.sum()
    expected = np.concatenate([np.zeros((1, 2)), np.cumsum(
        (m - w @ m) * dtb[:, None], axis=0)])
    se = 1.2533 * np.sqrt(2) * sig_true / np.sqrt(64 * 64 * 0.97)
    assert np.max(np.abs(C[0] - expected)) < 5 * se
    corrected = res - C[0][:, groups]
    # Read noise from the corrected ramps: 8 e- (see the white-noise test for the
    # tolerance: N = 128 x 64 x 0.97, dof = 28, 5 sigma plus 1 %).
    rn = measure_read_noise(corrected, times, read_noise=sig_model, groups=groups)
    tol = 5 * 0.5 * 1.2533 * np.sqrt(2 / 28) / np.sqrt(128 * 64 * 0.97) + 0.01
    np.testing.assert_allclose(rn / sig_true, 1, atol=tol)
    # Requirement: >= 99 % of the hits above 10 sigma found, < 0.5 % of the clean
    # pixels flagged.  With white noise and the right sigma the statistic is
    # N(0, 1): 2 Q(5) = 5.7e-7 per test, < 2e-5 per pixel for 29 differences.
    fp, found = rates(fit_ramps(corrected, times, read_noise=rn, jump_threshold=5.0))
    assert fp < 0.005 and found >= 0.99, (fp, found)
    with pytest.raises(ParameterError, match="saturated"):
        common_mode(res, times, read_noise=6.0, groups=groups,
                    saturated=np.zeros((3, 3), bool))


@pytest.mark.parametrize("name", list(READOUTS))
def test_common_mode_leaves_read_noise_limited_slopes_unbiased(name):
    """White noise only, rate 0: there is no common mode, and removing the estimated
    one must not move the slopes (its GLS-weighted mean rate is kept)."""
    times = READOUTS[name]()
    rng = np.random.default_rng(77)
    shape = (128, 128)
    res = simulate(rng, 0.0, times, SIGMA, shape)
    groups = np.broadcast_to(np.arange(shape[1]) // 32, shape).astype(np.int64)
    C = common_mode(res, times, read_noise=SIGMA, groups=groups)
    before = fit_ramps(res, times, read_noise=SIGMA, variance_rate="fit")
    after = fit_ramps(res - C[0][:, groups], times, read_noise=SIGMA,
                      variance_rate="fit")
    sig = np.sqrt(optimal_variance(0.0, times, SIGMA))
    shift = (after.slope.astype(float) - before.slope) / sig
    # The offsets' own GLS slope is 0 at the rate-0 weights; the fit's weights use
    # each pixel's fitted rate (|f| ~ 1 sigma), which changes the weights by
    # q_p sigma_f / V ~ a few %, so the per-group shift is < 0.05 x the offsets'
    # largest rate (~ 1.25 sqrt(2) sigma_d / sqrt(4096 pixels) ~ 0.03 sigma): the
    # bound 0.01 sigma is ~ 7x that.  The unweighted mean left 0.07-0.5 sigma.
    assert np.max(np.abs([shift[groups == g].mean() for g in range(4)])) < 0.01


@pytest.mark.parametrize("n", [1, 2, 7, 40])
def test_tridiagonal_solve_solves_the_system(n):
    """The rate-0 weights' solver (fixed-order elimination, no LAPACK) against the
    system itself: for a random symmetric positive-definite tridiagonal A (diagonal
    dominant), ||A x - b|| / ||b|| is at the float64 rounding level (< 1e-13: the
    backward error of elimination on such a matrix is a few n eps)."""
    from scenesim.calib.noise_model import _solve_tridiagonal
    rng = np.random.default_rng(n)
    off = -rng.uniform(0.1, 0.5, n - 1)
    diag = rng.uniform(1.5, 2.5, n)
    a = np.diag(diag) + np.diag(off, 1) + np.diag(off, -1)
    b = rng.normal(size=n)
    x = _solve_tridiagonal(diag, off, b)
    assert np.linalg.norm(a @ x - b) / np.linalg.norm(b) < 1e-13


def test_measure_read_noise_on_whole_dn_differences():
    # 5-frame groups at 4 e-/DN and 3 e- per read: a resultant's noise is ~0.4 DN,
    # the differences are whole DN and chi2 takes a few values (many pixels exactly
    # 0). The median-based estimate read 13 % high (3.64 e- for 3.21; probe: errors
    # 12 % too large through the CLI). The trimmed mean: within 3 % of the per-read
    # white noise sqrt(3^2 + 4^2/12) (its standard error over 65536 pixels is 0.1 %;
    # the additive quantisation model itself holds to ~2 % at 0.4 DN per resultant,
    # docs/VALIDATION_FIT.md), with the rounding of the group means passed.
    from noise.adc import averaging_noise
    rng = np.random.default_rng(3)
    times = jwst_times(8, nframes=5, groupgap=1)
    res = simulate(rng, 0.002, times, 3.0, (256, 256), gain=4.0)
    q = averaging_noise(4.0, [len(t) for t in times])
    want = float(np.hypot(3.0, 4.0 / np.sqrt(12)))
    rn = measure_read_noise(res, times, read_noise=1.3 * want, resultant_noise=q,
                            groups=np.zeros((256, 256), int), max_rows=256, threads=1)
    assert abs(float(rn[0, 0]) / want - 1) < 0.03, (float(rn[0, 0]), want)
