"""Tests of :mod:`scenesim.adapters.stcal` (stcal's ramp fitting on scenesim files).

Exposures are simulated with scenesim's own engine on small H2RG arrays whose pixel
time ``dt`` is stretched so that one frame lasts about 10 s (as on a full H2RG):
``t_frame = (ny + 1) * (nx / 4 + 12) * dt``.  Checks against theory:

* noiseless ramps: any linear unbiased fit returns the rate up to the ADC rounding;
* white read noise, rate 0: the scatter of the slopes and stcal's reported read-noise
  variance against the closed forms :func:`scenesim.rampfit.variance.ols_variance` /
  :func:`scenesim.rampfit.variance.optimal_variance`.  The reported variance depends
  only on the read noise, gain and timing handed to stcal, so it pins the unit conversion
  (per-read e- -> CDS DN): a factor sqrt(2), a gain or an NFRAMES mistake fails.

These closed-form checks hand stcal the model read noise and skip the common-mode
removal (``measure_noise=False, remove_common_mode=False``: on noiseless ramps the
measured noise falls to its floor, 0.1 sigma; the scatter test needs independent
pixels);
:func:`test_stcal_sees_the_prepared_exposure` checks the default, in which stcal gets
the arrays and the measured read-noise map of
:func:`scenesim.calib.prepare.prepare_exposure`, exactly as scenesim's own fitters do.
"""

import os
import subprocess
import sys

import numpy as np
import pytest

stcal = pytest.importorskip("stcal")

import scenesim  # noqa: E402

from astropy.io import fits  # noqa: E402

from noise.clock import preset  # noqa: E402
from noise.errors import FileFormatError, ParameterError  # noqa: E402
from noise.params import ZERO_NOISE  # noqa: E402
from scenesim.validate.compare import compare_files  # noqa: E402
from scenesim.engine import ChargeEngine, EngineOptions  # noqa: E402
from scenesim.run import write_exposure  # noqa: E402
from scenesim.detector.dq import (BAD_VARIANCE, DO_NOT_USE, REFERENCE_PIXEL,  # noqa: E402
                                  SATURATED)
from scenesim.io.fitfile import read_fit  # noqa: E402
from scenesim.rampfit import model_chi2, ols_variance, optimal_variance  # noqa: E402
from scenesim.calib.prepare import (PrepareOptions, fit_exposure_file,  # noqa: E402
                                    prepare_exposure)
from scenesim.detector.readout import ROMAN_LIKE_TABLE, Readout  # noqa: E402
from scenesim.adapters.stcal import (STCAL_ALGORITHMS, fit_exposure_stcal,  # noqa: E402
                                    stcal_read_noise)

T_FRAME = 10.01   # s


def _det(n):
    """n x n H2RG (4 outputs) with a frame time of T_FRAME."""
    return preset("H2RG", naxis1=n, naxis2=n, dt=T_FRAME / ((n + 1) * (n // 4 + 12)))


# With no charge at all the engine's digitiser dereferences its (absent) charge
# frame unless an IPC kernel is set; the identity kernel changes nothing.
_IDENTITY_IPC = np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.0]])


def _noiseless_stcal_fit(tmp_path, det, ro, rate, gain, algorithm, **engine_kw):
    """stcal fit (read noise 10 e-, no common mode, no noise measurement) of a
    noise-free, shot-noise-free exposure of ``rate``."""
    eng = ChargeEngine(det, ro, rate=rate, gain=gain, rng=1,
                       options=EngineOptions(shot_noise=False), **engine_kw)
    exp = str(tmp_path / "noiseless.fits")
    write_exposure(eng, exp)
    return fit_exposure_stcal(exp, str(tmp_path / "fit.fits"), algorithm=algorithm,
                              options=PrepareOptions(read_noise=10.0,
                                                     remove_common_mode=False,
                                                     measure_noise=False))


def _white_exposure(tmp_path, det, ro, *, sigma, gain, rate=0.0, seed=7, name="w"):
    noise = ZERO_NOISE.replace(rd_noise=sigma, bias_offset=2000.0)
    no_charge = bool(np.all(np.asarray(rate) == 0))
    eng = ChargeEngine(det, ro, rate=rate, gain=gain, noise_params=noise, rng=seed,
                       ipc_kernel=_IDENTITY_IPC if no_charge else None)
    path = str(tmp_path / f"{name}.fits")
    truth = str(tmp_path / f"{name}_truth.fits")
    write_exposure(eng, path, truth_path=truth)
    return path, truth


