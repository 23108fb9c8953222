"""Tests of :mod:`noise.adc`, the one electrons-to-DN conversion, against its definition.

Definition: ``DN = clip(rint(float64(e) / gain), 0, 2**bits - 1)`` (round half to even).
Every path that digitises (the charge engine, DN noise frames, :func:`to_dn`) goes
through :class:`noise.adc.ADC`; these tests compare each with the definition written
out here in numpy, not with another call of the code.
"""

import math

import numpy as np
import pytest

import noise
from noise.adc import ADC, from_dn, to_dn
from noise.errors import ParameterError


def _definition(e, gain, bits=16):
    """The documented conversion, independent of noise.adc."""
    q = np.rint(np.asarray(e, dtype=np.float64) / gain)
    return np.clip(q, 0, 2 ** bits - 1)


def test_to_dn_rounds_half_to_even_and_clips():
    e = np.array([[-10.0, -0.4, 0.5, 1.5, 2.5, 2.49, 2.51, 65534.5, 65535.6, 1e9,
                   np.inf, -np.inf]])
    dn = to_dn(e, 1.0)
    assert dn.dtype == np.uint16
    np.testing.assert_array_equal(dn, [[0, 0, 0, 2, 2, 2, 3, 65534, 65535, 65535,
                                        65535, 0]])
    # Gain divides first: 5 e- at 2 e-/DN is 2.5 DN -> 2; 7 e- -> 3.5 -> 4.
    np.testing.assert_array_equal(to_dn(np.array([[5.0, 7.0]]), 2.0), [[2, 4]])


def test_to_dn_bits_and_gain_map():
    e = np.array([[100.0, 5000.0], [1e6, 3.0]])
    np.testing.assert_array_equal(to_dn(e, 1.0, bits=12), [[100, 4095], [4095, 3]])
    dn20 = to_dn(e, np.array([[1.0, 2.0], [4.0, 1.0]]), bits=20)
    assert dn20.dtype == np.uint32
    np.testing.assert_array_equal(dn20, [[100, 2500], [250000, 3]])


def test_to_dn_quantisation_error_is_uniform():
    # Electrons spread over many DN: the rounding error u = dn*g - e is uniform on
    # [-g/2, g/2]; in DN, E[u] = 0, E[u^2] = 1/12, Var(u^2) = 1/80 - 1/144 = 1/180.
    n = 200_000
    g = 2.0
    e = np.random.default_rng(11).uniform(100.0, 60_000.0, (1, n))
    u = from_dn(to_dn(e, g), g) / g - e / g
    assert np.all(np.abs(u) <= 0.5)
    # 5 sigma of the sample mean: 5 * sqrt(1/12 / n) = 3.2e-3.
    assert abs(u.mean()) < 5 * math.sqrt(1 / 12 / n)
    # 5 sigma of the sample mean of u^2: 5 * sqrt(1/180 / n) = 8.3e-4.
    assert abs(np.mean(u**2) - 1 / 12) < 5 * math.sqrt(1 / 180 / n)


@pytest.mark.parametrize("gain", [0.0, -1.0, math.nan, math.inf])
def test_to_dn_rejects_bad_gain(gain):
    with pytest.raises(ParameterError, match="gain"):
        to_dn(np.ones((2, 2)), gain)
    with pytest.raises(ParameterError, match="gain"):
        from_dn(np.ones((2, 2), dtype=np.uint16), gain)


@pytest.mark.parametrize("bits", [0, 33, 16.0, True])
def test_to_dn_rejects_bad_bits(bits):
    with pytest.raises(ParameterError, match="adc_bits"):
        to_dn(np.ones((2, 2)), 1.0, bits=bits)


def test_to_dn_rejects_nan():
    with pytest.raises(ParameterError, match="NaN"):
        to_dn(np.array([[1.0, np.nan]]), 1.0)


def test_from_dn():
    dn = np.array([[0, 1, 65535]], dtype=np.uint16)
    out = from_dn(dn, 1.5)
    assert out.dtype == np.float64
    np.testing.assert_array_equal(out, [[0.0, 1.5, 65535 * 1.5]])


