"""Tests of scenesim.sky.psf against closed forms and independent quadratures."""

import math
import pickle

import numpy as np
import pytest
from astropy.io import fits
from scipy.integrate import quad
from scipy.special import erf, erfc, j0, j1

from noise.errors import FileFormatError, ParameterError
from scenesim.sky.psf import (AiryPSF, GaussianPSF, ImagePSF, encircled_energy,
                          render_point_sources)

SQRT2 = math.sqrt(2.0)
RZ = 1.2196698912665045          # first zero of J1 / pi


# ----------------------------------------------------------- independent references
def gauss_prf_1d(centres, x0, sigma):
    """Fraction of a 1-D Gaussian N(x0, sigma) in the unit pixels centred on ``centres``."""
    return 0.5 * (erf((centres - x0 + 0.5) / (SQRT2 * sigma))
                  - erf((centres - x0 - 0.5) / (SQRT2 * sigma)))


def gauss_image(shape, x0, y0, flux, sigma):
    ny, nx = shape
    return flux * np.outer(gauss_prf_1d(np.arange(ny), y0, sigma),
                           gauss_prf_1d(np.arange(nx), x0, sigma))


def gauss_frac_1d(n, x0, sigma):
    """Fraction of N(x0, sigma) inside [-0.5, n - 0.5]."""
    return 0.5 * (erfc((-0.5 - x0) / (SQRT2 * sigma)) - erfc((n - 0.5 - x0) / (SQRT2 * sigma)))


def airy_intensity(r, radius):
    """Unit-flux Airy surface brightness: pi/(4 a^2) (2 J1(v)/v)^2, v = pi r / a."""
    a = radius / RZ
    v = np.pi * np.asarray(r, dtype=float) / a
    safe = np.where(v > 0, v, 1.0)
    return np.where(v > 0, (2 * j1(safe) / safe) ** 2, 1.0) * np.pi / (4 * a * a)


def airy_pixel_reference(xc, yc, x0, y0, radius, nodes=14):
    """Pixel integrals of the Airy pattern over pixels centred on (xc, yc) grids."""
    t, w = np.polynomial.legendre.leggauss(nodes)
    t, w = 0.5 * t, 0.5 * w
    ux = (xc[:, None] - x0 + t[None, :])          # (nx, k)
    uy = (yc[:, None] - y0 + t[None, :])          # (ny, k)
    r = np.sqrt(uy[:, :, None, None] ** 2 + ux[None, None, :, :] ** 2)
    return np.einsum("ajbk,j,k->ab", airy_intensity(r, radius), w, w)


def centroid(image):
    yy, xx = np.indices(image.shape)
    total = image.sum()
    return (xx * image).sum() / total, (yy * image).sum() / total


def gaussian_subpixel_image(fwhm, oversample, npix):
    """Flux per sub-pixel of a centred Gaussian (exact erf), npix pixels wide."""
    sigma = fwhm / (2 * math.sqrt(2 * math.log(2)))
    n = oversample * npix
    edges = (np.arange(n + 1) - n / 2) / oversample
    p = np.diff(0.5 * erf(edges / (SQRT2 * sigma)))
    return np.outer(p, p)


# ------------------------------------------------------------------- Gaussian PSF
def test_gaussian_stamp_equals_erf_pixel_integral():
    rng = np.random.default_rng(101)
    psf = GaussianPSF(fwhm=2.3)
    shape = (48, 56)
    x = rng.uniform(10, 46, 5)
    y = rng.uniform(10, 38, 5)
    flux = rng.uniform(100, 1e4, 5)
    image, info = render_point_sources(shape, x, y, flux, psf)
    expected = sum(gauss_image(shape, xi, yi, fi, psf.sigma)
                   for xi, yi, fi in zip(x, y, flux))
    # Default stamps reach 7.5 sigma + 1 px, beyond which the 1-D tail is
    # erfc(7.5/sqrt 2) = 6e-14; both are float64 sums of O(1e4): allow 1e-12 relative.
    assert np.max(np.abs(image - expected)) <= 1e-12 * flux.max()
    assert np.allclose(info["flux_on_array"], flux, rtol=1e-12, atol=0)
    # photutils' CircularGaussianPRF is an independent implementation of the same model
    yy, xx = np.indices(shape)
    model = psf.to_photutils(flux=flux[0], x_0=x[0], y_0=y[0])
    single, _ = render_point_sources(shape, x[0], y[0], flux[0], psf)
    assert np.max(np.abs(single - model(xx, yy))) <= 1e-12 * flux[0]


