"""The references of a simulated detector against closed forms and the engine itself
(no pipeline needed)."""

import os

import numpy as np
import pytest

import noise
from noise.template import template_for
from scenesim.detector.ipc import apply_ipc, ipc_kernel
from scenesim.detector.nonlinearity import Nonlinearity
from scenesim.pipelines.instrument import InstrumentConfig, resolve_instrument
from scenesim.pipelines.jwst import jwst_frame_time
from scenesim.pipelines.reffiles import (HOT, detector_reference, ipc_inverse_kernel,
                                         linearity_coefficients,
                                         nonlinearity_coefficients, shift_polynomial)
from scenesim.detector.dq import REFERENCE_PIXEL
from scenesim.run import build_engine
from scenesim.scene import load_scene, parse_scene

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.join(HERE, "..", "data", "pipelines")


def test_linearity_polynomial_inverts_the_nonlinearity():
    # bright_star.toml's law: 7.7 % low at the 8e4 e- full well
    nl = Nonlinearity((-8e-7, -2e-12))
    gain, fw = 2.0, 8e4
    coeffs, err = linearity_coefficients(nl, fw, gain)
    q = np.linspace(0, fw, 1001)
    m_dn = nl.apply(q) / gain
    q_dn = np.polynomial.polynomial.polyval(m_dn, coeffs)
    # the recorded error bound holds (in e-), and it is far below the read noise
    assert np.max(np.abs(q_dn * gain - q)) <= err * 1.01 + 1e-9
    assert err < 0.1                              # e-, vs ~5 e- read noise per read


def test_nonlinearity_in_dn_is_the_engine_law():
    """p(q) / g = sum_i b_i (q / g)**i exactly (a change of variable), and the
    linearity polynomial inverts it to its recorded error."""
    nl = Nonlinearity((-8e-7, -2e-12))
    gain = 2.0
    b = nonlinearity_coefficients(nl, gain)
    assert b.tolist()[:2] == [0.0, 1.0] and b.size == 4
    q = np.linspace(0, 8e4, 1001)
    m_dn = np.polynomial.polynomial.polyval(q / gain, b)
    # float64: terms up to 8e4/2 DN, so the round-off is ~1e-16 x 4e4 x 4 terms
    assert np.allclose(m_dn, nl.apply(q) / gain, rtol=0, atol=1e-9)
    a, err = linearity_coefficients(nl, 8e4, gain)
    back = np.polynomial.polynomial.polyval(m_dn, a)
    assert np.max(np.abs(back - q / gain)) <= err / gain * 1.01 + 1e-9
    assert nonlinearity_coefficients(None, gain).tolist() == [0.0, 1.0]
    with pytest.raises(ValueError, match="'gain'"):
        nonlinearity_coefficients(nl, 0.0)


def test_shift_polynomial_recentres_on_each_offset():
    """shift_polynomial(a, b) evaluated at x equals P(x - b) evaluated directly (the
    binomial expansion), per offset; a zero offset changes nothing."""
    rng = np.random.default_rng(11)
    a = rng.normal(size=5) * 10.0 ** -np.arange(5)          # a decaying polynomial
    b = rng.uniform(-3, 3, size=(4, 6))
    shifted = shift_polynomial(a, b)
    assert shifted.shape == (5, 4, 6)
    x = rng.uniform(-2, 5, size=(4, 6))
    direct = np.polynomial.polynomial.polyval(x - b, a)
    expanded = np.zeros_like(x)
    for i in range(5):
        expanded += shifted[i] * x ** i
    # float64 round-off of terms of size up to |a_k| C(k, i) 8**k, summed: < 1e-10
    assert np.allclose(expanded, direct, rtol=0, atol=1e-10)
    assert np.array_equal(shift_polynomial(a, 0.0), a)
    # a float32 result is the float64 one rounded once (computed in float64)
    assert np.array_equal(shift_polynomial(a, b, dtype=np.float32),
                          shifted.astype(np.float32))
    with pytest.raises(ValueError, match="'coeffs'"):
        shift_polynomial([], 1.0)


def test_linearity_null_limit():
    coeffs, err = linearity_coefficients(None, 8e4, 2.0)
    assert coeffs.tolist() == [0.0, 1.0] and err == 0.0
    coeffs, err = linearity_coefficients(Nonlinearity(()), 8e4, 2.0)
    assert coeffs.tolist() == [0.0, 1.0]


