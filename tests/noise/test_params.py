"""Tests of :class:`noise.NoiseParams`: which parameters add noise (null limits)."""

import dataclasses

import numpy as np
import pytest

import noise
from noise.errors import ParameterTypeError
from noise.params import ZERO_NOISE, NoiseParams

#: Fields that shape a component but add nothing alone (every other field is an
#: amplitude); kept here, independently of the module, so that a new field must be
#: classified in both places.
OPTIONS = {"ref_ratio", "rtn_fraction", "rtn_tau_low", "rtn_tau_high", "f_min",
           "pink_spectrum", "pca0_file"}
AMPLITUDES = [f.name for f in dataclasses.fields(NoiseParams) if f.name not in OPTIONS]


def test_zero_noise_is_silent_and_makes_zero_frames():
    assert noise.ZERO_NOISE.is_silent()
    det = noise.preset("H2RG", naxis1=64, naxis2=64)
    frames = noise.NoiseGenerator(det, noise.ZERO_NOISE, rng=1).cube(2)
    assert not frames.any()


@pytest.mark.parametrize("name", AMPLITUDES)
def test_each_amplitude_alone_is_not_silent_and_adds_noise(name):
    # the null limit in reverse: any one amplitude switched on makes the parameters
    # audible (so the engine's "no noise" shortcut cannot skip it) and the frames
    # non-zero
    changes = {name: 10.0}
    if name == "rtn_amp":
        changes["rtn_fraction"] = 0.5       # RTN needs pixels that switch
    params = noise.ZERO_NOISE.replace(**changes)
    assert not params.is_silent()
    det = noise.preset("H2RG", naxis1=64, naxis2=64)
    frames = noise.NoiseGenerator(det, params, rng=2).cube(3)
    assert np.any(frames != 0)


def test_rtn_amplitude_without_pixels_is_silent():
    assert noise.ZERO_NOISE.replace(rtn_amp=10.0, rtn_fraction=0.0).is_silent()


def test_options_alone_are_silent():
    params = noise.ZERO_NOISE.replace(ref_ratio=2.0, f_min=1e-3, rtn_tau_low=2.0)
    assert params.is_silent()


def test_numbers_are_stored_as_python_numbers_and_paths_as_strings():
    # a numpy float16 was kept as given: a float16 'dt' made the frame time inf, and
    # amplitudes computed in float16; a pathlib.Path pca0_file was refused
    import pathlib
    det = noise.preset("H2RG", dt=np.float16(1e-5), naxis1=np.int64(64),
                       naxis2=np.int64(64))
    assert type(det.dt) is float and type(det.naxis1) is int
    assert np.isfinite(det.frame_time)
    p = noise.NoiseParams(rd_noise=np.float16(5), c_pink=np.float32(3), f_min=np.float16(1e-4),
                          pca0_file=pathlib.Path("t.fits"))
    assert type(p.rd_noise) is float and type(p.c_pink) is float and type(p.f_min) is float
    assert p.pca0_file == "t.fits"


@pytest.mark.parametrize("value", [np.ones((2, 2)), np.ones((1, 4)), [[1.0, 2.0]]])
def test_a_per_output_amplitude_must_be_one_dimensional(value):
    # a 2-D array was flattened into per-output values without a word
    with pytest.raises(ParameterTypeError, match="'rd_noise' must be a number or a"):
        NoiseParams(rd_noise=value)
    assert NoiseParams(rd_noise=np.full(4, 3.0)).rd_noise == (3.0,) * 4


def test_a_gain_whose_rounding_swamps_the_read_noise_is_warned_about():
    # half an ADC step above the white read noise per read: most reads of a dark
    # pixel repeat one code (a probe's --unit DN --gain 1000 wrote one code for every
    # read without a word).  At or below, and with no read noise at all, no warning.
    import warnings
    from noise.errors import ScenesimWarning
    p = NoiseParams(rd_noise=(3.0, 6.0))              # the smallest output counts
    with pytest.warns(ScenesimWarning, match=r"'gain' 6\.5 e-/DN: half an ADC step "
                                             r"\(3\.25 e-\) exceeds .* 3 e-"):
        p.warn_quantisation(6.5)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        p.warn_quantisation(6.0)
        NoiseParams(rd_noise=0.0).warn_quantisation(1e4)


def test_levels_float32_cannot_carry_the_read_noise_on_are_warned_about():
    # A probe: bias_offset 1e8 e- made 5.2 e- of white noise read 8.1 (float32 steps
    # of 8 e- there), 1e9 made every pixel one number; accepted without a word.  The
    # generator now warns once the steps pass 0.35 of the read noise (the rounding
    # adds > 1 % of its variance); 1e7 (steps of 1 e-: 0.3 %) and a noise-free
    # detector are quiet.
    import warnings
    from noise import NoiseGenerator, preset
    from noise.errors import ScenesimWarning
    det = preset("H2RG", naxis1=64, naxis2=64)
    with pytest.warns(ScenesimWarning, match=r"float32 steps by 8 e-, over 0.35 of the "
                                             r"white read noise"):
        NoiseGenerator(det, ZERO_NOISE.replace(rd_noise=5.2, bias_offset=1e8), rng=1)
    with pytest.warns(ScenesimWarning, match=r"float32 frames"):
        NoiseGenerator(det, ZERO_NOISE.replace(rd_noise=5.2, pedestal=3e8), rng=1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        NoiseGenerator(det, ZERO_NOISE.replace(rd_noise=5.2, bias_offset=1e7), rng=1)
        NoiseGenerator(det, ZERO_NOISE.replace(bias_offset=1e9), rng=1)