def test_gaussian_flux_conserved_and_centroid():
    rng = np.random.default_rng(102)
    psf = GaussianPSF(fwhm=3.0)
    for _ in range(10):
        x, y = rng.uniform(20, 30, 2)
        image, info = render_point_sources((50, 50), x, y, 1234.5, psf)
        assert abs(image.sum() - 1234.5) <= 1e-6 * 1234.5
        assert info["frac_on_array"][0] == pytest.approx(1.0, abs=1e-12)
        assert info["flux_lost_stamp"][0] <= 1e-10
        cx, cy = centroid(image)
        # Exact pixel integrals of a symmetric PSF: the centroid is exact up to the
        # stamp truncation (< 1e-12); 0.01 px is the requirement.
        assert abs(cx - x) < 0.01 and abs(cy - y) < 0.01


def test_gaussian_partly_off_array_fraction():
    psf = GaussianPSF(fwhm=2.5)
    s = psf.sigma
    ny, nx = 30, 40
    cases = [(-0.7, 15.2), (39.6, 14.9), (-1.3, -0.8), (20.0, 29.9), (-4.0, 10.0)]
    for x, y in cases:
        image, info = render_point_sources((ny, nx), x, y, 1000.0, psf)
        frac = gauss_frac_1d(nx, x, s) * gauss_frac_1d(ny, y, s)
        assert image.sum() == pytest.approx(1000.0 * frac, rel=1e-9, abs=1e-9)
        assert info["frac_on_array"][0] == pytest.approx(frac, rel=1e-9, abs=1e-12)
        assert info["rendered"][0]
    # Wholly off: nothing rendered, fraction 0.
    image, info = render_point_sources((ny, nx), -100.0, 5.0, 1000.0, psf)
    assert not image.any()
    assert info["frac_on_array"][0] == 0 and info["flux_on_array"][0] == 0
    assert not info["rendered"][0]


def test_zero_flux_and_no_sources_render_nothing():
    psf = GaussianPSF(fwhm=2.0)
    image, info = render_point_sources((20, 20), [5.0, 10.0], [5.0, 12.0], [0.0, 0.0], psf)
    assert not image.any()
    assert np.all(info["frac_on_array"] > 0.99)      # fraction is a PSF property
    image, info = render_point_sources((20, 20), [], [], [], psf)
    assert not image.any() and len(info) == 0


def test_adaptive_stamp_omits_only_pixels_below_min_rate():
    rng = np.random.default_rng(103)
    x = rng.uniform(45, 55, 6)
    y = rng.uniform(45, 55, 6)
    flux = 10 ** rng.uniform(1, 4, 6)
    min_rate = 0.05
    for psf in (GaussianPSF(fwhm=2.0), AiryPSF(radius=2.0)):
        for xi, yi, fi in zip(x, y, flux):
            adaptive, info = render_point_sources((100, 100), xi, yi, fi, psf,
                                                  min_rate=min_rate)
            full, info_full = render_point_sources((100, 100), xi, yi, fi, psf,
                                                   stamp_radius=44)
            r = int(info["stamp_radius"][0])
            assert r < 44
            ix, iy = int(np.floor(xi + 0.5)), int(np.floor(yi + 0.5))
            outside = np.ones((100, 100), bool)
            outside[iy - r:iy + r + 1, ix - r:ix + r + 1] = False
            assert not adaptive[outside].any()
            # every omitted pixel would have received less than min_rate
            assert full[outside].max() < min_rate
            # inside the stamp the two renderings agree (same quadrature)
            assert np.allclose(adaptive[~outside], full[~outside], rtol=1e-12, atol=1e-15)
            # the reported loss is what the large stamp has beyond the small one plus
            # the large stamp's own loss (pixel values agree, so up to round-off)
            lost = info["flux_lost_stamp"][0]
            ring = full[outside].sum()
            assert lost == pytest.approx(ring + info_full["flux_lost_stamp"][0],
                                         abs=1e-12 * fi)


