"""Classical nonlinearity, forward (the engine) and inverse (linearisation).

The integrating node's capacitance grows as charge collects, so the measured signal
falls below the collected charge (classical nonlinearity; the JWST calibration
pipeline's ``linearity`` step corrects it with a per-pixel polynomial).  The forward
model is::

    m = p(q) = q + c2 q**2 + c3 q**3 + ...       (q, m in e-; c_k in e-**(1-k))

The linear coefficient is 1 by construction (gain is applied separately, at the ADC).
The inverse ``q = p^-1(m)`` exists on the interval ``(q_lo, q_hi)`` around 0 where
``p'(q) = 1 + 2 c2 q + 3 c3 q**2 + ... > 0``; ``q_lo`` (``q_hi``) is the largest
negative (smallest positive) real root of ``p'``, or -inf (+inf) when there is none.
Negative ``q`` is allowed so that noisy, bias-subtracted data can be inverted.

:meth:`Nonlinearity.invert` solves ``p(q) = m`` with a bracketed (safeguarded) Newton
iteration, vectorised over pixels (Press et al., Numerical Recipes, 3rd ed., section
9.4, ``rtsafe``): each pixel keeps a bracket ``[a, b]`` with ``p(a) <= m <= p(b)``
(0 is one end, since ``p(0) = 0``; the other is ``q_hi`` or ``q_lo``, or found by
doubling when the domain is unbounded); a Newton step that would leave the bracket is
replaced by bisection.  Because ``p`` is monotonic on the bracket the iteration always
converges; near the root it is quadratic, so 4 to 6 iterations are typical.  The
result is exact to float64 round-off: its relative error is about
``eps * |m| / (p'(q) |q|)``, which grows only as ``p'`` approaches 0 at the turnover
(exactly at ``q_hi``, where ``p' = 0``, the problem itself is ill-conditioned and the
error is about ``sqrt(eps)``).

:func:`linearize_resultants` applies the inverse to recorded resultants, as a
pipeline's linearity step does.
"""

import math
import numbers
from dataclasses import dataclass, field

import numpy as np

from noise.errors import ParameterError, ParameterTypeError
from noise.validate import check_image, check_instance, describe

__all__ = ['Nonlinearity', 'linearize_resultants']


_EPS = np.finfo(np.float64).eps


_BLOCK = 1 << 15  # elements per block of Nonlinearity.invert


