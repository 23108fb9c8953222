"""Tests of scenesim.validate.compare against closed forms on synthetic fit and truth files.

Synthetic fits are ``truth + sqrt(V) * N(0, 1)`` with a known ``V``.  The optimal
variance is checked in two limits with closed forms:

* rate 0, single reads at ``t_k = (k + 1) t_frame`` (k = 0..n-1): white noise only, the
  GLS slope is the least-squares slope, ``V = 12 sigma^2 / (t_frame^2 n (n^2 - 1))``;
* read noise 0: pure Poisson, the charge between the first and last read is all the
  information, ``V = f / (t_last - t_first)``.

Both are divided by ``nints`` for independent integrations.
"""

import math
import os

import numpy as np
import pytest
from astropy.io import fits
from astropy.table import Table
from scipy.special import erf

from noise.errors import FileFormatError, ParameterError
from scenesim.validate.compare import Report, compare, compare_files
from scenesim.detector.dq import DO_NOT_USE, JUMP_DET
from scenesim.io.fitfile import FitResult, write_fit

NG, TF, NINTS, GAIN = 6, 10.0, 2, 2.0


def _header(rdnoise, **extra):
    cards = {"NINTS": NINTS, "NGROUPS": NG, "NFRAMES": 1, "GROUPGAP": 0, "DROPFRM1": 0,
             "TFRAME": TF, "READPATT": "RAPID", "RESETMD": "rolling",
             "RDNOISE": rdnoise, "GAIN": GAIN}
    cards.update(extra)
    return cards


def _write_truth(path, rate, header, crs=None, sources=None, extra=()):
    prim = fits.PrimaryHDU()
    for k, v in header.items():
        prim.header[k] = v
    if crs is None:
        crs = Table({"TIME": [0.0], "X": [0], "Y": [0], "CHARGE": [0.0], "SEEN": [False]})
    if sources is None:
        sources = Table({"x": [], "y": [], "flux": []})
    hdul = fits.HDUList([prim,
                         fits.ImageHDU(rate.astype(np.float32), name="RATE"),
                         fits.ImageHDU(rate.astype(np.float32), name="RATE_IPC"),
                         fits.BinTableHDU(crs, name="CRS"),
                         fits.BinTableHDU(sources, name="SOURCES")] + list(extra))
    # 'ignore': the detector cards NAXIS1D/NAXIS2D look like NAXISj to astropy
    hdul.writeto(path, output_verify="ignore")
    return str(path)


def _write_fit(path, slope, var, dq=None, rn=1.0):
    shape = slope.shape
    z = np.zeros(shape, np.float32)
    res = FitResult(slope=slope.astype(np.float32), var_read=var.astype(np.float32),
                    var_poisson=z, chi2=np.ones(shape, np.float32),
                    dof=np.full(shape, 9, np.int32),
                    dq=(np.zeros(shape, np.uint32) if dq is None else dq.astype(np.uint32)),
                    slope_ints=np.stack([slope] * NINTS).astype(np.float32),
                    var_ints=np.stack([var] * NINTS).astype(np.float32),
                    n_jumps=np.zeros(shape, np.int32), gain=GAIN, read_noise=rn,
                    fitter="gls")
    write_fit(str(path), res)
    return str(path)


def _row(report, lo):
    return next(r for r in report.rows if r["lo"] == lo)