# ----------------------------------------------------------------------- Airy PSF
def test_airy_pixel_values_match_independent_quadrature():
    psf = AiryPSF(radius=2.0)
    x0, y0, flux = 20.37, 19.74, 1.0
    image, _ = render_point_sources((40, 40), x0, y0, flux, psf, stamp_radius=8)
    ref = airy_pixel_reference(np.arange(12, 29.0), np.arange(12, 29.0), x0, y0, 2.0)
    got = image[12:29, 12:29]
    # Module bound: Gauss-Legendre error <= 1e-6 of the peak surface brightness
    # pi/(4 a^2) (Bernstein bound) plus table interpolation <= 1.6e-8 of it.  The
    # 14-node reference has a bound < 1e-16.
    peak = math.pi / (4 * (2.0 / RZ) ** 2)
    assert np.max(np.abs(got - ref)) <= (1e-6 + 1.6e-8) * peak


def test_airy_quadrature_order_matches_documentation():
    assert [AiryPSF(r).quadrature_order for r in (1.0, 2.0, 3.0, 6.0)] == [7, 5, 5, 4]


def test_airy_flux_accounting_against_box_integral():
    rng = np.random.default_rng(104)
    psf = AiryPSF(radius=2.0)
    R = 12
    for _ in range(3):
        x0, y0 = rng.uniform(30, 31, 2)
        image, info = render_point_sources((64, 64), x0, y0, 500.0, psf, stamp_radius=R)
        ix, iy = int(np.floor(x0 + 0.5)), int(np.floor(y0 + 0.5))
        cols = np.arange(ix - R, ix + R + 1, dtype=float)
        rows = np.arange(iy - R, iy + R + 1, dtype=float)
        box = airy_pixel_reference(cols, rows, x0, y0, 2.0).sum()
        lost_true = 500.0 * (1.0 - box)
        # rendered + lost == flux * frac (frac = 1 on the array) to 1e-6 relative ...
        assert image.sum() + info["flux_lost_stamp"][0] == pytest.approx(500.0, rel=1e-6)
        # ... and the loss is the true PSF flux outside the stamp: the sum of the
        # per-pixel bound over 25^2 pixels is 625 * 1e-6 * 0.29 = 2e-4 of the flux,
        # but the measured summed error is ~1e-8 (module notes); use 1e-6 relative.
        assert info["flux_lost_stamp"][0] == pytest.approx(lost_true, abs=1e-6 * 500.0)
        # the loss is a few per cent: between the encircled-energy deficits of the
        # circles inscribed in and circumscribing the box (radius R + 1/2 -/+ 1/2 offset)
        a = 2.0 / RZ

        def ee(r):
            return 1 - j0(np.pi * r / a) ** 2 - j1(np.pi * r / a) ** 2
        assert 1 - ee(math.sqrt(2) * (R + 1)) <= lost_true / 500 <= 1 - ee(R)


def test_chunking_does_not_change_the_result():
    # Stamps are built in chunks of about 2.5e5 array elements: groups of sources,
    # and for the Airy pattern blocks of stamp rows.  Enough sources to need several
    # chunks give the image of the same sources rendered 20 at a time (one chunk
    # each: at R = 6 a chunk holds ~1480 Gaussian, ~340 image or ~40 Airy sources).
    rng = np.random.default_rng(107)
    data = gaussian_subpixel_image(2.0, 4, npix=11)
    for psf, n in ((GaussianPSF(2.0), 3000), (AiryPSF(1.5), 200),
                   (ImagePSF(data, oversample=4), 1000)):
        x, y = rng.uniform(5, 95, n), rng.uniform(5, 95, n)
        flux = rng.uniform(1, 100, n)
        whole, _ = render_point_sources((100, 100), x, y, flux, psf, stamp_radius=6)
        pieces = sum(render_point_sources((100, 100), x[i:i + 20], y[i:i + 20],
                                          flux[i:i + 20], psf, stamp_radius=6)[0]
                     for i in range(0, n, 20))
        assert np.allclose(pieces, whole, rtol=1e-13, atol=1e-13)
    # One Airy source with a 129 x 129 stamp is built in row blocks (129 rows x 36
    # nodes per pixel exceed a chunk); its inner 17 x 17 pixels equal those of a
    # 17 x 17 stamp, built in one block, to round-off.
    psf = AiryPSF(1.5)
    assert psf.quadrature_order == 6
    big, _ = render_point_sources((140, 140), 70.3, 69.8, 1.0, psf, stamp_radius=64)
    small, _ = render_point_sources((140, 140), 70.3, 69.8, 1.0, psf, stamp_radius=8)
    inner = (slice(62, 79), slice(62, 79))
    assert np.allclose(big[inner], small[inner], rtol=1e-13, atol=1e-13 * small.max())
    assert not small[~np.pad(np.ones((17, 17), bool), ((62, 61), (62, 61)))].any()


