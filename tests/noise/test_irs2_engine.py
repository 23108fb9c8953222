"""IRS2 through the charge engine and the exposure file: the interleaved and
reference-output samples are digitised and averaged as the pixels are, collect no
charge, and are written to RAWREF (tests on a small IRS2 detector, seeded)."""

import os

import numpy as np
import pytest
from astropy.io import fits

import noise
from noise.adc import ADC
from noise.clock import preset
from noise.errors import FileFormatError
from scenesim.detector.readout import Readout
from scenesim.engine import ChargeEngine
from scenesim.io.exposure import Exposure, raw_resultants
from scenesim.run import write_exposure

DET = preset("NIRSPEC-IRS2", naxis1=256, naxis2=64)
_, _, IMAGE_X = DET.raw_columns()


def _engine(rate=0.0, params=None, pattern="NRSIRS2", ngroups=2, seed=4, gain=1.5):
    ro = Readout.named(pattern, ngroups=ngroups)
    return ChargeEngine(DET, ro, noise_params=params, rate=rate, gain=gain, rng=seed)


def test_nirspec_irs2_patterns():
    assert Readout.named("NRSIRS2", ngroups=2).nframes == 5
    assert Readout.named("NRSIRS2RAPID", ngroups=2).nframes == 1


def test_raw_resultants_are_the_generators_frames_averaged(tmp_path):
    """Noise only: every raw sample of the file is the rounded mean of the ADC codes
    of the generator's raw frames of its group (5 frames per NRSIRS2 group)."""
    eng = _engine(params=noise.NoiseParams())
    write_exposure(eng, os.fspath(tmp_path / "x.fits"))
    exp = Exposure.read(tmp_path / "x.fits")
    raw = raw_resultants(exp, DET)
    gen = noise.NoiseGenerator(DET, noise.NoiseParams(), rng=np.random.SeedSequence(
        eng.entropy, spawn_key=eng.key + (1,)))
    ro, adc = eng.readout, ADC(1.5)
    frames = {k: f.astype(np.float64) for _, k, f in gen.frames(ro.nreads, raw=True)}
    for g, reads in enumerate(ro.resultants):
        codes = sum(adc.codes(frames[k].copy()) for k in reads)
        want = np.empty(DET.raw_shape, dtype=np.uint16)
        adc.mean_codes(codes.astype(np.uint32), len(reads), out=want)
        np.testing.assert_array_equal(raw[0, g], want)
    with fits.open(tmp_path / "x.fits") as h:
        assert [x.name for x in h] == ["PRIMARY", "SCI", "RAWREF", "READS"]
        assert h[0].header["NEXTEND"] == 3 and h[0].header["NRS_NORM"] == 16


def test_reference_samples_collect_no_charge():
    out = write_exposure(_engine(rate=200.0, pattern="NRSIRS2RAPID", ngroups=3), None)
    exp = out["exposure"]
    assert exp.raw_ref.shape == (1, 3, 64, (IMAGE_X < 0).sum())
    assert np.all(exp.raw_ref == 0)                         # no noise, no charge
    regular = ~DET.reference_mask()
    assert np.all(np.diff(exp.sci[0][:, regular].astype(int), axis=0) > 0)


def test_plain_detector_has_no_rawref(tmp_path):
    det = preset("H2RG", naxis1=64, naxis2=64)
    eng = ChargeEngine(det, Readout.named("RAPID", ngroups=2), rng=1)
    write_exposure(eng, os.fspath(tmp_path / "p.fits"))
    exp = Exposure.read(tmp_path / "p.fits")
    assert exp.raw_ref is None
    with pytest.raises(FileFormatError, match="'RAWREF'"):
        raw_resultants(exp, DET)

