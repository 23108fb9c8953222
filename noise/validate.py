"""The project's one family of validators, shared by :mod:`noise` and :mod:`scenesim`.

Every check returns the value converted to its canonical type, or raises
:class:`~noise.errors.ParameterError` (:class:`~noise.errors.FileFormatError` for
files) with a one-line message that names the parameter, quotes the bad value and
says what is allowed, e.g. ``'gain' must be > 0, got -1.0``.  Callers pass the name a
user knows (a scene key, an argument or option name); a scene section prefixes its
table (``[effects] 'gain' must be ...``).

A value of the wrong type (a string where a number is expected, a list where a
``Detector`` is, ``None``, ...) raises :class:`~noise.errors.ParameterTypeError`, a
``ParameterError`` that is also a ``TypeError``.  Bad values are quoted by
:func:`describe`, which keeps every message on one line (an array is described by its
shape and dtype, a long repr is cut).
"""

import difflib
import math
import numbers
import os

import numpy as np

from noise.errors import FileFormatError, ParameterError, ParameterTypeError

__all__ = ["suggest", "is_sequence", "is_real", "describe", "check_instance",
           "check_int", "check_float", "check_bool", "check_str", "check_choice",
           "check_shape", "check_map", "check_image", "check_writable",
           "check_existing_file", "check_array", "check_mask", "check_path",
           "check_rng"]

#: Longest quoted value in a message (longer reprs are cut with "...").
_MAX_REPR = 80


def _num(v):
    """A bound as written in messages: ``0`` rather than ``0.0``."""
    return f"{v:g}" if isinstance(v, float) else f"{v}"


def describe(value):
    """A one-line quotation of ``value`` for an error message.

    Scalars and short containers are their ``repr``; an array of more than one
    dimension or more than 8 elements is ``array of shape (3, 5), float64``; anything
    else longer than 80 characters is cut (``...``).  Never contains a newline.
    """
    if isinstance(value, np.generic):       # as written: -0.5, not np.float64(-0.5)
        value = value.item()
    if isinstance(value, np.ndarray) and (value.ndim > 1 or value.size > 8):
        return f"array of shape {value.shape}, {value.dtype}"
    text = " ".join(repr(value).split()) if isinstance(value, np.ndarray) else repr(value)
    text = text.replace("\n", " ")
    return text if len(text) <= _MAX_REPR else text[:_MAX_REPR - 3] + "..."


def check_instance(name, value, cls, what=None, *, allow_none=False):
    """``value`` if it is an instance of ``cls`` (a class or a tuple of classes; or
    ``None`` with ``allow_none``), else :class:`~noise.errors.ParameterTypeError`
    naming ``what`` (default: the class names) and the type and value received."""
    if value is None and allow_none:
        return value
    if not isinstance(value, cls):
        if what is None:
            classes = cls if isinstance(cls, tuple) else (cls,)
            what = " or ".join(f"a {c.__module__}.{c.__qualname__}" for c in classes)
        if allow_none:
            what += " or None"
        raise ParameterTypeError(
            f"{name!r} must be {what}, got {type(value).__name__} {describe(value)}")
    return value


def suggest(word, candidates):
    """``"; did you mean 'x'?"`` for the closest of ``candidates``, else ``""``."""
    close = difflib.get_close_matches(str(word), [str(c) for c in candidates], n=1,
                                      cutoff=0.6)
    return f"; did you mean {close[0]!r}?" if close else ""


def is_sequence(value):
    """True for sized iterables other than strings and bytes."""
    if isinstance(value, (str, bytes)):
        return False
    try:
        len(value)
        iter(value)
    except TypeError:
        return False
    return True


def is_real(value):
    """True for real numbers (numpy scalars included), False for bools."""
    return isinstance(value, (numbers.Real, np.number)) and not isinstance(
        value, (bool, np.bool_)) and not isinstance(value, np.complexfloating)