def test_read_noise_limit_table(tmp_path):
    """Rate 0: V_opt = 12 sigma^2 / (tf^2 n (n^2-1)) / nints; OLS = GLS there."""
    rng = np.random.default_rng(11)
    sigma = 12.0
    shape = (40, 50)
    rate = np.zeros(shape)
    v_opt = 12 * sigma ** 2 / (TF ** 2 * NG * (NG ** 2 - 1)) / NINTS
    slope = rate + math.sqrt(v_opt) * rng.standard_normal(shape)
    # reported variance twice the truth: the chi2_rep column must see it (~0.5)
    fit = _write_fit(tmp_path / "fit.fits", slope, np.full(shape, 2 * v_opt), rn=sigma)
    truth = _write_truth(tmp_path / "truth.fits", rate, _header(sigma))
    rep = compare_files(fit, truth)
    assert isinstance(rep, Report)
    row = _row(rep, 0.0)
    n = row["n"]
    assert n == 2000
    # mean of n unit normals: standard error 1/sqrt(n); 5 sigma
    assert abs(row["bias_opt"]) < 5 / math.sqrt(n)
    # sample std of n unit normals: standard error 1/sqrt(2n); 5 sigma
    assert abs(row["std_opt"] - 1) < 5 / math.sqrt(2 * n)
    # z_rep = z / sqrt(2): mean of z^2/2 has standard error sqrt(2/n)/2; 5 sigma
    assert abs(row["chi2_rep"] - 0.5) < 5 * math.sqrt(2 / n) / 2
    assert abs(row["bias_rep"]) < 5 / math.sqrt(2 * n)
    # white noise, single reads: equal weights are optimal (exact up to rounding)
    assert row["ols_ratio"] == pytest.approx(1.0, rel=1e-9)
    assert row["chi2_fit"] == pytest.approx(1.0)
    assert row["frac_flagged"] == 0.0
    assert all(r["n"] == 0 for r in rep.rows if r["lo"] > 0)
    text = rep.format()
    assert "bias_opt" in text and "MULTIACCUM" in text
    d = rep.to_dict()
    assert d["rows"][0]["n"] == 2000


def test_poisson_limit_and_jwst_layout(tmp_path):
    """Read noise 0: V_opt = f / (t_last - t_first) / nints; JWST rate file in DN/s."""
    rng = np.random.default_rng(12)
    shape = (40, 50)
    rate = np.where(rng.random(shape) < 0.5, 5.0, 500.0)
    v_opt = rate / ((NG - 1) * TF) / NINTS
    slope = rate + np.sqrt(v_opt) * rng.standard_normal(shape)
    dq = np.zeros(shape, np.uint32)
    dq[:2] = DO_NOT_USE          # 100 unusable pixels, left out of the statistics
    slope[:2] = 1e6
    prim = fits.PrimaryHDU()
    hdul = fits.HDUList([prim, fits.ImageHDU(slope / GAIN, name="SCI"),
                         fits.ImageHDU(np.sqrt(v_opt) / GAIN, name="ERR"),
                         fits.ImageHDU(dq, name="DQ"),
                         fits.ImageHDU(v_opt / GAIN ** 2, name="VAR_POISSON"),
                         fits.ImageHDU(np.zeros(shape), name="VAR_RNOISE")])
    fit = str(tmp_path / "rate.fits")
    hdul.writeto(fit)
    truth = _write_truth(tmp_path / "truth.fits", rate, _header(0.0))
    rep = compare_files(fit, truth)
    assert "fit layout: jwst" in rep.notes
    for lo in (1.0, 100.0):
        row = _row(rep, lo)
        n = row["n"]
        assert 800 < n < 1100
        assert abs(row["bias_opt"]) < 5 / math.sqrt(n)       # 5 sigma, mean of N(0,1)
        assert abs(row["std_opt"] - 1) < 5 / math.sqrt(2 * n)  # 5 sigma, std of N(0,1)
        # reported var = true var: mean z^2 has standard error sqrt(2/n); 5 sigma
        assert abs(row["chi2_rep"] - 1) < 5 * math.sqrt(2 / n)
        assert math.isnan(row["chi2_fit"])
        # 100 flagged of 2000 regular pixels, split between the two bins
        assert row["n_regular"] - row["n"] == pytest.approx(
            row["frac_flagged"] * row["n_regular"])
    assert _row(rep, 1.0)["n_regular"] + _row(rep, 100.0)["n_regular"] == 2000


