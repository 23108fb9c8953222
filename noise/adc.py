"""The ADC: electrons to DN and back, the one conversion every path uses.

``DN = rint(e / gain)`` (round half to even) of the signal in electrons, clipped to
``[0, 2**bits - 1]``: the charge engine's reads, noise-only ramps written in DN
(:func:`noise.write_noise_fits`, ``NoiseGenerator.frames(dn_gain=...)``) and
:func:`to_dn` all go through :meth:`ADC.codes`.  A resultant that averages several
reads on board is the rounded mean of their codes (:meth:`ADC.mean_codes`).  Quantisation adds a variance of
``1/12`` DN**2 for signals spanning many DN.

The quotient is the float64 one, ``rint(float64(e) / gain)``.  When ``gain`` is a
power of two it is computed in float32 in place instead: scaling by ``2**-k`` only
changes the exponent, so the float32 quotient of a float32 value is exact and rounds
the same (two passes fewer and no float64 scratch, which the hot paths measure).
"""

import math

import numpy as np

from noise.errors import ParameterError, ParameterTypeError
from noise.validate import check_int, check_map, describe, is_sequence


__all__ = ["ADC", "averaging_noise", "to_dn", "from_dn"]


def _check_shape(name, shape):
    """``shape`` as a tuple of ints >= 0 (an image or cube shape, ``(..., ny, nx)``)."""
    if not is_sequence(shape) or isinstance(shape, np.ndarray) or not all(
            isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))
            and v >= 0 for v in shape):
        raise ParameterTypeError(
            f"{name!r} must be a tuple of integers >= 0 (an image shape), got "
            f"{describe(shape)}")
    return tuple(int(v) for v in shape)


class ADC:
    """An analogue-to-digital converter: gain (e-/DN) and resolution (bits).

    Parameters
    ----------
    gain : float or ndarray of shape (ny, nx), e-/DN
        Conversion gain, finite and > 0 (validated once, here).
    bits : int
        Resolution, 1 to 32; codes run from 0 to ``2**bits - 1``.
    shape : tuple, optional
        Image shape a gain map must match (its last two axes).

    Attributes
    ----------
    top : float
        The highest code, ``2**bits - 1``.
    dtype : numpy.dtype
        ``uint16`` for ``bits <= 16``, else ``uint32``.
    """

    def __init__(self, gain, bits=16, *, shape=None):
        self.bits = check_int("adc_bits", bits, minimum=1, maximum=32)
        if shape is not None:
            shape = _check_shape("shape", shape)
        if shape is None and np.ndim(gain):
            shape = np.shape(gain)
        self.gain = check_map("gain", gain, shape or (1, 1), minimum=0.0,
                              strict_min=True)
        self.top = float(2 ** self.bits - 1)
        self.dtype = np.dtype(np.uint16 if self.bits <= 16 else np.uint32)
        # a scalar power-of-two gain: the float32 quotient is exact
        self._exact32 = np.ndim(self.gain) == 0 and math.frexp(self.gain)[0] == 0.5

    def codes(self, e, *, scratch=None):
        """The ADC codes of ``e`` as floats: ``clip(rint(e / gain), 0, top)``.

        Parameters
        ----------
        e : ndarray, float32 or float64, e-
            Overwritten with the codes when the gain is a power of two or ``e`` is
            float64; otherwise left as it is.  ``+inf`` gives the top code, ``-inf``
            0; NaN is not checked here (see :func:`to_dn`).
        scratch : ndarray, float64, shape of ``e``, optional
            Where float32 input with any other gain is divided (allocated if absent).

        Returns
        -------
        ndarray
            ``e`` or ``scratch``, holding the codes (integral values in ``[0, top]``).
        """
        if e.dtype == np.float64 or (self._exact32 and e.dtype == np.float32):
            q = e
            if np.ndim(self.gain) or self.gain != 1.0:
                if self._exact32:
                    np.multiply(q, q.dtype.type(1.0 / self.gain), out=q)
                else:
                    np.divide(q, self.gain, out=q)
        else:
            q = scratch if scratch is not None else np.empty(e.shape, dtype=np.float64)
            np.divide(e, self.gain, out=q, dtype=np.float64)
        np.rint(q, out=q)
        np.clip(q, 0.0, self.top, out=q)
        return q

    def mean_codes(self, code_sum, count, *, out):
        """``out[:] =`` the rounded mean of ``count`` codes (on-board averaging of the
        reads of a resultant): ``clip(rint(code_sum / count), 0, top)``.

        ``code_sum`` is the exact integer (uint32) sum of the codes.  For ``count <=
        128`` the mean is taken in float32, which gives the same result as float64:
        the sum (< 128 * 65536 = 2**23) is exact in float32, the quotient is off by at
        most half an ulp (<= 2**-9 below 65536), while a quotient that is not exactly
        a half-integer is at least ``1 / (2 count) >= 2**-8`` away from one, so
        rounding (half to even, as in float64 for exact halves) cannot change.  Larger
        counts use float64.  Returns ``out``.
        """
        if count == 1:
            np.copyto(out, code_sum, casting="unsafe")
            return out
        dt = np.float32 if count <= 128 else np.float64
        m = np.divide(code_sum, dt(count), dtype=dt)
        np.rint(m, out=m)
        np.clip(m, 0, self.top, out=m)
        np.copyto(out, m, casting="unsafe")
        return out

    def to_dn(self, e, *, out=None, scratch=None):
        """Digitise ``e`` (e-) into ``out`` (a new array of :attr:`dtype` if None).

        ``e`` may be overwritten (see :meth:`codes`).  Returns ``out``.
        """
        q = self.codes(e, scratch=scratch)
        if out is None:
            out = np.empty(q.shape, dtype=self.dtype)
        np.copyto(out, q, casting="unsafe")
        return out


