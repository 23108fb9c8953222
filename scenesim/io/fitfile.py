"""Slope files: the fit result in memory, written and read back, and JWST rate files.

:class:`FitResult` holds the slopes of one exposure, as every fitter returns them
(:func:`scenesim.rampfit.fit_ramps`, :func:`scenesim.adapters.stcal.fit_exposure_stcal`).
:func:`write_fit` writes it as a FITS file atomically and :func:`read_fit` reads it
back.  :func:`read_slopes` reads either a scenesim slope file or a JWST rate file
into the plain dict of arrays that :mod:`scenesim.validate.compare` grades, and
:func:`fit_arrays` makes the same dict from a :class:`FitResult` or a dict.

Layout of a scenesim slope file
-------------------------------
Primary header: ``FILETYPE = 'slopes'`` (:func:`scenesim.io.header.filetype_card`),
``NEXTEND = 10``,
``FITTER`` (``'cds'``, ``'ols'``, ``'gls'``, ``'stcal-...'``),
``GAIN`` (e-/DN, used only for ``SLOPE_DN``), ``RNOISE`` (read noise **per read**,
e-, not CDS; the median of a map), ``BUNIT = 'e-/s'``, ``NINTS``, plus the cards of
the caller (e.g. the preparation cards of :mod:`scenesim.calib.prepare`).  Image
extensions: ``SLOPE`` (e-/s), ``SLOPE_DN`` (DN/s), ``VAR_READ`` and ``VAR_POIS``
((e-/s)^2), ``CHI2``, ``DQ`` (uint32, bits of :mod:`scenesim.detector.dq`),
``SLOPEINT`` (e-/s, per integration), ``VARINT`` ((e-/s)^2), ``DOF``, ``NJUMPS``.

JWST rate files (``SCI`` in DN/s, ``DQ``, ``VAR_POISSON`` + ``VAR_RNOISE`` or
``ERR``) are converted to e- with a gain (e-/DN) the caller supplies; a ``rateints``
file (3-D ``SCI``) is combined over integrations with inverse-variance weights
first.  Roman L2 files (``.asdf``) are read by
:func:`scenesim.pipelines.products.read_roman_l2`.

Files are written atomically (a ``.gz`` name gzip-compressed; an OS error such as a
full disk raises :class:`noise.errors.OutputError` and leaves nothing) and read
through :func:`noise.fitsio.open_fits`: a missing, empty, truncated, corrupt or
non-FITS file, or another kind of scenesim file (``FILETYPE``), is one
:class:`noise.errors.FileFormatError` naming it.
"""

from dataclasses import dataclass

import numpy as np
from astropy.io import fits

from noise.errors import FileFormatError, ParameterError
from noise.fitsio import atomic_file, check_output_name, input_path, open_fits
from noise.validate import check_writable

from scenesim.io.header import (check_file_kind, dms_to_detector, filetype_card,
                                nextend_card)
from scenesim.pipelines.products import is_asdf, read_roman_l2

__all__ = ["FitResult", "write_fit", "read_fit", "read_slopes", "fit_arrays"]

_F32 = np.float32

#: Image extensions of a slope file that :func:`read_fit` needs.
_EXTENSIONS = ("SLOPE", "VAR_READ", "VAR_POIS", "CHI2", "DQ", "SLOPEINT", "VARINT",
               "DOF", "NJUMPS")


