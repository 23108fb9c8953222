"""Flat field: relative quantum efficiency.

A quantum-efficiency flat scales the photon rate a pixel converts into charge, so it
acts on the **rates** (e-/s) of light from the sky before the Poisson draws: the
collected charge stays Poisson with mean ``flat * rate * t`` (variance equal to the
mean).  Scaling integer charge afterwards would give non-integer charge with
variance ``flat**2`` times the mean instead.  Dark current is not light and is not
flat-fielded.
"""

from noise.validate import check_image, check_map

__all__ = ['apply_flat']


# ------------------------------------------------------------------------------- flat
def apply_flat(rate, flat):
    """Scale photo-electron rates by a quantum-efficiency (flat-field) map.

    Applied to the **rates** of light (e-/s) before the Poisson draws
    (:func:`scenesim.sky.rates.scene_rates`), so the collected charge stays Poisson
    with variance equal to its mean; scaling integer charge afterwards would give
    non-integer charge whose variance is ``flat**2`` times the mean instead.

    Parameters
    ----------
    rate : ndarray, shape (..., ny, nx), e-/s
    flat : float or ndarray of shape (ny, nx)
        Relative QE, finite and >= 0 (1 = nominal).

    Returns
    -------
    ndarray, shape (..., ny, nx), float
        ``rate * flat`` (a new array).

    Raises
    ------
    ParameterError
        If ``flat`` is negative or not finite, or a map has the wrong shape.
    """
    q = check_image("rate", rate)
    f = check_map("flat", flat, q.shape)
    return q * f
