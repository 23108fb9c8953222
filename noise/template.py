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

import os

import numpy as np

from .errors import FileFormatError

__all__ = ["synthetic_template", "load_template", "template_for"]


def _normalise(img):
    img = np.asarray(img, dtype=np.float64)
    med = np.median(img)
    mad = np.median(np.abs(img - med)) * 1.4826
    if not np.isfinite(mad) or mad <= 0:
        mad = np.std(img)
    if not np.isfinite(mad) or mad <= 0:
        return np.zeros_like(img)
    return (img - med) / mad


def synthetic_template(naxis2, naxis1):
    """Synthetic picture-frame template of the full array, shape (naxis2, naxis1).

    ``exp(-d / w)`` with ``d`` the distance to the nearest edge and ``w = min(shape)/24``,
    plus a 10 % linear gradient along rows, normalised to unit robust sigma.
    """
    y = np.arange(naxis2, dtype=float)[:, None]
    x = np.arange(naxis1, dtype=float)[None, :]
    d = np.minimum(np.minimum(y, naxis2 - 1 - y), np.minimum(x, naxis1 - 1 - x))
    w = max(min(naxis1, naxis2) / 24.0, 1.0)
    img = np.exp(-d / w) + 0.1 * (y / max(naxis2 - 1, 1))
    return _normalise(img)


def load_template(path, detector):
    """Read a user template FITS (primary or first image HDU) for ``detector``.

    The image may be the full array (it is then cut to the subarray) or exactly the
    read-out shape.  It is normalised to zero median and unit robust sigma.
    """
    from astropy.io import fits

    if not os.path.isfile(path):
        raise FileFormatError(f"'pca0_file': {path!r} does not exist")
    with fits.open(path) as hdul:
        data = next((h.data for h in hdul if h.data is not None and h.data.ndim == 2),
                    None)
        if data is None:
            raise FileFormatError(f"'pca0_file': {path!r} has no 2-D image HDU")
        data = np.array(data, dtype=np.float64)
    if data.shape == (detector.naxis2, detector.naxis1):
        data = data[detector.y0:detector.y0 + detector.ny,
                    detector.x0:detector.x0 + detector.nx]
    elif data.shape != detector.shape:
        raise FileFormatError(
            f"'pca0_file': {path!r} has shape {data.shape}; expected the full array "
            f"{(detector.naxis2, detector.naxis1)} or the read-out shape {detector.shape}")
    return _normalise(data)


def template_for(detector, path=None):
    """Template for the read-out image of ``detector``, shape (ny, nx), float32."""
    if path:
        return load_template(path, detector).astype(np.float32)
    full = synthetic_template(detector.naxis2, detector.naxis1)
    return full[detector.y0:detector.y0 + detector.ny,
                detector.x0:detector.x0 + detector.nx].astype(np.float32)
