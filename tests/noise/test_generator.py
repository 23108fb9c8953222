"""Acceptance tests of noise.NoiseGenerator: each component against theory.

Each statistical check compares an estimator with a closed form and allows five
standard errors of that estimator, derived from the sample size and written next to the
assertion.  Where a statistic's sampling distribution has no simple closed form (frame
variances of 1/f series), independent seeds give independent samples and the standard
error is their scatter over sqrt(N).  Structural properties (where a time-line sample
lands in the image, what cancels in CDS, which draws a zero amplitude leaves unchanged)
are checked exactly.

Small detectors keep the file fast; ``Detector(..., nroh=0, nfoh=0)`` makes the image
of a 1-output detector exactly its time line, so frame statistics match the amplitude
definition exactly (no overhead samples missing from the image).
"""

import dataclasses

import numpy as np
import pytest
from scipy.special import polygamma

from noise import (NIRSPEC_DEFAULTS, ZERO_NOISE, Detector, NoiseGenerator, NoiseParams,
                   preset, synthetic_template, template_for, to_dn)
import noise
from noise.generator import Layout
from noise.errors import ParameterError

DET = preset("H2RG", naxis1=128, naxis2=128, n_out=4)     # 4 outputs of 32 columns
RATE = 1.0 / DET.dt


def _gen(params, det=DET, rng=1, threads=1):
    return NoiseGenerator(det, params, rng=rng, threads=threads)


def _section(img, det, o):
    """Section of output ``o`` in that output's own time order (flipped if reversed)."""
    n = det.ncols_out
    sec = img[..., o * n:(o + 1) * n]
    return sec[..., ::-1] if det.output_reversed(o) else sec


# ================================================================== white noise
def test_white_noise_cds_sigma_and_reference_ratio():
    rd, ratio = 5.2, 0.8
    cube = _gen(ZERO_NOISE.replace(rd_noise=rd, ref_ratio=ratio), rng=11).cube(10)[0]
    cds = (cube[1::2] - cube[0::2]).astype(np.float64)     # 5 independent CDS pairs
    ref = DET.reference_mask()
    for values, sigma in ((cds[:, ~ref], np.sqrt(2) * rd),
                          (cds[:, ref], np.sqrt(2) * rd * ratio)):
        n = values.size
        # Gaussian sample std: standard error sigma / sqrt(2 N); mean: sigma / sqrt(N)
        assert abs(values.std() - sigma) < 5 * sigma / np.sqrt(2 * n), (values.std(), n)
        assert abs(values.mean()) < 5 * sigma / np.sqrt(n)


def test_white_noise_per_output_amplitudes():
    rd = (1.0, 2.0, 3.0, 4.0)
    frame = _gen(ZERO_NOISE.replace(rd_noise=rd), rng=12).cube(1)[0, 0].astype(np.float64)
    ref = DET.reference_mask()
    for o in range(4):
        values = frame[:, 32 * o:32 * (o + 1)][~ref[:, 32 * o:32 * (o + 1)]]
        # standard error of a Gaussian sample std: sigma / sqrt(2 N)
        assert abs(values.std() - rd[o]) < 5 * rd[o] / np.sqrt(2 * values.size)


@pytest.mark.slow
def test_full_h2rg_white_noise_cds_sigma():
    det = preset("H2RG")
    cube = NoiseGenerator(det, ZERO_NOISE.replace(rd_noise=5.2), rng=13,
                          threads=2).cube(2)[0]
    cds = (cube[1] - cube[0]).astype(np.float64)[~det.reference_mask()]
    sigma = np.sqrt(2) * 5.2
    # 2040^2 regular pixels: standard error of the std sigma / sqrt(2 N) ~ 0.05 %
    assert abs(cds.std() - sigma) < 5 * sigma / np.sqrt(2 * cds.size)


# ================================================================== correlated pink
@pytest.mark.parametrize("det", [
    DET, dataclasses.replace(DET, reverse_scan=True), DET.stripe(20, 40),
    DET.window(30, 50, 24, 16),
], ids=["full", "reverse_scan", "stripe", "window"])
def test_correlated_pink_identical_on_all_outputs(det):
    gen = _gen(ZERO_NOISE.replace(c_pink=3.0), det=det, rng=21)
    L = det.frame_samples
    idx = det.pixel_sample_index()
    for _, k, img in gen.frames(3):
        slot = 1 + k
        line = gen.timeline("c_pink", 0, slot * L, L)
        np.testing.assert_array_equal(img, line[idx])      # placed by the one clock
        for o in range(1, det.n_out_active):
            np.testing.assert_array_equal(_section(img, det, o), _section(img, det, 0))
    assert np.std(img) > 0


