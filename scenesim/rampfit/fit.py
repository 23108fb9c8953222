"""Up-the-ramp slope fitting: CDS, equal-weight least squares and optimal GLS.

Conventions
-----------
Resultants are in electrons (the caller multiplies DN by the gain and subtracts
nothing else), times in seconds from the pixel's reset, rates in e-/s.  The read
noise ``sigma`` is the noise of **one read** (one frame), in e-, never the CDS noise
(CDS noise = sqrt(2) sigma).  The JWST calibration library stcal instead takes the
CDS read noise in DN; convert with ``sigma = rnoise_cds_dn * gain / sqrt(2)``.

Model (Brandt 2024, PASP 136, 045004)
-------------------------------------
Resultant ``i`` averages ``N_i`` reads at times ``t_{i,1} < ... < t_{i,N_i}``.  With a
constant rate ``f`` the charge collected by time ``t`` is a Poisson process, so
``Cov(Q(t), Q(t')) = f min(t, t')``, and each read adds independent read noise of
variance ``sigma^2``.  Hence, with ``tbar_i`` the mean read time and
``tau_i = (1/N_i^2) sum_k (2 N_i - 2k + 1) t_{i,k}``::

    Var(R_i)            = sigma^2 / N_i + f tau_i
    Cov(R_i, R_j), i<j  = f tbar_i                   (all reads of i precede those of j)

The rate estimates ``d_i = (R_{i+1} - R_i) / dt_i`` (``dt_i = tbar_{i+1} - tbar_i``) have
a tridiagonal covariance ``C`` (Brandt 2024, eqs. 28-29)::

    alpha_i = [sigma^2 (1/N_i + 1/N_{i+1}) + f (tau_i + tau_{i+1} - 2 tbar_i)] / dt_i^2
    beta_i  = [-sigma^2 / N_{i+1} + f (tbar_{i+1} - tau_{i+1})] / (dt_i dt_{i+1})

and every ``d_i`` has mean ``f``.  The best linear unbiased estimate is the GLS mean
``f_hat = (1^T C^-1 d) / (1^T C^-1 1)`` with variance ``1 / (1^T C^-1 1)``
(:func:`optimal_variance`).  Differencing removes the unknown zero point (bias, kTC),
and the GLS estimate from differences equals the GLS estimate from resultants with a
free intercept.  Because the covariance only involves differences of times, a common
shift of all read times (a global reset) changes nothing.

Algorithm
---------
All fitters are one routine: a weighted mean of the ``d_i`` whose weights are
``W^-1 1 / (1^T W^-1 1)`` for a tridiagonal "weighting" matrix ``W``:

* ``'gls'``: ``W = C(f)`` -- optimal.  ``f`` is unknown, so it is iterated: start from
  the CDS estimate, clip at >= 0 for the covariance, re-solve ``n_iter`` times.
* ``'ols'``: ``W`` = covariance of differences of independent, equal-variance
  resultants (``2`` on the diagonal and ``-1`` off it, in charge units): this is
  exactly equal-weight least squares of the resultants against ``tbar`` with a free
  intercept (Rauscher et al. 2007).
* ``'cds'``: ``W = diag(1/dt_i)``: ``sum D_i / sum dt_i``, i.e. last minus first usable
  resultant over their ``tbar`` difference.

The tridiagonal systems are solved with an ``L D L^T`` (Thomas) recursion that loops
only over the resultant differences and is vectorised over pixels, in float32, in
row chunks run on a thread pool.  The same forward pass accumulates
``1^T W^-1 1``, ``1^T W^-1 y`` and ``y^T W^-1 y`` (``y = d - f_ref``, with ``f_ref``
the previous estimate, so the chi-square does not suffer from cancellation), and a
back substitution gives the weights, which are propagated through the model
covariance to split the variance into a read part (``sigma^2`` terms) and a Poisson
part (``f`` terms)::

    var_read = sigma^2 w^T C_read w,     var_poisson = r w^T C_poisson w

with ``r`` the *variance rate* (see "Reported variance" below; ``max(slope, 0)`` with
``variance_rate='fit'``).  For GLS with ``r = max(slope, 0)`` their sum is
``1 / (1^T C^-1 1)`` up to the last update of ``f``.

Unusable differences (after saturation, or containing a jump) are removed by
replacing their row and column of ``W`` by the identity: the matrix becomes block
diagonal, one block per usable segment, and the estimate is the inverse-variance
combination of the segment estimates with one common rate (so no pixel grouping is
needed, and pixels with different numbers of usable resultants share one vectorised
code path).  Integrations are further independent blocks with the same rate: GLS
solves them jointly (= inverse-variance weighting of the per-integration slopes with
one common ``f``); OLS and CDS combine their per-integration slopes with inverse
model variances evaluated at the joint rate (JWST style).

chi-square: ``chi2 = (d - f_hat)^T C^-1 (d - f_hat) / dof`` with ``dof = n_diff - 1``
(usable differences of all integrations minus one).  For GLS its expectation is 1;
for OLS and CDS it is ``1 + (V/V_opt - 1)/dof`` (slightly above 1).  ``chi2 = 0`` where
``dof <= 0``.  :func:`model_chi2` evaluates the same quantity for a rate from
elsewhere (e.g. another fitter's, as :mod:`scenesim.adapters.stcal` does).

Saturation, jumps and short ramps
---------------------------------
* Only resultants before the first saturated one are used.  DQ ``SATURATED`` is set
  when any resultant of the pixel is saturated (even if the slope is measured).
* Jumps (``jump_threshold`` in sigma), per integration: at the rate
  ``max(median(d), 0)`` (robust to the jumps themselves) each usable difference gets
  the GLS outlier statistic ``z_i = (C^-1 r)_i / sqrt((C^-1)_ii - (C^-1 1)_i^2 /
  (1^T C^-1 1))`` (``r`` the GLS residuals): the standardised score test for a jump
  in difference ``i``, exactly N(0, 1) without jumps for Gaussian noise whatever the
  readout (so a threshold ``k`` gives ``2 Q(k)`` false alarms per test).  The largest
  ``|z|`` above the threshold is flagged and excluded, and the test repeated on the
  pixels that had a flag (at most ``n_diff - 2`` passes).  Detection needs >= 3
  usable differences.  Excluding a difference splits the ramp into independent
  segments.  A hit during a multi-read resultant spreads over the two differences
  that use that resultant, so (i) each such pair is also tested, with the signature
  of a hit halfway through the resultant, and flagged as a whole when it is the
  larger excess; (ii) the differences next to a flagged span that share a
  multi-read resultant with it are excluded too, unconditionally (choosing them by
  their values would bias the slope; excluding them costs some precision in hit
  pixels only).  With single-read resultants (JWST NFRAMES=1) neither applies.
  ``n_jumps`` counts flagged differences.
* Two usable resultants: one difference, the CDS slope (all fitters agree).
* One usable resultant: the zero point (bias + reset level) is in the data and cannot
  be separated from the charge, so by default the pixel is ``DO_NOT_USE``.  If the
  caller knows it (``zero_point``, e.g. a superbias plus reset frame), the slope is
  ``(R_0 - zero_point) / tbar_0`` with variance ``(sigma^2 / N_0 + f tau_0)/tbar_0^2``
  (as stcal does for one-group ramps after its superbias step).  This is used only
  when no integration of the pixel has a usable difference.
* Unmeasured pixels (no usable difference and no usable single resultant, e.g. fully
  saturated): ``DO_NOT_USE`` (plus ``SATURATED`` if saturated), slope 0,
  ``var_read = BAD_VARIANCE`` (finite and huge, so inverse-variance weights vanish),
  ``var_poisson = 0``, ``chi2 = 0``, ``dof = 0``.  Never NaN.
* ``refmask`` pixels are fitted like the others but flagged
  ``REFERENCE_PIXEL | DO_NOT_USE`` (JWST practice).

Reported variance
-----------------
The slope is a weighted mean of the ``d_i``, and its variance
``V = V_read + q_p f`` (``q_p = w^T C_poisson w``) is linear in the unknown true
rate ``f``.  stcal and Brandt's fitramp evaluate it at the pixel's own fitted rate,
``V_hat = V_read + q_p max(f_hat, 0)``.  That makes ``V_hat`` correlated with the
error ``e = f_hat - f``: for Gaussian ``e`` of variance ``V``, by Stein's lemma
``E[e^2 / V_hat] ~ 1 + 3 kappa^2`` without the clip, ``kappa = q_p sqrt(V) / V`` being
the relative change of ``V_hat`` per standard deviation of the rate; the clip at 0
removes the low side, so at the lowest fluxes the mean falls below 1.  ``kappa^2``
is ``~1/counts`` where Poisson noise dominates (harmless) but reaches
``q_p^2 / V_read`` where read noise dominates: 20 JWST frames of 10.737 s with 10 e-
read noise give ``E[(f_hat - f)^2 / V_hat] = 0.93`` at 0.01 e-/s and 1.04 at
0.1 e-/s; the uneven 9-resultant table 0.91 and 1.08 (``expected_z2`` in the tests
computes these).

A rate that is *not* correlated with the pixel's own error removes the effect to
first order: the error of ``V_hat`` then only enters through Jensen's inequality,
``E[V / V_hat] - 1 ~ q_p^2 Var(r) / V^2``.  The default ``variance_rate='local'`` is
an empirical-Bayes estimate of that kind (:func:`local_rate`).  The prior mean of
the pixel's rate is the median ``m`` of its 24 neighbours in a 5 x 5 box (centre
excluded, so independent of the pixel's own noise; one clip at 4 robust sigma
leaves out isolated hot or hit neighbours, each of which would otherwise move the
median by ~0.1 sigma); its mean squared error is
``tau^2 + (pi/2) V_m / n``, with ``tau^2`` the spread of the neighbours' rates beyond
their noise, estimated from their interquartile range (``s = IQR / 1.349``) as
``max(s^2 - V_m (1 + 2 x 2.33 / sqrt(n)), 0)``: the noise variance ``V_m`` at rate
``m`` plus two standard errors of ``s^2`` (``2.33 sigma^2 / sqrt(n)``
asymptotically), so that flat regions do not read noise in ``s`` as structure.  The
variance rate is the posterior mean ``r = w max(f_hat, 0) + (1 - w) max(m, 0)``,
``w = MSE / (MSE + V_m)``: in flat regions ``w ~ 0`` (the neighbours' rate); at
sources, gradients and flat-field structure ``w -> 1`` (the pixel's own rate, where
``kappa`` is small because such pixels are bright).  A pixel 3 to 5 sigma away from
``m`` (hot pixel, unresolved source) moves linearly to ``w = 1``, as do pixels with
fewer than 8 usable neighbours; pixels with ``kappa^2 < 3e-3`` (own-rate error of
``E[z^2]``, ``3 kappa^2``, below 1 %) keep their own rate without the neighbourhood
sort.
Measured on 400 x 400 uniform pixels (tests), ``E[z^2]`` is 0.99-1.01 from 0.01 to
1e4 e-/s for both readouts and all fitters (own rate: 0.91-1.08).  The slopes do
not depend on ``r``: efficiency and bias are unchanged.  ``E[V_hat]`` exceeds ``V``
by < 1 % at 0.01 e-/s (the clip of ``m`` at 0).

Read noise from the data
------------------------
The model is white read noise per read.  Real data after reference correction also
carry noise common to many pixels: (i) per output and read (the 1/f noise of the
output's own amplifier, which the side reference columns of the outer outputs do
not see, and low frequencies that a stripe without reference rows cannot remove);
(ii) per row and read (the part of the 1/f banding that the row-wise reference
correction misses, larger the later the pixel is read within its row).  In one
pixel's ramp (ii) looks like extra white noise and (i) like a slow wander common to
the output.  The GLS jump statistic is a step test over the whole ramp (the score
test for a jump is powerful because it compares all reads before and after), so a
slow wander of a few tenths of the read noise reads as a step: on the cosmic-ray
scene (H2RG stripe, 60 RAPID groups) the statistic had variance 1.56 instead of 1,
almost all of it an offset per (output, difference) common to the output's pixels,
and 1-4 % of the clean pixels were flagged.

Two data-driven corrections, used by :func:`scenesim.calib.prepare.fit_exposure_file`:

* :func:`common_mode` estimates (i): after a first fit of a subsample of rows, the
  median over an output's read-noise dominated pixels of ``d_i - f_hat`` (robust to
  jumps and sources), minus its mean over ``i`` (a constant offset of the ``d_i`` is
  a rate, indistinguishable from a uniform background of the output, and is kept),
  summed into resultant offsets that are subtracted.  The slopes keep the mean of
  the common wander; the jump statistic and ``chi2`` lose the rest.
* :func:`measure_read_noise` estimates the effective white noise per column from the
  median ``chi2`` of read-noise dominated pixels, each normalised by the median of
  the chi-square distribution of its degrees of freedom (exactly 1 for a right
  model; the median is robust to the ramps with jumps): ``sigma_eff = k sigma``,
  ``k^2 = median(chi2 / med_nu)``, corrected to first order for the Poisson share
  and refined by a second fit at ``sigma_eff``.  On white-noise simulations it is
  within 1 % of the true noise whatever the starting value (up to 1 % low near
  zero rate, where the fit's covariance uses the clipped fitted rate, above the
  true one half of the time, so its ``chi2`` is slightly low).

With both, the cosmic-ray scene's false-positive rate fell to 0.03 % with all
1129 in-ramp hits above 10 sigma found, and the mean ``chi2`` per degree of freedom
went from 1.54 to 1.00.

Measured cost
-------------
One core (2-core machine, numpy 2.4, float32 input), GLS with 2 iterations, 20
resultants: 1024 x 1024 in 0.3 s and 2048 x 2048 in 1.25 s; with jump detection
(1 % of pixels hit) 1.1 s and 4.1 s.  The local variance rate adds nothing where
every pixel is bright enough (``kappa^2 < 3e-3``) and 0.6-0.8 s (2 threads, 1.1 s on
one) for 2048 x 2048 read-noise dominated pixels (one sort of 24 neighbours per
pixel).  Working memory beyond the outputs (36 bytes per
pixel per integration) is bounded by the row chunks: about 15 MiB per thread
(``_CHUNK_ELEMS`` float32 values per (nints, nres, pixels) array).  Row chunks run on
a thread pool (numpy releases the GIL in its loops).
"""

