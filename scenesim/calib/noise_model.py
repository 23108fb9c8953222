"""Read noise from the data: the common mode of an output and the effective white noise.

The fitter's model (:mod:`scenesim.rampfit`) is white read noise per read (e-, not
CDS).  Real data after reference correction also carry noise common to many
pixels: (i) per output and read (the 1/f noise of the output's own amplifier, which
the side reference columns of the outer outputs do not see, and low frequencies
that a stripe without reference rows cannot remove); (ii) per row and read (the part
of the 1/f banding that the row-wise reference correction misses, larger the later
the pixel is read within its row).  In one pixel's ramp (ii) looks like extra white
noise and (i) like a slow wander common to the output.  The GLS jump statistic is a
step test over the whole ramp (the score test for a jump is powerful because it
compares all reads before and after), so a slow wander of a few tenths of the read
noise reads as a step and clean pixels are flagged as jumps.

Two data-driven corrections, used by :func:`scenesim.calib.prepare.prepare_exposure`:

* :func:`common_mode` estimates (i): after a first fit of a subsample of rows, the
  median over an output's read-noise dominated pixels of ``d_i - f_hat`` (robust to
  jumps and sources), minus its GLS-weighted mean over ``i`` (a constant offset of
  the ``d_i`` is a rate, indistinguishable from a uniform background of the output,
  and is kept; the weights are those of a read-noise limited ramp, so that the
  correction leaves those pixels' GLS slopes unchanged), summed into resultant
  offsets that are subtracted.  The slopes keep the mean of the common wander; the
  jump statistic and ``chi2`` lose the rest.
* :func:`measure_read_noise` estimates the effective white noise per group of pixels
  (e.g. per column) from the ``chi2`` of read-noise dominated pixels: ``sigma_eff
  = k sigma``, ``k^2`` the mean of ``chi2`` (per degree of freedom) without the
  values beyond 1.25 times the chi-square's 99.9 % quantile at the median's scale
  (the ramps with jumps), divided by what that cut keeps of a scaled chi-square's
  mean (:func:`_trimmed_k2`), corrected to
  first order for the Poisson share and refined by a second fit at ``sigma_eff``.
  (The median of ``chi2`` over the chi-square's median, used before, fails where a
  resultant's noise is below 1 DN: the differences are whole DN, ``chi2`` takes a
  few values, 10 % of pixels exactly 0, and a probe's k^2 came out 1.146 for a mean
  of 0.985: read noise 6.72 e- for 6.17, errors 8-12 % too large.)  Near zero rate
  it reads slightly low: the fit's covariance uses the clipped fitted rate, above
  the true one half of the time, so its ``chi2`` is slightly low.

A pixel is *read-noise dominated* when the Poisson variance of every difference, at
its fitted rate, is at most half its read variance.  Both functions fit at most
``max_rows`` evenly spaced rows, with GLS and without jump detection.  Their measured
effect on the example scenes is in ``docs/VALIDATION_FIT.md``.
"""

import numpy as np
from scipy.special import gammainc, gammaincinv

from noise.errors import ParameterError
from noise.validate import check_int, check_map, check_mask, is_sequence

from scenesim.detector.dq import DO_NOT_USE
from scenesim.rampfit.covariance import RampCovariance
from scenesim.rampfit.fitter import fit_ramps
from scenesim.rampfit.times import check_read_times

__all__ = ["NOISE_MIN_PIXELS", "common_mode", "measure_read_noise"]

#: Read-noise dominated pixels a group needs for its own estimate.
NOISE_MIN_PIXELS = 32

_F32 = np.float32
_NOISE_RHO = 0.5         # read-noise dominated: Poisson / read variance of a difference
_NOISE_CONVERGED = 0.02  # a second chi2 pass unless every group's k^2 is within 2 % of 1
_CM_MAX_PIXELS = 16384   # pixels per group for the common-mode medians
_NOISE_K2_MIN = 0.01     # sigma_eff >= 0.1 sigma
_CUT_QUANTILE = 0.999    # chi2 above _CUT times this quantile (at the median's scale)
_CUT = 1.25              # is left out of the noise estimate (_trimmed_k2)