def test_a_subtracted_dark_is_graded_at_the_rate_the_pixels_collected(tmp_path):
    """A pipeline that subtracted a dark reports ``net = collected - dark``, but its
    ramps carried the shot noise of all the charge: the optimum is
    ``V = f_collected / (t_last - t_first) / nints`` (read noise 0).  Before, it was
    taken at the net rate: std_opt sqrt(40 / 10) = 2 for a 10 e-/s source on a 30
    e-/s dark (a hostile probe saw 2.85 against 1.016 by hand on a Detector1 file)."""
    from scenesim.io.exposure import read_truth
    from scenesim.pipelines.products import subtract_dark
    rng = np.random.default_rng(14)
    shape = (40, 50)
    dark, net = 30.0, 10.0
    collected = np.full(shape, dark + net)
    v_opt = collected / ((NG - 1) * TF) / NINTS
    slope = net + np.sqrt(v_opt) * rng.standard_normal(shape)
    fit = dict(slope=slope, var=v_opt, dq=np.zeros(shape, np.uint32))
    truth = read_truth(_write_truth(tmp_path / "truth.fits", collected, _header(0.0)))
    rep = compare(fit, subtract_dark(truth, np.full(shape, dark)))
    row = _row(rep, 10.0)
    n = row["n"]
    assert n == 2000 and any("collected rate" in note for note in rep.notes)
    assert abs(row["bias_opt"]) < 5 / math.sqrt(n)         # 5 sigma, mean of N(0, 1)
    assert abs(row["std_opt"] - 1) < 5 / math.sqrt(2 * n)  # 5 sigma, std of N(0, 1)
    assert abs(row["chi2_rep"] - 1) < 5 * math.sqrt(2 / n)


@pytest.mark.parametrize("cards", [{"REFTYPE": "DARK", "DATAMODL": "DarkModel"},
                                   {"DATAMODL": "RampModel"}])
def test_a_jwst_file_that_is_not_a_rate_file_is_refused(tmp_path, cards):
    """A JWST dark reference (SCI, DQ, ERR like a rate file) was graded as slopes:
    an empty table and photometry 0.0000."""
    shape = (10, 10)
    prim = fits.PrimaryHDU()
    for key, value in cards.items():
        prim.header[key] = value
    fits.HDUList([prim, fits.ImageHDU(np.ones((3,) + shape, np.float32), name="SCI"),
                  fits.ImageHDU(np.zeros(shape, np.uint32), name="DQ"),
                  fits.ImageHDU(np.ones((3,) + shape, np.float32), name="ERR")]
                 ).writeto(tmp_path / "ref.fits")
    truth = _write_truth(tmp_path / "truth.fits", np.ones(shape), _header(1.0))
    with pytest.raises(FileFormatError, match=r"ref\.fits' is a JWST .*not a rate "
                                              r"\(ImageModel\) or rateints"):
        compare_files(str(tmp_path / "ref.fits"), truth)


def test_a_slope_file_of_another_exposure_is_refused(tmp_path):
    """compare graded a slope file against another run's truth without a word (bias
    -35 sigma, chi2 1270): the exposure cards both carry must agree."""
    shape = (10, 10)
    rate = np.full(shape, 5.0)
    fit = _write_fit(tmp_path / "fit.fits", rate, np.ones(shape))
    with fits.open(fit, mode="update") as hdul:
        hdul[0].header["NINTS"] = NINTS
        hdul[0].header["TFRAME"] = TF
        hdul[0].header["SEED"] = 5
        hdul[0].header["READPATT"] = "RAPID"
    for card, value in (("NINTS", 1), ("TFRAME", 2.5), ("SEED", 6), ("READPATT", "DEEP8")):
        truth = _write_truth(tmp_path / f"t_{card}.fits", rate,
                             _header(1.0, **{"SEED": 5, card: value}))
        with pytest.raises(FileFormatError, match=rf"slope file .*fit\.fits.* and truth "
                                                  rf"file .*t_{card}\.fits.* are not of the "
                                                  rf"same exposure: '{card}' = "):
            compare_files(fit, truth)
    compare_files(fit, _write_truth(tmp_path / "same.fits", rate, _header(1.0, SEED=5)))


