"""The header contract: every card scenesim writes to its files, and how it is read back.

One module knows the keywords.  The writers (:mod:`scenesim.io.exposure` for the
exposure and truth files, :mod:`scenesim.calib.prepare` and the fit files) take
their cards from here, and every reader (the fit's preparation, ``compare``, the
stcal adapter) rebuilds what it needs through the functions below, never by hand.

What a file is: ``FILETYPE`` (:func:`filetype_card`) in every primary header,
``'exposure'``, ``'truth'``, ``'slopes'`` (fit files) or ``'noise'`` (noise-only ramps,
written by :func:`noise.fitsio.write_noise_fits`).  The readers check it
(:func:`check_file_kind`), so a file of the wrong kind is refused in one line; files
without the card (older exposures and slope files, foreign files) are recognised by
their extensions.  ``NEXTEND`` (:func:`nextend_card`) counts the extensions after the
primary HDU, so a file cut at an HDU boundary (which astropy reads without a word) is
refused as truncated.

Exposure and truth primary header (:func:`exposure_cards`):

* detector and clock: the cards of :meth:`noise.clock.Detector.to_header_cards`
  (``DETECTOR``, ``DETNAX1``/``DETNAX2``, ``NOUTPUTS``, ``NROH``, ``NFOH``,
  ``PIXDWELL``, ``REFBORD``, ``REVSCAN``, ``SUBARRAY``/``SUBSTRT``/``SUBSIZE``,
  ``TFRAME``), read back by :func:`noise.clock.detector_from_header` (which also
  reads the ``NAXIS1D``/``NAXIS2D`` of older files);
* readout: :meth:`scenesim.detector.readout.Readout.to_header_cards` (``NINTS``,
  ``NGROUPS``, ``NFRAMES``, ``GROUPGAP``, ``DROPFRM1``, ``READPATT``, ``TGROUP``,
  ``RESETMD``, ...) plus the exposure's ``READS`` table, read back by
  :func:`exposure_readout` (table) or :func:`readout_from_header` (cards only,
  exact for MULTIACCUM patterns);
* ``GAIN`` (e-/DN) and ``ADCBITS``; the noise amplitudes of
  :meth:`noise.NoiseParams.to_header_cards` (``RDNOISE``: e- per read, not CDS;
  :func:`exposure_read_noise`);
* charge effects: ``FULLWELL`` (e-), ``NONLIN`` + ``NLCOEFF`` (``c2,c3,...``,
  :func:`header_nonlinearity`), ``IPC`` + ``IPCKERN`` (the nine kernel values row by
  row, ``k[1+dy, 1+dx]``, :func:`header_ipc_kernel`);
* the engine options (``GAUSSAB``, ``ARRIVALS``), ``SEEDENT``, and the scene's own
  cards (``SEED``, ``SCENE``, ...), then the PSF (:func:`psf_cards`: ``PSFFWHM`` for a
  Gaussian, ``PSFAIRY`` for an Airy disk; :func:`header_psf`);
* the JWST identity chosen in the scene's ``[instrument]`` table, when it has one
  (:func:`instrument_cards`: ``JWSTINST``, ``JWSTDET``, ``JWSTEXPT``, ``JWSTSUBA``;
  read back by :func:`header_instrument`).  They are scenesim names: the plain
  exposure keeps ``DETECTOR`` for the HxRG preset, and only the JWST uncal
  (:mod:`scenesim.pipelines.jwst`) carries ``INSTRUME``, a JWST ``DETECTOR``,
  ``EXP_TYPE``...

JWST rate files are read by their own keywords: :func:`header_jwst_steps` gives the
calibration steps that ran (``S_IPC``, ``S_DARK``, ... = ``'COMPLETE'``).

Fit files copy :data:`COPIED_KEYS` from the exposure; every card is made to fit
one 80-character card (:func:`card`).  Every header passes astropy's verification
(``output_verify='exception'``).
"""

import math

import numpy as np
from astropy.io import fits

from noise.clock import detector_from_header
from noise.errors import FileFormatError, ParameterError