def test_airy_centroid():
    rng = np.random.default_rng(105)
    psf = AiryPSF(radius=2.0)
    for _ in range(3):
        x0, y0 = rng.uniform(49.5, 50.5, 2)
        image, _ = render_point_sources((101, 101), x0, y0, 1.0, psf, stamp_radius=48)
        cx, cy = centroid(image)
        # The stamp is centred on the nearest pixel, so it is asymmetric about the
        # source by delta <= 0.5 px.  With the wing line integral 4 a/(pi^3 R^2) at
        # the edge, the bias is about 8 a delta/(pi^3 R) = 0.0044 px for a = 1.64,
        # R = 48: below the 0.01 px requirement.
        assert abs(cx - x0) < 0.01 and abs(cy - y0) < 0.01


def test_airy_encircled_energy_matches_radial_integral():
    psf = AiryPSF(radius=2.5)
    for r in (0.5, 2.5, 7.0):
        num, _ = quad(lambda s: 2 * np.pi * s * airy_intensity(s, 2.5), 0, r,
                      limit=200, epsabs=1e-13)
        assert encircled_energy(psf, r) == pytest.approx(num, abs=1e-9)
    assert encircled_energy(psf, 0.0) == 0.0


# ---------------------------------------------------------------------- Image PSF
def test_image_psf_reproduces_gaussian_prf():
    fwhm, os_ = 3.0, 4
    gauss = GaussianPSF(fwhm)
    data = gaussian_subpixel_image(fwhm, os_, npix=25)
    psf = ImagePSF(data, oversample=os_)
    rng = np.random.default_rng(106)
    sigma = gauss.sigma
    # Aligned positions (multiples of 1/os from the array-centred alignment): each
    # pixel is an exact sum of sub-pixel erf integrals.
    for x0, y0 in [(20.0, 20.25), (19.5, 21.75)]:
        img, _ = render_point_sources((40, 40), x0, y0, 1.0, psf)
        assert np.max(np.abs(img - gauss_image((40, 40), x0, y0, 1.0, sigma))) <= 1e-13
    # Arbitrary positions.  A sub-pixel of width h = 1/os that straddles a pixel edge
    # at distance u from its side is split in proportion u/h, as if uniform; with a
    # linear surface-brightness gradient g across it the true split differs by
    # g h u (h - u)/2 <= g h^3/8.  Along one pixel edge there are 1/h such sub-pixels,
    # and a pixel has 4 edges, so |error| <= h^2/2 max|grad psf| (+ O(h^3)).  For the
    # circular Gaussian max|grad| = exp(-1/2) / (2 pi sigma^3).
    h = 1.0 / os_
    bound = h * h / 2 * math.exp(-0.5) / (2 * math.pi * sigma ** 3)
    worst = 0.0
    for _ in range(8):
        x0, y0 = rng.uniform(18, 22, 2)
        img, _ = render_point_sources((40, 40), x0, y0, 1.0, psf)
        exact = gauss_image((40, 40), x0, y0, 1.0, sigma)
        worst = max(worst, np.max(np.abs(img - exact)))
        assert img.sum() == pytest.approx(1.0, abs=1e-12)
        cx, cy = centroid(img)
        # overlap weights are linear in position: first moments are exact
        assert abs(cx - x0) < 1e-9 and abs(cy - y0) < 1e-9
    # 10 % margin for the O(h^3) terms neglected in the bound
    assert worst <= 1.1 * bound


