"""Picture-frame (PCA-zero) template.

NG modulates the zeroth principal component of NIRSpec darks, PCA-zero, by a 1/f series
sampled once per row (Rauscher 2015, Sec. 4.3), and multiplies the same image by
``bias_amp`` to mimic the fixed bias pattern of single reads.  The NIRSpec PCA-zero file
is an instrument file we do not have, so the default here is a **synthetic template**:
a smooth pattern that is strongest near the array edges (a picture frame), with a gentle
large-scale gradient, defined in full-array coordinates (subarrays see their part of it),
normalised to zero median and unit robust sigma (1.4826 * MAD).  It is a deterministic
function of the array size: no file, no randomness.  A user FITS file can replace it; it
is normalised the same way.
"""

import functools
import os

import numpy as np

from noise.clock import Detector
from noise.errors import FileFormatError
from noise.fitsio import open_fits
from noise.validate import check_instance, check_int, check_path

__all__ = ["synthetic_template", "load_template", "template_for", "template_range"]


def _normalise(img):
    img = np.asarray(img, dtype=np.float64)
    med = np.median(img)
    mad = np.median(np.abs(img - med)) * 1.4826
    if not np.isfinite(mad) or mad <= 0:
        mad = np.std(img)
    if not np.isfinite(mad) or mad <= 0:
        return np.zeros_like(img)
    return (img - med) / mad


def _profiles(naxis2, naxis1):
    """Row and column factors of the synthetic template (float64).

    The edge distance is ``d = min(dy, dx)`` and ``exp`` is decreasing, so
    ``exp(-d / w) = max(exp(-dy / w), exp(-dx / w))``: the image is
    ``max(ey[:, None], ex[None, :]) + g[:, None]``, a broadcast, no 2-D index arrays.
    """
    w = max(min(naxis1, naxis2) / 24.0, 1.0)
    y = np.arange(naxis2, dtype=float)
    x = np.arange(naxis1, dtype=float)
    ey = np.exp(-np.minimum(y, naxis2 - 1 - y) / w)
    ex = np.exp(-np.minimum(x, naxis1 - 1 - x) / w)
    g = 0.1 * (y / max(naxis2 - 1, 1))
    return ey, ex, g


def _count_le(ey, ex_sorted, g, v, strict=False):
    """Number of pixels of ``max(ey, ex) + g`` that are <= ``v`` (< with ``strict``).

    Row ``y`` holds values <= v where both ``ey[y]`` and ``ex`` are <= ``v - g[y]``:
    ``ex_sorted`` (ascending) gives the column count by binary search, O(ny log nx).
    """
    lim = v - g
    side = "left" if strict else "right"
    ok = (ey < lim) if strict else (ey <= lim)
    cols = np.searchsorted(ex_sorted, lim, side=side)
    return int(np.sum(np.where(ok, cols, 0)))


def _order_stat(count_le, k, lo, hi):
    """Smallest ``v`` in ``[lo, hi]`` with ``count_le(v) >= k + 1`` (bisection to the
    last float64 bit)."""
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if mid <= lo or mid >= hi:
            break
        if count_le(mid) >= k + 1:
            hi = mid
        else:
            lo = mid
    return hi


