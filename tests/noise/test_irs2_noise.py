"""Noise on the IRS2 raw samples (interleaved reference samples, reference output):
they see the 1/f lines, ACN and pedestal of their neighbours in time, white noise at
the reference level, kTC shared by the two reads of a reference pixel.

Small IRS2 detectors (the NIRSpec clock on 256 columns): every test is seeded, every
tolerance is 5 standard errors of its estimator, derived next to the assertion.
"""

import numpy as np
import pytest

import noise
from noise.clock import frame_slot, preset

DET = preset("NIRSPEC-IRS2", naxis1=256, naxis2=64)     # 64 columns per output
OFF = dict(rd_noise=0.0, c_pink=0.0, u_pink=0.0, acn=0.0, pca0=0.0, pedestal=0.0,
           ktc=0.0, bias_offset=0.0, bias_amp=0.0)


def _params(**on):
    return noise.NoiseParams(**{**OFF, **on})


def _raw(params, nframes, seed, det=DET):
    gen = noise.NoiseGenerator(det, params, rng=seed, threads=1)
    return gen, np.stack([f for *_, f in gen.frames(nframes, raw=True)])


def test_layout_sizes():
    assert DET.raw_shape == (64, 400) and DET.row_samples == 64 + 4 * 6 + 8


def test_image_pixels_unchanged_by_raw():
    p = noise.NoiseParams()
    gen, raw = _raw(p, 3, 11)
    img = noise.NoiseGenerator(DET, p, rng=11, threads=1).cube(3)[0]
    _, _, image_x = DET.raw_columns()
    normal = image_x >= 0
    assert np.array_equal(raw[:, :, normal], img[:, :, image_x[normal]])