def check_int(name, value, *, minimum=None, maximum=None):
    """``value`` as int, or raise if it is not an integer in ``[minimum, maximum]``."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise ParameterTypeError(f"{name!r} must be an integer, got {describe(value)}")
    value = int(value)
    if minimum is not None and value < minimum:
        raise ParameterError(f"{name!r} must be >= {minimum}, got {describe(value)}")
    if maximum is not None and value > maximum:
        raise ParameterError(f"{name!r} must be <= {maximum}, got {describe(value)}")
    return value


def check_float(name, value, *, minimum=None, maximum=None, strict_min=False):
    """``value`` as a finite float in range (``> minimum`` with ``strict_min``)."""
    if not is_real(value):
        raise ParameterTypeError(f"{name!r} must be a real number, got {describe(value)}")
    try:
        v = float(value)
    except OverflowError:                      # an int beyond the float range
        v = math.inf
    if not math.isfinite(v):
        raise ParameterError(f"{name!r} must be finite, got {describe(value)}")
    if minimum is not None:
        if strict_min and v <= minimum:
            raise ParameterError(
                f"{name!r} must be > {_num(minimum)}, got {describe(value)}")
        if not strict_min and v < minimum:
            raise ParameterError(
                f"{name!r} must be >= {_num(minimum)}, got {describe(value)}")
    if maximum is not None and v > maximum:
        raise ParameterError(
            f"{name!r} must be <= {_num(maximum)}, got {describe(value)}")
    return v


def check_bool(name, value):
    """``value`` as bool; only ``True``/``False`` (numpy's too) are accepted."""
    if not isinstance(value, (bool, np.bool_)):
        raise ParameterTypeError(f"{name!r} must be true or false, got {describe(value)}")
    return bool(value)


def check_str(name, value, *, nonempty=False, label=False):
    """``value`` if it is a string (non-empty with ``nonempty``).

    ``label``: a name written into FITS headers and tables, which hold printable
    ASCII only (characters 32-126: no accents, tabs or line breaks)."""
    if not isinstance(value, str) or (nonempty and not value):
        what = "a non-empty string" if nonempty else "a string"
        cls = ParameterError if isinstance(value, str) else ParameterTypeError
        raise cls(f"{name!r} must be {what}, got {describe(value)}")
    if label:
        bad = [(i, c) for i, c in enumerate(value) if not " " <= c <= "~"]
        if bad:
            i, c = bad[0]
            raise ParameterError(
                f"{name!r} must be printable ASCII (characters 32-126: it is written "
                f"to FITS headers), got {value!r}: {c!r} at position {i}")
    return value


def check_choice(name, value, allowed, *, ignore_case=False):
    """``value`` if it is one of ``allowed`` (strings), suggesting the nearest one.

    With ``ignore_case`` the matching entry of ``allowed`` is returned.
    """
    if isinstance(value, str):
        if value in allowed:
            return value
        if ignore_case:
            for a in allowed:
                if a.lower() == value.lower():
                    return a
    cls = ParameterError if isinstance(value, str) else ParameterTypeError
    raise cls(
        f"{name!r} must be one of {', '.join(repr(a) for a in allowed)}, got "
        f"{describe(value)}{suggest(value, allowed) if isinstance(value, str) else ''}")


def check_shape(name, shape):
    """``(ny, nx)`` as ints >= 1."""
    if not is_sequence(shape) or len(shape) != 2 or not all(
            isinstance(v, numbers.Integral) and not isinstance(v, (bool, np.bool_))
            for v in shape):
        raise ParameterTypeError(
            f"{name!r} must be (ny, nx), two integers, got {describe(shape)}")
    ny, nx = (int(v) for v in shape)
    if ny < 1 or nx < 1:
        raise ParameterError(f"{name!r} must be positive, got {describe(shape)}")
    return ny, nx


def check_map(name, value, shape, *, minimum=0.0, strict_min=False):
    """A scalar or a per-pixel map for images of ``shape`` (its last two axes).

    Returns a float, or a float64 ndarray of shape ``shape[-2:]``; every value must be
    finite and ``>= minimum`` (``> minimum`` with ``strict_min``; no bound for
    ``minimum=None``).
    """
    if isinstance(value, np.ndarray) and value.ndim == 0:
        value = value.item()
    rule = "" if minimum is None else f" and {'>' if strict_min else '>='} {_num(minimum)}"

    def bad_values(v):
        out = ~np.isfinite(v)
        if minimum is not None:
            out |= (v <= minimum) if strict_min else (v < minimum)
        return out

    if np.ndim(value) == 0:
        if not is_real(value):
            raise ParameterTypeError(
                f"{name!r} must be a real number or a map, got {describe(value)}")
        try:
            v = float(value)
        except OverflowError:                  # an int beyond the float range
            v = math.inf
        if bad_values(np.float64(v)):
            raise ParameterError(f"{name!r} must be finite{rule}, got {describe(value)}")
        return v
    try:
        if np.iscomplexobj(value):         # (float64 would drop the imaginary part)
            raise TypeError("complex")
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as exc:
        raise ParameterTypeError(
            f"{name!r} must be a real number or a map of shape {tuple(shape[-2:])}, "
            f"got {type(value).__name__} {describe(value)}") from exc
    if arr.shape != tuple(shape[-2:]):
        raise ParameterError(
            f"{name!r} map must be a scalar or have the image shape {tuple(shape[-2:])} "
            f"(ny, nx), got shape {arr.shape}")
    bad = bad_values(arr)
    if bad.any():
        y, x = np.argwhere(bad)[0]
        raise ParameterError(
            f"{name!r} map must be finite{rule} everywhere; {int(bad.sum())} pixels "
            f"are not, e.g. [{y}, {x}] = {float(arr[y, x])!r}")
    return arr


def check_image(name, image):
    """``image`` as an integer or float array with at least two axes ``(..., ny, nx)``."""
    try:
        arr = np.asarray(image)
    except (TypeError, ValueError) as exc:       # ragged nested sequences
        raise ParameterTypeError(
            f"{name!r} must be an integer or float array (..., ny, nx), got "
            f"{describe(image)}") from exc
    if arr.ndim < 2:
        raise ParameterError(
            f"{name!r} must have at least 2 dimensions (..., ny, nx), "
            f"got shape {arr.shape}")
    if not (np.issubdtype(arr.dtype, np.integer)
            or np.issubdtype(arr.dtype, np.floating)):
        raise ParameterTypeError(
            f"{name!r} must be an integer or float array, got {arr.dtype} "
            f"{describe(image)}")
    return arr


def check_writable(name, path, *, overwrite=True):
    """``path`` if it can be written: its directory exists and is writable, it is not a
    directory, it does not exist unless ``overwrite``, and what exists there is a
    regular file (a FIFO, a device or a socket is never replaced by one: as root,
    ``overwrite`` would otherwise turn ``/dev/null`` into a file)."""
    path = check_path(name, path)
    directory = os.path.dirname(os.path.abspath(path)) or "."
    if not os.path.isdir(directory):
        what = "is a file, not a directory" if os.path.exists(directory) else \
            "does not exist"
        raise ParameterError(
            f"{name!r}: directory {directory!r} of output {path!r} {what}")
    # as the kernel resolves it: 'missing/../x.fits' goes through 'missing' (the
    # text-normalised directory above exists; the write failed after the work)
    raw = os.path.dirname(os.path.expanduser(path)) or "."
    if not os.path.isdir(raw):
        raise ParameterError(
            f"{name!r}: the directory part {raw!r} of output {path!r} cannot be entered "
            f"(a component of it does not exist or is not a directory)")
    if not os.access(directory, os.W_OK):
        raise ParameterError(f"{name!r}: directory {directory!r} is not writable")
    check_name_length(name, path)
    if os.path.isdir(path):
        raise ParameterError(f"{name!r}: {path!r} is a directory, expected a file path")
    if os.path.exists(path) and not os.path.isfile(path):
        raise ParameterError(f"{name!r}: {path!r} is not a regular file (a device, FIFO "
                             f"or socket); it is never replaced: write to a file path")
    if os.path.lexists(path) and not overwrite:    # a link to nothing too
        raise ParameterError(f"{name!r}: {path!r} exists; pass overwrite=True to replace it")
    return path


#: Bytes of a file name kept free for the temporary files written beside an output
#: (``.scenesim-<pid>-<random>.<name>.tmp``, noise.fitsio).
TEMP_NAME_ROOM = 48


def check_name_length(name, path):
    """Refuse a file or directory name that the file system, or the temporary file
    written beside it (:data:`TEMP_NAME_ROOM` bytes more), could not hold (a name
    of 300 bytes failed after the work)."""
    base = os.path.basename(os.path.normpath(os.path.expanduser(path)))
    parent = os.path.dirname(os.path.abspath(os.path.expanduser(path))) or "."
    try:
        limit = os.pathconf(parent, "PC_NAME_MAX")
    except (OSError, ValueError):
        limit = 255
    n = len(os.fsencode(base))
    if n + TEMP_NAME_ROOM > limit:
        raise ParameterError(
            f"{name!r}: the name {base[:40]!r}... is {n} bytes; this file system takes "
            f"{limit}, of which {TEMP_NAME_ROOM} are kept for the temporary file "
            f"written beside it: at most {limit - TEMP_NAME_ROOM} bytes")


def check_existing_file(name, path, extensions=None):
    """Absolute path of an existing file (with one of ``extensions``, if given)."""
    path = os.path.abspath(os.path.expanduser(check_path(name, path)))
    if extensions is not None and not path.lower().endswith(tuple(extensions)):
        raise FileFormatError(
            f"{name!r} file {path!r} must have one of the extensions "
            f"{', '.join(extensions)}")
    if not os.path.isfile(path):
        raise FileFormatError(f"{name!r} file {path!r} does not exist")
    return path


def check_array(name, value, *, minimum=None, strict_min=False, unit=""):
    """``value`` (a scalar or an array of any shape) as a float64 ndarray whose values
    are all finite and ``>= minimum`` (``> minimum`` with ``strict_min``; no bound for
    ``minimum=None``); ``unit`` is named in the message."""
    what = f" ({unit})" if unit else ""
    if isinstance(value, (str, bytes, dict)) or value is None:
        raise ParameterTypeError(
            f"{name!r} must be a real number or array{what}, got {describe(value)}")
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as exc:
        raise ParameterTypeError(
            f"{name!r} must be a real number or array{what}, got "
            f"{describe(value)}") from exc
    bad = ~np.isfinite(arr)
    rule = ""
    if minimum is not None:
        bad |= (arr <= minimum) if strict_min else (arr < minimum)
        rule = f" and {'>' if strict_min else '>='} {_num(minimum)}"
    if bad.any():
        raise ParameterError(f"{name!r} must be finite{rule}{what}, got {describe(value)}")
    return arr


def check_mask(name, value, shape):
    """``value`` as a bool ndarray of exactly ``shape`` (e.g. a reference-pixel mask);
    other dtypes are refused rather than cast (0/1 floats are not a mask)."""
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError) as exc:       # ragged nested sequences
        raise ParameterTypeError(
            f"{name!r} must be a bool array of shape {tuple(shape)}, got "
            f"{describe(value)}") from exc
    if arr.dtype != bool or arr.shape != tuple(shape):
        raise ParameterTypeError(
            f"{name!r} must be a bool array of shape {tuple(shape)}, got {arr.dtype} "
            f"{arr.shape}")
    return arr


