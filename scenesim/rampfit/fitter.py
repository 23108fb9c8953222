"""Up-the-ramp slope fitting: CDS, equal-weight least squares and optimal GLS.

Conventions
-----------
Resultants are in electrons (the caller multiplies DN by the gain and subtracts
nothing else), times in seconds from the pixel's reset, rates in e-/s.  The read
noise ``sigma`` is the noise of **one read** (one frame), in e-, never the CDS noise
(CDS noise = sqrt(2) sigma).  The JWST calibration library stcal instead takes the
CDS read noise in DN; convert with ``sigma = rnoise_cds_dn * gain / sqrt(2)``.

Model: the rate estimates ``d_i = (R_{i+1} - R_i) / dt_i`` all have mean ``f`` and a
tridiagonal covariance ``C(f)`` (Brandt 2024, PASP 136, 045004, eqs. 28-29;
:mod:`scenesim.rampfit.covariance`).  The best linear unbiased estimate is the GLS
mean ``f_hat = (1^T C^-1 d) / (1^T C^-1 1)`` with variance ``1 / (1^T C^-1 1)``
(:func:`scenesim.rampfit.variance.optimal_variance`).  Differencing removes the
unknown zero point (bias, kTC), and the GLS estimate from differences equals the GLS
estimate from resultants with a free intercept.

Algorithm
---------
All fitters are one routine: a weighted mean of the ``d_i`` whose weights are
``W^-1 1 / (1^T W^-1 1)`` for a tridiagonal "weighting" matrix ``W``:

* ``'gls'``: ``W = C(f)`` -- optimal.  ``f`` is unknown.  First fit: start from the
  CDS estimate, clip at >= 0 for the covariance, re-solve ``n_iter`` times.  Weights
  evaluated at the pixel's own noisy rate are correlated with its noise, which
  biases and degrades the slope where the Poisson part of ``C`` is comparable to
  the read part over one standard deviation of the rate (rates ~0 with low read
  noise: +0.05 to +0.45 sigma and std/sqrt(V_opt) 1.04-1.79 at read noise 1 and
  0.1 e-).  With the default ``variance_rate='local'`` the pixels whose reported
  variance takes its rate from the neighbours
  (:func:`scenesim.rampfit.local_rate.uses_neighbours`) are therefore solved again
  with ``C`` at the *weight rate* of :func:`scenesim.rampfit.local_rate.local_rates`
  (the neighbours' median, shrunk toward 0 where it cannot be told from 0; not the
  pixel's own rate unless the pixel stands out from its neighbours), in two rounds
  (the second from the refitted neighbours, only where the rate moved ``C`` by
  > 5 %); with a known ``variance_rate`` array every pixel is solved again at that
  rate; ``'fit'`` keeps the first fit (per pixel, independent of the neighbours).
* ``'ols'``: ``W`` = covariance of differences of independent, equal-variance
  resultants (``2`` on the diagonal and ``-1`` off it, in charge units): this is
  exactly equal-weight least squares of the resultants against ``tbar`` with a free
  intercept (Rauscher et al. 2007).
* ``'cds'``: ``W = diag(1/dt_i)``: ``sum D_i / sum dt_i``, i.e. last minus first usable
  resultant over their ``tbar`` difference.

The tridiagonal systems are solved by :func:`scenesim.rampfit.solver.ldl_pass`
(vectorised over pixels, float32, in row chunks on a thread pool); the weights are
propagated through the model covariance to split the variance into a read part
(``sigma^2`` terms) and a Poisson part (``f`` terms)::

    var_read = sigma^2 w^T C_read w,     var_poisson = r w^T C_poisson w

with ``r`` the *variance rate* (:mod:`scenesim.rampfit.local_rate`;
``max(slope, 0)`` with ``variance_rate='fit'``).  The split holds for any weights, so
the reported variance is that of the weights actually used, at rate ``r``; for GLS
weighted at ``r`` itself (a known rate) it is ``1 / (1^T C(r)^-1 1)``.

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
(usable differences of all integrations minus one).  For GLS its expectation is 1
at the true rate; with ``variance_rate='local'`` the refitted pixels' chi-square is
taken at the variance rate, not at the weight rate (which is shrunk toward 0 near 0
and read it 1.03-1.07 for faint pixels; now 1.006-1.025 at 0.05 e-/s and 1 e- read
noise, against 1.000-1.015 with ``'fit'``; docs/VALIDATION_FIT.md);
for OLS and CDS it is ``1 + (V/V_opt - 1)/dof`` (slightly above 1).  ``chi2 = 0`` where
``dof <= 0``.  :func:`scenesim.rampfit.variance.model_chi2` evaluates the same
quantity for a rate from elsewhere (e.g. another fitter's).

Saturation, jumps and short ramps
---------------------------------
* Only resultants before the first saturated one are used.  DQ ``SATURATED`` is set
  when any resultant of the pixel is saturated (even if the slope is measured).
* Jumps (``jump_threshold`` in sigma): :mod:`scenesim.rampfit.jumps`; flagged
  differences are excluded, which splits the ramp into independent segments, and
  ``n_jumps`` counts them.
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

Precision: the differences are taken in the input's dtype (float64 for float64 or
integer input) before the float32 arithmetic, so float64 resultants keep their
precision whatever their size (1000 reads at 1e7 e-/s: chi2 1.00).  float32 input
is rounded before the fitter sees it (to 2^14 e- at 1e11 e-), noise the model does
not include (chi2 1.05 there): keep resultants above ~1e9 e- in float64, or take
the differences before casting.

Row blocks
----------
The fit runs by blocks of rows (``block_rows``; by default about
:data:`scenesim.rampfit.solver.CHUNK_PIXELS` pixels, so the cost per difference is
the same at every ramp length: time linear in the number of resultants), each read
from ``resultants`` when a worker thread takes it up: a view of an in-memory array,
or a read from a file through a row source (:mod:`scenesim.io.cuberows`), so a cube
larger than memory can be fitted.  The fit passes over the blocks up to four times:
a finiteness check (float data only), the first fit, and with GLS the solves at the
weight rate, which re-read only the blocks holding a pixel to refit (a block where
most pixels are refitted is solved whole; the few refitted pixels of the other blocks
are gathered into batches of a block's size).  The neighbourhood rates between the
passes use the per-pixel outputs of the whole frame.  Every step is per pixel, so the
result does not depend on the block size or the thread count, to the last bit.

Cost: memory is the outputs, ~40 bytes per pixel per integration (670 MB at
4096 x 4096, whatever the ramp length), plus ~30 bytes per value of the blocks in
flight (two per thread; ~130 MB per block at 200 resultants); the cube itself is
held only when the caller passes it as an array.  Time: ~25 numpy calls per
difference and solve, each a pass over one block's (pixels,) vector: the fit is
bound by the number of those passes, not by reading the cube
(``scenesim bench fit``, BENCHMARKS.md).  The second solve at the weight rate costs
nothing where every pixel is bright enough not to need its neighbours
(``kappa^2 < 3e-3``), up to ~2 solves more (jump detection repeated only on pixels
with a jump) in dark, read-noise dominated frames.  Measured timings are in
``docs/VALIDATION_FIT.md``.
"""

