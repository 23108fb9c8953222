"""The streamed preparation of :func:`scenesim.calib.prepare.fit_exposure_file` gives
the bytes of the in-memory one (:func:`scenesim.calib.prepare.prepare_exposure`).

``fit_exposure_file`` prepares an exposure by frames and rows of a temporary float32
file (issue 16: memory independent of the number of resultants) and fits it from
the file.  The reference is ``prepare_exposure`` on the whole cube; every array
(resultants, flags, read-noise map) and the slope file must agree to the last bit,
for each reference-pixel scheme, with IPC undone or not, with a nonlinearity and
with pixels reaching the full well, for one and two integrations, with blocks made
small (a few rows, two-frame linearisation batches) so that every step spans
several of them.  Nothing is left in the output's directory but the slope file.
"""

import os

import numpy as np
import pytest

import noise
from noise.clock import preset
from scenesim.calib import prepare as prep_mod
from scenesim.calib.prepare import PrepareOptions, fit_exposure_file, prepare_exposure
from scenesim.detector.ipc import ipc_kernel
from scenesim.detector.nonlinearity import Nonlinearity
from scenesim.detector.readout import Readout
from scenesim.engine import ChargeEngine, EngineOptions
from scenesim.io.fitfile import read_fit
from scenesim.rampfit import fit_ramps
from scenesim.run import write_exposure

_FIT_FIELDS = ("slope", "var_read", "var_poisson", "chi2", "dof", "dq", "slope_ints",
               "var_ints", "n_jumps")


def _engine(kernel, nints, seed):
    """48 x 40 H2RG (4 outputs of 10 columns), 7 RAPID groups (10.8 ms frames),
    paper-default noise, rates of 2000 e-/s and, on a diagonal pattern, 8e5 e-/s,
    which reach the 2e4 e- full well at the third read; nonlinearity of an H2RG."""
    det = preset("H2RG", naxis1=40, naxis2=48, n_out=4)
    ro = Readout.multiaccum(1, 7, nints=nints, name="RAPID")
    yy, xx = np.mgrid[0:48, 0:40]
    rate = np.where(det.reference_mask(), 0.0, 2e3 + 8e5 * ((xx + yy) % 11 == 0))
    return ChargeEngine(det, ro, rate=rate, full_well=2e4, gain=1.5,
                        nonlinearity=Nonlinearity((-8e-7, -2e-12)), ipc_kernel=kernel,
                        noise_params=noise.NoiseParams(), rng=seed,
                        options=EngineOptions(threads=1))


def _small_blocks(monkeypatch):
    # 3 rows of 2 x 7 x 40 values per block; linearisation two frames at a time
    monkeypatch.setattr(prep_mod, "_BLOCK_VALUES", 3 * 2 * 7 * 40)
    monkeypatch.setattr(prep_mod, "_LINEARIZE_VALUES", 1)


def _same_bits(a, b, what):
    a, b = np.asarray(a), np.asarray(b)
    assert a.dtype == b.dtype and a.shape == b.shape, what
    assert a.tobytes() == b.tobytes(), what


@pytest.mark.parametrize("refpix", ["none", "median", "jwst"])
@pytest.mark.parametrize("kernel, decon, nints", [
    (None, True, 2), (ipc_kernel(0.015, 0.002), True, 1),
    (ipc_kernel(0.015), False, 2)], ids=["no-ipc", "ipc-undone", "ipc-kept"])
def test_streamed_preparation_is_the_in_memory_one(tmp_path, monkeypatch, refpix,
                                                   kernel, decon, nints):
    _small_blocks(monkeypatch)
    path = str(tmp_path / "e.fits")
    write_exposure(_engine(kernel, nints, seed=5), path)
    opts = PrepareOptions(refpix=refpix, deconvolve_ipc=decon, threads=2)
    ref = prepare_exposure(path, options=opts)
    assert ref.saturated.any() and not ref.saturated.all()      # flags exercised
    src = prep_mod._open_source(path)
    got, res, sat = prep_mod._prepare_to_file(src, str(tmp_path / "cube.npy"), opts)
    ny = ref.electrons.shape[2]
    _same_bits(res.rows(0, ny), ref.electrons, "electrons")
    _same_bits(sat.rows(0, ny), ref.saturated, "saturated")
    _same_bits(got.read_noise, ref.read_noise, "read_noise")
    assert got.cards == ref.cards and got.read_noise_model == ref.read_noise_model
    # the slope file: streamed fit against the fit of the in-memory preparation
    out = str(tmp_path / "f.fits")
    fit_exposure_file(path, out, options=opts)
    want = fit_ramps(ref.electrons, ref.read_times, read_noise=ref.read_noise,
                     gain=ref.gain, saturated=ref.saturated, jump_threshold=5.0,
                     refmask=ref.refmask, threads=2)
    fit = read_fit(out)
    for name in _FIT_FIELDS:
        _same_bits(getattr(fit, name), getattr(want, name), name)
    assert sorted(os.listdir(tmp_path)) == ["cube.npy", "e.fits", "f.fits"]