@dataclass(frozen=True, eq=False)
class FitResult:
    """Slopes fitted to the ramps of one exposure.

    Attributes
    ----------
    slope : ndarray, shape (ny, nx), float32, e-/s
        Rate combined over integrations (0 where ``DO_NOT_USE``).
    var_read, var_poisson : ndarray, shape (ny, nx), float32, (e-/s)^2
        Read-noise and Poisson parts of the variance of ``slope``; the Poisson part
        is evaluated at the variance rate (:mod:`scenesim.rampfit.local_rate`).
    chi2 : ndarray, shape (ny, nx), float32
        chi-square of the rate estimates under the model covariance per degree of
        freedom (0 where ``dof == 0``).
    dof : ndarray, shape (ny, nx), int32
        Degrees of freedom: usable differences (all integrations) minus 1, >= 0.
    dq : ndarray, shape (ny, nx), uint32
        DQ bits ``DO_NOT_USE``, ``SATURATED``, ``JUMP_DET``, ``REFERENCE_PIXEL``
        (:mod:`scenesim.detector.dq`).
    slope_ints : ndarray, shape (nints, ny, nx), float32, e-/s
        Per-integration rates (0 where an integration has no usable data).
    var_ints : ndarray, shape (nints, ny, nx), float32, (e-/s)^2
        Total variance of ``slope_ints`` (``BAD_VARIANCE`` where unmeasured), its
        Poisson part at the same variance rate as ``var_poisson``.
    n_jumps : ndarray, shape (ny, nx), int32
        Number of differences flagged as jumps (all integrations).
    gain : float
        Gain, e-/DN, used only to write ``SLOPE_DN``.
    read_noise : float
        Read noise, e- per read (not CDS); the median if a map was given.
    fitter : str
        ``'cds'``, ``'ols'`` or ``'gls'`` (``'stcal-OLS_C'``, ``'stcal-LIKELY'`` for
        the stcal adapter).
    """

    slope: np.ndarray
    var_read: np.ndarray
    var_poisson: np.ndarray
    chi2: np.ndarray
    dof: np.ndarray
    dq: np.ndarray
    slope_ints: np.ndarray
    var_ints: np.ndarray
    n_jumps: np.ndarray
    gain: float
    read_noise: float
    fitter: str

    @property
    def var(self):
        """Total variance ``var_read + var_poisson``, (ny, nx) float32, (e-/s)^2."""
        return self.var_read + self.var_poisson

    @property
    def err(self):
        """Standard error ``sqrt(var)``, (ny, nx) float32, e-/s."""
        return np.sqrt(self.var)

    @property
    def slope_dn(self):
        """Rate in DN/s, ``slope / gain``, (ny, nx) float32."""
        return (self.slope / _F32(self.gain)).astype(_F32)

    def to_hdul(self, header_cards=()):
        """Return the fit as an :class:`astropy.io.fits.HDUList`.

        Parameters
        ----------
        header_cards : iterable of (key, value, comment)
            Extra cards for the primary header (e.g. ``Detector.to_header_cards()``).

        Returns
        -------
        astropy.io.fits.HDUList
            Primary header with ``FITTER``, ``GAIN``, ``RNOISE``, ``BUNIT`` and
            ``NINTS``; image extensions ``SLOPE`` (e-/s), ``SLOPE_DN`` (DN/s),
            ``VAR_READ``, ``VAR_POIS`` ((e-/s)^2), ``CHI2``, ``DQ``, ``SLOPEINT``
            (e-/s, per integration), ``VARINT`` ((e-/s)^2), ``DOF``, ``NJUMPS``.
        """
        cards = _check_cards(header_cards)
        primary = fits.PrimaryHDU()
        hdr = primary.header
        kind = filetype_card("slopes")
        nextend = nextend_card(len(_EXTENSIONS) + 1)         # + SLOPE_DN
        hdr[kind[0]] = kind[1:]
        hdr[nextend[0]] = nextend[1:]
        hdr["FITTER"] = (self.fitter, "ramp fitter: cds, ols or gls")
        hdr["GAIN"] = (float(self.gain), "[e-/DN] gain used for SLOPE_DN")
        hdr["RNOISE"] = (float(self.read_noise),
                         "[e-] read noise per read (NOT CDS)")
        hdr["BUNIT"] = ("e-/s", "unit of SLOPE")
        hdr["NINTS"] = (int(self.slope_ints.shape[0]), "integrations combined")
        for key, value, comment in cards:
            if key not in (kind[0], nextend[0]):
                hdr[key] = (value, comment)
        exts = [
            ("SLOPE", self.slope.astype(_F32), "e-/s"),
            ("SLOPE_DN", self.slope_dn, "DN/s"),
            ("VAR_READ", self.var_read.astype(_F32), "(e-/s)**2"),
            ("VAR_POIS", self.var_poisson.astype(_F32), "(e-/s)**2"),
            ("CHI2", self.chi2.astype(_F32), ""),
            ("DQ", self.dq.astype(np.uint32), ""),
            ("SLOPEINT", self.slope_ints.astype(_F32), "e-/s"),
            ("VARINT", self.var_ints.astype(_F32), "(e-/s)**2"),
            ("DOF", self.dof.astype(np.int32), ""),
            ("NJUMPS", self.n_jumps.astype(np.int32), ""),
        ]
        hdus = [primary]
        for name, data, unit in exts:
            hdu = fits.ImageHDU(data=data, name=name)
            if unit:
                hdu.header["BUNIT"] = unit
            hdus.append(hdu)
        return fits.HDUList(hdus)


