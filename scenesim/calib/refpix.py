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
``'irs2'`` (interleaved reference samples, NIRSpec's IRS2; :func:`correct_irs2`)
    Needs the *raw* frames of a detector with :class:`noise.clock.Interleave` (every
    written sample, :meth:`noise.clock.Detector.raw_columns`), and returns the image
    pixels.  Per output and frame, the interleaved reference samples are put on the
    output's time line at their slots; each excursion gives two values, the mean of
    its samples at even slots and the mean of those at odd slots (the two ACN
    phases); each of the two series is smoothed by a running mean over ``window``
    excursions (truncated at the frame's ends) and interpolated linearly in time to
    every normal pixel of the same slot parity, which is subtracted.  So pedestal,
    correlated and uncorrelated 1/f and ACN are removed up to about ``1 / (2 window
    period dt)`` (150 Hz for NIRSpec with the default ``window = 15``, the best of 1,
    3, 5, 9, 15, 25 and 41 on NIRSpec's default noise: ``docs/REFPIX.md``), per
    output, at the price of the white noise of the estimate, about ``(ref_ratio
    rd)^2 / (reference / 2) / window``.  Each reference sample's mean over the
    groups of its integration, less the mean of those means over the output's samples
    of the same slot parity, is subtracted first (its reset level; a constant per
    pixel, which cancels in every difference of reads).  The reference output is not
    used: it sees the correlated 1/f only, which the interleaved samples of each
    output already carry.
    Unlike the jwst pipeline's IRS2 step (Rauscher et al. 2017), which weighs the
    reference samples with frequency-domain coefficients fitted to darks (its
    ``refpix`` reference file), this is the time-domain interpolation only: no
    calibration file, nothing fitted.

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

__all__ = ["SCHEMES", "correct_reference", "correct_irs2", "irs2_noise_study",
           "reference_layout", "reference_edges", "check_correction_options",
           "applied_scheme",
           "running_mean", "window_bounds", "clipped_mean_variance_factor"]

#: Reference-correction schemes accepted by :func:`correct_reference`.
SCHEMES = ("none", "median", "jwst", "irs2")

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
    if scheme == "irs2" and detector.interleave is None:
        raise ParameterError(
            f"refpix 'irs2' needs interleaved reference samples, but detector "
            f"{detector.name!r} has no 'interleave' (use a detector such as preset "
            f"'NIRSPEC-IRS2', or refpix 'jwst'/'median'/'none')")
    rows, cols = reference_layout(detector)
    if scheme == "median" and rows.size == 0:
        raise ParameterError(
            f"refpix 'median' needs top/bottom reference rows, but readout "
            f"{detector.subarray_name!r} (rows {detector.y0}..{detector.y0 + detector.ny - 1}"
            f" of {detector.naxis2}, border {detector.ref_border}) has none; use "
            f"refpix 'none'")
    if scheme == "jwst" and rows.size == 0 and cols.size == 0:
        raise ParameterError(
            f"refpix 'jwst' needs reference rows or side reference columns, but "
            f"readout {detector.subarray_name!r} has none (border "
            f"{detector.ref_border}); use refpix 'none'")


def applied_scheme(detector, scheme):
    """The correction a fit applies for the requested ``scheme`` on ``detector``.

    ``'jwst'`` (the default everywhere) on a readout with no reference pixel at all
    (a window inside the array) has nothing to subtract: it is ``'none'``, and the
    fit records ``REFPIX = 'none'``.  A scheme asked for by name that the readout
    cannot support (``'median'`` without top/bottom reference rows, ``'irs2'``
    without interleaved reference samples) is refused, never skipped.

    Parameters
    ----------
    detector : noise.clock.Detector
    scheme : str
        One of :data:`SCHEMES`.

    Returns
    -------
    str
        The scheme applied.

    Raises
    ------
    noise.errors.ParameterError
        ``scheme`` unknown, or not supported by the readout
        (:func:`check_correction_options`).
    """
    check_choice("refpix", scheme, SCHEMES)
    check_instance("detector", detector, Detector, "a noise.clock.Detector")
    if scheme == "jwst":
        rows, cols = reference_layout(detector)
        if rows.size == 0 and cols.size == 0:
            return "none"
    check_correction_options(detector, scheme, 11, 3.0)
    return scheme


def correct_reference(cube, detector, *, scheme="jwst", side_window=11, sigma=3.0):
    """Subtract reference-pixel estimates from frames or resultants.

    Parameters
    ----------
    cube : ndarray, shape (..., ny, nx), e- (or DN; the correction is linear)
        Frames or resultants read out with ``detector``; ``(ny, nx)`` must equal
        ``detector.shape``.  A reference pixel that is NaN is left out of the
        statistics (the side means count the others; :mod:`scenesim.calib.prepare`
        leaves out those beside a saturated pixel once IPC is undone); it stays NaN
        in the output.
    detector : noise.clock.Detector
        Geometry: outputs, reference border, subarray position.
    scheme : {'jwst', 'median', 'none', 'irs2'}
        See the module notes; ``'irs2'`` takes the raw frames (:func:`correct_irs2`)
        and returns the image pixels.
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
    if scheme == "irs2":
        check_correction_options(detector, scheme, side_window, sigma)
        return correct_irs2(cube, detector)
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
            med = (np.nanmedian(ref, axis=-1) if np.isnan(ref).any()  # (F, nout)
                   else np.median(ref, axis=-1))                   # (NaN: left out)
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
            values = blk[:, :, cols].astype(np.float64)
            if np.isnan(values).any():    # reference pixels left out (NaN): the mean
                smooth = _running_nanmean(values, side_window)   # of the rest
            else:
                smooth = running_mean(values.mean(axis=-1), side_window)  # (F, ny)
            blk -= smooth[:, :, None].astype(dtype)
    return out


def _running_nanmean(values, window):
    """Centred running mean over rows (axis 1) of the finite side values of each row
    ``(F, ny, ncols)``: every finite value of the window weighs alike, as in the mean
    of the row means when none is missing; 0 where a whole window has none."""
    ok = np.isfinite(values)
    total = running_mean(np.where(ok, values, 0.0).sum(axis=-1), window)
    count = running_mean(ok.sum(axis=-1).astype(np.float64), window)
    return np.where(count > 0, total / np.where(count > 0, count, 1.0), 0.0)


def _irs2_plan(detector):
    """Per science output: columns of its interleaved samples and their slots, and of
    its normal samples with their slots and image columns (all in time order)."""
    output, slot, image_x = detector.raw_columns()
    plan = []
    for o in range(detector.n_out_active):
        ref = np.flatnonzero((output == o) & (image_x < 0))
        ref = ref[np.argsort(slot[ref])]
        nor = np.flatnonzero((output == o) & (image_x >= 0))
        nor = nor[np.argsort(slot[nor])]
        plan.append((ref, slot[ref], nor, slot[nor], image_x[nor]))
    return plan


def correct_irs2(raw, detector, *, window=15):
    """The ``'irs2'`` scheme (module notes): raw frames in, corrected image out.

    Parameters
    ----------
    raw : ndarray, shape (..., ny, raw_nx)
        Raw frames or resultants of ``detector`` (:meth:`noise.clock.Detector.raw_columns`
        layout), e- or DN.  With three or more axes, axis -3 is the groups of one
        integration (each reference sample's mean over it is removed first).
    detector : noise.clock.Detector
        With ``interleave``.
    window : int
        Excursions in the running mean of each parity's reference series (odd, >= 1;
        default 15, the measured optimum for NIRSpec's default noise).

    Returns
    -------
    ndarray, shape (..., ny, nx), float64
        The corrected image pixels (the detector's image layout).
    """
    if not isinstance(detector, Detector):
        raise ParameterError(
            f"'detector' must be a noise.clock.Detector, got {type(detector).__name__}")
    if detector.interleave is None:
        raise ParameterError(
            f"'irs2' correction needs interleaved reference samples, but detector "
            f"{detector.name!r} has no 'interleave'")
    check_int("window", window, minimum=1)
    if window % 2 == 0:
        raise ParameterError(f"'window' must be an odd integer >= 1 (excursions), got "
                             f"{window!r}")
    raw = np.asarray(raw)
    if raw.dtype.kind not in "iuf" or raw.ndim < 2 or raw.shape[-2:] != detector.raw_shape:
        raise ParameterError(
            f"'raw' must be a real array of shape (..., {detector.ny}, {detector.raw_nx}) "
            f"(the raw frames of {detector.name!r}, interleaved samples included), got "
            f"{raw.dtype} {raw.shape}")
    ny, rs = detector.ny, detector.row_samples
    lead = raw.shape[:-2]
    out = np.empty(lead + detector.shape, dtype=np.float64)
    rows = np.arange(ny)[:, None] * rs
    for ref, rslot, nor, nslot, image_x in _irs2_plan(detector):
        r = raw[..., ref].astype(np.float64)
        if r.ndim >= 3:
            # each reference pixel's reset level: its mean over the groups, less the
            # mean of those over the output's samples of one slot parity (so the
            # groups' common mean, e.g. a pedestal, stays in and is removed with it)
            off = r.mean(axis=-3, keepdims=True)
            for parity in (0, 1):
                same = (rslot % 2) == parity
                off[..., same] -= off[..., same].mean(axis=(-2, -1), keepdims=True)
            r -= off
        r = r.reshape((-1, ny, ref.size))
        n = raw[..., nor].astype(np.float64).reshape((-1, ny, nor.size))
        n_exc = detector.n_excursions
        per = ref.size // n_exc
        for parity in (0, 1):
            pick = (rslot[:per] % 2) == parity          # the same in every excursion
            vals = r.reshape(r.shape[0], ny, n_exc, per)[..., pick].mean(axis=-1)
            t_ref = (rows + rslot.reshape(n_exc, per)[:, pick].mean(axis=-1)).ravel()
            vals = vals.reshape(vals.shape[0], -1)
            vals = running_mean(vals, window)
            cols = (nslot % 2) == parity
            t_nor = (rows + nslot[cols]).ravel()
            for f in range(n.shape[0]):
                est = np.interp(t_nor, t_ref, vals[f]).reshape(ny, -1)
                n[f][:, cols] -= est
        out.reshape((-1,) + detector.shape)[..., image_x] = n
    return out


def irs2_noise_study(detector, params, *, nreads=10, nramps=2, seed=2017,
                     windows=(1, 3, 9), threads=None):
    """What the IRS2 correction buys: total noise per CDS and per slope in the regular
    pixels of noise-only ramps, with no correction, the border (``'jwst'``) scheme and
    ``'irs2'`` (one row per ``window``), all on the same ramps.

    Ramp ``r`` draws from ``SeedSequence(seed, spawn_key=(r,))``.  CDS: reads 1 - 0;
    slope: the equal-weight least-squares slope over the ``nreads`` reads.

    Returns
    -------
    list of dict
        ``{'scheme', 'cds', 'cds_err', 'slope', 'slope_err'}``: rms of the CDS (e-)
        and of the slope (e-/s) in regular pixels, over ``nramps`` ramps (``_err``:
        the standard error of the rms from the ramp-to-ramp scatter, 0 with one ramp).
    """
    from noise.generator import NoiseGenerator     # scenesim.calib imports no generator
    check_int("nreads", nreads, minimum=2)
    check_int("nramps", nramps, minimum=1)
    reg = ~detector.reference_mask()
    _, _, image_x = detector.raw_columns()
    normal = image_x >= 0
    k = np.arange(nreads) - (nreads - 1) / 2
    rows = {}
    for r in range(nramps):
        gen = NoiseGenerator(detector, params, threads=threads,
                             rng=np.random.SeedSequence(seed, spawn_key=(r,)))
        raw = np.stack([f for *_, f in gen.frames(nreads, raw=True)]).astype(np.float64)
        img = np.empty((nreads,) + detector.shape)
        img[..., image_x[normal]] = raw[..., normal]
        runs = [("none", img), ("border (jwst)", correct_reference(img, detector))]
        runs += [(f"irs2, window {w}", correct_irs2(raw, detector, window=w))
                 for w in windows]
        for name, c in runs:
            cds = (c[1] - c[0])[reg]
            kc = (k.reshape((-1,) + (1,) * (c.ndim - 1)) * c).sum(axis=0)
            slope = kc[reg] / (k ** 2).sum() \
                / detector.frame_time
            rows.setdefault(name, []).append((np.mean(cds ** 2), np.mean(slope ** 2)))
    out = []
    for name, v in rows.items():
        v = np.array(v)
        rms = np.sqrt(v.mean(axis=0))
        # rms = sqrt(mean var): error of the mean of the ramps' variances, propagated
        err = (v.std(axis=0, ddof=1) / np.sqrt(len(v)) / (2 * rms)) if len(v) > 1 \
            else np.zeros(2)
        out.append(dict(scheme=name, cds=float(rms[0]), cds_err=float(err[0]),
                        slope=float(rms[1]), slope_err=float(err[1])))
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
