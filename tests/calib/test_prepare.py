"""Tests of :mod:`scenesim.calib.prepare`: the options, the shared pre-processing, fits
of in-memory exposures, and the header of the slope file.

* ``prepare_exposure`` with every data-driven step off is exactly DN x GAIN (then the
  reference correction of :mod:`scenesim.calib.refpix`), with the header's read noise;
* an exposure kept in memory (``write_exposure(engine, None)``) prepares and fits to
  the same bits as the file written from the same engine and seed, and
  ``run_scene`` with ``ramp = false`` (no ramp file) gives the same slope file as
  with ``ramp = true``;
* the ``EXPOSURE`` card of a slope file fits in one 80-character card whatever the
  path (pytest turns astropy's "card is too long" warning into an error).
"""

import os
import warnings

import numpy as np
import pytest
from astropy.io import fits

import noise
from noise.clock import Subarray, preset
from noise.errors import FileFormatError, ParameterError
from scenesim.engine import ChargeEngine, EngineOptions
from scenesim.io.exposure import Exposure, read_exposure
from scenesim.run import write_exposure
from scenesim.io.fitfile import read_fit
from scenesim.calib.prepare import (PreparedExposure, PrepareOptions, fit_exposure_file,
                                    load_exposure, prepare_exposure)
from scenesim.io.header import exposure_readout, header_nonlinearity
from scenesim.detector.nonlinearity import Nonlinearity, linearize_resultants
from scenesim.detector.readout import Readout
from scenesim.calib.refpix import correct_reference
from scenesim.run import run_scene
from scenesim.scene import parse_scene

_FIT_FIELDS = ("slope", "var_read", "var_poisson", "chi2", "dof", "dq", "slope_ints",
               "var_ints", "n_jumps")


def _engine(seed=21):
    """64 x 64 H2RG, 6 RAPID groups, paper-default noise, a gradient of rates and a
    full well that the brightest column reaches (so saturation flags are exercised)."""
    det = preset("H2RG", naxis1=64, naxis2=64)
    ro = Readout.multiaccum(1, 6, nints=2, name="RAPID")
    xx = np.mgrid[0:64, 0:64][1]
    rate = np.where(det.reference_mask(), 0.0, 200.0 + 4e4 * (xx >= 56))
    return ChargeEngine(det, ro, rate=rate, full_well=2000.0, gain=1.5,
                        noise_params=noise.NoiseParams(), rng=seed,
                        options=EngineOptions(threads=1))


def _assert_same_fit(a, b):
    for name in _FIT_FIELDS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), name)
    assert a.read_noise == b.read_noise and a.gain == b.gain


# ------------------------------------------------------------------ steps
def test_prepare_without_data_driven_steps_is_dn_times_gain(tmp_path):
    path = str(tmp_path / "e.fits")
    write_exposure(_engine(), path)
    sci, hdr, _ = read_exposure(path)
    gain = float(hdr["GAIN"])
    p = prepare_exposure(path,
                         options=PrepareOptions(refpix="none", remove_common_mode=False,
                                                measure_noise=False))
    assert isinstance(p, PreparedExposure)
    assert p.electrons.dtype == np.float32 and p.electrons.shape == sci.shape
    np.testing.assert_array_equal(p.electrons,
                                  sci.astype(np.float32) * np.float32(gain))
    assert p.read_noise == p.read_noise_model == float(hdr["RDNOISE"])
    assert p.gain == gain and p.t_frame == float(hdr["TFRAME"])
    assert p.name == path
    # bright columns (4e4 e-/s, 728 e- per 0.0182 s frame) reach the 2000 e- full
    # well at the third read: flagged, and sticky; the 200 e-/s columns never reach
    # it (22 e- in all).  A clipped last resultant is flagged when it is >= 97 % of
    # the full well above the zero level extrapolated from resultants 0 and 1,
    # z = 2 R0 - R1: its error 2 P0 - P1 (independent Poisson 728 e- each, sd 27 e-,
    # so sd ~38 e- with the read noise) must stay below the 60 e- margin, which
    # misses P(N(0,1) > 60/38) ~ 6 % of the pixels.  Over 2 x 56 x 4 = 448 pixels
    # the flagged fraction is 0.94 +- 0.011; 5 sigma below is 0.88.
    bright = p.saturated[..., 4:60, 56:60]                 # regular pixels only
    assert bright[:, -1].mean() > 0.88 and not p.saturated[..., 8:50].any()
    assert np.all(np.diff(p.saturated.astype(np.int8), axis=1) >= 0)
    cards = dict((k, v) for k, v, _ in p.cards)
    assert cards["RNSOURCE"] == "model" and cards["CMREMOVE"] is False
    assert cards["REFPIX"] == "none" and cards["RNCONV"] == "per read"
    assert cards["READPATT"] == "RAPID" and cards["NINTS"] == 2
    # no IPC in this exposure: nothing undone, the read noise as in the header
    assert cards["IPCDECON"] is False and cards["IPCRNFAC"] == 1.0
    assert cards["IPC"] is False and "IPCKERN" not in cards
    # the reference correction is refpix.correct_reference on the e- cube
    q = prepare_exposure(path,
                         options=PrepareOptions(refpix="jwst", remove_common_mode=False,
                                                measure_noise=False))
    np.testing.assert_array_equal(
        q.electrons, correct_reference(p.electrons, p.detector, scheme="jwst"))
    np.testing.assert_array_equal(q.saturated, p.saturated)


