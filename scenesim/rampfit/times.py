"""Read times handed to the ramp fitter: validation and the global-reset shift.

A fit needs, for every resultant, the times of the reads it averages, in seconds
from the pixel's reset (``Readout.read_times``).  They are either 1-D arrays, the
same for every pixel (rolling reset; uneven Roman-style tables and gaps allowed), or
``(N_i, ny, nx)`` arrays (global reset).  A global reset shifts all read times of a
pixel by the same amount (its clock offset), and the covariance of the rate
estimates involves only differences of times (:mod:`scenesim.rampfit.covariance`),
so the fitter works with the times of pixel ``[0, 0]`` and the per-pixel shift
matters only for a single-resultant slope (``R_0 / tbar_0``).

Rules: each resultant has >= 1 read; times are finite, >= 0 s and at most
:data:`MAX_READ_TIME` (the fit's ``1 / dt^2`` stays a normal float32), strictly
increasing within a resultant; resultants do not overlap in time; per-pixel times
differ between pixels only by a common shift.
"""

import numpy as np

from noise.errors import ParameterError
from noise.validate import check_int, describe, is_sequence

__all__ = ["check_read_times", "MAX_READ_TIME", "shortest_spacing"]

#: Latest read time (s from reset) a fit takes: 1e9 s (32 years); ``1 / dt^2`` of a
#: spacing that long, 1e-18, is still far from float32's underflow.
MAX_READ_TIME = 1e9


def shortest_spacing(times):
    """The shortest interval (s) between two consecutive reads of ``times`` (checked
    1-D read times, one array per resultant), or ``inf`` for a single read."""
    flat = np.concatenate(times)
    return float(np.diff(flat).min()) if flat.size > 1 else float("inf")


def check_read_times(read_times, nres=None, image_shape=None):
    """Validate ``read_times``; return the times of one pixel and the pixel shifts.

    Parameters
    ----------
    read_times : sequence of array_like, s from reset
        One entry per resultant: ``(N_i,)`` (every pixel alike) or
        ``(N_i,) + image_shape`` (global reset).
    nres : int, optional
        Required number of resultants.
    image_shape : (ny, nx), optional
        Image shape of per-pixel entries; ``None`` (theory functions) takes it from
        the first 3-D entry.

    Returns
    -------
    times : list of ndarray, each (N_i,) float64, s
        Read times of pixel ``[0, 0]`` (of every pixel for 1-D input).
    shift : ndarray (ny, nx) float64 or None
        Per-pixel shift of the read times relative to pixel ``[0, 0]``; ``None``
        when all entries are 1-D.

    Raises
    ------
    noise.errors.ParameterError
        Naming the entry and the rule it breaks.
    """
    if not is_sequence(read_times) or len(read_times) == 0 or isinstance(read_times, dict):
        raise ParameterError(
            f"'read_times' must be a non-empty sequence of 1-D arrays of read times "
            f"(s from reset), one per resultant, got {describe(read_times)}")
    if nres is not None:
        nres = check_int("nres", nres, minimum=1)
    if nres is not None and len(read_times) != nres:
        raise ParameterError(
            f"'read_times' has {len(read_times)} entries but 'resultants' has {nres} "
            f"resultants; one array of read times per resultant is required")
    if image_shape is None:        # theory functions: accept per-pixel times too
        for t in read_times:
            shp = np.shape(t)
            if len(shp) == 3:
                image_shape = shp[1:]
                break
    arrays = [_entry(r, t, image_shape) for r, t in enumerate(read_times)]
    shift = None
    if any(a.ndim == 3 for a in arrays):
        arrays, shift = _common_shift(arrays, image_shape)
    for r, a in enumerate(arrays):
        if np.any(np.diff(a) <= 0):
            raise ParameterError(
                f"'read_times'[{r}] must be strictly increasing, got {describe(a)}")
        if r > 0 and a[0] <= arrays[r - 1][-1]:
            raise ParameterError(
                f"'read_times': resultant {r} starts at {a[0]} s, not after the last "
                f"read of resultant {r - 1} at {arrays[r - 1][-1]} s; resultants must "
                f"not overlap in time")
    return arrays, shift


def _entry(r, t, image_shape):
    """Entry ``r`` as a float64 array of shape (N,) or (N,) + image_shape."""
    if np.iscomplexobj(t):                 # (float() would drop the imaginary part)
        raise ParameterError(
            f"'read_times'[{r}] must be real read times (s), got complex values")
    try:
        a = np.asarray(t, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ParameterError(
            f"'read_times'[{r}] must be an array of read times (s), got {describe(t)}"
        ) from exc
    if a.ndim == 0:
        a = a.reshape(1)
    if a.ndim != 1 and not (image_shape is not None and a.ndim == 3
                            and a.shape[1:] == tuple(image_shape)):
        allowed = "(n_reads,)" + (f" or (n_reads, {image_shape[0]}, "
                                  f"{image_shape[1]})" if image_shape else "")
        raise ParameterError(
            f"'read_times'[{r}] must have shape {allowed}, got shape {a.shape}")
    if a.shape[0] == 0:
        raise ParameterError(f"'read_times'[{r}] is empty; each resultant needs "
                             f">= 1 read")
    if not np.all(np.isfinite(a)) or np.any(a < 0) or np.any(a > MAX_READ_TIME):
        raise ParameterError(
            f"'read_times'[{r}] must be finite, >= 0 s and <= {MAX_READ_TIME:g} s (from "
            f"the reset), got {describe(t)}")
    return a


def _common_shift(arrays, image_shape):
    """Per-pixel entries -> (times of pixel [0, 0], shift of every pixel)."""
    arrays = [a if a.ndim == 3 else np.broadcast_to(
        a[:, None, None], (a.shape[0],) + tuple(image_shape)) for a in arrays]
    off = arrays[0][0] - arrays[0][0, 0, 0]
    base = []
    for r, a in enumerate(arrays):
        rel = a - off
        if np.ptp(rel, axis=(1, 2)).max() > 1e-9 * max(1.0, float(np.abs(a).max())):
            raise ParameterError(
                f"'read_times'[{r}]: per-pixel read times must differ between "
                f"pixels only by a common shift (rolling or global reset)")
        base.append(np.array(rel[:, 0, 0]))
    return base, off