@pytest.mark.parametrize("alpha, diag", [(0.015, 0.0), (0.02, 0.002), (0.0, 0.0)])
def test_ipc_inverse_undoes_the_kernel(alpha, diag):
    k = ipc_kernel(alpha, diag)
    inv = ipc_inverse_kernel(k)
    assert inv.shape == (5, 5) and abs(inv.sum() - 1) < 1e-12
    rng = np.random.default_rng(5)
    img = rng.uniform(0, 1e4, (40, 40))
    from scipy.ndimage import convolve
    back = convolve(apply_ipc(img, k), inv, mode="wrap")
    # truncation error of order (4 alpha)^3 of the signal (module notes); the edge
    # of apply_ipc is not periodic, so the interior is checked
    tol = 20 * (4 * alpha + 4 * diag) ** 3 * 1e4 + 1e-6
    assert np.max(np.abs(back - img)[3:-3, 3:-3]) < tol
    if alpha == 0:
        assert np.array_equal(inv[2, 2], 1.0)


def test_detector_reference_matches_the_engine():
    scene = load_scene(os.path.join(DATA, "jwst_loop.toml"))
    engine, _ = build_engine(scene)
    ref = detector_reference(scene, engine)
    det = engine.detector
    refmask = det.reference_mask()
    # dark: dark current + hot pixels, the engine's own draws; the engine's rate is
    # that plus light (background and stars), which is >= 0
    dark_scene = scene.replace(sources=scene.sources.__class__(
        dark_current=scene.sources.dark_current,
        hot_pixel_fraction=scene.sources.hot_pixel_fraction,
        hot_pixel_rate=scene.sources.hot_pixel_rate))
    dark_engine, _ = build_engine(dark_scene)
    assert np.array_equal(ref.dark, dark_engine.rate)
    assert np.all(ref.dark[refmask] == 0)
    hot = (ref.mask & HOT) != 0
    assert hot.sum() > 0 and np.all(ref.dark[hot] > scene.sources.dark_current)
    assert np.array_equal((ref.mask & REFERENCE_PIXEL) != 0, refmask)
    # read noise per read: the white noise, times ref_ratio on reference pixels
    p = scene.noise
    assert np.allclose(ref.read_noise[~refmask], p.rd_noise)
    assert np.allclose(ref.read_noise[refmask], p.rd_noise * p.ref_ratio)
    # bias: offset + amplitude x the generator's template (its mean reset level:
    # test_reset_levels_average_to_the_bias)
    assert np.allclose(ref.bias, p.bias_offset + p.bias_amp * template_for(det))
    # saturation: k_c p(full well) above the bias, less 5 times the spread of every
    # noise component about the bias (kTC, pedestal, 1/f wander too: below)
    nl = engine.nonlinearity
    level = ref.ipc_kernel[1, 1] * nl.apply(np.array([8e4]))[0]
    assert np.allclose(ref.saturation[~refmask],
                       ref.bias[~refmask] + level - 5 * p.spread(det))
    assert np.allclose(ref.ipc_kernel, ipc_kernel(0.015))


def test_reset_levels_average_to_the_bias():
    """The bias reference is the mean reset level: the average of many integrations'
    noise-only first reads approaches it within the noise's standard error."""
    scene = parse_scene({
        "seed": 3, "detector": {"preset": "H2RG", "naxis1": 64, "naxis2": 64,
                                "n_out": 1},
        "noise": {"c_pink": 0, "u_pink": 0, "acn": 0, "pca0": 0},
        "readout": {"pattern": "RAPID", "ngroups": 1, "nints": 200},
        "output": {"path": "x.fits", "truth": False}})
    engine, _ = build_engine(scene)
    ref = detector_reference(scene, engine)
    first = []
    with engine.simulate() as run:
        for res in run:
            first.append(res.dn.astype(np.float64))
    mean_e = np.mean(first, axis=0) * engine.gain
    p = scene.noise
    # per pixel: kTC, pedestal and white noise of one read, over 200 integrations;
    # rounding to DN adds gain^2/12
    sigma = np.sqrt(p.ktc ** 2 + p.pedestal ** 2 + p.rd_noise ** 2
                    + engine.gain ** 2 / 12) / np.sqrt(len(first))
    z = (mean_e - ref.bias) / sigma
    # the pedestal is common to the frame: one draw per integration for every pixel,
    # so the mean of z over pixels has the pedestal's standard error
    assert abs(np.median(z)) < 5 * p.pedestal / np.sqrt(len(first)) / sigma.mean() + 0.5
    assert 0.7 < np.std(z) < 1.3


def test_jwst_frame_time_formula():
    # JDox "NIRCam Detector Subarrays": SUB64P (1 output) 0.05016 s; full frame
    # 10.73677 s with 4 outputs
    full = noise.preset("NIRCAM")
    assert jwst_frame_time(full) == pytest.approx(10.73677, abs=1e-8)
    assert full.frame_time == pytest.approx(jwst_frame_time(full) - 1e-5, abs=1e-9)
    win = noise.preset("NIRCAM", nfoh=2).window(0, 0, 64, 64)
    assert jwst_frame_time(win) == pytest.approx(0.05016, abs=1e-9)
    assert win.frame_time == pytest.approx(jwst_frame_time(win), abs=1e-12)