def test_image_psf_partly_off_array_and_truncated_image():
    data = gaussian_subpixel_image(2.0, 4, npix=15)
    psf = ImagePSF(data, oversample=4)
    # aligned position at the left edge: columns x >= 0 receive the sub-pixels whose
    # centres (x0 + (j - 29.5)/4) lie right of -0.5
    x0, y0 = 0.25, 10.0
    img, info = render_point_sources((21, 21), x0, y0, 1.0, psf)
    centres = x0 + (np.arange(60) - 29.5) / 4
    frac = data[:, centres > -0.5].sum()
    assert img.sum() == pytest.approx(frac, abs=1e-13)
    assert info["frac_on_array"][0] == pytest.approx(frac, abs=1e-13)
    # normalize=False: a truncated image's deficit is reported as stamp loss
    cut = data[8:-8, 8:-8]
    psf2 = ImagePSF(cut, oversample=4, normalize=False)
    img2, info2 = render_point_sources((21, 21), 10.3, 10.6, 100.0, psf2)
    assert img2.sum() == pytest.approx(100.0 * cut.sum(), rel=1e-12)
    assert info2["flux_lost_stamp"][0] == pytest.approx(100.0 * (1 - cut.sum()), rel=1e-9)


def test_image_psf_to_photutils_matches_at_aligned_positions():
    data = gaussian_subpixel_image(2.5, 4, npix=12)
    psf = ImagePSF(data, oversample=4)
    # photutils interpolates its ePSF exactly at its nodes, which fall on pixel
    # centres when the sub-pixel centres do: x0 - (47/2)/4 on the quarter-pixel grid
    x0, y0 = 15.125, 14.625
    img, _ = render_point_sources((30, 30), x0, y0, 7.0, psf)
    yy, xx = np.indices((30, 30))
    model = psf.to_photutils(flux=7.0, x_0=x0, y_0=y0)
    assert np.max(np.abs(model(xx, yy) - img)) <= 1e-12 * 7.0


def test_image_psf_value_semantics_and_fits(tmp_path):
    data = gaussian_subpixel_image(2.0, 2, npix=9)
    psf = ImagePSF(data, oversample=2)
    same = ImagePSF(data.copy(), oversample=2)
    assert psf == same and hash(psf) == hash(same)
    assert psf != ImagePSF(data, oversample=1)
    assert pickle.loads(pickle.dumps(psf)) == psf
    assert not psf.data.flags.writeable
    with pytest.raises(ValueError):
        psf.data[0, 0] = 1.0
    assert {psf, same} == {psf}
    path = tmp_path / "psf.fits"
    hdu = fits.PrimaryHDU(data)
    hdu.header["OVERSAMP"] = 2
    hdu.writeto(path)
    assert ImagePSF.from_fits(path) == psf
    assert ImagePSF.from_fits(path, oversample=2) == psf
    with pytest.raises(ParameterError, match="OVERSAMP"):
        ImagePSF.from_fits(path, oversample=4)
    with pytest.raises(FileFormatError, match="does not exist"):
        ImagePSF.from_fits(tmp_path / "missing.fits")
    # OVERSAMP = T (a boolean) was taken as 1
    hdu.header["OVERSAMP"] = True
    hdu.writeto(tmp_path / "bool.fits")
    with pytest.raises(FileFormatError, match="OVERSAMP = True is not an integer"):
        ImagePSF.from_fits(tmp_path / "bool.fits")


def test_encircled_energy_gaussian_and_image():
    g = GaussianPSF(fwhm=3.0)
    r = np.array([0.5, 1.0, 2.0, 4.0])
    assert np.allclose(encircled_energy(g, r), 1 - np.exp(-r ** 2 / (2 * g.sigma ** 2)),
                       rtol=0, atol=1e-15)
    os_ = 8
    img = ImagePSF(gaussian_subpixel_image(3.0, os_, npix=21), oversample=os_)
    # The exact circle/sub-pixel overlap treats each sub-pixel's flux as uniform; with
    # the same straddling argument as above, along a circle of length 2 pi r the error
    # is <= 2 pi r h^2/8 max|grad psf| = 2 pi r h^2/8 exp(-1/2)/(2 pi sigma^3).
    h = 1.0 / os_
    tol = 2 * np.pi * r * h * h / 8 * math.exp(-0.5) / (2 * math.pi * g.sigma ** 3)
    assert np.all(np.abs(encircled_energy(img, r) - encircled_energy(g, r)) <= tol)


