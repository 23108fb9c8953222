"""Aperture photometry in ``compare`` for an Airy PSF recorded in the truth header.

The truth header records the PSF (``PSFAIRY``: radius of the first dark ring); the
aperture correction must be the Airy encircled energy, closed form
``EE(r) = 1 - J0(v)^2 - J1(v)^2`` with ``v = j1 r / a``, ``j1 = 3.8317`` the first zero
of ``J1`` (the dark ring sits at ``v = j1``; Born & Wolf, section 8.5.2).
Before the header contract, ``PSFAIRY`` was written but never read, so Airy scenes got
no aperture correction (ratio ~ EE(4 px) = 0.93 instead of 1).
"""

import math

import numpy as np
import pytest
from astropy.io import fits
from astropy.table import Table
from scipy.special import j0, j1, jn_zeros

from scenesim.io.fitfile import FitResult, write_fit
from scenesim.sky.psf import AiryPSF, render_point_sources
from scenesim.validate.compare import compare_files


def _ee(r, a):
    v = jn_zeros(1, 1)[0] * r / a
    return 1.0 - j0(v) ** 2 - j1(v) ** 2


def test_airy_psf_from_header_gives_the_aperture_correction(tmp_path):
    a, radius, bkg, flux, sigma = 1.5, 4.0, 10.0, 2e5, 2.0
    shape = (140, 140)
    rng = np.random.default_rng(21)
    g = np.arange(25, 120, 22.0)
    xs, ys = np.meshgrid(g, g)
    xs = xs.ravel() + rng.uniform(-0.5, 0.5, xs.size)
    ys = ys.ravel() + rng.uniform(-0.5, 0.5, ys.size)
    n = xs.size
    img, _ = render_point_sources(shape, xs, ys, np.full(n, flux), AiryPSF(a),
                                  stamp_radius=20)
    rate = bkg + img
    slope = rate + sigma * rng.standard_normal(shape)
    z = np.zeros(shape, np.float32)
    fit = FitResult(slope=slope.astype(np.float32),
                    var_read=np.full(shape, sigma ** 2, np.float32), var_poisson=z,
                    chi2=np.ones(shape, np.float32), dof=np.full(shape, 9, np.int32),
                    dq=np.zeros(shape, np.uint32),
                    slope_ints=slope[None].astype(np.float32),
                    var_ints=np.full((1,) + shape, sigma ** 2, np.float32),
                    n_jumps=np.zeros(shape, np.int32), gain=1.0, read_noise=5.0,
                    fitter="gls")
    write_fit(str(tmp_path / "fit.fits"), fit)
    prim = fits.PrimaryHDU()
    for key, value in {"NINTS": 1, "NGROUPS": 5, "NFRAMES": 1, "GROUPGAP": 0,
                       "DROPFRM1": 0, "TFRAME": 10.0, "READPATT": "RAPID",
                       "RESETMD": "rolling", "RDNOISE": 5.0, "GAIN": 1.0,
                       "PSFAIRY": a}.items():
        prim.header[key] = value
    fits.HDUList([prim, fits.ImageHDU(rate.astype(np.float32), name="RATE"),
                  fits.ImageHDU(rate.astype(np.float32), name="RATE_IPC"),
                  fits.BinTableHDU(Table({"x": xs, "y": ys, "flux": np.full(n, flux)}),
                                   name="SOURCES")]).writeto(tmp_path / "truth.fits")
    p = compare_files(tmp_path / "fit.fits", tmp_path / "truth.fits").photometry
    ee = _ee(radius, a)
    assert p["aperture_correction"] == pytest.approx(ee, rel=1e-9)
    # Expected ratio: the annulus (2r..3r) median removes the Airy wing lying in it,
    # (EE(3r) - EE(2r)) / A_ann per pixel, times the aperture area A_ap.
    a_ap = math.pi * radius ** 2
    a_ann = math.pi * ((3 * radius) ** 2 - (2 * radius) ** 2)
    expected = (ee - (_ee(3 * radius, a) - _ee(2 * radius, a)) * a_ap / a_ann) / ee
    # Noise of one ratio: aperture sum sigma^2 A_ap, annulus median (pi/2) sigma^2 /
    # A_ann per pixel times A_ap^2; the median of n ratios has standard error
    # 1.2533 s / sqrt(n).  Pixel integration moves the encircled energy at 4 px (where
    # the Airy surface brightness is < 1e-3 of its peak) by at most 2e-3 (allowed):
    s = math.sqrt(sigma ** 2 * a_ap + math.pi / 2 * sigma ** 2 / a_ann * a_ap ** 2) / ee / flux
    assert abs(p["median_ratio"] - expected) < 5 * 1.2533 * s / math.sqrt(n) + 2e-3
    assert abs(p["median_ratio"] - 1.0) < 0.02   # without the correction: ~ 1/0.93


def test_annulus_medians_are_photutils_aperture_stats_medians():
    """The background medians equal photutils' ApertureStats(..., mask=bad).median
    (same 'center' masks): annuli inside, across the edges and off the array, bad
    and non-finite pixels excluded (seeded image; exact equality)."""
    import warnings
    from photutils.aperture import ApertureStats, CircularAnnulus
    from scenesim.validate.photometry import annulus_medians
    rng = np.random.default_rng(5)
    img = rng.normal(3.0, 1.0, (64, 80))
    bad = rng.random(img.shape) < 0.1
    img[rng.random(img.shape) < 0.02] = np.nan
    pos = np.column_stack([rng.uniform(-3, 83, 30), rng.uniform(-3, 67, 30)])
    pos[0] = (-20.0, -20.0)                        # no pixel at all: NaN
    ann = CircularAnnulus(pos, r_in=4.0, r_out=7.5)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")            # photutils warns about the NaNs
        want = np.asarray(ApertureStats(img, ann, mask=bad).median, dtype=float)
    got = annulus_medians(img, ann, bad)
    assert np.isnan(got[0])
    np.testing.assert_array_equal(got, want)


def test_a_source_with_unmeasured_pixels_in_its_aperture_is_left_out():
    # A saturated core is DO_NOT_USE; counted as 0 e-/s it read 0.32 of a probe's
    # star into the median.  Two noise-free stars, one with its peak pixel bad: the
    # other alone is measured (ratio 1 to 1e-3: the Gaussian outside 3 r, at 4.7
    # sigma, and pixel integration), and a note says one was left out.  With a flat,
    # the injected flux is what the array collected (flux_on_array).
    from scenesim.sky.psf import GaussianPSF
    from scenesim.validate.photometry import source_photometry
    shape, flux, radius = (80, 80), 1e5, 4.0
    psf = GaussianPSF(2.0)
    xs, ys = np.array([20.3, 60.4]), np.array([40.2, 40.6])
    img, info = render_point_sources(shape, xs, ys, np.full(2, flux), psf,
                                     stamp_radius=20, qe=np.full(shape, 0.5))
    bad = np.zeros(shape, bool)
    bad[40, 20] = True
    notes = []
    p = source_photometry(img, np.full(shape, 1.0), bad, info, psf, radius, notes)
    assert p["n"] == 1 and p["sources"][0]["x"] == pytest.approx(60.4)
    assert p["sources"][0]["flux"] == pytest.approx(0.5 * flux, rel=1e-6)
    assert abs(p["median_ratio"] - 1) < 1e-3, p["median_ratio"]
    assert any("1 source(s) left out" in n for n in notes), notes
