"""Tests of :mod:`scenesim.calib.refpix` on synthetic cubes built here (white noise plus
known per-output offsets, even/odd column offsets and a row drift common to all
outputs).  The measurement on noise-only ramps is tested in
``tests/validate/test_refpix_study.py``.

Theory used for the tolerances (white noise sigma per pixel):

* median of n normal values: Var ~ pi sigma^2 / (2 n) (asymptotic; the finite-n
  correction is ~1/n, 1 % for n = 128); with a fixed spread tau added to each pixel
  (kTC), the frame-to-frame variance of the median is
  2 pi (sigma^2 + tau^2) [1/4 + asin(rho) / (2 pi)] / n, rho = -tau^2/(sigma^2 + tau^2)
  (linearised count of values below the median: Var(count) = sum F(1-F) over the
  pixels, slope = sum f; the mean of F(1-F) is a bivariate-normal orthant probability);
* mean with iterative 3-sigma clipping around the median: Var = c sigma^2 / n with c
  the second moment of the influence function (C_CLIP, ``tests/refpix_theory.py``,
  1.034);
* running mean of W rows of the average of k side pixels: Var = sigma^2 / (k W).
"""

import math

import numpy as np
import pytest

from noise.clock import Detector
from noise.errors import ParameterError
from refpix_theory import C_CLIP
from scenesim.calib.refpix import SCHEMES, correct_reference, reference_layout

SIG = 5.0


def _det(naxis1, naxis2, n_out):
    return Detector(name="TEST", naxis1=naxis1, naxis2=naxis2, n_out=n_out, nroh=12,
                    nfoh=1, ref_border=4)


def test_layout_full_and_subarrays():
    det = _det(64, 64, 4)
    rows, cols = reference_layout(det)
    np.testing.assert_array_equal(rows, [0, 1, 2, 3, 60, 61, 62, 63])
    np.testing.assert_array_equal(cols, [0, 1, 2, 3, 60, 61, 62, 63])
    rows, cols = reference_layout(det.window(10, 2, 20, 10))
    np.testing.assert_array_equal(rows, [0, 1])
    assert cols.size == 0
    rows, cols = reference_layout(det.stripe(20, 8))
    assert rows.size == 0 and cols.size == 8


def test_median_removes_output_offsets_and_adds_theory_variance():
    # 16 outputs of 16 columns: 8 reference rows x 16 = 128 pixels per output.
    det = _det(256, 16, 16)
    nframes = 2000
    rng = np.random.default_rng(21)
    white = SIG * rng.standard_normal((nframes,) + det.shape)
    offsets = rng.normal(0, 100, (nframes, det.n_out))          # per frame and output
    cube = white + np.repeat(offsets, det.ncols_out, axis=1)[:, None, :]
    corr = correct_reference(cube, det, scheme="median")
    # What was subtracted beyond the true offsets = the median of the reference
    # pixels' white noise: one value per frame and output.
    est = (cube - corr)[:, 8, :] - np.repeat(offsets, det.ncols_out, axis=1)
    med = est[:, ::det.ncols_out]                                   # (F, 16)
    assert np.allclose(est, np.repeat(med, det.ncols_out, axis=1))
    n_ref, n = 128, med.size
    v_theory = np.pi * SIG ** 2 / (2 * n_ref)
    # Offsets removed: the mean of 32000 medians is 0 within 5 sigma.
    assert abs(med.mean()) < 5 * np.sqrt(v_theory / n)
    # Added variance: a variance estimate from n samples has relative standard error
    # sqrt(2/n) = 0.008; 5 sigma plus 1 % for the finite-n correction.
    assert med.var() / v_theory == pytest.approx(1, abs=5 * np.sqrt(2 / n) + 0.01)


def _sinusoid(ny, period, phase):
    y = np.arange(ny)
    return 30.0 * np.sin(2 * np.pi * y / period + phase)


