"""The scene's frozen dataclasses: what each table of a scene file accepts.

Each class validates its own values in ``__post_init__`` (types, ranges, the keys of
each ``kind``, cross-checks within the table), so a scene built in memory is checked
as one read from a file.  They do no file I/O beyond checking that a named file
exists: the contents of the files (map shapes, catalogue columns and light-curve
names, light-curve tables, the PSF image) are checked once, when a scene is loaded
(:func:`scenesim.scene.parse.check_files`), and again by the readers when a run uses
them.  So ``dataclasses.replace`` on a scene or on one of its tables never re-reads a
file.

Every key, its unit and its default are listed in the :mod:`scenesim.scene` package
docstring.
"""

import dataclasses
import json
import math
import os
import re
import secrets
from dataclasses import dataclass, field

import numpy as np
from astropy.io import fits
from astropy.table import MaskedColumn, Table, vstack

from noise.clock import Detector
from noise.errors import FileFormatError, ParameterError, ParameterTypeError
from noise.params import NoiseParams
from noise.streams import MAX_SEED as SEED_MAX
from noise.validate import (check_bool, check_choice, check_existing_file, check_float,
                            check_int, check_str, describe, is_real, is_sequence, suggest)

from scenesim.detector.ipc import check_kernel, ipc_kernel as _kernel_from_alpha
from scenesim.detector.nonlinearity import Nonlinearity
from scenesim.detector.readout import MAX_READS, Readout, check_pattern_detector
from scenesim.calib.refpix import applied_scheme
from scenesim.engine import MAX_CHARGE
from scenesim.rampfit.times import MAX_READ_TIME
from scenesim.outputs import derived_path
from scenesim.pipelines.instrument import InstrumentConfig
from scenesim.sky.lightcurve import MAX_TIME as LC_MAX_TIME, LightCurve
from scenesim.sky.maps import FITS_EXTENSIONS
from scenesim.sky.psf import AiryPSF, GaussianPSF, ImagePSF
from scenesim.sky.rates import integration_span
from scenesim.sky.sources import read_catalogue
from scenesim.sky.tables import TABLE_EXTENSIONS

__all__ = [
    "PSFConfig",
    "StarConfig",
    "LightCurveConfig",
    "SourcesConfig",
    "ReadoutConfig",
    "EffectsConfig",
    "OutputConfig",
    "Scene",
    "PSF_KEYS",
    "PSF_COMMON_KEYS",
    "LIGHT_CURVE_REQUIRED",
    "LIGHT_CURVE_OPTIONAL",
    "READOUT_FORMS",
    "MAX_SEED",
    "check_nonlinearity_range",
    "RENDER_COLUMNS",
]

#: Largest seed: fits a signed 64-bit integer (TOML and FITS).
MAX_SEED = SEED_MAX


def curve_table(name):
    """The TOML table of light curve ``name`` as a message shows it:
    ``[sources.light_curves.tr]``, or with the name quoted (and escaped) where it is
    not a bare key: ``[sources.light_curves."SN 1"]``."""
    if re.fullmatch(r"[A-Za-z0-9_-]+", name):
        return f"[sources.light_curves.{name}]"
    return f"[sources.light_curves.{json.dumps(name)}]"


def _rate_or_map(name, value, *, allow_zero=True, allow_none=False):
    """A finite scalar (>= 0 or > 0) or the absolute path of an existing FITS file."""
    if value is None and allow_none:
        return None
    if isinstance(value, str):
        return check_existing_file(name, value, FITS_EXTENSIONS)
    return check_float(name, value, minimum=0.0, strict_min=not allow_zero)


