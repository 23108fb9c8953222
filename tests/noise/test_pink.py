"""Tests of the streaming 1/f synthesis (noise.pink) through the generator's time lines.

Spectra are checked against theory: a log-log slope of the averaged periodogram over
three decades, and the absolute PSD level against the amplitude definition of
``noise.params`` integrated here from scratch (``conftest._pink_level``).  Every
tolerance is five standard errors of its estimator, derived from the number of
averaged periodograms and independent bins.  Chunk independence is checked exactly.
"""

import concurrent.futures

import numpy as np
import pytest

from noise import ZERO_NOISE, NoiseGenerator, PinkSeries, pink_psd_shape, preset
from noise.clock import Detector
from noise.errors import ParameterError
from noise.pink import measure_psd_error

DET = preset("H2RG", naxis1=128, naxis2=128, n_out=4)   # 4 outputs of 32 columns
RATE = 1.0 / DET.dt                                       # 1e5 Hz pixel rate
F_MIN = ZERO_NOISE.f_min


def _slope_check(x, rate, welch, spaced_bins, fit_loglog, expected, nperseg=2 ** 15):
    """Fit the PSD slope of ``x`` from 30 Hz to 30 kHz (three decades)."""
    f, psd, K = welch(x, nperseg, rate)
    df = f[1]
    idx = spaced_bins(30.0 / df, 30e3 / df, 120)
    assert f[idx[-1]] / f[idx[0]] > 900          # at least three decades fitted
    slope, sigma = fit_loglog(f[idx], psd[idx], K)
    # K = 64 periodograms: sigma_b = log10(e)/8 = 0.054 per bin; ~100 independent bins
    # over three decades give sigma(slope) ~ 0.007, so 5 sigma ~ 0.035: tighter than
    # the +-0.05 the issue asks for.
    tol = 5 * sigma
    assert tol < 0.05
    assert abs(slope - expected) < tol, (slope, sigma)


@pytest.mark.parametrize("output", range(4))
def test_uncorrelated_pink_slope_each_output(output, welch, spaced_bins, fit_loglog):
    gen = NoiseGenerator(DET, ZERO_NOISE.replace(u_pink=1.0), rng=101, threads=1)
    x = gen.timeline("u_pink", output, 7 * DET.frame_samples, 64 * 2 ** 15)
    _slope_check(x, RATE, welch, spaced_bins, fit_loglog, -1.0)


def test_correlated_pink_slope(welch, spaced_bins, fit_loglog):
    gen = NoiseGenerator(DET, ZERO_NOISE.replace(c_pink=3.0), rng=102, threads=1)
    x = gen.timeline("c_pink", 0, 0, 64 * 2 ** 15)
    _slope_check(x, RATE, welch, spaced_bins, fit_loglog, -1.0)


@pytest.mark.parametrize("slope", [0.0, -2.0])
def test_user_spectrum_slope(slope, welch, spaced_bins, fit_loglog):
    """A user PSD table f**slope is reproduced (0: white, -2: random-walk-like)."""
    table = ((1.0, 1.0), (1e5, 1e5 ** slope))
    params = ZERO_NOISE.replace(u_pink=2.0, pink_spectrum=table)
    gen = NoiseGenerator(DET, params, rng=103, threads=1)
    x = gen.timeline("u_pink", 1, 0, 64 * 2 ** 15)
    _slope_check(x, RATE, welch, spaced_bins, fit_loglog, slope)


def test_broken_power_law_spectrum(welch, spaced_bins, fit_loglog):
    """A table with a knee: flat below 1 kHz, f^-2 above; each side has its slope."""
    table = ((1.0, 1.0), (1e3, 1.0), (1e5, 1e-4))
    params = ZERO_NOISE.replace(u_pink=2.0, pink_spectrum=table)
    gen = NoiseGenerator(DET, params, rng=104, threads=1)
    f, psd, K = welch(gen.timeline("u_pink", 0, 0, 64 * 2 ** 15), 2 ** 15, RATE)
    df = f[1]
    for (lo, hi), expected in zip(((30.0, 600.0), (2e3, 40e3)), (0.0, -2.0)):
        idx = spaced_bins(lo / df, hi / df, 80)
        slope, sigma = fit_loglog(f[idx], psd[idx], K)
        # 5 standard errors of the fitted slope (K = 64 averaged periodograms)
        assert abs(slope - expected) < 5 * sigma, (lo, hi, slope, sigma)


