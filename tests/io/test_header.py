"""The header contract (:mod:`scenesim.io.header`): what is written is read back.

An exposure written by the engine carries its detector, readout, gain, read noise,
nonlinearity, IPC kernel and PSF; every reader of the module gives them back exactly.
"""

import numpy as np
import pytest
from astropy.io import fits

import noise
from noise.clock import detector_from_header
from noise.errors import FileFormatError
from scenesim.detector.ipc import ipc_kernel
from scenesim.detector.nonlinearity import Nonlinearity
from scenesim.detector.readout import Readout
from scenesim.engine import ChargeEngine
from scenesim.io import header as hd
from scenesim.io.exposure import Exposure
from scenesim.run import write_exposure
from scenesim.scene import parse_scene
from scenesim.sky.psf import AiryPSF, GaussianPSF


def _psf_config(table):
    """The ``[sources.psf]`` config of a minimal scene."""
    return parse_scene({"readout": {"pattern": "RAPID", "ngroups": 2},
                        "sources": {"psf": table}}).sources.psf


@pytest.mark.parametrize("readout", [
    Readout.named("MEDIUM8", 3, nints=2),
    Readout.from_ma_table(((0, 1), (2, 3), (6, 2)), reset_mode="global"),
])
def test_exposure_header_round_trip(tmp_path, readout):
    # Old behaviour: the READS table's meta (MULTIACC, NFRAMES, GROUPGAP) was dropped
    # when an exposure was read back, so a MULTIACCUM readout came back as a custom
    # one (nframes=None); new: the table is read with its header, and equals.
    det = noise.preset("H2RG").window(100, 200, 32, 48, name="WIN")
    kernel = np.array([[0.0, 0.01, 0.0], [0.02, 0.93, 0.02], [0.0, 0.01, 0.01]])
    nl = Nonlinearity((-1e-6, 2e-12))
    params = noise.ZERO_NOISE.replace(rd_noise=(6.5,), bias_offset=100.0)
    eng = ChargeEngine(det, readout, noise_params=params, rate=3.0, full_well=9e4,
                       nonlinearity=nl, ipc_kernel=kernel, gain=1.5, adc_bits=14, rng=3)
    cards = hd.psf_cards(_psf_config({"kind": "airy", "radius": 1.7}))
    out = write_exposure(eng, None, cards=cards)
    exp = out["exposure"]
    h = exp.header
    assert detector_from_header(h) == det
    assert hd.exposure_readout(exp) == readout
    assert hd.exposure_read_noise(h) == pytest.approx(6.5)
    assert hd.header_nonlinearity(h) == nl
    np.testing.assert_allclose(hd.header_ipc_kernel(h), kernel / kernel.sum(),
                               rtol=1e-9)
    assert hd.header_psf(h) == AiryPSF(1.7)
    assert float(h["GAIN"]) == 1.5 and int(h["ADCBITS"]) == 14
    assert float(h["FULLWELL"]) == 9e4
    if readout.is_multiaccum:           # the cards alone describe MULTIACCUM exactly
        assert hd.readout_from_header(h) == readout


def test_psf_cards_round_trip_and_absent():
    for kind, psf in (({"kind": "gaussian", "fwhm": 2.5}, GaussianPSF(2.5)),
                      ({"kind": "airy", "radius": 1.2}, AiryPSF(1.2))):
        cfg = _psf_config(kind)
        h = fits.Header()
        for key, value, comment in hd.psf_cards(cfg):
            h[key] = (value, comment)
        assert hd.header_psf(h) == psf
    assert hd.header_psf(fits.Header()) is None
    with pytest.raises(FileFormatError, match="PSF"):
        hd.header_psf(fits.Header({"PSFAIRY": -1.0}))


def test_read_noise_default_and_per_output():
    assert hd.exposure_read_noise(fits.Header()) == 0.0
    assert hd.exposure_read_noise(fits.Header(), default=None) is None
    assert hd.exposure_read_noise(fits.Header({"RDNOISE": "3.0,4.0"})) == \
        pytest.approx(np.sqrt(12.5))


def test_identity_or_unrecorded_kernel_is_none():
    assert hd.header_ipc_kernel(fits.Header({"IPC": True})) is None
    ident = "0,0,0,0,1,0,0,0,0"
    assert hd.header_ipc_kernel(fits.Header({"IPC": True, "IPCKERN": ident})) is None
    k = ",".join(f"{v:.10g}" for v in ipc_kernel(0.01).ravel())
    assert hd.header_ipc_kernel(fits.Header({"IPC": False, "IPCKERN": k})) is None
    with pytest.raises(FileFormatError, match="IPCKERN"):
        hd.header_ipc_kernel(fits.Header({"IPC": True, "IPCKERN": "1,2,3"}))


def test_exposure_readout_checks_the_sci_shape():
    det = noise.preset("H2RG", naxis1=32, naxis2=32)
    eng = ChargeEngine(det, Readout.named("RAPID", 3), rng=1)
    exp = write_exposure(eng, None)["exposure"]
    bad = Exposure(exp.sci[:, :2], exp.header, exp.reads, "x.fits")
    with pytest.raises(FileFormatError, match="SCI shape"):
        hd.exposure_readout(bad)


@pytest.mark.parametrize("key, value, match", [
    ("TFRAME", 1.0, r"header says TFRAME = 1.0 s, its READS table"),
    ("NGROUPS", 7, r"header says NGROUPS = 7, its READS table and SCI hold 3"),
    ("TFRAME", "fast", r"TFRAME = 'fast' is not a number"),
    ("GAIN", -1.0, r"GAIN = -1.0 e-/DN must be a finite number > 0")])
def test_exposure_readout_checks_the_header_against_the_reads(key, value, match):
    # an edited TFRAME of 1 s on ~ms frames had scaled every slope without a word
    det = noise.preset("H2RG", naxis1=32, naxis2=32)
    eng = ChargeEngine(det, Readout.named("RAPID", 3), rng=1)
    exp = write_exposure(eng, None)["exposure"]
    assert hd.exposure_readout(exp).ngroups == 3
    hdr = exp.header.copy()
    hdr[key] = value
    with pytest.raises(FileFormatError, match=match):
        hd.exposure_readout(Exposure(exp.sci, hdr, exp.reads, "x.fits"))
    # the table's own times, edited: refused too
    reads = exp.reads.copy()
    reads["READ_TIMES"][1, 0] *= 1.5
    with pytest.raises(FileFormatError, match="READ_TIMES are not the reads"):
        hd.exposure_readout(Exposure(exp.sci, exp.header, reads, "x.fits"))
