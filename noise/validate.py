"""Small validators that raise :class:`~noise.errors.ParameterError` with a clear message."""

import math
import numbers
import os


from noise.errors import ParameterError

__all__ = []


def check_int(name, value, *, minimum=None, maximum=None):
    """Return ``value`` as int, or raise if it is not an integer in [minimum, maximum]."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ParameterError(f"{name!r} must be an integer, got {value!r}")
    value = int(value)
    if minimum is not None and value < minimum:
        raise ParameterError(f"{name!r} must be >= {minimum}, got {value!r}")
    if maximum is not None and value > maximum:
        raise ParameterError(f"{name!r} must be <= {maximum}, got {value!r}")
    return value


def check_float(name, value, *, minimum=None, maximum=None, strict_min=False):
    """Return ``value`` as a finite float in range, or raise naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ParameterError(f"{name!r} must be a real number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise ParameterError(f"{name!r} must be finite, got {value!r}")
    if minimum is not None:
        if strict_min and value <= minimum:
            raise ParameterError(f"{name!r} must be > {minimum}, got {value!r}")
        if not strict_min and value < minimum:
            raise ParameterError(f"{name!r} must be >= {minimum}, got {value!r}")
    if maximum is not None and value > maximum:
        raise ParameterError(f"{name!r} must be <= {maximum}, got {value!r}")
    return value


def check_writable(name, path, *, overwrite=True):
    """Raise if ``path`` cannot be written (missing directory, no permission, exists)."""
    path = os.fspath(path)
    directory = os.path.dirname(os.path.abspath(path)) or "."
    if not os.path.isdir(directory):
        raise ParameterError(
            f"{name!r}: directory {directory!r} of output {path!r} does not exist")
    if not os.access(directory, os.W_OK):
        raise ParameterError(f"{name!r}: directory {directory!r} is not writable")
    if os.path.isdir(path):
        raise ParameterError(f"{name!r}: {path!r} is a directory, expected a file path")
    if os.path.exists(path) and not overwrite:
        raise ParameterError(f"{name!r}: {path!r} exists; pass overwrite=True to replace it")
    return path


def check_shape(name, shape):
    """Return ``(ny, nx)`` as ints >= 1, or raise naming ``name``."""
    try:
        ny, nx = (int(v) for v in shape)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{name!r} must be (ny, nx), got {shape!r}") from exc
    if ny < 1 or nx < 1:
        raise ParameterError(f"{name!r} must be positive, got {shape!r}")
    return ny, nx