def test_jump_completeness_and_false_positives(tmp_path):
    rng = np.random.default_rng(13)
    shape = (30, 30)
    sigma = 5.0
    thr = 10 * math.sqrt(2) * sigma
    pix = rng.choice(shape[0] * shape[1], size=60, replace=False)
    hit, small, unseen = pix[:30], pix[30:45], pix[45:]
    idx = np.concatenate([hit, small, unseen])
    charge = np.concatenate([np.full(30, 3 * thr), np.full(15, 0.5 * thr),
                             np.full(15, 3 * thr)])
    seen = np.concatenate([np.ones(45, bool), np.zeros(15, bool)])
    crs = Table({"TIME": np.zeros(60), "X": idx % shape[1], "Y": idx // shape[1],
                 "CHARGE": charge, "SEEN": seen})
    dq = np.zeros(shape[0] * shape[1], np.uint32)
    dq[hit[:24]] |= JUMP_DET                 # 24 of 30 detectable hits found
    clean = np.setdiff1d(np.arange(dq.size), idx)
    dq[clean[:7]] |= JUMP_DET                # 7 false positives among clean pixels
    dq[small[:3]] |= JUMP_DET                # neither hit nor clean: ignored
    dq = dq.reshape(shape)
    rate = np.full(shape, 10.0)
    fit = _write_fit(tmp_path / "fit.fits", rate, np.ones(shape), dq=dq, rn=sigma)
    truth = _write_truth(tmp_path / "truth.fits", rate, _header(sigma), crs=crs)
    j = compare_files(fit, truth).jumps
    assert j["threshold_e"] == pytest.approx(thr)
    assert j["n_hit"] == 30 and j["completeness"] == pytest.approx(24 / 30)
    assert j["n_clean"] == dq.size - 60
    assert j["false_positive"] == pytest.approx(7 / (dq.size - 60))


def test_jump_hits_are_deposits_inside_a_ramp(tmp_path):
    """A deposit is a jump only between the first and the last usable read.

    Conventions: read k of integration i is in frame slot i (1 + nreads) + 1 + k and a
    pixel is read t_pix after the start of its frame, so with NGROUPS = 6 single
    reads the usable ramp of integration i spans clock times
    ((7 i + 1) t_f + t_pix, (7 i + 6) t_f + t_pix]; SATGROUP g ends it at the last
    read of resultant g - 1.
    """
    from noise.clock import preset

    det = preset("H2RG").window(100, 100, 16, 12, "W")
    tf = det.frame_time
    tpix = det.pixel_time()
    hdr = _header(5.0, TFRAME=tf)
    hdr.update({k: v for k, v, _ in det.to_header_cards()})
    thr = 10 * math.sqrt(2) * 5.0
    pix = [(1, 1), (3, 2), (5, 3), (7, 4), (9, 5), (11, 6), (13, 7)]

    def t0(i, yx):
        return (7 * i + 1) * tf + tpix[yx[1], yx[0]]

    times = [t0(0, pix[0]) - 0.1 * tf,      # before the first read: an offset
             t0(0, pix[1]) + 0.5 * tf,      # inside integration 0: hit
             t0(0, pix[2]) + 5.5 * tf,      # after its last read (reset of int 1)
             t0(1, pix[3]) + 2.5 * tf,      # inside integration 1: hit
             t0(1, pix[4]) + 5.5 * tf,      # after the last read of the exposure
             t0(0, pix[5]) + 3.5 * tf,      # after saturation (SATGROUP 3)
             t0(0, pix[6]) + 3.5 * tf]      # before saturation (SATGROUP 5): hit
    crs = Table({"TIME": times, "X": [p[0] for p in pix], "Y": [p[1] for p in pix],
                 "CHARGE": np.full(7, 3 * thr), "SEEN": np.ones(7, bool)})
    shape = det.shape
    satg = np.full((NINTS,) + shape, -1, np.int16)
    satg[0, pix[5][1], pix[5][0]] = 3
    satg[0, pix[6][1], pix[6][0]] = 5
    rate = np.full(shape, 10.0)
    truth = _write_truth(tmp_path / "truth.fits", rate, hdr, crs=crs,
                         extra=[fits.ImageHDU(satg, name="SATGROUP")])
    dq = np.zeros(shape, np.uint32)
    for p in (pix[0], pix[1], pix[3], pix[6]):      # the three hits and one offset
        dq[p[1], p[0]] |= JUMP_DET
    fit = _write_fit(tmp_path / "fit.fits", rate, np.ones(shape), dq=dq, rn=5.0)
    rep = compare_files(fit, truth)
    j = rep.jumps
    assert j["n_hit"] == 3 and j["completeness"] == 1.0
    # all 7 pixels have a deposit: neither hit nor clean unless inside the ramp
    assert j["n_clean"] == shape[0] * shape[1] - 7 and j["false_positive"] == 0.0
    assert not any("every seen deposit" in n for n in rep.notes)


