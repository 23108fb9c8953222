"""Reference-pixel correction of HxRG frames or resultants, and its measured effect.

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

White noise added (closed forms, :func:`white_noise_added`)
-----------------------------------------------------------
A reference estimate ``e`` is built from reference pixels only, so it is independent
of a regular pixel's own white noise and adds ``Var(e)`` to every read; in a CDS
difference (or any slope) the added variance relative to the pixel's white variance
``sigma**2`` is the same fraction ``Var(e) / sigma**2``.  With reference-pixel white
noise ``sigma_r = ref_ratio * sigma``:

* median of ``n`` reference-row pixels per output (``n = 2 b ncols_out`` for a full
  frame): ``Var(e) = (pi / 2) sigma_r**2 / n`` (asymptotic; relative error O(1/n)).
  Full H2RG: ``n = 4096``, added fraction ``0.64 pi / 8192 = 2.45e-4``.
* jwst, step 1: a clipped mean of ``n_p`` pixels (``n_p = b ncols_out / 2`` per half
  and parity; top and bottom halves averaged) has ``Var = c sigma_r**2 / n_p`` per
  half, so ``Var(m) = c sigma_r**2 / (b ncols_out)`` (2048 pixels on an H2RG); ``c``
  is the asymptotic variance factor of a mean clipped at ``+-k sigma`` around the
  sample median,
  ``c = [1 - 2Q - 2k phi + 4 k phi sqrt(pi/2) (2 phi(0) - 2 phi) + (pi/2)(2 k phi)**2]
  / (1 - 2Q)**2`` (influence function of the clipped mean plus that of the median
  centre; ``Q`` and ``phi`` the normal tail and density at ``k``), evaluated at the
  fixed point ``k`` of the iterated clip (std of the kept values shrinks the
  threshold from 3 to 2.955): ``c = 1.034`` for ``sigma = 3``.
* jwst, step 2: the row average of ``n_s = 2 b`` side pixels smoothed over ``W`` rows,
  ``Var = sigma_r**2 / (n_s W)``; it carries step 1's estimates of the side pixels'
  outputs, ``M = sum_h w_h m_h`` (``w_h``: share of side pixels in output/parity group
  ``h``), so a pixel of group ``g`` receives ``sum_h (delta_gh - w_h) m_h + s_y`` with
  variance ``sum_h (delta_gh - w_h)**2 Var(m_h) + sigma_r**2 / (n_s W_eff(y))`` plus a
  small covariance from the corner pixels that belong to both (included; < 0.5 %).
  Averaged over the outputs of a 4-output array the step-1 factor is ``(2 * 5/4 + 2 *
  3/4) / 4 = 1``.  Full H2RG, ``W = 11``: ``0.64 (1.034 / 2048 + 1 / 88) = 7.6e-3``.

With kTC in the reference pixels (a spread ``tau`` that is constant over the frames of
an integration), the median picks different pixels from frame to frame and its
frame-to-frame variance grows to ``2 pi (sigma_r**2 + tau**2) [1/4 + arcsin(rho) /
(2 pi)] / n`` with ``rho = -tau**2 / (sigma_r**2 + tau**2)`` (``sqrt(2) sigma_r tau / n``
for ``tau >> sigma_r``): 6.4x the white-only value for NIRSpec (``tau = 29``), still
1.6e-3 of the white variance.  The clipped mean is nearly linear and barely affected.

Measurement (:func:`measure_reference_correction`)
--------------------------------------------------
Each noise component of :mod:`noise` is generated alone (all other amplitudes zero,
the same root seed, so the ``'all'`` ramp is the sum of the single-component ramps),
every frame is corrected, and the statistics are taken on the regular pixels of the
``nframes - 1`` consecutive frame differences ``D`` (CDS pairs), before and after
correction: ``var = <D**2>`` (mean over pixels and pairs, e-**2).  kTC and the bias
are constant over an integration and cancel exactly in ``D``; for ``'all'`` the known
bias (offset + pattern) is subtracted before correcting, as the pipeline's superbias
step does, and the kTC of the integration stays in the frames.

The *targeted* part of ``D`` is what an ideal correction of the same form would remove
if it could read the regular pixels themselves: for ``'median'`` the mean of ``D``
over each output's regular pixels; for ``'jwst'`` the mean over each output's regular
even and odd columns, plus the running mean over the same ``W`` rows of the row means
of the remainder.  ``var_targeted = <D**2> - <(D - T)**2>``.

Measured (docs/REFPIX.md; full H2RG, NIRSpec defaults, W = 11): both schemes remove the
pedestal exactly.  jwst removes 94 % of the correlated-1/f variance it targets; that
target is 45 % of the component's CDS variance, and the rest varies faster than the
window.  Neither scheme removes uncorrelated 1/f or ACN; both add 4-10 % to them,
because reference rows read at the start and end of a frame do not see the drift in
its middle.  Both spread picture-frame noise, which the synthetic template makes
strongest in the border, over the whole array (x5 to x8 its CDS variance).  The white
noise added agrees with the closed forms above.
"""

