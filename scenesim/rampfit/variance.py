"""Theoretical slope variances of a readout, and the model chi-square of any rate.

All functions take the read noise ``sigma`` of **one read** in e- (not CDS), rates
in e-/s and read times in seconds from reset; variances are in (e-/s)^2.

* :func:`optimal_variance`: ``1 / (1^T C^-1 1)``, the variance of the GLS slope and
  the minimum variance of any unbiased linear slope estimate for that readout
  (Brandt 2024, PASP 136, 045004, eqs. 28-29; ``C`` the covariance of the rate
  estimates, :mod:`scenesim.rampfit.covariance`).
* :func:`ols_variance`: the exact variance ``c^T Sigma c`` of the equal-weight least
  squares slope of the resultants against their mean read times, with the full
  resultant covariance ``Sigma_ij = sigma^2 delta_ij / N_i + f m_ij``,
  ``m_ii = tau_i``, ``m_ij = tbar_min(i,j)``.
* :func:`rauscher2007_variance`: the closed form of Rauscher et al. (2007, PASP 119,
  768, eq. 1; third term's sign and factor corrected) for even MULTIACCUM ramps.
* :func:`model_chi2`: the ``CHI2`` of :func:`scenesim.rampfit.fit_ramps` for any
  rate, e.g. another fitter's (:mod:`scenesim.adapters.stcal` uses it):
  ``chi2 = sum_k (d_k - rate)^T C^-1 (d_k - rate) / (n_usable - ddof)`` over the
  integrations ``k`` and their usable differences.  Its expectation is 1 for the
  GLS rate with ``ddof=1`` (and for the true rate with ``ddof=0``), and
  ``1 + (V/V_opt - 1)/dof`` for another linear unbiased estimate of variance ``V``.
"""

import math

import numpy as np

from noise.errors import ParameterError
from noise.validate import check_array, check_float, check_int, check_map, check_mask

from scenesim.rampfit.covariance import RATE_FLOOR, RampCovariance
from scenesim.rampfit.solver import ldl_pass, row_chunks
from scenesim.rampfit.times import check_read_times

__all__ = ["optimal_variance", "ols_variance", "rauscher2007_variance", "model_chi2"]

_F32 = np.float32


def _broadcast_rate_noise(rate, read_noise):
    """Validated ``rate`` (e-/s) and ``read_noise`` (e- per read) broadcast together."""
    rate = check_array("rate", rate, minimum=0.0, unit="e-/s")
    read_noise = check_array("read_noise", read_noise, minimum=0.0, unit="e- per read")
    try:
        return np.broadcast_arrays(rate, read_noise)
    except ValueError as exc:
        raise ParameterError(
            f"'rate' shape {rate.shape} and 'read_noise' shape {read_noise.shape} do "
            f"not broadcast") from exc


def _slope_times(read_times):
    """Validated read times of >= 2 resultants (theory functions)."""
    times, _ = check_read_times(read_times)
    if len(times) < 2:
        raise ParameterError(f"'read_times' needs >= 2 resultants for a slope, got "
                             f"{len(times)}")
    return times


