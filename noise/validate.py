"""Small validators that raise :class:`~noise.errors.ParameterError` with a clear message."""

import math
import numbers
import os

import numpy as np

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


def check_map(name, value, shape, *, allow_zero):
    """Validate a scalar or a (ny, nx) map against ``shape`` (the image's last two axes).

    Returns a float or a float64 ndarray; values must be finite and >= 0 (``allow_zero``)
    or > 0.
    """
    if isinstance(value, np.ndarray) and value.ndim == 0:
        value = value.item()
    rule = ">= 0" if allow_zero else "> 0"
    if np.ndim(value) == 0:
        if isinstance(value, bool) or not isinstance(value, (numbers.Real, np.number)):
            raise ParameterError(
                f"{name!r} must be a real number or a map, got {value!r}")
        v = float(value)
        if not math.isfinite(v) or (v < 0 if allow_zero else v <= 0):
            raise ParameterError(f"{name!r} must be finite and {rule}, got {value!r}")
        return v
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != tuple(shape[-2:]):
        raise ParameterError(
            f"{name!r} map must be a scalar or have the image shape {tuple(shape[-2:])} "
            f"(ny, nx), got shape {arr.shape}")
    bad = ~np.isfinite(arr) | ((arr < 0) if allow_zero else (arr <= 0))
    if bad.any():
        y, x = np.argwhere(bad)[0]
        raise ParameterError(
            f"{name!r} map must be finite and {rule} everywhere; {int(bad.sum())} pixels "
            f"are not, e.g. [{y}, {x}] = {float(arr[y, x])!r}")
    return arr


def check_image(name, image):
    arr = np.asarray(image)
    if arr.ndim < 2:
        raise ParameterError(
            f"{name!r} must have at least 2 dimensions (..., ny, nx), "
            f"got shape {arr.shape}")
    if not (np.issubdtype(arr.dtype, np.integer)
            or np.issubdtype(arr.dtype, np.floating)):
        raise ParameterError(
            f"{name!r} must be an integer or float array, got {arr.dtype}")
    return arr