def measure_read_noise(resultants, read_times, *, read_noise, groups, saturated=None,
                       refmask=None, max_rows=256, threads=None, resultant_noise=0.0):
    """Effective white read noise per read, per group of pixels, from the data.

    A GLS fit (no jump detection) of at most ``max_rows`` evenly spaced rows gives
    each pixel's chi-square per degree of freedom.  Where the read noise dominates
    the differences, ``chi2 / dof`` estimates ``k^2 = sigma_eff^2 / sigma^2``
    (corrected to first order for the Poisson share ``rho``:
    ``k^2 = (chi2 / dof) (1 + rho) - rho``).  Their mean over a group, without the
    values far above the chi-square's tail (the ramps with jumps) and divided by
    what that cut keeps of a chi-square's mean (:func:`_trimmed_k2`), gives the
    group's ``sigma_eff = k sigma``.  Unless every ``k^2`` is
    within 2 % of 1, a second fit with ``sigma_eff`` refines it: at the right
    model ``chi2 / dof = 1`` whatever ``rho``, so the first-order correction no
    longer matters.  See the module notes.

    Parameters
    ----------
    resultants, read_times, saturated, refmask, resultant_noise :
        As in :func:`scenesim.rampfit.fit_ramps` (``resultant_noise``, the known
        white noise of each resultant, is kept as it is: only the per-read term is
        measured).
    read_noise : float or ndarray (ny, nx), e- per read (not CDS)
        Model read noise (e.g. the white noise of the header), >= 0.
    groups : ndarray of int, shape (ny, nx)
        Group label (>= 0) of every pixel; one ``sigma_eff`` per group (e.g. the
        column index: the noise that the reference correction leaves depends on
        the read time within the row).
    max_rows : int
        Rows used (>= 1): every ``ceil(ny / max_rows)``-th row.
    threads : int or None
        As in :func:`scenesim.rampfit.fit_ramps`.

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
    rn = read_noise
    k = None
    for _ in range(2):
        fp = _first_pass(resultants, read_times, rn, groups, saturated, refmask,
                         max_rows, threads, resultant_noise)
        k2 = _k2_per_group(fp)
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


def _k2_per_group(fp):
    """``k^2 = (sigma_eff / sigma)^2`` of every group from one first pass."""
    g, ok = fp["fit"], fp["quiet"]
    k2 = np.ones(fp["ngroups"])
    if ok.sum() < NOISE_MIN_PIXELS:
        return k2
    rho = fp["rho"][ok]
    u = g.chi2[ok].astype(np.float64) * (1 + rho) - rho
    nu = g.dof[ok].astype(np.float64)
    k2[:] = _trimmed_k2(u, nu, np.zeros(u.size, np.intp), 1)[0]
    lab = fp["groups"][ok].astype(np.intp)
    count = np.bincount(lab, minlength=k2.size)
    est = _trimmed_k2(u, nu, lab, k2.size)          # one estimate per group
    big = count >= NOISE_MIN_PIXELS
    k2[big] = est[big]
    return k2


def _trimmed_k2(u, nu, lab, ngr):
    """``k^2`` of each group ``lab`` (ints in ``[0, ngr)``) of values ``u = k^2 X /
    nu``, ``X ~ chi^2_nu`` (``nu`` per value), robust to a few large ones (ramps with
    jumps); an array of ``ngr`` (groups without values: nan).

    A first, robust scale ``k0^2`` per group: the median of ``u`` over the
    chi-square's median (biased where ``u`` takes few values, module notes, but only
    used for the cut).  Values above ``t = k0^2`` times :data:`_CUT` times the
    chi-square's :data:`_CUT_QUANTILE` quantile (per degree of freedom) are left out,
    and the mean of the rest is divided by what that cut keeps of a scaled
    chi-square's mean, ``E[u 1(u <= t)] = k^2 F_{nu+2}(t nu / k^2)`` (``F`` the
    chi-square distribution function), solved for ``k^2`` by a few fixed-point steps.
    The mean of the kept values is right whatever their shape near 0 (the median is
    not, for whole-DN differences).  The special functions run once per distinct
    (group, nu), not per value (per value they took 1.7 s of a 1024^2 fit)."""
    nus, inv_nu = np.unique(nu, return_inverse=True)
    med = (2 * gammaincinv(nus / 2, 0.5) / nus)[inv_nu]    # median of chi2_nu / nu
    x = u / med
    order = np.lexsort((x, lab))
    xs, ls = x[order], lab[order]
    start = np.searchsorted(ls, np.arange(ngr))
    cnt = np.bincount(lab, minlength=ngr)
    k0 = np.full(ngr, np.nan)
    has = cnt > 0
    lo = start[has] + (cnt[has] - 1) // 2                   # the sorted middle(s)
    hi = start[has] + cnt[has] // 2
    k0[has] = 0.5 * (xs[lo] + xs[hi])                       # per-group median
    qcut = _CUT * 2 * gammaincinv(nus / 2, _CUT_QUANTILE) / nus
    key = lab * nus.size + inv_nu                           # (group, nu) pairs
    keys, kinv, kcnt = np.unique(key, return_inverse=True, return_counts=True)
    kg, kn = keys // nus.size, keys % nus.size
    t = k0[kg] * qcut[kn]
    kept = np.bincount(lab, weights=np.where(u <= t[kinv], u, 0.0), minlength=ngr)
    k2 = k0.copy()
    for _ in range(8):
        a = nus[kn] / 2
        frac = np.bincount(kg, weights=kcnt * gammainc(a + 1, t * a / np.maximum(
            k2[kg], 1e-300)), minlength=ngr)
        k2 = np.where(has & (k0 > 0), kept / np.maximum(frac, 1e-300), k0)
    return k2


def common_mode(resultants, read_times, *, read_noise, groups, saturated=None,
                refmask=None, max_rows=64, threads=None, resultant_noise=0.0):
    """Offsets shared by all pixels of a group, read by read, that a line cannot fit.

    Noise common to all pixels of an output (the per-output 1/f noise, the part of
    the correlated 1/f noise that the reference pixels miss) adds the same series
    ``m_i`` to the rate estimates ``d_i`` of every pixel of the output.  From a
    first GLS fit (no jumps) of at most ``max_rows`` evenly spaced rows,
    ``c_i = median over the group's read-noise dominated pixels of (d_i - f_hat)``,
    minus its GLS-weighted mean over ``i`` (weights of a read-noise limited ramp, so
    that the correction leaves those pixels' GLS slopes unchanged); the offsets are
    its running sum ``C_k = sum_{i<k} c_i dt_i`` (``C_0 = 0``).  Subtracting ``C_k``
    from resultant ``k`` of the group's pixels removes the common series except its
    mean, which is a rate common to the group and cannot be told from a uniform
    background (module notes).

    The median uses at most 16384 pixels per group (evenly spaced among those
    selected): its noise, ``1.25 sigma_d / sqrt(n)``, is then < 1 % of the noise
    ``sigma_d`` of one difference.

    Parameters
    ----------
    resultants, read_times, saturated, refmask, max_rows, threads, resultant_noise :
        As in :func:`measure_read_noise`.
    read_noise : float or ndarray (ny, nx), e- per read (not CDS), >= 0
        Model read noise (selects read-noise dominated pixels).
    groups : ndarray of int, shape (ny, nx)
        Group label (>= 0) of every pixel, e.g. the output index of its column.

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
                     max_rows, threads, resultant_noise)
    sub = fp["res"]
    nints, nres = sub.shape[:2]
    out = np.zeros((nints, nres, fp["ngroups"]))
    if nres < 3:
        return out
    lab_all = fp["groups"]
    for lb in np.unique(lab_all[fp["usable"]]):
        pix = fp["quiet"] & (lab_all == lb)
        if pix.sum() < NOISE_MIN_PIXELS:
            pix = fp["usable"] & (lab_all == lb)
        if pix.sum() < NOISE_MIN_PIXELS:
            continue
        ys, xs = np.nonzero(pix)
        stride = -(-ys.size // _CM_MAX_PIXELS)                 # enough for the median
        for k in range(nints):
            c = _group_offsets(fp, k, ys[::stride], xs[::stride])
            if c is not None:
                out[k, 1:, lb] = np.cumsum(c * fp["cov"].dt)
    return out


def _group_offsets(fp, k, ys, xs):
    """``c_i`` (nd,) of one group and integration from its pixels ``(ys, xs)``, or
    None when fewer than two differences have enough usable pixels."""
    g, cov, sub = fp["fit"], fp["cov"], fp["res"]
    f = g.slope[ys, xs]
    inv_dt = (1 / cov.dt).astype(_F32)[:, None]
    r = sub[k][:, ys, xs].astype(_F32)                    # (nres, n)
    d = np.diff(r, axis=0) * inv_dt - f[None]
    if fp["sat"] is not None:
        bad = fp["sat"][k][:, ys, xs]
        bad = np.maximum.accumulate(bad, axis=0)
        d[bad[1:]] = np.nan
    fin = np.isfinite(d)
    good = fin.sum(axis=1) >= NOISE_MIN_PIXELS
    if good.sum() < 2:
        return None
    if fin.all():
        c = np.median(d, axis=1)
    else:
        c = np.array([np.median(row[ok]) if gd else 0.0
                      for row, ok, gd in zip(d, fin, good)])
    # keep the GLS-weighted mean (weights at rate 0), so that the correction
    # changes no read-noise dominated slope: sum_i w_i (c_i - cbar) = 0
    w = _rate0_weights(cov, good)
    return np.where(good, c - np.sum(w * np.where(good, c, 0.0)), 0.0)


def _rate0_weights(cov, good):
    """GLS weights (summing to 1) of the rate estimates ``d_i`` of the differences
    flagged ``good``, for read noise only: ``C^-1 1 / (1^T C^-1 1)`` with the
    tridiagonal covariance ``alpha_i = Ar_i``, ``beta_i = Br_i`` (sigma^2 cancels)."""
    n = cov.dt.size
    idx = np.flatnonzero(good)
    w = np.zeros(n)
    if idx.size:
        # the rows and columns idx of the tridiagonal (Ar, Br): tridiagonal too,
        # its off-diagonal Br where two kept differences are neighbours, else 0
        # (bands only: a dense n x n matrix took 1.6 GB at 10000 resultants)
        adjacent = np.diff(idx) == 1
        off = np.where(adjacent, cov.Br[idx[:-1]], 0.0)      # idx[:-1] <= n - 2
        sub = _solve_tridiagonal(cov.Ar[idx], off, np.ones(idx.size))
        w[idx] = sub / sub.sum()
    return w


def _solve_tridiagonal(diag, off, b):
    """``a^-1 b`` for the symmetric positive-definite tridiagonal ``a`` of diagonal
    ``diag`` (n,) and off-diagonal ``off`` (n - 1,).

    Elimination without pivoting (stable for a positive-definite matrix), in a fixed
    order of scalar operations: the result does not depend on the CPU, as LAPACK's
    (through BLAS) does in its last bits.
    """
    n = b.size
    diag = np.asarray(diag, dtype=float).tolist()
    off = np.asarray(off, dtype=float).tolist() if n > 1 else []
    rhs = np.asarray(b, dtype=float).tolist()
    for i in range(1, n):
        f = off[i - 1] / diag[i - 1]
        diag[i] -= f * off[i - 1]
        rhs[i] -= f * rhs[i - 1]
    x = [0.0] * n
    for i in range(n - 1, -1, -1):
        x[i] = (rhs[i] - (off[i] * x[i + 1] if i < n - 1 else 0.0)) / diag[i]
    return np.array(x)


def _check_first_pass_args(resultants, groups, max_rows, read_noise, saturated,
                           refmask):
    """Validate the arguments shared by both estimators; return them as arrays."""
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
    max_rows = check_int("max_rows", max_rows, minimum=1)
    rn = check_map("read_noise", read_noise, (ny, nx), minimum=0.0)
    sat = None
    if saturated is not None:
        sat = check_mask("saturated", saturated, res.shape)
        sat = sat if sat.ndim == 4 else sat[None]
    ref = None if refmask is None else check_mask("refmask", refmask, (ny, nx))
    return res, gr, max_rows, rn, sat, ref


def _first_pass(resultants, read_times, read_noise, groups, saturated, refmask,
                max_rows, threads, resultant_noise=0.0):
    """Validate, fit a row subsample (GLS, no jumps) and select read-dominated pixels.

    Returns a dict: ``res`` (nints, nres, m, nx) subsample, ``sat`` its saturation
    flags or None, ``rows``, ``fit`` (FitResult of the subsample), ``cov``
    (RampCovariance), ``s2`` (m, nx) read variance, ``rho`` (m, nx) mean Poisson /
    read variance of a difference at the fitted rate, ``usable`` and ``quiet``
    (m, nx) bool (usable; usable and read-noise dominated: Poisson variance of every
    difference <= ``_NOISE_RHO`` times its read variance), ``groups`` (m, nx)
    labels, ``ngroups`` and ``rn`` (validated read noise).
    """
    res, gr, max_rows, rn, sat, ref = _check_first_pass_args(
        resultants, groups, max_rows, read_noise, saturated, refmask)
    ny = res.shape[-2]
    rows = np.arange(0, ny, -(-ny // max_rows))
    res4 = res if res.ndim == 4 else res[None]
    sub = res4[:, :, rows]
    times = read_times
    if is_sequence(read_times):
        times = [t[:, rows] if np.ndim(t) == 3 else t for t in read_times]
    sat = None if sat is None else sat[:, :, rows]
    ref = None if ref is None else ref[rows]
    rn_sub = rn if np.isscalar(rn) else rn[rows]
    g = fit_ramps(sub, times, read_noise=rn_sub, saturated=sat, refmask=ref,
                  threads=threads, variance_rate="fit", resultant_noise=resultant_noise)
    cov = RampCovariance(check_read_times(times, len(times), sub.shape[-2:])[0])
    s2 = np.broadcast_to(np.asarray(rn_sub, dtype=float) ** 2, g.slope.shape)
    fpos = np.maximum(g.slope.astype(float), 0.0)
    ratio = cov.Ap / cov.Ar              # Poisson / read variance per unit f and s2
    with np.errstate(divide="ignore", invalid="ignore"):
        rho_max = np.where(s2 > 0, fpos * ratio.max() / s2, np.inf)
        rho = np.where(s2 > 0, fpos * ratio.mean() / s2, np.inf)
    usable = ((g.dq & np.uint32(DO_NOT_USE)) == 0) & (g.dof >= 1)
    return {"res": sub, "sat": sat, "rows": rows, "fit": g, "cov": cov, "s2": s2,
            "rho": rho, "usable": usable, "quiet": usable & (rho_max <= _NOISE_RHO),
            "groups": gr[rows], "ngroups": int(np.max(gr, initial=0)) + 1, "rn": rn}
