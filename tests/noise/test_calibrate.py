"""Tests of :mod:`noise.calibrate` (noise parameters from darks) and its commands.

The round trip simulates dark ramps with random, known parameter sets
(:class:`noise.NoiseGenerator`), calibrates them and checks the pull distribution
``(estimate - true) / reported sigma`` of every identifiable parameter: mean 0 and
width 1 within 0.2.  With ``N`` independent simulations the standard error of the
pulls' mean is ``1 / sqrt(N)`` and that of their width ``1 / sqrt(2 (N - 1))``; the
numbers of simulations below make the 0.2 bounds >= 3 standard errors of both.
"""

import math
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from noise import NoiseGenerator, NoiseParams, preset, write_noise_fits
from noise.calibrate import (MIN_DIFFERENCES, DarkRamps, _cds_lag_cov, _expected,
                             calibrate_darks, load_darks)
from noise.errors import FileFormatError, ParameterError, ParameterTypeError
from noise.pink import realised_psd, unit_frame_variance

PULL_PARAMETERS = ("rd_noise", "ref_ratio", "c_pink", "u_pink", "acn", "pedestal",
                   "pca0", "ktc", "bias_amp", "bias_offset")


def _random_params(rng):
    """A parameter set whose every component is detected on a 64x64, 4-output array
    with 32 CDS differences (each variance several sigma above 0)."""
    return NoiseParams(
        rd_noise=rng.uniform(3, 8), ref_ratio=rng.uniform(0.6, 1.0),
        c_pink=rng.uniform(1.5, 4.5), u_pink=rng.uniform(1.5, 3), acn=rng.uniform(0.9, 2),
        pca0=rng.uniform(0.3, 1.0), pedestal=rng.uniform(3, 6), ktc=rng.uniform(15, 40),
        bias_offset=rng.uniform(1000, 10000), bias_amp=rng.uniform(100, 800))


def _pulls(det, n_sim, nreads, nints, seed):
    pulls = {k: [] for k in PULL_PARAMETERS}
    for child in np.random.SeedSequence(seed).spawn(n_sim):
        rng = np.random.default_rng(child)
        p = _random_params(rng)
        cube = NoiseGenerator(det, p, rng=rng.integers(2 ** 63), threads=1).cube(
            nreads, nints=nints)
        res = calibrate_darks(DarkRamps(tuple(cube), det))
        for k in PULL_PARAMETERS:
            est = res.estimates[k]
            assert est.value is not None and est.sigma is not None and est.upper is None, \
                (k, est)                      # detected: no selection of the pulls
            pulls[k].append((est.value - getattr(p, k)) / est.sigma)
    return {k: np.array(v) for k, v in pulls.items()}


#: Bounds on the mean pull and on |width - 1|: 0.2 everywhere but for the pedestal.
#: Its variance is measured once per CDS difference (one offset per frame), so with
#: ``J`` differences its uncertainty, taken from the scatter of those ``J`` values,
#: is correlated with its error and the pulls are skewed: for ``J`` samples of a
#: chi^2_1 variable the t-statistic has mean -0.29 and width 1.25 at J = 32 (-0.19
#: and 1.13 at 64; numpy, 2e5 trials).  0.35 is that offset plus 1.5 SE of 225
#: pulls (docs/NOISE_CALIBRATION.md).
MEAN_BOUND = {"pedestal": 0.35}
WIDTH_BOUND = {"pedestal": 0.35}


def _check_pulls(pulls, n_sim):
    se_mean, se_width = 1 / math.sqrt(n_sim), 1 / math.sqrt(2 * (n_sim - 1))
    assert 0.2 >= 3 * se_mean and 0.2 >= 3 * se_width      # the bounds are >= 3 SE
    bad = {k: (round(float(v.mean()), 3), round(float(v.std(ddof=1)), 3))
           for k, v in pulls.items()
           if abs(v.mean()) > MEAN_BOUND.get(k, 0.2)
           or abs(v.std(ddof=1) - 1) > WIDTH_BOUND.get(k, 0.2)}
    assert not bad, f"pull (mean, width) outside the bounds: {bad}"


def test_round_trip_pulls_small_array():
    # 225 simulations: the 0.2 bounds are 3.0 SE of the mean, 4.2 SE of the width
    det = preset("H2RG", naxis1=64, naxis2=64)
    n_sim = 225
    _check_pulls(_pulls(det, n_sim, nreads=16, nints=4, seed=20261125), n_sim)


# ------------------------------------------------------------ the model, from theory
def test_cds_lag_covariance_matches_direct_integral():
    # C_y(tau) = int S_1(f) 4 sin^2(pi f L / rate) cos(2 pi f tau / rate) df, computed
    # here on a dense logarithmic grid (independent of the module's FFT grid); the
    # 1/f integrand is smooth on a log grid below 1/T, oscillating above: 2e6 points
    rate, L, f_min = 1e5, 1000, 1e-4
    c = _cds_lag_cov(rate, L, L, f_min, None)
    f = np.geomspace(f_min * 1e-3, rate / 2, 2_000_000)
    s = realised_psd(f, rate, f_min) / unit_frame_variance(rate, L, f_min)
    s *= 4 * np.sin(np.pi * f * L / rate) ** 2
    for tau in (0, 1, 7, 100, 999):
        direct = np.trapezoid(s * np.cos(2 * np.pi * f * tau / rate), f)
        # the two quadratures agree to 2e-3 of C_y(0) (the log grid's resolution of
        # the oscillating part at high frequency)
        assert abs(c[tau] - direct) < 2e-3 * c[0], (tau, c[tau], direct)


