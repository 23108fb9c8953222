"""Reference-pixel correction of HxRG frames or resultants.

Reference pixels (the ``ref_border``-wide border of the full array) are not
connected to photodiodes: they see the readout electronics (bias drifts, pedestal,
alternating-column noise, 1/f banding) but no charge.  Subtracting estimates built
from them removes the common-mode part of the read noise, at the price of the white
noise of the estimates.

Schemes
-------
``'none'``
    Return an unchanged copy.
``'median'`` (Rauscher 2015, the NG program's simple correction)
    Per output and per frame, subtract the median of that output's reference-row
    pixels (top and bottom border rows, all their columns) from every pixel of the
    output.
``'jwst'`` (the JWST calibration pipeline's ``refpix`` step for NIR full frames)
    1. Per output and per frame, the bottom and the top reference rows each give,
       separately for even and odd columns, a sigma-clipped mean (median centre,
       standard deviation of the kept values, ``sigma`` clip, up to 5 iterations, as
       astropy's ``sigma_clipped_stats``); the bottom and top means are averaged and
       subtracted from the even and odd columns of that output.  Even/odd is the
       column parity within the output; the fast-scan sample parity is the same
       partition for both scan directions (it swaps the labels only), so ACN-like
       even/odd offsets are caught whichever way an output scans.
    2. The side reference columns (left and right ``ref_border`` columns of the full
       array, already corrected by step 1) are averaged per row, smoothed with a
       running mean over ``side_window`` rows (truncated at the image edges) and
       subtracted row by row from every pixel.  This removes the row-to-row (1/f)
       banding common to all outputs on time scales longer than the window,
       ``side_window`` row times.

    Differences from the pipeline, on purpose: the pipeline smooths the side signal
    with a running *median* of the ``side_window x 4`` box on each side (reflected at
    the ends) and averages left and right; a running mean is used here because the
    simulated reference pixels have no outliers, and a mean adds ``2/pi`` as much white
    noise as a median of the same pixels.  Its clipped mean uses ``scipy`` sigmaclip
    (mean centre); the median centre used here differs only at the 1e-3 level of the
    estimator's variance for Gaussian data.

    Each step runs when the image contains its reference pixels (a subarray may have
    only some); when it has neither, the scheme cannot run.

The correction works on frames or resultants alike (any leading axes), in the input's
floating dtype (integers become float64); statistics are computed in float64 one block
of frames at a time, so temporaries stay small.  It is not linear (median, clipping),
so it is applied to each frame as a pipeline does, before differences or fits.

The white noise each scheme adds (closed forms) and the measured effect on every
noise component are in :mod:`scenesim.validate.refpix_study` and ``docs/REFPIX.md``.
:func:`clipped_mean_variance_factor` gives the variance of the ``'jwst'`` clipped
mean for Gaussian data.
"""

import math

import numpy as np

from noise.clock import Detector
from noise.errors import ParameterError
from noise.validate import check_choice, check_float, check_instance, check_int

__all__ = ["SCHEMES", "correct_reference", "reference_layout", "reference_edges",
           "check_correction_options", "running_mean", "window_bounds",
           "clipped_mean_variance_factor"]

#: Reference-correction schemes accepted by :func:`correct_reference`.
SCHEMES = ("none", "median", "jwst")

_FRAMES_PER_BLOCK = 8
_MAXITERS = 5


def reference_layout(detector):
    """Where the reference pixels of a read-out image are.

    Parameters
    ----------
    detector : noise.clock.Detector

    Returns
    -------
    rows : ndarray of int
        Image rows (0-based) that are top/bottom reference rows.
    side_cols : ndarray of int
        Image columns that are left/right reference columns.
    """
    bottom, top, cols = reference_edges(detector)
    return np.concatenate([bottom, top]), cols


def reference_edges(detector):
    """Bottom reference rows, top reference rows and side columns of the image.

    Parameters
    ----------
    detector : noise.clock.Detector

    Returns
    -------
    bottom, top, side_cols : ndarray of int
        Image rows of the bottom and of the top reference rows, and image columns
        of the left/right reference columns (0-based; empty where the readout has
        none).
    """
    check_instance("detector", detector, Detector, "a noise.clock.Detector")
    b = detector.ref_border
    ys = np.arange(detector.y0, detector.y0 + detector.ny)
    xs = np.arange(detector.x0, detector.x0 + detector.nx)
    bottom = np.flatnonzero(ys < b)
    top = np.flatnonzero(ys >= detector.naxis2 - b)
    cols = np.flatnonzero((xs < b) | (xs >= detector.naxis1 - b))
    return bottom, top, cols