# --------------------------------------------------------------------- bad input
def test_bad_inputs_raise_parameter_error():
    data = gaussian_subpixel_image(2.0, 4, npix=9)
    with pytest.raises(ParameterError, match="sums to .* normalize=True"):
        ImagePSF(data * 0.9, oversample=4)
    with pytest.raises(ParameterError, match="photutils ePSF"):
        ImagePSF(data * 16, oversample=4)
    rescaled = ImagePSF.normalized(data * 0.9, oversample=4)
    assert rescaled.data.sum() == pytest.approx(1.0, abs=1e-15)
    assert np.allclose(rescaled.data, data / data.sum(), rtol=1e-14, atol=0)
    with pytest.raises(ParameterError, match="> 1"):
        ImagePSF(data * 1.5, oversample=4, normalize=False)
    with pytest.raises(ParameterError, match=">= 0"):
        ImagePSF(data - 0.01, oversample=4, normalize=False)
    with pytest.raises(ParameterError, match="fwhm"):
        GaussianPSF(fwhm=-1.0)
    with pytest.raises(ParameterError, match="radius"):
        AiryPSF(radius=0.0)
    with pytest.raises(ParameterError, match="oversample"):
        ImagePSF(data, oversample=0)
    psf = GaussianPSF(2.0)
    with pytest.raises(ParameterError, match="'x' must be finite"):
        render_point_sources((10, 10), [1.0, np.nan], [1.0, 2.0], [1.0, 1.0], psf)
    with pytest.raises(ParameterError, match="'y' must be finite"):
        render_point_sources((10, 10), 1.0, np.inf, 1.0, psf)
    with pytest.raises(ParameterError, match="flux"):
        render_point_sources((10, 10), 1.0, 1.0, -5.0, psf)
    with pytest.raises(ParameterError, match="min_rate"):
        render_point_sources((10, 10), 1.0, 1.0, 5.0, psf, min_rate=-1.0)
    with pytest.raises(ParameterError, match="shape"):
        render_point_sources((10,), 1.0, 1.0, 5.0, psf)
    with pytest.raises(ParameterError, match="psf"):
        render_point_sources((10, 10), 1.0, 1.0, 5.0, "gaussian")
    with pytest.raises(ParameterError, match="radius"):
        encircled_energy(psf, -1.0)


def test_blind_pixels_get_nothing_and_count_as_off_the_array():
    """The truth's SOURCES counted as 'on the array' the flux that fell on reference
    pixels, which collect nothing: two stars at the 4-pixel border put 772 e-/s into
    the rate map and reported 1975 e-/s on the array."""
    psf = GaussianPSF(fwhm=3.0)
    blind = np.zeros((64, 64), bool)
    blind[:, :4] = True
    img, info = render_point_sources((64, 64), [4.0, 2.0, 30.0], [30.0, 40.0, 30.0],
                                     [1000.0, 1000.0, 1000.0], psf, blind=blind)
    assert not img[blind].any()
    full, _ = render_point_sources((64, 64), [4.0, 2.0, 30.0], [30.0, 40.0, 30.0],
                                   [1000.0, 1000.0, 1000.0], psf)
    np.testing.assert_array_equal(img[~blind], full[~blind])
    # each star's reported flux is what it put into the image (one star at a time)
    for k in range(3):
        one, i1 = render_point_sources((64, 64), [[4.0, 2.0, 30.0][k]],
                                       [[30.0, 40.0, 30.0][k]], [1000.0], psf, blind=blind)
        assert i1["flux_on_array"][0] == pytest.approx(one.sum(), rel=1e-12)
        assert info["flux_on_array"][k] == pytest.approx(one.sum(), rel=1e-12)
    assert info["flux_on_array"][2] == pytest.approx(1000.0, rel=1e-6)
    assert info["flux_on_array"][:2].sum() < 0.5 * 2000.0