def test_ipc_neighbours_of_deposits_are_not_clean(tmp_path):
    shape = (20, 20)
    crs = Table({"TIME": [0.0], "X": [10], "Y": [10], "CHARGE": [1000.0],
                 "SEEN": [True]})
    dq = np.zeros(shape, np.uint32)
    dq[10, 11] |= JUMP_DET              # the IPC share of the hit, in a neighbour
    rate = np.full(shape, 1.0)
    fit = _write_fit(tmp_path / "fit.fits", rate, np.ones(shape), dq=dq, rn=5.0)
    for ipc, n_clean, fp in ((True, 400 - 9, 0.0), (False, 400 - 1, 1 / 399)):
        truth = _write_truth(tmp_path / f"truth{ipc}.fits", rate,
                             _header(5.0, IPC=ipc), crs=crs)
        j = compare_files(fit, truth).jumps
        assert j["n_clean"] == n_clean and j["false_positive"] == pytest.approx(fp)


def _gauss_image(shape, xs, ys, fluxes, sigma):
    """Exact pixel integrals of circular Gaussians (erf), independent of scenesim.sky.psf."""
    ny, nx = shape
    out = np.zeros(shape)
    s = math.sqrt(2) * sigma
    xe, ye = np.arange(nx + 1) - 0.5, np.arange(ny + 1) - 0.5
    for x, y, f in zip(xs, ys, fluxes):      # a handful of sources
        px = np.diff(0.5 * erf((xe - x) / s))
        py = np.diff(0.5 * erf((ye - y) / s))
        out += f * np.outer(py, px)
    return out


def test_photometry_aperture_correction(tmp_path):
    pytest.importorskip("photutils", reason="photutils is needed for photometry")
    pytest.importorskip("scenesim.sky.psf", reason="scenesim.sky.psf provides encircled_energy")
    rng = np.random.default_rng(14)
    shape = (120, 120)
    fwhm, radius, bkg, flux = 2.0, 4.0, 10.0, 4000.0
    g = np.arange(20, 100, 18.0)
    xs, ys = np.meshgrid(g, g)
    xs = xs.ravel() + rng.uniform(-0.5, 0.5, xs.size)
    ys = ys.ravel() + rng.uniform(-0.5, 0.5, ys.size)
    n_src = xs.size
    fl = np.full(n_src, flux)
    # plus one source too close to the edge and one too faint: both excluded
    xs, ys = np.append(xs, [3.0, 47.0]), np.append(ys, [60.0, 47.0])
    fl = np.append(fl, [flux, 1.0])
    sig = fwhm / (2 * math.sqrt(2 * math.log(2)))
    rate = bkg + _gauss_image(shape, xs, ys, fl, sig)
    var = np.full(shape, 4.0)
    slope = rate + 2.0 * rng.standard_normal(shape)
    sources = Table({"x": xs, "y": ys, "flux": fl})
    fit = _write_fit(tmp_path / "fit.fits", slope, var)
    truth = _write_truth(tmp_path / "truth.fits", rate, _header(5.0, PSFFWHM=fwhm),
                         sources=sources)
    p = compare_files(fit, truth).photometry
    assert p["n"] == n_src
    ee = 1 - math.exp(-radius ** 2 / (2 * sig ** 2))   # Gaussian encircled energy
    assert p["aperture_correction"] == pytest.approx(ee, rel=1e-12)
    # per-source noise: aperture sum var = 4 * area; annulus median times area adds
    # (pi/2) * 4 / n_ann * area^2 (median efficiency); the median of the ratios has
    # standard error 1.2533 * s / sqrt(n).  Pixelisation changes the encircled energy
    # by < 1e-4 at r = 4.7 sigma, far below that.  5 sigma:
    area = math.pi * radius ** 2
    n_ann = math.pi * ((3 * radius) ** 2 - (2 * radius) ** 2)
    s = math.sqrt(4 * area + math.pi / 2 * 4 / n_ann * area ** 2) / ee / flux
    assert abs(p["median_ratio"] - 1) < 5 * 1.2533 * s / math.sqrt(n_src)
    # the reported error of the median estimates the same quantity (std of a sample of
    # 25: relative standard error 1/sqrt(2*24) ~ 0.15; allow a factor 2)
    assert 0.5 < p["median_ratio_err"] / (1.2533 * s / math.sqrt(n_src)) < 2