def _check_cards(header_cards):
    """``header_cards`` as a list of (str key, value, comment) tuples, or raise."""
    try:
        cards = [tuple(c) for c in header_cards]
    except TypeError as exc:
        raise ParameterError(
            f"'header_cards' must be an iterable of (key, value, comment) tuples, "
            f"got {header_cards!r}") from exc
    for c in cards:
        if len(c) != 3 or not isinstance(c[0], str):
            raise ParameterError(
                f"'header_cards' entries must be (key, value, comment) with a str key, "
                f"got {c!r}")
    return cards


def write_fit(path, result, *, header_cards=(), overwrite=False):
    """Write a :class:`FitResult` to a FITS file atomically.

    The file is written to a temporary file in the same directory and moved into
    place with :func:`os.replace`, so no partial file is ever left at ``path``.

    Parameters
    ----------
    path : str or os.PathLike
        Output file.
    result : FitResult
    header_cards : iterable of (key, value, comment)
        Extra primary-header cards.
    overwrite : bool
        Replace an existing file (default: refuse it).

    Returns
    -------
    str
        The path written.

    Raises
    ------
    noise.errors.ParameterError
        Bad ``result`` or cards, or an output path that cannot be written.
    noise.errors.OutputError
        The file could not be written (disk full, file-size limit); nothing is left.
    """
    if not isinstance(result, FitResult):
        raise ParameterError(f"'result' must be a FitResult, got {type(result).__name__}")
    path = check_writable("path", path, overwrite=overwrite)
    check_output_name("path", path)
    hdul = result.to_hdul(header_cards)
    with atomic_file(path, overwrite=overwrite) as f:
        hdul.writeto(f, output_verify="exception")
    return path


def read_fit(path):
    """Read a file written by :func:`write_fit` back into a :class:`FitResult`.

    Raises
    ------
    noise.errors.FileFormatError
        One line naming the file: missing, a directory, empty, truncated, corrupt or
        not FITS, another kind of scenesim file (exposure, truth, noise-only), or an
        extension or keyword missing.
    """
    path = input_path(path, "fit file")
    names = _EXTENSIONS
    with open_fits(path, "fit file", memmap=False) as hdul:
        check_file_kind(hdul, path, "slopes")
        hdr = hdul[0].header
        missing = [n for n in names if n not in hdul]
        missing += [k for k in ("FITTER", "GAIN", "RNOISE") if k not in hdr]
        if missing:
            raise FileFormatError(
                f"{path!r} is not a scenesim fit file: missing {missing} "
                f"(expected extensions {list(names)} and keywords FITTER, GAIN, "
                f"RNOISE)")
        data = {n: np.array(hdul[n].data) for n in names}
        empty = [n for n in names if data[n].ndim == 0]
        if empty:
            raise FileFormatError(f"fit file {path!r}: extension(s) {empty} hold no data")
        fitter, gain, rnoise = str(hdr["FITTER"]), float(hdr["GAIN"]), float(
            hdr["RNOISE"])
    return FitResult(
        slope=data["SLOPE"].astype(_F32), var_read=data["VAR_READ"].astype(_F32),
        var_poisson=data["VAR_POIS"].astype(_F32), chi2=data["CHI2"].astype(_F32),
        dof=data["DOF"].astype(np.int32), dq=data["DQ"].astype(np.uint32),
        slope_ints=data["SLOPEINT"].astype(_F32), var_ints=data["VARINT"].astype(_F32),
        n_jumps=data["NJUMPS"].astype(np.int32), gain=gain, read_noise=rnoise,
        fitter=fitter)