def test_wfi_preset_frame_time_is_3_04_s():
    det = noise.preset("WFI")
    assert det.frame_time == 3.04
    assert (det.n_out, det.ncols_out, det.nroh, det.ref_border) == (32, 128, 14, 4)
    # the H4RG-10 preset keeps its clock (existing scenes keep their arrays)
    assert noise.preset("H4RG-10").frame_time == pytest.approx(3.03178, abs=1e-5)


def test_instrument_defaults_and_checks():
    det = noise.preset("H2RG")
    got = resolve_instrument(InstrumentConfig(), det, "NRSRAPID")
    assert got == {"name": "NIRSPEC", "detector": "NRS1", "exp_type": "NRS_IMAGE",
                   "subarray": "FULL", "readpatt": "NRSRAPID"}
    got = resolve_instrument(InstrumentConfig(detector="nrcb2"), det.window(0, 0, 8, 8),
                             "MA_TABLE")
    assert got["name"] == "NIRCAM" and got["subarray"] == "GENERIC"
    assert got["readpatt"] == "ANY"
    with pytest.raises(ValueError, match="'exp_type' of a NIRSPEC"):
        InstrumentConfig(name="NIRSPEC", exp_type="NRC_IMAGE")
    with pytest.raises(ValueError, match="did you mean 'NIRCAM'"):
        InstrumentConfig(name="NIRCAMM")


@pytest.mark.parametrize("as_map", [False, True], ids=["scalar", "map"])
def test_every_read_of_a_full_pixel_is_at_or_above_the_saturation_reference(tmp_path,
                                                                            as_map):
    """A field saturated from the first read (probe of 2026-11-27: with a margin of 5
    white sigma, kTC, the pedestal and the 1/f wander left one full pixel in seven
    below the reference for its whole ramp).  The reference is 5 times the noise's
    whole spread below the flat top: a read falls under it with probability
    < 3e-7 (Gaussian), ~1e-3 expected over these 64 x 64 x 5 x 4 reads; none
    allowed.  A full well that differs between pixels (a map) is each pixel's own."""
    fw = np.full((64, 64), 8e4)
    full_well = 8e4
    if as_map:
        fw[:, 32:] = 6e4
        from astropy.io import fits
        fits.writeto(tmp_path / "fw.fits", fw)
        full_well = str(tmp_path / "fw.fits")
    scene = parse_scene({
        "seed": 404, "detector": {"preset": "H2RG", "naxis1": 64, "naxis2": 64,
                                  "n_out": 1},
        "noise": {"preset": "nirspec"},
        "readout": {"pattern": "RAPID", "ngroups": 5, "nints": 4},
        "sources": {"background": 3e7},
        "effects": {"full_well": full_well, "gain": 2.0},
        "output": {"path": "x.fits", "truth": False}})
    engine, _ = build_engine(scene)
    ref = detector_reference(scene, engine)
    regular = ~engine.detector.reference_mask()
    below = 0
    lowest = np.inf
    with engine.simulate() as run:
        for res in run:
            e = res.dn.astype(np.float64) * engine.gain
            below += int((e[regular] < ref.saturation[regular]).sum())
            lowest = min(lowest, float((e - ref.saturation)[regular].min()))
    assert below == 0, (below, lowest)
    # and not absurdly early: within 10 spreads of the flat top (the margin is 5)
    spread = scene.noise.spread(engine.detector)
    top = ref.bias + ref.ipc_kernel[1, 1] * fw
    assert np.all(top[regular] - ref.saturation[regular] <= 10 * spread)


def test_reference_id_follows_the_hot_pixels_not_the_seed():
    """Runs of one scene with other seeds have other hot pixels, hence another
    reference id (the pipelines refuse their references for each other); without
    hot pixels their references are the same, and so is the id."""
    from scenesim.pipelines.reffiles import reference_id

    def ident(seed, hot):
        scene = parse_scene({
            "seed": seed, "detector": {"preset": "H2RG", "naxis1": 64, "naxis2": 64},
            "readout": {"pattern": "RAPID", "ngroups": 3},
            "sources": {"dark_current": 0.01, "hot_pixel_fraction": hot},
            "output": {"path": "x.fits", "truth": False}})
        engine, _ = build_engine(scene)
        return reference_id(detector_reference(scene, engine))

    assert ident(1, 0.01) != ident(2, 0.01)
    assert ident(1, 0.0) == ident(2, 0.0)
    assert ident(1, 0.01) == ident(1, 0.01) and len(ident(1, 0.0)) == 16