import collections
import contextlib
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from noise.errors import ParameterError, ParameterTypeError
from noise.validate import check_choice, check_float, check_int, check_map, check_mask

from scenesim.detector.dq import (BAD_VARIANCE, DO_NOT_USE, JUMP_DET, REFERENCE_PIXEL,
                                  SATURATED)
from scenesim.io.fitfile import FitResult
from scenesim.rampfit.covariance import RATE_FLOOR, RampCovariance, check_resultant_noise
from scenesim.rampfit.jumps import flag_jumps, jump_block
from scenesim.rampfit.local_rate import local_rates, uses_neighbours
from scenesim.rampfit.solver import TINY, ldl_pass, quad_form, row_chunks
from scenesim.rampfit.times import check_read_times, shortest_spacing

__all__ = ["FITTERS", "VARIANCE_RATES", "fit_ramps"]

#: Fitter names accepted by :func:`fit_ramps`.
FITTERS = ("cds", "ols", "gls")

#: Named choices of the rate of the reported Poisson variance (:func:`fit_ramps`).
VARIANCE_RATES = ("local", "fit")

_F32 = np.float32
#: Per-pixel outputs of a chunk written to the FitResult, and the auxiliary ones.
_OUTPUTS = ("slope", "var_read", "chi2", "dof", "dq", "slope_ints", "var_ints",
            "n_jumps")
_AUX = ("pcoef", "pcoef_ints")
#: Above this fraction of a row block's pixels refitted, the refit solves the whole
#: block (no gather) and keeps those pixels.
_DENSE_REFIT = 0.5
#: Row blocks in flight per worker thread (each holds its rows' resultants).
_WINDOW = 2


# ---------------------------------------------------------------------- entry point
#: Largest read noise per read (e-) :func:`fit_ramps` takes: its square, 1e30 e-^2,
#: stays far inside float32.
MAX_READ_NOISE = 1e15
#: Largest rate scale (e-/s) :func:`fit_ramps` takes: a resultant, the read noise or
#: ``variance_rate`` over the shortest read spacing.  Rates, their squares (1e30) and
#: sums of squares stay finite in float32; beyond it a fit used to overflow and give
#: every pixel DO_NOT_USE without a word.
MAX_RATE_SCALE = 1e15


