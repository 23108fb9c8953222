"""Piecewise-linear light curves with exact interval integrals.

A source's rate is ``F(t) = F0 * s(t)`` where ``F0`` (e-/s) is its catalogue flux and
``s(t) >= 0`` a dimensionless relative flux, ``t`` in seconds from the exposure start.
The charge engine needs, for every pixel and read interval ``[t1, t2]``, the mean
number of electrons ``F0 * integral_{t1}^{t2} s(t) dt`` (DESIGN.md section 5), so the
one operation that matters is an *exact* and *vectorised* interval integral.

Model
-----
``s`` is piecewise linear through the nodes ``(t_k, s_k)`` and constant beyond the
ends (``s_0`` before ``t_0``, ``s_last`` after ``t_last``).  Node times are
non-decreasing; two equal consecutive times ``t_k = t_{k+1}`` mark a discontinuity
(a step: ``s`` jumps from ``s_k`` to ``s_{k+1}``; the curve is right-continuous, so at
``t_k`` itself it takes ``s_{k+1}``).  Three equal times in a row are rejected (the
middle value would be meaningless).

Integral
--------
With the antiderivative ``A(t) = integral_{t_0}^{t} s``, precomputed at the nodes as
``C_k = A(t_k)`` (trapezoids; a zero-width step segment adds nothing), for ``t`` in the
segment that starts at node ``k``::

    A(t) = C_k + s_k (t - t_k) + 1/2 m_k (t - t_k)**2,   m_k = (s_{k+1} - s_k)/(t_{k+1} - t_k)

with ``m = 0`` and the end value on the two unbounded end segments.  The segment is
found with :func:`numpy.searchsorted` (``side='right'``, so a zero-width step segment
is never selected), and ``integral(t1, t2) = (C_{k2} - C_{k1}) + (a_2 - a_1)`` with
``a`` the local part above.  When both ends fall in one segment the integral is
computed as ``(t2 - t1) * (s_k + m_k (t1 + t2 - 2 t_k) / 2)`` instead, so a short
interval far from the node keeps full relative precision.  The result is exact up to
float64 round-off; it is signed (``integral(t2, t1) = -integral(t1, t2)``).

Constructors
------------
:meth:`LightCurve.step` (exact step), :meth:`LightCurve.transit` (trapezoid; exact),
:meth:`LightCurve.flare` (linear rise, exponential decay sampled on a grid; its error
bound is derived in the method's notes) and :meth:`LightCurve.from_file`.
"""

import math
from dataclasses import dataclass, field

import numpy as np
from astropy import units as u

from noise.errors import FileFormatError, ParameterError, ParameterTypeError
from noise.validate import check_float, describe

from scenesim.sky.tables import column_values, find_columns, read_table

__all__ = ["LightCurve"]

#: Largest |time| of a light curve's nodes, s from the exposure start (about 30 000
#: years: far beyond any exposure, and far from float overflow in the integrals).
MAX_TIME = 1e12


def _seconds(name, value):
    """``value`` as a float64 array of times (s), or a ParameterTypeError."""
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ParameterTypeError(
            f"{name!r} must be a time or an array of times (s), got {describe(value)}"
        ) from exc