import math
import numbers
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from noise.errors import FileFormatError, ParameterError
from noise.fitsio import atomic_path

__all__ = [
    "DO_NOT_USE",
    "SATURATED",
    "JUMP_DET",
    "REFERENCE_PIXEL",
    "BAD_VARIANCE",
    "FITTERS",
    "VARIANCE_RATES",
    "FitResult",
    "fit_ramps",
    "model_chi2",
    "local_rate",
    "measure_read_noise",
    "common_mode",
    "NOISE_MIN_PIXELS",
    "write_fit",
    "read_fit",
    "optimal_variance",
    "ols_variance",
    "rauscher2007_variance",
]

#: DQ bits (JWST values).
DO_NOT_USE = 1
SATURATED = 2
JUMP_DET = 4
REFERENCE_PIXEL = 2 ** 31

#: Variance ((e-/s)^2) reported for unmeasured pixels: finite, huge, never NaN.
BAD_VARIANCE = 1e20

#: Fitter names accepted by :func:`fit_ramps`.
FITTERS = ("cds", "ols", "gls")

#: Read-noise dominated pixels a group needs for its own ``measure_read_noise`` value.
NOISE_MIN_PIXELS = 32

#: Named choices of the rate of the reported Poisson variance (:func:`fit_ramps`).
VARIANCE_RATES = ("local", "fit")

_F32 = np.float32
# Target number of float32 values per (nints, nres, pixels) chunk array: small enough
# for the per-difference vectors to stay in cache, large enough to amortise numpy's
# per-call overhead.
_CHUNK_ELEMS = 1 << 19
_TINY = 1e-30
_RATE_FLOOR = 1e-6
_JUMP_BLOCK = 4096
_LOCAL_HALF = 2          # 5 x 5 neighbourhood of the variance rate
_LOCAL_MIN = 8           # fewer usable neighbours: the pixel's own rate
_LOCAL_CLIP = 4.0        # neighbours beyond 4 robust sigma of their median are left out
_LOCAL_KAPPA2 = 3e-3     # own rate where (d var / d rate)^2 Var(rate) / var^2 is below
_IQR_SIGMA = 1.349       # interquartile range of a unit normal
_NOISE_RHO = 0.5         # read-noise dominated: Poisson / read variance of a difference
_NOISE_CONVERGED = 0.02  # a second chi2 pass unless every group's k^2 is within 2 % of 1
_CM_MAX_PIXELS = 16384   # pixels per group for the common-mode medians
_NOISE_K2_MIN = 0.01     # sigma_eff >= 0.1 sigma
_IQR_VAR = 2.33          # sd of (IQR / 1.349)^2 is 2.33 sigma^2 / sqrt(n) (asymptotic)


# ---------------------------------------------------------------------- result
@dataclass(frozen=True, eq=False)
class FitResult:
    """Slopes fitted to the ramps of one exposure.

    Attributes
    ----------
    slope : ndarray, shape (ny, nx), float32, e-/s
        Rate combined over integrations (0 where ``DO_NOT_USE``).
    var_read, var_poisson : ndarray, shape (ny, nx), float32, (e-/s)^2
        Read-noise and Poisson parts of the variance of ``slope``; the Poisson part
        is evaluated at the variance rate (module notes, "Reported variance").
    chi2 : ndarray, shape (ny, nx), float32
        chi-square of the rate estimates under the model covariance per degree of
        freedom (0 where ``dof == 0``).
    dof : ndarray, shape (ny, nx), int32
        Degrees of freedom: usable differences (all integrations) minus 1, >= 0.
    dq : ndarray, shape (ny, nx), uint32
        DQ bits ``DO_NOT_USE``, ``SATURATED``, ``JUMP_DET``, ``REFERENCE_PIXEL``.
    slope_ints : ndarray, shape (nints, ny, nx), float32, e-/s
        Per-integration rates (0 where an integration has no usable data).
    var_ints : ndarray, shape (nints, ny, nx), float32, (e-/s)^2
        Total variance of ``slope_ints`` (``BAD_VARIANCE`` where unmeasured), its
        Poisson part at the same variance rate as ``var_poisson``.
    n_jumps : ndarray, shape (ny, nx), int32
        Number of differences flagged as jumps (all integrations).
    gain : float
        Gain, e-/DN, used only to write ``SLOPE_DN``.
    read_noise : float
        Read noise, e- per read (not CDS); the median if a map was given.
    fitter : str
        ``'cds'``, ``'ols'`` or ``'gls'``.
    """

    slope: np.ndarray
    var_read: np.ndarray
    var_poisson: np.ndarray
    chi2: np.ndarray
    dof: np.ndarray
    dq: np.ndarray
    slope_ints: np.ndarray
    var_ints: np.ndarray
    n_jumps: np.ndarray
    gain: float
    read_noise: float
    fitter: str

    @property
    def var(self):
        """Total variance ``var_read + var_poisson``, (ny, nx) float32, (e-/s)^2."""
        return self.var_read + self.var_poisson

    @property
    def err(self):
        """Standard error ``sqrt(var)``, (ny, nx) float32, e-/s."""
        return np.sqrt(self.var)

    @property
    def slope_dn(self):
        """Rate in DN/s, ``slope / gain``, (ny, nx) float32."""
        return (self.slope / _F32(self.gain)).astype(_F32)

    def to_hdul(self, header_cards=()):
        """Return the fit as an :class:`astropy.io.fits.HDUList`.

        Parameters
        ----------
        header_cards : iterable of (key, value, comment)
            Extra cards for the primary header (e.g. ``Detector.to_header_cards()``).

        Returns
        -------
        astropy.io.fits.HDUList
            Primary header with ``FITTER``, ``GAIN``, ``RNOISE``, ``BUNIT`` and
            ``NINTS``; image extensions ``SLOPE`` (e-/s), ``SLOPE_DN`` (DN/s),
            ``VAR_READ``, ``VAR_POIS`` ((e-/s)^2), ``CHI2``, ``DQ``, ``SLOPEINT``
            (e-/s, per integration), ``VARINT`` ((e-/s)^2), ``DOF``, ``NJUMPS``.
        """
        from astropy.io import fits

        cards = _check_cards(header_cards)
        primary = fits.PrimaryHDU()
        hdr = primary.header
        hdr["FITTER"] = (self.fitter, "ramp fitter: cds, ols or gls")
        hdr["GAIN"] = (float(self.gain), "[e-/DN] gain used for SLOPE_DN")
        hdr["RNOISE"] = (float(self.read_noise),
                         "[e-] read noise per read (NOT CDS)")
        hdr["BUNIT"] = ("e-/s", "unit of SLOPE")
        hdr["NINTS"] = (int(self.slope_ints.shape[0]), "integrations combined")
        for key, value, comment in cards:
            hdr[key] = (value, comment)
        exts = [
            ("SLOPE", self.slope.astype(_F32), "e-/s"),
            ("SLOPE_DN", self.slope_dn, "DN/s"),
            ("VAR_READ", self.var_read.astype(_F32), "(e-/s)**2"),
            ("VAR_POIS", self.var_poisson.astype(_F32), "(e-/s)**2"),
            ("CHI2", self.chi2.astype(_F32), ""),
            ("DQ", self.dq.astype(np.uint32), ""),
            ("SLOPEINT", self.slope_ints.astype(_F32), "e-/s"),
            ("VARINT", self.var_ints.astype(_F32), "(e-/s)**2"),
            ("DOF", self.dof.astype(np.int32), ""),
            ("NJUMPS", self.n_jumps.astype(np.int32), ""),
        ]
        hdus = [primary]
        for name, data, unit in exts:
            hdu = fits.ImageHDU(data=data, name=name)
            if unit:
                hdu.header["BUNIT"] = unit
            hdus.append(hdu)
        return fits.HDUList(hdus)


def _check_cards(header_cards):
    try:
        cards = [tuple(c) for c in header_cards]
    except TypeError as exc:
        raise ParameterError(
            f"'header_cards' must be an iterable of (key, value, comment) tuples, "
            f"got {header_cards!r}") from exc
    for c in cards:
        if len(c) != 3 or not isinstance(c[0], str):
            raise ParameterError(
                f"'header_cards' entries must be (key, value, comment) with a str key, "
                f"got {c!r}")
    return cards


def write_fit(path, result, *, header_cards=(), overwrite=True):
    """Write a :class:`FitResult` to a FITS file atomically.

    The file is written to a temporary file in the same directory and moved into
    place with :func:`os.replace`, so no partial file is ever left at ``path``.

    Parameters
    ----------
    path : str or os.PathLike
        Output file.
    result : FitResult
    header_cards : iterable of (key, value, comment)
        Extra primary-header cards.
    overwrite : bool
        Replace an existing file.

    Returns
    -------
    str
        The path written.
    """
    from noise.validate import check_writable

    if not isinstance(result, FitResult):
        raise ParameterError(f"'result' must be a FitResult, got {type(result).__name__}")
    path = check_writable("path", path, overwrite=overwrite)
    hdul = result.to_hdul(header_cards)
    with atomic_path(path, overwrite=overwrite) as tmp:
        hdul.writeto(tmp, overwrite=True)
    return path