def fit_ramps(resultants, read_times, *, read_noise, gain=1.0, fitter="gls",
              saturated=None, jump_threshold=None, n_iter=2, refmask=None,
              zero_point=None, threads=None, variance_rate="local", block_rows=None,
              resultant_noise=0.0):
    """Fit a rate to every pixel's resultants.

    Parameters
    ----------
    resultants : ndarray, shape (nres, ny, nx) or (nints, nres, ny, nx), e-, or a row source
        Resultants of one or several integrations, in electrons (DN times gain;
        nothing else subtracted: with a dark ramp subtracted the net rate may be
        negative while the Poisson variance is that of the collected charge, and the
        covariance, taken at a rate >= 0, understates it; pass the collected rate
        as ``variance_rate``: a probe's -1 e-/s net ramps reported E[z^2] = 9.3
        with 'local', 1.03 with the collected rate).  Any real dtype; differences
        are taken in the input dtype (float64 for integers), the rest in float32
        (module notes: keep resultants above ~1e9 e- in float64).  A *row source*
        (:mod:`scenesim.io.cuberows`, e.g. :func:`scenesim.io.cuberows.exposure_rows`
        of an exposure file) is read by row blocks, so the cube is never held in
        memory (module notes, "Row blocks").
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
    saturated : ndarray of bool, same shape as ``resultants``, or a row source, optional
        Saturated resultants; only resultants before the first saturated one of
        each pixel and integration are used (flagged values may be NaN).  A row
        source (``shape`` that of ``resultants`` as 4-D, ``dtype`` bool) is read by
        row blocks with the resultants.
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
        Worker threads over row chunks (None: ``min(os.cpu_count(), 8)``).  The
        result does not depend on it.
    variance_rate : {'local', 'fit'} or ndarray (ny, nx), e-/s
        Rate at which the Poisson part of the reported variances (``var_poisson``,
        ``var_ints``) is evaluated, and, for GLS, where the rate of the weights
        comes from (module notes).  ``'local'`` (default): the median of the
        pixel's 5 x 5 neighbours, or its own fitted rate where it stands out from
        them (:func:`scenesim.rampfit.local_rate.local_rates`); the GLS weights of
        read-noise dominated pixels at the neighbours' rate shrunk toward 0.  A
        faint source that does not stand out (a few e- per ramp, < ~3 sigma above
        its neighbours) therefore reports too small an error (``E[z^2]`` 2.4-2.7 at
        6 e- per ramp; module notes of :mod:`~scenesim.rampfit.local_rate`): pass
        known sources' rates as an array.
        ``'fit'``: the pixel's own fitted rate clipped at 0, for the weights
        (iterated) and the variance (stcal and fitramp practice; each pixel's
        result depends on its own ramp only).  Its error is correlated with the
        slope's, which biases faint slopes, and where the rate is not well above
        its own scatter, ``max(rate, 0)`` is biased up, so the reported variance
        is too large, by more the smaller the read noise: at rate 0, 10 reads
        10 s apart, the mean reported variance is about 1.06, 1.18, 1.4 and 1.8
        times the mean squared error at 5, 2, 1 and 0.5 e- read noise
        (``tests/rampfit/test_variance.py``).  An array: a rate known independently of
        these data (e.g. a dark calibration or a deeper exposure), clipped at 0,
        for the weights and the variance: optimal and calibrated.
    block_rows : int or None
        Rows per block (>= 1) read and solved at once; None: about
        :data:`scenesim.rampfit.solver.CHUNK_PIXELS` pixels per block on one thread,
        up to :data:`~scenesim.rampfit.solver.CHUNK_PIXELS_THREADED` on more
        (:func:`scenesim.rampfit.solver.chunk_pixels`; fewer for ramps above 256
        resultants).  The result does not depend on it, to the last bit.
    resultant_noise : float or sequence of nres floats, e- rms
        White noise added to each resultant once, independently of its reads (>= 0;
        default 0): the rounding of an on-board average of ``N > 1`` digitised
        reads, :func:`noise.adc.averaging_noise` (the per-read quantisation,
        ``gain**2 / 12`` per read, belongs in ``read_noise``).  It enters the
        covariance of the weights, the reported variances (``var_read``) and the
        jump test (:class:`~scenesim.rampfit.covariance.RampCovariance`); without it
        such data report too small errors (read-noise dominated MEDIUM8 at 5 e-/DN
        and 6 e- per read: ``E[z^2]`` 1.31, 1.01 with it; ``docs/VALIDATION_FIT.md``).
        :func:`scenesim.calib.prepare.fit_exposure_file` passes it for DN data.

    Returns
    -------
    scenesim.io.fitfile.FitResult

    Raises
    ------
    noise.errors.ParameterError
        On bad input, before any work.
    """
    check_choice("fitter", fitter, FITTERS)
    src, sat = _check_resultants(resultants, saturated)
    nints, nres, ny, nx = src.shape
    times, shift = check_read_times(read_times, nres, (ny, nx))
    read_noise = check_map("read_noise", read_noise, (ny, nx), minimum=0.0)
    if np.max(read_noise) > MAX_READ_NOISE:       # its square must stay finite in float32
        raise ParameterError(
            f"'read_noise' must be <= {MAX_READ_NOISE:g} e- per read (its square is "
            f"computed in float32), got {float(np.max(read_noise))!r}")
    gain = check_float("gain", gain, minimum=0.0, strict_min=True)
    thr = None if jump_threshold is None else check_float(
        "jump_threshold", jump_threshold, minimum=0.0, strict_min=True)
    n_iter = check_int("n_iter", n_iter, minimum=1)
    if np.sqrt(check_resultant_noise(resultant_noise, nres).max()) > MAX_READ_NOISE:
        raise ParameterError(
            f"'resultant_noise' must be <= {MAX_READ_NOISE:g} e- (its square is computed "
            f"in float32), got {resultant_noise!r}")
    refmask = None if refmask is None else check_mask("refmask", refmask, (ny, nx))
    if zero_point is not None:
        zero_point = check_map("zero_point", zero_point, (ny, nx), minimum=None)
    variance_rate = _check_variance_rate(variance_rate, (ny, nx))
    threads = min(os.cpu_count() or 1, 8) if threads is None else check_int(
        "threads", threads, minimum=1)
    if block_rows is not None:
        block_rows = check_int("block_rows", block_rows, minimum=1)
    bounds = row_chunks(ny, nx, nints * nres, rows=block_rows, threads=threads)
    _check_scale(_check_finite(src, sat, bounds), times, read_noise, variance_rate)

    cov = RampCovariance(times, resultant_noise=resultant_noise)
    s2 = float(read_noise) ** 2 if np.isscalar(read_noise) else \
        (read_noise ** 2).astype(_F32)
    setup = _Setup(src, sat, s2, cov, fitter, thr, n_iter, zero_point, shift, bounds,
                   _WINDOW * threads, jump_block(nres - 1, threads))
    pool = ThreadPoolExecutor(max_workers=threads) \
        if threads > 1 and len(bounds) > 1 else None
    with pool if pool is not None else contextlib.nullcontext():
        out = _fit_chunks(setup, pool)
        if refmask is not None:
            out["dq"][refmask] |= np.uint32(REFERENCE_PIXEL | DO_NOT_USE)
        local = fitter == "gls" and isinstance(variance_rate, str) and \
            variance_rate == "local"
        rate_v, rate_w, refit = _variance_rate(variance_rate, out, pool,
                                               own_share=not local)
        # with 'local' the weight rate is shrunk toward 0 where it cannot be told
        # from 0: the chi-square is taken at the variance rate (one more solve; at
        # the weight rate it read 1.03-1.07 for faint uniform pixels)
        if fitter == "gls" and refit is not None:
            _refit_at_rate(setup, out, rate_w, refit, pool,
                           chi_rate=rate_v if local else None)
        if local and refit.any():
            # second round, from the refitted (efficient) slopes: the own rate
            # joins the weight rate where the pixel stands out from its neighbours
            prev = rate_w
            rate_v, rate_w, refit = _variance_rate(variance_rate, out, pool)
            _refit_at_rate(setup, out, rate_w, refit & _moved(prev, rate_w, out),
                           pool, chi_rate=rate_v)
    pcoef, pcoef_ints = out.pop("pcoef"), out.pop("pcoef_ints")
    out["var_poisson"] = (rate_v * pcoef).astype(_F32)
    out["var_ints"] += rate_v[None] * pcoef_ints
    rn = float(read_noise) if np.isscalar(read_noise) else float(np.median(read_noise))
    return FitResult(gain=gain, read_noise=rn, fitter=fitter, **out)