from scenesim.detector.ipc import check_kernel
from scenesim.detector.nonlinearity import Nonlinearity
from scenesim.detector.readout import Readout
from scenesim.sky.psf import AiryPSF, GaussianPSF

__all__ = ["COPIED_KEYS", "CARD_LENGTH", "exposure_cards", "psf_cards", "card",
           "printable", "exposure_card", "exposure_read_noise", "exposure_readout",
           "readout_from_header", "readout_from_table", "header_nonlinearity", "header_ipc_kernel",
           "header_psf", "exposure_settings", "preparation_cards",
           "header_ipc_deconvolved", "FILETYPES", "filetype_card", "nextend_card",
           "file_kind", "check_file_kind", "instrument_cards", "header_instrument",
           "header_jwst_steps", "dms_to_detector"]


#: Exposure header keywords copied into the header of a fit.
COPIED_KEYS = ("DETECTOR", "SUBARRAY", "READPATT", "NINTS", "NGROUPS", "TFRAME",
                "SEED", "SCENE", "SCENEID", "IPC", "IPCKERN", "BATCHSD", "BATCHKEY",
                "BATCHTSK", "BATCHDET")


CARD_LENGTH = 80                       # characters in a FITS header card

#: ``FILETYPE`` values of scenesim files, and how messages name each kind.
FILETYPES = {"exposure": "an exposure", "truth": "a truth file",
             "slopes": "a slope file", "noise": "a noise-only ramp"}


def filetype_card(kind):
    """The ``FILETYPE`` card of a scenesim file of ``kind`` (a key of
    :data:`FILETYPES`)."""
    if kind not in FILETYPES:
        raise ParameterError(f"'kind' must be one of {sorted(FILETYPES)}, got {kind!r}")
    return ("FILETYPE", kind, "scenesim file: exposure, truth, slopes or noise")


def nextend_card(n):
    """The ``NEXTEND`` card: ``n`` extensions follow the primary HDU."""
    return ("NEXTEND", int(n), "extensions after the primary HDU")


def file_kind(hdul):
    """What an opened FITS file is, and how that is known.

    Parameters
    ----------
    hdul : astropy.io.fits.HDUList

    Returns
    -------
    (str or None, str)
        The kind (a key of :data:`FILETYPES`, or None when unknown, e.g. a JWST
        file) and the evidence for the message: ``'FILETYPE=truth'``, or the
        extension that marks a file written before the card existed.
    """
    value = hdul[0].header.get("FILETYPE") if len(hdul) else None
    if isinstance(value, str) and value.strip().lower() in FILETYPES:
        kind = value.strip().lower()
        return kind, f"FILETYPE={kind}"
    names = {h.name for h in hdul}
    if "SLOPE" in names:
        return "slopes", "extension 'SLOPE'"
    if "RATE" in names and "RATE_IPC" in names:
        return "truth", "extensions 'RATE' and 'RATE_IPC'"
    if "SCI" in names and "READS" in names:
        return "exposure", "extensions 'SCI' and 'READS'"
    return None, ""


def check_file_kind(hdul, path, expected):
    """Raise unless the opened file ``path`` can be a complete file of kind
    ``expected``.

    A file whose kind :func:`file_kind` cannot tell passes (the caller checks its
    extensions); one with fewer extensions than its ``NEXTEND`` says is truncated.

    Raises
    ------
    noise.errors.FileFormatError
        E.g. ``'x.fits' is a truth file (FILETYPE=truth), not an exposure``.
    """
    kind, evidence = file_kind(hdul)
    if kind is not None and kind != expected:
        raise FileFormatError(
            f"{path!r} is {FILETYPES[kind]} ({evidence}), not {FILETYPES[expected]}")
    declared = hdul[0].header.get("NEXTEND")
    if isinstance(declared, int) and not isinstance(declared, bool) \
            and len(hdul) - 1 < declared:
        raise FileFormatError(
            f"{path!r} is truncated: {len(hdul) - 1} of its {declared} extensions "
            f"(NEXTEND) are there")