def test_in_memory_exposure_streams_to_the_same_slope_file(tmp_path, monkeypatch):
    _small_blocks(monkeypatch)
    engine = _engine(ipc_kernel(0.015), 2, seed=8)
    mem = write_exposure(engine, None)["exposure"]
    a, b = str(tmp_path / "a.fits"), str(tmp_path / "b.fits")
    fit_exposure_file(mem, a)
    ref = prepare_exposure(mem)
    want = fit_ramps(ref.electrons, ref.read_times, read_noise=ref.read_noise,
                     gain=ref.gain, saturated=ref.saturated, jump_threshold=5.0,
                     refmask=ref.refmask)
    got = read_fit(a)
    for name in _FIT_FIELDS:
        _same_bits(getattr(got, name), getattr(want, name), name)
    # an error while preparing leaves no temporary file behind
    monkeypatch.setattr(prep_mod, "_noise_from_file",
                        lambda *args: (_ for _ in ()).throw(RuntimeError("stop")))
    with pytest.raises(RuntimeError, match="stop"):
        fit_exposure_file(mem, b)
    assert sorted(os.listdir(tmp_path)) == ["a.fits"]


def test_rounded_group_means_enter_the_fit_streamed_or_not(tmp_path, monkeypatch):
    # 4-frame groups are rounded means of their codes: the preparation carries their
    # rounding (noise.adc.averaging_noise, times the IPC factor), the streamed and
    # the in-memory fits use it alike, and the slope file records it (RSNOISE)
    from noise.adc import averaging_noise
    from scenesim.detector.ipc import ipc_noise_gain
    _small_blocks(monkeypatch)
    kernel = ipc_kernel(0.015)
    engine = _engine(kernel, 1, seed=9)
    engine = ChargeEngine(engine.detector, Readout.multiaccum(4, 5, name="CUSTOM"),
                          rate=engine.rate, full_well=2e4, gain=1.5,
                          ipc_kernel=kernel, noise_params=noise.NoiseParams(), rng=9,
                          options=EngineOptions(threads=1))
    path = str(tmp_path / "e.fits")
    write_exposure(engine, path)
    ref = prepare_exposure(path)
    want_q = averaging_noise(1.5, [4] * 5) * ipc_noise_gain(kernel)
    np.testing.assert_array_equal(ref.resultant_noise, want_q)
    src = prep_mod._open_source(path)
    got, _, _ = prep_mod._prepare_to_file(src, str(tmp_path / "cube.npy"),
                                          PrepareOptions())
    _same_bits(got.resultant_noise, ref.resultant_noise, "resultant_noise")
    _same_bits(got.read_noise, ref.read_noise, "read_noise")
    out = str(tmp_path / "f.fits")
    fit_exposure_file(path, out)
    want = fit_ramps(ref.electrons, ref.read_times, read_noise=ref.read_noise,
                     gain=ref.gain, saturated=ref.saturated, jump_threshold=5.0,
                     refmask=ref.refmask, resultant_noise=want_q)
    fit = read_fit(out)
    for name in _FIT_FIELDS:
        _same_bits(getattr(fit, name), getattr(want, name), name)
    from astropy.io import fits
    assert fits.getheader(out)["RSNOISE"] == pytest.approx(float(want_q.max()))
    # without the rounding the reported variances would be smaller (its share)
    plain = fit_ramps(ref.electrons, ref.read_times, read_noise=ref.read_noise,
                      gain=ref.gain, saturated=ref.saturated, jump_threshold=5.0,
                      refmask=ref.refmask)
    clean = (fit.dq == 0) & (plain.dq == 0)
    assert clean.sum() > 1000
    assert np.all(fit.var_read[clean] > plain.var_read[clean])