def read_slopes(path, *, gain=None):
    """Read a slope file of either supported layout into a dict, e-/s.

    Parameters
    ----------
    path : str or os.PathLike
        scenesim fit file (``SLOPE``, ``VAR_READ``, ``VAR_POIS``, ``CHI2``, ``DQ``),
        JWST rate file (``SCI`` DN/s, ``DQ``, ``VAR_POISSON`` + ``VAR_RNOISE`` or
        ``ERR``) or Roman L2 ASDF file (a name ending in ``.asdf``:
        :func:`scenesim.pipelines.products.read_roman_l2`).
    gain : float, keyword-only
        e-/DN; required for a JWST rate file and a Roman L2 file.

    Returns
    -------
    dict
        ``slope``, ``var`` ((ny, nx) float64, e-/s and (e-/s)^2), ``dq`` (uint32),
        ``chi2`` (float64 or None), ``read_noise`` (e- per read or None),
        ``layout`` ('scenesim' or 'jwst').
    """
    path = input_path(path, "slope file")
    if is_asdf(path):                           # a Roman L2 file
        return read_roman_l2(path, gain=gain)
    with open_fits(path, "slope file", memmap=False) as hdul:
        check_file_kind(hdul, path, "slopes")
        names = [h.name for h in hdul]
        if "SLOPE" in names:
            layout = "scenesim"
        elif "SCI" in names:
            layout = "jwst"
            hdr0 = hdul[0].header
            model = hdr0.get("DATAMODL")
            if "REFTYPE" in hdr0 or (model is not None
                                     and model not in ("ImageModel", "CubeModel")):
                what = (f"reference file (REFTYPE = {hdr0['REFTYPE']!r})"
                        if "REFTYPE" in hdr0 else f"{model} file")
                raise FileFormatError(
                    f"{path!r} is a JWST {what}, not a rate (ImageModel) or rateints "
                    f"(CubeModel) file")
            need = ["SCI", "DQ"]
            if not ("VAR_POISSON" in names and "VAR_RNOISE" in names):
                need.append("ERR")
            missing = [n for n in need if n not in names]
            if missing:
                raise FileFormatError(
                    f"JWST rate file {path!r} lacks extension(s) {missing} (found "
                    f"{names}; needs SCI, DQ and VAR_POISSON + VAR_RNOISE or ERR)")
            if not _positive(gain):
                raise ParameterError(
                    f"'gain' (e-/DN, > 0) is needed to convert the JWST rate file "
                    f"{path!r} to e-/s, got {gain!r}")
            g = float(gain)
            sci = np.asarray(hdul["SCI"].data, dtype=np.float64)
            if "VAR_POISSON" in names and "VAR_RNOISE" in names:
                var = (np.asarray(hdul["VAR_POISSON"].data, dtype=np.float64)
                       + np.asarray(hdul["VAR_RNOISE"].data, dtype=np.float64))
            else:
                var = np.asarray(hdul["ERR"].data, dtype=np.float64) ** 2
            dq = np.asarray(hdul["DQ"].data).astype(np.uint32)
            # a NIRSpec file in the DMS frame (IRS2): back to the detector's
            sci, var, dq = (dms_to_detector(a, hdul[0].header) for a in (sci, var, dq))
            if sci.ndim == 3:                   # a rateints file: one plane per int
                sci, var, dq = _combine_integrations(sci, var, dq)
                layout = "jwst-rateints"
            out = {"slope": sci * g, "var": var * g * g, "dq": dq,
                   "chi2": None, "read_noise": None, "layout": layout}
            for key in ("slope", "var"):
                out[key] = np.nan_to_num(out[key], nan=0.0 if key == "slope"
                                         else np.inf, posinf=np.inf)
            return out
        else:
            raise FileFormatError(
                f"{path!r} is neither a scenesim fit file (extension 'SLOPE') nor a "
                f"JWST rate file (extension 'SCI'); found {names}")
    fit = read_fit(path)
    return fit_arrays(fit)