def exposure_read_noise(header, default=0.0):
    """White read noise per read (e-, not CDS) recorded in a header (``RDNOISE``).

    ``RDNOISE`` is a number, or comma-separated per-output values (their rms is
    returned); ``default`` when the card is absent or empty.
    """
    value = header.get("RDNOISE", None)
    if value is None:
        return default
    if isinstance(value, str):
        vals = [float(v) for v in value.split(",") if v.strip()]
        return float(np.sqrt(np.mean(np.square(vals)))) if vals else default
    return float(value)


def printable(text):
    """``text`` with every character outside printable ASCII replaced by ``?``."""
    return "".join(c if " " <= c <= "~" else "?" for c in str(text))


def _tail(text, width):
    """The end of ``text``, prefixed by ``...``, in at most ``width`` card characters
    (a quote counts twice in a FITS string)."""
    if len(text) + text.count("'") <= width:
        return text
    out = []
    used = 3
    for c in reversed(text):
        used += 2 if c == "'" else 1
        if used > width:
            break
        out.append(c)
    return "..." + "".join(reversed(out))


def card(key, value, comment):
    """``(key, value, comment)`` that astropy writes as one card without a warning.

    Strings are made printable ASCII; the comment is cut to the room the value
    leaves (a string value longer than one card becomes CONTINUE cards, no comment).
    """
    if isinstance(value, str):
        value = printable(value)
    image = fits.Card(key, value).image
    if len(image) > CARD_LENGTH:
        return key, value, ""
    room = CARD_LENGTH - 10 - max(len(image[10:].rstrip()), 20) - 3
    return key, value, printable(comment)[:max(room, 0)]


def exposure_card(name):
    """``EXPOSURE`` card: the end of the exposure's path, fitting one card."""
    comment = "fitted exposure"
    width = CARD_LENGTH - 10 - 2 - 3 - len(comment)        # KEY=_ + quotes + _/_ + comment
    return card("EXPOSURE", _tail(printable(name), width), comment)


def exposure_readout(exposure):
    """The readout of an exposure, checked against its header and ``SCI`` shape.

    Parameters
    ----------
    exposure : scenesim.io.exposure.Exposure

    Returns
    -------
    scenesim.detector.readout.Readout
        From the ``READS`` table, with ``NINTS``, ``RESETMD`` and ``READPATT`` from
        the header.

    Raises
    ------
    noise.errors.FileFormatError
        The header lacks ``GAIN``, ``TFRAME`` or ``NINTS``, or ``SCI`` does not have
        the shape (NINTS, resultants, ny, nx) that the header and table describe.
    """
    hdr = exposure.header
    missing = [k for k in ("GAIN", "TFRAME", "NINTS") if k not in hdr]
    if missing:
        raise FileFormatError(
            f"exposure {exposure.name!r} lacks header keyword {missing[0]!r}")
    try:
        det = detector_from_header(hdr)
        nints = int(hdr["NINTS"])
        ro = readout_from_table(hdr, exposure.reads)
    except (TypeError, ValueError) as exc:   # FileFormatError, ParameterError too
        raise FileFormatError(f"exposure {exposure.name!r}: {exc}") from exc
    sci = exposure.sci
    if (sci.ndim != 4 or sci.shape[:2] != (nints, ro.ngroups)
            or sci.shape[2:] != det.shape):
        raise FileFormatError(
            f"exposure {exposure.name!r}: SCI shape {sci.shape} does not match "
            f"NINTS={nints}, {ro.ngroups} resultants and the {det.shape} detector in "
            f"its header")
    _check_header_against_reads(exposure, ro)
    return ro


