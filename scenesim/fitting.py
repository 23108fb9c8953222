"""Fit an exposure file: DN to electrons, reference correction, saturation, slopes.

``fit_exposure_file`` reads a scenesim exposure (JWST uncal layout, see
:mod:`scenesim.exposure`), converts DN to electrons with the header's ``GAIN``,
corrects the reference pixels (:mod:`scenesim.refpix`), flags saturated resultants,
fits slopes (:mod:`scenesim.fit`) and writes the slope file.

Conventions: read noise is **per read** in e- (header ``RDNOISE``, the white
component; not CDS).  Saturation is judged from the ramp alone, as a pipeline would
without a reference file: a resultant is saturated when it is at the ADC ceiling, or
when its charge above the pixel's zero level (the first resultant extrapolated back to
the reset) reaches 97 % of ``FULLWELL``.  Pixels that saturate before their second
resultant have an uncertain zero level; the ADC ceiling still catches full saturation.
"""

import numpy as np

from noise.detector import detector_from_header
from noise.errors import FileFormatError, ParameterError

from .exposure import read_exposure
from .fit import FITTERS, fit_ramps, write_fit
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


def saturation_flags(e, tbar, full_well, adc_ceiling_e, *, fraction=0.97):
    """Boolean flags of saturated resultants, same shape as ``e`` (nints, nres, ny, nx)."""
    sat = e >= adc_ceiling_e
    if full_well and full_well > 0 and e.shape[1] >= 2:
        r0, r1 = e[:, 0], e[:, 1]
        slope = np.maximum(r1 - r0, 0) / (tbar[1] - tbar[0])
        zero = r0 - slope * tbar[0]
        sat |= (e - zero[:, None]) >= fraction * full_well
    # once saturated, stay saturated
    return np.maximum.accumulate(sat, axis=1)


def fit_exposure_file(exposure, output, *, fitter="gls", refpix="jwst",
                      jump_threshold=5.0, read_noise=None, threads=None,
                      overwrite=True):
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
        e- per read; default the header's ``RDNOISE``.

    Returns
    -------
    scenesim.fit.FitResult
    """
    if fitter not in FITTERS:
        raise ParameterError(f"'fitter' must be one of {list(FITTERS)}, got {fitter!r}")
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
    sat = saturation_flags(e, tbar, float(hdr.get("FULLWELL", 0.0)),
                           (2 ** bits - 1) * gain)
    if refpix != "none":
        from .refpix import correct_reference
        if det.reference_mask().any():
            e = correct_reference(e, det, scheme=refpix)
    if ro.reset_mode == "global":
        times = ro.read_times(t_frame, det.pixel_time())
    else:
        times = ro.read_times(t_frame)
    result = fit_ramps(e, times, read_noise=rdn, gain=gain, fitter=fitter,
                       saturated=sat, jump_threshold=jump_threshold or None,
                       refmask=det.reference_mask(), threads=threads)
    cards = [("EXPOSURE", str(exposure)[-68:], "fitted exposure"),
             ("REFPIX", refpix, "reference-pixel correction"),
             ("JUMPTHR", float(jump_threshold or 0.0), "[sigma] jump threshold, 0=off"),
             ("RNCONV", "per read", "read noise convention: per read, not CDS")]
    for key in ("DETECTOR", "SUBARRAY", "READPATT", "NINTS", "NGROUPS", "TFRAME",
                "SEED", "SCENE"):
        if key in hdr:
            cards.append((key, hdr[key], hdr.comments[key][:40]))
    write_fit(output, result, header_cards=cards, overwrite=overwrite)
    return result
