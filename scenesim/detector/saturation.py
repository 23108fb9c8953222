"""Saturation: a pixel holds at most ``full_well`` electrons.

Charge beyond the full well is lost (no blooming into neighbours is modelled).  A
pixel is saturated when its charge has reached the full well, ``charge >=
full_well``.  For integer charge the full well is taken as ``floor(full_well)``
whole electrons.  It is the first effect on the charge of a read, before the
nonlinearity and IPC (DESIGN.md section 5).

Detecting saturation in recorded ramps (the pipeline's side) is
:func:`scenesim.calib.saturation.saturation_flags`.
"""

import numpy as np

from noise.validate import check_image, check_map

__all__ = ["FullWell", "apply_saturation"]


# --------------------------------------------------------------------------- saturation
class FullWell:
    """A full-well capacity, validated once and applied read by read.

    Parameters
    ----------
    full_well : float or ndarray of shape (ny, nx), e-
        Full-well capacity, finite and > 0.
    shape : tuple
        Image shape (its last two axes must match a map).

    Attributes
    ----------
    value : float or ndarray (ny, nx), float64, e-
    """

    def __init__(self, full_well, shape):
        self.value = check_map("full_well", full_well, shape, minimum=0.0,
                               strict_min=True)
        self._levels = {}

    @property
    def max(self):
        """The largest full well over the pixels, e-."""
        return float(np.max(self.value))

    def level(self, dtype, rows=None):
        """The full well in the charge type ``dtype``: whole electrons
        (``floor(full_well)``) for integer charge.  ``rows`` selects rows of a map."""
        key = np.dtype(dtype)
        lv = self._levels.get(key)
        if lv is None:
            if np.issubdtype(key, np.integer):
                lv = np.minimum(np.floor(self.value), np.iinfo(key).max).astype(key)
            else:
                lv = np.asarray(self.value, dtype=key)
            self._levels[key] = lv
        return lv if lv.ndim == 0 or rows is None else lv[rows]

    def apply(self, charge, *, rows=None, out=None):
        """Clip ``charge`` at the full well; flag the pixels that reached it.

        Parameters
        ----------
        charge : ndarray, shape (..., ny, nx), int or float, e-
            Charge accumulated since reset (rows ``rows`` of the image, if given).
        rows : slice, optional
            The rows of the image ``charge`` holds (selects the rows of a map).
        out : ndarray, optional
            Where the clipped charge goes (any float or int dtype; cast).

        Returns
        -------
        clipped : ndarray, e-
            ``minimum(charge, full_well)``: ``out``, or a new array of ``charge``'s dtype.
        saturated : ndarray of bool, shape of ``charge``
            ``charge >= full_well``.
        """
        fw = self.level(charge.dtype, rows)
        saturated = charge >= fw
        if out is None:
            return np.minimum(charge, fw), saturated
        np.minimum(charge, fw, out=out, casting="unsafe")
        return out, saturated


def apply_saturation(charge, full_well):
    """Clip charge at the full well and flag the pixels that reached it.

    Parameters
    ----------
    charge : ndarray, shape (..., ny, nx), int or float, e-
        Charge accumulated since reset.
    full_well : float or ndarray of shape (ny, nx), e-
        Full-well capacity, finite and > 0.  For integer ``charge`` it is floored to
        whole electrons.

    Returns
    -------
    clipped : ndarray, same shape and dtype as ``charge``, e-
        ``minimum(charge, full_well)`` (a new array).
    saturated : ndarray, same shape as ``charge``, bool
        True where ``charge >= full_well``.

    Raises
    ------
    ParameterError
        If ``full_well`` is not finite and > 0, or a map has the wrong shape.
    """
    q = check_image("charge", charge)
    return FullWell(full_well, q.shape).apply(q)