def test_plots_and_no_psf_note(tmp_path):
    pytest.importorskip("matplotlib", reason="plots need matplotlib")
    rng = np.random.default_rng(15)
    shape = (32, 32)
    rate = rng.uniform(0.5, 50, shape)
    slope = rate + rng.standard_normal(shape)
    sources = Table({"x": [16.0], "y": [16.0], "flux": [1000.0]})
    fit = _write_fit(tmp_path / "fit.fits", slope, np.ones(shape))
    truth = _write_truth(tmp_path / "truth.fits", rate, _header(5.0), sources=sources)
    out = tmp_path / "plots"
    out.mkdir()
    rep = compare_files(fit, truth, plots=str(out))
    assert sorted(os.path.basename(p) for p in rep.plots) == [
        "noise_vs_flux.png", "residuals.png", "slope.png"]
    assert all(os.path.getsize(p) > 1000 for p in rep.plots)
    assert any("no aperture correction" in n for n in rep.notes)
    assert math.isnan(rep.photometry["aperture_correction"])


def test_bad_inputs(tmp_path):
    rate = np.ones((10, 12))
    truth = _write_truth(tmp_path / "truth.fits", rate, _header(5.0))
    fit_bad_shape = _write_fit(tmp_path / "f1.fits", np.ones((10, 11)), np.ones((10, 11)))
    with pytest.raises(FileFormatError, match="shape"):
        compare_files(fit_bad_shape, truth)
    # JWST-like file without DQ
    hdul = fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(rate, name="SCI"),
                         fits.ImageHDU(rate, name="ERR")])
    nodq = str(tmp_path / "nodq.fits")
    hdul.writeto(nodq)
    with pytest.raises(FileFormatError, match="DQ"):
        compare_files(nodq, truth)
    # neither layout
    other = str(tmp_path / "other.fits")
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(rate, name="FOO")]).writeto(other)
    with pytest.raises(FileFormatError, match="SLOPE"):
        compare_files(other, truth)
    ok = _write_fit(tmp_path / "ok.fits", rate, np.ones_like(rate))
    with pytest.raises(ParameterError, match="plots"):
        compare_files(ok, truth, plots=str(tmp_path / "missing_dir"))
    with pytest.raises(FileFormatError, match="does not exist"):
        compare_files(str(tmp_path / "nope.fits"), truth)
    with pytest.raises(ParameterError, match="'fit'"):
        compare([1, 2], {"header": {}})


def test_read_times_from_exposure(tmp_path):
    """READS table of the exposure wins over the truth header (which says NFRAMES=1).

    Rate 0, resultants of 2 reads (groupgap 1): white resultant noise sigma^2 / 2, so
    V_opt = (sigma^2 / 2) / sum (tbar - <tbar>)^2 / nints with tbar = 10 * (1.5 + 3 g).
    """
    from scenesim.detector.readout import Readout
    rng = np.random.default_rng(16)
    sigma, shape = 8.0, (40, 50)
    ro = Readout.multiaccum(2, NG, groupgap=1, nints=NINTS)
    tab = fits.table_to_hdu(ro.read_table(TF))
    tab.name = "READS"
    prim = fits.PrimaryHDU()
    prim.header["NINTS"], prim.header["TFRAME"] = NINTS, TF
    exposure = str(tmp_path / "exp.fits")
    fits.HDUList([prim, tab]).writeto(exposure)
    tbar = TF * (1.5 + 3 * np.arange(NG))
    v_opt = sigma ** 2 / 2 / np.sum((tbar - tbar.mean()) ** 2) / NINTS
    rate = np.zeros(shape)
    slope = math.sqrt(v_opt) * rng.standard_normal(shape)
    fit = _write_fit(tmp_path / "fit.fits", slope, np.full(shape, v_opt), rn=sigma)
    truth = _write_truth(tmp_path / "truth.fits", rate, _header(sigma))
    row = _row(compare_files(fit, truth, exposure=exposure), 0.0)
    n = row["n"]
    assert abs(row["std_opt"] - 1) < 5 / math.sqrt(2 * n)  # 5 sigma, std of N(0,1)
    # with the header's single-read readout the ratio would be sqrt(V_opt / V_1read):
    v1 = 12 * sigma ** 2 / (TF ** 2 * NG * (NG ** 2 - 1)) / NINTS
    assert abs(math.sqrt(v_opt / v1) - 1) > 20 / math.sqrt(2 * n)


