"""The 'irs2' reference correction (scenesim.calib.refpix.correct_irs2): exact on what
it must remove exactly, the white noise it adds against its closed form, and clear
errors.  Small IRS2 detectors (the NIRSpec clock on 256 columns), seeded."""

import numpy as np
import pytest

import noise
from noise.clock import preset
from noise.errors import ParameterError
from scenesim.calib.refpix import correct_irs2, correct_reference, irs2_noise_study

DET = preset("NIRSPEC-IRS2", naxis1=256, naxis2=64)
OUTPUT, SLOT, IMAGE_X = DET.raw_columns()
OFF = dict(rd_noise=0.0, c_pink=0.0, u_pink=0.0, acn=0.0, pca0=0.0, pedestal=0.0,
           ktc=0.0, bias_offset=0.0, bias_amp=0.0)


def _raw(params, nframes, seed):
    gen = noise.NoiseGenerator(DET, noise.NoiseParams(**{**OFF, **params}), rng=seed,
                               threads=1)
    return np.stack([f for *_, f in gen.frames(nframes, raw=True)]).astype(np.float64)


def test_constant_per_output_and_reference_offsets_removed_exactly():
    """A per-frame, per-output constant (pedestal) and constant reference-pixel offsets
    (kTC): the corrected frames are one constant per output and slot parity (minus the
    mean reset level of its reference samples), the same in every frame."""
    rng = np.random.default_rng(1)
    raw = np.zeros((3,) + DET.raw_shape)
    for o in range(4):
        raw[:, :, OUTPUT == o] += rng.normal(0, 50, 3)[:, None, None]   # per frame
    ktc = rng.normal(0, 30, (DET.ny, (IMAGE_X < 0).sum()))
    raw[:, :, IMAGE_X < 0] += ktc
    out = correct_irs2(raw, DET, window=5)
    np.testing.assert_allclose(out[1:] - out[0], 0.0, atol=1e-9)
    parity = DET.pixel_sample_index() % 2
    for o in range(4):
        for p in (0, 1):
            sel = (parity == p) & (np.arange(256) // 64 == o)[None, :]
            assert np.ptp(out[0][sel]) < 1e-9


def test_linear_drift_in_time_removed_between_excursions():
    """A drift linear in each output's time, different in every frame, is removed
    exactly by the linear interpolation (window 1) wherever a normal pixel lies between
    two excursions (not before the first or after the last of the frame): the frames
    differ by nothing (what stays is the same in every frame: the groups' mean)."""
    t = DET.raw_sample_index().astype(float)
    raw = np.stack([(1 + f) * 0.01 * t + 7 * f for f in range(3)])
    out = correct_irs2(raw, DET, window=1)
    idx = DET.pixel_sample_index()
    inside = (idx > DET.reference_slots()[0]) & \
        (idx < (DET.ny - 1) * DET.row_samples + DET.reference_slots()[-1])
    np.testing.assert_allclose((out[1:] - out[0])[:, inside], 0.0, atol=1e-8)


def test_added_white_noise_matches_closed_form():
    """White noise only.  With window 1, a normal pixel at time t between the
    same-parity means of two excursions (at t1 < t < t2, u = (t - t1)/(t2 - t1)) gets
    the estimate (1-u) m1 + u m2, each mean of reference/2 samples of sigma
    rd*ratio: corrected variance rd^2 + (rd ratio)^2 / (reference/2) ((1-u)^2 + u^2).
    Frames are corrected independently of each other except for the reference
    samples' mean over the groups, removed first (a factor (1 - 1/nframes) on the
    estimate's variance)."""
    rd, ratio, nframes = 3.0, 0.8, 8
    raw = _raw(dict(rd_noise=rd, ref_ratio=ratio), nframes, 3)
    out = correct_irs2(raw, DET, window=1)
    per = DET.interleave.reference // 2
    idx = DET.pixel_sample_index()
    pred = np.full(DET.shape, np.nan)
    for parity in (0, 1):
        rs = DET.reference_slots()
        pick = rs % 2 == parity
        t_ref = (np.arange(DET.ny)[:, None] * DET.row_samples
                 + rs[pick].reshape(DET.n_excursions, -1).mean(axis=1)).ravel()
        sel = (idx % 2 == parity) & (idx > t_ref[0]) & (idx < t_ref[-1])
        j = np.searchsorted(t_ref, idx[sel])
        u = (idx[sel] - t_ref[j - 1]) / (t_ref[j] - t_ref[j - 1])
        var_est = (rd * ratio) ** 2 / per * ((1 - u) ** 2 + u ** 2) * (1 - 1 / nframes)
        ref = DET.reference_mask()[sel]
        pred[sel] = np.where(ref, (rd * ratio) ** 2, rd ** 2) + var_est
    ok = ~np.isnan(pred)
    z2 = out[:, ok] ** 2 / pred[ok]
    # mean of n chi2(1)/1 values is 1 with standard error sqrt(2 / n) (the frames'
    # estimates share the removed mean, a 1/nframes effect on a small term: ignored)
    assert z2.mean() == pytest.approx(1.0, abs=5 * np.sqrt(2 / z2.size))


def test_irs2_beats_border_on_uncorrelated_pink_and_acn():
    """Uncorrelated 1/f and ACN differ between outputs and are invisible to the border
    rows' per-row mean; the interleaved samples of each output see them."""
    raw = _raw(dict(u_pink=3.0, acn=2.0), 3, 5)
    img = np.empty((3,) + DET.shape)
    img[..., IMAGE_X[IMAGE_X >= 0]] = raw[..., IMAGE_X >= 0]
    reg = ~DET.reference_mask()
    v = {name: (c[1] - c[0])[reg].var() for name, c in (
        ("none", img), ("border", correct_reference(img, DET, scheme="jwst")),
        ("irs2", correct_irs2(raw, DET, window=3)))}
    assert v["irs2"] < 0.6 * v["none"] and v["irs2"] < 0.6 * v["border"]


def test_study_rows():
    rows = irs2_noise_study(DET, noise.NoiseParams(), nreads=3, nramps=2, windows=(3,),
                            threads=1)
    assert [r["scheme"] for r in rows] == ["none", "border (jwst)", "irs2, window 3"]
    assert all(r["cds"] > 0 and r["slope"] > 0 and r["cds_err"] >= 0 for r in rows)


def test_scheme_through_correct_reference():
    raw = _raw(dict(rd_noise=1.0), 2, 1)
    np.testing.assert_array_equal(correct_reference(raw, DET, scheme="irs2"),
                                  correct_irs2(raw, DET))


@pytest.mark.parametrize("call, words", [
    (lambda: correct_irs2(np.zeros((2, 64, 64)), preset("H2RG", naxis1=64, naxis2=64)),
     ["'irs2'", "'interleave'"]),
    (lambda: correct_reference(np.zeros((2, 64, 64)),
                               preset("H2RG", naxis1=64, naxis2=64), scheme="irs2"),
     ["refpix 'irs2'", "NIRSPEC-IRS2"]),
    (lambda: correct_irs2(np.zeros((2,) + DET.shape), DET),
     ["'raw'", "(..., 64, 400)", "(2, 64, 256)"]),
    (lambda: correct_irs2(np.zeros((2,) + DET.raw_shape), DET, window=4),
     ["'window'", "odd", "4"]),
])
def test_bad_input(call, words):
    with pytest.raises(ParameterError) as err:
        call()
    for w in words:
        assert w in str(err.value)