def optimal_variance(rate, read_times, read_noise, *, resultant_noise=0.0):
    """Variance of the optimal (GLS) slope, ``1 / (1^T C^-1 1)``, for a known rate.

    Parameters
    ----------
    rate : float or ndarray, e-/s (>= 0)
    read_times : sequence of 1-D arrays, seconds from reset
        Read times of each resultant (>= 2 resultants).
    read_noise : float or ndarray, e- per read (not CDS), broadcast with ``rate``
    resultant_noise : float or sequence of float (one per resultant), keyword-only
        White noise added to each resultant once, independently of its reads, e- rms
        (e.g. the rounding of an on-board average of several digitised reads,
        ``gain / sqrt(12)``): ``Var(R_i)`` gains ``q_i = resultant_noise_i**2``, so
        ``alpha_i`` gains ``(q_i + q_{i+1}) / dt_i^2`` and ``beta_i``
        ``-q_{i+1} / (dt_i dt_{i+1})``.

    Returns
    -------
    ndarray or float, (e-/s)^2, float64
        The theoretical minimum variance of an unbiased linear slope estimate for
        that readout (Brandt 2024, eqs. 28-29); 0 where rate and read noise are 0.
        Per-pixel read times (global reset) give the same result as the 1-D times:
        the variance depends on time differences only.
    """
    times = _slope_times(read_times)
    rate, rn = _broadcast_rate_noise(rate, read_noise)
    cov = RampCovariance(times)
    s2 = rn ** 2
    dt = cov.dt
    q = np.broadcast_to(np.asarray(resultant_noise, dtype=np.float64) ** 2,
                        (dt.size + 1,))
    S11 = np.zeros(rate.shape)
    u = Dprev = None
    with np.errstate(divide="ignore", invalid="ignore"):
        for i in range(dt.size):
            a = s2 * cov.Ar[i] + rate * cov.Ap[i] + (q[i] + q[i + 1]) / dt[i] ** 2
            if i == 0:
                D, u = a, np.ones(rate.shape)
            else:
                b = (s2 * cov.Br[i - 1] + rate * cov.Bp[i - 1]
                     - q[i] / (dt[i - 1] * dt[i]))
                ell = b / Dprev
                D = a - ell * b
                u = 1 - ell * u
            S11 = S11 + u * u / D
            Dprev = D
        out = 1 / S11
    out = np.where((rate == 0) & (rn == 0) & (not q.any()), 0.0, out)   # no noise
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
    times = _slope_times(read_times)
    rate, rn = _broadcast_rate_noise(rate, read_noise)
    cov = RampCovariance(times)
    tb = cov.tbar
    c = (tb - tb.mean()) / np.sum((tb - tb.mean()) ** 2)
    idx = np.arange(tb.size)
    m = tb[np.minimum.outer(idx, idx)]
    m[idx, idx] = cov.tau
    q_read = float(np.sum(c * c / cov.n))
    # an exactly rounded sum, not BLAS (whose last bits depend on the CPU)
    q_pois = math.fsum((np.multiply.outer(c, c) * m).ravel().tolist())
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
    check_int("ngroups", ngroups, minimum=2)
    check_int("nframes", nframes, minimum=1)
    check_int("groupgap", groupgap, minimum=0)
    t_frame = check_float("t_frame", t_frame, minimum=0.0, strict_min=True)
    rate, rn = _broadcast_rate_noise(rate, read_noise)
    n, m = float(ngroups), float(nframes)
    tg = (m + groupgap) * t_frame
    tot = (12 * (n - 1) * rn ** 2 / (m * n * (n + 1))
           + 6 * (n * n + 1) * (n - 1) * tg * rate / (5 * n * (n + 1))
           - 2 * (m * m - 1) * (n - 1) * t_frame * rate / (m * n * (n + 1)))
    out = tot / ((n - 1) * tg) ** 2
    return float(out) if out.ndim == 0 else out