def check_correction_options(detector, scheme, side_window, sigma):
    """Validate the correction options against ``detector``; raise before any work.

    Parameters
    ----------
    detector : noise.clock.Detector
    scheme : str
        One of :data:`SCHEMES`.
    side_window : int
        Odd number of rows (>= 1) of the side-column running mean.
    sigma : float
        Clipping threshold (> 0) of the ``'jwst'`` means.

    Raises
    ------
    noise.errors.ParameterError
        Naming the option and the value, or the scheme that the readout's reference
        pixels cannot support.
    """
    check_choice("scheme", scheme, SCHEMES)
    if not isinstance(detector, Detector):
        raise ParameterError(
            f"'detector' must be a noise.clock.Detector, got {type(detector).__name__}")
    check_int("side_window", side_window, minimum=1)
    if side_window % 2 == 0:
        raise ParameterError(
            f"'side_window' must be an odd integer >= 1 (rows), got {side_window!r}")
    check_float("sigma", sigma, minimum=0.0, strict_min=True)
    rows, cols = reference_layout(detector)
    if scheme == "median" and rows.size == 0:
        raise ParameterError(
            f"scheme 'median' needs top/bottom reference rows, but readout "
            f"{detector.subarray_name!r} (rows {detector.y0}..{detector.y0 + detector.ny - 1}"
            f" of {detector.naxis2}, border {detector.ref_border}) has none; use "
            f"scheme 'none'")
    if scheme == "jwst" and rows.size == 0 and cols.size == 0:
        raise ParameterError(
            f"scheme 'jwst' needs reference rows or side reference columns, but "
            f"readout {detector.subarray_name!r} has none (border "
            f"{detector.ref_border}); use scheme 'none'")


def correct_reference(cube, detector, *, scheme="jwst", side_window=11, sigma=3.0):
    """Subtract reference-pixel estimates from frames or resultants.

    Parameters
    ----------
    cube : ndarray, shape (..., ny, nx), e- (or DN; the correction is linear)
        Frames or resultants read out with ``detector``; ``(ny, nx)`` must equal
        ``detector.shape``.
    detector : noise.clock.Detector
        Geometry: outputs, reference border, subarray position.
    scheme : {'jwst', 'median', 'none'}
        See the module notes.
    side_window : int
        Rows of the running mean of the side reference columns (odd, >= 1).
    sigma : float
        Clipping threshold (standard deviations, > 0) of the ``'jwst'`` means.

    Returns
    -------
    ndarray, shape of ``cube``
        Corrected copy, float32 for float32 input, else float64.  The input is not
        modified.

    Raises
    ------
    noise.errors.ParameterError
        For an unknown scheme, a shape that does not match the detector, a bad
        ``side_window`` or ``sigma``, or a readout with none of the reference
        pixels the scheme needs.
    """
    check_choice("scheme", scheme, SCHEMES)
    if not isinstance(detector, Detector):
        raise ParameterError(
            f"'detector' must be a noise.clock.Detector, got {type(detector).__name__}")
    cube = np.asarray(cube)
    if cube.dtype.kind not in "iuf":
        raise ParameterError(f"'cube' must be a real numeric array, got dtype {cube.dtype}")
    if cube.ndim < 2 or cube.shape[-2:] != detector.shape:
        raise ParameterError(
            f"'cube' must have shape (..., {detector.ny}, {detector.nx}) to match the "
            f"detector readout, got {cube.shape}")
    check_correction_options(detector, scheme, side_window, sigma)

    dtype = cube.dtype if cube.dtype in (np.float32, np.float64) else np.float64
    out = np.array(cube, dtype=dtype, copy=True)
    if scheme == "none":
        return out
    bottom, top, cols = reference_edges(detector)
    rows = np.concatenate([bottom, top])
    halves = [h for h in (bottom, top) if h.size]
    ny, nx = detector.shape
    nout, ncol = detector.n_out_active, detector.ncols_out
    flat = out.reshape(-1, ny, nx)
    for start in range(0, flat.shape[0], _FRAMES_PER_BLOCK):
        blk = flat[start:start + _FRAMES_PER_BLOCK]                 # view (F, ny, nx)
        nf = blk.shape[0]
        by_out = blk.reshape(nf, ny, nout, ncol)
        if scheme == "median":
            ref = by_out[:, rows].astype(np.float64)                # (F, nr, nout, ncol)
            ref = np.moveaxis(ref, 2, 1).reshape(nf, nout, -1)
            med = np.median(ref, axis=-1)                           # (F, nout)
            by_out -= med[:, None, :, None].astype(dtype)
            continue
        if halves:
            for parity in range(min(2, ncol)):                  # 1-column outputs
                mean = np.zeros((nf, nout))
                for half in halves:
                    ref = by_out[:, half, :, parity::2].astype(np.float64)
                    ref = np.moveaxis(ref, 2, 1).reshape(nf, nout, -1)
                    mean += _clipped_mean(ref, float(sigma))       # (F, nout)
                mean /= len(halves)
                by_out[:, :, :, parity::2] -= mean[:, None, :, None].astype(dtype)
        if cols.size:
            side = blk[:, :, cols].astype(np.float64).mean(axis=-1)  # (F, ny)
            smooth = running_mean(side, side_window)
            blk -= smooth[:, :, None].astype(dtype)
    return out


