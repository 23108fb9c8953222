"""Tests of scenesim.sky.sources: catalogue reading and hot pixels."""

import math

import numpy as np
import pytest
from astropy import units as u
from astropy.table import Table

from noise.clock import preset
from noise.errors import FileFormatError, ParameterError
from scenesim.sky.sources import draw_hot_pixels, read_catalogue


# --------------------------------------------------------------------- catalogues
def test_read_catalogue_ecsv_and_fits_case_insensitive(tmp_path):
    tab = Table({"X": [1.5, 2.5], "Y": [3.0, 4.0], "FLUX": [10.0, 20.0],
                 "mag": [15.0, 16.0]})
    for name in ("cat.ecsv", "cat.fits"):
        path = tmp_path / name
        tab.write(path)
        cat = read_catalogue(path)
        assert cat.colnames[:4] == ["id", "x", "y", "flux"]
        assert list(cat["id"]) == [0, 1]
        assert np.array_equal(cat["x"], [1.5, 2.5])
        assert np.array_equal(cat["flux"], [10.0, 20.0])
        assert np.array_equal(cat["mag"], [15.0, 16.0])     # extra columns kept
    cat = read_catalogue(tab)                                 # in-memory table
    assert np.array_equal(cat["y"], [3.0, 4.0])


def test_read_catalogue_units_ids_and_light_curve_names(tmp_path):
    # The light_curve column holds names of the scene's [sources.light_curves.NAME]
    # entries, kept as written (stripped); an empty entry means constant.
    tab = Table({"id": [7, 9], "x": [1.0, 2.0], "y": [1.0, 2.0],
                 "flux": [60.0, 120.0] * u.electron / u.min,
                 "light_curve": [" transit ", ""]})
    path = tmp_path / "cat.ecsv"
    tab.write(path)
    cat = read_catalogue(path)
    assert np.allclose(cat["flux"], [1.0, 2.0])               # e-/min -> e-/s
    assert list(cat["id"]) == [7, 9]
    assert list(cat["light_curve"]) == ["transit", ""]
    # FITS stores the empty string as a missing value: also "constant"
    tab["flux"] = [1.0, 2.0]             # FITS cannot store the unit e-/min
    tab.write(tmp_path / "cat.fits")
    assert list(read_catalogue(tmp_path / "cat.fits")["light_curve"]) == ["transit", ""]
    # without the column every source is constant
    plain = read_catalogue(Table({"x": [1.0], "y": [1.0], "flux": [1.0]}))
    assert list(plain["light_curve"]) == [""]
    bad = Table({"x": [1.0], "y": [1.0], "flux": [1.0] * u.m})
    with pytest.raises(FileFormatError, match="unit"):
        read_catalogue(bad)


def test_read_catalogue_errors(tmp_path):
    path = tmp_path / "nofux.ecsv"
    Table({"x": [1.0], "Y": [2.0]}).write(path)
    with pytest.raises(FileFormatError) as exc:
        read_catalogue(path)
    assert "flux" in str(exc.value) and "nofux.ecsv" in str(exc.value)
    assert "did you mean" not in str(exc.value)         # nothing close to flux
    with pytest.raises(FileFormatError, match="does not exist"):
        read_catalogue(tmp_path / "missing.ecsv")
    with pytest.raises(ParameterError, match="flux"):
        read_catalogue(Table({"x": [1.0, 2.0], "y": [1.0, 2.0], "flux": [1.0, -1.0]}))
    with pytest.raises(ParameterError, match="flux"):
        read_catalogue(Table({"x": [1.0], "y": [1.0], "flux": [np.nan]}))
    with pytest.raises(ParameterError, match="'x'"):
        read_catalogue(Table({"x": [np.inf], "y": [1.0], "flux": [1.0]}))
    with pytest.raises(ParameterError, match="unique"):
        read_catalogue(Table({"id": [1, 1], "x": [1.0, 2.0], "y": [1.0, 2.0],
                              "flux": [1.0, 1.0]}))
    with pytest.raises(FileFormatError, match="numbers"):
        read_catalogue(Table({"x": ["a"], "y": [1.0], "flux": [1.0]}))
    with pytest.raises(FileFormatError, match="clash"):
        read_catalogue(Table({"x": [1.0], "X": [1.0], "y": [1.0], "flux": [1.0]}))


