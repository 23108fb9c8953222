"""The covariance model of up-the-ramp rate estimates (Brandt 2024, PASP 136, 045004).

Conventions
-----------
Resultants are in electrons, times in seconds from the pixel's reset, rates in
e-/s.  The read noise ``sigma`` is the noise of **one read** (one frame), in e-,
never the CDS noise (CDS noise = sqrt(2) sigma).

Model
-----
Resultant ``i`` averages ``N_i`` reads at times ``t_{i,1} < ... < t_{i,N_i}``.  With a
constant rate ``f`` the charge collected by time ``t`` is a Poisson process, so
``Cov(Q(t), Q(t')) = f min(t, t')``, and each read adds independent read noise of
variance ``sigma^2``.  Hence, with ``tbar_i`` the mean read time and
``tau_i = (1/N_i^2) sum_k (2 N_i - 2k + 1) t_{i,k}``
(:func:`scenesim.detector.readout.resultant_moments`)::

    Var(R_i)            = sigma^2 / N_i + f tau_i
    Cov(R_i, R_j), i<j  = f tbar_i                   (all reads of i precede those of j)

The rate estimates ``d_i = (R_{i+1} - R_i) / dt_i`` (``dt_i = tbar_{i+1} - tbar_i``) have
a tridiagonal covariance ``C`` (Brandt 2024, eqs. 28-29)::

    alpha_i = [sigma^2 (1/N_i + 1/N_{i+1}) + f (tau_i + tau_{i+1} - 2 tbar_i)] / dt_i^2
    beta_i  = [-sigma^2 / N_{i+1} + f (tbar_{i+1} - tau_{i+1})] / (dt_i dt_{i+1})

and every ``d_i`` has mean ``f``.  :class:`RampCovariance` holds the read part (per
``sigma^2``) and the Poisson part (per unit ``f``) of ``alpha`` and ``beta``, which
depend on the readout only, and a constant part from white noise added to each
resultant once, independently of its reads (``resultant_noise``, e.g. the rounding of
an on-board average of ``N > 1`` digitised reads, :func:`noise.adc.averaging_noise`):
``Var(R_i)`` gains ``q_i``, so ``alpha_i`` gains ``(q_i + q_{i+1}) / dt_i^2`` and
``beta_i`` gains ``-q_{i+1} / (dt_i dt_{i+1})``.  Differencing removes the unknown
zero point (bias, kTC); because the covariance only involves differences of times,
a common shift of all read times (a global reset) changes nothing.

Where ``sigma = 0`` the covariance is evaluated at a rate of at least
:data:`RATE_FLOOR`, so that it stays positive definite when the rate estimate is
<= 0 (no effect otherwise).
"""

import numpy as np

from noise.errors import ParameterError
from scenesim.detector.readout import resultant_moments
from scenesim.rampfit.times import check_read_times

__all__ = ["RampCovariance", "RATE_FLOOR", "check_resultant_noise"]

#: Least rate (e-/s) of the covariance where the read noise is 0.
RATE_FLOOR = 1e-6


class RampCovariance:
    """Per-resultant constants and covariance coefficients of one readout.

    Parameters
    ----------
    read_times : sequence of 1-D ndarray, s from reset
        Sorted read times of every resultant (one pixel; validated by
        :func:`scenesim.rampfit.times.check_read_times`).
    resultant_noise : float or sequence of float, e- rms, keyword-only
        White noise added to each resultant once (one value, or one per resultant;
        >= 0; module notes).  Default 0.

    Attributes
    ----------
    n, tbar, tau : ndarray, shape (nres,), float64
        Reads per resultant, mean read time (s) and Brandt's ``tau`` (s), from
        :func:`scenesim.detector.readout.resultant_moments` (the one implementation,
        also behind ``Readout.mean_times`` and ``Readout.tau``).
    dt : ndarray, shape (nres - 1,), s
        ``tbar_{i+1} - tbar_i``.
    Ar, Ap : ndarray, shape (nres - 1,)
        Read (per sigma^2, s^-2) and Poisson (per f, s^-1) parts of ``alpha_i``.
    Br, Bp : ndarray, shape (nres - 2,)
        The same for ``beta_i``.
    q : ndarray, shape (nres,)
        ``resultant_noise**2``, e-^2.
    Aq, Bq : ndarray, shapes (nres - 1,) and (nres - 2,), (e-/s)^2
        The constant parts of ``alpha_i`` and ``beta_i`` (zeros without
        ``resultant_noise``).
    has_q : bool
        Whether any ``q`` is non-zero (the solves skip the constant part otherwise).
    """

    def __init__(self, read_times, *, resultant_noise=0.0):
        times, shift = check_read_times(read_times)
        if shift is not None:
            raise ParameterError(
                "'read_times' of a RampCovariance must be the same for every pixel "
                "(1-D arrays, one per resultant)")
        self.n, self.tbar, self.tau = resultant_moments(times)
        self.dt = np.diff(self.tbar)
        n, tb, tau, dt = self.n, self.tbar, self.tau, self.dt
        self.Ar = (1 / n[:-1] + 1 / n[1:]) / dt ** 2
        self.Ap = (tau[:-1] + tau[1:] - 2 * tb[:-1]) / dt ** 2
        self.Br = (-1 / n[1:-1]) / (dt[:-1] * dt[1:])
        self.Bp = (tb[1:-1] - tau[1:-1]) / (dt[:-1] * dt[1:])
        self.q = check_resultant_noise(resultant_noise, n.size)
        self.has_q = bool(self.q.any())
        q = self.q
        self.Aq = (q[:-1] + q[1:]) / dt ** 2
        self.Bq = -q[1:-1] / (dt[:-1] * dt[1:])

    @property
    def nres(self):
        """Number of resultants."""
        return self.n.size

    def coefficient_lists(self):
        """``((Ar, Ap, Aq), (Br, Bp, Bq))`` as lists of Python floats (``Aq`` and
        ``Bq`` None without ``resultant_noise``).

        The form :func:`scenesim.rampfit.solver.ldl_pass` takes: Python floats keep
        the float32 arithmetic of the per-pixel arrays in float32.
        """
        aq, bq = (self.Aq.tolist(), self.Bq.tolist()) if self.has_q else (None, None)
        return ((self.Ar.tolist(), self.Ap.tolist(), aq),
                (self.Br.tolist(), self.Bp.tolist(), bq))


def check_resultant_noise(resultant_noise, nres):
    """``resultant_noise`` (one value or one per resultant, e- rms, >= 0, finite) as
    the variances ``q`` (nres,) float64, e-^2."""
    try:
        q = np.asarray(resultant_noise, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"'resultant_noise' must be a number or one number per "
                             f"resultant (e- rms), got {resultant_noise!r}") from exc
    if q.ndim > 1 or (q.ndim == 1 and q.size != nres):
        raise ParameterError(f"'resultant_noise' must be one number or {nres} (one per "
                             f"resultant), got shape {q.shape}")
    if not np.all(np.isfinite(q)) or np.any(q < 0):
        raise ParameterError(f"'resultant_noise' must be finite and >= 0 (e- rms), got "
                             f"{resultant_noise!r}")
    return np.broadcast_to(q * q, (nres,)).copy()