import math
import numbers

import numpy as np

from noise.clock import Detector
from noise.errors import ParameterError
from noise.generator import NoiseGenerator
from noise.streams import root_seed
from noise.params import NIRSPEC_DEFAULTS, NoiseParams

__all__ = ["SCHEMES", "MEASURED_COMPONENTS", "correct_reference", "reference_layout",
           "white_noise_added", "measure_reference_correction", "pool_measurements",
           "format_measurement"]

#: Reference-correction schemes accepted by :func:`correct_reference`.
SCHEMES = ("none", "median", "jwst")

#: Components :func:`measure_reference_correction` can isolate, plus ``'all'``.
MEASURED_COMPONENTS = ("pedestal", "c_pink", "u_pink", "acn", "pca0", "white", "all")

_FRAMES_PER_BLOCK = 8
_MAXITERS = 5
# Amplitudes switched off to isolate one component.
_OFF = dict(rd_noise=0.0, c_pink=0.0, u_pink=0.0, acn=0.0, pca0=0.0, pedestal=0.0,
            ktc=0.0, bias_offset=0.0, bias_amp=0.0, rtn_fraction=0.0)


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
    bottom, top, cols = _layout(detector)
    return np.concatenate([bottom, top]), cols


def _layout(detector):
    """Bottom reference rows, top reference rows and side columns of the image."""
    b = detector.ref_border
    ys = np.arange(detector.y0, detector.y0 + detector.ny)
    xs = np.arange(detector.x0, detector.x0 + detector.nx)
    bottom = np.flatnonzero(ys < b)
    top = np.flatnonzero(ys >= detector.naxis2 - b)
    cols = np.flatnonzero((xs < b) | (xs >= detector.naxis1 - b))
    return bottom, top, cols


def _check_options(detector, scheme, side_window, sigma):
    """Validate the correction options against ``detector``; raise before any work."""
    if scheme not in SCHEMES:
        raise ParameterError(f"'scheme' must be one of {list(SCHEMES)}, got {scheme!r}")
    if not isinstance(detector, Detector):
        raise ParameterError(
            f"'detector' must be a noise.clock.Detector, got {type(detector).__name__}")
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
    if scheme not in SCHEMES:
        raise ParameterError(f"'scheme' must be one of {list(SCHEMES)}, got {scheme!r}")
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
    _check_options(detector, scheme, side_window, sigma)

    dtype = cube.dtype if cube.dtype in (np.float32, np.float64) else np.float64
    out = np.array(cube, dtype=dtype, copy=True)
    if scheme == "none":
        return out
    bottom, top, cols = _layout(detector)
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


def _window_bounds(n, window):
    """First and one-past-last index of the centred, truncated window of each index."""
    idx = np.arange(n)
    half = window // 2
    return np.maximum(idx - half, 0), np.minimum(idx + half, n - 1) + 1


def _running_mean(x, window):
    """Centred running mean over the last axis, truncated at the ends."""
    lo, hi = _window_bounds(x.shape[-1], window)
    c = np.concatenate([np.zeros(x.shape[:-1] + (1,)), np.cumsum(x, axis=-1)], axis=-1)
    return (c[..., hi] - c[..., lo]) / (hi - lo)


