"""Inputs that become charge rates: source catalogues, rate maps and hot pixels.

Everything here returns rates in e-/s on the read-out image (``[y, x]``, pixel centres
at integers, ``x`` = column), ready for the charge engine, which turns a rate ``r`` and
an interval ``[t1, t2]`` into a Poisson draw of mean ``r (t2 - t1)`` (DESIGN.md
section 5).

Catalogues
----------
:func:`read_catalogue` reads a point-source list (ECSV or FITS table, or an astropy
:class:`~astropy.table.Table`) with the columns ``x``, ``y`` (pixels of the read-out
image) and ``flux`` (e-/s), matched case-insensitively, and the optional ``id`` and
``light_curve`` (path of a light-curve file, see :mod:`scenesim.sky.lightcurve`; relative
paths are taken relative to the catalogue file).  A ``flux`` column with an astropy
unit is converted to e-/s; ``x``/``y`` with a unit must be in pixels.

Rate maps
---------
:func:`uniform_or_map` turns a dark-current or background setting into a map: a scalar
(uniform) or a FITS image of the read-out shape, or a full-frame image that is cut to
the detector's subarray.

Hot pixels
----------
:func:`draw_hot_pixels` draws a population of hot pixels: each regular (non-reference)
pixel is hot independently with probability ``fraction`` and then gets an extra dark
rate, either fixed or log-uniform between two bounds, i.e. with density
``p(r) = 1 / (r ln(r_hi / r_lo))`` -- equal numbers per decade, a common first
description of the long tail of dark-current distributions in HgCdTe arrays.  The draw
is made as ``k ~ Binomial(n_regular, fraction)`` followed by ``k`` distinct pixels
chosen uniformly, which has the same law as independent Bernoulli trials but costs
``O(k)`` random numbers.
"""

import math
import numbers
import os

import numpy as np

from noise.validate import check_shape
from noise.errors import FileFormatError, ParameterError

__all__ = ["read_catalogue", "uniform_or_map", "draw_hot_pixels"]

_REQUIRED = ("x", "y", "flux")


def read_catalogue(path_or_table):
    """Read and validate a point-source catalogue.

    Parameters
    ----------
    path_or_table : str, os.PathLike or astropy.table.Table
        ECSV (``.ecsv``) or FITS table file, or a table already in memory.

    Returns
    -------
    astropy.table.Table
        A new table with columns ``id`` (int64; ``0 .. n-1`` when absent from the
        input), ``x``, ``y`` (float64, pixels), ``flux`` (float64, e-/s), ``light_curve``
        (str, ``''`` for none; only when present in the input) and any other input
        columns unchanged.

    Raises
    ------
    FileFormatError
        The file is missing or unreadable, a required column is missing (the message
        names the column(s) and the file), column names clash case-insensitively, or a
        unit cannot be converted.
    ParameterError
        ``flux`` negative or NaN/inf, ``x``/``y`` NaN/inf, or duplicate ``id`` values.
    """
    from astropy import units as u
    from astropy.table import Table

    source_dir = None
    if isinstance(path_or_table, Table):
        table = path_or_table
        where = "the input table"
    elif isinstance(path_or_table, (str, os.PathLike)):
        path = os.fspath(path_or_table)
        where = f"catalogue {path!r}"
        if not os.path.isfile(path):
            raise FileFormatError(f"{where} does not exist")
        try:
            table = Table.read(path)
        except Exception as exc:  # astropy raises many types for unreadable files
            raise FileFormatError(f"cannot read {where}: {exc}") from exc
        source_dir = os.path.dirname(os.path.abspath(path))
    else:
        raise ParameterError(
            f"'path_or_table' must be a file path or an astropy Table, got "
            f"{type(path_or_table).__name__}")

    lower = {}
    for name in table.colnames:
        key = name.lower()
        if key in lower and key in _REQUIRED + ("id", "light_curve"):
            raise FileFormatError(
                f"{where} has columns {lower[key]!r} and {name!r}, which clash "
                f"(column names are matched case-insensitively)")
        lower.setdefault(key, name)
    missing = [c for c in _REQUIRED if c not in lower]
    if missing:
        raise FileFormatError(
            f"{where} lacks required column(s) {missing} (need x, y, flux; found "
            f"{table.colnames})")

    def values(key, unit, what):
        col = table[lower[key]]
        try:
            arr = np.ma.filled(np.ma.asarray(col, dtype=np.float64), np.nan)
        except (TypeError, ValueError) as exc:
            raise FileFormatError(
                f"{where}: column {lower[key]!r} must hold numbers, got {col.dtype}"
            ) from exc
        if getattr(col, "unit", None) is not None:
            try:
                arr = (arr * col.unit).to_value(unit)
            except u.UnitConversionError as exc:
                raise FileFormatError(
                    f"{where}: column {lower[key]!r} has unit {col.unit}, which is not "
                    f"{what}") from exc
        return arr

    xs = values("x", u.pix, "pixels")
    ys = values("y", u.pix, "pixels")
    flux = values("flux", u.electron / u.s, "e-/s (electron / s)")
    for key, arr in (("x", xs), ("y", ys)):
        bad = ~np.isfinite(arr)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ParameterError(
                f"{where}: {key!r} must be finite (pixels); row {i} has {arr[i]!r} "
                f"({int(bad.sum())} bad rows)")
    bad = ~np.isfinite(flux) | (flux < 0)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ParameterError(
            f"{where}: 'flux' must be finite and >= 0 (e-/s); row {i} has {flux[i]!r} "
            f"({int(bad.sum())} bad rows)")

    out = Table()
    if "id" in lower:
        ids = np.asarray(table[lower["id"]])
        if len(np.unique(ids)) != len(ids):
            raise ParameterError(f"{where}: 'id' values must be unique")
        out["id"] = ids
    else:
        out["id"] = np.arange(len(table), dtype=np.int64)
    out["x"] = xs
    out["y"] = ys
    out["flux"] = flux
    out["x"].unit = u.pix
    out["y"].unit = u.pix
    out["flux"].unit = u.electron / u.s
    if "light_curve" in lower:
        raw = table[lower["light_curve"]]
        lcs = [("" if v is np.ma.masked else str(v).strip()) for v in raw]
        if source_dir is not None:
            lcs = [v if (not v or os.path.isabs(v)) else os.path.join(source_dir, v)
                   for v in lcs]
        out["light_curve"] = np.array(lcs, dtype=str) if lcs else np.array([], dtype=str)
    used = {lower[k] for k in ("id", "x", "y", "flux", "light_curve") if k in lower}
    for name in table.colnames:
        if name not in used:
            out[name] = table[name]
    out.meta.update(table.meta)
    return out


