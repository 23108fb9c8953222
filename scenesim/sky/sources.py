"""Point sources and hot pixels: inputs that become charge rates.

Everything here works on the read-out image (``[y, x]``, pixel centres at integers,
``x`` = column) in e-/s, ready for the charge engine, which turns a rate ``r`` and an
interval ``[t1, t2]`` into a Poisson draw of mean ``r (t2 - t1)`` (DESIGN.md section 5).

Catalogues
----------
:func:`read_catalogue` is the one catalogue reader; the scene's ``[sources]
catalogue`` goes through it.  A catalogue is an ECSV or FITS table (or an astropy
:class:`~astropy.table.Table`) with the columns

* ``x``, ``y``: position, pixels of the read-out image (0-based, column and row); a
  unit, if any, must be pixels;
* ``flux``: total rate over the PSF, e-/s (>= 0); a unit, if any, is converted to
  e-/s (e.g. ``electron / min``);
* ``id`` (optional): unique labels, ``0 .. n-1`` when absent;
* ``light_curve`` (optional): the **name** of a light curve defined in the scene
  (``[sources.light_curves.NAME]``), or empty for a constant source.  FITS stores an
  empty string as a missing value, which also means constant.  The names are checked
  against the scene's light curves by :meth:`scenesim.scene.SourcesConfig.star_table`.

Column names are matched case-insensitively (:mod:`scenesim.sky.tables`); other
columns are kept, and a scene's run writes them, with ``id``, to the truth's
``SOURCES`` table, row for row in the catalogue's order
(:meth:`scenesim.scene.SourcesConfig.star_table`).

Hot pixels
----------
:func:`draw_hot_pixels` draws a population of hot pixels: each regular (non-reference)
pixel is hot independently with probability ``fraction`` and then gets an extra dark
rate, either fixed or log-uniform between two bounds, i.e. with density
``p(r) = 1 / (r ln(r_hi / r_lo))`` -- equal numbers per decade, a common first
description of the long tail of dark-current distributions in HgCdTe arrays.  One
uniform per pixel decides both (a pixel is hot when it is below ``fraction``, and the
rest of it places the rate), drawn for the detector's full array and cut to its
window, so that a window has the hot pixels of the full frame (since 2026-11-28; the
draw had been ``k ~ Binomial(n_regular, fraction)`` distinct pixels of the read-out
image, other pixels in every window).
"""

import math
import os

import numpy as np
from astropy import units as u
from astropy.table import Table

from noise.errors import ParameterError, ParameterTypeError
from noise.streams import detector_uniform
from noise.validate import (check_float, check_instance, check_mask, check_rng,
                            check_shape, describe, is_real)

from scenesim.sky.tables import column_values, find_columns, read_table

__all__ = ["read_catalogue", "draw_hot_pixels"]