# ---------------------------------------------------------------------- validation
def _check_resultants(resultants, saturated):
    """``resultants`` and ``saturated`` as row sources of shape (nints, nres, ny, nx)
    (``saturated`` None if not given)."""
    if _is_row_source(resultants):
        src = _check_row_source(resultants)
    else:
        src = _ArrayRows(_resultant_array(resultants))
    if saturated is None:
        return src, None
    if _is_row_source(saturated):
        if tuple(saturated.shape) != src.shape or np.dtype(saturated.dtype) != bool:
            raise ParameterError(
                f"'saturated' row source must give bool blocks of shape {src.shape}, "
                f"got {np.dtype(saturated.dtype)} {tuple(saturated.shape)}")
        return src, _SourceRows(saturated, src.shape, "saturated")
    sat = check_mask("saturated", saturated, src.shape if src.ndim == 4 else
                     src.shape[1:])
    return src, _ArrayRows(sat if sat.ndim == 4 else sat[None])


def _resultant_array(resultants):
    """``resultants`` as a 3-D or 4-D real ndarray (checked)."""
    if isinstance(resultants, np.ma.MaskedArray):
        # a mask would be ignored: the values under it fitted as data (a probe's
        # masked 1e9 read gave -2.4e6 e-/s with DQ 0); an empty one changes nothing
        if np.ma.getmaskarray(resultants).any():
            raise ParameterTypeError(
                "'resultants' is a masked array with masked values, whose mask "
                "fit_ramps does not read: pass the data (np.ma.getdata) and the masked "
                "reads as 'saturated' (they and the later reads of the pixel are then "
                "left out)")
        resultants = np.ma.getdata(resultants)
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
    if min(resultants.shape) == 0:
        raise ParameterError(f"'resultants' must not be empty, got shape "
                             f"{resultants.shape}")
    return resultants


def _is_row_source(obj):
    return not isinstance(obj, np.ndarray) and callable(getattr(obj, "rows", None)) \
        and hasattr(obj, "shape") and hasattr(obj, "dtype")


def _check_row_source(src):
    """A row source (:mod:`scenesim.io.cuberows`) with a 4-D shape and a real dtype."""
    shape = tuple(src.shape)
    if len(shape) != 4 or not all(isinstance(v, (int, np.integer)) and v > 0
                                  for v in shape):
        raise ParameterError(
            f"'resultants' row source must have a shape (nints, nres, ny, nx) of "
            f"positive integers, got {shape!r}")
    if np.dtype(src.dtype).kind not in "iuf":
        raise ParameterError(f"'resultants' row source must give real numbers (e-), "
                             f"got dtype {src.dtype}")
    return _SourceRows(src, shape, "resultants")


class _ArrayRows:
    """An in-memory (nints, nres, ny, nx) array (or a 3-D one, one integration) as a
    row source: blocks are views."""

    all_finite = False

    def __init__(self, array):
        self.ndim = array.ndim
        self.array = array if array.ndim == 4 else array[None]
        self.shape = self.array.shape
        self.dtype = array.dtype

    def rows(self, y0, y1):
        return self.array[:, :, y0:y1]


class _SourceRows:
    """A caller's row source, its blocks checked for shape."""

    ndim = 4

    def __init__(self, src, shape, name):
        self.src, self.shape, self.dtype = src, shape, np.dtype(src.dtype)
        self.all_finite = bool(getattr(src, "all_finite", False))
        self.name = name

    def rows(self, y0, y1):
        blk = np.asarray(self.src.rows(y0, y1))
        want = self.shape[:2] + (y1 - y0, self.shape[3])
        if blk.shape != want:
            raise ParameterError(f"{self.name!r} row source gave shape {blk.shape} for "
                                 f"rows {y0}:{y1}, expected {want}")
        return blk


def _check_variance_rate(variance_rate, shape):
    if not isinstance(variance_rate, str):
        return check_map("variance_rate", variance_rate, shape, minimum=None)
    try:
        return check_choice("variance_rate", variance_rate, VARIANCE_RATES)
    except ParameterError as exc:
        raise ParameterError(f"{exc}; or an array of shape {shape} (e-/s)") from exc


def _check_finite(src, sat, bounds):
    """Raise unless the resultants are finite wherever ``sat`` does not flag them;
    return the largest ``|resultant|`` there, or a bound of it (one pass over the row
    blocks; none for a source that says it is finite or for 8- and 16-bit
    integers, whose dtype bounds them)."""
    if src.all_finite or (src.dtype.kind in "iu" and src.dtype.itemsize <= 2):
        return float(np.iinfo(src.dtype).max) if src.dtype.kind in "iu" else 0.0
    nints, nres = src.shape[:2]
    nbad = np.zeros((nints, nres), np.int64)
    largest = 0.0
    for y0, y1 in bounds:
        blk = src.rows(y0, y1)
        good = None if src.dtype.kind in "iu" else np.isfinite(blk)
        flagged = sat.rows(y0, y1) if sat is not None else None
        if good is not None:
            bad = ~good if flagged is None else ~good & ~flagged
            nbad += bad.sum(axis=(2, 3))
        if flagged is not None and not flagged.any():
            flagged = None
        if flagged is None and (good is None or good.all()):     # two reductions
            largest = max(largest, abs(float(blk.max())), abs(float(blk.min())))
        else:
            use = ~flagged if good is None else (good if flagged is None
                                                 else good & ~flagged)
            if use.any():
                largest = max(largest, float(np.abs(blk[use]).max()))
    if nbad.any():
        k, r = np.argwhere(nbad)[0]
        raise ParameterError(
            f"'resultants' must be finite where not flagged in 'saturated'; "
            f"integration {k} resultant {r} has {int(nbad[k, r])} NaN or inf values")
    return largest