def read_fit(path):
    """Read a file written by :func:`write_fit` back into a :class:`FitResult`.

    Raises
    ------
    noise.errors.FileFormatError
        If the file is missing, unreadable or lacks an extension or keyword.
    """
    from astropy.io import fits

    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileFormatError(f"'path': fit file {path!r} does not exist")
    names = ("SLOPE", "VAR_READ", "VAR_POIS", "CHI2", "DQ", "SLOPEINT", "VARINT",
             "DOF", "NJUMPS")
    try:
        with fits.open(path, memmap=False) as hdul:
            hdr = hdul[0].header
            missing = [n for n in names if n not in hdul]
            missing += [k for k in ("FITTER", "GAIN", "RNOISE") if k not in hdr]
            if missing:
                raise FileFormatError(
                    f"{path!r} is not a scenesim fit file: missing {missing} "
                    f"(expected extensions {list(names)} and keywords FITTER, GAIN, "
                    f"RNOISE)")
            data = {n: np.array(hdul[n].data) for n in names}
            fitter, gain, rnoise = str(hdr["FITTER"]), float(hdr["GAIN"]), float(
                hdr["RNOISE"])
    except OSError as exc:
        raise FileFormatError(f"cannot read fit file {path!r}: {exc}") from exc
    return FitResult(
        slope=data["SLOPE"].astype(_F32), var_read=data["VAR_READ"].astype(_F32),
        var_poisson=data["VAR_POIS"].astype(_F32), chi2=data["CHI2"].astype(_F32),
        dof=data["DOF"].astype(np.int32), dq=data["DQ"].astype(np.uint32),
        slope_ints=data["SLOPEINT"].astype(_F32), var_ints=data["VARINT"].astype(_F32),
        n_jumps=data["NJUMPS"].astype(np.int32), gain=gain, read_noise=rnoise,
        fitter=fitter)


# ---------------------------------------------------------------------- readout
def _is_sequence(value):
    try:
        len(value)
        iter(value)
    except TypeError:
        return False
    return not isinstance(value, (str, bytes))