def read_catalogue(path_or_table):
    """Read and validate a point-source catalogue.

    Parameters
    ----------
    path_or_table : str, os.PathLike or astropy.table.Table
        ECSV (``.ecsv``) or FITS table file, or a table already in memory.

    Returns
    -------
    astropy.table.Table
        A new table with columns ``id`` (``0 .. n-1`` when absent from the input),
        ``x``, ``y`` (float64, pixels), ``flux`` (float64, e-/s), ``light_curve`` (str,
        the light-curve name, ``''`` for none) and any other input columns unchanged.

    Raises
    ------
    FileFormatError
        The file is missing or unreadable, a required column is missing (the message
        names the column, the nearest name and the file), column names clash
        case-insensitively, a column is not numeric, or a unit cannot be converted.
    ParameterError
        ``flux`` negative or NaN/inf, ``x``/``y`` NaN/inf, or duplicate ``id`` values.
    """
    if isinstance(path_or_table, Table):
        table = path_or_table
        where = "the input table"
    elif isinstance(path_or_table, (str, os.PathLike)):
        path = os.fspath(path_or_table)
        where = f"catalogue {path!r}"
        table = read_table(path, what="catalogue")
    else:
        raise ParameterError(
            f"'path_or_table' must be a file path or an astropy Table, got "
            f"{type(path_or_table).__name__}")
    names = find_columns(table, ("x", "y", "flux"), ("id", "light_curve"), where=where)
    xs = column_values(table, names["x"], u.pix, where=where)
    ys = column_values(table, names["y"], u.pix, where=where)
    flux = column_values(table, names["flux"], u.electron / u.s, where=where)
    for key, arr in (("x", xs), ("y", ys)):
        bad = ~np.isfinite(arr)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ParameterError(
                f"{where}: {key!r} must be finite (pixels); row {i} has {float(arr[i])!r} "
                f"({int(bad.sum())} bad rows)")
    bad = ~np.isfinite(flux) | (flux < 0)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ParameterError(
            f"{where}: 'flux' must be finite and >= 0 (e-/s); row {i} has "
            f"{float(flux[i])!r} "
            f"({int(bad.sum())} bad rows)")

    out = Table()
    if "id" in names:
        ids = np.asarray(table[names["id"]])
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
    curves = [""] * len(table)
    if "light_curve" in names:
        col = table[names["light_curve"]]
        filled = col.filled("") if hasattr(col, "filled") else col
        curves = [str(v).strip() for v in filled]
    out["light_curve"] = np.array(curves, dtype=str)
    for name in table.colnames:
        if name not in names.values():
            out[name] = table[name]
    out.meta.update(table.meta)
    return out


def draw_hot_pixels(shape, fraction, *, rate, rng, refmask=None, detector=None):
    """Draw a population of hot pixels as an extra dark-rate map.

    One uniform ``u`` per pixel: a regular pixel is hot when ``u < fraction``, and its
    rate is ``lo (hi / lo) ** (u / fraction)`` (``u / fraction`` is uniform on [0, 1)
    given that).  With ``detector``, ``u`` is drawn for the full array and cut
    (:func:`noise.streams.detector_uniform`): the same pixels are hot, at the same
    rates, in a window as in the full frame of one detector and seed (drawn on the
    read-out image, a window had other hot pixels than the full frame).

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
    detector : noise.Detector or None
        The detector whose read-out image ``shape`` is (its shape): the draw is
        that of its full array, cut to it (``rng`` a ``PCG64`` generator).

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
    fraction = check_float("fraction", fraction, minimum=0.0, maximum=1.0)
    if is_real(rate):
        lo = hi = check_float("rate", rate, minimum=0.0, strict_min=True)
    else:
        try:
            lo, hi = (float(v) for v in rate)
        except (TypeError, ValueError) as exc:
            raise ParameterTypeError(
                f"'rate' must be a rate > 0 or a pair (lo, hi) in e-/s, got "
                f"{describe(rate)}") from exc
        if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
            raise ParameterError(
                f"'rate' bounds must satisfy 0 < lo <= hi (e-/s), got {describe(rate)}")
    if refmask is not None:
        refmask = check_mask("refmask", refmask, (ny, nx))
    rng = check_rng("rng", rng)
    if detector is not None:
        from noise.clock import Detector
        check_instance("detector", detector, Detector, "a noise.Detector")
        if tuple(detector.shape) != (ny, nx):
            raise ParameterError(f"'detector' reads out {tuple(detector.shape)}, but "
                                 f"'shape' is {(ny, nx)}")
        draw = detector_uniform(rng, detector)
    else:
        draw = rng.random((ny, nx))
    hot = draw < fraction
    if refmask is not None:
        hot &= ~refmask
    out = np.zeros((ny, nx), dtype=np.float64)
    if fraction > 0 and hot.any():
        share = draw[hot] / fraction
        out[hot] = lo if lo == hi else lo * np.exp(share * math.log(hi / lo))
    return out
