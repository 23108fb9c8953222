"""Tests of :mod:`scenesim.io.fitfile`: a fit written and read back bit for bit.

Ramps and reference variances come from ``tests/ramp_sim.py`` (built from the read
times alone, independently of the simulator and of the package's formulas).
"""

import os

import numpy as np
import pytest
from astropy.io import fits

from noise.errors import FileFormatError, ParameterError
from ramp_sim import SIGMA, jwst_times, simulate
from scenesim.io.fitfile import FitResult, read_fit, write_fit
from scenesim.rampfit import fit_ramps


def test_write_read_roundtrip(tmp_path):
    times = jwst_times(4)
    rng = np.random.default_rng(17)
    res = simulate(rng, 3.0, times, SIGMA, (6, 5), nints=2)
    g = fit_ramps(res, times, read_noise=SIGMA, gain=2.0)
    path = tmp_path / "fit.fits"
    write_fit(path, g, header_cards=[("DETECTOR", "H2RG", "detector")])
    assert os.listdir(tmp_path) == ["fit.fits"]     # no temporary file left
    back = read_fit(path)
    assert isinstance(back, FitResult) and back.fitter == "gls" and back.gain == 2.0
    for key in ("slope", "var_read", "var_poisson", "chi2", "dof", "dq", "slope_ints",
                "var_ints", "n_jumps"):
        np.testing.assert_array_equal(getattr(back, key), getattr(g, key))
    with fits.open(path) as hdul:
        hdr = hdul[0].header
        assert hdr["RNOISE"] == SIGMA and "NOT CDS" in hdr.comments["RNOISE"]
        assert hdr["BUNIT"] == "e-/s" and hdr["DETECTOR"] == "H2RG"
        np.testing.assert_allclose(hdul["SLOPE_DN"].data, g.slope / 2.0, rtol=1e-6)
        assert hdul["SLOPEINT"].data.shape == (2, 6, 5)
        assert hdul["DQ"].data.dtype == np.uint32
    with pytest.raises(ParameterError, match="exists"):
        write_fit(path, g, overwrite=False)
    with pytest.raises(FileFormatError):
        read_fit(tmp_path / "missing.fits")
    fits.PrimaryHDU(np.zeros(3)).writeto(tmp_path / "other.fits")
    with pytest.raises(FileFormatError, match="missing"):
        read_fit(tmp_path / "other.fits")
