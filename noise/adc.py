"""The ADC: electrons to DN and back, the one conversion every path uses.

``DN = rint(e / gain)`` (round half to even), clipped to ``[0, 2**bits - 1]``.
Quantisation adds a variance of ``1/12`` DN**2 for signals spanning many DN.
"""

import numbers

import numpy as np

from noise.errors import ParameterError
from noise.validate import check_image, check_map

__all__ = ['to_dn', 'from_dn']


# -------------------------------------------------------------------------------- ADC
def _check_gain(gain, shape):
    return check_map("gain", gain, shape, strict_min=True)


def _check_bits(bits):
    if isinstance(bits, bool) or not isinstance(bits, (numbers.Integral, np.integer)) \
            or not 1 <= bits <= 32:
        raise ParameterError(f"'adc_bits' must be an integer in [1, 32], got {bits!r}")
    return int(bits)


def to_dn(electrons, gain, *, bits=16):
    """Digitise: ``rint(electrons / gain)`` clipped to ``[0, 2**bits - 1]``.

    Parameters
    ----------
    electrons : ndarray, shape (..., ny, nx), e-
        Signal including bias and noise.  ``+inf`` clips to the top code, ``-inf`` to 0.
    gain : float or ndarray of shape (ny, nx), e-/DN
        Conversion gain, finite and > 0.
    bits : int, keyword-only
        ADC resolution, 1 to 32.

    Returns
    -------
    ndarray, shape (..., ny, nx), uint16 (``bits <= 16``) or uint32, DN
        Rounded half to even (``np.rint``).

    Raises
    ------
    ParameterError
        If ``gain`` is not finite and > 0, ``bits`` is out of range, or ``electrons``
        contains NaN.
    """
    e = check_image("electrons", electrons)
    g = _check_gain(gain, e.shape)
    nbits = _check_bits(bits)
    top = float(2 ** nbits - 1)
    with np.errstate(invalid="ignore"):
        dn = np.divide(e, g, dtype=np.float64)
    np.rint(dn, out=dn)
    if np.isnan(dn).any():
        raise ParameterError("'electrons' contains NaN; cannot digitise")
    np.clip(dn, 0.0, top, out=dn)
    return dn.astype(np.uint16 if nbits <= 16 else np.uint32)


def from_dn(dn, gain):
    """Convert DN back to electrons: ``dn * gain``.

    Parameters
    ----------
    dn : ndarray, shape (..., ny, nx), DN
    gain : float or ndarray of shape (ny, nx), e-/DN
        Finite and > 0.

    Returns
    -------
    ndarray, shape (..., ny, nx), float64, e-
    """
    d = check_image("dn", dn)
    g = _check_gain(gain, d.shape)
    return np.multiply(d, g, dtype=np.float64)
