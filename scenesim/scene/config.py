"""Declarative scene files: TOML validated into frozen dataclasses.

A scene file says *what* to simulate: the detector and its clocking, the noise, the
readout pattern, the sources of charge, the detector effects, the outputs and the seed.
It is read with the standard library (:mod:`tomllib`; ``tomli`` on Python 3.10) and
validated, before any work starts, into frozen (hashable, picklable) dataclasses:

=========================  ==================================================
TOML table                 dataclass
=========================  ==================================================
``[detector]``             :class:`noise.clock.Detector` (with ``Subarray``)
``[noise]``                :class:`noise.params.NoiseParams`
``[readout]``              :class:`ReadoutConfig` (``build()`` -> ``Readout``)
``[sources]``              :class:`SourcesConfig`, :class:`PSFConfig`,
                           :class:`StarConfig`, :class:`LightCurveConfig`
``[effects]``              :class:`EffectsConfig`
``[output]``               :class:`OutputConfig`
top level                  :class:`Scene` (``seed``, ``description``)
=========================  ==================================================

Validation rules
----------------
* Unknown keys are rejected with the nearest valid name and the table path, e.g.
  ``unknown key 'backgroud' in [sources]; did you mean 'background'?``.
* Types and ranges are checked (a negative or NaN rate names its key); files named by
  the scene must exist (:class:`~noise.errors.FileFormatError`); tables (catalogue,
  light-curve files) are read and their columns checked; FITS maps have their shape
  checked against the detector from the header alone (values are checked when the map
  is loaded, :func:`load_map`).
* Cross-checks: stars reference defined light curves, exactly one readout form, per-output
  noise amplitudes match the active outputs, the nonlinearity is monotonic up to the full
  well, ``ramp = false`` needs a fit, ...
* :func:`load_scene` builds the readout once (:meth:`ReadoutConfig.build`) so an unknown
  pattern name or a bad MA table fails at load time.

Every error is a :class:`~noise.errors.ParameterError` or
:class:`~noise.errors.FileFormatError` (both :class:`ValueError`) whose message names the
table, the key, the bad value and what is allowed; :func:`load_scene` prefixes the scene
file's path.

Paths
-----
Every relative file path *inside* a scene (maps, catalogue, PSF image, light-curve
files, ``noise.pca0_file``) is resolved relative to the scene file's directory and
stored as an absolute path string.  The exception is ``[output] path``: it is kept as
written and is relative to the current working directory of the process that runs the
scene, so the same scene can be run from anywhere and writes there.

Coordinates, times and units
----------------------------
Star positions ``x, y`` are 0-based pixel coordinates of the read-out image (column, row;
for a subarray, relative to its first pixel), with pixel centres at integers.  Rates are
e-/s (star ``flux`` is the total rate over the whole PSF); charges e-; ``gain`` e-/DN.
Light-curve times are seconds from the start of the exposure: the start of the reset
frame of integration 0, the same clock as ``docs/CONVENTIONS.md`` (slot ``s`` of a pixel
is at ``s * t_frame + t_pix``).

Light curves
------------
A light curve is a dimensionless factor ``f(t) >= 0`` multiplying a star's flux:

* ``transit`` (``t0``, ``duration``, ``depth``, ``ingress = 0``): trapezoid centred on
  ``t0``, ``f = 1 - depth`` on the flat bottom, total length ``duration`` from first to
  fourth contact, linear ingress and egress of length ``ingress`` each
  (``ingress <= duration / 2``; 0 is a box).
* ``step`` (``t_on``, ``before = 1``, ``after``): ``f = before`` for ``t < t_on``, else
  ``after``.
* ``flare`` (``t0``, ``amplitude``, ``rise = 0``, ``decay``): ``f = 1 + amplitude * s``
  with ``s = exp((t - t0) / rise)`` before ``t0`` (0 if ``rise = 0``) and
  ``exp(-(t - t0) / decay)`` after: peak ``1 + amplitude`` at ``t0``.
* ``table`` (``time``, ``flux``): linear interpolation, constant beyond the ends.
* ``file`` (``file``): ECSV or FITS table with columns ``time`` (s) and ``flux``
  (relative), used like ``table``.

Seeds
-----
``seed`` (an integer in ``[0, 2**63 - 1]``, so it fits TOML and FITS) is stored in the
scene and written to every output header.  Without one the scene is random:
:meth:`Scene.ensure_seed` draws a fresh seed from OS entropy and returns a scene that
records it, so any run can be repeated.
"""

import dataclasses
import difflib
import math
import numbers
import os
import secrets
from dataclasses import dataclass, field

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

import numpy as np

from noise.clock import Detector, Subarray, preset as detector_preset
from noise.errors import FileFormatError, ParameterError
from noise.params import NIRSPEC_DEFAULTS, ZERO_NOISE, NoiseParams

from scenesim.detector.nonlinearity import Nonlinearity
from scenesim.detector.ipc import ipc_kernel as _ipc_kernel

__all__ = [
    "PSFConfig",
    "StarConfig",
    "LightCurveConfig",
    "SourcesConfig",
    "ReadoutConfig",
    "EffectsConfig",
    "OutputConfig",
    "Scene",
    "load_scene",
    "parse_scene",
    "load_map",
    "NOISE_PRESETS",
]

#: Noise presets selectable with ``[noise] preset``.
NOISE_PRESETS = {"nirspec": NIRSPEC_DEFAULTS, "none": ZERO_NOISE}

_MAX_SEED = 2 ** 63 - 1
_FITS_EXT = (".fits", ".fit", ".fts", ".fits.gz", ".fit.gz", ".fts.gz")
_TABLE_EXT = (".ecsv",) + _FITS_EXT


# ============================================================================ helpers
def _suggest(word, candidates):
    close = difflib.get_close_matches(str(word), list(candidates), n=1, cutoff=0.6)
    return f"; did you mean {close[0]!r}?" if close else ""


def _check_keys(table, allowed, where, *, elsewhere=()):
    """Reject keys of ``table`` not in ``allowed``, suggesting the nearest valid name.

    ``elsewhere`` are keys that exist in the same table for another ``kind``: they get a
    message saying they do not apply rather than "unknown".
    """
    for key in table:
        if key in allowed:
            continue
        if key in elsewhere:
            raise ParameterError(
                f"key {key!r} does not apply in {where}; allowed keys here: "
                f"{', '.join(sorted(allowed))}")
        hint = _suggest(key, allowed)
        if not hint:
            hint = f"; allowed keys: {', '.join(sorted(allowed))}"
        raise ParameterError(f"unknown key {key!r} in {where}{hint}")


def _table(where, value):
    if not isinstance(value, dict):
        raise ParameterError(f"{where} must be a table, got {value!r}")
    return value


class _Section:
    """Context manager prefixing ParameterError/FileFormatError messages with a table."""

    def __init__(self, where):
        self.where = where

    def __enter__(self):
        return self

    def __exit__(self, typ, exc, tb):
        if isinstance(exc, (ParameterError, FileFormatError)):
            raise type(exc)(f"{self.where} {exc}") from exc
        return False