# --------------------------------------------------------------------- hot pixels
def test_hot_pixel_count_and_log_uniform_rates():
    det = preset("H2RG", naxis1=256, naxis2=256)
    ref = det.reference_mask()
    n_regular = int((~ref).sum())
    fraction, lo, hi = 0.02, 0.1, 100.0
    hot = draw_hot_pixels(det.shape, fraction, rate=(lo, hi), rng=301, refmask=ref)
    k = int((hot > 0).sum())
    # k ~ Binomial(n, f): 5 sigma with sigma = sqrt(n f (1 - f))
    assert abs(k - n_regular * fraction) <= 5 * math.sqrt(n_regular * fraction * (1 - fraction))
    assert not hot[ref].any()
    rates = hot[hot > 0]
    assert rates.min() >= lo and rates.max() <= hi
    # ln(rate) ~ Uniform(ln lo, ln hi): mean (a + b)/2, sd (b - a)/sqrt(12); the
    # sample mean's sigma is sd/sqrt(k) and the sample variance's is about
    # sd^2 * sqrt(4/(5 k)) (uniform: mu4 = 9/5 sd^4, Var(s^2) = (mu4 - sd^4)/k).
    a, b = math.log(lo), math.log(hi)
    sd = (b - a) / math.sqrt(12)
    logs = np.log(rates)
    assert abs(logs.mean() - (a + b) / 2) <= 5 * sd / math.sqrt(k)
    assert abs(logs.var(ddof=1) - sd ** 2) <= 5 * sd ** 2 * math.sqrt(0.8 / k)


def test_hot_pixels_scalar_rate_limits_and_seeding():
    hot = draw_hot_pixels((64, 64), 0.1, rate=5.0, rng=302)
    assert set(np.unique(hot)) == {0.0, 5.0}
    assert np.array_equal(hot, draw_hot_pixels((64, 64), 0.1, rate=5.0, rng=302))
    assert not draw_hot_pixels((64, 64), 0.0, rate=5.0, rng=303).any()
    ref = np.zeros((8, 8), bool)
    ref[:2] = True
    all_hot = draw_hot_pixels((8, 8), 1.0, rate=1.0, rng=304, refmask=ref)
    assert np.all(all_hot[~ref] == 1.0) and not all_hot[ref].any()


def test_a_window_has_the_hot_pixels_of_the_full_frame():
    # Hot pixels are pixels of the detector: drawn on the read-out image, a window
    # had other ones than the full frame of the same detector and seed.  Now the
    # window's map is the full frame's, cut (rates included), for an interior
    # window, one on the reference border, and a stripe.
    from noise.streams import HOT_PIXELS, generator
    det = preset("H2RG", naxis1=256, naxis2=256)
    kw = dict(rate=(0.1, 100.0), refmask=det.reference_mask())
    full = draw_hot_pixels(det.shape, 0.05, rng=generator(7, HOT_PIXELS), detector=det,
                           **kw)
    assert full.any()
    for x0, y0, nx, ny in ((64, 40, 64, 32), (0, 0, 30, 20), (0, 100, 256, 16)):
        win = det.window(x0, y0, nx, ny)
        cut = draw_hot_pixels(win.shape, 0.05, rng=generator(7, HOT_PIXELS),
                              detector=win, rate=(0.1, 100.0),
                              refmask=win.reference_mask())
        assert np.array_equal(cut, full[y0:y0 + ny, x0:x0 + nx])


def test_hot_pixels_bad_input():
    with pytest.raises(ParameterError, match="fraction"):
        draw_hot_pixels((8, 8), 1.5, rate=1.0, rng=0)
    with pytest.raises(ParameterError, match="rate"):
        draw_hot_pixels((8, 8), 0.1, rate=(5.0, 1.0), rng=0)
    with pytest.raises(ParameterError, match="rate"):
        draw_hot_pixels((8, 8), 0.1, rate=0.0, rng=0)
    with pytest.raises(ParameterError, match="refmask"):
        draw_hot_pixels((8, 8), 0.1, rate=1.0, rng=0, refmask=np.zeros((4, 4), bool))