def _check_read_times(read_times, nres=None, image_shape=None):
    """Validate ``read_times``; return (list of 1-D float64 arrays, pixel shift or None).

    Entries may be 1-D (same for every pixel) or ``(n_r,) + image_shape`` (global
    reset); per-pixel entries must differ between pixels only by a common shift,
    returned as an (ny, nx) array relative to pixel [0, 0].
    """
    if not _is_sequence(read_times) or len(read_times) == 0:
        raise ParameterError(
            f"'read_times' must be a non-empty sequence of 1-D arrays of read times "
            f"(s from reset), one per resultant, got {read_times!r}")
    if nres is not None and len(read_times) != nres:
        raise ParameterError(
            f"'read_times' has {len(read_times)} entries but 'resultants' has {nres} "
            f"resultants; one array of read times per resultant is required")
    if image_shape is None:        # theory functions: accept per-pixel times too
        for t in read_times:
            shp = np.shape(t)
            if len(shp) == 3:
                image_shape = shp[1:]
                break
    arrays = []
    for r, t in enumerate(read_times):
        try:
            a = np.asarray(t, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ParameterError(
                f"'read_times'[{r}] must be an array of read times (s), got {t!r}"
            ) from exc
        if a.ndim == 0:
            a = a.reshape(1)
        if a.ndim != 1 and not (image_shape is not None and a.ndim == 3
                                and a.shape[1:] == tuple(image_shape)):
            allowed = "(n_reads,)" + (f" or (n_reads, {image_shape[0]}, "
                                      f"{image_shape[1]})" if image_shape else "")
            raise ParameterError(
                f"'read_times'[{r}] must have shape {allowed}, got shape {a.shape}")
        if a.shape[0] == 0:
            raise ParameterError(f"'read_times'[{r}] is empty; each resultant needs "
                                 f">= 1 read")
        if not np.all(np.isfinite(a)) or np.any(a < 0):
            raise ParameterError(
                f"'read_times'[{r}] must be finite and >= 0 s, got {t!r}")
        arrays.append(a)
    per_pixel = any(a.ndim == 3 for a in arrays)
    shift = None
    if per_pixel:
        arrays = [a if a.ndim == 3 else np.broadcast_to(
            a[:, None, None], (a.shape[0],) + tuple(image_shape)) for a in arrays]
        off = arrays[0][0] - arrays[0][0, 0, 0]
        base = []
        for r, a in enumerate(arrays):
            rel = a - off
            if np.ptp(rel, axis=(1, 2)).max() > 1e-9 * max(1.0, float(np.abs(a).max())):
                raise ParameterError(
                    f"'read_times'[{r}]: per-pixel read times must differ between "
                    f"pixels only by a common shift (rolling or global reset)")
            base.append(np.array(rel[:, 0, 0]))
        arrays, shift = base, off
    for r, a in enumerate(arrays):
        if np.any(np.diff(a) <= 0):
            raise ParameterError(
                f"'read_times'[{r}] must be strictly increasing, got {a!r}")
        if r > 0 and a[0] <= arrays[r - 1][-1]:
            raise ParameterError(
                f"'read_times': resultant {r} starts at {a[0]} s, not after the last "
                f"read of resultant {r - 1} at {arrays[r - 1][-1]} s; resultants must "
                f"not overlap in time")
    return arrays, shift


class _Readout:
    """Per-resultant constants and covariance coefficients of a readout (private).

    ``Ar``/``Ap`` (n_diff,) are the read (per sigma^2) and Poisson (per f) parts of the
    diagonal ``alpha_i``; ``Br``/``Bp`` (n_diff - 1,) those of ``beta_i``.
    """

    def __init__(self, times):
        self.n = np.array([t.size for t in times], dtype=float)
        self.tbar = np.array([t.mean() for t in times])
        self.tau = np.array([_tau(t) for t in times])
        self.dt = np.diff(self.tbar)
        n, tb, tau, dt = self.n, self.tbar, self.tau, self.dt
        self.Ar = (1 / n[:-1] + 1 / n[1:]) / dt ** 2
        self.Ap = (tau[:-1] + tau[1:] - 2 * tb[:-1]) / dt ** 2
        self.Br = (-1 / n[1:-1]) / (dt[:-1] * dt[1:])
        self.Bp = (tb[1:-1] - tau[1:-1]) / (dt[:-1] * dt[1:])

    @property
    def nres(self):
        return self.n.size


def _tau(t):
    """Brandt (2024) tau: ``(1/N^2) sum_k (2N - 2k + 1) t_k``, k = 1..N, t sorted."""
    n = t.size
    k = np.arange(1, n + 1)
    return float(np.dot(2 * n - 2 * k + 1, t)) / n ** 2


# ---------------------------------------------------------------------- validation
def _check_real(name, value, *, minimum=None, strict=False, allow_none=False):
    if value is None and allow_none:
        return None
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not \
            math.isfinite(value):
        raise ParameterError(f"{name!r} must be a finite real number, got {value!r}")
    if minimum is not None and (value <= minimum if strict else value < minimum):
        op = ">" if strict else ">="
        raise ParameterError(f"{name!r} must be {op} {minimum}, got {value!r}")
    return float(value)


def _check_map(name, value, shape, *, minimum=None, unit=""):
    """Scalar or (ny, nx) array of finite values >= minimum; returns float or array."""
    if isinstance(value, numbers.Real) and not isinstance(value, bool):
        return _check_real(name, value, minimum=minimum)
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ParameterError(
            f"{name!r} must be a scalar or an array of shape {shape} ({unit}), "
            f"got {value!r}") from exc
    if arr.ndim == 0:
        return _check_real(name, float(arr), minimum=minimum)
    if arr.shape != tuple(shape):
        raise ParameterError(
            f"{name!r} must be a scalar or have the image shape {tuple(shape)}, "
            f"got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ParameterError(f"{name!r} must be finite everywhere ({unit})")
    if minimum is not None and np.any(arr < minimum):
        raise ParameterError(
            f"{name!r} must be >= {minimum} ({unit}) everywhere, got min "
            f"{float(arr.min())!r}")
    return arr


# ---------------------------------------------------------------------- fitting
def fit_ramps(resultants, read_times, *, read_noise, gain=1.0, fitter="gls",
              saturated=None, jump_threshold=None, n_iter=2, refmask=None,
              zero_point=None, threads=None, variance_rate="local"):
    """Fit a rate to every pixel's resultants.

    Parameters
    ----------
    resultants : ndarray, shape (nres, ny, nx) or (nints, nres, ny, nx), e-
        Resultants of one or several integrations, in electrons (DN times gain;
        nothing else subtracted).  Any real dtype; computations are float32.
    read_times : sequence of nres arrays, seconds from reset
        Times of the reads averaged into each resultant: 1-D ``(N_i,)`` arrays, the
        same for every pixel (uneven Roman-style tables and gaps are allowed), or
        ``(N_i, ny, nx)`` arrays that differ between pixels by a common shift (global
        reset, as returned by ``Readout.read_times``).
    read_noise : float or ndarray (ny, nx), e- per read
        White read noise of **one read** (not CDS), >= 0.
    gain : float
        e-/DN (> 0); only used for ``SLOPE_DN`` in the output file.
    fitter : {'gls', 'ols', 'cds'}
        Optimal generalised least squares, equal-weight least squares on resultants
        against mean read time, or last minus first usable resultant.
    saturated : ndarray of bool, same shape as ``resultants``, optional
        Saturated resultants; only resultants before the first saturated one of
        each pixel and integration are used (flagged values may be NaN).
    jump_threshold : float or None
        Jump detection threshold in sigma (> 0); ``None`` turns detection off.
    n_iter : int
        GLS solves, each with the covariance at the previous rate estimate (>= 1).
    refmask : ndarray of bool, shape (ny, nx), optional
        Reference pixels, flagged ``REFERENCE_PIXEL | DO_NOT_USE``.
    zero_point : float or ndarray (ny, nx), e-, optional
        Known zero point (bias + reset level) of the resultants; used only for
        pixels with a single usable resultant (see module notes).  ``None``: such
        pixels are ``DO_NOT_USE``.
    threads : int or None
        Worker threads over row chunks (None: ``min(os.cpu_count(), 8)``).
    variance_rate : {'local', 'fit'} or ndarray (ny, nx), e-/s
        Rate at which the Poisson part of the reported variances (``var_poisson``,
        ``var_ints``) is evaluated; the slopes do not depend on it.  ``'local'``
        (default): the pixel's fitted rate shrunk toward the median of its 5 x 5
        neighbours, as far as they predict it (see the module notes "Reported
        variance"); ``'fit'``: the pixel's own fitted rate clipped at 0 (stcal and
        fitramp practice; its error is correlated with the slope's, which makes the
        reported variance wrong by up to ~10 % at low flux); an array: a rate known
        independently of these data (e.g. from a deeper exposure), clipped at 0.

    Returns
    -------
    FitResult

    Raises
    ------
    noise.errors.ParameterError
        On bad input, before any work.
    """
    # ---- validation (all before any work)
    if fitter not in FITTERS:
        raise ParameterError(f"'fitter' must be one of {list(FITTERS)}, got {fitter!r}")
    if not isinstance(resultants, np.ndarray):
        try:
            resultants = np.asarray(resultants)
        except (TypeError, ValueError) as exc:
            raise ParameterError("'resultants' must be a numeric array") from exc
    if resultants.dtype.kind not in "iuf":
        raise ParameterError(
            f"'resultants' must be a real numeric array (e-), got dtype "
            f"{resultants.dtype}")
    if resultants.ndim not in (3, 4):
        raise ParameterError(
            f"'resultants' must have shape (nres, ny, nx) or (nints, nres, ny, nx), "
            f"got shape {resultants.shape}")
    res4 = resultants if resultants.ndim == 4 else resultants[None]
    nints, nres, ny, nx = res4.shape
    if min(res4.shape) == 0:
        raise ParameterError(f"'resultants' must not be empty, got shape "
                             f"{resultants.shape}")
    times, shift = _check_read_times(read_times, nres, (ny, nx))
    read_noise = _check_map("read_noise", read_noise, (ny, nx), minimum=0.0,
                            unit="e- per read")
    gain = _check_real("gain", gain, minimum=0.0, strict=True)
    sat4 = None
    if saturated is not None:
        sat = np.asarray(saturated)
        if sat.dtype != bool:
            raise ParameterError(f"'saturated' must be a bool array, got dtype "
                                 f"{sat.dtype}")
        if sat.shape != resultants.shape:
            raise ParameterError(
                f"'saturated' must have the shape of 'resultants' {resultants.shape}, "
                f"got {sat.shape}")
        sat4 = sat if sat.ndim == 4 else sat[None]
    thr = _check_real("jump_threshold", jump_threshold, minimum=0.0, strict=True,
                      allow_none=True)
    if isinstance(n_iter, bool) or not isinstance(n_iter, numbers.Integral) or n_iter < 1:
        raise ParameterError(f"'n_iter' must be an integer >= 1, got {n_iter!r}")
    if refmask is not None:
        refmask = np.asarray(refmask)
        if refmask.dtype != bool or refmask.shape != (ny, nx):
            raise ParameterError(
                f"'refmask' must be a bool array of shape {(ny, nx)}, got "
                f"{refmask.dtype} {refmask.shape}")
    if zero_point is not None:
        zero_point = _check_map("zero_point", zero_point, (ny, nx), unit="e-")
    if isinstance(variance_rate, str):
        if variance_rate not in VARIANCE_RATES:
            raise ParameterError(
                f"'variance_rate' must be one of {list(VARIANCE_RATES)} or an array of "
                f"shape {(ny, nx)} (e-/s), got {variance_rate!r}")
    else:
        variance_rate = _check_map("variance_rate", variance_rate, (ny, nx),
                                   unit="e-/s")
    if threads is None:
        threads = min(os.cpu_count() or 1, 8)
    elif isinstance(threads, bool) or not isinstance(threads, numbers.Integral) \
            or threads < 1:
        raise ParameterError(f"'threads' must be an integer >= 1 or None, got "
                             f"{threads!r}")
    for k in range(nints):
        for r in range(nres):
            bad = ~np.isfinite(res4[k, r])
            if sat4 is not None:
                bad &= ~sat4[k, r]
            if bad.any():
                raise ParameterError(
                    f"'resultants' must be finite where not flagged in 'saturated'; "
                    f"integration {k} resultant {r} has {int(bad.sum())} NaN or inf "
                    f"values")

    # ---- work
    ro = _Readout(times)
    out = {
        "slope": np.zeros((ny, nx), _F32), "var_read": np.zeros((ny, nx), _F32),
        "var_poisson": np.zeros((ny, nx), _F32), "chi2": np.zeros((ny, nx), _F32),
        "dof": np.zeros((ny, nx), np.int32), "dq": np.zeros((ny, nx), np.uint32),
        "slope_ints": np.zeros((nints, ny, nx), _F32),
        "var_ints": np.zeros((nints, ny, nx), _F32),
        "n_jumps": np.zeros((ny, nx), np.int32),
    }
    aux = {"pcoef": np.zeros((ny, nx), _F32),
           "pcoef_ints": np.zeros((nints, ny, nx), _F32)}
    rows = max(1, _CHUNK_ELEMS // (nx * nints * nres))
    bounds = [(y, min(y + rows, ny)) for y in range(0, ny, rows)]
    s2_map = None if np.isscalar(read_noise) else (read_noise ** 2).astype(_F32)
    s2_scalar = None if s2_map is not None else float(read_noise) ** 2

    def pix(a, y0, y1):
        return None if a is None or np.isscalar(a) else a[y0:y1].reshape(-1)

    def work(bound):
        y0, y1 = bound
        blk = res4[:, :, y0:y1].reshape(nints, nres, -1)
        sblk = None if sat4 is None else sat4[:, :, y0:y1].reshape(nints, nres, -1)
        s2 = s2_scalar if s2_map is None else s2_map[y0:y1].reshape(-1)
        zp = zero_point if zero_point is None or np.isscalar(zero_point) else pix(
            zero_point, y0, y1)
        r = _fit_block(blk, sblk, s2, ro, fitter, thr, int(n_iter), zp,
                       pix(shift, y0, y1))
        shp = (y1 - y0, nx)
        for key, val in r.items():
            dest = out[key] if key in out else aux[key]
            if val.ndim == 2:
                dest[:, y0:y1] = val.reshape((nints,) + shp)
            else:
                dest[y0:y1] = val.reshape(shp)

    pool = None
    if threads > 1 and len(bounds) > 1:
        pool = ThreadPoolExecutor(max_workers=threads)
    try:
        if pool is None:
            for b in bounds:
                work(b)
        else:
            list(pool.map(work, bounds))
        if refmask is not None:
            out["dq"][refmask] |= np.uint32(REFERENCE_PIXEL | DO_NOT_USE)
        # ---- Poisson part of the reported variances, at the variance rate
        if isinstance(variance_rate, str) and variance_rate == "local":
            usable = (out["dq"] & np.uint32(DO_NOT_USE)) == 0
            rate_v = local_rate(out["slope"], out["var_read"], aux["pcoef"],
                                usable=usable, pool=pool)
        elif isinstance(variance_rate, str):
            rate_v = np.maximum(out["slope"], _F32(0))
        else:
            rate_v = np.maximum(np.asarray(variance_rate, dtype=_F32), _F32(0))
    finally:
        if pool is not None:
            pool.shutdown()
    out["var_poisson"] = (rate_v * aux["pcoef"]).astype(_F32)
    out["var_ints"] += rate_v[None] * aux["pcoef_ints"]
    rn = float(read_noise) if s2_map is None else float(np.median(read_noise))
    return FitResult(gain=gain, read_noise=rn, fitter=fitter, **out)


def model_chi2(resultants, read_times, rate, read_noise, *, valid=None, ddof=1):
    """Chi-square per degree of freedom of the resultants about a given rate.

    The quantity ``CHI2`` of :func:`fit_ramps`, for any rate: with the rate
    estimates ``d_i = (R_{i+1} - R_i) / dt_i`` of each integration and ``C(f)`` their
    model covariance (Brandt 2024, eqs. 28-29; module notes), evaluated at
    ``max(rate, 0)`` as the GLS fitter does::

        chi2 = sum_k (d_k - rate)^T C^-1 (d_k - rate) / (n_usable - ddof)

    summed over integrations ``k`` and over the usable differences only (removing a
    difference splits the ramp into independent segments, as in the fit).  For ramps
    whose true rate is ``rate`` (so that ``C`` is their covariance) its expectation
    is 1 with ``ddof=0``; for the GLS rate of the same data it is 1 with ``ddof=1``,
    and
    ``1 + (V/V_opt - 1)/dof`` for another linear unbiased estimate of variance
    ``V`` (e.g. stcal's).

    Parameters
    ----------
    resultants : ndarray, shape (nres, ny, nx) or (nints, nres, ny, nx), e-
        Resultants, in electrons.  Any real dtype (differences are taken in float64,
        then float32).  Finite wherever a usable difference uses them; elsewhere
        (e.g. saturated) they may be NaN.
    read_times : sequence of nres arrays, seconds from reset
        As in :func:`fit_ramps` (1-D, or per pixel differing by a common shift).
    rate : float or ndarray (ny, nx), e-/s
        Rate the rate estimates are compared with (finite; any sign).
    read_noise : float or ndarray (ny, nx), e- per read
        White read noise of **one read** (not CDS), >= 0.  Where it is 0 the
        covariance uses a rate of at least 1e-6 e-/s, as :func:`fit_ramps` does.
    valid : ndarray of bool, optional
        Shape (nres - 1, ny, nx) or (nints, nres - 1, ny, nx), with the leading
        axes of ``resultants``: usable differences (difference ``i`` uses
        resultants ``i`` and ``i + 1``); default all.
    ddof : int, keyword-only
        Degrees of freedom taken by the rate (>= 0): 1 (default) when it was fitted
        to these resultants, 0 for a rate known independently.

    Returns
    -------
    ndarray, shape (ny, nx), float32
        ``chi2`` per degree of freedom; 0 where ``n_usable - ddof <= 0``.

    Raises
    ------
    noise.errors.ParameterError
        On bad input, before any work.
    """
    res = np.asarray(resultants)
    if res.dtype.kind not in "iuf" or res.ndim not in (3, 4) or min(res.shape) == 0:
        raise ParameterError(
            f"'resultants' must be a non-empty real array of shape (nres, ny, nx) or "
            f"(nints, nres, ny, nx), e-, got {res.dtype} {res.shape}")
    res4 = res if res.ndim == 4 else res[None]
    nints, nres, ny, nx = res4.shape
    if nres < 2:
        raise ParameterError(
            f"'resultants' must have >= 2 resultants for a rate estimate, got {nres}")
    times, _ = _check_read_times(read_times, nres, (ny, nx))
    rate = _check_map("rate", rate, (ny, nx), unit="e-/s")
    read_noise = _check_map("read_noise", read_noise, (ny, nx), minimum=0.0,
                            unit="e- per read")
    dshape = res.shape[:-3] + (nres - 1, ny, nx)
    if valid is None:
        valid4 = np.ones((nints, nres - 1, ny, nx), bool)
    else:
        valid4 = np.asarray(valid)
        if valid4.dtype != bool or valid4.shape != dshape:
            raise ParameterError(
                f"'valid' must be a bool array of shape {dshape} (one flag per "
                f"difference), got {valid4.dtype} {valid4.shape}")
        valid4 = valid4 if valid4.ndim == 4 else valid4[None]
    if isinstance(ddof, bool) or not isinstance(ddof, numbers.Integral) or ddof < 0:
        raise ParameterError(f"'ddof' must be an integer >= 0, got {ddof!r}")
    if res.dtype.kind == "f":
        need = np.zeros(res4.shape, bool)          # resultants of a usable difference
        need[:, :-1] |= valid4
        need[:, 1:] |= valid4
        nbad = int((need & ~np.isfinite(res4)).sum())
        if nbad:
            raise ParameterError(
                f"'resultants' must be finite where a usable difference ('valid') "
                f"uses them; {nbad} NaN or inf values are")

    ro = _Readout(times)
    A = (ro.Ar.tolist(), ro.Ap.tolist())
    B = (ro.Br.tolist(), ro.Bp.tolist())
    inv_dt = (1.0 / ro.dt)[:, None]
    rate_map = np.broadcast_to(np.asarray(rate, dtype=_F32), (ny, nx))
    s2_map = np.broadcast_to(np.asarray(read_noise, dtype=float) ** 2, (ny, nx))
    raw = np.zeros((ny, nx), _F32)
    rows = max(1, _CHUNK_ELEMS // (nx * nints * nres))
    for y0 in range(0, ny, rows):
        y1 = min(y0 + rows, ny)
        f = rate_map[y0:y1].reshape(-1)
        s2 = s2_map[y0:y1].reshape(-1).astype(_F32)
        fc = np.maximum(f, np.where(s2 == 0, _F32(_RATE_FLOOR), _F32(0)))
        acc = np.zeros(f.size, _F32)
        for k in range(nints):
            blk = res4[k, :, y0:y1].reshape(nres, -1)
            blk = blk if blk.dtype in (np.float32, np.float64) else blk.astype(float)
            v = valid4[k, :, y0:y1].reshape(nres - 1, -1)
            with np.errstate(invalid="ignore"):
                d = np.where(v, np.diff(blk, axis=0) * inv_dt, 0).astype(_F32)
            mf = v.astype(_F32)
            mc = mf[:-1] * mf[1:]
            acc += _ldl_pass(d, v, mf, mc, f, s2, fc, A, B, want_x=False)[2]
        raw[y0:y1] = acc.reshape(y1 - y0, nx)
    dof = valid4.sum(axis=(0, 1), dtype=np.int64) - int(ddof)
    return np.divide(np.maximum(raw, 0), dof, out=np.zeros((ny, nx), _F32),
                     where=dof > 0).astype(_F32)


def _first_pass(resultants, read_times, read_noise, groups, saturated, refmask,
                max_rows, threads):
    """Validate, fit a row subsample (GLS, no jumps) and select read-dominated pixels.

    Returns a dict: ``res`` (nints, nres, m, nx) subsample, ``rows``, ``fit``
    (FitResult of the subsample), ``ro`` (_Readout), ``s2`` (m, nx) read variance,
    ``rho`` (m, nx) mean Poisson / read variance of a difference at the fitted rate,
    ``usable`` and ``quiet`` (m, nx) bool (usable; usable and read-noise dominated:
    Poisson variance of every difference <= ``_NOISE_RHO`` times its read variance),
    ``groups`` (m, nx) labels, ``ngroups`` and ``rn`` (validated read noise).
    """
    res = np.asarray(resultants)
    if res.ndim not in (3, 4):
        raise ParameterError(
            f"'resultants' must have shape (nres, ny, nx) or (nints, nres, ny, nx), "
            f"got shape {res.shape}")
    ny, nx = res.shape[-2:]
    gr = np.asarray(groups)
    if gr.shape != (ny, nx) or gr.dtype.kind not in "iu" or (gr.size and gr.min() < 0):
        raise ParameterError(
            f"'groups' must be an integer array >= 0 of shape {(ny, nx)}, got "
            f"{gr.dtype} {gr.shape}")
    if isinstance(max_rows, bool) or not isinstance(max_rows, numbers.Integral) \
            or max_rows < 1:
        raise ParameterError(f"'max_rows' must be an integer >= 1, got {max_rows!r}")
    rn = _check_map("read_noise", read_noise, (ny, nx), minimum=0.0, unit="e- per read")
    rows = np.arange(0, ny, -(-ny // int(max_rows)))
    res4 = res if res.ndim == 4 else res[None]
    sub = res4[:, :, rows]
    times = read_times
    if _is_sequence(read_times):
        times = [t[:, rows] if np.ndim(t) == 3 else t for t in read_times]
    sat = None
    if saturated is not None:
        sat = np.asarray(saturated)
        if sat.dtype != bool or sat.shape != res.shape:
            raise ParameterError(
                f"'saturated' must be a bool array of the shape of 'resultants' "
                f"{res.shape}, got {sat.dtype} {sat.shape}")
        sat = (sat if sat.ndim == 4 else sat[None])[:, :, rows]
    ref = None
    if refmask is not None:
        ref = np.asarray(refmask)
        if ref.dtype != bool or ref.shape != (ny, nx):
            raise ParameterError(
                f"'refmask' must be a bool array of shape {(ny, nx)}, got "
                f"{ref.dtype} {ref.shape}")
        ref = ref[rows]
    rn_sub = rn if np.isscalar(rn) else rn[rows]
    g = fit_ramps(sub, times, read_noise=rn_sub, saturated=sat, refmask=ref,
                  threads=threads, variance_rate="fit")
    ro = _Readout(_check_read_times(times, len(times), sub.shape[-2:])[0])
    s2 = np.broadcast_to(np.asarray(rn_sub, dtype=float) ** 2, g.slope.shape)
    fpos = np.maximum(g.slope.astype(float), 0.0)
    ratio = ro.Ap / ro.Ar                # Poisson / read variance per unit f and s2
    with np.errstate(divide="ignore", invalid="ignore"):
        rho_max = np.where(s2 > 0, fpos * ratio.max() / s2, np.inf)
        rho = np.where(s2 > 0, fpos * ratio.mean() / s2, np.inf)
    usable = ((g.dq & np.uint32(DO_NOT_USE)) == 0) & (g.dof >= 1)
    return {"res": sub, "sat": sat, "rows": rows, "fit": g, "ro": ro, "s2": s2,
            "rho": rho, "usable": usable, "quiet": usable & (rho_max <= _NOISE_RHO),
            "groups": gr[rows], "ngroups": int(np.max(gr, initial=0)) + 1, "rn": rn}


def measure_read_noise(resultants, read_times, *, read_noise, groups, saturated=None,
                       refmask=None, max_rows=256, threads=None):
    """Effective white read noise per read, per group of pixels, from the data.

    A GLS fit (no jump detection) of at most ``max_rows`` evenly spaced rows gives
    each pixel's chi-square per degree of freedom.  Where the read noise dominates
    the differences, ``chi2 / dof`` estimates ``k^2 = sigma_eff^2 / sigma^2``
    (corrected to first order for the Poisson share ``rho``:
    ``k^2 = (chi2 / dof) (1 + rho) - rho``).  The median over a group, each pixel
    normalised by the median of the chi-square distribution of its ``dof`` (so that
    it is exactly 1 for a right model; the median is robust to the few ramps with
    jumps), gives the group's ``sigma_eff = k sigma``.  Unless every ``k^2`` is
    within 2 % of 1, a second fit with ``sigma_eff`` refines it: at the right
    model ``chi2 / dof = 1`` whatever ``rho``, so the first-order correction no
    longer matters.  See the module notes "Read noise from the data".

    Parameters
    ----------
    resultants, read_times, saturated, refmask :
        As in :func:`fit_ramps`.
    read_noise : float or ndarray (ny, nx), e- per read (not CDS)
        Model read noise (e.g. the white noise of the header), >= 0.
    groups : ndarray of int, shape (ny, nx)
        Group label (>= 0) of every pixel; one ``sigma_eff`` per group (e.g. the
        column index: the noise that the reference correction leaves depends on
        the read time within the row).
    max_rows : int
        Rows used (>= 1): every ``ceil(ny / max_rows)``-th row.
    threads : int or None
        As in :func:`fit_ramps`.

    Returns
    -------
    ndarray, shape (ny, nx), float64, e- per read
        ``k_g * read_noise``.  A group with fewer than :data:`NOISE_MIN_PIXELS`
        read-noise dominated pixels (Poisson variance of every difference at most
        half its read variance) gets the median over all groups; with fewer than
        that in total, ``k = 1``.

    Raises
    ------
    noise.errors.ParameterError
        On bad input, before any work.
    """
    from scipy.special import gammaincinv

    rn = read_noise
    k = None
    for _ in range(2):
        fp = _first_pass(resultants, read_times, rn, groups, saturated, refmask,
                         max_rows, threads)
        g, ok = fp["fit"], fp["quiet"]
        k2 = np.ones(fp["ngroups"])
        if ok.sum() >= NOISE_MIN_PIXELS:
            nu, inv = np.unique(g.dof[ok], return_inverse=True)
            med_chi2 = (2 * gammaincinv(nu / 2, 0.5) / nu)[inv]  # median chi2_nu / nu
            rho = fp["rho"][ok]
            u = (g.chi2[ok] / med_chi2) * (1 + rho) - rho
            k2[:] = np.median(u)
            lab, u = _sort_by_label(fp["groups"][ok], u)
            uniq, start, count = np.unique(lab, return_index=True, return_counts=True)
            for lb, a, c in zip(uniq, start, count):        # one median per group
                if c >= NOISE_MIN_PIXELS:
                    k2[lb] = np.median(u[a:a + c])
        step = np.sqrt(np.maximum(k2, _NOISE_K2_MIN))
        if k is None:
            k, rn0 = step, np.asarray(fp["rn"], dtype=float)
        else:
            k = k * step
        lab = np.asarray(groups)
        rn = np.broadcast_to(rn0, lab.shape) * k[lab]
        if np.all(np.abs(k2 - 1) < _NOISE_CONVERGED):
            break
    return rn


def _rate0_weights(ro, good):
    """GLS weights (summing to 1) of the rate estimates ``d_i`` of the differences
    flagged ``good``, for read noise only: ``C^-1 1 / (1^T C^-1 1)`` with the
    tridiagonal covariance ``alpha_i = Ar_i``, ``beta_i = Br_i`` (sigma^2 cancels)."""
    n = ro.dt.size
    cov = np.diag(ro.Ar) + np.diag(ro.Br, 1) + np.diag(ro.Br, -1)
    idx = np.flatnonzero(good)
    w = np.zeros(n)
    if idx.size:
        sub = np.linalg.solve(cov[np.ix_(idx, idx)], np.ones(idx.size))
        w[idx] = sub / sub.sum()
    return w


def common_mode(resultants, read_times, *, read_noise, groups, saturated=None,
                refmask=None, max_rows=64, threads=None):
    """Offsets shared by all pixels of a group, read by read, that a line cannot fit.

    Noise common to all pixels of an output (the per-output 1/f noise, the part of
    the correlated 1/f noise that the reference pixels miss) adds the same series
    ``m_i`` to the rate estimates ``d_i`` of every pixel of the output.  From a
    first GLS fit (no jumps) of at most ``max_rows`` evenly spaced rows,
    ``c_i = median over the group's read-noise dominated pixels of (d_i - f_hat)``,
    minus its GLS-weighted mean over ``i`` (weights of a read-noise limited ramp, so
    that the correction leaves those pixels' GLS slopes unchanged); the offsets are its running sum
    ``C_k = sum_{i<k} c_i dt_i`` (``C_0 = 0``).  Subtracting ``C_k`` from resultant
    ``k`` of the group's pixels removes the common series except its mean, which is
    a rate common to the group and cannot be told from a uniform background (module
    notes, "Common-mode noise").

    The median uses at most 16384 pixels per group (evenly spaced among those
    selected): its noise, ``1.25 sigma_d / sqrt(n)``, is then < 1 % of the noise
    ``sigma_d`` of one difference.

    Parameters
    ----------
    resultants, read_times, saturated, refmask :
        As in :func:`fit_ramps`.
    read_noise : float or ndarray (ny, nx), e- per read (not CDS), >= 0
        Model read noise (selects read-noise dominated pixels).
    groups : ndarray of int, shape (ny, nx)
        Group label (>= 0) of every pixel, e.g. the output index of its column.
    max_rows : int
        Rows used (>= 1): every ``ceil(ny / max_rows)``-th row.
    threads : int or None
        As in :func:`fit_ramps`.

    Returns
    -------
    ndarray, shape (nints, nres, n_groups), float64, e-
        ``C_k`` of each integration and group (``n_groups = max(groups) + 1``); 0
        for a group with fewer than :data:`NOISE_MIN_PIXELS` usable pixels.
        ``resultants - C[..., groups]`` is the corrected cube.

    Raises
    ------
    noise.errors.ParameterError
        On bad input, before any work.
    """
    fp = _first_pass(resultants, read_times, read_noise, groups, saturated, refmask,
                     max_rows, threads)
    sub, g, ro = fp["res"], fp["fit"], fp["ro"]
    nints, nres = sub.shape[:2]
    out = np.zeros((nints, nres, fp["ngroups"]))
    if nres < 3:
        return out
    sel = fp["quiet"]
    lab_all = fp["groups"]
    for lb in np.unique(lab_all[fp["usable"]]):
        pix = sel & (lab_all == lb)
        if pix.sum() < NOISE_MIN_PIXELS:
            pix = fp["usable"] & (lab_all == lb)
        if pix.sum() < NOISE_MIN_PIXELS:
            continue
        ys, xs = np.nonzero(pix)
        stride = -(-ys.size // _CM_MAX_PIXELS)                 # enough for the median
        ys, xs = ys[::stride], xs[::stride]
        f = g.slope[ys, xs]
        inv_dt = (1 / ro.dt).astype(_F32)[:, None]
        for k in range(nints):
            r = sub[k][:, ys, xs].astype(_F32)                    # (nres, n)
            d = np.diff(r, axis=0) * inv_dt - f[None]
            if fp["sat"] is not None:
                bad = fp["sat"][k][:, ys, xs]
                bad = np.maximum.accumulate(bad, axis=0)
                d[bad[1:]] = np.nan
            fin = np.isfinite(d)
            good = fin.sum(axis=1) >= NOISE_MIN_PIXELS
            if good.sum() < 2:
                continue
            if fin.all():
                c = np.median(d, axis=1)
            else:
                c = np.array([np.median(row[ok]) if gd else 0.0
                              for row, ok, gd in zip(d, fin, good)])
            # keep the GLS-weighted mean (weights at rate 0), so that the correction
            # changes no read-noise dominated slope: sum_i w_i (c_i - cbar) = 0
            w = _rate0_weights(ro, good)
            c = np.where(good, c - np.sum(w * np.where(good, c, 0.0)), 0.0)
            out[k, 1:, lb] = np.cumsum(c * ro.dt)
    return out


def _sort_by_label(lab, values):
    order = np.argsort(lab, kind="stable")
    return lab[order], values[order]


def _fit_block(res, sat, s2, ro, fitter, thr, n_iter, zp, tshift):
    """Fit one chunk: ``res`` (nints, nres, P); returns a dict of (P,)/(nints, P) arrays."""
    nints, nres, npix = res.shape
    nd = nres - 1
    if sat is None:
        nuse = np.full((nints, npix), nres, np.int32)
        anysat = np.zeros(npix, bool)
    else:
        satany = sat.any(axis=1)
        nuse = np.where(satany, sat.argmax(axis=1), nres).astype(np.int32)
        anysat = satany.any(axis=0)
    slope = np.zeros(npix, _F32)
    var_read = np.zeros(npix, _F32)
    chi2 = np.zeros(npix, _F32)
    dof = np.zeros(npix, np.int32)
    slope_ints = np.zeros((nints, npix), _F32)
    var_ints = np.full((nints, npix), BAD_VARIANCE, _F32)   # read part until fit_ramps
    pcoef = np.zeros(npix, _F32)              # Poisson variance of slope per unit rate
    pcoef_ints = np.zeros((nints, npix), _F32)
    njump = np.zeros(npix, np.int32)
    measured = np.zeros(npix, bool)

    if nd >= 1:
        rf = res if res.dtype in (np.float32, np.float64) else res.astype(np.float64)
        if sat is not None:
            rf = np.where(sat, rf.dtype.type(0), rf)   # saturated values may be NaN
        inv_dt = (1.0 / ro.dt)[None, :, None]
        d = (np.diff(rf, axis=1) * inv_dt).astype(_F32)            # (nints, nd, P)
        valid = np.arange(nd)[None, :, None] < (nuse[:, None, :] - 1)
        if thr is not None and nd >= 3:
            # Sub-blocks of pixels keep the (nd, n) work arrays in cache.
            for k in range(nints):
                for c0 in range(0, npix, _JUMP_BLOCK):
                    c1 = min(c0 + _JUMP_BLOCK, npix)
                    s2b = s2 if np.isscalar(s2) else s2[c0:c1]
                    njump[c0:c1] += _detect_jumps(
                        d[k, :, c0:c1], valid[k, :, c0:c1], s2b, ro, thr).sum(
                        axis=0, dtype=np.int32)
        mf = valid.astype(_F32)
        mc = mf[:, :-1] * mf[:, 1:]
        nvalid = valid.sum(axis=1, dtype=np.int32)                  # (nints, P)
        # Rate floor of the covariance where sigma = 0, so that W stays positive
        # definite when the rate estimate is <= 0 (1e-6 e-/s; no effect otherwise).
        if np.isscalar(s2):
            lo = _F32(_RATE_FLOOR if s2 == 0 else 0)
        else:
            lo = np.where(s2 == 0, _F32(_RATE_FLOOR), _F32(0))
        A_mod = (ro.Ar.tolist(), ro.Ap.tolist())
        B_mod = (ro.Br.tolist(), ro.Bp.tolist())
        if fitter == "gls":
            dtw = ro.dt.astype(_F32)[None, :, None]
            den = (mf * dtw).sum(axis=(0, 1))
            num = (d * mf * dtw).sum(axis=(0, 1))
            fref = np.divide(num, den, out=np.zeros(npix, _F32), where=den > 0)
            for it in range(n_iter):
                last = it == n_iter - 1
                fc = np.maximum(fref, lo)
                passes = [_ldl_pass(d[k], valid[k], mf[k], mc[k], fref, s2, fc,
                                    A_mod, B_mod, want_x=last) for k in range(nints)]
                S11 = sum(p[0] for p in passes)
                S1y = sum(p[1] for p in passes)
                measured = S11 > 0
                new = fref + np.divide(S1y, S11, out=np.zeros(npix, _F32),
                                       where=measured)
                if not last:
                    fref = new
            slope = new
            syy = sum(p[2] for p in passes)
            chi2_raw = syy - np.divide(S1y * S1y, S11, out=np.zeros(npix, _F32),
                                       where=measured)
            inv11 = np.divide(1, S11, out=np.zeros(npix, _F32), where=measured)
            qr_tot = np.zeros(npix, _F32)
            qp_tot = np.zeros(npix, _F32)
            for k, p in enumerate(passes):
                x = p[3]
                qr = _quad(x, ro.Ar, ro.Br)
                qp = _quad(x, ro.Ap, ro.Bp)
                qr_tot += qr
                qp_tot += qp
                ok = p[0] > 0
                ik = np.divide(1, p[0], out=np.zeros(npix, _F32), where=ok)
                slope_ints[k] = np.where(ok, fref + p[1] * ik, 0)
                var_ints[k] = np.where(ok, s2 * qr * ik * ik, BAD_VARIANCE)
                pcoef_ints[k] = qp * ik * ik
            var_read = s2 * qr_tot * inv11 * inv11
            pcoef = qp_tot * inv11 * inv11
        else:
            if fitter == "ols":
                A_w = ((2.0 / ro.dt ** 2).tolist(), None)
                B_w = ((-1.0 / (ro.dt[:-1] * ro.dt[1:])).tolist(), None)
            else:
                A_w = ((1.0 / ro.dt).tolist(), None)
                B_w = None
            zero = np.zeros(npix, _F32)
            passes = [_ldl_pass(d[k], valid[k], mf[k], mc[k], zero, 1.0, 0.0, A_w, B_w,
                                want_x=True) for k in range(nints)]
            S11 = sum(p[0] for p in passes)
            measured = S11 > 0
            f0 = np.divide(sum(p[1] for p in passes), S11, out=np.zeros(npix, _F32),
                           where=measured)
            fv = np.maximum(f0, _F32(0))
            wsum = np.zeros(npix, _F32)
            wslope = np.zeros(npix, _F32)
            wr = []
            for k, p in enumerate(passes):
                ok = p[0] > 0
                ik = np.divide(1, p[0], out=np.zeros(npix, _F32), where=ok)
                x = p[3]
                vr = s2 * _quad(x, ro.Ar, ro.Br) * ik * ik
                qp = _quad(x, ro.Ap, ro.Bp) * ik * ik
                vp = fv * qp
                sk = p[1] * ik
                slope_ints[k] = sk
                var_ints[k] = np.where(ok, vr, BAD_VARIANCE)
                pcoef_ints[k] = qp
                w = np.where(ok, 1 / np.maximum(vr + vp, _F32(_TINY)), 0).astype(_F32)
                wsum += w
                wslope += w * sk
                wr.append((w, vr, qp))
            iw = np.divide(1, wsum, out=np.zeros(npix, _F32), where=wsum > 0)
            slope = wslope * iw
            for w, vr, qp in wr:
                var_read += (w * iw) ** 2 * vr
                pcoef += (w * iw) ** 2 * qp
            fv2 = np.maximum(slope, lo)
            syy = sum(_ldl_pass(d[k], valid[k], mf[k], mc[k], slope, s2, fv2, A_mod,
                                B_mod, want_x=False)[2] for k in range(nints))
            chi2_raw = syy
        ndof = nvalid.sum(axis=0) - 1
        dof = np.where(measured, np.maximum(ndof, 0), 0).astype(np.int32)
        chi2 = np.divide(np.maximum(chi2_raw, 0), dof, out=np.zeros(npix, _F32),
                         where=dof > 0).astype(_F32)

    # ---- pixels without a usable difference
    unmeasured = ~measured
    if unmeasured.any():
        slope[unmeasured] = 0
        var_read[unmeasured] = BAD_VARIANCE
        pcoef[unmeasured] = 0
        chi2[unmeasured] = 0
        if zp is not None:
            _single_resultant(res, nuse, unmeasured, measured, s2, ro, zp, tshift,
                              slope, var_read, pcoef, slope_ints, var_ints, pcoef_ints)
    dq = np.where(anysat, SATURATED, 0).astype(np.uint32)
    dq[njump > 0] |= np.uint32(JUMP_DET)
    dq[~measured] |= np.uint32(DO_NOT_USE)
    return {"slope": slope.astype(_F32), "var_read": var_read.astype(_F32),
            "pcoef": pcoef.astype(_F32), "chi2": chi2, "dof": dof, "dq": dq,
            "slope_ints": slope_ints, "var_ints": var_ints,
            "pcoef_ints": pcoef_ints, "n_jumps": njump}


def local_rate(slope, var_read, pcoef, *, usable, pool=None):
    """Rate for the reported Poisson variance: own rate shrunk toward the neighbours.

    Empirical-Bayes estimate (module notes, "Reported variance"): the prior of a
    pixel's rate is the median ``m`` of the fitted rates of its 24 neighbours in a
    5 x 5 box (centre excluded, unusable pixels skipped, neighbours more than 4
    robust standard deviations from the first median left out), with a mean squared
    error
    ``tau^2 + (pi / 2) V_m / n``, where ``tau^2 = max(s^2 - V_m, 0)`` is the spread
    of the neighbours' rates beyond their noise (``s`` = interquartile range / 1.349),
    ``V_m`` the pixel's slope variance at rate ``m`` and ``n`` the number of
    neighbours.  The rate is ``w max(f_hat, 0) + (1 - w) max(m, 0)`` with
    ``w = MSE / (MSE + V_m)``; ``w`` rises to 1 where ``|f_hat - m|`` exceeds 3 to 5
    standard deviations (hot pixels, unresolved sources) and where fewer than 8
    neighbours are usable.

    Parameters
    ----------
    slope, var_read, pcoef : ndarray, shape (ny, nx), float32
        Fitted rate (e-/s), read variance ((e-/s)^2) and Poisson variance per unit
        rate ((e-/s)^2 per e-/s) of every pixel.
    usable : ndarray of bool, shape (ny, nx)
        Pixels whose rate may serve as a neighbour (measured, not reference).
    pool : concurrent.futures.Executor or None
        Runs row chunks in parallel.

    Returns
    -------
    ndarray, shape (ny, nx), float32, e-/s, >= 0
    """
    ny, nx = slope.shape
    half = _LOCAL_HALF
    own = np.maximum(slope, _F32(0)).astype(_F32)
    # Where one sigma of the rate changes the variance by less than sqrt(eps)
    # (kappa^2 = pcoef^2 / V < eps), the own rate is as good (module notes).
    vown = var_read + pcoef * own
    need = usable & (pcoef * pcoef > _F32(_LOCAL_KAPPA2) * vown)
    idx = np.flatnonzero(need)
    if idx.size == 0:
        return own
    wpad = nx + 2 * half
    pad = np.pad(np.where(usable, slope, np.nan).astype(_F32), half,
                 constant_values=np.nan).reshape(-1)
    offs = np.array([dy * wpad + dx for dy in range(-half, half + 1)
                     for dx in range(-half, half + 1) if (dy, dx) != (0, 0)], np.intp)
    base = (idx // nx + half) * wpad + idx % nx + half
    nnb = offs.size
    f_all, vr_all, pc_all = slope.reshape(-1), var_read.reshape(-1), pcoef.reshape(-1)
    out = own.reshape(-1).copy()
    step = max(1, _CHUNK_ELEMS // nnb)

    # usable neighbours of every pixel: 5 x 5 box sum of the mask minus the centre
    box = 2 * half + 1
    up = np.pad(usable.astype(np.int8), half)
    rows_sum = sum(up[:, k:k + nx] for k in range(box))          # (ny + 4, nx)
    nmap = (sum(rows_sum[k:k + ny] for k in range(box)) - usable).reshape(-1)

    def quantile(flat, rowbase, start, n, p):
        """Linearly interpolated quantile ``p`` of sorted ``row[start:start + n]``."""
        pos = p * (np.maximum(n, 1) - 1).astype(_F32)
        i0 = pos.astype(np.intp)
        i1 = np.minimum(i0 + 1, np.maximum(n - 1, 0))
        a = flat[rowbase + start + i0]
        return a + (pos - i0) * (flat[rowbase + start + i1] - a)

    def work(c0):
        sel = idx[c0:c0 + step]
        stack = pad[base[c0:c0 + step, None] + offs[None, :]]     # (m, 24)
        stack.sort(axis=1)                                       # NaN (unusable) last
        flat = stack.reshape(-1)
        rowbase = np.arange(sel.size, dtype=np.intp) * nnb
        n = nmap[sel]
        lo = np.zeros_like(n)
        f, vr, pc = f_all[sel], vr_all[sel], pc_all[sel]
        with np.errstate(invalid="ignore", divide="ignore"):
            med = quantile(flat, rowbase, lo, n, 0.5)
            q1 = quantile(flat, rowbase, lo, n, 0.25)
            q3 = quantile(flat, rowbase, lo, n, 0.75)
            # one clip at 4 robust sigma: isolated hot or hit neighbours out
            scale = _F32(_LOCAL_CLIP) * np.maximum(
                (q3 - q1) / _F32(_IQR_SIGMA),
                np.sqrt(vr + pc * np.maximum(np.nan_to_num(med), 0)))
            clip = (flat[rowbase] < med - scale) | (
                flat[rowbase + np.maximum(n - 1, 0)] > med + scale)
            if clip.any():
                c = np.flatnonzero(clip)
                sc = stack[c]
                lo_c = (sc < (med[c] - scale[c])[:, None]).sum(axis=1)
                n_c = (sc <= (med[c] + scale[c])[:, None]).sum(axis=1) - lo_c
                lo[c], n[c] = lo_c, n_c
                med[c] = quantile(flat, rowbase[c], lo_c, n_c, 0.5)
                q1[c] = quantile(flat, rowbase[c], lo_c, n_c, 0.25)
                q3[c] = quantile(flat, rowbase[c], lo_c, n_c, 0.75)
            mpos = np.maximum(np.nan_to_num(med), _F32(0))
            v_m = vr + pc * mpos
            nn = np.maximum(n, 1).astype(_F32)
            spread = ((q3 - q1) / _F32(_IQR_SIGMA)) ** 2
            gate = v_m * (1 + _F32(2 * _IQR_VAR) / np.sqrt(nn))
            mse = np.maximum(spread - gate, 0) + _F32(math.pi / 2) * v_m / nn
            w = mse / np.maximum(mse + v_m, _F32(_TINY))
            dev = np.abs(f - med) / np.sqrt(np.maximum(v_m + mse, _F32(_TINY)))
            w = np.maximum(w, np.clip((dev - _F32(3)) / _F32(2), 0, 1))
            w = np.where((n >= _LOCAL_MIN) & np.isfinite(w), w, _F32(1))
        out[sel] = w * np.maximum(f, _F32(0)) + (1 - w) * mpos

    starts = range(0, idx.size, step)
    if pool is None:
        for c0 in starts:
            work(c0)
    else:
        list(pool.map(work, starts))
    return out.reshape(ny, nx)


def _single_resultant(res, nuse, unmeasured, measured, s2, ro, zp, tshift, slope,
                      var_read, pcoef, slope_ints, var_ints, pcoef_ints):
    """Slope ``(R_0 - zero_point) / tbar_0`` for pixels with one usable resultant.

    Updates the output arrays and ``measured`` in place (``var_ints`` gets the read
    part, ``pcoef``/``pcoef_ints`` the Poisson variance per unit rate).
    """
    nints, _, npix = res.shape
    tb = np.full(npix, ro.tbar[0]) if tshift is None else ro.tbar[0] + tshift
    ta = np.full(npix, ro.tau[0]) if tshift is None else ro.tau[0] + tshift
    use = (nuse >= 1) & unmeasured[None, :] & (tb > 0)[None, :]     # (nints, P)
    n1 = use.sum(axis=0)
    pick = n1 > 0
    if not pick.any():
        return
    tb_safe = np.where(tb > 0, tb, 1.0)
    r0 = np.where(use, res[:, 0, :].astype(np.float64), 0.0)         # (nints, P)
    sk = np.where(use, (r0 - zp) / tb_safe, 0.0)
    mean = sk.sum(axis=0) / np.maximum(n1, 1)
    s2v = s2 if np.isscalar(s2) else s2.astype(np.float64)
    vr = s2v / ro.n[0] / tb_safe ** 2
    qp = ta / tb_safe ** 2
    slope[pick] = mean[pick]
    var_read[pick] = np.broadcast_to(vr / np.maximum(n1, 1), (npix,))[pick]
    pcoef[pick] = (qp / np.maximum(n1, 1))[pick]
    vr_b = np.broadcast_to(vr, (npix,))
    for k in range(nints):
        uk = use[k]
        slope_ints[k][uk] = sk[k][uk]
        var_ints[k][uk] = vr_b[uk]
        pcoef_ints[k][uk] = qp[uk]
    measured |= pick


def _ldl_pass(d, valid, mf, mc, fref, s2, f, A, B, *, want_x):
    """Forward L D L^T recursion of a tridiagonal W for every pixel at once.

    Parameters
    ----------
    d : (nd, P) float32 rate estimates; valid/mf : (nd, P) bool/float32 usable
    differences; mc : (nd - 1, P) float32 couplings (both neighbours usable).
    fref : (P,) float32 reference rate subtracted from ``d`` (``y = d - fref``).
    s2, f : scalar or (P,) float32: read variance per read and rate in ``W``.
    A : (A_read, A_pois or None), lists of nd diagonal coefficients;
    B : (B_read, B_pois or None) lists of nd - 1 off-diagonal coefficients, or None.
    Masked rows/columns of W are replaced by the identity (their ``y`` is 0).

    Returns
    -------
    S11, S1y, Syy : (P,) float32
        ``1^T W^-1 1``, ``1^T W^-1 y``, ``y^T W^-1 y`` over the usable differences.
    x : (nd, P) float32 or None
        ``W^-1 1`` (zero at masked differences) when ``want_x``.
    """
    nd, npix = d.shape
    ar, ap = A
    S11 = np.zeros(npix, _F32)
    S1y = np.zeros(npix, _F32)
    Syy = np.zeros(npix, _F32)
    if want_x:
        Lo = np.zeros((nd, npix), _F32)
        Z = np.empty((nd, npix), _F32)
    u = v = Dprev = None
    one = _F32(1)
    for i in range(nd):
        a = s2 * ar[i]
        if ap is not None:
            a = a + f * ap[i]
        a = np.where(valid[i], a, one)
        y = d[i] - fref
        y *= mf[i]
        if i == 0 or B is None:
            D = a
            u = mf[i]
            v = y
        else:
            b = s2 * B[0][i - 1]
            if B[1] is not None:
                b = b + f * B[1][i - 1]
            b = b * mc[i - 1]
            ell = b / Dprev
            D = a - ell * b
            u = mf[i] - ell * u
            v = y - ell * v
            if want_x:
                Lo[i] = ell
        invd = one / D
        ud = u * invd
        S11 += u * ud
        S1y += v * ud
        Syy += v * v * invd
        if want_x:
            Z[i] = ud
        Dprev = D
    if not want_x:
        return S11, S1y, Syy, None
    x = Z
    for i in range(nd - 2, -1, -1):
        x[i] -= Lo[i + 1] * x[i + 1]
    return S11, S1y, Syy, x


def _quad(x, A, B):
    """``x^T M x`` for the tridiagonal M with diagonal A (nd,) and off-diagonal B."""
    a = np.asarray(A, _F32)[:, None]
    q = (a * x * x).sum(axis=0)
    if x.shape[0] > 1:
        b = np.asarray(B, _F32)[:, None]
        q += 2 * (b * x[:-1] * x[1:]).sum(axis=0)
    return q


def _detect_jumps(d, valid, s2, ro, thr):
    """Flag jumps in one integration; ``valid`` (nd, P) is updated in place.

    Each pass computes, for the pixels still being tested, the GLS outlier
    statistics of :func:`_jump_statistics` at the rate ``max(median(d), 0)``, flags
    the largest one above ``thr`` (a single difference, or a pair sharing a
    multi-read resultant) together with the neighbours that share a multi-read
    resultant with the flagged span, and repeats on the pixels that had a flag.

    Returns the (nd, P) bool array of flagged differences.
    """
    nd, npix = d.shape
    jumps = np.zeros((nd, npix), bool)
    multi = ro.n > 1                                   # multi-read resultants
    idx = np.flatnonzero(valid.sum(axis=0) >= 3)
    for _ in range(nd - 2):
        if idx.size == 0:
            break
        dd = d[:, idx]
        vv = valid[:, idx]
        srt = np.where(vv, dd, np.inf).T.copy()
        srt.sort(axis=1)
        n = vv.sum(axis=0)
        lo = np.take_along_axis(srt, ((n - 1) // 2)[:, None], axis=1)[:, 0]
        hi = np.take_along_axis(srt, (n // 2)[:, None], axis=1)[:, 0]
        med = _F32(0.5) * (lo + hi)
        s2i = s2 if np.isscalar(s2) else s2[idx]
        lo = _F32(_RATE_FLOOR) * (s2i == 0)            # see _fit_block
        z, zp = _jump_statistics(dd, vv, med, s2i, np.maximum(med, lo), ro)
        cols = np.arange(idx.size)
        first = z.argmax(axis=0)
        zmax = z[first, cols]
        last = first.copy()
        if zp is not None:
            q = zp.argmax(axis=0)
            zq = zp[q, cols]
            better = zq > zmax
            first = np.where(better, q, first)
            last = np.where(better, q + 1, last)
            zmax = np.where(better, zq, zmax)
        hit = zmax > thr
        ih, a, b = idx[hit], first[hit], last[hit]
        # A hit may have arrived during a multi-read resultant at either end of the
        # flagged span; the differences beyond that share it are excluded too
        # (unconditionally: a data-dependent choice would bias the slope).
        left = (a >= 1) & multi[a]
        right = (b + 1 < nd) & multi[np.minimum(b + 1, nd - 1)]
        for pos, sel in ((a, None), (b, None), (a - 1, left), (b + 1, right)):
            p, i = (pos, ih) if sel is None else (pos[sel], ih[sel])
            jumps[p, i] |= valid[p, i]
            valid[p, i] = False
        idx = ih[valid[:, ih].sum(axis=0) >= 3]
    return jumps


def _jump_statistics(d, valid, fref, s2, f, ro):
    """GLS outlier statistics for a jump in each difference and each shared pair.

    For the model ``d = f 1 + J s + noise`` with covariance ``C`` (at rate ``f``),
    the standardised score statistic for a jump of signature ``s`` is::

        z = s^T C^-1 r / sqrt(s^T C^-1 s - (s^T C^-1 1)^2 / (1^T C^-1 1)),

    ``r = d - f_hat 1`` the GLS residuals; under no jump it is N(0, 1) whatever the
    readout, so the false-positive rate per test is ``2 Q(threshold)``.  Single
    differences use ``s = e_i``; a hit halfway through a multi-read resultant
    ``R_{i+1}`` adds half its charge to ``D_i`` and half to ``D_{i+1}``:
    ``s = e_i / dt_i + e_{i+1} / dt_{i+1}``.  ``(C^-1)_ii = 1/(delta_i + eta_i - a_i)``
    with forward and backward pivots ``delta``, ``eta``, and
    ``(C^-1)_{i,i+1} = -b_i (C^-1)_{i+1,i+1} / delta_i``.

    Returns |z| for singles (nd, n) and for pairs (nd - 1, n) or None (no pair
    shares a multi-read resultant); 0 where a difference is not usable.
    """
    nd, npix = d.shape
    mf = valid.astype(_F32)
    a = np.empty((nd, npix), _F32)
    for i in range(nd):
        a[i] = np.where(valid[i], s2 * float(ro.Ar[i]) + f * float(ro.Ap[i]), _F32(1))
    np.maximum(a, _F32(_TINY), out=a)
    b = np.empty((max(nd - 1, 0), npix), _F32)
    for i in range(nd - 1):
        b[i] = (s2 * float(ro.Br[i]) + f * float(ro.Bp[i])) * mf[i] * mf[i + 1]
    y = (d - fref) * mf
    # forward pivots, L, and forward solves for 1 and y
    delta = np.empty_like(a)
    ell = np.zeros_like(a)
    zu = np.empty_like(a)
    zv = np.empty_like(a)
    S11 = np.zeros(npix, _F32)
    S1y = np.zeros(npix, _F32)
    for i in range(nd):
        if i == 0:
            delta[0], u, v = a[0], mf[0], y[0]
        else:
            ell[i] = b[i - 1] / delta[i - 1]
            delta[i] = a[i] - ell[i] * b[i - 1]
            u = mf[i] - ell[i] * u
            v = y[i] - ell[i] * v
        zu[i] = u / delta[i]
        zv[i] = v / delta[i]
        S11 += u * zu[i]
        S1y += v * zu[i]
    for i in range(nd - 2, -1, -1):                    # back substitution
        zu[i] -= ell[i + 1] * zu[i + 1]
        zv[i] -= ell[i + 1] * zv[i + 1]
    h = zu                                               # C^-1 1
    shift = np.divide(S1y, S11, out=np.zeros(npix, _F32), where=S11 > 0)
    g = zv - shift * h                                   # C^-1 r
    eta = np.empty_like(a)
    eta[nd - 1] = a[nd - 1]
    for i in range(nd - 2, -1, -1):
        eta[i] = a[i] - b[i] * b[i] / eta[i + 1]
    xd = _F32(1) / (delta + eta - a)                     # diag of C^-1
    inv11 = np.divide(1, S11, out=np.zeros(npix, _F32), where=S11 > 0)
    den = np.maximum(xd - h * h * inv11, _F32(_TINY))
    z = np.abs(g) * mf / np.sqrt(den)
    pair_ok = ro.n[1:-1] > 1
    if nd < 2 or not pair_ok.any():
        return z, None
    xo = -b * xd[1:] / delta[:-1]                        # (C^-1)_{i,i+1}
    s0 = (1 / ro.dt[:-1]).astype(_F32)[:, None]
    s1 = (1 / ro.dt[1:]).astype(_F32)[:, None]
    num = s0 * g[:-1] + s1 * g[1:]
    sh = s0 * h[:-1] + s1 * h[1:]
    den_p = s0 * s0 * xd[:-1] + 2 * s0 * s1 * xo + s1 * s1 * xd[1:] - sh * sh * inv11
    ok = mf[:-1] * mf[1:] * pair_ok[:, None]
    zp = np.abs(num) * ok / np.sqrt(np.maximum(den_p, _F32(_TINY)))
    return z, zp


# ---------------------------------------------------------------------- theory
def _broadcast_rate_noise(rate, read_noise):
    rate = np.asarray(rate, dtype=float)
    read_noise = np.asarray(read_noise, dtype=float)
    if not np.all(np.isfinite(rate)) or np.any(rate < 0):
        raise ParameterError(f"'rate' must be finite and >= 0 e-/s, got {rate!r}")
    if not np.all(np.isfinite(read_noise)) or np.any(read_noise < 0):
        raise ParameterError(
            f"'read_noise' must be finite and >= 0 e- per read, got {read_noise!r}")
    try:
        return np.broadcast_arrays(rate, read_noise)
    except ValueError as exc:
        raise ParameterError(
            f"'rate' shape {rate.shape} and 'read_noise' shape {read_noise.shape} do "
            f"not broadcast") from exc


def optimal_variance(rate, read_times, read_noise):
    """Variance of the optimal (GLS) slope, ``1 / (1^T C^-1 1)``, for a known rate.

    Parameters
    ----------
    rate : float or ndarray, e-/s (>= 0)
    read_times : sequence of 1-D arrays, seconds from reset
        Read times of each resultant (>= 2 resultants).
    read_noise : float or ndarray, e- per read (not CDS), broadcast with ``rate``

    Returns
    -------
    ndarray or float, (e-/s)^2, float64
        The theoretical minimum variance of an unbiased linear slope estimate for
        that readout (Brandt 2024, eqs. 28-29); 0 where rate and read noise are 0.
        Per-pixel read times (global reset) give the same result as the 1-D times:
        the variance depends on time differences only.
    """
    times, _ = _check_read_times(read_times)
    if len(times) < 2:
        raise ParameterError(f"'read_times' needs >= 2 resultants for a slope, got "
                             f"{len(times)}")
    rate, rn = _broadcast_rate_noise(rate, read_noise)
    ro = _Readout(times)
    s2 = rn ** 2
    S11 = np.zeros(rate.shape)
    u = Dprev = None
    with np.errstate(divide="ignore", invalid="ignore"):
        for i in range(ro.dt.size):
            a = s2 * ro.Ar[i] + rate * ro.Ap[i]
            if i == 0:
                D, u = a, np.ones(rate.shape)
            else:
                b = s2 * ro.Br[i - 1] + rate * ro.Bp[i - 1]
                ell = b / Dprev
                D = a - ell * b
                u = 1 - ell * u
            S11 = S11 + u * u / D
            Dprev = D
        out = 1 / S11
    out = np.where((rate == 0) & (rn == 0), 0.0, out)     # no noise at all
    return float(out) if out.ndim == 0 else out


def ols_variance(rate, read_times, read_noise):
    """Exact variance of the equal-weight least-squares slope (resultants vs ``tbar``).

    The estimator is ``sum_i c_i R_i`` with ``c_i = (tbar_i - <tbar>) / S_tt``; its
    variance is ``c^T Sigma c`` with the full covariance of the resultants
    ``Sigma_ij = sigma^2 delta_ij / N_i + f m_ij``, ``m_ii = tau_i``,
    ``m_ij = tbar_min(i,j)`` (see the module notes).

    Parameters
    ----------
    rate : float or ndarray, e-/s (>= 0)
    read_times : sequence of 1-D arrays, seconds from reset (>= 2 resultants)
    read_noise : float or ndarray, e- per read (not CDS)

    Returns
    -------
    ndarray or float, (e-/s)^2, float64
    """
    times, _ = _check_read_times(read_times)
    if len(times) < 2:
        raise ParameterError(f"'read_times' needs >= 2 resultants for a slope, got "
                             f"{len(times)}")
    rate, rn = _broadcast_rate_noise(rate, read_noise)
    ro = _Readout(times)
    tb = ro.tbar
    c = (tb - tb.mean()) / np.sum((tb - tb.mean()) ** 2)
    idx = np.arange(tb.size)
    m = tb[np.minimum.outer(idx, idx)]
    m[idx, idx] = ro.tau
    q_read = float(np.sum(c * c / ro.n))
    q_pois = float(c @ m @ c)
    out = rn ** 2 * q_read + rate * q_pois
    return float(out) if out.ndim == 0 else out


def rauscher2007_variance(rate, ngroups, nframes, groupgap, t_frame, read_noise):
    """Equal-weight least-squares slope variance for an even MULTIACCUM ramp.

    Rauscher et al. (2007, PASP 119, 768), eq. 1, with the sign and factor of the
    third term corrected, for ``n`` groups of ``m`` frames, group time
    ``t_g = (m + groupgap) t_f`` and first read one frame after reset::

        sigma_tot^2 = 12 (n-1) sigma^2 / (m n (n+1))
                      + 6 (n^2+1) (n-1) t_g f / (5 n (n+1))
                      - 2 (m^2-1) (n-1) t_f f / (m n (n+1))

    is the variance of the total counts over ``(n-1) t_g``; the slope variance is
    ``sigma_tot^2 / ((n-1) t_g)^2``.  The third term follows from
    ``tau - tbar = -(m^2 - 1) t_f / (6 m)`` for ``m`` evenly spaced frames.

    Parameters
    ----------
    rate : float or ndarray, e-/s
    ngroups : int (>= 2)
    nframes : int (>= 1)
    groupgap : int (>= 0), frames dropped between groups
    t_frame : float, s (> 0)
    read_noise : float or ndarray, e- per read (not CDS)

    Returns
    -------
    ndarray or float, (e-/s)^2
    """
    for name, val, lo in (("ngroups", ngroups, 2), ("nframes", nframes, 1),
                          ("groupgap", groupgap, 0)):
        if isinstance(val, bool) or not isinstance(val, numbers.Integral) or val < lo:
            raise ParameterError(f"{name!r} must be an integer >= {lo}, got {val!r}")
    t_frame = _check_real("t_frame", t_frame, minimum=0.0, strict=True)
    rate, rn = _broadcast_rate_noise(rate, read_noise)
    n, m = float(ngroups), float(nframes)
    tg = (m + groupgap) * t_frame
    tot = (12 * (n - 1) * rn ** 2 / (m * n * (n + 1))
           + 6 * (n * n + 1) * (n - 1) * tg * rate / (5 * n * (n + 1))
           - 2 * (m * m - 1) * (n - 1) * t_frame * rate / (m * n * (n + 1)))
    out = tot / ((n - 1) * tg) ** 2
    return float(out) if out.ndim == 0 else out