def _is_real(value):
    return isinstance(value, (numbers.Real, np.number)) and not isinstance(value, bool)


def _real(name, value, *, minimum=None, strict=False, maximum=None):
    """Finite float in range, or ParameterError naming ``name``."""
    if not _is_real(value):
        raise ParameterError(f"{name!r} must be a real number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise ParameterError(f"{name!r} must be finite, got {value!r}")
    if minimum is not None and (v <= minimum if strict else v < minimum):
        raise ParameterError(
            f"{name!r} must be {'>' if strict else '>='} {minimum:g}, got {value!r}")
    if maximum is not None and v > maximum:
        raise ParameterError(f"{name!r} must be <= {maximum:g}, got {value!r}")
    return v


def _int(name, value, *, minimum=None, maximum=None):
    if isinstance(value, bool) or not isinstance(value, (numbers.Integral, np.integer)):
        raise ParameterError(f"{name!r} must be an integer, got {value!r}")
    v = int(value)
    if minimum is not None and v < minimum:
        raise ParameterError(f"{name!r} must be >= {minimum}, got {value!r}")
    if maximum is not None and v > maximum:
        raise ParameterError(f"{name!r} must be <= {maximum}, got {value!r}")
    return v


def _bool(name, value):
    if not isinstance(value, (bool, np.bool_)):
        raise ParameterError(f"{name!r} must be true or false, got {value!r}")
    return bool(value)


def _str(name, value):
    if not isinstance(value, str):
        raise ParameterError(f"{name!r} must be a string, got {value!r}")
    return value


def _choice(name, value, allowed):
    if not isinstance(value, str) or value not in allowed:
        raise ParameterError(
            f"{name!r} must be one of {', '.join(repr(a) for a in allowed)}, "
            f"got {value!r}{_suggest(value, allowed)}")
    return value


def _existing_file(name, path, extensions=None):
    """Absolute path of an existing file, or FileFormatError naming ``name``."""
    path = os.path.abspath(os.path.expanduser(_str(name, path)))
    if extensions is not None and not path.lower().endswith(extensions):
        raise FileFormatError(
            f"{name!r} file {path!r} must have one of the extensions "
            f"{', '.join(extensions)}")
    if not os.path.isfile(path):
        raise FileFormatError(f"{name!r} file {path!r} does not exist")
    return path


def _resolve(base_dir, value):
    """Resolve a path string relative to ``base_dir``; other values pass through."""
    if isinstance(value, str):
        return os.path.abspath(os.path.join(base_dir, os.path.expanduser(value)))
    return value


def _rate_or_map(name, value, *, allow_zero=True, allow_none=False):
    """A finite scalar (>= 0 or > 0) or an existing FITS file path."""
    if value is None and allow_none:
        return None
    if isinstance(value, str):
        return _existing_file(name, value, _FITS_EXT)
    return _real(name, value, minimum=0.0, strict=not allow_zero)


def _image_hdu(name, path):
    """Index and (ny, nx) shape of the first 2-D image HDU of a FITS file."""
    from astropy.io import fits

    try:
        with fits.open(path) as hdul:
            for i, hdu in enumerate(hdul):
                if isinstance(hdu, (fits.PrimaryHDU, fits.ImageHDU, fits.CompImageHDU)) \
                        and hdu.header.get("NAXIS") == 2:
                    return i, (int(hdu.header["NAXIS2"]), int(hdu.header["NAXIS1"]))
    except OSError as exc:
        raise FileFormatError(f"{name!r} file {path!r} is not a readable FITS file: "
                              f"{exc}") from exc
    raise FileFormatError(f"{name!r} file {path!r} has no 2-D image HDU")


def _check_map_shape(name, path, detector):
    _, shape = _image_hdu(name, path)
    full = (detector.naxis2, detector.naxis1)
    if shape not in (full, detector.shape):
        raise FileFormatError(
            f"{name!r} map {path!r} has shape {shape} (ny, nx); expected the full array "
            f"{full} or the read-out shape {detector.shape}")


def _read_map_data(name, path):
    from astropy.io import fits

    index, _ = _image_hdu(name, path)
    with fits.open(path) as hdul:
        return np.array(hdul[index].data, dtype=np.float64)


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
        In the unit of the parameter (e-/s for rates, e- for the full well).

    Raises
    ------
    ParameterError
        A value is negative (or 0 when not allowed), NaN or infinite.
    FileFormatError
        The file is missing, not FITS, or has the wrong shape.
    """
    if not isinstance(value, str):
        return np.float64(_real(name, value, minimum=0.0, strict=not allow_zero))
    path = _existing_file(name, value, _FITS_EXT)
    data = _read_map_data(name, path)
    full = (detector.naxis2, detector.naxis1)
    if data.shape == full and data.shape != detector.shape:
        data = data[detector.y0:detector.y0 + detector.ny,
                    detector.x0:detector.x0 + detector.nx]
    elif data.shape != detector.shape:
        raise FileFormatError(
            f"{name!r} map {path!r} has shape {data.shape}; expected {full} or "
            f"{detector.shape}")
    bad = ~np.isfinite(data) | ((data < 0) if allow_zero else (data <= 0))
    if bad.any():
        y, x = np.argwhere(bad)[0]
        raise ParameterError(
            f"{name!r} map {path!r} must be finite and {'>=' if allow_zero else '>'} 0; "
            f"{int(bad.sum())} pixels are not, e.g. [{y}, {x}] = {float(data[y, x])!r}")
    return np.ascontiguousarray(data)


def _table_format(name, path):
    low = path.lower()
    if low.endswith(".ecsv"):
        return "ascii.ecsv"
    if low.endswith(_FITS_EXT):
        return "fits"
    raise FileFormatError(
        f"{name!r} table {path!r} must be ECSV (.ecsv) or FITS (.fits)")


def _read_table(name, path, required):
    """Read an ECSV/FITS table and check it has the ``required`` numeric columns."""
    from astropy.table import Table

    fmt = _table_format(name, path)
    try:
        table = Table.read(path, format=fmt)
    except Exception as exc:  # astropy raises many types for unreadable files
        raise FileFormatError(f"{name!r} table {path!r} cannot be read as {fmt}: "
                              f"{exc}") from exc
    for col in required:
        if col not in table.colnames:
            raise FileFormatError(
                f"{name!r} table {path!r} has no column {col!r}"
                f"{_suggest(col, table.colnames)} (columns: {', '.join(table.colnames)})")
        data = np.ma.getdata(table[col])
        if not np.issubdtype(data.dtype, np.number) or np.ma.is_masked(table[col]) \
                or not np.all(np.isfinite(data)):
            raise FileFormatError(
                f"{name!r} table {path!r}: column {col!r} must hold finite numbers "
                f"with no missing values")
    return table


# ======================================================================== dataclasses
_PSF_KEYS = {
    "gaussian": ("fwhm",),
    "airy": ("radius",),
    "image": ("file", "oversample", "normalize"),
}
_PSF_COMMON = ("kind", "min_rate")


@dataclass(frozen=True)
class PSFConfig:
    """Point-spread function of the point sources.

    Parameters
    ----------
    kind : {'gaussian', 'airy', 'image'}
        Circular Gaussian, Airy disc, or a user PSF image.
    fwhm : float
        Gaussian full width at half maximum, pixels (> 0).
    radius : float
        Airy disc radius of the first dark ring, pixels (> 0);
        FWHM = 0.8436 * radius (1.029 / 1.2197).
    file : str or None
        ``kind='image'``: FITS image of the PSF (absolute path once loaded).
    oversample : int or None
        ``kind='image'``: sub-pixels per detector pixel along each axis (>= 1);
        ``None`` takes the file's ``OVERSAMP`` keyword (1 if absent).
    normalize : bool
        ``kind='image'``: the image must sum to 1 within 1e-3 and is rescaled to
        exactly 1; if false it is used as given and the shortfall from 1 is flux
        outside the image (:class:`scenesim.sky.psf.ImagePSF`).
    min_rate : float
        PSF pixels with a rate below this are skipped, e-/s per pixel (>= 0).
    """

    kind: str = "gaussian"
    fwhm: float = 2.0
    radius: float = 2.5
    file: str | None = None
    oversample: int | None = None
    normalize: bool = True
    min_rate: float = 0.0

    def __post_init__(self):
        _choice("kind", self.kind, tuple(_PSF_KEYS))
        set_ = object.__setattr__
        set_(self, "fwhm", _real("fwhm", self.fwhm, minimum=0.0, strict=True))
        set_(self, "radius", _real("radius", self.radius, minimum=0.0, strict=True))
        if self.oversample is not None:
            set_(self, "oversample", _int("oversample", self.oversample, minimum=1))
        set_(self, "normalize", _bool("normalize", self.normalize))
        set_(self, "min_rate", _real("min_rate", self.min_rate, minimum=0.0))
        if self.kind == "image":
            if self.file is None:
                raise ParameterError("'file' is required for a PSF of kind 'image'")
            set_(self, "file", _existing_file("file", self.file, _FITS_EXT))
            _image_hdu("file", self.file)
        elif self.file is not None:
            raise ParameterError(
                f"'file' is only used by a PSF of kind 'image', got kind {self.kind!r}")

    def build(self):
        """The :mod:`scenesim.sky.psf` model: ``GaussianPSF``, ``AiryPSF`` or ``ImagePSF``."""
        from scenesim.sky import psf

        if self.kind == "gaussian":
            return psf.GaussianPSF(self.fwhm)
        if self.kind == "airy":
            return psf.AiryPSF(self.radius)
        return psf.ImagePSF.from_fits(self.file, self.oversample, self.normalize)


@dataclass(frozen=True)
class StarConfig:
    """One point source.

    Parameters
    ----------
    x, y : float
        Position, pixels, 0-based in the read-out image (pixel centres at integers).
    flux : float
        Total rate over the PSF, e-/s (>= 0).
    light_curve : str or None
        Name of an entry of ``SourcesConfig.light_curves``; ``None`` = constant.
    """

    x: float
    y: float
    flux: float
    light_curve: str | None = None

    def __post_init__(self):
        object.__setattr__(self, "x", _real("x", self.x))
        object.__setattr__(self, "y", _real("y", self.y))
        object.__setattr__(self, "flux", _real("flux", self.flux, minimum=0.0))
        if self.light_curve is not None:
            _str("light_curve", self.light_curve)


_LC_REQUIRED = {
    "transit": ("t0", "duration", "depth"),
    "step": ("t_on", "after"),
    "flare": ("t0", "amplitude", "decay"),
    "table": ("time", "flux"),
    "file": ("file",),
}
_LC_OPTIONAL = {
    "transit": ("ingress",),
    "step": ("before",),
    "flare": ("rise",),
    "table": (),
    "file": (),
}
_LC_SCALARS = ("t0", "duration", "depth", "ingress", "t_on", "before", "after",
               "amplitude", "rise", "decay")


def _check_series(name, time, flux):
    t = np.asarray(time, dtype=np.float64)
    f = np.asarray(flux, dtype=np.float64)
    if t.ndim != 1 or t.size < 2 or f.shape != t.shape:
        raise ParameterError(
            f"{name!r}: 'time' and 'flux' must be 1-d with the same length >= 2, got "
            f"{t.size} times and {f.size} fluxes")
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise ParameterError(f"{name!r}: 'time' must be finite and strictly increasing")
    if not np.all(np.isfinite(f)) or np.any(f < 0):
        raise ParameterError(f"{name!r}: 'flux' must be finite and >= 0")
    return t, f


@dataclass(frozen=True)
class LightCurveConfig:
    """A named light curve: a factor ``f(t) >= 0`` on a star's flux (module notes).

    Parameters
    ----------
    name : str
        Name used by ``StarConfig.light_curve``.
    kind : {'transit', 'step', 'flare', 'table', 'file'}
    t0 : float or None
        ``transit``: mid-transit time; ``flare``: peak time; s from exposure start.
    duration : float or None
        ``transit``: first to fourth contact, s (> 0).
    depth : float or None
        ``transit``: fractional depth, in [0, 1].
    ingress : float or None
        ``transit``: ingress (= egress) duration, s, in [0, duration / 2]; default 0.
    t_on : float or None
        ``step``: switch time, s.
    before, after : float or None
        ``step``: factors before and after ``t_on`` (>= 0); ``before`` default 1.
    amplitude : float or None
        ``flare``: peak factor minus 1 (>= 0).
    rise, decay : float or None
        ``flare``: e-folding times before (>= 0, default 0) and after (> 0) the peak, s.
    time, flux : tuple of float or None
        ``table``: sample times (s, strictly increasing) and factors (>= 0).
    file : str or None
        ``file``: ECSV/FITS table with columns ``time`` and ``flux``.
    """

    name: str
    kind: str
    t0: float | None = None
    duration: float | None = None
    depth: float | None = None
    ingress: float | None = None
    t_on: float | None = None
    before: float | None = None
    after: float | None = None
    amplitude: float | None = None
    rise: float | None = None
    decay: float | None = None
    time: tuple | None = None
    flux: tuple | None = None
    file: str | None = None

    def __post_init__(self):
        _str("name", self.name)
        kind = _choice("kind", self.kind, tuple(_LC_REQUIRED))
        used = set(_LC_REQUIRED[kind]) | set(_LC_OPTIONAL[kind])
        for f in dataclasses.fields(self):
            if f.name in ("name", "kind"):
                continue
            value = getattr(self, f.name)
            if f.name in _LC_REQUIRED[kind] and value is None:
                raise ParameterError(
                    f"light curve {self.name!r} of kind {kind!r} needs {f.name!r}")
            if f.name not in used and value is not None:
                raise ParameterError(
                    f"{f.name!r} does not apply to a light curve of kind {kind!r} "
                    f"(its keys: {', '.join(sorted(used))})")
        set_ = object.__setattr__
        for key in _LC_SCALARS:
            if getattr(self, key) is not None:
                set_(self, key, _real(key, getattr(self, key)))
        if kind == "transit":
            _real("duration", self.duration, minimum=0.0, strict=True)
            _real("depth", self.depth, minimum=0.0, maximum=1.0)
            if self.ingress is None:
                set_(self, "ingress", 0.0)
            _real("ingress", self.ingress, minimum=0.0, maximum=self.duration / 2)
        elif kind == "step":
            if self.before is None:
                set_(self, "before", 1.0)
            _real("before", self.before, minimum=0.0)
            _real("after", self.after, minimum=0.0)
        elif kind == "flare":
            _real("amplitude", self.amplitude, minimum=0.0)
            if self.rise is None:
                set_(self, "rise", 0.0)
            _real("rise", self.rise, minimum=0.0)
            _real("decay", self.decay, minimum=0.0, strict=True)
        elif kind == "table":
            if isinstance(self.time, str) or isinstance(self.flux, str):
                raise ParameterError("'time' and 'flux' must be lists of numbers")
            try:
                t, f = _check_series(self.name, self.time, self.flux)
            except (TypeError, ValueError) as exc:
                if isinstance(exc, ParameterError):
                    raise
                raise ParameterError(
                    f"light curve {self.name!r}: 'time' and 'flux' must be lists of "
                    f"numbers") from exc
            set_(self, "time", tuple(t.tolist()))
            set_(self, "flux", tuple(f.tolist()))
        else:  # file
            set_(self, "file", _existing_file("file", self.file, _TABLE_EXT))
            self.samples()

    def samples(self):
        """Sample times (s) and factors of a ``table`` or ``file`` light curve.

        Returns
        -------
        time, flux : ndarray, shape (n,), float64
        """
        if self.kind == "table":
            return np.array(self.time), np.array(self.flux)
        if self.kind == "file":
            table = _read_table("file", self.file, ("time", "flux"))
            return _check_series(self.name, np.ma.getdata(table["time"]),
                                 np.ma.getdata(table["flux"]))
        raise ParameterError(
            f"light curve {self.name!r} of kind {self.kind!r} has no samples; only "
            f"'table' and 'file' light curves do")


@dataclass(frozen=True)
class SourcesConfig:
    """Sources of charge.

    Parameters
    ----------
    dark_current : float or str
        Dark current, e-/s per pixel (>= 0), or the absolute path of a FITS map.
    hot_pixel_fraction : float
        Fraction of regular pixels that are hot, in [0, 1].
    hot_pixel_rate : float or (float, float)
        Extra dark current of a hot pixel, e-/s: one value, or ``(min, max)`` with hot
        pixels drawn log-uniformly in between (``0 < min <= max``).
    background : float or str
        Sky/thermal background, e-/s per pixel (>= 0), or the path of a FITS map.
    catalogue : str or None
        Absolute path of an ECSV/FITS table with columns ``x``, ``y``, ``flux`` and
        optionally ``light_curve`` (same meaning as :class:`StarConfig`).
    psf : PSFConfig
    stars : tuple of StarConfig
        Inline point sources.
    light_curves : tuple of LightCurveConfig
        Named light curves (unique names).
    """

    dark_current: float | str = 0.0
    hot_pixel_fraction: float = 0.0
    hot_pixel_rate: float | tuple = (1.0, 100.0)
    background: float | str = 0.0
    catalogue: str | None = None
    psf: PSFConfig = field(default_factory=PSFConfig)
    stars: tuple = ()
    light_curves: tuple = ()

    def __post_init__(self):
        set_ = object.__setattr__
        set_(self, "dark_current", _rate_or_map("dark_current", self.dark_current))
        set_(self, "background", _rate_or_map("background", self.background))
        set_(self, "hot_pixel_fraction",
             _real("hot_pixel_fraction", self.hot_pixel_fraction, minimum=0.0,
                   maximum=1.0))
        rate = self.hot_pixel_rate
        if isinstance(rate, (list, tuple, np.ndarray)):
            if len(rate) != 2:
                raise ParameterError(
                    f"'hot_pixel_rate' must be one rate or [min, max] (e-/s), "
                    f"got {rate!r}")
            lo = _real("hot_pixel_rate", rate[0], minimum=0.0, strict=True)
            hi = _real("hot_pixel_rate", rate[1], minimum=0.0, strict=True)
            if hi < lo:
                raise ParameterError(
                    f"'hot_pixel_rate' [min, max] needs min <= max, got {list(rate)!r}")
            set_(self, "hot_pixel_rate", (lo, hi))
        else:
            set_(self, "hot_pixel_rate", _real("hot_pixel_rate", rate, minimum=0.0))
        if not isinstance(self.psf, PSFConfig):
            raise ParameterError(f"'psf' must be a PSFConfig, got {self.psf!r}")
        stars = tuple(self.stars)
        for s in stars:
            if not isinstance(s, StarConfig):
                raise ParameterError(f"'stars' must hold StarConfig objects, got {s!r}")
        set_(self, "stars", stars)
        curves = tuple(self.light_curves)
        for c in curves:
            if not isinstance(c, LightCurveConfig):
                raise ParameterError(
                    f"'light_curves' must hold LightCurveConfig objects, got {c!r}")
        names = [c.name for c in curves]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ParameterError(f"light curve names must be unique, repeated: {dup}")
        set_(self, "light_curves", curves)
        for i, s in enumerate(stars):
            if s.light_curve is not None:
                self._check_curve(s.light_curve, f"stars[{i}]")
        if self.catalogue is not None:
            set_(self, "catalogue", _existing_file("catalogue", self.catalogue,
                                                   _TABLE_EXT))
            self._read_catalogue()

    def _check_curve(self, name, who):
        names = [c.name for c in self.light_curves]
        if name not in names:
            defined = f"; defined: {', '.join(map(repr, names))}" if names else \
                "; none is defined"
            hint = _suggest(name, names) or defined
            raise ParameterError(
                f"{who} uses light_curve {name!r}, which is not defined in "
                f"[sources.light_curves]{hint}")

    def _read_catalogue(self):
        table = _read_table("catalogue", self.catalogue, ("x", "y", "flux"))
        if np.any(np.ma.getdata(table["flux"]) < 0):
            raise ParameterError(
                f"'catalogue' {self.catalogue!r}: column 'flux' must be >= 0 (e-/s)")
        curves = np.full(len(table), "", dtype=object)
        if "light_curve" in table.colnames:
            col = table["light_curve"]
            filled = col.filled("") if hasattr(col, "filled") else col
            curves = np.array([str(v).strip() for v in filled], dtype=object)
            for name in sorted(set(curves) - {""}):
                self._check_curve(name, f"catalogue {self.catalogue!r}")
        return table, curves

    def light_curve(self, name):
        """The :class:`LightCurveConfig` called ``name``."""
        for c in self.light_curves:
            if c.name == name:
                return c
        self._check_curve(name, "lookup")

    def star_table(self):
        """Every point source: the inline stars, then the catalogue rows.

        Returns
        -------
        astropy.table.Table
            Columns ``x``, ``y`` (pixels, read-out image), ``flux`` (e-/s, float64) and
            ``light_curve`` (str, ``''`` for none).
        """
        from astropy.table import Table

        x = [s.x for s in self.stars]
        y = [s.y for s in self.stars]
        flux = [s.flux for s in self.stars]
        lc = [s.light_curve or "" for s in self.stars]
        if self.catalogue is not None:
            table, curves = self._read_catalogue()
            x += np.ma.getdata(table["x"]).astype(float).tolist()
            y += np.ma.getdata(table["y"]).astype(float).tolist()
            flux += np.ma.getdata(table["flux"]).astype(float).tolist()
            lc += list(curves)
        return Table({"x": np.array(x, dtype=np.float64),
                      "y": np.array(y, dtype=np.float64),
                      "flux": np.array(flux, dtype=np.float64),
                      "light_curve": np.array(lc, dtype=str)})

    @property
    def map_files(self):
        """``{name: path}`` of the parameters given as FITS maps."""
        return {k: getattr(self, k) for k in ("dark_current", "background")
                if isinstance(getattr(self, k), str)}


_READOUT_FORMS = ("pattern", "nframes", "ma_table", "resultants")


@dataclass(frozen=True)
class ReadoutConfig:
    """Readout pattern, in exactly one of four forms.

    Parameters
    ----------
    pattern : str or None
        Named JWST-like pattern (e.g. ``'RAPID'``, ``'MEDIUM8'``), with ``ngroups``.
    ngroups : int or None
        Groups per integration (``pattern`` and ``nframes`` forms), >= 1.
    nframes : int or None
        MULTIACCUM by numbers: frames averaged per group (>= 1), with ``ngroups``,
        ``groupgap`` (frames dropped between groups) and ``nskip`` (frames dropped after
        reset).
    groupgap, nskip : int
        ``nframes`` form only, >= 0.
    ma_table : tuple of (int, int) or None
        Roman-like multi-accumulation table of ``(first_read, nreads)`` pairs, reads
        counted from 0 after reset.
    resultants : tuple of tuple of int or None
        Explicit read indices averaged into each resultant.
    nints : int
        Integrations, >= 1.
    reset : {'rolling', 'global'}
        Reset scheme (``docs/CONVENTIONS.md``).
    name : str or None
        Label of a ``nframes`` / ``ma_table`` / ``resultants`` pattern.
    """

    pattern: str | None = None
    ngroups: int | None = None
    nframes: int | None = None
    groupgap: int = 0
    nskip: int = 0
    ma_table: tuple | None = None
    resultants: tuple | None = None
    nints: int = 1
    reset: str = "rolling"
    name: str | None = None

    def __post_init__(self):
        given = [f for f in _READOUT_FORMS if getattr(self, f) is not None]
        if len(given) != 1:
            raise ParameterError(
                f"the readout needs exactly one of {', '.join(map(repr, _READOUT_FORMS))}"
                f"; got {' and '.join(map(repr, given)) if given else 'none'}")
        set_ = object.__setattr__
        form = given[0]
        set_(self, "nints", _int("nints", self.nints, minimum=1))
        _choice("reset", self.reset, ("rolling", "global"))
        set_(self, "groupgap", _int("groupgap", self.groupgap, minimum=0))
        set_(self, "nskip", _int("nskip", self.nskip, minimum=0))
        if form != "nframes" and (self.groupgap or self.nskip):
            raise ParameterError(
                f"'groupgap' and 'nskip' apply only to the 'nframes' form, not {form!r}")
        if self.name is not None:
            _str("name", self.name)
            if form == "pattern":
                raise ParameterError("'name' is not used with 'pattern' (the pattern "
                                     "is its own name)")
        if form in ("pattern", "nframes"):
            if self.ngroups is None:
                raise ParameterError(f"'ngroups' is required with {form!r}")
            set_(self, "ngroups", _int("ngroups", self.ngroups, minimum=1))
        elif self.ngroups is not None:
            raise ParameterError(
                f"'ngroups' is implied by {form!r} (one resultant per entry); remove it")
        if form == "pattern":
            set_(self, "pattern", _str("pattern", self.pattern).strip().upper())
        elif form == "nframes":
            set_(self, "nframes", _int("nframes", self.nframes, minimum=1))
        elif form == "ma_table":
            rows = self._int_rows("ma_table", self.ma_table)
            for row in rows:
                if len(row) != 2 or row[0] < 0 or row[1] < 1:
                    raise ParameterError(
                        f"'ma_table' rows must be [first_read >= 0, nreads >= 1], "
                        f"got {list(row)!r}")
            set_(self, "ma_table", rows)
        else:
            rows = self._int_rows("resultants", self.resultants)
            for row in rows:
                if not row or min(row) < 0:
                    raise ParameterError(
                        f"'resultants' entries must be non-empty lists of read indices "
                        f">= 0, got {list(row)!r}")
            set_(self, "resultants", rows)

    @staticmethod
    def _int_rows(name, rows):
        if isinstance(rows, (str, dict)) or not hasattr(rows, "__iter__"):
            raise ParameterError(f"{name!r} must be a list of lists of integers, got "
                                 f"{rows!r}")
        out = []
        for row in rows:
            if isinstance(row, (str, dict)) or not hasattr(row, "__iter__"):
                raise ParameterError(
                    f"{name!r} must be a list of lists of integers, got row {row!r}")
            out.append(tuple(_int(name, v) for v in row))
        if not out:
            raise ParameterError(f"{name!r} must have at least one row")
        return tuple(out)

    @property
    def form(self):
        """Which form is used: ``'pattern'``, ``'nframes'``, ``'ma_table'`` or
        ``'resultants'``."""
        return next(f for f in _READOUT_FORMS if getattr(self, f) is not None)

    def build(self):
        """The :class:`scenesim.detector.readout.Readout` this configuration describes.

        Raises
        ------
        ParameterError
            Unknown pattern name, reads not strictly increasing, ... (raised by
            :mod:`scenesim.detector.readout`).
        """
        from scenesim.detector.readout import Readout

        kw = {"nints": self.nints, "reset_mode": self.reset}
        form = self.form
        if form == "pattern":
            return Readout.named(self.pattern, self.ngroups, **kw)
        if form == "nframes":
            return Readout.multiaccum(self.nframes, self.ngroups, groupgap=self.groupgap,
                                      nskip=self.nskip, name=self.name or "CUSTOM", **kw)
        if form == "ma_table":
            return Readout.from_ma_table([list(r) for r in self.ma_table],
                                         name=self.name or "MA_TABLE", **kw)
        return Readout.from_reads([list(r) for r in self.resultants],
                                  name=self.name or "CUSTOM", **kw)


@dataclass(frozen=True)
class EffectsConfig:
    """Detector effects on charge, and the ADC.

    Parameters
    ----------
    cosmic_ray_rate : float
        Cosmic-ray hits per cm^2 per s on the read-out area (>= 0; ~5 in space at L2).
    cosmic_ray_charge : (float, float)
        Log-normal charge per hit: median e- (> 0) and sigma of ln(charge) (>= 0).
    full_well : float, str or None
        Full-well capacity, e- (> 0), or a FITS map path; ``None`` = no saturation.
    nonlinearity : tuple of float
        ``(c2, c3, ...)`` of ``m = q + c2 q**2 + ...`` (:class:`effects.Nonlinearity`);
        empty = linear.  Must be monotonic up to the full well, which it then requires.
    ipc_alpha, ipc_alpha_diag : float
        Nearest-neighbour and diagonal IPC coupling (:func:`effects.ipc_kernel`).
    ipc_kernel : tuple of 3 tuples of 3 floats, or None
        Explicit 3x3 kernel (>= 0, sum 1) instead of ``ipc_alpha``.
    flat : float or str
        Relative QE (>= 0), scalar or FITS map path; multiplies all rates.
    gain : float
        e-/DN (> 0).
    adc_bits : int
        ADC resolution, 1 to 16 (the exposure stores uint16 resultants).
    """

    cosmic_ray_rate: float = 0.0
    cosmic_ray_charge: tuple = (1000.0, 0.7)
    full_well: float | str | None = None
    nonlinearity: tuple = ()
    ipc_alpha: float = 0.0
    ipc_alpha_diag: float = 0.0
    ipc_kernel: tuple | None = None
    flat: float | str = 1.0
    gain: float = 1.0
    adc_bits: int = 16

    def __post_init__(self):
        set_ = object.__setattr__
        set_(self, "cosmic_ray_rate",
             _real("cosmic_ray_rate", self.cosmic_ray_rate, minimum=0.0))
        crc = self.cosmic_ray_charge
        if isinstance(crc, str) or not hasattr(crc, "__len__") or len(crc) != 2:
            raise ParameterError(
                f"'cosmic_ray_charge' must be [median_e, sigma_ln], got {crc!r}")
        set_(self, "cosmic_ray_charge",
             (_real("cosmic_ray_charge", crc[0], minimum=0.0, strict=True),
              _real("cosmic_ray_charge", crc[1], minimum=0.0)))
        set_(self, "full_well",
             _rate_or_map("full_well", self.full_well, allow_zero=False,
                          allow_none=True))
        set_(self, "flat", _rate_or_map("flat", self.flat))
        set_(self, "gain", _real("gain", self.gain, minimum=0.0, strict=True))
        set_(self, "adc_bits", _int("adc_bits", self.adc_bits, minimum=1, maximum=16))
        coeffs = self.nonlinearity
        if _is_real(coeffs):
            coeffs = (coeffs,)
        if isinstance(coeffs, str) or not hasattr(coeffs, "__iter__") \
                or not all(_is_real(c) for c in coeffs):
            raise ParameterError(
                f"'nonlinearity' must be a list of coefficients [c2, c3, ...], "
                f"got {self.nonlinearity!r}")
        nl = Nonlinearity(tuple(coeffs))
        set_(self, "nonlinearity", nl.coeffs)
        if not nl.is_linear:
            if self.full_well is None:
                raise ParameterError(
                    f"'nonlinearity' {nl.coeffs!r} needs a 'full_well' (the polynomial "
                    f"is only used, and checked monotonic, below it; it turns over at "
                    f"{nl.q_hi:.6g} e-)")
            max_charge = self.full_well
            if isinstance(max_charge, str):
                max_charge = float(np.nanmax(_read_map_data("full_well", max_charge)))
            nl.check_monotonic(max_charge)
        for key in ("ipc_alpha", "ipc_alpha_diag"):
            set_(self, key, _real(key, getattr(self, key), minimum=0.0))
        if self.ipc_kernel is not None:
            if self.ipc_alpha or self.ipc_alpha_diag:
                raise ParameterError(
                    "give either 'ipc_alpha' (and 'ipc_alpha_diag') or 'ipc_kernel', "
                    "not both")
            from scenesim.detector.ipc import check_kernel

            try:
                k = check_kernel(self.ipc_kernel)
            except (TypeError, ValueError) as exc:
                if isinstance(exc, ParameterError):
                    raise
                raise ParameterError(
                    f"'ipc_kernel' must be a 3x3 list of numbers, got "
                    f"{self.ipc_kernel!r}") from exc
            # Stored renormalised to an exact unit sum.
            set_(self, "ipc_kernel", tuple(tuple(float(v) for v in row) for row in k))
        else:
            _ipc_kernel(self.ipc_alpha, self.ipc_alpha_diag)

    def nonlinearity_model(self):
        """The :class:`effects.Nonlinearity` (linear when no coefficients)."""
        return Nonlinearity(self.nonlinearity)

    def ipc(self):
        """The 3x3 IPC kernel (ndarray, float64), or ``None`` when there is no IPC."""
        if self.ipc_kernel is not None:
            k = np.array(self.ipc_kernel, dtype=np.float64)
            return None if k[1, 1] == 1.0 else k
        if self.ipc_alpha == 0 and self.ipc_alpha_diag == 0:
            return None
        return _ipc_kernel(self.ipc_alpha, self.ipc_alpha_diag)

    @property
    def map_files(self):
        """``{name: path}`` of the parameters given as FITS maps."""
        return {k: getattr(self, k) for k in ("full_well", "flat")
                if isinstance(getattr(self, k), str)}


_FITS_OUT = (".fits", ".fits.gz")


@dataclass(frozen=True)
class OutputConfig:
    """What to write.

    Parameters
    ----------
    path : str
        Exposure file (``.fits`` or ``.fits.gz``), as written in the scene: relative
        to the current working directory of the run, not to the scene file.
    truth : bool
        Also write ``<stem>_truth.fits`` (:attr:`truth_path`).
    save_charge : bool
        Put the noise-free charge resultants in the truth file (needs ``truth``).
    save_noise : bool
        Put the noise-only resultants in the truth file (needs ``truth``).
    ramp : bool
        Write the ramp (resultants) file; ``False`` keeps only the fitted slopes and
        needs ``fit``.
    fit : {'', 'cds', 'ols', 'gls'}
        Ramp fit to run after the simulation; ``''`` = none.
    refpix : {'none', 'median', 'jwst'}
        Reference-pixel correction applied before the fit.
    compare : bool
        Compare the fitted slopes with the injected truth (needs ``fit``).
    """

    path: str = "exposure.fits"
    truth: bool = True
    save_charge: bool = False
    save_noise: bool = False
    ramp: bool = True
    fit: str = ""
    refpix: str = "jwst"
    compare: bool = False

    def __post_init__(self):
        _str("path", self.path)
        if not self.path.strip() or not self.path.lower().endswith(_FITS_OUT):
            raise ParameterError(
                f"'path' must name a .fits or .fits.gz file, got {self.path!r}")
        for key in ("truth", "save_charge", "save_noise", "ramp", "compare"):
            object.__setattr__(self, key, _bool(key, getattr(self, key)))
        _choice("fit", self.fit, ("", "cds", "ols", "gls"))
        _choice("refpix", self.refpix, ("none", "median", "jwst"))
        if not self.ramp and not self.fit:
            raise ParameterError("'ramp = false' writes slopes only, so it needs 'fit' "
                                 "('cds', 'ols' or 'gls')")
        if self.compare and not self.fit:
            raise ParameterError("'compare = true' compares fitted slopes with the "
                                 "truth, so it needs 'fit' ('cds', 'ols' or 'gls')")
        for key in ("save_charge", "save_noise"):
            if getattr(self, key) and not self.truth:
                raise ParameterError(f"{key!r} writes into the truth file; it needs "
                                     f"'truth = true'")

    @property
    def truth_path(self):
        """``<stem>_truth.fits`` next to :attr:`path`."""
        low = self.path.lower()
        stem = self.path[:-len(".fits.gz")] if low.endswith(".fits.gz") else \
            self.path[:-len(".fits")]
        return stem + "_truth.fits"


@dataclass(frozen=True)
class Scene:
    """A complete, validated scene.

    Parameters
    ----------
    detector : noise.clock.Detector
    noise : noise.params.NoiseParams
    readout : ReadoutConfig
    sources : SourcesConfig
    effects : EffectsConfig
    output : OutputConfig
    seed : int or None
        Master seed in ``[0, 2**63 - 1]`` (``np.random.SeedSequence(seed)``); ``None``
        = fresh entropy, see :meth:`ensure_seed`.
    description : str
        Free text.
    path : str or None
        Absolute path of the scene file, ``None`` if built in memory.
    """

    detector: Detector
    noise: NoiseParams
    readout: ReadoutConfig
    sources: SourcesConfig
    effects: EffectsConfig
    output: OutputConfig
    seed: int | None = None
    description: str = ""
    path: str | None = None

    def __post_init__(self):
        for name, cls in (("detector", Detector), ("noise", NoiseParams),
                          ("readout", ReadoutConfig), ("sources", SourcesConfig),
                          ("effects", EffectsConfig), ("output", OutputConfig)):
            if not isinstance(getattr(self, name), cls):
                raise ParameterError(
                    f"{name!r} must be a {cls.__name__}, got {getattr(self, name)!r}")
        if self.seed is not None:
            object.__setattr__(self, "seed",
                               _int("seed", self.seed, minimum=0, maximum=_MAX_SEED))
        _str("description", self.description)
        if self.path is not None:
            _str("path", self.path)
        det = self.detector
        n_out = det.n_out_active
        for name in ("rd_noise", "u_pink", "acn"):
            value = getattr(self.noise, name)
            if isinstance(value, tuple) and len(value) != n_out:
                raise ParameterError(
                    f"[noise] {name!r} has {len(value)} per-output values but the "
                    f"detector reads through {n_out} output(s)")
        if self.noise.pca0_file is not None:
            path = _existing_file("pca0_file", self.noise.pca0_file, _FITS_EXT)
            with _Section("[noise]"):
                _check_map_shape("pca0_file", path, det)
        for where, files in (("[sources]", self.sources.map_files),
                             ("[effects]", self.effects.map_files)):
            with _Section(where):
                for name, path in files.items():
                    _check_map_shape(name, path, det)

    def replace(self, **changes):
        """Return a copy with ``changes`` applied (validated again)."""
        return dataclasses.replace(self, **changes)

    def ensure_seed(self):
        """This scene if it has a seed, else a copy with a fresh one from OS entropy.

        Returns
        -------
        Scene
            ``seed`` is an int in ``[0, 2**63 - 1]``; record it to repeat the run.
        """
        if self.seed is not None:
            return self
        return self.replace(seed=secrets.randbits(63))

    def to_header_cards(self):
        """``(key, value, comment)`` FITS cards: scene file name and seed."""
        name = os.path.basename(self.path) if self.path else "(in memory)"
        return [
            ("SCENE", name[:68], "scene file"),
            ("SEED", self.seed, "master seed (numpy SeedSequence entropy)"),
        ]


# ============================================================================ parsing
_TOP_KEYS = ("seed", "description", "detector", "noise", "readout", "sources",
             "effects", "output")
_DETECTOR_FIELDS = tuple(f.name for f in dataclasses.fields(Detector)
                         if f.name != "subarray")
_NOISE_FIELDS = tuple(f.name for f in dataclasses.fields(NoiseParams))


def _parse_detector(tab):
    where = "[detector]"
    _check_keys(tab, ("preset",) + _DETECTOR_FIELDS + ("subarray",), where)
    with _Section(where):
        name = _str("preset", tab.get("preset", "H2RG"))
        if "name" in tab:
            _str("name", tab["name"])
        if "reverse_scan" in tab:
            _bool("reverse_scan", tab["reverse_scan"])
        changes = {k: tab[k] for k in _DETECTOR_FIELDS if k in tab}
        det = detector_preset(name, **changes)
    if "subarray" in tab:
        where = "[detector.subarray]"
        sub = _table(where, tab["subarray"])
        _check_keys(sub, ("kind", "x0", "y0", "nx", "ny", "name"), where)
        with _Section(where):
            kind = _choice("kind", sub.get("kind", "window"), ("window", "stripe"))
            for key in ("ny",) + (("nx",) if kind == "window" else ()):
                if key not in sub:
                    raise ParameterError(f"{key!r} is required for a {kind!r} subarray")
            x0 = sub.get("x0", 0)
            nx = sub.get("nx", det.naxis1 if kind == "stripe" else None)
            subarray = Subarray(kind, x0, sub.get("y0", 0), nx, sub["ny"],
                                _str("name", sub.get("name", "")))
            det = dataclasses.replace(det, subarray=subarray)
    return det


def _parse_noise(tab, base_dir):
    where = "[noise]"
    _check_keys(tab, ("preset",) + _NOISE_FIELDS, where)
    with _Section(where):
        name = _choice("preset", tab.get("preset", "nirspec"), tuple(NOISE_PRESETS))
        changes = {k: tab[k] for k in _NOISE_FIELDS if k in tab}
        for key in ("rd_noise", "u_pink", "acn"):
            if isinstance(changes.get(key), list) and \
                    not all(_is_real(v) for v in changes[key]):
                raise ParameterError(
                    f"{key!r} per-output values must be numbers, got {changes[key]!r}")
        if "pca0_file" in changes:
            changes["pca0_file"] = _existing_file(
                "pca0_file", _resolve(base_dir, _str("pca0_file", changes["pca0_file"])),
                _FITS_EXT)
        try:
            return NOISE_PRESETS[name].replace(**changes)
        except (TypeError, ValueError) as exc:
            if isinstance(exc, (ParameterError, FileFormatError)):
                raise
            raise ParameterError(f"invalid value: {exc}") from exc


_READOUT_KEYS = ("pattern", "ngroups", "nframes", "groupgap", "nskip", "ma_table",
                 "resultants", "nints", "reset", "name")


def _parse_readout(tab):
    where = "[readout]"
    _check_keys(tab, _READOUT_KEYS, where)
    with _Section(where):
        given = [f for f in _READOUT_FORMS if f in tab]
        if len(given) != 1:
            raise ParameterError(
                f"needs exactly one of {', '.join(map(repr, _READOUT_FORMS))}; got "
                f"{' and '.join(map(repr, given)) if given else 'none'}")
        for key in ("groupgap", "nskip"):
            if key in tab and given[0] != "nframes":
                raise ParameterError(
                    f"{key!r} applies only with 'nframes', not with {given[0]!r}")
        return ReadoutConfig(**{k: tab[k] for k in _READOUT_KEYS if k in tab})


def _parse_psf(tab, base_dir):
    where = "[sources.psf]"
    all_keys = set(_PSF_COMMON).union(*_PSF_KEYS.values())
    _check_keys(tab, all_keys, where)
    with _Section(where):
        kind = _choice("kind", tab.get("kind", "gaussian"), tuple(_PSF_KEYS))
    allowed = _PSF_COMMON + _PSF_KEYS[kind]
    _check_keys(tab, allowed, f"{where} of kind {kind!r}", elsewhere=all_keys)
    values = dict(tab)
    if "file" in values:
        values["file"] = _resolve(base_dir, values["file"])
    with _Section(where):
        return PSFConfig(**values)


def _parse_light_curves(tab, base_dir):
    curves = []
    all_keys = {"kind"}.union(*_LC_REQUIRED.values(), *_LC_OPTIONAL.values())
    for name, spec in tab.items():
        where = f"[sources.light_curves.{name}]"
        spec = _table(where, spec)
        _check_keys(spec, all_keys, where)
        with _Section(where):
            if "kind" not in spec:
                raise ParameterError(f"'kind' is required (one of "
                                     f"{', '.join(map(repr, _LC_REQUIRED))})")
            kind = _choice("kind", spec["kind"], tuple(_LC_REQUIRED))
        allowed = ("kind",) + _LC_REQUIRED[kind] + _LC_OPTIONAL[kind]
        _check_keys(spec, allowed, f"{where} of kind {kind!r}", elsewhere=all_keys)
        values = dict(spec)
        if "file" in values:
            values["file"] = _resolve(base_dir, values["file"])
        with _Section(where):
            curves.append(LightCurveConfig(name=name, **values))
    return tuple(curves)


_SOURCES_KEYS = ("dark_current", "hot_pixel_fraction", "hot_pixel_rate", "background",
                 "catalogue", "psf", "stars", "light_curves")


def _parse_sources(tab, base_dir):
    where = "[sources]"
    _check_keys(tab, _SOURCES_KEYS, where)
    values = {k: tab[k] for k in ("dark_current", "hot_pixel_fraction", "hot_pixel_rate",
                                  "background", "catalogue") if k in tab}
    for key in ("dark_current", "background", "catalogue"):
        if key in values:
            values[key] = _resolve(base_dir, values[key])
    if "psf" in tab:
        values["psf"] = _parse_psf(_table("[sources.psf]", tab["psf"]), base_dir)
    if "light_curves" in tab:
        values["light_curves"] = _parse_light_curves(
            _table("[sources.light_curves]", tab["light_curves"]), base_dir)
    if "stars" in tab:
        stars = tab["stars"]
        if not isinstance(stars, list):
            raise ParameterError(
                f"[sources] 'stars' must be an array of tables ([[sources.stars]]), "
                f"got {stars!r}")
        parsed = []
        for i, star in enumerate(stars):
            swhere = f"[[sources.stars]] #{i}"
            star = _table(swhere, star)
            _check_keys(star, ("x", "y", "flux", "light_curve"), swhere)
            with _Section(swhere):
                for key in ("x", "y", "flux"):
                    if key not in star:
                        raise ParameterError(f"{key!r} is required")
                parsed.append(StarConfig(**star))
        values["stars"] = tuple(parsed)
    with _Section(where):
        return SourcesConfig(**values)


_EFFECTS_KEYS = tuple(f.name for f in dataclasses.fields(EffectsConfig))


def _parse_effects(tab, base_dir):
    where = "[effects]"
    _check_keys(tab, _EFFECTS_KEYS, where)
    with _Section(where):
        if "ipc_kernel" in tab and ("ipc_alpha" in tab or "ipc_alpha_diag" in tab):
            raise ParameterError("give either 'ipc_alpha' (and 'ipc_alpha_diag') or "
                                 "'ipc_kernel', not both")
        values = dict(tab)
        for key in ("full_well", "flat"):
            if key in values:
                values[key] = _resolve(base_dir, values[key])
        return EffectsConfig(**values)


_OUTPUT_KEYS = tuple(f.name for f in dataclasses.fields(OutputConfig))


def _parse_output(tab):
    where = "[output]"
    _check_keys(tab, _OUTPUT_KEYS, where)
    with _Section(where):
        return OutputConfig(**tab)


def _parse(mapping, base_dir, path):
    top = _table("the scene", mapping)
    _check_keys(top, _TOP_KEYS, "the top level of the scene")
    base_dir = os.path.abspath(os.fspath(base_dir))
    sections = {}
    for key in ("detector", "noise", "readout", "sources", "effects", "output"):
        sections[key] = _table(f"[{key}]", top.get(key, {}))
    if "readout" not in top:
        raise ParameterError(
            f"the scene needs a [readout] table with one of "
            f"{', '.join(map(repr, _READOUT_FORMS))}")
    seed = top.get("seed")
    description = top.get("description", "")
    scene = Scene(
        detector=_parse_detector(sections["detector"]),
        noise=_parse_noise(sections["noise"], base_dir),
        readout=_parse_readout(sections["readout"]),
        sources=_parse_sources(sections["sources"], base_dir),
        effects=_parse_effects(sections["effects"], base_dir),
        output=_parse_output(sections["output"]),
        seed=seed,
        description=description,
        path=path,
    )
    with _Section("[readout]"):
        scene.readout.build()
    if scene.sources.psf.kind == "image":
        with _Section("[sources.psf]"):
            scene.sources.psf.build()
    return scene


def parse_scene(mapping, *, base_dir="."):
    """Validate a scene given as a mapping (e.g. the result of ``tomllib.load``).

    Parameters
    ----------
    mapping : dict
        Tables and keys as in a scene file.
    base_dir : str or path-like, keyword-only
        Directory that relative file paths in the scene are resolved against.

    Returns
    -------
    Scene
        With ``path=None``.

    Raises
    ------
    ParameterError
        Unknown key (with the nearest valid name), bad type or value, inconsistent
        settings, or a readout that :mod:`scenesim.detector.readout` rejects.
    FileFormatError
        A file named by the scene is missing or has the wrong layout.
    """
    return _parse(mapping, base_dir, None)


def load_scene(path):
    """Read and validate a TOML scene file.

    Parameters
    ----------
    path : str or path-like
        The scene file.  Relative paths inside it are resolved against its directory.

    Returns
    -------
    Scene
        With ``path`` the absolute path of the file.

    Raises
    ------
    FileFormatError
        The file is missing or not valid TOML, or a file it names is missing or
        malformed.
    ParameterError
        As :func:`parse_scene`.  Messages start with the scene file's path.
    """
    path = os.path.abspath(os.fspath(path))
    try:
        with open(path, "rb") as fh:
            mapping = tomllib.load(fh)
    except FileNotFoundError as exc:
        raise FileFormatError(f"scene file {path!r} does not exist") from exc
    except OSError as exc:
        raise FileFormatError(f"scene file {path!r} cannot be read: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise FileFormatError(f"scene file {path!r} is not valid TOML: {exc}") from exc
    try:
        return _parse(mapping, os.path.dirname(path), path)
    except (ParameterError, FileFormatError) as exc:
        raise type(exc)(f"{path}: {exc}") from exc
