"""Up-the-ramp slope fitting: CDS, equal-weight least squares and optimal GLS.

Modules, in the order a newcomer reads them:

* :mod:`~scenesim.rampfit.covariance`: the covariance model of the rate estimates
  (Brandt 2024), :class:`RampCovariance`;
* :mod:`~scenesim.rampfit.fitter`: :func:`fit_ramps`, the fitters as one weighted
  mean, saturation and short ramps, by row blocks of an array or of a file
  (:mod:`scenesim.io.cuberows`);
* :mod:`~scenesim.rampfit.solver`: the tridiagonal ``L D L^T`` solves vectorised
  over pixels, and the row chunks they run on;
* :mod:`~scenesim.rampfit.jumps`: jump detection (GLS score statistics);
* :mod:`~scenesim.rampfit.local_rate`: the rate of the reported Poisson variance;
* :mod:`~scenesim.rampfit.variance`: theoretical variances and the model
  chi-square of any rate;
* :mod:`~scenesim.rampfit.times`: validation of the read times.

The result, :class:`scenesim.io.fitfile.FitResult`, and its file live in
:mod:`scenesim.io.fitfile`; the DQ bits in :mod:`scenesim.detector.dq`; the noise
estimated from the data (common mode, effective read noise) in
:mod:`scenesim.calib.noise_model`.  Read noise is always per read, in e- (not CDS).
"""

from scenesim.rampfit.covariance import RATE_FLOOR, RampCovariance
from scenesim.rampfit.fitter import FITTERS, VARIANCE_RATES, fit_ramps
from scenesim.rampfit.jumps import flag_jumps, jump_statistics
from scenesim.rampfit.local_rate import local_rate
from scenesim.rampfit.times import check_read_times
from scenesim.rampfit.variance import (model_chi2, ols_variance, optimal_variance,
                                       rauscher2007_variance)

__all__ = ["FITTERS", "VARIANCE_RATES", "fit_ramps", "RampCovariance", "RATE_FLOOR",
           "flag_jumps", "jump_statistics", "local_rate", "check_read_times",
           "model_chi2", "ols_variance", "optimal_variance", "rauscher2007_variance"]