def _combine_integrations(sci, var, dq):
    """The rates of a JWST ``rateints`` file (nints, ny, nx) combined as ``rate``
    files combine them: inverse-variance weights per pixel, variance ``1 / sum(1 /
    var)``, DQ the OR over integrations (an integration with no valid variance gets
    no weight)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.where(np.isfinite(var) & (var > 0), 1.0 / var, 0.0)
        wsum = w.sum(axis=0)
        slope = np.where(wsum > 0, (w * np.nan_to_num(sci)).sum(axis=0) / wsum, np.nan)
        total = np.where(wsum > 0, 1.0 / wsum, np.inf)
    return slope, total, np.bitwise_or.reduce(dq, axis=0) if dq.ndim == 3 else dq


def _positive(value):
    """True for a finite real number > 0."""
    try:
        return bool(np.isfinite(value) and value > 0) and not isinstance(value, bool)
    except (TypeError, ValueError):
        return False


def fit_arrays(fit):
    """The dict of :func:`read_slopes` from a :class:`FitResult` or a dict of arrays.

    Parameters
    ----------
    fit : FitResult or dict
        A dict needs ``slope`` (e-/s), ``var`` ((e-/s)^2) and ``dq`` of one 2-D
        shape, optionally ``chi2``, ``read_noise`` (e- per read) and ``layout``.

    Returns
    -------
    dict
        ``slope``, ``var`` (float64), ``dq`` (uint32), ``chi2`` (float64 or None),
        ``read_noise``, ``layout``.
    """
    if isinstance(fit, FitResult):
        return {"slope": np.asarray(fit.slope, dtype=np.float64),
                "var": np.asarray(fit.var, dtype=np.float64),
                "dq": np.asarray(fit.dq).astype(np.uint32),
                "chi2": np.asarray(fit.chi2, dtype=np.float64),
                "read_noise": float(fit.read_noise), "layout": "scenesim"}
    if isinstance(fit, dict):
        missing = [k for k in ("slope", "var", "dq") if k not in fit]
        if missing:
            raise ParameterError(
                f"'fit' dict lacks {missing}; needs 'slope' (e-/s), 'var' ((e-/s)^2), "
                f"'dq', optionally 'chi2' and 'read_noise'")
        out = {"slope": np.asarray(fit["slope"], dtype=np.float64),
               "var": np.asarray(fit["var"], dtype=np.float64),
               "dq": np.asarray(fit["dq"]).astype(np.uint32),
               "chi2": None if fit.get("chi2") is None else np.asarray(
                   fit["chi2"], dtype=np.float64),
               "read_noise": fit.get("read_noise"), "layout": fit.get("layout", "dict")}
        shapes = {k: out[k].shape for k in ("slope", "var", "dq")}
        if out["chi2"] is not None:
            shapes["chi2"] = out["chi2"].shape
        if len(set(shapes.values())) != 1 or out["slope"].ndim != 2:
            raise ParameterError(f"'fit' arrays must share one 2-D shape, got {shapes}")
        return out
    raise ParameterError(
        f"'fit' must be a FitResult or a dict of arrays, got {type(fit).__name__}")
