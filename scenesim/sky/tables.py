"""Reading the tables a scene names: source catalogues and light-curve files.

One reader for both (:func:`scenesim.sky.sources.read_catalogue` and
:meth:`scenesim.sky.lightcurve.LightCurve.from_file` use it):

* Formats: ECSV (``.ecsv``) and FITS binary tables (``.fits``, ``.fit``, ``.fts``,
  optionally gzipped) are read with that format explicitly; other names are left to
  astropy's format detection.
* Columns are matched case-insensitively (``X`` is ``x``); two columns whose names
  differ only in case clash; a missing column is reported with the nearest name.
* Numeric columns are read as float64 with missing (masked) values as NaN; a column
  that carries an astropy unit is converted to the unit the caller asks for.
"""

import os
import warnings

import numpy as np
from astropy import units as u
from astropy.table import Table
from astropy.utils.exceptions import AstropyWarning

from noise.errors import FileFormatError
from noise.validate import check_path, suggest

from scenesim.sky.maps import FITS_EXTENSIONS

__all__ = ["TABLE_EXTENSIONS", "read_table", "find_columns", "column_values"]

#: File name endings of the table formats read with an explicit format.
TABLE_EXTENSIONS = (".ecsv",) + FITS_EXTENSIONS


def read_table(path, *, what):
    """Read an ECSV or FITS table.

    Parameters
    ----------
    path : str or os.PathLike
    what : str, keyword-only
        What the file is, for messages (e.g. ``'catalogue'``).

    Returns
    -------
    astropy.table.Table

    Raises
    ------
    FileFormatError
        The file is missing or cannot be read.
    """
    path = check_path(what, path)
    if not os.path.isfile(path):
        raise FileFormatError(f"{what} {path!r} does not exist")
    low = path.lower()
    fmt = "ascii.ecsv" if low.endswith(".ecsv") else \
        "fits" if low.endswith(FITS_EXTENSIONS) else None
    try:
        with warnings.catch_warnings():
            # a truncated or damaged file: astropy's warning is the error
            warnings.simplefilter("error", AstropyWarning)
            return Table.read(path, format=fmt)
    except Exception as exc:  # astropy raises many types for unreadable files
        how = f" as {fmt}" if fmt else ""
        reason = " ".join(str(exc).split())[:300]
        raise FileFormatError(f"{what} {path!r} cannot be read{how}: {reason}") from exc


def find_columns(table, required, optional=(), *, where):
    """Map lower-case column keys to the table's own column names.

    Parameters
    ----------
    table : astropy.table.Table
    required, optional : sequence of str
        Lower-case keys; a missing required key is an error.
    where : str, keyword-only
        The table, for messages (e.g. ``"catalogue 'cat.ecsv'"``).

    Returns
    -------
    dict
        ``{key: column name}`` for the required keys and the optional keys present.

    Raises
    ------
    FileFormatError
        A required column is missing (the nearest name is suggested), or two columns
        match one key.
    """
    keys = tuple(required) + tuple(optional)
    lower = {}
    for name in table.colnames:
        key = name.lower()
        if key in lower and key in keys:
            raise FileFormatError(
                f"{where} has columns {lower[key]!r} and {name!r}, which clash "
                f"(column names are matched case-insensitively)")
        lower.setdefault(key, name)
    for key in required:
        if key not in lower:
            raise FileFormatError(
                f"{where} has no column {key!r}{suggest(key, table.colnames)} "
                f"(columns: {', '.join(table.colnames)})")
    return {key: lower[key] for key in keys if key in lower}


def column_values(table, name, unit=None, *, where):
    """A numeric column as float64, masked values as NaN, converted to ``unit``.

    Parameters
    ----------
    table : astropy.table.Table
    name : str
        The column's name in ``table``.
    unit : astropy.units.Unit or None
        Unit to convert to when the column has one; ``None`` ignores the column's unit.
    where : str, keyword-only
        The table, for messages.

    Returns
    -------
    ndarray, shape (len(table),), float64

    Raises
    ------
    FileFormatError
        The column does not hold numbers, or its unit does not convert to ``unit``.
    """
    col = table[name]
    try:
        arr = np.array(np.ma.filled(np.ma.asarray(col, dtype=np.float64), np.nan),
                       dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise FileFormatError(
            f"{where}: column {name!r} must hold numbers, got {col.dtype}") from exc
    if unit is not None and getattr(col, "unit", None) is not None:
        try:
            arr = np.asarray((arr * col.unit).to_value(unit), dtype=np.float64)
        except u.UnitConversionError as exc:
            raise FileFormatError(
                f"{where}: column {name!r} has unit {col.unit}, which does not convert "
                f"to {unit}") from exc
    return arr