@pytest.mark.parametrize("gain", [1.0, 2.0, 0.5, 4.0, 1.5, 2.7, 3.3])
def test_adc_codes_match_definition_for_float32_input(gain):
    # float32 electrons as the engine and the generator hold them, including values
    # whose quotient lies within float32 rounding of a half-integer (e = (k + 1/2) g):
    # a float32 quotient would round some of them the other way; the definition is
    # the float64 quotient, which ADC follows for every gain (exactly, in float32,
    # only when the gain is a power of two).
    rng = np.random.default_rng(3)
    e = rng.uniform(-100, 70000, 200_000).astype(np.float32)
    halves = ((np.arange(5000) + 0.5) * gain).astype(np.float32)
    e = np.concatenate([e, halves, np.nextafter(halves, np.float32(0)),
                        np.nextafter(halves, np.float32(1e9))])
    want = _definition(e, gain)
    got = ADC(gain).to_dn(e.copy())
    assert got.dtype == np.uint16
    np.testing.assert_array_equal(got, want)


def test_adc_codes_leaves_float32_input_alone_for_other_gains():
    e = np.array([1.0, 2.5, 3.5], dtype=np.float32)
    codes = ADC(1.5).codes(e)
    np.testing.assert_array_equal(e, [1.0, 2.5, 3.5])
    np.testing.assert_array_equal(codes, [1.0, 2.0, 2.0])


def test_adc_bits_above_16_give_uint32_and_never_wrap():
    # an ADC of 20 bits keeps 1e6 DN (a uint16 conversion would wrap it to 16960)
    dn = to_dn(np.array([[1e6, 2e6]]), 1.0, bits=20)
    assert dn.dtype == np.uint32
    np.testing.assert_array_equal(dn, [[1_000_000, 2 ** 20 - 1]])


def test_noise_frames_in_dn_match_definition():
    # NoiseGenerator.frames(dn_gain=g) digitises each float32 frame by the definition
    det = noise.preset("H2RG", naxis1=64, naxis2=64)
    params = noise.NIRSPEC_DEFAULTS.replace(bias_offset=3000.0)
    for gain in (2.0, 2.7):
        fe = [f.copy() for *_, f in noise.NoiseGenerator(det, params, rng=4).frames(3)]
        fd = [f for *_, f in noise.NoiseGenerator(det, params, rng=4).frames(3,
                                                                             dn_gain=gain)]
        for a, b in zip(fe, fd):
            np.testing.assert_array_equal(b, _definition(a, gain))


def test_adc_rejects_bad_gain_and_bits_at_construction():
    with pytest.raises(ParameterError, match="'gain' must be"):
        ADC(0.0)
    with pytest.raises(ParameterError, match="'adc_bits'"):
        ADC(1.0, bits=0)
    with pytest.raises(ParameterError, match="'electrons' must be an array of real"):
        to_dn("abc", 1.0)


@pytest.mark.parametrize("count", [2, 3, 7, 44, 127, 128, 129, 300])
def test_mean_codes_rounds_like_float64(count):
    """The resultant mean of uint32 DN sums: float32 arithmetic (count <= 128) must
    give exactly the float64 rounding, half to even included.  Checked on every sum
    within +-count of the half-integer boundaries of the 512 highest DN (where the
    float32 ulp is largest) and of the lowest 64 DN."""
    k = np.r_[np.arange(64), np.arange(65535 - 512, 65535)]
    off = np.arange(-count, count + 1)
    s = (k[:, None] * count + count // 2 + off[None, :]).ravel()
    s = s[(s >= 0) & (s <= 65535 * count)].astype(np.uint32)
    expected = np.clip(np.rint(s / count), 0, 65535).astype(np.uint16)
    out = np.empty(s.size, np.uint16)
    np.testing.assert_array_equal(ADC(1.0).mean_codes(s, count, out=out), expected)