def test_a_truth_grades_a_custom_readout_without_its_exposure(tmp_path):
    """Without --exposure the read times were rebuilt as MULTIACCUM from the header
    even for explicit resultants: std_opt 0.26 where the exposure's read times give
    1.07 (found by a docs probe).  The truth now carries the READS table: the report
    is the exposure's; a truth without it (written before) is refused for such a
    readout."""
    from scenesim.run import run_scene
    from scenesim.scene import parse_scene
    scene = parse_scene({
        "seed": 4, "detector": {"preset": "H2RG", "naxis1": 64, "naxis2": 64},
        "readout": {"resultants": [[0], [1, 3], [5, 6, 7], [10, 11, 12, 13]]},
        "sources": {"background": 20.0},
        "output": {"path": str(tmp_path / "x.fits"), "fit": "gls"}})
    res = run_scene(scene, progress=False)
    alone = compare_files(res.fit, res.truth)
    given = compare_files(res.fit, res.truth, exposure=res.exposure)
    assert "read times from the truth's READS table" in alone.notes
    np.testing.assert_equal(alone.rows, given.rows)      # (NaN in empty bins alike)
    old = tmp_path / "old_truth.fits"
    with fits.open(res.truth) as hdul:
        hdus = [h for h in hdul if h.name != "READS"]
        hdus[0].header["NEXTEND"] = len(hdus) - 1       # as the truth files before
        fits.HDUList(hdus).writeto(old)
    with pytest.raises(FileFormatError, match=r"not MULTIACCUM .*NREADS = 14.* pass it "
                                              r"\(--exposure\)"):
        compare_files(res.fit, str(old))
    np.testing.assert_equal(compare_files(res.fit, str(old), exposure=res.exposure).rows,
                            given.rows)


@pytest.mark.parametrize("with_exposure", [False, True])
def test_a_one_group_exposure_is_refused_before_the_slope_file_is_made(
        tmp_path, with_exposure):
    # `scenesim pipeline jwst --truth --exposure` checks the comparison's inputs
    # before Detector1 runs; a one-group exposure passed that check when the
    # exposure was given (its readout, not the truth's, was used) and failed after
    # the pipeline, blaming the dark reference (a probe)
    from scenesim.run import run_scene
    from scenesim.scene import parse_scene
    from scenesim.validate.compare import check_compare_inputs
    scene = parse_scene({"seed": 1, "detector": {"preset": "H2RG", "naxis1": 32,
                                                 "naxis2": 32},
                         "readout": {"pattern": "RAPID", "ngroups": 1},
                         "output": {"path": str(tmp_path / "one.fits"), "truth": True,
                                    "fit": ""}})
    run_scene(scene, progress=False)
    with pytest.raises(FileFormatError, match="'NGROUPS' = 1: a slope needs at least "
                                              "2 resultants"):
        check_compare_inputs(str(tmp_path / "one_truth.fits"),
                             exposure=str(tmp_path / "one.fits") if with_exposure
                             else None)


def test_a_reference_corrected_fit_says_what_se_bias_leaves_out(tmp_path):
    # A probe: white-noise fits after the 'jwst' reference correction read p_bias
    # ~1e-17 (its offsets, common to an output and column parity, are one draw per
    # exposure).  Clusters of whole outputs were tried and dropped (one output: two
    # clusters); the report now says what se_bias leaves out when the fit file's
    # REFPIX card says the ramps were corrected, and nothing when it says 'none'.
    from astropy.io import fits as _fits
    rng = np.random.default_rng(61)
    shape, sigma = (32, 64), 12.0
    v_opt = 12 * sigma ** 2 / (TF ** 2 * NG * (NG ** 2 - 1)) / NINTS
    truth = _write_truth(tmp_path / "t.fits", np.zeros(shape), _header(sigma))
    fit = _write_fit(tmp_path / "f.fits", math.sqrt(v_opt) * rng.standard_normal(shape),
                     np.full(shape, v_opt), rn=sigma)
    for card, said in (("jwst", True), ("none", False)):
        with _fits.open(fit, mode="update") as hdul:
            hdul[0].header["REFPIX"] = card
        rep = compare_files(fit, truth)
        assert any("leave out the reference correction's offsets" in n
                   for n in rep.notes) == said, rep.notes