# =========================================================================== PSF
#: Keys of each PSF kind (besides :data:`PSF_COMMON_KEYS`).
PSF_KEYS = {
    "gaussian": ("fwhm",),
    "airy": ("radius",),
    "image": ("file", "oversample", "normalize"),
}
#: Keys every PSF kind accepts.
PSF_COMMON_KEYS = ("kind", "min_rate")


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
        check_choice("kind", self.kind, tuple(PSF_KEYS))
        set_ = object.__setattr__
        set_(self, "fwhm", check_float("fwhm", self.fwhm, minimum=0.0, strict_min=True))
        set_(self, "radius",
             check_float("radius", self.radius, minimum=0.0, strict_min=True))
        if self.kind == "gaussian":
            GaussianPSF(self.fwhm)             # its bounds (pixels)
        elif self.kind == "airy":
            AiryPSF(self.radius)
        if self.oversample is not None:
            set_(self, "oversample", check_int("oversample", self.oversample, minimum=1))
        set_(self, "normalize", check_bool("normalize", self.normalize))
        set_(self, "min_rate", check_float("min_rate", self.min_rate, minimum=0.0))
        if self.kind == "image":
            if self.file is None:
                raise ParameterError("'file' is required for a PSF of kind 'image'")
            set_(self, "file", check_existing_file("file", self.file, FITS_EXTENSIONS))
        elif self.file is not None:
            raise ParameterError(
                f"'file' is only used by a PSF of kind 'image', got kind {self.kind!r}")

    def build(self):
        """The :mod:`scenesim.sky.psf` model: ``GaussianPSF``, ``AiryPSF`` or ``ImagePSF``.

        An image PSF reads and checks its file here.
        """
        if self.kind == "gaussian":
            return GaussianPSF(self.fwhm)
        if self.kind == "airy":
            return AiryPSF(self.radius)
        try:
            return ImagePSF.from_fits(self.file, self.oversample, self.normalize)
        except (ParameterError, FileFormatError) as exc:
            raise type(exc)(f"'file': {exc}") from exc


# ======================================================================= stars
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
        object.__setattr__(self, "x", check_float("x", self.x))
        object.__setattr__(self, "y", check_float("y", self.y))
        object.__setattr__(self, "flux", check_float("flux", self.flux, minimum=0.0))
        if self.light_curve is not None:
            check_str("light_curve", self.light_curve, label=True)


