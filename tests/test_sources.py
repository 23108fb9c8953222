"""Tests of scenesim.sky.sources: catalogue reading, rate maps and hot pixels."""

import math
import os

import numpy as np
import pytest
from astropy import units as u
from astropy.io import fits
from astropy.table import Table

from noise.clock import preset
from noise.errors import FileFormatError, ParameterError
from scenesim.sky.sources import draw_hot_pixels, read_catalogue, uniform_or_map


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


def test_read_catalogue_units_ids_and_light_curves(tmp_path):
    tab = Table({"id": [7, 9], "x": [1.0, 2.0], "y": [1.0, 2.0],
                 "flux": [60.0, 120.0] * u.electron / u.min,
                 "light_curve": ["lc/a.ecsv", ""]})
    path = tmp_path / "cat.ecsv"
    tab.write(path)
    cat = read_catalogue(path)
    assert np.allclose(cat["flux"], [1.0, 2.0])               # e-/min -> e-/s
    assert list(cat["id"]) == [7, 9]
    assert cat["light_curve"][0] == os.path.join(str(tmp_path), "lc/a.ecsv")
    assert cat["light_curve"][1] == ""
    bad = Table({"x": [1.0], "y": [1.0], "flux": [1.0] * u.m})
    with pytest.raises(FileFormatError, match="unit"):
        read_catalogue(bad)


def test_read_catalogue_errors(tmp_path):
    path = tmp_path / "nofux.ecsv"
    Table({"x": [1.0], "Y": [2.0]}).write(path)
    with pytest.raises(FileFormatError) as exc:
        read_catalogue(path)
    assert "flux" in str(exc.value) and "nofux.ecsv" in str(exc.value)
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


# ---------------------------------------------------------------------- rate maps
def test_uniform_or_map_scalar_array_and_fits(tmp_path):
    m = uniform_or_map(0.02, (4, 5), "dark_current")
    assert m.shape == (4, 5) and m.dtype == np.float64 and np.all(m == 0.02)
    arr = np.arange(20, dtype=np.float32).reshape(4, 5)
    path = tmp_path / "bg.fits"
    fits.PrimaryHDU(arr).writeto(path)
    assert np.array_equal(uniform_or_map(path, (4, 5), "background"), arr)
    assert np.array_equal(uniform_or_map(arr, (4, 5), "background"), arr)
    with pytest.raises(ParameterError, match=r"'background'.*shape \(4, 5\)"):
        uniform_or_map(path, (5, 4), "background")


def test_uniform_or_map_full_frame_cut_to_subarray(tmp_path):
    det = preset("H1RG").window(x0=100, y0=200, nx=32, ny=16)
    full = np.add.outer(np.arange(1024.0) * 1e-3, np.arange(1024.0) * 1e-6)
    path = tmp_path / "dark_full.fits"
    fits.PrimaryHDU(full).writeto(path)
    m = uniform_or_map(path, det.shape, "dark_current", detector=det)
    assert np.array_equal(m, full[200:216, 100:132])
    with pytest.raises(ParameterError, match="full frame"):
        uniform_or_map(full[:10], det.shape, "dark_current", detector=det)


def test_uniform_or_map_bad_values():
    with pytest.raises(ParameterError, match="'dark_current'"):
        uniform_or_map(-0.1, (3, 3), "dark_current")
    bad = np.ones((3, 3))
    bad[1, 2] = np.nan
    with pytest.raises(ParameterError, match=r"'background'.*y=1, x=2"):
        uniform_or_map(bad, (3, 3), "background")
    bad[1, 2] = -1.0
    with pytest.raises(ParameterError, match="'background'"):
        uniform_or_map(bad, (3, 3), "background")
    with pytest.raises(FileFormatError, match="does not exist"):
        uniform_or_map("/nonexistent/map.fits", (3, 3), "background")


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


def test_hot_pixels_bad_input():
    with pytest.raises(ParameterError, match="fraction"):
        draw_hot_pixels((8, 8), 1.5, rate=1.0, rng=0)
    with pytest.raises(ParameterError, match="rate"):
        draw_hot_pixels((8, 8), 0.1, rate=(5.0, 1.0), rng=0)
    with pytest.raises(ParameterError, match="rate"):
        draw_hot_pixels((8, 8), 0.1, rate=0.0, rng=0)
    with pytest.raises(ParameterError, match="refmask"):
        draw_hot_pixels((8, 8), 0.1, rate=1.0, rng=0, refmask=np.zeros((4, 4), bool))