def _clipped_mean(x, sigma):
    """Sigma-clipped mean along the last axis (median centre, std scale), vectorised.

    Iterates at most ``_MAXITERS`` times or until no pixel changes state; a group
    whose mask would become empty keeps its previous mask.
    """
    keep = np.ones(x.shape, bool)
    for _ in range(_MAXITERS):
        xm = np.where(keep, x, np.nan)
        med = np.nanmedian(xm, axis=-1, keepdims=True)
        std = np.nanstd(xm, axis=-1, keepdims=True)
        new = np.abs(x - med) <= sigma * std
        empty = ~new.any(axis=-1)
        if empty.any():
            new[empty] = keep[empty]
        if np.array_equal(new, keep):
            break
        keep = new
    return np.where(keep, x, 0.0).sum(axis=-1) / keep.sum(axis=-1)


def window_bounds(n, window):
    """First and one-past-last index of the centred, truncated window of each index."""
    idx = np.arange(n)
    half = window // 2
    return np.maximum(idx - half, 0), np.minimum(idx + half, n - 1) + 1


def running_mean(x, window):
    """Centred running mean over the last axis, truncated at the ends."""
    lo, hi = window_bounds(x.shape[-1], window)
    c = np.concatenate([np.zeros(x.shape[:-1] + (1,)), np.cumsum(x, axis=-1)], axis=-1)
    return (c[..., hi] - c[..., lo]) / (hi - lo)


def clipped_mean_variance_factor(sigma):
    """Variance factor ``c`` of the ``'jwst'`` clipped mean for Gaussian data.

    The clipped mean of :func:`correct_reference` (median centre, standard deviation
    of the kept values, ``sigma`` clip, up to 5 iterations) of ``n`` values of
    standard deviation ``sigma_x`` has ``Var = c sigma_x**2 / n`` asymptotically.
    The clip threshold ``k`` (in true standard deviations) follows the iteration: the
    std of values kept within ``+-k`` is ``sqrt(1 - 2 k phi(k) / (1 - 2 Q(k)))``, so
    ``k <- sigma * that``, 4 times from ``k = sigma``.  The influence function of a mean of the values within
    ``+-k`` of the sample median is ``[x 1(|x| <= k) + 2 k phi(k) sqrt(pi/2) sign(x)] /
    (1 - 2Q(k))`` (the second term: the window follows the median, whose influence is
    ``sqrt(pi/2) sign(x)``, and moving it by ``d`` moves the kept mean by ``2 k phi d``);
    its second moment is ``c``.

    Parameters
    ----------
    sigma : float
        Clipping threshold, standard deviations (> 0).

    Returns
    -------
    float
        ``c`` (1.034 for ``sigma = 3``).
    """
    def phi(z):
        return math.exp(-0.5 * z * z) / math.sqrt(2 * math.pi)

    def kept(z):
        return math.erf(z / math.sqrt(2))                   # 1 - 2 Q(z)

    k = float(sigma)
    for _ in range(_MAXITERS - 1):
        k = sigma * math.sqrt(max(1 - 2 * k * phi(k) / kept(k), 0.0))
    p, a = kept(k), 2 * k * phi(k)
    second = (p - a) + 2 * a * math.sqrt(math.pi / 2) * 2 * (phi(0) - phi(k)) \
        + (math.pi / 2) * a * a
    return second / p ** 2