def test_prepare_measured_noise_is_a_column_map(tmp_path):
    path = str(tmp_path / "e.fits")
    write_exposure(_engine(), path)
    p = prepare_exposure(path)
    ny, nx = p.detector.shape
    assert p.read_noise.shape == (ny, nx)
    # one value per column (the groups of measure_read_noise)
    np.testing.assert_array_equal(p.read_noise,
                                  np.broadcast_to(p.read_noise[0], (ny, nx)))
    assert np.all(p.read_noise > 0)
    cards = dict((k, v) for k, v, _ in p.cards)
    assert cards["RNSOURCE"] == "measured" and cards["CMREMOVE"] is True


# ------------------------------------------------------------------ in memory
def test_in_memory_exposure_fits_like_the_file(tmp_path):
    path = str(tmp_path / "e.fits")
    write_exposure(_engine(), path)
    mem = write_exposure(_engine(), None)["exposure"]
    assert isinstance(mem, Exposure) and mem.name == "(in memory)"
    disk = load_exposure(path)
    np.testing.assert_array_equal(mem.sci, disk.sci)
    assert list(mem.header.items()) == list(disk.header.items())
    assert exposure_readout(mem) == exposure_readout(disk)
    a, b = prepare_exposure(path), prepare_exposure(mem)
    for name in ("electrons", "saturated", "read_noise", "refmask"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), name)
    assert a.cards[1:] == b.cards[1:]            # all but EXPOSURE
    fa = fit_exposure_file(path, str(tmp_path / "a.fits"))
    fb = fit_exposure_file(mem, str(tmp_path / "b.fits"))
    _assert_same_fit(fa, fb)
    with fits.open(tmp_path / "b.fits") as hdul:
        assert hdul[0].header["EXPOSURE"] == "(in memory)"


def _scene(ramp):
    return parse_scene({
        "seed": 8675309,
        "detector": {"preset": "H2RG", "naxis1": 64, "naxis2": 64},
        "noise": {"preset": "nirspec"},
        "readout": {"pattern": "RAPID", "ngroups": 6},
        "sources": {"background": 20.0, "dark_current": 0.01,
                    "stars": [{"x": 30.3, "y": 20.6, "flux": 2e6}],
                    "psf": {"kind": "gaussian", "fwhm": 2.0}},
        "effects": {"full_well": 1e4, "cosmic_ray_rate": 2e3},
        "output": {"path": "x.fits", "ramp": ramp, "fit": "gls", "truth": True},
    })


def test_run_without_ramp_file_gives_the_same_slopes(tmp_path):
    """ramp = false fits the resultants in memory: same slope file, no ramp file."""
    for ramp in (True, False):
        (tmp_path / str(ramp)).mkdir()
    with_ramp = run_scene(_scene(True), output=str(tmp_path / "True" / "x.fits"),
                          progress=False)
    without = run_scene(_scene(False), output=str(tmp_path / "False" / "x.fits"),
                        progress=False)
    assert with_ramp.exposure is not None and without.exposure is None
    assert sorted(os.listdir(tmp_path / "False")) == ["x_gls.fits", "x_truth.fits"]
    a, b = read_fit(with_ramp.fit), read_fit(without.fit)
    _assert_same_fit(a, b)
    # the scene injects saturation and cosmic rays, so both paths are exercised
    assert np.any(a.dq & 2) and np.any(a.n_jumps > 0)