def _check_header_against_reads(exposure, ro):
    """Refuse a ``GAIN`` or ``TFRAME`` that is not a number > 0, and a header whose
    ``NGROUPS`` or ``TFRAME`` contradicts the ``READS``
    table (its resultants, its ``READ_TIMES`` and its own ``TFRAME``): the fit takes
    the times from ``TFRAME`` and the frame indices, so an edited ``TFRAME`` of 1 s
    on 18.2 ms frames had scaled every slope by 0.0182 without a word."""
    hdr, name = exposure.header, exposure.name
    if "NGROUPS" in hdr:
        try:
            ng = int(hdr["NGROUPS"])
        except (TypeError, ValueError) as exc:
            raise FileFormatError(f"exposure {name!r}: NGROUPS = {hdr['NGROUPS']!r} is "
                                  f"not an integer") from exc
        if ng != ro.ngroups:
            raise FileFormatError(
                f"exposure {name!r}: its header says NGROUPS = {ng}, its READS table "
                f"and SCI hold {ro.ngroups} resultants")
    for key, unit in (("GAIN", "e-/DN"), ("TFRAME", "s")):
        try:
            value = float(hdr[key])
        except (TypeError, ValueError) as exc:
            raise FileFormatError(f"exposure {name!r}: {key} = {hdr[key]!r} is not "
                                  f"a number") from exc
        if not (math.isfinite(value) and value > 0):
            raise FileFormatError(f"exposure {name!r}: its header card {key} = "
                                  f"{hdr[key]!r} {unit} must be a finite number > 0")
    t_frame = float(hdr["TFRAME"])
    reads = exposure.reads
    meta_t = getattr(reads, "meta", {}).get("TFRAME") if reads is not None else None
    if meta_t is not None and not math.isclose(float(meta_t), t_frame, rel_tol=1e-9):
        raise FileFormatError(
            f"exposure {name!r}: its header says TFRAME = {t_frame!r} s, its READS "
            f"table {float(meta_t)!r} s")
    if reads is not None and "READ_TIMES" in getattr(reads, "colnames", ()):
        recorded = np.asarray(reads["READ_TIMES"], dtype=np.float64)
        want = np.full(recorded.shape, np.nan)
        for r, t in enumerate(ro.read_times(t_frame)):
            want[r, :len(t)] = t
        ok = np.isnan(recorded) == np.isnan(want)
        ok &= np.isnan(want) | np.isclose(recorded, want, rtol=1e-9, atol=0.0)
        if not ok.all():
            raise FileFormatError(
                f"exposure {name!r}: its READS table's READ_TIMES are not the reads "
                f"at TFRAME = {t_frame!r} s from the header (the file was edited?)")


def readout_from_table(header, reads):
    """The readout of a ``READS`` table (:meth:`Readout.read_table`), with ``NINTS``
    (default 1), ``RESETMD`` ('rolling') and ``READPATT`` from ``header``; exact for
    any readout.

    Raises
    ------
    noise.errors.FileFormatError
        The table describes no valid readout.
    """
    return Readout.from_read_table(reads, nints=int(header.get("NINTS", 1)),
                                   reset_mode=str(header.get("RESETMD", "rolling")),
                                   name=str(header.get("READPATT", "CUSTOM")))


def header_nonlinearity(header):
    """The :class:`~scenesim.detector.nonlinearity.Nonlinearity` recorded in an exposure header
    (``NONLIN`` and ``NLCOEFF``), or ``None``."""
    if not header.get("NONLIN", False) or not str(header.get("NLCOEFF", "")).strip():
        return None
    coeffs = [float(c) for c in str(header["NLCOEFF"]).split(",") if c.strip()]
    nl = Nonlinearity(tuple(coeffs))
    return None if nl.is_linear else nl


def header_ipc_kernel(header):
    """The IPC kernel recorded in an exposure header (``IPC`` and ``IPCKERN``), or
    ``None``.

    Parameters
    ----------
    header : astropy.io.fits.Header
        Exposure primary header.

    Returns
    -------
    ndarray, shape (3, 3), float64, or None
        The kernel of :func:`scenesim.detector.ipc.apply_ipc` (``IPCKERN``: the nine
        values row by row, ``kernel[1 + dy, 1 + dx]`` is the fraction a pixel sends
        to its neighbour at ``(y + dy, x + dx)``), renormalised to sum 1 exactly as
        the engine did.  ``None`` when ``IPC`` is false, when ``IPCKERN`` is absent
        (files from before the card existed: the kernel is unknown), or when the
        kernel is the identity (nothing to undo).

    Raises
    ------
    noise.errors.FileFormatError
        ``IPCKERN`` is not nine numbers forming a valid kernel (finite, >= 0, sum 1).
    """
    if not header.get("IPC", False) or "IPCKERN" not in header:
        return None
    text = str(header["IPCKERN"])
    try:
        k = check_kernel(np.array([float(v) for v in text.split(",")]).reshape(3, 3))
    except (ValueError, TypeError) as exc:   # ParameterError is a ValueError
        raise FileFormatError(
            f"header keyword 'IPCKERN' must be the 9 comma-separated values of a 3x3 "
            f"IPC kernel (finite, >= 0, summing to 1), got {text!r}") from exc
    if k[1, 1] == 1.0:
        return None
    return k