# --------------------------------------------------------------------- conventions
def test_stcal_read_noise_convention():
    """stcal wants the CDS noise of two single frames in DN: sqrt(2) sigma / gain."""
    assert stcal_read_noise(10.0, 2.0) == pytest.approx(np.sqrt(2.0) * 5.0, rel=1e-15)
    np.testing.assert_allclose(stcal_read_noise(np.array([3.0, 6.0]), 3.0),
                               np.sqrt(2.0) * np.array([1.0, 2.0]), rtol=1e-15)
    with pytest.raises(ParameterError, match="gain"):
        stcal_read_noise(10.0, 0.0)
    with pytest.raises(ParameterError, match="read_noise"):
        stcal_read_noise(-1.0, 1.0)


def test_importing_the_adapter_does_not_import_stcal():
    root = os.path.dirname(os.path.dirname(os.path.abspath(scenesim.__file__)))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [root] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]))
    code = ("import sys, scenesim, scenesim.adapters.stcal; "
            "sys.exit(3 if any(m == 'stcal' or m.startswith('stcal.') "
            "for m in sys.modules) else 0)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60, env=env)
    assert proc.returncode == 0, (proc.returncode, proc.stderr)


def test_missing_stcal_gives_install_hint(tmp_path, monkeypatch):
    for mod in [m for m in sys.modules if m == "stcal" or m.startswith("stcal.")]:
        monkeypatch.setitem(sys.modules, mod, None)
    monkeypatch.setitem(sys.modules, "stcal", None)
    out = tmp_path / "fit.fits"
    with pytest.raises(ImportError, match=r"pip install 'scenesim\[stcal\]'"):
        fit_exposure_stcal(str(tmp_path / "nothing.fits"), str(out))
    assert not out.exists()


# --------------------------------------------------------------------- 1. no noise
@pytest.mark.parametrize("algorithm", STCAL_ALGORITHMS)
def test_noiseless_rate_recovered_within_adc_rounding(tmp_path, algorithm):
    """Zero noise, constant rate (noise-free charge): the slope equals the rate.

    The rate map varies along x and y differently, so a transposed or reshaped cube
    would fail.  Each resultant (one read each) is the rate times its read time
    rounded to the DN: error |eps_i| <= 0.5 DN = 0.5 * gain e-.  A linear unbiased
    slope sum_i c_i R_i errs by at most 0.5 gain sum_i |c_i|.

    * OLS_C: weights |x_i|^P / sigma^2 with x_i = i - (N-1)/2, P >= 0, so
      sum |c_i| = sum |x|^(P+1) / (t_g sum |x|^(P+2)) = E[1/|x|] under weights
      |x|^(P+2); raising P moves weight to larger |x|, so the bound is largest at
      P = 0: sum|x| / (t_g sum x^2) = 25 / (82.5 t_g) for N = 10.
    * LIKELY (GLS on the differences d_i = (R_{i+1} - R_i)/t_g): weights summing to
      1 and positive (parabolic at rate 0, flat in the Poisson limit, positive in
      between: checked for 1e-4 to 1e5 e-/s with this readout), so
      |error| <= 2 * 0.5 gain / t_g.
    Plus float32 rounding of the slope, 1e-6 relative.
    """
    det = _det(64)
    ro = Readout.multiaccum(1, 10, name="RAPID")
    gain = 2.0
    yy, xx = np.mgrid[0:64, 0:64]
    rate = 5.0 + 0.5 * xx + 0.2 * yy                       # e-/s, 5 .. 49
    # stcal divides by the read noise, so the weights need a value > 0 even here
    res = _noiseless_stcal_fit(tmp_path, det, ro, rate, gain, algorithm)
    tg = T_FRAME
    if algorithm == "OLS_C":
        bound = 0.5 * gain * 25.0 / (82.5 * tg)
    else:
        bound = 2 * 0.5 * gain / tg
    reg = ~det.reference_mask()
    err = np.abs(res.slope.astype(float) - rate)[reg]
    assert np.all(err <= bound + 1e-6 * rate[reg]), err.max()
    # Reported variance at a known rate: this pins the gain handed to stcal (its read
    # term in DN does not depend on it, its Poisson term does, as f_DN / gain).
    # stcal's rate estimate inside (a median of the differences for OLS_C, a first
    # GLS fit for LIKELY) errs by at most delta = 2 * 0.5 DN / t_g = gain / t_g e-/s.
    delta = gain / tg
    if algorithm == "OLS_C":
        # stcal's Poisson term is that of the first-to-last rate of the segment,
        # f / ((N - 1) t_g), at its median rate
        v_pois = rate / (9 * tg)
        np.testing.assert_array_less(np.abs(res.var_poisson - v_pois)[reg],
                                     delta / (9 * tg) + 1e-5 * v_pois[reg])
    else:
        # GLS at its rate guess: the total is Brandt's V_opt(f) with sigma = 10 e-
        # (read_noise above); V_opt is monotonic in f, so the guess error delta moves
        # it by at most |V_opt(f +- delta) - V_opt(f)|
        times = ro.read_times(tg)
        v_opt = optimal_variance(rate, times, 10.0)
        tol = np.maximum(optimal_variance(rate + delta, times, 10.0) - v_opt,
                         v_opt - optimal_variance(rate - delta, times, 10.0))
        np.testing.assert_array_less(np.abs(res.var - v_opt)[reg],
                                     tol[reg] + 1e-5 * v_opt[reg])
    assert np.all(res.dq[reg] == 0)
    # reference pixels: no charge, flagged as scenesim does
    assert np.all(res.dq[~reg] & REFERENCE_PIXEL)
    assert np.all(res.dq[~reg] & DO_NOT_USE)


@pytest.mark.parametrize("algorithm", STCAL_ALGORITHMS)
def test_saturation_handled_as_scenesim_does(tmp_path, algorithm):
    """Noise-free ramps with a full well FW = 60000 e-, reads at 10, 20, 30 ... s.

    scenesim's saturation test (shared pre-processing) flags a resultant when it is
    >= 0.97 FW above the zero level extrapolated from the first two resultants:

    * 5 e-/s: never; 9 differences, dof 8, slope 5;
    * 2000 e-/s: 20000, 40000, then 60000 (clipped) -> resultants 2.. flagged: one
      usable difference, the CDS slope (40000 - 20000)/t_g = 2000, dof 0, chi2 0;
    * 3050 e-/s: 30500 then 60000; zero = 2 * 30500 - 60000 = 1000, so resultant 1
      is 59000 >= 58200 above it and flagged: one usable resultant, DO_NOT_USE.

    Slopes within the ADC bound of the noiseless test (gain / t_g for one difference).
    """
    det = _det(32)
    ro = Readout.multiaccum(1, 10, name="RAPID")
    gain = 2.0
    xx = np.mgrid[0:32, 0:32][1]
    rate = np.select([xx < 12, xx < 22], [5.0, 2000.0], 3050.0)
    res = _noiseless_stcal_fit(tmp_path, det, ro, rate, gain, algorithm,
                               full_well=60000.0)
    reg = ~det.reference_mask()
    low, mid, high = (reg & (rate == r) for r in (5.0, 2000.0, 3050.0))
    bound = gain / T_FRAME
    assert np.all(res.dof[low] == 8) and np.all(res.dq[low] == 0)
    assert np.all(np.abs(res.slope[low] - 5.0) <= bound)
    assert np.all(res.dof[mid] == 0) and np.all(res.chi2[mid] == 0)
    assert np.all(res.dq[mid] == SATURATED)
    assert np.all(np.abs(res.slope[mid] - 2000.0) <= bound + 1e-6 * 2000.0)
    assert np.all(res.dq[high] == SATURATED | DO_NOT_USE)
    assert np.all(res.slope[high] == 0) and np.all(res.var_read[high] == BAD_VARIANCE)
    for arr in (res.slope, res.var_read, res.var_poisson, res.chi2, res.slope_ints,
                res.var_ints):
        assert np.all(np.isfinite(arr))


# --------------------------------------------------------------------- 2. white noise
@pytest.mark.parametrize("algorithm, ro, gain", [
    ("OLS_C", Readout.multiaccum(1, 10, name="RAPID"), 2.0),
    ("OLS_C", Readout.multiaccum(4, 6, groupgap=1, nints=2, name="NF4"), 0.5),
    ("LIKELY", Readout.multiaccum(1, 10, name="RAPID"), 2.0),
    ("LIKELY", Readout.from_ma_table(ROMAN_LIKE_TABLE), 0.5),
], ids=["OLS_C-rapid", "OLS_C-nframes4-2ints", "LIKELY-rapid", "LIKELY-uneven"])
def test_white_noise_scatter_and_reported_variance(tmp_path, algorithm, ro, gain):
    """Rate 0, white read noise sigma per read: theory for the slope and its error."""
    det = _det(128)
    nints = ro.nints
    sigma = 10.0
    exp, _ = _white_exposure(tmp_path, det, ro, sigma=sigma, gain=gain)
    # Model noise and no common-mode removal: the scatter test needs independent
    # pixels, and the common mode estimated from a finite number of pixels moves all
    # slopes of an output together (for the uneven table by up to ~0.5 sigma of one
    # pixel's slope on this 128 x 128 array).
    res = fit_exposure_stcal(exp, str(tmp_path / "fit.fits"), algorithm=algorithm,
                             options=PrepareOptions(refpix="none",
                                                    remove_common_mode=False,
                                                    measure_noise=False))
    times = ro.read_times(T_FRAME)
    reg = ~det.reference_mask()
    clean = reg & (res.n_jumps == 0)
    n = int(clean.sum())
    # LIKELY's jump test: false alarms 2 Q(4.5) = 7e-6 per test, ~17 tests per pixel
    # -> ~1e-4 per pixel, ~2 of 14400 expected; 0.1 % (14) is far in the tail
    assert n > 0.999 * reg.sum()
    if algorithm == "OLS_C":
        # stcal's read-noise variance is the equal-weight least-squares one,
        # 12 sigma^2 / (nframes t_g^2 (N^3 - N)) per integration, combined with
        # inverse-variance weights over nints equal integrations: deterministic,
        # so only float32 rounding (1e-6) separates it from the closed form.
        v_read = ols_variance(0.0, times, sigma) / nints
        np.testing.assert_allclose(res.var_read[clean], v_read, rtol=1e-5)
        v_theory = v_read
    else:
        # LIKELY weights are the GLS weights at a rate guess max(fit, 0); where the
        # guess is 0 (about half of the pixels: the noise is symmetric) they are the
        # read-noise-optimal weights, so its read variance is exactly V_opt(0);
        # elsewhere it can only be larger (Gauss-Markov).
        v_read = optimal_variance(0.0, times, sigma)
        ratio = res.var_read[clean] / v_read
        assert ratio.min() == pytest.approx(1.0, abs=1e-5)
        assert np.all(ratio >= 1.0 - 1e-5)
        v_theory = v_read
    # Scatter: n = 120^2 = 14400 regular pixels, sample std relative error
    # 1/sqrt(2 (n - 1)) = 0.0059 -> 5 sigma = 0.030.  Neglected, all far below it:
    # ADC rounding (rapid, gain 2: gain^2/12 = 0.33 e-^2 per resultant against
    # sigma^2 = 100: +0.17 % in std; gain 0.5: < 0.05 %); for LIKELY the rate guess
    # (|f| ~ 1 e-/s) moves the weights off the optimum by a second-order amount,
    # < 0.5 % in std.  A sqrt(2) read-noise error would change the reported
    # variance by 100 %, a gain error by (gain)^(+-2).
    z = res.slope[clean].astype(float) / np.sqrt(v_theory)
    tol = 5.0 / np.sqrt(2.0 * (n - 1))
    assert abs(z.std(ddof=1) - 1.0) < tol, z.std(ddof=1)
    # mean 0: standard error 1/sqrt(n) -> 5 sigma
    assert abs(z.mean()) < 5.0 / np.sqrt(n)


# --------------------------------------------------------------------- 3. files
def test_file_round_trip_and_compare(tmp_path):
    det = _det(64)
    ro = Readout.multiaccum(1, 10, nints=2, name="RAPID")
    rate = 50.0
    exp, truth = _white_exposure(tmp_path, det, ro, sigma=10.0, gain=2.0, rate=rate,
                                 seed=11)
    out = str(tmp_path / "stcal_fit.fits")
    res = fit_exposure_stcal(exp, out)
    back = read_fit(out)
    for name in ("slope", "var_read", "var_poisson", "chi2", "dof", "dq", "slope_ints",
                 "var_ints", "n_jumps"):
        np.testing.assert_array_equal(getattr(back, name), getattr(res, name), name)
    assert back.fitter == res.fitter == "stcal-OLS_C"
    assert back.gain == 2.0 and back.read_noise == 10.0
    with fits.open(out) as hdul:
        hdr = hdul[0].header
        assert hdr["STCALVER"] == stcal.__version__
        assert hdr["RNCONV"] == "per read"
        assert hdr["RNSTCAL"] == pytest.approx(np.sqrt(2.0) * 10.0 / 2.0, rel=1e-12)
        assert hdr["REFPIX"] == "jwst"
    reg = ~det.reference_mask()
    # 2 integrations x 9 usable differences - 1, no saturation, no jump detection
    assert np.all(res.dof[reg] == 17)
    assert np.all(np.isfinite(res.slope)) and np.all(np.isfinite(res.var))

    report = compare_files(out, truth, exposure=exp)
    row = next(r for r in report.rows if r["lo"] <= rate < r["hi"])
    n = int(reg.sum())
    assert row["n"] == row["n_regular"] == n
    assert "fit layout: scenesim" in report.notes
    # Gauss-Markov: no linear unbiased fit beats V_opt; sample std error
    # 1/sqrt(2 (n - 1)) with n = 3600 -> 5 sigma = 0.059
    assert row["std_opt"] > 1.0 - 5.0 / np.sqrt(2.0 * (n - 1))
    # unbiased: mean of r / sqrt(V_opt) has standard error std_opt / sqrt(n)
    assert abs(row["bias_opt"]) < 5.0 * row["std_opt"] / np.sqrt(n)
    # CHI2 (scenesim's model chi-square, 17 dof): mean E = 1 + (V/V_opt - 1)/17 and
    # per-pixel sd sqrt(2/17) -> the bin mean has sd sqrt(2/17/n) = 0.0057.  The
    # 'jwst' reference correction adds ~1.6 % to the per-read variance (the mean of
    # 64 reference pixels per output and column parity); 5 sigma + that margin.
    e_chi2 = 1.0 + (row["std_opt"] ** 2 - 1.0) / 17.0
    assert abs(row["chi2_fit"] - e_chi2) < 5.0 * np.sqrt(2.0 / 17.0 / n) + 0.02


def test_stcal_sees_the_prepared_exposure(tmp_path):
    """By default stcal gets prepare_exposure's cube and measured read-noise map.

    OLS_C's read-noise variance is the equal-weight one, ``ols_variance(0, t, 1)
    sigma^2`` per pixel whatever its weights, so it shows the sigma each pixel was
    handed: it must be the measured per-column map of ``prepare_exposure`` (not
    ``RDNOISE``), through the per-read e- -> CDS DN conversion; float32 only
    (1e-5).  scenesim's own fit of the same exposure reports the same median read
    noise, and the in-memory exposure gives the same result as the file.
    """
    det = _det(64)
    ro = Readout.multiaccum(1, 8, name="RAPID")
    noise = ZERO_NOISE.replace(rd_noise=8.0, bias_offset=2000.0)

    def engine():
        return ChargeEngine(det, ro, rate=0.0, gain=2.0, noise_params=noise, rng=5,
                            ipc_kernel=_IDENTITY_IPC)

    exp = str(tmp_path / "e.fits")
    write_exposure(engine(), exp)
    prep = prepare_exposure(exp)
    assert prep.read_noise.shape == det.shape
    # the jwst correction adds noise, so the map is not the header's 8 e-
    assert not np.allclose(prep.read_noise, 8.0, rtol=1e-3)
    res = fit_exposure_stcal(exp, str(tmp_path / "s.fits"))
    reg = ~det.reference_mask()
    v1 = ols_variance(0.0, ro.read_times(T_FRAME), 1.0)
    np.testing.assert_allclose(res.var_read[reg], v1 * prep.read_noise[reg] ** 2,
                               rtol=1e-5)
    own = fit_exposure_file(exp, str(tmp_path / "g.fits"), jump_threshold=None)
    assert res.read_noise == own.read_noise == float(np.median(prep.read_noise))
    # CHI2 is scenesim's model chi-square of the prepared cube at stcal's slope
    ok = reg & (res.dof > 0)
    np.testing.assert_allclose(
        res.chi2[ok], model_chi2(prep.electrons, prep.read_times, res.slope,
                                 prep.read_noise)[ok], rtol=1e-6)
    with fits.open(tmp_path / "s.fits") as hs, fits.open(tmp_path / "g.fits") as hg:
        for key in ("RNSOURCE", "CMREMOVE", "RNMODEL", "REFPIX", "RNOISE"):
            assert hs[0].header[key] == hg[0].header[key], key
        assert hs[0].header["RNSOURCE"] == "measured"
    mem = write_exposure(engine(), None)["exposure"]
    res_mem = fit_exposure_stcal(mem, str(tmp_path / "m.fits"))
    for name in ("slope", "var_read", "var_poisson", "chi2", "dof", "dq"):
        np.testing.assert_array_equal(getattr(res_mem, name), getattr(res, name), name)


def test_exposure_card_fits_for_a_long_path(tmp_path):
    deep = tmp_path / ("a_rather_long_directory_name_" * 3)
    deep.mkdir()
    det = _det(32)
    exp, _ = _white_exposure(deep, det, Readout.multiaccum(1, 5), sigma=5.0, gain=1.0,
                             name="exposure_" * 4)
    assert len(exp) > 120
    out = str(tmp_path / "fit.fits")
    fit_exposure_stcal(exp, out,
                       options=PrepareOptions(measure_noise=False,
                                              remove_common_mode=False))
    with fits.open(out) as hdul:
        hdr = hdul[0].header
        assert len(hdr.cards["EXPOSURE"].image) == 80
        assert hdr["EXPOSURE"].startswith("...")
        assert hdr["EXPOSURE"].endswith(os.path.basename(exp))


# --------------------------------------------------------------------- 4. bad input
def test_unknown_algorithm_named_before_any_work(tmp_path):
    out = tmp_path / "fit.fits"
    with pytest.raises(ParameterError, match=r"'algorithm'.*OLS_C.*LIKELY.*'OLS_X'"):
        fit_exposure_stcal(str(tmp_path / "missing.fits"), str(out), algorithm="OLS_X")
    with pytest.raises(ParameterError, match="no separate Python 'OLS'"):
        fit_exposure_stcal(str(tmp_path / "missing.fits"), str(out), algorithm="OLS")
    with pytest.raises(ParameterError, match="'refpix'"):
        fit_exposure_stcal(str(tmp_path / "missing.fits"), str(out),
                           options=PrepareOptions(refpix="JWST"))
    with pytest.raises(ParameterError, match="'read_noise'"):
        fit_exposure_stcal(str(tmp_path / "missing.fits"), str(out),
                           options=PrepareOptions(read_noise=0.0))
    assert list(tmp_path.iterdir()) == []


def test_missing_exposure_file(tmp_path):
    missing = str(tmp_path / "missing.fits")
    with pytest.raises(FileFormatError, match="missing.fits.*does not exist"):
        fit_exposure_stcal(missing, str(tmp_path / "fit.fits"))
    assert list(tmp_path.iterdir()) == []


def test_readouts_stcal_cannot_fit(tmp_path):
    det = _det(32)
    uneven, _ = _white_exposure(tmp_path, det, Readout.from_ma_table(ROMAN_LIKE_TABLE),
                                sigma=5.0, gain=1.0, name="uneven")
    short, _ = _white_exposure(tmp_path, det, Readout.multiaccum(1, 3), sigma=5.0,
                               gain=1.0, name="short")
    silent, _ = _white_exposure(tmp_path, det, Readout.multiaccum(1, 5), sigma=0.0,
                                gain=1.0, rate=3.0, name="silent")
    out = tmp_path / "fit.fits"
    with pytest.raises(ParameterError, match="OLS_C.*uneven.*LIKELY"):
        fit_exposure_stcal(uneven, str(out), algorithm="OLS_C")
    with pytest.raises(ParameterError, match="LIKELY.*>= 4 resultants"):
        fit_exposure_stcal(short, str(out), algorithm="LIKELY")
    with pytest.raises(ParameterError, match="RDNOISE.*read_noise > 0"):
        fit_exposure_stcal(silent, str(out))
    assert not out.exists()