@pytest.mark.parametrize("component", ["u_pink", "acn", "c_pink"])
def test_samples_are_the_time_line_at_their_slots(component):
    """With one 1/f component alone, every raw sample (normal, interleaved, reference
    output) is that series' value at the sample's slot of its output's time line."""
    gen, raw = _raw(_params(**{component: 3.0}), 2, 5)
    output, slot, _ = DET.raw_columns()
    L, rs = DET.frame_samples, DET.row_samples
    for k in range(2):
        s = frame_slot(0, k, 2)
        t = s * L + np.arange(DET.ny)[:, None] * rs + slot[None, :]
        for o in range(4):
            cols = output == o
            if component == "c_pink":
                line = gen.timeline("c_pink", 0, s * L, L)
            elif component == "u_pink":
                line = gen.timeline("u_pink", o, s * L, L)
            else:
                pair = gen.timeline("acn", o, s * L // 2, L // 2)
                line = np.empty(L, dtype=np.float32)
                line[0::2], line[1::2] = pair
            want = line[t[:, cols] - s * L]
            np.testing.assert_allclose(raw[k][:, cols], want, rtol=0, atol=1e-5)
        if component == "c_pink":       # the reference output shares the common line
            cols = output == -1
            want = gen.timeline("c_pink", 0, s * L, L)[t[:, cols] - s * L]
            np.testing.assert_allclose(raw[k][:, cols], want, rtol=0, atol=1e-5)


def test_white_level_is_the_reference_level():
    rd, ratio = 5.0, 0.8
    _, raw = _raw(_params(rd_noise=rd, ref_ratio=ratio), 4, 3)
    output, _, image_x = DET.raw_columns()
    for name, cols, sigma in (
            ("interleaved", (image_x < 0) & (output >= 0), rd * ratio),
            ("reference output", output == -1, rd * ratio),
            ("normal (inner)", (image_x >= 4) & (image_x < 252), rd)):
        x = raw[:, 4:-4][:, :, cols].astype(np.float64)
        n = x.size
        # sample std of n iid normals: relative standard error 1 / sqrt(2 n)
        assert x.std() == pytest.approx(sigma, rel=5 / np.sqrt(2 * n)), name


def test_reference_output_tracks_correlated_pink():
    """A science sample and the reference output's sample at the same slot share the
    correlated 1/f exactly: their difference is white only, variance rd^2 (1 +
    ratio^2), however strong c_pink is.  Misaligned by one slot, the difference
    would carry c_pink's lag-1 increments."""
    rd, ratio, c = 2.0, 0.8, 40.0
    _, raw = _raw(_params(rd_noise=rd, ref_ratio=ratio, c_pink=c), 6, 9)
    output, slot, image_x = DET.raw_columns()
    ref = np.flatnonzero(output == -1)
    diffs = []
    for o in range(4):
        cols = np.flatnonzero(output == o)
        # the same slot: the reference output's column holding each slot
        by_slot = {int(t): j for j, t in zip(ref, slot[ref])}
        partner = np.array([by_slot[int(t)] for t in slot[cols]])
        inner = (image_x[cols] < 0) | ((image_x[cols] >= 4) & (image_x[cols] < 252))
        d = raw[:, 4:-4][:, :, cols[inner]] - raw[:, 4:-4][:, :, partner[inner]]
        diffs.append(d.ravel())
    d = np.concatenate(diffs).astype(np.float64)
    # normal science samples have rd, interleaved ones rd*ratio; count each kind
    n_int = sum(((image_x[output == o] < 0)).sum() for o in range(4))
    n_nor = sum(((image_x[output == o] >= 4) & (image_x[output == o] < 252)).sum()
                for o in range(4))
    var = (n_nor * rd ** 2 + n_int * (rd * ratio) ** 2) / (n_nor + n_int) \
        + (rd * ratio) ** 2
    # variance of n normal-ish values: relative standard error sqrt(2 / n) (the
    # mixture of two normals has a slightly larger one: kurtosis < 3.1 here, so
    # sqrt(2.1 / n) bounds it)
    assert d.var() == pytest.approx(var, rel=5 * np.sqrt(2.1 / d.size))


def test_interleaved_sample_sees_its_neighbours_1f():
    """Uncorrelated 1/f and ACN, no white noise: an interleaved sample and the normal
    pixel two slots before it (across the jump) differ by the series' lag-2
    increment; so do two normal pixels two slots apart.  Same law, same variance
    (stationarity)."""
    _, raw = _raw(_params(u_pink=20.0, acn=5.0), 8, 4)
    output, slot, image_x = DET.raw_columns()
    cols = np.flatnonzero(output == 0)
    s = slot[cols]
    at = {int(t): c for t, c in zip(s, cols)}
    refs = [at[t] for t in s if t in at and t - 2 in at and image_x[at[t]] < 0
            and image_x[at[t - 2]] >= 0]
    ref_pairs = [(at[int(slot[c]) - 2], c) for c in refs]
    norm_pairs = [(at[t - 2], at[t]) for t in s if t - 2 in at and image_x[at[t]] >= 0
                  and image_x[at[t - 2]] >= 0][:len(ref_pairs)]
    a = np.concatenate([raw[:, :, c] - raw[:, :, p] for p, c in ref_pairs], axis=None)
    b = np.concatenate([raw[:, :, c] - raw[:, :, p] for p, c in norm_pairs], axis=None)
    # the increments are nearly independent across rows and frames (a lag-2 increment
    # of 1/f noise is dominated by the highest frequencies); each variance has a
    # relative standard error ~ sqrt(2 / n); 5 sigma on their ratio: 5 sqrt(4 / n)
    ratio = a.var() / b.var()
    assert ratio == pytest.approx(1.0, abs=5 * np.sqrt(4 / min(a.size, b.size)))


def test_ktc_shared_by_the_two_reads_of_a_reference_pixel():
    rd, ratio, ktc = 1.0, 1.0, 30.0
    _, raw = _raw(_params(rd_noise=rd, ref_ratio=ratio, ktc=ktc), 1, 8)
    output, slot, image_x = DET.raw_columns()
    cols = np.flatnonzero((output == 0) & (image_x < 0))
    cols = cols[np.argsort(slot[cols])]                # time order: A A B B A A ...
    x = raw[0][:, cols].astype(np.float64)
    same = x[:, 0::2] - x[:, 1::2]                      # two reads of one pixel
    other = x[:, 1:-1:2] - x[:, 2::2]                   # reads of two pixels
    # variance estimates: relative standard error sqrt(2 / n)
    assert same.var() == pytest.approx(2 * rd ** 2, rel=5 * np.sqrt(2 / same.size))
    assert other.var() == pytest.approx(2 * rd ** 2 + 2 * ktc ** 2,
                                        rel=5 * np.sqrt(2 / other.size))
    # the reference output reads no pixel: no kTC
    assert raw[0][:, output == -1].std() == pytest.approx(
        rd, rel=5 / np.sqrt(2 * raw[0][:, output == -1].size))


def test_pedestal_is_common_to_every_sample():
    _, raw = _raw(_params(pedestal=7.0), 3, 2)
    for k in range(3):
        assert np.ptp(raw[k]) == 0.0 and raw[k, 0, 0] != 0.0


def test_dn_raw_frames():
    gen, raw = _raw(noise.NoiseParams(), 2, 1)
    dn = np.stack([f for *_, f in noise.NoiseGenerator(DET, noise.NoiseParams(), rng=1,
                                                      threads=1).frames(
        2, raw=True, dn_gain=1.5)])
    assert dn.dtype == np.uint16
    np.testing.assert_array_equal(dn, noise.adc.to_dn(raw, 1.5))


def test_raw_refused_without_raw_samples():
    gen = noise.NoiseGenerator(preset("H2RG", naxis1=64, naxis2=64), rng=1)
    with pytest.raises(noise.errors.ParameterError, match="'raw'=True.*'interleave'"):
        gen.frames(2, raw=True)


def test_reference_output_without_interleave():
    """A reference output alone (Roman's amp 33 style, no interleave): its block comes
    first, mirrored with respect to output 0, and with c_pink alone each of its samples
    is the correlated line at its slot, as output 0's pixel at that slot is."""
    det = preset("H2RG", naxis1=64, naxis2=16, ref_output=True)
    assert det.raw_shape == (16, 80) and det.row_samples == 16 + 12
    gen, raw = _raw(_params(c_pink=5.0), 2, 6, det=det)
    output, slot, image_x = det.raw_columns()
    assert np.array_equal(slot[:16], np.arange(16)[::-1])
    for k in range(2):
        ref = raw[k][:, :16]
        out0 = raw[k][:, 16:32]                      # output 0, left to right
        np.testing.assert_allclose(ref[:, ::-1], out0, rtol=0, atol=1e-5)


@pytest.mark.parametrize("det", [DET, preset("H2RG", naxis1=64, naxis2=16, ref_output=True),
                                 preset("NIRSPEC-IRS2", naxis1=256, naxis2=64,
                                        ref_output=True)],
                         ids=["irs2", "ref_output", "irs2+ref_output"])
def test_split_frames_are_the_raw_frames_parts(det):
    """``frames(raw='split')`` yields (image, extra): the raw frame's image columns
    and its other columns, in raw-column order, with the same draws."""
    p = noise.NoiseParams()
    _, raw = _raw(p, 3, 21, det=det)
    gen = noise.NoiseGenerator(det, p, rng=21, threads=1)
    split = [f for *_, f in gen.frames(3, raw="split")]
    _, _, image_x = det.raw_columns()
    normal, extra = np.flatnonzero(image_x >= 0), np.flatnonzero(image_x < 0)
    for k, (img, ext) in enumerate(split):
        assert img.shape == det.shape and ext.shape == (det.ny, extra.size)
        assert np.array_equal(raw[k][:, normal], img[:, image_x[normal]])
        assert np.array_equal(raw[k][:, extra], ext)
    dn = [f for *_, f in noise.NoiseGenerator(det, p, rng=21, threads=1).frames(
        3, raw="split", dn_gain=1.5)]
    for (img, ext), (dimg, dext) in zip(split, dn):
        np.testing.assert_array_equal(dimg, noise.adc.to_dn(img, 1.5))
        np.testing.assert_array_equal(dext, noise.adc.to_dn(ext, 1.5))
    with pytest.raises(noise.errors.ParameterError, match="'raw' must be"):
        gen.frames(2, raw="yes")


def test_column_runs_copy_any_pairing():
    """The slice runs that place the image in the raw frame copy exactly what the
    column gather ``out[..., d] = a[..., s]`` copies, for runs up, down, of one
    column and reaching column 0, pairs in any order (seeded random layouts)."""
    from noise.clock import column_runs, copy_columns
    rng = np.random.default_rng(4)
    for _ in range(50):
        n = int(rng.integers(1, 40))
        pieces = []
        # cut the destination into segments, each from a run of sources up or down
        cuts = np.sort(rng.choice(np.arange(1, n), size=min(n - 1, int(rng.integers(0, 6))),
                                  replace=False)) if n > 1 else []
        start = 0
        for end in [*cuts, n]:
            m = end - start
            s0 = int(rng.integers(0, n - m + 1))
            seg = np.arange(s0, s0 + m)
            pieces.append(seg[::-1] if rng.random() < 0.5 else seg)
            start = end
        s = np.concatenate(pieces)
        d = np.sort(rng.choice(np.arange(n + 10), size=n, replace=False))
        if rng.random() < 0.5:                     # mirrored: destination descending
            d = d[::-1]
        pairs = rng.permutation(n)                 # the pairs in any order
        d, s = d[pairs], s[pairs]
        src = rng.standard_normal((2, 3, n)).astype(np.float32)
        want = np.zeros((2, 3, n + 10), np.float32)
        want[..., d] = src[..., s]
        got = np.zeros_like(want)
        assert copy_columns(got, src, column_runs(d, s)) is got
        assert np.array_equal(got, want), (d, s)
