"""Reading what the pipelines write, for ``compare``.

* :func:`fit_header`: the primary header of a slope file: FITS (scenesim fits, JWST
  ``rate``/``rateints``) or, for a Roman L2 ASDF file, the FITS-like cards ``compare``
  reads (``S_IPC``/``S_DARK`` from its ``cal_step``).
* :func:`subtracted_dark_rate`: the dark rate a pipeline subtracted.  When
  ``S_DARK = 'COMPLETE'`` the rate file lacks the dark current and hot pixels the
  truth includes; the dark reference it names (``R_DARK``) gives what was taken out.
  JWST (FITS ``DarkModel``): a linear dark ramp changes any linear fit's slope by
  exactly its own slope, which is ``(SCI[-1] - SCI[0]) / ((ngroups - 1) (nframes +
  groupgap) t_frame)`` DN/s.  Roman (ASDF ``DarkRefModel``, named by the L2's
  ``meta.ref_file.dark``): romancal subtracts its ``dark_slope`` (DN/s) from the
  fitted slopes.
* :func:`subtract_dark`: the truth with that dark removed (``RATE``, and ``RATE_IPC``
  by the dark seen through the IPC kernel), so ``compare`` grades what the pipeline
  was asked to recover.
* :func:`slope_agreement`: a pipeline's slopes against another fit of the same
  exposure (scenesim's GLS), pixel by pixel, in units of the other fit's errors,
  with the dark the pipeline took out put back on the same footing.
* :func:`read_roman_l2`: a Roman L2 (``ImageModel``) file as the dict of
  :func:`scenesim.io.fitfile.read_slopes` (``data`` DN/s, ``var_poisson`` +
  ``var_rnoise``, or ``err``, ``dq``), converted to e- with the truth's gain and put
  back on the read-out grid: romancal trims a 4-pixel border from every side, which
  comes back flagged ``REFERENCE_PIXEL | DO_NOT_USE`` (not graded).  romancal stores
  the variances as float16 (3 significant digits), which ``chi2_rep`` inherits.
"""

import os
import warnings

import numpy as np
from astropy.io import fits

from noise.errors import FileFormatError, ParameterError

from scenesim.detector.dq import DO_NOT_USE, REFERENCE_PIXEL
from scenesim.detector.ipc import apply_ipc
from noise.clock import detector_from_header

# scenesim.io.header is imported inside the functions: scenesim.io's package
# imports fitfile, which imports this module (for Roman L2 files), so a top-level
# import would make "import scenesim.pipelines.products" circular when it comes first

__all__ = ["fit_header", "subtracted_dark_rate", "subtract_dark", "read_roman_l2",
           "slope_agreement", "is_asdf", "ROMAN_BORDER"]

#: Border that romancal's ramp fit trims from every side of the L2 image, pixels
#: (``romancal.ramp_fitting.ramp_fit_step``: ``[4:-4, 4:-4]``).
ROMAN_BORDER = 4


def is_asdf(path):
    """True for a path ending in ``.asdf``."""
    return os.fspath(path).lower().endswith(".asdf")


def _open_roman(path):
    try:
        import roman_datamodels as rdm
    except ImportError as exc:              # pragma: no cover - depends on the extra
        raise ParameterError("reading a Roman L2 file needs the optional 'roman' "
                             "extra (roman_datamodels is not installed): pip install "
                             "-e '.[roman]'") from exc
    if not os.path.isfile(os.fspath(path)):
        raise FileFormatError(f"{os.fspath(path)!r} does not exist (or is not a file)")
    try:
        with warnings.catch_warnings():     # a damaged tree: one line, not the schema
            warnings.simplefilter("ignore")
            return rdm.open(os.fspath(path))
    except Exception as exc:          # asdf raises many types for a bad file
        text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        raise FileFormatError(f"{os.fspath(path)!r} is not a Roman datamodels ASDF "
                              f"file ({type(exc).__name__}: {text[:200]})") from exc


def fit_header(path):
    """The primary header of a slope file (FITS), or the cards ``compare`` reads from
    a Roman L2 ASDF file (``S_IPC``, ``S_DARK``: ``'COMPLETE'`` when that step ran;
    ``R_DARK``; and, from its exposure metadata, ``READPATT`` (the MA table's name),
    ``NGROUPS`` (resultants), ``NINTS`` (1) and ``TFRAME``)."""
    if not is_asdf(path):
        return fits.getheader(os.fspath(path))
    hdr = fits.Header()
    with _open_roman(path) as m:
        exposure = m.meta.get("exposure", {})
        for key, name in (("READPATT", "ma_table_name"), ("NGROUPS", "nresultants"),
                          ("TFRAME", "frame_time")):
            value = exposure.get(name) if hasattr(exposure, "get") else None
            if value is None or (isinstance(value, str) and value.strip() in ("", "?")):
                continue                    # not recorded
            hdr[key] = value
        hdr["NINTS"] = 1
        steps = m.meta.cal_step
        for key, name in (("S_IPC", "ipc"), ("S_DARK", "dark")):
            value = str(getattr(steps, name, "INCOMPLETE")) if name in steps else \
                "INCOMPLETE"
            hdr[key] = value
        refs = m.meta.get("ref_file", {})
        if "dark" in refs:
            hdr["R_DARK"] = str(refs["dark"])
    return hdr


