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

__all__ = ['apply_saturation']


# --------------------------------------------------------------------------- saturation
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
    fw = check_map("full_well", full_well, q.shape, strict_min=True)
    if np.issubdtype(q.dtype, np.integer):
        info = np.iinfo(q.dtype)
        fw = np.minimum(np.floor(fw), info.max).astype(q.dtype)
    else:
        fw = np.asarray(fw, dtype=q.dtype)
    saturated = q >= fw
    clipped = np.minimum(q, fw)
    return clipped, saturated