def averaging_noise(gain, n_reads):
    """Noise that rounding the on-board mean of ``n_reads`` digitised reads adds to a
    resultant, e- rms: ``gain * sqrt((1 - 1/n**2) / 12)`` for odd ``n``,
    ``gain * sqrt((1 + 2/n**2) / 12)`` for even ``n``.

    The mean of ``n`` integer codes is a multiple of ``1/n`` DN; for signals
    spanning many DN (a bias that differs between pixels is enough) its rounding
    error takes the ``n`` values ``k/n`` nearest 0 equally often: ``k = -(n-1)/2 ..
    (n-1)/2`` for odd ``n``, and ``-n/2 + 1 .. n/2`` for even ``n``, whose exact
    halves (``k = n/2``) round to the even code, up or down alike (mean 0).  The
    variances are the mean squares of those values.  0 for one read, whose
    quantisation, ``gain**2 / 12`` e-**2, is per read like the read noise.

    Parameters
    ----------
    gain : float, e-/DN (>= 0)
    n_reads : int or array_like of int (>= 1)
        Reads averaged into each resultant.

    Returns
    -------
    ndarray of float64, shape of ``n_reads``, e- rms
    """
    n = np.asarray(n_reads, dtype=np.float64)
    if np.any(n < 1) or float(gain) < 0:
        raise ParameterError(f"'n_reads' must be >= 1 and 'gain' >= 0, got "
                             f"{n_reads!r} and {gain!r}")
    even = (n % 2) == 0
    return float(gain) * np.sqrt(np.where(even, 1.0 + 2.0 / (n * n),
                                          1.0 - 1.0 / (n * n)) / 12.0)


def to_dn(electrons, gain, *, bits=16):
    """Digitise: ``rint(electrons / gain)`` clipped to ``[0, 2**bits - 1]``.

    Parameters
    ----------
    electrons : array_like, e-
        Signal including bias and noise.  ``+inf`` clips to the top code, ``-inf`` to 0.
    gain : float or ndarray of shape (ny, nx), e-/DN
        Conversion gain, finite and > 0 (a map needs ``electrons`` of shape
        ``(..., ny, nx)``).
    bits : int, keyword-only
        ADC resolution, 1 to 32.

    Returns
    -------
    ndarray, shape of ``electrons``, uint16 (``bits <= 16``) or uint32, DN
        Rounded half to even (``np.rint``).

    Raises
    ------
    ParameterError
        If ``gain`` is not finite and > 0, ``bits`` is out of range, or ``electrons``
        is not real or contains NaN.
    """
    try:
        e = np.array(electrons, dtype=np.float64)   # a copy: codes() works in place
    except (TypeError, ValueError) as exc:
        raise ParameterError(
            f"'electrons' must be an array of real numbers (e-), got "
            f"{type(electrons).__name__}") from exc
    if np.ndim(gain) and e.ndim < 2:
        raise ParameterError(
            f"'electrons' must have at least 2 dimensions (..., ny, nx) for a gain map, "
            f"got shape {e.shape}")
    adc = ADC(gain, bits, shape=e.shape if e.ndim >= 2 else None)
    if np.isnan(e).any():
        raise ParameterError("'electrons' contains NaN; cannot digitise")
    return adc.to_dn(e)


def from_dn(dn, gain):
    """Convert DN back to electrons: ``dn * gain``.

    Parameters
    ----------
    dn : array_like, DN
    gain : float or ndarray of shape (ny, nx), e-/DN
        Finite and > 0.

    Returns
    -------
    ndarray, shape of ``dn``, float64, e-
    """
    try:
        d = np.asarray(dn)
    except (TypeError, ValueError) as exc:          # ragged nested sequences
        raise ParameterTypeError(
            f"'dn' must be an array of real numbers (DN), got {describe(dn)}") from exc
    if d.dtype.kind not in "iuf":
        raise ParameterTypeError(
            f"'dn' must be an array of real numbers (DN), got {d.dtype} {describe(dn)}")
    g = check_map("gain", gain, d.shape if d.ndim >= 2 else (1, 1), minimum=0.0,
                  strict_min=True)
    return np.multiply(d, g, dtype=np.float64)