def _coherence(x, y, nper):
    """Mean magnitude-squared coherence over independent bins, and K, J."""
    K = x.size // nper
    w = np.hanning(nper)

    def spec(z):
        seg = z[:K * nper].reshape(K, nper).astype(np.float64)
        return np.fft.rfft((seg - seg.mean(axis=1, keepdims=True)) * w, axis=1)

    X, Y = spec(x), spec(y)
    j = np.arange(8, nper // 2 - 8, 2)          # bins 2 apart: independent (Hann)
    X, Y = X[:, j], Y[:, j]
    coh = np.abs((X * Y.conj()).sum(0)) ** 2 / (
        (np.abs(X) ** 2).sum(0) * (np.abs(Y) ** 2).sum(0))
    return coh.mean(), K, j.size


# 2 outputs, no overheads: each output's section, in its own scan order, is its time line
DET2 = Detector(name="T", naxis1=128, naxis2=256, n_out=2, nroh=0, nfoh=0, ref_border=0)


@pytest.mark.parametrize("c_pink, u_pink", [(0.0, 1.0), (3.0, 1.0)])
def test_output_coherence(c_pink, u_pink):
    """Coherence between outputs: 0 for uncorrelated pink, (c^2/(c^2+u^2))^2 with both.

    Both series share the PSD shape and frame length, so their PSDs are in the ratio
    c^2 : u^2 and the true magnitude-squared coherence is
    gamma^2 = [c^2 / (c^2 + u^2)]^2 at every frequency.
    """
    params = ZERO_NOISE.replace(c_pink=c_pink, u_pink=u_pink)
    cube = _gen(params, det=DET2, rng=22).cube(64)[0]
    x = _section(cube, DET2, 0).reshape(-1)
    y = _section(cube, DET2, 1).reshape(-1)
    coh, K, J = _coherence(x, y, 4096)
    g2 = (c_pink ** 2 / (c_pink ** 2 + u_pink ** 2)) ** 2
    # Averaging K segments: E[coh] = gamma^2 + (1 - gamma^2)^2 / K (Carter 1973), and
    # per bin Var = (1 - gamma^2)^2 [2 gamma^2 + 1/K] / K  (for gamma = 0 this is the
    # Beta(1, K-1) variance ~ 1/K^2); the mean over J independent bins divides it by J.
    expected = g2 + (1 - g2) ** 2 / K
    se = (1 - g2) * np.sqrt((2 * g2 + 1.0 / K) / K / J)
    assert abs(coh - expected) < 5 * se, (coh, expected, se)


def test_uncorrelated_pink_time_lines_uncorrelated(corr_sigma):
    """Zero-lag correlation of the outputs' whitened time lines is 0 within 5 sigma.

    First differences of a 1/f series are nearly white (rho_1 ~ -0.26), so
    N_eff = N / (1 + 2 sum rho_x rho_y) ~ N / 1.2 (Bartlett), estimated from the data.
    """
    gen = _gen(ZERO_NOISE.replace(u_pink=1.0), rng=23)
    n = 400_000
    lines = np.diff(np.array([gen.timeline("u_pink", o, 0, n + 1) for o in range(4)],
                             dtype=np.float64), axis=1)
    r = np.corrcoef(lines)
    for a in range(4):
        for b in range(a + 1, 4):
            sigma = corr_sigma(lines[a], lines[b])       # ~ 1/sqrt(N_eff)
            assert abs(r[a, b]) < 5 * sigma, (a, b, r[a, b], sigma)


def test_per_output_pink_amplitudes():
    """u_pink=(0, 1, 0, 2): outputs 0, 2 silent; output 3 has 4x the power of output 1."""
    det = Detector(name="T", naxis1=256, naxis2=128, n_out=4, nroh=0, nfoh=0,
                   ref_border=0)
    cube = _gen(ZERO_NOISE.replace(u_pink=(0.0, 1.0, 0.0, 2.0)), det=det,
                rng=24).cube(32)[0]
    assert not cube[..., 0:64].any() and not cube[..., 128:192].any()
    # same seed, amplitude 1 on output 3: exactly half (scaling by 2 is exact in float32)
    one = _gen(ZERO_NOISE.replace(u_pink=(0.0, 0.0, 0.0, 1.0)), det=det,
               rng=24).cube(32)[0]
    np.testing.assert_array_equal(cube[..., 192:], 2 * one[..., 192:])
    # statistically: mean log ratio of the averaged periodograms of outputs 3 and 1
    nper = 4096
    lines = [_section(cube, det, o).reshape(-1).astype(np.float64) for o in (1, 3)]
    K = lines[0].size // nper
    w = np.hanning(nper)
    psd = [(np.abs(np.fft.rfft(z[:K * nper].reshape(K, nper) * w, axis=1)) ** 2).mean(0)
           for z in lines]
    j = np.arange(8, nper // 2 - 8, 2)
    lr = np.log(psd[1][j] / psd[0][j])
    # ln of a mean of K exponentials has variance psi1(K); the difference of two
    # independent ones 2 psi1(K) with zero mean bias; J independent bins.
    se = np.sqrt(2 * polygamma(1, K) / j.size)
    assert abs(lr.mean() - np.log(4.0)) < 5 * se, (lr.mean(), se)


# ================================================================== ACN
def test_acn_placement_even_odd_columns():
    """ACN: even and odd samples of each output's time line are two series, in place."""
    det = dataclasses.replace(DET, reverse_scan=False)
    gen = _gen(ZERO_NOISE.replace(acn=2.0), det=det, rng=31)
    L = det.frame_samples
    idx = det.pixel_sample_index()
    for _, k, img in gen.frames(2):
        slot = 1 + k
        for o in range(4):
            even, odd = gen.timeline("acn", o, slot * (L // 2), L // 2)
            line = np.empty(L, dtype=np.float32)
            line[0::2], line[1::2] = even, odd
            cols = slice(32 * o, 32 * (o + 1))
            np.testing.assert_array_equal(img[:, cols], line[idx[:, cols]])


DET1 = Detector(name="T", naxis1=256, naxis2=256, n_out=1, nroh=0, nfoh=0, ref_border=0)


def test_acn_spectrum_line_at_nyquist(welch, pink_level):
    """PSD of an output's time line with ACN + white noise, against the closed form.

    With independent even/odd series a, b of one-sided PSD S_h (rate r/2), the
    interleaved line has S(f) = S_h(f)/2 for f < r/4 and S_h(r/2 - f)/2 above (its
    autocovariance is R_a(n/2) at even lags, 0 at odd ones): a 1/f rise at low f and a
    line at Nyquist r/2 with a 1/(f_nyq - f) wing, on top of white 2 sigma^2 / r.
    """
    acn, rd = 3.0, 5.0
    cube = _gen(ZERO_NOISE.replace(acn=acn, rd_noise=rd), det=DET1, rng=32).cube(64)
    nper = 2 ** 14
    f, psd, K = welch(cube.reshape(-1), nper, RATE)
    white = 2 * rd ** 2 / RATE
    c_h = pink_level(acn, RATE / 2, DET1.frame_samples // 2, ZERO_NOISE.f_min)
    nyq = RATE / 2
    # the line: top 3 bins vs the white level.  The model gives >= c_h/(2*3 df) ~ 70x
    # white there; a 3-bin mean of K = 256 periodograms has relative sigma 4 %, so 20x
    # is many sigma below the expectation while still "far above white".
    assert psd[-4:-1].mean() > 20 * white
    df = f[1]
    for lo, hi in ((200.0, 5e3), (15e3, 35e3), (nyq - 5e3, nyq - 200.0)):
        j = np.arange(int(lo / df), int(hi / df), 2)      # bins 2 apart: independent
        model = white + c_h / 2 / np.minimum(f[j], nyq - f[j])
        ratio = psd[j] / model
        # mean of J ratios, each a mean of K exponentials (relative sigma 1/sqrt(K));
        # Hann smoothing bias <= 1/(3 k^2) ~ 3e-4 at k >= 33 bins from 0 or Nyquist.
        se = 1.0 / np.sqrt(K * j.size)
        assert abs(ratio.mean() - 1.0) < 5 * se, (lo, hi, ratio.mean(), se)


def test_acn_wing_rises_toward_nyquist(welch, spaced_bins, fit_loglog):
    """ACN alone: PSD ~ (f_nyq - f)^-1 over two decades of f_nyq - f (100 Hz - 10 kHz)."""
    cube = _gen(ZERO_NOISE.replace(acn=3.0), det=DET1, rng=33).cube(64)
    nper = 2 ** 14
    f, psd, K = welch(cube.reshape(-1), nper, RATE)
    df = f[1]
    k = spaced_bins(100 / df, 1e4 / df, 100)          # distance from Nyquist in bins
    j = nper // 2 - k
    slope, sigma = fit_loglog(RATE / 2 - f[j], psd[j], K)
    # K = 256 averaged periodograms: sigma(slope) ~ 0.005 from ~80 independent bins
    assert 5 * sigma < 0.05
    assert abs(slope + 1.0) < 5 * sigma, (slope, sigma)
    # the power increases toward Nyquist across the decade 1 kHz -> 100 Hz
    near = psd[nper // 2 - int(100 / df)]
    far = psd[nper // 2 - int(1000 / df)]
    assert near > 5 * far          # expected ratio 10; each value has sigma 6 %


def test_acn_even_minus_odd_variance():
    """E[var(even - odd)] / 2 = acn^2 per frame (frame mean removed).

    On a 1-output detector without overheads the frame holds exactly L/2 samples of
    each parity series; the two are independent, so the expected mean-removed variance
    of their difference is 2 acn^2 by the amplitude definition.
    """
    acn = 2.0
    det = Detector(name="T", naxis1=64, naxis2=64, n_out=1, nroh=0, nfoh=0, ref_border=0)
    vals = []
    for seed in range(100):
        img = _gen(ZERO_NOISE.replace(acn=acn), det=det, rng=seed).cube(1)[0, 0]
        d = img[:, 0::2].astype(np.float64) - img[:, 1::2]
        vals.append(d.var() / 2)
    vals = np.array(vals)
    # 100 independent seeds: standard error = sample std / sqrt(100)
    se = vals.std(ddof=1) / np.sqrt(vals.size)
    assert abs(vals.mean() - acn ** 2) < 5 * se, (vals.mean(), se)
    assert 5 * se < 0.2 * acn ** 2


# ================================================================== pedestal, kTC, bias
def test_pedestal_common_per_frame():
    ped = 4.0
    det = Detector(name="T", naxis1=16, naxis2=16, n_out=1, ref_border=1)
    cube = _gen(ZERO_NOISE.replace(pedestal=ped), det=det, rng=41).cube(1000, nints=3)
    frames = cube.reshape(-1, 16 * 16)
    assert np.all(frames == frames[:, :1])           # one value for all pixels
    v = frames[:, 0].astype(np.float64)
    n = v.size                                       # 3000 independent frames
    # Gaussian: std has standard error sigma/sqrt(2N), mean sigma/sqrt(N)
    assert abs(v.std() - ped) < 5 * ped / np.sqrt(2 * n), v.std()
    assert abs(v.mean()) < 5 * ped / np.sqrt(n)
    # independent from frame to frame: lag-1 correlation within 5/sqrt(N)
    assert abs(np.corrcoef(v[:-1], v[1:])[0, 1]) < 5 / np.sqrt(n - 1)


def test_pedestal_does_not_depend_on_request_order():
    """Offsets are drawn per block of slots; any order of requests gives each slot's
    value (across a block edge too)."""
    slots = [5, 2000, 1023, 1024, 3, 4096, 1024]
    gen = _gen(ZERO_NOISE.replace(pedestal=4.0), rng=42)
    got = [gen.pedestal(s) for s in slots]
    want = [_gen(ZERO_NOISE.replace(pedestal=4.0), rng=42).pedestal(s) for s in slots]
    assert got == want
    assert len(set(got)) == len(set(slots))


def test_ktc_and_bias_per_integration():
    ktc, offset, amp = 29.0, 5000.0, 500.0
    params = ZERO_NOISE.replace(ktc=ktc, bias_offset=offset, bias_amp=amp)
    cube = _gen(params, rng=42).cube(4, nints=3).astype(np.float64)
    # identical in every frame of an integration: CDS is exactly zero
    assert not np.diff(cube, axis=1).any()
    # different between integrations: two independent kTC draws round to the same
    # float32 (ulp 4.9e-4 e- near 5000 e-) with probability ~ ulp * pdf_diff(0) =
    # 4.9e-4 / (sqrt(2 pi) * sqrt(2) * 29) = 4.8e-6 per pixel, i.e. 0.08 of the 16384
    # pixels expected; 4 or more coincidences have Poisson probability 1.6e-6.
    assert np.count_nonzero(cube[0, 0] == cube[1, 0]) <= 3
    template = template_for(DET).astype(np.float64)
    n = DET.nx * DET.ny
    for i in range(3):
        k = cube[i, 0] - offset - amp * template          # the kTC field
        # tolerance: float32 storage of ~5000 e- values (ulp 5e-4) is negligible;
        # Gaussian std error sigma/sqrt(2N), mean error sigma/sqrt(N)
        assert abs(k.std() - ktc) < 5 * ktc / np.sqrt(2 * n)
        assert abs(k.mean()) < 5 * ktc / np.sqrt(n)
    diff = (cube[1, 0] - cube[0, 0]).ravel()
    # kTC redrawn: the difference has sigma sqrt(2) ktc (standard error as above)
    assert abs(diff.std() - np.sqrt(2) * ktc) < 5 * np.sqrt(2) * ktc / np.sqrt(2 * n)
    # and the two kTC fields are uncorrelated: |r| < 5/sqrt(N)
    k0, k1 = (cube[i, 0] - offset - amp * template for i in (0, 1))
    assert abs(np.corrcoef(k0.ravel(), k1.ravel())[0, 1]) < 5 / np.sqrt(n)


@pytest.mark.parametrize("window", [None, (500, 500, 64, 64), (0, 2000, 48, 30),
                                    (2040, 0, 8, 2048)])
def test_template_range_is_the_templates_least_and_largest_value(window):
    # template_range works from the separable form (no image): it must give the
    # image's own extremes, exactly (both are float32 of the same float64 values)
    from noise.template import template_range
    det = preset("H2RG") if window is None else preset("H2RG").window(*window)
    t = template_for(det)
    assert template_range(det) == (float(t.min()), float(t.max()))


def test_a_template_file_gives_a_window_the_full_frames_values(tmp_path):
    # A full-array template file is normalised (zero median, unit robust sigma) on
    # the full array, then cut: a window's bias pattern is the full frame's there
    # (a probe: normalised on the window alone, 1998 e- apart at bias_amp 500).  An
    # image of the window's shape only is normalised as given.
    from astropy.io import fits
    rng = np.random.default_rng(0)
    img = rng.normal(size=(256, 256))
    img[:, :128] += 10.0
    path = tmp_path / "t.fits"
    fits.writeto(path, img)
    full = preset("H2RG", naxis1=256, naxis2=256)
    win = full.window(0, 0, 64, 64)
    med = np.median(img)
    mad = 1.4826 * np.median(np.abs(img - med))
    np.testing.assert_allclose(template_for(win, str(path)),
                               ((img - med) / mad)[:64, :64], rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(template_for(win, str(path)),
                                  template_for(full, str(path))[:64, :64])
    p = ZERO_NOISE.replace(bias_amp=500.0, pca0_file=str(path))
    a = NoiseGenerator(full, p, rng=1, threads=1).cube(1)[0, 0, :64, :64]
    b = NoiseGenerator(win, p, rng=1, threads=1).cube(1)[0, 0]
    np.testing.assert_array_equal(a, b)
    # a NaN anywhere is refused, naming it (it had made the whole pattern 0)
    from noise.errors import FileFormatError
    bad = img.copy()
    bad[5, 7] = np.nan
    fits.writeto(tmp_path / "nan.fits", bad)
    with pytest.raises(FileFormatError, match=r"1 NaN or inf values \(the first at "
                                              r"row 5, column 7\)"):
        template_for(win, str(tmp_path / "nan.fits"))
    small = tmp_path / "w.fits"
    fits.writeto(small, img[:64, :64])
    part = img[:64, :64]
    m = np.median(part)
    np.testing.assert_allclose(template_for(win, str(small)),
                               (part - m) / (1.4826 * np.median(np.abs(part - m))),
                               rtol=1e-6, atol=1e-6)


def test_bias_pattern_is_template():
    params = ZERO_NOISE.replace(bias_offset=1000.0, bias_amp=300.0)
    img = _gen(params, rng=43).cube(1)[0, 0]
    expected = np.float32(1000.0) + np.float32(300.0) * template_for(DET)
    np.testing.assert_array_equal(img, expected)


# ================================================================== picture frame
def test_picture_frame_is_template_times_row_series():
    gen = _gen(ZERO_NOISE.replace(pca0=2.0), rng=51)
    template = template_for(DET)
    ny = DET.ny
    for _, k, img in gen.frames(3):
        slot = 1 + k
        s = gen.timeline("pca0", 0, slot * (ny + DET.nfoh), ny)
        np.testing.assert_array_equal(img, template * s[:, None])
        # rank one per row: img / template is one value along each row
        nz = template != 0
        ratio = np.where(nz, img / np.where(nz, template, 1), np.nan)
        spread = np.nanmax(ratio, axis=1) - np.nanmin(ratio, axis=1)
        assert np.all(spread <= 1e-5 * np.abs(s))      # float32 rounding only


def test_picture_frame_amplitude():
    """E[var over a frame's rows of s] = pca0^2 when the frame has no overhead rows."""
    pca0 = 2.0
    det = Detector(name="T", naxis1=64, naxis2=64, n_out=1, nroh=12, nfoh=0,
                   ref_border=0)
    template = template_for(det).astype(np.float64)
    vals = []
    for seed in range(150):
        img = _gen(ZERO_NOISE.replace(pca0=pca0), det=det, rng=seed).cube(1)[0, 0]
        s = (img * template).sum(1) / (template ** 2).sum(1)   # per-row least squares
        vals.append(s.var())
    vals = np.array(vals)
    # 150 independent seeds: standard error = sample std / sqrt(150)
    se = vals.std(ddof=1) / np.sqrt(vals.size)
    assert abs(vals.mean() - pca0 ** 2) < 5 * se, (vals.mean(), se)
    assert 5 * se < 0.3 * pca0 ** 2


@pytest.mark.parametrize("shape", [(256, 256), (255, 129), (64, 300), (2, 2), (1, 7)])
def test_synthetic_template_matches_its_definition(shape):
    # The documented definition, built directly: exp(-d/w) + 0.1 y/(ny-1), then zero
    # median and unit robust sigma (std when the MAD is 0).  The fast path (separable
    # form, statistics by counting) must agree to float64 rounding (1e-12).
    ny, nx = shape
    y = np.arange(ny, dtype=float)[:, None]
    x = np.arange(nx, dtype=float)[None, :]
    d = np.minimum(np.minimum(y, ny - 1 - y), np.minimum(x, nx - 1 - x))
    img = np.exp(-d / max(min(nx, ny) / 24.0, 1.0)) + 0.1 * y / max(ny - 1, 1)
    med = np.median(img)
    sig = np.median(np.abs(img - med)) * 1.4826
    sig = sig if sig > 0 else img.std()
    expected = (img - med) / sig if sig > 0 else np.zeros_like(img)
    np.testing.assert_allclose(synthetic_template(ny, nx), expected, rtol=0, atol=1e-12)


def test_synthetic_template_normalised_and_edge_bright():
    t = synthetic_template(256, 256)
    assert t.shape == (256, 256)
    med = np.median(t)
    assert abs(med) < 1e-12
    assert np.median(np.abs(t - med)) * 1.4826 == pytest.approx(1.0, rel=1e-12)
    edge = np.r_[t[:8].ravel(), t[-8:].ravel(), t[:, :8].ravel(), t[:, -8:].ravel()]
    assert edge.mean() > t[64:192, 64:192].mean() + 3      # strongest near the edges
    # subarrays see their part of the full-array template
    det = preset("H2RG", naxis1=256, naxis2=256).window(10, 20, 32, 16)
    np.testing.assert_array_equal(template_for(det), t[20:36, 10:42].astype(np.float32))


# ================================================================== RTN
def test_random_telegraph_noise():
    frac, amp = 0.2, 20.0
    tf = DET.frame_time
    tau_low, tau_high = 5 * tf, 3 * tf
    params = ZERO_NOISE.replace(rtn_fraction=frac, rtn_amp=amp, rtn_tau_low=tau_low,
                                rtn_tau_high=tau_high)
    nframes = 200
    cube = _gen(params, rng=61).cube(nframes)[0]
    assert set(np.unique(cube).tolist()) <= {0.0, amp}       # two levels amp apart
    high = cube == amp
    rtn = high.any(axis=0)
    ref = DET.reference_mask()
    assert not rtn[ref].any()                                # regular pixels only
    n_reg = int((~ref).sum())
    # A pixel in the low state stays low over one frame with probability 0.85, so an
    # RTN pixel never seen high in 200 frames has probability < 1e-14: rtn == RTN pixels.
    # Binomial count: sigma = sqrt(N p (1 - p)).
    assert abs(rtn.sum() - frac * n_reg) < 5 * np.sqrt(n_reg * frac * (1 - frac))
    states = high[:, rtn].T.astype(np.float64)               # (pixels, frames)
    p_high = tau_high / (tau_low + tau_high)
    rho = np.exp(-tf * (1 / tau_low + 1 / tau_high))         # lag-1 autocorrelation
    # Time average of a two-state Markov chain: Var = p(1-p)/n * (1+rho)/(1-rho) per
    # pixel (chains independent, started in the stationary distribution).
    se = np.sqrt(p_high * (1 - p_high) * (1 + rho) / (1 - rho) / states.size)
    assert abs(states.mean() - p_high) < 5 * se, (states.mean(), p_high, se)
    # transition probabilities over one frame time:
    # P(low -> high) = p_high (1 - rho), P(high -> low) = (1 - p_high)(1 - rho);
    # given the current state the transitions are independent Bernoulli draws, so
    # the estimate from n transitions has standard error sqrt(q (1 - q) / n).
    now, nxt = states[:, :-1].ravel(), states[:, 1:].ravel()
    for start, q in ((0.0, p_high * (1 - rho)), (1.0, (1 - p_high) * (1 - rho))):
        sel = now == start
        est = np.mean(nxt[sel] != start)
        assert abs(est - q) < 5 * np.sqrt(q * (1 - q) / sel.sum()), (start, est, q)


# ================================================================== null limits
ALL_ON = NIRSPEC_DEFAULTS.replace(rtn_fraction=0.02)
ONLY = {
    "acn": ZERO_NOISE.replace(acn=ALL_ON.acn),
    "c_pink": ZERO_NOISE.replace(c_pink=ALL_ON.c_pink),
    "u_pink": ZERO_NOISE.replace(u_pink=ALL_ON.u_pink),
    "rd_noise": ZERO_NOISE.replace(rd_noise=ALL_ON.rd_noise),
    "pca0": ZERO_NOISE.replace(pca0=ALL_ON.pca0),
    "pedestal": ZERO_NOISE.replace(pedestal=ALL_ON.pedestal),
    "ktc": ZERO_NOISE.replace(ktc=ALL_ON.ktc),
    "rtn_fraction": ZERO_NOISE.replace(rtn_fraction=ALL_ON.rtn_fraction),
}


@pytest.mark.parametrize("name", sorted(ONLY))
def test_zero_amplitude_leaves_other_draws_unchanged(name):
    """frame(all on) - frame(name = 0) == frame(only name), to float32 rounding."""
    full = _gen(ALL_ON, rng=71).cube(2, nints=2).astype(np.float64)
    without = _gen(ALL_ON.replace(**{name: 0.0}), rng=71).cube(2, nints=2)
    only = _gen(ONLY[name], rng=71).cube(2, nints=2)
    assert np.abs(only).max() > 0
    # Each frame is a float32 sum of < 10 terms, each addition rounding by <= 1/2 ulp
    # of the running sum (<= max |frame|): both sides are within 10 ulp of exact.
    tol = 10 * np.spacing(np.float32(np.abs(full).max()))
    np.testing.assert_allclose(full - without, only, rtol=0, atol=tol)


def test_zero_noise_is_exactly_zero():
    assert not _gen(ZERO_NOISE, rng=72).cube(3, nints=2).any()


# ================================================================== reproducibility
def test_threads_do_not_change_frames():
    params = ALL_ON
    a = _gen(params, rng=81, threads=1).cube(3, nints=2)
    b = _gen(params, rng=81, threads=2).cube(3, nints=2)
    c = _gen(params, rng=81, threads=3).cube(3, nints=2)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a, c)


@pytest.mark.parametrize("band_rows", [64, 128])
def test_band_and_chunk_layout_do_not_change_frames(band_rows):
    """The frame is made in bands of rows; the band size only reorders the work."""
    det = preset("H2RG", naxis1=128, naxis2=256, n_out=4)
    ref = _gen(ALL_ON, det=det, rng=85, threads=2).cube(3)
    for threads in (2, 1):
        gen = NoiseGenerator(det, ALL_ON, rng=85, threads=threads,
                             layout=Layout(band_rows=band_rows))
        np.testing.assert_array_equal(gen.cube(3), ref)


@pytest.mark.parametrize("per", [1, 3])
def test_series_per_task_does_not_change_frames(per):
    """The uncorrelated and ACN series of several outputs are synthesised together
    (``Layout.series_per_task``, default 8); the grouping only batches the work: one
    series per task, or groups of 3 (the last one short), give the same frames on the
    banded path (65536 pixels), the batched path of small frames and the raw frames of
    an interleaved detector with a reference output (whose extra samples take each
    output's lines from its group), and the same time lines."""
    cases = [(preset("H2RG", naxis1=256, naxis2=256, n_out=8), {}),
             (preset("H2RG", naxis1=64, naxis2=64, n_out=8), {}),
             (preset("NIRSPEC-IRS2").stripe(8, 64, "S64"), {"raw": True})]
    for det, kw in cases:
        def frames(layout):
            gen = NoiseGenerator(det, ALL_ON, rng=86, threads=2, layout=layout)
            return np.array([f for *_, f in gen.frames(3, nints=2, **kw)]), gen
        ref, gen_ref = frames(Layout())
        got, gen = frames(Layout(series_per_task=per))
        np.testing.assert_array_equal(got, ref)
        assert ref.std() > 0
    for name, o in (("u_pink", 2), ("acn", 3), ("pink", 1)):
        np.testing.assert_array_equal(gen.timeline(name, o, 500, 3000),
                                      gen_ref.timeline(name, o, 500, 3000))


@pytest.mark.parametrize("params", [NIRSPEC_DEFAULTS, ALL_ON], ids=["paper", "with-rtn"])
def test_reads_subset_equals_full_ramp(params):
    # with RTN on, the telegraph chain was advanced over the requested reads only and
    # started from its stationary distribution at the first: reads [1, 4] of
    # integration 1 differed from the full ramp's in ~60 of 128^2 pixels by rtn_amp
    full = _gen(params, rng=82).cube(6, nints=2)
    got = list(_gen(params, rng=82).frames(6, reads=[1, 4], nints=2))
    assert [(i, k) for i, k, _ in got] == [(0, 1), (0, 4), (1, 1), (1, 4)]
    for i, k, img in got:
        np.testing.assert_array_equal(img, full[i, k])
    later = list(_gen(params, rng=82).frames(6, nints=2, integrations=[1]))
    for i, k, img in later:
        np.testing.assert_array_equal(img, full[i, k])


def test_frame_in_any_order_is_the_frame_of_its_slot():
    """frame(slot) is a function of the slot: asked in decreasing order, again, or
    after other frames (before: refused out of order, and RTN depended on what came
    before)."""
    gen = _gen(ALL_ON, rng=85)
    order = [5, 2, 9, 2, 0, 9]
    got = [gen.frame(s, 0).copy() for s in order]
    for s, img in zip(order, got):          # each against a fresh generator's
        np.testing.assert_array_equal(img, _gen(ALL_ON, rng=85).frame(s, 0))


def test_seed_forms_and_differences():
    a = _gen(ALL_ON, rng=83).cube(2)
    np.testing.assert_array_equal(_gen(ALL_ON, rng=83).cube(2), a)
    np.testing.assert_array_equal(_gen(ALL_ON, rng=np.random.SeedSequence(83)).cube(2), a)
    np.testing.assert_array_equal(_gen(ALL_ON, rng=np.random.default_rng(83)).cube(2), a)
    b = _gen(ALL_ON, rng=84).cube(2)
    # independent draws: values ~5000 e- with sigma ~40 e- and a float32 ulp of 5e-4
    # coincide with probability ~1e-5 per pixel, so well under 1e-3 of the pixels
    assert np.mean(a == b) < 1e-3
    # rng=None draws fresh entropy and records it, so the run can be repeated
    fresh = _gen(ALL_ON, rng=None)
    first = fresh.cube(1)
    np.testing.assert_array_equal(_gen(ALL_ON, rng=fresh.entropy).cube(1), first)


# ================================================================== bad input
@pytest.mark.parametrize("name", ["rd_noise", "ref_ratio", "c_pink", "u_pink", "acn",
                                  "pca0", "pedestal", "ktc", "bias_amp", "rtn_amp"])
@pytest.mark.parametrize("value", [-1.0, float("nan"), float("inf")])
def test_bad_amplitude(name, value):
    with pytest.raises(ParameterError, match=f"'{name}'"):
        NoiseParams(**{name: value})


@pytest.mark.parametrize("name", ["rd_noise", "u_pink", "acn"])
def test_bad_per_output_amplitude(name):
    with pytest.raises(ParameterError, match=f"'{name}'"):
        NoiseParams(**{name: (1.0, float("nan"), 1.0, 1.0)})
    with pytest.raises(ParameterError, match=f"'{name}'"):
        NoiseParams(**{name: (1.0, -2.0, 1.0, 1.0)})
    # wrong number of outputs is caught when the readout is known
    with pytest.raises(ParameterError, match=f"'{name}'.*3 per-output values.*4 outputs"):
        NoiseGenerator(DET, ZERO_NOISE.replace(**{name: (1.0, 1.0, 1.0)}), rng=1)


@pytest.mark.parametrize("kwargs, name", [
    (dict(rtn_fraction=1.5), "rtn_fraction"), (dict(rtn_tau_low=0.0), "rtn_tau_low"),
    (dict(f_min=-1.0), "f_min"), (dict(pink_spectrum=((1.0, 1.0),)), "pink_spectrum"),
    (dict(pink_spectrum=((2.0, 1.0), (1.0, 1.0))), "pink_spectrum"),
    (dict(bias_offset=float("nan")), "bias_offset"),
])
def test_bad_params_options(kwargs, name):
    with pytest.raises(ParameterError, match=f"'{name}'"):
        NoiseParams(**kwargs)


def test_acn_needs_even_columns_per_output():
    det = Detector(naxis1=60, naxis2=64, n_out=4)           # 15 columns per output
    with pytest.raises(ParameterError, match=r"15 columns per output.*'acn'"):
        NoiseGenerator(det, ZERO_NOISE.replace(acn=0.5), rng=1)
    NoiseGenerator(det, ZERO_NOISE.replace(u_pink=0.5), rng=1)   # fine without ACN
    odd_row = Detector(naxis1=64, naxis2=64, n_out=4, nroh=11)   # 16 + 11 per row
    with pytest.raises(ParameterError, match=r"'nroh'.*'acn'"):
        NoiseGenerator(odd_row, ZERO_NOISE.replace(acn=0.5), rng=1)


def test_bad_generator_arguments():
    with pytest.raises(ParameterError, match="'threads'"):
        NoiseGenerator(DET, ZERO_NOISE, rng=1, threads=0)
    with pytest.raises(ParameterError, match="'rng'"):
        NoiseGenerator(DET, ZERO_NOISE, rng=-3)
    with pytest.raises(ParameterError, match="'rng'"):
        NoiseGenerator(DET, ZERO_NOISE, rng="seed")
    with pytest.raises(ParameterError, match="'detector'"):
        NoiseGenerator("H2RG", ZERO_NOISE, rng=1)
    with pytest.raises(ParameterError, match="'params'"):
        NoiseGenerator(DET, {"rd_noise": 5.0}, rng=1)
    gen = NoiseGenerator(DET, ZERO_NOISE.replace(u_pink=1.0), rng=1)
    with pytest.raises(ParameterError, match="'component'"):
        gen.timeline("c_pink", 0, 0, 10)
    with pytest.raises(ParameterError, match="'nreads'"):
        next(gen.frames(0))
    with pytest.raises(ParameterError, match="'reads'"):
        next(gen.frames(3, reads=[3]))


@pytest.mark.parametrize("kwargs, match", [
    (dict(nreads=3, nints=2, integrations=[2]), r"'integrations'.*\[0, 1\].*2"),
    (dict(nreads=3, nints=2, integrations=[-1]), r"'integrations'.*-1"),
    (dict(nreads=3, nints=2, integrations=[0.5]), r"'integrations'.*0\.5"),
    (dict(nreads=3, nints=2, integrations=[True]), r"'integrations'"),
    (dict(nreads=3, nints=2, integrations=5), r"'integrations'.*iterable"),
    (dict(nreads=3, nints=2, integrations=[]), r"'integrations' is empty"),
    (dict(nreads=3, reads=[]), r"'reads' is empty"),
    (dict(nreads=3, reads=[1, -2]), r"'reads'.*-2"),
    (dict(nreads=3, nints=0), r"'nints' must be >= 1"),
    (dict(nreads=3, nints=1.5), r"'nints' must be an integer"),
    (dict(nreads=0), r"'nreads' must be >= 1"),
])
def test_frames_arguments_checked_before_any_work(kwargs, match):
    """Bad read / integration selections raise at the call, naming the parameter."""
    gen = _gen(NIRSPEC_DEFAULTS, rng=1)
    with pytest.raises(ParameterError, match=match):
        gen.frames(**kwargs)                 # raised by the call itself, not by next():
                                             # frames are made only when iterated


def test_frames_selected_integrations_in_order():
    got = [(i, k) for i, k, _ in _gen(ZERO_NOISE, rng=1).frames(
        2, reads=[1, 0, 1], nints=3, integrations=[2, 0])]
    assert got == [(0, 0), (0, 1), (2, 0), (2, 1)]      # sorted, duplicates removed


@pytest.mark.parametrize("size", [256, 64])                  # threaded / batched path
@pytest.mark.parametrize("gain, offset", [(1.0, 5000.0), (2.7, 5000.0), (1.0, 0.0),
                                          (0.5, 32767.0), (2.0, 5000.0), (4.0, 100.0)])
def test_dn_frames_equal_converted_electron_frames(gain, offset, size):
    """frames(dn_gain=g) is exactly noise.adc.to_dn(frame, g), clipping at 0 and 65535
    included (offset 0 clips about half the pixels low, 32767 e- at 0.5 e-/DN high).

    With g = 2.7 a float32 division would round ~1e-4 of the pixels differently from
    to_dn's float64 one (e/g near a half-integer): the 256x256 frames make that
    visible (~40 pixels), so the comparison checks the arithmetic, not just the layout.
    Powers of two (0.5, 1, 2, 4) take the float32 shortcut, which must agree exactly.
    """
    params = ALL_ON.replace(bias_offset=offset)
    det = preset("H2RG", naxis1=size, naxis2=size, n_out=4)
    e = list(_gen(params, det=det, rng=86, threads=1).frames(3, nints=2))
    dn = list(_gen(params, det=det, rng=86, threads=2).frames(3, nints=2, dn_gain=gain))
    assert [(i, k) for i, k, _ in dn] == [(i, k) for i, k, _ in e]
    for (_, _, fe), (_, _, fd) in zip(e, dn):
        assert fd.dtype == np.uint16 and fd.shape == fe.shape
        np.testing.assert_array_equal(fd, to_dn(fe, gain))
    if offset == 0.0:
        assert np.mean(dn[0][2] == 0) > 0.3
    if offset == 32767.0:
        assert np.mean(dn[0][2] == 65535) > 0.3


@pytest.mark.parametrize("gain", [0.0, -1.0, float("nan"), "2"])
def test_bad_dn_gain(gain):
    with pytest.raises(ParameterError, match="'dn_gain'"):
        _gen(ZERO_NOISE, rng=1).frames(2, dn_gain=gain)


@pytest.mark.parametrize("nframes, nints, match", [
    (0, 1, r"'nframes' must be >= 1, got 0"), (2, 0, r"'nints' must be >= 1, got 0"),
    (-3, 1, r"'nframes'"), (2.0, 1, r"'nframes' must be an integer")])
def test_cube_needs_at_least_one_frame(nframes, nints, match):
    with pytest.raises(ParameterError, match=match):
        _gen(ZERO_NOISE, rng=1).cube(nframes, nints=nints)


@pytest.mark.parametrize("reuse", [1, 2, True])
def test_reused_frame_buffers_give_the_same_frames(reuse):
    """Frames written into rotating buffers equal fresh frames, and the buffers are
    really reused (frame k and k + n share memory)."""
    n = 2 if reuse == 2 else 1
    ref = [f.copy() for *_, f in _gen(ALL_ON, rng=86).frames(4, nints=2)]
    got, ids = [], []
    for *_, f in _gen(ALL_ON, rng=86).frames(4, nints=2, reuse=reuse):
        got.append(f.copy())
        ids.append(id(f))
    for a, b in zip(ref, got):
        np.testing.assert_array_equal(a, b)
    assert len(set(ids)) == n


def test_bad_reuse_and_out():
    gen = _gen(ALL_ON, rng=87)
    with pytest.raises(ParameterError, match="'reuse'"):
        gen.frames(2, reuse=-1)
    with pytest.raises(ParameterError, match="'out'"):
        gen.frame(1, 0, out=np.empty((3, 3), np.float32))


@pytest.mark.parametrize("ny, band_rows", [(192, 64), (128, 64), (128, 128)])
def test_frames_with_lines_made_ahead_equal_frames_made_one_by_one(ny, band_rows):
    # frames() makes the next frame's first-band 1/f lines with the current frame's
    # last rows; the frames must equal frame() called slot by slot on a fresh
    # generator, for an odd and an even number of bands, a single band, two
    # integrations, a subset of reads, and a frame() call slipped in between two
    # frames of the iterator (it reuses the band buffers the lines ahead sit in)
    from noise.clock import frame_slot
    det = preset("H2RG", naxis1=128, naxis2=ny, n_out=4)
    lay = Layout(band_rows=band_rows, pool_min_pixels=1)

    def gen():
        return NoiseGenerator(det, NIRSPEC_DEFAULTS, rng=91, threads=2, layout=lay)

    one = gen()
    ref = {(i, k): one.frame(frame_slot(i, k, 5), i).copy()
           for i in range(2) for k in (0, 2, 3)}
    g = gen()
    it = g.frames(5, reads=[0, 2, 3], nints=2)
    for n, (i, k, img) in enumerate(it):
        np.testing.assert_array_equal(img, ref[i, k])
        if n == 2:                              # before (1, 0), whose lines are ahead
            g.frame(frame_slot(0, 4, 5), 0)
    assert len({float(f.std()) for f in ref.values()}) == len(ref)


@pytest.mark.parametrize("call, match", [
    (lambda g: g.frame(-1, 0), "'slot' must be >= 0"),
    (lambda g: g.frame(1.5, 0), "'slot' must be an integer"),
    (lambda g: g.frame(1, None), "'integration' must be an integer"),
    (lambda g: g.frame(1, 0, pool="x"), "'pool' must be a concurrent"),
    (lambda g: g.frame(1, 0, dn_gain=0.0), "'dn_gain' must be > 0"),
    (lambda g: g.frame(1, 0, out=[[0.0]]), "'out' must be a writable"),
    (lambda g: g.timeline("u_pink", 0, -5, 10), "'start' must be >= 0"),
    (lambda g: g.timeline("u_pink", 0, 0, 10.5), "'n' must be an integer"),
    (lambda g: g.timeline("u_pink", 0, 3.9, 10), "'start' must be an integer"),
    (lambda g: g.timeline("u_pink", True, 0, 10), "'output' must be an integer"),
    (lambda g: g.timeline("u_pink", 4, 0, 10), "'output' must be <= 3"),
    (lambda g: g.timeline("upink", 0, 0, 10), "'component' must be one of"),
])
def test_frame_and_timeline_name_a_bad_argument(call, match):
    # before: bare ValueError/TypeError/AttributeError from numpy and SeedSequence,
    # and 10.5 samples or start 3.9 silently truncated
    gen = NoiseGenerator(DET, NIRSPEC_DEFAULTS, rng=1, threads=1)
    with pytest.raises(ParameterError, match=match):
        call(gen)
    ro = np.zeros(DET.shape, np.float32)
    ro.flags.writeable = False
    with pytest.raises(ParameterError, match="'out' must be a writable"):
        gen.frame(1, 0, out=ro)
    assert gen.timeline("u_pink", 3, 0, 10).shape == (10,)


def test_more_frames_than_one_call_lists_are_refused():
    # before: frames(10**15) built its list of reads and ran out of memory
    from noise.generator import MAX_FRAMES
    gen = NoiseGenerator(DET, NIRSPEC_DEFAULTS, rng=1, threads=1)
    with pytest.raises(ParameterError, match="'nreads' must be <="):
        gen.frames(10 ** 15)
    with pytest.raises(ParameterError, match="at most 4194304 frames"):
        gen.frames(MAX_FRAMES, nints=5)
    with pytest.raises(ParameterError, match="'nframes' must be <="):
        noise.write_noise_fits("never.fits", gen, 10 ** 9)


def test_a_cube_larger_than_the_memory_available_is_refused(monkeypatch):
    # before: cube(10**6) of 64x64 (16 GB, allowed by overcommit) ran until killed
    import noise.generator as generator
    gen = NoiseGenerator(DET, NIRSPEC_DEFAULTS, rng=1, threads=1)
    monkeypatch.setattr(generator, "available_memory", lambda: 1e6)   # 1 MB
    with pytest.raises(ParameterError, match=r"cube of 'nints' x 'nframes' = 1 x 16 "
                                             r"frames of 128x128.*memory available"):
        gen.cube(16)                                   # 16 x 64 kB = 1.05 MB
    assert gen.cube(15).shape == (1, 15, 128, 128)     # 0.98 MB


def test_a_window_has_the_telegraph_pixels_of_the_full_frame():
    # A probe: RTN pixels were drawn on the read-out image; a 64^2 window of a 256^2
    # H2RG shared 7 of ~210 with the full frame (chance: ~11).  Now the same pixels.
    det = noise.preset("H2RG", naxis1=256, naxis2=256)
    p = noise.params.ZERO_NOISE.replace(rd_noise=1.0, rtn_fraction=0.05, rtn_amp=50.0)
    full = noise.NoiseGenerator(det, p, rng=3, threads=1)._rtn_idx
    full_set = {divmod(int(i), det.nx) for i in full}
    for x0, y0 in ((64, 64), (100, 3)):
        win = det.window(x0, y0, 64, 48)
        idx = noise.NoiseGenerator(win, p, rng=3, threads=1)._rtn_idx
        got = {(y0 + y, x0 + x) for y, x in (divmod(int(i), win.nx) for i in idx)}
        want = {(y, x) for y, x in full_set if y0 <= y < y0 + 48 and x0 <= x < x0 + 64}
        assert got == want and len(got) > 50


def test_a_window_takes_its_outputs_value_of_full_array_per_output_amplitudes():
    # A probe: per-output values for the full array (one noise table for a
    # detector) were refused on every window ("4 per-output values but the detector
    # reads through 1 outputs").  A window on output 1 (columns 512-1023) of an H2RG
    # now takes the second value: its white noise is 6 e-, measured on the CDS of
    # 60^2 regular pixels over 8 read pairs (the std of n = 28800 unit normals has a
    # standard error 1/sqrt(2n) = 0.0042: 5 of them, 2.1 %).  A window across two
    # outputs is refused, naming the value to give.
    p = noise.params.ZERO_NOISE.replace(rd_noise=(3.0, 6.0, 9.0, 12.0))
    det = noise.preset("H2RG").window(600, 100, 64, 64)
    gen = noise.NoiseGenerator(det, p, rng=1, threads=1)
    assert gen.params.rd_noise == (6.0,)
    f = np.array([fr for _, _, fr in gen.frames(nreads=16)], float)
    reg = ~det.reference_mask()
    cds = (f[1::2] - f[0::2])[:, reg] / np.sqrt(2)
    assert abs(cds.std() / 6.0 - 1) < 5 / np.sqrt(2 * cds.size)
    with pytest.raises(noise.ParameterError, match=r"spans its outputs 0\.\.1 .*give "
                                                   r"'rd_noise' one value"):
        noise.NoiseGenerator(noise.preset("H2RG").window(500, 100, 64, 64), p, rng=1)
    with pytest.raises(noise.ParameterError, match=r"3 per-output values .* or the "
                                                   r"full array's 4"):
        noise.NoiseGenerator(det, p.replace(rd_noise=(1.0, 2.0, 3.0)), rng=1)