def exposure_cards(engine, cards):
    """The primary-header cards of an exposure of ``engine``, ``cards`` last (a card
    of ``cards`` replaces one of the same key); ``FILETYPE = 'exposure'`` and
    ``NEXTEND = 2`` (``SCI``, ``READS``; the truth file replaces both)."""
    det, ro = engine.detector, engine.readout
    t_frame = det.frame_time
    out = [("TELESCOP", "scenesim", "simulated HxRG exposure"),
           ("ORIGIN", "scenesim", ""), filetype_card("exposure"), nextend_card(2)]
    seen = set()
    for key, value, comment in list(det.to_header_cards()) + list(
            ro.to_header_cards(t_frame)):
        if key not in seen:
            out.append((key, value, comment))
            seen.add(key)
    out.append(("GAIN", engine.gain, "[e-/DN] conversion gain"))
    out.append(("ADCBITS", engine.adc_bits, "ADC bits"))
    if engine.noise is not None:
        for key, value, comment in engine.noise.params.to_header_cards():
            out.append((key, value, comment))
    else:
        out.append(("RDNOISE", 0.0, "[e-] white read noise per read (not CDS)"))
    out.append(("SEEDENT", str(engine.entropy), "root SeedSequence entropy"))
    out.append(("FULLWELL", engine.full_well.max if engine.full_well is not None
                else 0.0, "[e-] full well (max over pixels; 0 = none)"))
    out.append(("IPC", engine.ipc_kernel is not None, "IPC applied"))
    if engine.ipc_kernel is not None:
        kern = np.asarray(engine.ipc_kernel, dtype=np.float64).ravel()
        out.append(("IPCKERN", ",".join(f"{v:.10g}" for v in kern),
                    "3x3 IPC kernel row by row, k[1+dy,1+dx]"))
    out.append(("NONLIN", engine.nonlinearity is not None, "nonlinearity applied"))
    if engine.nonlinearity is not None:
        out.append(("NLCOEFF", ",".join(f"{c:.10g}" for c in engine.nonlinearity.coeffs),
                    "c2,c3,...: m = q + c2 q^2 + c3 q^3 (e-)"))
    out.append(("GAUSSAB", engine.options.gauss_above or 0.0,
                "[e-] Gaussian above this mean (0 = exact Poisson)"))
    out.append(("ARRIVALS", engine.options.arrivals,
                "charge arrivals: time (exact) or 2d (shortcut)"))
    for key, value, comment in cards:
        out = [c for c in out if c[0] != key]
        out.append((key, value, comment))
    return out


# ---------------------------------------------------------------------- inputs
def readout_from_header(header):
    """Rebuild a MULTIACCUM :class:`scenesim.detector.readout.Readout` from header cards.

    Parameters
    ----------
    header : astropy.io.fits.Header or dict
        Needs ``NGROUPS``; uses ``NFRAMES`` (1), ``GROUPGAP`` (0), ``DROPFRM1`` (0),
        ``NINTS`` (1), ``RESETMD`` ('rolling'), ``READPATT``.

    Returns
    -------
    scenesim.detector.readout.Readout
    """
    if "NGROUPS" not in header:
        raise FileFormatError(
            "truth header lacks 'NGROUPS'; pass the exposure file to get the read times")
    try:
        ro = Readout.multiaccum(int(header.get("NFRAMES", 1)), int(header["NGROUPS"]),
                                groupgap=int(header.get("GROUPGAP", 0)),
                                nskip=int(header.get("DROPFRM1", 0)),
                                nints=int(header.get("NINTS", 1)),
                                reset_mode=str(header.get("RESETMD", "rolling")))
        # the file's own label, as written (a scene may no longer give a custom
        # readout a JWST pattern's name, but files written before may carry one)
        return Readout(ro.resultants, nints=ro.nints, reset_mode=ro.reset_mode,
                       name=str(header.get("READPATT", "CUSTOM")), nframes=ro.nframes,
                       groupgap=ro.groupgap, nskip=ro.nskip)
    except ParameterError as exc:
        raise FileFormatError(f"truth header describes an invalid readout: {exc}") from exc