def _check_scale(largest, times, read_noise, variance_rate):
    """Refuse inputs whose rates overflow the fit's float32 (:data:`MAX_RATE_SCALE`):
    the largest resultant or read noise over the shortest read spacing, or a
    ``variance_rate`` above it."""
    dt = shortest_spacing(times)
    for name, value in (("resultants", largest),
                        ("read_noise", float(np.max(read_noise)))):
        if value / dt > MAX_RATE_SCALE:
            raise ParameterError(
                f"'{name}' up to {value:g} e- over the shortest read spacing of "
                f"'read_times', {dt:g} s, is a rate of {value / dt:g} e-/s; the fit "
                f"works in float32 and takes rates up to {MAX_RATE_SCALE:g} e-/s (are "
                f"the resultants in e- and the read times in s?)")
    if not isinstance(variance_rate, str) and \
            float(np.max(variance_rate)) > MAX_RATE_SCALE:
        raise ParameterError(
            f"'variance_rate' must be <= {MAX_RATE_SCALE:g} e-/s (its Poisson variance "
            f"is computed in float32), got {float(np.max(variance_rate))!r}")


# ---------------------------------------------------------------------- chunks
@dataclass(frozen=True, eq=False)
class _Setup:
    """What every row block of one :func:`fit_ramps` call needs (validated)."""

    src: object                # row source of the resultants
    sat: object                # row source of the saturation flags, or None
    s2: object                 # read variance per read: float, or (ny, nx) float32
    cov: RampCovariance
    fitter: str
    thr: object
    n_iter: int
    zero_point: object
    shift: object
    bounds: list               # the row blocks [(y0, y1), ...]
    window: int                # row blocks in flight on the pool
    jump_block: int            # pixels per block of the jumps' first pass

    def chunk(self, y0, y1):
        """Arguments of :func:`_fit_block` for rows ``y0:y1``, pixels flattened
        (the rows read from the source)."""
        nints, nres = self.src.shape[:2]

        def pix(a):
            return None if a is None or np.isscalar(a) else a[y0:y1].reshape(-1)

        blk = self.src.rows(y0, y1).reshape(nints, nres, -1)
        sblk = None if self.sat is None else \
            self.sat.rows(y0, y1).reshape(nints, nres, -1)
        s2 = self.s2 if np.isscalar(self.s2) else self.s2[y0:y1].reshape(-1)
        zp = self.zero_point if self.zero_point is None or np.isscalar(
            self.zero_point) else pix(self.zero_point)
        return (blk, sblk, s2, self.cov, self.fitter, self.thr, self.n_iter, zp,
                pix(self.shift))


def _run(pool, items, window):
    """Call ``fn(arg)`` for each ``(fn, arg)`` of the iterable ``items``: here, or on
    the pool with at most ``window`` in flight (each holds a row block, so the
    memory stays bounded while ``items`` reads ahead)."""
    if pool is None:
        for fn, arg in items:
            fn(arg)
        return
    pending = collections.deque()
    try:
        for fn, arg in items:
            pending.append(pool.submit(fn, arg))
            if len(pending) >= window:
                pending.popleft().result()
        while pending:
            pending.popleft().result()
    finally:
        for f in pending:
            f.cancel()


def _fit_chunks(setup, pool):
    """Fit every row block; return the dict of (ny, nx) / (nints, ny, nx) outputs."""
    nints, _, ny, nx = setup.src.shape
    out = {"slope": np.zeros((ny, nx), _F32), "var_read": np.zeros((ny, nx), _F32),
           "chi2": np.zeros((ny, nx), _F32), "dof": np.zeros((ny, nx), np.int32),
           "dq": np.zeros((ny, nx), np.uint32),
           "slope_ints": np.zeros((nints, ny, nx), _F32),
           "var_ints": np.zeros((nints, ny, nx), _F32),
           "n_jumps": np.zeros((ny, nx), np.int32),
           "pcoef": np.zeros((ny, nx), _F32),
           "pcoef_ints": np.zeros((nints, ny, nx), _F32)}

    def work(bound):
        y0, y1 = bound
        shp = (y1 - y0, nx)
        for key, val in _fit_block(*setup.chunk(y0, y1),
                                   jump_pixels=setup.jump_block).items():
            if key not in out:
                continue
            if val.ndim == 2:
                out[key][:, y0:y1] = val.reshape((nints,) + shp)
            else:
                out[key][y0:y1] = val.reshape(shp)

    _run(pool, ((work, b) for b in setup.bounds), setup.window)
    return out


def _variance_rate(variance_rate, out, pool, own_share=True):
    """Rates (ny, nx) float32 >= 0 of the reported Poisson variances and of the GLS
    weights, and the pixels to fit again with those weights ((ny, nx) bool, or
    None)."""
    usable = (out["dq"] & np.uint32(DO_NOT_USE)) == 0
    if isinstance(variance_rate, str) and variance_rate == "local":
        need = uses_neighbours(out["slope"], out["var_read"], out["pcoef"],
                               usable=usable)
        rate, wrate = local_rates(out["slope"], out["var_read"], out["pcoef"],
                                  usable=usable, pool=pool, own_share=own_share,
                                  need=need)
        return rate, wrate, need
    if isinstance(variance_rate, str):
        own = np.maximum(out["slope"], _F32(0))
        return own, own, None
    known = np.maximum(np.broadcast_to(np.asarray(variance_rate, dtype=_F32),
                                       usable.shape), _F32(0))
    return known, known, usable


def _moved(prev, rate, out):
    """Pixels whose weight rate moved the covariance by more than 5 % (of the
    slope variance at the new rate): a smaller change moves the GLS weights' variance
    by ~1e-3 of itself or less (second order)."""
    v = out["var_read"] + out["pcoef"] * rate
    return np.abs(rate - prev) * out["pcoef"] > _F32(0.05) * v