def test_jwst_removes_offsets_even_odd_and_row_drift():
    # 8 outputs of 32 columns: per parity 8 reference rows x 16 columns = 128 pixels.
    det = _det(256, 64, 8)
    ny, nx = det.shape
    nout, ncol = det.n_out, det.ncols_out
    nframes, window = 1000, 11
    rng = np.random.default_rng(22)
    white = SIG * rng.standard_normal((nframes, ny, nx)).astype(np.float32)
    offsets = rng.normal(0, 100, (nframes, nout))
    even_odd = rng.normal(0, 20, (nout, 2))                          # ACN-like
    per_col = np.repeat(offsets, ncol, axis=1)[:, None, :] + np.tile(
        even_odd.reshape(nout, 1, 2), (1, ncol // 2, 1)).reshape(nx)[None, None, :]
    cube = (white + per_col).astype(np.float32)
    cube_in = cube.copy()
    corr = correct_reference(cube, det, scheme="jwst", side_window=window)
    assert corr.dtype == np.float32 and np.array_equal(cube, cube_in)
    mid = slice(ncol, (nout - 1) * ncol)                              # middle outputs
    y = ny // 2
    # What was subtracted beyond the true offsets, at an interior row.
    sub = (cube.astype(np.float64) - corr)[:, y, :] - per_col[:, 0, :]
    v_m = C_CLIP * SIG ** 2 / 128
    # Even/odd estimate: within a frame, even minus odd columns of a middle output
    # differ only by m_even - m_odd (the side term is common): variance 2 c s^2/128.
    diffs = np.stack([sub[:, o * ncol] - sub[:, o * ncol + 1] for o in range(1, nout - 1)])
    n = diffs.size
    # Variance of n = 6000 samples: relative standard error sqrt(2/n) = 0.018.
    assert diffs.var() / (2 * v_m) == pytest.approx(1, abs=5 * np.sqrt(2 / n))
    assert abs(diffs.mean()) < 5 * np.sqrt(2 * v_m / n)               # offsets removed
    # Total added variance at a middle output, interior row: m + side term, where
    # the side term = (white of 8 side columns over W rows) - (mean of the four
    # side-column m's): c s^2/128 + s^2/(8W) + (c s^2/128)/4.  The side term is shared
    # by all columns of a frame, so only nframes samples are independent: relative
    # standard error <= sqrt(2/nframes) = 0.045.
    v_added = v_m * (1 + 1 / 4) + SIG ** 2 / (8 * window)
    assert np.mean(sub[:, mid] ** 2) / v_added == pytest.approx(
        1, abs=5 * np.sqrt(2 / nframes))

    # Row drift common to all outputs (1/f banding): a sinusoid of wavenumber k.
    # The side step subtracts its running mean, d_y sin(kW/2)/(W sin(k/2)), so the
    # residual d_y (1 - sin(kW/2)/(W sin(k/2))) remains (rows whose window is inside
    # the image); the part of the drift in the reference rows cancels between steps.
    period = 40.0
    drift = _sinusoid(ny, period, 0.3)
    corr_d = correct_reference(cube + drift[None, :, None].astype(np.float32), det,
                               scheme="jwst", side_window=window)
    k = 2 * np.pi / period
    gain = np.sin(k * window / 2) / (window * np.sin(k / 2))
    rows = np.arange(window // 2, ny - window // 2)
    expected = drift[rows] * (1 - gain)
    got = (corr_d.astype(np.float64) - white)[:, rows, mid].mean(axis=0)
    # Noise of a mean over frames: sqrt(v_added / nframes) (v_added with c <= 1.03
    # is an upper bound: the drift in the reference rows only loosens the clip).
    assert np.all(np.abs(got - expected[:, None]) < 5 * np.sqrt(v_added / nframes))
    # Null check: the drift is large compared with that tolerance, and 'none'
    # leaves it.
    raw = (cube + drift[None, :, None] - white).mean(axis=0)
    assert np.abs(raw[rows, mid] - expected[:, None]).max() > 10


def test_jwst_side_columns_only_window():
    # A window at the left edge with no reference rows: only step 2 runs; 4 side
    # columns averaged per row, running mean over W rows (truncated at the edges).
    det = _det(256, 256, 4).window(0, 64, 8, 64)
    rows, cols = reference_layout(det)
    assert rows.size == 0 and cols.size == 4
    nframes, window = 2000, 11
    rng = np.random.default_rng(23)
    white = SIG * rng.standard_normal((nframes,) + det.shape)
    corr = correct_reference(white, det, scheme="jwst", side_window=window)
    sub = (white - corr)[:, :, 6]                                    # (F, ny)
    assert np.allclose(white - corr, sub[:, :, None])
    y = np.arange(det.ny)
    w_eff = np.minimum(y + window // 2, det.ny - 1) - np.maximum(y - window // 2, 0) + 1
    v = SIG ** 2 / (4 * w_eff)
    # Rows 11 apart have disjoint windows: independent samples.
    pick = np.arange(0, det.ny, window)
    z2 = sub[:, pick] ** 2 / v[pick]
    n = z2.size
    assert z2.mean() == pytest.approx(1, abs=5 * np.sqrt(2 / n))
    # A drift linear in rows is removed exactly where the window is complete.
    ramp = 0.7 * y
    corr2 = correct_reference(white + ramp[None, :, None], det, side_window=window)
    inner = slice(window // 2, det.ny - window // 2)
    np.testing.assert_allclose(corr2[:, inner], corr[:, inner], atol=1e-9)


def test_jwst_reference_rows_only_window():
    # A window touching the bottom edge away from the sides: only step 1 runs, one
    # output; per parity 4 rows x 32 columns = 128 pixels.
    det = _det(256, 256, 4).window(64, 0, 64, 16)
    nframes = 2000
    rng = np.random.default_rng(24)
    white = SIG * rng.standard_normal((nframes,) + det.shape)
    eo = np.tile([3.0, -3.0], 32)
    corr = correct_reference(white + eo, det, scheme="jwst")
    sub = (white + eo - corr)[:, 8, :2] - eo[:2]                     # (F, 2)
    v = C_CLIP * SIG ** 2 / 128
    n = sub.size
    assert abs(sub.mean()) < 5 * np.sqrt(v / n)
    assert sub.var() / v == pytest.approx(1, abs=5 * np.sqrt(2 / n))


def test_none_is_a_copy_and_integer_input():
    det = _det(64, 64, 4)
    cube = np.arange(2 * 64 * 64).reshape(2, 64, 64)
    out = correct_reference(cube, det, scheme="none")
    assert out.dtype == np.float64 and np.array_equal(out, cube)
    assert not np.shares_memory(out, cube)
    # A constant frame: every scheme removes it completely (null limit).
    flat = np.full((3, 64, 64), 1234.0)
    for scheme in ("median", "jwst"):
        np.testing.assert_allclose(correct_reference(flat, det, scheme=scheme), 0,
                                   atol=1e-9)
    # Extra leading axes (integrations x resultants) are handled.
    four = np.full((2, 3, 64, 64), 7.0)
    assert correct_reference(four, det).shape == (2, 3, 64, 64)


@pytest.mark.parametrize("kwargs,match", [
    (dict(scheme="mean"), "scheme"),
    (dict(side_window=4), "side_window"),
    (dict(side_window=0), "side_window"),
    (dict(sigma=0.0), "sigma"),
    (dict(cube=np.zeros((2, 64, 32))), "shape"),
    (dict(cube=np.zeros(64)), "shape"),
    (dict(detector="H2RG"), "detector"),
])
def test_bad_input(kwargs, match):
    args = dict(cube=np.zeros((2, 64, 64)), detector=_det(64, 64, 4))
    args.update(kwargs)
    with pytest.raises(ParameterError, match=match):
        correct_reference(args.pop("cube"), args.pop("detector"), **args)


def test_subarray_without_reference_pixels():
    det = _det(256, 256, 4).window(64, 64, 32, 32)
    cube = np.zeros((2, 32, 32))
    for scheme in ("median", "jwst"):
        with pytest.raises(ParameterError, match="none"):
            correct_reference(cube, det, scheme=scheme)
    assert np.array_equal(correct_reference(cube, det, scheme="none"), cube)
    # A stripe has side columns but no reference rows: 'median' cannot run.
    stripe = _det(64, 64, 4).stripe(16, 8)
    with pytest.raises(ParameterError, match="reference rows"):
        correct_reference(np.zeros((1, 8, 64)), stripe, scheme="median")
    assert correct_reference(np.zeros((1, 8, 64)), stripe, scheme="jwst").shape == (1, 8, 64)
    assert SCHEMES == ("none", "median", "jwst", "irs2")


def test_median_with_ktc_spread_theory():
    # Reference pixels with a fixed per-pixel spread tau (kTC, constant over the
    # frames of an integration) plus white noise: the median moves from frame to frame
    # with the variance of the module notes, 6.4x the white-only value for NIRSpec.
    # 4000 frames of n = 1024 pixels; the variance of 4000 medians has relative
    # standard error sqrt(2/4000) = 0.022; the formula is asymptotic in the pixel
    # density (tau sampled by 1024 pixels): 5 sigma plus 2 % allowed.
    rng = np.random.default_rng(26)
    n, nframes, sig_r, tau = 1024, 4000, 4.16, 29.0
    fixed = tau * rng.standard_normal(n)
    med = np.median(fixed + sig_r * rng.standard_normal((nframes, n)), axis=1)
    rho = -tau ** 2 / (sig_r ** 2 + tau ** 2)
    theory = 2 * np.pi * (sig_r ** 2 + tau ** 2) * (0.25 + math.asin(rho) / (2 * np.pi)) / n
    assert theory / (np.pi * sig_r ** 2 / (2 * n)) == pytest.approx(6.36, abs=0.01)
    assert med.var() / theory == pytest.approx(1, abs=5 * np.sqrt(2 / nframes) + 0.02)