def exposure_settings(header):
    """The scalar cards of an exposure or truth header, read in one place.

    Returns
    -------
    dict
        ``gain`` (``GAIN``, e-/DN, None if absent), ``t_frame`` (``TFRAME``, s, None
        if absent), ``nints`` (``NINTS``, default 1), ``adc_bits`` (``ADCBITS``,
        default 16), ``full_well`` (``FULLWELL``, e-, default 0: none or unknown),
        ``ipc`` (``IPC``: IPC was applied) and ``ipc_unrecorded`` (``IPC`` true but
        no ``IPCKERN``: the kernel is unknown).

    Raises
    ------
    noise.errors.FileFormatError
        A card that is present has a value of the wrong type.
    """
    try:
        return {"gain": float(header["GAIN"]) if "GAIN" in header else None,
                "t_frame": float(header["TFRAME"]) if "TFRAME" in header else None,
                "nints": int(header.get("NINTS", 1)),
                "adc_bits": int(header.get("ADCBITS", 16)),
                "full_well": float(header.get("FULLWELL", 0.0)),
                "ipc": bool(header.get("IPC", False)),
                "ipc_unrecorded": bool(header.get("IPC", False)) and "IPCKERN" not in header}
    except (TypeError, ValueError) as exc:
        raise FileFormatError(f"header card has a value of the wrong type: {exc}") from exc


def preparation_cards(name, hdr, options, rdn_model, decon, rn_gain, linearized,
                      resultant_noise):
    """Cards of a fit file recording the exposure and its preparation
    (:func:`scenesim.calib.prepare.prepare_exposure`), then the exposure's
    :data:`COPIED_KEYS`.

    ``EXPOSURE`` (its path), ``REFPIX``, ``RNCONV`` (read noise per read, not CDS),
    ``RNMODEL`` (e-), ``RNSOURCE``, ``CMREMOVE``, ``IPCDECON`` (IPC undone, read back
    by :func:`header_ipc_deconvolved`), ``IPCRNFAC``, ``RSNOISE`` (the largest
    ``resultant_noise``, e- rms: the rounding of on-board means in the fit's
    covariance) and ``LINCORR``.
    """
    cards = [exposure_card(name),
             ("REFPIX", options.refpix, "reference-pixel correction"),
             ("RNCONV", "per read", "read noise convention: per read, not CDS"),
             ("RNMODEL", float(rdn_model), "[e-] model white read noise per read"),
             ("RNSOURCE", "measured" if options.measure_noise else "model",
              "RNOISE: per-column measured or model"),
             ("CMREMOVE", bool(options.remove_common_mode),
              "per-output common mode removed"),
             ("IPCDECON", bool(decon), "IPC kernel (IPCKERN) deconvolved"),
             ("IPCRNFAC", float(rn_gain), "read noise x this by the IPC deconvolution"),
             ("RSNOISE", float(np.max(resultant_noise, initial=0.0)),
              "[e-] max rounding noise of on-board group means"),
             ("LINCORR", linearized, "classical nonlinearity inverted (NLCOEFF)")]
    for key in COPIED_KEYS:
        if key in hdr:
            cards.append(card(key, hdr[key], hdr.comments[key]))
    return tuple(cards)


def header_ipc_deconvolved(header):
    """True when a fit file's header says the fit undid IPC: scenesim's ``IPCDECON``,
    or a JWST rate file whose ``ipc`` step ran (``S_IPC = 'COMPLETE'``)."""
    return bool(header.get("IPCDECON", False)) or "ipc" in header_jwst_steps(header)