def check_path(name, value):
    """``value`` as a path string: a ``str`` or an ``os.PathLike`` (not bytes), not
    empty; else :class:`~noise.errors.ParameterTypeError` (or ``ParameterError`` for
    an empty string)."""
    if isinstance(value, os.PathLike):
        value = os.fspath(value)
    if not isinstance(value, str):
        raise ParameterTypeError(
            f"{name!r} must be a path (str or os.PathLike), got {type(value).__name__} "
            f"{describe(value)}")
    if not value:
        raise ParameterError(f"{name!r} must be a non-empty path, got ''")
    return value


def check_rng(name, rng):
    """``np.random.default_rng(rng)`` for ``rng`` a ``Generator``, ``SeedSequence``,
    an int >= 0 or None; else :class:`~noise.errors.ParameterTypeError` (a negative
    seed: :class:`~noise.errors.ParameterError`)."""
    if isinstance(rng, (np.random.Generator, np.random.SeedSequence,
                        np.random.BitGenerator)) or rng is None:
        return np.random.default_rng(rng)
    if isinstance(rng, (bool, np.bool_)) or not isinstance(rng, numbers.Integral):
        raise ParameterTypeError(
            f"{name!r} must be a numpy Generator, SeedSequence, an int seed >= 0 or None, "
            f"got {describe(rng)}")
    if rng < 0:
        raise ParameterError(f"{name!r} seed must be >= 0, got {rng!r}")
    return np.random.default_rng(int(rng))