def _refit_at_rate(setup, out, rate, refit, pool, chi_rate=None):
    """GLS of the pixels ``refit`` again, with the covariance at ``rate`` (and their
    chi-squares at ``chi_rate``, when given).

    One solve per pixel (started from the first fit's slope), on the same usable
    differences: jump detection does not depend on the weights, so it is only
    repeated on the pixels that had a jump.  Updates the slopes, read variances,
    Poisson coefficients, chi-squares and per-integration values of ``out``.

    Row blocks are read again (only those with a pixel to refit): a block where most
    pixels are refitted (dark frames) is solved whole and the others dropped; from the
    other blocks the refitted pixels are gathered into batches of about a block's
    pixels (the same per-pixel solve either way; fewer than a block's pixels in a
    batch would multiply numpy's per-call overhead).
    """
    nints, nres, ny, nx = setup.src.shape
    jumped = out["n_jumps"] > 0

    def keep(y, x, got, ok):
        y, x = y[ok], x[ok]
        for key in ("slope", "var_read", "pcoef", "chi2"):
            out[key][y, x] = got[key][ok]
        for key in ("slope_ints", "var_ints", "pcoef_ints"):
            out[key][:, y, x] = got[key][:, ok]

    def fit_rows(bound):
        y0, y1 = bound
        args = setup.chunk(y0, y1)
        got = _fit_block(*args[:6], 1, None, None,
                         frate=rate[y0:y1].reshape(-1),
                         fstart=out["slope"][y0:y1].reshape(-1),
                         fchi=None if chi_rate is None else
                         chi_rate[y0:y1].reshape(-1),
                         jumped=jumped[y0:y1].reshape(-1),
                         jump_pixels=setup.jump_block)
        y, x = np.divmod(np.arange((y1 - y0) * nx), nx)
        keep(y + y0, x, got, got["by_diff"] & refit[y0:y1].reshape(-1))

    def fit_pixels(batch):
        y, x, res, sat = batch
        s2 = setup.s2 if np.isscalar(setup.s2) else setup.s2[y, x]
        got = _fit_block(res, sat, s2, setup.cov, "gls", setup.thr, 1, None, None,
                         frate=rate[y, x], fstart=out["slope"][y, x],
                         fchi=None if chi_rate is None else chi_rate[y, x],
                         jumped=jumped[y, x], jump_pixels=setup.jump_block)
        keep(y, x, got, got["by_diff"])

    _run(pool, _refit_items(setup, refit, fit_rows, fit_pixels), setup.window)


def _refit_items(setup, refit, fit_rows, fit_pixels):
    """The work of :func:`_refit_at_rate`: ``(fit_rows, (y0, y1))`` for dense blocks,
    ``(fit_pixels, (y, x, res, sat))`` for batches gathered from the sparse ones."""
    nints, nres, ny, nx = setup.src.shape
    y0, y1 = setup.bounds[0]
    target = (y1 - y0) * nx                # a batch holds about one block's pixels
    parts, count = [], 0

    def batch():
        y, x, res, sat = zip(*parts)
        return (np.concatenate(y), np.concatenate(x), np.concatenate(res, axis=2),
                None if setup.sat is None else np.concatenate(sat, axis=2))

    for y0, y1 in setup.bounds:
        m = refit[y0:y1].reshape(-1)
        n = int(np.count_nonzero(m))
        if n == 0:
            continue
        if n > _DENSE_REFIT * m.size:
            yield fit_rows, (y0, y1)
            continue
        flat = np.flatnonzero(m)
        res = setup.src.rows(y0, y1).reshape(nints, nres, -1)[:, :, flat]
        sat = None if setup.sat is None else \
            setup.sat.rows(y0, y1).reshape(nints, nres, -1)[:, :, flat]
        y, x = np.divmod(flat, nx)
        parts.append((y + y0, x, res, sat))
        count += n
        if count >= target:
            yield fit_pixels, batch()
            parts, count = [], 0
    if parts:
        yield fit_pixels, batch()


# ---------------------------------------------------------------------- one chunk
class _Block:
    """Per-pixel outputs of one chunk of ``P`` pixels, filled by the fit steps.

    ``var_ints`` holds the read part only (the Poisson part is added by
    :func:`fit_ramps` at the variance rate); ``pcoef``/``pcoef_ints`` are the
    Poisson variances per unit rate.
    """

    def __init__(self, nints, npix):
        self.slope = np.zeros(npix, _F32)
        self.var_read = np.zeros(npix, _F32)
        self.pcoef = np.zeros(npix, _F32)
        self.chi2 = np.zeros(npix, _F32)
        self.dof = np.zeros(npix, np.int32)
        self.slope_ints = np.zeros((nints, npix), _F32)
        self.var_ints = np.full((nints, npix), BAD_VARIANCE, _F32)
        self.pcoef_ints = np.zeros((nints, npix), _F32)
        self.n_jumps = np.zeros(npix, np.int32)
        self.measured = np.zeros(npix, bool)


def _fit_block(res, sat, s2, cov, fitter, thr, n_iter, zp, tshift, *, frate=None,
               fstart=None, fchi=None, jumped=None, jump_pixels):
    """Fit one chunk: ``res`` (nints, nres, P); returns a dict of (P,)/(nints, P) arrays.

    ``frate`` (P,): GLS weights at this rate (one solve from ``fstart``) instead of
    the iteration from the CDS slope; ``fchi`` (P,): the chi-square at ``C(fchi)``
    instead of at the weights' covariance; ``jumped`` (P,) bool: run the jump detection
    on these pixels only (the others are known to have none); ``jump_pixels``: its
    first pass's block (:func:`scenesim.rampfit.jumps.jump_block`).
    """
    nints, nres, npix = res.shape
    nuse, anysat = _usable_resultants(res, sat)
    blk = _Block(nints, npix)
    by_diff = np.zeros(npix, bool)
    if nres >= 2:
        d, valid = _rate_estimates(res, sat, nuse, cov)
        if thr is not None and nres >= 3:
            blk.n_jumps = _flag_jumps_of(d, valid, s2, cov, thr, jumped, jump_pixels)
        diffs = _Differences(d, valid, s2, cov)
        if fitter == "gls":
            chi2_raw = _fit_gls(diffs, n_iter, blk, frate, fstart, fchi)
        else:
            chi2_raw = _fit_weighted(diffs, fitter, blk)
        ndof = valid.sum(axis=1, dtype=np.int32).sum(axis=0) - 1
        blk.dof = np.where(blk.measured, np.maximum(ndof, 0), 0).astype(np.int32)
        blk.chi2 = np.divide(np.maximum(chi2_raw, 0), blk.dof,
                             out=np.zeros(npix, _F32), where=blk.dof > 0).astype(_F32)
        by_diff = blk.measured.copy()
    unmeasured = ~blk.measured
    if unmeasured.any():
        blk.slope[unmeasured] = 0
        blk.var_read[unmeasured] = BAD_VARIANCE
        blk.pcoef[unmeasured] = 0
        blk.chi2[unmeasured] = 0
        if zp is not None:
            _single_resultant(res, nuse, unmeasured, s2, cov, zp, tshift, blk)
    dq = np.where(anysat, SATURATED, 0).astype(np.uint32)
    dq[blk.n_jumps > 0] |= np.uint32(JUMP_DET)
    dq[~blk.measured] |= np.uint32(DO_NOT_USE)
    return {"slope": blk.slope.astype(_F32), "var_read": blk.var_read.astype(_F32),
            "pcoef": blk.pcoef.astype(_F32), "chi2": blk.chi2, "dof": blk.dof,
            "dq": dq, "slope_ints": blk.slope_ints, "var_ints": blk.var_ints,
            "pcoef_ints": blk.pcoef_ints, "n_jumps": blk.n_jumps, "by_diff": by_diff}