#: JWST step-status keywords (``S_<KEY> = 'COMPLETE'`` once the step ran) -> step.
JWST_STEP_KEYWORDS = {"S_GRPSCL": "group_scale", "S_DQINIT": "dq_init",
                      "S_SATURA": "saturation", "S_IPC": "ipc", "S_SUPERB": "superbias",
                      "S_REFPIX": "refpix", "S_LINEAR": "linearity",
                      "S_DARK": "dark_current", "S_JUMP": "jump",
                      "S_RAMP": "ramp_fit", "S_GANSCL": "gain_scale"}


def header_jwst_steps(header):
    """The JWST calibration steps a file's header says ran (``S_* = 'COMPLETE'``).

    Returns
    -------
    set of str
        Step names (``'ipc'``, ``'dark_current'``, ...); empty for scenesim files.
    """
    return {step for key, step in JWST_STEP_KEYWORDS.items()
            if str(header.get(key, "")).strip().upper() == "COMPLETE"}


def dms_to_detector(array, header):
    """``array`` (..., ny, nx) of a JWST file back in scenesim's detector orientation,
    from the file's ``FASTAXIS``/``SLOWAXIS``: ``(2, 1)`` (NIRSpec NRS1 in the DMS
    frame: scenesim's IRS2 uncal and what Detector1 makes of it) is transposed,
    ``(-2, -1)`` (NRS2) reversed on both axes and transposed (the inverse of
    :func:`scenesim.pipelines.jwst.irs2_to_dms`); any other pair (scenesim's own
    ``(1, 2)``, or none) is returned as it is."""
    axes = (header.get("FASTAXIS"), header.get("SLOWAXIS"))
    if axes == (2, 1):
        return np.swapaxes(array, -1, -2)
    if axes == (-2, -1):
        return np.swapaxes(array[..., ::-1, ::-1], -1, -2)
    return array


def instrument_cards(instrument):
    """Cards recording a scene's ``[instrument]`` table (an
    :class:`scenesim.pipelines.instrument.InstrumentConfig`); none when it is empty."""
    if instrument is None or not instrument.is_set:
        return []
    return [("JWSTINST", instrument.name, "JWST instrument ('' = inferred)"),
            ("JWSTDET", instrument.detector, "JWST detector ('' = inferred)"),
            ("JWSTEXPT", instrument.exp_type, "JWST EXP_TYPE ('' = inferred)"),
            ("JWSTSUBA", instrument.subarray, "JWST subarray ('' = inferred)")]


def header_instrument(header):
    """The :class:`~scenesim.pipelines.instrument.InstrumentConfig` recorded by
    :func:`instrument_cards` (all fields empty when there is none).

    Raises
    ------
    noise.errors.FileFormatError
        The cards name no valid JWST instrument or detector.
    """
    from scenesim.pipelines.instrument import InstrumentConfig
    try:
        return InstrumentConfig(name=str(header.get("JWSTINST", "")),
                                detector=str(header.get("JWSTDET", "")),
                                exp_type=str(header.get("JWSTEXPT", "")),
                                subarray=str(header.get("JWSTSUBA", "")))
    except ParameterError as exc:
        raise FileFormatError(f"header JWST identity cards are invalid: {exc}") from exc


def psf_cards(psf):
    """Cards recording a scene's PSF (a ``PSFConfig``) for ``compare``'s aperture
    correction: ``PSFFWHM`` (pix) for a Gaussian, ``PSFAIRY`` (pix, radius of the
    first dark ring) for an Airy disk, none for an image PSF."""
    if psf.kind == "gaussian":
        return [("PSFFWHM", psf.fwhm, "[pix] Gaussian PSF FWHM")]
    if psf.kind == "airy":
        return [("PSFAIRY", psf.radius, "[pix] Airy first dark ring")]
    return []


def header_psf(header):
    """The PSF recorded by :func:`psf_cards`, or ``None`` when there is none.

    Returns
    -------
    scenesim.sky.psf.GaussianPSF, scenesim.sky.psf.AiryPSF or None
    """
    try:
        if "PSFFWHM" in header:
            return GaussianPSF(float(header["PSFFWHM"]))
        if "PSFAIRY" in header:
            return AiryPSF(float(header["PSFAIRY"]))
    except (TypeError, ValueError) as exc:      # ParameterError is a ValueError
        raise FileFormatError(f"header PSF card is invalid: {exc}") from exc
    return None
