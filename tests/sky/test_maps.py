"""Tests of scenesim.sky.maps: the one loader of per-pixel maps (the run's)."""

import numpy as np
import pytest
from astropy.io import fits

from noise.clock import preset
from noise.errors import FileFormatError, ParameterError
from scenesim.sky.maps import check_map_file, load_map


@pytest.fixture
def window():
    """A 4 x 5 read-out window of an H1RG (full array 1024 x 1024)."""
    return preset("H1RG").window(x0=100, y0=200, nx=5, ny=4)


def test_scalar_and_read_out_shaped_map(tmp_path, window):
    value = load_map(0.02, window, name="dark_current")
    assert isinstance(value, np.float64) and value == 0.02
    arr = np.arange(20, dtype=np.float32).reshape(4, 5)
    path = tmp_path / "bg.fits"
    fits.PrimaryHDU(arr).writeto(path)
    got = load_map(str(path), window, name="background")
    assert got.dtype == np.float64 and got.flags.c_contiguous
    assert np.array_equal(got, arr)
    # the first 2-D image is used, after an empty primary HDU
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(arr * 2)]).writeto(tmp_path / "e.fits")
    assert np.array_equal(load_map(str(tmp_path / "e.fits"), window, name="flat"), arr * 2)


def test_full_frame_map_is_cut_to_the_window(tmp_path):
    det = preset("H1RG").window(x0=100, y0=200, nx=32, ny=16)
    full = np.add.outer(np.arange(1024.0) * 1e-3, np.arange(1024.0) * 1e-6)
    path = tmp_path / "dark_full.fits"
    fits.PrimaryHDU(full).writeto(path)
    m = load_map(str(path), det, name="dark_current")
    assert np.array_equal(m, full[200:216, 100:132]) and m.flags.c_contiguous
    check_map_file("dark_current", str(path), det)           # header check agrees
    fits.PrimaryHDU(full[:10]).writeto(tmp_path / "cut.fits")
    for check in (lambda p: load_map(p, det, name="dark_current"),
                  lambda p: check_map_file("dark_current", p, det)):
        with pytest.raises(FileFormatError,
                           match=r"'dark_current' map .*cut.fits' has shape \(10, 1024\) "
                                 r"\(ny, nx\); expected the full array \(1024, 1024\) or "
                                 r"the read-out shape \(16, 32\)"):
            check(str(tmp_path / "cut.fits"))


def test_bad_values_name_the_parameter_and_pixel(tmp_path, window):
    with pytest.raises(ParameterError, match=r"'dark_current' must be finite and >= 0, "
                                             r"got -0.1"):
        load_map(-0.1, window, name="dark_current")
    with pytest.raises(ParameterError, match=r"'full_well' must be finite and > 0"):
        load_map(0.0, window, name="full_well", allow_zero=False)
    bad = np.ones((4, 5))
    bad[1, 2] = np.nan
    fits.PrimaryHDU(bad).writeto(tmp_path / "nan.fits")
    with pytest.raises(ParameterError, match=r"'background' map .* 1 pixels are not, "
                                             r"e.g. \[1, 2\] = nan"):
        load_map(str(tmp_path / "nan.fits"), window, name="background")
    bad[1, 2] = -1.0
    fits.PrimaryHDU(bad).writeto(tmp_path / "neg.fits")
    with pytest.raises(ParameterError, match=r"'background' map .*\[1, 2\] = -1.0"):
        load_map(str(tmp_path / "neg.fits"), window, name="background")
    with pytest.raises(FileFormatError, match="does not exist"):
        load_map("/nonexistent/map.fits", window, name="background")
    (tmp_path / "map.txt").write_text("1 2 3")
    with pytest.raises(FileFormatError, match="must have one of the extensions"):
        load_map(str(tmp_path / "map.txt"), window, name="background")