def _clip_variance_factor(sigma):
    """Variance factor ``c`` of :func:`_clipped_mean` for Gaussian data.

    ``Var = c sigma_x**2 / n`` asymptotically.  The clip threshold ``k`` (in true
    standard deviations) follows the iteration: the std of values kept within ``+-k``
    is ``sqrt(1 - 2 k phi(k) / (1 - 2 Q(k)))``, so ``k <- sigma * that``, ``_MAXITERS``
    times from ``k = sigma``.  The influence function of a mean of the values within
    ``+-k`` of the sample median is ``[x 1(|x| <= k) + 2 k phi(k) sqrt(pi/2) sign(x)] /
    (1 - 2Q(k))`` (the second term: the window follows the median, whose influence is
    ``sqrt(pi/2) sign(x)``, and moving it by ``d`` moves the kept mean by ``2 k phi d``);
    its second moment is ``c``.
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


def white_noise_added(detector, params=NIRSPEC_DEFAULTS, *, scheme="jwst", side_window=11,
                      sigma=3.0):
    """Closed-form white-noise variance a correction adds, relative to the pixels' own.

    Parameters
    ----------
    detector : noise.clock.Detector
    params : noise.params.NoiseParams
        Only ``rd_noise`` (per read, e-, scalar or per output) and ``ref_ratio`` are
        used: white noise alone, no kTC or bias in the reference pixels (see the
        module notes for the median with kTC).
    scheme, side_window, sigma
        As in :func:`correct_reference`.

    Returns
    -------
    float
        ``mean Var(e) / mean sigma**2`` over the regular pixels (dimensionless): the
        fractional increase of the white variance of every read, and so of a CDS
        difference.  Formulas in the module notes.
    """
    _check_options(detector, scheme, side_window, sigma)
    if not isinstance(params, NoiseParams):
        raise ParameterError(
            f"'params' must be a noise.params.NoiseParams, got {type(params).__name__}")
    ny, nx = detector.shape
    nout, ncol = detector.n_out_active, detector.ncols_out
    reg = _regular(detector)
    col_out = detector.output_of_column()
    rd2 = params.per_output("rd_noise", nout) ** 2               # (nout,) e-^2
    sr2 = params.ref_ratio ** 2 * rd2
    nreg_col = reg.sum(axis=0)                                   # regular pixels per column
    sig2 = np.sum(nreg_col * rd2[col_out]) / nreg_col.sum()
    if scheme == "none" or sig2 == 0:
        return 0.0
    bottom, top, side = _layout(detector)
    if scheme == "median":
        n_out = (bottom.size + top.size) * ncol
        var_col = (math.pi / 2) * sr2[col_out] / n_out
        return float(np.sum(nreg_col * var_col) / nreg_col.sum() / sig2)

    ngrp = 2 * nout
    group = 2 * col_out + (np.arange(nx) % ncol) % 2             # output/parity of a column
    grp_out = np.arange(ngrp) // 2
    ncols_g = np.bincount(group, minlength=ngrp)                 # columns per group
    halves = [h for h in (bottom, top) if h.size]
    var = np.zeros((ny, ngrp))                                   # Var(e) per row and group
    alpha = np.zeros((ngrp, ngrp))
    if halves:
        c = _clip_variance_factor(sigma)
        inv = np.divide(1.0, ncols_g, out=np.zeros(ngrp), where=ncols_g > 0)
        v_m = c * sr2[grp_out] * inv * sum(1.0 / h.size for h in halves) \
            / len(halves) ** 2                                   # (G,) Var(m_h)
        w = np.zeros(ngrp)
        if side.size:
            w = np.bincount(group[side], minlength=ngrp) / side.size
        alpha = np.eye(ngrp) - w[None, :]
        var += ((alpha ** 2) * v_m[None, :]).sum(axis=1)[None, :]
    if side.size:
        lo, hi = _window_bounds(ny, side_window)
        weff = (hi - lo).astype(float)
        s2 = np.sum(sr2[col_out[side]]) / side.size ** 2         # one row's side mean
        var += (s2 / weff)[:, None]
        if halves:
            # Corner pixels are in both m_h and the side rows of the window.
            k_h = np.bincount(group[side], minlength=ngrp)       # side columns per group
            cov = np.zeros((ny, ngrp))                           # Cov(m_h, s_y)
            for h in halves:
                inside = (h[None, :] >= lo[:, None]) & (h[None, :] < hi[:, None])
                n_in = inside.sum(axis=1)                        # rows of h in window(y)
                cov += n_in[:, None] * (sr2[grp_out] * k_h * inv
                                        / (len(halves) * h.size))[None, :]
            cov /= (side.size * weff)[:, None]
            var += 2 * cov @ alpha.T
    onehot = (group[:, None] == np.arange(ngrp)[None, :]).astype(float)
    counts = reg.astype(float) @ onehot                          # (ny, G) regular pixels
    return float(np.sum(counts * var) / counts.sum() / sig2)


def _regular(detector):
    """Regular-pixel mask of the readout; raise if it has none."""
    reg = ~detector.reference_mask()
    if not reg.any():
        raise ParameterError(
            f"readout {detector.subarray_name!r} of detector {detector.name!r} has only "
            f"reference pixels; the measurement needs regular pixels")
    return reg


def _isolate(params, name):
    """``params`` with only component ``name`` on, or None if it is off in ``params``."""
    if name == "all":
        return params
    keep = "rd_noise" if name == "white" else name
    p = params.replace(**{k: v for k, v in _OFF.items() if k != keep})
    return p if p.enabled(keep) else None


class _Oracle:
    """The part of a difference image an ideal correction of the scheme's form removes."""

    def __init__(self, detector, scheme, side_window):
        bottom, top, side = _layout(detector)
        ncol = detector.ncols_out
        col_out = detector.output_of_column()
        self.reg = ~detector.reference_mask()
        self.scheme = scheme
        self.window = side_window
        self.group = None
        if scheme == "median":
            self.group = col_out
        elif scheme == "jwst" and (bottom.size or top.size):
            self.group = 2 * col_out + (np.arange(detector.nx) % ncol) % 2
        self.rows = scheme == "jwst" and side.size > 0
        if self.group is not None:
            self.cnt = np.bincount(self.group, weights=self.reg.sum(axis=0))
        self.nrow = self.reg.sum(axis=1)

    def __call__(self, d):
        t = np.zeros_like(d)
        if self.scheme == "none":
            return t
        if self.group is not None:
            s = np.bincount(self.group, weights=np.where(self.reg, d, 0.0).sum(axis=0),
                            minlength=self.cnt.size)
            o = np.divide(s, self.cnt, out=np.zeros_like(s), where=self.cnt > 0)
            t += o[self.group][None, :]
        if self.rows:
            ok = self.nrow > 0
            r = np.where(self.reg, d - t, 0.0).sum(axis=1) / np.maximum(self.nrow, 1)
            num = _running_mean(r * ok, self.window)
            den = _running_mean(ok.astype(float), self.window)
            t += np.divide(num, den, out=np.zeros_like(num), where=den > 0)[:, None]
        return t


