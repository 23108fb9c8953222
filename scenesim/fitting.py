"""Fit an exposure file: DN to electrons, reference correction, saturation, slopes.

``fit_exposure_file`` reads a scenesim exposure (JWST uncal layout, see
:mod:`scenesim.exposure`), converts DN to electrons with the header's ``GAIN``,
flags saturated resultants, corrects the reference pixels (:mod:`scenesim.refpix`),
removes the per-output common mode that the reference pixels missed, measures the
effective read noise per column, fits slopes (:mod:`scenesim.fit`) and writes the
slope file.

Noise model from the data (see :mod:`scenesim.fit`, "Read noise from the data"): the
header's ``RDNOISE`` is the white noise of one read, but after the reference
correction the ramps also carry (i) noise common to all pixels of an output, read by
read, and (ii) residual row banding.  (i) is a slow wander of every ramp of the
output, which the GLS jump test (a step test) flags as jumps; it is estimated from
the regular pixels (median over each output of the residuals from each pixel's
line, :func:`scenesim.fit.common_mode`, on at most 64 rows) and subtracted, except
its mean rate, which cannot be told from a uniform background.  (ii) is white in
each pixel's ramp and depends on the column (the time within the row at which the
pixel is read): the read noise is rescaled per column so that the median ``chi2``
of read-noise dominated pixels is that of a right model
(:func:`scenesim.fit.measure_read_noise`, on at most 256 rows).  The file records
the model value (``RNMODEL``), the median fitted value (``RNOISE``) and whether the
corrections ran (``RNSOURCE``, ``CMREMOVE``).  On the cosmic-ray scene (H2RG stripe,
60 RAPID groups, ``nirspec`` noise) they lower the false-positive jump rate from
3.9 % to 0.03 % of clean pixels and the mean ``chi2`` from 1.54 to 1.00, keep all
1129 in-ramp hits above 10 sigma, and cost ~2 s on top of a ~3 s fit (the 256-row
stripe is fitted twice more, without jump detection, to measure the noise; a full
2048-row frame uses 1/8 of its rows).

Conventions: read noise is **per read** in e- (header ``RDNOISE``, the white
component; not CDS).  Saturation is judged from the ramp alone, as a pipeline would
without a reference file: a resultant is saturated when its last read is at the ADC
ceiling, or when the charge of its last read above the pixel's zero level (the first
resultant extrapolated back to the reset) reaches 97 % of ``FULLWELL``; the last read
is estimated as the resultant plus the initial slope times the time from the mean
read to the last read (a multi-read resultant whose last reads are saturated has a
mean below the full well but a bent ramp, which the jump test would flag).  Pixels
that saturate before their second resultant have an uncertain zero level; the ADC
ceiling still catches full saturation.
"""

import numpy as np

from noise.detector import detector_from_header
from noise.errors import FileFormatError, ParameterError

from .exposure import read_exposure
from .fit import FITTERS, common_mode, fit_ramps, measure_read_noise, write_fit
from .readout import Readout

__all__ = ["fit_exposure_file", "exposure_read_noise", "saturation_flags",
           "REFPIX_SCHEMES"]

REFPIX_SCHEMES = ("none", "median", "jwst")


def exposure_read_noise(header):
    """White read noise per read (e-) from an exposure header: a scalar or per-output."""
    value = header.get("RDNOISE", 0.0)
    if isinstance(value, str):
        vals = [float(v) for v in value.split(",") if v.strip()]
        return float(np.sqrt(np.mean(np.square(vals)))) if vals else 0.0
    return float(value)


def saturation_flags(e, tbar, full_well, adc_ceiling_e, *, fraction=0.97, t_last=None):
    """Boolean flags of saturated resultants, same shape as ``e`` (nints, nres, ny, nx).

    Parameters
    ----------
    e : ndarray, shape (nints, nres, ny, nx), e-
        Resultants.
    tbar : ndarray, shape (nres,), s
        Mean read time of each resultant from reset.
    full_well : float, e-
        Full well (0: only the ADC ceiling is checked).
    adc_ceiling_e : float, e-
        ADC ceiling in electrons.
    fraction : float
        Fraction of the full well above the zero level that counts as saturated.
    t_last : ndarray, shape (nres,), s, optional
        Time of the last read of each resultant (default ``tbar``).  A resultant
        averages its reads, so when only its last reads are at the full well or the
        ceiling its mean stays below them while the ramp is already bent; the test is
        therefore made on the estimated last read, ``e + slope * (t_last - tbar)``.

    Returns
    -------
    ndarray of bool, shape of ``e``
        Once a resultant is saturated, all later ones of the integration are too.
    """
    if t_last is None or e.shape[1] < 2:
        last = e
        slope = None
    else:
        slope = np.maximum(e[:, 1] - e[:, 0], 0) / np.float32(tbar[1] - tbar[0])
        lead = (np.asarray(t_last, dtype=np.float64) - np.asarray(tbar, dtype=np.float64))
        last = e + slope[:, None] * lead.astype(np.float32)[None, :, None, None]
    sat = last >= adc_ceiling_e
    if full_well and full_well > 0 and e.shape[1] >= 2:
        r0, r1 = e[:, 0], e[:, 1]
        if slope is None:
            slope = np.maximum(r1 - r0, 0) / (tbar[1] - tbar[0])
        zero = r0 - slope * tbar[0]
        sat |= (last - zero[:, None]) >= fraction * full_well
    # once saturated, stay saturated
    return np.maximum.accumulate(sat, axis=1)