# ------------------------------------------------------------------ header card
def test_exposure_card_fits_for_a_long_path(tmp_path):
    deep = tmp_path / ("a_rather_long_directory_name_" * 3) / "more"
    deep.mkdir(parents=True)
    path = str(deep / "l'été_exposure.fits")             # quote and non-ASCII too
    assert len(path) > 120
    write_exposure(_engine(), path)
    out = str(tmp_path / "fit.fits")
    with warnings.catch_warnings():
        warnings.simplefilter("error")          # also outside pytest's filter
        fit_exposure_file(path, out,
                          options=PrepareOptions(measure_noise=False,
                                                 remove_common_mode=False))
        with fits.open(out) as hdul:
            hdr = hdul[0].header
            card = hdr.cards["EXPOSURE"]
            assert len(card.image) == 80
            value = hdr["EXPOSURE"]
            # the end of the path, made printable ASCII (a quote counts twice)
            assert value.startswith("...")
            assert value.endswith("/more/l'?t?_exposure.fits")
            assert len(value) + value.count("'") == 50
            assert hdr.comments["EXPOSURE"] == "fitted exposure"
            hdr.tostring()


# ------------------------------------------------------------------ bad input
@pytest.mark.parametrize("kwargs, match", [
    (dict(refpix="JWST"), "'refpix'"),
    (dict(read_noise=-1.0), "'read_noise'"),
    (dict(read_noise=float("nan")), "'read_noise'"),
    (dict(remove_common_mode=1), "'remove_common_mode'"),
    (dict(measure_noise="no"), "'measure_noise'"),
    (dict(threads=0), "'threads'"),
    (dict(deconvolve_ipc=1), "'deconvolve_ipc'"),
    (dict(linearize="no"), "'linearize'"),
])
def test_prepare_options_are_checked_when_made(kwargs, match):
    with pytest.raises(ParameterError, match=match):
        PrepareOptions(**kwargs)


def test_prepare_options_defaults_and_canonical_values(tmp_path):
    # The defaults are those of the former keyword arguments; values come back in
    # their canonical types; a non-options object is rejected before any reading.
    o = PrepareOptions()
    assert (o.refpix, o.read_noise, o.remove_common_mode, o.measure_noise, o.threads,
            o.linearize, o.deconvolve_ipc) == ("jwst", None, True, True, None, True, True)
    o = PrepareOptions(read_noise=np.float32(5), threads=np.int64(2))
    assert type(o.read_noise) is float and type(o.threads) is int
    assert hash(o) == hash(PrepareOptions(read_noise=5.0, threads=2))
    with pytest.raises(ParameterError, match="'read_noise'.*None"):
        PrepareOptions(read_noise=-1.0)
    with pytest.raises(ParameterError, match="'options'.*PrepareOptions"):
        prepare_exposure(str(tmp_path / "missing.fits"), options={"refpix": "none"})
    with pytest.raises(ParameterError, match="'options'.*PrepareOptions"):
        fit_exposure_file(str(tmp_path / "missing.fits"), str(tmp_path / "f.fits"),
                          options=None)
    assert list(tmp_path.iterdir()) == []


def test_prepare_bad_exposure(tmp_path):
    with pytest.raises(ParameterError, match="'exposure'.*Exposure"):
        prepare_exposure(42)
    with pytest.raises(FileFormatError, match="does not exist"):
        prepare_exposure(tmp_path / "missing.fits")
    mem = write_exposure(_engine(), None)["exposure"]
    hdr = mem.header.copy()
    del hdr["TFRAME"]
    with pytest.raises(FileFormatError, match="TFRAME"):
        prepare_exposure(Exposure(mem.sci, hdr, mem.reads))
    with pytest.raises(FileFormatError, match="SCI shape"):
        prepare_exposure(Exposure(mem.sci[:, :3], mem.header, mem.reads))
    with pytest.raises(ParameterError, match="'jump_threshold'"):
        fit_exposure_file(mem, str(tmp_path / "f.fits"), jump_threshold=-1.0)
    assert list(tmp_path.iterdir()) == []