@functools.lru_cache(maxsize=8)
def _synthetic_stats(naxis2, naxis1):
    """Median and robust sigma (1.4826 MAD) of the raw synthetic template.

    Computed from the separable form by counting (:func:`_count_le`) and bisection,
    without building the image: O(ny log nx) per step instead of sorting ny * nx values
    (1.6 s for 4096^2).  Exact to float64 rounding.
    """
    ey, ex, g = _profiles(naxis2, naxis1)
    exs = np.sort(ex)
    n = naxis1 * naxis2
    lo, hi = float(min(ey.min(), ex.min()) - 1.0), float(max(ey.max(), ex.max()) + 1.0)
    le = functools.partial(_count_le, ey, exs, g)

    def median(count, a, b):
        if n % 2:
            return _order_stat(count, n // 2, a, b)
        return 0.5 * (_order_stat(count, n // 2 - 1, a, b) + _order_stat(count, n // 2, a, b))

    med = median(le, lo, hi)
    # |img - med| <= t  <=>  med - t <= img <= med + t
    mad = median(lambda t: le(med + t) - le(med - t, strict=True), 0.0, hi - lo)
    sig = mad * 1.4826
    if not sig > 0:            # degenerate (tiny) arrays: fall back as _normalise does
        sig = float(np.std(np.maximum(ey[:, None], ex[None, :]) + g[:, None]))
    return med, sig


def _synthetic_region(naxis2, naxis1, y0, y1, x0, x1):
    """Rows ``y0:y1`` and columns ``x0:x1`` of :func:`synthetic_template` (float64)."""
    med, sig = _synthetic_stats(naxis2, naxis1)
    ey, ex, g = _profiles(naxis2, naxis1)
    img = np.maximum(ey[y0:y1, None], ex[None, x0:x1])
    img += g[y0:y1, None]
    if not np.isfinite(sig) or sig <= 0:
        return np.zeros_like(img)
    img -= med
    img /= sig
    return img


def _synthetic_region32(naxis2, naxis1, y0, y1, x0, x1, rows=256):
    """:func:`_synthetic_region` cast to float32, made in blocks of ``rows`` rows (the
    same values without a full-size float64 temporary: 134 MB at 4096^2)."""
    out = np.empty((y1 - y0, x1 - x0), dtype=np.float32)
    for a in range(y0, y1, rows):
        b = min(a + rows, y1)
        out[a - y0:b - y0] = _synthetic_region(naxis2, naxis1, a, b, x0, x1)
    return out


def synthetic_template(naxis2, naxis1):
    """Synthetic picture-frame template of the full array, shape (naxis2, naxis1).

    ``exp(-d / w)`` with ``d`` the distance to the nearest edge and ``w = min(shape)/24``,
    plus a 10 % linear gradient along rows, normalised to zero median and unit robust
    sigma (the statistics are computed without building the image, see
    :func:`_synthetic_stats`; cached per array size).
    """
    naxis2 = check_int("naxis2", naxis2, minimum=1)
    naxis1 = check_int("naxis1", naxis1, minimum=1)
    return _synthetic_region(naxis2, naxis1, 0, naxis2, 0, naxis1)


def load_template(path, detector):
    """Read a user template FITS (primary or first image HDU) for ``detector``.

    The image may be the full array or exactly the read-out shape.  It is normalised
    to zero median and unit robust sigma, a full-array image before it is cut to the
    subarray, so that a window sees the same values as the full frame there (a
    probe found a window's pattern normalised on its own: 1998 e- apart at
    ``bias_amp`` 500); an image of the read-out shape only is normalised as given.
    """
    if not os.path.isfile(path):
        raise FileFormatError(f"'pca0_file': {path!r} does not exist")
    with open_fits(path, "'pca0_file'") as hdul:
        data = next((h.data for h in hdul if h.data is not None and h.data.ndim == 2),
                    None)
        if data is None:
            raise FileFormatError(f"'pca0_file': {path!r} has no 2-D image HDU")
        data = np.array(data, dtype=np.float64)
    bad = ~np.isfinite(data)
    if bad.any():            # a NaN made the normalisation all zeros: no pattern
        y, x = (int(v) for v in np.argwhere(bad)[0])
        raise FileFormatError(
            f"'pca0_file': {path!r} has {int(bad.sum())} NaN or inf values (the first "
            f"at row {y}, column {x}); a template must be finite everywhere (replace "
            f"bad pixels, e.g. by their neighbours' median)")
    if data.shape == (detector.naxis2, detector.naxis1):
        return _normalise(data)[detector.y0:detector.y0 + detector.ny,
                                detector.x0:detector.x0 + detector.nx]
    if data.shape != detector.shape:
        raise FileFormatError(
            f"'pca0_file': {path!r} has shape {data.shape}; expected the full array "
            f"{(detector.naxis2, detector.naxis1)} or the read-out shape {detector.shape}")
    return _normalise(data)


def template_for(detector, path=None):
    """Template for the read-out image of ``detector``, shape (ny, nx), float32.

    ``path``: a FITS template (:func:`load_template`), or None (or ``""``) for the
    synthetic one.
    """
    check_instance("detector", detector, Detector, "a noise.Detector")
    if path is not None and not (isinstance(path, str) and not path):
        return load_template(check_path("pca0_file", path), detector).astype(np.float32)
    return _synthetic_region32(detector.naxis2, detector.naxis1,
                               detector.y0, detector.y0 + detector.ny,
                               detector.x0, detector.x0 + detector.nx)


def template_range(detector, path=None):
    """``(least, largest)`` value of :func:`template_for` ``(detector, path)``.

    For the synthetic template, from its separable form without building the image
    (O(ny + nx): a scene's checks may not allocate an array its size budget has not
    yet allowed): over rows ``Y`` and columns ``X`` of ``max(ey, ex) + g``, the
    largest is ``max(max_Y (ey + g), max_X ex + max_Y g)`` and the least ``min_Y
    (max(ey, min_X ex) + g)``, then normalised as the image is (float32, as
    :func:`template_for` gives it).  A template file is read.
    """
    check_instance("detector", detector, Detector, "a noise.Detector")
    if path is not None and not (isinstance(path, str) and not path):
        t = template_for(detector, path)
        return float(t.min()), float(t.max())
    med, sig = _synthetic_stats(detector.naxis2, detector.naxis1)
    if not np.isfinite(sig) or sig <= 0:
        return 0.0, 0.0
    ey, ex, g = _profiles(detector.naxis2, detector.naxis1)
    ys = slice(detector.y0, detector.y0 + detector.ny)
    xs = slice(detector.x0, detector.x0 + detector.nx)
    ey, ex, g = ey[ys], ex[xs], g[ys]
    hi = max(float((ey + g).max()), float(ex.max() + g.max()))
    lo = float((np.maximum(ey, ex.min()) + g).min())
    return tuple(float(np.float32((v - med) / sig)) for v in (lo, hi))