def measure_reference_correction(detector, params=NIRSPEC_DEFAULTS, *, scheme="jwst",
                                 nframes=5, rng=None, side_window=11, sigma=3.0,
                                 components=MEASURED_COMPONENTS, threads=None):
    """Measure what a reference correction removes from, and adds to, noise-only ramps.

    Each component is generated alone with its amplitude from ``params`` (others
    zero), ``nframes`` reads of one integration, every frame corrected with
    :func:`correct_reference`; statistics are over the regular pixels of the
    ``nframes - 1`` consecutive frame differences (CDS pairs).  See the module notes.

    Parameters
    ----------
    detector : noise.clock.Detector
    params : noise.params.NoiseParams
        Amplitudes (e-); default the paper's NIRSpec values.
    scheme : {'jwst', 'median', 'none'}
    nframes : int
        Reads per component (>= 2).
    rng : int, SeedSequence, Generator or None
        Root seed, the same for every component (the streams of :mod:`noise` are
        per component, so ``'all'`` is the sum of the single components).
    side_window, sigma
        As in :func:`correct_reference`.
    components : sequence of str
        Subset of :data:`MEASURED_COMPONENTS`.  ``'white'`` is the white read noise,
        ``'all'`` every component of ``params`` together (kTC, bias and RTN included).
        Components whose amplitude is zero in ``params`` are skipped.
    threads : int, optional
        Threads of the noise generator (results do not depend on it).

    Returns
    -------
    dict
        ``scheme``, ``side_window``, ``sigma``, ``nframes``, ``shape``, ``entropy``
        (root seed entropy, to repeat the run) and ``components``: per component a
        dict with

        ``var_before``, ``var_after``
            ``<D**2>`` over regular pixels and pairs, before and after, e-**2.
        ``removed``
            ``1 - var_after / var_before``.
        ``var_targeted``, ``removed_of_targeted``
            Variance of the part an ideal correction of the same form removes (module
            notes) and ``(var_before - var_after) / var_targeted`` (not for
            ``'white'``).
        ``added``, ``added_theory`` (``'white'`` only)
            ``var_after / var_before - 1`` and :func:`white_noise_added`.
        ``removed_of_correlated`` (``'all'`` with ``'white'`` measured)
            ``(var_before - var_after) / (var_before - var_before['white'])``: the
            net reduction as a share of the correlated (non-white) variance.

    Raises
    ------
    noise.errors.ParameterError
        For bad options, before any frame is generated.
    """
    _check_options(detector, scheme, side_window, sigma)
    if not isinstance(params, NoiseParams):
        raise ParameterError(
            f"'params' must be a noise.params.NoiseParams, got {type(params).__name__}")
    if isinstance(nframes, bool) or not isinstance(nframes, numbers.Integral) \
            or nframes < 2:
        raise ParameterError(f"'nframes' must be an integer >= 2, got {nframes!r}")
    if isinstance(components, str):
        components = (components,)
    components = tuple(components)
    bad = [c for c in components if c not in MEASURED_COMPONENTS]
    if bad or not components:
        raise ParameterError(
            f"'components' must be a non-empty subset of {list(MEASURED_COMPONENTS)}, "
            f"got {list(components)!r}")
    if threads is not None and (isinstance(threads, bool) or not isinstance(
            threads, numbers.Integral) or threads < 1):
        raise ParameterError(f"'threads' must be an integer >= 1 or None, got {threads!r}")
    _regular(detector)
    entropy, key = root_seed(rng)
    seed = np.random.SeedSequence(entropy, spawn_key=key)
    for name in components:                      # validates per-output amplitudes
        p = _isolate(params, name)
        if p is not None:
            for amp in ("rd_noise", "u_pink", "acn"):
                p.per_output(amp, detector.n_out_active)

    oracle = _Oracle(detector, scheme, side_window)
    reg = oracle.reg
    npix = int(reg.sum())
    results = {}
    for name in components:
        p = _isolate(params, name)
        if p is None:
            continue
        bias = 0.0
        if name == "all" and (p.bias_offset != 0 or p.bias_amp > 0):
            # the known bias (superbias); kTC of the integration stays in the frames
            bias = NoiseGenerator(detector, p.replace(**{k: v for k, v in _OFF.items()
                                                         if k not in ("bias_offset",
                                                                      "bias_amp")}),
                                  rng=0, threads=1).reset_level(0).astype(np.float64)
        gen = NoiseGenerator(detector, p, rng=seed, threads=threads)
        before = after = resid = 0.0
        prev = prev_c = None
        for _, _, frame in gen.frames(nframes):
            f = frame.astype(np.float64) - bias
            c = correct_reference(f, detector, scheme=scheme, side_window=side_window,
                                  sigma=sigma)
            if prev is not None:
                d = f - prev
                before += np.sum(d[reg] ** 2)
                after += np.sum((c - prev_c)[reg] ** 2)
                if name != "white":
                    resid += np.sum((d - oracle(d))[reg] ** 2)
            prev, prev_c = f, c
        n = npix * (nframes - 1)
        vb, va = before / n, after / n
        res = dict(var_before=vb, var_after=va, removed=1 - va / vb if vb > 0 else 0.0)
        if name == "white":
            res["added"] = va / vb - 1
            res["added_theory"] = white_noise_added(detector, p, scheme=scheme,
                                                    side_window=side_window, sigma=sigma)
        else:
            vt = vb - resid / n
            res["var_targeted"] = vt
            res["removed_of_targeted"] = (vb - va) / vt if vt > 0 else float("nan")
        results[name] = res
    if "all" in results and "white" in results:
        a, w = results["all"], results["white"]
        corr = a["var_before"] - w["var_before"]
        a["removed_of_correlated"] = (a["var_before"] - a["var_after"]) / corr \
            if corr > 0 else float("nan")
    return dict(scheme=scheme, side_window=int(side_window), sigma=float(sigma),
                nframes=int(nframes), shape=detector.shape, entropy=entropy,
                components=results)