def _flag_jumps_of(d, valid, s2, cov, thr, jumped, block):
    """:func:`flag_jumps` on every pixel, or on the pixels ``jumped`` only."""
    if jumped is None:
        return flag_jumps(d, valid, s2, cov, thr, block=block)
    counts = np.zeros(d.shape[2], np.int32)
    j = np.flatnonzero(jumped)
    if j.size:
        vj = valid[:, :, j]
        counts[j] = flag_jumps(d[:, :, j], vj, s2 if np.isscalar(s2) else s2[j], cov,
                               thr, block=block)
        valid[:, :, j] = vj
    return counts


def _usable_resultants(res, sat):
    """Resultants before the first saturated one (nints, P) and any saturation (P,)."""
    nints, nres, npix = res.shape
    if sat is None:
        return np.full((nints, npix), nres, np.int32), np.zeros(npix, bool)
    satany = sat.any(axis=1)
    nuse = np.where(satany, sat.argmax(axis=1), nres).astype(np.int32)
    return nuse, satany.any(axis=0)


def _rate_estimates(res, sat, nuse, cov):
    """Rate estimates ``d`` (nints, nd, P) float32 and their usable mask."""
    nd = res.shape[1] - 1
    rf = res if res.dtype in (np.float32, np.float64) else res.astype(np.float64)
    if sat is not None:
        rf = np.where(sat, rf.dtype.type(0), rf)   # saturated values may be NaN
    inv_dt = (1.0 / cov.dt)[None, :, None]
    d = (np.diff(rf, axis=1) * inv_dt).astype(_F32)
    valid = np.arange(nd)[None, :, None] < (nuse[:, None, :] - 1)
    return d, valid


class _Differences:
    """The usable rate estimates of a chunk and what every solve of them needs."""

    def __init__(self, d, valid, s2, cov):
        self.d, self.valid, self.s2, self.cov = d, valid, s2, cov
        self.nints, _, self.npix = d.shape
        self.mf = valid.astype(_F32)
        self.mc = self.mf[:, :-1] * self.mf[:, 1:]
        # Rate floor of the covariance where sigma = 0, so that W stays positive
        # definite when the rate estimate is <= 0 (no effect otherwise).
        if np.isscalar(s2):
            self.lo = _F32(RATE_FLOOR if s2 == 0 else 0)
        else:
            self.lo = np.where(s2 == 0, _F32(RATE_FLOOR), _F32(0))
        self.A_mod, self.B_mod = cov.coefficient_lists()

    def solve(self, k, fref, s2, f, A, B, *, want_x):
        """:func:`~scenesim.rampfit.solver.ldl_pass` of integration ``k``."""
        return ldl_pass(self.d[k], self.valid[k], self.mf[k], self.mc[k], fref, s2, f,
                        A, B, want_x=want_x)

    def model_solves(self, fref, f, *, want_x):
        """Solves of every integration with the model covariance ``C(f)``."""
        return [self.solve(k, fref, self.s2, f, self.A_mod, self.B_mod, want_x=want_x)
                for k in range(self.nints)]

    def zeros(self):
        return np.zeros(self.npix, _F32)


def _fit_gls(diffs, n_iter, blk, frate=None, fstart=None, fchi=None):
    """GLS with the covariance at the previous estimate (or at ``frate``, one solve
    from ``fstart``); fills ``blk``, returns raw chi2: at the weights' covariance, or
    with ``fchi`` at ``C(fchi)`` (one more solve, about the slope found)."""
    if frate is not None:
        fref, n_iter = fstart, 1
    else:
        dtw = diffs.cov.dt.astype(_F32)[None, :, None]
        den = (diffs.mf * dtw).sum(axis=(0, 1))
        num = (diffs.d * diffs.mf * dtw).sum(axis=(0, 1))
        fref = np.divide(num, den, out=diffs.zeros(), where=den > 0)    # CDS start
    for it in range(n_iter):
        last = it == n_iter - 1
        fcov = fref if frate is None else frate
        passes = diffs.model_solves(fref, np.maximum(fcov, diffs.lo), want_x=last)
        S11 = sum(p[0] for p in passes)
        S1y = sum(p[1] for p in passes)
        blk.measured = S11 > 0
        new = fref + np.divide(S1y, S11, out=diffs.zeros(), where=blk.measured)
        if not last:
            fref = new
    blk.slope = new
    _gls_variances(diffs, passes, fref, np.maximum(fcov, diffs.lo), S11, blk)
    if fchi is not None:
        passes = diffs.model_solves(new, np.maximum(fchi, diffs.lo), want_x=False)
        S11 = sum(p[0] for p in passes)
        S1y = sum(p[1] for p in passes)
    syy = sum(p[2] for p in passes)
    return syy - np.divide(S1y * S1y, S11, out=diffs.zeros(), where=S11 > 0)