def fit_exposure_file(exposure, output, *, fitter="gls", refpix="jwst",
                      jump_threshold=5.0, read_noise=None, threads=None,
                      overwrite=True, remove_common_mode=True, measure_noise=True):
    """Fit the slopes of ``exposure`` and write them to ``output``.

    Parameters
    ----------
    exposure : str
        Exposure written by scenesim (``SCI`` uint16 DN + ``READS`` table).
    output : str
        Slope file (see :func:`scenesim.fit.write_fit`).
    fitter : {'cds', 'ols', 'gls'}
    refpix : {'none', 'median', 'jwst'}
    jump_threshold : float or None
        Jump detection in sigma; 0 or None turns it off.
    read_noise : float, optional
        Model white read noise, e- per read (not CDS); default the header's
        ``RDNOISE``.
    threads : int or None
        Worker threads (see :func:`scenesim.fit.fit_ramps`).
    overwrite : bool
        Replace an existing ``output``.
    remove_common_mode : bool
        Subtract, per output and read, the noise common to the output's pixels that
        the reference correction left (:func:`scenesim.fit.common_mode`; see the
        module notes).
    measure_noise : bool
        Rescale the read noise per column to the scatter measured in the ramps
        (:func:`scenesim.fit.measure_read_noise`; see the module notes).  False:
        use ``read_noise`` as it is.

    Returns
    -------
    scenesim.fit.FitResult
    """
    if fitter not in FITTERS:
        raise ParameterError(f"'fitter' must be one of {list(FITTERS)}, got {fitter!r}")
    for name, flag in (("remove_common_mode", remove_common_mode),
                       ("measure_noise", measure_noise)):
        if not isinstance(flag, bool):
            raise ParameterError(f"{name!r} must be True or False, got {flag!r}")
    if refpix not in REFPIX_SCHEMES:
        raise ParameterError(
            f"'refpix' must be one of {list(REFPIX_SCHEMES)}, got {refpix!r}")
    from noise._validate import check_writable
    check_writable("output", output, overwrite=overwrite)
    sci, hdr, reads = read_exposure(exposure)
    det = detector_from_header(hdr)
    try:
        gain = float(hdr["GAIN"])
        t_frame = float(hdr["TFRAME"])
        nints = int(hdr["NINTS"])
    except KeyError as exc:
        raise FileFormatError(
            f"exposure {exposure!r} lacks header keyword {exc.args[0]!r}") from exc
    ro = Readout.from_read_table(reads, nints=nints,
                                 reset_mode=str(hdr.get("RESETMD", "rolling")),
                                 name=str(hdr.get("READPATT", "CUSTOM")))
    if sci.ndim != 4 or sci.shape[:2] != (nints, ro.ngroups) or sci.shape[2:] != det.shape:
        raise FileFormatError(
            f"exposure {exposure!r}: SCI shape {sci.shape} does not match NINTS={nints}, "
            f"{ro.ngroups} resultants and the {det.shape} detector in its header")
    rdn = exposure_read_noise(hdr) if read_noise is None else float(read_noise)
    e = sci.astype(np.float32) * np.float32(gain)
    bits = int(hdr.get("ADCBITS", 16))
    tbar = ro.mean_times(t_frame)
    t_last = np.array([t[-1] for t in ro.read_times(t_frame)])
    sat = saturation_flags(e, tbar, float(hdr.get("FULLWELL", 0.0)),
                           (2 ** bits - 1) * gain, t_last=t_last)
    if refpix != "none":
        from .refpix import correct_reference
        if det.reference_mask().any():
            e = correct_reference(e, det, scheme=refpix)
    if ro.reset_mode == "global":
        times = ro.read_times(t_frame, det.pixel_time())
    else:
        times = ro.read_times(t_frame)
    refmask = det.reference_mask()
    if remove_common_mode:
        outputs = np.broadcast_to(det.output_of_column(), det.shape).astype(np.intp)
        offsets = common_mode(e, times, read_noise=rdn, groups=outputs, saturated=sat,
                              refmask=refmask, threads=threads)
        e = np.asarray(e, dtype=np.float32)
        for o in range(offsets.shape[-1]):
            cols = det.output_of_column() == o
            e[:, :, :, cols] -= offsets[:, :, o, None, None].astype(np.float32)
    rn_fit = rdn
    if measure_noise:
        columns = np.broadcast_to(np.arange(det.nx), det.shape)
        rn_fit = measure_read_noise(e, times, read_noise=rdn, groups=columns,
                                    saturated=sat, refmask=refmask, threads=threads)
    result = fit_ramps(e, times, read_noise=rn_fit, gain=gain, fitter=fitter,
                       saturated=sat, jump_threshold=jump_threshold or None,
                       refmask=refmask, threads=threads)
    cards = [("EXPOSURE", str(exposure)[-68:], "fitted exposure"),
             ("REFPIX", refpix, "reference-pixel correction"),
             ("JUMPTHR", float(jump_threshold or 0.0), "[sigma] jump threshold, 0=off"),
             ("RNCONV", "per read", "read noise convention: per read, not CDS"),
             ("RNMODEL", float(rdn), "[e-] model white read noise per read"),
             ("RNSOURCE", "measured" if measure_noise else "model",
              "RNOISE: per-column measured or model"),
             ("CMREMOVE", bool(remove_common_mode), "per-output common mode removed")]
    for key in ("DETECTOR", "SUBARRAY", "READPATT", "NINTS", "NGROUPS", "TFRAME",
                "SEED", "SCENE"):
        if key in hdr:
            cards.append((key, hdr[key], hdr.comments[key][:40]))
    write_fit(output, result, header_cards=cards, overwrite=overwrite)
    return result