def test_linearize_resultants_inverts_the_recorded_nonlinearity():
    """Closed form: single-read resultants m_k = z + p(f t_k) with p(q) = q + c2 q^2
    + c3 q^3 and a zero level z; linearising gives z + f t_k back (to float32
    round-off of values ~5e4 e-, i.e. < 0.01 e-), and the header round-trips."""
    nl = Nonlinearity((-8e-7, -2e-12))
    t = (np.arange(6) + 1) * 10.0                       # s
    f = np.array([[10.0, 300.0], [1000.0, 800.0]])      # e-/s, up to 6e4 e-
    z = np.array([[5000.0, 4000.0], [6000.0, 5500.0]])  # zero level, e-
    q = f[None] * t[:, None, None]
    m = (z[None] + nl.apply(q))[None].astype(np.float32)     # (1, 6, 2, 2)
    out = linearize_resultants(m, nl, t)
    np.testing.assert_allclose(out[0], z[None] + q, atol=0.02)
    hdr = fits.Header([("NONLIN", True), ("NLCOEFF", "-8e-07,-2e-12")])
    assert header_nonlinearity(hdr) == nl
    assert header_nonlinearity(fits.Header([("NONLIN", False)])) is None


@pytest.mark.parametrize("flag", ["remove_common_mode", "measure_noise"])
def test_prepare_options_check_flags_first(flag):
    with pytest.raises(ParameterError, match=flag):
        PrepareOptions(**{flag: "yes"})


# ------------------------------------------------------------------ refpix on a window
def _window_exposure(tmp_path):
    """A 16 x 16 window at (20, 20) of a 64 x 64 H2RG: no reference pixel at all."""
    det = preset("H2RG", naxis1=64, naxis2=64,
                 subarray=Subarray("window", 20, 20, 16, 16))
    assert not det.reference_mask().any()
    ro = Readout.multiaccum(1, 5, name="RAPID")
    eng = ChargeEngine(det, ro, rate=np.full(det.shape, 5.0), gain=1.0,
                       noise_params=noise.NoiseParams(), rng=4,
                       options=EngineOptions(threads=1))
    path = str(tmp_path / "w.fits")
    write_exposure(eng, path)
    return path


def test_a_correction_the_window_cannot_support_is_refused_and_jwst_recorded_as_none(
        tmp_path):
    """'median' (no reference rows) and 'irs2' (no interleaving) are refused naming
    the exposure, before a fit file is written; the default 'jwst' has nothing to
    subtract on a window with no reference pixel: the fit is that of 'none' and its
    file says so (before: REFPIX 'jwst', with nothing done)."""
    path = _window_exposure(tmp_path)
    for scheme, match in (("median", "needs top/bottom reference rows"),
                          ("irs2", "needs interleaved reference samples")):
        out = tmp_path / f"{scheme}.fits"
        with pytest.raises(ParameterError, match=rf"exposure .*w\.fits.*{match}"):
            fit_exposure_file(path, str(out), options=PrepareOptions(refpix=scheme))
        assert not out.exists()
    a = fit_exposure_file(path, str(tmp_path / "jwst.fits"))
    b = fit_exposure_file(path, str(tmp_path / "none.fits"),
                          options=PrepareOptions(refpix="none"))
    _assert_same_fit(a, b)
    assert fits.getheader(tmp_path / "jwst.fits")["REFPIX"] == "none"
    assert prepare_exposure(path).cards[1] == ("REFPIX", "none",
                                               "reference-pixel correction")


def test_a_scene_asking_a_correction_its_readout_cannot_support_is_refused():
    scene = {"detector": {"preset": "H2RG", "naxis1": 64, "naxis2": 64,
                          "subarray": {"x0": 20, "y0": 20, "nx": 16, "ny": 16}},
             "readout": {"pattern": "RAPID", "ngroups": 5},
             "output": {"path": "x.fits", "fit": "gls", "refpix": "median"}}
    with pytest.raises(ParameterError, match=r"\[output\] refpix 'median' needs "
                                             r"top/bottom reference rows"):
        parse_scene(scene)
    scene["output"]["refpix"] = "jwst"
    assert parse_scene(scene).output.refpix == "jwst"
