"""Reference-pixel correction of HxRG frames or resultants.

Reference pixels (the ``ref_border``-wide border of the full array) are not
connected to photodiodes: they see the readout electronics (bias drifts, pedestal,
alternating-column noise, 1/f banding) but no charge.  Subtracting estimates built
from them removes the common-mode part of the read noise.

Schemes
-------
``'none'``
    Return an unchanged copy.
``'median'`` (Rauscher 2015, the NG program's simple correction)
    Per output and per frame, subtract the median of that output's reference-row
    pixels (top and bottom border rows, all their columns) from every pixel of the
    output.  For white noise ``sigma`` and ``n`` reference pixels per output the
    subtracted median adds variance ``~ pi sigma^2 / (2 n)`` to every pixel.
``'jwst'`` (JWST calibration pipeline ``refpix`` step, simplified)
    1. Per output and per frame, the top and bottom reference rows give, separately
       for even and odd columns, a sigma-clipped mean (median centre, standard
       deviation, ``sigma`` clip, up to 5 iterations, as astropy's
       ``sigma_clipped_stats``); it is subtracted from the even and odd columns of
       that output.  This removes per-output offsets and the alternating-column
       (ACN) offset.  Even/odd is the column parity within the output, which is the
       parity of the fast-scan sample for both scan directions.  For white noise and
       ``n_p`` pixels per parity group the subtracted mean adds variance
       ``c sigma^2 / n_p`` with ``c = 1.030`` for a 3-sigma clip (the asymptotic
       variance of a mean with rejection at ``+-k sigma``, ``1/(1 - 2Q(k) - 2k
       phi(k))``).
    2. The side reference columns (left and right ``ref_border`` columns of the full
       array) are averaged per row, smoothed with a running mean over
       ``side_window`` rows (truncated at the image edges), and subtracted row by
       row from every pixel.  This removes the row-to-row (1/f) banding common to all
       outputs on scales longer than the window.  It adds variance
       ``sigma^2 / (n_side W)`` plus the step-1 noise carried by the side columns.

    Each step runs when the image contains its reference pixels (a subarray may
    have only some); when it has neither, the scheme cannot run.

The correction works on frames or resultants alike (any leading axes), in the
input's floating dtype (integers become float64); statistics are computed in float64
one block of frames at a time, so temporaries stay small.
"""

import numbers

import numpy as np

from noise.detector import Detector
from noise.errors import ParameterError

__all__ = ["SCHEMES", "correct_reference", "reference_layout"]

#: Reference-correction schemes accepted by :func:`correct_reference`.
SCHEMES = ("none", "median", "jwst")

_FRAMES_PER_BLOCK = 8
_MAXITERS = 5


def reference_layout(detector):
    """Where the reference pixels of a read-out image are.

    Parameters
    ----------
    detector : noise.detector.Detector

    Returns
    -------
    rows : ndarray of int
        Image rows (0-based) that are top/bottom reference rows.
    side_cols : ndarray of int
        Image columns that are left/right reference columns.
    """
    b = detector.ref_border
    ys = np.arange(detector.y0, detector.y0 + detector.ny)
    xs = np.arange(detector.x0, detector.x0 + detector.nx)
    rows = np.flatnonzero((ys < b) | (ys >= detector.naxis2 - b))
    cols = np.flatnonzero((xs < b) | (xs >= detector.naxis1 - b))
    return rows, cols


def correct_reference(cube, detector, *, scheme="jwst", side_window=11, sigma=3.0):
    """Subtract reference-pixel estimates from frames or resultants.

    Parameters
    ----------
    cube : ndarray, shape (..., ny, nx), e- (or DN; the correction is linear)
        Frames or resultants read out with ``detector``; ``(ny, nx)`` must equal
        ``detector.shape``.
    detector : noise.detector.Detector
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
    if scheme not in SCHEMES:
        raise ParameterError(f"'scheme' must be one of {list(SCHEMES)}, got {scheme!r}")
    if not isinstance(detector, Detector):
        raise ParameterError(
            f"'detector' must be a noise.detector.Detector, got {type(detector).__name__}")
    cube = np.asarray(cube)
    if cube.dtype.kind not in "iuf":
        raise ParameterError(f"'cube' must be a real numeric array, got dtype {cube.dtype}")
    if cube.ndim < 2 or cube.shape[-2:] != detector.shape:
        raise ParameterError(
            f"'cube' must have shape (..., {detector.ny}, {detector.nx}) to match the "
            f"detector readout, got {cube.shape}")
    if isinstance(side_window, bool) or not isinstance(side_window, numbers.Integral) \
            or side_window < 1 or side_window % 2 == 0:
        raise ParameterError(
            f"'side_window' must be an odd integer >= 1 (rows), got {side_window!r}")
    if isinstance(sigma, bool) or not isinstance(sigma, numbers.Real) or \
            not np.isfinite(sigma) or sigma <= 0:
        raise ParameterError(f"'sigma' must be a finite number > 0, got {sigma!r}")
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

    dtype = cube.dtype if cube.dtype in (np.float32, np.float64) else np.float64
    out = np.array(cube, dtype=dtype, copy=True)
    if scheme == "none":
        return out
    ny, nx = detector.shape
    nout, ncol = detector.n_out_active, detector.ncols_out
    flat = out.reshape(-1, ny, nx)
    for start in range(0, flat.shape[0], _FRAMES_PER_BLOCK):
        blk = flat[start:start + _FRAMES_PER_BLOCK]                 # view (F, ny, nx)
        by_out = blk.reshape(blk.shape[0], ny, nout, ncol)
        if scheme == "median":
            ref = by_out[:, rows].astype(np.float64)                # (F, nr, nout, ncol)
            ref = np.moveaxis(ref, 2, 1).reshape(blk.shape[0], nout, -1)
            med = np.median(ref, axis=-1)                           # (F, nout)
            by_out -= med[:, None, :, None].astype(dtype)
            continue
        if rows.size:
            for parity in (0, 1):
                ref = by_out[:, rows, :, parity::2].astype(np.float64)
                ref = np.moveaxis(ref, 2, 1).reshape(blk.shape[0], nout, -1)
                mean = _clipped_mean(ref, float(sigma))             # (F, nout)
                by_out[:, :, :, parity::2] -= mean[:, None, :, None].astype(dtype)
        if cols.size:
            side = blk[:, :, cols].astype(np.float64).mean(axis=-1)  # (F, ny)
            smooth = _running_mean(side, side_window)
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


def _running_mean(x, window):
    """Centred running mean over the last axis, truncated at the ends."""
    n = x.shape[-1]
    half = window // 2
    c = np.concatenate([np.zeros(x.shape[:-1] + (1,)), np.cumsum(x, axis=-1)], axis=-1)
    idx = np.arange(n)
    lo = np.maximum(idx - half, 0)
    hi = np.minimum(idx + half, n - 1) + 1
    return (c[..., hi] - c[..., lo]) / (hi - lo)
