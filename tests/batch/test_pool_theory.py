"""Pooled statistics of real realisations against theory (no dask: the tasks run in
this process, one after the other, exactly as a worker runs them).

The scene makes every pixel independent of every other and of the other
realisations: white read noise only (``[noise] preset = "none"``, no 1/f, no
reference correction), Poisson arrivals at one uniform rate, no cosmic rays, RAPID
single-frame resultants.  Then, with ``K`` realisations of ``n`` pixels:

* OLS (equal weights on a straight ramp) is unbiased whatever the noise, and so is
  GLS with weights that do not depend on the pixel's own noise: the pooled bias is 0
  within its standard error (5 sigma of the estimator; the jackknife ratio is a
  Student t with K - 1 degrees of freedom, P(|t_31| > 5) = 2e-5);
* the realisation means ``b_k`` are independent draws of variance ``s**2 / n``
  (``s`` the pixel scatter), so ``(K - 1) var_k(b_k) / (s**2 / n)`` is chi-square
  with ``K - 1`` degrees of freedom: the jackknife standard error over the
  pixel-count one, squared, lies within the chi-square's 5-sigma quantiles / (K - 1);
* the scatter of OLS against the optimum is ``sqrt(V_ols / V_opt)``, computed here
  from the covariance of the reads (read noise on the diagonal, ``rate *
  min(t_i, t_j)`` from the Poisson arrivals); GLS reaches the optimum (1).  At this
  rate (shot noise 43 e- per read difference against 10 e- read noise) they differ by
  ~10 standard errors of the scatter.
"""

import math

import numpy as np
import pytest
from astropy.io import fits
from scipy.stats import chi2, norm

from scenesim.batch.plan import plan_batch
from scenesim.batch.pool import pool_reports
from scenesim.batch.tasks import run_task

K = 32                 # realisations
RATE = 1.0e5           # e-/s, every pixel
READ_NOISE = 10.0      # e- per read
NGROUPS = 6

WHITE_SCENE = f"""\
seed = 4242
[detector]
preset = "H2RG"
naxis1 = 64
naxis2 = 64
[noise]
preset = "none"
rd_noise = {READ_NOISE}
bias_offset = 5000.0        # the ramps stay clear of the ADC's 0 (no clipping)
[readout]
pattern = "RAPID"
ngroups = {NGROUPS}
[sources]
dark_current = 0.0
background = {RATE}
[output]
path = "white.fits"
"""

#: two-sided tail probability of 5 sigma
P5 = 2 * norm.sf(5.0)


@pytest.fixture(scope="module")
def pooled(tmp_path_factory):
    """``({fitter: pool_reports}, frame time s)`` of K realisations, OLS and GLS."""
    root = tmp_path_factory.mktemp("white")
    scene = root / "white.toml"
    scene.write_text(WHITE_SCENE)
    plan = plan_batch(scene, out=root / "out", realisations=K, fit=["ols", "gls"],
                      compare=True, ramp=False, refpix="none")
    (root / "out").mkdir()
    records = [run_task(t) for t in plan.tasks()]
    tframe = fits.getheader(plan.tasks()[0].path["truth"])["TFRAME"]
    return {f: pool_reports([r["reports"][f] for r in records])
            for f in ("ols", "gls")}, tframe


def _row(pooled_one):
    rows = [r for r in pooled_one["rows"] if r["n_real"]]
    assert len(rows) == 1 and rows[0]["n_real"] == K     # one rate: one bin
    return rows[0]


def _ols_over_opt(tframe):
    """sqrt(V_ols / V_opt) of the slope of NGROUPS single reads, one frame apart.

    Reads y_i = c + N(t_i) + e_i: Poisson counts N (covariance rate * min(t_i, t_j),
    times from the first read; the counts before it are in the intercept) and white
    read noise e_i.  V_ols = w^T C w with the least-squares weights w; V_opt the
    slope element of (X^T C^-1 X)^-1.
    """
    t = tframe * np.arange(NGROUPS)
    cov = RATE * np.minimum.outer(t, t) + READ_NOISE ** 2 * np.eye(NGROUPS)
    w = (t - t.mean()) / np.sum((t - t.mean()) ** 2)
    v_ols = w @ cov @ w
    x = np.column_stack([np.ones(NGROUPS), t])
    v_opt = np.linalg.inv(x.T @ np.linalg.solve(cov, x))[1, 1]
    return math.sqrt(v_ols / v_opt)


@pytest.mark.parametrize("fitter", ["ols", "gls"])
def test_pooled_bias_of_an_unbiased_fitter_is_zero_within_its_error(pooled, fitter):
    row = _row(pooled[0][fitter])
    assert math.isfinite(row["bias_se"]) and row["bias_se"] > 0
    # 5 sigma of the estimator (Student t, K - 1 = 31 dof: false alarm 2e-5)
    assert abs(row["bias"]) < 5 * row["bias_se"], row


@pytest.mark.parametrize("fitter", ["ols", "gls"])
def test_standard_error_matches_the_spread_expected_of_independent_pixels(pooled,
                                                                          fitter):
    row = _row(pooled[0][fitter])
    ratio2 = (row["bias_se"] / row["bias_se_pixels"]) ** 2
    lo, hi = chi2.ppf(P5 / 2, K - 1) / (K - 1), chi2.isf(P5 / 2, K - 1) / (K - 1)
    # chi-square / dof with K - 1 = 31 dof, two-sided 5 sigma: [0.19, 2.8]; a standard
    # error off by sqrt(K) = 5.7 (or one taken from the pixel count when pixels are
    # correlated) falls far outside
    assert lo < ratio2 < hi, (ratio2, lo, hi)


def test_scatter_against_the_optimum(pooled):
    pools, tframe = pooled
    ols, gls = _row(pools["ols"]), _row(pools["gls"])
    theory = _ols_over_opt(tframe)
    # the rate is high enough that OLS is measurably worse than the optimum
    assert theory - 1 > 5 * ols["scatter_se"]
    # 5 standard errors of each scatter (jackknife over realisations).  The ADC's
    # rounding (gain 1: 1/12 e-^2 per read against 100 e-^2) moves them by < 0.1 of it.
    assert abs(ols["scatter"] - theory) < 5 * ols["scatter_se"], (ols["scatter"], theory)
    assert abs(gls["scatter"] - 1.0) < 5 * gls["scatter_se"], gls["scatter"]
    # the comparison's own closed form (per pixel, averaged) agrees with this one
    assert ols["ols_ratio"] == pytest.approx(theory, rel=1e-3)
    # no read is clipped or flagged here: the scatter within realisations is the
    # whole scatter (no common draw per realisation), to 5 of its errors
    assert abs(ols["scatter_within"] - ols["scatter"]) < 5 * ols["scatter_se"]