@pytest.mark.parametrize("component", ["u_pink", "acn", "pca0"])
def test_psd_level_matches_amplitude_definition(component, welch, pink_level):
    """Absolute level: S(f) = c/f with c fixed by amp**2 = E[frame variance].

    Each 1/f series has its own rate and frame length: pixel rate and L samples for
    u_pink; half the pixel rate and L/2 samples for each ACN parity series; the row
    rate and (ny + nfoh) samples for the picture-frame series.
    """
    amp = 1.7
    gen = NoiseGenerator(DET, ZERO_NOISE.replace(**{component: amp}), rng=105, threads=1)
    L = DET.frame_samples
    if component == "u_pink":
        rate, n, nseg, nper = RATE, L, 64, 2 ** 15
        x = gen.timeline("u_pink", 3, 0, nseg * nper)
    elif component == "acn":
        rate, n, nseg, nper = RATE / 2, L // 2, 64, 2 ** 15
        x = gen.timeline("acn", 2, 0, nseg * nper)      # (2, n): even and odd series
    else:
        rate, n, nseg, nper = 1.0 / DET.row_time, DET.ny + DET.nfoh, 256, 2 ** 12
        x = gen.timeline("pca0", 0, 0, nseg * nper)
    c = pink_level(amp, rate, n, F_MIN)
    f, psd, K = welch(x, nper, rate)
    sel = np.arange(100, nper // 2 - 1, 2)         # above the window's low-f bias
    ratio = (psd[..., sel] * f[sel] / c).ravel()
    # Each ratio is a mean of K exponentials (relative sigma 1/sqrt(K)); the bins are
    # two apart (independent with a Hann window) and the ACN parities independent, so
    # the mean of the N = ratio.size values has standard error 1/sqrt(K N).
    se = 1.0 / np.sqrt(K * ratio.size)
    assert abs(ratio.mean() - 1.0) < 5 * se, (ratio.mean(), se)


def test_amplitude_is_expected_frame_sigma():
    """amp**2 is the expected variance over one frame's time line, frame mean removed."""
    amp = 2.5
    gen = NoiseGenerator(DET, ZERO_NOISE.replace(u_pink=amp), rng=106, threads=1)
    L = DET.frame_samples
    nbatch, per = 40, 50
    x = gen.timeline("u_pink", 0, L, nbatch * per * L).reshape(nbatch * per, L)
    var = x.astype(np.float64).var(axis=1)
    # Frames of one 1/f series are not independent, so the standard error comes from
    # the scatter of the means of 40 batches of 50 consecutive frames (batch means).
    means = var.reshape(nbatch, per).mean(axis=1)
    se = means.std(ddof=1) / np.sqrt(nbatch)
    assert abs(var.mean() - amp ** 2) < 5 * se, (var.mean(), se)
    assert 5 * se < 0.1 * amp ** 2       # the check resolves the amplitude to < 10 %


def test_psd_does_not_depend_on_cube_length():
    """The first frame of a 10-frame cube is the 1-frame cube (same seed)."""
    params = ZERO_NOISE.replace(c_pink=3.0, u_pink=1.0, acn=0.5, pca0=0.2)
    one = NoiseGenerator(DET, params, rng=107, threads=1).cube(1)
    ten = NoiseGenerator(DET, params, rng=107, threads=1).cube(10)
    np.testing.assert_array_equal(ten[:, :1], one)


# ----------------------------------------------------------------- chunking
def _series(**kw):
    return PinkSeries(RATE, 5676, [1.0, 2.5], f_min=F_MIN, entropy=99,
                      seed_keys=[(3, 0), (3, 1)], **kw)


def test_pink_series_chunk_independent():
    start, n = 1000, 300_000
    whole = _series().get(start, n)
    assert whole.shape == (2, n) and whole.dtype == np.float32
    pieces, pos = [], start
    sizes = np.random.default_rng(1).integers(1, 40_000, size=100)
    series = _series()
    for size in sizes:
        take = int(min(size, start + n - pos))
        if take <= 0:
            break
        pieces.append(series.get(pos, take))
        pos += take
    np.testing.assert_array_equal(np.concatenate(pieces, axis=1), whole)
    # any order: a late range first, then an early one, from a fresh object
    series = _series()
    np.testing.assert_array_equal(series.get(start + 250_000, 777),
                                  whole[:, 250_000:250_777])
    np.testing.assert_array_equal(series.get(start + 10, 5), whole[:, 10:15])


def test_pink_series_does_not_depend_on_batch():
    """A series' samples depend only on its own seed key, not on its batch mates."""
    both = _series().get(0, 50_000)
    alone = PinkSeries(RATE, 5676, [2.5], f_min=F_MIN, entropy=99,
                       seed_keys=[(3, 1)]).get(0, 50_000)
    np.testing.assert_array_equal(alone[0], both[1])


def test_timeline_chunk_independent():
    gen = NoiseGenerator(DET, ZERO_NOISE.replace(u_pink=1.0), rng=108, threads=1)
    whole = gen.timeline("u_pink", 2, 500, 60_000)
    gen2 = NoiseGenerator(DET, ZERO_NOISE.replace(u_pink=1.0), rng=108, threads=1)
    parts = [gen2.timeline("u_pink", 2, 500 + s, 6_000) for s in range(0, 60_000, 6_000)]
    np.testing.assert_array_equal(np.concatenate(parts), whole)


def test_pink_series_scale_is_linear_in_amplitude():
    """Amplitude only scales: amp 2.5 is 2.5x amp 1 of the same seed (float32)."""
    a = PinkSeries(RATE, 5676, [1.0], f_min=F_MIN, entropy=5, seed_keys=[(1,)]).get(0, 9999)
    b = PinkSeries(RATE, 5676, [2.5], f_min=F_MIN, entropy=5, seed_keys=[(1,)]).get(0, 9999)
    np.testing.assert_allclose(b, 2.5 * a, rtol=4 * np.finfo(np.float32).eps,
                               atol=4 * np.finfo(np.float32).eps * np.abs(b).max())


def test_series_is_not_periodic(corr_sigma):
    """No wrap-around: samples one block or one frame apart are uncorrelated at high f.

    First differences of 1/f noise are nearly white; the correlation coefficient of n
    values of two such stretches has the Bartlett standard deviation (~ 1.1/sqrt(n)).
    For a stationary series the true correlation of increments falls off as lag^-2 and
    is negligible at these lags; a periodic or repeated synthesis would give r ~ 1.
    """
    gen = NoiseGenerator(DET, ZERO_NOISE.replace(u_pink=1.0), rng=109, threads=1)
    n = 200_000
    x = np.diff(gen.timeline("u_pink", 0, 0, 2 * n + 1).astype(np.float64))
    sigma = corr_sigma(x[:n], x[n:2 * n])
    for lag in (28672, DET.frame_samples, n):     # overlap-save block, frame, far
        r = np.corrcoef(x[:n], x[lag:lag + n])[0, 1]
        assert abs(r) < 5 * sigma, (lag, r, sigma)


# ----------------------------------------------------------------- PSD shape
def test_pink_psd_shape_closed_form():
    f = np.array([1e-6, 1e-4, 1.0, 250.0])
    np.testing.assert_allclose(pink_psd_shape(f, 1e-4), [1e4, 1e4, 1.0, 1 / 250.0])
    table = ((1.0, 4.0), (100.0, 0.04))              # slope -1 in log-log, level 4/f
    g = pink_psd_shape(np.array([0.5, 10.0, 1e3]), 1e-4, table)
    np.testing.assert_allclose(g, [4.0, 0.4, 0.04])  # constant beyond the table's ends


def test_timeline_window_subarray_has_pixel_rate(welch, pink_level):
    """A 1-output window keeps the pixel rate: its frame is (ny+nfoh)(nx+nroh) samples."""
    det = Detector(naxis1=256, naxis2=256, n_out=4).window(10, 20, 32, 16)
    amp = 1.0
    gen = NoiseGenerator(det, ZERO_NOISE.replace(u_pink=amp), rng=110, threads=1)
    nper = 2 ** 14
    x = gen.timeline("u_pink", 0, 0, 64 * nper)
    f, psd, K = welch(x, nper, RATE)
    c = pink_level(amp, RATE, det.frame_samples, F_MIN)
    sel = np.arange(100, nper // 2 - 1, 2)
    ratio = psd[sel] * f[sel] / c
    # mean of ratio.size independent bins, each of relative sigma 1/sqrt(K)
    se = 1.0 / np.sqrt(K * ratio.size)
    assert det.frame_samples == 17 * 44
    assert abs(ratio.mean() - 1.0) < 5 * se


def test_plan_tasks_equal_get_in_any_order_and_thread():
    """PinkSeries.plan: one task per range; any order of ranges and threads = get()."""
    whole = _series().get(0, 400_000)
    series = _series()
    out = np.full((2, 400_000), np.nan, dtype=np.float32)
    ranges = [(0, 90_000), (90_000, 150_000), (240_000, 160_000)]
    with concurrent.futures.ThreadPoolExecutor(2) as pool:
        for start, n in ranges:
            pool.submit(series.plan(start, n, out[:, start:start + n])).result()
    np.testing.assert_array_equal(out, whole)
    # a strided destination (as for the interleaved ACN pair) receives the same values
    inter = np.zeros(2 * 50_000, dtype=np.float32)
    task = _series().plan(1234, 50_000, inter.reshape(-1, 2).T)
    task()
    np.testing.assert_array_equal(inter[0::2], whole[0, 1234:51_234])
    np.testing.assert_array_equal(inter[1::2], whole[1, 1234:51_234])
    # leading axes read in C order as the series: (1, 2, n), one line's even/odd pair
    pair = np.zeros((1, 2 * 50_000), dtype=np.float32)
    _series().plan(1234, 50_000, pair.reshape(1, -1, 2).transpose(0, 2, 1))()
    np.testing.assert_array_equal(pair[0], inter)
    for bad in (np.zeros((3, 50_000), np.float32), np.zeros((2, 49_999), np.float32),
                np.zeros(100_000, np.float32)):
        with pytest.raises(ParameterError, match="'out'.*2 series.*50000 samples"):
            _series().plan(1234, 50_000, bad)


# ----------------------------------------------------------------- PSD error
def test_measure_psd_error_within_documented_tolerance():
    """Per decade: the designed PSD is within 1e-3 dex of 1/f theory (the documented
    tolerance; ~1e-4 measured), and the simulated PSD within 5 standard errors."""
    r = measure_psd_error(nperseg=2 ** 15, nseg=32, rng=113)
    assert set(r["design"]) == set(r["measured"]) == {
        "30-300 Hz", "300-3000 Hz", "3000-30000 Hz"}
    for key, dev in r["design"].items():
        assert dev < 1e-3, (key, dev)
        # max over 10 sub-bands of |log10 ratio|, each within 5 of its standard errors
        assert r["measured"][key] < dev + 5 * r["measured_sigma"][key], (key, r)
    # a linear filter of Gaussian inputs is Gaussian: excess kurtosis 0 within 5 SE
    assert abs(r["measured_kurtosis"]) < 5 * r["kurtosis_sigma"]
    assert r["seconds_per_msample"] > 0