# ------------------------------------------------------------------------- nonlinearity
@dataclass(frozen=True)
class Nonlinearity:
    """Polynomial classical nonlinearity ``m = q + c2 q**2 + c3 q**3 + ...`` (e-).

    Parameters
    ----------
    coeffs : sequence of float
        ``(c2, c3, ...)`` in e-**(1-k) for the term ``c_k q**k``.  Empty means linear.
        Typical H2RG values: ``c2`` of order -1e-6 /e- (a few per cent at 5e4 e-).

    Attributes
    ----------
    q_lo, q_hi : float
        The monotonic interval ``(q_lo, q_hi)`` of ``p`` around 0, e- (see module notes);
        ``-inf`` / ``+inf`` when unbounded.  :meth:`invert` is defined on
        ``[p(q_lo), p(q_hi)]``.

    Examples
    --------
    >>> nl = Nonlinearity((-1e-6,))
    >>> nl.check_monotonic(8e4)
    >>> float(nl.invert(nl.apply(5e4)))  # doctest: +SKIP
    50000.0
    """

    coeffs: tuple = ()
    q_lo: float = field(init=False, repr=False, compare=False)
    q_hi: float = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        raw = self.coeffs
        if isinstance(raw, (numbers.Real, np.number)) and not isinstance(raw, bool):
            raw = (raw,)
        try:
            vals = tuple(float(c) for c in np.asarray(raw, dtype=np.float64).ravel())
        except (TypeError, ValueError) as exc:
            raise ParameterError(
                f"'nonlinearity' coefficients must be real numbers (c2, c3, ...), "
                f"got {self.coeffs!r}") from exc
        if not all(math.isfinite(c) for c in vals):
            raise ParameterError(
                f"'nonlinearity' coefficients must be finite, got {self.coeffs!r}")
        # Trailing zeros do not change the polynomial; dropping them keeps the roots
        # computation well posed and makes (0.0,) equal to the linear case.
        while vals and vals[-1] == 0.0:
            vals = vals[:-1]
        object.__setattr__(self, "coeffs", vals)
        lo, hi = self._monotonic_interval(vals)
        object.__setattr__(self, "q_lo", lo)
        object.__setattr__(self, "q_hi", hi)

    @staticmethod
    def _monotonic_interval(coeffs):
        if not coeffs:
            return -math.inf, math.inf
        # p'(q) = 1 + 2 c2 q + 3 c3 q^2 + ...  (ascending powers)
        dcoef = np.array([1.0] + [k * c for k, c in enumerate(coeffs, start=2)])
        roots = np.polynomial.polynomial.polyroots(dcoef)
        # A complex pair with a tiny imaginary part is a near-touching of zero:
        # treat it as a root (conservative), so p' is safely positive inside.
        real = roots.real[np.abs(roots.imag) <= 1e-7 * np.abs(roots)]
        pos = real[real > 0]
        neg = real[real < 0]
        hi = float(pos.min()) if pos.size else math.inf
        lo = float(neg.max()) if neg.size else -math.inf
        return lo, hi

    @property
    def is_linear(self):
        """True when there are no non-zero coefficients."""
        return not self.coeffs

    def _p(self, q):
        if not self.coeffs:
            return q.copy()
        h = np.full_like(q, self.coeffs[-1])
        for c in self.coeffs[-2::-1]:
            h *= q
            h += c
        return q + q * q * h

    def _dp(self, q):
        d = np.full_like(q, len(self.coeffs) + 1.0) * self.coeffs[-1]
        for k in range(len(self.coeffs) - 1, 0, -1):
            d *= q
            d += (k + 1) * self.coeffs[k - 1]
        return 1.0 + q * d

    def apply(self, charge):
        """Measured signal of ``charge``: ``q + c2 q**2 + ...``.

        Parameters
        ----------
        charge : array_like, any shape, e-

        Returns
        -------
        ndarray, same shape, float64, e-
        """
        try:
            q = np.asarray(charge, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ParameterTypeError(
                f"'charge' must be a number or an array of numbers (e-), got "
                f"{describe(charge)}") from exc
        return self._p(q)

    @property
    def measured_range(self):
        """``(p(q_lo), p(q_hi))``: the domain of :meth:`invert`, e-."""
        def p(x):
            return float(self._p(np.array(x))) if math.isfinite(x) else x
        return p(self.q_lo), p(self.q_hi)

    def check_monotonic(self, max_charge):
        """Raise unless ``p`` is strictly increasing on ``[0, max_charge]``.

        Parameters
        ----------
        max_charge : float, e-
            Largest charge the pixel can hold (the full well), finite and > 0.

        Raises
        ------
        ParameterError
            If ``p'(q) <= 0`` somewhere in ``[0, max_charge]`` (the polynomial turns over
            below the full well and the signal could not be inverted).
        """
        if isinstance(max_charge, bool) or not isinstance(max_charge, (numbers.Real,
                                                                       np.number)):
            raise ParameterError(
                f"'max_charge' must be a real number, got {max_charge!r}")
        if not math.isfinite(max_charge) or max_charge <= 0:
            raise ParameterError(
                f"'max_charge' must be finite and > 0, got {max_charge!r}")
        if max_charge >= self.q_hi:
            raise ParameterError(
                f"'nonlinearity' coefficients {self.coeffs!r} are not monotonic up to "
                f"{float(max_charge):g} e-: the polynomial turns over at "
                f"{self.q_hi:.6g} e-; use coefficients whose derivative "
                f"1 + 2 c2 q + 3 c3 q^2 + ... stays > 0 up to the full well, "
                f"or a full well below {self.q_hi:.6g} e-")

    def invert(self, measured, *, max_iter=200):
        """Charge ``q`` with ``p(q) = measured``, exact to float64 round-off.

        Parameters
        ----------
        measured : array_like, any shape, e-
            Finite values inside :attr:`measured_range`.
        max_iter : int
            Iteration cap of the safeguarded Newton solver (never reached in practice:
            bisection alone would need about 60 steps per 2**60 of bracket width).

        Returns
        -------
        ndarray, same shape, float64, e-

        Raises
        ------
        ParameterError
            If any value is not finite or lies outside :attr:`measured_range`.
        """
        m = np.array(measured, dtype=np.float64)
        if not self.coeffs:
            return m
        shape = m.shape
        m = m.reshape(-1)
        if not np.all(np.isfinite(m)):
            raise ParameterError("'measured' must be finite to invert the nonlinearity")
        m_lo, m_hi = self.measured_range
        if m.size and (m.min() < m_lo or m.max() > m_hi):
            raise ParameterError(
                f"'measured' values span [{m.min():.6g}, {m.max():.6g}] e- but the "
                f"nonlinearity {self.coeffs!r} is invertible only on "
                f"[{m_lo:.6g}, {m_hi:.6g}] e- (its monotonic range)")
        out = np.empty_like(m)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            # Blocks that fit in cache: ~4x faster than whole-array passes.
            for i in range(0, m.size, _BLOCK):
                out[i:i + _BLOCK] = self._solve(m[i:i + _BLOCK], int(max_iter))
        return out.reshape(shape)

    def _solve(self, m, max_iter):
        """Safeguarded Newton for one 1-d block of ``m`` (inside the domain)."""
        # Brackets: p(a) <= m <= p(b), with 0 as one end (p(0) = 0).
        nonneg = m >= 0
        a = np.where(nonneg, 0.0, self.q_lo)
        b = np.where(nonneg, self.q_hi, 0.0)
        for end, sign in ((b, 1.0), (a, -1.0)):
            unbounded = ~np.isfinite(end)
            if unbounded.any():
                # p is increasing and unbounded there: double until it passes m.
                end[unbounded] = sign * np.maximum(2.0 * np.abs(m[unbounded]), 1.0)
                for _ in range(2100):
                    short = unbounded & (sign * (self._p(end) - m) < 0)
                    if not short.any():
                        break
                    end[short] *= 2.0
        x = np.clip(m, a, b)
        tiny = np.finfo(np.float64).tiny
        for _ in range(max_iter):
            g = self._p(x) - m
            d = self._dp(x)
            a = np.where(g < 0, x, a)
            b = np.where(g > 0, x, b)
            xn = x - g / d
            bad = ~(d > 0) | ~(xn >= a) | ~(xn <= b)
            xn = np.where(bad, 0.5 * (a + b), xn)
            xn = np.where(g == 0, x, xn)
            tol = 4.0 * _EPS * np.maximum(np.abs(xn), tiny)
            done = (np.abs(xn - x) <= tol) | (b - a <= tol)
            x = xn
            if done.all():
                break
        return x


_PASSES = 3   # linearisations of multi-read ramps: one plain, then two with the rate
_PIXELS = 1 << 18  # pixels per block of the multi-read linearisation (2 MB images)


def linearize_resultants(e, nl, tbar, *, read_times=None, saturated=None):
    """Invert the classical nonlinearity of resultants, like a pipeline's linearity step.

    The engine applies ``m = p(q)`` to the charge ``q`` accumulated since reset, before
    the bias, kTC and read noise are added, and a resultant is the mean of its reads:
    ``R_r = z + (1/n_r) sum_k p(q_k) + noise``.  The zero level ``z`` of each pixel and
    integration is estimated as the first resultant extrapolated back to the reset on
    the linearised scale, ``z = L_0 - tbar_0 (L_1 - L_0) / (tbar_1 - tbar_0)`` with
    ``L = z + p^-1(R - z - delta)`` iterated (``R_0`` for one-resultant ramps), and
    every resultant becomes ``L_r = z + p^-1(R_r - z - delta_r)`` (values outside the
    invertible range are clipped to it; those are saturated anyway).

    ``delta_r`` is the excess of a resultant that averages several reads over one read
    at its mean charge, ``delta_r = (1/n_r) sum_k p(f t_k) - p(f tbar_r)`` for a pixel
    of rate ``f`` (``c2 f^2 var(t) + c3 f^3 (3 tbar var(t) + mu3(t))`` over the
    group's read times ``t_k``): without it a 6-read resultant 5.4e4 e- deep is read
    ``c2 f^2 var(t)`` = -14 e- low for ``c2`` = -8e-7.  It is 0 for one-read
    resultants, and when ``read_times`` is not given (one read at ``tbar`` assumed).
    ``f`` is the least-squares slope of the linearised ramp over its resultants
    before the first one flagged ``saturated`` (0, no correction, with fewer than
    two); the ramp is linearised
    ``_PASSES`` = 3 times, without ``delta`` and then with the rate of the previous
    pass.  The rate error of a pass scales the next one's by ``2 eps`` (``eps``: the
    relative slope error without the correction, 5.5e-4 for the Roman test window),
    so the third pass is converged to ``(2 eps)^2 delta``.  ``delta`` is set to 0
    where a predicted charge ``f t_k`` leaves the monotonic range, and on resultants
    flagged ``saturated``.

    Remaining error: the charges scatter about ``f t_k`` (Poisson), and the resultant
    carries ``c2 s^2`` with ``s^2`` their variance within the group, whose mean is
    ``f^2 var(t) + f (tbar - tau)`` (``tau = (1/n^2) sum_jk min(t_j, t_k)``, from the
    random walk's covariance ``f min(t_j, t_k)``).  ``delta`` removes the first term;
    the second, ``c2 f (tbar - tau)`` = ``c2 f dt (n^2 - 1) / (6 n)`` for ``n`` reads
    ``dt`` apart, is a fraction ``2 / (n f dt)`` of the first: -1.9e-3 e- for the
    6-read resultant above (``f dt`` = 2.5e3 e-), 1e-5 of its noise (a Monte Carlo
    of the random walk agrees; with ``c3`` read ``c2 + 3 c3 q`` for ``c2``).  The
    rate's own
    noise ``sigma_f`` enters as ``2 c2 f var(t) delta_f`` (zero mean) plus ``c2
    var(t) sigma_f^2``, far smaller still.  With a global reset the pixel's clock
    offset shifts every ``t_k`` (``read_times`` are those of a pixel at offset 0);
    the ``c2`` part of ``delta`` does not depend on it, the ``c3`` part moves by
    ``3 c3 f^3 var(t)`` per second of offset: -2.2 e-/s for the 6-read resultant
    above with ``c3`` = -2e-12, up to -0.27 e- for an offset of one frame time
    (1e-3 of its noise).  Not corrected.

    ``e`` must be free of IPC, which the engine applies
    after the nonlinearity: :func:`prepare_exposure` undoes it first
    (:func:`undo_ipc`) when the header records the kernel.  On IPC-mixed signals
    ``sum_j k_j p(q_j)`` the inversion returns ``sum_j k_j q_j + c2 sum_j k_j (q_j -
    Q)^2`` to first order (``Q = sum_j k_j q_j``): the kernel-weighted variance of
    the neighbours' charges, ``~ c2 alpha sum_n (q_n - q)^2``, times ``c2`` (-0.3
    sigma in the bright-star scene's bright bins, down to -0.8 sigma next to its
    bright pixels).

    Parameters
    ----------
    e : ndarray, shape (nints, nres, ny, nx), float32, e-
    nl : scenesim.detector.nonlinearity.Nonlinearity
    tbar : ndarray, shape (nres,), s
    read_times : list of nres 1-d arrays, s, optional, keyword-only
        Times of each resultant's reads from the reset
        (:meth:`scenesim.detector.readout.Readout.read_times` of a pixel at clock
        offset 0); their means must be ``tbar``.  Without it (or with one read per
        resultant) the result is that of one read per resultant.
    saturated : ndarray of bool, shape of ``e``, optional, keyword-only
        Saturated resultants (sticky, as
        :func:`scenesim.calib.saturation.saturation_flags` makes them): the rate
        is fitted before the first one, and flagged resultants get no ``delta``.

    Returns
    -------
    ndarray, same shape, float32, e-
    """
    check_instance("nl", nl, Nonlinearity, "a scenesim.detector.nonlinearity.Nonlinearity")
    e = check_image("e", e)
    if e.ndim != 4:
        raise ParameterError(
            f"'e' must have shape (nints, nres, ny, nx), got shape {e.shape}")
    try:
        t = np.asarray(tbar, dtype=np.float64)
    except (TypeError, ValueError):
        t = None
    if t is None or t.shape != (e.shape[1],) or not np.all(np.isfinite(t)):
        raise ParameterError(
            f"'tbar' must hold {e.shape[1]} finite mean times (s), one per resultant, "
            f"got {describe(tbar)}")
    groups = _check_read_times(read_times, t)
    if saturated is not None:
        sat = np.asarray(saturated)
        if sat.dtype != np.bool_ or sat.shape != e.shape:
            raise ParameterError(
                f"'saturated' must be a bool array of the shape of 'e' {e.shape}, got "
                f"{describe(saturated)}")
        saturated = sat
    e = np.asarray(e, dtype=np.float32)
    lo, hi = nl.measured_range
    lo, hi = np.nextafter(lo, np.inf), np.nextafter(hi, -np.inf)   # strictly inside
    out = np.empty_like(e)
    if (groups is None or nl.is_linear or e.shape[1] < 2
            or all(g.size == 1 for g in groups)):
        _linearize(e, nl, tbar, lo, hi, out)
        return out
    # pixels are independent: blocks of rows keep the passes' float64 images small
    nints, _, ny, nx = e.shape
    rows = max(1, _PIXELS // (nints * nx))
    for y0 in range(0, ny, rows):
        sl = (slice(None), slice(None), slice(y0, y0 + rows))
        sat = None if saturated is None else saturated[sl]
        # resultants before the first flagged one give the rate (flags are sticky)
        n_ok = None if sat is None else np.where(sat.any(axis=1), sat.argmax(axis=1),
                                                  e.shape[1])
        rate = None
        for i in range(_PASSES):
            rate = _linearize(e[sl], nl, t, lo, hi, out[sl], rate=rate, groups=groups,
                              saturated=sat, n_ok=n_ok, want_rate=i < _PASSES - 1)
    return out


def _check_read_times(read_times, t):
    """``read_times`` as a list of 1-d float64 arrays whose means are ``t``, or None."""
    if read_times is None:
        return None
    bad = (f"'read_times' must be {t.size} non-empty 1-d arrays of finite read times "
           f"(s), one per resultant, whose means are 'tbar'")
    try:
        groups = [np.asarray(g, dtype=np.float64) for g in read_times]
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{bad}, got {describe(read_times)}") from exc
    if (len(groups) != t.size
            or any(g.ndim != 1 or g.size == 0 or not np.all(np.isfinite(g))
                   for g in groups)):
        raise ParameterError(f"{bad}, got {describe(read_times)}")
    means = np.array([g.mean() for g in groups])
    if not np.allclose(means, t, rtol=1e-9, atol=1e-12):
        raise ParameterError(f"{bad}; their means are {means.tolist()}, 'tbar' is "
                             f"{t.tolist()}")
    return groups


def _minus(x, d):
    return x if d is None else x - d


def _linearize(e, nl, tbar, lo, hi, out, *, rate=None, groups=None, saturated=None,
               n_ok=None, want_rate=False):
    """One linearisation of ``e`` into ``out``, with the excesses of the resultants
    of ``groups`` at ``rate`` taken out (none when ``rate`` is None); returns the
    least-squares rate of the linearised ramps over their first ``n_ok`` resultants
    (all when None) when ``want_rate``.  Memory: a few (nints, ny, nx) float64
    images; each excess is made when its resultant is inverted."""
    def excess(r):
        if rate is None or groups[r].size == 1:
            return None
        return _group_excess(nl, rate, groups[r],
                             None if saturated is None else saturated[:, r])

    nres = e.shape[1]
    r0 = e[:, 0].astype(np.float64)
    zero = r0
    if nres >= 2:
        # extrapolate on the linearised scale: the raw ramp is curved, so a straight
        # line through R_0, R_1 misplaces z by ~ -2 c2 q_0^2; each pass shrinks the
        # error by a factor ~ c2 q (three passes: < 1e-6 e- for H2RG-like c2)
        r1 = e[:, 1].astype(np.float64)
        d0, d1 = excess(0), excess(1)
        w = tbar[0] / (tbar[1] - tbar[0])
        for _ in range(4):
            l0 = nl.invert(np.clip(_minus(r0 - zero, d0), lo, hi))
            l1 = nl.invert(np.clip(_minus(r1 - zero, d1), lo, hi))
            zero = zero + l0 - np.maximum(l1 - l0, 0.0) * w
    if want_rate:
        # least squares of q on tbar - tbar_0 (centred: no cancellation): the sums
        # over the first n resultants of 1, t, t^2 are tables, those of q, t q images
        tr = np.asarray(tbar, dtype=np.float64) - float(tbar[0])
        s0 = np.arange(nres + 1, dtype=np.float64)
        st = np.concatenate([[0.0], np.cumsum(tr)])
        stt = np.concatenate([[0.0], np.cumsum(tr * tr)])
        sq = np.zeros(e.shape[:1] + e.shape[2:])
        stq = np.zeros_like(sq)
    for r in range(nres):
        m = np.clip(_minus(e[:, r] - zero, excess(r)), lo, hi)
        q = nl.invert(m)
        out[:, r] = q + zero
        if want_rate:
            if n_ok is not None:
                q = np.where(r < n_ok, q, 0.0)
            sq += q
            stq += tr[r] * q
    if not want_rate:
        return None
    n = nres if n_ok is None else n_ok
    s0, st, stt = s0[n], st[n], stt[n]
    den = s0 * stt - st * st
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(den > 0, (s0 * stq - st * sq) / den, 0.0)


def _group_excess(nl, rate, times, saturated):
    """``(1/n) sum_k p(f t_k) - p(f tbar)`` per pixel; 0 where a predicted charge
    leaves the monotonic range or the resultant is saturated."""
    acc = np.zeros_like(rate)
    for tk in times:
        acc += nl.apply(rate * tk)
    d = acc / times.size - nl.apply(rate * times.mean())
    ends = (rate * times.min(), rate * times.max())
    inside = ((np.minimum(*ends) > nl.q_lo) & (np.maximum(*ends) < nl.q_hi)
              & np.isfinite(d))
    if saturated is not None:
        inside &= ~saturated
    return np.where(inside, d, 0.0)