def subtracted_dark_rate(header, t_frame, gain):
    """Dark rate (e-/s, (ny, nx)) a pipeline took out of a slope file, or None.

    Parameters
    ----------
    header : astropy.io.fits.Header
        The rate file's primary header (``S_DARK``, ``R_DARK``), or the cards
        :func:`fit_header` makes of a Roman L2.
    t_frame : float
        Frame time, s (the truth's ``TFRAME``).
    gain : float
        e-/DN.

    Returns
    -------
    (ndarray or None, str)
        The rate and a note for the report.
    """
    from scenesim.io.header import header_jwst_steps
    if "dark_current" not in header_jwst_steps(header):
        return None, ""
    path = str(header.get("R_DARK", "")).strip()
    if path.startswith("crds://") or not os.path.isfile(path):
        return None, (f"the pipeline subtracted a dark (R_DARK = {path!r}) that is not "
                      f"readable here: the truth still includes dark current and hot "
                      f"pixels")
    if is_asdf(path):
        with _open_roman(path) as m:
            if "dark_slope" not in m:
                raise FileFormatError(f"dark reference {path!r} has no 'dark_slope' (a "
                                      f"Roman DarkRefModel)")
            rate = np.asarray(m.dark_slope, dtype=np.float64) * float(gain)
        return rate, (f"the pipeline subtracted the dark {os.path.basename(path)}: "
                      f"compared with the truth minus its rate")
    from scenesim.io.header import dms_to_detector
    with fits.open(path) as hdul:
        h = hdul[0].header
        # a dark in the DMS frame (NIRSpec IRS2): back to the detector's orientation
        sci = dms_to_detector(np.asarray(hdul["SCI"].data, dtype=np.float64), h)
        nframes, groupgap = int(h.get("NFRAMES", 1)), int(h.get("GROUPGAP", 0))
    if sci.ndim != 3 or sci.shape[0] < 2:
        raise FileFormatError(f"dark reference {path!r}: SCI must be (ngroups >= 2, ny, "
                              f"nx), got {sci.shape}")
    span = (sci.shape[0] - 1) * (nframes + groupgap) * float(t_frame)
    rate = (sci[-1] - sci[0]) / span * float(gain)
    return rate, (f"the pipeline subtracted the dark {os.path.basename(path)}: compared "
                  f"with the truth minus its rate")


def subtract_dark(truth, dark):
    """A copy of ``truth`` (:func:`scenesim.io.exposure.read_truth`) without ``dark``
    (e-/s, before IPC): ``RATE - dark`` and ``RATE_IPC - IPC(dark)``.  The rates the
    pixels collected, dark included, stay in ``out['COLLECTED']`` (a truth-like dict
    of ``RATE``, ``RATE_IPC`` and ``header``): the shot noise of a ramp, and so the
    optimum a fit is graded against, is that of all the charge, not of the charge
    left after the pipeline took the dark out."""
    out = dict(truth)
    out["COLLECTED"] = {k: truth[k] for k in ("RATE", "RATE_IPC", "header") if k in truth}
    for key in ("RATE", "RATE_IPC"):
        if key in out and np.shape(out[key]) != np.shape(dark):
            raise FileFormatError(
                f"the truth's {key} has shape {np.shape(out[key])} but the pipeline's "
                f"dark {np.shape(dark)}: not the same detector")
    if "RATE" in out:
        out["RATE"] = np.asarray(out["RATE"], dtype=np.float64) - dark
    if "RATE_IPC" in out:
        from scenesim.io.header import header_ipc_kernel
        kernel = header_ipc_kernel(truth["header"])
        seen = dark if kernel is None else apply_ipc(
            dark, kernel, refmask=header_refmask(truth["header"], dark.shape))
        out["RATE_IPC"] = np.asarray(out["RATE_IPC"], dtype=np.float64) - seen
    return out