def _read_map(path, name):
    from astropy.io import fits
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileFormatError(f"{name!r}: map file {path!r} does not exist")
    try:
        with fits.open(path, memmap=False) as hdul:
            for hdu in hdul:
                if hdu.data is not None and np.ndim(hdu.data) == 2:
                    return np.array(hdu.data, dtype=np.float64)
    except (OSError, TypeError, ValueError) as exc:
        raise FileFormatError(f"{name!r}: cannot read map {path!r}: {exc}") from exc
    raise FileFormatError(f"{name!r}: map file {path!r} has no 2-D image HDU")


def uniform_or_map(value_or_path, shape, name, *, detector=None):
    """A rate setting as a map: scalar (uniform), FITS file or array.

    Parameters
    ----------
    value_or_path : float, str, os.PathLike or array_like
        Rate in e-/s: a scalar, the path of a FITS image (first HDU holding 2-D data)
        or a 2-D array.
    shape : tuple of int
        ``(ny, nx)`` of the read-out image.
    name : str
        Name of the setting, used in error messages (e.g. ``'dark_current'``).
    detector : noise.clock.Detector or None
        When given, a map of the full-array shape ``(naxis2, naxis1)`` is cut to the
        detector's subarray (``[y0:y0+ny, x0:x0+nx]``).

    Returns
    -------
    ndarray, shape (ny, nx), float64, e-/s
        A new array.

    Raises
    ------
    ParameterError
        Negative or NaN/inf values, or a map whose shape matches neither ``shape`` nor
        the full array.
    FileFormatError
        Missing or unreadable file, or no 2-D image in it.
    """
    ny, nx = check_shape("shape", shape)
    if isinstance(value_or_path, numbers.Real) and not isinstance(value_or_path, bool):
        value = float(value_or_path)
        if not math.isfinite(value) or value < 0:
            raise ParameterError(
                f"{name!r} must be a finite rate >= 0 (e-/s), got {value_or_path!r}")
        return np.full((ny, nx), value, dtype=np.float64)
    if isinstance(value_or_path, (str, os.PathLike)):
        arr = _read_map(value_or_path, name)
        origin = f"map file {os.fspath(value_or_path)!r}"
    elif isinstance(value_or_path, (np.ndarray, list, tuple)):
        try:
            arr = np.array(value_or_path, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ParameterError(f"{name!r} must be an array of numbers") from exc
        origin = "array"
    else:
        raise ParameterError(
            f"{name!r} must be a rate (e-/s), a FITS path or a 2-D array, got "
            f"{type(value_or_path).__name__}")
    if arr.ndim != 2:
        raise ParameterError(f"{name!r}: {origin} must be 2-D, got shape {arr.shape}")
    if arr.shape != (ny, nx):
        full = None if detector is None else (detector.naxis2, detector.naxis1)
        if full is not None and arr.shape == full and (ny, nx) == tuple(detector.shape):
            y0, x0 = detector.y0, detector.x0
            arr = arr[y0:y0 + ny, x0:x0 + nx]
        else:
            allowed = f"{(ny, nx)}" + ("" if full is None else f" or full frame {full}")
            raise ParameterError(
                f"{name!r}: {origin} has shape {arr.shape}, expected {allowed}")
    bad = ~np.isfinite(arr) | (arr < 0)
    if bad.any():
        y, x = (int(v[0]) for v in np.nonzero(bad))
        raise ParameterError(
            f"{name!r} must be finite and >= 0 (e-/s); {origin} has {arr[y, x]!r} at "
            f"[y={y}, x={x}] ({int(bad.sum())} bad pixels)")
    return np.ascontiguousarray(arr, dtype=np.float64).copy()


def draw_hot_pixels(shape, fraction, *, rate, rng, refmask=None):
    """Draw a population of hot pixels as an extra dark-rate map.

    Parameters
    ----------
    shape : tuple of int
        ``(ny, nx)`` of the read-out image.
    fraction : float
        Probability that a regular pixel is hot, ``0 <= fraction <= 1``.
    rate : float or (float, float)
        Extra dark rate of a hot pixel, e-/s: a scalar (> 0), or ``(lo, hi)`` with
        ``0 < lo <= hi`` for a log-uniform draw between them.
    rng : numpy.random.Generator, int, SeedSequence or None
        Random source (``np.random.default_rng(rng)``).
    refmask : ndarray of bool, shape (ny, nx), or None
        True for reference pixels, which are never hot.

    Returns
    -------
    ndarray, shape (ny, nx), float64, e-/s
        Extra dark rate: 0 except on hot pixels.

    Raises
    ------
    ParameterError
        Bad shape, fraction, rate or refmask (checked before drawing).
    """
    ny, nx = check_shape("shape", shape)
    if isinstance(fraction, bool) or not isinstance(fraction, numbers.Real) \
            or not (0.0 <= float(fraction) <= 1.0):
        raise ParameterError(f"'fraction' must be a number in [0, 1], got {fraction!r}")
    fraction = float(fraction)
    if isinstance(rate, numbers.Real) and not isinstance(rate, bool):
        lo = hi = float(rate)
        if not math.isfinite(lo) or lo <= 0:
            raise ParameterError(f"'rate' must be a finite rate > 0 (e-/s), got {rate!r}")
    else:
        try:
            lo, hi = (float(v) for v in rate)
        except (TypeError, ValueError) as exc:
            raise ParameterError(
                f"'rate' must be a rate > 0 or a pair (lo, hi) in e-/s, got {rate!r}"
            ) from exc
        if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
            raise ParameterError(
                f"'rate' bounds must satisfy 0 < lo <= hi (e-/s), got {rate!r}")
    if refmask is None:
        candidates = None
        n_regular = ny * nx
    else:
        refmask = np.asarray(refmask)
        if refmask.shape != (ny, nx) or refmask.dtype != bool:
            raise ParameterError(
                f"'refmask' must be a bool array of shape {(ny, nx)}, got "
                f"{refmask.dtype} {refmask.shape}")
        candidates = np.flatnonzero(~refmask)
        n_regular = candidates.size

    rng = np.random.default_rng(rng)
    out = np.zeros(ny * nx, dtype=np.float64)
    k = int(rng.binomial(n_regular, fraction))
    if k == 0:
        return out.reshape(ny, nx)
    chosen = rng.choice(n_regular, size=k, replace=False)
    if candidates is not None:
        chosen = candidates[chosen]
    if lo == hi:
        values = np.full(k, lo)
    else:
        values = np.exp(rng.uniform(math.log(lo), math.log(hi), size=k))
    out[chosen] = values
    return out.reshape(ny, nx)