def model_chi2(resultants, read_times, rate, read_noise, *, valid=None, ddof=1,
               resultant_noise=0.0):
    """Chi-square per degree of freedom of the resultants about a given rate.

    The quantity ``CHI2`` of :func:`scenesim.rampfit.fit_ramps`, for any rate: with
    the rate estimates ``d_i = (R_{i+1} - R_i) / dt_i`` of each integration and
    ``C(f)`` their model covariance (Brandt 2024, eqs. 28-29;
    :mod:`scenesim.rampfit.covariance`), evaluated at ``max(rate, 0)`` as the GLS
    fitter does::

        chi2 = sum_k (d_k - rate)^T C^-1 (d_k - rate) / (n_usable - ddof)

    summed over integrations ``k`` and over the usable differences only (removing a
    difference splits the ramp into independent segments, as in the fit).  For ramps
    whose true rate is ``rate`` (so that ``C`` is their covariance) its expectation
    is 1 with ``ddof=0``; for the GLS rate of the same data it is 1 with ``ddof=1``,
    and ``1 + (V/V_opt - 1)/dof`` for another linear unbiased estimate of variance
    ``V`` (e.g. stcal's).

    Parameters
    ----------
    resultants : ndarray, shape (nres, ny, nx) or (nints, nres, ny, nx), e-
        Resultants, in electrons.  Any real dtype (differences are taken in float64,
        then float32).  Finite wherever a usable difference uses them; elsewhere
        (e.g. saturated) they may be NaN.
    read_times : sequence of nres arrays, seconds from reset
        As in :func:`scenesim.rampfit.fit_ramps` (1-D, or per pixel differing by a
        common shift).
    rate : float or ndarray (ny, nx), e-/s
        Rate the rate estimates are compared with (finite; any sign).
    read_noise : float or ndarray (ny, nx), e- per read
        White read noise of **one read** (not CDS), >= 0.  Where it is 0 the
        covariance uses a rate of at least 1e-6 e-/s, as the fitter does.
    valid : ndarray of bool, optional
        Shape (nres - 1, ny, nx) or (nints, nres - 1, ny, nx), with the leading
        axes of ``resultants``: usable differences (difference ``i`` uses
        resultants ``i`` and ``i + 1``); default all.
    ddof : int, keyword-only
        Degrees of freedom taken by the rate (>= 0): 1 (default) when it was fitted
        to these resultants, 0 for a rate known independently.
    resultant_noise : float or sequence of nres floats, e- rms, keyword-only
        White noise added to each resultant once (as in
        :func:`scenesim.rampfit.fit_ramps`); default 0.

    Returns
    -------
    ndarray, shape (ny, nx), float32
        ``chi2`` per degree of freedom; 0 where ``n_usable - ddof <= 0``.

    Raises
    ------
    noise.errors.ParameterError
        On bad input, before any work.
    """
    res4, valid4, times, rate, read_noise, ddof = _check_chi2_args(
        resultants, read_times, rate, read_noise, valid, ddof)
    nints, nres, ny, nx = res4.shape
    cov = RampCovariance(times, resultant_noise=resultant_noise)
    A, B = cov.coefficient_lists()
    inv_dt = (1.0 / cov.dt)[:, None]
    rate_map = np.broadcast_to(np.asarray(rate, dtype=_F32), (ny, nx))
    s2_map = np.broadcast_to(np.asarray(read_noise, dtype=float) ** 2, (ny, nx))
    raw = np.zeros((ny, nx), _F32)
    for y0, y1 in row_chunks(ny, nx, nints * nres):
        f = rate_map[y0:y1].reshape(-1)
        s2 = s2_map[y0:y1].reshape(-1).astype(_F32)
        fc = np.maximum(f, np.where(s2 == 0, _F32(RATE_FLOOR), _F32(0)))
        acc = np.zeros(f.size, _F32)
        for k in range(nints):
            blk = res4[k, :, y0:y1].reshape(nres, -1)
            blk = blk if blk.dtype in (np.float32, np.float64) else blk.astype(float)
            v = valid4[k, :, y0:y1].reshape(nres - 1, -1)
            with np.errstate(invalid="ignore"):
                d = np.where(v, np.diff(blk, axis=0) * inv_dt, 0).astype(_F32)
            mf = v.astype(_F32)
            mc = mf[:-1] * mf[1:]
            acc += ldl_pass(d, v, mf, mc, f, s2, fc, A, B, want_x=False)[2]
        raw[y0:y1] = acc.reshape(y1 - y0, nx)
    dof = valid4.sum(axis=(0, 1), dtype=np.int64) - ddof
    return np.divide(np.maximum(raw, 0), dof, out=np.zeros((ny, nx), _F32),
                     where=dof > 0).astype(_F32)


def _check_chi2_args(resultants, read_times, rate, read_noise, valid, ddof):
    """Validate :func:`model_chi2`'s arguments; return them in canonical form."""
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
    times, _ = check_read_times(read_times, nres, (ny, nx))
    rate = check_map("rate", rate, (ny, nx), minimum=None)
    read_noise = check_map("read_noise", read_noise, (ny, nx), minimum=0.0)
    dshape = res.shape[:-3] + (nres - 1, ny, nx)
    if valid is None:
        valid4 = np.ones((nints, nres - 1, ny, nx), bool)
    else:
        valid4 = check_mask("valid", valid, dshape)    # one flag per difference
        valid4 = valid4 if valid4.ndim == 4 else valid4[None]
    ddof = check_int("ddof", ddof, minimum=0)
    if res.dtype.kind == "f":
        need = np.zeros(res4.shape, bool)          # resultants of a usable difference
        need[:, :-1] |= valid4
        need[:, 1:] |= valid4
        nbad = int((need & ~np.isfinite(res4)).sum())
        if nbad:
            raise ParameterError(
                f"'resultants' must be finite where a usable difference ('valid') "
                f"uses them; {nbad} NaN or inf values are")
    return res4, valid4, times, rate, read_noise, ddof