@dataclass(frozen=True, eq=False)
class LightCurve:
    """Piecewise-linear relative flux versus time, constant beyond its ends.

    Parameters
    ----------
    time : array_like, shape (n,), float, seconds
        Node times from the exposure start; non-decreasing, finite, ``n >= 1``.  Two
        equal consecutive times make a step (see module notes).
    flux : array_like, shape (n,), float, dimensionless
        Relative flux at the nodes (finite, >= 0); multiplies the source's rate.

    Notes
    -----
    Both arrays are stored as read-only float64 copies; equality and hashing use
    their bytes, so the object is a hashable, picklable value.
    """

    time: np.ndarray = field(repr=False)
    flux: np.ndarray = field(repr=False)

    def __post_init__(self):
        try:
            t = np.array(self.time, dtype=np.float64, copy=True).reshape(-1) \
                if np.ndim(self.time) <= 1 else None
            f = np.array(self.flux, dtype=np.float64, copy=True).reshape(-1) \
                if np.ndim(self.flux) <= 1 else None
        except (TypeError, ValueError) as exc:
            raise ParameterError("'time' and 'flux' must be 1-D arrays of numbers") from exc
        if t is None or f is None:
            raise ParameterError(
                f"'time' and 'flux' must be 1-D, got shapes {np.shape(self.time)} and "
                f"{np.shape(self.flux)}")
        if t.size < 1 or t.size != f.size:
            raise ParameterError(
                f"'time' and 'flux' must have the same length >= 1, got {t.size} and "
                f"{f.size}")
        if not np.all(np.isfinite(t)):
            raise ParameterError("'time' must be finite (seconds), found NaN or inf")
        if np.any(np.abs(t) > MAX_TIME):          # (their differences must not overflow)
            bad = int(np.flatnonzero(np.abs(t) > MAX_TIME)[0])
            raise ParameterError(
                f"'time' must lie within +-{MAX_TIME:g} s of the exposure start, got "
                f"time[{bad}]={float(t[bad])!r}")
        if not np.all(np.isfinite(f)) or np.any(f < 0):
            bad = np.flatnonzero(~np.isfinite(f) | (f < 0))[0]
            raise ParameterError(
                f"'flux' must be finite and >= 0 (relative flux), got flux[{bad}]="
                f"{float(f[bad])!r}")
        dt = np.diff(t)
        if np.any(dt < 0):
            bad = int(np.flatnonzero(dt < 0)[0])
            raise ParameterError(
                f"'time' must be non-decreasing, got time[{bad}]={float(t[bad])!r} > "
                f"time[{bad + 1}]={float(t[bad + 1])!r}")
        if np.any((dt[:-1] == 0) & (dt[1:] == 0)):
            bad = int(np.flatnonzero((dt[:-1] == 0) & (dt[1:] == 0))[0])
            raise ParameterError(
                f"'time' has three equal values in a row at index {bad} "
                f"({t[bad]!r} s); a step needs exactly two")
        for arr in (t, f):
            arr.setflags(write=False)
        object.__setattr__(self, "time", t)
        object.__setattr__(self, "flux", f)
        # Extended segment tables, indexed by k + 1 with k = searchsorted(..) - 1 in
        # [-1, n-1]: base value C, anchor time, anchor value, slope.
        width = np.diff(t)
        slope = np.divide(np.diff(f), width, out=np.zeros(width.size), where=width > 0)
        cum = np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * width)])
        object.__setattr__(self, "_base", np.concatenate([[0.0], cum]))
        object.__setattr__(self, "_t_anchor", np.concatenate([[t[0]], t]))
        object.__setattr__(self, "_f_anchor", np.concatenate([[f[0]], f]))
        object.__setattr__(self, "_slope", np.concatenate([[0.0], slope, [0.0]]))

    # value semantics -------------------------------------------------------
    def _key(self):
        return (self.time.tobytes(), self.flux.tobytes())

    def __eq__(self, other):
        if not isinstance(other, LightCurve):
            return NotImplemented
        return self._key() == other._key()

    def __hash__(self):
        return hash(self._key())

    def __reduce__(self):
        return (type(self), (np.array(self.time), np.array(self.flux)))

    def __repr__(self):
        return (f"LightCurve(<{self.time.size} nodes, t={self.time[0]:.6g}..."
                f"{self.time[-1]:.6g} s, flux={self.flux.min():.6g}..."
                f"{self.flux.max():.6g}>)")

    # evaluation ------------------------------------------------------------
    def _local(self, t):
        k = np.searchsorted(self.time, t, side="right")     # = segment index + 1
        d = t - self._t_anchor[k]
        return k, d, d * (self._f_anchor[k] + 0.5 * self._slope[k] * d)

    def __call__(self, t):
        """Relative flux at time(s) ``t`` (s); right-continuous at steps.

        Parameters
        ----------
        t : float or array_like, seconds

        Returns
        -------
        float or ndarray (shape of ``t``), float64
        """
        t = _seconds("t", t)
        k = np.searchsorted(self.time, t, side="right")
        out = self._f_anchor[k] + self._slope[k] * (t - self._t_anchor[k])
        return out[()] if out.ndim == 0 else out

    def integral(self, t1, t2):
        """Exact integral of the relative flux over ``[t1, t2]``, seconds.

        Parameters
        ----------
        t1, t2 : float or array_like, seconds
            Interval ends, any broadcastable shapes.  Finite.

        Returns
        -------
        float or ndarray (broadcast shape), float64, seconds
            Signed: negative when ``t2 < t1``.
        """
        t1 = _seconds("t1", t1)
        t2 = _seconds("t2", t2)
        if not (np.all(np.isfinite(t1)) and np.all(np.isfinite(t2))):
            raise ParameterError("'t1' and 't2' must be finite (seconds)")
        try:
            t1, t2 = np.broadcast_arrays(t1, t2)
        except ValueError as exc:
            raise ParameterError(
                f"'t1' and 't2' must have broadcastable shapes, got {t1.shape} and "
                f"{t2.shape}") from exc
        k1, d1, a1 = self._local(t1)
        k2, d2, a2 = self._local(t2)
        out = (self._base[k2] - self._base[k1]) + (a2 - a1)
        # Same segment: width times the mean value, free of the anchor offset.
        same = (t2 - t1) * (self._f_anchor[k1] + 0.5 * self._slope[k1] * (d1 + d2))
        out = np.where(k1 == k2, same, out)
        return out[()] if out.ndim == 0 else out

    def mean(self, t1, t2):
        """Mean relative flux over ``[t1, t2]``; the value at ``t1`` where ``t1 == t2``.

        Parameters
        ----------
        t1, t2 : float or array_like, seconds (broadcastable)

        Returns
        -------
        float or ndarray, float64, dimensionless
        """
        t1 = _seconds("t1", t1)
        t2 = _seconds("t2", t2)
        integ = np.asarray(self.integral(t1, t2))
        width = np.broadcast_to(t2 - t1, integ.shape)
        safe = np.where(width == 0, 1.0, width)
        out = np.where(width == 0, np.broadcast_to(self(t1), integ.shape), integ / safe)
        return out[()] if out.ndim == 0 else out

    # constructors ----------------------------------------------------------
    @classmethod
    def step(cls, t_on, *, after, before=1.0):
        """A source that switches from ``before`` to ``after`` at ``t_on`` (exact step).

        Parameters
        ----------
        t_on : float, seconds
            Switch time; from ``t_on`` on the flux is ``after`` (right-continuous).
        after : float, relative flux (>= 0), keyword-only
            Relative flux from ``t_on`` on.
        before : float, relative flux (>= 0), keyword-only
            Relative flux before ``t_on``; default 1 (the source at its catalogue flux),
            the same default as the scene's ``step`` light curve.
        """
        t_on = check_float("t_on", t_on)
        before = check_float("before", before, minimum=0.0)
        after = check_float("after", after, minimum=0.0)
        return cls([t_on, t_on], [before, after])

    @classmethod
    def transit(cls, t0, duration, depth, ingress):
        """Trapezoidal transit: 1 outside, ``1 - depth`` at the bottom.

        Parameters
        ----------
        t0 : float, seconds
            Mid-transit time.
        duration : float, seconds
            First to fourth contact (> 0).
        depth : float
            Fractional depth, ``0 <= depth <= 1``.
        ingress : float, seconds
            Ingress (= egress) duration, ``0 <= ingress <= duration / 2``; 0 gives a
            box (exact steps), ``duration / 2`` a triangle.

        Notes
        -----
        Area removed: ``depth * (duration - ingress)`` seconds.
        """
        t0 = check_float("t0", t0)
        duration = check_float("duration", duration, minimum=0.0, strict_min=True)
        depth = check_float("depth", depth, minimum=0.0)
        if depth > 1:
            raise ParameterError(f"'depth' must be <= 1, got {depth!r}")
        ingress = check_float("ingress", ingress, minimum=0.0)
        if ingress > duration / 2:
            raise ParameterError(
                f"'ingress' must be <= duration/2 = {duration / 2!r} s, got {ingress!r}")
        h = duration / 2
        low = 1.0 - depth
        t = [t0 - h, t0 - h + ingress, t0 + h - ingress, t0 + h]
        f = [1.0, low, low, 1.0]
        if ingress == h:                        # triangle: merge the two bottom nodes
            t, f = [t[0], t0, t[3]], [1.0, low, 1.0]
        return cls(t, f)

    @classmethod
    def flare(cls, t0, amplitude, rise, decay, *, tol=1e-4):
        """Flare: linear rise to ``1 + amplitude`` at ``t0``, then exponential decay.

        ``s(t) = 1`` before ``t0 - rise``; linear up to ``1 + amplitude`` at ``t0``
        (exact; ``rise = 0`` gives a step); ``1 + amplitude * exp(-(t - t0)/decay)``
        after ``t0``.

        Parameters
        ----------
        t0 : float, seconds
            Time of the peak.
        amplitude : float
            Peak excess over quiescence, relative (>= 0).
        rise : float, seconds
            Duration of the linear rise, from quiescence at ``t0 - rise`` to the peak
            (>= 0; 0 is a step).  A duration, not an e-folding time: white-light flare
            templates rise in minutes, impulsively and close to linearly (Davenport et
            al. 2014, ApJ 797, 122 fit a polynomial), and a linear rise keeps the
            integral exact.
        decay : float, seconds
            e-folding decay time (> 0).
        tol : float
            Accuracy goal relative to ``amplitude`` (0 < tol <= 0.01).

        Notes
        -----
        Pointwise, ``|s(t) - s_exact(t)| <= tol * A`` for ``t >= t0`` and
        ``s = s_exact`` before (``tests/sky/test_lightcurve.py`` checks the values and
        the interval integrals against this closed form).  The decay is sampled on a
        uniform grid of step ``h = decay * sqrt(8 tol)``:
        linear interpolation of ``A exp(-u/decay)`` errs by at most
        ``h**2 / 8 * max|f''| = tol * A`` pointwise, always above the curve (it is
        convex).  The grid stops at ``u_end = decay * ln(1/tol)``, where the excess
        is ``tol * A``, with a last node returning to exactly 1 one step later, so the
        light curve is 1 afterwards.  The integral over all time then exceeds the
        exact ``A * (rise / 2 + decay)`` by the interpolation excess (at most
        ``tol * A * u_end``) and differs by the truncated tail ``tol * A * decay`` at
        most: ``|error| <= tol * A * decay * (1 + ln(1/tol))``.
        """
        t0 = check_float("t0", t0)
        amplitude = check_float("amplitude", amplitude, minimum=0.0)
        rise = check_float("rise", rise, minimum=0.0)
        decay = check_float("decay", decay, minimum=0.0, strict_min=True)
        tol = check_float("tol", tol, minimum=0.0, strict_min=True)
        if tol > 0.01:
            raise ParameterError(f"'tol' must be <= 0.01, got {tol!r}")
        h = decay * math.sqrt(8.0 * tol)
        u_end = decay * math.log(1.0 / tol)
        nstep = int(math.ceil(u_end / h))
        u = np.arange(nstep + 1) * (u_end / nstep)
        t = np.concatenate([[t0 - rise], t0 + u, [t0 + u_end + u_end / nstep]])
        f = np.concatenate([[1.0], 1.0 + amplitude * np.exp(-u / decay), [1.0]])
        return cls(t, f)

    @classmethod
    def from_file(cls, path):
        """Read a light curve from an ECSV or FITS table with columns time, flux.

        The one reader of light-curve files: a scene's ``file`` light curve goes
        through it.  Column names are case-insensitive.  A ``time`` column with a unit
        is converted to seconds (``h``, ``d``, ``min``, ...); without a unit it is taken
        as seconds.  ``flux`` is the relative factor on the star's flux: without a unit,
        or with a dimensionless one (``%`` is converted: 99 % is 0.99); any other unit
        (``mag``, ``Jy``, ``electron / s``) is refused, since it is no factor (before,
        it was ignored: a dip of 0.01 mag became a factor near 0).  The samples are the
        nodes of the piecewise-linear curve (two equal consecutive times make a step).

        Raises
        ------
        FileFormatError
            Missing/unreadable file, missing column, a time unit that is not a time,
            or a flux unit that is not dimensionless.
        ParameterError
            Invalid values (see :class:`LightCurve`).
        """
        where = f"light-curve file {str(path)!r}"
        table = read_table(path, what="light-curve file")
        names = find_columns(table, ("time", "flux"), where=where)
        time = column_values(table, names["time"], u.s, where=where)
        unit = getattr(table[names["flux"]], "unit", None)
        if unit is not None and not unit.is_equivalent(u.dimensionless_unscaled):
            raise FileFormatError(
                f"{where}: column {names['flux']!r} has unit {unit.to_string()!r}; a "
                f"light curve's flux is a relative factor on the star's flux: give it "
                f"without a unit or dimensionless (e.g. '%'), not a magnitude or a "
                f"flux (for magnitudes m relative to the star's, write 10**(-0.4 m))")
        flux = column_values(table, names["flux"], u.dimensionless_unscaled,
                             where=where)
        return cls(time, flux)