def _ratio(a, b):
    """Ratio estimator ``sum a / sum b`` and its delta-method standard error."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    k = a.size
    if b.sum() == 0:
        return float("nan"), float("nan")
    r = a.sum() / b.sum()
    se = np.sqrt(np.sum((a - r * b) ** 2) / (k * (k - 1))) / b.mean() if k > 1 else \
        float("nan")
    return float(r), float(se)


def pool_measurements(results):
    """Pool independent :func:`measure_reference_correction` runs (e.g. several seeds).

    Parameters
    ----------
    results : sequence of dict
        Runs with the same scheme, window, detector and number of frames.

    Returns
    -------
    dict
        Same layout, variances averaged over the runs and ratios recomputed from
        them (ratio estimators); each ratio ``x`` gets ``x_se``, its standard error
        from the run-to-run scatter (delta method; needs two runs or more).
    """
    results = list(results)
    if not results:
        raise ParameterError("'results' must hold at least one measurement, got none")
    keys = ("scheme", "side_window", "sigma", "nframes", "shape")
    for r in results[1:]:
        if any(r[k] != results[0][k] for k in keys):
            raise ParameterError(
                f"'results' must share {list(keys)}; got "
                f"{[tuple(x[k] for k in keys) for x in results]}")
    names = [n for n in results[0]["components"]
             if all(n in r["components"] for r in results)]
    pooled = {}
    for name in names:
        runs = [r["components"][name] for r in results]

        def col(key):
            return np.array([x[key] for x in runs])

        vb, va = col("var_before"), col("var_after")
        res = dict(var_before=float(vb.mean()), var_after=float(va.mean()))
        kept, se = _ratio(va, vb)
        res["removed"], res["removed_se"] = 1 - kept, se
        if "var_targeted" in runs[0]:
            vt = col("var_targeted")
            res["var_targeted"] = float(vt.mean())
            res["removed_of_targeted"], res["removed_of_targeted_se"] = _ratio(vb - va, vt)
        if "added" in runs[0]:
            res["added"], res["added_se"] = kept - 1, se
            res["added_theory"] = runs[0]["added_theory"]
        pooled[name] = res
    if "all" in pooled and "white" in pooled:
        a = [r["components"]["all"] for r in results]
        w = [r["components"]["white"] for r in results]
        num = [x["var_before"] - x["var_after"] for x in a]
        den = [x["var_before"] - y["var_before"] for x, y in zip(a, w)]
        (pooled["all"]["removed_of_correlated"],
         pooled["all"]["removed_of_correlated_se"]) = _ratio(num, den)
    out = {k: results[0][k] for k in keys}
    out.update(entropy=[r["entropy"] for r in results], runs=len(results),
               components=pooled)
    return out


def format_measurement(result):
    """Markdown table of a :func:`measure_reference_correction` result.

    Parameters
    ----------
    result : dict
        As returned by :func:`measure_reference_correction` or
        :func:`pool_measurements` (then ratios show ``+- standard error``).

    Returns
    -------
    str
        One row per component: CDS variance before and after (e-**2), fraction
        removed, targeted share of the variance, fraction of the targeted part
        removed, and for white noise the variance added (measured / closed form).
    """
    def fmt(r, key, spec):
        if key not in r:
            return ""
        s = format(r[key], spec)
        se = r.get(key + "_se")
        return s + (f" ± {se:.{spec[-2]}f}" if se is not None and np.isfinite(se) else "")

    lines = ["| component | var before (e-²) | var after (e-²) | removed | "
             "targeted share | removed of targeted | white added (meas. / theory) |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for name, r in result["components"].items():
        vb = r["var_before"]
        share = f"{r['var_targeted'] / vb:.3f}" if "var_targeted" in r and vb > 0 else ""
        add = ""
        if "added" in r:
            se = r.get("added_se")
            add = f"{r['added']:.2e}" + (f" ± {se:.1e}" if se is not None else "") + \
                f" / {r['added_theory']:.2e}"
        label = name
        if "removed_of_correlated" in r:
            corr = fmt(r, "removed_of_correlated", "+.3f")
            label += f" (correlated part removed: {corr})"
        lines.append(f"| {label} | {vb:.4g} | {r['var_after']:.4g} | "
                     f"{fmt(r, 'removed', '+.3f')} | {share} | "
                     f"{fmt(r, 'removed_of_targeted', '+.3f')} | {add} |")
    return "\n".join(lines)