# ================================================================ light curves
#: Required keys of each light-curve kind.
LIGHT_CURVE_REQUIRED = {
    "transit": ("t0", "duration", "depth"),
    "step": ("t_on", "after"),
    "flare": ("t0", "amplitude", "decay"),
    "table": ("time", "flux"),
    "file": ("file",),
}
#: Optional keys of each light-curve kind (defaults in :class:`LightCurveConfig`).
LIGHT_CURVE_OPTIONAL = {
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
    if not np.all(np.isfinite(t)):
        raise ParameterError(f"{name!r}: 'time' must be finite and strictly increasing")
    if np.any(np.abs(t) > LC_MAX_TIME):
        raise ParameterError(
            f"{name!r}: 'time' must lie within +-{LC_MAX_TIME:g} s of the exposure "
            f"start, got {float(t[np.argmax(np.abs(t))])!r}")
    if np.any(np.diff(t) <= 0):
        raise ParameterError(f"{name!r}: 'time' must be finite and strictly increasing")
    if not np.all(np.isfinite(f)) or np.any(f < 0):
        raise ParameterError(f"{name!r}: 'flux' must be finite and >= 0")
    return t, f


@dataclass(frozen=True)
class LightCurveConfig:
    """A named light curve: a factor ``f(t) >= 0`` on a star's flux.

    The shapes are those of :class:`scenesim.sky.lightcurve.LightCurve`, which
    :meth:`build` returns (see the :mod:`scenesim.scene` notes).

    Parameters
    ----------
    name : str
        Name used by ``StarConfig.light_curve`` and a catalogue's ``light_curve``.
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
    rise : float or None
        ``flare``: duration of the linear rise to the peak, s (>= 0, default 0).
    decay : float or None
        ``flare``: e-folding time of the exponential decay after the peak, s (> 0).
    time, flux : tuple of float or None
        ``table``: sample times (s, strictly increasing) and factors (>= 0).
    file : str or None
        ``file``: ECSV/FITS table with columns ``time`` and ``flux``, read by
        :meth:`scenesim.sky.lightcurve.LightCurve.from_file` (time units converted;
        ``flux`` without a unit or dimensionless).
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
        check_str("name", self.name, label=True)
        kind = check_choice("kind", self.kind, tuple(LIGHT_CURVE_REQUIRED))
        used = set(LIGHT_CURVE_REQUIRED[kind]) | set(LIGHT_CURVE_OPTIONAL[kind])
        for f in dataclasses.fields(self):
            if f.name in ("name", "kind"):
                continue
            value = getattr(self, f.name)
            if f.name in LIGHT_CURVE_REQUIRED[kind] and value is None:
                raise ParameterError(
                    f"light curve {self.name!r} of kind {kind!r} needs {f.name!r}")
            if f.name not in used and value is not None:
                raise ParameterError(
                    f"{f.name!r} does not apply to a light curve of kind {kind!r} "
                    f"(its keys: {', '.join(sorted(used))})")
        set_ = object.__setattr__
        for key in _LC_SCALARS:
            if getattr(self, key) is not None:
                set_(self, key, check_float(key, getattr(self, key)))
        if kind == "transit":
            check_float("duration", self.duration, minimum=0.0, strict_min=True)
            check_float("depth", self.depth, minimum=0.0, maximum=1.0)
            if self.ingress is None:
                set_(self, "ingress", 0.0)
            check_float("ingress", self.ingress, minimum=0.0, maximum=self.duration / 2)
        elif kind == "step":
            if self.before is None:
                set_(self, "before", 1.0)
            check_float("before", self.before, minimum=0.0)
            check_float("after", self.after, minimum=0.0)
        elif kind == "flare":
            check_float("amplitude", self.amplitude, minimum=0.0)
            if self.rise is None:
                set_(self, "rise", 0.0)
            check_float("rise", self.rise, minimum=0.0)
            check_float("decay", self.decay, minimum=0.0, strict_min=True)
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
        else:  # file: its table is read by build()
            set_(self, "file", check_existing_file("file", self.file, TABLE_EXTENSIONS))
        if kind in ("transit", "step", "flare"):
            # the breakpoints must be distinct floats (e.g. t0 = 1e300 with a 1 s
            # duration is not): build the curve now, naming the keys if it fails
            try:
                self.build()
            except ParameterError as exc:
                keys = LIGHT_CURVE_REQUIRED[kind] + LIGHT_CURVE_OPTIONAL[kind]
                given = ", ".join(f"{k!r} = {getattr(self, k)!r}" for k in keys)
                raise ParameterError(
                    f"light curve {self.name!r} ({given}) cannot be represented: "
                    f"{exc}") from exc

    def peak(self):
        """``(factor, key)``: the largest factor of an analytic or table curve and the
        key that sets it (``(None, None)`` for a ``file`` curve, whose table is read
        by :meth:`build`)."""
        if self.kind == "transit":
            return 1.0, "depth"
        if self.kind == "step":
            return (self.after, "after") if self.after > self.before else \
                (self.before, "before")
        if self.kind == "flare":
            return 1.0 + self.amplitude, "amplitude"
        if self.kind == "table":
            return max(self.flux), "flux"
        return None, None

    def build(self):
        """The :class:`scenesim.sky.lightcurve.LightCurve` this entry describes.

        A ``file`` light curve reads its file here
        (:meth:`~scenesim.sky.lightcurve.LightCurve.from_file`).
        """
        if self.kind == "transit":
            return LightCurve.transit(self.t0, self.duration, self.depth, self.ingress)
        if self.kind == "step":
            return LightCurve.step(self.t_on, before=self.before, after=self.after)
        if self.kind == "flare":
            return LightCurve.flare(self.t0, self.amplitude, self.rise, self.decay)
        if self.kind == "table":
            return LightCurve(self.time, self.flux)
        return LightCurve.from_file(self.file)


# ===================================================================== sources
#: Columns the rendering adds to a star in the truth's ``SOURCES`` table
#: (:func:`scenesim.sky.psf.render_point_sources`); a catalogue column of one of these
#: names is kept as ``catalogue_<name>``.
RENDER_COLUMNS = ("flux_on_array", "frac_on_array", "flux_lost_stamp", "stamp_radius",
                  "rendered")


def _check_fits_column(where, name, col):
    """Refuse, naming it, a catalogue column a FITS table cannot hold (the truth's
    ``SOURCES`` keeps it; found when the truth is written, the run would be lost)."""
    try:
        fits.BinTableHDU(Table([col], names=[name]))
    except Exception as exc:                 # astropy raises several types
        reason = " ".join(str(exc).split())[:200]
        raise FileFormatError(
            f"{where}: column {name!r} ({col.dtype}) cannot be written to the truth "
            f"file's SOURCES table (a FITS table): {reason}; remove it or give it "
            f"numbers or strings") from exc


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
        Absolute path of an ECSV/FITS table read by
        :func:`scenesim.sky.sources.read_catalogue`: columns ``x``, ``y``, ``flux`` and
        optionally ``light_curve`` (the name of one of ``light_curves``, as in
        :class:`StarConfig`).
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
             check_float("hot_pixel_fraction", self.hot_pixel_fraction, minimum=0.0,
                         maximum=1.0))
        rate = self.hot_pixel_rate
        if isinstance(rate, (list, tuple, np.ndarray)):
            if len(rate) != 2:
                raise ParameterError(
                    f"'hot_pixel_rate' must be one rate or [min, max] (e-/s), "
                    f"got {rate!r}")
            lo = check_float("hot_pixel_rate", rate[0], minimum=0.0, strict_min=True)
            hi = check_float("hot_pixel_rate", rate[1], minimum=0.0, strict_min=True)
            if hi < lo:
                raise ParameterError(
                    f"'hot_pixel_rate' [min, max] needs min <= max, got {list(rate)!r}")
            set_(self, "hot_pixel_rate", (lo, hi))
        else:
            # > 0, as for [min, max] (draw_hot_pixels refused 0 only at run time)
            set_(self, "hot_pixel_rate",
                 check_float("hot_pixel_rate", rate, minimum=0.0, strict_min=True))
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
            set_(self, "catalogue",
                 check_existing_file("catalogue", self.catalogue, TABLE_EXTENSIONS))

    def _check_curve(self, name, who):
        names = [c.name for c in self.light_curves]
        if name not in names:
            defined = f"; defined: {', '.join(map(repr, names))}" if names else \
                "; none is defined"
            hint = suggest(name, names) or defined
            raise ParameterError(
                f"{who} uses light_curve {name!r}, which is not defined in "
                f"[sources.light_curves]{hint}")

    def light_curve(self, name):
        """The :class:`LightCurveConfig` called ``name``."""
        for c in self.light_curves:
            if c.name == name:
                return c
        self._check_curve(name, "lookup")

    def star_table(self):
        """Every point source, in a fixed order: the inline stars (``[[sources.stars]]``,
        in the file's order), then the catalogue rows (in the catalogue's order).  So
        row ``i`` of the catalogue is row ``len(stars) + i``; the truth's ``SOURCES``
        keeps this order.

        Reads the catalogue (:func:`scenesim.sky.sources.read_catalogue`) and checks
        that each of its ``light_curve`` names is defined.

        Returns
        -------
        astropy.table.Table
            Columns ``x``, ``y`` (pixels, read-out image), ``flux`` (e-/s, float64) and
            ``light_curve`` (str, ``''`` for none); with a catalogue, first ``id`` (the
            catalogue's, ``0 .. n-1`` when it has none) and, last, the catalogue's other
            columns, both masked on the inline stars' rows.  A catalogue column named
            as a column the rendering adds (:data:`RENDER_COLUMNS`, case-insensitively)
            is kept as ``catalogue_<name>``.

        Raises
        ------
        FileFormatError, ParameterError
            As :func:`~scenesim.sky.sources.read_catalogue`; a catalogue row names an
            undefined light curve; a catalogue column the truth file cannot hold.
        """
        inline = Table({"x": np.array([s.x for s in self.stars], dtype=np.float64),
                        "y": np.array([s.y for s in self.stars], dtype=np.float64),
                        "flux": np.array([s.flux for s in self.stars], dtype=np.float64),
                        "light_curve": np.array([s.light_curve or "" for s in self.stars],
                                                dtype=str)})
        if self.catalogue is None:
            return inline
        where = f"catalogue {self.catalogue!r}"
        table = read_catalogue(self.catalogue)
        curves = [str(name) for name in table["light_curve"]]
        for name in sorted(set(curves) - {""}):
            self._check_curve(name, where)
        core = ("id", "x", "y", "flux", "light_curve")
        cat = Table({"id": table["id"], "x": np.asarray(table["x"], dtype=np.float64),
                     "y": np.asarray(table["y"], dtype=np.float64),
                     "flux": np.asarray(table["flux"], dtype=np.float64),
                     "light_curve": np.array(curves, dtype=str)})
        lower = {name.lower() for name in table.colnames}
        for name in table.colnames:
            if name in core:
                continue
            out = f"catalogue_{name}" if name.lower() in RENDER_COLUMNS else name
            if out != name and out.lower() in lower:
                raise FileFormatError(
                    f"{where}: column {name!r} is named as a column the truth's SOURCES "
                    f"table adds ({', '.join(RENDER_COLUMNS)}), and its other name "
                    f"{out!r} is taken too; rename one of them")
            _check_fits_column(where, name, table[name])
            cat[out] = table[name]
        if not len(inline):
            return cat
        n = len(inline)
        for name in cat.colnames:
            if name not in inline.colnames:
                col = cat[name]
                inline[name] = MaskedColumn(
                    np.zeros((n,) + col.shape[1:], dtype=col.dtype),
                    mask=np.ones((n,) + col.shape[1:], dtype=bool), unit=col.unit)
        out = vstack([inline[cat.colnames], cat], join_type="exact",
                     metadata_conflicts="silent")
        if out["id"].dtype.kind in "iu":        # a null value no catalogue id takes
            info = np.iinfo(out["id"].dtype)
            ids = set(np.asarray(cat["id"]).tolist())
            out["id"].fill_value = next(v for v in (info.min, info.max, -1, 0)
                                        if v not in ids)
        return out

    @property
    def map_files(self):
        """``{name: path}`` of the parameters given as FITS maps."""
        return {k: getattr(self, k) for k in ("dark_current", "background")
                if isinstance(getattr(self, k), str)}


# ===================================================================== readout
#: The four ways to give a readout; a scene uses exactly one.
READOUT_FORMS = ("pattern", "nframes", "ma_table", "resultants")


def _int_rows(name, rows):
    if isinstance(rows, (str, dict)) or not hasattr(rows, "__iter__"):
        raise ParameterError(f"{name!r} must be a list of lists of integers, got "
                             f"{rows!r}")
    out = []
    for row in rows:
        if isinstance(row, (str, dict)) or not hasattr(row, "__iter__"):
            raise ParameterError(
                f"{name!r} must be a list of lists of integers, got row {row!r}")
        out.append(tuple(check_int(name, v) for v in row))
    if not out:
        raise ParameterError(f"{name!r} must have at least one row")
    return tuple(out)


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
        given = [f for f in READOUT_FORMS if getattr(self, f) is not None]
        if len(given) != 1:
            raise ParameterError(
                f"the readout needs exactly one of {', '.join(map(repr, READOUT_FORMS))}"
                f"; got {' and '.join(map(repr, given)) if given else 'none'}")
        set_ = object.__setattr__
        form = given[0]
        set_(self, "nints", check_int("nints", self.nints, minimum=1))
        check_choice("reset", self.reset, ("rolling", "global"))
        set_(self, "groupgap", check_int("groupgap", self.groupgap, minimum=0))
        set_(self, "nskip", check_int("nskip", self.nskip, minimum=0))
        if form != "nframes" and (self.groupgap or self.nskip):
            raise ParameterError(
                f"'groupgap' and 'nskip' apply only to the 'nframes' form, not {form!r}")
        if self.name is not None:
            check_str("name", self.name, label=True)
            if form == "pattern":
                raise ParameterError("'name' is not used with 'pattern' (the pattern "
                                     "is its own name)")
        if form in ("pattern", "nframes"):
            if self.ngroups is None:
                raise ParameterError(f"'ngroups' is required with {form!r}")
            set_(self, "ngroups", check_int("ngroups", self.ngroups, minimum=1))
        elif self.ngroups is not None:
            raise ParameterError(
                f"'ngroups' is implied by {form!r} (one resultant per entry); remove it")
        if form == "pattern":
            set_(self, "pattern", check_str("pattern", self.pattern).strip().upper())
        elif form == "nframes":
            set_(self, "nframes", check_int("nframes", self.nframes, minimum=1))
        elif form == "ma_table":
            rows = _int_rows("ma_table", self.ma_table)
            for row in rows:
                if len(row) != 2 or row[0] < 0 or row[1] < 1:
                    raise ParameterError(
                        f"'ma_table' rows must be [first_read >= 0, nreads >= 1], "
                        f"got {list(row)!r}")
                if row[0] + row[1] > MAX_READS:
                    raise ParameterError(
                        f"'ma_table' row {list(row)!r} reads up to read "
                        f"{row[0] + row[1] - 1}; at most {MAX_READS} reads per "
                        f"integration are allowed")
            set_(self, "ma_table", rows)
        else:
            rows = _int_rows("resultants", self.resultants)
            for row in rows:
                if not row or min(row) < 0 or max(row) >= MAX_READS:
                    raise ParameterError(
                        f"'resultants' entries must be non-empty lists of read indices "
                        f"in [0, {MAX_READS - 1}], got {describe(list(row))}")
            set_(self, "resultants", rows)

    @property
    def form(self):
        """Which form is used: ``'pattern'``, ``'nframes'``, ``'ma_table'`` or
        ``'resultants'``."""
        return next(f for f in READOUT_FORMS if getattr(self, f) is not None)

    def build(self):
        """The :class:`scenesim.detector.readout.Readout` this configuration describes.

        Raises
        ------
        ParameterError
            Unknown pattern name, reads not strictly increasing, ... (raised by
            :mod:`scenesim.detector.readout`).
        """
        kw = {"nints": self.nints, "reset_mode": self.reset}
        form = self.form
        if form == "pattern":
            return Readout.named(self.pattern, self.ngroups, **kw)
        if form == "nframes":
            return Readout.multiaccum(self.nframes, self.ngroups, groupgap=self.groupgap,
                                      nskip=self.nskip, name=self.name or "CUSTOM", **kw)
        # the library's argument names, as the scene's keys
        arg, key = {"ma_table": ("'table'", "'ma_table'"),
                    "resultants": ("'read_lists'", "'resultants'")}[form]
        try:
            if form == "ma_table":
                return Readout.from_ma_table([list(r) for r in self.ma_table],
                                             name=self.name or "MA_TABLE", **kw)
            return Readout.from_reads([list(r) for r in self.resultants],
                                      name=self.name or "CUSTOM", **kw)
        except ParameterError as exc:
            raise type(exc)(str(exc).replace(arg, key)) from exc


# ===================================================================== effects
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
        ``(c2, c3, ...)`` of ``m = q + c2 q**2 + ...``
        (:class:`scenesim.detector.nonlinearity.Nonlinearity`); empty = linear.  Must
        be monotonic up to the full well, which it then requires (a scalar full well is
        checked here, a map when the scene is loaded).
    ipc_alpha, ipc_alpha_diag : float
        Nearest-neighbour and diagonal IPC coupling
        (:func:`scenesim.detector.ipc.ipc_kernel`).
    ipc_kernel : tuple of 3 tuples of 3 floats, or None
        Explicit 3x3 kernel (>= 0, sum 1) instead of ``ipc_alpha``.
    flat : float or str
        Relative response (>= 0), scalar or FITS map path (how it acts:
        :mod:`scenesim.detector.flat`).
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
             check_float("cosmic_ray_rate", self.cosmic_ray_rate, minimum=0.0))
        crc = self.cosmic_ray_charge
        if not is_sequence(crc) or len(crc) != 2:
            raise ParameterError(
                f"'cosmic_ray_charge' must be [median_e, sigma_ln], got {crc!r}")
        set_(self, "cosmic_ray_charge",
             (check_float("cosmic_ray_charge[0] (median_e)", crc[0], minimum=0.0,
                          strict_min=True),
              check_float("cosmic_ray_charge[1] (sigma_ln)", crc[1], minimum=0.0)))
        median, sigma_ln = self.cosmic_ray_charge
        # the log-normal's mean median * exp(sigma_ln**2 / 2) (what the cosmic-ray
        # model takes) must be a charge the engine can count; the check is on logs,
        # so no overflow warning for a wide sigma
        log_mean = math.log(median) + sigma_ln * sigma_ln / 2
        if log_mean > math.log(MAX_CHARGE):
            raise ParameterError(
                f"'cosmic_ray_charge' = {[median, sigma_ln]!r} ([median_e, sigma_ln]) "
                f"has a mean charge per hit median * exp(sigma_ln**2 / 2) = "
                f"exp({log_mean:.4g}) e-; at most {MAX_CHARGE:.3g} e- (2**53) is allowed "
                f"(sigma_ln <= {math.sqrt(2 * max(math.log(MAX_CHARGE / median), 0)):.3g} "
                f"for this median)")
        set_(self, "full_well",
             _rate_or_map("full_well", self.full_well, allow_zero=False,
                          allow_none=True))
        set_(self, "flat", _rate_or_map("flat", self.flat))
        set_(self, "gain", check_float("gain", self.gain, minimum=0.0, strict_min=True))
        set_(self, "adc_bits", check_int("adc_bits", self.adc_bits, minimum=1, maximum=16))
        coeffs = self.nonlinearity
        if is_real(coeffs):
            coeffs = (coeffs,)
        if isinstance(coeffs, str) or not hasattr(coeffs, "__iter__") \
                or not all(is_real(c) for c in coeffs):
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
            if not isinstance(self.full_well, str):      # a map: checked on loading
                check_nonlinearity_range(nl, self.full_well)
        for key in ("ipc_alpha", "ipc_alpha_diag"):
            set_(self, key, check_float(key, getattr(self, key), minimum=0.0))
        if self.ipc_kernel is not None:
            if self.ipc_alpha or self.ipc_alpha_diag:
                raise ParameterError(
                    "give either 'ipc_alpha' (and 'ipc_alpha_diag') or 'ipc_kernel', "
                    "not both")
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
            _kernel_from_alpha(self.ipc_alpha, self.ipc_alpha_diag)

    def nonlinearity_model(self):
        """The :class:`~scenesim.detector.nonlinearity.Nonlinearity` (linear when no
        coefficients)."""
        return Nonlinearity(self.nonlinearity)

    def ipc(self):
        """The 3x3 IPC kernel (ndarray, float64), or ``None`` when there is no IPC."""
        if self.ipc_kernel is not None:
            k = np.array(self.ipc_kernel, dtype=np.float64)
            return None if k[1, 1] == 1.0 else k
        if self.ipc_alpha == 0 and self.ipc_alpha_diag == 0:
            return None
        return _kernel_from_alpha(self.ipc_alpha, self.ipc_alpha_diag)

    @property
    def map_files(self):
        """``{name: path}`` of the parameters given as FITS maps."""
        return {k: getattr(self, k) for k in ("full_well", "flat")
                if isinstance(getattr(self, k), str)}


def check_nonlinearity_range(nl, full_well):
    """Raise unless the polynomial ``nl`` is monotonic up to ``full_well`` (e-) and
    maps it to a signal of at most :data:`scenesim.engine.MAX_CHARGE` (a huge positive
    coefficient would send every charged pixel to inf in the float32 frames)."""
    try:
        nl.check_monotonic(full_well)
    except ParameterError as exc:
        raise ParameterError(f"{exc} (given 'full_well' = {full_well!r} e-)") from exc
    with np.errstate(over="ignore", invalid="ignore"):
        top = float(nl.apply(full_well))
    if not top <= MAX_CHARGE:
        raise ParameterError(
            f"'nonlinearity' coefficients {nl.coeffs!r} map the 'full_well' of "
            f"{float(full_well):g} e- to {top:.3g} e-; the measured signal must stay "
            f"<= {MAX_CHARGE:.3g} e- (2**53)")


# ====================================================================== output
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
        Also write ``<stem>_truth.fits`` (:attr:`truth_path`; ``<stem>_truth.fits.gz``
        for a ``.fits.gz`` path).
    save_charge : bool
        Put the noise-free signal resultants (the charge after saturation,
        nonlinearity and IPC) in the truth file (needs ``truth``).
    save_noise : bool
        Put the noise-only resultants in the truth file (needs ``truth``).
    ramp : bool
        Write the ramp (resultants) file; ``False`` keeps only the fitted slopes and
        needs ``fit``.
    fit : {'', 'cds', 'ols', 'gls'}
        Ramp fit to run after the simulation; ``''`` = none.
    refpix : {'none', 'median', 'jwst', 'irs2'}
        Reference-pixel correction applied before the fit (``'irs2'``: interleaved
        reference samples, an IRS2 detector such as preset ``'NIRSPEC-IRS2'``).
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
        check_str("path", self.path)
        if not self.path.strip() or not self.path.lower().endswith(_FITS_OUT):
            raise ParameterError(
                f"'path' must name a .fits or .fits.gz file, got {self.path!r}")
        for key in ("truth", "save_charge", "save_noise", "ramp", "compare"):
            object.__setattr__(self, key, check_bool(key, getattr(self, key)))
        check_choice("fit", self.fit, ("", "cds", "ols", "gls"))
        check_choice("refpix", self.refpix, ("none", "median", "jwst", "irs2"))
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
        """``<stem>_truth.fits`` next to :attr:`path`, with its whole extension
        (``out.fits.gz`` -> ``out_truth.fits.gz``;
        :func:`scenesim.outputs.derived_path`)."""
        return derived_path(self.path, "_truth")


# ======================================================================= scene
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
    instrument : scenesim.pipelines.instrument.InstrumentConfig
        The JWST identity of the exposure (``[instrument]``; every field optional).
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
    instrument: InstrumentConfig = field(default_factory=InstrumentConfig)

    def __post_init__(self):
        for name, cls in (("detector", Detector), ("noise", NoiseParams),
                          ("readout", ReadoutConfig), ("sources", SourcesConfig),
                          ("effects", EffectsConfig), ("output", OutputConfig),
                          ("instrument", InstrumentConfig)):
            if not isinstance(getattr(self, name), cls):
                raise ParameterTypeError(
                    f"{name!r} must be a {cls.__name__}, got "
                    f"{describe(getattr(self, name))}")
        if self.seed is not None:
            object.__setattr__(self, "seed",
                               check_int("seed", self.seed, minimum=0, maximum=MAX_SEED))
        check_str("description", self.description)
        if self.path is not None:
            check_str("path", self.path)
        eff = self.effects
        try:
            # per-output values, f_min below every Nyquist frequency, no noise
            # clipped at the ADC (noise.params module notes)
            self.noise.check_detector(self.detector, where="[detector]")
            # a window takes its output's value of full-array per-output amplitudes
            object.__setattr__(self, "noise", self.noise.for_detector(self.detector))
            self.noise.check_adc(eff.gain, eff.adc_bits, self.detector)
        except ParameterError as exc:
            table = "[effects]" if str(exc).startswith("'gain'") else "[noise]"
            raise type(exc)(f"{table} {exc}") from exc
        try:
            ro = self.readout
            check_pattern_detector(ro.pattern or ro.name, self.detector,
                                   key="pattern" if ro.pattern else "name")
        except ParameterError as exc:
            raise type(exc)(f"[readout] {exc}") from exc
        try:        # 'median' without reference rows, 'irs2' without interleaving
            applied_scheme(self.detector, self.output.refpix)
        except ParameterError as exc:
            raise type(exc)(f"[output] {exc}") from exc
        self._check_charge()

    def _check_charge(self):
        """Refuse scalar rates whose pixel would collect more than
        :data:`scenesim.engine.MAX_CHARGE` in one integration (FITS maps, catalogue
        rows, ``file`` light curves and the sum in a pixel are checked when the run
        loads them, before any work: :func:`scenesim.sky.rates.scene_rates`)."""
        try:
            ro = self.readout.build()
        except ParameterError as exc:
            raise type(exc)(f"[readout] {exc}") from exc
        t_int, span = integration_span(self.detector, ro)
        src, eff = self.sources, self.effects
        flat = eff.flat if not isinstance(eff.flat, str) else None
        if self.output.fit and t_int > MAX_READ_TIME:
            raise ParameterError(
                f"[output] 'fit' = {self.output.fit!r}: an integration lasts {t_int:.6g} "
                f"s ({span}); the fitter takes read times up to {MAX_READ_TIME:g} s")

        def check(where, key, rate, what):
            if rate > 0 and not rate * t_int <= MAX_CHARGE:
                raise ParameterError(
                    f"{where} {key!r} = {what} collects {rate * t_int:.3g} e- per pixel "
                    f"over an integration of {t_int:.6g} s ({span}); at most "
                    f"{MAX_CHARGE:.3g} e- (2**53) per pixel is allowed")

        if not isinstance(src.dark_current, str):
            check("[sources]", "dark_current", src.dark_current,
                  f"{src.dark_current!r} e-/s")
        if src.hot_pixel_fraction > 0:
            top = max(np.atleast_1d(src.hot_pixel_rate))
            check("[sources]", "hot_pixel_rate", float(top), f"{src.hot_pixel_rate!r} e-/s")
        if flat is not None and not isinstance(src.background, str):
            check("[sources]", "background", src.background * flat,
                  f"{src.background!r} e-/s x [effects] 'flat' {flat!r}")
        for i, star in enumerate(src.stars):
            peak, curve = 1.0, ""
            if star.light_curve is not None:
                value, key = src.light_curve(star.light_curve).peak()
                if value is not None:
                    peak = value
                    curve = (f" x {curve_table(star.light_curve)} {key!r} "
                             f"peak {value!r}")
            if flat is not None:
                check(f"[[sources.stars]] #{i}", "flux", star.flux * peak * flat,
                      f"{star.flux!r} e-/s{curve} x [effects] 'flat' {flat!r}")

    def replace(self, **changes):
        """Return a copy with ``changes`` applied (validated again; no file is read)."""
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
        """``(key, value, comment)`` FITS cards: scene file name, its content digest
        (:func:`scenesim.outputs.scene_id`) and seed."""
        from scenesim.io.header import card
        from scenesim.outputs import scene_id
        name = os.path.basename(self.path) if self.path else "(in memory)"
        return [
            # printable ASCII, one card (a probe: 'scène.toml' crashed the write)
            card("SCENE", name[:68], "scene file"),
            ("SCENEID", scene_id(self), "scene content digest (not seed, outputs)"),
            ("SEED", self.seed, "master seed (numpy SeedSequence entropy)"),
        ]
