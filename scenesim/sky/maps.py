"""Per-pixel maps named by a scene: a scalar, or a FITS image of the array.

Every parameter a scene may give per pixel -- the dark current and background rates
(e-/s), and the detector's full well (e-) and flat -- is either a scalar or the path
of a FITS file.  The map is the **first 2-D image HDU** of the file (primary, image or
compressed image; an empty primary HDU is skipped) and holds either

* the full array, ``(naxis2, naxis1)`` including the reference pixels: for a
  subarray the read-out window ``[y0:y0+ny, x0:x0+nx]`` is cut from it; or
* the read-out image, ``detector.shape`` (``(ny, nx)``, the window itself).

:func:`load_map` is the one loader (the run uses it for all four parameters); it
checks the shape and that every value is finite and ``>= 0`` (``> 0`` where zero is
not allowed, e.g. the full well).  :func:`check_map_file` checks the shape from the
header alone, without reading the data, so a scene can be validated when it is
loaded.
"""

import numpy as np
from astropy.io import fits

from noise.errors import FileFormatError, ParameterError
from noise.fitsio import open_fits
from noise.clock import Detector
from noise.validate import check_existing_file, check_instance, check_map

__all__ = ["FITS_EXTENSIONS", "image_hdu", "check_map_file", "load_map"]

#: File name endings accepted for FITS files.
FITS_EXTENSIONS = (".fits", ".fit", ".fts", ".fits.gz", ".fit.gz", ".fts.gz")


def image_hdu(name, path):
    """Index and ``(ny, nx)`` shape of the first 2-D image HDU of a FITS file.

    Reads the headers only.

    Parameters
    ----------
    name : str
        Parameter name for error messages (e.g. ``'dark_current'``).
    path : str
        An existing FITS file.

    Returns
    -------
    index : int
    shape : (int, int)

    Raises
    ------
    FileFormatError
        The file is not readable FITS or has no 2-D image HDU.
    """
    with open_fits(path, f"{name!r} file") as hdul:
        for i, hdu in enumerate(hdul):
            if isinstance(hdu, (fits.PrimaryHDU, fits.ImageHDU, fits.CompImageHDU)) \
                    and hdu.header.get("NAXIS") == 2:
                return i, (int(hdu.header["NAXIS2"]), int(hdu.header["NAXIS1"]))
    raise FileFormatError(f"{name!r} file {path!r} has no 2-D image HDU")


def _check_shape(name, path, shape, detector):
    full = (detector.naxis2, detector.naxis1)
    if shape not in (full, detector.shape):
        raise FileFormatError(
            f"{name!r} map {path!r} has shape {shape} (ny, nx); expected the full array "
            f"{full} or the read-out shape {detector.shape}")


def check_map_file(name, path, detector):
    """Check from its header that a FITS map fits ``detector`` (values are not read).

    Parameters
    ----------
    name : str
        Parameter name for error messages.
    path : str
        An existing FITS file.
    detector : noise.clock.Detector

    Raises
    ------
    FileFormatError
        Not FITS, no 2-D image, or a shape that is neither the full array nor the
        read-out image.
    """
    _, shape = image_hdu(name, path)
    _check_shape(name, path, shape, detector)


def load_map(value, detector, *, name, allow_zero=True):
    """A scalar or FITS-map parameter as used by the simulation.

    Parameters
    ----------
    value : float or str
        A scalar, or the path of a FITS file whose first 2-D image holds either the full
        array ``(naxis2, naxis1)`` (the read-out window is cut from it) or the read-out
        shape ``detector.shape``.
    detector : noise.clock.Detector
    name : str, keyword-only
        Parameter name for error messages (e.g. ``'dark_current'``).
    allow_zero : bool, keyword-only
        Accept 0 (``>= 0``); otherwise values must be ``> 0`` (e.g. ``full_well``).

    Returns
    -------
    numpy.float64 or ndarray of shape ``detector.shape``, float64
        In the unit of the parameter (e-/s for rates, e- for the full well).  An array
        is C-contiguous and owns its data.

    Raises
    ------
    ParameterError
        A value is negative (or 0 when not allowed), NaN or infinite.
    FileFormatError
        The file is missing, not FITS, or has the wrong shape.
    """
    check_instance("detector", detector, Detector, "a noise.Detector")
    if not isinstance(value, str):
        return np.float64(check_map(name, value, detector.shape, minimum=0.0,
                                    strict_min=not allow_zero))
    path = check_existing_file(name, value, FITS_EXTENSIONS)
    index, shape = image_hdu(name, path)
    _check_shape(name, path, shape, detector)
    with open_fits(path, f"{name!r} file") as hdul:
        data = np.array(hdul[index].data, dtype=np.float64)
    if data.shape != detector.shape:
        data = data[detector.y0:detector.y0 + detector.ny,
                    detector.x0:detector.x0 + detector.nx]
    try:
        data = check_map(name, data, detector.shape, minimum=0.0,
                         strict_min=not allow_zero)
    except ParameterError as exc:
        raise ParameterError(f"{exc} (map file {path!r})") from exc
    return np.ascontiguousarray(data)