def test_expected_periodogram_matches_brute_force():
    # E[F_a F_b^*] = sum_{t, t'} w_a(t) w_b(t') C(t - t') e^{-2 pi i k (t - t') / L}:
    # evaluated by the explicit double sum on a small gappy mask
    rng = np.random.default_rng(3)
    L = 48
    cov = np.exp(-np.arange(L) / 5.0) + (np.arange(L) == 0)
    wa = (rng.random(L) < 0.7).astype(float)
    wb = (rng.random(L) < 0.6).astype(float)
    t = np.arange(L)
    C = cov[np.abs(t[:, None] - t[None, :])]
    for k in range(L // 2 + 1):
        e = np.exp(-2j * np.pi * k * t / L)
        brute = (wa * e) @ C @ np.conj(wb * e)
        assert np.isclose(_expected(cov, wa, wb)[k], brute.real, rtol=1e-10, atol=1e-10)


# ------------------------------------------------- null limits and identifiability
def test_absent_components_give_bounds_not_detections():
    # acn = pca0 = pedestal = 0: each variance is consistent with 0 (|theta| < 4 sigma,
    # a 6e-5 two-sided chance for a Gaussian estimate) and reported with a bound
    det = preset("H2RG", naxis1=64, naxis2=64)
    p = NoiseParams(acn=0.0, pca0=0.0, pedestal=0.0)
    cube = NoiseGenerator(det, p, rng=11, threads=1).cube(16, nints=4)
    res = calibrate_darks(DarkRamps(tuple(cube), det))
    for i, name in ((4, "acn"), (5, "pedestal"), (6, "pca0")):
        z = res.theta[i] / math.sqrt(res.theta_cov[i, i])
        assert abs(z) < 4, (name, z)
        if res.theta[i] < 2 * math.sqrt(res.theta_cov[i, i]):
            assert res.estimates[name].upper is not None


def test_one_integration_ktc_is_a_bound():
    det = preset("H2RG", naxis1=64, naxis2=64)
    p = NoiseParams()
    cube = NoiseGenerator(det, p, rng=5, threads=1).cube(16, nints=1)
    res = calibrate_darks(DarkRamps(tuple(cube), det))
    est = res.estimates["ktc"]
    assert est.value is None and "not identifiable" in est.note
    # the bound is the rms of kTC and bias pattern together: at least the kTC
    assert est.upper >= p.ktc
    assert "# ktc: not fitted" in res.to_toml()


def test_one_output_pink_is_the_total_and_no_refs_no_ratio():
    # a window through one output, away from the border: no reference pixels, and
    # c_pink and u_pink reach the same pixels (only their hypot is seen)
    det = preset("H2RG").window(512, 512, 64, 64)
    p = NoiseParams(c_pink=3.0, u_pink=2.0, pca0=0.0)
    cube = NoiseGenerator(det, p, rng=9, threads=1).cube(16, nints=4)
    res = calibrate_darks(DarkRamps(tuple(cube), det))
    assert res.estimates["u_pink"].value is None
    assert res.estimates["ref_ratio"].value is None
    c = res.estimates["c_pink"]
    # within 4 sigma of hypot(3, 2) (a 6e-5 chance for a calibrated estimate)
    assert abs(c.value - math.hypot(3.0, 2.0)) < 4 * c.sigma


def test_too_few_differences_and_bad_types_are_refused():
    det = preset("H2RG", naxis1=64, naxis2=64)
    cube = np.zeros((2 * MIN_DIFFERENCES - 1, 64, 64), np.float32)   # one pair short
    with pytest.raises(ParameterError, match="CDS differences"):
        calibrate_darks(DarkRamps((cube,), det))
    with pytest.raises(ParameterTypeError, match="'ramps'"):
        calibrate_darks(cube)
    with pytest.raises(ParameterError, match="shape"):
        calibrate_darks(DarkRamps((np.zeros((8, 32, 64), np.float32),), det))


# --------------------------------------------------------- files and the commands
def _write_dark(path, det, params, *, seed, nreads=16, nints=2, unit="e", gain=1.0):
    gen = NoiseGenerator(det, params, rng=seed, threads=1)
    write_noise_fits(str(path), gen, nreads, nints=nints, unit=unit, gain=gain)
    return path


def test_dn_file_round_trip_uses_the_gain(tmp_path):
    # the same ramp in e- and in DN (gain 2): the DN fit removes the ADC rounding
    # (gain^2 / 12 per read) and agrees with the e- fit within the rounding's noise
    det = preset("H2RG", naxis1=64, naxis2=64)
    p = NoiseParams(pca0=0.0)
    fe = _write_dark(tmp_path / "e.fits", det, p, seed=4)
    fd = _write_dark(tmp_path / "dn.fits", det, p, seed=4, unit="DN", gain=2.0)
    re_ = calibrate_darks(load_darks([fe]))
    rd_ = calibrate_darks(load_darks([fd]))
    a, b = re_.estimates["rd_noise"], rd_.estimates["rd_noise"]
    assert load_darks([fd]).gain == 2.0
    # the rounding adds an independent uniform error of variance 1/3 e-^2 per read:
    # the two fits differ by much less than their sigma
    assert abs(a.value - b.value) < a.sigma


def test_a_gain_for_darks_in_electrons_is_refused(tmp_path):
    # it would change nothing (before: silently ignored)
    det = preset("H2RG", naxis1=64, naxis2=64)
    dark = _write_dark(tmp_path / "e.fits", det, NoiseParams(), seed=2, nints=1)
    with pytest.raises(ParameterError, match=r"'gain' 2\.0 e-/DN applies to dark "
                                             r"ramps in DN.*in electrons"):
        load_darks([dark], gain=2.0)
    dn = _write_dark(tmp_path / "dn.fits", det, NoiseParams(), seed=3, nints=1,
                     unit="DN", gain=2.0)
    assert load_darks([dn], gain=2.0).gain == 2.0


def test_one_dark_named_twice_is_refused(tmp_path, monkeypatch):
    # under another spelling or through a link it would count as a second dark and
    # shrink every uncertainty by sqrt(2)
    det = preset("H2RG", naxis1=64, naxis2=64)
    dark = _write_dark(tmp_path / "dark.fits", det, NoiseParams(), seed=2, nints=1)
    os.link(dark, tmp_path / "hard.fits")
    os.symlink(dark, tmp_path / "soft.fits")
    monkeypatch.chdir(tmp_path)
    for other in ("./dark.fits", str(dark), "hard.fits", "soft.fits", "../"
                  + tmp_path.name + "/dark.fits"):
        with pytest.raises(ParameterError, match="same file"):
            load_darks(["dark.fits", other])
    _write_dark(tmp_path / "other.fits", det, NoiseParams(), seed=3, nints=1)
    assert len(load_darks(["dark.fits", "other.fits"]).integrations) == 2


def test_cli_calibrate_writes_a_scene_ready_table(tmp_path):
    from scenesim.cli import main
    from scenesim.scene import load_scene
    det = preset("H2RG", naxis1=64, naxis2=64)
    dark = _write_dark(tmp_path / "dark.fits", det, NoiseParams(), seed=2)
    out = tmp_path / "noise.toml"
    assert main(["noise", "calibrate", str(dark), "-o", str(out), "-q"]) == 0
    # refuses to replace it without --overwrite, and replaces it with
    assert main(["calibrate", str(dark), "-o", str(out), "-q"]) == 2
    assert main(["calibrate", str(dark), "-o", str(out), "-q", "--overwrite"]) == 0
    scene = tmp_path / "scene.toml"
    scene.write_text(textwrap.dedent("""\
        seed = 1
        [detector]
        preset = "H2RG"
        naxis1 = 64
        naxis2 = 64
        [readout]
        pattern = "RAPID"
        ngroups = 4
        """) + out.read_text())
    loaded = load_scene(str(scene)).noise
    res = calibrate_darks(load_darks([dark]))
    for name in ("rd_noise", "c_pink", "u_pink", "acn", "pedestal", "pca0", "ktc",
                 "bias_amp", "bias_offset", "ref_ratio"):
        assert math.isclose(getattr(loaded, name), getattr(res.params, name),
                            rel_tol=1e-5), name
    assert loaded.rtn_fraction == 0.0


def test_cli_psd_plot(tmp_path):
    pytest.importorskip("matplotlib")
    det = preset("H2RG", naxis1=64, naxis2=64)
    a = _write_dark(tmp_path / "a.fits", det, NoiseParams(), seed=1)
    b = _write_dark(tmp_path / "b.fits", det, NoiseParams(c_pink=6.0), seed=2)
    png = tmp_path / "psd.png"
    env = dict(os.environ, MPLBACKEND="Agg")
    run = subprocess.run([sys.executable, "-m", "scenesim.cli", "psd", str(a), str(b),
                          "--plot", str(png)], capture_output=True, text=True, env=env)
    assert run.returncode == 0, run.stderr
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    again = subprocess.run([sys.executable, "-m", "scenesim.cli", "psd", str(a),
                            "--plot", str(png)], capture_output=True, text=True, env=env)
    assert again.returncode == 2 and "exists" in again.stderr


def _print_pull_table(n_sim, size, nreads, nints, seed):
    """Print the pull table of ``n_sim`` round trips (docs/NOISE_CALIBRATION.md)."""
    import time
    det = preset("H2RG", naxis1=size, naxis2=size)
    t0 = time.perf_counter()
    pulls = _pulls(det, n_sim, nreads, nints, seed)
    print(f"{n_sim} simulations, {size}x{size}, 4 outputs, {nints} x {nreads} reads "
          f"({nints * (nreads // 2)} CDS differences), seed {seed}: "
          f"{time.perf_counter() - t0:.0f} s")
    print("| parameter | mean pull | width |\n|---|---|---|")
    for k, v in pulls.items():
        print(f"| `{k}` | {v.mean():+.3f} | {v.std(ddof=1):.3f} |")


def _full_size_round_trip(n_sim, nreads, nints, png=None):
    """Full-size H2RG round trips: simulation 0 with the paper's defaults, the others
    with random sets (:func:`_random_params`), seeds spawned from 2048; one JSON line
    per simulation (true, value, sigma, upper bound of each parameter) and the PSD
    figure of simulation 0."""
    import json
    import time
    det = preset("H2RG")
    for i, child in enumerate(np.random.SeedSequence(2048).spawn(n_sim)):
        rng = np.random.default_rng(child)
        p = NoiseParams() if i == 0 else _random_params(rng)
        t0 = time.perf_counter()
        cube = NoiseGenerator(det, p, rng=rng.integers(2 ** 63), threads=2).cube(
            nreads, nints=nints)
        t1 = time.perf_counter()
        res = calibrate_darks(DarkRamps(tuple(cube), det))
        row = {"sim": i, "gen_s": round(t1 - t0, 1),
               "cal_s": round(time.perf_counter() - t1, 1)}
        for k in PULL_PARAMETERS:
            e = res.estimates[k]
            row[k] = (getattr(p, k), e.value, e.sigma, e.upper)
        print(json.dumps(row), flush=True)
        if i == 0 and png:
            from scenesim.calib.calibrate_command import plot_psd
            plot_psd(png, [res], ["H2RG NIRSpec defaults, seed sim 0"])
        del cube


if __name__ == "__main__":
    # python tests/noise/test_calibrate.py N SIZE NREADS NINTS SEED     (pull table)
    # python tests/noise/test_calibrate.py full N NREADS NINTS [PNG]    (full size)
    if sys.argv[1] == "full":
        _full_size_round_trip(*(int(a) for a in sys.argv[2:5]),
                              *(sys.argv[5:6] or [None]))
    else:
        _print_pull_table(*(int(a) for a in sys.argv[1:6]))


def test_cli_template_file_is_written_and_loads(tmp_path):
    # a user template: the bias pattern is regressed on it and the table names it,
    # as an absolute path a scene anywhere can resolve
    from astropy.io import fits
    from scenesim.cli import main
    from scenesim.scene import load_scene
    det = preset("H2RG", naxis1=64, naxis2=64)
    yy, xx = np.mgrid[0:64, 0:64]
    tmpl = tmp_path / "tmpl.fits"
    fits.PrimaryHDU(np.sin(xx / 5.0) + np.cos(yy / 7.0)).writeto(tmpl)
    p = NoiseParams(pca0=0.0, bias_amp=300.0, pca0_file=str(tmpl))
    dark = _write_dark(tmp_path / "dark.fits", det, p, seed=6)
    out = tmp_path / "noise.toml"
    assert main(["calibrate", str(dark), "-o", str(out), "-q", "--template",
                 str(tmpl)]) == 0
    (tmp_path / "sub").mkdir()
    scene = tmp_path / "sub" / "scene.toml"
    scene.write_text('seed = 1\n[detector]\npreset = "H2RG"\nnaxis1 = 64\nnaxis2 = 64\n'
                     '[readout]\npattern = "RAPID"\nngroups = 4\n' + out.read_text())
    loaded = load_scene(str(scene)).noise
    assert os.path.samefile(loaded.pca0_file, tmpl)
    res = calibrate_darks(load_darks([dark]), template_file=str(tmpl))
    b = res.estimates["bias_amp"]
    # within 4 sigma of the true 300 e- (a 6e-5 chance for a calibrated estimate)
    assert abs(b.value - 300.0) < 4 * b.sigma


def test_sci_extension_files_need_preset_gain_and_single_frames(tmp_path):
    # a JWST-uncal-like file: uint16 DN in a SCI extension, no scenesim detector
    # cards, no GAIN: refused until the detector and the gain are given; frame
    # averaging (NFRAMES > 1) is refused outright
    from astropy.io import fits
    det = preset("H2RG", naxis1=64, naxis2=64)
    cube = NoiseGenerator(det, NoiseParams(), rng=8, threads=1).cube(10, nints=2)
    dn = np.clip(np.round(cube / 2.0), 0, 65535).astype(np.uint16)

    def write(name, nframes):
        hdr = fits.Header()
        hdr["NFRAMES"] = nframes
        hdr["GROUPGAP"] = 0
        sci = fits.ImageHDU(dn, name="SCI")
        sci.header["BUNIT"] = "DN"
        path = tmp_path / name
        fits.HDUList([fits.PrimaryHDU(header=hdr), sci]).writeto(path)
        return str(path)

    ok, averaged = write("uncal.fits", 1), write("avg.fits", 4)
    with pytest.raises(ParameterError, match="detector"):
        load_darks([ok])
    with pytest.raises(ParameterError, match="gain"):
        load_darks([ok], detector=det)
    with pytest.raises(FileFormatError, match="NFRAMES"):
        load_darks([averaged], detector=det, gain=2.0)
    ramps = load_darks([ok], detector=det, gain=2.0)
    assert len(ramps.integrations) == 2 and ramps.gain == 2.0
    # the e- values are the DN times the gain
    assert np.array_equal(ramps.integrations[1][3], dn[1, 3].astype(np.float32) * 2)


def test_non_finite_or_noiseless_darks_are_refused_naming_them(tmp_path):
    """Before: NaN in a dark ended in "'rd_noise' must be finite" (a fitted value, not
    an input), inf added numpy warnings, and an all-zero dark was 'calibrated' to a
    table of zeros with NaN bounds."""
    from astropy.io import fits
    det = preset("H2RG", naxis1=64, naxis2=64)
    dark = _write_dark(tmp_path / "d.fits", det, NoiseParams(), seed=5, nints=2)
    with fits.open(dark) as hdul:
        data, hdr = hdul[0].data.copy(), hdul[0].header.copy()
    for value in (np.nan, np.inf):
        bad = data.copy()
        bad[1, 3, 10, 12] = value
        fits.writeto(tmp_path / "bad.fits", bad, hdr, overwrite=True)
        with pytest.raises(FileFormatError, match=r"dark ramp .*bad\.fits.*integration "
                           r"1 has 1 NaN or inf samples \(the first at read 3, row 10, "
                           r"column 12\)"):
            load_darks([tmp_path / "bad.fits"])
        with pytest.raises(ParameterError, match="integration 0 has 1 NaN or inf"):
            calibrate_darks(DarkRamps((bad[1],), det))
    fits.writeto(tmp_path / "zero.fits", np.zeros_like(data), hdr)
    with pytest.raises(ParameterError, match=r"the darks \(.*zero\.fits\) have no noise"):
        calibrate_darks(load_darks([tmp_path / "zero.fits"]))
    flat = np.broadcast_to(data[0, :1], data[0].shape)       # a bias, never changing
    with pytest.raises(ParameterError, match="have no noise"):
        calibrate_darks(DarkRamps((flat,), det))


def test_cli_psd_prints_a_table_for_every_file(tmp_path, capsys):
    # before: only the first file's table, the others dropped without a word
    from scenesim.cli import main
    det = preset("H2RG", naxis1=64, naxis2=64)
    a = _write_dark(tmp_path / "a.fits", det, NoiseParams(), seed=1)
    b = _write_dark(tmp_path / "b.fits", det, NoiseParams(c_pink=6.0), seed=2)
    assert main(["psd", str(a), str(b)]) == 0
    out = capsys.readouterr().out
    heads = [line for line in out.splitlines() if line.startswith("#")]
    assert len(heads) == 2 and heads[0].endswith("a.fits)") and \
        heads[1].endswith("b.fits)")
    # the tables differ: b has more correlated 1/f
    tables = out.split("\n\n")
    assert len(tables) == 2 and tables[0].split("\n")[1:] != tables[1].split("\n")[1:]


def test_a_recorded_gain_or_detector_wins_over_the_options(tmp_path):
    # a probe's --gain 1.0 on a 2 e-/DN dark halved rd_noise, and --n-out 8 on a
    # 4-output dark moved c_pink by -5 sigma, without a word: both are refused now
    det = preset("H2RG", naxis1=64, naxis2=64)
    dn = _write_dark(tmp_path / "dn.fits", det, NoiseParams(), seed=3, nints=1,
                     unit="DN", gain=2.0)
    with pytest.raises(ParameterError, match=r"records GAIN = 2\.0 e-/DN; 'gain' 1\.0 "
                                             r"contradicts it"):
        load_darks([dn], gain=1.0)
    other = preset("H2RG", naxis1=64, naxis2=64, n_out=8)
    with pytest.raises(ParameterError, match=r"records its detector.*4 outputs.*"
                                             r"8 outputs.*leave the detector options"):
        load_darks([dn], detector=other)
    assert load_darks([dn], detector=det).detector == det     # the same: accepted
    # darks of two gains: refused, without pointing at --gain
    dn1 = _write_dark(tmp_path / "dn1.fits", det, NoiseParams(), seed=4, nints=1,
                      unit="DN", gain=1.0)
    with pytest.raises(ParameterError, match="one gain together") as err:
        load_darks([dn, dn1])
    assert "--gain" not in str(err.value)


def _full_model_dark(naxis, *, seed):
    """``(detector, params, cube, regular flat indices)``: darks (4 integrations of
    16 reads) of an H2RG of ``naxis``^2 with every fitted component on."""
    det = preset("H2RG", naxis1=naxis, naxis2=naxis)
    p = NoiseParams(rd_noise=7.0, ref_ratio=0.7, c_pink=2.0, u_pink=1.5, acn=1.0,
                    pca0=0.5, pedestal=3.0, ktc=25.0, bias_offset=4000.0,
                    bias_amp=300.0)
    cube = NoiseGenerator(det, p, rng=seed, threads=1).cube(16, nints=4)
    return det, p, cube, np.flatnonzero(~det.reference_mask())


def test_cosmic_rays_in_darks_are_found_and_left_out():
    # 1 % of the pixels of every integration take a hit (lognormal, median 1000 e-)
    # between two random reads: left in, a probe's rd_noise came out +5.5 sigma and
    # kTC +3.9 sigma.  Found (> 6 robust sigma of the read step) and left out, every
    # fitted parameter is within 5 of its sigmas of the truth.
    det, p, cube, regular = _full_model_dark(64, seed=18)
    rng = np.random.default_rng(17)
    n_hits = 0
    for k in range(cube.shape[0]):
        hit = rng.choice(regular, size=regular.size // 100, replace=False)
        read = rng.integers(1, cube.shape[1], size=hit.size)
        charge = rng.lognormal(np.log(1000.0), 0.7, size=hit.size)
        for pix, r, q in zip(hit, read, charge):
            y, x = divmod(int(pix), det.nx)
            cube[k, r:, y, x] += q
        n_hits += hit.size
    res = calibrate_darks(DarkRamps(tuple(cube), det))
    for name in ("rd_noise", "ref_ratio", "c_pink", "u_pink", "ktc", "bias_amp"):
        est = res.estimates[name]
        assert abs(est.value - getattr(p, name)) < 5 * est.sigma, (name, est)
    note = [n for n in res.notes if "jumped" in n]
    assert note and note[0].startswith(f"{n_hits} read steps"), res.notes


def test_hot_pixels_below_the_step_threshold_are_found_by_their_sum():
    # 1 % of the pixels are hot, 20-900 e-/s (log-uniform): 4-180 e- per 0.195 s
    # frame, most steps below 6 robust sigma of a read step (~60 e- here), so the
    # step test alone left them in: rd_noise +15 sigma, ref_ratio -5.  The sum of a
    # pixel's steps over the integrations grows with the reads where its noise does
    # not: found there, every CDS difference of theirs takes the row's median and
    # the white-noise basis keeps the share of samples that were not replaced (left
    # out, 1 % of the white variance missing had put rd_noise at -2.3 sigma).
    # Tolerance: 5 of each estimate's own sigmas.
    det, p, cube, regular = _full_model_dark(256, seed=101)
    rng = np.random.default_rng(1)
    hot = rng.choice(regular, size=regular.size // 100, replace=False)
    rate = np.exp(rng.uniform(np.log(20.0), np.log(900.0), size=hot.size))
    y, x = np.divmod(hot, det.nx)
    for k in range(cube.shape[0]):
        steps = rng.poisson(rate * det.frame_time, size=(cube.shape[1], hot.size))
        cube[k][:, y, x] += np.cumsum(steps, axis=0)
    res = calibrate_darks(DarkRamps(tuple(cube), det))
    for name in ("rd_noise", "ref_ratio", "c_pink", "u_pink", "acn", "ktc", "bias_amp"):
        est = res.estimates[name]
        assert abs(est.value - getattr(p, name)) < 5 * est.sigma, (name, est)
    assert any("collected more charge" in n for n in res.notes), res.notes
    # every hot pixel found, by its steps or by their sum (the faintest sum 4 e- x
    # 15 steps x 4 integrations = 240 e- against a sum's noise of ~2 sqrt(2) x 7 =
    # 20 e-), and no other pixel taken by the sum
    from noise.calibrate import _find_jumps
    _, stepped, _, found, _ = _find_jumps(DarkRamps(tuple(cube), det))
    injected = np.zeros(det.shape, bool)
    injected.flat[hot] = True
    assert np.all((stepped | found)[injected]) and not found[~injected].any()


@pytest.mark.parametrize("params", [
    NoiseParams(rd_noise=3.0, pca0=2.0),                # a picture frame strong at
    NoiseParams(rd_noise=(5.0, 5.0, 5.0, 15.0)),        # the edges; one noisy output
    NoiseParams()])
def test_the_hot_pixel_sum_flags_no_clean_pixel_and_no_cosmic_ray(params):
    # A regression probe of the hot-pixel sum: clean darks had 2-22 "hot" pixels
    # per 64^2 set (reference pixels under a strong picture frame, the pixels of an
    # output with 3x the read noise: one spread for the whole array), and a pixel
    # hit by a cosmic ray in one integration was "hot" (every difference of it
    # replaced: c_pink pulls -1 over 60 sets).  Now: regular pixels only, each
    # output against its own spread, the flagged steps left out of the sum.  A 6
    # sigma Gaussian test expects 4096 x 1e-9 false flags per set: none in 5.  The
    # step test, by kind (regular, reference) and output: at most one false step
    # per set of 4096 x 60 (expected 2e-4) without a picture frame.
    from noise.calibrate import _find_jumps
    det = preset("H2RG", naxis1=64, naxis2=64)
    for seed in range(5):
        cube = NoiseGenerator(det, params, rng=seed, threads=1).cube(16, nints=4)
        _, stepped, n0, hot, _ = _find_jumps(DarkRamps(tuple(cube), det))
        assert not hot.any(), seed
        if params.pca0 == 0:            # a strong picture frame still flags steps of
            assert n0 <= 1, (seed, n0)  # reference pixels (docs/NOISE_CALIBRATION.md)
    # a 3000 e- hit in one integration: one more jump, not a hot pixel
    cube[2, 9:, 30, 30] += 3000.0
    jumps, stepped, n, hot, _ = _find_jumps(DarkRamps(tuple(cube), det))
    assert stepped[30, 30] and not hot.any() and n == n0 + 1


def test_detector_options_that_match_a_file_are_accepted(tmp_path):
    # the same clock under another name (an uncal's DETECTOR is the JWST one) or
    # pixel pitch is the same detector: a probe found it refused
    import dataclasses
    det = preset("H2RG", naxis1=64, naxis2=64)
    dn = _write_dark(tmp_path / "dn.fits", det, NoiseParams(), seed=3, nints=1,
                     unit="DN", gain=2.0)
    alias = dataclasses.replace(det, name="NRCA1", pixel_pitch=10.0)
    assert load_darks([dn], detector=alias).detector == det


def test_acn_does_not_leak_into_ktc():
    # ACN's even and odd series have their own slow offsets, which a row's mean
    # alone left in the integration means: kTC pulls +0.8 at acn 2 e-, +6.7 at 6 e-
    # (a probe, 12 seeds).  Demeaned by row, output and column parity: over 12
    # seeds the mean pull is within 5 standard errors (5 / sqrt(12) = 1.44) of 0.
    det = preset("H2RG", naxis1=128, naxis2=128)
    pulls = []
    for s in range(12):
        p = NoiseParams(rd_noise=3.0, c_pink=0.0, u_pink=0.0, acn=6.0, pca0=0.0,
                        pedestal=0.0, ktc=10.0, bias_offset=1000.0, bias_amp=100.0)
        cube = NoiseGenerator(det, p, rng=1000 + s, threads=1).cube(8, nints=4)
        e = calibrate_darks(DarkRamps(tuple(cube), det)).estimates["ktc"]
        pulls.append((e.value - 10.0) / e.sigma)
    assert abs(np.mean(pulls)) < 5 / np.sqrt(12), pulls


def test_files_the_statistics_do_not_describe_are_refused_or_turned(tmp_path):
    # three probes' cases: (1) a read list of averaged resultants passed the
    # NFRAMES/GROUPGAP check (its cards describe its first resultant only) and was
    # fitted as single reads; (2) a JWST file in the DMS frame (FASTAXIS = 2) was
    # fitted along the wrong axis; (3) an e- dark and a DN dark together had the
    # ADC rounding removed from both (rd_noise -5 sigma)
    from astropy.io import fits
    from scenesim.run import run_scene
    from scenesim.scene import parse_scene
    res = [[0], [1]] + [[4 * k + 2 + i for i in range(4)] for k in range(3)]
    scene = parse_scene({"seed": 7, "detector": {"preset": "H2RG", "naxis1": 64,
                                                 "naxis2": 64},
                         "readout": {"resultants": res},
                         "output": {"path": str(tmp_path / "avg.fits"), "fit": ""}})
    run_scene(scene, progress=False)
    with pytest.raises(FileFormatError, match="resultant 2 averages 4 reads"):
        load_darks([str(tmp_path / "avg.fits")])
    # (2) the same dark in the DMS frame (transposed, FASTAXIS = 2) fits as itself
    det = preset("H2RG", naxis1=64, naxis2=64)
    path = _write_dark(tmp_path / "d.fits", det, NoiseParams(), seed=5)
    with fits.open(path) as h:
        data = np.ascontiguousarray(np.swapaxes(h[0].data, -1, -2))
        hdr = h[0].header.copy()
    hdr["FASTAXIS"], hdr["SLOWAXIS"] = 2, 1
    fits.writeto(tmp_path / "dms.fits", data, hdr)
    a, b = (load_darks([str(p)]) for p in (path, tmp_path / "dms.fits"))
    for x, y in zip(a.integrations, b.integrations):
        np.testing.assert_array_equal(x, y)
    hdr["FASTAXIS"], hdr["SLOWAXIS"] = 2, -1
    fits.writeto(tmp_path / "odd.fits", data, hdr)
    with pytest.raises(FileFormatError, match="FASTAXIS = 2, SLOWAXIS = -1"):
        load_darks([str(tmp_path / "odd.fits")])
    # (3) units mixed
    dn = _write_dark(tmp_path / "dn.fits", det, NoiseParams(), seed=6, unit="DN",
                     gain=6.0)
    with pytest.raises(ParameterError, match="in DN and .* in electrons: calibrate "
                                             "darks of one unit together"):
        load_darks([path, dn])


def test_a_window_without_a_pattern_within_rows_says_what_bias_offset_is():
    # a window away from the array's left and right edges: the synthetic template is
    # constant along each row, bias_amp is not identifiable, and bias_offset is the
    # mean reset level (it had read 5320 for 5000 with bias_amp 500, without a word)
    from noise.template import template_for
    det = preset("H2RG", naxis1=256, naxis2=256).window(100, 2, 64, 64)
    p = NoiseParams(bias_amp=500.0, bias_offset=5000.0)
    cube = NoiseGenerator(det, p, rng=3, threads=1).cube(16, nints=4)
    r = calibrate_darks(DarkRamps(tuple(cube), det))
    assert r.estimates["bias_amp"].value is None
    off = r.estimates["bias_offset"]
    tmean = float(template_for(det)[~det.reference_mask()].mean())
    assert "bias_offset + bias_amp x" in off.note and "not identifiable" in off.note
    # it is that combination, within 5 of its sigmas
    assert abs(off.value - (5000.0 + 500.0 * tmean)) < 5 * off.sigma


def test_a_window_of_a_full_size_array_does_not_regress_on_rounding():
    # A 64^2 window at (1000, 1000) of a full-size H2RG (and of an H4RG-10): the
    # template is constant along its rows but for float32 steps (~1e-5), and the
    # regression on them gave bias_amp 25331 +- 24263 and bias_offset 17451 +- 3
    # for 500 and 5000 (H4RG-10: -73765, written as 0, and bias_offset -32980 for a
    # mean level of 4749; a probe).  Now: not identifiable, and bias_offset is the
    # mean reset level 5000 + 500 x mean(template), within 5 of its sigmas.
    from noise.template import template_for
    p = NoiseParams(bias_amp=500.0, bias_offset=5000.0)
    for det in (preset("H2RG").window(1000, 1000, 64, 64),
                preset("H4RG-10").window(2000, 2000, 64, 64)):
        cube = NoiseGenerator(det, p, rng=3, threads=1).cube(16, nints=4)
        r = calibrate_darks(DarkRamps(tuple(cube), det))
        assert r.estimates["bias_amp"].value is None
        off = r.estimates["bias_offset"]
        tmean = float(template_for(det)[~det.reference_mask()].mean())
        assert abs(off.value - (5000.0 + 500.0 * tmean)) < 5 * off.sigma, off
        assert r.params.bias_amp == 0.0 and r.params.bias_offset == off.value


def test_stuck_pixels_are_left_out_and_said():
    # 2 % of the pixels at the ADC's top code (65535 DN x 1.7 e-/DN) in every read:
    # taken as they were, bias_offset read 8133 +- 3 for 6000 and ref_ratio +3 %
    # (a probe).  Left out like hot pixels, and named in a note; every estimate
    # within 5 of its own sigmas of the truth.
    det = preset("H2RG", naxis1=128, naxis2=128)
    p = NoiseParams(bias_offset=6000.0, bias_amp=400.0)
    cube = NoiseGenerator(det, p, rng=4, threads=1).cube(20, nints=3)
    stuck = np.random.default_rng(1).random(det.shape) < 0.02
    cube[:, :, stuck] = 65535 * 1.7
    r = calibrate_darks(DarkRamps(tuple(cube), det))
    for name in ("rd_noise", "ref_ratio", "bias_amp", "bias_offset"):
        est = r.estimates[name]
        assert abs(est.value - getattr(p, name)) < 5 * est.sigma, (name, est)
    assert any(n.startswith(f"{int(stuck.sum())} pixels never changed value")
               for n in r.notes), r.notes


def test_bias_offset_sigma_covers_white_noise_darks():
    # White read noise only (5.2 e-, kTC 0): the mean level's sigma left out the
    # white noise, rd / sqrt(pixels x reads) = 0.012 e- here, and was 0 for some
    # seeds (a probe: pull width 2.25 over 40 seeds).  Now at least that floor (at
    # the estimated rd_noise);
    # over 12 seeds the pulls (value - 0) / sigma have an rms below 1.6 (12 unit
    # normals exceed it with probability < 0.005: chi2(12)/12 < 2.55) and none
    # beyond 4.  (It is conservative, rms 0.48 here and 0.62 over 30 other seeds:
    # the fitted pedestal and kTC of a white dark are small positive values whose
    # model variance counts too.)
    det = preset("H2RG", naxis1=64, naxis2=64)
    floor = 5.2 / math.sqrt(56 * 56 * 16 * 4)      # 56^2 regular pixels, 64 reads
    p = NoiseParams(rd_noise=5.2, c_pink=0.0, u_pink=0.0, acn=0.0, pca0=0.0,
                    pedestal=0.0, ktc=0.0, bias_amp=0.0, bias_offset=0.0)
    pulls = []
    for seed in range(1000, 1012):
        cube = NoiseGenerator(det, p, rng=seed, threads=1).cube(16, nints=4)
        off = calibrate_darks(DarkRamps(tuple(cube), det)).estimates["bias_offset"]
        assert off.sigma >= 0.98 * floor, off       # rd_noise is estimated: 0.3 %
        pulls.append(off.value / off.sigma)
    rms = float(np.sqrt(np.mean(np.square(pulls))))
    assert rms < 1.6 and max(map(abs, pulls)) < 4, pulls


@pytest.mark.slow
def test_bias_offset_pulls_in_a_window_with_a_pattern_within_rows():
    # A regression probe: bias_offset's sigma added mean(template) x bias_amp's
    # sigma, picture-frame drift included, which cancels in the level: on a
    # left-edge window (the template has structure within rows there) the pulls
    # had a width of 0.28.  Over 12 random parameter sets the sample sd of unit
    # pulls lies in [0.53, 1.52] with probability 0.99 (chi2(11) / 11).
    det = preset("H2RG").window(0, 900, 64, 64)
    pulls = []
    for child in np.random.SeedSequence(4).spawn(12):
        rng = np.random.default_rng(child)
        p = _random_params(rng)
        cube = NoiseGenerator(det, p, rng=rng.integers(2 ** 63), threads=1).cube(
            8, nints=3)
        off = calibrate_darks(DarkRamps(tuple(cube), det)).estimates["bias_offset"]
        pulls.append((off.value - p.bias_offset) / off.sigma)
    assert 0.53 < np.std(pulls, ddof=1) < 1.52, pulls