def read_roman_l2(path, *, gain):
    """A Roman L2 file as the dict :func:`scenesim.io.fitfile.read_slopes` returns.

    Parameters
    ----------
    path : str or os.PathLike
        ASDF file of a ``roman_datamodels`` ``ImageModel`` (``data`` DN/s, ``dq``,
        ``var_poisson``, ``var_rnoise`` (DN/s)^2, or ``err``).
    gain : float, keyword-only
        e-/DN.

    Returns
    -------
    dict
        ``slope``, ``var`` (e-/s, (e-/s)^2), ``dq``, ``chi2`` (None), ``read_noise``
        (None), ``layout`` (``'roman'``).
    """
    if not (gain is not None and np.isfinite(gain) and gain > 0):
        raise ParameterError(f"'gain' (e-/DN, > 0) is needed to convert the Roman L2 "
                             f"file {os.fspath(path)!r} to e-/s, got {gain!r}")
    with _open_roman(path) as m:
        kind = type(m).__name__
        if kind != "ImageModel":        # an L1 ramp, a reference file...
            raise FileFormatError(
                f"{os.fspath(path)!r} holds a Roman {kind}, not an L2 image "
                f"(ImageModel, the slopes 'scenesim pipeline roman' writes)")
        try:                            # the blocks are read here: a damaged one fails
            slope = np.asarray(m.data, dtype=np.float64)
            if "var_rnoise" in m and "var_poisson" in m:
                var = np.asarray(m.var_poisson, dtype=np.float64) + np.asarray(
                    m.var_rnoise, dtype=np.float64)
            else:
                var = np.asarray(m.err, dtype=np.float64) ** 2
            dq = np.asarray(m.dq).astype(np.uint32)
        except Exception as exc:        # noqa: BLE001 - asdf/numpy on a damaged file
            raise FileFormatError(f"cannot read Roman L2 {os.fspath(path)!r}: damaged "
                                  f"file ({type(exc).__name__}: {exc})") from exc
    # romancal's ramp fit trims the 4-pixel border ([4:-4, 4:-4]) whatever the
    # array; put the L2 back on the read-out grid, the border flagged as reference
    # (not graded) and DO_NOT_USE
    b = ROMAN_BORDER
    full = tuple(n + 2 * b for n in slope.shape)
    pad = ((b, b), (b, b))
    slope = np.pad(slope, pad)
    var = np.pad(var, pad, constant_values=np.inf)
    dq = np.pad(dq, pad, constant_values=np.uint32(REFERENCE_PIXEL | DO_NOT_USE))
    assert slope.shape == full
    g = float(gain)
    return {"slope": np.nan_to_num(slope * g, nan=0.0),
            "var": np.nan_to_num(var * g * g, nan=np.inf, posinf=np.inf),
            "dq": dq, "chi2": None, "read_noise": None, "layout": "roman"}


def slope_agreement(product, reference, exposure):
    """How a pipeline's slopes differ from another fit of the same exposure.

    Pixels unflagged (``dq == 0``) in both files, with finite slopes and positive
    finite variances, are compared.  When the pipeline subtracted a dark
    (:func:`subtracted_dark_rate`) it is subtracted from ``reference`` too (through
    the IPC kernel unless ``reference`` undid IPC); both must have treated IPC alike.

    Parameters
    ----------
    product : str
        Pipeline output: JWST rate file or Roman L2 ASDF file.
    reference : str
        The other fit (a scenesim slope file, e.g. ``scenesim fit --fitter gls``).
    exposure : str
        The scenesim exposure both fitted (``GAIN``, ``TFRAME``, ``IPCKERN``).

    Returns
    -------
    dict
        ``n`` (pixels compared), ``mean`` and ``rms`` of ``(product - reference) /
        sigma_reference``, ``sigma_ratio`` (median of ``sigma_product /
        sigma_reference``).
    """
    from scenesim.io.fitfile import read_slopes
    from scenesim.io.header import header_ipc_deconvolved, header_ipc_kernel
    h = fits.getheader(os.fspath(exposure))
    gain, t_frame = float(h["GAIN"]), float(h["TFRAME"])
    p = read_slopes(product, gain=gain)
    r = read_slopes(reference, gain=gain)
    ph, rh = fit_header(product), fits.getheader(os.fspath(reference))
    if header_ipc_deconvolved(ph) != header_ipc_deconvolved(rh):
        raise ParameterError(f"{os.fspath(product)!r} and {os.fspath(reference)!r} "
                             f"treated IPC differently (IPCDECON / S_IPC): their "
                             f"slopes are not comparable pixel by pixel")
    ref = np.array(r["slope"], dtype=np.float64)
    dark, _ = subtracted_dark_rate(ph, t_frame, gain)
    if dark is not None:
        kernel = header_ipc_kernel(h)
        deconvolved = header_ipc_deconvolved(rh)
        ref -= dark if (kernel is None or deconvolved) else apply_ipc(
            dark, kernel, refmask=header_refmask(h, dark.shape))
    ok = (p["dq"] == 0) & (r["dq"] == 0) & np.isfinite(p["slope"]) & np.isfinite(ref)
    for var in (p["var"], r["var"]):
        ok &= np.isfinite(var) & (var > 0)
    if not ok.any():
        raise ParameterError("no pixel is unflagged in both slope files")
    z = (p["slope"][ok] - ref[ok]) / np.sqrt(r["var"][ok])
    return {"n": int(ok.sum()), "mean": float(z.mean()),
            "rms": float(np.sqrt(np.mean(z * z))),
            "sigma_ratio": float(np.median(np.sqrt(p["var"][ok] / r["var"][ok])))}


def header_refmask(header, shape, what="the dark rate"):
    """The reference pixels of the detector ``header`` records, which IPC does not
    couple (:mod:`scenesim.detector.ipc`); ``shape`` (of ``what``) must be its
    image's."""
    m = detector_from_header(header).reference_mask()
    if m.shape != tuple(shape):
        raise FileFormatError(f"{what} has shape {tuple(shape)} but the detector "
                              f"of the header {m.shape}: not the same detector")
    return m