def _gls_variances(diffs, passes, fref, f, S11, blk):
    """Read and Poisson variances of the GLS slopes, combined and per integration.

    The weights ``x / (1^T x)``, ``x = C(f)^-1 1``, have variance ``1 / (1^T x)`` at
    the rate ``f`` of ``C`` (``x^T C x = 1^T x``, a sum of positive terms); its
    Poisson part is ``x^T C_poisson x / (1^T x)^2`` (non-negative terms) and the read
    part the rest.  (``x^T C_read x`` itself cancels beyond float32 in long
    read-noise dominated ramps: 1000 reads at 100 e- scattered it by +-30 %.)
    """
    cov, s2 = diffs.cov, diffs.s2
    inv11 = np.divide(1, S11, out=diffs.zeros(), where=blk.measured)
    has_read = np.asarray(s2 > 0) | cov.has_q
    qp_tot = diffs.zeros()
    for k, p in enumerate(passes):
        qp = quad_form(p[3], cov.Ap, cov.Bp)
        qp_tot += qp
        ok = p[0] > 0
        ik = np.divide(1, p[0], out=diffs.zeros(), where=ok)
        blk.slope_ints[k] = np.where(ok, fref + p[1] * ik, 0)
        pk = qp * ik * ik
        vr = np.where(has_read, np.maximum(ik - f * pk, 0), 0)
        blk.var_ints[k] = np.where(ok, vr, BAD_VARIANCE)
        blk.pcoef_ints[k] = pk
    blk.pcoef = qp_tot * inv11 * inv11
    blk.var_read = np.where(has_read, np.maximum(inv11 - f * blk.pcoef, 0),
                            0).astype(_F32)


def _weighting(fitter, cov):
    """Tridiagonal weighting matrix ``W`` of OLS or CDS, as (A, B) coefficient lists."""
    if fitter == "ols":
        return (((2.0 / cov.dt ** 2).tolist(), None),
                ((-1.0 / (cov.dt[:-1] * cov.dt[1:])).tolist(), None))
    return ((1.0 / cov.dt).tolist(), None), None


def _fit_weighted(diffs, fitter, blk):
    """OLS or CDS per integration, combined with inverse model variances at the
    joint rate; fills ``blk``, returns the raw chi2 about the combined slope."""
    A_w, B_w = _weighting(fitter, diffs.cov)
    zero = diffs.zeros()
    passes = [diffs.solve(k, zero, 1.0, 0.0, A_w, B_w, want_x=True)
              for k in range(diffs.nints)]
    S11 = sum(p[0] for p in passes)
    blk.measured = S11 > 0
    f0 = np.divide(sum(p[1] for p in passes), S11, out=diffs.zeros(),
                   where=blk.measured)
    weights = _integration_weights(diffs, passes, np.maximum(f0, _F32(0)), blk)
    _combine_integrations(weights, diffs, blk)
    slope = blk.slope
    return sum(p[2] for p in diffs.model_solves(slope, np.maximum(slope, diffs.lo),
                                                want_x=False))


def _integration_weights(diffs, passes, fv, blk):
    """Per-integration slopes and variances (into ``blk``) and their inverse-variance
    weights at the rate ``fv``: a list of (w, var_read, pcoef) per integration."""
    cov, s2 = diffs.cov, diffs.s2
    weights = []
    for k, p in enumerate(passes):
        ok = p[0] > 0
        ik = np.divide(1, p[0], out=diffs.zeros(), where=ok)
        x = p[3]
        # x^T C_read x cancels in long ramps: float64 (see quad_form)
        x64 = x.astype(np.float64)
        vr64 = s2 * quad_form(x64, cov.Ar, cov.Br)
        if cov.has_q:
            vr64 = vr64 + quad_form(x64, cov.Aq, cov.Bq)
        vr = vr64.astype(_F32) * ik * ik
        qp = quad_form(x, cov.Ap, cov.Bp) * ik * ik
        vp = fv * qp
        blk.slope_ints[k] = p[1] * ik
        blk.var_ints[k] = np.where(ok, vr, BAD_VARIANCE)
        blk.pcoef_ints[k] = qp
        w = np.where(ok, 1 / np.maximum(vr + vp, _F32(TINY)), 0).astype(_F32)
        weights.append((w, vr, qp))
    return weights


def _combine_integrations(weights, diffs, blk):
    """Inverse-variance mean of the per-integration slopes, and its variances."""
    wsum = diffs.zeros()
    wslope = diffs.zeros()
    for k, (w, _, _) in enumerate(weights):
        wsum += w
        wslope += w * blk.slope_ints[k]
    iw = np.divide(1, wsum, out=diffs.zeros(), where=wsum > 0)
    blk.slope = wslope * iw
    for w, vr, qp in weights:
        blk.var_read += (w * iw) ** 2 * vr
        blk.pcoef += (w * iw) ** 2 * qp


def _single_resultant(res, nuse, unmeasured, s2, cov, zp, tshift, blk):
    """Slope ``(R_0 - zero_point) / tbar_0`` for pixels with one usable resultant.

    Updates ``blk`` in place (``var_ints`` gets the read part, ``pcoef``/
    ``pcoef_ints`` the Poisson variance per unit rate, ``measured`` the pixels).
    """
    nints, _, npix = res.shape
    tb = np.full(npix, cov.tbar[0]) if tshift is None else cov.tbar[0] + tshift
    ta = np.full(npix, cov.tau[0]) if tshift is None else cov.tau[0] + tshift
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
    vr = (s2v / cov.n[0] + cov.q[0]) / tb_safe ** 2
    qp = ta / tb_safe ** 2
    blk.slope[pick] = mean[pick]
    blk.var_read[pick] = np.broadcast_to(vr / np.maximum(n1, 1), (npix,))[pick]
    blk.pcoef[pick] = (qp / np.maximum(n1, 1))[pick]
    vr_b = np.broadcast_to(vr, (npix,))
    for k in range(nints):
        uk = use[k]
        blk.slope_ints[k][uk] = sk[k][uk]
        blk.var_ints[k][uk] = vr_b[uk]
        blk.pcoef_ints[k][uk] = qp[uk]
    blk.measured |= pick
